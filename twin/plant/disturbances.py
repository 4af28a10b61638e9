"""Disturbances and modelling uncertainty of the twin: pushes, payload, centre-of-mass
offset, wheel friction changes, ground slope, and a "true plant" that differs from the
controllers' nominal parameters.

Everything here is plain, immutable data. Randomness enters only through the functions
that take a ``numpy.random.Generator`` (:func:`sample_plant`, :func:`random_pushes`),
so a run built from one seed is reproduced exactly by the same seed.

Units: N, m, s, rad, kg.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from twin.errors import TwinError
from twin.params import PARAMETER_DOCS, RobotParams, clip_inertia_factors
from twin.plant.urdf import Payload

WHEELS = ("left", "right", "both")
PUSH_FRAMES = ("heading", "world")


def _finite(name: str, value, lo: float = -math.inf, hi: float = math.inf, unit: str = "") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TwinError(f"{name} must be a number{' in ' + unit if unit else ''}, got {value!r}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        rng = f"[{lo:g}, {hi:g}]" if math.isfinite(lo) and math.isfinite(hi) else (f">= {lo:g}" if math.isfinite(lo) else f"<= {hi:g}")
        raise TwinError(f"{name} must be finite and {rng}{' ' + unit if unit else ''}, got {value!r}")
    return v


def _vec3(name: str, value, bound: float, unit: str) -> tuple[float, float, float]:
    try:
        vals = tuple(value)
    except TypeError:
        raise TwinError(f"{name} must be 3 numbers in {unit}, got {value!r}") from None
    if len(vals) != 3:
        raise TwinError(f"{name} must be 3 numbers in {unit}, got {len(vals)}")
    return tuple(_finite(f"{name}[{i}]", v, -bound, bound, unit) for i, v in enumerate(vals))


@dataclass(frozen=True)
class Push:
    """A force on the body for a while.

    Parameters
    ----------
    force : (3,) N
        In the ``frame``: "heading" (x forward along the robot's current heading, y to its
        left, z up; default) or "world".
    start, duration : s
    point : (3,) m
        Point of application in the body frame, from the axle midpoint (default: 10 cm
        above the axle, near the top of the body).
    """

    force: tuple[float, float, float]
    start: float
    duration: float
    point: tuple[float, float, float] = (0.0, 0.0, 0.1)
    frame: str = "heading"

    def __post_init__(self):
        object.__setattr__(self, "force", _vec3("push force", self.force, 1e4, "N"))
        object.__setattr__(self, "point", _vec3("push point", self.point, 1.0, "m"))
        object.__setattr__(self, "start", _finite("push start", self.start, 0.0, 1e6, "s"))
        object.__setattr__(self, "duration", _finite("push duration", self.duration, 0.0, 1e6, "s"))
        if self.duration <= 0:
            raise TwinError(f"push duration must be > 0 s, got {self.duration!r}")
        if self.frame not in PUSH_FRAMES:
            raise TwinError(f"push frame must be one of {', '.join(PUSH_FRAMES)}, got {self.frame!r}")

    @property
    def impulse(self) -> float:
        """|F| · duration in N·s."""
        return math.sqrt(sum(f * f for f in self.force)) * self.duration


@dataclass(frozen=True)
class FrictionChange:
    """From ``time`` (s) on, a wheel's tyre–ground friction coefficients become these
    (None keeps a coefficient). ``wheel`` is "left", "right" or "both"."""

    time: float
    wheel: str = "both"
    lateral: float | None = None
    rolling: float | None = None
    spinning: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "time", _finite("friction change time", self.time, 0.0, 1e6, "s"))
        if self.wheel not in WHEELS:
            raise TwinError(f"friction change wheel must be one of {', '.join(WHEELS)}, got {self.wheel!r}")
        for name in ("lateral", "rolling", "spinning"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _finite(f"{name} friction", v, 0.0, 10.0))


@dataclass(frozen=True)
class Ground:
    """The floor: tyre–ground friction coefficients and slope.

    ``lateral_friction`` is Coulomb's μ (dimensionless); ``rolling_friction`` and
    ``spinning_friction`` are Bullet's rolling and torsional coefficients (m: the torque
    limit is the coefficient times the normal force), 0 by default because equation (1)
    models rolling resistance as the viscous d_w. ``slope`` (rad) tilts the floor so that
    it rises towards the azimuth ``slope_direction`` (rad, 0 = world +x).
    """

    lateral_friction: float = 1.0
    rolling_friction: float = 0.0
    spinning_friction: float = 0.0
    slope: float = 0.0
    slope_direction: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "lateral_friction", _finite("ground lateral_friction", self.lateral_friction, 0.0, 10.0))
        object.__setattr__(self, "rolling_friction", _finite("ground rolling_friction", self.rolling_friction, 0.0, 1.0, "m"))
        object.__setattr__(self, "spinning_friction", _finite("ground spinning_friction", self.spinning_friction, 0.0, 1.0, "m"))
        object.__setattr__(self, "slope", _finite("ground slope", self.slope, -0.5, 0.5, "rad"))
        object.__setattr__(self, "slope_direction", _finite("ground slope_direction", self.slope_direction, -2 * math.pi, 2 * math.pi, "rad"))

    def normal(self) -> tuple[float, float, float]:
        """Unit normal of the floor (world frame)."""
        s, c = math.sin(self.slope), math.cos(self.slope)
        return (-s * math.cos(self.slope_direction), -s * math.sin(self.slope_direction), c)

    def height(self, x: float, y: float) -> float:
        """Floor height in m at the world point (x, y); the floor passes through the origin."""
        return math.tan(self.slope) * (x * math.cos(self.slope_direction) + y * math.sin(self.slope_direction))


@dataclass(frozen=True)
class Disturbances:
    """What acts on the true plant beyond the controllers' commands."""

    pushes: tuple[Push, ...] = ()
    payload: Payload | None = None
    com_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m, body frame
    friction_changes: tuple[FrictionChange, ...] = field(default=())

    def __post_init__(self):
        for name, kind in (("pushes", Push), ("friction_changes", FrictionChange)):
            items = getattr(self, name)
            try:
                items = tuple(items)
            except TypeError:
                raise TwinError(f"{name} must be a sequence of {kind.__name__} objects, got {items!r}") from None
            for item in items:
                if not isinstance(item, kind):
                    raise TwinError(f"{name} must hold {kind.__name__} objects, got {item!r}")
            object.__setattr__(self, name, items)
        object.__setattr__(self, "friction_changes", tuple(sorted(self.friction_changes, key=lambda c: c.time)))
        object.__setattr__(self, "com_offset", _vec3("centre-of-mass offset", self.com_offset, 0.1, "m"))
        if self.payload is not None and not isinstance(self.payload, Payload):
            raise TwinError(f"payload must be a Payload(mass, position), got {self.payload!r}")


