"""The fit: parameters and window start states by nonlinear least squares.

Unknowns: the chosen parameters (:mod:`twin.calibrate.parameters`) and, per window
(:mod:`twin.calibrate.windows`), its start state θ, θ̇, ψ̇, α̇ and the two encoder offsets (ψ and
α do not enter the dynamics). Residuals: each reading minus the model's
(:mod:`twin.calibrate.readings` along :func:`twin.calibrate.model.step_windows`), divided by the
reading's white-noise σ, so that the cost is a χ² for white noise. Where the log holds the motor
current (``Windows.current``), its samples join them: the model's current at the end of each
period is :func:`twin.actuators.dc_motor.steady_current` of that period's duty and the shaft
speed then, i = τ_s (d ω_0 − ω) / V_s. A current measures the torque in N·m (τ = k_t i), which
the duty gives only through the motor's figures: with it the stall torque τ_s and the no-load
speed ω_0 are read off the drive directly, no longer traded against the body's mass and
inertias (τ_s) or the drive's damping d_b (ω_0). Without the channel the residuals are exactly
the IMU's and the encoders'.

Solver: :func:`scipy.optimize.least_squares` (trust-region reflective, ``x_scale="jac"``) with
the Jacobian's sparsity given (a window's residuals depend on the parameters and its own six
states only): finite differences then cost one model run per parameter plus six, whatever the
number of windows, and the trust-region steps are solved by LSMR. Physical parameters are fitted
as the logarithms of their factors of the log's model (positive by construction), sensor
constants as themselves.

Uncertainty (:func:`covariance`): the window states are eliminated per window (the Schur
complement through a QR of each window's state Jacobian), leaving the parameters' Gauss–Newton
information H; the covariance is s² H⁻¹ (s² the residual variance per degree of freedom), and
the cluster-robust "sandwich" H⁻¹ B H⁻¹ with the windows' score vectors grouped into
:data:`CLUSTER_S` of consecutive log, which holds when the residuals are correlated within a
cluster (a drifting bias, model error) rather than white.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from twin.actuators.dc_motor import steady_current
from twin.calibrate.model import step_windows
from twin.calibrate.parameters import PARAMETERS
from twin.calibrate.readings import encoder_angles, imu_readings
from twin.calibrate.windows import Windows
from twin.errors import TwinError

PLANT_NAMES = ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w")
MOTOR_NAMES = ("stall_torque", "no_load_speed")
SENSOR_NAMES = ("gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "accel_bias_x", "gyro_scale_y", "gyro_scale_z",
                "accel_scale_x", "accel_scale_z")
CURRENT_NAMES = ("current_offset_l", "current_offset_r")  # the current sensor's offsets (A), with the channel
STATE_COLUMNS = (0, 1, 3, 5)  # θ, θ̇, ψ̇, α̇ of a window's start state are fitted; ψ, α stay the EKF's
CLUSTER_S = 1.0  # s of log per cluster of the sandwich covariance and the bootstrap (0: each window its own)
TOLERANCE = 1e-8  # scipy's xtol, ftol, gtol: relative changes well below the intervals (about 1e-3)
OUTLIER_ALPHA = 0.01  # family-wise level of the windows' χ² test (a push, a bump, a start transient)


class Plant:
    """The model of one log: its robot (:attr:`SensorLog.model`), motors, IMU position and
    rates, and which parameters are fitted (``names``, continuous ones; order of the registry)."""

    def __init__(self, log, names, physics_rate: float, fixed: dict | None = None):
        self.names = tuple(names)
        self.fixed = dict(fixed or {})  # values (absolute SI) of parameters held other than at the log's model
        self.model = log.model
        self.motor = log.motor
        self.physics_rate = float(physics_rate)
        self.control_rate = float(log.control_rate)
        self.position = tuple(log.sensors.imu.position)
        self.b_r = log.model.b / log.model.r
        for n in self.names:
            if n not in PARAMETERS or n == "imu_latency":
                raise TwinError(f"{n!r} is not a continuous parameter of the fit")
            if n in MOTOR_NAMES and self.motor is None:
                raise TwinError(f"{n} needs DC motors; the log's robot has ideal torque sources")

    def base(self, name: str) -> float:
        if name in PLANT_NAMES:
            return float(getattr(self.model, name))
        if name in MOTOR_NAMES:
            return float(getattr(self.motor, name))
        return 0.0

    def scaled(self, name: str) -> bool:
        """Fitted as the logarithm of its factor of the log's model, ln(value / model's): the
        positive physical parameters (so that no trial step makes a mass or a damping negative; a
        zero-bound parameter such as d_b otherwise stalls the trust region at the bound)."""
        return name in PLANT_NAMES or name in MOTOR_NAMES

    def values(self, p) -> dict:
        """Every parameter's value (absolute SI) for the fitted vector ``p``; the others at the
        log's model (sensor constants at zero)."""
        v = {n: self.base(n) for n in PLANT_NAMES + SENSOR_NAMES + CURRENT_NAMES}
        if self.motor is not None:
            v.update({n: self.base(n) for n in MOTOR_NAMES})
        v.update({n: x for n, x in self.fixed.items() if n in v})
        for n, x in zip(self.names, p):
            v[n] = self.to_value(n, x)
        return v

    def held(self, p) -> "Plant":
        """This plant with every parameter held at the values of ``p`` (none fitted)."""
        import copy

        out = copy.copy(self)
        out.names, out.fixed = (), self.values(p)
        return out

    def p0(self) -> np.ndarray:
        return np.zeros(len(self.names))

    def to_value(self, name: str, x: float) -> float:
        return self.base(name) * math.exp(float(x)) if self.scaled(name) else float(x)

    def from_value(self, name: str, value: float) -> float:
        """The fitted coordinate of a value (:meth:`to_value`'s inverse)."""
        return math.log(value / self.base(name)) if self.scaled(name) else float(value)

    def robot(self, v: dict):
        m = self.model
        changes = {n: v[n] for n in PLANT_NAMES}
        changes["n_xb"] = m.n_xb * v["n_yb"] / m.n_yb  # the roll inertia scaled with the pitch one
        return m.replace(**changes)

    def motors(self, v: dict):
        if self.motor is None:
            return None
        from dataclasses import replace

        return replace(self.motor, stall_torque=v["stall_torque"], no_load_speed=v["no_load_speed"])

    def predict(self, w: Windows, v: dict, S: np.ndarray, offsets: np.ndarray, current: bool = False):
        """(imu (W, N, 5), encoder angles (W, N + 1, 2)) of windows ``w`` from full start states
        ``S`` (W, 6) and encoder offsets (W, 2), for parameter values ``v``; with ``current``, a
        third: the motor current (W, N, 2) A at the end of each period (None where the windows have
        no current or the drive is not a duty through DC motors)."""
        motor = self.motors(v)
        X = step_windows(S, w.drive, self.robot(v), motor, self.physics_rate, self.control_rate,
                         drive_is_duty=w.streams.drive_is_duty)
        imu = imu_readings(X, 1.0 / self.control_rate, self.position, self.model.r, self.model.g,
                           (v["gyro_bias_x"], v["gyro_bias_y"], v["gyro_bias_z"]),
                           (0.0, v["gyro_scale_y"], v["gyro_scale_z"]), (v["accel_bias_x"], 0.0),
                           (v["accel_scale_x"], v["accel_scale_z"]))
        angles = encoder_angles(X, self.b_r, offsets)
        if not current:
            return imu, angles
        cur = motor_current(X, w, motor, self.b_r)
        if cur is not None:  # the sensor's offsets (its gain error is left at 1: see windows.streams)
            cur = cur + np.array([v["current_offset_l"], v["current_offset_r"]])
        return imu, angles, cur


