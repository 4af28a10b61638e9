"""Disturbances and plant uncertainty (twin/plant/disturbances.py) and the Payload of
twin/plant/urdf.py: validation, geometry of the sloped floor, and seeded sampling."""
import math

import numpy as np
import pytest

from twin.errors import TwinError
from twin.params import NOMINAL, PARAMETER_DOCS, RobotParams
from twin.plant.disturbances import (Disturbances, FrictionChange, Ground, Push,
                                     random_pushes, sample_plant)
from twin.plant.urdf import Payload

PERTURBABLE = [n for n in PARAMETER_DOCS if n not in ("g", "n_xb")]


# ---- Push ---------------------------------------------------------------------------------

@pytest.mark.parametrize("force, duration, impulse", [
    ((3.0, 4.0, 0.0), 0.5, 2.5),
    ((0.0, 0.0, -2.0), 0.1, 0.2),
    ((1.0, 2.0, 2.0), 1.0, 3.0),
    ((-6.0, 0.0, 8.0), 0.25, 2.5),
])
def test_push_impulse(force, duration, impulse):
    """The impulse of a constant push is |F| · duration (N·s)."""
    assert Push(force, 1.0, duration).impulse == pytest.approx(impulse, rel=1e-12)


def test_push_defaults_and_coercion():
    """A push defaults to the heading frame, 10 cm above the axle; vectors become float tuples."""
    p = Push([1, 2, 3], 2, 1)
    assert p.point == (0.0, 0.0, 0.1) and p.frame == "heading"
    assert p.force == (1.0, 2.0, 3.0) and all(type(f) is float for f in p.force)
    assert isinstance(p.start, float) and isinstance(p.duration, float)
    assert Push((0, 0, 0), 0.0, 0.1, frame="world").frame == "world"


@pytest.mark.parametrize("kw, match", [
    (dict(force=(float("nan"), 0, 0)), r"push force\[0\]"),
    (dict(force=(0, float("inf"), 0)), r"push force\[1\]"),
    (dict(force=(1.0, 2.0)), r"push force must be 3 numbers"),
    (dict(force=5.0), r"push force must be 3 numbers"),
    (dict(force=(0, 0, "x")), r"push force\[2\] must be a number"),
    (dict(force=(2e4, 0, 0)), r"push force\[0\]"),
    (dict(duration=0.0), r"push duration"),
    (dict(duration=-0.1), r"push duration"),
    (dict(start=-1.0), r"push start"),
    (dict(start=float("nan")), r"push start"),
    (dict(frame="body"), r"push frame"),
    (dict(point=(0, 0, 2.0)), r"push point\[2\]"),
])
def test_push_invalid(kw, match):
    """Invalid push fields raise a one-line TwinError naming the field."""
    args = dict(force=(1.0, 0.0, 0.0), start=1.0, duration=0.1) | kw
    with pytest.raises(TwinError, match=match) as err:
        Push(**args)
    assert "\n" not in str(err.value)


# ---- FrictionChange -------------------------------------------------------------------------

def test_friction_change_defaults():
    """A friction change defaults to both wheels and keeps unspecified coefficients (None)."""
    c = FrictionChange(2)
    assert c.time == 2.0 and c.wheel == "both"
    assert (c.lateral, c.rolling, c.spinning) == (None, None, None)
    c = FrictionChange(1.0, "left", lateral=0, rolling=0.01)
    assert c.lateral == 0.0 and isinstance(c.lateral, float) and c.rolling == 0.01 and c.spinning is None


@pytest.mark.parametrize("kw, match", [
    (dict(wheel="middle"), r"friction change wheel"),
    (dict(lateral=-0.1), r"lateral friction"),
    (dict(rolling=float("nan")), r"rolling friction"),
    (dict(spinning=11.0), r"spinning friction"),
    (dict(time=-1.0), r"friction change time"),
])
def test_friction_change_invalid(kw, match):
    """Unknown wheels, negative/absurd coefficients and negative times raise TwinError."""
    with pytest.raises(TwinError, match=match):
        FrictionChange(**(dict(time=1.0) | kw))


