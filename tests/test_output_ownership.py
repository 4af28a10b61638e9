"""Outputs of one command never destroyed by another (issue 39).

Every output folder says which command wrote it (its manifest.json's "command"; an unfinished
sweep's sweep.json), and every command refuses, in one line, a folder another command wrote:
before, 'twin replay --out R' and 'twin calibrate --out R' over a finished 'twin run' folder R
left only the replay's files, 'twin run --out' a replay's or a sweep's folder deleted them,
'twin sweep --out' a run's folder mixed the two under a sweep manifest, and 'twin compare'
read that as a run. A folder is held from a command's start to its end (a lock file beside it):
two 'twin run' to one --out both said "wrote" and the last won. A full disk while the figure
is drawn keeps the earlier complete run whole (it was replaced by the new data alone).
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_scenarios import assert_one_line_error, twin
from twin.outputs import rundir

RUN = ("run", "paper-exp1", "--controller", "lqr", "--no-video")  # no LMI design: quick
SWEEP = ("sweep", "paper-exp1", "--samples", "1", "--set", "sweep.levels=[0.0]", "--duration", "0.3",
         "--controller", "lqr", "--workers", "1")


def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A finished run (with its sensor log), replay, calibration and sweep, each in its folder."""
    d = tmp_path_factory.mktemp("owners")
    status, out, err = twin(*RUN, "--duration", "2", "--log-sensors", "--out", d / "run")  # a log to calibrate on
    assert status == 0, err
    log = d / "run" / "sensor-logs" / "lqr"
    status, out, err = twin("replay", log, "--out", d / "replay")
    assert status == 0, err
    cal = d / "calibration"  # what 'twin calibrate' leaves (a fit needs a longer log than this one)
    cal.mkdir()
    for name in ("report.json", "calibration.toml", "figure.png"):
        (cal / name).write_text("{}\n")
    rundir.seal(cal, "twin calibrate")
    status, out, err = twin(*SWEEP, "--out", d / "sweep")
    assert status == 0, err
    for name, command in (("run", "twin run"), ("replay", "twin replay"), ("calibration", "twin calibrate"),
                          ("sweep", "twin sweep")):
        assert rundir.owner(d / name) == command and json.loads((d / name / "manifest.json").read_text())[
            "command"] == command
    return d, log


@pytest.mark.parametrize("command, target, owner", [
    (("replay", "{log}"), "run", "twin run"),
    (("calibrate", "{log}", "--parameters", "m_b"), "run", "twin run"),
    ((*RUN, "--duration", "0.5"), "replay", "twin replay"),
    ((*RUN, "--duration", "0.5"), "sweep", "twin sweep"),
    ((*RUN, "--duration", "0.5"), "calibration", "twin calibrate"),
    (SWEEP, "run", "twin run"),
    (("replay", "{log}"), "sweep", "twin sweep"),
    (("compare", "{run}", "{run}", "--out"), "replay", "twin replay"),
])
def test_a_folder_another_command_wrote_is_refused_and_left_as_it_was(folders, tmp_path, command, target, owner):
    d, log = folders
    copy = shutil.copytree(d / target, tmp_path / target)
    before = _snapshot(copy)
    args = [str(a).format(log=log, run=d / "run") for a in command]
    status, out, err = twin(*args, *([] if args[-1] == "--out" else ["--out"]), copy)
    assert_one_line_error(status, out, err, f"{copy}: holds the output of '{owner}' (its manifest.json says so)",
                          "writes only into a new, empty or earlier", "give another --out")  # before anything runs
    assert _snapshot(copy) == before


def test_an_unfinished_sweep_is_known_by_its_sweep_json(folders, tmp_path):
    d, _ = folders
    copy = shutil.copytree(d / "sweep", tmp_path / "sweep")
    for name in ("manifest.json", "sweep.csv", "summary.md", "summary.json"):  # as a sweep stopped early leaves it
        (copy / name).unlink()
    assert rundir.owner(copy) == "twin sweep"
    status, out, err = twin(*RUN, "--duration", "0.5", "--out", copy)
    assert_one_line_error(status, out, err, "holds the output of 'twin sweep' (its sweep.json says so)")


def test_twin_compare_reads_only_run_folders(folders):
    d, _ = folders
    for name, owner in (("sweep", "twin sweep"), ("replay", "twin replay")):
        status, out, err = twin("compare", d / "run", d / name)
        assert_one_line_error(status, out, err, f"{d / name}: holds the output of '{owner}', not a run directory")


