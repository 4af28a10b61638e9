"""What every mtwip environment shares: a scenario driven through :class:`twin.sim.loop.ClosedLoop`.

The task environments (:mod:`twin.envs.balance`, :mod:`twin.envs.track`) subclass
:class:`TwinEnv` and add their default scenario, their task observation (after the six
or eleven entries below) and their reward. Everything else is here, once:

* **The loop.** One :class:`~twin.sim.loop.ClosedLoop` per episode (the twin, the simulated
  IMU and encoders, the estimator), built from the scenario; the agent's action is its
  ``step(command)``. No controller runs: the action *is* the command. One PyBullet
  client is alive per environment at a time (the loop's twin); :meth:`close` releases it.
* **Observation modes** (``obs=``), float32, each entry clipped to the bounds of the
  observation space (given in :data:`ANGLE_LIMIT`, :data:`RATE_LIMIT` and the IMU's full
  scale; the values stay inside them except in extreme runs, and the clip makes the
  bound a guarantee; a non-finite value, which the loop never lets through, would be
  reported as 0):

  ``"estimate"`` (default)
      The estimator's output [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s, rad, rad/s, rad, rad/s)
      (see :mod:`twin.protocols`); θ clipped to ±π rad, ψ and α to ±1e4 rad, the rates
      to ±100 rad/s.
  ``"truth"``
      The same six quantities from the ground truth (:class:`~twin.plant.bullet.GroundTruth`),
      same layout and bounds: a policy trained on one runs on the other.
  ``"readings"``
      The raw sensor readings as they reach the estimator, 11 values: gyro (3) rad/s and
      accelerometer (3) m/s² in body axes (x forward, y left along the axle, z up the
      body), each clipped to the sensor's full scale; encoders (2) rad, each wheel's
      angle relative to the body since power-up (quantised), clipped to ±1e4 rad; then
      three freshness flags (gyro, accelerometer, encoders): 1.0 when a new sample
      arrived at this control instant, 0.0 when none did (latency, a lower IMU rate, a
      dropout). A missing sample holds the sensor's last value (zeros before the first
      one); a non-finite sample counts as missing. Never NaN. Needs simulated sensors
      (not ``sensors.sensing = "ideal"``).

* **Action**: (ul, ur), the left and right wheel torque commands in N·m, positive
  driving the robot forward, Box [−τ_max, τ_max]² (float32). τ_max is what the scenario's motor
  driver passes at standstill, min(stall torque, k_t · current limit) of
  ``TwinConfig.motor`` (1.2 N·m for the default DC motor). The scenario's
  ``plant.motor = "ideal"`` has no limit of its own; the bound is then that of the DC
  motor it stands in for (``TwinConfig``'s default motor), so switching the motor model
  keeps the action space. ``max_torque=`` sets another bound. Actions outside the box
  are clipped to it (the reward's torque cost sees the clipped command); a non-finite
  action is a one-line :class:`~twin.errors.PluginError`. The motors may deliver less
  than commanded (back-EMF, PWM quantisation; see :mod:`twin.actuators`).

  ``normalize_actions=True`` makes the action space Box [−1, 1]² (float32, what
  Gymnasium's checker and stable-baselines3 recommend): the action is (ul, ur) / τ_max,
  each entry clipped to [−1, 1] and then multiplied by τ_max (so a = 0.5 commands
  0.6 N·m with the default motor); ``info["command"]`` and the reward's torque cost
  stay in N·m, so the same torques give the same episode and reward either way. The
  default (False) keeps the box in N·m. Gymnasium's ``RescaleAction(env, -1, 1)``
  wrapper does the same from outside.
* **Episode end**: ``terminated`` when the loop's status becomes ``"fell"`` (tilt past
  ``fall_angle``, or the body touched the floor) or ``"diverged"`` (non-finite physics);
  ``truncated`` after the scenario's ``duration`` (round(duration · control rate)
  control periods, :attr:`TwinEnv.n_steps`). A diverged step returns the previous
  observation (the state is not finite). The registered ids also carry
  ``max_episode_steps``, the default scenario's step count (3000: 15 s at 200 Hz), so
  ``gymnasium.make`` adds a ``TimeLimit`` that truncates on the same step; a scenario or
  ``duration`` override lasting longer needs ``gymnasium.make(..., max_episode_steps=N)``
  (or ``-1``, no TimeLimit), else the TimeLimit ends its episodes at 3000 steps (the
  first :meth:`reset` of such an environment warns).
* **Seeding and randomisation**: every draw comes from ``self.np_random``, seeded by
  ``reset(seed=...)``; the same seed gives the same episode. Without ``randomize`` only
  the sensors' seed (noise, faults) is drawn per episode. With ``randomize=True`` or a
  dict, the episode is sample ``k`` of the scenario's Monte Carlo sweep
  (:func:`twin.sweep.sampling.sample_scenario`) with a root seed drawn from
  ``np_random``: plant factors, sensor seed, initial tilt and pushes as the scenario's
  ``[sweep]`` table says. ``True`` draws the level λ uniformly from ``sweep.levels`` each
  episode; a dict sets ``[sweep]`` keys for the environment (``{"level": 0.3}`` is
  ``sweep.levels = [0.3]``; e.g. ``{"level": 0.3, "initial_theta": [-0.3, 0.3],
  "push_count": 2}``). ``info["replay"]`` of ``reset`` is the ``twin run`` command that
  rebuilds the episode's plant, sensors and pushes (with a controller in place of the
  agent).
* **Estimator**: the scenario's (``sensors.estimator`` with ``sensors.estimator_params``;
  ``ideal`` with ideal sensing), built fresh each episode through :mod:`twin.registry`;
  ``estimator="kind"`` (a built-in name or ``"package.module:attribute"``) overrides it.
* **Rendering** (opt-in): ``render_mode="rgb_array"`` returns (H, W, 3) uint8 pictures
  of the true state from :class:`twin.render.scene.Scene` (a camera that follows the
  robot; ``render_size=(W, H)``, ``renderer`` "auto"/"egl"/"tiny") with the heads-up
  overlay of :mod:`twin.render.hud` (``hud=False`` leaves it out). The scene, a PyBullet
  client of its own, is built on the first :meth:`render` and never without a render mode;
  a picture is taken only when :meth:`render` is called (at 640x480 one costs some
  tens of milliseconds, many control steps' worth). ``metadata["render_fps"]`` is the control rate (200), Gymnasium's
  convention (one picture per step, as MuJoCo's environments): Gymnasium's own
  ``RecordVideo`` wrapper (which needs ``pip install moviepy``) then writes a real-time
  video but renders every step and plays at 200 frames/s. :class:`twin.envs.RecordVideo`
  records at :attr:`TwinEnv.video_fps` (the scenario's ``video.fps``, 30) in real time,
  rendering only the steps that fall on a frame time, as H.264 through the project's
  ffmpeg writer (no moviepy).

Reward. ``reward = alive − Σ_k w_k c_k``: ``alive`` is 1 while the robot is up and 0 on
the step it falls; each cost ``c_k`` is a squared, normalised quantity capped at 1
(see the task's docstring for its terms and default weights). The weights are
``reward_weights`` (``reward_weights=`` overrides some or all); ``info`` holds
``alive`` and every ``cost_*``, and ``truth`` (the ground truth) and the clipped
``command``, so a wrapper can recombine them or compute its own reward.
"""
from __future__ import annotations

