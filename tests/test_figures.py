"""The run figure and the video's key answer the questions a reader brings (issue 31, item 4):
checked through the matplotlib Figure that :func:`twin.outputs.report.figure_runs` builds (its
panels found by title, their lines, limits and texts) and through the overlay's drawing
functions (:mod:`twin.render.hud`), never through pixels of a PNG.

What each test asks of the figure: whether runs drawn on top of each other differ (a
difference panel); the catch, at a readable scale (a zoom panel); a heading that only moves by
numerical noise drawn flat (a floor on the axis' span); which fault and which push (named
spans); where the robot went (the x–y path); what the controller computed on the way (its
logged signals, a plugin's included); what the motors were asked for against what they gave
(commanded and delivered torque), without a delivered torque that drops to zero at the end.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import textwrap

import numpy as np
import pytest

from twin.outputs.report import figure_runs
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario


def _runs(name: str, sets=(), controllers=("it2",)):
    return run_scenario(load_scenario(name, list(sets)), controllers=controllers).runs


@pytest.fixture(scope="module")
def exp1():
    """Paper experiment 1 for 6 s with IT2 and type-1: balance only, where the two are the same."""
    return _runs("paper-exp1", ["duration=6"], ("it2", "t1"))


@pytest.fixture(scope="module")
def exp1_figure(exp1):
    return figure_runs(exp1, "paper-exp1")


@pytest.fixture(scope="module")
def exp3():
    """Paper experiment 3 for 4 s, IT2: the cascade's position and heading loops at work."""
    return _runs("paper-exp3", ["duration=4"])


def _panel(fig, start: str):
    """The one visible panel whose title starts with ``start``."""
    found = [ax for ax in fig.get_axes() if ax.get_visible() and ax.get_title().startswith(start)]
    assert len(found) == 1, (start, [ax.get_title() for ax in fig.get_axes()])
    return found[0]


def _line(ax, label: str):
    found = [ln for ln in ax.get_lines() if ln.get_label() == label or ln.get_gid() == label]
    assert len(found) == 1, (ax.get_title(), label, [ln.get_label() for ln in ax.get_lines()])
    return found[0]


def _texts(ax) -> str:
    return "\n".join(t.get_text() for t in ax.texts)


# ---- runs on top of each other: the difference panel -------------------------------------------
def test_runs_that_overlap_get_a_difference_panel_that_says_how_far_apart_they_are(exp1, exp1_figure):
    it2, t1 = exp1
    assert np.array_equal(it2.signal("theta"), t1.signal("theta"))  # the overlap the panel is for
    ax = _panel(exp1_figure, "difference to IT2")
    diff = _line(ax, "type-1 − IT2")
    t, y = diff.get_data()
    np.testing.assert_array_equal(t, it2.t)
    np.testing.assert_array_equal(y, t1.signal("theta") - it2.signal("theta"))
    assert "identical to IT2, bit for bit" in _texts(ax)
    # a flat zero is drawn flat: not autoscaled into rounding noise, not into ±0.05
    lo, hi = ax.get_ylim()
    assert 0.0 < hi - lo < 1e-5 and lo < 0.0 < hi


def test_the_difference_panel_gives_the_largest_differences_of_runs_that_differ(exp3):
    lqr = _runs("paper-exp3", ["duration=4"], ("lqr",))[0]
    fig = figure_runs([exp3[0], lqr])
    ax = _panel(fig, "difference to IT2")
    t, y = _line(ax, "LQR − IT2").get_data()
    np.testing.assert_allclose(y, lqr.signal("theta") - exp3[0].signal("theta"))
    largest = float(np.max(np.abs(lqr.signal("theta") - exp3[0].signal("theta"))))
    assert largest > 1e-3 and f"θ {largest:.2g} rad" in _texts(ax)
    lo, hi = ax.get_ylim()
    assert lo <= float(np.min(y)) and hi >= float(np.max(y))


