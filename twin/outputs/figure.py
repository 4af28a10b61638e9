"""The run figure drawn from plain data: twelve panels, matplotlib's object API on the Agg canvas.

Split from the data (:func:`twin.outputs.report.figure_data`, which reads the runs) so that the
drawing can happen in another process (:mod:`twin.outputs.figure_worker`) from arrays and strings
alone; this module imports nothing of the twin, and matplotlib only inside its functions.

The panels (:data:`LAYOUT`, four rows of three; :func:`panels` gives them by key)::

    θ                       | zoom: θ in the catch (or a push) | estimator error θ̂ − θ
    torque per wheel,       | zoom: the same torques           | dψ/dt
      delivered and commanded
    distance p = rψ         | heading α                        | x–y path (top view)
    difference to run 1     | controller's signals (one unit)  | controller's signals (another)

Each panel answers a question the six of before left open: the zoom shows the 1 s catch
that a 15 s axis squashes; the difference panel shows whether runs drawn on top of each
other differ at all (and by how much); an axis whose data spans less than its floor
(:data:`FLOORS`, e.g. a heading that only moves by 1e-9 rad of numerical noise) is drawn on
the floor's scale with a note, rather than autoscaled into what looks like a signal; pushes
and sensor faults are shaded and named (the force and its direction, the fault's kind).

Drawn for speed, the figure looking the same as with matplotlib's defaults: no pyplot (no
figure manager, no global state); the empty figure (:func:`new_figure`) is built before the
data exists, with its tick objects made, so that a worker can build it while the runs
are simulated; margins are fixed (:func:`_place`) instead
of matplotlib's tight layout, which measures every text of the figure in an extra pass
(0.1-0.2 s here), and are checked after drawing (:func:`_clipped`): only if a tick label
would be cut off is the tight layout used after all. Titles and x labels are placed at fixed
offsets, which saves matplotlib comparing each panel's ticks with its shared-axis siblings'.
"""
from __future__ import annotations

import math
import textwrap

import numpy as np

# the torque panels' line styles, said in their titles (the legend then names only the runs: with
# four styles per run it held 8–12 entries and covered the curves)
TORQUE_STYLES = {"l": "-", "r": "--"}  # delivered: left solid, right dashed
COMMANDED = dict(ls="none", marker=".", ms=1.6, alpha=0.6)  # commanded: dots
TORQUE_TITLE = "torque per wheel [N·m]: delivered left ─, right ╌; commanded ·; saturated ×"
# (key, title) of each panel, row by row; a title ending in ":" is completed by the data
LAYOUT = (
    (("theta", "θ [rad]"), ("zoom_theta", "zoom:"), ("error", "estimator error θ̂ − θ [rad]")),
    (("torque", TORQUE_TITLE), ("zoom_torque", "zoom:"),
     ("psi_dot", "dψ/dt [rad/s]")),
    (("distance", "distance p = rψ [m]"), ("alpha", "heading α [rad]"), ("path", "path seen from above (x, y) [m]")),
    (("difference", "difference to the first run:"), ("signals_1", "controller's signals:"),
     ("signals_2", "controller's signals:")),
)
KEYS = tuple(key for row in LAYOUT for key, _ in row)
PANELS = tuple(title for row in LAYOUT for _, title in row)
TIME_KEYS = ("theta", "error", "torque", "psi_dot", "distance", "alpha", "difference", "signals_1", "signals_2")
ZOOM_KEYS = ("zoom_theta", "zoom_torque")
# the smallest span (in the panel's unit) an axis is scaled to: a signal that moves less is
# numerical noise at the figure's resolution (1e-3 rad of heading is 0.06°; the encoders
# resolve about 2e-3 rad of it). The difference panel's floor is relative (DIFFERENCE_FLOOR).
FLOORS = {"theta": 1e-3, "zoom_theta": 1e-3, "error": 1e-4, "torque": 1e-3, "zoom_torque": 1e-3,
          "psi_dot": 1e-2, "distance": 1e-3, "alpha": 1e-3, "path": 1e-2}
