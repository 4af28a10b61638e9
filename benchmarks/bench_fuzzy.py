"""Benchmark the twin's IT2 Mamdani position controller against pyit2fls.

Run from the repository root::

    python benchmarks/bench_fuzzy.py

pyit2fls (the ``bench`` extra, ``pyit2fls==0.9.0``) is needed only here. If it cannot be
imported the script prints a one-line note and reports the twin's own figures.

The system compared
-------------------
θ_off = π/40 · F(p_e/3, θ̇/4), with F the Table II IT2 Mamdani FLS of
``twin.controllers.mamdani.position_controller()``: per input 7 IT2 sets NB..PB with
centres k/3 (k = −3..3); upper MF half-width h(1 + fou), lower MF half-width
h(1 − fou), h = 1/3, fou = DEFAULT_FOU = 0.25, both of height 1; NB and PB are
shoulders (membership 1 beyond ∓1). Rule (i, j) fires [min(μ̲_Ai, μ̲_Bj),
min(μ̄_Ai, μ̄_Bj)] and the output is the BMM centre-of-sets reduction over the
consequent centres y_r:  y = m Σ f̲_r y_r / Σ f̲_r + n Σ f̄_r y_r / Σ f̄_r, m = n = 0.5.

The same system in pyit2fls
---------------------------
* Sets: ``pyit2fls.IT2FS`` with the library's own membership functions, feet and peaks
  exactly those of ``twin.fuzzy.sets.uniform_partition``:
  ``tri_mf([c − w, c, c + w, 1])`` for NM..PM, ``rtri_mf([c + w, c, 1])`` for NB
  (1 for x ≤ c, then falling: a left shoulder) and ``ltri_mf([c − w, c, 1])`` for PB
  (rising, then 1 for x > c: a right shoulder), with w = h(1 + fou) for the UMF and
  w = h(1 − fou) for the LMF. These are closed-form functions of x, so the inputs are
  not discretised; like ours (``ScaledFLS``), the normalised inputs are clipped to the
  universe [−1, 1] before they reach the sets.
  (The ``domain`` given to IT2FS is only used for plotting.)
* Firing and type reduction: ``pyit2fls.IT2TSK(min_t_norm, max_s_norm)`` with a
  zeroth-order consequent per rule, ``{"const": y_r, "x1": 0.0, "x2": 0.0}`` where y_r
  is the centre of the rule's Table II consequent set. ``IT2TSK.evaluate`` computes,
  for every rule, ``l = min_t_norm(1, lmf_A(x1), lmf_B(x2))`` and
  ``u = min_t_norm(1, umf_A(x1), umf_B(x2))`` (the same min t-norm of lower and of
  upper memberships), stacks ``intervals = [y_r, y_r, l_r, u_r]`` and hands them to
  ``IT2TSK.algorithm``. We set that attribute to pyit2fls' own
  ``BMM_algorithm(intervals, [m, n])`` (wrapped to return the pair (y, y), because
  ``IT2TSK.evaluate`` passes the algorithm's result to ``crisp`` = midpoint of a pair).
  ``BMM_algorithm`` computes ``m Σ F[:,0] Y / Σ F[:,0] + n Σ F[:,1] Y / Σ F[:,1]`` with
  ``Y = (intervals[:,0] + intervals[:,1]) / 2 = y_r`` – our formula term for term. Its
  sort by Y and ``trim`` of non-firing rules at either end only change the order of
  summation (differences at the 1e-16 level). A constant-consequent TSK system with the
  consequent centres as constants *is* the centre-of-sets Mamdani system with BMM.
* Why not ``IT2Mamdani(method="CoSet", algorithm="BMM", algorithm_params=[m, n])``:
  in pyit2fls 0.9.0 ``CoSet`` first reduces every consequent IT2FS with
  ``Centroid(consequent, alg_func, domain)`` *without* the algorithm's params, so
  ``BMM_algorithm`` fails with ``IndexError`` on ``params[0]``; and even with another
  algorithm the consequent centroids would be computed numerically on a discretised
  output domain (and for the shoulder sets NB/PB they are not ±1), which is not the
  paper's formula with the consequent centres.
* Batch: pyit2fls has no batch evaluation (``IT2TSK.evaluate`` and ``BMM_algorithm``
  take one sample). Two per-sample figures are reported: (a) the ``IT2TSK.evaluate``
  loop, timed on a subset of the batch (stated in the table); (b) the fastest
  composition of pyit2fls' own functions we could make – membership functions and
  ``min_t_norm`` evaluated on the whole batch arrays (they are numpy-vectorised), then
  one ``BMM_algorithm`` call per sample on a preallocated (49, 4) intervals array.

Timing and targets
------------------
``time.perf_counter``, best of several repetitions, garbage collector off while timing.
Inputs come from ``numpy.random.default_rng(SEED)`` (p_e ~ U[−4, 4] m,
θ̇ ~ U[−5, 5] rad/s) and are passed to the scalar paths as Python floats. Targets:
scalar speed-up (pyit2fls / twin) ≥ 200×; max |twin − pyit2fls| ≤ 1e-9 rad; max
|twin scalar − twin vectorised| ≤ 1e-9 rad. The accuracy checks also run on a grid of
"knot" inputs (every set's peak and feet, ±1 and beyond) where the piecewise-linear
memberships change slope. The exit status is 1 if an accuracy target fails, else 0
(timing targets depend on the machine and do not change the exit status).
"""
from __future__ import annotations

