"""The state estimator (:mod:`estimation`): the strapdown EKF's Jacobians against finite
differences, its consistency over a Monte Carlo batch (NEES, NIS), its accuracy against the
two hobby baselines on the same readings, the closed loop on the twin with the EKF in it
(outliers included), robustness (dropouts, stuck sensors, latency changes, non-finite
readings and commands, the reset path, misuse), determinism, and :meth:`covariance6`.

Closed-loop checks run the PyBullet twin with the default sensors (MPU-6050-class IMU at
200 Hz, 1200-count encoders) and fixed seeds; the figures measured when the tests were
written are in each docstring, so every threshold's margin can be judged. The loop runs
the compiled kernel (``estimation._ekf``) where it is built; tests that reach into the
filter's internals use the pure-Python reference path (``compiled=False``), and tests of
behaviour run on both paths.
"""
import dataclasses
import math

import numpy as np
import pytest

from estimation import ekf, replay
from twin.registry import build_estimator_for as build_estimator
from estimation.consistency import filter_truth, monte_carlo
from estimation.ekf import BY, BZ, C0, H0, N, PS, SAX, SAZ, SY, SZ, TH, V, EKFEstimator
from estimation.model import EstimatorModel
from twin.controllers.cascade import build_cascade
from twin.experiments import Experiment
from twin.sim.bullet_loop import simulate_twin
from twin.errors import TwinError
from twin.params import NOMINAL
from twin.actuators.dc_motor import DEFAULT_MOTOR
from twin.plant.bullet import TwinConfig
from twin.sensors import Dropout, ImuSpec, LatencyChange, Measurement, SensorConfig, Spikes, Stuck
from twin.sensors.specs import MPU6050_ACCEL, MPU6050_GYRO

RATE = 200.0  # Hz, the default control rate
SENSORS = SensorConfig()
MOTOR = TwinConfig().motor
HAS_KERNEL = ekf._kernel is not None
# both implementations of the filter step, where a test runs the filter itself
PATHS = [pytest.param(False, id="python"),
         pytest.param(True, id="compiled", marks=pytest.mark.skipif(not HAS_KERNEL, reason="EKF kernel not built"))]
BASELINES = ("complementary", "kalman2")


def _experiment(theta0: float, duration: float) -> Experiment:
    return Experiment("estimator", f"balance from θ0 = {theta0} rad", theta0=theta0, duration=duration)


@pytest.fixture(scope="module")
def twin_run(design):
    """``twin_run(theta0, duration, seed, faults=(), sensors=True)``: a closed-loop run with the EKF
    (``log_filter``), cached for the module; ``sensors=False`` gives ideal sensing."""
    cache = {}

    def get(theta0, duration, seed, faults=(), sensors=True):
        key = (theta0, duration, seed, tuple(faults), sensors)
        if key not in cache:
            e = _experiment(theta0, duration)
            cfg = SensorConfig(faults=tuple(faults)) if sensors else None
            cache[key] = simulate_twin(build_cascade("it2", design, e.targets), e, sensors=cfg, seed=seed, log_filter=True)
        return cache[key]

    return get


def _ekf(sensors: SensorConfig = SENSORS, compiled=None) -> EKFEstimator:
    """An EKF as the twin builds it (``build_estimator``), with the implementation chosen."""
    model = EstimatorModel(NOMINAL, MOTOR, sensors.imu, sensors.encoders, RATE)
    return EKFEstimator(model, *sensors.steps(RATE), compiled=compiled)


def _replay(run, est, measurements=None) -> np.ndarray:
    return replay(est, run, measurements)


def _baseline_theta_rmse(run, kind: str) -> float:
    """θ RMSE of a baseline estimator run offline on the run's readings and commands."""
    f = build_estimator(kind, run.sensor_config, RATE, run.config.motor, NOMINAL)
    est = _replay(run, f)
    return float(np.sqrt(np.mean((est[:, 0] - run.signal("theta")) ** 2)))


def _theta_error(run) -> np.ndarray:
    return run.signal("theta_est") - run.signal("theta")


def _window(run, a: float, b: float) -> np.ndarray:
    return (run.t >= a - 1e-9) & (run.t < b - 1e-9)


# ---- 1. the prediction's Jacobians --------------------------------------------------------

JACOBIAN_SENSORS = {
    "default-imu": SENSORS,
    # an IMU off the centre line (x_i ≠ 0) at 100 Hz: the dx, dz terms and Δt = 10 ms
    "off-centre-100Hz": SensorConfig(imu=ImuSpec(position=(0.03, 0.0, 0.12), rate=100.0)),
}
# variances (ω_y, ω_z, f_x, f_z) that a synthetic (model) sample adds, as StrapdownFilter.synthetic gives them
EXTRA = (3e-4, 2e-3, 0.05, 0.02)
CONSTANT_STATES = (C0, SY, H0, SZ, SAX, SAZ)


def _random_case(rng):
    """A state with every component nonzero (tilted ±0.1–0.5 rad, scale factors of a few %) and an
    IMU sample with a yaw rate of 0.5–4 rad/s, so that every term of the prediction matters."""
    sign = rng.choice([-1.0, 1.0], size=3)
    x = np.array([sign[0] * rng.uniform(0.1, 0.5), rng.uniform(-20.0, 20.0), rng.uniform(-1.5, 1.5),
                  rng.uniform(-3.0, 3.0), rng.normal(0.0, 0.02), rng.normal(0.0, 0.02), rng.uniform(-0.5, 0.5),
                  rng.normal(0.0, 0.03), rng.uniform(-0.1, 0.1), rng.normal(0.0, 0.03), rng.normal(0.0, 0.03),
                  rng.normal(0.0, 0.03)])
    sample = np.array([rng.uniform(-3.0, 3.0), sign[1] * rng.uniform(0.5, 4.0), rng.uniform(-5.0, 5.0),
                       9.81 + rng.uniform(-3.0, 3.0)])
    return x, sample


