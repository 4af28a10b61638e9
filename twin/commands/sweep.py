"""``twin sweep``: a Monte Carlo sweep (:mod:`twin.workflows.sweep`), with a progress bar,
and the success table of each level and controller."""
from __future__ import annotations

import re
from pathlib import Path

import click

from twin.commands.common import (Once, SweepBar, complete_kinds, complete_scenario, contained, counted,
                                  echo_plugins, limit_options, limit_overrides, robot_option, with_robot)
from twin.errors import TwinError
from twin.outputs import rundir
from twin.registry import label
from twin.workflows.run import title
from twin.workflows.sweep import SweepJob, failure


@click.command(cls=Once)
@click.argument("scenario", metavar="SCENARIO|FILE", shell_complete=complete_scenario)
@click.option("--samples", "draws", type=click.IntRange(1, 100_000), required=True, metavar="N",
              help="Samples per uncertainty level (sweep.levels); IT2 and type-1 run on each.")
@click.option("--workers", type=click.IntRange(1, 1024), default=None, metavar="K",
              help="Worker processes (local) or Ray CPUs (default: every core here, or the Ray cluster's).")
@click.option("--backend", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="local: spawned worker processes; ray: Ray tasks (pip install 'mtwip-twin[ray]').")
@click.option("--ray-address", default=None, metavar="ADDRESS",
              help="Ray cluster to join, as for ray.init(address=...) (default: a local Ray instance).")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Root seed of the sweep (default: the scenario's 'seed').")
@click.option("--duration", type=float, default=None, help="Simulated time per run in s (default: the scenario's).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a scenario key (repeatable), e.g. --set sweep.levels=[0,0.2,0.4].")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Sweep directory (default: runs/sweep-<scenario name>); rerun to resume.")
@click.option("--controller", default=None, metavar="KINDS", shell_complete=complete_kinds,
              help="Controllers compared on identical samples, comma-separated: it2, t1, lqr, both (= it2,t1) or "
                   "package.module:attribute. Default: the scenario's controller.kinds.")
@click.option("--reference", default=None, metavar="KIND",
              help="The controller each other one is paired with in the paired statistics (default: the last listed).")
@click.option("--log-sensors", "log_sensors", default=None, metavar="K[,K...]",
              help="Also write each controller's run of samples K (the 'sample' column of sweep.csv) as sensor "
                   "logs, in sensor-logs/sample-K/KIND/: the logs 'twin run SCENARIO --sample K --log-sensors' "
                   "writes.")
@limit_options(" for each controller's run of a sample",
                "the scenario's, else 60 s + 10 × the simulated time in s (210 s for 15 s)")
@robot_option("to sweep around (the uncertainty is drawn around its figures)")
@contained
def sweep(scenario, draws, workers, backend, ray_address, seed, duration, overrides, out, controller, reference,
          log_sensors, step_limit, run_limit, memory_limit, robot):
    """Monte Carlo sweep: controllers compared on sampled plants, noise, tilts and pushes.

    The scenario's [sweep] table says what is sampled (see docs/howto/sweeps.md). Each sample's
    seed and sampled values are in sweep.csv, and 'twin run SCENARIO --sample K'
    replays sample K exactly. Finished samples are kept as they finish: rerun the
    same command after an interruption and only the rest runs. Writes sweep.csv,
    summary.md, summary.json, success.png, distributions.png and paired.png (and, with
    --log-sensors, the chosen samples' sensor logs for 'twin replay'). A run
    stopped by a limit (--step-limit, --run-limit, --memory-limit; by default each run
    may take 60 s + 10 s per simulated s) is an error of that controller on that sample;
    a plugin that breaks its contract or ends its process on some samples is recorded there,
    and the sweep ends with exit status 2.

    {CONTAINED}

    \b
    Examples:
      twin sweep paper-exp3 --samples 50
      twin sweep paper-exp3 --samples 50 --controller it2,t1,lqr --reference lqr
      twin sweep push-recovery --samples 20 --workers 2 --set sweep.push_count=2
      twin sweep paper-exp2 --samples 100 --backend ray --ray-address auto
      twin sweep paper-exp3 --samples 50 --log-sensors 0,17   # and samples 0 and 17 as sensor logs
    """
    if ray_address is not None and backend != "ray":
        raise TwinError("--ray-address needs --backend ray")
    job = SweepJob.prepare(scenario, draws, seed, duration, with_robot(limit_overrides(overrides, step_limit, run_limit,
                           memory_limit), robot), out, controller, reference, sample_numbers(log_sensors))
    out, levels = job.out, job.levels
    click.echo(title(job.scenario))
    echo_plugins(job.summary["plugins"])
    click.echo(f"  {counted(draws, 'sample')} × {counted(len(levels), 'level')} λ = {', '.join(f'{v:g}' for v in levels)}, "
               f"root seed {job.scenario.seed}, backend {backend}" + (f", {workers} worker{'s' * (workers > 1)}" if workers else ""))
    bar = SweepBar()
    try:
        result = job.execute(workers, backend, ray_address, bar.update)
    except KeyboardInterrupt as exc:
        bar.close()
        if bar.total and bar.done >= bar.total:  # stopped while the report was written
            rundir.kept(exc, f"all {bar.total} samples are stored in {out}, the report is not finished; rerun the "
                             "same command to write it")
        else:
            rundir.kept(exc, f"{bar.done} of {bar.total} samples are stored in {out}; rerun the same command to "
                             "finish the rest")
        raise
    bar.close()
    if result.environment_changes:
        click.echo(f"  note: resumed in another environment than the first samples' ({'; '.join(result.environment_changes)}); "
                   "the samples run now may differ from the others in the last digits (sweep.json: resumed_in)")
    sims = len(job.kinds) * result.ran
    click.echo(f"  ran {counted(result.ran, 'sample')} ({counted(sims, 'run')}) in {result.wall_s:.1f} s"
               + (f", {60 * result.ran / result.wall_s:.1f} samples/min" if result.ran and result.wall_s > 0 else "")
               + (f"; {result.resumed} {'was' if result.resumed == 1 else 'were'} already finished" if result.resumed else ""))
    click.echo(success_table(result.summary))
    if result.logs:
        logged = sorted({k for k, _ in result.logs})
        click.echo(f"  sensor logs of sample{'s' * (len(logged) > 1)} {', '.join(map(str, logged))}: "
                   f"{len(result.logs)} in {out}/sensor-logs/sample-K/KIND/ (for twin replay)")
    for note in result.log_notes:
        click.echo(f"  note: {note}")
    click.echo(f"wrote {out}/: " + ", ".join(Path(f).name for f in result.files))
    error = failure(result, out)
    if error:  # every run an error, or a plugin broke its contract past the preflight: not a result, the rest kept
        raise TwinError(error)


def sample_numbers(text: str | None) -> tuple[int, ...]:
    """--log-sensors K[,K...] as sample numbers (whether each is one of the sweep's is checked
    by twin.sweep.runner.check_log_samples, which knows how many there are)."""
    if text is None:
        return ()
    parts = [p.strip() for p in text.split(",")]
    if not all(re.fullmatch(r"\d+", p) for p in parts):
        raise TwinError(f"--log-sensors must be sample numbers, comma-separated (the 'sample' column of sweep.csv, "
                        f"e.g. 0,17), got {text!r}")
    return tuple(int(p) for p in parts)


def success_table(summary) -> str:
    width = max([10] + [len(label(s["controller"])) for s in summary])
    lines = [f"  {'level':>7} {'controller':>{width}} {'n':>5} {'success':>8}  {'95 % CI':>15} {'falls':>6} {'errors':>6}"]
    for s in summary:
        lo, hi = s["success_ci"]
        level = "all" if s["level"] is None else f"{s['level']:g}"
        lines.append(f"  {level:>7} {label(s['controller']):>{width}} {s['n']:5d} {s['success_rate']:8.1%}  "
                     f"[{lo:5.1%}, {hi:5.1%}] {s['falls']:6d} {s['errors']:6d}")
    return "\n".join(lines)
