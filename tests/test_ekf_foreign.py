"""The EKF on logs it did not write: short logs of the independent simulator
(tests/foreign/robot_sim.py, none of the twin's code), written in format version 2 so that they
say what the sensors are (the accelerometer's turn-on bias, the IMU's sampling and mounting, the
commands' semantics, the true per-sample noise).

What is held here (benchmarks/foreign_logs.py measures the same on 20 logs of 20 s):

* profile A (200 Hz, interval means, 1 % scale factors, a constant accelerometer bias, drives,
  turns and pushes): the Monte Carlo mean NEES inside its 95 % bounds, NIS per degree of freedom
  in [0.8, 1.25], θ RMSE at most 1.5 mrad; the accelerometer's scale factors never moved by a
  measurement; its constant bias in the reported covariance (as a consider parameter) and in no
  gain;
* profile B-shaped logs (33 Hz rows of point samples from a 1 kHz loop, an IMU pitched 0.07 rad,
  voltages sampled at the rows, vibration noise, the true noise in the log) that begin
  mid-motion: NIS per degree of freedom in [0.5, 2], θ within 0.05 rad of the truth 0.5 s after
  the start, no latency-change event;
* pushes of 10–12 N: the NEES at most 1.5 × its upper bound and no latency-change event.

Before these changes (the same logs): profile A's mean NEES about 22 (θ's e²/P 3.5, the encoder
zero's 2.1, the accelerometer's scale factors' 2.7 and 2.2), a forward accelerometer scale factor
learned +0.9 % off on average; on the B-shaped logs false "latency changed" events and θ up to
0.055 rad off 0.5 s after the start.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # tests/ (for the foreign package)

from foreign import robot_sim as rs  # noqa: E402

from estimation.ekf_core import C0, SAX, SAZ, TH  # noqa: E402
from twin.logs.format import read_log  # noqa: E402
from twin.logs.replay import build_for, consistency, instants_of, replay  # noqa: E402


def _replay(path: Path):
    """(log, replay, estimator) of the EKF on the log at ``path``, told the log's sampling (and,
    on jittered rows, that its instants are the rows) as build_for tells it."""
    log = read_log(path)
    est = build_for(log, "ekf")
    return log, replay(log, est, "ekf", diagnostics=True), est


def _theta_errors(log, r) -> tuple[np.ndarray, np.ndarray]:
    """(t, θ̂ − θ) at the truth's rows inside the replay."""
    k = instants_of(log, r.t, log.truth_t)
    ok = (k >= 0) & (k < len(r.estimates))
    return log.truth_t[ok], r.estimates[k[ok], 0] - log.truth[ok, 0]


def _latency_events(r) -> list:
    return [e for e in r.stats.get("events", []) if "latency changed" in e]


def _bounds(runs: int, dof: int = 12) -> tuple[float, float]:
    """The 95 % interval of the Monte Carlo mean NEES over ``runs`` independent runs."""
    return tuple(float(v) for v in chi2.ppf([0.025, 0.975], dof * runs) / runs)


@pytest.fixture(scope="module")
def logs_a(tmp_path_factory):
    where = tmp_path_factory.mktemp("foreign-a")
    out = []
    for seed in range(6):  # 12 s: the learning window (10 s), a drive, a turn, a push
        p = where / f"a{seed}"
        rs.generate(p, "A", seed, duration=12.0, version=2)
        out.append(p)
    return out


def test_profile_a_is_honest_and_learns_no_accelerometer_scale_factor(logs_a):
    nees, nis, rmse, scale, events = [], [], [], [], []
    for p in logs_a:
        log, r, est = _replay(p)
        c = consistency(r, log)
        nees.append(c["nees_mean"])
        nis.append(c["nis_per_dof"])
        _, e = _theta_errors(log, r)
        rmse.append(math.sqrt(float(np.mean(e[e == e] ** 2))))
        scale.append((est.x[SAX], est.x[SAZ], math.sqrt(est.P[SAX, SAX])))
        events += _latency_events(r)
    lo, hi = _bounds(len(logs_a))
    mean = float(np.mean(nees))
    assert lo <= mean <= hi, f"Monte Carlo mean NEES {mean:.2f} outside [{lo:.2f}, {hi:.2f}] ({nees})"
    assert 0.8 <= float(np.mean(nis)) <= 1.25, nis
    assert float(np.mean(rmse)) <= 1.5e-3, rmse
    # held from the first step (Schmidt): the estimates stay at their prior, their σ with them
    assert all(sx == 0.0 and sz == 0.0 and sd == pytest.approx(0.01, rel=1e-3) for sx, sz, sd in scale), scale
    assert events == []