def _central(fun, z, h=1e-5):
    """Central-difference Jacobian of ``fun`` at ``z`` (steps h·max(1, |z_j|))."""
    cols = []
    for j in range(len(z)):
        hj = h * max(1.0, abs(z[j]))
        zp, zm = z.copy(), z.copy()
        zp[j] += hj
        zm[j] -= hj
        cols.append((fun(zp) - fun(zm)) / (2.0 * hj))
    return np.column_stack(cols)


def _jacobian_cases():
    rng = np.random.default_rng(2024)
    return [_random_case(rng) for _ in range(6)]


@pytest.mark.parametrize("extra", [None, EXTRA], ids=["real-sample", "synthetic-sample"])
@pytest.mark.parametrize("imu", list(JACOBIAN_SENSORS), ids=list(JACOBIAN_SENSORS))
def test_prediction_jacobian_equals_finite_differences(imu, extra):
    """F of ``StrapdownFilter.propagate`` against central differences of x⁺ over the state (h = 1e-5 relative),
    at six seeded random states and samples: |F − F_fd| ≤ 2e-9 + 1e-6 |F_fd| entrywise.

    Measured: the largest difference is 1.4e-10 (central differences' own error); the smallest
    nonzero entries of F − I are ~1e-7, so a missing or sign-flipped term fails by a factor ≥ 50.
    The prediction x⁺ does not depend on the sample's extra variance (exactly).
    """
    est = _ekf(JACOBIAN_SENSORS[imu], compiled=False)
    for x, s in _jacobian_cases():
        sample = (tuple(s), extra)
        x1, F, _, w = est.filter.propagate(x, sample)
        assert w == (s[0], s[1])
        assert np.array_equal(x1, est.filter.propagate(x, (tuple(s), None))[0])
        F_fd = _central(lambda z: est.filter.propagate(z, sample)[0], x)
        bad = np.abs(F - F_fd) > 2e-9 + 1e-6 * np.abs(F_fd)
        assert not bad.any(), [(int(i), int(j), F[i, j], F_fd[i, j]) for i, j in zip(*np.nonzero(bad))]


@pytest.mark.parametrize("extra", [None, EXTRA], ids=["real-sample", "synthetic-sample"])
@pytest.mark.parametrize("imu", list(JACOBIAN_SENSORS), ids=list(JACOBIAN_SENSORS))
def test_process_noise_equals_finite_difference_noise_map(imu, extra):
    """Q of ``StrapdownFilter.propagate`` = L_fd diag(var) L_fdᵀ + the gyro-bias random walk on b_y, b_z, with L_fd
    = ∂x⁺/∂(ω_y, ω_z, f_x, f_z) by central differences and var = (gyro, gyro, accel, accel)
    per-sample variances (+ ``extra`` for a synthetic sample), and ψ's share of the trapezoid's
    error (Δt |v⁺ − v| / r)² / 12 (issue 29: the acceleration's course within the period is unknown).

    Compared entrywise normalised by √(Q_ii Q_jj) of the reference: ≤ 1e-5 (measured ≤ 2.2e-7);
    the rows of the constant states (encoder zeros, scale factors) are exactly zero, and b_y, b_z
    get exactly the random walk K² Δt. A term missing from L, a wrong variance (e.g. the gyro's for
    the accelerometer) or a missing random walk changes a normalised entry by 1e-3 or more.
    """
    sensors = JACOBIAN_SENSORS[imu]
    est = _ekf(sensors, compiled=False)
    dt = 1.0 / sensors.imu.rate
    g, a = sensors.imu.gyro, sensors.imu.accel
    var = np.array([g.white_sigma(dt) ** 2 + g.lsb ** 2 / 12.0] * 2 + [a.white_sigma(dt) ** 2 + a.lsb ** 2 / 12.0] * 2)
    if extra is not None:
        var = var + np.array(extra)
    walk = g.bias_random_walk ** 2 * dt
    for x, s in _jacobian_cases():
        x1, _, Q, _ = est.filter.propagate(x, (tuple(s), extra))
        L_fd = _central(lambda z: est.filter.propagate(x, (tuple(z), extra))[0], s)
        Q_fd = (L_fd * var) @ L_fd.T
        Q_fd[BY, BY] += walk
        Q_fd[BZ, BZ] += walk
        Q_fd[PS, PS] += (dt * (x1[V] - x[V]) / est.r) ** 2 / 12.0
        assert Q[BY, BY] == pytest.approx(walk, rel=1e-12) and Q[BZ, BZ] == pytest.approx(walk, rel=1e-12)
        const = list(CONSTANT_STATES)
        assert not Q[const].any() and not Q[:, const].any()
        live = [i for i in range(N) if i not in CONSTANT_STATES]
        d = np.sqrt(np.diag(Q_fd)[live])
        assert (d > 0).all()
        norm = np.abs(Q[np.ix_(live, live)] - Q_fd[np.ix_(live, live)]) / np.outer(d, d)
        assert norm.max() <= 1e-5, norm.max()


# ---- 2. consistency over a Monte Carlo batch ----------------------------------------------

MC_SEEDS = range(20)
MC_START = 0.5  # s: the first half second holds the start-up transient of the encoder zeros


@pytest.fixture(scope="module")
def mc_runs(design):
    """20 runs from θ0 = 0.05 rad, 3 s, seeds 0–19, default sensors, filter logged."""
    e = _experiment(0.05, 3.0)
    ctrl = build_cascade("it2", design, e.targets)
    return [simulate_twin(ctrl, e, sensors=SENSORS, seed=s, log_filter=True) for s in MC_SEEDS]


