"""The paper's experiments on the analytic model (the reference for the PyBullet twin)."""
import numpy as np
import pytest

from twin.sim.analytic_loop import run_paper_experiment, simulate
from twin.controllers.cascade import build_cascade
from twin.experiments import PAPER_EXPERIMENTS, Experiment
from twin.errors import TwinError
from twin.params import NOMINAL


@pytest.fixture(scope="module")
def tight_design():
    """ρ just above the default design's certified peak (1.197 N·m), so that |u| ≤ ρ is a real test."""
    from twin.controllers.lmi import design_balance_gains

    return design_balance_gains(rho=1.25)


@pytest.mark.parametrize("kind", ["it2", "t1"])
def test_exp1_balance_from_048(tight_design, kind):
    run = run_paper_experiment(1, kind, tight_design, duration=5.0)
    theta = run.signal("theta")
    assert run.settling_time(0.01) <= 3.0
    assert np.all(np.abs(theta[run.t >= 3.0]) < 0.01)
    assert np.max(np.abs(run.signal("u"))) <= tight_design.rho == 1.25
    assert np.max(np.abs(run.signal("u"))) > 0.4  # it did act


@pytest.mark.parametrize("kind", ["it2", "t1"])
def test_exp2_position_reaches_07m(design, kind):
    run = run_paper_experiment(2, kind, design)
    assert run.t[-1] == pytest.approx(15.0)
    err = np.abs(run.distance - 0.7)
    assert err[-1] < 0.01
    assert run.distance.max() < 0.7 + 0.05  # no large overshoot
    assert np.all(np.abs(run.signal("theta")) < 0.6)


@pytest.mark.parametrize("kind", ["it2", "t1"])
def test_exp3_position_and_direction(design, kind):
    run = run_paper_experiment(3, kind, design)
    assert abs(run.distance[-1] - 1.0) < 0.01
    assert abs(run.signal("alpha")[-1] - 1.5) < 0.01


@pytest.mark.parametrize("p_d, alpha_d", [(-0.5, -1.0), (0.3, 0.4)])
def test_sign_conventions_reach_any_target(design, p_d, alpha_d):
    exp = Experiment("custom", "", theta0=-0.2, p_d=p_d, alpha_d=alpha_d, duration=15.0)
    run = simulate(build_cascade("it2", design, exp.targets), exp)
    assert abs(run.distance[-1] - p_d) < 0.01
    assert abs(run.signal("alpha")[-1] - alpha_d) < 0.01


def test_balances_a_mismatched_true_plant(design):
    plant = NOMINAL.perturbed(scale={"m_b": 1.15, "l": 1.1, "n_yb": 1.3, "d_w": 2.0})
    run = run_paper_experiment(2, "it2", design, plant=plant)
    assert abs(run.distance[-1] - 0.7) < 0.02
    assert np.all(np.abs(run.signal("theta")[run.t > 12]) < 0.01)


def test_control_period_must_be_whole_number_of_physics_steps(design):
    exp = PAPER_EXPERIMENTS[1]
    with pytest.raises(TwinError, match="whole number of physics steps"):
        simulate(build_cascade("it2", design, exp.targets), exp, physics_dt=0.001, control_dt=0.0025)


def test_constant_disturbance_shifts_but_does_not_topple(design):
    exp = PAPER_EXPERIMENTS[1]
    run = simulate(build_cascade("it2", design, exp.targets), exp, disturbance=lambda t: (0.0, 0.05, 0.0), duration=6)
    assert np.all(np.abs(run.signal("theta")[run.t > 3]) < 0.2)
    assert np.all(np.isfinite(run.truth))


def _time_to_reach(run, target, tol=0.01):
    outside = np.nonzero(np.abs(run.distance - target) >= tol)[0]
    return np.inf if outside[-1] == len(run.t) - 1 else run.t[outside[-1] + 1]


class _Negated:
    def __init__(self, fls):
        self.fls = fls

    def __call__(self, a, b):
        return -self.fls(a, b)


def test_position_fls_drives_towards_the_target_on_its_own(design):
    """With the ψ channel off, the FLS alone must move the robot towards p_d (and a
    sign-flipped FLS away from it): this catches a wrong θ_off sign convention."""
    exp = PAPER_EXPERIMENTS[2]
    alone = simulate(build_cascade("it2", design, exp.targets, psi_error_limit=1e-9), exp)
    assert 0.2 < alone.distance[-1] < 0.7
    assert np.all(np.diff(alone.distance[alone.t > 2]) > -1e-4)  # steadily towards the target
    flipped = build_cascade("it2", design, exp.targets, psi_error_limit=1e-9)
    flipped.position = _Negated(flipped.position)
    assert simulate(flipped, exp).distance[-1] < -0.2


def test_position_fls_shortens_the_approach(design):
    exp = PAPER_EXPERIMENTS[2]
    times = {}
    for mode in ("fls", "zero", "flipped"):
        c = build_cascade("it2", design, exp.targets)
        if mode == "zero":
            c.position = lambda a, b: 0.0
        elif mode == "flipped":
            c.position = _Negated(c.position)
        times[mode] = _time_to_reach(simulate(c, exp, duration=20.0), 0.7)
    assert times["fls"] < 0.95 * times["zero"] < 0.95 * times["flipped"]


def test_bad_simulation_inputs(design):
    exp = PAPER_EXPERIMENTS[1]
    ctrl = build_cascade("it2", design, exp.targets)
    with pytest.raises(TwinError, match="x0 must be 8 finite numbers"):
        simulate(ctrl, exp, x0=[0.1, 0.0])
    with pytest.raises(TwinError, match="duration must be at least one control period"):
        simulate(ctrl, exp, duration=0.001)
