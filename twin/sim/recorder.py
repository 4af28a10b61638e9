"""A run's log, kept apart from the loop: :class:`Recorder` is fed what
:class:`twin.sim.loop.ClosedLoop` publishes (its :class:`~twin.protocols.StepResult` at every
control instant and the command computed from it) and makes the :class:`twin.sim.runs.Run`.

It reads nothing of the loop's internals, the way a logger is attached to a system's
outputs: whoever drives the loop hands it what the loop returned::

    rec = Recorder.for_loop(loop, steps=n + 1)
    res = loop.reset(seed)
    for i in range(n + 1):
        if res.status == "diverged":        # a non-finite state is not logged
            break
        u = loop.command()
        rec.instant(res, u)                 # row i: truth, measurement, gyro bias, estimate, command
        if i == n or res.status != "running":
            break
        res = loop.step(u)
        rec.period(res)                     # row i's actuation and push, over [t_i, t_i+1)
    run = rec.run(status, reason, config, experiment=...)

:func:`twin.sim.bullet_loop.simulate_twin` is that driver. One's own logger is fed the same
way (the step results carry everything; see :class:`~twin.protocols.StepResult`).

Memory: the step results are gathered for a chunk of ``chunk`` control steps at a time
(the cheapest thing to append in the loop), then moved into preallocated float64 arrays,
so a run costs about 8 bytes per logged number. With ``log_every`` N > 1 only every N-th
step is kept, and :data:`twin.sim.runs.FULL_RATE_NAMES` at every step (``Run.full_rate``).
"""
from __future__ import annotations

from itertools import chain, repeat
from operator import attrgetter, is_

import numpy as np

from twin.errors import TwinError
from twin.sensors.types import type_of
from twin.sim.runs import (ACTUATION_NAMES, ESTIMATE_NAMES, FULL_RATE_NAMES, PUSH_NAMES, TRUTH_NAMES, MeasurementLog,
                       Run)

CHUNK = 4096  # control steps gathered before they move into the log's arrays

__all__ = ["CHUNK", "Recorder", "check_log_every"]

_NO_ACTUATION = (0.0,) * len(ACTUATION_NAMES)
_NO_PUSH = (0.0,) * len(PUSH_NAMES)
# a step result's fields, read for a whole chunk at once (map: no Python frame per row)
_TRUTH, _MEASUREMENT, _ESTIMATE, _GYRO_BIAS, _ACTUATION, _PUSH = (
    attrgetter(name) for name in ("truth", "measurement", "estimate", "gyro_bias", "actuation", "push_force"))