UNIT_FLOORS = {"rad": 1e-3, "rad/s": 1e-2, "m": 1e-3, "m/s": 1e-3, "N·m": 1e-3, "N": 1e-2}
DIFFERENCE_FLOOR = 1e-6  # of the compared signal's span: rounding differences stay flat
PUSH_COLOUR, FAULT_COLOUR, ZOOM_COLOUR = "tab:red", "tab:purple", "0.3"
SPAN_TEXT_KEYS = ("theta", "zoom_theta", "error")  # the panels whose shaded spans are named
SIZE = (16.5, 13.0)  # in
DPI = 110
Y_TICKS = 6  # y tick intervals at most (each label drawn costs about 0.5 ms)
TICKS_READY = 10  # tick objects made per axis in advance (matplotlib reuses them; making one costs ~1 ms)
# fixed margins (fractions of the figure): room for y tick labels of 8 characters ("−0.00025")
# at the left and between the columns; the top leaves the suptitle's lines (see _place)
LEFT, RIGHT, BOTTOM, WSPACE, HSPACE = 0.048, 0.99, 0.045, 0.2, 0.36
TITLE_LINES = 6  # the suptitle's lines at most (the rest cut): the panels keep most of the height
PNG_COMPRESSION = 1  # zlib level of the figures PIL writes (the replay's): 15 % larger than 6, 30 ms less
LEGEND = {"fontsize": 7, "framealpha": 0.8}


