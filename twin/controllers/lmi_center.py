"""The LMI design's one answer: a unique point of the semidefinite program, computed to
~50 digits with correctly rounded arithmetic, so the gains are the same on every machine.

Why this exists
---------------
The SDP solvers (Clarabel, SCS) stop at a tolerance of about 1e-8 somewhere on the optimal
face of the program, and the optimal face is not a point: many (Q, N) reach the smallest
peak-input bound t. Where exactly a solver stops depends on the last bits of every BLAS
call it makes, and OpenBLAS picks its kernel per CPU (Haswell, SkylakeX, ...): measured,
the default design's gains differed at 1e-5 relative between kernels, and the wheels'
stick and slip in the catch amplify that into different trajectories. Tightening the
solver does not help (Clarabel stalls, "AlmostSolved", at the same spread of 1e-5), and
rounding the solver's answer to a few digits cannot help either: a value within the spread
of a rounding boundary rounds both ways on two machines.

What is computed instead
------------------------
The design is defined as a point that is unique and depends smoothly on the data: the
point of the program's *central path* whose duality gap is :data:`KAPPA` (1 %) of its
objective. For the program's constraints F_k(x) ⪰ 0 (every LMI of
:func:`twin.controllers.lmi_regions.build_program`, with the room :data:`ROOM`) it is the
minimiser of the strictly convex

    φ_μ(x) = t / μ − Σ_k log det F_k(x),   with μ = KAPPA · t / ν   (ν = Σ_k size of F_k),

so that the gap ν μ (Boyd & Vandenberghe, *Convex Optimization*, 2004, §11.2) is KAPPA · t:
the objective t (the squared peak-input bound) is within 1 % of its minimum, the bound
itself within 0.5 %, and every constraint holds strictly with a margin the barrier keeps
(the design is pushed a little inside the feasible set rather than onto its edge). Being
the minimiser of a strictly convex function, the point does not depend on where it is
approached from: the solver's answer is only where the search starts, so the design is
also the same whichever solver (Clarabel, SCS, cvxpy's formulation or the direct one)
found the start, and whatever their versions.

Why 1 % and not less: the barrier's Hessian grows ill-conditioned as the gap shrinks
(cond ~ 1/KAPPA²; measured on the default design 6e8 at 1 %, 6e10 at 0.01 %), and the
exact steps below contract only while cond(H) · 1e-16 ≪ 1. At 1 % every design tried
converges (the paper's relaxation over the five-parameter example box, 1207 variables,
included); at 0.1 % that one did not.

How: damped Newton steps on φ_μ in float64 (numpy; these may differ in their last bits
from machine to machine, which only changes the path; Boyd & Vandenberghe §9.6), then
Newton steps whose *gradient* is evaluated in :mod:`decimal` arithmetic at :data:`DIGITS`
significant digits (correctly rounded, the same everywhere) with a float64 Hessian, until
the step is below 1e-26 relative (the next would be ~1e-30). The float64 Hessian's error
only slows the contraction (to about 1e-4 per step here); the fixed point is where the
exact gradient vanishes. The design's numbers (Q, P, the gains, the peak input) are then
computed from that point in the same arithmetic and rounded once to float64: two machines
agree unless a number lies within ~1e-30 of a rounding boundary of float64. The program's
own numbers are the same everywhere too: they are built by elementwise IEEE operations
only (:func:`twin.controllers.lmi_regions.build_program`).

Should the point not be found (a numerical limit near the edge of feasibility),
:func:`refine` raises and the design falls back to the solver's answer with a one-line
note (``BalanceDesign.unique`` is then False).

What it costs (benchmarks/bench_design_cost.py): the default design's first solve in a
process about 0.1 s more than the solver's answer alone; a cached design
(:mod:`twin.controllers.design_cache`) nothing.
"""
from __future__ import annotations

import decimal
import math
from dataclasses import dataclass
from decimal import Decimal

import numpy as np

from twin.controllers import lmi_regions as regions
from twin.errors import InfeasibleDesign

KAPPA = 1e-2  # relative duality gap of the design's central point
ROOM = 0.25e-5  # the refined program's room: a quarter of the solve's (lmi._ROOM["CLARABEL"])
DIGITS = 50  # significant decimal digits of the refinement's arithmetic
_STEP_TOL = 1e-26  # relative Newton step below which the point is final (the next would be ~1e-30)
_KAPPA_START = 1e-2
_MAX_NEWTON = 60  # per stage of the float64 path
_CTX = decimal.Context(prec=DIGITS, rounding=decimal.ROUND_HALF_EVEN, Emin=-999999, Emax=999999)


