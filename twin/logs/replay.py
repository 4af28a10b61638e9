"""Estimators replayed on a sensor log: the readings and commands of a log
(:mod:`twin.logs.format`) handed to any estimator of the registry, one control instant at a
time, as :class:`twin.sim.loop.ClosedLoop` hands them over; no physics involved.

The control instants are t_k = t_0 + k / control_rate from the first command at or after the
first whole IMU reading (gyro and accelerometer: the estimators start from one), up to the
last command.
A reading belongs to the first instant at or after its time (up to one microsecond of a period
earlier counts as at it; a reading before t_0 belongs to t_0); several of one sensor at one
instant: the last one is what arrives (as in the twin, where a newer sample supersedes one still
on its way). The estimator gets ``start(m_0)``, then ``step(m_k, u_{k-1})`` with the command of
the instant before (the torques applied over the period that just ended), so a log the twin
wrote replays to the very estimates of its run.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from twin.errors import PluginError, TwinError
from twin.logs.format import SensorLog
from twin.sensors import Measurement

INSTANT_TOLERANCE = 1e-6  # of a control period: a reading this much after an instant counts as at it


@dataclass
class Replay:
    """One estimator's replay of one log: ``t`` (N,) s the control instants, ``estimates``
    (N, 6) [θ, θ̇, ψ, ψ̇, α, α̇], ``diagnostics`` the estimator's ``diagnostics()`` at each
    instant when asked for (else None), ``stats`` its ``stats()`` at the end, and the wall time
    per step ``step_s`` (s)."""

    estimator: str
    t: np.ndarray
    estimates: np.ndarray
    diagnostics: list | None
    stats: dict
    step_s: float


def instants(log: SensorLog) -> tuple[np.ndarray, list, np.ndarray]:
    """(t (N,) s, the Measurement of each instant, the command (N, 2) N·m in force from each)."""
    rate = log.control_rate
    both = np.isfinite(log.gyro).all(axis=1) & np.isfinite(log.accel).all(axis=1)
    if not both.any():
        raise TwinError(f"{log.path / 'imu.csv'}: no row holds both a gyro and an accelerometer reading; the "
                        f"estimators start from one")
    # the first instant: the first command once a whole IMU reading has arrived (the estimators start from one)
    first = int(np.searchsorted(log.commands_t, float(log.imu_t[both][0]) - INSTANT_TOLERANCE / rate, side="left"))
    if first >= len(log.commands_t) - 1:
        raise TwinError(f"{log.path / 'commands.csv'}: fewer than 2 commands from the first IMU reading on "
                        f"(t = {float(log.imu_t[both][0]):g} s); a replay needs at least 2 control instants")
    t0 = float(log.commands_t[first])
    n = int(math.floor((float(log.commands_t[-1]) - t0) * rate + INSTANT_TOLERANCE)) + 1
    t = np.array([t0 + k / rate for k in range(n)])

    def slot(times: np.ndarray) -> np.ndarray:
        k = np.ceil((times - t0) * rate - INSTANT_TOLERANCE).astype(np.int64)
        return np.clip(k, 0, None)

    def last_at(times: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """For each instant, the index of the last ok row that arrives there (-1: none)."""
        idx = np.full(n, -1, dtype=np.int64)
        rows = np.flatnonzero(ok)
        k = slot(times[rows])
        keep = k < n
        idx[k[keep]] = rows[keep]  # later rows overwrite earlier ones: the last one arrives
        return idx

    gi = last_at(log.imu_t, np.isfinite(log.gyro).all(axis=1))
    ai = last_at(log.imu_t, np.isfinite(log.accel).all(axis=1))
    ei = last_at(log.encoders_t, log.has_counts)
    res = 1.0 / (log.counts_per_rev / (2.0 * math.pi))  # rad per count, as the twin's encoders
    gyro, accel, counts = log.gyro.tolist(), log.accel.tolist(), log.counts.tolist()
    ms = []
    for k in range(n):
        g, a, e = gi[k], ai[k], ei[k]
        ms.append(Measurement(float(t[k]), tuple(gyro[g]) if g >= 0 else None, tuple(accel[a]) if a >= 0 else None,
                              (counts[e][0] * res, counts[e][1] * res) if e >= 0 else None))
    # the command in force at instant k: the last row at or before it
    ci = np.searchsorted(log.commands_t, t + INSTANT_TOLERANCE / rate, side="right") - 1
    commands = log.commands[np.clip(ci, 0, None)]
    return t, ms, commands


def replay(log: SensorLog, estimator, name: str = "", diagnostics: bool = False) -> Replay:
    """Run ``estimator`` (an object meeting :class:`twin.protocols.Estimator`) over ``log``."""
    from twin.protocols import describe_object

    t, ms, commands = instants(log)
    who = name or describe_object(estimator)
    out = np.empty((len(t), 6))
    diag = [] if diagnostics else None
    cmd = commands.tolist()
    t_start = time.perf_counter()
    try:
        est = estimator.start(ms[0])
        out[0] = _checked(est, who, 0.0)
        if diag is not None:
            diag.append(estimator.diagnostics())
        step = estimator.step
        for k in range(1, len(t)):
            est = step(ms[k], (cmd[k - 1][0], cmd[k - 1][1]))
            out[k] = _checked(est, who, t[k])
            if diag is not None:
                diag.append(estimator.diagnostics())
    except (TwinError, PluginError):
        raise
    except Exception as exc:  # noqa: BLE001 -- a plugin's failure is one line naming it
        raise PluginError(f"estimator {who}: raised {type(exc).__name__}: {' '.join(str(exc).split())[:300]} on "
                          f"the log {log.path}") from None
    wall = time.perf_counter() - t_start
    stats = dict(estimator.stats()) if callable(getattr(estimator, "stats", None)) else {}
    return Replay(who, t, out, diag, stats, wall / len(t))


def _checked(est, who: str, t: float):
    try:
        v = tuple(est)
    except TypeError:
        v = ()
    if len(v) != 6 or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in v):
        raise PluginError(f"estimator {who} returned {est!r} at t = {t:.3f} s; expected 6 finite numbers "
                          f"[θ, θ̇, ψ, ψ̇, α, α̇] (see twin.protocols.Estimator)")
    return v


def build_for(log: SensorLog, kind: str, params: dict | None = None):
    """Estimator ``kind`` of the registry built for ``log``'s rate, model, motors and sensors
    (with the scenario's ``sensors.estimator_params`` when the log's scenario names that kind)."""
    from twin.registry import build_estimator

    sc = log.scenario
    if params is None and sc is not None and sc.data["sensors"]["estimator"] == kind:
        params = sc.data["sensors"]["estimator_params"] or None
    return build_estimator(kind, params, log.context())


def errors(log: SensorLog, r: Replay) -> dict | None:
    """θ, ψ, α errors against the log's truth (at the instants the truth has a row for): RMSE and
    max |error| in rad, and the error over time; None without truth."""
    if log.truth is None:
        return None
    k = np.round((log.truth_t - r.t[0]) * log.control_rate).astype(np.int64)
    on = (k >= 0) & (k < len(r.t)) & np.isclose(r.t[np.clip(k, 0, len(r.t) - 1)], log.truth_t, atol=1e-9, rtol=0)
    truth, est = log.truth[on], r.estimates[k[on]]
    out = {"rows": int(on.sum())}
    for name, j in (("theta", 0), ("psi", 2), ("alpha", 4)):
        e = est[:, j] - truth[:, j]
        out[f"{name}_rmse_rad"] = float(np.sqrt(np.mean(e * e))) if e.size else None
        out[f"{name}_max_abs_rad"] = float(np.max(np.abs(e))) if e.size else None
    return out


__all__ = ["INSTANT_TOLERANCE", "Replay", "build_for", "errors", "instants", "replay"]


def consistency(r: Replay) -> dict:
    """NIS per degree of freedom (1 for a consistent filter) over the instants with an update,
    from the estimator's ``diagnostics()`` (``nis``, ``nis_dof``): needs no truth."""
    if not r.diagnostics:
        return {}
    nis = np.array([d.get("nis", math.nan) if isinstance(d, dict) else math.nan for d in r.diagnostics], float)
    dof = np.array([d.get("nis_dof", 0) if isinstance(d, dict) else 0 for d in r.diagnostics], float)
    on = np.isfinite(nis) & (dof > 0)
    if not on.any():
        return {}
    return {"nis_per_dof": float(nis[on].sum() / dof[on].sum()), "nis_updates": int(on.sum())}