def new_figure():
    """(fig, axes): the empty figure, its panels (:data:`LAYOUT`, in that order) titled and
    gridded, the time panels sharing their x axis (and the two zoom panels theirs), on an Agg
    canvas at :data:`DPI`."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator
    from matplotlib.transforms import offset_copy

    # white whatever a matplotlibrc says: the halves drawn apart are put together where each is white
    fig = Figure(figsize=SIZE, dpi=DPI, facecolor="white")
    FigureCanvasAgg(fig)
    axes = list(fig.subplots(len(LAYOUT), len(LAYOUT[0])).ravel())
    keyed = dict(zip(KEYS, axes))
    for key in TIME_KEYS[1:]:
        keyed[key].sharex(keyed[TIME_KEYS[0]])
    keyed["zoom_torque"].sharex(keyed["zoom_theta"])
    for ax, key, label in zip(axes, KEYS, PANELS):
        # centred: the axis' ×10ⁿ offset sits at the top left; y=1.0: the title's place
        # fixed (over the axes' top), where matplotlib would look on every draw for tick
        # labels above the axes (there are none)
        ax.set_title(label, fontsize=9, y=1.0)
        ax.grid(alpha=0.3)
        # the x label at a fixed distance below the axes (tick labels are one line of
        # fixed height), not placed by comparing the ticks of the shared x axes
        ax.xaxis.set_label_coords(0.5, 0.0, transform=offset_copy(ax.transAxes, fig=fig, y=-19.0, units="points"))
        ax.tick_params(labelsize=8)
        ax.yaxis.set_major_locator(MaxNLocator(nbins=Y_TICKS, steps=[1, 2, 2.5, 5, 10]))
        ax.xaxis.get_major_ticks(TICKS_READY)
        ax.yaxis.get_major_ticks(TICKS_READY)
        if key in TIME_KEYS[-3:] or key == "zoom_torque":
            ax.set_xlabel("time [s]", fontsize=8)
    keyed["path"].set_xlabel("x [m]", fontsize=8)
    return fig, axes


def panels(axes) -> dict:
    """The panels of :func:`new_figure` (its ``axes``, or the Figure) by key (:data:`KEYS`)."""
    if hasattr(axes, "get_axes"):
        axes = axes.get_axes()
    return dict(zip(KEYS, axes))


def fill_figure(fig, axes, data: dict, title: str = ""):
    """Draw ``data`` (:func:`twin.outputs.report.figure_data`) into the empty figure of
    :func:`new_figure`: θ with each run's settling time marked; the zoom on the catch (or the
    first push); the estimator's error θ̂ − θ; each wheel's delivered torque with its
    commanded torque and the saturated samples marked; dψ/dt; p = rψ and α with their targets;
    the path from above; each run's difference to the first; the controller's own signals
    (the cascade's u, θ_off and u_α, a plugin's ``signals``) grouped by unit. Pushes and
    sensor-fault windows shaded on every time panel and named on the top row, every line in
    a legend, every axis scaled to at least its floor. Returns ``fig``."""
    p = panels(axes)
    runs = data["runs"]
    zoom = data.get("zoom")
    ranges = {}  # panel key → [lo, hi] of what was drawn (for the floors)

    def plot(key, xy, **kw):
        t, y = xy
        p[key].plot(t, y, **kw)
        _extend(ranges, key, y)

    for r in runs:
        c, name = r["colour"], r["name"]
        plot("theta", r["theta"], color=c, lw=1.2, label=name)
        ts = r["settling_time"]
        if math.isfinite(ts):
            p["theta"].axvline(ts, color=c, ls=":", lw=1.0, label=f"{name} settled, {ts:.2f} s")
        if r["error"] is not None:
            plot("error", r["error"], color=c, lw=1.0, label=f"{name} ({r['sensing']})")
        for side, word in (("l", "left"), ("r", "right")):  # one legend entry per run (styles: the title)
            plot("torque", r[f"torque_{side}"], color=c, lw=1.0, ls=TORQUE_STYLES[side],
                 label=name if side == "l" else "_" + name, gid=f"{name} {word}")
            if r.get(f"cmd_{side}") is not None:
                plot("torque", r[f"cmd_{side}"], color=c, label="_" + name, gid=f"{name} {word} commanded", **COMMANDED)
            sat = r[f"saturated_{side}"]
            if sat is not None:
                p["torque"].plot(*sat, ls="none", marker="x", ms=4, color=c, label="_" + name,
                                 gid=f"{name} {word} saturated")
        plot("psi_dot", r["psi_dot"], color=c, lw=1.2, label=name)
        plot("distance", r["distance"], color=c, lw=1.2, label=name)
        plot("alpha", r["alpha"], color=c, lw=1.2, label=name)
        _draw_path(p["path"], r, ranges)
        if zoom is not None and r.get("zoom"):
            z = r["zoom"]
            plot("zoom_theta", z["theta"], color=c, lw=1.2, label=name)
            if math.isfinite(ts) and zoom[0] <= ts <= zoom[1]:
                p["zoom_theta"].axvline(ts, color=c, ls=":", lw=1.0, label=f"{name} settled, {ts:.2f} s")
            for side, word in (("l", "left"), ("r", "right")):
                plot("zoom_torque", z[f"torque_{side}"], color=c, lw=1.0, ls=TORQUE_STYLES[side],
                     label=name if side == "l" else "_" + name, gid=f"{name} {word}")
                if z.get(f"cmd_{side}") is not None:
                    plot("zoom_torque", z[f"cmd_{side}"], color=c, label="_" + name, gid=f"{name} {word} commanded",
                         **COMMANDED)
    if data["p_d"] is not None:
        p["distance"].axhline(data["p_d"], color="k", ls="--", lw=0.8, label="target p_d")
        _extend(ranges, "distance", [data["p_d"]])
    if data["alpha_d"] is not None:
        p["alpha"].axhline(data["alpha_d"], color="k", ls="--", lw=0.8, label="target α_d")
        _extend(ranges, "alpha", [data["alpha_d"]])
    _draw_path_marks(p["path"], data, ranges)
    if not p["error"].lines:
        _note(p["error"], "ideal sensing: the controllers read the truth")
    _draw_zoom_frame(p, zoom, data.get("zoom_why_not", ""))
    _draw_difference(p["difference"], runs, ranges)
    _draw_signals(p, runs, ranges)
    spans = data["spans"]
    for key in TIME_KEYS + ZOOM_KEYS:
        ax = p[key]
        if not ax.get_visible() or (key in ZOOM_KEYS and zoom is None):
            continue
        lo, hi = (zoom[0], zoom[1]) if key in ZOOM_KEYS else (-math.inf, math.inf)
        for kind, a, b, label in spans:
            if b < lo or a > hi:
                continue
            # in the legend of the θ panel only (the top row names each span)
            ax.axvspan(a, b, color=PUSH_COLOUR if kind == "push" else FAULT_COLOUR, alpha=0.15, lw=0,
                       label=kind if key == "theta" else "_" + kind)
            if key in SPAN_TEXT_KEYS:  # the span's kind, along its left edge at the top
                ax.text(max(a, lo), 0.98, " " + label, transform=ax.get_xaxis_transform(), rotation=90, ha="left",
                        va="top", fontsize=6.5, color="darkred" if kind == "push" else "indigo", clip_on=True)
    lines = "\n".join(textwrap.fill(line, 180) for line in title.splitlines()).split("\n")
    if len(lines) > TITLE_LINES:  # each line lowers the panels' top: a long title would leave them no room
        lines = lines[:TITLE_LINES - 1] + [lines[TITLE_LINES - 1][:179] + "…"]
    text = "\n".join(lines)
    fig.suptitle(text, fontsize=10)
    _place(fig, max(1, text.count("\n") + 1))  # first: the path's scales follow its panel's shape
    for key in KEYS:
        _apply_floor(p[key], key, ranges, data)
        if key not in ZOOM_KEYS:  # a zoom panel's lines are those of the panel on its left, legend and all
            _legend(p[key])
    _outer_time_labels(p)
    return fig


def _outer_time_labels(p: dict) -> None:
    """Time tick labels only under the lowest visible time panel of each column (the others
    share its axis), and under the zoom's lower panel."""
    for col in range(len(LAYOUT[0])):
        keys = [row[col][0] for row in LAYOUT]
        timed = [k for k in keys if k in TIME_KEYS and p[k].get_visible()]
        for k in timed[:-1]:
            below = keys[keys.index(k) + 1:]
            if all(b in TIME_KEYS and p[b].get_visible() for b in below[:1]):  # a time panel right below
                p[k].xaxis.set_tick_params(labelbottom=False)
        if timed and not p[timed[-1]].get_xlabel():
            p[timed[-1]].set_xlabel("time [s]", fontsize=8)
    p["zoom_theta"].xaxis.set_tick_params(labelbottom=False)


