"""The twin's compiled hot path must equal its pure-Python path bit for bit."""
import math
import os

import numpy as np
import pytest

from twin.actuators import DCMotorParams, MotorDriver
from twin.controllers.cascade import build_cascade
from twin.experiments import Experiment
from twin.sim.bullet_loop import simulate_twin as _simulate_twin
from twin.plant import bullet
from twin.plant.bullet import GroundTruth, TwinConfig, truth_from_states


def simulate_twin(*args, **kwargs):
    """These are tests of the plant: the controllers read the ground truth (ideal sensing)."""
    return _simulate_twin(*args, sensors=None, **kwargs)

PURE = os.environ.get("TWIN_PURE_PYTHON", "") not in ("", "0")
needs_fastpath = pytest.mark.skipif(PURE or bullet._fastpath is None, reason="compiled fast path not available")


def _bits(values) -> bytes:
    return np.array([float(v) for v in values]).tobytes()


@pytest.mark.skipif(PURE or (bullet._fastpath is None and not os.environ.get("TWIN_REQUIRE_KERNEL")),
                    reason="fast path not built here (no C compiler?); CI sets TWIN_REQUIRE_KERNEL=1")
def test_fastpath_is_built():
    assert bullet._fastpath is not None, "the compiled module twin.plant._fastpath was not built"


def _random_states(rng, n):
    for i in range(n):
        q = rng.normal(size=4)
        if i % 7 == 0:
            q[[0, 2]] = 0.0  # pure pitch and yaw, as on a level floor
        q /= np.linalg.norm(q)
        scale = 10.0 ** rng.integers(-6, 3)
        pose = (tuple(rng.normal(size=3)), tuple(q))
        vel = (tuple(rng.normal(size=3)), tuple(scale * rng.normal(size=3)))
        joints = tuple((float(a), float(b), (0.0,) * 6, 0.0) for a, b in rng.normal(scale=30.0, size=(2, 2)))
        alpha_prev = None if i % 5 == 0 else float(rng.normal(scale=20.0))
        com = tuple(rng.normal(scale=0.05, size=3))
        yield pose, vel, joints, alpha_prev, com, float(rng.uniform(0.01, 0.2)), float(i) * 0.005


@needs_fastpath
def test_truth_arithmetic_is_identical():
    rng = np.random.default_rng(0)
    for args in _random_states(rng, 20000):
        py, py_axle = truth_from_states(GroundTruth, *args)
        c, c_axle = bullet._fastpath.truth(GroundTruth, *args)
        assert type(c) is GroundTruth
        assert _bits(py) == _bits(c) and _bits(py_axle) == _bits(c_axle), args


@needs_fastpath
@pytest.mark.parametrize("motor", [
    DCMotorParams(),
    DCMotorParams(pwm_bits=8, dead_band=0.05),
    DCMotorParams(back_emf_compensation=False, current_limit=2.0),
    DCMotorParams(pwm_bits=16, supply_voltage=24.0, stall_torque=0.5, no_load_speed=80.0),
], ids=["default", "8bit-deadband", "no-compensation", "16bit"])
def test_motor_update_is_identical(motor):
    """Saturation, dead band, quantisation (ties to even, no −0.0), compensation on and off."""
    rng = np.random.default_rng(1)
    driver = MotorDriver(motor)
    consts = driver.constants
    cmds = np.concatenate([rng.normal(scale=0.5, size=20000), [0.0, -0.0, 1e-12, -1e-12, 5.0, -5.0]])
    speeds = np.concatenate([rng.normal(scale=30.0, size=20000), [0.0, 0.0, 0.0, 0.0, 100.0, -100.0]])
    # commands landing exactly on half a PWM step test the rounding of ties
    half = (np.arange(-40, 40) + 0.5) / motor.pwm_steps * motor.stall_torque
    cmds = np.concatenate([cmds, half])
    speeds = np.concatenate([speeds, np.zeros_like(half)])
    for ul, w in zip(cmds, speeds):
        dl, dr, tq_l, tq_r, sl, sr, t0l, t0r = bullet._fastpath.motors(float(ul), -float(ul), float(w), -float(w),
                                                                       *consts)
        for (d, s, t0, tq), cmd, omega in (((dl, sl, t0l, tq_l), ul, w), ((dr, sr, t0r, tq_r), -ul, -w)):
            pd, ps, pt0, ptq = driver.update(float(cmd), float(omega))
            assert _bits((d, t0, tq)) == _bits((pd, pt0, ptq)) and s is ps, (cmd, omega)
            assert math.copysign(1.0, d) == math.copysign(1.0, pd)


@needs_fastpath
def test_closed_loop_trajectory_is_identical(design, monkeypatch):
    """A whole run with pushes and the default motor: compiled and pure-Python twins agree bit for bit."""
    from twin.plant.disturbances import Disturbances, Push

    e = Experiment("fast", "", theta0=0.3, p_d=0.3, alpha_d=0.5, duration=3.0)
    ctrl = build_cascade("it2", design, e.targets)
    cfg = TwinConfig(disturbances=Disturbances(pushes=(Push((6.0, 1.0, 0.0), 1.0, 0.1),)))
    fast = simulate_twin(ctrl, e, cfg)
    monkeypatch.setattr(bullet, "_fastpath", None)
    slow = simulate_twin(ctrl, e, cfg)
    for a, b in ((fast.truth, slow.truth), (fast.actuation, slow.actuation), (fast.commands, slow.commands)):
        assert a.tobytes() == b.tobytes()


def test_benchmark_script_runs(tmp_path):
    """benchmarks/bench_twin.py --quick runs to its result line (a smoke test, not a timed test)."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_twin.py"
    r = subprocess.run([sys.executable, str(script), "--quick"], capture_output=True, text=True, cwd=tmp_path,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "RESULT: twin" in r.stdout and "physics steps/s" in r.stdout
