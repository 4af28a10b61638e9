"""Issue 29 (4b): the EKF's events and its NEES/NIS summary in every run's metrics.json and in
``twin run``'s summary, computed while the run goes (memory independent of its length), and the
filter log's lag in force at every row.

What is held here:

* the summary streamed by :class:`estimation.consistency.RunningConsistency` during a default
  run (no filter log) equals :func:`estimation.consistency.summary` of the same run logged with
  its diagnostics, to the bit, over several blocks of rows; its NEES equals
  :func:`estimation.consistency.nees` averaged over the rows from 0.5 s, and that agrees with
  ``np.linalg.solve`` to 1e-9;
* the meter's memory does not grow with the run;
* metrics.json's ``estimator`` section (stats, events with times, encoder re-synchronisations,
  consistency) and the flat ``estimator_*`` metrics; none under ideal sensing; a plugin's
  ``stats()`` made JSON-safe;
* ``twin run`` prints one line per estimator;
* after a detected latency change the rows are aligned with the filter's own time: the mean NEES
  after the change is smallest there among the truth shifted by −3 … +3 periods, and the
  starting lag (the filter log's one number before) gives 1.4–4× as much;
* ``twin check`` may bound the new metrics.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import tracemalloc
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from estimation.consistency import (DIM, NEES_START, ONE_RUN_NEES_BOUNDS, SUM_BLOCK, RunningConsistency,
                                    TruthConstants, filter_rows, nees, run_truth, state_matrix, summary)
from estimation.detlinalg import quad_inv_rows
from twin.errors import TwinError
from twin.outputs.metrics import exact_mean, jsonable, run_metrics
from twin.outputs.report import estimator_line
from twin.scenarios import load_scenario
from twin.scenarios.planning import plan
from twin.workflows.run import run_scenario
from twin.sim.simulate import simulate
from twin.sim.spec import Logging


def _spec(*overrides, scenario="paper-exp1", kind="it2"):
    return plan(load_scenario(scenario, list(overrides)), [kind])[0]


@pytest.fixture(scope="module")
def pair():
    """paper-exp1 from 0.48 rad, 6.5 s (1301 rows: two blocks of the sums), seed 3: the same run
    with the default logging and with the filter's diagnostics."""
    spec = _spec("duration=6.5", "seed=3")
    return simulate(spec), simulate(replace(spec, logging=Logging(1, True)))


# ---- the streamed summary is the batch one ----------------------------------------------------
def test_the_streamed_summary_equals_the_batch_on_the_filter_log_to_the_bit(pair):
    plain, logged = pair
    assert plain.filter_log is None and logged.filter_log is not None
    assert len(plain.t) == 1301 > SUM_BLOCK
    got = plain.estimator_consistency
    assert got == logged.estimator_consistency == summary(logged)  # floats compared exactly
    assert got["start_s"] == NEES_START and got["states"] == DIM and got["nees_bounds"] == list(ONE_RUN_NEES_BOUNDS)
    q = nees(logged)
    keep = (logged.t >= NEES_START - 1e-9) & np.isfinite(q)
    assert got["rows"] == int(keep.sum()) == len(logged.t) - 100  # every row from 0.5 s on
    assert got["nees_mean"] == pytest.approx(exact_mean(q[keep]), rel=1e-15, abs=0)
    fl = logged.filter_log
    on = keep & (fl["nis_dof"] > 0) & np.isfinite(fl["nis"])
    assert got["nis_updates"] == int(on.sum()) and got["nis_dof"] == int(fl["nis_dof"][on].sum())
    assert got["nis_per_dof"] == pytest.approx(math.fsum(fl["nis"][on].tolist()) / got["nis_dof"], rel=1e-15)
    assert 4.0 < got["nees_mean"] < 30.0 and 0.7 < got["nis_per_dof"] < 1.4  # a filter about consistent


def test_the_pure_python_core_feeds_the_same_summary():
    """The reference path (filterpy, ``compiled=False``): its core's ``state_into`` gives the
    summary the filter log does."""
    from twin.controllers.lqr import LQRController
    from twin.experiments import Experiment
    from twin.params import NOMINAL
    from twin.plant.bullet import TwinConfig
    from twin.registry import build_estimator_for
    from twin.sensors import SensorConfig
    from twin.sim.bullet_loop import simulate_twin

    exp, config, sensors = Experiment("pure", "", theta0=0.2, duration=1.0), TwinConfig(), SensorConfig()
    runs = []
    for log_filter in (False, True):
        est = build_estimator_for("ekf", sensors, config.control_rate, config.motor, NOMINAL, compiled=False)
        assert not est.compiled
        runs.append(simulate_twin(LQRController(), exp, config, sensors=sensors, estimator=est, seed=5,
                                  log_filter=log_filter))
    assert runs[0].estimator_consistency == runs[1].estimator_consistency == summary(runs[1])
    assert runs[0].estimator_consistency["rows"] == 101


