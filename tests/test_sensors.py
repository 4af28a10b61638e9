"""The sensor models: IMU noise statistics (Allan deviation, Gauss–Markov bias, turn-on
bias and scale factor, ADC), encoder quantisation, the IMU's true readings from the
physics, faults, latency, determinism and input validation.

Statistical checks use fixed seeds, and their tolerances are a stated number of standard
errors of the estimator (given with each test), so a wrong factor (√2, √3, Δt versus
√Δt, ...) fails while the test stays deterministic. The sensors are driven through their
real per-sample code paths (:meth:`TriadNoise.sample`, :meth:`SensorSuite.read`); only
the analysis is vectorised.
"""
import math
from dataclasses import replace

import numpy as np
import pybullet
import pytest

from twin.errors import TwinError
from twin.plant.bullet import BulletTwin, TwinConfig
from twin.sensors import (Dropout, EncoderSpec, ImuSpec, LatencyChange, SensorConfig, SensorSuite, Spikes, Stuck,
                          TriadSpec, imu_kinematics)
from twin.sensors.noise import TriadNoise
from twin.sensors.specs import DEG, G0, MPU6050_ACCEL, MPU6050_GYRO

RATE = 200.0  # Hz, the default control rate
T = 1.0 / RATE
G = 9.81
N_SIGMA = 5.0  # tolerance of the statistical checks, in standard errors
REST_G, REST_A = (0.0, 0.0, 0.0), (0.0, 0.0, G)  # true gyro and accelerometer readings, upright at rest


def _ideal(spec: TriadSpec, **kw) -> TriadSpec:
    """``spec`` without turn-on bias and scale error, and with a 32-bit ADC over ±1000 (quantisation
    step 4.7e-7: negligible against every noise level used here); ``kw`` overrides."""
    base = dict(turn_on_bias=0.0, scale_factor_error=0.0, full_scale=1e3, bits=32)
    base.update(kw)
    return replace(spec, **base)


def _noiseless(spec: TriadSpec) -> TriadSpec:
    return _ideal(spec, noise_density=0.0, bias_random_walk=0.0, bias_correlation_time=None)