# ---- the panels' parts --------------------------------------------------------------------------
def _extend(ranges: dict, key: str, y) -> None:
    """Widen panel ``key``'s [lo, hi] by the finite values of ``y``."""
    y = np.asarray(y, dtype=float)
    y = y[np.isfinite(y)]
    if not y.size:
        return
    lo, hi = float(y.min()), float(y.max())
    if key in ranges:
        lo, hi = min(lo, ranges[key][0]), max(hi, ranges[key][1])
    ranges[key] = [lo, hi]


def _note(ax, text: str, y: float = 0.5, va: str = "center") -> None:
    """Grey text across the panel (what it shows, or why it shows nothing), on a light box
    that keeps it readable over the lines."""
    ax.text(0.5, y, text, ha="center", va=va, transform=ax.transAxes, fontsize=7.5, color="0.3",
            bbox=dict(boxstyle="round,pad=0.2", facecolor="white", edgecolor="none", alpha=0.75))


def _legend(ax) -> None:
    """One legend entry per label (spans repeat theirs), two columns above four entries."""
    if not ax.get_visible():
        return
    handles, labels = ax.get_legend_handles_labels()
    keep = {}
    for h, lab in zip(handles, labels):
        keep.setdefault(lab, h)
    if keep:
        ax.legend(keep.values(), keep.keys(), loc="best", ncol=2 if len(keep) > 4 else 1, **LEGEND)


def _draw_path(ax, r: dict, ranges: dict) -> None:
    """A run's path from above: the line, its start (o) and its end (x, or a red x where it fell)."""
    if r.get("path") is None:
        return
    x, y = r["path"]
    c = r["colour"]
    ax.plot(x, y, color=c, lw=1.2, label=r["name"])
    ax.plot(x[-1:], y[-1:], ls="none", marker="X" if r.get("fell") else "x", ms=7 if r.get("fell") else 6,
            color="tab:red" if r.get("fell") else c, label=f"{r['name']} fell here" if r.get("fell") else "_end")
    _extend(ranges, "path", x)
    _extend(ranges, "path_y", y)


