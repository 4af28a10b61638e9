"""Limits on plugins (issue 26): twin.limits' PluginLimits and RunGuard, the closed loop and the
analytic loop stopped by a slow controller or estimator, a slow run or a leaking controller
(one PluginError line naming the plugin, the limit and t), nothing timed without limits and
the same bytes with generous ones, and the options --step-limit, --run-limit and
--memory-limit of twin run, twin check and twin sweep: a run a limit stops is one line against
that controller alone, the other controllers' results written, exit status 2.

Short runs (0.5 s of paper-exp1, no video), so the file takes seconds.
"""
from __future__ import annotations

import json
import math
import time

import pytest

from slow_plugin import write_slow_plugin
from test_scenarios import twin
from twin.errors import PluginError, TwinError
from twin.limits import LIMIT_KEYS, MB, MEMORY_EVERY, PluginLimits, RunGuard, limit_of, resident_bytes

SHORT = ["--set", "duration=0.5", "--no-video"]


def one_line_plugin_error(exc_info, *fragments):
    text = str(exc_info.value)
    assert isinstance(exc_info.value, PluginError) and "\n" not in text, text
    for fragment in fragments:
        assert fragment in text, (fragment, text)
    return text


# ---- PluginLimits and RunGuard --------------------------------------------------------------------------------

def test_plugin_limits_take_positive_finite_numbers_or_none():
    assert not PluginLimits().active
    lim = PluginLimits(step_wall_s=1, run_wall_s=2.5, run_memory_mb=100)
    assert lim.active and (lim.step_wall_s, lim.run_wall_s, lim.run_memory_mb) == (1.0, 2.5, 100.0)
    assert isinstance(lim.step_wall_s, float)
    for key, unit in (("step_wall_s", "s"), ("run_wall_s", "s"), ("run_memory_mb", "MB")):
        for bad in (0, -1.0, math.nan, math.inf, True, "1", [1]):
            with pytest.raises(TwinError) as info:
                PluginLimits(**{key: bad})
            text = str(info.value)
            assert f"limits.{key} must be a positive finite number in {unit}" in text and "\n" not in text, text
        assert PluginLimits(**{key: 0.5}).active


class _Named:
    def __call__(self, estimate, targets):
        return (0.0, 0.0)


def test_run_guard_charges_steps_and_runs_and_names_the_limit():
    ctrl, est = _Named(), object()
    guard = RunGuard(PluginLimits(step_wall_s=0.1), ctrl, est, 0.005)
    guard.start()
    now = time.perf_counter()
    guard.charge("controller", 0.05, now, 3)  # under the limit
    guard.charge("controller", 0.5, now, 3, per_step=False)  # start()/reset(): not a control step
    with pytest.raises(PluginError) as info:
        guard.charge("controller", 0.2, now, 40)
    text = one_line_plugin_error(info, "controller test_limits._Named took 0.2 s for one control step",
                                 "over limits.step_wall_s = 0.1 s", "at t = 0.200 s")
    assert limit_of(info.value) == "step_wall_s" and "estimator" not in text
    assert guard.spent["controller"] == pytest.approx(0.75)

    guard = RunGuard(PluginLimits(run_wall_s=1.0), ctrl, est, 0.005)
    guard.start()
    guard.charge("estimator", 0.3, guard.t0 + 0.9, 10)  # 0.9 s into the run
    with pytest.raises(PluginError) as info:
        guard.charge("controller", 0.4, guard.t0 + 1.2, 20)
    one_line_plugin_error(info, "the run of controller test_limits._Named (estimator builtins.object) took 1.2 s",
                          "over limits.run_wall_s = 1 s", "stopped at t = 0.100 s", "0.4 s in the controller",
                          "0.3 s in the estimator", "0.5 s in the plant and the rest")
    assert limit_of(info.value) == "run_wall_s"
    guard.start()  # a new run: its own clock and plugin times
    assert guard.spent == {"controller": 0.0, "estimator": 0.0}
    guard.charge("controller", 0.4, guard.t0 + 0.5, 1)


@pytest.mark.skipif(resident_bytes() is None, reason="no resident memory on this platform")
def test_run_guard_memory_reads_growth_since_start():
    guard = RunGuard(PluginLimits(run_memory_mb=5), _Named(), None, 0.005)
    guard.start()
    guard.memory(0)
    hoard = fresh_resident(int(20 * MB))
    try:
        with pytest.raises(PluginError) as info:
            guard.memory(MEMORY_EVERY)
    finally:
        del hoard
    one_line_plugin_error(info, "the run of controller test_limits._Named grew the process's resident memory by",
                          "over limits.run_memory_mb = 5 MB", f"at t = {MEMORY_EVERY * 0.005:.3f} s")
    assert limit_of(info.value) == "run_memory_mb"


