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

The solver's answer is not the design: it lands somewhere on the optimal face, at a place
that depends on the BLAS kernel. The design is the program's unique central point at a 1 %
duality gap, found from the solver's answer and computed in 50-digit decimal arithmetic
(:mod:`twin.controllers.lmi_center`), so its gains are the same on every machine.

After solving, :func:`verify_certificate` re-checks everything with numpy eigenvalues,
independent of the solver's status: every LMI with a margin, plus the closed-loop
Lyapunov inequality (Σ_ij m_i m_j (A_i + B_i G_j))ᵀ P + P (…) + 2aP ≺ 0 on a grid of
weights m1 ∈ [0, 1], built from P and G alone.

Beyond the decay rate (:mod:`twin.controllers.lmi_regions`, issue 18):

* ``damping=ζ``: an LMI region, the decay rate together with a conic sector of half-angle
  arccos ζ (every frozen closed-loop mix has damping ratio ≥ ζ), with the Y_ij relaxation
  put in block form;
* ``uncertain={name: range}``: a robust design, one P and one pair of gains certified for
  the nominal model and every corner of a box of Table III parameters, and checked (not
  certified) at plants sampled inside it;
* ``all_vertices=True``: every vertex closed loop A_i + B_i G_j certified (any pair of model
  and controller weights), instead of the IT2 PDC's own mixes that the Y_ij relaxation covers.

These are solved by a program assembled directly for Clarabel (SCS as fallback); the
design without them is the cvxpy program below, unchanged.

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

import dataclasses
import math
import time
import warnings
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from twin.controllers import lmi_center, lmi_regions as regions
from twin.digests import design_digest
from twin.errors import InfeasibleDesign, TwinError
from twin.interrupts import deferred_signals
from twin.params import NOMINAL, RobotParams
from twin.plant.ts_model import local_model, rule1_weight, ts_matrices

DEFAULT_EPSILON = 0.5  # ‖x0‖ bound of the certified region (mixed units of x); covers θ0 = 0.48 rad
DEFAULT_RHO = 2.0  # N·m: bound on |u| = |ul + ur| (1 N·m per wheel)
# The twin's default balance design (issue 18), chosen by the paper-exp3 Monte Carlo sweep
# (docs/explanation/paper-method.md, "The default design"): one pair of PDC gains certified for the nominal model
# and the corners of m_b ±30 %, l ±15 % (the heavier, taller bodies that made the nominal
# design's limit cycles), a decay rate of 2 1/s and a damping ratio of at least 0.5 for
# every vertex closed loop A_i + B_i G_j. Success at λ = 0.3 rose from 73 % to 95 % (IT2)
# and 69 % to 97 % (type-1); settling at λ = 0 is about 1.3 s slower, the IAE lower.
DEFAULT_DECAY_RATE = 2.0  # 1/s
DEFAULT_DAMPING = 0.5  # minimum damping ratio ζ of the closed-loop poles
DEFAULT_UNCERTAIN = MappingProxyType({"m_b": 0.3, "l": 0.15})  # relative half-ranges of the box
DEFAULT_ALL_VERTICES = True
# The nominal design (the twin's default until issue 18; Lemmas 1–2 and a decay rate on the
# nominal model alone): θ from 0.48 rad below 0.01 rad in about 1.1 s on the analytic model,
# but lightly damped (ζ 0.15) with m_b ×1.2 and l ×1.15. design_balance_gains(**NOMINAL_DESIGN).
NOMINAL_DESIGN = MappingProxyType({"decay_rate": 3.0, "damping": 0.0, "uncertain": None, "all_vertices": False})

