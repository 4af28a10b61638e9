"""Recording apart from the loop: twin.sim.recorder.Recorder, fed the step results ClosedLoop
publishes, gives the Run simulate_twin gives; one's own logger reads the same outputs; the
IMU's lever-arm kinematics live with the sensors (twin.sensors.ImuMotion)."""
from __future__ import annotations

import numpy as np
import pytest

from twin.sim.bullet_loop import simulate_twin
from twin.errors import TwinError
from twin.experiments import Experiment
from twin.sim.loop import ClosedLoop
from twin.params import NOMINAL
from twin.plant.analytic_plant import AnalyticPlant
from twin.plant.bullet import TwinConfig
from twin.sim.recorder import Recorder
from twin.registry import BuildContext, build_controller, build_estimator
from twin.sim.runs import MeasurementLog
from twin.sensors import ImuMotion, ImuSpec, SensorConfig, imu_kinematics

ARRAYS = ("t", "truth", "commands", "actuation", "push", "estimates", "gyro_bias")


def _parts(exp, config, sensors, kind="lqr"):
    ctx = BuildContext(config.control_rate, NOMINAL, config.motor, sensors, exp.targets, 0.0)
    return build_controller(kind, None, ctx), build_estimator("ekf", None, ctx)


def _drive(loop, rec, seed, n_ctrl, log_filter=False):
    """What simulate_twin does, written out: the loop's outputs into the recorder."""
    res = loop.reset(seed)
    for i in range(n_ctrl + 1):
        if res.status == "diverged":
            break
        d = loop.diagnostics() if log_filter else None
        u = loop.command()
        rec.instant(res, u, d)
        if i == n_ctrl or res.status != "running":
            break
        res = loop.step(u)
        rec.period(res)


def _same_run(a, b):
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert isinstance(a.measurements, MeasurementLog) and a.measurements == b.measurements
    assert (a.status, a.end_reason, a.command_names, a.log_every) == (b.status, b.end_reason, b.command_names,
                                                                      b.log_every)
    assert a.estimator_stats == b.estimator_stats and a.sensor_counts == b.sensor_counts
    assert a.sensor_truth == b.sensor_truth
    if a.full_rate is None:
        assert b.full_rate is None
    else:
        for name, v in a.full_rate.items():
            np.testing.assert_array_equal(v, b.full_rate[name], err_msg=name)


@pytest.mark.parametrize("log_every, chunk, log_filter", [(1, 4096, True), (7, 50, False)])
def test_a_recorder_fed_the_step_results_gives_simulate_twins_run(log_every, chunk, log_filter):
    exp = Experiment("balance", "", theta0=0.15, p_d=0.2, duration=1.0)
    config = TwinConfig()
    sensors = SensorConfig(imu=ImuSpec(rate=100.0, latency=0.01))
    controller, ekf = _parts(exp, config, sensors)
    n_ctrl = int(round(exp.duration * config.control_rate))
    with ClosedLoop(config, ekf, controller, sensors, exp.targets, exp.theta0) as loop:
        rec = Recorder.for_loop(loop, n_ctrl + 1, log_every=log_every, diagnostics=log_filter, chunk=chunk)
        _drive(loop, rec, 4, n_ctrl, log_filter)
        status = "ok" if loop.status == "running" else loop.status
        mine = rec.run(status, loop.end_reason, config, estimator_stats=loop.estimator_stats(),
                       sensor_counts=loop.sensor_counts(), sensor_truth=loop.sensor_truth())
    run = simulate_twin(_parts(exp, config, sensors)[0], exp, config, sensors=sensors, seed=4, log_every=log_every,
                        log_filter=log_filter)
    assert run.status == "ok" and len(mine.t) == len(run.t) == (n_ctrl + log_every) // log_every
    _same_run(mine, run)
    if log_filter:
        for key, v in run.filter_log.items():
            np.testing.assert_array_equal(mine.filter_log[key], v, err_msg=key)


