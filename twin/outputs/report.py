"""Figures, trajectories and metrics files for runs (matplotlib imported lazily)."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

# FAULT_COLOUR and PUSH_COLOUR are named here too, where they always were
from twin.outputs.figure import FAULT_COLOUR, PUSH_COLOUR, fill_figure, new_figure, save_figure  # noqa: F401
from twin.outputs.rundir import deferred_signals
from twin.registry import label as kind_label
from twin.sensors.faults import fault_windows
from twin.sim.runs import Run

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray",
            "tab:olive", "tab:cyan")  # matplotlib's tab10, in the order the runs are given


def load_matplotlib(pyplot: bool = False) -> None:
    """Import what the figures are drawn with (the Agg canvas, Figure; ``pyplot``: pyplot on
    Agg), SIGINT and SIGTERM held meanwhile (:func:`twin.outputs.rundir.deferred_signals`,
    delivered as the imports end; 0.3-0.5 s, once). matplotlib's extension modules are C++
    (pybind11), which turns an exception raised while one loads (an interrupt, from a Python
    import it makes) into ``ImportError: initialization failed``, the module left half made: a
    command interrupted there ended with that error (exit status 1, its manifest saying "error
    during the figure"), or crashed as the interpreter ended (abort, -6)."""
    import sys

    wanted = ("matplotlib.pyplot",) if pyplot else ("matplotlib.backends.backend_agg", "matplotlib.figure")
    if all(name in sys.modules for name in wanted):
        return

    with deferred_signals():
        import matplotlib

        if pyplot:
            matplotlib.use("Agg")
            import matplotlib.pyplot  # noqa: F401
        else:
            import matplotlib.backends.backend_agg  # noqa: F401
            import matplotlib.figure  # noqa: F401
            import matplotlib.ticker  # noqa: F401
            import matplotlib.transforms  # noqa: F401


def _pyplot():
    load_matplotlib(pyplot=True)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_runs(runs: list, path: Path, title: str = "") -> Path:
    """The figure of a scenario's runs (:func:`figure_runs`), written to ``path`` (PNG)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(figure_runs(runs, title), path)
    return path


def figure_runs(runs: list, title: str = ""):
    """The paper's Figs. 6–8 quantities with runs overlaid, and what explains them: θ with
    each run's settling time marked, and a zoom on the catch from a tilted start (or on the
    first push); the estimator's error θ̂ − θ (what the controllers were given minus the
    truth); each wheel's delivered torque against its commanded torque, with the samples
    where the motor driver saturated marked; dψ/dt; the distance p = rψ and the heading α
    with their targets; the path seen from above; each run's difference to the first; the
    controller's own signals (the cascade's u, θ_off, u_α; a plugin's). Pushes (their force
    and direction) and sensor-fault windows (their kind) are shaded and named, an axis whose
    data spans less than its floor is drawn on the floor's scale, and every line is in a
    legend. A matplotlib Figure, drawn by :mod:`twin.outputs.figure` from :func:`figure_data`
    (:func:`twin.outputs.figure.panels` gives its panels by key).

    ``runs``: :class:`~twin.sim.runs.Run` (from the twin or the analytic model)."""
    load_matplotlib()
    fig, axes = new_figure()
    return fill_figure(fig, axes, figure_data(runs), title)


ZOOM_THETA0 = 0.1  # rad: a start tilted this far or more is a catch worth a zoom
ZOOM_MIN_S = 1.5  # s: the shortest zoom window


def figure_data(runs: list) -> dict:
    """What :func:`figure_runs` draws, as plain data (floats, strings, NumPy arrays; picklable
    without the twin's classes, for :mod:`twin.outputs.figure_worker`): per run its name, colour,
    settling time (s, NaN if never settled), sensing, whether it fell, and (t, y) pairs
    thinned by :func:`_envelope` for θ, θ̂ − θ (None under ideal sensing), each wheel's
    delivered torque and its saturated samples (None if none), each wheel's commanded torque
    (``cmd_l``, ``cmd_r``), dψ/dt, p and α; its path (x, y) in m; its ``signals``, the
    controller's logged signals as (name, unit, (t, y)); for every run after the first its
    ``difference`` to the first (:func:`_difference`); and, with a zoom window, the same
    signals over the window at full rate (``zoom``). Then the experiment's targets p_d, α_d
    (None if it has none), the shaded spans (:func:`_shaded_spans`), the zoom window
    (:func:`zoom_window`: (start s, end s, why) or None, and ``zoom_why_not`` the reason
    for None), the first run's ``pushes`` (their time, force, where they hit and a label)
    and its ``start`` (x m, y m, α rad)."""
    out = []
    first = runs[0]
    pushes = push_windows(first)
    zoom = zoom_window(runs, pushes)
    for i, r in enumerate(runs):
        name = kind_label(r.controller) or r.controller or f"run {i + 1}"
        d = {"name": name, "colour": _COLOURS[i % len(_COLOURS)], "settling_time": float(r.settling_time()),
             "sensing": r.sensing, "fell": bool(r.fell), "theta": _envelope(r.t, r.signal("theta")), "error": None,
             "psi_dot": _envelope(r.t, r.signal("psi_dot")), "distance": _envelope(r.t, r.distance),
             "alpha": _envelope(r.t, r.signal("alpha")), "path": _thinned(r.signal("x"), r.signal("y"))}
        if r.estimates is not None and r.sensing != "ideal":
            d["error"] = _envelope(r.t, r.signal("theta_est") - r.signal("theta"))
        for side in ("l", "r"):
            tq = r.signal(f"torque_{side}")
            d[f"torque_{side}"] = _envelope(r.t, tq)
            d[f"cmd_{side}"] = _envelope(r.t, r.signal(f"u{side}_cmd")) if f"u{side}_cmd" in r.command_names else None
            sat = r.signal(f"saturated_{side}") > 0.5
            d[f"saturated_{side}"] = (r.t[sat], tq[sat]) if sat.any() else None
        units = dict(zip(r.command_names, r.command_units))
        d["signals"] = [(n, units.get(n, "1"), _envelope(r.t, r.signal(n))) for n in r.command_names
                        if n not in ("ul_cmd", "ur_cmd")]
        if i > 0:
            d["difference"] = _difference(first, r)
        if zoom is not None:
            d["zoom"] = _zoomed(r, zoom)
        out.append(d)
    exp = first.experiment
    start = tuple(float(first.signal(k)[0]) for k in ("x", "y", "alpha"))
    why_not = ""
    if zoom is None:
        why_not = ("the run is short enough to read whole" if pushes or abs(float(first.signal("theta")[0])) >= ZOOM_THETA0
                   else "no catch from a tilted start and no push")
    return {"runs": out, "p_d": None if exp is None else exp.p_d, "alpha_d": None if exp is None else exp.alpha_d,
            "spans": _shaded_spans(runs, pushes), "zoom": zoom, "zoom_why_not": why_not, "pushes": pushes,
            "start": start}


def _thinned(x, y, points: int = 4000):
    """A path (x, y) with at most about ``points`` points, evenly picked (the last kept)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if len(x) <= 2 * points:
        return x, y
    keep = np.unique(np.linspace(0, len(x) - 1, points).round().astype(int))
    return x[keep], y[keep]


def _difference(ref: Run, run: Run) -> dict:
    """``run`` against ``ref`` over the time both ran: θ − θ_ref (t, Δθ) thinned, the span of
    θ_ref (rad, the scale the difference is judged on) and ``largest``, the largest |Δ| of θ
    (rad), p (m), α (rad) and the total torque (N·m) as (value, unit). Logs on the same time
    grid are subtracted row by row; others are interpolated onto ``ref``'s."""
    n = min(len(ref.t), len(run.t))
    same = np.array_equal(ref.t[:n], run.t[:n])
    t = ref.t[:n] if same else ref.t[ref.t <= run.t[-1]]

    def delta(a, b):
        return b[:n] - a[:n] if same else np.interp(t, run.t, b) - a[:len(t)]

    dth = delta(ref.signal("theta"), run.signal("theta"))
    largest = {}
    for key, sig, unit in (("θ", ref.signal("theta"), "rad"), ("p", ref.distance, "m"),
                           ("α", ref.signal("alpha"), "rad"), ("τ_l + τ_r", ref.total_torque, "N·m")):
        other = {"θ": run.signal("theta"), "p": run.distance, "α": run.signal("alpha"),
                 "τ_l + τ_r": run.total_torque}[key]
        dd = delta(sig, other)
        largest[key] = (float(np.max(np.abs(dd))) if dd.size else 0.0, unit)
    theta = ref.signal("theta")
    return {"theta": _envelope(t, dth), "largest": largest, "span": float(np.ptp(theta)) if theta.size else 0.0}


def zoom_window(runs: list, pushes: list):
    """(start s, end s, why) the zoom panels show, or None: the catch from a start tilted by
    :data:`ZOOM_THETA0` or more (until 3 times the last moment, in the first half of the
    run, that any run's |θ| exceeded a fifth of its start; at least :data:`ZOOM_MIN_S`),
    else the first push (from 0.25 s before it); None if the window would cover more than a
    third of the run (the whole run is then as readable)."""
    r = runs[0]
    t0, t_end = float(r.t[0]), max(float(x.t[-1]) for x in runs)
    theta0 = float(r.signal("theta")[0])
    if abs(theta0) >= ZOOM_THETA0:
        last = 0.0
        for x in runs:
            th = np.abs(x.signal("theta"))
            early = x.t <= t0 + 0.5 * (t_end - t0)
            over = np.flatnonzero(early & (th > 0.2 * abs(theta0)))
            if over.size:
                last = max(last, float(x.t[over[-1]]) - t0)
        width = math.ceil(max(ZOOM_MIN_S, 3.0 * last) * 2.0) / 2.0  # s, to half a second
        window = (t0, t0 + width, f"the catch from θ0 = {theta0:.2f} rad")
    elif pushes:
        p = pushes[0]
        window = (max(t0, p["t"] - 0.25), p["t"] - 0.25 + max(ZOOM_MIN_S, 2.0),
                  f"push of {p['label']} at {p['t']:.2f} s")
    else:
        return None
    if window[1] - window[0] > (t_end - t0) / 3.0:
        return None
    return window


def _zoomed(r: Run, zoom) -> dict:
    """θ and the torques (delivered and commanded) of ``r`` inside the zoom window, at full rate."""
    a, b, _ = zoom
    i0, i1 = np.searchsorted(r.t, a, side="left"), np.searchsorted(r.t, b, side="right")
    i0, i1 = max(0, i0 - 1), min(len(r.t), i1 + 1)  # a sample beyond each edge: the lines reach the frame
    t = r.t[i0:i1]
    out = {"theta": (t, r.signal("theta")[i0:i1])}
    for side in ("l", "r"):
        out[f"torque_{side}"] = (t, r.signal(f"torque_{side}")[i0:i1])
        name = f"u{side}_cmd"
        out[f"cmd_{side}"] = (t, r.signal(name)[i0:i1]) if name in r.command_names else None
    return out


_DIRECTIONS = (("forward", "backward"), ("to the left", "to the right"), ("up", "down"))


def push_windows(run: Run) -> list:
    """The pushes on ``run``: per stretch of rows with a push force, its start ``t`` (s), its
    end ``end`` (s), the largest ``force`` (fx, fy, fz) N in the world frame, where it hit
    (``at``: the robot's (x, y) m then) and a ``label``: its size and direction in the robot's
    frame at the time, e.g. "12 N forward"."""
    if not len(run.t):
        return []
    force = np.abs(run.push).sum(axis=1) > 0.0
    if not force.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate(([0], force.astype(np.int8), [0]))))
    dt = float(run.t[1] - run.t[0]) if len(run.t) > 1 else 0.0
    out = []
    for a, b in zip(edges[::2], edges[1::2]):
        rows = run.push[a:b]
        k = a + int(np.argmax(np.linalg.norm(rows, axis=1)))
        f = run.push[k]
        alpha = float(run.signal("alpha")[k])
        # the force in the robot's frame: along the heading, to its left, up
        parts = (f[0] * math.cos(alpha) + f[1] * math.sin(alpha), -f[0] * math.sin(alpha) + f[1] * math.cos(alpha),
                 f[2])
        j = int(np.argmax(np.abs(parts)))
        label = f"{float(np.linalg.norm(f)):.3g} N {_DIRECTIONS[j][0 if parts[j] >= 0 else 1]}"
        out.append({"t": float(run.t[a]), "end": float(run.t[b - 1]) + dt, "force": tuple(float(v) for v in f),
                    "at": (float(run.signal("x")[a]), float(run.signal("y")[a])), "label": label})
    return out


