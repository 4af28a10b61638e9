"""The project's layering, read from its code: imports by ``ast``, and a traced run.

Run from the repository root to print the figures::

    python tests/layering.py            # imports: cycles, imports that run back up, function-level imports
    python tests/layering.py --walk     # and where a scenario goes from `twin run` to trajectory.csv

What is read: every module of ``twin`` and ``estimation``; an import is *function-level*
when it sits inside a function (it runs on a call, not when its module loads); imports under
``if TYPE_CHECKING:`` run never and are not counted. A *unit* is a subpackage of ``twin``
(``twin.sim``), a module at its top (``twin.cli``) or ``estimation``. :data:`LAYERS` puts
the units on floors, from the shared types at the bottom to the command line at the top; an
import from a unit to one on a higher floor *runs back up*. ``tests/test_layout.py`` holds
the rules to these figures.
"""
from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("twin", "estimation")

# the floors, bottom up: a unit imports only from its own floor or below (plant → sensors →
# estimator → controllers → actuators is the data flow; these are who-builds-on-whom)
LAYERS = {
    # shared types and helpers of no domain
    "twin": 0, "twin.errors": 0, "twin.validation": 0, "twin.timing": 0, "twin.rotations": 0,
    "twin.params": 0, "twin.inputs": 0, "twin.workers": 0, "twin.interrupts": 0, "twin.digests": 0,
    "twin.measures": 0,
    # the parts: fuzzy systems, motors, sensors
    "twin.fuzzy": 1, "twin.actuators": 1, "twin.sensors": 1,
    # the plants and the types every plant shares
    "twin.plant": 2,
    # the contracts between the parts, the robots (in absolute units), the estimators, the paper's experiments
    "twin.protocols": 3, "twin.robots": 3, "estimation": 4, "twin.experiments": 4,
    # controllers (their designs)
    "twin.controllers": 5,
    # the kinds: built-ins and users' plugins; the limits a run is held to
    "twin.limits": 6, "twin.registry": 6,
    # the controllers and estimators written as C, and that C run back in the loop (the export:DIR kinds)
    "twin.export": 6,
    # the engine: one run from its specification
    "twin.sim": 7,
    # what a run leaves: files, figures, video; plugins run in a process of their own
    "twin.outputs": 8, "twin.render": 8, "twin.containment": 8,
    # scenarios, robot logs, checks
    "twin.scenarios": 9, "twin.logs": 10, "twin.verify": 11,
    # calibration, sweeps and environments over them
    "twin.calibrate": 12, "twin.sweep": 12, "twin.envs": 12,
    # the workflows: what each command does
    "twin.workflows": 13,
    # the command line: the commands (options, what they print), the process they run in
    "twin.commands": 14, "twin.cli": 15, "twin.__main__": 16,
}


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name → file, for every module of :data:`PACKAGES` (its compiled kernels,
    C sources, too: ``twin.plant._fastpath`` is a module of its own, not its package)."""
    found = {}
    for pkg in PACKAGES:
        for path in sorted([*(root / pkg).rglob("*.py"), *(root / pkg).rglob("*.c")]):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _resolve(name: str, mods) -> str | None:
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def imports(mods: dict[str, Path]) -> list[tuple[str, str, bool, int]]:
    """(importer, imported, function_level, line) of every import of a module of the project
    (imports of other packages left out)."""
    found = []
    for mod, path in mods.items():
        if path.suffix != ".py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]

        def visit(node, in_function: bool):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                    for other in child.orelse:
                        visit_one(other, in_function)
                    continue
                visit_one(child, in_function)

        def visit_one(node, in_function: bool):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    target = _resolve(alias.name, mods)
                    if target:
                        found.append((mod, target, in_function, node.lineno))
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package
                    for _ in range(node.level - 1):
                        base = base.rpartition(".")[0]
                    source = base + ("." + node.module if node.module else "")
                else:
                    source = node.module
                for alias in node.names:
                    full = f"{source}.{alias.name}"
                    target = full if full in mods else _resolve(source, mods)
                    if target:
                        found.append((mod, target, in_function, node.lineno))
            else:
                visit(node, in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

        visit(tree, False)
    return [(a, b, f, line) for a, b, f, line in found if a != b]


def unit(mod: str) -> str:
    """The unit a module belongs to (see the module's docstring)."""
    parts = mod.split(".")
    return "estimation" if parts[0] == "estimation" else ".".join(parts[:2])


def cycles(edges) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan), each sorted."""
    graph = defaultdict(set)
    for a, b in edges:
        graph[a].add(b)
        graph.setdefault(b, set())
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(max(10_000, sys.getrecursionlimit()))
    for v in sorted(graph):
        if v not in index:
            strong(v)
    return sorted(out)


def figures(root: Path = ROOT) -> dict:
    """The layering's figures (see :func:`report`)."""
    mods = modules(root)
    found = imports(mods)
    mods = {m: p for m, p in mods.items() if p.suffix == ".py"}
    unknown = sorted({unit(m) for m in mods} - set(LAYERS))
    between = [(a, b, f, line) for a, b, f, line in found if unit(a) != unit(b)]
    return {
        "modules": len(mods),
        "units without a floor": unknown,
        "unit cycles": cycles({(unit(a), unit(b)) for a, b, _, _ in between}),
        "file cycles": cycles({(a, b) for a, b, _, _ in found}),
        "back up": sorted({(a, b, line) for a, b, _, line in between
                           if LAYERS.get(unit(a), 99) < LAYERS.get(unit(b), 99)}),
        "function-level": sorted({(a, b) for a, b, f, _ in found if f}),
    }


