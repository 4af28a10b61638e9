"""The ``twin`` command line.

Every user error ends with a one-line ``error: …`` on stderr and exit status 2.
"""
from __future__ import annotations

import json
import math
import os
import re
import sys
import time
from pathlib import Path

# One OpenBLAS thread unless the user says otherwise, set before NumPy loads: the twin's
# matrices are 12 × 12 at most, which OpenBLAS computes on one thread anyway (the same
# numbers), while starting its thread pool cost every command 60 ms of its start-up on the
# project's 2-core machine; sweeps run one process per CPU already
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _the_process() -> bool:
    """True when this module is the process's command (the ``twin`` script, ``python -m
    twin``, ``python -m twin.cli``), not imported by a program or a test that calls :func:`main` in its own process
    (click's CliRunner): the command then owns the process's signals from its start, and its end."""
    m = sys.modules.get("__main__")
    spec = getattr(m, "__spec__", None)
    if spec is not None and getattr(spec, "name", None) in ("twin.cli", "twin.__main__"):  # python -m twin(.cli)
        return True
    return os.path.basename(getattr(m, "__file__", None) or "") in ("twin", "twin-script.py", "twin.exe")


if _the_process():  # from here (before the heavy imports below) a signal is noted, and raised once main() runs
    from twin.outputs import rundir as _rundir

    _rundir.hold_from_start()
    if sys.argv[1:2] == ["run"]:  # the figure's worker, started before the imports below (see run)
        from twin.outputs import figure_worker as _figure_worker

        _figure_worker.start_early()


import click  # noqa: E402

from twin.errors import TwinError  # noqa: E402


class _Once(click.Command):
    """Refuses an option given twice that takes one value: click keeps the last one silently, so
    ``--controller it2 --controller lqr`` ran LQR alone (issue 31)."""

    def parse_args(self, ctx, args):
        single = {}
        for p in self.params:
            if isinstance(p, click.Option) and not p.multiple and not p.count:
                for name in p.opts + p.secondary_opts:
                    if name.startswith("--"):
                        single[name] = p
        seen = {}
        for a in args:
            if a == "--":
                break
            name = a.split("=", 1)[0]
            p = single.get(name)
            if p is not None:
                if p.name in seen:
                    said = (f"{name} is given more than once; allowed: once" if seen[p.name] == name else
                            f"{seen[p.name]} and {name} are both given; allowed: one of them")
                    if p.name == "controller":
                        said += " (several kinds go comma-separated, e.g. --controller it2,lqr)"
                    raise click.UsageError(said, ctx=ctx)
                seen[p.name] = name
        return super().parse_args(ctx, args)


class _Group(click.Group):
    """Turns usage errors, TwinError and file errors into one line and exit status 2, and
    SIGINT and SIGTERM into one line saying what was kept and exit status 130 or 143."""

    command_class = _Once

    def main(self, args=None, prog_name=None, **extra):
        from twin.outputs import rundir

        # SIGTERM (a CI runner's timeout, a container stopping, kill) otherwise ends the
        # process where it stands: no clean-up, no message; SIGINT's KeyboardInterrupt became
        # "error: aborted" and exit status 1, a failed bound's. Both now raise Interrupted,
        # which every command's clean-up sees, and end here with 128 + the signal's number.
        # Every way out goes through _leave: from the moment the exit status is decided, a
        # signal is noted, not raised (no traceback, no second line while the command ends).
        with rundir.interrupts_raise():
            try:
                try:
                    rundir.started()  # a signal that came while the command line loaded: raised here
                    rv = super().main(args=args, prog_name=prog_name, standalone_mode=False, **extra)
                    status = rv if isinstance(rv, int) else 0
                except click.UsageError as exc:
                    rundir.leaving()
                    hint = f" (see 'twin {exc.ctx.info_name if exc.ctx and exc.ctx.parent else ''} --help')".replace("  ", " ")
                    click.echo(f"error: {' '.join(exc.format_message().split())}{hint}", err=True)
                    status = 2
                except click.ClickException as exc:
                    rundir.leaving()
                    click.echo(f"error: {exc.format_message()}", err=True)
                    status = exc.exit_code
                except click.Abort as exc:
                    cause = exc.__cause__ or exc.__context__
                    if isinstance(cause, KeyboardInterrupt):  # while click parsed the arguments
                        status = _interrupted(cause)
                    else:
                        rundir.leaving()
                        click.echo("error: aborted", err=True)
                        status = 1
            except KeyboardInterrupt as exc:  # after click's own handling (while it prints), or in the clauses above
                status = _interrupted(exc)
            except SystemExit as exc:  # an error's or an interrupt's in invoke, or a command's own exit
                status = _exit_code(exc)
            except BaseException as exc:  # noqa: BLE001 -- what a library made of an interrupt (a Rust panic, say)
                if rundir.signal_received() is None:
                    raise  # a bug: its traceback
                status = _interrupted(exc)
            _leave(status)

    def invoke(self, ctx):
        from twin.outputs import rundir

        try:
            rv = super().invoke(ctx)
        except KeyboardInterrupt as exc:
            sys.exit(_interrupted(exc))
        except TwinError as exc:
            rundir.leaving()
            click.echo(f"error: {_with_kept(str(exc), exc)}", err=True)
            sys.exit(2)
        except OSError as exc:
            rundir.leaving()
            text = f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": ")
            click.echo(f"error: {_with_kept(text, exc)}", err=True)
            sys.exit(2)
        if not rundir.kept_so_far():  # a signal from here on finds the command's work done
            rundir.keep_so_far("the command had finished: its outputs are complete")
        return rv


def _with_kept(text: str, exc: BaseException) -> str:
    from twin.outputs import rundir

    kept = rundir.kept_text(exc)
    return f"{text}; {kept}" if kept else text


def _interrupted(exc: BaseException) -> int:
    """One line on stderr, the signal and what was kept; the exit status, 130 (SIGINT) or 143
    (SIGTERM). Signals are noted, not raised, from here on (rundir.leaving)."""
    from twin.outputs import rundir

    rundir.leaving()
    kept = rundir.kept_text(exc) or rundir.kept_so_far()
    click.echo(f"interrupted: {rundir.signal_name(exc)}" + (f"; {kept}" if kept else ""), err=True)
    return rundir.exit_status_of(exc)


def _exit_code(exc: SystemExit) -> int:
    """The exit status ``sys.exit(code)`` asks for, as Python would make it (a text is said, and is 1)."""
    code = exc.code
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    from twin.outputs import rundir

    rundir.leaving()
    click.echo(str(code), err=True)
    return 1


def _late(status: int) -> int:
    """``status``, or 130 / 143 with its one line if a signal came to a command ending well (one
    noted as it ended, or one a library swallowed): a signal is never an exit status of 0."""
    from twin.outputs import rundir

    got = rundir.signal_received() if status == 0 else None
    if got is None:
        return status
    exc = rundir.Interrupted(got)
    kept = rundir.kept_so_far()
    click.echo(f"interrupted: {exc.name}" + (f"; {kept}" if kept else ""), err=True)
    return 128 + got


def _leave(status: int):
    """End the command with ``status`` (SIGINT and SIGTERM noted from now on: rundir.leaving).

    As the process's command, without the interpreter's teardown: the atexit functions run,
    the output is flushed and the process ends (os._exit). Python's teardown takes 50-60 ms
    after a run (numpy, matplotlib, PyBullet), and puts the default handlers back while it
    runs: a SIGTERM there ended the process with no word (exit status -15), a SIGINT with a
    KeyboardInterrupt, and an extension module half made by an interrupt could crash it
    (abort, -6). Imported by a program or a test, main() ends with SystemExit as before."""
    import threading

    from twin.outputs import rundir

    rundir.leaving()
    status = _late(status)
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon and t.is_alive()]
    if not _the_process() or others:  # threads to wait for: Python's own exit does that
        sys.exit(status)
    import atexit

    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):  # a closed pipe, say: Python's own exit says so, as before
        sys.exit(status)
    atexit._run_exitfuncs()
    status = _late(status)  # one that came meanwhile
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    os._exit(status)


