"""What a sweep worker runs: one sample, every controller of the sweep, on its own PyBullet clients.

:func:`run_sample` is the only function a backend ships to its workers (local
processes or Ray tasks), so every backend computes the same thing. It depends on
nothing but its arguments: the :class:`SweepJob` carries the validated scenario, the
controller kinds, the LMI design the sweep solved once (workers do not solve it again,
nor import cvxpy) and the directories of the plugins' modules (put on ``sys.path`` in
the worker, so a spawned process or a Ray worker imports the same files).
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from twin.errors import PluginError
from twin.registry import use_plugin_dirs
from twin.scenarios.runs import simulate_scenario
from twin.scenarios.scenario import Scenario
from twin.sweep.sampling import sample_scenario, success

# Fault injection for the tests: sample numbers whose worker dies (os._exit) every time.
CRASH_ENV = "TWIN_SWEEP_CRASH_SAMPLES"


@dataclass(frozen=True)
class SweepJob:
    """The scenario's validated data, source and ``--set`` items, the root seed, the design
    (None: not needed by the kinds, or solved where a plugin asks), the controller kinds in
    order and the plugins' module directories."""

    data: dict
    source: str
    overrides: tuple
    root_seed: int
    design: object
    controllers: tuple = ("it2", "t1")
    plugin_paths: tuple = ()
    config: str = ""  # the configuration hash every record carries (twin.sweep.store.config_of)

    def scenario(self):
        use_plugin_dirs(self.plugin_paths)
        sc = Scenario(self.data, self.source, self.overrides)
        return sc.adopt_design(self.design) if self.design is not None else sc


def run_sample(job: SweepJob, index: int) -> dict:
    """Run sample ``index`` of ``job`` with each controller, in this process; the record stored for it.

    A run that falls or diverges is a result (its metrics say so). An exception inside a
    controller's run (a plugin that breaks its contract, say) is recorded against that
    controller alone, in ``errors``, so the others' results on the sample stand; a run
    stopped by one of the scenario's ``[limits]`` (:mod:`twin.limits`: too slow a step or
    run, too much memory) likewise, as ``LimitExceeded: ...``.
    """
    return assemble(job, index, {kind: run_part(job, index, kind) for kind in job.controllers})


def run_part(job: SweepJob, index: int, kind: str) -> dict:
    """Controller ``kind``'s run of sample ``index``: ``{"sample": (index, draw, level, seed,
    values), "metrics": ...}`` or ``{"sample": ..., "error": "<Name>: <message>"}``, and
    ``wall_s``. What a local worker runs (:func:`twin.sweep.backends.run_local`): each
    controller of a sample apart, so that a run a limit stops from outside (its worker killed)
    costs the others nothing."""
    if str(index) in os.environ.get(CRASH_ENV, "").split(","):
        os._exit(70)
    t0 = time.perf_counter()
    scenario = job.scenario()
    sample = sample_scenario(scenario, job.root_seed, index)
    out = {"sample": _head(sample)}
    try:
        metrics = simulate_scenario(sample.scenario, (kind,)).metrics[kind]
        out["metrics"] = {**metrics, "success": success(metrics, scenario)}
    except Exception as exc:  # noqa: BLE001 -- a run that errors is a result, kept with its message
        out["error"] = error_text(exc)
    out["wall_s"] = time.perf_counter() - t0
    return out


def _head(sample) -> tuple:
    return (sample.index, sample.draw, sample.level, sample.seed, sample.values)


def assemble(job: SweepJob, index: int, parts: dict) -> dict:
    """The record of sample ``index`` from its controllers' parts (kind → :func:`run_part`'s
    dict, or ``{"error": text}`` for a run stopped or lost from outside), in the controllers'
    order, as :func:`run_sample` always wrote it."""
    head = next((p["sample"] for p in parts.values() if "sample" in p), None)
    runs, errors = {}, {}
    for kind in job.controllers:
        part = parts[kind]
        if "metrics" in part:
            runs[kind] = part["metrics"]
        else:
            errors[kind] = part["error"]
    error = "; ".join(f"{k}: {m}" for k, m in errors.items())
    wall = sum(p.get("wall_s", 0.0) for p in parts.values())
    if head is None:
        head = _head(sample_scenario(job.scenario(), job.root_seed, index))
    record = _record(_Head(*head), runs, error, wall, job.config)
    if errors:
        record["errors"] = errors
    return record


class _Head:
    """Who a sample is (what :func:`_record` reads of a :class:`twin.sweep.sampling.Sample`)."""

    def __init__(self, index, draw, level, seed, values):
        self.index, self.draw, self.level, self.seed, self.values = index, draw, level, seed, values


LIMIT = "LimitExceeded"  # the error's name in a record when a [limits] guard stopped the run


def over_a_limit(exc: BaseException) -> bool:
    """True if ``exc`` is a run stopped by one of the scenario's ``[limits]`` (twin.limits raises
    a PluginError saying "over limits.<key>"): a result of that controller on that sample (too
    slow, too hungry), unlike a broken contract, which the sweep reports as a failure."""
    return isinstance(exc, PluginError) and (getattr(exc, "limit", None) is not None or " over limits." in str(exc))


def error_text(exc: BaseException) -> str:
    """One line for a record: the exception's name (:data:`LIMIT` for a limit) and its message."""
    return f"{LIMIT if over_a_limit(exc) else type(exc).__name__}: {' '.join(str(exc).split())}"


def crash_record(job: SweepJob, index: int, why: str) -> dict:
    """The record of a sample whose worker died every time it ran it (or that the sweep stopped)."""
    return _record(sample_scenario(job.scenario(), job.root_seed, index), {}, why, 0.0, job.config)


def _record(sample, runs: dict, error: str, wall_s: float, config: str) -> dict:
    """What the store keeps of a sample: who it is, what was sampled, each controller's metrics,
    and the hash of the configuration that produced it (checked when the sweep is resumed)."""
    return {"sample": sample.index, "draw": sample.draw, "level": sample.level, "seed": sample.seed,
            "values": sample.values, "runs": runs, "error": error, "wall_s": wall_s, "config": config}