def test_nees_agrees_with_linalg_solve_and_a_row_alone_with_the_stack(pair):
    _, logged = pair
    x, P = logged.filter_log["x"], logged.filter_log["P"]
    e = x - state_matrix(run_truth(logged), logged.filter_log["lag"])
    ok = np.isfinite(e).all(axis=1)
    ref = np.einsum("ti,ti->t", e[ok], np.linalg.solve(P[ok], e[ok][..., None])[..., 0])
    got = nees(logged)[ok]
    assert np.max(np.abs(got - ref) / ref) < 1e-9
    rows = np.flatnonzero(ok)[[0, 7, 500, -1]]
    alone = [quad_inv_rows(P[i:i + 1], e[i:i + 1])[0] for i in rows]
    assert alone == nees(logged)[rows].tolist()  # a row's value does not depend on the others


def test_quad_inv_rows_on_ill_conditioned_covariances():
    """Variances spanning 12 decades, as the EKF's (scale factors to 1e-12): within 1e-9 of
    LAPACK; a singular matrix gives a non-finite value for its row alone."""
    rng = np.random.default_rng(0)
    m, n = 300, 12
    A = rng.normal(size=(m, n, n))
    s = 10.0 ** rng.uniform(-6, 0, size=(m, n))
    P = s[:, :, None] * (A @ A.transpose(0, 2, 1) + 1e-3 * np.eye(n)) * s[:, None, :]
    e = rng.normal(size=(m, n)) * s
    ref = np.einsum("ti,ti->t", e, np.linalg.solve(P, e[..., None])[..., 0])
    assert np.max(np.abs(quad_inv_rows(P, e) - ref) / ref) < 1e-9
    P[3] = 0.0
    got = quad_inv_rows(P, e)
    assert not np.isfinite(got[3]) and np.isfinite(np.delete(got, 3)).all()


def test_one_run_bounds_are_scipys():
    from scipy.stats import chi2

    assert ONE_RUN_NEES_BOUNDS == tuple(float(v) for v in chi2.ppf([0.025, 0.975], DIM))


def test_the_meters_memory_does_not_grow_with_the_run():
    """Ten blocks of synthetic rows (a lag of 2 periods): what the meter keeps is one block of
    x and P and the truth of the rows the filter has not reached, whatever the run's length;
    traced memory after 10 blocks as after 2."""
    c = TruthConstants((0.0,) * 3, (0.0,) * 3, (0.5, 0.5), (0.0, 0.0, 0.1), 0.04, 4.0, 2 * math.pi / 1200)
    meter = RunningConsistency(c)
    state = np.concatenate([np.zeros(DIM), np.eye(DIM).ravel()])
    bias = (0.0, 0.0, 0.0)
    tracemalloc.start()
    peaks = []
    for block in range(10):
        for j in range(SUM_BLOCK):
            meter.add(((block * SUM_BLOCK + j) * 0.005,) + (0.0,) * 14, bias, state, math.nan, 0, 2)
        assert len(meter._pending) == 0 and meter._truth.shape[0] <= 3
        peaks.append(tracemalloc.get_traced_memory()[0])
    tracemalloc.stop()
    assert peaks[-1] < peaks[1] + 50_000, peaks
    r = meter.result()
    assert r["rows"] == 10 * SUM_BLOCK - 100  # from 0.5 s on
    assert r["nees_mean"] == 0.0 and r["nis_per_dof"] is None and r["nis_updates"] == 0
    meter.add((60.0,) + (0.0,) * 14, bias, state, math.nan, 0, 2)
    with pytest.raises(TwinError, match="after result"):
        meter.result()


# ---- the filter log's lag, and alignment after a latency change -------------------------------
def test_filter_rows_from_a_scalar_lag_are_the_old_alignment_and_follow_a_changing_one():
    assert filter_rows(2, 6).tolist() == [0, 0, 0, 1, 2, 3]  # rows 0 … lag: the filter has not stepped
    # the lag grows 1 → 4 at row 5: the filter pauses at 4 until i − 4 catches up, then steps on
    lag = np.array([1, 1, 1, 1, 1, 4, 4, 4, 4, 4, 4])
    assert filter_rows(lag, 11).tolist() == [0, 0, 1, 2, 3, 3, 3, 3, 4, 5, 6]
    # it shrinks 4 → 1 at row 8: the steps due are made at once
    lag = np.array([4] * 8 + [1] * 3)
    assert filter_rows(lag, 11).tolist() == [0, 0, 0, 0, 0, 1, 2, 3, 7, 8, 9]


