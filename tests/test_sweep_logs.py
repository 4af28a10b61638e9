"""Sensor logs of a sweep's chosen samples (issue 28): ``twin sweep ... --log-sensors K[,K...]``
writes each controller's run of sample K as the very log ``twin run SCENARIO --sample K --seed
ROOT --log-sensors`` writes, of the run whose metrics sweep.csv holds; a resumed sweep writes
them without running its samples again; without the option the outputs are as they were.

The sweeps are those of tests/test_sweep.py (2 draws × 2 levels of a 3 s paper-exp2)."""
from __future__ import annotations

import csv
import hashlib
import json
import tomllib

import numpy as np
import pytest

from test_scenarios import assert_one_line_error, twin
from test_sweep import OVERRIDES, SETS, sweep_cli
from twin.logs.format import read_log, write_log
from twin.logs.replay import build_for, errors, replay
from twin.params import NOMINAL
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario
from twin.sweep.sampling import sample_scenario
from twin.sweep.table import read_sweep_csv

KINDS = ("it2", "t1")
STREAMS = ("imu.csv", "encoders.csv", "commands.csv", "truth.csv", "duty.csv")  # duty: DC motors (issue 30)


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """A sweep that logs samples 3 and 1 (given out of order), with 2 workers: its directory."""
    out = tmp_path_factory.mktemp("sweep-logs") / "logged"
    r = sweep_cli(out, "--workers", "2", "--log-sensors", "3,1")
    assert r.returncode == 0, r.stderr
    assert "sensor logs of samples 1, 3: 4 in" in r.stdout
    return out


@pytest.fixture(scope="module")
def run3(tmp_path_factory):
    """``twin run paper-exp2 --sample 3 --seed 0 ... --log-sensors``: its directory."""
    out = tmp_path_factory.mktemp("run-sample3")
    status, stdout, stderr = twin("run", "paper-exp2", "--sample", 3, "--seed", 0, *SETS, "--no-video",
                                  "--log-sensors", "--out", out)
    assert status == 0, stderr
    return out


def test_a_sweeps_log_of_a_sample_replays_as_twin_runs_log_of_it(swept, run3):
    for kind in KINDS:
        ours, theirs = swept / "sensor-logs" / "sample-3" / kind, run3 / "sensor-logs" / kind
        for name in STREAMS:  # the readings, commands and truth: the same bytes
            assert (ours / name).read_bytes() == (theirs / name).read_bytes(), (kind, name)
        a, b = read_log(ours), read_log(theirs)
        ra, rb = (replay(log, build_for(log, "ekf"), "ekf") for log in (a, b))
        assert ra.estimates.shape[0] == 601 and np.isfinite(ra.estimates).all()
        assert ra.estimates.tobytes() == rb.estimates.tobytes() and ra.t.tobytes() == rb.t.tobytes(), kind
        assert ra.stats["rejected_total"] == rb.stats["rejected_total"]
        # the manifest names the sweep's scenario and --set items and says which sample it is
        m = tomllib.loads((ours / "log.toml").read_text(encoding="utf-8"))
        assert m["scenario"] == "paper-exp2" and m["set"][:len(OVERRIDES)] == OVERRIDES
        assert m["source"] == "twin sweep, sweep sample 3 (root seed 0)"
        assert tomllib.loads((theirs / "log.toml").read_text())["source"] == "twin run, sweep sample 3 (root seed 0)"
        # which rebuilds the sensors and motor the sample's estimator believed in, and its nominal model
        sample = sample_scenario(load_scenario("paper-exp2", OVERRIDES), 0, 3).scenario
        assert a.sensors == sample.believed_sensor_config() and a.motor == sample.twin_config().motor
        assert a.model == NOMINAL


def test_the_logged_run_is_the_one_whose_metrics_sweep_csv_holds(swept, run3):
    rows = read_sweep_csv(swept / "sweep.csv")
    doc = json.loads((run3 / "metrics.json").read_text())
    finals = set()
    for row in (r for r in rows if r["sample"] in (1, 3)):
        kind, log_dir = row["controller"], swept / "sensor-logs" / f"sample-{row['sample']}" / row["controller"]
        if row["sample"] == 3:  # the run that wrote the same log (above) has the sample's metrics
            metrics = doc["runs"][kind]
            compared = [k for k in metrics if k in row and k not in ("controller", "seed")]
            assert len(compared) >= 15
            assert all(metrics[k] == row[k] for k in compared), [k for k in compared if metrics[k] != row[k]]
        with open(log_dir / "truth.csv", newline="") as fh:
            truth = list(csv.DictReader(fh))
        # and the log's own truth and estimates give the row's figures
        assert float(truth[-1]["t"]) == row["duration_s"]
        assert float(truth[-1]["theta"]) == row["final_theta_rad"]
        assert float(truth[-1]["alpha"]) == row["final_heading_rad"]
        log = read_log(log_dir)
        e = errors(log, replay(log, build_for(log, "ekf"), "ekf"))
        assert e["rows"] == len(truth)
        assert e["theta_rmse_rad"] == pytest.approx(row["estimator_theta_rmse_rad"], rel=1e-9, abs=0)
        finals.add(row["final_theta_rad"])
    assert len(finals) == 4  # two samples, two controllers: four different runs logged