@dataclass
class Fit:
    """A least-squares fit: ``p`` the fitted vector (factors or values, see :class:`Plant`),
    ``values`` every parameter's absolute SI value, ``S`` (W, 6) the windows' start states,
    ``offsets`` (W, 2) rad, ``residuals`` (W, R) in σ units, ``windows`` the windows fitted,
    ``cost`` ½ Σ r², ``nfev`` model runs, ``status`` scipy's."""

    plant: Plant
    windows: Windows
    p: np.ndarray
    values: dict
    S: np.ndarray
    offsets: np.ndarray
    residuals: np.ndarray
    cost: float
    nfev: int
    status: int
    jac: object = field(default=None, repr=False)

    @property
    def window_costs(self) -> np.ndarray:
        return np.sum(self.residuals ** 2, axis=1)


def motor_current(X, w: Windows, motor, b_r: float):
    """(W, N, 2) A: the motors' current at the end of each period of states X (W, N + 1, 6) under
    that period's duty (``w.drive``), left and right; None without a current channel or motors."""
    if w.current is None or motor is None or not w.streams.drive_is_duty:
        return None
    th_d, ps_d, al_d = X[:, 1:, 1], X[:, 1:, 3], X[:, 1:, 5]
    return np.stack([steady_current(motor, w.drive[..., 0], ps_d - b_r * al_d - th_d),
                     steady_current(motor, w.drive[..., 1], ps_d + b_r * al_d - th_d)], axis=-1)