def _consistency(runs):
    """(monte_carlo result, NIS tolerance, [NEES test, NIS test, NIS level test] passed).

    NEES: the batch's mean NEES (each run's averaged over its rows) inside the 95 % χ² bounds
    of a 20-run average, and the state dimension inside the 95 % Student-t interval of the
    per-run averages (see :func:`estimation.consistency.monte_carlo` for why not the fraction
    of rows inside the bounds). NIS per degree of freedom: over D degrees of freedom (the
    summed ``nis_dof`` of the rows considered) a consistent filter's mean NIS per dof has
    standard error √(2/D) (χ²_D / D); the tolerance is 5 standard errors. The encoders' noise
    is uniform, not Gaussian, which makes the true spread smaller, so the bound is conservative.
    """
    m = monte_carlo(runs, start=MC_START)
    dof = sum(int(r.filter_log["nis_dof"][r.t >= MC_START - 1e-9].sum()) for r in runs)
    tol = 5.0 * math.sqrt(2.0 / dof)
    (lo, hi), (tlo, thi) = m["nees_bounds"], m["nees_mean_interval"]
    nees_ok = lo <= m["nees_mean"] <= hi and tlo <= m["dim"] <= thi
    return m, tol, [nees_ok, m["nis_inside"] >= 0.90, abs(m["nis_per_dof"] - 1.0) <= tol]


def test_monte_carlo_nees_and_nis_are_consistent(mc_runs):
    """20 runs × 3 s from θ0 = 0.05 rad, rows from 0.5 s: the mean NEES inside its 95 % χ² bounds
    and 12 inside the t-interval of the per-run means; the summed NIS inside its bounds on ≥ 90 %
    of the rows with an encoder update; NIS per dof within 5 standard errors of 1.

    Measured on seeds 0–19: mean NEES 12.28 (bounds 9.95–14.24), NIS inside 96.5 %, NIS per
    dof 0.969 (tolerance ±0.148); before the dwelling-wheel update (SensorFrontEnd.keep_inside)
    12.21, 94.7 %, 0.962, and with it at the count's own edges 12.93, 92.9 %, 0.754 (fails).
    The batch figures below predate that update. On the 15 disjoint batches
    of seeds 0–299 the NEES test passes 14 times (seeds 40–59 fail: mean 15.07, interval
    12.46–17.68), as a 95 % test should; over all 300 runs the mean NEES is 12.62 ± 0.25 (s.e.),
    about 5 % overconfident, inside what 20 runs can resolve (the cause, the scale factors
    drifting from noise while learned, is in docs/explanation/sensors-ekf.md, "Consistency"). The NIS tests pass on
    all 15. Not asserted, because it swings from batch to batch (the rows of a run are strongly
    correlated): the fraction of rows whose 20-run average NEES is inside the bounds, 100 %
    here, 8–100 % over the 15 batches (≥ 90 % on 13).
    """
    assert all(r.status == "ok" for r in mc_runs)
    m, tol, passed = _consistency(mc_runs)
    assert m["rows"] == 501 and m["dim"] == N
    assert passed == [True, True, True], (m["nees_mean"], m["nees_mean_interval"], m["nis_inside"],
                                          m["nis_per_dof"], tol)


def _with_log(run, **changes):
    """A copy of ``run`` whose filter log has ``changes`` (key → function of the logged array)."""
    log = dict(run.filter_log)
    for key, f in changes.items():
        log[key] = f(log[key])
    return dataclasses.replace(run, filter_log=log)


def test_monte_carlo_test_fails_for_a_mis_stated_covariance(mc_runs):
    """The same batch with the logged P scaled by 0.25 (overconfident) or by 4 (underconfident)
    fails the NEES criterion, and with the logged NIS scaled by 4 (an S four times too small) fails
    both NIS criteria. Measured: mean NEES 49.9 and 3.1 (bounds 9.95–14.24), NIS inside 42 % and
    NIS per dof 4.0."""
    for scale in (0.25, 4.0):
        _, _, passed = _consistency([_with_log(r, P=lambda P: P * scale) for r in mc_runs])
        assert not passed[0], scale
        assert passed[1] and passed[2]  # the NIS is the filter's own: untouched by the scaled log
    _, _, passed = _consistency([_with_log(r, nis=lambda v: v * 4.0) for r in mc_runs])
    assert passed[0] and not passed[1] and not passed[2]


def test_monte_carlo_test_fails_for_a_mistuned_filter(design):
    """A real inconsistent filter: the EKF told the IMU's noise densities are 0.3 of the truth (its
    process noise ~10× too small), run in the loop on the same 20 seeds. It fails the NEES test
    and the NIS tests. Measured: mean NEES 70.8, NIS inside 26 %, NIS per dof 5.8."""
    quiet = ImuSpec(gyro=dataclasses.replace(MPU6050_GYRO, noise_density=0.3 * MPU6050_GYRO.noise_density),
                    accel=dataclasses.replace(MPU6050_ACCEL, noise_density=0.3 * MPU6050_ACCEL.noise_density))
    e = _experiment(0.05, 3.0)
    ctrl = build_cascade("it2", design, e.targets)
    mistuned = dataclasses.replace(SENSORS, imu=quiet)
    runs = [simulate_twin(ctrl, e, sensors=SENSORS, seed=s, log_filter=True,
                          estimator=build_estimator("ekf", mistuned, 200.0, DEFAULT_MOTOR, NOMINAL))
            for s in MC_SEEDS]
    m, tol, passed = _consistency(runs)
    assert passed == [False, False, False], (m["nees_inside"], m["nis_inside"], m["nis_per_dof"], tol)


