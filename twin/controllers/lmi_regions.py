"""LMI regions and a robust design over a parameter box for the IT2 PDC (issue 18).

:func:`twin.controllers.lmi.design_balance_gains` is the entry point; this module holds
what its ``damping=`` and ``uncertain=`` options add: the plant models to certify, the
semidefinite program solved directly by Clarabel (or SCS), and the numpy checks of the
region on a grid of rule weights.

The region (Chilali & Gahinet 1996)
-----------------------------------
Closed-loop eigenvalues λ with Re λ ≤ −a (the decay rate, as before) and inside the conic
sector of half-angle φ = arccos ζ about the negative real axis (damping ratio ≥ ζ).
For a closed loop A_cl with Lyapunov matrix X = Q ≻ 0 the sector condition is

    S(A_cl Q) = [[sin φ (M + Mᵀ), cos φ (M − Mᵀ)],
                 [cos φ (Mᵀ − M), sin φ (M + Mᵀ)]] ≺ 0,   M = A_cl Q,

a 2n×2n LMI, linear in M, and with M = A_i Q − B_i N_j linear in (Q, N_j).

The PDC's closed loop is A_cl(m) = Σ_ij m_i m_j (A_i + B_i G_j), G_j = −N_j Q⁻¹. Because S is
linear, S(A_cl(m) Q) = Σ_ij m_i m_j S_ij with S_ij = S(A_i Q − B_i N_j): the sector LMI is
applied to each (i, j) term, relaxed like the decay LMI (the paper's Lemma 1), with the
decay LMI's own slack Y_ij put in block form:

    S_ii + sin φ · diag(Y_ii, Y_ii) ≺ 0,   S_ij + sin φ · diag(Y_ij, Y_ij) ⪯ 0 (i ≠ j),

with [[Y11, Y12], [Y21, Y22]] ≻ 0 as in Lemma 1 (one Y per plant model).

Why it holds: write Z_ij = sin φ · diag(Y_ij, Y_ij) and Z = [Z_ij] (2rn×2rn). Z is a
permutation of sin φ · diag(Y, Y) with Y = [Y_ij] ≻ 0, so Z ≻ 0 (sin φ > 0 for ζ < 1).
For weights m ≥ 0, Σ m_i = 1, Σ_ij m_i m_j Z_ij = (m ⊗ I_2n)ᵀ Z (m ⊗ I_2n) ≻ 0, hence
Σ_ij m_i m_j S_ij ⪯ −Σ_ij m_i m_j Z_ij ≺ 0: S(A_cl(m) Q) ≺ 0 for every weight m, and every
eigenvalue of every frozen A_cl(m) lies in the sector (Chilali–Gahinet with X = Q). The
independent check confirms it from P and G alone: (I₂ ⊗ P) S(A_cl Q) (I₂ ⊗ P) = S(P A_cl) ≺ 0
on a grid of weights, for every certified model.

Why this slack and not a separate one: any Z = [Z_ij] ≻ 0 would do (the argument above
uses nothing else), so a free 2rn×2rn slack per model is never more conservative than the
shared one. Measured on the example box of five parameters (33 models, 2 rules): the
largest certifiable damping ratio is the same with both to three digits (0.534 at decay
rate 3 1/s, 0.696 at 1 1/s; 0.982 on the nominal model), the optimal peak-input bound t is
0.3–5 % higher with the shared slack, and the SDP takes 3–4 times as long with the
separate one (33 more 16×16 PSD blocks: 2.9 s against 0.8 s). ``slack="separate"`` in
:func:`solve_program` keeps the other for comparison (benchmarks/bench_lmi.py).

What the region means along a trajectory: the decay rate is a Lyapunov statement, valid
for weights that vary in time (V = xᵀPx falls at least as e^{−2at}); the sector is a
statement about each frozen closed loop A_cl(m) with a common Lyapunov matrix ("quadratic
D-stability"): it bounds the damping of every frozen mix, not of the time-varying system.

Which closed loops: the relaxation or every vertex
--------------------------------------------------
What the paper's relaxation certifies is the IT2 PDC's own closed loop Σ_ij m_i m_j
(A_i + B_i G_j), whose weights are the model's: A_i + B_i G_i and every mix. A cross vertex
A_i + B_i G_j (i ≠ j) alone is not covered, since Y_ij may be indefinite: with the nominal
design at a decay rate of 2 1/s, A_1 + B_1 G_2 has a pole at −1.988 1/s (and at −2.999 1/s
against 3 1/s with damping ratio 0.5). ``all_vertices=True`` drops the slack altogether
(Φ_ij ≺ 0 and S_ij ≺ 0 for every i, j, with the common Q), which certifies every vertex
closed loop, hence Σ_ij m_i h_j
(A_i + B_i G_j) for *any* model weights m and controller weights h: the type-1 PDC's, or a
controller that computes its weights from an estimated θ. In that form the Y_ij slack adds
nothing (every Φ_ij ≺ 0 already gives the relaxed conditions with Y = 0), so it is an
alternative to the paper's relaxation, not a refinement of it. Its price, measured: the
optimal peak-input bound t is 1–9 % higher (nominal 1–2 %, the example box 2–9 %), and the
same requests were feasible or infeasible with both in the 12 cases tried (three boxes,
four regions).

Robust design over a parameter box
----------------------------------
``uncertain = {"m_b": 0.2, "l": 0.15, ...}`` means m_b ∈ m_b,nom·[0.8, 1.2], etc. The
plant models certified are the nominal one and the 2^K corners of the box: A_i^k, B_i^k
from :func:`twin.plant.ts_model.ts_matrices` at each, with one common (Q, N_1, N_2), so the
same gains and the same P serve all of them, and with slack Y^k per model (each model is a
plant fixed in time; only the rule weights vary along a trajectory, so the slack may differ
from plant to plant).

What is certified: for the nominal model and every corner model, the TS closed loop with
these gains decays at rate a (any rule weights, time-varying) and every frozen closed loop
has its eigenvalues in the region (the IT2 PDC's mixes, or with ``all_vertices`` every
vertex closed loop). Also certified, exactly: every plant whose d_b and d_w
lie anywhere in their ranges while the other parameters sit at the nominal or a corner
value, because A_i, B_i are affine in (d_b, d_w) (B_i does not depend on them) and the LMIs
are affine in (A_i, B_i) for fixed (Q, N), so the (d_b, d_w) corners span that polytope and
the slack interpolates (Y = Σ λ_k Y^k).

What is not certified: the A_i(p), B_i(p) depend nonlinearly (rationally, through
Δ = m11 m22 − m12² β²) on m_b, l, n_yb, m_w, n_wa and r, so the corner models are *not* the
vertices of a polytope containing every plant of the box. The interior is checked, not
proven: the design evaluates the decay and sector inequalities from P and G at sampled
plants inside the box (a 3-level grid over the ranges and 200 seeded uniform draws) and
reports the worst margin there as ``Certificate.sampled_margin``. The closed loop on
equation (1) and on the twin is, as for the nominal design, only simulated.

Why corners and not a norm-bounded description: a norm-bounded (or entry-wise interval)
model A_i = A_i0 + E Δ F, ‖Δ‖ ≤ 1, would cover the interior, but the uncertain entries of
A_i and B_i move together (every one of them has the same Δ in its denominator, m_b scales
g_b, m12 and m22 at once), and a Δ that treats them as independent admits plants no
parameter set gives. Measured on the example box (m_b ±20 %, l ±15 %, n_yb ±20 %,
d_b ±50 %, d_w ±50 %, rule 1): over the box's plants the open-loop unstable pole lies in
[14.2, 23.8] 1/s and the ratio of the gravity term to the input gain, A[1,0]/|B[1]|, in
[0.51, 0.85]; the entry-wise interval hull of the same entries (the smallest box a
norm-bounded Δ with a diagonal structure must contain) spans [5.2, 26.6] 1/s and
[0.41, 1.05]: it asks for robustness to a plant 12 % more unstable, and to one with a
gravity-to-input ratio 24 % higher, than any in the box. The corners follow the true image exactly at its
extremes; what they miss inside, the sampled check measures (worst margins there have
been positive in every design tried, see tests/test_lmi_regions.py).

The semidefinite program
------------------------
The robust problem has 2^K + 1 models, each with r² decay LMIs (n×n), r² sector LMIs
(2n×2n) and Y^k (rn×rn): 300 matrix inequalities for the example box of five parameters.
cvxpy takes 1–4 s to canonicalise that many small expressions, several times the
solver's time, so the program is assembled here directly in the solvers' standard form
(s = b − A x in a product of PSD cones, triangles scaled by √2) and handed to Clarabel, or
to SCS as the fallback. The nominal design without region or box keeps
its cvxpy formulation in :mod:`twin.controllers.lmi` unchanged (its gains are recorded
bit for bit in outputs); ``tests/test_lmi_regions.py`` checks that both formulations give
the same design where they overlap.
"""
from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from twin.errors import TwinError
from twin.params import PARAMETER_DOCS, RobotParams, clip_inertia_factors
from twin.plant.ts_model import ts_matrices

