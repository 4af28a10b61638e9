"""Small dense linear algebra in Python's :mod:`decimal` at 50 significant digits: the
matrix exponential, the Van Loan integrals, and the discrete- and continuous-time
algebraic Riccati equations, computed the same way to the last bit on every machine.

Why not numpy/scipy
-------------------
numpy's and scipy's dense linear algebra runs in the BLAS/LAPACK they bundle (OpenBLAS),
which picks a kernel per CPU at load time (``OPENBLAS_CORETYPE`` overrides the choice).
The kernels block, vectorise and fuse multiply-adds differently, so ``A @ B``,
``scipy.linalg.expm``, ``solve_discrete_are`` and ``np.linalg.solve`` return different
last bits on different CPUs (measured for the LQR gains, issue 25), and a closed loop with
stick/slip amplifies a last-bit difference of a gain into a visibly different trajectory.

What this module does instead
-----------------------------
Every operation is one of the General Decimal Arithmetic operations (+, −, ×, ÷, ln,
exp, comparison) of :mod:`decimal`, each correctly rounded to the context precision
(IEEE 754-2008 decimal semantics, implemented by libmpdec in integer arithmetic: no
floating-point unit, no SIMD, no BLAS), applied in an order fixed by this code. The
inputs are converted from float64 exactly (``Decimal(float)`` is exact) and the results
back to float64 once, correctly rounded (``float(Decimal)`` parses the decimal string with
Python's correctly rounded conversion). So the output bits are a function of the input
bits alone: the same on any CPU, BLAS kernel, numpy SIMD target, numpy or scipy version.
50 digits leave some 30 digits of margin over float64's 16 for the error growth of the
algorithms below, so the rounded results are float64's nearest values (in all but
astronomically rare ties).

Algorithms (all deterministic; no starting value from a floating-point solver, so no
trace of any kernel remains even in the last decimal digits):

* :func:`expm`: scaling and squaring with a Taylor series (Moler & Van Loan, "Nineteen
  dubious ways to compute the exponential of a matrix, twenty-five years later", SIAM
  Review 45(1), 2003, §3): scale by 2^-s until ‖M‖₁ ≤ 1/8, sum the series until a
  term is below 10⁻⁵² of the sum, square s times.
* :func:`van_loan`: the zero-order-hold discretisation and the exactly sampled quadratic
  cost from one exponential of a block matrix (C. F. Van Loan, "Computing integrals
  involving the matrix exponential", IEEE TAC 23(3), 1978, Theorem 1).
* :func:`solve_dare`: the structure-preserving doubling algorithm (SDA; E. K.-W. Chu,
  H.-Y. Fan, W.-W. Lin, C.-S. Wang, "Structure-preserving algorithms for periodic
  discrete-time algebraic Riccati equations", Int. J. Control 77(8), 2004; convergence:
  W.-W. Lin, S.-F. Xu, SIAM J. Matrix Anal. Appl. 28(1), 2006), which needs no
  stabilising initial gain and converges quadratically, then Newton's method (Hewer,
  IEEE TAC 16(4), 1971) until an update is below 10⁻³⁰ of P.
* :func:`solve_care`: the matrix sign function of the Hamiltonian by Newton's iteration
  with determinant scaling (J. D. Roberts, Int. J. Control 32(4), 1980; R. Byers, Linear
  Algebra Appl. 85, 1987), then Newton's method (Kleinman, IEEE TAC 13(1), 1968) until
  an update is below 10⁻³⁰ of P.

Both Riccati solvers then check, in the same arithmetic, that the residual is below 10⁻³⁰
of P and that the closed loop is stable (the Lyapunov/Stein equation of the closed loop
with right-hand side I has a positive definite solution), so "no stabilising solution"
is decided identically everywhere too.

Cost: designed for the handful of states of a balance or yaw model (n ≤ 10 or so); each
operation is a Python-level loop over :class:`decimal.Decimal` values. The two sampled
LQR designs of :class:`twin.controllers.lqr.LQRController` (a 10 × 10 and a 6 × 6 Van
Loan exponential, a 4-state and a 2-state Riccati equation) take about 10 ms together.

Matrices are lists of rows of Decimals; :func:`dec` and :func:`to_float` convert.
"""
from __future__ import annotations

