"""LMI design time of the IT2 PDC balance gains (target: under 0.5 s).

Run from the repository root::

    python benchmarks/bench_lmi.py

Side by side in the same process: the first design (cvxpy's canonicalisation caches
are cold; the import of cvxpy itself is timed separately and excluded, as in
``solve_time_s``), the median of repeated designs, the same problem with SCS, and as a
reference a continuous-time LQR for the upright model (scipy's Riccati solver), the
classic non-fuzzy way to get balance gains.
"""
from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TARGET_S = 0.5


def main() -> int:
    t0 = time.perf_counter()
    import cvxpy  # noqa: F401

    t_import = time.perf_counter() - t0
    import numpy as np
    from scipy.linalg import solve_continuous_are

    from twin.controllers.lmi import design_balance_gains
    from twin.params import NOMINAL
    from twin.plant.ts_model import ts_matrices

    t0 = time.perf_counter()
    first = design_balance_gains()
    t_first = time.perf_counter() - t0
    warm = []
    for _ in range(10):
        t0 = time.perf_counter()
        design_balance_gains()
        warm.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    scs = design_balance_gains(solver="SCS")
    t_scs = time.perf_counter() - t0
    (A1, _), (B1, _) = ts_matrices(NOMINAL)
    lqr = []
    for _ in range(10):
        t0 = time.perf_counter()
        X = solve_continuous_are(A1, B1, np.diag([100.0, 1.0, 1.0, 1.0]), np.array([[100.0]]))
        _ = -np.linalg.solve(np.array([[100.0]]), B1.T @ X)
        lqr.append(time.perf_counter() - t0)

    print("LMI design of the IT2 PDC gains (ε = 0.5, ρ = 2 N·m, decay rate 3 1/s)")
    print(f"{'case':52}{'time [ms]':>12}")
    print("-" * 64)
    print(f"{'import cvxpy (excluded from the design time)':52}{t_import * 1e3:12.1f}")
    print(f"{'first design in process, Clarabel (wall)':52}{t_first * 1e3:12.1f}")
    print(f"{'  of which solve_time_s (build + solve)':52}{first.solve_time_s * 1e3:12.1f}")
    print(f"{'repeated design, Clarabel, median of 10 (wall)':52}{statistics.median(warm) * 1e3:12.1f}")
    print(f"{'design with SCS (fallback solver, wall)':52}{t_scs * 1e3:12.1f}")
    print(f"{'reference: LQR via scipy Riccati, median of 10':52}{statistics.median(lqr) * 1e3:12.3f}")
    print(f"certificates: Clarabel {'PASSED' if first.certificate.passed else 'FAILED'}, "
          f"SCS {'PASSED' if scs.certificate.passed else 'FAILED'}")
    ok = t_first < TARGET_S
    print(f"RESULT: first design {t_first:.3f} s < {TARGET_S} s: {'PASS' if ok else 'FAIL'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
