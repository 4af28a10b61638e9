"""Limits on what a controller and an estimator may cost a run: wall time per control step,
wall time per run, and the growth of the process's resident memory over a run.

A scenario sets them with ``[limits]`` (``step_wall_s``, ``run_wall_s``, ``run_memory_mb``;
absent: no limit); :class:`PluginLimits` carries them in the twin's
:class:`~twin.plant.bullet.TwinConfig` to :class:`twin.sim.loop.ClosedLoop`, which times each
call of the controller and of the estimator with :class:`RunGuard` and stops the run with
one :class:`~twin.errors.PluginError` line naming the plugin and the limit. Each run of a
loop (each :meth:`~twin.sim.loop.ClosedLoop.reset`) starts its own clock: in a scenario with
several controllers, each controller's run has the whole budget, whatever the others took.

Two enforcers. In the run's own process :class:`RunGuard` checks each call when it returns
(the time it took, the run's time so far, and, with a memory limit, the resident memory
after every call of the controller or the estimator): what it stops, it names precisely.
A call that never returns cannot be stopped from inside the process; that is the second
enforcer's: the ``twin`` commands run every run that involves a user's plugin in a worker
process (:mod:`twin.containment`), which publishes through :data:`STATUS` (shared memory)
when its run started, which plugin call is under way since when, and its memory baseline;
the command reads it and kills the worker when a limit is overrun by more than a grace.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from time import perf_counter

from twin.errors import PluginError, TwinError
from twin.protocols import describe_object

MEMORY_EVERY = 1  # control steps between two reads of the resident memory: every call (about 3 µs a read on Linux)
MB = 1e6  # bytes: the limits' memory unit (SI megabyte)

# What a plugin's call may raise that is the plugin's failure, reported as a PluginError naming it:
# any Exception, and SystemExit (a plugin may not end the process; sys.exit() in a controller
# ended 'twin run' with exit status 0 and nothing written). In a contained worker
# (twin.containment) KeyboardInterrupt too: the worker ignores SIGINT, so only a plugin raises it
# there; in one's own process Ctrl-C is a KeyboardInterrupt and must stay one.
PLUGIN_FAILURES: tuple = (Exception, SystemExit)

# The shared status of a contained worker's run (twin.containment sets it in the worker; None
# elsewhere): a float64 array read by the command that started the worker. Its slots:
RUN_T0, CALL_T0, ROLE, METHOD, STEP, RSS0, DT, PEAK = range(8)
STATUS_SIZE = 8
ROLES = ("", "controller", "estimator", "plant")  # ROLE's values: 0 none, 1 controller, ...
METHODS = ("", "reset()", "__call__()", "start()", "step()", "building it", "importing it")
STATUS = None
IMPORTING, BUILDING = 6, 5  # METHODS' indices of a plugin's import and construction


def mark(role: int, method: int) -> None:
    """A contained worker's plugin ``role`` begins ``method`` outside a run (its import or its
    construction: :data:`IMPORTING`, :data:`BUILDING`), for the command that watches; nothing
    elsewhere."""
    status = STATUS
    if status is not None:
        status[ROLE] = role
        status[METHOD] = method
        status[STEP] = 0
        status[CALL_T0] = perf_counter()


def unmark() -> None:
    """The call :func:`mark` announced returned."""
    status = STATUS
    if status is not None:
        status[CALL_T0] = 0.0


@dataclass(frozen=True)
class PluginLimits:
    """What one run may cost; None: no limit.

    ``step_wall_s``: seconds of wall time one call of the controller (``__call__``) or of
    the estimator (``step``) may take; ``run_wall_s``: seconds of wall time one run may take
    from its :meth:`~twin.sim.loop.ClosedLoop.reset` (the twin's own time included);
    ``run_memory_mb``: MB (10⁶ bytes) by which the process's resident memory may grow over
    one run (Linux: the current resident set; elsewhere its peak)."""

    step_wall_s: float | None = None
    run_wall_s: float | None = None
    run_memory_mb: float | None = None

    def __post_init__(self):
        for name in ("step_wall_s", "run_wall_s", "run_memory_mb"):
            v = getattr(self, name)
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                unit = "MB" if name == "run_memory_mb" else "s"
                raise TwinError(f"limits.{name} must be a positive finite number in {unit} or None (no limit), "
                                f"got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.run_memory_mb is not None and _reader() is None:
            raise TwinError(f"limits.run_memory_mb needs the process's resident memory, which this platform "
                            f"({sys.platform}) does not report; leave it out here")

    @property
    def active(self) -> bool:
        return self.step_wall_s is not None or self.run_wall_s is not None or self.run_memory_mb is not None


_STATM_FD: list = []  # /proc/self/statm held open (in this process: a forked child reopens it), read with pread


def _statm() -> int:
    """The current resident set in bytes (Linux): about 3 µs with the file held open."""
    pid = os.getpid()
    if not _STATM_FD or _STATM_FD[0] != pid:
        _STATM_FD[:] = [pid, os.open("/proc/self/statm", os.O_RDONLY)]
    return int(os.pread(_STATM_FD[1], 128, 0).split()[1]) * _PAGE


def resident_of(pid: int) -> int | None:
    """The resident set in bytes of process ``pid`` (Linux), None if it is gone or unknown."""
    try:
        with open(f"/proc/{pid}/statm", "rb") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


def _maxrss() -> int:
    """The peak resident set in bytes (macOS, the BSDs): ru_maxrss is in bytes on macOS, KiB elsewhere."""
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024


def _reader():
    """The function reading the resident memory here, or None."""
    global _PAGE
    try:
        _PAGE = os.sysconf("SC_PAGE_SIZE")
        _statm()
        return _statm
    except (OSError, ValueError, AttributeError, IndexError):
        pass
    try:
        _maxrss()
        return _maxrss
    except (ImportError, OSError, ValueError):
        return None


_PAGE = 4096


def resident_bytes() -> int | None:
    """The process's resident memory in bytes (see :class:`PluginLimits`), or None where unknown."""
    read = _reader()
    return None if read is None else read()


class RunGuard:
    """Enforces :class:`PluginLimits` over the runs of one loop: :meth:`start` at each reset,
    :meth:`charge` after each timed call, :meth:`memory` every :data:`MEMORY_EVERY` steps."""

    __slots__ = ("limits", "step", "run", "memory_bytes", "controller", "estimator", "control_dt", "t0", "spent",
                 "rss0", "_read", "status")

    def __init__(self, limits: PluginLimits, controller, estimator, control_dt: float):
        self.limits = limits = limits if limits is not None else PluginLimits()
        self.status = STATUS  # a contained worker's shared status, or None
        inf = math.inf
        self.step = limits.step_wall_s if limits.step_wall_s is not None else inf
        self.run = limits.run_wall_s if limits.run_wall_s is not None else inf
        self.memory_bytes = limits.run_memory_mb * MB if limits.run_memory_mb is not None else None
        self.controller, self.estimator, self.control_dt = controller, estimator, control_dt
        self._read = _reader() if self.memory_bytes is not None else None
        self.t0 = perf_counter()
        self.spent = {"controller": 0.0, "estimator": 0.0}
        self.rss0 = 0

    def start(self) -> None:
        """A new run: its clock, its plugins' time and its memory baseline start now."""
        self.spent = {"controller": 0.0, "estimator": 0.0}
        self.rss0 = self._read() if self._read is not None else 0
        self.t0 = perf_counter()
        status = self.status
        if status is not None:
            status[RSS0] = self.rss0 if self._read is not None else (resident_bytes() or 0)
            status[DT] = self.control_dt
            status[CALL_T0] = 0.0
            status[RUN_T0] = self.t0

    def enter(self, role: int, method: int, k: int) -> float:
        """A call of the ``role`` (1 controller, 2 estimator: :data:`ROLES`) begins, its
        ``method`` (:data:`METHODS`) at control step ``k``: published for the command that
        watches a contained worker; the time it began (perf_counter)."""
        t0 = perf_counter()
        status = self.status
        if status is not None:
            status[ROLE] = role
            status[METHOD] = method
            status[STEP] = k
            status[CALL_T0] = t0
        return t0

    def leave(self) -> float:
        """The call begun by :meth:`enter` returned; the time it did (perf_counter)."""
        t1 = perf_counter()
        status = self.status
        if status is not None:
            status[CALL_T0] = 0.0
        return t1

    def charge(self, role: str, dt: float, now: float, k: int, per_step: bool = True) -> None:
        """``role`` ("controller" or "estimator") took ``dt`` s in one call that ended at
        ``now`` (perf_counter) at control step ``k``: a PluginError if that is over a limit."""
        self.spent[role] += dt
        if self.memory_bytes is not None:  # after every call: a plugin that grows a lot per call is seen at once
            self.memory(k)
        if per_step and dt > self.step:
            raise _over("step_wall_s", f"{self._who(role)} took {dt:.3g} s for one control step, over "
                                       f"limits.step_wall_s = {self.step:g} s (at t = {k * self.control_dt:.3f} s)")
        if now - self.t0 > self.run:
            self.over_run(now, k)

    def over_run(self, now: float, k: int) -> None:
        total = now - self.t0
        c, e = self.spent["controller"], self.spent["estimator"]
        parts = ([f"{c:.3g} s in the controller"] if self.controller is not None else []) + (
            [f"{e:.3g} s in the estimator"] if self.estimator is not None else []) + [
            f"{max(0.0, total - c - e):.3g} s in the plant and the rest"]
        raise _over("run_wall_s", f"{self._run_of()} took {total:.3g} s, over limits.run_wall_s = {self.run:g} s "
                                  f"(stopped at t = {k * self.control_dt:.3f} s: {', '.join(parts)})")

    def memory(self, k: int) -> None:
        """A PluginError if the resident memory grew by more than the limit since :meth:`start`."""
        grown = self._read() - self.rss0
        if grown > self.memory_bytes:
            raise _over("run_memory_mb", f"{self._run_of()} grew the process's resident memory by "
                                         f"{grown / MB:.4g} MB, over limits.run_memory_mb = "
                                         f"{self.memory_bytes / MB:g} MB (at t = {k * self.control_dt:.3f} s; the "
                                         f"run's own log takes about 0.4 kB per control step)")

    def _who(self, role: str) -> str:
        return f"{role} {describe_object(self.controller if role == 'controller' else self.estimator)}"

    def _run_of(self) -> str:
        if self.estimator is None:  # the analytic loop: the controller reads the true state
            return f"the run of {self._who('controller')}"
        estimator = describe_object(self.estimator)
        if self.controller is not None:
            return f"the run of {self._who('controller')} (estimator {estimator})"
        return f"the run with estimator {estimator}"


def _over(limit: str, message: str) -> PluginError:
    """The PluginError of a run stopped by ``limit`` (a key of :class:`PluginLimits`), carrying
    it as ``exc.limit`` (see :func:`limit_of`)."""
    exc = PluginError(message)
    exc.limit = limit
    return exc


def limit_of(exc: BaseException) -> str | None:
    """The limit (``"step_wall_s"``, ``"run_wall_s"`` or ``"run_memory_mb"``) that stopped the run
    ``exc`` ended, or None if ``exc`` is not a limit's PluginError (a broken contract, say)."""
    limit = getattr(exc, "limit", None) if isinstance(exc, PluginError) else None
    return limit if limit in LIMIT_KEYS else None


LIMIT_KEYS = ("step_wall_s", "run_wall_s", "run_memory_mb")

def over(limit: str, message: str) -> PluginError:
    """The PluginError of a run stopped by ``limit``, as :class:`RunGuard` raises it (for the
    command that stops a contained worker from outside)."""
    return _over(limit, message)


__all__ = ["LIMIT_KEYS", "MEMORY_EVERY", "PLUGIN_FAILURES", "PluginLimits", "RunGuard", "limit_of", "over",
           "resident_bytes", "resident_of"]