def test_limit_of_is_none_for_other_errors():
    assert limit_of(PluginError("controller x returned nan")) is None
    assert limit_of(ValueError("x")) is None
    assert set(LIMIT_KEYS) == {"step_wall_s", "run_wall_s", "run_memory_mb"}


def fresh_resident(n: int):
    """``n`` bytes of new resident memory: an anonymous mapping of its own, every page written.
    (A bytearray may reuse heap pages a long test session freed but kept resident, so the
    resident set would not grow.)"""
    import mmap

    m = mmap.mmap(-1, n)
    m.write(b"\x01" * n)
    return m


# ---- the closed loop ------------------------------------------------------------------------------------------

class Feedback:
    """The state feedback of examples/my_plugins.py (balances paper-exp1 for a while)."""

    def __init__(self, sleep_from=None, sleep=0.0, leak_bytes=0):
        self.sleep_from, self.sleep, self.leak_bytes = sleep_from, sleep, leak_bytes
        self.calls, self.hoard = 0, []

    def reset(self, targets):
        self.calls = 0

    def __call__(self, estimate, targets):
        self.calls += 1
        if self.sleep_from is not None and self.calls >= self.sleep_from:
            time.sleep(self.sleep)
        if self.leak_bytes:
            self.hoard.append(fresh_resident(self.leak_bytes))
        theta, theta_dot, psi, psi_dot = estimate[:4]
        u = 1.2 * theta + 0.085 * theta_dot + 0.06 * psi + 0.032 * psi_dot
        return (0.5 * u, 0.5 * u)


class SlowEstimator:
    """The scenario's estimator, slow at its 5th step()."""

    def __init__(self, inner):
        self.inner, self.steps = inner, 0

    def start(self, measurement):
        self.steps = 0
        return self.inner.start(measurement)

    def step(self, measurement, command):
        self.steps += 1
        if self.steps == 5:
            time.sleep(0.2)
        return self.inner.step(measurement, command)


def closed_loop_run(controller, limits: dict, duration=0.5, slow_estimator=False):
    """paper-exp1 on the twin with ``controller`` and the scenario's sensors and estimator, with ``limits``."""
    from twin.sim.bullet_loop import simulate_twin
    from twin.scenarios import load_scenario

    sc = load_scenario("paper-exp1", [f"limits.{k}={v!r}" for k, v in limits.items()])
    context = sc.build_context()
    estimator = sc.build_estimator(context)
    if slow_estimator:
        estimator = SlowEstimator(estimator)
    return simulate_twin(controller, sc.experiment(), sc.twin_config(), duration=duration,
                         sensors=sc.sensor_config(), estimator=estimator, seed=0, model_params=context.model,
                         limits=sc.plugin_limits())


def test_a_slow_controller_stops_the_closed_loop_at_its_step():
    with pytest.raises(PluginError) as info:
        closed_loop_run(Feedback(sleep_from=10, sleep=0.15), {"step_wall_s": 0.05})
    one_line_plugin_error(info, "controller test_limits.Feedback took", "for one control step",
                          "over limits.step_wall_s = 0.05 s", "at t = 0.045 s")
    assert limit_of(info.value) == "step_wall_s"


def test_a_slow_estimator_stops_the_closed_loop_at_its_step():
    with pytest.raises(PluginError) as info:
        closed_loop_run(Feedback(), {"step_wall_s": 0.05}, slow_estimator=True)
    one_line_plugin_error(info, "estimator test_limits.SlowEstimator took", "over limits.step_wall_s = 0.05 s",
                          "at t = 0.025 s")


def test_a_slow_run_stops_the_closed_loop():
    with pytest.raises(PluginError) as info:
        closed_loop_run(Feedback(sleep_from=1, sleep=0.004), {"run_wall_s": 0.2, "step_wall_s": 1.0}, duration=2.0)
    text = one_line_plugin_error(info, "the run of controller test_limits.Feedback (estimator ", "took",
                                 "over limits.run_wall_s = 0.2 s", "s in the controller", "s in the estimator")
    assert limit_of(info.value) == "run_wall_s"
    t = float(text.split("stopped at t = ")[1].split(" s")[0])
    assert 0 < t < 2.0


