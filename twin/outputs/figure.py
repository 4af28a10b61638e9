"""The run figure drawn from plain data: six panels, matplotlib's object API on the Agg canvas.

Split from the data (:func:`twin.outputs.report.figure_data`, which reads the runs) so that the
drawing can happen in another process (:mod:`twin.outputs.figure_worker`) from arrays and strings
alone; this module imports nothing of the twin, and matplotlib only inside its functions.

Drawn for speed, the figure looking the same as with matplotlib's defaults: no pyplot (no
figure manager, no global state); the empty figure (:func:`new_figure`) is built before the
data exists, with its tick objects made, so that a worker can build it and draw it once
(loading the fonts) while the runs are simulated; margins are fixed (:func:`_place`) instead
of matplotlib's tight layout, which measures every text of the figure in an extra pass
(0.1-0.2 s here), and are checked after drawing (:func:`_clipped`): only if a tick label
would be cut off is the tight layout used after all. Titles and x labels are placed at fixed
offsets, which saves matplotlib comparing each panel's ticks with its shared-axis siblings'.
"""
from __future__ import annotations

import math
import textwrap

PANELS = ("θ [rad]", "estimator error θ̂ − θ [rad]", "delivered torque per wheel [N·m]", "dψ/dt [rad/s]",
          "distance p = rψ [m]", "heading α [rad]")
PUSH_COLOUR, FAULT_COLOUR = "tab:red", "tab:purple"
SIZE = (12.0, 10.5)  # in
DPI = 110
TICKS_READY = 12  # tick objects made per axis in advance (matplotlib reuses them; making one costs ~1 ms)
# fixed margins (fractions of the figure): room for y tick labels of 8 characters ("−0.00025")
# at the left and between the columns; the top leaves the suptitle's lines (see _place)
LEFT, RIGHT, BOTTOM, WSPACE, HSPACE = 0.062, 0.988, 0.056, 0.17, 0.16
TITLE_LINES = 6  # the suptitle's lines at most (the rest cut): the panels keep 3/4 of the height
PNG_COMPRESSION = 1  # zlib level: 15 % larger files than matplotlib's 6, 30 ms less to write


