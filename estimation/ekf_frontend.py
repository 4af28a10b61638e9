"""The EKF's sensor front end: what reaches the filter of each reading, and when.

:class:`Books`           what the filter did with the samples: counts per sensor and events, for
                         :meth:`estimation.ekf.EKFEstimator.stats`
:class:`Clock`           the instants' times (s): a constant period, or a log's own rows
:class:`SensorFrontEnd`  the readings screened and queued by sample time, each sensor on its own
                         latency: non-finite readings, stale (repeated) IMU triads, point samples
                         turned into interval means, IMU axes at their rails, the gyro's latency
                         watched against the commands (and the queues re-aligned when it
                         changes); the encoders' counts checked (beyond a 32-bit counter, jumps
                         no wheel can make, counts stuck while the IMU shows the wheels turning),
                         re-based after a counter reset, and kept inside an unchanged count

The reasons and the measurements behind each rule are in the module docstring of
:mod:`estimation.ekf`; the thresholds are :data:`estimation.ekf_config.POLICY`'s, the rules
with state of their own (the latency watch, the truncation) :mod:`estimation.ekf_policies`'.
The filter's arithmetic is :mod:`estimation.ekf_filter`'s; the step that puts the two together
under the gates is :mod:`estimation.ekf_fusion`'s.
"""
from __future__ import annotations

import math

from estimation.ekf_config import COUNTER_RANGE, ENCODERS_LOST_AFTER, MAX_RIM_SPEED, RAIL_SIGMAS, STALE_LSB, \
    TRAPEZOID_VAR
from estimation.ekf_filter import StrapdownFilter
from estimation.ekf_policies import KeepInside, LatencyWatch

GROUPS = ("gyro", "accel", "encoders")
_isfinite = math.isfinite


def finite_reading(v) -> bool:
    """A sensor reading that arrived (not None) with every value finite."""
    # a finite sum proves every value finite (NaN and ±inf propagate); only a sum that
    # overflowed from huge finite values needs the values one by one
    return v is not None and (math.isfinite(sum(v)) or all(map(math.isfinite, v)))


class Books:
    """What the filter did with the sensors' samples over one run: accepted and rejected samples
    per sensor (:data:`GROUPS`), the other counts of :meth:`estimation.ekf.EKFEstimator.stats`,
    and the events, (t in s, what) each."""

    def __init__(self):
        self.accepted = dict.fromkeys(GROUPS, 0)
        self.rejected = dict.fromkeys(GROUPS, 0)
        self.predict_only = 0  # steps without an encoder update
        self.unchanged_encoders = 0  # encoder samples whose counts had not changed
        self.interval_updates = 0  # truncated updates that brought the estimate back into a count
        self.saturated = 0  # IMU samples at their rails
        self.stale = 0  # repeated IMU samples
        self.accel_outliers = 0  # accelerometer halves replaced by the model's (the gyro's kept)
        self.latency_changes = 0
        self.resets = 0  # restorations of the last good state
        self.resyncs = 0  # encoder samples forced in after rejections in a row, and re-based zeros
        self.events: list[tuple[float, str]] = []


class Clock:
    """The instants' times: ``t0`` (s, the first measurement's) plus k periods of ``model.dt``,
    or (``rows``, a log whose rows are its instants) each instant's own time, kept in
    :attr:`times` by the estimator back to what a step may still ask for."""

    def __init__(self, model, rows: bool, nominal_dt: float):
        self.model, self.rows, self.nominal_dt = model, rows, nominal_dt
        self.t0 = 0.0  # s: the first measurement's time
        self.times: dict[int, float] = {}
        self.times_from = 0  # the oldest instant kept in times

    def now(self, k: int) -> float:
        """s: the time of instant ``k``."""
        if self.rows and k in self.times:
            return self.times[k]
        return self.t0 + k * self.model.dt

    def span(self, a: int, b: int) -> float:
        """s from instant ``a`` to instant ``b`` (rows: their times; before the first instant, the
        nominal period)."""
        if not self.rows:
            return (b - a) * self.model.dt
        ta, tb = self.times.get(a), self.times.get(b)
        if ta is None:
            ta = self.t0 + a * self.nominal_dt
        if tb is None:
            tb = self.t0 + b * self.nominal_dt
        return tb - ta


