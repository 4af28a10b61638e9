"""``twin compare``: two results side by side (:mod:`twin.workflows.compare`); exit status 0 if
they agree, 1 if they differ."""
from __future__ import annotations

from pathlib import Path

import click

from twin.commands.common import Once, tolerance_options, tolerances
from twin.workflows.compare import compare


@click.command("compare", cls=Once)
@click.argument("a", type=click.Path(path_type=Path), metavar="A")
@click.argument("b", type=click.Path(path_type=Path), metavar="B")
@tolerance_options("the trajectories")
@click.option("--figure", "figure_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              metavar="PATH", help="Write the figure (θ, torque, dψ/dt, distance; A solid, B dashed) as PNG here.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None, metavar="DIR",
              help="Write comparison.png and comparison.json (the report as data) into DIR.")
def compare_command(a, b, atol, rtol, tolerance, figure_path, out):
    """Compare two results side by side: exit 0 if they agree, 1 if they differ.

    A and B are run directories of 'twin run' (metrics.json and trajectory.csv or
    trajectory.csv.gz) or golden trajectories of 'twin check --record' (.npz); A is the
    reference. Prints each controller's metrics with B − A, what the environments and the
    designs differ in, and the first departure of each signal under the tolerances
    (default: bit for bit). Controllers only one side holds are named, not compared.
    Exit status 2 on bad input.

    \b
    Examples:
      twin compare runs/before runs/after
      twin compare runs/seed0 runs/seed1 --atol 1e-6 --tolerance theta=1e-4 --figure cmp.png
      twin compare gold/paper-exp1/it2/seed-0.npz runs/paper-exp1 --out runs/cmp
    """
    result, wrote = compare(a, b, tolerances(atol, rtol, tolerance), figure_path, out, click.echo)
    if wrote:
        click.echo(wrote)
    return 0 if result.agree else 1
