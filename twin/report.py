"""Figures, trajectories and metrics files for runs (matplotlib imported lazily)."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from twin.registry import label as kind_label
from twin.runs import Run

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray",
            "tab:olive", "tab:cyan")  # matplotlib's tab10, in the order the runs are given


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_runs(runs: list, path: Path, title: str = "") -> Path:
    """The paper's Figs. 6–8 panels (θ, torque, dψ/dt, distance, α) with runs overlaid.

    ``runs``: :class:`~twin.runs.Run` (from the twin or the analytic model).
    """
    plt = _pyplot()
    panels = [
        ("θ [rad]", lambda r: r.signal("theta")),
        ("total torque ul + ur [N·m]", lambda r: r.total_torque),
        ("dψ/dt [rad/s]", lambda r: r.signal("psi_dot")),
        ("distance p = rψ [m]", lambda r: r.distance),
        ("heading α [rad]", lambda r: r.signal("alpha")),
    ]
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 10), sharex=True)
    for ax, (label, get) in zip(axes, panels):
        for i, r in enumerate(runs):
            ax.plot(*_envelope(r.t, get(r)), color=_COLOURS[i % len(_COLOURS)], lw=1.2, label=kind_label(r.controller) or None)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
    exp = runs[0].experiment
    if exp is not None:
        if exp.p_d is not None:
            axes[3].axhline(exp.p_d, color="k", ls="--", lw=0.8, label="target")
        if exp.alpha_d is not None:
            axes[4].axhline(exp.alpha_d, color="k", ls="--", lw=0.8, label="target")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    import textwrap

    fig.suptitle("\n".join(textwrap.fill(line, 95) for line in title.splitlines()), fontsize=10)
    return _save(plt, fig, path)


def _envelope(t, y, buckets: int = 2000):
    """(t, y) thinned for drawing: above 4 × ``buckets`` samples, each of ``buckets`` equal
    runs of samples keeps its minimum and its maximum, in time order. A line 880 pixels
    wide shows no difference, peaks stay exact, and an hour at 200 Hz (720 000 samples a
    line) no longer costs matplotlib hundreds of megabytes."""
    t, y = np.asarray(t), np.asarray(y)
    n = len(t)
    if n <= 4 * buckets:
        return t, y
    edges = np.linspace(0, n, buckets + 1).astype(int)
    keep = []
    for a, b in zip(edges[:-1], edges[1:]):
        seg = y[a:b]
        if np.isnan(seg).all():  # nothing to draw there; keep the gap a gap
            keep.append(a)
            continue
        keep.extend(sorted({a + int(np.nanargmin(seg)), a + int(np.nanargmax(seg))}))
    keep = np.asarray(keep)
    return t[keep], y[keep]


def _save(plt, fig, path: Path) -> Path:
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_trajectory_csv(run: Run, path: Path) -> Path:
    """Every logged signal, one row per control step, with units in the header."""
    names, units, data = run.columns()
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow([f"{n} [{u}]" for n, u in zip(names, units)])
        for row in data:
            w.writerow([repr(float(v)) for v in row])
    return path


def write_json(obj, path: Path) -> Path:
    """JSON with non-finite floats written as null (valid JSON for every reader)."""
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clean(obj), indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    return path


def plot_surface(g1, g2, z, path: Path, labels: tuple[str, str, str], title: str) -> Path:
    """A control surface as a filled contour map."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 5))
    cs = ax.contourf(g1, g2, z.T, levels=31, cmap="coolwarm")
    fig.colorbar(cs, ax=ax, label=labels[2])
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(title, fontsize=10)
    return _save(plt, fig, path)