def test_strapdown_is_exact_for_theta_and_v_but_not_for_the_twins_position(design):
    """What the consistency figures from θ0 = 0.2 rad rest on (docs/explanation/sensors-ekf.md, "Consistency"): on noise-free,
    finely quantised IMU samples, the EKF's strapdown step (``StrapdownFilter.propagate``) from the true initial
    state reproduces the twin's θ and v over 1 s (the gyro is a delta-angle, the accelerometer a
    delta-velocity sample), but not its ψ: the simulator's positions are not the trapezoid of its
    velocities (Bullet integrates positions with the end-of-substep velocities at 1 kHz, and the
    motion inside a 5 ms period after the release is far from linear). ψ is off by up to 0.7 mrad
    within 0.1 s of the release, where the filter's σ_ψ was 0.1–1 mrad with no process noise for
    it, and the encoders pushed that error into the encoder zero c (mean error −0.6 σ over 300
    runs). Since issue 29 the step's Q covers it (``TRAPEZOID_VAR``: ∫v anywhere in Δt [v, v⁺]),
    and the filter's own σ_ψ after the first 0.1 s is asserted to cover the error here.

    Measured: max |θ error| 1.4e-10 rad, max |v error| 0.023 mm/s, max |ψ error| 0.70 mrad (first
    0.1 s). Fails when the twin's positions become the trapezoid of its velocities: then the
    documented cause no longer holds.
    """
    quiet = dict(noise_density=1e-12, bias_random_walk=0.0, turn_on_bias=0.0, scale_factor_error=0.0, bits=30)
    sensors = SensorConfig(imu=ImuSpec(gyro=dataclasses.replace(MPU6050_GYRO, **quiet),
                                       accel=dataclasses.replace(MPU6050_ACCEL, **quiet)))
    e = _experiment(0.2, 1.0)
    run = simulate_twin(build_cascade("it2", design, e.targets), e, sensors=sensors, seed=0, log_filter=True)
    assert run.status == "ok"
    truth = filter_truth(run)
    est = _ekf(compiled=False)
    x = np.zeros(N)
    x[TH] = run.signal("theta")[0]
    err, sd = [], []
    P = np.zeros((N, N))  # the true initial state: only the step's own Q
    for k in range(int(run.filter_log["lag"][0]) + 1, len(run.t)):  # the sample taken at t_m arrives at m + lag
        g, a = run.measurements[k].gyro, run.measurements[k].accel
        x, F, Q, _ = est.filter.propagate(x, ((g[1], g[2], a[0], a[2]), None))
        P = F @ P @ F.T + Q
        err.append(x - truth[k])
        sd.append(math.sqrt(P[1, 1]))
    err = np.abs(np.array(err))
    assert err[:, TH].max() < 1e-6 and err[:, 2].max() < 1e-4, (err[:, TH].max(), err[:, 2].max())
    assert err[:20, 1].max() > 4e-4, err[:20, 1].max()
    # the trapezoid's variance covers it: within 3 σ over the first 0.1 s (measured: at most 1.28 σ)
    assert (err[:20, 1] <= 3.0 * np.array(sd[:20])).all(), (err[:20, 1] / np.array(sd[:20])).max()


# ---- 3. accuracy against the baselines ------------------------------------------------------

ACCURACY_SEEDS = range(4)


@pytest.mark.parametrize("theta0", [0.2, 0.48])
def test_ekf_theta_error_is_30_percent_below_each_baseline(twin_run, theta0):
    """6 s from θ0 = 0.2 and 0.48 rad, seeds 0–3, the EKF in the loop; the complementary filter and
    the two-state Kalman filter run offline on the same readings and commands. Per seed, the
    EKF's θ RMSE ≤ 0.7 × each baseline's.

    Per seed rather than on the mean: a user runs one robot, and the claim should hold for each
    draw of the sensors' constants, not only on average. Measured (mrad, EKF / complementary /
    two-state KF): θ0 = 0.2: 0.60/3.41/2.67, 1.75/4.13/4.14, 1.14/2.63/2.11, 1.61/3.03/2.81
    (worst ratio 0.57); θ0 = 0.48: 0.78/7.36/6.51, 1.73/9.07/9.50, 1.38/7.22/5.49, 1.65/6.97/5.52
    (worst 0.30).
    """
    for seed in ACCURACY_SEEDS:
        r = twin_run(theta0, 6.0, seed)
        assert r.status == "ok"
        ekf_rmse = r.estimation_rmse("theta")
        for kind in BASELINES:
            base = _baseline_theta_rmse(r, kind)
            assert ekf_rmse <= 0.7 * base, (seed, kind, ekf_rmse, base)


# ---- 4. the closed loop with the EKF in it ---------------------------------------------------

def _settled(run, tol=0.01):
    """Ran its duration and |θ| ≤ ``tol`` rad over the last second."""
    last_second = _window(run, run.t[-1] - 1.0, math.inf)
    return run.status == "ok" and float(np.abs(run.signal("theta")[last_second]).max()) <= tol


def test_balances_from_048_with_the_ekf_as_with_ideal_sensing(twin_run):
    """From θ0 = 0.48 rad, 6 s: with ideal sensing and with the EKF (seeds 0–3) the robot runs its
    duration and |θ| ≤ 0.01 rad over the last second, and the EKF never resets.

    The default (robust) design catches the fall so hard that |θ̇| peaks at about 5.6 rad/s,
    beyond the MPU-6050's ±250 °/s (4.36 rad/s) full scale: 11–13 gyro samples saturate in
    the first 0.08 s and equation (1) stands in for them. Until issue 29 the EKF took them as
    intervals, its estimate departed, and it rejected 0–17 encoder samples after them; now
    0–2 per run over seeds 0–11. A stale triad (three axes repeating the previous reading,
    chance ~3e-5 per sample) is treated as missing and counted as rejected: seed 1 has one at
    3.475 s. So the samples the gate rejects, other than stale ones, must all follow a saturated
    gyro, within the first 0.5 s."""
    import re

    ideal = twin_run(0.48, 6.0, 0, sensors=False)
    assert ideal.sensing == "ideal" and _settled(ideal)
    for seed in ACCURACY_SEEDS:
        r = twin_run(0.48, 6.0, seed)
        assert r.sensing == "ekf"
        assert _settled(r), (seed, r.status, r.signal("theta")[-1])
        st = r.estimator_stats
        assert st["resets"] == 0
        saturated = r.t[np.abs(r.signal("theta_dot")) > MPU6050_GYRO.full_scale]
        assert st["saturated_imu_samples"] == 0 or saturated.max() < 0.15, saturated
        if st["saturated_imu_samples"] == 0:  # the gate rejects 1e-4 of the samples that fit: one is allowed
            assert st["rejected_total"] <= 1
        else:
            stale = st["stale_imu_samples"]
            assert st["rejected"]["gyro"] == st["rejected"]["accel"] == stale and st["rejected_total"] <= 25
            assert all(float(re.match(r"t = ([0-9.]+) s", e).group(1)) < 0.5 for e in st["events"]
                       if "stale" not in e), st["events"]


SPIKES = (Spikes("imu", rate=2.0, magnitude=1.0), Spikes("encoders", rate=2.0, magnitude=0.1))


