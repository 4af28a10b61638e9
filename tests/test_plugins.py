"""A user's own controller and estimator, from a file outside the package, through every door:
the Python API, a scenario file, 'twin run' and 'twin sweep' (identical metrics each way);
and plugins that break the contract, each a one-line error that writes nothing."""
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

from twin.cli import main
from twin.errors import PluginError, TwinError
from twin.experiments import Experiment
from twin.sim.loop import ClosedLoop
from twin.protocols import Controller, Estimator, Targets
from twin.registry import (BuildContext, build_controller, build_estimator, check_kind, label, parse_controllers,
                           provenance)
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "my_plugins.py"
CTRL, EST = "my_plugins:StateFeedback", "my_plugins:TiltFilter"
SHORT = ["duration=3"]

BAD = textwrap.dedent('''
    import math

    class NoReset:
        def __call__(self, estimate, targets):
            return (0.0, 0.0)

    class WrongShape:
        def reset(self, targets):
            pass
        def __call__(self, estimate, targets):
            return (0.1,)

    class NaNTorque:
        """Fine for 0.05 s, then a NaN torque."""
        def reset(self, targets):
            self.calls = 0
        def __call__(self, estimate, targets):
            self.calls += 1
            return (0.0, math.nan) if self.calls > 10 else (0.0, 0.0)

    class NaNEstimator:
        def start(self, m):
            return (0.0,) * 6
        def step(self, m, command):
            return (math.nan,) * 6

    class Gain:
        def __init__(self, k):
            self.k = k
        def reset(self, targets):
            pass
        def __call__(self, estimate, targets):
            return (self.k, self.k)

    class Raises:
        def reset(self, targets):
            pass
        def __call__(self, estimate, targets):
            raise RuntimeError("boom in controller")

    class Clash:
        signals = ("theta", "extra")
        def reset(self, targets):
            pass
        def __call__(self, estimate, targets):
            return (0.0, 0.0, 1.0, 2.0)

    class LateNaN:
        """Fine for 0.5 s (past the sweep's preflight), then a NaN torque."""
        def reset(self, targets):
            self.calls = 0
        def __call__(self, estimate, targets):
            self.calls += 1
            return (0.0, math.nan) if self.calls > 100 else (0.0, 0.0)

    class BufferEstimator:
        """Returns the same list object every step, updated in place (as array-based filters do)."""
        reads_truth = True
        def start(self, m):
            self.out = [0.0] * 6
            return self.step(m, None)
        def step(self, m, command):
            tr = m.truth
            self.out[:] = [tr.theta, tr.theta_dot, tr.psi, tr.psi_dot, tr.alpha, tr.alpha_dot]
            return self.out

    not_callable = 3
''')


@pytest.fixture()
def plugin_dir(tmp_path, monkeypatch):
    """A directory outside the package holding the example plugins and some broken ones, on sys.path."""
    d = tmp_path / "plugins"
    d.mkdir()
    shutil.copy(EXAMPLE, d / "my_plugins.py")
    (d / "bad_plugins.py").write_text(BAD, encoding="utf-8")
    monkeypatch.syspath_prepend(str(d))
    for name in ("my_plugins", "bad_plugins"):
        sys.modules.pop(name, None)
    yield d
    for name in ("my_plugins", "bad_plugins"):
        sys.modules.pop(name, None)