def replay_logs(paths, kinds) -> dict:
    """Every estimator kind of ``kinds`` on every log of ``paths``: {"logs": {path: {"duration_s", "instants",
    "estimators": {kind: {"errors", "consistency", "rejected_total", "step_us", ...}}}}} and the replays."""
    from twin.logs.format import read_log

    doc, replays = {"logs": {}}, {}
    for p in paths:
        log = read_log(p)
        entry = {"duration_s": log.duration, "control_rate_hz": log.control_rate, "has_truth": log.truth is not None,
                 "estimators": {}}
        for kind in kinds:
            est = build_for(log, kind)
            r = replay(log, est, kind, diagnostics=callable(getattr(est, "diagnostics", None)))
            replays[(str(p), kind)] = r
            entry["instants"] = len(r.t)
            entry["estimators"][kind] = {
                "errors": errors(log, r), "consistency": consistency(r),
                "rejected_total": int(r.stats.get("rejected_total", 0)), "step_us": r.step_s * 1e6,
                "events": list(r.stats.get("events", []))}
        doc["logs"][str(p)] = entry
    return doc, replays


def write_estimates_csv(replays: dict, path) -> None:
    """One row per log, estimator and instant: log, estimator, t, θ, θ̇, ψ, ψ̇, α, α̇ (s, rad, rad/s)."""
    import csv

    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["log", "estimator", "t [s]", "theta [rad]", "theta_dot [rad/s]", "psi [rad]", "psi_dot [rad/s]",
                    "alpha [rad]", "alpha_dot [rad/s]"])
        for (log, kind), r in replays.items():
            for t, row in zip(r.t.tolist(), r.estimates.tolist()):
                fh.write(",".join([log, kind, repr(t)] + [repr(v) for v in row]) + "\r\n")