import gc
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's ``twin``

from twin.fuzzy.mamdani import MamdaniFLS  # noqa: E402
from twin.controllers.mamdani import (  # noqa: E402
    ScaledFLS,
    DEFAULT_FOU, OUTPUT_CENTRES, P_E_RANGE, RULE_INDEX, THETA_DOT_RANGE, THETA_OFF_RANGE, position_controller,
)

SEED = 20240521
N_SCALAR = 2000  # random input pairs for the scalar timings
N_BATCH = 10_000  # batch size for the vectorised timings
N_BATCH_TSK = 2000  # subset of the batch for the (slow) IT2TSK.evaluate loop
REPEAT_FAST = 7  # best-of repetitions for the fast paths
REPEAT_SLOW = 3  # ... and for the pyit2fls loops
BMM_M, BMM_N = 0.5, 0.5
SPEEDUP_TARGET = 200.0
DIFF_TARGET = 1e-9


def best_of(fn, repeat: int) -> float:
    """Smallest wall time (s) of ``repeat`` calls of ``fn()``, with the GC off."""
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        best = math.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
        return best
    finally:
        if gc_was_enabled:
            gc.enable()


def knot_inputs() -> tuple[np.ndarray, np.ndarray]:
    """Physical input pairs on a grid through every peak, foot, ±1 and beyond (normalised)."""
    h = 1.0 / 3.0
    pts = {0.0, 1.0, -1.0, 1.5, -1.5, 2.0, -2.0}
    for k in range(-3, 4):
        c = k / 3.0
        for w in (h * (1.0 + DEFAULT_FOU), h * (1.0 - DEFAULT_FOU)):
            pts.update((c, c - w, c + w))
    g = np.array(sorted(pts))
    a, b = np.meshgrid(g, g, indexing="ij")
    return a.ravel() * P_E_RANGE, b.ravel() * THETA_DOT_RANGE


