"""One filter step per IMU instant: the front end's screened samples through the filter, under
the gates.

:class:`Fusion` takes the samples of one sample time (:meth:`estimation.ekf_frontend.SensorFrontEnd.due`)
and makes the step they call for: the IMU-driven strapdown step, fused in the compiled core
where it is built (its decisions booked here) or composed here on the core's predict and update
(the reference path); or, for a sample at its rails, missing, or an outlier, the coasting step
(:class:`estimation.ekf_filter.Coasting`). The decisions on the way are the policies'
(:mod:`estimation.ekf_policies`: the accelerometer test, the IMU outlier test and the encoder
gate of :class:`~estimation.ekf_policies.EncoderGate`, the truncation into an unchanged count);
what happens to an estimate that turns non-finite (the last good one restored) or leaves its
physical range (re-initialised, :meth:`Fusion.lost`) is decided here. The reasons are in the
module docstring of :mod:`estimation.ekf`.
"""
from __future__ import annotations

import math

import numpy as np

from estimation.ekf_config import GYRO_EXTRAPOLATION_SAMPLES
from estimation.ekf_core import _kernel
from estimation.ekf_filter import StrapdownFilter
from estimation.ekf_frontend import Books, Clock, SensorFrontEnd
from estimation.ekf_policies import AccelOutlierTest, EncoderGate

KERNEL = object()  # Fusion.innov: the last update's innovation is the compiled core's to report


