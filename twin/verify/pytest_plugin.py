"""pytest plugin (entry point ``pytest11``): scenario files with an ``[expect]`` table become tests.

Two ways in, one test item per scenario and controller (its seeds inside), or per log and
estimator for a ``twin_*.toml`` that names a sensor log (``log = "DIR"``, :mod:`twin.logs.expect`):

* ``pytest --twin-scenarios DIR|FILE|builtin`` (repeatable): the ``.toml`` files of a
  directory that have an ``[expect]`` table, a file, or ``builtin`` for every built-in
  scenario; ``--twin-seeds N`` checks N seeds each;
* the naming rule: files called ``twin_*.toml`` under the test paths are collected like
  test modules.

A failing item's report is the table of every bound with its measured value, then one line
per failed bound (scenario, controller, seed, metric, measured value and bound). Nothing
is imported from the twin until a scenario is collected, so the plugin costs nothing in a
session that does not use it.
"""
from __future__ import annotations

from pathlib import Path

import pytest

NAMING_RULE = "twin_*.toml"
_SCENARIOS = pytest.StashKey[list]()  # the --twin-scenarios, loaded once at configure time


def pytest_addoption(parser):
    group = parser.getgroup("twin", "mtwip-twin scenario checks")
    group.addoption("--twin-scenarios", action="append", default=[], metavar="DIR|FILE|builtin",
                    help="check these scenarios' [expect] tables as tests ('builtin': every built-in scenario)")
    group.addoption("--twin-seeds", type=int, default=1, metavar="N", help="seeds per scenario and controller")


def pytest_configure(config):
    """Bad --twin-* options are usage errors (one message, pytest's exit status 4), not tracebacks."""
    if config.getoption("twin_seeds", 1) < 1:
        raise pytest.UsageError(f"--twin-seeds must be at least 1, got {config.getoption('twin_seeds')}")
    targets = config.getoption("twin_scenarios", [])
    if targets:
        from twin.errors import TwinError  # optional: the twin loads only when its tests do

        try:
            config.stash[_SCENARIOS] = _scenarios(_expand(targets))
        except TwinError as exc:
            raise pytest.UsageError(f"--twin-scenarios: {exc}") from None


def _expand(targets) -> list[str]:
    from twin.scenarios.scenario import builtin_names  # optional: the twin loads only when its tests do

    names = []
    for t in targets:
        names += builtin_names() if t == "builtin" else [t]
    return names


def pytest_collect_file(parent, file_path):
    if file_path.suffix == ".toml" and file_path.match(NAMING_RULE):
        return TwinScenarioFile.from_parent(parent, path=file_path)
    return None


def pytest_collection_modifyitems(session, config, items):
    scenarios = config.stash.get(_SCENARIOS, None)
    if not scenarios:
        return
    # a twin_*.toml under the test paths is collected by the naming rule already: not twice
    have = {(str(it.scenario.source), it.kind) for it in items if isinstance(it, TwinCheckItem)}
    for scenario in scenarios:
        for kind in scenario.controllers:
            if (str(scenario.source), kind) in have:
                continue
            items.append(TwinCheckItem.from_parent(session, name=f"{scenario.name}::{kind}",
                                                   nodeid=f"twin:{scenario.name}::{kind}", scenario=scenario,
                                                   kind=kind))



def _scenarios(names):
    from twin.verify.check import collect  # optional: the twin loads only when its tests do

    return collect(names)[0]


class TwinScenarioFile(pytest.File):
    """A ``twin_*.toml`` scenario file: one item per controller of ``controller.kinds``."""

    def collect(self):
        from twin.errors import TwinError  # optional: the twin loads only when its tests do
        from twin.logs.expect import is_log_target, load_log_check  # optional: the twin loads only when its tests do
        from twin.scenarios import load_scenario  # optional: the twin loads only when its tests do

        if is_log_target(self.path):  # log = "DIR": bounds on estimators replayed on a sensor log
            try:
                check = load_log_check(self.path)
            except TwinError as exc:
                raise TwinCheckFailure(str(exc)) from None
            for kind in check.kinds:
                yield TwinLogItem.from_parent(self, name=kind, check=check, kind=kind)
            return
        try:
            scenario = load_scenario(str(self.path))
        except TwinError as exc:
            raise TwinCheckFailure(str(exc)) from None
        if not scenario.expect:
            raise TwinCheckFailure(f"{self.path}: a {NAMING_RULE} file needs an [expect] table (bounds such as "
                                   "fell = false)")
        for kind in scenario.controllers:
            yield TwinCheckItem.from_parent(self, name=kind, scenario=scenario, kind=kind)

    def repr_failure(self, excinfo):
        if isinstance(excinfo.value, TwinCheckFailure):
            return str(excinfo.value)
        return super().repr_failure(excinfo)


class TwinCheckFailure(Exception):
    """A check that failed; its message is the report."""


class _CheckItem(pytest.Item):
    """A check whose failure report is the table of bounds and the failed ones (``_result()``)."""

    def runtest(self):
        from twin.errors import TwinError  # optional: the twin loads only when its tests do
        from twin.verify.testing import report  # optional: the twin loads only when its tests do

        try:
            result = self._result()
        except TwinError as exc:  # a plugin not found, a bad key: one line, as twin check says it
            raise TwinCheckFailure(f"error: {exc}") from None
        if not result.passed:
            raise TwinCheckFailure(report(result))

    def repr_failure(self, excinfo):
        if isinstance(excinfo.value, TwinCheckFailure):
            return str(excinfo.value)
        return super().repr_failure(excinfo)


class TwinCheckItem(_CheckItem):
    """One scenario and controller, over ``--twin-seeds`` seeds."""

    def __init__(self, *, scenario, kind, **kwargs):
        super().__init__(**kwargs)
        self.scenario, self.kind = scenario, kind

    def _result(self):
        from twin.verify.check import run_checks  # optional: the twin loads only when its tests do

        return run_checks([self.scenario], [self.kind], self.config.getoption("twin_seeds"), 1)

    def reportinfo(self):
        return Path(self.scenario.source.split(" with --set ")[0]), None, f"{self.scenario.name} {self.kind}"


class TwinLogItem(_CheckItem):
    """One estimator replayed on a sensor log, judged by the log's bounds (:mod:`twin.logs.expect`)."""

    def __init__(self, *, check, kind, **kwargs):
        super().__init__(**kwargs)
        self.check, self.kind = check, kind

    def _result(self):
        from dataclasses import replace

        from twin.verify.check import CheckResult, run_log_checks  # optional: the twin loads only when its tests do

        return CheckResult(run_log_checks([replace(self.check, kinds=(self.kind,))]))

    def reportinfo(self):
        return Path(self.check.source), None, f"{self.check.name} {self.kind}"
