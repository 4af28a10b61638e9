"""``twin calibrate``'s procedure: logs in, fitted parameters with their intervals out.

By default (:func:`model_for`) the robot's continuous equations fit its physical parameters
(:mod:`twin.calibrate.robot`); a log the twin wrote itself is fitted by the twin's own stepping,
the procedure below (one log):

1. The log on its control instants, the EKF replayed on it for the windows' first start states
   (:mod:`twin.calibrate.windows`).
2. Stage 0: the IMU's biases alone, the plant at the log's model (from biases at zero, the first
   plant fit can fall into a far minimum: a body 80 % lighter on one of twenty test robots).
3. Stage 1: the body, the friction and the biases, by χ²-trimmed least squares
   (:func:`twin.calibrate.fit.trimmed`: windows a push or a bump spoils are left out, the set
   chosen again at each estimate).
4. The IMU latency, if fitted: for each whole number of periods in :data:`LATENCIES`, the biases
   and start states refitted on :data:`PROFILE_WINDOWS` windows; the lowest cost wins (a latency
   is a shift of the samples, not a smooth parameter).
5. Stage 2: every chosen parameter (the scale factors and the yaw inertia join), trimmed again,
   from stage 1's estimate and windows.
6. Intervals: :func:`twin.calibrate.fit.covariance` and the bootstrap over windows;
   identifiability (:mod:`twin.calibrate.identify`).

A log with the motor current (:attr:`twin.logs.format.SensorLog.channels`) adds its samples to
every stage's residuals (:func:`twin.calibrate.fit.residuals`) and the sensor's two offsets
(:data:`twin.calibrate.fit.CURRENT_NAMES`) to every stage's parameters, and by default the
motors' stall torque and no-load speed are fitted too: the current measures the torque, which
tells them apart from the body's mass and from d_b (without it they are confounded, see
:func:`default_names`). A log without the channel is calibrated exactly as before.
"""
from __future__ import annotations

import time

import numpy as np

from twin.calibrate import fit as F
from twin.calibrate.fit import Calibration  # noqa: F401  (twin.calibrate.run.Calibration, as before)
from twin.calibrate.parameters import PARAMETERS
from twin.calibrate.robot import calibrate_robot, twin_lags, window_periods
from twin.calibrate.windows import WINDOW_PERIODS, cut, streams
from twin.errors import TwinError

