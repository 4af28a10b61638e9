"""Sensor specifications in scenarios: the IMU presets against their datasheets (Allan
deviation of the simulated static sensor), the believed specification reaching the EKF
while the sensors simulate the true one, the new keys' one-line errors, and the old keys
and the run record unchanged at their defaults.

The Allan checks drive :class:`TriadNoise` through its real per-sample path with fixed
seeds (the analysis alone is vectorised), so they are deterministic; the 10 % tolerance is
several standard errors of each estimate (stated per test), so a wrong factor (√2, √3,
Δt against √Δt, a unit) fails.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from estimation.ekf import EKFEstimator
from twin.cli import main
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario
from twin.sensors.noise import TriadNoise
from twin.sensors.specs import DEG, G0, IMU_PRESETS, MPU6050_ACCEL, MPU6050_GYRO

RATE = 200.0  # Hz, the default IMU rate
PRESET_CASES = [(name, i) for name in IMU_PRESETS for i in (0, 1)]
PRESET_IDS = [f"{name}-{'gyro' if i == 0 else 'accel'}" for name, i in PRESET_CASES]


def _samples(noise: TriadNoise, n: int) -> np.ndarray:
    """``n`` readings of a zero true input through the real per-sample path, (n, 3)."""
    s = noise.sample
    return np.array([s(0.0, 0.0, 0.0) for _ in range(n)])


def _avar(y: np.ndarray, m: int) -> float:
    """Overlapping Allan variance at cluster size ``m``, averaged over the axes (columns)."""
    theta = np.vstack([np.zeros((1, y.shape[1])), np.cumsum(y, axis=0)])
    d = (theta[2 * m:] - 2.0 * theta[m:-m] + theta[:-2 * m]) / m
    return float(np.mean(d ** 2) / 2.0)


# ---- 1. the presets against their datasheets --------------------------------------------------

@pytest.mark.parametrize("name, i", PRESET_CASES, ids=PRESET_IDS)
def test_preset_white_noise_is_the_datasheet_noise_density(name, i):
    """Static preset sensor at the IMU's 200 Hz, its own 16-bit ADC, turn-on bias and scale
    error as drawn (a constant and a zero input: the Allan variance ignores both): σ_A(τ0)·√τ0
    at τ0 = 5 ms is the noise density. Quantisation adds LSB²/12 (≤ 1.3 % of the variance, the
    ICM-42688-P gyro), the walk ≤ 1e-5. 40 000 samples × 3 axes: one standard error 0.3 %.
    Measured: 0.997–1.003 of the datasheet figure."""
    spec = IMU_PRESETS[name][i]
    dt = 1.0 / RATE
    y = _samples(TriadNoise(spec, dt, np.random.default_rng(4200 + 2 * PRESET_CASES.index((name, i)))), 40_000)
    n_hat = math.sqrt(_avar(y, 1) * dt)
    assert n_hat / spec.noise_density == pytest.approx(1.0, abs=0.10), (name, spec.name, n_hat / spec.noise_density)
    # the figure is the datasheet's, in SI: 1 °/s = π/180 rad/s, 1 µg = 9.80665e-6 m/s²
    datasheet = {"mpu6050": (0.005 * DEG, 400e-6 * G0), "icm42688p": (0.0028 * DEG, 70e-6 * G0),
                 "bmi088": (0.014 * DEG, 190e-6 * G0)}[name][i]
    assert spec.noise_density == pytest.approx(datasheet, rel=1e-12)


@pytest.mark.parametrize("name, i", PRESET_CASES, ids=PRESET_IDS)
def test_preset_bias_random_walk_from_the_allan_deviation(name, i):
    """K = σ_A(τ)·√(3/τ) where the Allan deviation rises as +1/2 (the walk rules).

    White noise and walk cross at τc = √3·N/K (3.8 s for the MPU-6050 gyro, 113 s for the
    BMI088 gyro): the +1/2 region lies at τ ≫ τc, hours of 200 Hz samples. The pipeline
    scales both figures with the output interval (σ_w = N/√Δt, K·√Δt per sample), so the
    static sensor is sampled at Δt = τc/8 instead (the 200 Hz scaling is the test above), with
    a 32-bit ADC: at that Δt the per-sample noise is below the 16-bit LSB, whose steps would
    otherwise be all one sees. 131 072 samples (16 384 τc) × 3 axes; K̂ at τ = 16 τc and 32 τc,
    where the white noise adds 0.2 % and 0.05 % (one standard error 1.3 % and 1.8 %); the
    log-log slope from 8 τc to 32 τc is the model's 0.495 within 0.05. Measured: K̂/K
    0.974–1.044, slope 0.479–0.517."""
    spec = replace(IMU_PRESETS[name][i], bits=32)
    tau_c = math.sqrt(3.0) * spec.noise_density / spec.bias_random_walk
    dt = tau_c / 8.0
    y = _samples(TriadNoise(spec, dt, np.random.default_rng(4201 + 2 * PRESET_CASES.index((name, i)))), 131_072)
    avar = {m: _avar(y, m) for m in (64, 128, 256)}
    for m in (128, 256):
        k_hat = math.sqrt(avar[m] * 3.0 / (m * dt))
        assert k_hat / spec.bias_random_walk == pytest.approx(1.0, abs=0.10), (name, spec.name, m, k_hat)
    slope = 0.5 * math.log(avar[256] / avar[64]) / math.log(256 / 64)
    assert slope == pytest.approx(0.5, abs=0.05), (name, spec.name, slope)


def test_preset_full_scales_give_the_datasheet_sensitivities():
    """The chosen ranges on 16 bits give the datasheets' LSB per unit: ICM-42688-P 65.5 LSB per
    °/s (±500 °/s) and 8192 LSB/g (±4 g); BMI088 65.536 LSB per °/s and 5460 LSB/g (±6 g)."""
    expected = {"icm42688p": (65.5, 8192.0), "bmi088": (65.536, 5460.0), "mpu6050": (131.0, 16384.0)}
    for name, (g, a) in IMU_PRESETS.items():
        assert (g.bits, a.bits) == (16, 16)
        assert DEG / g.lsb == pytest.approx(expected[name][0], rel=1e-3), name
        assert G0 / a.lsb == pytest.approx(expected[name][1], rel=1e-3), name
    assert IMU_PRESETS["mpu6050"] == (MPU6050_GYRO, MPU6050_ACCEL)  # the default stays the MPU-6050


def test_gauss_markov_bias_through_the_scenario_key(tmp_path):
    """``sensors.gyro.bias_correlation_time`` turns the preset's walk into a Gauss–Markov bias:
    steady σ = K·√(τ/2) and correlation e^{−1} at lag τ. τ = 20 s, Δt = 1 s, 200 000 samples ×
    3 axes (10 000 τ): one standard error about 0.5 % on σ, 0.01 on the correlation. Measured:
    σ̂/σ 0.998, correlation 0.366 (e^{−1} = 0.368)."""
    sc = _scenario(tmp_path, '[sensors]\nimu = "bmi088"\n[sensors.gyro]\nbias_correlation_time = 20.0\n'
                             'bias_random_walk = 1e-4\n')
    spec = sc.sensor_config().imu.gyro
    assert (spec.bias_correlation_time, spec.bias_random_walk) == (20.0, 1e-4)
    assert spec.noise_density == IMU_PRESETS["bmi088"][0].noise_density  # the rest is the preset's
    noise = TriadNoise(spec, 1.0, np.random.default_rng(88))
    drift = []
    for _ in range(200_000):
        noise.sample(0.0, 0.0, 0.0)
        drift.append(tuple(noise.drift))
    b = np.array(drift)
    assert b.std(axis=0).mean() / (1e-4 * math.sqrt(10.0)) == pytest.approx(1.0, abs=0.10)
    lag = 20
    corr = np.mean([np.corrcoef(b[:-lag, a], b[lag:, a])[0, 1] for a in range(3)])
    assert corr == pytest.approx(math.exp(-1.0), abs=0.05)


# ---- 2. the believed specification -----------------------------------------------------------

def _scenario(tmp_path, text: str, overrides=()):
    path = tmp_path / "spec.toml"
    path.write_text('duration = 0.05\n[video]\nenabled = false\n' + text, encoding="utf-8")
    return load_scenario(path, overrides)


def _spy_loops(monkeypatch) -> list:
    """Every twin.sim.loop.ClosedLoop the runner builds, kept for inspection (replaced where the
    engine looks it up: twin.sim.loop, and twin.sim.simulate where it imports the class by name)."""
    import twin.sim.loop
    import twin.sim.simulate

    loops = []

    class Spy(twin.sim.loop.ClosedLoop):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            loops.append(self)

    monkeypatch.setattr(twin.sim.loop, "ClosedLoop", Spy)
    if hasattr(twin.sim.simulate, "ClosedLoop"):
        monkeypatch.setattr(twin.sim.simulate, "ClosedLoop", Spy)
    return loops


def _q_and_r(triads, dt: float) -> tuple[float, float, float]:
    """The EKF's per-sample gyro and accelerometer variances and gyro-bias process noise for
    (gyro, accel) specifications (estimation/ekf.py: white noise + LSB²/12; K²·Δt)."""
    g, a = triads
    return (g.white_sigma(dt) ** 2 + g.lsb ** 2 / 12.0, a.white_sigma(dt) ** 2 + a.lsb ** 2 / 12.0,
            g.bias_random_walk ** 2 * dt)


def test_believed_specification_reaches_the_ekf_and_the_truth_the_sensors(tmp_path, monkeypatch):
    """A BMI088 on the robot, an EKF tuned to an ICM-42688-P datasheet with a yet lower gyro
    noise: through load_scenario → run_scenario, the SensorSuite's noise pipelines carry the
    BMI088 figures and the EKF's Q and R (``_g_var``, ``_a_var``, ``_bias_q``) the belief's;
    the run record keeps the belief."""
    sc = _scenario(tmp_path, '[sensors]\nimu = "bmi088"\n[sensors.believed]\nimu = "icm42688p"\n'
                             '[sensors.believed.gyro]\nnoise_density = 2e-5\n')
    loops = _spy_loops(monkeypatch)
    result = run_scenario(sc, ("lqr",), out=tmp_path / "out", video=False)
    assert result.runs[0].status == "ok" and len(loops) == 1
    suite, ekf = loops[0].suite, loops[0].estimator
    bmi_g, bmi_a = IMU_PRESETS["bmi088"]
    icm_g, icm_a = IMU_PRESETS["icm42688p"]
    believed = (replace(icm_g, noise_density=2e-5), icm_a)
    assert (suite.gyro.spec, suite.accel.spec) == (bmi_g, bmi_a)
    assert isinstance(ekf, EKFEstimator)
    got = (ekf._g_var, ekf._a_var, ekf._bias_q)
    assert got == pytest.approx(_q_and_r(believed, ekf.dt), rel=1e-12)
    truth = _q_and_r((bmi_g, bmi_a), ekf.dt)
    assert all(abs(x / y - 1.0) > 0.5 for x, y in zip(got, truth))  # the belief is far from the truth
    assert ekf.model.imu.position == suite.config.imu.position  # mounting point, rate, latency: the true ones
    record = json.loads((tmp_path / "out" / "metrics.json").read_text(encoding="utf-8"))["scenario"]["sensors"]
    assert record["imu"] == "bmi088"
    assert record["believed"] == {"imu": "icm42688p", "gyro": {"noise_density": 2e-5}}


def test_without_a_belief_the_ekf_believes_the_true_overridden_sensor(tmp_path, monkeypatch):
    """No [sensors.believed]: the EKF's Q and R follow the true specification, overrides included;
    a belief of one figure keeps the true preset's others."""
    sc = _scenario(tmp_path, '[sensors]\nimu = "icm42688p"\n[sensors.accel]\nnoise_density = 1e-3\n')
    assert sc.build_context().sensors == sc.sensor_config()
    loops = _spy_loops(monkeypatch)
    run_scenario(sc, ("lqr",))
    ekf = loops[0].estimator
    true = (IMU_PRESETS["icm42688p"][0], replace(IMU_PRESETS["icm42688p"][1], noise_density=1e-3))
    assert (ekf._g_var, ekf._a_var, ekf._bias_q) == pytest.approx(_q_and_r(true, ekf.dt), rel=1e-12)
    one = _scenario(tmp_path, '[sensors]\nimu = "icm42688p"\n[sensors.believed.gyro]\nbias_random_walk = 1e-5\n')
    g, a = one.believed_sensor_config().imu.gyro, one.believed_sensor_config().imu.accel
    assert g == replace(IMU_PRESETS["icm42688p"][0], bias_random_walk=1e-5) and a == IMU_PRESETS["icm42688p"][1]
    assert one.sensor_config().imu.gyro == IMU_PRESETS["icm42688p"][0]


