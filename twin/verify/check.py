"""``twin check``: run scenarios with their ``[expect]`` tables and say pass or fail.

Every (scenario, controller, seed) is one run of :func:`twin.scenarios.runs.simulate_scenario`,
on local worker processes when there are several (spawned, like the sweeps'; the LMI
design is solved once per scenario here and shipped). Seeds are the scenario's ``seed``,
``seed + 1``, … so that any run replays with ``twin run SCENARIO --seed S``. The verdicts
come from :mod:`twin.scenarios.expectations`. Nothing here depends on the number of workers or the
order in which runs finish.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from twin.containment import run_contained, Task, Workers
from twin.errors import TwinError
from twin.logs.expect import replay_metrics
from twin.logs.replay import replay_logs_contained
from twin.outputs import golden as g
from twin.outputs.fingerprint import differences
from twin.outputs.golden import Trajectory
from twin.outputs.rundir import MANIFEST, RECORD_COMMAND, FileBatch, kept, test_point
from twin.outputs.tolerances import Tolerances, known_signals, parse_table
from twin.registry import check_kinds, is_import_path, is_user_code, label, plugin_dirs, use_plugin_dirs, uses_design
from twin.scenarios import load_scenario
from twin.scenarios.contained import involves_plugins, limits_of, names_of, plan_summary, plugin_roles, Recipe
from twin.scenarios.expectations import GOLDEN, evaluate, failed, parse_expect
from twin.scenarios.planning import plan as runs_of
from twin.scenarios.runs import simulate_scenario
from twin.scenarios.scenario import builtin_names, Scenario


@dataclass(frozen=True)
class CheckTask:
    """One run: the scenario's validated data, source and overrides, its design (None: not
    needed), the controller kind, the seed, and the plugins' directories."""

    data: dict
    source: str
    overrides: tuple
    design: object
    kind: str
    seed: int
    plugin_paths: tuple = ()
    trajectory: bool = False  # also return the run's signals (for golden trajectories)


def run_task(task: CheckTask) -> tuple[dict | None, str, object, dict | None]:
    """(metrics, "", trajectory or None, environment) of one run, or (None, error message, None,
    None) if it raised; the environment is the one it ran in, with its designs' digests
    (:func:`twin.outputs.fingerprint.record`)."""
    use_plugin_dirs(task.plugin_paths)
    sc = Scenario({**task.data, "seed": task.seed}, task.source, task.overrides)
    if task.design is not None:
        sc.adopt_design(task.design)
    try:
        result = simulate_scenario(sc, (task.kind,))
    except Exception as exc:  # noqa: BLE001 -- a run that errors fails its check, with its message
        return None, f"{type(exc).__name__}: {' '.join(str(exc).split())}", None, None
    traj = None
    if task.trajectory:
        traj = Trajectory.of(result.runs[0])
    return result.metrics[task.kind], "", traj, result.environment()


@dataclass
class CaseResult:
    """One scenario and controller over its seeds: the runs' metrics (seed → dict), errors,
    the verdicts and which of them fail."""

    scenario: str
    source: str
    controller: str
    seeds: tuple
    metrics: dict
    errors: dict
    verdicts: list
    failures: list
    golden: dict = field(default_factory=dict)  # seed → Departure, or a message (no reference), or None (agrees)
    has_seed_bounds: bool = False  # the scenario has [expect.seeds] bounds
    environment: dict | None = None  # what the first run ran on, with its designs' digests
    kind_of: str = "scenario"  # or "log": an estimator replayed on a sensor log (twin.logs.expect)

    @property
    def departures(self) -> dict:
        return {seed: d for seed, d in self.golden.items() if d is not None}

    @property
    def passed(self) -> bool:
        return not self.failures and not self.errors and not self.departures


@dataclass
class CheckResult:
    cases: list
    wall_s: float = 0.0
    runs: int = 0
    skipped: list = field(default_factory=list)
    recorded: int = 0  # golden trajectories written

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.cases)