def test_the_accelerometer_bias_is_a_consider_parameter_of_tilt_and_encoder_zero(logs_a, tmp_path):
    """The filter estimates θ − b/g and c − b/g (an accelerometer bias b is a tilt on level
    ground): the bias enters the reported covariance on that block, (σ_b/g)², and no gain."""
    log, r, est = _replay(logs_a[0])
    sigma_b = log.sensors.imu.accel.turn_on_bias
    assert sigma_b == 0.005
    extra = est.covariance12() - est.P
    want = np.zeros_like(extra)
    for i in (TH, C0):
        for j in (TH, C0):
            want[i, j] = (sigma_b / est.model.g) ** 2
    assert np.allclose(extra, want, rtol=1e-9, atol=1e-18)
    d = est.diagnostics()
    assert np.array_equal(d["P"], est.covariance12())
    # a log whose sensor has no turn-on bias (version 1: the preset's, 0 for the accelerometer):
    # nothing added, the covariance is the filter's own
    rs.generate(tmp_path / "v1", "A", 0, duration=1.0)
    log1 = read_log(tmp_path / "v1")
    assert log1.sensors.imu.accel.turn_on_bias == 0.0
    est1 = build_for(log1, "ekf")
    replay(log1, est1, "ekf")
    assert np.array_equal(est1.covariance12(), est1.P)


@pytest.mark.parametrize("seed, start", [(0, 0.015), (1, 0.015), (2, 0.015), (0, 0.0)])
def test_a_real_robot_shaped_log_that_begins_mid_motion(seed, start, tmp_path):
    """33 Hz rows of point samples and sampled voltages, the log starting 15 ms into the
    stand-up from about 0.5 rad (θ̇ about −4 rad/s at the first row), or (start 0) lying still
    just before it. Seed 0 from lying was 0.056 rad off at 0.5 s with its 30–33 ms rows put on
    a 30 ms grid; taking the trapezoid means of point samples as white noise of σ² made the NIS
    per degree of freedom 0.41–0.64 once the rows were at their own times."""
    rs.generate(tmp_path / "b", "B", seed, version=2, log_start=start)
    log, r, est = _replay(tmp_path / "b")
    assert est.periods == "rows"
    assert abs(log.truth[0, 1]) > 3.0 or start == 0.0  # it does begin in motion
    c = consistency(r, log)
    assert 0.5 <= c["nis_per_dof"] <= 2.0, c["nis_per_dof"]
    t, e = _theta_errors(log, r)
    j = int(np.searchsorted(t, t[0] + 0.5))
    assert abs(e[j]) <= 0.05, f"θ off by {e[j]:.3f} rad 0.5 s after the start"
    assert _latency_events(r) == []


def test_pushes_of_10_to_12_newtons(tmp_path):
    nees = []
    for seed in (300, 301, 302):
        rs.generate(tmp_path / f"p{seed}", "A", seed, duration=14.0, version=2, variant="push")
        log, r, _ = _replay(tmp_path / f"p{seed}")
        nees.append(consistency(r, log)["nees_mean"])
        assert _latency_events(r) == []
    hi = _bounds(len(nees))[1]
    assert float(np.mean(nees)) <= 1.5 * hi, nees


def test_sampling_is_checked(logs_a):
    est = build_for(read_log(logs_a[0]), "ekf")
    with pytest.raises(Exception, match="sampling"):
        est.set_sampling("instant")
    with pytest.raises(Exception, match="semantics"):
        est.set_sampling("point", "interpolated")


def test_the_compiled_and_the_python_cores_agree_on_rebuilt_point_samples(tmp_path):
    """The kernel takes a rebuilt point sample's own variances with the sample (an 8-tuple); the
    reference path adds them in StrapdownFilter.propagate: the two paths stay together."""
    from estimation.ekf_core import compiled_kernel_loaded

    if not compiled_kernel_loaded():
        pytest.skip("the compiled kernel is not built (or TWIN_PURE_PYTHON=1)")
    rs.generate(tmp_path / "b", "B", 1, duration=4.0, version=2)
    log = read_log(tmp_path / "b")
    out = []
    for compiled in (True, False):
        est = build_for(log, "ekf", {"compiled": compiled})
        assert est.periods == "rows"  # (jittered rows: each step spans its own period)
        assert est.compiled is compiled
        r = replay(log, est, "ekf")
        out.append(r.estimates)
    assert np.allclose(out[0], out[1], rtol=0.0, atol=1e-9), float(np.max(np.abs(out[0] - out[1])))


