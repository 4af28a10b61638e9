"""LMI design (Lemmas 1–2 + decay rate) and its independent certificate."""
import numpy as np
import pytest

from twin.controllers.lmi import design_balance_gains, verify_certificate
from twin.errors import InfeasibleDesign, TwinError
from twin.params import NOMINAL
from twin.plant.ts_model import rule1_weight, ts_matrices


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
    for _ in range(20):
        x = rng.normal(size=4)
        x *= design.epsilon / np.linalg.norm(x)
        for _ in range(1500):
            m1 = rule1_weight(x[0])
            u = (m1 * design.gains[0] + (1 - m1) * design.gains[1]) @ x
            worst = max(worst, abs(u))
            dx = m1 * (A1 @ x + B1[:, 0] * u) + (1 - m1) * (A2 @ x + B2[:, 0] * u)
            x = x + 1e-4 * dx
    assert worst <= design.peak_input * 1.001
    assert design.peak_input <= design.rho
    # the bound also limits the gains: ‖G_i‖ ≤ √t / ε
    assert np.linalg.norm(design.gains, axis=1).max() <= design.peak_input / design.epsilon * 1.0001


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
    with pytest.raises(InfeasibleDesign, match=r"decay rate 200 1/s is infeasible.*largest feasible"):
        design_balance_gains(decay_rate=200.0, rho=1e6)


def test_max_gain_bound():
    d = design_balance_gains(max_gain=3.0)
    assert np.linalg.norm(d.gains, axis=1).max() <= 3.0
    with pytest.raises(InfeasibleDesign, match="max gain 0.1 is too small"):
        design_balance_gains(max_gain=0.1)


@pytest.mark.parametrize("kw", [{"epsilon": -1}, {"rho": 0}, {"decay_rate": float("nan")}, {"rho": "big"}])
def test_bad_design_inputs(kw):
    with pytest.raises(TwinError):
        design_balance_gains(**kw)


def test_json_keys(design):
    j = design.to_json_dict()
    assert np.array(j["gains"]).shape == (2, 4) and np.array(j["P"]).shape == (4, 4)
    for key in ("solve_time_s", "epsilon", "rho", "decay_rate"):
        assert isinstance(j[key], float)
