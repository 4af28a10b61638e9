"""Brushed DC motor and PWM driver (twin/actuators/dc_motor.py), checked against the
motor equations L di/dt = V − R i − k_e ω, τ = k_t i, V = d V_s with k_t = k_e."""
import math

import numpy as np
import pytest

from twin.actuators.dc_motor import DEFAULT_MOTOR, DCMotorParams, MotorDriver
from twin.errors import TwinError

PARAM_SETS = [
    dict(),
    dict(supply_voltage=24.0, stall_torque=0.5, no_load_speed=80.0),
    dict(supply_voltage=6, stall_torque=3, no_load_speed=10, current_limit=2.0, pwm_bits=8),
]


def _physics(p: DCMotorParams):
    """k_t, R, c and the stall current derived by hand from V_s, τ_stall, ω_0."""
    kt = p.supply_voltage / p.no_load_speed  # no-load: V_s = k_e ω_0
    R = kt * p.supply_voltage / p.stall_torque  # stall: τ = k_t V_s / R
    return kt, R, kt * kt / R, p.supply_voltage / R


def _quantum_torque(p: DCMotorParams) -> float:
    """Largest torque error from rounding the duty: half a PWM step times τ_stall."""
    return 0.5 * p.stall_torque / (2**p.pwm_bits - 1) + 1e-12


# ---- parameters ---------------------------------------------------------------------

@pytest.mark.parametrize("kw", PARAM_SETS)
def test_derived_constants(kw):
    """k_t = V_s/ω_0, R = k_t V_s/τ_stall, i_stall = V_s/R = τ_stall/k_t, c = k_t²/R = τ_stall/ω_0."""
    p = DCMotorParams(**kw)
    kt, R, c, i_stall = _physics(p)
    assert p.k_t == pytest.approx(kt, rel=1e-12)
    assert p.resistance == pytest.approx(R, rel=1e-12)
    assert p.stall_current == pytest.approx(i_stall, rel=1e-12)
    assert p.stall_current == pytest.approx(p.stall_torque / kt, rel=1e-12)
    assert p.electrical_damping == pytest.approx(c, rel=1e-12)
    assert p.electrical_damping == pytest.approx(p.stall_torque / p.no_load_speed, rel=1e-12)
    assert p.pwm_steps == 2**p.pwm_bits - 1
    expected_imax = i_stall if p.current_limit is None else p.current_limit
    assert p.max_current == pytest.approx(expected_imax, rel=1e-12)


def test_default_motor_sizing():
    """The default 12 V / 1.2 N·m / 35 rad/s motor has k_t ≈ 0.343 N·m/A, R ≈ 3.43 Ω, 3.5 A stall."""
    p = DEFAULT_MOTOR
    assert (p.supply_voltage, p.stall_torque, p.no_load_speed) == (12.0, 1.2, 35.0)
    assert p.k_t == pytest.approx(0.343, abs=5e-4)
    assert p.resistance == pytest.approx(3.43, abs=5e-3)
    assert p.stall_current == pytest.approx(3.5, rel=1e-12)
    assert p.pwm_steps == 1023 and p.dead_band == 0.0 and p.inductance == 0.0
    assert p.back_emf_compensation is True and p.current_limit is None


@pytest.mark.parametrize("field, value", [
    ("supply_voltage", -12.0),
    ("supply_voltage", 0.0),
    ("supply_voltage", float("nan")),
    ("supply_voltage", "12"),
    ("stall_torque", 0),
    ("stall_torque", float("inf")),
    ("no_load_speed", -1.0),
    ("current_limit", 0.0),
    ("current_limit", -2.0),
    ("current_limit", float("nan")),
    ("pwm_bits", 0),
    ("pwm_bits", 25),
    ("pwm_bits", 10.0),
    ("dead_band", 1.0),
    ("dead_band", -0.1),
    ("dead_band", float("nan")),
    ("inductance", -1e-3),
    ("inductance", float("inf")),
])
def test_invalid_params_raise(field, value):
    """Non-physical motor/driver parameters raise TwinError naming the field."""
    with pytest.raises(TwinError, match=rf"^motor {field} ") as err:
        DCMotorParams(**{field: value})
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("field, value", [("current_limit", "5"), ("dead_band", "x"), ("inductance", None)])
def test_non_numeric_params_raise_twin_error(field, value):
    """A non-number for an optional numeric field is a TwinError naming the field."""
    with pytest.raises(TwinError, match=rf"motor {field}"):
        DCMotorParams(**{field: value})


