"""SIGINT and SIGTERM as an exception that says which, held where an interrupt must not cut.

SIGINT and SIGTERM raise :class:`Interrupted` (:func:`interrupts_raise`, installed for every
command by the command line), held while a commit renames, a foreign library calls back into
Python or a C++ extension is imported (:func:`deferred_signals`); the command says what it
kept (:func:`kept`) and exits 130 or 143 (:func:`exit_status_of`). A process-wide concern of
no domain, so the plant, the controllers' design store and the output directories
(:mod:`twin.outputs.rundir`, which re-exports these names) use it alike. :func:`test_point`
is where a kill test may stop the command.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from pathlib import Path

from twin.errors import TwinError


SIGNAL_NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM, raised where the main thread was. A KeyboardInterrupt, so that every
    ``except KeyboardInterrupt`` clean-up (a sweep's, a pool's) runs for SIGTERM too; the exit
    status is the shell's convention, 128 + the signal's number (130, 143)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        return SIGNAL_NAMES.get(self.signum, f"signal {self.signum}")


def _signal_of(exc: BaseException) -> int | None:
    """The signal that stopped the command ``exc`` stops, if one did: the Interrupted's; else the
    one this command's handler raised (what reached here instead is its copy, as Ray's waits
    make a bare KeyboardInterrupt of it, or what a library made of it: an ImportError of an
    extension module interrupted while it loaded, say); else a bare KeyboardInterrupt's SIGINT."""
    if isinstance(exc, Interrupted):
        return exc.signum
    if _raised is not None:
        return _raised
    if isinstance(exc, KeyboardInterrupt):
        return int(signal.SIGINT)
    return None


def exit_status_of(exc: BaseException) -> int:
    """The exit status a command ends with when ``exc`` stops it: 128 + the signal for an
    interrupt (a bare KeyboardInterrupt is SIGINT's 130; any exception after this command's
    handler raised an interrupt is that interrupt's), 2 for a user error or a file error (the
    command line's one-line errors), 1 for anything else (a traceback)."""
    signum = _signal_of(exc)
    if signum is not None:
        return 128 + signum
    if isinstance(exc, (TwinError, OSError)):
        return 2
    return 1


def signal_name(exc: BaseException) -> str:
    """SIGINT or SIGTERM: the signal that stopped the command ``exc`` stops (see :func:`exit_status_of`)."""
    signum = _signal_of(exc)
    return SIGNAL_NAMES.get(signum, f"signal {signum}") if signum is not None else "SIGINT"


_deferred: list = []  # signals noted, not raised: held (deferred_signals), or come after the command's end was decided
_holds = 0  # blocks holding SIGINT and SIGTERM now (deferred_signals, the start-up's), in any thread
_ours = False  # the handlers are this module's (interrupts_raise, hold_from_start): a hold swaps nothing
_raised: int | None = None  # the signal an Interrupted was raised for: one per command, the next ones are noted
_leaving = False  # the command's exit status is decided (leaving): signals are noted, never raised
_start_hold = False  # hold_from_start's hold, open until started()
_early: dict | None = None  # the handlers before hold_from_start's, for interrupts_raise to put back
_standing = ""  # what stands if a signal ends the command now (keep_so_far)
_raised_exc: BaseException | None = None  # the Interrupted raised, which _watch follows on its way out
_asking = False  # _watch asks the handler whether _raised_exc is still on its way (not a signal)
_watching = threading.Lock()  # _watch's question against interrupts_raise's putting the handlers back
_watcher: threading.Thread | None = None
WATCH_S = 0.1  # how often _watch asks
# (_holds is counted up and down by plain statements, not under a lock: the handler runs in the main thread
# between two of its instructions, and would wait forever for a lock that thread holds; in CPython a
# global's += is not cut by a signal handler or another thread, which both run at calls and jumps only)


def _raise_interrupted(signum, frame):
    """The handler of SIGINT and SIGTERM (:func:`interrupts_raise`): :class:`Interrupted` where the
    main thread is, or the signal noted for later while it must not be raised: a hold is open
    (:func:`deferred_signals`), the command's exit status is decided (:func:`leaving`), an
    interrupt was raised already (its clean-up runs on, its exit status stands), or the
    interpreter is shutting down (where an exception is only printed)."""
    global _asking, _raised
    if _asking and _raised is not None:  # _watch's question, not a signal
        _asking = False
        if _holds or _leaving or sys.is_finalizing() or _in_hook(frame) or _on_its_way(_raised_exc):
            return  # (in the hook: asked again later, once it has returned)
        signum, _raised = _raised, None  # swallowed on its way (see _watch): raised again, here
    elif _holds or _leaving or _raised is not None or sys.is_finalizing():
        _deferred.append(signum)
        return
    exc = _interrupt(signum)
    if _in_hook(frame):  # an exception here would be printed, not raised: _watch raises it after the hook
        return
    raise exc


