"""``twin surface``: a Mamdani controller's surface over Table I's input ranges, as CSV and PNG."""
from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from twin.commands.common import Once
from twin.controllers import mamdani
from twin.outputs import report
from twin.outputs.rundir import FileBatch


@click.command(cls=Once)
@click.argument("which", type=click.Choice(["position", "direction"]), metavar="{position|direction}")
@click.option("--controller", type=click.Choice(["it2", "t1"]), default="it2", show_default=True)
@click.option("--points", type=click.IntRange(3, 1001), default=81, show_default=True, help="Grid points per input.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("runs/surfaces"),
              show_default=True, help="Output directory.")
def surface(which, controller, points, out):
    """Export a Mamdani controller's surface over Table I's input ranges (CSV and PNG).

    \b
    Examples:
      twin surface position --controller it2 --out runs/surfaces
      twin surface direction --controller t1 --points 101
    """
    batch = FileBatch(out, "twin surface")  # added beside the other surfaces there, with a manifest
    fls = mamdani.position_controller(controller) if which == "position" else mamdani.direction_controller(controller)
    g1, g2, z = fls.surface(points)
    labels = {"position": ("p_e [m]", "θ̇ [rad/s]", "θ_off [rad]"),
              "direction": ("α_e [rad]", "α̇_e [rad/s]", "u_α [N·m]")}[which]
    stem = f"{which}_{controller}"
    rows = [(a, b, z[i, j]) for i, a in enumerate(g1) for j, b in enumerate(g2)]
    with batch:
        np.savetxt(batch.temp(f"{stem}.csv"), np.array(rows), delimiter=",", header=",".join(labels), comments="")
        report.plot_surface(g1, g2, z, batch.temp(f"{stem}.png"), labels,
                            f"{controller.upper()} {which} controller (Table II)")
        batch.commit()
    click.echo(f"wrote {out / stem}.csv and {out / stem}.png")
