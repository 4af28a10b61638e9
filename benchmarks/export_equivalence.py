"""The C export against the Python path, on every built-in scenario, controller and seed.

For each built-in scenario, each controller (it2, t1, lqr) and seeds 0-4: the Python path's run;
the float64 export run in the loop with the twin's driver (``drive = "torque"``): bit for bit the
same run?; the float32 export, with the twin's driver and with its own driver law setting the
duties (``drive = "duty"``, as the firmware does): the scenario's ``[expect]`` bounds, and the
settling time and θ RMS against the Python run's. tests/test_export_sil.py checks one controller
and seed per scenario in CI.

    python benchmarks/export_equivalence.py OUT_DIR [--seeds 5] [--markdown docs/_generated/export-equivalence.md]
"""
from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from published import provenance

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from twin.outputs.metrics import run_metrics  # noqa: E402
from twin.scenarios import builtin_names, load_scenario  # noqa: E402
from twin.scenarios.expectations import evaluate, parse_expect  # noqa: E402
from twin.sim.simulate import simulate  # noqa: E402
from twin.workflows.export import export  # noqa: E402

CONTROLLERS = ("it2", "t1", "lqr")


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("estimates", "commands", "actuation", "truth"))


def case(args) -> dict:
    name, kind, seeds, out = args
    dirs = {p: Path(out) / f"{name}-{kind}-{p}" for p in ("float64", "float32")}
    for p, d in dirs.items():
        export(name, kind, None, p, d, seconds=0.05)
    sc = load_scenario(name)
    bounds = parse_expect(sc.expect)
    row = {"scenario": name, "controller": kind, "identical": 0, "seeds": len(seeds), "d_settling": {}, "d_rms": {},
           "held": {"torque": 0, "duty": 0}, "python_held": 0}
    for seed in seeds:
        py = simulate(load_scenario(name, (f"seed={seed}",)).run_spec(kind))
        m_py = run_metrics(py)
        row["python_held"] += all(v.holds for v in evaluate(bounds, kind, {seed: m_py}))
        runs = {}
        for p, drive in (("float64", "torque"), ("float32", "torque"), ("float32", "duty")):
            d = dirs[p]
            sets = (f"seed={seed}", f"sensors.estimator=export:{d}", f'controller.params."export:{d}".drive={drive}')
            runs[p, drive] = simulate(load_scenario(name, sets).run_spec(f"export:{d}"))
        row["identical"] += _same(runs["float64", "torque"], py)
        for drive in ("torque", "duty"):
            m = run_metrics(runs["float32", drive])
            row["held"][drive] += all(v.holds for v in evaluate(bounds, f"export:{dirs['float32']}", {seed: m}))
            s, s_py = m["settling_time_s"], m_py["settling_time_s"]
            ds = abs(s - s_py) if s is not None and s_py is not None else float("inf")
            dr = abs(m["theta_rms_rad"] - m_py["theta_rms_rad"]) / m_py["theta_rms_rad"]
            row["d_settling"][drive] = max(row["d_settling"].get(drive, 0.0), ds)
            row["d_rms"][drive] = max(row["d_rms"].get(drive, 0.0), dr)
    return row


def table(rows) -> str:
    lines = ["| scenario | controller | float64 = Python, bit for bit | float32, twin's driver: Δ settling / Δ θ RMS "
             "| float32, its own duties: Δ settling / Δ θ RMS | `[expect]` held: Python / float32 torque / "
             "float32 duty |", "|---|---|---|---|---|---|"]
    for r in rows:
        n = r["seeds"]
        lines.append(f"| {r['scenario']} | {r['controller']} | {r['identical']} of {n} | "
                     f"{r['d_settling']['torque']:.3f} s / {100 * r['d_rms']['torque']:.1f} % | "
                     f"{r['d_settling']['duty']:.3f} s / {100 * r['d_rms']['duty']:.1f} % | "
                     f"{r['python_held']} / {r['held']['torque']} / {r['held']['duty']} of {n} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--markdown", type=Path, default=None)
    a = ap.parse_args(argv)
    jobs = [(n, k, list(range(a.seeds)), str(a.out)) for n in builtin_names() for k in CONTROLLERS]
    with ProcessPoolExecutor(a.workers) as pool:
        rows = list(pool.map(case, jobs))
    text = table(rows)
    print(text)
    if a.markdown is not None:
        a.markdown.parent.mkdir(parents=True, exist_ok=True)
        a.markdown.write_text(provenance() + "\n\n" + text + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
