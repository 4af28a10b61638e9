"""Run a scenario: design the gains, run each controller on the twin, write the outputs.

Outputs in the run directory:

- ``trajectory.csv``: one row per control step and controller (``controller`` column
  first), every logged signal with its unit in the header: time, ground truth, the
  estimates the controllers acted on, commands, torques delivered, pushes. With
  ``log_every`` N > 1, one row per N control steps; with ``log_format="csv.gz"`` the same
  text gzip-compressed, as ``trajectory.csv.gz``;
- ``metrics.json``: the scenario (complete, defaults filled in), the seed, and one
  object per controller run (:func:`twin.outputs.metrics.run_metrics`, always from every control
  step); when the trajectory is decimated or compressed, a ``log`` object says so (which
  rows were written, how many of how many, the file); with ``keep_limited``, an
  ``errors`` object holds the controllers whose runs a limit of ``[limits]`` stopped
  (kind → ``LimitExceeded: <the one-line message>``), which are in no other file;
- ``figure.png``: θ, torque, dψ/dt, distance and α over time (the paper's Figs. 6–8),
  the controllers overlaid;
- ``video.mp4``: offscreen rendering, the controllers side by side (optional);
- ``design.json``: the LMI design the balance controllers used;
- ``manifest.json``, written last: every file with its size and SHA-256, the command's exit
  status and whether every output is there (:mod:`twin.outputs.rundir`).

The directory is written as a unit: staged beside the target and put in its place when
complete, so it never mixes this run's files with an earlier run's.

Nothing here depends on the wall clock: the same scenario and seed give byte-identical
``metrics.json`` and ``trajectory.csv``.
"""
from __future__ import annotations

import csv
import gzip
import io
import re
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from twin.outputs import figure_worker, rundir
from twin.outputs.report import ZOOM_THETA0, push_windows, zoom_window  # the catch the figure zooms on
from twin.errors import PluginError, TwinError
from twin.limits import limit_of
from twin.scenarios.planning import LazyDesign, plugins_of, refuse_unused_params
from twin.scenarios.scenario import Scenario

from twin.sim.spec import LOG_FORMATS, Logging  # noqa: E402 -- trajectory.csv, or the same text gzip-compressed


@dataclass
class ScenarioResult:
    """What :func:`run_scenario` produced: the runs, their metrics, the plugins loaded (their
    provenance), the files written and timings (s)."""

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
        from twin.outputs.fingerprint import record

        return record(self.designs)


def controllers_of(choice: str | None, scenario: Scenario | None = None) -> tuple[str, ...]:
    """The controller kinds of ``--controller CHOICE`` ("both", or a comma-separated list of
    built-in names and import paths); None: the scenario's ``controller.kinds``."""
    from twin.registry import parse_controllers

    if choice is None:
        return scenario.controllers if scenario is not None else ("it2", "t1")
    return parse_controllers(choice)


def run_scenario(scenario: Scenario, controllers=None, out: Path | None = None, video: bool | None = None,
                 progress=None, log_every: int = 1, log_format: str = "csv",
                 keep_limited: bool = False, specs=None, log_sensors: bool = False,
                 contained=False, figure=None) -> ScenarioResult:
    """Run ``scenario`` with each of ``controllers`` (kinds; None: the scenario's
    ``controller.kinds``) on identical conditions: same true plant, sensor seed,
    estimator kind, pushes and faults.

    ``out``: the run directory (None: write nothing), written as a unit with its manifest
    (:class:`twin.outputs.rundir.StagedDirectory`: the directory is the earlier one until this one is
    complete; see :func:`_write` for what an error or interrupt keeps); ``video``: render the
    MP4 (None: as the scenario says); ``progress(stage, done, total)``: called as the runs and the video advance;
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

    ``specs``: the runs' specifications as :func:`plan` made them for these controllers
    (their plugins built already, as ``twin run`` does before it prints anything); None:
    planned here.

    ``contained``: run a scenario that involves a user's plugin in a worker process
    (:mod:`twin.containment`): True, or the :class:`twin.scenarios.contained.ContainedScenario`
    that planned it already (the ``twin`` commands); False (the default): in this process. A
    scenario of built-in kinds alone always runs here. The numbers are the same either way.

    ``figure``: a :class:`twin.outputs.figure_worker.FigureWorker` started by the caller
    (``twin run`` starts it before it loads the scenario, so that it imports matplotlib
    meanwhile), ended here whatever happens; None: one is started here where a CPU is free for it.
    """
    try:
        return _run_scenario(scenario, controllers, out, video, progress, log_every, log_format, keep_limited, specs,
                             log_sensors, contained, figure)
    finally:
        if figure is not None:  # used and done, or not taken up (an error before the runs): ended
            figure.cancel()