# The solver works to ~1e-8 relative accuracy, so every inequality is solved with a little
# room (relative to its scale) and the independent check then needs no tolerance at all.
# SCS, a first-order method, is less precise and gets more room.
_ROOM = {"CLARABEL": 1e-5, "SCS": 1e-2}
# Accepted ranges (beyond them the numbers stop meaning anything for this robot, or overflow)
_MAX_EPSILON = 100.0
# The design is solved at ε = 1 and scaled: its check takes (ρ/ε)², which overflows once
# ε < ρ · 7e-155 (an OverflowError from 1e-149 at ρ = 1e6), and its P is scaled by ε², which
# underflows below about 1e-154. The bound keeps far from both; a certified radius of a
# micro-unit is already inside any sensor's noise.
MIN_EPSILON = 1e-6
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
    # With a damping ratio: min over the weight grid and the certified models of the sector
    # condition's normalised margin, from P and G (None: no sector requested).
    region_margin: float | None = None
    models: int = 1  # plant models certified (the nominal one; with a box, also its 2^K corners)
    # With a box: the worst decay/sector margin, from P and G on the weight grid, at plants
    # sampled inside the box. Checked, not certified: not part of ``passed``.
    sampled_margin: float | None = None
    sampled_plants: int = 0

    def summary(self) -> str:
        worst = min(self.lmi_margins.values())
        text = (
            f"certificate {'PASSED' if self.passed else 'FAILED'}: worst LMI margin {worst:.3e}, "
            f"Lyapunov margin {self.lyapunov_margin:.3e}, ε margin {self.epsilon_margin:.3e}, "
            f"ρ margin {self.rho_margin:.3e}"
        )
        if self.region_margin is not None:
            text += f", sector margin {self.region_margin:.3e}"
        if self.models > 1:
            text += f", over {self.models} plant models"
        if self.sampled_margin is not None:
            text += (f"; sampled check (not certified) {'PASSED' if self.sampled_margin > 0 else 'FAILED'}: "
                     f"worst margin {self.sampled_margin:.3e} over {self.sampled_plants} plants inside the box")
        return text


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
    damping: float = 0.0  # minimum damping ratio ζ of the region (0: no sector)
    # the box of the robust design: ((parameter, relative half-range), ...) in Table III
    # order; () for a design on ``params`` alone
    uncertain: tuple = ()
    # True: every vertex closed loop A_i + B_i G_j is certified (any controller weights)
    all_vertices: bool = False
    # True: the numbers are the program's unique central point, computed to 50 digits and
    # rounded once (twin.controllers.lmi_center): the same on every machine. False: the
    # solver's own answer (the refinement failed), whose last digits depend on the BLAS kernel.
    unique: bool = True
    # where this object came from, not part of the design: not compared, not written out
    from_cache: bool = field(default=False, compare=False, repr=False)

    def to_json_dict(self) -> dict:
        """The design as design.json records it. The gains, P and the peak are the design's
        own numbers, the same on every machine (``unique_point``); the certificate's margins
        and the slowest pole are diagnostics from numpy's LAPACK, whose last bits depend on the
        BLAS kernel, so they are written with 6 significant digits (a margin would have to lie
        within ~1e-15 of a rounding boundary to be written differently elsewhere)."""
        c = self.certificate
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
            "slowest_vertex_pole_per_s": _sig6(self.slowest_vertex_pole),
            "damping": self.damping,
            "uncertain": dict(self.uncertain),
            "all_vertices": self.all_vertices,
            "unique_point": self.unique,
            "certificate": {
                "passed": c.passed,
                "lmi_margins": {k: _sig6(v) for k, v in c.lmi_margins.items()},
                "lyapunov_margin": _sig6(c.lyapunov_margin),
                "epsilon_margin": _sig6(c.epsilon_margin),
                "rho_margin": _sig6(c.rho_margin),
                "region_margin": _sig6(c.region_margin),
                "models": c.models,
                "sampled_margin": _sig6(c.sampled_margin),
                "sampled_plants": c.sampled_plants,
            },
        }

    def digest(self) -> str:
        """SHA-256 of the gains and P by their exact bits (:func:`twin.outputs.fingerprint.design_digest`):
        equal digests, identical designs."""
        return design_digest(gains=self.gains, P=self.P)

    def certified_models(self) -> list[tuple[list[np.ndarray], list[np.ndarray]]]:
        """(A_i, B_i) of every plant model the certificate covers: the nominal one, then the
        box's corners (see :mod:`twin.controllers.lmi_regions`)."""
        return regions.models_of(regions.box_params(self.params, self.uncertain))


def _sig6(v):
    """A diagnostic float with 6 significant digits (None stays None)."""
    return None if v is None else float(f"{v:.6g}")


def _check_positive(name: str, value: float, allow_zero: bool = False, upper: float = math.inf,
                    lower: float = 0.0) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise TwinError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < lower or (v == 0 and not allow_zero) or v > upper:
        bound = f"in [{lower:g}, " if allow_zero or lower > 0 else "in (0, "
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
    a_scale = regions.a_scale_of([(A, B)])  # as the direct program's (deterministic Frobenius norm)

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
                with _solver_call():
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


def _solver_call():
    """SIGINT and SIGTERM held while a solver runs, delivered as it returns
    (:func:`twin.interrupts.deferred_signals`): Clarabel is Rust, and calls back into Python
    while it solves (it imports SciPy's LAPACK on its first solve); an interrupt raised there
    became a Rust panic (a traceback, exit status 1), or an error the fallback to SCS took for
    a failed solver, the signal lost. A solve takes 0.1-0.5 s here (SCS, the fallback, a few s)."""
    return deferred_signals()