def test_the_sweeps_manifest_lists_the_logs(swept):
    files = json.loads((swept / "manifest.json").read_text())["files"]
    logged = sorted(n for n in files if n.startswith("sensor-logs/"))
    assert logged == sorted(f"sensor-logs/sample-{k}/{kind}/{name}" for k in (1, 3) for kind in KINDS
                            for name in (*STREAMS, "log.toml"))
    for n in logged:
        assert files[n]["sha256"] == hashlib.sha256((swept / n).read_bytes()).hexdigest(), n


def test_a_resumed_sweep_writes_the_logs_without_running_its_samples(swept, tmp_path):
    out = tmp_path / "plain"
    r = sweep_cli(out, "--workers", "2")
    assert r.returncode == 0, r.stderr
    assert not (out / "sensor-logs").exists() and "sensor logs" not in r.stdout
    for name in ("sweep.csv", "summary.json", "summary.md"):  # the option changes no other output
        assert (out / name).read_bytes() == (swept / name).read_bytes(), name
    r = sweep_cli(out, "--log-sensors", "3")
    assert r.returncode == 0, r.stderr
    assert "ran 0 samples" in r.stdout and "4 were already finished" in r.stdout and "note:" not in r.stdout
    assert sorted(p.name for p in (out / "sensor-logs").iterdir()) == ["sample-3"]
    for kind in KINDS:
        for name in (*STREAMS, "log.toml"):
            a = out / "sensor-logs" / "sample-3" / kind / name
            assert a.read_bytes() == (swept / "sensor-logs" / "sample-3" / kind / name).read_bytes(), (kind, name)
    assert any(n.startswith("sensor-logs/") for n in json.loads((out / "manifest.json").read_text())["files"])
    # run again without the option: the directory holds what this command wrote, no earlier logs
    r = sweep_cli(out)
    assert r.returncode == 0, r.stderr
    assert not (out / "sensor-logs").exists()
    assert not any(n.startswith("sensor-logs/") for n in json.loads((out / "manifest.json").read_text())["files"])


@pytest.mark.parametrize("args, fragments", [
    (["--log-sensors", "4"], ["--log-sensors: 4 is not a sample of this sweep", "from 0 to 3"]),
    (["--log-sensors", "0,x"], ["--log-sensors must be sample numbers, comma-separated", "'0,x'"]),
    (["--log-sensors", "-1"], ["--log-sensors must be sample numbers"]),
    (["--log-sensors", "1", "--set", "sensors.sensing=ideal"], ["--log-sensors needs simulated sensors",
                                                                 'sensors.sensing = "estimated"']),
])
def test_bad_log_sensors_is_one_line_before_anything_is_written(tmp_path, args, fragments):
    status, stdout, stderr = twin("sweep", "paper-exp2", "--samples", 2, *SETS, *args, "--out", tmp_path / "x")
    assert_one_line_error(status, stdout, stderr, *fragments)
    assert not (tmp_path / "x").exists()


def test_a_samples_log_names_its_scenario_without_any_set_item(tmp_path):
    # a sample's source is "built-in scenario paper-exp2, sweep sample 1 (root seed 0)": the log's
    # scenario is paper-exp2, not that text (twin run --sample 1 --log-sensors, no --set, no --seed)
    sample = sample_scenario(load_scenario("paper-exp2"), 0, 1).scenario
    assert sample.overrides == ()
    run = run_scenario(sample, ["lqr"]).runs[0]
    log = read_log(write_log(run, tmp_path / "lqr", sample))
    assert log.manifest["scenario"] == "paper-exp2" and log.manifest["set"] == []
    assert log.manifest["source"] == "twin run, sweep sample 1 (root seed 0)"
    assert replay(log, build_for(log, "ekf"), "ekf").estimates.tobytes() == run.estimates.tobytes()


def test_a_sweep_interrupted_while_it_writes_its_logs_is_finished_by_the_same_command(tmp_path):
    """SIGTERM after the first log is written: exit 143 with one line, the samples kept, no
    manifest (the folder is not complete); the same command again writes the logs and seals it."""
    import subprocess
    import sys

    from test_sweep_store import stop_at

    out = tmp_path / "sw"
    cmd = [sys.executable, "-m", "twin.cli", "sweep", "paper-exp2", "--samples", "2", *SETS, "--out", str(out),
           "--workers", "1", "--log-sensors", "1"]
    proc = stop_at("sweep-logs", tmp_path, cmd, tmp_path)
    proc.terminate()
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.splitlines()[-1].startswith("interrupted: SIGTERM; "), err
    assert not (out / "manifest.json").exists()
    assert (out / "samples.jsonl").read_bytes().count(b"\n") == 4  # every sample kept
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert sorted(f for f in manifest["files"] if f.startswith("sensor-logs/")) == sorted(
        f"sensor-logs/sample-1/{k}/{n}" for k in KINDS for n in ("log.toml",) + STREAMS)
