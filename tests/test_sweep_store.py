"""A sweep resumes only what it can vouch for (issue 26): the configuration hash every stored
sample carries, stores of another configuration or without a manifest refused in one line,
damaged lines named, the draws a report states, the lock on a folder in use, and per-sample
limits. Small sweeps (2 draws × 2 levels of a 1 s paper-exp2), so each runs in seconds.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from slow_plugin import write_slow_plugin
from test_scenarios import twin
from twin.scenarios import load_scenario
from twin.outputs import rundir
from twin.sweep.table import read_sweep_csv

SETS = ["--set", "duration=1.0", "--set", "sweep.levels=[0.0, 0.3]", "--set", "sweep.initial_theta=[0.3, 0.5]"]
DRAWS = 2
STORE = ("sweep.json", "samples.jsonl")


def sweep_cli(out: Path, *extra, env=None, cwd=None):
    """``twin sweep`` in a subprocess, outside the source tree (see tests/test_sweep.py)."""
    cmd = [sys.executable, "-m", "twin.cli", "sweep", "paper-exp2", "--samples", str(DRAWS), *SETS, "--out", str(out),
           *extra]
    return subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, **(env or {})},
                          cwd=cwd or Path(out).parent, timeout=600)


def sweep_here(out: Path, *extra):
    """``twin sweep`` in this process: (status, stdout, stderr)."""
    return twin("sweep", "paper-exp2", "--samples", DRAWS, *SETS, "--out", out, *extra)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("store") / "ref"
    r = sweep_cli(out, "--workers", "2")
    assert r.returncode == 0, r.stderr
    return out


def assert_one_line_error(status, stdout, stderr, *fragments):
    """Exit status 2 and one line ``error: ...`` on stderr holding every fragment (stdout may
    hold the sweep's title: the refusal comes once the sweep has said what it is)."""
    assert status == 2, (status, stdout, stderr)
    assert "Traceback" not in stderr, stderr
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


def sample_lines(reference: Path) -> list:
    """The reference's samples.jsonl lines in the order of their sample numbers (two workers
    append them in the order they finish, which varies from run to run)."""
    lines = (reference / "samples.jsonl").read_bytes().splitlines(keepends=True)
    return sorted(lines, key=lambda line: json.loads(line)["sample"])


def copy_store(reference: Path, out: Path, names=STORE) -> Path:
    """A copy of the reference's store, its samples in order (line n holds sample n − 1)."""
    out.mkdir()
    for name in names:
        if name == "samples.jsonl":
            (out / name).write_bytes(b"".join(sample_lines(reference)))
        else:
            shutil.copyfile(reference / name, out / name)
    return out


def snapshot(out: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.is_file() and p.name != ".twin.lock"}


# ---- what a store records ----------------------------------------------------------------------------

def test_every_sample_carries_the_configuration_hash_of_the_manifest(reference):
    from twin.sweep.store import CONFIG_KEY, config_hash, config_of

    doc = json.loads((reference / "sweep.json").read_text())
    assert doc["format"] == 2 and doc["draws"] == DRAWS and list(doc)[-1] == "environment"
    assert doc[CONFIG_KEY] == config_hash(config_of(doc))
    lines = (reference / "samples.jsonl").read_text().splitlines()
    assert len(lines) == 4 and all(json.loads(line)["config"] == doc[CONFIG_KEY] for line in lines)
    # the report is sealed last: manifest.json lists every file of the folder with its SHA-256
    manifest = json.loads((reference / "manifest.json").read_text())
    assert manifest["command"] == "twin sweep" and manifest["exit_status"] == 0
    assert set(manifest["files"]) == {"sweep.json", "samples.jsonl", "sweep.csv", "summary.md", "summary.json",
                                      "success.png", "distributions.png", "paired.png"}


def test_what_the_configuration_covers_and_what_it_does_not():
    from twin.sweep.store import config_hash, config_of

    def h(**change):
        sc = load_scenario("paper-exp2", ["duration=1.0"])
        m = {"scenario": json.loads(json.dumps(sc.data)), "root_seed": 0, "controllers": ["it2", "t1"],
             "environment": {"designs": {"balance": "abc"}, "blas": {"kernel": "Haswell"}}, "plugins": {},
             "sampling": 1, "draws": 5, "overrides": [], "source": "x"}
        for k, v in change.items():
            if k.startswith("scenario."):
                tree = m["scenario"]
                *path, last = k.split(".")[1:]
                for p in path:
                    tree = tree[p]
                tree[last] = v
            else:
                m[k] = v
        return config_hash(config_of(m))

    base = h()
    # what changes what a sample is or what is stored for it
    for change in ({"scenario.duration": 2.0}, {"scenario.sweep.levels": [0.0, 0.5]}, {"root_seed": 1},
                   {"controllers": ["t1", "it2"]}, {"environment": {"designs": {"balance": "abd"}}},
                   {"plugins": {"controller m:C": "00"}}, {"sampling": 2}, {"scenario.sweep.success_position_tol": 0.1},
                   {"scenario.plant.scale": {"m_b": 1.1}}):
        assert h(**change) != base, change
    # what does not: how many draws, where and how it ran, how it is named, and text
    for change in ({"draws": 50}, {"environment": {"designs": {"balance": "abc"}, "blas": {"kernel": "SkylakeX"}}},
                   {"overrides": ["duration=1"]}, {"source": "y"}, {"scenario.description": "other words"},
                   {"scenario.name": "renamed"}, {"scenario.seed": 7}, {"scenario.video.fps": 60},
                   {"scenario.controller.kinds": ["lqr"]}):
        assert h(**change) == base, change


def test_the_sampling_code_still_gives_the_pinned_sample():
    """If this fails because sample_scenario was changed on purpose, raise SAMPLES_VERSION in
    twin/sweep/sampling.py (stores of the old samples are then refused, not mixed) and pin anew."""
    from twin.sweep.sampling import SAMPLES_VERSION, sample_scenario

    import hashlib

    sc = load_scenario("paper-exp2", ["sweep.levels=[0.0, 0.3]", "sweep.initial_theta=[0.3, 0.5]",
                                      "sweep.push_count=1"])
    s = sample_scenario(sc, 7, 3)
    assert SAMPLES_VERSION == 1
    assert (s.draw, s.level, s.seed) == (1, 0.3, 2021251017632032385)
    assert (s.values["factor_m_b"], s.values["push1_force_n"]) == (1.3451648663038984, 8.872607657291802)
    d = s.scenario.data  # everything the sample sets, by its exact bits
    sampled = json.dumps([s.values, d["pushes"], d["plant"]["scale"], d["initial"], d["seed"]], sort_keys=True)
    assert hashlib.sha256(sampled.encode()).hexdigest() == \
        "1bc0d9218cfaa8687fe0bb5f7cd55dd16a3ca196abf27d511a5c97751a978b9a"


# ---- refused: another configuration, no manifest, damaged lines ------------------------------------------

@pytest.mark.parametrize("extra, fragment", [
    (["--set", "sweep.levels=[0.5, 0.6]"], "scenario.sweep.levels (stored [0.0, 0.3], now [0.5, 0.6])"),
    (["--seed", "4"], "root_seed (stored 0, now 4)"),
    (["--controller", "it2,t1,lqr"], 'controllers (stored ["it2", "t1"], now ["it2", "t1", "lqr"])'),
    (["--set", "duration=1.5"], "scenario.duration (stored 1.0, now 1.5)"),
])
def test_a_store_of_another_configuration_is_refused_naming_what_differs(reference, tmp_path, extra, fragment):
    out = copy_store(reference, tmp_path / "other")
    before = snapshot(out)
    status, stdout, stderr = sweep_here(out, *extra)
    assert_one_line_error(status, stdout, stderr, f"{out} holds a different sweep", fragment, "use another --out",
                          f"delete {out}")
    assert snapshot(out) == before  # nothing touched


def test_samples_without_a_manifest_are_refused(reference, tmp_path):
    """The issue's case: a samples.jsonl copied into a fresh folder gave "ran 0 samples" and a
    report of other levels."""
    out = copy_store(reference, tmp_path / "copied", names=("samples.jsonl",))
    status, stdout, stderr = sweep_here(out, "--set", "sweep.levels=[0.5, 0.6]")
    assert_one_line_error(status, stdout, stderr, "samples.jsonl holds samples", "no sweep.json",
                          "use another --out")
    assert sorted(p.name for p in out.iterdir() if p.name != ".twin.lock") == ["samples.jsonl"]


def test_a_line_of_another_configuration_is_refused(reference, tmp_path):
    out = copy_store(reference, tmp_path / "mixed")
    lines = (out / "samples.jsonl").read_text().splitlines(keepends=True)
    alien = json.loads(lines[1])
    alien["config"] = "0" * 64
    lines[1] = json.dumps(alien, separators=(",", ":")) + "\n"
    (out / "samples.jsonl").write_text("".join(lines))
    before = snapshot(out)
    status, stdout, stderr = sweep_here(out)
    assert_one_line_error(status, stdout, stderr, "samples.jsonl line 2: sample 1 was produced by another "
                          "configuration", "delete that line")
    assert snapshot(out) == before


def _line(reference: Path, n: int) -> dict:
    return json.loads(sample_lines(reference)[n])


@pytest.mark.parametrize("line, fragment", [
    (b"5\n", "5 is not a sample record"),
    (b"null\n", "null is not a sample record"),
    (b"[1, 2]\n", "[1, 2] is not a sample record"),
    (b"\n", "not JSON"),
    (b'{"sample": 1, "draw": \n', "not JSON"),
    (b"\xff\xfe{}\n", "not JSON"),
    (b'{"draw": 0, "runs": {}}\n', 'no sample number ("sample": a non-negative integer)'),
    (b'{"sample": -1}\n', '"sample" is -1, not a non-negative integer'),
    (b'{"sample": true}\n', '"sample" is true, not a non-negative integer'),
    (b'{"sample": 1}\n', "sample 1 carries no configuration hash"),
    ("no-runs", "sample 1: no \"runs\""),
    ("wrong-draw", "sample 1: \"draw\" is 7, not 0"),
    ("repeat", "sample 0 again (first on line 1)"),
])
def test_damaged_lines_are_one_line_errors_naming_the_line(reference, tmp_path, line, fragment):
    out = copy_store(reference, tmp_path / "damaged")
    lines = (out / "samples.jsonl").read_bytes().splitlines(keepends=True)
    if line == "no-runs":
        rec = _line(reference, 1)
        del rec["runs"]
        line = json.dumps(rec).encode() + b"\n"
    elif line == "wrong-draw":
        rec = _line(reference, 1)
        rec["draw"] = 7
        line = json.dumps(rec).encode() + b"\n"
    elif line == "repeat":
        line = lines[0]
    lines[1] = line
    (out / "samples.jsonl").write_bytes(b"".join(lines))
    before = snapshot(out)
    status, stdout, stderr = sweep_here(out)
    assert_one_line_error(status, stdout, stderr, f"{out / 'samples.jsonl'} line 2: ", fragment,
                          "delete that line")
    assert snapshot(out) == before  # nothing lost: the user decides what to delete


def test_a_torn_last_line_is_dropped_even_if_it_parses(reference, tmp_path):
    """What a kill can leave: the last line without its newline (here all of it but the
    newline, which parses as JSON): dropped, and its sample runs again."""
    out = copy_store(reference, tmp_path / "torn")
    raw = (out / "samples.jsonl").read_bytes()
    (out / "samples.jsonl").write_bytes(raw[:-1])
    r = sweep_cli(out, "--workers", "1")
    assert r.returncode == 0, r.stderr
    assert "ran 1 sample (" in r.stdout
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()


def test_a_manifest_changed_by_hand_is_refused(reference, tmp_path):
    out = copy_store(reference, tmp_path / "edited")
    doc = json.loads((out / "sweep.json").read_text())
    doc["scenario"]["sweep"]["levels"] = [0.5, 0.6]  # the configuration hash left as it was
    (out / "sweep.json").write_text(json.dumps(doc))
    status, stdout, stderr = sweep_here(out, "--set", "sweep.levels=[0.5, 0.6]")
    assert_one_line_error(status, stdout, stderr, "sweep.json was changed by hand", "config_sha256")


@pytest.mark.parametrize("text, fragment", [("{not json", "not a sweep manifest"),
                                            ("[1]", "not a sweep manifest"),
                                            ('{"format": 9, "scenario": {}, "root_seed": 0, "controllers": []}',
                                             "format 9, which this mtwip-twin does not read")])
def test_an_unreadable_manifest_is_one_line(reference, tmp_path, text, fragment):
    out = copy_store(reference, tmp_path / "bad", names=())
    (out / "sweep.json").write_text(text)
    status, stdout, stderr = sweep_here(out)
    assert_one_line_error(status, stdout, stderr, fragment)


# ---- resumed: what must not invalidate, older stores, the draws reported ------------------------------------

def test_workers_backend_and_reference_do_not_invalidate_a_store(reference, tmp_path):
    out = copy_store(reference, tmp_path / "same")
    status, stdout, stderr = sweep_here(out, "--workers", "1", "--reference", "it2")
    assert status == 0, stderr
    assert "ran 0 samples" in stdout and "4 were already finished" in stdout
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()


def test_a_store_of_format_1_is_upgraded_and_resumed(reference, tmp_path):
    """A sweep begun before configuration hashes: its manifest, checked as before, vouches for
    its samples, which are then stamped."""
    from twin.sweep.store import CONFIG_KEY

    out = tmp_path / "old"
    out.mkdir()
    doc = json.loads((reference / "sweep.json").read_text())
    old = {"format": 1, **{k: v for k, v in doc.items() if k not in ("format", CONFIG_KEY, "plugins", "sampling")}}
    (out / "sweep.json").write_text(json.dumps(old, indent=1) + "\n")
    lines = [json.loads(line) for line in sample_lines(reference)[:3]]
    for rec in lines:
        del rec["config"]
    (out / "samples.jsonl").write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in lines))
    r = sweep_cli(out, "--workers", "1")
    assert r.returncode == 0, r.stderr
    assert "ran 1 sample (" in r.stdout and "3 were already finished" in r.stdout
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()
    new = json.loads((out / "sweep.json").read_text())
    assert new["format"] == 2 and new[CONFIG_KEY] == doc[CONFIG_KEY]
    assert all(json.loads(line)["config"] == doc[CONFIG_KEY]
               for line in (out / "samples.jsonl").read_text().splitlines())


