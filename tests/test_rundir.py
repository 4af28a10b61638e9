"""Issue 26: run directories written as a unit, safe output paths, and interrupts.

Kill tests stop a real ``twin`` process (a subprocess) at a chosen point through the
``TWIN_TEST_STOP_AT`` hook (twin.outputs.rundir.test_point: the process writes a marker file and
waits there for the signal), so that the stages aimed at (a trajectory half written, a video
under way, a commit) are hit every time, whatever the machine's load. Afterwards every
directory is either complete with its manifest (every file listed, as listed) or as it was
before, never a mix of two runs; SIGINT and SIGTERM end in 130 and 143 with one line saying
what was kept, leave no hidden partial files and no process of the command behind.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_golden import write_short
from test_scenarios import assert_one_line_error, twin
from twin.outputs import golden
from twin.outputs import rundir
from twin.errors import TwinError

RUN = ("run", "paper-exp1", "--duration", "1", "--controller", "lqr")  # no LMI design: a quick run
PARTIAL = rundir.PARTIAL


# ---- helpers ----------------------------------------------------------------------------------------

def _start(args, cwd: Path, stop_at: str | None = None) -> tuple[subprocess.Popen, Path]:
    marker = cwd / f"marker-{time.monotonic_ns()}"
    env = dict(os.environ)
    if stop_at is not None:
        env["TWIN_TEST_STOP_AT"] = f"{stop_at}:{marker}"
    # a session of its own: its processes can be found (and signalled, as a terminal would) by it
    proc = subprocess.Popen([sys.executable, "-m", "twin.cli", *map(str, args)], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    return proc, marker


def _stop(args, cwd: Path, point: str, sig) -> tuple[int, str, str, int]:
    """Run ``twin ARGS`` until it reaches ``point``, send ``sig`` to its process group (as a
    terminal's Ctrl-C, or a service manager, would); (exit status, stdout, stderr, session)."""
    proc, marker = _start(args, cwd, point)
    deadline = time.monotonic() + 180
    while not marker.exists():
        assert proc.poll() is None, ("ended before reaching " + point, proc.communicate())
        assert time.monotonic() < deadline, f"did not reach {point} in 180 s"
        time.sleep(0.02)
    os.killpg(proc.pid, sig)
    out, err = proc.communicate(timeout=120)
    marker.unlink()
    return proc.returncode, out, err, proc.pid


def _session(sid: int) -> list[str]:
    """The command lines of the processes still in session ``sid``."""
    left = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            fields = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()
            if int(fields[3]) == sid:
                left.append(Path(f"/proc/{d}/cmdline").read_text().replace("\0", " "))
        except (OSError, IndexError, ValueError):
            continue
    return left


def _no_process_left(sid: int) -> None:
    deadline = time.monotonic() + 10
    while _session(sid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _session(sid), _session(sid)


def _complete(directory: Path) -> dict:
    """The manifest of ``directory``, after checking that it lists every file there, as it is."""
    doc = rundir.read_manifest(directory)
    present = sorted(p.relative_to(directory).as_posix() for p in directory.rglob("*")
                     if p.is_file() and p.name not in (rundir.MANIFEST, rundir.LOCK_NAME))
    assert present == sorted(doc["files"]), (present, sorted(doc["files"]))
    for name in doc["files"]:
        rundir.check_listed(directory, doc, name)
    return doc


def _hidden(where: Path) -> list[str]:
    """Unfinished files or directories anywhere under ``where`` (a staging, a partial video, ...)."""
    return sorted(str(p.relative_to(where)) for p in where.rglob("*") if PARTIAL in p.name or ".partial." in p.name)


def _one_line(err: str, *fragments) -> str:
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("  ")]  # bars: indented
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    for f in fragments:
        assert f in lines[0], (f, lines[0])
    return lines[0]


def _error(status: int, err: str, *fragments) -> None:
    """Exit status 2 and one line ``error: ...`` holding ``fragments`` (besides the progress bars)."""
    assert status == 2, err
    assert _one_line(err, *fragments).startswith("error: "), err


@pytest.fixture(scope="module")
def earlier(tmp_path_factory):
    """A complete run directory with a video (seed 0), to be copied and run over."""
    d = tmp_path_factory.mktemp("earlier")
    r = subprocess.run([sys.executable, "-m", "twin.cli", *RUN, "--video", "--out", "R"], cwd=d, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    doc = _complete(d / "R")
    assert "video.mp4" in doc["files"] and doc["complete"] and doc["exit_status"] == 0
    return d / "R"


def _copy(earlier: Path, tmp_path: Path) -> Path:
    target = shutil.copytree(earlier, tmp_path / "R")
    return target


def _seed(directory: Path) -> int:
    return json.loads((directory / "metrics.json").read_text())["seed"]


def _unchanged(target: Path, earlier: Path) -> None:
    """``target`` is still the earlier run, every byte of it."""
    _complete(target)
    assert (target / rundir.MANIFEST).read_bytes() == (earlier / rundir.MANIFEST).read_bytes()


# ---- twin run killed at several points ----------------------------------------------------------------

@pytest.mark.parametrize("sig, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupted_while_writing_the_trajectory_leaves_the_earlier_run(earlier, tmp_path, sig, status):
    target = _copy(earlier, tmp_path)
    code, _, err, sid = _stop([*RUN, "--seed", "1", "--video", "--out", "R"], tmp_path, "trajectory", sig)
    assert code == status, err
    _one_line(err, f"interrupted: {signal.Signals(sig).name}; nothing of this run was written: R is as it was")
    _unchanged(target, earlier)
    assert _hidden(tmp_path) == []
    _no_process_left(sid)


@pytest.mark.parametrize("sig, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupted_during_the_video_keeps_the_new_data_and_the_old_complete_run(earlier, tmp_path, sig, status):
    """The new run's data are kept, never beside the old video; the earlier complete run stays whole
    in R until a new one is complete (issue 39: it was replaced by the data alone), and the new data go
    to R-incomplete, which the line names with how to keep them instead."""
    target = _copy(earlier, tmp_path)
    code, _, err, sid = _stop([*RUN, "--seed", "1", "--video", "--out", "R"], tmp_path, "video", sig)
    assert code == status, err
    _one_line(err, f"interrupted: {signal.Signals(sig).name}; kept figure.png, metrics.json and trajectory.csv in "
                   f"R-incomplete, without video.mp4; its manifest.json says so, with exit status {status}; R still "
                   f"holds the earlier complete run (move R-incomplete to R to keep this one instead)")
    _unchanged(target, earlier)
    aside = tmp_path / "R-incomplete"
    doc = _complete(aside)
    assert not (aside / "video.mp4").exists() and _seed(aside) == 1  # the new run's, without the old video
    assert (doc["complete"], doc["missing"], doc["exit_status"]) == (False, ["video.mp4"], status)
    assert doc["stopped"] == f"{signal.Signals(sig).name} during the video"
    assert _hidden(tmp_path) == []  # the video writer's .video.*.partial.mp4 included
    _no_process_left(sid)
    # what was kept reads as a run, said to be one an interrupted command kept
    status, out, _ = twin("compare", earlier, aside)
    assert status == 1 and "note: R-incomplete holds what an unfinished 'twin run' kept" in out.replace(
        str(aside), "R-incomplete")
    # without an earlier complete run, the data go to R itself, as before
    fresh = tmp_path / "fresh"
    code, _, err, _ = _stop([*RUN, "--seed", "1", "--video", "--out", "fresh"], tmp_path, "video", sig)
    assert code == 128 + sig, err
    _one_line(err, "in fresh, without video.mp4")
    assert _complete(fresh)["missing"] == ["video.mp4"] and not (tmp_path / "fresh-incomplete").exists()


@pytest.mark.parametrize("point", ["trajectory", "video", "commit"])
def test_killed_at_any_point_leaves_the_earlier_run_whole_and_the_next_run_clears_the_rest(earlier, tmp_path,
                                                                                          point):
    target = _copy(earlier, tmp_path)
    code, _, err, _ = _stop([*RUN, "--seed", "1", "--video", "--out", "R"], tmp_path, point, signal.SIGKILL)
    assert code == -signal.SIGKILL, err
    _unchanged(target, earlier)  # nothing of the killed run in it: not a new file, not a partial video
    staged = [p for p in tmp_path.iterdir() if p.name.startswith(".R" + PARTIAL)]
    assert len(staged) == 1  # its staging, hidden beside the target, marked unfinished by its name
    status, _, err = twin(*RUN, "--seed", "2", "--no-video", "--out", tmp_path / "R")
    assert status == 0, err
    assert _hidden(tmp_path) == []  # cleared by the next command writing there
    doc = _complete(target)
    assert _seed(target) == 2 and "video.mp4" not in doc["files"] and doc["complete"]


def test_an_interrupt_after_everything_was_written_keeps_it_all(earlier, tmp_path):
    target = _copy(earlier, tmp_path)
    code, _, err, _ = _stop([*RUN, "--seed", "1", "--no-video", "--out", "R"], tmp_path, "commit", signal.SIGINT)
    assert code == 130
    _one_line(err, "interrupted: SIGINT; kept figure.png, metrics.json and trajectory.csv in R (complete)")
    doc = _complete(target)
    assert doc["complete"] and doc["exit_status"] == 130 and _seed(target) == 1
    assert "video.mp4" not in doc["files"]  # the earlier run's video went with it


def test_an_interrupt_during_the_swap_is_held_until_it_is_done(earlier, tmp_path):
    target = _copy(earlier, tmp_path)
    code, _, err, _ = _stop([*RUN, "--seed", "1", "--no-video", "--out", "R"], tmp_path, "exchanged", signal.SIGTERM)
    assert code == 143
    _one_line(err, "interrupted: SIGTERM; this run was complete: R holds it, with its manifest.json")
    doc = _complete(target)
    assert doc["exit_status"] == 0 and _seed(target) == 1 and _hidden(tmp_path) == []
    # killed there: the new run is in place, the earlier one hidden beside it until the next command
    code, *_ = _stop([*RUN, "--seed", "2", "--no-video", "--out", "R"], tmp_path, "exchanged", signal.SIGKILL)
    assert code == -signal.SIGKILL and _seed(target) == 2 and _complete(target)["complete"]
    assert len(_hidden(tmp_path)) >= 1
    assert twin(*RUN, "--no-video", "--out", tmp_path / "R")[0] == 0 and _hidden(tmp_path) == []


def test_an_interrupt_before_anything_is_written_says_so_and_exits_130_not_1(tmp_path):
    # SIGINT used to end in "error: aborted" and exit status 1, a failed bound's
    code, _, err, sid = _stop([*RUN, "--no-video", "--out", "fresh"], tmp_path, "trajectory", signal.SIGINT)
    assert code == 130
    _one_line(err, "interrupted: SIGINT; nothing of this run was written (fresh was not created)")
    assert not (tmp_path / "fresh").exists() and _hidden(tmp_path) == []
    _no_process_left(sid)


def test_sigterm_of_any_command_is_143_with_one_line(tmp_path):
    f = write_short(tmp_path)
    code, out, err, sid = _stop(["check", f, "--seeds", "2", "--workers", "1"], tmp_path, "check-run", signal.SIGTERM)
    assert code == 143 and _one_line(err) == "interrupted: SIGTERM", err
    _no_process_left(sid)


# ---- twin check --record killed at several points ------------------------------------------------------

@pytest.fixture(scope="module")
def gold(tmp_path_factory):
    """(scenario file, a complete golden directory of the short scenario, IT2 seed 0)."""
    d = tmp_path_factory.mktemp("gold")
    f = write_short(d)
    status, out, err = twin("check", f, "--workers", "1", "--record", d / "gold")
    assert status == 0, out + err
    doc = _complete(d / "gold")
    assert list(doc["files"]) == ["short/it2/seed-0.npz"] and doc["command"] == "twin check --record"
    return f, d / "gold"


RECORD_MORE = ("--controller", "it2,lqr", "--seeds", "2", "--workers", "1")  # four references, two replaced


@pytest.mark.parametrize("point, sig", [("check-run", signal.SIGINT), ("record", signal.SIGTERM),
                                        ("record", signal.SIGINT)])
def test_an_interrupted_record_leaves_the_golden_directory_as_it_was(gold, tmp_path, point, sig):
    f, original = gold
    copy = shutil.copytree(original, tmp_path / "gold")
    before = (copy / rundir.MANIFEST).read_bytes()
    code, _, err, sid = _stop(["check", f, *RECORD_MORE, "--record", copy], tmp_path, point, sig)
    assert code == 128 + sig, err
    _one_line(err, f"interrupted: {signal.Signals(sig).name}; nothing recorded: {copy} is as it was")
    assert (copy / rundir.MANIFEST).read_bytes() == before
    _complete(copy)
    assert _hidden(copy) == []
    _no_process_left(sid)


def test_a_record_interrupted_during_its_commit_finishes_it_first(gold, tmp_path):
    f, original = gold
    copy = shutil.copytree(original, tmp_path / "gold")
    code, _, err, _ = _stop(["check", f, *RECORD_MORE, "--record", copy], tmp_path, "record-commit", signal.SIGINT)
    assert code == 130
    _one_line(err, f"interrupted: SIGINT; the record is complete: {copy} holds all 4 references (manifest.json)")
    doc = _complete(copy)
    assert sorted(doc["files"]) == ["short/it2/seed-0.npz", "short/it2/seed-1.npz", "short/lqr/seed-0.npz",
                                    "short/lqr/seed-1.npz"]
    assert twin("check", f, *RECORD_MORE, "--golden", copy)[0] == 0


def test_a_killed_record_is_as_it_was_or_finished_by_the_next_command(gold, tmp_path):
    f, original = gold
    # killed while writing its files: the directory as it was, the unfinished file hidden, cleared next time
    copy = shutil.copytree(original, tmp_path / "a")
    code, *_ = _stop(["check", f, *RECORD_MORE, "--record", copy], tmp_path, "record", signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert (copy / rundir.MANIFEST).read_bytes() == (original / rundir.MANIFEST).read_bytes()
    assert len(_hidden(copy)) == 1 and twin("check", f, "--workers", "1", "--golden", copy)[0] == 0
    assert twin("check", f, "--controller", "lqr", "--workers", "1", "--record", copy)[0] == 0
    assert _hidden(copy) == [] and sorted(_complete(copy)["files"]) == ["short/it2/seed-0.npz", "short/lqr/seed-0.npz"]
    # killed in its commit, some files renamed (issue 39: the references were then refused until recorded
    # again): its journal says what goes where, and the next reader carries the commit through
    for name, reader in (("b", lambda copy: twin("check", f, *RECORD_MORE, "--golden", copy)),
                         ("c", lambda copy: twin("compare", copy / "short" / "it2" / "seed-0.npz",
                                                 copy / "short" / "it2" / "seed-0.npz")),
                         ("d", lambda copy: twin("check", f, "--controller", "lqr", "--workers", "1", "--record",
                                                 copy))):
        copy = shutil.copytree(original, tmp_path / name)
        code, *_ = _stop(["check", f, *RECORD_MORE, "--record", copy], tmp_path, "record-commit", signal.SIGKILL)
        assert code == -signal.SIGKILL and (copy / rundir.JOURNAL).exists()
        assert (copy / rundir.MANIFEST).read_bytes() == (original / rundir.MANIFEST).read_bytes()  # not yet new
        status, out, err = reader(copy)
        assert status == 0, out + err
        assert not (copy / rundir.JOURNAL).exists() and _hidden(copy) == []
        assert sorted(_complete(copy)["files"]) == ["short/it2/seed-0.npz", "short/it2/seed-1.npz",
                                                    "short/lqr/seed-0.npz", "short/lqr/seed-1.npz"]
        assert twin("check", f, *RECORD_MORE, "--golden", copy)[0] == 0  # every reference the new record's


def test_a_reference_changed_after_its_record_is_refused_by_every_reader(gold, tmp_path):
    f, original = gold
    copy = shutil.copytree(original, tmp_path / "gold")
    ref = copy / "short" / "it2" / "seed-0.npz"
    with __import__("numpy").load(ref) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["data"][3, 1] += 1.0  # a valid archive, but not the one recorded
    with open(ref, "wb") as fh:
        __import__("numpy").savez_compressed(fh, **arrays)
    with pytest.raises(TwinError, match="not the file .*manifest.json lists"):
        golden.load(ref)
    status, out, err = twin("compare", ref, original / "short" / "it2" / "seed-0.npz")
    assert_one_line_error(status, out, err, f"{ref}: not the file {copy / 'manifest.json'} lists")
    # a reference copied out of its directory is read on its own
    alone = shutil.copy(original / "short" / "it2" / "seed-0.npz", tmp_path / "alone.npz")
    assert golden.load(alone)[1]["scenario"] == "short"


# ---- run directories: never mixed, and readers that check -----------------------------------------------

def test_a_run_directory_without_a_manifest_or_with_changed_files_is_refused_as_incomplete(earlier, tmp_path):
    target = _copy(earlier, tmp_path)
    raw = (target / "trajectory.csv").read_bytes()
    i = raw.index(b"0.", 5000)
    (target / "trajectory.csv").write_bytes(raw[:i] + b"1." + raw[i + 2:])  # a value changed, the size the same
    status, out, err = twin("compare", earlier, target)
    assert_one_line_error(status, out, err, f"{target / 'trajectory.csv'}: not the file",
                          "its SHA-256 is not the one listed")
    (target / "trajectory.csv").write_bytes(raw[:5000])  # cut short
    status, out, err = twin("compare", earlier, target)
    assert_one_line_error(status, out, err, f"{target / 'trajectory.csv'}: not the file", "changed or cut short")
    (target / rundir.MANIFEST).unlink()
    status, out, err = twin("compare", earlier, target)
    assert_one_line_error(status, out, err, f"{target}: an incomplete run directory: no manifest.json")


def test_a_new_run_replaces_the_whole_directory_and_refuses_one_holding_other_files(earlier, tmp_path,
                                                                                       monkeypatch):
    target = _copy(earlier, tmp_path)
    status, _, err = twin(*RUN, "--seed", "3", "--no-video", "--log-format", "csv.gz", "--out", target)
    assert status == 0, err
    assert sorted(_complete(target)["files"]) == ["figure.png", "metrics.json", "trajectory.csv.gz"]
    (target / "notes.txt").write_text("mine")
    status, out, err = twin(*RUN, "--no-video", "--out", target)
    assert_one_line_error(status, out, err, f"{target}: holds notes.txt, which no run wrote", "give another --out")
    assert (target / "notes.txt").read_text() == "mine" and _seed(target) == 3
    monkeypatch.chdir(tmp_path)  # the current directory (or one above it) would be swapped from under the shell
    status, out, err = twin(*RUN, "--no-video", "--out", ".")
    assert_one_line_error(status, out, err, ".: is the current directory or holds it")


def test_a_directory_another_command_holds_is_refused(earlier, tmp_path):
    held = _copy(earlier, tmp_path)
    with rundir.lock(held, "twin sweep"):
        for args in ([*RUN, "--no-video", "--out", held],
                     ["run", "paper-exp1", "--set", "plant.model=analytic", "--duration", "0.2", "--out", held],
                     ["check", "paper-exp1", "--controller", "lqr", "--record", held],
                     ["compare", earlier, earlier, "--out", held]):
            status, out, err = twin(*args)
            assert_one_line_error(status, out, err, f"{held} is in use by 'twin sweep' (process {os.getpid()})")
    _unchanged(held, earlier)


def test_twin_run_on_the_analytic_model_writes_its_directory_as_a_unit(tmp_path):
    """What 'twin analytic' wrote before issue 27, through twin run: a whole directory with its
    manifest, which twin compare reads; an old 'twin analytic' directory is refused in one line
    naming the twin run that makes a comparable one, and a twin run may replace it."""
    out = tmp_path / "exp1"
    status, stdout, err = twin("run", "paper-exp1", "--controller", "t1", "--duration", "0.5", "--set",
                               "plant.model=analytic", "--set", "plant.scale={}", "--set", "sensors.sensing=ideal",
                               "--no-video", "--out", out)
    assert status == 0, err
    doc = _complete(out)
    assert doc["command"] == "twin run" and sorted(doc["files"]) == [
        "design.json", "figure.png", "metrics.json", "trajectory.csv"]
    status, stdout, err = twin("compare", out, out)
    assert status == 0, err
    old = tmp_path / "old"  # what 'twin analytic 1 --controller t1' left
    staged = rundir.StagedDirectory(old, "twin analytic", "paper experiment")
    for name in ("design.json", "figure.png", "trajectory_t1.csv"):
        (staged.path / name).write_bytes((out / name if name != "trajectory_t1.csv" else out / "trajectory.csv")
                                         .read_bytes())
    (staged.path / "metrics.json").write_text('{"experiment": "paper-exp1", "controllers": {"t1": {}}}')
    staged.commit(0)
    staged.close()  # held from its making to here, as a command holds its output directory
    assert _complete(old)["command"] == "twin analytic"
    status, stdout, err = twin("compare", out, old)
    assert_one_line_error(status, stdout, err, f"{old}: a directory of 'twin analytic', which gave way to 'twin run'",
                          "'twin run paper-expN --set plant.model=analytic --set plant.scale={} --set "
                          "sensors.sensing=ideal'")
    status, stdout, err = twin(*RUN, "--no-video", "--out", old)  # its outputs are a run's: replaced
    assert status == 0, err
    assert _complete(old)["command"] == "twin run"


# ---- a full disk ---------------------------------------------------------------------------------------

@pytest.fixture
def small_disk(tmp_path):
    """A mount point for a tmpfs of a given size (KiB); skipped where mounting is not allowed."""
    mounted = []

    def make(kib: int) -> Path:
        where = tmp_path / f"disk{len(mounted)}"
        where.mkdir()
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={kib}k", "tmpfs", str(where)], capture_output=True)
        if r.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip()}): the mocked test stands in")
        mounted.append(where)
        return where

    yield make
    for where in mounted:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def test_a_full_disk_while_writing_the_data_leaves_nothing_that_looks_complete(small_disk):
    disk = small_disk(64)  # the trajectory (120 kB) does not fit
    status, out, err = twin(*RUN, "--no-video", "--out", disk / "R")
    _error(status, err, f"cannot write {disk / 'R' / 'trajectory.csv'}: No space left on device",
                          "nothing of this run was written")
    assert sorted(os.listdir(disk)) == []


def test_a_full_disk_while_drawing_keeps_the_data_marked_incomplete(small_disk):
    disk = small_disk(160)  # the data (125 kB) fits, the figure (170 kB) does not
    status, out, err = twin(*RUN, "--no-video", "--out", disk / "R")
    _error(status, err, f"cannot write {disk / 'R' / 'figure.png'}: No space left on device",
                          "kept metrics.json and trajectory.csv", "without figure.png", "exit status 2")
    doc = _complete(disk / "R")
    assert (doc["complete"], doc["missing"], doc["exit_status"]) == (False, ["figure.png"], 2)
    assert sorted(os.listdir(disk)) == ["R"]


def test_a_full_disk_while_recording_leaves_the_golden_directory_as_it_was(gold, small_disk):
    f, original = gold
    disk = small_disk(96)  # the reference there (30 kB) and three more do not fit
    copy = shutil.copytree(original, disk / "gold")
    before = (copy / rundir.MANIFEST).read_bytes()
    status, out, err = twin("check", f, *RECORD_MORE, "--record", copy)
    assert status == 2 and "Traceback" not in err
    line = [x for x in err.splitlines() if x.startswith("error: ")]
    assert line == [f"error: cannot record into {copy}: No space left on device; nothing recorded: {copy} is as it "
                    "was"], err
    assert (copy / rundir.MANIFEST).read_bytes() == before and _hidden(copy) == []


def test_a_mount_point_is_refused_as_an_output_directory(small_disk):
    disk = small_disk(64)
    status, out, err = twin(*RUN, "--no-video", "--out", disk)
    assert_one_line_error(status, out, err, f"{disk}: is a mount point", f"--out {disk / 'run'}")


def test_a_write_error_is_one_line_and_the_target_as_it_was_mocked(earlier, tmp_path, monkeypatch):
    """The full disk of the tests above, without a tmpfs: the trajectory's writer fails half-way."""
    from twin.outputs import run_directory as runner

    real = runner.write_trajectories_csv

    def full(runs, path):
        path.write_bytes(b"controller,t [s]\r\nlqr,0.0")  # a part of it, then the disk is full
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    target = _copy(earlier, tmp_path)
    monkeypatch.setattr(runner, "write_trajectories_csv", full)
    status, out, err = twin(*RUN, "--seed", "1", "--video", "--out", target)
    _error(status, err, f"cannot write {target / 'trajectory.csv'}: No space left on device; "
                                            f"nothing of this run was written: {target} is as it was")
    _unchanged(target, earlier)
    assert _hidden(tmp_path) == []
    monkeypatch.setattr(runner, "write_trajectories_csv", real)


# ---- outputs never leave the directory named -----------------------------------------------------------

HOSTILE = ["../..", ".", "..", "/tmp/elsewhere", "a/../../b", "ok\x00bad", "", "runs/../..", "x/y"]


@pytest.mark.parametrize("name", HOSTILE)
def test_a_default_output_directory_stays_one_directory_inside_runs(tmp_path, name):
    with pytest.raises(TwinError, match="not in a directory of its own inside") as info:
        rundir.child_of(tmp_path / "runs", name, "the scenario's name")
    assert "\n" not in str(info.value)
    assert rundir.child_of(tmp_path / "runs", "paper-exp1", "the scenario's name") == tmp_path / "runs" / "paper-exp1"


def test_a_default_output_directory_linked_elsewhere_is_refused(tmp_path):
    (tmp_path / "runs").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "runs" / "link").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(TwinError, match="would put the outputs at .*elsewhere"):
        rundir.child_of(tmp_path / "runs", "link", "the scenario's name")


def _tree(root: Path) -> dict:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for p in root.rglob("*")}


@pytest.mark.parametrize("name", HOSTILE)
def test_a_hostile_scenario_name_writes_nothing_outside(tmp_path, name):
    """Set in a scenario file: refused (by the schema, and by the containment check behind it),
    and nothing anywhere changed; a user's run directory where "../.." points is untouched."""
    work = tmp_path / "project" / "sub"
    work.mkdir(parents=True)
    victim = tmp_path / "project" / "victim"  # a user's run directory
    victim.mkdir()
    (victim / "video.mp4").write_bytes(b"a user's video")
    (victim / "metrics.json").write_text("{}")
    toml = work / "v.toml"
    toml.write_text(f"name = {json.dumps(name)}\nduration = 0.2\n", encoding="utf-8")
    before = _tree(tmp_path)
    r = subprocess.run([sys.executable, "-m", "twin.cli", "run", str(toml), "--no-video", "--controller", "lqr"],
                       cwd=work, capture_output=True, text=True, timeout=300)
    if name == "":  # no name: the file's, "v"
        assert r.returncode == 0 and (work / "runs" / "v" / rundir.MANIFEST).exists(), r.stderr
        return
    assert r.returncode == 2 and "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("name", [n for n in HOSTILE if n])
def test_the_containment_check_holds_when_a_name_gets_past_the_schema(tmp_path, monkeypatch, name):
    from twin.scenarios.scenario import Scenario

    monkeypatch.setattr(Scenario, "name", property(lambda self: name))  # as if the schema had let it through
    monkeypatch.chdir(tmp_path)
    before = _tree(tmp_path)
    commands = [[*RUN[:2], "--duration", "0.2", "--controller", "lqr", "--no-video"]]
    if name not in (".", ".."):  # runs/sweep-. would be a directory inside runs/ like any other
        commands.append(["sweep", "paper-exp1", "--samples", "1", "--duration", "0.2"])
    for args in commands:
        status, out, err = twin(*args)
        assert_one_line_error(status, out, err, "the scenario's name", "not in a directory of its own inside")
    assert _tree(tmp_path) == before
    # a replayed sample's directory, runs/<name>-sample<K>: refused, or one directory inside runs/
    status, out, err = twin(*RUN[:2], "--sample", "0", "--duration", "0.2", "--controller", "lqr", "--no-video")
    new = {Path(p) for p in set(_tree(tmp_path)) - set(before)}
    if status == 2:
        assert_one_line_error(status, out, err, "the scenario's name", "not in a directory of its own inside")
    else:
        assert status == 0, err
        assert {p.parts[:2] for p in new if len(p.parts) > 1} == {("runs", f"{name}-sample0".split("/")[-1])}
        assert (tmp_path / "runs").resolve() in (tmp_path / "runs" / f"{name}-sample0").resolve().parents
    # and the golden files' paths, which come from the names too, stay inside their directory
    root = tmp_path / "gold"
    for part in (name, "..", "."):
        path = golden.path_for(root, part, part, 0)
        assert root.resolve() in path.resolve().parents and len(path.relative_to(root).parts) == 3