def _draw_path_marks(ax, data: dict, ranges: dict) -> None:
    """The start, the position target (when the robot is to stop there) and each push, where
    it hit the robot, as an arrow along the force (its horizontal part) and its size."""
    start = data.get("start")
    if start is None:
        return
    x0, y0, a0 = start
    ax.plot([x0], [y0], ls="none", marker="o", ms=5, mfc="none", color="k", label="start")
    if data["p_d"] is not None and data["alpha_d"] is None:
        tx, ty = x0 + data["p_d"] * math.cos(a0), y0 + data["p_d"] * math.sin(a0)
        ax.plot([tx], [ty], ls="none", marker="*", ms=9, color="k", label="target p_d")
        _extend(ranges, "path", [tx])
        _extend(ranges, "path_y", [ty])
    span = max(np.ptp(ranges.get("path", [0.0, 0.0])), np.ptp(ranges.get("path_y", [0.0, 0.0])), 0.05)
    if data["p_d"] is not None and data["alpha_d"] is not None:
        # driving and turning: the target is a distance along the path and a heading, not a point;
        # the heading is drawn where each run ended, the distance said beside it
        for r in data.get("runs", ()):
            if r.get("path") is None:
                continue
            ex, ey = float(r["path"][0][-1]), float(r["path"][1][-1])
            dx, dy = 0.15 * span * math.cos(data["alpha_d"]), 0.15 * span * math.sin(data["alpha_d"])
            ax.annotate("", xy=(ex + dx, ey + dy), xytext=(ex, ey), zorder=4,
                        arrowprops=dict(arrowstyle="-|>", color="k", lw=1.4, mutation_scale=10))
            _extend(ranges, "path", [ex + dx])
            _extend(ranges, "path_y", [ey + dy])
        ax.plot([], [], color="k", lw=1.4,
                label=f"target: α_d = {data['alpha_d']:g} rad (arrow),\np_d = {data['p_d']:g} m along the path")
    for push in data.get("pushes", ()):
        fx, fy = push["force"][:2]
        norm = math.hypot(fx, fy)
        if norm == 0.0:
            continue
        # an arrow a fifth of the path's extent long, ending where the robot was
        dx, dy = 0.2 * span * fx / norm, 0.2 * span * fy / norm
        px, py = push["at"]
        ax.annotate("", xy=(px, py), xytext=(px - dx, py - dy), zorder=4,
                    arrowprops=dict(arrowstyle="-|>", color=PUSH_COLOUR, lw=1.6, mutation_scale=12))
        ax.text(px - dx, py - dy, f"{push['label']}\nat {push['t']:.2f} s", fontsize=6.5, color="darkred",
                ha="center", va="bottom" if dy <= 0 else "top")
        _extend(ranges, "path", [px - dx])
        _extend(ranges, "path_y", [py - dy])
    if any(push["force"][:2] != (0.0, 0.0) for push in data.get("pushes", ())):
        ax.plot([], [], color=PUSH_COLOUR, lw=1.2, label="push (horizontal part)")  # the arrows' legend entry


def _draw_zoom_frame(p: dict, zoom, why_not: str = "") -> None:
    """The zoom panels' window and titles; without a window, a note saying why (``why_not``)."""
    if zoom is None:
        for key in ZOOM_KEYS:
            ax = p[key]
            ax.set_title("zoom: none", fontsize=9, y=1.0)
            _note(ax, (why_not or "nothing to zoom on") + ":\nthe panels on the left show the whole run")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_xlabel("")
        return
    a, b, why = zoom
    p["zoom_theta"].set_title(f"zoom: θ [rad], {why}", fontsize=9, y=1.0)
    p["zoom_torque"].set_title(f"zoom: torque per wheel [N·m], {why}", fontsize=9, y=1.0)
    p["zoom_theta"].set_xlim(a, b)
    for key in ("theta", "torque"):  # where the zoom is, on the panels it zooms into
        p[key].axvspan(a, b, color=ZOOM_COLOUR, alpha=0.07, lw=0, label="zoomed on the right")