def _run_scenario(scenario, controllers, out, video, progress, log_every, log_format, keep_limited, specs,
                  log_sensors, contained, figure) -> ScenarioResult:
    """:func:`run_scenario`'s work (which ends ``figure`` after it)."""
    from twin.sim.recorder import check_log_every
    from twin.registry import check_kinds, parse_controllers

    every = check_log_every(log_every)
    if log_format not in LOG_FORMATS:
        raise TwinError(f"log_format must be one of {', '.join(LOG_FORMATS)}, got {log_format!r}")
    if isinstance(controllers, str):
        kinds = parse_controllers(controllers)
    else:
        kinds = check_kinds("controller", controllers if controllers is not None else scenario.controllers,
                            "controllers")
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
    from twin.scenarios.contained import ContainedScenario, involves_plugins

    box = contained if isinstance(contained, ContainedScenario) else None
    if box is None and contained and involves_plugins(scenario, kinds):
        with ContainedScenario(scenario, kinds) as box:
            return run_scenario(scenario, kinds, out, video, progress, log_every, log_format, keep_limited, None,
                                log_sensors, box, figure)
    if box is not None and box.kinds != tuple(kinds):
        raise TwinError(f"contained must be the ContainedScenario of controllers {list(kinds)!r}, got one of "
                        f"{list(box.kinds)!r}")
    # checked before the runs simulate, so that a directory that cannot take them is said at once
    staged = rundir.StagedDirectory(out, "twin run") if out is not None else None
    try:
        # the figure's worker process starts now (unless the caller started it), to import
        # matplotlib while the runs simulate
        worker = (figure if figure is not None else figure_worker.start()) if out is not None else None
        try:
            return _run_and_write(scenario, kinds, staged, video, progress, every, log_format, worker, keep_limited,
                                  specs, log_sensors, box)
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


def plan(scenario: Scenario, kinds) -> list:
    """The :class:`twin.sim.spec.RunSpec` of each controller kind's run of ``scenario``, its
    controller and estimator built once (:meth:`Scenario.run_spec`), so that a plugin that
    cannot be built is one line before anything runs; the LMI design is solved only if a
    controller asks for it (:class:`LazyDesign`)."""
    refuse_unused_params(scenario, kinds)
    context = scenario.build_context(LazyDesign(scenario))
    return [scenario.run_spec(kind, context) for kind in kinds]


def reads_truth(run) -> bool:
    """True if the run's estimator read the ground truth (it declares ``reads_truth = True``,
    so each measurement carried the truth): its estimate is a reference, not an estimate."""
    return getattr(getattr(run, "measurements", None), "truth", None) is not None


def _run_and_write(scenario, kinds, staged, video, progress, every, log_format, worker,
                   keep_limited: bool = False, specs=None, log_sensors: bool = False, box=None) -> ScenarioResult:
    """:func:`run_scenario` after its checks; ``staged`` a :class:`twin.outputs.rundir.StagedDirectory`
    (None: write nothing); ``worker`` a :class:`twin.outputs.figure_worker.FigureWorker` for the
    figure, or None (drawn here); ``box`` a :class:`twin.scenarios.contained.ContainedScenario`
    whose worker runs every controller, or None (here)."""
    from twin.outputs.metrics import run_metrics
    from twin.sim.simulate import simulate

    timings = {}
    if box is not None:
        summary = box.plan()
        lazy = LazyDesign(scenario)
        if summary["design"] is not None:
            lazy.solved, lazy.seconds = summary["design"], summary["design_s"]
        plugins = summary["plugins"]
        sensors, config = scenario.sensor_config(), scenario.twin_config()
        specs = [None] * len(kinds)
    else:
        if specs is None:
            specs = plan(scenario, kinds)
        lazy = specs[0].design if specs and isinstance(specs[0].design, LazyDesign) else None
        plugins = plugins_of(scenario, kinds)
        sensors, config = specs[0].sensing.true, specs[0].plant
    runs, metrics, controllers, errors = [], {}, [], {}
    for kind, spec in zip(kinds, specs):
        cb = None if progress is None else (lambda done, total, k=kind: progress(f"run {k}", done, total))
        t0 = time.perf_counter()
        try:
            if box is None:
                spec = replace(spec, logging=Logging(every, format=log_format))
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
    from twin.outputs.fingerprint import digests

    result = ScenarioResult(scenario, runs, metrics, timings=timings, plugins=plugins,
                            design=solved[0] if solved else None,
                            designs=digests(solved[0] if solved else None, controllers), errors=errors)
    if staged is None:
        return result
    _write(result, staged, video, progress, every, log_format, worker, sensors, config, log_sensors)
    return result


