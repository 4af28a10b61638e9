"""Two results side by side (``twin compare A B``): metrics, environments and trajectories.

A result is a run directory of ``twin run`` (``metrics.json`` and ``trajectory.csv`` or
``trajectory.csv.gz``, with the ``manifest.json`` that lists them, :mod:`twin.outputs.rundir`) or a
golden trajectory of ``twin check --record`` (``.npz``). A directory without a manifest,
or whose files are not the ones it lists, is refused as incomplete (one line). A is
taken as the reference and B as the run compared with it, as in ``twin check --golden``:

* for each controller both hold: its metrics, with B − A and (B − A)/|A| where that means
  something; the first departure of each signal of B from A's, under the tolerances of
  :mod:`twin.outputs.tolerances` (none set: bit for bit, as golden trajectories on one build);
  and whether the runs end alike (rows, last time, status);
* the controllers only one side holds are named, not compared;
* what the environments and the designs differ in (:func:`twin.outputs.fingerprint.differences`).

They agree when every common controller's trajectories agree (same signals, rows and
status, every value within its tolerance). Metrics are shown, not judged: they are
computed from the trajectories (from every control step, even when the file keeps every
N-th).
"""
from __future__ import annotations

import csv
import gzip
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twin.errors import TwinError
from twin.inputs import json_loads
from twin.outputs import golden, rundir
from twin.outputs.fingerprint import differences
from twin.outputs.golden import Departure, Trajectory, ends_text, first_departures, signals_text
from twin.outputs.report import plot_comparison
from twin.outputs.tolerances import Tolerances, known_signals

_HEADER = re.compile(r"^(?P<name>.+) \[(?P<unit>[^\]]*)\]$")


@dataclass
class Result:
    """One side: where it came from (``what``: "run directory" or "golden trajectory"), its
    scenario and seed, each controller's trajectory and metrics, the environment it recorded
    (None: none) and its build ("compiled", "pure", "mixed"; None: unknown)."""

    path: Path
    what: str
    scenario: str | None
    seed: int | None
    trajectories: dict
    metrics: dict
    environment: dict | None
    build: str | None
    log_every: int = 1
    note: str | None = None  # said beside the comparison (a run directory kept from an unfinished run)


def load(path) -> Result:
    """A run directory or a golden ``.npz``; a one-line error naming the path if it is neither."""
    path = Path(path)
    if path.is_dir():
        return _load_run(path)
    if path.is_file():
        return _load_golden(path)
    raise TwinError(f"{path}: no such file or directory; give a run directory of 'twin run' or a golden .npz of "
                    "'twin check --record'")


def _load_golden(path: Path) -> Result:
    if path.suffix != ".npz":
        raise TwinError(f"{path}: neither a run directory nor a golden trajectory (.npz); give a directory of "
                        "'twin run' or a .npz of 'twin check --record'")
    traj, meta = golden.load(path)
    kind = str(meta.get("controller", "run"))
    metrics = meta.get("metrics")
    return Result(path, "golden trajectory", meta.get("scenario"), meta.get("seed"), {kind: traj},
                  {kind: metrics} if isinstance(metrics, dict) else {}, meta.get("environment"), meta.get("build"))