@pytest.mark.parametrize("bad", [None, 12.0, {"supply_voltage": 12.0}])
def test_driver_rejects_non_params(bad):
    """MotorDriver needs a DCMotorParams."""
    with pytest.raises(TwinError, match="a motor driver needs DCMotorParams"):
        MotorDriver(bad)


# ---- duty: quantisation and saturation -------------------------------------------------

@pytest.mark.parametrize("bits", [1, 3, 8, 10, 16])
def test_duty_is_quantised(bits):
    """The duty is a multiple of 1/(2^bits − 1), the nearest one to the ideal duty R i*/V_s."""
    p = DCMotorParams(pwm_bits=bits, back_emf_compensation=False)
    drv = MotorDriver(p)
    steps = 2**bits - 1
    for frac in np.linspace(-0.99, 0.99, 37):
        cmd = frac * p.stall_torque  # ideal duty = τ*/τ_stall without compensation
        d, sat = drv.duty(cmd, 3.0)
        assert not sat
        assert d * steps == pytest.approx(round(d * steps), abs=1e-9)
        assert abs(d - frac) <= 0.5 / steps + 1e-12


@pytest.mark.parametrize("cmd_frac, omega_frac", [(0.8, 0.5), (0.3, 0.9), (1.0, 0.01), (0.5, 0.6)])
def test_duty_clips_when_supply_runs_out(cmd_frac, omega_frac):
    """With compensation the ideal duty is τ*/τ_stall + ω/ω_0; above 1 it clips to 1 and flags saturation."""
    p = DEFAULT_MOTOR
    assert cmd_frac + omega_frac > 1.0
    d, sat = MotorDriver(p).duty(cmd_frac * p.stall_torque, omega_frac * p.no_load_speed)
    assert d == 1.0 and sat


@pytest.mark.parametrize("cmd_frac, omega_frac", [(0.4, 0.5), (0.9, 0.0), (-0.6, 0.3), (0.2, -0.7)])
def test_duty_unsaturated_inside_supply_limit(cmd_frac, omega_frac):
    """A command the supply can deliver at that speed is not flagged and its duty is τ*/τ_stall + ω/ω_0."""
    p = DEFAULT_MOTOR
    d, sat = MotorDriver(p).duty(cmd_frac * p.stall_torque, omega_frac * p.no_load_speed)
    assert not sat
    assert d == pytest.approx(cmd_frac + omega_frac, abs=0.5 / p.pwm_steps + 1e-12)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_current_limit_caps_torque(sign):
    """With a current limit below the stall current, a big command at standstill gives k_t · limit."""
    limit = 1.0
    p = DCMotorParams(current_limit=limit)
    kt, R, _, i_stall = _physics(p)
    assert limit < i_stall
    drv = MotorDriver(p)
    d, sat = drv.duty(sign * 10.0 * p.stall_torque, 0.0)
    assert sat
    assert abs(d) < 1.0  # the voltage is not what cut it
    assert d == pytest.approx(sign * R * limit / p.supply_voltage, abs=0.5 / p.pwm_steps + 1e-12)
    assert drv.torque_at(d, 0.0) == pytest.approx(sign * kt * limit, abs=_quantum_torque(p))


def test_current_limit_above_stall_current_hits_supply():
    """A current limit above V_s/R still cannot exceed full duty: the supply saturates it."""
    p = DCMotorParams(current_limit=10.0, back_emf_compensation=False)
    d, sat = MotorDriver(p).duty(5.0, 0.0)
    assert d == 1.0 and sat


# ---- delivered torque --------------------------------------------------------------------

@pytest.mark.parametrize("cmd, omega", [(0.3, 10.0), (-0.4, 15.0), (0.5, -12.0), (0.1, 5.0), (-0.2, -8.0)])
def test_back_emf_compensation_delivers_command(cmd, omega):
    """With k_e ω added to the voltage, the steady torque at ω equals the command (up to quantisation)."""
    p = DEFAULT_MOTOR
    drv = MotorDriver(p)
    d, sat = drv.duty(cmd, omega)
    assert not sat
    assert drv.torque_at(d, omega) == pytest.approx(cmd, abs=_quantum_torque(p))


