"""Two-input IT2 (and type-1) Mamdani fuzzy logic systems on normalised inputs.

Rule (i, j): if x1 is A_i and x2 is B_j then y is C_{table[i, j]}. The firing interval
of a rule is [min(μ̲_Ai, μ̲_Bj), min(μ̄_Ai, μ̄_Bj)] (minimum t-norm). The consequents
enter type reduction through their centres (the paper's BMM formula); KM uses the
same centres as point consequents, so the three reducers are compared like for like.

A partition with zero footprint makes every firing interval a point, and then BMM,
Nie–Tan and KM all reduce to the type-1 weighted average Σ f y / Σ f.
"""
from __future__ import annotations

import math
import os

import numpy as np

from twin.errors import TwinError
from twin.fuzzy import type_reduction as tr
from twin.fuzzy.sets import Partition

try:  # the optional compiled kernel (setup.py); TWIN_PURE_PYTHON=1 turns it off
    from twin.fuzzy import _kernel
except ImportError:  # pragma: no cover - depends on the build
    _kernel = None
if os.environ.get("TWIN_PURE_PYTHON", "") not in ("", "0"):
    _kernel = None


def compiled_kernel_loaded() -> bool:
    """True if the Mamdani FLS runs in its compiled kernel in this process."""
    return _kernel is not None

TYPE_REDUCERS = ("bmm", "nt", "km")