# ---- Ground -----------------------------------------------------------------------------------

def test_flat_ground_by_default():
    """The default floor is level: normal +z, height 0 everywhere, Coulomb μ = 1."""
    g = Ground()
    assert g.normal() == pytest.approx((0.0, 0.0, 1.0), abs=1e-15)
    assert g.height(3.0, -2.0) == 0.0
    assert (g.lateral_friction, g.rolling_friction, g.spinning_friction) == (1.0, 0.0, 0.0)


SLOPES = [(0.1, 0.0), (0.3, math.pi / 3), (-0.2, 1.0), (0.5, -2.5), (0.05, 2 * math.pi)]


@pytest.mark.parametrize("slope, azimuth", SLOPES)
def test_ground_normal_is_unit_and_perpendicular(slope, azimuth):
    """The normal has length 1, is tilted by the slope from +z and is orthogonal to both floor directions."""
    g = Ground(slope=slope, slope_direction=azimuth)
    n = np.array(g.normal())
    assert np.linalg.norm(n) == pytest.approx(1.0, rel=1e-12)
    assert n[2] == pytest.approx(math.cos(slope), rel=1e-12)
    uphill = np.array([math.cos(azimuth), math.sin(azimuth), math.tan(slope)])
    level = np.array([-math.sin(azimuth), math.cos(azimuth), 0.0])
    assert n @ uphill == pytest.approx(0.0, abs=1e-12)
    assert n @ level == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("slope, azimuth", SLOPES)
def test_ground_height_rises_at_tan_slope(slope, azimuth):
    """The floor passes through the origin and rises by tan(slope) per metre along slope_direction."""
    g = Ground(slope=slope, slope_direction=azimuth)
    assert g.height(0.0, 0.0) == 0.0
    ux, uy = math.cos(azimuth), math.sin(azimuth)
    for x0, y0 in [(0.0, 0.0), (1.5, -0.7), (-3.0, 2.0)]:
        for d in (0.5, 2.0, -1.0):
            rise = g.height(x0 + d * ux, y0 + d * uy) - g.height(x0, y0)
            assert rise == pytest.approx(d * math.tan(slope), rel=1e-9, abs=1e-12)
            # across the slope the floor is level
            assert g.height(x0 - d * uy, y0 + d * ux) == pytest.approx(g.height(x0, y0), abs=1e-12)


@pytest.mark.parametrize("slope, azimuth", SLOPES)
def test_ground_normal_matches_height_gradient(slope, azimuth):
    """n = (−∇h, 1)/√(1 + |∇h|²) for the floor z = h(x, y); floor points satisfy n · p = 0."""
    g = Ground(slope=slope, slope_direction=azimuth)
    eps = 1e-3
    hx = (g.height(eps, 0.0) - g.height(-eps, 0.0)) / (2 * eps)
    hy = (g.height(0.0, eps) - g.height(0.0, -eps)) / (2 * eps)
    n = np.array([-hx, -hy, 1.0]) / math.sqrt(1 + hx * hx + hy * hy)
    assert np.array(g.normal()) == pytest.approx(n, abs=1e-9)
    for x, y in [(1.0, 2.0), (-0.4, 0.9)]:
        assert np.dot(g.normal(), (x, y, g.height(x, y))) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("kw, match", [
    (dict(slope=0.8), r"ground slope"),
    (dict(slope=-0.6), r"ground slope"),
    (dict(slope=float("nan")), r"ground slope"),
    (dict(slope_direction=7.0), r"ground slope_direction"),
    (dict(lateral_friction=-0.1), r"ground lateral_friction"),
    (dict(rolling_friction=2.0), r"ground rolling_friction"),
    (dict(spinning_friction="a"), r"ground spinning_friction must be a number"),
])
def test_ground_invalid(kw, match):
    """Slopes beyond ±0.5 rad and invalid friction coefficients raise TwinError naming the field."""
    with pytest.raises(TwinError, match=match):
        Ground(**kw)