# The Table III parameters the balance model's A_i, B_i depend on (through m11, m12, m22,
# g_b, d_b, d_w), in Table III's order. The others (n_wd, n_zb, n_xb, b) only enter the yaw
# dynamics, and a range on them would only duplicate corners.
UNCERTAIN_PARAMETERS = ("m_w", "m_b", "n_wa", "n_yb", "r", "l", "d_b", "d_w")
# A_i is affine in these and B_i independent of them: their corners span the exact polytope.
AFFINE_PARAMETERS = ("d_b", "d_w")
MAX_UNCERTAIN_PARAMETERS = 6  # 65 models; 8 would be 257, tens of seconds per solve
SAMPLE_DRAWS = 200  # uniform draws inside the box for the (uncertified) interior check
SAMPLE_SEED = 0
_GRID_LIMIT = 729  # 3-level grid points (3^K) checked besides the draws, up to K = 6


def check_damping(value) -> float:
    """ζ as a float in [0, 1), or a one-line TwinError naming what is allowed."""
    try:
        z = float(value)
    except (TypeError, ValueError):
        raise TwinError(f"damping ratio must be a number in [0, 1), got {value!r}") from None
    if not (math.isfinite(z) and 0.0 <= z < 1.0):
        raise TwinError(f"damping ratio must be in [0, 1) (0: no sector; cos of the sector's half-angle), "
                        f"got {value!r}")
    return z


