"""Plugin code where it can be stopped: a user's plugins run in worker processes the command kills.

A controller or an estimator named by an import path (``package.module:attribute``) is code
the twin does not know. The ``twin`` commands (``run``, ``sweep``, ``check``) never run it in
their own process: its import, its construction and every run it takes part in go to a
:class:`Worker`, a spawned process that the command watches and kills. What that contains:

* **Exits and crashes.** A plugin's ``sys.exit()``, a ``KeyboardInterrupt`` it raises, an
  ``os._exit()`` or a crash in native code (a segmentation fault) end the worker, not the
  command: the run ends with a one-line :class:`~twin.errors.PluginError` naming the plugin,
  the call under way and the simulated time, and the command reports it as that plugin's
  failure (exit status 2 for ``twin run`` and ``twin sweep``, a failed check for
  ``twin check``). Before, ``SystemExit(0)`` in a controller ended ``twin check`` with exit
  status 0 and no verdict.
* **Calls that never return.** The command knows, through shared memory
  (:data:`twin.limits.STATUS`), when the worker's run started and which plugin call is under
  way since when; a call over ``limits.step_wall_s``, a run over ``limits.run_wall_s`` or a
  worker whose resident memory grew by more than ``limits.run_memory_mb`` is killed once the
  limit is overrun by a grace (:func:`grace`), and the run ends with the limit's one line, as
  when the worker's own guard (:class:`twin.limits.RunGuard`, checking each call as it
  returns) stops it. A plugin's import and construction may take at most ``run_wall_s``.
* **Threads and processes.** The worker is a process-group leader and a child subreaper
  (Linux: ``PR_SET_CHILD_SUBREAPER``), so every process a plugin starts, even a daemon that
  forks twice and leaves its session, stays its descendant; after each task the command kills
  them all, and a worker in which a plugin left a thread running is retired (killed) rather
  than reused. Worker processes die with the command (``PR_SET_PDEATHSIG``,
  :mod:`twin.workers`), SIGKILL included.

What it does not contain: a plugin runs with the user's rights, so it can still write or
delete files, use the network, signal other processes or read the twin's ground truth by
introspection; containment is about time, memory, exits, threads and processes, not a
security boundary. In one's own Python process (:func:`twin.run_scenario`, the Gymnasium
environments, ``ClosedLoop``) plugins run in that process, as one's own code does: the
limits are then checked as each call returns.

Numbers do not change: a run in a worker is the same code on the same inputs, byte for byte
(``tests/test_containment.py``).
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from time import perf_counter

from twin import limits as _limits, registry
from twin.controllers import design_cache
from twin.errors import MAY_NOT_END, PluginError, TwinError
from twin.interrupts import deferred_signals
from twin.registry import is_user_code
from twin.workers import descendants, die_with_parent, process_stat

PR_SET_CHILD_SUBREAPER = 36  # <linux/prctl.h>
POLL_S = 0.05  # how often a watched worker's limits are read (s): a run overruns a limit by at most about this
GRACE_S = 0.25  # s past a limit before the worker is killed: a call that returns just over it is named by its guard
GRACE_FRACTION = 0.1  # and this fraction of the limit


def grace(limit_s: float) -> float:
    """Seconds past a time limit of ``limit_s`` at which the command kills the worker."""
    return GRACE_S + GRACE_FRACTION * limit_s


# ---- the worker's side -----------------------------------------------------------------------------------

def _worker_main(conn, status, parent: int, beside: list, cache_enabled: bool) -> None:
    """A worker: become a group leader and a subreaper, die with ``parent``, then run the tasks
    ``conn`` brings (``(fn, args, kwargs, progress)``) one at a time and send back
    ``("done", result, threads)`` or ``("raised", exception, threads)``, threads being how many
    threads beyond its own are alive after the task."""
    with contextlib.suppress(OSError):
        os.setpgid(0, 0)  # a group of its own: the terminal's Ctrl-C is the command's to handle
    die_with_parent(parent)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _limits.STATUS = status
    _limits.PLUGIN_FAILURES = (Exception, SystemExit, KeyboardInterrupt)  # nobody else raises them here
    if beside:
        for d in beside:
            registry.look_beside(d)
    if not cache_enabled:
        design_cache.set_enabled(False)
    threads = threading.active_count()
    while True:
        _reap()
        try:
            fn, args, kwargs, wants_progress = conn.recv()
        except (EOFError, OSError):
            os._exit(0)
        status[_limits.RUN_T0] = status[_limits.CALL_T0] = status[_limits.ROLE] = 0.0
        if wants_progress:
            kwargs = {**kwargs, "progress": lambda done, total: conn.send(("progress", done, total))}
        try:
            reply = ("done", fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 -- whatever it is, the command decides
            reply = ("raised", _portable(exc))
        status[_limits.CALL_T0] = 0.0
        extra = threading.active_count() - threads
        try:
            conn.send(reply + (extra,))
        except Exception as exc:  # noqa: BLE001 -- a result that cannot be pickled
            conn.send(("raised", TwinError(f"the worker's result could not be sent back: {type(exc).__name__}: "
                                           f"{' '.join(str(exc).split())[:200]}"), extra))


def _reap() -> None:
    """Collect the worker's finished children (the plugin's, killed by the command, and the
    orphans it inherits as a subreaper), so that none lingers as a zombie."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except (ChildProcessError, OSError):
            return
        if pid == 0:
            return


