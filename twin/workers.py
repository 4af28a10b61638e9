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
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys

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


def terminate(pool) -> None:
    """Stop a :class:`~concurrent.futures.ProcessPoolExecutor`'s workers now (``shutdown``
    alone would wait for the tasks they are running, a slow plugin's for minutes)."""
    for p in list((getattr(pool, "_processes", None) or {}).values()):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            p.terminate()


@contextlib.contextmanager
def process_pool(width: int):
    """A spawned :class:`~concurrent.futures.ProcessPoolExecutor` of ``width`` workers that die
    with this process; if the block raises (Ctrl-C, SIGTERM turned into an exception, an
    error) its workers are stopped at once instead of finishing their tasks. Spawned, not
    forked: a fork would copy PyBullet clients and locks held by other threads."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(width, mp_context=multiprocessing.get_context("spawn"),
                               initializer=pool_worker_init, initargs=(os.getpid(),))
    try:
        yield pool
    except BaseException:
        terminate(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


__all__ = ["die_with_parent", "pool_worker_init", "process_pool", "subprocess_env", "subprocess_worker_init",
           "terminate"]
