"""One robot everywhere: ``--robot`` in twin design, check and sweep, ``robot=`` in the
Gymnasium environments, ``twin robots FILE``, golden files that record the robot, sensor logs
that carry their robot file, and a robot file's known IMU constants in the runs."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from twin.controllers import robot_settings
from twin.robots import load_robot, robot_text
from twin.scenarios import load_scenario
from twin.sensors.noise import TriadNoise


def _twin(*args, cwd=None):
    r = subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True, timeout=300,
                       cwd=cwd)
    return r.returncode, r.stdout, r.stderr


@pytest.fixture()
def mine(tmp_path) -> Path:
    """The Balboa's figures as a robot file of one's own, with the IMU's own constants known."""
    text = robot_text("balboa").replace('name = "balboa"', 'name = "mine"').replace(
        "[encoders]", "gyro_bias = [0.001, -0.002, 0.003]\naccel_scale = [0.01, 0.0, -0.01]\n\n[encoders]")
    path = tmp_path / "mine.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_the_paper_robots_settings_are_the_papers():
    paper = load_robot("paper")
    assert robot_settings.design_settings(paper) == {"rho": 2.0, "decay_rate": 2.0}
    assert robot_settings.universes(paper) == {k: v for k, (v, _) in robot_settings.UNIVERSES.items()}
    # another robot: its own, by the stated rules (a slower fall, a weaker drive)
    b = load_robot("balboa")
    d = robot_settings.design_settings(b)
    assert d["decay_rate"] == pytest.approx(2.0 * robot_settings.fall_rate(b.params())
                                            / robot_settings.fall_rate(paper.params()), rel=5e-3)  # 3 significant digits
    assert d["rho"] == pytest.approx(2.0 * robot_settings.peak_torque(b) / 1.2, rel=5e-3) and d["rho"] < 0.5
    assert robot_settings.universes(b)["pitch_rate"] < 4.0


def test_a_scenario_takes_the_robots_settings_unless_it_gives_its_own(mine):
    sc = load_scenario("paper-exp3", [f"robot={json.dumps(str(mine))}"])
    implied = robot_settings.design_settings(sc.robot)
    assert sc.data["design"]["rho"] == implied["rho"] and sc.data["design"]["decay_rate"] == implied["decay_rate"]
    assert sc.cascade_options()["universes"]["turn_torque"] == robot_settings.universes(sc.robot)["turn_torque"]
    own = load_scenario("paper-exp3", [f"robot={json.dumps(str(mine))}", "design.rho=0.3",
                                       "controller.universes.turn_torque=0.05"])
    assert own.data["design"]["rho"] == 0.3 and own.cascade_options()["universes"]["turn_torque"] == 0.05
    # the paper's robot: nothing added, the options as they were
    assert load_scenario("paper-exp3").cascade_options() == {"fou": 0.25, "type_reduction": "bmm",
                                                              "psi_error_limit": 1.0}


def test_the_design_model_has_a_non_compensating_drivers_back_emf_damping():
    b = load_robot("balboa")
    m = b.motor()
    assert not m.back_emf_compensation
    assert b.model().d_b == pytest.approx(b.params().d_b + m.electrical_damping)
    assert b.model(motors=False) == b.params()
    assert load_robot("paper").model() == load_robot("paper").params()  # compensated: unchanged
    sc = load_scenario("paper-exp1", ["robot=balboa", "plant.motor=ideal"])
    assert sc.model() == b.params()  # ideal torque sources: no back-EMF to model


def test_design_check_and_robots_take_a_robot(mine, tmp_path):
    code, out, err = _twin("design", "--robot", str(mine), "--out", str(tmp_path / "d.json"))
    assert code == 0, err
    assert "robot mine: its model (with its drive's back-EMF damping); ρ = 0.408 N·m, decay rate 1.05 1/s" in out
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["rho"] == 0.408 and doc["decay_rate"] == 1.05
    code, out, err = _twin("robots", str(mine))
    assert code == 0 and out.startswith("mine: ") and "design: ρ = 0.408 N·m" in out, err
    broken = tmp_path / "broken.toml"
    broken.write_text(mine.read_text().replace("gear_ratio = 2.142857", "gear_ratio = 1.0").replace(
        "stall_torque = 0.127", "stall_torque = 0.001"), encoding="utf-8")
    code, out, err = _twin("robots", str(broken))
    assert code == 2 and err.count("\n") == 1 and "drive.stall_torque" in err and "allowed:" in err
    code, out, err = _twin("check", "balboa-exp3", "--robot", "balboa", "--set", "robot=balboa")
    assert code == 2 and "--robot and --set robot=... both name the robot" in err


def test_golden_files_record_the_robot(tmp_path):
    gold = tmp_path / "gold"
    args = ("check", "paper-exp1", "--controller", "lqr", "--set", "duration=0.3")
    code, out, err = _twin(*args, "--record", str(gold))
    assert (gold / "paper-exp1" / "lqr" / "seed-0.npz").exists(), err
    code, out, err = _twin(*args, "--golden", str(gold), "--robot", "balboa")
    assert code == 1
    paper, balboa = load_robot("paper").digest[:12], load_robot("balboa").digest[:12]
    assert f"robot balboa {balboa}, the reference's paper {paper}" in out + err