@pytest.mark.parametrize("cmd, omega", [(0.3, 10.0), (-0.4, 15.0), (0.5, -12.0), (0.8, 30.0)])
def test_without_compensation_torque_loses_damping(cmd, omega):
    """Without compensation the steady torque is τ* − c ω with c = k_t²/R."""
    p = DCMotorParams(back_emf_compensation=False)
    _, _, c, _ = _physics(p)
    drv = MotorDriver(p)
    d, sat = drv.duty(cmd, omega)
    assert not sat
    assert drv.torque_at(d, omega) == pytest.approx(cmd - c * omega, abs=_quantum_torque(p))


@pytest.mark.parametrize("kw", PARAM_SETS)
def test_full_duty_speed_torque_curve(kw):
    """At full duty the torque falls linearly from τ_stall at rest to 0 at the no-load speed."""
    p = DCMotorParams(**kw)
    drv = MotorDriver(p)
    w0 = p.no_load_speed
    assert drv.torque_at(1.0, 0.0) == pytest.approx(p.stall_torque, rel=1e-12)
    assert drv.torque_at(1.0, w0) == pytest.approx(0.0, abs=1e-12)
    for w in np.linspace(-0.5 * w0, 1.5 * w0, 9):
        assert drv.torque_at(1.0, w) == pytest.approx(p.stall_torque * (1.0 - w / w0), rel=1e-12, abs=1e-12)
    assert drv.torque_at(-1.0, -w0) == pytest.approx(0.0, abs=1e-12)


def test_max_command_follows_speed_torque_curve():
    """A huge command at speed ω in (0, ω_0) gets full duty, hence τ_stall (1 − ω/ω_0), never more."""
    p = DEFAULT_MOTOR
    drv = MotorDriver(p)
    for w in np.linspace(0.0, p.no_load_speed, 6)[1:]:
        d, sat = drv.duty(100.0, w)
        assert d == 1.0 and sat
        assert drv.torque_at(d, w) == pytest.approx(p.stall_torque * (1 - w / p.no_load_speed), abs=1e-12)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_dead_band_zeroes_small_duty(sign):
    """Ideal duties inside the dead band give zero; just outside, the (quantised) duty passes."""
    p = DCMotorParams(dead_band=0.2, back_emf_compensation=False)
    drv = MotorDriver(p)
    assert drv.duty(sign * 0.1 * p.stall_torque, 0.0) == (0.0, False)
    assert drv.duty(sign * 0.199 * p.stall_torque, 0.0)[0] == 0.0
    d, _ = drv.duty(sign * 0.3 * p.stall_torque, 0.0)
    assert d == pytest.approx(sign * 0.3, abs=0.5 / p.pwm_steps + 1e-12)


def test_zero_dead_band_passes_smallest_step():
    """Without a dead band, a command worth one PWM step yields that step."""
    p = DCMotorParams(back_emf_compensation=False)
    d, _ = MotorDriver(p).duty(p.stall_torque / p.pwm_steps, 0.0)
    assert d == pytest.approx(1.0 / p.pwm_steps, rel=1e-12)


@pytest.mark.parametrize("kw", [dict(), dict(back_emf_compensation=False), dict(current_limit=1.0),
                                dict(dead_band=0.15, pwm_bits=4)])
@pytest.mark.parametrize("cmd, omega", [(0.3, 10.0), (1.0, 25.0), (5.0, 0.0), (0.05, 1.0), (0.7, -20.0)])
def test_negative_command_is_mirror(kw, cmd, omega):
    """The motor is odd-symmetric: (−τ*, −ω) gives (−d, same saturation) and the opposite torque."""
    drv = MotorDriver(DCMotorParams(**kw))
    d, sat = drv.duty(cmd, omega)
    dn, satn = drv.duty(-cmd, -omega)
    assert dn == -d and satn == sat
    assert drv.torque_at(dn, -omega) == pytest.approx(-drv.torque_at(d, omega), abs=1e-12)


