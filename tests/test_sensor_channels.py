"""Readings as named channels (twin.sensors.types) and the motor current sensor that proves them:
its noise model, its own random stream (the other sensors' readings unchanged by it), the
scenario keys and their one-line errors, the loop, the recorder, the sensor log and the replay."""
from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from twin.actuators import DEFAULT_MOTOR, steady_current
from twin.errors import PluginError, TwinError
from twin.experiments import PAPER_EXPERIMENTS
from twin.logs.format import read_log, write_log
from twin.logs.replay import instants, replay
from twin.plant.base import GroundTruth, TwinConfig
from twin.scenarios import load_scenario
from twin.sensors import Measurement, SensorConfig, SensorSuite
from twin.sensors.channels import Sources
from twin.sensors.motor_current import KEYS, MotorCurrentSensor, MotorCurrentSpec
from twin.sensors.types import SENSOR_TYPES, channel, extra_types
from twin.sim.bullet_loop import simulate_twin

CURRENT = SensorConfig(extra=(MotorCurrentSpec(),))


def _suite(config, seed=3):
    s = SensorSuite(config, 200.0, np.random.default_rng(np.random.SeedSequence(seed)))
    s.start((0.0, 0.0, 0.0), (0.0, 0.0, 9.81), 0.0, 0.0)
    return s


def _readings(config, n=300, seed=3):
    s = _suite(config, seed)
    tr = GroundTruth(*([0.0] * 15))
    src = Sources(None, tr, (0.3, -0.2, 0.0, 0.0, False, False), DEFAULT_MOTOR)
    return [s.read(k, (0.1, 0.2, 0.3), (0.0, 0.0, 9.81), 0.01 * k, 0.02 * k, src) for k in range(n)], s


def test_the_table_names_each_channel_with_its_unit_and_shape():
    assert channel("motor_current").unit == "A" and channel("motor_current").shape == (2,)
    assert channel("gyro").unit == "rad/s" and channel("encoders").columns == ("left", "right")
    assert [t.name for t in extra_types()] == ["motor_current"] and SENSOR_TYPES["imu"].core
    with pytest.raises(TwinError, match="no sensor channel 'magnetometer'; channels: gyro, accel, encoders, "
                                        "motor_current"):
        channel("magnetometer")


def test_measurement_keeps_its_attributes_and_gives_channels_by_name():
    m = Measurement(0.5, (1.0, 2.0, 3.0), None, (0.1, 0.2), None, {"motor_current": (0.4, -0.1)})
    assert m.gyro == m["gyro"] == m[1] == (1.0, 2.0, 3.0) and m.accel is None and m.encoders == (0.1, 0.2)
    assert m["motor_current"] == (0.4, -0.1) and m.channels["motor_current"] == (0.4, -0.1)
    plain = Measurement(0.5, None, None, None)
    assert plain["motor_current"] is None and "motor_current" not in plain.channels  # the run has none
    with pytest.raises(KeyError, match="no sensor channel 'torque'"):
        plain["torque"]


def test_the_current_sensor_leaves_every_other_reading_and_constant_unchanged():
    # its stream is one more child spawned after the six (Generator.spawn numbers children and draws
    # nothing from the parent): the IMU's and encoders' readings and drawn constants are identical
    off, s_off = _readings(SensorConfig())
    on, s_on = _readings(CURRENT)
    assert [m[:5] for m in off] == [m[:5] for m in on]
    assert {k: v for k, v in s_on.truth().items() if not k.startswith("motor_current")} == s_off.truth()
    assert off[0].extra is None and set(on[0].extra) == {"motor_current"}
    # and the children the suite spawns first are what SeedSequence gives for spawn keys 0..5
    rng = np.random.default_rng(np.random.SeedSequence(3))
    first = rng.spawn(6)
    more = rng.spawn(1)[0]
    again = np.random.default_rng(np.random.SeedSequence(3)).spawn(6)
    assert all(a.bit_generator.seed_seq.spawn_key == b.bit_generator.seed_seq.spawn_key for a, b in zip(first, again))
    assert more.bit_generator.seed_seq.spawn_key == (6,)


def test_the_current_reading_follows_the_noise_model():
    spec = MotorCurrentSpec(noise=0.02, offset=0.0, gain_error=0.0)
    on, _ = _readings(SensorConfig(extra=(spec,)), n=4000)
    i_true = steady_current(DEFAULT_MOTOR, 0.3, 0.0)  # (the duty 0.3 held, the wheel still)
    got = np.array([m["motor_current"][0] for m in on[1:]])
    assert abs(got.mean() - i_true) < 4 * 0.02 / math.sqrt(len(got))
    assert 0.019 < got.std() < 0.021
    lsb = spec.resolution
    assert np.allclose(np.round(got / lsb) * lsb, got, rtol=0, atol=1e-12)  # whole ADC steps
    clipped = MotorCurrentSensor(MotorCurrentSpec(full_scale=0.5, noise=0.0, offset=0.0, gain_error=0.0), 200.0,
                                 np.random.default_rng(0))
    assert clipped.sample(((3.0, -3.0),)) == ((0.5, -0.5),)