def _complete_scenario(ctx, param, incomplete: str):
    """Shell completion of SCENARIO: the built-ins' names, then .toml files and folders."""
    from click.shell_completion import CompletionItem

    from twin.scenarios import builtin_scenarios

    items = [CompletionItem(n, help=d) for n, d in builtin_scenarios().items() if n.startswith(incomplete)]
    return items + [CompletionItem(incomplete, type="file")]


def _complete_kinds(ctx, param, incomplete: str):
    """Shell completion of --controller: the registry's kinds (and "both"), after any
    comma-separated ones already typed."""
    from click.shell_completion import CompletionItem

    from twin.registry import CONTROLLERS

    head, _, last = incomplete.rpartition(",")
    prefix = head + "," if head else ""
    return [CompletionItem(prefix + k) for k in (*CONTROLLERS, *(() if head else ("both",))) if k.startswith(last)]


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(None, "-V", "--version", package_name="mtwip-twin")
def main():
    """Digital twin of a mobile two-wheeled inverted pendulum under IT2 fuzzy control.

    \b
    Examples:
      twin design --decay-rate 3 --out gains.json
      twin run paper-exp3
      twin run paper-exp3 --set plant.model=analytic --set plant.scale={} --set sensors.sensing=ideal
      twin run paper-exp1 --controller it2,t1,lqr --set plant.scale={}
      twin sweep paper-exp3 --samples 50 --workers 2
      twin run paper-exp3 --log-sensors --no-video --out runs/exp3
      twin replay runs/exp3/sensor-logs/it2 --estimator ekf,complementary
      twin calibrate runs/exp3/sensor-logs/it2 --out runs/calibration
      twin scenarios
      twin kinds
      twin surface position --out runs/surfaces
      twin compare runs/before runs/after
    """


def _design_options(f):
    from twin.controllers import lmi

    f = click.option("--max-gain", type=float, default=None,
                     help="Upper bound on each gain's spectral norm ‖G_i‖.")(f)
    f = click.option("--decay-rate", type=float, default=lmi.DEFAULT_DECAY_RATE, show_default=True,
                     help="Guaranteed decay rate of ‖x‖ on the TS model, 1/s.")(f)
    f = click.option("--rho", type=float, default=lmi.DEFAULT_RHO, show_default=True,
                     help="Bound on the total wheel torque |ul + ur|, N·m (Lemma 2).")(f)
    f = click.option("--epsilon", type=float, default=lmi.DEFAULT_EPSILON, show_default=True,
                     help="Radius of the certified set of initial states ‖x0‖ ≤ ε (Lemma 2).")(f)
    f = click.option("--damping", type=float, default=lmi.DEFAULT_DAMPING, show_default=True,
                     help="Minimum damping ratio ζ in [0, 1) of the closed-loop poles (an LMI conic sector with the "
                          "decay rate; 0: none).")(f)
    f = click.option("--uncertain", default=_format_uncertain(lmi.DEFAULT_UNCERTAIN), show_default=True,
                     metavar="NAME=RANGE,...|none",
                     help="Robust design over a parameter box: relative half-ranges of Table III parameters "
                          "(m_b=0.2,l=0.15: m_b ±20 %, l ±15 %), certified at the box's corners and the nominal "
                          "model; none: the nominal model alone.")(f)
    f = click.option("--all-vertices/--pdc-mixes", default=lmi.DEFAULT_ALL_VERTICES, show_default=True,
                     help="Certify every vertex closed loop A_i + B_i G_j (any controller weights, the type-1 "
                          "PDC's included), or only the IT2 PDC's own rule mixes (the paper's Y_ij relaxation).")(f)
    return f


def _format_uncertain(box) -> str:
    return ",".join(f"{k}={v:g}" for k, v in box.items()) or "none"


def _no_cache_option(f):
    """--no-cache: solve the LMI design even if the design cache has it, and do not store it."""
    def disable(ctx, param, value):
        if value:
            from twin.controllers import design_cache

            design_cache.set_enabled(False)
        return value
    return click.option("--no-cache", is_flag=True, callback=disable, expose_value=True,
                        help="Solve the LMI design anew instead of taking it from the design cache "
                             "(see 'twin cache'), and do not store it.")(f)


def _tolerance_options(what: str):
    """--atol, --rtol and --tolerance SIGNAL=ATOL[,RTOL] (twin.outputs.tolerances), for ``what``."""
    def decorate(f):
        f = click.option("--tolerance", multiple=True, metavar="SIGNAL=ATOL[,RTOL]",
                         help="Tolerance of one signal (repeatable), e.g. theta=1e-6 or torque_l=1e-3,1e-6; "
                              "overrides --atol/--rtol for it.")(f)
        f = click.option("--rtol", type=float, default=None, metavar="FRACTION",
                         help=f"Relative tolerance of every signal in {what}: |a − b| ≤ ATOL + RTOL·|b| "
                              "(default 0).")(f)
        f = click.option("--atol", type=float, default=None, metavar="ATOL",
                         help=f"Absolute tolerance of every signal in {what}, in the signal's SI unit (default 0: "
                              "bit for bit; at least 1e-9 between compiled and pure-Python builds).")(f)
        return f
    return decorate


def _tolerances(atol, rtol, items):
    from twin.outputs.tolerances import parse_options

    return parse_options(atol, rtol, items)


# --step-limit, --run-limit, --memory-limit: the scenario's [limits] keys (twin.limits), with
# their ranges as twin.scenarios.schema has them (tests/test_limits.py checks that they agree)
LIMIT_OPTIONS = (
    ("step_limit", "--step-limit", "step_wall_s", "SECONDS", "(0, 3600] s",
     "Wall time in s one call of a controller, or one step() of the estimator, may take"),
    ("run_limit", "--run-limit", "run_wall_s", "SECONDS", "(0, 1e+06] s",
     "Wall time in s one controller's run may take, the twin's own time included"),
    ("memory_limit", "--memory-limit", "run_memory_mb", "MB", "(0, 1e+06] MB",
     "Growth in MB (10⁶ bytes) of the process's resident memory over one controller's run"),
)


CONTAINED = """A plugin (package.module:attribute) is imported, built and run only in worker
    processes this command kills: its sys.exit, KeyboardInterrupt, os._exit or crash, a
    call that overruns --step-limit, a run that overruns --run-limit or grows the worker
    by more than --memory-limit end that run alone, as one line naming the plugin; its
    threads and child processes end with the run. It can still write files, use the
    network or signal other processes (see docs/howto/limits.md)."""


def _contained(f):
    """Put :data:`CONTAINED` (what the worker processes contain) in the command's help, where the
    docstring says {CONTAINED}: one text for twin run, sweep and check."""
    f.__doc__ = f.__doc__.replace("{CONTAINED}", CONTAINED)
    return f


def _limit_options(where: str, run_default: str = ""):
    """--step-limit, --run-limit and --memory-limit, each setting a key of [limits] (``where``: to
    what it applies, for the help; ``run_default``: what --run-limit's default is, if not none)."""
    def decorate(f):
        for dest, flag, key, metavar, allowed, what in reversed(LIMIT_OPTIONS):
            default = "the scenario's, else none"
            if dest == "run_limit" and run_default:
                default = run_default
            f = click.option(flag, dest, default=None, metavar=metavar,
                             help=f"{what}, in {allowed}: sets limits.{key}{where} (not with --set "
                                  f"limits.{key}). Default: {default}.")(f)
        return f
    return decorate