def test_the_report_states_the_draws_in_it_and_keeps_the_others(reference, tmp_path):
    """The issue's case: after a rerun with fewer --samples the report said the larger number."""
    out = copy_store(reference, tmp_path / "fewer")
    stored = (out / "samples.jsonl").read_bytes()
    status, stdout, stderr = twin("sweep", "paper-exp2", "--samples", 1, *SETS, "--out", out)
    assert status == 0, stderr
    assert "ran 0 samples" in stdout and "2 were already finished" in stdout
    assert "2 samples (1 draw × 2 levels" in (out / "summary.md").read_text()
    assert json.loads((out / "sweep.json").read_text())["draws"] == 1
    notes = json.loads((out / "summary.json").read_text())["notes"]
    assert any("2 samples (1 draw × 2 levels" in n for n in notes)
    assert sorted({r["sample"] for r in read_sweep_csv(out / "sweep.csv")}) == [0, 1]
    assert (out / "samples.jsonl").read_bytes() == stored  # the second draw's samples are kept for later
    status, stdout, stderr = sweep_here(out)
    assert status == 0 and "ran 0 samples" in stdout, stderr
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()
    assert json.loads((out / "sweep.json").read_text())["draws"] == DRAWS


def stop_at(point: str, tmp_path: Path, cmd: list, cwd: Path):
    """Start ``cmd`` with the test hook :func:`twin.outputs.rundir.test_point` set at ``point``; the
    process once it waits there."""
    marker = tmp_path / f"stopped-at-{point}"
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=cwd,
                            env={**os.environ, "TWIN_TEST_STOP_AT": f"{point}:{marker}"})
    deadline = time.monotonic() + 120
    while not marker.exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.02)
    return proc