def check_uncertain(uncertain) -> tuple[tuple[str, float], ...]:
    """The box as ((name, relative half-range), ...) in Table III order, zero ranges dropped;
    a one-line TwinError for an unknown parameter or a range outside [0, 1)."""
    if uncertain is None:
        return ()
    if isinstance(uncertain, (tuple, list)):
        try:
            uncertain = dict(uncertain)
        except (TypeError, ValueError):
            raise TwinError(f"uncertain must map parameter names to relative ranges, got {uncertain!r}") from None
    if not isinstance(uncertain, Mapping):
        raise TwinError(f"uncertain must map parameter names to relative ranges, got {uncertain!r}")
    allowed = ", ".join(UNCERTAIN_PARAMETERS)
    out = {}
    for name, value in uncertain.items():
        if name not in UNCERTAIN_PARAMETERS:
            why = ("does not enter the balance model's A_i, B_i" if name in PARAMETER_DOCS
                   else "is not a Table III parameter")
            raise TwinError(f"uncertain parameter {name!r} {why}; allowed: {allowed}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise TwinError(f"uncertain range of {name} must be a number in [0, 1) (0.2: ±20 %), "
                            f"got {value!r}") from None
        if not (math.isfinite(v) and 0.0 <= v < 1.0):
            raise TwinError(f"uncertain range of {name} must be in [0, 1) (a relative half-range: 0.2 is ±20 %), "
                            f"got {value!r}")
        if v > 0:
            out[name] = v
    if len(out) > MAX_UNCERTAIN_PARAMETERS:
        raise TwinError(f"at most {MAX_UNCERTAIN_PARAMETERS} uncertain parameters ({2 ** MAX_UNCERTAIN_PARAMETERS} "
                        f"corners), got {len(out)}: {', '.join(out)}")
    return tuple((n, out[n]) for n in UNCERTAIN_PARAMETERS if n in out)


def format_box(box) -> str:
    """'m_b ±20 %, l ±15 %' for messages."""
    return ", ".join(f"{n} ±{100 * v:.4g} %" for n, v in box)


def box_params(params: RobotParams, box) -> list[RobotParams]:
    """The certified plant parameter sets: the nominal one first, then the 2^K corners
    (none without a box)."""
    out = [params]
    if not box:
        return out
    for signs in itertools.product((-1.0, 1.0), repeat=len(box)):
        out.append(_plant(params, box, signs))
    return out