# ---- Disturbances ------------------------------------------------------------------------------

def test_disturbances_defaults():
    """No disturbance by default: no pushes, no payload, zero CoM offset, no friction changes."""
    d = Disturbances()
    assert d.pushes == () and d.payload is None and d.friction_changes == ()
    assert d.com_offset == (0.0, 0.0, 0.0)


def test_disturbances_sorts_friction_changes_by_time():
    """Friction changes are applied in time order whatever order they are given in."""
    changes = [FrictionChange(5.0, lateral=0.2), FrictionChange(1.0, "left", lateral=0.5),
               FrictionChange(3.0, "right", rolling=0.01)]
    d = Disturbances(friction_changes=changes)
    assert [c.time for c in d.friction_changes] == [1.0, 3.0, 5.0]
    assert isinstance(d.friction_changes, tuple)
    assert sorted(d.friction_changes, key=id) == sorted(changes, key=id)


def test_disturbances_keeps_pushes_and_payload():
    """Pushes become a tuple in the given order; a Payload and a small CoM offset are accepted."""
    pushes = [Push((5, 0, 0), 2.0, 0.1), Push((-5, 0, 0), 1.0, 0.1)]
    d = Disturbances(pushes=pushes, payload=Payload(0.5), com_offset=[0.01, 0, -0.02])
    assert d.pushes == tuple(pushes)
    assert d.payload == Payload(0.5, (0.0, 0.0, 0.1))
    assert d.com_offset == (0.01, 0.0, -0.02)


@pytest.mark.parametrize("kw, match", [
    (dict(com_offset=(0.2, 0.0, 0.0)), r"centre-of-mass offset\[0\]"),
    (dict(com_offset=(0.0, 0.0, -0.11)), r"centre-of-mass offset\[2\]"),
    (dict(com_offset=(0.0, 0.0)), r"centre-of-mass offset must be 3 numbers"),
    (dict(pushes=[(5.0, 0.0, 0.0)]), r"pushes must hold Push objects"),
    (dict(payload=0.5), r"payload must be a Payload"),
])
def test_disturbances_invalid(kw, match):
    """A CoM offset over 10 cm and wrongly typed pushes or payloads raise TwinError."""
    with pytest.raises(TwinError, match=match):
        Disturbances(**kw)


def test_disturbances_rejects_non_friction_change():
    """A friction change that is not a FrictionChange is a TwinError."""
    with pytest.raises(TwinError, match="friction_changes must hold FrictionChange"):
        Disturbances(friction_changes=(1.0,))


# ---- Payload ----------------------------------------------------------------------------------

def test_payload_values():
    """A payload stores its mass in kg and a 3-float position, 10 cm above the axle by default."""
    p = Payload(2)
    assert p.mass == 2.0 and isinstance(p.mass, float)
    assert p.position == (0.0, 0.0, 0.1)
    assert Payload(0.3, [0.05, -0.02, 0.2]).position == (0.05, -0.02, 0.2)


@pytest.mark.parametrize("kw, match", [
    (dict(mass=0.0), r"payload mass"),
    (dict(mass=-1.0), r"payload mass"),
    (dict(mass=float("nan")), r"payload mass"),
    (dict(mass="1"), r"payload mass"),
    (dict(mass=1.0, position=(0.0, 0.0, 1.5)), r"payload position"),
    (dict(mass=1.0, position=(0.0, 0.1)), r"payload position"),
    (dict(mass=1.0, position=(float("inf"), 0.0, 0.0)), r"payload position"),
])
def test_payload_invalid(kw, match):
    """Non-positive masses and positions off the robot raise TwinError naming the field."""
    with pytest.raises(TwinError, match=match):
        Payload(**kw)


@pytest.mark.parametrize("position", [("a", 0.0, 0.0), 5.0])
def test_payload_non_numeric_position(position):
    """A position that is not 3 numbers is a TwinError."""
    with pytest.raises(TwinError, match="payload position"):
        Payload(1.0, position)


