"""The LQR baseline (twin.controllers.lqr): its design, its closed loop on the analytic
model (equation 1) in the paper's three experiments, and its contract."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from twin.controllers.cascade import DEFAULT_PSI_ERROR_LIMIT
from twin.controllers.lmi import DEFAULT_SCALING, DEFAULT_RHO
from twin.controllers.lqr import LQRController, build_lqr, lqr_design, sampled_cost, yaw_model
from twin.controllers.mamdani import DEFAULT_U_ALPHA_MAX
from twin.errors import TwinError
from twin.params import NOMINAL
from twin.plant.analytic import rhs, rk4_step
from twin.plant.ts_model import ts_matrices
from twin.protocols import Controller, Targets

PHYSICS_DT = 0.001  # s
CONTROL_DT = 0.005  # s (200 Hz, zero-order hold)
PERTURBED = NOMINAL.perturbed(scale={"m_b": 1.2, "l": 1.15})


@pytest.fixture(scope="module")
def ctrl():
    return LQRController()


# ---- design ------------------------------------------------------------------------

def _dare_residual(Ad, Bd, Qd, Rd, Nd, P):
    G = Bd.T @ P @ Ad + Nd.T
    res = Ad.T @ P @ Ad - P - G.T @ np.linalg.solve(Rd + Bd.T @ P @ Bd, G) + Qd
    return np.linalg.norm(res) / np.linalg.norm(P)


def test_balance_gain_solves_the_sampled_riccati_equation_and_stabilises_a1_b1(ctrl):
    (A1, _), (B1, _) = ts_matrices(NOMINAL)
    d = ctrl.balance_design
    assert np.array_equal(d.A, A1) and np.array_equal(d.B, B1)
    assert ctrl.K.shape == (1, 4)
    Ad, Bd, Qd, Rd, Nd = sampled_cost(A1, B1, d.Q, d.R, CONTROL_DT)
    assert _dare_residual(Ad, Bd, Qd, Rd, Nd, d.P) < 1e-9
    assert d.riccati_residual() < 1e-9
    # the gain is the one the Riccati solution implies, and P is positive definite
    K = np.linalg.solve(Rd + Bd.T @ d.P @ Bd, Bd.T @ d.P @ Ad + Nd.T)
    np.testing.assert_allclose(ctrl.K, K, rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(0.5 * (d.P + d.P.T)) > 0)
    # the sampled loop is stable, and so is the continuous loop A1 − B1 K
    assert np.max(np.abs(np.linalg.eigvals(Ad - Bd @ ctrl.K))) < 0.99
    assert np.max(np.linalg.eigvals(A1 - B1 @ ctrl.K).real) < -1.0
    poles = ctrl.closed_loop_poles()[0]
    assert poles.shape == (4,) and np.max(poles.real) < -1.0
    # an unstable open loop (the upright pendulum) made stable
    assert np.max(np.linalg.eigvals(A1).real) > 10.0


def test_continuous_design_solves_the_continuous_riccati_equation():
    c = LQRController(control_period=None)
    (A1, _), (B1, _) = ts_matrices(NOMINAL)
    d = c.balance_design
    P, Q, R = d.P, d.Q, d.R
    res = A1.T @ P + P @ A1 - P @ B1 @ np.linalg.solve(R, B1.T @ P) + Q
    assert np.linalg.norm(res) / np.linalg.norm(P) < 1e-9
    np.testing.assert_allclose(c.K, np.linalg.solve(R, B1.T @ P), rtol=1e-9)
    assert np.max(np.linalg.eigvals(A1 - B1 @ c.K).real) < -1.0
    np.testing.assert_allclose(np.sort_complex(c.closed_loop_poles()[0]),
                               np.sort_complex(np.linalg.eigvals(A1 - B1 @ c.K)), rtol=1e-9)


def test_sampled_design_tends_to_the_continuous_one_as_the_period_shrinks():
    cont = LQRController(control_period=None)
    fine = LQRController(control_period=1e-5)
    coarse = LQRController()
    np.testing.assert_allclose(fine.K, cont.K, rtol=2e-3)
    np.testing.assert_allclose(fine.K_yaw, cont.K_yaw, rtol=2e-3)
    # at 5 ms the fast mode's gain differs (the reason for the discrete design) ...
    assert abs(coarse.K[0, 0] / cont.K[0, 0] - 1) > 0.1
    # ... while the slow closed-loop poles agree
    slow_c = np.sort_complex(cont.closed_loop_poles()[0][1:])
    slow_d = np.sort_complex(coarse.closed_loop_poles()[0][1:])
    np.testing.assert_allclose(slow_d, slow_c, rtol=1e-3)


def test_sampled_cost_is_the_continuous_cost_over_one_held_period():
    (A1, _), (B1, _) = ts_matrices(NOMINAL)
    Q = np.diag([1.0, 0.01, 0.01, 0.0004])
    R = np.array([[0.25]])
    T = CONTROL_DT
    Ad, Bd, Qd, Rd, Nd = sampled_cost(A1, B1, Q, R, T)
    np.testing.assert_allclose(Ad, scipy.linalg.expm(A1 * T), rtol=1e-10, atol=1e-12)
    x0, u0 = np.array([0.3, -1.0, 0.5, 2.0]), 0.7
    # Simpson's rule on a fine grid of the exact solution z(t) = expm(F t) [x0; u0]
    F = np.zeros((5, 5))
    F[:4, :4], F[:4, 4:] = A1, B1
    n = 400
    step = scipy.linalg.expm(F * (T / n))
    z = np.append(x0, u0)
    z0 = z.copy()
    vals = []
    for _ in range(n + 1):
        vals.append(z[:4] @ Q @ z[:4] + R[0, 0] * z[4] ** 2)
        z = step @ z
    integral = scipy.integrate.simpson(vals, dx=T / n)
    sampled = x0 @ Qd @ x0 + 2 * u0 * (x0 @ Nd[:, 0]) + Rd[0, 0] * u0**2
    assert sampled == pytest.approx(integral, rel=1e-6)
    np.testing.assert_allclose((Ad @ x0 + Bd[:, 0] * u0), (scipy.linalg.expm(F * T) @ z0)[:4], rtol=1e-10)


def test_yaw_model_is_equation_1_linearised_at_rest():
    A, B = yaw_model(NOMINAL)
    x = np.zeros(6)
    h = 1e-6
    # α̈ as a function of α̇ and of u_α (ul = −u_α, ur = +u_α), by central differences
    xp, xm = x.copy(), x.copy()
    xp[5], xm[5] = h, -h
    d_alpha_dot = (rhs(xp, 0.0, 0.0, NOMINAL, (0, 0, 0))[5] - rhs(xm, 0.0, 0.0, NOMINAL, (0, 0, 0))[5]) / (2 * h)
    d_u_alpha = (rhs(x, -h, h, NOMINAL, (0, 0, 0))[5] - rhs(x, h, -h, NOMINAL, (0, 0, 0))[5]) / (2 * h)
    assert A[1, 1] == pytest.approx(d_alpha_dot, rel=1e-6)
    assert B[1, 0] == pytest.approx(d_u_alpha, rel=1e-6)
    assert A[0, 1] == 1.0 and A[0, 0] == A[1, 0] == B[0, 0] == 0.0


def test_yaw_gain_solves_its_riccati_equation_and_stabilises(ctrl):
    d = ctrl.yaw_design
    A, B = yaw_model(NOMINAL)
    Ad, Bd, Qd, Rd, Nd = sampled_cost(A, B, d.Q, d.R, CONTROL_DT)
    assert ctrl.K_yaw.shape == (1, 2)
    assert _dare_residual(Ad, Bd, Qd, Rd, Nd, d.P) < 1e-9
    assert np.max(np.abs(np.linalg.eigvals(Ad - Bd @ ctrl.K_yaw))) < 1.0
    assert np.max(np.linalg.eigvals(A - B @ ctrl.K_yaw).real) < -0.5
    assert np.max(ctrl.closed_loop_poles()[1].real) < -0.5
    # the open yaw loop is only marginally stable (an integrator): feedback on α is needed
    assert np.max(np.linalg.eigvals(A).real) == pytest.approx(0.0, abs=1e-12)
    c = LQRController(control_period=None)
    P = c.yaw_design.P
    res = A.T @ P + P @ A - P @ B @ np.linalg.solve(c.yaw_design.R, B.T @ P) + c.yaw_design.Q
    assert np.linalg.norm(res) / np.linalg.norm(P) < 1e-9


def test_weights_follow_brysons_rule_with_the_lmi_designs_scales(ctrl):
    np.testing.assert_array_equal(ctrl.balance_design.Q, np.diag(1.0 / np.asarray(DEFAULT_SCALING) ** 2))
    np.testing.assert_array_equal(ctrl.balance_design.R, [[1.0 / DEFAULT_RHO**2]])
    np.testing.assert_array_equal(ctrl.yaw_design.Q, np.diag([1.0, 1.0]))  # 1 rad, 1 rad/s (Table I)
    np.testing.assert_array_equal(ctrl.yaw_design.R, [[1.0 / DEFAULT_U_ALPHA_MAX**2]])
    c = LQRController(state_scales=(0.5, 2.0, 4.0, 8.0), input_scale=0.5, yaw_state_scales=(2.0, 0.25),
                      yaw_input_scale=0.2)
    np.testing.assert_allclose(c.balance_design.Q, np.diag([4.0, 0.25, 1 / 16, 1 / 64]), rtol=1e-15)
    np.testing.assert_allclose(c.balance_design.R, [[4.0]], rtol=1e-15)
    np.testing.assert_allclose(c.yaw_design.Q, np.diag([0.25, 16.0]), rtol=1e-15)
    np.testing.assert_allclose(c.yaw_design.R, [[25.0]], rtol=1e-15)
    assert not np.allclose(c.K, ctrl.K)


def test_lqr_design_rejects_an_unstabilisable_pair():
    with pytest.raises(TwinError, match="Riccati"):
        lqr_design(np.array([[1.0, 0.0], [0.0, 2.0]]), np.array([[1.0], [0.0]]), np.eye(2), np.eye(1), None)


# ---- closed loop on the analytic model --------------------------------------------

def _simulate(controller, plant, p_d=None, alpha_d=None, duration=15.0, theta0=0.48):
    """Equation (1) by RK4 at 1 ms; the controller at 200 Hz with zero-order hold.
    Returns t (n,) s and the state (n, 8) after each control period, and the commands (n, 5)."""
    x = np.zeros(8)
    x[0] = theta0
    targets = Targets(p_d, alpha_d)
    controller.reset(targets)
    k = round(CONTROL_DT / PHYSICS_DT)
    n = round(duration / CONTROL_DT)
    xs, cmds = np.empty((n, 8)), np.empty((n, 5))
    for i in range(n):
        cmd = controller(x[:6], targets)
        cmds[i] = cmd
        for _ in range(k):
            x = rk4_step(x, cmd[0], cmd[1], plant, PHYSICS_DT)
        xs[i] = x
        assert abs(x[0]) < 1.5, f"fell at t = {(i + 1) * CONTROL_DT:.3f} s"
    return np.arange(1, n + 1) * CONTROL_DT, xs, cmds


@pytest.mark.parametrize("plant", [NOMINAL, PERTURBED], ids=["nominal", "m_b x1.2, l x1.15"])
def test_experiment_1_balances_from_0_48_rad(ctrl, plant):
    t, x, cmds = _simulate(ctrl, plant, duration=6.0)
    assert np.all(np.abs(x[t >= 3.0, 0]) < 0.01)
    assert np.abs(x[-1, :4]).max() < 1e-4  # back upright at the start, at rest
    assert abs(x[-1, 4]) < 1e-12 and np.all(cmds[:, 4] == 0.0) and np.all(cmds[:, 3] == 0.0)
    # within the input bound the weights were designed with (|u| ≤ ρ = 2 N·m)
    assert np.abs(cmds[:, 2]).max() < DEFAULT_RHO


@pytest.mark.parametrize("plant", [NOMINAL, PERTURBED], ids=["nominal", "m_b x1.2, l x1.15"])
def test_experiment_2_reaches_0_7_m(ctrl, plant):
    t, x, _ = _simulate(ctrl, plant, p_d=0.7)
    assert abs(plant.r * x[-1, 2] - 0.7) < 0.02
    assert abs(x[-1, 0]) < 0.01
    # on the way, a cruise at the speed the clipped ψ channel sets (module docstring)
    K_th, _, K_psi, K_psid = ctrl.K[0]
    w = K_psi * DEFAULT_PSI_ERROR_LIMIT / (K_psid + 2 * K_th * plant.d_w / plant.g_b + 2 * (plant.d_w + plant.d_b))
    cruise = (t > 3.0) & (plant.r * x[:, 2] < 0.6)
    assert cruise.sum() > 200 and w > 0
    np.testing.assert_allclose(x[cruise, 3], w, rtol=1e-3)


@pytest.mark.parametrize("plant", [NOMINAL, PERTURBED], ids=["nominal", "m_b x1.2, l x1.15"])
def test_experiment_3_reaches_1_m_and_1_5_rad(ctrl, plant):
    t, x, cmds = _simulate(ctrl, plant, p_d=1.0, alpha_d=1.5)
    assert abs(plant.r * x[-1, 2] - 1.0) < 0.02
    assert abs(x[-1, 4] - 1.5) < 0.02
    assert abs(x[-1, 0]) < 0.01
    assert np.abs(cmds[:, :2]).max() < 1.2  # inside the motors' stall torque per wheel


def test_without_position_target_the_robot_returns_to_its_start_even_when_far(ctrl):
    # ψ is not clipped without a target: regulation back to ψ = 0 from 0.2 m away
    x_far = [0.0, 0.0, 5.0, 0.0, 0.0, 0.0]
    u_far = ctrl(x_far, Targets())[2]
    assert u_far == pytest.approx(-ctrl.K[0, 2] * 5.0, rel=1e-12)


# ---- the call --------------------------------------------------------------------

def test_meets_the_controller_protocol(ctrl):
    assert isinstance(ctrl, Controller)
    assert ctrl.signals == ("u", "theta_off", "u_alpha")
    assert ctrl.signal_units == {"u": "N·m", "theta_off": "rad", "u_alpha": "N·m"}
    assert ctrl.reset(Targets()) is None


@pytest.mark.parametrize("targets", [Targets(), Targets(0.7), Targets(1.0, 1.5), Targets(None, -0.5)])
def test_call_returns_five_finite_floats_in_the_cascade_convention(ctrl, targets):
    est = (0.1, -0.3, 2.0, 1.5, 0.2, -0.1)
    out = ctrl(est, targets)
    assert len(out) == 5 and all(type(v) is float and math.isfinite(v) for v in out)
    ul, ur, u, theta_off, u_alpha = out
    assert theta_off == 0.0
    assert ur - ul == pytest.approx(2.0 * u_alpha, abs=1e-15)
    assert ul + ur == pytest.approx(u, abs=1e-15)
    if targets.heading is None:
        assert u_alpha == 0.0 and ul + ur == u and ul == ur
    else:
        assert u_alpha != 0.0


def test_signs_lean_forward_drives_forward_and_heading_error_turns_towards_target(ctrl):
    assert ctrl((0.1, 0, 0, 0, 0, 0), Targets())[2] > 0  # forward lean: wheels forward
    assert ctrl((0, 0, 0, 0, 0, 0), Targets(None, 1.0))[4] > 0  # α_d > α: turn left (ur > ul)
    assert ctrl((0, 0, 0, 0, 2.0, 0), Targets(None, 1.0))[4] < 0


def test_gains_are_the_ones_applied(ctrl):
    est = (0.05, 0.2, -0.3, 0.4, 0.7, -0.2)
    _, _, u, _, u_alpha = ctrl(est, Targets(None, 0.5))
    assert u == pytest.approx(-(ctrl.K[0] @ np.array(est[:4])), rel=1e-12)
    assert u_alpha == pytest.approx(-(ctrl.K_yaw[0] @ np.array([0.7 - 0.5, -0.2])), rel=1e-12)


def test_position_error_is_measured_from_the_target_and_clipped(ctrl):
    r = NOMINAL.r
    lim = DEFAULT_PSI_ERROR_LIMIT
    at_target = ctrl((0, 0, 0.5 / r, 0, 0, 0), Targets(0.5))[2]
    assert at_target == pytest.approx(0.0, abs=1e-15)
    near = ctrl((0, 0, 0, 0, 0, 0), Targets(0.5 * lim * r))[2]
    assert near == pytest.approx(ctrl.K[0, 2] * 0.5 * lim, rel=1e-12)
    at_limit = ctrl((0, 0, 0, 0, 0, 0), Targets(lim * r))[2]
    far = ctrl((0, 0, 0, 0, 0, 0), Targets(3.0))[2]
    assert far == at_limit and abs(far) > abs(near)
    behind = ctrl((0, 0, 0, 0, 0, 0), Targets(-3.0))[2]
    assert behind == -far
    tight = LQRController(psi_error_limit=0.25)
    assert tight((0, 0, 0, 0, 0, 0), Targets(3.0))[2] == pytest.approx(0.25 * far, rel=1e-12)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_estimate_raises(ctrl, bad):
    with pytest.raises(TwinError, match="non-finite estimate"):
        ctrl((0.0, 0.0, 0.0, bad, 0.0, 0.0), Targets())
    with pytest.raises(TwinError, match="non-finite position target"):
        ctrl((0.0,) * 6, Targets(bad))
    with pytest.raises(TwinError, match="non-finite heading target"):
        ctrl((0.0,) * 6, Targets(None, bad))


def test_short_or_non_numeric_estimate_raises(ctrl):
    with pytest.raises(TwinError, match="6 numbers"):
        ctrl((0.0, 0.0, 0.0), Targets())
    with pytest.raises(TwinError, match="6 numbers"):
        ctrl(("a", 0.0, 0.0, 0.0, 0.0, 0.0), Targets())


# ---- construction ------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, match", [
    ({"state_scales": (1.0, 10.0, 10.0)}, "state_scales"),
    ({"state_scales": (1.0, 10.0, 0.0, 50.0)}, "state_scales"),
    ({"state_scales": (1.0, -10.0, 10.0, 50.0)}, "state_scales"),
    ({"state_scales": (1.0, float("nan"), 10.0, 50.0)}, "state_scales"),
    ({"state_scales": "abcd"}, "state_scales"),
    ({"input_scale": 0.0}, "input_scale"),
    ({"input_scale": -2.0}, "input_scale"),
    ({"input_scale": float("inf")}, "input_scale"),
    ({"input_scale": "2"}, "input_scale"),
    ({"yaw_state_scales": (1.0,)}, "yaw_state_scales"),
    ({"yaw_state_scales": (1.0, 0.0)}, "yaw_state_scales"),
    ({"yaw_input_scale": 0.0}, "yaw_input_scale"),
    ({"psi_error_limit": 0.0}, "psi_error_limit"),
    ({"psi_error_limit": float("nan")}, "psi_error_limit"),
    ({"control_period": 0.0}, "control_period"),
    ({"control_period": -0.005}, "control_period"),
    ({"control_period": 5.0}, "control_period"),
    ({"params": {"m_b": 2.58}}, "RobotParams"),
])
def test_bad_constructor_arguments_raise_one_line_twin_errors(kwargs, match):
    with pytest.raises(TwinError, match=match) as err:
        LQRController(**kwargs)
    assert "\n" not in str(err.value)


def test_design_follows_the_model_params():
    c = LQRController(params=PERTURBED)
    (A1, _), (B1, _) = ts_matrices(PERTURBED)
    assert np.array_equal(c.balance_design.A, A1)
    assert not np.allclose(c.K, LQRController().K)


def test_factory_builds_from_keywords_and_context():
    from types import SimpleNamespace

    c = build_lqr(None, psi_error_limit=0.5)
    assert isinstance(c, LQRController) and c.psi_error_limit == 0.5
    ctx = SimpleNamespace(model=PERTURBED, control_rate=100.0, options={"psi_error_limit": 0.3})
    c = build_lqr(ctx)
    assert c.params is PERTURBED and c.psi_error_limit == 0.3 and c.control_period == pytest.approx(0.01)
    assert c.balance_design.control_period == pytest.approx(0.01)
    assert build_lqr(ctx, psi_error_limit=0.7, control_period=None).balance_design.control_period is None
    with pytest.raises(TwinError, match="control_rate"):
        build_lqr(SimpleNamespace(control_rate=0.0))


# ---- on the twin, with the EKF in the loop ----------------------------------------------------
@pytest.mark.parametrize("number", [1, 2, 3])
def test_lqr_balances_the_paper_experiments_on_the_twin_with_the_ekf(number):
    """Built-in scenarios paper-exp1..3: the mismatched true plant (m_b ×1.06, l ×1.08, n_yb ×1.1,
    d_b and d_w ×1.5), DC motors, IMU and encoders with the EKF in the loop. Measured (seed 0):
    θ peak-to-peak over the last 5 s 0.004, 0.004, 0.033 rad; final position error 9e-5 m (exp 2),
    1e-5 m (exp 3); heading error −0.007 rad (exp 3)."""
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    sc = load_scenario(f"paper-exp{number}")
    assert sc.estimator == "ekf" and sc.data["plant"]["scale"]  # the EKF in the loop, a true plant that differs
    m = run_scenario(sc, ["lqr"]).metrics["lqr"]
    assert m["status"] == "ok" and not m["fell"]
    assert m["oscillation_peak_to_peak_rad"] < 0.05 and abs(m["final_theta_rad"]) < 0.03
    if number >= 2:
        assert abs(m["final_position_error_m"]) < 0.02
    if number == 3:
        assert abs(m["final_heading_error_rad"]) < 0.02


# ---- the same bits on every CPU kernel (issue 25) ----------------------------------------------
# the child: both designs (sampled and continuous), every exposed matrix by its exact bits, and
# which OpenBLAS kernel and numpy SIMD targets it actually ran with
_CHILD = r"""
import json
import numpy as np
try:
    from numpy._core import _multiarray_umath as mu
