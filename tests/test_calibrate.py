"""``twin calibrate`` from the command line: its outputs, ``twin run --plant``, and bad input
(one line, exit status 2). The accuracy over twenty robots is tests/test_calibrate_acceptance.py."""
from __future__ import annotations

import json
import shutil
import tomllib

import numpy as np
import pytest

from types import SimpleNamespace

from test_sensor_logs import _twin as _twin_call


def _twin(*args):
    code, out, err = _twin_call(*args)
    return SimpleNamespace(returncode=code, stdout=out, stderr=err)
from twin.calibrate.identify import assess
from twin.calibrate.run import TURN_RATE, calibrate
from twin.errors import TwinError
from twin.logs.format import read_log
from twin.robots import load_robot, robot_text

QUICK = "m_b,l,n_yb,n_zb,d_b,d_w,gyro_bias_x,gyro_bias_y,gyro_bias_z"


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """An 8 s paper-exp1 log (balance only: it never turns) with the plant 10 % heavier, and a
    3 s one (too short to calibrate from)."""
    d = tmp_path_factory.mktemp("calibrate")
    # a robot file of one's own (the paper's figures, under another name): the log carries it
    (d / "mine.toml").write_text(robot_text("paper").replace('name = "paper"', 'name = "mine"'), encoding="utf-8")
    r = _twin("run", "paper-exp1", "--controller", "it2", "--duration", "8", "--no-video", "--log-sensors",
              "--robot", str(d / "mine.toml"), "--set", "plant.scale={m_b = 1.1, l = 1.05}", "--out", str(d / "exp1"))
    assert r.returncode == 0, r.stderr
    r = _twin("run", "paper-exp1", "--controller", "it2", "--duration", "3", "--no-video", "--log-sensors",
              "--out", str(d / "short"))
    assert r.returncode == 0, r.stderr
    return d / "exp1" / "sensor-logs" / "it2", d / "short" / "sensor-logs" / "it2"


@pytest.fixture(scope="module")
def calibrated(logs, tmp_path_factory):
    out = tmp_path_factory.mktemp("calibration") / "cal"
    r = _twin("calibrate", str(logs[0]), "--parameters", QUICK, "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out, r.stdout


def test_report_has_every_parameter_with_value_interval_unit_and_identifiability(calibrated):
    out, stdout = calibrated
    doc = json.loads((out / "report.json").read_text())
    assert list(doc["parameters"]) == QUICK.split(",")
    for name, e in doc["parameters"].items():
        assert {"value", "ci95", "unit", "identifiable"} <= set(e), name
        lo, hi = e["ci95"]
        assert lo <= e["value"] <= hi and np.isfinite([lo, hi]).all(), name
    # absolute SI values: the body mass in kg (Table III's 2.58 kg × 1.1), within its interval's reach
    assert abs(doc["parameters"]["m_b"]["value"] / (2.58 * 1.1) - 1.0) < 0.05
    assert doc["parameters"]["m_b"]["unit"] == "kg" and doc["parameters"]["d_w"]["unit"] == "N·m·s/rad"
    k = len(doc["correlation"]["names"])
    C = np.array(doc["correlation"]["matrix"])
    assert C.shape == (k, k) and np.allclose(np.diag(C), 1.0) and np.allclose(C, C.T)
    assert (out / "figure.png").stat().st_size > 10_000 and (out / "manifest.json").exists()
    assert "m_b" in stdout and "kg" in stdout


def test_a_log_that_never_turns_does_not_identify_the_yaw_inertia(calibrated, logs):
    out, stdout = calibrated
    doc = json.loads((out / "report.json").read_text())
    e = doc["parameters"]["n_zb"]
    assert e["identifiable"] is False and "never turns" in e["why"]
    assert any(w.startswith("n_zb is not identified") for w in doc["warnings"])
    assert "warning: n_zb is not identified by this log: the log never turns" in stdout
    # and without --parameters it is not fitted at all
    from twin.calibrate.run import default_names
    from twin.calibrate.windows import streams

    assert "n_zb" not in default_names([streams(read_log(logs[0]))])


def test_the_calibration_runs_as_the_twins_plant(calibrated, tmp_path):
    out, _ = calibrated
    cal = tomllib.loads((out / "calibration.toml").read_text())
    scale = cal["plant"]["scale"]
    assert "n_zb" not in scale  # not identified: the nominal stays
    assert abs(scale["m_b"] - 1.1) < 0.05 and abs(scale["l"] - 1.05) < 0.05
    r = _twin("run", "paper-exp1", "--controller", "lqr", "--duration", "0.5", "--no-video", "--plant",
              str(out / "calibration.toml"), "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    ran = json.loads((tmp_path / "run" / "metrics.json").read_text())["scenario"]["plant"]["scale"]
    assert ran == pytest.approx(scale, rel=1e-12)
    # --set after --plant wins
    r = _twin("run", "paper-exp1", "--controller", "lqr", "--duration", "0.5", "--no-video", "--plant",
              str(out / "calibration.toml"), "--set", "plant.scale.m_b=1.3", "--out", str(tmp_path / "run2"))
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "run2" / "metrics.json").read_text())["scenario"]["plant"]["scale"]["m_b"] == 1.3


