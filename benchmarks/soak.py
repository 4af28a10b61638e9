"""Hour-long soak of every built-in scenario with the EKF in the loop (issue 16).

Each built-in scenario is run for ``--duration`` simulated seconds (default 3600) with the
IT2 controller and the EKF, for seeds 0 and 1, on ``--workers`` processes. The loop is
driven directly (no trajectory is kept), so memory stays flat. Printed per run:

* θ peak-to-peak over the first settled 5 minutes (from the scenario's own end, when its
  manoeuvre is over) and over the last 5 minutes, and their ratio (bound: 1.5);
* max |α̂ − α| and |ψ̂ − ψ| (rad) after settling, at samples where the wheels do not slip
  (the axle's mean speed over the control step within 1 mm/s of r Δψ/Δt) (bound: 0.02 rad),
  and the 99.9th percentile;
* the heading's drift over the settled part (rad; yaw creep), and the axle's slip (m): the
  sum over control steps of |the axle's travel along the heading − r Δψ| (on the ground:
  up a ramp, the horizontal travel / cos(slope)).

Usage: python benchmarks/soak.py [--duration S] [--seeds 0 1] [--workers 2] [--only NAME ...]
"""
from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import sys
import time

import numpy as np

WINDOW = 300.0  # s


def soak(name: str, seed: int, duration: float) -> dict:
    from twin.sim.loop import ClosedLoop
    from twin.scenarios import load_scenario

    sc = load_scenario(name, [f"duration={duration}", f"seed={seed}"])
    base = load_scenario(name)
    settle = max(20.0, base.duration)  # the scenario's own manoeuvre is over by its end
    ctx = sc.build_context(sc.design)
    ctrl = sc.build_controller("it2", ctx)
    est = sc.build_estimator(ctx)
    exp, d = sc.experiment(), sc.data
    loop = ClosedLoop(sc.twin_config() if sc.plant_model == "bullet" else sc.plant(), est, ctrl, sc.sensor_config(), exp.targets, exp.theta0,
                      d["initial"]["alpha"], (d["initial"]["x"], d["initial"]["y"]))
    rate = sc.twin_config().control_rate
    n = int(round(duration * rate))
    first = [math.inf, -math.inf]
    last = [math.inf, -math.inf]
    errs = {"alpha": [], "psi": []}
    r = sc.true_params().r
    ground = sc.data.get("ground", {})
    cos_slope, slope_dir = math.cos(float(ground.get("slope", 0.0))), float(ground.get("slope_direction", 0.0))
    prev = None
    alpha_settled = None
    slip = 0.0
    t0 = time.perf_counter()
    with loop:
        loop.reset(seed)
        for i in range(n + 1):
            tr, e = loop.truth, loop.estimate
            t = tr.t
            if t >= settle:
                if alpha_settled is None:
                    alpha_settled = tr.alpha
                th = tr.theta
                for w, lo in ((first, settle), (last, duration - WINDOW)):
                    if lo <= t < lo + WINDOW:
                        w[0], w[1] = min(w[0], th), max(w[1], th)
                if prev is not None:
                    # along the heading, on the ground: up a ramp the ground is longer than
                    # its horizontal projection by 1/cos(slope)
                    dx, dy = tr.x - prev.x, tr.y - prev.y
                    du = dx * math.cos(slope_dir) + dy * math.sin(slope_dir)
                    dp = -dx * math.sin(slope_dir) + dy * math.cos(slope_dir)
                    speed = (du / cos_slope * math.cos(tr.alpha - slope_dir)
                             + dp * math.sin(tr.alpha - slope_dir)) * rate
                    rolled = r * (tr.psi - prev.psi) * rate  # the step's mean, as the speed's
                    slip += abs(speed - rolled) / rate
                    if abs(speed - rolled) < 1e-3:
                        errs["alpha"].append(abs(e[4] - tr.alpha))
                        errs["psi"].append(abs(e[2] - tr.psi))
            prev = tr
            if i == n or loop.status != "running":
                break
            loop.step()
        status = loop.status
        final = loop.truth
    out = dict(scenario=name, seed=seed, status=status, t_end=final.t, settle=settle,
               first_ptp=first[1] - first[0], last_ptp=last[1] - last[0],
               yaw_drift=(final.alpha - alpha_settled) if alpha_settled is not None else math.nan,
               slip_m=slip, wall_s=time.perf_counter() - t0)
    out["ratio"] = out["last_ptp"] / out["first_ptp"] if out["first_ptp"] > 0 else math.inf
    for k, v in errs.items():
        a = np.array(v) if v else np.array([math.nan])
        out[f"{k}_err_max"] = float(a.max())
        out[f"{k}_err_p999"] = float(np.percentile(a, 99.9))
    return out


def _job(args):
    return soak(*args)


def main(argv=None) -> int:
    from twin.scenarios import builtin_names

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=3600.0)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--only", nargs="+", default=None)
    a = p.parse_args(argv)
    names = a.only or builtin_names()
    jobs = [(n, s, a.duration) for n in names for s in a.seeds]
    with mp.get_context("spawn").Pool(a.workers) as pool:
        rows = pool.map(_job, jobs, chunksize=1)
    print(f"soak: {a.duration:g} s simulated per run, IT2 + EKF; bounds: ratio <= 1.5, |α̂−α|, |ψ̂−ψ| <= 0.02 rad")
    print("| scenario | seed | status | θ p-p first 5 min (mrad) | last 5 min (mrad) | ratio | max |α̂−α| (rad) "
          "| max |ψ̂−ψ| (rad) | p99.9 |ψ̂−ψ| | yaw drift (rad) | slip (m) | wall (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    ok = True
    for o in rows:
        good = (o["status"] == "running" and o["ratio"] <= 1.5 and o["alpha_err_max"] <= 0.02
                and o["psi_err_max"] <= 0.02)
        ok &= good
        print(f"| {o['scenario']} | {o['seed']} | {'ok' if o['status'] == 'running' else o['status']} "
              f"| {1e3 * o['first_ptp']:.1f} | {1e3 * o['last_ptp']:.1f} | {o['ratio']:.2f} | {o['alpha_err_max']:.4f} "
              f"| {o['psi_err_max']:.4f} | {o['psi_err_p999']:.4f} | {o['yaw_drift']:.2e} | {o['slip_m']:.4f} "
              f"| {o['wall_s']:.0f} |{'' if good else ' **fails**'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
