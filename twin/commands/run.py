"""``twin run``: a scenario's runs into a run directory (:mod:`twin.workflows.run`), and the
table of their metrics."""
from __future__ import annotations

import re
from pathlib import Path

import click

from twin.commands.common import (Once, Progress, complete_kinds, complete_scenario, contained, echo_plugins, fmt,
                                  limit_options, limit_overrides, no_cache_option, robot_option, with_robot)
from twin.errors import TwinError
from twin.outputs import figure_worker
from twin.outputs.report import estimator_line
from twin.registry import label
from twin.workflows.run import RunJob, title


@click.command(cls=Once)
@click.argument("scenario", metavar="SCENARIO|FILE", shell_complete=complete_scenario)
@click.option("--controller", default=None, metavar="KINDS", shell_complete=complete_kinds,
              help="Controllers to run on identical conditions, comma-separated: it2, t1, lqr, both (= it2,t1) or "
                   "package.module:attribute (runs that module's code). Default: the scenario's controller.kinds.")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Seed of the sensor noise and faults (default: the scenario's 'seed').")
@click.option("--duration", type=float, default=None, help="Simulated time in s (default: the scenario's).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a scenario key by its dotted path, validated like the file "
                   "(repeatable), e.g. --set plant.scale.m_b=1.2.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output directory (default: runs/<scenario name>).")
@click.option("--video/--no-video", default=None, help="Render video.mp4 (default: the scenario's video.enabled).")
@click.option("--sample", type=click.IntRange(min=0), default=None, metavar="K",
              help="Replay sample K of 'twin sweep' (the 'sample' column of sweep.csv); --seed is then the "
                   "sweep's root seed, and --set/--duration must be the sweep's.")
@click.option("--log-every", "log_every", default="1", show_default=True, metavar="N",
              help="Write (and keep in memory) every N-th control step of the trajectory only; the metrics are "
                   "still computed from every step. metrics.json's 'log' says what was dropped.")
@click.option("--log-format", "log_format", type=click.Choice(["csv", "csv.gz"]), default="csv", show_default=True,
              help="trajectory.csv, or trajectory.csv.gz: the same text gzip-compressed (pandas.read_csv reads it).")
@click.option("--log-sensors", "log_sensors", is_flag=True,
              help="Also write each controller's run as a sensor log (sensor-logs/KIND/: log.toml, imu.csv, "
                   "encoders.csv, commands.csv, truth.csv), the format a robot's logs take for 'twin replay'.")
@click.option("--plant", "plant_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              metavar="CALIBRATION.toml",
              help="Run the robot 'twin calibrate' fitted: the file's [plant] and [sensors] replace the scenario's "
                   "true plant scale and IMU latency (before any --set).")
@robot_option("to run")
@limit_options("")
@no_cache_option
@contained
def run(scenario, controller, seed, duration, overrides, out, video, sample, log_every, log_format, log_sensors,
        plant_file, robot, step_limit, run_limit, memory_limit, no_cache):
    """Run a scenario on the PyBullet twin: trajectory, metrics, figure and video.

    SCENARIO is a built-in name (see 'twin scenarios') or a scenario .toml file. Writes
    trajectory.csv (or trajectory.csv.gz), metrics.json, figure.png, design.json,
    video.mp4 and manifest.json (every file's size and SHA-256) into --out, as a whole:
    --out is the earlier run until the new one is complete, and an interrupt (exit
    status 130 or 143) keeps the data if only the figure or the video was missing. The
    same scenario and seed give identical metrics.json and trajectory.csv. A controller's
    run stopped by a limit ([limits], --step-limit, --run-limit, --memory-limit) is one
    line naming it and the limit, exit status 2; the other controllers' results are
    written, and metrics.json's 'errors' names the run stopped. A plugin that breaks its
    contract (or ends its process) is one line, exit status 2, and nothing is written.
    --out must be a new or empty directory or an earlier run's: one another command
    wrote (a sweep, a replay) is refused, and so is one another command is writing.

    {CONTAINED}

    \b
    Examples:
      twin run paper-exp3
      twin run paper-exp1 --controller it2 --seed 7 --no-video
      twin run paper-exp3 --controller it2,t1,lqr
      twin run paper-exp3 --controller my_plugins:StateFeedback,it2   # your own, from ./my_plugins.py
      twin run push-recovery --set pushes='[{force=[20,0,0], start=3, duration=0.1}]'
      twin run my-robot.toml --set plant.scale.m_b=1.2 --set sensors.sensing=ideal --out runs/heavy
      twin run paper-exp3 --sample 17 --seed 0 --no-video   # replay a sweep's sample 17
      twin run paper-exp2 --duration 3600 --log-every 20 --log-format csv.gz --no-video   # an hour at 10 Hz
      twin run paper-exp3 --plant runs/calibration/calibration.toml   # the robot 'twin calibrate' fitted
      twin run paper-exp1 --robot my-robot.toml   # your robot (see 'twin robots')
    """
    # first: the figure's worker imports matplotlib while the scenario loads and the runs simulate
    # (started here, or as twin.cli loaded when it is the process's command, not when the
    # runs start: it is ready 0.1-0.2 s sooner); ended by the run
    figure = figure_worker.take_early() or figure_worker.start()
    try:
        every = log_every_of(log_every)
        with RunJob.prepare(scenario, controller, seed, duration, with_robot(limit_overrides(
                overrides, step_limit, run_limit, memory_limit), robot), out, sample, plant_file) as job:
            if job.picked is not None:
                p = job.picked
                click.echo(f"sample {p.index} of a sweep (root seed {job.root_seed}): level λ = {p.level:g}, "
                           f"draw {p.draw}, seed {p.seed}")
            click.echo(title(job.scenario))
            if job.earlier:
                click.echo(f"  note: {job.out} holds an earlier run; this one replaces it when it is complete "
                           f"(--out DIR writes elsewhere)")
            echo_plugins(job.plugins)
            with Progress() as bar:
                result = job.execute(video, bar.update, every, log_format, log_sensors, figure)
            figure = None  # taken up (and ended) by the run
    finally:
        if figure is not None:  # not taken up: the command failed before its runs
            figure.cancel()
    print_result(result, job.kinds, job.out, every)


def print_result(result, kinds, out, every: int) -> None:
    """The metrics of each controller's run in a table, the estimator's line, the time taken and
    the files written; a run a limit stopped is the command's error, said last."""
    limited, kinds = result.errors, tuple(k for k in kinds if k in result.metrics)  # runs a limit stopped: said last
    keys = ("status", "settling_time_s", "theta_rms_rad", "oscillation_peak_to_peak_rad", "final_position_error_m",
            "final_heading_error_rad", "iae_theta", "control_effort", "max_abs_torque_nm", "estimator_theta_rmse_rad",
            "rejected_measurements")
    click.echo(f"  {'metric':32}" + "".join(f"{label(k)[:13]:>14}" for k in kinds))
    for k in keys:
        vals = [result.metrics[c][k] for c in kinds]
        click.echo(f"  {k:32}" + "".join(f"{fmt(v):>14}" for v in vals))
    for c in kinds:
        if result.metrics[c]["status"] != "ok":  # fell, diverged, or degraded (what the estimator lost)
            click.echo(f"  {label(c)}: {result.metrics[c]['status']}: {result.metrics[c]['end_reason']}")
    for c in kinds:  # the estimator's consistency, rejections and events (metrics.json's "estimator")
        if result.metrics[c].get("estimator_reads_truth"):
            click.echo(f"  {label(c)}: estimator {result.scenario.estimator} reads the ground truth "
                       f"(reads_truth = True): a reference, not an estimator under test")
        line = estimator_line(result.metrics[c], label(c))
        if line:
            click.echo(f"  {line}")
    t = result.timings
    sim = sum(float(r.full_signal("t")[-1]) for r in result.runs)  # the last step simulated, logged or not
    wall = sum(v for k, v in t.items() if k.startswith("run_"))
    each = f"{sim / len(result.runs):g} s for each of {len(result.runs)} runs" if len(result.runs) > 1 else f"{sim:g} s"
    click.echo(f"  simulated {each} in {wall:.2f} s (real-time factor {sim / max(wall, 1e-9):.0f})"
               + (f"; video {result.video.frames} frames in {t['video_s']:.1f} s ({result.video.codec}, "
                  f"{result.video.renderer})" if result.video is not None else ""))
    if every > 1:
        n = sum(len(r.t) for r in result.runs)
        click.echo(f"  trajectory: one control step in {every} written ({n} of "
                   f"{sum(r.control_steps for r in result.runs)} rows); the metrics are from every step")
    for note in result.notes:
        click.echo(f"  note: {note}")
    click.echo(f"wrote {out}/: " + ", ".join(Path(f).name for f in result.files))
    if limited:  # a plugin error against that controller alone: its one line, exit status 2, the others kept
        first, exc = next(iter(limited.items()))
        n = len(limited) - 1
        more = f" (and {n} more run{'s' * (n > 1)} stopped by a limit)" if n else ""
        raise TwinError(f"{first}: {' '.join(str(exc).split())}{more}; the results of {', '.join(kinds)} are in "
                        f"{out} (metrics.json's 'errors' names the runs stopped)")



def log_every_of(text: str) -> int:
    """--log-every as an int ≥ 1, or one line saying what is allowed."""
    value = int(text.strip()) if re.fullmatch(r"\s*\d+\s*", text) else None
    if value is None or value < 1:
        raise TwinError(f"--log-every must be a whole number ≥ 1 (write every N-th control step; 1: every step), "
                        f"got {text!r}")
    return value
