"""The noise pipeline of one 3-axis inertial sensor (see :mod:`twin.sensors.specs`).

Stages, per sample: scale-factor error → turn-on bias + drifting bias → white noise →
range saturation → ADC quantisation (two's-complement codes). The drifting bias then
advances by one sample interval.

One code path serves the closed loop and the statistics tests: :meth:`TriadNoise.sample`
works on one sample in plain floats. Normal draws are taken from the generator in
blocks (so a sample costs a few µs, not a NumPy call per number); the stream is the
generator's own, so the same seed gives the same readings.
"""
from __future__ import annotations

import math

import numpy as np

from twin.sensors.specs import TriadSpec

_BLOCK = 512  # samples of normals drawn at a time


class TriadNoise:
    """Stateful noise of one triad at a fixed output interval.

    Parameters
    ----------
    spec : TriadSpec
    dt : float
        Output interval in s.
    rng : numpy.random.Generator
        The only source of randomness (draws the turn-on bias, the scale factors, the
        initial Gauss–Markov bias, then the per-sample noise).

    Attributes
    ----------
    turn_on : (3,) unit, the constant bias of this run
    scale : (3,) 1, the sensitivity errors s
    drift : (3,) unit, the drifting bias now (it applies to the next sample)
    """

    def __init__(self, spec: TriadSpec, dt: float, rng: np.random.Generator):
        self.spec = spec
        self.dt = float(dt)
        self.rng = rng
        self.turn_on = [float(v) for v in spec.turn_on_bias * rng.standard_normal(3)]
        self.scale = [float(v) for v in spec.scale_factor_error * rng.standard_normal(3)]
        # the device's own constants where known: drawn all the same, so that every later draw of
        # the run (drift, noise) is the one it would be without them
        if spec.bias is not None:
            self.turn_on = [float(v) for v in spec.bias]
        if spec.scale is not None:
            self.scale = [float(v) for v in spec.scale]
        tau = spec.bias_correlation_time
        K = spec.bias_random_walk
        if tau is None:
            self._phi, self._q = 1.0, K * math.sqrt(self.dt)
            self.drift = [0.0, 0.0, 0.0]
        else:
            self._phi = math.exp(-self.dt / tau)
            self._q = K * math.sqrt(0.5 * tau * (1.0 - self._phi * self._phi))
            self.drift = [float(v) for v in K * math.sqrt(0.5 * tau) * rng.standard_normal(3)]
        self._sigma = spec.white_sigma(self.dt)
        self._lsb = spec.lsb
        half = 1 << (spec.bits - 1)
        self._code_lo, self._code_hi = -half, half - 1
        self._block: list = []
        self._i = 0

    @property
    def bias(self) -> tuple[float, float, float]:
        """Total bias (turn-on + drift) that the next sample carries, per axis."""
        on, d = self.turn_on, self.drift
        return (on[0] + d[0], on[1] + d[1], on[2] + d[2])

    def sample(self, x0: float, x1: float, x2: float) -> tuple[float, float, float]:
        """One reading of the true values (x0, x1, x2): noisy, saturated and quantised."""
        i = self._i
        if i >= len(self._block):
            self._block = self.rng.standard_normal((_BLOCK, 6)).tolist()
            i = 0
        n0, n1, n2, m0, m1, m2 = self._block[i]
        self._i = i + 1
        s, on, d = self.scale, self.turn_on, self.drift
        sig, lsb, lo, hi, phi, q = self._sigma, self._lsb, self._code_lo, self._code_hi, self._phi, self._q
        floor = math.floor
        # the three axes written out (a loop over them cost a third of this call, every IMU sample)
        d0, d1, d2 = d
        c0 = floor(((1.0 + s[0]) * x0 + on[0] + d0 + sig * n0) / lsb + 0.5)
        c1 = floor(((1.0 + s[1]) * x1 + on[1] + d1 + sig * n1) / lsb + 0.5)
        c2 = floor(((1.0 + s[2]) * x2 + on[2] + d2 + sig * n2) / lsb + 0.5)
        d[0], d[1], d[2] = phi * d0 + q * m0, phi * d1 + q * m1, phi * d2 + q * m2
        return ((lo if c0 < lo else (hi if c0 > hi else c0)) * lsb, (lo if c1 < lo else (hi if c1 > hi else c1)) * lsb,
                (lo if c2 < lo else (hi if c2 > hi else c2)) * lsb)

    def clip(self, v: float) -> float:
        """``v`` limited to the sensor's range (for values injected after the ADC)."""
        lo, hi = self._code_lo * self._lsb, self._code_hi * self._lsb
        return lo if v < lo else (hi if v > hi else v)