import decimal
from decimal import Decimal
from operator import mul
from typing import Sequence

import numpy as np

DIGITS = 50  # significant decimal digits of every operation
NEWTON_TOL = Decimal("1e-30")  # relative size of the last Newton update, and of the final residual
# relative change of an iterate at which the doubling (sign) iteration has converged: far below
# float64, and Newton's method after it squares the error again
_SDA_TOL = Decimal("1e-40")
_SIGN_TOL = Decimal("1e-25")  # inverting Z each step leaves noise of cond(Z)·1e-50: stop well above it
_MAX_DOUBLING = 200  # SDA squares the closed loop each step: 2^200 periods is far past convergence
_MAX_SIGN = 200
_MAX_NEWTON = 20
_TAYLOR_TOL = Decimal("1e-52")
_CONTEXT = decimal.Context(prec=DIGITS, rounding=decimal.ROUND_HALF_EVEN, Emin=-999999, Emax=999999,
                           traps=[decimal.InvalidOperation, decimal.DivisionByZero, decimal.Overflow])
ZERO, ONE, HALF = Decimal(0), Decimal(1), Decimal("0.5")

Matrix = list  # list[list[Decimal]]


class NoSolution(ArithmeticError):
    """The equation has no (stabilising) solution, or the iteration did not find it."""


def context() -> decimal.Context:
    """The arithmetic every function here runs in (use ``with decimal.localcontext(context())``)."""
    return _CONTEXT.copy()