def _plant(params: RobotParams, box, levels) -> RobotParams:
    """``params`` with each boxed parameter at 1 + level × range times its value.

    A small n_yb can leave the body's yaw inertia n_zb above n_xb + n_yb, which no rigid
    body has (RobotParams refuses it); n_zb does not enter the balance model, so it is
    lowered to the limit as the sweeps do (:func:`twin.params.clip_inertia_factors`)."""
    scale = {n: 1.0 + float(s) * v for s, (n, v) in zip(levels, box)}
    fixed = clip_inertia_factors(scale, params)
    changed = [n for n, _ in box if fixed.get(n) != scale[n]]
    if changed:  # n_wa would be lowered: it enters m11, so the model would not be the corner's
        raise TwinError(f"uncertain: the box reaches {', '.join(f'{n} ×{scale[n]:.4g}' for n in changed)}, which no "
                        f"rigid wheel has with this n_wd (n_wa at most 2 n_wd); narrow the range of "
                        f"{', '.join(changed)}")
    return params.perturbed(scale=fixed)


def sample_params(params: RobotParams, box) -> list[RobotParams]:
    """Plants inside the box checked but not certified: the 3-level grid's points that are
    neither a corner nor the centre (when 3^K ≤ 729), then ``SAMPLE_DRAWS`` seeded uniform draws."""
    if not box:
        return []
    out = []
    if 3 ** len(box) <= _GRID_LIMIT:
        for levels in itertools.product((-1.0, 0.0, 1.0), repeat=len(box)):
            if all(v == 0.0 for v in levels) or all(v != 0.0 for v in levels):
                continue  # centre and corners: certified
            out.append(_plant(params, box, levels))
    rng = np.random.default_rng(SAMPLE_SEED)
    for u in rng.uniform(-1.0, 1.0, size=(SAMPLE_DRAWS, len(box))):
        out.append(_plant(params, box, u))
    return out


def models_of(plants) -> list[tuple[list[np.ndarray], list[np.ndarray]]]:
    return [ts_matrices(p) for p in plants]


def sector_sin_cos(damping: float) -> tuple[float, float]:
    """(sin φ, cos φ) of the sector of half-angle φ = arccos ζ."""
    return math.sqrt(1.0 - damping * damping), damping


def sector_of(M: np.ndarray, damping: float) -> np.ndarray:
    """S(M) = [[sφ (M + Mᵀ), cφ (M − Mᵀ)], [cφ (Mᵀ − M), sφ (M + Mᵀ)]] for the last two axes."""
    s, c = sector_sin_cos(damping)
    H = M + np.swapaxes(M, -1, -2)
    K = M - np.swapaxes(M, -1, -2)
    top = np.concatenate([s * H, c * K], axis=-1)
    bottom = np.concatenate([-c * K, s * H], axis=-1)
    return np.concatenate([top, bottom], axis=-2)


# ---- frozen-weight checks from P and G (numpy only) ----------------------------------------
def closed_loops(models, G: np.ndarray, weights: np.ndarray, any_weights: bool = False) -> np.ndarray:
    """A_cl = Σ_ij m_i h_j (A_i + B_i G_j) for every model and rule-1 weight in ``weights``:
    the IT2 PDC's own mixes (h = m), shape (len(models), len(weights), n, n); or, with
    ``any_weights``, every pair of model weight m1 and controller weight h1 from ``weights``
    (the type-1 PDC's, or any other controller's), shape (len(models), len(weights)², n, n)."""
    m = np.stack([weights, 1.0 - weights], axis=-1)  # (W, 2)
    out = []
    for A, B in models:
        r = len(A)
        terms = np.stack([np.stack([A[i] + B[i] @ G[j:j + 1] for j in range(r)]) for i in range(r)])  # (r, r, n, n)
        if any_weights:
            out.append(np.einsum("wi,vj,ijab->wvab", m, m, terms).reshape(-1, *terms.shape[2:]))
        else:
            out.append(np.einsum("wi,wj,ijab->wab", m, m, terms))
    return np.stack(out)