def _hobby_log(name: str, tmp_path: Path) -> Path:
    """The robot-logs how-to's hobby recording ``name`` (docs/howto/hobby-robot) made a log by
    the page's own to_log.py, in ``tmp_path``."""
    import re
    import shutil
    import subprocess

    docs = HERE.parent / "docs" / "howto"
    page = (docs / "real-robot.md").read_text(encoding="utf-8")
    code = re.search(r"<!-- file: to_log.py -->\s*```python\n(.*?)\n```", page, re.S).group(1)
    (tmp_path / "to_log.py").write_text(code + "\n", encoding="utf-8")
    shutil.copy(docs / "hobby-robot" / name, tmp_path / name)
    subprocess.run([sys.executable, "to_log.py", name, "logs/x"], cwd=tmp_path, check=True, capture_output=True)
    return tmp_path / "logs" / "x"


@pytest.mark.parametrize("compiled", [True, False])
def test_the_hobby_robot_with_datasheet_noise_keeps_a_positive_definite_covariance(compiled, tmp_path):
    """Told the datasheet's noise, 25–100× below the hobby robot's vibration, the EKF trusted its
    IMU far too much. It diverged: its model stepped once per 33 Hz row, past RK4's stability
    limit for these motors (h λ ≈ 5.6), θ̂ passed −π/2, where the heading's rate ω_z / cos θ is
    singular, and ran to 3880 rad, v̂ to 680 m/s, P's condition number to 1e29, where rounding
    alone made it indefinite (least eigenvalue −0.018, largest 4e4; its diagonal positive, so
    kept as "good"), and the encoders' innovation covariance S was not positive definite at
    t = 7.29 s, which stopped ``twin replay``."""
    from dataclasses import replace

    from estimation import ekf as ekf_mod
    from estimation.detlinalg import positive_definite
    from twin.logs.noise import choose

    if compiled and ekf_mod._kernel is None:
        pytest.skip("the compiled EKF kernel is not built here")
    log = read_log(_hobby_log("balance-2.csv", tmp_path))
    _, sensors, _ = choose(log, "datasheet")
    log = replace(log, sensors=sensors)
    est = build_for(log, "ekf", {"compiled": compiled})
    assert est.compiled == compiled
    r = replay(log, est, "ekf", diagnostics=True)
    assert all(positive_definite(d["P"]) for d in r.diagnostics)
    covs = [d["innovation_cov"] for d in r.diagnostics if "innovation_cov" in d]
    assert covs and all(np.linalg.eigvalsh(S).min() > 0.0 for S in covs)
    assert np.abs(r.estimates[:, 0]).max() < math.pi / 2


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("how", ["tilt", "variance", "indefinite"])
def test_an_estimate_out_of_its_physical_range_is_reinitialised(how, compiled, logs_a):
    """θ̂ beyond π/2, θ's variance beyond a tilt's whole range (π²/12), or a P whose diagonal
    is positive but which is not positive definite: the next step re-initialises the estimate
    from the accelerometer (an event), on either core, instead of keeping it as the good state
    to restore (which also went on from a P no longer positive definite)."""
    from estimation import ekf as ekf_mod
    from estimation.detlinalg import positive_definite
    from twin.logs.replay import command_integral, schedule
    from twin.logs.replay import _chunk

    if compiled and ekf_mod._kernel is None:
        pytest.skip("the compiled EKF kernel is not built here")
    log = read_log(logs_a[0])
    est = build_for(log, "ekf", {"compiled": compiled})
    sched = schedule(log)
    ts, ms, cmds = _chunk(log, sched, 0, 400, command_integral(log))
    est.start(ms[0])
    for j in range(1, 300):
        est.step(ms[j], tuple(cmds[j - 1]))
    est.core.pull()
    x, P = est.x.copy(), est.P.copy()
    if how == "tilt":
        x[TH] = 1.7
    elif how == "variance":
        f = math.sqrt(1.0 / P[TH, TH])  # σ_θ 1 rad, P kept positive definite
        P[TH, :] *= f
        P[:, TH] *= f
    else:
        P[TH, C0] = P[C0, TH] = 2.0 * math.sqrt(P[TH, TH] * P[C0, C0])
    est.core.set_state(x, P, est.core.w, est.core.w_prev)
    for j in range(300, 400):
        est.step(ms[j], tuple(cmds[j - 1]))
        assert abs(est.x[TH]) < math.pi / 2 and positive_definite(est.P)
    lost = [e for e in est.stats()["events"] if "left its physical range" in e]
    assert len(lost) == 1, est.stats()["events"]


