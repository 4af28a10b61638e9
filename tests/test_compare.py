"""'twin compare A B': two run directories or golden files side by side; exit 0 when they
agree, 1 when they differ (naming the departures), 2 on bad input (one line)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from test_golden import write_short
from test_scenarios import assert_one_line_error, twin

ESTIMATED = ("--set", "sensors.sensing=estimated")  # the seed draws the sensor noise only when sensors are in the loop


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Run directories of the short scenario: "a" and "a_again" (IT2 and LQR, seed 0), "seed1"
    (seed 1), "it2" (IT2 alone, seed 0), "lqr" (LQR alone), and a golden file of IT2, seed 0."""
    d = tmp_path_factory.mktemp("compare")
    f = write_short(d)
    out = {}
    for name, extra in (("a", ("--controller", "it2,lqr")), ("a_again", ("--controller", "it2,lqr")),
                        ("seed1", ("--controller", "it2,lqr", "--seed", "1")), ("it2", ("--controller", "it2")),
                        ("lqr", ("--controller", "lqr"))):
        status, _, err = twin("run", f, *ESTIMATED, "--no-video", "--out", d / name, *extra)
        assert status == 0, err
        out[name] = d / name
    status, _, err = twin("check", f, *ESTIMATED, "--workers", "1", "--record", d / "gold")
    assert status == 0, err
    out["golden"] = d / "gold" / "short" / "it2" / "seed-0.npz"
    return out


def test_two_runs_of_one_scenario_and_seed_agree(runs):
    status, out, err = twin("compare", runs["a"], runs["a_again"])
    assert status == 0, out + err
    assert "environment and designs: identical" in out and "trajectories compared on one build: bit for bit" in out
    assert "it2: agree (201 rows compared in A, 201 in B)" in out and "lqr: agree" in out
    assert out.rstrip().endswith("A and B agree")


def test_two_seeds_differ_and_each_signals_first_departure_is_named(runs):
    status, out, err = twin("compare", runs["a"], runs["seed1"])
    assert status == 1, out + err
    assert "note: A's seed is 0, B's 1" in out and "it2: DIFFER" in out and "lqr: DIFFER" in out
    assert "first departure of each signal" in out
    # the seed draws the sensor noise: the estimate departs at the first row, the truth after it acted
    first = [line.split() for line in out.splitlines() if line.strip().startswith("theta_est ")]
    assert [row[1] for row in first] == ["0.000", "0.000"]  # IT2's and LQR's, at t = 0.000 s
    assert all(row[-4] == "rad" and row[-3:] == ["bit", "for", "bit"] for row in first), first
    assert "settling_time_s" in out and out.rstrip().endswith("A and B differ: 2 of 2 controllers (it2, lqr)")


def test_tolerances_decide_what_departs(runs):
    # every signal within 1e3 of its SI unit, but the estimate of θ held to 1e-9 rad: only it departs
    status, out, _ = twin("compare", runs["a"], runs["seed1"], "--atol", "1e3", "--tolerance", "theta_est=1e-9")
    assert status == 1
    assert "(1 of 35 depart)" in out and "theta_est " in out and "theta_dot_est" not in out
    assert twin("compare", runs["a"], runs["seed1"], "--atol", "1e3")[0] == 0


def test_controllers_only_one_side_has_are_named_not_compared(runs):
    status, out, _ = twin("compare", runs["a"], runs["it2"])
    assert status == 0 and "only in A, not compared: lqr" in out and "it2: agree" in out
    assert "environment and designs: identical" in out  # LQR's design is not one of the compared runs'


def test_a_golden_file_compares_with_a_run_directory(runs):
    status, out, err = twin("compare", runs["golden"], runs["a"])
    assert status == 0, out + err
    assert "A: " in out and "golden trajectory, scenario short, seed 0, controllers it2" in out
    assert "only in B, not compared: lqr" in out and "settling_time_s" in out  # the golden file's metrics too


