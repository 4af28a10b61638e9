"""Expectations in scenarios and 'twin check': bounds parsed and judged, built-ins pass, broken
controllers and estimators fail naming what broke, JUnit output, bad input."""
from __future__ import annotations

import math
import textwrap
import xml.etree.ElementTree as ET

import pytest

from twin.scenarios import load_scenario
from click.testing import CliRunner

from twin.cli import main
from twin.scenarios.expectations import ALL, SEEDS, ExpectError, evaluate, failed, parse_expect
from twin.scenarios.scenario import builtin_names

BROKEN = textwrap.dedent('''
    import math

    from twin.registry import build_controller


    class FlippedPosition:
        """The IT2 cascade with the sign of its position error flipped (a regression to catch):
        it drives to −p_d instead of p_d."""

        signals = ("u", "theta_off", "u_alpha")

        def __init__(self, context):
            self.cascade = build_controller("it2", None, context)

        def reset(self, targets):
            self.cascade.reset(targets)

        def __call__(self, estimate, targets):
            flipped = None if targets.position is None else -targets.position
            return self.cascade(estimate, type(targets)(flipped, targets.heading))


    class GyroOnly:
        """Integrates the gyro's pitch rate and never looks at the accelerometer: its bias is ignored."""

        def __init__(self, context):
            self.dt = 1.0 / context.control_rate
            self.r_b = context.model.r / context.model.b

        def start(self, m):
            self.theta = math.atan2(-m.accel[0], m.accel[2])
            self.theta0, self.rate, self.enc, self.psi = self.theta, m.gyro[1], (0.0, 0.0), 0.0
            return self._out(0.0)

        def step(self, m, command):
            if m.gyro is not None:
                self.rate = m.gyro[1]
            self.theta += self.rate * self.dt
            if m.encoders is not None:
                self.enc = tuple(m.encoders)
            psi = 0.5 * (self.enc[0] + self.enc[1]) + self.theta - self.theta0
            rate, self.psi = (psi - self.psi) / self.dt, psi
            return self._out(rate)

        def _out(self, psi_dot):
            return (self.theta, self.rate, self.psi, psi_dot, self.r_b * 0.5 * (self.enc[1] - self.enc[0]), 0.0)
''')


