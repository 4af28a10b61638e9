"""``twin export``: the controller and the estimator a scenario runs, as a C99 library for a
robot's microcontroller (:mod:`twin.workflows.export`)."""
from __future__ import annotations

from pathlib import Path

import click

from twin.commands.common import Once, complete_scenario, robot_option, with_robot
from twin.workflows.export import CONTROLLERS, ESTIMATORS, export


@click.command("export", cls=Once)
@click.option("--controller", default="it2", show_default=True, metavar="|".join(CONTROLLERS),
              help="The controllers to export: the IT2 or type-1 fuzzy cascade, or the LQR.")
@click.option("--estimator", default=None, metavar="|".join(ESTIMATORS),
              help="The estimator to export (default: the scenario's sensors.estimator).")
@click.option("--scenario", default="paper-exp3", show_default=True, metavar="NAME|FILE",
              shell_complete=complete_scenario,
              help="The scenario whose design, targets (which loops are closed), sensors and rates are exported.")
@click.option("--precision", type=click.Choice(["float64", "float32"]), default="float64", show_default=True,
              help="float64: the twin's arithmetic, bit for bit; float32: for a microcontroller with a "
                   "single-precision FPU (a Cortex-M4F).")
@click.option("--arithmetic", type=click.Choice(["exact", "lean"]), default=None,
              help="The EKF's arithmetic. exact: the twin's, operation for operation (float64: bit for bit); lean: "
                   "the same equations with fewer operations in the coasting step and the latency watch, for a "
                   "microcontroller. [default: exact for float64, lean for float32]")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a scenario key by its dotted path (repeatable), as in 'twin run'.")
@robot_option("to export for")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True, metavar="DIR",
              help="The directory to write: the library, its host test, CMakeLists.txt, README.md, export.json.")
def export_command(controller, estimator, scenario, precision, arithmetic, overrides, robot, out):
    """Write the tested controller and estimator as portable C99 for the robot's firmware.

    The library is generated from the same design the twin runs: the balance PDC with its LMI
    gains (or the LQR's), the Mamdani position and direction controllers with their sets and
    rules, the estimator with its noise figures and gates, and the motors' driver law. Every
    number is written as an exact hex literal, so the float64 export computes what the twin
    computes, bit for bit. The interface (mtwip.h): mtwip_init(state, config) once, then
    mtwip_step(state, readings, targets, outputs) every control period: readings in (gyro,
    accelerometer, encoder counts, a validity flag each), the two motor duties out.

    \b
    Examples:
      twin export --controller it2 --estimator ekf --out build/mtwip
      twin export --controller lqr --robot balboa --scenario balboa-exp3 --precision float32 --out fw/
      twin run paper-exp3 --controller export:build/mtwip     # the C in the twin's loop
    """
    result = export(scenario, controller, estimator, precision, out, with_robot(overrides, robot),
                    arithmetic=arithmetic)
    ident = result["identity"]
    click.echo(f"wrote {len(result['files'])} files to {out}: {ident['controller']} with {ident['estimator']}, "
               f"{ident['precision']} ({ident['arithmetic']}), robot {ident['robot']}, design {ident['design_digest'][:12]}")
    click.echo(f"host test: cmake -S {out} -B {out}/build && cmake --build {out}/build && ctest --test-dir {out}/build")


__all__ = ["export_command"]
