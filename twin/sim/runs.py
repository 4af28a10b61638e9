"""The one run-result type: a closed-loop trajectory, from the twin or the analytic model.

Row i holds the ground truth at t_i, what the controllers were given at t_i
(``estimates``), the command computed from it, and what the motors delivered and the
pushes did over [t_i, t_i+1) (period means). A run that falls stops at the row where that
was detected. Nothing is applied after a run's last row, so that row repeats the actuation
of the period before it (what the motors were delivering when the run ended). A
run that diverges (a non-finite state from the physics) stops at the last finite row: no
NaN is logged. :func:`twin.outputs.metrics.run_metrics` gives every run's figures of merit.

A long run may keep only every N-th control step (``log_every``, see
:func:`twin.sim.bullet_loop.simulate_twin`): row i is then control step i·N, and the few
signals the metrics need are kept at every step in ``full_rate``, so that the metrics do not
depend on N.
"""
from __future__ import annotations

import math
import operator
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from twin.errors import TwinError
from twin.experiments import Experiment
from twin.measures import exact_mean, settling_time
from twin.params import RobotParams
from twin.plant.base import ACTUATION_UNITS, TRUTH_UNITS, Actuation, GroundTruth, TwinConfig
# the names of a run's logged columns are the contracts' (twin.protocols), named here as before
from twin.protocols import (ACTUATION_NAMES, COMMAND_NAMES, COMMAND_UNITS, ESTIMATE_NAMES, ESTIMATE_UNITS,  # noqa: F401
                            PUSH_NAMES, PUSH_UNITS, TRUTH_NAMES)
from twin.sensors import Measurement, SensorConfig

# the signals twin.outputs.metrics.run_metrics reads, kept at every control step when the log keeps every N-th
FULL_RATE_NAMES = ("t", "theta", "theta_est", "torque_l", "torque_r", "distance", "alpha")