def _draw_difference(ax, runs: list, ranges: dict) -> None:
    """Each run's θ minus the first run's, over the time both ran, and the largest differences
    of θ, p, α and the total torque; hidden with a single run."""
    others = [r for r in runs[1:] if r.get("difference") is not None]
    if len(runs) < 2:
        ax.set_visible(False)
        return
    ax.set_title(f"difference to {runs[0]['name']}: θ − θ({runs[0]['name']}) [rad]", fontsize=9, y=1.0)
    ax.axhline(0.0, color=runs[0]["colour"], lw=0.8, label=f"{runs[0]['name']} (reference)")
    notes = []
    for r in others:
        d = r["difference"]
        ax.plot(*d["theta"], color=r["colour"], lw=1.2, label=f"{r['name']} − {runs[0]['name']}")
        _extend(ranges, "difference", d["theta"][1])
        biggest = d["largest"]
        if all(v == 0.0 for v, _ in biggest.values()):
            notes.append(f"{r['name']}: identical to {runs[0]['name']}, bit for bit (θ, p, α, torque)")
        else:
            notes.append(f"{r['name']}: largest |Δ| " + ", ".join(f"{k} {_g(v)} {u}" for k, (v, u) in biggest.items()))
    ranges["difference_span"] = max((r["difference"]["span"] for r in others), default=0.0)
    _extend(ranges, "difference", [0.0])
    if notes:
        _note(ax, "\n".join(notes), y=0.03, va="bottom")


def _g(v: float) -> str:
    return f"{v:.2g}" if v != 0.0 else "0"


def _draw_signals(p: dict, runs: list, ranges: dict) -> None:
    """The controller's logged signals, a panel per unit (the first two units; the others are
    named in a note): the cascade's u and u_α [N·m] and θ_off [rad], a plugin's own."""
    units = []
    for r in runs:
        for _, unit, _ in r.get("signals", ()):
            if unit not in units:
                units.append(unit)
    styles = ("-", "--", ":", "-.")
    for key, unit in zip(("signals_1", "signals_2"), units[:2] + [None] * (2 - len(units[:2]))):
        ax = p[key]
        if unit is None:
            ax.set_title("controller's signals", fontsize=9, y=1.0)
            _note(ax, "the controller logs no signals" if not units else "the controller's signals have one unit")
            continue
        said = [f"{_pretty(n)} = {_MEANING[n]}" for n, u, _ in runs[0].get("signals", ()) if u == unit and n in _MEANING]
        ax.set_title(f"controller's signals [{unit}]" + (": " + "; ".join(said) if said else ""), fontsize=9, y=1.0)
        for r in runs:
            names = [n for n, u, _ in r.get("signals", ()) if u == unit]
            for (name, u, xy) in r.get("signals", ()):
                if u != unit:
                    continue
                ax.plot(*xy, color=r["colour"], lw=1.1, ls=styles[names.index(name) % len(styles)],
                        label=f"{r['name']} {_pretty(name)}")
                _extend(ranges, key, xy[1])
        ranges[f"{key}_unit"] = unit
    if len(units) > 2:
        rest = [f"{_pretty(n)} [{u}]" for r in runs[:1] for n, u, _ in r.get("signals", ()) if u in units[2:]]
        _note(p["signals_2"], "not drawn (see trajectory.csv): " + ", ".join(rest), y=0.03, va="bottom")


_PRETTY = {"theta_off": "θ_off", "u_alpha": "u_α"}
# what the fuzzy cascade's signals are, said in their panel's title (a plugin's are its own)
_MEANING = {"theta_off": "tilt set by the position loop", "u": "balance torque",
            "u_alpha": "heading torque"}


def _pretty(name: str) -> str:
    return _PRETTY.get(name, name)


