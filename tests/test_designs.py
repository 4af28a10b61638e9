"""The design store (twin.controllers.designs): one design per inputs, held in the process,
kept on disk when the cache is on, the same numbers as a solve."""
from __future__ import annotations

from dataclasses import replace

import pytest

from twin.controllers import design_cache, designs
from twin.controllers.lmi import NOMINAL_DESIGN, design_balance_gains
from twin.errors import TwinError
from twin.params import NOMINAL


@pytest.fixture(autouse=True)
def empty_store(tmp_path, monkeypatch):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path))
    designs.forget()
    yield
    designs.forget()


def test_a_design_is_solved_once_and_held(tmp_path):
    a = designs.balance_design(**NOMINAL_DESIGN, cache=True)
    assert len(list(tmp_path.glob("lmi-*.json"))) == 1  # kept on disk
    b = designs.balance_design(**NOMINAL_DESIGN, cache=True)
    assert b is a  # held: not even read from disk again
    fresh = design_balance_gains(**NOMINAL_DESIGN)
    assert fresh.gains.tobytes() == a.gains.tobytes() and fresh.P.tobytes() == a.P.tobytes()


def test_without_the_disk_cache_nothing_is_written_and_the_design_is_still_held(tmp_path):
    a = designs.balance_design(**NOMINAL_DESIGN, cache=False)
    assert not list(tmp_path.glob("lmi-*.json"))
    assert designs.balance_design(**NOMINAL_DESIGN, cache=False) is a


def test_a_new_process_reads_the_disk_cache():
    a = designs.balance_design(**NOMINAL_DESIGN, cache=True)
    designs.forget()  # as a new process
    b = designs.balance_design(**NOMINAL_DESIGN, cache=True)
    assert b is not a and b.from_cache and b.gains.tobytes() == a.gains.tobytes()


def test_other_inputs_are_another_design():
    a = designs.balance_design(**NOMINAL_DESIGN, cache=False)
    heavier = replace(NOMINAL, m_b=NOMINAL.m_b * 1.1)
    b = designs.balance_design(heavier, **NOMINAL_DESIGN, cache=False)
    assert b is not a and b.gains.tobytes() != a.gains.tobytes()
    assert designs.key_of(heavier, **NOMINAL_DESIGN) != designs.key_of(NOMINAL, **NOMINAL_DESIGN)


def test_an_adopted_design_is_the_answer_for_its_inputs():
    solved = design_balance_gains(**NOMINAL_DESIGN)
    designs.adopt(solved, NOMINAL, **NOMINAL_DESIGN)
    assert designs.balance_design(**NOMINAL_DESIGN, cache=False) is solved


def test_the_key_is_the_disk_caches_and_bad_options_are_one_line():
    from twin.controllers.lmi import design_options

    inputs = design_cache.inputs_of(NOMINAL, **design_options(**NOMINAL_DESIGN))
    assert designs.key_of(NOMINAL, **NOMINAL_DESIGN) == design_cache.key_of(inputs)
    with pytest.raises(TwinError, match=r"rho must be a finite number in \(0, 1e\+06\]"):
        designs.balance_design(rho=-1.0)


def test_the_solver_does_not_know_the_store():
    """lmi solves; the store sits above it (no import back up, no cache argument)."""
    import inspect

    from twin.controllers import lmi

    assert "cache" not in inspect.signature(design_balance_gains).parameters
    import ast

    imported = {n.module if isinstance(n, ast.ImportFrom) else a.name
                for n in ast.walk(ast.parse(inspect.getsource(lmi))) if isinstance(n, (ast.Import, ast.ImportFrom))
                for a in n.names}
    imported |= {f"{n.module}.{a.name}" for n in ast.walk(ast.parse(inspect.getsource(lmi)))
                 if isinstance(n, ast.ImportFrom) and n.module for a in n.names}
    assert not {"twin.controllers.designs", "twin.controllers.design_cache"} & imported, imported
