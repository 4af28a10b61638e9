"""What the twin's compiled fast path (``twin/plant/_fastpath.c``) saves the closed loop.

Run from the repository root::

    python benchmarks/bench_fastpath.py     # about 1 min

The fast path does the twin's own per-step arithmetic (the ground truth from PyBullet's
raw state, the two motor drivers) in C, bit for bit as the Python code does it (tested in
tests/test_twin_fastpath.py). It is a third build variant to keep (compiled, pure Python,
and the mix when one kernel fails to build), so it must pay for itself. Measured in one
process, rounds interleaved (A B, B A, ...), medians: ``ClosedLoop.step()`` on paper-exp3
(1 kHz physics, 200 Hz control, DC motors, IMU and encoders, the EKF, the IT2 cascade),
3000 control periods per round, with the fast path and with the Python path (the module
attribute switched before the twin is built).
"""
from __future__ import annotations

import statistics
import sys
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model, pybullet_version  # noqa: E402


def main() -> int:
    from twin.sim.loop import ClosedLoop
    from twin.plant import bullet
    from twin.registry import build_controller
    from twin.scenarios import load_scenario

    if bullet._fastpath is None:  # noqa: SLF001 -- this benchmark switches it, nothing else does
        print("the compiled fast path is not built here (or TWIN_PURE_PYTHON=1): nothing to compare")
        return 1
    built = bullet._fastpath  # noqa: SLF001
    sc = load_scenario("paper-exp3", [])
    ctx = sc.build_context()
    exp = sc.experiment()

    def run(fast: bool, n: int = 3000) -> float:
        bullet._fastpath = built if fast else None  # noqa: SLF001 -- read when the twin is built
        try:
            loop = ClosedLoop(sc.twin_config(), sc.build_estimator(ctx), build_controller("it2", {}, ctx),
                              sc.sensor_config(), exp.targets, exp.theta0, 0.0, (0.0, 0.0))
            loop.reset(0)
            t0 = pc()
            for _ in range(n):
                loop.step()
            per = (pc() - t0) / n * 1e6
            loop.close()
            return per
        finally:
            bullet._fastpath = built  # noqa: SLF001

    print("the twin's compiled fast path against its Python path, in the closed loop")
    print(f"machine: {cpu_model()}; Python {sys.version.split()[0]}; PyBullet {pybullet_version()}")
    run(True, 200), run(False, 200)  # warm-up
    times = {True: [], False: []}
    for r in range(7):
        for fast in ((True, False) if r % 2 == 0 else (False, True)):
            times[fast].append(run(fast))
    fast, slow = statistics.median(times[True]), statistics.median(times[False])
    print(f"ClosedLoop.step, per 5 ms control period (median of 7): fast path {fast:.1f} µs, Python path {slow:.1f} µs")
    print(f"saved: {slow - fast:.1f} µs per control period, {(slow - fast) / slow:.1%} of the closed loop")
    print("rounds (µs): fast path " + ", ".join(f"{t:.1f}" for t in times[True]) + " / Python "
          + ", ".join(f"{t:.1f}" for t in times[False]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
