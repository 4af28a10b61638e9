"""The run specification (issue 27): a scenario becomes a typed :class:`twin.sim.spec.RunSpec`,
validated once when it is built, and one :func:`twin.sim.simulate.simulate` runs it; the
runner, ``simulate_twin`` (kept with its signature) and the Gymnasium environment all go
through it and give the same runs."""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from twin.errors import PluginError, TwinError
from twin.scenarios import load_scenario
from twin.scenarios.planning import plan
from twin.workflows.run import run_scenario
from twin.sensors import SensorConfig
from twin.sim.simulate import build_loop, simulate
from twin.sim.spec import IDEAL_SENSING, InitialState, Logging, Plugin, RunSpec, Sensing


@pytest.fixture(scope="module")
def short():
    return load_scenario("paper-exp3", ["duration=1.0"])


def _same_run(a, b) -> None:
    (na, ua, xa), (nb, ub, xb) = a.columns(), b.columns()
    assert (na, ua) == (nb, ub)
    assert xa.tobytes() == xb.tobytes()  # bit for bit
    assert (a.status, a.end_reason, a.controller, a.sensing, a.plant, a.seed) == \
        (b.status, b.end_reason, b.controller, b.sensing, b.plant, b.seed)


def test_a_scenario_gives_a_spec_that_simulate_runs_as_twin_run_does(short):
    from twin.outputs.metrics import run_metrics

    spec = short.run_spec("it2")
    assert isinstance(spec, RunSpec) and spec.label == "it2" and spec.name == "paper-exp3"
    assert spec.initial == InitialState(short.data["initial"]["theta"], 0.0, 0.0, 0.0)
    assert spec.duration == 1.0 and spec.seed == short.seed and spec.control_rate == 200.0
    run = simulate(spec)
    reference = run_scenario(short, ["it2"])
    assert run_metrics(run) == {**reference.metrics["it2"], "sensing": run.sensing}
    _same_run(run, reference.runs[0])


def test_a_spec_of_kinds_builds_its_plugins_per_run_and_gives_the_same_run(short):
    built, kinds = short.run_spec("lqr"), short.run_spec("lqr", build=False)
    assert kinds.controller == Plugin("lqr", None) and kinds.estimator.kind == "ekf"
    assert not built.controller.is_kind
    _same_run(simulate(built), simulate(kinds))


def test_simulate_twin_is_a_wrapper_of_simulate(short):
    from twin.sim.bullet_loop import simulate_twin

    spec = short.run_spec("lqr")
    controller = spec.controller.kind
    run = simulate_twin(controller, spec.experiment, spec.plant, controller_name="lqr", sensors=spec.sensing.true,
                        estimator=spec.estimator.kind, seed=spec.seed)
    _same_run(run, simulate(short.run_spec("lqr")))


def test_a_spec_is_reused_with_other_parameters_as_calibration_will(short):
    """replace() makes a new, re-validated spec; the same spec runs any number of times."""
    spec = short.run_spec("lqr", build=False)
    first, again = simulate(spec), simulate(spec)
    _same_run(first, again)
    heavy = dataclasses.replace(spec, plant=dataclasses.replace(spec.plant, params=spec.plant.params.perturbed(
        scale={"m_b": 1.2})))
    other = simulate(heavy)
    assert not np.array_equal(other.signal("theta"), first.signal("theta"))
    reseeded = simulate(dataclasses.replace(spec, seed=spec.seed + 1))
    assert reseeded.seed == spec.seed + 1
    assert reseeded.columns()[2].tobytes() != first.columns()[2].tobytes()  # other sensor noise


def test_the_analytic_plant_and_ideal_sensing_are_fields_of_the_spec():
    sc = load_scenario("paper-exp1", ["duration=0.5", "plant.model=\"analytic\"", "sensors.sensing=\"ideal\""])
    spec = sc.run_spec("it2")
    assert spec.plant_model == "analytic" and spec.sensing.ideal and spec.motor is None
    run = simulate(spec)
    assert run.plant == "analytic" and run.sensing == "ideal" and run.seed is None


