"""Commands that gave way to ``twin run``: hidden, each says in one line what replaced it."""
from __future__ import annotations

import click

from twin.errors import TwinError


def gave_way(name: str, instead) -> click.Command:
    """A hidden command ``twin NAME [N ...]`` that says in one line (exit status 2) what replaced
    it: ``instead(n)``, n the paper experiment's number given ("N" if none)."""
    @click.command(name, hidden=True, context_settings={"ignore_unknown_options": True, "allow_extra_args": True},
                  help=f"Replaced: 'twin {name}' gave way to 'twin run'.")
    @click.argument("experiment", required=False)
    def gone(experiment):
        n = experiment[-1] if experiment and experiment[-1] in "123" else "N"
        raise TwinError(instead(n))
    return gone


analytic = gave_way("analytic", lambda n: (
    f"'twin analytic' gave way to 'twin run paper-exp{n} --set plant.model=analytic --set plant.scale={{}} --set "
    "sensors.sensing=ideal' (the same runs and metrics; --controller, --duration and --out as before, --no-video for "
    "no video); the design options are --set design.decay_rate=A (and design.epsilon, rho, max_gain, damping, "
    "uncertain, all_vertices), and a --gains file has no equivalent: give the options that designed it"))
physics = gave_way("physics", lambda n: (
    f"'twin physics' gave way to 'twin run paper-exp{n}' (the same pipeline); for its nominal plant add --set "
    "plant.scale={}, for ground truth --set sensors.sensing=ideal, for ideal motors --set plant.motor=ideal"))
