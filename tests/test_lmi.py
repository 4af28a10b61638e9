"""LMI design (Lemmas 1–2 + decay rate) and its independent certificate.

The ``design`` fixture is the twin's default (robust) design; the tests that solve their
own call the nominal design of Lemmas 1–2 and a decay rate (``NOMINAL_DESIGN``), whose
behaviour they pin down; the regions and the parameter box are tested in
test_lmi_regions.py."""
from functools import partial

import numpy as np
import pytest

from twin.controllers import lmi
from twin.controllers.lmi import NOMINAL_DESIGN, verify_certificate
from twin.errors import InfeasibleDesign, TwinError
from twin.params import NOMINAL
from twin.plant.ts_model import rule1_weight, ts_matrices

design_balance_gains = partial(lmi.design_balance_gains, **NOMINAL_DESIGN)


def test_certificate_passes(design):
    assert design.certificate.passed
    assert design.certificate.lyapunov_margin > 0
    assert min(design.certificate.lmi_margins.values()) > 0
    assert design.gains.shape == (2, 4) and design.P.shape == (4, 4)


def test_lyapunov_decrease_checked_here_from_P_and_G(design):
    """Own check, independent of the module's: V = xᵀPx falls at rate 2a for every weight."""
    (A1, A2), (B1, B2) = ts_matrices(NOMINAL)
    A, B, G, P, a = (A1, A2), (B1, B2), design.gains, design.P, design.decay_rate
    assert np.linalg.eigvalsh(P).min() > 0
    for m1 in np.linspace(0, 1, 51):
        m = (m1, 1 - m1)
        Acl = sum(m[i] * m[j] * (A[i] + B[i] @ G[j:j + 1]) for i in range(2) for j in range(2))
        L = Acl.T @ P + P @ Acl + 2 * a * P
        assert np.linalg.eigvalsh(0.5 * (L + L.T)).max() < 0
        assert np.linalg.eigvals(Acl).real.max() < -a


def test_input_bound_of_lemma_2_holds_on_the_ts_model(design):
    """From any ‖x0‖ = ε, |u| stays below the certified peak (≤ ρ) along the TS trajectory."""
    (A1, A2), (B1, B2) = ts_matrices(NOMINAL)
    rng = np.random.default_rng(7)
    worst = 0.0

    def f(x):
        m1 = rule1_weight(x[0])
        u = (m1 * design.gains[0] + (1 - m1) * design.gains[1]) @ x
        return m1 * (A1 @ x + B1[:, 0] * u) + (1 - m1) * (A2 @ x + B2[:, 0] * u), u

    for _ in range(20):
        x = rng.normal(size=4)
        x *= design.epsilon / np.linalg.norm(x)
        for _ in range(3000):  # 3 s, RK4
            k1, u = f(x)
            worst = max(worst, abs(u))
            k2, _ = f(x + 0.0005 * k1)
            k3, _ = f(x + 0.0005 * k2)
            k4, _ = f(x + 0.001 * k3)
            x = x + (0.001 / 6) * (k1 + 2 * k2 + 2 * k3 + k4)
        assert np.linalg.norm(x) < 1e-3 * design.epsilon  # it converged (decay rate 3 1/s)
    assert worst <= design.peak_input * 1.001
    assert design.peak_input <= design.rho
    # the bound also limits the gains: ‖G_i‖ ≤ √t / ε
    assert np.linalg.norm(design.gains, axis=1).max() <= design.peak_input / design.epsilon * 1.0001


def test_certificate_check_fails_for_a_decay_rate_it_was_not_designed_for(design):
    from twin.controllers import lmi

    (A1, A2), (B1, B2) = ts_matrices(NOMINAL)
    sol = lmi._certified_solution([A1, A2], [B1, B2], 3.0, None)
    Q, N, Y, T, _, _ = sol
    assert lmi.verify_certificate([A1, A2], [B1, B2], Q, N, Y, 1.0, 1e6, 3.0, T).passed
    cert = lmi.verify_certificate([A1, A2], [B1, B2], Q, N, Y, 1.0, 1e6, 10.0, T)
    assert not cert.passed and cert.lyapunov_margin < 0
    # and for a ρ below the peak
    assert not lmi.verify_certificate([A1, A2], [B1, B2], Q, N, Y, 1.0, 0.5, 3.0, T).passed


def test_decay_rate_zero_is_reported_as_nearly_marginal():
    d = design_balance_gains(decay_rate=0.0)
    assert d.certificate.passed
    assert -0.1 < d.slowest_vertex_pole < 0  # the paper's Lemma 1 alone: stable, barely
    assert design_balance_gains(decay_rate=3.0).slowest_vertex_pole < -2.5


def test_certificate_check_can_fail(design):
    """Gains of the wrong sign must not pass the numpy check."""
    (A1, A2), (B1, B2) = ts_matrices(NOMINAL)
    Q = design.Q
    N_bad = [(+design.gains[i:i + 1]) @ Q for i in range(2)]  # N = +G Q instead of −G Q
    Y = [[np.eye(4), np.zeros((4, 4))], [np.zeros((4, 4)), np.eye(4)]]
    cert = verify_certificate([A1, A2], [B1, B2], Q, N_bad, Y, design.epsilon, design.rho, design.decay_rate)
    assert not cert.passed
    assert cert.lyapunov_margin < 0