class MeasurementLog(Sequence):
    """What reached the estimator at each logged step, stored as arrays: a read-only
    sequence of :class:`twin.sensors.Measurement`, each built when it is read.

    ``t`` (n,) s; ``gyro`` (n, 3) rad/s, ``accel`` (n, 3) m/s² and ``encoders`` (n, 2) rad,
    NaN where nothing arrived at that step; ``has_gyro``, ``has_accel`` and ``has_encoders``
    (n,) bool say where something did (so a reading is never taken for a gap); ``truth``
    (n, 15) the ground truth attached to each measurement (``Measurement.truth``, for
    estimators that read it), else None; ``extra`` the other channels (``Measurement.extra``,
    :mod:`twin.sensors.types`) as name -> (values (n, c) in the channel's unit, NaN where
    nothing arrived; has (n,) bool), else None. ``log[i]`` is the Measurement the estimator got
    (None for what did not arrive), ``log[a:b]`` a MeasurementLog, and a log equals another
    log or a list holding the same Measurements.
    """

    __slots__ = ("t", "gyro", "accel", "encoders", "has_gyro", "has_accel", "has_encoders", "truth", "extra")
    _BLOCK = 4096  # Measurements built at a time when iterating

    def __init__(self, t, gyro, accel, encoders, has_gyro, has_accel, has_encoders, truth=None, extra=None):
        self.t, self.gyro, self.accel, self.encoders = t, gyro, accel, encoders
        self.has_gyro, self.has_accel, self.has_encoders = has_gyro, has_accel, has_encoders
        self.truth = truth
        self.extra = extra or None

    @classmethod
    def empty(cls, n: int, with_truth: bool = False, channels=()) -> "MeasurementLog":
        """A log of ``n`` steps to fill in with :meth:`put` (allocated, not yet written: a row
        takes memory once it is put); ``channels`` the extra channels
        (:class:`twin.sensors.channels.Channel`) it holds besides the core three."""
        return cls(np.empty(n), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 2)),
                   np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool),
                   np.empty((n, len(TRUTH_NAMES))) if with_truth else None,
                   {c.name: (np.empty((n, len(c.columns))), np.zeros(n, bool)) for c in channels})

    def put(self, start: int, measurements) -> None:
        """Store ``measurements`` (Measurement objects) at rows ``start``, ``start`` + 1, …"""
        m = list(measurements)
        rows = slice(start, start + len(m))
        self.t[rows] = [x.t for x in m]
        for name, values, has in (("gyro", self.gyro, self.has_gyro), ("accel", self.accel, self.has_accel),
                                  ("encoders", self.encoders, self.has_encoders)):
            self._put(start, rows, [getattr(x, name) for x in m], values, has)
        if self.extra:
            for name, (values, has) in self.extra.items():
                self._put(start, rows, [(x.extra or {}).get(name) for x in m], values, has)
        if self.truth is not None:
            self.truth[rows] = [x.truth for x in m]

    @staticmethod
    def _put(start, rows, got, values, has) -> None:
        where = [j for j, v in enumerate(got) if v is not None]
        values[rows] = np.nan
        has[rows] = False
        if where:
            values[start + np.array(where)] = [got[j] for j in where]
            has[start + np.array(where)] = True

    def __len__(self) -> int:
        return len(self.t)

    def _lists(self) -> tuple:
        """The columns as Python lists (floats, bools; None for no truth), to build Measurements from."""
        extra = None if not self.extra else {k: (v.tolist(), h.tolist()) for k, (v, h) in self.extra.items()}
        return (self.t.tolist(), self.gyro.tolist(), self.accel.tolist(), self.encoders.tolist(),
                self.has_gyro.tolist(), self.has_accel.tolist(), self.has_encoders.tolist(),
                None if self.truth is None else self.truth.tolist(), extra)

    @staticmethod
    def _one(j: int, t, g, a, e, hg, ha, he, tr, extra=None) -> Measurement:
        return Measurement(t[j], tuple(g[j]) if hg[j] else None, tuple(a[j]) if ha[j] else None,
                           tuple(e[j]) if he[j] else None, None if tr is None else GroundTruth(*tr[j]),
                           None if extra is None else {k: tuple(v[j]) if h[j] else None for k, (v, h) in extra.items()})

    def __getitem__(self, i):
        if isinstance(i, slice):
            return MeasurementLog(*(None if v is None else v[i] for v in (
                self.t, self.gyro, self.accel, self.encoders, self.has_gyro, self.has_accel, self.has_encoders,
                self.truth)), None if not self.extra else {k: (v[i], h[i]) for k, (v, h) in self.extra.items()})
        n = len(self)
        i = operator.index(i)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"measurement index out of range: {n} steps logged")
        return self._one(0, *self[i:i + 1]._lists())

    def __iter__(self):
        for s in range(0, len(self), self._BLOCK):
            cols = self[s:s + self._BLOCK]._lists()
            for j in range(len(cols[0])):
                yield self._one(j, *cols)

    def channel(self, name: str) -> tuple:
        """(values (n, c), has (n,)) of channel ``name`` (a core one or an extra one); a one-line
        error naming the channels this log holds."""
        if name in ("gyro", "accel", "encoders"):
            return getattr(self, name), getattr(self, f"has_{name}")
        if self.extra and name in self.extra:
            return self.extra[name]
        raise TwinError(f"no channel {name!r} in this log; channels: "
                        f"{', '.join(('gyro', 'accel', 'encoders') + tuple(self.extra or ()))}")

    def __eq__(self, other):
        if isinstance(other, MeasurementLog):
            if len(self) != len(other) or (self.truth is None) != (other.truth is None):
                return False
            if set(self.extra or ()) != set(other.extra or ()):
                return False
            pairs = [(self.t, other.t), (self.has_gyro, other.has_gyro), (self.has_accel, other.has_accel),
                     (self.has_encoders, other.has_encoders)]
            if self.truth is not None:
                pairs.append((self.truth, other.truth))
            triples = [(self.gyro, other.gyro, self.has_gyro), (self.accel, other.accel, self.has_accel),
                       (self.encoders, other.encoders, self.has_encoders)]
            for k, (v, h) in (self.extra or {}).items():
                pairs.append((h, other.extra[k][1]))
                triples.append((v, other.extra[k][0], h))
            if not all(np.array_equal(x, y) for x, y in pairs):
                return False
            return all(np.array_equal(x[h], y[h]) for x, y, h in triples)
        if isinstance(other, (list, tuple)):
            return len(self) == len(other) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    __hash__ = None

    def __repr__(self) -> str:
        more = "".join(f", {k} {int(h.sum())}" for k, (_, h) in (self.extra or {}).items())
        return (f"MeasurementLog({len(self)} steps, gyro {int(self.has_gyro.sum())}, accel {int(self.has_accel.sum())}, "
                f"encoders {int(self.has_encoders.sum())}{more} arrived)")