def _limit_overrides(overrides, step_limit, run_limit, memory_limit) -> tuple:
    """``overrides`` (the --set items) followed by ``limits.KEY=V`` for each limit option
    given, validated like the scenario key; an option and a --set of the same key are refused."""
    given = {"step_limit": step_limit, "run_limit": run_limit, "memory_limit": memory_limit}
    if all(v is None for v in given.values()):
        return tuple(overrides)
    from twin.scenarios.schema import ScenarioError, parse_value, lookup
    from twin.scenarios.scenario import parse_override

    extra = []
    for dest, flag, key, _metavar, _allowed, _what in LIMIT_OPTIONS:
        text = given[dest]
        if text is None:
            continue
        for item in overrides:  # the same key twice would leave one of them unsaid
            name, _, rest = str(item).partition("=")
            name = name.strip()
            if name == f"limits.{key}" or (name == "limits" and key in _inline_table(rest)):
                raise TwinError(f"{flag} and --set {name}=... both set limits.{key}; give one of them")
        try:
            _, value = parse_override(f"limits.{key}={text}")
            value = parse_value(value, lookup(f"limits.{key}"), flag)
        except ScenarioError as exc:
            message = str(exc)
            if message.startswith("--set"):  # what the TOML reader could not take, said of the option
                message = f"{flag}: {message.partition(': ')[2]}"
            raise TwinError(message) from None
        extra.append(f"limits.{key}={value!r}")
    return tuple(overrides) + tuple(extra)