@pytest.fixture(scope="module")
def latency_runs():
    """paper-exp1 from θ0 = 0.2 rad, the gyro's latency 5 → 20 ms at 2 s, 6 s, the filter logged;
    seeds 0–4."""
    runs = []
    for seed in range(5):
        spec = _spec("duration=6", f"seed={seed}", "initial.theta=0.2",
                     "faults=[{kind='latency', sensor='gyro', start=2, latency=0.02}]")
        runs.append(simulate(replace(spec, logging=Logging(1, True))))
    return runs


def test_the_filter_log_keeps_the_lag_in_force_at_every_row(latency_runs):
    for run in latency_runs:
        lag = run.filter_log["lag"]
        assert lag.shape == run.t.shape and lag.dtype.kind == "i"
        changed = np.flatnonzero(np.diff(lag))
        assert len(changed) == 1 and lag[0] == 1 and lag[-1] == 4  # 5 ms, then 20 ms: 1, then 4 periods
        t = run.t[changed[0] + 1]
        assert 2.0 < t < 3.5
        assert any("latency changed" in e and abs(float(e[4:e.index(" s:")]) - t) < 1e-9
                   for e in run.estimator_stats["events"])
        # while the filter waits for t_{i − lag} to catch up, its state does not move
        i = changed[0] + 1
        x = run.filter_log["x"]
        assert np.array_equal(x[i - 1], x[i]) and np.array_equal(x[i], x[i + 2])
        f = filter_rows(lag, len(lag))
        assert f[i - 1] == f[i] == f[i + 2] == i - 2 and f[i + 3] == i - 1


def test_nees_after_a_latency_change_is_aligned(latency_runs):
    """Rows from 0.5 s after the detection on: the mean NEES with each row compared with the
    truth at the filter's own time (:func:`filter_rows`) is the smallest of the truth shifted by
    −3 … +3 periods from it, and the starting lag for every row (what the filter log kept before:
    the truth 3 periods later than the filter's time) gives at least 1.25× as much (measured on
    seeds 0–9: 1.37–4.2×). A test of the alignment alone: how consistent the filter is after a
    change it saw late is its own matter (the mean NEES there is 8–315 on seeds 0–9, 6–15
    before the fault)."""
    from estimation.consistency import truth_rows

    for run in latency_runs:
        lag = run.filter_log["lag"]
        n = len(lag)
        t_change = run.t[np.flatnonzero(np.diff(lag))[0] + 1]
        s = run_truth(run)
        ref = (float(s.psi_l[0] - s.theta[0]), float(s.psi_r[0] - s.theta[0]), float(s.alpha[0]))
        X = truth_rows(s.constants, ref, s.theta, s.theta_dot, s.psi_l, s.psi_r, s.psi, s.psi_dot, s.alpha,
                        s.gyro_bias[:, 1], s.gyro_bias[:, 2])
        f = filter_rows(lag, n)
        rows = np.flatnonzero(run.t >= t_change + 0.5)
        x, P = run.filter_log["x"][rows], run.filter_log["P"][rows]
        mean = {sh: float(np.mean(quad_inv_rows(P, x - X[f[rows] + sh]))) for sh in range(-3, 4)}
        assert min(mean, key=mean.get) == 0, mean
        # the starting lag: row i against the truth at i − lag_0, 3 periods after the filter's time
        old = state_matrix(s, int(lag[0]))[rows]
        assert np.array_equal(old, X[f[rows] + 3])
        assert mean[3] > 1.25 * mean[0], mean
        # the same rows through nees(): the per-row alignment
        assert np.array_equal(nees(run)[rows], quad_inv_rows(P, x - X[f[rows]]))


# ---- metrics.json and the console ---------------------------------------------------------------
@pytest.fixture(scope="module")
def faulty():
    """sensor-faults for 5 s with its first fault alone (gyro spikes from 2 s: IMU samples
    rejected, each an event)."""
    return run_scenario(load_scenario("sensor-faults", [
        "duration=5", "faults=[{kind='spikes', sensor='gyro', start=2, duration=2, rate=5, magnitude=0.5}]"]), ("it2",))


def test_metrics_hold_the_estimators_section(faulty):
    m = faulty.metrics["it2"]
    run = faulty.runs[0]
    sec = m["estimator"]
    assert sec["name"] == "ekf"
    stats = sec["stats"]
    for key in ("accepted", "rejected", "rejected_total", "saturated_imu_samples", "stale_imu_samples",
                "accel_outliers", "latency_changes", "resets"):
        assert key in stats, key
    assert set(stats["accepted"]) == set(stats["rejected"]) == {"gyro", "accel", "encoders"}
    assert "events" not in stats and sec["events_total"] == len(run.estimator_stats["events"]) > 0
    assert sec["encoder_resyncs"] == sum("re-synchronising" in e or "re-based" in e
                                         for e in run.estimator_stats["events"])
    for e, text in zip(sec["events"], run.estimator_stats["events"]):
        assert text == f"t = {e['t_s']:.3f} s: {e['message']}"
    assert sec["consistency"] == run.estimator_consistency
    assert m["estimator_events"] == sec["events_total"]
    assert m["estimator_nees_mean"] == sec["consistency"]["nees_mean"]
    assert m["estimator_nis_per_dof"] == sec["consistency"]["nis_per_dof"]
    assert json.loads(json.dumps(m, allow_nan=False)) == m  # plain JSON, nothing lost