@pytest.mark.parametrize("point", ["sweep-sample", "sweep-report"])
def test_an_interrupted_rerun_leaves_no_report_that_looks_complete(reference, tmp_path, point):
    """The earlier report is deleted before any sample runs and the folder sealed by
    manifest.json last: interrupted while it samples or while it writes the report, a rerun
    with more draws leaves a folder without manifest.json and no report of the earlier run;
    the next rerun finishes it."""
    out = copy_store(reference, tmp_path / "grown", names=STORE + ("sweep.csv", "summary.md", "manifest.json"))
    cmd = [sys.executable, "-m", "twin.cli", "sweep", "paper-exp2", "--samples", "3", *SETS, "--out", str(out),
           "--workers", "1"]
    proc = stop_at(point, tmp_path, cmd, tmp_path)
    proc.terminate()
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.splitlines()[-1].startswith("interrupted: SIGTERM; "), err
    assert not (out / "manifest.json").exists()
    if point == "sweep-sample":  # the earlier report is gone, not left beside samples it does not cover
        assert not (out / "sweep.csv").exists() and not (out / "summary.md").exists()
        assert (out / "samples.jsonl").read_bytes().count(b"\n") == 5
    assert json.loads((out / "sweep.json").read_text())["draws"] == 3
    r = sweep_cli(out, "--workers", "2")  # back to 2 draws: nothing to run, the report of those
    assert r.returncode == 0, r.stderr
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()
    assert (out / "manifest.json").exists()


