"""The EKF's compiled kernel (estimation/_ekf.c) must follow its pure-Python path on
filterpy: same decisions (counts, rejections, events) and the same numbers to rounding
(the kernel sums its matrix products in another order than NumPy)."""
import os

import numpy as np
import pytest

from estimation import replay
from twin.registry import build_estimator_for as build_estimator
from estimation import ekf as ekf_module
from twin.controllers.cascade import build_cascade
from twin.experiments import Experiment
from twin.sim.bullet_loop import simulate_twin
from twin.controllers.lmi import design_balance_gains
from twin.params import NOMINAL
from twin.sensors import SensorConfig
from twin.sensors.faults import Dropout, LatencyChange, Spikes, Stuck

PURE = os.environ.get("TWIN_PURE_PYTHON", "") not in ("", "0")
needs_kernel = pytest.mark.skipif(PURE or ekf_module._kernel is None, reason="compiled EKF kernel not available")


@pytest.mark.skipif(PURE or (ekf_module._kernel is None and not os.environ.get("TWIN_REQUIRE_KERNEL")),
                    reason="kernel not built here (no C compiler?); CI sets TWIN_REQUIRE_KERNEL=1")
def test_kernel_is_built():
    assert ekf_module._kernel is not None, "the compiled module estimation._ekf was not built"


@pytest.fixture(scope="module")
def design():
    return design_balance_gains()


FAULTS = {
    "default noise": (),
    "spikes and dropouts": (Spikes("gyro", rate=5.0, magnitude=3.0), Spikes("encoders", rate=3.0, magnitude=0.5),
                            Dropout("imu", start=1.0, duration=0.2), Dropout("encoders", start=1.5, duration=0.2)),
    "stuck and latency": (Stuck("gyro", start=0.8, duration=0.1), LatencyChange("imu", time=1.2, latency=0.015)),
}


def _replay(run, sensors, compiled):
    f = build_estimator("ekf", sensors, 200.0, run.config.motor, NOMINAL, compiled=compiled)
    assert f.compiled == compiled
    return replay(f, run), f


@needs_kernel
@pytest.mark.parametrize("case", list(FAULTS))
@pytest.mark.parametrize("theta0", [0.2, 0.48])
def test_kernel_follows_python_path(design, case, theta0):
    sensors = SensorConfig(faults=FAULTS[case])
    exp = Experiment("k", "k", theta0=theta0, duration=2.5)
    run = simulate_twin(build_cascade("it2", design, exp.targets), exp, sensors=sensors, seed=3)
    a, fa = _replay(run, sensors, True)
    b, fb = _replay(run, sensors, False)
    sa, sb = fa.stats(), fb.stats()
    assert sa == sb
    # relative as well: a ψ̇ estimate of 8 rad/s after a coasting step has differed by 1.06e-9
    # (1.4e-10 of it) since the default design's inputs became products (issue 25); since
    # clipped samples coast too (issue 29), with the model's parameters in the coasting state,
    # single rows during a catch differ by up to 2.8e-7 relative (3e-8 rad/s in 6.6 rad/s of
    # θ̇: the finite differences' 1e-13 → 1e-7 lift, then the forward prediction through the
    # unstable pendulum); the filters' own states end 1e-15 to 1e-9 apart
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(fa.x, fb.x, rtol=1e-8, atol=1e-10)  # (1.4e-9 relative: the same lift)
    # coasting steps (IMU missing or rejected) run in Python for both, with a Jacobian by
    # central differences (h = 1e-6): that lifts the paths' 1e-13 differences in x to ~1e-7
    # relative in P's smallest elements
    # compared on the scale of each element's correlation: the consider states' tiny cross
    # covariances (~1e-11) are rounding-level differences otherwise
    scale = np.sqrt(np.outer(np.diag(fb.P), np.diag(fb.P)))
    assert np.all(np.abs(fa.P - fb.P) <= 1e-5 * np.abs(fb.P) + 1e-9 * scale + 1e-14)
    np.testing.assert_allclose(fa.covariance6(), fb.covariance6(), rtol=1e-6, atol=1e-15)
    if case != "default noise":
        assert sa["rejected_total"] > 0 or sa["predict_only_steps"] > 0


@needs_kernel
def test_kernel_restores_from_non_finite_state(design):
    """A NaN forced into the kernel's state is caught at the next step: the last good
    state comes back (finite) and the reset is logged."""
    sensors = SensorConfig()
    exp = Experiment("k", "k", theta0=0.1, duration=0.5)
    run = simulate_twin(build_cascade("it2", design, exp.targets), exp, sensors=sensors, seed=0)
    f = build_estimator("ekf", sensors, 200.0, run.config.motor, NOMINAL)
    cmds = run.commands[:, :2]
    f.start(run.measurements[0])
    for i in range(1, 40):
        f.step(run.measurements[i], cmds[i - 1])
    x, P = f.x.copy(), f.P.copy()
    x[0] = np.nan
    f.core.set_state(x, P, (0.0, 0.0), (0.0, 0.0))  # behind the filter's back, in the kernel
    out = f.step(run.measurements[40], cmds[39])
    assert np.isfinite(out).all() and np.isfinite(f.x).all()
    assert f.resets == 1 and "restored the last good estimate" in f.events[-1][1]


def test_compiled_true_without_kernel_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(ekf_module, "_kernel", None)
    from estimation.model import EstimatorModel
    with pytest.raises(ekf_module.TwinError, match="not built"):
        ekf_module.EKFEstimator(EstimatorModel(), compiled=True)
