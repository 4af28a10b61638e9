"""``twin scenarios``, ``twin robots`` and ``twin kinds``: the built-in scenarios and robots (or
one's TOML to copy), and the controller, estimator and plant kinds."""
from __future__ import annotations

import re
from importlib import resources

import click

from twin.commands.common import Once
from twin.errors import TwinError
from twin.registry import CONTROLLERS, ESTIMATORS, PLANTS
from twin.robots import builtin_robots, load_robot, robot_text
from twin.scenarios import builtin_scenarios
from twin.scenarios.scenario import BUILTIN_PACKAGE, builtin_names


def copy_text(text: str) -> str:
    """A built-in scenario's TOML as ``twin scenarios NAME`` prints it to copy: its ``name`` line
    commented out, so that a copy takes its file's name (``my-exp2.toml`` runs as ``my-exp2``, into
    ``runs/my-exp2``) instead of replacing the built-in's results in ``runs/NAME``."""
    return re.sub(r'^name\s*=\s*(.*)$', lambda m: f"# name = {m.group(1)}   (a copy takes its file's name: "
                  f"my-copy.toml runs as my-copy, into runs/my-copy)", text, count=1, flags=re.M)


@click.command("scenarios", cls=Once)
@click.argument("name", required=False)
def scenarios_command(name):
    """List the built-in scenarios, a line each; with NAME, print that one's TOML to copy and edit.

    \b
    Examples:
      twin scenarios
      twin scenarios paper-exp2 > my-exp2.toml
      twin run slope-payload --controller both
    """
    if name is not None:
        if name not in builtin_names():
            raise TwinError(f"no built-in scenario {name!r}; built-ins: {', '.join(builtin_names())}")
        text = resources.files(BUILTIN_PACKAGE).joinpath(f"{name}.toml").read_text(encoding="utf-8")
        click.echo(copy_text(text), nl=False)
        return
    items = builtin_scenarios()
    width = max(map(len, items))
    for name, description in items.items():
        click.echo(f"{name:{width}}  {description}")


@click.command("kinds", cls=Once)
def kinds_command():
    """List the built-in controller, estimator and plant kinds (any 'package.module:attribute' works too).

    \b
    Examples:
      twin kinds
      twin run paper-exp2 --controller it2,lqr
    """
    for title, table in (("controllers (--controller, controller.kinds)", CONTROLLERS),
                         ("estimators (sensors.estimator)", ESTIMATORS), ("plants (plant.model)", PLANTS)):
        click.echo(title)
        width = max(map(len, table))
        for name, kind in table.items():
            click.echo(f"  {name:{width}}  {kind.description}")
    click.echo("your own: package.module:attribute, a class or factory (see docs/howto/plugins.md)")


@click.command("robots", cls=Once)
@click.argument("name", required=False)
def robots_command(name):
    """List the built-in robots, a line each; with NAME, print that one's robot file to copy and edit.

    A robot file (robot.toml) describes a robot in SI units: body, wheels, friction, drive, IMU,
    encoders, control rate and the tilt at which it is lost; every key, its unit and range are
    on the robot file reference page (docs/reference/robot-file.md).

    \b
    Examples:
      twin robots
      twin robots paper > my-robot.toml
    """
    if name is not None:
        click.echo(robot_text(name), nl=False)
        return
    items = builtin_robots()
    width = max(map(len, items))
    for n, description in items.items():
        r = load_robot(n)
        p = r.params()
        click.echo(f"{n:{width}}  {description} [body {p.m_b:g} kg, wheels r = {p.r * 100:g} cm, control "
                   f"{r.control_rate:g} Hz]")