def collect(targets, overrides=()) -> tuple[list, list[str]]:
    """The scenarios named by ``targets`` (built-in names, .toml files, directories of .toml
    files), loaded with ``overrides``; files in a directory without an ``[expect]`` table are
    skipped (and listed), a scenario named on its own must have one."""
    scenarios, skipped = [], []
    if not targets:
        raise TwinError("twin check needs at least one SCENARIO, FILE or DIR (built-ins: "
                        f"{', '.join(builtin_names())})")
    for target in targets:
        path = Path(target)
        if path.is_dir():
            files = sorted(path.glob("*.toml"))
            if not files:
                raise TwinError(f"{path}: no .toml scenario files in this directory")
            for f in files:
                sc = load_scenario(str(f), overrides)
                (scenarios if sc.expect else skipped).append(sc if sc.expect else str(f))
            continue
        sc = load_scenario(str(target), overrides)
        if not sc.expect:
            raise TwinError(f"{sc.source}: no [expect] table, so nothing to check; add bounds such as "
                            "fell = false (see docs/howto/regression.md)")
        scenarios.append(sc)
    seen: dict[str, str] = {}
    for sc in scenarios:  # reports, JUnit suites and golden files are keyed by the name
        if sc.name in seen:
            raise TwinError(f"two scenarios are named {sc.name!r} ({seen[sc.name]} and {sc.source}); give each its own "
                            "'name' (or check them separately)")
        seen[sc.name] = sc.source
    return scenarios, skipped


def run_checks(scenarios, controllers=None, seeds: int = 1, workers: int = 1, progress=None,
               record: Path | None = None, golden: Path | None = None, tolerances=None) -> CheckResult:
    """Run every scenario with each controller (None: each scenario's ``controller.kinds``) on
    ``seeds`` seeds, on ``workers`` processes, and judge the runs by the ``[expect]`` tables;
    ``record``: store each run as a golden trajectory under this directory; ``golden``:
    compare each run with the one stored there (:mod:`twin.outputs.golden`), with ``tolerances``
    (a :class:`twin.outputs.tolerances.Tolerances`, the command line's) over each scenario's
    ``[expect.golden]``."""
    if not (isinstance(seeds, int) and 1 <= seeds <= 10_000):
        raise TwinError(f"--seeds must be an integer from 1 to 10000, got {seeds!r}")
    if not (isinstance(workers, int) and 1 <= workers <= 1024):
        raise TwinError(f"--workers must be an integer from 1 to 1024, got {workers!r}")
    plan, tolerance_of, logged = [], {}, []
    given = tolerances if tolerances is not None else Tolerances()
    for sc in scenarios:
        kinds = check_kinds("controller", controllers if controllers is not None else sc.controllers, "controllers")
        design = sc.design() if any(uses_design(k) for k in kinds) else None
        extra = []
        # every plugin built once here (a user's in a worker process: twin.containment): one that cannot
        # be built is a user error, said before anything runs
        if involves_plugins(sc, kinds):
            summary = run_contained(Task(plan_summary, (Recipe.of(sc, design), kinds), limits=limits_of(sc),
                                         plugins=plugin_roles(sc, kinds), what="plan"))
            paths, reads = summary["dirs"], summary["reads_truth"]
            signals = [summary["signals"][k] for k in kinds]
        else:
            paths, reads = plugin_dirs(plugin_roles(sc, kinds)), False
            signals = [getattr(spec.controller.kind, "signals", ()) for spec in runs_of(sc, kinds)]
        _refuse_truth_reader(sc, reads)
        for kind, own in zip(kinds, signals):
            extra += own
            plan.append((sc, kind, tuple(CheckTask(sc.data, sc.source, sc.overrides, design, kind, sc.seed + i,
                                                   paths, record is not None or golden is not None)
                                         for i in range(seeds))))
        logged += extra
        if golden is not None:  # tolerances naming a signal no run logs are a typo: said before anything runs
            tolerance_of[sc.name] = given.over(_scenario_tolerances(sc, extra))
    if golden is not None:
        given.check_signals(known_signals(logged), "--tolerance")
    tasks = [t for _, _, ts in plan for t in ts]
    batch = FileBatch(record, RECORD_COMMAND) if record is not None else None  # refused now if in use
    t0 = time.perf_counter()
    outcomes = iter(_run(tasks, workers, _with_test_point(progress, len(tasks))))
    wall = time.perf_counter() - t0
    cases, to_record = [], []
    for sc, kind, ts in plan:
        done = [(t.seed, next(outcomes)) for t in ts]
        metrics = {seed: m for seed, (m, _, _, _) in done if m is not None}
        errors = {seed: e for seed, (_, e, _, _) in done if e}
        bounds = parse_expect(sc.expect)
        verdicts = evaluate(bounds, kind, metrics) if metrics else []
        case = CaseResult(sc.name, sc.source, kind, tuple(t.seed for t in ts), metrics, errors, verdicts,
                          failed(verdicts, bounds), has_seed_bounds=bool(bounds.get("seeds")),
                          environment=next((env for _, (_, _, _, env) in done if env is not None), None))
        for seed, (m, _, traj, env) in done:
            if traj is not None:
                _golden(case, sc, kind, seed, traj, env, golden, tolerance_of.get(sc.name))
                if record is not None:
                    to_record.append((sc, kind, seed, traj, m, env))
        cases.append(case)
    result = CheckResult(cases, wall, len(tasks))
    if batch is not None:
        result.recorded = _record(batch, to_record, 0 if result.passed else 1)
    return result