@pytest.mark.parametrize("cmd, omega", [(0.3, 10.0), (2.0, 20.0), (-0.5, 4.0)])
def test_update_splits_torque_into_stall_part_and_damping(cmd, omega):
    """update() gives τ_0 = k_t d V_s/R = d τ_stall and τ = τ_0 − c ω = torque_at(d, ω)."""
    p = DEFAULT_MOTOR
    _, _, c, _ = _physics(p)
    drv = MotorDriver(p)
    d, sat, tau0, tau = drv.update(cmd, omega)
    assert (d, sat) == drv.duty(cmd, omega)
    assert tau0 == pytest.approx(d * p.stall_torque, rel=1e-12)
    assert drv.stall_part(d) == pytest.approx(d * p.stall_torque, rel=1e-12)
    assert tau == pytest.approx(tau0 - c * omega, rel=1e-12, abs=1e-12)
    assert tau == pytest.approx(drv.torque_at(d, omega), rel=1e-12, abs=1e-12)


# ---- electrical lag -----------------------------------------------------------------------

@pytest.mark.parametrize("i0, duty, omega, dt", [(0.0, 0.5, 10.0, 1e-3), (3.0, -0.2, 0.0, 1e-4), (-1.0, 1.0, 35.0, 0.01)])
def test_current_step_without_inductance_is_steady_state(i0, duty, omega, dt):
    """With L = 0 the current jumps to i_ss = (d V_s − k_e ω)/R, and k_t i_ss is the steady torque."""
    p = DEFAULT_MOTOR
    kt, R, _, _ = _physics(p)
    drv = MotorDriver(p)
    i_ss = (duty * p.supply_voltage - kt * omega) / R
    i = drv.current_step(i0, duty, omega, dt)
    assert i == pytest.approx(i_ss, rel=1e-12, abs=1e-12)
    assert kt * i == pytest.approx(drv.torque_at(duty, omega), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("L", [1e-4, 1e-3, 5e-3])
@pytest.mark.parametrize("i0, duty, omega, dt", [(0.0, 0.5, 10.0, 1e-3), (3.0, -0.2, 0.0, 2e-4), (-1.0, 1.0, 20.0, 5e-3)])
def test_current_step_exact_exponential(L, i0, duty, omega, dt):
    """With L > 0 the current is i_ss + (i0 − i_ss) exp(−t R/L)."""
    p = DCMotorParams(inductance=L)
    kt, R, _, _ = _physics(p)
    i_ss = (duty * p.supply_voltage - kt * omega) / R
    expected = i_ss + (i0 - i_ss) * math.exp(-dt * R / L)
    assert MotorDriver(p).current_step(i0, duty, omega, dt) == pytest.approx(expected, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("i0, duty, omega, dt", [(0.0, 0.5, 10.0, 1e-3), (3.0, -0.2, 0.0, 2e-4), (-1.0, 1.0, 20.0, 5e-3)])
def test_current_step_half_steps_compose(i0, duty, omega, dt):
    """For constant V and ω, two half steps equal one full step (exact flow of a linear ODE)."""
    drv = MotorDriver(DCMotorParams(inductance=1e-3))
    half = drv.current_step(drv.current_step(i0, duty, omega, dt / 2), duty, omega, dt / 2)
    assert half == pytest.approx(drv.current_step(i0, duty, omega, dt), rel=1e-12, abs=1e-12)


def test_current_step_time_constant():
    """After one time constant L/R the gap to steady state shrinks by e; after 50 it is gone."""
    p = DCMotorParams(inductance=2e-3)
    kt, R, _, _ = _physics(p)
    drv = MotorDriver(p)
    i_ss = 0.6 * p.supply_voltage / R
    tau_e = p.inductance / R
    assert drv.current_step(0.0, 0.6, 0.0, tau_e) == pytest.approx(i_ss * (1 - math.exp(-1)), rel=1e-12)
    assert drv.current_step(0.0, 0.6, 0.0, 50 * tau_e) == pytest.approx(i_ss, rel=1e-12)
    assert drv.current_step(1.234, 0.6, 0.0, 0.0) == pytest.approx(1.234, rel=1e-12)


@pytest.mark.parametrize("L", [0.0, 1e-3])
def test_current_mean_is_time_average(L):
    """current_mean over dt is the time average of the exact current trajectory."""
    drv = MotorDriver(DCMotorParams(inductance=L))
    i0, duty, omega, dt = 2.0, 0.3, 12.0, 1e-3
    t = np.linspace(0.0, dt, 4001)
    traj = np.array([drv.current_step(i0, duty, omega, s) for s in t])
    avg = np.sum(0.5 * (traj[1:] + traj[:-1]) * np.diff(t)) / dt
    assert drv.current_mean(i0, duty, omega, dt) == pytest.approx(avg, rel=1e-6)
