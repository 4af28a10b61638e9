"""The certificates of the designs the twin ships with, re-checked in exact rational
arithmetic, independently of any solver and of floating point.

The designs are rounded to float64 once (twin.controllers.lmi_center, and the LQR's
decimal_linalg); here every float of the design and of its model (A_i, B_i from
ts_matrices, the gains, P) is taken as the exact rational it is, and each matrix
inequality is decided by an LDLᵀ factorisation in fractions.Fraction: M ≺ 0 exactly when
every pivot of −M is positive. So what is asserted is a proof about the gains actually used,
not a numerical check with a tolerance.
"""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from twin.controllers import lmi, lmi_regions
from twin.controllers.lmi import NOMINAL_DESIGN, design_balance_gains
from twin.params import NOMINAL


def _frac(M) -> list[list[Fraction]]:
    return [[Fraction(float(v)) for v in row] for row in np.atleast_2d(np.asarray(M, dtype=float))]


def _mul(A, B):
    return [[sum(A[i][k] * B[k][j] for k in range(len(B))) for j in range(len(B[0]))] for i in range(len(A))]


def _add(*Ms):
    return [[sum(M[i][j] for M in Ms) for j in range(len(Ms[0][0]))] for i in range(len(Ms[0]))]


def _scale(c, M):
    return [[c * v for v in row] for row in M]


def _t(M):
    return [list(r) for r in zip(*M)]


def _positive_definite(M) -> bool:
    """Exact: M (symmetric, rational) ≻ 0 iff every pivot of its LDLᵀ is positive."""
    A = [row[:] for row in M]
    n = len(A)
    assert all(A[i][j] == A[j][i] for i in range(n) for j in range(n)), "not symmetric"
    for k in range(n):
        p = A[k][k]
        if p <= 0:
            return False
        for i in range(k + 1, n):
            f = A[i][k] / p
            for j in range(k + 1, n):
                A[i][j] -= f * A[k][j]
    return True


def _negative_definite(M) -> bool:
    return _positive_definite(_scale(Fraction(-1), M))


def _sym(M):
    return _scale(Fraction(1, 2), _add(M, _t(M)))


def _sector(W, s, c):
    """S(W) = [[s (W + Wᵀ), c (W − Wᵀ)], [c (Wᵀ − W), s (W + Wᵀ)]] for the conic sector."""
    H = _add(W, _t(W))
    K = _add(W, _scale(Fraction(-1), _t(W)))
    top = [hr + kr for hr, kr in zip(_scale(s, H), _scale(c, K))]
    bottom = [kr + hr for kr, hr in zip(_scale(-c, K), _scale(s, H))]
    return top + bottom


@pytest.fixture(scope="module")
def default_design():
    return design_balance_gains()


def test_the_default_designs_every_vertex_closed_loop_decays_and_stays_in_the_sector(default_design):
    """all_vertices: with the common P, sym(P A_cl) + 2aP ≺ 0 and S(P A_cl) ≺ 0 for every
    vertex A_i + B_i G_j of every certified model (nominal and the box's corners), which by
    convexity covers every mix of model and controller weights."""
    d = default_design
    assert d.unique and d.all_vertices and d.damping > 0 and len(d.uncertain) == 2
    P = _frac(d.P)
    assert _positive_definite(P)
    G = [_frac(d.gains[j:j + 1]) for j in range(2)]
    a2 = Fraction(2) * Fraction(d.decay_rate)
    s, c = (Fraction(v) for v in lmi_regions.sector_sin_cos(d.damping))
    checked = 0
    for A, B in d.certified_models():
        for i in range(2):
            Ai, Bi = _frac(A[i]), _frac(B[i])
            for j in range(2):
                Acl = _add(Ai, _mul(Bi, G[j]))
                W = _mul(P, Acl)
                assert _negative_definite(_add(W, _t(W), _scale(a2, P))), ("decay", i, j)
                assert _negative_definite(_sector(W, s, c)), ("sector", i, j)
                checked += 1
    assert checked == 4 * d.certificate.models == 20


def test_a_doctored_gain_fails_the_exact_check(default_design):
    """The check can fail: the same design with G1's θ gain halved leaves the decay region."""
    d = default_design
    P = _frac(d.P)
    bad = d.gains.copy()
    bad[0, 0] *= 0.5
    (A, B) = d.certified_models()[0]
    W = _mul(P, _add(_frac(A[0]), _mul(_frac(B[0]), _frac(bad[0:1]))))
    assert not _negative_definite(_add(W, _t(W), _scale(Fraction(2) * Fraction(d.decay_rate), P)))