class DesignDigest:
    """A controller run in a worker, as :func:`twin.outputs.fingerprint.digests` asks of it: its
    ``design_digest()`` (None: it has none)."""

    def __init__(self, digest: str | None):
        if digest is not None:
            self.design_digest = lambda: digest


def _write(result, staged, video, progress, every, log_format, worker, sensors, config,
           log_sensors: bool = False) -> None:
    """Write the run directory of ``result`` as a unit (:class:`twin.outputs.rundir.StagedDirectory`).

    The data (metrics.json, the trajectory, design.json) is the result; the figure and the
    video are pictures of it. Until the data is written, an error or an interrupt leaves the
    target as it was. Once it is written, it is kept: an error or an interrupt while the
    figure or the video is made commits the data (and the figure, if finished) with a manifest
    that says what is missing, what stopped the command and its exit status, rather than
    throwing away a simulation that may have taken an hour."""
    from twin.outputs import report

    scenario, runs, metrics, solved = result.scenario, result.runs, result.metrics, result.design
    d = scenario.data
    out = staged.path
    title = f"{scenario.name}: {scenario.description}\nseed {scenario.seed}, " + (
        "ideal sensing" if sensors is None else f"{scenario.estimator} estimator in the loop") + (
        ", analytic model (equation 1)" if scenario.plant_model == "analytic" else "") + (
        # the description was written for the file as it is: say which tables --set changed
        f"; changed by --set: {', '.join(scenario.changed_keys)}" if scenario.changed_keys else "")
    want_video = video if video is not None else d["video"]["enabled"]
    stage, drawn, writing = "data", False, None
    try:
        # the figure first: a worker draws it while the files below are written
        handed = worker is not None and worker.submit(report.figure_data(runs), title, out / "figure.png")
        doc = {"scenario": scenario.record(), "source": scenario.source, "seed": scenario.seed, "runs": metrics}
        if result.plugins:
            doc["plugins"] = result.plugins
        if result.errors:  # runs a limit stopped: in no other file
            doc["errors"] = {k: limit_text(exc) for k, exc in result.errors.items()}
        name = "trajectory." + log_format
        if every > 1 or log_format != "csv":  # at the defaults metrics.json stays as it always was
            doc["log"] = log_record(runs, every, log_format, name)
        doc["environment"] = result.environment()  # last: what precedes it is as it always was
        writing = "metrics.json"
        report.write_json(doc, out / writing)
        writing = name
        write_trajectories_csv(runs, out / name)
        if solved is not None:
            writing = "design.json"
            report.write_json(solved.to_json_dict(), out / writing)
        if log_sensors:
            # runs back up: --log-sensors writes the robot-log format (the runner is a workflow, to
            # sit above the log formats)
            from twin.logs.format import write_log

            for run in runs:
                writing = f"sensor-logs/{re.sub(r'[^A-Za-z0-9_.-]+', '_', run.controller)}"  # a plugin's "a.b:C"
                write_log(run, out / writing, scenario)
        stage, writing = "figure", "figure.png"
        failed = worker.finish() if handed else None
        if failed is not None:
            result.notes.append(f"{failed}; drew the figure in this process")
        if not handed or failed is not None:
            report.plot_runs(runs, out / "figure.png", title)
        drawn = True
        if want_video:
            stage, writing = "video", "video.mp4"
            _video(result, out, progress, every, config)
        stage, writing = "commit", rundir.MANIFEST
        if result.errors:  # complete for the runs that finished; the command ends with the limit's error
            staged.commit(2, stopped="; ".join(f"{k}: {limit_text(exc)}" for k, exc in result.errors.items()))
        else:
            staged.commit(0)
        written = ["metrics.json", name] + ["design.json"] * (solved is not None) + \
            ["sensor-logs/"] * log_sensors + ["figure.png"] + \
            ["video.mp4"] * bool(want_video) + [rundir.MANIFEST]  # in the order they were written
        result.files += [staged.shown / n for n in written]
    except BaseException as exc:
        err = exc
        if isinstance(exc, OSError):  # a full disk, say: one line, naming the file as the user will know it
            where = staged.shown / writing if writing else staged.shown
            err = TwinError(f"cannot write {where}: {exc.strerror or exc}")
        if stage == "data" or (stage == "commit" and staged.committed):
            rundir.kept(err, staged.unchanged())
        else:
            _keep_data(err, staged, worker, stage, drawn, want_video)
        if err is exc:
            raise
        raise err from exc
    if result.video is not None:
        result.video = replace(result.video, path=staged.shown / "video.mp4")