def residual_count(w: Windows) -> int:
    """Residuals per window: 5 IMU channels per period, 2 encoders per instant, and with a current
    channel 2 currents per period."""
    return w.periods * 5 + (w.periods + 1) * 2 + (0 if w.current is None else w.periods * 2)


def _unpack(plant: Plant, w: Windows, z: np.ndarray):
    k = len(plant.names)
    p = z[:k]
    st = z[k:].reshape(w.count, 6)
    S = w.S0.copy()
    S[:, STATE_COLUMNS] = st[:, :4]
    return p, S, st[:, 4:]


def residuals(plant: Plant, w: Windows, p, S, offsets) -> np.ndarray:
    """(W, R): the readings' misfit in σ units, IMU periods first, then encoder instants, then
    (with a current channel) the motor currents per period."""
    v = plant.values(p)
    if w.current is None:
        imu, ang = plant.predict(w, v, S, offsets)
        cur = None
    else:
        imu, ang, cur = plant.predict(w, v, S, offsets, current=True)
    s = w.streams
    ri = (imu - w.imu) / s.imu_sigma
    re = (ang - w.angles) / s.encoder_sigma
    parts = [ri.reshape(w.count, -1), re.reshape(w.count, -1)]
    if w.current is not None:
        # (no motors to compare with: the samples count as fitted exactly, so the residual count holds)
        rc = np.zeros(w.current.shape) if cur is None else (cur - w.current) / s.current_sigma
        parts.append(rc.reshape(w.count, -1))
    return np.concatenate(parts, axis=1)


def sparsity(k: int, W: int, R: int):
    """The Jacobian's structure: every residual depends on the k parameters; window w's R
    residuals on its own 6 states."""
    J = lil_matrix((W * R, k + 6 * W), dtype=np.int8)
    if k:
        J[:, :k] = 1
    for i in range(W):
        J[i * R:(i + 1) * R, k + 6 * i:k + 6 * i + 6] = 1
    return J.tocsr()


def fit(plant: Plant, w: Windows, p0=None, S0=None, offsets0=None, max_nfev: int | None = None) -> Fit:
    """Least squares over the parameters and the windows' start states (see the module docstring)."""
    if w.count == 0:
        raise TwinError("no window to fit")
    k = len(plant.names)
    p0 = plant.p0() if p0 is None else np.asarray(p0, dtype=float)
    S0 = w.S0 if S0 is None else S0
    if offsets0 is None:
        zero = encoder_angles(S0[:, None, :], plant.b_r, np.zeros((w.count, 2)))[:, 0, :]
        offsets0 = w.angles[:, 0, :] - zero
    z0 = np.concatenate([p0, np.column_stack([S0[:, STATE_COLUMNS], offsets0]).ravel()])
    R = residual_count(w)

    def fun(z):
        p, S, off = _unpack(plant, w, z)
        try:
            r = residuals(plant, w, p, S, off).ravel()
        except (TwinError, ValueError, OverflowError):  # a trial step to an invalid plant, or one whose
            return np.full(w.count * R, 1e6)  # windows blow up (sin of an infinite angle): reject it
        if not np.all(np.isfinite(r)):
            r = np.where(np.isfinite(r), r, 1e6)
        return r

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        # unbounded (the physical parameters are positive through their logarithms): reflective
        # steps at a bound cost hundreds of iterations more
        res = least_squares(fun, z0, jac_sparsity=sparsity(k, w.count, R), method="trf", x_scale="jac",
                            tr_solver="lsmr", tr_options={"regularize": False},
                            max_nfev=max_nfev, xtol=TOLERANCE, ftol=TOLERANCE, gtol=TOLERANCE)
    p, S, off = _unpack(plant, w, res.x)
    r = residuals(plant, w, p, S, off)
    return Fit(plant, w, p, plant.values(p), S, off, r, 0.5 * float(np.sum(r ** 2)), int(res.nfev), int(res.status),
               res.jac)


