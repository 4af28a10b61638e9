"""The README's tables of single runs, measured again with the code as it is.

Run from the repository root (about 2 minutes on 2 cores; the analytic table alone, a few
seconds)::

    python benchmarks/readme_tables.py [--only analytic|twin|builtins ...] [--set KEY=VALUE ...]

Prints three markdown tables, each from the command the README names:

* "Results on the analytic model": ``twin run paper-expN --controller it2,t1 --set
  plant.model=analytic --set plant.scale={} --set sensors.sensing=ideal`` (N = 1, 2, 3:
  equation (1) on the nominal plant, the controllers on the true state, 200 Hz control,
  1 kHz RK4; what ``twin analytic N --controller both`` gave before issue 27, bit for bit);
* "Measured on the twin": ``twin run paper-expN --set plant.scale={} --set sensors.sensing=ideal``
  (nominal plant, default motors, controllers on ground truth);
* "IT2, type-1 and LQR on this twin": ``twin run NAME --controller it2,t1,lqr`` for every
  built-in scenario (seed 0, the EKF in the loop).

``--only`` prints the tables named (repeatable; default: all three). ``--markdown PATH``
also writes them for the documentation (see ``benchmarks/published.py``): with one table, to
the file PATH (``docs/_generated/results-analytic.md``, ``results-twin.md``,
``results-builtins.md``); with several, to PATH/results-NAME.md each::

    python benchmarks/readme_tables.py --markdown docs/_generated

``--set`` options are
passed to every ``twin run``, the analytic model's included (for example the nominal
design of before issue 18: ``--set design.decay_rate=3 --set design.damping=0 --set
'design.uncertain={}' --set design.all_vertices=false``).
"""
from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BUILTINS = ("paper-exp1", "paper-exp2", "paper-exp3", "push-recovery", "sensor-faults", "slope-payload")
LABEL = {"it2": "IT2", "t1": "type-1", "lqr": "LQR"}
EXPERIMENTS = {1: "1: balance from θ0 = 0.48 rad", 2: "2: + position, p_d = 0.7 m",
               3: "3: + direction, p_d = 1 m, α_d = 1.5 rad"}


def twin(*args: str) -> None:
    r = subprocess.run([sys.executable, "-m", "twin.cli", *args], cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"twin {' '.join(args)} failed:\n{r.stderr}")


def runs(out: Path, key: str = "runs") -> dict:
    """The metrics per controller in ``out/metrics.json``."""
    return json.loads((out / "metrics.json").read_text(encoding="utf-8"))[key]


def mm(value) -> str:
    return "–" if value is None else f"{value * 1e3:.1f}".replace("-", "−")