@pytest.mark.parametrize("change, message", [
    ({"duration": 0.001}, "duration must be at least one control period (0.005 s), got 0.001 s"),
    ({"duration": float("nan")}, "duration must be at least one control period"),
    ({"seed": -1}, "seed must be a non-negative integer, got -1"),
    ({"seed": True}, "seed must be a non-negative integer, got True"),
    ({"plant_model": "mujoco"}, "plant 'mujoco' is neither a built-in (bullet, analytic) nor an import path"),
    ({"plant_params": [1]}, "RunSpec.plant_params must be a table of keyword arguments"),
    ({"plant_model": object()}, "has no reset(), step(), close()"),
    ({"targets": (1.0, None)}, "RunSpec.targets must be a twin.protocols.Targets(position, heading)"),
    ({"controller": "it2"}, "RunSpec.controller must be a twin.sim.spec.Plugin(kind, params) or None"),
    ({"sensing": IDEAL_SENSING, "estimator": Plugin("complementary")},
     "sensors=None is ideal sensing (the 'ideal' estimator reads the truth), so estimator 'complementary' would not"),
    ({"sensing": Sensing(SensorConfig(imu=dataclasses.replace(SensorConfig().imu, rate=66.0)))},
     "the control rate (200 Hz) must be a whole multiple of the IMU rate (66 Hz)"),
    ({"options": [1, 2]}, "RunSpec.options must be a table"),
])
def test_a_bad_spec_is_one_line_when_it_is_built(short, change, message):
    spec = short.run_spec("lqr", build=False)
    with pytest.raises((TwinError, PluginError)) as err:
        dataclasses.replace(spec, **change)
    text = str(err.value)
    assert message in text and "\n" not in text


@pytest.mark.parametrize("build, message", [
    (lambda: Logging(every=0), "log_every must be a whole number of control steps ≥ 1"),
    (lambda: Logging(every=5, diagnostics=True), "log_filter needs every control step"),
    (lambda: Logging(format="parquet"), "log_format must be one of csv, csv.gz, got 'parquet'"),
    (lambda: Sensing(None, SensorConfig()), "sensing.believed needs simulated sensors"),
    (lambda: Sensing("mpu6050"), "sensing.true must be a SensorConfig or None (ideal sensing)"),
    (lambda: InitialState(theta=float("inf")), "initial theta must be a finite number in rad"),
    (lambda: Plugin(""), "a plugin kind must not be empty"),
    (lambda: Plugin(object(), {"a": 1}), "plugin parameters are for a kind"),
    (lambda: Plugin("it2", [("fou", 0.1)]), "plugin parameters must be a table"),
])
def test_the_parts_of_a_spec_check_themselves(build, message):
    with pytest.raises(TwinError) as err:
        build()
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_spec_without_a_controller_is_a_loop_stepped_with_commands_but_no_simulation(short):
    spec = short.run_spec(None, build=False)
    assert spec.controller is None and spec.label == ""
    with pytest.raises(TwinError, match="this run has no controller"):
        simulate(spec)
    with build_loop(spec) as loop:
        loop.reset(spec.seed)
        res = loop.step((0.01, 0.01))
        assert res.status == "running" and res.truth.t == pytest.approx(0.005)


def test_a_plugin_that_cannot_be_built_is_said_once_before_anything_runs(tmp_path):
    (tmp_path / "broken_plugin.py").write_text("def make(context):\n    return object()\n")
    code = ("import sys; sys.path.insert(0, %r)\n"
            "import twin.registry as r\n"
            "calls = []\n"
            "orig = r.build_controller\n"
            "def counted(*a, **k):\n"
            "    calls.append(a[0])\n"
            "    return orig(*a, **k)\n"
            "r.build_controller = counted\n"
            "from twin.scenarios import load_scenario\n"
            "from twin.scenarios.planning import plan\nfrom twin.workflows.run import run_scenario\n"
            "sc = load_scenario('paper-exp1', ['duration=0.05'])\n"
            "specs = plan(sc, ('lqr', 't1'))\n"
            "run_scenario(sc, ('lqr', 't1'), specs=specs)\n"
            "print(calls)\n" % str(tmp_path))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "['lqr', 't1']"  # each controller built once, by plan
    sc = load_scenario("paper-exp1", ["duration=0.05"])
    with pytest.raises(TwinError) as err:
        plan(sc, ("lqr", "broken_plugin:make"))
    assert "\n" not in str(err.value)


def test_specs_that_are_not_the_runs_asked_for_are_refused(short):
    specs = plan(short, ("lqr",))
    with pytest.raises(TwinError, match=r"specs must be plan\(scenario, \['it2'\]\)'s"):
        run_scenario(short, ("it2",), specs=specs)


def test_the_python_api_exports_the_spec_and_simulate():
    import twin

    assert twin.RunSpec is RunSpec and twin.simulate is simulate and twin.build_loop is build_loop


def test_the_build_context_is_not_changed_after_it_is_made():
    """The registry's context is a frozen value: its default model is the nominal one from the
    start, and the default design comes from the design store, not a memo written into it."""
    from twin.params import NOMINAL
    from twin.registry import BuildContext

    ctx = BuildContext()
    assert ctx.model is NOMINAL and ctx.design is None
    first = ctx.balance_design()
    assert ctx.design is None and ctx.balance_design() is first  # the store's, once per process
    with pytest.raises(TwinError, match="BuildContext.model must be a twin.params.RobotParams"):
        BuildContext(200.0, None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ctx.model = None