def test_faster_decay_needs_bigger_gains():
    slow = design_balance_gains(decay_rate=1.0)
    fast = design_balance_gains(decay_rate=5.0)
    assert fast.peak_input > slow.peak_input
    assert abs(fast.gains[0, 0]) > abs(slow.gains[0, 0])


def test_scs_fallback_solver_gives_a_certified_design():
    d = design_balance_gains(solver="SCS", decay_rate=2.0)
    assert d.certificate.passed and d.solver == "SCS"


def test_rho_too_small_is_a_clear_error():
    with pytest.raises(InfeasibleDesign) as info:
        design_balance_gains(rho=0.05)
    msg = str(info.value)
    assert "rho = 0.05" in msg and "smallest feasible rho" in msg and "\n" not in msg


def test_decay_rate_too_large_is_a_clear_error():
    with pytest.raises(InfeasibleDesign, match=r"decay rate 60 1/s cannot be certified.*infeasible.*largest certified is about") as info:
        design_balance_gains(decay_rate=60.0, rho=1e6)
    # the value it reports really is certified
    largest = float(str(info.value).split("largest certified is about ")[1].split()[0])
    assert 5.0 < largest < 60.0
    assert design_balance_gains(decay_rate=largest, rho=1e6).certificate.passed


def test_epsilon_only_sets_the_scale_and_large_rho_is_harmless():
    ref = design_balance_gains(epsilon=0.5, rho=1e6, decay_rate=5.0)
    for eps in (1e-6, 0.05, 5.0):
        d = design_balance_gains(epsilon=eps, rho=1e6, decay_rate=5.0)
        assert np.allclose(d.gains, ref.gains, rtol=1e-12)
        assert d.peak_input == pytest.approx(ref.peak_input * eps / 0.5, rel=1e-9)
        assert d.certificate.passed


def test_max_gain_bound_is_on_the_actual_gain_norm():
    norm = np.linalg.norm(design_balance_gains().gains, axis=1).max()  # about 1.235
    assert design_balance_gains(max_gain=norm * 1.001).certificate.passed
    with pytest.raises(InfeasibleDesign, match="max gain .* is below the designed gains' norm"):
        design_balance_gains(max_gain=norm * 0.99)


@pytest.mark.parametrize("eps", [0.2, 0.37, 0.6, 0.77])
def test_suggested_rho_is_accepted_when_passed_back(eps):
    with pytest.raises(InfeasibleDesign) as info:
        design_balance_gains(epsilon=eps, rho=0.01)
    suggested = float(str(info.value).split("smallest feasible rho is ")[1].split()[0])
    assert design_balance_gains(epsilon=eps, rho=suggested).certificate.passed


def test_unknown_solver_is_a_clear_error():
    with pytest.raises(TwinError, match="solver 'NOPE' is not installed; installed:"):
        design_balance_gains(solver="NOPE")


@pytest.mark.parametrize("scale", [{"m_b": 2.0, "l": 0.5}, {"l": 3.0}, {"r": 2.0}, {"n_yb": 10.0}])
def test_design_on_perturbed_plants(scale):
    d = design_balance_gains(NOMINAL.perturbed(scale=scale), rho=1e6)
    assert d.certificate.passed and d.slowest_vertex_pole < -2.5


@pytest.mark.parametrize("kw", [{"epsilon": -1}, {"rho": 0}, {"decay_rate": float("nan")}, {"rho": "big"},
                                {"rho": 1e300}, {"epsilon": 1e200}, {"max_gain": 0}, {"decay_rate": 1e3}])
def test_bad_design_inputs(kw):
    with pytest.raises(TwinError):
        design_balance_gains(**kw)


def test_json_keys(design):
    j = design.to_json_dict()
    assert np.array(j["gains"]).shape == (2, 4) and np.array(j["P"]).shape == (4, 4)
    for key in ("solve_time_s", "epsilon", "rho", "decay_rate"):
        assert isinstance(j[key], float)


def test_type1_pdc_keeps_the_decay_rate_along_theta():
    """The certificate covers the IT2 weights; along the weights both controllers really
    meet (θ in the model's domain) the designed decay rate holds for both, and a decay
    rate the design was not made for does not (the nominal design, whose decay along θ
    is not padded by a parameter box)."""
    from twin.controllers.balance import PDCBalanceController
    from twin.controllers.lmi import decay_along_theta

    design = design_balance_gains()
    for kind in ("it2", "t1"):
        rate = decay_along_theta(design, PDCBalanceController(design.gains, kind).weight)
        assert design.decay_rate <= rate < design.decay_rate + 0.5
    slow = design_balance_gains(decay_rate=1.0)
    assert decay_along_theta(slow, PDCBalanceController(slow.gains, "t1").weight) < 2.0


def test_clarabel_failure_falls_back_to_scs(monkeypatch):
    """If Clarabel is missing or crashes, the design is solved by SCS and still certified."""
    import cvxpy

    real_solve = cvxpy.Problem.solve
    tried = []

    def solve(self, *args, solver=None, **kwargs):
        tried.append(solver)
        if solver == "CLARABEL":
            raise cvxpy.error.SolverError("Clarabel crashed (simulated)")
        return real_solve(self, *args, solver=solver, **kwargs)

    monkeypatch.setattr(cvxpy.Problem, "solve", solve)
    d = design_balance_gains(decay_rate=2.0)
    assert tried[:2] == ["CLARABEL", "SCS"]
    assert d.solver == "SCS" and d.certificate.passed
