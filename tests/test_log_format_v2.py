"""Sensor-log format version 2 (issue 40, part 1; docs/reference/sensor-log.md): log.toml says
every figure the estimators are built with, the twin writes it and its logs replay bit for bit
as they did in version 1, version 1 is still read and says what it assumed, the replay applies
what the format says (the IMU's orientation, sampled commands, volts, motor encoders, a truth at
another rate) and notes what an estimator cannot use, streams of one's own are read and
reported, sign checks tell a user whether their sensors agree, and bad input is one line."""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from twin.errors import TwinError
from twin.logs.checks import sign_checks
from twin.logs.format import read_log, write_log
from twin.logs.replay import build_for, instants, replay, replay_logs, write_estimates_csv
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario

KINDS = ["ekf", "complementary", "kalman2"]
DOCS = Path(__file__).resolve().parent.parent / "docs" / "reference" / "sensor-log.md"


def _twin(*args):
    r = subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True, timeout=300)
    return r.returncode, r.stdout, r.stderr


def _logs(root: Path, scenario: str, *items: str):
    """A twin run of ``scenario`` (IT2; 2 s unless ``items`` say otherwise) written as version 1 and as version 2."""
    sc = load_scenario(scenario, ["duration=2", *items])
    run = run_scenario(sc, ["it2"], out=None, video=False).runs[0]
    return sc, write_log(run, root / "v1", sc, version=1), write_log(run, root / "v2", sc)


@pytest.fixture(scope="module")
def twin_logs(tmp_path_factory):
    """paper-exp3 (a catch from 0.48 rad, a drive and a turn), 2 s, as version 1 and version 2."""
    return _logs(tmp_path_factory.mktemp("exp3"), "paper-exp3")


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _edit(d: Path, old: str, new: str) -> None:
    text = (d / "log.toml").read_text(encoding="utf-8")
    assert old in text, old
    (d / "log.toml").write_text(text.replace(old, new, 1), encoding="utf-8")


def _without_step_us(entry: dict) -> str:
    entry = json.loads(json.dumps(entry))
    for e in entry["estimators"].values():
        e.pop("step_us")
    return json.dumps(entry, sort_keys=True)


# ---- the twin's logs: version 2, bit for bit ------------------------------------------------------
@pytest.mark.parametrize("scenario, items", [
    ("paper-exp3", ()),
    ("paper-exp1", ('plant.motor="ideal"',)),  # ideal torque sources: [motor] kind = "ideal"
    ("sensor-faults", ("duration=9.5", 'sensors.believed.imu="icm42688p"')),  # faults; a believed other part
])
def test_a_twin_log_replays_bit_for_bit_whether_written_as_version_1_or_2(tmp_path, scenario, items):
    sc, v1, v2 = _logs(tmp_path, scenario, *items)
    text1, text2 = (v1 / "log.toml").read_text(), (v2 / "log.toml").read_text()
    assert "version = 1" in text1 and "encoder_counts = " in text1 and "[imu]" not in text1
    assert "version = 2" in text2 and "[imu.gyro]" in text2 and "encoder_counts" not in text2
    a, b = read_log(v1), read_log(v2)
    assert b.format_info["assumed"] == {}  # every figure is in log.toml
    believed = sc.believed_sensor_config()  # what the run's estimator was built for
    assert b.sensors.imu == believed.imu and b.sensors.encoders == believed.encoders
    assert (b.motor, b.model) == (a.motor, a.model)
    da, ra = replay_logs([v1], KINDS)
    db, rb = replay_logs([v2], KINDS)
    ea, eb = da["logs"][str(v1)], db["logs"][str(v2)]
    assert ea["format"]["version"] == 1 and eb["format"]["version"] == 2
    ea.pop("format"), eb.pop("format")
    assert _without_step_us(ea) == _without_step_us(eb)  # errors, NEES, NIS, whiteness, events, checks, notes
    assert json.dumps(da["estimators"], sort_keys=True) == json.dumps(db["estimators"], sort_keys=True)
    write_estimates_csv(ra, tmp_path / "a.csv")
    write_estimates_csv(rb, tmp_path / "b.csv")
    rows_a = [ln.split(",", 1)[1] for ln in (tmp_path / "a.csv").read_text().splitlines()[1:]]
    rows_b = [ln.split(",", 1)[1] for ln in (tmp_path / "b.csv").read_text().splitlines()[1:]]
    assert rows_a == rows_b and len(rows_a) == len(KINDS) * len(ra[(str(v1), "ekf")].t)


