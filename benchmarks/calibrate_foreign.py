"""``twin calibrate`` on robots the twin did not simulate: accuracy over twenty robots, and speed.

The logs come from the independent simulator kept as a test fixture, ``tests/foreign/robot_sim.py``
(equation (1) by RK4 at 1 kHz, its own LQR on its own estimates, its own IMU and encoders, none of
the twin's code), written in format version 2 through its public API
(``profile_a(seed, duration, plant_scale=...)``, ``simulate``, ``write_log``).

* **Acceptance**: :data:`COUNT` robots drawn by a seeded generator (:func:`draw`: m_b, l and n_yb
  within ±30 % of Table III, d_b and d_w ×0.5–×2, n_zb Table III's), each a profile-A log of
  :data:`DURATION` s (drives, turns, 3–6 N pushes, an MPU-6050-like IMU with 1 % scale factors),
  calibrated with the defaults (:func:`twin.calibrate.robot.calibrate_robot`, as ``twin calibrate``
  runs it): per physical parameter, how often it is reported as identified, how often the truth
  lies inside the reported 95 % interval, the largest error and how often it is within 5 % (n_zb:
  10 %); and how well the twin, given the mapped parameters (:func:`twin.calibrate.robot.to_twin`),
  reproduces each log's readings against the continuous model (RMS misfit in σ of the readings'
  noise).
* **Speed**: ``twin calibrate LOG`` on a 60 s profile-A log at 200 Hz and on a 20 s profile-B log
  at 33 Hz (the real-robot-shaped one: sampled voltage commands, an IMU pitched 0.07 rad,
  vibration noise, a start from lying), each in a subprocess of its own, side by side with
  ``twin replay LOG`` (the closed-loop replay of the same log's EKF).

* **A jittered logger** (``--jittered``, :func:`jittered`): five profile-B logs of one robot
  together (with and without noise figures) and the robot-logs how-to's two hobby recordings:
  per physical parameter the error, whether the truth is inside the 95 % interval, whether it is
  identified; the fit's cost per residual and the wall time.

Run from the repository root::

    python benchmarks/calibrate_foreign.py OUT_DIR --markdown docs/_generated/calibration-foreign.md
    python benchmarks/calibrate_foreign.py OUT_DIR --robots 4 --duration 20   # a quick look
    python benchmarks/calibrate_foreign.py OUT_DIR --jittered   # the jittered logger's logs only

``tests/test_calibrate_foreign.py`` checks the same properties on two short robots. The table's
first line says the command, the machine, the date and the commit (``benchmarks/published.py``).
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for p in (str(ROOT / "tests"), str(HERE), str(ROOT)):
    if p not in sys.path:
        sys.path.insert(0, p)

COUNT = 20
DURATION = 30.0  # s of each acceptance log
SEED = 4000  # of the robots' draw (robot i: numpy.random.default_rng([SEED, i])) and of their logs (SEED + i)
PHYSICAL = ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w")
WITHIN = {"m_b": 0.05, "l": 0.05, "n_yb": 0.05, "n_zb": 0.10, "d_b": None, "d_w": 0.05}  # the bounds
NEED = 0.9  # share of (parameter, robot) pairs of an identified parameter whose interval holds the truth


def draw(i: int, seed: int = SEED) -> dict:
    """Robot i's true plant as factors of Table III: m_b, l, n_yb uniform in [0.7, 1.3], d_b and d_w
    log-uniform in [0.5, 2]."""
    rng = np.random.default_rng([seed, i])
    f = {n: float(rng.uniform(0.7, 1.3)) for n in ("m_b", "l", "n_yb")}
    f.update({n: float(math.exp(rng.uniform(math.log(0.5), math.log(2.0)))) for n in ("d_b", "d_w")})
    return f


def make_log(out: Path, i: int, duration: float = DURATION, seed: int = SEED, rate: float | None = None,
             log_seed: int | None = None) -> dict:
    """Robot i's profile-A log in ``out`` (format version 2); ``rate`` Hz another control and IMU rate
    than the profile's 200 Hz (the same robot logged otherwise); ``log_seed`` another log of it.
    Returns {"path", "factors", "fell", "generate_s"}."""
    from dataclasses import replace

    from foreign import robot_sim as rs

    t0 = time.perf_counter()
    factors = draw(i, seed)
    spec = rs.profile_a(seed + i if log_seed is None else log_seed, duration=duration, plant_scale=factors)
    if rate is not None:
        spec = replace(spec, controller=replace(spec.controller, rate=float(rate)),
                       imu=replace(spec.imu, rate=float(rate), latency=1.0 / float(rate)))
    result = rs.simulate(spec)
    rs.write_log(result, out, version=2)
    fell = bool(np.max(np.abs(result.states[:, 0])) > 0.6)
    return {"path": str(out), "factors": factors, "fell": fell, "generate_s": time.perf_counter() - t0}


def calibrate_one(path: str, names=None, bootstrap: int = 200) -> dict:
    """``twin calibrate``'s fit of one log (in process): each physical parameter's value, interval,
    identifiability and truth (the sidecar's true plant), the twin's mapping and the wall time."""
    from twin.calibrate.identify import assess
    from twin.calibrate.robot import TURN_RATE, calibrate_robot, to_twin
    from twin.logs.format import read_log

    t0 = time.perf_counter()
    log = read_log(path)
    cal = calibrate_robot([log], names, bootstrap=bootstrap)
    params, warnings, _ = assess(cal, TURN_RATE)
    twin = to_twin(cal, params)
    wall = time.perf_counter() - t0
    truth = json.loads((Path(path) / "robot_sim.json").read_text())["plant_true"]
    out = {}
    for n in PHYSICAL:
        if n in params:
            e = params[n]
            out[n] = {"value": e["value"], "ci95": e["ci95"], "identifiable": e["identifiable"], "truth": truth[n],
                      "error": e["value"] / truth[n] - 1.0}
    return {"path": path, "params": out, "warnings": warnings, "wall_s": wall, "twin": twin,
            "dropped": len(cal.dropped), "windows": cal.windows_total}


def _robot(args) -> dict:
    out, i, duration, seed = args
    made = make_log(Path(out) / f"robot-{i:02d}", i, duration, seed)
    made.update(calibrate_one(made["path"]))
    made["robot"] = i
    return made


def study(out: Path, count: int = COUNT, duration: float = DURATION, seed: int = SEED, workers: int = 2) -> list:
    """Every robot made and calibrated (two worker processes share them)."""
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(str(out), i, duration, seed) for i in range(count)]
    if workers <= 1:
        return [_robot(j) for j in jobs]
    import multiprocessing

    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as ex:
        return list(ex.map(_robot, jobs))


def summary(rows: list) -> dict:
    """Per physical parameter: identified, inside the interval (of identified), within the bound,
    largest error; and whether the issue's acceptance holds."""
    out = {}
    for n in PHYSICAL:
        have = [r["params"][n] for r in rows if n in r["params"]]
        ident = [e for e in have if e["identifiable"]]
        inside = [e for e in ident if e["ci95"][0] <= e["truth"] <= e["ci95"][1]]
        bound = WITHIN[n]
        within = [e for e in have if bound is not None and abs(e["error"]) <= bound]
        out[n] = {"fitted": len(have), "identified": len(ident), "inside": len(inside),
                  "largest_error": max((abs(e["error"]) for e in ident), default=float("nan")),
                  "within": len(within), "bound": bound}
        e = out[n]
        ok = not ident or e["inside"] >= NEED * e["identified"]
        if n in ("m_b", "l", "n_yb", "d_w"):
            ok = ok and e["within"] == e["fitted"]
        if n == "n_zb":
            ok = ok and all(abs(x["error"]) <= 0.10 or not x["identifiable"] for x in have)
        e["accepted"] = bool(ok)
    return out


def _twin_exe() -> list:
    exe = Path(sys.executable).parent / "twin"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "twin.cli"]


