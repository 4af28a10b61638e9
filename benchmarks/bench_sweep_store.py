"""What a sweep's checks and seal cost ``twin sweep`` (issue 26: at most 2 % wall time).

Run from the repository root::

    python benchmarks/bench_sweep_store.py            # 32 samples of paper-exp3 (5 s): about 1 min
    python benchmarks/bench_sweep_store.py --quick    # 8 samples of 2 s runs: about 20 s

Side by side, in one process, rounds interleaved (A B, B A, ...: a machine that slows down
or speeds up meanwhile weighs on both alike), each a whole ``run_sweep`` into a fresh
folder with the local backend and 2 workers:

* **checked** – as ``twin sweep`` runs now: the folder locked, the configuration hashed and
  stamped on every stored sample, the earlier report removed, each controller's run under
  the sweep's default wall-time limit (two clock reads per control step in the workers),
  and ``manifest.json`` written last (every file's SHA-256);
* **bare** – the same sweep without those: no lock, no limit (no clock reads), no
  manifest. The configuration hash stays (it is part of the records' format), but is
  timed in the checked rounds with the rest of the store's own work.

Reported: the median wall time of each, their difference as a fraction of the bare one,
and the store's own time in the checked rounds (opening: lock, hash, reading; the seal),
the part of the difference that is not noise. Medians, as the machine may be shared.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import statistics
import sys
import tempfile
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model, pybullet_version  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="8 samples of 2 s runs, fewer rounds")
    ap.add_argument("--rounds", type=int, default=None, help="rounds per variant (default 3, --quick 2)")
    args = ap.parse_args(argv)
    from twin.outputs import rundir
    from twin.scenarios import load_scenario
    from twin.sweep import runner, store

    rounds = args.rounds or (2 if args.quick else 3)
    levels = "[0.0, 0.2, 0.4, 0.6]"
    sc = load_scenario("paper-exp3", [f"sweep.levels={levels}", "duration=2.0" if args.quick else "duration=5.0"])
    draws = 2 if args.quick else 8
    sc.design()  # solved (or taken from the cache) once, before anything is timed
    own = []

    real_store, real_seal, real_sweep_data = store.SweepStore, rundir.seal, runner.sweep_data

    class TimedStore(real_store):
        def __init__(self, *a, **k):
            t0 = pc()
            super().__init__(*a, **k)
            own.append(pc() - t0)

    def timed_seal(*a, **k):
        t0 = pc()
        try:
            return real_seal(*a, **k)
        finally:
            own[-1] += pc() - t0

    class BareStore(real_store):
        def __init__(self, out, manifest):  # no lock: the rest as it is
            self.out = Path(out)
            self.out.mkdir(parents=True, exist_ok=True)  # what the lock did
            self._fd = None
            self._held = contextlib.ExitStack()
            self._open(manifest)

    def variant(name):
        if name == "checked":
            runner.SweepStore, rundir.seal, runner.sweep_data = TimedStore, timed_seal, real_sweep_data
        else:
            runner.SweepStore, rundir.seal, runner.sweep_data = BareStore, lambda *a, **k: {}, lambda d: d

    n = draws * 4
    print("twin sweep with its checks (lock, configuration hash, default run limit, manifest) against without")
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores; Python {sys.version.split()[0]}; "
          f"PyBullet {pybullet_version()}")
    print(f"scenario {sc.name}: {sc.duration:g} s, controllers {', '.join(sc.controllers)}; {n} samples "
          f"({draws} draws × 4 levels), local backend, 2 workers; {rounds} rounds per variant, interleaved, after a "
          f"warm-up of each\n")
    times = {"checked": [], "bare": []}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(rounds + 1):  # round 0 warms up (imports, the page cache)
                order = ("checked", "bare") if r % 2 == 0 else ("bare", "checked")
                for name in order:
                    variant(name)
                    out = Path(tmp) / name
                    shutil.rmtree(out, ignore_errors=True)
                    t0 = pc()
                    runner.run_sweep(sc, draws, out, workers=2)
                    wall = pc() - t0
                    if r:
                        times[name].append(wall)
                    elif name == "checked":
                        own.clear()
                    assert (name == "checked") == (out / rundir.MANIFEST).exists()
    finally:
        runner.SweepStore, rundir.seal, runner.sweep_data = real_store, real_seal, real_sweep_data
    med = statistics.median
    checked, bare = med(times["checked"]), med(times["bare"])
    diff, share = (checked - bare) / bare, med(own) / bare
    print(f"{'twin sweep':12}{'bare s':>10}{'checked s':>11}{'difference':>12}{'own ms':>9}{'own share':>11}")
    print(f"{n} samples{'':2}{bare:10.2f}{checked:11.2f}{diff:+11.2%}{med(own) * 1e3:9.1f}{share:11.2%}")
    print("\nper round (s): bare " + ", ".join(f"{t:.2f}" for t in times["bare"]) + " / checked "
          + ", ".join(f"{t:.2f}" for t in times["checked"]))
    worst = max(diff, share)
    print(f"target: at most 2 % of the wall time ({'met' if worst <= 0.02 else 'not met'}: the larger of the medians' "
          f"difference and the store's own share is {worst:.2%})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
