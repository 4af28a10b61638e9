"""``mtwip/Balance-v0``: keep the two-wheeled robot upright, from the scenario's initial tilt.

The PyBullet twin with its simulated IMU and encoders and the estimator in the loop
(:class:`twin.sim.loop.ClosedLoop`), one control period (5 ms at the default 200 Hz) per
step; the agent commands the two wheel torques. Default scenario ``paper-exp1`` (the
paper's experiment 1: from θ0 = 0.48 rad on a true plant that differs from the nominal
model, 15 s). Any built-in or scenario file runs: its targets, if any, are ignored here
(see ``mtwip/Track-v0``)::

    import gymnasium, twin.envs
    env = gymnasium.make("mtwip/Balance-v0")                       # paper-exp1, EKF estimate
    env = gymnasium.make("mtwip/Balance-v0", scenario="push-recovery", obs="readings",
                         overrides=("duration=5",), randomize={"level": 0.3})
    env = gymnasium.make("mtwip/Balance-v0", normalize_actions=True)  # action Box [-1, 1]

Action Space
    (ul, ur), left and right wheel torque commands in N·m, positive driving forward,
    each in [−τ_max, τ_max]: τ_max = 1.2 N·m, the default DC motor's stall torque (read
    from the scenario's motor; ``max_torque=`` overrides). Clipped to the box.

    With ``normalize_actions=True``: Box [−1, 1]², the torques as fractions of τ_max
    (1 dimensionless): (a_l, a_r) commands (a_l τ_max, a_r τ_max) N·m, each a clipped to
    [−1, 1] first. ``info["command"]`` and the reward are in N·m either way.

Observation Space (Box, float32; ``obs=``)
    ==========  =====  ===========================================  =================
    ``obs``     index  quantity                                     bounds (clipped)
    ==========  =====  ===========================================  =================
    estimate    0      θ, body pitch from the vertical, + forward   ±π rad
                1      θ̇                                            ±100 rad/s
                2      ψ, mean wheel angle from the vertical        ±1e4 rad
                3      ψ̇ (travel speed ṗ = r ψ̇, r = 0.04 m)         ±100 rad/s
                4      α, heading (unwrapped), + turning left       ±1e4 rad
                5      α̇                                            ±100 rad/s
    truth       0–5    the same, from the ground truth              the same
    readings    0–2    gyro, body axes (x fwd, y left, z up)        ±full scale, rad/s
                3–5    accelerometer (specific force), body axes    ±full scale, m/s²
                6–7    encoders (left, right), wheel angle rel.     ±1e4 rad
                       to the body since power-up
                8–10   fresh flags (gyro, accel, encoders)          {0, 1}
    ==========  =====  ===========================================  =================

    ``estimate`` is the scenario's estimator (EKF by default) on the sensors; a
    missing reading holds its last value with its fresh flag at 0 (never NaN). The
    default IMU's full scales are 250 °/s (4.36 rad/s) and 2 g (19.6 m/s²).

Rewards (per step, from the ground truth at the end of the period)
    ``alive − 0.5 c_theta − 0.1 c_theta_dot − 0.1 c_torque``, with

    =============  ===================================  ======
    term           cost, capped at 1                    weight
    =============  ===================================  ======
    alive          1 while up, 0 on the step it falls   +1
    c_theta        (θ / 1 rad)²                         0.5
    c_theta_dot    (θ̇ / 5 rad/s)²                       0.1
    c_torque       (ul² + ur²) / (2 τ_max²)             0.1
    =============  ===================================  ======

    so a step is worth 0.3 to 1 while the robot is up and −0.7 to 0 on the step it
    falls: falling never pays. ``reward_weights={"theta": ..., ...}`` changes the
    weights; ``info`` holds ``alive``, ``cost_theta``, ``cost_theta_dot``,
    ``cost_torque``, ``truth`` (:class:`~twin.plant.bullet.GroundTruth`) and
    ``command`` (the clipped (ul, ur)) for a wrapper that wants its own reward.

Starting State
    The scenario's ``[initial]`` table: paper-exp1 starts at rest, tilted θ0 = 0.48 rad
    forward, at the origin heading along x (ψ = α = 0). ``reset(seed=...)`` draws the
    sensors' seed (noise, faults); with ``randomize`` the episode is a sample of the
    scenario's Monte Carlo sweep instead (plant factors, initial tilt and pushes as its
    ``[sweep]`` table says; :mod:`twin.envs.base`).

Episode End
    ``terminated``: the robot fell (tilt past 1 rad, or the body touched the floor) or
    the physics diverged; ``truncated``: the scenario's duration elapsed (3000 steps
    for paper-exp1's 15 s at 200 Hz). The id is registered with
    ``max_episode_steps=3000`` (paper-exp1's duration over its 5 ms control period), so
    ``gymnasium.make``'s TimeLimit truncates on the same step; give
    ``max_episode_steps=`` to ``gymnasium.make`` for a scenario that lasts longer.

Rendering and video
    ``render_mode="rgb_array"``: (H, W, 3) uint8 pictures, taken only when ``render()``
    is called, with the overlay of a ``twin run`` video (``hud=True``): the text box, the
    key, and on the floor the targets and, once the robot has moved 5 cm, the start and the
    path through the places it was pictured at; ``metadata["render_fps"]`` = 200, one picture per step (Gymnasium's
    convention). :class:`twin.envs.RecordVideo` records real-time H.264 video at the
    scenario's ``video.fps`` (30 frames per simulated second), rendering 451 pictures
    for a 15 s episode instead of 3001.

Arguments
    ``gymnasium.make("mtwip/Balance-v0", ...)`` takes ``scenario`` (a built-in name or a
    ``.toml`` file; default ``paper-exp1``), ``overrides`` (``"KEY=VALUE"`` strings, as
    ``twin run --set``), ``obs`` (``"estimate"``, ``"truth"`` or ``"readings"``),
    ``estimator`` (a kind), ``randomize`` (False, True or a dict of ``[sweep]`` keys),
    ``render_mode`` (None or ``"rgb_array"``), ``render_size``, ``renderer``, ``hud``,
    ``max_torque`` (N·m), ``reward_weights`` and ``normalize_actions``. The shared
    behaviour (seeding, ``randomize``, ``estimator=``, rendering): :mod:`twin.envs.base`.

Version History
    v0: the first version (the twin's release 0.1.0).
"""
from __future__ import annotations

from twin.envs.base import TwinEnv

THETA_SCALE = 1.0  # rad
THETA_DOT_SCALE = 5.0  # rad/s


class BalanceEnv(TwinEnv):
    """Balance the robot (``mtwip/Balance-v0``); see the module docstring for the full specification."""

    default_scenario = "paper-exp1"
    task = "balance"
    reward_weights = {"theta": 0.5, "theta_dot": 0.1, "torque": 0.1}

    def _reward(self, truth, ul: float, ur: float, alive: float, info: dict) -> float:
        w = self.weights
        th = truth[1] / THETA_SCALE
        thd = truth[2] / THETA_DOT_SCALE
        t2 = self.max_torque * self.max_torque
        c_th = min(th * th, 1.0)
        c_thd = min(thd * thd, 1.0)
        c_u = (ul * ul + ur * ur) / (2.0 * t2)
        info["alive"] = alive
        info["cost_theta"] = c_th
        info["cost_theta_dot"] = c_thd
        info["cost_torque"] = c_u
        return alive - w["theta"] * c_th - w["theta_dot"] * c_thd - w["torque"] * c_u


__all__ = ["BalanceEnv"]