def test_the_fitted_robot_file_round_trips(calibrated, logs, tmp_path):
    """robot file → twin run --log-sensors → twin calibrate → robot.toml: its identified figures
    hold the true plant's (the robot file's × plant.scale) within their intervals, what the log does
    not identify is the input robot's and says so, and a run of the fitted robot (no mismatch
    left) matches the original run."""
    out, stdout = calibrated
    assert "robot.toml" in stdout.splitlines()[-1]
    text = (out / "robot.toml").read_text()
    fitted, mine = load_robot(out / "robot.toml"), load_robot(logs[0].parent.parent.parent / "mine.toml")
    assert fitted.name == "mine-fitted"
    doc = json.loads((out / "report.json").read_text())["parameters"]
    truth = {"m_b": 2.58 * 1.1, "l": 0.0622 * 1.05, "n_yb": 0.00128, "d_b": 0.001, "d_w": 0.01}
    where = {"m_b": ("body", "mass"), "l": ("body", "com_height"), "n_yb": ("body", "pitch_inertia"),
             "d_b": ("friction", "drive"), "d_w": ("friction", "ground")}
    identified = [n for n in truth if doc[n]["identifiable"]]
    assert {"m_b", "l", "n_yb"} <= set(identified)
    for n in identified:
        lo, hi = doc[n]["ci95"]
        assert lo <= truth[n] <= hi, (n, truth[n], lo, hi)
        assert fitted.values[where[n][0]][where[n][1]] == pytest.approx(doc[n]["value"], rel=1e-5)
    # n_zb: fitted, not identified (the log never turns): the input robot's, said so
    assert fitted.values["body"]["yaw_inertia"] == mine.values["body"]["yaw_inertia"]
    assert any(line.startswith("yaw_inertia = ") and "not identified" in line for line in text.splitlines())
    # the wheels and drive: not fitted, the input robot's
    assert fitted.values["wheels"] == mine.values["wheels"] and fitted.params().r == mine.params().r
    # the gyro's constant biases: identified axes are the fitted ones
    assert list(fitted.values["imu"]["gyro_bias"]) == pytest.approx(
        [doc[f"gyro_bias_{a}"]["value"] for a in "xyz"], rel=1e-5)
    # the fitted robot runs as the robot that wrote the log does (the true plant as a robot file:
    # the controllers are designed for each robot's own figures, so neither run has a mismatch)
    true_file = tmp_path / "truth.toml"
    true_file.write_text(robot_text("paper").replace("mass = 2.58 ", f"mass = {2.58 * 1.1!r} ")
                         .replace("com_height = 0.0622 ", f"com_height = {0.0622 * 1.05!r} "), encoding="utf-8")
    assert load_robot(true_file).params().m_b == pytest.approx(2.58 * 1.1)
    for robot, name in ((true_file, "truth"), (out / "robot.toml", "fitted")):
        r = _twin("run", "paper-exp1", "--controller", "it2", "--duration", "8", "--no-video", "--robot",
                  str(robot), "--set", "plant.scale={}", "--out", str(tmp_path / name))
        assert r.returncode == 0, r.stderr
    a, b = (json.loads((tmp_path / n / "metrics.json").read_text())["runs"]["it2"] for n in ("truth", "fitted"))
    assert a["fell"] is b["fell"] is False
    assert abs(a["settling_time_s"] - b["settling_time_s"]) <= 0.05, (a["settling_time_s"], b["settling_time_s"])
    assert b["iae_theta"] == pytest.approx(a["iae_theta"], rel=0.05)
    assert b["theta_rms_rad"] == pytest.approx(a["theta_rms_rad"], rel=0.05)


