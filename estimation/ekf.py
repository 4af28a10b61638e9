"""The twin's state estimator: an extended Kalman filter (filterpy) driven by the IMU and
corrected by the wheel encoders, with gyro-bias states, χ² gating and latency handling.

Design: a strapdown filter. The IMU drives the prediction (as in inertial navigation),
so its process noise is the IMU's own: the gyro's and accelerometer's noise densities,
scale-factor tolerances, ADC steps and bias random walks, straight from
:mod:`twin.sensors.specs`. The encoders correct it. No model of the robot's dynamics is
needed for that, so a mismatched plant, a payload, a slope or a push does not bias the
estimate. Equation (1) with the commands serves where there is no IMU sample: through
dropouts, to test a suspicious IMU sample, and to predict across the sensors' latency.

Coasting (no IMU sample, a stale one, or one rejected as an outlier): equation (1)
predicts the sample from the state, so the prediction's Jacobian must include how that
sample depends on the state, or the covariance stays at its strapdown size while the
error grows with the pendulum's instability (a 0.2 s dropout once left θ 40–60 mrad off
at σ 0.7 mrad). The sample also depends on θ̇, which is no state of the strapdown filter
but comes from the gyro's last two samples; while coasting these join the state (16 in
all) and the encoders correct them too. See :meth:`EKFEstimator._coast`.

Clipping (issue 29): a gyro or accelerometer axis at the end of its range (or within
:data:`RAIL_SIGMAS` σ of it) is no measurement; equation (1) stands in for it on the coasting
path, the other axes kept as readings, and the step's Jacobian through the model's value
cancels the scale factor and the bias, so clipped samples teach the filter neither. While
equation (1) stands in for a sensor, the model's uncertain parameters (``model_uncertainty``)
join the state as random constants, so the errors of consecutive synthetic samples add up
as a wrong mass or height makes them add up (:meth:`EKFEstimator._coast`).

Stuck encoders (issue 29): an unchanged count with the estimate more than 3.72 σ outside
it is a rejected measurement; ``max_rejects_in_row`` in a row and the encoders are taken
as stuck until both counts change (:meth:`EKFEstimator._count_check`); :meth:`EKFEstimator.degraded`
says what the estimate has lost, and a run that ends so is "degraded".

Why an EKF and not a UKF: over one 5 ms period the prediction is nearly linear (the
nonlinear terms are sines of θ, which moves by milliradians per period) and the encoder
measurement is linear. A UKF would push 25 sigma points through the same equations for
no measurable gain. The analytic Jacobians are tested against finite differences.

State (12,), SI units::

    x = [θ, ψ, v, α, b_y, b_z, c, s_y, h, s_z, s_ax, s_az]

θ pitch (rad); ψ mean wheel angle (rad); v the IMU point's forward speed (m/s) in the
heading frame, v = r ψ̇ + θ̇ dz; α heading (rad); b_y, b_z gyro biases about the axle and
the body's z axis (rad/s); c, h the encoders' zeros (rad): they count from power-up from
an unknown position of the first edge, so they read e_l,r = ψ − θ + c ∓ ((b/r)(α − α_0)
+ h); s_y, s_z the gyro's and s_ax, s_az the accelerometer's scale-factor errors (1).
The scale factors are states because they are constants: as white noise they would
integrate as √n where they really integrate as n (a 1 % accelerometer scale error during
a recovery tilts the estimate by ~2 mrad, coherently).

Prediction from t_{m−1} to t_m with the IMU sample (means over the interval) ω, f, the
true values ω̂_y = (ω_y − b_y)/(1 + s_y), ω̂_z = (ω_z − b_z)/(1 + s_z), f̂ = f/(1 + s_a)
(dx = x_i cos θ + z_i sin θ, dz = −x_i sin θ + z_i cos θ for the IMU at (x_i, z_i) in the
body frame)::

    θ⁺ = θ + Δt ω̂_y
    α⁺ = α + Δt α̇,   α̇ = ω̂_z / cos θ̄   (θ̄ the mid-interval pitch)
    v⁺ = v + Δt (f̂_x cos θ⁺ + f̂_z sin θ⁺ + α̇² dx(θ⁺))     (the point's forward acceleration)
    ψ⁺ = ψ + (Δt (v + v⁺)/2 − dx(θ⁺) + dx(θ)) / r

The IMU gives the period's mean rates and accelerations, so θ⁺ and v⁺ are exact on noise-free
samples; ψ⁺ takes ∫v as the trapezoid, exact only for a constant acceleration: knowing v and
v⁺ alone, ∫v lies anywhere in Δt [v, v⁺], and Q has that uniform interval's variance on ψ,
(Δt |v⁺ − v| / r)² / 12 (:data:`TRAPEZOID_VAR`).

A tilt error δθ shows as a horizontal acceleration g δθ, which the encoders see as a
drifting ψ: that is what makes θ and the biases observable while the robot balances.

Measurements: the encoders, per wheel whose count changed since the last sample used:
the position of the edge it last crossed (the count's lower boundary moving up, its upper
one moving down). The wheel was exactly there at an unknown instant of the interval T,
so it now lies beyond the edge by u |q̇| T, u ~ U(0, 1), at most one count: mean half,
variance (q̇T)²/12 plus the uncertainty of q̇. An unchanged count carries no new
information and is skipped (a white-noise model of quantisation, R = Δ²/12 at every
sample, counts the same error again and again and made this filter 2× overconfident).
It still bounds the wheel: once the estimate lies more than a count outside it, it is
truncated back (:meth:`EKFEstimator._keep_inside`); without that, a wheel dwelling in one
count let v run free on the accelerometer and ψ̂ stray up to 0.033 rad in 10 minutes.

Gating (χ² on the normalised innovation squared ε = yᵀ S⁻¹ y, at 1 − ``gate_probability``
with as many degrees of freedom as rows): an encoder sample that fails is rejected; after
``max_rejects_in_row`` rejections in a row the next one is accepted (logged): the
filter, not the encoders, is then the likely culprit. An IMU sample is tested against
both wheels (unchanged ones as "inside the current count", variance Δ²/12) at the much
stricter 1 − 1e-9: when it fails, the step is repeated with the sample equation (1)
predicts from the commands; if the encoders then pass, the IMU sample was the outlier
and is replaced. A triad (gyro or accelerometer) whose three values repeat the previous
sample exactly is stale (stuck), not measured: its noise spans several ADC steps, so
that happens by chance with probability < 4e-4. Encoder counts that moved further than a
wheel can turn (:data:`MAX_RIM_SPEED` at the rim), or beyond a 32-bit counter, are faults
and never reach the gate (see :meth:`EKFEstimator._screen_encoders`).
Rejections are counted per sensor. An accelerometer spike moves v, which the encoders see
only in later samples, so the accelerometer half is also tested on its own, against the
specific force equation (1) predicts from the state and the command (innovation variance:
the accelerometer's noise per sample + the model's torque uncertainty + g² P_θθ and the
scale factors' share): its innovation less the median of the last three innovations must
pass the 1 − 1e-9 gate (2 dof) at twice the variance - the median follows a lasting
mismatch (a slope, a payload, a push) after two samples and an isolated spike not at all.
It is an outlier only if the gyro sample agrees with the model (its NIS ≤ the 1 − 1e-9 gate):
a push moves θ̈ too, a sensor spike does not. An outlier's accelerometer half is replaced
by the model's (with its variance), the gyro half is kept; after
:data:`ACCEL_MAX_IN_ROW` in a row the next is taken as real (``accel_outliers`` in
:meth:`EKFEstimator.stats`). Measured (θ0 = 0.2 rad, 5 s): fault-free NIS ≤ 17.5 against
the gate 2 × 41.4, no rejection on 10 fault-free runs nor on any built-in scenario
(push-recovery and slope-payload included); every one of 31 injected ±1 m/s² spikes
rejected at the sample, no forced encoder re-synchronisation (before: 8 of 22 spiked IMU
samples caught, up to 24 re-synchronisations per run).

Consider states: the four scale factors and the two encoder zeros are learned for
``learn_time`` (10 s: the initial alignment and the first recovery, when they are
observable), then held (a Schmidt–Kalman filter: the gain's rows for them are zero, the
Joseph-form update keeps P exact for that gain, so their uncertainty still enters every
other state's). Learned for ever, they drift without bound while the robot balances: a
scale factor's Jacobian is the measured rate, whose noise is also in the error it is
regressed on, and the zeros sit in a direction (ψ + c, α + h r/b) no sensor sees, where
the strapdown's unmodelled errors accumulate. In paper-exp2 the gyro and accelerometer
scale states reached +0.17 to +0.25 in 900 s (true 0.2–0.9 %) at σ 0.004–0.009, θ̇ was read
17 % low, and the robot rocked into a 0.35 rad limit cycle (docs/explanation/sensors-ekf.md, "Long runs").
The accelerometer's two scale factors are held from the first step (:data:`UNTAUGHT`): a
balancing robot leans into its accelerations, so its forward specific force is noise but in
catches and pushes, which cannot teach a sensitivity either; learned, they drifted by errors in
variables (on an independent simulator's logs, +0.9 % on average in quiet balance, e²/P 2.7).

The accelerometer's constant bias b (the specification's ``turn_on_bias``) is no state: on level
ground it is a tilt (b + g δθ = 0), so the filter estimates θ − b/g and the encoder zero
c − b/g exactly, and the covariance it reports (:meth:`EKFEstimator.covariance12`, the
diagnostics, the NEES) adds (σ_b/g)² on that block, as a Schmidt consider parameter would
(zero for the twin's IMU presets, which leave no turn-on bias to the accelerometer).

Point-sampled IMU rows and commands sampled from a faster loop (a log's ``[imu] sampling =
"point"``, ``[commands] semantics = "sampled"``): :meth:`EKFEstimator.set_sampling`.

Latency: the filter runs L = max(gyro, accelerometer, encoder latency) periods behind,
where every sample it uses has arrived; the estimate handed to the controllers is its state
predicted the L periods forward with equation (1) and the commands since. The gyro and
the accelerometer are stored under their own latencies and paired by sample time.

Latency changes are watched (:meth:`EKFEstimator._watch_latency`, with one IMU sample per
control period): θ̈ responds to the wheel torques at once, so every 50 ms the gyro's second
difference over the last 0.5 s is correlated with the commands' differences at candidate
latencies 0–100 ms; the commands are known exactly and undelayed, so the correlation
peaks at the gyro's true latency. When another latency wins clearly (ρ ≥ 0.2, 0.15 above
the assumed one's) in three checks in a row, the event "gyro latency changed: now about
20 ms (was 5 ms) ..." is logged, the samples not yet used are re-aligned and L grows (the
filter pauses for the difference, the forward prediction covers it). The accelerometer is
taken to have changed with it when its arrivals stopped for as long at the same time (the
event then says "gyro and accelerometer"); an accelerometer-only change is not detected,
nor is a change while the IMU runs slower than the control loop. The window holds every
gyro sample the filter takes as a measurement of the rate: the ones it rejected as
outliers (spikes), stale ones and clipped ones are left out like missing ones, and a row
of unusual size is winsorised (counted at 5 robust σ with its sign), not left out. A screen
that left such rows out made false events during pushes (issue 29): it dropped the rows of
a shove's catch that the commands explain best, and the catch's slow remainder then
correlated best at 25–30 ms - on push-recovery at seeds 0–49, 103 false changes on 83 of
the 150 runs of IT2, type-1 and LQR, one of which fell (the measurements and the
mechanism are in :class:`~estimation.ekf_policies.LatencyWatch`). Now no event on any
built-in scenario at seeds 0–49 with the three controllers (900 runs;
benchmarks/latency_watch_sweep.py). Stated time: the event comes within 1.5 s of the
change (tests/test_estimator_faults.py). Measured (θ0 = 0.2 rad, fault at 2 s, 10 seeds,
IT2 with the default design; before the fix the same but a median of 0.40 s for the
first): gyro 5 → 20 ms logged 0.20–0.60 s after it (median 0.35), 10/10 balanced, θ RMSE
median 1.5 mrad; gyro and accelerometer 5 → 20 ms 0.25–0.65 s, 10/10, 1.6 mrad; gyro
5 → 15 ms 0.20–0.60 s and 5 → 10 ms 0.30–1.20 s. Until the event the filter works with
the old latency, so the error in that window is as before.

No NaN or infinity leaves: a non-finite state or covariance restores the last good
estimate with its covariance inflated, and the reason is logged in ``events``. Nor does an
estimate out of its physical range stay: |θ| ≥ π/2, θ's variance beyond a tilt's whole range
(π²/12), or a P no longer positive definite (an LDLᵀ pivot ≤ 0, the same verdict on either
core; its diagonal can stay positive meanwhile) re-initialises the filter from the
accelerometer for a robot that may be moving (:meth:`EKFEstimator._lost`, an event).

Two implementations of one algorithm: the reference runs on filterpy's
ExtendedKalmanFilter in Python (:class:`~estimation.twin_ekf.TwinEKF`); the compiled kernel
``estimation._ekf`` (built by setup.py where a C compiler is present; ``TWIN_PURE_PYTHON=1``
turns it off) does the same step in about 7 µs instead of 150–260 µs, with x and P kept on
the Python side in a :class:`KernelState`. tests/test_estimator_kernel.py holds them
together. Only the reference path imports filterpy (whose package imports scipy.stats, 0.8 s
of a command's start-up), and the χ² gates come from :mod:`estimation.gates`.

The same bits on every CPU (issue 25): no matrix product or solve here goes through numpy's
BLAS/LAPACK (``@``, ``np.dot``, ``np.linalg``), whose last bits depend on the kernel OpenBLAS
picks for the CPU. The Python code (the reference path's steps, the coasting steps and
the latency watch of both paths) uses :mod:`estimation.detlinalg`, which adds every sum's
products in ascending order, as the kernel's C loops do; the encoder update of the
reference path (:class:`~estimation.twin_ekf.TwinEKF`) and its innovation, NIS and
truncation quantities follow the kernel's association term for term. Measured: every
OPENBLAS_CORETYPE (Prescott … SkylakeX) and numpy SIMD level give byte-identical runs on
both paths (before, the reference path parted after 0.02 s and the compiled one at its
first coasting step). Cost (benchmarks/bench_estimator.py, median per control step): the
reference path 203 → 259 µs (numpy calls of a few µs each instead of ~1 µs BLAS
products), the compiled path 13.4 → 13.9 µs (its latency watch). The transcendental
functions (sin, cos, tan, exp, erfc, atan2) are libm's, scalar, in both paths (as in the
plant and PyBullet): glibc picks its FMA or its SSE2 variant of each per CPU (measured,
glibc 2.36: about 1 argument in 1000 rounds differently), so runs are bit-identical among
CPUs with FMA (x86-64-v3: Haswell, Zen and later) and among CPUs without, not between
the two.
"""
from __future__ import annotations

