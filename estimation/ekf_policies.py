"""The EKF's policies, composed on its filter core (:mod:`estimation.ekf_core`) by the sensor
front end (:mod:`estimation.ekf_frontend`) and the fusion step (:mod:`estimation.ekf_fusion`):
what to do with a measurement, not how to filter it.

:class:`EncoderGate`       the χ² gates of the encoder update and of the IMU outlier test, and
                           the forced re-synchronisation
:class:`LatencyWatch`      the gyro's latency watched against the commands
:class:`AccelOutlierTest`  the accelerometer half of an IMU sample against equation (1)
:class:`KeepInside`        the truncation that keeps a wheel in an unchanged count
                           (:func:`truncated_measurement`)
:class:`ConsiderStates`    which states are held (Schmidt) after the learning time

The module docstring of :mod:`estimation.ekf` gives the reasons and the measurements behind
each; their thresholds are :data:`estimation.ekf_config.POLICY`'s. The compiled core runs the
gate, the accelerometer test and the truncation fused in its IMU step (estimation/_ekf.c) with
the same thresholds, handed to it in its configuration; the front end books its decisions.
"""
from __future__ import annotations

import math

import numpy as np

from estimation.detlinalg import affine, dot, mv, rowsums
from estimation.ekf_config import (ACCEL_MAX_IN_ROW, ACCEL_VARIANCE_FACTOR, IMU_GATE_PROBABILITY, INSIDE_MARGIN,
                                   LEARN_SLACK, WATCH_CLIP, WATCH_EVERY, WATCH_MARGIN, WATCH_MAX_LAG, WATCH_PERSIST,
                                   WATCH_RHO, WATCH_WINDOW)
from estimation.ekf_core import _kernel
from estimation.gates import chi2_gate

# row j of the window at latency L reads the command kernel at r0 − 2 − L + j, where
# r0 = n − 1 − WATCH_WINDOW = WATCH_MAX_LAG + 4 is the window's first row (see LatencyWatch.observe)
_WATCH_INDEX = (WATCH_MAX_LAG + 2 - np.arange(WATCH_MAX_LAG + 1)[:, None] + np.arange(WATCH_WINDOW)[None, :])


class EncoderGate:
    """The χ² gate of an encoder update at 1 − ``probability`` (1 or 2 degrees of freedom), and
    of an IMU sample's outlier test at 1 − :data:`IMU_GATE_PROBABILITY`: wrongly replacing a real
    sample by the model's is worse than keeping a mild outlier. After ``max_rejects_in_row``
    rejections in a row the next sample is accepted (the filter is then the likely culprit)."""

    def __init__(self, probability: float, max_rejects_in_row: int):
        self.gates = {k: chi2_gate(probability, k) for k in (1, 2)}
        self.imu_gates = {k: chi2_gate(IMU_GATE_PROBABILITY, k) for k in (1, 2)}
        self.max_rejects_in_row = int(max_rejects_in_row)

    def passes(self, eps: float, dof: int) -> bool:
        """The encoder measurement whose NIS is ``eps`` (``dof`` rows) passes the gate."""
        return eps <= self.gates[dof]

    def may_reject(self, in_row: int) -> bool:
        """False once ``in_row`` rejections in a row force the next sample in."""
        return in_row < self.max_rejects_in_row

    def imu_outlier(self, eps: float, dof: int, alternative) -> bool:
        """The IMU sample is an outlier: the encoders' NIS with it, ``eps`` (``dof`` rows, every
        wheel), fails the IMU gate, and the NIS with the sample equation (1) predicts instead,
        ``alternative()`` → (NIS, rows) (called only then), passes the normal gate."""
        if eps <= self.imu_gates[dof]:
            return False
        eps_alt, dof_alt = alternative()
        return eps_alt <= self.gates[dof_alt]