def _inline_table(text: str) -> dict:
    """The keys of ``--set limits={...}``'s value, or {} if it is not a table."""
    import tomllib

    try:
        value = tomllib.loads(f"v = {text.strip()}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}


@main.group()
def cache():
    """The design cache: LMI designs stored by their inputs, so that a run need not solve them.

    Where: $TWIN_CACHE_DIR, else $XDG_CACHE_HOME/mtwip-twin, else ~/.cache/mtwip-twin.

    \b
    Examples:
      twin cache info
      twin cache clear
    """


@cache.command("info")
def cache_info():
    """Print the design cache's directory and how many designs it holds."""
    from twin.controllers import design_cache

    d = design_cache.cache_dir()
    n = len(list(d.glob("lmi-*.json"))) if d.is_dir() else 0
    click.echo(f"{d}: {n} cached design{'s' * (n != 1)}")


@cache.command("clear")
def cache_clear():
    """Delete every cached design (only the cache's own files)."""
    from twin.controllers import design_cache

    d, n = design_cache.clear()
    click.echo(f"removed {n} file{'s' * (n != 1)} from {d}")


@main.command()
@_design_options
@click.option("--solver", type=click.Choice(["CLARABEL", "SCS"], case_sensitive=False), default=None,
              help="cvxpy solver (default Clarabel, SCS as fallback).")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the design as JSON (gains, P, solve time, ε, ρ, decay rate, certificate).")
@_no_cache_option
def design(epsilon, rho, decay_rate, max_gain, damping, uncertain, all_vertices, solver, out, no_cache):
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
    """
    from twin.controllers.designs import balance_design

    d = balance_design(epsilon=epsilon, rho=rho, decay_rate=decay_rate, max_gain=max_gain,
                       solver=solver.upper() if solver else None, damping=damping,
                       uncertain=_parse_uncertain(uncertain), all_vertices=all_vertices)
    _print_design(d)
    if out is not None:
        from twin.outputs.report import write_json

        write_json(d.to_json_dict(), out)
        click.echo(f"wrote {out}")


def _parse_uncertain(text: str | None) -> dict:
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


def _print_design(d) -> None:
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
        _print_region(d)
    from twin.controllers.balance import PDCBalanceController
    from twin.controllers.lmi import decay_along_theta

    rates = [decay_along_theta(d, PDCBalanceController(d.gains, k).weight) for k in ("it2", "t1")]
    click.echo(f"decay of xᵀPx along θ in [-π/6, π/6] on the TS model (grid check): "
               f"IT2 PDC {rates[0]:.4g} 1/s, type-1 PDC {rates[1]:.4g} 1/s")


def _print_region(d) -> None:
    """The closed-loop poles of the certified models (and of the sampled ones), from the gains."""
    import numpy as np

    from twin.controllers import lmi_regions

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


def _gave_way(name: str, instead) -> None:
    """A hidden command ``twin NAME [N ...]`` that says in one line (exit status 2) what replaced
    it: ``instead(n)``, n the paper experiment's number given ("N" if none)."""
    @main.command(name, hidden=True, context_settings={"ignore_unknown_options": True, "allow_extra_args": True},
                  help=f"Replaced: 'twin {name}' gave way to 'twin run'.")
    @click.argument("experiment", required=False)
    def gone(experiment):
        n = experiment[-1] if experiment and experiment[-1] in "123" else "N"
        raise TwinError(instead(n))


_gave_way("analytic", lambda n: (
    f"'twin analytic' gave way to 'twin run paper-exp{n} --set plant.model=analytic --set plant.scale={{}} --set "
    "sensors.sensing=ideal' (the same runs and metrics; --controller, --duration and --out as before, --no-video for "
    "no video); the design options are --set design.decay_rate=A (and design.epsilon, rho, max_gain, damping, "
    "uncertain, all_vertices), and a --gains file has no equivalent: give the options that designed it"))
_gave_way("physics", lambda n: (
    f"'twin physics' gave way to 'twin run paper-exp{n}' (the same pipeline); for its nominal plant add --set "
    "plant.scale={}, for ground truth --set sensors.sensing=ideal, for ideal motors --set plant.motor=ideal"))


@main.command()
@click.argument("scenario", metavar="SCENARIO|FILE", shell_complete=_complete_scenario)
@click.option("--controller", default=None, metavar="KINDS", shell_complete=_complete_kinds,
              help="Controllers to run on identical conditions, comma-separated: it2, t1, lqr, both (= it2,t1) or "
                   "package.module:attribute (runs that module's code). Default: the scenario's controller.kinds.")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Seed of the sensor noise and faults (default: the scenario's 'seed').")
@click.option("--duration", type=float, default=None, help="Simulated time in s (default: the scenario's).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a scenario key by its dotted path, validated like the file "
                   "(repeatable), e.g. --set plant.scale.m_b=1.2.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output directory (default: runs/<scenario name>).")
@click.option("--video/--no-video", default=None, help="Render video.mp4 (default: the scenario's video.enabled).")
@click.option("--sample", type=click.IntRange(min=0), default=None, metavar="K",
              help="Replay sample K of 'twin sweep' (the 'sample' column of sweep.csv); --seed is then the "
                   "sweep's root seed, and --set/--duration must be the sweep's.")
@click.option("--log-every", "log_every", default="1", show_default=True, metavar="N",
              help="Write (and keep in memory) every N-th control step of the trajectory only; the metrics are "
                   "still computed from every step. metrics.json's 'log' says what was dropped.")
@click.option("--log-format", "log_format", type=click.Choice(["csv", "csv.gz"]), default="csv", show_default=True,
              help="trajectory.csv, or trajectory.csv.gz: the same text gzip-compressed (pandas.read_csv reads it).")
@click.option("--log-sensors", "log_sensors", is_flag=True,
              help="Also write each controller's run as a sensor log (sensor-logs/KIND/: log.toml, imu.csv, "
                   "encoders.csv, commands.csv, truth.csv), the format a robot's logs take for 'twin replay'.")
@click.option("--plant", "plant_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              metavar="CALIBRATION.toml",
              help="Run the robot 'twin calibrate' fitted: the file's [plant] and [sensors] replace the scenario's "
                   "true plant scale and IMU latency (before any --set).")
@_limit_options("")
@_no_cache_option
@_contained
def run(scenario, controller, seed, duration, overrides, out, video, sample, log_every, log_format, log_sensors,
        plant_file, step_limit, run_limit, memory_limit, no_cache):
    """Run a scenario on the PyBullet twin: trajectory, metrics, figure and video.

    SCENARIO is a built-in name (see 'twin scenarios') or a scenario .toml file. Writes
    trajectory.csv (or trajectory.csv.gz), metrics.json, figure.png, design.json,
    video.mp4 and manifest.json (every file's size and SHA-256) into --out, as a whole:
    --out is the earlier run until the new one is complete, and an interrupt (exit
    status 130 or 143) keeps the data if only the figure or the video was missing. The
    same scenario and seed give identical metrics.json and trajectory.csv. A controller's
    run stopped by a limit ([limits], --step-limit, --run-limit, --memory-limit) is one
    line naming it and the limit, exit status 2; the other controllers' results are
    written, and metrics.json's 'errors' names the run stopped. A plugin that breaks its
    contract (or ends its process) is one line, exit status 2, and nothing is written.
    --out must be a new or empty directory or an earlier run's: one another command
    wrote (a sweep, a replay) is refused, and so is one another command is writing.

    {CONTAINED}

    \b
    Examples:
      twin run paper-exp3
      twin run paper-exp1 --controller it2 --seed 7 --no-video
      twin run paper-exp3 --controller it2,t1,lqr
      twin run paper-exp3 --controller my_plugins:StateFeedback,it2   # your own, from ./my_plugins.py
      twin run push-recovery --set pushes='[{force=[20,0,0], start=3, duration=0.1}]'
      twin run my-robot.toml --set plant.scale.m_b=1.2 --set sensors.sensing=ideal --out runs/heavy
      twin run paper-exp3 --sample 17 --seed 0 --no-video   # replay a sweep's sample 17
      twin run paper-exp2 --duration 3600 --log-every 20 --log-format csv.gz --no-video   # an hour at 10 Hz
      twin run paper-exp3 --plant runs/calibration/calibration.toml   # the robot 'twin calibrate' fitted
    """
    import contextlib

    from twin.outputs import figure_worker

    # first: the figure's worker imports matplotlib while the scenario loads and the runs simulate
    # (started here, or as this module loaded when it is the process's command, not when the
    # runs start: it is ready 0.1-0.2 s sooner); ended by run_scenario
    figure = figure_worker.take_early() or figure_worker.start()
    try:
        _run(scenario, controller, seed, duration, overrides, out, video, sample, log_every, log_format, log_sensors,
             plant_file, step_limit, run_limit, memory_limit, figure)
    finally:
        if figure is not None:  # not taken up: the command failed before its runs
            figure.cancel()


def _run(scenario, controller, seed, duration, overrides, out, video, sample, log_every, log_format, log_sensors,
         plant_file, step_limit, run_limit, memory_limit, figure) -> None:
    """``twin run``'s work, with the figure's worker started (or None)."""
    import contextlib

    from twin.outputs import rundir
    from twin.registry import label
    from twin.scenarios.contained import ContainedScenario, involves_plugins
    from twin.scenarios.runner import controllers_of, plan, plugins_of, run_scenario

    every = _log_every(log_every)
    if plant_file is not None:
        from twin.calibrate.output import plant_overrides

        overrides = tuple(plant_overrides(plant_file)) + tuple(overrides)
    sc = _load(scenario, _limit_overrides(overrides, step_limit, run_limit, memory_limit), seed, duration)
    if out is None:  # the scenario's name must not lead the outputs out of runs/ (a shared file may say "../..")
        out = rundir.child_of(Path("runs"), sc.name if sample is None else f"{sc.name}-sample{sample}",
                              "the scenario's name")
    target = rundir.StagedDirectory(out, "twin run")  # a directory the run may not replace: said before anything runs
    # an earlier run there is replaced once this one is complete: said, before anything runs
    earlier = target.existed and any(Path(out).iterdir())
    try:
        kinds = controllers_of(controller, sc)
        picked, root = None, sc.seed
        if sample is not None:
            from twin.sweep import sample_scenario

            picked = sample_scenario(sc, sc.seed, sample)
            sc = picked.scenario
        with contextlib.ExitStack() as stack:
            # every plugin built once, before anything runs or is said: a user's in a worker process
            # (twin.containment), where its exits, crashes, hangs, threads and processes are contained
            box, specs = None, None
            if involves_plugins(sc, kinds):
                box = stack.enter_context(ContainedScenario(sc, kinds))
                plugins = box.plan()["plugins"]
            else:
                specs, plugins = plan(sc, kinds), plugins_of(sc, kinds)
            if picked is not None:
                click.echo(f"sample {picked.index} of a sweep (root seed {root}): level λ = {picked.level:g}, "
                           f"draw {picked.draw}, seed {picked.seed}")
            click.echo(_title(sc))
            if earlier:
                click.echo(f"  note: {out} holds an earlier run; this one replaces it when it is complete "
                           f"(--out DIR writes elsewhere)")
            _echo_plugins(plugins)
            with _Progress() as bar:
                result = run_scenario(sc, kinds, out=out, video=video, progress=bar.update, log_every=every,
                                      log_format=log_format, keep_limited=True, specs=specs, log_sensors=log_sensors,
                                      contained=box or False, figure=figure)
    except KeyboardInterrupt as exc:  # what the run kept, if it got that far, stands
        rundir.kept(exc, target.unchanged())
        raise
    finally:
        target.close()  # the directory was held from the start: a second command writing there is refused
    limited, kinds = result.errors, tuple(k for k in kinds if k in result.metrics)  # runs a limit stopped: said last
    keys = ("status", "settling_time_s", "theta_rms_rad", "oscillation_peak_to_peak_rad", "final_position_error_m",
            "final_heading_error_rad", "iae_theta", "control_effort", "max_abs_torque_nm", "estimator_theta_rmse_rad",
            "rejected_measurements")
    click.echo(f"  {'metric':32}" + "".join(f"{label(k)[:13]:>14}" for k in kinds))
    for k in keys:
        vals = [result.metrics[c][k] for c in kinds]
        click.echo(f"  {k:32}" + "".join(f"{_fmt(v):>14}" for v in vals))
    for c in kinds:
        if result.metrics[c]["status"] != "ok":  # fell, diverged, or degraded (what the estimator lost)
            click.echo(f"  {label(c)}: {result.metrics[c]['status']}: {result.metrics[c]['end_reason']}")
    from twin.outputs.report import estimator_line

    for c in kinds:  # the estimator's consistency, rejections and events (metrics.json's "estimator")
        if result.metrics[c].get("estimator_reads_truth"):
            click.echo(f"  {label(c)}: estimator {result.scenario.estimator} reads the ground truth "
                       f"(reads_truth = True): a reference, not an estimator under test")
        line = estimator_line(result.metrics[c], label(c))
        if line:
            click.echo(f"  {line}")
    t = result.timings
    sim = sum(float(r.full_signal("t")[-1]) for r in result.runs)  # the last step simulated, logged or not
    wall = sum(v for k, v in t.items() if k.startswith("run_"))
    each = f"{sim / len(result.runs):g} s for each of {len(result.runs)} runs" if len(result.runs) > 1 else f"{sim:g} s"
    click.echo(f"  simulated {each} in {wall:.2f} s (real-time factor {sim / max(wall, 1e-9):.0f})"
               + (f"; video {result.video.frames} frames in {t['video_s']:.1f} s ({result.video.codec}, "
                  f"{result.video.renderer})" if result.video is not None else ""))
    if every > 1:
        n = sum(len(r.t) for r in result.runs)
        click.echo(f"  trajectory: one control step in {every} written ({n} of "
                   f"{sum(r.control_steps for r in result.runs)} rows); the metrics are from every step")
    for note in result.notes:
        click.echo(f"  note: {note}")
    click.echo(f"wrote {out}/: " + ", ".join(Path(f).name for f in result.files))
    if limited:  # a plugin error against that controller alone: its one line, exit status 2, the others kept
        first, exc = next(iter(limited.items()))
        n = len(limited) - 1
        more = f" (and {n} more run{'s' * (n > 1)} stopped by a limit)" if n else ""
        raise TwinError(f"{first}: {' '.join(str(exc).split())}{more}; the results of {', '.join(kinds)} are in "
                        f"{out} (metrics.json's 'errors' names the runs stopped)")


def _log_every(text: str) -> int:
    """--log-every as an int ≥ 1, or one line saying what is allowed."""
    value = int(text.strip()) if re.fullmatch(r"\s*\d+\s*", text) else None
    if value is None or value < 1:
        raise TwinError(f"--log-every must be a whole number ≥ 1 (write every N-th control step; 1: every step), "
                        f"got {text!r}")
    return value


def _echo_plugins(plugins) -> None:
    for p in plugins:
        click.echo(f"  plugin {p['role']} {p['kind']}: {p['file']} (sha256 {(p['sha256'] or '?')[:12]})")


def _load(scenario, overrides, seed, duration):
    """The scenario with ``--set`` items, ``--seed`` and ``--duration`` applied (in that order)."""
    from twin.scenarios import load_scenario

    extra = list(overrides)
    if seed is not None:
        extra.append(f"seed={seed}")
    if duration is not None:
        if not (math.isfinite(duration) and 0 < duration <= 3600):
            raise TwinError(f"--duration must be in (0, 3600] s, got {duration:g}")
        extra.append(f"duration={duration!r}")
    return load_scenario(scenario, extra)


def _title(sc) -> str:
    """The scenario's name and description, saying which tables --set changed (the
    description was written for the file as it is)."""
    changed = sc.changed_keys
    if sc.sets_nothing:  # an empty file: say what the defaults are rather than run them without a word
        d = sc.data
        return (f"{sc.name}: the file sets nothing, so the defaults run: a catch from θ0 = {d['initial']['theta']:g} rad "
                f"for {d['duration']:g} s (twin scenarios NAME prints a built-in to start from)")
    text = f"{sc.name}: {sc.description}" if sc.description else sc.name
    return text + (f" [changed by --set: {', '.join(changed)}]" if changed else "")


@main.command()
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
def replay(logs, estimators, noise, out):
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
    from twin.logs.replay import figure_name, replay_logs_contained, summary_lines, write_estimates_csv, write_figure
    from twin.outputs import report, rundir
    from twin.registry import check_kinds

    kinds = check_kinds("estimator", [k.strip() for k in estimators.split(",") if k.strip()], "--estimator")
    if "ideal" in kinds:
        raise TwinError("--estimator: 'ideal' reads the truth, which a log's readings are not; allowed: ekf, "
                        "complementary, kalman2 or package.module:attribute")
    with rundir.written_whole(out, "twin replay") as path:
        doc, replays = replay_logs_contained(logs, kinds, noise)  # a plugin estimator in a worker process
        report.write_json(doc, path / "replay.json")
        write_estimates_csv(replays, path / "estimates.csv")
        figures = [figure_name(k) for k in range(len(doc["logs"]))]
        for k, name in enumerate(figures):  # one per log: figure.png, figure-2.png, ...
            write_figure(doc, replays, path / name, which=k)
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
            click.echo(f"  {kind:{w}}{_fmt(err.get('theta_rmse_rad')):>12}{_fmt(err.get('theta_max_abs_rad')):>12}"
                       f"{_fmt(err.get('psi_rmse_rad')):>12}{_fmt(err.get('alpha_rmse_rad')):>12}"
                       f"{_fmt(c.get('nis_per_dof')):>9}{_fmt(c.get('nees_mean')):>8}"
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


@main.command()
@click.argument("scenario", metavar="SCENARIO|FILE", shell_complete=_complete_scenario)
@click.option("--samples", "draws", type=click.IntRange(1, 100_000), required=True, metavar="N",
              help="Samples per uncertainty level (sweep.levels); IT2 and type-1 run on each.")
@click.option("--workers", type=click.IntRange(1, 1024), default=None, metavar="K",
              help="Worker processes (local) or Ray CPUs (default: every core here, or the Ray cluster's).")
@click.option("--backend", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="local: spawned worker processes; ray: Ray tasks (pip install 'mtwip-twin[ray]').")
@click.option("--ray-address", default=None, metavar="ADDRESS",
              help="Ray cluster to join, as for ray.init(address=...) (default: a local Ray instance).")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Root seed of the sweep (default: the scenario's 'seed').")
@click.option("--duration", type=float, default=None, help="Simulated time per run in s (default: the scenario's).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a scenario key (repeatable), e.g. --set sweep.levels=[0,0.2,0.4].")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Sweep directory (default: runs/sweep-<scenario name>); rerun to resume.")
@click.option("--controller", default=None, metavar="KINDS", shell_complete=_complete_kinds,
              help="Controllers compared on identical samples, comma-separated: it2, t1, lqr, both (= it2,t1) or "
                   "package.module:attribute. Default: the scenario's controller.kinds.")
@click.option("--reference", default=None, metavar="KIND",
              help="The controller each other one is paired with in the paired statistics (default: the last listed).")
@click.option("--log-sensors", "log_sensors", default=None, metavar="K[,K...]",
              help="Also write each controller's run of samples K (the 'sample' column of sweep.csv) as sensor "
                   "logs, in sensor-logs/sample-K/KIND/: the logs 'twin run SCENARIO --sample K --log-sensors' "
                   "writes.")
@_limit_options(" for each controller's run of a sample",
                "the scenario's, else 60 s + 10 × the simulated time in s (210 s for 15 s)")
@_contained
def sweep(scenario, draws, workers, backend, ray_address, seed, duration, overrides, out, controller, reference,
          log_sensors, step_limit, run_limit, memory_limit):
    """Monte Carlo sweep: controllers compared on sampled plants, noise, tilts and pushes.

    The scenario's [sweep] table says what is sampled (see docs/howto/sweeps.md). Each sample's
    seed and sampled values are in sweep.csv, and 'twin run SCENARIO --sample K'
    replays sample K exactly. Finished samples are kept as they finish: rerun the
    same command after an interruption and only the rest runs. Writes sweep.csv,
    summary.md, summary.json, success.png, distributions.png and paired.png (and, with
    --log-sensors, the chosen samples' sensor logs for 'twin replay'). A run
    stopped by a limit (--step-limit, --run-limit, --memory-limit; by default each run
    may take 60 s + 10 s per simulated s) is an error of that controller on that sample;
    a plugin that breaks its contract or ends its process on some samples is recorded there,
    and the sweep ends with exit status 2.

    {CONTAINED}

    \b
    Examples:
      twin sweep paper-exp3 --samples 50
      twin sweep paper-exp3 --samples 50 --controller it2,t1,lqr --reference lqr
      twin sweep push-recovery --samples 20 --workers 2 --set sweep.push_count=2
      twin sweep paper-exp2 --samples 100 --backend ray --ray-address auto
      twin sweep paper-exp3 --samples 50 --log-sensors 0,17   # and samples 0 and 17 as sensor logs
    """
    from twin.outputs import rundir
    from twin.scenarios.runner import controllers_of
    from twin.sweep import run_sweep
    from twin.sweep.runner import check_log_samples, sweep_controllers, sweep_plan

    if ray_address is not None and backend != "ray":
        raise TwinError("--ray-address needs --backend ray")
    chosen = _sample_numbers(log_sensors)
    sc = _load(scenario, _limit_overrides(overrides, step_limit, run_limit, memory_limit), seed, duration)
    if out is None:
        out = rundir.child_of(Path("runs"), f"sweep-{sc.name}", "the scenario's name")
    rundir.refuse_if_in_use(out)
    from twin.sweep.store import refuse_others

    refuse_others(out)  # another command's folder, said before anything runs
    levels = sc.sweep["levels"]
    kinds, reference = sweep_controllers(sc, controllers_of(controller, sc), reference)
    chosen = check_log_samples(sc, chosen, draws * len(levels))  # said before anything is
    # every plugin built once here (a user's in a worker process): one that cannot be is one line before anything runs
    summary = sweep_plan(sc, kinds)
    click.echo(_title(sc))
    _echo_plugins(summary["plugins"])
    click.echo(f"  {counted(draws, 'sample')} × {counted(len(levels), 'level')} λ = {', '.join(f'{v:g}' for v in levels)}, "
               f"root seed {sc.seed}, backend {backend}" + (f", {workers} worker{'s' * (workers > 1)}" if workers else ""))
    bar = _SweepBar()
    try:
        result = run_sweep(sc, draws, out, scenario_arg=scenario, workers=workers, backend=backend,
                           address=ray_address, progress=bar.update, controllers=kinds, reference=reference,
                           log_sensors=chosen, summary=summary)
    except KeyboardInterrupt as exc:
        bar.close()
        if bar.total and bar.done >= bar.total:  # stopped while the report was written
            rundir.kept(exc, f"all {bar.total} samples are stored in {out}, the report is not finished; rerun the "
                             "same command to write it")
        else:
            rundir.kept(exc, f"{bar.done} of {bar.total} samples are stored in {out}; rerun the same command to "
                             "finish the rest")
        raise
    bar.close()
    if result.environment_changes:
        click.echo(f"  note: resumed in another environment than the first samples' ({'; '.join(result.environment_changes)}); "
                   "the samples run now may differ from the others in the last digits (sweep.json: resumed_in)")
    sims = len(kinds) * result.ran
    click.echo(f"  ran {counted(result.ran, 'sample')} ({counted(sims, 'run')}) in {result.wall_s:.1f} s"
               + (f", {60 * result.ran / result.wall_s:.1f} samples/min" if result.ran and result.wall_s > 0 else "")
               + (f"; {result.resumed} {'was' if result.resumed == 1 else 'were'} already finished" if result.resumed else ""))
    click.echo(_success_table(result.summary))
    if result.logs:
        logged = sorted({k for k, _ in result.logs})
        click.echo(f"  sensor logs of sample{'s' * (len(logged) > 1)} {', '.join(map(str, logged))}: "
                   f"{len(result.logs)} in {out}/sensor-logs/sample-K/KIND/ (for twin replay)")
    for note in result.log_notes:
        click.echo(f"  note: {note}")
    click.echo(f"wrote {out}/: " + ", ".join(Path(f).name for f in result.files))
    if result.rows and all(r["status"] == "error" for r in result.rows):
        first = result.rows[0]
        raise TwinError(f"every run of the sweep ended in an error, so nothing was measured (first: sample "
                        f"{first['sample']}, {first['controller']}: {first['error']})")
    broken = [r for r in result.rows if str(r.get("error") or "").startswith("PluginError")]
    if broken:  # a plugin broke its contract past the preflight: not a result, though the rest is kept
        first = broken[0]
        raise TwinError(f"{len(broken)} run{'s' * (len(broken) > 1)} ended with a plugin error (first: sample "
                        f"{first['sample']}, {first['error'][len('PluginError: '):]}); the other runs are stored "
                        f"in {out}")


def _sample_numbers(text: str | None) -> tuple[int, ...]:
    """--log-sensors K[,K...] as sample numbers (whether each is one of the sweep's is checked
    by twin.sweep.runner.check_log_samples, which knows how many there are)."""
    if text is None:
        return ()
    parts = [p.strip() for p in text.split(",")]
    if not all(re.fullmatch(r"\d+", p) for p in parts):
        raise TwinError(f"--log-sensors must be sample numbers, comma-separated (the 'sample' column of sweep.csv, "
                        f"e.g. 0,17), got {text!r}")
    return tuple(int(p) for p in parts)


@main.command()
@click.argument("targets", nargs=-1, metavar="SCENARIO|FILE|DIR...", shell_complete=_complete_scenario)
@click.option("--controller", default=None, metavar="KINDS", shell_complete=_complete_kinds,
              help="Controllers to check, comma-separated (default: each scenario's controller.kinds).")
@click.option("--seeds", type=click.IntRange(1, 10_000), default=1, show_default=True, metavar="N",
              help="Seeds per scenario and controller: the scenario's seed, seed + 1, ...")
@click.option("--workers", type=click.IntRange(1, 1024), default=None, metavar="K",
              help="Worker processes (default: every core here).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Override a key in every scenario.")
@click.option("--junit", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="FILE",
              help="Also write the verdicts as JUnit XML, for CI systems.")
@click.option("--record", type=click.Path(file_okay=False, path_type=Path), default=None, metavar="DIR",
              help="Store every run as a golden trajectory under DIR (compressed).")
@click.option("--golden", type=click.Path(file_okay=False, path_type=Path), default=None, metavar="DIR",
              help="Compare every run with the golden trajectory stored under DIR; report where it departs.")
@_tolerance_options("the golden trajectories (with --golden)")
@_limit_options(" in every scenario checked")
@_contained
def check(targets, controller, seeds, workers, overrides, junit, record, golden, atol, rtol, tolerance, step_limit,
          run_limit, memory_limit):
    """Check scenarios against their [expect] bounds: exit 0 if all hold, 1 if any fails.

    Runs every scenario, controller and seed (in parallel on local cores) and prints each
    bound with the measured value. A directory contributes its .toml files that have an
    [expect] table. With --golden, each run must also follow its recorded trajectory: bit
    for bit unless --atol, --rtol, --tolerance or the scenario's [expect.golden] allow
    more; a departure says whether the environment or a design differs from the
    reference's. A run stopped by a limit (--step-limit, --run-limit, --memory-limit),
    or by a plugin that breaks its contract or ends its process, fails its check. Exit
    status 2 on a user error (a bad file, key or kind).

    {CONTAINED}

    \b
    Examples:
      twin check paper-exp1 paper-exp2 paper-exp3
      twin check scenarios/ --controller my_filters:Tuned,it2 --seeds 20 --junit check.xml
      twin check paper-exp1 --golden gold/ --atol 1e-6 --tolerance theta=1e-8
    """
    from twin.verify.check import collect, failure_lines, format_table, run_checks, write_junit
    from twin.sweep.backends import default_workers

    if record is not None and golden is not None:
        raise TwinError("--record and --golden together would overwrite the references with the runs they judge; "
                        "give one of them")
    if golden is not None and not golden.is_dir():
        raise TwinError(f"--golden {golden}: no such directory; record references first with --record {golden}")
    from twin.outputs import rundir

    if golden is not None:  # references of a record that did not finish are not judged against
        rundir.finish_batch(golden)  # one killed while it committed is carried through first
        rundir.read_manifest(golden, (rundir.RECORD_COMMAND,), "golden directory",
                             f"record it again with 'twin check ... --record {golden}'")
    tolerances = _tolerances(atol, rtol, tolerance)
    if tolerances.is_set and golden is None:
        raise TwinError("--atol, --rtol and --tolerance set how closely a run must follow its golden trajectory; "
                        "give --golden DIR with them")

    kinds = None
    if controller is not None:
        from twin.registry import parse_controllers

        kinds = parse_controllers(controller)
    from twin.logs.expect import is_log_target, load_log_check, run_log_checks

    logs = [load_log_check(t) for t in targets if is_log_target(t)]  # sensor logs: replays with bounds
    targets = [t for t in targets if not is_log_target(t)]
    scenarios, skipped = collect(targets, _limit_overrides(overrides, step_limit, run_limit, memory_limit)) \
        if targets or not logs else ([], [])
    for f in skipped:
        click.echo(f"  skipped {f}: no [expect] table")
    if not scenarios and not logs:
        raise TwinError("no scenario with an [expect] table to check")
    if logs and (record is not None or golden is not None):
        raise TwinError("--record and --golden are for scenarios' runs; a sensor log's replay has no golden "
                        "trajectory: check logs without them")
    from twin.verify.check import CheckResult

    result = CheckResult([])
    if scenarios:
        bar = _SweepBar("runs")
        try:
            result = run_checks(scenarios, kinds, seeds, workers or default_workers(), progress=bar.update,
                                record=record, golden=golden, tolerances=tolerances)
        except BaseException as exc:
            if record is not None:  # the record's own clause, where it got that far, stands
                rundir.kept(exc, f"nothing recorded: {record} is as it was")
            raise
        finally:
            bar.close()
    if logs:
        t0 = time.perf_counter()
        cases = run_log_checks(logs)
        result.cases += cases
        result.runs += len(cases)
        result.wall_s += time.perf_counter() - t0
    click.echo(format_table(result))
    n_bad = sum(not c.passed for c in result.cases)
    click.echo(f"  {counted(len(result.cases), 'check')} ({counted(result.runs, 'run')}) in {result.wall_s:.1f} s: "
               + ("all bounds hold" if not n_bad else f"{n_bad} failed"))
    if junit is not None:
        click.echo(f"wrote {write_junit(result, junit)}")
    if record is not None:
        click.echo(f"recorded {result.recorded} golden trajectories under {record}")
    for line in failure_lines(result):
        click.echo(line, err=True)
    return 0 if result.passed else 1


@main.command()
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
def calibrate(logs, parameters, held_out, seed, model_kind, out, list_):
    """Calibrate the robot from its sensor logs: its physical parameters, and the twin that runs it.

    LOG is a sensor log (a robot's, or the twin's from 'twin run --log-sensors'); several LOGs of
    one robot are fitted together (shared physical parameters, each log's own IMU constants). Each
    0.1 s window is simulated from its own fitted start state with the log's drive, by the
    robot's continuous equations (RK4 at 1 kHz or more, with its motors), and the parameters that
    make the simulated IMU and encoder readings match the logs' are found by least squares, with
    95 % intervals, correlations and a warning for each parameter the logs do not excite. The
    twin's parameters that reproduce that robot (its stepping differs) go to calibration.toml.
    --validate compares the nominal and the calibrated robot on held-out logs and says whether
    their parameters are the calibrated robot's. Writes report.json, calibration.toml (for 'twin
    run SCENARIO --plant calibration.toml') and figure.png into --out.

    \b
    Examples:
      twin run paper-exp3 --log-sensors --no-video --out runs/exp3
      twin calibrate runs/exp3/sensor-logs/it2 --out runs/calibration
      twin calibrate robot/log1 robot/log2 --validate robot/log3 --out runs/calibration
      twin calibrate runs/exp3/sensor-logs/it2 --parameters m_b,l,n_yb,d_b,d_w --validate runs/exp3b/sensor-logs/it2
      twin run paper-exp3 --plant runs/calibration/calibration.toml
    """
    from twin.calibrate.parameters import NOT_FROM_A_LOG, PARAMETERS, parse_names

    if list_:
        for name, p in PARAMETERS.items():
            if name in NOT_FROM_A_LOG:
                continue
            click.echo(f"  {name:15} {p.unit:10} {p.group:6} {p.doc}")
        for name, why in NOT_FROM_A_LOG.items():
            click.echo(f"  ({name}: {why})")
        return
    from twin.calibrate import identify, output
    from twin.calibrate.robot import same_geometry, to_twin, validate_physical
    from twin.calibrate.run import TURN_RATE, calibrate as fit_logs, model_for
    from twin.calibrate.validate import same_robot, validate
    from twin.logs.format import read_log
    from twin.outputs import report, rundir

    names = parse_names(parameters) if parameters is not None else None
    if not logs:
        raise TwinError("twin calibrate needs a LOG (a sensor log's directory); 'twin calibrate --list' names the "
                        "parameters")
    seen = {}
    for p in logs:  # one log twice would count its information twice
        key = Path(p).resolve()
        if key in seen:
            raise TwinError(f"twin calibrate: the log {p} is given twice (as {seen[key]}); give each log once")
        seen[key] = p
    read = [read_log(p) for p in logs]
    log = read[0]
    for other in read[1:]:
        same_geometry(log, other)
    kind = model_for(read, model_kind)
    held = [read_log(p) for p in held_out]
    for h in held:
        same_robot(log, h) if kind == "twin" else same_geometry(log, h)
    with rundir.written_whole(out, "twin calibrate") as path:
        for lg in read:
            click.echo(f"{lg.path}: {lg.duration:g} s at {lg.control_rate:g} Hz")
        cal = fit_logs(read, names, seed=seed, progress=lambda m: click.echo(f"  {m}"), model=kind)
        params, warnings, corr = identify.assess(cal, TURN_RATE)
        twin = None
        if kind == "physical":
            twin = to_twin(cal, params)
            val = validate_physical(cal, held, progress=lambda m: click.echo(f"  {m}")) if held else None
        else:
            val = validate(cal, held) if held else None
        doc = output.report_doc(cal, params, warnings, corr, output.strip_private(val), seed, twin)
        report.write_json(doc, path / "report.json")
        toml_text = output.calibration_toml(cal, params, twin, geometry=(read[0].model.r, read[0].model.b))
        (path / "calibration.toml").write_text(toml_text, encoding="utf-8")
        output.write_figure(cal, params, val, path / "figure.png")
    click.echo(f"  {'parameter':15}{'value':>13}{'95 % interval':>28}  unit")
    for n, e in params.items():
        lo, hi = e["ci95"]
        mark = "" if e["identifiable"] else "   not identified"
        click.echo(f"  {n:15}{_sig(e['value']):>13}   [{_sig(lo):>11}, {_sig(hi):>11}]  {e['unit']}{mark}")
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
    import tomllib

    limit = tomllib.loads(toml_text)["calibration"].get("twin_why")
    if limit:
        click.echo(f"  warning: the twin cannot run this robot: {limit}; calibration.toml records it, without "
                   f"[plant]")
    if twin is not None and twin["values"] is None:
        click.echo(f"  warning: no twin reproduces this robot: {twin['why']}")
    elif twin is not None:
        tw = twin["values"]
        click.echo(f"  in the twin ({twin['control_rate_hz']:g} Hz control, {twin['physics_rate_hz']:g} Hz physics): "
                   + ", ".join(f"{n} {_sig(tw[n])}" for n in ("m_b", "l", "n_yb", "n_zb", "n_wa"))
                   + f" (trajectory misfit {twin['rms_misfit']['mapped']:.3g}, the robot's own parameters "
                     f"{twin['rms_misfit']['unmapped']:.3g})")
    for line in warnings:
        click.echo(f"  warning: {line}")
    click.echo(f"  {doc['method']['windows']} windows fitted ({len(cal.dropped)} left out), residual σ "
               f"{doc['method']['residual_sigma']:.3g}, {cal.wall_s:.1f} s")
    click.echo(f"wrote {out}/: report.json, calibration.toml, figure.png, {rundir.MANIFEST}")


def _sig(v) -> str:
    return f"{float(v):.5g}"


@main.command("compare")
@click.argument("a", type=click.Path(path_type=Path), metavar="A")
@click.argument("b", type=click.Path(path_type=Path), metavar="B")
@_tolerance_options("the trajectories")
@click.option("--figure", "figure_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              metavar="PATH", help="Write the figure (θ, torque, dψ/dt, distance; A solid, B dashed) as PNG here.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None, metavar="DIR",
              help="Write comparison.png and comparison.json (the report as data) into DIR.")
def compare_(a, b, atol, rtol, tolerance, figure_path, out):
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
    from twin.outputs import compare as cmp

    if figure_path is not None and out is not None:
        raise TwinError("--figure PATH and --out DIR both say where the figure goes; give one of them")
    tolerances = _tolerances(atol, rtol, tolerance)
    from twin.outputs import rundir

    target = rundir.StagedDirectory(out, "twin compare", "comparison") if out is not None else None
    try:
        result = cmp.compare(cmp.load(a), cmp.load(b), tolerances)
        click.echo(cmp.report(result))
        if target is not None:  # written as a unit, with its manifest: a directory of twin compare's
            from twin.outputs.report import write_json

            with rundir.written_whole(out, "twin compare") as path:
                write_json(cmp.as_json(result), path / "comparison.json")
                cmp.figure(result, path / "comparison.png")
            click.echo(f"wrote {out}/: comparison.json, comparison.png, {rundir.MANIFEST}")
        elif figure_path is not None:
            click.echo(f"wrote {cmp.figure(result, figure_path)}")
    finally:
        if target is not None:
            target.close()
    return 0 if result.agree else 1


def _success_table(summary) -> str:
    from twin.registry import label

    width = max([10] + [len(label(s["controller"])) for s in summary])
    lines = [f"  {'level':>7} {'controller':>{width}} {'n':>5} {'success':>8}  {'95 % CI':>15} {'falls':>6} {'errors':>6}"]
    for s in summary:
        lo, hi = s["success_ci"]
        level = "all" if s["level"] is None else f"{s['level']:g}"
        lines.append(f"  {level:>7} {label(s['controller']):>{width}} {s['n']:5d} {s['success_rate']:8.1%}  "
                     f"[{lo:5.1%}, {hi:5.1%}] {s['falls']:6d} {s['errors']:6d}")
    return "\n".join(lines)


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """"1 run", "2 runs": a count with its noun in the right number."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"


def _terminal() -> bool:
    """Whether stderr is a terminal: progress bars are drawn there, and left out of a file or a pipe
    (where click would write each bar's label alone, "  runs", with nothing after it)."""
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


class _SweepBar:
    """Samples (or runs) finished out of those left to run, with the time left, on stderr."""

    def __init__(self, what: str = "samples"):
        self._bar = None
        self.what = what
        self.done = self.total = 0

    def update(self, done: int, total: int) -> None:
        if not _terminal():  # a bar needs a terminal (a CI log would keep only its label): counted, not drawn
            if not self.total:
                self.total = total
            self.done = done
            return
        if self._bar is None:  # the first call gives the samples already finished
            self.done, self.total = done, total
            label = f"  {self.what}" + (f" ({done} done before)" if done else "")
            self._bar = click.progressbar(length=max(total - done, 1), label=label, file=sys.stderr,
                                          show_eta=True, show_pos=True, width=30).__enter__()
        self._bar.update(done - self.done)
        self.done = done

    def close(self) -> None:
        if self._bar is not None:
            self._bar.__exit__(None, None, None)
            self._bar = None


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


class _Progress:
    """A progress bar on stderr over the stages of a run (runs, then the video)."""

    def __init__(self):
        self._bar = None
        self._stage = None
        self._done = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._bar is not None:
            self._bar.__exit__(*exc)

    def update(self, stage: str, done: int, total: int) -> None:
        if not _terminal():  # a bar needs a terminal; a CI log would keep only its label
            return
        if stage != self._stage:
            if self._bar is not None:
                self._bar.__exit__(None, None, None)
            self._bar = click.progressbar(length=max(total, 1), label=f"  {stage:8}", file=sys.stderr,
                                          show_eta=True, width=30).__enter__()
            self._stage, self._done = stage, 0
        self._bar.update(done - self._done)
        self._done = done


def copy_text(text: str) -> str:
    """A built-in scenario's TOML as ``twin scenarios NAME`` prints it to copy: its ``name`` line
    commented out, so that a copy takes its file's name (``my-exp2.toml`` runs as ``my-exp2``, into
    ``runs/my-exp2``) instead of replacing the built-in's results in ``runs/NAME``."""
    import re

    return re.sub(r'^name\s*=\s*(.*)$', lambda m: f"# name = {m.group(1)}   (a copy takes its file's name: "
                  f"my-copy.toml runs as my-copy, into runs/my-copy)", text, count=1, flags=re.M)


@main.command()
@click.argument("name", required=False)
def scenarios(name):
    """List the built-in scenarios, a line each; with NAME, print that one's TOML to copy and edit.

    \b
    Examples:
      twin scenarios
      twin scenarios paper-exp2 > my-exp2.toml
      twin run slope-payload --controller both
    """
    from twin.scenarios import builtin_scenarios

    if name is not None:
        from importlib import resources

        from twin.scenarios.scenario import BUILTIN_PACKAGE, builtin_names

        if name not in builtin_names():
            raise TwinError(f"no built-in scenario {name!r}; built-ins: {', '.join(builtin_names())}")
        text = resources.files(BUILTIN_PACKAGE).joinpath(f"{name}.toml").read_text(encoding="utf-8")
        click.echo(copy_text(text), nl=False)
        return
    items = builtin_scenarios()
    width = max(map(len, items))
    for name, description in items.items():
        click.echo(f"{name:{width}}  {description}")


@main.command()
def kinds():
    """List the built-in controller, estimator and plant kinds (any 'package.module:attribute' works too).

    \b
    Examples:
      twin kinds
      twin run paper-exp2 --controller it2,lqr
    """
    from twin.registry import CONTROLLERS, ESTIMATORS, PLANTS

    for title, table in (("controllers (--controller, controller.kinds)", CONTROLLERS),
                         ("estimators (sensors.estimator)", ESTIMATORS), ("plants (plant.model)", PLANTS)):
        click.echo(title)
        width = max(map(len, table))
        for name, kind in table.items():
            click.echo(f"  {name:{width}}  {kind.description}")
    click.echo("your own: package.module:attribute, a class or factory (see docs/howto/plugins.md)")


@main.command()
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
    import numpy as np

    from twin.outputs import report
    from twin.controllers import mamdani

    from twin.outputs.rundir import FileBatch

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


if __name__ == "__main__":  # pragma: no cover
    main()