class WorkerDied(TwinError):
    """A worker process ended without answering while no user's plugin was being called (a
    crash of the twin's own native code, the out-of-memory killer, a signal from outside):
    not held against a plugin. One that dies in a plugin's call is that plugin's
    :class:`~twin.errors.PluginError`."""


def _is_plugin(kind) -> bool:
    return is_user_code(kind)


class RemoteTraceback(Exception):
    """The traceback of an exception raised in a worker (the cause of the exception re-raised
    in the command), as :mod:`concurrent.futures` gives it."""

    def __init__(self, text: str):
        super().__init__(text)
        self.text = text

    def __str__(self):
        return self.text


def _portable(exc: BaseException) -> BaseException:
    """``exc`` as it can travel back to the command: itself if it pickles, else a
    RuntimeError with its type and message; with its traceback as ``__cause__``."""
    import pickle
    import traceback

    text = "".join(traceback.format_exception(exc))
    try:
        pickle.dumps(exc)
        out = exc
    except Exception:  # noqa: BLE001
        out = RuntimeError(f"{type(exc).__name__}: {' '.join(str(exc).split())[:500]}")
    out.__cause__ = RemoteTraceback(f'\n"""\n{text}"""')
    out.__traceback__ = None
    return out


# ---- the command's side ----------------------------------------------------------------------------------

@dataclass
class Task:
    """One piece of work for a worker: ``fn(*args, **kwargs)`` (importable: it travels by
    pickle), watched under ``limits`` (a :class:`twin.limits.PluginLimits`; None: none);
    ``names`` (role → kind) name the plugins in what the command says if the worker is killed
    or dies; ``progress(done, total)``, if given, is called as the worker reports it."""

    fn: object
    args: tuple = ()
    kwargs: dict = field(default_factory=dict)
    limits: object = None
    names: dict = field(default_factory=dict)
    progress: object = None
    what: str = "run"  # "run"; "plan": importing and building the plugins; "replay": estimators on logs
    plugins: tuple = ()  # (role, kind) of each plugin a "plan" imports and builds, for its messages
    key: object = None  # the caller's name for it


@dataclass
class Outcome:
    """What became of a :class:`Task`: ``value`` if it returned, else ``error`` (an exception:
    raised in the worker, a limit's PluginError, or a PluginError for a worker that died);
    ``died``: the worker ended without answering (a crash, an exit, the OOM killer), which a
    caller may try again; ``limit``: the limit that stopped it, if one did."""

    task: Task
    value: object = None
    error: BaseException | None = None
    died: bool = False
    wall_s: float = 0.0

    @property
    def ok(self) -> bool:
        return self.error is None


