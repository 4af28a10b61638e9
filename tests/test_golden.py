"""Golden trajectories: recorded, compared bit for bit on the same build and with tolerance
across builds, departures reported with their time and signal."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from twin import golden
from twin.cli import main
from twin.golden import ATOL, Trajectory, compare


def twin(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.stdout, r.stderr


def _traj(n=5, status="ok"):
    t = np.arange(n) * 0.005
    data = np.column_stack([t, np.linspace(0.4, 0.0, n), np.zeros(n)])
    return Trajectory(("t", "theta", "ul_cmd"), ("s", "rad", "N·m"), data, status)


def test_identical_runs_agree_and_the_first_difference_is_found():
    ref = _traj()
    assert compare(_traj(), ref, exact=True) is None
    run = _traj()
    run.data[3, 2] += 1e-15
    run.data[4, 1] += 1.0
    dep = compare(run, ref, exact=True)
    assert (dep.t, dep.signal, dep.unit, dep.tolerance) == (pytest.approx(0.015), "ul_cmd", "N·m", 0.0)
    assert "bit for bit" in str(dep) and str(dep).startswith("departs at t = 0.015 s in ul_cmd")


def test_across_builds_the_paths_disagreement_passes_and_more_does_not():
    ref = _traj()
    run = _traj()
    run.data[2, 1] += 1e-13  # the compiled and pure-Python paths' size of disagreement
    assert compare(run, ref, exact=False) is None and compare(run, ref, exact=True) is not None
    run.data[2, 1] += 10 * ATOL
    dep = compare(run, ref, exact=False)
    assert dep.signal == "theta" and dep.t == pytest.approx(0.010)
    assert dep.tolerance == pytest.approx(ATOL + golden.RTOL * abs(ref.data[2, 1]))


def test_a_run_that_ends_otherwise_departs_where_the_shorter_ends():
    full = _traj(5)
    dep = compare(Trajectory(full.names, full.units, full.data[:4], "fell"), full, exact=True)
    assert "ends 'fell' after 4 rows, the reference 'ok' after 5" in str(dep) and dep.t == pytest.approx(0.015)


def test_record_and_load_round_trip(tmp_path):
    p = golden.path_for(tmp_path, "my scenario", "pkg.mod:Ctrl", 7)
    assert p == tmp_path / "my_scenario" / "pkg.mod_Ctrl" / "seed-7.npz"
    golden.record(p, _traj(), {"scenario": "x"})
    back, meta = golden.load(p)
    assert back.names == _traj().names and np.array_equal(back.data, _traj().data) and meta["build"] == golden.build()
    with pytest.raises(Exception, match="no golden trajectory here"):
        golden.load(tmp_path / "nope.npz")


def test_a_one_percent_heavier_body_departs_and_an_unchanged_rerun_passes(tmp_path):
    gold = tmp_path / "gold"
    status, out, err = twin("check", "paper-exp1", "--controller", "it2", "--workers", "1", "--record", gold)
    assert status == 0, out + err
    assert (gold / "paper-exp1" / "it2" / "seed-0.npz").exists()
    status, out, err = twin("check", "paper-exp1", "--controller", "it2", "--workers", "1", "--golden", gold)
    assert status == 0 and "golden trajectory, seed 0" in out and "matches" in out, out + err
    # the built-in's body mass factor is 1.06: 1 % more
    status, out, err = twin("check", "paper-exp1", "--controller", "it2", "--workers", "1", "--golden", gold,
                            "--set", "plant.scale.m_b=1.0706")
    assert status == 1, out + err
    (line,) = [l for l in err.splitlines() if "golden trajectory" in l]
    assert line.startswith("FAIL paper-exp1 it2 seed 0: golden trajectory departs at t = ")
    assert " in " in line and "bit for bit" in line  # the time and the signal where it parts


def test_a_missing_reference_fails_the_check(tmp_path):
    status, out, err = twin("check", "paper-exp1", "--controller", "lqr", "--workers", "1", "--golden", tmp_path)
    assert status == 1 and "no golden trajectory here" in err, out + err


def test_the_pure_python_build_passes_a_compiled_reference_within_tolerance(tmp_path):
    """Across builds the comparison is by tolerance (the paths agree to ~1e-13, not bit for bit)."""
    if golden.build() != "compiled":
        pytest.skip("needs the compiled kernels to record the reference")
    gold = tmp_path / "gold"
    assert twin("check", "paper-exp3", "--controller", "it2", "--workers", "1", "--record", gold)[0] == 0
    env = {**os.environ, "TWIN_PURE_PYTHON": "1"}
    r = subprocess.run([sys.executable, "-m", "twin.cli", "check", "paper-exp3", "--controller", "it2", "--workers",
                        "1", "--golden", str(gold)], capture_output=True, text=True, env=env, cwd=tmp_path,
                       timeout=600)
    assert r.returncode == 0 and "matches" in r.stdout, r.stdout + r.stderr


def test_nan_and_infinity_on_both_sides_agree_with_tolerance_too():
    ref = _traj()
    ref.data[1, 2] = np.nan
    ref.data[2, 2] = np.inf
    run = Trajectory(ref.names, ref.units, ref.data.copy(), "ok")
    assert compare(run, ref, exact=False) is None and compare(run, ref, exact=True) is None
    run.data[1, 2] = 0.0
    assert compare(run, ref, exact=False).signal == "ul_cmd"


def test_signals_in_another_order_are_named_as_such():
    ref = _traj()
    run = Trajectory(("t", "ul_cmd", "theta"), ("s", "N·m", "rad"), ref.data[:, [0, 2, 1]], "ok")
    assert "the same but in another order" in str(compare(run, ref, exact=True))
