"""What a scenario's runs need settled before they run, wherever they run: the controllers
asked for (:func:`controllers_of`), each run's specification with its plugins built
(:func:`plan`), the LMI design solved on first demand (:class:`LazyDesign`), the provenance
of the plugins they load (:func:`plugins_of`) and the refusal of parameters no run would use
(:func:`refuse_unused_params`).

Both sides of a run use them: :mod:`twin.scenarios.runs` in the command's process and
:mod:`twin.scenarios.contained` in a plugin's worker process; they live here, below both, so
that neither imports the other for them.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from twin.registry import is_user_code, parse_controllers, provenance
from twin.scenarios.schema import ScenarioError, key_text
from twin.scenarios.scenario import Scenario


class LazyDesign:
    """The scenario's LMI design, solved (or taken from the design store) when a controller
    first asks for it, with the time that took: only the fuzzy cascades, or a plugin that
    asks, need it, and design.json is written only then."""

    def __init__(self, scenario: Scenario):
        self.solve = scenario.design_solver()  # the scenario's design options alone, not the scenario
        self.solved = None
        self.seconds = None

    def __call__(self):
        if self.solved is None:
            t0 = time.perf_counter()
            self.solved = self.solve()
            self.seconds = time.perf_counter() - t0
        return self.solved


def kinds_of(scenario: Scenario, controllers) -> tuple:
    """(role, kind) of every kind a run of ``scenario`` with ``controllers`` builds: each
    controller, the estimator, the plant (the one place that lists them)."""
    return (*(("controller", k) for k in controllers), ("estimator", scenario.estimator),
            ("plant", scenario.plant_model))


def plugin_roles(scenario: Scenario, controllers) -> tuple:
    """(role, kind) of each kind of :func:`kinds_of` that runs a user's code (an import path, an
    export directory's C: :func:`twin.registry.is_user_code`)."""
    return tuple((role, k) for role, k in kinds_of(scenario, controllers) if is_user_code(k))


def plugins_of(scenario: Scenario, controllers) -> list[dict]:
    """The provenance (module, file, SHA-256) of every import-path kind a run of ``scenario``
    with ``controllers`` loads (:func:`twin.registry.provenance`)."""
    return [provenance(role, k) for role, k in plugin_roles(scenario, controllers)]


def refuse_unused_params(scenario: Scenario, kinds) -> None:
    """``[controller.params.KIND]`` for a controller that neither this run nor the scenario's
    ``controller.kinds`` runs would be ignored without a word (a typo in KIND, or parameters
    for a controller that was taken out of the list): one line instead. Parameters for a
    listed controller that ``--controller`` leaves out this time are kept for when it runs."""
    listed = scenario.data["controller"]["kinds"]
    runs = list(dict.fromkeys([*kinds, *listed]))
    unused = [k for k in scenario.data["controller"]["params"] if k not in runs]
    if unused:
        raise ScenarioError(f"{scenario.source}: controller.params.{key_text(unused[0])}: controller "
                            f"{unused[0]!r} is never run (this run's: {', '.join(kinds)}; controller.kinds: "
                            f"{', '.join(listed)}), so its parameters would be ignored; allowed: "
                            f"parameters for a controller run or listed in controller.kinds")


def controllers_of(choice: str | None, scenario: Scenario | None = None) -> tuple[str, ...]:
    """The controller kinds of ``--controller CHOICE`` ("both", or a comma-separated list of
    built-in names and import paths); None: the scenario's ``controller.kinds``."""
    if choice is None:
        return scenario.controllers if scenario is not None else ("it2", "t1")
    return parse_controllers(choice)


def plan(scenario: Scenario, kinds) -> list:
    """The :class:`twin.sim.spec.RunSpec` of each controller kind's run of ``scenario``, its
    controller and estimator built once (:meth:`twin.sim.spec.RunSpec.built`, a plugin that
    cannot be built a one-line error naming the scenario's key), so that it is said before
    anything runs; the LMI design is solved only if a controller asks for it (:class:`LazyDesign`)."""
    refuse_unused_params(scenario, kinds)
    design = LazyDesign(scenario)
    named = [scenario.named(k) for k in kinds]
    return [spec.built(n) for spec, n in zip(scenario.run_specs(kinds, design), named)]


@dataclass(frozen=True)
class RunPlan:
    """What a command runs of a scenario, settled before anything runs or is said: the
    controller ``kinds``; ``roles``, the (role, kind) of each import-path kind (a user's code);
    ``plugins``, their provenance (:func:`twin.registry.provenance`); ``specs``, each run's
    specification with its plugins built (:func:`plan`), or None when a user's code is
    involved: it is then built and run in a worker process (:mod:`twin.scenarios.contained`)."""

    kinds: tuple
    roles: tuple
    plugins: list
    specs: list | None


def plan_runs(scenario: Scenario, choice: str | None = None) -> RunPlan:
    """The :class:`RunPlan` of ``scenario`` with ``--controller CHOICE`` (None: its ``controller.kinds``)."""
    kinds = controllers_of(choice, scenario)
    roles = plugin_roles(scenario, kinds)
    return RunPlan(kinds, roles, [provenance(role, k) for role, k in roles], None if roles else plan(scenario, kinds))


__all__ = ["LazyDesign", "RunPlan", "controllers_of", "kinds_of", "plan", "plan_runs", "plugin_roles", "plugins_of",
           "refuse_unused_params"]
