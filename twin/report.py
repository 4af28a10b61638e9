"""Figures, trajectories and metrics files for runs (matplotlib imported lazily)."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from twin.registry import label as kind_label
from twin.runs import Run
from twin.sensors.faults import fault_windows

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray",
            "tab:olive", "tab:cyan")  # matplotlib's tab10, in the order the runs are given


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


PUSH_COLOUR, FAULT_COLOUR = "tab:red", "tab:purple"


def plot_runs(runs: list, path: Path, title: str = "") -> Path:
    """The figure of a scenario's runs (:func:`figure_runs`), written to ``path`` (PNG)."""
    plt = _pyplot()
    fig = figure_runs(runs, title)
    return _save(plt, fig, path)


def figure_runs(runs: list, title: str = ""):
    """The paper's Figs. 6–8 quantities with runs overlaid, and what explains them: θ with
    each run's settling time marked; the estimator's error θ̂ − θ (what the controllers were
    given minus the truth) beside it; each wheel's delivered torque with the samples where
    the motor driver saturated marked; dψ/dt; the distance p = rψ and the heading α with
    their targets. Pushes and sensor-fault windows are shaded on every panel, and every
    line is in a legend. A matplotlib Figure (axes titled by their quantity and unit).

    ``runs``: :class:`~twin.runs.Run` (from the twin or the analytic model)."""
    import textwrap

    plt = _pyplot()
    fig, grid = plt.subplots(3, 2, figsize=(12, 10.5), sharex=True)
    ax_th, ax_err, ax_tq, ax_psd, ax_p, ax_al = grid.ravel()
    for i, r in enumerate(runs):
        c = _COLOURS[i % len(_COLOURS)]
        name = kind_label(r.controller) or r.controller or f"run {i + 1}"
        ax_th.plot(*_envelope(r.t, r.signal("theta")), color=c, lw=1.2, label=name)
        ts = r.settling_time()
        if math.isfinite(ts):
            ax_th.axvline(ts, color=c, ls=":", lw=1.0, label=f"{name} settled, {ts:.2f} s")
        if r.estimates is not None and r.sensing != "ideal":
            ax_err.plot(*_envelope(r.t, r.signal("theta_est") - r.signal("theta")), color=c, lw=1.0,
                        label=f"{name} ({r.sensing})")
        for side, ls in (("l", "-"), ("r", "--")):
            tq = r.signal(f"torque_{side}")
            ax_tq.plot(*_envelope(r.t, tq), color=c, lw=1.0, ls=ls, label=f"{name} {'left' if side == 'l' else 'right'}")
            sat = r.signal(f"saturated_{side}") > 0.5
            if sat.any():
                ax_tq.plot(r.t[sat], tq[sat], ls="none", marker="x", ms=4, color=c,
                           label=f"{name} {'left' if side == 'l' else 'right'} saturated")
        ax_psd.plot(*_envelope(r.t, r.signal("psi_dot")), color=c, lw=1.2, label=name)
        ax_p.plot(*_envelope(r.t, r.distance), color=c, lw=1.2, label=name)
        ax_al.plot(*_envelope(r.t, r.signal("alpha")), color=c, lw=1.2, label=name)
    exp = runs[0].experiment
    if exp is not None:
        if exp.p_d is not None:
            ax_p.axhline(exp.p_d, color="k", ls="--", lw=0.8, label="target p_d")
        if exp.alpha_d is not None:
            ax_al.axhline(exp.alpha_d, color="k", ls="--", lw=0.8, label="target α_d")
    if not ax_err.lines:
        ax_err.text(0.5, 0.5, "ideal sensing: the controllers read the truth", ha="center", va="center",
                    transform=ax_err.transAxes, fontsize=9, color="0.4")
    spans = _shaded_spans(runs)
    for ax, label in ((ax_th, "θ [rad]"), (ax_err, "estimator error θ̂ − θ [rad]"),
                      (ax_tq, "delivered torque per wheel [N·m]"), (ax_psd, "dψ/dt [rad/s]"),
                      (ax_p, "distance p = rψ [m]"), (ax_al, "heading α [rad]")):
        for kind, a, b in spans:
            ax.axvspan(a, b, color=PUSH_COLOUR if kind == "push" else FAULT_COLOUR, alpha=0.15, lw=0,
                       label=kind)
        ax.set_title(label, fontsize=9)  # centred: the axis' ×10ⁿ offset sits at the top left
        ax.grid(alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        keep = {}
        for h, lab in zip(handles, labels):
            keep.setdefault(lab, h)  # one entry per label: spans repeat theirs
        if keep:
            ax.legend(keep.values(), keep.keys(), loc="best", fontsize=7, ncol=2 if len(keep) > 4 else 1)
    for ax in grid[-1]:
        ax.set_xlabel("time [s]")
    text = "\n".join(textwrap.fill(line, 140) for line in title.splitlines())
    fig.suptitle(text, fontsize=10)
    n_lines = max(1, text.count("\n") + 1)
    fig.set_layout_engine("tight", rect=(0, 0, 1, 1 - 0.017 * n_lines))  # the title's room kept
    return fig


def _shaded_spans(runs: list) -> list:
    """[(kind, start, end)]: the pushes of any run ("push", where a push force acted) and the
    sensor-fault windows of the first run's sensors ("sensor fault"; a latency change from
    its time to the end), in s."""
    spans = []
    end = max(float(r.t[-1]) for r in runs) if runs else 0.0
    for r in runs[:1]:
        force = np.abs(r.push).sum(axis=1) > 0.0
        if force.any():
            edges = np.flatnonzero(np.diff(np.concatenate(([0], force.astype(np.int8), [0]))))
            dt = float(r.t[1] - r.t[0]) if len(r.t) > 1 else 0.0
            for a, b in zip(edges[::2], edges[1::2]):
                spans.append(("push", float(r.t[a]), float(r.t[b - 1]) + dt))
        for _, a, b in fault_windows(getattr(r.sensor_config, "faults", ())):
            spans.append(("sensor fault", a, min(b, end)))  # a latency change lasts to the end
    return spans


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
    if not fig.get_layout_engine():
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
