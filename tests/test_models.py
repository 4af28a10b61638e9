"""Analytic model (equation 1) and the IT2 Takagi–Sugeno model."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from twin.params import NOMINAL
from twin.plant.analytic import balance_dynamics, dynamics, rk4_step
from twin.plant.ts_model import antecedent_bounds, local_model, nie_tan_weights, ts_dynamics, ts_matrices


def numerical_jacobian(f, x0, h):
    x0 = np.asarray(x0, dtype=float)
    cols = []
    for k in range(len(x0)):
        e = np.zeros_like(x0)
        e[k] = h
        cols.append((f(x0 + e) - f(x0 - e)) / (2 * h))
    return np.column_stack(cols)


def test_A1_B1_equal_numerical_jacobian_of_equation_1():
    (A1, _), (B1, _) = ts_matrices(NOMINAL)
    fx = lambda x: balance_dynamics(0.0, x, 0.0, NOMINAL)
    fu = lambda u: balance_dynamics(0.0, np.zeros(4), u[0], NOMINAL)
    A_num = numerical_jacobian(fx, np.zeros(4), 1e-6)
    B_num = numerical_jacobian(fu, np.zeros(1), 1e-3)
    for exact, num in ((A1, A_num), (B1, B_num)):
        nz = np.abs(exact) > 0
        assert np.all(np.abs(num[~nz]) < 1e-9)
        rel = np.abs(num[nz] - exact[nz]) / np.abs(exact[nz])
        assert rel.max() < 1e-6, rel.max()


def test_A1_eigenvalues_match_paper_notes():
    (A1, _), _ = ts_matrices(NOMINAL)
    ev = np.sort(np.linalg.eigvals(A1).real)
    assert ev == pytest.approx([-35.01, -4.06, 0.0, 18.07], abs=0.01)


def test_A2_from_paper_formulas_and_limits():
    beta = math.cos(math.pi / 6)
    p = NOMINAL
    A2, B2 = local_model(p, beta)
    d = p.m11 * p.m22 - p.m12**2 * beta**2
    assert A2[1, 0] == pytest.approx(p.m11 * p.g_b * beta / d, rel=1e-14)
    assert A2[3, 0] == pytest.approx(-p.m12 * p.g_b * beta**2 / d, rel=1e-14)
    assert B2[1, 0] == pytest.approx(-(p.m11 + p.m12 * beta) / d, rel=1e-14)
    assert B2[3, 0] == pytest.approx((p.m12 * beta + p.m22) / d, rel=1e-14)


def test_nie_tan_weights_and_antecedents():
    th = np.linspace(-1.0, 1.0, 401)
    lo1, up1, lo2, up2 = antecedent_bounds(th)
    assert np.all(lo1 <= up1) and np.all(lo2 <= up2)
    w = nie_tan_weights(th)
    assert np.allclose(w.sum(axis=-1), 1.0)
    assert nie_tan_weights(0.0)[0] == 1.0
    # beyond π/6 only the tilted rule remains
    assert nie_tan_weights(math.pi / 6 + 0.01)[0] == 0.0
    # hand value at θ = π/12: lower 1 − (π/12)/(π/7) = 5/12, upper 1 − (π/12)/(π/6) = 1/2
    assert nie_tan_weights(math.pi / 12)[0] == pytest.approx(0.5 * (5 / 12 + 0.5))


def test_ts_model_approximates_equation_1_and_is_exact_at_upright():
    # The blend of two linear models is an approximation: about 4 % off at θ = 0.05 rad,
    # shrinking to zero at the upright linearisation point.
    errors = []
    for theta in (0.05, 0.01, 0.001):
        x = np.array([theta, 0.1, 0.0, 0.2])
        exact = balance_dynamics(0.0, x, 0.1, NOMINAL)
        fuzzy = ts_dynamics(0.0, x, 0.1, NOMINAL)
        errors.append(np.abs(fuzzy - exact).max() / np.abs(exact).max())
    assert errors[0] < 0.05
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-3


def test_dynamics_works_with_scipy_and_matches_rk4():
    x0 = np.array([0.1, 0, 0, 0, 0, 0.5, 0, 0])
    u = (0.05, 0.08)
    sol = solve_ivp(lambda t, x: dynamics(t, x, u, NOMINAL), (0, 0.3), x0, rtol=1e-10, atol=1e-12)
    x = x0.copy()
    for _ in range(300):
        x = rk4_step(x, u[0], u[1], NOMINAL, 0.001)
    assert np.allclose(sol.y[:, -1], x, atol=1e-7)


def test_equilibrium_and_disturbance_inputs():
    assert np.all(dynamics(0, np.zeros(8), (0, 0), NOMINAL) == 0)
    # τ2 pitches the body, τ3 turns it, τ1 drives the wheels
    d = dynamics(0, np.zeros(8), (0, 0), NOMINAL, tau=(0, 0.1, 0))
    assert d[1] > 0
    d = dynamics(0, np.zeros(8), (0, 0), NOMINAL, tau=(0, 0, 0.1))
    assert d[5] == pytest.approx(0.1 / NOMINAL.m33)
    d = dynamics(0, np.zeros(8), (0, 0), NOMINAL, tau=(0.1, 0, 0))
    assert d[3] > 0 and d[1] < 0


def test_signs_torque_turns_and_drives():
    # equal torques drive the wheels forward and pitch the body back
    d = dynamics(0, np.zeros(8), (0.1, 0.1), NOMINAL)
    assert d[3] > 0 and d[1] < 0 and d[5] == 0
    # more torque on the right wheel turns left (α grows)
    d = dynamics(0, np.zeros(8), (-0.1, 0.1), NOMINAL)
    assert d[5] == pytest.approx(NOMINAL.b / NOMINAL.r * 0.2 / NOMINAL.m33)
    # rolling: planar position follows heading
    x = np.zeros(8)
    x[3], x[4] = 10.0, math.pi / 2
    d = dynamics(0, x, (0, 0), NOMINAL)
    assert d[6] == pytest.approx(0, abs=1e-12) and d[7] == pytest.approx(NOMINAL.r * 10)