def truncated_measurement(w: float, s2: float, lo: float, hi: float, gate: float):
    """(z, R): the scalar measurement whose Kalman update turns the prior N(w, s2) into the
    mean and variance of that prior truncated to [lo, hi]; None if w lies inside (nothing
    to correct), if s2 is not positive, or if w lies more than ``gate`` standard deviations
    outside (a constraint that far off says the prior, not the interval, is wrong).

    With a = (lo − w)/s, b = (hi − w)/s the truncated normal's mean is w + s (φ(a) − φ(b))/Z
    and its variance s² (1 + (a φ(a) − b φ(b))/Z − ((φ(a) − φ(b))/Z)²), Z = Φ(b) − Φ(a).
    A gain k = 1 − σ_t²/s² gives that variance; z = w + (μ_t − w)/k that mean;
    R = s² (1 − k)/k. Units: those of w (rad for a wheel angle), s2 and R their squares."""
    if not s2 > 0.0 or lo <= w < hi:
        return None
    s = math.sqrt(s2)
    a, b = (lo - w) / s, (hi - w) / s
    sign = 1.0
    if b <= 0.0:  # the mean above the interval: mirror it below
        a, b, sign = -b, -a, -1.0
    if a > gate:
        return None
    pa, pb = math.exp(-0.5 * a * a) / _SQRT_2PI, math.exp(-0.5 * b * b) / _SQRT_2PI
    Z = 0.5 * (math.erfc(a / _SQRT_2) - math.erfc(b / _SQRT_2))
    if not Z > 0.0:
        return None
    mean = (pa - pb) / Z
    var = 1.0 + (a * pa - b * pb) / Z - mean * mean
    if not 0.0 < var < 1.0:
        return None
    k = 1.0 - var
    return w + sign * s * mean / k, s2 * var / k


_SQRT_2, _SQRT_2PI = math.sqrt(2.0), math.sqrt(2.0 * math.pi)


class KeepInside:
    """For each wheel whose count has not changed since the last sample used: if the estimate
    has left that count by more than :data:`INSIDE_MARGIN` counts, the truncated update that
    brings it back (see :meth:`estimation.ekf_frontend.SensorFrontEnd.keep_inside` for why, and why the margin).

    ``H`` (2, 12) the wheels' rows, ``b_r`` b/r, ``alpha0`` the initial heading (rad),
    ``delta`` the count (rad), ``gate`` the σ beyond which the unchanged count is implausible
    (the wheel must have turned: no update, and the wheel's bit set in ``implausible``)."""

    def __init__(self, H, b_r: float, alpha0: float, delta: float, gate: float):
        self.H, self.b_r, self.alpha0, self.gate = H, b_r, alpha0, gate
        self.half = (0.5 + INSIDE_MARGIN) * delta  # rad
        self.implausible = 0  # the last call's mask of implausible wheels (bit 0 left, 1 right)

    def measurements(self, enc, last, kf):
        """The truncated measurements (z, off, H, R), one per wheel that needs one, each computed
        from the state ``kf`` (x, P) as it is after the previous one's update."""
        self.implausible = 0
        for i in (0, 1):
            if enc[i] != last[i]:
                continue
            x, P = kf.x, kf.P
            h = self.H[i]
            off = -(2 * i - 1) * self.b_r * self.alpha0
            w = float(affine([off], h[None, :], x)[0])
            s2 = dot(h, mv(P, h))
            lo, hi = enc[i] - self.half, enc[i] + self.half
            if s2 > 0.0 and (lo - w if w < lo else w - hi) > self.gate * math.sqrt(s2):
                self.implausible |= 1 << i
                continue
            pm = truncated_measurement(w, s2, lo, hi, self.gate)
            if pm is None:
                continue
            z, R = pm
            yield np.array([z]), np.array([off]), self.H[[i]], np.array([[R]])


