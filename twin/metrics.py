"""Metrics shared by every run, whatever the plant."""
from __future__ import annotations

import math

import numpy as np


def settling_time(t: np.ndarray, theta: np.ndarray, tol: float = 0.01) -> float:
    """First time (s) after which |θ| stays below ``tol`` rad; inf if it never does."""
    bad = np.nonzero(~(np.abs(theta) < tol))[0]
    if len(bad) == 0:
        return float(t[0])
    if bad[-1] == len(t) - 1:
        return math.inf
    return float(t[bad[-1] + 1])
