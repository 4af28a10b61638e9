"""Scenarios: validation and one-line errors, the built-ins, the paper regression, determinism, metrics.

Every CLI call goes through click's CliRunner on ``twin.cli.main`` (in process, so the
whole file stays fast) with ``--no-video``; one determinism run also goes through a
subprocess, so that byte-identity is checked across processes too.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import tomllib
from importlib import resources
from types import SimpleNamespace

import numpy as np
import pytest

from twin.robots import load_robot
from click.testing import CliRunner

from twin.cli import main
from twin.outputs.metrics import run_metrics
from twin.params import NOMINAL
from twin.scenarios import ScenarioError, builtin_names, load_scenario
from twin.workflows.run import run_scenario
from twin.scenarios.scenario import parse_override

BUILTINS = ("balboa-exp3", "paper-exp1", "paper-exp2", "paper-exp3", "push-recovery", "rmp220-exp3", "sensor-faults",
            "slope-payload")
METRIC_KEYS = ("fell", "settling_time_s", "theta_rms_rad", "oscillation_peak_to_peak_rad", "final_position_error_m",
               "final_heading_error_rad", "iae_theta", "control_effort", "max_abs_torque_nm",
               "estimator_theta_rmse_rad", "rejected_measurements")


def twin(*args):
    """``twin ARGS`` in process: (exit status, stdout, stderr)."""
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.stdout, r.stderr


def assert_one_line_error(status, stdout, stderr, *fragments, ran=False):
    """Exit status 2, exactly one line ``error: ...`` on stderr holding every fragment; nothing on
    stdout unless the run had ``ran`` (started: its title line was printed)."""
    assert status == 2, (status, stdout, stderr)
    assert "Traceback" not in stderr, stderr
    assert stdout == "" if not ran else stdout.count("\n") == 1, (stdout, stderr)
    lines = stderr.splitlines()
    assert len(lines) == 1 and stderr.endswith("\n"), stderr
    assert lines[0].startswith("error: "), stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


# ---- 1. invalid scenario files and overrides: one line, status 2, nothing written -----------------

FILE = "{file}"  # replaced by the scenario file's path in the expected fragments

INVALID_FILES = {
    "unknown-top-level-key": ('durration = 3.0\n',
                              [FILE, "durration: unknown key", "allowed here: name, description, duration, seed"]),
    "unknown-nested-key": ('[initial]\ntheta = 0.1\nthetta = 0.2\n',
                           [FILE, "initial.thetta: unknown key", "allowed here: theta, alpha, x, y"]),
    "wrong-type": ('duration = "long"\n', [FILE, "duration: must be a number in (0, 3600] s, got 'long'"]),
    "negative-payload": ('[plant]\npayload_mass = -1.0\n',
                         [FILE, "plant.payload_mass: -1.0 is out of range", "allowed in [0, 20] kg"]),
    "control-rate-not-dividing": ('[rates]\ncontrol = 300\n',
                                  [FILE, "rates.control: 300 Hz does not divide rates.physics = 1000 Hz",
                                   "allowed: a control rate whose period is a whole number of physics steps",
                                   "100, 200, 250, 500, 1000 Hz"]),
    "position-beyond-table-I": ('[targets]\nposition = 4.0\n',
                                [FILE, "targets.position: 4.0 is out of range", "allowed in [-3, 3] m"]),
    "push-after-the-end": ('duration = 5.0\n[[pushes]]\nforce = [10.0, 0.0, 0.0]\nstart = 6.0\nduration = 0.1\n',
                           [FILE, "pushes[0].start: 6 s is not before the end of the run (duration = 5 s)",
                            "allowed: [0, 5) s"]),
    "fault-after-the-end": ('duration = 2.0\n[[faults]]\nkind = "dropout"\nsensor = "imu"\nstart = 2.0\n',
                            [FILE, "faults[0].start: 2 s is not before the end of the run", "allowed: [0, 2) s"]),
    "unknown-fault-kind": ('[[faults]]\nkind = "explode"\nsensor = "gyro"\n',
                           [FILE, "faults[0].kind: 'explode' is not allowed",
                            "one of 'dropout', 'stuck', 'spikes', 'latency'"]),
    "unknown-table-III-parameter": ('[plant]\nscale = { m_x = 1.1 }\n',
                                    [FILE, "plant.scale.m_x: unknown parameter",
                                     "allowed: m_w, m_b, n_wa, n_wd, n_yb, n_zb, n_xb, r, b, l, d_b, d_w, g"]),
    "fault-missing-sensor": ('[[faults]]\nkind = "dropout"\nstart = 1.0\n',
                             [FILE, "faults[0].sensor: missing; it is required"]),
    "latency-fault-missing-latency": ('[[faults]]\nkind = "latency"\nsensor = "gyro"\nstart = 1.0\n',
                                      [FILE, "faults[0].latency: missing", "needs the new latency in s"]),
    "invalid-toml": ('duration = = 3\n', [FILE, "not valid TOML", "line 1"]),
    "theta-beyond-fall-limit": ('[initial]\ntheta = 1.2\n',
                                [FILE, "initial.theta: 1.2 is out of range", "allowed in [-0.99, 0.99] rad"]),
    "imu-rate-not-dividing-control": ('[sensors]\nimu_rate = 150\n',
                                      [FILE, "sensors: the control rate (200 Hz) must be a whole multiple of the "
                                             "IMU rate (150 Hz)"]),
    "imu-latency-not-whole-periods": ('[sensors]\nimu_latency = 0.0033\n',
                                      [FILE, "IMU latency (0.0033 s) must be a whole number of control periods "
                                             "(0.005 s)"]),
    "faults-not-an-array": ('[faults]\nkind = "dropout"\nsensor = "imu"\n',
                            [FILE, "faults: must be a list of tables ([[faults]] entries)"]),
    "seed-not-an-integer": ('seed = 1.5\n', [FILE, "seed: must be an integer in [0, ", "got 1.5"]),
}


@pytest.mark.parametrize("case", sorted(INVALID_FILES))
def test_invalid_scenario_file_is_one_line_and_runs_nothing(tmp_path, case):
    text, fragments = INVALID_FILES[case]
    path = tmp_path / f"{case}.toml"
    path.write_text(text, encoding="utf-8")
    out = tmp_path / "out"
    status, stdout, stderr = twin("run", path, "--no-video", "--out", out)
    assert_one_line_error(status, stdout, stderr, *(f.replace(FILE, str(path)) for f in fragments))
    assert stderr.startswith(f"error: {path}: "), stderr
    assert not out.exists(), sorted(p.name for p in out.iterdir())
    # the library raises the same message (the CLI adds nothing but "error: ")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert f"error: {err.value}\n" == stderr


def test_missing_file_and_unknown_builtin(tmp_path):
    out = tmp_path / "out"
    missing = tmp_path / "nope.toml"
    assert_one_line_error(*twin("run", missing, "--no-video", "--out", out), f"{missing}: no such scenario file")
    assert_one_line_error(*twin("run", "paper-exp9", "--no-video", "--out", out),
                          "'paper-exp9' is neither a built-in scenario nor a .toml file",
                          "built-ins: " + ", ".join(BUILTINS), "see 'twin scenarios'")
    assert not out.exists()


SET = "built-in scenario paper-exp2 with --set "

INVALID_OVERRIDES = {
    "unknown-key-path": (["plant.scale.m_q=1.1"],
                         ["--set plant.scale.m_q: unknown key 'm_q' in plant.scale",
                          "allowed: m_w, m_b, n_wa, n_wd, n_yb, n_zb, n_xb, r, b, l, d_b, d_w, g"]),
    "unknown-top-level": (["speed=3"], ["--set speed: unknown key 'speed' in the top level", "allowed: name, "]),
    "below-a-leaf": (["initial.theta.x=3"], ["--set initial.theta.x: unknown key 'x' in initial.theta",
                                            "allowed: none (not a table)"]),
    "non-numeric": (["duration=abc"], [SET + "duration=abc: duration: must be a number in (0, 3600] s, got 'abc'"]),
    "out-of-range": (["initial.theta=2"], [SET + "initial.theta=2: initial.theta: 2.0 is out of range",
                                           "allowed in [-0.99, 0.99] rad"]),
    "scale-out-of-range": (["plant.scale.m_b=0.1"], ["plant.scale.m_b: 0.1 is out of range", "allowed in [0.2, 5] ×"]),
    "no-equals-sign": (["duration"], ["--set 'duration': expected KEY=VALUE with a dotted key",
                                      "e.g. --set plant.scale.m_b=1.2"]),
    "empty-key": (["=3"], ["--set '=3': expected KEY=VALUE"]),
    "table-replaced-by-number": (["initial=3"], ["initial: must be a table, got 3"]),
    "physics-rate-breaks-division": (["rates.physics=999"],
                                     ["rates.control: 200 Hz does not divide rates.physics = 999 Hz"]),
    "push-after-shortened-run": (["pushes=[{force=[20,0,0], start=3, duration=0.1}]", "duration=1"],
                                 ["pushes[0].start: 3 s is not before the end of the run (duration = 1 s)"]),
    "bad-string-choice": (["sensors.estimator=magic"],
                          ["sensors.estimator: estimator 'magic' is neither a built-in (ekf, complementary, kalman2, "
                           "ideal) nor an import path 'package.module:attribute'"]),
}


@pytest.mark.parametrize("case", sorted(INVALID_OVERRIDES))
def test_invalid_override_is_one_line_and_runs_nothing(tmp_path, case):
    items, fragments = INVALID_OVERRIDES[case]
    out = tmp_path / "out"
    args = ["run", "paper-exp2", "--no-video", "--out", out]
    for item in items:
        args += ["--set", item]
    assert_one_line_error(*twin(*args), *fragments)
    assert not out.exists()


def test_duration_option_is_validated_and_named_as_given(tmp_path):
    """--duration is named as the user gave it (not as a --set item the user never wrote)."""
    out = tmp_path / "out"
    for value in ("nan", "7200", "-5", "0"):
        for command in (["run", "paper-exp1", "--no-video"], ["sweep", "paper-exp1", "--samples", "1"]):
            status, stdout, stderr = twin(*command, "--duration", value, "--out", out)
            assert_one_line_error(status, stdout, stderr, f"--duration must be in (0, 3600] s, got {float(value):g}")
            assert "--set" not in stderr
    assert not out.exists()


@pytest.mark.parametrize("items, fragment", [
    (["controller.fou=0.5"], "controller.fou: 0.5 is out of range; allowed in [0, 0.5)"),
    (["initial.theta=0.98"], "initial.theta: 0.98 rad does not start on the wheels"),
    (["faults=[{kind='dropout', sensor='gyro', start=1, duration=0.2, rate=3}]"],
     "faults[0].rate: a dropout fault has no 'rate'; allowed: duration, kind, sensor, start"),
    (["faults=[{kind='latency', sensor='imu', start=1, latency=0.01, magnitude=2}]"],
     "faults[0].magnitude: a latency fault has no 'magnitude'"),
])
def test_inputs_the_engine_cannot_honour_are_refused_on_load(tmp_path, items, fragment):
    out = tmp_path / "out"
    args = ["run", "paper-exp2", "--no-video", "--out", out]
    for item in items:
        args += ["--set", item]
    assert_one_line_error(*twin(*args), fragment)
    assert not out.exists()


def test_scenarios_name_prints_the_toml_to_copy(tmp_path):
    status, stdout, stderr = twin("scenarios", "paper-exp2")
    assert status == 0 and stdout.startswith("# Paper experiment 2") and "[expect]" in stdout
    copy = tmp_path / "mine.toml"
    copy.write_text(stdout, encoding="utf-8")
    assert load_scenario(str(copy)).data["targets"]["position"] == 0.7  # a valid scenario as it stands
    assert_one_line_error(*twin("scenarios", "nope"), "no built-in scenario 'nope'; built-ins: " + ", ".join(BUILTINS))


def test_a_rerun_removes_the_outputs_it_does_not_write_again(tmp_path):
    out = tmp_path / "out"
    (out).mkdir()
    (out / "video.mp4").write_bytes(b"an old video")
    (out / "design.json").write_text("{}")
    status, stdout, stderr = twin("run", "paper-exp1", "--controller", "lqr", "--duration", "0.5", "--no-video",
                                  "--out", out)
    assert status == 0, stderr
    assert not (out / "video.mp4").exists() and not (out / "design.json").exists()  # LQR needs no LMI design
    assert (out / "metrics.json").exists()


def test_the_title_says_which_tables_set_changed(tmp_path):
    status, stdout, stderr = twin("run", "paper-exp3", "--set", "targets.position=0.5", "--duration", "0.2",
                                  "--no-video", "--out", tmp_path / "out")
    assert status == 0, stderr
    assert stdout.splitlines()[0].endswith("[changed by --set: targets]")
    status, stdout, stderr = twin("run", "paper-exp3", "--seed", "3", "--duration", "0.2", "--no-video",
                                  "--out", tmp_path / "out")
    assert "changed by" not in stdout.splitlines()[0]  # the seed and the duration do not change what it shows


def test_infeasible_design_is_one_line_names_the_key_and_writes_nothing(tmp_path):
    """An infeasible design is found on load, before anything runs or is written, and the
    message names the scenario and the keys to change (not the options of 'twin design')."""
    out = tmp_path / "out"
    assert_one_line_error(*twin("run", "paper-exp1", "--no-video", "--set", "design.rho=0.1", "--out", out),
                          "built-in scenario paper-exp1", "rho = 0.1 N·m is too small",
                          "the smallest feasible rho is", "raise design.rho")
    assert not out.exists()


def test_duration_shorter_than_a_control_period_is_rejected_on_load(tmp_path):
    with pytest.raises(ScenarioError, match=r"paper-exp1.*duration: 0.001 s is shorter than one control period"):
        load_scenario("paper-exp1", ["duration=0.001"])
    out = tmp_path / "out"
    assert_one_line_error(*twin("run", "paper-exp1", "--no-video", "--duration", "0.001", "--out", out),
                          "duration: 0.001 s is shorter than one control period; allowed: at least 0.005 s")
    assert not out.exists()


def test_parse_override_reads_toml_values_and_rejects_bad_items():
    assert parse_override("plant.scale.m_b=1.2") == ("plant.scale.m_b", 1.2)
    assert parse_override(" seed = 7 ") == ("seed", 7)
    assert parse_override("video.enabled=false") == ("video.enabled", False)
    assert parse_override("sensors.sensing=ideal") == ("sensors.sensing", "ideal")  # bare string
    assert parse_override("plant.payload_position=[0, 0, 0.2]") == ("plant.payload_position", [0, 0, 0.2])
    for bad in ("duration", "=1", "nope.key=1"):
        with pytest.raises(ScenarioError, match=r"^--set "):
            parse_override(bad)


# ---- 2. the built-ins and valid overrides ---------------------------------------------------------

def _builtin_toml(name):
    return tomllib.loads(resources.files("twin.scenarios.builtin").joinpath(f"{name}.toml").read_text("utf-8"))


def test_builtin_names_match_the_package_files():
    files = sorted(p.name[:-5] for p in resources.files("twin.scenarios.builtin").iterdir()
                   if p.name.endswith(".toml"))
    assert builtin_names() == files == sorted(BUILTINS)


@pytest.mark.parametrize("name", BUILTINS)
def test_every_builtin_loads_and_validates(name):
    raw = _builtin_toml(name)
    sc = load_scenario(name)
    assert sc.name == name and sc.source == f"built-in scenario {name}"
    assert sc.description == raw["description"] and sc.description and "\n" not in sc.description
    assert sc.duration == raw.get("duration", 15.0) > 0
    # every key the file gives survives validation, every other key got its default
    assert sc.data["initial"]["theta"] == raw["initial"]["theta"]
    assert sc.data["targets"]["position"] == raw.get("targets", {}).get("position")
    assert sc.data["targets"]["heading"] == raw.get("targets", {}).get("heading")
    assert len(sc.data["pushes"]) == len(raw.get("pushes", [])) and len(sc.data["faults"]) == len(raw.get("faults", []))
    robot = load_robot(raw.get("robot", "paper"))  # a robot's rates; the paper's: Table III's 200 Hz
    assert sc.robot is robot and sc.data["rates"] == {"physics": 1000.0, "control": robot.control_rate}
    assert sc.data["sensors"]["sensing"] == "estimated" and sc.data["sensors"]["estimator"] == "ekf"
    params = sc.true_params()
    for pname, factor in raw.get("plant", {}).get("scale", {}).items():
        assert getattr(params, pname) == pytest.approx(factor * getattr(robot.params(), pname))
    # building everything again works (check() is idempotent)
    assert sc.check() is sc
    assert sc.sensor_config() is not None and sc.twin_config().control_rate == robot.control_rate


def test_scenarios_command_lists_each_builtin_on_one_line():
    status, stdout, stderr = twin("scenarios")
    assert status == 0 and stderr == "", stderr
    lines = stdout.splitlines()
    assert len(lines) == len(BUILTINS)
    width = max(map(len, BUILTINS))
    for line, name in zip(lines, BUILTINS):
        assert line == f"{name:{width}}  {_builtin_toml(name)['description']}"


def test_valid_override_changes_the_built_objects():
    base = load_scenario("paper-exp1")
    sc = load_scenario("paper-exp1", ["plant.scale.m_b=1.2", "initial.theta=0.2", "seed=9"])
    assert sc.overrides == ("plant.scale.m_b=1.2", "initial.theta=0.2", "seed=9")
    assert sc.source == "built-in scenario paper-exp1 with --set plant.scale.m_b=1.2 initial.theta=0.2 seed=9"
    assert base.true_params().m_b == pytest.approx(1.06 * NOMINAL.m_b)
    assert sc.true_params().m_b == pytest.approx(1.2 * NOMINAL.m_b)
    assert sc.twin_config().params.m_b == pytest.approx(1.2 * NOMINAL.m_b)
    # the file's other factors are kept
    assert sc.true_params().l == pytest.approx(1.08 * NOMINAL.l)
    assert sc.true_params().d_b == pytest.approx(1.5 * NOMINAL.d_b)
    assert sc.experiment().theta0 == 0.2 and sc.seed == 9
    # a whole inline table replaces the file's table
    only = load_scenario("paper-exp1", ["plant.scale={n_yb=2.0}"])
    assert only.true_params().n_yb == pytest.approx(2.0 * NOMINAL.n_yb) and only.true_params().m_b == NOMINAL.m_b
    # structured overrides: a push and a fault
    pushed = load_scenario("paper-exp1", ["pushes=[{force=[20,0,0], start=3, duration=0.1}]"])
    assert pushed.twin_config().disturbances.pushes[0].force == (20.0, 0.0, 0.0)
    faulty = load_scenario("paper-exp1", ["faults=[{kind='latency', sensor='imu', start=1, latency=0.01}]"])
    assert faulty.data["faults"][0]["latency"] == 0.01 and len(faulty.sensor_config().faults) == 1
    # the built-in itself is unchanged by an override (no shared mutable state)
    assert load_scenario("paper-exp1").data == base.data


def test_valid_override_reaches_the_run_directory(tmp_path):
    out = tmp_path / "heavy"
    status, stdout, stderr = twin("run", "paper-exp1", "--no-video", "--controller", "it2", "--duration", "0.5",
                                  "--set", "plant.scale.m_b=1.2", "--out", out)
    assert status == 0, stderr
    assert stdout.startswith("paper-exp1: ") and f"wrote {out}/" in stdout
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["scenario"]["plant"]["scale"]["m_b"] == 1.2 and doc["scenario"]["duration"] == 0.5
    assert "--set plant.scale.m_b=1.2" in doc["source"]
    assert list(doc["runs"]) == ["it2"] and doc["runs"]["it2"]["duration_s"] == pytest.approx(0.5)
    assert not (out / "video.mp4").exists()


# ---- 3. regression: the paper's experiments, estimator in the loop, default noise -----------------

@pytest.fixture(scope="module")
def paper_runs():
    """name → ScenarioResult of the built-in with both controllers (no files written)."""
    return {name: run_scenario(load_scenario(name), ("it2", "t1"), out=None, video=False)
            for name in ("paper-exp1", "paper-exp2", "paper-exp3")}


def _estimated(result, kind):
    run = result.runs[["it2", "t1"].index(kind)]
    assert run.controller == kind and run.sensing == "ekf" and run.estimates is not None
    m = result.metrics[kind]
    assert m["sensing"] == "ekf" and m["estimator_theta_rmse_rad"] > 0  # the estimator really was in the loop
    return run, m


def test_exp1_it2_balances(paper_runs):
    """Measured (seed 0): not fallen, max |θ| for t ≥ 3 s = 0.00998 rad, settling 3.0 s,
    IAE 0.2467 rad·s, estimator θ RMSE 0.00058 rad."""
    run, m = _estimated(paper_runs["paper-exp1"], "it2")
    assert m["fell"] is False and run.status == "ok" and run.t[-1] == pytest.approx(15.0)
    late = run.t >= 3.0 - 1e-9
    assert np.max(np.abs(run.signal("theta")[late])) < 0.02
    assert m["final_position_error_m"] is None and m["final_heading_error_rad"] is None


def test_exp2_it2_reaches_the_position(paper_runs):
    """Measured (seed 0): final position error −0.00068 m (|·| ≤ 0.02 m required), settling 6.5 s."""
    run, m = _estimated(paper_runs["paper-exp2"], "it2")
    assert m["fell"] is False
    assert abs(m["final_position_error_m"]) <= 0.02
    assert m["final_position_error_m"] == pytest.approx(run.distance[-1] - 0.7)


def test_exp3_it2_reaches_position_and_heading(paper_runs):
    """Measured (seed 0): final position error −0.0011 m, final heading error −0.0087 rad
    (|·| ≤ 0.03 each required), settling 8.07 s."""
    run, m = _estimated(paper_runs["paper-exp3"], "it2")
    assert m["fell"] is False
    assert abs(m["final_position_error_m"]) <= 0.03
    assert abs(m["final_heading_error_rad"]) <= 0.03
    assert m["final_heading_error_rad"] == pytest.approx(run.signal("alpha")[-1] - 1.5)


@pytest.mark.parametrize("name", ["paper-exp1", "paper-exp2", "paper-exp3"])
def test_type1_metrics_are_finite_and_recorded(paper_runs, name):
    """Type-1, measured (seed 0) for reference only (no claim about which wins):
    exp1 identical to IT2 (the 10-bit PWM absorbs the small weight difference), IAE 0.2467;
    exp2 position error −0.00030 m, IAE 0.3985; exp3 position error −0.0013 m, heading error
    −0.0084 rad, IAE 0.5284."""
    run, m = _estimated(paper_runs[name], "t1")
    assert m["controller"] == "t1" and set(METRIC_KEYS) <= set(m)
    for k in METRIC_KEYS:
        v = m[k]
        if k in ("final_position_error_m", "final_heading_error_rad", "settling_time_s") and v is None:
            continue
        assert isinstance(v, (bool, int, float)) and math.isfinite(v), (k, v)
    assert (m["final_position_error_m"] is None) == (name == "paper-exp1")
    assert (m["final_heading_error_rad"] is None) == (name != "paper-exp3")
    assert m["iae_theta"] > 0 and m["control_effort"] > 0 and m["max_abs_torque_nm"] > 0


# ---- 4. determinism and the output files -------------------------------------------------------

def _run_exp2(out, seed, subprocess_=False):
    args = ["run", "paper-exp2", "--no-video", "--seed", str(seed), "--duration", "4", "--out", str(out)]
    if subprocess_:
        r = subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True,
                           cwd=tempfile.gettempdir())
        assert r.returncode == 0, r.stderr
    else:
        status, _, stderr = twin(*args)
        assert status == 0, stderr
    return (out / "metrics.json").read_bytes(), (out / "trajectory.csv").read_bytes()


def test_same_seed_is_byte_identical_and_another_seed_differs(tmp_path):
    a = _run_exp2(tmp_path / "A", 3)
    b = _run_exp2(tmp_path / "B", 3, subprocess_=True)  # another process: no hidden state either way
    c = _run_exp2(tmp_path / "C", 4)
    assert a[0] == b[0], "metrics.json differs between two runs with the same seed"
    assert a[1] == b[1], "trajectory.csv differs between two runs with the same seed"
    assert a[1] != c[1] and a[0] != c[0]
    assert json.loads(c[0])["seed"] == 4 and json.loads(a[0])["seed"] == 3


def test_output_files_have_units_a_controller_column_and_every_metric(tmp_path):
    out = tmp_path / "A"
    metrics_bytes, csv_bytes = _run_exp2(out, 3)
    assert sorted(p.name for p in out.iterdir()) == ["design.json", "figure.png", "manifest.json", "metrics.json",
                                                     "trajectory.csv"]
    lines = csv_bytes.decode("utf-8").splitlines()
    header = lines[0].split(",")
    assert header[0] == "controller"
    for column in ("t [s]", "theta [rad]", "theta_est [rad]", "torque_l [N·m]", "distance [m]", "push_fx [N]"):
        assert column in header, column
    assert all(h == "controller" or (h.endswith("]") and " [" in h) for h in header), header
    rows = [line.split(",") for line in lines[1:]]
    assert all(len(r) == len(header) for r in rows)
    per = {k: sum(r[0] == k for r in rows) for k in ("it2", "t1")}
    assert per == {"it2": 801, "t1": 801} and len(rows) == 1602  # 4 s at 200 Hz, both ends
    t = [float(r[header.index("t [s]")]) for r in rows if r[0] == "it2"]
    assert t[0] == 0.0 and t[-1] == pytest.approx(4.0)

    doc = json.loads(metrics_bytes)
    assert doc["seed"] == 3 and doc["scenario"]["seed"] == 3 and doc["scenario"]["duration"] == 4.0
    assert doc["scenario"]["targets"]["position"] == 0.7
    assert set(doc["runs"]) == {"it2", "t1"}
    for kind, m in doc["runs"].items():
        assert set(METRIC_KEYS) <= set(m), set(METRIC_KEYS) - set(m)
        assert m["controller"] == kind and m["final_heading_error_rad"] is None
        assert isinstance(m["final_position_error_m"], float)
        # the CSV's last row is what the metrics report
        last = [r for r in rows if r[0] == kind][-1]
        assert float(last[header.index("distance [m]")]) - 0.7 == pytest.approx(m["final_position_error_m"], abs=1e-12)


# ---- 5. run_metrics against hand computation ------------------------------------------------------

class FakeRun:
    """The parts of a TwinRun that run_metrics reads."""

    def __init__(self, t, theta, torque_l, torque_r, alpha=None, distance=None, theta_est=None, p_d=None,
                 alpha_d=None, status="ok", rejected=0):
        self.t = np.asarray(t, float)
        n = len(self.t)
        self._s = {"theta": np.asarray(theta, float), "torque_l": np.asarray(torque_l, float),
                   "torque_r": np.asarray(torque_r, float),
                   "alpha": np.zeros(n) if alpha is None else np.asarray(alpha, float)}
        self.distance = np.zeros(n) if distance is None else np.asarray(distance, float)
        self.estimates = None if theta_est is None else np.asarray(theta_est, float)
        self.experiment = SimpleNamespace(p_d=p_d, alpha_d=alpha_d)
        self.status, self.controller, self.sensing, self.end_reason, self.seed = status, "it2", "ekf", "", 5
        self.estimator_stats = {"rejected_total": rejected}

    @property
    def fell(self):
        return self.status != "ok"

    def signal(self, name):
        return self._s[name]

    def estimation_rmse(self, name="theta"):
        return float(np.sqrt(np.mean((self.estimates - self._s[name]) ** 2)))


def test_run_metrics_on_a_synthetic_run():
    dt = 0.01
    t = np.arange(0, 1001) * dt  # 0 … 10 s
    # a linear descent from 0.3 rad to 0 at 2.5 s, then a 0.004 rad, 1.3 Hz wobble
    theta = np.where(t < 2.5, 0.3 * (1 - t / 2.5), 0.004 * np.sin(2 * np.pi * 1.3 * (t - 2.5)))
    tl, tr = 0.2 * np.cos(t), -0.5 * np.exp(-t)
    m = run_metrics(FakeRun(t, theta, tl, tr, alpha=0.1 * t, distance=0.05 * t, theta_est=theta + 0.001,
                            p_d=0.7, alpha_d=1.5, rejected=4))
    # |θ| < 0.01 once 0.3 (1 − t/2.5) < 0.01, i.e. t > 2.41667: the first sample is 2.42 s
    assert m["settling_time_s"] == pytest.approx(2.42)
    after = t >= 2.42 - 1e-9
    assert m["theta_rms_rad"] == pytest.approx(math.sqrt(sum(v * v for v in theta[after]) / after.sum()), rel=1e-12)
    # a hand-written trapezoid of |θ|; the triangle alone is 0.3 × 2.5 / 2 = 0.375 rad·s
    iae = sum(0.5 * (abs(theta[i]) + abs(theta[i + 1])) * dt for i in range(len(t) - 1))
    assert m["iae_theta"] == pytest.approx(iae, rel=1e-9)
    assert 0.375 < m["iae_theta"] < 0.375 + 0.004 * 7.5 * 2 / math.pi + 1e-3
    effort = tl ** 2 + tr ** 2
    assert m["control_effort"] == pytest.approx(sum(0.5 * (effort[i] + effort[i + 1]) * dt for i in range(len(t) - 1)),
                                                rel=1e-9)
    last5 = theta[t >= 5.0 - 1e-9]
    assert len(last5) == 501
    assert m["oscillation_peak_to_peak_rad"] == pytest.approx(max(last5) - min(last5), rel=1e-12)
    assert m["oscillation_peak_to_peak_rad"] == pytest.approx(0.008, rel=1e-3)  # the wobble's full swing
    assert m["max_abs_torque_nm"] == pytest.approx(0.5)  # |τ_r| at t = 0
    assert m["final_position_error_m"] == pytest.approx(0.05 * 10 - 0.7)
    assert m["final_heading_error_rad"] == pytest.approx(0.1 * 10 - 1.5)
    assert m["estimator_theta_rmse_rad"] == pytest.approx(0.001)
    assert m["rejected_measurements"] == 4 and m["fell"] is False and m["duration_s"] == pytest.approx(10.0)


def test_run_metrics_when_it_never_settles_or_falls():
    t = np.arange(0, 801) * 0.01  # 0 … 8 s
    theta = 0.05 * np.cos(np.pi * t)  # never inside ±0.01 for good: the last sample is 0.05
    zeros = np.zeros_like(t)
    m = run_metrics(FakeRun(t, theta, zeros, zeros))
    last = theta[t >= 3.0 - 1e-9]  # the last 5 s
    assert m["settling_time_s"] is None
    assert m["theta_rms_rad"] == pytest.approx(math.sqrt(np.mean(last ** 2)), rel=1e-12)
    assert m["oscillation_peak_to_peak_rad"] == pytest.approx(0.1, rel=1e-3)
    assert m["final_position_error_m"] is None and m["final_heading_error_rad"] is None
    assert m["estimator_theta_rmse_rad"] == 0.0 and m["control_effort"] == 0.0 and m["max_abs_torque_nm"] == 0.0
    # a run that fell has no settling time even if its last samples are small
    fell = run_metrics(FakeRun(t[:101], np.linspace(0.5, 0.0, 101), zeros[:101], zeros[:101], status="fell"))
    assert fell["fell"] is True and fell["settling_time_s"] is None and fell["status"] == "fell"
    # one sample: no integral
    one = run_metrics(FakeRun([0.0], [0.2], [0.1], [0.1]))
    assert one["iae_theta"] == 0.0 and one["control_effort"] == 0.0


def test_run_metrics_on_a_real_run_by_hand(paper_runs):
    result = paper_runs["paper-exp2"]
    run, m = result.runs[0], result.metrics["it2"]
    assert m == run_metrics(run)
    t, theta = run.t, run.signal("theta")
    assert m["iae_theta"] == pytest.approx(np.trapezoid(np.abs(theta), t), rel=1e-12)
    effort = run.signal("torque_l") ** 2 + run.signal("torque_r") ** 2
    assert m["control_effort"] == pytest.approx(np.trapezoid(effort, t), rel=1e-12)
    last = t >= t[-1] - 5.0 - 1e-9
    assert m["oscillation_peak_to_peak_rad"] == pytest.approx(theta[last].max() - theta[last].min(), rel=1e-12)
    bad = np.nonzero(np.abs(theta) >= 0.01)[0]
    assert m["settling_time_s"] == pytest.approx(t[bad[-1] + 1])
    assert np.all(np.abs(theta[t >= m["settling_time_s"] - 1e-9]) < 0.01)
    err = run.estimates[:, 0] - theta
    assert m["estimator_theta_rmse_rad"] == pytest.approx(math.sqrt(np.mean(err ** 2)), rel=1e-9)
    assert m["max_abs_torque_nm"] == pytest.approx(np.max(np.abs(run.actuation[:, 2:4])))


def test_twin_run_writes_a_side_by_side_video_that_decodes(tmp_path):
    """`twin run` with video and both controllers: video.mp4 decodes with OpenCV, 30 fps at real
    time (1 s → 31 frames), two 640×480 panels side by side, and the frames change over time."""
    import numpy as np
    from test_render import read_video

    out = tmp_path / "out"
    status, stdout, stderr = twin("run", "paper-exp1", "--duration", "1", "--video", "--out", out)
    assert status == 0, stderr
    frames = read_video(out / "video.mp4")
    assert len(frames) == 31
    assert frames[0].shape == (480, 1280, 3)
    diff = np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean()
    assert diff > 1.0, diff
    assert "video 31 frames" in stdout
