"""Brushed DC motor and its PWM driver, one per wheel: what turns a torque command into
the torque the wheel actually receives.

Electrical model (SI units; the motor drives the wheel directly, as in the paper)::

    L di/dt = V − R i − k_e ω,   τ = k_t i,   V = d · V_s

with ω the shaft speed relative to the body (the wheel joint rate ψ̇ − θ̇, rad/s), d the
PWM duty in [−1, 1], V_s the supply voltage. In SI units k_t = k_e (N·m/A = V·s/rad).

Driver (runs at the control rate, as the microcontroller's PWM update does):

1. current command i* = τ* / k_t, limited to ±``current_limit`` (A) (the limit acts on the
   command; between updates the current follows the motor equation, with no clamp);
2. voltage V* = R i* (+ k_e ω_k with ``back_emf_compensation``, ω_k the shaft speed
   measured at the update), duty d = V* / V_s clipped to [−1, 1] (the supply limit, the
   back-EMF speed–torque curve), zeroed inside the ``dead_band`` and quantised to the
   PWM resolution (2^bits − 1 steps per direction);
3. the duty is held until the next update.

Between updates, with no inductance, the torque is affine in the shaft speed:
τ(ω) = k_t (V − k_e ω) / R = τ_0 − c ω with the electrical damping c = k_t k_e / R.
The twin hands τ_0 to PyBullet as the joint torque and c to its joint damping, so the
speed–torque curve acts at every physics step inside the engine. A non-zero inductance
adds the electrical lag; its time constant L/R (0.3 ms for 1 mH) is shorter than the 1 ms
physics step, which is why the default leaves it off; when on, the twin integrates the
current exactly per physics step (slower).

The current the motor draws at an instant (what a shunt amplifier measures,
:mod:`twin.sensors.motor_current`) is :func:`steady_current` of the duty held and the shaft
speed then (the current itself, per physics step, with inductance).

Defaults: a 12 V brushed motor sized for this robot: 1.2 N·m stall torque per wheel
(gravity needs m_b g l sin 0.5 ≈ 0.75 N·m in total to hold the body at 0.5 rad), 35 rad/s
no-load speed (1.4 m/s on r = 4 cm), so k_t = k_e = 0.343 N·m/A, R = 3.43 Ω, stall
current 3.5 A; 10-bit PWM (a 20 kHz PWM from a 16–72 MHz microcontroller timer has 800–3600 counts); no dead band; back-EMF compensation on (the firmware adds
k_e ω from the encoder, so a torque command is delivered until the voltage runs out).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from twin.errors import TwinError
from twin.validation import bounded_number


@dataclass(frozen=True)
class DCMotorParams:
    """Motor and driver parameters (see the module docstring). Units in the field comments."""

    supply_voltage: float = 12.0  # V
    stall_torque: float = 1.2  # N·m at the supply voltage
    no_load_speed: float = 35.0  # rad/s at the supply voltage
    current_limit: float | None = None  # A; None: the stall current
    pwm_bits: int = 10  # duty resolution: 2**bits − 1 steps per direction
    dead_band: float = 0.0  # |duty| below this gives no voltage (static friction, driver dead time)
    inductance: float = 0.0  # H; 0 leaves out the electrical lag
    back_emf_compensation: bool = True

    def __post_init__(self):
        def number(name, lo, hi, lo_open=False, unit=""):
            object.__setattr__(self, name, bounded_number("motor", name, getattr(self, name), lo, hi, unit, lo_open))

        number("supply_voltage", 0.0, 1e4, True, "V")
        number("stall_torque", 0.0, 1e4, True, "N·m")
        number("no_load_speed", 0.0, 1e5, True, "rad/s")
        if self.current_limit is not None:
            number("current_limit", 0.0, 1e5, True, "A")
        if not (isinstance(self.pwm_bits, int) and not isinstance(self.pwm_bits, bool) and 1 <= self.pwm_bits <= 24):
            raise TwinError(f"motor pwm_bits must be an integer from 1 to 24, got {self.pwm_bits!r}")
        number("dead_band", 0.0, 1.0)
        if self.dead_band >= 1.0:
            raise TwinError(f"motor dead_band must be a duty fraction in [0, 1), got {self.dead_band!r}")
        number("inductance", 0.0, 10.0, False, "H")
        if not isinstance(self.back_emf_compensation, bool):
            raise TwinError(f"motor back_emf_compensation must be true or false, got {self.back_emf_compensation!r}")

    @property
    def k_t(self) -> float:
        """Torque constant in N·m/A, equal to the back-EMF constant k_e in V·s/rad."""
        return self.supply_voltage / self.no_load_speed

    @property
    def resistance(self) -> float:
        """Armature resistance R in Ω."""
        return self.k_t * self.supply_voltage / self.stall_torque

    @property
    def stall_current(self) -> float:
        """V_s / R in A."""
        return self.supply_voltage / self.resistance

    @property
    def electrical_damping(self) -> float:
        """c = k_t k_e / R in N·m·s/rad: the slope of the speed–torque curve."""
        return self.k_t * self.k_t / self.resistance

    @property
    def max_current(self) -> float:
        return self.stall_current if self.current_limit is None else float(self.current_limit)

    @property
    def pwm_steps(self) -> int:
        return (1 << self.pwm_bits) - 1


DEFAULT_MOTOR = DCMotorParams()


def steady_current(params: DCMotorParams, duty, omega):
    """The armature current in A for a PWM ``duty`` in [−1, 1] at shaft speed ``omega`` (rad/s,
    relative to the body), without inductance: i = (d V_s − k_e ω) / R, signed (positive drives
    the wheel forward); elementwise for numpy arrays. The torque is k_t i
    (:meth:`MotorDriver.torque_at`). With the stall torque τ_s and the no-load speed ω_0 at the
    supply V_s this is i = τ_s (d ω_0 − ω) / V_s: a current measures the torque in N·m directly,
    where the duty alone gives it only through the motor's figures."""
    return (duty * params.supply_voltage - params.k_t * omega) / params.resistance