def _refuse_truth_reader(sc, reads_truth: bool) -> None:
    """A check of an estimator plugin that reads the ground truth (``reads_truth``: it says so)
    passes on information no robot has: refused unless the scenario says it is a reference
    (``reference = true``). The built-in ``ideal`` estimator and ``sensing = "ideal"`` say so
    by their names."""
    if not reads_truth or sc.data.get("reference") or sc.data["sensors"]["sensing"] == "ideal" \
            or not is_import_path(sc.estimator):
        return
    raise TwinError(f"{sc.source}: estimator {sc.estimator!r} reads the ground truth (reads_truth = True), so its "
                    f"checks would pass on information no robot has; allowed: an estimator that does not, or "
                    f"reference = true in the scenario to check it as a reference")


def _with_test_point(progress, total: int):
    """``progress`` with the kill tests' point "check-run" after the first of several runs."""
    def update(done, n):
        if 0 < done < total:
            test_point("check-run")
        if progress is not None:
            progress(done, n)
    return update


def _record(batch, items, exit_status: int) -> int:
    """Store every run of ``items`` as a golden trajectory, as one unit (:class:`twin.outputs.rundir.FileBatch`):
    an interrupt or an error while they are written leaves the directory as it was; the
    number stored."""
    try:
        with batch:
            for i, (sc, kind, seed, traj, metrics, env) in enumerate(items):
                relative = g.path_for(".", sc.name, kind, seed).as_posix()
                g.record(batch.temp(relative), traj, {"scenario": sc.name, "source": sc.source, "controller": kind,
                                                      "seed": seed, "metrics": metrics, "environment": env,
                                                      "robot": robot_record(sc)})
                if i == 0:
                    test_point("record")
            return batch.commit(exit_status)
    except BaseException as exc:
        if batch.committed:  # an interrupt held during the commit, delivered after it
            kept(exc, f"the record is complete: {batch.root} holds all {len(items)} references ({MANIFEST})")
        elif isinstance(exc, OSError):  # a full disk, say: one line
            raise kept(TwinError(f"cannot record into {batch.root}: {exc.strerror or exc}"),
                       f"nothing recorded: {batch.root} is as it was") from exc
        else:
            kept(exc, f"nothing recorded: {batch.root} is as it was")
        raise


def _scenario_tolerances(sc, extra):
    """The scenario's ``[expect.golden]`` tolerances, their signals checked against those its runs log."""
    table = sc.expect.get(GOLDEN)
    if table is None:
        return Tolerances()
    tol = parse_table(table, f"{sc.source}: expect.{GOLDEN}")  # valid: the scenario was validated on loading
    tol.check_signals(known_signals(extra), f"{sc.source}: expect.{GOLDEN}.signals")
    return tol