def verify_certificate(A, B, Q, N, Y, epsilon, rho, decay_rate, T=None, weight_grid: int = 201, *,
                       damping: float = 0.0, Z=None, model_names=None, any_weights: bool = False) -> Certificate:
    """Check an LMI solution with numpy alone (see the module docstring).

    ``Q, N, Y`` are in the coordinates z = T⁻¹ x of :func:`_solve` (T = 1 for the
    original ones); ``A, B`` are in x and are transformed here.

    For one plant model ``A = [A1, A2]``, ``B = [B1, B2]`` and ``Y[i][j]``; for several
    (the robust design) ``A[k]``, ``B[k]``, ``Y[k][i][j]`` per model k, with the common
    Q, N. With ``damping`` ζ > 0, ``Z[i][j]`` (or ``Z[k][i][j]``) are the sector LMI's slack
    blocks (2n×2n, see :mod:`twin.controllers.lmi_regions`); then every sector LMI is checked
    and the sector condition itself, from P and G, on the weight grid of every model.
    ``any_weights`` (a design with ``all_vertices``): the conditions from P and G are checked
    for every pair of model and controller weights (an 11 × 11 grid), not only for equal ones.
    """
    multi = np.ndim(A[0]) == 3
    models = list(zip(A, B)) if multi else [(A, B)]
    Ys = list(Y) if multi else [Y]
    sector = damping > 0
    Zs = (list(Z) if multi else [Z]) if sector else []
    names = list(model_names) if model_names is not None else [f"model {k}" for k in range(len(models))]
    tags = [f"{name}: " for name in names] if multi else [""]
    n = Q.shape[0]
    r = len(models[0][0])
    T = np.ones(n) if T is None else np.asarray(T, dtype=float)
    models = [([Ai * (1.0 / T)[:, None] * T[None, :] for Ai in Ak], [Bi * (1.0 / T)[:, None] for Bi in Bk])
              for Ak, Bk in models]
    Q = 0.5 * (Q + Q.T)
    scale = max(np.linalg.norm(Q, 2), 1e-300)
    margins: dict[str, float] = {}
    margins["Q>0"] = float(np.linalg.eigvalsh(Q).min() / scale)
    margins["Q>=eps^2 I"] = float(np.linalg.eigvalsh(Q - np.diag(epsilon**2 / T**2)).min() / scale)
    # Each LMI's matrix, the scale its margin is relative to, and whether its largest
    # (≺ 0 form) or smallest (≻ 0 form) eigenvalue matters; evaluated in batches below.
    checks: list[tuple[str, np.ndarray, object, bool]] = []
    # With every vertex certified there is no slack: each Φ_ij (and S_ij) ≺ 0 on its own.
    slack = not any_weights
    for k, tag in enumerate(tags if slack else []):
        Ybig = np.block(Ys[k])
        checks.append((f"{tag}Y>0", 0.5 * (Ybig + Ybig.T), scale, False))
        if sector:
            Zbig = np.block(Zs[k])
            checks.append((f"{tag}Z>0", 0.5 * (Zbig + Zbig.T), scale, False))
    inputs = {}
    for i in range(r):
        for k, (Ak, Bk) in enumerate(models):
            AQ = Ak[i] @ Q
            for j in range(r):
                phi = Q @ Ak[i].T + AQ - N[j].T @ Bk[i].T - Bk[i] @ N[j] + 2 * decay_rate * Q
                ij = f"{i + 1}{j + 1}"
                if slack:
                    phi = phi + Ys[k][i][j]
                checks.append((f"{tags[k]}Phi{ij}" + (f"+Y{ij}" if slack else "") + "<=0", 0.5 * (phi + phi.T), AQ,
                               True))
                if sector:
                    S = regions.sector_of(AQ - Bk[i] @ N[j], damping)
                    if slack:
                        S = S + Zs[k][i][j]
                    checks.append((f"{tags[k]}S{ij}" + (f"+Z{ij}" if slack else "") + "<=0", 0.5 * (S + S.T), AQ,
                                   True))
        # Lemma 2's [[Q, N_iᵀ], [N_i, ρ²]] ⪰ 0 is, with Q ≻ 0, its Schur complement:
        inputs[len(checks)] = (f"input bound rule {i + 1}",
                               float(1.0 - (N[i] @ np.linalg.solve(Q, N[i].T)).item() / rho**2))
        checks.append(None)
    # batched eigenvalues and norms: the same LAPACK calls, per matrix, as one at a time
    values = [None] * len(checks)
    by_size: dict[int, list[int]] = {}
    for idx, c in enumerate(checks):
        if c is not None:
            by_size.setdefault(c[1].shape[0], []).append(idx)
    for idxs in by_size.values():
        eig = np.linalg.eigvalsh(np.stack([checks[x][1] for x in idxs]))
        need = [x for x in idxs if not isinstance(checks[x][2], float)]
        norms = dict(zip(need, np.linalg.norm(np.stack([checks[x][2] for x in need]), 2, axis=(1, 2)))) if need else {}
        for row, x in enumerate(idxs):
            name, _, s, upper = checks[x]
            if upper:
                values[x] = float(-eig[row].max() / max(float(norms[x]), scale))
            else:
                values[x] = float(eig[row].min() / s)
    for idx, c in enumerate(checks):
        if c is None:
            name, v = inputs[idx]
        else:
            name, v = c[0], values[idx]
        margins[name] = v

    P = np.linalg.inv(Q)
    P = 0.5 * (P + P.T)
    G = [-Ni @ P for Ni in N]
    region = None
    batched = np.inf
    if multi or sector or any_weights:
        # every model at once (batched eigenvalues): the margins, from P and G alone
        grid = np.linspace(0.0, 1.0, 11 if any_weights else weight_grid)
        Acl = regions.closed_loops(models, np.vstack(G), grid, any_weights)
        batched, region = regions.frozen_margins(Acl, P, decay_rate, damping)
    worst = batched
    if not multi:  # the one-model decay check exactly as it always was (its margin is recorded)
        A, B = models[0]
        worst = np.inf
        for m1 in np.linspace(0.0, 1.0, weight_grid):
            m = (m1, 1.0 - m1)
            Acl = sum(m[i] * m[j] * (A[i] + B[i] @ G[j]) for i in range(r) for j in range(r))
            L = Acl.T @ P + P @ Acl + 2 * decay_rate * P
            s = max(np.linalg.norm(P @ Acl, 2), 1e-300)
            worst = min(worst, float(-np.linalg.eigvalsh(0.5 * (L + L.T)).max() / s))
        if any_weights:
            worst = min(worst, batched)
    # x0ᵀ P_x x0 <= 1 for every ‖x0‖ <= ε, with P_x = T⁻¹ P T⁻¹ the Lyapunov matrix in x
    eps_margin = float(1.0 - epsilon**2 * np.linalg.eigvalsh(P / T[:, None] / T[None, :]).max())
    peak = max(float(np.sqrt(max((Gi @ Q @ Gi.T).item(), 0.0))) for Gi in G)
    rho_margin = 1.0 - peak / rho
    passed = (all(v > 0 for v in margins.values()) and worst > 0 and (region is None or region > 0)
              and eps_margin >= 0 and rho_margin >= 0)
    return Certificate(margins, worst, eps_margin, rho_margin, bool(passed), region_margin=region,
                       models=len(models))


