"""``twin design``: the IT2 PDC balance gains by LMIs (:mod:`twin.controllers.designs`), and
what certifies them: the certificate, the decay, the closed-loop poles' region."""
from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from twin.commands.common import Once, no_cache_option
from twin.controllers import lmi, lmi_regions, robot_settings
from twin.controllers.balance import PDCBalanceController
from twin.controllers.designs import balance_design
from twin.controllers.lmi import decay_along_theta
from twin.errors import TwinError
from twin.outputs.report import write_json
from twin.robots import load_robot


def design_options(f):
    f = click.option("--max-gain", type=float, default=None,
                     help="Upper bound on each gain's spectral norm ‖G_i‖.")(f)
    f = click.option("--decay-rate", type=float, default=None,
                     help=f"Guaranteed decay rate of ‖x‖ on the TS model, 1/s [default: the robot's; the paper's "
                          f"robot {lmi.DEFAULT_DECAY_RATE:g}].")(f)
    f = click.option("--rho", type=float, default=None,
                     help=f"Bound on the total wheel torque |ul + ur|, N·m (Lemma 2) [default: the robot's; the "
                          f"paper's robot {lmi.DEFAULT_RHO:g}].")(f)
    f = click.option("--epsilon", type=float, default=lmi.DEFAULT_EPSILON, show_default=True,
                     help="Radius of the certified set of initial states ‖x0‖ ≤ ε (Lemma 2).")(f)
    f = click.option("--damping", type=float, default=lmi.DEFAULT_DAMPING, show_default=True,
                     help="Minimum damping ratio ζ in [0, 1) of the closed-loop poles (an LMI conic sector with the "
                          "decay rate; 0: none).")(f)
    f = click.option("--uncertain", default=format_uncertain(lmi.DEFAULT_UNCERTAIN), show_default=True,
                     metavar="NAME=RANGE,...|none",
                     help="Robust design over a parameter box: relative half-ranges of Table III parameters "
                          "(m_b=0.2,l=0.15: m_b ±20 %, l ±15 %), certified at the box's corners and the nominal "
                          "model; none: the nominal model alone.")(f)
    f = click.option("--all-vertices/--pdc-mixes", default=lmi.DEFAULT_ALL_VERTICES, show_default=True,
                     help="Certify every vertex closed loop A_i + B_i G_j (any controller weights, the type-1 "
                          "PDC's included), or only the IT2 PDC's own rule mixes (the paper's Y_ij relaxation).")(f)
    return f


def format_uncertain(box) -> str:
    return ",".join(f"{k}={v:g}" for k, v in box.items()) or "none"


@click.command(cls=Once)
@design_options
@click.option("--solver", type=click.Choice(["CLARABEL", "SCS"], case_sensitive=False), default=None,
              help="cvxpy solver (default Clarabel, SCS as fallback).")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the design as JSON (gains, P, solve time, ε, ρ, decay rate, certificate).")
@click.option("--robot", default="paper", show_default=True, metavar="NAME|FILE",
              help="The robot designed for: a built-in's name ('twin robots') or a robot file; its model, and the "
                   "torque bound and decay rate it implies (docs/explanation/paper-method.md, 'Another robot').")
@no_cache_option
def design(epsilon, rho, decay_rate, max_gain, damping, uncertain, all_vertices, solver, out, robot, no_cache):
    """Design the IT2 PDC balance gains by LMIs (paper Lemmas 1–2 plus a decay rate).

    Prints G1, G2 for the state [θ, θ̇, ψ, ψ̇] (u = Σ m_i G_i x, the total wheel torque
    in N·m), the independent certificate check and the solve time. With --damping, the
    closed-loop poles also keep a minimum damping ratio; with --uncertain, one pair of
    gains is certified for every corner of the parameter box (and checked, not
    certified, at plants sampled inside it). The defaults are the twin's default design,
    robust to m_b ±30 % and l ±15 % (chosen by the paper-exp3 sweep; see docs/explanation/paper-method.md).

    \b
    Examples:
      twin design
      twin design --decay-rate 2 --damping 0.5 --uncertain m_b=0.2,l=0.15 --rho 3 --out gains.json
      twin design --decay-rate 3 --damping 0 --uncertain none --pdc-mixes    # the nominal design
      twin design --robot balboa    # for another robot (its model, torque bound and decay rate)
    """
    r = load_robot(robot)
    implied = robot_settings.design_settings(r)
    rho = implied["rho"] if rho is None else rho
    decay_rate = implied["decay_rate"] if decay_rate is None else decay_rate
    if r.name != "paper":
        damping_note = "" if r.motor().back_emf_compensation else " (with its drive's back-EMF damping)"
        click.echo(f"robot {r.name}: its model{damping_note}; ρ = {rho:g} N·m, decay rate {decay_rate:g} 1/s")
    d = balance_design(r.model(), epsilon=epsilon, rho=rho, decay_rate=decay_rate, max_gain=max_gain,
                       solver=solver.upper() if solver else None, damping=damping,
                       uncertain=parse_uncertain(uncertain), all_vertices=all_vertices)
    print_design(d)
    if out is not None:
        write_json(d.to_json_dict(), out)
        click.echo(f"wrote {out}")