def timed(args: list, cwd: Path):
    """Wall time (s) of ``twin ARGS`` in a subprocess, or the reason it failed (a string)."""
    t0 = time.perf_counter()
    r = subprocess.run(_twin_exe() + args, cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        print(f"twin {' '.join(args)} failed ({r.returncode}): {r.stderr.strip()[-800:]}", file=sys.stderr)
        return "failed: " + (r.stderr.strip().splitlines() or ["?"])[-1][:160]
    return wall


def speed(out: Path) -> list:
    """(log, wall of twin calibrate, wall of twin replay) for the 60 s log at 200 Hz and the 20 s log at
    33 Hz."""
    from foreign import robot_sim as rs

    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, profile, opts in (("60 s at 200 Hz (profile A)", "A", {"duration": 60.0}),
                                ("20 s at 33 Hz (profile B)", "B", {"duration": 20.0})):
        path = out / f"speed-{profile.lower()}"
        rs.generate(path, profile, 0, version=2, **opts)
        cal = timed(["calibrate", str(path), "--out", str(out / f"speed-{profile.lower()}-cal")], out)
        rep = timed(["replay", str(path), "--out", str(out / f"speed-{profile.lower()}-replay")], out)
        rows.append({"log": name, "calibrate_s": cal, "replay_s": rep,
                     "limit_s": 60.0 if profile == "A" else 30.0, "path": str(path)})
    return rows


def _pct(x: float) -> str:
    return f"{x * 100:+.1f} %"


def markdown(rows: list, summ: dict, speeds: list, duration: float) -> str:
    lines = [f"{len(rows)} robots drawn by a seeded generator (m_b, l, n_yb within ±30 % of Table III, d_b and d_w "
             f"×0.5–×2), each a {duration:g} s log of the independent simulator `tests/foreign/robot_sim.py` "
             f"(profile A: 200 Hz, drives, turns, 3–6 N pushes, 1 % scale factors; format version 2), calibrated with "
             f"the defaults.", "",
             "| parameter | identified | truth inside the 95 % interval (of identified) | largest error (identified) | "
             "within the bound | accepted |", "|---|---|---|---|---|---|"]
    for n, e in summ.items():
        bound = "–" if e["bound"] is None else f"{e['within']}/{e['fitted']} (±{e['bound'] * 100:g} %)"
        largest = "–" if not e["identified"] else f"{e['largest_error'] * 100:.1f} %"
        lines.append(f"| {n} | {e['identified']}/{e['fitted']} | {e['inside']}/{e['identified']} | {largest} | {bound} "
                     f"| {'yes' if e['accepted'] else 'no'} |")
    lines += ["", "Per robot: each physical parameter's error against the simulator's true plant, ✓ where the truth is "
                  "inside the reported 95 % interval, (n) where the report says not identified; the twin's readings "
                  "with the mapped parameters and with the robot's own (RMS misfit over the fitted windows, σ of the "
                  "readings' noise; the continuous model's in the first column).", "",
              "| robot | factors m_b, l, n_yb, d_b, d_w | m_b | l | n_yb | n_zb | d_b | d_w | misfit: model / twin mapped "
              "/ twin unmapped [σ] | wall [s] |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f = r["factors"]
        cells = []
        for n in PHYSICAL:
            e = r["params"].get(n)
            if e is None:
                cells.append("–")
                continue
            mark = "✓" if e["ci95"][0] <= e["truth"] <= e["ci95"][1] else "✗"
            cells.append(f"{_pct(e['error'])} {mark}" + ("" if e["identifiable"] else " (n)"))
        rep = (r["twin"] or {}).get("reproduces_log") or {}
        unmapped = rep.get("twin, the robot's parameters")
        mis = f"{rep['continuous model']:.2f} / {rep['twin, mapped']:.2f} / {unmapped:.2f}" if rep else "–"
        lines.append(f"| {r['robot']}{' (fell)' if r['fell'] else ''} | {f['m_b']:.2f}, {f['l']:.2f}, {f['n_yb']:.2f}, "
                     f"{f['d_b']:.2f}, {f['d_w']:.2f} | " + " | ".join(cells) + f" | {mis} | {r['wall_s']:.1f} |")
    walls = [r["wall_s"] for r in rows]
    lines += ["", f"Calibration wall time per {duration:g} s log (in process, two robots at a time on the machine's "
                  f"cores): median {np.median(walls):.1f} s, largest {max(walls):.1f} s."]
    if speeds:
        lines += ["", "**Speed**, each command in a subprocess of its own (one at a time):", "",
                  "| log | `twin calibrate LOG` [s] | limit [s] | `twin replay LOG` (closed-loop EKF replay) [s] |",
                  "|---|---|---|---|"]
        for s in speeds:
            cal, rep = (f"{v:.1f}" if isinstance(v, float) else v for v in (s["calibrate_s"], s["replay_s"]))
            lines.append(f"| {s['log']} | {cal} | {s['limit_s']:g} | {rep} |")
    return "\n".join(lines) + "\n"


JITTERED_SEEDS = (0, 1, 2, 3, 4)  # profile-B logs of one robot (B_PLANT), each its own run
JITTERED_WITHIN = 0.10  # the bound on m_b, l, n_yb and d_w for a jittered logger's logs


def jittered(out: Path, bootstrap: int = 100) -> list:
    """Real-robot-shaped logs (profile B: a row every 30–33 ms of a 1 kHz loop, uniformly jittered,
    point IMU samples with vibration noise, sampled voltages, an IMU pitched 0.07 rad), of one robot:
    the five of :data:`JITTERED_SEEDS` calibrated together, with the true noise figures in log.toml
    and without (the noise then measured from the readings), and the robot-logs how-to's two hobby
    recordings (seeds 3 and 4, tests/foreign/hobby_recording.py) converted as the how-to does.
    Per case: each physical parameter's value, interval and identifiability against the truth, the
    fit's cost per residual and the wall time. Each case ~1–3 min on one core."""
    from foreign import robot_sim as rs
    from twin.calibrate.identify import assess
    from twin.calibrate.robot import TURN_RATE, calibrate_robot
    from twin.logs.format import read_log

    truth = {n: float(getattr(rs.B_PLANT, n)) for n in PHYSICAL}
    cases = {}
    for figures in (True, False):
        paths = []
        for seed in JITTERED_SEEDS:
            p = out / f"b-{seed}-{'figures' if figures else 'no-figures'}"
            if not (p / "log.toml").exists():
                rs.write_log(rs.simulate(rs.profile_b(seed)), p, version=2, noise_figures=figures)
            paths.append(p)
        cases[f"5 profile-B logs, {'with' if figures else 'without'} noise figures"] = paths
    hobby = _hobby_logs(out / "hobby")
    if hobby:
        cases["the how-to's two hobby recordings"] = hobby
    rows = []
    for name, paths in cases.items():
        t0 = time.perf_counter()
        cal = calibrate_robot([read_log(p) for p in paths], bootstrap=bootstrap)
        wall = time.perf_counter() - t0
        params, _, _ = assess(cal, TURN_RATE)
        f = cal.robot_fit
        res = {n: {"value": params[n]["value"], "ci95": params[n]["ci95"], "identifiable": params[n]["identifiable"],
                   "truth": truth[n], "error": params[n]["value"] / truth[n] - 1.0} for n in PHYSICAL if n in params}
        rows.append({"case": name, "params": res, "wall_s": wall, "windows": sum(g.count for g in f.groups),
                     "cost_per_residual": 2.0 * f.cost / sum(r.size for r in f.residuals)})
    return rows


def _hobby_logs(out: Path) -> list:
    """The how-to's hobby recordings as logs (docs/howto/real-robot.md's to_log.py), or [] if the
    how-to's script cannot be found."""
    doc = ROOT / "docs" / "howto" / "real-robot.md"
    if not doc.exists():
        return []
    text = doc.read_text(encoding="utf-8")
    mark = text.find("<!-- file: to_log.py -->")
    start = text.find("```python", mark)
    if mark < 0 or start < 0:
        return []
    body = text[text.find("\n", start) + 1:text.find("\n```", start)]
    out.mkdir(parents=True, exist_ok=True)
    (out / "to_log.py").write_text(body + "\n", encoding="utf-8")
    paths = []
    for n in (1, 2):
        csv = ROOT / "docs" / "howto" / "hobby-robot" / f"balance-{n}.csv"
        dest = out / f"balance-{n}"
        if not (dest / "log.toml").exists():
            subprocess.run([sys.executable, "to_log.py", str(csv), str(dest)], cwd=out, check=True,
                           capture_output=True)
        paths.append(dest)
    return paths


def jittered_markdown(rows: list) -> str:
    lines = ["| logs | cost / residual | windows | wall | " + " | ".join(n for n in PHYSICAL) + " |",
             "|---|---|---|---|" + "---|" * len(PHYSICAL)]
    for r in rows:
        cells = []
        for n in PHYSICAL:
            e = r["params"].get(n)
            if e is None:
                cells.append("—")
                continue
            inside = e["ci95"][0] <= e["truth"] <= e["ci95"][1]
            cells.append(f"{_pct(e['error'])}{'' if inside else ' (out)'}{'' if e['identifiable'] else ', n.i.'}")
        lines.append(f"| {r['case']} | {r['cost_per_residual']:.2f} | {r['windows']} | {r['wall_s']:.0f} s | "
                     + " | ".join(cells) + " |")
    lines.append("")
    lines.append("Error of each physical parameter against the truth; (out): the truth outside the reported 95 % "
                 "interval; n.i.: reported not identified.")
    return "\n".join(lines)


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="directory for the logs and calibrations")
    ap.add_argument("--robots", type=int, default=COUNT)
    ap.add_argument("--duration", type=float, default=DURATION, help="s of each acceptance log")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-speed", action="store_true", help="leave out the speed measurements")
    ap.add_argument("--reuse", action="store_true", help="take the robots' results from OUT_DIR's last run")
    ap.add_argument("--markdown", type=Path, help="write the tables there (docs/_generated/calibration-foreign.md)")
    ap.add_argument("--jittered", action="store_true",
                    help="only the jittered logger's logs (profile B and the how-to's hobby recordings)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.jittered:
        args.out.mkdir(parents=True, exist_ok=True)
        rows = jittered(args.out)
        print(jittered_markdown(rows))
        (args.out / "calibrate_jittered.json").write_text(json.dumps({"rows": rows}, indent=1, default=float) + "\n")
        print(f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
        return 0
    saved = args.out / "calibrate_foreign.json"
    if args.reuse and saved.exists():  # the robots of an earlier run (the speed measured again)
        rows = json.loads(saved.read_text())["rows"]
    else:
        rows = study(args.out, args.robots, args.duration, workers=args.workers)
        saved.write_text(json.dumps({"rows": rows}, indent=1, default=float) + "\n")
    summ = summary(rows)
    speeds = [] if args.no_speed else speed(args.out)
    text = markdown(rows, summ, speeds, args.duration)
    print(text)
    (args.out / "calibrate_foreign.json").write_text(json.dumps({"rows": rows, "summary": summ, "speed": speeds},
                                                                indent=1, default=float) + "\n")
    print(f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    if args.markdown:
        from published import write_markdown

        write_markdown(args.markdown, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