@dataclass
class _Block:
    C: np.ndarray  # (m, m)
    idx: np.ndarray  # (k,) variable indices
    M: np.ndarray  # (k, m, m) coefficients: F(x) = C + Σ x[idx[v]] M[v]
    # the same in Decimal: C as rows, and per variable its nonzero entries (a, b, value)
    Cd: list
    Md: list


def _blocks(prog) -> list[_Block]:
    out = []
    for const, terms in prog.blocks:
        coef: dict[int, np.ndarray] = {}
        for idx, c in terms:
            for v, cv in zip(np.asarray(idx).tolist(), c):
                coef[v] = coef[v] + cv if v in coef else np.array(cv)
        keep = [v for v in sorted(coef) if np.any(coef[v] != 0.0)]
        M = np.stack([coef[v] for v in keep]) if keep else np.zeros((0,) + const.shape)
        Cd = [[Decimal(float(v)) for v in row] for row in const]
        Md = [[(a, b, Decimal(float(M[q, a, b]))) for a, b in zip(*np.nonzero(M[q]))] for q in range(len(keep))]
        out.append(_Block(np.array(const), np.array(keep, dtype=int), M, Cd, Md))
    return out


def _groups(blocks) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The blocks stacked by shape, for batched float64 work: [(C (B, m, m), idx (B, k),
    M (B, k, m, m)), ...]."""
    by: dict[tuple, list] = {}
    for b in blocks:
        by.setdefault((b.C.shape[0], len(b.idx)), []).append(b)
    return [(np.stack([b.C for b in bs]), np.stack([b.idx for b in bs]), np.stack([b.M for b in bs]))
            for bs in by.values()]


def _float_derivatives(groups, x, it, mu, n):
    """Gradient and Hessian of φ_μ at x in float64, or None if x is outside the domain."""
    g_at, g_w, h_at, h_w = [], [], [], []
    for C, idx, M in groups:
        F = C + np.einsum("bv,bvij->bij", x[idx], M)
        try:
            L = np.linalg.cholesky(0.5 * (F + np.swapaxes(F, 1, 2)))
        except np.linalg.LinAlgError:
            return None
        Linv = np.linalg.inv(L)
        W = np.swapaxes(Linv, 1, 2) @ Linv
        WM = W[:, None] @ M  # (b, v, m, m)
        b, v, m = WM.shape[0], WM.shape[1], WM.shape[2]
        g_at.append(idx.ravel())
        g_w.append(np.trace(WM, axis1=2, axis2=3).ravel())
        h_at.append((idx[:, :, None] * n + idx[:, None, :]).ravel())
        # tr(WM_v WM_w) = Σ_ij WM_v[i, j] WM_w[j, i]: one batched product
        h_w.append((WM.reshape(b, v, m * m) @ np.swapaxes(WM, 2, 3).reshape(b, v, m * m).transpose(0, 2, 1)).ravel())
    # one accumulation of every block's terms (variables shared by blocks add up)
    g = -np.bincount(np.concatenate(g_at), weights=np.concatenate(g_w), minlength=n)
    H = np.bincount(np.concatenate(h_at), weights=np.concatenate(h_w), minlength=n * n).reshape(n, n)
    g[it] += 1.0 / mu
    return g, H


def _feasible(groups, x) -> bool:
    for C, idx, M in groups:
        F = C + np.einsum("bv,bvij->bij", x[idx], M)
        try:
            np.linalg.cholesky(0.5 * (F + np.swapaxes(F, 1, 2)))
        except np.linalg.LinAlgError:
            return False
    return True


def _newton_float(groups, x, it, mu, tol, local=()):
    """Damped Newton on φ_μ for a fixed μ until the Newton decrement is below ``tol``;
    returns (x, H, steps) or raises."""
    for k in range(_MAX_NEWTON):
        d = _float_derivatives(groups, x, it, mu, len(x))
        if d is None:  # pragma: no cover - steps keep x inside
            raise InfeasibleDesign("the design's refinement left the feasible set (a numerical limit); "
                                   "lower --decay-rate or --damping")
        g, H = d
        dx = _solve(H, -g, local)
        lam = math.sqrt(max(float(-g @ dx), 0.0))
        if lam < tol:
            return x, H, k
        # the damped step of a self-concordant function stays inside its domain (Boyd &
        # Vandenberghe §9.6.4); the check below only guards against rounding
        step = 1.0 if lam < 0.25 else 1.0 / (1.0 + lam)
        while not _feasible(groups, x + step * dx):
            step *= 0.5
            if step < 1e-12:  # pragma: no cover
                raise InfeasibleDesign("the design's refinement stalled at the edge of the feasible set (a "
                                       "numerical limit); lower --decay-rate or --damping")
        x = x + step * dx
    raise InfeasibleDesign(f"the design's refinement did not converge in {_MAX_NEWTON} Newton steps (a numerical "
                           f"limit); lower --decay-rate or --damping")


def _solve(H, rhs, local=()):
    """H⁻¹ rhs in float64, Jacobi-scaled (the variables Q, N, t, Y span decades). ``local``:
    index arrays of variables that couple only among themselves and with the rest (the
    slack Y^k of each plant model): those blocks are eliminated one by one (a Schur
    complement), which for the 33-model example box is 1/1000 of a dense solve's work."""
    s = 1.0 / np.sqrt(np.maximum(np.abs(np.diag(H)), 1e-300))
    bs = rhs * s
    if not len(local):
        return s * np.linalg.solve(H * s[:, None] * s[None, :], bs)
    n = len(rhs)
    mask = np.ones(n, dtype=bool)
    for idx in local:
        mask[idx] = False
    g = np.nonzero(mask)[0]
    sg = s[g]
    S = H[np.ix_(g, g)] * sg[:, None] * sg[None, :]  # only the blocks used are scaled
    r = bs[g].copy()
    parts = []
    for idx in local:  # x_k = H_kk⁻¹ (b_k − H_kg x_g)
        sk = s[idx]
        Hkk = H[np.ix_(idx, idx)] * sk[:, None] * sk[None, :]
        Hkg = H[np.ix_(idx, g)] * sk[:, None] * sg[None, :]
        sol = np.linalg.solve(Hkk, np.column_stack([bs[idx], Hkg]))
        S -= Hkg.T @ sol[:, 1:]
        r -= Hkg.T @ sol[:, 0]
        parts.append((idx, sol))
    x = np.empty(n)
    x[g] = np.linalg.solve(S, r)
    for idx, sol in parts:
        x[idx] = sol[:, 0] - sol[:, 1:] @ x[g]
    return s * x


