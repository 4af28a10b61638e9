"""Estimators replayed on a sensor log: the readings and commands of a log
(:mod:`twin.logs.format`) handed to any estimator of the registry, one control instant at a
time, as :class:`twin.sim.loop.ClosedLoop` hands them over; no physics involved.

The control instants are t_k = t_0 + k / control_rate from the first command at or after the
first whole IMU reading (gyro and accelerometer: the estimators start from one), up to the
last command.
A reading belongs to the first instant at or after its time (up to one microsecond of a period
earlier counts as at it; a reading before t_0 belongs to t_0); several of one sensor at one
instant: the last one is what arrives (as in the twin, where a newer sample supersedes one still
on its way). A log's other sensor channels (:attr:`twin.logs.format.SensorLog.channels`: the motor
current) are slotted the same way into each Measurement's ``extra`` (``meas["motor_current"]``): an
estimator that reads a channel gets it, the others never look. An estimator that declares the
channels it needs (``channels = ("motor_current",)``) is refused in one line on a log without
them. The estimator gets ``start(m_0)``, then ``step(m_k, u_{k-1})`` with the command of
the instant before (the torques applied over the period that just ended), so a log the twin
wrote replays to the very estimates of its run.

The command of a period [t_k, t_{k+1}) (:func:`period_commands`): with ``semantics = "held"``
(version 1 always) the row in force at t_k, the last at or before it; with ``"sampled"`` (each
row the value at its instant, changing between rows) the mean over the period of the samples
joined by straight lines (held constant before the first row and after the last). A
sampled signal is best rebuilt between its samples by a straight line, and the estimators hold
one torque over a period: the one with the same impulse as the signal is that mean. (The row
in force at t_k would lag a ramp by half a row interval; the nearest sample would jump.)

The log's truth (:func:`errors`, :func:`truth_usage`): a truth row at a control instant is
compared with that instant's estimate; a row between two instants (a truth at another rate, or
on another clock's grid) with the estimates interpolated linearly between them (the estimates
come at the control rate, denser than a slower truth; interpolating the truth instead would
smooth its own features away); rows outside the replay are left out and counted. The EKF's
NEES needs the 12-state truth at the filter's own instants: it is computed at the instants
that have a truth row (a truth at a lower rate on the control grid gives NEES at its own
instants), and not at all, said in one line, where no truth row falls on a control instant or
none on the first (the encoders' reference).

A replay streams: :func:`schedule` puts every reading on its instant as a row number (checked
in floating point first: no timestamp becomes an index unless it falls inside the replay), the
Measurements are made :data:`CHUNK` instants at a time, and :func:`replay_logs` keeps the
estimators' diagnostics as arrays (:mod:`twin.logs.diagnostics`): a few hundred bytes an instant
in all, no object per instant.

The noise figures (:func:`replay_logs`' ``noise``, ``twin replay --noise``): every IMU axis's noise
is measured from the log's readings (:mod:`twin.logs.noise`: differences of order 3 with a robust
scale, the Allan deviation where the log is long enough) and compared with the figures the log
gives; by default ("log") the estimators are built with the log's figures unless it gives none or
the readings contradict them, then with the measured ones ("given", "measured", "datasheet"
choose). With the log's figures the estimators get the log's own SensorConfig, so a twin's log
replays bit for bit; replay.json's ``noise`` holds the given, datasheet and measured figures,
which was used and why.

Consistency (:func:`consistency`), from the estimator's ``diagnostics()`` (the optional keys
:class:`twin.protocols.Estimator` documents):

* NIS per degree of freedom over every instant with an update (1 for a consistent filter).
* NEES of the EKF where the log carries the state truth (:mod:`twin.logs.format`: the truth
  columns ``psi_l … gyro_bias_z`` at every instant and the ``[truth]`` table): the arithmetic of
  :mod:`estimation.consistency` on the replay's ``x``, ``P``, ``lag`` and that truth, averaged
  over the instants at least :data:`NEES_START` s after the first (12 for a consistent filter);
  over several logs of one estimator, :func:`monte_carlo` gives the Monte Carlo χ² tests of
  :func:`estimation.consistency.monte_carlo` (each log one run).
* Whiteness of the innovations (``innovation`` y and ``innovation_cov`` S): each update's
  normalised innovation s_k = 1ᵀ L⁻¹ y / √m (L the Cholesky factor of S, m = dim y), which is
  N(0, 1) for a consistent filter whatever m, and white if the innovations are; its sample
  autocorrelation ρ(l) at lags l = 1 … :data:`WHITENESS_LAGS` counted in updates (not in time:
  the EKF updates only when a count changed), against the 95 % band ±1.96/√N of a white
  sequence of N updates; a white sequence has about 5 % of lags outside. Needs no truth.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from estimation.consistency import FilterRecord, StateTruth, monte_carlo as mc, nees
from twin import limits as _limits
from twin.errors import MAY_NOT_END, PluginError, TwinError, ends_process, raised_text
from twin.logs.bounds import MAX_INSTANTS
from twin.logs.checks import sign_checks
from twin.logs.diagnostics import DiagnosticsLog, NeesRecord, normalised_innovation
from twin.logs.diagnostics import monte_carlo as mc_arrays
from twin.logs.format import SensorLog, read_log
from twin.logs.instants import instants_of, rows_clock
from twin.logs.noise import choose
from twin.protocols import describe_object
from twin.registry import build_estimator, is_user_code
from twin.sensors import Measurement
from twin.sensors.types import CORE_CHANNELS
from twin.sim.recorder import filter_log_of  # the arrays Run.filter_log holds, built the same way

INSTANT_TOLERANCE = 1e-6  # of a control period: a reading this much after an instant counts as at it
NEES_START = 0.5  # s after the first instant: the EKF's start-up transient of the encoder zeros is left out
WHITENESS_LAGS = 20  # lags (in updates) of the innovations' autocorrelation: 0.1 s of 200 Hz updates at most
WHITENESS_Z = 1.959963984540054  # the two-sided 95 % point of N(0, 1): the band is ±z/√N


@dataclass
class Replay:
    """One estimator's replay of one log: ``t`` (N,) s the control instants, ``estimates``
    (N, 6) [θ, θ̇, ψ, ψ̇, α, α̇], ``diagnostics`` the estimator's ``diagnostics()`` at each
    instant when asked for (else None: a list of its dicts from :func:`replay`, a
    :class:`~twin.logs.diagnostics.DiagnosticsLog` of arrays from :func:`replay_logs`), ``stats``
    its ``stats()`` at the end, and the estimator's wall time per step ``step_s`` (s); ``log``
    the log replayed."""

    estimator: str
    t: np.ndarray
    estimates: np.ndarray
    diagnostics: list | None
    stats: dict
    step_s: float
    log: SensorLog | None = None


@dataclass(frozen=True)
class Schedule:
    """What reaches the estimator at each control instant of a log (:func:`schedule`), as row
    numbers into the log's arrays (40 bytes an instant, no object per instant): ``t`` (N,) s
    the instants; ``gyro``, ``accel`` and ``encoders`` (N,) the row of imu.csv or encoders.csv
    whose reading arrives at each (−1: none); ``command`` (N,) the commands.csv row in force
    from each."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    encoders: np.ndarray
    command: np.ndarray
    rows: bool = False
    extra: dict = field(default_factory=dict)  # channel name -> (N,) the row of its stream arriving at each (−1: none)


