"""Issue 25: the same build gives the same bytes on every CPU. numpy's BLAS (OpenBLAS) picks a
kernel per CPU at load time (``OPENBLAS_CORETYPE`` overrides it) and numpy dispatches its
own SIMD loops per CPU (``NPY_DISABLE_CPU_FEATURES`` narrows them); neither may change a
result. The LQR design's own check is in tests/test_lqr.py; here the estimator's
fixed-order arithmetic (:mod:`estimation.detlinalg`) and whole closed loops, run in child
processes under each kernel and SIMD level this CPU supports."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from estimation import detlinalg as dl


# ---- estimation.detlinalg: the order of every sum ----------------------------------------------
def _loop_mm(A, B):
    """Σₖ aᵢₖ bₖⱼ, products added one at a time in ascending k, in Python floats."""
    n, K = A.shape
    m = B.shape[1]
    C = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            s = A[i, 0] * B[0, j]
            for k in range(1, K):
                s += A[i, k] * B[k, j]
            C[i, j] = s
    return C


@pytest.mark.parametrize("n, K, m", [(12, 12, 12), (16, 16, 16), (1, 12, 12), (12, 12, 1), (1, 12, 1), (2, 12, 2),
                                     (12, 2, 12), (1, 1, 1), (3, 1, 5), (21, 100, 1), (1, 100, 21), (16, 4, 16)])
def test_mm_sums_every_entry_in_ascending_order(n, K, m):
    """Bit for bit a Python loop, whatever the memory layout of the operands: the magnitudes
    span 16 decades, so any other order of the additions shows in the last bits."""
    rng = np.random.default_rng(n * 10000 + K * 100 + m)
    for _ in range(5):
        A = rng.standard_normal((n, K)) * 10.0 ** rng.integers(-8, 8, (n, K))
        B = rng.standard_normal((K, m)) * 10.0 ** rng.integers(-8, 8, (K, m))
        want = _loop_mm(A, B)
        for a, b in ((A, B), (np.asfortranarray(A), np.asfortranarray(B)), (A.T.copy().T, B[::-1].copy()[::-1])):
            assert np.array_equal(dl.mm(a, b), want)
        assert np.array_equal(dl.mv(A, B[:, 0]), want[:, 0])
        assert np.array_equal(dl.vm(A[0], B), want[0])
        assert dl.dot(A[0], B[:, 0]) == want[0, 0]
        c = rng.standard_normal(n)
        assert np.array_equal(dl.affine(c, A, B[:, 0]), _loop_mm(np.hstack([c[:, None], A]),
                                                                 np.concatenate(([1.0], B[:, 0]))[:, None])[:, 0])
        assert np.array_equal(dl.rowsums(A), _loop_mm(A, np.ones((K, 1)))[:, 0])
        assert np.array_equal(dl.affine(c[:1], A[:1], B[:, 0]), dl.affine(c, A, B[:, 0])[:1])
    # and a sum whose order matters: 1 + 1e-16 + ... is not 1e-16 + ... + 1
    A = np.array([[1.0, 1e-16, 1e-16, -1.0]])
    assert dl.mm(A, np.ones((4, 1)))[0, 0] == 0.0 and dl.mm(A[:, ::-1], np.ones((4, 1)))[0, 0] == 2.0 ** -52


def test_small_solves_and_inverses():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 4, 16):
        A = rng.standard_normal((n, n)) + n * np.eye(n)
        b = rng.standard_normal(n)
        np.testing.assert_allclose(dl.solve(A, b), np.linalg.solve(A, b), rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(dl.inv(A), np.linalg.inv(A), rtol=1e-12, atol=1e-14)
        S = A @ A.T
        if n <= 2:
            assert dl.quad_inv(b, S) == pytest.approx(b @ np.linalg.solve(S, b), rel=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        dl.solve(np.zeros((3, 3)), np.ones(3))
    with pytest.raises(np.linalg.LinAlgError):
        dl.inv(np.ones((2, 2)))


# ---- whole closed loops under every CPU kernel ---------------------------------------------------
_CHILD = r"""
import hashlib, json, sys
import numpy as np
try:
    from numpy._core import _multiarray_umath as mu
except ImportError:  # numpy 1.x
    from numpy.core import _multiarray_umath as mu
from threadpoolctl import threadpool_info
from types import SimpleNamespace
from twin.registry import build_estimator_for as build_estimator
from twin.sim.bullet_loop import simulate_twin
from twin.controllers.cascade import build_cascade
from twin.controllers.lqr import LQRController
from twin.experiments import Experiment
from twin.params import NOMINAL
from twin.plant.bullet import TwinConfig
from twin.sensors import SensorConfig
from twin.sensors.faults import Dropout, Spikes

