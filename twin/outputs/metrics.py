"""Metrics shared by every run, whatever the plant."""
from __future__ import annotations

import math

import numpy as np


def exact_mean(x: np.ndarray) -> float:
    """The mean of ``x`` with an exactly rounded sum (``math.fsum``). numpy's SIMD sums can depend
    on where the array sits in memory, which breaks bit-identical replays across processes."""
    return math.fsum(np.ravel(x).tolist()) / x.size


def settling_time(t: np.ndarray, theta: np.ndarray, tol: float = 0.01) -> float:
    """First time (s) after which |θ| stays below ``tol`` rad; inf if it never does."""
    bad = np.nonzero(~(np.abs(theta) < tol))[0]
    if len(bad) == 0:
        return float(t[0])
    if bad[-1] == len(t) - 1:
        return math.inf
    return float(t[bad[-1] + 1])


def _integral(t: np.ndarray, y: np.ndarray) -> float:
    """∫ y dt by the trapezoid rule (0 for fewer than two samples)."""
    return math.fsum((0.5 * (y[1:] + y[:-1]) * np.diff(t)).tolist()) if len(t) > 1 else 0.0


def run_metrics(run, settle_tol: float = 0.01, tail: float = 5.0) -> dict:
    """The figures of merit of a closed-loop twin run (SI units; None where undefined).

    ``fell``; ``settling_time_s`` (first time after which |θ| < ``settle_tol`` rad for good;
    None if never); ``theta_rms_rad`` (RMS of θ after settling; if it never settles, over
    the last ``tail`` s); ``oscillation_peak_to_peak_rad`` (max − min of θ over the last
    ``tail`` s); ``final_position_error_m`` and ``final_heading_error_rad`` (final value
    minus target, None without that target); ``iae_theta`` (∫|θ| dt, rad·s);
    ``control_effort`` (∫(τ_l² + τ_r²) dt of the delivered torques, N²·m²·s);
    ``max_abs_torque_nm``; ``estimator_theta_rmse_rad`` (estimate against truth, whole run;
    0 with ideal sensing); ``rejected_measurements`` (the estimator's count).

    Every figure is computed from every control step: a run that logs every N-th step only
    (``run.log_every`` > 1) keeps the signals read here at every step in ``run.full_rate``.
    """
    full = getattr(run, "full_rate", None)
    if full is None:
        t, theta, distance = run.t, run.signal("theta"), run.distance
        alpha, tl, tr = run.signal("alpha"), run.signal("torque_l"), run.signal("torque_r")
    else:
        t, theta, distance, alpha, tl, tr = (full[k] for k in ("t", "theta", "distance", "alpha", "torque_l",
                                                               "torque_r"))
    ts = settling_time(t, theta, settle_tol) if not run.fell else math.inf
    after = t >= ts - 1e-12 if math.isfinite(ts) else t >= t[-1] - tail - 1e-12
    last = t >= t[-1] - tail - 1e-12
    e = run.experiment
    effort = tl * tl + tr * tr
    return {
        "controller": run.controller,
        "sensing": run.sensing,
        "status": run.status,
        "fell": bool(run.fell),
        "end_reason": run.end_reason,
        "duration_s": float(t[-1]),
        "settling_time_s": ts if math.isfinite(ts) else None,
        "theta_rms_rad": math.sqrt(exact_mean(theta[after] ** 2)),
        "oscillation_peak_to_peak_rad": float(np.ptp(theta[last])),
        "final_theta_rad": float(theta[-1]),
        "final_distance_m": float(distance[-1]),
        "final_heading_rad": float(alpha[-1]),
        "final_position_error_m": None if e is None or e.p_d is None else float(distance[-1] - e.p_d),
        "final_heading_error_rad": None if e is None or e.alpha_d is None else float(alpha[-1] - e.alpha_d),
        "iae_theta": _integral(t, np.abs(theta)),
        "control_effort": _integral(t, effort),
        "max_abs_torque_nm": float(np.max(np.abs(np.concatenate([tl, tr])))),
        "estimator_theta_rmse_rad": run.estimation_rmse("theta") if run.estimates is not None else 0.0,
        "rejected_measurements": int(run.estimator_stats.get("rejected_total", 0)),
        "seed": run.seed,
    }