def frozen_margins(Acl: np.ndarray, P: np.ndarray, decay_rate: float, damping: float) -> tuple[float, float | None]:
    """Worst normalised margins, over every closed loop in ``Acl`` (..., n, n), of
    sym(P A_cl) + 2aP ≺ 0 (the decay rate) and, when ζ > 0, of the sector condition written
    with P: (I₂ ⊗ P) S(A_cl P⁻¹) (I₂ ⊗ P) = S(P A_cl) ≺ 0, the congruent form of S(A_cl Q) ≺ 0.
    Positive margins mean satisfied; they are relative to ‖P A_cl‖_F (the Frobenius norm:
    thousands of closed loops are checked, and an SVD each would cost more than the check)."""
    W = P @ Acl
    scale = np.maximum(np.sqrt(np.einsum("...ab,...ab->...", W, W)), 1e-300)
    L = W + np.swapaxes(W, -1, -2) + 2.0 * decay_rate * P
    lyap = float(np.min(-np.linalg.eigvalsh(0.5 * (L + np.swapaxes(L, -1, -2)))[..., -1] / scale))
    if damping <= 0:
        return lyap, None
    # S(A_cl Q) with Q = P⁻¹ times I₂⊗P on both sides: the blocks become P A_cl ± A_clᵀ P
    S = sector_of(W, damping)
    sec = float(np.min(-np.linalg.eigvalsh(0.5 * (S + np.swapaxes(S, -1, -2)))[..., -1] / scale))
    return lyap, sec


def region_of_poles(Acl: np.ndarray) -> tuple[float, float]:
    """(max Re λ, min damping ratio −Re λ/|λ|) over the eigenvalues of every closed loop."""
    ev = np.linalg.eigvals(Acl).ravel()
    zeta = -ev.real / np.maximum(np.abs(ev), 1e-300)
    return float(ev.real.max()), float(zeta.min())


# ---- the semidefinite program in standard conic form --------------------------------------
def _sym_basis(m: int) -> np.ndarray:
    """Basis E_k of the symmetric m×m matrices (E = e_a e_bᵀ + e_b e_aᵀ for a < b): (m(m+1)/2, m, m)."""
    idx = [(a, b) for b in range(m) for a in range(b + 1)]
    E = np.zeros((len(idx), m, m))
    for k, (a, b) in enumerate(idx):
        E[k, a, b] = 1.0
        E[k, b, a] = 1.0
    return E


def _svec_index(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows, columns and √2 scale of Clarabel's PSD triangle (upper triangle, by columns)."""
    rows, cols = [], []
    for b in range(m):
        for a in range(b + 1):
            rows.append(a)
            cols.append(b)
    rows, cols = np.array(rows), np.array(cols)
    return rows, cols, np.where(rows == cols, 1.0, math.sqrt(2.0))


def _scs_order(m: int) -> np.ndarray:
    """Permutation from Clarabel's svec order to SCS's (lower triangle by columns: for a
    symmetric matrix, the upper triangle by rows)."""
    clar = {(a, b): k for k, (a, b) in enumerate((a, b) for b in range(m) for a in range(b + 1))}
    return np.array([clar[(a, b)] for a in range(m) for b in range(a, m)])


class _Program:
    """Constraints M(x) ⪰ 0 with M affine in the decision vector x, collected as
    s = b − A x ∈ PSD triangle cones (Clarabel's layout; SCS's is a permutation)."""

    def __init__(self, n_vars: int):
        self.n = n_vars
        self.rows, self.cols, self.vals, self.b, self.sizes = [], [], [], [], []
        self._row = 0
        self._svec = {}
        # the same constraints in matrix form, for the central-point refinement
        # (twin.controllers.lmi_center): [(const (m, m), [(idx (k,), coef (k, m, m)), ...]), ...]
        self.blocks = []

    def psd(self, const: np.ndarray, terms) -> None:
        """Add const + Σ x[idx] · coef ⪰ 0 for ``terms`` = [(idx (k,), coef (k, m, m)), ...]."""
        self.blocks.append((np.array(const, dtype=float), [(np.asarray(i), np.asarray(c, dtype=float))
                                                           for i, c in terms]))
        m = const.shape[0]
        if m not in self._svec:
            self._svec[m] = _svec_index(m)
        r, c, w = self._svec[m]
        d = len(r)
        self.b.append(const[r, c] * w)
        for idx, coef in terms:
            sv = coef[:, r, c] * w  # (k, d)
            kk, dd = np.nonzero(sv)
            self.rows.append(self._row + dd)
            self.cols.append(np.asarray(idx)[kk])
            self.vals.append(-sv[kk, dd])
        self.sizes.append(m)
        self._row += d

    def matrices(self):
        import scipy.sparse as sp

        A = sp.csc_matrix((np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))),
                          shape=(self._row, self.n))
        return A, np.concatenate(self.b)


