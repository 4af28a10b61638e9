"""Linear-quadratic regulator baseline (built-in name ``lqr``): the fuzzy cascade's job
done by two fixed linear state feedbacks, designed by a rule fixed in advance.

Structure (mirrors :class:`twin.controllers.cascade.FuzzyCascade`, paper Fig. 4)
--------------------------------------------------------------------------------
State s = [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s, rad, rad/s, rad, rad/s), targets p_d (m),
α_d (rad), each None when that loop is off.

1. balance and position: u = −K [θ, θ̇, ψ_e, ψ̇] (total torque ul + ur, N·m) with
   ψ_e = clip(ψ − p_d / r, ±``psi_error_limit``) when a position target is set and
   ψ_e = ψ otherwise (back to the start, the paper's experiment 1). The clip is the
   cascade's: a distant target must not become a huge torque. There is no θ_off: an LQR
   with a ψ channel moves the robot to the target on its own (θ_off is logged as 0.0 so
   that trajectory files of all controllers share columns);
2. direction: u_α = −K_yaw [α − α_d, α̇] (N·m per wheel) when a heading target is set,
   0 otherwise;
3. wheel torques ul = u/2 − u_α, ur = u/2 + u_α (N·m), the cascade's convention.

Models
------
Balance: the TS model's upright rule (A1, B1) of :func:`twin.plant.ts_model.ts_matrices`,
the exact Jacobian of equation (1) at θ = 0 with the yaw at rest; x = [θ, θ̇, ψ, ψ̇],
u = ul + ur.

Yaw: the third line of equation (1) linearised at rest (θ = 0, θ̇ = ψ̇ = α̇ = 0, where
every product term vanishes and J(0) = m33)::

    m33 α̈ = −(2b²/r²)(d_b + d_w) α̇ + (b/r)(ur − ul),   ur − ul = 2 u_α

so with x_yaw = [α − α_d, α̇] (rad, rad/s) and input u_α (N·m per wheel)::

    A_yaw = [[0, 1], [0, −yaw_damping / m33]],   B_yaw = [[0], [2 b / (r m33)]]

(``yaw_damping`` and ``m33`` are :class:`twin.params.RobotParams` properties.)

Weights: Bryson's rule, with the scales the fuzzy design already uses
---------------------------------------------------------------------
Q = diag(1 / s_i²), R = 1 / ρ², "a state (input) of its typical size costs 1". The
scales are not tuned here, in either direction, against the fuzzy controllers; they are
the numbers the fuzzy design already committed to:

* balance states s = [1 rad, 10 rad/s, 10 rad, 50 rad/s], ``DEFAULT_SCALING`` of
  :mod:`twin.controllers.lmi`, the typical magnitudes of [θ, θ̇, ψ, ψ̇] during a recovery
  that the LMI design normalises its state by;
* balance input ρ = ``DEFAULT_RHO`` = 2 N·m on u = ul + ur, the input bound of the LMI
  design (Lemma 2), 1 N·m per wheel, inside the motors' 1.2 N·m stall torque
  (:mod:`twin.actuators.dc_motor`);
* yaw states [1 rad, 1 rad/s] and input 0.1 N·m per wheel: the direction FLS's ranges
  (Table I: α_e ±1 rad, α̇_e ±1 rad/s; the twin's u_α range ``DEFAULT_U_ALPHA_MAX`` of
  :mod:`twin.controllers.mamdani`), i.e. the sizes at which the fuzzy direction
  controller saturates. Balance plus yaw then ask at most 1 + 0.1 N·m of one wheel.

Discrete design on the zero-order-hold model (default), and why
---------------------------------------------------------------
The controller runs every ``control_period`` (5 ms, 200 Hz in the twin) and holds its
output in between. With the weights above the continuous-time LQR's fastest closed-loop
pole is at about −179 rad/s, a time constant (5.6 ms) of one control period: the
continuous design assumes a feedback the sampled loop does not have. So by default the
gains minimise the *same continuous-time cost* ∫ (xᵀQx + uᵀRu) dt exactly over the
sampled-data loop: (A, B) are discretised with a zero-order hold at the control period,
the cost integrated over each period (Van Loan's method: Q_d, R_d and the cross term
N_d), and the discrete-time Riccati equation with that cross term (the one
:func:`scipy.linalg.solve_discrete_are` solves) gives the optimal sampled feedback,
which is stable for the loop as it actually runs. The slow poles agree with the
continuous design to three digits; only the fast mode differs. ``control_period=None``
gives the continuous design (the equation of :func:`scipy.linalg.solve_continuous_are`)
for comparison.

The same gains on every machine, and how (issue 25)
-----------------------------------------------------
scipy's ``expm``, ``solve_discrete_are`` and numpy's ``solve`` run in the bundled
OpenBLAS, whose kernel is chosen per CPU at load time; their results differed in the last
bits between kernels (measured: all four balance gains and both yaw gains differed between
OPENBLAS_CORETYPE=Haswell, SkylakeX and Prescott), and the twin's closed loop, with the
wheels' stick/slip, amplifies such a difference into a visibly different trajectory. So
the design is computed in :mod:`twin.controllers.decimal_linalg` instead: Python's
:mod:`decimal` at 50 digits, every operation correctly rounded in an order fixed by the
code (the General Decimal Arithmetic specification, in integer arithmetic: no FPU, SIMD
or BLAS), from the exact decimal values of the float64 inputs to one correctly rounded
conversion of each result back to float64. The equations are the ones above (Van Loan
1978 for Ad, Bd, Qd, Rd, Nd; the same Riccati equations), solved by algorithms that need
no floating-point start: for the sampled design the structure-preserving doubling
algorithm (Chu, Fan, Lin & Wang, Int. J. Control 77(8), 2004), for the continuous one the
matrix sign function (Roberts 1980, Byers 1987), each followed by Newton's method (Hewer
1971; Kleinman 1968) until an update is below 10⁻³⁰ of P, then the residual and the
closed loop's stability checked in the same arithmetic. A start from scipy's solution
would converge to the same numbers only up to the working precision's last digits; a
deterministic start makes K, K_yaw and every exposed matrix (P, Ad, Bd, Qd, Rd, Nd) a
function of the input bits alone, whatever the CPU, BLAS kernel, numpy SIMD target or
numpy/scipy version (tests/test_lqr.py runs the design under each OpenBLAS kernel and
numpy SIMD level this CPU supports and compares the bits). With 50 digits the float64
results are the correctly rounded values of the exact design (identical at 90 digits).
The design calls no libm function either (Bryson's squares are products), so glibc's
choice between its FMA and SSE2 variants of pow/exp/sin per CPU does not reach it; its
inputs A, B do go through libm's pow (the ``**2`` of :mod:`twin.params` and
:mod:`twin.plant.ts_model`), which gives the same bits on both variants for the nominal
robot (measured with GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA: the same digests).
The gains changed once, in their last bits, with this. Cost: constructing an
:class:`LQRController` (both designs) takes about 10.5 ms (the continuous designs 5 ms)
instead of 1-2 ms with single-threaded BLAS (measured on the project's 2-core machine).

How fast it travels
-------------------
Far from a position target the clipped ψ channel is the only thing that drives the
robot (there is no θ_off), and the loop settles into a cruise at constant ψ̇ = w with
ψ_e = ∓L (L = ``psi_error_limit``). Setting the accelerations of equation (1) to zero,
u = 2 (d_w + d_b) w and g_b θ = 2 d_w w, so with u = −K [θ, 0, ψ_e, w]::

    w = −K_ψ ψ_e / (K_ψ̇ + 2 K_θ d_w / g_b + 2 (d_w + d_b))

6.7 cm/s on the nominal robot with the default gains and L = 1 rad (tested). So the
target distance, not the weights, sets how long the approach takes: on the nominal
analytic model from θ0 = 0.48 rad, 0.7 m is within 2 cm after 9.4 s and 1 m after 13.9 s
(the fuzzy cascade, whose position FLS adds a lean θ_off, takes 5.5 s and 7.7 s).
"""
from __future__ import annotations

