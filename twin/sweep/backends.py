"""Where a sweep's samples run: local worker processes, or Ray.

Both backends run :func:`twin.sweep.worker.run_sample` on the same :class:`SweepJob` and
hand each record to ``on_result`` in the parent as soon as it arrives (the parent
stores it), so results are identical whichever backend ran them, and finishing order
does not matter. At most ``workers`` samples are in flight, so an interruption loses at
most those.

A worker that dies (a crash in native code, the OOM killer) breaks only the samples it
held: they run again, each alone, and a sample that kills its worker ``MAX_CRASHES``
times is recorded with an error instead of stopping the sweep.

Local workers die with the sweep, however it ends (:mod:`twin.workers`: SIGKILL included);
Ray's tasks are cancelled when the sweep stops by an exception (Ctrl-C, SIGTERM), and a
local Ray instance shares the sweep's fate: Ray starts its daemons so, and what they leave
behind when the sweep is killed (Ray's agents, which would wait a minute for the dead GCS)
is killed by a :class:`twin.workers.Reaper`.
"""
from __future__ import annotations

import os
from concurrent.futures import FIRST_COMPLETED, wait
from concurrent.futures.process import BrokenProcessPool

from twin.errors import TwinError
from twin.sweep.worker import SweepJob, crash_record, run_sample
from twin.workers import Reaper, process_pool

MAX_CRASHES = 2
BACKENDS = ("local", "ray")


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def run_local(job: SweepJob, indices, workers: int, on_result) -> None:
    """Run samples ``indices`` in ``workers`` spawned processes (one PyBullet client each per run)."""
    queue = list(indices)
    crashes: dict[int, int] = {}
    suspects: list[int] = []  # samples held by a worker that died: rerun one at a time, to find the culprit
    while queue or suspects:
        alone = bool(suspects)
        batch, width = ([suspects.pop(0)], 1) if alone else (queue, workers)
        running: dict = {}
        broken = False
        with process_pool(width) as pool:  # its workers stopped at once if this raises (Ctrl-C, SIGTERM)
            while (batch or running) and not broken:
                while batch and len(running) < width:
                    try:
                        running[pool.submit(run_sample, job, batch[0])] = batch[0]
                    except BrokenProcessPool:  # a worker died since the last wait: its future will say which
                        break
                    batch.pop(0)
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for fut in finished:
                    k = running.pop(fut)
                    if not isinstance(fut.exception(), BrokenProcessPool):
                        on_result(fut.result())
                        continue
                    broken = True
                    crashes[k] = crashes.get(k, 0) + alone
                    if crashes[k] >= MAX_CRASHES:
                        on_result(crash_record(job, k, f"worker died {MAX_CRASHES} times running this sample"))
                    else:
                        suspects.append(k)
            suspects += running.values()  # held by the dead pool: not yet known to be innocent


def run_ray(job: SweepJob, indices, workers: int | None, on_result, address: str | None = None) -> None:
    """Run samples ``indices`` as Ray tasks: on the cluster at ``address`` (``ray.init(address=...)``,
    e.g. "auto" or "ray://head:10001"), or on a local Ray instance with ``workers`` CPUs.
    ``workers`` also caps the tasks in flight (default: the cluster's CPUs)."""
    try:
        import ray
    except ImportError:
        raise TwinError("the ray backend needs Ray: pip install 'mtwip-twin[ray]' (or use --backend local)") from None
    started = not ray.is_initialized()
    # a local instance's processes go with the sweep even when it is killed: Ray fate-shares its
    # daemons with this process, and a reaper (twin.workers) takes what is left (its agents)
    reaper = Reaper() if started and address is None else None
    try:
        _drive_ray(ray, job, indices, workers, on_result, address, started, reaper)
    finally:
        if reaper is not None:
            reaper.close()  # after ray.shutdown(): nothing of Ray's is left to kill


def _drive_ray(ray, job, indices, workers, on_result, address, started, reaper) -> None:
    import logging
    import signal
    import threading

    main_thread = threading.current_thread() is threading.main_thread()
    # ray.init puts its own SIGTERM handler in (sys.exit(15)), which bypasses the command's
    # (an interrupt that stores what finished and exits 143): the one there before is put back
    sigterm = signal.getsignal(signal.SIGTERM) if main_thread else None
    if started:
        # Ray's notice that the local instance it starts uses token authentication (its default)
        # is a line on stderr in every sweep: left out (a warning that it does not is kept)
        notices = logging.getLogger("ray._private.authentication.authentication_token_setup")
        quiet = _DropNotice("Token authentication is enabled for this Ray cluster")
        notices.addFilter(quiet)
        try:
            if address is None:
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                         logging_level=logging.WARNING, configure_logging=False)
            else:
                ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING, configure_logging=False)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise TwinError(f"cannot start or reach Ray at {address or 'a local instance'}: "
                            f"{' '.join(str(exc).split())[:300]}") from None
        finally:
            notices.removeFilter(quiet)
            if sigterm is not None:
                signal.signal(signal.SIGTERM, sigterm)
        if reaper is not None:
            reaper.scan()  # Ray's daemons and agents, noted now
    running: dict = {}
    raised: list = []  # what the command's signal handlers raised (Ray's waits turn it into a bare KeyboardInterrupt)
    relays = _relay_signals(raised) if main_thread else {}
    try:
        cap = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        task = ray.remote(num_cpus=1, max_retries=MAX_CRASHES - 1)(run_sample)
        job_ref = ray.put(job)
        queue = list(indices)
        while queue or running:
            while queue and len(running) < cap:
                k = queue.pop(0)
                running[task.remote(job_ref, k)] = k
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                k = running.pop(ref)
                try:
                    record = ray.get(ref)
                except ray.exceptions.RayError as exc:  # the worker died MAX_CRASHES times
                    record = crash_record(job, k, f"Ray task failed {MAX_CRASHES} times running this sample "
                                                  f"({type(exc).__name__})")
                on_result(record)
    except BaseException as exc:
        for ref in running:  # a cluster outlives this driver: do not leave its tasks running
            ray.cancel(ref, force=True)
        if raised and type(exc) is KeyboardInterrupt and exc is not raised[-1]:
            raise raised[-1] from None  # the interrupt as the handler raised it (SIGTERM's, say), not Ray's copy
        raise
    finally:
        for signum, handler in relays.items():
            signal.signal(signum, handler)
        if started:
            ray.shutdown()


class _DropNotice:
    """A logging filter that drops the records whose message starts with ``prefix``."""

    def __init__(self, prefix: str):
        self.prefix = prefix

    def filter(self, record) -> bool:
        return not str(record.msg).startswith(self.prefix)


def _relay_signals(raised: list) -> dict:
    """Wrap the SIGINT and SIGTERM handlers that are Python functions so that what they raise is
    also kept in ``raised``; the handlers wrapped, to put back."""
    import signal

    def relay(handler):
        def on_signal(signum, frame):
            try:
                handler(signum, frame)
            except BaseException as exc:
                raised.append(exc)
                raise
        return on_signal

    old = {}
    for signum in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(signum)
        if callable(handler):
            old[signum] = handler
            signal.signal(signum, relay(handler))
    return old