def test_balances_through_imu_and_encoder_spikes(twin_run):
    """From θ0 = 0.48 rad, 6 s, outliers on the IMU (±1 rad/s, ±1 m/s² on every axis) and the
    encoders (±0.1 rad = 19 counts), each at 2 per second to the end, seeds 0–2: the robot
    balances (runs its duration, |θ| ≤ 0.08 rad from t = 2 s on), both the IMU's and the
    encoders' outliers are rejected, and the EKF's θ RMSE stays below both baselines' on the
    same readings.

    The spikes go on to the end, so the bound is on every transient they cause, not on a
    settled state: over seeds 0–19 |θ| from 2 s on reached at most 0.043 rad (seed 2; 0.008
    without faults), over the last second up to 0.033 rad. Measured for seeds 0–2: |θ| from 2 s
    on 0.009, 0.027, 0.043 rad; rejected IMU samples 7–13 (of 9–14 gyro spikes), encoder
    samples 25–120; θ RMSE EKF 0.9–3.4 mrad, baselines 6.3–10.1 mrad.
    """
    for seed in range(3):
        r = twin_run(0.48, 6.0, seed, SPIKES)
        assert r.sensor_counts["gyro"]["spiked"] > 0 and r.sensor_counts["encoders"]["spiked"] > 0
        assert r.status == "ok", (seed, r.end_reason)
        assert float(np.abs(r.signal("theta")[_window(r, 2.0, math.inf)]).max()) <= 0.08, seed
        stats = r.estimator_stats
        assert stats["rejected_total"] > 0
        assert stats["rejected"]["gyro"] > 0 and stats["rejected"]["encoders"] > 0, stats["rejected"]
        assert any("IMU sample rejected as an outlier" in ev for ev in stats["events"])
        assert np.isfinite(r.estimates).all()
        ekf_rmse = r.estimation_rmse("theta")
        for kind in BASELINES:
            assert ekf_rmse < _baseline_theta_rmse(r, kind), (seed, kind)


# ---- 5. robustness ------------------------------------------------------------------------------

FAULTS = {
    "imu-dropout-0.1s": ((Dropout("imu", 1.0, 0.1),), 1.1),
    "imu-dropout-0.2s": ((Dropout("imu", 1.0, 0.2),), 1.2),
    "imu-dropout-0.5s": ((Dropout("imu", 1.0, 0.5),), 1.5),
    "encoder-dropout-0.5s": ((Dropout("encoders", 1.0, 0.5),), 1.5),
    "imu-stuck-0.1s": ((Stuck("imu", 1.0, 0.1),), 1.1),
    "imu-stuck-0.3s": ((Stuck("imu", 1.0, 0.3),), 1.3),
    "encoders-stuck-0.3s": ((Stuck("encoders", 1.0, 0.3),), 1.3),
    "imu-latency-5-to-15ms": ((LatencyChange("imu", 1.0, 0.015),), 1.0),
    "encoder-latency-0-to-10ms": ((LatencyChange("encoders", 1.0, 0.01),), 1.0),
}


@pytest.mark.parametrize("name", list(FAULTS))
def test_fault_keeps_the_estimate_bounded_and_it_reconverges(twin_run, name):
    """From θ0 = 0.2 rad, 4 s, one fault from t = 1 s, seeds 0 and 1: the robot runs its duration,
    every estimate is finite, the θ error stays ≤ 0.05 rad from the fault's start to 0.5 s after
    its end (the controllers still balance), and from 1 s after its end the θ error is back to
    the EKF's normal accuracy: RMS ≤ 2 mrad (the fault-free EKF: 0.6–1.8 mrad over whole runs,
    0.28 and 0.52 mrad over this window of these runs).

    Measured when written (max |error| during, seeds 0, 1; RMS after; mrad): IMU dropout 0.1 s
    1.9, 2.0; 0.24, 0.35; 0.2 s 1.9, 2.0; 0.36, 0.29; 0.5 s 4.8, 2.8; 0.38, 0.30. Encoder
    dropout 0.5 s 1.8, 1.9; 0.33, 0.48. IMU stuck 0.1 s 1.9, 2.0; 0.24, 0.35; 0.3 s 2.3, 2.8;
    0.27, 0.23. Encoders stuck 0.3 s 2.0, 3.0; 0.27, 0.44. Latency changes 1.3–2.1; 0.28–0.73.
    Before the filter coasted with θ̇ in its state (see estimation.ekf_filter.Coasting) and told stale IMU
    samples from real ones, a 0.2 s IMU dropout gave 39, 62; 9.4, 14.1 and 0.5 s fell.
    """
    faults, end = FAULTS[name]
    for seed in (0, 1):
        r = twin_run(0.2, 4.0, seed, faults)
        assert r.status == "ok", (seed, r.end_reason)
        assert np.isfinite(r.estimates).all() and np.isfinite(r.filter_log["x"]).all()
        err = _theta_error(r)
        during = float(np.abs(err[_window(r, 1.0, end + 0.5)]).max())
        after = float(np.sqrt(np.mean(err[_window(r, end + 1.0, math.inf)] ** 2)))
        assert during <= 0.05, (seed, during)
        assert after <= 0.002, (seed, after)


@pytest.mark.parametrize("name, frozen", [("imu-stuck-0.1s", 20), ("imu-stuck-0.3s", 60)])
def test_a_stuck_imu_is_told_stale_and_coasted_through(twin_run, name, frozen):
    """A stuck IMU repeats its last sample: every repeated sample (0.1 s or 0.3 s at 200 Hz) is
    counted stale, logged once, and none of the fault-free run's samples is (the noise spans
    ~9 ADC steps per gyro sample, so three axes repeat by chance with probability ~3e-5)."""
    faults, _ = FAULTS[name]
    for seed in (0, 1):
        s = twin_run(0.2, 4.0, seed, faults).estimator_stats
        assert s["stale_imu_samples"] == frozen
        assert sum("stale, treated as missing" in ev for ev in s["events"]) == 1
        assert twin_run(0.2, 4.0, seed).estimator_stats["stale_imu_samples"] == 0


