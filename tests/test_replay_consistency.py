"""Consistency in ``twin replay`` (issue 28): the EKF's NEES from a log's state truth, NIS, and
the innovations' whiteness.

The acceptance test: 20 twin runs (paper-exp1, 3 s, seeds 0–19, the filter logged) written as
sensor logs and replayed give the very NEES/NIS figures of
:func:`estimation.consistency.monte_carlo` on the runs themselves, equal to the bit: the replay
reproduces the runs' filter states and covariances bit for bit, the log holds the truth as
``repr`` of each float (which reads back exactly), and both sides go through the same arithmetic
(:func:`estimation.consistency.state_matrix`, :func:`~estimation.consistency.nees`).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from estimation.consistency import monte_carlo, nees
from twin.errors import TwinError
from twin.logs.format import read_log, write_log
from twin.logs.replay import (NEES_START, Replay, build_for, consistency, normalised_innovations, replay,
                              replay_logs, whiteness)
from twin.scenarios import load_scenario
from twin.scenarios.planning import plan
from twin.sim.simulate import simulate
from twin.sim.spec import Logging

SEEDS = range(20)


def _run(seed: int, duration: float = 3.0):
    sc = load_scenario("paper-exp1", [f"duration={duration}", f"seed={seed}"])
    return sc, simulate(replace(plan(sc, ["it2"])[0], logging=Logging(1, True)))


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """20 runs and their logs, and replay_logs' document and replays of them with the EKF."""
    root = tmp_path_factory.mktemp("mc")
    runs, paths = [], []
    for s in SEEDS:
        sc, run = _run(s)
        runs.append(run)
        paths.append(write_log(run, root / f"seed{s}", sc))
    doc, replays = replay_logs(paths, ["ekf", "kalman2", "complementary"])
    return runs, paths, doc, replays


def test_replayed_nees_and_nis_equal_monte_carlo_on_the_runs_to_the_bit(batch):
    runs, paths, doc, _ = batch
    want = monte_carlo(runs, start=NEES_START)
    got = doc["estimators"]["ekf"]["monte_carlo"]
    assert got is not None and got["runs"] == 20 and got["rows"] == want["rows"]
    for key in ("nees_mean", "nees_inside", "nis_inside", "nis_per_dof"):
        assert got[key] == want[key], key  # equal to the bit, not merely close
    assert tuple(got["nees_bounds"]) == want["nees_bounds"]
    assert tuple(got["nees_mean_interval"]) == want["nees_mean_interval"]
    for run, p in zip(runs, paths):
        c = doc["logs"][str(p)]["estimators"]["ekf"]["consistency"]
        e = nees(run)
        keep = (run.t >= NEES_START - 1e-9) & np.isfinite(e)
        assert c["nees_mean"] == float(e[keep].mean()) and c["nees_rows"] == int(keep.sum())
        nis, dof = run.filter_log["nis"], run.filter_log["nis_dof"]
        on = np.isfinite(nis) & (dof > 0)
        assert c["nis_per_dof"] == float(nis[on].sum() / dof[on].sum())
    # NEES exists only where the filter reports a 12-state covariance; no Monte Carlo otherwise
    assert doc["estimators"]["kalman2"]["monte_carlo"] is None
    assert "nees_mean" not in doc["logs"][str(paths[0])]["estimators"]["kalman2"]["consistency"]


def test_a_wrong_truth_changes_the_replayed_nees(batch, tmp_path):
    """The equality above is not vacuous: a log whose state truth is off by one count of one
    encoder's phase gives another NEES."""
    runs, paths, doc, _ = batch
    src = paths[0]
    dst = tmp_path / "off"
    dst.mkdir()
    for f in src.iterdir():
        (dst / f.name).write_bytes(f.read_bytes())
    text = (dst / "log.toml").read_text(encoding="utf-8")
    line = next(ln for ln in text.splitlines() if ln.startswith("encoder_phase"))
    left = float(line.split("[")[1].split(",")[0])
    (dst / "log.toml").write_text(text.replace(line, f"encoder_phase = [{left + 1.0!r}, "
                                               f"{line.split(',')[1].strip()}"), encoding="utf-8")
    log = read_log(dst)
    r = replay(log, build_for(log, "ekf"), "ekf", diagnostics=True)
    assert consistency(r, log)["nees_mean"] != doc["logs"][str(src)]["estimators"]["ekf"]["consistency"]["nees_mean"]