def test_a_run_that_falls_is_recorded_as_simulate_twin_records_it():
    exp = Experiment("fall", "", theta0=0.3, duration=2.0)
    config = TwinConfig(motor=None)
    sensors = SensorConfig()
    ctx = BuildContext(config.control_rate, NOMINAL, None, sensors, exp.targets, 0.0)

    class Idle:  # no torque: the robot falls forward
        signals = ("nothing",)

        def reset(self, targets):
            pass

        def __call__(self, estimate, targets):
            return (0.0, 0.0, 1.0)

    n_ctrl = 400
    with ClosedLoop(AnalyticPlant(config), build_estimator("ekf", None, ctx), Idle(), sensors, exp.targets,
                    exp.theta0) as loop:
        rec = Recorder.for_loop(loop, n_ctrl + 1)
        _drive(loop, rec, 0, n_ctrl)
        mine = rec.run(loop.status, loop.end_reason, config, estimator_stats=loop.estimator_stats(),
                       sensor_counts=loop.sensor_counts(), sensor_truth=loop.sensor_truth())
    run = simulate_twin(Idle(), exp, config, sensors=sensors, plant="analytic")
    assert run.status == mine.status == "fell" and len(run.t) < n_ctrl + 1
    assert np.all(mine.actuation[-1] == 0.0) and mine.command_names == ("ul_cmd", "ur_cmd", "nothing")
    _same_run(mine, run)


def test_ones_own_logger_reads_the_loops_outputs():
    """A logger of one's own attached to what the loop returns: no internals read."""
    exp = Experiment("balance", "", theta0=0.1, duration=0.5)
    config = TwinConfig()
    sensors = SensorConfig()
    controller, ekf = _parts(exp, config, sensors)

    class ThetaLogger:
        def __init__(self):
            self.rows = []

        def __call__(self, result):
            torque = None if result.actuation is None else result.actuation.torque_l
            self.rows.append((result.truth.t, result.truth.theta, result.estimate[0], torque,
                              result.gyro_bias is not None))

    log = ThetaLogger()
    with ClosedLoop(config, ekf, controller, sensors, exp.targets, exp.theta0) as loop:
        log(loop.reset(seed=2))
        while loop.status == "running" and loop.k < 100:
            log(loop.step())
    t, theta, theta_est, torque, sampled = zip(*log.rows)
    run = simulate_twin(_parts(exp, config, sensors)[0], exp, config, sensors=sensors, seed=2)
    np.testing.assert_array_equal(t, run.t[:101])
    np.testing.assert_array_equal(theta, run.signal("theta")[:101])
    np.testing.assert_array_equal(theta_est, run.signal("theta_est")[:101])
    # row i's actuation is the period [t_i, t_i+1): published by the step that ends it
    assert torque[0] is None
    np.testing.assert_array_equal(torque[1:], run.signal("torque_l")[:100])
    assert all(sampled) and not np.isnan(run.gyro_bias[:101]).any()  # a gyro sample at every 200 Hz instant


def test_the_recorder_checks_how_it_is_fed():
    with pytest.raises(TwinError, match="log_every"):
        Recorder(10, log_every=0)
    with pytest.raises(TwinError, match="diagnostics"):
        Recorder(10, log_every=2, diagnostics=True)
    rec = Recorder(1, measured=False)
    with pytest.raises(TwinError, match="follows an instant"):
        rec.period(None)


def test_the_imu_lever_arm_kinematics_live_with_the_sensors():
    plant = AnalyticPlant(TwinConfig(motor=None))
    plant.reset(0.2)
    pos = SensorConfig().imu.position
    motion = ImuMotion(plant, pos, 0.005)
    com = plant.com_local
    lever = tuple(p - c for p, c in zip(pos, com))
    pose, vel = rest = plant.kinematics
    assert motion.reading == imu_kinematics(pose, vel, pose, vel, 0.005, lever, plant.gravity)
    plant.step(0.1, -0.1)
    kin = plant.kinematics
    assert motion.update(kin) == imu_kinematics(*kin, *rest, 0.005, lever, plant.gravity) == motion.reading
    assert motion.last is kin
