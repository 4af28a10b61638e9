"""The independent simulator kept as a fixture (tests/foreign/robot_sim.py, issue 40): it shares no
code with the twin, the twin reads its logs, and its data and dynamics are physically right.

What is checked here is the generator itself (the twin's estimators on its logs are measured by
``benchmarks/foreign_logs.py``): that it imports nothing of ``twin`` or ``estimation``; that
``twin.logs.format.read_log`` reads both profiles with the state truth on every replay instant;
that its readings agree with each other and with what it was told to do (the gyro's pitch rate
integrated into the gravity the accelerometer feels matches the IMU point's speed from the
encoders; the encoders follow the commanded drives and turns); that RK4 conserves the energy
of equation (1) without damping or inputs, at fourth order, and the energy changes by exactly
the inputs' and the damping's work otherwise; and that its linearisation at upright has
paper-notes' A1 eigenvalues.
"""
from __future__ import annotations

import ast
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # tests/ (for the foreign package), as pytest's rootdir-relative import does

from foreign import robot_sim as rs  # noqa: E402

SIM = HERE / "foreign" / "robot_sim.py"


@pytest.fixture(scope="module")
def log_a(tmp_path_factory):
    """A profile-A log of 20 s (seed 3: drives, turns, three pushes) and its SimResult."""
    out = tmp_path_factory.mktemp("foreign") / "a3"
    return out, rs.generate(out, "A", 3)


@pytest.fixture(scope="module")
def log_b(tmp_path_factory):
    """A profile-B log (seed 0): a stand-up from 0.53 rad, 33 Hz rows of a 1 kHz loop, voltages."""
    out = tmp_path_factory.mktemp("foreign") / "b0"
    return out, rs.generate(out, "B", 0)


