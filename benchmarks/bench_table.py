"""The documentation's benchmark page (docs/_generated/benchmarks.md): the ``bench_*.py`` scripts
run on this machine, their reports as they print them.

Run from the repository root (the default set takes a few minutes on 2 cores)::

    python benchmarks/bench_table.py --markdown docs/_generated/benchmarks.md
    python benchmarks/bench_table.py --markdown OUT.md --run bench_twin --run bench_lmi

Every script of :data:`SCRIPTS` is listed with what it measures (its docstring's first
sentence); those in the chosen set (``--run``, repeatable; default :data:`DEFAULT`, the ones
that take about a minute or less) are run, one after the other, each in a process of its own, and
their output is written under the page's header line (command, machine, date, commit; see
``benchmarks/published.py``). The others are named by the command that measures them, with how
long it takes: no figure on the page is typed by hand.
"""
from __future__ import annotations

import argparse
import ast
import re
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from published import as_text_block, write_markdown  # noqa: E402

# (script, extra arguments, how long it takes on 2 cores) in the page's order
SCRIPTS = [
    ("bench_fuzzy", [], "a few seconds; pyit2fls, the reference, needs `pip install '.[bench]'`"),
    ("bench_lmi", [], "about 30 s"),
    ("bench_design_cost", [], "about 1 min"),
    ("bench_twin", [], "about 10 s"),
    ("bench_estimator", [], "about 20 s"),
    ("bench_run", [], "about 20 s"),
    ("bench_consistency", [], "about 30 s"),
    ("bench_startup", [], "about 30 s"),
    ("bench_replay", [], "about 20 s"),
    ("bench_replay_memory", [], "about 5 min"),
    ("bench_containment", [], "about 1 min"),
    ("bench_gym", [], "about 30 s; needs the gym extra"),
    ("bench_fastpath", [], "about 1 min"),
    ("bench_check", [], "about 1 min"),
    ("bench_calibrate", [], "about 3 min"),
    ("bench_render", [], "about 1 min; needs EGL for the fast renderer"),
    ("bench_sweep", [], "about 2 min"),
    ("bench_sweep_store", [], "about 1 min"),
    ("bench_rundir", [], "about 6 min"),
    ("bench_memory", [], "about 20 min"),
]
DEFAULT = ("bench_fuzzy", "bench_lmi", "bench_design_cost", "bench_twin", "bench_estimator", "bench_run", "bench_consistency",
           "bench_startup", "bench_replay", "bench_gym", "bench_fastpath", "bench_check")
TIMEOUT_S = 900


def summary(script: str) -> str:
    """The first sentence of the script's docstring, on one line."""
    doc = ast.get_docstring(ast.parse((HERE / f"{script}.py").read_text(encoding="utf-8"))) or ""
    first = " ".join(doc.split("\n\n")[0].split())
    first = re.sub(r"\s*\((issue \d+[^)]*)\)|\s*\(issue \d+, ([^)]*)\)", "", first)  # the page is for users
    first = re.sub(r"\(issue \d+: ([^)]*)\)", r"(\1)", first)
    return first.replace("|", "\\|")


def command(script: str, extra: list[str]) -> str:
    return " ".join(["python", f"benchmarks/{script}.py", *extra])


def run(script: str, extra: list[str]) -> tuple[str, float, int]:
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, str(HERE / f"{script}.py"), *extra], cwd=ROOT, capture_output=True,
                           text=True, timeout=TIMEOUT_S)
        out, status = r.stdout + ("" if r.returncode == 0 else "\n" + r.stderr[-3000:]), r.returncode
    except subprocess.TimeoutExpired:
        out, status = f"(stopped after {TIMEOUT_S} s)", -1
    return out, time.perf_counter() - t0, status


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", action="append", choices=[s for s, *_ in SCRIPTS],
                    help=f"run this script (repeatable; default: {', '.join(DEFAULT)})")
    ap.add_argument("--markdown", metavar="PATH", required=True, help="the page to write (docs/_generated/...)")
    a = ap.parse_args(argv)
    chosen = set(a.run or DEFAULT)
    rows = ["| script | what it measures | on this page |", "|---|---|---|"]
    sections = []
    failed = 0
    for script, extra, cost in SCRIPTS:
        cmd = command(script, extra)
        if script not in chosen:
            rows.append(f"| `{script}.py` | {summary(script)} | not measured here: run `{cmd}` ({cost}) |")
            continue
        print(f"running {cmd} ...", file=sys.stderr, flush=True)
        out, wall, status = run(script, extra)
        failed += status != 0
        anchor = script + "py"  # MyST's slug of the heading "NAME.py"
        verdict = "below" if status == 0 else f"below: **exited with status {status}**"
        rows.append(f"| `{script}.py` | {summary(script)} | [{verdict}](#{anchor}) |")
        sections.append(f"## {script}.py\n\n`{cmd}`, {wall:.0f} s wall time"
                        + ("" if status == 0 else f", **exit status {status}**") + ":\n\n" + as_text_block(out))
    write_markdown(a.markdown, "\n".join(rows) + "\n\n" + "\n\n".join(sections), argv=argv and [sys.argv[0], *argv])
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
