"""Is the EKF's covariance honest? Its true state from a twin run, NEES, NIS and the
Monte Carlo χ² tests of Bar-Shalom, Li and Kirubarajan (2001, §5.4).

For one run, the normalised estimation error squared NEES_k = e_kᵀ P_k⁻¹ e_k (e the
filter's state minus the truth) is χ² with n = 12 degrees of freedom if the filter is
consistent; the normalised innovation squared NIS_k of the encoder update is χ² with as
many degrees of freedom as wheels whose count changed. Over N independent runs the
averages at each step, N·NEES̄_k ~ χ²_{N n} and Σ NIS_k ~ χ²_{Σ dof}, have two-sided
bounds; a consistent filter keeps about the confidence level of the steps inside them.

One run's summary (:func:`summary`, and :class:`RunningConsistency`, which computes the same
figures while the run goes, in memory that does not grow with its length): the mean NEES over
the rows from :data:`NEES_START` s on, against :data:`ONE_RUN_NEES_BOUNDS`, and the NIS per
degree of freedom of the encoder updates (``twin run``'s metrics.json, "estimator").

The same bits on every CPU: no BLAS or LAPACK here (:func:`estimation.detlinalg.quad_inv_rows`
solves, sines and cosines come from the C library as the filter's own), and sums are
exactly rounded (``math.fsum``) within fixed blocks of :data:`SUM_BLOCK` rows.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import chain

import numpy as np

from estimation.detlinalg import quad_inv_rows
from estimation.ekf_steps import STATE_NAMES
from twin.errors import TwinError

NEES_START = 0.5  # s: one run's summary leaves out the start-up transient of the encoder zeros
SUM_BLOCK = 1024  # rows: the summary's sums are exact within each block of rows (by row index), then over blocks
DIM = 12  # the EKF's states
# the two-sided 95 % interval of χ² with 12 degrees of freedom (one row's NEES if the filter is
# consistent): float(scipy.stats.chi2.ppf([0.025, 0.975], 12)), scipy 1.17.1, tested against scipy.
# The reference for one run's time-averaged NEES (see summary()).
ONE_RUN_NEES_BOUNDS = (float.fromhex("0x1.19d7abbfff2c4p+2"), float.fromhex("0x1.7562f9f4f1dfap+4"))


@dataclass(frozen=True)
class TruthConstants:
    """The constants of a :class:`StateTruth` (what does not change from row to row), for
    :class:`RunningConsistency`, which gets the rows one at a time."""

    gyro_scale: tuple
    accel_scale: tuple
    encoder_phase: tuple
    imu_position: tuple
    wheel_radius: float
    b_over_r: float
    resolution: float


@dataclass(frozen=True)
class StateTruth(TruthConstants):
    """What the EKF's 12-state truth is computed from, on the rows of a run or a log (n rows,
    one per control instant, row 0 the filter's start).

    ``theta``, ``theta_dot``, ``psi_l``, ``psi_r``, ``psi``, ``psi_dot``, ``alpha`` (n,) rad and
    rad/s (wheel angles ψ_l, ψ_r absolute, as the plant's); ``gyro_bias`` (n, 3) rad/s the gyro's
    true bias in the sample taken at each row (NaN without one); the sensors' drawn constants
    ``gyro_scale`` (3,) and ``accel_scale`` (3,) (dimensionless scale-factor errors) and
    ``encoder_phase`` (2,) (where each encoder's first edge lies, in counts); ``imu_position``
    (3,) m; ``wheel_radius`` m the plant's (true) radius; ``b_over_r`` the estimator model's
    half track over wheel radius; ``resolution`` rad per encoder count (those seven, the
    constants, are :class:`TruthConstants`' fields)."""

    theta: np.ndarray
    theta_dot: np.ndarray
    psi_l: np.ndarray
    psi_r: np.ndarray
    psi: np.ndarray
    psi_dot: np.ndarray
    alpha: np.ndarray
    gyro_bias: np.ndarray
    @property
    def constants(self) -> "TruthConstants":
        return TruthConstants(tuple(self.gyro_scale), tuple(self.accel_scale), tuple(self.encoder_phase),
                              tuple(self.imu_position), float(self.wheel_radius), float(self.b_over_r),
                              float(self.resolution))


def run_truth(run) -> StateTruth:
    """The :class:`StateTruth` of a twin run (simulated sensors and a gyro-bias record)."""
    if run.sensor_config is None or not run.sensor_truth or run.gyro_bias is None:
        raise TwinError("the EKF's state truth needs a run with simulated sensors (sensing = \"estimated\")")
    st, cfg, mp = run.sensor_truth, run.sensor_config, run.model_params
    col = {n: run.signal(n) for n in ("theta", "theta_dot", "psi_l", "psi_r", "psi", "psi_dot", "alpha")}
    return StateTruth(**col, gyro_bias=run.gyro_bias, gyro_scale=tuple(st["gyro_scale"]),
                      accel_scale=tuple(st["accel_scale"]), encoder_phase=tuple(st["encoder_phase"]),
                      imu_position=tuple(cfg.imu.position), wheel_radius=float(run.config.params.r),
                      b_over_r=float(mp.b / mp.r), resolution=float(cfg.encoders.resolution))


@dataclass
class FilterRecord:
    """A filter's record that is not a :class:`twin.sim.runs.Run` (for example a replay of a
    sensor log): control instants ``t`` (n,) s, ``filter_log`` as ``Run.filter_log`` (``x``
    (n, 12), ``P`` (n, 12, 12), ``nis`` (n,), ``nis_dof`` (n,), ``lag`` (n,) the lag in force
    at each row in periods, or one number for all) and the :class:`StateTruth` on the same
    rows (None: no NEES, NIS only)."""

    t: np.ndarray
    filter_log: dict
    truth: StateTruth | None = None


def _truth_of(source) -> StateTruth:
    if isinstance(source, FilterRecord):
        if source.truth is None:
            raise TwinError("NEES needs the EKF's state truth, which this record does not have")
        return source.truth
    return run_truth(source)


def filter_truth(source) -> np.ndarray:
    """The true value of each EKF state (n, 12) on the rows of ``source.filter_log["x"]``;
    ``source`` a :class:`twin.sim.runs.Run` or a :class:`FilterRecord`.

    Row i is the truth at the filter's own time t_{f_i} (:func:`filter_rows`, from the lag in
    force at each row, ``filter_log["lag"]``); rows where the filter has not yet made a step
    (f_i = 0) are NaN. The encoder zeros are the values that make the filter's measurement
    equations exact: with q_j = ψ_j − θ the wheel angles relative to the body and φ_j the
    position of each encoder's first edge (counts), c = ē − (ψ − θ) and h = ẽ − (b/r)(α − α_0),
    where ē, ẽ are the mean and half-difference of the unquantised readings
    q_j − q_j(0) + (φ_j − ½)Δ (b/r of the estimator's model).
    """
    if source.filter_log is None:
        raise TwinError("filter_truth needs a run with the EKF and log_filter=True")
    return state_matrix(_truth_of(source), source.filter_log["lag"])


def filter_rows(lag, n: int, last: int = 0) -> np.ndarray:
    """The filter's own time f_i (n,) (a control step) at each of ``n`` rows, from the lag in
    force at each row ``lag`` (periods; one number, or one per row as the filter log keeps it):
    f_i = max(f_{i−1}, i − lag_i), f_{−1} = ``last`` (0 at the start).

    The EKF steps to t_{i − lag} and never back: when the lag grows (a latency change it
    detected) it pauses until t_{i − lag} catches up with its time, so on those rows
    f_i > i − lag_i; when the lag shrinks it makes the steps due at once. With an IMU slower
    than the control loop the filter's time is the last IMU instant at or before t_{f_i}: a row
    whose f_i is no IMU instant has no gyro-bias truth there (NaN), so it drops out of NEES
    rather than being compared with the wrong instant."""
    lag = np.asarray(lag)
    if lag.ndim and lag.shape != (n,):
        raise TwinError(f"the filter log's lag has {lag.shape[0]} rows, its states {n}")
    cand = np.arange(n, dtype=np.int64) - np.broadcast_to(lag.astype(np.int64), (n,))
    return np.maximum.accumulate(np.maximum(cand, last))


def truth_rows(c: TruthConstants, ref: tuple, th, thd, psl, psr, psi, psd, al, by, bz) -> np.ndarray:
    """The 12 true states (m, 12) of rows given by their truth columns (arrays (m,));
    ``ref`` (q_l(0), q_r(0), α(0)) of the run's first row. Elementwise: a row's values depend on
    that row alone (the batch and the streaming figures agree to the bit)."""
    m = len(th)
    xi, _, zi = c.imu_position
    tl = th.tolist()
    dz = -xi * np.fromiter(map(math.sin, tl), float, m) + zi * np.fromiter(map(math.cos, tl), float, m)
    delta = c.resolution
    ql0, qr0, alpha0 = ref
    ql, qr = psl - th, psr - th
    el = ql - ql0 + (c.encoder_phase[0] - 0.5) * delta
    er = qr - qr0 + (c.encoder_phase[1] - 0.5) * delta
    gs, acs = c.gyro_scale, c.accel_scale
    return np.column_stack([
        th, psi, c.wheel_radius * psd + thd * dz, al, by, bz, 0.5 * (el + er) - (psi - th), np.full(m, gs[1]),
        0.5 * (er - el) - c.b_over_r * (al - alpha0), np.full(m, gs[2]), np.full(m, acs[0]), np.full(m, acs[2])])


def state_matrix(s: StateTruth, lag) -> np.ndarray:
    """:func:`filter_truth` from a :class:`StateTruth` and the filter's ``lag`` (periods: one
    number, or the lag in force at each row)."""
    n = len(s.theta)
    f = filter_rows(lag, n)
    out = np.full((n, DIM), np.nan)
    if not n:
        return out
    ref = (float(s.psi_l[0] - s.theta[0]), float(s.psi_r[0] - s.theta[0]), float(s.alpha[0]))
    x = truth_rows(s.constants, ref, *(np.asarray(v, float) for v in (
        s.theta, s.theta_dot, s.psi_l, s.psi_r, s.psi, s.psi_dot, s.alpha)), s.gyro_bias[:, 1], s.gyro_bias[:, 2])
    ok = f >= 1
    out[ok] = x[f[ok]]
    return out


def nees(source) -> np.ndarray:
    """NEES (n,) of the EKF at each row (NaN where the truth is not defined); ``source`` a
    :class:`twin.sim.runs.Run` or a :class:`FilterRecord`. Solved by
    :func:`estimation.detlinalg.quad_inv_rows` (the same bits on every CPU)."""
    x, P = source.filter_log["x"], source.filter_log["P"]
    return nees_rows(x, P, filter_truth(source))


def nees_rows(x, P, truth) -> np.ndarray:
    e = x - truth
    ok = np.isfinite(e).all(axis=1)
    if ok.all():
        return quad_inv_rows(P, e)
    out = np.full(len(e), np.nan)
    if ok.any():
        out[ok] = quad_inv_rows(P[ok], e[ok])
    return out


def summary(source, start: float = NEES_START) -> dict:
    """One run's consistency figures from its filter log (``source`` a :class:`twin.sim.runs.Run`
    logged with the filter's diagnostics, or a :class:`FilterRecord` with its truth): what
    :class:`RunningConsistency` gives while the run goes, to the bit.

    Over the rows with t ≥ ``start`` s: ``nees_mean`` (the mean of :func:`nees` over the rows
    where it is defined, ``rows`` of them; 12 for a consistent filter) with ``nees_bounds``
    (:data:`ONE_RUN_NEES_BOUNDS`, the 95 % interval of one row's NEES: a single run's time
    average is strongly correlated in time, see :func:`monte_carlo`, and spreads at most as
    much as one of its rows, so this is the interval that holds whatever the correlation; the
    χ² bounds of the mean over N independent runs, χ²_{12N}/N, are far narrower and apply to
    N runs only); ``nis_per_dof`` (Σ NIS / Σ dof over the encoder updates there, 1 if
    consistent), ``nis_updates`` and ``nis_dof`` (Σ dof)."""
    t = np.asarray(source.t, float)
    q = nees(source)
    fl = source.filter_log
    acc = _Sums(start)
    for a in range(0, len(t), SUM_BLOCK):
        b = slice(a, a + SUM_BLOCK)
        acc.block(t[b], q[b], np.asarray(fl["nis"][b], float), np.asarray(fl["nis_dof"][b]))
    return acc.result(fl["x"].shape[1] if len(fl["x"]) else DIM)


class _Sums:
    """The summary's sums, a block of rows at a time: exact (``math.fsum``) within a block,
    then over the blocks' sums."""

    def __init__(self, start: float):
        self.start = float(start)
        self.nees, self.nis = [], []
        self.rows = self.updates = self.dof = 0

    def block(self, t, q, nis, dof) -> None:
        late = t >= self.start - 1e-9
        keep = late & np.isfinite(q)
        self.nees.append(math.fsum(q[keep].tolist()))
        self.rows += int(keep.sum())
        on = late & (dof > 0) & np.isfinite(nis)
        self.nis.append(math.fsum(nis[on].tolist()))
        self.updates += int(on.sum())
        self.dof += int(dof[on].sum())

    def result(self, dim: int = DIM) -> dict:
        return {"start_s": self.start, "states": int(dim), "rows": self.rows,
                "nees_mean": math.fsum(self.nees) / self.rows if self.rows else None,
                "nees_bounds": list(ONE_RUN_NEES_BOUNDS) if dim == DIM else None,
                "nis_per_dof": math.fsum(self.nis) / self.dof if self.dof else None,
                "nis_updates": self.updates, "nis_dof": self.dof}


_TRUTH_COLUMNS = [1, 2, 3, 4, 5, 6, 7]  # θ, θ̇, ψ_l, ψ_r, ψ, ψ̇, α of a GroundTruth (t first)
_STATE = 12 + 12 * 12  # x then P (row-major) of one row


def measurable(estimator) -> bool:
    """True for an estimator whose state a run can hold against the twin's truth: it reports
    the EKF's twelve states (``state_names`` is :data:`estimation.ekf_steps.STATE_NAMES`),
    writes them with their covariance (``state_into(out, row)``: x, then P row by row, at its
    own time t_{k − lag}) and gives ``last_nis``, ``last_dof`` and ``lag`` after each step."""
    return (tuple(getattr(estimator, "state_names", ()) or ()) == tuple(STATE_NAMES)
            and callable(getattr(estimator, "state_into", None))
            and all(hasattr(estimator, n) for n in ("last_nis", "last_dof", "lag")))


class RunningConsistency:
    """:func:`summary` of a run computed while it goes, in memory that does not grow with the
    run: the rows wait in a block of :data:`SUM_BLOCK` (1.25 kB of x and P each), then their NEES
    is solved at once (:func:`estimation.detlinalg.quad_inv_rows`) and summed, and only the
    truth of the rows the filter has not yet reached is kept (its lag, a few periods).

    ``constants`` the run's :class:`TruthConstants`. Feed :meth:`add` at every control instant
    from row 0 on, in order; :meth:`result` then gives the summary (at the end: no row can be
    added after it)."""

    def __init__(self, constants: TruthConstants, start: float = NEES_START):
        self.constants = constants
        self._sums = _Sums(start)
        self._pending = []
        self.n = 0  # rows summed
        self._f = 0  # the filter's time (control step) at the last row summed
        self._ref = None  # (q_l(0), q_r(0), α(0))
        self._base = 0  # the row of self._truth[0]
        self._truth = np.empty((0, 9))  # θ, θ̇, ψ_l, ψ_r, ψ, ψ̇, α, b_y, b_z of rows _base, _base + 1, …
        self._done = False  # result() was asked for: the last block is summed
        self._states = np.empty((SUM_BLOCK, _STATE))  # x then P of each pending row

    def add(self, truth, gyro_bias, state, nis: float, dof: int, lag: int) -> None:
        """One control instant: ``truth`` its :class:`~twin.plant.bullet.GroundTruth`, ``gyro_bias``
        the gyro's true bias (3,) rad/s in the sample taken there (None without one), and the
        filter's diagnostics after its step there: ``state`` its x (12,) and P (12, 12) as 156
        numbers (x, then P row by row), or a callable ``state(out, row)`` that writes them into
        row ``row`` of ``out`` (as the EKF core's ``state_into`` does, with no array between);
        ``nis`` and ``dof`` of the encoder update (NaN and 0 without one) and ``lag`` the lag in
        force (periods)."""
        pending = self._pending
        j = len(pending)
        if callable(state):
            state(self._states, j)
        else:
            self._states[j] = state
        pending.append((truth, gyro_bias, nis, dof, lag))
        if j + 1 >= SUM_BLOCK:
            self._flush()

    def _flush(self) -> None:
        rows = self._pending
        m = len(rows)
        if not m:
            return
        if self._done:
            rows.clear()
            raise TwinError("RunningConsistency: no row can be added after result()")
        i0 = self.n
        truths, biases, nis, dof, lag = zip(*rows)
        tr = np.fromiter(chain.from_iterable(truths), float).reshape(m, -1)
        if biases.count(None):
            bias = np.full((m, 2), np.nan)
            have = [j for j, b in enumerate(biases) if b is not None]
            if have:
                bias[have] = [tuple(biases[j])[1:3] for j in have]
        else:  # a gyro sample at every row
            bias = np.fromiter(chain.from_iterable(biases), float).reshape(m, -1)[:, 1:3]
        state = self._states[:m]
        nis = np.array(nis, float)
        dof = np.array(dof, np.int64)
        lag = np.array(lag, np.int64)
        rows.clear()
        if self._ref is None:
            th0 = tr[0, 1]
            self._ref = (float(tr[0, 3] - th0), float(tr[0, 4] - th0), float(tr[0, 7]))
        self._truth = np.concatenate([self._truth, np.column_stack([tr[:, _TRUTH_COLUMNS], bias])])
        f = np.maximum.accumulate(np.maximum(np.arange(i0, i0 + m, dtype=np.int64) - lag, self._f))
        ok = f >= 1
        q = np.full(m, np.nan)
        if ok.any():
            T = self._truth[f[ok] - self._base]
            X = truth_rows(self.constants, self._ref, *T.T)
            truth = np.full((m, DIM), np.nan)
            truth[ok] = X
            q = nees_rows(state[:, :DIM], state[:, DIM:].reshape(m, DIM, DIM), truth)
        self._sums.block(tr[:, 0], q, nis, dof)
        self.n = i0 + m
        self._f = int(f[-1])
        drop = self._f - self._base  # rows the filter has passed: no later row needs their truth
        if drop > 0:
            self._truth = self._truth[drop:]
            self._base = self._f

    def result(self) -> dict:
        """The :func:`summary` of the rows added (the run's end: no more rows after it)."""
        self._flush()
        self._done = True
        return self._sums.result(DIM)


def monte_carlo(runs, start: float = 0.0, confidence: float = 0.95) -> dict:
    """The two-sided χ² tests of NEES and NIS over independent ``runs`` of equal length (each a
    :class:`twin.sim.runs.Run` or a :class:`FilterRecord` with its truth).

    Considers the rows with t ≥ ``start`` s. Returns the per-row average NEES (``nees``),
    its ``nees_bounds``, the fraction of rows inside them (``nees_inside``), the overall
    mean NEES against the state dimension (``nees_mean``, ``dim``); and for NIS the
    fraction of rows, among those with an encoder update in some run, whose summed NIS
    lies inside its bounds (``nis_inside``) and the overall NIS per degree of freedom
    (``nis_per_dof``, 1 for a consistent filter).

    Why also ``nees_run_means`` and ``nees_mean_interval``: a run's NEES is strongly
    correlated in time (nearly unobservable states such as the scale factors keep their
    drawn errors for the whole run), so the fraction of rows inside the bounds is close to
    all-or-nothing for a batch and swings from batch to batch for one and the same filter.
    The runs are independent, though: each run's time-averaged NEES (``nees_run_means``,
    (N,)) has mean ``dim`` for a consistent filter, and ``nees_mean_interval`` is the
    Student-t interval (at ``confidence``) of their mean, which holds whatever the
    correlation in time. ``nees_mean`` inside ``nees_bounds`` is the χ² test of the
    average (conservative for a time average, whose spread is at most one row's).
    """
    from scipy.stats import chi2
    from scipy.stats import t as t_dist

    if len(runs) < 2:
        raise TwinError(f"a Monte Carlo consistency test needs at least 2 runs, got {len(runs)}")
    if not (0.5 < confidence < 1.0):
        raise TwinError(f"confidence must be in (0.5, 1), got {confidence!r}")
    n = min(len(r.t) for r in runs)
    keep = runs[0].t[:n] >= start - 1e-9
    E = np.array([nees(r)[:n] for r in runs])[:, keep]
    rows = np.isfinite(E).all(axis=0)
    E = E[:, rows]
    N, dim = len(runs), runs[0].filter_log["x"].shape[1]
    a = 0.5 * (1.0 - confidence)
    lo, hi = chi2.ppf([a, 1.0 - a], N * dim) / N
    mean = E.mean(axis=0)
    per_run = E.mean(axis=1)
    half = t_dist.ppf(1.0 - a, N - 1) * per_run.std(ddof=1) / math.sqrt(N)
    nis = np.array([np.nan_to_num(r.filter_log["nis"][:n]) for r in runs])[:, keep].sum(axis=0)
    dof = np.array([r.filter_log["nis_dof"][:n] for r in runs])[:, keep].sum(axis=0)
    used = dof > 0
    nlo, nhi = chi2.ppf(a, dof[used]), chi2.ppf(1.0 - a, dof[used])
    return {"runs": N, "dim": dim, "rows": int(E.shape[1]), "nees": mean, "nees_bounds": (float(lo), float(hi)),
            "nees_inside": float(np.mean((mean >= lo) & (mean <= hi))), "nees_mean": float(E.mean()),
            "nees_run_means": per_run, "nees_mean_interval": (float(per_run.mean() - half), float(per_run.mean() + half)),
            "nis_inside": float(np.mean((nis[used] >= nlo) & (nis[used] <= nhi))),
            "nis_per_dof": float(nis[used].sum() / dof[used].sum()) if used.any() else math.nan}
