"""Figures of a Monte Carlo robustness sweep (PNG, matplotlib's Agg canvas, no pyplot state).

Each function takes :func:`twin.sweep.statistics.summarize` output or the sweep's rows,
writes one PNG and returns its path. Metric values are over the runs that stayed up
(neither fell, diverged nor errored); infinite values (settling never came) cannot be
drawn and are counted in the panel title instead.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from twin.sweep.statistics import (CONTROLLER_LABELS, CONTROLLERS, _pairs, metric_value,
                                   present_metrics, stayed_up)

DPI = 110
COLOURS = {"it2": "tab:blue", "t1": "tab:orange"}


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    fig.clear()  # a Figure without pyplot is freed with its last reference
    return path


def _grid(fig, count: int):
    ncols = min(3, max(count, 1))
    nrows = max(1, math.ceil(count / ncols))
    return [fig.add_subplot(nrows, ncols, i + 1) for i in range(count)]


def _log_if_wide(ax, values, axis="y") -> None:
    """Log scale when the positive values span more than two decades."""
    v = np.asarray(values, dtype=float)
    if len(v) and np.all(v > 0) and v.max() / v.min() > 100:
        (ax.set_yscale if axis == "y" else ax.set_xscale)("log")


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _level_text(level: float) -> str:
    return f"{level:g}"


def plot_success(summary: list[dict], path) -> Path:
    """Success rate against the uncertainty level λ, IT2 and type-1, with Wilson CIs.

    Parameters
    ----------
    summary : list of dict
        :func:`~twin.sweep.statistics.summarize` output (the "all levels" entries are
        not drawn).
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        ``path``.
    """
    per_level = [s for s in summary if s["level"] is not None and s["n"] > 0]
    levels = sorted({s["level"] for s in per_level})
    span = (levels[-1] - levels[0]) if len(levels) > 1 else 1.0
    fig = _figure(6.0, 4.0)
    ax = fig.add_subplot(1, 1, 1)
    controllers = [c for c in CONTROLLERS if any(s["controller"] == c for s in per_level)]
    for i, c in enumerate(controllers):
        pts = [s for s in per_level if s["controller"] == c]
        # offsets of 2 % of the λ range keep the error bars apart
        x = np.array([s["level"] for s in pts]) + (i - (len(controllers) - 1) / 2) * 0.02 * span
        y = np.array([s["success_rate"] for s in pts])
        err = np.array([[r - s["success_ci"][0], s["success_ci"][1] - r] for s, r in zip(pts, y)])
        ax.errorbar(x, y, yerr=np.clip(err.T, 0, None), fmt="o-", capsize=4, color=COLOURS.get(c),
                    label=f"{CONTROLLER_LABELS.get(c, c)} (Wilson {100 * pts[0]['confidence']:g} % CI)")
    if not per_level:
        _empty(ax, "no runs")
    ax.set_xticks(levels)
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("uncertainty level λ (dimensionless)")
    ax.set_ylabel("success rate (fraction of runs)")
    ax.grid(alpha=0.3)
    if controllers:
        ax.legend(loc="lower left")
    fig.tight_layout()
    return _save(fig, path)


def _metric_figure(rows: list[dict], panel_height: float):
    """(figure with room for one panel per metric present, the metrics, the sorted levels); without
    any metric the figure already says so."""
    metrics = present_metrics(rows)
    levels = sorted({float(r["level"]) for r in rows})
    fig = _figure(4.2 * min(3, max(len(metrics), 1)), panel_height * max(1, math.ceil(len(metrics) / 3)))
    if not metrics:
        _empty(fig.add_subplot(1, 1, 1), "no run stayed up: no metric to show")
    return fig, metrics, levels


def plot_distributions(rows: list[dict], path) -> Path:
    """Box plots of each metric per level, IT2 and type-1 side by side (runs that stayed up).

    Parameters
    ----------
    rows : list of dict
        The sweep's rows.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib.patches import Patch

    fig, metrics, levels = _metric_figure(rows, 3.4)
    if not metrics:
        return _save(fig, path)
    for ax, (key, label, unit, _) in zip(_grid(fig, len(metrics)), metrics):
        shown, infinite = [], 0
        for i, level in enumerate(levels):
            for j, c in enumerate(CONTROLLERS):
                v = [metric_value(r, key) for r in rows if float(r["level"]) == level
                     and r["controller"] == c and stayed_up(r)]
                v = [x for x in v if x is not None]
                finite = [x for x in v if math.isfinite(x)]
                infinite += len(v) - len(finite)
                if finite:
                    bp = ax.boxplot([finite], positions=[i + (j - 0.5) * 0.38], widths=0.32,
                                    patch_artist=True, showfliers=True)
                    for box in bp["boxes"]:
                        box.set(facecolor=COLOURS[c], alpha=0.6)
                    shown += finite
        if shown:
            _log_if_wide(ax, shown)
        else:
            _empty(ax, "no finite value")
        ax.set_xticks(range(len(levels)), [_level_text(lv) for lv in levels])
        ax.set_xlim(-0.6, len(levels) - 0.4)
        ax.set_xlabel("uncertainty level λ (dimensionless)")
        ax.set_ylabel(f"{label} ({unit})")
        ax.set_title(label + (f" (never settled, ∞, not shown: {infinite})" if infinite else ""),
                     fontsize=9)
        ax.grid(alpha=0.3, axis="y")
    fig.legend(handles=[Patch(facecolor=COLOURS[c], alpha=0.6, label=CONTROLLER_LABELS[c])
                        for c in CONTROLLERS], loc="upper right")
    fig.tight_layout(rect=(0, 0, 0.93, 1))
    return _save(fig, path)


