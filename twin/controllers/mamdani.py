"""The paper's IT2 Mamdani position and direction controllers (Table I, Table II, Fig. 3).

Each controller is a :class:`ScaledFLS`: physical inputs are divided by the Table I
range (normalised to [−1, 1]; beyond it the shoulder sets saturate), the 7×7 Table II
rule base is evaluated, and the normalised output is multiplied by the output range.

Sign conventions (chosen so that the robot reaches its targets; tested):

* errors are *actual minus target*: p_e = p − p_d (m), α_e = α − α_d (rad);
* position: inputs (p_e, θ̇), output θ_off (rad). A robot short of its target
  (p_e < 0) gets θ_off > 0, a forward lean, and drives forward;
* direction: inputs (α_e, α̇_e = α̇ for a constant target), output u_α (N·m per wheel);
  ul = u_p − u_α, ur = u_p + u_α, so u_α > 0 turns left (α grows).

Table II is antisymmetric, output index = sat(−(i + j)) for row i and column j in
−3..3, and so is every controller: f(−e, −ė) = −f(e, ė).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from twin.errors import TwinError
from twin.fuzzy.mamdani import MamdaniFLS, require_finite
from twin.fuzzy.sets import LINGUISTIC_7, uniform_partition

# Table II: rows = first input (p_e or α_e), columns = second input (θ̇ or α̇_e), NB..PB.
TABLE_II = (
    ("PB", "PB", "PB", "PB", "PM", "PS", "ZO"),
    ("PB", "PB", "PB", "PM", "PS", "ZO", "NS"),
    ("PB", "PB", "PM", "PS", "ZO", "NS", "NM"),
    ("PB", "PM", "PS", "ZO", "NS", "NM", "NB"),
    ("PM", "PS", "ZO", "NS", "NM", "NB", "NB"),
    ("PS", "ZO", "NS", "NM", "NB", "NB", "NB"),
    ("ZO", "NS", "NM", "NB", "NB", "NB", "NB"),
)
RULE_INDEX = np.array([[LINGUISTIC_7.index(name) for name in row] for row in TABLE_II])
OUTPUT_CENTRES = np.linspace(-1.0, 1.0, 7)  # NB..PB, normalised

# Table I ranges (SI). The paper's u_α range is ±200 PWM units; the twin's own
# actuator scaling is a torque per wheel, see DEFAULT_U_ALPHA_MAX.
P_E_RANGE = 3.0  # m
THETA_DOT_RANGE = 4.0  # rad/s
THETA_OFF_RANGE = math.pi / 40  # rad
ALPHA_E_RANGE = 1.0  # rad
ALPHA_DOT_E_RANGE = 1.0  # rad/s
DEFAULT_U_ALPHA_MAX = 0.1  # N·m per wheel: a yaw rate of about 2.4 rad/s at saturation on the nominal robot

DEFAULT_FOU = 0.25  # IT2 upper half-width h(1+fou), lower h(1−fou), h = set spacing


@dataclass(frozen=True)
class ScaledFLS:
    """A Mamdani FLS between physical units: y = out_range · F(clip(x1/r1), clip(x2/r2)).

    Inputs are normalised by their Table I range and clipped to the universe [−1, 1],
    so beyond the range the output is exactly its value at the range's edge.
    """

    fls: MamdaniFLS
    input_ranges: tuple[float, float]
    output_range: float
    name: str = "fls"

    def __call__(self, x1: float, x2: float) -> float:
        """Scalar evaluation in physical units (the control loop's call)."""
        if not (math.isfinite(x1) and math.isfinite(x2)):
            raise TwinError(f"{self.name} controller: inputs must be finite numbers, got ({x1}, {x2})")
        a = x1 / self.input_ranges[0]
        b = x2 / self.input_ranges[1]
        a = 1.0 if a > 1.0 else (-1.0 if a < -1.0 else a)
        b = 1.0 if b > 1.0 else (-1.0 if b < -1.0 else b)
        try:
            return self.output_range * self.fls.evaluate_scalar(a, b)
        except TwinError as exc:
            raise TwinError(f"{self.name} controller: {exc}") from None

    def evaluate(self, x1, x2) -> np.ndarray:
        """Vectorised evaluation in physical units (arrays broadcast together)."""
        try:
            require_finite(x1, x2)
            a = np.clip(np.asarray(x1, dtype=float) / self.input_ranges[0], -1.0, 1.0)
            b = np.clip(np.asarray(x2, dtype=float) / self.input_ranges[1], -1.0, 1.0)
            return self.output_range * self.fls.evaluate(a, b)
        except TwinError as exc:
            raise TwinError(f"{self.name} controller: {exc}") from None

    def surface(self, n: int = 81):
        """Control surface in physical units: (grid1 (n,), grid2 (n,), Z (n, n))."""
        g1, g2, z = self.fls.surface(n, n)
        return g1 * self.input_ranges[0], g2 * self.input_ranges[1], z * self.output_range


def table_ii_fls(kind: str = "it2", fou: float = DEFAULT_FOU, type_reduction: str = "bmm",
                 m: float = 0.5, n: float = 0.5) -> MamdaniFLS:
    """The Table II rule base on normalised inputs; ``kind="t1"`` forces fou = 0."""
    if kind not in ("it2", "t1"):
        raise TwinError(f"controller kind must be 'it2' or 't1', got {kind!r}")
    part = uniform_partition(7, fou if kind == "it2" else 0.0)
    return MamdaniFLS(part, part, OUTPUT_CENTRES, RULE_INDEX, type_reduction=type_reduction, m=m, n=n)


def _ranges(ranges, n: int, what: str) -> tuple:
    if not (isinstance(ranges, (tuple, list)) and len(ranges) == n
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
                    for v in ranges)):
        raise TwinError(f"{what} must be {n} positive finite numbers, got {ranges!r}")
    return tuple(float(v) for v in ranges)


