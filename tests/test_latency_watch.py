"""The EKF's latency watch (:class:`estimation.ekf_policies.LatencyWatch`) against pushes (issue 29,
part 3): a shove's catch is no latency change, and a latency change is still one.

Before: the watch left out every row of Δ²ω_y beyond 5 robust σ (against gyro spikes), which
during a shove were the catch's rows - the ones the commands at the true latency explain
best - and the catch's slow remainder then correlated best at 25–30 ms: push-recovery logged
false "gyro latency changed" events on 13 of its 30 runs at seeds 0–9 (it2, t1, lqr; seeds 3,
6 and 8 among them, after the shove at 3 s or 8 s). Now the watch leaves out the samples the
filter rejected as outliers (spikes), stale and clipped ones, and keeps every other row,
winsorised at 5 robust σ (so that spikes the filter lets through cannot carry the sums).
``benchmarks/latency_watch_sweep.py`` runs the full sweep (every built-in, 50 seeds, three
controllers) and the injected changes. The two tests that the fault table's changes are still
detected in time are in tests/test_estimator_faults.py; here one more, and one in a push
scenario.
"""
import math
import re

import numpy as np
import pytest

from estimation import replay
from estimation.ekf_policies import WATCH_MAX_LAG, WATCH_WINDOW, LatencyWatch
from twin.controllers.cascade import build_cascade
from twin.experiments import Experiment
from twin.params import NOMINAL
from twin.registry import build_estimator_for as build_estimator
from twin.sensors import LatencyChange, Measurement, SensorConfig
from twin.sim.bullet_loop import simulate_twin

STATED = 1.5  # s: an injected change is logged within this (tests/test_estimator_faults.py)


def _latency_events(run_or_events):
    evs = run_or_events.estimator_stats["events"] if hasattr(run_or_events, "estimator_stats") else run_or_events
    out = []
    for ev in evs:
        m = re.match(r"t = ([0-9.]+) s: (.*latency changed.*)", ev)
        if m:
            out.append((float(m.group(1)), m.group(2)))
    return out


def _scenario(name, seed, controllers, extra_toml=""):
    """The runs of built-in ``name`` at ``seed``, with ``extra_toml`` appended to its file."""
    from twin.workflows.run import run_scenario
    from twin.scenarios.scenario import load_scenario

    if not extra_toml:
        return run_scenario(load_scenario(name, [f"seed={seed}"]), controllers=controllers).runs
    import importlib.resources

    text = importlib.resources.files("twin.scenarios.builtin").joinpath(f"{name}.toml").read_text(encoding="utf-8")
    return _scenario_text(text + extra_toml, seed, controllers)


def _scenario_text(text, seed, controllers):
    """The runs of the scenario file ``text`` at ``seed``."""
    import os
    import tempfile

    from twin.workflows.run import run_scenario
    from twin.scenarios.scenario import load_scenario

    fd, path = tempfile.mkstemp(suffix=".toml", prefix="scenario-")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    try:
        return run_scenario(load_scenario(path, [f"seed={seed}"]), controllers=controllers).runs
    finally:
        os.unlink(path)


@pytest.mark.parametrize("seed", [3, 6, 8])
def test_push_recovery_catches_are_no_latency_change(seed):
    """push-recovery with IT2, type-1 and LQR: no latency event. Before the fix: seed 3 gave
    one for IT2 and type-1 after the 8 s shove when the issue was filed (ρ 0.30; type-1's θ
    RMSE 5.6 mrad), and for LQR after the 3 s shove on the code this was fixed on; seed 6
    for IT2 and type-1 after 8 s (ρ 0.40 and 0.29 at 30 ms); seed 8 for all three (ρ
    0.24–0.30 at 25–30 ms). Measured now: none, θ RMSE at most 1.24 mrad (seeds 0–9)."""
    for run in _scenario("push-recovery", seed, "it2,t1,lqr"):
        assert run.status == "ok"
        assert run.estimator_stats["latency_changes"] == 0 and not _latency_events(run), \
            (run.controller, _latency_events(run))
        assert run.estimation_rmse("theta") < 0.003, run.controller


@pytest.mark.parametrize("magnitude", [0.1, 0.2])
def test_gyro_spikes_the_filter_lets_through_set_off_no_latency_event(magnitude):
    """sensor-faults with its gyro spikes at ±0.1 and ±0.2 rad/s instead of ±0.5, seed 0, IT2
    and type-1: the filter's outlier test lets most of them through (0–2 of 8 rejected), so
    they stay in the watch's window, where unbounded they carried the sums (a false change
    to 0 ms at 4.15 s for IT2 at 0.1 rad/s and type-1 at 0.2 rad/s); winsorised, no event."""
    import importlib.resources

    builtin = importlib.resources.files("twin.scenarios.builtin")
    text = builtin.joinpath("sensor-faults.toml").read_text(encoding="utf-8")
    assert "magnitude = 0.5" in text
    for run in _scenario_text(text.replace("magnitude = 0.5", f"magnitude = {magnitude}", 1), 0, "it2,t1"):
        assert run.status == "ok"
        assert not _latency_events(run), (run.controller, _latency_events(run))


