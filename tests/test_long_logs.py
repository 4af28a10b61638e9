"""Logs of long runs: ``--log-every N`` (every N-th control step written and kept, the
metrics still from every step), ``--log-format csv.gz``, what metrics.json says about it,
and the measurements stored as arrays."""
from __future__ import annotations

import csv
import gzip
import io
import json
import math
import subprocess
import sys
import tempfile

import numpy as np
import pytest

from twin.sim.bullet_loop import simulate_twin
from twin.controllers.cascade import build_cascade
from twin.errors import TwinError
from twin.experiments import Experiment
from twin.outputs.metrics import run_metrics
from twin.plant.bullet import TwinConfig
from twin.plant.disturbances import Disturbances, Push
from twin.sim.runs import FULL_RATE_NAMES, MeasurementLog
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario
from twin.sensors import Measurement, SensorConfig
from twin.sensors.specs import ImuSpec

N = 7  # does not divide the 600 steps of a 3 s run: its last step is off the grid
T = 0.005  # s, paper-exp2's control period (200 Hz)


def twin(*args):
    return subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True,
                          cwd=tempfile.gettempdir())


def _rows(path) -> tuple[str, list[str]]:
    """(header, data lines) of a trajectory file, .csv or .csv.gz, as the bytes say (CRLF kept)."""
    raw = path.read_bytes()
    text = (gzip.decompress(raw) if path.suffix == ".gz" else raw).decode("utf-8")
    lines = text.splitlines(keepends=True)
    return lines[0], lines[1:]


@pytest.fixture(scope="module")
def outs(tmp_path_factory):
    """paper-exp2, 3 s, IT2 and type-1: every step in trajectory.csv; every N-th in trajectory.csv;
    every step in trajectory.csv.gz."""
    base = tmp_path_factory.mktemp("long-logs")
    sc = load_scenario("paper-exp2", ["duration=3"])
    res = {}
    for name, kw in (("full", {}), ("every", {"log_every": N}), ("gz", {"log_format": "csv.gz"})):
        res[name] = run_scenario(sc, ("it2", "t1"), out=base / name, video=False, **kw)
        res[name].out = base / name
    return res


def test_written_rows_are_every_nth_step_of_the_full_log(outs):
    head_full, full = _rows(outs["full"].out / "trajectory.csv")
    head, every = _rows(outs["every"].out / "trajectory.csv")
    assert head == head_full
    written = []
    for kind in ("it2", "t1"):
        mine = [r for r in full if r.startswith(kind + ",")]
        assert len(mine) == 601  # 0 … 3 s at 200 Hz
        written += mine[::N]
    assert every == written  # byte for byte: rows 0, N, 2N, … of each run, in order
    t = np.array([float(r.split(",")[1]) for r in every])
    k = t / (N * T)
    assert np.allclose(k, np.round(k), rtol=0, atol=1e-9)  # times are multiples of N·T
    assert len(every) == 2 * math.ceil(601 / N) and t.max() < 3.0  # 3 s is not on the grid of 7 steps


def test_metrics_are_the_same_with_and_without_decimation(outs):
    full = json.loads((outs["full"].out / "metrics.json").read_text())
    every = json.loads((outs["every"].out / "metrics.json").read_text())
    assert every["runs"] == full["runs"]
    assert outs["every"].metrics == outs["full"].metrics
    for a, b in zip(outs["full"].runs, outs["every"].runs):
        assert len(b.t) == math.ceil(len(a.t) / N) and b.log_every == N and b.control_steps == len(a.t)
        np.testing.assert_array_equal(b.truth, a.truth[::N])
        np.testing.assert_array_equal(b.estimates, a.estimates[::N])
        np.testing.assert_array_equal(b.commands, a.commands[::N])
        np.testing.assert_array_equal(b.actuation, a.actuation[::N])
        np.testing.assert_array_equal(b.gyro_bias, a.gyro_bias[::N])
        assert b.measurements == list(a.measurements)[::N]
        for name in FULL_RATE_NAMES:  # what the metrics read is kept at every step
            np.testing.assert_array_equal(b.full_signal(name), a.full_signal(name))
        # the decimated log alone would give other figures (the check above is not vacuous)
        theta = b.signal("theta")
        assert b.settling_time() == a.settling_time()
        assert run_metrics(b)["iae_theta"] != pytest.approx(
            math.fsum((0.5 * (abs(theta[1:]) + abs(theta[:-1])) * np.diff(b.t)).tolist()), rel=1e-9)