class SensorFrontEnd:
    """The sensor front end of the EKF (see the module docstring) for filter ``f`` (its model,
    period, encoder geometry and the ADC's limits), the nominal latencies ``d_imu``, ``d_enc``
    (control periods), ``max_rejects_in_row`` (encoder jumps and implausible unchanged counts in
    a row before the counter is re-based or the encoders taken as stuck), ``stuck_sigmas`` (σ
    outside an unchanged count at which it is implausible) and ``watches`` (the gyro's latency
    is watched; :data:`torque_sign` the sign equation (1) gives the correlation)."""

    def __init__(self, f: StrapdownFilter, d_imu: int, d_enc: int, max_rejects_in_row: int, stuck_sigmas: float,
                 watches: bool, torque_sign: float):
        self.f = f
        self.every, self.d_imu, self.d_enc = f.every, int(d_imu), int(d_enc)
        self.max_rejects_in_row = int(max_rejects_in_row)
        self.watches, self.torque_sign = watches, torque_sign
        self.imu_sampling = "mean"  # or "point" (see EKFEstimator.set_sampling)
        self.delta, self.limits = f.delta, f.limits
        g, a = f.model.imu.gyro, f.model.imu.accel
        # a reading within RAIL_SIGMAS white-noise σ of the ADC's limits is no measurement (see railed)
        self.rails = tuple(lim - RAIL_SIGMAS * tr.white_sigma(f.dt) for lim, tr in zip(f.limits, (g, g, a, a)))
        # a stale (repeated) triad is told from a real one where the white noise per sample
        # spans ≥ 4 ADC steps: three axes then repeat by chance with probability < 4e-4
        self.stale_check = tuple(t.white_sigma(f.dt) >= STALE_LSB * t.lsb for t in (g, a))
        # a wheel's counts cannot move faster than this relative to the body, nor leave a
        # 32-bit counter's range: anything else is a fault (see screen_encoders)
        self.max_wheel_rate = MAX_RIM_SPEED / f.r
        self.enc_range = COUNTER_RANGE * f.delta
        self.inside = KeepInside(f.H, f.b_r, f.alpha0, f.delta, stuck_sigmas)
        self.books = self.clock = None

    def new_run(self, books: Books, clock: Clock) -> None:
        """Nothing of a previous run: empty queues, the nominal latencies, a fresh watch."""
        self.books, self.clock = books, clock
        self.gyro: dict[int, tuple] = {}  # by sample time (control step), each half on its own latency
        self.acc: dict[int, tuple] = {}
        self.enc: dict[int, tuple] = {}
        self.pvar_g: dict[int, tuple] = {}  # point samples: the rebuilt means' own variances (point_means)
        self.pvar_a: dict[int, tuple] = {}
        self.points = None  # point-sampled IMU: the last (gyro, accel, instant) taken (see point_means)
        self.d_gyro = self.d_acc = self.d_imu  # the latencies assumed now (periods); the watch may change them
        self.lag = max(self.d_imu, self.d_enc)
        self.last_imu = None  # the last (gyro, accel) triads that arrived
        self.stale_in_row = 0
        # the latency watch (None: not watched, see EKFEstimator.__init__ and set_sampling)
        self.watch = LatencyWatch(self.torque_sign) if self.watches else None
        self.last_enc = None  # the encoder counts last used (rad), and their sample time
        self.last_enc_m = 0
        self.enc_seen_t = None  # s: the last encoder reading that arrived
        self.implausible = 0  # encoder jumps in a row (screen_encoders)
        self.still = 0  # unchanged counts in a row with the estimate implausibly far outside them
        self.stuck_since = None  # s: when the encoders were taken as stuck (None: they count)
        self.stuck_total = 0.0  # s spent with the encoders taken as stuck

    def start(self, meas) -> None:
        """The first measurement (instant 0): its samples queued, its counts the first used."""
        self.store(meas, 0, 0, None)
        if finite_reading(meas.encoders):
            self.enc_seen_t = self.clock.t0
            self.last_enc, self.last_enc_m = tuple(meas.encoders), -self.d_enc

    # ---- the readings as they arrive -----------------------------------------------------------
    def store(self, meas, k: int, m: int, command) -> int:
        """Screen and queue the readings ``meas`` that arrived at instant ``k`` (the filter at
        sample time ``m``, ``command`` (ul, ur) N·m over the period that just ended); returns
        the periods the filter runs behind now (the latency watch may have grown them)."""
        books = self.books
        gyro, accel, enc = meas.gyro, meas.accel, meas.encoders
        # all three arrived and finite (a finite sum proves it; see finite_reading), the common
        # case, in one test; else each on its own
        if gyro is not None and accel is not None and enc is not None and \
                _isfinite(sum(gyro) + sum(accel) + sum(enc)):
            g_ok = a_ok = e_ok = True
        else:
            ok = finite_reading
            g_ok, a_ok, e_ok = ok(gyro), ok(accel), ok(enc)
        if not (g_ok and a_ok and e_ok):  # (the loop below only when a reading is missing or bad)
            for n, v, good in (("gyro", gyro, g_ok), ("accel", accel, a_ok), ("encoders", enc, e_ok)):
                if v is not None and not good:
                    books.events.append((meas.t, f"non-finite {n} reading ignored"))
        g_stale = False  # the gyro triad repeats the previous one (for the latency watch)
        if g_ok or a_ok:
            # each half on its own latency: they pair up by sample time in due()
            g_new, a_new = (tuple(gyro) if g_ok else None), (tuple(accel) if a_ok else None)
            last_g, last_a = self.last_imu if self.last_imu is not None else (None, None)
            # with the noise several ADC steps wide, a triad repeating all three values is
            # stale (stuck), not a measurement: coast as without the sample
            g_stale = self.stale_check[0] and g_new is not None and g_new == last_g
            if g_stale or (self.stale_check[1] and a_new is not None and a_new == last_a):
                books.rejected["gyro"] += 1
                books.rejected["accel"] += 1
                books.stale += 1
                if self.stale_in_row == 0:
                    books.events.append((meas.t, "IMU sample repeats the previous one: stale, treated as missing"))
                self.stale_in_row += 1
            else:
                pvar = None
                if self.imu_sampling == "point":  # the interval's mean from its two ends (see set_sampling)
                    gyro, accel, pvar = self.point_means(k, gyro if g_ok else None, accel if a_ok else None)
                # a sample for a time the filter has already passed (just after the assumed
                # latency grew) can no longer be used
                if g_ok and k - self.d_gyro > m:
                    self.gyro[k - self.d_gyro] = gyro
                    if pvar is not None:
                        self.pvar_g[k - self.d_gyro] = pvar[0]
                if a_ok and k - self.d_acc > m:
                    self.acc[k - self.d_acc] = accel
                    if pvar is not None:
                        self.pvar_a[k - self.d_acc] = pvar[1]
                self.stale_in_row = 0
            self.last_imu = (g_new if g_ok else last_g, a_new if a_ok else last_a)
        watch = self.watch
        if watch is not None and k > 0:
            # the watch correlates only gyro samples that measure the rate: not those the filter
            # rejected as outliers (its IMU rejections less the stale ones; it has used the samples
            # up to m), nor a stale or a clipped one (within RAIL_SIGMAS σ of the rail). Every other
            # sample is correlated, however large its second difference: see LatencyWatch for why
            # a size screen made false events during pushes
            watch.filter_verdicts(m, books.rejected["gyro"] - books.stale, self.d_gyro)
            found = watch.observe(meas.t, k, gyro if g_ok else None, a_ok, command, self.d_gyro,
                                  g_ok and not g_stale and abs(gyro[1]) < self.rails[0])
            if found is not None:
                self.latency_changed(meas.t, k, m, *found)
        if e_ok:
            if -self.enc_range <= enc[0] <= self.enc_range and -self.enc_range <= enc[1] <= self.enc_range:
                self.enc[k - self.d_enc] = enc
            else:
                books.events.append((meas.t, f"encoder reading {tuple(enc)} ignored: beyond a 32-bit "
                                             f"counter's range (±{self.enc_range:.4g} rad)"))
        return self.lag

    def point_means(self, k: int, gyro, accel):
        """(gyro, accel, variances) of sample instant ``k`` as interval means from point samples
        (see :meth:`estimation.ekf.EKFEstimator.set_sampling`), remembering this instant's for the
        next. ``variances``: ((ω_y, ω_z, h_y, h_z), (f_x, f_z, h_x, h_z)) the mean's own
        uncertainty about the trapezoid, and h 1.0 where the mean is the average of two samples
        (its noise then half the previous interval's: see
        :meth:`estimation.ekf_filter.StrapdownFilter.propagate`), as for ψ's
        (:data:`~estimation.ekf_config.TRAPEZOID_VAR`): with the signal monotonic between its two
        samples a and b, the interval's mean lies anywhere between them, taken uniform:
        (b − a)² / 12. The trapezoid is exact for a linear change; a catch's rate, which rises
        within a few ms and then levels off, is not, and a 30 ms row holds it all (on 33 Hz rows
        of a robot standing up from 0.5 rad: 0.035 rad of θ in one row)."""
        prev = self.points
        out, var = [], []
        for j, v in enumerate((gyro, accel)):
            p = prev[j] if prev is not None and prev[2] == k - self.every else None
            if v is None or p is None:
                out.append(v)
                var.append((0.0, 0.0, 0.0, 0.0))
                continue
            rail = self.rails[2 * j]
            out.append(tuple(a if abs(a) >= rail else (b if abs(b) >= rail else 0.5 * (a + b)) for a, b in zip(v, p)))
            axes = (1, 2) if j == 0 else (0, 2)
            var.append(tuple((v[i] - p[i]) ** 2 * TRAPEZOID_VAR for i in axes)
                       + tuple(float(abs(v[i]) < rail and abs(p[i]) < rail) for i in axes))
        self.points = (gyro, accel, k)
        return out[0], out[1], var

    def latency_changed(self, t: float, k: int, m: int, new: int, rho: float) -> None:
        """The gyro's latency is now ``new`` periods: re-align the samples not yet used (the
        filter is at sample time ``m``), and the accelerometer's too if it fell behind by as
        much at the same time (both halves of the IMU then stopped arriving for the same span: a
        gap of ``new − old`` samples in each, within a period of each other; an
        accelerometer-only change is not detected)."""
        old, delta = self.d_gyro, new - self.d_gyro
        acc = self.watch.accel_gapped(delta)
        dt_ms = 1e3 * self.f.model.dt
        for store, d in ((self.gyro, delta), (self.acc, delta if acc else 0)):
            if d:
                moved = {key - d: v for key, v in store.items() if key > m}
                for key in [key for key in store if key > m]:
                    del store[key]
                store.update({key: v for key, v in moved.items() if key > m})
        self.d_gyro = new
        if acc:
            self.d_acc += delta
        self.lag = max(self.d_gyro, self.d_acc, self.d_enc)
        self.books.latency_changes += 1
        self.watch.changed(k)
        what = "gyro and accelerometer latency" if acc else "gyro latency"
        self.books.events.append((t, f"{what} changed: now about {new * dt_ms:.0f} ms (was {old * dt_ms:.0f} ms; "
                                     f"correlation with the commands {rho:.2f}): re-aligned, the filter now runs "
                                     f"{self.lag} periods behind"))

    # ---- the samples of one filter step ------------------------------------------------------
    def due(self, m: int, t: float, since: int):
        """(imu, rail, enc): the samples of sample time ``m`` (time ``t``), screened: ``imu`` the
        (gyro, accel) pair (point samples: with their variances and trapezoid flags) or None,
        ``rail`` None or what :meth:`railed` says of it, ``enc`` the counts or None (see
        :meth:`screen_encoders`). The queues forget the samples before ``m − every`` back to the
        previous step's ``since`` (no step will need them again)."""
        g, a = self.gyro.get(m), self.acc.get(m)
        imu = None if g is None or a is None else (g, a)
        if imu is not None and self.imu_sampling == "point":
            gv, av = self.pvar_g.get(m, (0.0,) * 4), self.pvar_a.get(m, (0.0,) * 4)
            imu = (g, a, (gv[0], gv[1], av[0], av[1]), (gv[2], gv[3], av[2], av[3]))
        if imu is None and (g is not None or a is not None):
            self.books.events.append((t, "an IMU sample without its gyro or accelerometer half was dropped"))
        enc = self.screen_encoders(self.enc.get(m), m, t)
        for j in range(since - self.every, m - self.every):  # samples no step will need again
            self.gyro.pop(j, None)
            self.acc.pop(j, None)
            self.enc.pop(j, None)
            if self.pvar_g or self.pvar_a:
                self.pvar_g.pop(j, None)
                self.pvar_a.pop(j, None)
        return imu, (None if imu is None else self.railed(imu)), enc

    def railed(self, imu):
        """None, or the IMU reading (ω_y, ω_z, f_x, f_z) and which axes of it are censored.

        A clipped reading says only "at least this much": it measures neither the rate nor the
        scale factor nor the bias, so it must not be fused as a measurement (PX4's EKF2 likewise
        counts clipped IMU samples and stops learning the biases on a clipped axis). A reading
        within :data:`~estimation.ekf_config.RAIL_SIGMAS` σ of the rail is censored too: its
        noise is cut off by the rail (a censored Gaussian is not the white noise the filter
        assumes). Such an axis is taken from equation (1), with the model's uncertainty, by the
        coasting step (:class:`estimation.ekf_filter.Coasting`); the other axes stay readings."""
        (_, wy, wz), (fx, _, fz) = imu[0], imu[1]
        r = self.rails
        if abs(wy) < r[0] and abs(wz) < r[1] and abs(fx) < r[2] and abs(fz) < r[3]:
            return None
        v = (wy, wz, fx, fz)
        return v, tuple(abs(a) >= b for a, b in zip(v, r))

    # ---- the encoders ----------------------------------------------------------------------
    def screen_encoders(self, enc, m: int, t: float):
        """``enc``, or None if its counts moved further since the last sample used than a wheel
        can turn relative to the body (:data:`~estimation.ekf_config.MAX_RIM_SPEED` at the rim,
        plus two counts), or the encoders are taken as stuck and a count is still unchanged
        (:meth:`count_check`). Such a jump is a fault of the encoders, not motion, so it never
        reaches the χ² gate and is never forced in. After ``max_rejects_in_row`` in a row the
        counts are taken to have jumped for good (a counter reset): their zeros c, h are re-based
        onto the reading, with the filter's uncertainty of the reading as theirs."""
        if enc is None:
            return None
        self.enc_seen_t = t
        if self.last_enc is None:
            self.last_enc, self.last_enc_m = tuple(enc), m
            return enc
        last = self.last_enc
        books = self.books
        if self.stuck_since is not None:  # (see count_check)
            if enc[0] == last[0] or enc[1] == last[1]:
                books.rejected["encoders"] += 1
                return None
            self.stuck_total += t - self.stuck_since
            books.events.append((t, f"encoder counts change again after {t - self.stuck_since:.3g} s stuck: "
                                    "used again"))
            self.stuck_since = None
            self.still = 0
        T = self.clock.span(self.last_enc_m, m)
        limit = self.max_wheel_rate * T + 2.0 * self.delta
        jump = max(abs(enc[0] - last[0]), abs(enc[1] - last[1]))
        if jump <= limit:
            self.implausible = 0
            return enc
        books.rejected["encoders"] += 1
        self.implausible += 1
        if self.implausible == 1:
            books.events.append((t, f"encoder counts jumped {jump:.4g} rad in {T:.3g} s, more than a wheel can turn "
                                    f"({limit:.3g} rad): rejected"))
        if self.implausible >= self.max_rejects_in_row:
            y = self.f.rebase_encoders(enc)
            self.last_enc, self.last_enc_m = tuple(enc), m
            self.implausible = 0
            books.resyncs += 1
            books.events.append((t, f"encoder counts stayed {self.max_rejects_in_row} samples away from the "
                                    f"estimate: re-based their zeros by ({y[0]:.4g}, {y[1]:.4g}) rad"))
        return None

    def used(self, enc, m: int) -> None:
        """The filter took encoder sample ``enc`` at sample time ``m``: the counts to compare with next."""
        self.last_enc, self.last_enc_m = tuple(enc), m

    def keep_inside(self, enc, update, t: float) -> None:
        """For each wheel whose count has not changed since the last sample used: if the
        estimate has left that count by more than :data:`~estimation.ekf_config.INSIDE_MARGIN`
        counts, the truncated update (``update(measurement)``) that brings it back.

        The wheel lies in [reading − Δ/2, reading + Δ/2) (the filter's frame of the count).
        An unchanged count is skipped as a measurement (its quantisation error is the same
        one again), but while a wheel dwells in one count for tenths of a second, v runs free
        on the accelerometer and the estimate drifts out of the count (ψ̂ up to 0.033 rad
        off in 600 s of paper-exp2). Outside the count, "still inside" is an active
        constraint: the prior of that wheel's angle, N(w, s²), is truncated to the interval
        and the state takes the truncated mean and variance (Simon & Simon, "Constrained
        Kalman filtering via density function truncation", 2010), written as the equivalent
        measurement (z, R) so that the update, Schmidt rows and all, is the ordinary one.

        Why only outside, and why a margin: the filter keeps a Gaussian, so after a
        truncation its tails reach past the count again, and the next sample's drift would
        truncate them again: the same information counted again and again, the overconfidence
        that made unchanged counts a skipped measurement in the first place. Truncating at the
        count's own edges (margin 0) made 818 updates in 20 runs × 3 s (from 0.05 rad, the
        nominal design) and took the encoders' NIS per degree of freedom from 0.93 to 0.74 and
        the mean NEES from 12.6 to 13.0; a margin of one count each side (a true but weaker
        constraint) makes 22, leaves NIS 0.99 and NEES 12.7, and still bounds the excursion
        (ψ̂ − ψ at most 0.011 rad in 600 s of paper-exp2, against 0.0051 rad with margin 0
        and 0.031 rad without). A mean more than the IMU
        gate's σ outside is left to the gate of the next edge (the filter, not the count, is
        then in doubt)."""
        last = self.last_enc
        if last is None:
            return
        for em in self.inside.measurements(enc, last, self.f.kf):  # (:class:`~estimation.ekf_policies.KeepInside`)
            update(em)
            self.books.interval_updates += 1
        self.count_check(t, self.inside.implausible)

    def count_check(self, t: float, implausible: int) -> None:
        """After an encoder sample: ``implausible`` the mask of wheels whose count did not
        change although the estimate lies more than 3.72 σ (the encoder gate's probability,
        one-sided) outside it.

        Encoders that stop counting (a frozen reading, a broken wire) are not a latency change
        nor a robot standing still: while the robot moves, the IMU-driven prediction leaves the
        count, and an unchanged count then is a rejected measurement (no truncated update:
        :meth:`keep_inside`). After ``max_rejects_in_row`` such samples in a row the encoders
        are taken as stuck (logged; :meth:`degraded` reports the position as degraded): until
        both counts change again, their samples are dropped, and the position and speed come
        from the IMU alone, their covariance growing as it must. A robot that creeps at under a
        count per period's σ cannot be told from a stuck encoder by the IMU (it measures
        acceleration, not speed); there the truncation keeps the estimate at the count, which is
        as good as the IMU can do."""
        if not implausible:
            self.still = 0
            return
        self.books.rejected["encoders"] += 1
        self.still += 1
        if self.still >= self.max_rejects_in_row and self.stuck_since is None:
            self.stuck_since = t
            which = {1: "left encoder's count", 2: "right encoder's count"}.get(implausible, "encoder counts")
            self.books.events.append((t, f"{which} unchanged for {self.still} samples while the IMU shows the "
                                         "wheels turning: encoders taken as stuck, position and speed from the IMU "
                                         "alone"))

    def degraded(self, now: float) -> list[str]:
        """What the estimate has lost at time ``now`` (s), one line each (see
        :meth:`estimation.ekf.EKFEstimator.degraded`)."""
        out = []
        if self.stuck_since is not None:
            out.append(f"position: encoders stuck since t = {self.stuck_since:.3f} s (counts unchanged while the IMU "
                       "shows the wheels turning); position and speed from the IMU alone")
        elif self.enc_seen_t is None or now - self.enc_seen_t > ENCODERS_LOST_AFTER:
            since = self.clock.t0 if self.enc_seen_t is None else self.enc_seen_t
            out.append(f"position: no encoder sample since t = {since:.3f} s; position and speed from the IMU alone")
        return out


__all__ = ["Books", "Clock", "GROUPS", "SensorFrontEnd", "finite_reading"]