def _in_hook(frame) -> bool:
    """Whether ``frame`` is :func:`_unraisable`'s, or one it called."""
    depth = 0
    while frame is not None and depth < 8:
        if frame.f_code is _unraisable.__code__:
            return True
        frame, depth = frame.f_back, depth + 1
    return False


def _interrupt(signum: int) -> Interrupted:
    """The Interrupted for ``signum``, noted as the command's interrupt (and followed: _watch)."""
    global _raised, _raised_exc, _watcher
    _raised = int(signum)
    _deferred.clear()
    _raised_exc = exc = Interrupted(signum)
    if _ours and (_watcher is None or not _watcher.is_alive()):
        _watcher = threading.Thread(target=_watch, name="twin-interrupt-watch", daemon=True)
        _watcher.start()
    return exc


def _watch() -> None:
    """Every :data:`WATCH_S` until the command ends, after an interrupt was raised: ask the main
    thread's handler whether the Interrupted is still on its way out (being handled, or in a
    ``finally`` or an ``__exit__`` on the way: in the exception the main thread handles, or in
    its chain). One that is not was swallowed where it was raised, and is raised again. Who
    swallows one: Cython's module initialisation (``try: Sequence.register(...) except: pass``,
    in every module with memoryviews: numpy.random's, SciPy's, loaded as they are first
    used), where SIGTERM was lost and the command ended with exit status 0; a C++ module's
    initialisation, which makes an ImportError of it that a fallback import catches."""
    import _thread

    global _asking
    while True:
        time.sleep(WATCH_S)
        with _watching:
            if not _ours or _leaving:
                return
            if _raised is not None and not _asking:
                _asking = True
                _thread.interrupt_main(_raised)


def _on_its_way(exc) -> bool:
    """Whether ``exc`` is the exception the main thread handles now (in an ``except``, a
    ``finally``, an ``__exit__``), or in that one's chain (``raise ... from``, or raised while
    handling it); or a KeyboardInterrupt is (a copy of it: Ray's waits make a bare one)."""
    todo, seen = [sys.exc_info()[1]], set()
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        if e is exc or isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        todo += [e.__cause__, e.__context__]
    return False


def _take() -> int | None:
    """The signal to deliver as the last hold ends (None: none, or not now)."""
    if _holds or _leaving or _raised is not None or not _deferred:
        return None
    got = _deferred[0]
    _deferred.clear()
    return got


def _unraisable(unraisable) -> None:
    """``sys.unraisablehook`` while :func:`interrupts_raise` is on. An Interrupted raised where
    Python cannot raise (the handler ran inside a ``__del__``, a weakref callback such as the
    one importlib's module locks have, the garbage collector) would be printed as "Exception
    ignored" (or not at all: PyBullet's connection points stderr at /dev/null meanwhile) and
    lost, the command going on as if no signal had come and ending with exit status 0: it is
    not printed, and :func:`_watch` raises it again once this hook has returned."""
    exc = unraisable.exc_value
    if isinstance(exc, Interrupted) and _ours and exc is _raised_exc:
        return
    (_unraisable_before or sys.__unraisablehook__)(unraisable)


_unraisable_before = None


def _install() -> dict:
    """This module's handler for SIGINT and SIGTERM; the handlers before."""
    old = {}
    for s in SIGNAL_NAMES:
        old[s] = signal.signal(s, _raise_interrupted)
    return old


def hold_from_start() -> None:
    """For the command line, as its process starts (before the heavy imports): SIGINT and SIGTERM
    are noted from now on, so that one that comes while the command is still loading is not a
    KeyboardInterrupt traceback, or SIGTERM's end without a word; :func:`interrupts_raise` takes
    the handlers over and :func:`started` raises what was noted. Main thread only; once."""
    global _holds, _start_hold, _early, _ours
    if _early is not None or _ours or threading.current_thread() is not threading.main_thread():
        return
    _holds += 1
    _start_hold = True
    _early = _install()
    _ours = True


def started() -> None:
    """The command line is ready for interrupts: :func:`hold_from_start`'s hold ends, and a
    signal noted since is raised here, as :class:`Interrupted`."""
    global _holds, _start_hold
    if not _start_hold:
        return
    _start_hold = False
    _holds -= 1
    got = _take()
    if got is not None:
        raise _interrupt(got)