# -- the same FLS in pyit2fls --------------------------------------------------------
class PyIT2FLSModel:
    """The Table II position controller built from pyit2fls' own classes and functions."""

    def __init__(self, p):
        self.p = p
        fou, h = DEFAULT_FOU, 1.0 / 3.0
        domain = np.linspace(-1.0, 1.0, 201)  # plotting only; memberships are closed-form
        self.sets = []
        for k in range(-3, 4):
            c = k / 3.0
            wu, wl = h * (1.0 + fou), h * (1.0 - fou)
            if k == -3:  # NB: left shoulder
                s = p.IT2FS(domain, p.rtri_mf, [c + wu, c, 1.0], p.rtri_mf, [c + wl, c, 1.0])
            elif k == 3:  # PB: right shoulder
                s = p.IT2FS(domain, p.ltri_mf, [c - wu, c, 1.0], p.ltri_mf, [c - wl, c, 1.0])
            else:
                s = p.IT2FS(domain, p.tri_mf, [c - wu, c, c + wu, 1.0], p.tri_mf, [c - wl, c, c + wl, 1.0])
            self.sets.append(s)
        self.y = np.array([float(OUTPUT_CENTRES[RULE_INDEX[i, j]]) for i in range(7) for j in range(7)])

        tsk = p.IT2TSK(p.min_t_norm, p.max_s_norm)
        tsk.add_input_variable("x1")
        tsk.add_input_variable("x2")
        tsk.add_output_variable("y")
        for i in range(7):
            for j in range(7):
                tsk.add_rule([("x1", self.sets[i]), ("x2", self.sets[j])],
                             [("y", {"const": self.y[7 * i + j], "x1": 0.0, "x2": 0.0})])
        bmm = p.BMM_algorithm

        def bmm_pair(intervals):  # IT2TSK.evaluate returns crisp(result) = midpoint of a pair
            yc = bmm(intervals, [BMM_M, BMM_N])
            return yc, yc

        tsk.algorithm = bmm_pair
        self.tsk = tsk
        self._buf = np.empty((49, 4))
        self._buf[:, 0] = self.y
        self._buf[:, 1] = self.y

    def __call__(self, p_e: float, theta_dot: float) -> float:
        """Scalar call in physical units through ``IT2TSK.evaluate``."""
        x1 = min(1.0, max(-1.0, p_e / P_E_RANGE))
        x2 = min(1.0, max(-1.0, theta_dot / THETA_DOT_RANGE))
        return THETA_OFF_RANGE * self.tsk.evaluate({"x1": x1, "x2": x2})["y"]

    def firing(self, x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 49) lower and upper firing strengths from pyit2fls MFs and min_t_norm, vectorised."""
        lo1 = [s.lmf(x1, s.lmf_params) for s in self.sets]
        up1 = [s.umf(x1, s.umf_params) for s in self.sets]
        lo2 = [s.lmf(x2, s.lmf_params) for s in self.sets]
        up2 = [s.umf(x2, s.umf_params) for s in self.sets]
        t = self.p.min_t_norm
        f_lo = np.stack([t(lo1[i], lo2[j]) for i in range(7) for j in range(7)], axis=-1)
        f_up = np.stack([t(up1[i], up2[j]) for i in range(7) for j in range(7)], axis=-1)
        return f_lo, f_up

    def evaluate_batch(self, p_e: np.ndarray, theta_dot: np.ndarray) -> np.ndarray:
        """Vectorised firing, then one ``BMM_algorithm`` call per sample."""
        f_lo, f_up = self.firing(np.clip(np.asarray(p_e, float) / P_E_RANGE, -1, 1),
                                 np.clip(np.asarray(theta_dot, float) / THETA_DOT_RANGE, -1, 1))
        buf, bmm, params = self._buf, self.p.BMM_algorithm, [BMM_M, BMM_N]
        out = np.empty(f_lo.shape[0])
        for s in range(f_lo.shape[0]):
            buf[:, 2] = f_lo[s]
            buf[:, 3] = f_up[s]
            out[s] = bmm(buf, params)  # BMM_algorithm sorts into a copy; buf is not modified
        return THETA_OFF_RANGE * out


def load_pyit2fls():
    os.environ.setdefault("MPLBACKEND", "Agg")  # pyit2fls imports matplotlib.pyplot
    try:
        import pyit2fls
        from importlib.metadata import version
        try:
            ver = version("pyit2fls")
        except Exception:
            ver = "?"
        return pyit2fls, ver
    except Exception as exc:  # ImportError, or a broken optional dependency
        print(f"note: pyit2fls not available ({type(exc).__name__}: {exc}); "
              f"reporting the twin's own figures only (pip install 'pyit2fls==0.9.0')")
        return None, None


def main() -> int:
    t_start = time.perf_counter()
    pc = position_controller()
    rng = np.random.default_rng(SEED)
    pe_s = rng.uniform(-4.0, 4.0, N_SCALAR)
    td_s = rng.uniform(-5.0, 5.0, N_SCALAR)
    pe_b = rng.uniform(-4.0, 4.0, N_BATCH)
    td_b = rng.uniform(-5.0, 5.0, N_BATCH)
    pairs_s = list(zip(pe_s.tolist(), td_s.tolist()))
    pairs_b_sub = list(zip(pe_b[:N_BATCH_TSK].tolist(), td_b[:N_BATCH_TSK].tolist()))
    pe_k, td_k = knot_inputs()
    pairs_k = list(zip(pe_k.tolist(), td_k.tolist()))

    p, ver = load_pyit2fls()
    model = PyIT2FLSModel(p) if p is not None else None

    # -- timings ----------------------------------------------------------------
    t_ours_scalar = best_of(lambda: [pc(a, b) for a, b in pairs_s], REPEAT_FAST) / N_SCALAR
    pc.evaluate(pe_b, td_b)  # warm-up
    t_ours_batch = best_of(lambda: pc.evaluate(pe_b, td_b), REPEAT_FAST) / N_BATCH
    # the pure-Python / numpy fallback used when the compiled kernel is not built
    f = pc.fls
    pc_py = ScaledFLS(MamdaniFLS(f.input1, f.input2, f.output_centres, f.rule_table, compiled=False),
                      pc.input_ranges, pc.output_range)
    t_py_fallback_scalar = best_of(lambda: [pc_py(a, b) for a, b in pairs_s], REPEAT_FAST) / N_SCALAR
    t_py_fallback_batch = best_of(lambda: pc_py.evaluate(pe_b, td_b), REPEAT_FAST) / N_BATCH
    d_fallback = max(float(np.max(np.abs(np.array([pc_py(a, b) for a, b in pairs_s]) - np.array([pc(a, b) for a, b in pairs_s])))),
                     float(np.max(np.abs(pc_py.evaluate(pe_b, td_b) - pc.evaluate(pe_b, td_b)))))
    if model is not None:
        model(0.1, 0.2)  # warm-up
        t_py_scalar = best_of(lambda: [model(a, b) for a, b in pairs_s], REPEAT_SLOW) / N_SCALAR
        t_py_batch_tsk = best_of(lambda: [model(a, b) for a, b in pairs_b_sub], REPEAT_SLOW) / N_BATCH_TSK
        t_py_batch_vec = best_of(lambda: model.evaluate_batch(pe_b, td_b), REPEAT_SLOW) / N_BATCH

    # -- accuracy ---------------------------------------------------------------
    ours_s = np.array([pc(a, b) for a, b in pairs_s])
    ours_b_scalar = np.array([pc(a, b) for a, b in zip(pe_b.tolist(), td_b.tolist())])
    ours_b = pc.evaluate(pe_b, td_b)
    ours_k = np.array([pc(a, b) for a, b in pairs_k])
    d_self = max(np.max(np.abs(ours_s - pc.evaluate(pe_s, td_s))),
                 np.max(np.abs(ours_b_scalar - ours_b)),
                 np.max(np.abs(ours_k - pc.evaluate(pe_k, td_k))))
    if model is not None:
        py_s = np.array([model(a, b) for a, b in pairs_s])
        py_k = np.array([model(a, b) for a, b in pairs_k])
        py_b_tsk = np.array([model(a, b) for a, b in pairs_b_sub])
        py_b_vec = model.evaluate_batch(pe_b, td_b)
        d_scalar = float(np.max(np.abs(ours_s - py_s)))
        d_knots = float(np.max(np.abs(ours_k - py_k)))
        d_batch = float(max(np.max(np.abs(ours_b - py_b_vec)), np.max(np.abs(ours_b[:N_BATCH_TSK] - py_b_tsk))))
        d_py = max(d_scalar, d_knots, d_batch)

    # -- report -----------------------------------------------------------------
    title = f"IT2 Mamdani position controller (7x7 rules, fou={DEFAULT_FOU}, BMM m={BMM_M} n={BMM_N}, seed={SEED})"
    print(title)
    print(f"twin vs pyit2fls {ver}" if model is not None else "twin only (pyit2fls not installed)")
    print(f"twin path: {'compiled kernel (twin.fuzzy._kernel)' if pc.fls.compiled else 'pure Python (kernel not built)'}")
    w = 62
    print()
    print(f"{'timing':<{w}}{'twin':>12}{'pyit2fls':>12}{'ratio':>10}")
    print("-" * (w + 34))

    def row(label, ours, theirs=None, unit_scale=1.0, digits=2):
        if theirs is None:
            print(f"{label:<{w}}{ours * unit_scale:>12.{digits}f}{'-':>12}{'-':>10}")
        else:
            print(f"{label:<{w}}{ours * unit_scale:>12.{digits}f}{theirs * unit_scale:>12.{digits}f}"
                  f"{theirs / ours:>9.1f}x")

    batch = f"batch of {N_BATCH}, ns/sample"
    if model is not None:
        row(f"scalar call, us/call ({N_SCALAR} random pairs)", t_ours_scalar, t_py_scalar, 1e6)
        row(f"{batch}: IT2TSK loop*", t_ours_batch, t_py_batch_tsk, 1e9, 0)
        row(f"{batch}: vec. firing + BMM loop", t_ours_batch, t_py_batch_vec, 1e9, 0)
        print(f"  twin batch = pc.evaluate on all {N_BATCH}; *IT2TSK.evaluate timed on the first "
              f"{N_BATCH_TSK} samples of the batch")
    else:
        row(f"scalar call, us/call ({N_SCALAR} random pairs)", t_ours_scalar, None, 1e6)
        row(f"{batch} (pc.evaluate)", t_ours_batch, None, 1e9, 0)
    if model is not None:
        row("scalar call, us/call: twin pure-Python fallback", t_py_fallback_scalar, t_py_scalar, 1e6)
        row(f"{batch}: twin numpy fallback vs IT2TSK loop", t_py_fallback_batch, t_py_batch_tsk, 1e9, 0)
    else:
        row("scalar call, us/call: twin pure-Python fallback", t_py_fallback_scalar, None, 1e6)
        row(f"{batch}: twin numpy fallback", t_py_fallback_batch, None, 1e9, 0)
    print()
    print(f"{'max |difference| of theta_off (rad)':<{w}}{'value':>12}")
    print("-" * (w + 12))
    if model is not None:
        print(f"{f'twin scalar vs pyit2fls IT2TSK ({N_SCALAR} pairs)':<{w}}{d_scalar:>12.2e}")
        print(f"{f'twin vs pyit2fls, knot grid ({len(pairs_k)} pairs)':<{w}}{d_knots:>12.2e}")
        print(f"{f'twin vectorised vs pyit2fls, batch of {N_BATCH}':<{w}}{d_batch:>12.2e}")
    print(f"{'twin scalar vs twin vectorised (all inputs)':<{w}}{d_self:>12.2e}")
    print(f"{'twin compiled vs twin pure-Python/numpy fallback':<{w}}{d_fallback:>12.2e}")
    print()

    ok_self = max(d_self, d_fallback) <= DIFF_TARGET
    verdicts = []
    if model is not None:
        speedup = t_py_scalar / t_ours_scalar
        ok_speed = speedup >= SPEEDUP_TARGET
        ok_py = d_py <= DIFF_TARGET
        verdicts.append(f"speed-up {speedup:.1f}x >= {SPEEDUP_TARGET:.0f}x: {'PASS' if ok_speed else 'FAIL'}")
        verdicts.append(f"|twin - pyit2fls| {d_py:.1e} <= {DIFF_TARGET:.0e}: {'PASS' if ok_py else 'FAIL'}")
    else:
        ok_py = True
        verdicts.append(f"speed-up >= {SPEEDUP_TARGET:.0f}x: SKIP")
        verdicts.append(f"|twin - pyit2fls| <= {DIFF_TARGET:.0e}: SKIP")
    verdicts.append(f"|scalar - vectorised| {d_self:.1e} <= {DIFF_TARGET:.0e}: {'PASS' if ok_self else 'FAIL'}")
    print("RESULT: " + " | ".join(verdicts))
    print(f"(total run time {time.perf_counter() - t_start:.1f} s)")
    return 0 if (ok_self and ok_py) else 1


if __name__ == "__main__":
    sys.exit(main())