def test_a_catch_that_clips_the_gyro(tmp_path):
    """A catch from 0.35–0.45 rad whose rate clips the gyro from its second period on: equation
    (1) stands in for the clipped samples, starting from the rate the last two readings
    extrapolate to. That extrapolation was 0.93 rad/s short at σ 0.003 (the torque steps in and
    the rate is anything but linear over the two periods); θ̂ ended the clipped stretch 0.13 rad
    off at σ 0.023, and a forced encoder update left ±10 mrad between ψ and the encoder zero for
    good (their e²/P about 14 and 30 on such a log). The NEES from 0.5 s on, over six logs: at
    most 1.5 × its upper bound (as for the pushes), and no latency-change event.

    Not yet held: θ̂'s error during the clipped stretch itself is still 5–9 σ."""
    nees = []
    for seed in range(200, 206):
        rs.generate(tmp_path / f"c{seed}", "A", seed, duration=4.0, version=2, variant="clip")
        log, r, _ = _replay(tmp_path / f"c{seed}")
        assert sum(json_clipped(tmp_path / f"c{seed}")) > 5  # it does clip
        nees.append(consistency(r, log)["nees_mean"])
        assert _latency_events(r) == []
    hi = _bounds(len(nees))[1]
    assert float(np.mean(nees)) <= 1.5 * hi, (nees, 1.5 * hi)


def json_clipped(path: Path) -> list:
    """The gyro's clipped samples per axis the simulator reports for the log at ``path``."""
    import json

    return json.loads((path / "robot_sim.json").read_text())["clipped_samples"]["gyro"]


def test_jittered_rows_are_the_instants_and_each_step_spans_its_own_period(tmp_path):
    """A log whose command rows come 30–33 ms apart is replayed at those rows (every reading at
    its own row, none lost to a collision on a grid), and an estimator told periods = "rows"
    integrates over each row's own period; a twin-like log on its grid stays on the grid."""
    from twin.logs.replay import rows_clock, schedule

    rs.generate(tmp_path / "b", "B", 3, version=2, duration=3.0)
    log = read_log(tmp_path / "b")
    assert rows_clock(log)
    sched = schedule(log)
    assert sched.rows and np.array_equal(sched.t, log.commands_t[: len(sched.t)])
    assert (sched.gyro >= 0).all() and np.array_equal(log.imu_t[sched.gyro], sched.t)
    gaps = np.diff(sched.t)
    assert gaps.min() >= 0.030 - 1e-9 and gaps.max() <= 0.033 + 1e-9 and gaps.max() > gaps.min()
    for kind in ("ekf", "complementary", "kalman2"):
        assert build_for(log, kind).periods == "rows"
    # the complementary filter integrates the gyro over each row's period: a constant rate read
    # at every row moves θ by rate × (t_N − t_0), not by rate × N / control_rate
    est = build_for(log, "complementary")
    from twin.sensors import Measurement

    est.start(Measurement(float(sched.t[0]), (0.0, 0.5, 0.0), (0.0, 0.0, 9.81), (0.0, 0.0)))
    for t in sched.t[1:]:
        out = est.step(Measurement(float(t), (0.0, 0.5, 0.0), None, (0.0, 0.0)), (0.0, 0.0))
    assert out[0] == pytest.approx(0.5 * (sched.t[-1] - sched.t[0]), rel=1e-9)
    # on a regular grid (profile A) nothing changes: the grid's instants, constant periods
    rs.generate(tmp_path / "a", "A", 0, duration=1.0, version=2)
    log_a = read_log(tmp_path / "a")
    assert not rows_clock(log_a) and not schedule(log_a).rows
    assert build_for(log_a, "ekf").periods == "constant"


def test_the_ekf_over_rows_on_a_regular_grid_is_the_ekf_over_constant_periods(logs_a):
    """periods = "rows" on rows that are on the grid: the same estimates as constant periods up
    to the rounding of t_k − t_{k−1} against 1 / control_rate."""
    log = read_log(logs_a[0])
    out = []
    for periods in ("constant", "rows"):
        est = build_for(log, "ekf")
        est.set_sampling(log.sampling, log.command_semantics, periods=periods)
        out.append(replay(log, est, "ekf").estimates)
    assert np.allclose(out[0], out[1], rtol=0.0, atol=1e-9), float(np.max(np.abs(out[0] - out[1])))
    with pytest.raises(Exception, match="periods"):
        build_for(log, "ekf").set_sampling("mean", "held", periods="jittered")