class AccelOutlierTest:
    """The accelerometer half of an IMU sample against the specific force equation (1) predicts:
    its innovation less the median of the last three must pass the IMU gate (2 dof) at
    :data:`~estimation.ekf_config.ACCEL_VARIANCE_FACTOR` times the variance, while the gyro agrees
    with the model; at most :data:`~estimation.ekf_config.ACCEL_MAX_IN_ROW` in a row."""

    def __init__(self, gate2: float, gyro_gate: float):
        self.gate2, self.gyro_gate = gate2, gyro_gate
        self.history: list = []  # the last three innovations (m/s², (f_x, f_z))
        self.in_row = 0
        # params() for the next sample, as an attribute the filter reads every step: seen()
        # (the only change to what it depends on) recomputes it
        self.test = (gate2, 0.0, 0.0, 0.0)

    def params(self):
        """(gate, b_x, b_z, may) for the next sample: b the median of the last three innovations;
        ``may`` 0.0 until three are known and after :data:`ACCEL_MAX_IN_ROW` rejections in a row.
        Also the attribute ``test``."""
        return self.test

    def is_outlier(self, test, e, sx: float, sz: float, eg: float, sg: float) -> bool:
        """With ``test`` from :meth:`params`: innovation ``e`` (variances ``sx``, ``sz``) less the
        median fails the gate at ACCEL_VARIANCE_FACTOR times the variance, and the gyro's innovation ``eg`` (variance
        ``sg``) passes its own (a push moves θ̈ too, a sensor spike does not)."""
        ex, ez = e[0] - test[1], e[1] - test[2]
        return bool(test[3]) and ex * ex / sx + ez * ez / sz > ACCEL_VARIANCE_FACTOR * test[0] and \
            eg * eg / sg <= self.gyro_gate

    def seen(self, e, outlier: bool) -> None:
        """After a sample: its innovation ``e`` (None: not computed) and the verdict."""
        h = self.history
        if e is not None and math.isfinite(e[0]) and math.isfinite(e[1]):
            h.append(e)
            if len(h) > 3:
                del h[0]
        self.in_row = in_row = self.in_row + 1 if outlier else 0
        # the next sample's params() (may: 0.0 before three are known, or after too many in a row)
        if len(h) < 3:
            self.test = (self.gate2, 0.0, 0.0, 0.0)
        else:
            (x0, z0), (x1, z1), (x2, z2) = h
            bx = max(min(x0, x1), min(max(x0, x1), x2))
            bz = max(min(z0, z1), min(max(z0, z1), z2))
            self.test = (self.gate2, bx, bz, float(in_row < ACCEL_MAX_IN_ROW))


def _median(a: np.ndarray) -> float:
    """np.median of a non-empty 1-d array, bit for bit, without its overhead (a few µs
    against 17 µs on 100 samples)."""
    k = len(a) // 2
    if len(a) % 2:
        return float(np.partition(a, k)[k])
    p = np.partition(a, (k - 1, k))
    return float((p[k - 1] + p[k]) / 2.0)  # as np.mean of the two: their sum, halved


