"""Regression tests with the twin, from a user's own test file.

::

    from twin.verify.testing import assert_expectations

    def test_my_filter_keeps_the_robot_up():
        assert_expectations("paper-exp3", controller="it2", estimator="my_filters:Tuned",
                            expect={"fell": False, "|final_position_error_m|": "<= 0.02"})

:func:`check` runs a scenario (a built-in name, a ``.toml`` file or a loaded
:class:`~twin.scenarios.scenario.Scenario`) with the given controller(s) and estimator on
one or more seeds and judges the runs by the scenario's ``[expect]`` table (or ``expect``,
which replaces it); :func:`assert_expectations` raises an ``AssertionError`` whose message
is the table of every bound with its measured value and the failing lines. The pytest
plugin (:mod:`twin.verify.pytest_plugin`) turns scenario files into test items the same way.
"""
from __future__ import annotations

from twin.errors import TwinError
from twin.scenarios import load_scenario
from twin.scenarios.scenario import Scenario
from twin.verify.check import CheckResult, failure_lines, format_table, run_checks


def check(scenario, controller=None, estimator: str | None = None, seeds: int = 1, overrides=(), expect=None,
          workers: int = 1) -> CheckResult:
    """Run ``scenario`` with ``controller`` (a kind, a list of kinds, or None: the scenario's
    ``controller.kinds``) and ``estimator`` (a kind; None: the scenario's) on ``seeds`` seeds,
    and judge the runs by its ``[expect]`` table, or by ``expect`` (a dict in the same form)."""
    if expect is not None and not expect:
        raise TwinError("expect= is empty: give at least one bound, e.g. {'fell': False}")
    extra = list(overrides)
    if estimator is not None:
        extra.append(f"sensors.estimator={estimator!r}")
    if isinstance(scenario, Scenario):
        if extra or expect is not None:
            scenario = load_scenario(_source_name(scenario), list(scenario.overrides) + extra + _expect(expect))
    else:
        scenario = load_scenario(str(scenario), extra + _expect(expect))
    if not scenario.expect:
        raise TwinError(f"{scenario.source}: no [expect] table and no expect= given, so nothing to check")
    kinds = [controller] if isinstance(controller, str) else controller
    return run_checks([scenario], kinds, seeds, workers)


def _expect(expect) -> list[str]:
    if expect is None:
        return []
    import json

    # an inline TOML table; JSON's strings and numbers are TOML's, true/false too
    items = ", ".join(f"{json.dumps(k)} = {json.dumps(v)}" if not isinstance(v, dict) else
                      f"{json.dumps(k)} = {{{', '.join(f'{json.dumps(a)} = {json.dumps(b)}' for a, b in v.items())}}}"
                      for k, v in expect.items())
    return [f"expect={{{items}}}"]


def _source_name(scenario) -> str:
    src = scenario.source.split(" with --set ")[0]
    return src.removeprefix("built-in scenario ")


def report(result: CheckResult) -> str:
    """The table of bounds and measured values, then one line per failure."""
    return "\n".join([format_table(result), *failure_lines(result)])


def assert_expectations(scenario, controller=None, estimator: str | None = None, seeds: int = 1, overrides=(),
                        expect=None, workers: int = 1) -> CheckResult:
    """:func:`check`, raising ``AssertionError`` with the report if any bound fails."""
    result = check(scenario, controller, estimator, seeds, overrides, expect, workers)
    if not result.passed:
        raise AssertionError("twin expectations failed\n" + report(result))
    return result


__all__ = ["assert_expectations", "check", "report"]