def states_only(plant: Plant, w: Windows, p, S0=None, offsets0=None) -> Fit:
    """The windows' start states and offsets for fixed parameters ``p`` (each window on its own)."""
    fixed = plant.held(p)
    f = fit(fixed, w, p0=np.empty(0), S0=S0, offsets0=offsets0)
    return Fit(plant, w, np.asarray(p, dtype=float), plant.values(p), f.S, f.offsets, f.residuals, f.cost, f.nfev,
               f.status)


def outlier_limit(costs: np.ndarray, residuals_per_window: int) -> float:
    """The window cost (Σ r² in σ units) above which a window is left out.

    For white noise of the σ assumed, a window's cost is χ² with ν = R − 6 degrees of freedom
    (R residuals, 6 start states fitted). The limit is that χ²'s 1 − α/W quantile (Bonferroni over
    the W windows, α = :data:`OUTLIER_ALPHA`: a log that fits has about a 1 % chance of losing any
    window), scaled by the median cost over the χ²'s median, so that a log whose noise is larger
    than its σ says keeps its windows."""
    from scipy.stats import chi2

    nu = residuals_per_window - 6
    W = len(costs)
    return float(np.median(costs) * chi2.isf(OUTLIER_ALPHA / W, nu) / chi2.median(nu))


def trimmed(plant: Plant, w: Windows, p0=None, S0=None, offsets0=None, keep=None, rounds: int = 4):
    """(fit, keep): least squares on the windows whose cost is within :func:`outlier_limit`, the
    set chosen again from every window's cost at each new estimate until it stays (a push drags a
    plain least-squares fit; leaving its windows out, then checking every window against the
    cleaner fit, brings back the ones it wrongly condemned). ``keep`` (W,) bool: the windows to
    start from (default: all)."""
    S = (w.S0 if S0 is None else S0).copy()
    if offsets0 is None:
        offsets0 = w.angles[:, 0, :] - encoder_angles(S[:, None, :], plant.b_r, np.zeros((w.count, 2)))[:, 0, :]
    off = np.asarray(offsets0, dtype=float).copy()
    # the start states first settled for p0 alone: a joint step from states that do not fit p0
    # is dominated by the states' corrections and can throw the parameters far off (a wheel
    # damping of zero from a plant already within 2 %, research for issue 30)
    p0 = plant.p0() if p0 is None else np.asarray(p0, dtype=float)
    settled = states_only(plant, w, p0, S, off)
    S, off = settled.S.copy(), settled.offsets.copy()
    if keep is None:  # a push's windows misfit any plant by far: out before the first fit
        keep = settled.window_costs <= outlier_limit(settled.window_costs, residual_count(w))
    keep = np.asarray(keep, dtype=bool).copy()
    f = fit(plant, w.subset(keep), p0=p0, S0=S[keep], offsets0=off[keep])
    S[keep], off[keep] = f.S, f.offsets
    for _ in range(rounds):
        if keep.all():
            wc = f.window_costs
            S, off = f.S.copy(), f.offsets.copy()
        else:
            every = states_only(plant, w, f.p, S, off)
            S, off, wc = every.S, every.offsets, every.window_costs
        new = wc <= outlier_limit(wc, residual_count(w))
        if np.array_equal(new, keep):
            break
        keep = new
        f = fit(plant, w.subset(keep), p0=f.p, S0=S[keep], offsets0=off[keep])
        S, off = S.copy(), off.copy()
        S[keep], off[keep] = f.S, f.offsets
    return f, keep


@dataclass
class Information:
    """The parameters' information with the window states eliminated: per window ``H_w`` (W, k, k)
    and score ``g_w`` (W, k) = B_wᵀ r_w, ``s2`` the residual variance per degree of freedom,
    ``dof``."""

    H_w: np.ndarray
    g_w: np.ndarray
    s2: float
    dof: int

    @property
    def H(self) -> np.ndarray:
        return np.sum(self.H_w, axis=0)


