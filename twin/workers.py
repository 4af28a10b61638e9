"""Worker processes that die with the process that started them.

Every place that starts worker processes (the sweeps' local backend, ``twin check``'s
pool, the figure worker of ``twin run``, the video's panel renderers) goes through here,
so that no worker outlives its parent, however the parent ends: a worker blocked on its
task queue or busy in a slow plugin would otherwise run on under PID 1 after a SIGKILL or
an unhandled SIGTERM of the command, computing for nobody (measured before issue 26: both
sweep workers and multiprocessing's resource tracker, indefinitely).

How: on Linux each worker asks the kernel, first thing, for SIGKILL when its parent exits
(``prctl(PR_SET_PDEATHSIG)``, through ctypes), then checks that its parent is still the
process that started it: had the parent died between the fork and the ``prctl``, no signal
would ever come, so the worker exits by itself. SIGKILL, because a worker holds nothing
worth saving (the parent stores every result) and a plugin could catch or ignore anything
milder. The kernel sends it when the parent *thread* that started the worker ends, so
workers are started and ended by one call on one thread here (a pool lives inside one
function call).

multiprocessing's resource tracker (started by the parent for the pool's semaphores)
cannot be given an initializer; it exits, unlinking the semaphores, once every process
holding its pipe has ended: the parent and the pool's workers, so it goes with them.

Elsewhere than Linux (no ``prctl``) the workers are ended by the parent on every path it
survives (exceptions, Ctrl-C, SIGTERM when the command handles it), as before.

Processes this module does not start (a local Ray instance's) are watched by a
:class:`Reaper`: a small process of its own session that notes, twice a second, every
process descended from the command, and SIGKILLs those still alive if the command dies
without saying it is done (the end of its stdin pipe). Ray fate-shares its own daemons with
the driver, but its two agents, left by a killed raylet, wait a minute for the dead GCS
before they exit (measured with Ray 2.60).
"""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PARENT_ENV = "TWIN_WORKER_PARENT"  # the expected parent's pid, for workers started as plain subprocesses


def die_with_parent(parent: int) -> bool:
    """Have this process killed when its parent ends; exit at once if the parent already has
    (``os.getppid()`` is no longer ``parent``). True where the kernel supports it (Linux)."""
    supported = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            supported = libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
        except (OSError, AttributeError):  # pragma: no cover - no prctl in this C library
            supported = False
    if os.getppid() != parent:  # reparented before the prctl took effect: the parent is gone
        os._exit(1)
    return supported


def pool_worker_init(parent: int) -> None:
    """Initializer of a pool's workers: die with ``parent``; Ctrl-C is the parent's to handle
    (the terminal sends it to the whole process group; the parent stops the workers itself)."""
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def subprocess_env(env: dict | None = None) -> dict:
    """The environment for a worker started with :mod:`subprocess`: ``env`` (default: this
    process's) with this process's id, for :func:`subprocess_worker_init` in the child."""
    return {**(os.environ if env is None else env), PARENT_ENV: str(os.getpid())}


def subprocess_worker_init() -> None:
    """First thing in a worker started with :func:`subprocess_env`: die with the parent named
    there (nothing if it is not set: the module was run by hand)."""
    parent = os.environ.get(PARENT_ENV, "")
    if parent.isdigit():
        die_with_parent(int(parent))


def _recording_context():
    """multiprocessing's spawn context, noting every process a pool starts through it in its
    ``started`` list: the pool's workers, known without reading the pool's private state."""
    import multiprocessing.context

    class RecordingSpawnContext(multiprocessing.context.SpawnContext):
        def __init__(self):
            super().__init__()
            self.started = []

        def Process(self, *args, **kwargs):  # noqa: N802 -- multiprocessing's name
            p = multiprocessing.context.SpawnProcess(*args, **kwargs)
            self.started.append(p)
            return p

    return RecordingSpawnContext()


def terminate(processes) -> None:
    """Stop ``processes`` (a pool's workers) now: ``shutdown`` alone would wait for the tasks
    they are running, a slow plugin's for minutes."""
    for p in list(processes):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            p.terminate()


@contextlib.contextmanager
def process_pool(width: int):
    """A spawned :class:`~concurrent.futures.ProcessPoolExecutor` of ``width`` workers that die
    with this process; if the block raises (Ctrl-C, SIGTERM turned into an exception, an
    error) its workers are stopped at once instead of finishing their tasks. Spawned, not
    forked: a fork would copy PyBullet clients and locks held by other threads."""
    from concurrent.futures import ProcessPoolExecutor

    ctx = _recording_context()
    pool = ProcessPoolExecutor(width, mp_context=ctx, initializer=pool_worker_init, initargs=(os.getpid(),))
    try:
        yield pool
    except BaseException:
        terminate(ctx.started)
        try:
            pool.shutdown(wait=True, cancel_futures=True)
        except RuntimeError:
            # an interrupt that came while the pool started its manager thread (Thread.start waits for
            # it) leaves a thread that never started: nothing to join, and the interrupt is what to say
            pass
        raise
    pool.shutdown(wait=True, cancel_futures=True)


