"""Twenty seeded "true robots" for ``twin calibrate``, and how well it calibrates them.

Each robot is Table III with m_b, l and n_yb scaled within ±30 %, d_b and d_w within ×0.5–×2
(log-uniform), and a gyro turn-on bias of its own, logged by the twin (``twin run paper-exp3
--log-sensors``: noisy sensors, the EKF in the loop, a 12 N push at 8 s); a robot 15 % or more off
Table III in m_b or l also gets a held-out log (another seed, no push) for the validation. Each
log is calibrated with the defaults, and the result compared with the truth the twin ran: the
plant from the ``--set plant.scale`` factors (not the log's [robot], which is the estimator's
model), the gyro biases from truth.csv (their mean over the fitted windows: they drift), the scale
factors from the log's [truth] table, the IMU latency of the scenario. Used by
tests/test_calibrate_acceptance.py (issue 30's acceptance).

    python benchmarks/calibration_plants.py OUT_DIR [COUNT]   # about 3 minutes on 2 cores
    python benchmarks/calibration_plants.py OUT_DIR --markdown docs/_generated/calibration-acceptance.md

writes OUT_DIR/plant-K/, OUT_DIR/held-K/ (the runs, with sensor-logs/it2) and
OUT_DIR/results.json, and prints per parameter how often the report calls it identifiable, how
often its 95 % interval holds the truth, and the largest relative error. ``--markdown PATH`` also
writes that table to PATH for the documentation (under a line naming the command, machine, date
and commit; see ``benchmarks/published.py``).
"""
from __future__ import annotations

import json
import math
import multiprocessing
import os
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT_SEED = 30  # the generator's seed: the same twenty robots on every machine
PUSH = "pushes=[{force=[12,0,0], start=8, duration=0.1}]"


def draw(count: int = 20, seed: int = ROOT_SEED) -> list[dict]:
    """The plants: ``scale`` (factors of Table III), ``gyro_turn_on_bias`` (rad/s, the σ the
    twin draws the run's gyro bias with) and the run's ``seed``."""
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    out = []
    for k in range(count):
        scale = {n: float(rng.uniform(0.7, 1.3)) for n in ("m_b", "l", "n_yb")}
        scale.update({n: float(math.exp(rng.uniform(math.log(0.5), math.log(2.0)))) for n in ("d_b", "d_w")})
        out.append({"plant": k, "scale": scale, "gyro_turn_on_bias": float(rng.uniform(0.005, 0.03)),
                    "seed": int(rng.integers(0, 2**31))})
    return out


def command(plant: dict, out: Path, held_out: bool = False) -> list[str]:
    """``twin run`` logging ``plant``; ``held_out``: another run of the same robot for validation
    (another seed, so other noise and another gyro bias, and no push)."""
    sets = ([] if held_out else [PUSH]) + [f"sensors.gyro.turn_on_bias={plant['gyro_turn_on_bias']!r}"]
    sets += [f"plant.scale.{n}={v!r}" for n, v in plant["scale"].items()]
    cmd = [sys.executable, "-m", "twin.cli", "run", "paper-exp3", "--controller", "it2", "--no-video", "--log-sensors",
           "--seed", str(plant["seed"] + (1 if held_out else 0)), "--out", str(out)]
    for s in sets:
        cmd += ["--set", s]
    return cmd


