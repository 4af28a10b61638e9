"""``twin calibrate``: a robot fitted to its sensor logs (:mod:`twin.workflows.calibrate`),
and the table of the fitted parameters with their intervals, the validation and warnings."""
from __future__ import annotations

from pathlib import Path

import click

from twin.calibrate.parameters import NOT_FROM_A_LOG, PARAMETERS
from twin.commands.common import Once, sig
from twin.outputs import rundir
from twin.workflows.calibrate import calibrate


@click.command("calibrate", cls=Once)
@click.argument("logs", nargs=-1, type=click.Path(path_type=Path), metavar="LOG")
@click.option("--parameters", default=None, metavar="NAMES",
              help="Parameters to fit, comma-separated (default: m_b, l, n_yb, d_b, d_w, n_zb if the log turns, "
                   "the IMU's biases, scale factors and latency). 'twin calibrate --list' names them all.")
@click.option("--validate", "held_out", multiple=True, type=click.Path(path_type=Path), metavar="LOG",
              help="A held-out log of the same robot on which the nominal and the calibrated twin predict the "
                   "readings (repeatable).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the bootstrap over windows.")
@click.option("--model", "model_kind", type=click.Choice(["auto", "physical", "twin"]), default="auto",
              show_default=True,
              help="physical: the robot's continuous equations (its physical parameters; several logs); twin: the "
                   "PyBullet twin's stepping (one log); auto: twin for one log the twin wrote, else physical.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("runs/calibration"),
              show_default=True, help="Output directory: report.json, calibration.toml, figure.png, manifest.json.")
@click.option("--list", "list_", is_flag=True, help="List the parameters that can be fitted, with their units.")
def calibrate_command(logs, parameters, held_out, seed, model_kind, out, list_):
    """Calibrate the robot from its sensor logs: its physical parameters, and the twin that runs it.

    LOG is a sensor log (a robot's, or the twin's from 'twin run --log-sensors'); several LOGs of
    one robot are fitted together (shared physical parameters, each log's own IMU constants). Each
    0.1 s window is simulated from its own fitted start state with the log's drive, by the
    robot's continuous equations (RK4 at 1 kHz or more, with its motors), and the parameters that
    make the simulated IMU and encoder readings match the logs' are found by least squares, with
    95 % intervals, correlations and a warning for each parameter the logs do not excite. The
    twin's parameters that reproduce that robot (its stepping differs) go to calibration.toml.
    --validate compares the nominal and the calibrated robot on held-out logs and says whether
    their parameters are the calibrated robot's. Writes report.json, robot.toml (the fitted robot,
    complete: the logs' own robot with every identified figure replaced, each with its interval;
    for 'twin run SCENARIO --robot robot.toml'), calibration.toml (the paper's robot scaled, for
    'twin run SCENARIO --plant calibration.toml') and figure.png into --out.

    \b
    Examples:
      twin run paper-exp3 --log-sensors --no-video --out runs/exp3
      twin calibrate runs/exp3/sensor-logs/it2 --out runs/calibration
      twin calibrate robot/log1 robot/log2 --validate robot/log3 --out runs/calibration
      twin calibrate runs/exp3/sensor-logs/it2 --parameters m_b,l,n_yb,d_b,d_w --validate runs/exp3b/sensor-logs/it2
      twin run paper-exp3 --robot runs/calibration/robot.toml
    """
    if list_:
        for name, p in PARAMETERS.items():
            if name in NOT_FROM_A_LOG:
                continue
            click.echo(f"  {name:15} {p.unit:10} {p.group:6} {p.doc}")
        for name, why in NOT_FROM_A_LOG.items():
            click.echo(f"  ({name}: {why})")
        return
    c = calibrate(logs, parameters, held_out, seed, model_kind, out, click.echo)
    params, val, twin, doc = c.params, c.validation, c.twin, c.doc
    click.echo(f"  {'parameter':15}{'value':>13}{'95 % interval':>28}  unit")
    for n, e in params.items():
        lo, hi = e["ci95"]
        mark = "" if e["identifiable"] else "   not identified"
        click.echo(f"  {n:15}{sig(e['value']):>13}   [{sig(lo):>11}, {sig(hi):>11}]  {e['unit']}{mark}")
    for v in val or ():
        click.echo(f"  validation on {v['log']}: RMS prediction error over {v['horizon_s']:g} s, nominal "
                   f"{v['nominal']['rms_sigma']:.3g} σ, calibrated {v['calibrated']['rms_sigma']:.3g} σ (1 σ: the "
                   f"readings' noise); the model's own error {v['ratio']:.2f}× smaller calibrated ({v['windows']} "
                   f"windows)")
        if "same_robot" in v:
            sr = v["same_robot"]
            zs = ", ".join(f"{n} z {e['z']:+.1f}" for n, e in sr["parameters"].items())
            click.echo(f"  {v['log']} calibrated alone: {'the same robot' if sr['consistent'] else 'NOT the same robot'}"
                       f" by its parameters ({zs}; |z| < {sr['z_limit']:g})")
    limit = c.twin_why
    if limit and c.robot is not None:
        click.echo(f"  note: calibration.toml has no [plant] (the paper's robot scaled cannot be this one: {limit}); "
                   f"robot.toml is the robot: twin run SCENARIO --robot {out}/robot.toml")
    elif limit:
        click.echo(f"  warning: the twin cannot run this robot: {limit}; calibration.toml records it, without "
                   f"[plant]")
    if twin is not None and twin["values"] is None:
        click.echo(f"  warning: no twin reproduces this robot: {twin['why']}")
    elif twin is not None:
        tw = twin["values"]
        click.echo(f"  in the twin ({twin['control_rate_hz']:g} Hz control, {twin['physics_rate_hz']:g} Hz physics): "
                   + ", ".join(f"{n} {sig(tw[n])}" for n in ("m_b", "l", "n_yb", "n_zb", "n_wa"))
                   + f" (trajectory misfit {twin['rms_misfit']['mapped']:.3g}, the robot's own parameters "
                     f"{twin['rms_misfit']['unmapped']:.3g})")
    for line in c.warnings:
        click.echo(f"  warning: {line}")
    click.echo(f"  {doc['method']['windows']} windows fitted ({len(c.cal.dropped)} left out), residual σ "
               f"{doc['method']['residual_sigma']:.3g}, {c.cal.wall_s:.1f} s")
    robot = "robot.toml, " if c.robot is not None else ""
    click.echo(f"wrote {out}/: report.json, {robot}calibration.toml, figure.png, {rundir.MANIFEST}")
