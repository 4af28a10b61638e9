"""Run a Monte Carlo sweep of a scenario and write its report.

Outputs in the sweep directory:

- ``sweep.json``, ``samples.jsonl``: the manifest (with the configuration hash every
  sample carries, the environment the samples ran in and the designs' digests) and the
  finished samples (see :mod:`twin.sweep.store`); a rerun with the same command resumes
  from them, and a rerun of another configuration is refused;
- ``sweep.csv``: one row per sample and controller (:mod:`twin.sweep.table`);
- ``summary.md``, ``summary.json``: success rates and metric quantiles with confidence
  intervals per level and controller, and the paired tests of each controller against
  the reference (by default the last one listed: IT2 against type-1 for the default
  pair) (:mod:`twin.sweep.statistics`);
- ``success.png``, ``distributions.png``, ``paired.png``: the figures;
- ``sensor-logs/sample-K/KIND/``, for the samples chosen (``log_sensors``): each controller's
  run of sample K as a sensor log (:mod:`twin.logs.format`), exactly the log
  ``twin run SCENARIO --sample K --seed ROOT --log-sensors`` writes (:func:`write_sample_logs`);
- ``manifest.json``, written last (:func:`twin.outputs.rundir.seal`): every file with its size and
  SHA-256. The report of an earlier run is deleted before any sample runs, so a directory
  without ``manifest.json`` holds a sweep that did not finish, never an out-of-date report.

The report depends only on the finished samples, never on the backend, the number of
workers, the finishing order or on interruptions. The directory is held
(:func:`twin.outputs.rundir.lock`) from the first sample to the manifest.

Limits: each controller's run of a sample is bounded by the scenario's ``[limits]``
(:mod:`twin.limits`); where it sets no ``run_wall_s`` the sweep sets
``RUN_WALL_BASE_S + RUN_WALL_PER_SIMULATED_S × duration`` (210 s for a 15 s scenario, which
runs in about 1 s), so that a plugin far too slow for the sweep fails its samples, as
``LimitExceeded: ...`` against that controller, instead of holding the sweep for hours.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from twin.containment import run_contained, Task
from twin.errors import TwinError
from twin.logs.format import write_log
from twin.outputs import report, rundir
from twin.outputs.fingerprint import digests, record
from twin.registry import check_kinds, is_user_code, label, plugin_dirs, uses_design
from twin.scenarios.contained import involves_plugins, limits_of, plan_summary, Recipe
from twin.scenarios.planning import plugin_roles, refuse_unused_params
from twin.scenarios.runs import DesignDigest, simulate_scenario
from twin.scenarios.scenario import Scenario
from twin.sweep.backends import BACKENDS, default_workers, run_local, run_ray
from twin.sweep.sampling import SAMPLES_VERSION, sample_scenario, value_columns
from twin.sweep.store import SweepStore
from twin.sweep.table import columns, rows_of, write_sweep_csv
from twin.sweep.worker import LIMIT, SweepJob

MAX_DRAWS = 100_000
# the sweep's per-run wall-time limit where the scenario sets none: s, + s per simulated s
RUN_WALL_BASE_S = 60.0
RUN_WALL_PER_SIMULATED_S = 10.0
COMMAND = "twin sweep"
REPORT_FILES = ("sweep.csv", "summary.md", "summary.json", "success.png", "distributions.png", "paired.png")
LOGS_DIR = "sensor-logs"  # the chosen samples' sensor logs: LOGS_DIR/sample-K/KIND/


@dataclass
class SweepResult:
    """A finished sweep: its rows, summary and paired tests, the files written, and what ran now."""

    out: Path
    manifest: dict
    rows: list
    summary: list
    paired: list
    files: list = field(default_factory=list)
    ran: int = 0           # samples run by this call
    resumed: int = 0       # samples found finished in the directory
    wall_s: float = 0.0    # time spent running samples in this call
    logs: dict = field(default_factory=dict)  # (sample, kind) → the sensor log's directory (log_sensors)
    log_notes: list = field(default_factory=list)  # what to say about those logs (a run that differs, say)
    environment_changes: list = field(default_factory=list)  # this call's environment against the first samples'
    failure: str | None = None  # why the sweep measured nothing usable (the command exits 2), or None


def replay_command(manifest: dict, sample: int) -> str:
    """The ``twin run`` command line that replays ``sample`` of the sweep."""
    import shlex

    sets = "".join(f" --set {shlex.quote(o)}" for o in manifest["overrides"])
    kinds = list(manifest.get("controllers", ()))
    own = list(manifest["scenario"].get("controller", {}).get("kinds", ()))
    ctl = f" --controller {shlex.quote(','.join(kinds))}" if kinds and kinds != own else ""
    return (f"twin run {shlex.quote(manifest['scenario_arg'])} --sample {sample} --seed {manifest['root_seed']}"
            f"{sets}{ctl}")


def sweep_controllers(scenario: Scenario, controllers=None, reference: str | None = None) -> tuple[tuple, str]:
    """(kinds, reference): ``controllers`` (None: the scenario's ``controller.kinds``) checked,
    and the reference the paired statistics compare each other controller with (default:
    the last one listed)."""
    kinds = check_kinds("controller", controllers if controllers is not None else scenario.controllers, "controllers")
    refuse_unused_params(scenario, kinds)
    reference = kinds[-1] if reference is None else reference
    if reference not in kinds:
        raise TwinError(f"--reference {reference!r} is not one of the sweep's controllers ({', '.join(kinds)})")
    return kinds, reference


def sweep_plan(scenario: Scenario, kinds) -> dict:
    """Every controller and the estimator built once, before anything runs or is written (a
    plugin that cannot be built is one line): :func:`twin.scenarios.contained.plan_summary`, in a
    worker process if a user's plugin is involved (:mod:`twin.containment`), else here."""
    if not involves_plugins(scenario, kinds):
        return plan_summary(scenario, kinds)
    return run_contained(Task(plan_summary, (Recipe.of(scenario), tuple(kinds)), limits=limits_of(scenario),
                              plugins=plugin_roles(scenario, kinds), what="plan"))


def preflight(scenario: Scenario, kinds, duration: float = 0.05, design=None) -> None:
    """Run the plugins among ``kinds`` (and a plugin estimator or plant) for ``duration`` s in a worker
    process, before anything is written: a plugin that breaks its contract at once is a
    one-line error rather than N failed samples."""
    plugins = [k for k in kinds if is_user_code(k)]
    if plugin_roles(scenario, ()) and not plugins:  # the estimator or the plant is a user's
        plugins = [kinds[0]]
    if not plugins:
        return
    d = scenario.data
    short = Scenario({**d, "duration": max(duration, 1.0 / d["rates"]["control"])}, scenario.source,
                     scenario.overrides)
    if design is not None:
        short.adopt_design(design)
    simulate_scenario(short, plugins, contained=True)


def run_sweep(scenario: Scenario, draws: int, out: Path, scenario_arg: str | None = None, workers: int | None = None,
              backend: str = "local", address: str | None = None, progress=None, controllers=None,
              reference: str | None = None, log_sensors=(), summary: dict | None = None) -> SweepResult:
    """Run ``draws`` samples at each level of ``scenario``'s ``[sweep]`` (every controller on each),
    resuming any finished samples found in ``out``, then write the report.

    ``scenario_arg``: how the user named the scenario (for the replay commands);
    ``workers``: processes or Ray CPUs (default: the cores here, or the Ray cluster's);
    ``progress(done, total)``: called as samples finish; ``controllers``: the kinds compared
    on identical samples (None: the scenario's ``controller.kinds``); ``reference``: the one
    the paired statistics compare each other with (default: the last); ``log_sensors``: sample
    numbers whose runs are also written as sensor logs (:func:`write_sample_logs`); ``summary``:
    :func:`sweep_plan`'s, if the caller made it already (planned here if None).
    """
    if not (isinstance(draws, int) and 1 <= draws <= MAX_DRAWS):
        raise TwinError(f"--samples must be an integer from 1 to {MAX_DRAWS} (samples per level), got {draws!r}")
    if backend not in BACKENDS:
        raise TwinError(f"--backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if workers is not None and not (isinstance(workers, int) and 1 <= workers <= 1024):
        raise TwinError(f"--workers must be an integer from 1 to 1024, got {workers!r}")
    kinds, reference = sweep_controllers(scenario, controllers, reference)
    log_sensors = check_log_samples(scenario, log_sensors, draws * len(scenario.sweep["levels"]))
    if summary is None:
        summary = sweep_plan(scenario, kinds)
    design = summary["design"]
    if design is None and any(uses_design(k) for k in kinds):
        design = scenario.design()
    preflight(scenario, kinds, design=design)

    levels = scenario.sweep["levels"]
    roles = plugin_roles(scenario, kinds)
    manifest = {"scenario": scenario.data, "source": scenario.source, "scenario_arg": scenario_arg or scenario.name,
                "overrides": [o for o in scenario.overrides if not o.startswith("seed=")],
                "root_seed": scenario.seed, "controllers": list(kinds),
                # the plugins' code, which no version number covers (part of the configuration hash)
                "plugins": {f"{p['role']} {p['kind']}": p["sha256"] for p in summary["plugins"]},
                "sampling": SAMPLES_VERSION, "draws": draws}
    manifest["environment"] = environment_of(summary, kinds, design)
    paths = summary["dirs"] or plugin_dirs(roles)
    with SweepStore(out, manifest) as store:
        job = SweepJob(sweep_data(scenario.data), scenario.source, scenario.overrides, scenario.seed, design, kinds,
                       paths, store.config)
        for name in (rundir.MANIFEST, *REPORT_FILES):  # the earlier report is no longer this directory's
            (store.out / name).unlink(missing_ok=True)
        if (store.out / LOGS_DIR).exists():  # nor are the logs an earlier call chose (this one may choose others)
            import shutil

            shutil.rmtree(store.out / LOGS_DIR)
        total = draws * len(levels)
        todo = [k for k in range(total) if k not in store.records]
        resumed = total - len(todo)
        done = [resumed]
        if progress is not None:
            progress(done[0], total)

        def on_result(record):
            # stored and counted as one: an interrupt lands before or after, so the count it reports is the store's
            with rundir.deferred_signals():
                store.append(record)
                done[0] += 1
                if progress is not None:
                    progress(done[0], total)
            rundir.test_point("sweep-sample")  # the kill tests' stop: a sample stored, others in flight

        t0 = time.perf_counter()
        if todo:
            if backend == "local":
                run_local(job, todo, workers or default_workers(), on_result)
            else:
                run_ray(job, todo, workers, on_result, address=address)
        wall = time.perf_counter() - t0
        records = [store.records[k] for k in range(total)]
        result = write_report(out, store.manifest, records, scenario, reference)
        rundir.test_point("sweep-report")  # the kill tests' stop: the report written, not yet sealed
        if log_sensors:
            result.logs, result.log_notes = write_sample_logs(job, log_sensors, records, store.out)
            result.files.append(store.out / LOGS_DIR)
        result.failure = failure_of(result.rows)
        result.ran, result.resumed, result.wall_s = len(todo), resumed, wall
        result.environment_changes = store.environment_changes
        rundir.seal(store.out, COMMAND, exit_status=2 if result.failure else 0)  # last: the report is complete
        result.files.append(store.out / rundir.MANIFEST)
    return result


def check_log_samples(scenario: Scenario, samples, total: int) -> tuple[int, ...]:
    """``samples`` (the sample numbers ``--log-sensors`` chose) as a sorted tuple without repeats,
    each checked to be one of the sweep's ``total`` samples, and the scenario checked to simulate
    sensors; one line otherwise, before anything runs or is written."""
    samples = tuple(samples or ())
    if not samples:
        return ()
    bad = next((k for k in samples if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < total), None)
    if bad is not None:
        raise TwinError(f"--log-sensors: {bad!r} is not a sample of this sweep; allowed: sample numbers from 0 to "
                        f"{total - 1} (the 'sample' column of sweep.csv: draws × levels)")
    if scenario.sensor_config() is None:
        raise TwinError("--log-sensors needs simulated sensors: sensors.sensing is \"ideal\" here (nothing is "
                        "measured); allowed: sensors.sensing = \"estimated\"")
    return tuple(sorted(set(samples)))


def log_dir_name(kind: str) -> str:
    """A controller kind as a directory name (a plugin's "pkg.mod:Cls" has a colon), as twin run names it."""
    import re

    return re.sub(r"[^A-Za-z0-9_.-]+", "_", kind)


def write_sample_logs(job: SweepJob, samples, records, out: Path) -> tuple[dict, list]:
    """Write each controller's run of each of ``samples`` as a sensor log in
    ``out/sensor-logs/sample-K/KIND/``; ({(K, kind): directory}, notes).

    The samples are run again here, in this process, at every control step: a sample is a
    deterministic function of the scenario, the root seed and K (:mod:`twin.sweep.sampling`), so
    the run is the one the sweep stored, whether it finished in this call, in a worker, or in an
    earlier call this one resumed (whose workers kept no readings). Each run's metrics are
    compared with the stored ones: a difference (a sweep resumed in another environment, say) is
    a note, the log being of the run made here. A controller whose run of the sample ended in an
    error has no log. log.toml names the sweep's scenario and --set items (a sample differs from
    it only in plant, tilt, pushes and seed, none of which the estimators' sensors and motors
    depend on) and says which sample it is in ``source``.
    """
    import json

    sc = job.scenario()  # exactly what the workers ran: the sweep's limits and design
    logs, notes = {}, []
    for k in samples:
        sample = sample_scenario(sc, job.root_seed, k)
        stored = records[k]["runs"]
        for kind in job.controllers:
            if kind not in stored:
                notes.append(f"sample {k}, {kind}: no sensor log (its run ended in an error: "
                             f"{(records[k].get('errors') or {}).get(kind, records[k]['error'])})")
                continue
            done = simulate_scenario(sample.scenario, (kind,), contained=True)  # as the worker runs it (twin.sweep.worker)
            run, metrics = done.runs[0], done.metrics[kind]
            if json.dumps(metrics, sort_keys=True) != json.dumps(
                    {m: v for m, v in stored[kind].items() if m != "success"}, sort_keys=True):
                notes.append(f"sample {k}, {kind}: the run logged differs from the one sweep.csv holds (resumed "
                             f"in another environment?); the log is of the run made now")
            d = out / LOGS_DIR / f"sample-{k}" / log_dir_name(kind)
            logs[(k, kind)] = write_log(run, d, sample.scenario, source=COMMAND)
            rundir.test_point("sweep-logs")  # the kill tests' stop: a log written, the folder not yet sealed
    return logs, notes


def sweep_data(data: dict) -> dict:
    """The scenario data the samples run with: the scenario's ``[limits]`` with the sweep's
    default per-run wall time where it sets none (see the module docstring)."""
    limits = data.get("limits")
    if not isinstance(limits, dict) or limits.get("run_wall_s") is not None:
        return data
    return {**data, "limits": {**limits, "run_wall_s": RUN_WALL_BASE_S + RUN_WALL_PER_SIMULATED_S * data["duration"]}}


def failure_of(rows) -> str | None:
    """Why a finished sweep measured nothing it can stand by (the command then exits 2, its
    outputs kept): every run ended in an error, or a plugin broke its contract past the
    preflight. A run stopped by a limit is a result, not a failure."""
    if rows and all(r["status"] == "error" for r in rows):
        first = rows[0]
        return (f"every run of the sweep ended in an error, so nothing was measured (first: sample {first['sample']}, "
                f"{first['controller']}: {first['error']})")
    broken = [r for r in rows if str(r.get("error") or "").startswith("PluginError")]
    if broken:
        first = broken[0]
        return (f"{len(broken)} run{'s' * (len(broken) > 1)} ended with a plugin error (first: sample "
                f"{first['sample']}, {first['error'][len('PluginError: '):]})")
    return None


def environment_of(summary: dict, kinds, design) -> dict:
    """sweep.json's ``environment``: this process's, with the digest of each design the
    controllers use (the LMI balance design ``design`` when one of them asks for it, and each
    controller's own ``design_digest()``, from :func:`sweep_plan`'s ``summary``: every sample's
    controllers are designed on the same nominal model)."""
    asked = summary["design"] is not None or design is not None
    return record(digests(design if asked else None, [(k, DesignDigest(summary["digests"].get(k))) for k in kinds]))


def write_report(out: Path, manifest: dict, records, scenario: Scenario, reference: str | None = None) -> SweepResult:
    """``sweep.csv``, the summary and the figures of the finished ``records``; the paired
    statistics compare each controller with ``reference`` (default: the last; it is not part
    of the manifest, so a finished sweep can be reported against another reference)."""
    from twin.sweep import figures, statistics  # heavy: matplotlib and scipy, for the report alone

    out = Path(out)
    vcols = value_columns(scenario)
    kinds = list(manifest["controllers"])
    reference = kinds[-1] if reference is None else reference
    labels = {k: label(k) for k in kinds}
    rows = rows_of(records, vcols, controllers=kinds)
    files = [write_sweep_csv(rows, columns(vcols), out / "sweep.csv")]
    summary = statistics.summarize(rows, controllers=kinds)
    paired = statistics.paired_tests(rows, controllers=kinds, reference=reference)
    sw = scenario.sweep
    n = len(records)
    notes = [f"Scenario {scenario.name} ({manifest['source']}): {scenario.description}",
             f"{n} samples ({manifest['draws']} draw{'s' * (manifest['draws'] != 1)} × {len(sw['levels'])} levels λ = "
             f"{', '.join(f'{v:g}' for v in sw['levels'])}), root seed {manifest['root_seed']}; "
             f"{', '.join(labels[k] for k in kinds)} run on every sample with the same plant, noise and "
             f"disturbances; paired differences are each controller minus {labels[reference]}.",
             f"Parameters perturbed ({sw['distribution']}, on top of plant.scale): {', '.join(sw['parameters'])}.",
             f"Success: no fall, |θ| below 0.01 rad for good over at least the last {sw['success_settled_for']:g} s, "
             f"final position error within "
             f"{sw['success_position_tol']:g} m and heading error within {sw['success_heading_tol']:g} rad "
             "(where the scenario has those targets).",
             "The levels share their draws (common random numbers: the same noise seed and unit draws at every "
             "level), so the 'all' rows pool correlated samples; read the per-level rows for inference.",
             f"Replay a sample: {replay_command(manifest, 0).replace(' --sample 0 ', ' --sample K ')}"]
    errors = [r for r in records if r["error"]]
    if errors:
        notes.append(f"{len(errors)} samples ended in an error (first: sample {errors[0]['sample']}: "
                     f"{errors[0]['error']})")
    limited = [(r["sample"], k, m) for r in records for k, m in (r.get("errors") or {}).items()
               if m.startswith(f"{LIMIT}: ")]
    if limited:
        k, kind, m = limited[0]
        notes.append(f"{len(limited)} run{'s' * (len(limited) > 1)} stopped by a limit of [limits], counted as "
                     f"failures of their controller (first: sample {k}, {labels.get(kind, kind)}: "
                     f"{m[len(LIMIT) + 2:]})")
    text = statistics.summary_markdown(summary, paired, f"Sweep of {scenario.name}", notes, labels=labels)
    (out / "summary.md").write_text(text, encoding="utf-8")
    files.append(out / "summary.md")
    files.append(report.write_json({"notes": notes, **statistics.summary_json(summary, paired, labels=labels)},
                                   out / "summary.json"))
    files.append(figures.plot_success(summary, out / "success.png", controllers=kinds, labels=labels))
    files.append(figures.plot_distributions(rows, out / "distributions.png", controllers=kinds, labels=labels))
    files.append(figures.plot_paired(rows, out / "paired.png", controllers=kinds, reference=reference,
                                     labels=labels))
    return SweepResult(out, manifest, rows, summary, paired, files)