def robot_record(sc) -> dict:
    """The scenario's robot as a golden file records it: its name and :attr:`twin.robots.Robot.digest`
    (a reference made for another robot, or the same robot's changed figures, then says so)."""
    return {"name": sc.robot.name, "digest": sc.robot.digest}


def _golden(case: CaseResult, sc, kind: str, seed: int, traj, env, golden, tolerances) -> None:
    """Compare the run with its reference under ``golden`` (with ``tolerances``), if given."""
    if golden is None:
        return
    try:
        ref, meta = g.load(g.path_for(golden, sc.name, kind, seed))
    except TwinError as exc:
        case.golden[seed] = str(exc)
    else:
        here = g.build()
        dep = g.compare(traj, ref, meta.get("build") == here and here != "mixed", tolerances)
        if dep is not None:  # say whether the environment, a design or the robot changed, or none did
            robot, theirs = robot_record(sc), meta.get("robot")
            moved = [] if theirs is None or theirs == robot else [
                f"robot {robot['name']} {robot['digest'][:12]}, the reference's {theirs.get('name')} "
                f"{str(theirs.get('digest'))[:12]}"]
            dep = replace(dep, environment=tuple(differences(env, meta.get("environment")) + moved))
        case.golden[seed] = dep


def _run(tasks, workers: int, progress) -> list:
    """The outcomes of ``tasks``, in their order. With K workers this process runs tasks too,
    beside K − 1 spawned ones: it needs no start-up, which on a short check is much of the
    work (a spawned worker takes about a second to import the twin)."""
    out: list = [None] * len(tasks)
    finished = [0]

    def done(i, r):
        out[i] = r
        finished[0] += 1
        if progress is not None:
            progress(finished[0], len(tasks))

    if progress is not None:
        progress(0, len(tasks))
    plugin = [_involves_plugins(t) for t in tasks]
    if not any(plugin) and (workers == 1 or len(tasks) == 1):
        for i, t in enumerate(tasks):
            done(i, run_task(t))
        return out

    def contained(i):
        t = tasks[i]
        sc = Scenario(t.data, t.source, t.overrides)
        return Task(run_task, (t,), limits=limits_of(sc), names=names_of(sc, t.kind), key=i)

    def settle(outcome):
        if outcome.error is None:
            done(outcome.task.key, outcome.value)
        else:  # a limit overrun from outside, or a worker that died: that run's error
            e = outcome.error
            done(outcome.task.key, (None, f"{type(e).__name__}: {' '.join(str(e).split())}", None, None))

    # this process runs tasks of built-in kinds too (beside K − 1 workers): it needs no start-up,
    # which on a short check is much of the work (a worker takes about a second to import the twin);
    # a user's plugin runs only in a worker (twin.containment), where what it does can be stopped
    here = workers > 1 and not all(plugin)
    width = workers - 1 if here else workers
    queue = list(range(len(tasks)))  # this process takes from the front, the workers from the back
    deaths: dict = {}
    with Workers(width) as pool:
        while queue or pool.busy:
            while queue and len(pool.busy) < width:
                pool.start(contained(queue.pop()))
            mine = next((i for i in queue if not plugin[i]), None) if here else None
            for outcome in pool.wait(0.0 if mine is not None else None):
                if outcome.died and deaths.get(outcome.task.key, 0) < 1:  # tried once more: a crash may be another's
                    deaths[outcome.task.key] = 1
                    queue.append(outcome.task.key)
                    continue
                settle(outcome)
            if mine is not None:
                queue.remove(mine)
                done(mine, run_task(tasks[mine]))
    return out


def _involves_plugins(task: CheckTask) -> bool:
    """True if ``task``'s run runs a user's code (its controller or estimator is an import path or
    an export directory's C: :func:`twin.registry.is_user_code`)."""
    s = task.data["sensors"]
    return is_user_code(task.kind) or (s["sensing"] != "ideal" and is_user_code(s["estimator"]))