# gyro and encoder spikes, then an IMU dropout: the filter rejects samples and coasts (its
# Python path in both implementations) besides its ordinary steps
faults = (Spikes("gyro", start=0.2, duration=0.6, rate=10.0, magnitude=2.0),
          Spikes("encoders", start=0.2, duration=0.6, rate=5.0, magnitude=0.3), Dropout("imu", start=0.9, duration=0.1))
sensors = SensorConfig(faults=faults)
exp = Experiment("cpu", "cpu", theta0=0.3, p_d=0.2, alpha_d=0.5, duration=1.5)
config = TwinConfig()
lqr = LQRController()
# the IT2 cascade with fixed gains (the LMI design is not this test's subject): u = −K x per rule
pdc = SimpleNamespace(gains=np.vstack([-lqr.K, -0.9 * lqr.K]))
out = {}
for name, ctrl, compiled in (("lqr, compiled EKF", lqr, None), ("it2, pure-Python EKF", build_cascade("it2", pdc, exp.targets), False),
                             ("lqr, pure-Python EKF", lqr, False)):
    est = build_estimator("ekf", sensors, config.control_rate, config.motor, NOMINAL, compiled=compiled)
    run = simulate_twin(ctrl, exp, config, sensors=sensors, estimator=est, seed=1)
    h = hashlib.sha256()
    for a in (run.truth, run.estimates, run.commands, run.actuation):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(json.dumps(run.estimator_stats, sort_keys=True, default=str).encode())
    h.update(json.dumps(run.estimator_consistency, sort_keys=True).encode())  # NEES/NIS of metrics.json
    out[name] = {"hash": h.hexdigest(), "steps": len(run.t), "status": run.status,
                 "rejected": run.estimator_stats.get("rejected_total")}
blas = [d.get("architecture") for d in threadpool_info() if d.get("internal_api") == "openblas"]
print(json.dumps({"runs": out, "blas": blas, "simd": sorted(f for f in mu.__cpu_dispatch__ if mu.__cpu_features__.get(f))}))
"""


def test_closed_loops_are_bit_identical_under_every_blas_kernel_and_numpy_simd_target():
    """LQR with the compiled EKF, and IT2 (fixed gains) and LQR with the pure-Python EKF, 1.5 s
    with gyro/encoder spikes and an IMU dropout, in child processes under each OpenBLAS
    kernel and numpy SIMD level (tests/cpu_kernels.py): the truth, the
    estimates, the commands, the estimator's counts and its NEES/NIS summary must have the
    same bytes. Before
    issue 25 the pure-Python EKF (filterpy's BLAS products) parted after 0.02 s under
    Prescott, and the compiled path after the first coasting step."""
    import twin
    from cpu_kernels import kernel_environments

    envs = kernel_environments()
    if not envs:
        pytest.skip("neither OpenBLAS kernels nor numpy SIMD targets to switch between on this machine")
    root = os.path.dirname(os.path.dirname(os.path.abspath(twin.__file__)))
    base = {k: v for k, v in os.environ.items()
            if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES", "TWIN_PURE_PYTHON")}
    base["PYTHONPATH"] = os.pathsep.join([root] + ([base["PYTHONPATH"]] if base.get("PYTHONPATH") else []))
    runs = {"this machine's default": {}, **envs}
    results = {}
    # two at a time: each child is one process running the twin
    names = list(runs)
    for i in range(0, len(names), 2):
        procs = {n: subprocess.Popen([sys.executable, "-c", _CHILD], env={**base, **runs[n]}, cwd=root,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for n in names[i:i + 2]}
        for n, p in procs.items():
            out, err = p.communicate(timeout=600)
            assert p.returncode == 0, f"{n}: {err.strip().splitlines()[-1:]}"
            results[n] = json.loads(out.strip().splitlines()[-1])
    ref = results["this machine's default"]
    for name, r in ref["runs"].items():
        assert r["status"] == "ok" and r["steps"] == 301 and r["rejected"] > 0, (name, r)
    for n, r in results.items():
        differ = [k for k in ref["runs"] if r["runs"][k] != ref["runs"][k]]
        assert not differ, f"{n} (BLAS {r['blas']}, numpy SIMD {r['simd']}): {', '.join(differ)} differ"
    if any("OPENBLAS_CORETYPE" in e for e in envs.values()) and all(r["blas"] for r in results.values()):
        assert len({tuple(r["blas"]) for r in results.values()}) > 1
    if any("NPY_DISABLE_CPU_FEATURES" in e for e in envs.values()):
        assert len({tuple(r["simd"]) for r in results.values()}) > 1