def information(f: Fit) -> Information:
    """From the fit's Jacobian at the optimum: see the module docstring."""
    k = len(f.plant.names)
    W, R = f.residuals.shape
    J = f.jac.tocsr() if hasattr(f.jac, "tocsr") else np.asarray(f.jac)
    Jp = np.asarray(J[:, :k].todense() if hasattr(J, "todense") else J[:, :k]).reshape(W, R, k)
    Js = np.empty((W, R, 6))
    Jsp = J[:, k:]
    for i in range(W):
        block = Jsp[i * R:(i + 1) * R, 6 * i:6 * i + 6]
        Js[i] = block.toarray() if hasattr(block, "toarray") else block
    Q, _ = np.linalg.qr(Js)
    Bp = Jp - Q @ (np.swapaxes(Q, 1, 2) @ Jp)
    r = f.residuals
    rp = r - (Q @ (np.swapaxes(Q, 1, 2) @ r[..., None]))[..., 0]
    H_w = np.swapaxes(Bp, 1, 2) @ Bp
    g_w = (np.swapaxes(Bp, 1, 2) @ rp[..., None])[..., 0]
    dof = W * R - k - 6 * W
    return Information(H_w, g_w, float(np.sum(r ** 2)) / dof, dof)


def covariance(info: Information, windows: Windows, cluster_s: float = CLUSTER_S):
    """(C_jacobian, C_sandwich, clusters): covariances of the fitted vector (see the module
    docstring); the sandwich's clusters are windows grouped by ``cluster_s`` of log."""
    H = info.H
    Hi = np.linalg.inv(H)
    t0 = windows.t0
    group = _groups(t0, cluster_s)
    G = int(group.max()) + 1
    scores = np.zeros((G, H.shape[0]))
    np.add.at(scores, group, info.g_w)
    used = np.unique(group).size
    B = scores.T @ scores * (used / max(used - 1, 1))
    return info.s2 * Hi, Hi @ B @ Hi, used


def bootstrap(info: Information, windows: Windows, rng: np.random.Generator, replicates: int = 200,
              cluster_s: float = CLUSTER_S) -> np.ndarray:
    """(replicates, k): one Gauss–Newton step from the optimum on clusters of windows resampled
    with replacement (the windows' information and scores at the optimum reweighted by the
    resample's counts); their spread checks the intervals."""
    ids, group = np.unique(_groups(windows.t0, cluster_s), return_inverse=True)
    G, k = len(ids), info.H_w.shape[1]
    Hg = np.zeros((G, k, k))
    gg = np.zeros((G, k))
    np.add.at(Hg, group, info.H_w)
    np.add.at(gg, group, info.g_w)
    out = np.empty((replicates, k))
    for b in range(replicates):
        m = np.bincount(rng.integers(0, G, G), minlength=G).astype(float)
        Hb = np.tensordot(m, Hg, axes=1)
        out[b] = -np.linalg.solve(Hb, m @ gg)
    return out


def _groups(t0: np.ndarray, cluster_s: float) -> np.ndarray:
    if cluster_s <= 0.0:
        return np.arange(len(t0))
    return np.floor((t0 - t0[0]) / cluster_s).astype(int)


def t_quantile(dof: int, q: float = 0.975) -> float:
    from scipy.stats import t

    return float(t.ppf(q, max(dof, 1)))


def correlation(C: np.ndarray) -> np.ndarray:
    sd = np.sqrt(np.diag(C))
    with np.errstate(invalid="ignore", divide="ignore"):
        return C / np.outer(sd, sd)


__all__ = ["CLUSTER_S", "CURRENT_NAMES", "Fit", "Information", "MOTOR_NAMES", "PLANT_NAMES", "Plant", "SENSOR_NAMES", "bootstrap",
           "correlation", "covariance", "fit", "information", "residuals", "t_quantile"]


@dataclass
class Calibration:
    """The outcome: ``fit`` (the final :class:`Fit`), ``info``, covariances
    ``C_jacobian`` and ``C_sandwich`` of the fitted vector, ``boot`` (B, k) the bootstrap's
    vectors, ``clusters``, ``imu_latency`` (periods) and its ``latency_costs``, ``dropped`` the
    start times (s) of the windows left out as outliers, ``wall_s``, ``logs`` the paths."""

    names: tuple
    fit: Fit
    info: Information
    C_jacobian: np.ndarray
    C_sandwich: np.ndarray
    boot: np.ndarray
    clusters: int
    imu_latency: int
    latency_costs: dict
    dropped: list
    windows_total: int
    wall_s: float
    logs: list
    streams: list = field(repr=False, default_factory=list)
    max_turn_rate: float = 0.0
    model_kind: str = "twin"