def design_options(epsilon=DEFAULT_EPSILON, rho=DEFAULT_RHO, decay_rate=DEFAULT_DECAY_RATE, max_gain=None,
                   solver=None, damping=DEFAULT_DAMPING, uncertain=DEFAULT_UNCERTAIN,
                   all_vertices=DEFAULT_ALL_VERTICES) -> dict:
    """The design options of :func:`design_balance_gains`, checked (one-line TwinError naming
    the option and its range) and in canonical form: floats, the parameter box as
    ((name, relative half-range), ...) in Table III order, ``all_vertices`` a bool.
    ``solver`` is kept as given (its upper-case name is what the design depends on)."""
    epsilon = _check_positive("epsilon", epsilon, upper=_MAX_EPSILON, lower=MIN_EPSILON)
    rho = _check_positive("rho", rho, upper=_MAX_RHO)
    decay_rate = _check_positive("decay rate", decay_rate, allow_zero=True, upper=_MAX_DECAY)
    if max_gain is not None:
        max_gain = _check_positive("max gain", max_gain, upper=_MAX_GAIN)
    if solver is not None and not isinstance(solver, str):
        raise TwinError(f"solver must be a cvxpy solver name, got {solver!r}")
    damping = regions.check_damping(damping)
    box = regions.check_uncertain(uncertain)
    if not isinstance(all_vertices, (bool, np.bool_)):
        raise TwinError(f"all_vertices must be true or false, got {all_vertices!r}")
    return {"epsilon": epsilon, "rho": rho, "decay_rate": decay_rate, "max_gain": max_gain, "solver": solver,
            "damping": damping, "uncertain": box, "all_vertices": bool(all_vertices)}


def design_balance_gains(
    params: RobotParams = NOMINAL,
    epsilon: float = DEFAULT_EPSILON,
    rho: float = DEFAULT_RHO,
    decay_rate: float = DEFAULT_DECAY_RATE,
    max_gain: float | None = None,
    solver: str | None = None,
    *,
    damping: float = DEFAULT_DAMPING,
    uncertain=DEFAULT_UNCERTAIN,
    all_vertices: bool = DEFAULT_ALL_VERTICES,
) -> BalanceDesign:
    """Solve Lemmas 1–2 with a decay rate for the IT2 PDC gains.

    The defaults are the twin's default design, robust over a parameter box
    (:data:`DEFAULT_UNCERTAIN`, see the comment on :data:`DEFAULT_DECAY_RATE`);
    ``design_balance_gains(**NOMINAL_DESIGN)`` is the nominal design of Lemmas 1–2 and a
    decay rate alone, the default before issue 18.

    Parameters
    ----------
    params : RobotParams
        Model parameters (the controllers' nominal set).
    epsilon : float
        Radius of the set of initial states ‖x0‖ ≤ ε that the input bound covers.
    rho : float
        Bound on the total torque |u| = |ul + ur| in N·m.
    decay_rate : float
        Guaranteed exponential decay rate a ≥ 0 of ‖x‖ on the TS model, in 1/s (default 2).
    max_gain : float, optional
        Upper bound on the spectral norm of each G_i.
    solver : str, optional
        A cvxpy solver name; default Clarabel, then SCS as fallback.
    damping : float
        Minimum damping ratio ζ ∈ [0, 1) of every frozen closed loop's eigenvalues (the
        conic sector of half-angle arccos ζ, with the decay rate: an LMI region; see
        :mod:`twin.controllers.lmi_regions`); default 0.5, and 0 adds no sector.
    uncertain : mapping, optional
        The robust design's parameter box, Table III name → relative half-range in [0, 1)
        (``{"m_b": 0.2}``: m_b within ±20 % of ``params.m_b``): one P and one pair of gains
        certified for the nominal model and every corner of the box, and checked (not
        certified) at plants sampled inside it. Names: those the balance model depends on,
        :data:`twin.controllers.lmi_regions.UNCERTAIN_PARAMETERS`. Default m_b ±30 %,
        l ±15 %; None or ``{}``: the nominal model alone.
    all_vertices : bool
        Certify the region for every vertex closed loop A_i + B_i G_j (i ≠ j too), with the
        common P, instead of only the IT2 PDC's own mixes Σ m_i m_j (A_i + B_i G_j) that the
        paper's Y_ij relaxation covers: then it holds for any pair of model and controller
        weights, the type-1 PDC's included (see :mod:`twin.controllers.lmi_regions`);
        default True.

    This always solves; :func:`twin.controllers.designs.balance_design` takes the same
    arguments and answers from the design store (this process's designs, the on-disk
    cache) when it can, bit for bit the same design, without importing cvxpy.

    Raises
    ------
    InfeasibleDesign
        With a one-line message naming the requirement (ρ, max_gain, decay rate, damping
        ratio or the parameter range) that cannot be met and the value that can.
    """
    o = design_options(epsilon, rho, decay_rate, max_gain, solver, damping, uncertain, all_vertices)
    epsilon, rho, decay_rate, max_gain, solver = o["epsilon"], o["rho"], o["decay_rate"], o["max_gain"], o["solver"]
    damping, box, all_vertices = o["damping"], o["uncertain"], o["all_vertices"]
    if damping > 0 or box or all_vertices:
        return _design_region(params, epsilon, rho, decay_rate, max_gain, solver, damping, box, all_vertices)
    import cvxpy  # (imported before the clock starts: solve time excludes import)

    if solver is not None and solver.upper() not in cvxpy.installed_solvers():
        raise TwinError(f"solver {solver!r} is not installed; installed: {', '.join(cvxpy.installed_solvers())}")
    solver = solver.upper() if solver else None

    A, B = ts_matrices(params)
    t0 = time.perf_counter()
    sol = _certified_solution(A, B, decay_rate, solver)
    if isinstance(sol, str):
        _explain_decay(A, B, decay_rate, solver, sol)
    Q1, N1, Y1, T, used, t1 = sol
    found = _unique_point([(A, B)], decay_rate, 0.0, False, _ModelsSolution(Q1, N1, [Y1], None, T, used, t1),
                          epsilon)
    elapsed = time.perf_counter() - t0
    _check_rho_and_gain(found.peak, found.gains, epsilon, rho, decay_rate, max_gain, used)
    # Checked at ε = 1 with ρ/ε: the exact equivalent of (ε²Q, ε²N, ε²Y) with ρ, without
    # the rounding that multiplying by ε² = 1e-18 (say) would bring into the margins.
    s = found.solution
    cert = verify_certificate(A, B, s.Q, s.N, s.Y[0], 1.0, rho / epsilon, decay_rate, s.T)
    if not cert.passed:  # pragma: no cover - the ε = 1 solution passed and peak <= ρ was checked
        raise InfeasibleDesign(f"the design failed the independent check ({cert.summary()}); relax rho")
    return _design(params, A, B, found, epsilon, rho, decay_rate, max_gain, elapsed, used, cert)