def twin(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.stdout, r.stderr


# ---- the [expect] table -------------------------------------------------------------------------
def test_bounds_parse_from_the_toml_form():
    b = parse_expect({"fell": False, "|final_position_error_m|": "<= 0.02", "settling_time_s": "< 9",
                      "lqr": {"iae_theta": ">= 0.1"}, "seeds": {"pass_rate": ">= 0.95", "p95(iae_theta)": "<= 0.8"}})
    assert [str(x) for x in b[ALL]] == ["fell == false", "|final_position_error_m| <= 0.02", "settling_time_s < 9"]
    assert b[ALL][1].absolute and b[ALL][1].metric == "final_position_error_m" and b[ALL][1].unit == "m"
    assert [str(x) for x in b["lqr"]] == ["iae_theta >= 0.1"]
    assert [(x.metric, x.stat) for x in b[SEEDS]] == [("pass_rate", None), ("iae_theta", "p95")]


@pytest.mark.parametrize("table, message", [
    ({"speed": "<= 1"}, "expect.speed: unknown metric 'speed'; allowed: fell, settling_time_s"),
    ({"iae_theta": "about 1"}, "'about 1' is not a bound; allowed: a string \"<op> number\""),
    ({"iae_theta": 0.5}, "0.5 is not a bound"),
    ({"fell": "no"}, "fell takes true or false"),
    ({"|iae_theta": "<= 1"}, "is not a bound's quantity"),
    ({"p95(iae_theta)": "<= 1"}, "a statistic over seeds (p95) belongs in [expect.seeds]"),
    ({"seeds": {"iae_theta": "<= 1"}}, "needs a statistic over seeds here"),
    ({"seeds": {"p100(iae_theta)": "<= 1"}}, "is not a bound's quantity"),
    ({"seeds": {"pass_rate": ">= 95"}}, "a pass rate is a fraction in [0, 1]"),
    ({"it3": {"fell": False}}, "controller 'it3' is neither a built-in"),
])
def test_bad_bounds_are_one_line_errors_naming_the_key(table, message):
    with pytest.raises(ExpectError) as info:
        parse_expect(table)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_verdicts_on_runs_and_over_seeds():
    bounds = parse_expect({"fell": False, "|final_position_error_m|": "<= 0.02", "settling_time_s": "<= 9",
                           "seeds": {"mean(iae_theta)": "<= 0.6", "max(settling_time_s)": "<= 20"}})
    runs = {0: {"fell": False, "final_position_error_m": -0.01, "settling_time_s": 8.0, "iae_theta": 0.5},
            1: {"fell": False, "final_position_error_m": 0.03, "settling_time_s": None, "iae_theta": 0.9}}
    v = evaluate(bounds, "it2", runs)
    bad = {(x.seed, str(x.bound)) for x in failed(v, bounds)}
    # seed 1: |−| 0.03 > 0.02, never settled (undefined fails); over seeds: mean IAE 0.7, max settling +∞
    assert bad == {(1, "|final_position_error_m| <= 0.02"), (1, "settling_time_s <= 9"),
                   (None, "mean(iae_theta) <= 0.6"), (None, "max(settling_time_s) <= 20")}
    assert next(x for x in v if x.seed is None and x.bound.stat == "max").measured == math.inf


def test_a_pass_rate_judges_the_runs_bounds_over_seeds():
    runs = {s: {"fell": s == 3} for s in range(10)}  # one of ten falls
    loose = parse_expect({"fell": False, "seeds": {"pass_rate": ">= 0.9"}})
    strict = parse_expect({"fell": False, "seeds": {"pass_rate": ">= 0.95"}})
    assert failed(evaluate(loose, "t1", runs), loose) == []
    (bad,) = failed(evaluate(strict, "t1", runs), strict)
    assert bad.bound.metric == "pass_rate" and bad.measured == pytest.approx(0.9)
    plain = parse_expect({"fell": False})  # without a pass rate, every seed must hold
    assert [x.seed for x in failed(evaluate(plain, "t1", runs), plain)] == [3]


def test_percentiles_interpolate_between_order_statistics():
    bounds = parse_expect({"seeds": {"p95(iae_theta)": "<= 1", "median(iae_theta)": "<= 1"}})
    runs = {s: {"iae_theta": float(s)} for s in range(21)}  # 0 … 20
    got = {x.bound.stat: x.measured for x in evaluate(bounds, "it2", runs)}
    assert got == {"p95": pytest.approx(19.0), "median": pytest.approx(10.0)}


# ---- twin check ----------------------------------------------------------------------------------
def test_every_built_in_passes_its_expectations(tmp_path):
    """The built-ins' own bounds hold today (their margins are stated in the files)."""
    junit = tmp_path / "check.xml"
    status, out, err = twin("check", *builtin_names(), "--workers", "2", "--junit", junit)
    assert status == 0, out + err
    runs = sum(len(load_scenario(n).data["controller"]["kinds"]) for n in builtin_names())  # each its kinds
    assert runs >= 2 * len(builtin_names())
    assert f"{runs} checks ({runs} runs)" in out and "all bounds hold" in out
    root = ET.parse(junit).getroot()
    cases = root.findall(".//testcase")
    assert {(c.get("classname"), c.get("name")) for c in cases} == {
        (n, f"{k} seed 0") for n in builtin_names() for k in load_scenario(n).data["controller"]["kinds"]}
    assert root.get("tests") == str(len(cases)) and root.get("failures") == "0" and not root.findall(".//failure")


@pytest.fixture()
def broken(tmp_path, monkeypatch):
    (tmp_path / "broken_plugins.py").write_text(BROKEN, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_a_flipped_position_loop_fails_naming_scenario_controller_metric_value_and_bound(broken):
    junit = broken / "j.xml"
    status, out, err = twin("check", "paper-exp2", "--controller", "broken_plugins:FlippedPosition,it2",
                            "--workers", "1", "--junit", junit)
    assert status == 1, out + err
    line = next(l for l in err.splitlines() if "|final_position_error_m|" in l)
    assert line.startswith("FAIL paper-exp2 broken_plugins:FlippedPosition seed 0: |final_position_error_m| = ")
    measured = float(line.split(" = ")[1].split()[0])
    assert measured == pytest.approx(1.4, abs=0.05) and line.endswith("m, bound |final_position_error_m| <= 0.01")
    assert not any("FAIL paper-exp2 it2" in l for l in err.splitlines())  # the unbroken one still passes
    root = ET.parse(junit).getroot()
    assert root.get("failures") == "1" and root.get("tests") == "2"
    (failure,) = root.findall(".//failure")
    assert "|final_position_error_m| <= 0.01: measured" in failure.get("message")


def test_an_estimator_that_ignores_the_gyro_bias_fails(broken):
    status, out, err = twin("check", "paper-exp1", "--controller", "it2", "--workers", "1",
                            "--set", "sensors.estimator='broken_plugins:GyroOnly'")
    assert status == 1, out + err
    (line,) = [l for l in err.splitlines() if l.startswith("FAIL paper-exp1 it2 seed 0: estimator_theta_rmse_rad = ")]
    # measured 0.41 rad: the uncorrected gyro bias drifts the estimate until the robot, balanced
    # on it, falls (fell is a failure too); the EKF's is 0.0006
    assert float(line.split(" = ")[1].split()[0]) > 0.03 and line.endswith("bound estimator_theta_rmse_rad <= 0.01")


def test_statistics_over_seeds_and_the_table(tmp_path):
    toml = tmp_path / "short.toml"
    toml.write_text(textwrap.dedent('''
        duration = 2.0
        [initial]
        theta = 0.2
        [controller]
        kinds = ["it2"]
        [expect]
        fell = false
        [expect.seeds]
        pass_rate = ">= 0.99"
        "p95(iae_theta)" = "<= 0.001"
    '''), encoding="utf-8")
    status, out, err = twin("check", toml, "--seeds", "3", "--workers", "2")
    assert status == 1, out + err
    assert "fell == false" in out and "(worst of 3 seeds)" in out
    assert "FAIL short it2 over 3 seeds: p95(iae_theta) = " in err and "pass_rate" not in err


@pytest.mark.parametrize("args, message", [
    (["check"], "twin check needs at least one SCENARIO, FILE or DIR"),
    (["check", "paper-exp1", "--set", "expect={speed='<= 1'}"], "expect.speed: unknown metric 'speed'"),
    (["check", "paper-exp1", "--set", "expect={}"], "no [expect] table, so nothing to check"),
    (["check", "paper-exp1", "--controller", "it3"], "controller 'it3' is neither a built-in"),
    (["check", "nope"], "'nope' is neither a built-in scenario nor a .toml file"),
])
def test_bad_input_is_one_line_and_exit_2(args, message):
    status, out, err = twin(*args)
    assert status == 2, (out, err)
    lines = [l for l in err.splitlines() if l.startswith("error: ")]
    assert len(lines) == 1 and message in lines[0], err


def test_a_directory_checks_the_files_with_expectations(tmp_path):
    d = tmp_path / "scenarios"
    d.mkdir()
    (d / "a.toml").write_text('duration = 1.0\n[controller]\nkinds = ["lqr"]\n[expect]\nfell = false\n',
                              encoding="utf-8")
    (d / "b.toml").write_text('duration = 1.0\n', encoding="utf-8")
    status, out, err = twin("check", d, "--workers", "1")
    assert status == 0, out + err
    assert f"skipped {d / 'b.toml'}: no [expect] table" in out and "1 check (1 run)" in out


# ---- found in review -----------------------------------------------------------------------------
def test_an_undefined_value_sits_on_the_failing_side_of_a_statistic():
    from twin.scenarios.expectations import _stat

    assert _stat("median", [1.0, 2.0, None]) == 2.0 and _stat("p50", [1.0, None, 3.0]) == 3.0  # not NaN
    cap = parse_expect({"seeds": {"median(settling_time_s)": "<= 5"}})
    runs = {0: {"settling_time_s": 1.0}, 1: {"settling_time_s": 2.0}, 2: {"settling_time_s": None}}
    assert failed(evaluate(cap, "lqr", runs), cap) == []  # the median of 1, 2, never is 2
    floor = parse_expect({"seeds": {"min(final_theta_rad)": ">= -0.1"}})
    (bad,) = failed(evaluate(floor, "lqr", {0: {"final_theta_rad": None}}), floor)
    assert bad.measured == -math.inf  # an undefined value does not pass a floor


@pytest.mark.parametrize("table, message", [
    ({"duration_s": "== 0.7"}, "== on a real-valued metric holds only by accident of rounding"),
    ({"iae_theta": "<= 1e400"}, "is not a finite number"),
    ({"|fell|": False}, "|fell| has no meaning"),
])
def test_bounds_that_cannot_mean_what_they_say_are_refused(table, message):
    with pytest.raises(ExpectError, match=message.replace("|", "\\\\|")):
        parse_expect(table)
    assert parse_expect({"rejected_measurements": "== 0"})  # whole numbers may be compared exactly


def test_record_and_golden_together_and_a_missing_golden_dir_are_user_errors(tmp_path):
    for args, message in ((["--record", tmp_path, "--golden", tmp_path], "--record and --golden together"),
                          (["--golden", tmp_path / "nope"], "no such directory")):
        status, out, err = twin("check", "paper-exp1", "--controller", "lqr", *args)
        assert status == 2 and message in err, (out, err)


def test_two_scenarios_with_one_name_are_refused(tmp_path):
    for f in ("a.toml", "b.toml"):
        (tmp_path / f).write_text('name = "same"\nduration = 1.0\n[expect]\nfell = false\n', encoding="utf-8")
    status, out, err = twin("check", tmp_path)
    assert status == 2 and "two scenarios are named 'same'" in err, (out, err)


def test_recorded_counts_only_the_files_written(tmp_path):
    status, out, err = twin("check", "paper-exp1", "--controller", "lqr", "--set", "duration=0.5", "--workers", "1",
                            "--record", tmp_path / "g")
    assert "recorded 1 golden trajectories" in out and len(list((tmp_path / "g").rglob("*.npz"))) == 1