def _load_run(path: Path) -> Result:
    mfile = path / "metrics.json"
    if not mfile.is_file() and not (path / rundir.MANIFEST).is_file():
        raise TwinError(f"{path}: not a run directory of 'twin run' (no metrics.json)")
    # the manifest first: a directory an interrupted or failed command left is said to be one,
    # rather than read as if its files belonged together
    who = rundir.owner(path)  # a run's (a sweep's folder was read as one)
    if who is not None and who not in (*rundir.RUN_COMMANDS, "twin analytic"):
        raise TwinError(f"{path}: holds the output of {who!r}, not a run directory; twin compare reads run "
                        f"directories of 'twin run' and golden .npz files of 'twin check --record'")
    manifest = rundir.read_manifest(path, None, "run directory", "run 'twin run' again")
    if manifest.get("command") == "twin analytic":  # the command of before issue 27, which gave way to twin run
        raise TwinError(f"{path}: a directory of 'twin analytic', which gave way to 'twin run'; for one twin compare "
                        "reads, run 'twin run paper-expN --set plant.model=analytic --set plant.scale={} --set "
                        "sensors.sensing=ideal'")
    rundir.check_all_present(path, manifest)
    try:
        raw = mfile.read_bytes()
    except OSError as exc:
        raise TwinError(f"{mfile}: not readable ({exc.strerror or exc})") from None
    rundir.check_listed(path, manifest, "metrics.json", raw)
    try:
        doc = json_loads(raw.decode("utf-8"))  # nesting bounded (twin.inputs): no RecursionError
    except ValueError as exc:
        raise TwinError(f"{mfile}: not readable as JSON ({' '.join(str(exc).split())})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("runs"), dict):
        raise TwinError(f"{mfile}: not the metrics.json of 'twin run'; twin compare reads run directories of "
                        "'twin run' and golden .npz files")
    log = doc.get("log") or {}
    files = [path / n for n in ("trajectory.csv", "trajectory.csv.gz") if n in manifest["files"]]
    if not files:
        raise TwinError(f"{path}: no trajectory.csv or trajectory.csv.gz beside metrics.json")
    tfile = path / log["file"] if log.get("file") and log["file"] in manifest["files"] else files[0]
    rundir.check_listed(path, manifest, tfile.name)
    trajectories = _read_trajectories(tfile, {k: (m or {}).get("status", "ok") for k, m in doc["runs"].items()})
    missing = sorted(set(doc["runs"]) ^ set(trajectories))
    if missing:
        raise TwinError(f"{path}: metrics.json and {tfile.name} hold other controllers ({', '.join(missing)} in "
                        "only one of them); the directory mixes two runs")
    env = doc.get("environment")
    scenario = doc.get("scenario", {}).get("name") if isinstance(doc.get("scenario"), dict) else None
    note = None
    if not manifest.get("complete", True):  # the data of a run whose figure or video was cut short: complete
        note = (f"{path} holds what an unfinished 'twin run' kept ({manifest.get('stopped') or 'stopped'}; exit "
                f"status {manifest.get('exit_status')}): its metrics and trajectories are complete, "
                f"{' and '.join(manifest.get('missing') or [])} missing")
    return Result(path, "run directory", scenario, doc.get("seed"), trajectories, dict(doc["runs"]), env,
                  _build_of(env), int(log.get("every", 1)), note)


def _build_of(env) -> str | None:
    """"compiled", "pure" or "mixed" from an environment's kernels (None: not recorded)."""
    kernels = (env or {}).get("kernels")
    if not isinstance(kernels, dict) or not kernels:
        return None
    on = list(kernels.values())
    return "compiled" if all(on) else "pure" if not any(on) else "mixed"


def _read_trajectories(path: Path, status: dict) -> dict:
    """controller → :class:`Trajectory` of a trajectory.csv(.gz); a controller's columns are the
    ones its rows fill (another controller's own signals are left empty)."""
    opener = gzip.open if path.suffix == ".gz" else open
    rows: dict[str, list] = {}
    try:
        with opener(path, "rt", encoding="utf-8", newline="") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            for row in reader:
                rows.setdefault(row[0], []).append(row[1:])
    except (OSError, EOFError, UnicodeDecodeError, csv.Error) as exc:
        raise TwinError(f"{path}: not readable ({' '.join(str(exc).split()) or type(exc).__name__})") from None
    if not header or header[0] != "controller":
        raise TwinError(f"{path}: not a trajectory file of 'twin run' (its first column is not 'controller')")
    cols = [_HEADER.match(h) for h in header[1:]]
    if not all(cols):
        raise TwinError(f"{path}: a header cell is not 'name [unit]'; not a trajectory file of 'twin run'")
    names, units = [m["name"] for m in cols], [m["unit"] for m in cols]
    out = {}
    for kind, block in rows.items():
        if any(len(r) != len(names) for r in block):
            raise TwinError(f"{path}: a row of {kind} has another number of cells than the header ({len(names) + 1})")
        cells = np.array(block, dtype=str)
        empty = cells == ""
        logged = ~empty[0]  # a controller logs a signal at every row or at none
        try:
            data = np.where(empty, "nan", cells)[:, logged].astype(float)
        except ValueError as exc:
            raise TwinError(f"{path}: {kind}: a cell is not a number ({exc})") from None
        keep = [i for i in range(len(names)) if logged[i]]
        out[kind] = Trajectory(tuple(names[i] for i in keep), tuple(units[i] for i in keep), data,
                               str(status.get(kind, "ok")))
    return out


@dataclass
class ControllerComparison:
    """One controller both sides hold: its metrics (rows of (key, A, B)), B's first departure
    from A per signal, how the runs end (None: alike) and how their signals differ (None: alike)."""

    controller: str
    metrics: list
    departures: list
    ends: str | None
    signals: str | None
    rows: tuple  # (A's rows, B's rows)

    @property
    def agree(self) -> bool:
        return not self.departures and self.ends is None and self.signals is None


@dataclass
class Comparison:
    a: Result
    b: Result
    controllers: list
    only_a: list
    only_b: list
    environment: list
    same_build: bool
    tolerances: Tolerances
    notes: list = field(default_factory=list)

    @property
    def agree(self) -> bool:
        return all(c.agree for c in self.controllers)


def compare(a: Result, b: Result, tolerances: Tolerances | None = None) -> Comparison:
    """A and B side by side (see the module docstring); a one-line error if they share no controller."""
    tolerances = tolerances or Tolerances()
    common = [k for k in a.trajectories if k in b.trajectories]
    only_a = [k for k in a.trajectories if k not in b.trajectories]
    only_b = [k for k in b.trajectories if k not in a.trajectories]
    if not common:
        raise TwinError(f"A ({a.path}) holds {', '.join(only_a)}, B ({b.path}) holds {', '.join(only_b)}: no "
                        "controller in common to compare")
    logged = [n for tr in (*a.trajectories.values(), *b.trajectories.values()) for n in tr.names]
    tolerances.check_signals(known_signals(logged), "--tolerance")
    # unknown builds (files written before builds were recorded) are taken as one: bit for bit by default
    same_build = a.build is None or b.build is None or (a.build == b.build and a.build != "mixed")
    env = [_as_a_b(d) for d in differences(*_designs_compared(b.environment, a.environment, common))]
    notes, step_a, step_b = [r.note for r in (a, b) if r.note], 1, 1
    if a.log_every != b.log_every:
        lo, hi = sorted((a.log_every, b.log_every))
        kept = f"A's trajectory keeps every {_nth(a.log_every)}control step, B's every {_nth(b.log_every)}control step"
        if hi % lo == 0:  # both grids start at t = 0: the coarser one's rows are among the finer one's
            step_a, step_b = (hi // lo, 1) if a.log_every == lo else (1, hi // lo)
            notes.append(f"{kept}: compared on the rows both keep (every {_nth(hi)}control step)")
        else:
            notes.append(f"{kept}: their rows are not at the same times")
    for what, x, y in (("scenario", a.scenario, b.scenario), ("seed", a.seed, b.seed)):
        if x != y:
            notes.append(f"A's {what} is {x}, B's {y}")
    out = []
    for k in common:
        ta, tb = _every(a.trajectories[k], step_a), _every(b.trajectories[k], step_b)
        out.append(ControllerComparison(k, _metric_rows(a.metrics.get(k), b.metrics.get(k)),
                                        first_departures(tb, ta, same_build, tolerances),
                                        ends_text(ta, tb, ("A", "B")), signals_text(ta, tb, ("A", "B")),
                                        (len(ta.data), len(tb.data))))
    return Comparison(a, b, out, only_a, only_b, env, same_build, tolerances, notes)


def _designs_compared(env_b, env_a, common):
    """The two environments with the designs worth comparing: those both record, and those of
    the controllers compared (a design only one side's extra controller used is no difference)."""
    if not env_a or not env_b:
        return env_b, env_a
    da, db = env_a.get("designs") or {}, env_b.get("designs") or {}
    keep = (set(da) & set(db)) | set(common)
    return ({**env_b, "designs": {k: v for k, v in db.items() if k in keep}},
            {**env_a, "designs": {k: v for k, v in da.items() if k in keep}})


def _every(tr: Trajectory, step: int) -> Trajectory:
    return tr if step == 1 else Trajectory(tr.names, tr.units, tr.data[::step], tr.status)


def _nth(n: int) -> str:
    """"" for 1, "2nd ", "3rd ", "4th ", ...: "every {_nth(n)}control step"."""
    return "" if n == 1 else f"{n}th " if n > 3 else {2: "2nd ", 3: "3rd "}[n]


def _as_a_b(text: str) -> str:
    """fingerprint.differences' phrase with A (the reference) and B (the run) named."""
    return (text.replace(", the reference's ", ", A's ").replace("the reference records", "A records")
            .replace("this run records", "B records").replace("(not recorded)", "(none)"))


def _metric_rows(ma: dict | None, mb: dict | None) -> list:
    """(key, A's value, B's value) of every metric either side has (A's order, then B's)."""
    ma, mb = ma or {}, mb or {}
    keys = list(ma) + [k for k in mb if k not in ma]
    # (a nested section, such as the estimator's, is shown through its flat metrics: estimator_*)
    return [(k, ma.get(k), mb.get(k)) for k in keys if k not in ("controller", "seed")
            and not isinstance(ma.get(k), dict) and not isinstance(mb.get(k), dict)]


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _value(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v) if str(v) else '""'


def _difference(a, b) -> tuple[str, str]:
    """(B − A, (B − A)/|A|) as text: "" where it means nothing (text, a value missing, A = 0)."""
    if not (_number(a) and _number(b)):
        return ("" if a == b else "differs", "")
    d = b - a
    rel = f"{100 * d / abs(a):+.3g} %" if a != 0 else ""
    return (f"{d:+.3g}" if d != 0 else "0", rel if d != 0 else "")


def report(c: Comparison) -> str:
    """The comparison as text: who A and B are, the environments, and per controller the
    metrics and the first departure of each signal."""
    def side(name, r):
        bits = [r.what, f"scenario {r.scenario}" if r.scenario else None,
                f"seed {r.seed}" if r.seed is not None else None, f"controllers {', '.join(r.trajectories)}"]
        return f"{name}: {r.path} ({', '.join(b for b in bits if b)})"

    lines = [side("A", c.a), side("B", c.b)]
    lines.append("environment and designs: " + ("identical" if not c.environment else
                                                "B differs from A in: " + "; ".join(c.environment)))
    lines.append(f"trajectories compared {'on one build' if c.same_build else 'across builds'}: "
                 f"{c.tolerances.describe(c.same_build)}")
    lines += [f"note: {n}" for n in c.notes]
    for who, only in (("A", c.only_a), ("B", c.only_b)):
        if only:
            lines.append(f"only in {who}, not compared: {', '.join(only)}")
    for cc in c.controllers:
        lines.append("")
        lines.append(f"{cc.controller}: " + ("agree" if cc.agree else "DIFFER") +
                     f" ({cc.rows[0]} rows compared in A, {cc.rows[1]} in B)")
        if cc.metrics:
            rows = [("metric", "A", "B", "B − A", "(B − A)/|A|")]
            rows += [(k, _value(va), _value(vb), *_difference(va, vb)) for k, va, vb in cc.metrics]
            widths = [max(len(r[i]) for r in rows) for i in range(5)]
            for r in rows:
                lines.append("  " + "  ".join(x.rjust(w) if i else x.ljust(w)
                                              for i, (x, w) in enumerate(zip(r, widths))).rstrip())
        else:
            lines.append("  (no metrics on one side: a golden file recorded before they were stored)")
        for text in (cc.signals, cc.ends):
            if text:
                lines.append(f"  {text}")
        if cc.departures:
            rows = [("signal", "departs at t [s]", "A", "B", "B − A", "tolerance")]
            for d in cc.departures:
                rows.append((d.signal, f"{d.t:.3f}", f"{d.reference!r}", f"{d.run!r}",
                             f"{d.run - d.reference:+.3g} {d.unit}",
                             "bit for bit" if d.tolerance == 0 else f"{d.tolerance:.3g} {d.unit}"))
            widths = [max(len(r[i]) for r in rows) for i in range(6)]
            lines.append(f"  first departure of each signal ({len(cc.departures)} of "
                         f"{len(c.a.trajectories[cc.controller].names)} depart):")
            for r in rows:
                lines.append("    " + "  ".join(x.rjust(w) if i else x.ljust(w)
                                                for i, (x, w) in enumerate(zip(r, widths))).rstrip())
        elif cc.ends is None and cc.signals is None:
            lines.append("  every signal within its tolerance at every row")
    n_bad = sum(not cc.agree for cc in c.controllers)
    lines.append("")
    lines.append("A and B agree" if c.agree else
                 f"A and B differ: {n_bad} of {len(c.controllers)} controller{'s' * (len(c.controllers) > 1)} "
                 f"({', '.join(cc.controller for cc in c.controllers if not cc.agree)})")
    return "\n".join(lines)


def as_json(c: Comparison) -> dict:
    """The comparison as data (comparison.json)."""
    def dep(d: Departure) -> dict:
        return {"signal": d.signal, "unit": d.unit, "t_s": d.t, "a": d.reference, "b": d.run,
                "difference": d.run - d.reference, "tolerance": d.tolerance}

    return {
        "a": str(c.a.path), "b": str(c.b.path), "agree": c.agree, "same_build": c.same_build,
        "tolerances": c.tolerances.describe(c.same_build), "environment_differences": c.environment,
        "only_in_a": c.only_a, "only_in_b": c.only_b, "notes": c.notes,
        "controllers": {cc.controller: {
            "agree": cc.agree, "rows": list(cc.rows), "ends": cc.ends, "signals": cc.signals,
            "metrics": {k: {"a": va, "b": vb} for k, va, vb in cc.metrics},
            "departures": [dep(d) for d in cc.departures]} for cc in c.controllers},
    }


def figure(c: Comparison, path: Path) -> Path:
    """θ, the total wheel torque, dψ/dt and the distance over time, A solid and B dashed, a
    colour per controller, each one's first departure marked (a dotted vertical line)."""
    series = []
    for cc in c.controllers:
        ta, tb = c.a.trajectories[cc.controller], c.b.trajectories[cc.controller]
        series.append({"name": cc.controller, "a": _panels(ta), "b": _panels(tb),
                       "departs": min((d.t for d in cc.departures), default=None)})
    title = (f"A (solid): {c.a.path}    B (dashed): {c.b.path}\n" + ("A and B agree" if c.agree else
                                                    "A and B differ" + (" (first departure marked)"
                                                                        if any(s["departs"] is not None
                                                                               for s in series) else "")))
    return plot_comparison(series, path, title)


def _panels(tr: Trajectory) -> dict:
    """The figure's quantities of one trajectory: (t, y) per panel (None where it is not logged)."""
    t = tr.data[:, tr.names.index("t")]

    def sig(name):
        return tr.data[:, tr.names.index(name)] if name in tr.names else None

    tl, tr_ = sig("torque_l"), sig("torque_r")
    torque = tl + tr_ if tl is not None and tr_ is not None else None
    return {"theta": (t, sig("theta")), "torque": (t, torque), "psi_dot": (t, sig("psi_dot")),
            "distance": (t, sig("distance"))}


__all__ = ["Comparison", "ControllerComparison", "Result", "as_json", "compare", "figure", "load", "report"]
