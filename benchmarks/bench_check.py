"""'twin check' of every built-in: wall time on 1 and 2 workers, and the time per check
beyond the simulation itself.

Run from the repository root::

    python benchmarks/bench_check.py            # about 1 minute on 2 cores
    python benchmarks/bench_check.py --quick    # about 20 s (5 s runs)
    python benchmarks/bench_check.py --seeds 3  # 36 runs: the workers' start-up matters less

Measured, in one process (the built-ins with their default controllers, IT2 and type-1,
one seed: 12 runs of 15 s simulated):

* **simulation alone** – ``simulate_twin`` for each run in this process (controllers and
  estimators built as the scenario says, the LMI design solved beforehand): the work a
  check cannot avoid;
* **twin check, 1 worker** and **2 workers** – :func:`twin.verify.check.run_checks` (scenario
  loading, run_scenario with its metrics, the verdicts; worker start-up included). Their
  ratio is the speed-up (target: close to linear, about 2 on 2 cores), and
  (1 worker − simulation alone) / runs is the cost per check beyond the simulation.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model, pybullet_version  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run (5 s runs)")
    ap.add_argument("--seeds", type=int, default=1, help="seeds per scenario and controller (default 1)")
    args = ap.parse_args(argv)
    from twin.sim.bullet_loop import simulate_twin
    from twin.verify.check import collect, run_checks
    from twin.scenarios.scenario import builtin_names

    overrides = ["duration=5"] if args.quick else []
    scenarios, _ = collect(builtin_names(), overrides)
    for sc in scenarios:
        sc.design()  # solved once, outside every timing (a check ships it to its workers)
    runs = sum(len(sc.controllers) for sc in scenarios) * args.seeds
    print("twin check of every built-in: wall time on 1 and 2 workers")
    print(f"machine: {cpu_model()}; Python {sys.version.split()[0]}; PyBullet {pybullet_version()}")
    print(f"{len(scenarios)} scenarios × their controllers × {args.seeds} seed(s) = {runs} runs, "
          f"{args.seeds * sum(sc.duration * len(sc.controllers) for sc in scenarios):g} s simulated\n")

    t0 = pc()
    for sc in scenarios:
        ctx = sc.build_context()
        d = sc.data
        for kind in sc.controllers:
            for seed in range(sc.seed, sc.seed + args.seeds):
                simulate_twin(sc.build_controller(kind, ctx), sc.experiment(), sc.twin_config(), duration=sc.duration,
                              controller_name=kind, alpha0=d["initial"]["alpha"], sensors=sc.sensor_config(),
                              estimator=sc.build_estimator(ctx), seed=seed)
    sim = pc() - t0
    walls = {}
    for workers in (1, 2):
        t0 = pc()
        result = run_checks(scenarios, None, args.seeds, workers)
        walls[workers] = pc() - t0
        if not result.passed:
            print(f"warning: {sum(not c.passed for c in result.cases)} checks failed with {workers} workers")
    print(f"{'variant':32} {'wall s':>8} {'per run ms':>11}")
    print(f"{'simulation alone':32} {sim:8.2f} {1000 * sim / runs:11.0f}")
    for w, wall in walls.items():
        print(f"{'twin check, ' + str(w) + ' worker' + 's' * (w > 1):32} {wall:8.2f} {1000 * wall / runs:11.0f}")
    speedup = walls[1] / walls[2]
    beyond = (walls[1] - sim) / runs
    print(f"\nspeed-up 1 → 2 workers {speedup:.2f}× (target close to 2: "
          f"{'met' if speedup >= 1.7 else 'missed'}); per check beyond the simulation {1000 * beyond:.0f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