# ---- no code of the twin --------------------------------------------------------------------------
def test_the_generator_imports_no_module_of_twin_or_estimation(tmp_path):
    code = (f"import sys\nsys.path.insert(0, {str(HERE)!r})\n"
            f"from foreign import robot_sim\n"
            f"robot_sim.generate({str(tmp_path / 'a')!r}, 'A', 1, duration=2.0)\n"
            f"robot_sim.generate({str(tmp_path / 'b')!r}, 'B', 1, duration=2.0)\n"
            f"bad = sorted(m for m in sys.modules if m.split('.')[0] in ('twin', 'estimation'))\n"
            f"print(','.join(bad))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"the generator imported {out.stdout.strip()}"
    assert (tmp_path / "a" / "log.toml").is_file() and (tmp_path / "b" / "robot_sim.json").is_file()


def test_the_generator_source_imports_only_numpy_scipy_and_the_standard_library():
    allowed = set(sys.stdlib_module_names) | {"numpy", "scipy"}
    for path in (SIM, SIM.parent / "__init__.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""] if node.level == 0 else []
            else:
                continue
            for name in names:
                assert name.split(".")[0] in allowed, f"{path.name} imports {name}"


# ---- the twin reads its logs ------------------------------------------------------------------------
def test_the_twin_reads_profile_a_with_the_state_truth_on_every_instant(log_a):
    from twin.logs.format import read_log
    from twin.logs.replay import schedule, state_truth

    path, res = log_a
    log = read_log(path)
    assert log.control_rate == 200.0 and log.counts_per_rev == 1440
    assert len(log.imu_t) == len(log.commands_t) == len(log.encoders_t) == 4001
    assert log.model.m_b == rs.TABLE_III.m_b and log.model.l == rs.TABLE_III.l  # the owner's nominal plant
    assert res.spec.plant.m_b == pytest.approx(1.15 * log.model.m_b)  # not the true one
    assert log.truth_constants["gyro_scale"] == pytest.approx(res.constants["gyro_scale"], abs=0)
    assert state_truth(log, schedule(log).t) is not None  # the EKF's NEES can be computed
    np.testing.assert_allclose(log.truth[:, 0], res.states[::5, 0], rtol=0, atol=0)
    # the state truth means what the twin's NEES takes it to mean: counts = floor((q − q(t_0)) c + φ)
    # with q_j = ψ_j − θ from the truth's wheel angles and φ the [truth] table's encoder_phase, and
    # ψ_r − ψ_l = (2b/r)(α − α_0)
    q = log.truth_state[:, :2] - log.truth[:, [0]]
    c = log.counts_per_rev / (2.0 * math.pi)
    want = np.floor((q - q[0]) * c + np.array(log.truth_constants["encoder_phase"]))
    assert np.array_equal(log.counts, want.astype(np.int64))
    b_over_r = res.spec.plant.b / res.spec.plant.r
    np.testing.assert_allclose(log.truth_state[:, 1] - log.truth_state[:, 0], 2.0 * b_over_r * log.truth[:, 4],
                               atol=1e-12)


def test_the_twin_reads_profile_b_a_decimated_log_of_sampled_voltages(log_b):
    import json

    from twin.logs.format import read_log
    from twin.logs.replay import schedule, state_truth

    path, res = log_b
    log = read_log(path)
    assert log.control_rate == pytest.approx(1000.0 / 30.0)
    gaps = np.round(np.diff(log.commands_t) * 1000.0).astype(int)
    assert set(gaps.tolist()) <= {30, 31, 32, 33} and len(set(gaps.tolist())) > 1  # jittered rows
    assert log.motor is not None and log.motor.supply_voltage == 12.0
    assert np.abs(log.commands).max() <= log.motor.stall_torque + 1e-12  # duty × stall torque
    assert log.truth[0, 0] > 0.4  # it starts lying
    assert state_truth(log, schedule(log).t) is not None
    side = json.loads((path / "robot_sim.json").read_text())
    assert side["imu"]["mount_pitch"] == 0.07 and side["imu"]["sampling"] == "point"
    assert side["commands"]["semantics"] == "sampled" and side["commands"]["unit"] == "V"


# ---- physical checks on the data ---------------------------------------------------------------------
def _velocity_check(imu_t, gyro_y, accel_x, enc_t, counts, t1, t2, r, pz, cpr, T, g=rs.GRAVITY):
    """Over [t1, t2]: the IMU point's forward speed from the encoders and the gyro,
    v = r (q̄̇ + θ̇) + p_z θ̇, less its value at t1, against ∫ (a_x + g sin θ) dt with θ the gyro's
    integral (a_x = r ψ̈ cosθ + p_z θ̈ − g sinθ + small terms). The unknown start tilt θ1 and gyro
    bias b enter linearly (g θ1 t and −g b t²/2) and are fitted with an offset. Returns (the
    residual's RMS m/s, the speed's spread m/s, the fitted b rad/s)."""
    m = (imu_t > t1) & (imu_t <= t2)
    ts = imu_t[m] - T  # each reading is the mean over the interval ending one period before its arrival
    w, f = gyro_y[m], accel_x[m]
    th = np.cumsum(w * T)
    qbar = counts.mean(axis=1) * 2.0 * math.pi / cpr
    h = 0.025  # s: the encoders' speed over 50 ms
    qd = (np.interp(ts + h, enc_t, qbar) - np.interp(ts - h, enc_t, qbar)) / (2.0 * h)
    thd = np.convolve(w, np.ones(10) / 10.0, mode="same")  # the gyro over the same 50 ms
    v = r * (qd + thd) + pz * thd
    tt = ts - ts[0] + T
    y = (v - v[0]) - np.cumsum((f + g * np.sin(th)) * T)
    A = np.column_stack([g * tt, -0.5 * g * tt * tt, np.ones_like(tt)])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    resid = (y - A @ coef)[10:-10]  # (the ends lack a whole encoder window)
    return float(resid.std()), float((v - v[0]).std()), float(coef[1])


def test_the_gyro_integrates_to_the_tilt_the_accelerometer_feels(log_a):
    from twin.logs.format import read_log

    path, res = log_a
    log = read_log(path)
    spec = res.spec
    pushes = [(p.start, p.start + p.duration) for p in spec.pushes]
    t1, t2 = 2.0, 7.5  # a drive and a turn, no push, nothing clipped
    assert not any(a < t2 and b > t1 for a, b in pushes) and res.clipped == {"gyro": [0] * 3, "accel": [0] * 3}
    args = (log.imu_t, log.gyro[:, 1], log.accel[:, 0], log.encoders_t, log.counts.astype(float), t1, t2,
            log.model.r, log.sensors.imu.position[2], log.counts_per_rev, 1.0 / log.control_rate)
    resid, spread, bias = _velocity_check(*args)
    assert spread > 0.05, "the stretch should move the robot"
    assert resid < 0.1 * spread and resid < 0.01, (resid, spread)
    # the fitted gyro bias is the true one (the scale factor and the tilt's nonlinearity aside)
    assert bias == pytest.approx(res.constants["gyro_bias"][1], abs=2e-3)
    # the check can fail: the gyro's sign flipped, or the accelerometer's, the speeds do not match
    flipped, _, _ = _velocity_check(log.imu_t, -log.gyro[:, 1], *args[2:])
    assert flipped > 10 * resid
    flipped, _, _ = _velocity_check(log.imu_t, log.gyro[:, 1], -log.accel[:, 0], *args[3:])
    assert flipped > 10 * resid


def test_the_encoders_follow_the_commanded_drives_and_turns(log_a):
    from twin.logs.format import read_log

    path, res = log_a
    log = read_log(path)
    nom = res.spec.nominal
    q = log.counts.astype(float) * 2.0 * math.pi / log.counts_per_rev
    pos = nom.r * q.mean(axis=1)  # distance travelled (r ψ less r θ: θ stays within 0.2 rad)
    heading = res.spec.initial[4] + nom.r / (2.0 * nom.b) * (q[:, 1] - q[:, 0])
    ref = np.array([np.interp(log.encoders_t, res.ref_t, res.ref[:, j]) for j in range(4)]).T
    assert np.ptp(ref[:, 0]) > 0.3 and np.ptp(ref[:, 2]) > 1.0, "the schedule should drive and turn"
    # after each target is reached the robot stands there; allow the controller's lag of about 2 s
    settled = np.zeros(len(ref), bool)
    for k in range(len(ref)):
        j = np.searchsorted(log.encoders_t, log.encoders_t[k] - 2.0)
        settled[k] = j < k and np.ptp(ref[j:k + 1, 0]) < 1e-9 and np.ptp(ref[j:k + 1, 2]) < 1e-9
    assert settled.sum() > 500
    assert np.abs(pos - ref[:, 0])[settled].max() < 0.05  # m
    assert np.abs(heading - ref[:, 2])[settled].max() < 0.05  # rad
    # speeds while the reference drives at its limit: the encoders' speed is the commanded one
    v_enc = np.gradient(pos, log.encoders_t)
    driving = np.abs(ref[:, 1]) > 0.99 * res.spec.controller.drive_speed
    assert driving.sum() > 100
    lag = int(0.5 * log.control_rate)  # the robot follows the reference about 0.5 s late
    v_mean = np.convolve(v_enc, np.ones(40) / 40.0, mode="same")
    ok = np.flatnonzero(driving)
    ok = ok[ok + lag < len(v_mean)]
    assert np.corrcoef(v_mean[ok + lag], ref[ok, 1])[0, 1] > 0.8
    # the check can fail: the encoders swapped left for right turn the other way
    swapped = res.spec.initial[4] + nom.r / (2.0 * nom.b) * (q[:, 0] - q[:, 1])
    assert np.abs(swapped - ref[:, 2])[settled].max() > 0.5


def test_the_imu_reads_gravity_and_its_mounting_as_the_log_format_says():
    dyn = rs.Dynamics(rs.TABLE_III, imu_position=(0.0, 0.0, 0.1))
    f, w = dyn.imu_true((0.0,) * 6, (0.0, 0.0, 0.0))
    assert f == pytest.approx((0.0, 0.0, rs.GRAVITY)) and w == pytest.approx((0.0, 0.0, 0.0))
    f, _ = dyn.imu_true((0.2, 0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # at rest leaning forward
    assert f == pytest.approx((-rs.GRAVITY * math.sin(0.2), 0.0, rs.GRAVITY * math.cos(0.2)))
    _, w = dyn.imu_true((0.3, 1.5, 0.0, 0.0, 0.0, 0.7), (0.0, 0.0, 0.0))  # pitching forward, turning left
    assert w == pytest.approx((-0.7 * math.sin(0.3), 1.5, 0.7 * math.cos(0.3)))
    # a mount pitched β reads a body at rest upright as one pitched β forward
    beta = 0.07
    assert rs._imu_rotation(beta) @ np.array([0.0, 0.0, 1.0]) == pytest.approx([-math.sin(beta), 0.0, math.cos(beta)])
    # the forward acceleration of the wheels and the body's pitch acceleration add at the IMU point
    f, _ = dyn.imu_true((0.0,) * 6, (10.0, 2.0, 0.0))
    assert f[0] == pytest.approx(rs.TABLE_III.r * 2.0 + 0.1 * 10.0)
    # driving forward while turning left: the centripetal acceleration points left (+y)
    f, _ = dyn.imu_true((0.0, 0.0, 0.0, 10.0, 0.0, 1.0), (0.0, 0.0, 0.0))
    assert f[1] == pytest.approx(rs.TABLE_III.r * 10.0 * 1.0)


def test_a_gear_motor_gives_its_stall_torque_standing_and_none_at_its_no_load_speed():
    m = rs.B_MOTOR
    assert m.torque(m.supply, 0.0) == pytest.approx(m.stall_torque)
    assert m.torque(m.supply, m.no_load_speed) == pytest.approx(0.0, abs=1e-12)
    assert m.torque(0.0, 10.0) < 0.0  # back-EMF brakes a wheel turning forward
    dyn = rs.Dynamics(rs.B_PLANT, m)
    tl, tr = dyn.torques((0.0, 0.0, 0.0, 5.0, 0.0, 0.0), 20.0, -20.0)  # volts beyond the supply are clipped
    assert tl == pytest.approx(m.torque(m.supply, 5.0)) and tr == pytest.approx(m.torque(-m.supply, 5.0))
    # the speed is each wheel's relative to the body: ψ̇_j − θ̇, ψ̇_{l,r} = ψ̇ ∓ (b/r) α̇
    bor = rs.B_PLANT.b / rs.B_PLANT.r
    tl, tr = dyn.torques((0.0, 2.0, 0.0, 5.0, 0.0, 0.5), 3.0, 3.0)
    assert tl == pytest.approx(m.torque(3.0, 5.0 - bor * 0.5 - 2.0))
    assert tr == pytest.approx(m.torque(3.0, 5.0 + bor * 0.5 - 2.0))


# ---- the dynamics ----------------------------------------------------------------------------------------
def _energy_error(plant, s0, h, seconds=2.0):
    dyn = rs.Dynamics(plant)
    e0, s, worst = rs.energy(plant, s0), s0, 0.0
    for _ in range(round(seconds / h)):
        s, _ = dyn.step(s, h, 0.0, 0.0)
        worst = max(worst, abs(rs.energy(plant, s) - e0))
    return worst / e0, s


def test_rk4_conserves_the_energy_of_equation_1_without_damping_or_inputs():
    plant = rs.PlantParams(d_b=0.0, d_w=0.0)
    s0 = (0.3, 1.0, 0.0, 2.0, 0.0, 1.5)  # falls over and spins, turning: every coupling term at work
    e1, s1 = _energy_error(plant, s0, 1e-3)
    e2, _ = _energy_error(plant, s0, 2e-3)
    assert e1 < 1e-5, e1
    assert e2 / e1 > 12.0, (e1, e2)  # RK4's order: halving the step divides the error by 2⁴ or more
    assert abs(s1[0] - s0[0]) > 3.0  # (it did fall over and spin)
    # the check can fail: damping takes energy out well beyond RK4's error
    ed, _ = _energy_error(rs.TABLE_III, s0, 1e-3)
    assert ed > 100 * e1


def test_the_energy_changes_by_the_work_of_the_inputs_push_and_damping():
    plant = rs.TABLE_III.scaled(d_b=3.0, d_w=2.0)
    dyn = rs.Dynamics(plant)
    push = rs.Push(0.05, 0.2, 6.0)
    tl, tr = 0.05, -0.03  # N·m, held
    h, s, t = 1e-3, (0.1, 0.5, 0.0, 1.0, 0.0, 0.8), 0.0
    e0, work = rs.energy(plant, s), 0.0
    bor, yaw = plant.b / plant.r, 2.0 * (plant.b / plant.r) ** 2 * (plant.d_b + plant.d_w)

    def power(s, t):
        th, thd, _, psd, _, ald = s
        inputs = ((tl + tr) * (psd - thd) + (tr - tl) * bor * ald
                  + push.at(t) * (plant.r * psd + plant.l * math.cos(th) * thd))
        damping = 2.0 * plant.d_w * psd ** 2 + 2.0 * plant.d_b * (psd - thd) ** 2 + yaw * ald ** 2
        return inputs - damping

    for _ in range(400):
        p0 = power(s, t)
        mid, _ = dyn.step(s, 0.5 * h, tl, tr, push.at, t)
        s_new, _ = dyn.step(s, h, tl, tr, push.at, t)
        work += h / 6.0 * (p0 + 4.0 * power(mid, t + 0.5 * h) + power(s_new, t + h))  # Simpson
        s, t = s_new, t + h
    change = rs.energy(plant, s) - e0
    assert abs(change) > 0.01
    assert change == pytest.approx(work, rel=1e-4, abs=1e-7)


def test_the_linearisation_at_upright_has_paper_notes_a1_eigenvalues():
    A, B = rs.linearise(rs.TABLE_III)
    eig = np.sort(np.linalg.eigvals(A).real)
    np.testing.assert_allclose(eig, [-35.01, -4.06, 0.0, 18.07], atol=0.01)
    # and paper-notes' A1 and B1 themselves, from Table III
    d = rs.TABLE_III.derived()
    m11, m12, m22, gb = d["m11"], d["m12"], d["m22"], d["g_b"]
    db, dw = rs.TABLE_III.d_b, rs.TABLE_III.d_w
    D = m11 * m22 - m12 ** 2
    A1 = np.array([[0, 1, 0, 0], [m11 * gb / D, -2 * db * (m11 + m12) / D, 0, 2 * (m12 * dw + db * (m11 + m12)) / D],
                   [0, 0, 0, 1], [-m12 * gb / D, 2 * db * (m12 + m22) / D, 0, -2 * (m22 * dw + db * (m12 + m22)) / D]])
    B1 = np.array([[0], [-(m11 + m12) / D], [0], [(m12 + m22) / D]])
    np.testing.assert_allclose(A, A1, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(B, B1, rtol=1e-6)
    # the check can fail: another plant has other eigenvalues
    other = np.sort(np.linalg.eigvals(rs.linearise(rs.TABLE_III.scaled(l=0.9))[0]).real)
    assert abs(other[-1] - 18.07) > 0.1


def test_a_torque_difference_turns_the_robot_with_the_yaw_inertia_of_the_notes():
    p = rs.TABLE_III
    # J(θ) = m33 + n_bla sin²θ, m33 = n_zb + 2 n_wd + (2b²/r²)(n_wa + m_w r²), n_bla = m_b l² + n_xb − n_zb, n_xb = n_yb
    m33 = 0.00128 + 2 * 0.00054 + (2 * 0.15 ** 2 / 0.04 ** 2) * (0.00014 + 0.14 * 0.04 ** 2)
    n_bla = 2.58 * 0.0622 ** 2 + 0.00128 - 0.00128
    for th in (0.0, 0.4):
        _, _, aldd = rs.Dynamics(p).accelerations((th, 0.0, 0.0, 0.0, 0.0, 0.0), -0.1, 0.1)
        assert aldd == pytest.approx((0.15 / 0.04) * 0.2 / (m33 + n_bla * math.sin(th) ** 2), rel=1e-12)
    # the check can fail: another roll inertia is another J(θ) away from upright
    _, _, aldd = rs.Dynamics(rs.PlantParams(n_xb=0.00256)).accelerations(
        (0.4, 0.0, 0.0, 0.0, 0.0, 0.0), -0.1, 0.1)
    assert aldd != pytest.approx((0.15 / 0.04) * 0.2 / (m33 + n_bla * math.sin(0.4) ** 2), rel=1e-3)


def test_a_seed_determines_the_log_and_another_seed_changes_it(tmp_path):
    files = ("imu.csv", "encoders.csv", "commands.csv", "truth.csv", "log.toml", "robot_sim.json")
    a, b, c = (tmp_path / n for n in "abc")
    rs.generate(a, "A", 5, duration=1.0)
    rs.generate(b, "A", 5, duration=1.0)
    rs.generate(c, "A", 6, duration=1.0)
    assert all((a / f).read_bytes() == (b / f).read_bytes() for f in files)
    assert (a / "imu.csv").read_bytes() != (c / "imu.csv").read_bytes()


def test_without_scale_factors_every_true_scale_factor_is_zero(tmp_path):
    res = rs.generate(tmp_path / "z", "A", 2, duration=1.0, scale_sigma=0.0)
    assert res.constants["gyro_scale"] == [0.0] * 3 and res.constants["accel_scale"] == [0.0] * 3
    res = rs.generate(tmp_path / "s", "A", 2, duration=1.0)
    assert min(abs(v) for v in res.constants["gyro_scale"] + res.constants["accel_scale"]) > 0.0


# ---- version 2 of the log format ------------------------------------------------------------------
def test_version_2_says_what_version_1_cannot_and_the_rows_are_the_same(tmp_path):
    """Version 2 states profile B as it is (point samples decimated to the rows, an IMU pitched
    0.07 rad, volts sampled at each row, the row's true noise), the twin's reader applies it (the
    readings in body axes feel gravity on z at rest), and the rows are version 1's but for the
    commands' unit; without noise figures the reader falls back on the preset's datasheet noise."""
    from twin.logs.format import read_log

    v1, v2, v2q = tmp_path / "v1", tmp_path / "v2", tmp_path / "v2q"
    res = rs.generate(v1, "B", 2, duration=3.0)
    rs.write_log(res, v2, version=2)
    rs.write_log(res, v2q, version=2, noise_figures=False)
    assert (v1 / "imu.csv").read_bytes() == (v2 / "imu.csv").read_bytes()
    a, b = read_log(v1), read_log(v2)
    assert (a.version, b.version) == (1, 2)
    assert (b.sampling, b.command_unit, b.command_semantics) == ("point", "V", "sampled")
    assert b.imu_rotation is not None and b.imu_rotation[0][2] == pytest.approx(math.sin(0.07), abs=1e-12)
    sg, sa = rs._row_sigma(res.spec.imu, b.control_rate)
    rate = b.sensors.imu.rate
    assert b.sensors.imu.gyro.noise_density * math.sqrt(rate) == pytest.approx(sg, rel=1e-12)
    assert b.sensors.imu.accel.noise_density * math.sqrt(rate) == pytest.approx(sa, rel=1e-12)
    assert sg > 0.04 and sa > 0.5  # the vibration, not the datasheet's 0.0087 rad/s / 0.12 m/s² at 1 kHz
    q = read_log(v2q)
    assert "noise_density" in " ".join(q.format_info["assumed"].get("imu.gyro", []))
    assert q.sensors.imu.gyro.noise_density == pytest.approx(rs.ImuModel().gyro_density, rel=1e-12)
    # the first row is of the robot lying still at θ_0: in body axes the specific force is g (−sin θ, 0, cos θ)
    th = res.spec.initial[0]
    first = b.accel[0]
    assert first[0] == pytest.approx(-9.81 * math.sin(th), abs=2.5)  # 4 σ of the row's 0.6 m/s² vibration
    assert first[2] == pytest.approx(9.81 * math.cos(th), abs=2.5)
    raw = a.accel[0]  # version 1 cannot turn the IMU's axes: 0.07 rad off
    assert abs(math.atan2(-raw[0], raw[2]) - math.atan2(-first[0], first[2]) - 0.07) < 1e-9
    # the commands: volts in version 2, the duty V / supply in version 1, the same torques
    assert np.allclose(a.commands, b.commands, rtol=0, atol=1e-12)


def test_version_2_of_profile_a_is_a_complete_manifest(tmp_path):
    from twin.logs.format import read_log

    rs.generate(tmp_path / "a", "A", 1, duration=1.0, version=2)
    log = read_log(tmp_path / "a")
    assert log.version == 2 and log.format_info["assumed"] == {}
    assert log.sensors.imu.latency == 0.005 and log.sampling == "mean" and log.imu_rotation is None
    assert log.sensors.imu.gyro.noise_density == rs.ImuModel().gyro_density
    with pytest.raises(ValueError):
        rs.write_log(rs.simulate(rs.profile_a(1, duration=0.1)), tmp_path / "x", version=3)