def test_version_2_is_not_vacuous_a_changed_figure_changes_the_replay(twin_logs, tmp_path):
    """The equality above holds because version 2 carries the figures: one changed (the gyro's
    noise density) changes the EKF's estimates."""
    _, _, v2 = twin_logs
    d = _copy(v2, tmp_path / "noisier")
    text = (d / "log.toml").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("noise_density"))
    _edit(d, line, f"noise_density = {2.0 * float(line.split('=')[1])!r}")
    a, b = read_log(v2), read_log(d)
    ra, rb = replay(a, build_for(a, "ekf")), replay(b, build_for(b, "ekf"))
    assert not np.array_equal(ra.estimates, rb.estimates)


def test_the_command_says_a_logs_version_and_what_version_1_leaves_unsaid(twin_logs, tmp_path):
    _, v1, v2 = twin_logs
    status, out, err = _twin("replay", str(v1), str(v2), "--estimator", "ekf", "--out", str(tmp_path / "o"))
    assert status == 0, err
    lines = out.splitlines()
    one = [ln for ln in lines if "log format version 1" in ln]
    assert len(one) == 1 and "assumed from scenario paper-exp3 with duration=2" in one[0]
    assert "means over 5 ms (200 Hz), 5 ms late, in the body's axes, mpu6050 noise figures" in one[0]
    assert "commands held" in one[0] and "DC motors (12 V" in one[0]
    assert sum("log format version 2: every figure the estimators use is in log.toml" in ln for ln in lines) == 1
    assert sum(ln.strip().startswith("check gravity_on_z: pass") for ln in lines) == 2
    doc = json.loads((tmp_path / "o" / "replay.json").read_text())
    f1 = doc["logs"][str(v1)]["format"]
    assert f1["version"] == 1 and f1["assumed"]["imu"]["sampling"] == "mean"
    assert f1["assumed"]["imu"]["latency_s"] == 0.005 and f1["assumed"]["commands"]["semantics"] == "held"
    assert f1["assumed"]["motor"]["stall_torque"] == 1.2
    assert set(doc["logs"][str(v2)]["checks"]) == {"gravity_on_z", "gyro_pitch_vs_accel_tilt",
                                                   "gyro_yaw_vs_encoders", "encoders_vs_commands"}


# ---- what the replay applies ---------------------------------------------------------------------------
def _rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx  # v_body = C v_imu


def _rotate_imu(d: Path, C: np.ndarray) -> None:
    """imu.csv's body-axis readings written in the IMU's axes: v_imu = Cᵀ v_body."""
    lines = (d / "imu.csv").read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        cells = ln.split(",")
        v = np.array([float(c) for c in cells[1:]]).reshape(2, 3) @ C  # rows: (Cᵀ v)ᵀ = vᵀ C
        out.append(",".join([cells[0]] + [repr(float(x)) for x in v.ravel()]))
    (d / "imu.csv").write_text("\n".join(out) + "\n")


