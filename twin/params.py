"""Physical parameters of the mobile two-wheeled inverted pendulum (paper Table III).

All values are SI: kg, m, kg·m², N·m·s/rad for the viscous coefficients, m/s² for
gravity. :class:`RobotParams` is immutable; :meth:`RobotParams.perturbed` builds the
"true plant" of an uncertainty study from the nominal set.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Mapping

from twin.errors import TwinError

# name -> (unit, meaning); the order is Table III's.
PARAMETER_DOCS: dict[str, tuple[str, str]] = {
    "m_w": ("kg", "wheel mass (each)"),
    "m_b": ("kg", "body mass"),
    "n_wa": ("kg·m²", "wheel inertia about its axle"),
    "n_wd": ("kg·m²", "wheel inertia about a diameter"),
    "n_yb": ("kg·m²", "body inertia about the axle (pitch) axis"),
    "n_zb": ("kg·m²", "body inertia about the vertical (yaw) axis"),
    "n_xb": ("kg·m²", "body inertia about the roll axis (not in the paper; defaults to n_yb)"),
    "r": ("m", "wheel radius"),
    "b": ("m", "half of the wheel distance"),
    "l": ("m", "axle to body centre of mass"),
    "d_b": ("N·m·s/rad", "viscous resistance in the drive (body-wheel)"),
    "d_w": ("N·m·s/rad", "viscous resistance wheel-ground"),
    "g": ("m/s²", "gravitational acceleration"),
}

_POSITIVE = ("m_w", "m_b", "n_wa", "n_wd", "n_yb", "n_zb", "n_xb", "r", "b", "l", "g")
_NON_NEGATIVE = ("d_b", "d_w")


def clip_inertia_factors(scale: Mapping[str, float], nominal: "RobotParams") -> dict[str, float]:
    """``scale`` (parameter → factor of ``nominal``) with the n_zb and n_wa factors lowered where
    independently drawn factors give a tensor no rigid body has: the body's yaw inertia above
    n_xb + n_yb, or the wheel's axle inertia above twice its diameter inertia."""
    scale = dict(scale)

    def value(name):
        return getattr(nominal, name) * scale.get(name, 1.0)

    n_yb = value("n_yb")
    # a defaulted n_xb follows n_yb (see RobotParams.perturbed)
    n_xb = n_yb if nominal._n_xb_default and "n_xb" not in scale else value("n_xb")
    if value("n_zb") > n_xb + n_yb:
        scale["n_zb"] = (n_xb + n_yb) / nominal.n_zb
    if value("n_wa") > 2.0 * value("n_wd"):
        scale["n_wa"] = 2.0 * value("n_wd") / nominal.n_wa
    return scale