@pytest.mark.skipif(resident_bytes() is None, reason="no resident memory on this platform")
def test_a_leaking_controller_stops_the_closed_loop():
    leaky = Feedback(leak_bytes=int(1 * MB))
    try:
        with pytest.raises(PluginError) as info:
            closed_loop_run(leaky, {"run_memory_mb": 30}, duration=1.0)
        calls = leaky.calls
    finally:
        for m in leaky.hoard:
            m.close()
    one_line_plugin_error(info, "the run of controller test_limits.Feedback", "grew the process's resident memory",
                          "over limits.run_memory_mb = 30 MB")
    assert limit_of(info.value) == "run_memory_mb"
    # read after every call (the run's own growth counts too): seen at the call that crossed the limit; it
    # was every 64 steps, and a plugin leaking 20 MB a call grew 1.2 GB past a 300 MB limit unseen
    assert MEMORY_EVERY == 1 and 20 <= calls <= 31


def test_without_limits_nothing_is_timed(monkeypatch):
    import twin.sim.loop
    from twin.sim.analytic_loop import simulate
    from twin.experiments import PAPER_EXPERIMENTS

    def refuse(*args, **kwargs):
        raise AssertionError("a RunGuard was built without limits")

    monkeypatch.setattr(twin.sim.loop, "RunGuard", refuse)
    run = closed_loop_run(Feedback(), {}, duration=0.1)
    assert run.control_steps == 21
    simulate(Feedback(), PAPER_EXPERIMENTS[1], duration=0.1)
    simulate(Feedback(), PAPER_EXPERIMENTS[1], duration=0.1, limits=PluginLimits())  # all None: none active
    from twin.sim.loop import ClosedLoop
    from twin.plant.base import TwinConfig

    loop = ClosedLoop(TwinConfig(), _Estimator(), Feedback(), limits=PluginLimits())
    assert loop._guard is None


class _Estimator:
    def start(self, measurement):
        return (0.0,) * 6

    def step(self, measurement, command):
        return (0.0,) * 6


def test_generous_limits_change_no_byte_of_a_run(tmp_path):
    from twin.workflows.run import run_scenario
    from twin.scenarios.scenario import Scenario, load_scenario

    sc = load_scenario("paper-exp1", ["duration=0.5", "video.enabled=false"])
    generous = {"step_wall_s": 3600.0, "run_wall_s": 1e6, "run_memory_mb": 1e6}
    limited = Scenario({**sc.data, "limits": generous}, sc.source, sc.overrides)
    assert limited.plugin_limits().active and sc.plugin_limits() is None
    assert limited.run_spec("it2", build=False).limits == limited.plugin_limits()  # the run's, not the plant's
    run_scenario(sc, ("it2", "lqr"), out=tmp_path / "plain")
    run_scenario(limited, ("it2", "lqr"), out=tmp_path / "limited")
    for name in ("metrics.json", "trajectory.csv"):
        assert (tmp_path / "plain" / name).read_bytes() == (tmp_path / "limited" / name).read_bytes(), name


# ---- the analytic loop ----------------------------------------------------------------------------------------

def analytic(controller, duration=0.5, **limits):
    from twin.sim.analytic_loop import simulate
    from twin.experiments import PAPER_EXPERIMENTS

    return simulate(controller, PAPER_EXPERIMENTS[1], duration=duration, limits=PluginLimits(**limits))


def test_the_analytic_loop_keeps_the_limits():
    with pytest.raises(PluginError) as info:
        analytic(Feedback(sleep_from=10, sleep=0.15), step_wall_s=0.05)
    one_line_plugin_error(info, "controller test_limits.Feedback took", "over limits.step_wall_s = 0.05 s",
                          "at t = 0.045 s")
    with pytest.raises(PluginError) as info:
        analytic(Feedback(sleep_from=1, sleep=0.004), duration=2.0, run_wall_s=0.2)
    # the analytic loop is ClosedLoop with the ideal estimator (the truth passed through)
    one_line_plugin_error(info, "the run of controller test_limits.Feedback (estimator estimation.ideal.IdealEstimator) "
                          "took", "over limits.run_wall_s = 0.2 s", "s in the controller", "s in the plant and the rest")
    if resident_bytes() is not None:
        leaky = Feedback(leak_bytes=int(1 * MB))
        try:
            with pytest.raises(PluginError) as info:
                analytic(leaky, duration=1.0, run_memory_mb=30)
        finally:
            for m in leaky.hoard:
                m.close()
        one_line_plugin_error(info, "the run of controller test_limits.Feedback (estimator estimation.ideal.IdealEstimator) "
                              "grew", "over limits.run_memory_mb = 30")
    with pytest.raises(TwinError, match="limits must be a twin.limits.PluginLimits or None"):
        from twin.sim.analytic_loop import simulate
        from twin.experiments import PAPER_EXPERIMENTS

        simulate(Feedback(), PAPER_EXPERIMENTS[1], duration=0.1, limits={"step_wall_s": 1})


