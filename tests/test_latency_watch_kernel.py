"""The latency watch's check compiled (estimation._ekf.watch_rho) is the NumPy check
(LatencyWatch.correlations), bit for bit: on random windows with missing rows, spikes the
check winsorises, repeated values (median ties) and windows with too few rows."""
from __future__ import annotations

import numpy as np
import pytest

from estimation import ekf_policies as pol
from estimation.ekf_core import _kernel

needs_kernel = pytest.mark.skipif(_kernel is None, reason="the compiled EKF kernel is not built")
N = pol.WATCH_WINDOW + pol.WATCH_MAX_LAG + 5


def _window(rng, missing: float, spikes: int, ties: bool):
    y = rng.standard_normal(N) * 10 ** rng.uniform(-4, 0)
    if ties:
        y = np.round(y, 2)
    y[rng.random(N) < missing] = np.nan
    y[rng.integers(0, N, spikes)] += rng.choice([-1, 1], spikes) * 50.0
    u = rng.standard_normal(N) * 10 ** rng.uniform(-3, 0)
    return y.tolist(), u.tolist()


@needs_kernel
@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_check_is_the_numpy_check_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    compared = nones = 0
    for trial in range(300):
        y, u = _window(rng, missing=rng.choice([0.0, 0.05, 0.4, 0.6]), spikes=int(rng.integers(0, 4)),
                       ties=bool(rng.integers(0, 2)))
        sign = float(rng.choice([-1.0, 1.0]))
        watch = pol.LatencyWatch(sign)
        watch.y, watch.u = y, u
        ref = watch.correlations()
        got = _kernel.watch_rho(y, u, pol.WATCH_WINDOW, pol.WATCH_MAX_LAG, pol.WATCH_CLIP, sign)
        if ref is None:
            assert got is None
            nones += 1
            continue
        assert got is not None and len(got) == pol.WATCH_MAX_LAG + 1
        assert np.array_equal(np.asarray(got), ref), (trial, np.max(np.abs(np.asarray(got) - ref)))
        compared += 1
    assert compared >= 100 and nones >= 10  # both kinds of window were seen


@needs_kernel
def test_a_bad_call_is_an_error_not_a_crash():
    with pytest.raises(ValueError, match="must have"):
        _kernel.watch_rho([0.0] * 3, [0.0] * N, pol.WATCH_WINDOW, pol.WATCH_MAX_LAG, pol.WATCH_CLIP, 1.0)
    with pytest.raises(ValueError, match="out of range"):
        _kernel.watch_rho([0.0] * 5000, [0.0] * 5000, 4000, 20, 5.0, 1.0)