def schedule(log: SensorLog) -> Schedule:
    """The control instants of ``log`` and the rows that reach each (see the module docstring).

    Their number is checked before anything is allocated for them: at most
    :data:`twin.logs.bounds.MAX_INSTANTS` (:func:`twin.logs.format.read_log` refuses a log asking
    for more; a :class:`SensorLog` made otherwise is held to it here). A reading is put on its
    instant in floating point and only then, if it falls inside the replay, made an index: a
    timestamp far beyond the last instant can neither overflow nor wrap round to instant 0."""
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
    periods = (float(log.commands_t[-1]) - t0) * rate + INSTANT_TOLERANCE
    if not periods < MAX_INSTANTS:  # (NaN too)
        raise TwinError(f"{log.path / 'commands.csv'}: the commands span {periods / rate:.6g} s at {rate:g} Hz, "
                        f"{periods:.6g} control periods; allowed: a replay of at most {MAX_INSTANTS:,} control "
                        f"instants (split a longer log)")
    on_rows = rows_clock(log)
    if on_rows:  # the command rows are the instants (rows at one time: one instant, the last row in force)
        ct = log.commands_t[first:]
        last_of = np.append(np.diff(ct) > INSTANT_TOLERANCE / rate, True)
        t = ct[last_of].astype(float)
        n = len(t)
    else:
        n = int(math.floor(periods)) + 1
        t = t0 + np.arange(n) / rate  # t_0 + k / rate, each rounded once: as the closed loop's clock

    def last_at(times: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """For each instant, the index of the last ok row that arrives there (-1: none)."""
        idx = np.full(n, -1, dtype=np.int64)
        rows = np.flatnonzero(ok)
        if on_rows:  # the first instant at or after each (up to the tolerance)
            k = np.searchsorted(t, times[rows] - INSTANT_TOLERANCE / rate, side="left").astype(float)
        else:
            k = np.ceil((times[rows] - t0) * rate - INSTANT_TOLERANCE)  # the instant each arrives at, in floats
        keep = k < n  # (a reading after the last instant never arrives)
        k = np.maximum(k[keep], 0.0).astype(np.int64)  # a reading before t_0 belongs to t_0
        idx[k] = rows[keep]  # later rows overwrite earlier ones: the last one arrives
        return idx

    gi = last_at(log.imu_t, np.isfinite(log.gyro).all(axis=1))
    ai = last_at(log.imu_t, np.isfinite(log.accel).all(axis=1))
    ei = last_at(log.encoders_t, log.has_counts)
    # the command in force at instant k: the last row at or before it
    ci = np.searchsorted(log.commands_t, t + INSTANT_TOLERANCE / rate, side="right") - 1
    extra = {name: last_at(st.t, np.isfinite(st.values).all(axis=1)) for name, st in log.channels.items()}
    return Schedule(t, gi, ai, ei, np.clip(ci, 0, None), on_rows, extra)


CHUNK = 4096  # control instants whose Measurements are made at a time: a replay holds no list of them


def command_integral(log: SensorLog):
    """For ``semantics = "sampled"`` commands: (times (k,) s made non-decreasing, the integral
    (k, 2) N·m·s of the commands joined by straight lines from the first row to each); None for
    held commands."""
    if log.command_semantics != "sampled":
        return None
    t = np.maximum.accumulate(log.commands_t)  # (a row up to the tolerance earlier counts as simultaneous)
    u = log.commands
    seg = 0.5 * (u[1:] + u[:-1]) * np.diff(t)[:, None]
    return t, np.vstack([np.zeros((1, 2)), np.cumsum(seg, axis=0)])


def _integral_at(log: SensorLog, integral, x: np.ndarray) -> np.ndarray:
    """∫ u from the first command row to each time of ``x`` (n, 2): u the rows joined by straight
    lines, held at the first row's value before it and the last's after it."""
    t, cum = integral
    u = log.commands
    last = len(t) - 1
    i = np.clip(np.searchsorted(t, x, side="right") - 1, 0, last)
    j = np.minimum(i + 1, last)
    width = t[j] - t[i]
    dx = (x - t[i])[:, None]
    slope = np.zeros((len(x), 2))
    inner = (width > 0) & (x >= t[0])
    slope[inner] = (u[j[inner]] - u[i[inner]]) / width[inner, None]
    return cum[i] + dx * (u[i] + 0.5 * slope * dx)


def period_commands(log: SensorLog, sched: Schedule, a: int, b: int, integral=None) -> np.ndarray:
    """(b − a, 2) N·m: the command of each control period [t_k, t_{k+1}) of instants a … b−1 (see
    the module docstring): held, the row in force at t_k; sampled (``integral`` from
    :func:`command_integral`), the mean over the period of the samples joined by straight lines."""
    if integral is None:
        return log.commands[sched.command[a:b]]
    t0, rate = float(sched.t[0]), log.control_rate
    k = np.arange(a, b)
    if sched.rows:  # a period ends at the next instant (the last: one nominal period on)
        start = sched.t[a:b]
        end = np.append(sched.t[a + 1:b + 1], [] if b < len(sched.t) else [sched.t[-1] + 1.0 / rate])
    else:
        start, end = sched.t[a:b], t0 + (k + 1) / rate
    return (_integral_at(log, integral, end) - _integral_at(log, integral, start)) / (end - start)[:, None]


def _chunk(log: SensorLog, sched: Schedule, a: int, b: int, integral=None) -> tuple[list, list, list]:
    """(t, the Measurement of each instant, the command [ul, ur] N·m of the period from each) of
    instants a … b−1, as plain floats (the readings' floats as the log holds them)."""
    res = 1.0 / (log.counts_per_rev / (2.0 * math.pi))  # rad per count, as the twin's encoders
    gi, ai, ei = sched.gyro[a:b], sched.accel[a:b], sched.encoders[a:b]
    g = log.gyro[np.maximum(gi, 0)].tolist()
    acc = log.accel[np.maximum(ai, 0)].tolist()
    e = log.counts[np.maximum(ei, 0)].tolist() if len(log.counts) else [None] * (b - a)
    hg, ha, he = (gi >= 0).tolist(), (ai >= 0).tolist(), (ei >= 0).tolist()
    ts = sched.t[a:b].tolist()
    ms = [Measurement(ts[j], tuple(g[j]) if hg[j] else None, tuple(acc[j]) if ha[j] else None,
                      (e[j][0] * res, e[j][1] * res) if he[j] else None) for j in range(b - a)]
    if sched.extra:  # the log's other channels, by name (Measurement.extra)
        chans = log.channels
        cols = {}
        for name, rows in sched.extra.items():
            r = rows[a:b]
            vals = chans[name].values[np.maximum(r, 0)].tolist() if len(chans[name].values) else [None] * (b - a)
            cols[name] = (vals, (r >= 0).tolist())
        ms = [m._replace(extra={n: tuple(v[j]) if h[j] else None for n, (v, h) in cols.items()})
              for j, m in enumerate(ms)]
    return ts, ms, period_commands(log, sched, a, b, integral).tolist()


def instants(log: SensorLog) -> tuple[np.ndarray, list, np.ndarray]:
    """(t (N,) s, the Measurement of each instant, the command (N, 2) N·m of the period from each).

    A list of N Measurements: for a look at a log's instants; :func:`replay` makes them
    :data:`CHUNK` at a time instead (:func:`schedule`)."""
    sched = schedule(log)
    ms = []
    for a in range(0, len(sched.t), CHUNK):
        ms += _chunk(log, sched, a, min(len(sched.t), a + CHUNK))[1]
    return sched.t, ms, period_commands(log, sched, 0, len(sched.t), command_integral(log))


def replay(log: SensorLog, estimator, name: str = "", diagnostics: bool = False) -> Replay:
    """Run ``estimator`` (an object meeting :class:`twin.protocols.Estimator`) over ``log``.

    ``diagnostics``: keep its ``diagnostics()`` of every instant, as it returns them (a list of
    dicts: the EKF's hold its states and covariance, 2 kB an instant); :func:`replay_logs` keeps
    them as arrays instead (:class:`twin.logs.diagnostics.DiagnosticsLog`). Memory: the
    schedule, the estimates and (without ``diagnostics``) nothing else per instant; the
    readings reach the estimator :data:`CHUNK` instants at a time."""
    return _replay(log, estimator, name, [] if diagnostics else None)


def _replay(log: SensorLog, estimator, name: str, diag) -> Replay:
    """:func:`replay`, the diagnostics appended to ``diag`` (a list, or a DiagnosticsLog made
    here for ``diag = "arrays"``; None: not asked for)."""
    sched = schedule(log)
    n = len(sched.t)
    who = name or describe_object(estimator)
    needed = [c for c in getattr(estimator, "channels", ()) or () if c not in CORE_CHANNELS and c not in log.channels]
    if needed:
        have = ", ".join(log.channels) or "none"
        raise PluginError(f"estimator {who} needs the {needed[0]} channel, which the log {log.path} does not hold "
                          f"(its extra channels: {have}); allowed: a log with [streams.{needed[0]}] "
                          f"(twin run --log-sensors with [sensors.{needed[0]}])")
    if diag == "arrays":
        diag = DiagnosticsLog(who, log, sched.t)
    out = np.empty((n, 6))
    wall, prev = 0.0, None
    integral = command_integral(log)
    for a in range(0, n, CHUNK):
        ts, ms, cmds = _chunk(log, sched, a, min(n, a + CHUNK), integral)
        t_start = time.perf_counter()  # the estimator's time only: making the chunk is the replay's
        try:
            j0 = 0
            if a == 0:
                out[0] = _checked(estimator.start(ms[0]), who, 0.0)
                if diag is not None:
                    _keep(diag, ts[0], estimator.diagnostics())
                prev, j0 = cmds[0], 1
            step = estimator.step
            for j in range(j0, len(ms)):
                # the command of the instant before: the torques applied over the period that just ended
                out[a + j] = _checked(step(ms[j], (prev[0], prev[1])), who, ts[j])
                if diag is not None:
                    _keep(diag, ts[j], estimator.diagnostics())
                prev = cmds[j]
        except TwinError:  # a PluginError too: already one line naming the plugin
            raise
        except _limits.PLUGIN_FAILURES as exc:  # a plugin's failure (its sys.exit() too) is one line naming it
            raise PluginError(f"estimator {who}: raised {raised_text(exc, 300)} on the log {log.path}"
                              + (f"; {MAY_NOT_END}" if ends_process(exc) else "")) from None
        wall += time.perf_counter() - t_start
    if isinstance(diag, DiagnosticsLog):
        diag.finish()
    stats = dict(estimator.stats()) if callable(getattr(estimator, "stats", None)) else {}
    return Replay(who, sched.t, out, diag, stats, wall / n, log)


def _keep(diag, t: float, d) -> None:
    if isinstance(diag, list):
        diag.append(d)
    else:
        diag.add(t, d)


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
    sc = log.scenario
    if params is None and sc is not None and sc.data["sensors"]["estimator"] == kind:
        params = sc.data["sensors"]["estimator_params"] or None
    est = build_estimator(kind, params, log.context())
    # an estimator that can take the rows' sampling is told it (the EKF: point IMU samples become
    # interval means by the trapezoid; sampled commands turn its latency watch off), and, on a log
    # whose instants are its rows (rows_clock), that each step spans the time since the last; the
    # twin's own logs ("mean", "held", on the grid) leave it as in the closed loop
    tell = getattr(est, "set_sampling", None)
    if callable(tell):
        if rows_clock(log) and takes_periods(tell):
            tell(log.sampling, log.command_semantics, periods="rows")
        elif (log.sampling, log.command_semantics) != ("mean", "held"):
            tell(log.sampling, log.command_semantics)
    return est


def takes_periods(set_sampling) -> bool:
    """Whether (None: no hook at all, False) an estimator's ``set_sampling`` takes ``periods`` (an older plugin's takes
    ``imu`` and ``commands`` alone: it is then replayed as if every period were the nominal one,
    and the replay says so)."""
    import inspect

    if not callable(set_sampling):
        return False
    try:
        inspect.signature(set_sampling).bind("mean", "held", periods="rows")
    except (TypeError, ValueError):
        return False
    return True


def _truth_rows(log: SensorLog, t: np.ndarray):
    """(k (j,) the instant of each truth row, on (j,) the rows at a control instant, between (j,)
    the rows between two instants of the replay ``t``)."""
    tt = log.truth_t
    k = instants_of(log, t, tt)
    on = (k >= 0) & (k < len(t)) & np.isclose(t[np.clip(k, 0, len(t) - 1)], tt, atol=1e-9, rtol=0)
    between = ~on & (tt > t[0]) & (tt < t[-1])
    return k, on, between


def errors(log: SensorLog, r: Replay) -> dict | None:
    """θ, ψ, α errors against the log's truth: RMSE and max |error| in rad over the truth's rows
    in the replay, ``rows`` of them; a row at a control instant against that instant's estimate,
    a row between two (``interpolated_rows``) against the estimates interpolated linearly between
    them (see the module docstring); ``outside_rows`` the rows before the first instant or after
    the last. None without truth."""
    if log.truth is None:
        return None
    k, on, between = _truth_rows(log, r.t)
    truth, est = log.truth[on], r.estimates[k[on]]
    if between.any():  # a truth off the control instants: the estimates interpolated to its rows
        tt = log.truth_t[between]
        i = np.clip(np.searchsorted(r.t, tt, side="right") - 1, 0, len(r.t) - 2)
        w = ((tt - r.t[i]) / (r.t[i + 1] - r.t[i]))[:, None]
        truth = np.vstack([truth, log.truth[between]])
        est = np.vstack([est, (1.0 - w) * r.estimates[i] + w * r.estimates[i + 1]])
    out = {"rows": int(on.sum() + between.sum()), "interpolated_rows": int(between.sum()),
           "outside_rows": int((~on & ~between).sum())}
    for name, j in (("theta", 0), ("psi", 2), ("alpha", 4)):
        e = est[:, j] - truth[:, j]
        out[f"{name}_rmse_rad"] = float(np.sqrt(np.mean(e * e))) if e.size else None
        out[f"{name}_max_abs_rad"] = float(np.max(np.abs(e))) if e.size else None
    return out


__all__ = ["CHUNK", "INSTANT_TOLERANCE", "NEES_START", "Replay", "Schedule", "WHITENESS_LAGS", "build_for",
           "command_integral", "consistency", "errors", "estimator_notes", "filter_record", "format_entry",
           "instants", "monte_carlo", "normalised_innovations", "period_commands", "replay", "replay_logs",
           "rows_clock", "schedule", "state_truth", "streams_entry", "summary_lines", "truth_usage", "whiteness",
           "write_estimates_csv", "write_figure"]


def consistency(r: Replay, log: SensorLog | None = None, start: float = NEES_START) -> dict:
    """From the estimator's ``diagnostics()`` (see the module docstring): ``nis_per_dof`` (1 for a
    consistent filter) and ``nis_updates`` over the instants with an update; ``nees_mean`` (12 for
    the EKF if consistent), ``nees_rows`` and ``nees_start_s`` where ``log`` has the state truth
    (``start`` s after the first instant on); ``whiteness`` (:func:`whiteness`) and its
    ``whiteness_outside_fraction`` where the estimator reports innovations. {} if it reports none
    of these."""
    if not r.diagnostics:
        return {}
    out = {}
    nis, dof = _nis_and_dof(r)
    on = np.isfinite(nis) & (dof > 0)
    if on.any():
        out.update(nis_per_dof=float(nis[on].sum() / dof[on].sum()), nis_updates=int(on.sum()))
    e = t = None
    if isinstance(r.diagnostics, DiagnosticsLog):  # the NEES was computed while the replay went
        e = r.diagnostics.nees if log is not None else None
        t, dim = r.t - r.t[0], 12
    else:
        rec = filter_record(log, r) if log is not None else None
        if rec is not None and rec.truth is not None:

            e, t, dim = nees(rec), rec.t, int(rec.filter_log["x"].shape[1])
    if e is not None:
        keep = (t >= start - 1e-9) & np.isfinite(e)
        if keep.any():
            out.update(nees_mean=float(e[keep].mean()), nees_dim=dim, nees_rows=int(keep.sum()),
                       nees_start_s=float(start))
    w = whiteness(r)
    if w is not None:
        out.update(whiteness_outside_fraction=w["outside_fraction"], whiteness=w)
    return out


def _nis_and_dof(r: Replay) -> tuple[np.ndarray, np.ndarray]:
    """(NIS (N,), its degrees of freedom (N,) as floats) of each instant of ``r``'s diagnostics
    (NaN and 0 where the estimator reported none)."""
    if isinstance(r.diagnostics, DiagnosticsLog):
        return r.diagnostics.nis(), r.diagnostics.nis_dof()
    ds = [d if isinstance(d, dict) else {} for d in r.diagnostics or []]
    return (np.array([d.get("nis", math.nan) for d in ds], float),
            np.array([d.get("nis_dof", 0) for d in ds], float))


def normalised_innovations(r: Replay) -> tuple[np.ndarray, np.ndarray]:
    """(t (N,) s, s (N,)) at the instants with an ``innovation`` and ``innovation_cov``: s_k =
    1ᵀ L⁻¹ y / √m, L the Cholesky factor of S, m = dim y (N(0, 1) for a consistent filter)."""
    if isinstance(r.diagnostics, DiagnosticsLog):  # computed, with the same checks, while the replay went
        return r.diagnostics.innovations()
    ts, ss = [], []
    for t, d in zip(r.t.tolist(), r.diagnostics or []):
        if not isinstance(d, dict) or "innovation" not in d or "innovation_cov" not in d:
            continue
        value = normalised_innovation(r.estimator, t, d["innovation"], d["innovation_cov"])
        if value is not None:
            ts.append(t)
            ss.append(value)
    return np.array(ts), np.array(ss)


def whiteness(r: Replay, lags: int = WHITENESS_LAGS) -> dict | None:
    """The normalised innovations' sample autocorrelation ρ(l) = Σ_k (s_k − s̄)(s_{k+l} − s̄) /
    Σ_k (s_k − s̄)² at l = 1 … ``lags`` (in updates) against the 95 % band ±1.96/√N of a white
    sequence of N: {"updates": N, "lags": lags, "band": 1.96/√N, "autocorrelation": [ρ(1) …],
    "outside_fraction": the fraction of lags with |ρ| above the band, "mean", "variance": of s
    (0 and 1 if consistent)}; None without innovations or with fewer than 2 × ``lags`` updates."""
    _, s = normalised_innovations(r)
    n = len(s)
    if n < 2 * lags:
        return None
    # sums exactly rounded (math.fsum), not by the BLAS or SIMD reductions: the same bits on every CPU
    mean = math.fsum(s) / n
    c = s - mean
    den = math.fsum(c * c)
    rho = [math.fsum(c[:-l] * c[l:]) / den if den > 0 else 0.0 for l in range(1, lags + 1)]
    band = WHITENESS_Z / math.sqrt(n)
    return {"updates": n, "lags": lags, "band": band, "autocorrelation": rho,
            "outside_fraction": float(np.mean(np.abs(rho) > band)), "mean": mean,
            "variance": den / n}


def state_truth(log: SensorLog, t: np.ndarray):
    """The :class:`estimation.consistency.StateTruth` of ``log`` at the instants ``t`` (s), NaN at
    the instants without a truth row (a truth at a lower rate: no NEES there), or None unless the
    log has the state truth (the extra truth columns and the ``[truth]`` table) with a truth row
    at the first instant."""
    if log.truth is None or log.truth_state is None or log.truth_constants is None:
        return None

    k = instants_of(log, t, log.truth_t)
    on = (k >= 0) & (k < len(t)) & np.isclose(t[np.clip(k, 0, len(t) - 1)], log.truth_t, atol=1e-9, rtol=0)
    rows = np.full(len(t), -1, dtype=np.int64)
    rows[k[on]] = np.flatnonzero(on)  # the last truth row at an instant, as for the readings
    if rows[0] < 0:  # the encoder zeros' truth is relative to the first instant's wheel angles
        return None
    tr, st, c = log.truth[rows], log.truth_state[rows], log.truth_constants
    if (rows < 0).any():  # a truth at a lower rate: NaN (no NEES) at the instants without a row
        tr, st = tr.copy(), st.copy()
        tr[rows < 0] = np.nan
        st[rows < 0] = np.nan
    model, sensors = log.model, log.sensors
    return StateTruth(theta=tr[:, 0], theta_dot=tr[:, 1], psi_l=st[:, 0], psi_r=st[:, 1], psi=tr[:, 2],
                      psi_dot=tr[:, 3], alpha=tr[:, 4], gyro_bias=st[:, 2:5], gyro_scale=c["gyro_scale"],
                      accel_scale=c["accel_scale"], encoder_phase=c["encoder_phase"],
                      imu_position=tuple(sensors.imu.position), wheel_radius=c["wheel_radius"],
                      b_over_r=float(model.b / model.r), resolution=float(sensors.encoders.resolution))


def filter_record(log: SensorLog | None, r: Replay):
    """The :class:`estimation.consistency.FilterRecord` of replay ``r`` (t from the first
    instant, s) with ``log``'s state truth (None if it has none), or None unless the estimator
    reported the EKF's ``x``, ``P`` and ``lag`` at every instant and they were kept (a replay
    of :func:`replay` with ``diagnostics``; :func:`replay_logs` keeps the NEES instead)."""
    if isinstance(r.diagnostics, DiagnosticsLog):
        return None
    ds = r.diagnostics
    if not ds or not all(isinstance(d, dict) and {"x", "P", "lag"} <= set(d) for d in ds):
        return None
    keys = ("x", "P", "nis", "nis_dof", "lag")
    flog = filter_log_of([{k: d[k] for k in keys if k in d} for d in ds], len(ds))
    if "nis" not in flog:
        flog["nis"], flog["nis_dof"] = np.full(len(ds), math.nan), np.zeros(len(ds), dtype=int)
    t = r.t - r.t[0]
    return FilterRecord(t, flog, None if log is None else state_truth(log, r.t))


def monte_carlo(records, start: float = NEES_START) -> dict | None:
    """:func:`estimation.consistency.monte_carlo` over the :func:`filter_record` of several logs of
    one estimator (each log an independent run; truncated to the shortest), in JSON: ``runs``,
    ``dim``, ``rows``, ``start_s``, ``nees_mean`` with its 95 % χ² ``nees_bounds`` and Student-t
    ``nees_mean_interval``, ``nees_inside`` (the fraction of instants whose average NEES lies in
    the bounds), ``nis_inside`` and ``nis_per_dof``; None with fewer than 2 records with truth, or
    with no instant where every record has its NEES.
    The records may also be :class:`twin.logs.diagnostics.NeesRecord` s (what :func:`replay_logs`
    keeps: the NEES of each instant), all of one kind."""
    recs = [x for x in records if x is not None and (isinstance(x, NeesRecord) or x.truth is not None)]
    if len(recs) < 2:
        return None
    m = mc_arrays(recs, start=start) if isinstance(recs[0], NeesRecord) else mc(recs, start=start)
    if m is None:
        return None
    return {"runs": m["runs"], "dim": m["dim"], "rows": m["rows"], "start_s": float(start),
            "nees_mean": m["nees_mean"], "nees_bounds": list(m["nees_bounds"]),
            "nees_mean_interval": list(m["nees_mean_interval"]), "nees_inside": m["nees_inside"],
            "nis_inside": m["nis_inside"], "nis_per_dof": m["nis_per_dof"]}


def replay_logs(paths, kinds, noise: str = "log") -> dict:
    """Every estimator kind of ``kinds`` on every log of ``paths``: {"logs": {path: {"duration_s", "instants",
    "noise", "estimators": {kind: {"errors", "consistency", "rejected_total", "step_us", ...}}}}, "estimators":
    {kind: {"monte_carlo": :func:`monte_carlo` over the logs with the state truth, or None}}} and the replays.

    ``noise``: which noise figures the estimators are built with (:func:`twin.logs.noise.choose`): "log" (the
    log's, or the measured ones where it gives none or its readings contradict them), "given", "measured" or
    "datasheet"; ``noise`` of each log's entry says which, per triad, and why."""
    from dataclasses import replace


    doc, replays, records = {"logs": {}}, {}, {k: [] for k in kinds}
    for p in paths:
        log = read_log(p)
        noise_entry, sensors, tuned = choose(log, noise)
        # the log as the estimators get it: its own SensorConfig (the very object) unless other noise
        # figures are in use, so a twin's log with its figures replays bit for bit
        run_log = log if sensors is log.sensors else replace(log, sensors=sensors)
        entry = {"duration_s": log.duration, "control_rate_hz": log.control_rate, "has_truth": log.truth is not None,
                 "format": format_entry(log), "notes": estimator_notes(log, kinds, bool(tuned)),
                 "noise": noise_entry,
                 # the gravity check's tolerance widens with the accelerometer's noise in use
                 "checks": sign_checks(log, accel_sigma=noise_entry["triads"]["accel"]["sigma"]), "streams": streams_entry(log), "estimators": {}}
        for kind in kinds:
            est = build_for(run_log, kind, _tuned_params(run_log, kind, tuned))
            if rows_clock(log) and not takes_periods(getattr(est, "set_sampling", None)):
                entry["notes"].append(f"{kind}: takes no periods = \"rows\" (its set_sampling): it steps as if every "
                                      f"row were 1 / control_rate apart")
            # the diagnostics as arrays (twin.logs.diagnostics): a long log's replay in memory that grows by
            # a few numbers an instant, not by the EKF's 12 × 12 covariance
            r = _replay(run_log, est, kind, "arrays" if callable(getattr(est, "diagnostics", None)) else None)
            replays[(str(p), kind)] = r
            entry["instants"] = len(r.t)
            records[kind].append(r.diagnostics.record(r.t) if r.diagnostics is not None else None)
            entry["estimators"][kind] = {
                "errors": errors(log, r), "consistency": consistency(r, log),
                "rejected_total": int(r.stats.get("rejected_total", 0)), "step_us": r.step_s * 1e6,
                "events": list(r.stats.get("events", []))}
        entry["truth"] = truth_usage(log, r.t) if kinds else None
        doc["logs"][str(p)] = entry
    doc["estimators"] = {k: {"monte_carlo": monte_carlo(records[k])} for k in kinds}
    return doc, replays


def _tuned_params(log: SensorLog, kind: str, tuned: dict) -> dict | None:
    """The parameters ``kind`` is built with for ``log``: None (:func:`build_for`'s own: the log's
    scenario's, or the published tuning) unless ``kind`` is kalman2 and measured noise figures are
    in use (``tuned``, from :func:`twin.logs.noise.choose`), which then replace its Q_angle and
    R_measure."""
    if kind != "kalman2" or not tuned:
        return None
    sc = log.scenario
    base = {}
    if sc is not None and sc.data["sensors"]["estimator"] == kind:
        base = dict(sc.data["sensors"]["estimator_params"] or {})
    return base | tuned


def format_entry(log: SensorLog) -> dict:
    """replay.json's ``format`` of a log: its version, what the reader assumed where the log is
    silent (version 1: everything version 2 states, from its scenario), one line ``text``, and
    ``applied``: what the replay does with what the log says (beyond handing the rows over)."""
    applied = []
    if log.imu_rotation is not None:
        applied.append("the IMU's readings turned into the body's axes (imu.orientation) before the estimators")
    if log.command_unit == "V":
        applied.append("commands in volts: duty = V / motor.supply_voltage, torque = duty × motor.stall_torque")
    if log.command_semantics == "sampled":
        applied.append("sampled commands: each control period gets the mean of the samples joined by straight lines")
    if rows_clock(log):
        gaps = np.diff(log.commands_t)
        gaps = gaps[gaps > INSTANT_TOLERANCE / log.control_rate]
        applied.append(f"command rows off the regular grid ({1e3 * float(gaps.min()):.4g}–{1e3 * float(gaps.max()):.4g} ms "
                       f"apart): the instants are the rows, each step over its own period")
    enc = log.sensors.encoders
    if log.version == 2 and (log.manifest.get("encoders") or {}).get("on") == "motor":
        applied.append(f"encoders on the motor: {enc.counts_per_rev} counts per wheel revolution")
    info = dict(log.format_info)
    info["applied"] = applied
    return info


def estimator_notes(log: SensorLog, kinds, tuned: bool = False) -> list:
    """What the log says that an estimator of ``kinds`` cannot use (yet), one line each (with the
    reader's own notes, e.g. a latency rounded to whole control periods). ``tuned``: kalman2 is
    tuned from measured noise figures (:func:`twin.logs.noise.choose`)."""
    notes = list(log.notes)
    imu = log.sensors.imu
    for kind in kinds:
        if kind == "ekf":
            if log.sampling == "point":
                notes.append("ekf: imu.sampling = \"point\": its strapdown step takes each interval's mean as the "
                             "trapezoid of the samples at its ends")
            if log.command_semantics == "sampled":
                notes.append("ekf: commands sampled from a faster loop: its latency watch is off (that loop reacts "
                             "to the rates within a row, which the watch would take for a changed latency)")
            if log.imu_rotation is not None:
                notes.append("ekf: its clipping test holds the IMU's full scales against the body's axes, not the "
                             "IMU's own, once the readings are turned into body axes")
            if imu.gyro.bias_correlation_time is not None:
                notes.append("ekf: models the gyro's bias as a random walk of imu.gyro.bias_random_walk; "
                             "imu.gyro.bias_correlation_time is not used")
        elif kind == "kalman2" and tuned:
            notes.append("kalman2: tuned from the measured noise (Q_angle = σ_g² Δt, R_measure = (σ_a / g)², "
                         "replay.json's noise.kalman2) instead of its published tuning; uses none of the log's "
                         "ranges or latencies (each reading as of its row's instant)")
        elif kind in ("complementary", "kalman2"):
            notes.append(f"{kind}: uses none of the log's noise figures, ranges or latencies (its own tuning; each "
                         f"reading as of its row's instant)")
    if log.command_semantics == "sampled" and log.duty is not None:
        notes.append("duty.csv is held over each period as the format says, whatever commands.semantics")
    return notes


def streams_entry(log: SensorLog) -> dict:
    """replay.json's ``streams``: each stream log.toml declares beyond the format's, as read; a
    sensor channel's (:attr:`SensorLog.channels`) is handed to every estimator (``used_by``: "channel")."""
    out = {}
    channels = log.channels
    for name, st in log.streams.items():
        n = len(st.t)
        use = ("a sensor channel: handed to the estimators (Measurement.extra), for those that read it"
               if name in channels else "read and checked; no estimator uses it")
        out[name] = {"file": st.file, "rows": n, "columns": dict(zip(st.columns, st.units)),
                     "t_first_s": float(st.t[0]) if n else None, "t_last_s": float(st.t[-1]) if n else None,
                     "latency_s": st.latency, "used_by": ["channel"] if name in channels else [],
                     "text": f"stream {name} ({st.file}): {n} rows, "
                             + ", ".join(f"{c} [{u}]" for c, u in zip(st.columns, st.units)) + f": {use}"}
    return out


def truth_usage(log: SensorLog, t: np.ndarray) -> dict | None:
    """How the log's truth meets the replay's instants ``t`` (see the module docstring): its rows
    at control instants, between them (errors against interpolated estimates), outside the
    replay; its rate; where the EKF's NEES is computed, or why not; one line ``text``."""
    if log.truth is None:
        return None
    k, on, between = _truth_rows(log, t)
    tt = log.truth_t
    at = np.unique(k[on])
    span = float(tt[-1] - tt[0]) if len(tt) > 1 else 0.0
    rate = (len(tt) - 1) / span if span > 0 else None
    if log.truth_state is None or log.truth_constants is None:
        nees = "no state truth (truth.csv's psi_l … gyro_bias_z and the [truth] table): no NEES"
    elif not at.size:
        nees = ("not computed: no truth row lies on a control instant; the NEES needs the state truth at the "
                "filter's own instants")
    elif at[0] != 0:
        nees = (f"not computed: no truth row at the first control instant (t = {float(t[0]):g} s), the encoders' "
                f"reference")
    elif at.size == len(t):
        nees = "at every control instant"
    else:
        nees = f"at the {at.size} control instants with a truth row (of {len(t)})"
    outside = int((~on & ~between).sum())
    parts = [f"{int(on.sum())} at control instants"]
    if between.any():
        parts.append(f"{int(between.sum())} between them (errors against the estimates interpolated to them)")
    if outside:
        parts.append(f"{outside} outside the replay (left out)")
    text = (f"truth: {len(tt)} rows" + (f" (about {rate:.4g} Hz)" if rate else "") + f": {', '.join(parts)}; "
            f"NEES {nees}")
    return {"rows": int(len(tt)), "rate_hz": rate, "at_instants": int(on.sum()), "between_instants": int(between.sum()),
            "outside": outside, "instants_with_truth": int(at.size), "nees": nees, "text": text}


def summary_lines(entry: dict) -> list:
    """The lines ``twin replay`` prints about one log beyond its table: the format (version 1:
    what it leaves unsaid and what was assumed), the notes, the noise figures in use and why, the
    truth's use, the sign checks and the other streams."""
    out = [entry["format"]["text"]]
    out += [f"applied: {a}" for a in entry["format"].get("applied", [])]
    out += [f"note: {n}" for n in entry.get("notes", [])]
    if entry.get("noise"):
        out.append(entry["noise"]["text"])
    if entry.get("truth"):
        out.append(entry["truth"]["text"])
    out += [f"check {c['text']}" for c in entry.get("checks", {}).values()]
    out += [s["text"] for s in entry.get("streams", {}).values()]
    return out


def replay_logs_contained(paths, kinds, noise: str = "log") -> dict:
    """:func:`replay_logs`, in a worker process the command kills (:mod:`twin.containment`) if an
    estimator is a user's code (``package.module:attribute``, or an export directory's C): its
    exit, its crash, its threads and its processes end with the replay, which then ends with one
    line naming it. Built-in estimators alone replay here. The same numbers either way."""
    # only for plugin estimators, each replayed in a process of its own
    from twin.containment import Task, run_contained

    plugins = tuple(("estimator", k) for k in kinds if is_user_code(k))
    if not plugins:
        return replay_logs(paths, kinds, noise)
    return run_contained(Task(replay_logs, ([str(p) for p in paths], list(kinds), noise), plugins=plugins,
                              what="replay"))


def write_estimates_csv(replays: dict, path) -> None:
    """One row per log, estimator and instant: log, estimator, t, θ, θ̇, ψ, ψ̇, α, α̇ (s, rad, rad/s)."""
    import csv

    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["log", "estimator", "t [s]", "theta [rad]", "theta_dot [rad/s]", "psi [rad]", "psi_dot [rad/s]",
                    "alpha [rad]", "alpha_dot [rad/s]"])
        for (log, kind), r in replays.items():
            for a in range(0, len(r.t), CHUNK):  # a chunk of rows as Python floats at a time, not the whole log
                for t, row in zip(r.t[a:a + CHUNK].tolist(), r.estimates[a:a + CHUNK].tolist()):
                    fh.write(",".join([log, kind, repr(t)] + [repr(v) for v in row]) + "\r\n")