def test_metrics_json_records_what_was_dropped(outs):
    full = json.loads((outs["full"].out / "metrics.json").read_text())
    assert "log" not in full  # at the defaults metrics.json is as it always was
    log = json.loads((outs["every"].out / "metrics.json").read_text())["log"]
    assert log["every"] == N and log["file"] == "trajectory.csv" and log["format"] == "csv"
    assert log["rows_simulated"] == {"it2": 601, "t1": 601}
    assert log["rows_written"] == {"it2": math.ceil(601 / N), "t1": math.ceil(601 / N)}
    assert log["control_period_s"] == T and log["log_period_s"] == pytest.approx(N * T)
    assert f"one control step in {N}" in log["dropped"] and "every control step" in log["dropped"]
    gz = json.loads((outs["gz"].out / "metrics.json").read_text())["log"]
    assert gz["format"] == "csv.gz" and gz["file"] == "trajectory.csv.gz" and gz["every"] == 1
    assert gz["rows_written"] == gz["rows_simulated"] and gz["dropped"].startswith("nothing")


def test_csv_gz_holds_the_csv_and_round_trips(outs):
    plain = (outs["full"].out / "trajectory.csv").read_bytes()
    gz = outs["gz"].out / "trajectory.csv.gz"
    assert not (outs["gz"].out / "trajectory.csv").exists()
    assert gz.read_bytes()[:2] == b"\x1f\x8b" and gzip.decompress(gz.read_bytes()) == plain
    assert len(gz.read_bytes()) < 0.6 * len(plain)
    with gzip.open(gz, "rt", newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    assert rows[0][:2] == ["controller", "t [s]"] and len(rows) == 1 + 2 * 601
    run = outs["full"].runs[0]
    got = np.array([[float(v) for v in r[1:1 + run.truth.shape[1]]] for r in rows[1:602]])
    np.testing.assert_array_equal(got, run.truth)  # every digit survives: repr round-trips a float64


def test_csv_gz_reads_with_pandas(outs):
    pd = pytest.importorskip("pandas")
    df = pd.read_csv(outs["gz"].out / "trajectory.csv.gz")
    assert df.shape[0] == 2 * 601 and list(df["controller"].unique()) == ["it2", "t1"]
    np.testing.assert_array_equal(df[df["controller"] == "it2"]["theta [rad]"].to_numpy(),
                                  outs["full"].runs[0].signal("theta"))


def test_the_same_run_gives_the_same_gz_bytes(outs, tmp_path):
    """No time stamp in the gzip header: the same scenario and seed give the same file."""
    sc = load_scenario("paper-exp2", ["duration=3"])
    run_scenario(sc, ("it2", "t1"), out=tmp_path, video=False, log_format="csv.gz")
    assert (tmp_path / "trajectory.csv.gz").read_bytes() == (outs["gz"].out / "trajectory.csv.gz").read_bytes()


@pytest.mark.parametrize("value", ["0", "-2", "1.5", "abc", ""])
def test_bad_log_every_is_one_line_and_exit_2(value, tmp_path):
    r = twin("run", "paper-exp2", "--duration", "1", "--no-video", "--out", str(tmp_path), "--log-every", value)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --log-every must be a whole number ≥ 1"), r.stderr
    assert repr(value) in lines[0] and not (tmp_path / "metrics.json").exists()


def test_bad_log_format_is_one_line_and_exit_2(tmp_path):
    r = twin("run", "paper-exp2", "--duration", "1", "--no-video", "--out", str(tmp_path), "--log-format", "zip")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "'zip' is not one of 'csv', 'csv.gz'" in lines[0], r.stderr


def test_cli_log_every_and_gz(tmp_path):
    """A plain run, then a decimated compressed one into the same directory: the stale
    trajectory.csv goes, the summary says what was written."""
    assert twin("run", "paper-exp2", "--duration", "1", "--controller", "it2", "--no-video", "--out",
                str(tmp_path)).returncode == 0
    assert (tmp_path / "trajectory.csv").exists()
    r = twin("run", "paper-exp2", "--duration", "1", "--controller", "it2", "--no-video", "--out", str(tmp_path),
             "--log-every", "4", "--log-format", "csv.gz")
    assert r.returncode == 0, r.stderr
    assert "one control step in 4 written (51 of 201 rows)" in r.stdout
    assert not (tmp_path / "trajectory.csv").exists()
    head, rows = _rows(tmp_path / "trajectory.csv.gz")
    assert len(rows) == 51 and json.loads((tmp_path / "metrics.json").read_text())["log"]["every"] == 4
    r = twin("run", "paper-exp2", "--duration", "1.01", "--controller", "it2", "--no-video", "--out",
             str(tmp_path / "b"), "--log-every", "4")  # 203 steps: the last written is t = 1.0 s, the last 1.01 s
    assert r.returncode == 0 and "simulated 1.01 s in" in r.stdout, r.stdout


# ---- the Python API ----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def falling(design):
    """A run pushed over (fall limit 0.3 rad): its last step is wherever it fell."""
    exp = Experiment("upright", "balance only from upright", theta0=0.0, duration=4.0)
    cfg = TwinConfig(fall_angle=0.3, disturbances=Disturbances(pushes=(Push((-12.0, 0.0, 0.0), 0.5, 0.1),)))
    return [simulate_twin(build_cascade("it2", design, exp.targets), exp, cfg, seed=3, log_every=n) for n in (1, N)]


def test_a_fall_is_measured_from_every_step_whatever_n(falling):
    a, b = falling
    assert a.status == b.status == "fell" and a.end_reason == b.end_reason
    n = len(a.t)
    assert (n - 1) % N  # the fall's step is off the grid: the decimated log does not hold it
    assert b.control_steps == n and len(b.t) == math.ceil(n / N) and b.t[-1] < a.t[-1]
    assert run_metrics(b) == run_metrics(a)
    assert run_metrics(b)["duration_s"] == a.t[-1] and run_metrics(b)["final_theta_rad"] == a.signal("theta")[-1]
    np.testing.assert_array_equal(b.actuation, a.actuation[::N])


@pytest.mark.parametrize("value", [0, -1, 1.0, True, "2"])
def test_simulate_twin_refuses_a_bad_log_every(design, value):
    exp = Experiment("upright", "", theta0=0.0, duration=0.1)
    with pytest.raises(TwinError, match="log_every must be a whole number of control steps ≥ 1"):
        simulate_twin(build_cascade("it2", design, exp.targets), exp, log_every=value)


def test_log_filter_needs_every_step(design):
    exp = Experiment("upright", "", theta0=0.0, duration=0.1)
    with pytest.raises(TwinError, match="log_filter needs every control step"):
        simulate_twin(build_cascade("it2", design, exp.targets), exp, log_every=2, log_filter=True)


def test_run_scenario_refuses_a_bad_log_format():
    with pytest.raises(TwinError, match="log_format must be one of csv, csv.gz, got 'csv.bz2'"):
        run_scenario(load_scenario("paper-exp2", ["duration=0.1"]), ("it2",), log_format="csv.bz2")


def test_video_from_a_log_slower_than_the_frame_rate_says_so(tmp_path):
    sc = load_scenario("paper-exp2", ["duration=0.5", "video.width=64", "video.height=48"])
    res = run_scenario(sc, ("it2",), out=tmp_path, video=True, log_every=20)  # 10 Hz log, 30 frames/s
    assert (tmp_path / "video.mp4").exists() and res.video.frames == 16
    assert len(res.notes) == 1 and "logged at 10 Hz (--log-every 20)" in res.notes[0]
    quiet = run_scenario(sc, ("it2",), out=tmp_path, video=True, log_every=5)  # 40 Hz ≥ 30 frames/s
    assert quiet.notes == []


# ---- measurements as arrays ---------------------------------------------------------------------

def test_measurements_are_arrays_with_nan_where_nothing_arrived(design):
    """The IMU at 100 Hz under 200 Hz control: nothing new from it on every other step."""
    exp = Experiment("upright", "", theta0=0.1, duration=1.0)
    sensors = SensorConfig(imu=ImuSpec(rate=100.0, latency=0.01))
    run = simulate_twin(build_cascade("it2", design, exp.targets), exp, sensors=sensors, seed=1)
    log = run.measurements
    assert isinstance(log, MeasurementLog) and len(log) == len(run.t) == 201
    assert 0 < log.has_gyro.sum() < len(log) and log.has_encoders.all()
    assert np.isnan(log.gyro[~log.has_gyro]).all() and np.isfinite(log.gyro[log.has_gyro]).all()
    items = list(log)
    assert all(isinstance(m, Measurement) for m in items) and items == [log[i] for i in range(len(log))]
    for i in (0, 1, 2, 57, -1):
        m = log[i]
        assert m.t == log.t[i] and (m.gyro is None) == (not log.has_gyro[i])
        assert m.gyro is None or m.gyro == tuple(log.gyro[i])
    assert log[10:20] == items[10:20] and log[10:20] != items[11:21]
    with pytest.raises(IndexError):
        log[len(log)]


@pytest.mark.parametrize("chunk", [50, 64])
def test_chunk_boundaries_change_nothing(design, monkeypatch, chunk):
    """The log moves into its arrays every CHUNK steps; chunks that do not line up with N (50)
    or do (64 with N = 8) give the same arrays as one chunk for the whole run."""
    import twin.sim.bullet_loop as bl

    exp = Experiment("balance", "", theta0=0.2, p_d=0.3, duration=1.5)
    sensors = SensorConfig(imu=ImuSpec(rate=100.0, latency=0.01))

    def run(n):
        return simulate_twin(build_cascade("it2", design, exp.targets), exp, sensors=sensors, seed=2, log_every=n)

    whole = run(1)  # 301 steps, less than one default chunk
    monkeypatch.setattr(bl, "CHUNK", chunk)
    for n in (1, 7, 8):
        r = run(n)
        for name in ("truth", "estimates", "commands", "actuation", "push", "gyro_bias"):
            np.testing.assert_array_equal(getattr(r, name), getattr(whole, name)[::n], err_msg=f"{name}, N = {n}")
        assert r.measurements == list(whole.measurements)[::n]
        assert run_metrics(r) == run_metrics(whole)