def test_a_log_carries_its_robot_file_and_replays_without_it(mine, tmp_path):
    code, out, err = _twin("run", "paper-exp1", "--robot", str(mine), "--controller", "lqr", "--duration", "1",
                           "--no-video", "--log-sensors", "--out", str(tmp_path / "run"))
    assert code == 0, err
    log = tmp_path / "run" / "sensor-logs" / "lqr"
    assert (log / "robot.toml").read_text() == mine.read_text()
    assert 'robot=\\"robot.toml\\"' in (log / "log.toml").read_text()
    mine.unlink()  # the log stands alone
    code, out, err = _twin("replay", str(log), "--out", str(tmp_path / "replay"))
    assert code == 0, err


def test_known_imu_constants_replace_the_draws_and_nothing_else(mine):
    sc = load_scenario("paper-exp1", [f"robot={json.dumps(str(mine))}"])
    gyro, accel = sc.sensor_config().imu.gyro, sc.sensor_config().imu.accel
    assert gyro.bias == (0.001, -0.002, 0.003) and gyro.scale is None and accel.scale == (0.01, 0.0, -0.01)
    a = TriadNoise(gyro, 0.01, np.random.default_rng(5))
    b = TriadNoise(load_scenario("paper-exp1", ["robot=balboa"]).sensor_config().imu.gyro, 0.01,
                   np.random.default_rng(5))
    assert a.turn_on == [0.001, -0.002, 0.003] and a.turn_on != b.turn_on
    assert a.scale == b.scale and a.drift == b.drift  # the other draws are the same


def test_the_gymnasium_environment_takes_a_robot():
    gymnasium = pytest.importorskip("gymnasium")
    import twin.envs  # noqa: F401 (registers the environments)

    env = gymnasium.make("mtwip/Balance-v0", robot="balboa", overrides=("duration=0.2",))
    try:
        env.reset(seed=0)
        u = env.unwrapped
        assert u.scenario.robot.name == "balboa" and u.max_torque == pytest.approx(load_robot("balboa").motor().stall_torque)
        assert u.control_rate == 100.0
    finally:
        env.close()


def test_an_imu_mounted_turned_errs_along_its_own_axes():
    """A known gyro bias along the IMU's own x, the IMU pitched 0.3 rad on the body: the readings
    come in the body's axes, so the bias shows on the body's x and z as C b; the run's truth says
    the same; a flat IMU's reading has it on x alone."""
    from dataclasses import replace as with_

    from twin.rotations import mounting_matrix
    from twin.sensors import SensorConfig
    from twin.sensors.specs import DEFAULT_IMU
    from twin.sensors.suite import SensorSuite

    quiet = with_(DEFAULT_IMU.gyro, noise_density=0.0, bias_random_walk=0.0, bias=(0.02, 0.0, 0.0), scale=(0, 0, 0))
    readings = {}
    for pitch in (0.0, 0.3):
        imu = with_(DEFAULT_IMU, gyro=quiet, orientation=(0.0, pitch, 0.0))
        suite = SensorSuite(SensorConfig(imu=imu), 200.0, np.random.default_rng(0))
        suite.start((0.0, 0.0, 0.0), (0.0, 0.0, 9.81), 0.0, 0.0)
        got = [suite.read(k, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81), 0.0, 0.0).gyro for k in range(4)]
        readings[pitch] = next(g for g in got if g is not None)
        if pitch:
            assert suite.truth()["gyro_turn_on_bias"] == pytest.approx(
                np.array(mounting_matrix(0.0, pitch, 0.0)) @ [0.02, 0.0, 0.0])
    lsb = DEFAULT_IMU.gyro.lsb
    assert readings[0.0] == pytest.approx((0.02, 0.0, 0.0), abs=lsb)
    assert readings[0.3] == pytest.approx((0.02 * np.cos(0.3), 0.0, -0.02 * np.sin(0.3)), abs=2 * lsb)
    # and from a robot file, through the scenario
    sc = load_scenario("paper-exp1", ["robot=paper", "sensors.imu_orientation=[0.0, 0.3, 0.0]"])
    assert sc.sensor_config().imu.orientation == (0.0, 0.3, 0.0)


def test_a_sweep_draws_around_the_robots_own_figures(tmp_path):
    """twin sweep --robot: the sampled plant.scale is a factor of the robot's figures, and the
    sample replays (twin run --sample) as the robot it was."""
    out = tmp_path / "sweep"
    code, stdout, err = _twin("sweep", "balboa-exp3", "--robot", "balboa", "--samples", "1", "--workers", "1",
                              "--controller", "lqr", "--set", "duration=0.5", "--set", "sweep.levels=[0.3]",
                              "--out", str(out))
    assert code == 0, err
    import csv

    row = next(csv.DictReader((out / "sweep.csv").open()))
    code, stdout, err = _twin("run", "balboa-exp3", "--robot", "balboa", "--sample", "0", "--controller", "lqr",
                              "--set", "duration=0.5", "--set", "sweep.levels=[0.3]", "--no-video",
                              "--out", str(tmp_path / "sample"))
    assert code == 0, err
    doc = json.loads((tmp_path / "sample" / "metrics.json").read_text())
    assert doc["scenario"]["robot"] == "balboa"
    assert doc["scenario"]["plant"]["scale"]["m_b"] == pytest.approx(float(row["factor_m_b"]))
    assert float(row["factor_m_b"]) != 1.06  # drawn, around the robot's own mass
