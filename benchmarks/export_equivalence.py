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


def _delta(a, b) -> float:
    """|a − b| of two settling times; 0 when neither settles, ∞ when one does."""
    if a is None or b is None:
        return 0.0 if a is None and b is None else float("inf")
    return abs(a - b)


def case(args) -> dict:
    name, kind, seeds, out = args
    dirs = {p: Path(out) / f"{name}-{kind}-{p}" for p in ("float64", "float32")}
    for p, d in dirs.items():
        export(name, kind, None, p, d, seconds=0.05)
    sc = load_scenario(name)
    bounds = parse_expect(sc.expect)
    row = {"scenario": name, "controller": kind, "identical": 0, "seeds": len(seeds), "d_settling": {}, "d_rms": {},
           "held": {"torque": 0, "duty": 0}, "python_held": 0, "osc": {"python": [], "duty": []}}
    # how far the float64 run's own metrics move when its start moves by a rounding error (seed 0)
    theta = sc.data["initial"]["theta"]
    m0 = run_metrics(simulate(load_scenario(name, (f"seed={seeds[0]}",)).run_spec(kind)))
    ds0, dr0 = 0.0, 0.0
    for dt in (1e-12, -1e-12):
        m = run_metrics(simulate(load_scenario(name, (f"seed={seeds[0]}", f"initial.theta={theta + dt!r}")).run_spec(kind)))
        ds0 = max(ds0, _delta(m["settling_time_s"], m0["settling_time_s"]))
        dr0 = max(dr0, abs(m["theta_rms_rad"] - m0["theta_rms_rad"]) / m0["theta_rms_rad"])
    row["rounding"] = (ds0, dr0)
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
        row["osc"]["python"].append(m_py["oscillation_peak_to_peak_rad"])
        row["osc"]["duty"].append(run_metrics(runs["float32", "duty"])["oscillation_peak_to_peak_rad"])
        for drive in ("torque", "duty"):
            m = run_metrics(runs["float32", drive])
            row["held"][drive] += all(v.holds for v in evaluate(bounds, f"export:{dirs['float32']}", {seed: m}))
            ds = _delta(m["settling_time_s"], m_py["settling_time_s"])
            dr = abs(m["theta_rms_rad"] - m_py["theta_rms_rad"]) / m_py["theta_rms_rad"]
            row["d_settling"][drive] = max(row["d_settling"].get(drive, 0.0), ds)
            row["d_rms"][drive] = max(row["d_rms"].get(drive, 0.0), dr)
    return row


def table(rows) -> str:
    lines = ["| scenario | controller | float64 = Python, bit for bit | float32, twin's driver: Δ settling / Δ θ RMS "
             "| float64 itself, start moved 1e-12 rad: Δ settling / Δ θ RMS | float32, its own duties: Δ settling / "
             "Δ θ RMS | oscillation, last 5 s: Python / own duties (median) | `[expect]` held: Python / float32 "
             "torque / float32 duty |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        n = r["seeds"]
        lines.append(f"| {r['scenario']} | {r['controller']} | {r['identical']} of {n} | "
                     f"{r['d_settling']['torque']:.3f} s / {100 * r['d_rms']['torque']:.1f} % | "
                     f"{r['rounding'][0]:.3f} s / {100 * r['rounding'][1]:.1f} % | "
                     f"{r['d_settling']['duty']:.3f} s / {100 * r['d_rms']['duty']:.1f} % | "
                     f"{1000 * np.median(r['osc']['python']):.1f} / {1000 * np.median(r['osc']['duty']):.1f} mrad | "
                     f"{r['python_held']} / {r['held']['torque']} / {r['held']['duty']} of {n} |")
    return "\n".join(lines) + (
        "\n\nΔ: the worst over the seeds of |float32 − Python| (settling time, s) and |float32 − Python| / Python "
        "(θ RMS after settling). The settling time is the first time after which |θ| stays below 0.01 rad: where "
        "the last excursion grazes that threshold, a rounding error moves it by tenths of a second, as the float64 "
        "run's own column shows. 'Its own duties': the C's driver law sets the PWM duties with the wheel speeds "
        "from its estimate (the robot's case); 'twin's driver': with the true speeds.")


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
