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

CONTROLLERS = ("it2", "t1")


@dataclass
class ScenarioResult:
    """What :func:`run_scenario` produced: the runs, their metrics, the files written and timings (s)."""

    scenario: Scenario
    runs: list
    metrics: dict
    files: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    video: object = None


def controllers_of(choice: str) -> tuple[str, ...]:
    if choice == "both":
        return CONTROLLERS
    if choice not in CONTROLLERS:
        raise TwinError(f"controller must be it2, t1 or both, got {choice!r}")
    return (choice,)


def run_scenario(scenario: Scenario, controllers=CONTROLLERS, out: Path | None = None, video: bool | None = None,
                 progress=None) -> ScenarioResult:
    """Run ``scenario`` with each of ``controllers`` ("it2", "t1") on identical conditions.

    ``out``: the run directory (None: write nothing); ``video``: render the MP4 (None: as the
    scenario says); ``progress(stage, done, total)``: called as the runs and the video advance.
    """
    from twin.analytic_loop import build_cascade
    from twin.bullet_loop import simulate_twin
    from twin.metrics import run_metrics

    d = scenario.data
    exp = scenario.experiment()
    config = scenario.twin_config()
    sensors = scenario.sensor_config()
    timings = {}
    t0 = time.perf_counter()
    design = scenario.design()
    timings["design_s"] = time.perf_counter() - t0
    runs, metrics = [], {}
    for kind in controllers:
        cb = None if progress is None else (lambda done, total, k=kind: progress(f"run {k}", done, total))
        t0 = time.perf_counter()
        run = simulate_twin(build_cascade(kind, design, exp, **scenario.cascade_options()), exp, config,
                            duration=scenario.duration, controller_name=kind, alpha0=d["initial"]["alpha"],
                            position=(d["initial"]["x"], d["initial"]["y"]), sensors=sensors,
                            estimator=d["sensors"]["estimator"], seed=scenario.seed, progress=cb)
        timings[f"run_{kind}_s"] = time.perf_counter() - t0
        runs.append(run)
        metrics[kind] = run_metrics(run)
    result = ScenarioResult(scenario, runs, metrics, timings=timings)
    if out is None:
        return result
    from twin import report

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {"scenario": d, "source": scenario.source, "seed": scenario.seed, "runs": metrics}
    result.files += [report.write_json(doc, out / "metrics.json"), write_trajectories_csv(runs, out / "trajectory.csv"),
                     report.write_json(design.to_json_dict(), out / "design.json")]
    title = f"{scenario.name}: {scenario.description}\nseed {scenario.seed}, " + (
        "ideal sensing" if sensors is None else f"{d['sensors']['estimator']} estimator in the loop")
    result.files.append(report.plot_runs(runs, out / "figure.png", title))
    if video if video is not None else d["video"]["enabled"]:
        from twin.render import render_video

        v = d["video"]
        cb = None if progress is None else (lambda done, total: progress("video", done, total))
        t0 = time.perf_counter()
        result.video = render_video(runs, out / "video.mp4", fps=v["fps"], size=(v["width"], v["height"]), progress=cb)
        timings["video_s"] = time.perf_counter() - t0
        result.files.append(out / "video.mp4")
    return result


def write_trajectories_csv(runs, path: Path) -> Path:
    """Every logged signal of every run, one row per control step, units in the header."""
    names, units, _ = runs[0].columns()
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["controller"] + [f"{n} [{u}]" for n, u in zip(names, units)])
        for run in runs:
            _, _, data = run.columns()
            for row in data:
                w.writerow([run.controller] + [repr(float(v)) for v in row])
    return path