import json
import math
import shlex
from dataclasses import replace
from os import PathLike

import gymnasium
import numpy as np
from gymnasium import spaces

from twin.errors import TwinError
from twin.plant.urdf import body_box
from twin.registry import build_estimator, check_kind
from twin.robots import robot_item
from twin.render.hud import draw_hud, HudState
from twin.render.panels import draw_markers, from_start, PATH_STEP_M
from twin.render.scene import camera_mode, check_size, resolve_renderer, robot_scale, Scene
from twin.scenarios import load_scenario
from twin.scenarios.schema import SCHEMA
from twin.sim.simulate import build_loop
from twin.sim.spec import Plugin
from twin.sweep.sampling import sample_scenario

OBS_MODES = ("estimate", "truth", "readings")
ANGLE_LIMIT = 1.0e4  # rad: ψ, α and the encoders (4e2 m of travel at r = 4 cm; float32 keeps 1e-3 rad there)
RATE_LIMIT = 100.0  # rad/s: θ̇, ψ̇, α̇ (the DC motors' no-load speed is 35 rad/s)
PITCH_LIMIT = math.pi  # rad: θ (a run ends past fall_angle ≤ 1.5 rad)
POSITION_LIMIT = 1.0e3  # m: position errors and targets
_SEED_BOUND = 2 ** 63  # episode and root seeds are drawn in [0, 2^63), the scenario schema's seed range