import decimal
import math
from dataclasses import dataclass
from decimal import Decimal
from typing import Sequence

import numpy as np

from twin.controllers import decimal_linalg as dl
from twin.controllers.cascade import DEFAULT_PSI_ERROR_LIMIT
from twin.controllers.lmi import DEFAULT_SCALING, DEFAULT_RHO
from twin.controllers.mamdani import ALPHA_DOT_E_RANGE, ALPHA_E_RANGE, DEFAULT_U_ALPHA_MAX
from twin.digests import design_digest
from twin.errors import TwinError
from twin.params import NOMINAL, RobotParams
from twin.plant.ts_model import ts_matrices

DEFAULT_CONTROL_PERIOD = 0.005  # s: the twin's 200 Hz control rate
# Bryson scales (see the module docstring)
BALANCE_STATE_SCALES = tuple(float(v) for v in DEFAULT_SCALING)  # rad, rad/s, rad, rad/s
BALANCE_INPUT_SCALE = float(DEFAULT_RHO)  # N·m on u = ul + ur
YAW_STATE_SCALES = (float(ALPHA_E_RANGE), float(ALPHA_DOT_E_RANGE))  # rad, rad/s
YAW_INPUT_SCALE = float(DEFAULT_U_ALPHA_MAX)  # N·m per wheel
_MAX_CONTROL_PERIOD = 1.0  # s


