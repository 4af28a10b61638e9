"""Long runs: no yaw or position creep from the contact solver, and (the short soak) the
EKF in the loop holding balance and its estimates over simulated minutes.

See README, "Long runs", and docs/investigations/yaw-creep.md.
"""
import math

import numpy as np
import pytest

from twin.plant.bullet import TwinConfig
from twin.errors import TwinError
from twin.scenarios import load_scenario
from twin.scenarios.runner import run_scenario


def _run(name, *sets, controller="it2"):
    return run_scenario(load_scenario(name, list(sets)), controllers=controller).runs[0]


@pytest.mark.parametrize("alpha0", [0.0, 0.1, math.pi / 4])
def test_no_yaw_creep_on_the_default_floor(alpha0):
    """Balancing in place with equal commands on both wheels, the heading must hold and the
    axle must roll without slipping. With Bullet's default residual threshold (1e-7) the
    heading crept 0.082 rad and the axle slid 26 mm from 20 s to 120 s at α0 = 0.1."""
    run = _run("paper-exp2", "duration=120", f"initial.alpha={alpha0}", "sensors.sensing=ideal")
    assert run.status == "ok"
    t = run.t
    i20 = int(np.searchsorted(t, 20.0))
    alpha = run.signal("alpha")
    assert abs(alpha[-1] - alpha[i20]) < 1e-3
    # forward travel of the axle against what the wheels rolled
    x, y, psi = run.signal("x"), run.signal("y"), run.signal("psi")
    travel = (x[-1] - x[i20]) * math.cos(alpha0) + (y[-1] - y[i20]) * math.sin(alpha0)
    rolled = run.config.params.r * (psi[-1] - psi[i20])
    assert abs(travel - rolled) < 1e-3


def test_solver_residual_threshold_is_validated():
    with pytest.raises(TwinError, match="solver_residual_threshold"):
        TwinConfig(solver_residual_threshold=-1.0)
    with pytest.raises(TwinError, match="solver_residual_threshold"):
        TwinConfig(solver_residual_threshold=float("nan"))


def _window_ptp(run, start, length):
    t, theta = run.t, run.signal("theta")
    m = (t >= start) & (t < start + length)
    return float(np.ptp(theta[m]))


def test_short_soak_ekf_in_the_loop_holds_balance_and_estimates():
    """10 simulated minutes of paper-exp2 with the EKF in the loop (the short form of the
    hour-long soak in benchmarks/soak.py). Before issue 16 the filter's scale-factor and
    encoder-zero states drifted (gyro scale +0.13, accelerometer scale +0.24 by 600 s with
    true values of 1 %), ψ̂ − ψ reached 0.076 rad at 600 s and θ's rocking grew into a
    0.35 rad limit cycle by 950 s."""
    run = _run("paper-exp2", "duration=600")
    assert run.status == "ok"
    first = _window_ptp(run, 20.0, 100.0)
    last = _window_ptp(run, 500.0, 100.0)
    assert last <= 1.5 * first, (first, last)
    t = run.t
    settled, last100 = t >= 20.0, t >= 500.0
    for name in ("alpha", "psi"):
        err = np.abs(run.signal(f"{name}_est") - run.signal(name))
        # no drift: the typical error at the end is as small as after settling (before: 0.076 rad)
        assert float(np.median(err[last100])) <= 0.01, (name, float(np.median(err[last100])))
        # brief excursions while a wheel dwells inside one encoder count stay rare; their peak
        # (0.033 rad for ψ in 1200 s) is above 0.02 rad, an open point of issue 16
        assert float(np.percentile(err[settled], 99.0)) <= 0.02, (name, float(err[settled].max()))
    alpha = run.signal("alpha")
    assert abs(alpha[-1] - alpha[int(np.searchsorted(t, 20.0))]) < 1e-3