def _toml_value(value) -> str:
    """A Python number, bool, string or list as a TOML value (JSON is valid TOML for these)."""
    if isinstance(value, tuple):
        value = list(value)
    return json.dumps(value, ensure_ascii=False)


class TwinEnv(gymnasium.Env):
    """Base class of the mtwip environments (see the module docstring); not registered itself.

    Subclasses set :attr:`default_scenario`, :attr:`reward_weights` and
    :attr:`extra_names`, and implement :meth:`_extras_bounds`, :meth:`_extra_values` and
    :meth:`_reward`.

    Parameters
    ----------
    scenario : str or path
        A built-in scenario name (see ``twin scenarios``) or a scenario ``.toml`` file;
        None: the task's default.
    overrides : sequence of str
        ``"KEY=VALUE"`` items applied to the scenario, as ``twin run --set``.
    obs : {"estimate", "truth", "readings"}
    estimator : str or None
        An estimator kind overriding the scenario's.
    randomize : bool or dict
        Per-episode randomisation (module docstring).
    render_mode : None or "rgb_array"
    render_size : (int, int)
        (width, height) of rendered pictures, even, px.
    renderer : {"auto", "egl", "tiny"} or None
        None: ``$TWIN_RENDERER`` or ``"auto"``.
    hud : bool
        Draw the heads-up overlay on rendered pictures.
    max_torque : float or None
        Action bound τ_max in N·m (default: from the scenario's motor).
    reward_weights : dict or None
        Weights replacing some of :attr:`reward_weights`.
    normalize_actions : bool
        False (default): the action is (ul, ur) in N·m, Box [−τ_max, τ_max]². True:
        Box [−1, 1]², the torques as fractions of τ_max (module docstring).
    robot : str or path or None
        A built-in robot's name (``twin robots``) or a robot file: the scenario's ``robot``
        (its dimensions, drive, sensors and rates); None: the scenario's own.

    Attributes
    ----------
    n_steps : int
        Steps of an episode that is not cut short: round(duration · control rate).
    control_rate : float
        Steps per simulated second, Hz (200 by default).
    max_torque : float
        τ_max, N·m.
    video_fps : int
        The scenario's ``video.fps``, frames per simulated second of
        :class:`twin.envs.RecordVideo` (30 by default).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 200}
    default_scenario = "paper-exp1"
    task = "twin"
    reward_weights: dict = {}
    extra_names: tuple = ()  # names of the task's observation entries after the base ones

    def __init__(self, scenario=None, overrides=(), obs: str = "estimate", estimator: str | None = None,
                 randomize=False, render_mode: str | None = None, render_size=(640, 480),
                 renderer: str | None = None, hud: bool = True, max_torque: float | None = None,
                 reward_weights: dict | None = None, normalize_actions: bool = False, robot=None):
        if obs not in OBS_MODES:
            raise TwinError(f"obs must be one of {', '.join(OBS_MODES)}, got {obs!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise TwinError(f"render_mode must be None or one of {', '.join(self.metadata['render_modes'])}, "
                            f"got {render_mode!r}")
        if isinstance(overrides, str) or not all(isinstance(o, str) for o in overrides):
            raise TwinError(f"overrides must be a sequence of 'KEY=VALUE' strings, got {overrides!r}")
        if not isinstance(normalize_actions, bool):
            raise TwinError(f"normalize_actions must be True (action Box [-1, 1], fractions of max_torque) or "
                            f"False (action in N·m), got {normalize_actions!r}")
        scenario = self.default_scenario if scenario is None else scenario
        if not isinstance(scenario, (str, PathLike)):
            raise TwinError(f"scenario must be a built-in scenario name or a .toml file, got {scenario!r}")
        self.obs_mode = obs
        self.render_mode = render_mode
        self.render_size = check_size(render_size, "render_size")
        self.renderer = resolve_renderer(renderer)
        self.hud = bool(hud)

        self._sweep_overrides, self._level_draw = self._parse_randomize(randomize)
        self.randomize = randomize not in (False, None)
        if robot is not None:  # the scenario's robot key, as twin run --robot sets it
            if not isinstance(robot, (str, PathLike)):
                raise TwinError(f"robot must be a built-in robot's name or a robot file (.toml), got {robot!r}")
            overrides = (robot_item(robot),) + tuple(overrides)
        self.overrides = tuple(overrides) + self._sweep_overrides
        self._scenario_arg = str(scenario)
        self.scenario = sc = load_scenario(self._scenario_arg, self.overrides)
        self.weights = self._parse_weights(reward_weights)

        # what every episode shares (without randomize, everything but the sensor seed)
        self.config = sc.twin_config()
        self.sensors = sc.sensor_config()
        self.experiment = sc.experiment()
        self.control_rate = self.config.control_rate
        self.n_steps = int(round(sc.duration * self.control_rate))
        self.video_fps = int(sc.data["video"]["fps"])
        if obs == "readings" and self.sensors is None:
            raise TwinError(f"{sc.source}: obs='readings' needs simulated sensors, but sensors.sensing is 'ideal'; "
                            "use obs='estimate' or 'truth', or --set sensors.sensing=estimated")
        self.estimator_kind = check_kind("estimator", estimator) if estimator is not None else sc.estimator
        self._context = sc.build_context()
        self._next_estimator = self._build_estimator(sc, self._context)  # fails here, not at the first reset
        self.max_torque = self._torque_bound(max_torque)
        self.metadata = {**type(self).metadata, "render_fps": _fps(self.control_rate)}

        self.normalize_actions = normalize_actions
        t = 1.0 if normalize_actions else self.max_torque
        self.action_space = spaces.Box(-t, t, shape=(2,), dtype=np.float32)
        self._limit_checked = False
        low, high = self._base_bounds()
        xlow, xhigh = self._extras_bounds()
        self._low = np.array(low + xlow, dtype=np.float32)
        self._high = np.array(high + xhigh, dtype=np.float32)
        self.observation_space = spaces.Box(self._low, self._high, dtype=np.float32)
        self.obs_names = self._base_names() + tuple(self.extra_names)
        self._low_f, self._high_f = self._low.tolist(), self._high.tolist()
        self._held = [0.0] * 11
        self._base_values = {"estimate": self._estimate_values, "truth": self._truth_values,
                             "readings": self._readings_values}[obs]

        self.loop = None
        self._episode = None  # (scenario, config, targets) of the running episode
        self._scene = None
        self._scene_key = None
        self._last_obs = None
        self._last_truth = None
        self._path: list[tuple[float, float]] = []  # (x, y) m of the axle at reset and pictured since, 1 cm apart
        self._start = (0.0, 0.0, 0.0)  # (x, y, α) m, m, rad at reset

    # ---- construction helpers ------------------------------------------------------------------
    def _parse_randomize(self, randomize) -> tuple[tuple[str, ...], bool]:
        """(sweep overrides, whether the level is drawn per episode)."""
        if randomize is None or randomize is False:
            return (), False
        if randomize is True:
            return (), True
        if not isinstance(randomize, dict):
            raise TwinError(f"randomize must be False, True or a dict of [sweep] keys (e.g. {{'level': 0.3}}), "
                            f"got {randomize!r}")
        allowed = ("level",) + tuple(SCHEMA["sweep"].keys)
        items = []
        for key, value in randomize.items():
            if key not in allowed:
                raise TwinError(f"randomize: unknown key {key!r}; allowed: {', '.join(allowed)}")
            if key == "level":
                if "levels" in randomize:
                    raise TwinError("randomize: give 'level' or 'levels', not both")
                key, value = "levels", [value]
            items.append(f"sweep.{key}={_toml_value(value)}")
        return tuple(items), "level" not in randomize

    def _parse_weights(self, weights) -> dict:
        out = dict(type(self).reward_weights)
        if weights is None:
            return out
        if not isinstance(weights, dict):
            raise TwinError(f"reward_weights must be a dict of {', '.join(out)} to numbers, got {weights!r}")
        for k, v in weights.items():
            if k not in out:
                raise TwinError(f"reward_weights: unknown term {k!r}; terms: {', '.join(out)}")
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise TwinError(f"reward_weights[{k!r}] must be a finite number, got {v!r}")
            out[k] = float(v)
        return out

    def _torque_bound(self, max_torque) -> float:
        if max_torque is not None:
            if isinstance(max_torque, bool) or not isinstance(max_torque, (int, float)) or not (
                    math.isfinite(max_torque) and max_torque > 0):
                raise TwinError(f"max_torque must be a positive number of N·m, got {max_torque!r}")
            return float(max_torque)

        # ideal torque sources (plant.motor = "ideal"): the bound of the robot's drive they stand in for
        motor = self.config.motor if self.config.motor is not None else self.scenario.robot.motor()
        return float(min(motor.stall_torque, motor.k_t * motor.max_current))

    def _build_estimator(self, sc, context):
        if self.estimator_kind == sc.estimator:
            return sc.build_estimator(context)
        try:
            return build_estimator(self.estimator_kind, None, context)
        except TwinError as exc:
            raise TwinError(f"{sc.source}: estimator: {exc}") from None

    # ---- observation layout --------------------------------------------------------------------
    def _base_names(self) -> tuple[str, ...]:
        if self.obs_mode == "readings":
            return ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z", "encoder_l", "encoder_r",
                    "gyro_fresh", "accel_fresh", "encoders_fresh")
        return ("theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot")

    def _base_bounds(self) -> tuple[list, list]:
        if self.obs_mode == "readings":
            g, a = self.sensors.imu.gyro.full_scale, self.sensors.imu.accel.full_scale
            high = [g] * 3 + [a] * 3 + [ANGLE_LIMIT] * 2 + [1.0] * 3
            return [-v for v in high[:8]] + [0.0] * 3, high
        high = [PITCH_LIMIT, RATE_LIMIT, ANGLE_LIMIT, RATE_LIMIT, ANGLE_LIMIT, RATE_LIMIT]
        return [-v for v in high], high

    def _extras_bounds(self) -> tuple[list, list]:
        """(low, high) of the task's observation entries after the base ones."""
        return [], []

    def _estimate_values(self):
        return self.loop.estimate

    def _truth_values(self):
        tr = self.loop.truth
        return tr[1], tr[2], tr[5], tr[6], tr[7], tr[8]  # θ, θ̇, ψ, ψ̇, α, α̇

    def _readings_values(self):
        m = self.loop.measurement
        held = self._held  # the last finite sample of each sensor, then the three fresh flags
        isfinite = math.isfinite
        g, a, e = m.gyro, m.accel, m.encoders
        if g is not None and isfinite(g[0] + g[1] + g[2]):
            held[0:3] = g
            held[8] = 1.0
        else:
            held[8] = 0.0
        if a is not None and isfinite(a[0] + a[1] + a[2]):
            held[3:6] = a
            held[9] = 1.0
        else:
            held[9] = 0.0
        if e is not None and isfinite(e[0] + e[1]):
            held[6:8] = e
            held[10] = 1.0
        else:
            held[10] = 0.0
        return held

    def _begin_episode(self, targets) -> None:
        """Called by :meth:`reset` with the episode's :class:`~twin.protocols.Targets` before its first observation."""

    def _extra_values(self, base) -> tuple:
        """The task's observation entries after the base ones (``base``: the base entries)."""
        return ()

    def _observe(self) -> np.ndarray:
        base = self._base_values()
        vals = (*base, *self._extra_values(base))
        obs = np.array(vals, dtype=np.float32)  # the one allocation of a step
        # every bound is a float32 number, so a float64 value inside it stays inside once rounded
        for v, lo, hi in zip(vals, self._low_f, self._high_f):
            if not lo <= v <= hi:  # rare (or NaN): clip the whole row
                np.nan_to_num(obs, copy=False)
                np.clip(obs, self._low, self._high, out=obs)
                break
        self._last_obs = obs
        return obs

    # ---- reward --------------------------------------------------------------------------------
    def _reward(self, truth, ul: float, ur: float, alive: float, info: dict) -> float:
        """The reward of the step that ended at ``truth``; writes its terms into ``info``."""
        raise NotImplementedError

    # ---- the Gymnasium API ---------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode: a new twin at the scenario's initial state, a fresh estimator.

        ``options`` is not used (must be None or empty). ``info`` holds ``t`` (s),
        ``status``, ``truth``, ``seed`` (the sensors' seed), ``scenario`` and ``replay``,
        and with ``randomize`` also ``root_seed``, ``sample``, ``level`` and
        ``sample_values`` (the sampled plant factors, tilt and pushes, units in the names).
        """
        super().reset(seed=seed)
        if options:
            raise TwinError(f"reset options are not supported, got {options!r}")
        if not self._limit_checked:
            self._limit_checked = True
            self._warn_if_time_limit_is_shorter()
        rng = self.np_random
        info = {}
        if self.randomize:
            root = int(rng.integers(0, _SEED_BOUND, dtype=np.uint64))
            levels = self.scenario.sweep["levels"]
            index = int(rng.integers(0, len(levels))) if self._level_draw else 0
            sample = sample_scenario(self.scenario, root, index)
            sc, run_seed = sample.scenario, sample.seed
            config, sensors, exp = sc.twin_config(), sc.sensor_config(), sc.experiment()
            context = sc.build_context()
            estimator = self._build_estimator(sc, context)
            info.update(root_seed=root, sample=index, level=sample.level, sample_values=dict(sample.values))
            replay = f"--sample {index} --seed {root}"
        else:
            sc, config, sensors, exp = self.scenario, self.config, self.sensors, self.experiment
            run_seed = int(rng.integers(0, _SEED_BOUND, dtype=np.uint64))
            estimator = self._next_estimator or self._build_estimator(sc, self._context)
            replay = f"--seed {run_seed}"
        self._next_estimator = None
        self._close_loop()
        # the episode's run: the scenario's (sample's) specification without a controller, the agent acting
        spec = sc.run_spec(None, build=False)
        if self.estimator_kind != sc.estimator:
            spec = replace(spec, estimator=Plugin(self.estimator_kind))
        self.loop = loop = build_loop(spec, estimator=estimator)
        self._episode = (sc, config, exp.targets)
        self._begin_episode(exp.targets)
        self._held[:] = [0.0] * 11
        loop.reset(run_seed)
        self._last_truth = tr0 = loop.truth
        self._start, self._path = (tr0.x, tr0.y, tr0.alpha), [(tr0.x, tr0.y)]
        sets = "".join(f" --set {shlex.quote(o)}" for o in self.overrides)
        if self.estimator_kind != self.scenario.estimator:
            sets += f" --set {shlex.quote('sensors.estimator=' + _toml_value(self.estimator_kind))}"
        info.update(t=0.0, status=loop.status, truth=loop.truth, seed=run_seed, scenario=sc.name,
                    replay=f"twin run {shlex.quote(self._scenario_arg)} {replay}{sets}")
        return self._observe(), info

    def step(self, action):
        loop = self.loop
        if loop is None:
            raise TwinError("call reset() before step()")
        t = self.max_torque
        try:
            ul, ur = action  # an array of shape (2,), a list or a tuple
            ul, ur = float(ul), float(ur)
        except (TypeError, ValueError):
            what = ("the two wheel torques as fractions of max_torque, (ul, ur) / τ_max in [-1, 1]"
                    if self.normalize_actions else "the two wheel torques (ul, ur) in N·m")
            raise TwinError(f"action must be {what}, got {action!r}") from None
        if self.normalize_actions:  # clip to [-1, 1], then to N·m (NaN passes through, as below)
            ul = t if ul > 1.0 else (-t if ul < -1.0 else ul * t)
            ur = t if ur > 1.0 else (-t if ur < -1.0 else ur * t)
        else:
            ul = t if ul > t else (-t if ul < -t else ul)  # NaN passes through: the loop rejects it in one line
            ur = t if ur > t else (-t if ur < -t else ur)
        loop.step((ul, ur))
        status = loop.status
        terminated = status != "running"
        truncated = not terminated and loop.k >= self.n_steps
        truth = loop.truth
        info = {"t": loop.k / self.control_rate, "status": status, "truth": truth, "command": (ul, ur)}
        if status == "diverged":
            obs = self._last_obs.copy()  # the state is not finite: the previous observation
            reward = self._diverged_reward(info)
        else:
            obs = self._observe()
            reward = self._reward(truth, ul, ur, 0.0 if terminated else 1.0, info)
        if terminated:
            info["reason"] = loop.end_reason
        return obs, reward, terminated, truncated, info

    def _warn_if_time_limit_is_shorter(self) -> None:
        """Made by ``gymnasium.make`` from an id whose registered ``max_episode_steps`` is less
        than this scenario's :attr:`n_steps`: its TimeLimit would end episodes early (a
        ``max_episode_steps=`` given to ``make`` is not visible here, hence a warning)."""
        spec = self.spec
        if spec is None or spec.id not in gymnasium.registry:
            return
        limit = gymnasium.registry[spec.id].max_episode_steps
        if limit is not None and limit < self.n_steps:
            gymnasium.logger.warn(
                f"{spec.id}: the scenario lasts {self.n_steps} steps ({self.scenario.duration:g} s at "
                f"{self.control_rate:g} Hz), more than the registered max_episode_steps={limit}: gymnasium.make's "
                f"TimeLimit truncates episodes at step {limit} unless it was given max_episode_steps={self.n_steps} "
                f"(or -1, no TimeLimit)")

    def _diverged_reward(self, info: dict) -> float:
        """alive 0 and every cost at its cap of 1."""
        info["alive"] = 0.0
        for k in self.weights:
            info["cost_" + k] = 1.0
        return -sum(self.weights.values())

    # ---- rendering -----------------------------------------------------------------------------
    def render(self):
        """The current true state as an (H, W, 3) uint8 RGB picture (``render_mode="rgb_array"``);
        None without a render mode."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() was called without a render_mode; make the environment with "
                                  "render_mode='rgb_array'")
            return None
        if self.loop is None:
            raise TwinError("call reset() before render()")
        sc, config, targets = self._episode
        tr = self.loop.truth
        if math.isfinite(tr.theta + tr.alpha + tr.x + tr.y + tr.psi_l + tr.psi_r + tr.roll):
            self._last_truth = tr
        else:  # diverged: the last finite state that was pictured (or the initial one)
            tr = self._last_truth
        scene = self._scene_for(config)
        frame = scene.render(tr.theta, tr.alpha, tr.x, tr.y, tr.psi_l, tr.psi_r, tr.roll)
        if self.hud:
            frame = self._draw_hud(frame, tr, sc, targets, scene, config)
        return frame

    def _scene_for(self, config):
        d = config.disturbances
        key = (config.params, config.ground, d.payload, d.com_offset)  # what the picture depends on
        scene = self._scene
        if scene is None or key != self._scene_key:  # a scene is rebuilt for another robot or floor
            self._close_scene()
            # the camera scaled to the robot's size (the paper's robot: the default camera, exactly)
            scale = robot_scale(self.scenario.model(), config.body)
            camera = None if scale == 1.0 else camera_mode("turning", scale=scale)
            self._scene = Scene(config, self.render_size, self.renderer, camera)
            self._scene_key = key
        return self._scene

    def _close_scene(self) -> None:
        scene, self._scene = self._scene, None
        if scene is not None:
            scene.close()

    def _draw_hud(self, frame, tr, sc, targets, scene, config):
        """The overlay, as a ``twin run`` video draws it: the floor markers (the start, the path
        since through the axle's places at reset and when pictured, a centimetre apart at
        least; the targets), then the text and its key."""
        from types import SimpleNamespace

        loop = self.loop
        ended, alarm = "", False
        if loop.status != "running":
            ended, alarm = f"{loop.status.upper()} at {loop.t:.2f} s", True
        elif loop.k >= self.n_steps:
            ended = f"END at {loop.t:.2f} s"
        label = f"{self.spec.id if self.spec is not None else type(self).__name__}  {sc.name}"
        bgr = np.ascontiguousarray(frame[:, :, ::-1])
        box = body_box(config.params, config.body)
        track = SimpleNamespace(p_d=targets.position, alpha_d=targets.heading, r=config.params.r, box=box,
                                body_top=box[1][2], start=self._start)
        last = self._path[-1]
        if math.hypot(tr.x - last[0], tr.y - last[1]) >= PATH_STEP_M:  # a point a centimetre on, at least
            self._path.append((tr.x, tr.y))
        xy = np.asarray(self._path + [(tr.x, tr.y)], dtype=float)  # the path kept, and where the robot is
        n = len(xy)
        now = {"alpha": tr.alpha, "roll": tr.roll, "theta": tr.theta, "distance": tr.distance,
               "push_fx": 0.0, "push_fy": 0.0, "push_fz": 0.0}  # the push is not shown (nor keyed)
        samples = {"x": xy[:, 0], "y": xy[:, 1], **{k: np.full(n, v) for k, v in now.items()}}
        draw_markers(bgr, scene, track, samples, n - 1)
        draw_hud(bgr, HudState(label, loop.t, tr.theta, tr.distance, tr.alpha, targets.position, targets.heading,
                               ended, alarm, from_start=from_start(track, samples, n - 1)))
        return np.ascontiguousarray(bgr[:, :, ::-1])

    # ---- life cycle ----------------------------------------------------------------------------
    def _close_loop(self) -> None:
        if self.loop is not None:
            self.loop.close()
            self.loop = None

    def close(self) -> None:
        """Release the twin's PyBullet client and the render scene's (safe to call twice)."""
        self._close_loop()
        self._close_scene()


def _fps(rate: float):
    return int(rate) if float(rate).is_integer() else float(rate)


__all__ = ["ANGLE_LIMIT", "OBS_MODES", "PITCH_LIMIT", "POSITION_LIMIT", "RATE_LIMIT", "TwinEnv"]
