"""Small matrix products and solves whose every rounding is fixed by this code, not by the
CPU: the estimator's Python code (the pure-Python EKF path, and the coasting steps and the
latency watch of both paths) uses them instead of ``@``/``np.dot``/``np.linalg``.

Why (issue 25): ``A @ B``, ``np.dot`` and ``np.linalg.solve``/``inv`` call the BLAS/LAPACK
numpy bundles (OpenBLAS), which picks a kernel per CPU at load time; kernels block,
vectorise and fuse multiply-adds differently, so the last bits of a 12 × 12 product
differed between ``OPENBLAS_CORETYPE`` values (measured), and a filter in a closed loop
carries such a difference into the trajectory.

What instead, and why it is the same everywhere:

* :func:`mm`, :func:`mv`: every entry Σₖ aᵢₖ bₖⱼ is the products (each rounded once, an
  elementwise IEEE multiply) added one at a time in ascending k. Built as one elementwise
  product array of shape (K, n, m) in C order and ``np.add.reduce`` over its first (slowest)
  axis: numpy reduces a non-inner axis by adding whole (n, m) slices in turn, each an
  elementwise IEEE add, so SIMD width only changes how many independent entries are added
  at once, never the order of any one sum. (numpy's pairwise summation applies only when
  the reduced axis is the innermost one: the cases where it could be, outputs of one
  element, are summed here in Python.) tests/test_cpu_independence.py checks the results
  against a plain Python loop bit for bit.
* :func:`dot`, :func:`affine`: the same, for a vector (``affine`` starts each sum from
  its constant, as the compiled kernel's ``s = off; s += h[k] * x[k]`` does).
* :func:`solve`: Gaussian elimination with partial pivoting in Python floats (one IEEE
  operation per step; CPython never fuses a multiply and an add); :func:`inv` and
  :func:`quad_inv` of the 1 × 1 and 2 × 2 innovation covariances by the kernel's explicit
  formulas (adjugate over determinant).

Ascending-index sums are also the compiled kernel's order (estimation/_ekf.c loops
``for k: s += a[k] * b[k]``), so where the pure-Python path mirrors the kernel's
association too (the encoder update, :class:`estimation.twin_ekf.TwinEKF`), the two paths
agree more closely than they did with BLAS (θ0 = 0.2 rad, gyro/encoder spikes and
dropouts: final state 5e-12 apart instead of 1e-10); they still differ where the
Python path is vectorised differently (the strapdown step), to ~1e-13 per step.

Each costs a few µs on the filter's 12 × 12 (16 × 16 while coasting) matrices against
about 1 µs for BLAS. The compiled kernel (``estimation._ekf``) does its own arithmetic in
C, in a fixed order, built without FMA contraction.
"""
from __future__ import annotations

import math

import numpy as np


def _f64(a) -> np.ndarray:
    return a if type(a) is np.ndarray and a.dtype == np.float64 else np.asarray(a, dtype=np.float64)


def mm(A, B) -> np.ndarray:
    """A @ B for 2-d A (n, K), B (K, m), each entry summed in ascending K (see the module docstring)."""
    A, B = _f64(A), _f64(B)
    n, K = A.shape
    if B.shape[0] != K:
        raise ValueError(f"mm: shapes {A.shape} and {B.shape} do not fit")
    m = B.shape[1]
    if K == 0:
        return np.zeros((n, m))
    if n * m == 1:
        # one entry: a 1-d reduction would be pairwise; accumulate is sequential by definition
        return np.add.accumulate(A[0] * B[:, 0])[-1:].reshape(1, 1)
    # (K, n, m) in C order: the reduced axis is the slowest, so each entry's sum runs over K in turn
    return np.add.reduce(np.multiply(A.T[:, :, None], B[:, None, :], order="C"), axis=0)


def mv(A, x) -> np.ndarray:
    """A @ x for 2-d A (n, K) and 1-d x (K,), each entry summed in ascending K."""
    x = np.asarray(x, dtype=float)
    return mm(A, x[:, None])[:, 0]


def vm(x, A) -> np.ndarray:
    """x @ A for 1-d x (K,) and 2-d A (K, m), each entry summed in ascending K."""
    x = np.asarray(x, dtype=float)
    return mm(x[None, :], A)[0]