@dataclass(frozen=True)
class LQRDesign:
    """One LQR design and everything needed to check it.

    Attributes
    ----------
    A : ndarray, shape (n, n)
        Continuous-time state matrix (SI units of the state per second).
    B : ndarray, shape (n, 1)
        Continuous-time input matrix.
    Q : ndarray, shape (n, n)
        State weight of the continuous-time cost (1 / state unit²).
    R : ndarray, shape (1, 1)
        Input weight of the continuous-time cost (1 / input unit²).
    K : ndarray, shape (1, n)
        Gain, input = −K x.
    P : ndarray, shape (n, n)
        Stabilising solution of the Riccati equation solved.
    control_period : float or None
        Sampling period in s of the discrete design; None for the continuous one.
    Ad, Bd : ndarray, shapes (n, n), (n, 1), or None
        Zero-order-hold discretisation of (A, B) at ``control_period``.
    Qd, Rd, Nd : ndarray, shapes (n, n), (1, 1), (n, 1), or None
        The continuous cost integrated over one period: Σ xₖᵀQd xₖ + 2 xₖᵀNd uₖ + uₖᵀRd uₖ.
    """

    A: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    K: np.ndarray
    P: np.ndarray
    control_period: float | None = None
    Ad: np.ndarray | None = None
    Bd: np.ndarray | None = None
    Qd: np.ndarray | None = None
    Rd: np.ndarray | None = None
    Nd: np.ndarray | None = None

    @property
    def discrete(self) -> bool:
        return self.control_period is not None

    def riccati_residual(self) -> float:
        """Relative residual of the Riccati equation P solves (‖residual‖ / ‖largest term‖)."""
        P, K = self.P, self.K
        if self.discrete:
            Ad, Bd, Qd, Rd, Nd = self.Ad, self.Bd, self.Qd, self.Rd, self.Nd
            gain_term = (Ad.T @ P @ Bd + Nd) @ np.linalg.solve(Rd + Bd.T @ P @ Bd, Bd.T @ P @ Ad + Nd.T)
            terms = (Ad.T @ P @ Ad, P, gain_term, Qd)
            res = terms[0] - terms[1] - terms[2] + terms[3]
        else:
            A, B, Q, R = self.A, self.B, self.Q, self.R
            terms = (A.T @ P, P @ A, P @ B @ np.linalg.solve(R, B.T @ P), Q)
            res = terms[0] + terms[1] - terms[2] + terms[3]
        return float(np.linalg.norm(res) / max(np.linalg.norm(t) for t in terms))

    def closed_loop_poles(self) -> np.ndarray:
        """Closed-loop poles in 1/s, shape (n,), sorted by real part.

        Continuous design: eig(A − B K). Discrete design: the sampled loop's eigenvalues
        z = eig(Ad − Bd K) as s = ln(z) / T (its continuous-time equivalents).
        """
        if self.discrete:
            z = np.linalg.eigvals(self.Ad - self.Bd @ self.K).astype(complex)
            s = np.log(z) / self.control_period
        else:
            s = np.linalg.eigvals(self.A - self.B @ self.K).astype(complex)
        return s[np.argsort(s.real)]


