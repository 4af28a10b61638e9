"""The robot's sensors as the estimator sees them: IMU and wheel encoders, noise, faults
and latency, read once per control period.

Timing. Control instants are t_k = k T (T the control period). The IMU samples at
instants that are control instants (its rate divides the control rate), the encoders at
every control instant; a sample taken at step k arrives at step k + d (d = latency / T,
a whole number). :meth:`SensorSuite.read` returns, at each control instant, the newest
sample of each sensor that arrived then (``None`` where nothing new arrived). Before
t = 0 the robot stood still, so the first readings are of that rest state
(:meth:`SensorSuite.start`).

Randomness. One generator per run, split with ``Generator.spawn`` into independent
streams for the gyro, the accelerometer, the encoders' count phases and each sensor's
fault draws, so adding a fault does not change the noise.

More sensors (``SensorConfig.extra``: the types of :data:`twin.sensors.types.SENSOR_TYPES`
beyond the IMU and encoders, e.g. the motor current) are read on the same clock, each with its
own latency queue, into ``Measurement.extra``. Each gets one more child of the run's
generator, spawned after the six above and in the order of ``extra``: ``spawn`` numbers a
generator's children (the SeedSequence's ``spawn_key``, 0, 1, …) and draws nothing from its
stream, so the six children, and every reading drawn from them, are the same with or without
the extra sensors (tests/test_sensor_channels.py checks it); with none, nothing is spawned.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from itertools import islice
from typing import NamedTuple

import numpy as np

from twin.errors import TwinError, shown
from twin.rotations import mounting_matrix
from twin.sensors.channels import whole_steps as _whole
from twin.sensors.faults import FAULT_TYPES, Dropout, LatencyChange, Spikes, Stuck
from twin.sensors.noise import TriadNoise
from twin.sensors.specs import DEFAULT_ENCODERS, DEFAULT_IMU, EncoderSpec, ImuSpec
from twin.sensors.types import CORE_CHANNELS, SENSOR_TYPES, type_of


@dataclass(frozen=True)
class SensorConfig:
    """IMU, encoders and the faults to inject; ``extra`` the specs of more sensors, at most one
    per type of :data:`twin.sensors.types.SENSOR_TYPES` (e.g.
    :class:`~twin.sensors.motor_current.MotorCurrentSpec`), none by default."""

    imu: ImuSpec = DEFAULT_IMU
    encoders: EncoderSpec = DEFAULT_ENCODERS
    faults: tuple = ()
    extra: tuple = ()

    def __post_init__(self):
        if not isinstance(self.imu, ImuSpec):
            raise TwinError(f"imu must be an ImuSpec, got {self.imu!r}")
        if not isinstance(self.encoders, EncoderSpec):
            raise TwinError(f"encoders must be an EncoderSpec, got {self.encoders!r}")
        faults = tuple(self.faults) if isinstance(self.faults, (list, tuple)) else None
        if faults is None or not all(isinstance(f, FAULT_TYPES) for f in faults):
            raise TwinError(f"faults must be a list of Dropout, Stuck, Spikes or LatencyChange, got {self.faults!r}")
        object.__setattr__(self, "faults", faults)
        extra = tuple(self.extra) if isinstance(self.extra, (list, tuple)) else None
        if extra is None:
            raise TwinError(f"extra must be a list of sensor specifications, got {shown(self.extra)}")
        kinds = [type_of(spec).name for spec in extra]  # (a one-line error for anything else)
        twice = sorted({k for k in kinds if kinds.count(k) > 1})
        if twice:
            raise TwinError(f"extra has two {twice[0]} sensors; allowed: one of each type")
        object.__setattr__(self, "extra", extra)

    def spec(self, name: str):
        """The spec of sensor type ``name`` in :attr:`extra`, or None (it is off)."""
        for s in self.extra:
            if type_of(s).name == name:
                return s
        return None

    @property
    def channels(self) -> tuple:
        """The names of the channels these sensors give (the core three, then the extra ones')."""
        return CORE_CHANNELS + tuple(c.name for s in self.extra for c in type_of(s).channels)

    def steps(self, control_rate: float) -> tuple[int, int, int]:
        """(control steps per IMU sample, IMU latency steps, encoder latency steps); a
        one-line error if the IMU rate does not divide the control rate or a latency is
        not a whole number of control periods."""
        if self.imu.rate > control_rate * (1.0 + 1e-9):
            raise TwinError(f"the IMU rate ({self.imu.rate:g} Hz) must not exceed the control rate "
                            f"({control_rate:g} Hz): the IMU is read once per control period at most")
        every = _whole(control_rate / self.imu.rate, f"the control rate ({control_rate:g} Hz) must be a whole "
                       f"multiple of the IMU rate ({self.imu.rate:g} Hz)")
        d_imu = latency_steps(self.imu.latency, control_rate, "IMU latency")
        d_enc = latency_steps(self.encoders.latency, control_rate, "encoder latency")
        for f in self.faults:
            if isinstance(f, LatencyChange):
                latency_steps(f.latency, control_rate, "LatencyChange latency")
        for spec in self.extra:  # each extra sensor's rate and latency fit the control period
            spec.steps(control_rate)
        return every, d_imu, d_enc


def latency_steps(latency: float, control_rate: float, what: str) -> int:
    """``latency`` (s) in control periods; a one-line error unless it is a whole number."""
    return _whole(latency * control_rate, f"{what} ({latency:g} s) must be a whole number of control periods "
                  f"({1.0 / control_rate:g} s)")


class Measurement(NamedTuple):
    """What reached the estimator at control instant ``t`` (s); None: nothing new.

    Channels by name (:mod:`twin.sensors.types`): ``meas["motor_current"]`` or
    ``meas.channels`` (a dict of every channel the run has, core and extra); a channel the run
    does not have reads as None, as one that gave nothing new at ``t``. An integer index is the
    tuple's, as ever."""

    t: float
    gyro: tuple | None  # rad/s, body axes (x forward, y along the axle to the left, z up the body)
    accel: tuple | None  # m/s², specific force, body axes
    encoders: tuple | None  # rad, (left, right) wheel angle relative to the body since power-up
    truth: object = None  # the GroundTruth at t, attached only for estimators with reads_truth = True
    extra: dict | None = None  # the other channels' readings (name -> tuple, None: nothing new); None: none

    @property
    def channels(self) -> dict:
        """Every channel's reading at ``t`` by name: gyro, accel, encoders, then :attr:`extra`'s."""
        out = {"gyro": self.gyro, "accel": self.accel, "encoders": self.encoders}
        if self.extra:
            out.update(self.extra)
        return out

    def __getitem__(self, key):
        if isinstance(key, str):
            if key in CORE_CHANNELS:
                return getattr(self, key)
            extra = self.extra
            if extra is not None and key in extra:
                return extra[key]
            if any(c.name == key for t in SENSOR_TYPES.values() for c in t.channels):
                return None  # a channel this run does not have
            raise KeyError(f"no sensor channel {key!r}; channels: "
                           f"{', '.join(c.name for t in SENSOR_TYPES.values() for c in t.channels)}")
        return tuple.__getitem__(self, key)


class _Channel:
    """One sensor's samples on their way out: faults, then the latency queue."""

    def __init__(self, name: str, latency: int, faults, rng: np.random.Generator, sample_dt: float,
                 control_dt: float, clip=None, quantum: float | None = None):
        self.name = name
        # an encoder's reading is a whole number of counts (quantum rad each): so is a glitch
        self.quantum = quantum
        self.latency = latency
        self.control_dt = control_dt
        self.dropouts = [f for f in faults if isinstance(f, Dropout) and name in f.sensors]
        self.stucks = [f for f in faults if isinstance(f, Stuck) and name in f.sensors]
        self.spikes = [(f, min(1.0, f.rate * sample_dt)) for f in faults if isinstance(f, Spikes) and name in f.sensors]
        self.latency_changes = sorted((f for f in faults if isinstance(f, LatencyChange) and name in f.sensors),
                                      key=lambda f: f.time)
        self.rng = rng
        self.clip = clip
        self.queue: deque = deque()  # (arrival step, values), in production order
        self.in_order = True  # arrival steps non-decreasing along the queue
        self.last = None
        self.counts = dict(produced=0, dropped=0, stuck=0, spiked=0, superseded=0)
        # no fault and no latency change for this sensor (most runs): produce() only queues
        self._plain = not (self.dropouts or self.stucks or self.spikes or self.latency_changes)

    def produce(self, k: int, values: tuple) -> None:
        if self._plain:  # what the general path below does without faults, in fewer steps (600 calls a second)
            self.counts["produced"] += 1
            self.last = values
            q, arrival = self.queue, k + self.latency
            if q and q[-1][0] > arrival:
                self.in_order = False
            q.append((arrival, values))
            return
        t = k * self.control_dt
        self.counts["produced"] += 1
        d = self.latency
        for f in self.latency_changes:
            if f.time <= t + 1e-9:
                d = round(f.latency / self.control_dt)
        # (the emptiness tests first: most runs have no faults, and this runs 600 times a second)
        if self.dropouts and any(f.active(t) for f in self.dropouts):
            self.counts["dropped"] += 1
            return
        if self.stucks and self.last is not None and any(f.active(t) for f in self.stucks):
            values = self.last
            self.counts["stuck"] += 1
        else:
            self.last = values
        for f, p in self.spikes:
            if f.active(t) and self.rng.random() < p:
                signs = self.rng.integers(0, 2, len(values))
                if self.quantum is None:
                    values = tuple(v + (f.magnitude if s else -f.magnitude) for v, s in zip(values, signs))
                else:  # ±magnitude as whole counts (at least one): count × quantum, as every encoder reading
                    q = self.quantum
                    n = max(1, round(f.magnitude / q))
                    values = tuple((round(v / q) + (n if s else -n)) * q for v, s in zip(values, signs))
                if self.clip is not None:
                    values = tuple(self.clip(v) for v in values)
                self.counts["spiked"] += 1
        q = self.queue
        if q and q[-1][0] > k + d:  # a shorter latency overtakes the samples still on their way
            self.in_order = False
        q.append((k + d, values))

    def deliver(self, k: int):
        q = self.queue
        if self.in_order:
            # arrivals in production order (no latency change overtook any): the samples due are
            # a prefix of the queue, taken off its front; a latency of L periods holds L samples,
            # which the general path below would walk through at every step (1 s at 100 kHz:
            # 10⁵ samples per step)
            if not q or q[0][0] > k:
                return None
            newest = q.popleft()[1]
            while q and q[0][0] <= k:
                self.counts["superseded"] += 1
                newest = q.popleft()[1]
            return newest
        for a, _ in q:  # anything due? (as any(), without a generator per call)
            if a <= k:
                break
        else:
            return None
        newest = None
        keep = deque()
        for arrival, values in q:
            if arrival <= k:
                if newest is not None:
                    self.counts["superseded"] += 1
                newest = values
            else:
                keep.append((arrival, values))
        self.queue = keep
        # in order again once the overtaken samples have arrived
        self.in_order = all(a[0] <= b[0] for a, b in zip(keep, islice(keep, 1, None)))
        return newest


class SensorSuite:
    """IMU and encoders of one run.

    Parameters
    ----------
    config : SensorConfig
    control_rate : float
        Hz; the IMU rate must divide it, latencies must be whole control periods.
    rng : numpy.random.Generator
        The run's sensor generator (split into child streams here).
    """

    def __init__(self, config: SensorConfig, control_rate: float, rng: np.random.Generator):
        if not isinstance(config, SensorConfig):
            raise TwinError(f"sensors must be a SensorConfig, got {config!r}")
        if not isinstance(rng, np.random.Generator):
            raise TwinError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self.config = config
        self.control_rate = float(control_rate)
        T = 1.0 / self.control_rate
        self.every, d_imu, d_enc = config.steps(control_rate)
        g_rng, a_rng, e_rng, gf_rng, af_rng, ef_rng = rng.spawn(6)
        imu_dt = self.every * T
        self.gyro = TriadNoise(config.imu.gyro, imu_dt, g_rng)
        self.accel = TriadNoise(config.imu.accel, imu_dt, a_rng)
        self.counts_per_rad = config.encoders.counts_per_rev / (2.0 * math.pi)
        self.encoder_phase = tuple(float(v) for v in e_rng.random(2))  # where the first edge lies, in counts
        self._q0 = None
        self.channels = {
            "gyro": _Channel("gyro", d_imu, config.faults, gf_rng, imu_dt, T, self.gyro.clip),
            "accel": _Channel("accel", d_imu, config.faults, af_rng, imu_dt, T, self.accel.clip),
            "encoders": _Channel("encoders", d_enc, config.faults, ef_rng, T, T,
                                 quantum=1.0 / self.counts_per_rad),
        }
        self.last_gyro_bias = self.gyro.bias
        o = config.imu.orientation  # an IMU mounted turned: its errors act along its own axes
        self._mount = None if o == (0.0, 0.0, 0.0) else np.array(mounting_matrix(*o))
        # the extra sensors: (type, reader, its latency queue), each reader on a child of its own,
        # spawned after the six above (none spawned without extra sensors: see the module docstring)
        self.extra = []
        for spec in config.extra:
            t = type_of(spec)
            reader = t.reader(spec, self.control_rate, rng.spawn(1)[0])
            name = t.channels[0].name if len(t.channels) == 1 else t.name
            queue = _Channel(name, reader.latency, (), None, reader.every * T, T, getattr(reader, "clip", None))
            self.extra.append((t, reader, queue))

    def encoder_counts(self, q_l: float, q_r: float) -> tuple[int, int]:
        """Counts since power-up for wheel angles relative to the body ``q_l``, ``q_r`` (rad)."""
        c = self.counts_per_rad
        (q0l, q0r), (pl, pr) = self._q0, self.encoder_phase
        return math.floor((q_l - q0l) * c + pl), math.floor((q_r - q0r) * c + pr)

    def start(self, gyro, accel, q_l: float, q_r: float) -> None:
        """Power up with the robot at rest: ``gyro`` (rad/s) and ``accel`` (m/s²) the true
        body-frame readings of the rest state, q_l, q_r the wheel angles relative to the
        body (rad). Fills the latency queues with samples of that state."""
        self._q0 = (float(q_l), float(q_r))
        for name in ("gyro", "accel"):
            ch = self.channels[name]
            for j in range(-ch.latency, 0):
                if j % self.every == 0:
                    self._imu_sample(name, j, gyro if name == "gyro" else accel)
        ch = self.channels["encoders"]
        for j in range(-ch.latency, 0):
            ch.produce(j, (0.0, 0.0))
        for t, reader, queue in self.extra:  # at rest: zero truth (no current, say) before t = 0
            rest = tuple((0.0,) * len(c.columns) for c in t.channels)
            for j in range(-queue.latency, 0):
                if j % reader.every == 0:
                    queue.produce(j, reader.sample(rest))

    def _imu_sample(self, name: str, k: int, true) -> None:
        noise = self.gyro if name == "gyro" else self.accel
        if name == "gyro":
            self.last_gyro_bias = noise.bias
        if self._mount is None:
            self.channels[name].produce(k, noise.sample(*true))
            return
        # the sensor's axes: v_imu = Cᵀ v_body; its reading turned back into the body's axes
        C = self._mount
        read = noise.sample(*(C.T @ np.asarray(true, dtype=float)))
        self.channels[name].produce(k, tuple(float(v) for v in C @ np.asarray(read, dtype=float)))

    def read(self, k: int, gyro, accel, q_l: float, q_r: float, sources=None) -> Measurement:
        """Sample what is due at control step ``k`` and return what arrives then.

        ``gyro``, ``accel``: the true IMU readings at t_k (from
        :func:`twin.sensors.imu.imu_kinematics`; ignored on steps without an IMU sample);
        ``q_l``, ``q_r``: the wheels' angles relative to the body (rad); ``sources``
        (:class:`twin.sensors.channels.Sources`): what the extra sensors' truth is taken from
        (needed only with extra sensors).
        """
        if self._q0 is None:
            raise TwinError("call SensorSuite.start before reading the sensors")
        if k % self.every == 0:
            self._imu_sample("gyro", k, gyro)
            self._imu_sample("accel", k, accel)
        cl, cr = self.encoder_counts(q_l, q_r)
        res = 1.0 / self.counts_per_rad
        self.channels["encoders"].produce(k, (cl * res, cr * res))
        ch = self.channels
        if not self.extra:
            return Measurement(k / self.control_rate, ch["gyro"].deliver(k), ch["accel"].deliver(k),
                               ch["encoders"].deliver(k))
        extra = {}
        for t, reader, queue in self.extra:
            if k % reader.every == 0:
                queue.produce(k, reader.sample(t.truth(sources)))
            got = queue.deliver(k)
            for j, c in enumerate(t.channels):
                extra[c.name] = None if got is None else got[j]
        return Measurement(k / self.control_rate, ch["gyro"].deliver(k), ch["accel"].deliver(k),
                           ch["encoders"].deliver(k), None, extra)

    def gyro_bias_body(self):
        """The gyro's bias now (rad/s), in the body's axes (what an estimator of the body's rates
        sees: the sensor's own bias turned by its mounting)."""
        b = self.gyro.bias
        return b if self._mount is None else tuple(float(v) for v in self._mount @ np.asarray(b, dtype=float))

    def truth(self) -> dict:
        """The constants this run drew: scale factors (1), turn-on biases, encoder phases (counts),
        in the body's axes (for an IMU mounted turned: its biases turned, and of its scale errors
        the diagonal of C S Cᵀ, the part along each body axis; the rest couples the axes)."""
        gs, as_, gb, ab = self.gyro.scale, self.accel.scale, self.gyro.turn_on, self.accel.turn_on
        if self._mount is not None:
            C = self._mount
            gs, as_ = (tuple(float(v) for v in np.diag(C @ np.diag(s) @ C.T)) for s in (gs, as_))
            gb, ab = (tuple(float(v) for v in C @ np.asarray(b, dtype=float)) for b in (gb, ab))
        out = {"gyro_scale": tuple(gs), "accel_scale": tuple(as_),
               "gyro_turn_on_bias": tuple(gb), "accel_turn_on_bias": tuple(ab),
               "encoder_phase": self.encoder_phase}
        for _, reader, _ in self.extra:  # an extra sensor's drawn constants (the current's offsets, gains)
            out.update(reader.truth())
        return out

    def fault_counts(self) -> dict:
        """Per sensor: samples produced, dropped, stuck, spiked, superseded."""
        out = {name: dict(ch.counts) for name, ch in self.channels.items()}
        for _, _, queue in self.extra:
            out[queue.name] = dict(queue.counts)
        return out
