"""The command line as a user runs it: exit status, one-line errors, files written."""
import json
import re
import subprocess
import sys
import tempfile

import pytest


def twin(*args):
    # run outside the checkout, so that the installed package is what runs, as for a user
    return subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True, cwd=tempfile.gettempdir())


def test_design_writes_json(tmp_path):
    out = tmp_path / "gains.json"
    # --no-cache: since issue 18 this is the default design, which other tests may have cached
    r = twin("design", "--decay-rate", "2", "--out", str(out), "--no-cache")
    assert r.returncode == 0, r.stderr
    assert "certificate PASSED" in r.stdout and "G1" in r.stdout and "ms)" in r.stdout
    data = json.loads(out.read_text())
    assert len(data["gains"]) == 2 and all(len(g) == 4 for g in data["gains"])
    assert len(data["P"]) == 4 and data["decay_rate"] == 2.0
    assert {"solve_time_s", "epsilon", "rho"} <= set(data)


@pytest.mark.parametrize("args, message", [
    (["design", "--rho", "0.1"], "rho = 0.1 N·m is too small"),
    (["design", "--epsilon", "-2"], "epsilon must be a finite number in [1e-06, 100]"),
    (["design", "--decay-rate", "500"], "decay rate must be a finite number in [0, 100]"),
    (["design", "--rho", "1e300"], "rho must be a finite number in (0, 1e+06]"),
    (["design", "--max-gain", "0.5"], "max gain 0.5 is below the designed gains' norm"),
    (["run", "paper-exp2", "--set", "plant.model=analytic", "--duration", "-1"], "--duration must be in (0, 3600] s"),
    (["run", "paper-exp2", "--set", "plant.model=analytic", "--duration", "nan"], "--duration must be in (0, 3600] s"),
    (["design", "--rho", "abc"], "Invalid value for '--rho': 'abc' is not a valid float"),
    (["run", "paper-exp7", "--set", "plant.model=analytic"], "'paper-exp7' is neither a built-in scenario"),
    (["analytic"], "'twin analytic' gave way to 'twin run paper-expN --set plant.model=analytic"),
    (["surface", "speed"], "'speed' is not one of 'position', 'direction'"),
    (["analytic", "2", "--duration", "0", "--gains", "g.json"], "'twin analytic' gave way to 'twin run paper-exp2"),
    (["physics", "2", "--duration", "3"], "'twin physics' gave way to 'twin run paper-exp2'"),
    (["design", "--nope"], "No such option '--nope'"),
    (["fly"], "No such command 'fly'"),
])
def test_user_errors_are_one_line(args, message):
    r = twin(*args)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], r.stderr


def test_twin_analytic_names_the_twin_run_that_replaced_it_and_that_command_runs(tmp_path):
    """'twin analytic 3' (issue 27): one line, exit status 2, no traceback, naming the twin run
    that gives the same runs; the command named runs as it is written."""
    r = twin("analytic", "3", "--controller", "both", "--out", str(tmp_path / "old"))
    assert r.returncode == 2 and r.stdout == "" and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: 'twin analytic' gave way to "), r.stderr
    assert "--set design.decay_rate=" in lines[0] and "--gains" in lines[0]
    assert not (tmp_path / "old").exists()
    command = re.search(r"'(twin run [^']+)'", lines[0]).group(1)
    assert command == ("twin run paper-exp3 --set plant.model=analytic --set plant.scale={} "
                       "--set sensors.sensing=ideal")
    out = tmp_path / "new"
    r = twin(*command.split()[1:], "--duration", "1", "--no-video", "--out", str(out))
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "metrics.json").read_text())
    assert set(doc["runs"]) == {"it2", "t1"}  # the old --controller both is the scenario's default
    assert doc["scenario"]["plant"]["model"] == "analytic" and doc["scenario"]["sensors"]["sensing"] == "ideal"


def test_twin_run_on_the_analytic_model_writes_outputs_with_design_options(tmp_path):
    """What 'twin analytic 2 --decay-rate 2.5' did, through twin run: outputs written, the
    design's option recorded, the twin's columns in the trajectory."""
    out = tmp_path / "exp2"
    r = twin("run", "paper-exp2", "--set", "plant.model=analytic", "--set", "plant.scale={}", "--set",
             "sensors.sensing=ideal", "--set", "design.decay_rate=2.5", "--no-video", "--out", str(out))
    assert r.returncode == 0, r.stderr
    for name in ("figure.png", "metrics.json", "design.json", "trajectory.csv"):
        assert (out / name).stat().st_size > 0
    assert json.loads((out / "design.json").read_text())["decay_rate"] == 2.5
    m = json.loads((out / "metrics.json").read_text())
    assert abs(m["runs"]["it2"]["final_position_error_m"]) < 0.01
    header = (out / "trajectory.csv").read_text().splitlines()[0]
    assert "theta [rad]" in header and "ul_cmd [N·m]" in header and "torque_l [N·m]" in header  # the twin's columns


def test_surface_export(tmp_path):
    r = twin("surface", "direction", "--points", "11", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    rows = (tmp_path / "direction_it2.csv").read_text().splitlines()
    assert len(rows) == 1 + 11 * 11
    assert (tmp_path / "direction_it2.png").stat().st_size > 0


def test_twin_run_on_the_nominal_plant_writes_outputs_and_no_native_chatter(tmp_path):
    """What 'twin physics 1' did, through the one pipeline: outputs written; PyBullet's own
    chatter suppressed (stderr holds only the progress bars)."""
    out = tmp_path / "exp1"
    r = twin("run", "paper-exp1", "--controller", "it2", "--duration", "3", "--set", "plant.scale={}",
             "--no-video", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "argv" not in r.stdout + r.stderr and r.stdout.startswith("paper-exp1")
    m = json.loads((out / "metrics.json").read_text())
    it2 = m["runs"]["it2"]
    assert it2["status"] == "ok" and it2["settling_time_s"] < 3.0
    header = (out / "trajectory.csv").read_text().splitlines()[0]
    for column in ("theta [rad]", "torque_l [N·m]", "duty_r [1]", "saturated_l [bool]", "push_fx [N]", "x [m]"):
        assert column in header
    assert len((out / "trajectory.csv").read_text().splitlines()) == 1 + 601
