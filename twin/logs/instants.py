"""The control instants of a log's replay, and the instant a time falls on.

A replay's instants are the grid t_0 + k / control_rate, or the log's command rows themselves
when they lie off any regular grid (:func:`rows_clock`); :func:`instants_of` puts times (a
truth's rows) on them. Both the replay (:mod:`twin.logs.replay`) and its diagnostics
(:mod:`twin.logs.diagnostics`: the NEES truth rows) need this, so it lives below both.
"""
from __future__ import annotations

import numpy as np

from twin.logs.format import SensorLog

OFF_GRID = 0.01  # of a control period: command rows this far off t_0 + k / control_rate are instants of their own


def rows_clock(log: SensorLog) -> bool:
    """Whether ``log``'s instants are its command rows rather than the grid t_0 + k / control_rate:
    some command row lies more than :data:`OFF_GRID` of a period off the grid (a logger whose
    rows come 30–33 ms apart). The twin's logs, and any log on a regular clock, are on the grid."""
    t = log.commands_t
    if len(t) < 2:
        return False
    x = (t - t[0]) * log.control_rate
    return bool(np.max(np.abs(x - np.round(x))) > OFF_GRID)


def instants_of(log: SensorLog, t: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(j,) int: the instant of ``t`` (the replay's) nearest each of ``times`` (s), by the grid's
    arithmetic where the replay is on it (the same numbers as ever), else by search; may lie
    outside 0 … len(t) − 1 on the grid (callers test it)."""
    if not rows_clock(log):
        return np.round((times - t[0]) * log.control_rate).astype(np.int64)
    i = np.clip(np.searchsorted(t, times), 1, max(len(t) - 1, 1))
    if len(t) < 2:
        return np.zeros(len(times), dtype=np.int64)
    return np.where(np.abs(times - t[i - 1]) <= np.abs(t[i] - times), i - 1, i).astype(np.int64)