def _without(measurements, t0: float, t1: float, **fields):
    """Copies of ``measurements`` with ``fields`` (name → value) replaced on steps t ∈ [t0, t1)."""
    return [m._replace(**fields) if t0 - 1e-9 <= m.t < t1 - 1e-9 else m for m in measurements]


@pytest.mark.parametrize("compiled", PATHS)
def test_imu_dropout_is_predicted_through_with_the_model(twin_run, compiled):
    """The readings of the θ0 = 0.48 rad run (seed 0) replayed with the IMU's removed on the 40
    steps t ∈ [1.0, 1.2) s. Each of these steps is a prediction with equation (1): the count of
    predict-only steps rises by exactly one per step there, where the replay with the IMU counts
    only the steps without an encoder update (measured: 2 of the 40), and no IMU sample is
    used there; from the next step on every IMU sample is used again; every estimate is finite.
    With the encoders' readings removed instead, every IMU sample is used."""
    r = twin_run(0.48, 6.0, 0)
    window = _window(r, 1.0, 1.2)
    after = _window(r, 1.2, math.inf)
    assert window.sum() == 40

    def replay(measurements):
        """Estimates, and the per-step increments of the predict-only and used-IMU counts."""
        f = _ekf(compiled=compiled)
        est, counts = [f.start(measurements[0])], [(0, 0)]
        for i, m in enumerate(measurements[1:]):
            est.append(f.step(m, r.commands[i, :2]))
            s = f.stats()
            counts.append((s["predict_only_steps"], s["accepted"]["gyro"] + s["rejected"]["gyro"]))
        inc = np.diff(np.array(counts), axis=0, prepend=0)
        return np.array(est), inc[:, 0], inc[:, 1]

    _, clean_po, clean_used = replay(r.measurements)
    est, po, used = replay(_without(r.measurements, 1.0, 1.2, gyro=None, accel=None))
    assert np.isfinite(est).all()
    assert (po[window] == 1).all() and po[window].sum() > clean_po[window].sum()
    assert (used[window] == 0).all() and (clean_used[window] == 1).all() and (used[after] == 1).all()
    est, _, used = replay(_without(r.measurements, 1.0, 1.2, encoders=None))
    assert np.isfinite(est).all() and (used[2:] == 1).all()  # the filter's first step is at step 2 (its lag)


NONFINITE = {
    # step → (field, non-finite reading)
    100: ("gyro", (math.nan, 0.0, 0.0)),
    150: ("accel", (0.0, math.inf, 9.8)),
    200: ("encoders", (math.nan, 0.0)),
    250: ("encoders", (math.inf, -math.inf)),
    300: ("gyro", (0.0, -math.inf, 0.0)),
}


@pytest.mark.parametrize("compiled", PATHS)
def test_non_finite_readings_are_ignored_like_missing_ones(twin_run, compiled):
    """NaN and ±inf in single readings, and in every reading for 0.3 s, replayed into the EKF: no
    estimate is non-finite, each such reading is logged as ignored, and the estimates are
    identical (bit for bit) to those with the same readings missing (None)."""
    r = twin_run(0.48, 6.0, 0)
    bad, missing = list(r.measurements), list(r.measurements)
    for k, (field, value) in NONFINITE.items():
        bad[k] = bad[k]._replace(**{field: value})
        missing[k] = missing[k]._replace(**{field: None})
    nan3, nan2 = (math.nan,) * 3, (math.nan, math.nan)
    bad = _without(bad, 2.0, 2.3, gyro=nan3, accel=nan3, encoders=nan2)
    missing = _without(missing, 2.0, 2.3, gyro=None, accel=None, encoders=None)
    f_bad, f_missing = _ekf(compiled=compiled), _ekf(compiled=compiled)
    est_bad, est_missing = _replay(r, f_bad, bad), _replay(r, f_missing, missing)
    assert np.isfinite(est_bad).all() and np.isfinite(f_bad.x).all() and np.isfinite(f_bad.P).all()
    assert est_bad.tobytes() == est_missing.tobytes()
    events = f_bad.stats()["events"]
    for field in ("gyro", "accel", "encoders"):
        n_logged = sum(f"non-finite {field} reading ignored" in ev for ev in events)
        n_fed = sum(1 for k, (f, _) in NONFINITE.items() if f == field) + 60
        assert n_logged == n_fed, (field, n_logged, n_fed)
    assert f_bad.stats()["resets"] == 0


def test_restore_returns_the_last_good_estimate_inflated_and_logs_why(twin_run):
    """Pure-Python path: the filter's state made non-finite behind its back at step 300 of a replay.
    The next step restores the last good state (x exactly, P inflated), logs the reason, counts a
    reset, and every estimate handed out stays finite; the filter then runs on normally."""
    r = twin_run(0.48, 6.0, 0)
    f = _ekf(compiled=False)
    meas, cmds = r.measurements, r.commands[:, :2]
    f.start(meas[0])
    for i in range(1, 300):
        f.step(meas[i], cmds[i - 1])
    good_x, good_P = f.x.copy(), f.P.copy()
    f.kf.x[TH] = math.nan
    out = [f.step(meas[300], cmds[299])]
    s = f.stats()
    assert s["resets"] == 1
    assert any("restored the last good estimate" in ev for ev in s["events"])
    assert np.array_equal(f.x, good_x)
    assert np.all(np.diag(f.P) > np.diag(good_P)) and np.all(np.linalg.eigvalsh(f.P - good_P) > 0)
    out += [f.step(meas[i], cmds[i - 1]) for i in range(301, 600)]
    assert np.isfinite(np.array(out)).all()
    assert f.stats()["resets"] == 1
    err = np.array(out)[-100:, 0] - r.signal("theta")[500:600]
    assert np.sqrt(np.mean(err ** 2)) < 0.005


