"""``mtwip/Track-v0``: balance, drive to a travel target and turn to a heading target.

The same loop, action and episode end as ``mtwip/Balance-v0`` (:mod:`twin.envs.balance`),
on a scenario with targets: default ``paper-exp3`` (the paper's experiment 3: from
θ0 = 0.48 rad, travel p_d = 1 m and turn to α_d = 1.5 rad, 15 s). The targets are the
scenario's ``[targets]`` table (``overrides=("targets.position=0.5",)`` changes them); a
scenario needs at least one (``paper-exp2`` has a position target only; a missing one
contributes 0 to the observation and the reward)::

    env = gymnasium.make("mtwip/Track-v0")                                  # paper-exp3
    env = gymnasium.make("mtwip/Track-v0", scenario="paper-exp2", obs="truth")

Why one class per task over a shared base (:class:`twin.envs.base.TwinEnv`): the tasks
differ in their default scenario, two observation entries and the reward; the loop,
sensing modes, seeding, randomisation and rendering are the same code.

Action Space
    (ul, ur) in N·m, Box [−τ_max, τ_max]², clipped: as ``mtwip/Balance-v0``; with
    ``normalize_actions=True`` Box [−1, 1]², fractions of τ_max.

Observation Space (Box, float32)
    The Balance observation of the chosen ``obs`` mode (6 entries, or 11 for
    ``"readings"``), then two task entries that make the task Markov:

    ==================  =====  ==============================================  ===========
    ``obs``             index  quantity                                        bounds
    ==================  =====  ==============================================  ===========
    estimate            6      position error e_p = r ψ̂ − p_d (r the nominal   ±1e3 m
                               wheel radius the estimator assumes, 0.04 m)
                        7      heading error e_α = α̂ − α_d (unwrapped)         ±1e4 rad
    truth               6, 7   the same from the ground truth (p = r ψ with    the same
                               the true r)
    readings            11     the target p_d                                  ±1e3 m
                        12     the target α_d                                  ±1e4 rad
    ==================  =====  ==============================================  ===========

    Errors are value − target, as the controllers and the run metrics use them (a
    robot short of its target has e_p < 0). With raw readings the errors are not
    observable, so the targets themselves are given (travel is measured from where
    the robot started, heading from the world x axis).

Rewards (per step, from the ground truth at the end of the period)
    ``alive − 0.3 c_theta − 0.05 c_theta_dot − 0.05 c_torque − 0.3 c_position − 0.2 c_heading``

    ===========  ========================================  ======
    term         cost, capped at 1                         weight
    ===========  ========================================  ======
    alive        1 while up, 0 on the step it falls        +1
    c_theta      (θ / 1 rad)²                              0.3
    c_theta_dot  (θ̇ / 5 rad/s)²                            0.05
    c_torque     (ul² + ur²) / (2 τ_max²)                  0.05
    c_position   ((p − p_d) / 1 m)², p = r ψ true travel   0.3
    c_heading    ((α − α_d) / 1 rad)²                      0.2
    ===========  ========================================  ======

    A step is worth 0.1 to 1 while the robot is up and −0.9 to 0 on the step it falls.
    ``info`` holds ``alive`` and every ``cost_*``, ``truth`` and ``command``
    (``reward_weights=`` changes the weights).

Starting State
    The scenario's ``[initial]`` table: paper-exp3 starts at rest, tilted θ0 = 0.48 rad
    forward, at the origin heading along x; the targets are fixed for the episode. Seeding
    and ``randomize`` as ``mtwip/Balance-v0``.

Episode End
    As ``mtwip/Balance-v0``: ``terminated`` on a fall or divergence, ``truncated`` at
    the scenario's duration; registered with ``max_episode_steps=3000`` (paper-exp3's
    15 s at 200 Hz).

Arguments
    Those of ``mtwip/Balance-v0`` (:mod:`twin.envs.balance`); default ``scenario``
    ``paper-exp3``, and a scenario needs a ``[targets]`` table.

Version History
    v0: the first version (the twin's release 0.1.0).
"""
from __future__ import annotations

from twin.envs.balance import THETA_DOT_SCALE, THETA_SCALE
from twin.envs.base import ANGLE_LIMIT, POSITION_LIMIT, TwinEnv
from twin.errors import TwinError

POSITION_SCALE = 1.0  # m
HEADING_SCALE = 1.0  # rad


class TrackEnv(TwinEnv):
    """Balance and reach the scenario's targets (``mtwip/Track-v0``); see the module docstring."""

    default_scenario = "paper-exp3"
    task = "track"
    reward_weights = {"theta": 0.3, "theta_dot": 0.05, "torque": 0.05, "position": 0.3, "heading": 0.2}

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        targets = self.experiment.targets
        if targets.position is None and targets.heading is None:
            self.close()
            raise TwinError(f"{self.scenario.source}: mtwip/Track-v0 needs a target (targets.position in m and/or "
                            f"targets.heading in rad); this scenario has none: use mtwip/Balance-v0, or set one, "
                            f"e.g. overrides=('targets.position=1.0',)")
        self._r = self._context.model.r  # the nominal wheel radius the estimator assumes, m
        self._p_d = self._a_d = 0.0
        self._has_p = self._has_a = False

    @property
    def extra_names(self) -> tuple:
        if self.obs_mode == "readings":
            return ("target_position", "target_heading")
        return ("position_error", "heading_error")

    def _extras_bounds(self) -> tuple[list, list]:
        return [-POSITION_LIMIT, -ANGLE_LIMIT], [POSITION_LIMIT, ANGLE_LIMIT]

    def _begin_episode(self, targets) -> None:
        self._has_p, self._has_a = targets.position is not None, targets.heading is not None
        self._p_d = float(targets.position) if self._has_p else 0.0
        self._a_d = float(targets.heading) if self._has_a else 0.0

    def _extra_values(self, base) -> tuple:
        mode = self.obs_mode
        if mode == "readings":
            return self._p_d, self._a_d
        if mode == "estimate":
            p, a = self._r * base[2], base[4]  # ψ̂ → travel with the nominal r
        else:
            tr = self.loop.truth
            p, a = tr[9], tr[7]
        return (p - self._p_d if self._has_p else 0.0), (a - self._a_d if self._has_a else 0.0)

    def _reward(self, truth, ul: float, ur: float, alive: float, info: dict) -> float:
        w = self.weights
        th = truth[1] / THETA_SCALE
        thd = truth[2] / THETA_DOT_SCALE
        ep = (truth[9] - self._p_d) / POSITION_SCALE if self._has_p else 0.0
        ea = (truth[7] - self._a_d) / HEADING_SCALE if self._has_a else 0.0
        t2 = self.max_torque * self.max_torque
        c_th, c_thd = min(th * th, 1.0), min(thd * thd, 1.0)
        c_u = (ul * ul + ur * ur) / (2.0 * t2)
        c_p, c_a = min(ep * ep, 1.0), min(ea * ea, 1.0)
        info["alive"] = alive
        info["cost_theta"] = c_th
        info["cost_theta_dot"] = c_thd
        info["cost_torque"] = c_u
        info["cost_position"] = c_p
        info["cost_heading"] = c_a
        return (alive - w["theta"] * c_th - w["theta_dot"] * c_thd - w["torque"] * c_u - w["position"] * c_p
                - w["heading"] * c_a)


__all__ = ["TrackEnv"]
