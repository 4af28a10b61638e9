"""``twin replay``: estimators replayed on sensor logs (:mod:`twin.workflows.replay`), and a
table per log of their errors, consistency, rejections and cost."""
from __future__ import annotations

from pathlib import Path

import click

from twin.commands.common import Once, fmt
from twin.logs.replay import summary_lines
from twin.outputs import rundir
from twin.workflows.replay import estimator_kinds, replay


@click.command("replay", cls=Once)
@click.argument("logs", nargs=-1, required=True, type=click.Path(path_type=Path), metavar="LOG...")
@click.option("--estimator", "estimators", default="ekf", show_default=True, metavar="KINDS",
              help="Estimators to replay, comma-separated: ekf, complementary, kalman2 or package.module:attribute.")
@click.option("--noise", type=click.Choice(["log", "given", "measured", "datasheet"]), default="log",
              show_default=True,
              help="The IMU noise figures the estimators take: log (the log's, or the noise measured from its "
                   "readings where it gives none or the readings contradict them), given (the log's, whatever the "
                   "readings say), measured (from the readings), datasheet (the IMU part's). replay.json's noise "
                   "says which was used and why.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("runs/replay"),
              show_default=True, help="Output directory: replay.json, estimates.csv, manifest.json.")
def replay_command(logs, estimators, noise, out):
    """Replay estimators on sensor logs (a robot's, or the twin's from 'twin run --log-sensors').

    No physics: each log's readings and commands go to each estimator one control instant at a
    time. Reports the θ, ψ, α errors where the log has truth, NIS per degree of freedom and the
    innovations' whiteness where the estimator reports them, the EKF's NEES where the log has
    the state truth (the twin's logs do; over several logs also the Monte Carlo χ² tests),
    rejected readings and the cost per step; per log, its format version (version 1: what it
    leaves unsaid and what was assumed), what the estimators cannot use of it, how its truth
    meets the control instants, and sign checks of the sensors against each other (gravity on
    z, the gyro against the accelerometer's tilt and the encoders' heading, the wheels against
    the commands; twin.logs.checks). Writes replay.json, estimates.csv and figure.png
    (the first log: θ, ψ, α against the truth, NIS with its χ² bounds).

    The IMU's noise is measured from each log's readings (differences of order 3, robust to
    the robot's motion; twin.logs.noise) and, by default, used where the log gives no noise
    figures or its readings contradict them (beyond a factor of 2); --noise chooses.

    An estimator plugin (package.module:attribute) replays in a worker process this
    command kills: its sys.exit, os._exit or crash, its threads and its child processes end
    with the replay, which ends with one line naming it (see docs/howto/limits.md).

    \b
    Examples:
      twin run paper-exp3 --log-sensors --no-video --out runs/exp3
      twin replay runs/exp3/sensor-logs/it2 --estimator ekf,complementary,kalman2
      twin replay robot-log --estimator ekf,kalman2 --noise measured
    """
    doc, figures = replay(logs, estimator_kinds(estimators), noise, out)
    for path, entry in doc["logs"].items():
        click.echo(f"{path}: {entry['instants']} instants, {entry['duration_s']:g} s at {entry['control_rate_hz']:g} Hz"
                   + ("" if entry["has_truth"] else " (no truth: errors not computed)"))
        for line in summary_lines(entry):  # format, notes, truth, sign checks, other streams: one line each
            click.echo(f"  {line}")
        w = max([16] + [len(k) + 2 for k in entry["estimators"]])  # a plugin's import path may be long
        click.echo(f"  {'estimator':{w}}{'θ RMSE rad':>12}{'θ max rad':>12}{'ψ RMSE rad':>12}{'α RMSE rad':>12}"
                   f"{'NIS/dof':>9}{'NEES':>8}{'ρ out':>8}{'rejected':>10}{'µs/step':>9}")
        for kind, e in entry["estimators"].items():
            err, c = e["errors"] or {}, e["consistency"]
            out_frac = c.get("whiteness_outside_fraction")  # lags outside the 95 % band (about 5 % if white)
            click.echo(f"  {kind:{w}}{fmt(err.get('theta_rmse_rad')):>12}{fmt(err.get('theta_max_abs_rad')):>12}"
                       f"{fmt(err.get('psi_rmse_rad')):>12}{fmt(err.get('alpha_rmse_rad')):>12}"
                       f"{fmt(c.get('nis_per_dof')):>9}{fmt(c.get('nees_mean')):>8}"
                       f"{'-' if out_frac is None else f'{out_frac:.0%}':>8}{e['rejected_total']:>10}"
                       f"{e['step_us']:>9.1f}")
    for kind, mc in doc.get("estimators", {}).items():
        if mc.get("monte_carlo"):
            m = mc["monte_carlo"]
            click.echo(f"{kind} over {m['runs']} logs from {m['start_s']:g} s: mean NEES {m['nees_mean']:.3g} "
                       f"(95 % bounds {m['nees_bounds'][0]:.3g} to {m['nees_bounds'][1]:.3g}, dim {m['dim']}), "
                       f"{m['nees_inside']:.0%} of instants inside; NIS per dof {m['nis_per_dof']:.3g}, "
                       f"{m['nis_inside']:.0%} of update instants inside")
    click.echo(f"wrote {out}/: replay.json, estimates.csv, {', '.join(figures)}, {rundir.MANIFEST}")
