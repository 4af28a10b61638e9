"""A scenario's plugins, planned and run in a worker process the command can stop.

When a run involves a user's plugin (a controller or an estimator named by an import path),
the ``twin`` commands run it through here, in a :class:`twin.containment.Worker`: first
:func:`plan_summary` (import and build every plugin once, so that one that cannot be built is
one line before anything runs, and learn what the command must know of them: their files and
SHA-256, their extra signals, whether the estimator reads the truth, their designs' digests),
then each controller's run (:func:`run_kind`). The command's process never imports the
plugins' modules. Runs of built-in kinds alone stay in the command's process, as before.

The numbers are those of a run in one's own process: the worker runs the same code on the
same scenario, design and seed.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

from twin.containment import Task, Workers, run_contained
from twin.limits import PluginLimits
from twin.registry import plugin_dirs
from twin.scenarios.planning import LazyDesign, plan, plugin_roles, plugins_of
from twin.scenarios.scenario import Scenario
from twin.sim.simulate import simulate
from twin.sim.spec import Logging


def involves_plugins(scenario: Scenario, kinds) -> bool:
    """True if a run of ``scenario`` with controllers ``kinds`` runs a user's code: a
    controller, the estimator or the plant named by an import path."""
    return bool(plugin_roles(scenario, kinds))


@dataclass(frozen=True)
class Recipe:
    """What a worker rebuilds the scenario from: its validated data, source and ``--set``
    items, and the LMI design already solved for it (None: solved there if a controller asks)."""

    data: dict
    source: str
    overrides: tuple
    design: object = None

    @classmethod
    def of(cls, scenario: Scenario, design=None) -> "Recipe":
        return cls(scenario.data, scenario.source, tuple(scenario.overrides), design)

    def scenario(self) -> Scenario:
        sc = Scenario(self.data, self.source, self.overrides)
        return sc.adopt_design(self.design) if self.design is not None else sc


def names_of(scenario: Scenario, kind: str | None = None) -> dict:
    """The plugins of a run, role → kind, for what a command says of it."""
    return {**({"controller": kind} if kind is not None else {}), "estimator": scenario.estimator}


def limits_of(scenario: Scenario):
    """The scenario's :class:`twin.limits.PluginLimits` (inactive if ``[limits]`` sets none)."""
    return PluginLimits(**scenario.data["limits"])


# ---- what runs in the worker (importable, pickled by reference) --------------------------------------------

def plan_summary(recipe, kinds) -> dict:
    """Build every controller of ``kinds`` and the estimator of the scenario once (the one-line
    error of one that cannot be built is raised here), and say what a command needs of them:
    ``plugins`` (the provenance of each import-path kind, :func:`twin.scenarios.planning.plugins_of`),
    ``dirs`` (their modules' directories, :func:`twin.registry.plugin_dirs`), ``signals`` (kind →
    the controller's extra logged signals), ``digests`` (kind → its ``design_digest()``, for
    the controllers that have one), ``reads_truth`` (the estimator declares it), ``design``
    (the LMI design, if a controller asked for it: solved or taken from the design cache) and
    ``design_s`` (the seconds that took)."""
    sc = recipe.scenario() if isinstance(recipe, Recipe) else recipe
    kinds = tuple(kinds)
    if kinds:
        specs = plan(sc, kinds)
    else:  # the estimator alone (a sweep's preflight of a user's estimator)
        specs = [sc.run_specs((None,), LazyDesign(sc))[0].built(sc.named(None))]
    lazy = specs[0].design
    signals, digests = {}, {}
    for kind, spec in zip(kinds, specs):
        obj = spec.controller.kind
        signals[kind] = tuple(getattr(obj, "signals", ()))
        own = getattr(obj, "design_digest", None)
        if callable(own):
            digests[kind] = str(own())
    estimator = specs[0].estimator.kind
    return {"plugins": plugins_of(sc, kinds), "dirs": plugin_dirs(plugin_roles(sc, kinds)), "signals": signals, "digests": digests,
            "reads_truth": bool(getattr(estimator, "reads_truth", False)) if not isinstance(estimator, str) else False,
            "design": lazy.solved, "design_s": lazy.seconds}


def run_kind(recipe: Recipe, kind: str, every: int = 1, log_format: str = "csv", progress=None) -> dict:
    """Controller ``kind``'s run of the recipe's scenario, logged every ``every`` control steps:
    ``run`` (a :class:`twin.sim.runs.Run`), ``digest`` (the controller's ``design_digest()``,
    or None), ``design`` and ``design_s`` (the LMI design if it was solved here)."""
    sc = recipe.scenario()
    lazy = LazyDesign(sc)
    spec = replace(sc.run_specs((kind,), lazy)[0], logging=Logging(every, format=log_format)).built(sc.named(kind))
    run = simulate(spec, progress)
    own = getattr(spec.controller.kind, "design_digest", None)
    return {"run": run, "digest": str(own()) if callable(own) else None, "design": lazy.solved,
            "design_s": lazy.seconds}


# ---- the command's side -------------------------------------------------------------------------------------

class ContainedScenario:
    """A scenario's plugin runs in one worker (a new one after a worker is killed or retired):
    :meth:`plan`, then :meth:`run` per controller. Use with ``with``: the worker dies when the
    block ends."""

    def __init__(self, scenario: Scenario, kinds, design=None):
        self.scenario = scenario
        self.kinds = tuple(kinds)
        self.recipe = Recipe.of(scenario, design)
        self.limits = limits_of(scenario)
        self.pool = Workers(1)
        self.summary: dict | None = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self.pool.close()

    def _do(self, task: Task):
        return run_contained(task, self.pool)

    def plan(self) -> dict:
        """:func:`plan_summary` in the worker; the design it solved, if any, is adopted for the runs."""
        if self.summary is None:
            self.summary = self._do(Task(plan_summary, (self.recipe, self.kinds), limits=self.limits,
                                         plugins=plugin_roles(self.scenario, self.kinds), what="plan"))
            if self.summary["design"] is not None and self.recipe.design is None:
                self.recipe = replace(self.recipe, design=self.summary["design"])
        return self.summary

    def adopt(self, design) -> None:
        """Use ``design`` (solved in the command's process) in the runs."""
        if design is not None:
            self.recipe = replace(self.recipe, design=design)

    def run(self, kind: str, every: int = 1, log_format: str = "csv", progress=None) -> dict:
        """:func:`run_kind` in the worker, under the scenario's limits."""
        t0 = time.perf_counter()
        out = self._do(Task(run_kind, (self.recipe, kind, every, log_format), limits=self.limits,
                            names=names_of(self.scenario, kind), progress=progress))
        out["wall_s"] = time.perf_counter() - t0
        if out["design"] is not None and self.recipe.design is None:
            self.recipe = replace(self.recipe, design=out["design"])
        return out


__all__ = ["ContainedScenario", "Recipe", "involves_plugins", "limits_of", "names_of", "plan_summary", "plugin_roles",
           "run_kind"]
