"""A motor current sensor on each wheel's driver: a shunt resistor, a current-sense amplifier and
the microcontroller's ADC, what real motor drivers give. Off unless a scenario's
``[sensors.motor_current]`` (or a log's) turns it on; its entry in
:data:`twin.sensors.types.SENSOR_TYPES` is ``motor_current``.

Channel ``motor_current`` (2,) A: (left, right), signed (positive drives the wheel forward),
sampled at control instants (``rate`` divides the control rate; absent: every one), arriving
``latency`` s later (whole control periods). The truth is the drive model's current at the
instant (:func:`true_current`): a plant's own ``motor_current`` where it has one, else
:func:`twin.actuators.dc_motor.steady_current` of the duty held over the period that just ended
and the shaft speed then (exact for the twin's motors without inductance: the current the
shunt carries just before the driver's next update). Per sample and wheel::

    y = quantise((1 + s) i + b + σ n),   n ~ N(0, 1),   clipped to ±full_scale

with s the gain error and b the offset, both drawn once per run (per wheel), and the
quantiser's step ``resolution`` (A per LSB; 0: none).

Defaults, a bidirectional shunt amplifier of the INA240 class read by a 12-bit ADC (TI INA240,
data sheet SBOS662C, Dec. 2021, section 6.5 Electrical Characteristics): the INA240A2 (gain 50
V/V) across a 5 mΩ shunt gives 0.25 V/A; its output biased at mid-supply (REF1/REF2 splitting
3.3 V) swings ±1.65 V, so ``full_scale`` = 6.6 A (the twin's motors stall at 3.5 A) and one LSB
of a 12-bit ADC at 3.3 V is 3.3 V / 4096 / 0.25 V/A = 3.22 mA (``resolution``). Judgement calls,
as for the IMU (:mod:`twin.sensors.specs`, a datasheet's ± maximum taken as 3σ):

* ``gain_error`` σ = 0.34 %: the amplifier's gain error (±0.20 % max) and a 1 % shunt, in
  quadrature, 1.02 % as 3σ;
* ``offset`` σ = 3 mA: the input offset (±25 µV max, 5 mA over 5 mΩ) and the reference divider
  (0.1 % of 1.65 V max, 6.6 mA), in quadrature, 8.3 mA as 3σ (firmware that zeroes the channel
  at power-up with the bridge off leaves less);
* ``noise`` σ = 5 mA (1.5 LSB): the ADC's own noise and what is left of the PWM ripple when the
  conversion is triggered at the PWM period's centre (the usual practice);
* ``latency`` 0: the conversion (about 1 µs) is done before the control step reads it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from twin.actuators.dc_motor import steady_current
from twin.errors import TwinError
from twin.sensors.channels import Channel, Sources, SpecKey, whole_steps

DOC = ("motor current per wheel from the drivers' shunt amplifiers (A, signed); off unless [sensors.motor_current] "
       "is given")
CHANNEL = Channel("motor_current", "A", ("left", "right"), "armature current of each wheel's motor, signed "
                  "(positive drives the wheel forward)")
SHUNT_GAIN = 0.25  # V/A: an INA240A2 (50 V/V) across 5 mΩ
ADC_SPAN = 3.3  # V, a 12-bit ADC's reference; the amplifier's output biased at half of it
MAX_ADC_BITS = 32  # the finest resolution taken: a step of full_scale / 2^32
KEYS = {
    "noise": SpecKey("A", 0.0, 100.0, 0.005, "σ of the white noise of one sample"),
    "offset": SpecKey("A", 0.0, 100.0, 0.003, "σ of the offset drawn per run and wheel"),
    "gain_error": SpecKey("1", 0.0, 0.5, 0.0034, "σ of the gain error drawn per run and wheel (y = (1 + s) i)"),
    "resolution": SpecKey("A", 0.0, 100.0, ADC_SPAN / 4096 / SHUNT_GAIN,
                          "one ADC step (A per LSB; 0: not quantised)"),
    "full_scale": SpecKey("A", 0.0, 1e4, 0.5 * ADC_SPAN / SHUNT_GAIN, "the range ±full_scale: a reading there "
                          "is clipped", lo_open=True),
    "rate": SpecKey("Hz", 0.0, 1e5, None, "sample rate, dividing the control rate (absent: the control rate)",
                    lo_open=True),
    "latency": SpecKey("s", 0.0, 1.0, 0.0, "from the sample instant to its arrival, whole control periods"),
}


@dataclass(frozen=True)
class MotorCurrentSpec:
    """The figures of both wheels' current sensors (see the module docstring): ``noise``,
    ``offset`` (σ A), ``gain_error`` (σ, 1), ``resolution`` (A per LSB, 0: none), ``full_scale``
    (A), ``rate`` (Hz, None: the control rate) and ``latency`` (s)."""

    noise: float = KEYS["noise"].default
    offset: float = KEYS["offset"].default
    gain_error: float = KEYS["gain_error"].default
    resolution: float = KEYS["resolution"].default
    full_scale: float = KEYS["full_scale"].default
    rate: float | None = None
    latency: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None and f.name == "rate":
                continue
            object.__setattr__(self, f.name, KEYS[f.name].check(f.name, v, "[sensors.motor_current]"))
        if self.resolution > self.full_scale:
            raise TwinError(f"[sensors.motor_current] resolution must be at most full_scale ({self.full_scale:g} A), "
                            f"got {self.resolution:g} A")
        finest = self.full_scale / 2.0 ** MAX_ADC_BITS
        if 0.0 < self.resolution < finest:
            raise TwinError(f"[sensors.motor_current] resolution must be 0 (not quantised) or at least full_scale / "
                            f"2^{MAX_ADC_BITS} ({finest:.3g} A: an ADC of {MAX_ADC_BITS} bits at most), got "
                            f"{self.resolution:g} A")

    def steps(self, control_rate: float) -> tuple[int, int]:
        """(control periods per sample, latency in control periods), or one line saying what the
        control rate allows."""
        every = 1
        if self.rate is not None:
            if self.rate > control_rate * (1.0 + 1e-9):
                raise TwinError(f"[sensors.motor_current] rate must be at most the control rate ({control_rate:g} Hz), "
                                f"got {self.rate:g} Hz")
            every = whole_steps(control_rate / self.rate, f"[sensors.motor_current] rate must divide the control rate "
                                f"({control_rate:g} Hz) a whole number of times, got {self.rate:g} Hz")
        d = whole_steps(self.latency * control_rate, f"[sensors.motor_current] latency must be a whole number of "
                        f"control periods ({1.0 / control_rate:g} s), got {self.latency:g} s")
        return every, d


_BLOCK = 512  # samples of normals drawn at a time


class MotorCurrentSensor:
    """The noise of both wheels' current sensors over one run (the reader of the sensor type).

    ``rng`` is the sensor's own child of the run's generator: it draws the offsets (2,), then the
    gain errors (2,), then blocks of per-sample normals, nothing else."""

    def __init__(self, spec: MotorCurrentSpec, control_rate: float, rng: np.random.Generator):
        self.spec = spec
        self.every, self.latency = spec.steps(control_rate)
        self.rng = rng
        self.offset = [float(v) for v in spec.offset * rng.standard_normal(2)]
        self.gain = [float(v) for v in spec.gain_error * rng.standard_normal(2)]
        self._block: list = []
        self._i = 0

    def sample(self, true) -> tuple:
        """The reading of each channel: ``true`` ((i_l, i_r),) A → ((y_l, y_r),) A."""
        (i_l, i_r), = true
        i = self._i
        if i >= len(self._block):
            self._block = self.rng.standard_normal((_BLOCK, 2)).tolist()
            i = 0
        n_l, n_r = self._block[i]
        self._i = i + 1
        s = self.spec
        return ((self._adc((1.0 + self.gain[0]) * i_l + self.offset[0] + s.noise * n_l),
                 self._adc((1.0 + self.gain[1]) * i_r + self.offset[1] + s.noise * n_r)),)

    def _adc(self, v: float) -> float:
        s = self.spec
        if s.resolution > 0.0:
            v = math.floor(v / s.resolution + 0.5) * s.resolution
        return self.clip(v)

    def clip(self, v: float) -> float:
        fs = self.spec.full_scale
        return -fs if v < -fs else (fs if v > fs else v)

    def truth(self) -> dict:
        """The constants this run drew: offsets (A) and gain errors (1), (left, right)."""
        return {"motor_current_offset": tuple(self.offset), "motor_current_gain_error": tuple(self.gain)}


def true_current(src: Sources) -> tuple:
    """((i_l, i_r),) A: the motors' current at the instant (see the module docstring)."""
    own = getattr(src.plant, "motor_current", None)
    if own is not None:
        return ((float(own[0]), float(own[1])),)
    m, tr, act = src.motor, src.truth, src.actuation
    dl, dr = (0.0, 0.0) if act is None else (act[0], act[1])
    return ((steady_current(m, dl, tr.psi_l_dot - tr.theta_dot), steady_current(m, dr, tr.psi_r_dot - tr.theta_dot)),)


__all__ = ["CHANNEL", "KEYS", "MotorCurrentSensor", "MotorCurrentSpec", "true_current"]