def sample_plant(nominal: RobotParams, rng: np.random.Generator,
                 spread: float | Mapping[str, float] = 0.1) -> RobotParams:
    """A "true plant": each parameter scaled by an independent uniform factor 1 ± spread
    (n_zb and n_wa then lowered where needed to keep the inertia tensors physical, see
    :func:`~twin.params.clip_inertia_factors`).

    ``spread`` is one relative half-width for every Table III parameter, or a mapping
    from parameter names to half-widths (unnamed parameters stay nominal). Gravity is
    never perturbed. Draws come from ``rng`` in a fixed parameter order.
    """
    if not isinstance(rng, np.random.Generator):
        raise TwinError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    names = [n for n in PARAMETER_DOCS if n not in ("g", "n_xb")]
    if isinstance(spread, Mapping):
        for n in spread:
            if n not in names:
                raise TwinError(f"cannot perturb {n!r}; allowed: {', '.join(names)}")
        spreads = {n: _finite(f"spread of {n}", spread.get(n, 0.0), 0.0, 0.9) for n in names}
    else:
        s = _finite("spread", spread, 0.0, 0.9)
        spreads = {n: s for n in names}
    factors = rng.uniform(-1.0, 1.0, size=len(names))
    scale = clip_inertia_factors({n: 1.0 + spreads[n] * f for n, f in zip(names, factors)}, nominal)
    return nominal.perturbed(scale=scale)


def random_pushes(rng: np.random.Generator, count: int, force: tuple[float, float] = (5.0, 15.0),
                  window: tuple[float, float] = (1.0, 10.0), duration: float = 0.1,
                  height: float = 0.1) -> tuple[Push, ...]:
    """``count`` horizontal pushes in the heading frame at ``height`` m above the axle.

    Magnitudes uniform in ``force`` (N), directions forward or backward with equal odds,
    start times uniform in ``window`` (s), sorted by start.
    """
    if not isinstance(rng, np.random.Generator):
        raise TwinError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if not (isinstance(count, int) and 0 <= count <= 1000):
        raise TwinError(f"push count must be an integer from 0 to 1000, got {count!r}")
    for name, pair in (("force", force), ("window", window)):
        if not (isinstance(pair, (tuple, list)) and len(pair) == 2):
            raise TwinError(f"push {name} range must be (low, high), got {pair!r}")
    f_lo, f_hi = (_finite("push force bound", v, 0.0, 1e4, "N") for v in force)
    t_lo, t_hi = (_finite("push window bound", v, 0.0, 1e6, "s") for v in window)
    if f_lo > f_hi or t_lo > t_hi:
        raise TwinError(f"push force and window ranges must be (low, high), got {force!r} and {window!r}")
    mags = rng.uniform(f_lo, f_hi, size=count)
    signs = np.where(rng.random(count) < 0.5, -1.0, 1.0)
    starts = np.sort(rng.uniform(t_lo, t_hi, size=count))
    return tuple(Push((float(m * s), 0.0, 0.0), float(t0), duration, (0.0, 0.0, height))
                 for m, s, t0 in zip(mags, signs, starts))