@pytest.mark.parametrize("compiled", PATHS)
def test_non_finite_commands_trigger_the_reset_path_and_nothing_non_finite_leaves(compiled):
    """Through the public interface on both paths: the robot at rest, the IMU missing for 10 steps
    (so the filter predicts from the commands) and NaN/inf commands on 5 of them. The state goes
    non-finite, is restored (logged, counted), the forward prediction's failure is logged, and
    every estimate handed out is finite."""
    f = _ekf(compiled=compiled)
    rest_g, rest_a = (0.0, 0.0, 0.0), (0.0, 0.0, 9.81)
    f.start(Measurement(0.0, rest_g, rest_a, (0.0, 0.0)))
    out = []
    for k in range(1, 40):
        imu = not 10 <= k < 20
        cmd = (math.nan, math.inf) if 10 <= k < 15 else (0.0, 0.0)
        out.append(f.step(Measurement(k / RATE, rest_g if imu else None, rest_a if imu else None, (0.0, 0.0)), cmd))
    assert np.isfinite(np.array(out)).all() and np.isfinite(f.x).all() and np.isfinite(f.P).all()
    s = f.stats()
    assert s["resets"] >= 1
    assert sum("restored the last good estimate" in ev for ev in s["events"]) == s["resets"]
    assert any("forward prediction non-finite" in ev for ev in s["events"])
    assert abs(out[-1][0]) < 1e-3  # still upright at rest


@pytest.mark.parametrize("meas", [
    Measurement(0.0, None, (0.0, 0.0, 9.81), (0.0, 0.0)),
    Measurement(0.0, (0.0, 0.0, 0.0), None, (0.0, 0.0)),
    Measurement(0.0, None, None, (0.0, 0.0)),
    Measurement(0.0, (math.nan, 0.0, 0.0), (0.0, 0.0, 9.81), (0.0, 0.0)),
    Measurement(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, math.inf), (0.0, 0.0)),
], ids=["no-gyro", "no-accel", "no-imu", "nan-gyro", "inf-accel"])
def test_start_without_an_imu_reading_is_a_one_line_error(meas):
    with pytest.raises(TwinError) as err:
        _ekf().start(meas)
    msg = str(err.value)
    assert "\n" not in msg and "gyro" in msg and "accelerometer" in msg


@pytest.mark.parametrize("kind", ["ekf", *BASELINES])
def test_step_before_start_is_an_error(kind):
    f = build_estimator(kind, SENSORS, RATE, MOTOR, NOMINAL)
    with pytest.raises(TwinError, match="start"):
        f.step(Measurement(0.005, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81), (0.0, 0.0)), (0.0, 0.0))


# ---- 6. determinism -----------------------------------------------------------------------------

def test_same_seed_same_everything_different_seed_different_readings(twin_run, design):
    """θ0 = 0.48 rad, 6 s, seed 0 twice: estimates, commands, filter log (x, P, NIS, dof) and the
    estimator's stats are identical bit for bit; a fresh EKF fed the logged readings and commands
    reproduces the loop's estimates bit for bit; seed 1 gives other readings and other estimates."""
    a = twin_run(0.48, 6.0, 0)
    e = _experiment(0.48, 6.0)
    b = simulate_twin(build_cascade("it2", design, e.targets), e, sensors=SENSORS, seed=0, log_filter=True)
    for u, v in ((a.estimates, b.estimates), (a.commands, b.commands), (a.truth, b.truth)):
        assert u.tobytes() == v.tobytes()
    for key in ("x", "P", "nis", "nis_dof"):
        assert a.filter_log[key].tobytes() == b.filter_log[key].tobytes(), key
    assert a.estimator_stats == b.estimator_stats and a.measurements == b.measurements
    assert _replay(a, _ekf()).tobytes() == a.estimates.tobytes()
    c = twin_run(0.48, 6.0, 1)
    assert c.measurements[1] != a.measurements[1]
    assert np.abs(c.estimates - a.estimates).max() > 1e-3


# ---- 7. covariances --------------------------------------------------------------------------------

@pytest.mark.parametrize("theta", [0.0, 0.3, -0.48])
def test_start_covariance_is_symmetric_positive_definite(theta):
    """start() at rest tilted θ (the accelerometer reads (−g sin θ, 0, g cos θ)): θ from gravity's
    direction, P symmetric positive definite (the encoder zero c = θ shares θ's error, so a θ
    variance below that shared part makes P indefinite), and P[θ, θ] = P[θ, c]."""
    f = _ekf()
    g = 9.81
    f.start(Measurement(0.0, (0.0, 0.0, 0.0), (-g * math.sin(theta), 0.0, g * math.cos(theta)), (0.0, 0.0)))
    P = f.P
    assert f.x[TH] == pytest.approx(theta, abs=1e-12) and f.x[C0] == f.x[TH]
    assert np.array_equal(P, P.T) and np.linalg.eigvalsh(P).min() > 0
    assert P[TH, TH] == P[TH, C0] and P[C0, C0] > P[TH, TH]


@pytest.mark.parametrize("compiled", PATHS)
def test_covariance6_is_symmetric_psd_and_its_theta_variance_is_p_theta(twin_run, compiled):
    """Every 25th step of a replay (θ0 = 0.48 rad, seed 0): covariance6() is exactly symmetric,
    positive semi-definite (eigenvalues ≥ −1e-12 of the largest), positive on its diagonal, and
    its θ variance equals P[θ, θ] (rel 1e-9: θ is a state, its Jacobian row is a unit vector);
    its θ̇ variance includes the gyro's white noise of the extrapolated rate (≥ 2.5 σ_g²/(1+s_y)²)."""
    r = twin_run(0.48, 6.0, 0)
    f = _ekf(compiled=compiled)
    meas, cmds = r.measurements, r.commands[:, :2]
    f.start(meas[0])
    checked = 0
    for i in range(1, len(meas)):
        f.step(meas[i], cmds[i - 1])
        if i % 25:
            continue
        C, P, x = f.covariance6(), f.P, f.x
        assert C.shape == (6, 6) and np.array_equal(C, C.T)
        eig = np.linalg.eigvalsh(C)
        assert eig.min() >= -1e-12 * eig.max() and (np.diag(C) > 0).all()
        assert C[0, 0] == pytest.approx(P[TH, TH], rel=1e-9)
        assert C[1, 1] >= 2.5 * f._g_var / (1.0 + x[SY]) ** 2
        checked += 1
    assert checked == (len(meas) - 1) // 25


