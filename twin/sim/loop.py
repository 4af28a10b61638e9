"""The steppable closed loop: plant → sensors → estimator → controller → actuators.

:class:`ClosedLoop` is the one loop every consumer drives: :func:`twin.sim.bullet_loop.simulate_twin`
(and through it the scenario runner and the sweeps), the Gymnasium environment and a
user's own script or test.

One control period (T = 1 / control_rate, a whole number of physics steps)::

    loop.reset(seed)          # instant 0: truth, readings, estimator.start → estimate
    while loop.status == "running":
        u = loop.command()    # the controller on the current estimate: (ul, ur, *signals)
        loop.step(u)          # apply (ul, ur) N·m for T; instant k+1: truth, readings, estimate

``step(command)`` takes any (ul, ur) in N·m (the torques a reinforcement-learning agent
chooses, say); without one it asks the controller. At every instant the loop exposes
:attr:`truth` (:class:`~twin.plant.base.GroundTruth`), :attr:`measurement` (what
reached the estimator), :attr:`estimate` (6,) and, after a step, :attr:`actuation` and
:attr:`push_force` (what the motors and pushes did over the period).

Outputs. ``reset`` and ``step`` return a :class:`~twin.protocols.StepResult`: everything
the loop publishes at the instant (truth, measurement, the gyro's true bias, estimate,
status) and over the period that ended there (actuation, push force). A logger is fed
these, never the loop's internals: :class:`twin.sim.recorder.Recorder` (what
:func:`twin.sim.bullet_loop.simulate_twin` logs into a :class:`twin.sim.runs.Run`) or one's own::

    rows = [loop.reset(seed)]
    while loop.status == "running":
        rows.append(loop.step())

At the end of a run :meth:`ClosedLoop.estimator_stats`, :meth:`ClosedLoop.sensor_counts`
and :meth:`ClosedLoop.sensor_truth` give the counts and the sensors' drawn constants.

The plant: any object meeting :class:`twin.protocols.Plant` (the PyBullet twin, equation
(1), one's own; :func:`twin.registry.build_plant` makes a scenario's ``plant.model``), which
the loop knows by that contract alone: :meth:`ClosedLoop.reset` calls its ``reset(theta0,
alpha0, position)``, each step its ``step(ul, ur)``; the control rate is the plant's, the
sensors read its truth and (for the IMU) its ``kinematics``. Given a
:class:`~twin.plant.base.TwinConfig` (or None: the defaults), the plant is the PyBullet twin
on it. A plant's missing member, or a truth that is not 15 numbers, is a one-line
:class:`~twin.errors.PluginError` naming the plant and the contract (a plant that declares
``trusted``, as the built-ins do, has its truth taken as it is).

Sensing. With a :class:`~twin.sensors.SensorConfig` the IMU and encoders are simulated
with their noise and faults, drawn from ``numpy.random.default_rng(SeedSequence(seed))``
and nothing else; with ``sensors=None`` nothing is measured and each measurement
carries only its time. An estimator that declares ``reads_truth = True`` (the ``ideal``
reference) also gets the ground truth in ``measurement.truth``; no other does. The extra
sensors of ``SensorConfig.extra`` (the motor current, :mod:`twin.sensors.types`) read what the
plant reports at each instant (:class:`twin.sensors.channels.Sources`: its truth, the actuation
of the period that just ended, the motors it drives its wheels through); a sensor that needs
motors on a plant with ideal torque sources is a one-line error at :meth:`ClosedLoop.reset`.

Contracts. The controller's output and the estimator's are checked at every step (here
alone: every consumer runs this loop); a
wrong length, a non-number or a non-finite value stops the run with a one-line
:class:`~twin.errors.PluginError` naming the object.

Limits. With ``limits`` (:class:`twin.limits.PluginLimits`: a scenario's
``[limits]``) each call of the controller and of the estimator is timed, and a call over
``step_wall_s``, a run over ``run_wall_s`` (from :meth:`ClosedLoop.reset`) or a process
whose resident memory grew by more than ``run_memory_mb`` over the run stops it with a
one-line PluginError naming the plugin and the limit. Without limits nothing is timed.
"""
from __future__ import annotations

from math import isfinite
from time import perf_counter
from typing import Sequence

import numpy as np

