import math

import pytest

from twin.errors import TwinError
from twin.params import NOMINAL, PARAMETER_DOCS, RobotParams, clip_inertia_factors


def test_table_iii_values_and_units_documented():
    assert NOMINAL.m_b == 2.58 and NOMINAL.m_w == 0.14 and NOMINAL.r == 0.04 and NOMINAL.b == 0.15
    assert NOMINAL.l == 0.0622 and NOMINAL.n_yb == 0.00128 and NOMINAL.d_w == 0.01
    assert NOMINAL.n_xb == NOMINAL.n_yb  # paper-notes: take n_xb = n_yb
    assert set(PARAMETER_DOCS) == set(NOMINAL.as_dict())


def test_derived_quantities_by_hand():
    p = NOMINAL
    assert p.m11 == pytest.approx((2.58 + 0.28) * 0.04**2 + 2 * 0.00014, rel=1e-14)
    assert p.m12 == pytest.approx(2.58 * 0.0622 * 0.04, rel=1e-14)
    assert p.m22 == pytest.approx(2.58 * 0.0622**2 + 0.00128, rel=1e-14)
    assert p.g_b == pytest.approx(2.58 * 9.81 * 0.0622, rel=1e-14)
    m33 = 0.00128 + 2 * 0.00054 + (2 * 0.15**2 / 0.04**2) * (0.00014 + 0.14 * 0.04**2)
    assert p.m33 == pytest.approx(m33, rel=1e-14)
    assert p.J(0.0) == pytest.approx(m33, rel=1e-14)
    assert p.J(math.pi / 2) == pytest.approx(m33 + 2.58 * 0.0622**2, rel=1e-12)


def test_immutable():
    with pytest.raises(Exception):
        NOMINAL.m_b = 3.0


@pytest.mark.parametrize("name", ["m_b", "m_w", "r", "b", "l", "n_wa", "n_wd", "n_yb", "n_zb"])
@pytest.mark.parametrize("value", [0.0, -1.0])
def test_non_positive_physical_quantity_is_a_clear_error(name, value):
    with pytest.raises(TwinError, match=rf"parameter {name} .* must be > 0"):
        RobotParams(**{name: value})


@pytest.mark.parametrize("value", [float("nan"), float("inf"), "heavy"])
def test_non_numbers_rejected(value):
    with pytest.raises(TwinError, match="m_b"):
        RobotParams(m_b=value)


def test_negative_damping_rejected_zero_allowed():
    assert RobotParams(d_b=0.0).d_b == 0.0
    with pytest.raises(TwinError, match="d_w .* >= 0"):
        RobotParams(d_w=-0.1)


def test_perturbed_true_plant():
    p = NOMINAL.perturbed(scale={"m_b": 1.2, "l": 0.5}, offset={"n_yb": 0.001, "l": 0.01})
    assert p.m_b == pytest.approx(2.58 * 1.2)
    assert p.l == pytest.approx(0.0622 * 0.5 + 0.01)
    assert p.n_yb == pytest.approx(0.00228)
    assert p.r == NOMINAL.r  # untouched
    assert NOMINAL.m_b == 2.58  # nominal unchanged
    with pytest.raises(TwinError, match="unknown parameter 'mass'"):
        NOMINAL.perturbed(scale={"mass": 2})
    with pytest.raises(TwinError, match="m_b"):
        NOMINAL.perturbed(offset={"m_b": -3.0})


def test_defaulted_n_xb_follows_n_yb_in_a_perturbed_plant():
    assert NOMINAL.perturbed(scale={"n_yb": 2.0}).n_xb == pytest.approx(0.00256)
    assert NOMINAL.replace(n_yb=0.002).n_xb == 0.002
    explicit = NOMINAL.replace(n_xb=0.002)
    assert explicit.perturbed(scale={"n_yb": 2.0}).n_xb == 0.002


def test_an_inertia_tensor_no_rigid_body_has_is_refused():
    """PyBullet would silently zero it; the message names the parameter and the rule."""
    with pytest.raises(TwinError, match=r"n_zb .* exceeds n_xb \+ n_yb .*triangle inequality"):
        NOMINAL.perturbed(scale={"n_zb": 2.01})
    with pytest.raises(TwinError, match=r"n_wa .* exceeds n_wd \+ n_wd"):
        NOMINAL.replace(n_wa=0.0011)
    assert NOMINAL.perturbed(scale={"n_zb": 2.0}).n_zb == pytest.approx(0.00256)
    clipped = clip_inertia_factors({"n_zb": 1.9, "n_yb": 0.5, "n_wa": 9.0}, NOMINAL)
    assert clipped["n_zb"] == pytest.approx(1.0) and clipped["n_wa"] == pytest.approx(2 * 0.00054 / 0.00014)
    NOMINAL.perturbed(scale=clipped)  # physical now