import copy
import math
from statistics import NormalDist

import numpy as np

from estimation.detlinalg import affine, mm, mm3, mv, positive_definite, quad_inv, solve
from estimation.ekf_core import (AL, BY, BZ, C0, H0, PS, SAX, SAZ, STATE_NAMES, STATE_UNITS, SY, SZ, TH, V,  # noqa: F401
                                 KernelState, N, compiled_kernel_loaded, cov_predict, make_core)
from estimation.ekf_core import _kernel  # noqa: F401 - golden.py and the tests read ekf._kernel
from estimation.ekf_policies import (ACCEL_MAX_IN_ROW, INSIDE_MARGIN, WATCH_EVERY, WATCH_MARGIN,  # noqa: F401
                                     WATCH_MAX_LAG, WATCH_PERSIST, WATCH_RHO, WATCH_WINDOW, AccelOutlierTest,
                                     ConsiderStates, EncoderGate, KeepInside, LatencyWatch, truncated_measurement)
from estimation.model import MODEL_UNCERTAINTY, TORQUE_TOLERANCE, EstimatorModel
from twin.errors import TwinError
from twin.protocols import Estimate

GROUPS = ("gyro", "accel", "encoders")
# the constants the encoders and the IMU cannot tell apart from the strapdown integration's
# own errors: kept in P (their uncertainty is accounted for) but never corrected (Schmidt);
# see the module docstring, "Consider states"
CONSIDER = ("encoder_zero", "encoder_heading_zero", "gyro_scale_y", "gyro_scale_z", "accel_scale_x", "accel_scale_z")
# consider states from the first step on, not only after learn_time (those of them in ``consider``):
# nothing a balancing robot does teaches the accelerometer's scale factors. It leans into every
# acceleration, so the forward specific force stays within a few noise σ of zero but in catches
# and pushes, where the model's own errors are largest; and the vertical one is g throughout. Their
# Jacobians are the measured specific force, whose noise is also in the error they are regressed
# on (errors in variables): on an independent simulator's logs (20 × 20 s) the forward one drifted
# by +0.9 % on average in quiet balance alone (0.07 % in catches, 0.04 % in drives), its e²/P 2.7
# and the vertical one's 2.2; held, 0.8 each, at 0.02 mrad more θ RMSE
UNTAUGHT = ("accel_scale_x", "accel_scale_z")
MAX_RIM_SPEED = 20.0  # m/s: encoder counts implying a faster wheel (relative to the body) are a fault
# a reading this many white-noise σ from the end of its range is censored, not a measurement:
# its noise is cut by the rail (see EKFEstimator._railed)
RAIL_SIGMAS = 3.0
# The physical range of the state (EKFEstimator._in_range). A robot on its wheels cannot tilt
# past lying flat, and the heading's kinematics (α̇ = ω_z / cos θ) are singular there: an
# estimate beyond |θ| = π/2 (as a filter given noise figures 25–100× too small reached, then
# its speed 680 m/s and θ 3880 rad, its covariance's condition number 1e29, beyond what
# double precision keeps positive definite) is lost, not a state to go on from. θ's variance
# beyond that of a tilt known only to lie in (−π/2, π/2), uniform there (π²/12), is no
# knowledge either; nor is the heading's beyond a uniform angle's on the circle (π²/3)
TILT_LIMIT = 0.5 * math.pi  # rad
TILT_VAR_MAX = math.pi * math.pi / 12.0  # rad²
HEADING_VAR_MAX = math.pi * math.pi / 3.0  # rad²
ENCODERS_LOST_AFTER = 1.0  # s without an encoder sample after which the position is reported as degraded
_NOT_IN_MODEL = frozenset((PS, AL, C0, H0))  # states the synthetic IMU sample does not depend on
TRAPEZOID_VAR = 1.0 / 12.0  # variance of U(−½, ½): where ∫v lies in Δt [v, v⁺] about the trapezoid's midpoint
_isfinite = math.isfinite
_new = tuple.__new__
_KERNEL = object()  # diagnostics(): the last update's innovation is the compiled core's to report


def _checked_uncertainty(unc) -> dict:
    from twin.params import PARAMETER_DOCS

    if not isinstance(unc, dict) or not all(isinstance(k, str) and k in PARAMETER_DOCS for k in unc) or \
            not all(not isinstance(v, bool) and isinstance(v, (int, float)) and 0.0 <= v <= 1.0 for v in unc.values()):
        raise TwinError("model_uncertainty must map parameter names (" + ", ".join(PARAMETER_DOCS) +
                        f") to relative half-ranges in [0, 1], got {unc!r}")
    return {k: float(v) for k, v in unc.items()}


def finite_reading(v) -> bool:
    """A sensor reading that arrived (not None) with every value finite."""
    # a finite sum proves every value finite (NaN and ±inf propagate); only a sum that
    # overflowed from huge finite values needs the values one by one
    return v is not None and (math.isfinite(sum(v)) or all(map(math.isfinite, v)))


def __getattr__(name: str):
    # TwinEKF lives with filterpy in estimation.twin_ekf, imported on first use: the
    # compiled path never needs filterpy, whose package imports scipy.stats (about 0.8 s)
    if name == "TwinEKF":
        from estimation.twin_ekf import TwinEKF

        return TwinEKF
    raise AttributeError(f"module 'estimation.ekf' has no attribute {name!r}")


