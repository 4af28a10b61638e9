"""The IMU's noise measured from a log's own readings (twin.logs.noise) and the figures a replay
uses (``twin replay --noise``): the differencing estimator recovers a known σ under strong
motion, pushes, spikes, jittered row times, railed and quantised readings; on a real-robot-shaped
log of the independent simulator it recovers the true per-row noise, and the EKF told it is
consistent where the datasheet's figures made it reject most readings; a log whose figures the
data do not contradict keeps them; bad input is one line and exit status 2."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from twin.errors import TwinError
from twin.logs import noise
from twin.logs.format import read_log
from twin.logs.replay import replay_logs

sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/ (for the foreign package), as test_foreign_sim.py

TOL = 0.10  # relative: the recovered σ of synthetic readings (2000–4000 windows: a standard error of 2–2.5 %)
SIM_TOL = 0.20  # relative: the recovered σ of a simulator's log (450–550 rows: a standard error of about 5 %)


def _twin(*args):
    r = subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True, timeout=300)
    return r.returncode, r.stdout, r.stderr


def _motion(t: np.ndarray) -> np.ndarray:
    """A strong smooth motion: rad/s, up to ±3 rad/s, components up to 3 Hz (a balancing robot's)."""
    w = 2 * np.pi
    return 2.0 * np.sin(w * 0.4 * t) + 0.6 * np.sin(w * 3.0 * t + 1.0) + 0.4 * np.cos(w * 1.3 * t)


# ---- the estimator on synthetic readings ---------------------------------------------------------------
@pytest.mark.parametrize("rate, sigma", [(200.0, 1.2e-3), (200.0, 0.05), (33.0, 0.05)])
def test_differences_recover_a_known_sigma_under_strong_smooth_motion(rate, sigma):
    rng = np.random.default_rng(1)
    t = np.arange(4000) / rate
    y = _motion(t) + rng.normal(0.0, sigma, t.size)
    d = noise.difference_sigma(t, y)
    assert abs(d["sigma"] / sigma - 1.0) < TOL, d["sigma"]
    assert d["residuals"] == t.size - noise.ORDER and d["se_rel"] < 0.03
    if rate == 200.0 and sigma < 0.01:  # the readings' own spread is the motion's, 1000× the noise
        assert np.std(y) > 100 * sigma


def test_pushes_and_spikes_do_not_inflate_it():
    rng = np.random.default_rng(2)
    rate, sigma = 200.0, 2e-3
    t = np.arange(3000) / rate
    y = _motion(t) + rng.normal(0.0, sigma, t.size)
    for start in (2.0, 6.0, 11.0):  # half-sine pushes of 0.15 s: a jolt of ±8 rad/s through the pitch rate
        on = (t >= start) & (t < start + 0.15)
        y[on] += 8.0 * np.sin(np.pi * (t[on] - start) / 0.15) ** 3 * np.sign(np.sin(40 * (t[on] - start)))
    spikes = rng.choice(t.size, 30, replace=False)  # 1 % of the rows: ±0.5 rad/s glitches
    y[spikes] += rng.choice([-0.5, 0.5], spikes.size)
    got = noise.difference_sigma(t, y)["sigma"]
    assert abs(got / sigma - 1.0) < TOL, got
    # the plain RMS of the same residuals is many times the noise: the robust scale is what holds
    w, _ = noise.difference_weights(t)
    r = (w * np.lib.stride_tricks.sliding_window_view(y, noise.ORDER + 1)).sum(axis=1)
    assert np.sqrt(np.mean(r * r)) > 5 * sigma


def test_jittered_row_times_are_handled_by_divided_differences():
    """Rows every 30–33 ms (a logger decimating a 1 kHz loop): the weights from the rows' own
    times annihilate the motion; the same readings taken as equally spaced do not."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.integers(30, 34, 3000)) * 1e-3
    sigma = 0.01
    y = 25.0 * np.sin(2 * np.pi * 0.3 * t) + 6.0 * np.sin(2 * np.pi * 0.6 * t) + rng.normal(0.0, sigma, t.size)
    got = noise.difference_sigma(t, y)
    assert abs(got["sigma"] / sigma - 1.0) < TOL, got["sigma"]
    equal = noise.difference_sigma(np.arange(t.size) * float(np.median(np.diff(t))), y)["sigma"]
    assert equal > 1.8 * sigma  # the jitter times the motion's slope, taken for noise


def test_duplicated_times_and_gaps_are_left_out_not_taken_for_noise():
    rng = np.random.default_rng(4)
    t = np.arange(2000) / 200.0
    t[500] = t[499]  # a duplicated time
    t = np.concatenate([t[:1000], t[1000:] + 0.5])  # a 0.5 s gap
    sigma = 1e-3
    y = _motion(t) + rng.normal(0.0, sigma, t.size)
    d = noise.difference_sigma(t, y)
    assert d["left_out"]["duplicated"] > 0 and d["left_out"]["gaps"] > 0
    assert abs(d["sigma"] / sigma - 1.0) < TOL


def test_railed_readings_are_left_out_and_the_adc_step_is_accounted_for():
    """A gyro that clips on a fast swing and quantises to 16 bits: the railed rows are left out,
    and the white part √(σ² − q²/12) is the noise a density describes."""
    rng = np.random.default_rng(5)
    from twin.sensors.specs import MPU6050_GYRO

    fs, lsb = MPU6050_GYRO.full_scale, MPU6050_GYRO.lsb
    rate, sigma = 200.0, 0.6 * lsb  # noise below one ADC step: q²/12 is 23 % of σ² + q²/12
    t = np.arange(4000) / rate
    y = 5.0 * np.sin(2 * np.pi * 0.2 * t) + rng.normal(0.0, sigma, t.size)  # beyond ±4.36 rad/s a third of the time
    codes = np.clip(np.floor(y / lsb + 0.5), -2 ** 15, 2 ** 15 - 1)
    read = codes * lsb
    railed = noise._railed(np.column_stack([read] * 3), MPU6050_GYRO)[:, 0]
    assert railed.mean() > 0.1
    got = noise.difference_sigma(t, read, exclude=railed)
    assert got["left_out"]["excluded"] > 0
    assert abs(got["sigma"] / math.sqrt(sigma ** 2 + lsb ** 2 / 12) - 1.0) < TOL
    assert abs(math.sqrt(got["sigma"] ** 2 - lsb ** 2 / 12) / sigma - 1.0) < 1.5 * TOL  # the white part
    kept = noise.difference_sigma(t, read)  # railed rows in: the rail's flat stretches pull σ down
    assert kept["sigma"] < 0.9 * got["sigma"]


def test_too_few_rows_is_no_measurement():
    t = np.arange(40) / 200.0
    d = noise.difference_sigma(t, np.random.default_rng(6).normal(0, 1e-3, 40))
    assert math.isnan(d["sigma"]) and d["residuals"] < noise.MIN_RESIDUALS


def test_allan_deviation_of_a_long_still_log_and_its_motion_flag():
    rng = np.random.default_rng(7)
    rate, sigma, k = 200.0, 1e-3, 2e-4  # white noise per sample and a rate random walk (rad/s/√s)
    n = 200_000  # 1000 s
    walk = np.cumsum(rng.normal(0.0, k / math.sqrt(rate), n))
    y = rng.normal(0.0, sigma, n) + walk
    d = noise.difference_sigma(np.arange(n) / rate, y)
    a = noise.allan_figures(y, 1.0 / rate, d["sigma"])
    assert abs(a["white_sigma"] / sigma - 1.0) < 0.05 and not a["motion"]
    assert abs(a["white_density"] / (sigma / math.sqrt(rate)) - 1.0) < 0.05
    assert a["random_walk"] is not None and 0.5 < a["random_walk"] / k < 2.0  # read off the curve's +½ slope
    assert a["bias_instability"] > 0
    moving = y[:4000] + _motion(np.arange(4000) / rate)
    assert noise.allan_figures(moving, 1.0 / rate, sigma)["motion"]
    assert noise.allan_figures(y[:500], 1.0 / rate, sigma) is None  # too short


# ---- a log's figures: given, measured, datasheet ---------------------------------------------------------
def _v2_log(d: Path, *, gyro: str = "", accel: str = "", rows: int = 1001, sg: float = 2e-3, sa: float = 0.05,
            jitter: bool = False, stuck: tuple = ()) -> Path:
    """A version-2 log by hand: a robot rocking ±0.2 rad at 1 Hz, IMU and encoders at 200 Hz, with white
    noise σ ``sg`` rad/s and ``sa`` m/s² per row; ``gyro`` and ``accel`` the [imu.*] tables' lines."""
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
[imu.gyro]
{gyro}
[imu.accel]
{accel}
[encoders]
counts_per_rev = 1200
on = "wheel"
latency = 0.0
[commands]
unit = "N·m"
semantics = "held"
[motor]
kind = "ideal"
""", encoding="utf-8")
    rng = np.random.default_rng(8)
    t = np.arange(rows) / 200.0 + (rng.uniform(0, 4e-4, rows) if jitter else 0.0)
    th = 0.2 * np.sin(2 * np.pi * t)
    w = 0.4 * np.pi * np.cos(2 * np.pi * t)
    g = np.column_stack([np.zeros(rows), w, np.zeros(rows)]) + rng.normal(0, sg, (rows, 3))
    a = np.column_stack([-9.81 * np.sin(th), np.zeros(rows), 9.81 * np.cos(th)]) + rng.normal(0, sa, (rows, 3))
    if stuck:  # the gyro stuck at one reading over rows stuck[0] … stuck[1] − 1
        g[stuck[0]:stuck[1]] = g[stuck[0]]
    with open(d / "imu.csv", "w") as fh:
        fh.write("t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n")
        for k in range(rows):
            fh.write(",".join(repr(float(v)) for v in (t[k], *g[k], *a[k])) + "\n")
    with open(d / "encoders.csv", "w") as fh:
        q = np.floor(-th / (2 * np.pi / 1200)).astype(int)
        fh.write("t,left,right\n" + "".join(f"{k / 200!r},{q[k]},{q[k]}\n" for k in range(rows)))
    with open(d / "commands.csv", "w") as fh:
        fh.write("t,ul,ur\n" + "".join(f"{k / 200!r},0.0,0.0\n" for k in range(rows)))
    return d


def test_figures_the_data_do_not_contradict_are_kept_as_given(tmp_path):
    sg, sa = 2e-3, 0.05
    d = _v2_log(tmp_path / "said", gyro=f"sigma = {sg * 1.3!r}", accel=f"sigma = {sa / 1.3!r}", sg=sg, sa=sa)
    log = read_log(d)
    entry, sensors, k2 = noise.choose(log)
    assert sensors is log.sensors and k2 == {}  # the very figures: a twin's log replays bit for bit
    for name, s in (("gyro", sg), ("accel", sa)):
        tr = entry["triads"][name]
        assert tr["used"] == "log" and tr["verdict"] == "agree" and "do not contradict" in tr["why"]
        assert abs(tr["measured"]["sigma"] / s - 1.0) < TOL + 0.05  # the largest of three axes
    assert entry["used_by"] == ["ekf"]


def test_figures_the_data_contradict_or_none_given_are_replaced_by_the_measured_ones(tmp_path):
    sg, sa = 2e-3, 0.05
    wrong = read_log(_v2_log(tmp_path / "wrong", gyro=f"sigma = {sg / 20!r}", accel=f"sigma = {sa * 10!r}"))
    none = read_log(_v2_log(tmp_path / "none", jitter=True))
    e, sensors, k2 = noise.choose(wrong)
    g, a = e["triads"]["gyro"], e["triads"]["accel"]
    assert g["verdict"] == a["verdict"] == "contradict" and g["used"] == a["used"] == "measured"
    assert "the data contradict the log's figure" in g["why"] and e["used_by"] == ["ekf", "kalman2"]
    assert abs(sensors.imu.gyro.white_sigma(1 / 200.0) / g["measured"]["sigma"] - 1.0) < 0.01  # ADC step aside
    assert set(k2) == {"q_angle", "r_measure"} and e["kalman2"] == k2
    e2, s2, _ = noise.choose(none)
    assert all(e2["triads"][n]["used"] == "measured" and e2["triads"][n]["given"] is None for n in ("gyro", "accel"))
    assert "the log gives no noise figure" in e2["triads"]["gyro"]["why"]
    # the other choices
    eg, sg_, _ = noise.choose(wrong, "given")
    assert sg_ is wrong.sensors and all(eg["triads"][n]["used"] == "log" for n in ("gyro", "accel"))
    ed, sd, _ = noise.choose(wrong, "datasheet")
    assert sd.imu.gyro.noise_density == ed["triads"]["gyro"]["datasheet"]["noise_density"] == 0.005 * math.pi / 180
    em, sm, _ = noise.choose(read_log(_v2_log(tmp_path / "right", gyro=f"sigma = {sg!r}")), "measured")
    assert em["triads"]["gyro"]["used"] == "measured" and em["triads"]["gyro"]["verdict"] == "agree"
    with pytest.raises(TwinError, match="allowed: log, given, measured, datasheet"):
        noise.choose(wrong, "bogus")


def test_a_log_too_short_to_measure(tmp_path):
    short = read_log(_v2_log(tmp_path / "short", rows=40))
    e, sensors, _ = noise.choose(short)  # the default falls back to the datasheet's, saying so
    assert e["triads"]["gyro"]["used"] == "datasheet" and "too short to measure" in e["triads"]["gyro"]["why"]
    assert e["triads"]["gyro"]["verdict"] == "unmeasured"
    with pytest.raises(TwinError) as exc:
        noise.choose(short, "measured")
    msg = str(exc.value)
    assert "\n" not in msg and "too few usable IMU rows to measure the gyro's noise" in msg


def test_bad_noise_input_through_the_command_line_is_one_line_and_exit_status_2(tmp_path):
    d = _v2_log(tmp_path / "short", rows=40)
    status, out, err = _twin("replay", str(d), "--noise", "bogus", "--out", str(tmp_path / "o"))
    assert status == 2 and len(err.strip().splitlines()) == 1 and "--noise" in err and "bogus" in err
    status, out, err = _twin("replay", str(d), "--noise", "measured", "--out", str(tmp_path / "o"))
    assert status == 2 and len(err.strip().splitlines()) == 1 and "too few usable IMU rows" in err, err
    assert not (tmp_path / "o").exists()


# ---- the independent simulator's real-robot-shaped logs ---------------------------------------------------
def _profile_b(out: Path, seed: int) -> tuple[Path, dict]:
    """A profile-B log (33 Hz rows decimated from a 1 kHz loop, vibration, an IMU pitched 0.07 rad) in
    version 2 without noise figures: the noise must come from the data."""
    from foreign import robot_sim

    robot_sim.generate(out, "B", seed, version=2, noise_figures=False)
    return out, json.loads((out / "robot_sim.json").read_text())


def _true_row_sigma(side: dict) -> dict:
    """Each row is one point sample of the 1 kHz IMU: its noise is that sample's, the white noise
    (density · √1 kHz), the vibration (white, per sample) and the ADC step's q²/12, independent."""
    imu = side["imu"]
    out = {}
    for i, (name, rng_key) in enumerate((("gyro", "gyro_range"), ("accel", "accel_range"))):
        lsb = imu[rng_key] / 2 ** (imu["bits"] - 1)
        out[name] = math.sqrt(imu["white_sigma_per_sample"][i] ** 2 + imu[f"vibration_{name}"] ** 2 + lsb ** 2 / 12)
    return out


@pytest.fixture(scope="module")
def b_logs(tmp_path_factory):
    root = tmp_path_factory.mktemp("b")
    return [_profile_b(root / f"b{s}", s) for s in (0, 1)]


def test_the_measured_noise_of_a_real_robot_shaped_log_is_the_true_one(b_logs):
    for path, side in b_logs:
        truth = _true_row_sigma(side)
        assert truth["gyro"] > 0.04 and truth["accel"] > 0.5  # 100× and 25× the datasheet's at 33 Hz
        m = noise.measure(read_log(path))
        assert 29.0 < m["row_rate_hz"] < 34.0 and m["jitter"] > 0.03
        for name in ("gyro", "accel"):
            for ax in "xyz":
                got = m[name][ax]["sigma"]
                assert abs(got / truth[name] - 1.0) < SIM_TOL, (path.name, name, ax, got, truth[name])


def test_replay_with_the_measured_noise_makes_the_ekf_consistent_where_the_datasheet_did_not(b_logs, tmp_path):
    path, side = b_logs[0]
    status, out, err = _twin("replay", str(path), "--estimator", "ekf,kalman2", "--noise", "measured",
                             "--out", str(tmp_path / "m"))
    assert status == 0, err
    assert "noise: gyro" in out and "(measured: --noise measured)" in out
    doc = json.loads((tmp_path / "m" / "replay.json").read_text())
    entry = doc["logs"][str(path)]
    n = entry["noise"]
    truth = _true_row_sigma(side)
    assert n["mode"] == "measured" and "Rice 1984" in n["method"] and n["used_by"] == ["ekf", "kalman2"]
    for name in ("gyro", "accel"):
        tr = n["triads"][name]
        assert tr["used"] == "measured" and abs(tr["sigma"] / truth[name] - 1.0) < SIM_TOL
        assert tr["datasheet"]["sigma"] < tr["sigma"] / 10 and tr["axes"]["y"]["residuals"] > 400
    measured = entry["estimators"]["ekf"]["consistency"]["nis_per_dof"]
    sheet, _ = replay_logs([path], ["ekf", "kalman2"], "datasheet")
    datasheet = sheet["logs"][str(path)]["estimators"]["ekf"]["consistency"]["nis_per_dof"]
    assert measured < 3.0 and datasheet > 3.0 * measured, (measured, datasheet)
    rejected = (entry["estimators"]["ekf"]["rejected_total"],
                sheet["logs"][str(path)]["estimators"]["ekf"]["rejected_total"])
    assert rejected[1] > 5 * rejected[0], rejected  # with the datasheet's figures most readings are "outliers"
    k2 = entry["estimators"]["kalman2"]["consistency"]["nis_per_dof"]
    k2_sheet = sheet["logs"][str(path)]["estimators"]["kalman2"]["consistency"]["nis_per_dof"]
    assert k2 < 3.0 and k2_sheet > 50 * k2  # its published R_measure: 0.03 deg², against (3.5°)² of noise
    # the default finds the same: the log gives no figure, or figures the data contradict
    auto, _ = replay_logs([path], ["ekf"])
    assert all(auto["logs"][str(path)]["noise"]["triads"][t]["used"] == "measured" for t in ("gyro", "accel"))
    # bit for bit in one process (the command ran in another, where the compiled or the Python core
    # may have been loaded: they agree to ~1e-13, not bit for bit)
    forced, _ = replay_logs([path], ["ekf"], "measured")
    got = auto["logs"][str(path)]["estimators"]["ekf"]["consistency"]["nis_per_dof"]
    assert got == forced["logs"][str(path)]["estimators"]["ekf"]["consistency"]["nis_per_dof"]
    assert got == pytest.approx(measured, rel=1e-9)


def test_a_stuck_gyro_is_left_out_not_taken_for_silence(tmp_path):
    sg = 2e-3
    log = read_log(_v2_log(tmp_path / "stuck", rows=1501, sg=sg, stuck=(300, 1000)))  # stuck for 3.5 of 7.5 s
    m = noise.measure(log)["gyro"]["y"]
    assert m["stale_rows"] == 699 and abs(m["sigma"] / sg - 1.0) < TOL + 0.05, m["sigma"]
    # taken in, the stuck rows' zero differences are the majority: the median says "no noise"
    t = np.asarray(log.imu_t)
    assert noise.difference_sigma(t, log.gyro[:, 1])["sigma"] < 0.5 * sg


def test_a_twins_own_log_keeps_its_figures_by_default(tmp_path):
    """The twin's IMU noise is what its log says: the readings bear the figures out, so the default
    replays with them (the log's very SensorConfig) and equals --noise given."""
    from twin.logs.format import write_log
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    sc = load_scenario("paper-exp3", ["duration=2"])
    run = run_scenario(sc, ["it2"], out=None, video=False).runs[0]
    path = write_log(run, tmp_path / "twin", sc)
    log = read_log(path)
    entry, sensors, _ = noise.choose(log)
    assert sensors is log.sensors
    for name in ("gyro", "accel"):
        tr = entry["triads"][name]
        assert tr["used"] == "log" and tr["verdict"] == "agree"
        assert 0.8 < tr["measured"]["sigma"] / tr["given"]["sigma"] < 1.5  # the catch's motion leaks a little
    auto, ra = replay_logs([path], ["ekf"])
    given, rg = replay_logs([path], ["ekf"], "given")
    assert ra[(str(path), "ekf")].estimates.tobytes() == rg[(str(path), "ekf")].estimates.tobytes()
    assert ra[(str(path), "ekf")].estimates.tobytes() == run.estimates.tobytes()