def check_log_every(value) -> int:
    """``log_every`` as an int, or a TwinError naming what is allowed."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise TwinError(f"log_every must be a whole number of control steps ≥ 1 (1: log every step), got {value!r}")
    return int(value)


class Recorder:
    """A run's log, fed one control instant and one control period at a time.

    Parameters
    ----------
    steps : int
        The most control instants the run can have (rows of the log with N = 1); the arrays
        are allocated for them (``np.empty``: a row takes memory once it is written).
    command_names : sequence of str
        The command's columns: ``("ul_cmd", "ur_cmd")`` and the controller's ``signals``.
    measured : bool
        Log the measurements and the gyro's true bias (False: ideal sensing, nothing measured).
    with_truth : bool
        The measurements carry the ground truth (an estimator that ``reads_truth``).
    log_every : int
        N ≥ 1: keep control steps 0, N, 2N, … (and the metrics' signals at every step).
    diagnostics : bool
        Keep the estimator's ``diagnostics()`` given to :meth:`instant` (``Run.filter_log``).
    channels : sequence of twin.sensors.channels.Channel
        The extra channels the measurements carry (``Measurement.extra``: the motor current, say),
        logged beside the core three (``MeasurementLog.extra``).
    chunk : int
        Control steps gathered before they move into the arrays.

    Feed it :meth:`instant` at every control instant logged (in order, from 0) and
    :meth:`period` after every step that followed one; :meth:`run` then gives the Run.
    """

    def __init__(self, steps: int, command_names=("ul_cmd", "ur_cmd"), *, measured: bool = True,
                 with_truth: bool = False, log_every: int = 1, diagnostics: bool = False, chunk: int = CHUNK,
                 channels=()):
        self.every = every = check_log_every(log_every)
        if diagnostics and every > 1:
            raise TwinError(f"the estimator's diagnostics need every control step, so log_every must be 1 with "
                            f"them, got {log_every!r}")
        if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
            raise TwinError(f"chunk must be a whole number of control steps ≥ 1, got {chunk!r}")
        self.steps = int(steps)
        self.chunk = int(chunk)
        self.command_names = tuple(command_names)
        k = self._kept(self.steps)
        self.truth = np.empty((k, len(TRUTH_NAMES)))
        self.est = np.empty((k, len(ESTIMATE_NAMES)))
        self.cmds = np.empty((k, len(self.command_names)))
        self.act = np.empty((k, len(ACTUATION_NAMES)))
        self.push = np.empty((k, len(PUSH_NAMES)))
        self.meas = MeasurementLog.empty(k, with_truth, channels) if measured else None
        self.bias = np.empty((k, 3)) if measured else None  # the gyro's true bias, NaN on steps without a sample
        self.full = {name: np.empty(self.steps) for name in FULL_RATE_NAMES} if every > 1 else None
        self._diag = [] if diagnostics else None
        self._instants, self._commands, self._periods = [], [], []
        self._held = (_NO_ACTUATION, _NO_PUSH)  # the last period's actuation and push, for a last row without one
        self._start = 0  # the control step of the gathered lists' first row
        self.n = 0  # control instants recorded
        self._due = min(self.steps, self.chunk)  # instant() looks further at n = this: a chunk or the log full

    @classmethod
    def for_loop(cls, loop, steps: int, *, log_every: int = 1, diagnostics: bool = False,
                 chunk: int = CHUNK) -> "Recorder":
        """A recorder for what ``loop`` (a :class:`twin.sim.loop.ClosedLoop`) publishes: its
        controller's ``signals``, whether it has ``sensors`` (and which extra channels), and
        whether its estimator ``reads_truth`` (public attributes, read once)."""
        sensors = loop.sensors
        channels = () if sensors is None else tuple(c for s in sensors.extra for c in type_of(s).channels)
        return cls(steps, ("ul_cmd", "ur_cmd") + tuple(loop.signals), measured=sensors is not None,
                   with_truth=bool(getattr(loop.estimator, "reads_truth", False)), log_every=log_every,
                   diagnostics=diagnostics, chunk=chunk, channels=channels)

    # ---- fed by the driver --------------------------------------------------------------------
    def instant(self, result, command, diagnostics=None) -> None:
        """Control instant ``n`` (the next row): ``result`` the loop's
        :class:`~twin.protocols.StepResult` there (truth, measurement, gyro bias, estimate) and
        ``command`` (ul, ur, *signals) the controller's output on it; ``diagnostics`` the
        estimator's, when the recorder keeps them."""
        n = self.n
        if n >= self._due:  # (once per chunk: the log is full, or the gathered chunk is)
            if n >= self.steps:
                raise TwinError(f"the recorder holds {self.steps} control instants; make it for more")
            self.flush()
        self._instants.append(result)
        self._commands.append(command)
        if self._diag is not None:
            self._diag.append(diagnostics)
        self.n = n + 1

    def period(self, result) -> None:
        """The control period after the last instant: ``result`` the StepResult the loop's step
        returned, whose ``actuation`` and ``push_force`` the last row gets. A row that no
        period follows (the run's last: it ends before that row's command is applied) repeats
        the period before it, what the motors were delivering when the run ended, rather
        than zeros that would read as the torque dropping to nothing at the end (zeros
        only for a run of a single instant)."""
        if len(self._periods) >= len(self._instants):
            raise TwinError("Recorder.period() follows an instant(): one period per step after a logged instant")
        self._periods.append(result)

    # ---- the log ------------------------------------------------------------------------------
    def _kept(self, steps: int) -> int:
        """Rows logged out of the first ``steps`` control steps."""
        return (steps + self.every - 1) // self.every

    def flush(self) -> None:
        """Move the gathered steps into the arrays (every N-th of them; the metrics' signals all)."""
        instants = self._instants
        m = len(instants)
        if not m:
            return
        periods = self._periods
        s, every = self._start, self.every
        first = (-s) % every  # the lists' first row that is a logged step
        r0 = (s + first) // every
        r1 = r0 + len(range(first, m, every))
        pick = slice(first, m, every)
        act_rows = list(map(_ACTUATION, periods))
        push_rows = list(map(_PUSH, periods))
        if periods:
            self._held = (act_rows[-1], push_rows[-1])
        if len(periods) < m:  # the run's last row: it ends before that row's command is applied
            act_rows += [self._held[0]] * (m - len(periods))  # what the motors were delivering then
            push_rows += [self._held[1]] * (m - len(periods))
        truth = _array(list(map(_TRUTH, instants)), m, len(TRUTH_NAMES))
        est = _array(list(map(_ESTIMATE, instants)), m, len(ESTIMATE_NAMES))
        act = _array(act_rows, m, len(ACTUATION_NAMES))
        self.truth[r0:r1] = truth[pick]
        self.est[r0:r1] = est[pick]
        self.act[r0:r1] = act[pick]
        commands = self._commands[pick]
        try:
            one_length = len(set(map(len, commands))) == 1
        except TypeError:
            one_length = False
        if one_length:
            self.cmds[r0:r1] = _array(commands, r1 - r0, self.cmds.shape[1])
        else:  # (none kept, or a driver's own commands of mixed lengths: np.array says what is wrong)
            self.cmds[r0:r1] = np.array(commands, dtype=float).reshape(r1 - r0, self.cmds.shape[1])
        self.push[r0:r1] = _array(push_rows[pick], r1 - r0, len(PUSH_NAMES))
        if self.meas is not None:
            kept = instants[pick]
            self.meas.put(r0, list(map(_MEASUREMENT, kept)))
            bias = list(map(_GYRO_BIAS, kept))
            if not any(map(is_, bias, repeat(None))):  # a gyro sample at every instant kept
                self.bias[r0:r1] = _array(bias, r1 - r0, 3)
            else:
                self.bias[r0:r1] = np.nan
                where = [j for j, b in enumerate(bias) if b is not None]
                if where:
                    self.bias[r0 + np.array(where)] = [bias[j] for j in where]
        if self.full is not None:
            rows = slice(s, s + m)
            f = self.full
            f["t"][rows] = truth[:, TRUTH_NAMES.index("t")]
            f["theta"][rows] = truth[:, TRUTH_NAMES.index("theta")]
            f["distance"][rows] = truth[:, TRUTH_NAMES.index("distance")]
            f["alpha"][rows] = truth[:, TRUTH_NAMES.index("alpha")]
            f["theta_est"][rows] = est[:, ESTIMATE_NAMES.index("theta_est")]
            f["torque_l"][rows] = act[:, ACTUATION_NAMES.index("torque_l")]
            f["torque_r"][rows] = act[:, ACTUATION_NAMES.index("torque_r")]
        instants.clear()
        self._commands.clear()
        periods.clear()
        self._start = s + m
        self._due = min(self.steps, self._start + self.chunk)

    def run(self, status: str, reason: str, config, command_units=None, **fields) -> Run:
        """The :class:`twin.sim.runs.Run` of what was recorded: ``status`` "ok", "fell" or "diverged",
        ``reason`` why it ended, ``config`` the TwinConfig (or None); ``command_units`` one unit
        per command column (default "1" each, "N·m" for the torques); ``fields`` the Run's other
        fields (experiment, controller, sensing, estimator_stats, sensor_counts, seed,
        sensor_truth, sensor_config, model_params, plant)."""
        self.flush()
        n = self.n
        rows = self._kept(n)
        truth, est, cmds, act, push = (a[:rows] for a in (self.truth, self.est, self.cmds, self.act, self.push))
        if command_units is None:
            command_units = tuple("N·m" if k in ("ul_cmd", "ur_cmd") else "1" for k in self.command_names)
        return Run(truth[:, 0].copy(), truth, cmds, act, push, status, reason, config, estimates=est,
                   measurements=[] if self.meas is None else self.meas[:rows],
                   gyro_bias=None if self.bias is None else self.bias[:rows], filter_log=filter_log_of(self._diag, n),
                   command_names=self.command_names, command_units=tuple(command_units), log_every=self.every,
                   full_rate=None if self.full is None else {name: a[:n] for name, a in self.full.items()}, **fields)


def _array(rows, m: int, k: int) -> np.ndarray:
    """``rows`` (m rows of k numbers each) as an (m, k) float64 array, bit for bit as
    ``np.array(rows, dtype=float).reshape(m, k)`` gives it (each number converted alone, as
    float()), in a third less time than that takes on tuples (namedtuples above all). Rows
    whose numbers do not add up to m·k, or a value that does not convert, go that way (and
    fail as they did). The rows must be of one length: the loop's own are (truth, estimate,
    actuation, push, gyro bias: fixed by their types and the loop's checks); the commands,
    which a driver gives, :meth:`Recorder.flush` checks first."""
    try:
        a = np.fromiter(chain.from_iterable(rows), float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.size != m * k:
        return np.array(rows, dtype=float).reshape(m, k)
    return a.reshape(m, k)


def filter_log_of(diag: list | None, n: int) -> dict | None:
    """The estimator's per-step diagnostics as arrays: for the EKF ``x`` (n, 12), ``P`` (n, 12, 12),
    ``nis`` (n,), ``nis_dof`` (n,) and ``lag`` (n,) the lag in force at each row (control
    periods: it changes when the filter detects a latency change); None if not logged or no hook."""
    if not diag or diag[0] is None:
        return None
    diag = diag[:n]
    out = {}
    for key, first in diag[0].items():
        if key in ("lag", "nis_dof"):
            out[key] = np.array([d[key] for d in diag], dtype=int)
        else:
            out[key] = np.array([d[key] for d in diag], dtype=float)
    return out
