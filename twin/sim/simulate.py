"""A run specification becomes a logged run: :func:`simulate` (and :func:`build_loop`, the
closed loop of a specification, for those who step it themselves: the Gymnasium environments,
a user's script).

:func:`simulate` drives :class:`twin.sim.loop.ClosedLoop`: reset, then the controller's command
and a step per control period, each step's result handed to a :class:`twin.sim.recorder.Recorder`
(which builds the :class:`twin.sim.runs.Run`), never reading the loop's internals. Logged at the
control rate, one row per control instant, or at every N-th instant (``spec.logging.every``).
Memory: the step results are gathered for a chunk of :data:`CHUNK` control steps at a time,
then moved into preallocated float64 arrays, so a run costs about 8 bytes per logged number
(some 0.27 GB per simulated hour at 200 Hz with sensors, every step logged).

The plant is closed when the run ends, fallen or not.
"""
from __future__ import annotations

import numpy as np

from estimation.consistency import RunningConsistency, TruthConstants, measurable
from twin.plant.base import TwinConfig
from twin.registry import build_plant
from twin.sim.loop import ClosedLoop
from twin.sim.recorder import Recorder
from twin.sim.runs import COMMAND_UNITS, Run
from twin.sim.spec import RunSpec

CHUNK = 4096  # control steps gathered before they move into the log's arrays (twin.sim.recorder.Recorder's chunk)


def build_loop(spec: RunSpec, controller=None, estimator=None):
    """The :class:`twin.sim.loop.ClosedLoop` of ``spec``, not yet reset.

    ``controller``/``estimator``: objects already built for ``spec`` (default: built here,
    :meth:`RunSpec.build_controller` and :meth:`RunSpec.build_estimator`); a spec without a
    controller gives a loop stepped with commands."""
    made = spec.build_plugins(controller is None and spec.controller is not None, estimator is None)
    estimator = made.get("estimator", estimator)
    controller = made.get("controller", controller)
    i = spec.initial
    model = spec.plant_model
    # a kind: built here at the start (the loop resets it for each run); an object: the caller's
    plant = build_plant(model, spec.plant, i.theta, i.alpha, i.position, spec.plant_params) \
        if isinstance(model, str) else model
    return ClosedLoop(plant, estimator, controller, spec.sensing.true, spec.targets, i.theta, i.alpha, i.position,
                      limits=spec.limits)


def config_of(spec: RunSpec):
    """The :class:`~twin.plant.bullet.TwinConfig` a run of ``spec`` records: the plant object's
    own, if it has one (a BulletTwin, an AnalyticPlant), else ``spec.plant``."""
    own = getattr(spec.plant_model, "config", None) if not isinstance(spec.plant_model, str) else None
    return own if isinstance(own, TwinConfig) else spec.plant