def test_the_figure_and_the_report_as_data(runs, tmp_path):
    from PIL import Image

    status, out, _ = twin("compare", runs["a"], runs["seed1"], "--figure", tmp_path / "cmp.png")
    assert status == 1 and f"wrote {tmp_path / 'cmp.png'}" in out
    assert Image.open(tmp_path / "cmp.png").size == (1210, 770)
    status, out, _ = twin("compare", runs["a"], runs["seed1"], "--out", tmp_path / "cmp")
    assert status == 1 and (tmp_path / "cmp" / "comparison.png").stat().st_size > 10_000
    doc = json.loads((tmp_path / "cmp" / "comparison.json").read_text())
    assert doc["agree"] is False and doc["environment_differences"] == []
    first = doc["controllers"]["it2"]["departures"][0]
    assert first["signal"] == "theta_est" and first["t_s"] == 0.0 and first["difference"] == first["b"] - first["a"]


def test_a_decimated_run_is_compared_on_its_rows_and_said_to_be(runs, tmp_path):
    f = write_short(tmp_path)
    status, _, err = twin("run", f, *ESTIMATED, "--no-video", "--controller", "it2", "--log-every", "2",
                          "--log-format", "csv.gz", "--out", tmp_path / "every2")
    assert status == 0, err
    status, out, _ = twin("compare", runs["it2"], tmp_path / "every2")
    assert status == 0, out  # the same run: on the rows both keep, identical
    assert ("note: A's trajectory keeps every control step, B's every 2nd control step: compared on the rows both "
            "keep (every 2nd control step)") in out and "it2: agree (101 rows compared in A, 101 in B)" in out
    status, out, _ = twin("compare", tmp_path / "every2", runs["seed1"])
    assert status == 1 and "(101 rows compared in A, 101 in B)" in out


def test_a_run_directory_whose_files_differ_from_its_metrics_is_refused(runs, tmp_path):
    import shutil

    from twin.outputs import rundir

    broken = shutil.copytree(runs["a"], tmp_path / "mixed")
    doc = json.loads((broken / "metrics.json").read_text())
    del doc["runs"]["lqr"]
    (broken / "metrics.json").write_text(json.dumps(doc))
    # changed after its manifest was written: refused as such, whatever the change
    status, out, err = twin("compare", runs["a"], broken)
    assert_one_line_error(status, out, err, f"{broken / 'metrics.json'}: not the file {broken / 'manifest.json'} lists")
    rundir.seal(broken, "twin run")  # and with a manifest over the mixed files, the mix is named
    status, out, err = twin("compare", runs["a"], broken)
    assert_one_line_error(status, out, err, f"{broken}: metrics.json and trajectory.csv hold other controllers (lqr")


@pytest.mark.parametrize("make, says", [
    (lambda d: d / "nothing", "no such file or directory"),
    (lambda d: d, "not a run directory of 'twin run' (no metrics.json)"),
    (lambda d: (d / "notes.txt").write_text("x") and d / "notes.txt", "neither a run directory nor a golden"),
    (lambda d: (d / "bad.npz").write_bytes(b"PK\x03\x04 broken") and d / "bad.npz", "a damaged or truncated .npz"),
])
def test_bad_input_is_one_line_and_exit_2(runs, tmp_path, make, says):
    path = make(tmp_path)
    status, out, err = twin("compare", runs["a"], path)
    assert_one_line_error(status, out, err, str(path), says)


def test_no_controller_in_common_and_conflicting_options_are_one_line(runs, tmp_path):
    status, out, err = twin("compare", runs["it2"], runs["lqr"])
    assert_one_line_error(status, out, err, "holds it2", "holds lqr", "no controller in common")
    status, out, err = twin("compare", runs["a"], runs["a"], "--figure", tmp_path / "x.png", "--out", tmp_path)
    assert_one_line_error(status, out, err, "--figure PATH and --out DIR")
    status, out, err = twin("compare", runs["a"], runs["a"], "--tolerance", "thetaa=1")
    assert_one_line_error(status, out, err, "--tolerance: no signal 'thetaa' is logged")


def test_a_trajectory_file_reads_back_as_the_golden_file_holds_it(runs):
    from twin.outputs import compare

    r = compare.load(runs["a"])
    ours, gold = r.trajectories["it2"], compare.load(runs["golden"]).trajectories["it2"]
    assert ours.names == gold.names and ours.units == gold.units
    np.testing.assert_array_equal(ours.data, gold.data)  # every bit, through the CSV text
    assert r.metrics["it2"]["status"] == ours.status == "ok" and r.trajectories["lqr"].status == "ok"
