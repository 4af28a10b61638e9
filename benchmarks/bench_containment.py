"""What running a user's plugin in a contained worker process costs, side by side with running it in
the caller's process.

Run from the repository root::

    python benchmarks/bench_containment.py                  # about 1 min
    python benchmarks/bench_containment.py --markdown docs/_generated/containment.md

What is measured, in one process, rounds interleaved (round 0 warms up and is dropped), with the
example controller and estimator of ``examples/my_plugins.py`` on ``paper-exp3``:

* **a run** – ``run_scenario(scenario, [plugin])``, nothing written: in this process
  (``contained=False``, as the Python API does) against in a worker (``contained=True``, as
  ``twin run``, ``twin sweep`` and ``twin check`` do), for a short (1 s) and a long (15 s) run; the
  worker's column includes starting the worker (it imports the twin), planning (building the
  plugins) and sending the run back;
* **a control period** – (15 s run − 1 s run) / the control steps between them, in each place:
  what the watched loop adds per step (its shared status, written around each plugin call),
  the worker's start-up cancelled.

The two columns give byte-identical runs (``tests/test_containment.py``); only the time differs.
"""
from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
from pathlib import Path
from time import perf_counter as pc

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from published import as_text_block, cpu_model, write_markdown  # noqa: E402


def measure(rounds: int) -> list[tuple[str, float, float]]:
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    kinds = ["my_plugins:StateFeedback"]
    est = ["sensors.estimator='my_plugins:TiltFilter'"]
    cases = {"1 s run": load_scenario("paper-exp3", ["duration=1", *est]),
             "15 s run": load_scenario("paper-exp3", ["duration=15", *est])}
    times = {(name, where): [] for name in cases for where in ("here", "worker")}
    steps = {}
    for r in range(rounds + 1):
        for name, sc in cases.items():
            for where in ("here", "worker"):
                t0 = pc()
                result = run_scenario(sc, kinds, contained=where == "worker")
                if r:
                    times[(name, where)].append(pc() - t0)
                steps[name] = result.runs[0].control_steps
    rows = []
    for name in cases:
        here, there = (statistics.median(times[(name, w)]) for w in ("here", "worker"))
        rows.append((name, here, there))
    # per control step: the 15 s run less the 1 s run, over the steps between them (the start-up cancels)
    extra = steps["15 s run"] - steps["1 s run"]
    rows.append(("per control step, µs", (rows[1][1] - rows[0][1]) / extra * 1e6,
                 (rows[1][2] - rows[0][2]) / extra * 1e6))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="measured rounds (after one warm-up)")
    ap.add_argument("--markdown", type=Path, default=None, metavar="PATH",
                    help="also write the table as Markdown to PATH (e.g. docs/_generated/containment.md)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copy(HERE.parent / "examples" / "my_plugins.py", Path(tmp) / "my_plugins.py")
        sys.path.insert(0, tmp)
        rows = measure(args.rounds)
    lines = [f"a plugin's run in this process and in a contained worker (twin.containment)",
             f"machine: {cpu_model()}; Python {sys.version.split()[0]}; {args.rounds} rounds after a warm-up, medians",
             "",
             f"{'what':36}{'in this process':>18}{'in a worker':>14}{'difference':>14}"]
    for name, here, there in rows:
        unit = "" if "µs" in name else " s"
        lines.append(f"{name:36}{here:>16.3g}{unit:2}{there:>12.3g}{unit:2}{there - here:>+12.3g}{unit:2}")
    text = "\n".join(lines)
    print(text)
    if args.markdown is not None:
        write_markdown(args.markdown, as_text_block(text), sys.argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
