"""Type-1 and interval type-2 fuzzy sets: triangles and shoulders, and uniform partitions.

A type-1 triangle is given by its feet and peak; a left shoulder has ``left = -inf``
(membership 1 for every x ≤ peak), a right shoulder ``right = +inf``. An IT2 set is a
pair (lower, upper) of such sets with lower ≤ upper everywhere: the region between
them is the footprint of uncertainty (FOU).

Memberships are computed as ``height * clip(min(1 + (x − peak)/(peak − left),
1 + (peak − x)/(right − peak)), 0, 1)``, with the infinite feet of shoulders giving a
slope of zero, so no inf/inf arises.
"""
from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from dataclasses import dataclass

import numpy as np

from twin.errors import TwinError

LINGUISTIC_7 = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")


@dataclass(frozen=True)
class Triangle:
    """A type-1 triangular (or shoulder) membership function.

    ``left < peak < right``; ``left = -inf`` makes a left shoulder, ``right = +inf`` a
    right shoulder; ``height`` in (0, 1].
    """

    left: float
    peak: float
    right: float
    height: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.peak) and self.left < self.peak < self.right):
            raise TwinError(f"a triangle needs left < peak < right with a finite peak, got {self.left}, {self.peak}, {self.right}")
        if math.isnan(self.left) or math.isnan(self.right):
            raise TwinError("triangle feet must not be NaN")
        if not (0.0 < self.height <= 1.0):
            raise TwinError(f"membership height must be in (0, 1], got {self.height}")

    @property
    def slopes(self) -> tuple[float, float]:
        """(1/(peak − left), 1/(right − peak)); zero on a shoulder side."""
        inv_l = 0.0 if math.isinf(self.left) else 1.0 / (self.peak - self.left)
        inv_r = 0.0 if math.isinf(self.right) else 1.0 / (self.right - self.peak)
        return inv_l, inv_r

    def __call__(self, x):
        inv_l, inv_r = self.slopes
        x = np.asarray(x, dtype=float)
        v = np.minimum(1.0 + (x - self.peak) * inv_l, 1.0 + (self.peak - x) * inv_r)
        return self.height * np.clip(v, 0.0, 1.0)

    def contains(self, other: "Triangle") -> bool:
        """True if ``other`` ≤ ``self`` everywhere (other's support inside, peak-compatible)."""
        grid = np.linspace(min(self.peak, other.peak) - 3, max(self.peak, other.peak) + 3, 2001)
        finite = [v for v in (self.left, self.right, other.left, other.right) if math.isfinite(v)]
        # the corners added to the grid (order and repeats do not matter to the test below;
        # np.union1d would import numpy.ma, 20 ms of every command's start-up)
        grid = np.concatenate([grid, finite, [self.peak, other.peak]])
        return bool(np.all(other(grid) <= self(grid) + 1e-12))


@dataclass(frozen=True)
class IT2Set:
    """An interval type-2 set: lower ≤ upper membership functions."""

    name: str
    lower: Triangle
    upper: Triangle

    def __post_init__(self) -> None:
        if not self.upper.contains(self.lower):
            raise TwinError(f"IT2 set {self.name}: the lower membership function must lie under the upper one")

    @property
    def centre(self) -> float:
        return self.upper.peak

    def __call__(self, x):
        """(lower, upper) memberships of ``x``."""
        return self.lower(x), self.upper(x)


