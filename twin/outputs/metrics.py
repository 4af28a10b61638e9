"""Metrics shared by every run, whatever the plant."""
from __future__ import annotations

import math
import re

import numpy as np

# the exactly rounded figures a run computes too, named here as before
from twin.measures import exact_mean, settling_time  # noqa: F401

EVENTS_KEPT = 100  # the estimator's events listed in metrics.json (all are counted): the first ones
_EVENT = re.compile(r"t = ([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?) s: (.*)", re.S)


# What each metric a run's metrics.json holds (and an [expect] bound may name) measures: the single
# place of these definitions; the documentation's metrics reference is generated from it, with the
# units of twin.scenarios.expectations.METRICS (a test keeps the two key sets equal). "θ" is the body's
# pitch from upright, "ψ" the wheels' mean rotation, "α" the heading; every figure from every
# control step (see run_metrics).
METRIC_DEFINITIONS = {
    "fell": "Whether the run ended early because the robot fell: the tilt passed 1 rad or the body touched "
            "the floor.",
    "duration_s": "Simulated time the run lasted: the last control instant (shorter than the scenario's "
                  "duration if the robot fell or a run limit stopped it).",
    "settling_time_s": "First time after which |θ| stays below 0.01 rad to the end of the run; absent (null) if "
                       "it never does or the robot fell.",
    "theta_rms_rad": "Root mean square of θ after the settling time; over the last 5 s if θ never settles.",
    "oscillation_peak_to_peak_rad": "Largest minus smallest θ over the last 5 s of the run: the residual "
                                    "oscillation (a limit cycle shows here).",
    "final_theta_rad": "θ at the last control instant.",
    "final_distance_m": "Distance travelled along the heading, r·ψ, at the last control instant.",
    "final_heading_rad": "Heading α at the last control instant.",
    "final_position_error_m": "Final distance minus the position target p_d; absent (null) in a scenario "
                              "without a position target.",
    "final_heading_error_rad": "Final heading minus the heading target α_d; absent (null) in a scenario "
                               "without a heading target.",
    "iae_theta": "Integral of the absolute tilt, ∫|θ| dt over the run (trapezoid rule).",
    "control_effort": "∫(τ_l² + τ_r²) dt of the torques delivered at the wheels over the run (trapezoid rule).",
    "max_abs_torque_nm": "Largest |torque| delivered at either wheel (the 5 ms control-period mean) in the run.",
    "estimator_theta_rmse_rad": "Root mean square of the estimated minus the true θ over the whole run, as "
                                "handed to the controllers; 0 with ideal sensing.",
    "rejected_measurements": "Sensor samples the estimator rejected in the run (outliers, gated encoder "
                             "samples); 0 for an estimator that does not count them.",
    "estimator_events": "Events the estimator logged in the run (faults detected, re-synchronisations, "
                        "resets); 0 without any.",
    "estimator_nees_mean": "The EKF's mean normalised estimation error squared over the run (from 0.5 s on), "
                           "e·P⁻¹·e with e the estimate's error against the simulated truth: 12, the state's "
                           "dimension, for a consistent filter; absent (null) for other estimators and under "
                           "ideal sensing.",
    "estimator_nis_per_dof": "The EKF's normalised innovation squared per degree of freedom of its encoder "
                             "updates: 1 for a consistent filter; absent (null) where not computed.",
}
# The metrics of a replay of a sensor log (twin.logs.replay; a log's [expect] may name them), with
# the units of twin.scenarios.expectations.REPLAY_METRICS.
REPLAY_METRIC_DEFINITIONS = {
    "theta_rmse_rad": "Root mean square of the replayed estimator's θ minus the log's truth (logs with a "
                      "[truth], such as the twin's).",
    "theta_max_abs_rad": "Largest |θ error| of the replayed estimator against the log's truth.",
    "psi_rmse_rad": "Root mean square of the ψ (mean wheel angle) error against the log's truth.",
    "psi_max_abs_rad": "Largest |ψ error| against the log's truth.",
    "alpha_rmse_rad": "Root mean square of the heading (α) error against the log's truth.",
    "alpha_max_abs_rad": "Largest |α error| against the log's truth.",
    "nis_per_dof": "Normalised innovation squared per degree of freedom over the instants with an update: 1 "
                   "for a consistent filter.",
    "rejected_total": "Sensor samples the replayed estimator rejected.",
    "nees_mean": "Mean normalised estimation error squared against the log's state truth: the state's "
                 "dimension (12 for the EKF) for a consistent filter.",
    "whiteness_outside_fraction": "Fraction of the lags 1 … L of the normalised innovations' autocorrelation "
                                  "outside the 95 % band ±1.96/√N of a white sequence: about 0.05 for a "
                                  "consistent filter.",
}


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
    0 with ideal sensing); ``rejected_measurements`` (the estimator's count);
    ``estimator_events`` (how many events the estimator logged, 0 without any),
    ``estimator_nees_mean`` and ``estimator_nis_per_dof`` (the EKF's consistency on simulated
    sensors, :func:`estimation.consistency.summary`; None otherwise); and ``estimator``, the
    estimator's section (:func:`estimator_section`; absent under ideal sensing).

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
    section = estimator_section(run)
    consistency = (section or {}).get("consistency") or {}
    out = {
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
        "estimator_events": (section or {}).get("events_total", 0),
        "estimator_nees_mean": consistency.get("nees_mean"),
        "estimator_nis_per_dof": consistency.get("nis_per_dof"),
        "seed": run.seed,
    }
    if section is not None:
        out["estimator"] = section
    return out


def estimator_section(run) -> dict | None:
    """metrics.json's ``estimator`` object of a run: None under ideal sensing (or for an
    estimator with neither a ``stats()`` hook nor a known truth), else

    ``name`` the estimator; ``stats`` its ``stats()`` made JSON-safe (:func:`jsonable`), its
    events moved out to ``events``: [{"t_s", "message"}] (the first :data:`EVENTS_KEPT`;
    ``t_s`` None where an event does not start "t = … s: ") with ``events_total``; for the
    EKF, whose ``stats()`` are its accepted and rejected samples per sensor group
    (``accepted``/``rejected``: gyro, accel, encoders), ``rejected_total``,
    ``saturated_imu_samples``, ``stale_imu_samples``, ``accel_outliers``, ``latency_changes``,
    ``resets``, ``predict_only_steps``, ``unchanged_encoder_samples``, ``interval_updates``,
    ``encoders_stuck_s``, ``degraded``, also ``encoder_resyncs`` (encoder samples accepted after
    a run of rejections, and encoder zeros re-based), lifted out of ``stats`` too; and
    ``consistency`` where the truth of its state is known (the EKF on simulated sensors,
    ``run.estimator_consistency``, :func:`estimation.consistency.summary`): ``start_s``,
    ``states``, ``rows``, ``nees_mean``, ``nees_bounds``, ``nis_per_dof``, ``nis_updates``,
    ``nis_dof``."""
    stats = getattr(run, "estimator_stats", None) or {}
    consistency = getattr(run, "estimator_consistency", None)
    if run.sensing == "ideal" or (not stats and consistency is None):
        return None
    stats = jsonable(dict(stats))
    out = {"name": run.sensing, "stats": stats}
    events = stats.pop("events", None)
    if isinstance(events, list):
        parsed = [_event(e) for e in events]
        out["events_total"] = len(parsed)
        out["events"] = parsed[:EVENTS_KEPT]
    if "encoder_resyncs" in stats:  # the EKF counts them (forced-in samples and re-based zeros)
        out["encoder_resyncs"] = stats["encoder_resyncs"]
    if consistency is not None:
        out["consistency"] = jsonable(dict(consistency))
    return out


def _event(e) -> dict:
    """One event as {"t_s", "message"}: from "t = 8.120 s: why" (the EKF's form) or a (t, why) pair."""
    if isinstance(e, (list, tuple)) and len(e) == 2 and isinstance(e[0], (int, float)) and \
            not isinstance(e[0], bool):
        t = float(e[0])
        return {"t_s": t if math.isfinite(t) else None, "message": str(e[1])}
    text = str(e)
    m = _EVENT.fullmatch(text)
    return {"t_s": float(m[1]), "message": m[2]} if m else {"t_s": None, "message": text}


def jsonable(v):
    """``v`` with what JSON cannot hold made plain: numpy scalars and arrays as numbers and lists,
    tuples and sets as lists (a set sorted, for the same file every time), dict keys as
    strings, non-finite floats as None, anything else as its ``str``."""
    if v is None or isinstance(v, (bool, str)):
        return v
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        f = float(v)
        return f if math.isfinite(f) else None
    if isinstance(v, dict):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, np.ndarray):
        return jsonable(v.tolist())
    if isinstance(v, (set, frozenset)):
        return [jsonable(x) for x in sorted(v, key=repr)]
    if isinstance(v, (list, tuple)):
        return [jsonable(x) for x in v]
    return str(v)