# ---- the catch -----------------------------------------------------------------------------------
def test_the_catch_has_a_zoom_panel_at_its_own_scale(exp1, exp1_figure):
    it2 = exp1[0]
    ax = _panel(exp1_figure, "zoom: θ")
    assert "catch" in ax.get_title()
    a, b = ax.get_xlim()
    settled = it2.settling_time()
    # the whole catch (0.48 rad, caught and settled within about 0.7 s), on an axis a quarter
    # of the run's or less: not squashed onto the full time axis
    assert a == pytest.approx(0.0) and settled < b <= it2.t[-1] / 3.0
    t, y = _line(ax, "IT2").get_data()
    np.testing.assert_array_equal(y, it2.signal("theta")[:len(y)])
    assert t[0] <= a and t[-1] >= b
    full = _panel(exp1_figure, "θ [rad]")
    assert full.get_xlim()[1] >= it2.t[-1]  # the first panel still shows the whole run
    zoom_torque = _panel(exp1_figure, "zoom: torque")
    assert zoom_torque.get_xlim() == pytest.approx((a, b))
    _line(zoom_torque, "IT2 left commanded")


def test_a_push_is_zoomed_on_when_the_start_is_upright():
    run = _runs("push-recovery", ["duration=9"])[0]
    fig = figure_runs([run])
    ax = _panel(fig, "zoom: θ")
    a, b = ax.get_xlim()
    assert "push of 12 N forward at 3.00 s" in ax.get_title()
    assert a < 3.0 < 3.1 < b < 8.0  # the first shove, not the second


# ---- numerical noise drawn as such ---------------------------------------------------------------
def test_a_heading_of_numerical_noise_is_drawn_on_a_floor_scale(exp1_figure, exp1, exp3):
    alpha = exp1[0].signal("alpha")
    assert 0.0 < np.ptp(alpha) < 1e-6  # the twin's rounding noise, on a robot that never turns
    ax = _panel(exp1_figure, "heading α")
    lo, hi = ax.get_ylim()
    assert hi - lo >= 1e-3 and lo < float(alpha.min()) and hi > float(alpha.max())
    assert "below this axis' floor of 0.001 rad" in _texts(ax)
    # a heading that turns is autoscaled as before, without the note
    turning = _panel(figure_runs(exp3), "heading α")
    lo, hi = turning.get_ylim()
    assert hi - lo < 2.0 and hi >= 1.5 and "floor" not in _texts(turning)


# ---- pushes and faults, named --------------------------------------------------------------------
def test_fault_windows_are_named_by_their_kind():
    run = _runs("sensor-faults", ["duration=9.5"])[0]
    fig = figure_runs([run])
    for title in ("θ [rad]", "estimator error"):
        texts = _texts(_panel(fig, title))
        for kind in ("gyro spikes", "IMU dropout", "encoders stuck", "encoders spikes"):
            assert kind in texts, (title, kind, texts)
        assert "sensor fault\n" not in texts + "\n"  # not the bare category


def test_pushes_are_labelled_with_their_force_and_direction():
    run = _runs("push-recovery", ["duration=9"])[0]
    fig = figure_runs([run])
    texts = _texts(_panel(fig, "θ [rad]"))
    assert "push 12 N forward" in texts and "push 10 N backward" in texts
    path = _texts(_panel(fig, "path"))
    assert "12 N forward\nat 3.00 s" in path and "10 N backward\nat 8.00 s" in path


# ---- where the robot went ------------------------------------------------------------------------
def test_the_path_is_drawn_from_above_on_one_scale(exp3):
    run = exp3[0]
    fig = figure_runs([run])
    ax = _panel(fig, "path")
    x, y = _line(ax, "IT2").get_data()
    np.testing.assert_array_equal(x, run.signal("x"))
    np.testing.assert_array_equal(y, run.signal("y"))
    assert ax.get_xlabel() == "x [m]" and "(x, y) [m]" in ax.get_title()
    _line(ax, "start")
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert x0 <= x.min() and x1 >= x.max() and y0 <= y.min() and y1 >= y.max()
    box = ax.get_position()
    w, h = fig.get_size_inches()
    # one metre is as long across as up (a quarter circle looks like one)
    assert (x1 - x0) / (box.width * w) == pytest.approx((y1 - y0) / (box.height * h), rel=1e-6)


