"""Whole-process wall time of a short ``twin run`` against real time (issue 17, item 5).

Run from the repository root::

    python benchmarks/bench_startup.py             # 5 rounds, about 30 s
    python benchmarks/bench_startup.py --rounds 9

What is measured, each a fresh process started from this one, rounds interleaved:

* **twin run** – ``python -m twin.cli run paper-exp3 --duration 20 --no-video --controller
  it2`` with a warm LMI design cache (a private one, filled by a first, cold run that is
  reported apart): all of its outputs (metrics.json, trajectory.csv, design.json,
  figure.png) written before it exits, as a user runs it (the figure drawn by a worker
  process where a CPU is free for it, started before the scenario loads, in two processes
  that each draw half of the figure's rows once the runs end). The target is 18× real time,
  ≤ 1.11 s for 20 s.
* the same with ``TWIN_FIGURE_WORKER=1`` (the worker, whatever the load) and ``=0`` (the
  figure drawn in the process itself, after the rest: what the worker saves);
* **references in the same run**: ``python -c pass`` (the interpreter), ``python -c
  "import twin.cli"`` (the command line's imports), and the simulation alone, as the run
  prints it ("simulated 20 s in … s": the loop, from building the twin to the logged run),
  with the worker importing matplotlib on the other CPU meanwhile and without.

Wall times are medians over the rounds (min–max beside them), with the CPU time (user +
sys, of the process and its children) of the twin run; the machine's load average is
printed, since other work on the machine slows every row.
"""
from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from time import perf_counter as pc

ROOT = Path(__file__).resolve().parent.parent
DURATION = 20.0  # s simulated
TARGET = 18.0  # × real time


def _child_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _timed(cmd, env, cwd) -> tuple[float, float, str]:
    """(wall s, CPU s, stdout) of one process."""
    cpu0, t0 = _child_cpu(), pc()
    r = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True)
    wall, cpu = pc() - t0, _child_cpu() - cpu0
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stderr}")
    return wall, cpu, r.stdout


def _sim_time(stdout: str) -> float:
    m = re.search(r"simulated [0-9.]+ s in ([0-9.]+) s", stdout)
    return float(m.group(1)) if m else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="timed rounds (default 5)")
    args = ap.parse_args(argv)
    py = sys.executable
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp:
        env = {**os.environ, "PYTHONPATH": str(ROOT), "TWIN_CACHE_DIR": str(Path(tmp) / "cache")}
        env.pop("TWIN_FIGURE_WORKER", None)
        # bytecode cached as after an install (without it every process compiles the
        # project's modules again, about 0.1 s here)
        no_pyc = env.pop("PYTHONDONTWRITEBYTECODE", None)
        run = [py, "-m", "twin.cli", "run", "paper-exp3", "--duration", f"{DURATION:g}", "--no-video",
               "--controller", "it2", "--out", str(Path(tmp) / "out")]
        cases = {
            "twin run (as a user runs it)": (run, env),
            "twin run, worker forced": (run, {**env, "TWIN_FIGURE_WORKER": "1"}),
            "twin run, figure drawn in-process": (run, {**env, "TWIN_FIGURE_WORKER": "0"}),
            "python -c pass": ([py, "-c", "pass"], env),
            "python -c 'import twin.cli'": ([py, "-c", "import twin.cli"], env),
        }
        print(f"whole-process wall time of a {DURATION:g} s twin run without video, against real time")
        print(f"Python {sys.version.split()[0]}; {os.cpu_count()} CPUs; load average before "
              f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}")
        cold, _, _ = _timed(run, env, tmp)  # fills the design cache
        print(f"first run (cold design cache: the LMI solved, cvxpy imported): {cold:.2f} s"
              + ("; PYTHONDONTWRITEBYTECODE unset for the runs" if no_pyc else "") + "\n")
        walls = {k: [] for k in cases}
        cpus = []
        sims = {"simulation alone, beside the worker": [], "simulation alone, figure in-process": []}
        for _ in range(args.rounds):
            for name, (cmd, e) in cases.items():
                wall, cpu, out = _timed(cmd, e, tmp)
                walls[name].append(wall)
                if name.startswith("twin run (as"):
                    cpus.append(cpu)
                elif name.endswith("forced"):
                    sims["simulation alone, beside the worker"].append(_sim_time(out))
                elif name.endswith("in-process"):
                    sims["simulation alone, figure in-process"].append(_sim_time(out))
        med = statistics.median
        print(f"{'process':40}{'wall s (median)':>17}{'min–max':>14}{'× real time':>13}")
        for name, w in {**walls, **sims}.items():
            rtf = f"{DURATION / med(w):12.1f}×" if name.startswith(("twin run", "simulation")) else ""
            print(f"{name:40}{med(w):17.3f}{min(w):7.3f}–{max(w):.3f}{rtf:>13}")
        w = med(walls["twin run (as a user runs it)"])
        print(f"\ntwin run: CPU (user + sys, worker included) {med(cpus):.2f} s; "
              f"{args.rounds} rounds; load average after {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
        print(f"real-time factor {DURATION / w:.1f} (target ≥ {TARGET:g}, i.e. ≤ {DURATION / TARGET:.2f} s: "
              f"{'met' if DURATION / w >= TARGET else 'missed'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
