"""An estimator's diagnostics over a replay, kept as it goes: arrays of what the figures need.

``twin replay`` asks the estimator for its ``diagnostics()`` at every control instant
(:class:`twin.protocols.Estimator`). The EKF's holds its 12 states and their 12 × 12
covariance: kept as dicts, 2 kB an instant, a 10⁶-instant log needed gigabytes.
:class:`DiagnosticsLog` keeps, per instant, only the numbers the replay's figures are made of
(NIS, its degrees of freedom, the lag, the normalised innovation where there was one, and the
NEES where the log has the state truth), and computes the NEES a block of
:data:`NEES_BLOCK` instants at a time: the states and covariances wait in a buffer of that many
rows, then each row's NEES is solved (:func:`estimation.detlinalg.quad_inv_rows`, whose value
for a row depends on that row alone) and the buffer is reused.

The figures come out of the very arithmetic of :func:`twin.logs.replay.consistency` and
:func:`estimation.consistency.monte_carlo` on the same arrays, so they are the same to the bit
(``tests/test_replay_consistency.py``): the NEES of each row as
:func:`estimation.consistency.nees` computes it (the filter's own time from the lag in force,
:func:`estimation.consistency.filter_rows`; the truth's 12 states of that row,
:func:`estimation.consistency.state_matrix`), and the same means over the same arrays.
"""
from __future__ import annotations

import array
import bisect
import math
from collections.abc import Sequence

import numpy as np

from estimation.consistency import TruthConstants, nees_rows, truth_rows
from twin.errors import PluginError
from twin.logs.instants import instants_of

NEES_BLOCK = 1024  # instants whose states and covariances wait for their NEES (1.25 MB of them)
_DIM = 12  # the EKF's states: the state truth of a log has 12 (estimation.consistency.DIM)


def _number(v, default: float) -> float:
    """A diagnostics value as the replay's arrays hold it (``np.array([...], float)`` did: None
    and what is no number become NaN)."""
    if v is None:
        return math.nan
    try:
        return float(v)
    except (TypeError, ValueError):
        return default


def normalised_innovation(who: str, t: float, y, S) -> float | None:
    """The sum of an update's whitened innovation over √m (a standard normal number for an honest
    filter), from its ``innovation`` ``y`` (m,) and ``innovation_cov`` ``S`` (m, m) reported at
    ``t`` s by estimator ``who``; None for an empty update; a one-line PluginError for a misshapen,
    non-finite or not positive definite one."""
    y = np.atleast_1d(np.asarray(y, float))
    S = np.atleast_2d(np.asarray(S, float))
    if y.size == 0:
        return None
    if S.shape != (y.size, y.size) or not np.isfinite(y).all() or not np.isfinite(S).all():
        raise PluginError(f"estimator {who}: diagnostics() at t = {t:.3f} s: innovation {y.shape} and "
                          f"innovation_cov {S.shape}; allowed: finite (m,) and (m, m) (see twin.protocols.Estimator)")
    w = _whitened(S, y)
    if w is None:
        raise PluginError(f"estimator {who}: diagnostics() at t = {t:.3f} s: innovation_cov is not positive "
                          f"definite; allowed: a covariance (symmetric, positive definite)")
    return math.fsum(w) / math.sqrt(y.size)


def _whitened(S: np.ndarray, y: np.ndarray) -> list | None:
    """L⁻¹ y with S = L Lᵀ (Cholesky, lower triangle of S), or None if S is not positive definite.
    Written out in one fixed order of operations, not LAPACK's: the NIS whiteness in replay.json
    is then the same bits on every CPU (an innovation has a handful of components)."""
    m = len(y)
    L = [[0.0] * m for _ in range(m)]
    w = [0.0] * m
    for i in range(m):
        for j in range(i + 1):
            acc = float(S[i, j]) - math.fsum(L[i][k] * L[j][k] for k in range(j))
            if i == j:
                if not acc > 0.0:
                    return None
                L[i][i] = math.sqrt(acc)
            else:
                L[i][j] = acc / L[j][j]
        w[i] = (float(y[i]) - math.fsum(L[i][k] * w[k] for k in range(i))) / L[i][i]
    return w