class LatencyWatch:
    """Watch the gyro's latency: every :data:`WATCH_EVERY` periods, correlate the gyro's
    second difference Δ²ω_y (arrival-indexed, the last :data:`WATCH_WINDOW` samples) with
    the commands' torque-sum differences at candidate latencies 0 … :data:`WATCH_MAX_LAG`.

    Why this works: θ̈ responds to the wheel torques at once (equation (1)), so Δ²ω_y of
    the sample taken over period p follows (u_p + u_{p−1}) − (u_{p−2} + u_{p−3}) (u the
    command sum; the two-period kernel because the sample is a mean over its period and
    the difference spans two), whose high-frequency part is the controller's reaction
    to sensor noise - uncorrelated with the state, so the correlation peaks sharply at
    the gyro's true latency (|ρ| 0.2–0.4 balancing, 0.3–0.8 in a limit cycle) and drops
    to ~0 one or more periods off. The commands are known exactly and undelayed: they
    are the clock. A change is declared when the best latency differs from the assumed
    one, its ρ (sign as equation (1) gives, ``torque_sign``) ≥ :data:`WATCH_RHO` and beats the
    assumed one's by :data:`WATCH_MARGIN`, in :data:`WATCH_PERSIST` checks in a row.

    Which rows count, and how much (issue 29). Every gyro sample the filter takes as a
    measurement of the rate is correlated; a sample that is none is left out like a missing
    one (its three rows of Δ²ω_y with it): one the filter rejected as an outlier against the
    encoders (a spike; :meth:`filter_verdicts`), a stale (repeated) one and one at the rail
    (clipped: it says only "at least this much"), the estimator's ``usable=False``. A row
    is never left out for its size: a row beyond :data:`WATCH_CLIP` robust σ (median
    absolute deviation) of the window is winsorised, i.e. counted at that bound with its
    sign, so that no handful of rows carries the sums (bounded influence, as a Huber
    estimator's) while a large row still votes for the latency that explains it.

    Why not left out: an earlier screen dropped the rows beyond 5 robust σ, against spikes,
    and that made false "gyro latency changed" events during pushes. Measured at the 13
    false events of push-recovery's seeds 0–9: a shove makes Δ²ω_y 0.5–0.6 rad/s (robust σ
    3–4 mrad/s balancing, 5–8 in such a window), so the screen dropped 13–16 rows of the
    catch - the force's onset and release, which no command explains, but also the
    controller's reaction to them, the rows the commands at the true latency explain best
    (Δ²ω_y ≈ −0.77 × the command kernel there). What was left was the catch's slow part: the
    commands ramping as the body swings (the kernel's standard deviation 0.04–0.06 N·m in
    the rows kept, 20–40 × its 0.0014–0.0024 while balancing) while Δ²ω_y stays small,
    because equation (1)'s state terms (gravity, the body–wheel damping and back-EMF) cancel
    most of the ramp's torque. Those rows carried the sums, and their slow co-variation
    peaked at whichever lag lined the ramps up: ρ 0.22–0.43 at 25–30 ms against −0.08–0.26
    at the true 5 ms (the same windows with every row kept: 0.53–0.57 at 5 ms, 0.04–0.06 at
    the false lag). Over seeds 0–49 (benchmarks/latency_watch_sweep.py, the code before)
    push-recovery logged 103 such events on 83 of its 150 runs of IT2, type-1 and LQR
    (mostly "now about 25 / 30 ms", ρ 0.20–0.44, 0.2–0.5 s after a shove, each undone
    0.6–0.75 s later but one: type-1's seed 43 went to 100 ms at 3.2 s and fell), and
    sensor-faults 3 after its IMU dropout. Neither the motors nor the gyro clipped in those
    catches (no saturated period; |θ̇| ≤ 4.06 rad/s against the gyro's 4.36 rad/s). With the
    catch's rows in, winsorised, the true latency's ρ is 0.35–0.68 (median 0.59) 0.1–0.6 s
    after a shove (seeds 0–9) and no other lag comes within the margin of beating it (at
    most 0.09 above it); over every built-in at seeds 0–49 with the three controllers the
    watch logs no event. Why bounded: with every row in at its full size, spikes the filter
    lets through (±0.1–0.2 rad/s on sensor-faults, too small for its outlier test) carried
    the sums instead and set off false changes to 0 ms (2 of 90 runs, seeds 0–9, three
    controllers); winsorised, none with ±0.05–0.3 rad/s spikes (120 runs)."""

    def __init__(self, torque_sign: float):
        self.torque_sign = torque_sign
        self.y: list[float] = []  # the window: gyro ω_y by arrival step (NaN: none, or no measurement)
        self.u: list[float] = []  # the sum of the wheel commands over the period ending at each step
        self.k = -1  # the step of the window's newest entry
        self.gaps = {"gyro": [], "accel": []}  # (step, length) of recent arrival gaps, per triad
        self.last_arrival = {"gyro": 0, "accel": 0}
        self.votes = (0, 0)  # (candidate latency, consecutive checks that chose it)
        self.hold_until = 0  # no verdict before this step (after a change)
        self.last = None  # (t, best latency, its ρ, the assumed one's ρ) of the last check
        self.verdicts = (0, 0)  # (the filter's last sample time seen, its IMU outliers by then)

    def filter_verdicts(self, m: int, outliers: int, latency: int) -> None:
        """The filter has used its samples up to sample time ``m`` and rejected ``outliers``
        IMU samples as outliers so far; a gyro sample with time j arrived at step j +
        ``latency``. The samples it rejected since the last call are forgotten (their entries
        become NaN): a spike is no measurement of the motion. The filter steps one sample
        time per period as a rule, so that is the one rejected; when it stepped several at
        once, all are forgotten (a few rows, never a false verdict)."""
        m0, n0 = self.verdicts
        if outliers != n0:
            wy, k = self.y, self.k
            for j in range(max(m0 + 1, m - len(wy)), m + 1):
                i = len(wy) - 1 - (k - (j + latency))
                if 0 <= i < len(wy):
                    wy[i] = math.nan
        self.verdicts = (m, outliers)

    def observe(self, t: float, k: int, gyro, a_ok: bool, command, assumed: int, usable: bool = True):
        """Step ``k`` (time ``t``): the gyro reading (None: none), whether the accelerometer's
        arrived, the command over the period that ended, the latency assumed now (periods);
        ``usable`` False: the reading arrived but is no measurement of the rate (stale or
        clipped), so it counts as an arrival but is not correlated.
        Returns (new latency, its ρ) when a change is declared, else None."""
        wy, wu = self.y, self.u
        wy.append(float(gyro[1]) if gyro is not None and usable else math.nan)
        wu.append(command[0] + command[1])
        self.k = k
        last = self.last_arrival
        # (the common case, both halves arriving without a gap, without a loop: every period)
        if gyro is None or not a_ok or last["gyro"] != k - 1 or last["accel"] != k - 1:
            for name, arrived in (("gyro", gyro is not None), ("accel", a_ok)):
                if arrived:
                    gap = k - last[name] - 1
                    if gap > 0:
                        self.gaps[name].append((k, gap))
                        if len(self.gaps[name]) > 8:
                            del self.gaps[name][0]
                    last[name] = k
        else:
            last["gyro"] = last["accel"] = k
        n = WATCH_WINDOW + WATCH_MAX_LAG + 5
        if len(wy) > n:
            del wy[0], wu[0]
        if k % WATCH_EVERY or len(wy) < n or self.hold_until > k:
            return None
        # the compiled check (estimation._ekf.watch_rho) is correlations() below, bit for bit,
        # 10× faster (tests/test_latency_watch_kernel.py)
        if _kernel is not None:
            rho = _kernel.watch_rho(wy, wu, WATCH_WINDOW, WATCH_MAX_LAG, WATCH_CLIP, self.torque_sign)
        else:
            rho = self.correlations()
        return None if rho is None else self._verdict(t, rho, assumed)

    def correlations(self):
        """ρ at latencies 0 … :data:`WATCH_MAX_LAG` over the present window (NumPy), or None
        when fewer than half its rows hold a measurement."""
        wy, wu = self.y, self.u
        n = len(wy)
        # the same arithmetic as on index arrays, on slices: this check runs every
        # WATCH_EVERY periods and was most of the filter's cost per step
        y, u = np.fromiter(wy, float, n), np.fromiter(wu, float, n)
        r0 = n - 1 - WATCH_WINDOW  # rows r0 … n − 2: the newest has no command after it yet
        y2 = y[r0:n - 1] - 2.0 * y[r0 - 1:n - 2] + y[r0 - 2:n - 3]
        ok = np.isfinite(y2)
        used = int(ok.sum())
        if used < WATCH_WINDOW // 2:
            return None
        # wu[i] is the command over the period ending at step i; the Δ-kernel at step i,
        # dk[i − 2] = u[i+1] + u[i] − u[i−1] − u[i−2]; at latency L row r reads dk at r − L
        dk = u[3:] + u[2:-1] - u[1:-2] - u[:-3]
        if used == WATCH_WINDOW:
            Z, yy = dk[_WATCH_INDEX], y2
        else:
            Z, yy = dk[_WATCH_INDEX[:, ok]], y2[ok]
        # bounded influence: a row beyond WATCH_CLIP robust σ (median absolute deviation) of
        # the window counts as if it were there, with its sign - winsorised, not left out (see
        # the class docstring)
        med = _median(yy)
        lim = WATCH_CLIP * 1.4826 * _median(np.abs(yy - med))
        yy = np.minimum(np.maximum(yy, med - lim), med + lim)
        yy = yy - yy.mean()
        Z -= Z.sum(axis=1, keepdims=True) / used  # as Z.mean(axis=1): the sum, divided
        # Σ z y, Σ z², Σ y² in one fixed-order sum each (not @: BLAS products differ in their
        # last bits between CPU kernels, issue 25)
        R = len(Z)
        sums = rowsums(np.vstack([Z * yy, Z * Z, (yy * yy)[None, :]]))
        den = np.sqrt(sums[2 * R] * sums[R:2 * R])
        return self.torque_sign * sums[:R] / np.where(den > 0, den, math.inf)

    def _verdict(self, t: float, rho, assumed: int):
        """The check's verdict on the correlations ``rho`` (a sequence, by latency)."""
        # np.argmax's answer (the first largest; the first NaN if any) without its conversion of
        # the kernel's tuple to an array, which cost 10 µs a call
        nan = [i for i, r in enumerate(rho) if r != r]
        best = nan[0] if nan else max(range(len(rho)), key=rho.__getitem__)
        self.last = (t, best, float(rho[best]), float(rho[assumed]))
        if best != assumed and rho[best] >= WATCH_RHO and rho[best] - rho[assumed] >= WATCH_MARGIN:
            votes = self.votes[1] + 1 if self.votes[0] == best else 1
            self.votes = (best, votes)
            if votes >= WATCH_PERSIST:
                return best, float(rho[best])
        else:
            self.votes = (0, 0)
        return None

    def accel_gapped(self, delta: int) -> bool:
        """True if the accelerometer stopped arriving for ``delta`` samples when the gyro did
        (within a period of each other): the whole IMU then fell behind, not the gyro alone."""
        g_gap = [s for s, n in self.gaps["gyro"] if n == delta]
        return delta > 0 and any(abs(s - sg) <= 1 for s, n in self.gaps["accel"] if n == delta for sg in g_gap)

    def changed(self, k: int) -> None:
        """A change was acted on at step ``k``: the next verdict on a window of the new latency alone."""
        self.votes = (0, 0)
        self.hold_until = k + WATCH_WINDOW