# ---- the exact part ---------------------------------------------------------------------------
def _inverse_decimal(F: list, ctx) -> list | None:
    """Inverse of a symmetric matrix (rows of Decimal) by LDLᵀ, in the context ``ctx``; None
    if it is not positive definite (a pivot d_k ≤ 0). W = L⁻ᵀ D⁻¹ L⁻¹ costs about m³/2
    operations, half of Gauss–Jordan's."""
    m = len(F)
    zero, one = Decimal(0), Decimal(1)
    with decimal.localcontext(ctx):
        L = [[zero] * m for _ in range(m)]
        d = [zero] * m
        for k in range(m):
            Lk = L[k]
            for j in range(k):  # L_kj = (F_kj − Σ_{i<j} L_ki L_ji d_i) / d_j
                Lj = L[j]
                acc = F[k][j]
                for i in range(j):
                    acc -= Lk[i] * Lj[i] * d[i]
                Lk[j] = acc / d[j]
            acc = F[k][k]
            for i in range(k):
                acc -= Lk[i] * Lk[i] * d[i]
            if acc <= 0:
                return None
            d[k] = acc
            Lk[k] = one
        # X = L⁻¹ (unit lower triangular), column by column
        X = [[zero] * m for _ in range(m)]
        for c in range(m):
            X[c][c] = one
            for r in range(c + 1, m):
                acc = zero
                Lr = L[r]
                for i in range(c, r):
                    acc -= Lr[i] * X[i][c]
                X[r][c] = acc
        inv_d = [one / v for v in d]
        W = [[zero] * m for _ in range(m)]
        for a in range(m):
            for b in range(a, m):
                acc = zero
                for k in range(b, m):  # X_ka = 0 for k < a, X_kb = 0 for k < b
                    acc += X[k][a] * X[k][b] * inv_d[k]
                W[a][b] = W[b][a] = acc
    return W


def _gradient_decimal(blocks, xd, it, nu, kappa, ctx) -> list:
    """∇φ_μ at ``xd`` (Decimal), μ = kappa·t/ν, every operation correctly rounded in ``ctx``."""
    g = [Decimal(0)] * len(xd)
    with decimal.localcontext(ctx):
        for b in blocks:
            F = [row[:] for row in b.Cd]
            for q, v in enumerate(b.idx):
                xv = xd[v]
                for a, c, val in b.Md[q]:
                    F[a][c] += xv * val
            W = _inverse_decimal(F, ctx)
            if W is None:
                raise InfeasibleDesign("the design's refinement left the feasible set in exact arithmetic (a "
                                       "numerical limit); lower --decay-rate or --damping")
            for q, v in enumerate(b.idx):
                acc = Decimal(0)
                for a, c, val in b.Md[q]:
                    acc += W[c][a] * val
                g[v] -= acc
        mu = Decimal(repr(kappa)) * xd[it] / Decimal(nu)
        g[it] += 1 / mu
    return g