@dataclass
class Run:
    """A closed-loop trajectory (see the module docstring for the row layout).

    ``plant`` is "twin" (:func:`twin.sim.bullet_loop.simulate_twin`) or "analytic"
    (:func:`twin.sim.analytic_loop.simulate`: equation (1), ideal torque sources, the
    controllers reading the truth; its ``config`` is None).

    ``truth`` (n, 15) columns :data:`TRUTH_NAMES`; ``estimates`` (n, 6)
    :data:`ESTIMATE_NAMES`, the state the controllers were given; ``commands`` (n, k)
    ``command_names``: ul_cmd, ur_cmd (N·m) and the controller's extra signals
    (:data:`COMMAND_NAMES` for the fuzzy cascade and LQR); ``actuation`` (n, 6) :data:`ACTUATION_NAMES`; ``push`` (n, 3)
    N, world frame. ``status`` is "ok" (ran its duration), "degraded" (ran its duration, but the
    estimator ended without something it needs, ``end_reason`` says what: the position with the
    encoders stuck or gone), "fell" or "diverged".
    ``sensing`` is "ideal" or the estimator's name; ``measurements`` what reached the
    estimator at each step (a :class:`MeasurementLog`; an empty list with ideal sensing); ``estimator_stats`` its counts (rejected measurements,
    resets, events); ``gyro_bias`` (n, 3) rad/s the gyro's true bias in the sample taken
    at each step (NaN without one); ``sensor_truth`` the sensors' drawn constants (scale
    factors, turn-on biases, encoder phases); ``sensor_config`` and ``model_params`` what the
    run was given; ``filter_log`` (EKF with ``log_filter``) the filter's own state ``x``
    (n, 12) and covariance ``P`` (n, 12, 12) at its own time, t_{i − lag} as a rule
    (:func:`estimation.consistency.filter_rows`; see :mod:`estimation.ekf`), the encoder
    update's ``nis`` (n,) (NaN where none was tried) with its degrees of freedom ``nis_dof``
    (n,) (the number of wheels whose count changed; 0 where none was tried), and ``lag`` (n,)
    the lag in force at each row (periods). ``estimator_consistency``: the EKF's NEES and NIS
    summary (:func:`estimation.consistency.summary`, computed while the run went, whether or
    not it kept the filter log) for a run of the EKF on simulated sensors; else None.

    ``log_every`` N: row i is control step i·N (1: every step is logged). With N > 1 every
    per-row attribute above holds those rows only (so replaying the estimator on
    ``measurements`` needs N = 1), and ``full_rate`` holds :data:`FULL_RATE_NAMES` (t, θ,
    the θ estimate, both delivered torques, distance, α) at every control step, which the
    metrics read (:meth:`full_signal`); None when N = 1.
    """

    t: np.ndarray
    truth: np.ndarray
    commands: np.ndarray
    actuation: np.ndarray
    push: np.ndarray
    status: str
    end_reason: str
    config: TwinConfig | None = field(repr=False)
    experiment: Experiment | None = None
    controller: str = ""
    estimates: np.ndarray | None = None
    sensing: str = "ideal"
    measurements: list = field(default_factory=list, repr=False)
    estimator_stats: dict = field(default_factory=dict)
    sensor_counts: dict = field(default_factory=dict)
    gyro_bias: np.ndarray | None = field(default=None, repr=False)
    filter_log: dict | None = field(default=None, repr=False)
    seed: int | None = None
    sensor_truth: dict = field(default_factory=dict, repr=False)
    sensor_config: SensorConfig | None = field(default=None, repr=False)
    model_params: RobotParams | None = field(default=None, repr=False)
    command_names: tuple = COMMAND_NAMES
    command_units: tuple = tuple(COMMAND_UNITS[k] for k in COMMAND_NAMES)
    plant: str = "twin"
    log_every: int = 1
    full_rate: dict | None = field(default=None, repr=False)
    estimator_consistency: dict | None = None

    @property
    def fell(self) -> bool:
        return self.status in ("fell", "diverged")

    def signal(self, name: str) -> np.ndarray:
        """One logged signal by name (truth, estimate, command, actuation or push column)."""
        for names, data in ((TRUTH_NAMES, self.truth), (ESTIMATE_NAMES, self.estimates),
                            (self.command_names, self.commands), (ACTUATION_NAMES, self.actuation),
                            (PUSH_NAMES, self.push)):
            if name in names:
                return data[:, names.index(name)]
        raise TwinError(f"no signal {name!r}; signals: {', '.join(self.signal_names())}")

    def signal_names(self) -> tuple[str, ...]:
        return TRUTH_NAMES + ESTIMATE_NAMES + tuple(self.command_names) + ACTUATION_NAMES + PUSH_NAMES

    def signal_units(self) -> dict[str, str]:
        return {**TRUTH_UNITS, **ESTIMATE_UNITS, **dict(zip(self.command_names, self.command_units)),
                **ACTUATION_UNITS, **PUSH_UNITS}

    @property
    def distance(self) -> np.ndarray:
        """Travelled distance p = r ψ in m."""
        return self.signal("distance")

    @property
    def total_torque(self) -> np.ndarray:
        """Torque delivered by both motors, N·m."""
        return self.signal("torque_l") + self.signal("torque_r")

    def columns(self) -> tuple[list[str], list[str], np.ndarray]:
        """(names, units, data (n, k)) of everything logged, for CSV files."""
        names = list(self.signal_names())
        units = [self.signal_units()[n] for n in names]
        return names, units, np.column_stack(self._blocks())

    def _blocks(self) -> list:
        return [self.truth, self.estimates, self.commands, self.actuation, self.push]

    def column_chunks(self, rows: int = 4096):
        """The data of :meth:`columns`, ``rows`` rows at a time (arrays (≤ rows, k)): the same
        values without a copy of the whole log."""
        blocks = self._blocks()
        for s in range(0, len(self.t), rows):
            yield np.column_stack([b[s:s + rows] for b in blocks])

    @property
    def control_steps(self) -> int:
        """Control instants simulated (rows of the log at every step; ``len(t)`` when N = 1)."""
        return len(self.full_rate["t"]) if self.full_rate is not None else len(self.t)

    def full_signal(self, name: str) -> np.ndarray:
        """Signal ``name`` ("t" or a logged signal) at every control step: from ``full_rate``
        when the log keeps every N-th step (only :data:`FULL_RATE_NAMES` are there), else the log."""
        if self.full_rate is None:
            return self.t if name == "t" else self.signal(name)
        if name not in self.full_rate:
            raise TwinError(f"{name!r} was logged at one control step in {self.log_every} only; kept at every "
                            f"step: {', '.join(self.full_rate)}")
        return self.full_rate[name]

    def settling_time(self, tol: float = 0.01) -> float:
        """First time (s) after which |θ| stays below ``tol`` rad; inf if it never does or fell.
        From every control step, whatever ``log_every``."""
        if self.fell:
            return math.inf
        return settling_time(self.full_signal("t"), self.full_signal("theta"), tol)

    def estimation_rmse(self, name: str = "theta", start: float = 0.0) -> float:
        """RMS of (estimate − truth) of ``name`` (θ, θ̇, ψ, ψ̇, α or α̇) from ``start`` s on: over
        every control step for θ (and for all when ``log_every`` is 1), else over the logged rows."""
        full = self.full_rate is None or (name in self.full_rate and name + "_est" in self.full_rate)
        get, t = (self.full_signal, self.full_signal("t")) if full else (self.signal, self.t)
        keep = t >= start - 1e-9
        err = get(name + "_est")[keep] - get(name)[keep]
        return math.sqrt(exact_mean(err * err)) if err.size else math.nan


TwinRun = Run  # the name it had when only the twin made runs