@dataclass(frozen=True)
class _Found:
    """A design's numbers: the solution in z = T⁻¹ x (for the independent check), the gains,
    P and Q in x for the design's ε, the certified peak |u| (N·m), and whether they are the
    unique point of :mod:`twin.controllers.lmi_center` (the same on every machine)."""

    solution: "_ModelsSolution"
    gains: np.ndarray
    P: np.ndarray
    Q: np.ndarray
    peak: float
    unique: bool


def _unique_point(models, decay_rate, damping, all_vertices, sol: "_ModelsSolution", epsilon) -> _Found:
    """The design's unique point from the solver's answer (see :mod:`twin.controllers.lmi_center`).
    Should it not be found (a numerical limit, near the edge of feasibility), the solver's
    own answer is used, with a one-line note: it is certified all the same, but its last
    digits depend on this machine's BLAS kernel."""
    try:
        ref = lmi_center.refine(models, decay_rate, damping, all_vertices, sol.Q, sol.N, sol.Y, sol.t, sol.T,
                                epsilon, DEFAULT_SCALING)
    except InfeasibleDesign as exc:
        import sys

        print(f"note: LMI design: {exc}; using the solver's answer, whose last digits depend on this machine's "
              f"BLAS kernel", file=sys.stderr)
        gains, Qx1, Px1, peak = _gains_and_peak(sol.Q, sol.N, sol.T, epsilon)
        e2 = epsilon**2
        Px = Px1 / e2
        return _Found(sol, gains, 0.5 * (Px + Px.T), Qx1 * e2, peak, False)
    Z = None
    if damping > 0:
        s_phi = regions.sector_sin_cos(damping)[0]
        Z = [[[np.kron(np.eye(2), s_phi * Yk[i][j]) for j in range(len(Yk))] for i in range(len(Yk))]
             for Yk in ref.Y]
    return _Found(_ModelsSolution(ref.Qz, ref.N, ref.Y, Z, ref.T, sol.solver, ref.t), ref.gains, ref.P, ref.Q,
                  ref.peak, True)


def _design(params, A, B, found: _Found, epsilon, rho, decay_rate, max_gain, elapsed, solver, cert,
            **region) -> BalanceDesign:
    """The :class:`BalanceDesign` of ``found``; ``region`` its damping, box and all_vertices, where given."""
    return BalanceDesign(gains=found.gains, P=found.P, Q=found.Q, epsilon=epsilon, rho=rho,
                         decay_rate=decay_rate, max_gain=max_gain, peak_input=found.peak, solve_time_s=elapsed,
                         solver=solver, certificate=cert, params=params,
                         slowest_vertex_pole=_slowest_vertex_pole(A, B, found.gains), unique=found.unique, **region)


def _gains_and_peak(Q1, N1, T, epsilon):
    """Gains, Q and P in x (ε = 1) and the peak |u| over the invariant ellipsoid of the
    starts ‖x0‖ ≤ ε, from Q and G alone."""
    Qx1 = Q1 * T[:, None] * T[None, :]  # ε = 1, x coordinates
    Px1 = np.linalg.inv(Qx1)
    gains = np.vstack([-(Ni * T[None, :]) @ Px1 for Ni in N1])
    peak = epsilon * max(math.sqrt(max(float(g @ Qx1 @ g), 0.0)) for g in gains)
    return gains, Qx1, Px1, peak