@pytest.mark.parametrize("text, says", [
    (None, "no such file"),
    ("[plant]\nscale = {m_b = 1.1}\n", "not a calibration.toml"),
    ("[calibration]\n[plant]\nmass = 3\n", "[plant] mass is not taken from a calibration"),
    ("[calibration\n", "not a calibration.toml"),
])
def test_a_bad_plant_file_is_one_line(tmp_path, text, says):
    f = tmp_path / "calibration.toml"
    if text is not None:
        f.write_text(text)
    r = _twin("run", "paper-exp1", "--duration", "0.1", "--no-video", "--plant", str(f), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and says in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_an_unknown_parameter_is_one_line(logs, tmp_path):
    r = _twin("calibrate", str(logs[0]), "--parameters", "m_b,mass", "--out", str(tmp_path / "c"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "no parameter 'mass'" in r.stderr and "allowed: m_b, l, n_yb" in r.stderr
    assert not (tmp_path / "c").exists()


def test_a_log_too_short_to_excite_anything_is_one_line(logs, tmp_path):
    r = _twin("calibrate", str(logs[1]), "--out", str(tmp_path / "c"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "a calibration needs at least 50" in r.stderr
    assert not (tmp_path / "c").exists()


def test_a_validation_log_of_another_robot_is_one_line(logs, tmp_path):
    other = tmp_path / "other"
    shutil.copytree(logs[1], other)
    text = (other / "log.toml").read_text()
    (other / "log.toml").write_text(text.replace("wheel_radius = 0.04", "wheel_radius = 0.05", 1))
    r = _twin("calibrate", str(logs[0]), "--validate", str(other), "--out", str(tmp_path / "c"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "another robot" in r.stderr and "wheel_radius" in r.stderr


def test_one_log_twice_and_the_twins_stepping_on_two_logs_are_one_line(logs, tmp_path):
    # several logs of one robot are one fit (tests/test_calibrate_foreign.py); the same log twice is not
    r = _twin("calibrate", str(logs[0]), str(logs[0]), "--out", str(tmp_path / "c"))
    assert r.returncode == 2 and "given twice" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = _twin("calibrate", str(logs[0]), str(logs[1]), "--model", "twin", "--out", str(tmp_path / "c"))
    assert r.returncode == 2 and "fits one log" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "c").exists()


def test_motor_figures_need_motors_and_the_dead_band_is_refused(logs):
    log = read_log(logs[0])
    with pytest.raises(TwinError, match="dead_band: a log's duty.csv holds the duty after the dead band"):
        calibrate([log], ("m_b", "dead_band"))


def test_confounded_parameters_are_named(logs):
    # the motors' no-load speed enters only through c_e = stall torque / no-load speed, which adds to
    # d_b on the joint: the log cannot tell them apart
    cal = calibrate([read_log(logs[0])], ("m_b", "d_b", "no_load_speed", "gyro_bias_y"), bootstrap=20)
    _, warnings, corr = assess(cal, TURN_RATE)
    assert any(w.startswith("d_b and no_load_speed are confounded in this log (correlation ") for w in warnings), warnings
    names = corr["names"]
    assert abs(corr["matrix"][names.index("d_b")][names.index("no_load_speed")]) >= 0.95


def test_the_same_log_and_seed_give_the_same_report(calibrated, tmp_path, logs):
    out, _ = calibrated
    r = _twin("calibrate", str(logs[0]), "--parameters", QUICK, "--out", str(tmp_path / "again"))
    assert r.returncode == 0, r.stderr
    a = json.loads((out / "report.json").read_text())
    b = json.loads((tmp_path / "again" / "report.json").read_text())
    for doc in (a, b):
        doc["method"].pop("wall_s")
    assert a == b
    assert (out / "calibration.toml").read_text() == (tmp_path / "again" / "calibration.toml").read_text()


def test_list_names_every_parameter_with_its_unit_and_no_log_is_one_line():
    r = _twin("calibrate", "--list")
    assert r.returncode == 0 and "m_b" in r.stdout and "kg" in r.stdout and "imu_latency" in r.stdout
    r = _twin("calibrate")
    assert r.returncode == 2 and "needs a LOG" in r.stderr and len(r.stderr.strip().splitlines()) == 1
