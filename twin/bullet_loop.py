"""Closed loop on the PyBullet twin: physics → sensors → estimator → controllers → motors.

Sensing. By default the controllers act on the estimator's output, computed from the
simulated IMU and encoders (:mod:`twin.sensors`, :mod:`estimation`); ``sensors=None``
asks for ideal sensing (the controllers read the ground truth), kept as a reference.

Logged at the control rate: row i holds the ground truth at t_i, what the controllers
were given at t_i (``estimates``), the command computed from it, and what the motors
delivered and the pushes did over [t_i, t_i+1) (period means). A run that falls stops at
the row where that was detected; its last row's actuation is zero, because nothing was
applied after it. A run that diverges (a non-finite state from the physics) stops at the
last finite row: no NaN is logged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from estimation import ESTIMATORS
from twin.analytic_loop import Experiment
from twin.controllers.cascade import FuzzyCascade
from twin.errors import TwinError
from twin.metrics import settling_time
from twin.params import NOMINAL, RobotParams
from twin.plant.bullet import ACTUATION_UNITS, TRUTH_UNITS, Actuation, BulletTwin, GroundTruth, TwinConfig
from twin.sensors import Measurement, SensorConfig, SensorSuite, imu_kinematics

TRUTH_NAMES = GroundTruth._fields
ESTIMATE_NAMES = ("theta_est", "theta_dot_est", "psi_est", "psi_dot_est", "alpha_est", "alpha_dot_est")
ESTIMATE_UNITS = dict(theta_est="rad", theta_dot_est="rad/s", psi_est="rad", psi_dot_est="rad/s", alpha_est="rad",
                      alpha_dot_est="rad/s")
COMMAND_NAMES = ("ul_cmd", "ur_cmd", "u", "theta_off", "u_alpha")
COMMAND_UNITS = dict(ul_cmd="N·m", ur_cmd="N·m", u="N·m", theta_off="rad", u_alpha="N·m")
ACTUATION_NAMES = Actuation._fields
PUSH_NAMES = ("push_fx", "push_fy", "push_fz")
PUSH_UNITS = dict(push_fx="N", push_fy="N", push_fz="N")


@dataclass
class TwinRun:
    """A closed-loop trajectory on the twin (see the module docstring for the row layout).

    ``truth`` (n, 15) columns :data:`TRUTH_NAMES`; ``estimates`` (n, 6)
    :data:`ESTIMATE_NAMES`, the state the controllers were given; ``commands`` (n, 5)
    :data:`COMMAND_NAMES`; ``actuation`` (n, 6) :data:`ACTUATION_NAMES`; ``push`` (n, 3)
    N, world frame. ``status`` is "ok" (ran its duration), "fell" or "diverged".
    ``sensing`` is "ideal" or the estimator's name; ``measurements`` what reached the
    estimator at each step; ``estimator_stats`` its counts (rejected measurements,
    resets, events); ``gyro_bias`` (n, 3) rad/s the gyro's true bias in the sample taken
    at each step (NaN without one); ``sensor_truth`` the sensors' drawn constants (scale
    factors, turn-on biases, encoder phases); ``sensor_config`` and ``model_params`` what the
    run was given; ``filter_log`` (EKF with ``log_filter``) the
    filter's own state ``x`` (n, 12) and covariance ``P`` (n, 12, 12) at t_{i − lag} (see
    :mod:`estimation.ekf`), and the encoder update's ``nis`` (n,) (NaN where none was tried) with its degrees of freedom
    ``nis_dof`` (n,) (the number of wheels whose count changed; 0 where none was tried).
    """

    t: np.ndarray
    truth: np.ndarray
    commands: np.ndarray
    actuation: np.ndarray
    push: np.ndarray
    status: str
    end_reason: str
    config: TwinConfig = field(repr=False)
    experiment: Experiment | None = None
    controller: str = ""
    estimates: np.ndarray | None = None
    sensing: str = "ideal"
    measurements: list = field(default_factory=list, repr=False)
    estimator_stats: dict = field(default_factory=dict)
    sensor_counts: dict = field(default_factory=dict)
    gyro_bias: np.ndarray | None = field(default=None, repr=False)
    filter_log: dict | None = field(default=None, repr=False)
    seed: int | None = None
    sensor_truth: dict = field(default_factory=dict, repr=False)
    sensor_config: SensorConfig | None = field(default=None, repr=False)
    model_params: RobotParams | None = field(default=None, repr=False)

    @property
    def fell(self) -> bool:
        return self.status != "ok"

    def signal(self, name: str) -> np.ndarray:
        """One logged signal by name (truth, estimate, command, actuation or push column)."""
        for names, data in ((TRUTH_NAMES, self.truth), (ESTIMATE_NAMES, self.estimates),
                            (COMMAND_NAMES, self.commands), (ACTUATION_NAMES, self.actuation),
                            (PUSH_NAMES, self.push)):
            if name in names:
                return data[:, names.index(name)]
        raise TwinError(f"no signal {name!r}; signals: {', '.join(self.signal_names())}")

    @staticmethod
    def signal_names() -> tuple[str, ...]:
        return TRUTH_NAMES + ESTIMATE_NAMES + COMMAND_NAMES + ACTUATION_NAMES + PUSH_NAMES

    @staticmethod
    def signal_units() -> dict[str, str]:
        return {**TRUTH_UNITS, **ESTIMATE_UNITS, **COMMAND_UNITS, **ACTUATION_UNITS, **PUSH_UNITS}

    @property
    def distance(self) -> np.ndarray:
        """Travelled distance p = r ψ in m."""
        return self.signal("distance")

    @property
    def total_torque(self) -> np.ndarray:
        """Torque delivered by both motors, N·m."""
        return self.signal("torque_l") + self.signal("torque_r")

    def columns(self) -> tuple[list[str], list[str], np.ndarray]:
        """(names, units, data (n, k)) of everything logged, for CSV files."""
        names = list(self.signal_names())
        units = [self.signal_units()[n] for n in names]
        return names, units, np.column_stack([self.truth, self.estimates, self.commands, self.actuation, self.push])

    def settling_time(self, tol: float = 0.01) -> float:
        """First time (s) after which |θ| stays below ``tol`` rad; inf if it never does or fell."""
        if self.fell:
            return math.inf
        return settling_time(self.t, self.signal("theta"), tol)

    def estimation_rmse(self, name: str = "theta", start: float = 0.0) -> float:
        """RMS of (estimate − truth) of ``name`` (θ, θ̇, ψ, ψ̇, α or α̇) from ``start`` s on."""
        keep = self.t >= start - 1e-9
        err = self.signal(name + "_est")[keep] - self.signal(name)[keep]
        from twin.metrics import exact_mean

        return math.sqrt(exact_mean(err * err)) if err.size else math.nan

    def summary(self) -> dict:
        e = self.experiment
        out = {
            "controller": self.controller,
            "sensing": self.sensing,
            "status": self.status,
            "end_reason": self.end_reason,
            "duration_s": float(self.t[-1]),
            "settling_time_s": self.settling_time(),
            "final_theta_rad": float(self.signal("theta")[-1]),
            "max_abs_torque_nm": float(np.max(np.abs(self.actuation[:, 2:4]))),
            "saturated_fraction": float(np.mean(self.actuation[:-1, 4:6] > 0)) if len(self.t) > 1 else 0.0,
            "final_distance_m": float(self.signal("distance")[-1]),
            "final_heading_rad": float(self.signal("alpha")[-1]),
            "estimator_theta_rmse_rad": self.estimation_rmse("theta"),
            "rejected_measurements": int(self.estimator_stats.get("rejected_total", 0)),
        }
        if e is not None and e.p_d is not None:
            out["final_position_error_m"] = out["final_distance_m"] - e.p_d
        if e is not None and e.alpha_d is not None:
            out["final_heading_error_rad"] = out["final_heading_rad"] - e.alpha_d
        return out


def simulate_twin(controller: FuzzyCascade, experiment: Experiment, config: TwinConfig | None = None,
                  duration: float | None = None, controller_name: str = "", alpha0: float = 0.0,
                  position=(0.0, 0.0), sensors: SensorConfig | None = SensorConfig(), estimator: str = "ekf",
                  seed: int = 0, model_params: RobotParams = NOMINAL, log_filter: bool = False,
                  progress=None) -> TwinRun:
    """Run ``controller`` on a new twin built from ``config`` from the experiment's θ0.

    Parameters
    ----------
    sensors : SensorConfig or None
        The IMU, encoders and faults; None: ideal sensing (the controllers read the truth).
    estimator : str
        One of :data:`ESTIMATORS`: what turns the readings into the controllers' state.
    seed : int
        The run's seed: the sensors' noise and faults are drawn from it (and nothing else).
    model_params : RobotParams
        The robot the estimator assumes (the controllers' nominal model by default).
    log_filter : bool
        Keep the EKF's own state, covariance and NIS at every step (``filter_log``).
    progress : callable or None
        ``progress(steps_done, steps_total)``, called once per simulated second and at the end.

    The twin is closed when the run ends, fallen or not.
    """
    config = config if config is not None else TwinConfig()
    duration = experiment.duration if duration is None else float(duration)
    control_dt = 1.0 / config.control_rate
    if not (math.isfinite(duration) and duration >= control_dt):
        raise TwinError(f"duration must be at least one control period ({control_dt:g} s), got {duration:g} s")
    if sensors is not None and not isinstance(sensors, SensorConfig):
        raise TwinError(f"sensors must be a SensorConfig or None (ideal sensing), got {sensors!r}")
    if sensors is not None:
        sensors.steps(config.control_rate)  # rates and latencies fit the control period: check before building
    if estimator not in ESTIMATORS:
        raise TwinError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TwinError(f"seed must be a non-negative integer, got {seed!r}")
    n_ctrl = int(round(duration / control_dt))
    report_every = max(1, int(round(config.control_rate)))
    n_rows = n_ctrl + 1
    # rows collected as tuples (cheaper per step than writing numpy rows), stacked at the end
    truth, est, cmds, act, push = [], [], [], [], []
    p_d, alpha_d = experiment.p_d, experiment.alpha_d
    ideal = sensors is None
    meas_log: list[Measurement] = []
    bias_log = None if ideal else np.full((n_rows, 3), np.nan)
    flog = None
    with BulletTwin(config, theta0=experiment.theta0, alpha0=alpha0, position=position) as twin:
        tr = twin.truth
        if not ideal:
            from estimation import build_estimator

            suite = SensorSuite(sensors, config.control_rate, np.random.default_rng(np.random.SeedSequence(seed)))
            filt = build_estimator(estimator, sensors, config.control_rate, config.motor, model_params, alpha0)
            com = twin._com_local
            imu_pos = sensors.imu.position
            lever = (imu_pos[0] - com[0], imu_pos[1] - com[1], imu_pos[2] - com[2])
            g = config.params.g
            imu_dt = suite.every * control_dt
            last_imu = pose, vel = twin.kinematics  # the body at rest before t = 0
            gyro, accel = imu_kinematics(pose, vel, pose, vel, imu_dt, lever, g)
            suite.start(gyro, accel, tr.psi_l - tr.theta, tr.psi_r - tr.theta)
            if log_filter and estimator == "ekf":
                nx = len(filt.x)
                flog = {"x": np.full((n_rows, nx), np.nan), "P": np.full((n_rows, nx, nx), np.nan),
                        "nis": np.full(n_rows, np.nan), "nis_dof": np.zeros(n_rows, dtype=int), "lag": filt.lag}
        n = n_rows
        c = None
        for i in range(n_rows):
            if twin.status == "diverged":
                n = i  # the non-finite state is not logged: the log ends with the last finite one
                break
            truth.append(tr)
            if ideal:
                state = tr.state6()
            else:
                if i % suite.every == 0:
                    if i > 0:
                        gyro, accel = imu_kinematics(*twin.kinematics, *last_imu, imu_dt, lever, g)
                        last_imu = twin.kinematics
                    bias_log[i] = suite.gyro.bias
                meas = suite.read(i, gyro, accel, tr.psi_l - tr.theta, tr.psi_r - tr.theta)
                meas_log.append(meas)
                state = filt.start(meas) if i == 0 else filt.step(meas, (c.ul, c.ur))
                if flog is not None:
                    flog["x"][i] = filt.x
                    flog["P"][i] = filt.P
                    flog["nis"][i] = filt.last_nis
                    flog["nis_dof"][i] = filt.last_dof
                    filt.last_nis, filt.last_dof = math.nan, 0
            est.append(state)
            c = controller(state, p_d, alpha_d)
            cmds.append((c.ul, c.ur, c.u, c.theta_off, c.u_alpha))
            if i == n_ctrl or twin.status != "running":
                n = i + 1
                break
            if progress is not None and i % report_every == 0 and i:
                progress(i, n_ctrl)
            tr = twin.step(c.ul, c.ur)
            act.append(twin.actuation)
            push.append(twin.push_force)
        status = "ok" if twin.status == "running" else twin.status
        reason = "" if status == "ok" else twin.end_reason
        if progress is not None:
            progress(n_ctrl, n_ctrl)
    truth = np.array(truth[:n], dtype=float).reshape(n, len(TRUTH_NAMES))
    est = np.array(est[:n], dtype=float).reshape(n, len(ESTIMATE_NAMES))
    cmds = np.array(cmds[:n], dtype=float).reshape(n, len(COMMAND_NAMES))
    # the last row's actuation is zero: nothing was applied after it
    act = np.array(act[:n] + [(0.0,) * len(ACTUATION_NAMES)] * (n - len(act[:n])), dtype=float).reshape(
        n, len(ACTUATION_NAMES))
    push = np.array(push[:n] + [(0.0,) * 3] * (n - len(push[:n])), dtype=float).reshape(n, 3)
    t = truth[:, 0].copy()
    if flog is not None:
        for key in ("x", "P", "nis", "nis_dof"):
            flog[key] = flog[key][:n]
    return TwinRun(t, truth, cmds, act, push, status, reason, config, experiment, controller_name,
                   estimates=est, sensing="ideal" if ideal else estimator, measurements=meas_log[:n],
                   estimator_stats={} if ideal else filt.stats(), sensor_counts={} if ideal else suite.fault_counts(),
                   gyro_bias=None if ideal else bias_log[:n], filter_log=flog, seed=None if ideal else int(seed),
                   sensor_truth={} if ideal else suite.truth(), sensor_config=sensors, model_params=model_params)