def test_the_defaults_are_the_cited_parts():
    # INA240A2 (50 V/V) over 5 mΩ: 0.25 V/A; a 12-bit ADC at 3.3 V biased at mid-supply
    assert KEYS["resolution"].default == pytest.approx(3.3 / 4096 / 0.25)
    assert KEYS["full_scale"].default == pytest.approx(6.6) and DEFAULT_MOTOR.stall_current < 6.6


def test_latency_and_rate_are_whole_control_periods():
    on, _ = _readings(SensorConfig(extra=(MotorCurrentSpec(latency=0.01, rate=100.0),)), n=8)
    assert [m["motor_current"] is not None for m in on] == [True, False] * 4
    with pytest.raises(TwinError, match=r"^\[sensors.motor_current\] latency must be a whole number of control "
                                        r"periods \(0.005 s\), got 0.007 s$"):
        _suite(SensorConfig(extra=(MotorCurrentSpec(latency=0.007),)))


@pytest.mark.parametrize("item, says", [
    ("sensors.motor_current.noise=-0.1", "sensors.motor_current.noise: -0.1 is out of range; allowed in [0, 100] A"),
    ("sensors.motor_current.rate=300", "[sensors.motor_current] rate must be at most the control rate (200 Hz)"),
    ("sensors.motor_current.latency=0.003", "[sensors.motor_current] latency must be a whole number of control "
                                            "periods"),
    ("sensors.motor_current.volume=3", "unknown key 'volume' in sensors.motor_current; allowed: enabled, noise"),
    # a step so fine that the quantiser's count overflowed (found by tests/test_fuzz.py)
    ("sensors.motor_current.resolution=5e-324", "[sensors.motor_current] resolution must be 0 (not quantised) or at "
                                                "least full_scale / 2^32"),
])
def test_bad_keys_are_one_line_naming_the_key_and_what_is_allowed(item, says):
    with pytest.raises(TwinError) as err:
        load_scenario("paper-exp1", [item])
    assert says in str(err.value) and "\n" not in str(err.value)


def test_the_scenario_turns_it_on_and_off():
    assert load_scenario("paper-exp1").sensor_config().extra == ()
    on = load_scenario("paper-exp1", ["sensors.motor_current.noise=0.01"]).sensor_config()
    assert on.extra == (MotorCurrentSpec(noise=0.01),)
    assert load_scenario("paper-exp1", ["sensors.motor_current.enabled=true"]).sensor_config().extra == (
        MotorCurrentSpec(),)
    assert load_scenario("paper-exp1", ["sensors.motor_current.enabled=false",
                                        "sensors.motor_current.noise=0.01"]).sensor_config().extra == ()
    with pytest.raises(TwinError, match='sensors.motor_current: needs DC motors, and plant.motor = "ideal"'):
        load_scenario("paper-exp1", ["sensors.motor_current.enabled=true", 'plant.motor="ideal"'])


def test_the_loop_refuses_a_current_sensor_without_motors_and_an_estimator_missing_its_channel(design):
    from twin.controllers.cascade import build_cascade

    exp = PAPER_EXPERIMENTS[1]
    with pytest.raises(TwinError, match=r"^\[sensors.motor_current\] needs DC motors"):
        simulate_twin(build_cascade("it2", design, exp.targets), exp, TwinConfig(motor=None), duration=0.1,
                      sensors=CURRENT, estimator="ideal")

    class Needs:
        channels = ("motor_current",)

        def start(self, m):
            return (0.0,) * 6

        def step(self, m, u):
            return (0.0,) * 6

    with pytest.raises(PluginError, match="needs the motor_current channel, which these sensors do not give"):
        simulate_twin(build_cascade("it2", design, exp.targets), exp, duration=0.1, sensors=SensorConfig(),
                      estimator=Needs())


@pytest.fixture(scope="module")
def current_run(design):
    from twin.controllers.cascade import build_cascade

    exp = PAPER_EXPERIMENTS[1]
    return simulate_twin(build_cascade("it2", design, exp.targets), exp, duration=2.0, sensors=CURRENT, seed=1,
                         estimator="ideal")


