"""A run directory: the files of a scenario's runs, written as a unit.

- ``trajectory.csv``: one row per control step and controller (``controller`` column
  first), every logged signal with its unit in the header: time, ground truth, the
  estimates the controllers acted on, commands, torques delivered, pushes. With
  ``log_every`` N > 1, one row per N control steps; with ``log_format="csv.gz"`` the same
  text gzip-compressed, as ``trajectory.csv.gz``;
- ``metrics.json``: the scenario (complete, defaults filled in), the seed, and one
  object per controller run (:func:`twin.outputs.metrics.run_metrics`, always from every control
  step); when the trajectory is decimated or compressed, a ``log`` object says so (which
  rows were written, how many of how many, the file); an ``errors`` object holds the
  controllers whose runs a limit of ``[limits]`` stopped (kind → ``LimitExceeded: <the
  one-line message>``), which are in no other file;
- ``figure.png``: θ, torque, dψ/dt, distance and α over time (the paper's Figs. 6–8),
  the controllers overlaid;
- ``video.mp4``: offscreen rendering, the controllers side by side (optional);
- ``design.json``: the LMI design the balance controllers used;
- whatever the caller adds (``twin run --log-sensors``: sensor logs, written by :mod:`twin.logs.format`);
- ``manifest.json``, written last: every file with its size and SHA-256, the command's exit
  status and whether every output is there (:mod:`twin.outputs.rundir`).

The directory is staged beside the target and put in its place when complete, so it never
mixes this run's files with an earlier run's. Nothing here depends on the wall clock: the
same runs give byte-identical ``metrics.json`` and ``trajectory.csv``.
"""
from __future__ import annotations

import csv
import gzip
import io
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from twin.errors import TwinError
from twin.outputs import report, rundir
from twin.outputs.report import ZOOM_THETA0, push_windows, zoom_window  # the catch the figure zooms on
from twin.render import render_video
from twin.render.scene import camera_mode, robot_scale


@dataclass(frozen=True)
class RunFiles:
    """What the files of a run directory say of the runs besides the runs themselves.

    ``title``: the figure's title; ``head``: metrics.json's first entries (the scenario as
    recorded, its source, the seed); ``video``: the video's settings (fps, width, height,
    camera; None: no video); ``control_rate``: Hz; ``every``, ``log_format``: how the
    trajectory is written; ``extra``: (name, write) pairs of more files the caller writes after the data,
    ``write(path)`` for each ``name`` (a path inside the directory; an error names it)."""

    title: str
    head: dict
    video: dict | None
    control_rate: float
    every: int = 1
    log_format: str = "csv"
    extra: tuple = ()


def write_run_directory(result, staged, files: RunFiles, progress=None, worker=None) -> None:
    """Write the run directory of ``result`` as a unit (:class:`twin.outputs.rundir.StagedDirectory`).

    The data (metrics.json, the trajectory, design.json) is the result; the figure and the
    video are pictures of it. Until the data is written, an error or an interrupt leaves the
    target as it was. Once it is written, it is kept: an error or an interrupt while the
    figure or the video is made commits the data (and the figure, if finished) with a manifest
    that says what is missing, what stopped the command and its exit status, rather than
    throwing away a simulation that may have taken an hour."""
    runs, metrics, solved = result.runs, result.metrics, result.design
    out, every, log_format, title = staged.path, files.every, files.log_format, files.title
    want_video = files.video is not None
    extra = []
    stage, drawn, writing = "data", False, None
    try:
        # the figure first: a worker draws it while the files below are written
        handed = worker is not None and worker.submit(report.figure_data(runs), title, out / "figure.png")
        doc = {**files.head, "runs": metrics}
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
        if files.extra:  # the caller's files (twin run --log-sensors: the sensor logs)
            for writing, write in files.extra:
                write(out / writing)
                top = writing.split("/")[0] + "/" * ("/" in writing)
                if top not in extra:
                    extra.append(top)
        stage, writing = "figure", "figure.png"
        failed = worker.finish() if handed else None
        if failed is not None:
            result.notes.append(f"{failed}; drew the figure in this process")
        if not handed or failed is not None:
            report.plot_runs(runs, out / "figure.png", title)
        drawn = True
        if want_video:
            stage, writing = "video", "video.mp4"
            _video(result, out, progress, every, files.control_rate, files.video)
        stage, writing = "commit", rundir.MANIFEST
        if result.errors:  # complete for the runs that finished; the command ends with the limit's error
            staged.commit(2, stopped="; ".join(f"{k}: {limit_text(exc)}" for k, exc in result.errors.items()))
        else:
            staged.commit(0)
        written = ["metrics.json", name] + ["design.json"] * (solved is not None) + \
            extra + ["figure.png"] + \
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


def _video(result, out: Path, progress, every: int, control_rate: float, v: dict) -> None:
    """Render video.mp4 of ``result``'s runs into ``out`` with the settings ``v`` (fps, width,
    height, camera)."""
    runs = result.runs
    rate = control_rate / every
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
    catch = catch_end(runs)
    # the robot's size (its nominal figures: a mismatched true plant is the same robot, seen the same)
    scale = robot_scale(runs[0].model_params, runs[0].config.body)
    camera = camera_mode(v["camera"], float(runs[0].signal("alpha")[0]), _extent(runs),
                         None if e is None else e.alpha_d, catch, scale)
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


def catch_end(runs) -> float | None:
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