def parse_uncertain(text: str | None) -> dict:
    """'m_b=0.2,l=0.15' → {'m_b': 0.2, 'l': 0.15}, 'none' → {}; names and ranges are checked by
    the design."""
    if text is None or text.strip().lower() in ("none", ""):
        return {}
    out = {}
    for item in text.split(","):
        name, eq, value = item.strip().partition("=")
        name = name.strip()
        if not eq or not name:
            raise TwinError(f"--uncertain must be NAME=RANGE pairs separated by commas (e.g. m_b=0.2,l=0.15), "
                            f"got {text!r}")
        if name in out:
            raise TwinError(f"--uncertain names {name} twice; allowed: each parameter once")
        try:
            out[name] = float(value)
        except ValueError:
            raise TwinError(f"--uncertain {name}: the range must be a number in [0, 1) (0.2: ±20 %), "
                            f"got {value.strip()!r}") from None
    return out


def print_design(d) -> None:
    names = ("θ [N·m/rad]", "θ̇ [N·m·s/rad]", "ψ [N·m/rad]", "ψ̇ [N·m·s/rad]")
    region = f", damping ratio ≥ {d.damping:g}" if d.damping > 0 else ""
    click.echo(f"IT2 PDC gains (ε = {d.epsilon:g}, ρ = {d.rho:g} N·m, decay rate = {d.decay_rate:g} 1/s{region}, "
               f"solver {d.solver}, {d.solve_time_s * 1000:.0f} ms{', from the design cache' if d.from_cache else ''})")
    click.echo("        " + "".join(f"{n:>16}" for n in names))
    for i, g in enumerate(d.gains):
        click.echo(f"  G{i + 1}  " + "".join(f"{v:16.6g}" for v in g))
    click.echo(f"certified peak |u| = {d.peak_input:.4g} N·m for ‖x0‖ ≤ {d.epsilon:g} (on the TS model); "
               f"slowest rule closed-loop pole {d.slowest_vertex_pole:.3g} 1/s")
    click.echo(d.certificate.summary())
    if d.damping > 0 or d.uncertain or d.all_vertices:
        print_region(d)
    rates = [decay_along_theta(d, PDCBalanceController(d.gains, k).weight) for k in ("it2", "t1")]
    click.echo(f"decay of xᵀPx along θ in [-π/6, π/6] on the TS model (grid check): "
               f"IT2 PDC {rates[0]:.4g} 1/s, type-1 PDC {rates[1]:.4g} 1/s")


def print_region(d) -> None:
    """The closed-loop poles of the certified models (and of the sampled ones), from the gains."""
    weights = np.linspace(0.0, 1.0, 21 if d.all_vertices else 51)
    models = d.certified_models()
    what = "the nominal model" if len(models) == 1 else (
        f"the nominal model and the {len(models) - 1} corners of {lmi_regions.format_box(d.uncertain)}")
    mixes = ("every pair of model and controller rule weights (all vertex closed loops A_i + B_i G_j)"
             if d.all_vertices else "every frozen IT2 rule mix")
    re_max, zeta_min = lmi_regions.region_of_poles(lmi_regions.closed_loops(models, d.gains, weights, d.all_vertices))
    click.echo(f"certified for {what}, {mixes}: poles with Re λ ≤ {re_max:.4g} 1/s and damping ratio "
               f"≥ {zeta_min:.3g}")
    if d.uncertain:
        samples = lmi_regions.models_of(lmi_regions.sample_params(d.params, d.uncertain))
        re_max, zeta_min = lmi_regions.region_of_poles(lmi_regions.closed_loops(samples, d.gains, weights,
                                                                                d.all_vertices))
        click.echo(f"checked, not certified, at {len(samples)} plants inside the box: Re λ ≤ {re_max:.4g} 1/s, "
                   f"damping ratio ≥ {zeta_min:.3g}")