def simulate(spec: RunSpec, progress=None, controller=None, estimator=None) -> Run:
    """Run ``spec`` and return its log (:class:`twin.sim.runs.Run`).

    ``progress(steps_done, steps_total)`` is called once per simulated second and at the end.
    ``controller``/``estimator``: objects already built for ``spec`` (see :func:`build_loop`).
    """
    if spec.controller is None and controller is None:
        spec.build_plugins(True, False)  # the one-line error: a run needs a controller
    loop = build_loop(spec, controller, estimator)
    # what the run records of its specification, asked once (the loop is built: the plugins are the run's)
    experiment, sensing_name, plant_name = spec.experiment, spec.sensing_name, spec.plant_name
    controller = loop.controller
    ideal = spec.sensing.ideal
    log_filter = spec.logging.diagnostics
    rate = loop.control_rate
    n_ctrl = int(round(spec.duration / loop.control_dt))
    report_every = max(1, int(round(rate)))
    rec = Recorder.for_loop(loop, n_ctrl + 1, log_every=spec.logging.every, diagnostics=log_filter, chunk=CHUNK)
    instant, period = rec.instant, rec.period
    diagnostics = loop.diagnostics if log_filter else None
    with loop:
        res = loop.reset(spec.seed)
        meter, feed = consistency_meter(loop, spec, log_filter)
        command, step = loop.command, loop.step
        for i in range(n_ctrl + 1):
            if res.status == "diverged":  # the non-finite state is not logged: the log ends with the last finite one
                break
            d = None if diagnostics is None else diagnostics()
            c = command()
            instant(res, c, d)
            if feed is not None:
                feed(res, d)
            if i == n_ctrl or res.status != "running":
                break
            if progress is not None and i % report_every == 0 and i:
                progress(i, n_ctrl)
            res = step(c)
            period(res)  # what the motors and pushes did over [t_i, t_i+1)
        status = "ok" if loop.status == "running" else loop.status
        reason = "" if status == "ok" else loop.end_reason
        stats = {} if ideal else loop.estimator_stats()
        lost = stats.get("degraded") if isinstance(stats, dict) else None
        if status == "ok" and lost and isinstance(lost, (list, tuple)):  # ran its duration, the estimator lost something
            status, reason = "degraded", "; ".join(str(x) for x in lost)
        sensor_counts = {} if ideal else loop.sensor_counts()
        sensor_truth = {} if ideal else loop.sensor_truth()
        if progress is not None:
            progress(n_ctrl, n_ctrl)
    units = {**COMMAND_UNITS, **getattr(controller, "signal_units", {})}
    label = spec.label or (spec.controller.kind if spec.controller is not None and spec.controller.is_kind else "")
    config = config_of(spec)
    run = rec.run(status, reason, config, command_units=tuple(units.get(k, "1") for k in rec.command_names),
                  experiment=experiment, controller=label, sensing=sensing_name, estimator_stats=stats,
                  sensor_counts=sensor_counts, seed=None if ideal else int(spec.seed), sensor_truth=sensor_truth,
                  sensor_config=spec.sensing.true, model_params=spec.model, plant=plant_name,
                  estimator_consistency=None if meter is None else meter.result())
    return run


def consistency_meter(loop, spec: RunSpec, diagnosed: bool = False):
    """(meter, feed) for a run on simulated sensors of an estimator that reports the EKF's states
    (:func:`estimation.consistency.measurable`: the built-in EKF, or one's own that reports the same
    layout), whose state truth the twin knows; (None, None) for any other run. ``meter`` an
    :class:`estimation.consistency.RunningConsistency`, ``feed(result, diagnostics)`` to call
    after every control instant is recorded (``diagnostics`` the EKF's, when the run logs them,
    else None: then the state is written by the filter's core into the meter's block,
    ``state_into``, which costs a fifth of what ``diagnostics()`` does). Call after ``loop.reset()``: the sensors' drawn
    constants are the truth of some states.

    Memory: a block of :data:`estimation.consistency.SUM_BLOCK` rows (1.3 MB of x and P), not
    the run: an hour-long run costs no more than a minute's."""
    est = loop.estimator
    if loop.sensors is None or spec.sensing.true is None or not measurable(est):
        return None, None
    drawn, sensors = loop.sensor_truth(), spec.sensing.true
    constants = TruthConstants(tuple(drawn["gyro_scale"]), tuple(drawn["accel_scale"]), tuple(drawn["encoder_phase"]),
                               tuple(sensors.imu.position), float(config_of(spec).params.r),
                               float(spec.model.b / spec.model.r), float(sensors.encoders.resolution))
    meter = RunningConsistency(constants)
    add = meter.add

    if diagnosed:
        def feed(res, d):
            add(res.truth, res.gyro_bias, np.concatenate([d["x"], np.ravel(d["P"])]), d["nis"], d["nis_dof"], d["lag"])
    else:
        into = est.state_into  # bound to the run's filter core from start() (reset) on

        def feed(res, d):
            add(res.truth, res.gyro_bias, into, est.last_nis, est.last_dof, est.lag)
    return meter, feed


__all__ = ["CHUNK", "build_loop", "config_of", "consistency_meter", "simulate"]