class MotorDriver:
    """PWM update of one motor: torque command → duty (held for a control period)."""

    def __init__(self, params: DCMotorParams = DEFAULT_MOTOR):
        if not isinstance(params, DCMotorParams):
            raise TwinError(f"a motor driver needs DCMotorParams, got {params!r}")
        self.params = params
        self._kt = params.k_t
        self._R = params.resistance
        self._vs = params.supply_voltage
        self._imax = params.max_current
        self._steps = params.pwm_steps
        self._comp = params.back_emf_compensation
        # the arguments of the compiled twin.plant._fastpath.motors after the four inputs
        self.constants = (self._kt, self._R, self._vs, self._imax, float(self._steps), float(self._comp),
                          params.dead_band)

    def duty(self, torque_cmd: float, omega: float) -> tuple[float, bool]:
        """(duty in [−1, 1], saturated) for a torque command in N·m at shaft speed ω in rad/s.

        ``saturated`` is true when the current limit or the supply voltage cut the command.
        """
        if not (math.isfinite(torque_cmd) and math.isfinite(omega)):
            raise TwinError(f"motor torque command and shaft speed must be finite, got {torque_cmd!r} N·m, {omega!r} rad/s")
        i_cmd = torque_cmd / self._kt
        saturated = abs(i_cmd) > self._imax
        if saturated:
            i_cmd = math.copysign(self._imax, i_cmd)
        v = self._R * i_cmd
        if self._comp:
            v += self._kt * omega
        d = v / self._vs
        if d > 1.0 or d < -1.0:
            saturated = True
            d = 1.0 if d > 0 else -1.0
        if abs(d) < self.params.dead_band:
            return 0.0, saturated
        return round(d * self._steps) / self._steps, saturated

    def update(self, torque_cmd: float, omega: float) -> tuple[float, bool, float, float]:
        """One PWM update: (duty, saturated, τ_0, τ) for a command (N·m) at shaft speed ω (rad/s).

        τ_0 = k_t V / R is the speed-independent torque the duty gives, τ = τ_0 − c ω the
        torque delivered at the update.
        """
        d, saturated = self.duty(torque_cmd, omega)
        tau0 = self._kt * d * self._vs / self._R
        return d, saturated, tau0, tau0 - self._kt * self._kt * omega / self._R

    def held(self, duty: float, omega: float) -> tuple[float, float]:
        """(duty, τ_0, τ) for a duty a firmware computed (its own driver law, outside the twin):
        the duty as the PWM peripheral holds it (clipped to [−1, 1] and quantised to the PWM
        resolution, as a compare register does), τ_0 and τ at shaft speed ω as in :meth:`update`."""
        if not (math.isfinite(duty) and math.isfinite(omega)):
            raise TwinError(f"motor duty and shaft speed must be finite, got {duty!r}, {omega!r} rad/s")
        d = 1.0 if duty > 1.0 else (-1.0 if duty < -1.0 else duty)
        d = round(d * self._steps) / self._steps
        tau0 = self._kt * d * self._vs / self._R
        return d, tau0, tau0 - self._kt * self._kt * omega / self._R

    def torque_at(self, duty: float, omega: float) -> float:
        """Steady-state torque in N·m for a duty at shaft speed ω (no inductance)."""
        return self._kt * (duty * self._vs - self._kt * omega) / self._R

    def stall_part(self, duty: float) -> float:
        """τ_0 = k_t V / R in N·m: the speed-independent part of the torque for a duty."""
        return self._kt * duty * self._vs / self._R

    def current_step(self, current: float, duty: float, omega: float, dt: float) -> float:
        """Current after ``dt`` s with the electrical lag, exact for constant V and ω."""
        L = self.params.inductance
        i_ss = (duty * self._vs - self._kt * omega) / self._R
        if L <= 0.0:
            return i_ss
        return i_ss + (current - i_ss) * math.exp(-dt * self._R / L)

    def current_mean(self, current: float, duty: float, omega: float, dt: float) -> float:
        """Mean current over the next ``dt`` s from ``current``, exact for constant V and ω.

        The twin applies k_t times this as the torque of a physics step, so the lag is
        resolved even when L/R is shorter than the step.
        """
        L = self.params.inductance
        i_ss = (duty * self._vs - self._kt * omega) / self._R
        if L <= 0.0:
            return i_ss
        if dt <= 0.0:
            return current
        tau = L / self._R
        return i_ss + (current - i_ss) * (tau / dt) * -math.expm1(-dt / tau)