class DiagnosticsLog(Sequence):
    """The diagnostics of one estimator's replay of one log, instant by instant (:meth:`add`).

    As a sequence, item k is a dict of what was kept of ``diagnostics()`` at instant k:
    ``nis``, ``nis_dof``, ``lag`` (where reported) and, where the estimator reported an
    update's ``innovation`` and ``innovation_cov``, those two (arrays); not the states ``x``
    and covariance ``P``, which only the NEES needs (:attr:`nees`).

    Arrays (N instants): :meth:`nis` and :meth:`nis_dof` (NaN and 0 where none);
    :meth:`innovations` (t, s) the normalised innovation s = 1ᵀL⁻¹y/√m of each update and its
    instant; :attr:`nees` (N,) the NEES of each instant (NaN where undefined) where ``log``
    has the state truth and the estimator reported a 12-state ``x``, ``P`` and ``lag`` at
    every instant, else None."""

    def __init__(self, who: str, log=None, t: np.ndarray | None = None):
        self.who = who
        self._nis = array.array("d")
        self._dof = array.array("d")
        self._lag = array.array("q")  # -1: not reported
        self._updates = array.array("q")  # the instant of each update with an innovation
        self._dims = array.array("q")  # its m
        self._starts = array.array("q")  # where its y (m) then S (m × m) begin in _values
        self._values = array.array("d")
        self._s = array.array("d")
        self._s_t = array.array("d")
        self._nees = None
        self._truth = _StateTruthRows.of(log, t) if log is not None and t is not None else None
        if self._truth is not None:
            self._nees = array.array("d")
            self._states = np.empty((NEES_BLOCK, _DIM + _DIM * _DIM))
            self._pending_lags = []
            self._f = 0  # the filter's own time (an instant) at the last row whose NEES is solved
        self._done = False

    # ---- filled while the replay goes ------------------------------------------------------------
    def add(self, t: float, d) -> None:
        """Instant number ``len(self)``, at ``t`` s: the estimator's ``diagnostics()`` ``d``."""
        k = len(self._nis)
        if not isinstance(d, dict):
            d = {}
        self._nis.append(_number(d.get("nis", math.nan), math.nan))
        self._dof.append(_number(d.get("nis_dof", 0), 0.0))
        lag = d.get("lag")
        self._lag.append(int(lag) if isinstance(lag, (int, np.integer)) else -1)
        if "innovation" in d and "innovation_cov" in d:
            self._innovation(k, t, d["innovation"], d["innovation_cov"])
        if self._nees is not None:
            self._state(d)

    def _innovation(self, k: int, t: float, y, S) -> None:
        """As :func:`twin.logs.replay.normalised_innovations` reads an update (the same checks,
        the same arithmetic)."""
        y = np.atleast_1d(np.asarray(y, float))
        S = np.atleast_2d(np.asarray(S, float))
        value = normalised_innovation(self.who, t, y, S)
        if value is None:  # an empty update: nothing was tried
            return
        self._s_t.append(t)
        self._s.append(value)
        self._updates.append(k)
        self._dims.append(y.size)
        self._starts.append(len(self._values))
        self._values.extend(y.ravel().tolist())
        self._values.extend(S.ravel().tolist())

    def _state(self, d: dict) -> None:
        """The row's x and P into the NEES buffer; an instant without them ends the NEES (as
        :func:`twin.logs.replay.filter_record` asks for them at every instant)."""
        x, P, lag = d.get("x"), d.get("P"), d.get("lag")
        try:
            x = np.asarray(x, float)
            P = np.asarray(P, float)
        except (TypeError, ValueError):
            x = P = None
        if x is None or x.shape != (_DIM,) or P.shape != (_DIM, _DIM) or not isinstance(lag, (int, np.integer)):
            self._nees = None  # no NEES for this replay: let the buffer go
            self._states = self._pending_lags = None
            return
        j = len(self._pending_lags)
        self._states[j, :_DIM] = x
        self._states[j, _DIM:] = P.ravel()
        self._pending_lags.append(int(lag))
        if j + 1 == NEES_BLOCK:
            self._flush()

    def _flush(self) -> None:
        if self._nees is None:
            return
        lags = self._pending_lags
        m = len(lags)
        if not m:
            return
        i0 = len(self._nees)
        f = np.maximum.accumulate(np.maximum(np.arange(i0, i0 + m, dtype=np.int64) - np.array(lags, np.int64),
                                             self._f))
        ok = f >= 1
        truth = np.full((m, _DIM), np.nan)
        if ok.any():
            truth[ok] = self._truth.states(f[ok])
        state = self._states[:m]
        self._nees.extend(nees_rows(state[:, :_DIM], state[:, _DIM:].reshape(m, _DIM, _DIM), truth).tolist())
        self._f = int(f[-1])
        lags.clear()

    def finish(self) -> "DiagnosticsLog":
        """The last block's NEES solved: call once the replay is over."""
        if not self._done:
            self._flush()
            self._done = True
            self._states = None
        return self

    # ---- read afterwards ---------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._nis)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        n = len(self)
        if k < 0:
            k += n
        if not 0 <= k < n:
            raise IndexError("DiagnosticsLog index out of range")
        d = {"nis": self._nis[k], "nis_dof": int(self._dof[k]) if self._dof[k].is_integer() else self._dof[k]}
        if self._lag[k] >= 0:
            d["lag"] = self._lag[k]
        u = bisect.bisect_left(self._updates, k)
        if u < len(self._updates) and self._updates[u] == k:
            m, a = self._dims[u], self._starts[u]
            d["innovation"] = np.array(self._values[a:a + m])
            d["innovation_cov"] = np.array(self._values[a + m:a + m + m * m]).reshape(m, m)
        return d

    def nis(self) -> np.ndarray:
        """(N,) the NIS at each instant (NaN where none was reported)."""
        return np.frombuffer(self._nis, dtype=float) if len(self._nis) else np.empty(0)

    def nis_dof(self) -> np.ndarray:
        """(N,) float: its degrees of freedom (0 where no update was tried)."""
        return np.frombuffer(self._dof, dtype=float) if len(self._dof) else np.empty(0)

    def innovations(self) -> tuple[np.ndarray, np.ndarray]:
        """(t (U,) s, s (U,)): each update's normalised innovation and its instant."""
        return np.array(self._s_t, dtype=float), np.array(self._s, dtype=float)

    @property
    def nees(self) -> np.ndarray | None:
        self.finish()
        return None if self._nees is None else np.array(self._nees, dtype=float)

    def record(self, t: np.ndarray):
        """What the Monte Carlo tests over several logs need of this replay (:class:`NeesRecord`),
        or None without the NEES. ``t`` (N,) s the replay's instants."""
        nees = self.nees
        if nees is None:
            return None
        return NeesRecord(np.asarray(t) - t[0], nees, self.nis().copy(), self.nis_dof().astype(int), _DIM)