def test_the_analytic_loop_gives_the_same_run_with_generous_limits():
    import numpy as np

    a = analytic(Feedback())
    b = analytic(Feedback(), step_wall_s=3600, run_wall_s=1e6, run_memory_mb=1e6)
    assert np.array_equal(a.truth, b.truth) and np.array_equal(a.commands, b.commands)


# ---- the command line -----------------------------------------------------------------------------------------

SLOW = "limslowplug:Slow"


@pytest.fixture(scope="module")
def plugdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("plugins")
    write_slow_plugin(d, "limslowplug", 0.15, first=20, last=22)
    return d


def error_lines(stderr: str) -> list:
    assert "Traceback" not in stderr, stderr
    return [line for line in stderr.splitlines() if line.startswith("error:")]


def assert_limited_run(out, stderr, limit_text):
    """One error line naming the slow controller and the limit; it2's results written, the slow one's
    in metrics.json's 'errors' alone; the manifest's exit status 2."""
    lines = error_lines(stderr)
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"error: {SLOW}: ") and "controller limslowplug.Slow" in lines[0], lines
    assert limit_text in lines[0], lines
    assert f"the results of it2 are in {out}" in lines[0], lines
    doc = json.loads((out / "metrics.json").read_text())
    assert list(doc["runs"]) == ["it2"] and doc["runs"]["it2"]["status"] == "ok"
    assert list(doc["errors"]) == [SLOW] and doc["errors"][SLOW].startswith("LimitExceeded: ")
    assert limit_text in doc["errors"][SLOW]
    rows = (out / "trajectory.csv").read_text().splitlines()[1:]
    assert rows and all(r.startswith("it2,") for r in rows)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["exit_status"] == 2 and manifest["complete"] and SLOW in manifest["stopped"]


def test_twin_run_step_limit_stops_that_controller_alone(plugdir, tmp_path, monkeypatch):
    monkeypatch.chdir(plugdir)
    out = tmp_path / "run"
    status, stdout, stderr = twin("run", "paper-exp1", "--controller", f"{SLOW},it2", *SHORT, "--step-limit", "0.05",
                                  "--out", out)
    assert status == 2, (stdout, stderr)
    assert_limited_run(out, stderr, "over limits.step_wall_s = 0.05 s (at t = 0.095 s)")
    assert "IT2" in stdout and f"wrote {out}/" in stdout
    status, stdout, stderr = twin("compare", out, out)  # the directory reads as a run's
    assert status == 0, stderr


def test_twin_run_limits_of_a_scenario_file_and_of_set(plugdir, tmp_path, monkeypatch):
    monkeypatch.chdir(plugdir)
    scenario = tmp_path / "slow.toml"
    scenario.write_text('name = "slow"\nduration = 0.5\n[initial]\ntheta = 0.2\n[video]\nenabled = false\n'
                        f'[controller]\nkinds = ["{SLOW}", "it2"]\n[limits]\nrun_wall_s = 0.4\n')
    out = tmp_path / "file"
    status, stdout, stderr = twin("run", scenario, "--out", out)
    assert status == 2, (stdout, stderr)
    assert_limited_run(out, stderr, "over limits.run_wall_s = 0.4 s")
    out = tmp_path / "set"  # --set limits... over the file's own
    status, stdout, stderr = twin("run", scenario, "--set", "limits.step_wall_s=0.05", "--set", "limits.run_wall_s=60",
                                  "--out", out)
    assert status == 2, (stdout, stderr)
    assert_limited_run(out, stderr, "over limits.step_wall_s = 0.05 s")
    out = tmp_path / "option"  # the option over the file's own
    status, stdout, stderr = twin("run", scenario, "--run-limit", "60", "--out", out)
    assert status == 0, (stdout, stderr)
    assert set(json.loads((out / "metrics.json").read_text())["runs"]) == {SLOW, "it2"}