def _shaded_spans(runs: list, pushes: list | None = None) -> list:
    """[(kind, start, end, label)]: the pushes of the first run ("push", where a push force
    acted, labelled with its size and direction: :func:`push_windows`) and the sensor-fault windows
    of its sensors ("sensor fault", labelled with the fault's kind, e.g. "IMU dropout"; a
    latency change from its time to the end), in s."""
    spans = []
    end = max(float(r.t[-1]) for r in runs) if runs else 0.0
    for r in runs[:1]:
        for p in push_windows(r) if pushes is None else pushes:
            spans.append(("push", p["t"], p["end"], f"push {p['label']}"))
        for name, a, b in fault_windows(getattr(r.sensor_config, "faults", ())):
            spans.append(("sensor fault", a, min(b, end), name))  # a latency change lasts to the end
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


def estimator_line(metrics: dict, name: str = "", events_shown: int = 2, width: int = 100) -> str | None:
    """One line about a run's estimator for ``twin run``'s summary, from its metrics
    (:func:`twin.outputs.metrics.run_metrics`), or None without an ``estimator`` section (ideal
    sensing). ``name`` the controller's label; the first ``events_shown`` events are shown
    (each cut to ``width`` characters), the rest counted::

        estimator ekf (IT2): NEES 10.6 (12 states; one run's 95 % [4.40, 23.3]), NIS/dof 1.06; 8 gyro,
        8 accel and 3 encoder samples rejected; 8 events: t = 2.340 s: IMU sample rejected as an
        outlier (encoder NIS 953 with it); t = 2.835 s: …; 6 more in metrics.json
    """
    sec = metrics.get("estimator")
    if not isinstance(sec, dict):
        return None
    stats = sec.get("stats") or {}
    parts = []
    c = sec.get("consistency") or {}
    figures = []
    if c.get("nees_mean") is not None:
        lo, hi = c.get("nees_bounds") or (None, None)
        ref = f"; one run's 95 % [{lo:.2f}, {hi:.3g}]" if lo is not None else ""
        figures.append(f"NEES {c['nees_mean']:.3g} ({c.get('states', '?')} states{ref})")
    if c.get("nis_per_dof") is not None:
        figures.append(f"NIS/dof {c['nis_per_dof']:.3g}")
    if figures:
        parts.append(", ".join(figures))
    rejected = stats.get("rejected")
    if isinstance(rejected, dict):
        got = [f"{n} {_GROUP.get(k, k)}" for k, n in rejected.items() if isinstance(n, int) and n]
        parts.append(_and(got) + " samples rejected" if got else "nothing rejected")
    elif isinstance(stats.get("rejected_total"), int):
        n = stats["rejected_total"]
        parts.append(f"{n} measurement{'s' * (n != 1)} rejected" if n else "nothing rejected")
    counts = [(stats.get("saturated_imu_samples"), "IMU sample{s} clipped"),
              (stats.get("accel_outliers"), "accelerometer outlier{s}"),
              (sec.get("encoder_resyncs"), "encoder re-synchronisation{s}"),
              (stats.get("latency_changes"), "latency change{s}"), (stats.get("resets"), "reset{s}")]
    more = [f"{n} " + what.format(s="s" * (n != 1)) for n, what in counts if isinstance(n, int) and n]
    stuck = stats.get("encoders_stuck_s")
    if isinstance(stuck, (int, float)) and not isinstance(stuck, bool) and stuck > 0:
        more.append(f"encoders stuck {stuck:.2f} s")
    if more:
        parts.append(", ".join(more))
    if "events_total" in sec:
        n = sec["events_total"]
        shown = [f"t = {e['t_s']:.3f} s: {e['message']}" if e.get("t_s") is not None else e["message"]
                 for e in (sec.get("events") or [])[:events_shown]]
        shown = [x if len(x) <= width else x[:width - 1] + "…" for x in shown]
        text = f"{n} event{'s' * (n != 1)}" + (": " + "; ".join(shown) if shown else "")
        if n > len(shown):
            text += f"; {n - len(shown)} more in metrics.json"
        parts.append(text if n else "no events")
    who = f"estimator {sec.get('name', '?')}" + (f" ({name})" if name else "")
    return who + (": " + "; ".join(parts) if parts else "")


