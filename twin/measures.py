"""Figures of merit on sampled signals, exactly rounded: a mean by ``math.fsum`` and the settling
time of θ. Of no domain (NumPy arrays in, floats out), so that a run (:mod:`twin.sim.runs`)
and the metrics of its results (:mod:`twin.outputs.metrics`, which names these too) compute
them the same way.
"""
from __future__ import annotations

import math

import numpy as np


def exact_mean(x: np.ndarray) -> float:
    """The mean of ``x`` with an exactly rounded sum (``math.fsum``). numpy's SIMD sums can depend
    on where the array sits in memory, which breaks bit-identical replays across processes."""
    return math.fsum(np.ravel(x).tolist()) / x.size


def settling_time(t: np.ndarray, theta: np.ndarray, tol: float = 0.01) -> float:
    """First time (s) after which |θ| stays below ``tol`` rad; inf if it never does."""
    bad = np.nonzero(~(np.abs(theta) < tol))[0]
    if len(bad) == 0:
        return float(t[0])
    if bad[-1] == len(t) - 1:
        return math.inf
    return float(t[bad[-1] + 1])