def test_a_gyro_latency_change_is_still_detected(design):
    """The fault table's set-up (θ0 = 0.2 rad, IT2, gyro 5 → 20 ms at 2 s), seed 0: logged
    with the new latency within the stated time (measured 0.25–0.50 s on seeds 0–9)."""
    e = Experiment("faults", "", theta0=0.2, duration=4.0)
    run = simulate_twin(build_cascade("it2", design, e.targets), e,
                        sensors=SensorConfig(faults=(LatencyChange("gyro", 2.0, 0.020),)), seed=0)
    assert run.status == "ok"
    ev = _latency_events(run)
    assert ev and ev[0][1].startswith("gyro latency changed: now about 20 ms (was 5 ms"), ev
    assert 2.0 < ev[0][0] <= 2.0 + STATED
    assert run.estimator_stats["latency_changes"] == 1


def test_a_latency_change_between_shoves_is_detected():
    """push-recovery with a gyro latency change 5 → 20 ms at 5.5 s (between its shoves), IT2,
    seed 0: no event before it, the change logged within the stated time, and no other."""
    toml = '\n[[faults]]\nkind = "latency"\nsensor = "gyro"\nstart = 5.5\nlatency = 0.02\n'
    (run,) = _scenario("push-recovery", 0, "it2", toml)
    assert run.status == "ok"
    ev = _latency_events(run)
    assert len(ev) == 1 and ev[0][1].startswith("gyro latency changed: now about 20 ms (was 5 ms"), ev
    assert 5.5 < ev[0][0] <= 5.5 + STATED


def test_filter_verdicts_forget_the_rejected_sample():
    """LatencyWatch.filter_verdicts: a sample the filter rejected (its outlier count grew) is
    forgotten at its arrival step (sample time + latency), nothing else."""
    w = LatencyWatch(-1.0)
    n = WATCH_WINDOW + WATCH_MAX_LAG + 5
    for k in range(1, n + 10):
        w.filter_verdicts(k - 2, 0, 1)
        w.observe(0.005 * k, k, (0.0, 0.001 * k, 0.0), True, (0.0, 0.0), 1)
    k = n + 9  # the last step observed; the filter has used sample k − 2 (arrived at k − 1)
    assert all(np.isfinite(w.y))  # no outlier counted: nothing forgotten
    w.filter_verdicts(k - 1, 1, 1)  # it used sample k − 1 (arrived at step k) and rejected it
    assert math.isnan(w.y[-1]) and all(np.isfinite(w.y[:-1]))
    assert w.verdicts == (k - 1, 1)


@pytest.mark.parametrize("compiled", [False, True])
def test_the_watch_leaves_out_the_gyro_spikes_the_filter_rejects(design, compiled):
    """±0.5 rad/s on every gyro axis at 5 samples of the last 0.5 s of a fault-free run,
    replayed: each sample the filter rejected as an outlier is NaN in the watch's window, and
    the window holds no other NaN; the watch's last check still finds the true latency."""
    from estimation import ekf as ekf_module

    if compiled and ekf_module._kernel is None:
        pytest.skip("compiled EKF kernel not available (not built, or TWIN_PURE_PYTHON=1)")
    e = Experiment("faults", "", theta0=0.2, duration=3.0)
    run = simulate_twin(build_cascade("it2", design, e.targets), e, sensors=SensorConfig(), seed=1)
    meas = list(run.measurements)
    hit = list(range(len(meas) - 95, len(meas) - 5, 18))
    for i in hit:
        m = meas[i]
        meas[i] = Measurement(m.t, tuple(v + 0.5 for v in m.gyro), m.accel, m.encoders)
    f = build_estimator("ekf", run.sensor_config, 200.0, run.config.motor, NOMINAL, compiled=compiled)
    replay(f, run, meas)
    w = f._watch
    rejected = {round(t, 3) for t, why in f.events if why.startswith("IMU sample rejected")}
    # the filter logs a sample at its own time, one latency (5 ms) before its arrival
    spiked_rejected = [i for i in hit if round(meas[i].t - 0.005, 3) in rejected]
    assert len(spiked_rejected) >= 4
    # meas[i] arrived at control step i (the first measurement starts the filter at step 0)
    nan_steps = {w.k - (len(w.y) - 1 - j) for j, v in enumerate(w.y) if math.isnan(v)}
    assert nan_steps == set(spiked_rejected)
    assert w.last is not None and w.last[1] == 1
