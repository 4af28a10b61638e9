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
    click.echo("exported C: export:DIR, the controllers or the estimator 'twin export' wrote into DIR, compiled and "
               "run in the loop (see docs/howto/export.md)")


@click.command("robots", cls=Once)
@click.argument("name", required=False, metavar="[NAME|FILE]")
def robots_command(name):
    """List the built-in robots, a line each; with NAME, print that one's robot file to copy and
    edit; with a robot FILE, check it and say what the twin makes of it.

    A robot file (robot.toml) describes a robot in SI units: body, wheels, friction, drive, IMU,
    encoders, control rate and the tilt at which it is lost; every key, its unit and range are
    on the robot file reference page (docs/reference/robot-file.md).

    \b
    Examples:
      twin robots
      twin robots paper > my-robot.toml
      twin robots my-robot.toml     # checked: one line naming the key if a figure is impossible
    """
    if name is not None and name.endswith(".toml"):
        describe_robot(load_robot(name))
        return
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


def describe_robot(r) -> None:
    """What the twin makes of robot ``r``: its figures in short, the drive at the wheel, and the
    controllers' settings it implies (twin.controllers.robot_settings)."""
    from twin.controllers import robot_settings  # only here: the listing of names needs no controllers

    p, m = r.params(), r.motor()
    click.echo(f"{r.name}: {r.description or '(no description)'} ({r.source})")
    click.echo(f"  body {p.m_b:g} kg, centre of mass {p.l:g} m above the axle; wheels r = {p.r:g} m, track "
               f"{2 * p.b:g} m; control {r.control_rate:g} Hz, lost at {r.fall_angle:g} rad")
    click.echo(f"  drive at the wheel: stall {m.stall_torque:.4g} N·m, no load {m.no_load_speed:.4g} rad/s, "
               f"peak {robot_settings.peak_torque(r):.4g} N·m per wheel; holds the body up to "
               f"{r.max_hold_angle():.3g} rad; falls at λ = {robot_settings.fall_rate(p):.3g} 1/s when free")
    d, u = robot_settings.design_settings(r), robot_settings.universes(r)
    click.echo(f"  design: ρ = {d['rho']:g} N·m, decay rate {d['decay_rate']:g} 1/s; Mamdani ranges: "
               + ", ".join(f"{k} {v:.3g} {robot_settings.UNIVERSES[k][1]}" for k, v in u.items()))
