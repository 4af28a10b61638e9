"""Where a sweep's samples run: local worker processes, or Ray.

Both backends run each controller's run of a sample (:func:`twin.sweep.worker.run_part`) in a
contained worker process (:mod:`twin.containment`: a plugin's exits, crashes, hangs, threads
and child processes stay there, and the scenario's limits are enforced from outside) and
hand each sample's record to ``on_result`` in the parent as soon as it is complete (the
parent stores it), so results are identical whichever backend ran them, and finishing
order does not matter. At most ``workers`` runs are in flight, so an interruption loses at
most those samples.

A worker that dies outside a plugin's call (a crash in the twin's native code, the OOM
killer) loses only the run it held: it runs again, and one that kills its worker
``MAX_CRASHES`` times is recorded with an error instead of stopping the sweep; one that
dies in a plugin's call is that plugin's error on that sample.

Local workers die with the sweep, however it ends (:mod:`twin.workers`: SIGKILL included);
Ray's tasks are cancelled when the sweep stops by an exception (Ctrl-C, SIGTERM), and a
local Ray instance shares the sweep's fate: Ray starts its daemons so, and what they leave
behind when the sweep is killed (Ray's agents, which would wait a minute for the dead GCS)
is killed by a :class:`twin.workers.Reaper`.
"""
from __future__ import annotations

import os
from twin.containment import Task, Workers
from twin.errors import PluginError
from twin.errors import TwinError
from twin.scenarios.contained import limits_of, names_of
from twin.sweep.worker import SweepJob, assemble, crash_record, error_text, run_part
from twin.workers import Reaper

MAX_CRASHES = 2
BACKENDS = ("local", "ray")


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def run_local(job: SweepJob, indices, workers: int, on_result, pool=None) -> None:
    """Run samples ``indices`` in ``workers`` contained worker processes (:mod:`twin.containment`),
    one controller's run of one sample at a time, each under the scenario's limits: a run that
    overruns one is stopped from outside (its worker killed), and the sample's other
    controllers run on. A sample's record goes to ``on_result`` when all its controllers are done.
    ``pool``: the :class:`twin.containment.Workers` to use (None: one of ``workers``, ended here)."""
    scenario = job.scenario()
    limits = limits_of(scenario)
    kinds = tuple(job.controllers)
    parts: dict[int, dict] = {}
    tasks = [Task(run_part, (job, k, kind), limits=limits, names=names_of(scenario, kind), key=(k, kind))
             for k in indices for kind in kinds]

    def settle(outcome) -> None:
        k, kind = outcome.task.key
        if outcome.error is None:
            part = outcome.value
        elif outcome.died and not isinstance(outcome.error, PluginError):  # the twin's crash, or the OOM killer
            part = {"error": f"worker died {MAX_CRASHES} times running this sample ({error_text(outcome.error)})"}
        else:  # a limit overrun, or a plugin that ended its worker
            part = {"error": error_text(outcome.error)}
        got = parts.setdefault(k, {})
        got[kind] = part
        if len(got) == len(kinds):
            del parts[k]
            on_result(assemble(job, k, got))

    if pool is not None:
        pool.run(tasks, settle, retries=MAX_CRASHES - 1)
        return
    with Workers(workers) as own:  # its workers killed at once if this raises (Ctrl-C, SIGTERM)
        own.run(tasks, settle, retries=MAX_CRASHES - 1)


_RAY_POOL: list = []  # a Ray worker's own contained worker, kept for its next tasks


def run_sample_contained(job: SweepJob, index: int) -> dict:
    """Sample ``index``'s record, each controller's run in a contained worker of this process's
    (what a Ray task runs: the limits and containment of a local sweep, on the cluster's node)."""
    if not _RAY_POOL:
        _RAY_POOL.append(Workers(1))
    got = []
    run_local(job, [index], 1, got.append, pool=_RAY_POOL[0])
    return got[0]


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
        task = ray.remote(num_cpus=1, max_retries=MAX_CRASHES - 1)(run_sample_contained)
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
