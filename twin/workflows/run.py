"""``twin run``: a scenario's runs, each controller on identical conditions, into a run
directory (:mod:`twin.outputs.run_directory` says what it holds).

:func:`run_scenario` is the workflow for programs; :class:`RunJob` is the same work in the
steps the command prints between (what will run, then the runs, then the table).
"""
from __future__ import annotations

import contextlib
import math
import re
from dataclasses import dataclass
from pathlib import Path

from twin.errors import TwinError
from twin.logs.format import write_log
from twin.outputs import figure_worker, rundir
from twin.outputs.run_directory import RunFiles, write_run_directory
from twin.scenarios import load_scenario
from twin.scenarios.contained import ContainedScenario, involves_plugins
from twin.scenarios.planning import plan, plan_runs
from twin.scenarios.runs import ScenarioResult, check_logging, checked_kinds, run_controllers
from twin.scenarios.scenario import Scenario


def load(scenario: str, overrides=(), seed: int | None = None, duration: float | None = None) -> Scenario:
    """The scenario (a built-in's name or a file) with ``--set`` items, ``--seed`` and
    ``--duration`` applied (in that order)."""
    extra = list(overrides)
    if seed is not None:
        extra.append(f"seed={seed}")
    if duration is not None:
        if not (math.isfinite(duration) and 0 < duration <= 3600):
            raise TwinError(f"--duration must be in (0, 3600] s, got {duration:g}")
        extra.append(f"duration={duration!r}")
    return load_scenario(scenario, extra)


def title(sc: Scenario) -> str:
    """The scenario's name and description, saying which tables --set changed (the
    description was written for the file as it is)."""
    changed = sc.changed_keys
    if sc.sets_nothing:  # an empty file: say what the defaults are rather than run them without a word
        d = sc.data
        return (f"{sc.name}: the file sets nothing, so the defaults run: a catch from θ0 = {d['initial']['theta']:g} rad "
                f"for {d['duration']:g} s (twin scenarios NAME prints a built-in to start from)")
    text = f"{sc.name}: {sc.description}" if sc.description else sc.name
    return text + (f" [changed by --set: {', '.join(changed)}]" if changed else "")


def run_scenario(scenario: Scenario, controllers=None, out: Path | None = None, video: bool | None = None,
                 progress=None, log_every: int = 1, log_format: str = "csv",
                 keep_limited: bool = False, specs=None, log_sensors: bool = False,
                 contained=False, figure=None, plugins=None) -> ScenarioResult:
    """Run ``scenario`` with each of ``controllers`` (kinds; None: the scenario's
    ``controller.kinds``) on identical conditions: same true plant, sensor seed,
    estimator kind, pushes and faults.

    ``out``: the run directory (None: write nothing), written as a unit with its manifest
    (:class:`twin.outputs.rundir.StagedDirectory`: the directory is the earlier one until this one is
    complete; see :func:`twin.outputs.run_directory.write_run_directory` for what an error or
    interrupt keeps); ``video``: render the MP4 (None: as the scenario says);
    ``progress(stage, done, total)``: called as the runs and the video advance;
    ``log_every`` N: keep and write every N-th control step only (the metrics still come
    from every step; see :func:`twin.sim.bullet_loop.simulate_twin`); ``log_format``: "csv"
    (trajectory.csv) or "csv.gz" (trajectory.csv.gz, gzip). Nothing is written unless every
    run finished (a run that falls is a result; a plugin that breaks its contract is an error).

    ``keep_limited``: a controller's run that a limit of the scenario's ``[limits]`` stops
    (:func:`twin.limits.limit_of`) is recorded against that controller alone, in the
    result's ``errors`` and metrics.json's ``errors``, and the other controllers run and are
    written (the manifest's exit status is then 2); if every run was stopped, the first
    one's PluginError is raised and nothing is written. False: that PluginError is raised
    at once, like any other.

    ``log_sensors``: also write each controller's run as a sensor log (:mod:`twin.logs.format`:
    the readings, commands and truth) in ``sensor-logs/KIND/`` (needs simulated sensors and
    every control step kept).

    ``specs``: the runs' specifications as :func:`twin.scenarios.planning.plan` made them for
    these controllers (their plugins built already, as ``twin run`` does before it prints
    anything); None: planned here.

    ``contained``: run a scenario that involves a user's plugin in a worker process
    (:mod:`twin.containment`): True, or the :class:`twin.scenarios.contained.ContainedScenario`
    that planned it already (the ``twin`` commands); False (the default): in this process. A
    scenario of built-in kinds alone always runs here. The numbers are the same either way.

    ``figure``: a :class:`twin.outputs.figure_worker.FigureWorker` started by the caller
    (``twin run`` starts it before it loads the scenario, so that it imports matplotlib
    meanwhile), ended here whatever happens; None: one is started here where a CPU is free for it.

    ``plugins``: the provenance of the plugins the runs load, if known (None: found here).
    """
    try:
        every = check_logging(log_every, log_format)
        kinds = checked_kinds(controllers, scenario.controllers)
        if specs is not None and [s.label for s in specs] != list(kinds):
            raise TwinError(f"specs must be plan(scenario, {list(kinds)!r})'s, one per controller in that order, got "
                            f"runs of {[s.label for s in specs]!r}")
        if log_sensors:  # said before anything runs
            if scenario.sensor_config() is None:
                raise TwinError("--log-sensors needs simulated sensors: sensors.sensing is \"ideal\" here (nothing is "
                                "measured); allowed: sensors.sensing = \"estimated\"")
            if every != 1:
                raise TwinError(f"--log-sensors needs every control step (a sensor log holds every reading), so "
                                f"--log-every must be 1, got {every}")
        box = contained if isinstance(contained, ContainedScenario) else None
        if box is None and contained and involves_plugins(scenario, kinds):
            with ContainedScenario(scenario, kinds) as box:
                return _run(scenario, kinds, out, video, progress, every, log_format, keep_limited, None,
                            log_sensors, box, figure, plugins)
        if box is not None and box.kinds != tuple(kinds):
            raise TwinError(f"contained must be the ContainedScenario of controllers {list(kinds)!r}, got one of "
                            f"{list(box.kinds)!r}")
        return _run(scenario, kinds, out, video, progress, every, log_format, keep_limited, specs, log_sensors, box,
                    figure, plugins)
    finally:
        if figure is not None:  # used and done, or not taken up (an error before the runs): ended
            figure.cancel()


