"""What the EKF's running NEES/NIS summary costs a run (issue 29, metrics.json's "estimator").

Run from the repository root::

    python benchmarks/bench_consistency.py            # about 30 s
    python benchmarks/bench_consistency.py --quick    # a few seconds

What is measured, in one process, rounds interleaved (CPU time of this process, so that
other jobs on the machine count less than in wall time):

* **closed loop** – :func:`twin.sim.simulate.simulate` on ``paper-exp3`` (15 s, IT2, simulated
  sensors and the EKF), with the meter (:func:`twin.sim.simulate.consistency_meter`, as every
  run has it) and without it; the difference per control step, and against the step.
* **its parts**, each alone on the state of a running filter: reading x and P into the
  meter's block (the filter core's ``state_into``: by the compiled kernel's own copy where it
  has one, else through its tuples of Python floats) and the meter's work per row at the end
  of a block (NEES solved for the block, the truth, the sums). In the loop the parts cost more
  than alone (the caches are shared with the physics and the filter).

The rounds vary by a few µs on a machine that runs other jobs: the added cost is the median
of the rounds' paired differences (each round runs both, in alternating order).
"""
from __future__ import annotations

import argparse
import gc
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run")
    args = ap.parse_args(argv)
    import numpy as np

    import estimation.consistency as C
    import twin.sim.simulate as S
    from estimation.ekf_core import compiled_kernel_loaded
    from twin.scenarios import load_scenario
    from twin.scenarios.planning import plan

    rounds = 2 if args.quick else 20
    sc = load_scenario("paper-exp3", ["duration=3"] if args.quick else [])
    spec = plan(sc, ["it2"])[0]
    real = S.consistency_meter

    def off(loop, spec, diagnosed=False):
        return None, None

    print("the EKF's running NEES/NIS summary: its cost per control step")
    print(f"machine: {cpu_model()}; Python {sys.version.split()[0]}; compiled EKF kernel: {compiled_kernel_loaded()}")
    S.simulate(spec)  # warm-up
    times = {"with": [], "without": []}
    for r in range(rounds):
        for mode in (("with", "without") if r % 2 == 0 else ("without", "with")):
            S.consistency_meter = real if mode == "with" else off
            gc.collect()
            t0 = time.process_time()
            run = S.simulate(spec)
            times[mode].append((time.process_time() - t0) / len(run.t) * 1e6)
    S.consistency_meter = real
    on, base = statistics.median(times["with"]), statistics.median(times["without"])
    added = statistics.median([a - b for a, b in zip(times["with"], times["without"])])

    # the parts, on a running filter
    loop = S.build_loop(spec)
    with loop:
        loop.reset(spec.seed)
        for _ in range(400):
            loop.step(loop.command())
        into = loop.estimator.state_into  # the run's binding: the kernel's own copy on the compiled path
        kernel_copy = getattr(into, "func", None) is not None  # bound kernel function (partial)
        out = np.empty((C.SUM_BLOCK, 12 + 144))
        n = 20000
        t0 = time.process_time()
        for i in range(n):
            into(out, i % C.SUM_BLOCK)
        read = (time.process_time() - t0) / n * 1e6
    grab = []
    flush = C.RunningConsistency._flush

    def keep(self):
        if len(self._pending) == C.SUM_BLOCK and not grab:
            grab.append((list(self._pending), self._states.copy(), self.__dict__.copy()))
        flush(self)

    C.RunningConsistency._flush = keep
    S.simulate(plan(load_scenario("paper-exp3", ["duration=6"]), ["it2"])[0])
    C.RunningConsistency._flush = flush
    rows, states, state = grab[0]
    meter = C.RunningConsistency(state["constants"])
    reps = 5 if args.quick else 30
    t0 = time.process_time()
    for _ in range(reps):
        meter.__dict__.update(state, _pending=list(rows), _states=states, _sums=C._Sums(C.NEES_START))
        flush(meter)
    per_row = (time.process_time() - t0) / reps / len(rows) * 1e6

    print(f"\nscenario {sc.name}: {sc.duration:g} s, IT2, {rounds} rounds interleaved, medians (CPU time)\n")
    print(f"  closed loop without the meter            {base:8.2f} µs per control step")
    print(f"  closed loop with it (every run)          {on:8.2f} µs per control step")
    print(f"  added (median of the paired rounds)      {added:8.2f} µs ({100 * added / base:+.2f} %)   "
          f"target ≤ 2 %")
    print(f"  of which: x and P into the block         {read:8.2f} µs per step "
          f"({'the kernel copies them' if kernel_copy else 'through the kernel tuples of Python floats'})")
    print(f"            NEES, truth and sums per row   {per_row:8.2f} µs (at the end of each block of "
          f"{C.SUM_BLOCK} rows)")
    print(f"  rounds: with {[round(x, 1) for x in times['with']]}")
    print(f"          without {[round(x, 1) for x in times['without']]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
