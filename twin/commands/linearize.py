"""``twin linearize``: a robot's linearised model (A, B, C, D with names and units) as JSON, the
model a controller or a firmware is designed on (:mod:`twin.plant.linearize`)."""
from __future__ import annotations

from pathlib import Path

import click

from twin.commands.common import Once
from twin.errors import TwinError
from twin.workflows.linearize import MAX_DT, model_json
from twin.robots import load_robot


@click.command("linearize", cls=Once)
@click.option("--robot", default="paper", show_default=True, metavar="NAME|FILE",
              help="The robot: a built-in's name ('twin robots') or a robot file (robot.toml).")
@click.option("--at", "at", default=None, metavar="theta=RAD,speed=M_PER_S,yaw_rate=RAD_PER_S",
              help="The operating point, a steady motion: speed (m/s) and yaw rate (rad/s), the tilt following "
                   "(the body leans into the rolling resistance); or the tilt (rad), the speed following. "
                   "Default: upright at rest.")
@click.option("--input", "input_kind", type=click.Choice(["torque", "voltage"]), default="torque", show_default=True,
              help="The inputs: wheel torques [ul, ur] in N·m, or motor voltages [vl, vr] in V (the robot's DC motors "
                   "folded in: the back-EMF's damping in A, k_t/R in B).")
@click.option("--dt", type=float, default=None, metavar="SECONDS",
              help=f"Sampling period in s, in (0, {MAX_DT:g}]: the discrete model by zero-order hold (the "
                   "controller's period). Default: continuous time.")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="FILE.json",
              help="Write the JSON there instead of to stdout.")
def linearize(robot, at, input_kind, dt, out):
    """Print the robot's model linearised at a steady motion, as JSON.

    The twin's equations of motion (paper equation (1)) linearised about the operating point:
    dx/dt = A x + B u, y = C x + D u with C the identity and D zero, x = [theta, theta_dot, psi,
    psi_dot, alpha, alpha_dot] (rad, rad/s) and u the wheel torques (N·m) or motor voltages (V),
    all deviations from the operating point. The JSON holds the names, units, the operating point
    (and the torques, voltages and currents that hold it), A, B, C, D and the eigenvalues of A.
    In Python: twin.plant.linearize.linearize gives a python-control StateSpace.

    \b
    Examples:
      twin linearize
      twin linearize --robot balboa --input voltage --dt 0.01
      twin linearize --robot my-robot.toml --at speed=0.5,yaw_rate=1 --out model.json
    """
    if dt is not None and not 0.0 < dt <= MAX_DT:
        raise TwinError(f"--dt must be a sampling period in (0, {MAX_DT:g}] s, got {dt:g}")
    text = model_json(load_robot(robot), at=at, input=input_kind, dt=dt)
    if out is None:
        click.echo(text, nl=False)
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    click.echo(f"wrote {out}")


__all__ = ["linearize"]