_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _run(cmd):
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def evaluate(job) -> dict:
    """One robot ``(plant, held-out log or None)``: calibrate its log (and validate on the held-out
    one); each fitted parameter's value, interval, identifiability and truth."""
    from twin.calibrate.identify import assess
    from twin.calibrate.run import TURN_RATE, calibrate
    from twin.calibrate.validate import validate
    from twin.logs.format import read_log
    from twin.params import NOMINAL

    plant, held = job
    log = read_log(plant["log"])
    cal = calibrate([log])
    params, warnings, _ = assess(cal, TURN_RATE)
    true = NOMINAL.perturbed(scale=plant["scale"])
    t = log.truth_t
    t0 = cal.fit.windows.t0
    span = (t >= t0.min()) & (t <= t0.max() + cal.fit.windows.periods / log.control_rate)
    bias = np.nanmean(log.truth_state[span, 2:5], axis=0)
    tc = log.truth_constants
    truth = {n: getattr(true, n) for n in ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w")}
    truth.update(gyro_bias_x=bias[0], gyro_bias_y=bias[1], gyro_bias_z=bias[2],
                 accel_bias_x=0.0,  # the preset's accelerometer has no turn-on bias; its drift over 15 s ~1e-4
                 gyro_scale_y=tc["gyro_scale"][1], gyro_scale_z=tc["gyro_scale"][2],
                 accel_scale_x=tc["accel_scale"][0], accel_scale_z=tc["accel_scale"][2],
                 imu_latency=log.sensors.imu.latency)
    out = {"plant": plant["plant"], "wall_s": cal.wall_s, "warnings": warnings, "validation": None,
           "params": {n: {"value": e["value"], "ci95": e["ci95"], "identifiable": e["identifiable"],
                          "truth": float(truth[n])} for n, e in params.items()}}
    if held:
        out["validation"] = validate(cal, [read_log(held)])[0]["ratio"]
    return out


def study(out_dir, count: int = 20) -> list[dict]:
    """Generate the robots' logs in ``out_dir`` and :func:`evaluate` each, two at a time."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs, cmds = [], []
    for p in draw(count):
        run = out_dir / f"plant-{p['plant']}"
        p["log"] = str(run / "sensor-logs" / "it2")
        cmds.append(command(p, run))
        held = None
        if abs(p["scale"]["m_b"] - 1.0) >= 0.15 or abs(p["scale"]["l"] - 1.0) >= 0.15:
            cmds.append(command(p, out_dir / f"held-{p['plant']}", held_out=True))
            held = str(out_dir / f"held-{p['plant']}" / "sensor-logs" / "it2")
        jobs.append((p, held))
    # two worker processes on two cores, each with one BLAS thread (two each oversubscribe the
    # cores and slow the fits twofold); spawned, so that the setting reaches their numpy
    saved = {k: os.environ.get(k) for k in _THREADS}
    os.environ.update({k: "1" for k in _THREADS})
    try:
        with ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn")) as pool:
            list(pool.map(_run, cmds))
            results = list(pool.map(evaluate, jobs))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    (out_dir / "results.json").write_text(json.dumps(results, indent=1, default=float))
    return results


def table(results) -> str:
    rows = ["| parameter | identifiable | truth inside the 95 % interval | largest error | within 5 % |",
            "|---|---|---|---|---|"]
    for n in results[0]["params"]:
        called = [r for r in results if r["params"][n]["identifiable"]]
        inside = sum(r["params"][n]["ci95"][0] <= r["params"][n]["truth"] <= r["params"][n]["ci95"][1] for r in called)
        line = f"| {n} | {len(called)}/{len(results)} | {inside}/{len(called)} |"
        if n in ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w"):
            rel = [abs(r["params"][n]["value"] / r["params"][n]["truth"] - 1.0) for r in results]
            line += f" {max(rel):.1%} | {sum(x <= 0.05 for x in rel)}/{len(results)} |"
        else:
            line += " | |"
        rows.append(line)
    v = sorted(r["validation"] for r in results if r["validation"] is not None)
    rows.append("")
    rows.append(f"Validation, model error nominal / calibrated on the held-out logs of the {len(v)} robots 15 % or "
                f"more off in m_b or l: {v[0]:.2f} to {v[-1]:.2f} (median {v[len(v) // 2]:.2f}).")
    return "\n".join(rows)


if __name__ == "__main__":
    import argparse

    from bench_twin import cpu_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", metavar="OUT_DIR")
    ap.add_argument("count", metavar="COUNT", nargs="?", type=int, default=20)
    ap.add_argument("--markdown", metavar="PATH", help="also write the table to PATH (docs/_generated/...)")
    a = ap.parse_args()
    t0 = time.perf_counter()
    res = study(a.out_dir, a.count)
    print(f"machine: {cpu_model()}; {time.perf_counter() - t0:.0f} s")
    text = table(res)
    print(text)
    if a.markdown:
        from published import write_markdown

        intro = (f"{len(res)} robots drawn by a seeded generator (m_b, l, n_yb within ±30 % of Table III, d_b and "
                 "d_w within ×0.5–×2, a gyro turn-on bias of their own), each logged by the twin on paper-exp3 "
                 "with a 12 N push (noisy sensors, the EKF in the loop) and calibrated with the defaults.")
        argv = ["benchmarks/calibration_plants.py", "OUT_DIR", *sys.argv[2:]]  # OUT_DIR: any scratch directory
        write_markdown(a.markdown, intro + "\n\n" + text, argv=argv)
