"""Run a scenario: design the gains, run each controller on the twin, write the outputs.

Outputs in the run directory:

- ``trajectory.csv``: one row per control step and controller (``controller`` column
  first), every logged signal with its unit in the header: time, ground truth, the
  estimates the controllers acted on, commands, torques delivered, pushes;
- ``metrics.json``: the scenario (complete, defaults filled in), the seed, and one
  object per controller run (:func:`twin.metrics.run_metrics`);
- ``figure.png``: θ, torque, dψ/dt, distance and α over time (the paper's Figs. 6–8),
  the controllers overlaid;
- ``video.mp4``: offscreen rendering, the controllers side by side (optional);
- ``design.json``: the LMI design the balance controllers used.

Nothing here depends on the wall clock: the same scenario and seed give byte-identical
``metrics.json`` and ``trajectory.csv``.
"""
from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path

from twin.errors import TwinError
from twin.scenarios.scenario import Scenario


@dataclass
class ScenarioResult:
    """What :func:`run_scenario` produced: the runs, their metrics, the plugins loaded (their
    provenance), the files written and timings (s)."""

    scenario: Scenario
    runs: list
    metrics: dict
    files: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    video: object = None
    plugins: list = field(default_factory=list)
    design: object = None


def controllers_of(choice: str | None, scenario: Scenario | None = None) -> tuple[str, ...]:
    """The controller kinds of ``--controller CHOICE`` ("both", or a comma-separated list of
    built-in names and import paths); None: the scenario's ``controller.kinds``."""
    from twin.registry import parse_controllers

    if choice is None:
        return scenario.controllers if scenario is not None else ("it2", "t1")
    return parse_controllers(choice)


def plugins_of(scenario: Scenario, controllers) -> list[dict]:
    """The provenance (module, file, SHA-256) of every import-path kind a run of ``scenario``
    with ``controllers`` loads (:func:`twin.registry.provenance`)."""
    from twin.registry import provenance

    found = [provenance("controller", k) for k in controllers] + [provenance("estimator", scenario.estimator)]
    return [p for p in found if p is not None]


def run_scenario(scenario: Scenario, controllers=None, out: Path | None = None, video: bool | None = None,
                 progress=None) -> ScenarioResult:
    """Run ``scenario`` with each of ``controllers`` (kinds; None: the scenario's
    ``controller.kinds``) on identical conditions: same true plant, sensor seed,
    estimator kind, pushes and faults.

    ``out``: the run directory (None: write nothing); ``video``: render the MP4 (None: as the
    scenario says); ``progress(stage, done, total)``: called as the runs and the video advance.
    Nothing is written unless every run finished (a run that falls is a result; a plugin
    that breaks its contract is an error).
    """
    from twin.bullet_loop import simulate_twin
    from twin.metrics import run_metrics

    from twin.registry import check_kinds, parse_controllers

    if isinstance(controllers, str):
        kinds = parse_controllers(controllers)
    else:
        kinds = check_kinds("controller", controllers if controllers is not None else scenario.controllers,
                            "controllers")
    d = scenario.data
    exp = scenario.experiment()
    config = scenario.twin_config()
    sensors = scenario.sensor_config()
    timings = {}
    solved = []

    def design():  # solved on first use: only the fuzzy cascades (or a plugin that asks) need it
        if not solved:
            t0 = time.perf_counter()
            solved.append(scenario.design())
            timings["design_s"] = time.perf_counter() - t0
        return solved[0]

    context = scenario.build_context(design)
    plugins = plugins_of(scenario, kinds)
    runs, metrics = [], {}
    for kind in kinds:
        controller = scenario.build_controller(kind, context)
        cb = None if progress is None else (lambda done, total, k=kind: progress(f"run {k}", done, total))
        t0 = time.perf_counter()
        run = simulate_twin(controller, exp, config, duration=scenario.duration, controller_name=kind,
                            alpha0=d["initial"]["alpha"], position=(d["initial"]["x"], d["initial"]["y"]),
                            sensors=sensors, estimator=scenario.build_estimator(context), seed=scenario.seed,
                            model_params=context.model, progress=cb)
        run.sensing = scenario.estimator
        timings[f"run_{kind}_s"] = time.perf_counter() - t0
        runs.append(run)
        metrics[kind] = run_metrics(run)
    result = ScenarioResult(scenario, runs, metrics, timings=timings, plugins=plugins,
                            design=solved[0] if solved else None)
    if out is None:
        return result
    from twin import report

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {"scenario": scenario.record(), "source": scenario.source, "seed": scenario.seed, "runs": metrics}
    if plugins:
        doc["plugins"] = plugins
    result.files += [report.write_json(doc, out / "metrics.json"), write_trajectories_csv(runs, out / "trajectory.csv")]
    if solved:
        result.files.append(report.write_json(solved[0].to_json_dict(), out / "design.json"))
    else:
        (out / "design.json").unlink(missing_ok=True)  # an earlier run's, which these runs did not use
    title = f"{scenario.name}: {scenario.description}\nseed {scenario.seed}, " + (
        "ideal sensing" if sensors is None else f"{scenario.estimator} estimator in the loop")
    result.files.append(report.plot_runs(runs, out / "figure.png", title))
    if video if video is not None else d["video"]["enabled"]:
        from twin.render import render_video

        v = d["video"]
        cb = None if progress is None else (lambda done, total: progress("video", done, total))
        t0 = time.perf_counter()
        result.video = render_video(runs, out / "video.mp4", fps=v["fps"], size=(v["width"], v["height"]), progress=cb)
        timings["video_s"] = time.perf_counter() - t0
        result.files.append(out / "video.mp4")
    else:
        (out / "video.mp4").unlink(missing_ok=True)  # an earlier run's video would not show these runs
    return result


def write_trajectories_csv(runs, path: Path) -> Path:
    """Every logged signal of every run, one row per control step, units in the header.

    Controllers may log different extra signals: the columns are their union, in the order
    first met, and a run leaves the columns it does not log empty."""
    names, units = [], []
    for run in runs:
        for n, u in zip(*run.columns()[:2]):
            if n not in names:
                names.append(n)
                units.append(u)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["controller"] + [f"{n} [{u}]" for n, u in zip(names, units)])
        for run in runs:
            own, _, data = run.columns()
            where = [own.index(n) if n in own else None for n in names]
            for row in data:
                w.writerow([run.controller] + ["" if j is None else repr(float(row[j])) for j in where])
    return path