LATENCIES = (0, 1, 2, 3)  # control periods tried for the IMU latency
MIN_WINDOWS = 50  # windows (5 s of usable log at 200 Hz) below which a log excites nothing reliably
TURN_RATE = 0.2  # rad/s: a log whose |α̇| never reaches this does not excite the yaw inertia
STAGE1 = ("m_b", "l", "n_yb", "d_b", "d_w", "gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "accel_bias_x")
BOOTSTRAP = 200  # cluster-bootstrap replicates
PROFILE_WINDOWS = 40  # windows the IMU latency's profile is computed on


def default_names(logs) -> tuple[str, ...]:
    """What is fitted without ``--parameters``: the body (m_b, l, n_yb), the friction (d_b, d_w), the
    yaw inertia where a log turns, and the IMU's biases, scale factors and latency. The motors'
    figures are not: the stall torque trades against the body's mass and inertias (only the wheels'
    fixed mass tells them apart; correlation 0.99 and more) and the no-load speed against d_b (both
    are damping of the joint). Fit them with ``--parameters`` once the body's mass is known (weighed
    and entered in the log's [robot] table), or record the motor current: with it (``logs`` whose
    streams all carry it) they are fitted by default, with the current sensor's offsets."""
    turns = any(float(np.nanmax(np.abs(s.estimates[:, 5]))) >= TURN_RATE for s in logs)
    plant = ("m_b", "l", "n_yb") + (("n_zb",) if turns else ()) + ("d_b", "d_w")
    current = bool(logs) and all(getattr(s, "current", None) is not None for s in logs)
    return plant + (F.MOTOR_NAMES if current else ()) + F.SENSOR_NAMES + ("imu_latency",) + (
        F.CURRENT_NAMES if current else ())




def check_names(names, logs, log_objs):
    turns = max(float(np.nanmax(np.abs(s.estimates[:, 5]))) for s in logs)
    for n in names:
        p = PARAMETERS[n]
        if p.group == "motor":
            if any(lg.motor is None for lg in log_objs):
                raise TwinError(f"--parameters {n}: the log's robot has ideal torque sources (no motor figures); "
                                f"allowed without motors: " + ", ".join(k for k, v in PARAMETERS.items()
                                                                         if v.group != "motor"))
            if n == "dead_band":
                raise TwinError("--parameters dead_band: a log's duty.csv holds the duty after the dead band, so "
                                "the log cannot show it; measure it on the bench (the smallest duty that turns "
                                "the wheel)")
    return turns


MODELS = ("auto", "physical", "twin")


def model_for(log_objs, model: str = "auto") -> str:
    """Which model fits ``log_objs``: ``"physical"`` (the robot's continuous equations,
    :mod:`twin.calibrate.robot`) or ``"twin"`` (the PyBullet twin's stepping, one log). ``"auto"``:
    the twin's stepping for one log the twin wrote itself (that stepping *is* its robot's dynamics,
    exactly), the physical model for anything else."""
    if model not in MODELS:
        raise TwinError(f"--model must be one of {', '.join(MODELS)}, got {model!r}")
    if model == "auto":
        return "twin" if len(log_objs) == 1 and twin_lags(log_objs[0]) is not None else "physical"
    if model == "twin" and len(log_objs) != 1:
        raise TwinError(f"--model twin fits one log ({len(log_objs)} given): the twin's stepping is fitted to one "
                        f"log at a time; several logs of one robot are fitted by --model physical")
    return model


def calibrate(log_objs, names=None, physics_rate: float | None = None, seed: int = 0,
              periods: int | None = None, bootstrap: int = BOOTSTRAP, progress=None, model: str = "auto"):
    """Fit ``names`` (default :func:`default_names`) to the logs (:class:`~twin.logs.format.SensorLog`):
    by the robot's continuous equations (:func:`twin.calibrate.robot.calibrate_robot`, several logs
    of one robot) or by the twin's stepping (one log; :func:`model_for` chooses for ``"auto"``)."""
    if model_for(log_objs, model) == "physical":
        return calibrate_robot(log_objs, names, seed=seed, bootstrap=bootstrap, progress=progress)
    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    log = log_objs[0]
    if periods is None:  # windows sized in seconds (WINDOW_PERIODS at 200 Hz)
        periods = window_periods(log.control_rate)
    if physics_rate is None:
        physics_rate = float(log.scenario.data["rates"]["physics"]) if log.scenario is not None else 1000.0
    st = streams(log)
    all_names = tuple(names) if names is not None else default_names([st])
    if st.current is not None:  # the current sensor's offsets are fitted with its samples, always
        all_names = tuple(n for n in PARAMETERS if n in all_names or n in F.CURRENT_NAMES)
    else:
        dropped_current = [n for n in all_names if n in F.CURRENT_NAMES]
        if dropped_current:
            raise TwinError(f"--parameters {dropped_current[0]}: the log {log.path} holds no motor current (or no DC "
                            f"motors to compare it with); allowed: the current sensor's offsets with a "
                            f"motor_current stream only")
    max_turn = check_names(all_names, [st], log_objs)
    d0 = int(round(log.sensors.imu.latency * log.control_rate))
    w = cut(st, max(LATENCIES) if "imu_latency" in all_names else d0, periods)
    if w.count < MIN_WINDOWS:
        raise TwinError(f"{log.path}: {w.count} windows of {periods / log.control_rate:g} s with every reading; "
                        f"a calibration needs at least {MIN_WINDOWS} ({MIN_WINDOWS * periods / log.control_rate:g} s "
                        f"of log while the robot moves)")
    cont = tuple(n for n in all_names if n != "imu_latency")
    stage1 = tuple(n for n in cont if n in STAGE1 or n in F.CURRENT_NAMES)
    say(f"{w.count} windows of {periods} periods; stage 1: {', '.join(stage1)}")

    def windows_for(d):
        if d == w.imu_latency:
            return w
        # the same start instants for every latency, so that the costs compare
        wd = cut(st, d, periods)
        keep = np.isin(wd.starts, w.starts)
        return wd.subset(keep)

    def carry(prev: F.Fit, plant: F.Plant) -> np.ndarray:
        return np.array([plant.from_value(n, prev.values[n]) for n in plant.names])

    p1 = F.Plant(log, stage1, physics_rate)
    d_first = d0 if ("imu_latency" not in all_names or d0 in LATENCIES) else 1
    # stage 0: the IMU's biases alone, the plant at the log's model; from the biases at zero the
    # first plant fit can fall into a far minimum (a body 80 % lighter, research for issue 30)
    biases = tuple(n for n in stage1 if PARAMETERS[n].group in ("imu", "current"))
    start1 = None
    if biases:
        f0 = F.fit(F.Plant(log, biases, physics_rate), windows_for(d_first))
        start1 = np.array([f0.values[n] if n in biases else 0.0 for n in stage1])
    f1, keep1 = F.trimmed(p1, windows_for(d_first), p0=start1)
    latency, costs = d_first, {}
    if "imu_latency" in all_names:
        # the profile on at most PROFILE_WINDOWS of the kept windows, spread over the log: a
        # period's shift changes the cost by thousands where the noise moves it by tens
        kept = np.flatnonzero(keep1)
        pick = kept[np.linspace(0, len(kept) - 1, min(PROFILE_WINDOWS, len(kept))).round().astype(int)]
        # per latency, only the biases and the start states move (the plant held at stage 1's):
        # a period's shift costs thousands in Σ r², the plant's last refinement tens
        held = F.Plant(log, biases, physics_rate, fixed=f1.values)
        for d in LATENCIES:
            wd = windows_for(d).subset(pick)
            fd = F.fit(held, wd, p0=np.array([f1.values[n] for n in biases]))
            costs[d] = fd.cost
            say(f"IMU latency {d} periods: cost {costs[d]:.1f} on {wd.count} windows")
        latency = min(costs, key=costs.get)
        if latency != d_first:
            f1, keep1 = F.trimmed(p1, windows_for(latency), p0=f1.p)
    w_l = windows_for(latency)
    p2 = F.Plant(log, cont, physics_rate)
    say(f"stage 2: {', '.join(cont)}")
    S1 = w_l.S0.copy()
    if f1.windows.imu_latency == latency:
        S1[keep1] = f1.S
    f3, keep = F.trimmed(p2, w_l, p0=carry(f1, p2), S0=S1, keep=keep1)
    dropped = [float(t) for t in w_l.t0[~keep]]
    w_f = w_l.subset(keep)
    say(f"final fit on {w_f.count} windows ({len(dropped)} left out)")
    info = F.information(f3)
    CJ, CS, G = F.covariance(info, w_f)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    boot = F.bootstrap(info, w_f, rng, bootstrap) if bootstrap else np.empty((0, len(cont)))
    return Calibration(all_names, f3, info, CJ, CS, boot, G, latency, costs, dropped, w.count,
                       time.perf_counter() - t_start, [str(log.path)], [st], max_turn)


__all__ = ["BOOTSTRAP", "Calibration", "LATENCIES", "MIN_WINDOWS", "MODELS", "calibrate", "default_names", "model_for"]
