"""Robot files in absolute units (twin.robots): the keys, their units and ranges, the built-ins,
what the twin makes of a robot (equation (1)'s parameters, the motors at the wheel, the IMU, the
encoders), and one line for a robot no physics allows."""
from __future__ import annotations

import math

import pytest

from twin.actuators import DEFAULT_MOTOR
from twin.errors import TwinError
from twin.params import NOMINAL
from twin.robots import ROBOT_KEYS, Robot, builtin_names, builtin_robots, load_robot, robot_text
from twin.sensors.specs import DEFAULT_ENCODERS, DEFAULT_IMU


def test_the_paper_robot_is_the_twin_as_it_always_was():
    r = load_robot("paper")
    assert r.params() == NOMINAL and r.params()._n_xb_default  # the roll moment follows the pitch moment
    assert r.motor() == DEFAULT_MOTOR and r.imu() == DEFAULT_IMU and r.encoders() == DEFAULT_ENCODERS
    assert r.control_rate == 200.0 and r.fall_angle == 1.0
    # a robot file that sets nothing is the paper's robot too
    assert Robot.from_dict({}).params() == NOMINAL and Robot.from_dict({}).motor() == DEFAULT_MOTOR


def test_every_key_has_a_unit_a_range_and_a_description():
    for section, keys in ROBOT_KEYS.items():
        for name, k in keys.items():
            assert k.doc, (section, name)
            if k.kind in ("number", "integer", "vector3"):
                assert k.unit and k.lo < k.hi, (section, name)


def test_the_built_ins_are_listed_and_load():
    names = builtin_names()
    assert "paper" in names and set(builtin_robots()) == set(names)
    for n in names:
        r = load_robot(n)
        assert r.name == n and r.description and r.values[""]["sources"], n
        assert r.max_hold_angle() > 0.05 and "[body]" in robot_text(n)


def test_a_geared_drive_is_the_twins_motor_at_the_wheel():
    """30:1 at 80 % efficiency: the wheel sees 24 times the stall torque, 1/30 of the no-load speed,
    and the rotor's inertia 900 times larger in the wheel's; encoders on the motor count 30 times
    per wheel turn."""
    r = Robot.from_dict({"drive": {"stall_torque": 0.05, "no_load_speed": 600.0, "gear_ratio": 30.0,
                                   "gear_efficiency": 0.8, "rotor_inertia": 1e-7},
                         "encoders": {"counts_per_rev": 48, "on": "motor"}})
    m = r.motor()
    assert math.isclose(m.stall_torque, 0.05 * 30 * 0.8) and math.isclose(m.no_load_speed, 20.0)
    assert math.isclose(r.params().n_wa, NOMINAL.n_wa + 900 * 1e-7)
    assert r.encoders().counts_per_rev == 48 * 30


def test_the_motor_may_be_given_by_its_constants():
    r = Robot.from_dict({"drive": {"supply_voltage": 12.0, "resistance": 3.0, "torque_constant": 0.3}})
    assert math.isclose(r.motor().stall_torque, 0.3 * 12 / 3) and math.isclose(r.motor().no_load_speed, 40.0)
    with pytest.raises(TwinError, match="give stall_torque and no_load_speed, or resistance and torque_constant"):
        Robot.from_dict({"drive": {"stall_torque": 1.0, "resistance": 3.0, "torque_constant": 0.3}})


@pytest.mark.parametrize("data, says", [
    ({"body": {"yaw_inertia": 0.01}}, "body.yaw_inertia: 0.01 kg·m² exceeds the sum of the other two moments"),
    ({"wheels": {"inertia_axle": 0.002}}, "wheels.inertia_axle: 0.002 kg·m² exceeds twice inertia_diameter"),
    ({"body": {"size": [0.08, 0.2, 0.1], "box_bottom": 0.1}}, "body.com_height: the centre of mass at 0.0622 m is "
                                                                 "outside the body's box"),
    ({"drive": {"stall_torque": 0.005}}, "drive.stall_torque: both motors give 0.01 N·m at the wheels"),
    ({"body": {"mass": -1}}, "body.mass: -1 kg is out of range; allowed in (0, 1000] kg"),
    ({"wheels": {"radius": "4 cm"}}, "wheels.radius: must be a number in m"),
    ({"imu": {"part": "bno055"}}, "imu.part: must be one of mpu6050"),
    ({"body": {"colour": "red"}}, "unknown key 'colour' in [body]; allowed: mass, com_height"),
    ({"body": {"size": [0.08, 0.5, 0.2]}}, "body.size: the body's width 0.5 m exceeds the wheels' track 0.3 m"),
    ({"encoders": {"counts_per_rev": 7, "on": "motor"}, "drive": {"gear_ratio": 2.5, "stall_torque": 1.0}},
     "encoders on the motor give 17.5 counts per wheel revolution"),
])
def test_a_robot_no_physics_allows_is_one_line_naming_the_key(data, says):
    with pytest.raises(TwinError) as err:
        Robot.from_dict(data, "my.toml")
    text = str(err.value)
    assert text.startswith("my.toml: ") and says in text and "\n" not in text, text


def test_a_robot_file_is_read_and_takes_its_files_name(tmp_path):
    f = tmp_path / "tiny.toml"
    f.write_text('[body]\nmass = 1.0\ncom_height = 0.05\n', encoding="utf-8")
    r = load_robot(f)
    assert r.name == "tiny" and r.params().m_b == 1.0 and r.params().r == NOMINAL.r
    with pytest.raises(TwinError, match="no robot 'nowhere': neither a built-in"):
        load_robot("nowhere")
    (tmp_path / "bad.toml").write_text("[body\n", encoding="utf-8")
    with pytest.raises(TwinError, match="bad.toml: not valid TOML"):
        load_robot(tmp_path / "bad.toml")


