"""The calibration round trip on robots other than the paper's, at full length.

For each built-in robot named: the robot that truly runs is the robot file's figures with
experiment 3's mismatch (body 6 % heavier, centre of mass 8 % higher, pitch moment 10 % more,
frictions 50 % more); ``twin run NAME-exp3 --log-sensors`` records it driving 1 m and turning
45° from 0.3 rad; ``twin calibrate`` fits the log with the robot file as its starting point and writes
``robot.toml``; each identified figure is compared with the truth (inside its 95 % interval?);
then the robot that truly ran (its figures as a robot file) and the fitted robot each run the
same scenario without a mismatch, and their metrics are compared. tests/test_calibrate.py runs
the same round trip, shorter, on a copy of the paper's robot in CI.

    python benchmarks/robot_round_trip.py OUT_DIR [--robots balboa,rmp220] [--markdown docs/_generated/robot-round-trip.md]
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

from published import provenance

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from twin.robots import load_robot, robot_text  # noqa: E402

MISMATCH = {("body", "mass"): 1.06, ("body", "com_height"): 1.08, ("body", "pitch_inertia"): 1.10,
            ("friction", "drive"): 1.5, ("friction", "ground"): 1.5}
FIT = {"m_b": ("body", "mass"), "l": ("body", "com_height"), "n_yb": ("body", "pitch_inertia"),
       "n_zb": ("body", "yaw_inertia"), "d_b": ("friction", "drive"), "d_w": ("friction", "ground")}
METRICS = ("settling_time_s", "theta_rms_rad", "iae_theta", "final_position_error_m", "final_heading_error_rad")


def twin(*args) -> str:
    r = subprocess.run([sys.executable, "-m", "twin.cli", *map(str, args)], capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"twin {' '.join(map(str, args))}: {r.stderr.strip().splitlines()[-1]}")
    return r.stdout


def scaled(text: str, factors: dict) -> tuple[str, dict]:
    """``text`` (a robot file) with each (section, key) multiplied by its factor; the new values."""
    out, section, values = [], "", {}
    for line in text.splitlines():
        m = re.match(r"\[(\w+)\]", line)
        if m:
            section = m.group(1)
        m = re.match(r"(\w+) = ([-0-9.e+]+)(.*)", line)
        if m and (section, m.group(1)) in factors:
            v = float(m.group(2)) * factors[(section, m.group(1))]
            values[(section, m.group(1))] = v
            line = f"{m.group(1)} = {v!r}{m.group(3)}"
        out.append(line)
    return "\n".join(out) + "\n", values


def round_trip(name: str, out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    text = robot_text(name)
    (out / "robot.toml").write_text(text, encoding="utf-8")
    truth_text, truth = scaled(text.replace(f'name = "{name}"', f'name = "{name}-truth"'), MISMATCH)
    (out / "truth.toml").write_text(truth_text, encoding="utf-8")
    scenario = f"{name}-exp3"  # the robot's built-in scenario: experiment 3 from 0.3 rad, 1 m, 45°
    twin("run", scenario, "--robot", out / "robot.toml", "--set",
         "plant.scale={m_b = 1.06, l = 1.08, n_yb = 1.10, d_b = 1.5, d_w = 1.5}", "--duration", "10",
         "--controller", "it2", "--no-video", "--log-sensors", "--out", out / "log")
    t0 = time.perf_counter()
    twin("calibrate", out / "log" / "sensor-logs" / "it2", "--out", out / "cal")
    seconds = time.perf_counter() - t0
    report = json.loads((out / "cal" / "report.json").read_text())["parameters"]
    base = load_robot(out / "robot.toml")
    rows = []
    for p, (section, key) in FIT.items():
        if p not in report:
            continue
        e = report[p]
        true = truth.get((section, key), base.values[section][key])
        lo, hi = e["ci95"]
        rows.append({"parameter": p, "truth": true, "fit": e["value"], "lo": lo, "hi": hi,
                     "identified": e["identifiable"], "inside": lo <= true <= hi})
    runs = {}
    for which, robot in (("truth", out / "truth.toml"), ("fitted", out / "cal" / "robot.toml")):
        twin("run", scenario, "--robot", robot, "--set", "plant.scale={}", "--controller", "it2,t1,lqr",
             "--no-video", "--out", out / which)
        runs[which] = json.loads((out / which / "metrics.json").read_text())["runs"]
    return {"robot": name, "calibrate_s": seconds, "rows": rows, "runs": runs}


def markdown(results) -> str:
    lines = [provenance(), ""]
    for r in results:
        lines += [f"**{r['robot']}** (calibration {r['calibrate_s']:.0f} s)", "",
                  "| parameter | truth | fitted | 95 % interval | identified | truth inside |", "|---|---|---|---|---|---|"]
        for row in r["rows"]:
            lines.append(f"| {row['parameter']} | {row['truth']:.4g} | {row['fit']:.4g} | [{row['lo']:.4g}, "
                         f"{row['hi']:.4g}] | {'yes' if row['identified'] else 'no'} | "
                         f"{'yes' if row['inside'] else 'NO'} |")
        lines += ["", "| controller | " + " | ".join(f"{m} (truth / fitted)" for m in METRICS) + " |",
                  "|---|" + "---|" * len(METRICS)]
        for kind in r["runs"]["truth"]:
            a, b = r["runs"]["truth"][kind], r["runs"]["fitted"][kind]
            cells = [f"{_f(a.get(m))} / {_f(b.get(m))}" for m in METRICS]
            lines.append(f"| {kind} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def _f(v) -> str:
    return "—" if v is None else f"{v:.4g}" if isinstance(v, float) else str(v)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--robots", default="balboa,rmp220")
    ap.add_argument("--markdown", type=Path)
    a = ap.parse_args(argv)
    results = [round_trip(n, a.out / n) for n in a.robots.split(",")]
    text = markdown(results)
    print(text)
    if a.markdown:
        a.markdown.write_text(text + "\n", encoding="utf-8")
    bad = [(r["robot"], row["parameter"]) for r in results for row in r["rows"] if row["identified"] and not row["inside"]]
    if bad:
        print(f"identified figures outside their intervals: {bad}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
