"""Figures of a Monte Carlo robustness sweep (PNG, matplotlib's Agg canvas, no pyplot state).

Each function takes :func:`twin.sweep.statistics.summarize` output or the sweep's rows,
writes one PNG and returns its path. The controllers are drawn in the order given
(``controllers``; default: first seen), each in the colour of its place in matplotlib's
tab10 cycle, and named by ``labels`` (default
:func:`~twin.sweep.statistics.default_label`). Metric values are over the runs that
stayed up (neither fell, diverged nor errored); infinite values (settling never came)
cannot be drawn and are counted in the panel title instead.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from twin.sweep.statistics import (select_controllers, controller_labels, metric_value, paired_rows, present_metrics,
                                   resolve_controllers, stayed_up)

DPI = 110
#: matplotlib's tab10 cycle: the i-th controller of a report takes the i-th colour.
TAB10 = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple",
         "tab:brown", "tab:pink", "tab:gray", "tab:olive", "tab:cyan")


def controller_colours(controllers: Sequence[str]) -> dict[str, str]:
    """The colour of each controller by its place in ``controllers`` (tab10, cycled)."""
    return {c: TAB10[i % len(TAB10)] for i, c in enumerate(controllers)}


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


def plot_success(summary: list[dict], path, *, controllers: Sequence[str] | None = None,
                 labels: Mapping[str, str] | None = None) -> Path:
    """Success rate against the uncertainty level λ, one line per controller, with Wilson CIs.

    Parameters
    ----------
    summary : list of dict
        :func:`~twin.sweep.statistics.summarize` output (the "all levels" entries are
        not drawn).
    path : str or Path
        PNG file to write.
    controllers : sequence of str, optional
        The controllers, in order (it sets their colours). None: the summary's order.
    labels : mapping of str to str, optional
        Display names (default :func:`~twin.sweep.statistics.default_label`).

    Returns
    -------
    Path
        ``path``.
    """
    controllers, _ = resolve_controllers(summary, controllers)
    colours, names = controller_colours(controllers), controller_labels(controllers, labels)
    per_level = [s for s in select_controllers(summary, controllers) if s["level"] is not None and s["n"] > 0]
    levels = sorted({s["level"] for s in per_level})
    span = (levels[-1] - levels[0]) if len(levels) > 1 else 1.0
    fig = _figure(6.0, 4.0)
    ax = fig.add_subplot(1, 1, 1)
    drawn = [c for c in controllers if any(s["controller"] == c for s in per_level)]
    for i, c in enumerate(drawn):
        pts = [s for s in per_level if s["controller"] == c]
        # offsets of 2 % of the λ range keep the error bars apart
        x = np.array([s["level"] for s in pts]) + (i - (len(drawn) - 1) / 2) * 0.02 * span
        y = np.array([s["success_rate"] for s in pts])
        err = np.array([[r - s["success_ci"][0], s["success_ci"][1] - r] for s, r in zip(pts, y)])
        ax.errorbar(x, y, yerr=np.clip(err.T, 0, None), fmt="o-", capsize=4, color=colours[c], label=names[c])
    if not per_level:
        _empty(ax, "no runs")
    ax.set_xticks(levels)
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("uncertainty level λ (dimensionless)")
    ax.set_ylabel("success rate (fraction of runs)")
    ax.grid(alpha=0.3)
    if drawn:
        ax.legend(loc="best", title=f"bars: Wilson {100 * per_level[0]['confidence']:g} % CI",
                  title_fontsize=8, fontsize=9)
    fig.tight_layout()
    return _save(fig, path)


def _metric_figure(rows: list[dict], panel_height: float, blocks: int = 1):
    """(figure with room for ``blocks`` groups of one panel per metric present, the metrics, the
    sorted levels); without any metric the figure already says so."""
    metrics = present_metrics(rows)
    levels = sorted({float(r["level"]) for r in rows})
    per_block = max(1, math.ceil(len(metrics) / 3))
    fig = _figure(4.2 * min(3, max(len(metrics), 1)), panel_height * per_block * (max(blocks, 1) if metrics else 1))
    if not metrics:
        _empty(fig.add_subplot(1, 1, 1), "no run stayed up: no metric to show")
    return fig, metrics, levels


def plot_distributions(rows: list[dict], path, *, controllers: Sequence[str] | None = None,
                       labels: Mapping[str, str] | None = None) -> Path:
    """Box plots of each metric per level, the controllers side by side (runs that stayed up).

    Parameters
    ----------
    rows : list of dict
        The sweep's rows.
    path : str or Path
        PNG file to write.
    controllers : sequence of str, optional
        The controllers, in order (left to right within a level; it sets their colours).
        None: those of ``rows``, first-seen order.
    labels : mapping of str to str, optional
        Display names (default :func:`~twin.sweep.statistics.default_label`).

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib.patches import Patch

    controllers, _ = resolve_controllers(rows, controllers)
    colours, names = controller_colours(controllers), controller_labels(controllers, labels)
    rows = select_controllers(rows, controllers)
    fig, metrics, levels = _metric_figure(rows, 3.4)
    if not metrics:
        return _save(fig, path)
    # the boxes of one level share 0.76 of the unit between levels (two: 0.38 apart, 0.32 wide)
    step = 0.76 / max(len(controllers), 1)
    for ax, (key, label, unit, _) in zip(_grid(fig, len(metrics)), metrics):
        shown, infinite = [], 0
        for i, level in enumerate(levels):
            for j, c in enumerate(controllers):
                v = [metric_value(r, key) for r in rows if float(r["level"]) == level
                     and r["controller"] == c and stayed_up(r)]
                v = [x for x in v if x is not None]
                finite = [x for x in v if math.isfinite(x)]
                infinite += len(v) - len(finite)
                if finite:
                    bp = ax.boxplot([finite], positions=[i + (j - (len(controllers) - 1) / 2) * step],
                                    widths=0.84 * step, patch_artist=True, showfliers=True,
                                    medianprops={"color": "0.15"})
                    for box in bp["boxes"]:
                        box.set(facecolor=colours[c], alpha=0.6)
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
    # the legend is a row (or rows of five) above the panels, whatever the length of the names
    ncol = min(len(controllers), 5)
    fig.legend(handles=[Patch(facecolor=colours[c], alpha=0.6, label=names[c]) for c in controllers],
               loc="upper center", ncol=ncol, frameon=False)
    top = 1 - (0.1 + 0.3 * math.ceil(len(controllers) / ncol)) / fig.get_figheight()
    fig.tight_layout(rect=(0, 0, 1, top))
    return _save(fig, path)