def _run(scenario, kinds, out, video, progress, every, log_format, keep_limited, specs, log_sensors, box,
         figure, plugins) -> ScenarioResult:
    """:func:`run_scenario` after its checks: the runs, then their directory."""
    # checked before the runs simulate, so that a directory that cannot take them is said at once
    staged = rundir.StagedDirectory(out, "twin run") if out is not None else None
    try:
        # the figure's worker process starts now (unless the caller started it), to import
        # matplotlib while the runs simulate
        worker = (figure if figure is not None else figure_worker.start()) if out is not None else None
        try:
            if box is None and specs is None:
                specs = plan(scenario, kinds)
            result = run_controllers(scenario, kinds, progress, every, log_format, keep_limited, specs, box, plugins)
            if staged is not None:
                write_run_directory(result, staged, _files(scenario, specs, video, every, log_format, log_sensors,
                                                           result), progress, worker)
            return result
        finally:
            if worker is not None:  # ended before its staging goes: it may be writing figure.png there
                worker.close()
    except BaseException as exc:
        if staged is not None:
            staged.discard()
            if staged.started or isinstance(exc, KeyboardInterrupt):  # an error before any writing says enough
                rundir.kept(exc, staged.unchanged())
        raise
    finally:
        if staged is not None:
            staged.discard()


def _files(scenario: Scenario, specs, video, every: int, log_format: str, log_sensors: bool,
           result: ScenarioResult) -> RunFiles:
    """What the run directory of ``scenario``'s runs says of them besides the runs."""
    if specs and specs[0] is not None:
        sensors, config = specs[0].sensing.true, specs[0].plant
    else:  # run in a worker process: the scenario says the same
        sensors, config = scenario.sensor_config(), scenario.twin_config()
    d = scenario.data
    text = f"{scenario.name}: {scenario.description}\nseed {scenario.seed}, " + (
        "ideal sensing" if sensors is None else f"{scenario.estimator} estimator in the loop") + (
        ", analytic model (equation 1)" if scenario.plant_model == "analytic" else "") + (
        # the description was written for the file as it is: say which tables --set changed
        f"; changed by --set: {', '.join(scenario.changed_keys)}" if scenario.changed_keys else "")
    want_video = video if video is not None else d["video"]["enabled"]
    extra = ()
    if log_sensors:  # the robot-log format, one directory per controller's run (a plugin's "a.b:C" made a name)
        extra = tuple((f"sensor-logs/{re.sub(r'[^A-Za-z0-9_.-]+', '_', run.controller)}",
                       lambda path, run=run: write_log(run, path, scenario)) for run in result.runs)
    return RunFiles(text, {"scenario": scenario.record(), "source": scenario.source, "seed": scenario.seed},
                    d["video"] if want_video else None, config.control_rate, every, log_format, extra)