def dot(x, y) -> float:
    """x · y for 1-d x, y: the products added one at a time in ascending index (as a C loop
    ``s = 0; s += x[k] * y[k]``)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    return float(mm(x[None, :], y[:, None])[0, 0]) if len(x) else 0.0


def affine(c, A, x) -> np.ndarray:
    """c + A @ x for 1-d c (n,), 2-d A (n, K), 1-d x (K,), each entry summed from cᵢ on in
    ascending K (as a C loop ``s = c[i]; s += A[i][k] * x[k]``)."""
    c, A, x = _f64(c), _f64(A), _f64(x)
    n, K = A.shape
    W = np.empty((K + 1, n))
    W[0] = c
    np.multiply(A.T, x[:, None], out=W[1:])
    if n == 1:  # a 1-d reduction would be pairwise; accumulate is sequential by definition
        return np.add.accumulate(W[:, 0])[-1:]
    return np.add.reduce(W, axis=0)  # C order, the summed axis the slowest: in turn


def rowsums(A) -> np.ndarray:
    """Σⱼ aᵢⱼ of each row of a 2-d A, added one at a time in ascending j."""
    A = _f64(A)
    if A.shape[0] == 1:  # a 1-d reduction would be pairwise; accumulate is sequential by definition
        return np.add.accumulate(A[0])[-1:] if A.shape[1] else np.zeros(1)
    # (m, n) in C order: the summed axis is the slowest, so each row's sum runs over j in turn
    return np.add.reduce(np.ascontiguousarray(A.T), axis=0) if A.shape[1] else np.zeros(A.shape[0])


def mm3(A, B, C) -> np.ndarray:
    """(A @ B) @ C, each product as :func:`mm`."""
    return mm(mm(A, B), C)


def solve(A, B) -> np.ndarray:
    """X with A X = B for a small square A (n, n) and B (n,) or (n, m): Gaussian elimination
    with partial pivoting (the first largest |pivot| on ties) in Python floats. Raises
    ``np.linalg.LinAlgError`` (as numpy does) if A is singular."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n = A.shape[0]
    if A.shape != (n, n) or B.shape[0] != n:
        raise ValueError(f"solve: shapes {A.shape} and {B.shape} do not fit")
    vec = B.ndim == 1
    M = [ra + rb for ra, rb in zip(A.tolist(), (B[:, None] if vec else B).tolist())]
    w = len(M[0])
    for k in range(n):
        p = max(range(k, n), key=lambda i: abs(M[i][k]))
        if M[p][k] == 0.0 or M[p][k] != M[p][k]:
            raise np.linalg.LinAlgError("Singular matrix")
        if p != k:
            M[k], M[p] = M[p], M[k]
        pr = M[k]
        for i in range(k + 1, n):
            row = M[i]
            f = row[k] / pr[k]
            if f != 0.0:
                for j in range(k + 1, w):
                    row[j] -= f * pr[j]
    X = [[0.0] * (w - n) for _ in range(n)]
    for i in range(n - 1, -1, -1):
        row = M[i]
        for j in range(w - n):
            s = row[n + j]
            for k in range(i + 1, n):
                s -= row[k] * X[k][j]
            X[i][j] = s / row[i]
    out = np.array(X, dtype=float)
    return out[:, 0] if vec else out


def inv(A) -> np.ndarray:
    """A⁻¹ of a small square A: 1 × 1 and 2 × 2 by the explicit formula (adjugate over the
    determinant, as the compiled kernel), larger ones as :func:`solve` with the identity."""
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    if A.shape == (1, 1):
        return np.array([[1.0 / float(A[0, 0])]])
    if A.shape == (2, 2):
        (a, b), (c, d) = A.tolist()
        det = a * d - b * c
        if det == 0.0:
            raise np.linalg.LinAlgError("Singular matrix")
        return np.array([[d / det, -b / det], [-c / det, a / det]])
    return solve(A, np.eye(n))