class ConsiderStates:
    """The states (names from ``state_names``) that become consider states after ``learn_time``
    s: measurements no longer correct their estimates (Schmidt–Kalman: their uncertainty stays
    in P)."""

    def __init__(self, names, state_names, learn_time: float):
        self.names = tuple(n for n in state_names if n in names)
        self.mask = np.array([n in self.names for n in state_names])
        self.learn_time = float(learn_time)

    @property
    def hold_from(self) -> float:
        """s: the first instant from which the states are held (inf: there are none)."""
        return self.learn_time - LEARN_SLACK if self.names else math.inf

    def due(self, t: float, holding: bool) -> bool:
        """True when the states are to be held from time ``t`` on."""
        return not holding and t >= self.hold_from


# (the thresholds are estimation.ekf_config's, named here too for the tests and the benchmarks)
__all__ = ["ACCEL_MAX_IN_ROW", "IMU_GATE_PROBABILITY", "INSIDE_MARGIN", "WATCH_CLIP", "WATCH_EVERY", "WATCH_MARGIN",
           "WATCH_MAX_LAG", "WATCH_PERSIST", "WATCH_RHO", "WATCH_WINDOW", "AccelOutlierTest", "ConsiderStates",
           "EncoderGate", "KeepInside", "LatencyWatch", "truncated_measurement"]