# ---- conversion --------------------------------------------------------------------------------
def dec(a) -> Matrix:
    """A 2-d float array as a Decimal matrix, exactly (every float64 is a finite decimal)."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"expected a 2-d array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("matrix entries must be finite")
    return [[Decimal(float(v)) for v in row] for row in arr.tolist()]


def to_float(M: Matrix) -> np.ndarray:
    """The Decimal matrix as float64, each entry correctly rounded (round half to even)."""
    return np.array([[float(v) for v in row] for row in M], dtype=np.float64).reshape(len(M), len(M[0]) if M else 0)


# ---- elementary operations (in the current decimal context) ------------------------------------
def eye(n: int) -> Matrix:
    return [[ONE if i == j else ZERO for j in range(n)] for i in range(n)]


def zeros(n: int, m: int) -> Matrix:
    return [[ZERO] * m for _ in range(n)]


def transpose(A: Matrix) -> Matrix:
    return [list(col) for col in zip(*A)]


def add(A: Matrix, B: Matrix) -> Matrix:
    return [[a + b for a, b in zip(ra, rb)] for ra, rb in zip(A, B)]


def sub(A: Matrix, B: Matrix) -> Matrix:
    return [[a - b for a, b in zip(ra, rb)] for ra, rb in zip(A, B)]


def scale(c: Decimal, A: Matrix) -> Matrix:
    return [[c * a for a in row] for row in A]


def matmul(A: Matrix, B: Matrix) -> Matrix:
    """A B, each entry summed left to right over the inner index."""
    cols = list(zip(*B))
    return [[sum(map(mul, row, col), ZERO) for col in cols] for row in A]


def sym(A: Matrix) -> Matrix:
    """(A + Aᵀ) / 2."""
    n = len(A)
    return [[(A[i][j] + A[j][i]) * HALF if i != j else A[i][i] for j in range(n)] for i in range(n)]


def norm1(A: Matrix) -> Decimal:
    """The 1-norm (largest column sum of absolute values)."""
    return max(sum((abs(v) for v in col), ZERO) for col in zip(*A))


def block(rows: Sequence[Sequence[Matrix]]) -> Matrix:
    """The block matrix of a grid of matrices (each block row of equal heights)."""
    out = []
    for blocks in rows:
        for i in range(len(blocks[0])):
            out.append([v for b in blocks for v in b[i]])
    return out


def sub_block(A: Matrix, r0: int, r1: int, c0: int, c1: int) -> Matrix:
    return [row[c0:c1] for row in A[r0:r1]]


def solve(A: Matrix, B: Matrix) -> Matrix:
    """X with A X = B: Gaussian elimination with partial pivoting (largest |entry|, the
    first one on ties). Raises :class:`NoSolution` if A is singular."""
    n = len(A)
    m = len(B[0])
    M = [list(ra) + list(rb) for ra, rb in zip(A, B)]
    for k in range(n):
        p = max(range(k, n), key=lambda i: abs(M[i][k]))
        if M[p][k] == 0:
            raise NoSolution("singular matrix")
        if p != k:
            M[k], M[p] = M[p], M[k]
        pivot_row = M[k]
        inv = ONE / pivot_row[k]
        for i in range(k + 1, n):
            row = M[i]
            f = row[k] * inv
            if f:
                for j in range(k + 1, n + m):
                    row[j] -= f * pivot_row[j]
            row[k] = ZERO
    X = [[ZERO] * m for _ in range(n)]
    for i in range(n - 1, -1, -1):
        row = M[i]
        for j in range(m):
            s = row[n + j]
            for k in range(i + 1, n):
                s -= row[k] * X[k][j]
            X[i][j] = s / row[i]
    return X


def inv(A: Matrix) -> Matrix:
    return solve(A, eye(len(A)))


def _pivots(A: Matrix, pivoting: bool):
    """The pivots of Gaussian elimination on A (rows swapped for the largest pivot when
    ``pivoting``), one at a time; a caller may stop early."""
    n = len(A)
    M = [list(r) for r in A]
    for k in range(n):
        if pivoting:
            p = max(range(k, n), key=lambda i: abs(M[i][k]))
            M[k], M[p] = M[p], M[k]
        yield M[k][k]
        if M[k][k] == 0:
            return
        inv_p = ONE / M[k][k]
        for i in range(k + 1, n):
            f = M[i][k] * inv_p
            if f:
                for j in range(k + 1, n):
                    M[i][j] -= f * M[k][j]


def det_abs_ln(A: Matrix) -> Decimal:
    """ln |det A| by the same elimination (for the sign iteration's scaling)."""
    total = ZERO
    for pivot in _pivots(A, pivoting=True):
        if pivot == 0:
            raise NoSolution("singular matrix")
        total += abs(pivot).ln()
    return total


def is_positive_definite(A: Matrix) -> bool:
    """Whether the symmetric A is positive definite (every pivot of its LDLᵀ is > 0)."""
    return all(pivot > 0 for pivot in _pivots(A, pivoting=False))


# ---- matrix functions --------------------------------------------------------------------------
def expm(M: Matrix) -> Matrix:
    """exp(M) by scaling and squaring with a Taylor series (see the module docstring)."""
    n = len(M)
    norm = norm1(M)
    s = 0
    eighth = Decimal("0.125")
    while norm > eighth:
        norm *= HALF
        s += 1
    X = scale(HALF ** s, M) if s else M
    E = eye(n)
    term = eye(n)
    k = 1
    while True:
        term = scale(ONE / k, matmul(term, X))
        E = add(E, term)
        if norm1(term) <= _TAYLOR_TOL * norm1(E):
            break
        k += 1
    for _ in range(s):
        E = matmul(E, E)
    return E


def van_loan(A: Matrix, B: Matrix, Q: Matrix, R: Matrix, T: Decimal):
    """(Ad, Bd, Qd, Rd, Nd): x_{k+1} = Ad xₖ + Bd uₖ for u held over [kT, (k+1)T), and
    ∫ over the period of xᵀQx + uᵀRu dt = xₖᵀQd xₖ + 2 xₖᵀNd uₖ + uₖᵀRd uₖ (Van Loan 1978).

    With F = [[A, B], [0, 0]] and W = diag(Q, R), exp([[−Fᵀ, W], [0, F]] T) =
    [[·, E12], [0, Φ]], Φ = exp(F T) = [[Ad, Bd], [0, I]], and Φᵀ E12 the cost matrix
    [[Qd, Nd], [Ndᵀ, Rd]] (symmetrised)."""
    n, m = len(B), len(B[0])
    F = block([[A, B], [zeros(m, n), zeros(m, m)]])
    W = block([[Q, zeros(n, m)], [zeros(m, n), R]])
    Ft = transpose(F)
    big = block([[scale(-T, Ft), scale(T, W)], [zeros(n + m, n + m), scale(T, F)]])
    E = expm(big)
    k = n + m
    phi = sub_block(E, k, 2 * k, k, 2 * k)
    cost = sym(matmul(transpose(phi), sub_block(E, 0, k, k, 2 * k)))
    return (sub_block(phi, 0, n, 0, n), sub_block(phi, 0, n, n, k), sub_block(cost, 0, n, 0, n),
            sub_block(cost, n, k, n, k), sub_block(cost, 0, n, n, k))


# ---- linear matrix equations (by their Kronecker form: n² unknowns, fine for small n) ----------
def _vec_solve(n: int, coef, rhs: Matrix) -> Matrix:
    """X (n × n) with Σ over the Kronecker form: row (i, j) of the system is
    coef(i, j) → dict {(k, l): value}; the right-hand side rhs[i][j]."""
    idx = {(i, j): i * n + j for i in range(n) for j in range(n)}
    S = [[ZERO] * (n * n) for _ in range(n * n)]
    for (i, j), r in idx.items():
        for kl, v in coef(i, j).items():
            S[r][idx[kl]] += v
    x = solve(S, [[rhs[i][j]] for i in range(n) for j in range(n)])
    return sym([[x[i * n + j][0] for j in range(n)] for i in range(n)])


def solve_stein(Acl: Matrix, C: Matrix) -> Matrix:
    """X = Aclᵀ X Acl + C (discrete Lyapunov), C symmetric."""
    n = len(Acl)

    def coef(i, j):
        # X_ij − Σ_kl Acl_ki Acl_lj X_kl
        c = {(i, j): ONE}
        for k in range(n):
            a = Acl[k][i]
            if a:
                for l in range(n):
                    b = Acl[l][j]
                    if b:
                        c[(k, l)] = c.get((k, l), ZERO) - a * b
        return c

    return _vec_solve(n, coef, C)


def solve_lyapunov(Acl: Matrix, C: Matrix) -> Matrix:
    """X with Aclᵀ X + X Acl + C = 0 (continuous Lyapunov), C symmetric."""
    n = len(Acl)

    def coef(i, j):
        # Σ_k Acl_ki X_kj + Σ_l X_il Acl_lj = −C_ij
        c = {}
        for k in range(n):
            if Acl[k][i]:
                c[(k, j)] = c.get((k, j), ZERO) + Acl[k][i]
            if Acl[k][j]:
                c[(i, k)] = c.get((i, k), ZERO) + Acl[k][j]
        return c

    return _vec_solve(n, coef, scale(-ONE, C))


def _rel(D: Matrix, X: Matrix) -> Decimal:
    nx = norm1(X)
    return norm1(D) / nx if nx else norm1(D)


# ---- Riccati equations -------------------------------------------------------------------------
def dare_gain(A, B, R, N, P) -> Matrix:
    """K = (R + BᵀPB)⁻¹ (BᵀPA + Nᵀ)."""
    Bt = transpose(B)
    BtP = matmul(Bt, P)
    return solve(add(R, matmul(BtP, B)), add(matmul(BtP, A), transpose(N)))


def dare_residual(A, B, Q, R, N, P) -> Matrix:
    """AᵀPA − P − (AᵀPB + N)(R + BᵀPB)⁻¹(BᵀPA + Nᵀ) + Q."""
    K = dare_gain(A, B, R, N, P)
    AtPB_N = add(matmul(matmul(transpose(A), P), B), N)
    return add(sub(sub(matmul(matmul(transpose(A), P), A), P), matmul(AtPB_N, K)), Q)


def solve_dare(A: Matrix, B: Matrix, Q: Matrix, R: Matrix, N: Matrix | None = None) -> tuple[Matrix, Matrix]:
    """(P, K): the stabilising solution of AᵀPA − P − (AᵀPB + N)(R + BᵀPB)⁻¹(BᵀPA + Nᵀ) + Q = 0
    and K = (R + BᵀPB)⁻¹(BᵀPA + Nᵀ) (u = −K x), as :func:`scipy.linalg.solve_discrete_are`
    with ``s=N``. Raises :class:`NoSolution` if there is none (or it was not found)."""
    n, m = len(B), len(B[0])
    N = zeros(n, m) if N is None else N
    Bt, Nt = transpose(B), transpose(N)
    # the cross term removed: Ā = A − B R⁻¹ Nᵀ, Q̄ = Q − N R⁻¹ Nᵀ, G = B R⁻¹ Bᵀ
    RiNt, RiBt = solve(R, Nt), solve(R, Bt)
    Ak = sub(A, matmul(B, RiNt))
    Hk = sym(sub(Q, matmul(N, RiNt)))
    Gk = sym(matmul(B, RiBt))
    I = eye(n)
    for _ in range(_MAX_DOUBLING):
        W = add(I, matmul(Gk, Hk))
        V = solve(W, [a + g for a, g in zip(Ak, Gk)])  # W⁻¹ [A_k, G_k] in one elimination
        V1, V2 = [row[:n] for row in V], [row[n:] for row in V]
        Akt = transpose(Ak)
        H_next = sym(add(Hk, matmul(matmul(Akt, Hk), V1)))
        Gk = sym(add(Gk, matmul(matmul(Ak, V2), Akt)))
        Ak = matmul(Ak, V1)
        done = _rel(sub(H_next, Hk), H_next) <= _SDA_TOL
        Hk = H_next
        if done:
            break
    else:
        raise NoSolution(f"the doubling iteration did not converge in {_MAX_DOUBLING} steps")
    # Newton's method (Hewer): P_{j+1} = Acl_jᵀ P_{j+1} Acl_j + Q − N K − Kᵀ Nᵀ + Kᵀ R K
    def hewer(P):
        K = dare_gain(A, B, R, N, P)
        Acl = sub(A, matmul(B, K))
        NK = matmul(N, K)
        return solve_stein(Acl, sym(add(sub(sub(Q, NK), transpose(NK)), matmul(matmul(transpose(K), R), K))))

    P = _newton(hewer, Hk)
    K = dare_gain(A, B, R, N, P)
    # stabilising: the closed loop's Stein equation with right-hand side I has a positive
    # definite solution exactly when every eigenvalue of Acl is inside the unit circle
    _check_solution(dare_residual(A, B, Q, R, N, P), P, solve_stein, sub(A, matmul(B, K)))
    return P, K


def _newton(step, P: Matrix) -> Matrix:
    """Iterate P ← step(P) until the update is below NEWTON_TOL relative (or raise)."""
    for _ in range(_MAX_NEWTON):
        P_next = step(P)
        done = _rel(sub(P_next, P), P_next) <= NEWTON_TOL
        P = P_next
        if done:
            return P
    raise NoSolution(f"Newton's method did not converge in {_MAX_NEWTON} steps")


def _check_solution(residual: Matrix, P: Matrix, lyapunov, Acl: Matrix) -> None:
    """Raise NoSolution unless ``residual`` is negligible against P and the closed loop Acl
    is stable: its Lyapunov (or Stein) equation ``lyapunov(Acl, I)`` has a positive definite
    solution."""
    if _rel(residual, P) > NEWTON_TOL:
        raise NoSolution("the solution found does not solve the equation")
    try:
        X = lyapunov(Acl, eye(len(Acl)))
    except NoSolution:
        X = None
    if X is None or not is_positive_definite(X):
        raise NoSolution("the closed loop of the solution found is not stable")


def care_residual(A, B, Q, R, P) -> Matrix:
    """AᵀP + PA − PB R⁻¹ BᵀP + Q."""
    PB = matmul(P, B)
    return add(sub(add(matmul(transpose(A), P), matmul(P, A)), matmul(PB, solve(R, transpose(PB)))), Q)


def solve_care(A: Matrix, B: Matrix, Q: Matrix, R: Matrix) -> tuple[Matrix, Matrix]:
    """(P, K): the stabilising solution of AᵀP + PA − PBR⁻¹BᵀP + Q = 0 and K = R⁻¹BᵀP,
    as :func:`scipy.linalg.solve_continuous_are`. Raises :class:`NoSolution` if there is none."""
    n = len(A)
    Bt = transpose(B)
    G = sym(matmul(B, solve(R, Bt)))
    # sign of the Hamiltonian [[A, −G], [−Q, −Aᵀ]] by Newton's iteration, determinant-scaled
    # while far from convergence (Byers 1987)
    Z = block([[A, scale(-ONE, G)], [scale(-ONE, Q), scale(-ONE, transpose(A))]])
    two_n = Decimal(2 * n)
    scaled = True
    for _ in range(_MAX_SIGN):
        if scaled:
            c = (-det_abs_ln(Z) / two_n).exp()
            cZ = scale(c, Z)
        else:
            cZ = Z
        Z_next = scale(HALF, add(cZ, inv(cZ)))
        change = _rel(sub(Z_next, Z), Z_next)
        Z = Z_next
        if change <= _SIGN_TOL:
            break
        scaled = scaled and change > Decimal("1e-2")
    else:
        raise NoSolution(f"the sign iteration did not converge in {_MAX_SIGN} steps")
    # (sign(H) + I) [I; P] = 0: [Z12; Z22 + I] P = −[Z11 + I; Z21], by the normal equations
    I = eye(n)
    M = block([[sub_block(Z, 0, n, n, 2 * n)], [add(sub_block(Z, n, 2 * n, n, 2 * n), I)]])
    rhs = block([[add(sub_block(Z, 0, n, 0, n), I)], [sub_block(Z, n, 2 * n, 0, n)]])
    Mt = transpose(M)
    P = sym(scale(-ONE, solve(matmul(Mt, M), matmul(Mt, rhs))))
    # Newton's method (Kleinman): Acl_jᵀ P_{j+1} + P_{j+1} Acl_j + Q + K_jᵀ R K_j = 0
    def kleinman(P):
        K = solve(R, matmul(Bt, P))
        Acl = sub(A, matmul(B, K))
        return solve_lyapunov(Acl, sym(add(Q, matmul(matmul(transpose(K), R), K))))

    P = _newton(kleinman, P)
    K = solve(R, matmul(Bt, P))
    _check_solution(care_residual(A, B, Q, R, P), P, solve_lyapunov, sub(A, matmul(B, K)))
    return P, K


__all__ = ["DIGITS", "NEWTON_TOL", "NoSolution", "care_residual", "context", "dare_gain", "dare_residual", "dec",
           "expm", "solve", "solve_care", "solve_dare", "solve_lyapunov", "solve_stein", "to_float", "van_loan"]
