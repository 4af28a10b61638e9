"""The run figure (twin.outputs.report.figure_runs): its panels, what is shaded and marked, and
that every line has a legend entry; checked through the figure's axes."""
import dataclasses
import math

import numpy as np
import pytest

from twin.outputs.figure import TIME_KEYS, panels
from twin.outputs.report import FAULT_COLOUR, PUSH_COLOUR, figure_runs
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario

TITLES = {"theta": "θ [rad]", "error": "estimator error θ̂ − θ [rad]",
          "torque": "torque per wheel [N·m]: delivered left ─, right ╌; commanded ·; saturated ×",
          "psi_dot": "dψ/dt [rad/s]",
          "distance": "distance p = rψ [m]", "alpha": "heading α [rad]", "path": "path seen from above (x, y) [m]"}
ZOOMED = {"zoom_theta": "theta", "zoom_torque": "torque"}  # a zoom panel's lines are in its original's legend


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
    p = panels(fig)
    assert {k: p[k].get_title() for k in TITLES} == TITLES
    for key, ax in p.items():
        labels = _legend(p[ZOOMED.get(key, key)])
        for line in ax.get_lines():
            if line.get_label().startswith("_"):
                continue
            assert line.get_label() in labels, (ax.get_title(), line.get_label())
    err = p["error"]
    assert {"IT2 (ekf)", "type-1 (ekf)"} <= set(_legend(err))  # the estimator's error of each run
    x, y = err.get_lines()[0].get_data()
    run = push_runs[0]
    np.testing.assert_allclose(y, run.signal("theta_est") - run.signal("theta"))
    # the torque panel: one legend entry per run (the styles are in its title), drawn as the title says
    assert [lab for lab in _legend(p["torque"]) if lab != "zoomed on the right"] == ["IT2", "type-1"]
    styles = {(ln.get_linestyle(), ln.get_marker()) for ln in p["torque"].get_lines()}
    assert ("-", "None") in styles and ("--", "None") in styles  # delivered: left solid, right dashed
    assert ("None", ".") in styles  # commanded: dots
    assert {ln.get_color() for ln in p["torque"].get_lines() if ln.get_label() in ("IT2", "_IT2")} == \
        {p["theta"].get_lines()[0].get_color()}  # a run's one colour
    # the zoom window's shading on the panels it zooms into is named in their legends
    assert "zoomed on the right" in _legend(p["theta"]) and "zoomed on the right" in _legend(p["torque"])


def test_pushes_are_shaded_on_every_panel_where_they_act(push_runs):
    fig = figure_runs(push_runs)
    p = panels(fig)
    for key, ax in p.items():
        spans = _spans(ax, PUSH_COLOUR)
        # the time panels show both shoves, the zoom (on the first shove) that one, the path none
        want = {"zoom_theta": 1, "zoom_torque": 1}.get(key, 2 if key in TIME_KEYS else 0)
        assert len(spans) == want, ax.get_title()
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
    p = panels(fig)
    faults = run.sensor_config.faults
    for key in TIME_KEYS:
        if p[key].get_visible():  # (the difference panel is hidden: a single run)
            assert len(_spans(p[key], FAULT_COLOUR)) == len(faults), key
    assert not _spans(p["zoom_theta"], FAULT_COLOUR)  # the catch, in the first 1.5 s: before the first fault
    ts = run.settling_time()
    assert np.isfinite(ts)
    marks = [ln for ln in p["theta"].get_lines() if ln.get_label().startswith("IT2 settled")]
    assert len(marks) == 1 and marks[0].get_xdata()[0] == pytest.approx(ts)
    sat = [ln for ln in p["torque"].get_lines() if ln.get_gid() == "IT2 left saturated"]
    assert len(sat) == 1 and len(sat[0].get_xdata()) == 10
    assert not [ln for ln in p["torque"].get_lines() if ln.get_gid() == "IT2 right saturated"]


def test_a_turning_experiments_path_shows_its_target_and_the_cascades_signals_say_what_they_are():
    """paper-exp3-like targets (a distance and a heading): the path panel draws the target heading
    at each run's end and names p_d along the path; the controller's signals panel says what θ_off is."""
    from twin.outputs.figure import fill_figure, new_figure

    data = {"runs": [{"name": "IT2", "colour": "tab:blue", "settling_time": float("nan"), "sensing": "ideal",
                      "fell": False, "theta": (np.arange(3.0), np.zeros(3)), "error": None,
                      "psi_dot": (np.arange(3.0), np.zeros(3)), "distance": (np.arange(3.0), np.array([0, .5, 1.0])),
                      "alpha": (np.arange(3.0), np.array([0, .7, 1.5])), "path": (np.array([0, .4, .5]), np.array([0, .2, .8])),
                      "torque_l": (np.arange(3.0), np.zeros(3)), "torque_r": (np.arange(3.0), np.zeros(3)),
                      "cmd_l": None, "cmd_r": None, "saturated_l": None, "saturated_r": None,
                      "signals": [("theta_off", "rad", (np.arange(3.0), np.zeros(3)))]}],
            "p_d": 1.0, "alpha_d": 1.5, "spans": [], "zoom": None, "zoom_why_not": "short", "pushes": [],
            "start": (0.0, 0.0, 0.0)}
    fig, axes = new_figure()
    fill_figure(fig, axes, data, "")
    p = panels(fig)
    assert "target: α_d = 1.5 rad (arrow),\np_d = 1 m along the path" in _legend(p["path"])
    arrows = [c for c in p["path"].texts if getattr(c, "arrow_patch", None) is not None]
    # in the targets' black (the runs' colours are the runs'; green is LQR's when it is third)
    assert arrows and tuple(arrows[0].arrow_patch.get_edgecolor()[:3]) == (0.0, 0.0, 0.0)
    assert arrows[0].xy == pytest.approx((0.5 + 0.15 * 0.8 * math.cos(1.5), 0.8 + 0.15 * 0.8 * math.sin(1.5)))
    assert "θ_off = tilt set by the position loop" in p["signals_1"].get_title()
