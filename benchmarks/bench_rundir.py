"""What writing a run directory as a unit costs ``twin run`` (issue 26: at most 2 % wall time).

Run from the repository root::

    python benchmarks/bench_rundir.py            # paper-exp3, 15 s: about 6 min
    python benchmarks/bench_rundir.py --quick    # 3 s runs, fewer rounds: about 1 min

Side by side, in one process, rounds interleaved (A B, B A, A B, ...: a machine that slows
down or speeds up meanwhile weighs on both alike), each ``run_scenario`` writing into the
same directory again, so that every round but the first replaces an earlier run:

* **unit** – as ``twin run`` writes now (:class:`twin.outputs.rundir.StagedDirectory`): the outputs
  into a staging directory beside the target, ``manifest.json`` last (every file's size and
  SHA-256), then the exchange with the target and the earlier run's removal;
* **direct** – the outputs written straight into the target as before issue 26 (the same
  runner, the staging replaced by the target itself, no manifest, no exchange).

Without video and with it (both controllers, 640×480 each). Reported: the median wall time
of each, their difference as a fraction of the direct one, and the commit's own time
(manifest, lock, exchange, removal), timed inside the unit rounds: the part of the
difference that is not noise (with making the staging: "own ms"). Medians, as the machine
may be shared.
"""
from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model, pybullet_version  # noqa: E402


class _Direct:
    """The writing before issue 26: into the target itself, nothing staged, no manifest."""

    def __init__(self, target, command, what="run"):
        self.shown = self.target = Path(target)
        self.committed = False
        self.started = True

    @property
    def path(self):
        self.target.mkdir(parents=True, exist_ok=True)
        return self.target

    def commit(self, exit_status=0, missing=(), stopped=None):
        self.committed = True
        return []

    def discard(self):
        pass

    def unchanged(self):
        return ""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 s runs, fewer rounds")
    ap.add_argument("--rounds", type=int, default=None, help="rounds per variant (default 7, --quick 3)")
    args = ap.parse_args(argv)
    from twin.outputs import rundir
    from twin.scenarios import load_scenario
    from twin.scenarios import runner

    rounds = args.rounds or (3 if args.quick else 7)
    sc = load_scenario("paper-exp3", ["duration=3"] if args.quick else [])
    sc.design()  # solved (or taken from the cache) once, before anything is timed
    staged_class = rundir.StagedDirectory
    commits = []

    class _Timed(staged_class):
        """The unit's own work timed: making the staging (the first use of ``path``) and the commit."""

        @property
        def path(self):
            if self.started:
                return super().path
            t0 = pc()
            try:
                return super().path
            finally:
                commits.append(pc() - t0)

        def commit(self, *a, **k):
            t0 = pc()
            try:
                return super().commit(*a, **k)
            finally:
                commits[-1] += pc() - t0

    print("twin run's outputs written as a unit (staging, manifest, exchange) against written in place")
    print(f"machine: {cpu_model()}; Python {sys.version.split()[0]}; PyBullet {pybullet_version()}")
    print(f"scenario {sc.name}: {sc.duration:g} s, controllers {', '.join(sc.controllers)}; {rounds} rounds per "
          f"variant, interleaved, after a warm-up of each\n")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for video in (False, True):
            times = {"unit": [], "direct": []}
            commits.clear()
            sizes = None
            for r in range(rounds + 1):  # round 0 warms up (imports, the figure worker, the encoder)
                order = ("unit", "direct") if r % 2 == 0 else ("direct", "unit")
                for variant in order:
                    runner.rundir.StagedDirectory = _Timed if variant == "unit" else _Direct
                    target = Path(tmp) / f"{variant}-{int(video)}"
                    try:
                        t0 = pc()
                        runner.run_scenario(sc, out=target, video=video)
                        wall = pc() - t0
                    finally:
                        runner.rundir.StagedDirectory = staged_class
                    if r:
                        times[variant].append(wall)
                    elif variant == "unit":
                        commits.clear()
                if sizes is None:
                    sizes = sum(p.stat().st_size for p in (Path(tmp) / f"unit-{int(video)}").iterdir())
            for d in Path(tmp).iterdir():
                shutil.rmtree(d)
            med = statistics.median
            unit, direct = med(times["unit"]), med(times["direct"])
            rows.append((("with" if video else "no") + " video", direct, unit, (unit - direct) / direct,
                         med(commits), med(commits) / direct, sizes, times))
    print(f"{'twin run':12}{'direct s':>10}{'unit s':>10}{'difference':>12}{'own ms':>9}{'own share':>11}"
          f"{'MB written':>12}")
    for name, direct, unit, diff, commit, share, size, _ in rows:
        print(f"{name:12}{direct:10.3f}{unit:10.3f}{diff:+11.2%}{commit * 1e3:9.1f}{share:11.2%}{size / 1e6:12.2f}")
    print("\nper round (s): " + "; ".join(
        f"{name}: direct {', '.join(f'{t:.2f}' for t in times['direct'])} / unit "
        f"{', '.join(f'{t:.2f}' for t in times['unit'])}" for name, *_, times in rows))
    worst = max(max(r[3], r[5]) for r in rows)
    print(f"target: at most 2 % of the wall time ({'met' if worst <= 0.02 else 'not met'}: the larger of the medians' "
          f"difference and the unit's own share is {worst:.2%})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