def format_table(result: CheckResult) -> str:
    """Each bound with its measured value (the worst over the seeds) and ok / FAIL, a line each."""
    rows = []
    for case in result.cases:
        n = len(case.seeds)
        for bound in dict.fromkeys(v.bound for v in case.verdicts):
            vs = [v for v in case.verdicts if v.bound == bound]
            bad = [v for v in vs if v in case.failures]
            over_seeds = bound.stat is not None or bound.metric == "pass_rate"
            shown = bad[0] if bad else vs[-1] if over_seeds else _worst(vs)
            n_bad = len([v for v in vs if not v.holds])
            where = "" if n == 1 or over_seeds else (f" ({n_bad}/{n} seeds fail)" if n_bad else f" (worst of {n} seeds)")
            rows.append((case.scenario, label(case.controller), str(bound), shown.measured_with_unit(False) + where,
                         "FAIL" if bad else "ok"))
        for seed, error in case.errors.items():
            rows.append((case.scenario, label(case.controller), f"run with seed {seed}", error[:60], "ERROR"))
        for seed, dep in case.golden.items():
            text = "matches" if dep is None else str(dep)
            rows.append((case.scenario, label(case.controller), f"golden trajectory, seed {seed}",
                         text if len(text) <= 70 else text[:67] + "...", "ok" if dep is None else "FAIL"))
    logs = any(c.kind_of == "log" for c in result.cases)
    head = ("scenario" + " or log" * logs, "controller" + " or estimator" * logs, "bound", "measured", "result")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(5)]
    return "\n".join("  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in [head] + rows)


def failure_lines(result: CheckResult) -> list[str]:
    """One line per failed bound or run: scenario, controller, seed, metric, measured value and bound."""
    out = []
    for case in result.cases:
        if case.kind_of == "log":  # a replay: the log, the estimator and the metric
            for v in case.failures:
                out.append(f"FAIL {case.scenario} estimator {case.controller}: {v.bound.key} = "
                           f"{v.measured_with_unit()}, bound {v.bound} ({case.source})")
            for error in case.errors.values():
                out.append(f"FAIL {case.scenario} estimator {case.controller}: {error}")
            continue
        for v in case.failures:
            seed = f" seed {v.seed}" if v.seed is not None else f" over {len(case.seeds)} seeds"
            out.append(f"FAIL {case.scenario} {case.controller}{seed}: {v.bound.key} = {v.measured_with_unit()}, "
                       f"bound {v.bound}" + (f": {v.detail}" if v.detail else ""))
        for seed, error in case.errors.items():
            out.append(f"FAIL {case.scenario} {case.controller} seed {seed}: {error}")
        for seed, dep in case.departures.items():
            out.append(f"FAIL {case.scenario} {case.controller} seed {seed}: {golden_text(dep)}")
    return out


def golden_text(departure) -> str:
    """"golden trajectory departs at ...", or "golden trajectory: <why>" (another length, no reference, ...)."""
    text = str(departure)
    return f"golden trajectory {text}" if text.startswith("departs at") else f"golden trajectory: {text}"


def _worst(verdicts):
    """The verdict whose measured value is nearest to breaking its bound (or past it)."""
    b = verdicts[0].bound
    if isinstance(b.value, bool):
        return verdicts[-1]
    missing = [v for v in verdicts if v.measured is None]
    if missing:
        return missing[0]
    return (max if b.op in ("<=", "<") else min)(verdicts, key=lambda v: float(v.measured))


def _flatten(doc, prefix: str):
    """(dotted name, text) of every leaf of a JSON-like tree: JUnit properties are flat strings."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _flatten(v, f"{prefix}.{k}")
    elif isinstance(doc, list):
        yield prefix, ",".join(map(str, doc))
    else:
        yield prefix, "" if doc is None else str(doc).lower() if isinstance(doc, bool) else str(doc)


def write_junit(result: CheckResult, path: Path) -> Path:
    """JUnit XML: a test suite per scenario, a test case per controller and seed (its per-run
    bounds) and one per controller over the seeds (the ``[expect.seeds]`` bounds), with the
    failing bounds, measured values and bounds in each failure; each suite's properties are
    the environment its runs ran in and their designs' digests (``environment.blas.kernel``,
    ``environment.designs.balance``, ...)."""
    import xml.etree.ElementTree as ET

    root = ET.Element("testsuites", name="twin check", tests="0", failures="0", time=f"{result.wall_s:.3f}")
    suites: dict[str, ET.Element] = {}
    total = fails = 0
    for case in result.cases:
        suite = suites.get(case.source)
        if suite is None:
            suite = suites[case.source] = ET.SubElement(root, "testsuite", name=case.scenario, tests="0", failures="0")
        groups = [(seed, f"{case.controller} seed {seed}" if case.kind_of != "log" else f"estimator {case.controller}")
                  for seed in case.seeds]
        if case.has_seed_bounds:
            groups.append((None, f"{case.controller} over {len(case.seeds)} seeds"))
        rates = [v for v in case.verdicts if v.seed is None and v.bound.metric == "pass_rate"]
        rate_failed = any(not v.holds for v in rates)
        rate_text = ", ".join(f"{v.bound}, measured {v.measured_text()}" for v in rates)
        for seed, name in groups:
            tc = ET.SubElement(suite, "testcase", classname=case.scenario, name=name)
            total += 1
            suite.set("tests", str(int(suite.get("tests")) + 1))
            bad = [v for v in case.failures if v.seed == seed]
            # a seed's broken bounds under a pass_rate are the rate's to judge: they fail this
            # seed's case where the rate failed, and are said in its output where it held
            absorbed = [v for v in case.verdicts if seed is not None and v.seed == seed and not v.holds
                        and v not in bad]
            if absorbed and rate_failed:
                bad, absorbed = bad + absorbed, []
            if absorbed:
                ET.SubElement(tc, "system-out").text = (
                    "; ".join(f"{v.bound}: measured {v.measured_with_unit()}" for v in absorbed)
                    + f" (allowed by {rate_text})")
            error = case.errors.get(seed) if seed is not None else None
            if seed is not None and case.departures.get(seed) is not None:
                error = "; ".join(filter(None, [error, *(f"{v.bound}: measured {v.measured_text()}" for v in bad),
                                                golden_text(case.departures[seed])]))
            if bad or error:
                fails += 1
                suite.set("failures", str(int(suite.get("failures")) + 1))
                text = error or "; ".join(f"{v.bound}: measured {v.measured_with_unit()}"
                                          + (f" ({v.detail})" if v.detail else "") for v in bad)
                ET.SubElement(tc, "failure", message=text[:500]).text = text
    for source, suite in suites.items():  # <properties> comes first in a suite (the JUnit schema)
        envs = [c.environment for c in result.cases if c.source == source and c.environment]
        if envs:
            props = ET.Element("properties")
            designs = {}
            for env in envs:  # the designs of every controller of the scenario
                designs.update(env.get("designs") or {})
            for name, value in _flatten({**envs[0], "designs": designs}, "environment"):
                ET.SubElement(props, "property", name=name, value=value)
            suite.insert(0, props)
    root.set("tests", str(total))
    root.set("failures", str(fails))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)
    return path


def run_log_checks(checks) -> list:
    """A :class:`CaseResult` per log and estimator of ``checks`` (:class:`twin.logs.expect.LogCheck`;
    seed 0: a replay has none)."""
    cases = []
    for chk in checks:
        try:
            doc, _ = replay_logs_contained([chk.log], chk.kinds)  # a plugin's in a worker: it cannot end the check
            entries = doc["logs"][str(chk.log)]["estimators"]
            errors = {}
        except TwinError as exc:
            entries, errors = {}, {0: f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
        for kind in chk.kinds:
            metrics = {0: replay_metrics(entries[kind])} if kind in entries else {}
            verdicts = evaluate(chk.bounds, kind, metrics) if metrics else []
            cases.append(CaseResult(f"log:{chk.name}", chk.source, kind, (0,), metrics, dict(errors), verdicts,
                                    failed(verdicts, chk.bounds), kind_of="log"))
    return cases


__all__ = ["CaseResult", "CheckResult", "CheckTask", "collect", "failure_lines", "format_table", "run_checks",
           "run_log_checks", "run_task", "write_junit"]