def plot_paired(rows: list[dict], path, *, controllers: Sequence[str] | None = None,
                reference: str | None = None, labels: Mapping[str, str] | None = None) -> Path:
    """Per metric, each controller against the reference on each pair of runs that both
    stayed up, by level: one row of panels per controller other than the reference.

    A point is one pair: the reference's value across, the controller's up; points below
    the diagonal are pairs where the controller has the lower (better) value.

    Parameters
    ----------
    rows : list of dict
        The sweep's rows.
    path : str or Path
        PNG file to write.
    controllers : sequence of str, optional
        The controllers, in order (the rows of panels follow it). None: those of ``rows``,
        first-seen order.
    reference : str, optional
        The controller the others are paired with. None: the last of ``controllers``.
    labels : mapping of str to str, optional
        Display names (default :func:`~twin.sweep.statistics.default_label`).

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib import colormaps

    controllers, reference = resolve_controllers(rows, controllers, reference)
    names = controller_labels(controllers, labels)
    others = [c for c in controllers if c != reference]
    rows = select_controllers(rows, controllers)
    fig, metrics, levels = _metric_figure(rows, 3.8, len(others))
    if not metrics:
        return _save(fig, path)
    if not others:
        _empty(fig.add_subplot(1, 1, 1), "fewer than two controllers: nothing to pair")
        return _save(fig, path)
    cmap = colormaps["viridis"]
    colour = {lv: cmap(i / max(len(levels) - 1, 1)) for i, lv in enumerate(levels)}
    per_block = max(1, math.ceil(len(metrics) / 3))
    ncols = min(3, len(metrics))
    for b, c in enumerate(others):
        a_name, r_name = names[c], names[reference]
        pairs = [(x, y) for x, y in paired_rows(rows, c, reference) if stayed_up(x) and stayed_up(y)]
        axes = [fig.add_subplot(per_block * len(others), ncols, b * per_block * ncols + k + 1)
                for k in range(len(metrics))]
        for ax, (key, label, unit, _) in zip(axes, metrics):
            pts = [(float(x["level"]), metric_value(y, key), metric_value(x, key)) for x, y in pairs]
            pts = [p for p in pts if p[1] is not None and p[2] is not None]
            finite = [p for p in pts if math.isfinite(p[1]) and math.isfinite(p[2])]
            for lv in levels:
                xy = np.array([(x, y) for level, x, y in finite if level == lv]).reshape(-1, 2)
                if len(xy):
                    ax.scatter(xy[:, 0], xy[:, 1], s=14, color=colour[lv], alpha=0.8, label=f"λ = {lv:g}")
            if finite:
                v = np.array([p[1:] for p in finite]).ravel()
                lo, hi = float(v.min()), float(v.max())
                ax.plot([lo, hi], [lo, hi], color="0.4", lw=1, ls="--", label=f"{a_name} = {r_name}")
                _log_if_wide(ax, v, "x")
                _log_if_wide(ax, v, "y")
                ax.legend(fontsize=7, loc="upper left")
            else:
                _empty(ax, "no pair with both values finite" if pts else "no pair with both runs up")
            dropped = len(pts) - len(finite)
            title = label if len(others) == 1 else f"{a_name} against {r_name}: {label}"
            ax.set_title(title + (f" (pairs with ∞, not shown: {dropped})" if dropped else ""), fontsize=9)
            ax.set_xlabel(f"{r_name} ({unit})")
            ax.set_ylabel(f"{a_name} ({unit})")
            ax.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, path)
