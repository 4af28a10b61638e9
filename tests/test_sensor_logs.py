"""Sensor logs (issue 28): the documented format written by hand replays with the built-in
estimators; the twin's own logs (``twin run --log-sensors``) replay to the very estimates of
the run; irregular timing, gaps and duplicates are handled as documented; a malformed log is
one line and exit status 2."""
from __future__ import annotations

import csv
import math
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from twin.errors import TwinError
from twin.logs.format import read_log, write_log
from twin.logs.replay import build_for, errors, instants, replay
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario

MANIFEST = """format = "mtwip-sensor-log"
version = 1
control_rate = 200.0
wheel_radius = 0.04
track = 0.30
encoder_counts = 1200
imu_position = [0.0, 0.0, 0.1]
"""


def write_by_hand(d: Path, seconds: float = 2.0, jitter: bool = False, tilt: float = 0.05) -> Path:
    """A robot standing still at a small tilt, written from the format's description alone:
    IMU and encoders at 200 Hz (with ``jitter``: up to 0.4 ms late, a 50 ms gap in the
    encoders and a duplicated IMU row), zero torque commands, and the truth."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "log.toml").write_text(MANIFEST, encoding="utf-8")
    rng = np.random.default_rng(7)
    n = int(seconds * 200) + 1
    g = 9.81
    with open(d / "imu.csv", "w", encoding="utf-8") as fh:
        fh.write("t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n")
        for k in range(n):
            t = k / 200 + (rng.uniform(0, 4e-4) if jitter else 0.0)
            gy = rng.normal(0, 1e-3, 3)
            a = np.array([-g * math.sin(tilt), 0.0, g * math.cos(tilt)]) + rng.normal(0, 0.02, 3)
            row = f"{t!r}," + ",".join(repr(float(v)) for v in (*gy, *a)) + "\n"
            fh.write(row)
            if jitter and k == 100:
                fh.write(row)  # a duplicated timestamp
    with open(d / "encoders.csv", "w", encoding="utf-8") as fh:
        fh.write("t,left,right\n")
        for k in range(n):
            if jitter and 200 <= k < 210:
                continue  # a 50 ms gap
            fh.write(f"{k / 200 + (3e-4 if jitter else 0.0)!r},0,0\n")
    with open(d / "commands.csv", "w", encoding="utf-8") as fh:
        fh.write("t,ul,ur\n")
        for k in range(n):
            fh.write(f"{k / 200!r},0.0,0.0\n")
    with open(d / "truth.csv", "w", encoding="utf-8") as fh:
        fh.write("t,theta,theta_dot,psi,psi_dot,alpha,alpha_dot\n")
        for k in range(n):
            fh.write(f"{k / 200!r},{tilt!r},0.0,0.0,0.0,0.0,0.0\n")
    return d


@pytest.mark.parametrize("kind", ["ekf", "complementary"])
def test_a_log_written_by_hand_replays(tmp_path, kind):
    log = read_log(write_by_hand(tmp_path / "hand"))
    assert log.control_rate == 200.0 and log.counts_per_rev == 1200 and log.truth is not None
    r = replay(log, build_for(log, kind), kind)
    assert r.estimates.shape == (401, 6) and np.isfinite(r.estimates).all()
    e = errors(log, r)
    assert e["rows"] == 401
    assert e["theta_rmse_rad"] < 0.01  # it finds the 0.05 rad tilt from gravity's direction
    assert abs(r.estimates[-1, 0] - 0.05) < 0.01


def test_irregular_timing_gaps_and_duplicates_are_handled_as_documented(tmp_path):
    log = read_log(write_by_hand(tmp_path / "jitter", jitter=True))
    t, ms, commands = instants(log)
    # the first IMU reading is up to 0.4 ms late: the replay starts at the first command after it
    assert len(t) == 400 and t[0] == 0.005 and t[1] == 0.005 + 1 / 200
    assert ms[0].gyro is not None and ms[0].accel is not None and ms[0].encoders == (0.0, 0.0)
    # encoder row k (at k/200 + 0.3 ms) reaches instant k; the gap leaves instants 200..209 without
    assert all(ms[k].encoders is None for k in range(200, 210)) and ms[210].encoders is not None
    assert all(ms[k].encoders is not None for k in range(1, 200))
    # the duplicated row: one reading at its instant (the last of the two)
    assert ms[100].gyro is not None
    assert commands.shape == (400, 2) and not commands.any()
    r = replay(log, build_for(log, "ekf"), "ekf")
    assert np.isfinite(r.estimates).all() and errors(log, r)["theta_rmse_rad"] < 0.01


@pytest.fixture(scope="module")
def twin_runs():
    sc = load_scenario("paper-exp3", ["duration=3"])
    return sc, run_scenario(sc, ["it2", "lqr"]).runs


def test_the_twins_log_replays_to_the_runs_estimates_bit_for_bit(twin_runs, tmp_path):
    sc, runs = twin_runs
    for run in runs:
        log = read_log(write_log(run, tmp_path / run.controller, sc))
        r = replay(log, build_for(log, sc.estimator), "ekf")
        assert np.allclose(r.t, run.t, rtol=0, atol=1e-12)  # the instants (the truth's clock may differ by an ulp)
        assert r.estimates.tobytes() == run.estimates.tobytes(), run.controller
        assert r.stats["rejected_total"] == run.estimator_stats["rejected_total"]


def test_the_twins_log_through_the_command_line_bit_for_bit(tmp_path):
    env_run = [sys.executable, "-m", "twin.cli"]
    out = tmp_path / "run"
    r = subprocess.run([*env_run, "run", "paper-exp2", "--duration", "4", "--controller", "lqr", "--no-video",
                        "--log-sensors", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    log_dir = out / "sensor-logs" / "lqr"
    assert sorted(p.name for p in log_dir.iterdir()) == ["commands.csv", "duty.csv", "encoders.csv", "imu.csv",
                                                         "log.toml", "truth.csv"]  # duty.csv: DC motors
    rp = tmp_path / "replay"
    r = subprocess.run([*env_run, "replay", str(log_dir), "--estimator", "ekf", "--out", str(rp)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    with open(out / "trajectory.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    with open(rp / "estimates.csv", newline="") as fh:
        got = list(csv.DictReader(fh))
    assert len(rows) == len(got) == 801
    for a, b in zip(rows, got):
        assert a["theta_est [rad]"] == b["theta [rad]"] and a["alpha_dot_est [rad/s]"] == b["alpha_dot [rad/s]"]
    assert "ekf" in r.stdout and (rp / "replay.json").is_file() and (rp / "manifest.json").is_file()


def _twin(*args, cwd=None):
    r = subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True, timeout=300,
                       cwd=cwd)
    return r.returncode, r.stdout, r.stderr


def _break(d: Path, how: str) -> None:
    if how == "no manifest":
        (d / "log.toml").unlink()
    elif how == "version":
        (d / "log.toml").write_text(MANIFEST.replace("version = 1", "version = 7"))
    elif how == "no stream":
        (d / "encoders.csv").unlink()
    elif how == "backwards":
        lines = (d / "imu.csv").read_text().splitlines()
        lines[10] = "0.01" + lines[10][lines[10].index(","):]  # row 11 at t = 0.01 s after t = 0.045 s
        (d / "imu.csv").write_text("\n".join(lines) + "\n")
    elif how == "float counts":
        lines = (d / "encoders.csv").read_text().splitlines()
        lines[5] = lines[5].rsplit(",", 1)[0] + ",1.5"
        (d / "encoders.csv").write_text("\n".join(lines) + "\n")
    elif how == "accel in g":
        rows = [r.split(",") for r in (d / "imu.csv").read_text().splitlines()]
        out = [",".join(rows[0])] + [",".join(r[:4] + [repr(float(v) / 9.81) for v in r[4:]]) for r in rows[1:]]
        (d / "imu.csv").write_text("\n".join(out) + "\n")
    elif how == "gravity on x":
        rows = [r.split(",") for r in (d / "imu.csv").read_text().splitlines()]
        out = [",".join(rows[0])] + [",".join(r[:4] + [r[6], r[5], r[4]]) for r in rows[1:]]
        (d / "imu.csv").write_text("\n".join(out) + "\n")
    elif how == "nan":
        lines = (d / "commands.csv").read_text().splitlines()
        lines[3] = lines[3].split(",")[0] + ",nan,0.0"
        (d / "commands.csv").write_text("\n".join(lines) + "\n")
    elif how == "units":
        (d / "log.toml").write_text(MANIFEST + '[units]\naccel = "g"\n')


@pytest.mark.parametrize("how, says", [
    ("no manifest", "log.toml: missing"),
    ("version", "version: 7 is not known here; allowed: 1"),
    ("no stream", "encoders.csv: missing"),
    ("backwards", "imu.csv: row 11: t = 0.01 s runs backwards"),
    ("float counts", "encoders.csv: row 6: right = '1.5' is not a whole number of counts"),
    ("accel in g", "imu.csv: rows from 2: the accelerometer reads 1 on average, gravity in g; allowed: m/s²"),
    ("gravity on x", "imu.csv: rows from 2: gravity is on +x"),
    ("nan", "commands.csv: row 4: ul = nan; allowed: a finite number"),
    ("units", "units.accel: 'g'; allowed: 'm/s^2'"),
])
def test_a_malformed_log_is_one_line_and_exit_status_2(tmp_path, how, says):
    d = write_by_hand(tmp_path / "bad", seconds=0.5)
    _break(d, how)
    with pytest.raises(TwinError) as err:
        read_log(d)
    assert says in str(err.value) and "\n" not in str(err.value)
    status, stdout, stderr = _twin("replay", str(d), "--out", str(tmp_path / "out"))
    assert status == 2 and "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert says in stderr
    assert not (tmp_path / "out").exists()


def test_log_sensors_is_refused_where_a_log_cannot_be_whole(tmp_path):
    status, _, stderr = _twin("run", "paper-exp1", "--duration", "0.5", "--no-video", "--log-sensors",
                              "--set", "sensors.sensing=ideal", "--out", str(tmp_path / "a"))
    assert status == 2 and "--log-sensors needs simulated sensors" in stderr and len(stderr.splitlines()) == 1
    status, _, stderr = _twin("run", "paper-exp1", "--duration", "0.5", "--no-video", "--log-sensors",
                              "--log-every", "5", "--out", str(tmp_path / "b"))
    assert status == 2 and "--log-every must be 1" in stderr and len(stderr.splitlines()) == 1
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_replay_refuses_the_ideal_estimator_and_unknown_kinds(tmp_path):
    d = write_by_hand(tmp_path / "ok", seconds=0.5)
    status, _, stderr = _twin("replay", str(d), "--estimator", "ideal", "--out", str(tmp_path / "o"))
    assert status == 2 and "'ideal' reads the truth" in stderr
    status, _, stderr = _twin("replay", str(d), "--estimator", "ekff", "--out", str(tmp_path / "o"))
    assert status == 2 and len(stderr.splitlines()) == 1 and "ekff" in stderr


# ---- regression bounds on replays ---------------------------------------------------------------------


def _bounded(tmp_path, table: str) -> Path:
    d = write_by_hand(tmp_path / "robot-log", seconds=1.0)
    with open(d / "log.toml", "a", encoding="utf-8") as fh:
        fh.write(table)
    return d


def test_twin_check_passes_a_logs_bounds_and_fails_one_naming_estimator_log_and_metric(tmp_path):
    ok = _bounded(tmp_path / "a", '\n[expect.ekf]\ntheta_rmse_rad = "<= 0.01"\n[expect.complementary]\n'
                                   'theta_rmse_rad = "<= 0.02"\n')
    status, stdout, stderr = _twin("check", str(ok), "--junit", str(tmp_path / "a.xml"))
    assert status == 0, stderr
    assert "log:robot-log" in stdout and "all bounds hold" in stdout
    xml = (tmp_path / "a.xml").read_text()
    assert 'name="estimator ekf"' in xml and 'failures="0"' in xml
    bad = _bounded(tmp_path / "b", '\n[expect.ekf]\ntheta_rmse_rad = "<= 1e-9"\n')
    status, stdout, stderr = _twin("check", str(bad), "--junit", str(tmp_path / "b.xml"))
    assert status == 1
    line = [s for s in stderr.splitlines() if s.startswith("FAIL")]
    assert len(line) == 1 and "log:robot-log" in line[0] and "estimator ekf" in line[0] \
        and "theta_rmse_rad" in line[0] and "bound theta_rmse_rad <= 1e-09" in line[0], stderr
    assert "<failure" in (tmp_path / "b.xml").read_text()


def test_a_check_file_beside_the_tests_names_the_log_and_a_bad_bound_is_one_line(tmp_path):
    d = write_by_hand(tmp_path / "logs" / "hall", seconds=1.0)
    f = tmp_path / "hall-check.toml"
    f.write_text('log = "logs/hall"\n[expect.kalman2]\n"|theta_max_abs_rad|" = "<= 0.05"\nrejected_total = "== 0"\n')
    status, stdout, stderr = _twin("check", str(f))
    assert status == 0, stderr
    assert "log:hall-check" in stdout and ("Kalman" in stdout or "kalman2" in stdout)
    f.write_text('log = "logs/hall"\n[expect.ekf]\nsettling_time_s = "<= 1"\n')
    status, _, stderr = _twin("check", str(f))
    assert status == 2 and len(stderr.strip().splitlines()) == 1 and "unknown metric 'settling_time_s'" in stderr
    f.write_text('log = "logs/nowhere"\n[expect.ekf]\nnis_per_dof = "<= 2"\n')
    status, _, stderr = _twin("check", str(f))
    assert status == 2 and "is not a sensor log" in stderr
    assert d.is_dir()


def test_the_pytest_plugin_collects_a_twin_toml_naming_a_log(tmp_path):
    write_by_hand(tmp_path / "logs" / "hall", seconds=1.0)
    (tmp_path / "twin_hall.toml").write_text('log = "logs/hall"\n[expect.ekf]\ntheta_rmse_rad = "<= 0.01"\n'
                                             '[expect.complementary]\ntheta_rmse_rad = "<= 1e-9"\n')
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "1 failed, 1 passed" in r.stdout and "estimator complementary" in r.stdout, r.stdout


def test_commands_as_pwm_duty_become_torques_through_the_motors_stall_torque(tmp_path):
    d = write_by_hand(tmp_path / "duty", seconds=0.5)
    (d / "log.toml").write_text(MANIFEST + '[commands]\nunit = "duty"\n')
    lines = (d / "commands.csv").read_text().splitlines()
    (d / "commands.csv").write_text("\n".join([lines[0]] + [ln.split(",")[0] + ",0.25,-0.5" for ln in lines[1:]])
                                    + "\n")
    log = read_log(d)
    stall = log.motor.stall_torque
    assert stall > 0 and np.array_equal(log.commands, np.tile([0.25 * stall, -0.5 * stall], (len(lines) - 1, 1)))
    lines = (d / "commands.csv").read_text().splitlines()
    lines[4] = lines[4].split(",")[0] + ",1.5,0.0"
    (d / "commands.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(TwinError, match=r"commands.csv: row 5: a PWM duty outside \[-1, 1\]"):
        read_log(d)


def test_the_motors_figures_in_the_manifest(tmp_path):
    d = write_by_hand(tmp_path / "motor", seconds=0.5)
    (d / "log.toml").write_text(MANIFEST + '[motor]\nstall_torque = 0.8\n[commands]\nunit = "duty"\n')
    lines = (d / "commands.csv").read_text().splitlines()
    (d / "commands.csv").write_text("\n".join([lines[0]] + [ln.split(",")[0] + ",0.5,0.5" for ln in lines[1:]]) + "\n")
    log = read_log(d)
    assert log.motor.stall_torque == 0.8 and np.all(log.commands == 0.4)
    # the EKF is built for these motors too, told that the duty is past the driver (its compensation
    # and current limit already acted: tests/test_log_duty.py)
    assert log.context().motor == replace(log.motor, back_emf_compensation=False, current_limit=None)
    (d / "log.toml").write_text(MANIFEST + '[motor]\nstall_torq = 0.8\n')
    with pytest.raises(TwinError, match=r"motor.stall_torq: unknown; allowed: .*stall_torque"):
        read_log(d)
    (d / "log.toml").write_text(MANIFEST + '[motor]\nstall_torque = -1\n')
    with pytest.raises(TwinError, match=r"log.toml: motor: .*stall_torque"):
        read_log(d)


def test_nees_and_whiteness_are_bounds_a_twin_logs_check_may_name(twin_runs, tmp_path):
    sc, runs = twin_runs
    d = write_log(runs[0], tmp_path / "it2", sc)
    with open(d / "log.toml", "a", encoding="utf-8") as fh:
        fh.write('\n[expect.ekf]\nnees_mean = "<= 1e6"\nwhiteness_outside_fraction = "<= 1"\n'
                 '[expect.complementary]\nnees_mean = "<= 1e6"\n')
    status, stdout, stderr = _twin("check", str(d))
    assert status == 1  # the complementary filter reports no covariance: its NEES is undefined, and fails
    assert "FAIL log:it2 estimator complementary: nees_mean = undefined" in stderr and "estimator ekf" not in stderr, \
        stderr


def test_encoder_glitches_are_whole_counts_so_a_run_with_them_is_a_log(tmp_path):
    """sensor-faults spikes the encoders by ±0.05 rad: whole counts (±10 of 1200 per revolution), as an
    encoder's every reading, so the run can be written as a log and replays bit for bit."""
    import math

    sc = load_scenario("sensor-faults")
    run = run_scenario(sc, ["it2"]).runs[0]
    ms, res = run.measurements, 2.0 * math.pi / 1200
    enc = ms.encoders[ms.has_encoders]
    counts = np.round(enc / (1.0 / (1200 / (2.0 * math.pi))))
    assert np.array_equal(counts * (1.0 / (1200 / (2.0 * math.pi))), enc)  # every reading a whole count
    assert run.sensor_counts["encoders"]["spiked"] > 0  # the glitches happened
    jumps = np.abs(np.diff(np.round(enc / res), axis=0))
    assert (jumps >= 10).any()  # a ±10-count glitch (the wheels turn far less in 5 ms)
    log = read_log(write_log(run, tmp_path / "faults", sc))
    r = replay(log, build_for(log, "ekf"), "ekf")
    assert r.estimates.tobytes() == run.estimates.tobytes()