class Fusion:
    """The step of each sample time for filter ``f`` and front end ``front`` under ``gate`` (the
    encoder and IMU gates; ``max_rejects_in_row`` its forced re-synchronisation)."""

    def __init__(self, f: StrapdownFilter, front: SensorFrontEnd, gate: EncoderGate):
        self.f, self.front, self.gate = f, front, gate
        self.gates, self.imu_gates = gate.gates, gate.imu_gates
        self.may_reject = gate.may_reject

    def new_run(self, books: Books, clock: Clock) -> None:
        """Nothing of a previous run; the filter's core is the run's (``f.new_run`` first)."""
        self.books, self.clock = books, clock
        core = self.f.core
        self.coasting = self.f.coasting  # the run's (StrapdownFilter.new_run)
        # the IMU-driven step: fused in the core where it can (the kernel), else composed here
        self.imu_step = self.imu_step_fused if core.fuses_imu_step else self.imu_step_composed
        self.core_advance = core.advance if core.fuses_imu_step else None
        self.accel = AccelOutlierTest(self.imu_gates[2], self.imu_gates[1])
        self.acc_out = False
        self.acc_e = None  # the last accelerometer innovation (m/s², (f_x, f_z)), None: not computed
        self.in_row = 0  # encoder samples rejected in a row
        self.last_nis, self.last_dof = math.nan, 0
        self.innov = None  # the last encoder update's (y, S), or KERNEL: ask the compiled core
        self.at = 0  # the sample time of the step under way (advance), for lost()

    def innovation(self):
        """The last encoder update's (y (dof,) rad, S (dof, dof) rad²), or None."""
        inn = self.innov
        if inn is KERNEL:  # the compiled core kept the update's y and S (estimation/_ekf.c)
            hook = getattr(_kernel, "innovation", None)  # None: a kernel built before it had one
            y, S = hook(self.f.core._core) if hook is not None else ((), ())
            inn = (np.array(y), np.array(S).reshape(len(y), len(y))) if len(y) else None
        return inn

    def advance(self, m: int, t: float, imu, rail, enc, command) -> None:
        """Predict from the filter's time to t_m with the IMU sample ``imu`` (``rail``: its axes
        at the rails, see :meth:`~estimation.ekf_frontend.SensorFrontEnd.railed`) and update with
        the encoders ``enc`` there, ``command`` (ul, ur) N·m held over the period."""
        self.at = m
        books = self.books
        if imu is not None:
            if rail is not None:  # the model stands in for the clipped axes
                books.saturated += 1
                books.accepted["gyro"] += 1
                books.accepted["accel"] += 1
                self.acc_out = False
                self.accel.seen(None, False)
                self.coast(m, t, True, enc, command, rail)
                return
            eps_imu = self.imu_step(m, t, imu, enc, command)
            acc_out = self.acc_out
            self.accel.seen(self.acc_e, acc_out)
            if acc_out:
                books.accel_outliers += 1
            if eps_imu is None:
                self.coasting.aug = None  # a real sample: ω is a reading again
                books.accepted["gyro"] += 1
                if acc_out:
                    books.rejected["accel"] += 1
                    books.events.append((t, "accelerometer sample rejected as an outlier (off the specific force "
                                            "equation (1) predicts): the model's used, the gyro's kept"))
                else:
                    books.accepted["accel"] += 1
                return
            books.rejected["gyro"] += 1
            books.rejected["accel"] += 1
            books.events.append((t, f"IMU sample rejected as an outlier (encoder NIS {eps_imu:.3g} with it)"))
        self.coast(m, t, imu is not None, enc, command)

    # ---- the IMU-driven step ------------------------------------------------------------------
    def imu_step_fused(self, m: int, t: float, imu, enc, command):
        """:meth:`imu_step_composed` fused in the core (the compiled kernel), the counts and
        events kept here from its decisions; returns the encoders' NIS with the sample if it is
        an outlier (the state then unchanged), else None."""
        sample = (imu[0][1], imu[0][2], imu[1][0], imu[1][2]) if len(imu) == 2 else \
            (imu[0][1], imu[0][2], imu[1][0], imu[1][2], *imu[2], *imu[3])
        front = self.front
        last = front.last_enc
        code_i, sat, code_e, nis, dof, ok, acc_out, ex, ez, inside = self.core_advance(
            sample, enc, last if enc is not None else None, self.clock.span(front.last_enc_m, m), command,
            self.in_row, self.accel.test)  # (the kernel forces a sample in as EncoderGate.may_reject does)
        self.acc_out = bool(acc_out)
        self.acc_e = (ex, ez)
        if code_i == 2:
            return nis
        books = self.books
        books.saturated += sat
        books.interval_updates += inside & 15
        if enc is not None and (inside > 15 or front.still):  # (a count is implausible, or a run of them ends)
            front.count_check(t, inside >> 4)
        if code_e <= 1:
            if code_e == 1:
                books.unchanged_encoders += 1
                front.last_enc_m = m
            books.predict_only += 1
        else:
            self.last_nis, self.last_dof = nis, dof
            self.innov = KERNEL
            if code_e == 3:
                books.rejected["encoders"] += 1
                self.in_row += 1
                books.predict_only += 1
            else:
                if code_e == 4:
                    books.resyncs += 1
                    books.events.append((t, f"encoders accepted after {self.in_row} rejections in a row "
                                            f"(NIS {nis:.3g} > gate {self.gates[dof]:.3g}): re-synchronising"))
                self.in_row = 0
                books.accepted["encoders"] += 1
                front.last_enc, front.last_enc_m = tuple(enc), m
        if ok < 0:  # finite but out of its physical range: re-initialised here
            core = self.f.core
            core.pull()
            self.lost(t)
            core.push()
            core.keep_good()
        elif not ok:
            books.resets += 1
            books.events.append((t, "the state or covariance became non-finite or lost positivity, or the update "
                                    "failed numerically; restored the last good estimate"))
        return None

    def imu_step_composed(self, m: int, t: float, imu, enc, command):
        """The IMU-driven step composed here on the core's predict and update (the reference
        path): the accelerometer test, the IMU outlier test, then the strapdown step; returns
        the encoders' NIS with the sample if it is an outlier (the state then unchanged), else None."""
        f = self.f
        sample, syn, sat, acc_out, rep = self.imu_sample(f.kf.x, imu, command, self.accel.test)
        half = None
        if len(imu) > 3:  # point samples (see propagate): which axes are trapezoids, which the reading's
            rep = rep or (False,) * 4
            half = [0.0 if r else float(h) for h, r in zip(imu[3], rep)] + [0.0 if r else 1.0 for r in rep]
        pred = f.propagate(f.kf.x, sample, half=half)
        eps_imu = None if enc is None else self.imu_outlier(pred, syn, enc, m, command)
        if eps_imu is None:
            self.books.saturated += sat
            f.Cx = f.Cx_next
            f.predict(pred)
            self.encoder_step(enc, m, t, True, f.update)
            self.finish(t)
        else:
            f.Cx = None
        self.acc_out = acc_out
        return eps_imu

    def imu_sample(self, x, imu, command, acc_test):
        """(sample, synthetic, saturated, accel outlier, replaced): the IMU reading as ((ω_y, ω_z,
        f_x, f_z), extra) for :meth:`~estimation.ekf_filter.StrapdownFilter.propagate`; an axis at
        the end of its range says only "at least this much", so the model's prediction
        (``synthetic``, else None) replaces it (``extra`` then holds the variances it adds; None
        for a sample with no axis replaced; ``replaced`` which axes, None for none). (A guard:
        the front end's ``railed`` sends every sample within 3 σ of the rail to the coasting step
        first, so ``saturated`` is False on the filter's own path; the kernel keeps the same
        guard.) With ``acc_test`` (:attr:`~estimation.ekf_policies.AccelOutlierTest.test`) the
        accelerometer half is tested against the model's first and, an outlier, replaced by it:
        the gyro half is kept."""
        f = self.f
        own = imu[2] if len(imu) > 2 else None  # the variances a rebuilt point sample adds (point_means)
        sample = ((imu[0][1], imu[0][2], imu[1][0], imu[1][2]), None if own is None else np.array(own))
        sat = [abs(v) >= lim for v, lim in zip(sample[0], f.limits)]
        syn, acc_out = None, False
        self.acc_e = None
        if acc_test is not None and acc_test[0] > 0.0 and not (sat[2] or sat[3]):
            syn = f.synthetic(x, command)
            e, sx, sz = f.accel_innovation(x, sample[0], syn)
            self.acc_e = e
            # a push moves the specific force too, but also θ̈, which the gyro sees (its NIS
            # against the model: ≤ 18 on fault-free runs, 10³–10⁵ in a push): an accelerometer
            # outlier needs a gyro sample that agrees with the model (the 1 − 1e-9 gate). The
            # gyro's variance: its noise in this sample and in the two the model's θ̇ is
            # extrapolated from (1 + 1.5² + 0.5²), and the model's torque uncertainty
            eg, sg = sample[0][0] - syn[0][0], GYRO_EXTRAPOLATION_SAMPLES * f.g_var + syn[1][0]
            acc_out = self.accel.is_outlier(acc_test, e, sx, sz, eg, sg)
        if not any(sat) and not acc_out:
            return sample, syn, False, False, None
        if syn is None:
            syn = f.synthetic(x, command)
        rep = [sat[0], sat[1], sat[2] or acc_out, sat[3] or acc_out]
        own = (0.0,) * 4 if own is None else own
        return (tuple(sv if k else v for v, sv, k in zip(sample[0], syn[0], rep)),
                tuple(e if k else o for e, k, o in zip(syn[1], rep, own))), syn, any(sat), acc_out, rep

    def imu_outlier(self, pred, syn, enc, m: int, command):
        """The encoders' NIS with the IMU sample behind ``pred`` (its step; ``syn`` the model's
        sample if already computed) if :meth:`~estimation.ekf_policies.EncoderGate.imu_outlier`
        marks the sample as an outlier, else None: the encoders (every wheel, an unchanged one as
        "still inside its count") fail the IMU gate with the sample, and pass the normal gate
        with the sample equation (1) predicts instead."""
        f, front = self.f, self.front
        x, P = f.kf.x, f.kf.P
        last, T = front.last_enc, self.clock.span(front.last_enc_m, m)
        tm, eps, _ = f.encoder_fit(enc, last, T, pred, P, test=True)

        def alternative():
            alt = f.propagate(x, syn if syn is not None else f.synthetic(x, command))
            tm_alt, eps_alt, _ = f.encoder_fit(enc, last, T, alt, P, test=True)
            return eps_alt, len(tm_alt[0])

        return eps if self.gate.imu_outlier(eps, len(tm[0]), alternative) else None

    # ---- the coasting step --------------------------------------------------------------------
    def coast(self, m: int, t: float, had_imu: bool, enc, command, rail=None) -> None:
        """The step where equation (1) stands in for the IMU (see
        :class:`~estimation.ekf_filter.Coasting`), on the core's Python-side state."""
        f = self.f
        f.core.take_over()
        if not had_imu:
            self.books.predict_only += 1
        update = f.coasting.predict(command, rail)
        self.encoder_step(enc, m, t, had_imu, update)
        self.finish(t)
        f.core.push()

    # ---- the encoders' update -----------------------------------------------------------------
    def encoder_step(self, enc, m: int, t: float, had_imu: bool, update) -> None:
        """The gated encoder update after a prediction, with ``update(measurement)``."""
        f, front, books = self.f, self.front, self.books
        em = eps = None
        raw = enc
        if enc is not None:
            em, eps, fit = f.encoder_fit(enc, front.last_enc, self.clock.span(front.last_enc_m, m), None, None)
            if em is None:  # unchanged counts: no edge was crossed (no new information)
                books.unchanged_encoders += 1
                front.last_enc_m = m
                enc = None
        if enc is None:
            if had_imu:
                books.predict_only += 1
            if em is None and raw is not None:  # unchanged counts: the wheels are still inside them
                front.keep_inside(raw, update, t)
        elif self.passes(em, t, eps, fit):
            update(em)
            books.accepted["encoders"] += 1
            front.keep_inside(enc, update, t)
            front.used(enc, m)
        elif had_imu:  # rejected: the step was a prediction only (without IMU, counted already)
            books.predict_only += 1

    def passes(self, em, t: float, eps: float, fit) -> bool:
        """The χ² gate for encoder measurement ``em`` whose NIS is ``eps`` (innovation and its
        covariance ``fit``): True to use it (a pass, or forced in after ``max_rejects_in_row``
        rejections in a row)."""
        dof = len(em[0])
        self.last_nis, self.last_dof = eps, dof
        self.innov = fit
        if not self.gate.passes(eps, dof):
            if self.may_reject(self.in_row):
                self.books.rejected["encoders"] += 1
                self.in_row += 1
                return False
            self.books.resyncs += 1
            self.books.events.append((t, f"encoders accepted after {self.in_row} rejections in a row "
                                         f"(NIS {eps:.3g} > gate {self.gates[dof]:.3g}): re-synchronising"))
        self.in_row = 0
        return True

    # ---- a broken or lost estimate -------------------------------------------------------------
    def finish(self, t: float) -> None:
        """After a step on the Python side: keep the state as the last good one, re-initialise it
        if it left its physical range (:meth:`lost`), restore the last good one if it broke."""
        health = self.f.symmetrised_health()
        if health:
            if health < 0:
                self.lost(t)
            self.f.core.keep_good()
        else:
            self.restore(t, "the state or covariance became non-finite or lost positivity; "
                            "restored the last good estimate")

    def lost(self, t: float) -> None:
        """The estimate left its physical range
        (:meth:`~estimation.ekf_filter.StrapdownFilter.in_range`): re-initialise it, logged.

        Going on from such a state only diverges further (the heading's secant, then the
        speed, run away) and restoring the last good state, just as close to the edge, repeats
        the divergence with the covariance inflated each time. So the filter starts again as
        :meth:`estimation.ekf.EKFEstimator.start` does, from the accelerometer's reading at the
        filter's time, but for a robot that may be moving
        (:meth:`~estimation.ekf_filter.StrapdownFilter.reinitialise`)."""
        front = self.front
        acc = front.acc.get(self.at)
        if acc is None and front.last_imu is not None:
            acc = front.last_imu[1]
        self.f.reinitialise(acc, front.last_enc)
        # (an event, not one of the ``resets``: those count restorations of the last good state)
        self.books.events.append((t, "the estimate left its physical range (|θ| ≥ π/2, θ's variance beyond a "
                                     "tilt's whole range, or a covariance no longer positive definite): "
                                     "re-initialised from the accelerometer, the robot taken as possibly moving"))

    def restore(self, t: float, why: str) -> None:
        """The last good state, its covariance inflated; ``why`` logged."""
        self.f.restore()
        self.books.resets += 1
        self.books.events.append((t, why))


__all__ = ["Fusion", "KERNEL"]