@dataclass(frozen=True)
class Center:
    """The design's point: ``x`` (Decimal, DIGITS digits) laid out as the program's decision
    vector, and how it was reached."""

    x: list
    float_steps: int
    exact_steps: int


def central_point(prog, x0, it: int, local=()) -> Center:
    """The unique point of ``prog`` (a :class:`twin.controllers.lmi_regions._Program` built
    with :data:`ROOM`) described in the module docstring, found from the solver's answer ``x0``
    (its objective ``x0[it]`` is raised a little: the solver stops on the boundary)."""
    blocks = _blocks(prog)
    groups = _groups(blocks)
    nu = sum(b.C.shape[0] for b in blocks)
    x = np.array(x0, dtype=float)
    x[it] = x[it] * (1.0 + 1e-3) + 1e-9
    if not _feasible(groups, x):
        raise InfeasibleDesign("the solver's answer does not meet the design's LMIs with room (a numerical limit); "
                               "lower --decay-rate or --damping")
    steps = 0
    kappa = _KAPPA_START
    while True:  # follow the central path down to the target gap, μ fixed in each stage
        # (a float64 Newton decrement below ~1e-8 is rounding noise: the exact steps finish)
        x, H, k = _newton_float(groups, x, it, kappa * x[it] / nu, 1e-6, local)
        steps += k
        if kappa <= KAPPA:
            break
        kappa = max(kappa * 0.1, KAPPA)
    # The exact system: r(x) = ∇φ_μ(x) with μ = KAPPA·t/ν, whose Jacobian is the barrier's
    # Hessian H minus ν/(KAPPA t²) on the (t, t) entry (μ moves with t).
    ctx = _CTX.copy()
    xd = [Decimal(float(v)) for v in x]
    scale = max(1.0, float(np.abs(x).max()))
    for k in range(12):
        g = _gradient_decimal(blocks, xd, it, nu, KAPPA, ctx)
        if k:  # the Hessian where the point now is (rounded to float64): the barrier's curvature
            # changes fast near the tight constraints, and a stale one slows the contraction
            xf = np.array([float(v) for v in xd])
            H = _float_derivatives(groups, xf, it, KAPPA * xf[it] / nu, len(xf))[1]
        J = H.copy()
        J[it, it] -= nu / (KAPPA * float(xd[it]) ** 2)
        dx = _solve(J, -np.array([float(v) for v in g]), local)
        xd = [ctx.add(a, Decimal(float(d))) for a, d in zip(xd, dx)]
        if float(np.abs(dx).max()) <= _STEP_TOL * scale:
            return Center(xd, steps, k + 1)
    raise InfeasibleDesign("the design's refinement did not settle in exact arithmetic (a numerical limit); "
                           "lower --decay-rate or --damping")


# ---- the design's numbers from the point -----------------------------------------------------
def start_vector(lay, Q, N, Y, t: float, T, T0) -> np.ndarray:
    """A solver's answer (Q, N_j, Y^k blocks, t in the coordinates z = T⁻¹ x) as the decision
    vector of a program laid out by ``lay`` in the coordinates of ``T0``."""
    T, T0 = np.asarray(T, dtype=float), np.asarray(T0, dtype=float)
    ratio = T / T0  # z0 = T0⁻¹ x = (T / T0) z: Q0 = D Q D, N0 = N D with D = diag(T / T0)
    x = np.zeros(lay.it + 1 + sum(len(i) for i in lay.iY) + sum(len(i) for i in lay.iZ))
    Q0 = Q * ratio[:, None] * ratio[None, :]
    x[lay.iq] = [Q0[a, b] for a, b in _basis_pairs(lay.n)]
    for j, idx in enumerate(lay.iN):
        x[idx] = np.ravel(N[j]) * ratio
    x[lay.it] = t
    if lay.iY:
        big = np.kron(np.ones((lay.r, lay.r)), np.outer(ratio, ratio))
        for k, idx in enumerate(lay.iY):
            Yb = np.block(Y[k]) * big
            x[idx] = [Yb[a, b] for a, b in _basis_pairs(lay.r * lay.n)]
    return x