def bryson_weights(state_scales: Sequence[float], input_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Bryson's rule: Q = diag(1 / s_i²), R = [[1 / ρ²]]; shapes (n, n), (1, 1).

    Squares as products, not ``**``: Python's float ``**`` is libm's pow, which glibc computes
    differently on CPUs with and without FMA (measured: x**2 ≠ x·x for about 1 argument
    in 1000, differently on the two); a product is correctly rounded everywhere."""
    s = np.asarray(state_scales, dtype=float)
    rho = float(input_scale)
    return np.diag(1.0 / (s * s)), np.array([[1.0 / (rho * rho)]])


def sampled_cost(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, T: float):
    """ZOH discretisation and the exactly sampled cost (Van Loan, 1978).

    Returns (Ad, Bd, Qd, Rd, Nd) such that, for u held at uₖ over [kT, (k+1)T),
    x_{k+1} = Ad xₖ + Bd uₖ and ∫ over the period of xᵀQx + uᵀRu dt
    = xₖᵀQd xₖ + 2 xₖᵀNd uₖ + uₖᵀRd uₖ. Shapes (n, n), (n, m), (n, n), (m, m), (n, m).
    Computed in 50-digit decimal arithmetic and rounded once (see the module docstring):
    the same bits on every machine.
    """
    A, B, Q, R = _checked(A, B, Q, R)
    T = _period(T, "the sampling period")
    with decimal.localcontext(dl.context()):
        parts = dl.van_loan(dl.dec(A), dl.dec(B), dl.dec(Q), dl.dec(R), Decimal(T))
    return tuple(dl.to_float(M) for M in parts)


def _period(value, name: str) -> float:
    """``value`` as a positive finite float (s), else a one-line TwinError naming ``name``."""
    try:
        T = float(value) if not isinstance(value, (bool, str)) else math.nan
    except (TypeError, ValueError):
        T = math.nan
    if not (math.isfinite(T) and T > 0):
        raise TwinError(f"{name} must be a positive finite number in s, got {value!r}")
    return T


def _checked(A, B, Q, R) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, Q, R) as float arrays of shapes (n, n), (n, m), (n, n), (m, m), finite; else TwinError."""
    try:
        A, B, Q, R = (np.asarray(M, dtype=float) for M in (A, B, Q, R))
    except (TypeError, ValueError):
        raise TwinError("the LQR design needs numeric matrices A, B, Q, R") from None
    ok = A.ndim == 2 and B.ndim == 2 and Q.ndim == 2 and R.ndim == 2
    n, m = (B.shape if B.ndim == 2 else (0, 0))
    if not (ok and n > 0 and m > 0 and A.shape == (n, n) and Q.shape == (n, n) and R.shape == (m, m)):
        raise TwinError(f"the LQR design needs A (n, n), B (n, m), Q (n, n), R (m, m); got shapes "
                        f"{A.shape}, {B.shape}, {Q.shape}, {R.shape}")
    if not all(np.all(np.isfinite(M)) for M in (A, B, Q, R)):
        raise TwinError("the LQR design's matrices A, B, Q, R must be finite")
    return A, B, Q, R


def lqr_design(A, B, Q, R, control_period: float | None = DEFAULT_CONTROL_PERIOD) -> LQRDesign:
    """Optimal state feedback u = −K x for ẋ = A x + B u and the cost ∫ xᵀQx + uᵀRu dt.

    ``control_period`` (s): minimise that cost over the zero-order-hold sampled loop (the
    discrete Riccati equation of :func:`scipy.linalg.solve_discrete_are` on
    :func:`sampled_cost`); None: the continuous-time design (the equation of
    :func:`scipy.linalg.solve_continuous_are`). Both solved in 50-digit decimal arithmetic
    (:mod:`twin.controllers.decimal_linalg`), every result rounded once to float64: the
    same bits on every machine (see the module docstring).
    """
    A, B, Q, R = _checked(A, B, Q, R)
    if control_period is not None:
        control_period = _period(control_period, "control_period (or None)")
    try:
        with decimal.localcontext(dl.context()):
            a, b, q, r = dl.dec(A), dl.dec(B), dl.dec(Q), dl.dec(R)
            if control_period is None:
                P, K = dl.solve_care(a, b, q, r)
                return LQRDesign(A, B, Q, R, dl.to_float(K), dl.to_float(P))
            parts = dl.van_loan(a, b, q, r, Decimal(control_period))
            P, K = dl.solve_dare(*parts)
    except ArithmeticError as exc:  # NoSolution, or a decimal overflow/singularity on the way
        raise TwinError(f"the LQR Riccati equation has no stabilising solution: "
                        f"{(str(exc).splitlines() or [type(exc).__name__])[0]}") from None
    Ad, Bd, Qd, Rd, Nd = (dl.to_float(M) for M in parts)
    return LQRDesign(A, B, Q, R, dl.to_float(K), dl.to_float(P), control_period, Ad, Bd, Qd, Rd, Nd)


def yaw_model(params: RobotParams) -> tuple[np.ndarray, np.ndarray]:
    """(A_yaw, B_yaw), shapes (2, 2), (2, 1): equation (1)'s yaw line linearised at rest,
    state [α − α_d, α̇] (rad, rad/s), input u_α (N·m per wheel, ur − ul = 2 u_α)."""
    J0 = params.m33
    A = np.array([[0.0, 1.0], [0.0, -params.yaw_damping / J0]])
    B = np.array([[0.0], [2.0 * params.b / (params.r * J0)]])
    return A, B


def _positive_scales(name: str, values, n: int, unit: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise TwinError(f"{name} must be {n} positive numbers ({unit}), got {values!r}") from None
    if len(out) != n or not all(v > 0 and math.isfinite(v) for v in out):
        raise TwinError(f"{name} must be {n} positive finite numbers ({unit}), got {values!r}")
    return out


def _positive(name: str, value, unit: str) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
    if not ok:
        raise TwinError(f"{name} must be a positive finite number in {unit}, got {value!r}")
    return float(value)


class LQRController:
    """Balance + position + direction by LQR (see the module docstring); meets
    :class:`twin.protocols.Controller`.

    Parameters
    ----------
    params : RobotParams
        The model the gains are designed on (the nominal robot by default).
    psi_error_limit : float
        Clip of the ψ-error channel in rad (as in the fuzzy cascade).
    state_scales : sequence of 4 float, optional
        Bryson scales of [θ, θ̇, ψ, ψ̇] (rad, rad/s, rad, rad/s); default
        :data:`BALANCE_STATE_SCALES`.
    input_scale : float, optional
        Bryson scale of u = ul + ur in N·m; default :data:`BALANCE_INPUT_SCALE` (2 N·m).
    yaw_state_scales : sequence of 2 float, optional
        Bryson scales of [α − α_d, α̇] (rad, rad/s); default :data:`YAW_STATE_SCALES`.
    yaw_input_scale : float, optional
        Bryson scale of u_α in N·m per wheel; default :data:`YAW_INPUT_SCALE` (0.1 N·m).
    control_period : float or None
        Period in s of the sampled-data design (default 0.005 s, the twin's 200 Hz);
        None for the continuous-time design.

    Attributes
    ----------
    K : ndarray, shape (1, 4)
        Balance gain (N·m/rad, N·m·s/rad, N·m/rad, N·m·s/rad), u = −K [θ, θ̇, ψ_e, ψ̇].
    K_yaw : ndarray, shape (1, 2)
        Yaw gain (N·m/rad, N·m·s/rad), u_α = −K_yaw [α − α_d, α̇].
    balance_design, yaw_design : LQRDesign
        The models, weights and Riccati solutions behind the gains.
    signals, signal_units
        The extra logged signals, as the fuzzy cascade's.
    """

    signals = ("u", "theta_off", "u_alpha")
    signal_units = {"u": "N·m", "theta_off": "rad", "u_alpha": "N·m"}

    def __init__(self, params: RobotParams = NOMINAL, psi_error_limit: float = DEFAULT_PSI_ERROR_LIMIT,
                 state_scales: Sequence[float] | None = None, input_scale: float | None = None,
                 yaw_state_scales: Sequence[float] | None = None, yaw_input_scale: float | None = None,
                 control_period: float | None = DEFAULT_CONTROL_PERIOD):
        if not isinstance(params, RobotParams):
            raise TwinError(f"params must be a twin.params.RobotParams, got {type(params).__name__}")
        self.params = params
        self.psi_error_limit = _positive("psi_error_limit", psi_error_limit, "rad")
        self.state_scales = _positive_scales(
            "state_scales", BALANCE_STATE_SCALES if state_scales is None else state_scales, 4, "rad, rad/s, rad, rad/s")
        self.input_scale = _positive("input_scale", BALANCE_INPUT_SCALE if input_scale is None else input_scale, "N·m")
        self.yaw_state_scales = _positive_scales(
            "yaw_state_scales", YAW_STATE_SCALES if yaw_state_scales is None else yaw_state_scales, 2, "rad, rad/s")
        self.yaw_input_scale = _positive(
            "yaw_input_scale", YAW_INPUT_SCALE if yaw_input_scale is None else yaw_input_scale, "N·m")
        if control_period is not None:
            control_period = _positive("control_period", control_period, "s")
            if control_period > _MAX_CONTROL_PERIOD:
                raise TwinError(f"control_period must be at most {_MAX_CONTROL_PERIOD:g} s, got {control_period:g} s")
        self.control_period = control_period

        (A1, _), (B1, _) = ts_matrices(params)
        self.balance_design = lqr_design(A1, B1, *bryson_weights(self.state_scales, self.input_scale), control_period)
        A_yaw, B_yaw = yaw_model(params)
        self.yaw_design = lqr_design(A_yaw, B_yaw, *bryson_weights(self.yaw_state_scales, self.yaw_input_scale),
                                     control_period)
        self.K = self.balance_design.K
        self.K_yaw = self.yaw_design.K
        # plain floats for the per-call path (u = −K x)
        self._k = tuple(-float(v) for v in self.K[0])
        self._k_yaw = tuple(-float(v) for v in self.K_yaw[0])
        self._r = float(params.r)

    def design_digest(self) -> str:
        """SHA-256 (hex) of the gains' exact bits, K and K_yaw (:func:`twin.outputs.fingerprint.design_digest`):
        equal digests, identical gains."""
        return design_digest(K=self.K, K_yaw=self.K_yaw)

    def closed_loop_poles(self) -> tuple[np.ndarray, np.ndarray]:
        """(balance poles (4,), yaw poles (2,)) in 1/s of the design models under these
        gains; see :meth:`LQRDesign.closed_loop_poles`."""
        return self.balance_design.closed_loop_poles(), self.yaw_design.closed_loop_poles()

    def reset(self, targets) -> None:
        """Nothing to clear: the LQR has no internal state."""

    def __call__(self, estimate: Sequence[float], targets) -> tuple[float, float, float, float, float]:
        """(ul, ur, u, θ_off = 0.0, u_α) in N·m, N·m, N·m, rad, N·m per wheel.

        ``estimate`` = [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s); ``targets`` a
        :class:`twin.protocols.Targets` (position m, heading rad; None = loop off).
        """
        try:
            theta, theta_dot, psi, psi_dot, alpha, alpha_dot = (float(v) for v in estimate[:6])
        except (TypeError, ValueError):
            raise TwinError(f"LQR controller needs an estimate of 6 numbers [θ, θ̇, ψ, ψ̇, α, α̇], "
                            f"got {estimate!r}") from None
        if not (math.isfinite(theta) and math.isfinite(theta_dot) and math.isfinite(psi) and math.isfinite(psi_dot)
                and math.isfinite(alpha) and math.isfinite(alpha_dot)):
            raise TwinError("LQR controller got a non-finite estimate "
                            f"{(theta, theta_dot, psi, psi_dot, alpha, alpha_dot)} (θ, θ̇, ψ, ψ̇, α, α̇)")
        p_d, alpha_d = targets.position, targets.heading
        psi_e = psi
        if p_d is not None:
            if not math.isfinite(p_d):
                raise TwinError(f"LQR controller got a non-finite position target {p_d!r} m")
            lim = self.psi_error_limit
            psi_e = min(lim, max(-lim, psi - p_d / self._r))
        k = self._k
        u = k[0] * theta + k[1] * theta_dot + k[2] * psi_e + k[3] * psi_dot
        u_alpha = 0.0
        if alpha_d is not None:
            if not math.isfinite(alpha_d):
                raise TwinError(f"LQR controller got a non-finite heading target {alpha_d!r} rad")
            u_alpha = self._k_yaw[0] * (alpha - alpha_d) + self._k_yaw[1] * alpha_dot
        u_p = 0.5 * u
        return u_p - u_alpha, u_p + u_alpha, u, 0.0, u_alpha


def build_lqr(context=None, **params) -> LQRController:
    """Factory for the registry: ``LQRController(**params)`` completed from ``context``.

    ``context`` (optional), a :class:`twin.registry.BuildContext` or any object with some
    of its attributes: ``model`` (the design model, RobotParams), ``control_rate`` (Hz,
    the sampled design's period is its inverse) and ``options``: ``psi_error_limit`` (rad),
    ``rho`` (N·m: the balance input's Bryson scale, the LMI design's torque bound) and
    ``universes`` (the direction FLS's ``heading_error`` rad, ``turn_rate`` rad/s and
    ``turn_torque`` N·m: the yaw loop's Bryson scales), each absent one the default.
    Explicit keyword arguments take precedence.
    """
    kwargs = {}
    if context is not None:
        model = getattr(context, "model", None)
        if model is not None:
            kwargs["params"] = model
        rate = getattr(context, "control_rate", None)
        if rate is not None:
            if not (isinstance(rate, (int, float)) and not isinstance(rate, bool) and math.isfinite(rate) and rate > 0):
                raise TwinError(f"control_rate must be a positive finite number in Hz, got {rate!r}")
            kwargs["control_period"] = 1.0 / float(rate)
        options = getattr(context, "options", None) or {}
        if options.get("psi_error_limit") is not None:
            kwargs["psi_error_limit"] = options["psi_error_limit"]
        if options.get("rho") is not None:  # the LMI design's torque bound, set for the robot
            kwargs["input_scale"] = options["rho"]
        u = options.get("universes") or {}  # the direction FLS's ranges, set for the robot
        if "heading_error" in u or "turn_rate" in u:
            kwargs["yaw_state_scales"] = (u.get("heading_error", YAW_STATE_SCALES[0]),
                                          u.get("turn_rate", YAW_STATE_SCALES[1]))
        if "turn_torque" in u:
            kwargs["yaw_input_scale"] = u["turn_torque"]
    kwargs.update(params)
    return LQRController(**kwargs)


__all__ = ["BALANCE_INPUT_SCALE", "BALANCE_STATE_SCALES", "DEFAULT_CONTROL_PERIOD", "LQRController", "LQRDesign",
           "YAW_INPUT_SCALE", "YAW_STATE_SCALES", "build_lqr", "bryson_weights", "lqr_design", "sampled_cost",
           "yaw_model"]
