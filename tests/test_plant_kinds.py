"""Plants are kinds of the registry, as controllers and estimators are: "bullet", "analytic" and
one's own "package.module:attribute", built alike (factory(config, theta0, alpha0, position,
**params)), selectable from a scenario file (examples/my_plant.toml); the loop and the run
specification know the Plant contract alone (Plant.trusted, Plant.applies_motor)."""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

from twin.errors import PluginError
from twin.plant.base import TwinConfig
from twin.registry import PLANTS, build_plant, check_kind
from twin.sim.spec import Plugin, RunSpec

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture
def lab(tmp_path, monkeypatch):
    """examples/my_plant.py and .toml copied into a folder of a user's (the module found beside the scenario)."""
    for name in ("my_plant.py", "my_plant.toml"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    monkeypatch.delitem(sys.modules, "my_plant", raising=False)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_the_built_in_plants_are_kinds_named_by_import_paths():
    assert set(PLANTS) == {"bullet", "analytic"}
    twin = build_plant("bullet", TwinConfig(), 0.1)
    try:
        assert type(twin).__name__ == "BulletTwin" and twin.truth.theta == pytest.approx(0.1)
        assert twin.trusted and twin.applies_motor
    finally:
        twin.close()
    analytic = build_plant("analytic", TwinConfig(motor=None), 0.1)
    assert type(analytic).__name__ == "AnalyticPlant" and analytic.trusted and not analytic.applies_motor
    with pytest.raises(PluginError, match=r"^plant 'mujoco' is neither a built-in \(bullet, analytic\) nor an import "
                                          r"path 'package.module:attribute'$"):
        check_kind("plant", "mujoco")
    with pytest.raises(PluginError, match=r"^plant 'bullet': unknown parameter 'gain'; allowed: none$"):
        build_plant("bullet", TwinConfig(), params={"gain": 1})


def test_a_fresh_twin_is_kept_by_reset_and_a_stepped_one_rebuilt():
    twin = build_plant("bullet", TwinConfig(), 0.1)
    try:
        client = twin.client
        twin.reset(0.1, 0.0, (0.0, 0.0))
        assert twin.client is client  # just built at that start: the same twin
        twin.reset(0.2, 0.0, (0.0, 0.0))
        assert twin.client is not client and twin.truth.theta == pytest.approx(0.2)  # another start: built again
        client = twin.client
        twin.step(0.0, 0.0)
        twin.reset(0.2, 0.0, (0.0, 0.0))
        assert twin.client is not client and twin.n_physics == 0 and twin.truth.t == 0.0
    finally:
        twin.close()


def test_a_plant_of_ones_own_runs_from_a_scenario_file(lab):
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    sc = load_scenario(str(lab / "my_plant.toml"), ["duration=1.0"])
    assert sc.plant_model == "my_plant:TSPlant"
    sc.twin_config()
    assert "my_plant" not in sys.modules  # loading a scenario runs none of a user's code
    result = run_scenario(sc, ("it2",), out=lab / "out", video=False)
    m = result.metrics["it2"]
    assert m["status"] == "ok" and m["settling_time_s"] < 1.0
    doc = json.loads((lab / "out" / "metrics.json").read_text())
    assert [p["role"] for p in doc["plugins"]] == ["plant"] and doc["plugins"][0]["kind"] == "my_plant:TSPlant"
    assert result.runs[0].plant == "my_plant:TSPlant"  # as the run records it
    # the spec carries the kind and its parameters; the controllers see ideal torque sources
    spec = sc.run_spec("it2", build=False)
    assert spec.plant_model == "my_plant:TSPlant" and spec.plant_params == {"substeps": 5} and spec.motor is None


def test_a_plant_kind_that_breaks_its_contract_is_one_line(lab):
    (lab / "bad_plant.py").write_text(
        "class NoStep:\n"
        "    control_rate = 200.0\n"
        "    def __init__(self, config, theta0, alpha0, position):\n"
        "        pass\n"
        "    def reset(self, theta0, alpha0, position):\n"
        "        pass\n"
        "    def close(self):\n"
        "        pass\n")
    sys.path.insert(0, str(lab))
    try:
        with pytest.raises(PluginError) as info:
            build_plant("bad_plant:NoStep", TwinConfig())
        assert str(info.value).startswith("plant 'bad_plant:NoStep': bad_plant.NoStep") and "has no step()" in str(info.value)
        assert "\n" not in str(info.value)
        with pytest.raises(PluginError, match=r"^plant 'bad_plant:Missing': module 'bad_plant' has no attribute 'Missing'$"):
            build_plant("bad_plant:Missing", TwinConfig())
        with pytest.raises(PluginError, match=r"^plant 'my_plant:TSPlant': cannot be built as factory\(config, theta0, "
                                              r"alpha0, position, \*\*\{'gain': 1\}\)"):
            build_plant("my_plant:TSPlant", TwinConfig(), params={"gain": 1})
    finally:
        sys.path.remove(str(lab))


def test_the_loop_checks_the_truth_of_a_plant_that_is_not_trusted(lab):
    """Plant.trusted: the built-ins' truth is taken as it is; one's own is checked at every step."""
    from twin.sim.loop import ClosedLoop

    sys.path.insert(0, str(lab))
    try:
        plant = build_plant("my_plant:TSPlant", TwinConfig())
        loop = ClosedLoop(plant, _Estimator(), None)
        assert loop._foreign
        type(plant).trusted = True
        try:
            assert not ClosedLoop(plant, _Estimator(), None)._foreign
        finally:
            del type(plant).trusted
        twin = build_plant("bullet", TwinConfig())
        try:
            assert not ClosedLoop(twin, _Estimator(), None)._foreign
        finally:
            twin.close()
    finally:
        sys.path.remove(str(lab))


def test_a_run_specification_names_a_plant_kind_or_refuses_in_one_line():
    with pytest.raises(PluginError, match=r"^plant 'pybullet' is neither a built-in"):
        RunSpec(Plugin("it2"), plant_model="pybullet")
    assert RunSpec(Plugin("it2"), plant_model="analytic", plant=TwinConfig(motor=None)).plant_name == "analytic"
    assert RunSpec(Plugin("it2")).plant_name == "twin" and RunSpec(Plugin("it2")).motor is not None


class _Estimator:
    def start(self, measurement):
        return (0.0,) * 6

    def step(self, measurement, command):
        return (0.0,) * 6