def _keep_data(exc, staged, worker, stage: str, drawn: bool, want_video: bool) -> None:
    """After ``exc`` stopped the figure, the video or the commit: commit what is complete (the
    data at least), with a manifest saying what is missing, why and the exit status, and say
    so on ``exc``; if even that fails (the disk is full for the manifest too), the target is
    left as it was."""
    if worker is not None:
        worker.close()  # a figure still being drawn into the staging is not one
    out = staged.path
    missing = []
    if stage != "commit":
        if not drawn:
            missing.append("figure.png")
        if want_video:
            missing.append("video.mp4")
    for name in missing:
        (out / name).unlink(missing_ok=True)
    # an interrupt a library turned into another exception is the interrupt (rundir.exit_status_of knows)
    how = (f"{rundir.signal_name(exc)} during the {stage}" if rundir.exit_status_of(exc) >= 128
           else f"error during the {stage}: {' '.join(str(exc).split())}")
    try:
        # an earlier complete run in the target stays there until a new one is complete: this one's data go
        # beside it then (NAME-incomplete); a full disk during the video replaced a complete run by data alone
        if missing:
            where = staged.commit_incomplete(rundir.exit_status_of(exc), missing, how)
        else:  # stopped in the commit itself: everything is there
            staged.commit(rundir.exit_status_of(exc), missing, how)
            where = staged.shown
    except BaseException:  # noqa: BLE001 -- whatever stops the commit, the original error is the one said
        if not staged.committed:
            staged.discard()
            rundir.kept(exc, staged.unchanged())
            return
        where = staged.aside or staged.shown
    names = [p.name for p in staged.files() if p.name != rundir.MANIFEST]
    earlier = (f"; {staged.shown} still holds the earlier complete run (move {where} to {staged.shown} to keep this "
               f"one instead)") if where != staged.shown else ""
    rundir.kept(exc, f"kept {', '.join(names[:-1])} and {names[-1]} in {where}"
                     + (f", without {' and '.join(missing)}" if missing else " (complete)")
                     + f"; its {rundir.MANIFEST} says so, with exit status {rundir.exit_status_of(exc)}{earlier}")


def _video(result, out: Path, progress, every: int, config) -> None:
    """Render video.mp4 of ``result``'s runs into ``out``."""
    from twin.render import render_video
    from twin.render.scene import camera_mode

    runs, v = result.runs, result.scenario.data["video"]
    rate = config.control_rate / every
    if rate < v["fps"]:
        result.notes.append(f"the video interpolates the trajectory logged at {rate:g} Hz (--log-every {every}) "
                            f"to {v['fps']} frames/s: motion between logged rows is drawn as straight lines")

    def cb(done, total):
        if done == 1:
            rundir.test_point("video")
        if progress is not None:
            progress("video", done, total)

    t0 = time.perf_counter()
    e = runs[0].experiment
    catch = _catch_end(runs)
    camera = camera_mode(v["camera"], float(runs[0].signal("alpha")[0]), _extent(runs),
                         None if e is None else e.alpha_d, catch)
    # the catch from a tilted start, the headline event (about 12 frames at real time), 4× slower
    result.video = render_video(runs, out / "video.mp4", fps=v["fps"], size=(v["width"], v["height"]), progress=cb,
                                camera=camera, slow=None if catch is None else (catch, SLOW_CATCH))
    result.timings["video_s"] = time.perf_counter() - t0
    if result.video.note:  # H.264 by ffmpeg was not available: say what wrote the video instead, and why
        result.notes.append(result.video.note)