def test_the_state_truth_reads_back_exactly(batch):
    runs, paths, _, _ = batch
    run, log = runs[3], read_log(paths[3])
    assert log.truth_state.shape == (len(run.t), 5)
    assert log.truth_state[:, 0].tobytes() == run.signal("psi_l").tobytes()
    bias_ok = np.isfinite(run.gyro_bias).all(axis=1)
    assert np.array_equal(np.isfinite(log.truth_state[:, 2:]).all(axis=1), bias_ok)
    assert log.truth_state[bias_ok, 2:].tobytes() == run.gyro_bias[bias_ok].tobytes()
    st = run.sensor_truth
    assert log.truth_constants["gyro_scale"] == tuple(st["gyro_scale"])
    assert log.truth_constants["encoder_phase"] == tuple(st["encoder_phase"])
    assert log.truth_constants["wheel_radius"] == run.config.params.r


def test_a_log_without_the_state_truth_has_nis_and_whiteness_but_no_nees(batch, tmp_path):
    """A robot's log with motion capture (the six truth columns, no [truth] table)."""
    _, paths, _, _ = batch
    dst = tmp_path / "robot"
    _copy_log(paths[0], dst)
    text = (dst / "log.toml").read_text(encoding="utf-8")
    (dst / "log.toml").write_text(text[:text.index("[truth]")], encoding="utf-8")
    rows = (dst / "truth.csv").read_text(encoding="utf-8").splitlines()
    (dst / "truth.csv").write_text("\n".join(",".join(r.split(",")[:7]) for r in rows) + "\n", encoding="utf-8")
    log = read_log(dst)
    assert log.truth is not None and log.truth_state is None and log.truth_constants is None
    c = consistency(replay(log, build_for(log, "ekf"), "ekf", diagnostics=True), log)
    assert "nees_mean" not in c and c["nis_per_dof"] > 0 and 0.0 <= c["whiteness_outside_fraction"] <= 1.0


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace("[truth]\n", "[truth]\nspin = 1.0\n"), "truth.spin: unknown key"),
    (lambda t: t.replace("encoder_phase = [", "encoder_phase = [0.5, "), "truth.encoder_phase"),
])
def test_a_malformed_truth_table_is_one_line(batch, tmp_path, edit, words):
    _, paths, _, _ = batch
    dst = tmp_path / "bad"
    _copy_log(paths[0], dst)
    (dst / "log.toml").write_text(edit((dst / "log.toml").read_text(encoding="utf-8")), encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        read_log(dst)
    msg = str(exc.value)
    assert words in msg and "allowed" in msg and "\n" not in msg


def test_a_partial_state_truth_row_is_one_line(batch, tmp_path):
    _, paths, _, _ = batch
    dst = tmp_path / "partial"
    _copy_log(paths[0], dst)
    rows = (dst / "truth.csv").read_text(encoding="utf-8").splitlines()
    cells = rows[5].split(",")
    cells[7] = ""  # psi_l empty, psi_r not
    rows[5] = ",".join(cells)
    (dst / "truth.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    with pytest.raises(TwinError, match=r"truth.csv: row 6: psi_l is empty while psi_l, psi_r are not"):
        read_log(dst)


# ---- innovations ------------------------------------------------------------------------------
@pytest.mark.parametrize("compiled", [None, False], ids=["default", "pure-python"])
def test_the_ekf_reports_its_encoder_innovations(batch, compiled):
    """nis = yᵀ S⁻¹ y of the reported innovation and its covariance, on both filter paths; the
    estimates are those of the run (the hook changes nothing)."""
    runs, paths, _, _ = batch
    log = read_log(paths[1])
    est = build_for(log, "ekf", {"compiled": False} if compiled is False else None)
    if compiled is False:
        assert est.compiled is False
    r = replay(log, est, "ekf", diagnostics=True)
    if compiled is None:
        assert r.estimates.tobytes() == runs[1].estimates.tobytes()
    n = 0
    for d in r.diagnostics:
        if d["nis_dof"] == 0:
            assert "innovation" not in d
            continue
        y, S = d["innovation"], d["innovation_cov"]
        assert y.shape == (d["nis_dof"],) and S.shape == (d["nis_dof"], d["nis_dof"])
        assert float(y @ np.linalg.solve(S, y)) == pytest.approx(d["nis"], rel=1e-9, abs=1e-12)
        assert np.all(np.abs(y) < 0.1)  # rad: within a few counts (Δ = 2π/1200 ≈ 0.0052 rad)
        n += 1
    assert n > 100


def test_kalman2_reports_its_angle_innovation_and_the_complementary_filter_none(batch):
    _, paths, doc, replays = batch
    r = replays[(str(paths[0]), "kalman2")]
    d = r.diagnostics[5]
    assert d["nis_dof"] == 1 and len(d["innovation"]) == 1
    assert d["nis"] == pytest.approx(d["innovation"][0] ** 2 / d["innovation_cov"][0][0], rel=1e-12)
    assert replays[(str(paths[0]), "complementary")].diagnostics is None
    assert doc["logs"][str(paths[0])]["estimators"]["complementary"]["consistency"] == {}


def _fake(s: np.ndarray) -> Replay:
    """A replay whose estimator reported the 1-D innovations ``s`` with unit covariance."""
    diags = [{"innovation": [v], "innovation_cov": [[4.0]]} for v in 2.0 * s]
    return Replay("fake", np.arange(len(s)) / 200.0, np.zeros((len(s), 6)), diags, {}, 0.0)


def test_whiteness_passes_white_innovations_and_fails_correlated_ones():
    rng = np.random.default_rng(1)
    white = rng.normal(size=4000)
    w = whiteness(_fake(white))
    assert w["updates"] == 4000 and w["band"] == pytest.approx(1.96 / math.sqrt(4000), rel=1e-3)
    assert w["outside_fraction"] <= 0.15 and abs(w["variance"] - 1.0) < 0.1
    _, s = normalised_innovations(_fake(white))
    assert np.allclose(s, white)  # y / √S with S = 4 and y = 2 s
    ar = np.empty_like(white)  # AR(1) with ρ = 0.5: every early lag far outside the band
    ar[0] = white[0]
    for k in range(1, len(ar)):
        ar[k] = 0.5 * ar[k - 1] + white[k]
    w = whiteness(_fake(ar))
    assert w["autocorrelation"][0] == pytest.approx(0.5, abs=0.05) and w["outside_fraction"] >= 0.2
    assert whiteness(_fake(white[:30])) is None  # fewer than 2 × 20 updates


def test_twin_replay_writes_the_figure_and_the_monte_carlo(batch, tmp_path):
    import json
    import subprocess
    import sys

    _, paths, _, _ = batch
    out = tmp_path / "rp"
    r = subprocess.run([sys.executable, "-m", "twin.cli", "replay", str(paths[0]), str(paths[1]), "--estimator",
                        "ekf,kalman2", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (out / "figure.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads((out / "replay.json").read_text(encoding="utf-8"))
    assert doc["estimators"]["ekf"]["monte_carlo"]["runs"] == 2
    c = doc["logs"][str(paths[0])]["estimators"]["ekf"]["consistency"]
    assert {"nees_mean", "nis_per_dof", "whiteness_outside_fraction"} <= set(c)
    assert "ekf over 2 logs from 0.5 s: mean NEES" in r.stdout


def _copy_log(src, dst) -> None:
    """A copy of the log directory ``src`` at ``dst``, to alter."""
    dst.mkdir()
    for f in src.iterdir():
        (dst / f.name).write_bytes(f.read_bytes())