# ---- sample_plant -------------------------------------------------------------------------------

def test_sample_plant_reproducible():
    """The same seed gives the same true plant; different seeds give different plants."""
    a = sample_plant(NOMINAL, np.random.default_rng(7), 0.2)
    b = sample_plant(NOMINAL, np.random.default_rng(7), 0.2)
    c = sample_plant(NOMINAL, np.random.default_rng(8), 0.2)
    assert a == b and a.as_dict() == b.as_dict()
    assert a != c
    assert all(a.as_dict()[n] != c.as_dict()[n] for n in PERTURBABLE)


@pytest.mark.parametrize("spread", [0.0, 0.05, 0.3, 0.9])
@pytest.mark.parametrize("seed", [0, 1, 123])
def test_sample_plant_within_spread(spread, seed):
    """Every sampled parameter lies in nominal·(1 ± spread); gravity is never perturbed."""
    p = sample_plant(NOMINAL, np.random.default_rng(seed), spread)
    assert isinstance(p, RobotParams)
    assert p.g == NOMINAL.g
    for name, v in p.as_dict().items():
        nom = getattr(NOMINAL, name)
        assert nom * (1 - spread) * (1 - 1e-12) <= v <= nom * (1 + spread) * (1 + 1e-12), name
    if spread > 0:
        assert all(p.as_dict()[n] != getattr(NOMINAL, n) for n in PERTURBABLE)
    else:
        assert p == NOMINAL


def test_sample_plant_spreads_over_the_interval():
    """Over many seeds the relative factors fill most of [1 − s, 1 + s] on both sides."""
    s = 0.2
    rel = np.array([sample_plant(NOMINAL, np.random.default_rng(k), s).m_b / NOMINAL.m_b - 1 for k in range(200)])
    assert rel.min() < -0.8 * s and rel.max() > 0.8 * s
    assert abs(rel.mean()) < 4 * s / math.sqrt(3 * 200)  # uniform: mean 0, sd of the mean s/√(3·200)


def test_sample_plant_keeps_custom_gravity():
    """A nominal with a different g keeps it exactly, even at the widest spread."""
    moon = NOMINAL.replace(g=1.62)
    for seed in range(5):
        assert sample_plant(moon, np.random.default_rng(seed), 0.9).g == 1.62


def test_sample_plant_mapping_perturbs_only_named():
    """A mapping spread perturbs only the named parameters, each within its own half-width."""
    spread = {"m_b": 0.3, "l": 0.05}
    for seed in range(10):
        p = sample_plant(NOMINAL, np.random.default_rng(seed), spread)
        for name, v in p.as_dict().items():
            nom = getattr(NOMINAL, name)
            if name in spread:
                assert v != nom
                assert abs(v / nom - 1) <= spread[name] * (1 + 1e-12)
            else:
                assert v == nom, name


def test_sample_plant_fixed_draw_order():
    """Draws follow a fixed parameter order, so a named parameter gets the same factor as with a scalar spread."""
    full = sample_plant(NOMINAL, np.random.default_rng(3), 0.25)
    only = sample_plant(NOMINAL, np.random.default_rng(3), {"d_w": 0.25})
    assert only.d_w == pytest.approx(full.d_w, rel=1e-15)


def test_sample_plant_defaulted_roll_inertia_follows_pitch():
    """With n_xb defaulted to n_yb, the sampled n_xb equals the sampled n_yb."""
    p = sample_plant(NOMINAL, np.random.default_rng(11), {"n_yb": 0.4})
    assert p.n_yb != NOMINAL.n_yb and p.n_xb == p.n_yb