@dataclass
class Solution:
    """A solve in the scaled coordinates z = T⁻¹ x (see :func:`twin.controllers.lmi._solve`)."""

    status: str
    Q: np.ndarray | None = None
    N: list | None = None
    Y: list | None = None  # per model: Y[k][i][j]
    Z: list | None = None  # per model: Z[k][i][j] (2n×2n), or None without a sector
    t: float | None = None
    solver: str = ""


SLACKS = ("shared", "separate")


def solve_program(models, decay_rate: float, damping: float, solver: str | None, T, room: dict,
                  feasibility_only: bool = False, quick_iters: int | None = None, slack: str = "shared",
                  all_vertices: bool = False) -> Solution:
    """Solve the decay + sector LMIs for every model (ε = 1, objective min t as in
    :func:`twin.controllers.lmi._solve`) with Clarabel, else SCS; in z = T⁻¹ x coordinates.

    ``all_vertices``: no slack at all (Φ_ij ≺ 0, S_ij ≺ 0 for every i, j), so that every
    vertex closed loop A_i + B_i G_j is in the region with the common Q; the returned slack
    blocks are then zero, and the independent check verifies each Φ_ij and S_ij on its own."""
    names = [solver] if solver else ["CLARABEL", "SCS"]
    last = Solution("not solved")
    for name in names:
        try:
            sol = _solve_with(name, models, decay_rate, damping, T, room.get(name, 1e-5), feasibility_only, quick_iters,
                              slack, all_vertices)
        except Exception as exc:  # noqa: BLE001 -- solver missing or crashed: try the fallback
            last = Solution(f"error: {exc}".splitlines()[0], solver=name)
            continue
        last = sol
        if sol.status in ("optimal", "optimal_inaccurate", "infeasible", "infeasible_inaccurate"):
            break
    return last


@dataclass
class Layout:
    """Where each matrix variable sits in the decision vector x of a :class:`_Program`."""

    n: int  # states
    r: int  # rules
    iq: np.ndarray  # Q (symmetric n×n) in the basis EQ
    iN: list  # N_j (1×n) for each rule j
    it: int  # t, the objective
    iY: list  # Y^k (symmetric rn×rn) per model in the basis EY
    iZ: list  # Z^k (symmetric 2rn×2rn) per model in the basis EZ (separate slack only)
    EQ: np.ndarray
    EY: np.ndarray
    EZ: np.ndarray
    sector: bool
    separate: bool
    s_phi: float
    all_vertices: bool


def a_scale_of(models) -> float:
    """max_i ‖A_i‖_F over the (scaled) models: the scale of the LMIs' room. The Frobenius norm
    (not the spectral one, an SVD whose last bits depend on the BLAS kernel) summed exactly
    with math.fsum, so that the program's numbers are the same on every machine."""
    return max(math.sqrt(math.fsum(float(v) * float(v) for v in np.asarray(Ai).ravel()))
               for A, _ in models for Ai in A)