def test_twin_run_with_every_controller_over_a_limit_writes_nothing(plugdir, tmp_path, monkeypatch):
    monkeypatch.chdir(plugdir)
    out = tmp_path / "none"
    status, stdout, stderr = twin("run", "paper-exp1", "--controller", SLOW, *SHORT, "--step-limit", "0.05",
                                  "--out", out)
    assert status == 2 and not out.exists(), (stdout, stderr)
    lines = error_lines(stderr)
    assert len(lines) == 1 and "controller limslowplug.Slow took" in lines[0], stderr
    assert "over limits.step_wall_s = 0.05 s" in lines[0]


def test_twin_check_honours_a_limit(plugdir, tmp_path, monkeypatch):
    monkeypatch.chdir(plugdir)
    status, stdout, stderr = twin("check", "paper-exp1", "--controller", SLOW, "--set", "duration=0.5",
                                  "--step-limit", "0.05", "--workers", "1")
    assert status == 1, (stdout, stderr)
    assert "ERROR" in stdout
    fails = [line for line in stderr.splitlines() if line.startswith("FAIL")]
    assert len(fails) == 1 and f"paper-exp1 {SLOW} seed 0: PluginError: controller limslowplug.Slow took" in fails[0]
    assert "over limits.step_wall_s = 0.05 s" in fails[0]


BAD = [
    (["--step-limit", "0"], "--step-limit: 0.0 is out of range; allowed in (0, 3600] s"),
    (["--step-limit", "abc"], "--step-limit: must be a number in (0, 3600] s, got 'abc'"),
    (["--step-limit", "inf"], "--step-limit: must be a finite number in (0, 3600] s, got inf"),
    (["--step-limit", "4000"], "--step-limit: 4000.0 is out of range; allowed in (0, 3600] s"),
    (["--run-limit", "-1"], "--run-limit: -1.0 is out of range; allowed in (0, 1e+06] s"),
    (["--run-limit", "[1]"], "--run-limit: must be a number in (0, 1e+06] s, got [1]"),
    (["--memory-limit", "nan"], "--memory-limit: must be a finite number in (0, 1e+06] MB, got nan"),
    (["--memory-limit", "2e6"], "--memory-limit: 2000000.0 is out of range; allowed in (0, 1e+06] MB"),
    (["--step-limit", "1", "--set", "limits.step_wall_s=2"],
     "--step-limit and --set limits.step_wall_s=... both set limits.step_wall_s; give one of them"),
    (["--run-limit", "1", "--set", "limits={run_wall_s=3}"],
     "--run-limit and --set limits=... both set limits.run_wall_s; give one of them"),
]


@pytest.mark.parametrize("command", ["run", "check", "sweep"])
@pytest.mark.parametrize("args,message", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_limit_options_are_one_line(command, args, message, tmp_path):
    extra = {"run": ["--out", tmp_path / "o"], "check": [], "sweep": ["--samples", "1", "--out", tmp_path / "o"]}
    status, stdout, stderr = twin(command, "paper-exp1", *args, *extra[command])
    assert status == 2 and stdout == "", (stdout, stderr)
    assert stderr == f"error: {message}\n"
    assert not (tmp_path / "o").exists()


def test_the_options_same_key_as_another_set_is_fine():
    from twin.commands.common import limit_overrides as _limit_overrides

    assert _limit_overrides(("limits.run_wall_s=5",), "0.5", None, None) == ("limits.run_wall_s=5",
                                                                               "limits.step_wall_s=0.5")
    assert _limit_overrides(("duration=1",), None, None, None) == ("duration=1",)
    assert _limit_overrides((), "1", "2", "3") == ("limits.step_wall_s=1.0", "limits.run_wall_s=2.0",
                                                   "limits.run_memory_mb=3.0")


def test_the_help_states_the_schemas_ranges_and_the_sweep_default():
    from twin.commands.common import LIMIT_OPTIONS
    from twin.scenarios.schema import _range, lookup
    from twin.sweep.runner import RUN_WALL_BASE_S, RUN_WALL_PER_SIMULATED_S

    for dest, flag, key, metavar, allowed, what in LIMIT_OPTIONS:
        assert _range(lookup(f"limits.{key}")) == f" in {allowed}", flag
    for command in ("run", "check", "sweep"):
        status, stdout, _ = twin(command, "--help")
        text = " ".join(stdout.split())
        assert status == 0
        assert "--step-limit SECONDS" in text and "--run-limit SECONDS" in text and "--memory-limit MB" in text
        assert "in (0, 3600] s" in text and "(10⁶ bytes)" in text
    status, stdout, _ = twin("sweep", "--help")
    assert f"{RUN_WALL_BASE_S:g} s + {RUN_WALL_PER_SIMULATED_S:g} × the simulated time" in " ".join(stdout.split())
