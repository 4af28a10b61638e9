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
all) and the encoders correct them too. See :class:`~estimation.ekf_filter.Coasting`.

Clipping (issue 29): a gyro or accelerometer axis at the end of its range (or within
:data:`~estimation.ekf_config.RAIL_SIGMAS` σ of it) is no measurement; equation (1) stands in for it on the coasting
path, the other axes kept as readings, and the step's Jacobian through the model's value
cancels the scale factor and the bias, so clipped samples teach the filter neither. While
equation (1) stands in for a sensor, the model's uncertain parameters (``model_uncertainty``)
join the state as random constants, so the errors of consecutive synthetic samples add up
as a wrong mass or height makes them add up (:class:`~estimation.ekf_filter.Coasting`).

Stuck encoders (issue 29): an unchanged count with the estimate more than 3.72 σ outside
it is a rejected measurement; ``max_rejects_in_row`` in a row and the encoders are taken
as stuck until both counts change (:meth:`~estimation.ekf_frontend.SensorFrontEnd.count_check`);
:meth:`EKFEstimator.degraded` says what the estimate has lost, and a run that ends so is "degraded".

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
(Δt |v⁺ − v| / r)² / 12 (:data:`~estimation.ekf_config.TRAPEZOID_VAR`).

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
truncated back (:meth:`~estimation.ekf_frontend.SensorFrontEnd.keep_inside`); without that, a wheel dwelling in one
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
wheel can turn (:data:`~estimation.ekf_config.MAX_RIM_SPEED` at the rim), or beyond a 32-bit counter, are faults
and never reach the gate (see :meth:`~estimation.ekf_frontend.SensorFrontEnd.screen_encoders`).
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
:data:`~estimation.ekf_config.ACCEL_MAX_IN_ROW` in a row the next is taken as real (``accel_outliers`` in
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

Latency changes are watched (:meth:`~estimation.ekf_frontend.SensorFrontEnd.store`, with one IMU sample
per control period): θ̈ responds to the wheel torques at once, so every 50 ms the gyro's second
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
accelerometer for a robot that may be moving (:meth:`~estimation.ekf_fusion.Fusion.lost`, an event).

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

Structure: :class:`EKFEstimator` (here) is the public estimator, a composition of

* :mod:`estimation.ekf_frontend`: the sensor front end (:class:`~estimation.ekf_frontend.SensorFrontEnd`:
  screening, stale samples, rails, point samples, the latency watch, the encoders' checks,
  re-basing and truncation) and the run's books (counts and events);
* :mod:`estimation.ekf_filter`: the filter's mathematics (:class:`~estimation.ekf_filter.StrapdownFilter`:
  x, P on a core of :mod:`estimation.ekf_core`, the strapdown step, the measurement models;
  :class:`~estimation.ekf_filter.Coasting`, the step on equation (1));
* :mod:`estimation.ekf_fusion`: the step of each sample time that takes the front end's samples
  through the filter under the policies of :mod:`estimation.ekf_policies` (the gates, the
  accelerometer test, the restore and the re-initialisation);
* :mod:`estimation.ekf_config`: every policy threshold once (:data:`~estimation.ekf_config.POLICY`)
  and the compiled kernel's typed configuration (:class:`~estimation.ekf_config.KernelConfig`),
  which says how the kernel's copy of the rules is held to the Python one.
