"""Issue 18's judgement by the twin: the paper-exp3 Monte Carlo sweep with the nominal balance
design (the default before issue 18) and with the robust one (the default since), IT2, type-1
and LQR on identical samples.

Run from the repository root (two sweeps of 600 samples × 3 controllers, about 10 min each on
2 cores; rerun to resume)::

    python benchmarks/robust_design_sweep.py              # runs both sweeps, then compares
    python benchmarks/robust_design_sweep.py --compare    # compares sweeps already run

``--markdown PATH`` (``docs/_generated/robust-design.md``) also writes the comparison there for
the documentation, under a line naming the command, machine, date and commit
(``benchmarks/published.py``).

Writes ``runs/robust-design/comparison.md`` (success against λ with Wilson intervals, and at
λ = 0 the medians of settling time and IAE over the runs that stayed up) and
``docs/sweep-robust-design.png`` (success against λ, both designs, every controller).

The robust design (the scenarios' default ``[design]``) is certified (``twin design``) for the nominal model and the corners of
m_b ±30 %, l ±15 % with decay rate 2 1/s and damping ratio 0.5 for every vertex closed loop
(``all_vertices``); the sweep perturbs all nine non-geometric Table III parameters by up to
±λ, so what is certified covers only part of what is sampled. LQR's gains come from its own
Riccati design and do not depend on the LMI design: it runs in both sweeps as the same
reference (its numbers must agree, which the comparison checks).
"""
from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "runs" / "robust-design"
# the nominal design: Lemmas 1–2 and a decay rate of 3 1/s on the nominal model alone
NOMINAL = ["--set", "design.decay_rate=3", "--set", "design.damping=0",
           "--set", "design.uncertain={}", "--set", "design.all_vertices=false"]
DESIGNS = {"nominal": NOMINAL, "robust": []}
LABEL = {"it2": "IT2", "t1": "type-1", "lqr": "LQR"}


def run_sweeps(samples: int) -> None:
    for name, extra in DESIGNS.items():
        cmd = [sys.executable, "-m", "twin.cli", "sweep", "paper-exp3", "--samples", str(samples),
               "--controller", "it2,t1,lqr", "--reference", "lqr", "--out", str(OUT / name), *extra]
        print(" ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, cwd=ROOT)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return c - h, c + h


def compare() -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    data = {name: pd.read_csv(OUT / name / "sweep.csv") for name in DESIGNS}
    lqr = [d[d.controller == "lqr"].sort_values("sample")["success"].to_numpy() for d in data.values()]
    lqr_same = len(lqr[0]) == len(lqr[1]) and (lqr[0] == lqr[1]).all()
    levels = sorted(data["nominal"].level.unique())
    lines = ["| controller | design | " + " | ".join(f"λ = {lv:g}" for lv in levels) + " |",
             "|---|---|" + "---|" * len(levels)]
    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=120)
    colours = {"it2": "tab:blue", "t1": "tab:orange", "lqr": "tab:green"}
    for c in ("it2", "t1", "lqr"):
        for name, d in data.items():
            if c == "lqr" and name == "robust":
                continue  # the same runs as in "nominal"
            rates, cells = [], []
            for lv in levels:
                s = d[(d.controller == c) & (d.level == lv)]["success"].astype(bool)
                k, n = int(s.sum()), len(s)
                lo, hi = wilson(k, n)
                rates.append((k / n, lo, hi))
                cells.append(f"{k / n:.2f} [{lo:.2f}, {hi:.2f}]")
            label = LABEL[c] + (" (its own design)" if c == "lqr" else
                                ", robust design (default)" if name == "robust" else ", nominal design")
            lines.append(f"| {LABEL[c]} | {'(its own)' if c == 'lqr' else name} | " + " | ".join(cells) + " |")
            r = list(zip(*rates))
            ax.errorbar(levels, r[0], yerr=[[max(a - b, 0.0) for a, b in zip(r[0], r[1])], [max(b - a, 0.0) for a, b in zip(r[0], r[2])]],
                        color=colours[c], ls="-" if name == "robust" else "--", marker="o", ms=4, capsize=3,
                        label=label)
    ax.set_xlabel("uncertainty level λ (each parameter × (1 + λu), u ~ U(−1, 1))")
    ax.set_ylabel("success rate (Wilson 95 % CI)")
    ax.set_ylim(0, 1.05)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title("paper-exp3, 100 draws per level: the nominal LMI design against the robust one", fontsize=9)
    fig.tight_layout()
    fig.savefig(ROOT / "docs" / "sweep-robust-design.png")
    lines += ["", "At λ = 0, runs that stayed up (medians):", "",
              "| controller | design | success | settling time [s] | IAE θ [rad·s] | θ p-p last 5 s [rad] |",
              "|---|---|---|---|---|---|"]
    for c in ("it2", "t1", "lqr"):
        for name, d in data.items():
            if c == "lqr" and name == "robust":
                continue
            s = d[(d.controller == c) & (d.level == 0)]
            up = s[~s.fell.astype(bool)]
            lines.append(f"| {LABEL[c]} | {'(its own)' if c == 'lqr' else name} | {s.success.astype(bool).mean():.2f} | "
                         f"{up.settling_time_s.median():.2f} | {up.iae_theta.median():.4f} | "
                         f"{up.oscillation_peak_to_peak_rad.median():.4f} |")
    lines += ["", f"LQR identical in both sweeps: {lqr_same}"]
    text = "\n".join(lines) + "\n"
    (OUT / "comparison.md").write_text(text)
    return text


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare", action="store_true", help="compare sweeps already run")
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--markdown", metavar="PATH", help="also write the comparison to PATH (docs/_generated/...)")
    a = ap.parse_args()
    if not a.compare:
        run_sweeps(a.samples)
    text = compare()
    print(text)
    if a.markdown:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from published import write_markdown

        intro = (f"paper-exp3, {a.samples} samples per uncertainty level λ (each of the nine non-geometric Table III "
                 "parameters × (1 + λu), u ~ U(−1, 1)), IT2, type-1 and LQR on identical samples, with the nominal "
                 "balance design and the robust (default) one; success rate with its Wilson 95 % interval.")
        write_markdown(a.markdown, intro + "\n\n" + text)