def _samples(noise: TriadNoise, n: int, x=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``n`` readings of the constant true value ``x`` through the real per-sample path, (n, 3)."""
    s = noise.sample
    x0, x1, x2 = x
    return np.array([s(x0, x1, x2) for _ in range(n)])


# ---- Allan deviation ----------------------------------------------------------------------

def _allan_diffs(y: np.ndarray, m: int) -> np.ndarray:
    """Differences of consecutive overlapping cluster means of ``m`` samples, per axis (columns)."""
    theta = np.vstack([np.zeros((1, y.shape[1])), np.cumsum(y, axis=0)])
    return (theta[2 * m:] - 2.0 * theta[m:-m] + theta[:-2 * m]) / m


def _avar(y: np.ndarray, dt: float, ms) -> np.ndarray:
    """Overlapping Allan variance of the columns of ``y`` (n samples × axes) at cluster sizes ``ms``,
    averaged over the axes (IEEE Std 952)."""
    return np.array([np.mean(_allan_diffs(y, m) ** 2) / 2.0 for m in ms])


def _edf_white(n: int, m: int) -> float:
    """Equivalent degrees of freedom of the overlapping Allan variance, white noise in y, n phase
    points (Howe, Allan & Barnes 1981; NIST SP 1065 table 5)."""
    return (3.0 * (n - 1) / (2.0 * m) - 2.0 * (n - 2) / n) * 4.0 * m * m / (4.0 * m * m + 5.0)


def _edf_rw(n: int, m: int) -> float:
    """The same for a random walk in y (random-walk FM): about the number of clusters n/m."""
    return (n - 2) / m * ((n - 1) ** 2 - 3.0 * m * (n - 1) + 4.0 * m * m) / ((n - 3) ** 2)


def _rel_sigma_adev(edf: float) -> float:
    """Relative standard error of a deviation estimated with ``edf`` degrees of freedom."""
    return 1.0 / math.sqrt(2.0 * edf)


ALLAN_RATE = 1000.0  # Hz
ALLAN_N = 600_000  # samples per axis (600 s)
ALLAN_WHITE_TO_WALK = 25.0  # N/K in output intervals: white noise dominates below ~40 Δt, the walk above


def _allan_run(spec: TriadSpec, true, seed: int):
    """A static triad with its bias random walk raised to K = N / (25 Δt); returns (spec used, ms,
    Allan variances averaged over the axes, samples)."""
    dt = 1.0 / ALLAN_RATE
    n_d = spec.noise_density
    custom = _ideal(spec, bias_random_walk=n_d / (ALLAN_WHITE_TO_WALK * dt))
    y = _samples(TriadNoise(custom, dt, np.random.default_rng(seed)), ALLAN_N, true)
    ms = (1, 2, 5, 10, 20, 50, 100, 250, 500, 1000)
    return custom, ms, _avar(y, dt, ms), y


@pytest.mark.parametrize("which", ["gyro", "accel"])
def test_allan_deviation_shows_the_white_noise_and_the_bias_random_walk(which):
    """Static sensor (true rate 0, or gravity on z), turn-on bias and scale error off, 32-bit ADC.

    The model is σ²(τ) = N²/τ + K² Δt (2m² + 1)/(6m) (the discrete-time random walk; → K² τ/3),
    τ = m Δt. Checked:

    * at every τ the measured deviation is the model's within 5 standard errors of the
      overlapping estimator (its degrees of freedom from NIST SP 1065, three axes pooled);
    * at τ = Δt, σ √τ = N (white noise only: the walk adds 0.06 % there);
    * at τ = 250, 500, 1000 Δt, after removing the measured white part, √(3 σ²/τ) = K;
    * the axes are uncorrelated, at τ = Δt and at τ = 500 Δt.

    Measured: measured/model deviation 0.9989–1.021 over τ = 1…1000 Δt, all within 2 standard
    errors; gyro σ√τ/N = 0.99993 at τ = Δt (tolerance 0.42 %), K̂/K = 1.012, 1.019, 1.021 at
    250, 500, 1000 Δt (tolerances 4.2, 5.9, 8.4 %); accelerometer 1.0007 and 1.015, 1.011,
    0.998; axis correlations ≤ 0.002 at Δt (tolerance 0.008), ≤ 0.033 at 500 Δt (0.14).
    """
    spec, true = (MPU6050_GYRO, (0.0, 0.0, 0.0)) if which == "gyro" else (MPU6050_ACCEL, (0.0, 0.0, G))
    custom, ms, avar, y = _allan_run(spec, true, 952 if which == "gyro" else 953)
    dt = 1.0 / ALLAN_RATE
    n_d, k_rw = custom.noise_density, custom.bias_random_walk
    n_phase = ALLAN_N + 1
    ms_arr = np.array(ms, dtype=float)
    tau = ms_arr * dt
    model = n_d ** 2 / tau + k_rw ** 2 * dt * (2 * ms_arr ** 2 + 1) / (6 * ms_arr)
    ratio = np.sqrt(avar / model)
    for m, r in zip(ms, ratio):
        edf = 3 * min(_edf_white(n_phase, m), _edf_rw(n_phase, m))
        assert abs(r - 1.0) < N_SIGMA * _rel_sigma_adev(edf), (m, r)

    # white noise at the shortest τ: N/√τ
    n_hat = math.sqrt(avar[0] * tau[0])
    tol = N_SIGMA * _rel_sigma_adev(3 * _edf_white(n_phase, 1))
    assert n_hat / n_d == pytest.approx(1.0, abs=tol + 1e-3)  # + the walk's 0.06 % at m = 1
    # the log-log slopes: −1/2 where white noise rules (τ ≤ 10 Δt; the walk bends it by 0.01
    # there), +1/2 where the walk does

    def slope(v, i, j):
        return math.log(v[j] / v[i]) / math.log(tau[j] / tau[i]) / 2.0

    assert slope(avar, 0, 3) == pytest.approx(slope(model, 0, 3), abs=0.005)
    assert slope(model, 0, 3) == pytest.approx(-0.5, abs=0.015)

    # the bias random walk at long τ: K √(τ/3)
    for i, m in enumerate(ms):
        if m < 250:
            continue
        k_hat = math.sqrt(3.0 * (avar[i] - n_hat ** 2 / tau[i]) / tau[i])
        tol = N_SIGMA * _rel_sigma_adev(3 * _edf_rw(n_phase, m))
        assert k_hat / k_rw == pytest.approx(1.0, abs=tol), (m, k_hat / k_rw)
    assert slope(avar, -3, -1) == pytest.approx(0.5, abs=0.05)

    # the axes are independent, in their white noise (τ = Δt) and in their walks (τ = 500 Δt)
    for m, edf in ((1, _edf_white(n_phase, 1)), (500, _edf_rw(n_phase, 500))):
        corr = np.corrcoef(_allan_diffs(y, m).T)
        assert np.all(np.abs(corr[np.triu_indices(3, 1)]) < N_SIGMA / math.sqrt(edf)), (m, corr)


@pytest.mark.parametrize("which", ["gyro", "accel"])
def test_default_mpu6050_white_noise_per_sample(which):
    """The default suite at 200 Hz: the per-sample white σ is density·√rate (gyro 0.0707 °/s,
    accelerometer 5.66 mg), measured as the Allan deviation at τ = 5 ms (insensitive to the
    turn-on bias and scale error; the walk adds 3e-6 of the variance) with the 16-bit ADC's
    quantisation variance LSB²/12 added (0.1 % of the gyro's). 20 000 samples, 3 axes:
    5 standard errors = 1.8 %. Measured: gyro 0.995, accelerometer 0.997 of the expectation."""
    spec = MPU6050_GYRO if which == "gyro" else MPU6050_ACCEL
    assert spec.white_sigma(T) == pytest.approx(spec.noise_density * math.sqrt(RATE), rel=1e-12)
    suite = SensorSuite(SensorConfig(), RATE, np.random.default_rng(6050))
    rest_g, rest_a = (0.0, 0.0, 0.0), (0.0, 0.0, G)
    suite.start(rest_g, rest_a, 0.0, 0.0)
    n = 20_000
    y = np.array([getattr(suite.read(k, rest_g, rest_a, 0.0, 0.0), which) for k in range(n)])
    expected = math.sqrt(spec.noise_density ** 2 * RATE + spec.lsb ** 2 / 12.0)
    measured = math.sqrt(_avar(y, T, (1,))[0])
    assert measured / expected == pytest.approx(1.0, abs=N_SIGMA * _rel_sigma_adev(3 * _edf_white(n + 1, 1)))
    # the figures of the datasheet, in SI
    if which == "gyro":
        assert spec.noise_density * math.sqrt(RATE) == pytest.approx(0.005 * math.sqrt(200) * math.pi / 180)
    else:
        assert spec.noise_density * math.sqrt(RATE) == pytest.approx(400e-6 * 9.80665 * math.sqrt(200))


@pytest.mark.parametrize("spec", [MPU6050_GYRO, MPU6050_ACCEL], ids=["gyro", "accel"])
def test_default_adc_gives_lsb_multiples_and_saturates_at_the_full_scale_code(spec):
    """16-bit two's complement: every output is code·LSB with code in [−32768, 32767]; inputs beyond
    the range read exactly 32767 LSB or −32768 LSB; without noise the ADC rounds to the nearest code."""
    lsb = spec.lsb
    assert lsb == pytest.approx(spec.full_scale / 32768)
    rng = np.random.default_rng(16)
    noise = TriadNoise(spec, T, np.random.default_rng(17))
    xs = rng.uniform(-1.3, 1.3, (3000, 3)) * spec.full_scale
    y = np.array([noise.sample(*x) for x in xs])
    codes = y / lsb
    assert np.all(np.abs(codes - np.round(codes)) < 1e-9)
    assert codes.min() >= -32768 - 1e-9 and codes.max() <= 32767 + 1e-9
    far = np.abs(xs) > 1.1 * spec.full_scale  # beyond the range by far more than noise, bias and scale error
    assert far.sum() > 500
    assert np.all(y[far & (xs > 0)] == 32767 * lsb)
    assert np.all(y[far & (xs < 0)] == -32768 * lsb)
    inside = np.abs(xs) < 0.9 * spec.full_scale
    assert np.all(np.abs(codes[inside]) < 32767 * 0.95)
    # noise-free: nearest code
    clean = TriadNoise(replace(spec, noise_density=0.0, bias_random_walk=0.0, turn_on_bias=0.0,
                               scale_factor_error=0.0), T, np.random.default_rng(0))
    xs = rng.uniform(-0.99, 0.99, (2000, 3)) * spec.full_scale
    y = np.array([clean.sample(*x) for x in xs])
    assert np.all(np.abs(y - xs) <= 0.5 * lsb * (1 + 1e-9))
    assert np.all(np.abs(y / lsb - np.round(y / lsb)) < 1e-9)
    assert clean.sample(2 * spec.full_scale, -2 * spec.full_scale, spec.full_scale) == (
        pytest.approx(32767 * lsb, rel=1e-15), pytest.approx(-32768 * lsb, rel=1e-15),
        pytest.approx(32767 * lsb, rel=1e-15))
    assert clean.clip(1e9) == pytest.approx(32767 * lsb) and clean.clip(-1e9) == pytest.approx(-32768 * lsb)


# ---- Gauss–Markov bias ----------------------------------------------------------------------

def test_gauss_markov_bias_has_its_steady_state_sigma_and_correlation():
    """τ = 10 Δt, K = 1 unit/√s, no white noise: the output is the bias. Its standard deviation is
    K √(τ/2) = 0.0707 and its lag-1 autocorrelation e^(−Δt/τ) = 0.9048 from the first sample on
    (the initial bias is drawn from the steady state).

    Tolerances, 5 standard errors of an AR(1) process with φ = 0.905 over 3 × 200 000 samples:
    σ 1.5 %, φ 0.003; over 3 × 1500 first samples of independent runs σ 5.3 %. Measured: σ ratio
    0.998, φ̂ − φ = −3.3e-4, first-sample σ ratio 0.991."""
    dt, tau, k = 1e-3, 0.01, 1.0
    spec = _ideal(MPU6050_GYRO, noise_density=0.0, bias_random_walk=k, bias_correlation_time=tau)
    n = 200_000
    y = _samples(TriadNoise(spec, dt, np.random.default_rng(1981)), n)
    sigma_ss = k * math.sqrt(tau / 2.0)
    phi = math.exp(-dt / tau)
    assert np.allclose(y.mean(axis=0), 0.0, atol=N_SIGMA * sigma_ss * math.sqrt((1 + phi) / (1 - phi) / n))
    ratio = y.std() / sigma_ss
    rel_var = math.sqrt(2.0 / (3 * n) * (1 + phi * phi) / (1 - phi * phi))  # of the sample variance
    assert ratio == pytest.approx(1.0, abs=N_SIGMA * rel_var / 2)
    yc = y - y.mean(axis=0)
    rho = float(np.sum(yc[1:] * yc[:-1]) / np.sum(yc * yc))
    assert rho == pytest.approx(phi, abs=N_SIGMA * math.sqrt((1 - phi * phi) / (3 * n)))
    # a random walk (no τ) would show ρ → 1, a white sequence ρ → 0: the check is sharp
    assert abs(rho - 1.0) > 0.05 and abs(rho - math.exp(-2 * dt / tau)) > 0.05
    # steady state from the start: the first samples of independent runs
    first = np.array([TriadNoise(spec, dt, np.random.default_rng(s)).sample(0.0, 0.0, 0.0) for s in range(1500)])
    assert first.std() / sigma_ss == pytest.approx(1.0, abs=N_SIGMA / math.sqrt(2 * first.size))


# ---- turn-on bias and scale factor ----------------------------------------------------------

@pytest.mark.parametrize("spec", [MPU6050_GYRO, replace(MPU6050_ACCEL, turn_on_bias=0.05, scale_factor_error=0.02)],
                         ids=["gyro-default", "accel-custom"])
def test_turn_on_bias_and_scale_factor_are_drawn_per_run_and_constant_within_it(spec):
    """No white noise, no walk, 32-bit ADC: reading 0 gives the turn-on bias b, reading x gives
    (1 + s) x + b. Over 2000 seeds × 3 axes the sample standard deviations of b and s are the
    spec's within 5 standard errors (4.6 %) and their means 0; within a run 20 repeated readings
    are identical. Measured: b 0.998, s 0.994 of the spec (both specs: the same seeds)."""
    custom = _ideal(spec, noise_density=0.0, bias_random_walk=0.0, turn_on_bias=spec.turn_on_bias,
                    scale_factor_error=spec.scale_factor_error)
    x = 100.0
    b, s = [], []
    for seed in range(2000):
        noise = TriadNoise(custom, T, np.random.default_rng(seed))
        b0 = noise.sample(0.0, 0.0, 0.0)
        y0 = noise.sample(x, x, x)
        if seed < 20:
            assert all(noise.sample(0.0, 0.0, 0.0) == b0 for _ in range(20))
            assert all(noise.sample(x, x, x) == y0 for _ in range(20))
            assert noise.bias == pytest.approx(b0, abs=1e-6)
        b.append(b0)
        s.append([(v - c) / x - 1.0 for v, c in zip(y0, b0)])
    b, s = np.array(b), np.array(s)
    tol = N_SIGMA / math.sqrt(2 * b.size)
    assert b.std() / spec.turn_on_bias == pytest.approx(1.0, abs=tol)
    assert s.std() / spec.scale_factor_error == pytest.approx(1.0, abs=tol)
    assert abs(b.mean()) < N_SIGMA * spec.turn_on_bias / math.sqrt(b.size)
    assert abs(s.mean()) < N_SIGMA * spec.scale_factor_error / math.sqrt(s.size)
    # independent axes and independent b and s
    assert abs(np.corrcoef(b[:, 0], b[:, 1])[0, 1]) < N_SIGMA / math.sqrt(len(b))
    assert abs(np.corrcoef(b.ravel(), s.ravel())[0, 1]) < N_SIGMA / math.sqrt(b.size)


def test_suite_reports_the_drawn_constants():
    """``SensorSuite.truth()`` holds the scale factors and turn-on biases that the readings show
    (noise-free IMU with the default bias and scale spreads, no latency)."""
    gyro = _ideal(MPU6050_GYRO, noise_density=0.0, bias_random_walk=0.0, turn_on_bias=MPU6050_GYRO.turn_on_bias,
                  scale_factor_error=MPU6050_GYRO.scale_factor_error)
    accel = _ideal(MPU6050_ACCEL, noise_density=0.0, bias_random_walk=0.0, turn_on_bias=0.05,
                   scale_factor_error=MPU6050_ACCEL.scale_factor_error)
    suite = SensorSuite(SensorConfig(imu=ImuSpec(gyro=gyro, accel=accel, latency=0.0)), RATE,
                        np.random.default_rng(3))
    truth = suite.truth()
    suite.start(REST_G, REST_A, 0.0, 0.0)
    x = 7.0
    m0 = suite.read(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, 0.0)
    m1 = suite.read(1, (x, x, x), (x, x, x), 0.0, 0.0)
    for name in ("gyro", "accel"):
        scale, bias = truth[f"{name}_scale"], truth[f"{name}_turn_on_bias"]
        assert len(set(scale)) == 3 and len(set(bias)) == 3
        y0, y1 = getattr(m0, name), getattr(m1, name)
        assert y0 == pytest.approx(bias, abs=1e-6)
        assert [(a - c) / x - 1 for a, c in zip(y1, y0)] == pytest.approx(scale, abs=1e-6)
    assert SensorSuite(SensorConfig(), RATE, np.random.default_rng(3)).truth()["accel_turn_on_bias"] == (0.0,) * 3
    assert all(0.0 <= p < 1.0 for p in truth["encoder_phase"])


# ---- encoders -----------------------------------------------------------------------------

@pytest.mark.parametrize("cpr", [1200, 48, 4096])
def test_encoder_counts_are_floor_of_angle_times_cpr_plus_phase(cpr):
    """counts = ⌊(q − q0)·CPR/2π + phase⌋: checked at 5000 random angles, and on both sides of
    the boundaries q0 + (n − phase)·2π/CPR of 800 counts n (1e-9 rad either side: ≥ 1000 ulps),
    so the edges lie exactly where the formula puts them, including the first edges (n = 0, 1);
    one revolution is exactly CPR counts. ``read`` reports counts × 2π/CPR."""
    config = SensorConfig(encoders=EncoderSpec(counts_per_rev=cpr))
    for seed in range(3):
        rng = np.random.default_rng(100 + seed)
        suite = SensorSuite(config, RATE, np.random.default_rng(seed))
        q0 = rng.uniform(-5, 5, 2)
        suite.start((0.0, 0.0, 0.0), (0.0, 0.0, G), q0[0], q0[1])
        phase = np.array(suite.encoder_phase)
        assert np.all((0.0 <= phase) & (phase < 1.0))
        c = cpr / (2 * np.pi)
        q = q0 + rng.uniform(-30, 30, (5000, 2))
        expected = np.floor((q - q0) * c + phase).astype(int)
        got = np.array([suite.encoder_counts(a, b) for a, b in q])
        assert np.array_equal(got, expected)
        assert suite.encoder_counts(*q0) == (0, 0)
        ns = np.concatenate([np.arange(-3, 4), rng.integers(-5 * cpr, 5 * cpr, 793)])
        for n in ns:
            qb = q0 + (n - phase) / c
            assert suite.encoder_counts(*(qb + 1e-9)) == (n, n)
            assert suite.encoder_counts(*(qb - 1e-9)) == (n - 1, n - 1)
            lo = suite.encoder_counts(*(qb - 1e-9))
            hi = suite.encoder_counts(*(qb + 1e-9 + 2 * np.pi))
            assert hi[0] - lo[0] == cpr + 1 and hi[1] - lo[1] == cpr + 1
        # readings are counts × resolution
        res = 2 * np.pi / cpr
        for k, (a, b) in enumerate(q[:200]):
            meas = suite.read(k, (0.0, 0.0, 0.0), (0.0, 0.0, G), a, b)
            counts = suite.encoder_counts(a, b)
            assert meas.encoders == (pytest.approx(counts[0] * res, rel=1e-12, abs=1e-15),
                                     pytest.approx(counts[1] * res, rel=1e-12, abs=1e-15))
            assert [round(v / res) for v in meas.encoders] == list(counts)


def test_encoder_phase_is_uniform_across_runs():
    """The first edge lies a uniform fraction of a count away: the phases of 2000 runs have mean 1/2
    and variance 1/12 within 5 standard errors, and the two wheels' phases are independent."""
    ph = np.array([SensorSuite(SensorConfig(), RATE, np.random.default_rng(s)).encoder_phase for s in range(2000)])
    assert abs(ph.mean() - 0.5) < N_SIGMA * math.sqrt(1 / 12 / ph.size)
    assert ph.var() == pytest.approx(1 / 12, abs=N_SIGMA * math.sqrt(1 / 180 / ph.size))
    assert abs(np.corrcoef(ph[:, 0], ph[:, 1])[0, 1]) < N_SIGMA / math.sqrt(len(ph))


# ---- the IMU's true readings --------------------------------------------------------------

def _quat_y(theta: float):
    return (0.0, math.sin(theta / 2), 0.0, math.cos(theta / 2))


def _matrix(q) -> np.ndarray:
    return np.array(pybullet.getMatrixFromQuaternion(q)).reshape(3, 3)


@pytest.mark.parametrize("theta", [-0.3, 0.0, 0.25])
def test_accelerometer_at_rest_reads_gravity_in_the_body_frame(theta):
    """The twin at rest pitched θ: the true specific force is (−g sin θ, 0, g cos θ), the true rate
    0; through the default suite (noise, 1 % scale error, drift) the mean of 4000 readings is the
    truth scaled by the drawn (1 + s), within 5 standard errors of white noise and drift
    (0.0046 m/s²; a 1 % scale error at θ = 0.25 is 0.024). Measured deviations ≤ 1.02 standard
    errors. The twin held by a fixed constraint: between control instants the true readings stay
    at gravity (after the constraint settles, within 1e-4 m/s²; 3e-3 in its first period)."""
    with BulletTwin(TwinConfig(motor=None), theta0=theta) as twin:
        g = twin.params.g
        pose, vel = twin.kinematics
        assert vel == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        com = twin._com_local
        imu_pos = ImuSpec().position
        lever = tuple(a - b for a, b in zip(imu_pos, com))
        assert lever[2] != 0.0  # the IMU is not at the centre of mass: the lever arm is exercised below
        gyro, accel = imu_kinematics(pose, vel, pose, vel, T, lever, g)
        assert gyro == (0.0, 0.0, 0.0)
        assert accel == pytest.approx((-g * math.sin(theta), 0.0, g * math.cos(theta)), abs=1e-12)

        suite = SensorSuite(SensorConfig(), RATE, np.random.default_rng(round(100 * theta) + 50))
        suite.start(gyro, accel, 0.0, 0.0)
        n = 4000
        y = np.array([suite.read(k, gyro, accel, 0.0, 0.0).accel for k in range(n)])
        s = np.array(suite.truth()["accel_scale"])
        expected = (1.0 + s) * np.array(accel)
        spec = MPU6050_ACCEL
        se = math.sqrt(spec.white_sigma(T) ** 2 / n + spec.bias_random_walk ** 2 * n * T / 3)
        assert np.all(np.abs(y.mean(axis=0) - expected) < N_SIGMA * se), (y.mean(axis=0) - expected) / se
        # the sign convention, independently of the scale error: x reads −g sin θ
        if theta != 0.0:
            assert np.sign(y[:, 0].mean()) == -np.sign(theta)

        # hold the body where it is and step the physics
        cid = twin.client.createConstraint(twin.robot, -1, -1, -1, pybullet.JOINT_FIXED, (0, 0, 0), (0, 0, 0),
                                           pose[0], (0, 0, 0, 1), pose[1])
        twin.client.changeConstraint(cid, maxForce=1e5)
        prev = twin.kinematics
        for i in range(20):
            tr = twin.step(0.0, 0.0)
            gyro, accel = imu_kinematics(*twin.kinematics, *prev, T, lever, g)
            prev = twin.kinematics
            assert abs(tr.theta - theta) < 1e-4
            want = (-g * math.sin(tr.theta), 0.0, g * math.cos(tr.theta))
            assert accel == pytest.approx(want, abs=5e-3 if i < 5 else 1e-4)
            assert max(abs(v) for v in gyro) < (1e-3 if i < 5 else 1e-5)


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@pytest.mark.parametrize("dt", [0.005, 1e-6])
def test_imu_kinematics_of_a_body_pitching_about_the_axle(dt):
    """The body turns about the fixed axle (world point A, axis y) with θ(t) = θ0 + ω0 t + α t²/2;
    PyBullet's state is that of the centre of mass c (body frame, from the axle), the IMU at p.

    * gyro: the mean rate over the interval, (θ1 − θ0)/dt about y, exactly;
    * specific force: the mean acceleration of P over the interval plus g, in the body axes at
      the end: R1ᵀ [(v_P(t1) − v_P(t0))/dt + g ẑ] with v_P = θ̇ ŷ × R p (derived here, not
      through the centre of mass); for α = 0 the same in closed form,
      (ω/dt)(p_z(1 − cos ωdt) − p_x sin ωdt, 0, −p_x(1 − cos ωdt) − p_z sin ωdt) + g(−sin θ1, 0, cos θ1);
    * for a short interval, the instantaneous value with its tangential (α ŷ × p) and
      centripetal (−θ̇² p) terms: (α p_z − θ̇² p_x − g sin θ, 0, −α p_x − θ̇² p_z + g cos θ),
      within 1e-3 m/s² for dt = 1 µs (the terms are 2–30 m/s²; the mean over the interval differs
      from the value at its end by about |ω| |a| dt/2, 1.2e-3 m/s² already at dt = 10 µs).
    """
    g = 9.81
    A = np.array([0.3, -0.2, 0.05])
    c = np.array([0.01, 0.0, 0.06])
    p = np.array([0.02, 0.01, 0.11])
    lever = tuple(p - c)
    th0, w0 = 0.15, 5.0
    y_hat = np.array([0.0, 1.0, 0.0])

    def state(t, alpha):
        th, w = th0 + w0 * t + 0.5 * alpha * t * t, w0 + alpha * t
        R = _rot_y(th)
        assert np.allclose(R, _matrix(_quat_y(th)))
        com = A + R @ c
        v_com = np.cross(w * y_hat, R @ c)
        return th, w, R, ((tuple(com), _quat_y(th)), (tuple(v_com), (0.0, w, 0.0)))

    for alpha in (0.0, 20.0, -35.0):
        t1 = 0.4
        th_a, w_a, R_a, (pose_a, vel_a) = state(t1 - dt, alpha)
        th_b, w_b, R_b, (pose_b, vel_b) = state(t1, alpha)
        gyro, f = imu_kinematics(pose_b, vel_b, pose_a, vel_a, dt, lever, g)
        assert gyro == pytest.approx((0.0, (th_b - th_a) / dt, 0.0), rel=1e-9, abs=1e-9)
        v_p = lambda w, R: np.cross(w * y_hat, R @ p)  # noqa: E731
        mean_world = (v_p(w_b, R_b) - v_p(w_a, R_a)) / dt + np.array([0.0, 0.0, g])
        assert f == pytest.approx(tuple(R_b.T @ mean_world), rel=1e-9, abs=1e-9)
        if alpha == 0.0:
            wd = w0 * dt
            closed = ((w0 / dt) * (p[2] * (1 - math.cos(wd)) - p[0] * math.sin(wd)) - g * math.sin(th_b), 0.0,
                      (w0 / dt) * (-p[0] * (1 - math.cos(wd)) - p[2] * math.sin(wd)) + g * math.cos(th_b))
            assert f == pytest.approx(closed, rel=1e-9, abs=1e-9)
        if dt < 1e-5:
            inst = (alpha * p[2] - w_b ** 2 * p[0] - g * math.sin(th_b), 0.0,
                    -alpha * p[0] - w_b ** 2 * p[2] + g * math.cos(th_b))
            assert f == pytest.approx(inst, abs=1e-3)
            centripetal, tangential = w_b ** 2 * p[2], abs(alpha) * p[2]
            assert centripetal > 2.0 and (alpha == 0.0 or tangential > 2.0)


def _axis_angle(v) -> np.ndarray:
    """Rotation matrix of the rotation vector ``v`` (Rodrigues)."""
    v = np.asarray(v, dtype=float)
    a = np.linalg.norm(v)
    if a == 0.0:
        return np.eye(3)
    k = v / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def _quat_axis_angle(v):
    v = np.asarray(v, dtype=float)
    a = np.linalg.norm(v)
    k = v / a if a > 0 else v
    return (*(math.sin(a / 2) * k), math.cos(a / 2))


def _qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


@pytest.mark.parametrize("dt", [0.005, 0.02, 1e-5])
def test_imu_kinematics_of_a_constant_body_rate_about_the_centre_of_mass(dt):
    """An arbitrary orientation turning at a constant body-frame rate ω_b about a fixed centre of
    mass (PyBullet's angular velocity is world-frame: R ω_b): the gyro reads ω_b exactly (a
    world-frame rate would not), and the specific force at lever l is
    (I − Rot(−ω_b dt))(ω_b × l)/dt + R1ᵀ g ẑ → ω_b × (ω_b × l) + R1ᵀ g ẑ for small dt."""
    g = 9.81
    q0 = _quat_axis_angle((0.4, -0.9, 1.7))
    R0 = _matrix(q0)
    w_b = np.array([1.5, -3.0, 2.0])
    lever = np.array([0.03, -0.02, 0.08])
    com = (0.1, 0.2, 0.3)
    for t0 in (0.0, 0.37):
        def state(t):
            q = _qmul(q0, _quat_axis_angle(w_b * t)) if t > 0 else q0
            R = R0 @ _axis_angle(w_b * t)
            assert np.allclose(R, _matrix(q), atol=1e-12)
            return R, ((com, q), ((0.0, 0.0, 0.0), tuple(R @ w_b)))

        Ra, (pose_a, vel_a) = state(t0)
        Rb, (pose_b, vel_b) = state(t0 + dt)
        gyro, f = imu_kinematics(pose_b, vel_b, pose_a, vel_a, dt, tuple(lever), g)
        assert gyro == pytest.approx(tuple(w_b), rel=1e-7)
        world_gyro = Rb @ w_b
        assert not np.allclose(gyro, world_gyro, rtol=1e-2)
        grav = Rb.T @ np.array([0.0, 0.0, g])
        exact = (np.eye(3) - _axis_angle(-w_b * dt)) @ np.cross(w_b, lever) / dt + grav
        assert f == pytest.approx(tuple(exact), rel=1e-7, abs=1e-9)
        if dt < 1e-4:
            assert f == pytest.approx(tuple(np.cross(w_b, np.cross(w_b, lever)) + grav), abs=1e-3)


def test_imu_kinematics_of_a_translation_with_constant_acceleration():
    """Fixed attitude (pitch 0.2, heading 0.7), centre of mass accelerating at a: f = Rᵀ (a + g ẑ)
    for any dt and lever; the gyro reads 0."""
    g = 9.81
    q = _qmul(_quat_axis_angle((0.0, 0.0, 0.7)), _quat_y(0.2))
    R = _matrix(q)
    a = np.array([1.2, -0.7, 0.4])
    v0 = np.array([0.3, 0.1, 0.0])
    for dt in (0.005, 0.01):
        t1 = 0.8
        vel_a = (tuple(v0 + a * (t1 - dt)), (0.0, 0.0, 0.0))
        vel_b = (tuple(v0 + a * t1), (0.0, 0.0, 0.0))
        gyro, f = imu_kinematics(((0, 0, 0), q), vel_b, ((0, 0, 0), q), vel_a, dt, (0.05, 0.0, 0.04), g)
        assert gyro == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
        assert f == pytest.approx(tuple(R.T @ (a + np.array([0.0, 0.0, g]))), rel=1e-9)
        # forward acceleration of a level robot reads +x (body x forward)
    q_level = (0.0, 0.0, 0.0, 1.0)
    _, f = imu_kinematics(((0, 0, 0), q_level), ((1.0, 0, 0), (0, 0, 0)), ((0, 0, 0), q_level),
                          ((0.0, 0, 0), (0, 0, 0)), 0.5, (0, 0, 0), g)
    assert f == pytest.approx((2.0, 0.0, g))


# ---- faults and latency ---------------------------------------------------------------------

def _ident_config(faults=(), imu_latency=0.005, enc_latency=0.0, imu_rate=RATE) -> SensorConfig:
    """Noise-free sensors, so every reading names the step whose sample it is."""
    imu = ImuSpec(gyro=_noiseless(MPU6050_GYRO), accel=_noiseless(MPU6050_ACCEL), rate=imu_rate,
                  latency=imu_latency)
    return SensorConfig(imu=imu, encoders=EncoderSpec(latency=enc_latency), faults=tuple(faults))


def _ident_run(config: SensorConfig, n: int, seed: int = 0):
    """Step k feeds gyro x = 1 + 0.01 k, accel x = 2 + 0.01 k and wheel angles of 10 (k + 1) counts;
    returns, per step, the sample index each sensor delivered (None: nothing; −1: the rest state
    from before t = 0), and the suite."""
    suite = SensorSuite(config, RATE, np.random.default_rng(seed))
    suite.start(REST_G, REST_A, 0.0, 0.0)
    res = 2 * math.pi / config.encoders.counts_per_rev
    out = []
    for k in range(n):
        q = 10 * (k + 1) * res + 1e-3 * res
        m = suite.read(k, (1.0 + 0.01 * k, 0.0, 0.0), (2.0 + 0.01 * k, 0.0, G), q, q)

        def idx(v, offset):
            if v is None:
                return None
            if v[0] == 0.0:
                return -1
            j = (v[0] - offset) / 0.01
            assert abs(j - round(j)) < 1e-4
            return round(j)

        enc = None if m.encoders is None else round(m.encoders[0] / res / 10) - 1
        out.append((idx(m.gyro, 1.0), idx(m.accel, 2.0), enc))
    return out, suite


def test_latency_delivers_each_sample_at_its_step():
    """IMU 15 ms late (3 steps), encoders 10 ms (2 steps): at step k the sample of step k − 3 (k − 2)
    arrives; before that the rest state. With the IMU at 100 Hz and 5 ms latency, samples of the even
    steps arrive at the odd ones and nothing arrives at the even ones."""
    out, suite = _ident_run(_ident_config(imu_latency=0.015, enc_latency=0.01), 60)
    for k, (g, a, e) in enumerate(out):
        assert g == a == (k - 3 if k >= 3 else -1)
        assert e == (k - 2 if k >= 2 else -1)
    assert suite.fault_counts()["gyro"] == dict(produced=63, dropped=0, stuck=0, spiked=0, superseded=0)
    out, _ = _ident_run(_ident_config(imu_rate=100.0), 40)
    for k, (g, a, e) in enumerate(out):
        assert g == a == (k - 1 if k % 2 == 1 else None)
        assert e == k
    out, _ = _ident_run(_ident_config(imu_rate=100.0, imu_latency=0.01), 40)
    for k, (g, a, e) in enumerate(out):
        assert g == (None if k % 2 else (k - 2 if k >= 2 else -1))


def test_dropout_removes_samples_in_its_window_only():
    """Dropout of the IMU over [0.1, 0.15) s: the samples of steps 20–29 never arrive (steps 21–30 read
    None for gyro and accelerometer), every other step delivers its sample; encoders untouched."""
    out, suite = _ident_run(_ident_config([Dropout("imu", start=0.1, duration=0.05)]), 60)
    for k, (g, a, e) in enumerate(out):
        want = None if 21 <= k <= 30 else (k - 1 if k >= 1 else -1)
        assert g == a == want, k
        assert e == k
    counts = suite.fault_counts()
    assert counts["gyro"]["dropped"] == counts["accel"]["dropped"] == 10
    assert counts["encoders"]["dropped"] == 0
    out, suite = _ident_run(_ident_config([Dropout("encoders", start=0.02, duration=0.01)]), 10)
    assert [e for _, _, e in out] == [0, 1, 2, 3, None, None, 6, 7, 8, 9]
    assert [g for g, _, _ in out] == [-1, 0, 1, 2, 3, 4, 5, 6, 7, 8]


def test_stuck_repeats_the_last_good_sample():
    """Stuck gyro over [0.1, 0.15) s: the samples of steps 20–29 are replaced by that of step 19; from
    step 30 the output moves again. The accelerometer is untouched. Stuck after a dropout repeats the
    last sample that got through."""
    out, suite = _ident_run(_ident_config([Stuck("gyro", start=0.1, duration=0.05)]), 60)
    for k, (g, a, e) in enumerate(out):
        want = k - 1 if k >= 1 else -1
        assert a == want
        assert g == (19 if 21 <= k <= 30 else want), k
    assert suite.fault_counts()["gyro"]["stuck"] == 10 and suite.fault_counts()["accel"]["stuck"] == 0
    out, _ = _ident_run(_ident_config([Dropout("gyro", start=0.05, duration=0.05),
                                       Stuck("gyro", start=0.1, duration=0.025)]), 40)
    gy = [g for g, _, _ in out]
    assert gy[10] == 9 and gy[11:21] == [None] * 10 and gy[21:26] == [9] * 5 and gy[26] == 25


def test_latency_change_applies_from_its_time():
    """The gyro's latency goes from 1 to 4 steps at t = 0.5 s: samples before step 100 arrive one
    step late, from step 100 on four steps late, so steps 101–103 get nothing new. Going down to 0
    at 0.5 s, samples 99 and 100 both arrive at step 100: the newest is delivered, one superseded."""
    out, suite = _ident_run(_ident_config([LatencyChange("gyro", time=0.5, latency=0.02)]), 150)
    for k, (g, a, e) in enumerate(out):
        assert a == (k - 1 if k >= 1 else -1)
        if k <= 100:
            assert g == (k - 1 if k >= 1 else -1), k
        elif k <= 103:
            assert g is None, k
        else:
            assert g == k - 4, k
    out, suite = _ident_run(_ident_config([LatencyChange("gyro", time=0.5, latency=0.0)]), 150)
    gy = [g for g, _, _ in out]
    assert gy[99] == 98 and gy[100] == 100 and gy[101:] == list(range(101, 150))
    assert suite.fault_counts()["gyro"]["superseded"] == 1
    out, _ = _ident_run(_ident_config([LatencyChange("encoders", time=0.1, latency=0.015)]), 40)
    en = [e for _, _, e in out]
    assert en[:20] == list(range(20)) and en[20:23] == [None] * 3 and en[23:] == list(range(20, 37))


def _run(config: SensorConfig, seed: int, n: int = 1500):
    """``n`` steps of the suite at rest (wheels turning); 1500 samples span three of the noise's
    512-sample blocks of normal draws, so that a fault drawing from a noise stream would show."""
    suite = SensorSuite(config, RATE, np.random.default_rng(np.random.SeedSequence(seed)))
    suite.start(REST_G, REST_A, 0.0, 0.0)
    return [suite.read(k, REST_G, REST_A, 0.01 * k, -0.02 * k) for k in range(n)], suite


def test_spikes_are_outliers_of_the_given_magnitude_and_are_counted():
    """Gyro spikes at 100 /s (probability 0.5 per 5 ms sample) over [0.5, 4.5) s, magnitude 1 rad/s:
    against the same seed without the fault, spiked readings differ by exactly ±1 on every axis
    (both signs occur), the others not at all; their number is ``fault_counts()["gyro"]["spiked"]``
    and is 400 ± 5σ (measured 369). With magnitude 30 (beyond ±250 °/s) the outliers read exactly
    the full-scale codes. Encoders spiked at every step by ±0.3 rad as whole counts (±57), unclipped."""
    clean, _ = _run(SensorConfig(), 11)
    faulty, suite = _run(SensorConfig(faults=(Spikes("gyro", start=0.5, duration=4.0, rate=100.0, magnitude=1.0),)),
                         11)
    spiked = 0
    signs = set()
    for k, (c, f) in enumerate(zip(clean, faulty)):
        d = np.subtract(f.gyro, c.gyro)
        assert f.accel == c.accel and f.encoders == c.encoders
        if np.any(d != 0):
            assert 101 <= k <= 900  # samples of [0.5, 4.5) s arrive one step late
            assert np.allclose(np.abs(d), 1.0, atol=1e-12)
            signs.update(np.sign(d))
            spiked += 1
    counts = suite.fault_counts()["gyro"]
    assert counts["spiked"] == spiked
    assert abs(spiked - 400) < N_SIGMA * math.sqrt(800 * 0.5 * 0.5)  # 800 samples in the window, p = 0.5
    assert signs == {-1.0, 1.0}

    lsb = MPU6050_GYRO.lsb
    faulty, suite = _run(SensorConfig(faults=(Spikes("imu", rate=1e4, magnitude=30.0),)), 11, 50)
    for f in faulty[1:]:  # step 0 delivers the rest sample taken before t = 0, outside the window
        assert set(f.gyro) <= {32767 * lsb, -32768 * lsb}
        assert set(f.accel) <= {32767 * MPU6050_ACCEL.lsb, -32768 * MPU6050_ACCEL.lsb}
    assert suite.fault_counts()["gyro"]["spiked"] == 50 and suite.fault_counts()["accel"]["spiked"] == 50

    faulty, suite = _run(SensorConfig(faults=(Spikes("encoders", rate=1e4, magnitude=0.3),)), 11, 50)
    res = 2.0 * math.pi / 1200
    for c, f in zip(clean, faulty):  # an encoder's glitch is whole counts: 0.3 rad is 57 counts (0.29845 rad)
        assert np.allclose(np.abs(np.subtract(f.encoders, c.encoders)), 57 * res, atol=1e-12)
        assert np.allclose(np.round(np.divide(f.encoders, res)), np.divide(f.encoders, res), atol=1e-9)
        assert f.gyro == c.gyro
    assert suite.fault_counts()["encoders"]["spiked"] == 50


def test_same_seed_same_streams_and_faults_do_not_change_the_noise():
    """Bit-identical streams for the same seed (with faults); another seed differs; adding spikes on the
    encoders (or a dropout of the accelerometer) leaves the gyro and accelerometer noise untouched."""
    faults = (Spikes("all", rate=20.0, magnitude=0.5), Dropout("gyro", start=0.3, duration=0.1),
              Stuck("accel", start=0.6, duration=0.1))
    a, sa = _run(SensorConfig(faults=faults), 5)
    b, sb = _run(SensorConfig(faults=faults), 5)
    assert a == b and sa.fault_counts() == sb.fault_counts() and sa.truth() == sb.truth()
    c, _ = _run(SensorConfig(faults=faults), 6)
    assert [m.gyro for m in a if m.gyro] != [m.gyro for m in c if m.gyro]

    base, _ = _run(SensorConfig(), 5)
    enc, se = _run(SensorConfig(faults=(Spikes("encoders", rate=50.0, magnitude=0.2),)), 5)
    assert se.fault_counts()["encoders"]["spiked"] > 0
    assert [m.gyro for m in enc] == [m.gyro for m in base]
    assert [m.accel for m in enc] == [m.accel for m in base]
    assert [m.encoders for m in enc] != [m.encoders for m in base]
    drop, _ = _run(SensorConfig(faults=(Dropout("accel", start=0.1, duration=0.5),)), 5)
    assert [m.gyro for m in drop] == [m.gyro for m in base]
    spiky, sg = _run(SensorConfig(faults=(Spikes("gyro", rate=50.0, magnitude=0.2),)), 5)
    assert sg.fault_counts()["gyro"]["spiked"] > 100
    assert [m.accel for m in spiky] == [m.accel for m in base]
    assert [m.encoders for m in spiky] == [m.encoders for m in base]


# ---- validation -------------------------------------------------------------------------------

def _triad(**kw):
    return replace(MPU6050_GYRO, **kw)


def _suite(**kw):
    return SensorSuite(SensorConfig(**kw), RATE, np.random.default_rng(0))


@pytest.mark.parametrize("make, match", [
    (lambda: _triad(noise_density=-1e-4), "noise_density"),
    (lambda: _triad(noise_density=math.nan), "noise_density"),
    (lambda: _triad(bias_random_walk=-1.0), "bias_random_walk"),
    (lambda: _triad(turn_on_bias=-0.1), "turn_on_bias"),
    (lambda: _triad(scale_factor_error=0.6), "scale_factor_error"),
    (lambda: _triad(bias_correlation_time=0.0), "bias_correlation_time"),
    (lambda: _triad(full_scale=0.0), "full_scale"),
    (lambda: _triad(bits=1), "bits"),
    (lambda: _triad(bits=33), "bits"),
    (lambda: _triad(bits=16.0), "bits"),
    (lambda: _triad(bits=True), "bits"),
    (lambda: ImuSpec(rate=0.0), "rate"),
    (lambda: ImuSpec(position=(0.0, 0.0, 2.0)), "position"),
    (lambda: ImuSpec(gyro="mpu"), "gyro"),
    (lambda: _suite(imu=ImuSpec(rate=150.0)), "IMU rate"),
    (lambda: _suite(imu=ImuSpec(rate=400.0)), "IMU rate"),
    (lambda: _suite(imu=ImuSpec(latency=0.007)), "IMU latency"),
    (lambda: _suite(encoders=EncoderSpec(latency=0.0025)), "encoder latency"),
    (lambda: EncoderSpec(counts_per_rev=3), "counts_per_rev"),
    (lambda: EncoderSpec(counts_per_rev=1200.0), "counts_per_rev"),
    (lambda: Dropout("lidar"), "sensor"),
    (lambda: Stuck("gyros"), "sensor"),
    (lambda: Spikes("camera"), "sensor"),
    (lambda: LatencyChange("sonar", 0.1, 0.01), "sensor"),
    (lambda: Spikes("gyro", magnitude=0.0), "magnitude"),
    (lambda: Spikes("gyro", magnitude=-1.0), "magnitude"),
    (lambda: Spikes("gyro", rate=0.0), "rate"),
    (lambda: Dropout("gyro", start=-1.0), "start"),
    (lambda: Stuck("gyro", duration=math.nan), "duration"),
    (lambda: LatencyChange("gyro", time=0.1, latency=2.0), "latency"),
    (lambda: _suite(faults=(LatencyChange("gyro", time=0.1, latency=0.0125),)), "LatencyChange latency"),
    (lambda: SensorConfig(faults=("dropout",)), "faults"),
    (lambda: SensorConfig(imu="mpu6050"), "imu"),
    (lambda: SensorSuite(SensorConfig(), RATE, 42), "rng"),
])
def test_invalid_specs_are_clear_errors(make, match):
    with pytest.raises(TwinError, match=match) as info:
        make()
    assert "\n" not in str(info.value)


def test_reading_before_start_is_an_error():
    with pytest.raises(TwinError, match="start"):
        _suite().read(0, REST_G, REST_A, 0.0, 0.0)


def test_datasheet_defaults():
    """The defaults are the MPU-6050 figures at FS_SEL = AFS_SEL = 0: ±250 °/s and ±2 g on 16 bits
    (131 and 16384 LSB per unit), 200 Hz, one 5 ms control period of latency; 1200 counts per rev."""
    assert 1.0 / (MPU6050_GYRO.lsb / DEG) == pytest.approx(131.072)
    assert 1.0 / (MPU6050_ACCEL.lsb / G0) == pytest.approx(16384.0)
    imu = ImuSpec()
    assert (imu.rate, imu.latency) == (200.0, 0.005)
    assert EncoderSpec().resolution == pytest.approx(2 * math.pi / 1200)
    assert SensorConfig().steps(RATE) == (1, 1, 0)
    assert SensorConfig(imu=ImuSpec(rate=50.0, latency=0.02)).steps(RATE) == (4, 4, 0)