def _basis_pairs(m: int) -> list[tuple[int, int]]:
    """(a, b) of each element of lmi_regions._sym_basis(m), in its order."""
    return [(a, b) for b in range(m) for a in range(b + 1)]


@dataclass(frozen=True)
class Refined:
    """A design's numbers from its central point, each rounded once from DIGITS digits.

    ``Qz, N, Y, t`` in the coordinates z = T⁻¹ x of the program (for the independent
    check); ``gains`` (r, n), ``P`` and ``Q`` (n, n) in x for the design's ε; ``peak`` the
    certified peak |u| (N·m)."""

    Qz: np.ndarray
    N: list
    Y: list
    t: float
    T: np.ndarray
    gains: np.ndarray
    P: np.ndarray
    Q: np.ndarray
    peak: float
    center: Center


def refine(models, decay_rate: float, damping: float, all_vertices: bool, Q, N, Y, t: float, T, epsilon: float,
           T0) -> Refined:
    """The design's central point from a solver's answer (``Q, N, Y, t`` in z = T⁻¹ x), and
    its numbers for ε = ``epsilon``; raises InfeasibleDesign if it cannot be found."""
    prog, lay = regions.build_program(models, decay_rate, damping, T0, ROOM, "shared", all_vertices)
    center = central_point(prog, start_vector(lay, Q, N, Y, t, T, T0), lay.it, lay.iY)
    ctx = _CTX.copy()
    xd = center.x
    n, r = lay.n, lay.r
    T0d = [Decimal(float(v)) for v in np.asarray(T0, dtype=float)]
    Qz = [[Decimal(0)] * n for _ in range(n)]
    for (a, b), v in zip(_basis_pairs(n), lay.iq):
        Qz[a][b] = Qz[b][a] = xd[v]
    Nz = [[xd[v] for v in idx] for idx in lay.iN]
    # x coordinates at ε = 1: Q = T Q̃ T, N = Ñ T, P = Q⁻¹, G_j = −N_j P
    Qx = [[ctx.multiply(ctx.multiply(T0d[a], Qz[a][b]), T0d[b]) for b in range(n)] for a in range(n)]
    Px = _inverse_decimal(Qx, ctx)
    if Px is None:  # pragma: no cover - Q ≻ 0 is one of the program's constraints
        raise InfeasibleDesign("the design's Q is not positive definite (a numerical limit)")
    Px = [[ctx.divide(ctx.add(Px[a][b], Px[b][a]), Decimal(2)) for b in range(n)] for a in range(n)]
    Nx = [[ctx.multiply(Nz[j][c], T0d[c]) for c in range(n)] for j in range(r)]
    G = [[-_dot([Nx[j][c] for c in range(n)], [Px[c][b] for c in range(n)], ctx) for b in range(n)]
         for j in range(r)]
    # peak |u| over the ellipsoid xᵀPx ≤ 1 of the starts ‖x0‖ ≤ ε: ε max_j sqrt(G_j Q G_jᵀ)
    quad = [_dot(G[j], [_dot(Qx[a], G[j], ctx) for a in range(n)], ctx) for j in range(r)]
    eps = Decimal(float(epsilon))
    e2 = ctx.multiply(eps, eps)
    peak = ctx.multiply(eps, max(q for q in quad).max(Decimal(0)).sqrt(ctx))
    f = np.vectorize(float, otypes=[float])
    Yf = []
    if lay.iY:
        m = r * n
        for idx in lay.iY:
            Yb = np.zeros((m, m))
            for (a, b), v in zip(_basis_pairs(m), idx):
                Yb[a, b] = Yb[b, a] = float(xd[v])
            Yf.append([[Yb[i * n:(i + 1) * n, j * n:(j + 1) * n] for j in range(r)] for i in range(r)])
    else:
        Yf = [[[np.zeros((n, n)) for _ in range(r)] for _ in range(r)] for _ in models]
    return Refined(
        Qz=f(np.array(Qz, dtype=object)), N=[f(np.array([row], dtype=object)) for row in Nz], Y=Yf,
        t=float(xd[lay.it]), T=np.asarray(T0, dtype=float), gains=f(np.array(G, dtype=object)),
        P=f(np.array([[ctx.divide(v, e2) for v in row] for row in Px], dtype=object)),
        Q=f(np.array([[ctx.multiply(v, e2) for v in row] for row in Qx], dtype=object)),
        peak=float(peak), center=center)


def _dot(a, b, ctx) -> Decimal:
    acc = Decimal(0)
    for u, v in zip(a, b):
        acc = ctx.add(acc, ctx.multiply(u, v))
    return acc
