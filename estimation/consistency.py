"""Is the EKF's covariance honest? Its true state from a twin run, NEES, NIS and the
Monte Carlo χ² tests of Bar-Shalom, Li and Kirubarajan (2001, §5.4).

For one run, the normalised estimation error squared NEES_k = e_kᵀ P_k⁻¹ e_k (e the
filter's state minus the truth) is χ² with n = 12 degrees of freedom if the filter is
consistent; the normalised innovation squared NIS_k of the encoder update is χ² with as
many degrees of freedom as wheels whose count changed. Over N independent runs the
averages at each step, N·NEES̄_k ~ χ²_{N n} and Σ NIS_k ~ χ²_{Σ dof}, have two-sided
bounds; a consistent filter keeps about the confidence level of the steps inside them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2
from scipy.stats import t as t_dist

from twin.errors import TwinError


@dataclass(frozen=True)
class StateTruth:
    """What the EKF's 12-state truth is computed from, on the rows of a run or a log (n rows,
    one per control instant, row 0 the filter's start).

    ``theta``, ``theta_dot``, ``psi_l``, ``psi_r``, ``psi``, ``psi_dot``, ``alpha`` (n,) rad and
    rad/s (wheel angles ψ_l, ψ_r absolute, as the plant's); ``gyro_bias`` (n, 3) rad/s the gyro's
    true bias in the sample taken at each row (NaN without one); the sensors' drawn constants
    ``gyro_scale`` (3,) and ``accel_scale`` (3,) (dimensionless scale-factor errors) and
    ``encoder_phase`` (2,) (where each encoder's first edge lies, in counts); ``imu_position``
    (3,) m; ``wheel_radius`` m the plant's (true) radius; ``b_over_r`` the estimator model's
    half track over wheel radius; ``resolution`` rad per encoder count."""

    theta: np.ndarray
    theta_dot: np.ndarray
    psi_l: np.ndarray
    psi_r: np.ndarray
    psi: np.ndarray
    psi_dot: np.ndarray
    alpha: np.ndarray
    gyro_bias: np.ndarray
    gyro_scale: tuple
    accel_scale: tuple
    encoder_phase: tuple
    imu_position: tuple
    wheel_radius: float
    b_over_r: float
    resolution: float


def run_truth(run) -> StateTruth:
    """The :class:`StateTruth` of a twin run (simulated sensors and a gyro-bias record)."""
    if run.sensor_config is None or not run.sensor_truth or run.gyro_bias is None:
        raise TwinError("the EKF's state truth needs a run with simulated sensors (sensing = \"estimated\")")
    st, cfg, mp = run.sensor_truth, run.sensor_config, run.model_params
    col = {n: run.signal(n) for n in ("theta", "theta_dot", "psi_l", "psi_r", "psi", "psi_dot", "alpha")}
    return StateTruth(**col, gyro_bias=run.gyro_bias, gyro_scale=tuple(st["gyro_scale"]),
                      accel_scale=tuple(st["accel_scale"]), encoder_phase=tuple(st["encoder_phase"]),
                      imu_position=tuple(cfg.imu.position), wheel_radius=float(run.config.params.r),
                      b_over_r=float(mp.b / mp.r), resolution=float(cfg.encoders.resolution))


@dataclass
class FilterRecord:
    """A filter's record that is not a :class:`twin.sim.runs.Run` (for example a replay of a
    sensor log): control instants ``t`` (n,) s, ``filter_log`` as ``Run.filter_log`` (``x``
    (n, 12), ``P`` (n, 12, 12), ``nis`` (n,), ``nis_dof`` (n,), ``lag`` periods) and the
    :class:`StateTruth` on the same rows (None: no NEES, NIS only)."""

    t: np.ndarray
    filter_log: dict
    truth: StateTruth | None = None


def _truth_of(source) -> StateTruth:
    if isinstance(source, FilterRecord):
        if source.truth is None:
            raise TwinError("NEES needs the EKF's state truth, which this record does not have")
        return source.truth
    return run_truth(source)


def filter_truth(source) -> np.ndarray:
    """The true value of each EKF state (n, 12) on the rows of ``source.filter_log["x"]``;
    ``source`` a :class:`twin.sim.runs.Run` or a :class:`FilterRecord`.

    Row i is the truth at t_{i − lag}, the filter's own time; the first lag + 1 rows are
    NaN. The encoder zeros are the values that make the filter's measurement equations
    exact: with q_j = ψ_j − θ the wheel angles relative to the body and φ_j the position
    of each encoder's first edge (counts), c = ē − (ψ − θ) and h = ẽ − (b/r)(α − α_0),
    where ē, ẽ are the mean and half-difference of the unquantised readings
    q_j − q_j(0) + (φ_j − ½)Δ (b/r of the estimator's model).
    """
    if source.filter_log is None:
        raise TwinError("filter_truth needs a run with the EKF and log_filter=True")
    return state_matrix(_truth_of(source), source.filter_log["lag"])


def state_matrix(s: StateTruth, lag: int) -> np.ndarray:
    """:func:`filter_truth` from a :class:`StateTruth` and the filter's ``lag`` (periods)."""
    n = len(s.theta)
    xi, _, zi = s.imu_position
    th = s.theta
    dz = -xi * np.sin(th) + zi * np.cos(th)
    delta = s.resolution
    ql, qr = s.psi_l - th, s.psi_r - th
    el = ql - ql[0] + (s.encoder_phase[0] - 0.5) * delta
    er = qr - qr[0] + (s.encoder_phase[1] - 0.5) * delta
    alpha0 = s.alpha[0]
    bias = s.gyro_bias
    gs, acs = s.gyro_scale, s.accel_scale
    x = np.column_stack([
        th, s.psi, s.wheel_radius * s.psi_dot + s.theta_dot * dz, s.alpha, bias[:, 1], bias[:, 2],
        0.5 * (el + er) - (s.psi - th), np.full(n, gs[1]), 0.5 * (er - el) - s.b_over_r * (s.alpha - alpha0),
        np.full(n, gs[2]), np.full(n, acs[0]), np.full(n, acs[2])])
    out = np.full_like(x, np.nan)
    out[lag + 1:] = x[1:n - lag]
    return out


def nees(source) -> np.ndarray:
    """NEES (n,) of the EKF at each row (NaN where the truth is not defined); ``source`` a
    :class:`twin.sim.runs.Run` or a :class:`FilterRecord`."""
    x, P = source.filter_log["x"], source.filter_log["P"]
    e = x - filter_truth(source)
    ok = np.isfinite(e).all(axis=1)
    out = np.full(len(e), np.nan)
    out[ok] = np.einsum("ti,ti->t", e[ok], np.linalg.solve(P[ok], e[ok][..., None])[..., 0])
    return out


def monte_carlo(runs, start: float = 0.0, confidence: float = 0.95) -> dict:
    """The two-sided χ² tests of NEES and NIS over independent ``runs`` of equal length (each a
    :class:`twin.sim.runs.Run` or a :class:`FilterRecord` with its truth).

    Considers the rows with t ≥ ``start`` s. Returns the per-row average NEES (``nees``),
    its ``nees_bounds``, the fraction of rows inside them (``nees_inside``), the overall
    mean NEES against the state dimension (``nees_mean``, ``dim``); and for NIS the
    fraction of rows, among those with an encoder update in some run, whose summed NIS
    lies inside its bounds (``nis_inside``) and the overall NIS per degree of freedom
    (``nis_per_dof``, 1 for a consistent filter).

    Why also ``nees_run_means`` and ``nees_mean_interval``: a run's NEES is strongly
    correlated in time (nearly unobservable states such as the scale factors keep their
    drawn errors for the whole run), so the fraction of rows inside the bounds is close to
    all-or-nothing for a batch and swings from batch to batch for one and the same filter.
    The runs are independent, though: each run's time-averaged NEES (``nees_run_means``,
    (N,)) has mean ``dim`` for a consistent filter, and ``nees_mean_interval`` is the
    Student-t interval (at ``confidence``) of their mean, which holds whatever the
    correlation in time. ``nees_mean`` inside ``nees_bounds`` is the χ² test of the
    average (conservative for a time average, whose spread is at most one row's).
    """
    if len(runs) < 2:
        raise TwinError(f"a Monte Carlo consistency test needs at least 2 runs, got {len(runs)}")
    if not (0.5 < confidence < 1.0):
        raise TwinError(f"confidence must be in (0.5, 1), got {confidence!r}")
    n = min(len(r.t) for r in runs)
    keep = runs[0].t[:n] >= start - 1e-9
    E = np.array([nees(r)[:n] for r in runs])[:, keep]
    rows = np.isfinite(E).all(axis=0)
    E = E[:, rows]
    N, dim = len(runs), runs[0].filter_log["x"].shape[1]
    a = 0.5 * (1.0 - confidence)
    lo, hi = chi2.ppf([a, 1.0 - a], N * dim) / N
    mean = E.mean(axis=0)
    per_run = E.mean(axis=1)
    half = t_dist.ppf(1.0 - a, N - 1) * per_run.std(ddof=1) / math.sqrt(N)
    nis = np.array([np.nan_to_num(r.filter_log["nis"][:n]) for r in runs])[:, keep].sum(axis=0)
    dof = np.array([r.filter_log["nis_dof"][:n] for r in runs])[:, keep].sum(axis=0)
    used = dof > 0
    nlo, nhi = chi2.ppf(a, dof[used]), chi2.ppf(1.0 - a, dof[used])
    return {"runs": N, "dim": dim, "rows": int(E.shape[1]), "nees": mean, "nees_bounds": (float(lo), float(hi)),
            "nees_inside": float(np.mean((mean >= lo) & (mean <= hi))), "nees_mean": float(E.mean()),
            "nees_run_means": per_run, "nees_mean_interval": (float(per_run.mean() - half), float(per_run.mean() + half)),
            "nis_inside": float(np.mean((nis[used] >= nlo) & (nis[used] <= nhi))),
            "nis_per_dof": float(nis[used].sum() / dof[used].sum()) if used.any() else math.nan}