class Worker:
    """A spawned worker process running one :class:`Task` at a time (see the module docstring)."""

    def __init__(self):
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        self.status = ctx.RawArray("d", _limits.STATUS_SIZE)
        self.conn, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=_worker_main, name="twin-worker",
                                   args=(child, self.status, os.getpid(), list(registry._BESIDE),
                                         design_cache.enabled()))
        self.process.start()
        child.close()
        self.pid = self.process.pid
        self.task: Task | None = None
        self.sent = 0.0
        self.retired = False

    # -- one task --
    def submit(self, task: Task) -> None:
        self.task = task
        self.sent = perf_counter()
        for i in range(_limits.STATUS_SIZE):
            self.status[i] = 0.0
        self.conn.send((task.fn, task.args, task.kwargs, task.progress is not None))

    def poll(self, now: float | None = None) -> Outcome | None:
        """The outcome of the task under way, if it has one now: a reply, the worker's death, or
        a limit overrun (the worker is then killed). Progress reports are passed on."""
        task = self.task
        while True:
            try:
                ready = self.conn.poll()
            except (EOFError, OSError):
                ready = False
            if not ready:
                break
            try:
                msg = self.conn.recv()
            except (EOFError, OSError):
                break
            if msg[0] == "progress":
                if task.progress is not None:
                    task.progress(msg[1], msg[2])
                continue
            kind, payload, threads = msg
            self.task = None
            wall = perf_counter() - self.sent
            self.clean(retire=threads > 0)
            if kind == "done":
                return Outcome(task, value=payload, wall_s=wall)
            return Outcome(task, error=payload, wall_s=wall)
        if not self.process.is_alive():
            self.task = None
            return Outcome(task, error=self._death(task), died=True, wall_s=perf_counter() - self.sent)
        over = self._over(task, perf_counter() if now is None else now)
        if over is not None:
            self.task = None
            self.kill()
            return Outcome(task, error=over, wall_s=perf_counter() - self.sent)
        return None

    def deadline(self) -> float | None:
        """Seconds until the next limit of the task under way could be overrun (None: none is set)."""
        lim = self.task.limits if self.task is not None else None
        if lim is None or not lim.active:
            return None
        return POLL_S

    # -- limits, read from outside --
    def _over(self, task: Task, now: float):
        lim = task.limits
        if lim is None or not lim.active:
            return None
        s = self.status
        run_t0, call_t0 = s[_limits.RUN_T0], s[_limits.CALL_T0]
        outside = int(s[_limits.METHOD]) in (_limits.IMPORTING, _limits.BUILDING)  # not a call of a run
        if call_t0 > 0 and outside:
            if lim.run_wall_s is not None and now - call_t0 > lim.run_wall_s + grace(lim.run_wall_s):
                return _limits.over("run_wall_s", f"{self._call(task, False)} took over limits.run_wall_s = "
                                                  f"{lim.run_wall_s:g} s (a plugin's import and construction may take "
                                                  f"a run's time); its worker process was stopped after "
                                                  f"{now - call_t0:.3g} s")
            return None
        if lim.step_wall_s is not None and call_t0 > 0 and now - call_t0 > lim.step_wall_s + grace(lim.step_wall_s):
            return _limits.over("step_wall_s", f"{self._call(task)} did not return within limits.step_wall_s = "
                                               f"{lim.step_wall_s:g} s; its worker process was stopped after "
                                               f"{now - call_t0:.3g} s")
        if lim.run_wall_s is not None and run_t0 > 0 and now - run_t0 > lim.run_wall_s + grace(lim.run_wall_s):
            where = f"; {self._call(task)} had not returned" if call_t0 > 0 else ""
            return _limits.over("run_wall_s", f"{self._run(task)} did not end within limits.run_wall_s = "
                                              f"{lim.run_wall_s:g} s; its worker process was stopped after "
                                              f"{now - run_t0:.3g} s (at t = {self._t():.3f} s{where})")
        if lim.run_memory_mb is not None and run_t0 > 0:
            rss = self.resident()
            grown = rss - s[_limits.RSS0] if rss is not None else 0
            if grown > lim.run_memory_mb * _limits.MB:
                return _limits.over("run_memory_mb", f"{self._run(task)} grew its worker process's resident memory "
                                                     f"by {grown / _limits.MB:.4g} MB, over limits.run_memory_mb = "
                                                     f"{lim.run_memory_mb:g} MB; the worker was stopped (at t = "
                                                     f"{self._t():.3f} s)")
        return None

    def resident(self) -> int | None:
        """The resident memory in bytes of the worker and every process descended from it."""
        total = _limits.resident_of(self.pid)
        if total is None:
            return None
        with contextlib.suppress(OSError):
            for pid in descendants(self.pid):
                total += _limits.resident_of(pid) or 0
        return total

    def _t(self) -> float:
        return self.status[_limits.STEP] * self.status[_limits.DT]

    def _call(self, task: Task, when: bool = True) -> str:
        """The plugin call under way, named: "__call__() of controller 'a.b:C' at t = 0.095 s"
        (``when``: with the simulated time), or "building controller 'a.b:C'"."""
        s = self.status
        role = _limits.ROLES[int(s[_limits.ROLE])] or "plugin"
        method = int(s[_limits.METHOD])
        kind = task.names.get(role) or dict(task.plugins).get(role)
        who = f"{role} {kind!r}" if kind else role
        if method in (_limits.IMPORTING, _limits.BUILDING):
            return f"{'importing' if method == _limits.IMPORTING else 'building'} {who}"
        return f"{_limits.METHODS[method] or 'call'} of {who}" + (f" at t = {self._t():.3f} s" if when else "")

    def _run(self, task: Task) -> str:
        n = task.names
        if "controller" in n:
            return f"the run of controller {n['controller']!r}" + (
                f" (estimator {n['estimator']!r})" if n.get("estimator") else "")
        return f"the run with estimator {n.get('estimator')!r}"

    def _plugins(self, task: Task) -> str:
        pairs = task.plugins or tuple(task.names.items())
        return ", ".join(f"{role} {kind!r}" for role, kind in pairs) or "the plugins"

    def _death(self, task: Task) -> PluginError:
        """The one line for a worker that ended without answering."""
        self.process.join(1.0)
        code = self.process.exitcode
        self.kill()
        if code is not None and code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            how = f"was killed by {name}" + (" (a crash in native code)" if -code in (
                signal.SIGSEGV, signal.SIGBUS, signal.SIGILL, signal.SIGFPE, signal.SIGABRT) else
                " (the system's out-of-memory killer, or a signal from outside)" if -code == signal.SIGKILL else "")
        else:
            how = f"ended with exit status {code} (os._exit, or an exit from native code)"
        s = self.status
        if s[_limits.CALL_T0] > 0 and int(s[_limits.METHOD]) in (_limits.IMPORTING, _limits.BUILDING):
            return PluginError(f"{self._call(task)}: its worker process {how}; {MAY_NOT_END}")
        if task.what == "plan":
            return PluginError(f"{self._plugins(task)}: the worker process importing and building "
                               f"{'them' if len(task.plugins) > 1 else 'it'} {how}")
        if task.what == "replay":  # no run, no loop: the estimators' code and the log's reading
            return PluginError(f"the replay with {self._plugins(task)}: its worker process {how}")
        if s[_limits.RUN_T0] > 0 and s[_limits.CALL_T0] > 0 and _is_plugin(self._kind(task)):
            return PluginError(f"{self._call(task)}: its worker process {how}; {MAY_NOT_END}")
        where = (f" during {self._call(task)}" if s[_limits.CALL_T0] > 0 else
                 f" at t = {self._t():.3f} s, outside the controller's and the estimator's calls") \
            if s[_limits.RUN_T0] > 0 else " before the run began"
        return WorkerDied(f"{self._run(task)}: its worker process {how}{where}")

    def _kind(self, task: Task):
        """The kind of the plugin whose call is under way (None: none is)."""
        return task.names.get(_limits.ROLES[int(self.status[_limits.ROLE])])

    # -- the end --
    def clean(self, retire: bool = False) -> None:
        """After a task: kill every process the plugin left (descendants of the worker); retire
        the worker (kill it) if ``retire`` (a thread of the plugin's still runs there)."""
        _kill_descendants(self.pid)
        if retire:
            self.kill()

    def kill(self) -> None:
        """Kill the worker and every process descended from it, and wait for it."""
        self.retired = True
        _kill_descendants(self.pid)
        with contextlib.suppress(OSError, ProcessLookupError):
            os.killpg(self.pid, signal.SIGKILL)  # its group: whatever has not left it
        with contextlib.suppress(OSError, ValueError, AttributeError):
            self.process.kill()
        with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
            self.process.join(5.0)
        with contextlib.suppress(OSError):
            self.conn.close()

    @property
    def alive(self) -> bool:
        return not self.retired and self.process.is_alive()