# ---- a scenario's robot ------------------------------------------------------------------------------------

HEAVIER = """name = "heavier"
description = "the paper's robot with a 3 kg body, 100 Hz control and a 100 Hz IMU"
[body]
mass = 3.0
[imu]
rate = 100.0
latency = 0.01
[control]
rate = 100.0
[drive]
stall_torque = 1.5
"""


def test_robot_paper_changes_nothing():
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    plain = run_scenario(load_scenario("paper-exp1", ["duration=1"]), ("lqr",))
    named = run_scenario(load_scenario("paper-exp1", ["duration=1", 'robot="paper"']), ("lqr",))
    assert plain.metrics == named.metrics
    assert (plain.runs[0].column_chunks().__next__() == named.runs[0].column_chunks().__next__()).all()
    assert "robot" not in named.scenario.record()  # recorded only where it is not the paper's


def test_a_scenarios_robot_is_its_model_its_plant_its_drive_and_its_sensors_defaults(tmp_path):
    from twin.scenarios import load_scenario

    (tmp_path / "heavier.toml").write_text(HEAVIER, encoding="utf-8")
    (tmp_path / "s.toml").write_text('base = "paper-exp1"\nrobot = "heavier.toml"\n[plant.scale]\nm_b = 1.1\n',
                                     encoding="utf-8")
    sc = load_scenario(str(tmp_path / "s.toml"))
    assert sc.data["rates"]["control"] == 100.0 and sc.data["sensors"]["imu_rate"] == 100.0
    assert sc.data["sensors"]["imu_latency"] == 0.01 and sc.data["robot"] == str((tmp_path / "heavier.toml").resolve())
    config = sc.twin_config()
    assert config.params.m_b == pytest.approx(3.0 * 1.1) and config.control_rate == 100.0  # scale: of its figures
    assert config.motor.stall_torque == 1.5
    spec = sc.run_specs(("lqr",))[0]
    assert spec.model.m_b == 3.0 and spec.model == sc.robot.params()  # the controllers' nominal model
    # a key the scenario gives stays its own
    own = load_scenario(str(tmp_path / "s.toml"), ["rates.control=200", "sensors.imu_rate=200",
                                                   "sensors.imu_latency=0.005"])
    assert own.data["rates"]["control"] == 200.0 and own.data["sensors"]["imu_rate"] == 200.0


def test_twin_run_takes_a_robot_by_name_or_file(tmp_path):
    from click.testing import CliRunner

    from twin.cli import main

    (tmp_path / "heavier.toml").write_text(HEAVIER, encoding="utf-8")
    r = CliRunner().invoke(main, ["run", "paper-exp1", "--robot", str(tmp_path / "heavier.toml"), "--controller",
                                  "lqr", "--duration", "1", "--no-video", "--out", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    import json

    doc = json.loads((tmp_path / "out" / "metrics.json").read_text(encoding="utf-8"))
    assert doc["scenario"]["robot"].endswith("heavier.toml") and doc["scenario"]["rates"]["control"] == 100.0
    r = CliRunner().invoke(main, ["run", "paper-exp1", "--robot", "nowhere", "--no-video"])
    assert r.exit_code == 2 and "robot: no robot 'nowhere'" in r.output


def test_a_robots_body_box_is_the_one_drawn_collided_with_and_checked():
    """The Balboa's box (8 mm above the floor, its centre of mass 14 mm above the axle): Table III's
    rule would centre a 12 cm box on the centre of mass, 6 mm into the floor at the start."""
    from twin.plant.base import TwinConfig, touch_angle
    from twin.plant.urdf import body_box, robot_urdf
    from twin.scenarios import load_scenario

    robot = load_robot("balboa")
    corners = robot.body_corners()
    assert corners == ((-0.02, -0.0485, -0.03), (0.02, 0.0485, 0.08)) and load_robot("paper").body_corners() is None
    p = robot.params()
    assert touch_angle(p) < 0.05 < 0.3 < touch_angle(p, corners)  # the rule's box starts in the floor
    urdf = robot_urdf(p, body=corners)
    assert '<collision><origin xyz="0.0 0.0 0.025" rpy="0 0 0"/><geometry><box size="0.04 0.097 0.11"/>' in urdf
    sc = load_scenario("paper-exp1", ["duration=1", 'robot="balboa"'])
    config = sc.twin_config()
    assert config.body == corners and body_box(config.params, config.body) == corners
    assert config.control_rate == 100.0 and config.fall_angle == 1.22
    with pytest.raises(TwinError, match=r"^body must be the box's \(lowest, highest\) corners"):
        TwinConfig(body=((0, 0, 0.1), (0.1, 0.1, 0.0)))


def test_a_robot_whose_box_reaches_the_floor_is_one_line_naming_the_robot(tmp_path):
    from twin.scenarios import load_scenario

    (tmp_path / "low.toml").write_text('[body]\nsize = [0.08, 0.2, 0.2]\nbox_bottom = -0.035\n', encoding="utf-8")
    with pytest.raises(TwinError) as err:
        load_scenario("paper-exp1", [f'robot="{tmp_path / "low.toml"}"'])
    assert "robot: the body's box (the robot file's body.size and body.box_bottom) reaches the floor at" in str(err.value)
