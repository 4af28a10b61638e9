"""The compiled Mamdani kernel must equal the pure-Python path bit for bit."""
import math
import os

import numpy as np
import pytest

from twin.controllers.mamdani import OUTPUT_CENTRES, RULE_INDEX, table_ii_fls
from twin.fuzzy import mamdani
from twin.fuzzy.mamdani import MamdaniFLS
from twin.fuzzy.sets import IT2Set, Partition, Triangle, uniform_partition

PURE = os.environ.get("TWIN_PURE_PYTHON", "") not in ("", "0")


def twins(fls: MamdaniFLS) -> tuple[MamdaniFLS, MamdaniFLS]:
    args = (fls.input1, fls.input2, fls.output_centres, fls.rule_table, fls.type_reduction, fls.m, fls.n)
    return MamdaniFLS(*args, compiled=True), MamdaniFLS(*args, compiled=False)


def inputs(seed=3, n=20000):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.4, 1.4, (n, 2))
    knots = np.array([k / 3 + d for k in range(-3, 4) for d in (0.0, 1 / 12, -1 / 12, 0.25 / 3)])
    grid = np.array([(a, b) for a in knots for b in knots])
    return np.vstack([x, grid, [[1.0, 1.0], [-1.0, -1.0], [1e6, -1e6]]])


@pytest.mark.skipif(PURE or (mamdani._kernel is None and not os.environ.get("TWIN_REQUIRE_KERNEL")),
                    reason="compiled kernel not built here (no C compiler?); CI sets TWIN_REQUIRE_KERNEL=1")
def test_kernel_is_built():
    assert mamdani._kernel is not None, "the compiled kernel twin.fuzzy._kernel was not built"
    assert table_ii_fls().compiled
    assert not table_ii_fls(type_reduction="km").compiled  # KM stays in numpy


@pytest.mark.skipif(PURE or mamdani._kernel is None, reason="compiled kernel not available")
@pytest.mark.parametrize("kind", ["it2", "t1"])
@pytest.mark.parametrize("reducer", ["bmm", "nt"])
def test_compiled_equals_pure_python_exactly(kind, reducer):
    fast, slow = twins(table_ii_fls(kind, type_reduction=reducer))
    x = inputs()
    a = np.array([fast.evaluate_scalar(float(u), float(v)) for u, v in x])
    b = np.array([slow.evaluate_scalar(float(u), float(v)) for u, v in x])
    assert np.array_equal(a, b)
    # the compiled batch path is the same kernel; numpy's fallback sums in another order
    assert np.array_equal(fast.evaluate(x[:, 0], x[:, 1]), a)
    assert np.allclose(slow.evaluate(x[:, 0], x[:, 1]), a, rtol=0, atol=1e-14)


@pytest.mark.skipif(PURE or mamdani._kernel is None, reason="compiled kernel not available")
def test_compiled_general_partition_with_heights_and_asymmetric_sets():
    sets = [
        IT2Set("L", Triangle(-math.inf, -0.5, 0.1, 0.8), Triangle(-math.inf, -0.4, 0.4)),
        IT2Set("M", Triangle(-0.3, 0.1, 0.3, 0.5), Triangle(-0.6, 0.1, 0.7)),
        IT2Set("H", Triangle(0.2, 0.7, math.inf), Triangle(-0.1, 0.6, math.inf)),
    ]
    p = Partition(sets)
    fls = MamdaniFLS(p, uniform_partition(5, 0.3), [-1.0, -0.2, 0.5, 1.0],
                     np.array([[0, 1, 2, 3, 3], [0, 0, 1, 2, 3], [1, 2, 2, 3, 0]]), m=0.3, n=0.7)
    fast, slow = twins(fls)
    x = inputs(5, 5000)
    a = [fast.evaluate_scalar(float(u), float(v)) for u, v in x]
    b = [slow.evaluate_scalar(float(u), float(v)) for u, v in x]
    assert a == b


def test_batch_keeps_shape_and_rejects_nan():
    fls = table_ii_fls()
    out = fls.evaluate(np.zeros((3, 4)), np.linspace(-1, 1, 4))
    assert out.shape == (3, 4)
    with pytest.raises(Exception, match="finite"):
        fls.evaluate(np.array([0.0, np.nan]), 0.0)
    with pytest.raises(Exception, match="finite"):
        fls.evaluate_scalar(math.inf, 0.0)


def test_rule_table_used_by_kernel_is_table_ii():
    # a changed consequent must change the compiled output: the kernel reads the table
    table = RULE_INDEX.copy()
    table[3, 3] = 6  # ZO/ZO -> PB
    changed = MamdaniFLS(uniform_partition(7, 0.25), uniform_partition(7, 0.25), OUTPUT_CENTRES, table)
    # lower: only ZO/ZO fires (1, y = 1); upper: ZO/ZO (1, y = 1) and its 8 neighbours at
    # 0.2 with consequents summing to 0, so the upper term is 1/2.6; BMM: 0.5 + 0.5/2.6
    assert changed.evaluate_scalar(0.0, 0.0) == pytest.approx(0.5 + 0.5 / 2.6, abs=1e-15)
    assert abs(table_ii_fls().evaluate_scalar(0.0, 0.0)) < 1e-15


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("reducer", ["bmm", "nt", "km"])
def test_no_rule_firing_is_a_clear_error_in_every_path(compiled, reducer):
    """Sets with a gap between them: no NaN may come out, whatever the path."""
    from twin.errors import TwinError

    gap = Partition([IT2Set("L", Triangle(-math.inf, -1.0, -0.5), Triangle(-math.inf, -1.0, -0.4)),
                     IT2Set("H", Triangle(0.5, 1.0, math.inf), Triangle(0.4, 1.0, math.inf))])
    fls = MamdaniFLS(gap, gap, [-1.0, 1.0], np.array([[1, 1], [0, 0]]), type_reduction=reducer,
                     compiled=compiled)
    assert fls.evaluate_scalar(-1.0, 1.0) == pytest.approx(1.0)
    with pytest.raises(TwinError, match="no rule fires at the inputs"):
        fls.evaluate_scalar(0.0, 0.0)
    with pytest.raises(TwinError, match="no rule fires at the inputs"):
        fls.evaluate(np.array([-1.0, 0.0]), np.array([1.0, 0.0]))


def test_mismatched_batch_shapes_are_a_clear_error():
    from twin.errors import TwinError

    with pytest.raises(TwinError, match="broadcast"):
        table_ii_fls().evaluate(np.zeros(3), np.zeros(4))