@contextlib.contextmanager
def interrupts_raise():
    """While the block runs, SIGINT and SIGTERM raise :class:`Interrupted` in the main thread
    (SIGTERM would otherwise end the process where it stands: no clean-up, no message, and
    SIGINT's KeyboardInterrupt does not say which signal came), one per command: a second
    signal is noted, not raised, while the first one's clean-up runs. The handlers before are
    put back afterwards. Outside the main thread, nothing changes (Python allows handlers there
    only)."""
    global _ours, _raised, _raised_exc, _leaving, _early, _standing, _unraisable_before, _holds, _start_hold
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    hook = sys.unraisablehook
    old, _early = _early, None
    try:
        if old is None:
            old = {}
            for s in SIGNAL_NAMES:
                old[s] = signal.signal(s, _raise_interrupted)
        _ours = True
        if hook is not _unraisable:
            _unraisable_before, sys.unraisablehook = hook, _unraisable
        yield
    finally:
        if _start_hold:  # started() never came: the block ended before the command did
            _start_hold = False
            _holds -= 1
        with _watching:  # _watch asks no more: the handler is about to go
            _ours = False
        for s, handler in (old or {}).items():
            signal.signal(s, handler)
        if sys.unraisablehook is _unraisable:
            sys.unraisablehook = hook
        _raised, _raised_exc, _leaving, _standing = None, None, False, ""
        _deferred.clear()


@contextlib.contextmanager
def deferred_signals():
    """SIGINT and SIGTERM held while the block runs, then delivered: raised as
    :class:`Interrupted` as the last hold ends (under :func:`interrupts_raise`), or to the
    handlers there were before. For a commit's renames and its manifest (cut short, they would
    leave a directory neither old nor new), and for what an exception must not cut: a call into
    a foreign library that calls back into Python (the LMI solver: an exception there is a
    Rust panic, or lost), an import of a C++ extension (an exception there becomes an
    ImportError, and leaves the module half made).

    Python-level, not a signal mask: a mask holds a signal for one thread, and the kernel
    hands a process's signal to any thread that does not block it (the video encoder's, a
    pool's), whose C handler would still raise in the main thread. Under interrupts_raise it
    holds from any thread (one held outside the main thread is delivered to the main thread
    as the hold ends); outside it, from the main thread only (as before)."""
    global _holds
    main = threading.current_thread() is threading.main_thread()
    if not (main or _ours):
        yield
        return
    swapped = {}
    _holds += 1
    try:
        if not _ours:  # outside a command (the Python API): this module's handler for the block, noting
            swapped = _install()
        yield
    finally:
        try:
            for s, handler in swapped.items():
                signal.signal(s, handler)
        finally:
            _holds -= 1
            got = _take()
        if got is not None:
            if swapped:
                signal.raise_signal(got)  # to the handler that was there: the default, or the caller's
            elif main:
                raise _interrupt(got)
            else:
                import _thread

                _thread.interrupt_main(got)  # the main thread's handler raises it there


def leaving() -> None:
    """The command's exit status is decided (it returned, or says its error or its interrupt):
    from now on SIGINT and SIGTERM are noted, never raised, so that nothing cuts the exit into
    a traceback or a second line. :func:`signal_received` says whether one came."""
    global _leaving
    _leaving = True


def signal_received() -> int | None:
    """The first SIGINT or SIGTERM the command received under :func:`interrupts_raise`, raised or
    noted (None: none). A command that would end well after one ends with it instead."""
    if _raised is not None:
        return _raised
    return _deferred[0] if _ours and _deferred else None


def keep_so_far(text: str) -> None:
    """What stands if a signal ends the command from now on and its exception says nothing (a
    run directory committed: "this run was complete: R holds it, with its manifest.json"); the
    command line says it after "interrupted: SIGNAL". Reset when the command ends."""
    global _standing
    _standing = text


def kept_so_far() -> str:
    """What :func:`keep_so_far` said ("" if nothing)."""
    return _standing


def kept(exc: BaseException, text: str) -> BaseException:
    """Attach to ``exc`` what the command kept of its outputs (one clause, said after its
    message); the first one attached stands."""
    if not getattr(exc, "twin_kept", None):
        try:
            exc.twin_kept = text
        except AttributeError:  # pragma: no cover - exceptions without a __dict__
            pass
    return exc


def kept_text(exc: BaseException) -> str:
    """What the command that ``exc`` stopped kept ("" if it did not say)."""
    return getattr(exc, "twin_kept", "") or ""


# ---- a hook for the kill tests ---------------------------------------------------------------------

_reached: set = set()

def test_point(name: str) -> None:
    """Where a test may stop the command: with ``TWIN_TEST_STOP_AT=NAME:MARKER`` in the
    environment, reaching point ``NAME`` writes this process's id to the file MARKER and waits
    there (up to 60 s) for the test's signal. Why a hook and not timing: the stages a kill
    test aims at (a trajectory half written, a commit under way) last milliseconds, and a
    test that guesses when to send its signal fails on a busy machine. Off (one dictionary
    look-up) without the variable."""
    spec = os.environ.get("TWIN_TEST_STOP_AT")
    if not spec or spec.partition(":")[0] != name or name in _reached:
        return
    _reached.add(name)  # the first time only: a point inside a loop stops it once
    marker = spec.partition(":")[2]
    start = len(_deferred)
    Path(marker).write_text(str(os.getpid()), encoding="ascii")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(_deferred) == start:  # a held signal ends the wait too
        time.sleep(0.01)