def report(root: Path = ROOT) -> str:
    f = figures(root)
    lines = [f"{f['modules']} modules of {', '.join(PACKAGES)}"]
    if f["units without a floor"]:
        lines.append(f"units without a floor in LAYERS: {', '.join(f['units without a floor'])}")
    lines.append(f"import cycles between units (function-level imports counted): {len(f['unit cycles'])}")
    lines += [f"  {' ↔ '.join(c)}" for c in f["unit cycles"]]
    lines.append(f"import cycles between files: {len(f['file cycles'])}")
    lines += [f"  {' ↔ '.join(c)}" for c in f["file cycles"]]
    ups = f["back up"]
    lines.append(f"imports that run back up: {len({(a, b) for a, b, _ in ups})}")
    lines += [f"  {a} → {b} (line {line})" for a, b, line in ups]
    lines.append(f"function-level imports of the project's own modules: {len(f['function-level'])} "
                 f"(distinct importer → imported)")
    return "\n".join(lines)


# ---- the walk: where a scenario goes, traced ---------------------------------------------
def walk(scenario: str = "paper-exp3", duration: float = 0.2) -> dict:
    """Run ``twin run SCENARIO --controller it2 --duration DURATION --no-video`` in this
    process with every Python call traced, and follow the run's description: each call that
    is handed the :class:`~twin.scenarios.scenario.Scenario`, a
    :class:`~twin.sim.spec.RunSpec` or a :class:`~twin.registry.BuildContext` (as an
    argument) is a step of the walk, in the module
    of the called function. Returns the modules in the order entered, how often each was
    entered (an entry: a step in another module than the step before), and the entries."""
    import tempfile

    from click.testing import CliRunner

    from twin.cli import main
    from twin.registry import BuildContext
    from twin.scenarios.scenario import Scenario
    from twin.sim.spec import RunSpec

    carried = (Scenario, RunSpec, BuildContext)
    steps = []

    def profile(frame, event, arg):
        if event != "call":
            return
        code = frame.f_code
        n = code.co_argcount + code.co_kwonlyargcount
        local = frame.f_locals
        for name in code.co_varnames[:n]:
            if isinstance(local.get(name), carried):
                mod = frame.f_globals.get("__name__", "?")
                if mod.startswith(PACKAGES):
                    steps.append(mod)
                return

    with tempfile.TemporaryDirectory() as tmp:
        sys.setprofile(profile)
        try:
            out = CliRunner().invoke(main, ["run", scenario, "--controller", "it2", "--duration", f"{duration:g}",
                                            "--no-video", "--out", str(Path(tmp) / "out")])
        finally:
            sys.setprofile(None)
        if out.exit_code != 0:
            raise RuntimeError(out.output)
    entries = [m for i, m in enumerate(steps) if i == 0 or steps[i - 1] != m]
    count = defaultdict(int)
    for m in entries:
        count[m] += 1
    return {"entries": entries, "count": dict(count), "modules": list(dict.fromkeys(entries))}


def walk_report(w: dict) -> str:
    n = len(w["entries"])
    returns = n - len(w["modules"])
    lines = [f"the walk of a scenario from `twin run` to trajectory.csv: {len(w['modules'])} modules, "
             f"{n} entries, {returns} returns to a module left before"]
    lines += [f"  {m}: entered {w['count'][m]}×" for m in w["modules"]]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    print(report())
    if "--walk" in sys.argv[1:]:
        print(walk_report(walk()))
