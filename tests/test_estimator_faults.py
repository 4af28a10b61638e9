"""Faults the EKF once handled badly (issue 16, item 3): a change of the IMU's latency, and
accelerometer spikes. Closed-loop runs on the PyBullet twin with the default sensors and
fixed seeds, θ0 = 0.2 rad, 5 s (as benchmarks/estimator_accuracy.py, section B); the figures
measured when the tests were written are in each docstring.

* Latency: :meth:`estimation.ekf_frontend.SensorFrontEnd.store` (the latency watch) must log the change within
  :data:`DETECT_WITHIN` of it and re-align, so that a gyro that falls 20 ms behind (5 ms
  before) no longer topples the robot (before: 0/10 balanced).
* Accelerometer spikes: each is to be caught at the sample (before: a median 8 of 22 spiked IMU
  samples per run rejected, up to 24 forced encoder re-synchronisations per run).
* Fault-free runs: no latency event, (almost) no accelerometer rejection.
"""
import re

import numpy as np
import pytest

from estimation import replay
from twin.registry import build_estimator_for as build_estimator
from estimation.ekf import EKFEstimator
from twin.sim.bullet_loop import simulate_twin
from twin.controllers.cascade import build_cascade
from twin.experiments import Experiment
from twin.params import NOMINAL
from twin.sensors import LatencyChange, Measurement, SensorConfig, Spikes

FAULT_T = 2.0  # s, when every fault starts
DETECT_WITHIN = 1.5  # s: the latency change is logged by FAULT_T + this (measured: 0.35-1.10 s)
SEEDS = range(10)


def _run(design, faults, seed, theta0=0.2, duration=5.0):
    e = Experiment("faults", "", theta0=theta0, duration=duration)
    return simulate_twin(build_cascade("it2", design, e.targets), e, sensors=SensorConfig(faults=tuple(faults)),
                         seed=seed)


def _latency_events(run):
    """[(t, text)] of the latency-change events of a run's EKF."""
    out = []
    for ev in run.estimator_stats["events"]:
        m = re.match(r"t = ([0-9.]+) s: (.*latency changed.*)", ev)
        if m:
            out.append((float(m.group(1)), m.group(2)))
    return out


def _resyncs(run) -> int:
    return sum("re-synchronising" in ev for ev in run.estimator_stats["events"])


def test_gyro_latency_5_to_20ms_is_detected_and_the_robot_stays_up(design):
    """Gyro 5 → 20 ms at t = 2 s, 10 seeds: measured 10/10 balanced (0/10 before), θ RMSE
    median 1.72 mrad (76 before), the event logged 0.35–0.75 s after the change, naming 20 ms
    and the gyro alone."""
    balanced, late = 0, []
    for s in SEEDS:
        run = _run(design, (LatencyChange("gyro", FAULT_T, 0.020),), s)
        balanced += run.status == "ok"
        ev = _latency_events(run)
        assert ev, f"seed {s}: no latency event; events: {run.estimator_stats['events'][:5]}"
        t, text = ev[0]
        assert text.startswith("gyro latency changed: now about 20 ms (was 5 ms"), text
        if not FAULT_T < t <= FAULT_T + DETECT_WITHIN:
            late.append((s, t))
    assert balanced >= 9, f"only {balanced}/10 balanced"
    assert not late, f"latency change logged outside (2 s, {FAULT_T + DETECT_WITHIN} s]: {late}"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_imu_latency_5_to_20ms_is_detected_for_both_triads(design, seed):
    """Gyro and accelerometer 5 → 20 ms at t = 2 s: measured 0.50–1.10 s to the event (seeds
    0–9), both triads re-aligned (the accelerometer follows when its arrivals stopped for as
    long at the same time)."""
    run = _run(design, (LatencyChange("imu", FAULT_T, 0.020),), seed)
    assert run.status == "ok"
    ev = _latency_events(run)
    assert ev, run.estimator_stats["events"][:8]
    t, text = ev[0]
    assert text.startswith("gyro and accelerometer latency changed: now about 20 ms (was 5 ms"), text
    assert FAULT_T < t <= FAULT_T + DETECT_WITHIN
    assert run.estimator_stats["latency_changes"] == 1


def test_fault_free_runs_raise_no_latency_event_and_reject_no_accelerometer_sample(design):
    """10 fault-free runs from 0.2 rad and 3 from 0.48 rad: measured 0 latency events and 0
    accelerometer rejections (the accelerometer NIS peaked at 17.5 against a gate of 82.9)."""
    runs = [_run(design, (), s) for s in SEEDS] + [_run(design, (), s, theta0=0.48) for s in range(3)]
    for r in runs:
        assert r.status == "ok"
        st = r.estimator_stats
        assert st["latency_changes"] == 0 and not _latency_events(r), st["events"]
        assert st["accel_outliers"] <= 1, st["events"]
    assert sum(r.estimator_stats["accel_outliers"] for r in runs) <= 2