def _check_rho_and_gain(peak, gains, epsilon, rho, decay_rate, max_gain, used, damping=0.0, box=()) -> None:
    """ρ and the gain bound are checks on the design, not constraints (see :func:`_solve`)."""
    also = (" or --decay-rate" if decay_rate > 0 else "") + (" or --damping" if damping > 0 else "") + (
        " or narrow --uncertain" if box else "")
    if peak > rho:
        raise InfeasibleDesign(
            f"rho = {rho:g} N·m is too small for epsilon = {epsilon:g} and decay rate {decay_rate:g} 1/s"
            + (f", damping ratio {damping:g}" if damping > 0 else "") + (f", {regions.format_box(box)}" if box else "")
            + f": the smallest feasible rho is {_round_up(peak)} N·m (solver {used}); raise --rho, or lower --epsilon"
            + also
        )
    gain_norm = float(np.linalg.norm(gains, axis=1).max())
    if max_gain is not None and gain_norm > max_gain:
        raise InfeasibleDesign(
            f"max gain {max_gain:g} is below the designed gains' norm {_round_up(gain_norm)} at decay rate "
            f"{decay_rate:g} 1/s; raise --max-gain" + (" or lower --decay-rate" if decay_rate > 0 else "")
            + (" or --damping" if damping > 0 else "") + (" or narrow --uncertain" if box else "")
        )


def _round_up(v: float) -> str:
    """v with 4 significant digits, never below v (so that passing it back works)."""
    if not (math.isfinite(v) and v > 0):
        return f"{v:.4g}"
    q = 10.0 ** (math.floor(math.log10(v)) - 3)  # the 4th significant digit's unit
    text = f"{math.ceil(v / q) * q:.4g}"
    while float(text) < v:  # the division or the product rounded down
        text = f"{float(text) + q:.4g}"
    return text


def _slowest_vertex_pole(A, B, gains) -> float:
    """max Re λ(A_i + B_i G_i) over the rules, 1/s: the closed loop at θ = 0 (rule 1) and
    at |θ| ≥ π/6 (rule 2). Near 0 means nearly marginal, whatever the certificate says."""
    return float(max(np.linalg.eigvals(A[i] + B[i] @ gains[i:i + 1]).real.max() for i in range(len(A))))


def _certified_solution(A, B, decay_rate, solver):
    """Solve for ε = 1 and check the certificate; on failure rescale by the solution's own
    spread and try once more. Returns (Q̃, Ñ, Ỹ, T, solver, t) or a string saying why not."""
    T = DEFAULT_SCALING
    for attempt in range(2):
        status, Q, N, Y, t, used = _solve(A, B, decay_rate, solver, T)
        if Q is None:
            return f"solver status {status}"
        cert = verify_certificate(A, B, Q, N, Y, 1.0, math.inf, decay_rate, T)
        if cert.passed:
            return Q, N, Y, T, used, t
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




# ---- LMI regions and the robust design (issue 18) --------------------------------------------
_REGION_SOLVERS = ("CLARABEL", "SCS")
_QUICK_ITERS = {"CLARABEL": 80, "SCS": 5000}


def input_scale(params: RobotParams) -> float:
    """s (N·m per unit of the SDP's input): the power of two nearest NOMINAL's input gain over
    ``params``' (the balance model's θ̈ per N·m at upright, |B1[1]|); 1 for the paper's robot."""
    def gain(p):  # θ̈ per N·m of u at upright, 1/(kg·m²): the upright rule's B[1]
        return abs(float(local_model(p, 1.0)[1][1, 0]))

    return 2.0 ** round(math.log2(gain(NOMINAL) / gain(params)))


def _scaled(models, s: float) -> list:
    """``models`` with the input in units of ``s`` N·m (each B times s); as they are for s = 1."""
    return models if s == 1.0 else [(A, [Bi * s for Bi in B]) for A, B in models]


def _design_region(params, epsilon, rho, decay_rate, max_gain, solver, damping, box, all_vertices) -> BalanceDesign:
    """The design with a damping ratio and/or a parameter box: the SDP of
    :mod:`twin.controllers.lmi_regions`, solved directly by Clarabel (SCS as fallback),
    then the same ρ / gain checks and independent certificate as the nominal design, plus
    the (uncertified) check at plants sampled inside the box."""
    if solver is not None and solver.upper() not in _REGION_SOLVERS:
        raise TwinError(f"solver {solver!r} is not available for a design with --damping or --uncertain; "
                        f"allowed: {', '.join(_REGION_SOLVERS)}")
    solver = solver.upper() if solver else None
    plants = regions.box_params(params, box)  # may raise: a corner no rigid body can be
    # the input in units of s N·m (u = s v), s a power of two that brings the model's input
    # gain to the paper robot's order: a 60 kg robot's B is 1e-3 of the paper's, and the SDP,
    # well scaled for the paper's, then stalls at a numerical limit. Exact in floating point
    # (s = 1 for any robot within a factor √2 of the paper's), and the design is the same.
    s = input_scale(params)
    models = _scaled(regions.models_of(plants), s)
    import scipy.sparse  # noqa: F401 (imported before the clock starts, as cvxpy is for the nominal design)

    try:
        import clarabel  # noqa: F401
    except ImportError:  # pragma: no cover - then SCS solves it
        pass
    t0 = time.perf_counter()
    sol = _certified_models(models, decay_rate, damping, solver, all_vertices)
    if isinstance(sol, str):
        _explain_region(params, box, decay_rate, damping, solver, sol, all_vertices)
    found = _unique_point(models, decay_rate, damping, all_vertices, sol, epsilon)
    elapsed = time.perf_counter() - t0
    gains, Px1 = found.gains, found.P * epsilon**2  # in v = u / s
    if s != 1.0:
        found = dataclasses.replace(found, gains=found.gains * s, peak=found.peak * s)
    _check_rho_and_gain(found.peak, found.gains, epsilon, rho, decay_rate, max_gain, sol.solver, damping, box)
    cert = _verify_models(models, found.solution, 1.0, rho / s / epsilon, decay_rate, damping, all_vertices)
    if not cert.passed:  # pragma: no cover - the ε = 1 solution passed and peak <= ρ was checked
        raise InfeasibleDesign(f"the design failed the independent check ({cert.summary()}); relax rho")
    if box:
        samples = _scaled(regions.models_of(regions.sample_params(params, box)), s)
        cert = dataclasses.replace(cert, sampled_margin=_sampled_margin(samples, gains, Px1, decay_rate, damping,
                                                                        all_vertices),
                                   sampled_plants=len(samples))
    A, B = regions.models_of([params])[0]
    return _design(params, A, B, found, epsilon, rho, decay_rate, max_gain, elapsed, sol.solver,
                   cert, damping=damping, uncertain=box, all_vertices=all_vertices)