def test_ideal_sensing_has_no_estimator_section():
    run = simulate(_spec("duration=1", "sensors.sensing='ideal'"))
    m = run_metrics(run)
    assert "estimator" not in m and m["estimator_events"] == 0
    assert m["estimator_nees_mean"] is None and m["estimator_nis_per_dof"] is None
    assert run.estimator_consistency is None


def test_another_estimators_stats_are_made_json_safe():
    run = simulate(_spec("duration=1", "sensors.estimator='complementary'"))
    assert run.estimator_consistency is None  # no truth of its state is known
    m = run_metrics(run)
    assert m["estimator"] == {"name": "complementary", "stats": {"rejected_total": 0}}
    fake = SimpleNamespace(**{k: getattr(run, k) for k in ("t", "fell", "status", "end_reason", "experiment",
                                                           "controller", "seed", "full_rate", "estimates")},
                           sensing="mine:Est", estimator_consistency=None,
                           signal=run.signal, distance=run.distance, estimation_rmse=run.estimation_rmse,
                           estimator_stats={"rejected_total": np.int64(2), "gain": np.float64(0.5),
                                            "trace": np.arange(3), "modes": {"b", "a"}, 7: math.inf,
                                            "events": [(1.25, "switched"), "t = 2.000 s: reset", "no time"]})
    sec = run_metrics(fake)["estimator"]
    assert sec["stats"] == {"rejected_total": 2, "gain": 0.5, "trace": [0, 1, 2], "modes": ["a", "b"], "7": None}
    assert sec["events"] == [{"t_s": 1.25, "message": "switched"}, {"t_s": 2.0, "message": "reset"},
                             {"t_s": None, "message": "no time"}]
    assert "encoder_resyncs" not in sec and json.dumps(sec, allow_nan=False)
    assert jsonable((np.bool_(True), None, "x")) == [True, None, "x"]


def test_the_console_line(faulty):
    line = estimator_line(faulty.metrics["it2"], "IT2")
    c = faulty.metrics["it2"]["estimator"]["consistency"]
    assert line.startswith(f"estimator ekf (IT2): NEES {c['nees_mean']:.3g} (12 states; one run's 95 % [4.40, 23.3]), "
                           f"NIS/dof {c['nis_per_dof']:.3g}; ")
    n = faulty.metrics["it2"]["estimator_events"]
    first = faulty.runs[0].estimator_stats["events"][0]
    assert f"; {n} events: {first}; " in line and line.endswith(f"; {n - 2} more in metrics.json")
    quiet = {"estimator": {"name": "ekf", "stats": {"rejected": {"gyro": 0, "accel": 0, "encoders": 3}},
                           "events_total": 1, "events": [{"t_s": 8.12, "message": "gyro latency changed"}],
                           "encoder_resyncs": 0}}
    assert estimator_line(quiet) == ("estimator ekf: 3 encoder samples rejected; 1 event: t = 8.120 s: gyro latency "
                                     "changed")
    assert estimator_line({"fell": False}) is None


def test_twin_run_prints_the_estimators_line(tmp_path):
    r = subprocess.run([sys.executable, "-m", "twin.cli", "run", "paper-exp1", "--duration", "2", "--controller", "it2",
                        "--no-video", "--out", str(tmp_path / "out")], capture_output=True, text=True,
                       cwd=tempfile.gettempdir())
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("  estimator ekf (IT2): NEES ")]
    assert len(lines) == 1, r.stdout
    doc = json.loads((tmp_path / "out" / "metrics.json").read_text())
    c = doc["runs"]["it2"]["estimator"]["consistency"]
    assert f"NEES {c['nees_mean']:.3g} " in lines[0] and c["rows"] == 301


# ---- twin check ---------------------------------------------------------------------------------
def test_twin_check_may_bound_the_new_metrics(faulty):
    from twin.scenarios.expectations import parse_expect

    bounds = parse_expect({"estimator_nees_mean": "<= 23.4", "estimator_nis_per_dof": "<= 20",
                           "estimator_events": ">= 1"})
    m = faulty.metrics["it2"]
    assert all(b.holds(b.measure(m)) for b in bounds["*"])
    assert parse_expect({"estimator_events": "== 0"})  # a whole number may be compared exactly