FIGURE_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
FIGURE_POINTS = 20_000  # points a curve of the figure is drawn with at most (a panel is ~550 pixels wide)


def _thinned(t: np.ndarray, y: np.ndarray, points: int = FIGURE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) as drawn: every point of a curve of at most ``points``; of a longer one (a long
    log's: 10⁶ instants would cost the figure seconds and hundreds of MB for what no pixel
    shows), the lowest and the highest point of each of ``points / 2`` equal runs of samples, in
    time order: the envelope the full curve draws at the figure's resolution."""
    n = len(t)
    if n <= points:
        return t, y
    runs = points // 2
    size = -(-n // runs)  # samples per run (the last one may be shorter)
    pad = runs * size - n
    v = np.concatenate([y, np.full(pad, np.nan)]).reshape(runs, size)
    base = np.arange(runs) * size
    lo = base + np.argmin(np.where(np.isnan(v), np.inf, v), axis=1)  # (a gap, NaN, is no extreme)
    hi = base + np.argmax(np.where(np.isnan(v), -np.inf, v), axis=1)
    idx = np.sort(np.concatenate([lo, hi]))
    idx = idx[idx < n]
    return t[idx], y[idx]


def figure_name(k: int) -> str:
    """The figure of log number ``k`` (0-based) of a replay: figure.png, figure-2.png, ..."""
    return "figure.png" if k == 0 else f"figure-{k + 1}.png"


def write_figure(doc: dict, replays: dict, path, confidence: float = 0.95, which: int = 0) -> None:
    """The figure of a replay's log number ``which`` (0: the first) of ``doc``: θ, ψ and α of every estimator
    against the truth (black; without truth, against each other), and every NIS-reporting
    estimator's NIS per degree of freedom at each update, on a log scale, with the two-sided
    ``confidence`` χ² bounds of one update of each dof present (χ²_d quantiles / d). Drawn as
    :mod:`twin.outputs.figure` draws: matplotlib's object API on the Agg canvas, no pyplot."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from scipy.stats import chi2

    # heavy: matplotlib comes with the figure module, only when a figure is drawn
    from twin.outputs.figure import DPI, PNG_COMPRESSION

    first = list(doc["logs"])[which]
    runs = [(kind, r) for (p, kind), r in replays.items() if p == first]
    log = runs[0][1].log if runs and runs[0][1].log is not None else read_log(first)  # read once, by the replay
    fig = Figure(figsize=(12.0, 8.0), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2, sharex=True).ravel()
    panels = (("θ [rad]", 0, 0), ("ψ [rad] (mean wheel angle)", 2, 1), ("heading α [rad]", 4, 2))
    truth = None if log.truth is None else (log.truth_t, log.truth)
    for ax, (title, j, _) in zip(axes, panels):
        ax.set_title(title, fontsize=9)
        if truth is not None:
            ax.plot(*_thinned(truth[0], truth[1][:, j]), color="k", lw=1.6, label="truth")
        for i, (kind, r) in enumerate(runs):
            ax.plot(*_thinned(r.t, r.estimates[:, j]), color=FIGURE_COLOURS[i % len(FIGURE_COLOURS)], lw=1.0,
                    label=kind)
    ax = axes[3]
    ax.set_title(f"NIS per degree of freedom at each update ({confidence:.0%} χ² bounds of one update dashed)",
                 fontsize=9)
    a = 0.5 * (1.0 - confidence)
    dofs = set()
    for i, (kind, r) in enumerate(runs):
        if not r.diagnostics:
            continue
        nis, dof = _nis_and_dof(r)
        dof = dof.astype(int)
        on = np.isfinite(nis) & (dof > 0)
        if not on.any():
            continue
        c = FIGURE_COLOURS[i % len(FIGURE_COLOURS)]
        per = doc["logs"][first]["estimators"][kind]["consistency"].get("nis_per_dof", math.nan)
        ax.plot(*_thinned(r.t[on], np.maximum(nis[on] / dof[on], 1e-6)), ls="none", marker=".", ms=2.5, color=c,
                label=f"{kind} (mean {per:.3g})")
        dofs |= set(dof[on].tolist())
    for d in sorted(dofs):
        lo, hi = chi2.ppf([a, 1.0 - a], d) / d
        ls = "--" if d == 1 else ":"
        ax.axhline(lo, color="0.3", ls=ls, lw=0.9, label=f"bounds, {d} dof: {lo:.2g}, {hi:.3g}")
        ax.axhline(hi, color="0.3", ls=ls, lw=0.9)
    if dofs:
        ax.set_yscale("log")
    else:
        ax.text(0.5, 0.5, "no estimator reports NIS", ha="center", va="center", transform=ax.transAxes,
                fontsize=9, color="0.4")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(loc="best", fontsize=7)
    for ax in axes[2:]:
        ax.set_xlabel("time [s]")
    n = len(doc["logs"])
    fig.suptitle(f"twin replay: {first}" + (f" (log {which + 1} of {n})" if n > 1 else "")
                 + ("" if log.truth is not None else ": no truth, the estimators against each other"), fontsize=10)
    fig.set_layout_engine("tight", rect=(0, 0, 1, 0.96))
    fig.savefig(path, dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESSION})
