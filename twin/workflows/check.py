"""``twin check``: scenarios run against their ``[expect]`` bounds (and, with golden
trajectories, against their recorded runs), sensor logs replayed against theirs
(:mod:`twin.verify.check`), all in one :class:`twin.verify.check.CheckResult`."""
from __future__ import annotations

import time
from pathlib import Path

from twin.errors import TwinError
from twin.logs.expect import is_log_target, load_log_check
from twin.outputs import rundir
from twin.registry import parse_controllers
from twin.sweep.backends import default_workers
from twin.verify.check import CheckResult, collect, run_checks, run_log_checks


def check_references(record: Path | None, golden: Path | None, tolerances) -> None:
    """--record, --golden and the tolerances as they may go together; the golden directory a
    complete record (one killed while it committed is carried through first)."""
    if record is not None and golden is not None:
        raise TwinError("--record and --golden together would overwrite the references with the runs they judge; "
                        "give one of them")
    if golden is not None and not golden.is_dir():
        raise TwinError(f"--golden {golden}: no such directory; record references first with --record {golden}")
    if golden is not None:  # references of a record that did not finish are not judged against
        rundir.finish_batch(golden)
        rundir.read_manifest(golden, (rundir.RECORD_COMMAND,), "golden directory",
                             f"record it again with 'twin check ... --record {golden}'")
    if tolerances.is_set and golden is None:
        raise TwinError("--atol, --rtol and --tolerance set how closely a run must follow its golden trajectory; "
                        "give --golden DIR with them")


def check(targets, controller: str | None = None, seeds: int = 1, workers: int | None = None, overrides=(),
          record: Path | None = None, golden: Path | None = None, tolerances=None, progress=None,
          skipped=None) -> CheckResult:
    """Check ``targets`` (scenario names, files, directories of them, sensor logs or files of
    their bounds) with ``controller`` (comma-separated kinds; None: each scenario's), ``seeds``
    seeds each, on ``workers`` processes; ``skipped(path)`` is called for each file without an
    ``[expect]`` table. The result holds every case; an error if there is nothing to check."""
    check_references(record, golden, tolerances)
    kinds = parse_controllers(controller) if controller is not None else None
    logs = [load_log_check(t) for t in targets if is_log_target(t)]  # sensor logs: replays with bounds
    targets = [t for t in targets if not is_log_target(t)]
    scenarios, without = collect(targets, overrides) if targets or not logs else ([], [])
    for f in without:
        if skipped is not None:
            skipped(f)
    if not scenarios and not logs:
        raise TwinError("no scenario with an [expect] table to check")
    if logs and (record is not None or golden is not None):
        raise TwinError("--record and --golden are for scenarios' runs; a sensor log's replay has no golden "
                        "trajectory: check logs without them")
    result = CheckResult([])
    if scenarios:
        try:
            result = run_checks(scenarios, kinds, seeds, workers or default_workers(), progress=progress,
                                record=record, golden=golden, tolerances=tolerances)
        except BaseException as exc:
            if record is not None:  # the record's own clause, where it got that far, stands
                rundir.kept(exc, f"nothing recorded: {record} is as it was")
            raise
    if logs:
        t0 = time.perf_counter()
        cases = run_log_checks(logs)
        result.cases += cases
        result.runs += len(cases)
        result.wall_s += time.perf_counter() - t0
    return result


__all__ = ["check", "check_references"]