def table(header: list[str], groups, cells) -> str:
    """A markdown table: for each (label, {kind: metrics}) of ``groups`` one row per controller,
    the label on its first row, then ``cells(kind, metrics)``."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for label, per_kind in groups:
        for i, (kind, m) in enumerate(per_kind.items()):
            lines.append(("| " + label + " | " if i == 0 else "| | ") + " | ".join(cells(kind, m)) + " |")
    return "\n".join(lines)


def below(value, bound: float, scale: float, bound_text: str, unit: str) -> str:
    """An error as the README's analytic table gives it: "< 1 mm" below ``bound``, else the
    value (× ``scale``, in ``unit``); "–" if none."""
    if value is None:
        return "–"
    return f"< {bound_text}" if abs(value) < bound else f"{abs(value) * scale:.2g} {unit}"


def short(kind: str) -> str:
    return "IT2" if kind == "it2" else "T1"


def max_total_torque(out: Path) -> dict:
    """controller → max |ul_cmd + ur_cmd| in N·m over ``out/trajectory.csv``."""
    totals: dict = {}
    with open(out / "trajectory.csv", encoding="utf-8", newline="") as fh:
        for row in csv.DictReader(fh):
            total = abs(float(row["ul_cmd [N·m]"]) + float(row["ur_cmd [N·m]"]))
            totals[row["controller"]] = max(totals.get(row["controller"], 0.0), total)
    return totals


def analytic(tmp: Path, extra: list[str]) -> str:
    def groups():
        for n in (1, 2, 3):
            out = tmp / f"analytic{n}"
            twin("run", f"paper-exp{n}", "--controller", "it2,t1", "--no-video", "--set", "plant.model=analytic",
                 "--set", "plant.scale={}", "--set", "sensors.sensing=ideal", "--out", str(out), *extra)
            totals = max_total_torque(out)
            yield EXPERIMENTS[n], {k: (totals[k], m) for k, m in runs(out).items()}

    def cells(kind, item):
        total, m = item
        pos, head = m.get("final_position_error_m"), m.get("final_heading_error_rad")
        return [short(kind), f"{m['settling_time_s']:.2f} s", f"{total:.3f} N·m",
                below(pos, 1e-3, 1e3, "1 mm", "mm"), below(head, 1e-3, 1.0, "0.001 rad", "rad")]

    return table(["experiment", "controller", "θ settles below 0.01 rad", "max \\|ul + ur\\|", "final position error",
                  "final heading error"], groups(), cells)


def nominal_twin(tmp: Path, extra: list[str]) -> str:
    def groups():
        for n in (1, 2, 3):
            out = tmp / f"nominal{n}"
            twin("run", f"paper-exp{n}", "--no-video", "--set", "plant.scale={}", "--set", "sensors.sensing=ideal",
                 "--out", str(out), *extra)
            yield EXPERIMENTS[n], runs(out)

    def cells(kind, m):
        pos, head = m.get("final_position_error_m"), m.get("final_heading_error_rad")
        return [short(kind), f"{m['settling_time_s']:.2f} s", f"{m['oscillation_peak_to_peak_rad']:.2g} rad",
                f"{m['max_abs_torque_nm']:.3f} N·m", mm(pos) + ("" if pos is None else " mm"),
                "–" if head is None else f"{head:.2g} rad".replace("-", "−")]

    return table(["experiment (twin, default motors)", "controller", "θ settles below 0.01 rad",
                  "θ peak-to-peak, last 5 s", "max wheel torque (5 ms mean)", "final position error",
                  "final heading error"], groups(), cells)


def builtins(tmp: Path, extra: list[str]) -> str:
    def groups():
        for name in BUILTINS:
            out = tmp / name
            twin("run", name, "--controller", "it2,t1,lqr", "--no-video", "--out", str(out), *extra)
            yield name, runs(out)

    def cells(kind, m):
        ts, head = m["settling_time_s"], m.get("final_heading_error_rad")
        return [LABEL.get(kind, kind), "never" if ts is None else f"{ts:.2f}",
                f"{m['theta_rms_rad'] * 1e3:.3g}" + ("" if ts is not None else " (last 5 s)"),
                f"{m['oscillation_peak_to_peak_rad'] * 1e3:.3g}", mm(m.get("final_position_error_m")),
                "–" if head is None else f"{head * 1e3:.1f}".replace("-", "−"), f"{m['iae_theta']:.3g}",
                f"{m['control_effort']:.3g}", f"{m['max_abs_torque_nm']:.2f}",
                f"{m['estimator_theta_rmse_rad'] * 1e3:.3g}"]

    return table(["scenario", "controller", "settling [s]", "θ RMS after settling [mrad]",
                  "θ peak-to-peak, last 5 s [mrad]", "final position error [mm]", "final heading error [mrad]",
                  "IAE θ [rad·s]", "effort [N²m²s]", "peak torque [N·m]", "estimator θ RMSE [mrad]"], groups(), cells)


COMMANDS = {
    "analytic": "twin run paper-expN --controller it2,t1 --no-video --set plant.model=analytic "
                "--set plant.scale={} --set sensors.sensing=ideal",
    "twin": "twin run paper-expN --no-video --set plant.scale={} --set sensors.sensing=ideal",
    "builtins": "twin run NAME --controller it2,t1,lqr --no-video",
}

TABLES = {"analytic": ("Results on the analytic model", analytic),
          "twin": ("Measured on the twin (nominal plant, ground truth)", nominal_twin),
          "builtins": ("IT2, type-1 and LQR on this twin", builtins)}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", action="append", choices=TABLES, default=[],
                    help="print this table only (repeatable; default: all three)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="passed to every 'twin run'")
    ap.add_argument("--markdown", metavar="PATH", type=Path,
                    help="also write the table to PATH (several tables: PATH/results-NAME.md) with a provenance line")
    a = ap.parse_args()
    extra = [x for s in a.set for x in ("--set", s)]
    chosen = [t for t in TABLES if t in a.only] if a.only else list(TABLES)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from published import write_markdown
    texts = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for t in chosen:
            texts[t] = TABLES[t][1](tmp, extra)
            print(f"{TABLES[t][0]}\n\n{texts[t]}\n", flush=True)
    if a.markdown is not None:
        for t, text in texts.items():
            path = a.markdown if len(chosen) == 1 else a.markdown / f"results-{t}.md"
            sets = "".join(f" --set {s}" for s in a.set)
            write_markdown(path, f"Each row from `{COMMANDS[t]}{sets}`.\n\n{text}")