def _spiked(measurements, rng, rate_per_sample, magnitude, t0, t1):
    """The measurements with accelerometer spikes (every axis ±magnitude, random signs) on a
    random set of samples in [t0, t1); returns (measurements, the spiked indices)."""
    out, hit = list(measurements), []
    for i, m in enumerate(out):
        if m.accel is not None and t0 <= m.t < t1 and rng.random() < rate_per_sample:
            signs = rng.integers(0, 2, 3) * 2 - 1
            out[i] = Measurement(m.t, m.gyro, tuple(v + magnitude * s for v, s in zip(m.accel, signs)), m.encoders)
            hit.append(i)
    return out, hit


@pytest.mark.parametrize("compiled", [False, True])
def test_accelerometer_spikes_are_rejected_at_the_sample(design, compiled):
    """±1 m/s² on every accelerometer axis, 10/s for 1 s, injected into the readings of three
    fault-free runs and replayed: each rejection is logged at the spiked sample's time less
    the latency. Measured: 100 % of the spiked samples rejected at the sample (31 of 31, no other), no
    forced re-synchronisation (before: 8 of 22 caught, up to 24 re-synchronisations)."""
    from estimation import ekf as ekf_module

    if compiled and ekf_module._kernel is None:
        pytest.skip("compiled EKF kernel not available (not built, or TWIN_PURE_PYTHON=1)")
    rng = np.random.default_rng(16)
    caught = total = 0
    for s in range(3):
        run = _run(design, (), s)
        meas, hit = _spiked(run.measurements, rng, 10.0 * 0.005, 1.0, FAULT_T, FAULT_T + 1.0)
        f = build_estimator("ekf", run.sensor_config, 200.0, run.config.motor, NOMINAL, compiled=compiled)
        replay(f, run, meas)
        times = {round(t, 3) for t, why in f.events if why.startswith("accelerometer sample rejected")}
        # the filter logs a sample at its own time, one IMU latency (5 ms) before its arrival
        caught += sum(round(meas[i].t - 0.005, 3) in times for i in hit)
        total += len(hit)
        assert sum("re-synchronising" in why for _, why in f.events) <= 2
    assert total >= 20
    assert caught >= 0.9 * total, f"{caught}/{total} spiked accelerometer samples rejected at the sample"


def test_imu_spikes_in_the_loop_cost_no_forced_resynchronisation(design):
    """The benchmark's fault row 'IMU spikes' (±1 rad/s, ±1 m/s², 10/s for 1 s), 3 seeds in
    the loop: measured 0 forced re-synchronisations, every spiked gyro sample rejected and
    accelerometer outliers ≥ its spiked samples (before: up to 24 re-synchronisations)."""
    for s in range(3):
        run = _run(design, (Spikes("imu", FAULT_T, 1.0, rate=10.0, magnitude=1.0),), s)
        assert run.status == "ok"
        assert _resyncs(run) <= 2
        st, sc = run.estimator_stats, run.sensor_counts
        # a spike on both halves is caught by the encoders (whole sample); one on the
        # accelerometer alone by the model: every spiked accelerometer sample is rejected
        assert st["rejected"]["accel"] >= 0.9 * sc["accel"]["spiked"]


def test_a_push_is_not_taken_for_an_accelerometer_spike(design):
    """The push-recovery built-in's shoves move the specific force for 0.1 s and θ̈ with it:
    the gyro disagrees with the model too, so no accelerometer sample is rejected (measured
    0; before the gyro check, 5 and a fall)."""
    from twin.workflows.run import run_scenario
    from twin.scenarios.scenario import load_scenario

    res = run_scenario(load_scenario("push-recovery"), controllers="it2")
    run = res.runs[0]
    assert run.status == "ok"
    assert run.estimator_stats["accel_outliers"] == 0


def test_latency_watch_is_off_for_a_slower_imu():
    """The watch's kernel assumes one IMU sample per control period; with fewer it stays off."""
    from estimation.model import EstimatorModel
    from twin.plant.bullet import TwinConfig
    from twin.sensors import ImuSpec

    sc = SensorConfig(imu=ImuSpec(rate=100.0))
    model = EstimatorModel(NOMINAL, TwinConfig().motor, sc.imu, sc.encoders, 200.0)
    assert not EKFEstimator(model, *sc.steps(200.0))._watch
    sc = SensorConfig()
    model = EstimatorModel(NOMINAL, TwinConfig().motor, sc.imu, sc.encoders, 200.0)
    assert EKFEstimator(model, *sc.steps(200.0))._watch