def build_program(models, decay_rate: float, damping: float, T, room: float, slack: str = "shared",
                  all_vertices: bool = False) -> tuple["_Program", Layout]:
    """The decay + sector LMIs of every model and the objective's blocks (ε = 1, in the
    z = T⁻¹ x coordinates), each with ``room`` relative to its scale; see :func:`solve_program`.

    Every number of the program is computed by elementwise IEEE operations (and
    :func:`a_scale_of`), never by BLAS, so the program is the same on every machine."""
    n = models[0][0][0].shape[0]
    r = len(models[0][0])
    T = np.asarray(T, dtype=float)
    models = [([Ai * (1.0 / T)[:, None] * T[None, :] for Ai in A], [Bi * (1.0 / T)[:, None] for Bi in B])
              for A, B in models]
    eps_floor = np.diag(1.0 / T**2)
    q_scale = float(eps_floor.max())
    delta = room * q_scale * a_scale_of(models)
    sector = damping > 0
    s_phi, c_phi = sector_sin_cos(damping)
    if slack not in SLACKS:
        raise TwinError(f"slack must be one of {', '.join(SLACKS)}, got {slack!r}")
    separate = slack == "separate"

    # decision vector: Q (sym n), N_1..N_r (1×n each), t, then Y^k (sym rn), Z^k (sym 2rn) per model
    EQ, EY, EZ = _sym_basis(n), _sym_basis(r * n), _sym_basis(2 * r * n)
    iq = np.arange(len(EQ))
    iN = [len(EQ) + j * n + np.arange(n) for j in range(r)]
    it = len(EQ) + r * n
    nxt = it + 1
    iY, iZ = [], []
    for _ in models:
        if all_vertices:  # no slack at all: every vertex LMI on its own (see solve_program)
            continue
        iY.append(nxt + np.arange(len(EY)))
        nxt += len(EY)
        if sector and separate:
            iZ.append(nxt + np.arange(len(EZ)))
            nxt += len(EZ)
    prog = _Program(nxt)
    I, I2 = np.eye(n), np.eye(2 * n)

    def block_terms(idx, E, i, j, size):
        """The slack's (i, j) block of size ``size``, symmetrised, as terms of its variables."""
        blk = E[:, i * size:(i + 1) * size, j * size:(j + 1) * size]
        blk = 0.5 * (blk + np.swapaxes(blk, 1, 2))
        keep = np.abs(blk).sum(axis=(1, 2)) > 0
        return idx[keep], blk[keep]

    prog.psd(-(1 + room) * eps_floor, [(iq, EQ)])  # Q ⪰ (1 + room) ε² T⁻²
    for k in range(0 if all_vertices else len(models)):
        prog.psd(-room * q_scale * np.eye(r * n), [(iY[k], EY)])  # Y^k ≻ 0
        if sector and separate:
            prog.psd(-room * q_scale * np.eye(2 * r * n), [(iZ[k], EZ)])  # Z^k ≻ 0
    e = np.eye(n)
    for i in range(r):
        for k, (A, B) in enumerate(models):
            Ai, Bi = A[i], B[i][:, 0]
            dQ_phi = EQ @ Ai.T + Ai @ EQ + 2.0 * decay_rate * EQ  # ∂Φ_ij/∂Q
            dN_phi = -(e[:, :, None] * Bi[None, None, :] + Bi[None, :, None] * e[:, None, :])  # ∂/∂N_j[c]
            if sector:
                dQ_M = Ai @ EQ  # M = A_i Q − B_i N_j
                dN_M = -(Bi[None, :, None] * e[:, None, :])
                dQ_S, dN_S = sector_of(dQ_M, damping), sector_of(dN_M, damping)
            for j in range(r):
                lvl = 1.0 if i == j else 0.1  # Φ_ii + Y_ii ≺ 0 strictly; Φ_ij + Y_ij ⪯ 0 with less room
                bare = all_vertices  # the vertex closed loop itself, no slack
                # −(Φ_ij + sym Y_ij) − δ I ⪰ 0
                prog.psd(-lvl * delta * I, [(iq, -dQ_phi), (iN[j], -dN_phi)]
                         + ([] if bare else [(ix, -c) for ix, c in [block_terms(iY[k], EY, i, j, n)]]))
                if sector:
                    if bare:
                        zt = []
                    elif separate:
                        zt = [block_terms(iZ[k], EZ, i, j, 2 * n)]
                    else:
                        ix, cy = block_terms(iY[k], EY, i, j, n)
                        cz = np.zeros((len(ix), 2 * n, 2 * n))
                        cz[:, :n, :n] = cz[:, n:, n:] = s_phi * cy
                        zt = [(ix, cz)]
                    prog.psd(-lvl * delta * I2, [(iq, -dQ_S), (iN[j], -dN_S)] + [(ix, -c) for ix, c in zt])
        # Lemma 2 / objective: [[Q, N_iᵀ], [N_i, t]] ⪰ 0
        big_q = np.zeros((len(EQ), n + 1, n + 1))
        big_q[:, :n, :n] = EQ
        big_n = np.zeros((n, n + 1, n + 1))
        for c in range(n):
            big_n[c, n, c] = big_n[c, c, n] = 1.0
        big_t = np.zeros((1, n + 1, n + 1))
        big_t[0, n, n] = 1.0
        prog.psd(np.zeros((n + 1, n + 1)), [(iq, big_q), (iN[i], big_n), (np.array([it]), big_t)])

    return prog, Layout(n, r, iq, iN, it, iY, iZ, EQ, EY, EZ, sector, separate, s_phi, all_vertices)


def _solve_with(name, models, decay_rate, damping, T, room, feasibility_only, quick_iters, slack,
                all_vertices) -> Solution:
    prog, lay = build_program(models, decay_rate, damping, T, room, slack, all_vertices)
    A_mat, b = prog.matrices()
    c = np.zeros(prog.n)
    if not feasibility_only:
        c[lay.it] = 1.0
    x, status = (_clarabel if name == "CLARABEL" else _scs if name == "SCS" else _unknown)(
        A_mat, b, c, prog.sizes, feasibility_only, quick_iters)
    if x is None:
        return Solution(status, solver=name)
    sol = solution_of(x, lay, len(models))
    sol.status, sol.solver = status, name
    return sol