@dataclass(frozen=True)
class RobotParams:
    """Nominal parameter set of the robot (paper Table III), with derived quantities.

    Attributes are in SI units, see :data:`PARAMETER_DOCS`. ``n_xb`` is not given by
    the paper; ``None`` (default) takes ``n_xb = n_yb`` as paper-notes prescribe.
    Invalid values (non-positive mass, length or inertia; negative damping; NaN)
    raise :class:`~twin.errors.TwinError` with a one-line message.
    """

    m_w: float = 0.14
    m_b: float = 2.58
    n_wa: float = 0.00014
    n_wd: float = 0.00054
    n_yb: float = 0.00128
    n_zb: float = 0.00128
    r: float = 0.04
    b: float = 0.15
    l: float = 0.0622
    d_b: float = 0.001
    d_w: float = 0.01
    g: float = 9.81
    n_xb: float | None = field(default=None)

    def __post_init__(self) -> None:
        # remembered so that a perturbed n_yb carries a defaulted n_xb along with it
        object.__setattr__(self, "_n_xb_default", self.n_xb is None)
        if self.n_xb is None:
            object.__setattr__(self, "n_xb", self.n_yb)
        for f in fields(self):
            value = getattr(self, f.name)
            unit, meaning = PARAMETER_DOCS[f.name]
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise TwinError(f"parameter {f.name} ({meaning}) must be a number in {unit}, got {value!r}") from None
            if not math.isfinite(value):
                raise TwinError(f"parameter {f.name} ({meaning}) must be finite, got {value}")
            if f.name in _POSITIVE and value <= 0.0:
                raise TwinError(f"parameter {f.name} ({meaning}) must be > 0 {unit}, got {value:g}")
            if f.name in _NON_NEGATIVE and value < 0.0:
                raise TwinError(f"parameter {f.name} ({meaning}) must be >= 0 {unit}, got {value:g}")
            object.__setattr__(self, f.name, value)
        # PyBullet silently zeroes an inertia tensor that no rigid body can have
        for body, axes in (("body", ("n_xb", "n_yb", "n_zb")), ("wheel", ("n_wd", "n_wa", "n_wd"))):
            for i, name in enumerate(axes[:2] if body == "wheel" else axes):
                others = [axes[j] for j in range(3) if j != i]
                total = sum(getattr(self, o) for o in others)
                if getattr(self, name) > total * (1.0 + 1e-12):
                    raise TwinError(f"parameter {name} ({PARAMETER_DOCS[name][1]}) = {getattr(self, name):g} kg·m² "
                                    f"exceeds {' + '.join(others)} = {total:g} kg·m²; allowed: each principal inertia "
                                    f"of the {body} at most the sum of the other two (triangle inequality)")

    # ---- derived quantities (paper-notes, "Derived") -------------------------------
    # Squares are products, not x**2: Python's float power calls the C library's pow(),
    # which glibc computes with other code on CPUs with and without FMA, and a design's inputs
    # must be the same numbers on every machine (x * x is one correctly rounded operation).
    @property
    def m11(self) -> float:
        """(m_b + 2 m_w) r² + 2 n_wa, kg·m²: wheel-rotation inertia."""
        return (self.m_b + 2.0 * self.m_w) * (self.r * self.r) + 2.0 * self.n_wa

    @property
    def m12(self) -> float:
        """m_b l r, kg·m²: body-wheel coupling inertia (times cos θ)."""
        return self.m_b * self.l * self.r

    @property
    def m22(self) -> float:
        """m_b l² + n_yb, kg·m²: body pitch inertia about the axle."""
        return self.m_b * (self.l * self.l) + self.n_yb

    @property
    def g_b(self) -> float:
        """m_b g l, N·m: gravity torque coefficient (times sin θ)."""
        return self.m_b * self.g * self.l

    @property
    def m33(self) -> float:
        """n_zb + 2 n_wd + (2b²/r²)(n_wa + m_w r²), kg·m²: yaw inertia at θ = 0."""
        r2 = self.r * self.r
        return self.n_zb + 2.0 * self.n_wd + (2.0 * (self.b * self.b) / r2) * (self.n_wa + self.m_w * r2)

    @property
    def n_bla(self) -> float:
        """m_b l² + n_xb − n_zb, kg·m²: how the yaw inertia grows with tilt."""
        return self.m_b * (self.l * self.l) + self.n_xb - self.n_zb

    def J(self, theta: float) -> float:
        """Yaw inertia J(θ) = m33 + n_bla sin²θ in kg·m²; ``theta`` in rad."""
        s = math.sin(theta)
        return self.m33 + self.n_bla * (s * s)

    @property
    def yaw_damping(self) -> float:
        """(2b²/r²)(d_b + d_w), N·m·s/rad: viscous yaw resistance."""
        return (2.0 * (self.b * self.b) / (self.r * self.r)) * (self.d_b + self.d_w)

    # ---- uncertainty --------------------------------------------------------------
    def perturbed(
        self,
        scale: Mapping[str, float] | None = None,
        offset: Mapping[str, float] | None = None,
    ) -> "RobotParams":
        """Return a "true plant" differing from this set.

        Each named parameter becomes ``value * scale[name] + offset[name]`` (offset in
        the parameter's unit). Unknown names and results that are physically invalid
        raise :class:`~twin.errors.TwinError`.
        """
        scale = dict(scale or {})
        offset = dict(offset or {})
        for name in list(scale) + list(offset):
            if name not in PARAMETER_DOCS:
                raise TwinError(f"unknown parameter {name!r}; allowed: {', '.join(PARAMETER_DOCS)}")
        values = self._own_values()
        for name in set(scale) | set(offset):
            base = getattr(self, name)
            values[name] = base * float(scale.get(name, 1.0)) + float(offset.get(name, 0.0))
        return RobotParams(**values)

    def replace(self, **changes: float) -> "RobotParams":
        """A copy with some parameters replaced (validated)."""
        for name in changes:
            if name not in PARAMETER_DOCS:
                raise TwinError(f"unknown parameter {name!r}; allowed: {', '.join(PARAMETER_DOCS)}")
        return RobotParams(**{**self._own_values(), **changes})

    def _own_values(self) -> dict:
        """Constructor arguments that rebuild this set (n_xb None where it was defaulted)."""
        values = self.as_dict()
        if self._n_xb_default:
            values["n_xb"] = None
        return values

    def as_dict(self) -> dict[str, float]:
        """Parameters by name, SI units."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


NOMINAL = RobotParams()
"""The paper's Table III, with g = 9.81 m/s² and n_xb = n_yb."""
