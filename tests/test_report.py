"""The run figure (twin.outputs.report.figure_runs): its panels, what is shaded and marked, and
that every line has a legend entry; checked through the figure's axes."""
import dataclasses

import numpy as np
import pytest

from twin.outputs.report import FAULT_COLOUR, PUSH_COLOUR, figure_runs
from twin.scenarios import load_scenario
from twin.scenarios.runner import run_scenario

PANELS = ["θ [rad]", "estimator error θ̂ − θ [rad]", "delivered torque per wheel [N·m]", "dψ/dt [rad/s]",
          "distance p = rψ [m]", "heading α [rad]"]


@pytest.fixture(scope="module")
def push_runs():
    # push-recovery's shoves act at 3 s and 8 s, 0.1 s each
    return run_scenario(load_scenario("push-recovery", ["duration=9"]), controllers=("it2", "t1")).runs


def _spans(ax, colour):
    from matplotlib.colors import to_rgba

    want = to_rgba(colour, 0.15)
    return [p for p in ax.patches if np.allclose(p.get_facecolor(), want)]


def _legend(ax):
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg else []


def test_figure_has_its_panels_with_every_line_in_a_legend(push_runs):
    fig = figure_runs(push_runs, "push-recovery")
    axes = fig.get_axes()
    assert [ax.get_title() for ax in axes] == PANELS
    for ax in axes:
        labels = _legend(ax)
        for line in ax.get_lines():
            if line.get_label().startswith("_"):
                continue
            assert line.get_label() in labels, (ax.get_title(), line.get_label())
    err = axes[1]
    assert {"IT2 (ekf)", "type-1 (ekf)"} <= set(_legend(err))  # the estimator's error of each run
    x, y = err.get_lines()[0].get_data()
    run = push_runs[0]
    np.testing.assert_allclose(y, run.signal("theta_est") - run.signal("theta"))
    torque = set(_legend(axes[2]))
    assert {"IT2 left", "IT2 right", "type-1 left", "type-1 right"} <= torque


def test_pushes_are_shaded_on_every_panel_where_they_act(push_runs):
    fig = figure_runs(push_runs)
    for ax in fig.get_axes():
        spans = _spans(ax, PUSH_COLOUR)
        assert len(spans) == 2, ax.get_title()
        for span, start in zip(spans, (3.0, 8.0)):
            x0, x1 = span.get_x(), span.get_x() + span.get_width()
            assert x0 == pytest.approx(start, abs=0.006) and x1 == pytest.approx(start + 0.1, abs=0.011)
        assert not _spans(ax, FAULT_COLOUR)


def test_fault_windows_shaded_settling_marked_and_saturation_marked():
    runs = run_scenario(load_scenario("sensor-faults"), controllers="it2").runs
    run = runs[0]
    # mark a stretch of the left wheel as saturated: the figure must show those samples
    act = run.actuation.copy()
    names = ("duty_l", "duty_r", "torque_l", "torque_r", "saturated_l", "saturated_r")
    act[100:110, names.index("saturated_l")] = 1.0
    sat_run = dataclasses.replace(run, actuation=act)
    fig = figure_runs([sat_run])
    axes = fig.get_axes()
    faults = run.sensor_config.faults
    for ax in axes:
        assert len(_spans(ax, FAULT_COLOUR)) == len(faults), ax.get_title()
    ts = run.settling_time()
    assert np.isfinite(ts)
    marks = [ln for ln in axes[0].get_lines() if ln.get_label().startswith("IT2 settled")]
    assert len(marks) == 1 and marks[0].get_xdata()[0] == pytest.approx(ts)
    sat = [ln for ln in axes[2].get_lines() if ln.get_label() == "IT2 left saturated"]
    assert len(sat) == 1 and len(sat[0].get_xdata()) == 10
    assert not [ln for ln in axes[2].get_lines() if ln.get_label() == "IT2 right saturated"]