def plot_paired(rows: list[dict], path) -> Path:
    """Per metric, IT2 against type-1 on each pair of runs that both stayed up, by level.

    Points below the diagonal are pairs where IT2 has the lower (better) value.

    Parameters
    ----------
    rows : list of dict
        The sweep's rows.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib import colormaps

    fig, metrics, levels = _metric_figure(rows, 3.8)
    if not metrics:
        return _save(fig, path)
    cmap = colormaps["viridis"]
    colour = {lv: cmap(i / max(len(levels) - 1, 1)) for i, lv in enumerate(levels)}
    pairs = [(a, b) for a, b in _pairs(rows) if stayed_up(a) and stayed_up(b)]
    for ax, (key, label, unit, _) in zip(_grid(fig, len(metrics)), metrics):
        pts = [(float(a["level"]), metric_value(b, key), metric_value(a, key)) for a, b in pairs]
        pts = [p for p in pts if p[1] is not None and p[2] is not None]
        finite = [p for p in pts if math.isfinite(p[1]) and math.isfinite(p[2])]
        for lv in levels:
            xy = np.array([(x, y) for level, x, y in finite if level == lv]).reshape(-1, 2)
            if len(xy):
                ax.scatter(xy[:, 0], xy[:, 1], s=14, color=colour[lv], alpha=0.8, label=f"λ = {lv:g}")
        if finite:
            v = np.array([p[1:] for p in finite]).ravel()
            lo, hi = float(v.min()), float(v.max())
            ax.plot([lo, hi], [lo, hi], color="0.4", lw=1, ls="--", label="IT2 = type-1")
            _log_if_wide(ax, v, "x")
            _log_if_wide(ax, v, "y")
            ax.legend(fontsize=7, loc="upper left")
        else:
            _empty(ax, "no pair with both runs up")
        dropped = len(pts) - len(finite)
        ax.set_title(label + (f" (pairs with ∞, not shown: {dropped})" if dropped else ""), fontsize=9)
        ax.set_xlabel(f"type-1 ({unit})")
        ax.set_ylabel(f"IT2 ({unit})")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, path)