def test_the_imus_orientation_turns_its_readings_into_body_axes(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    angles = (0.1, 0.07, 0.2)  # rad: roll, pitch, yaw
    C = _rotation(*angles)
    said = _copy(v2, tmp_path / "said")
    _rotate_imu(said, C)
    _edit(said, "orientation = [0.0, 0.0, 0.0]", f"orientation = [{', '.join(map(repr, angles))}]")
    matrix = _copy(said, tmp_path / "matrix")
    _edit(matrix, f"orientation = [{', '.join(map(repr, angles))}]",
          "orientation_matrix = [" + ", ".join("[" + ", ".join(repr(float(x)) for x in row) + "]" for row in C) + "]")
    unsaid = _copy(said, tmp_path / "unsaid")
    _edit(unsaid, f"orientation = [{', '.join(map(repr, angles))}]", "orientation = [0.0, 0.0, 0.0]")
    ref = read_log(v2)
    for d in (said, matrix):
        log = read_log(d)
        assert np.allclose(log.gyro, ref.gyro, rtol=0, atol=1e-12) and np.allclose(log.accel, ref.accel, atol=1e-12)
    r_ref, r_said = (replay(x, build_for(x, "ekf")) for x in (ref, read_log(said)))
    assert np.abs(r_said.estimates[:, 0] - r_ref.estimates[:, 0]).max() < 1e-6  # the same filter, to rounding
    wrong = read_log(unsaid)  # the mounting not said: a tilted, rolled IMU taken for the body's axes
    r_wrong = replay(wrong, build_for(wrong, "ekf"))
    assert np.abs(r_wrong.estimates[:, 0] - r_ref.estimates[:, 0]).max() > 0.03
    assert sign_checks(wrong)["gravity_on_z"]["status"] == "warn"  # the roll and yaw put g on y (1.7 m/s²)
    assert sign_checks(read_log(said))["gravity_on_z"]["status"] == "pass"
    doc, _ = replay_logs([said], ["ekf"])
    notes = doc["logs"][str(said)]["notes"]
    assert any(n.startswith("ekf: its clipping test holds the IMU's full scales against the body's axes") for n in notes)
    assert doc["logs"][str(said)]["format"]["applied"][0].startswith("the IMU's readings turned into the body's axes")


def _still_log(d: Path, *, unit: str = "N·m", semantics: str = "held", every: int = 1, seconds: float = 1.0,
               extra: str = "", motor: str = 'kind = "ideal"', command=lambda t: 0.1 * t) -> Path:
    """A version-2 log written by hand: a robot standing still at 0.05 rad, IMU and encoders at
    200 Hz, commands ``command(t)`` every ``every`` control periods."""
    d.mkdir(parents=True)
    (d / "log.toml").write_text(f"""format = "mtwip-sensor-log"
version = 2
control_rate = 200.0
wheel_radius = 0.04
track = 0.30
[imu]
sampling = "mean"
rate = 200.0
latency = 0.0
position = [0.0, 0.0, 0.1]
orientation = [0.0, 0.0, 0.0]
[encoders]
counts_per_rev = 1200
on = "wheel"
latency = 0.0
[commands]
unit = "{unit}"
semantics = "{semantics}"
[motor]
{motor}
{extra}""", encoding="utf-8")
    rng = np.random.default_rng(3)
    n = int(seconds * 200) + 1
    g, tilt = 9.81, 0.05
    with open(d / "imu.csv", "w") as fh:
        fh.write("t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n")
        for k in range(n):
            a = np.array([-g * math.sin(tilt), 0.0, g * math.cos(tilt)]) + rng.normal(0, 0.02, 3)
            fh.write(",".join(repr(float(v)) for v in (k / 200, *rng.normal(0, 1e-3, 3), *a)) + "\n")
    with open(d / "encoders.csv", "w") as fh:
        fh.write("t,left,right\n" + "".join(f"{k / 200!r},0,0\n" for k in range(n)))
    with open(d / "commands.csv", "w") as fh:
        fh.write("t,ul,ur\n")
        for k in range(0, n, every):
            fh.write(f"{k / 200!r},{command(k / 200)!r},{command(k / 200)!r}\n")
    return d


@pytest.mark.parametrize("every", [1, 4])  # commands at the control rate, and at a quarter of it
def test_sampled_commands_give_each_period_the_mean_of_the_samples_joined_by_lines(tmp_path, every):
    held = read_log(_still_log(tmp_path / "held", every=every))
    sampled = read_log(_still_log(tmp_path / "sampled", semantics="sampled", every=every))
    t, _, u_held = instants(held)
    t2, _, u_sampled = instants(sampled)
    assert np.array_equal(t, t2)
    period = 1.0 / 200.0
    rows = np.floor(t * 200 / every + 1e-9) * every / 200  # the row in force at each instant
    assert np.allclose(u_held[:, 0], 0.1 * rows, rtol=0, atol=1e-12)
    # a ramp's mean over [t_k, t_k + T] (the last period: the ramp held at its last sample)
    want = np.where(t + period <= t[-1] + 1e-12, 0.1 * (t + 0.5 * period), 0.1 * t[-1])
    assert np.allclose(u_sampled[:, 0], want, rtol=0, atol=1e-12)
    assert sampled.command_semantics == "sampled" and held.command_semantics == "held"


def test_commands_in_volts_are_a_duty_of_the_supply(tmp_path):
    motor = 'kind = "dc"\nsupply_voltage = 12.0\nstall_torque = 0.8'
    log = read_log(_still_log(tmp_path / "volts", unit="V", motor=motor, command=lambda t: 6.0 - 3.0 * t))
    assert np.allclose(log.commands[:, 0], (6.0 - 3.0 * log.commands_t) / 12.0 * 0.8, rtol=0, atol=1e-15)
    assert log.estimator_motor().back_emf_compensation is False  # past the driver, as a duty
    with pytest.raises(TwinError, match=r"commands.csv: row 2: a voltage beyond the supply's ±12 V"):
        read_log(_still_log(tmp_path / "over", unit="V", motor=motor, command=lambda t: 13.0))


def test_encoders_on_the_motor_count_through_the_gears(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    d = _copy(v2, tmp_path / "motor")
    _edit(d, 'counts_per_rev = 1200\non = "wheel"', 'counts_per_rev = 12\non = "motor"\ngear_ratio = 100.0')
    a, b = read_log(v2), read_log(d)
    assert b.counts_per_rev == 1200 and b.sensors.encoders == a.sensors.encoders
    assert np.array_equal(replay(a, build_for(a, "ekf")).estimates, replay(b, build_for(b, "ekf")).estimates)


def _thin_truth(d: Path, keep) -> None:
    lines = (d / "truth.csv").read_text().splitlines()
    (d / "truth.csv").write_text("\n".join([lines[0]] + [ln for k, ln in enumerate(lines[1:]) if keep(k, ln)]) + "\n")


def test_a_truth_at_a_lower_rate_gives_nees_at_its_instants_and_errors_there(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    low = _copy(v2, tmp_path / "50hz")
    _thin_truth(low, lambda k, _: k % 4 == 0)  # 50 Hz on the 200 Hz control instants
    doc, rep = replay_logs([v2, low], ["ekf"])
    full, thin = (doc["logs"][str(p)] for p in (v2, low))
    n = full["instants"]
    assert thin["truth"]["instants_with_truth"] == (n + 3) // 4 and thin["truth"]["nees"].startswith("at the ")
    assert thin["estimators"]["ekf"]["errors"]["rows"] == (n + 3) // 4
    c = thin["estimators"]["ekf"]["consistency"]
    assert 0 < c["nees_rows"] < full["estimators"]["ekf"]["consistency"]["nees_rows"] / 3
    e_full, e_thin = (rep[(str(p), "ekf")].diagnostics.nees for p in (v2, low))
    on = np.isfinite(e_thin)
    assert on.sum() > 0 and np.array_equal(e_thin[on], e_full[on])  # the same NEES at the truth's instants


def test_a_truth_off_the_control_instants_is_interpolated_and_the_nees_refused_in_one_line(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    off = _copy(v2, tmp_path / "off")
    lines = (off / "truth.csv").read_text().splitlines()
    shifted = [lines[0]] + [f"{float(ln.split(',', 1)[0]) + 0.001!r},{ln.split(',', 1)[1]}" for ln in lines[1:]]
    (off / "truth.csv").write_text("\n".join(shifted) + "\n")  # a truth 1 ms off the control grid
    doc, _ = replay_logs([v2, off], ["ekf"])
    full, moved = (doc["logs"][str(p)] for p in (v2, off))
    err = moved["estimators"]["ekf"]["errors"]
    assert err["rows"] == err["interpolated_rows"] > 0 and err["theta_rmse_rad"] is not None
    assert err["theta_rmse_rad"] < 2 * full["estimators"]["ekf"]["errors"]["theta_rmse_rad"] + 1e-3
    assert moved["truth"]["nees"].startswith("not computed: no truth row lies on a control instant")
    assert "nees_mean" not in moved["estimators"]["ekf"]["consistency"]
    assert "\n" not in moved["truth"]["text"]


def test_the_ekf_takes_point_samples_and_a_latency_is_whole_periods(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    d = _copy(v2, tmp_path / "point")
    _edit(d, 'sampling = "mean"', 'sampling = "point"')
    _edit(d, "latency = 0.005", "latency = 0.0033")
    log = read_log(d)
    assert log.sensors.imu.latency == 0.005 and log.sampling == "point"
    doc, replays = replay_logs([d], ["ekf", "kalman2"])
    notes = doc["logs"][str(d)]["notes"]
    assert any(n.startswith('ekf: imu.sampling = "point": its strapdown step takes each interval\'s mean as the '
                            'trapezoid') for n in notes)
    # the EKF was told: the same rows read as interval means give other estimates
    _, as_means = replay_logs([v2], ["ekf"])
    assert not np.array_equal(replays[(str(d), "ekf")].estimates, as_means[(str(v2), "ekf")].estimates)
    assert any(n.startswith("imu.latency = 0.0033 s is not a whole number of control periods") for n in notes)
    assert any(n.startswith("kalman2: uses none of the log's noise figures") for n in notes)


def test_noise_figures_as_sigma_and_bias_instability(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    d = _copy(v2, tmp_path / "figures")
    text = (d / "log.toml").read_text()
    gyro = text[text.index("[imu.gyro]"):text.index("[imu.accel]")]
    _edit(d, gyro, "[imu.gyro]\nsigma = 0.002\nbias_instability = 1e-4\nbias_correlation_time = 100.0\n\n")
    log = read_log(d)
    g = log.sensors.imu.gyro
    assert math.isclose(g.noise_density * math.sqrt(200.0), 0.002, rel_tol=1e-12)
    assert math.isclose(g.bias_random_walk, 1e-4 / 0.6174 * math.sqrt(2.0 / 100.0), rel_tol=1e-12)
    assert log.format_info["assumed"]["imu.gyro"] == ["turn_on_bias", "scale_factor_error", "full_scale", "bits"]
    doc, _ = replay_logs([d], ["ekf"])
    assert "imu.gyro turn_on_bias, scale_factor_error, full_scale, bits (mpu6050's)" in \
        doc["logs"][str(d)]["format"]["text"]
    assert any("bias_correlation_time is not used" in n for n in doc["logs"][str(d)]["notes"])


# ---- streams of one's own ----------------------------------------------------------------------------
def test_a_stream_of_ones_own_is_read_checked_and_reported(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    d = _copy(v2, tmp_path / "current")
    lines = (d / "commands.csv").read_text().splitlines()
    rows = [f"{ln.split(',')[0]},{float(ln.split(',')[1]) / 0.34!r}," for ln in lines[1:]]  # i_r empty: none came
    (d / "current.csv").write_text("t,i_l,i_r\n" + "\n".join(rows) + "\n")
    with open(d / "log.toml", "a") as fh:
        fh.write('\n[streams.current]\nfile = "current.csv"\ncolumns = { t = "s", i_l = "A", i_r = "A" }\n')
    log = read_log(d)
    st = log.streams["current"]
    assert st.columns == ("i_l", "i_r") and st.units == ("A", "A") and st.values.shape == (len(rows), 2)
    assert np.isnan(st.values[:, 1]).all() and np.isfinite(st.values[:, 0]).all()
    doc, rep = replay_logs([d], ["ekf"])
    entry = doc["logs"][str(d)]["streams"]["current"]
    assert entry["rows"] == len(rows) and entry["columns"] == {"i_l": "A", "i_r": "A"}
    assert entry["text"].endswith("read and checked; no estimator uses it")
    ref, _ = replay_logs([v2], ["ekf"])  # and the estimators are none the wiser
    assert np.array_equal(rep[(str(d), "ekf")].estimates, replay(read_log(v2), build_for(read_log(v2), "ekf")).estimates)
    (d / "current.csv").write_text("t,i_left,i_r\n0.0,1.0,1.0\n")
    with pytest.raises(TwinError, match=r"current.csv: row 1: the header must be t,i_l,i_r \(as log.toml's "
                                         r"\[streams.current\] declares\)"):
        read_log(d)


# ---- bad input: one line, exit status 2 ------------------------------------------------------------
BAD = [
    ("orientation = [0.0, 0.0, 0.0]", "orientation_matrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]]",
     "imu.orientation_matrix: not a rotation"),
    ("orientation = [0.0, 0.0, 0.0]", "orientation_matrix = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]",
     "imu.orientation_matrix: not a rotation (largest |CᵀC − I| 0, det -1)"),
    ("orientation = [0.0, 0.0, 0.0]\n", "", "imu.orientation: missing; allowed: [roll, pitch, yaw] in rad"),
    ("orientation = [0.0, 0.0, 0.0]", "orientation = [0.0, 4.0, 0.0]", "imu.orientation: [0.0, 4.0, 0.0]; allowed"),
    ("latency = 0.005", "latency = -0.005", "imu.latency: -0.005; allowed: a number in [0, 1] s"),
    ('sampling = "mean"', 'sampling = "average"', "imu.sampling: 'average'; allowed: \"mean\" or \"point\""),
    ('semantics = "held"', 'semantics = "interpolated"',
     "commands.semantics: 'interpolated'; allowed: \"held\" or \"sampled\""),
    ('unit = "N·m"', 'unit = "mN·m"', "commands.unit: 'mN·m'; allowed: \"N·m\" or \"duty\" or \"V\""),
    ("\nrate = 200.0", "\nrate = 150.0",
     "imu.rate: 150 Hz; allowed: the control rate (200 Hz) divided by a whole number"),
    ('counts_per_rev = 1200\non = "wheel"', 'counts_per_rev = 12\non = "motor"\ngear_ratio = 34.014',
     "encoders: counts_per_rev × gear_ratio = 408.168 counts per wheel revolution; allowed: a whole number"),
    ('unit = "N·m"\nsemantics = "held"\n\n[motor]\nkind = "dc"\nsupply_voltage = 12.0\n',
     'unit = "V"\nsemantics = "held"\n\n[motor]\nkind = "dc"\n',
     "motor.supply_voltage: missing; commands in volts need it"),
    ("[imu.gyro]\n", "[imu.gyro]\nnoise = 1.0\n", "imu.gyro.noise: unknown key; allowed: noise_density (rad/s/√Hz)"),
    ("[robot]\n", "[robot]\nmass = 2.0\n", "robot.mass: unknown key; allowed keys: m_w (kg), m_b (kg)"),
    ('kind = "dc"', 'kind = "stepper"', "motor.kind: 'stepper'; allowed: \"dc\" or \"ideal\""),
    ("[robot]\n", '[streams.current]\nfile = "current.csv"\ncolumns = { t = "s", i_l = "A" }\n[robot]\n',
     "streams.current: current.csv is missing; allowed: a declared stream's file beside log.toml"),
    ("[robot]\n", '[streams.imu]\ncolumns = { t = "s", gyro_x = "deg/s", gyro_y = "rad/s", gyro_z = "rad/s", '
                  'accel_x = "m/s^2", accel_y = "m/s^2", accel_z = "m/s^2" }\n[robot]\n',
     "streams.imu.columns.gyro_x: 'deg/s'; allowed: 'rad/s'"),
    ("[robot]\n", '[streams.temp]\ncolumns = { t = "ms", c = "K" }\n[robot]\n',
     "streams.temp.columns: the first column is 't' in 'ms'; allowed: t = \"s\" first"),
]


@pytest.mark.parametrize("old, new, says", BAD, ids=[b[2].split(":")[0] + f"-{i}" for i, b in enumerate(BAD)])
def test_bad_version_2_input_is_one_line_naming_the_key_and_what_is_allowed(twin_logs, tmp_path, old, new, says):
    _, _, v2 = twin_logs
    d = _copy(v2, tmp_path / "bad")
    _edit(d, old, new)
    with pytest.raises(TwinError) as exc:
        read_log(d)
    msg = str(exc.value)
    assert says in msg and "\n" not in msg and msg.startswith(str(d / "log.toml")), msg


def test_bad_input_through_the_command_line_is_exit_status_2(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    d = _copy(v2, tmp_path / "bad")
    _edit(d, "orientation = [0.0, 0.0, 0.0]", "orientation_matrix = [[1, 0, 0], [0, 1, 0.1], [0, 0, 1]]")
    status, out, err = _twin("replay", str(d), "--out", str(tmp_path / "o"))
    assert status == 2 and len(err.strip().splitlines()) == 1 and "imu.orientation_matrix: not a rotation" in err
    assert not (tmp_path / "o").exists()


# ---- sign checks ---------------------------------------------------------------------------------
def _flip(d: Path, stream: str, column: int) -> None:
    lines = (d / stream).read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        cells = ln.split(",")
        if cells[column]:
            cells[column] = cells[column][1:] if cells[column].startswith("-") else "-" + cells[column]
        out.append(",".join(cells))
    (d / stream).write_text("\n".join(out) + "\n")


def test_sign_checks_pass_on_the_twins_log_and_warn_where_a_sign_is_wrong(twin_logs, tmp_path):
    _, _, v2 = twin_logs
    checks = sign_checks(read_log(v2))
    assert checks["gravity_on_z"]["status"] == "pass"
    assert checks["gyro_pitch_vs_accel_tilt"]["status"] == "pass"  # the catch from 0.48 rad
    assert checks["encoders_vs_commands"]["status"] == "pass"
    assert all("\n" not in c["text"] and c["text"].startswith(n) for n, c in checks.items())
    pitch = _copy(v2, tmp_path / "pitch")
    _flip(pitch, "imu.csv", 2)  # gyro_y's sign
    c = sign_checks(read_log(pitch))["gyro_pitch_vs_accel_tilt"]
    assert c["status"] == "warn" and c["figures"]["slope"] < 0 and "opposite signs" in c["text"]
    left = _copy(v2, tmp_path / "left")
    _flip(left, "encoders.csv", 1)  # the left encoder counts backwards
    c = sign_checks(read_log(left))["encoders_vs_commands"]
    assert c["status"] == "warn" and "the left wheel" in c["text"] and c["figures"]["correlation_left"] < -0.3


def _turning_log(d: Path) -> Path:
    """A robot driven forward and turned left (kinematics only), version 2."""
    d = _still_log(d, seconds=2.0)
    t = np.arange(401) / 200.0
    turn = np.where(t >= 0.5, 0.5, 0.0)  # rad/s, turning left from 0.5 s
    alpha = np.concatenate([[0.0], np.cumsum(0.5 * (turn[1:] + turn[:-1]) / 200.0)])
    wheels = [np.floor((s * 0.15 / 0.04 * alpha + 2.0 * t) / (2 * math.pi / 1200)).astype(int) for s in (-1, 1)]
    rows = (d / "imu.csv").read_text().splitlines()
    out = [rows[0]]
    for k, ln in enumerate(rows[1:]):
        cells = ln.split(",")
        cells[3] = repr(float(np.diff(alpha, prepend=0.0)[k] * 200.0))
        out.append(",".join(cells))
    (d / "imu.csv").write_text("\n".join(out) + "\n")
    (d / "encoders.csv").write_text("t,left,right\n" + "".join(
        f"{float(t[k])!r},{wheels[0][k]},{wheels[1][k]}\n" for k in range(len(t))))
    return d


def test_the_yaw_check_tells_gyro_z_from_the_encoders_heading(tmp_path):
    good = read_log(_turning_log(tmp_path / "turn"))
    c = sign_checks(good)["gyro_yaw_vs_encoders"]
    assert c["status"] == "pass" and abs(c["figures"]["slope"] - 1.0) < 0.02
    bad = _copy(tmp_path / "turn", tmp_path / "flipped")
    _flip(bad, "imu.csv", 3)
    c = sign_checks(read_log(bad))["gyro_yaw_vs_encoders"]
    assert c["status"] == "warn" and c["figures"]["slope"] < 0
    assert sign_checks(read_log(_still_log(tmp_path / "still")))["gyro_yaw_vs_encoders"]["status"] == "skip"


# ---- the reference page --------------------------------------------------------------------------------
def test_the_reference_page_lists_every_key_with_its_unit():
    from twin.logs import format as fmt

    page = DOCS.read_text(encoding="utf-8")
    tables = {"[imu]": fmt.IMU_KEYS, "[imu.gyro]": fmt.TRIAD_KEYS, "[encoders]": fmt.ENCODER_KEYS,
              "[commands]": fmt.COMMAND_KEYS, "[motor]": fmt.motor_keys(), "[robot]": {
                  k: (u, d) for k, (u, d) in fmt.robot_keys().items()}, "[streams.NAME]": fmt.STREAM_KEYS}
    for table, keys in tables.items():
        for key, (unit, _) in keys.items():
            if key in ("gyro", "accel"):
                continue  # the sub-tables, [imu.gyro] and [imu.accel]
            unit = unit.replace("U", "")
            row = next((ln for ln in page.splitlines() if ln.startswith(f"| `{key}` |")), None)
            assert row is not None, f"{table} {key} is not in {DOCS.name}"
            assert not unit or unit.lstrip("/") in row, f"{table} {key}: its unit {unit!r} is not in its row"
    for key in sorted(fmt._KEYS_V2) + list(fmt.TRUTH_KEYS):
        assert f"`{key}`" in page or f"[{key}]" in page or f"`[{key}" in page, key