def solution_of(x, lay: Layout, n_models: int) -> Solution:
    """The matrices of a decision vector ``x`` laid out by ``lay`` (status and solver unset)."""
    n, r, EQ, EY, EZ = lay.n, lay.r, lay.EQ, lay.EY, lay.EZ
    iq, iN, it, iY, iZ = lay.iq, lay.iN, lay.it, lay.iY, lay.iZ
    sector, separate, s_phi, all_vertices = lay.sector, lay.separate, lay.s_phi, lay.all_vertices
    Q = np.einsum("k,kab->ab", x[iq], EQ)
    N = [x[iN[j]][None, :] for j in range(r)]
    Y, Z = [], []
    for k in range(n_models):
        if all_vertices:  # no slack variables: zero blocks (every vertex LMI holds on its own)
            Y.append([[np.zeros((n, n)) for _ in range(r)] for _ in range(r)])
            continue
        Yb = np.einsum("k,kab->ab", x[iY[k]], EY)
        Y.append([[Yb[i * n:(i + 1) * n, j * n:(j + 1) * n] for j in range(r)] for i in range(r)])
        if sector and separate:
            Zb = np.einsum("k,kab->ab", x[iZ[k]], EZ)
            Z.append([[Zb[2 * i * n:2 * (i + 1) * n, 2 * j * n:2 * (j + 1) * n] for j in range(r)] for i in range(r)])
    if sector and not separate:
        Z = [[[np.kron(np.eye(2), s_phi * Yk[i][j]) for j in range(r)] for i in range(r)] for Yk in Y]
    return Solution("", Q, N, Y, Z if sector else None, float(x[it]), "")


def _unknown(*_):
    raise TwinError("unknown solver")


def _clarabel(A, b, c, sizes, feasibility_only, quick_iters):
    import clarabel
    import scipy.sparse as sp

    settings = clarabel.DefaultSettings()
    settings.verbose = False
    # Iterative refinement of each KKT solve costs a quarter of the solve time here and
    # changed neither the answers (objective within 1e-6) nor which designs certify in a
    # comparison over 12 regions and boxes; the numpy certificate is the safeguard either way.
    settings.iterative_refinement_enable = False
    if quick_iters:
        settings.max_iter = quick_iters
    n = A.shape[1]
    solver = clarabel.DefaultSolver(sp.csc_matrix((n, n)), c, A, b, [clarabel.PSDTriangleConeT(m) for m in sizes],
                                    settings)
    sol = solver.solve()
    status = str(sol.status)
    mapped = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate", "PrimalInfeasible": "infeasible",
              "AlmostPrimalInfeasible": "infeasible_inaccurate"}.get(status, status)
    if mapped not in ("optimal", "optimal_inaccurate"):
        return None, mapped
    return np.asarray(sol.x, dtype=float), mapped


def _scs(A, b, c, sizes, feasibility_only, quick_iters):
    import scs

    perm, start = [], 0
    for m in sizes:
        perm.append(start + _scs_order(m))
        start += m * (m + 1) // 2
    perm = np.concatenate(perm)
    # A first-order method: on these programs SCS stalls near 1e-6 whatever its settings, so
    # it runs a fixed budget (3–9 s here) and the certificate, with SCS's larger room (1e-2),
    # decides whether the answer will do (it did in every case tried).
    opts = {"eps_abs": 1e-7, "eps_rel": 1e-7, "max_iters": quick_iters or 20000, "verbose": False}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver = scs.SCS({"A": A[perm].tocsc(), "b": b[perm], "c": c}, {"s": list(sizes)}, **opts)
        sol = solver.solve()
    status = sol["info"]["status"]  # e.g. "solved", "solved (inaccurate - reached max_iters)", "infeasible"
    mapped = status
    for word, name in (("solved", "optimal"), ("infeasible", "infeasible")):
        if status.startswith(word) or status.startswith(f"{word}_"):
            mapped = name + ("_inaccurate" if "inaccurate" in status else "")
    if mapped not in ("optimal", "optimal_inaccurate"):
        return None, mapped
    return np.asarray(sol["x"], dtype=float), mapped