# ---- what the controller computed ----------------------------------------------------------------
def test_the_cascades_theta_off_and_u_alpha_are_plotted(exp3):
    run = exp3[0]
    fig = figure_runs([run])
    rad = _panel(fig, "controller's signals [rad]")
    np.testing.assert_array_equal(_line(rad, "IT2 θ_off").get_data()[1], run.signal("theta_off"))
    torque = _panel(fig, "controller's signals [N·m]")
    np.testing.assert_array_equal(_line(torque, "IT2 u_α").get_data()[1], run.signal("u_alpha"))
    np.testing.assert_array_equal(_line(torque, "IT2 u").get_data()[1], run.signal("u"))
    assert np.ptp(run.signal("theta_off")) > 0.01 and np.ptp(run.signal("u_alpha")) > 0.01  # they do move


PLUGIN = textwrap.dedent('''
    from my_plugins import StateFeedback


    class Leaning(StateFeedback):
        """The example's state feedback, logging the pitch it acted on as well."""

        signals = StateFeedback.signals + ("lean",)
        signal_units = {**StateFeedback.signal_units, "lean": "rad"}

        def __call__(self, estimate, targets):
            return tuple(super().__call__(estimate, targets)) + (float(estimate[0]),)
''')


def test_a_plugins_own_signals_are_plotted_with_their_units(tmp_path, monkeypatch):
    from pathlib import Path

    examples = Path(__file__).resolve().parents[1] / "examples"
    (tmp_path / "fig_plugin.py").write_text(PLUGIN, encoding="utf-8")
    monkeypatch.syspath_prepend(str(examples))
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("my_plugins", "fig_plugin"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    run = _runs("paper-exp1", ["duration=1.5"], ("fig_plugin:Leaning",))[0]
    assert run.command_names[-1] == "lean"
    fig = figure_runs([run])
    name = [ln.get_label() for ln in _panel(fig, "controller's signals [rad]").get_lines()]
    assert len(name) == 1 and name[0].endswith(" lean")
    np.testing.assert_array_equal(_panel(fig, "controller's signals [rad]").get_lines()[0].get_data()[1],
                                  run.signal("lean"))
    labels = [ln.get_label() for ln in _panel(fig, "controller's signals [N·m]").get_lines()]
    assert sorted(label.rsplit(" ", 1)[1] for label in labels) == ["u", "u_α"]


# ---- the motors: commanded against delivered -----------------------------------------------------
def test_commanded_and_delivered_torque_are_drawn_together(exp1, exp1_figure):
    it2 = exp1[0]
    ax = _panel(exp1_figure, "torque per wheel")
    for side, word in (("l", "left"), ("r", "right")):
        np.testing.assert_array_equal(_line(ax, f"IT2 {word}").get_data()[1], it2.signal(f"torque_{side}"))
        np.testing.assert_array_equal(_line(ax, f"IT2 {word} commanded").get_data()[1], it2.signal(f"u{side}_cmd"))
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "IT2" in legend and not any("commanded" in t for t in legend)  # one entry per run; styles: the title
    # they do differ: the motor model (back-EMF, the driver's limits) stands between them
    assert np.max(np.abs(it2.signal("torque_l") - it2.signal("ul_cmd"))) > 1e-3


def test_the_delivered_torque_does_not_drop_to_zero_at_the_last_sample(exp1, exp1_figure):
    """The run ends before its last command is applied: its last row holds what the motors
    were delivering then, not zeros (which the figure drew as a drop at the very end)."""
    it2 = exp1[0]
    for name in ("torque_l", "torque_r", "duty_l", "duty_r"):
        sig = it2.signal(name)
        assert sig[-1] == sig[-2], (name, sig[-3:])
    # the delivered torque is never exactly 0 while the wheels turn (the motors' back-EMF); the duty
    # may be, where the commanded torque is below half a PWM step (the robot balanced at the end)
    for name in ("torque_l", "torque_r"):
        assert it2.signal(name)[-1] != 0.0, name
    t, y = _line(_panel(exp1_figure, "torque per wheel"), "IT2 left").get_data()
    assert y[-1] == y[-2] != 0.0


def test_a_run_that_falls_holds_its_last_torque_too(design):
    from twin.controllers.cascade import build_cascade
    from twin.experiments import Experiment
    from twin.plant.bullet import TwinConfig
    from twin.plant.disturbances import Disturbances, Push
    from twin.sim.bullet_loop import simulate_twin

    exp = Experiment("push", "pushed over", theta0=0.0, duration=1.0)
    config = TwinConfig(disturbances=Disturbances(pushes=(Push((28.0, 0.0, 0.0), 0.2, 0.1),)))
    run = simulate_twin(build_cascade("t1", design, exp.targets), exp, config, controller_name="t1", sensors=None)
    assert run.status == "fell"
    tq = run.signal("torque_l")
    assert tq[-1] == tq[-2] and tq[-1] != 0.0


# ---- the video's key -----------------------------------------------------------------------------
def test_the_video_key_names_every_marker_shown_in_its_colour():
    from twin.render import hud, panels

    s = hud.HudState("IT2  push-recovery", 3.05, 0.09, 0.0, 0.0, p_d=0.0, theta_est=0.086,
                     push=hud.push_caption(12.0, 0.0, 0.0, 0.0))
    items = hud.legend_lines(s)
    assert [(text, colour) for text, colour, _ in items] == [
        ("estimator's body (ghost)", panels.GHOST_BGR), ("position target 0.00 m", panels.TARGET_BGR),
        ("push 12 N forward", panels.PUSH_BGR)]
    # a heading target is an arrow, the position target then a ring ahead on the heading; no
    # estimate, no ghost; no push acting, no push; near the start, no start
    quiet = hud.legend_lines(hud.HudState("T1", 1.0, 0.0, 0.0, 0.0, p_d=1.0, alpha_d=1.5, from_start=0.04))
    assert [(text, shape) for text, _, shape in quiet] == [("position target 1.00 m ahead", "ring"),
                                                           ("heading target 1.50 rad", "arrow")]
    assert hud.legend_lines(hud.HudState("T1", 1.0, 0.0, 0.0, 0.0)) == []
    # away from the start: the start's cross and the path since, in their colour
    moved = hud.legend_lines(hud.HudState("T1", 1.0, 0.0, 0.0, 0.0, from_start=hud.START_SHOWN_M))
    assert moved == [("start, path since", panels.PATH_BGR, "path")]
    # the push in the robot's frame: a world-frame force against the heading is "backward"
    assert hud.push_caption(0.0, -10.0, 0.0, math.pi / 2) == "10 N backward"
    assert hud.push_caption(0.0, 0.0, 0.0, 0.0) == ""


def test_the_video_key_is_drawn_at_the_top_right_in_the_markers_colours():
    from twin.render import hud

    img = np.full((480, 640, 3), 128, np.uint8)
    s = hud.HudState("IT2", 3.05, 0.09, 0.0, 0.0, p_d=0.0, theta_est=0.086, push="12 N forward")
    hud.draw_hud(img, s)
    key = img[:80, 400:]
    for colour in (hud.CYAN, hud.GREEN, hud.MAGENTA):
        assert (np.abs(key.astype(int) - colour).max(axis=2) < 30).sum() > 20, colour
    plain = np.full((480, 640, 3), 128, np.uint8)
    hud.draw_hud(plain, dataclasses.replace(s, p_d=None, theta_est=None, push=""))
    assert (plain[:80, 480:] == 128).all()  # nothing to explain: no key