def new_figure():
    """(fig, axes): the empty figure, six panels titled and gridded, the bottom row's x axis
    labelled, on an Agg canvas at :data:`DPI`."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.transforms import offset_copy

    fig = Figure(figsize=SIZE, dpi=DPI)
    FigureCanvasAgg(fig)
    grid = fig.subplots(3, 2, sharex=True)
    axes = list(grid.ravel())
    for ax, label in zip(axes, PANELS):
        # centred: the axis' ×10ⁿ offset sits at the top left; y=1.0: the title's place
        # fixed (over the axes' top), where matplotlib would look on every draw for tick
        # labels above the axes (there are none)
        ax.set_title(label, fontsize=9, y=1.0)
        ax.grid(alpha=0.3)
        # the x label at a fixed distance below the axes (tick labels are one line of
        # fixed height), not placed by comparing the ticks of the six shared x axes
        ax.xaxis.set_label_coords(0.5, 0.0, transform=offset_copy(ax.transAxes, fig=fig, y=-21.0, units="points"))
        ax.xaxis.get_major_ticks(TICKS_READY)
        ax.yaxis.get_major_ticks(TICKS_READY)
    for ax in grid[-1]:
        ax.set_xlabel("time [s]")
    return fig, axes


def warm_up(fig) -> None:
    """Draw the empty figure once: fonts loaded, glyphs and text sizes cached, for the real
    drawing later (a worker does this while the runs are simulated)."""
    fig.canvas.draw()


def fill_figure(fig, axes, data: dict, title: str = ""):
    """Draw ``data`` (:func:`twin.outputs.report.figure_data`) into the empty figure of
    :func:`new_figure`: θ with each run's settling time marked; the estimator's error
    θ̂ − θ beside it; each wheel's delivered torque with the saturated samples marked;
    dψ/dt; p = rψ and α with their targets. Pushes and sensor-fault windows shaded on every
    panel, every line in a legend. Returns ``fig``."""
    ax_th, ax_err, ax_tq, ax_psd, ax_p, ax_al = axes
    for r in data["runs"]:
        c, name = r["colour"], r["name"]
        ax_th.plot(*r["theta"], color=c, lw=1.2, label=name)
        ts = r["settling_time"]
        if math.isfinite(ts):
            ax_th.axvline(ts, color=c, ls=":", lw=1.0, label=f"{name} settled, {ts:.2f} s")
        if r["error"] is not None:
            ax_err.plot(*r["error"], color=c, lw=1.0, label=f"{name} ({r['sensing']})")
        for side, ls, word in (("l", "-", "left"), ("r", "--", "right")):
            ax_tq.plot(*r[f"torque_{side}"], color=c, lw=1.0, ls=ls, label=f"{name} {word}")
            sat = r[f"saturated_{side}"]
            if sat is not None:
                ax_tq.plot(*sat, ls="none", marker="x", ms=4, color=c, label=f"{name} {word} saturated")
        ax_psd.plot(*r["psi_dot"], color=c, lw=1.2, label=name)
        ax_p.plot(*r["distance"], color=c, lw=1.2, label=name)
        ax_al.plot(*r["alpha"], color=c, lw=1.2, label=name)
    if data["p_d"] is not None:
        ax_p.axhline(data["p_d"], color="k", ls="--", lw=0.8, label="target p_d")
    if data["alpha_d"] is not None:
        ax_al.axhline(data["alpha_d"], color="k", ls="--", lw=0.8, label="target α_d")
    if not ax_err.lines:
        ax_err.text(0.5, 0.5, "ideal sensing: the controllers read the truth", ha="center", va="center",
                    transform=ax_err.transAxes, fontsize=9, color="0.4")
    for ax in axes:
        for kind, a, b in data["spans"]:
            ax.axvspan(a, b, color=PUSH_COLOUR if kind == "push" else FAULT_COLOUR, alpha=0.15, lw=0, label=kind)
        handles, labels = ax.get_legend_handles_labels()
        keep = {}
        for h, lab in zip(handles, labels):
            keep.setdefault(lab, h)  # one entry per label: spans repeat theirs
        if keep:
            ax.legend(keep.values(), keep.keys(), loc="best", fontsize=7, ncol=2 if len(keep) > 4 else 1)
    lines = "\n".join(textwrap.fill(line, 140) for line in title.splitlines()).split("\n")
    if len(lines) > TITLE_LINES:  # each line lowers the panels' top: a long title would leave them no room
        lines = lines[:TITLE_LINES - 1] + [lines[TITLE_LINES - 1][:139] + "…"]
    text = "\n".join(lines)
    fig.suptitle(text, fontsize=10)
    _place(fig, max(1, text.count("\n") + 1))
    return fig


def _place(fig, n_lines: int) -> None:
    """The fixed margins, the top lowered by one line of the suptitle per line."""
    fig.set_layout_engine(None)
    fig.subplots_adjust(left=LEFT, right=RIGHT, bottom=BOTTOM, top=0.9175 - 0.016 * n_lines,
                        wspace=WSPACE, hspace=HSPACE)


def _clipped(fig) -> bool:
    """True if a y tick label (or the ×10ⁿ offset) of the drawn figure comes within 3 points of
    the figure's edge or of the panel on its left: then the fixed margins are too narrow for
    these numbers. Reads the labels as the draw left them (``Axis.get_tightbbox`` would lay
    the ticks out again: 20 ms against 2)."""
    renderer = fig.canvas.get_renderer()
    axes = fig.get_axes()
    gap = 3.0 * fig.dpi / 72.0  # px: 3 points clear of the edge or the panel on the left
    for i, ax in enumerate(axes):
        limit = gap + (0.0 if i % 2 == 0 else axes[i - 1].bbox.x1)
        lo, hi = sorted(ax.get_ylim())
        slack = 1e-9 * (hi - lo)
        locs = ax.yaxis.get_majorticklocs()
        labels = [t.label1 for loc, t in zip(locs, ax.yaxis.get_major_ticks(len(locs)))
                  if lo - slack <= loc <= hi + slack]  # the ticks drawn: those in view
        labels.append(ax.yaxis.get_offset_text())
        for text in labels:
            if text.get_visible() and text.get_text() and text.get_window_extent(renderer).x0 < limit:
                return True
    return False


def save_figure(fig, path) -> None:
    """Write ``fig`` as a PNG at :data:`DPI`; with matplotlib's tight layout if the fixed
    margins would cut a tick label off (drawn again then)."""
    kwargs = {"dpi": DPI, "pil_kwargs": {"compress_level": PNG_COMPRESSION}}
    fig.savefig(path, **kwargs)
    if fig.get_layout_engine() is None and _clipped(fig):
        n = fig.get_suptitle().count("\n") + 1
        fig.set_layout_engine("tight", rect=(0, 0, 1, 1 - 0.017 * n))  # the title's room kept
        fig.savefig(path, **kwargs)