def test_a_command_rewrites_its_own_folder(folders, tmp_path):
    d, log = folders
    for name, args in (("replay", ("replay", log)), ("sweep", SWEEP), ("run", (*RUN, "--duration", "0.5"))):
        copy = shutil.copytree(d / name, tmp_path / name)
        status, out, err = twin(*args, "--out", copy)
        assert status == 0, err
    copy = shutil.copytree(d / "run", tmp_path / "run-with-logs")  # its sensor-logs/ is its own, listed
    status, out, err = twin(*RUN, "--duration", "0.5", "--log-sensors", "--out", copy)
    assert status == 0, err


def test_surface_and_compare_folders_say_who_wrote_them(tmp_path, folders):
    d, _ = folders
    status, out, err = twin("surface", "position", "--points", "5", "--out", tmp_path / "surfaces")
    assert status == 0, err
    status, out, err = twin("surface", "direction", "--points", "5", "--out", tmp_path / "surfaces")
    assert status == 0, err
    doc = json.loads((tmp_path / "surfaces" / "manifest.json").read_text())
    assert doc["command"] == "twin surface" and sorted(doc["files"]) == [
        "direction_it2.csv", "direction_it2.png", "position_it2.csv", "position_it2.png"]
    status, out, err = twin("compare", d / "run", d / "run", "--out", tmp_path / "cmp")
    assert status == 0, err
    assert rundir.owner(tmp_path / "cmp") == "twin compare"
    status, out, err = twin(*RUN, "--duration", "0.5", "--out", tmp_path / "surfaces")
    assert_one_line_error(status, out, err, "holds the output of 'twin surface'")


# ---- one folder, one command at a time ----------------------------------------------------------------

def test_a_second_run_into_a_folder_being_written_is_refused(tmp_path):
    """Two 'twin run' to one --out: both exited 0 and said "wrote"; the last one's results stood."""
    out = tmp_path / "R"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    first = subprocess.Popen([sys.executable, "-m", "twin.cli", "run", "paper-exp1", "--duration", "300",
                              "--controller", "lqr", "--no-video", "--out", str(out)], cwd=tmp_path, env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        lock = rundir.lock_path(out)
        deadline = time.monotonic() + 60
        while not (lock.exists() and lock.read_text().strip()):
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()
            time.sleep(0.02)
        status, stdout, err = twin(*RUN, "--duration", "0.5", "--out", out)
        assert_one_line_error(status, stdout, err, f"{out} is in use by 'twin run' (process {first.pid})")
        assert not out.exists()
    finally:
        first.terminate()
        first.communicate(timeout=60)
    assert first.returncode == 143
    assert not rundir.lock_path(out).exists()  # the lock goes with the command that held it


def test_the_lock_goes_with_its_command_and_a_stale_one_blocks_nobody(tmp_path):
    out = tmp_path / "R"
    status, _, err = twin(*RUN, "--duration", "0.5", "--out", out)
    assert status == 0 and not rundir.lock_path(out).exists(), err
    rundir.lock_path(out).write_text("'twin run' (process 1)\n")  # left by a command killed with SIGKILL
    status, _, err = twin(*RUN, "--duration", "0.5", "--out", out)
    assert status == 0 and not rundir.lock_path(out).exists(), err


# ---- the earlier complete run stays until a new one is complete -------------------------------------------

def test_a_full_disk_while_drawing_keeps_the_earlier_complete_run(tmp_path, monkeypatch):
    from twin.outputs import figure_worker, report

    out = tmp_path / "R"
    status, _, err = twin(*RUN, "--duration", "0.5", "--out", out)
    assert status == 0, err
    before = _snapshot(out)

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(figure_worker, "start", lambda: None)  # drawn in this process, where it fails
    monkeypatch.setattr(report, "plot_runs", full)
    status, stdout, err = twin(*RUN, "--duration", "0.5", "--seed", "5", "--out", out)
    assert status == 2 and "Traceback" not in err, err
    line = [x for x in err.splitlines() if x.startswith("error: ")]
    assert len(line) == 1 and f"cannot write {out / 'figure.png'}: No space left on device" in line[0], err
    assert f"kept metrics.json and trajectory.csv in {out}-incomplete, without figure.png" in line[0], err
    assert f"{out} still holds the earlier complete run (move {out}-incomplete to {out} to keep this one" in line[0]
    assert _snapshot(out) == before  # the earlier complete run, whole
    aside = json.loads((tmp_path / "R-incomplete" / "manifest.json").read_text())
    assert (aside["complete"], aside["missing"], aside["exit_status"]) == (False, ["figure.png"], 2)
    assert json.loads((tmp_path / "R-incomplete" / "metrics.json").read_text())["seed"] == 5
    monkeypatch.undo()
    status, _, err = twin(*RUN, "--duration", "0.5", "--seed", "5", "--out", out)  # the disk has room again: the new run replaces it
    assert status == 0, err
    assert json.loads((out / "metrics.json").read_text())["seed"] == 5