@dataclass(frozen=True)
class _ModelsSolution:
    Q: np.ndarray
    N: list
    Y: list
    Z: list | None
    T: np.ndarray
    solver: str
    t: float = math.nan  # the objective: the squared peak-input bound at ε = 1


def _verify_models(models, sol, epsilon, rho, decay_rate, damping, all_vertices=False) -> Certificate:
    """:func:`verify_certificate` for one model or several (named nominal, corner 1, ...)."""
    if len(models) == 1:
        (A, B), = models
        return verify_certificate(A, B, sol.Q, sol.N, sol.Y[0], epsilon, rho, decay_rate, sol.T, damping=damping,
                                  Z=sol.Z[0] if sol.Z else None, any_weights=all_vertices)
    names = ["nominal"] + [f"corner {k}" for k in range(1, len(models))]
    return verify_certificate([m[0] for m in models], [m[1] for m in models], sol.Q, sol.N, sol.Y, epsilon, rho,
                              decay_rate, sol.T, damping=damping, Z=sol.Z, model_names=names,
                              any_weights=all_vertices)


def _certified_models(models, decay_rate, damping, solver, all_vertices=False):
    """As :func:`_certified_solution` for the region / robust SDP: a :class:`_ModelsSolution`
    that passes the independent check, or a string saying why not."""
    T = DEFAULT_SCALING
    for attempt in range(2):
        with _solver_call():
            sol = regions.solve_program(models, decay_rate, damping, solver, T, _ROOM, all_vertices=all_vertices)
        if sol.Q is None:
            return f"solver status {sol.status}"
        found = _ModelsSolution(sol.Q, sol.N, sol.Y, sol.Z, T, sol.solver, sol.t)
        cert = _verify_models(models, found, 1.0, math.inf, decay_rate, damping, all_vertices)
        if cert.passed:
            return found
        T = T * np.sqrt(np.diag(sol.Q) / np.diag(sol.Q).min())
    return f"{sol.solver} returned gains that fail the independent check ({cert.summary()})"


def _sampled_margin(models, gains, Px, decay_rate, damping, any_weights=False, weight_grid: int = 21) -> float:
    """Worst normalised margin of the decay (and sector) condition from P and G on the
    weight grid, over plant models that are not certified (sampled inside the box); in
    the scaled coordinates of the certificate, so that the margins compare."""
    T = DEFAULT_SCALING
    scaled = [([Ai * (1.0 / T)[:, None] * T[None, :] for Ai in A], [Bi * (1.0 / T)[:, None] for Bi in B])
              for A, B in models]
    Pz = Px * T[:, None] * T[None, :]
    Acl = regions.closed_loops(scaled, gains * T[None, :], np.linspace(0.0, 1.0, 6 if any_weights else weight_grid),
                               any_weights)
    lyap, sector = regions.frozen_margins(Acl, Pz, decay_rate, damping)
    return lyap if sector is None else min(lyap, sector)


def _feasible(models, decay_rate, damping, solver, all_vertices=False) -> bool:
    """A quick yes/no: does the region / robust SDP have a solution?"""
    name = solver or "CLARABEL"
    with _solver_call():
        sol = regions.solve_program(models, decay_rate, damping, name, DEFAULT_SCALING, _ROOM, feasibility_only=True,
                                    quick_iters=_QUICK_ITERS.get(name), all_vertices=all_vertices)
    return sol.Q is not None and sol.status == "optimal"


def _largest(test, lo: float, hi: float, steps: int) -> float:
    """Bisection for the largest value in [lo, hi] that passes ``test`` (``lo`` assumed to pass)."""
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if test(mid):
            lo = mid
        else:
            hi = mid
    return lo


def _certified_below(value: float, certified) -> float | None:
    """``value`` rounded down to 3 significant digits, lowered until ``certified`` (a full
    design) accepts it, so that a reported value works when passed back; None if none did."""
    v = value
    for _ in range(5):
        v = float(f"{v * (1 - 2e-4):.3g}")
        if v > 0 and certified(v):
            return v
        v *= 0.9
    return None