"""
from __future__ import annotations

import copy
import math
from statistics import NormalDist

import numpy as np

from estimation.ekf_config import (ACCEL_MAX_IN_ROW, ENCODERS_LOST_AFTER, HEADING_VAR_MAX, INSIDE_MARGIN,  # noqa: F401
                                   MAX_RIM_SPEED, RAIL_SIGMAS, TILT_LIMIT, TILT_VAR_MAX, TRAPEZOID_VAR, WATCH_EVERY,
                                   WATCH_MARGIN, WATCH_MAX_LAG, WATCH_PERSIST, WATCH_RHO, WATCH_WINDOW)
from estimation.ekf_core import (AL, BY, BZ, C0, H0, PS, SAX, SAZ, STATE_NAMES, STATE_UNITS, SY,  # noqa: F401
                                 SZ, TH, V, KernelState, N, compiled_kernel_loaded, cov_predict, make_core)
from estimation.ekf_core import _kernel  # noqa: F401 - golden.py and the tests read ekf._kernel
from estimation.ekf_filter import StrapdownFilter, kernel_config
from estimation.ekf_frontend import GROUPS, Books, Clock, SensorFrontEnd, finite_reading  # noqa: F401
from estimation.ekf_fusion import Fusion
from estimation.ekf_policies import (AccelOutlierTest, ConsiderStates, EncoderGate, KeepInside,  # noqa: F401
                                     LatencyWatch, truncated_measurement)
from estimation.model import MODEL_UNCERTAINTY, EstimatorModel
from twin.errors import TwinError
from twin.params import PARAMETER_DOCS
from twin.protocols import Estimate

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
_NO_COMMAND = (0.0, 0.0)
_new = tuple.__new__


def _checked_uncertainty(unc) -> dict:
    if not isinstance(unc, dict) or not all(isinstance(k, str) and k in PARAMETER_DOCS for k in unc) or \
            not all(not isinstance(v, bool) and isinstance(v, (int, float)) and 0.0 <= v <= 1.0 for v in unc.values()):
        raise TwinError("model_uncertainty must map parameter names (" + ", ".join(PARAMETER_DOCS) +
                        f") to relative half-ranges in [0, 1], got {unc!r}")
    return {k: float(v) for k, v in unc.items()}


def __getattr__(name: str):
    # TwinEKF lives with filterpy in estimation.twin_ekf, imported on first use: the
    # compiled path never needs filterpy, whose package imports scipy.stats (about 0.8 s)
    if name == "TwinEKF":
        # heavy: filterpy imports scipy.stats; only a caller who asks for TwinEKF pays for it
        from estimation.twin_ekf import TwinEKF

        return TwinEKF
    raise AttributeError(f"module 'estimation.ekf' has no attribute {name!r}")


class EKFEstimator:
    """State estimation for the controllers from the twin's sensor readings: the sensor front
    end (:class:`~estimation.ekf_frontend.SensorFrontEnd`), the filter
    (:class:`~estimation.ekf_filter.StrapdownFilter`) and the step that joins them
    (:class:`~estimation.ekf_fusion.Fusion`), composed.

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
        rejected or clipped IMU samples; see :class:`~estimation.ekf_filter.Coasting`). Default
        :data:`~estimation.model.MODEL_UNCERTAINTY`; ``{}``: the parameters are taken as exact.
    compiled : bool or None
        Run the filter step in the compiled kernel (``estimation._ekf``, the same
        algorithm without filterpy's per-call overhead); None: when it is built. False:
        the pure-Python path on filterpy's ExtendedKalmanFilter, the reference.
    """

    name = "ekf"
    state_names = STATE_NAMES  # what state_into writes (estimation.consistency measures this layout)

    def __init__(self, model: EstimatorModel, imu_every: int = 1, imu_latency: int = 1, encoder_latency: int = 0,
                 alpha0: float = 0.0, gate_probability: float = 1e-4, max_rejects_in_row: int = 5,
                 consider=CONSIDER, learn_time: float = 10.0, model_uncertainty=None,
                 compiled: bool | None = None):
        if not (0.0 < gate_probability < 0.5):
            raise TwinError(f"gate_probability must be in (0, 0.5), got {gate_probability!r}")
        if isinstance(consider, str) or not isinstance(consider, (list, tuple)) or \
                not all(isinstance(n, str) and n in STATE_NAMES for n in consider):
            raise TwinError(f"consider must be a list of state names from {', '.join(STATE_NAMES)}, got {consider!r}")
        if isinstance(learn_time, bool) or not isinstance(learn_time, (int, float)) or \
                not (0.0 <= learn_time < math.inf):
            raise TwinError(f"learn_time must be a finite time >= 0 in s, got {learn_time!r}")
        self._consider = ConsiderStates(consider, STATE_NAMES, learn_time)
        self.consider = self._consider.names
        self.learn_time = self._consider.learn_time
        self._untaught = self._consider.mask & np.array([n in UNTAUGHT for n in STATE_NAMES])
        self.imu_sampling, self.command_semantics = "mean", "held"  # see set_sampling
        self.periods = "constant"  # see set_sampling: "rows", each step's period from the instants' times
        self.model = model
        unc = dict(MODEL_UNCERTAINTY if model_uncertainty is None else _checked_uncertainty(model_uncertainty))
        self.model_uncertainty = {k: v for k, v in unc.items() if v > 0.0}
        if compiled and _kernel is None:
            raise TwinError("the compiled EKF kernel is not built here (estimation._ekf); use compiled=None or False")
        self.every, self.d_imu, self.d_enc = int(imu_every), int(imu_latency), int(encoder_latency)
        self.alpha0 = float(alpha0)
        self.max_rejects_in_row = int(max_rejects_in_row)
        self.filter = f = StrapdownFilter(model, self.every, self.alpha0, self.model_uncertainty)
        gate = EncoderGate(gate_probability, max_rejects_in_row)
        self.gates, self.imu_gates = gate.gates, gate.imu_gates
        # an unchanged count with the estimate this many σ outside it is implausible (the one-sided
        # normal tail of gate_probability, 3.72 σ at 1e-4: the encoder gate's own probability)
        stuck_sigmas = NormalDist().inv_cdf(1.0 - gate_probability)
        # the latency watch: θ̈ responds to the wheel torques at once, so the gyro's second
        # difference follows the commands' differences at its latency, with the sign of
        # equation (1)'s torque term. The watch assumes one IMU sample per period, and it compares
        # the assumed latency with the others it looks at (0 … WATCH_MAX_LAG periods): a gyro
        # assumed later than that (over 100 ms at 200 Hz, over 4 ms at 5 kHz) has nothing to
        # compare with, so it is not watched
        torque_sign = -1.0 if (model.m11 + model.m12) / (model.m11 * model.m22 - model.m12 ** 2) > 0 else 1.0
        watches = self.every == 1 and self.d_imu <= WATCH_MAX_LAG
        self.front = SensorFrontEnd(f, self.d_imu, self.d_enc, max_rejects_in_row, stuck_sigmas, watches, torque_sign)
        self.fusion = Fusion(f, self.front, gate)
        self._compiled = compiled
        # the compiled kernel's configuration, by name (estimation.ekf_config), from the constants
        # as built (a log's own periods change them run by run, set_sampling)
        self._config = kernel_config(f, self.gates, self.imu_gates, self.max_rejects_in_row, self.front.inside.half,
                                     stuck_sigmas) \
            if _kernel is not None and compiled is not False else None
        self._new_run()

    def _new_run(self) -> None:
        """The state of one run, as before the first start(); start() calls it again when the
        filter is reused for another run, so that nothing of the previous one is kept."""
        self._books = books = Books()
        self._clock = clock = Clock(self.model, self.periods == "rows", getattr(self, "_nominal_dt", self.dt))
        f = self.filter
        f.new_run(self._compiled, _kernel if self._config is not None else None, self._config)
        core = f.core
        if f.tilt_var > 0.0:  # the per-step reader of x and P gets the reported covariance too
            into, tv, i, j = core.state_into, f.tilt_var, N + TH * N, N + C0 * N

            def state_into(out, row=0, into=into):
                into(out, row)
                if not isinstance(out, np.ndarray):
                    out = np.frombuffer(out, dtype=np.float64)
                o = out[row] if out.ndim == 2 else out.reshape(-1, N + N * N)[row]
                o[i + TH] += tv
                o[i + C0] += tv
                o[j + TH] += tv
                o[j + C0] += tv
            core.state_into = state_into
        # the per-step reader's own function, bound once (see the method state_into)
        self.state_into = core.state_into
        self.front.new_run(books, clock)
        self.fusion.new_run(books, clock)
        # what every step calls, bound once: the front end's and the core's forward prediction
        self._store, self._due, self._advance = self.front.store, self.front.due, self.fusion.advance
        self._forward = core.forwarder(f.state6, self.model.step6)
        self.holding = False  # the consider states are held (after learn_time)
        self._hold_at = self._consider.hold_from  # s: when they will be (inf: never, or held already)
        self.k = -1
        self.m = 0
        self._commands: dict[int, tuple[float, float]] = {}
        self.lag = self.front.lag
        self.last_nis, self.last_dof = math.nan, 0
        self._period_now = None  # periods = "rows": the period the core steps over now (None: the constant one)

    # ---- public -----------------------------------------------------------------------
    @property
    def rejected_total(self) -> int:
        return sum(self._books.rejected.values())

    @property
    def compiled(self) -> bool:
        """True if the filter steps run in the compiled kernel."""
        return self.filter.core.compiled

    @property
    def core(self):
        """The filter's core (:mod:`estimation.ekf_core`) of the present run."""
        return self.filter.core

    @property
    def kf(self):
        """The core's Python-side state (x, P, consider)."""
        return self.filter.kf

    @property
    def events(self) -> list[tuple[float, str]]:
        """(t in s, what) of every event of the present run."""
        return self._books.events

    @property
    def resets(self) -> int:
        """Restorations of the last good state in the present run."""
        return self._books.resets

    # the filter's constants, by their old names (units: see StrapdownFilter)
    dt = property(lambda self: self.filter.dt, doc="s: the filter's step (a log's own rows: the present one).")
    r = property(lambda self: self.filter.r, doc="m: the wheels' radius.")
    b_r = property(lambda self: self.filter.b_r, doc="1: b / r.")
    delta = property(lambda self: self.filter.delta, doc="rad: one encoder count.")
    H = property(lambda self: self.filter.H, doc="The wheels' measurement rows (2, 12).")
    _g_var = property(lambda self: self.filter.g_var, doc="(rad/s)²: the gyro's noise per sample.")
    _a_var = property(lambda self: self.filter.a_var, doc="(m/s²)²: the accelerometer's noise per sample.")
    _bias_q = property(lambda self: self.filter.bias_q, doc="(rad/s)²: the gyro bias's random walk per step.")
    _watch = property(lambda self: self.front.watch, doc="The latency watch of the present run (None: none).")

    @property
    def x(self) -> np.ndarray:
        """The filter's state (12,) at its own time t_{k−lag}."""
        self.filter.core.pull()
        return self.filter.kf.x

    @property
    def P(self) -> np.ndarray:
        """Its covariance (12, 12), as the filter's gains use it (:meth:`covariance12` reports it)."""
        self.filter.core.pull()
        return self.filter.kf.P

    def state_into(self, out, row: int = 0) -> None:
        """Write x (12,) then P (12, 12) row by row, float64, into row ``row`` of ``out`` (a
        writable C-contiguous buffer of rows of 156 float64; one row: ``row`` 0), P as
        :meth:`covariance12` reports it: the state at the filter's own time, for a reader that
        wants it at every step without arrays of its own
        (:class:`estimation.consistency.RunningConsistency`). Each run binds its core's own copy
        on the instance (the compiled kernel's, no Python frame in between)."""
        self.filter.core.state_into(out, row)

    def covariance12(self) -> np.ndarray:
        """The covariance (12, 12) of :attr:`x`'s error against the truth: :attr:`P` plus the
        accelerometer's turn-on bias as a consider parameter, (σ_b/g)² on the θ and encoder-zero
        block (see :class:`~estimation.ekf_filter.StrapdownFilter`); :attr:`P` itself where the
        specification has no such bias."""
        return self.filter.covariance12(self.P)

    def rates(self, x=None, w=None, w_prev=None) -> tuple[float, float]:
        """(θ̇, α̇) in rad/s at the filter's time: the gyro's mean rates over the last two
        periods (``w``, ``w_prev``; default the filter's) extrapolated linearly to the end of
        the last one."""
        return self.filter.rates(x, w, w_prev)

    def state6(self, x=None, w=None, w_prev=None) -> np.ndarray:
        """[θ, θ̇, ψ, ψ̇, α, α̇] at the filter's time (or of state ``x`` and gyro history ``w``,
        ``w_prev``)."""
        return self.filter.state6(x, w, w_prev)

    def covariance6(self) -> np.ndarray:
        """Covariance (6, 6) of :meth:`state6` at the filter's time: P mapped through the
        Jacobian of [θ, θ̇, ψ, ψ̇, α, α̇] by the state (central differences), plus the
        gyro's white noise in the extrapolated rates (1.5² + 0.5² samples' worth)."""
        x = self.x
        return self.filter.covariance6(x, self.covariance12())

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
            inn = self.fusion.innovation()
            if inn is not None:
                d["innovation"], d["innovation_cov"] = np.array(inn[0], float), np.array(inn[1], float)
        return d

    def degraded(self) -> list[str]:
        """What the estimate has lost at the filter's present time, one line each (empty: nothing):
        the position and speed when the encoders are taken as stuck
        (:meth:`~estimation.ekf_frontend.SensorFrontEnd.count_check`) or none has arrived for
        :data:`~estimation.ekf_config.ENCODERS_LOST_AFTER` s; they then come from the IMU alone
        and drift (a dropped encoder stream leaves the robot balancing, not knowing where it is)."""
        if self.k < 0:
            return []
        return self.front.degraded(self._clock.now(self.k))

    def stats(self) -> dict:
        b, front = self._books, self.front
        stuck = front.stuck_total
        if front.stuck_since is not None and self.k >= 0:
            stuck += self._clock.now(self.k) - front.stuck_since
        return {"accepted": dict(b.accepted), "rejected": dict(b.rejected),
                "encoders_stuck_s": stuck, "degraded": self.degraded(), "encoder_resyncs": b.resyncs,
                "rejected_total": self.rejected_total, "predict_only_steps": b.predict_only,
                "unchanged_encoder_samples": b.unchanged_encoders, "interval_updates": b.interval_updates,
                "saturated_imu_samples": b.saturated,
                "stale_imu_samples": b.stale, "accel_outliers": b.accel_outliers,
                "latency_changes": b.latency_changes,
                "resets": b.resets, "events": [f"t = {t:.3f} s: {why}" for t, why in b.events]}

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
        f = self.filter
        x, P = f.prior(meas.accel)
        self.last_nis, self.last_dof = math.nan, 0
        w = (meas.gyro[1], meas.gyro[2])
        f.core.set_state(x, P, w, w)
        self.k, self.m = 0, 0
        clock = self._clock
        clock.t0 = float(meas.t)
        if clock.rows:
            clock.times[0] = clock.t0
        self.front.start(meas)
        if self._untaught.any():  # held from the first step: nothing in a run teaches them (see UNTAUGHT)
            f.hold(self._untaught)
        f.core.keep_good()
        self._last_estimate = tuple(f.state6())
        return Estimate(*self._last_estimate)

    def step(self, meas, command) -> Estimate:
        """Advance to the next control instant.

        ``meas``: the :class:`twin.sensors.Measurement` that arrived now; ``command``:
        the wheel torque commands (ul, ur) in N·m applied over the period that just ended.
        """
        if self.k < 0:
            raise TwinError("call start() with the first measurement before step()")
        k = self.k = self.k + 1
        fusion = self.fusion
        fusion.last_nis, fusion.last_dof = math.nan, 0  # diagnostics() reports this step's update alone
        commands = self._commands
        commands[k - 1] = cmd = (float(command[0]), float(command[1]))
        clock = self._clock
        timed = clock.rows
        if timed:
            times = clock.times
            times[k] = float(meas.t)
        self.lag = lag = self._store(meas, k, self.m, cmd)
        every = self.every
        # one filter step per due IMU instant; after the assumed latency shrinks several are due
        for m in range(self.m + every, k - lag + 1, every):
            if timed:
                t = times[m]
                self._set_period(t - times[m - 1])
            else:
                t = meas.t - (k - m) * self.model.dt
            if t >= self._hold_at:
                self._hold()
            try:
                imu, rail, enc = self._due(m, t, self.m)
                self._advance(m, t, imu, rail, enc, commands.get(m - every, _NO_COMMAND))
            except (np.linalg.LinAlgError, FloatingPointError, ValueError, ZeroDivisionError, OverflowError) as err:
                fusion.restore(t, f"numerical failure in the filter ({err}); restored the last good estimate")
            for j in range(self.m - every, m - every):  # commands no step will need again
                commands.pop(j, None)
            self.m = m
        if timed:  # the instants' times no step will need again (see Clock.span)
            front = self.front
            keep = min(self.m - 1, front.last_enc_m if front.last_enc is not None else self.m - 1)
            while clock.times_from < keep:
                times.pop(clock.times_from, None)
                clock.times_from += 1
        self.last_nis, self.last_dof = fusion.last_nis, fusion.last_dof
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
        self.filter.set_period(dt)

    def _hold(self) -> None:
        """From now on the consider states are held: no update corrects them."""
        self.holding = True
        self._hold_at = math.inf
        self.filter.hold(self._consider.mask)

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
        self.front.imu_sampling = imu
        if commands == "sampled" or periods == "rows":
            self.front.watches = False
            self.front.watch = None
        if periods == "rows" and self.periods != "rows":
            # the model's period changes from step to step: a model of this filter's own
            self.model = self.filter.model = copy.copy(self.model)
            self.model.__dict__.pop("_perturbed", None)
            self._forward = self.filter.core.forwarder(self.filter.state6, self.model.step6)
            self._nominal_dt = self.dt
            self._clock.model, self._clock.nominal_dt = self.model, self._nominal_dt
        self.periods = periods
        self._clock.rows = periods == "rows"

    def _estimate(self, k: int) -> Estimate:
        """The filter's state predicted forward to control step ``k``; never non-finite."""
        m = self.m
        # (the commands since the filter's time: one as a rule, one period behind, without a comprehension)
        s, finite = self._forward([self._commands.get(m, _NO_COMMAND)] if k - m == 1 else
                                  [self._commands.get(j, _NO_COMMAND) for j in range(m, k)])
        if not finite:  # s is then the filter's own state, finite as a rule
            events = self._books.events
            events.append((k * self.model.dt, "forward prediction non-finite; handing out the filter's own state"))
            if not all(map(math.isfinite, s)):
                events.append((k * self.model.dt, "the filter's own state gives a non-finite estimate; "
                                                  "handing out the last finite one"))
                s = self._last_estimate
        self._last_estimate = tuple(s)
        return _new(Estimate, s)  # Estimate(*s) without its Python-level __new__


__all__ = ["CONSIDER", "EKFEstimator", "Estimate", "GROUPS", "UNTAUGHT", "finite_reading"]