# ---- 3. bad keys: one line, exit status 2 -------------------------------------------------------

def twin(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.stdout, r.stderr


BAD = {
    "negative-density": ('[sensors.gyro]\nnoise_density = -1e-4\n',
                         ["sensors.gyro.noise_density: -0.0001 is out of range", "allowed in [0, 1000] rad/s/√Hz"]),
    "negative-believed-density": ('[sensors.believed.accel]\nnoise_density = -0.01\n',
                                  ["sensors.believed.accel.noise_density: -0.01 is out of range",
                                   "allowed in [0, 1000] m/s²/√Hz"]),
    "range-below-noise": ('[sensors.accel]\nfull_scale = 0.1\n',
                          ["sensors.accel.full_scale: 0.1 m/s² is below 5 × the white noise of one sample",
                           "allowed: full_scale ≥ 0.2774 m/s²"]),
    "believed-range-below-noise": ('[sensors]\nimu = "bmi088"\n[sensors.believed.gyro]\nfull_scale = 0.01\n',
                                   ["sensors.believed.gyro.full_scale: 0.01 rad/s is below 5 × the white noise",
                                    "allowed: full_scale ≥ 0.01728 rad/s"]),
    "unknown-preset": ('[sensors]\nimu = "mpu9250"\n',
                       ["sensors.imu: 'mpu9250' is not allowed", "(one of 'mpu6050', 'icm42688p', 'bmi088')"]),
    "unknown-believed-preset": ('[sensors.believed]\nimu = "adxl345"\n',
                                ["sensors.believed.imu: 'adxl345' is not allowed",
                                 "(one of 'mpu6050', 'icm42688p', 'bmi088')"]),
    "mounting-point-above-the-body": ('[sensors]\nimu_position = [0.0, 0.0, 0.3]\n',
                                      ["sensors.imu_position: (0, 0, 0.3) m is outside the robot's body",
                                       "allowed: a point of the body's box, x in [-0.04, 0.04], y in [-0.1325, "
                                       "0.1325], z in [-0.01244, 0.1368] m"]),
    "mounting-point-beside-the-body": ('[sensors]\nimu_position = [0.06, 0.0, 0.1]\n',
                                       ["sensors.imu_position: (0.06, 0, 0.1) m is outside the robot's body"]),
    "unknown-triad-key": ('[sensors.gyro]\nnoise = 1e-4\n',
                          ["sensors.gyro.noise: unknown key", "allowed here: noise_density, bias_random_walk"]),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_sensor_key_is_one_line_naming_it(tmp_path, case):
    text, fragments = BAD[case]
    path = tmp_path / f"{case}.toml"
    path.write_text(text, encoding="utf-8")
    status, stdout, stderr = twin("run", path, "--no-video", "--out", tmp_path / "out")
    assert status == 2, (status, stdout, stderr)
    assert "Traceback" not in stderr and stdout == ""
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}: "), stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert not (tmp_path / "out").exists()


def test_mounting_point_follows_the_true_body():
    """The box is the true plant's: a body 20 % longer (plant.scale.l) holds a point 15 cm up
    that the nominal body does not."""
    status, _, stderr = twin("run", "paper-exp1", "--set", "sensors.imu_position=[0, 0, 0.15]", "--no-video",
                             "--duration", "0.05", "--controller", "lqr", "--out", "/nonexistent/never-written")
    assert status == 2 and "sensors.imu_position: (0, 0, 0.15) m is outside the robot's body" in stderr
    sc = load_scenario("paper-exp1", ["sensors.imu_position=[0, 0, 0.15]", "plant.scale.l=1.2"])
    assert sc.sensor_config().imu.position == (0.0, 0.0, 0.15)


def test_bad_key_from_a_real_process_is_one_line():
    r = subprocess.run([sys.executable, "-m", "twin.cli", "run", "paper-exp2", "--set", "sensors.imu=mpu9250",
                        "--no-video"], capture_output=True, text=True)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == ("error: built-in scenario paper-exp2 with --set sensors.imu=mpu9250: sensors.imu: 'mpu9250' "
                        "is not allowed (one of 'mpu6050', 'icm42688p', 'bmi088')\n")


# ---- 4. the old keys, and the record at defaults --------------------------------------------------

def test_old_sensor_keys_work_as_before_and_new_keys_stay_out_of_the_record():
    sc = load_scenario("paper-exp2", ["sensors.imu_latency=0.01", "sensors.encoder_counts=2000"])
    imu = sc.sensor_config().imu
    assert (imu.rate, imu.latency, sc.sensor_config().encoders.counts_per_rev) == (200.0, 0.01, 2000)
    assert (imu.gyro, imu.accel, imu.position) == (MPU6050_GYRO, MPU6050_ACCEL, (0.0, 0.0, 0.1))
    assert sc.build_estimator().d_imu == 2
    assert list(sc.record()["sensors"]) == ["sensing", "estimator", "imu_rate", "imu_latency", "encoder_counts",
                                            "encoder_latency"]
    moved = load_scenario("paper-exp2", ["sensors.imu=icm42688p", "sensors.gyro.bits=20",
                                         "sensors.believed.accel.turn_on_bias=0.01"])
    rec = moved.record()["sensors"]
    assert (rec["imu"], rec["gyro"], rec["believed"]) == ("icm42688p", {"bits": 20},
                                                          {"accel": {"turn_on_bias": 0.01}})
    assert "accel" not in rec and "imu_position" not in rec
