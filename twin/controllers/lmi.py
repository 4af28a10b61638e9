"""LMI design of the IT2 PDC balance gains (paper Lemmas 1 and 2) with cvxpy.

Variables Q = P⁻¹ ≻ 0, N_i (1×4), Y_ij (4×4). With Φ_ij = Q A_iᵀ + A_i Q − N_jᵀ B_iᵀ − B_i N_j
the paper's Lemma 1 asks Φ_ii + Y_ii ≺ 0, Φ_ij + Y_ij ⪯ 0 (i ≠ j), [[Y11, Y12], [Y21, Y22]] ≻ 0,
and the gains are G_i = −N_i Q⁻¹, so that u = Σ m_i G_i x. Lemma 2 bounds the input,
|u| ≤ ρ for every start with ‖x0‖ ≤ ε: ε² I ⪯ Q and [[Q, N_iᵀ], [N_i, ρ² I]] ⪰ 0.

What the paper lacks, added here:

* a decay rate a ≥ 0 (1/s): Φ_ij gains the term 2aQ, so V = xᵀPx falls at least as
  e^{−2at} on the TS model and ‖x(t)‖ ≤ √cond(P) ‖x0‖ e^{−at};
* an objective: minimise t with [[Q, N_iᵀ], [N_i, t]] ⪰ 0, the squared worst-case input
  over the certified ellipsoid. Because ε² I ⪯ Q, this also bounds the gains,
  ‖G_i‖₂ ≤ √t / ε, so the design returns small gains that meet the decay rate, not
  arbitrary feasible ones. (What is minimised is the certified peak-input
  bound; the gains' norms come out below it, not necessarily at their own minimum.)

ε only sets the scale of (Q, N, Y, t), so the problem is solved once for ε = 1 and
the gains do not depend on ε; ρ (|u| ≤ ρ) and ``max_gain`` (‖G_i‖ ≤ max_gain) are then
checks on the design (the peak bound and the gains' norms), and an infeasible request
names the value that works. Only the decay rate can make the problem itself infeasible.

After solving, :func:`verify_certificate` re-checks everything with numpy eigenvalues,
independent of the solver's status: every LMI with a margin, plus the closed-loop
Lyapunov inequality (Σ_ij m_i m_j (A_i + B_i G_j))ᵀ P + P (…) + 2aP ≺ 0 on a grid of
weights m1 ∈ [0, 1], built from P and G alone.

What the certificate does *not* say, plainly:

* it is about the TS model. Its invariant ellipsoid xᵀPx ≤ 1 reaches far beyond the
  model's θ domain of ±π/6 (√Q11 ≈ 3 rad with the defaults), where the two-rule model no
  longer describes equation (1); closed-loop behaviour on equation (1) and on the twin
  is checked by simulation, not proven here;
* with decay rate 0 (the paper's Lemma 1 alone) the gains can be nearly marginal:
  ``slowest_vertex_pole`` reports max Re λ(A_i + B_i G_i) so that this shows;
* it covers the IT2 PDC, whose weights equal the model's. The type-1 PDC uses the same
  gains with other weights, which the Y_ij relaxation does not cover (at arbitrary
  weight pairs the decay inequality fails); :func:`decay_along_theta` checks it along the
  weights it actually meets, θ ∈ [−π/6, π/6], on a grid.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from twin.errors import InfeasibleDesign, TwinError
from twin.params import NOMINAL, RobotParams
from twin.plant.ts_model import rule1_weight, ts_matrices

DEFAULT_EPSILON = 0.5  # ‖x0‖ bound of the certified region (mixed units of x); covers θ0 = 0.48 rad
DEFAULT_RHO = 2.0  # N·m: bound on |u| = |ul + ur| (1 N·m per wheel)
DEFAULT_DECAY_RATE = 3.0  # 1/s: θ from 0.48 rad to below 0.01 rad in about 1.1 s on the analytic model

# The solver works to ~1e-8 relative accuracy, so every inequality is solved with a little
# room (relative to its scale) and the independent check then needs no tolerance at all.
# SCS, a first-order method, is less precise and gets more room.
_ROOM = {"CLARABEL": 1e-5, "SCS": 1e-2}
# Accepted ranges (beyond them the numbers stop meaning anything for this robot, or overflow)
_MAX_EPSILON = 100.0
_MAX_RHO = 1e6  # N·m
_MAX_DECAY = 100.0  # 1/s
_MAX_GAIN = 1e9

# Typical magnitudes of [θ, θ̇, ψ, ψ̇] during a recovery (rad, rad/s, rad, rad/s).
DEFAULT_SCALING = np.array([1.0, 10.0, 10.0, 50.0])
_SOLVER_OPTIONS = {
    "CLARABEL": {},
    "SCS": {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iters": 100000, "acceleration_lookback": 0},
}
# For the bisection that explains an infeasible decay rate: a yes/no answer, quickly.
_QUICK_OPTIONS = {"CLARABEL": {"max_iter": 60}, "SCS": {"max_iters": 5000}}


@dataclass(frozen=True)
class Certificate:
    """Independent numerical check of an LMI solution; margins > 0 mean satisfied.

    Margins are eigenvalue gaps normalised by the scale of the matrices involved.
    """

    lmi_margins: dict[str, float]
    lyapunov_margin: float  # min over the weight grid of −max eig(sym(P A_cl) + 2aP) / ‖P A‖
    epsilon_margin: float  # 1 − ε² λmax(P)
    rho_margin: float  # 1 − max_i sqrt(G_i Q G_iᵀ) / ρ
    passed: bool

    def summary(self) -> str:
        worst = min(self.lmi_margins.values())
        return (
            f"certificate {'PASSED' if self.passed else 'FAILED'}: worst LMI margin {worst:.3e}, "
            f"Lyapunov margin {self.lyapunov_margin:.3e}, ε margin {self.epsilon_margin:.3e}, "
            f"ρ margin {self.rho_margin:.3e}"
        )


@dataclass(frozen=True)
class BalanceDesign:
    """Result of :func:`design_balance_gains`.

    ``gains`` has shape (2, 4): G1 and G2 for the state [θ, θ̇, ψ, ψ̇]
    (units N·m/rad, N·m·s/rad, N·m/rad, N·m·s/rad); u = Σ m_i G_i x is the total wheel
    torque in N·m. ``P`` (4×4) is the Lyapunov matrix, ``peak_input`` the certified
    bound on |u| (N·m) for ‖x0‖ ≤ ε.
    """

    gains: np.ndarray
    P: np.ndarray
    Q: np.ndarray
    epsilon: float
    rho: float
    decay_rate: float
    max_gain: float | None
    peak_input: float
    solve_time_s: float
    solver: str
    certificate: Certificate
    params: RobotParams = field(repr=False, default=NOMINAL)
    slowest_vertex_pole: float = math.nan  # max Re λ(A_i + B_i G_i), 1/s
    # where this object came from, not part of the design: not compared, not written out
    from_cache: bool = field(default=False, compare=False, repr=False)

    def to_json_dict(self) -> dict:
        return {
            "gains": self.gains.tolist(),
            "state": ["theta [rad]", "theta_dot [rad/s]", "psi [rad]", "psi_dot [rad/s]"],
            "input": "u = ul + ur [N·m] = sum_i m_i(theta) G_i x",
            "P": self.P.tolist(),
            "solve_time_s": self.solve_time_s,
            "solver": self.solver,
            "epsilon": self.epsilon,
            "rho": self.rho,
            "decay_rate": self.decay_rate,
            "max_gain": self.max_gain,
            "peak_input_nm": self.peak_input,
            "slowest_vertex_pole_per_s": self.slowest_vertex_pole,
            "certificate": {
                "passed": self.certificate.passed,
                "lmi_margins": self.certificate.lmi_margins,
                "lyapunov_margin": self.certificate.lyapunov_margin,
                "epsilon_margin": self.certificate.epsilon_margin,
                "rho_margin": self.certificate.rho_margin,
            },
        }


def _check_positive(name: str, value: float, allow_zero: bool = False, upper: float = math.inf) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TwinError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero) or v > upper:
        bound = "in [0, " if allow_zero else "in (0, "
        raise TwinError(f"{name} must be a finite number {bound}{upper:g}], got {value!r}")
    return v


def _solve(A, B, decay_rate, solver, T=None, feasibility_only=False):
    """Build and solve the SDP for ε = 1 in scaled coordinates z = T⁻¹ x (T diagonal > 0).

    Returns (status, Q̃, Ñ list, Ỹ blocks, t, solver name) in the z coordinates:
    Q = T Q̃ T, N = Ñ T, Y_ij = T Ỹ_ij T. The congruence keeps every LMI's sign but makes
    Q̃ far better conditioned (Q spans four decades in the x coordinates).

    ε only sets the scale: every LMI is homogeneous in (Q, N, Y) except ε² I ⪯ Q, so
    (ε²Q, ε²N, ε²Y, ε²t) solves the problem for ε whenever (Q, N, Y, t) solves it for 1,
    with the same gains. ρ and the gain bound are checks on the minimal t, not
    constraints (a constraint t ≤ ρ² with a huge ρ only spoils the solver's scaling).
    """
    epsilon = 1.0
    import cvxpy as cp

    n = A[0].shape[0]
    T = np.ones(n) if T is None else np.asarray(T, dtype=float)
    A = [Ai * (1.0 / T)[:, None] * T[None, :] for Ai in A]
    B = [Bi * (1.0 / T)[:, None] for Bi in B]
    eps_floor = np.diag(epsilon**2 / T**2)
    r = len(A)
    I = np.eye(n)
    q_scale = float(eps_floor.max())
    a_scale = max(np.linalg.norm(Ai, 2) for Ai in A)

    def build(room: float):
        Q = cp.Variable((n, n), symmetric=True)
        N = [cp.Variable((1, n)) for _ in range(r)]
        Ybig = cp.Variable((n * r, n * r), symmetric=True)
        Yb = [[Ybig[i * n:(i + 1) * n, j * n:(j + 1) * n] for j in range(r)] for i in range(r)]
        t = cp.Variable()
        # Q >= eps^2 I fixes the scale of Q; Phi_ij scales with ||A|| Q, and so does the room.
        delta = room * q_scale * a_scale
        cons = [Q >> (1 + room) * eps_floor, Ybig >> room * q_scale * np.eye(n * r)]
        for i in range(r):
            for j in range(r):
                phi = Q @ A[i].T + A[i] @ Q - N[j].T @ B[i].T - B[i] @ N[j] + 2 * decay_rate * Q
                lhs = phi + Yb[i][j]
                lhs = 0.5 * (lhs + lhs.T)
                cons.append(lhs << (-delta * I if i == j else -0.1 * delta * I))
            cons.append(cp.bmat([[Q, N[i].T], [N[i], cp.reshape(t, (1, 1), order="C")]]) >> 0)
        return cp.Problem(cp.Minimize(0 if feasibility_only else t), cons), Q, N, Yb, t

    names = [solver] if solver else ["CLARABEL", "SCS"]
    status, used = None, None
    for name in names:
        prob, Q, N, Yb, t = build(_ROOM.get(name, 1e-5))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                opts = dict(_SOLVER_OPTIONS.get(name, {}))
                if feasibility_only:
                    opts.update(_QUICK_OPTIONS.get(name, {}))
                prob.solve(solver=name, **opts)
            status, used = prob.status, name
        except Exception as exc:  # solver missing or crashed: try the fallback
            status, used = f"error: {exc}".splitlines()[0], name
            continue
        if status in ("optimal", "optimal_inaccurate", "infeasible", "infeasible_inaccurate"):
            break
    if status not in ("optimal", "optimal_inaccurate") or (feasibility_only and status != "optimal"):
        return status, None, None, None, None, used
    Yv = [[np.array(Yb[i][j].value) for j in range(r)] for i in range(r)]
    return status, np.array(Q.value), [np.array(Ni.value) for Ni in N], Yv, float(t.value), used


def verify_certificate(A, B, Q, N, Y, epsilon, rho, decay_rate, T=None, weight_grid: int = 201) -> Certificate:
    """Check an LMI solution with numpy alone (see the module docstring).

    ``Q, N, Y`` are in the coordinates z = T⁻¹ x of :func:`_solve` (T = 1 for the
    original ones); ``A, B`` are in x and are transformed here.
    """
    n = Q.shape[0]
    r = len(A)
    T = np.ones(n) if T is None else np.asarray(T, dtype=float)
    A = [Ai * (1.0 / T)[:, None] * T[None, :] for Ai in A]
    B = [Bi * (1.0 / T)[:, None] for Bi in B]
    Q = 0.5 * (Q + Q.T)
    scale = max(np.linalg.norm(Q, 2), 1e-300)
    margins: dict[str, float] = {}
    margins["Q>0"] = float(np.linalg.eigvalsh(Q).min() / scale)
    margins["Q>=eps^2 I"] = float(np.linalg.eigvalsh(Q - np.diag(epsilon**2 / T**2)).min() / scale)
    Ybig = np.block(Y)
    Ybig = 0.5 * (Ybig + Ybig.T)
    margins["Y>0"] = float(np.linalg.eigvalsh(Ybig).min() / scale)
    for i in range(r):
        for j in range(r):
            phi = Q @ A[i].T + A[i] @ Q - N[j].T @ B[i].T - B[i] @ N[j] + 2 * decay_rate * Q + Y[i][j]
            phi = 0.5 * (phi + phi.T)
            s = max(np.linalg.norm(A[i] @ Q, 2), scale)
            margins[f"Phi{i + 1}{j + 1}+Y{i + 1}{j + 1}<=0"] = float(-np.linalg.eigvalsh(phi).max() / s)
        # Lemma 2's [[Q, N_iᵀ], [N_i, ρ²]] ⪰ 0 is, with Q ≻ 0, its Schur complement:
        margins[f"input bound rule {i + 1}"] = float(1.0 - (N[i] @ np.linalg.solve(Q, N[i].T)).item() / rho**2)

    P = np.linalg.inv(Q)
    P = 0.5 * (P + P.T)
    G = [-Ni @ P for Ni in N]
    worst = np.inf
    for m1 in np.linspace(0.0, 1.0, weight_grid):
        m = (m1, 1.0 - m1)
        Acl = sum(m[i] * m[j] * (A[i] + B[i] @ G[j]) for i in range(r) for j in range(r))
        L = Acl.T @ P + P @ Acl + 2 * decay_rate * P
        s = max(np.linalg.norm(P @ Acl, 2), 1e-300)
        worst = min(worst, float(-np.linalg.eigvalsh(0.5 * (L + L.T)).max() / s))
    # x0ᵀ P_x x0 <= 1 for every ‖x0‖ <= ε, with P_x = T⁻¹ P T⁻¹ the Lyapunov matrix in x
    eps_margin = float(1.0 - epsilon**2 * np.linalg.eigvalsh(P / T[:, None] / T[None, :]).max())
    peak = max(float(np.sqrt(max((Gi @ Q @ Gi.T).item(), 0.0))) for Gi in G)
    rho_margin = 1.0 - peak / rho
    passed = all(v > 0 for v in margins.values()) and worst > 0 and eps_margin >= 0 and rho_margin >= 0
    return Certificate(margins, worst, eps_margin, rho_margin, bool(passed))


def design_balance_gains(
    params: RobotParams = NOMINAL,
    epsilon: float = DEFAULT_EPSILON,
    rho: float = DEFAULT_RHO,
    decay_rate: float = DEFAULT_DECAY_RATE,
    max_gain: float | None = None,
    solver: str | None = None,
    *,
    cache: bool = False,
) -> BalanceDesign:
    """Solve Lemmas 1–2 with a decay rate for the IT2 PDC gains.

    Parameters
    ----------
    params : RobotParams
        Model parameters (the controllers' nominal set).
    epsilon : float
        Radius of the set of initial states ‖x0‖ ≤ ε that the input bound covers.
    rho : float
        Bound on the total torque |u| = |ul + ur| in N·m.
    decay_rate : float
        Guaranteed exponential decay rate a ≥ 0 of ‖x‖ on the TS model, in 1/s.
    max_gain : float, optional
        Upper bound on the spectral norm of each G_i.
    solver : str, optional
        A cvxpy solver name; default Clarabel, then SCS as fallback.
    cache : bool
        Look the design up in the on-disk cache (:mod:`twin.controllers.design_cache`)
        first and store a fresh one there. Off by default so that a library call solves;
        the command line and the scenarios turn it on (unless ``--no-cache``). A cached
        design equals the fresh one bit for bit, including its original ``solve_time_s``;
        its ``from_cache`` is True. cvxpy is imported only when the design is solved.

    Raises
    ------
    InfeasibleDesign
        With a one-line message naming the requirement (ρ, max_gain or decay rate)
        that cannot be met and the value that can.
    """
    epsilon = _check_positive("epsilon", epsilon, upper=_MAX_EPSILON)
    rho = _check_positive("rho", rho, upper=_MAX_RHO)
    decay_rate = _check_positive("decay rate", decay_rate, allow_zero=True, upper=_MAX_DECAY)
    if max_gain is not None:
        max_gain = _check_positive("max gain", max_gain, upper=_MAX_GAIN)
    if solver is not None and not isinstance(solver, str):
        raise TwinError(f"solver must be a cvxpy solver name, got {solver!r}")
    if cache:
        from twin.controllers import design_cache

        inputs = design_cache.inputs_of(params, epsilon, rho, decay_rate, max_gain, solver.upper() if solver else None)
        key = design_cache.key_of(inputs)
        hit = design_cache.load(key, inputs, params)
        if hit is not None:
            return hit
        d = design_balance_gains(params, epsilon, rho, decay_rate, max_gain, solver)
        design_cache.store(key, inputs, d)
        return d
    import cvxpy  # (imported before the clock starts: solve time excludes import)

    if solver is not None and solver.upper() not in cvxpy.installed_solvers():
        raise TwinError(f"solver {solver!r} is not installed; installed: {', '.join(cvxpy.installed_solvers())}")
    solver = solver.upper() if solver else None

    A, B = ts_matrices(params)
    t0 = time.perf_counter()
    sol = _certified_solution(A, B, decay_rate, solver)
    elapsed = time.perf_counter() - t0
    if isinstance(sol, str):
        _explain_decay(A, B, decay_rate, solver, sol)
    Q1, N1, Y1, T, used = sol
    Qx1 = Q1 * T[:, None] * T[None, :]  # ε = 1, x coordinates
    Px1 = np.linalg.inv(Qx1)
    gains = np.vstack([-(Ni * T[None, :]) @ Px1 for Ni in N1])
    # peak |u| over the invariant ellipsoid of the starts ‖x0‖ ≤ ε, from Q and G alone
    peak = epsilon * max(math.sqrt(max(float(g @ Qx1 @ g), 0.0)) for g in gains)
    if peak > rho:
        raise InfeasibleDesign(
            f"rho = {rho:g} N·m is too small for epsilon = {epsilon:g} and decay rate {decay_rate:g} 1/s: "
            f"the smallest feasible rho is {_round_up(peak)} N·m (solver {used}); raise --rho, or lower --epsilon"
            + (" or --decay-rate" if decay_rate > 0 else "")
        )
    gain_norm = float(np.linalg.norm(gains, axis=1).max())
    if max_gain is not None and gain_norm > max_gain:
        raise InfeasibleDesign(
            f"max gain {max_gain:g} is below the designed gains' norm {_round_up(gain_norm)} at decay rate "
            f"{decay_rate:g} 1/s; raise --max-gain" + (" or lower --decay-rate" if decay_rate > 0 else "")
        )
    # Checked at ε = 1 with ρ/ε: the exact equivalent of (ε²Q, ε²N, ε²Y) with ρ, without
    # the rounding that multiplying by ε² = 1e-18 (say) would bring into the margins.
    cert = verify_certificate(A, B, Q1, N1, Y1, 1.0, rho / epsilon, decay_rate, T)
    if not cert.passed:  # pragma: no cover - the ε = 1 solution passed and peak <= ρ was checked
        raise InfeasibleDesign(f"the design failed the independent check ({cert.summary()}); relax rho")
    e2 = epsilon**2
    Px = Px1 / e2
    return BalanceDesign(
        gains=gains,
        P=0.5 * (Px + Px.T),
        Q=Qx1 * e2,
        epsilon=epsilon,
        rho=rho,
        decay_rate=decay_rate,
        max_gain=max_gain,
        peak_input=peak,
        solve_time_s=elapsed,
        solver=used,
        certificate=cert,
        params=params,
        slowest_vertex_pole=_slowest_vertex_pole(A, B, gains),
    )


def _round_up(v: float) -> str:
    """v with 4 significant digits, never below v (so that passing it back works)."""
    return f"{v * (1 + 2e-4):.4g}"


def _slowest_vertex_pole(A, B, gains) -> float:
    """max Re λ(A_i + B_i G_i) over the rules, 1/s: the closed loop at θ = 0 (rule 1) and
    at |θ| ≥ π/6 (rule 2). Near 0 means nearly marginal, whatever the certificate says."""
    return float(max(np.linalg.eigvals(A[i] + B[i] @ gains[i:i + 1]).real.max() for i in range(len(A))))


def _certified_solution(A, B, decay_rate, solver):
    """Solve for ε = 1 and check the certificate; on failure rescale by the solution's own
    spread and try once more. Returns (Q̃, Ñ, Ỹ, T, solver) or a string saying why not."""
    T = DEFAULT_SCALING
    for attempt in range(2):
        status, Q, N, Y, _, used = _solve(A, B, decay_rate, solver, T)
        if Q is None:
            return f"solver status {status}"
        cert = verify_certificate(A, B, Q, N, Y, 1.0, math.inf, decay_rate, T)
        if cert.passed:
            return Q, N, Y, T, used
        T = T * np.sqrt(np.diag(Q) / np.diag(Q).min())
    return f"{used} returned gains that fail the independent check ({cert.summary()})"


def _explain_decay(A, B, decay_rate, solver, why) -> None:
    """The decay rate is the only requirement that can make the ε = 1 problem fail: find
    the largest decay rate that still gives a certified design and raise a one-line error."""
    solver = solver or "CLARABEL"  # SCS near the limit takes seconds per try and rarely certifies
    lo, hi = 0.0, min(decay_rate, _MAX_DECAY)
    for _ in range(12):  # quick yes/no solves: near the limit a full solve can take seconds
        mid = 0.5 * (lo + hi)
        if _solve(A, B, mid, solver, DEFAULT_SCALING, feasibility_only=True)[1] is None:
            hi = mid
        else:
            lo = mid
    certified = False
    for _ in range(8):  # report only a value that the full design really certifies, as printed
        lo = float(f"{lo * (1 - 2e-4):.4g}")  # 4 significant digits, rounded down
        if lo > 1e-3 and not isinstance(_certified_solution(A, B, lo, solver), str):
            certified = True
            break
        lo *= 0.9
    what = ("the solver finds it infeasible" if "infeasible" in why
            else f"the solver's answer failed the independent check, a numerical limit ({why})")
    advice = (f"the largest certified is about {lo:.4g} 1/s: lower --decay-rate" if certified
              else "no certified decay rate was found below it: lower --decay-rate")
    raise InfeasibleDesign(f"decay rate {decay_rate:g} 1/s cannot be certified for this plant: {what}; {advice}")




def decay_along_theta(design: BalanceDesign, controller_weight, n: int = 721) -> float:
    """Largest decay rate (1/s) that V = xᵀPx shows on the TS model along θ ∈ [−π/6, π/6]
    when the controller weights its rules by ``controller_weight(θ)`` (its m1).

    A grid check with the design's P, not a certificate: it is how the type-1 PDC, whose
    weights differ from the model's, is compared with the IT2 one (which the LMIs cover).
    V̇ ≤ −2aV at θ holds for a = −λmax(P^{-1/2} sym(P A_cl) P^{-1/2}), with
    A_cl = Σ_ij m_i(θ) h_j(θ) (A_i + B_i G_j); the minimum over the grid is returned.
    """
    A, B = ts_matrices(design.params)
    G, P = design.gains, design.P
    w, V = np.linalg.eigh(P)
    P_half_inv = V @ np.diag(w ** -0.5) @ V.T
    worst = math.inf
    for theta in np.linspace(-math.pi / 6, math.pi / 6, n):
        m1 = rule1_weight(theta)
        h1 = controller_weight(theta)
        m, h = (m1, 1.0 - m1), (h1, 1.0 - h1)
        Acl = sum(m[i] * h[j] * (A[i] + B[i] @ G[j:j + 1]) for i in range(2) for j in range(2))
        S = P @ Acl
        M = P_half_inv @ (0.5 * (S + S.T)) @ P_half_inv
        worst = min(worst, -float(np.linalg.eigvalsh(0.5 * (M + M.T)).max()))
    return worst