@dataclass
class RunJob:
    """``twin run``'s work in the steps the command prints between: made by :meth:`prepare`
    (the scenario loaded, the output directory held, every plugin built once, before anything
    runs or is said), then :meth:`execute` (the runs and their directory). Use it as a context
    manager: leaving it lets go of the directory and of the plugins' worker process."""

    scenario: Scenario
    kinds: tuple
    out: Path
    earlier: bool  # --out holds an earlier run, replaced when this one is complete
    plugins: list
    picked: object  # the sweep's sample (twin.sweep.sampling.Sample) with --sample, else None
    root_seed: int
    _target: object = None
    _stack: object = None
    _specs: object = None
    _box: object = None

    @classmethod
    def prepare(cls, scenario: str, controller: str | None = None, seed: int | None = None,
                duration: float | None = None, overrides=(), out: Path | None = None, sample: int | None = None,
                plant_file: Path | None = None) -> "RunJob":
        if plant_file is not None:
            # only with --plant: the calibration's modules are not loaded for every run
            from twin.calibrate.output import plant_overrides

            overrides = tuple(plant_overrides(plant_file)) + tuple(overrides)
        sc = load(scenario, overrides, seed, duration)
        if out is None:  # the scenario's name must not lead the outputs out of runs/ (a shared file may say "../..")
            out = rundir.child_of(Path("runs"), sc.name if sample is None else f"{sc.name}-sample{sample}",
                                  "the scenario's name")
        target = rundir.StagedDirectory(out, "twin run")  # a directory the run may not replace: said before anything runs
        # an earlier run there is replaced once this one is complete: said, before anything runs
        earlier = target.existed and any(Path(out).iterdir())
        stack = contextlib.ExitStack()
        try:
            picked, root = None, sc.seed
            if sample is not None:
                # only with --sample: the sweep's package (its runner, its backends) is not loaded for every run
                from twin.sweep.sampling import sample_scenario

                picked = sample_scenario(sc, sc.seed, sample)
                sc = picked.scenario
            # every plugin built once, before anything runs or is said: a user's in a worker process
            # (twin.containment), where its exits, crashes, hangs, threads and processes are contained
            planned = plan_runs(sc, controller)
            box, kinds, specs, plugins = None, planned.kinds, planned.specs, planned.plugins
            if specs is None:
                box = stack.enter_context(ContainedScenario(sc, kinds))
                plugins = box.plan()["plugins"]
        except BaseException as exc:
            stack.close()
            if isinstance(exc, KeyboardInterrupt):
                rundir.kept(exc, target.unchanged())
            target.close()
            raise
        return cls(sc, kinds, out, earlier, plugins, picked, root, target, stack, specs, box)

    def execute(self, video: bool | None = None, progress=None, log_every: int = 1, log_format: str = "csv",
                log_sensors: bool = False, figure=None) -> ScenarioResult:
        """The runs and their directory (:func:`run_scenario`, a limit's run kept apart)."""
        try:
            return run_scenario(self.scenario, self.kinds, out=self.out, video=video, progress=progress,
                                log_every=log_every, log_format=log_format, keep_limited=True, specs=self._specs,
                                log_sensors=log_sensors, contained=self._box or False, figure=figure,
                                plugins=self.plugins)
        except KeyboardInterrupt as exc:  # what the run kept, if it got that far, stands
            rundir.kept(exc, self._target.unchanged())
            raise

    def __enter__(self) -> "RunJob":
        return self

    def __exit__(self, *exc) -> None:
        try:
            self._stack.close()
        finally:
            self._target.close()  # the directory was held from the start: a second command writing there is refused


__all__ = ["RunJob", "ScenarioResult", "load", "run_scenario", "title"]