_GROUP = {"encoders": "encoder", "accel": "accelerometer"}  # a sensor group's name before "samples"


def _and(items: list) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


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


_COMPARISON_PANELS = (("theta", "θ [rad]"), ("torque", "total wheel torque τ_l + τ_r [N·m]"),
                      ("psi_dot", "dψ/dt [rad/s]"), ("distance", "distance p = rψ [m]"))


def plot_comparison(series: list, path: Path, title: str = "") -> Path:
    """Two results overlaid (``twin compare``): θ, the total wheel torque, dψ/dt and the
    distance over time, A solid and B dashed (drawn over A's, so identical runs show as one
    dashed line on a solid one), a colour per controller, and each controller's first
    departure as a dotted vertical line. ``series``: per controller a dict with ``name``,
    ``a`` and ``b`` (panel → (t, y), y None where not logged) and ``departs`` (s, or None)."""
    plt = _pyplot()
    fig, grid = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for ax, (key, label) in zip(grid.ravel(), _COMPARISON_PANELS):
        for i, s in enumerate(series):
            colour = _COLOURS[i % len(_COLOURS)]
            name = kind_label(s["name"]) or s["name"]
            for side, style, width in (("a", "-", 1.6), ("b", "--", 1.2)):
                t, y = s[side][key]
                if y is not None:
                    ax.plot(*_envelope(t, y), style, color=colour, lw=width, label=f"{name}, {side.upper()}")
            if s["departs"] is not None:
                ax.axvline(s["departs"], color=colour, ls=":", lw=1.0,
                           label=f"{name}: B departs at {s['departs']:.3f} s")
        ax.set_title(label, fontsize=9)
        ax.grid(True, alpha=0.3)
    for ax in grid[1]:
        ax.set_xlabel("t [s]")
    handles, labels = grid[0, 0].get_legend_handles_labels()
    # a column per controller (the legend fills columns first): A, B and its departure under each other
    rows = -(-len(labels) // max(len(series), 1))
    fig.legend(handles, labels, loc="lower center", ncol=max(len(series), 1), fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, 0.01 + 0.026 * rows, 1, 1))
    return _save(plt, fig, Path(path))