def _apply_floor(ax, key: str, ranges: dict, data: dict) -> None:
    """Scale the panel to at least its floor: data spanning less is drawn around its middle
    on the floor's scale, with a note saying so (a numerical-noise heading then reads flat)."""
    if not ax.get_visible() or key not in ranges:
        return
    lo, hi = ranges[key]
    if key == "difference":
        floor = DIFFERENCE_FLOOR * max(ranges.get("theta", [0.0, 0.0])[1] - ranges.get("theta", [0.0, 0.0])[0],
                                       1e-12)
    elif key in ("signals_1", "signals_2"):
        unit = ranges.get(f"{key}_unit")
        floor = UNIT_FLOORS.get(unit, 1e-9 * max(abs(lo), abs(hi), 1.0))
    else:
        floor = FLOORS.get(key, 0.0)
    if key == "path":  # one scale for x and y (a turn looks like one), from the panel's shape
        ylo, yhi = ranges.get("path_y", [lo, hi])
        box = ax.get_position()
        ratio = (box.width * fig_size(ax)[0]) / max(box.height * fig_size(ax)[1], 1e-9)  # width / height
        hx, hy = 0.55 * max(hi - lo, floor), 0.55 * max(yhi - ylo, floor)
        hx, hy = max(hx, hy * ratio), max(hy, hx / ratio)
        cx, cy = 0.5 * (lo + hi), 0.5 * (ylo + yhi)
        ax.set_xlim(cx - hx, cx + hx)
        ax.set_ylim(cy - hy, cy + hy)
        return
    if hi - lo >= floor:
        return
    if key == "difference":  # flat: its own note says how far apart the runs are
        mid = 0.5 * (lo + hi)
        ax.set_ylim(mid - 0.55 * floor, mid + 0.55 * floor)
        return
    mid = 0.5 * (lo + hi)
    ax.set_ylim(mid - 0.55 * floor, mid + 0.55 * floor)
    ax.yaxis.get_major_formatter().set_useOffset(False)
    unit = {"theta": "rad", "zoom_theta": "rad", "error": "rad", "torque": "N·m", "zoom_torque": "N·m",
            "psi_dot": "rad/s", "distance": "m", "alpha": "rad", "difference": "rad"}.get(key) or ranges.get(
        f"{key}_unit", "")
    spread = "no spread" if hi == lo else f"a spread of {hi - lo:.2g} {unit}"
    _note(ax, f"{spread}: below this axis' floor of {floor:.2g} {unit}, drawn on that scale", y=0.97, va="top")


def fig_size(ax) -> tuple[float, float]:
    """(width, height) in inches of the figure holding ``ax``."""
    return tuple(ax.get_figure().get_size_inches())


def _place(fig, n_lines: int) -> None:
    """The fixed margins, the top lowered by one line of the suptitle per line."""
    fig.set_layout_engine(None)
    fig.subplots_adjust(left=LEFT, right=RIGHT, bottom=BOTTOM, top=0.942 - 0.0125 * n_lines,
                        wspace=WSPACE, hspace=HSPACE)


def _clipped(fig) -> bool:
    """True if a y tick label (or the ×10ⁿ offset) of the drawn figure comes within 3 points of
    the figure's edge or of the panel on its left: then the fixed margins are too narrow for
    these numbers. Reads the labels as the draw left them (``Axis.get_tightbbox`` would lay
    the ticks out again: 20 ms against 2)."""
    renderer = fig.canvas.get_renderer()
    axes = [ax for ax in fig.get_axes() if ax.get_visible()]
    gap = 3.0 * fig.dpi / 72.0  # px: 3 points clear of the edge or the panel on the left
    for ax in axes:
        box = ax.bbox
        left = [o.bbox.x1 for o in axes if o is not ax and o.bbox.x1 <= box.x0 + 1.0
                and o.bbox.y0 < box.y1 and o.bbox.y1 > box.y0]
        limit = gap + max(left, default=0.0)
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


# the figure's rows in two halves, for two processes to draw side by side (:func:`show_half`,
# :func:`compose`): rows interleaved, since the lower rows (path, differences, signals) cost more
HALVES = ((0, 2), (1, 3))


