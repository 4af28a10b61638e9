"""Issue 31's rough edges a new user hit, each refused or fixed before any work is done."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from test_sensor_logs import _twin as _twin_call


def _twin(*args):
    code, out, err = _twin_call(*args)
    return SimpleNamespace(returncode=code, stdout=out, stderr=err)


@pytest.mark.parametrize("key, value, says", [
    ("video.width", "641", "video.width: 641 is odd; allowed: an even number of pixels"),
    ("video.height", "481", "video.height: 481 is odd; allowed: an even number of pixels"),
])
def test_an_odd_video_size_is_refused_before_the_run_naming_the_key(tmp_path, key, value, says):
    # before issue 31 the run simulated, wrote its data, then failed at the video naming no key
    r = _twin("run", "paper-exp1", "--controller", "lqr", "--duration", "0.2", "--set", f"{key}={value}",
              "--out", str(tmp_path / "run"))
    assert r.returncode == 2 and says in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("args, says", [
    (("run", "paper-exp1", "--controller", "it2", "--controller", "lqr"),
     "--controller is given more than once; allowed: once (several kinds go comma-separated"),
    (("run", "paper-exp1", "--video", "--no-video"), "--video and --no-video are both given; allowed: one of them"),
    (("run", "paper-exp1", "--seed=1", "--seed", "2"), "--seed is given more than once; allowed: once"),
    (("calibrate", "x", "--seed", "1", "--seed", "2"), "--seed is given more than once"),
])
def test_an_option_given_twice_is_refused(tmp_path, args, says):
    # click keeps the last silently: --controller it2 --controller lqr ran LQR alone before issue 31
    r = _twin(*args, "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and says in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "o").exists()


def test_repeatable_options_stay_repeatable(tmp_path):
    r = _twin("run", "paper-exp1", "--controller", "lqr", "--duration", "0.1", "--no-video",
              "--set", "plant.scale.m_b=1.1", "--set", "plant.scale.l=1.05", "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr


def test_a_failed_bound_prints_six_digits_and_a_real_unit():
    from twin.scenarios.expectations import Bound, Verdict

    def line(metric, measured, value, unit_op="<="):
        b = Bound(metric, metric, False, None, unit_op, value)
        return Verdict("it2", 0, b, measured, False).measured_with_unit()

    assert line("final_position_error_m", 0.012345678901234, 0.01) == "0.0123457 m"
    assert line("settling_time_s", None, 5.0) == "undefined"  # not "undefined s"
    assert line("nis_per_dof", 5.1312345, 2.0) == "5.13123"  # dimensionless: no "1"
    # six digits that would print the bound itself: every digit, so the failure is visible
    assert line("final_position_error_m", 0.0100000004, 0.01) == repr(0.0100000004) + " m"


def test_a_failed_pass_rate_names_the_seeds_and_the_bounds_they_broke():
    from twin.scenarios.expectations import evaluate, parse_expect

    bounds = parse_expect({"iae_theta": "<= 0.5", "seeds": {"pass_rate": ">= 0.9"}}, "expect")
    runs = {0: {"iae_theta": 0.2}, 1: {"iae_theta": 0.7}, 2: {"iae_theta": 0.3}}
    (rate,) = [v for v in evaluate(bounds, "it2", runs) if v.bound.metric == "pass_rate"]
    assert not rate.holds and rate.measured == pytest.approx(2 / 3)
    assert rate.detail == "2 of 3 seeds held every bound; seed 1 broke iae_theta <= 0.5 (0.7 rad·s)"


def test_set_reaches_a_quoted_key_of_a_plugins_parameters(tmp_path):
    from pathlib import Path

    examples = Path(__file__).resolve().parent.parent / "examples"
    code, out, err = _twin_call("run", "paper-exp1", "--controller", "my_plugins:StateFeedback", "--duration", "0.1",
                                "--no-video", "--set",
                                'controller.params."my_plugins:StateFeedback".k=[-1.3, -0.085, -0.06, -0.032]',
                                "--out", str(tmp_path / "o"), cwd=examples)
    assert code == 0, err
    import json

    params = json.loads((tmp_path / "o" / "metrics.json").read_text())["scenario"]["controller"]["params"]
    assert params == {"my_plugins:StateFeedback": {"k": [-1.3, -0.085, -0.06, -0.032]}}


def test_a_key_that_is_not_a_dotted_key_is_one_line(tmp_path):
    r = _twin("run", "paper-exp1", "--set", "a..b=1", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "--set a..b: not a dotted key" in r.stderr and len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("scale", ["0.3", "3"])
def test_a_body_that_reaches_the_floor_is_blamed_on_its_size_not_the_tilt(tmp_path, scale):
    r = _twin("run", "paper-exp1", "--set", f"plant.scale.l={scale}", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "plant.scale.l: the body's centre of mass" in r.stderr and "plant.scale.l from 0.49 to 2.39" in r.stderr
    assert "initial.theta" not in r.stderr


def _junit_cases(iae_by_seed: dict, rate: str):
    """The JUnit test cases (name → (failure text or None, system-out or None)) of one scenario
    whose runs measured ``iae_by_seed`` under ``iae_theta <= 0.5`` and ``pass_rate rate``."""
    import xml.etree.ElementTree as ET

    from twin.verify.check import CaseResult, CheckResult, write_junit
    from twin.scenarios.expectations import evaluate, failed, parse_expect

    bounds = parse_expect({"iae_theta": "<= 0.5", "seeds": {"pass_rate": rate}}, "expect")
    runs = {seed: {"iae_theta": v} for seed, v in iae_by_seed.items()}
    verdicts = evaluate(bounds, "it2", runs)
    case = CaseResult("s", "s.toml", "it2", tuple(runs), runs, {}, verdicts, failed(verdicts, bounds),
                      has_seed_bounds=True)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        root = ET.parse(write_junit(CheckResult([case]), Path(d) / "j.xml")).getroot()
    out = {}
    for tc in root.iter("testcase"):
        f, so = tc.find("failure"), tc.find("system-out")
        out[tc.get("name")] = (None if f is None else f.text, None if so is None else so.text)
    return root, out


def test_junit_fails_the_seed_that_broke_a_bound_when_the_pass_rate_fails():
    # before: every per-seed case passed, the seed that broke iae_theta included
    root, cases = _junit_cases({0: 0.2, 1: 0.7, 2: 0.3}, ">= 0.9")
    assert cases["it2 seed 1"][0] == "iae_theta <= 0.5: measured 0.7 rad·s"
    assert cases["it2 seed 0"] == (None, None) and cases["it2 seed 2"] == (None, None)
    over = cases["it2 over 3 seeds"][0]
    assert "pass_rate >= 0.9" in over and "seed 1 broke iae_theta <= 0.5 (0.7 rad·s)" in over
    assert root.get("failures") == "2" and root.get("tests") == "4"


def test_junit_says_a_broken_bound_the_pass_rate_allowed_without_failing_the_seed():
    # the check passes (2 of 3 held, pass_rate >= 0.6): its failure count must stay 0, as its exit status
    root, cases = _junit_cases({0: 0.2, 1: 0.7, 2: 0.3}, ">= 0.6")
    fail, said = cases["it2 seed 1"]
    assert fail is None and said.startswith("iae_theta <= 0.5: measured 0.7 rad·s (allowed by pass_rate >= 0.6")
    assert root.get("failures") == "0"


# ---- scenario inheritance: base = "NAME" or "FILE.toml" ---------------------------------------------------

def _write(path, text):
    path.write_text(text, encoding="utf-8")
    return path


def test_a_scenario_file_starts_from_a_built_in_and_changes_two_keys(tmp_path):
    from twin.scenarios.scenario import load_scenario

    f = _write(tmp_path / "heavier.toml", 'base = "paper-exp3"\nduration = 4.0\n[plant.scale]\nm_b = 1.2\n')
    mine, builtin = load_scenario(str(f)), load_scenario("paper-exp3")
    assert mine.name == "heavier" and mine.duration == 4.0
    assert mine.data["plant"]["scale"] == {**builtin.data["plant"]["scale"], "m_b": 1.2}
    # everything else is the built-in's, key for key
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "duration", "plant")}  # noqa: E731
    assert rest(mine.data) == rest(builtin.data)
    assert {k: v for k, v in mine.data["plant"].items() if k != "scale"} == \
        {k: v for k, v in builtin.data["plant"].items() if k != "scale"}


def test_a_base_file_is_found_beside_the_file_and_chains(tmp_path):
    from twin.scenarios.scenario import load_scenario

    (tmp_path / "lab").mkdir()
    _write(tmp_path / "lab" / "common.toml", 'base = "push-recovery"\nname = "common"\nseed = 7\n'
                                            '[expect]\nfell = false\n')
    f = _write(tmp_path / "lab" / "mine.toml", 'base = "common.toml"\nduration = 9.0\n')
    s = load_scenario(str(f))  # from another working directory: the base is relative to the file
    assert s.name == "mine" and s.seed == 7 and s.duration == 9.0
    assert s.data["pushes"] == load_scenario("push-recovery").data["pushes"]
    assert s.data["expect"] == {"fell": False}
    # [expect] is replaced whole, not merged: the bounds are judged as a set
    g = _write(tmp_path / "lab" / "loose.toml", 'base = "common.toml"\n[expect]\nsettling_time_s = "<= 9"\n')
    assert load_scenario(str(g)).data["expect"] == {"settling_time_s": "<= 9"}


@pytest.mark.parametrize("text, says", [
    ('base = "paper-exp9"\n', "base: 'paper-exp9' is neither a built-in scenario nor a .toml file; allowed: balboa-exp3, paper-exp1"),
    ('base = "nowhere.toml"\n', "base: "),
    ('base = 3\n', "base: 3 is not a name; allowed: a built-in scenario's name"),
    ('base = "me.toml"\n', "the scenarios name each other in a cycle"),
])
def test_a_bad_base_is_one_line_naming_it(tmp_path, text, says):
    f = _write(tmp_path / "me.toml", text)
    r = _twin("run", str(f), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and says in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "no such scenario file" in r.stderr or "nowhere" not in text


def test_a_derived_scenario_runs_and_records_the_whole_tree(tmp_path):
    import json

    f = _write(tmp_path / "short.toml", 'base = "paper-exp1"\nduration = 0.2\n')
    r = _twin("run", str(f), "--controller", "lqr", "--no-video", "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    recorded = json.loads((tmp_path / "o" / "metrics.json").read_text())["scenario"]
    assert recorded["name"] == "short" and recorded["duration"] == 0.2 and "base" not in recorded
    assert recorded["initial"]["theta"] == 0.48  # the built-in's tilt


# ---- plugins beside the scenario file -------------------------------------------------------------------

_BESIDE_TOML = ('base = "paper-exp1"\nduration = 0.3\n[controller]\nkinds = ["lab_ctrl_beside:StateFeedback"]\n'
                '[expect]\nfell = false\n')


@pytest.fixture
def lab(tmp_path):
    """A scenario file with its plugin module beside it, in tmp_path/lab (a module name no
    other test imports: the import is cached per process)."""
    import shutil
    from pathlib import Path

    d = tmp_path / "lab"
    d.mkdir()
    shutil.copy(Path(__file__).resolve().parent.parent / "examples" / "my_plugins.py", d / "lab_ctrl_beside.py")
    _write(d / "twin_beside.toml", _BESIDE_TOML)
    return d


def test_a_plugin_beside_the_scenario_file_is_found_from_another_directory(lab, tmp_path):
    # before: found only when it was also in the current directory
    code, out, err = _twin_call("check", str(lab / "twin_beside.toml"), cwd=tmp_path)
    assert code == 0 and "all bounds hold" in out, err


def test_under_pytest_a_missing_plugin_is_one_line_not_a_traceback(lab, tmp_path):
    import subprocess
    import sys

    (lab / "lab_ctrl_beside.py").rename(lab / "elsewhere.py")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(lab)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stdout
    assert "Traceback" not in r.stdout and "raise PluginError" not in r.stdout, r.stdout
    assert ("twin_beside.toml: controller: controller 'lab_ctrl_beside:StateFeedback': no module named "
            "'lab_ctrl_beside'; the module must be importable (on sys.path, installed, in the current directory or "
            "beside the scenario file)") in r.stdout.replace("\n", "")


# ---- an estimator that reads the ground truth -----------------------------------------------------------

_CHEAT = '''
from estimation.ideal import IdealEstimator


class Peek(IdealEstimator):
    """A plugin that quietly reads the ground truth."""
    name = "peek"
'''


@pytest.fixture
def peek(tmp_path):
    d = tmp_path / "lab"
    d.mkdir()
    _write(d / "lab_peek_truth.py", _CHEAT)
    _write(d / "peek.toml", 'base = "paper-exp1"\nduration = 0.3\n[controller]\nkinds = ["lqr"]\n'
                            '[sensors]\nestimator = "lab_peek_truth:Peek"\n[expect]\nfell = false\n')
    return d


def test_a_run_whose_estimator_reads_the_truth_says_so_in_its_output_and_metrics(peek, tmp_path):
    import json

    code, out, err = _twin_call("run", str(peek / "peek.toml"), "--no-video", "--out", str(tmp_path / "o"))
    assert code == 0, err
    assert "LQR: estimator lab_peek_truth:Peek reads the ground truth (reads_truth = True)" in out
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["runs"]["lqr"]["estimator_reads_truth"] is True


def test_twin_check_refuses_an_estimator_that_reads_the_truth_unless_the_scenario_is_a_reference(peek, tmp_path):
    code, out, err = _twin_call("check", str(peek / "peek.toml"))
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "estimator 'lab_peek_truth:Peek' reads the ground truth (reads_truth = True)" in err
    assert "reference = true" in err
    ref = _write(peek / "ref.toml", 'base = "peek.toml"\nreference = true\n')
    code, out, err = _twin_call("check", str(ref))
    assert code == 0 and "all bounds hold" in out, err


def test_a_real_estimators_metrics_carry_no_truth_flag(tmp_path):
    import json

    code, out, err = _twin_call("run", "paper-exp1", "--controller", "lqr", "--duration", "0.2", "--no-video",
                                "--out", str(tmp_path / "o"))
    assert code == 0 and "reads the ground truth" not in out, err
    assert "estimator_reads_truth" not in json.loads((tmp_path / "o" / "metrics.json").read_text())["runs"]["lqr"]


# ---- parameters no controller uses; a payload on nothing --------------------------------------------------

def test_parameters_for_a_controller_never_run_are_refused(tmp_path):
    # before: silently ignored (a typo in the kind, or a controller taken out of the list)
    r = _twin("run", "paper-exp1", "--controller", "it2", "--duration", "0.1", "--no-video",
              "--set", "controller.params.lqr={}", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert ("controller.params.lqr: controller 'lqr' is never run (this run's: it2; controller.kinds: it2, t1), so "
            "its parameters would be ignored") in r.stderr
    assert not (tmp_path / "o").exists()


def test_parameters_for_a_listed_controller_left_out_by_controller_are_kept(tmp_path):
    f = _write(tmp_path / "s.toml", 'base = "paper-exp1"\nduration = 0.1\n[controller]\nkinds = ["it2", "lqr"]\n'
                                    '[controller.params.lqr]\n')
    r = _twin("run", str(f), "--controller", "it2", "--no-video", "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr


def test_a_sweep_refuses_parameters_for_a_controller_it_never_runs(tmp_path):
    r = _twin("sweep", "paper-exp1", "--controller", "it2", "--samples", "1", "--set", "controller.params.lqr={}",
              "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "controller.params.lqr: controller 'lqr' is never run" in r.stderr, r.stderr


@pytest.mark.parametrize("position, gap", [("[0.5, 0, 0.1]", "0.46 m"), ("[0, 0.4, 0.1]", "0.268 m"),
                                           ("[0, 0, 0.45]", "0.302 m")])
def test_a_payload_far_outside_the_body_is_refused(tmp_path, position, gap):
    r = _twin("run", "paper-exp1", "--duration", "0.1", "--no-video", "--set", "plant.payload_mass=20",
              "--set", f"plant.payload_position={position}", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"plant.payload_position: {position} m is {gap} outside the body box; allowed: within 0.1 m of it" in r.stderr


def test_a_payload_on_the_body_or_beside_it_runs(tmp_path):
    r = _twin("run", "paper-exp1", "--controller", "lqr", "--duration", "0.1", "--no-video",
              "--set", "plant.payload_mass=0.3", "--set", "plant.payload_position=[0.12, 0, 0.1]",
              "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr


# ---- Ctrl-C: 130 from every command (twin run's directory: tests/test_rundir.py) ---------------------------

def test_ctrl_c_during_twin_check_is_130_with_one_line_not_1(tmp_path):
    import signal

    from test_golden import write_short
    from test_rundir import _no_process_left, _stop

    f = write_short(tmp_path)
    code, out, err, sid = _stop(["check", f, "--seeds", "2", "--workers", "1"], tmp_path, "check-run", signal.SIGINT)
    # 1 is a failed bound's status: an interrupted check must not read as one
    said = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("  ")]  # progress bars: indented
    assert code == 130 and said == ["interrupted: SIGINT"], err
    _no_process_left(sid)


def test_twin_checks_table_shows_each_measured_value_with_its_unit():
    from twin.verify.check import CaseResult, CheckResult, format_table
    from twin.scenarios.expectations import evaluate, failed, parse_expect

    bounds = parse_expect({"iae_theta": "<= 0.5", "settling_time_s": "<= 2", "rejected_measurements": "== 0"},
                          "expect")
    runs = {0: {"iae_theta": 0.123456789, "settling_time_s": 0.7, "rejected_measurements": 0}}
    verdicts = evaluate(bounds, "it2", runs)
    table = format_table(CheckResult([CaseResult("s", "s.toml", "it2", (0,), runs, {}, verdicts,
                                                 failed(verdicts, bounds))]))
    assert "0.1235 rad·s" in table and "0.7 s " in table
    assert " 0 1" not in table  # dimensionless: no unit "1"