class Partition:
    """An ordered family of IT2 sets over one normalised variable, evaluated together.

    The membership arrays are kept as parameter vectors so that evaluation is one
    vectorised expression for arrays and a short loop over floats for scalars.
    """

    def __init__(self, sets: list[IT2Set]):
        if len(sets) < 2:
            raise TwinError("a partition needs at least two sets")
        self.sets = tuple(sets)
        self.names = tuple(s.name for s in sets)
        rows = []
        for s in sets:
            lo_l, lo_r = s.lower.slopes
            up_l, up_r = s.upper.slopes
            rows.append((s.lower.peak, lo_l, lo_r, s.lower.height, s.upper.peak, up_l, up_r, s.upper.height))
        p = np.array(rows, dtype=float)
        self._lo = (p[:, 0], p[:, 1], p[:, 2], p[:, 3])
        self._up = (p[:, 4], p[:, 5], p[:, 6], p[:, 7])
        self.is_type1 = all(s.lower == s.upper for s in sets)
        # Scalar path: flat lists (left feet, right feet, peaks, slopes, heights). The sets
        # are ordered, so those with non-zero membership at x form a contiguous run
        # (between the open supports) found by bisection.
        self.scalar_lower = _feet([s.lower for s in sets]) + tuple([float(v) for v in col] for col in self._lo)
        self.scalar_upper = _feet([s.upper for s in sets]) + tuple([float(v) for v in col] for col in self._up)
        # for the compiled kernel: K rows of (peak, 1/(peak-left), 1/(right-peak), height)
        self.kernel_lower = np.ascontiguousarray(p[:, 0:4]).tobytes()
        self.kernel_upper = np.ascontiguousarray(p[:, 4:8]).tobytes()

    def __len__(self) -> int:
        return len(self.sets)

    @staticmethod
    def _eval(params, x):
        peak, inv_l, inv_r, height = params
        d = x[..., None] - peak
        v = np.minimum(1.0 + d * inv_l, 1.0 - d * inv_r)
        return height * np.clip(v, 0.0, 1.0)

    def memberships(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper memberships, each of shape ``x.shape + (K,)``."""
        x = np.asarray(x, dtype=float)
        return self._eval(self._lo, x), self._eval(self._up, x)

    def memberships_scalar(self, x: float) -> tuple[list[float], list[float]]:
        """All K lower and upper memberships of one float, as two lists (no numpy)."""
        n = len(self.sets)
        return _active_run(x, 0, n, *self.scalar_lower[2:]), _active_run(x, 0, n, *self.scalar_upper[2:])

    def active(self, x: float) -> tuple[int, list[float], int, list[float]]:
        """(i0, upper memberships, j0, lower memberships): the contiguous runs of sets
        whose upper / lower MF is > 0 at x, starting at indices i0 / j0."""
        left, right, pk, il, ir, h = self.scalar_upper
        i0 = bisect_right(right, x)
        up = _active_run(x, i0, bisect_left(left, x), pk, il, ir, h)
        left, right, pk, il, ir, h = self.scalar_lower
        j0 = bisect_right(right, x)
        return i0, up, j0, _active_run(x, j0, bisect_left(left, x), pk, il, ir, h)


def _active_run(x: float, i0: int, i1: int, pk, il, ir, h) -> list[float]:
    """Memberships of sets i0..i1−1 at x. The min of the rising and falling lines is <= 1
    by construction, so only the clip at 0 is needed."""
    out = []
    for k in range(i0, i1):
        d = x - pk[k]
        v = 1.0 + d * il[k]
        w = 1.0 - d * ir[k]
        if w < v:
            v = w
        out.append(h[k] * v if v > 0.0 else 0.0)
    return out


def _feet(tris: list[Triangle]) -> tuple[list[float], list[float]]:
    left = [t.left for t in tris]
    right = [t.right for t in tris]
    if left != sorted(left) or right != sorted(right):
        raise TwinError("the sets of a partition must be ordered from left to right (feet increasing)")
    return left, right


def uniform_partition(n_sets: int = 7, fou: float = 0.0, names=None) -> Partition:
    """``n_sets`` IT2 sets with evenly spaced centres over the normalised range [−1, 1].

    The outer sets are shoulders (membership 1 beyond ±1, so inputs outside the range
    saturate instead of extrapolating). With spacing h = 2/(n_sets − 1), each upper
    membership function has half-width h(1 + fou) and each lower one h(1 − fou), both
    of height 1: ``fou = 0`` gives the type-1 partition of unity. ``fou`` must lie in
    [0, 0.5): beyond that the lower functions no longer overlap and some inputs fire no
    rule's lower bound.
    """
    if not isinstance(n_sets, int) or n_sets < 2 or n_sets % 2 == 0:
        raise TwinError(f"a uniform partition needs an odd number of sets >= 3, got {n_sets!r}")
    try:
        fou = float(fou)
    except (TypeError, ValueError):
        raise TwinError(f"fou (footprint of uncertainty) must be a number in [0, 0.5), got {fou!r}") from None
    if not (0.0 <= fou < 0.5):
        raise TwinError(f"fou (footprint of uncertainty) must be in [0, 0.5), got {fou:g}")
    if names is None:
        names = LINGUISTIC_7 if n_sets == 7 else tuple(f"S{k}" for k in range(n_sets))
    half = (n_sets - 1) // 2
    h = 1.0 / half
    sets = []
    for k in range(-half, half + 1):
        c = k / half
        def tri(w: float) -> Triangle:
            return Triangle(-math.inf if k == -half else c - w, c, math.inf if k == half else c + w)
        sets.append(IT2Set(names[k + half], lower=tri(h * (1.0 - fou)), upper=tri(h * (1.0 + fou))))
    return Partition(sets)
