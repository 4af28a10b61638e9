"""``twin sweep``: a Monte Carlo sweep of a scenario (:mod:`twin.sweep`) into its directory,
resumable: :class:`SweepJob` holds what is settled before anything runs (the scenario, the
controllers and the reference, the samples to log, every plugin built once), then runs it."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from twin.outputs import rundir
from twin.scenarios.planning import controllers_of
from twin.scenarios.scenario import Scenario
from twin.sweep import run_sweep
from twin.sweep.runner import check_log_samples, sweep_controllers, sweep_plan
from twin.sweep.store import refuse_others
from twin.workflows.run import load


@dataclass
class SweepJob:
    """A sweep made ready by :meth:`prepare`: ``scenario``, ``kinds`` and ``reference`` checked,
    ``logged`` the samples whose sensor logs are written, ``summary`` what building every
    plugin once found (:func:`twin.sweep.runner.sweep_plan`: their provenance, designs,
    signals), ``out`` the sweep's directory (refused before anything runs if another
    command's or in use)."""

    scenario: Scenario
    scenario_arg: str
    draws: int
    kinds: tuple
    reference: str
    logged: tuple
    summary: dict
    out: Path

    @classmethod
    def prepare(cls, scenario: str, draws: int, seed: int | None = None, duration: float | None = None,
                overrides=(), out: Path | None = None, controller: str | None = None,
                reference: str | None = None, log_samples=()) -> "SweepJob":
        sc = load(scenario, overrides, seed, duration)
        if out is None:
            out = rundir.child_of(Path("runs"), f"sweep-{sc.name}", "the scenario's name")
        rundir.refuse_if_in_use(out)
        refuse_others(out)  # another command's folder, said before anything runs
        kinds, reference = sweep_controllers(sc, controllers_of(controller, sc), reference)
        logged = check_log_samples(sc, tuple(log_samples), draws * len(sc.sweep["levels"]))  # said before anything is
        # every plugin built once here (a user's in a worker process): one that cannot be is one line before anything runs
        summary = sweep_plan(sc, kinds)
        return cls(sc, scenario, draws, kinds, reference, logged, summary, out)

    @property
    def levels(self) -> list:
        """The uncertainty levels λ sampled (sweep.levels)."""
        return self.scenario.sweep["levels"]

    def execute(self, workers: int | None = None, backend: str = "local", address: str | None = None, progress=None):
        """Run the samples not finished yet and write the report: a :class:`twin.sweep.SweepResult`.
        An error when every run ended in one, or when a plugin broke its contract on some
        samples (the other runs are kept): see :func:`failure`."""
        return run_sweep(self.scenario, self.draws, self.out, scenario_arg=self.scenario_arg, workers=workers,
                           backend=backend, address=address, progress=progress, controllers=self.kinds,
                           reference=self.reference, log_sensors=self.logged, summary=self.summary)


def failure(result, out: Path) -> str | None:
    """The sweep's error, if it is one: every run ended in an error (nothing measured), or a
    plugin broke its contract past the preflight on some samples (the rest kept); else None."""
    if result.rows and all(r["status"] == "error" for r in result.rows):
        first = result.rows[0]
        return (f"every run of the sweep ended in an error, so nothing was measured (first: sample "
                f"{first['sample']}, {first['controller']}: {first['error']})")
    broken = [r for r in result.rows if str(r.get("error") or "").startswith("PluginError")]
    if broken:
        first = broken[0]
        return (f"{len(broken)} run{'s' * (len(broken) > 1)} ended with a plugin error (first: sample "
                f"{first['sample']}, {first['error'][len('PluginError: '):]}); the other runs are stored in {out}")
    return None


__all__ = ["SweepJob", "failure"]
