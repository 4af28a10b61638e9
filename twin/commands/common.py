"""What several ``twin`` commands share: the command class that refuses an option given twice,
shell completion, the options of limits, tolerances and the design cache, progress bars on
stderr, and how numbers and counts are printed."""
from __future__ import annotations

import sys
import tomllib

import click
from click.shell_completion import CompletionItem

from twin.errors import TwinError
from twin.outputs.tolerances import parse_options


class Once(click.Command):
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



def complete_scenario(ctx, param, incomplete: str):
    """Shell completion of SCENARIO: the built-ins' names, then .toml files and folders."""
    from twin.scenarios import builtin_scenarios  # only when the shell asks: the scenarios' modules load NumPy

    items = [CompletionItem(n, help=d) for n, d in builtin_scenarios().items() if n.startswith(incomplete)]
    return items + [CompletionItem(incomplete, type="file")]


def complete_kinds(ctx, param, incomplete: str):
    """Shell completion of --controller: the registry's kinds (and "both"), after any
    comma-separated ones already typed."""
    from twin.registry import CONTROLLERS  # only when the shell asks: the registry loads NumPy

    head, _, last = incomplete.rpartition(",")
    prefix = head + "," if head else ""
    return [CompletionItem(prefix + k) for k in (*CONTROLLERS, *(() if head else ("both",))) if k.startswith(last)]



def no_cache_option(f):
    """--no-cache: solve the LMI design even if the design cache has it, and do not store it."""
    def disable(ctx, param, value):
        if value:
            from twin.controllers import design_cache  # only with --no-cache: the controllers' modules load NumPy

            design_cache.set_enabled(False)
        return value
    return click.option("--no-cache", is_flag=True, callback=disable, expose_value=True,
                        help="Solve the LMI design anew instead of taking it from the design cache "
                             "(see 'twin cache'), and do not store it.")(f)



def tolerance_options(what: str):
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


def tolerances(atol, rtol, items):
    """--atol, --rtol and --tolerance as a :class:`twin.outputs.tolerances.Tolerances`."""
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


def contained(f):
    """Put :data:`CONTAINED` (what the worker processes contain) in the command's help, where the
    docstring says {CONTAINED}: one text for twin run, sweep and check."""
    f.__doc__ = f.__doc__.replace("{CONTAINED}", CONTAINED)
    return f


def limit_options(where: str, run_default: str = ""):
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


def robot_option(what: str):
    """``--robot NAME|FILE``: the robot ``what`` runs (the scenarios' ``robot`` key)."""
    return click.option("--robot", default=None, metavar="NAME|FILE",
                        help=f"The robot {what}: a built-in's name ('twin robots') or a robot file (robot.toml); "
                             f"sets the scenario's robot key (not with --set robot=...).")


def with_robot(overrides, robot: str | None) -> tuple:
    """``overrides`` (the --set items), after ``robot=...`` if ``--robot`` was given; one line if
    ``--set robot=...`` is given too. A file is named by its absolute path (a worker process, or a
    scenario file elsewhere, finds it all the same)."""
    overrides = tuple(overrides)
    if robot is None:
        return overrides
    if any(str(o).partition("=")[0].strip() == "robot" for o in overrides):
        raise TwinError("--robot and --set robot=... both name the robot; give one of them")
    from twin.robots import robot_item  # only with --robot: the listings and cache commands need no robots

    return (robot_item(robot),) + overrides


def limit_overrides(overrides, step_limit, run_limit, memory_limit) -> tuple:
    """``overrides`` (the --set items) followed by ``limits.KEY=V`` for each limit option
    given, validated like the scenario key; an option and a --set of the same key are refused."""
    given = {"step_limit": step_limit, "run_limit": run_limit, "memory_limit": memory_limit}
    if all(v is None for v in given.values()):
        return tuple(overrides)
    # only with a limit option: the scenarios' modules load NumPy
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
            if name == f"limits.{key}" or (name == "limits" and key in inline_table(rest)):
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


def inline_table(text: str) -> dict:
    """The keys of ``--set limits={...}``'s value, or {} if it is not a table."""

    try:
        value = tomllib.loads(f"v = {text.strip()}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}



def counted(n: int, noun: str, plural: str | None = None) -> str:
    """"1 run", "2 runs": a count with its noun in the right number."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"


def terminal() -> bool:
    """Whether stderr is a terminal: progress bars are drawn there, and left out of a file or a pipe
    (where click would write each bar's label alone, "  runs", with nothing after it)."""
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


class SweepBar:
    """Samples (or runs) finished out of those left to run, with the time left, on stderr."""

    def __init__(self, what: str = "samples"):
        self._bar = None
        self.what = what
        self.done = self.total = 0

    def update(self, done: int, total: int) -> None:
        if not terminal():  # a bar needs a terminal (a CI log would keep only its label): counted, not drawn
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


def fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


class Progress:
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
        if not terminal():  # a bar needs a terminal; a CI log would keep only its label
            return
        if stage != self._stage:
            if self._bar is not None:
                self._bar.__exit__(None, None, None)
            self._bar = click.progressbar(length=max(total, 1), label=f"  {stage:8}", file=sys.stderr,
                                          show_eta=True, width=30).__enter__()
            self._stage, self._done = stage, 0
        self._bar.update(done - self._done)
        self._done = done


def echo_plugins(plugins) -> None:
    """One line per plugin a run loads: its role, kind, file and SHA-256."""
    for p in plugins:
        click.echo(f"  plugin {p['role']} {p['kind']}: {p['file']} (sha256 {(p['sha256'] or '?')[:12]})")


def sig(v) -> str:
    """A number with 5 significant digits."""
    return f"{float(v):.5g}"
