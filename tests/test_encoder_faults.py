"""Encoders that stop counting, or stop arriving, while the robot moves (issue 29).

An unchanged count while the IMU-driven prediction has left it by more than 3.72 σ is a rejected
measurement; five in a row and the EKF takes the encoders as stuck (an event), drops their samples
until the counts change again, and runs position and speed on the IMU alone. A run that ends so has
status "degraded", its ``end_reason`` naming the position. Before: the unchanged counts were taken
as the truth, the filter fought the IMU, logged false "gyro latency changed: now about 35 ms" events
and the robot fell in 10 of 10 runs (paper-exp3, stuck from 3 s).
"""
from __future__ import annotations

import numpy as np
import pytest

from twin.outputs.metrics import run_metrics
from twin.scenarios import load_scenario
from twin.sim.simulate import simulate

STUCK = '[{kind="stuck", sensor="encoders", start=3}]'
GONE = '[{kind="dropout", sensor="encoders", start=3, duration=100}]'


def _run(scenario: str, faults: str, seed: int, kind: str = "it2"):
    sc = load_scenario(scenario, [f"seed={seed}", f"faults={faults}"])
    return simulate(sc.run_spec(kind))


def test_encoders_stuck_for_good_are_detected_and_the_robot_balances_on_the_imu():
    """paper-exp3, encoders stuck from 3 s, IT2, seeds 0-9: at least 9 of 10 run their 15 s
    (measured 10/10, |θ̂ − θ| at most 15 mrad), each declares the encoders stuck within 0.1 s,
    logs no latency change, and ends "degraded" naming the lost position."""
    balanced = 0
    for seed in range(10):
        r = _run("paper-exp3", STUCK, seed)
        st = r.estimator_stats
        assert st["latency_changes"] == 0, (seed, st["events"])
        stuck = [e for e in st["events"] if "taken as stuck" in e]
        assert stuck, (seed, st["events"])
        assert 3.0 <= float(stuck[0].split()[2]) <= 3.1, stuck[0]
        if r.status in ("ok", "degraded") and r.t[-1] >= 15.0 - 1e-9:
            balanced += 1
            assert r.status == "degraded" and r.end_reason.startswith("position: encoders stuck since t = 3.0"), \
                (seed, r.status, r.end_reason)
            assert not r.fell
            assert np.abs(r.signal("theta_est") - r.signal("theta")).max() < 0.03
    assert balanced >= 9, balanced


def test_encoders_gone_for_good_leave_the_run_degraded_and_say_so_in_its_metrics():
    r = _run("paper-exp3", GONE, 0)
    assert r.status == "degraded" and not r.fell
    assert r.end_reason.startswith("position: no encoder sample since t = 2.99"), r.end_reason
    m = run_metrics(r)
    assert m["status"] == "degraded" and m["fell"] is False and m["end_reason"] == r.end_reason


@pytest.mark.parametrize("kind", ["it2", "lqr"])
def test_encoders_stuck_for_a_while_are_used_again_when_they_count(kind):
    """sensor-faults freezes both encoders at 7 s for 0.3 s: taken as stuck within 25 ms, used again
    when they count at 7.3 s; the run ends "ok"."""
    r = _run("sensor-faults", '[{kind="stuck", sensor="encoders", start=7.0, duration=0.3}]', 0, kind)
    st = r.estimator_stats
    assert r.status == "ok", (r.status, r.end_reason)
    assert any("taken as stuck" in e for e in st["events"]) and any("used again" in e for e in st["events"])
    assert 0.2 <= st["encoders_stuck_s"] <= 0.3
    assert st["degraded"] == [] and st["latency_changes"] == 0


def test_a_robot_at_rest_with_unchanged_counts_is_not_taken_as_stuck():
    """Balancing in place (paper-exp1 from 0.05 rad, 5 s) the counts dwell for tenths of a second:
    that is no fault."""
    sc = load_scenario("paper-exp1", ["seed=0", "duration=5", "initial.theta=0.05"])
    r = simulate(sc.run_spec("it2"))
    st = r.estimator_stats
    assert r.status == "ok" and st["encoders_stuck_s"] == 0.0 and st["unchanged_encoder_samples"] > 100
    assert not any("stuck" in e for e in st["events"]), st["events"]