def test_the_sensor_samples_the_drive_models_current(current_run):
    r = current_run
    values, has = r.measurements.channel("motor_current")
    assert has.all() and values.shape == (len(r.t), 2)
    # the current at instant k: the duty of the period before it and the shaft speed then
    w = r.signal("psi_l_dot") - r.signal("theta_dot")
    true = steady_current(DEFAULT_MOTOR, r.signal("duty_l")[:-1], w[1:])
    err = values[1:, 0] - true
    assert abs(err.mean()) < 0.02 and err.std() < 0.01 and np.abs(true).max() > 0.5
    assert set(r.sensor_counts) == {"gyro", "accel", "encoders", "motor_current"}
    assert {"motor_current_offset", "motor_current_gain_error"} <= set(r.sensor_truth)


def test_the_log_holds_the_channel_with_its_units_and_the_replay_hands_it_over(current_run, tmp_path):
    out = write_log(current_run, tmp_path / "log")
    text = (out / "log.toml").read_text()
    assert '[streams.motor_current]' in text and 'columns = { t = "s", left = "A", right = "A" }' in text
    assert "[sensors.motor_current]" in text and (out / "motor_current.csv").read_text().startswith("t,left,right\n")
    log = read_log(out)
    assert set(log.channels) == {"motor_current"} and log.sensors.extra == CURRENT.extra
    _, ms, _ = instants(log)
    assert [m.extra for m in ms] == [m.extra for m in current_run.measurements]

    seen = []

    class Reads:  # an estimator that asks for the channel gets it
        def start(self, m):
            seen.append(m["motor_current"])
            return (0.0,) * 6

        def step(self, m, u):
            seen.append(m["motor_current"])
            return (0.0,) * 6

    replay(log, Reads())
    assert seen == [m["motor_current"] for m in current_run.measurements]
    # a log without it: the channel reads None, and an estimator that needs it is refused in one line
    bare = tmp_path / "bare"
    shutil.copytree(out, bare)
    (bare / "motor_current.csv").unlink()
    toml = (bare / "log.toml").read_text()
    start = toml.index("[streams.motor_current]")
    end = toml.index("[truth]")
    (bare / "log.toml").write_text(toml[:start] + toml[end:])
    log = read_log(bare)
    assert log.channels == {} and log.sensors.extra == ()
    assert all(m["motor_current"] is None for m in instants(log)[1])
    Reads.channels = ("motor_current",)
    with pytest.raises(PluginError, match="needs the motor_current channel, which the log .* does not hold"):
        replay(log, Reads())


def test_a_log_declaring_the_channel_in_other_units_is_one_line(current_run, tmp_path):
    out = write_log(current_run, tmp_path / "log")
    toml = (out / "log.toml").read_text().replace('left = "A", right = "A"', 'left = "mA", right = "mA"')
    (out / "log.toml").write_text(toml)
    with pytest.raises(TwinError, match=r'streams.motor_current.columns: left, right in mA, mA; allowed: '
                                        r'\{ t = "s", left = "A", right = "A" \}'):
        read_log(out)
    toml = toml.replace('left = "mA", right = "mA"', 'left = "A", right = "A"').replace("noise = 0.005", "noise = -1")
    (out / "log.toml").write_text(toml)
    with pytest.raises(TwinError, match=r"log.toml: \[sensors.motor_current\] noise must be a number ≥ 0 and ≤ 100 "
                                        r"A, got -1$"):
        read_log(out)


def test_with_inductance_the_sensor_reads_the_current_the_twin_integrates():
    """A motor with inductance lags its duty: the twin integrates its current per physics step, and
    the sensor reads that current (the steady-state one of the duty would run ahead of it)."""
    from dataclasses import replace

    from twin.plant.bullet import BulletTwin
    from twin.sensors.motor_current import true_current

    lagged = replace(DEFAULT_MOTOR, inductance=0.02)  # H: L/R several control periods
    with BulletTwin(TwinConfig(motor=lagged), theta0=0.05) as plant:
        for _ in range(3):
            truth = plant.step(0.4, -0.4)
        now = plant.motor_current
        assert now is not None and now[0] > 0.0 > now[1]
        src = Sources(plant, truth, plant.actuation, lagged)
        assert true_current(src) == ((now[0], now[1]),)
        a = plant.actuation
        steady = steady_current(lagged, a[0], truth.psi_l_dot - truth.theta_dot)
        assert abs(steady - now[0]) > 0.05 * abs(steady)  # the lag the steady-state current would miss
    with BulletTwin(TwinConfig(), theta0=0.05) as plain:
        plain.step(0.4, -0.4)
        assert plain.motor_current is None  # no inductance: the current follows the duty at once