# ---- a reaper for processes started by others (a local Ray instance) ---------------------------------------

REAPER_SCAN_S = 0.5  # how often the reaper notes the command's descendants (a scan of /proc: ~2 ms)
_ROOT = str(Path(__file__).resolve().parent.parent)  # the directory holding this twin package
_REAPER_CODE = f"import sys; sys.path.insert(0, {_ROOT!r}); from twin.workers import reaper_main; reaper_main()"


def process_stat(pid: int):
    """(state, parent pid, start time in clock ticks) of process ``pid``; None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
        return fields[0].decode(), int(fields[1]), int(fields[19])
    except (OSError, IndexError, ValueError):
        return None


def descendants(root: int) -> dict:
    """Every live process descended from ``root`` (children, theirs, ...): pid -> start time."""
    children: dict = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            st = process_stat(int(name))
            if st is not None and st[0] != "Z":
                children.setdefault(st[1], []).append((int(name), st[2]))
    found, todo = {}, [root]
    while todo:
        for pid, start in children.get(todo.pop(), ()):
            if pid not in found:
                found[pid] = start
                todo.append(pid)
    return found


class Reaper:
    """Kills, if this process dies without :meth:`close`, every process descended from it that
    was started while the reaper watched (and still runs): for processes whose starting this
    module does not control. Linux only (/proc); elsewhere it does nothing. Use with ``with``:
    leaving the block normally or by an exception closes it (nothing killed: the block's own
    clean-up ran); a SIGKILL of this process leaves the reaper to act."""

    def __init__(self):
        self._proc = None
        if not sys.platform.startswith("linux") or not os.path.isdir("/proc/self"):
            return
        spared = [f"{pid}:{start}" for pid, start in descendants(os.getpid()).items()]  # not started under watch
        try:  # a session of its own: a signal to the command's process group leaves it to do its job
            self._proc = subprocess.Popen([sys.executable, "-c", _REAPER_CODE, *spared], stdin=subprocess.PIPE,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          env=subprocess_env(), start_new_session=True)
        except OSError:
            self._proc = None

    def scan(self) -> None:
        """Have the reaper note this process's descendants now (after starting some)."""
        self._say(b"scan\n")

    def close(self) -> None:
        """Stop the reaper without killing anything."""
        if self._proc is not None:
            self._say(b"done\n")
            with contextlib.suppress(OSError):
                self._proc.stdin.close()
            try:
                self._proc.wait(5.0)
            except subprocess.TimeoutExpired:  # pragma: no cover - a reaper that does not answer
                self._proc.kill()
                self._proc.wait()
            self._proc = None

    def _say(self, line: bytes) -> None:
        if self._proc is not None:
            with contextlib.suppress(OSError, ValueError):
                self._proc.stdin.write(line)
                self._proc.stdin.flush()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def reaper_main() -> None:
    """The reaper (:class:`Reaper`): notes the parent's descendants every ``REAPER_SCAN_S`` and
    when asked; "done" on stdin ends it; EOF without it (the parent died) kills every process
    noted that still runs, the same process (its pid and start time), then ends it."""
    import select

    parent = int(os.environ[PARENT_ENV])
    born = process_stat(parent)
    if born is None or os.getppid() != parent:
        return
    me = os.getpid()
    before = {tuple(map(int, a.split(":"))) for a in sys.argv[1:]}  # the parent's children before: not watched
    noted: dict = {}
    pending = b""
    while True:
        if select.select([0], [], [], REAPER_SCAN_S)[0]:
            chunk = os.read(0, 4096)
            if not chunk:
                break
            pending += chunk
            if b"done\n" in pending:
                return
        now = process_stat(parent)
        if now is None or now[0] == "Z" or now[2] != born[2]:
            break  # the parent is gone (its pid may be another process's by now): no scan
        noted.update((pid, start) for pid, start in descendants(parent).items()
                     if pid != me and (pid, start) not in before)
    for pid, start in noted.items():
        st = process_stat(pid)
        if st is not None and st[0] != "Z" and st[2] == start:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


__all__ = ["Reaper", "descendants", "die_with_parent", "pool_worker_init", "process_pool", "process_stat", "reaper_main",
           "subprocess_env", "subprocess_worker_init", "terminate"]