except ImportError:  # numpy 1.x
    from numpy.core import _multiarray_umath as mu
from threadpoolctl import threadpool_info
from twin.controllers.lqr import LQRController

def bits(a):
    return None if a is None else [float(v).hex() for v in np.asarray(a, dtype=float).ravel()]

out = {}
for name, c in (("sampled", LQRController()), ("continuous", LQRController(control_period=None))):
    out[name + " digest"] = c.design_digest()
    for which, d in (("balance", c.balance_design), ("yaw", c.yaw_design)):
        for m in ("K", "P", "Ad", "Bd", "Qd", "Rd", "Nd"):
            out[f"{name} {which} {m}"] = bits(getattr(d, m))
blas = [d.get("architecture") for d in threadpool_info() if d.get("internal_api") == "openblas"]
print(json.dumps({"design": out, "blas": blas,
                  "simd": sorted(f for f in mu.__cpu_dispatch__ if mu.__cpu_features__.get(f))}))
"""


def test_gains_are_bit_identical_under_every_blas_kernel_and_numpy_simd_target():
    """Issue 25: the design runs in child processes under each OpenBLAS kernel this CPU supports
    (OPENBLAS_CORETYPE) and with numpy's SIMD targets narrowed (NPY_DISABLE_CPU_FEATURES); the
    gains and every matrix of both designs, sampled and continuous, must have the same bits.
    With scipy's expm/solve_discrete_are the balance gains differed between Haswell, SkylakeX
    and Prescott."""
    import json
    import os
    import subprocess
    import sys

    from cpu_kernels import kernel_environments

    envs = kernel_environments()
    if not envs:
        pytest.skip("neither OpenBLAS kernels nor numpy SIMD targets to switch between on this machine")
    import twin

    # the children import the very code this process runs (and nothing from the working directory)
    root = os.path.dirname(os.path.dirname(os.path.abspath(twin.__file__)))
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")}
    base["PYTHONPATH"] = os.pathsep.join([root] + ([base["PYTHONPATH"]] if base.get("PYTHONPATH") else []))
    runs = {"this machine's default": {}, **envs}
    procs = {name: subprocess.Popen([sys.executable, "-c", _CHILD], env={**base, **extra}, cwd=root,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for name, extra in runs.items()}
    results = {}
    for name, p in procs.items():
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, f"{name}: {err.strip().splitlines()[-1:]}"
        results[name] = json.loads(out.strip().splitlines()[-1])
    ref = results["this machine's default"]
    assert ref["design"]["sampled balance K"] and ref["design"]["continuous yaw P"]
    for name, r in results.items():
        differ = sorted(k for k in ref["design"] if r["design"][k] != ref["design"][k])
        assert not differ, f"{name} (BLAS {r['blas']}, numpy SIMD {r['simd']}): {', '.join(differ)} differ"
    # the variables took effect: the children ran more than one kernel / SIMD level
    if any("OPENBLAS_CORETYPE" in e for e in envs.values()) and all(r["blas"] for r in results.values()):
        assert len({tuple(r["blas"]) for r in results.values()}) > 1
    if any("NPY_DISABLE_CPU_FEATURES" in e for e in envs.values()):
        assert len({tuple(r["simd"]) for r in results.values()}) > 1


def test_design_digest_is_the_gains_digest(ctrl):
    from twin.outputs.fingerprint import design_digest

    d = ctrl.design_digest()
    assert d == design_digest(K=ctrl.K, K_yaw=ctrl.K_yaw) and len(d) == 64
    assert LQRController().design_digest() == d  # the same design again: the same bits
    assert LQRController(control_period=None).design_digest() != d


def test_design_is_float64s_correctly_rounded_exact_design():
    """50 digits are enough: the same design at 90 digits rounds to the same float64s."""
    import decimal
    from decimal import Decimal

    from twin.controllers import decimal_linalg as dl

    d = LQRController().balance_design
    ctx = dl.context()
    ctx.prec = 90
    with decimal.localcontext(ctx):
        parts = dl.van_loan(dl.dec(d.A), dl.dec(d.B), dl.dec(d.Q), dl.dec(d.R), Decimal(CONTROL_DT))
        P, K = dl.solve_dare(*parts)
    for name, M in zip(("Ad", "Bd", "Qd", "Rd", "Nd"), parts):
        assert np.array_equal(dl.to_float(M), getattr(d, name)), name
    assert np.array_equal(dl.to_float(P), d.P) and np.array_equal(dl.to_float(K), d.K)
    # and scipy agrees to its own accuracy
    P_scipy = scipy.linalg.solve_discrete_are(d.Ad, d.Bd, d.Qd, d.Rd, s=d.Nd)
    np.testing.assert_allclose(d.P, P_scipy, rtol=1e-10)


def test_continuous_design_agrees_with_scipy():
    d = LQRController(control_period=None).balance_design
    np.testing.assert_allclose(d.P, scipy.linalg.solve_continuous_are(d.A, d.B, d.Q, d.R), rtol=1e-10)


def test_large_period_design_is_still_found():
    # at 1 s scipy's solve_discrete_are gives up ("eigenvalues too close to the unit circle")
    c = LQRController(control_period=1.0)
    assert c.balance_design.riccati_residual() < 1e-9
    assert np.max(np.abs(np.linalg.eigvals(c.balance_design.Ad - c.balance_design.Bd @ c.K))) < 1.0


@pytest.mark.parametrize("args, match", [
    ((np.eye(2), np.ones((3, 1)), np.eye(2), np.eye(1)), "shapes"),
    ((np.eye(2), np.ones((2, 1)), np.eye(2), np.eye(2)), "shapes"),
    ((np.eye(2) * np.nan, np.ones((2, 1)), np.eye(2), np.eye(1)), "finite"),
    ((np.eye(2), np.ones((2, 1)), np.eye(2), -np.eye(1)), "Riccati"),
])
def test_lqr_design_rejects_bad_matrices_in_one_line(args, match):
    with pytest.raises(TwinError, match=match) as err:
        lqr_design(*args)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("T", [0.0, -0.005, float("nan"), float("inf"), "5 ms", None])
def test_sampled_cost_rejects_a_bad_period_in_one_line(T):
    A, B = yaw_model(NOMINAL)
    with pytest.raises(TwinError, match="sampling period") as err:
        sampled_cost(A, B, np.eye(2), np.eye(1), T)
    assert "\n" not in str(err.value)
    with pytest.raises(TwinError, match="control_period") as err:
        lqr_design(A, B, np.eye(2), np.eye(1), T if T is not None else "none")
