"""Fuzzy engine: sets, type reduction, Mamdani inference and the Table II controllers.

Sections
--------
1. Zero footprint: IT2 reduces to type-1.
2. Hand-computed values (memberships, firing intervals, BMM / Nie–Tan / KM), and KM
   against a brute-force search over all vertex choices.
3. Vectorised and scalar paths agree; batch shapes are preserved.
4. The Table II controllers are odd.
5. Saturation outside the Table I ranges; control surfaces stay in the output range.
6. NaN / infinite inputs raise TwinError.
7. Validation errors.
8. Monotonicity and sign convention of the controllers along the ZO column.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from twin.controllers.mamdani import (
    ALPHA_DOT_E_RANGE,
    ALPHA_E_RANGE,
    DEFAULT_FOU,
    DEFAULT_U_ALPHA_MAX,
    P_E_RANGE,
    THETA_DOT_RANGE,
    THETA_OFF_RANGE,
    direction_controller,
    position_controller,
    table_ii_fls,
)
from twin.errors import TwinError
from twin.fuzzy import type_reduction as tr
from twin.fuzzy.mamdani import MamdaniFLS
from twin.fuzzy.sets import IT2Set, Partition, Triangle, uniform_partition

INF = math.inf
REDUCERS = ("bmm", "nt", "km")
KINDS = ("it2", "t1")
TOL = 1e-12


# ---------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------
def controller(which: str, kind: str, reducer: str):
    if which == "position":
        return position_controller(kind, type_reduction=reducer)
    return direction_controller(kind, type_reduction=reducer)


def ranges(which: str):
    """(input range 1, input range 2, output range) of a Table II controller."""
    if which == "position":
        return P_E_RANGE, THETA_DOT_RANGE, THETA_OFF_RANGE
    return ALPHA_E_RANGE, ALPHA_DOT_E_RANGE, DEFAULT_U_ALPHA_MAX


def brute_force_interval(f_lo, f_up, y_left, y_right=None):
    """min / max of Σ f y / Σ f over all 2^R vertices f_i ∈ {f̲_i, f̄_i}."""
    y_right = y_left if y_right is None else y_right
    lo, hi = math.inf, -math.inf
    for choice in itertools.product((0, 1), repeat=len(f_lo)):
        f = np.where(np.array(choice, dtype=bool), f_up, f_lo)
        s = f.sum()
        if s <= 0:
            continue
        lo = min(lo, float(f @ y_left) / s)
        hi = max(hi, float(f @ y_right) / s)
    return lo, hi


def random_firing(rng, shape, r, zero_lower_prob=0.0):
    """Random firing intervals 0 ≤ f̲ ≤ f̄ ≤ 1 with f̄ > 0 (some f̲ possibly exactly 0)."""
    f_up = rng.uniform(0.05, 1.0, size=shape + (r,))
    f_lo = f_up * rng.uniform(0.0, 1.0, size=shape + (r,))
    if zero_lower_prob:
        f_lo = np.where(rng.uniform(size=f_lo.shape) < zero_lower_prob, 0.0, f_lo)
    return f_lo, f_up


@pytest.fixture(scope="module")
def small_system_parts():
    """A hand-built 2×2 system.

    Input 1 (IT2, two shoulders):
      N: upper = Triangle(-inf, -1, 1)    → μ̄_N(x) = (1 − x)/2 on [−1, 1]
         lower = Triangle(-inf, -1, 0.25) → μ̲_N(x) = 1 − (x + 1)/1.25 on [−1, 0.25]
      P: mirror images: μ̄_P(x) = (1 + x)/2, μ̲_P(x) = 1 − (1 − x)/1.25
    Input 2 (type-1, two shoulders):
      N2 = Triangle(-inf, -2, 2) → μ(x) = 1 − (x + 2)/4
      P2 = Triangle(-2, 2, inf)  → μ(x) = 1 − (2 − x)/4
    Output centres [-1, 0, 2], rule table [[2, 1], [1, 0]]:
      rule order (row-major) NN → 2, NP → 0, PN → 0, PP → −1.
    """
    p1 = Partition([
        IT2Set("N", lower=Triangle(-INF, -1.0, 0.25), upper=Triangle(-INF, -1.0, 1.0)),
        IT2Set("P", lower=Triangle(-0.25, 1.0, INF), upper=Triangle(-1.0, 1.0, INF)),
    ])
    n2, p2 = Triangle(-INF, -2.0, 2.0), Triangle(-2.0, 2.0, INF)
    p2_ = Partition([IT2Set("N", n2, n2), IT2Set("P", p2, p2)])
    return p1, p2_, [-1.0, 0.0, 2.0], [[2, 1], [1, 0]]


def small_system(parts, **kw):
    p1, p2, centres, table = parts
    return MamdaniFLS(p1, p2, centres, table, **kw)


# ---------------------------------------------------------------------------------------
# 1. zero footprint: IT2 == type-1
# ---------------------------------------------------------------------------------------
GRID_1D = np.concatenate([np.linspace(-1.6, 1.6, 49), [-1e3, -7.5, -1.0, 1.0, 7.5, 1e3]])
X1, X2 = np.meshgrid(GRID_1D, GRID_1D, indexing="ij")


@pytest.mark.parametrize("reducer", REDUCERS)
def test_it2_with_zero_fou_is_identical_to_type1(reducer):
    z_it2 = table_ii_fls("it2", fou=0.0, type_reduction=reducer).evaluate(X1, X2)
    z_t1 = table_ii_fls("t1", type_reduction=reducer).evaluate(X1, X2)
    assert z_it2.shape == X1.shape
    np.testing.assert_array_equal(z_it2, z_t1)


def test_zero_fou_makes_all_reducers_equal_the_weighted_average():
    fls = table_ii_fls("it2", fou=0.0)
    f_lo, f_up = fls.firing(X1, X2)
    np.testing.assert_array_equal(f_lo, f_up)  # every firing interval is a point
    wa = tr.weighted_average(f_up, fls.y)
    b = tr.bmm(f_lo, f_up, fls.y)
    b37 = tr.bmm(f_lo, f_up, fls.y, m=0.3, n=0.7)
    nt = tr.nie_tan(f_lo, f_up, fls.y)
    y_l, y_r = tr.karnik_mendel(f_lo, f_up, fls.y)
    for z in (b, b37, nt, y_l, y_r, 0.5 * (y_l + y_r)):
        np.testing.assert_allclose(z, wa, rtol=0, atol=TOL)
    # and the systems' own outputs are the same numbers
    for reducer in REDUCERS:
        z = table_ii_fls("it2", fou=0.0, type_reduction=reducer).evaluate(X1, X2)
        np.testing.assert_allclose(z, wa, rtol=0, atol=TOL)


def test_positive_fou_actually_differs_from_type1():
    """Guards the tests above: a non-zero FOU must change the firing and the output."""
    fls = table_ii_fls("it2", fou=DEFAULT_FOU)
    f_lo, f_up = fls.firing(X1, X2)
    assert np.all(f_lo <= f_up)
    assert np.any(f_up - f_lo > 0.1)
    y_l, y_r = fls.interval(X1, X2)
    assert np.max(y_r - y_l) > 0.05
    z_t1 = table_ii_fls("t1").evaluate(X1, X2)
    assert np.max(np.abs(fls.evaluate(X1, X2) - z_t1)) > 1e-3


# ---------------------------------------------------------------------------------------
# 2. hand-computed values
# ---------------------------------------------------------------------------------------
def test_triangle_and_shoulder_memberships_by_hand():
    t = Triangle(-1.0, 0.0, 2.0)
    # left slope 1/(0 − (−1)) = 1, right slope 1/(2 − 0) = 0.5
    np.testing.assert_allclose(t([-2.0, -1.0, -0.5, 0.0, 1.0, 2.0, 3.0]),
                               [0.0, 0.0, 0.5, 1.0, 0.5, 0.0, 0.0], atol=TOL)
    assert float(Triangle(-1.0, 0.0, 2.0, height=0.8)(1.0)) == pytest.approx(0.8 * 0.5)
    left = Triangle(-INF, 0.0, 1.0)  # 1 for x ≤ 0, 1 − x on [0, 1]
    np.testing.assert_allclose(left([-1e9, -5.0, 0.0, 0.25, 1.0, 4.0]), [1, 1, 1, 0.75, 0, 0], atol=TOL)
    right = Triangle(0.0, 1.0, INF)
    np.testing.assert_allclose(right([-1.0, 0.5, 1.0, 1e9]), [0, 0.5, 1, 1], atol=TOL)


def test_uniform_partition_memberships_by_hand():
    # 3 sets, fou = 0.2: spacing h = 1, upper half-width 1.2, lower 0.8; x = 0.4:
    #   N (peak −1): distance 1.4 > 1.2 → upper 0, lower 0
    #   Z (peak 0):  upper 1 − 0.4/1.2 = 2/3, lower 1 − 0.4/0.8 = 0.5
    #   P (peak 1):  upper 1 − 0.6/1.2 = 0.5, lower 1 − 0.6/0.8 = 0.25
    part = uniform_partition(3, fou=0.2)
    lo, up = part.memberships(0.4)
    np.testing.assert_allclose(lo, [0.0, 0.5, 0.25], atol=TOL)
    np.testing.assert_allclose(up, [0.0, 2 / 3, 0.5], atol=TOL)
    lo_s, up_s = part.memberships_scalar(0.4)
    np.testing.assert_allclose(lo_s, lo, atol=TOL)
    np.testing.assert_allclose(up_s, up, atol=TOL)
    # the shoulders saturate: beyond ±1 only the outer set fires, with membership 1
    lo, up = part.memberships([-5.0, 5.0])
    np.testing.assert_array_equal(lo, [[1, 0, 0], [0, 0, 1]])
    np.testing.assert_array_equal(up, [[1, 0, 0], [0, 0, 1]])
    # type-1 (fou = 0) 7-set partition is a partition of unity
    lo, up = uniform_partition(7, 0.0).memberships(np.linspace(-2, 2, 101))
    np.testing.assert_allclose(up.sum(axis=-1), 1.0, atol=TOL)


def test_small_system_firing_intervals_by_hand(small_system_parts):
    fls = small_system(small_system_parts)
    # x1 = 0.5: μ̄_N = 0.25, μ̲_N = 1 − 1.5/1.25 < 0 → 0, μ̄_P = 0.75, μ̲_P = 1 − 0.5/1.25 = 0.6
    # x2 = 1:   μ_N2 = 1 − 3/4 = 0.25, μ_P2 = 1 − 1/4 = 0.75
    # min t-norm, rules NN, NP, PN, PP:
    #   lower: min(0, .25)=0, min(0, .75)=0, min(.6, .25)=.25, min(.6, .75)=.6
    #   upper: min(.25, .25)=.25, min(.25, .75)=.25, min(.75, .25)=.25, min(.75, .75)=.75
    f_lo, f_up = fls.firing(0.5, 1.0)
    np.testing.assert_allclose(f_lo, [0.0, 0.0, 0.25, 0.6], atol=TOL)
    np.testing.assert_allclose(f_up, [0.25, 0.25, 0.25, 0.75], atol=TOL)
    np.testing.assert_array_equal(fls.y, [2.0, 0.0, 0.0, -1.0])


# Expected outputs of the 2×2 system at (x1, x2) = (0.5, 1) and (0, 1).
#
# (0.5, 1): f̲ = [0, 0, .25, .6], f̄ = [.25, .25, .25, .75], y = [2, 0, 0, −1]
#   lower term Σf̲y/Σf̲ = (−0.6)/0.85 = −12/17; upper term Σf̄y/Σf̄ = (0.5 − 0.75)/1.5 = −1/6
#   BMM(.5, .5) = −6/17 − 1/12 = −89/204;  BMM(.3, .7) = −18/85 − 7/60 = −67/204
#   NT: f̲+f̄ = [.25, .25, .5, 1.35], Σ = 2.35, Σ(f̲+f̄)y = 0.5 − 1.35 = −0.85 → −17/47
#   KM y_l (upper on y < y_l, lower above): PP upper, rest lower:
#       (−0.75 + 0 + 0 + 0)/(0.75 + 0.25 + 0 + 0) = −0.75
#   KM y_r (upper on y > y_r, lower below): NN, NP, PN upper, PP lower:
#       (0.5 + 0 + 0 − 0.6)/(0.25 + 0.25 + 0.25 + 0.6) = −0.1/1.35 = −2/27
#   KM midpoint = (−3/4 − 2/27)/2 = −89/216
#
# (0, 1): μ_N = μ_P = [0.2, 0.5] (lower 1 − 1/1.25 = 0.2, upper 1/2); x2 as above
#   f̲ = [.2, .2, .2, .2], f̄ = [.25, .5, .25, .5]
#   lower term (0.4 − 0.2)/0.8 = 1/4; upper term (0.5 − 0.5)/1.5 = 0
#   BMM(.5, .5) = 1/8;  BMM(.3, .7) = 0.3/4 = 0.075
#   NT: f̲+f̄ = [.45, .7, .45, .7], Σ = 2.3, Σ(f̲+f̄)y = 0.9 − 0.7 = 0.2 → 2/23
#   KM y_l: PP upper, rest lower: (−0.5 + 0.4)/(0.5 + 0.2 + 0.2 + 0.2) = −1/11
#   KM y_r: NN upper, rest lower: (0.5 − 0.2)/(0.25 + 0.2 + 0.2 + 0.2) = 6/17
#   KM midpoint = (−1/11 + 6/17)/2 = 49/374
SMALL_CASES = [
    # x1,  bmm,      bmm(.3,.7), nt,     y_l,    y_r,   km midpoint
    (0.5, -89 / 204, -67 / 204, -17 / 47, -0.75, -2 / 27, -89 / 216),
    (0.0, 1 / 8, 0.075, 2 / 23, -1 / 11, 6 / 17, 49 / 374),
]


@pytest.mark.parametrize("x1, bmm55, bmm37, nt, y_l, y_r, km", SMALL_CASES)
def test_small_system_outputs_by_hand(small_system_parts, x1, bmm55, bmm37, nt, y_l, y_r, km):
    x2 = 1.0
    expected = {
        ("bmm", 0.5, 0.5): bmm55,
        ("bmm", 0.3, 0.7): bmm37,
        ("nt", 0.5, 0.5): nt,
        ("km", 0.5, 0.5): km,
    }
    for (reducer, m, n), value in expected.items():
        fls = small_system(small_system_parts, type_reduction=reducer, m=m, n=n)
        assert float(fls.evaluate(x1, x2)) == pytest.approx(value, abs=TOL)
        assert fls.evaluate_scalar(x1, x2) == pytest.approx(value, abs=TOL)
    lo, hi = small_system(small_system_parts).interval(x1, x2)
    assert float(lo) == pytest.approx(y_l, abs=TOL)
    assert float(hi) == pytest.approx(y_r, abs=TOL)


def test_small_system_bmm_falls_back_to_upper_term_when_no_lower_firing(small_system_parts):
    # Input 1 with lower MFs that leave a gap around 0: at x1 = 0 both lower memberships are 0,
    # both upper ones 0.5. x2 = −1: μ_N2 = 1 − 1/4 = 0.75, μ_P2 = 1 − 3/4 = 0.25.
    #   f̄ (NN, NP, PN, PP) = [min(.5,.75), min(.5,.25), min(.5,.75), min(.5,.25)] = [.5, .25, .5, .25]
    #   upper term = (0.5·2 + 0 + 0 − 0.25)/1.5 = 0.5; no lower term → BMM = (m + n)·0.5
    #   KM: y_l = −1 (only PP, upper), y_r = 2 (only NN, upper) → midpoint 0.5
    _, p2, centres, table = small_system_parts
    gap = Partition([
        IT2Set("N", lower=Triangle(-INF, -1.0, -0.5), upper=Triangle(-INF, -1.0, 1.0)),
        IT2Set("P", lower=Triangle(0.5, 1.0, INF), upper=Triangle(-1.0, 1.0, INF)),
    ])
    f_lo, f_up = MamdaniFLS(gap, p2, centres, table).firing(0.0, -1.0)
    np.testing.assert_array_equal(f_lo, 0.0)
    np.testing.assert_allclose(f_up, [0.5, 0.25, 0.5, 0.25], atol=TOL)
    for reducer, m, n, value in (("bmm", 0.3, 0.7, 0.5), ("bmm", 0.5, 0.5, 0.5), ("bmm", 0.2, 0.2, 0.2),
                                 ("nt", 0.5, 0.5, 0.5), ("km", 0.5, 0.5, 0.5)):
        fls = MamdaniFLS(gap, p2, centres, table, type_reduction=reducer, m=m, n=n)
        assert float(fls.evaluate(0.0, -1.0)) == pytest.approx(value, abs=TOL)
        assert fls.evaluate_scalar(0.0, -1.0) == pytest.approx(value, abs=TOL)
    lo, hi = MamdaniFLS(gap, p2, centres, table).interval(0.0, -1.0)
    assert (float(lo), float(hi)) == pytest.approx((-1.0, 2.0), abs=TOL)


def test_table_ii_system_by_hand_between_zo_and_ps():
    # Table II system, fou = 0.25: spacing h = 1/3, upper half-width 5/12, lower 1/4.
    # x1 = 1/4:  ZO: upper 1 − (1/4)/(5/12) = 0.4, lower 1 − (1/4)/(1/4) = 0
    #            PS (peak 1/3, distance 1/12): upper 1 − (1/12)/(5/12) = 0.8, lower 1 − (1/12)/(1/4) = 2/3
    # x2 = 0:    ZO [1, 1]; NS and PS (distance 1/3): upper 1 − (1/3)/(5/12) = 0.2, lower 0
    # Table II (output index −(i + j)): (ZO,NS)→PS=1/3, (ZO,ZO)→0, (ZO,PS)→−1/3,
    #                                   (PS,NS)→0, (PS,ZO)→−1/3, (PS,PS)→NM=−2/3
    # firing upper: .2, .4, .2, .2, .8, .2 (Σ = 2.0); lower: only (PS,ZO) = 2/3
    #   lower term = −1/3; upper term = (.2/3 − .2/3 − .8/3 − .4/3)/2 = −0.2
    #   BMM = −1/6 − 1/10 = −4/15
    #   NT = (2/3·(−1/3) − 0.4)/(2/3 + 2) = (−28/45)/(8/3) = −7/30
    #   KM y_l: upper only on (PS,PS): (.2·(−2/3) + 2/3·(−1/3))/(.2 + 2/3) = (−16/45)/(39/45) = −16/39
    #   KM y_r: upper on y ∈ {0, 1/3}, lower below: (−2/9 + .2/3)/(2/3 + .4 + .2 + .2) = −7/66
    #   KM midpoint = (−16/39 − 7/66)/2 = −443/1716
    for reducer, value in (("bmm", -4 / 15), ("nt", -7 / 30), ("km", -443 / 1716)):
        fls = table_ii_fls("it2", fou=0.25, type_reduction=reducer)
        assert float(fls.evaluate(0.25, 0.0)) == pytest.approx(value, abs=TOL)
        assert fls.evaluate_scalar(0.25, 0.0) == pytest.approx(value, abs=TOL)
    lo, hi = table_ii_fls("it2", fou=0.25).interval(0.25, 0.0)
    assert (float(lo), float(hi)) == pytest.approx((-16 / 39, -7 / 66), abs=TOL)
    # in physical units: p_e = 0.75 m (a quarter of 3 m), θ̇ = 0 → θ_off = −(4/15)·π/40
    assert position_controller("it2")(0.75, 0.0) == pytest.approx(-4 / 15 * math.pi / 40, abs=TOL)


def test_type_reducers_two_rules_by_hand():
    # f̲ = [0.2, 0.5], f̄ = [0.6, 0.9], y = [−1, 1]
    f_lo, f_up, y = np.array([0.2, 0.5]), np.array([0.6, 0.9]), np.array([-1.0, 1.0])
    # y_l: upper on the small y, lower on the large: (0.6·(−1) + 0.5·1)/(0.6 + 0.5) = −1/11
    # y_r: lower on the small y, upper on the large: (0.2·(−1) + 0.9·1)/(0.2 + 0.9) = 7/11
    y_l, y_r = tr.karnik_mendel(f_lo, f_up, y)
    assert (float(y_l), float(y_r)) == pytest.approx((-1 / 11, 7 / 11), abs=TOL)
    # BMM: lower (−0.2 + 0.5)/0.7 = 3/7, upper (−0.6 + 0.9)/1.5 = 1/5
    assert float(tr.bmm(f_lo, f_up, y)) == pytest.approx(0.5 * (3 / 7 + 1 / 5), abs=TOL)  # 11/35
    assert float(tr.bmm(f_lo, f_up, y, 0.3, 0.7)) == pytest.approx(0.3 * 3 / 7 + 0.7 / 5, abs=TOL)
    # NT: (−0.8 + 1.4)/2.2 = 3/11
    assert float(tr.nie_tan(f_lo, f_up, y)) == pytest.approx(3 / 11, abs=TOL)
    # weighted average of one vertex: (0.6·(−1) + 0.5)/1.1
    assert float(tr.weighted_average([0.6, 0.5], y)) == pytest.approx(-1 / 11, abs=TOL)


def test_karnik_mendel_three_rules_switch_in_the_middle():
    # y = [−1, 0, 1], f̲ = [0.1, 0.1, 0.8], f̄ = [0.2, 0.5, 0.9]
    # y_l candidates (first k+1 rules upper, rest lower):
    #   none upper: (−0.1 + 0.8)/1.0 = 0.7;  rule 0: (−0.2 + 0.8)/1.1 = 6/11
    #   rules 0,1:  (−0.2 + 0.8)/1.5 = 0.4  ← minimum;  all: (−0.2 + 0.9)/1.6 = 0.4375
    # y_r candidates (first k+1 rules lower, rest upper):
    #   all upper 0.4375;  rule 0 lower: (−0.1 + 0.9)/1.5 = 8/15
    #   rules 0,1 lower: (−0.1 + 0.9)/1.1 = 8/11  ← maximum;  all lower: 0.7
    f_lo, f_up, y = np.array([0.1, 0.1, 0.8]), np.array([0.2, 0.5, 0.9]), np.array([-1.0, 0.0, 1.0])
    y_l, y_r = tr.karnik_mendel(f_lo, f_up, y)
    assert (float(y_l), float(y_r)) == pytest.approx((0.4, 8 / 11), abs=TOL)
    # the order of the rules must not matter (the reducer sorts y itself)
    perm = [2, 0, 1]
    y_l2, y_r2 = tr.karnik_mendel(f_lo[perm], f_up[perm], y[perm])
    assert (float(y_l2), float(y_r2)) == pytest.approx((0.4, 8 / 11), abs=TOL)


@pytest.mark.parametrize("seed", range(6))
def test_karnik_mendel_equals_brute_force_over_vertices(seed):
    rng = np.random.default_rng(seed)
    for r in range(1, 8):
        f_lo, f_up = random_firing(rng, (20,), r, zero_lower_prob=0.3)
        y = rng.normal(size=r)
        if r >= 3:
            y[1] = y[0]  # ties in the consequents
        y_l, y_r = tr.karnik_mendel(f_lo, f_up, y)
        assert y_l.shape == y_r.shape == (20,)
        for b in range(20):
            lo, hi = brute_force_interval(f_lo[b], f_up[b], y)
            assert y_l[b] == pytest.approx(lo, abs=TOL)
            assert y_r[b] == pytest.approx(hi, abs=TOL)


def test_karnik_mendel_interval_consequents_equal_brute_force():
    rng = np.random.default_rng(42)
    for _ in range(30):
        r = int(rng.integers(2, 7))
        f_lo, f_up = random_firing(rng, (), r)
        y_left = rng.normal(size=r)
        y_right = y_left + rng.uniform(0.0, 0.5, size=r)
        y_l, y_r = tr.karnik_mendel(f_lo, f_up, y_left, y_right)
        lo, hi = brute_force_interval(f_lo, f_up, y_left, y_right)
        assert (float(y_l), float(y_r)) == pytest.approx((lo, hi), abs=TOL)


def test_bmm_and_nie_tan_lie_inside_the_km_interval():
    rng = np.random.default_rng(7)
    f_lo, f_up = random_firing(rng, (500,), 9)
    y = rng.normal(size=9)
    y_l, y_r = tr.karnik_mendel(f_lo, f_up, y)
    assert np.all(y_l <= y_r + TOL)
    for z in (tr.bmm(f_lo, f_up, y), tr.bmm(f_lo, f_up, y, 0.3, 0.7), tr.nie_tan(f_lo, f_up, y)):
        assert np.all((y_l - TOL <= z) & (z <= y_r + TOL))


# ---------------------------------------------------------------------------------------
# 3. vectorised vs scalar, batch shapes
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("reducer, m, n", [("bmm", 0.5, 0.5), ("bmm", 0.3, 0.7), ("nt", 0.5, 0.5),
                                           ("km", 0.5, 0.5)])
@pytest.mark.parametrize("fou", [0.0, 0.25, 0.45])
def test_scalar_path_equals_vectorised(reducer, m, n, fou):
    rng = np.random.default_rng(123)
    x1 = np.concatenate([rng.uniform(-2.5, 2.5, 300), [-1.0, 0.0, 1.0, -1e6, 1e6]])
    x2 = np.concatenate([rng.uniform(-2.5, 2.5, 300), [1.0, 0.0, -1.0, 1e6, -3.0]])
    fls = table_ii_fls("it2", fou=fou, type_reduction=reducer, m=m, n=n)
    z_vec = fls.evaluate(x1, x2)
    z_sca = np.array([fls.evaluate_scalar(float(a), float(b)) for a, b in zip(x1, x2)])
    np.testing.assert_allclose(z_sca, z_vec, rtol=0, atol=TOL)


@pytest.mark.parametrize("which", ["position", "direction"])
@pytest.mark.parametrize("reducer", REDUCERS)
def test_scaled_controller_call_equals_evaluate(which, reducer):
    r1, r2, _ = ranges(which)
    ctrl = controller(which, "it2", reducer)
    rng = np.random.default_rng(5)
    x1, x2 = rng.uniform(-2 * r1, 2 * r1, 150), rng.uniform(-2 * r2, 2 * r2, 150)
    z_vec = ctrl.evaluate(x1, x2)
    z_sca = np.array([ctrl(float(a), float(b)) for a, b in zip(x1, x2)])
    np.testing.assert_allclose(z_sca, z_vec, rtol=0, atol=TOL)


@pytest.mark.parametrize("reducer", REDUCERS)
def test_batch_shapes_broadcast(reducer):
    fls = table_ii_fls("it2", type_reduction=reducer)
    a = np.linspace(-1.5, 1.5, 4)[:, None]
    b = np.linspace(-1.2, 1.2, 5)[None, :]
    f_lo, f_up = fls.firing(a, b)
    assert f_lo.shape == f_up.shape == (4, 5, 49)
    z = fls.evaluate(a, b)
    assert z.shape == (4, 5)
    for i in range(4):
        for j in range(5):
            assert z[i, j] == pytest.approx(float(fls.evaluate(a[i, 0], b[0, j])), abs=TOL)
    # 3-D input with a scalar second input
    x = np.random.default_rng(0).uniform(-2, 2, size=(2, 3, 4))
    z3 = fls.evaluate(x, 0.3)
    assert z3.shape == (2, 3, 4)
    np.testing.assert_allclose(z3.ravel(), [fls.evaluate_scalar(float(v), 0.3) for v in x.ravel()],
                               rtol=0, atol=TOL)
    lo, hi = fls.interval(a, b)
    assert lo.shape == hi.shape == (4, 5)
    # scalars in, 0-d out
    assert np.ndim(fls.evaluate(0.1, 0.2)) == 0


def test_type_reducers_preserve_batch_shape():
    rng = np.random.default_rng(3)
    f_lo, f_up = random_firing(rng, (3, 4), 6)
    y = rng.normal(size=6)
    outs = {
        "bmm": tr.bmm(f_lo, f_up, y, 0.3, 0.7),
        "nt": tr.nie_tan(f_lo, f_up, y),
        "wa": tr.weighted_average(f_up, y),
        "y_l": tr.karnik_mendel(f_lo, f_up, y)[0],
        "y_r": tr.karnik_mendel(f_lo, f_up, y)[1],
    }
    for z in outs.values():
        assert z.shape == (3, 4)
    for i in range(3):
        for j in range(4):
            lo, up = f_lo[i, j], f_up[i, j]
            assert outs["bmm"][i, j] == pytest.approx(float(tr.bmm(lo, up, y, 0.3, 0.7)), abs=TOL)
            assert outs["nt"][i, j] == pytest.approx(float(tr.nie_tan(lo, up, y)), abs=TOL)
            assert outs["wa"][i, j] == pytest.approx(float(tr.weighted_average(up, y)), abs=TOL)
            bl, bh = brute_force_interval(lo, up, y)
            assert (outs["y_l"][i, j], outs["y_r"][i, j]) == pytest.approx((bl, bh), abs=TOL)


# ---------------------------------------------------------------------------------------
# 4. oddness of the Table II controllers
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["position", "direction"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("reducer", REDUCERS)
def test_controllers_are_odd(which, kind, reducer):
    r1, r2, out = ranges(which)
    ctrl = controller(which, kind, reducer)
    g = np.concatenate([np.linspace(-1.8, 1.8, 37), [-50.0, -1.1, 1.1, 50.0]])
    e, de = np.meshgrid(g * r1, g * r2, indexing="ij")
    z = ctrl.evaluate(e, de)
    z_neg = ctrl.evaluate(-e, -de)
    np.testing.assert_allclose(z_neg, -z, rtol=0, atol=TOL * out)
    assert np.max(np.abs(z)) > 0.5 * out  # not trivially zero
    assert abs(ctrl(0.0, 0.0)) <= TOL * out
    assert abs(float(ctrl.evaluate(0.0, 0.0))) <= TOL * out
    for a, b in ((0.37 * r1, -1.3 * r2), (2.5 * r1, 0.2 * r2), (-0.01 * r1, 0.0)):
        assert ctrl(-a, -b) == pytest.approx(-ctrl(a, b), abs=TOL * out)


# ---------------------------------------------------------------------------------------
# 5. saturation and control surface
# ---------------------------------------------------------------------------------------
FAR = (1e6, 1e3)  # far outside Table I in the first / second input (m or rad; rad/s)


@pytest.mark.parametrize("which", ["position", "direction"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("reducer", REDUCERS)
def test_far_inputs_stay_within_output_range(which, kind, reducer):
    r1, r2, out = ranges(which)
    ctrl = controller(which, kind, reducer)
    big1 = np.array([-FAR[0], -10 * r1, 10 * r1, FAR[0]])
    big2 = np.array([-FAR[1], -10 * r2, 10 * r2, FAR[1]])
    mid1, mid2 = np.linspace(-r1, r1, 9), np.linspace(-r2, r2, 9)
    for a, b in ((big1[:, None], mid2[None, :]), (mid1[:, None], big2[None, :]), (big1[:, None], big2[None, :])):
        z = ctrl.evaluate(a, b)
        assert np.all(np.isfinite(z))
        assert np.all(np.abs(z) <= out * (1 + 1e-12))
    for a in big1:
        for b in big2:
            assert abs(ctrl(float(a), float(b))) <= out * (1 + 1e-12)


@pytest.mark.parametrize("which", ["position", "direction"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("reducer", REDUCERS)
def test_saturates_at_the_range_edge(which, kind, reducer):
    """Inputs are clipped to the Table I range, so f(±1e6, x) = f(±range, x) for IT2 and T1."""
    r1, r2, out = ranges(which)
    ctrl = controller(which, kind, reducer)
    x2 = np.concatenate([np.linspace(-1.5 * r2, 1.5 * r2, 31), [-FAR[1], FAR[1]]])
    for sign in (-1.0, 1.0):
        np.testing.assert_allclose(ctrl.evaluate(sign * FAR[0], x2), ctrl.evaluate(sign * r1, x2),
                                   rtol=0, atol=TOL * out)
        assert ctrl(sign * 1.01 * r1, 0.0) == pytest.approx(ctrl(sign * r1, 0.0), abs=TOL * out)
    x1 = np.concatenate([np.linspace(-1.5 * r1, 1.5 * r1, 31), [-FAR[0], FAR[0]]])
    for sign in (-1.0, 1.0):
        np.testing.assert_allclose(ctrl.evaluate(x1, sign * FAR[1]), ctrl.evaluate(x1, sign * r2),
                                   rtol=0, atol=TOL * out)
    # both inputs saturated in the same direction: the corner rule (NB, NB) → PB dominates
    assert ctrl(-FAR[0], -FAR[1]) == pytest.approx(ctrl(-r1, -r2), abs=TOL * out)
    assert ctrl(-FAR[0], -FAR[1]) > 0.9 * out


def test_type1_corner_is_exactly_the_output_bound():
    for which in ("position", "direction"):
        r1, r2, out = ranges(which)
        ctrl = controller(which, "t1", "bmm")
        assert ctrl(-FAR[0], -FAR[1]) == pytest.approx(out, abs=TOL * out)
        assert ctrl(FAR[0], FAR[1]) == pytest.approx(-out, abs=TOL * out)


@pytest.mark.parametrize("which", ["position", "direction"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("reducer", REDUCERS)
def test_control_surface_within_output_range(which, kind, reducer):
    r1, r2, out = ranges(which)
    ctrl = controller(which, kind, reducer)
    g1, g2, z = ctrl.surface(41)
    assert g1.shape == g2.shape == (41,) and z.shape == (41, 41)
    assert (g1[0], g1[-1], g2[0], g2[-1]) == pytest.approx((-r1, r1, -r2, r2))
    assert np.all(np.isfinite(z))
    assert np.all(np.abs(z) <= out * (1 + 1e-12))
    assert z.max() > 0.5 * out and z.min() < -0.5 * out  # the surface spans the range
    np.testing.assert_allclose(z, ctrl.evaluate(g1[:, None], g2[None, :]), rtol=0, atol=TOL * out)


# ---------------------------------------------------------------------------------------
# 6. non-finite inputs
# ---------------------------------------------------------------------------------------
BAD = [(math.nan, 0.0), (0.0, math.nan), (math.inf, 0.0), (0.0, -math.inf)]


@pytest.mark.parametrize("which", ["position", "direction"])
@pytest.mark.parametrize("reducer", REDUCERS)
@pytest.mark.parametrize("x1, x2", BAD)
def test_scalar_controller_call_rejects_non_finite(which, reducer, x1, x2):
    ctrl = controller(which, "it2", reducer)
    with pytest.raises(TwinError, match="finite") as exc:
        ctrl(x1, x2)
    msg = str(exc.value)
    assert which in msg  # names the controller
    assert ("nan" in msg.lower()) or ("inf" in msg.lower())


@pytest.mark.parametrize("reducer", REDUCERS)
@pytest.mark.parametrize("x1, x2", BAD)
def test_evaluate_scalar_rejects_non_finite(reducer, x1, x2):
    fls = table_ii_fls("it2", type_reduction=reducer)
    with pytest.raises(TwinError, match="finite"):
        fls.evaluate_scalar(x1, x2)


@pytest.mark.parametrize("reducer", REDUCERS)
def test_vectorised_evaluate_rejects_arrays_with_nan_or_inf(reducer):
    fls = table_ii_fls("it2", type_reduction=reducer)
    good = np.linspace(-1, 1, 5)
    for bad in (np.array([0.1, np.nan, 0.3, 0.0, 0.2]), np.array([0.1, 0.2, np.inf, 0.0, 0.2])):
        for args in ((bad, good), (good, bad), (bad[:, None], good[None, :])):
            with pytest.raises(TwinError, match=r"finite.*NaN"):
                fls.evaluate(*args)
            with pytest.raises(TwinError, match="finite"):
                fls.interval(*args)
    ctrl = position_controller("it2", type_reduction=reducer)
    with pytest.raises(TwinError, match=r"position controller: .*finite.*NaN"):
        ctrl.evaluate(np.array([[0.0, np.nan]]), 0.0)


# ---------------------------------------------------------------------------------------
# 7. validation errors
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("fou", [-0.01, 0.5, 0.75, 2.0, math.nan, "wide", None])
def test_uniform_partition_rejects_bad_fou(fou):
    with pytest.raises(TwinError, match="fou"):
        uniform_partition(7, fou)


@pytest.mark.parametrize("n_sets", [1, 2, 4, 6, 7.0])
def test_uniform_partition_rejects_bad_set_counts(n_sets):
    with pytest.raises(TwinError):
        uniform_partition(n_sets)


def test_uniform_partition_accepts_fou_just_below_half():
    part = uniform_partition(7, 0.499)
    lo, up = part.memberships(np.linspace(-1.2, 1.2, 241))
    assert np.all(lo <= up) and np.all(lo.sum(axis=-1) > 0)  # every input fires some lower bound


@pytest.mark.parametrize("args", [
    (0.0, 0.0, 1.0),      # left == peak
    (0.5, 0.0, 1.0),      # left > peak
    (-1.0, 1.0, 1.0),     # peak == right
    (-1.0, 2.0, 1.0),     # peak > right
    (-INF, INF, INF),     # infinite peak
    (-1.0, math.nan, 1.0),
    (math.nan, 0.0, 1.0),
    (-1.0, 0.0, math.nan),
])
def test_triangle_rejects_bad_geometry(args):
    with pytest.raises(TwinError):
        Triangle(*args)


@pytest.mark.parametrize("height", [0.0, -0.5, 1.5])
def test_triangle_rejects_bad_height(height):
    with pytest.raises(TwinError, match="height"):
        Triangle(-1.0, 0.0, 1.0, height=height)


@pytest.mark.parametrize("lower, upper", [
    (Triangle(-1.0, 0.0, 1.0), Triangle(-0.5, 0.0, 0.5)),              # wider support
    (Triangle(-1.0, 0.0, 1.0), Triangle(-1.0, 0.0, 1.0, height=0.5)),  # higher
    (Triangle(-0.5, 0.2, 0.9), Triangle(-1.0, 0.0, 1.0)),              # shifted peak pokes out
    (Triangle(-INF, 0.0, 0.5), Triangle(-20.0, 0.0, 1.0)),             # shoulder beyond upper's foot
])
def test_it2_set_rejects_lower_above_upper(lower, upper):
    with pytest.raises(TwinError, match="lower"):
        IT2Set("X", lower=lower, upper=upper)


def test_it2_set_accepts_nested_and_equal_functions():
    t = Triangle(-1.0, 0.0, 1.0)
    IT2Set("eq", lower=t, upper=t)
    IT2Set("nested", lower=Triangle(-0.5, 0.0, 0.5, height=0.7), upper=t)


def test_partition_needs_two_sets():
    t = Triangle(-1.0, 0.0, 1.0)
    with pytest.raises(TwinError):
        Partition([IT2Set("only", t, t)])


def test_mamdani_rejects_bad_configuration():
    part3, part7 = uniform_partition(3), uniform_partition(7)
    centres = [-1.0, 0.0, 1.0]
    good = [[2, 1, 0], [1, 0, 0], [0, 0, 0]]
    MamdaniFLS(part3, part3, centres, good)  # the valid baseline builds
    with pytest.raises(TwinError, match=r"shape \(3, 3\)"):
        MamdaniFLS(part3, part3, centres, [[0, 1], [1, 2]])
    with pytest.raises(TwinError, match=r"shape \(3, 7\)"):
        MamdaniFLS(part3, part7, centres, good)
    with pytest.raises(TwinError, match="type reduction"):
        MamdaniFLS(part3, part3, centres, good, type_reduction="centroid")
    with pytest.raises(TwinError, match="type reduction"):
        MamdaniFLS(part3, part3, centres, good, type_reduction="BMM")
    with pytest.raises(TwinError, match="integer indices"):
        MamdaniFLS(part3, part3, centres, [[3, 1, 0], [1, 0, 0], [0, 0, 0]])
    with pytest.raises(TwinError, match="integer indices"):
        MamdaniFLS(part3, part3, centres, [[-1, 1, 0], [1, 0, 0], [0, 0, 0]])
    with pytest.raises(TwinError, match="integer indices"):
        MamdaniFLS(part3, part3, centres, np.array(good, dtype=float))
    with pytest.raises(TwinError, match="BMM weight m"):
        MamdaniFLS(part3, part3, centres, good, m=-0.1)
    with pytest.raises(TwinError, match="BMM weight n"):
        MamdaniFLS(part3, part3, centres, good, n=math.nan)
    with pytest.raises(TwinError, match="both be zero"):
        MamdaniFLS(part3, part3, centres, good, m=0.0, n=0.0)


def test_controller_factories_reject_bad_arguments():
    with pytest.raises(TwinError, match="kind"):
        table_ii_fls("t3")
    with pytest.raises(TwinError, match="type reduction"):
        position_controller("it2", type_reduction="ekm")
    with pytest.raises(TwinError, match="fou"):
        position_controller("it2", fou=0.6)
    for bad in (0.0, -1.0, math.inf, "0.1"):
        with pytest.raises(TwinError, match="u_alpha_max"):
            direction_controller(u_alpha_max=bad)
    assert issubclass(TwinError, ValueError)


# ---------------------------------------------------------------------------------------
# 8. monotonicity and sign convention along the ZO column
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["position", "direction"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("reducer", REDUCERS)
def test_output_non_increasing_in_error_along_zo_column(which, kind, reducer):
    r1, _, out = ranges(which)
    ctrl = controller(which, kind, reducer)
    e = np.linspace(-1.7 * r1, 1.7 * r1, 681)
    z = ctrl.evaluate(e, 0.0)
    assert np.all(np.diff(z) <= 1e-15 * out)
    # sign convention (error = actual − target): short of the target → positive output
    assert np.all(z[e < 0] > 0) and np.all(z[e > 0] < 0)
    assert z[0] > 0.8 * out and z[-1] < -0.8 * out
    # the scalar call agrees on the sign for small errors too
    assert ctrl(-1e-3 * r1, 0.0) > 0 > ctrl(1e-3 * r1, 0.0)


def test_position_controller_sign_convention_in_physical_units():
    ctrl = position_controller()
    # the robot is 1 m short of its target (p_e = p − p_d = −1 m) and at rest: lean forward
    assert 0 < ctrl(-1.0, 0.0) <= THETA_OFF_RANGE
    # at the target but pitching at θ̇ = +4 rad/s: Table II row ZO, column PB → NB, a negative offset
    assert ctrl(0.0, 4.0) < 0