def _explain_region(params, box, decay_rate, damping, solver, why, all_vertices=False) -> None:
    """One line naming what to relax when the region / robust design fails: the decay rate,
    the damping ratio, or which range of the box (found by trying them)."""
    solver = solver or "CLARABEL"
    nominal = regions.models_of([params])

    s = input_scale(params)  # as the design scales its input

    def feasible(models, a, z) -> bool:
        return _feasible(_scaled(models, s), a, z, solver, all_vertices)

    def certified(models, a, z) -> bool:
        return not isinstance(_certified_models(_scaled(models, s), a, z, solver, all_vertices), str)

    if box and feasible(nominal, decay_rate, damping):
        _explain_box(params, box, decay_rate, damping, why, feasible, certified)
    where = "even for the nominal plant" if box else "for this plant"
    if damping > 0 and feasible(nominal, decay_rate, 0.0):
        zeta = _largest(lambda z: feasible(nominal, decay_rate, z), 0.0, damping, 10)
        ok = _certified_below(zeta, lambda z: certified(nominal, decay_rate, z))
        advice = (f"the largest certified at this decay rate is about {ok:.3g}" if ok is not None
                  else "no certified damping ratio was found below it")
        raise InfeasibleDesign(f"damping ratio {damping:g} with decay rate {decay_rate:g} 1/s cannot be certified "
                               f"{where}: {_why(why)}; {advice}: lower --damping or --decay-rate")
    if feasible(nominal, decay_rate, 0.0):  # pragma: no cover - a numerical failure, not infeasibility
        raise InfeasibleDesign(f"the design could not be certified, a numerical limit ({why}); lower --decay-rate"
                               + (" or --damping" if damping > 0 else ""))
    # the decay rate alone is too much (as in _explain_decay, with this program)
    rate = _largest(lambda a: feasible(nominal, a, 0.0), 0.0, decay_rate, 12)
    ok = _certified_below(rate, lambda a: certified(nominal, a, 0.0))
    advice = (f"the largest certified is about {ok:.4g} 1/s: lower --decay-rate" if ok is not None
              else "no certified decay rate was found below it: lower --decay-rate")
    raise InfeasibleDesign(f"decay rate {decay_rate:g} 1/s cannot be certified {where}: {_why(why)}; {advice}")


def _why(why: str) -> str:
    return ("the solver finds it infeasible" if "infeasible" in why
            else f"the solver's answer failed the independent check, a numerical limit ({why})")


def _explain_box(params, box, decay_rate, damping, why, feasible_models, certified_models) -> None:
    """The nominal plant meets the region; the box does not: find which single range, when
    narrowed, makes the design feasible (the widest such first), and how far."""
    region = f"decay rate {decay_rate:g} 1/s" + (f" and damping ratio {damping:g}" if damping > 0 else "")

    def feasible(b, a=decay_rate, z=damping) -> bool:
        return feasible_models(regions.models_of(regions.box_params(params, b)), a, z)

    def certified(b) -> bool:
        return certified_models(regions.models_of(regions.box_params(params, b)), decay_rate, damping)

    def replaced(name, value):
        return tuple((n, value if n == name else v) for n, v in box if value > 0 or n != name)

    if feasible(box):  # pragma: no cover - the quick solve says yes where the certified one failed
        raise InfeasibleDesign(f"the design for {regions.format_box(box)} with {region} could not be certified, a "
                               f"numerical limit ({why}); narrow --uncertain or lower --decay-rate"
                               + (" or --damping" if damping > 0 else ""))
    head = f"the parameter box ({regions.format_box(box)}) is too wide for one common Lyapunov matrix with {region}"
    if (damping > 0 or decay_rate > 0) and not feasible(box, 0.0, 0.0):
        region_note = "; no decay rate or damping ratio would do (not even 0)"
        relax_region = ""
    else:
        region_note = ""
        relax_region = " or lower --decay-rate" + (" or --damping" if damping > 0 else "")
    by_width = sorted(box, key=lambda nv: -nv[1])
    culprits = [name for name, _ in by_width if feasible(replaced(name, 0.0))]
    if culprits:
        name = culprits[0]
        width = dict(box)[name]
        best = _largest(lambda v: feasible(replaced(name, v)), 0.0, width, 7)
        ok = _certified_below(best, lambda v: certified(replaced(name, v)))
        how = f"to ±{100 * ok:.3g} %" if ok is not None else "to 0"
        others = culprits[1:]
        alone = " alone" if len(box) > 1 else ""
        raise InfeasibleDesign(
            f"{head}{region_note}: narrowing {name}{alone} {how} (from ±{100 * width:.3g} %) makes it feasible"
            + (f" (narrowing {', '.join(others)} alone would also do)" if others else "")
            + f"; narrow {name} in --uncertain{relax_region}")
    widest, width = by_width[0]
    scale = _largest(lambda f: feasible(tuple((n, f * v) for n, v in box)), 0.0, 1.0, 7)
    ok = _certified_below(scale, lambda f: certified(tuple((n, f * v) for n, v in box)))
    if ok is not None:
        hint = f"all ranges scaled by {ok:.3g} ({regions.format_box(tuple((n, ok * v) for n, v in box))}) are feasible"
    else:
        hint = "no scaled-down box was certified"
    raise InfeasibleDesign(f"{head}{region_note}: no single range alone is to blame; {hint}; the widest is {widest} "
                           f"(±{100 * width:.3g} %): narrow the ranges in --uncertain{relax_region}")


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
