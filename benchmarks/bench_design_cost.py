"""What designs that are the same on every machine cost (issue 25): the default (robust) and
the nominal LMI design, and the LQR design, before and after, side by side in one run.

Run from the repository root::

    python benchmarks/bench_design_cost.py [--repeats 5]

"Before" is the design as it was solved until issue 25: the solver's own answer, whose last
digits depend on the BLAS kernel (reproduced here by making the unique-point refinement of
twin.controllers.lmi_center fail, which falls back to exactly that answer; the LQR by
scipy's expm and solve_discrete_are, as lqr.py did). "After" is the twin today: the
program's unique central point in 50-digit decimal arithmetic, and the LQR in decimal
arithmetic. Each figure is the median over ``--repeats`` fresh processes:

* first design in a process: the wall time of the call, with cvxpy/Clarabel/scipy already
  imported (their import is a fixed cost of the process, reported apart);
* cached design: the same call served by the design cache (twin.controllers.design_cache)
  in a fresh process, which never imports cvxpy.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time, os
which, mode, before = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
t0 = time.perf_counter()
import numpy, scipy.linalg  # noqa
if which == "nominal" and mode == "first":
    import cvxpy  # noqa
if mode == "first":
    import clarabel  # noqa
t_import = time.perf_counter() - t0
from twin.controllers import designs, lmi, lmi_center
from twin.errors import InfeasibleDesign
if before:
    def _fail(*a, **k):
        raise InfeasibleDesign("benchmark: the solver's answer, as before issue 25")
    lmi_center.refine = _fail
    import io, contextlib
kw = dict(lmi.NOMINAL_DESIGN) if which == "nominal" else {}
if which == "lqr":
    from twin.params import NOMINAL
    if before:
        import numpy as np
        from scipy.linalg import expm, solve_discrete_are, block_diag
        from twin.controllers.lqr import bryson_weights, BALANCE_STATE_SCALES, BALANCE_INPUT_SCALE
        from twin.plant.ts_model import ts_matrices
        def design():
            (A, _), (B, _) = ts_matrices(NOMINAL)
            Q, R = bryson_weights(BALANCE_STATE_SCALES, BALANCE_INPUT_SCALE)
            n, m = B.shape
            F = np.zeros((n + m, n + m)); F[:n, :n], F[:n, n:] = A, B
            M = np.block([[-F.T, block_diag(Q, R)], [np.zeros_like(F), F]])
            E = expm(M * 0.005)
            phi = E[n + m:, n + m:]; cost = phi.T @ E[:n + m, n + m:]; cost = 0.5 * (cost + cost.T)
            Ad, Bd, Qd, Rd, Nd = phi[:n, :n], phi[:n, n:], cost[:n, :n], cost[n:, n:], cost[:n, n:]
            P = solve_discrete_are(Ad, Bd, Qd, Rd, s=Nd)
            return np.linalg.solve(Rd + Bd.T @ P @ Bd, Bd.T @ P @ Ad + Nd.T)
    else:
        from twin.controllers.lqr import LQRController
        def design():
            return LQRController(NOMINAL)
    t0 = time.perf_counter(); design(); wall = time.perf_counter() - t0
    print(json.dumps({"import": t_import, "wall": wall})); sys.exit(0)
err = io.StringIO() if before else None
t0 = time.perf_counter()
if before:
    with contextlib.redirect_stderr(err):
        d = designs.balance_design(**kw, cache=True)  # an empty cache on "first": solved, then stored
else:
    d = designs.balance_design(**kw, cache=True)  # an empty cache on "first": solved, then stored
wall = time.perf_counter() - t0
assert d.from_cache == (mode == "cached"), (mode, d.from_cache)
assert d.unique == (not before) or d.from_cache, (before, d.unique)
print(json.dumps({"import": t_import, "wall": wall, "solve_time_s": d.solve_time_s,
                  "cvxpy_imported": "cvxpy" in sys.modules}))
"""


def _run(which: str, mode: str, before: bool, cache: str) -> dict:
    env = {**os.environ, "TWIN_CACHE_DIR": cache, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-c", CHILD, which, mode, "1" if before else "0"], capture_output=True,
                       text=True, env=env, cwd=tempfile.gettempdir())
    if r.returncode != 0:
        raise SystemExit(f"benchmark child failed ({which}, {mode}, before={before}): {r.stderr.strip()[-2000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    rows = []
    for which in ("default", "nominal", "lqr"):
        for before in (True, False):
            firsts, cached = [], []
            for _ in range(args.repeats):
                with tempfile.TemporaryDirectory() as cache:
                    firsts.append(_run(which, "first", before, cache))
                    if which != "lqr":
                        cached.append(_run(which, "cached", before, cache))
            rows.append((which, "before" if before else "after", firsts, cached))
    print(f"Design cost, median of {args.repeats} fresh processes ({platform.machine()}, "
          f"{os.cpu_count()} CPUs, Python {platform.python_version()})")
    print(f"{'design':10}{'':8}{'first in process [ms]':>24}{'cached [ms]':>14}{'imports before it [ms]':>26}")
    for which, when, firsts, cached in rows:
        first = statistics.median(r["wall"] for r in firsts) * 1e3
        cache = f"{statistics.median(r['wall'] for r in cached) * 1e3:14.1f}" if cached else f"{'-':>14}"
        imp = statistics.median(r["import"] for r in firsts) * 1e3
        print(f"{which:10}{when:8}{first:24.1f}{cache}{imp:26.1f}")
    for which, when, firsts, cached in rows:
        if cached and any(r["cvxpy_imported"] for r in cached):
            print(f"NOTE: a cached {which} design ({when}) imported cvxpy")
    return 0


if __name__ == "__main__":
    sys.exit(main())