def quad_inv(y, S) -> float:
    """yᵀ S⁻¹ y for a 1- or 2-vector y and symmetric S (the normalised innovation squared), by
    the compiled kernel's explicit formula; larger ones by :func:`solve`."""
    y = [float(v) for v in np.ravel(y)]
    S = np.asarray(S, dtype=float)
    if len(y) == 1:
        return y[0] * y[0] / float(S[0, 0])
    if len(y) == 2:
        (a, b), (c, d) = S.tolist()
        det = a * d - b * c
        return (y[0] * (d * y[0] - b * y[1]) + y[1] * (-c * y[0] + a * y[1])) / det
    return dot(y, solve(S, np.array(y)))


def quad_inv_rows(P, e) -> np.ndarray:
    """eᵢᵀ Pᵢ⁻¹ eᵢ (m,) for a stack of symmetric positive definite Pᵢ (m, n, n) (covariances)
    and eᵢ (m, n), vectorised over the stack.

    Gaussian elimination without pivoting, which is backward stable for a symmetric positive
    definite matrix (its growth factor is at most 1; Golub and Van Loan, *Matrix
    Computations*, 4th ed., §4.2), on [Pᵢ | eᵢ]: it factors Pᵢ = L D Lᵀ and leaves y = L⁻¹ eᵢ
    in the last column, so eᵢᵀ Pᵢ⁻¹ eᵢ = Σₖ yₖ² / dₖ, summed in ascending k (no
    back-substitution). Agrees with ``e @ np.linalg.solve(P, e)`` to ~1e-12 relative on the
    EKF's covariances (condition numbers up to ~1e12).

    Every operation is an elementwise IEEE one on the whole stack (numpy's elementwise
    multiply, subtract and divide round each result once and do not fuse), so a row's value
    depends on that row alone: the same bits on every CPU, and whether the row is computed
    with others or alone (so the streaming NEES of
    :class:`estimation.consistency.RunningConsistency` and the batch
    :func:`estimation.consistency.nees` agree to the bit). A zero pivot gives a non-finite
    value for its row (no error)."""
    P = np.asarray(P, dtype=float)
    e = np.asarray(e, dtype=float)
    m, n = e.shape
    if P.shape != (m, n, n):
        raise ValueError(f"quad_inv_rows: shapes {P.shape} and {e.shape} do not fit")
    if m == 0 or n == 0:
        return np.zeros(m)
    # rows, columns, stack: every operation below runs over contiguous stacks
    W = np.empty((n, n + 1, m))
    W[:, :n, :] = P.transpose(1, 2, 0)
    W[:, n, :] = e.T
    with np.errstate(all="ignore"):
        for k in range(n - 1):
            f = W[k + 1:, k, :] / W[k, k, :]
            W[k + 1:, k + 1:, :] -= f[:, None, :] * W[k, None, k + 1:, :]
        y = W[:, n, :]
        d = W[np.arange(n), np.arange(n), :]
        out = y[0] * y[0] / d[0]
        for k in range(1, n):
            out = out + y[k] * y[k] / d[k]
    return out


def positive_definite(P) -> bool:
    """True if the symmetric P (n, n) is positive definite: every pivot of its LDLᵀ elimination
    (without pivoting, as :func:`quad_inv_rows`) is positive and finite.

    A covariance can lose definiteness to rounding alone once its condition number nears
    1/ε ≈ 1e16 (a diverging filter's reaches 1e29), though every update is in Joseph form and
    symmetrised; the diagonal can stay positive meanwhile, so checking it is not enough. The
    eliminations are elementwise IEEE operations in the order of the compiled kernel's
    ``positive_definite`` (estimation/_ekf.c): the same verdict, bit for bit, on either core."""
    W = np.array(P, dtype=float)
    n = W.shape[0]
    with np.errstate(all="ignore"):
        for k in range(n):
            d = W[k, k]
            if not (d > 0.0 and d < math.inf):
                return False
            if k + 1 < n:
                f = W[k + 1:, k] / d
                W[k + 1:, k + 1:] -= f[:, None] * W[k, None, k + 1:]
    return True


__all__ = ["affine", "dot", "inv", "mm", "mm3", "mv", "positive_definite", "quad_inv", "quad_inv_rows", "rowsums",
           "solve", "vm"]
