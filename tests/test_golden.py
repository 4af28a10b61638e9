"""Golden trajectories: recorded with their environment and designs, compared bit for bit on
the same build and with tolerance across builds or where tolerances are set, departures
reported with their time, signal and what the environments differ in; damaged files refused."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from twin.outputs import fingerprint, rundir

from twin.outputs import golden
from twin.cli import main
from twin.errors import TwinError
from twin.outputs.golden import ATOL, Trajectory, compare
from twin.scenarios import load_scenario
from twin.outputs.tolerances import Tolerances, parse_options, parse_table

# One second of balance from 0.48 rad: short, and with ideal sensing its response to a
# plant change is smooth (an estimator's gates would turn a tiny change into a large one)
SHORT = """
name = "short"
description = "one second of balance from 0.48 rad with ideal sensing, for the golden tests"
duration = 1.0

[controller]
kinds = ["it2"]

[sensors]
sensing = "ideal"

[video]
enabled = false

[expect]
fell = false
"""


def twin(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, r.stdout, r.stderr


def _traj(n=5, status="ok"):
    t = np.arange(n) * 0.005
    data = np.column_stack([t, np.linspace(0.4, 0.0, n), np.zeros(n)])
    return Trajectory(("t", "theta", "ul_cmd"), ("s", "rad", "N·m"), data, status)


def test_identical_runs_agree_and_the_first_difference_is_found():
    ref = _traj()
    assert compare(_traj(), ref, same_build=True) is None
    run = _traj()
    run.data[3, 2] += 1e-15
    run.data[4, 1] += 1.0
    dep = compare(run, ref, same_build=True)
    assert (dep.t, dep.signal, dep.unit, dep.tolerance) == (pytest.approx(0.015), "ul_cmd", "N·m", 0.0)
    assert "bit for bit" in str(dep) and str(dep).startswith("departs at t = 0.015 s in ul_cmd")


def test_across_builds_the_paths_disagreement_passes_and_more_does_not():
    ref = _traj()
    run = _traj()
    run.data[2, 1] += 1e-13  # the compiled and pure-Python paths' size of disagreement
    assert compare(run, ref, same_build=False) is None and compare(run, ref, same_build=True) is not None
    run.data[2, 1] += 10 * ATOL
    dep = compare(run, ref, same_build=False)
    assert dep.signal == "theta" and dep.t == pytest.approx(0.010)
    assert dep.tolerance == pytest.approx(ATOL + golden.RTOL * abs(ref.data[2, 1]))


def test_a_run_of_another_length_is_reported_as_such():
    full = _traj(5)
    dep = compare(Trajectory(full.names, full.units, full.data[:4], "fell"), full, same_build=True)
    assert str(dep) == ("the run has 4 rows (ends at t = 0.015 s, status fell), the reference 5 rows "
                        "(t = 0.020 s, status ok); the rows both have agree (bit for bit)")
    # and where the rows both have part, after it
    short = Trajectory(full.names, full.units, full.data[:4].copy(), "fell")
    short.data[2, 1] += 1e-3
    text = str(compare(short, full, same_build=True))
    assert text.startswith("the run has 4 rows") and "over the rows both have it departs at t = 0.010 s in theta" in text


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


def test_a_missing_reference_fails_the_check(short):
    f, gold = short  # a complete record of IT2 alone
    status, out, err = twin("check", f, "--controller", "lqr", "--workers", "1", "--golden", gold)
    assert status == 1 and "no golden trajectory here" in err, out + err


def test_a_golden_directory_without_a_manifest_is_refused_as_incomplete(tmp_path):
    from test_scenarios import assert_one_line_error

    status, out, err = twin("check", "paper-exp1", "--controller", "lqr", "--workers", "1", "--golden", tmp_path)
    assert_one_line_error(status, out, err, f"{tmp_path}: an incomplete golden directory: no manifest.json")


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
    assert compare(run, ref, same_build=False) is None and compare(run, ref, same_build=True) is None
    run.data[1, 2] = 0.0
    assert compare(run, ref, same_build=False).signal == "ul_cmd"


def test_signals_in_another_order_are_named_as_such():
    ref = _traj()
    run = Trajectory(("t", "ul_cmd", "theta"), ("s", "N·m", "rad"), ref.data[:, [0, 2, 1]], "ok")
    assert "the same but in another order" in str(compare(run, ref, same_build=True))


# ---- the environment, tolerances, lengths and damaged files, on a short scenario -------------------

def write_short(directory, extra: str = "") -> str:
    """The short scenario (plus ``extra`` TOML) as a file in ``directory``: its path."""
    path = directory / "short.toml"
    path.write_text(SHORT + extra, encoding="utf-8")
    return str(path)


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    """(scenario file, golden directory) of the short scenario recorded with IT2, seed 0."""
    d = tmp_path_factory.mktemp("golden-short")
    f = write_short(d)
    status, out, err = twin("check", f, "--workers", "1", "--record", d / "gold")
    assert status == 0, out + err
    return f, d / "gold"


def _check(f, gold, *extra):
    status, out, err = twin("check", f, "--workers", "1", "--golden", gold, *extra)
    lines = [line for line in err.splitlines() if "golden trajectory" in line]
    return status, out, lines


def test_a_golden_file_records_the_environment_the_designs_and_the_metrics(short):
    f, gold = short
    _, meta = golden.load(gold / "short" / "it2" / "seed-0.npz")
    env = meta["environment"]
    here = fingerprint.environment()
    assert env["blas"]["kernel"] == here["blas"]["kernel"] and env["packages"] == here["packages"]
    assert env["designs"]["balance"] == load_scenario(f).design().digest()
    assert meta["format"] == golden.FORMAT == 2 and meta["metrics"]["fell"] is False


def _doctor(path, kernel: str, balance: str) -> None:
    """The reference as another machine would have recorded it: another BLAS kernel, another
    balance design, and θ in its last digits at one row (what another kernel's sums do)."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    meta["environment"]["blas"]["kernel"] = kernel
    meta["environment"]["designs"]["balance"] = balance
    arrays["meta"] = np.array(json.dumps(meta, sort_keys=True))
    arrays["data"][5, [str(n) for n in arrays["names"]].index("theta")] += 1e-12
    np.savez_compressed(path, **arrays)


def test_a_departure_names_the_environment_and_design_that_differ(short, tmp_path):
    f, gold = short
    doctored = shutil.copytree(gold, tmp_path / "gold")
    here = fingerprint.environment()["blas"]["kernel"]
    other = "Haswell" if here != "Haswell" else "SkylakeX"
    _doctor(doctored / "short" / "it2" / "seed-0.npz", other, "0" * 64)
    rundir.seal(doctored, rundir.RECORD_COMMAND)  # as that machine's record would list it
    status, out, lines = _check(f, doctored)
    assert status == 1 and len(lines) == 1, (out, lines)
    assert lines[0].startswith("FAIL short it2 seed 0: golden trajectory departs at t = 0.025 s in theta: ")
    digest = load_scenario(f).design().digest()
    assert lines[0].endswith(f"(difference -1e-12 rad, bit for bit); differs from the reference in: BLAS kernel "
                             f"{here}, the reference's {other}; design balance {digest[:12]}, the reference's "
                             f"000000000000"), lines[0]


def test_tolerances_pass_a_slightly_heavier_body_that_fails_bit_for_bit(short):
    f, gold = short
    heavier = ("--set", "plant.scale.m_b=1.001")  # a body 0.1 % heavier than the reference's
    status, out, lines = _check(f, gold, *heavier)
    assert status == 1 and " in torque_l: " in lines[0] and "bit for bit" in lines[0]
    # the environment is the reference's: what changed is the scenario (or the code)
    assert lines[0].endswith("environment and designs identical to the reference's (so the code or the scenario "
                             "changed)")
    # within the second, dψ/dt moves by about 0.02 rad/s and θ by about 2e-4 rad
    status, out, lines = _check(f, gold, *heavier, "--atol", "0.05")
    assert status == 0 and not lines and "matches" in out
    status, out, lines = _check(f, gold, *heavier, "--atol", "0.05", "--tolerance", "theta=1e-6")
    assert status == 1 and " in theta: " in lines[0] and "tolerance 1e-06 rad" in lines[0]
    # a relative tolerance alone: 0.1 % of a value is not enough where the values cross zero
    status, out, lines = _check(f, gold, *heavier, "--rtol", "0.5")
    assert status == 1 and "tolerance" in lines[0]


def test_a_scenarios_golden_tolerances_apply_and_the_command_line_replaces_them(short, tmp_path):
    _, gold = short
    f = write_short(tmp_path, "\n[expect.golden]\natol = 0.05\nsignals = { theta = { atol = 1e-3 } }\n")
    heavier = ("--set", "plant.scale.m_b=1.001")
    assert _check(f, gold, *heavier)[0] == 0
    status, _, lines = _check(f, gold, *heavier, "--tolerance", "theta=1e-6")  # the signal's own, replaced
    assert status == 1 and " in theta: " in lines[0] and "tolerance 1e-06 rad" in lines[0]
    status, _, lines = _check(f, gold, *heavier, "--atol", "0")  # the overall one, replaced: θ keeps its own
    assert status == 1 and " in theta: " not in lines[0] and "bit for bit" in lines[0]


def test_a_run_of_another_length_is_reported_with_rows_times_and_status(short):
    f, gold = short
    status, _, lines = _check(f, gold, "--set", "duration=0.5")
    assert status == 1
    assert lines == ["FAIL short it2 seed 0: golden trajectory: the run has 101 rows (ends at t = 0.500 s, status ok), "
                     "the reference 201 rows (t = 1.000 s, status ok); the rows both have agree (bit for bit); "
                     "environment and designs identical to the reference's (so the code or the scenario changed)"]


def _damage(path, how: str) -> None:
    raw = path.read_bytes()
    if how == "text":
        path.write_text("t,theta\n0,0.48\n")
    elif how == "truncated":
        path.write_bytes(raw[:len(raw) // 2])
    elif how == "corrupt":
        path.write_bytes(raw[:2000] + bytes(b ^ 0xFF for b in raw[2000:2100]) + raw[2100:])
    elif how == "foreign":
        np.savez(path, x=np.arange(3))
    elif how == "npy":
        with open(path, "wb") as fh:
            np.save(fh, np.arange(3))
    elif how == "old format":
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["meta"] = np.array(json.dumps({**json.loads(str(arrays["meta"])), "format": 1}))
        np.savez_compressed(path, **arrays)


@pytest.mark.parametrize("how, says", [
    ("text", "not an .npz archive, nor any zip file"),
    ("truncated", "a damaged or truncated .npz archive: BadZipFile"),
    ("corrupt", "a damaged or truncated .npz archive"),
    ("foreign", "an .npz archive without meta, names, units, data"),
    ("npy", "a single .npy array, not an .npz archive"),
    ("old format", "golden format 1 (an older mtwip-twin's), this version reads format 2; record it again"),
])
def test_a_damaged_foreign_or_old_reference_is_one_line_naming_the_file(short, tmp_path, how, says):
    f, gold = short
    copy = shutil.copytree(gold, tmp_path / "gold")
    path = copy / "short" / "it2" / "seed-0.npz"
    _damage(path, how)
    with pytest.raises(TwinError) as info:
        golden.load(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and says in message and "\n" not in message, message
    status, out, lines = _check(f, copy)  # the check fails on it, saying so in one line
    assert status == 1 and lines == [f"FAIL short it2 seed 0: golden trajectory: {message}"], lines


@pytest.mark.parametrize("args, says", [
    (("--atol", "-1"), "--atol: must be a finite number ≥ 0 in the signal's SI unit"),
    (("--rtol", "2"), "--rtol: must be a number in [0, 1]"),
    (("--atol", "nan"), "--atol: must be a finite number"),
    (("--tolerance", "theta"), "--tolerance must be SIGNAL=ATOL or SIGNAL=ATOL,RTOL"),
    (("--tolerance", "theta=abc"), "--tolerance theta=abc: ATOL must be a number, got 'abc'"),
    (("--tolerance", "theta=1e-6,-1"), "--tolerance theta=1e-6,-1: RTOL: must be a number in [0, 1]"),
    (("--tolerance", "thetta=1e-6"), "--tolerance: no signal 'thetta' is logged; signals: t, theta, theta_dot"),
    (("--tolerance", "theta=1", "--tolerance", "theta=2"), "--tolerance names theta twice"),
])
def test_bad_tolerances_on_the_command_line_are_one_line(short, args, says):
    from test_scenarios import assert_one_line_error

    f, gold = short
    status, out, err = twin("check", f, "--workers", "1", "--golden", gold, *args)
    assert_one_line_error(status, out, err, says)


def test_tolerances_without_golden_are_refused(short):
    from test_scenarios import assert_one_line_error

    status, out, err = twin("check", short[0], "--atol", "1e-6")
    assert_one_line_error(status, out, err, "give --golden DIR with them")


@pytest.mark.parametrize("table, says", [
    ("atol = -1", "expect.golden.atol: must be a finite number ≥ 0"),
    ("rtol = true", "expect.golden.rtol: must be a number in [0, 1]"),
    ("atoll = 1e-6", "expect.golden.atoll: unknown key; allowed here: atol, rtol, signals"),
    ("signals = { theta = 1e-6 }", "expect.golden.signals.theta: must be a table with atol and/or rtol"),
    ("signals = { theta = { atol = 1e-6, tol = 1 } }", "expect.golden.signals.theta: must be a table"),
    ("signals = { thta = { atol = 1e-6 } }", "expect.golden.signals: no signal 'thta' is logged"),
])
def test_bad_golden_tables_in_a_scenario_are_one_line(short, tmp_path, table, says):
    from test_scenarios import assert_one_line_error

    f = write_short(tmp_path, f"\n[expect.golden]\n{table}\n")
    status, out, err = twin("check", f, "--workers", "1", "--golden", short[1])
    assert_one_line_error(status, out, err, says, f)


def test_which_tolerance_a_signal_gets():
    scenario = parse_table({"atol": 1e-6, "signals": {"theta": {"atol": 1e-3}, "psi": {"rtol": 1e-2}}})
    assert scenario.of("x") == (1e-6, 0.0) and scenario.of("theta") == (1e-3, 0.0) and scenario.of("psi") == (1e-6, 1e-2)
    line = parse_options(rtol=1e-4, items=["theta=1e-5", "alpha=1,0.1"])
    both = line.over(scenario)
    assert both.of("x") == (1e-6, 1e-4) and both.of("theta") == (1e-5, 1e-4) and both.of("alpha") == (1.0, 0.1)
    assert both.of("psi") == (1e-6, 1e-2)  # the scenario's own rtol of psi outranks the overall one
    assert Tolerances().of("theta") == (0.0, 0.0) and Tolerances().describe() == "bit for bit"
    # between builds, never below the builds' floor
    assert Tolerances().of("theta", same_build=False) == (golden.ATOL, golden.RTOL)
    assert both.of("alpha", same_build=False) == (1.0, 0.1)
