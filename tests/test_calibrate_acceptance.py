"""Issue 30's acceptance: twenty seeded robots, each logged by the twin and calibrated from its log.

The robots (benchmarks/calibration_plants.py): Table III with m_b, l and n_yb scaled within ±30 %,
d_b and d_w within ×0.5–×2, a gyro turn-on bias of their own; paper-exp3 plus a 12 N push, noisy
sensors, the EKF in the loop, logged with ``--log-sensors``. The truth is what the twin ran: the
plant from the ``--set plant.scale`` factors (not the log's [robot], which is the estimator's
model), the gyro biases from truth.csv (their mean over the fitted windows: they drift), the scale
factors from the log's [truth] table, the IMU latency of the scenario.

Twenty calibrations take about 4 minutes of CPU; two worker processes share them.
"""
from __future__ import annotations

import importlib.util
import json
import multiprocessing
import os
import subprocess
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
COUNT = 20
NEED = 18  # of 20
_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _plants_module():
    spec = importlib.util.spec_from_file_location("calibration_plants", ROOT / "benchmarks" / "calibration_plants.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run(cmd):
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, cwd=ROOT)


def _calibrate(job):
    """One robot: calibrate its log, validate on its held-out log (if any); the numbers the tests need."""
    from twin.calibrate.identify import assess
    from twin.calibrate.run import TURN_RATE, calibrate
    from twin.calibrate.validate import validate
    from twin.logs.format import read_log
    from twin.params import NOMINAL

    plant, held = job
    log = read_log(plant["log"])
    cal = calibrate([log])
    params, warnings, _ = assess(cal, TURN_RATE)
    true = NOMINAL.perturbed(scale=plant["scale"])
    t = log.truth_t
    t0 = cal.fit.windows.t0
    span = (t >= t0.min()) & (t <= t0.max() + cal.fit.windows.periods / log.control_rate)
    bias = np.nanmean(log.truth_state[span, 2:5], axis=0)
    tc = log.truth_constants
    truth = {n: getattr(true, n) for n in ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w")}
    truth.update(gyro_bias_x=bias[0], gyro_bias_y=bias[1], gyro_bias_z=bias[2],
                 accel_bias_x=0.0,  # the accelerometer's turn-on bias is 0 in the preset; its drift over 15 s ~1e-4
                 gyro_scale_y=tc["gyro_scale"][1], gyro_scale_z=tc["gyro_scale"][2],
                 accel_scale_x=tc["accel_scale"][0], accel_scale_z=tc["accel_scale"][2],
                 imu_latency=log.sensors.imu.latency)
    out = {"plant": plant["plant"], "params": {n: {"value": e["value"], "ci95": e["ci95"], "identifiable": e["identifiable"],
                                                    "truth": float(truth[n])} for n, e in params.items()},
           "warnings": warnings, "validation": None}
    if held:
        out["validation"] = validate(cal, [read_log(held)])[0]["ratio"]
    return out


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    cp = _plants_module()
    out = tmp_path_factory.mktemp("calibration-plants")
    plants = cp.draw(COUNT)
    jobs, cmds = [], []
    for p in plants:
        run = out / f"plant-{p['plant']}"
        p["log"] = str(run / "sensor-logs" / "it2")
        cmds.append(cp.command(p, run))
        far = abs(p["scale"]["m_b"] - 1.0) >= 0.15 or abs(p["scale"]["l"] - 1.0) >= 0.15
        held = None
        if far:
            held_run = out / f"held-{p['plant']}"
            cmds.append(cp.command(p, held_run, held_out=True))
            held = str(held_run / "sensor-logs" / "it2")
        jobs.append((p, held))
    # two worker processes on the two cores, each with one BLAS thread (two each oversubscribe the
    # cores and slow the fits twofold); spawned, so that the setting reaches their numpy
    saved = {k: os.environ.get(k) for k in _THREADS}
    os.environ.update({k: "1" for k in _THREADS})
    try:
        with ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn")) as pool:
            list(pool.map(_run, cmds))
            results = list(pool.map(_calibrate, jobs))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    (out / "results.json").write_text(json.dumps(results, indent=1, default=float))
    return results


def test_identifiable_parameters_lie_inside_their_intervals(study):
    names = sorted({n for r in study for n in r["params"]})
    misses = {}
    for n in names:
        called = [r for r in study if n in r["params"] and r["params"][n]["identifiable"]]
        outside = [r["plant"] for r in called
                   if not r["params"][n]["ci95"][0] - 1e-12 <= r["params"][n]["truth"] <= r["params"][n]["ci95"][1] + 1e-12]
        if len(outside) > COUNT - NEED:
            misses[n] = outside
    assert not misses, f"identifiable parameters outside their 95 % interval in more than {COUNT - NEED} plants: {misses}"


def test_body_parameters_within_five_percent(study):
    bad = {}
    for n in ("m_b", "l", "n_yb"):
        off = [(r["plant"], round(r["params"][n]["value"] / r["params"][n]["truth"] - 1.0, 4)) for r in study
               if abs(r["params"][n]["value"] / r["params"][n]["truth"] - 1.0) > 0.05]
        if len(off) > COUNT - NEED:
            bad[n] = off
    assert not bad, f"more than {COUNT - NEED} of {COUNT} plants off by over 5 %: {bad}"


def test_the_body_is_identified(study):
    # the floor is about the body's parameters: the report must not dodge it by calling them unidentified
    for n in ("m_b", "l", "n_yb", "d_w"):
        called = sum(r["params"][n]["identifiable"] for r in study)
        assert called >= NEED, f"{n} identifiable in only {called} of {COUNT} plants"


def test_calibrated_twin_predicts_held_out_logs_twice_as_well(study):
    far = [r for r in study if r["validation"] is not None]
    assert len(far) >= 5, "the draw has too few plants 15 % off in m_b or l to test the validation"
    worse = [(r["plant"], round(r["validation"], 2)) for r in far if r["validation"] < 2.0]
    assert not worse, f"calibrated twin not twice as good as the nominal on held-out logs: {worse}"