class EKFEstimator:
    """State estimation for the controllers from the twin's sensor readings.

    Parameters
    ----------
    model : EstimatorModel
        Sensor specifications (for Q and R), the IMU's position, and equation (1) with
        the motors (for dropouts, outlier tests and the latency).
    imu_every : int
        Control periods per IMU sample.
    imu_latency, encoder_latency : int
        Nominal latencies in control periods (the filter assumes these).
    alpha0 : float
        The heading the encoders' odometry starts from (rad).
    gate_probability : float
        Probability that the gate rejects a measurement that fits the model.
    max_rejects_in_row : int
        See the module docstring.
    consider : sequence of str
        State names (:data:`STATE_NAMES`) that become consider states after ``learn_time``:
        measurements no longer correct their estimates (a Schmidt–Kalman filter: their
        uncertainty stays in P). Default :data:`CONSIDER`; ``()`` estimates every state for
        ever (a filter that drifts in long runs). Those of them in :data:`UNTAUGHT` (the
        accelerometer's scale factors) are held from the first step on.
    learn_time : float
        s; how long the consider states are estimated like the others (the initial
        alignment, through the robot's first recovery).
    model_uncertainty : mapping of str to float
        The box the robot's parameters are assumed in: parameter name (Table III, as
        :data:`twin.params.PARAMETER_DOCS`) → relative half-range in [0, 1] (0.3: ±30 %), each
        uniform inside it. Enters only where equation (1) stands in for a sensor (dropouts,
        rejected or clipped IMU samples; see :meth:`_coast`). Default
        :data:`~estimation.model.MODEL_UNCERTAINTY`; ``{}``: the parameters are taken as exact.
    compiled : bool or None
        Run the filter step in the compiled kernel (``estimation._ekf``, the same
        algorithm without filterpy's per-call overhead); None: when it is built. False:
        the pure-Python path on filterpy's ExtendedKalmanFilter, the reference.
    """

    name = "ekf"

    def __init__(self, model: EstimatorModel, imu_every: int = 1, imu_latency: int = 1, encoder_latency: int = 0,
                 alpha0: float = 0.0, gate_probability: float = 1e-4, max_rejects_in_row: int = 5,
                 consider=CONSIDER, learn_time: float = 10.0, model_uncertainty=None,
                 compiled: bool | None = None):
        if not (0.0 < gate_probability < 0.5):
            raise TwinError(f"gate_probability must be in (0, 0.5), got {gate_probability!r}")
        if isinstance(consider, str) or not isinstance(consider, (list, tuple)) or \
                not all(isinstance(n, str) and n in STATE_NAMES for n in consider):
            raise TwinError(f"consider must be a list of state names from {', '.join(STATE_NAMES)}, got {consider!r}")
        self._consider = ConsiderStates(consider, STATE_NAMES, 0.0)
        self.consider = self._consider.names
        self._consider_mask = self._consider.mask
        self._untaught = self._consider_mask & np.array([n in UNTAUGHT for n in STATE_NAMES])
        self._held = None  # the mask of the states held now (None: none)
        self.imu_sampling, self.command_semantics = "mean", "held"  # see set_sampling
        self.periods = "constant"  # see set_sampling: "rows", each step's period from the instants' times
        if isinstance(learn_time, bool) or not isinstance(learn_time, (int, float)) or \
                not (0.0 <= learn_time < math.inf):
            raise TwinError(f"learn_time must be a finite time >= 0 in s, got {learn_time!r}")
        self.learn_time = self._consider.learn_time = float(learn_time)
        self.model = model
        unc = dict(MODEL_UNCERTAINTY if model_uncertainty is None else _checked_uncertainty(model_uncertainty))
        self.model_uncertainty = {k: v for k, v in unc.items() if v > 0.0}
        self._unc_names = tuple(self.model_uncertainty)
        # σ (1) of each relative parameter error, uniform in its box
        self._unc_var = np.array([(h / math.sqrt(3.0)) ** 2 for h in self.model_uncertainty.values()])
        self.every, self.d_imu, self.d_enc = int(imu_every), int(imu_latency), int(encoder_latency)
        self.lag = max(self.d_imu, self.d_enc)
        # the latency watch (see _watch_latency): θ̈ responds to the wheel torques at once, so
        # the gyro's second difference follows the commands' differences at its latency
        m0 = model
        self._torque_sign = -1.0 if (m0.m11 + m0.m12) / (m0.m11 * m0.m22 - m0.m12 ** 2) > 0 else 1.0
        # the kernel below assumes one IMU sample per period, and it compares the assumed
        # latency with the others it looks at (0 … WATCH_MAX_LAG periods): a gyro assumed
        # later than that (over 100 ms at 200 Hz, over 4 ms at 5 kHz) has nothing to compare
        # with, so it is not watched
        self._watches = self.every == 1 and self.d_imu <= WATCH_MAX_LAG
        self.dt = self.every * model.dt
        self.alpha0 = float(alpha0)
        # an IMU sample is called an outlier only on much stronger evidence (1 − 1e-9):
        # wrongly replacing a real sample by the model's is worse than keeping a mild outlier
        self.max_rejects_in_row = int(max_rejects_in_row)
        imu = model.imu
        self.xi, self.zi = imu.position[0], imu.position[2]
        self.r = model.r
        self.b_r = model.b_r
        # per-sample noise of the IMU: white noise and the ADC step (the scale-factor part
        # depends on the reading and is added per sample)
        self._g_var = imu.gyro.white_sigma(self.dt) ** 2 + imu.gyro.lsb ** 2 / 12.0
        self._a_var = imu.accel.white_sigma(self.dt) ** 2 + imu.accel.lsb ** 2 / 12.0
        self._g_sf, self._a_sf = imu.gyro.scale_factor_error ** 2, imu.accel.scale_factor_error ** 2
        self._bias_q = imu.gyro.bias_random_walk ** 2 * self.dt
        # the accelerometer's constant forward bias b (turn_on_bias, σ_b m/s²) has no state: while
        # the robot moves on level ground it is one with a tilt (the strapdown's horizontal
        # acceleration is f_x cos θ + f_z sin θ, and b + g δθ = 0 for δθ = −b/g), so the filter
        # estimates θ − b/g and, through the encoders' ψ − θ + c, c − b/g, exactly: no update
        # sees b and no gain needs it. The reported covariance adds it as a Schmidt consider
        # parameter would, (σ_b/g)² on the θ, c block (:meth:`covariance12`); zero where the
        # specification has no turn-on bias (the twin's presets), so nothing changes there
        self._tilt_var = (imu.accel.turn_on_bias / model.g) ** 2
        self.delta = model.encoders.resolution
        # per wheel (left, right): e_i = ψ − θ + c ∓ ((b/r)(α − α_0) + h)
        self.H = np.zeros((2, N))
        for i, sgn in enumerate((-1.0, 1.0)):
            self.H[i, PS] = self.H[i, C0] = 1.0
            self.H[i, TH] = -1.0
            self.H[i, AL] = sgn * self.b_r
            self.H[i, H0] = sgn
        self._gate_policy = EncoderGate(gate_probability, max_rejects_in_row)
        self.gates, self.imu_gates = self._gate_policy.gates, self._gate_policy.imu_gates
        # an unchanged count with the estimate this many σ outside it is implausible (the one-sided
        # normal tail of gate_probability, 3.72 σ at 1e-4: the encoder gate's own probability)
        self._stuck_sigmas = NormalDist().inv_cdf(1.0 - gate_probability)
        self._inside = KeepInside(self.H, self.b_r, self.alpha0, self.delta, self._stuck_sigmas)
        self._inside_half = self._inside.half  # rad: see _keep_inside
        g, a = model.imu.gyro, model.imu.accel
        # the largest readings the ADC can give (a sample there may be clipped)
        self._limits = (g.lsb * ((1 << (g.bits - 1)) - 1),) * 2 + (a.lsb * ((1 << (a.bits - 1)) - 1),) * 2
        # a reading within RAIL_SIGMAS white-noise σ of them is no measurement (see _railed)
        self._rails = tuple(lim - RAIL_SIGMAS * tr.white_sigma(self.dt)
                            for lim, tr in zip(self._limits, (g, g, a, a)))
        # a stale (repeated) triad is told from a real one where the white noise per sample
        # spans ≥ 4 ADC steps: three axes then repeat by chance with probability < 4e-4
        self._stale_check = tuple(t.white_sigma(self.dt) >= 4.0 * t.lsb for t in (model.imu.gyro, model.imu.accel))
        # a wheel's counts cannot move faster than this relative to the body, nor leave a
        # 32-bit counter's range: anything else is a fault (see _screen_encoders)
        self._max_wheel_rate = MAX_RIM_SPEED / self.r
        self._enc_range = float(2 ** 31) * self.delta
        if compiled and _kernel is None:
            raise TwinError("the compiled EKF kernel is not built here (estimation._ekf); use compiled=None or False")
        self._compiled = compiled
        self._core_args = None
        if _kernel is not None and compiled is not False:
            m = model
            motor = m.motor
            self._core_args = (
                self.dt, self.r, self.xi, self.zi, self.b_r, self.alpha0, self.delta, self._g_var, self._a_var,
                self._bias_q, 0.0, self.gates[1], self.gates[2], 0.0, self.imu_gates[1], self.imu_gates[2],
                *self._limits, m.dt, m.m11, m.m12, m.m22, m.plant.n_bla, m.plant.d_b, m.plant.d_w, m.plant.g_b,
                m.plant.yaw_damping, m.plant.m33, m.g, float(motor is not None), float(m.compensates),
                m.tau_max, m.i_tau, m.sigma_tau, m.c_e, TORQUE_TOLERANCE, float(self.every), self._inside_half,
                self._stuck_sigmas, float(m.substeps), *([0.0] * N))
        self._new_run()

    def _new_run(self) -> None:
        """The state of one run, as before the first start(); start() calls it again when the
        filter is reused for another run, so that nothing of the previous one is kept."""
        # the filter core (estimation.ekf_core): filterpy's EKF, or the compiled kernel
        self._model_rate = (False, False)  # the filter's ω (y, z) is the model's, not a reading (_coast)
        self._at = 0  # the IMU instant of the step under way (_advance), for _lost
        self.core = core = make_core(self._compiled, _kernel if self._core_args is not None else None,
                                     self._core_args)
        self.kf = core.kf  # its state (x, P, consider)
        if self._tilt_var > 0.0:  # the per-step reader of x and P gets the reported covariance too
            into, tv, i, j = core.state_into, self._tilt_var, N + TH * N, N + C0 * N

            def state_into(out, row, into=into):
                into(out, row)
                o = out[row]
                o[i + TH] += tv
                o[i + C0] += tv
                o[j + TH] += tv
                o[j + C0] += tv
            core.state_into = state_into
        # the IMU-driven step: fused in the core where it can (the kernel), else composed here
        self._imu_step = self._imu_step_fused if core.fuses_imu_step else self._imu_step_composed
        # what every step calls, bound once: the core's fused step and forward prediction
        self._core_advance = core.advance if core.fuses_imu_step else None
        self._forward = core.forwarder(self.state6, self.model.step6)
        self.holding = False  # the consider states are held (after learn_time)
        self._held = None  # the states held now: UNTAUGHT's from start(), all consider states after learn_time
        self._points = None  # point-sampled IMU: the last (gyro, accel, instant) taken (see _point_means)
        self._pvar_g: dict[int, tuple] = {}  # the rebuilt means' own variances, by sample time (_point_means)
        self._pvar_a: dict[int, tuple] = {}
        self.last_dof = 0
        self.k = -1
        self.m = 0
        self._commands: dict[int, tuple[float, float]] = {}
        self._gyro: dict[int, tuple] = {}  # by sample time (control step), each half on its own latency
        self._acc: dict[int, tuple] = {}
        self._enc: dict[int, tuple] = {}
        # periods = "rows": each instant's time (s), kept back to the last encoder sample used, and
        # the period the core steps over now (None: the constant one it was built with)
        self._times: dict[int, float] = {}
        self._times_from = 0
        self._period_now = None
        self.d_gyro = self.d_acc = self.d_imu  # the latencies assumed now (periods); the watch may change them
        self.lag = max(self.d_imu, self.d_enc)
        self.latency_changes = 0
        self.accel_outliers = 0  # accelerometer halves replaced by the model's (the gyro's kept)
        self._acc_out = False
        self._acc_e = None  # the last accelerometer innovation (m/s², (f_x, f_z)), None: not computed
        self._accel = AccelOutlierTest(self.imu_gates[2], self.imu_gates[1])
        # the latency watch (None: not watched, see __init__)
        self._watch = LatencyWatch(self._torque_sign) if self._watches else None
        self.accepted = dict.fromkeys(GROUPS, 0)
        self.rejected = dict.fromkeys(GROUPS, 0)
        self.in_row = 0
        self.last_nis = math.nan
        self._innov = None  # the last encoder update's (y, S), or _KERNEL: ask the compiled core
        self._fit = None  # _encoder_fit's last (y, S), which _gate takes when it sets last_nis
        self.predict_only = 0
        self.unchanged_encoders = 0
        self.interval_updates = 0  # truncated updates that brought the estimate back into a count
        self.saturated = 0
        self._last_enc = None
        self._last_imu = None
        self._stale_in_row = 0
        self.stale = 0
        self._aug = None  # the coasting covariance of (x, ω, ω₋₁, δp), see _coast
        # point samples, the reference path: Cov(δx, n) with the last sample's noise (see _propagate;
        # None: nothing carried), the next step's, and the axes the model stands in for (_imu_sample)
        self._Cx = self._Cx_next = self._rep = None
        self._dp = None  # the model parameters' relative errors while coasting (model_uncertainty's order)
        self._implausible = 0
        self._still = 0  # unchanged counts in a row with the estimate implausibly far outside them
        self.stuck_since = None  # s: when the encoders were taken as stuck (None: they count)
        self.stuck_total = 0.0  # s spent with the encoders taken as stuck
        self._enc_seen_t = None  # s: the last encoder reading that arrived
        self._t0 = 0.0  # s: the first measurement's time
        self.events: list[tuple[float, str]] = []
        self.resets = 0
        self.resyncs = 0  # encoder samples forced in after rejections in a row, and re-based zeros

    # ---- public -----------------------------------------------------------------------
    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    @property
    def compiled(self) -> bool:
        """True if the filter steps run in the compiled kernel."""
        return self.core.compiled

    @property
    def x(self) -> np.ndarray:
        """The filter's state (12,) at its own time t_{k−lag}."""
        self.core.pull()
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        """Its covariance (12, 12), as the filter's gains use it (:meth:`covariance12` reports it)."""
        self.core.pull()
        return self.kf.P

    def covariance12(self) -> np.ndarray:
        """The covariance (12, 12) of :attr:`x`'s error against the truth: :attr:`P` plus the
        accelerometer's turn-on bias as a consider parameter, (σ_b/g)² on the θ and encoder-zero
        block (see ``__init__``); :attr:`P` itself where the specification has no such bias."""
        P = self.P
        if self._tilt_var > 0.0:
            P = P.copy()
            for i in (TH, C0):
                P[i, TH] += self._tilt_var
                P[i, C0] += self._tilt_var
        return P

    def rates(self, x=None, w=None, w_prev=None) -> tuple[float, float]:
        """(θ̇, α̇) in rad/s at the filter's time: the gyro's mean rates over the last two
        periods (``w``, ``w_prev``; default the filter's) extrapolated linearly to the end of
        the last one."""
        x = self.kf.x if x is None else x
        (wy, wz), (wy0, wz0) = (self.core.w if w is None else w), (self.core.w_prev if w_prev is None else w_prev)
        wy, wz = 1.5 * wy - 0.5 * wy0, 1.5 * wz - 0.5 * wz0
        return (wy - x[BY]) / (1.0 + x[SY]), (wz - x[BZ]) / ((1.0 + x[SZ]) * math.cos(x[TH]))

    def state6(self, x=None, w=None, w_prev=None) -> np.ndarray:
        """[θ, θ̇, ψ, ψ̇, α, α̇] at the filter's time (or of state ``x`` and gyro history ``w``,
        ``w_prev``)."""
        x = self.kf.x if x is None else x
        thd, ald = self.rates(x, w, w_prev)
        th = x[TH]
        dz = -self.xi * math.sin(th) + self.zi * math.cos(th)
        return np.array([th, thd, x[PS], (x[V] - thd * dz) / self.r, x[AL], ald])

    def covariance6(self) -> np.ndarray:
        """Covariance (6, 6) of :meth:`state6` at the filter's time: P mapped through the
        Jacobian of [θ, θ̇, ψ, ψ̇, α, α̇] by the state (central differences), plus the
        gyro's white noise in the extrapolated rates (1.5² + 0.5² samples' worth)."""
        x = self.x
        J = np.empty((6, N))
        for j in range(N):
            h = 1e-6 * max(1.0, abs(x[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            J[:, j] = (self.state6(xp) - self.state6(xm)) / (2.0 * h)
        C = mm3(J, self.covariance12(), J.T)
        th = x[TH]
        dz = -self.xi * math.sin(th) + self.zi * math.cos(th)
        q_y, q_z = 1.0 / (1.0 + x[SY]), 1.0 / ((1.0 + x[SZ]) * math.cos(th))
        w = 2.5 * self._g_var
        # θ̇ enters ψ̇ through −θ̇ dz / r
        g = np.array([0.0, q_y, 0.0, -q_y * dz / self.r, 0.0, 0.0])
        C += w * np.outer(g, g)
        C[5, 5] += w * q_z * q_z
        return 0.5 * (C + C.T)

    def covariance(self) -> np.ndarray:
        """The :class:`twin.protocols.Estimator` hook: :meth:`covariance6`."""
        return self.covariance6()

    def diagnostics(self) -> dict:
        """The :class:`twin.protocols.Estimator` hook, about the last start/step: the filter's
        state ``x`` (12,) and covariance ``P`` (12, 12, :meth:`covariance12`) at its own time t_{k − lag}, the
        encoder update's ``nis`` (NaN where none was tried) with ``nis_dof`` (the number of
        wheels whose count changed; 0 where none was tried), and ``lag`` (control periods);
        where an update was tried, also its ``innovation`` y (nis_dof,) rad (the measured edge
        position less the predicted, one row per wheel whose count changed, left first) and
        ``innovation_cov`` S (nis_dof, nis_dof) rad², with nis = yᵀ S⁻¹ y."""
        d = {"x": self.x.copy(), "P": self.covariance12().copy(), "nis": self.last_nis, "nis_dof": self.last_dof,
             "lag": self.lag}
        if self.last_dof:
            inn = self._innov
            if inn is _KERNEL:  # the compiled core kept the update's y and S (estimation/_ekf.c)
                hook = getattr(_kernel, "innovation", None)  # None: a kernel built before it had one
                y, S = hook(self.core._core) if hook is not None else ((), ())
                inn = (np.array(y), np.array(S).reshape(len(y), len(y))) if len(y) else None
            if inn is not None:
                d["innovation"], d["innovation_cov"] = np.array(inn[0], float), np.array(inn[1], float)
        return d

    def degraded(self) -> list[str]:
        """What the estimate has lost at the filter's present time, one line each (empty: nothing):
        the position and speed when the encoders are taken as stuck (:meth:`_count_check`) or
        none has arrived for :data:`ENCODERS_LOST_AFTER` s; they then come from the IMU alone
        and drift (a dropped encoder stream leaves the robot balancing, not knowing where it is)."""
        out = []
        if self.k < 0:
            return out
        now = self._now()
        if self.stuck_since is not None:
            out.append(f"position: encoders stuck since t = {self.stuck_since:.3f} s (counts unchanged while the IMU "
                       "shows the wheels turning); position and speed from the IMU alone")
        elif self._enc_seen_t is None or now - self._enc_seen_t > ENCODERS_LOST_AFTER:
            since = self._t0 if self._enc_seen_t is None else self._enc_seen_t
            out.append(f"position: no encoder sample since t = {since:.3f} s; position and speed from the IMU alone")
        return out

    def stats(self) -> dict:
        stuck = self.stuck_total
        if self.stuck_since is not None and self.k >= 0:
            stuck += self._now() - self.stuck_since
        return {"accepted": dict(self.accepted), "rejected": dict(self.rejected),
                "encoders_stuck_s": stuck, "degraded": self.degraded(), "encoder_resyncs": self.resyncs,
                "rejected_total": self.rejected_total, "predict_only_steps": self.predict_only,
                "unchanged_encoder_samples": self.unchanged_encoders, "interval_updates": self.interval_updates,
                "saturated_imu_samples": self.saturated,
                "stale_imu_samples": self.stale, "accel_outliers": self.accel_outliers,
                "latency_changes": self.latency_changes,
                "resets": self.resets, "events": [f"t = {t:.3f} s: {why}" for t, why in self.events]}

    def start(self, meas) -> Estimate:
        """Initialise from the first readings, the robot at rest (control step 0).

        θ from the accelerometer's direction of gravity; v = 0; ψ = 0 (the twin's wheel
        angles start at 0); the encoders' zero c = θ, exactly as uncertain as θ; gyro
        biases 0 with the turn-on σ of the specification.
        """
        if self.k >= 0:  # a second run with the same filter: forget the first
            self._new_run()
        ok = finite_reading
        if not ok(meas.accel) or not ok(meas.gyro):
            raise TwinError("the estimator needs a gyro and an accelerometer reading at start")
        x, P = self._prior(meas.accel)
        self.last_nis, self.last_dof = math.nan, 0
        w = (meas.gyro[1], meas.gyro[2])
        self.core.set_state(x, P, w, w)
        self.k, self.m = 0, 0
        self._t0 = float(meas.t)
        if self.periods == "rows":
            self._times[0] = self._t0
        self._store(meas, 0)
        if finite_reading(meas.encoders):
            self._enc_seen_t = self._t0
            self._last_enc, self._last_enc_m = tuple(meas.encoders), -self.d_enc
        if self._untaught.any():  # held from the first step: nothing in a run teaches them (see UNTAUGHT)
            self._held = self._untaught
            self.core.hold(self._untaught)
        self.core.keep_good()
        self._last_estimate = tuple(self.state6())
        return Estimate(*self._last_estimate)

    def _prior(self, accel, moving: bool = False):
        """(x, P): the state of a robot at rest from the accelerometer reading ``accel``
        (f_x, f_y, f_z) m/s² (see :meth:`start`). ``moving``: the robot may be moving (a
        re-initialisation, :meth:`_lost`): the speed is then known only to lie within
        ±:data:`MAX_RIM_SPEED` (its uniform variance), and θ's variance takes in the
        specific force's departure from g, the least acceleration the reading shows; without
        a reading, θ is known only to lie in (−π/2, π/2)."""
        spec_g = self.model.imu.gyro
        x = np.zeros(N)
        if accel is None:
            theta0, var_theta, sc = 0.0, TILT_VAR_MAX, 0.0
        else:
            fx, _, fz = accel
            theta0 = math.atan2(-fx, fz)
            g = math.hypot(fx, fz)
            # tan θ reads tan θ (1 + s_x)/(1 + s_z): the scale errors tilt it by sc (s_x − s_z)
            sc = math.sin(theta0) * math.cos(theta0)
            # (the accelerometer's turn-on bias is not θ's error: the filter's θ is the tilt less b/g,
            # and the bias enters the reported covariance alone, see __init__)
            var_theta = self._a_var / max(g, 1.0) ** 2 + 2.0 * sc * sc * self._a_sf
            if moving:
                dev = (g - self.model.g) / self.model.g
                var_theta = min(var_theta + dev * dev, TILT_VAR_MAX)
        x[TH] = x[C0] = theta0
        x[AL] = self.alpha0
        bias_var = spec_g.turn_on_bias ** 2 + 1e-12
        # where the encoders' first edges lie is unknown: a constant offset of variance
        # Δ²/12 per wheel, Δ²/24 in the mean and in the half-difference
        edge_var = self.delta ** 2 / 24.0
        g_sf, a_sf = self._g_sf + 1e-12, self._a_sf + 1e-12
        v_var = MAX_RIM_SPEED ** 2 / 3.0 if moving else 1e-12
        P = np.diag([var_theta, 1e-12, v_var, 1e-12, bias_var, bias_var, var_theta + edge_var,
                     g_sf, edge_var, g_sf, a_sf, a_sf])
        P[TH, C0] = P[C0, TH] = var_theta
        for i in (TH, C0):
            P[i, SAX] = P[SAX, i] = -sc * self._a_sf
            P[i, SAZ] = P[SAZ, i] = sc * self._a_sf
        return x, P

    def step(self, meas, command) -> Estimate:
        """Advance to the next control instant.

        ``meas``: the :class:`twin.sensors.Measurement` that arrived now; ``command``:
        the wheel torque commands (ul, ur) in N·m applied over the period that just ended.
        """
        if self.k < 0:
            raise TwinError("call start() with the first measurement before step()")
        k = self.k = self.k + 1
        self.last_nis, self.last_dof = math.nan, 0  # diagnostics() reports this step's update alone
        self._commands[k - 1] = (float(command[0]), float(command[1]))
        timed = self.periods == "rows"
        if timed:
            self._times[k] = float(meas.t)
        self._store(meas, k)
        last = k - self.lag
        # one filter step per due IMU instant; after the assumed latency shrinks several are due
        for m in range(self.m + self.every, last + 1, self.every):
            if timed:
                t = self._times[m]
                self._set_period(t - self._times[m - 1])
            else:
                t = meas.t - (k - m) * self.model.dt
            # (ConsiderStates.due, inline: every step)
            if not self.holding and self.consider and t >= self._consider.learn_time - 1e-9:
                self._hold()
            try:
                self._advance(m, t)
            except (np.linalg.LinAlgError, FloatingPointError, ValueError, ZeroDivisionError, OverflowError) as err:
                self._restore(t, f"numerical failure in the filter ({err}); restored the last good estimate")
            for j in range(self.m - self.every, m - self.every):  # samples no step will need again
                self._commands.pop(j, None)
                self._gyro.pop(j, None)
                self._acc.pop(j, None)
                self._enc.pop(j, None)
                if self._pvar_g or self._pvar_a:
                    self._pvar_g.pop(j, None)
                    self._pvar_a.pop(j, None)
            self.m = m
        if timed:  # the instants' times no step will need again (see _span)
            keep = min(self.m - 1, self._last_enc_m if self._last_enc is not None else self.m - 1)
            while self._times_from < keep:
                self._times.pop(self._times_from, None)
                self._times_from += 1
        return self._estimate(k)

    def _set_period(self, dt: float) -> None:
        """periods = "rows": the next step spans ``dt`` s (the filter's step, the model's with its
        RK4 sub-steps, the gyro bias's random walk). The noise figures stay the rows' own: a point
        sample's noise does not depend on the time since the last one, and a mean's changes by
        the period's ratio to the nominal one (a few per cent on jittered rows)."""
        if dt == self._period_now:
            return
        if not (dt > 0.0 and math.isfinite(dt)):
            raise TwinError(f"instants must be strictly increasing in time; got a period of {dt!r} s")
        self._period_now = dt
        model = self.model
        model.dt = dt
        model.substeps = model._substeps()
        for other in model.__dict__.get("_perturbed", {}).values():  # the sensitivities' models too
            other.dt, other.substeps = dt, other._substeps()
        self.dt = dt
        self._bias_q = self.model.imu.gyro.bias_random_walk ** 2 * dt
        self.core.set_period(dt, dt, model.substeps, self._bias_q)

    def _now(self) -> float:
        """s: the time of the present instant."""
        if self.periods == "rows" and self.k in self._times:
            return self._times[self.k]
        return self._t0 + self.k * self.model.dt

    def _span(self, a: int, b: int) -> float:
        """s from instant ``a`` to instant ``b`` (periods = "rows": their times; before the first
        instant, the nominal period)."""
        if self.periods != "rows":
            return (b - a) * self.model.dt
        ta, tb = self._times.get(a), self._times.get(b)
        if ta is None:
            ta = self._t0 + a * self._nominal_dt
        if tb is None:
            tb = self._t0 + b * self._nominal_dt
        return tb - ta

    # ---- internals ---------------------------------------------------------------------
    def _hold(self) -> None:
        """From now on the consider states are held: no update corrects them."""
        self.holding = True
        self._held = self._consider_mask
        self.core.hold(self._consider_mask)

    def _store(self, meas, k: int) -> None:
        gyro, accel, enc = meas.gyro, meas.accel, meas.encoders
        # all three arrived and finite (a finite sum proves it; see finite_reading), the common
        # case, in one test; else each on its own
        if gyro is not None and accel is not None and enc is not None and \
                _isfinite(sum(gyro) + sum(accel) + sum(enc)):
            g_ok = a_ok = e_ok = True
        else:
            ok = finite_reading
            g_ok, a_ok, e_ok = ok(gyro), ok(accel), ok(enc)
        if not (g_ok and a_ok and e_ok):  # (the loop below only when a reading is missing or bad)
            for n, v, good in (("gyro", gyro, g_ok), ("accel", accel, a_ok), ("encoders", enc, e_ok)):
                if v is not None and not good:
                    self.events.append((meas.t, f"non-finite {n} reading ignored"))
        g_stale = False  # the gyro triad repeats the previous one (for the latency watch)
        if g_ok or a_ok:
            # each half on its own latency: they pair up by sample time in _advance
            g_new, a_new = (tuple(gyro) if g_ok else None), (tuple(accel) if a_ok else None)
            last_g, last_a = self._last_imu if self._last_imu is not None else (None, None)
            # with the noise several ADC steps wide, a triad repeating all three values is
            # stale (stuck), not a measurement: coast as without the sample
            g_stale = self._stale_check[0] and g_new is not None and g_new == last_g
            if g_stale or (self._stale_check[1] and a_new is not None and a_new == last_a):
                self.rejected["gyro"] += 1
                self.rejected["accel"] += 1
                self.stale += 1
                if self._stale_in_row == 0:
                    self.events.append((meas.t, "IMU sample repeats the previous one: stale, treated as missing"))
                self._stale_in_row += 1
            else:
                pvar = None
                if self.imu_sampling == "point":  # the interval's mean from its two ends (see set_sampling)
                    gyro, accel, pvar = self._point_means(k, gyro if g_ok else None, accel if a_ok else None)
                # a sample for a time the filter has already passed (just after the assumed
                # latency grew) can no longer be used
                if g_ok and k - self.d_gyro > self.m:
                    self._gyro[k - self.d_gyro] = gyro
                    if pvar is not None:
                        self._pvar_g[k - self.d_gyro] = pvar[0]
                if a_ok and k - self.d_acc > self.m:
                    self._acc[k - self.d_acc] = accel
                    if pvar is not None:
                        self._pvar_a[k - self.d_acc] = pvar[1]
                self._stale_in_row = 0
            self._last_imu = (g_new if g_ok else last_g, a_new if a_ok else last_a)
        watch = self._watch
        if watch is not None and k > 0:  # (_watch_latency, inline: every step)
            # the watch correlates only gyro samples that measure the rate: not those the filter
            # rejected as outliers (its IMU rejections less the stale ones), nor a stale or a
            # clipped one (see LatencyWatch)
            watch.filter_verdicts(self.m, self.rejected["gyro"] - self.stale, self.d_gyro)
            found = watch.observe(meas.t, k, gyro if g_ok else None, a_ok, self._commands.get(k - 1, (0.0, 0.0)),
                                  self.d_gyro, g_ok and not g_stale and abs(gyro[1]) < self._rails[0])
            if found is not None:
                self._latency_changed(meas.t, k, *found)
        if e_ok:
            if -self._enc_range <= enc[0] <= self._enc_range and -self._enc_range <= enc[1] <= self._enc_range:
                self._enc[k - self.d_enc] = enc
            else:
                self.events.append((meas.t, f"encoder reading {tuple(enc)} ignored: beyond a 32-bit "
                                            f"counter's range (±{self._enc_range:.4g} rad)"))

    def set_sampling(self, imu: str = "mean", commands: str = "held", periods: str = "constant") -> None:
        """How a log's rows were sampled (its ``[imu] sampling`` and ``[commands] semantics``).
        Call before :meth:`start`.

        ``imu``: ``"mean"`` (the default, the twin's IMU: each row the mean over the interval
        since the previous one, what the strapdown step integrates) or ``"point"`` (each the
        value at its instant). Point samples become the means the step takes by the trapezoid:
        the mean over [t_{k−1}, t_k] as the average of the samples at its two ends, exact for a
        rate that changes linearly over the interval (at the start, or after a gap: the sample
        itself). The noise figures stay the sample's: the average halves one mean's white noise
        but correlates neighbouring means, and what the strapdown integrates over many samples
        has the variance of one sample's noise per interval, as for means. A clipped end keeps
        its sample (the clipping test sees the rail).

        ``commands``: ``"held"`` (the default: a controller at the control rate, its output held
        over the period) or ``"sampled"`` (a faster loop's output, sampled at the rows). With
        sampled commands the latency watch is off: it looks for the gyro's response to the
        commands' steps, and a loop faster than the rows has already reacted to the rates
        within the row it commands in (the feedback, not the latency, sets the correlation; on
        logs of 33 Hz rows from a 1 kHz loop it reported 30–60 ms changes that were not there).

        ``periods``: ``"constant"`` (the default: every step spans 1 / control rate) or
        ``"rows"`` (a log whose rows are not on a regular grid, its instants the rows: each step
        spans the time from the previous measurement's ``t`` to this one's, the model and the
        strapdown integrating over it). Rows 30–33 ms apart put on a 30 ms grid arrive up to a
        period late, some instants get none and some two: on 33 Hz logs of a robot standing up
        from 0.5 rad, θ's RMSE doubled (0.017 → 0.030 rad) and θ was 0.056 rad off 0.5 s after
        the start. The latency watch is off (it counts in periods). Needs one IMU sample per
        period (``imu_every`` 1)."""
        if imu not in ("mean", "point"):
            raise TwinError(f"imu sampling must be \"mean\" or \"point\", got {imu!r}")
        if commands not in ("held", "sampled"):
            raise TwinError(f"command semantics must be \"held\" or \"sampled\", got {commands!r}")
        if periods not in ("constant", "rows"):
            raise TwinError(f"periods must be \"constant\" or \"rows\", got {periods!r}")
        if periods == "rows" and self.every != 1:
            raise TwinError(f"periods = \"rows\" needs one IMU sample per period (imu_every = 1), got {self.every}")
        self.imu_sampling, self.command_semantics = imu, commands
        if commands == "sampled" or periods == "rows":
            self._watches = False
            self._watch = None
        if periods == "rows" and self.periods != "rows":
            # the model's period changes from step to step: a model of this filter's own
            self.model = copy.copy(self.model)
            self.model.__dict__.pop("_perturbed", None)
            self._forward = self.core.forwarder(self.state6, self.model.step6)
            self._nominal_dt = self.dt
        self.periods = periods

    def _point_means(self, k: int, gyro, accel):
        """(gyro, accel, variances) of sample instant ``k`` as interval means from point samples
        (see :meth:`set_sampling`), remembering this instant's for the next. ``variances``:
        ((ω_y, ω_z, h_y, h_z), (f_x, f_z, h_x, h_z)) the mean's own uncertainty about the
        trapezoid, and h 1.0 where the mean is the average of two samples (its noise then half the
        previous interval's: see :meth:`_propagate`), as for ψ's
        (:data:`TRAPEZOID_VAR`): with the signal monotonic between its two samples a and b, the
        interval's mean lies anywhere between them, taken uniform: (b − a)² / 12. The
        trapezoid is exact for a linear change; a catch's rate, which rises within a few ms
        and then levels off, is not, and a 30 ms row holds it all (on 33 Hz rows of a robot
        standing up from 0.5 rad: 0.035 rad of θ in one row)."""
        prev = self._points
        out, var = [], []
        for j, v in enumerate((gyro, accel)):
            p = prev[j] if prev is not None and prev[2] == k - self.every else None
            if v is None or p is None:
                out.append(v)
                var.append((0.0, 0.0, 0.0, 0.0))
                continue
            rail = self._rails[2 * j]
            out.append(tuple(a if abs(a) >= rail else (b if abs(b) >= rail else 0.5 * (a + b)) for a, b in zip(v, p)))
            axes = (1, 2) if j == 0 else (0, 2)
            var.append(tuple((v[i] - p[i]) ** 2 * TRAPEZOID_VAR for i in axes)
                       + tuple(float(abs(v[i]) < rail and abs(p[i]) < rail) for i in axes))
        self._points = (gyro, accel, k)
        return out[0], out[1], var

    def _watch_latency(self, t: float, k: int, gyro, a_ok: bool, stale: bool = False) -> None:
        """Feed the latency watch (:class:`~estimation.ekf_policies.LatencyWatch`); on a change
        it declares, :meth:`_latency_changed` re-aligns. (:meth:`_store` runs this inline.)

        The watch is told which gyro samples are no measurement of the rate, so that it leaves
        them out of its window: the ones the filter has rejected as outliers since the last
        step (its count of IMU rejections less the stale ones; the filter has just used the
        samples up to ``self.m``), a ``stale`` one and one within :data:`RAIL_SIGMAS` σ of the
        rail (clipped). Every other sample is correlated, however large its second difference:
        see :class:`~estimation.ekf_policies.LatencyWatch` for why a size screen made false
        events during pushes."""
        watch = self._watch
        watch.filter_verdicts(self.m, self.rejected["gyro"] - self.stale, self.d_gyro)
        found = watch.observe(t, k, gyro, a_ok, self._commands.get(k - 1, (0.0, 0.0)), self.d_gyro,
                              gyro is not None and not stale and abs(gyro[1]) < self._rails[0])
        if found is not None:
            self._latency_changed(t, k, *found)

    def _latency_changed(self, t: float, k: int, new: int, rho: float) -> None:
        """The gyro's latency is now ``new`` periods: re-align the samples not yet used, and the
        accelerometer's too if it fell behind by as much at the same time (both halves of the
        IMU then stopped arriving for the same span: a gap of ``new − old`` samples in each,
        within a period of each other; an accelerometer-only change is not detected)."""
        old, delta = self.d_gyro, new - self.d_gyro
        acc = self._watch.accel_gapped(delta)
        dt_ms = 1e3 * self.model.dt
        for store, d in ((self._gyro, delta), (self._acc, delta if acc else 0)):
            if d:
                moved = {key - d: v for key, v in store.items() if key > self.m}
                for key in [key for key in store if key > self.m]:
                    del store[key]
                store.update({key: v for key, v in moved.items() if key > self.m})
        self.d_gyro = new
        if acc:
            self.d_acc += delta
        self.lag = max(self.d_gyro, self.d_acc, self.d_enc)
        self.latency_changes += 1
        self._watch.changed(k)
        what = "gyro and accelerometer latency" if acc else "gyro latency"
        self.events.append((t, f"{what} changed: now about {new * dt_ms:.0f} ms (was {old * dt_ms:.0f} ms; "
                               f"correlation with the commands {rho:.2f}): re-aligned, the filter now runs "
                               f"{self.lag} periods behind"))

    def _estimate(self, k: int) -> Estimate:
        """The filter's state predicted forward to control step ``k``; never non-finite."""
        s, finite = self._forward([self._commands.get(j, (0.0, 0.0)) for j in range(self.m, k)])
        if not finite:  # s is then the filter's own state, finite as a rule
            self.events.append((k * self.model.dt, "forward prediction non-finite; handing out the filter's own state"))
            if not all(map(math.isfinite, s)):
                self.events.append((k * self.model.dt, "the filter's own state gives a non-finite estimate; "
                                                       "handing out the last finite one"))
                s = self._last_estimate
        self._last_estimate = tuple(s)
        return _new(Estimate, s)  # Estimate(*s) without its Python-level __new__

    def _advance(self, m: int, t: float) -> None:
        """Predict from the filter's time to t_m and update with the encoders there."""
        self._at = m
        g, a = self._gyro.get(m), self._acc.get(m)
        imu = None if g is None or a is None else (g, a)
        if imu is not None and self.imu_sampling == "point":
            gv, av = self._pvar_g.get(m, (0.0,) * 4), self._pvar_a.get(m, (0.0,) * 4)
            imu = (g, a, (gv[0], gv[1], av[0], av[1]), (gv[2], gv[3], av[2], av[3]))
        if imu is None and (g is not None or a is not None):
            self.events.append((t, "an IMU sample without its gyro or accelerometer half was dropped"))
        command = self._commands.get(m - self.every, (0.0, 0.0))
        enc = self._screen_encoders(self._enc.get(m), m, t)
        if imu is not None:
            rail = self._railed(imu)
            if rail is not None:  # the model stands in for the clipped axes
                self.saturated += 1
                self.accepted["gyro"] += 1
                self.accepted["accel"] += 1
                self._acc_out = False
                self._accel.seen(None, False)
                self._coast(m, t, True, enc, command, rail)
                return
            eps_imu = self._imu_step(m, t, imu, enc, command)
            acc_out = self._acc_out
            self._accel.seen(self._acc_e, acc_out)
            if acc_out:
                self.accel_outliers += 1
            if eps_imu is None:
                self._aug = None
                self.accepted["gyro"] += 1
                if acc_out:
                    self.rejected["accel"] += 1
                    self.events.append((t, "accelerometer sample rejected as an outlier (off the specific force "
                                           "equation (1) predicts): the model's used, the gyro's kept"))
                else:
                    self.accepted["accel"] += 1
                return
            self.rejected["gyro"] += 1
            self.rejected["accel"] += 1
            self.events.append((t, f"IMU sample rejected as an outlier (encoder NIS {eps_imu:.3g} with it)"))
        self._coast(m, t, imu is not None, enc, command)

    def _screen_encoders(self, enc, m: int, t: float):
        """``enc``, or None if its counts moved further since the last sample used than a wheel
        can turn relative to the body (:data:`MAX_RIM_SPEED` at the rim, plus two counts).
        Such a jump is a fault of the encoders, not motion, so it never reaches the χ² gate
        and is never forced in. After ``max_rejects_in_row`` in a row the counts are taken to
        have jumped for good (a counter reset): their zeros c, h are re-based onto the
        reading, with the filter's uncertainty of the reading as theirs."""
        if enc is None:
            return None
        self._enc_seen_t = t
        if self._last_enc is None:
            self._last_enc, self._last_enc_m = tuple(enc), m
            return enc
        last = self._last_enc
        if self.stuck_since is not None:  # (see _count_check)
            if enc[0] == last[0] or enc[1] == last[1]:
                self.rejected["encoders"] += 1
                return None
            self.stuck_total += t - self.stuck_since
            self.events.append((t, f"encoder counts change again after {t - self.stuck_since:.3g} s stuck: used again"))
            self.stuck_since = None
            self._still = 0
        T = self._span(self._last_enc_m, m)
        limit = self._max_wheel_rate * T + 2.0 * self.delta
        jump = max(abs(enc[0] - last[0]), abs(enc[1] - last[1]))
        if jump <= limit:
            self._implausible = 0
            return enc
        self.rejected["encoders"] += 1
        self._implausible += 1
        if self._implausible == 1:
            self.events.append((t, f"encoder counts jumped {jump:.4g} rad in {T:.3g} s, more than a wheel can turn "
                                   f"({limit:.3g} rad): rejected"))
        if self._implausible >= self.max_rejects_in_row:
            self._rebase_encoders(enc, m, t)
        return None

    def _rebase_encoders(self, enc, m: int, t: float) -> None:
        self._Cx = None
        self.core.pull()
        x, P = self.kf.x.copy(), self.kf.P.copy()
        off = np.array([self.b_r * self.alpha0, -self.b_r * self.alpha0])
        y = np.asarray(enc, dtype=float) - (mv(self.H, x) + off)
        S = mm3(self.H, P, self.H.T) + np.eye(2) * self.delta ** 2 / 12.0
        x[C0] += 0.5 * (y[0] + y[1])
        x[H0] += 0.5 * (y[1] - y[0])
        for i in (C0, H0):
            P[i, :] = P[:, i] = 0.0
        P[C0, C0] = 0.25 * (S[0, 0] + S[1, 1] + 2.0 * S[0, 1])
        P[H0, H0] = 0.25 * (S[0, 0] + S[1, 1] - 2.0 * S[0, 1])
        self.kf.x, self.kf.P = x, P
        if self._aug is not None:
            self._aug[:N, :N] = P
            for i in (C0, H0):
                self._aug[i, N:] = self._aug[N:, i] = 0.0
        self.core.push()
        self._last_enc, self._last_enc_m = tuple(enc), m
        self._implausible = 0
        self.resyncs += 1
        self.events.append((t, f"encoder counts stayed {self.max_rejects_in_row} samples away from the estimate: "
                               f"re-based their zeros by ({y[0]:.4g}, {y[1]:.4g}) rad"))

    def _railed(self, imu):
        """None, or the IMU reading (ω_y, ω_z, f_x, f_z) and which axes of it are censored.

        A clipped reading says only "at least this much": it measures neither the rate nor the
        scale factor nor the bias, so it must not be fused as a measurement (PX4's EKF2 likewise
        counts clipped IMU samples and stops learning the biases on a clipped axis). A reading
        within :data:`RAIL_SIGMAS` σ of the rail is censored too: its noise is cut off by the rail
        (a censored Gaussian is not the white noise the filter assumes). Such an axis is taken
        from equation (1), with the model's uncertainty, by :meth:`_coast`; the other axes stay
        readings."""
        (_, wy, wz), (fx, _, fz) = imu[0], imu[1]
        r = self._rails
        if abs(wy) < r[0] and abs(wz) < r[1] and abs(fx) < r[2] and abs(fz) < r[3]:
            return None
        v = (wy, wz, fx, fz)
        return v, tuple(abs(a) >= b for a, b in zip(v, r))

    def _imu_sample(self, x, imu, command, acc_test: bool = False):
        """(sample, synthetic, saturated, accel outlier): the IMU reading as ((ω_y, ω_z, f_x,
        f_z), extra) for :meth:`_propagate`; an axis at the end of its range says only "at least
        this much", so the model's prediction (``synthetic``, else None) replaces it (``extra``
        then holds the variances it adds; None for a sample with no axis replaced). (A guard:
        :meth:`_railed` sends every sample within 3 σ of the rail to :meth:`_coast` first, so
        ``saturated`` is False on the filter's own path; the kernel keeps the same guard.) With
        ``acc_test`` the accelerometer half is tested against the model's first
        (:meth:`_acc_test`) and, an outlier, replaced by it: the gyro half is kept."""
        own = imu[2] if len(imu) > 2 else None  # the variances a rebuilt point sample adds (_point_means)
        sample = ((imu[0][1], imu[0][2], imu[1][0], imu[1][2]), None if own is None else np.array(own))
        sat = [abs(v) >= lim for v, lim in zip(sample[0], self._limits)]
        syn, acc_out = None, False
        self._acc_e = None
        if acc_test is not None and acc_test[0] > 0.0 and not (sat[2] or sat[3]):
            syn = self._synthetic(x, command)
            e, sx, sz = self._accel_innovation(x, sample[0], syn)
            self._acc_e = e
            # a push moves the specific force too, but also θ̈, which the gyro sees (its NIS
            # against the model: ≤ 18 on fault-free runs, 10³–10⁵ in a push): an accelerometer
            # outlier needs a gyro sample that agrees with the model (the 1 − 1e-9 gate). The
            # gyro's variance: its noise in this sample and in the two the model's θ̇ is
            # extrapolated from (1 + 1.5² + 0.5²), and the model's torque uncertainty
            eg, sg = sample[0][0] - syn[0][0], 3.5 * self._g_var + syn[1][0]
            acc_out = self._accel.is_outlier(acc_test, e, sx, sz, eg, sg)
        if not any(sat) and not acc_out:
            return sample, syn, False, False
        if syn is None:
            syn = self._synthetic(x, command)
        rep = [sat[0], sat[1], sat[2] or acc_out, sat[3] or acc_out]
        self._rep = rep
        own = (0.0,) * 4 if own is None else own
        return (tuple(sv if k else v for v, sv, k in zip(sample[0], syn[0], rep)),
                tuple(e if k else o for e, k, o in zip(syn[1], rep, own))), syn, any(sat), acc_out

    def _accel_innovation(self, x, sample, syn):
        """((e_x, e_z), S_x, S_z): the accelerometer half (f_x, f_z) of ``sample`` less the specific
        force equation (1) predicts from the state and the command (``syn`` from
        :meth:`_synthetic`), and its variance per axis = the accelerometer's per-sample noise +
        the model's torque uncertainty (``synthetic``'s) + the state's share (θ through
        gravity, g² P_θθ, in f_x; the scale factors, f² P_s). Measured on fault-free runs
        (θ0 = 0.2 rad): e/√S has mean square 1.1–1.6 over both axes, max 17.5 in 3000 samples;
        a ±1 m/s² spike gives 300–470."""
        P = self.kf.P
        fx, fz = syn[0][2], syn[0][3]
        sx = self._a_var + syn[1][2] + self.model.g * self.model.g * P[TH, TH] + fx * fx * P[SAX, SAX]
        sz = self._a_var + syn[1][3] + fz * fz * P[SAZ, SAZ]
        return (sample[2] - fx, sample[3] - fz), sx, sz

    def _acc_test(self):
        """(gate, b_x, b_z, may) for the accelerometer test of the next sample
        (:meth:`~estimation.ekf_policies.AccelOutlierTest.params`)."""
        return self._accel.params()

    def _imu_outlier(self, pred, syn, enc, m: int, command):
        """The encoders' NIS with the IMU sample behind ``pred`` (its step, from
        :meth:`_propagate`; ``syn`` the model's sample if already computed) if that marks the
        sample as an outlier, else None.

        Outlier: the encoders (every wheel, an unchanged one as "still inside its count")
        fail the IMU gate (1 − 1e-9) with the sample, and pass the normal gate with the
        sample equation (1) predicts instead."""
        x, P = self.kf.x, self.kf.P
        tm, eps = self._encoder_fit(enc, m, pred, P, test=True)
        if eps <= self.imu_gates[len(tm[0])]:
            return None
        alt = self._propagate(x, syn if syn is not None else self._synthetic(x, command))
        tm_alt, eps_alt = self._encoder_fit(enc, m, alt, P, test=True)
        return eps if eps_alt <= self.gates[len(tm_alt[0])] else None

    def _imu_step_composed(self, m: int, t: float, imu, enc, command):
        """The IMU-driven step composed here on the core's predict and update (the reference
        path): the accelerometer test, the IMU outlier test, then :meth:`_strapdown`; returns
        the encoders' NIS with the sample if it is an outlier (the state then unchanged), else None."""
        self._rep = None
        sample, syn, sat, acc_out = self._imu_sample(self.kf.x, imu, command, self._acc_test())
        half = None
        if len(imu) > 3:  # point samples (see _propagate): which axes are trapezoids, which the reading's
            rep = self._rep or (False,) * 4
            half = [0.0 if r else float(h) for h, r in zip(imu[3], rep)] + [0.0 if r else 1.0 for r in rep]
        pred = self._propagate(self.kf.x, sample, half=half)
        eps_imu = None if enc is None else self._imu_outlier(pred, syn, enc, m, command)
        if eps_imu is None:
            self.saturated += sat
            self._Cx = self._Cx_next
            self._strapdown(m, t, pred, enc)
        else:
            self._Cx = None
        self._acc_out = acc_out
        return eps_imu

    def _strapdown(self, m: int, t: float, pred, enc) -> None:
        """One step driven by an IMU sample, its prediction ``pred`` from :meth:`_propagate`,
        on the core's predict and update."""
        core = self.core
        x_next, F, Q, w = pred
        core.predict(x_next, F, Q, w)

        def update(em):
            z, off, H, R = em
            Cx = self._Cx
            if Cx is not None:  # Cov(δx, n) after the update: (I − K H) Cov(δx, n), K with the prior P
                P = core.kf.P
                PHt = mm(P, H.T)
                K = solve(mm(H, PHt) + R, PHt.T).T
                if self._held is not None:
                    K[self._held] = 0.0  # Schmidt, as the update
                self._Cx = Cx - mm(K, mm(H, Cx))
            core.update(z, off, H, R)

        self._encoder_step(enc, m, t, True, update)
        self._finish(t)

    def _imu_step_fused(self, m: int, t: float, imu, enc, command):
        """:meth:`_imu_step_composed` fused in the core (the compiled kernel), the counts and
        events kept here from its decisions; returns the encoders' NIS with the sample if it is
        an outlier (the state then unchanged), else None."""
        sample = (imu[0][1], imu[0][2], imu[1][0], imu[1][2]) if len(imu) == 2 else \
            (imu[0][1], imu[0][2], imu[1][0], imu[1][2], *imu[2], *imu[3])
        T = self._span(self._last_enc_m, m)
        # (EncoderGate.may_reject and AccelOutlierTest.params inline: every step)
        code_i, sat, code_e, nis, dof, ok, acc_out, ex, ez, inside = self._core_advance(
            sample, enc, self._last_enc if enc is not None else None, T, command,
            self.in_row < self.max_rejects_in_row, self._accel.test)
        self._acc_out = bool(acc_out)
        self._acc_e = (ex, ez)
        if code_i == 2:
            return nis
        self.saturated += sat
        self.interval_updates += inside & 15
        if enc is not None and (inside > 15 or self._still):  # (a count is implausible, or a run of them ends)
            self._count_check(t, inside >> 4)
        if code_e <= 1:
            if code_e == 1:
                self.unchanged_encoders += 1
                self._last_enc_m = m
            self.predict_only += 1
        else:
            self.last_nis, self.last_dof = nis, dof
            self._innov = _KERNEL
            if code_e == 3:
                self.rejected["encoders"] += 1
                self.in_row += 1
                self.predict_only += 1
            else:
                if code_e == 4:
                    self.resyncs += 1
                    self.events.append((t, f"encoders accepted after {self.in_row} rejections in a row "
                                           f"(NIS {nis:.3g} > gate {self.gates[dof]:.3g}): re-synchronising"))
                self.in_row = 0
                self.accepted["encoders"] += 1
                self._last_enc, self._last_enc_m = tuple(enc), m
        if ok < 0:  # finite but out of its physical range: re-initialised here
            self.core.pull()
            self._lost(t)
            self.core.push()
            self.core.keep_good()
        elif not ok:
            self.resets += 1
            self.events.append((t, "the state or covariance became non-finite or lost positivity, or the update "
                                   "failed numerically; restored the last good estimate"))
        return None

    def _coast(self, m: int, t: float, had_imu: bool, enc, command, rail=None) -> None:
        """One step where equation (1) stands in for the IMU: without a (trustworthy) sample, or
        (``rail`` from :meth:`_railed`: the reading and which of its axes are censored) for
        the axes of a sample at the end of their range, the others kept as readings.

        The predicted sample depends on the state, and on θ̇, which is no state of the
        filter but the gyro's last two samples ω, ω₋₁: while coasting these join the state
        (at the first coasting step ω, ω₋₁ are the readings with the gyro's white noise,
        uncorrelated). The Jacobian of the step then holds the pendulum's own instability, so
        the covariance grows as the model's error does and the encoders, which see the
        wheels, correct θ and θ̇ through the model. The model's parameters (``model_uncertainty``)
        join the state too, as random constants (relative errors δp with mean 0 and the box's
        variance at the first coasting step; state augmentation, Simon, *Optimal State
        Estimation*, 2006, §7.4): a wrong mass or height biases every synthetic sample the same
        way, so the errors of consecutive samples add up coherently, as white noise they would
        not (with the clipped samples of a catch from 0.48 rad the filter claimed about 8× too
        little, mean NEES 76). A synthetic gyro value is (1 + s_y) ω_model + b_y, so the step's
        Jacobian through it cancels its dependence on the scale factor and the bias: clipped
        samples teach the filter neither. The first real sample ends it (ω becomes a reading
        again). Always the Python path: coasting is rare, and one implementation serves both."""
        self._Cx = None  # (the compiled core's is cleared by the push at the end)
        kf = self.kf
        self.core.take_over()
        if not had_imu:
            self.predict_only += 1
        names = self._unc_names
        K = len(names)
        na = N + 4 + K
        Pa = self._aug
        if Pa is None:
            Pa = np.zeros((na, na))
            Pa[:N, :N] = kf.P
            Pa[N:N + 4, N:N + 4] = np.eye(4) * self._g_var
            Pa[N + 4:, N + 4:] = np.diag(self._unc_var)
            self._dp = np.zeros(K)
        x, w, wp = kf.x, self.core.w, self.core.w_prev
        rep = (True,) * 4 if rail is None else rail[1]
        # θ̇ and α̇ are the last two readings' linear extrapolation, 1.5 ω − 0.5 ω₋₁, exact only
        # for a rate linear over the two periods; where the model first stands in for a gyro axis
        # (its readings were used up to now) that extrapolation starts the model. Its error is
        # unknown but of the order of its own reach ½ (ω − ω₋₁): uniform within that, variance
        # (ω − ω₋₁)²/12, carried by ω₋₁ (weight ½ in the rate). At the start of a catch from
        # 0.35–0.45 rad (the torque stepping in, the gyro clipping in the next period) the
        # extrapolation was 0.93 rad/s short at σ 0.003, the model's θ 0.13 rad off at σ 0.023,
        # and the encoder zero kept ±10 mrad of it for good (mean NEES 29 over 10 logs; 18 with it)
        for i in (0, 1):
            if rep[i] and (self._aug is None or not self._model_rate[i]):
                dw = self.core.w[i] - self.core.w_prev[i]
                Pa[N + 2 + i, N + 2 + i] += dw * dw / 3.0
        self._model_rate = rep[:2]
        s6 = self.state6(x, w, wp)
        raw = self.model.synthetic_imu(s6, command, self.every)
        syn = self._scaled(x, raw)
        # the model's sample by its parameters (only the axes it stands in for)
        Dp = self.model.sensitivity(names, s6, command, self.every, raw[0]) if K else np.zeros((4, 0))
        for i in range(4):
            if rep[i]:
                Dp[i] *= (1.0 + x[SY]) if i == 0 else (1.0 + x[SZ]) if i == 1 else (1.0 + x[SAX]) if i == 2 else \
                    (1.0 + x[SAZ])
            else:
                Dp[i] = 0.0
        dp = self._dp
        value = tuple((syn[0][i] + float(mv(Dp[i:i + 1], dp)[0])) if rep[i] else rail[0][i] for i in range(4))
        extra = tuple(syn[1][i] if rep[i] else 0.0 for i in range(4))
        x1, F, Q, w1, L = self._propagate(x, (value, extra), with_L=True)
        z = np.concatenate([x, w, wp])

        def sample(zz):
            v = self._synthetic(zz[:N], command, (zz[N], zz[N + 1]), (zz[N + 2], zz[N + 3]))[0]
            return np.array([v[i] if rep[i] else 0.0 for i in range(4)])

        # the sample by (x, ω, ω₋₁, δp): forward differences (the model's RK4 step dominates a
        # coasting step's cost: half as many as central ones, 1e-6 relative error), the model's
        # sensitivity to its parameters
        D = np.zeros((4, na))
        at = np.array([syn[0][i] if rep[i] else 0.0 for i in range(4)])
        for j in range(N + 4):
            if j in _NOT_IN_MODEL:  # equation (1) does not depend on ψ, α nor the encoders' zeros
                continue
            h = 1e-6 * max(1.0, abs(z[j]))
            zp = z.copy()
            zp[j] += h
            D[:, j] = (sample(zp) - at) / h
        D[:, N + 4:] = Dp
        J = np.zeros((na, na))
        J[:N, :N] = F
        J[:N] += mm(L, D)
        J[N:N + 2] = D[:2]
        J[N + 2, N] = J[N + 3, N + 1] = 1.0
        for j in range(N + 4, na):
            J[j, j] = 1.0
        Pa = mm3(J, Pa, J.T)
        Pa[:N, :N] += Q
        # a new ω: the model's (its torque uncertainty added) or the reading (its white noise)
        Pa[N, N] += syn[1][0] if rep[0] else self._g_var
        Pa[N + 1, N + 1] += syn[1][1] if rep[1] else self._g_var
        kf.x, kf.P = x1, Pa[:N, :N].copy()
        self.core.w_prev, self.core.w = self.core.w, w1
        self._aug = Pa

        def update(em):
            zm_, off, H, R = em
            Ha = np.zeros((len(zm_), na))
            Ha[:, :N] = H
            za = np.concatenate([kf.x, self.core.w, self.core.w_prev, self._dp])
            Pa = self._aug
            PHt = mm(Pa, Ha.T)
            S = mm(Ha, PHt) + R
            Kg = solve(S, PHt.T).T
            if self._held is not None:
                Kg[:N][self._held] = 0.0  # Schmidt, as TwinEKF.update
            za = za + mv(Kg, zm_ - (mv(H, kf.x) + off))
            IKH = np.eye(na) - mm(Kg, Ha)
            Pa = mm3(IKH, Pa, IKH.T) + mm3(Kg, R, Kg.T)
            self._aug = 0.5 * (Pa + Pa.T)
            kf.x, kf.P = za[:N], self._aug[:N, :N].copy()
            self.core.w, self.core.w_prev = (za[N], za[N + 1]), (za[N + 2], za[N + 3])
            self._dp = za[N + 4:]

        self._encoder_step(enc, m, t, had_imu, update)
        self._finish(t)
        self.core.push()

    def _encoder_step(self, enc, m: int, t: float, had_imu: bool, update) -> None:
        """The gated encoder update after a prediction, with ``update(measurement)``."""
        em = eps = None
        raw = enc
        if enc is not None:
            em, eps = self._encoder_fit(enc, m, None, None)
            if em is None:  # unchanged counts: no edge was crossed (no new information)
                self.unchanged_encoders += 1
                self._last_enc_m = m
                enc = None
        if enc is None:
            if had_imu:
                self.predict_only += 1
            if em is None and raw is not None:  # unchanged counts: the wheels are still inside them
                self._keep_inside(raw, update, t)
        elif self._gate(em, t, eps):
            update(em)
            self.accepted["encoders"] += 1
            self._keep_inside(enc, update, t)
            self._last_enc, self._last_enc_m = tuple(enc), m
        elif had_imu:  # rejected: the step was a prediction only (without IMU, counted already)
            self.predict_only += 1

    def _keep_inside(self, enc, update, t: float) -> None:
        """For each wheel whose count has not changed since the last sample used: if the
        estimate has left that count by more than :data:`INSIDE_MARGIN` counts, the
        truncated update that brings it back.

        The wheel lies in [reading − Δ/2, reading + Δ/2) (the filter's frame of the count).
        An unchanged count is skipped as a measurement (its quantisation error is the same
        one again), but while a wheel dwells in one count for tenths of a second, v runs free
        on the accelerometer and the estimate drifts out of the count (ψ̂ up to 0.033 rad
        off in 600 s of paper-exp2). Outside the count, "still inside" is an active
        constraint: the prior of that wheel's angle, N(w, s²), is truncated to the interval
        and the state takes the truncated mean and variance (Simon & Simon, "Constrained
        Kalman filtering via density function truncation", 2010), written as the equivalent
        measurement (z, R) so that the update, Schmidt rows and all, is the ordinary one.

        Why only outside, and why a margin: the filter keeps a Gaussian, so after a
        truncation its tails reach past the count again, and the next sample's drift would
        truncate them again: the same information counted again and again, the overconfidence
        that made unchanged counts a skipped measurement in the first place. Truncating at the
        count's own edges (margin 0) made 818 updates in 20 runs × 3 s (from 0.05 rad, the
        nominal design) and took the encoders' NIS per degree of freedom from 0.93 to 0.74 and
        the mean NEES from 12.6 to 13.0; a margin of one count each side (a true but weaker
        constraint) makes 22, leaves NIS 0.99 and NEES 12.7, and still bounds the excursion
        (ψ̂ − ψ at most 0.011 rad in 600 s of paper-exp2, against 0.0051 rad with margin 0
        and 0.031 rad without). A mean more than the IMU
        gate's σ outside is left to the gate of the next edge (the filter, not the count, is
        then in doubt)."""
        last = self._last_enc
        if last is None:
            return
        for em in self._inside.measurements(enc, last, self.kf):  # (:class:`~estimation.ekf_policies.KeepInside`)
            update(em)
            self.interval_updates += 1
        self._count_check(t, self._inside.implausible)

    def _count_check(self, t: float, implausible: int) -> None:
        """After an encoder sample: ``implausible`` the mask of wheels whose count did not
        change although the estimate lies more than 3.72 σ (the encoder gate's probability,
        one-sided) outside it.

        Encoders that stop counting (a frozen reading, a broken wire) are not a latency change
        nor a robot standing still: while the robot moves, the IMU-driven prediction leaves the
        count, and an unchanged count then is a rejected measurement (no truncated update:
        :meth:`_keep_inside`). After ``max_rejects_in_row`` such samples in a row the encoders
        are taken as stuck (logged; :meth:`stats` reports the position as degraded): until both
        counts change again, their samples are dropped, and the position and speed come from
        the IMU alone, their covariance growing as it must. A robot that creeps at under a count
        per period's σ cannot be told from a stuck encoder by the IMU (it measures acceleration,
        not speed); there the truncation keeps the estimate at the count, which is as good as
        the IMU can do."""
        if not implausible:
            self._still = 0
            return
        self.rejected["encoders"] += 1
        self._still += 1
        if self._still >= self.max_rejects_in_row and self.stuck_since is None:
            self.stuck_since = t
            which = {1: "left encoder's count", 2: "right encoder's count"}.get(implausible, "encoder counts")
            self.events.append((t, f"{which} unchanged for {self._still} samples while the IMU shows the wheels "
                                   "turning: encoders taken as stuck, position and speed from the IMU alone"))

    def _finish(self, t: float) -> None:
        kf = self.kf
        kf.P = 0.5 * (kf.P + kf.P.T)
        if np.isfinite(kf.x).all() and np.isfinite(kf.P).all() and (np.diag(kf.P) > 0).all():
            if not self._in_range(kf.x, kf.P):
                self._lost(t)
            self.core.keep_good()
        else:
            self._restore(t, "the state or covariance became non-finite or lost positivity; "
                             "restored the last good estimate")

    @staticmethod
    def _in_range(x, P) -> bool:
        """The state within its physical range (as the compiled kernel's ``in_range``): |θ| below
        :data:`TILT_LIMIT`, θ's variance below :data:`TILT_VAR_MAX`, P positive definite."""
        return abs(x[TH]) < TILT_LIMIT and P[TH, TH] < TILT_VAR_MAX and positive_definite(P)

    def _lost(self, t: float) -> None:
        self._Cx = None
        """The estimate left its physical range (:meth:`_in_range`): re-initialise it, logged.

        Going on from such a state only diverges further (the heading's secant, then the
        speed, run away) and restoring the last good state, just as close to the edge, repeats
        the divergence with the covariance inflated each time. So the filter starts again as
        :meth:`start` does, from the accelerometer's reading at the filter's time, but for a
        robot that may be moving (:meth:`_prior` with ``moving``); ψ and α keep their
        estimates (α's variance capped at :data:`HEADING_VAR_MAX`, a uniform angle's), the
        encoder zeros are placed so that the last counts used are predicted, and the sensors'
        constants start again from their priors (what they were fitted to while the filter
        diverged teaches nothing)."""
        kf = self.kf
        x_old, P_old = kf.x, kf.P
        acc = self._acc.get(self._at)
        if acc is None and self._last_imu is not None:
            acc = self._last_imu[1]
        x, P = self._prior(acc, moving=True)
        for i in (PS, AL):
            if math.isfinite(x_old[i]):
                x[i] = x_old[i]
        pa = P_old[AL, AL]
        P[AL, AL] = min(pa, HEADING_VAR_MAX) if pa > 0.0 else HEADING_VAR_MAX
        enc = self._last_enc
        if enc is not None:  # the counts ψ − θ + c ± (b/r (α − α0) + h) (self.H)
            x[C0] = 0.5 * (enc[0] + enc[1]) - x[PS] + x[TH]
            x[H0] = 0.5 * (enc[1] - enc[0]) - self.b_r * (x[AL] - self.alpha0)
            P[H0, H0] += self.b_r * self.b_r * P[AL, AL]
            P[H0, AL] = P[AL, H0] = -self.b_r * P[AL, AL]
        kf.x, kf.P = x, P
        self._aug = None
        # (an event, not one of the ``resets``: those count restorations of the last good state)
        self.events.append((t, "the estimate left its physical range (|θ| ≥ π/2, θ's variance beyond a tilt's "
                               "whole range, or a covariance no longer positive definite): re-initialised from the "
                               "accelerometer, the robot taken as possibly moving"))

    def _encoder_fit(self, enc, m: int, pred, P, test: bool = False):
        """(measurement, NIS) of encoder sample ``enc`` at t_m against the prior of
        ``pred`` = (x⁺, F, Q, ω) from ``P`` (None: the filter's current prior).

        The measurement is the position of the last edge each wheel crossed since the last
        encoder sample used, for the wheels whose count changed: the wheel was exactly
        there at an unknown instant of the interval T, so it now lies beyond the edge by
        u·|q̇|T, u ~ U(0, 1), at most one count (mean half, variance (q̇T)²/12, plus the
        uncertainty of q̇). Unchanged counts carry no new information (None, None)
        - the same quantisation error again, which a white-noise model would count anew.

        ``test``: for the IMU outlier test, a wheel whose count did not change is still
        somewhere inside its count: a row with the reading, variance Δ²/12. (That is
        what catches an IMU spike between two edges.)
        """
        last = self._last_enc
        if last is None:
            self._last_enc, self._last_enc_m = tuple(enc), m
            last = self._last_enc
        changed = [i for i in (0, 1) if enc[i] != last[i]]
        rows = (0, 1) if test else changed
        if not rows:
            return None, None
        if pred is None:
            x, Pp, (wy, wz) = self.kf.x, self.kf.P, self.core.w
        else:
            x, F, Q, (wy, wz) = pred
            Pp = cov_predict(F, P, Q)
        T = self._span(self._last_enc_m, m)
        dlt, b_r = self.delta, self.b_r
        th = x[TH]
        thd = (wy - x[BY]) / (1.0 + x[SY])
        dz = -self.xi * math.sin(th) + self.zi * math.cos(th)
        wheel = (x[V] - thd * dz) / self.r - thd
        spin = b_r * (wz - x[BZ]) / ((1.0 + x[SZ]) * math.cos(th))
        var_q = Pp[V, V] / self.r ** 2 + self._g_var * ((1.0 + dz / self.r) ** 2 + b_r * b_r)
        z, off, R = [], [], []
        for i in rows:
            sgn = 2 * i - 1
            if i not in changed:
                z.append(enc[i])
                off.append(-sgn * b_r * self.alpha0)
                R.append(dlt * dlt / 12.0)
                continue
            up = enc[i] > last[i]
            d = min(abs(wheel + sgn * spin) * T, dlt)
            d = d if up else -d
            z.append(enc[i] - 0.5 * dlt if up else enc[i] + 0.5 * dlt)
            off.append(-sgn * b_r * self.alpha0 - 0.5 * d)
            R.append(min(d * d / 12.0 + var_q * T * T / 3.0, dlt * dlt / 12.0))
        H = self.H[list(rows)]
        z, off, R = np.array(z), np.array(off), np.diag(R)
        y = z - affine(off, H, x)
        S = mm(H, mm(Pp, H.T)) + R
        if not test:
            self._fit = (y, S)  # for diagnostics(), should _gate take this fit
        return (z, off, H, R), quad_inv(y, S)

    def _gate(self, em, t: float, eps: float) -> bool:
        """The χ² gate for encoder measurement ``em`` whose NIS is ``eps``: True to use it."""
        dof = len(em[0])
        self.last_nis, self.last_dof = eps, dof
        self._innov = self._fit
        gate = self.gates[dof]
        if not self._gate_policy.passes(eps, dof):
            if self._gate_policy.may_reject(self.in_row):
                self.rejected["encoders"] += 1
                self.in_row += 1
                return False
            self.resyncs += 1
            self.events.append((t, f"encoders accepted after {self.in_row} rejections in a row "
                                   f"(NIS {eps:.3g} > gate {gate:.3g}): re-synchronising"))
        self.in_row = 0
        return True

    def _synthetic(self, x, command, w=None, w_prev=None):
        """The IMU sample equation (1) predicts at the end of the next period, and the
        extra variance (gyro, accelerometer) that the model's torque uncertainty adds."""
        return self._scaled(x, self.model.synthetic_imu(self.state6(x, w, w_prev), command, self.every))

    @staticmethod
    def _scaled(x, raw):
        """:meth:`_synthetic` from the model's sample ``raw`` (true rates and specific force,
        and their variances): as the sensor would read it with the state's scale factors and biases."""
        (wy, wz, fx, fz), (gv, av) = raw
        return (((1.0 + x[SY]) * wy + x[BY], (1.0 + x[SZ]) * wz + x[BZ], (1.0 + x[SAX]) * fx, (1.0 + x[SAZ]) * fz),
                (gv, gv, av, av))

    def _propagate(self, x, sample, with_L: bool = False, half=None):
        """(x⁺, F, Q, (ω_y, ω_z)): one strapdown step with IMU ``sample`` (and the noise
        map L (12, 4), the derivative of x⁺ by the sample, with ``with_L``).

        ``sample`` is ((ω_y, ω_z, f_x, f_z), extra), the means over the period, with
        ``extra`` None for a real sample or the variances (4,) that synthetic values add. F and the noise map are the exact derivatives of the step, built by the
        chain rule over the state (vectors ``d*`` are gradients by x) and over the sample
        (``i*``, by (ω_y, ω_z, f_x, f_z)).
        """
        (wy, wz, fx, fz), extra = sample
        dt, r, xi, zi = self.dt, self.r, self.xi, self.zi
        th, v, by, bz = x[TH], x[V], x[BY], x[BZ]
        q, qz, qax, qaz = 1.0 / (1.0 + x[SY]), 1.0 / (1.0 + x[SZ]), 1.0 / (1.0 + x[SAX]), 1.0 / (1.0 + x[SAZ])
        E = np.eye(N)
        thm = (wy - by) * q
        th1 = th + dt * thm
        thb = 0.5 * (th + th1)
        s0, c0, s1, c1 = math.sin(th), math.cos(th), math.sin(th1), math.cos(th1)
        cb, tb = math.cos(thb), math.tan(thb)
        ad = (wz - bz) * qz / cb
        dx0, dz0 = xi * c0 + zi * s0, -xi * s0 + zi * c0
        dx1, dz1 = xi * c1 + zi * s1, -xi * s1 + zi * c1
        fxt, fzt = fx * qax, fz * qaz
        Fx = c1 * fxt + s1 * fzt
        Fz = -s1 * fxt + c1 * fzt
        v1 = v + dt * (Fx + ad * ad * dx1)
        x1 = x.copy()
        x1[TH] = th1
        x1[AL] = x[AL] + dt * ad
        x1[V] = v1
        # r ψ = (the IMU point's forward position) − dx(θ)
        x1[PS] = x[PS] + (0.5 * dt * (v + v1) - dx1 + dx0) / r

        dth1 = E[TH] + dt * (-q * E[BY] - thm * q * E[SY])
        ith1 = np.array([dt * q, 0.0, 0.0, 0.0])
        dad = ad * tb * 0.5 * (E[TH] + dth1) - (qz / cb) * E[BZ] - ad * qz * E[SZ]
        iad = ad * tb * 0.5 * ith1 + np.array([0.0, qz / cb, 0.0, 0.0])
        dFx = Fz * dth1 - c1 * fxt * qax * E[SAX] - s1 * fzt * qaz * E[SAZ]
        iFx = Fz * ith1 + np.array([0.0, 0.0, c1 * qax, s1 * qaz])
        dv1 = E[V] + dt * (dFx + 2.0 * ad * dx1 * dad + ad * ad * dz1 * dth1)
        iv1 = dt * (iFx + 2.0 * ad * dx1 * iad + ad * ad * dz1 * ith1)
        F = E.copy()
        F[TH] = dth1
        F[AL] = E[AL] + dt * dad
        F[V] = dv1
        F[PS] = E[PS] + (0.5 * dt * (E[V] + dv1) - dz1 * dth1 + dz0 * E[TH]) / r
        L = np.zeros((N, 4))
        L[TH] = ith1
        L[AL] = dt * iad
        L[V] = iv1
        L[PS] = (0.5 * dt * iv1 - dz1 * ith1) / r
        # white noise and ADC steps; the scale factors are states
        base = np.array([self._g_var, self._g_var, self._a_var, self._a_var])
        var = base.copy()
        if half is not None:
            # point samples (half: 1.0 where an axis's mean is the trapezoid (n_{k−1} + n_k)/2 of two
            # samples' noise, then 1.0 where the axis is the reading's): the mean's own noise σ²/2, and
            # its n_{k−1} half correlated with the state through Cx = Cov(δx, n_{k−1}) of the step before
            # (the filter's white-noise step would take σ², twice the one step's, or σ²/2 and lose the
            # correlation: half the drift of an integral over many steps)
            for j in range(4):
                if half[j]:
                    var[j] *= 0.5
        if extra is not None:
            var += extra
        Q = mm(L * var, L.T)
        self._Cx_next = None
        if half is not None:
            Cx = self._Cx
            if Cx is not None:
                for j in range(4):
                    if half[j]:
                        G = mv(F, Cx[:, j])
                        cross = 0.5 * np.outer(G, L[:, j])
                        Q = Q + cross + cross.T
            self._Cx_next = L * np.array([(0.5 if half[j] else 1.0) * base[j] if half[4 + j] else 0.0
                                          for j in range(4)])
        Q[BY, BY] += self._bias_q
        Q[BZ, BZ] += self._bias_q
        # ψ integrates v by the trapezoid, exact only if the acceleration is constant over the
        # period; the IMU gives its mean alone. With v monotonic in between, ∫v lies anywhere in
        # Δt [v, v⁺] (taken uniform: σ = Δt |v⁺ − v| / √12). At release the motors' torque
        # steps from nothing and falls with the back-EMF within the first period: the
        # trapezoid was off by 0.2-0.6 mrad of ψ at σ 0.12, and the encoder zero absorbed it
        hv = dt * (v1 - v) / r
        Q[PS, PS] += hv * hv * TRAPEZOID_VAR
        if with_L:
            return x1, F, Q, (wy, wz), L
        return x1, F, Q, (wy, wz)

    def _restore(self, t: float, why: str) -> None:
        self._Cx = None
        self.core.restore()
        self._aug = None
        self.resets += 1
        self.events.append((t, why))
