"""A scenario's runs: each controller on identical conditions (the same true plant, sensor
seed, estimator, pushes and faults), simulated by the engine (:mod:`twin.sim`), with their
metrics. Nothing is written here: :mod:`twin.workflows.run` writes a run directory of what
:func:`run_controllers` returns, and a sweep or a check keeps only the metrics.

Nothing here depends on the wall clock but the timings: the same scenario and seed give the
same runs and metrics.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

from twin.errors import PluginError, TwinError
from twin.limits import limit_of
from twin.outputs.fingerprint import digests, record
from twin.outputs.metrics import run_metrics
from twin.registry import check_kinds, parse_controllers
from twin.scenarios.contained import ContainedScenario, involves_plugins
from twin.scenarios.planning import LazyDesign, plan, plugins_of
from twin.scenarios.scenario import Scenario
from twin.sim.recorder import check_log_every
from twin.sim.simulate import simulate
from twin.sim.spec import LOG_FORMATS, Logging  # trajectory.csv, or the same text gzip-compressed


@dataclass
class ScenarioResult:
    """What a scenario's runs produced: the runs, their metrics, the plugins loaded (their
    provenance), the files written (by :func:`twin.workflows.run.run_scenario`) and timings (s)."""

    scenario: Scenario
    runs: list
    metrics: dict
    files: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    video: object = None
    plugins: list = field(default_factory=list)
    design: object = None
    notes: list = field(default_factory=list)
    designs: dict = field(default_factory=dict)  # name → digest of each design the runs used
    errors: dict = field(default_factory=dict)  # kind → the PluginError of a run a limit stopped (keep_limited)

    def environment(self) -> dict:
        """What these runs ran on, with their designs' digests (metrics.json's "environment")."""
        return record(self.designs)


def checked_kinds(controllers, listed) -> tuple[str, ...]:
    """The controller kinds of a run: ``controllers`` ("both", a comma-separated text, or a
    sequence of kinds; None: ``listed``, the scenario's ``controller.kinds``), each checked."""
    if isinstance(controllers, str):
        return parse_controllers(controllers)
    return check_kinds("controller", controllers if controllers is not None else listed, "controllers")


def check_logging(log_every: int, log_format: str) -> int:
    """``log_every`` as a whole number ≥ 1 and ``log_format`` one of :data:`LOG_FORMATS`, or one line."""
    every = check_log_every(log_every)
    if log_format not in LOG_FORMATS:
        raise TwinError(f"log_format must be one of {', '.join(LOG_FORMATS)}, got {log_format!r}")
    return every


def reads_truth(run) -> bool:
    """True if the run's estimator read the ground truth (it declares ``reads_truth = True``,
    so each measurement carried the truth): its estimate is a reference, not an estimate."""
    return getattr(getattr(run, "measurements", None), "truth", None) is not None


def run_controllers(scenario: Scenario, kinds, progress=None, every: int = 1, log_format: str = "csv",
                    keep_limited: bool = False, specs=None, box=None, plugins=None) -> ScenarioResult:
    """Run ``scenario`` with each controller of ``kinds`` (checked already) and measure each run.

    ``progress(stage, done, total)``: called as the runs advance; ``every`` N: keep every N-th
    control step only (the metrics still come from every step); ``log_format``: what the
    trajectory will be written as (the runs record it). ``keep_limited``: a run that a limit of
    the scenario's ``[limits]`` stops (:func:`twin.limits.limit_of`) is recorded against that
    controller alone, in the result's ``errors``, and the others run; if every run was stopped,
    the first one's PluginError is raised. False: that PluginError is raised at once.
    ``specs``: the runs' specifications as :func:`twin.scenarios.planning.plan` made them (their
    plugins built already); None: planned here. ``box``: a
    :class:`twin.scenarios.contained.ContainedScenario` whose worker process runs every
    controller (a user's plugin is involved), or None (here). The numbers are the same either way.
    ``plugins``: the provenance of the plugins the runs load, if known (None: found here)."""
    timings = {}
    if box is not None:
        summary = box.plan()
        lazy = LazyDesign(scenario)
        if summary["design"] is not None:
            lazy.solved, lazy.seconds = summary["design"], summary["design_s"]
        plugins = summary["plugins"]
        specs = [None] * len(kinds)
    else:
        if specs is None:
            specs = plan(scenario, kinds)
        lazy = specs[0].design if specs and isinstance(specs[0].design, LazyDesign) else None
        if plugins is None:
            plugins = plugins_of(scenario, kinds)
    runs, metrics, controllers, errors = [], {}, [], {}
    for kind, spec in zip(kinds, specs):
        cb = None if progress is None else (lambda done, total, k=kind: progress(f"run {k}", done, total))
        t0 = time.perf_counter()
        try:
            if box is None:
                logging = Logging(every, format=log_format)
                if spec.logging != logging:
                    spec = replace(spec, logging=logging)
                run = simulate(spec, cb)
            else:
                done = box.run(kind, every, log_format, cb)
                run = done["run"]
                if done["design"] is not None and lazy.solved is None:
                    lazy.solved, lazy.seconds = done["design"], done["design_s"]
        except PluginError as exc:
            if not keep_limited or limit_of(exc) is None:
                raise
            errors[kind] = exc  # that controller's alone: the others run on
            continue
        controllers.append((kind, spec.controller.kind if box is None else DesignDigest(done["digest"])))
        run.sensing = scenario.estimator
        timings[f"run_{kind}_s"] = time.perf_counter() - t0
        runs.append(run)
        metrics[kind] = run_metrics(run)
        if reads_truth(run):  # said wherever the run's figures go: they are not an estimator's
            metrics[kind]["estimator_reads_truth"] = True
    solved = [] if lazy is None or lazy.solved is None else [lazy.solved]
    if solved:
        timings = {"design_s": lazy.seconds, **timings}
    if errors and not runs:  # nothing to write: the first limit's one line, as without keep_limited
        raise next(iter(errors.values()))
    return ScenarioResult(scenario, runs, metrics, timings=timings, plugins=plugins,
                          design=solved[0] if solved else None,
                          designs=digests(solved[0] if solved else None, controllers), errors=errors)


def simulate_scenario(scenario: Scenario, controllers=None, contained: bool = False, progress=None) -> ScenarioResult:
    """The runs of ``scenario`` with ``controllers`` (kinds; None: the scenario's
    ``controller.kinds``) and their metrics, nothing written (:func:`run_controllers`);
    ``contained``: a run that involves a user's plugin runs in a worker process
    (:mod:`twin.containment`), with the same numbers."""
    kinds = checked_kinds(controllers, scenario.controllers)
    if contained and involves_plugins(scenario, kinds):
        with ContainedScenario(scenario, kinds) as box:
            return run_controllers(scenario, kinds, progress, box=box)
    return run_controllers(scenario, kinds, progress)


class DesignDigest:
    """A controller run in a worker, as :func:`twin.outputs.fingerprint.digests` asks of it: its
    ``design_digest()`` (None: it has none)."""

    def __init__(self, digest: str | None):
        if digest is not None:
            self.design_digest = lambda: digest


__all__ = ["DesignDigest", "ScenarioResult", "check_logging", "checked_kinds", "reads_truth", "run_controllers",
           "simulate_scenario"]