def test_the_nominal_design_with_the_papers_relaxation_is_certified_exactly():
    """NOMINAL_DESIGN (Lemma 1's relaxation, one plant model): with Q = P⁻¹ and N_j = −G_j Q
    (exact rationals of the gains actually used) and the design's own slack Y (from its
    central point), Φ_ii + Y_ii ≺ 0, Φ_ij + Y_ij ⪯ 0 and [[Y11, Y12], [Y21, Y22]] ≻ 0; and
    ε² I ⪯ Q with the input bound of Lemma 2."""
    d = design_balance_gains(**NOMINAL_DESIGN)
    assert d.unique and not d.all_vertices
    # the slack is the design's own: its central point, refined from the cvxpy solution
    (A, B) = d.certified_models()[0]
    sol = lmi._certified_solution(A, B, d.decay_rate, None)
    Q1, N1, Y1, T, used, t1 = sol
    found = lmi._unique_point([(A, B)], d.decay_rate, 0.0, False, lmi._ModelsSolution(Q1, N1, [Y1], None, T, used, t1),
                              d.epsilon)
    assert found.gains.tobytes() == d.gains.tobytes()
    Tz = found.solution.T
    # Y in x coordinates at the design's ε: Y_x = ε² T Y_z T, blockwise
    Yx = [[_frac(d.epsilon**2 * Tz[:, None] * found.solution.Y[0][i][j] * Tz[None, :]) for j in range(2)]
          for i in range(2)]
    P = _frac(d.P)
    Q = _inverse(P)
    assert _positive_definite(Q)
    N = [_scale(Fraction(-1), _mul(_frac(d.gains[j:j + 1]), Q)) for j in range(2)]
    a2 = Fraction(2) * Fraction(d.decay_rate)
    for i in range(2):
        Ai, Bi = _frac(A[i]), _frac(B[i])
        for j in range(2):
            AQ = _mul(Ai, Q)
            BN = _mul(Bi, N[j])
            phi = _add(AQ, _t(AQ), _scale(Fraction(-1), _add(BN, _t(BN))), _scale(a2, Q), _sym(Yx[i][j]))
            if i == j:
                assert _negative_definite(phi), (i, j)
            else:
                assert _positive_definite(_scale(Fraction(-1), phi)) or _semidefinite_negative(phi), (i, j)
    Ybig = [Yx[0][0][r] + Yx[0][1][r] for r in range(4)] + [Yx[1][0][r] + Yx[1][1][r] for r in range(4)]
    assert _positive_definite(_sym(Ybig))
    # Lemma 2: ε² I ⪯ Q and |G_j x| ≤ ρ on the ellipsoid: ρ² − G_j Q G_jᵀ ≥ 0
    eps2 = Fraction(d.epsilon) ** 2
    assert _positive_definite(_add(Q, _scale(-eps2, _identity(4))))
    for j in range(2):
        g = _frac(d.gains[j:j + 1])
        assert _mul(_mul(g, Q), _t(g))[0][0] <= Fraction(d.rho) ** 2


def test_the_lqr_design_stabilises_its_sampled_model_exactly():
    """The LQR's rounded gain: the sampled closed loop A_c = Ad − Bd K (the float64 matrices
    the design exposes) is Schur stable, proved by its own Riccati matrix: A_cᵀ P A_c − P ≺ 0."""
    from twin.controllers.lqr import LQRController

    c = LQRController(NOMINAL)
    for design in (c.balance_design, c.yaw_design):
        Ac = _add(_frac(design.Ad), _scale(Fraction(-1), _mul(_frac(design.Bd), _frac(design.K))))
        P = _sym(_frac(design.P))
        assert _positive_definite(P)
        assert _negative_definite(_add(_mul(_mul(_t(Ac), P), Ac), _scale(Fraction(-1), P)))


def _identity(n):
    return [[Fraction(int(i == j)) for j in range(n)] for i in range(n)]


def _inverse(M):
    n = len(M)
    A = [row[:] + _identity(n)[i] for i, row in enumerate(M)]
    for c in range(n):
        p = next(r for r in range(c, n) if A[r][c] != 0)
        A[c], A[p] = A[p], A[c]
        piv = A[c][c]
        A[c] = [v / piv for v in A[c]]
        for r in range(n):
            if r != c and A[r][c] != 0:
                f = A[r][c]
                A[r] = [a - f * b for a, b in zip(A[r], A[c])]
    return [row[n:] for row in A]


def _semidefinite_negative(M) -> bool:
    """−M ⪰ 0 exactly, by the nonnegativity of every principal minor (small matrices only)."""
    from itertools import combinations

    N = _scale(Fraction(-1), M)
    n = len(N)
    for k in range(1, n + 1):
        for idx in combinations(range(n), k):
            if _det([[N[i][j] for j in idx] for i in idx]) < 0:
                return False
    return True


def _det(M):
    A = [row[:] for row in M]
    n = len(A)
    det = Fraction(1)
    for c in range(n):
        p = next((r for r in range(c, n) if A[r][c] != 0), None)
        if p is None:
            return Fraction(0)
        if p != c:
            A[c], A[p] = A[p], A[c]
            det = -det
        det *= A[c][c]
        for r in range(c + 1, n):
            f = A[r][c] / A[c][c]
            A[r] = [a - f * b for a, b in zip(A[r], A[c])]
    return det