@pytest.mark.parametrize("tilt_bias", [0.0, 0.05])
@pytest.mark.parametrize("compiled", PATHS)
def test_state_into_writes_x_then_the_reported_covariance_into_any_buffer(twin_run, compiled, tilt_bias):
    """EKFEstimator.state_into (what twin.sim.simulate's consistency meter reads every step): x
    then covariance12() row by row, float64, into a row of a 2-d array, a flat array or a
    bytearray, the same bits as diagnostics(); with an accelerometer turn-on bias too (the
    covariance then has (σ_b/g)² added on the θ, c block)."""
    r = twin_run(0.2, 1.0, 0)
    accel = dataclasses.replace(SENSORS.imu.accel, turn_on_bias=tilt_bias)
    sensors = dataclasses.replace(SENSORS, imu=dataclasses.replace(SENSORS.imu, accel=accel))
    f = _ekf(sensors, compiled=compiled)
    meas, cmds = r.measurements, r.commands[:, :2]
    f.start(meas[0])
    for i in range(1, 60):
        f.step(meas[i], cmds[i - 1])
    d = f.diagnostics()
    want = np.concatenate([d["x"], np.ravel(d["P"])])
    rows = np.zeros((3, N + N * N))
    f.state_into(rows, 2)
    flat = np.zeros(N + N * N)
    f.state_into(flat)
    raw = bytearray(8 * (N + N * N))
    f.state_into(raw)
    assert rows[2].tobytes() == flat.tobytes() == bytes(raw) == want.tobytes()
    assert not rows[:2].any()
    assert (d["P"][TH, TH] > f.P[TH, TH]) == (tilt_bias > 0.0)


@pytest.mark.parametrize("mag", [1.5e308, 1e3])
def test_absurd_finite_encoder_readings_are_rejected_without_resets_on_both_paths(mag):
    """The robot at rest, its encoders reading ±``mag`` rad from step 6 on, the sign flipping
    every 20 steps (finite, but 1.5e308 beyond a 32-bit counter and 1e3 rad a jump no wheel
    makes in 5 ms). Both paths: every estimate is finite and still reads the robot at rest (the
    encoders never reach the state), no reset, the same counts and events on both paths, and
    the reason logged: out of range, or the jump rejected and, when the counts stay there, the
    encoders' zeros re-based."""
    # at rest, with readings that differ from sample to sample (a repeat would be stale)
    g_rest = [(1e-4 * math.sin(k), -2e-4 * math.cos(k), 1e-4 * math.sin(2 * k)) for k in range(200)]
    a_rest = [(2e-3 * math.cos(k), 1e-3 * math.sin(3 * k), 9.81 + 2e-3 * math.sin(k)) for k in range(200)]
    stats, outs = [], []
    for compiled in (False, True):
        if compiled and ekf._kernel is None:
            continue
        f = _ekf(compiled=compiled)
        assert f.compiled == compiled
        f.start(Measurement(0.0, g_rest[0], a_rest[0], (0.0, 0.0)))
        out = []
        for k in range(1, 200):
            big = mag if (k // 20) % 2 == 0 else -mag
            enc = (big, big) if k > 5 else (0.0, 0.0)
            out.append(f.step(Measurement(k / RATE, g_rest[k], a_rest[k], enc), (0.0, 0.0)))
        out = np.array(out)
        assert np.isfinite(out).all() and np.isfinite(f.x).all() and np.isfinite(f.P).all()
        # θ, α stay put; ψ drifts only as the IMU alone integrates (0.2 mrad of tilt for 1 s)
        assert np.abs(out[:, [0, 4]]).max() < 1e-3 and np.abs(out[:, 2]).max() < 0.1, np.abs(out).max(axis=0)
        s = f.stats()
        assert s["resets"] == 0 and s["stale_imu_samples"] == 0
        if mag > 1e300:
            assert sum("beyond a 32-bit counter's range" in ev for ev in s["events"]) == 194
        else:
            assert any("more than a wheel can turn" in ev for ev in s["events"])
            assert any("re-based their zeros" in ev for ev in s["events"])
        stats.append(s)
        outs.append(out)
    if len(stats) == 2:
        assert stats[0] == stats[1]
        np.testing.assert_allclose(outs[0], outs[1], rtol=0, atol=1e-9)


@pytest.mark.parametrize("w, s2, lo, hi", [(0.0, 1.0, 0.5, 1.5), (2.0, 1.0, 0.5, 1.5), (0.0, 4e-6, 0.003, 0.008),
                                           (0.01, 1e-4, -0.002, 0.003), (-0.004, 1e-8, -0.0026, 0.0026)])
def test_truncated_measurement_gives_the_truncated_normals_moments(w, s2, lo, hi):
    """The pseudo-measurement of SensorFrontEnd.keep_inside: a scalar Kalman update with it
    gives the mean and variance of N(w, s2) truncated to [lo, hi] (scipy's truncnorm)."""
    from scipy.stats import truncnorm
    from estimation.ekf import truncated_measurement

    z, R = truncated_measurement(w, s2, lo, hi, 40.0)
    s = math.sqrt(s2)
    d = truncnorm((lo - w) / s, (hi - w) / s, loc=w, scale=s)
    k = s2 / (s2 + R)
    assert w + k * (z - w) == pytest.approx(d.mean(), rel=1e-9, abs=1e-12 * s)
    assert s2 * (1.0 - k) == pytest.approx(d.var(), rel=1e-7)


def test_truncated_measurement_leaves_a_mean_inside_or_beyond_the_gate_alone():
    from estimation.ekf import truncated_measurement

    assert truncated_measurement(0.001, 1e-6, 0.0, 0.002, 6.0) is None  # inside
    assert truncated_measurement(-0.01, 1e-6, 0.0, 0.002, 6.0) is None  # 10 σ below
    assert truncated_measurement(-0.001, 1e-6, 0.0, 0.002, 6.0) is not None  # 1 σ below
    assert truncated_measurement(-0.001, 0.0, 0.0, 0.002, 6.0) is None  # no prior spread