class NeesRecord:
    """One replay's NEES and NIS per instant for :func:`monte_carlo` (``t`` from the first instant, s)."""

    def __init__(self, t, nees, nis, nis_dof, dim):
        self.t, self.nees, self.nis, self.nis_dof, self.dim = t, nees, nis, nis_dof, dim


class _StateTruthRows:
    """A log's state truth on the replay's instants, handed out a few rows at a time: the 12
    true states of instants f (:meth:`states`), as :func:`estimation.consistency.state_matrix`
    computes them for the whole run (elementwise: the same bits)."""

    def __init__(self, log, rows: np.ndarray):

        c, sensors, model = log.truth_constants, log.sensors, log.model
        self.constants = TruthConstants(tuple(c["gyro_scale"]), tuple(c["accel_scale"]), tuple(c["encoder_phase"]),
                                        tuple(sensors.imu.position), float(c["wheel_radius"]),
                                        float(model.b / model.r), float(sensors.encoders.resolution))
        self.truth, self.state, self.rows = log.truth, log.truth_state, rows
        r0 = rows[0]
        th0 = self.truth[r0, 0]
        self.ref = (float(self.state[r0, 0] - th0), float(self.state[r0, 1] - th0), float(self.truth[r0, 4]))

    @classmethod
    def of(cls, log, t: np.ndarray):
        """The log's truth rows at the instants ``t`` (as :func:`twin.logs.replay.state_truth`
        finds them; -1 at an instant without one: a truth at a lower rate), or None unless it has
        the state truth at the first instant (the encoder zeros' reference)."""
        if log.truth is None or log.truth_state is None or log.truth_constants is None or not len(t):
            return None
        k = instants_of(log, t, log.truth_t)
        inside = (k >= 0) & (k < len(t))
        k = np.where(inside, k, 0).astype(np.int64)
        on = inside & np.isclose(t[k], log.truth_t, atol=1e-9, rtol=0)
        rows = np.full(len(t), -1, dtype=np.int64)
        rows[k[on]] = np.flatnonzero(on)  # the last truth row at an instant, as for the readings
        if rows[0] < 0:
            return None
        return cls(log, rows)

    def states(self, f: np.ndarray) -> np.ndarray:
        """The 12 true states (m, 12) of instants ``f``; NaN at an instant without a truth row."""
        r = self.rows[f]
        ok = r >= 0
        if not ok.all():
            out = np.full((len(f), _DIM), np.nan)
            if ok.any():
                out[ok] = self.states(f[ok])
            return out
        tr, st = self.truth[r], self.state[r]
        return truth_rows(self.constants, self.ref, tr[:, 0], tr[:, 1], st[:, 0], st[:, 1], tr[:, 2], tr[:, 3],
                           tr[:, 4], st[:, 3], st[:, 4])


