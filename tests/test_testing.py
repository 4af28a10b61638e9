"""twin.verify.testing and the pytest plugin: a user's own regression tests on the twin."""
from __future__ import annotations

import textwrap

import pytest

from twin.scenarios import load_scenario

from twin.errors import TwinError
from twin.scenarios.scenario import builtin_names
from twin.verify.testing import assert_expectations, check

pytest_plugins = ["pytester"]

SHORT = ["duration=1.5", "initial.theta=0.2"]


def test_assert_expectations_passes_and_returns_the_result():
    result = assert_expectations("paper-exp1", controller="lqr", overrides=SHORT,
                                 expect={"fell": False, "settling_time_s": "<= 1.5"})
    (case,) = result.cases
    assert case.passed and case.controller == "lqr" and case.metrics[0]["settling_time_s"] < 1.5


def test_a_failed_bound_is_a_readable_assertion_error():
    with pytest.raises(AssertionError) as info:
        assert_expectations("paper-exp1", controller="it2", overrides=SHORT,
                            expect={"fell": False, "settling_time_s": "<= 0.1", "lqr": {"iae_theta": "<= 0"}})
    text = str(info.value)
    assert text.startswith("twin expectations failed\n") and "settling_time_s <= 0.1" in text
    assert "FAIL paper-exp1 it2 seed 0: settling_time_s = " in text and "iae_theta" not in text  # lqr's bound not it2's


def test_the_estimator_and_the_seeds_are_the_callers():
    result = check("paper-exp1", controller=["it2"], estimator="complementary", seeds=2, overrides=SHORT,
                   expect={"fell": False})
    (case,) = result.cases
    assert case.seeds == (0, 1) and {m["sensing"] for m in case.metrics.values()} == {"complementary"}


def test_a_scenario_without_expectations_is_a_user_error():
    with pytest.raises(TwinError, match="no \\[expect\\] table and no expect= given"):
        check("paper-exp1", overrides=["expect={}"])


def test_the_plugin_collects_twin_files_and_a_users_test_file(pytester):
    pytester.makefile(".toml", twin_ok=textwrap.dedent('''
        duration = 1.5
        [initial]
        theta = 0.2
        [controller]
        kinds = ["lqr"]
        [expect]
        fell = false
        settling_time_s = "<= 1.5"
    '''), twin_strict=textwrap.dedent('''
        duration = 1.5
        [initial]
        theta = 0.2
        [controller]
        kinds = ["it2", "lqr"]
        [expect]
        settling_time_s = "<= 0.6"
    '''), other=textwrap.dedent('''
        duration = 1.5
    '''))
    pytester.makepyfile(test_mine=textwrap.dedent('''
        from twin.verify.testing import assert_expectations

        def test_lqr_balances_paper_exp1():
            assert_expectations("paper-exp1", controller="lqr", overrides=["duration=2"],
                                expect={"fell": False, "|final_theta_rad|": "<= 0.01"})
    '''))
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    # twin_ok: lqr passes; twin_strict: it2 (0.505 s) passes, lqr (0.64 s) fails; other.toml is not a twin_ file
    result.assert_outcomes(passed=3, failed=1)
    result.stdout.fnmatch_lines(["*FAIL twin_strict lqr seed 0: settling_time_s = * s, bound settling_time_s <= 0.6*"])


def test_twin_scenarios_builtin_makes_an_item_per_scenario_and_controller(pytester):
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--twin-scenarios", "builtin", "--collect-only",
                                           "-q")
    lines = [l for l in result.stdout.lines if l.startswith("twin:")]
    assert sorted(lines) == sorted(f"twin:{n}::{k}" for n in builtin_names()
                                   for k in load_scenario(n).data["controller"]["kinds"])
    run = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--twin-scenarios", "builtin", "-k", "paper-exp1")
    run.assert_outcomes(passed=2)


@pytest.mark.parametrize("args, message", [
    (["--twin-scenarios", "nonexist"], "--twin-scenarios: 'nonexist' is neither a built-in scenario"),
    (["--twin-seeds", "0"], "--twin-seeds must be at least 1"),
])
def test_bad_plugin_options_are_usage_errors(pytester, args, message):
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", *args)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert message in result.stderr.str() and "Traceback" not in result.stderr.str()


def test_a_twin_file_without_expectations_is_one_collection_error(pytester):
    pytester.makefile(".toml", twin_plain="duration = 1.0\n")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*twin_plain.toml: a twin_*.toml file needs an ?expect? table*"])
    assert "Traceback" not in result.stdout.str()
