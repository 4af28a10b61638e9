"""``twin check``: scenarios and sensor logs against their bounds (:mod:`twin.workflows.check`),
each bound printed with the value measured; exit status 0 if all hold, 1 if any fails."""
from __future__ import annotations

from pathlib import Path

import click

from twin.commands.common import (Once, SweepBar, complete_kinds, complete_scenario, contained, counted,
                                  limit_options, limit_overrides, robot_option, with_robot, tolerance_options, tolerances)
from twin.verify.check import failure_lines, format_table, write_junit
from twin.workflows.check import check


@click.command("check", cls=Once)
@click.argument("targets", nargs=-1, metavar="SCENARIO|FILE|DIR...", shell_complete=complete_scenario)
@click.option("--controller", default=None, metavar="KINDS", shell_complete=complete_kinds,
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
@tolerance_options("the golden trajectories (with --golden)")
@limit_options(" in every scenario checked")
@robot_option("every scenario runs")
@contained
def check_command(targets, controller, seeds, workers, overrides, junit, record, golden, atol, rtol, tolerance, step_limit,
          run_limit, memory_limit, robot):
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
    bar = SweepBar("runs")
    try:
        result = check(targets, controller, seeds, workers, with_robot(limit_overrides(overrides, step_limit, run_limit,
                       memory_limit), robot), record, golden, tolerances(atol, rtol, tolerance), bar.update,
                       lambda f: click.echo(f"  skipped {f}: no [expect] table"))
    finally:
        bar.close()
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