# ---- a folder in use ---------------------------------------------------------------------------------

def test_a_folder_a_sweep_is_using_is_refused_to_other_commands(reference, tmp_path):
    out = tmp_path / "busy"
    # 40 samples of 3 s: still running when it is terminated below, also on a fast machine (with 8 it could
    # reach its report, or exit, while the two commands ran: another window than the one tested here)
    proc = subprocess.Popen([sys.executable, "-m", "twin.cli", "sweep", "paper-exp2", "--samples", "20", *SETS,
                             "--set", "duration=3.0", "--out", str(out), "--workers", "1"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        deadline = time.monotonic() + 120
        lock = rundir.lock_path(out)  # beside the folder: .busy.twin-lock
        while not (out / "samples.jsonl").exists() or not lock.exists() or not lock.read_text().strip():
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.02)
        holder = f"'twin sweep' (process {proc.pid})"
        status, stdout, stderr = sweep_here(out)
        assert_one_line_error(status, stdout, stderr, f"{out} is in use by {holder}")
        status, stdout, stderr = twin("run", "paper-exp2", "--set", "duration=0.5", "--no-video", "--out", out)
        assert status == 2 and "Traceback" not in stderr, stderr
        assert len(stderr.splitlines()) == 1 and "in use by" in stderr and holder in stderr, stderr
        assert proc.poll() is None  # the sweep was not disturbed
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert not (out / "metrics.json").exists()


# ---- limits ------------------------------------------------------------------------------------------------



def test_a_run_over_a_limit_is_a_failed_run_of_that_controller_not_a_failed_sweep(tmp_path):
    pytest.importorskip("twin.limits")
    write_slow_plugin(tmp_path, "slowplug", 0.01, first=51)  # slow from its 51st call on
    out = tmp_path / "limited"
    r = sweep_cli(out, "--controller", "slowplug:Slow,it2", "--set", "limits.run_wall_s=0.4", "--workers", "2",
                  cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    rows = read_sweep_csv(out / "sweep.csv")
    slow = [row for row in rows if row["controller"] == "slowplug:Slow"]
    it2 = [row for row in rows if row["controller"] == "it2"]
    assert len(slow) == len(it2) == 4
    for row in slow:
        assert row["status"] == "error" and not row["success"], row
        assert row["error"].startswith("LimitExceeded: ") and "over limits.run_wall_s = 0.4 s" in row["error"], row
    assert all(row["status"] != "error" and row["error"] == "" for row in it2)  # the other's results stand
    assert "4 runs stopped by a limit of [limits]" in (out / "summary.md").read_text()
    assert json.loads((out / "manifest.json").read_text())["exit_status"] == 0


def test_a_sweep_sets_a_run_limit_where_the_scenario_sets_none():
    pytest.importorskip("twin.limits")
    from twin.sweep.runner import RUN_WALL_BASE_S, RUN_WALL_PER_SIMULATED_S, sweep_data

    data = load_scenario("paper-exp2", ["duration=15", "limits.step_wall_s=2"]).data
    limits = sweep_data(data)["limits"]
    assert limits["run_wall_s"] == RUN_WALL_BASE_S + RUN_WALL_PER_SIMULATED_S * 15 == 210.0
    assert limits["step_wall_s"] == 2.0 and data["limits"]["run_wall_s"] is None  # the scenario's own unchanged
    own = load_scenario("paper-exp2", ["limits.run_wall_s=5"]).data
    assert sweep_data(own)["limits"]["run_wall_s"] == 5.0