class MamdaniFLS:
    """A two-input, one-output Mamdani FLS.

    Parameters
    ----------
    input1, input2 : Partition
        Sets of the two (normalised) inputs; rows and columns of the rule table.
    output_centres : array_like, shape (K,)
        Centres of the consequent sets, normalised.
    rule_table : array_like of int, shape (len(input1), len(input2))
        Index into ``output_centres`` for each rule.
    type_reduction : {"bmm", "nt", "km"}
        Begian–Melek–Mendel (with weights ``m``, ``n``), Nie–Tan, or exact Karnik–Mendel
        centre of sets (midpoint of [y_l, y_r]).
    m, n : float
        BMM weights of the lower and upper terms; m + n = 1 keeps the output a convex
        combination of the consequent centres.
    compiled : bool
        Use the compiled kernel (``twin.fuzzy._kernel``) for BMM and Nie–Tan when it is
        built; it performs the pure-Python path's arithmetic in the same order, so the
        results are identical. False forces pure Python/numpy.
    """

    def __init__(self, input1: Partition, input2: Partition, output_centres, rule_table,
                 type_reduction: str = "bmm", m: float = 0.5, n: float = 0.5, compiled: bool = True):
        if type_reduction not in TYPE_REDUCERS:
            raise TwinError(f"type reduction must be one of {', '.join(TYPE_REDUCERS)}, got {type_reduction!r}")
        table = np.asarray(rule_table)
        if table.shape != (len(input1), len(input2)):
            raise TwinError(f"rule table must have shape ({len(input1)}, {len(input2)}), got {table.shape}")
        centres = np.asarray(output_centres, dtype=float)
        if not np.issubdtype(table.dtype, np.integer) or table.min() < 0 or table.max() >= len(centres):
            raise TwinError(f"rule table entries must be integer indices of the {len(centres)} output sets")
        for name, v in (("m", m), ("n", n)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise TwinError(f"BMM weight {name} must be a finite number >= 0, got {v!r}")
        if m + n <= 0:
            raise TwinError("BMM weights m and n must not both be zero")
        self.input1, self.input2 = input1, input2
        self.output_centres = centres
        self.rule_table = table
        self.type_reduction = type_reduction
        self.m, self.n = float(m), float(n)
        self.y = centres[table].ravel()  # consequent centre per rule, row-major (i, j)
        self._y_py = [[float(v) for v in row] for row in centres[table]]
        self._kernel = None
        if compiled and _kernel is not None and type_reduction != "km" and max(len(input1), len(input2)) <= 64:
            self._kernel = _kernel.make(input1.kernel_lower, input1.kernel_upper, input2.kernel_lower,
                                        input2.kernel_upper, np.ascontiguousarray(self.y).tobytes(),
                                        0 if type_reduction == "bmm" else 1, self.m, self.n)

    @property
    def compiled(self) -> bool:
        """True if evaluations run in the compiled kernel."""
        return self._kernel is not None

    # -- vectorised ---------------------------------------------------------------
    def firing(self, x1, x2) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper firing strengths, shape ``broadcast(x1, x2).shape + (K1*K2,)``."""
        x1, x2 = np.broadcast_arrays(np.asarray(x1, dtype=float), np.asarray(x2, dtype=float))
        lo1, up1 = self.input1.memberships(x1)
        lo2, up2 = self.input2.memberships(x2)
        shape = x1.shape + (-1,)
        f_lo = np.minimum(lo1[..., :, None], lo2[..., None, :]).reshape(shape)
        f_up = np.minimum(up1[..., :, None], up2[..., None, :]).reshape(shape)
        return f_lo, f_up

    def evaluate(self, x1, x2) -> np.ndarray:
        """Crisp outputs for arrays of normalised inputs (broadcast together)."""
        require_finite(x1, x2)
        try:
            a, b = np.broadcast_arrays(np.asarray(x1, dtype=float), np.asarray(x2, dtype=float))
        except ValueError:
            raise TwinError(f"fuzzy system inputs must have shapes that broadcast together, got "
                            f"{np.shape(x1)} and {np.shape(x2)}") from None
        if self._kernel is not None:
            out = np.empty(a.shape)
            _kernel.evaluate_many(self._kernel, np.ascontiguousarray(a.ravel()), np.ascontiguousarray(b.ravel()),
                                  out.reshape(-1))
        else:
            with np.errstate(invalid="ignore", divide="ignore"):
                out = self._reduce(*self.firing(a, b))
        if not np.all(np.isfinite(out)):
            bad = np.argwhere(~np.isfinite(np.asarray(out)).reshape(a.shape))[0] if a.ndim else ()
            raise TwinError(_no_rule_fires(a[tuple(bad)], b[tuple(bad)]))
        return out

    def _reduce(self, f_lo, f_up):
        if self.type_reduction == "bmm":
            return tr.bmm(f_lo, f_up, self.y, self.m, self.n)
        if self.type_reduction == "nt":
            return tr.nie_tan(f_lo, f_up, self.y)
        y_l, y_r = tr.karnik_mendel(f_lo, f_up, self.y)
        return 0.5 * (y_l + y_r)

    def interval(self, x1, x2) -> tuple[np.ndarray, np.ndarray]:
        """The exact KM type-reduced interval [y_l, y_r] (whatever the configured reducer)."""
        require_finite(x1, x2)
        return tr.karnik_mendel(*self.firing(x1, x2), self.y)

    # -- scalar fast path -------------------------------------------------------
    def evaluate_scalar(self, x1: float, x2: float) -> float:
        """One crisp output for two floats, without numpy (a control loop's call).

        Only the rules whose firing is non-zero are visited: the upper sums over the
        (at most 3×3) upper-active sets, the lower sums over the lower-active ones.
        """
        if not (math.isfinite(x1) and math.isfinite(x2)):
            raise TwinError(f"fuzzy system inputs must be finite numbers, got ({x1}, {x2})")
        if self._kernel is not None:
            y = _kernel.evaluate(self._kernel, x1, x2)
            if y != y:  # NaN: no rule fired (a partition with gaps)
                raise TwinError(_no_rule_fires(x1, x2))
            return y
        if self.type_reduction == "km":
            return float(self.evaluate(x1, x2))
        i0, a_up, k0, a_lo = self.input1.active(x1)
        j0, b_up, l0, b_lo = self.input2.active(x2)
        s_up, w_up = _min_firing_sums(a_up, i0, b_up, j0, self._y_py)
        if s_up <= 0.0:
            raise TwinError(_no_rule_fires(x1, x2))
        s_lo, w_lo = _min_firing_sums(a_lo, k0, b_lo, l0, self._y_py)
        if self.type_reduction == "nt":
            return (w_lo + w_up) / (s_lo + s_up)
        if s_lo > 0.0:
            return self.m * w_lo / s_lo + self.n * w_up / s_up
        return (self.m + self.n) * w_up / s_up

    __call__ = evaluate

    def surface(self, n1: int = 101, n2: int = 101):
        """Control surface over the normalised square: (grid1 (n1,), grid2 (n2,), Z (n1, n2))."""
        g1 = np.linspace(-1.0, 1.0, n1)
        g2 = np.linspace(-1.0, 1.0, n2)
        return g1, g2, self.evaluate(g1[:, None], g2[None, :])


def _no_rule_fires(x1, x2) -> str:
    return (f"no rule fires at the inputs ({float(x1):g}, {float(x2):g}): the fuzzy sets leave a gap there; "
            f"widen the upper membership functions so that they cover the whole input range")


def _min_firing_sums(a_run, i0: int, b_run, j0: int, Y) -> tuple[float, float]:
    """(Σ f, Σ f y) over rules (i, j) with f = min(a_i, b_j), for the active runs of
    memberships a (sets i0…) and b (sets j0…); row-major order, as the C kernel."""
    s = w = 0.0
    for i, a in enumerate(a_run, i0):
        row = Y[i]
        for j, b in enumerate(b_run, j0):
            f = a if a < b else b
            s += f
            w += f * row[j]
    return s, w


def require_finite(*arrays) -> None:
    for a in arrays:
        arr = np.asarray(a, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise TwinError("fuzzy system inputs must be finite numbers; got NaN or infinity")
