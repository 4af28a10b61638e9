"""Monte Carlo sweeps: sampling, determinism, replay, resumption, crashed workers, Ray.

The sweeps here are small (2 draws × 2 levels of a 3 s paper-exp2), so that each
runs in seconds; what they check does not depend on size.
"""
from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from test_scenarios import assert_one_line_error, twin
from twin.scenarios import load_scenario
from twin.sweep.sampling import PERTURBABLE, sample_scenario, sample_seed, success, value_columns
from twin.sweep.table import read_sweep_csv

SETS = ["--set", "duration=3.0", "--set", "sweep.levels=[0.0, 0.3]", "--set", "sweep.push_count=1",
        "--set", "sweep.push_window=[0.5, 2.5]", "--set", "sweep.initial_theta=[0.3, 0.5]"]
OVERRIDES = [SETS[i + 1] for i in range(0, len(SETS), 2)]
DRAWS = 2


def sweep_cli(out, *extra, env=None, **kw):
    """``twin sweep`` in a subprocess (the way a user runs it): the CompletedProcess."""
    cmd = [sys.executable, "-m", "twin.cli", "sweep", "paper-exp2", "--samples", str(DRAWS), *SETS,
           "--out", str(out), *extra]
    # run outside the source tree: there, a non-editable install would import the uncompiled sources,
    # whose pure-Python EKF path agrees with the compiled one to 1e-13, not bit for bit
    return subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, **(env or {})},
                          cwd=Path(out).parent, **kw)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted sweep with 2 local workers: its directory."""
    out = tmp_path_factory.mktemp("sweep") / "ref"
    r = sweep_cli(out, "--workers", "2")
    assert r.returncode == 0, r.stderr
    return out


# ---- sampling --------------------------------------------------------------------------------------

def test_draws_are_shared_by_every_level_and_seeds_are_seedsequence_children():
    sc = load_scenario("paper-exp2", OVERRIDES + ["sweep.levels=[0.0, 0.1, 0.4]"])
    s0, s1, s2 = (sample_scenario(sc, 5, k) for k in (3, 4, 5))  # draw 1 at levels 0, 0.1, 0.4
    assert (s0.draw, s1.draw, s2.draw) == (1, 1, 1) and (s0.level, s1.level, s2.level) == (0.0, 0.1, 0.4)
    assert s0.seed == s1.seed == s2.seed == sample_seed(5, 1)
    child = np.random.SeedSequence(5).spawn(2)[1]
    assert s0.seed == int(child.generate_state(1, np.uint64)[0] >> np.uint64(1))
    base = sc.data["plant"]["scale"]
    for name in PERTURBABLE:
        f0, f1, f2 = (s.values[f"factor_{name}"] / base.get(name, 1.0) for s in (s0, s1, s2))
        assert f0 == 1.0  # level 0: the scenario's own plant
        if name in ("r", "b"):  # geometry is not perturbed unless named
            assert f1 == f2 == 1.0
        else:  # the same unit draw, scaled by the level
            assert abs(f1 - 1.0) <= 0.1 and abs((f2 - 1.0) - 4 * (f1 - 1.0)) < 1e-12
    assert s0.values["initial_theta_rad"] == s2.values["initial_theta_rad"]
    assert 0.3 <= s0.values["initial_theta_rad"] <= 0.5
    assert s0.scenario.data["initial"]["theta"] == s0.values["initial_theta_rad"]
    assert s0.values["push1_start_s"] == s2.values["push1_start_s"] and 0.5 <= s0.values["push1_start_s"] <= 2.5
    assert 5.0 <= abs(s0.values["push1_force_n"]) <= 15.0
    assert list(s0.values) == value_columns(sc)
    # different draws differ; the scenario's own seed is not the sample's
    assert sample_scenario(sc, 5, 0).seed != s0.seed and s0.scenario.seed == s0.seed


def test_settings_do_not_shift_other_draws():
    a = load_scenario("paper-exp2", OVERRIDES)
    b = load_scenario("paper-exp2", OVERRIDES + ['sweep.parameters=["m_b"]'])
    sa, sb = sample_scenario(a, 0, 1), sample_scenario(b, 0, 1)
    assert sa.values["factor_m_b"] == sb.values["factor_m_b"] and sb.values["factor_l"] == 1.08
    assert sa.values["initial_theta_rad"] == sb.values["initial_theta_rad"]
    assert sa.values["push1_force_n"] == sb.values["push1_force_n"]


def test_success_needs_no_fall_settling_and_the_targets():
    sc = load_scenario("paper-exp3", ["sweep.success_position_tol=0.05", "sweep.success_heading_tol=0.1"])
    good = {"fell": False, "status": "ok", "settling_time_s": 2.0, "duration_s": 15.0, "final_position_error_m": -0.049,
            "final_heading_error_rad": 0.099}
    assert success(good, sc) and success({**good, "settling_time_s": 14.0}, sc)
    for change in ({"fell": True, "status": "fell"}, {"settling_time_s": None}, {"final_position_error_m": 0.051},
                   {"final_heading_error_rad": -0.11}, {"settling_time_s": 14.01}):
        assert not success({**good, **change}, sc), change
    assert success({**good, "final_position_error_m": None, "final_heading_error_rad": None}, sc)


# ---- determinism and replay --------------------------------------------------------------------------

def test_the_same_sweep_twice_gives_an_identical_sweep_csv(reference, tmp_path):
    r = sweep_cli(tmp_path / "again", "--workers", "1")
    assert r.returncode == 0, r.stderr
    for name in ("sweep.csv", "summary.json", "summary.md"):
        assert (tmp_path / "again" / name).read_bytes() == (reference / name).read_bytes(), name
    rows = read_sweep_csv(reference / "sweep.csv")
    assert [(r["sample"], r["controller"]) for r in rows] == [(k, c) for k in range(4) for c in ("it2", "t1")]
    assert len({r["seed"] for r in rows}) == DRAWS
    # the sweep is not degenerate: the sampled plants and the outcomes differ
    assert len({r["factor_m_b"] for r in rows}) == 3 and len({r["iae_theta"] for r in rows}) >= 4
    for name in ("success.png", "distributions.png", "paired.png", "summary.md"):
        assert (reference / name).stat().st_size > 1000, name


@pytest.mark.parametrize("sample", [3])
def test_replaying_a_sample_reproduces_its_row(reference, tmp_path, sample):
    rows = [r for r in read_sweep_csv(reference / "sweep.csv") if r["sample"] == sample]
    status, stdout, stderr = twin("run", "paper-exp2", "--sample", sample, "--seed", 0, *SETS, "--no-video",
                                  "--out", tmp_path)
    assert status == 0, stderr
    assert f"sample {sample} of a sweep" in stdout and "level λ = 0.3" in stdout
    doc = json.loads((tmp_path / "metrics.json").read_text())
    assert doc["seed"] == rows[0]["seed"]
    for row in rows:
        metrics = doc["runs"][row["controller"]]
        compared = [k for k in metrics if k in row and k not in ("controller", "seed")]
        assert len(compared) >= 15
        for k in compared:
            assert metrics[k] == row[k], (row["controller"], k, metrics[k], row[k])
    # and the sampled plant is the one the row records
    assert doc["scenario"]["plant"]["scale"]["m_b"] == rows[0]["factor_m_b"]
    assert doc["scenario"]["initial"]["theta"] == rows[0]["initial_theta_rad"]


def test_the_summary_prints_the_replay_command(reference):
    text = (reference / "summary.md").read_text()
    assert "twin run paper-exp2 --sample K --seed 0 --set duration=3.0" in text


# ---- resumption -------------------------------------------------------------------------------------

def _lines(out: Path) -> list[str]:
    p = out / "samples.jsonl"
    return p.read_text().splitlines(keepends=True) if p.exists() else []


def _interrupt(out: Path, sig, env=None) -> subprocess.Popen:
    """Start a one-worker sweep and send ``sig`` to its process group once two samples are stored."""
    cmd = [sys.executable, "-m", "twin.cli", "sweep", "paper-exp2", "--samples", str(DRAWS), *SETS, "--out", str(out),
           "--workers", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "PYTHONFAULTHANDLER": "1", **(env or {})}, cwd=out.parent)
    deadline = time.monotonic() + 120
    while len([line for line in _lines(out) if line.endswith("\n")]) < 2:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the sweep stored no samples in 120 s"
        time.sleep(0.05)
    os.killpg(proc.pid, sig)
    try:  # its output read while it ends (a full pipe would hold it up), and shown if it does not
        out_s, err_s = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:  # where it stands, in every thread (faulthandler), then killed
        os.kill(proc.pid, signal.SIGABRT)
        try:
            out_s, err_s = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            out_s, err_s = proc.communicate()
        pytest.fail(f"the sweep had not ended 60 s after {signal.Signals(sig).name}: {err_s[-3000:]}")
    proc.stdout, proc.stderr = io.StringIO(out_s), io.StringIO(err_s)  # read by the tests as before
    return proc


def test_a_killed_sweep_resumes_without_redoing_finished_samples(reference, tmp_path):
    out = tmp_path / "killed"
    proc = _interrupt(out, signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    before = _lines(out)
    finished = [json.loads(line)["sample"] for line in before if line.endswith("\n")]
    assert 2 <= len(finished) < 4
    r = sweep_cli(out, "--workers", "2")
    assert r.returncode == 0, r.stderr
    n, done = 4 - len(finished), len(finished)
    assert f"ran {n} sample{'s' * (n != 1)}" in r.stdout
    assert f"{done} {'was' if done == 1 else 'were'} already finished" in r.stdout
    after = _lines(out)
    assert after[:len(finished)] == before[:len(finished)]  # finished samples kept as they were
    assert sorted(json.loads(line)["sample"] for line in after) == [0, 1, 2, 3]  # none ran twice
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()
    # a complete sweep reruns nothing and gives the same report
    r = sweep_cli(out)
    assert r.returncode == 0 and "ran 0 samples" in r.stdout and "4 were already finished" in r.stdout
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()


def test_ctrl_c_stops_cleanly_and_the_rerun_finishes(reference, tmp_path):
    out = tmp_path / "interrupted"
    proc = _interrupt(out, signal.SIGINT)
    stderr = proc.stderr.read()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "interrupted: " in stderr and "rerun the same command" in stderr
    r = sweep_cli(out, "--workers", "2")
    assert r.returncode == 0, r.stderr
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()


def test_a_torn_last_line_is_dropped_and_its_sample_runs_again(reference, tmp_path):
    out = tmp_path / "torn"
    out.mkdir()
    for name in ("sweep.json", "samples.jsonl"):
        (out / name).write_bytes((reference / name).read_bytes())
    lines = _lines(out)
    (out / "samples.jsonl").write_text("".join(lines[:2]) + lines[2][:40])
    r = sweep_cli(out, "--workers", "1")
    assert r.returncode == 0, r.stderr
    assert "ran 2 samples" in r.stdout
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()


def test_a_crashing_worker_loses_no_other_sample(reference, tmp_path):
    out = tmp_path / "crash"
    r = sweep_cli(out, "--workers", "2", env={"TWIN_SWEEP_CRASH_SAMPLES": "1"})
    assert r.returncode == 0, r.stderr
    rows, ref = read_sweep_csv(out / "sweep.csv"), read_sweep_csv(reference / "sweep.csv")
    for a, b in zip(rows, ref):
        if a["sample"] == 1:
            assert a["status"] == "error" and "worker died 2 times" in a["error"] and a["iae_theta"] is None
            assert a["seed"] == b["seed"] and a["factor_m_b"] == b["factor_m_b"]
        else:
            assert a == b
    assert "1 samples ended in an error" in (out / "summary.md").read_text()


# ---- backends ---------------------------------------------------------------------------------------

def _ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


@pytest.mark.skipif(not _ray_available() and not os.environ.get("TWIN_REQUIRE_RAY"),
                    reason="Ray not installed (pip install '.[ray]'); CI sets TWIN_REQUIRE_RAY=1")
def test_ray_gives_the_same_results_as_local_processes(reference, tmp_path):
    r = sweep_cli(tmp_path / "ray", "--backend", "ray", "--workers", "2")
    assert r.returncode == 0, r.stderr
    for name in ("sweep.csv", "summary.json"):
        assert (tmp_path / "ray" / name).read_bytes() == (reference / name).read_bytes(), name


# ---- errors -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("args, fragments", [
    (["--samples", "0"], ["--samples", "0 is not in the range"]),
    (["--samples", "2", "--set", "sweep.levels=[]"], ["sweep.levels", "non-empty list"]),
    (["--samples", "2", "--set", "sweep.levels=[0.1, 0.9]"], ["sweep.levels[1]", "[0, 0.8]"]),
    (["--samples", "2", "--set", "sweep.initial_theta=[0.5, 0.2]"], ["sweep.initial_theta", "low 0.5 is above high"]),
    (["--samples", "2", "--set", 'sweep.parameters=["g"]'], ["sweep.parameters", "'g' is not allowed"]),
    (["--samples", "2", "--set", "sweep.distribution=cauchy"], ["sweep.distribution", "'uniform', 'normal'"]),
    (["--samples", "2", "--ray-address", "auto"], ["--ray-address needs --backend ray"]),
    (["--samples", "2", "--backend", "dask"], ["--backend", "'dask' is not one of"]),
])
def test_bad_sweep_input_is_one_line(tmp_path, args, fragments):
    status, stdout, stderr = twin("sweep", "paper-exp2", *args, "--out", tmp_path / "x")
    assert_one_line_error(status, stdout, stderr, *fragments)
    assert not (tmp_path / "x").exists()


def test_a_different_sweep_in_the_same_directory_is_refused(reference, tmp_path):
    out = tmp_path / "other"
    out.mkdir()
    (out / "sweep.json").write_bytes((reference / "sweep.json").read_bytes())
    status, stdout, stderr = twin("sweep", "paper-exp2", "--samples", DRAWS, *SETS, "--seed", 9, "--out", out)
    assert status == 2 and "Traceback" not in stderr
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "holds a different sweep" in lines[0], stderr
    assert "root_seed" in lines[0]
    assert not (out / "samples.jsonl").exists()


# ---- the environment ----------------------------------------------------------------------------------

def test_sweep_json_records_the_environment_and_the_designs(reference):
    from twin.outputs import fingerprint

    doc = json.loads((reference / "sweep.json").read_text())
    assert list(doc)[-1] == "environment" and "resumed_in" not in doc
    env, here = doc["environment"], fingerprint.environment()
    assert env["blas"]["kernel"] == here["blas"]["kernel"] and env["packages"] == here["packages"]
    assert env["designs"]["balance"] == load_scenario("paper-exp2", OVERRIDES).design().digest()


def test_a_sweep_resumed_in_another_environment_says_so_and_records_it(reference, tmp_path):
    out = tmp_path / "moved"
    out.mkdir()
    doc = json.loads((reference / "sweep.json").read_text())
    here = doc["environment"]["blas"]["kernel"]
    other = "Haswell" if here != "Haswell" else "SkylakeX"
    doc["environment"]["blas"]["kernel"] = other  # as if its samples had run on another machine
    (out / "sweep.json").write_text(json.dumps(doc, indent=1) + "\n")
    (out / "samples.jsonl").write_bytes((reference / "samples.jsonl").read_bytes())
    for _ in range(2):  # the second time, this environment is already listed
        r = sweep_cli(out, "--workers", "1")
        assert r.returncode == 0, r.stderr
        assert f"note: resumed in another environment than the first samples' (BLAS kernel {here}, the " \
               f"reference's {other})" in r.stdout, r.stdout
        after = json.loads((out / "sweep.json").read_text())
        assert after["environment"]["blas"]["kernel"] == other  # the first samples' environment is kept
        assert [e["blas"]["kernel"] for e in after["resumed_in"]] == [here]
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()