def _cli(*args, cwd: Path):
    """``twin ARGS`` as a user runs it, in ``cwd`` (where the plugin files are)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run([sys.executable, "-m", "twin.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=600)


def _strip(metrics: dict) -> dict:
    return {k: v for k, v in metrics.items() if k != "success"}


# ---- the contract ------------------------------------------------------------------------------
def test_the_examples_meet_the_protocols_structurally(plugin_dir):
    import my_plugins

    ctx = BuildContext()
    assert isinstance(my_plugins.StateFeedback(), Controller)
    assert isinstance(my_plugins.TiltFilter(ctx), Estimator)
    assert not isinstance(object(), Controller)


def test_registry_names_kinds_and_labels():
    assert check_kind("controller", "lqr") == "lqr"
    assert check_kind("estimator", "pkg.sub:Thing") == "pkg.sub:Thing"
    for bad in ("magic", "pkg.mod", "pkg:", ":X", "1pkg:X", 3):
        with pytest.raises(PluginError, match="neither a built-in"):
            check_kind("controller", bad)
    assert parse_controllers("both") == ("it2", "t1")
    assert parse_controllers("it2, lqr ,pkg:C") == ("it2", "lqr", "pkg:C")
    with pytest.raises(PluginError, match="repeated"):
        parse_controllers("it2,it2")
    assert [label(k) for k in ("it2", "t1", "lqr", "pkg.mod:Mine")] == ["IT2", "type-1", "LQR", "Mine"]


def test_provenance_records_module_file_and_hash(plugin_dir):
    import hashlib

    p = provenance("controller", CTRL)
    assert p["module"] == "my_plugins" and Path(p["file"]) == plugin_dir / "my_plugins.py"
    assert p["sha256"] == hashlib.sha256((plugin_dir / "my_plugins.py").read_bytes()).hexdigest()
    assert provenance("controller", "it2") is None


def test_parameters_reach_the_factory_and_unknown_ones_are_named(plugin_dir):
    c = build_controller(CTRL, {"k": [-1.0, -0.1, -0.05, -0.03]})
    assert c.k == (-1.0, -0.1, -0.05, -0.03)
    with pytest.raises(PluginError, match=r"cannot be built with parameters \{'gain': 2\}.*allowed parameters: k, "
                                          r"k_heading, wheel_radius, psi_error_limit"):
        build_controller(CTRL, {"gain": 2})
    e = build_estimator(EST, {"a": 0.9}, BuildContext(control_rate=100.0))
    assert e.a == 0.9 and e.dt == 0.01  # the context reached the factory, which asked for it


@pytest.mark.parametrize("role, kind, message", [
    ("controller", "no_such_module_xyz:C", "no module named 'no_such_module_xyz'"),
    ("controller", "bad_plugins:Missing", "module 'bad_plugins' has no attribute 'Missing'"),
    ("controller", "bad_plugins:not_callable", "'not_callable' is a int, not a class or factory function"),
    ("controller", "bad_plugins:NoReset", "has no reset(); a controller needs reset(targets) and __call__"),
    ("estimator", "bad_plugins:NoReset", "has no start() or step(); an estimator needs start(measurement)"),
])
def test_bad_plugins_fail_to_build_in_one_line(plugin_dir, role, kind, message):
    build = build_controller if role == "controller" else build_estimator
    with pytest.raises(PluginError) as info:
        build(kind)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_the_loop_checks_the_contract_at_every_step(plugin_dir):
    import bad_plugins

    exp = Experiment("e", "", theta0=0.1, duration=1.0)
    ideal = build_estimator("ideal")
    with ClosedLoop(None, ideal, bad_plugins.WrongShape(), None, exp.targets, 0.1) as loop:
        loop.reset(0)
        with pytest.raises(PluginError, match=r"WrongShape returned \(0.1,\) at t = 0.000 s; expected 2 finite"):
            loop.command()
        with pytest.raises(PluginError, match=r"step\(command\) returned \(1.0, 'x'\)"):
            loop.step((1.0, "x"))
        loop.step((0.0, 0.0))  # an external command of the right shape is taken
        assert loop.k == 1 and loop.status == "running"


def test_closed_loop_exposes_truth_readings_estimate_and_command():
    """The steppable loop with the EKF and no controller: a caller chooses the torques."""
    from twin.sensors import SensorConfig

    ctx = BuildContext(sensors=SensorConfig())
    with ClosedLoop(None, build_estimator("ekf", None, ctx), None, SensorConfig(), Targets(), theta0=0.05) as loop:
        first = loop.reset(seed=3)
        assert first.status == "running" and first.truth.theta == pytest.approx(0.05, abs=1e-6)
        assert first.measurement.gyro is not None and first.measurement.truth is None  # no truth for a real estimator
        with pytest.raises(TwinError, match="no controller"):
            loop.command()
        for _ in range(20):
            r = loop.step((0.05, 0.05))
        assert loop.t == pytest.approx(0.1) and r.truth.t == pytest.approx(0.1)
        assert abs(r.estimate[0] - r.truth.theta) < 0.02
        assert loop.actuation.torque_l > 0


# ---- the same plugins through every door -------------------------------------------------------
def test_plugins_give_identical_metrics_through_api_toml_run_and_sweep(plugin_dir, tmp_path):
    # 1. the Python API: the objects built by hand and handed to simulate_twin
    import my_plugins

    from twin.sim.bullet_loop import simulate_twin
    from twin.outputs.metrics import run_metrics

    sc = load_scenario("paper-exp3", SHORT)
    ctx = sc.build_context()
    run = simulate_twin(my_plugins.StateFeedback(), sc.experiment(), sc.twin_config(), controller_name=CTRL,
                        sensors=sc.sensor_config(), estimator=my_plugins.TiltFilter(ctx), seed=sc.seed)
    run.sensing = EST
    m_api = run_metrics(run)
    assert m_api["status"] == "ok" and m_api["final_position_error_m"] is not None

    # 2. a scenario file naming them: the built-in paper-exp3 plus the plugins (and a parameter)
    text = Path(__file__).resolve().parents[1].joinpath("twin", "scenarios", "builtin", "paper-exp3.toml").read_text(
        encoding="utf-8").replace("duration = 15.0", "duration = 3.0")
    toml = tmp_path / "mine.toml"
    toml.write_text(text + textwrap.dedent(f'''
        [controller]
        kinds = ["{CTRL}", "lqr"]
        [controller.params."{CTRL}"]
        psi_error_limit = 1.0
        [sensors]
        estimator = "{EST}"
        [video]
        enabled = false
    '''), encoding="utf-8")
    from_file = run_scenario(load_scenario(str(toml)))
    assert from_file.metrics[CTRL] == m_api
    assert [p["kind"] for p in from_file.plugins] == [CTRL, EST]

    # 3. twin run, in the plugins' directory (found there, as python -m would)
    out = tmp_path / "run"
    r = _cli("run", str(toml), "--out", out, cwd=plugin_dir)
    assert r.returncode == 0, r.stderr
    assert f"plugin controller {CTRL}: {plugin_dir / 'my_plugins.py'}" in r.stdout
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["runs"][CTRL] == json.loads(json.dumps(m_api))
    assert {p["kind"] for p in doc["plugins"]} == {CTRL, EST}
    assert doc["scenario"]["controller"]["kinds"] == [CTRL, "lqr"]
    header = (out / "trajectory.csv").read_text().splitlines()[0]
    assert "u_alpha [N·m]" in header and "theta_off [rad]" in header  # the union of both controllers' signals

    # 4. twin sweep: one draw at λ = 0; its metrics equal the API run of the same sample
    sweep_dir = tmp_path / "sweep"
    r = _cli("sweep", str(toml), "--samples", "1", "--workers", "1", "--set", "sweep.levels=[0.0]",
             "--set", "sweep.parameters=[]", "--out", sweep_dir, cwd=plugin_dir)
    assert r.returncode == 0, r.stderr
    record = json.loads((sweep_dir / "samples.jsonl").read_text().splitlines()[0])
    from twin.sweep import sample_scenario

    swept = load_scenario(str(toml), ["sweep.levels=[0.0]", "sweep.parameters=[]"])
    replay = run_scenario(sample_scenario(swept, swept.seed, 0).scenario)
    for kind in (CTRL, "lqr"):
        assert _strip(record["runs"][kind]) == json.loads(json.dumps(replay.metrics[kind]))
    assert "MyController" not in r.stdout and "StateFeedback" in (sweep_dir / "summary.md").read_text()


# ---- broken plugins on the command line ---------------------------------------------------------
@pytest.mark.parametrize("args, message", [
    (["--controller", "no_such_module_xyz:C"], "controller 'no_such_module_xyz:C': no module named"),
    (["--controller", "bad_plugins:Missing"], "module 'bad_plugins' has no attribute 'Missing'"),
    (["--controller", "bad_plugins:NoReset"], "has no reset()"),
    (["--controller", "bad_plugins:WrongShape"], "returned (0.1,) at t = 0.000 s; expected 2 finite numbers"),
    (["--controller", "bad_plugins:NaNTorque"], "returned (0.0, nan) at t = 0.050 s"),
    (["--controller", "it2", "--set", "sensors.estimator='bad_plugins:NaNEstimator'"],
     "NaNEstimator: step() returned (nan, nan"),
    (["--controller", "bad_plugins:Gain"], "cannot be built with parameters {}"),
    (["--controller", "bad_plugins:Raises"], "__call__() raised RuntimeError: boom in controller at t = 0.000 s"),
    (["--controller", "bad_plugins:Clash"], "signal names 'theta' repeat each other or a logged column"),
    (["--controller", "lqr", "--set", "controller.params.lqr.gain=3"],
     "controller.params.lqr: controller 'lqr': unknown parameter 'gain'; allowed: psi_error_limit"),
    (["--controller", "it2", "--set", "controller.params.it2=3"],
     "controller.params.it2: must be a table of keyword arguments"),
    (["--controller", "it2", "--set", "controller.params.it3={fou=0.1}"],
     "controller.params.it3: controller 'it3' is neither a built-in"),
])
@pytest.mark.parametrize("command", ["run", "sweep"])
def test_bad_plugins_are_one_line_exit_2_and_write_nothing(plugin_dir, tmp_path, monkeypatch, command, args,
                                                          message):
    monkeypatch.chdir(plugin_dir)
    out = tmp_path / "out"
    base = ["run", "paper-exp1", "--no-video", "--duration", "1"] if command == "run" else \
        ["sweep", "paper-exp1", "--samples", "1", "--workers", "1", "--duration", "1"]
    r = CliRunner().invoke(main, base + args + ["--out", str(out)])
    assert r.exit_code == 2, (r.stdout, r.stderr)
    errors = [line for line in r.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and message in errors[0], r.stderr
    assert "Traceback" not in r.stderr and r.stderr.rstrip().endswith(errors[0])
    assert not out.exists()


def test_a_plugin_whose_torque_turns_nan_later_stops_the_run_naming_the_time(plugin_dir):
    sc = load_scenario("paper-exp1", ["duration=2"])
    with pytest.raises(PluginError) as info:
        run_scenario(sc, ["bad_plugins:NaNTorque"])
    text = str(info.value)
    t = float(text.split(" at t = ")[1].split(" s")[0])
    assert 0.0 < t < 2.0 and not math.isnan(t)


@pytest.mark.parametrize("kind", ["ekf", "complementary", "kalman2"])
def test_a_reset_loop_reuses_its_estimator_as_if_new(kind):
    """ClosedLoop.reset reuses the estimator: start() must forget the previous run, so the
    second episode of a loop equals the first of a fresh loop, bit for bit, counts included."""
    from twin.sensors import SensorConfig

    sensors = SensorConfig()
    ctx = BuildContext(sensors=sensors)
    # from 0.2 rad: gentle enough for the hobby filters (from 0.3 rad the default design's hard catch
    # makes the complementary filter read the acceleration as tilt, and the robot falls; LQR's too)
    controller = build_controller("it2", None, ctx)

    def episode(loop, seed):
        out = [tuple(loop.reset(seed).estimate)]
        for _ in range(200):
            out.append(tuple(loop.step().estimate))
        return out, loop.estimator_stats()

    with ClosedLoop(None, build_estimator(kind, None, ctx), controller, sensors, Targets(), theta0=0.2) as loop:
        episode(loop, 5)
        again = episode(loop, 9)
    with ClosedLoop(None, build_estimator(kind, None, ctx), controller, sensors, Targets(), theta0=0.2) as loop:
        fresh = episode(loop, 9)
    assert again == fresh


def test_a_plugin_that_breaks_later_in_a_sweep_keeps_the_others_results_and_exits_2(plugin_dir, tmp_path,
                                                                                     monkeypatch):
    """Past the 0.05 s preflight: the broken controller's runs are errors, the reference's
    runs of the same samples stand, and the sweep says so in one line with exit status 2."""
    monkeypatch.chdir(plugin_dir)
    out = tmp_path / "sweep"
    r = CliRunner().invoke(main, ["sweep", "paper-exp1", "--samples", "1", "--workers", "1", "--duration", "1",
                                  "--set", "sweep.levels=[0.0]", "--set", "initial.theta=0.0",
                                  "--controller", "bad_plugins:LateNaN,it2",
                                  "--out", str(out)])
    assert r.exit_code == 2, (r.stdout, r.stderr)
    errors = [line for line in r.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "1 run ended with a plugin error (first: sample 0, controller" in errors[0]
    record = json.loads((out / "samples.jsonl").read_text().splitlines()[0])
    assert set(record["runs"]) == {"it2"} and record["runs"]["it2"]["status"] == "ok"
    assert record["errors"]["bad_plugins:LateNaN"].startswith("PluginError: controller bad_plugins.LateNaN returned")
    rows = (out / "sweep.csv").read_text().splitlines()
    assert rows[1].split(",")[4:6] == ["bad_plugins:LateNaN", "error"] and rows[2].split(",")[4:6] == ["it2", "ok"]


def test_an_estimate_returned_in_a_reused_buffer_is_logged_as_it_was(plugin_dir):
    """The loop keeps a copy: a filter that updates one list in place does not rewrite the log."""
    import bad_plugins

    from twin.sim.bullet_loop import simulate_twin

    exp = Experiment("e", "", theta0=0.3, duration=0.5)
    run = simulate_twin(build_controller("lqr"), exp, sensors=None, estimator=bad_plugins.BufferEstimator())
    assert run.signal("theta_est")[0] == pytest.approx(0.3, abs=1e-6)
    assert list(run.signal("theta_est")) == list(run.signal("theta"))


def test_ideal_sensing_refuses_an_estimator_it_would_not_run(plugin_dir):
    import my_plugins

    from twin.sim.bullet_loop import simulate_twin

    exp = Experiment("e", "", theta0=0.1, duration=0.1)
    with pytest.raises(TwinError, match="sensors=None is ideal sensing .* would not run"):
        simulate_twin(build_controller("lqr"), exp, sensors=None, estimator=my_plugins.TiltFilter(BuildContext()))
    with pytest.raises(TwinError, match="estimator 'kalman2' would not run"):
        simulate_twin(build_controller("lqr"), exp, sensors=None, estimator="kalman2")


def test_a_sweep_in_which_every_run_errors_exits_non_zero(plugin_dir, tmp_path, monkeypatch):
    monkeypatch.chdir(plugin_dir)
    out = tmp_path / "sweep"
    r = CliRunner().invoke(main, ["sweep", "paper-exp1", "--samples", "2", "--workers", "1", "--duration", "1",
                                  "--set", "sweep.levels=[0.0]", "--set", "initial.theta=0.0",
                                  "--controller", "bad_plugins:LateNaN", "--out", str(out)])
    assert r.exit_code == 2, (r.stdout, r.stderr)
    errors = [line for line in r.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "every run of the sweep ended in an error, so nothing was measured" in errors[0]
    assert len((out / "samples.jsonl").read_text().splitlines()) == 2  # what ran is kept