def test_replay_draws_a_figure_per_log(tmp_path):
    a, b = write_by_hand(tmp_path / "a", seconds=0.5), write_by_hand(tmp_path / "b", seconds=0.5, tilt=0.1)
    status, stdout, stderr = _twin("replay", str(a), str(b), "--estimator", "ekf", "--out", str(tmp_path / "o"))
    assert status == 0, stderr
    names = sorted(p.name for p in (tmp_path / "o").iterdir())
    assert names == ["estimates.csv", "figure-2.png", "figure.png", "manifest.json", "replay.json"]
    assert "figure.png, figure-2.png" in stdout


def test_a_users_own_estimator_replays_as_the_built_ins_do(tmp_path):
    """An estimator by import path (examples/my_plugins.py, outside the package) on a log, through
    the command line, beside the EKF; and a bound on it checked by twin check."""
    examples = Path(__file__).resolve().parent.parent / "examples"
    d = write_by_hand(tmp_path / "own", seconds=1.0)
    status, stdout, stderr = _twin("replay", str(d), "--estimator", "my_plugins:TiltFilter,ekf", "--out",
                                   str(tmp_path / "o"), cwd=examples)
    assert status == 0, stderr
    assert "my_plugins:TiltFilter" in stdout
    import json as _json

    doc = _json.loads((tmp_path / "o" / "replay.json").read_text())
    e = doc["logs"][str(d)]["estimators"]["my_plugins:TiltFilter"]["errors"]
    assert e["rows"] == 201 and e["theta_rmse_rad"] < 0.02
    with open(d / "log.toml", "a", encoding="utf-8") as fh:
        fh.write('\n[expect."my_plugins:TiltFilter"]\ntheta_rmse_rad = "<= 1e-9"\n')
    status, _, stderr = _twin("check", str(d), cwd=examples)
    assert status == 1 and "estimator my_plugins:TiltFilter: theta_rmse_rad" in stderr, stderr