from twin.errors import MAY_NOT_END, PluginError, TwinError, ends_process, raised_text, shown
from twin import limits as _limits
from twin.limits import PluginLimits, RunGuard
from twin.plant.base import Actuation, GroundTruth, TwinConfig
from twin.protocols import StepResult, Targets, describe_object, one_line
from twin.registry import build_plant, check_plant, check_protocol
from twin.sensors import ImuMotion, Measurement, SensorConfig, SensorSuite
from twin.sensors.channels import Sources
from twin.sensors.types import type_of

_IDLE = "idle"


class ClosedLoop:
    """A plant with sensors, an estimator and (optionally) a controller, one control period per step.

    Parameters
    ----------
    config : TwinConfig, Plant or None
        An object meeting :class:`twin.protocols.Plant` (a built-in or one's own, as
        :func:`twin.registry.build_plant` makes them), reset by every :meth:`reset`. Or a
        TwinConfig (None: the defaults): the PyBullet twin on it (the ``"bullet"`` kind),
        built at the first :meth:`reset`.
    estimator : Estimator
        Meets :class:`twin.protocols.Estimator`; reused by every :meth:`reset` (its
        ``start`` begins a new run).
    controller : Controller or None
        Meets :class:`twin.protocols.Controller`; None: every :meth:`step` needs a command.
    sensors : SensorConfig or None
        The IMU, encoders and faults; None: nothing is measured (use the ``ideal`` estimator).
    targets : Targets
        p_d (m) and α_d (rad) handed to the controller; None where that loop is off.
    theta0, alpha0 : float
        Initial pitch and heading, rad.
    position : (float, float)
        Initial axle midpoint (x, y) in m.
    limits : PluginLimits or None
        What the controller and the estimator may cost (:mod:`twin.limits`); None: no limits.
    """

    def __init__(self, config, estimator, controller=None, sensors: SensorConfig | None = None,
                 targets: Targets = Targets(), theta0: float = 0.0, alpha0: float = 0.0, position=(0.0, 0.0),
                 limits=None):
        if sensors is not None and not isinstance(sensors, SensorConfig):
            raise TwinError(f"sensors must be a SensorConfig or None (nothing measured), got {sensors!r}")
        if config is None or isinstance(config, TwinConfig):  # the "bullet" kind on it, built at the first reset
            self.config = config if config is not None else TwinConfig()
            self._given = None
            control_rate = self.config.control_rate
        else:
            check_plant(config, sensors is not None)
            self._given = config
            own = getattr(config, "config", None)
            self.config = own if isinstance(own, TwinConfig) else None
            control_rate = float(config.control_rate)
        # a plant that does not say its truth is sound (Plant.trusted): checked at every step
        self._foreign = self._given is not None and not getattr(self._given, "trusted", False)
        if sensors is not None:
            sensors.steps(control_rate)  # rates and latencies fit the control period: check first
            if self._given is None:  # the PyBullet twin on config: its motors are config.motor
                self._needs_check(self.config.motor, "bullet", sensors)
        if not isinstance(targets, Targets):
            raise TwinError(f"targets must be a twin.protocols.Targets(position, heading), got {targets!r}")
        check_protocol("estimator", describe_object(estimator), estimator)
        needed = [c for c in getattr(estimator, "channels", ()) or ()
                  if c not in (sensors.channels if sensors is not None else ())]
        if needed:
            raise PluginError(f"estimator {describe_object(estimator)} needs the {needed[0]} channel, which these "
                              f"sensors do not give (channels: {', '.join(sensors.channels) if sensors else 'none'}); "
                              f"allowed: sensors with it (a scenario's [sensors.{needed[0]}])")
        if controller is not None:
            check_protocol("controller", describe_object(controller), controller)
        self.estimator = estimator
        self.controller = controller
        self.sensors = sensors
        self.targets = targets
        self.theta0, self.alpha0, self.position = float(theta0), float(alpha0), tuple(position)
        self.control_rate = control_rate
        self.control_dt = 1.0 / control_rate
        self.signals = tuple(getattr(controller, "signals", ())) if controller is not None else ()
        self._n_out = 2 + len(self.signals)
        # a controller that computes the PWM duties itself (a firmware's driver law: Controller.drives_duty)
        self._duty_at = self._duty_signals(controller, config if self._given is not None else None)
        self._attach_truth = bool(getattr(estimator, "reads_truth", False))
        if limits is not None and not isinstance(limits, PluginLimits):
            raise TwinError(f"limits must be a twin.limits.PluginLimits or None, got {limits!r}")
        # None (no limits, and not in a contained worker, whose command watches each call): the hot
        # path below times nothing
        watched = _limits.STATUS is not None
        self._guard = RunGuard(limits, controller, estimator, self.control_dt) \
            if (limits and limits.active) or watched else None
        self.twin = None  # the plant of the current run
        self.suite: SensorSuite | None = None
        self._motion: ImuMotion | None = None  # the IMU's lever-arm kinematics of the current run
        self._motor = None  # the motors of the current run's plant, for extra sensors that need them
        self.k = 0
        self.truth = self.measurement = self.estimate = None
        self.true_gyro_bias = None
        self.seed: int | None = None
        self._command = None

    # ---- life cycle ---------------------------------------------------------------------------
    def reset(self, seed: int = 0) -> StepResult:
        """Start a run: a new twin (or the plant's ``reset``) at the initial state, and the
        readings of instant 0.

        ``seed`` (int ≥ 0) seeds the sensors' noise and faults. The estimator's ``start``
        and the controller's ``reset`` are called; returns instant 0.
        """
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise TwinError(f"seed must be a non-negative integer, got {seed!r}")
        self.close()
        self.seed = int(seed)
        self.k = 0
        if self._given is None:  # a TwinConfig was given: its twin, built once (reset() rebuilds it)
            self._given = build_plant("bullet", self.config, self.theta0, self.alpha0, self.position)
        twin = self._given
        if self._foreign:
            try:
                tr = twin.reset(self.theta0, self.alpha0, self.position)
            except _limits.PLUGIN_FAILURES as exc:  # the plant's failure, in one line
                raise self._raised("plant", twin, "reset()", exc) from None
            tr = self._check_truth(tr, "reset")
        else:
            tr = twin.reset(self.theta0, self.alpha0, self.position)
        self.twin = twin
        self._command = None
        self._last_command = (0.0, 0.0)
        tr = self.truth = tr
        self._motor = None
        if self.sensors is not None and self.sensors.extra:
            # the motors the plant drives its wheels through (Plant.applies_motor), for a sensor that needs them
            own = getattr(twin, "config", None)
            self._motor = own.motor if getattr(twin, "applies_motor", False) and isinstance(own, TwinConfig) else None
            self._needs_check(self._motor, describe_object(twin), self.sensors)
        if self.sensors is not None:
            self.suite = suite = SensorSuite(self.sensors, self.control_rate,
                                             np.random.default_rng(np.random.SeedSequence(self.seed)))
            self._motion = motion = ImuMotion(twin, self.sensors.imu.position, suite.every * self.control_dt)
            suite.start(*motion.reading, tr.psi_l - tr.theta, tr.psi_r - tr.theta)
        else:
            self.suite = self._motion = None
        self.measurement = self._read(tr)
        guard = self._guard
        if guard is not None:
            guard.start()  # the run's clock: start() and reset() count towards limits.run_wall_s
        t0 = perf_counter() if guard is None else guard.enter(2, 3, 0)
        try:
            est = self.estimator.start(self.measurement)
        except _limits.PLUGIN_FAILURES as exc:  # the plugin's failure, in one line
            raise self._raised("estimator", self.estimator, "start()", exc) from None
        if guard is not None:
            t1 = guard.leave()
            guard.charge("estimator", t1 - t0, t1, 0, per_step=False)
        est = self._check_estimate(est, "start")
        self.estimate = est if isinstance(est, tuple) else tuple(float(v) for v in est)
        if self.controller is not None:
            t0 = perf_counter() if guard is None else guard.enter(1, 1, 0)
            try:
                self.controller.reset(self.targets)
            except _limits.PLUGIN_FAILURES as exc:
                raise self._raised("controller", self.controller, "reset()", exc) from None
            if guard is not None:
                t1 = guard.leave()
                guard.charge("controller", t1 - t0, t1, 0, per_step=False)
        return self.result()

    def close(self) -> None:
        """Close the plant (the twin's PyBullet client; safe to call twice)."""
        if self.twin is not None:
            twin, self.twin = self.twin, None
            if not self._foreign:
                twin.close()
            else:
                try:
                    twin.close()
                except _limits.PLUGIN_FAILURES as exc:  # the plant's failure, in one line
                    raise self._raised("plant", twin, "close()", exc) from None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ---- one control period -------------------------------------------------------------------
    def command(self) -> tuple:
        """The controller's output on the current estimate, ``(ul, ur, *signals)`` (N·m, then
        the controller's extra signals); computed once per instant."""
        out = self._command
        if out is None:
            if self.controller is None:
                raise TwinError("this loop has no controller: give step() the command (ul, ur) in N·m")
            guard = self._guard
            try:
                if guard is None:
                    out = self.controller(self.estimate, self.targets)
                else:
                    t0 = guard.enter(1, 2, self.k)
                    out = self.controller(self.estimate, self.targets)
                    t1 = guard.leave()
            except _limits.PLUGIN_FAILURES as exc:  # the plugin's failure, in one line
                raise self._raised("controller", self.controller, "__call__()", exc) from None
            if guard is not None:
                guard.charge("controller", t1 - t0, t1, self.k)
            try:
                ok = len(out) == self._n_out and isfinite(sum(out))
            except TypeError:
                ok = False
            if not ok:
                out = self._check_command(out)  # raises, naming the controller and what was expected
            if not isinstance(out, tuple):  # a buffer the plugin reuses: keep a copy
                out = tuple(float(v) for v in out)
            self._command = out
        return out

    def step(self, command: Sequence[float] | None = None) -> StepResult:
        """Apply ``command`` (ul, ur) in N·m (default: :meth:`command`) for one control period,
        then read the sensors and run the estimator at the next instant."""
        # the hot path of every run: plain attribute access, checks inline
        twin = self.twin
        if twin is None or twin.status != "running":
            self._require_running()
        if command is None:
            command = self.command()
        elif command is not self._command:
            command = self._check_command(command, external=True)
        ul, ur = command[0], command[1]
        if self._duty_at is not None and len(command) == self._n_out:  # the controller's own duties drive
            i = self._duty_at
            self._last_command = (ul, ur)
            tr = self.truth = twin.step_duties(command[i], command[i + 1], ul, ur,
                                               (command[i + 2] != 0.0, command[i + 3] != 0.0))
            if self._foreign:
                tr = self.truth = self._check_truth(tr, "step_duties", 1)
            act, push = self.actuation, self.push_force
        elif self._foreign:
            tr = self.truth = self._plant_step(twin, ul, ur)
            act, push = self.actuation, self.push_force
        else:
            tr = self.truth = twin.step(ul, ur)
            act, push = twin.actuation, twin.push_force
        self.k += 1
        self._command = None
        status = twin.status
        if status == "diverged":  # a non-finite state: nothing more is read from it
            self.true_gyro_bias = None
            return StepResult(tr, self.measurement, self.estimate, status, twin.end_reason, None, act, push)
        meas = self.measurement = self._read(tr)
        guard = self._guard
        try:
            if guard is None:
                est = self.estimator.step(meas, (ul, ur))
            else:
                t0 = guard.enter(2, 4, self.k)
                est = self.estimator.step(meas, (ul, ur))
                t1 = guard.leave()
        except _limits.PLUGIN_FAILURES as exc:  # the plugin's failure, in one line
            raise self._raised("estimator", self.estimator, "step()", exc) from None
        if guard is not None:
            guard.charge("estimator", t1 - t0, t1, self.k)
        try:
            ok = len(est) == 6 and isfinite(sum(est))
        except TypeError:
            ok = False
        if not ok:
            est = self._check_estimate(est, "step")  # raises, naming the estimator
        if not isinstance(est, tuple):  # a buffer the plugin reuses: keep a copy
            est = tuple(float(v) for v in est)
        self.estimate = est
        # StepResult(...) without its Python-level __new__ (the same tuple, a step's cheapest)
        return tuple.__new__(StepResult, (tr, meas, est, status, "" if status == "running" else twin.end_reason,
                                          self.true_gyro_bias, act, push))

    def _read(self, tr) -> Measurement:
        suite = self.suite
        if suite is None:
            self.true_gyro_bias = None
            return Measurement(tr.t, None, None, None, tr if self._attach_truth else None)
        k = self.k
        motion = self._motion
        if k % suite.every == 0:
            if k > 0:
                motion.update(self.twin.kinematics)
            self.true_gyro_bias = suite.gyro_bias_body()
        else:
            self.true_gyro_bias = None
        if suite.extra:  # what the extra sensors read: the plant's truth, the last period's actuation
            src = Sources(self.twin, tr, self.actuation if k > 0 else None, self._motor)
            meas = suite.read(k, *motion.reading, tr.psi_l - tr.theta, tr.psi_r - tr.theta, src)
        else:
            meas = suite.read(k, *motion.reading, tr.psi_l - tr.theta, tr.psi_r - tr.theta)
        return meas._replace(truth=tr) if self._attach_truth else meas

    @staticmethod
    def _duty_signals(controller, plant) -> int | None:
        """Where a controller that drives the duties itself (``drives_duty``) puts them in its output
        (the index of ``duty_cmd_l``, followed by ``duty_cmd_r``, ``saturated_cmd_l``, ``saturated_cmd_r``),
        or None; a one-line error for a plant that cannot take duties."""
        if controller is None or not getattr(controller, "drives_duty", False):
            return None
        names = ("duty_cmd_l", "duty_cmd_r", "saturated_cmd_l", "saturated_cmd_r")
        signals = tuple(getattr(controller, "signals", ()))
        if signals[-4:] != names:
            raise PluginError(f"controller {describe_object(controller)} drives the duties (drives_duty) but its "
                              f"signals do not end with {', '.join(names)}")
        if plant is not None and not callable(getattr(plant, "step_duties", None)):
            raise TwinError(f"controller {describe_object(controller)} sets the motors' PWM duties itself, and plant "
                            f"{describe_object(plant)} takes torques only (no step_duties); allowed: the PyBullet twin "
                            f"with DC motors, or the controller driving torques")
        return 2 + len(signals) - 4

    @staticmethod
    def _needs_check(motor, plant: str, sensors: SensorConfig) -> None:
        """A one-line error if an extra sensor needs what the plant lacks (motors, for the current)."""
        for spec in sensors.extra:
            t = type_of(spec)
            if t.needs == "motor" and motor is None:
                raise TwinError(f"[sensors.{t.name}] needs DC motors, and plant {plant} drives its wheels with ideal "
                                f"torque sources (no motor current); allowed: a plant with DC motors (plant.motor = "
                                f"\"dc\" on the bullet plant), or no [sensors.{t.name}]")

    # ---- contracts ----------------------------------------------------------------------------
    def _plant_step(self, plant, ul, ur):
        """One step of a plant given to the loop, its output checked (one place: here)."""
        self._last_command = (ul, ur)
        try:
            tr = plant.step(ul, ur)
        except _limits.PLUGIN_FAILURES as exc:  # the plant's failure, in one line
            raise self._raised("plant", plant, "step()", exc) from None
        tr = self._check_truth(tr, "step", 1)
        status = getattr(plant, "status", None)
        if status not in ("running", "fell", "diverged", "closed"):
            raise PluginError(f"plant {describe_object(plant)}: status is {shown(status)} after step() at t = "
                              f"{(self.k + 1) * self.control_dt:.3f} s; expected \"running\", \"fell\" or "
                              f"\"diverged\" (see twin.protocols.Plant)")
        return tr

    def _check_truth(self, tr, where: str, ahead: int = 0) -> GroundTruth:
        """``tr`` as a GroundTruth, or a one-line PluginError naming the plant and the contract."""
        if type(tr) is GroundTruth:
            values = tr
        else:
            try:
                values = tuple(float(v) for v in tr)
            except (TypeError, ValueError):
                values = ()
        if len(values) != len(GroundTruth._fields):
            raise PluginError(f"plant {describe_object(self._given)}: {where}() returned {shown(tr)} at t = "
                              f"{(self.k + ahead) * self.control_dt:.3f} s; expected a GroundTruth, "
                              f"{len(GroundTruth._fields)} numbers ({', '.join(GroundTruth._fields)}; SI units) "
                              f"(see twin.protocols.Plant)")
        return tr if type(tr) is GroundTruth else GroundTruth(*values)

    def _check_estimate(self, est, where: str):
        try:
            ok = len(est) == 6 and (isfinite(sum(est)) or all(map(isfinite, est)))
        except TypeError:
            ok = False
        if not ok:
            raise PluginError(f"estimator {describe_object(self.estimator)}: {where}() returned {shown(est)} at "
                              f"t = {self.k * self.control_dt:.3f} s; expected 6 finite numbers "
                              f"[θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s)")
        return est

    def _check_command(self, out, external: bool = False):
        n = 2 if external else self._n_out
        try:
            ok = (len(out) == n or external and len(out) == self._n_out) and (isfinite(sum(out)) or
                                                                              all(map(isfinite, out)))
        except TypeError:
            ok = False
        if not ok:
            who = "step(command)" if external else f"controller {describe_object(self.controller)}"
            names = ", ".join(("ul", "ur") + (() if external else self.signals))
            raise PluginError(f"{who} returned {shown(out)} at t = {self.k * self.control_dt:.3f} s; expected "
                              f"{n} finite numbers ({names}; torques in N·m)")
        return out

    def _raised(self, role: str, obj, method: str, exc: BaseException) -> PluginError:
        if isinstance(exc, PluginError):
            return exc
        return PluginError(f"{role} {describe_object(obj)}: {method} raised {raised_text(exc)} at "
                           f"t = {self.k * self.control_dt:.3f} s" + (f"; {MAY_NOT_END}" if ends_process(exc) else ""))

    def _require_running(self):
        if self.twin is None:
            raise TwinError("call reset(seed) before step()")
        if self.twin.status != "running":
            raise TwinError(f"the run has ended ({self.twin.status}: {self.twin.end_reason}); call reset(seed)")
        return self.twin

    # ---- what the loop exposes ----------------------------------------------------------------
    @property
    def status(self) -> str:
        """"running", "fell" or "diverged" (``"idle"`` before the first reset)."""
        return self.twin.status if self.twin is not None else _IDLE

    @property
    def end_reason(self) -> str:
        return "" if self.twin is None or self.twin.status == "running" else self.twin.end_reason

    @property
    def plant(self):
        """The plant of the current run, None before the first :meth:`reset` and after :meth:`close`."""
        return self.twin

    @property
    def t(self) -> float:
        """Time of the current instant, s."""
        return self.k * self.control_dt

    @property
    def actuation(self):
        """What the motors did over the last period (:class:`~twin.plant.base.Actuation`); for a
        plant without ``actuation``, the last command delivered exactly."""
        got = getattr(self.twin, "actuation", None)
        if got is None:
            ul, ur = self._last_command
            return Actuation(0.0, 0.0, float(ul), float(ur), False, False)
        return got

    @property
    def push_force(self) -> tuple:
        """Mean push force over the last period, N, world frame ((0, 0, 0) for a plant without ``push_force``)."""
        return getattr(self.twin, "push_force", (0.0, 0.0, 0.0))

    def result(self) -> StepResult:
        """The current instant as a :class:`~twin.protocols.StepResult` (what :meth:`reset` and
        :meth:`step` return)."""
        period = self.k > 0 and self.twin is not None
        return StepResult(self.truth, self.measurement, self.estimate, self.status, self.end_reason,
                          self.true_gyro_bias, self.actuation if period else None,
                          self.push_force if period else None)

    def sensor_counts(self) -> dict:
        """The run's sensor fault counts so far (per sensor: samples produced, dropped, stuck,
        spiked, superseded); {} without sensors."""
        return {} if self.suite is None else self.suite.fault_counts()

    def sensor_truth(self) -> dict:
        """The constants the run's sensors drew (scale factors, turn-on biases, encoder
        phases); {} without sensors."""
        return {} if self.suite is None else self.suite.truth()

    def estimator_stats(self) -> dict:
        """The estimator's ``stats()`` hook, or {} without one."""
        hook = getattr(self.estimator, "stats", None)
        return dict(hook()) if callable(hook) else {}

    def covariance(self):
        """The estimator's ``covariance()`` hook: the (6, 6) covariance of :attr:`estimate` in
        its units squared, or None without one."""
        hook = getattr(self.estimator, "covariance", None)
        return hook() if callable(hook) else None

    def diagnostics(self) -> dict | None:
        """The estimator's ``diagnostics()`` hook for the last step, or None without one."""
        hook = getattr(self.estimator, "diagnostics", None)
        return hook() if callable(hook) else None


__all__ = ["ClosedLoop"]
