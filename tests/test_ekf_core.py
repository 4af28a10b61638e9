"""The EKF's filter core (:mod:`estimation.ekf_core`): one interface, two implementations.

Both cores run the same predict/update sequence to the same bits; the compiled core's
state makes the round trip through the kernel unchanged; the estimator composes its
policies on either without knowing which (:mod:`estimation.ekf_policies`)."""
from __future__ import annotations

import numpy as np
import pytest

from estimation import ekf_core
from estimation.ekf import EKFEstimator
from estimation.ekf_core import AL, PS, TH, V, N, CompiledCore, PythonCore, compiled_kernel_loaded
from estimation.model import EstimatorModel

needs_kernel = pytest.mark.skipif(not compiled_kernel_loaded(), reason="compiled EKF kernel not available")


def _state(rng):
    x = rng.normal(0.0, 0.1, N)
    A = rng.normal(0.0, 0.01, (N, N))
    P = A @ A.T + np.eye(N) * 1e-4
    return x, 0.5 * (P + P.T)


def _sequence(core, rng, steps=20):
    """predict/update steps with random strapdown-shaped F (the identity but rows θ, α, v, ψ),
    Q, one- and two-row encoder-like measurements; returns every (y, S) and the final x, P."""
    out = []
    for k in range(steps):
        F = np.eye(N)
        F[[TH, AL, V, PS]] += rng.normal(0.0, 0.01, (4, N))
        L = rng.normal(0.0, 0.01, (N, 4))
        Q = L @ L.T
        x_next = core.x + rng.normal(0.0, 1e-3, N)
        core.predict(x_next, F, Q, (float(rng.normal()), float(rng.normal())))
        rows = [0, 1] if k % 3 else [k % 2]
        H = np.zeros((len(rows), N))
        H[:, [PS, TH]] = [1.0, -1.0]
        H[:, AL] = [(-1.0, 1.0)[i] * 2.3 for i in rows]
        z = rng.normal(0.0, 0.1, len(rows))
        off = rng.normal(0.0, 0.01, len(rows))
        R = np.diag(rng.uniform(1e-7, 1e-6, len(rows)))
        y, S = core.update(z, off, H, R)
        out.append((np.array(y), np.array(S)))
    return out, core.x.copy(), core.P.copy(), core.w, core.w_prev


def _core(compiled: bool):
    return EKFEstimator(EstimatorModel(), compiled=compiled).core


def test_the_python_core_is_filterpys_ekf_and_meets_the_interface():
    from filterpy.kalman import ExtendedKalmanFilter

    core = _core(False)
    assert isinstance(core, PythonCore) and not core.compiled and not core.fuses_imu_step
    assert isinstance(core.kf, ExtendedKalmanFilter)
    for name in ("x", "P", "w", "w_prev", "pull", "push", "set_state", "hold", "keep_good", "take_over", "restore",
                 "predict", "update", "forward"):
        assert hasattr(core, name), name


def test_the_python_core_is_deterministic_with_consider_states_held():
    rng = np.random.default_rng(1)
    x, P = _state(rng)
    runs = []
    for _ in range(2):
        core = _core(False)
        core.set_state(x.copy(), P.copy(), (0.0, 0.0), (0.0, 0.0))
        mask = np.zeros(N, dtype=bool)
        mask[[6, 8]] = True
        core.hold(mask)
        runs.append(_sequence(core, np.random.default_rng(2)))
    (seq_a, xa, Pa, *_), (seq_b, xb, Pb, *_) = runs
    assert xa.tobytes() == xb.tobytes() and Pa.tobytes() == Pb.tobytes()
    assert all(ya.tobytes() == yb.tobytes() and Sa.tobytes() == Sb.tobytes() for (ya, Sa), (yb, Sb) in zip(seq_a, seq_b))


@needs_kernel
@pytest.mark.parametrize("hold", [False, True])
def test_both_cores_agree_bit_for_bit_on_a_predict_update_sequence(hold):
    rng = np.random.default_rng(3)
    x, P = _state(rng)
    results = []
    for compiled in (False, True):
        core = _core(compiled)
        assert core.compiled is compiled and isinstance(core, CompiledCore if compiled else PythonCore)
        core.set_state(x.copy(), P.copy(), (0.01, -0.02), (0.0, 0.0))
        if hold:
            mask = np.zeros(N, dtype=bool)
            mask[[6, 7, 8]] = True
            core.hold(mask)
        core.pull()
        results.append(_sequence(core, np.random.default_rng(4)))
        core.push()
        if compiled:  # the round trip through the kernel keeps every bit
            xm, Pm = core.x.copy(), core.P.copy()
            core.pull()
            assert core.x.tobytes() == xm.tobytes() and core.P.tobytes() == Pm.tobytes()
    (seq_p, xp, Pp, wp, wpp), (seq_c, xc, Pc, wc, wpc) = results
    assert xp.tobytes() == xc.tobytes() and Pp.tobytes() == Pc.tobytes() and (wp, wpp) == (wc, wpc)
    for (yp, Sp), (yc, Sc) in zip(seq_p, seq_c):
        assert yp.tobytes() == yc.tobytes() and Sp.tobytes() == Sc.tobytes()


@needs_kernel
def test_both_cores_restore_the_last_good_state_inflated():
    rng = np.random.default_rng(5)
    x, P = _state(rng)
    for compiled in (False, True):
        core = _core(compiled)
        core.set_state(x.copy(), P.copy(), (0.1, 0.2), (0.3, 0.4))
        core.keep_good()
        core.x[TH] = np.nan
        core.push()
        core.restore()
        core.pull()
        assert core.x.tobytes() == x.tobytes() and (core.w, core.w_prev) == ((0.1, 0.2), (0.3, 0.4))
        assert core.P.tobytes() == (4.0 * P + np.diag(np.full(N, 1e-10))).tobytes()


def test_the_compiled_kernel_is_read_through_one_flag():
    assert compiled_kernel_loaded() == (ekf_core._kernel is not None)


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=needs_kernel)])
def test_a_policy_composes_on_either_core(compiled):
    """KeepInside (the truncation into an unchanged count) on a bare core: a wheel estimated
    three counts off its unchanged count is pulled back towards it, its variance shrinks, and
    the other wheel (inside) is left alone; the gate policy's thresholds hold."""
    from estimation.detlinalg import affine, dot, mv
    from estimation.ekf_policies import EncoderGate, KeepInside

    est = EKFEstimator(EstimatorModel(), compiled=compiled)
    core, H, delta = est.core, est.H, est.delta
    x, P = np.zeros(N), np.eye(N) * 1e-6
    core.set_state(x, P, (0.0, 0.0), (0.0, 0.0))
    core.pull()
    enc = (3.0 * delta, 0.0)  # the left wheel's count three counts above its estimate (0)
    policy = KeepInside(H, est.b_r, 0.0, delta, 6.0)
    gate = EncoderGate(1e-4, 5)
    before = dot(H[0], mv(core.P, H[0]))
    used = 0
    for z, off, Hi, R in policy.measurements(enc, enc, core.kf):
        y, S = core.update(z, off, Hi, R)
        assert gate.passes(0.0, 1) and not gate.passes(float("inf"), 1) and S[0, 0] > 0.0
        used += 1
    core.push()
    assert used == 1
    w = float(affine([0.0], H[0][None, :], core.x)[0])
    assert 0.0 < w < 3.0 * delta and dot(H[0], mv(core.P, H[0])) < before
    assert gate.may_reject(4) and not gate.may_reject(5)
