"""Type reduction and defuzzification of rule firing intervals.

Every function takes firing strengths of shape (..., R) (R rules, any leading batch
shape) and the rules' consequent points ``y`` of shape (R,), and returns one crisp
output per batch element, shape (...).

* :func:`bmm` — Begian–Melek–Mendel: y = m·Σf̲y/Σf̲ + n·Σf̄y/Σf̄ (the paper's choice).
* :func:`nie_tan` — Nie–Tan: y = Σ(f̲+f̄)y / Σ(f̲+f̄).
* :func:`karnik_mendel` — the exact centre-of-sets interval [y_l, y_r] (what KM and
  EKM iterate towards), found by evaluating every switch point at once; its midpoint is
  the defuzzified output.
* :func:`weighted_average` — type-1 height defuzzification Σfy/Σf.

Where no lower firing is positive, BMM falls back to the upper term alone (the
partitions built by :func:`twin.fuzzy.sets.uniform_partition` never get there).
"""
from __future__ import annotations

import warnings

import numpy as np


def _dot(f, y):
    # einsum, not f @ y: a multi-threaded BLAS matrix-vector product is ~20x slower
    # on the (10^4, 49) arrays of a batch than this single-threaded reduction.
    return np.einsum("...r,r->...", f, y)


def weighted_average(f, y):
    f = np.asarray(f, dtype=float)
    return _dot(f, np.asarray(y, dtype=float)) / f.sum(axis=-1)


def bmm(f_lower, f_upper, y, m: float = 0.5, n: float = 0.5):
    f_lower = np.asarray(f_lower, dtype=float)
    f_upper = np.asarray(f_upper, dtype=float)
    y = np.asarray(y, dtype=float)
    s_lo = f_lower.sum(axis=-1)
    s_up = f_upper.sum(axis=-1)
    upper_term = _dot(f_upper, y) / s_up
    with np.errstate(invalid="ignore", divide="ignore"):
        lower_term = _dot(f_lower, y) / s_lo
    return np.where(s_lo > 0, m * lower_term + n * upper_term, (m + n) * upper_term)


def nie_tan(f_lower, f_upper, y):
    f = np.asarray(f_lower, dtype=float) + np.asarray(f_upper, dtype=float)
    return _dot(f, np.asarray(y, dtype=float)) / f.sum(axis=-1)


def karnik_mendel(f_lower, f_upper, y_left, y_right=None):
    """Exact centre-of-sets type-reduced interval (y_l, y_r), each of shape (...).

    ``y_left``/``y_right`` are the consequents' centroid bounds (equal for point
    consequents). y_l is the minimum over switch points k of
    (Σ_{i≤k} f̄_i y_i + Σ_{i>k} f̲_i y_i) / (Σ_{i≤k} f̄_i + Σ_{i>k} f̲_i) with y sorted
    ascending, and y_r the maximum of the mirror expression; enumerating every k gives
    the same optimum as the KM/EKM iterations, without iterating.
    """
    f_lower = np.asarray(f_lower, dtype=float)
    f_upper = np.asarray(f_upper, dtype=float)
    y_left = np.asarray(y_left, dtype=float)
    y_right = y_left if y_right is None else np.asarray(y_right, dtype=float)
    return (
        _switch_extreme(f_lower, f_upper, y_left, lower_end=True),
        _switch_extreme(f_lower, f_upper, y_right, lower_end=False),
    )


def _switch_extreme(f_lo, f_up, y, lower_end: bool):
    order = np.argsort(y, kind="stable")
    y = y[order]
    f_lo = f_lo[..., order]
    f_up = f_up[..., order]
    # to make y_l small, take upper firing for the small y (the first k+1 rules)
    first, rest = (f_up, f_lo) if lower_end else (f_lo, f_up)
    cum_first_w = np.cumsum(first, axis=-1)
    cum_first_wy = np.cumsum(first * y, axis=-1)
    tot_rest_w = rest.sum(axis=-1, keepdims=True)
    tot_rest_wy = (rest * y).sum(axis=-1, keepdims=True)
    cum_rest_w = np.cumsum(rest, axis=-1)
    cum_rest_wy = np.cumsum(rest * y, axis=-1)
    # switch after position k: rules 0..k use `first`, rules k+1.. use `rest`
    num = cum_first_wy + (tot_rest_wy - cum_rest_wy)
    den = cum_first_w + (tot_rest_w - cum_rest_w)
    # also the case "all rules use rest" (switch before the first rule)
    num = np.concatenate([tot_rest_wy, num], axis=-1)
    den = np.concatenate([tot_rest_w, den], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN where no rule fires: NaN out, caller raises
        ratios = np.where(den > 0, num / den, np.nan)
        return np.nanmin(ratios, axis=-1) if lower_end else np.nanmax(ratios, axis=-1)