def monte_carlo(runs, start: float = 0.0, confidence: float = 0.95) -> dict:
    """:func:`estimation.consistency.monte_carlo` on :class:`NeesRecord` s, statement for
    statement (the same arrays through the same numpy calls: the same bits; the test of the
    replay against the runs holds the two together)."""
    from scipy.stats import chi2
    from scipy.stats import t as t_dist

    n = min(len(r.t) for r in runs)
    keep = runs[0].t[:n] >= start - 1e-9
    E = np.array([r.nees[:n] for r in runs])[:, keep]
    rows = np.isfinite(E).all(axis=0)
    E = E[:, rows]
    if not E.shape[1]:  # no instant with every run's NEES (truths at other times): no statement
        return None
    N, dim = len(runs), runs[0].dim
    a = 0.5 * (1.0 - confidence)
    lo, hi = chi2.ppf([a, 1.0 - a], N * dim) / N
    mean = E.mean(axis=0)
    per_run = E.mean(axis=1)
    half = t_dist.ppf(1.0 - a, N - 1) * per_run.std(ddof=1) / math.sqrt(N)
    nis = np.array([np.nan_to_num(r.nis[:n]) for r in runs])[:, keep].sum(axis=0)
    dof = np.array([r.nis_dof[:n] for r in runs])[:, keep].sum(axis=0)
    used = dof > 0
    nlo, nhi = chi2.ppf(a, dof[used]), chi2.ppf(1.0 - a, dof[used])
    return {"runs": N, "dim": dim, "rows": int(E.shape[1]), "nees": mean, "nees_bounds": (float(lo), float(hi)),
            "nees_inside": float(np.mean((mean >= lo) & (mean <= hi))), "nees_mean": float(E.mean()),
            "nees_run_means": per_run,
            "nees_mean_interval": (float(per_run.mean() - half), float(per_run.mean() + half)),
            "nis_inside": float(np.mean((nis[used] >= nlo) & (nis[used] <= nhi))),
            "nis_per_dof": float(nis[used].sum() / dof[used].sum()) if used.any() else math.nan}


__all__ = ["DiagnosticsLog", "NEES_BLOCK", "NeesRecord", "monte_carlo"]