def position_controller(kind: str = "it2", fou: float = DEFAULT_FOU, type_reduction: str = "bmm",
                        ranges=(P_E_RANGE, THETA_DOT_RANGE, THETA_OFF_RANGE)) -> ScaledFLS:
    """θ_off (rad) = F(p_e (m), θ̇ (rad/s)); ``ranges`` (p_e m, θ̇ rad/s, θ_off rad), by default
    Table I's ±3 m, ±4 rad/s, ±π/40 rad."""
    p_e, theta_dot, theta_off = _ranges(ranges, 3, "the position controller's ranges (m, rad/s, rad)")
    return ScaledFLS(table_ii_fls(kind, fou, type_reduction), (p_e, theta_dot), theta_off, name=f"{kind} position")


def direction_controller(kind: str = "it2", fou: float = DEFAULT_FOU, type_reduction: str = "bmm",
                         u_alpha_max: float = DEFAULT_U_ALPHA_MAX,
                         ranges=(ALPHA_E_RANGE, ALPHA_DOT_E_RANGE)) -> ScaledFLS:
    """u_α (N·m per wheel) = F(α_e (rad), α̇_e (rad/s)); input ``ranges`` (rad, rad/s), by
    default Table I's ±1 rad, ±1 rad/s; output ±u_alpha_max."""
    if not (isinstance(u_alpha_max, (int, float)) and math.isfinite(u_alpha_max) and u_alpha_max > 0):
        raise TwinError(f"u_alpha_max must be a positive torque in N·m, got {u_alpha_max!r}")
    alpha_e, alpha_dot = _ranges(ranges, 2, "the direction controller's input ranges (rad, rad/s)")
    return ScaledFLS(table_ii_fls(kind, fou, type_reduction), (alpha_e, alpha_dot), float(u_alpha_max),
                     name=f"{kind} direction")