def limit_text(exc: BaseException) -> str:
    """One line for a run a limit stopped: ``LimitExceeded: <its message>`` (as a sweep records it)."""
    return f"LimitExceeded: {' '.join(str(exc).split())}"


def log_record(runs, every: int, log_format: str, name: str) -> dict:
    """metrics.json's ``log`` object: which rows of each run the trajectory file holds."""
    period = 1.0 / runs[0].config.control_rate if runs and runs[0].config is not None else None
    simulated = {r.controller: r.control_steps for r in runs}
    written = {r.controller: len(r.t) for r in runs}
    if every == 1:
        dropped = "nothing: every control step is written"
    else:
        grid = f"t = k·{every * period:g} s" if period is not None else f"control steps k·{every}"
        dropped = (f"one control step in {every} is written and kept ({grid}: steps 0, {every}, "
                   f"{2 * every}, …), so a run's last step is in the file only if it lies on that grid; the "
                   f"metrics in 'runs' are computed from every control step; the figure (and the video) show the "
                   f"written rows")
    return {"file": name, "format": log_format, "every": every, "control_period_s": period, "log_period_s": None if period is None else every * period,
            "rows_simulated": simulated, "rows_written": written, "dropped": dropped}


def write_trajectories_csv(runs, path: Path) -> Path:
    """Every logged signal of every run, one row per logged control step, units in the header;
    gzip-compressed if ``path`` ends in ``.gz`` (reproducible: no time stamp in the header).

    Controllers may log different extra signals: the columns are their union, in the order
    first met, and a run leaves the columns it does not log empty. Written a block of rows at a
    time: no copy of a whole log is made."""
    names, units = [], []
    for run in runs:
        for n in run.signal_names():
            if n not in names:
                names.append(n)
                units.append(run.signal_units()[n])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as raw:
        gz = (gzip.GzipFile(filename=path.name[:-3], mode="wb", fileobj=raw, mtime=0, compresslevel=6)
              if path.suffix == ".gz" else None)
        fh = io.TextIOWrapper(gz if gz is not None else raw, encoding="utf-8", newline="")
        try:
            w = csv.writer(fh)
            w.writerow(["controller"] + [f"{n} [{u}]" for n, u in zip(names, units)])
            for run in runs:
                own = list(run.signal_names())
                where = [own.index(n) if n in own else None for n in names]
                # the rows as csv.writer writes them, joined here (a third faster): a float's
                # repr never needs quoting, so only the controller's name goes through csv
                head = io.StringIO()
                csv.writer(head).writerow([run.controller, ""])
                prefix = head.getvalue()[:-2]  # "name," without the line's end ("\r\n")
                every = where == list(range(len(own)))
                for block in run.column_chunks():
                    rows = block.tolist()
                    if every:
                        lines = [prefix + ",".join(map(repr, row)) for row in rows]
                    else:
                        lines = [prefix + ",".join(["" if j is None else repr(row[j]) for j in where]) for row in rows]
                    lines.append("")
                    fh.write("\r\n".join(lines))
                    rundir.test_point("trajectory")  # a no-op unless a kill test asks (see there)
        finally:
            fh.close()  # closes the gzip stream (its trailer) and the file
    return path


SLOW_CATCH = 4.0  # the video plays a catch from a tilted start this many times slower


def _catch_end(runs) -> float | None:
    """s: the end of the catch from a tilted start the figure zooms on (None: no such catch)."""
    if abs(float(runs[0].signal("theta")[0])) < ZOOM_THETA0:
        return None
    zoom = zoom_window(runs, push_windows(runs[0]))
    return None if zoom is None else float(zoom[1])


def _extent(runs) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) m of every run's axle: what a fixed video camera must see."""
    xs = np.concatenate([r.signal("x") for r in runs])
    ys = np.concatenate([r.signal("y") for r in runs])
    return float(xs.min()), float(xs.max()), float(ys.min()), float(ys.max())