def _kill_descendants(pid: int) -> None:
    """SIGKILL every live process descended from ``pid`` (not ``pid``), until none is left: a
    process that forks meanwhile leaves its child to the subreaper, seen on the next pass."""
    if not sys.platform.startswith("linux"):
        return

    for _ in range(50):
        found = descendants(pid)
        if not found:
            return
        for child, start in found.items():
            st = process_stat(child)
            if st is not None and st[2] == start:
                with contextlib.suppress(OSError):
                    os.kill(child, signal.SIGKILL)
        time.sleep(0.001)


class Workers:
    """Up to ``width`` workers running :class:`Task` s: :meth:`run` hands out tasks as workers
    come free and calls ``on_outcome`` with each :class:`Outcome` in the command's process. A
    worker that died or was killed is replaced for the next task; every worker is killed when
    the block ends, however it ends (an interrupt included).

    Every worker the pool started and has not killed is in :attr:`idle` or :attr:`busy` at
    every moment (in both while it moves from one to the other), since an interrupt (SIGINT,
    SIGTERM raised as :class:`~twin.interrupts.Interrupted`) may land between any two
    statements: a worker that an interrupt left in neither list was never killed, and the
    command, at its exit, waited for it forever (multiprocessing joins the processes it
    started; the worker, idle on its pipe, never ends by itself while its parent lives)."""

    def __init__(self, width: int = 1):
        self.width = max(1, int(width))
        self.idle: list[Worker] = []
        self.busy: list[Worker] = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        # signals held while the workers die: an interrupt here (on a normal way out) would leave the
        # rest alive; it is raised once they are gone
        with deferred_signals():
            for w in self.idle + self.busy:
                w.kill()
            self.idle, self.busy = [], []

    def _new(self) -> Worker:
        """A new worker, listed in :attr:`busy` as it starts (signals held meanwhile: none is
        raised between its start and its listing)."""
        with deferred_signals():
            w = Worker()
            self.busy.append(w)
        return w

    def _worker(self) -> Worker:
        """A free worker, now in :attr:`busy`: an idle one that is alive, else a new one."""
        while self.idle:
            w = self.idle[-1]
            if w.alive:
                self.busy.append(w)  # listed as busy before it leaves idle
                self.idle.pop()
                return w
            w.kill()  # died idle: its pipe closed, the process collected
            self.idle.pop()
        return self._new()

    def start(self, task: Task) -> None:
        """Give ``task`` to a free worker (a new one if none is idle); at most ``width`` at once."""
        if len(self.busy) >= self.width:
            raise RuntimeError("no worker is free")
        w = self._worker()
        try:
            try:
                w.submit(task)
            except (OSError, ValueError):  # it died idle: a new one
                self._drop(w)
                w = self._new()
                w.submit(task)
        except BaseException:  # not sent (it does not pickle), or cut while sent (an interrupt): that worker ends
            self._drop(w)
            raise

    def _drop(self, w: Worker) -> None:
        """Kill busy worker ``w`` and unlist it (killed before it leaves the list)."""
        w.kill()
        if w in self.busy:
            self.busy.remove(w)

    def wait(self, timeout: float | None = None) -> list[Outcome]:
        """The outcomes that are ready, waiting up to ``timeout`` s (None: until one is, or a
        limit needs reading) for one."""
        from multiprocessing.connection import wait

        if not self.busy:
            return []
        steps = [w.deadline() for w in self.busy]
        steps = [s for s in steps if s is not None]
        if timeout is None and steps:
            timeout = min(steps)
        elif steps:
            timeout = min([timeout, *steps])
        objects = [w.conn for w in self.busy] + [w.process.sentinel for w in self.busy]
        wait(objects, timeout)
        out = []
        now = perf_counter()
        for w in list(self.busy):
            outcome = w.poll(now)
            if outcome is None:
                continue
            if w.alive:
                self.idle.append(w)  # listed as idle before it leaves busy
            self.busy.remove(w)
            out.append(outcome)
        return out

    def run(self, tasks, on_outcome, retries: int = 1) -> None:
        """Run ``tasks`` (an iterable, consumed as workers come free); ``on_outcome(outcome)``
        for each. A task whose worker died (not one a limit stopped) is tried ``retries`` more
        times, alone, before its outcome is given: a crash of the other worker's doing (the
        out-of-memory killer) is not held against it."""
        queue = list(tasks)
        deaths: dict[int, int] = {}
        while queue or self.busy:
            while queue and len(self.busy) < self.width:
                self.start(queue.pop(0))
            for outcome in self.wait():
                n = deaths.get(id(outcome.task), 0)
                if outcome.died and n < retries:
                    deaths[id(outcome.task)] = n + 1
                    queue.insert(0, outcome.task)
                    continue
                on_outcome(outcome)


def run_contained(task: Task, pool: Workers | None = None):
    """Run one ``task`` in a worker (of ``pool``, else of its own) and return its value, or
    raise its error (a limit's PluginError, a PluginError for a worker that died, or what it
    raised)."""
    if pool is None:
        with Workers(1) as own:
            return run_contained(task, own)
    pool.start(task)
    while True:
        for outcome in pool.wait():
            if outcome.error is not None:
                raise outcome.error
            return outcome.value


__all__ = ["Outcome", "RemoteTraceback", "Task", "Worker", "WorkerDied", "Workers", "grace", "run_contained"]