def show_half(fig, half: int | None, shown: list | None = None) -> list:
    """Hide every panel but those in the rows ``HALVES[half]`` (the suptitle
    goes with half 0); ``half`` None: show again what ``shown`` (a list this returned) says.
    Returns each panel's visibility (and the suptitle's) as it was. Hidden panels are skipped
    by the draw; their limits, shared axes and data stay, so a half is drawn pixel for pixel
    as in the whole figure."""
    axes = fig.get_axes()
    title = getattr(fig, "_suptitle", None)  # matplotlib keeps the suptitle's Text here
    before = [ax.get_visible() for ax in axes] + [title.get_visible() if title is not None else False]
    if half is None:
        for ax, v in zip(axes, shown):
            ax.set_visible(v)
        if title is not None:
            title.set_visible(shown[-1])
        return before
    cols = len(LAYOUT[0])
    for i, ax in enumerate(axes):
        if i // cols not in HALVES[half]:
            ax.set_visible(False)
    if title is not None and half != 0:
        title.set_visible(False)
    return before


def compose(a, b):
    """The whole figure from two halves drawn apart (RGBA arrays of the same shape, each white
    where its hidden panels were): each row of pixels from the half that drew something in
    it. None where a row holds something of both halves (the halves' drawings touch, so the
    whole must be drawn at once)."""
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 4:
        return None
    white = np.uint32(0xFFFFFFFF)  # a white opaque pixel, as one 32-bit word
    in_a = (np.ascontiguousarray(a).view(np.uint32)[:, :, 0] != white).any(axis=1)
    in_b = (np.ascontiguousarray(b).view(np.uint32)[:, :, 0] != white).any(axis=1)
    if (in_a & in_b).any():
        return None
    whole = np.array(a)
    whole[in_b] = b[in_b]
    return whole


def write_png(path, rgba, dpi: float = DPI) -> None:
    """Write ``rgba`` (an (H, W, 4) uint8 array, a drawn canvas) as a PNG: RGB where every pixel
    is opaque (the figure's are), each row's "Up" filter (the difference to the row above:
    a figure's rows repeat each other), deflated at zlib level 1, with the resolution in dpi.

    Why not matplotlib's writer (PIL's): 0.06 s against 0.02 s for the twelve-panel figure,
    and 8 % larger; the figure is what ``twin run`` waits for last. The pixels are the
    canvas's, whatever writes them."""
    import struct
    import zlib

    rgba = np.asarray(rgba, dtype=np.uint8)
    h, w = rgba.shape[:2]
    opaque = bool((rgba[:, :, 3] == 255).all())
    px = rgba[:, :, :3] if opaque else rgba
    rows = np.ascontiguousarray(px).reshape(h, -1)  # (contiguous: the subtraction below is 2× faster)
    data = np.empty((h, rows.shape[1] + 1), np.uint8)  # each row: its filter type, then its bytes
    data[:, 0] = 2  # filter type Up
    data[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=data[1:, 1:])  # modulo 256, as PNG's Up filter is

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ppm = round(dpi / 0.0254)  # pixels per metre
    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2 if opaque else 6, 0, 0, 0))
           + chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1)) + chunk(b"IDAT", zlib.compress(data, 1))
           + chunk(b"IEND", b""))
    with open(path, "wb") as fh:
        fh.write(png)


def save_pixels(fig, rgba, path) -> None:
    """Write ``rgba`` (the canvas of ``fig``, drawn) as :func:`save_figure` writes the figure."""
    write_png(path, rgba, fig.dpi)


def save_figure(fig, path) -> None:
    """Draw ``fig`` and write it as a PNG at its own resolution (:func:`new_figure`'s
    :data:`DPI`; :func:`write_png`); with matplotlib's tight layout if the fixed margins would
    cut a tick label off (drawn again then)."""
    fig.canvas.draw()
    if fig.get_layout_engine() is None and _clipped(fig):
        n = fig.get_suptitle().count("\n") + 1
        fig.set_layout_engine("tight", rect=(0, 0, 1, 1 - 0.014 * n))  # the title's room kept
        fig.canvas.draw()
    write_png(path, np.asarray(fig.canvas.buffer_rgba()), fig.dpi)
