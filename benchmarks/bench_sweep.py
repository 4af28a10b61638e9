"""Sweep throughput: samples per minute, and the speed-up from 1 to 2 local workers.

Run from the repository root::

    python benchmarks/bench_sweep.py            # about 2 minutes on 2 cores
    python benchmarks/bench_sweep.py --quick    # about 30 s

Every configuration runs the same samples of ``paper-exp3`` (15 s simulated, IT2 and
type-1 on each sample, so two closed-loop runs per sample; ``--quick``: 5 s):

* **in-process** – ``run_sample`` called in a loop in this process: the reference, what
  one core does with no backend at all;
* **local, 1 worker** and **local, 2 workers** – the local backend (spawned worker
  processes, start-up included); their ratio is the speed-up (target ≥ 1.7× on 2 cores);
* **ray, 2 CPUs** – the Ray backend on a local Ray instance (start-up included), if Ray
  is installed.

Samples per minute are wall-clock figures; the sweep's report (``sweep.csv``, summary,
figures) is written once at the end and timed separately.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model, pybullet_version  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run")
    ap.add_argument("--samples", type=int, default=None, help="samples per configuration (default 32, quick 12)")
    args = ap.parse_args(argv)
    from twin.scenarios import load_scenario
    from twin.sweep.backends import run_local, run_ray
    from twin.sweep.runner import write_report
    from twin.sweep.worker import SweepJob, run_sample

    n = args.samples or (12 if args.quick else 32)
    sc = load_scenario("paper-exp3", ["duration=5.0"] if args.quick else [])
    job = SweepJob(sc.data, sc.source, sc.overrides, sc.seed, sc.design())
    samples = list(range(n))
    print("sweep throughput: samples per minute (one sample = an IT2 and a type-1 run)")
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores; Python {sys.version.split()[0]}; "
          f"PyBullet {pybullet_version()}")
    print(f"scenario {sc.name}, {sc.duration:g} s simulated per run, {n} samples per configuration, levels "
          f"{', '.join(f'{v:g}' for v in sc.data['sweep']['levels'])}\n")

    results = {}

    def measure(name, fn):
        records = []
        t0 = pc()
        fn(records.append)
        wall = pc() - t0
        results[name] = (wall, sorted(records, key=lambda r: r["sample"]))
        print(f"  {name:22} {wall:7.1f} s   {60 * n / wall:7.1f} samples/min")

    measure("in-process (reference)", lambda put: [put(run_sample(job, k)) for k in samples])
    measure("local, 1 worker", lambda put: run_local(job, samples, 1, put))
    measure("local, 2 workers", lambda put: run_local(job, samples, 2, put))
    try:
        import ray  # noqa: F401
        measure("ray, 2 CPUs", lambda put: run_ray(job, samples, 2, put))
    except ImportError:
        print("  ray, 2 CPUs: Ray is not installed (pip install '.[ray]')")
    speedup = results["local, 1 worker"][0] / results["local, 2 workers"][0]
    print(f"\n  speed-up from 1 to 2 local workers: {speedup:.2f}× (target ≥ 1.7×)")
    runs = [r for _, recs in results.values() for r in recs]
    per_sample = sorted(r["wall_s"] for r in results["in-process (reference)"][1])
    print(f"  one sample in process: median {per_sample[len(per_sample) // 2]:.2f} s")
    ref = [{k: v for k, v in r.items() if k != "wall_s"} for r in results["in-process (reference)"][1]]
    same = all([{k: v for k, v in r.items() if k != "wall_s"} for r in recs] == ref for _, recs in results.values())
    print(f"  every configuration gave identical records: {same}")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = pc()
        write_report(Path(tmp), {"source": sc.source, "draws": n // len(sc.data["sweep"]["levels"]),
                                 "root_seed": sc.seed, "overrides": [], "scenario_arg": sc.name,
                                 "controllers": list(job.controllers), "scenario": sc.data},
                     results["in-process (reference)"][1], sc)
        print(f"  the report of {n} samples (sweep.csv, summary, 3 figures): {pc() - t0:.1f} s")
    return 0 if same and runs else 1


if __name__ == "__main__":
    sys.exit(main())