@pytest.mark.parametrize("spread, match", [
    ({"g": 0.1}, r"cannot perturb 'g'"),
    ({"n_xb": 0.1}, r"cannot perturb 'n_xb'"),
    ({"mass": 0.1}, r"cannot perturb 'mass'"),
    ({"m_b": 0.95}, r"spread of m_b"),
    ({"m_b": -0.1}, r"spread of m_b"),
    (1.0, r"spread must be finite"),
    (-0.1, r"spread must be finite"),
    (float("nan"), r"spread must be finite"),
    ("wide", r"spread must be a number"),
])
def test_sample_plant_invalid_spread(spread, match):
    """Unknown or unperturbable names and spreads outside [0, 0.9] raise TwinError."""
    with pytest.raises(TwinError, match=match):
        sample_plant(NOMINAL, np.random.default_rng(0), spread)


@pytest.mark.parametrize("rng", [None, 42, np.random.RandomState(0)], ids=["None", "int", "RandomState"])
def test_sample_plant_needs_generator(rng):
    """Randomness must come from a numpy Generator; anything else is a TwinError."""
    with pytest.raises(TwinError, match=r"rng must be a numpy.random.Generator"):
        sample_plant(NOMINAL, rng, 0.1)


# ---- random_pushes ------------------------------------------------------------------------------

def test_random_pushes_reproducible():
    """The same seed gives identical pushes; another seed gives different ones."""
    a = random_pushes(np.random.default_rng(5), 8)
    assert a == random_pushes(np.random.default_rng(5), 8)
    assert a != random_pushes(np.random.default_rng(6), 8)


@pytest.mark.parametrize("force, window", [((5.0, 15.0), (1.0, 10.0)), ((0.0, 2.0), (0.0, 0.5)), ((7.0, 7.0), (3.0, 3.0))])
def test_random_pushes_ranges(force, window):
    """Pushes are horizontal along ±x (heading frame), |F| within range, starts sorted within the window."""
    pushes = random_pushes(np.random.default_rng(9), 50, force=force, window=window, duration=0.2, height=0.15)
    assert isinstance(pushes, tuple) and len(pushes) == 50
    starts = [p.start for p in pushes]
    assert starts == sorted(starts)
    for p in pushes:
        assert isinstance(p, Push) and p.frame == "heading"
        assert p.force[1] == 0.0 and p.force[2] == 0.0
        assert force[0] <= abs(p.force[0]) <= force[1]
        assert window[0] <= p.start <= window[1]
        assert p.duration == 0.2 and p.point == (0.0, 0.0, 0.15)
        assert p.impulse == pytest.approx(abs(p.force[0]) * 0.2, rel=1e-12)


def test_random_pushes_both_directions():
    """Forward and backward pushes both occur (equal odds)."""
    signs = [math.copysign(1.0, p.force[0]) for p in random_pushes(np.random.default_rng(2), 200)]
    assert 50 < signs.count(1.0) < 150


def test_random_pushes_zero_count():
    """Zero pushes is an empty tuple."""
    assert random_pushes(np.random.default_rng(0), 0) == ()


@pytest.mark.parametrize("kw, match", [
    (dict(count=-1), r"push count"),
    (dict(count=2.0), r"push count"),
    (dict(count=1001), r"push count"),
    (dict(force=(15.0, 5.0)), r"push force and window ranges"),
    (dict(window=(10.0, 1.0)), r"push force and window ranges"),
    (dict(force=(-1.0, 5.0)), r"push force bound"),
    (dict(window=(float("nan"), 5.0)), r"push window bound"),
    (dict(duration=0.0), r"push duration"),
    (dict(height=2.0), r"push point\[2\]"),
])
def test_random_pushes_invalid(kw, match):
    """Bad counts, reversed or negative ranges and bad push shapes raise TwinError."""
    args = dict(count=3) | kw
    with pytest.raises(TwinError, match=match):
        random_pushes(np.random.default_rng(0), **args)


@pytest.mark.parametrize("rng", [None, 0, np.random.RandomState(0)], ids=["None", "int", "RandomState"])
def test_random_pushes_needs_generator(rng):
    """random_pushes only accepts a numpy Generator."""
    with pytest.raises(TwinError, match=r"rng must be a numpy.random.Generator"):
        random_pushes(rng, 3)
