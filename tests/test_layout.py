"""The layering rules, read from the code (tests/layering.py: imports by ast, the units and
their floors). ``python tests/layering.py`` prints the figures these tests hold."""
from __future__ import annotations

import subprocess
import sys

import pytest

from layering import LAYERS, ROOT, cycles, figures, imports, modules, unit, walk


@pytest.fixture(scope="module")
def fig():
    return figures()


def test_every_unit_has_a_floor(fig):
    assert fig["units without a floor"] == [], "add the new unit to tests/layering.py's LAYERS"


def test_no_import_cycle_between_files(fig):
    """Function-level imports counted: a cycle hidden inside a function is still a cycle."""
    assert fig["file cycles"] == []


def test_nothing_below_the_engine_imports_the_pybullet_twin():
    """The types every plant shares are in twin.plant.base: the estimators, the contracts, the
    controllers and the registry need no PyBullet (only the plant package's own builder)."""
    engine = LAYERS["twin.sim"]
    found = [(a, line) for a, b, _, line in imports(modules())
             if b == "twin.plant.bullet" and LAYERS.get(unit(a), 99) < engine and unit(a) != "twin.plant"]
    assert found == []
    code = ("import sys, estimation.ekf, twin.protocols, twin.registry, twin.limits, twin.controllers.cascade\n"
            "print(sorted(m for m in ('pybullet', 'twin.plant.bullet') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


def test_the_plant_configuration_holds_no_limits():
    """Limits are the run's (RunSpec.limits), not the robot's."""
    from twin.limits import PluginLimits
    from twin.plant.base import TwinConfig
    from twin.sim.spec import Plugin, RunSpec

    assert "limits" not in TwinConfig.__dataclass_fields__
    assert RunSpec(Plugin("it2"), limits=PluginLimits(step_wall_s=1.0)).limits.step_wall_s == 1.0
    from twin.errors import TwinError

    with pytest.raises(TwinError, match="RunSpec.limits must be a twin.limits.PluginLimits or None"):
        RunSpec(Plugin("it2"), limits={"step_wall_s": 1.0})


def test_no_private_name_is_imported_from_another_package():
    """What one package uses of another is public (named without a leading underscore)."""
    import ast

    found = []
    for mod, path in modules().items():
        if path.suffix != ".py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith(("twin", "estimation")):
                found += [f"{mod} <- {node.module}:{a.name}" for a in node.names
                          if a.name.startswith("_") and not a.name.startswith("__") and unit(mod) != unit(node.module)]
    assert found == []


def test_at_most_two_imports_run_back_up_each_with_its_reason(fig):
    """An import from a unit to one on a higher floor is said where it is: a comment "runs back
    up: why" on the lines just above it."""
    ups = fig["back up"]
    assert len({(a, b) for a, b, _ in ups}) <= 2, ups
    mods = modules()
    for a, b, line in ups:
        above = mods[a].read_text(encoding="utf-8").splitlines()[max(0, line - 4):line - 1]
        assert any("# runs back up:" in text for text in above), f"{a} → {b} (line {line}) says not why"


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}) == [["a", "b", "c"]]
    assert cycles({("a", "b"), ("b", "c")}) == []


def test_no_import_cycle_between_units(fig):
    assert fig["unit cycles"] == []


def test_the_command_line_parses_and_prints_only():
    """twin.cli is the process a command runs in and the commands by name; each command
    (twin.commands) calls a workflow (twin.workflows) and prints: none reaches into the engine,
    the estimators or a scenario's runs."""
    mods = modules()
    assert len(mods["twin.cli"].read_text(encoding="utf-8").splitlines()) <= 300
    engine = ("twin.sim", "twin.scenarios.runs", "twin.scenarios.planning", "twin.scenarios.contained", "estimation",
              "twin.plant", "twin.containment")
    reached = sorted({(a, b) for a, b, _, _ in imports(mods) if a.startswith(("twin.cli", "twin.commands"))
                      and b.startswith(engine)})
    assert reached == []


def test_a_scenario_goes_from_twin_run_to_its_files_without_going_back_and_forth():
    """The walk of a scenario's description (tests/layering.py --walk): the registry builds the
    run's plugins in one visit, every other module is entered at most three times (the scenario:
    loaded, asked for its runs, recorded), and the walk is short."""
    w = walk()
    assert w["count"].get("twin.registry") == 1, w["entries"]
    assert max(w["count"].values()) <= 3, w["count"]
    assert len(w["entries"]) <= 15, w["entries"]


def test_at_most_60_function_level_imports_of_the_projects_own_modules(fig):
    assert len(fig["function-level"]) <= 60


WHY = ("optional", "heavy", "only")


def test_every_function_level_import_says_why(fig):
    """An import inside a function is for an optional or a heavy dependency: a comment on its line
    or on the three lines above says which ("optional: ...", "heavy: ...", "only when ...")."""
    mods = modules()
    silent = []
    for a, b, in_function, line in imports(mods):
        if in_function:
            text = mods[a].read_text(encoding="utf-8").splitlines()[max(0, line - 4):line]
            comments = " ".join(t.split("#", 1)[1] for t in text if "#" in t)
            if not any(w in comments for w in WHY):
                silent.append(f"{a}:{line} → {b}")
    assert silent == []


def test_no_class_over_500_lines():
    """A class that grew past 500 lines holds more than one concern (the EKF did: 1,400 lines)."""
    import ast

    big = []
    for mod, path in modules().items():
        if path.suffix == ".py":
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > 500:
                    big.append(f"{mod}.{node.name}: {node.end_lineno - node.lineno + 1} lines")
    assert big == []
