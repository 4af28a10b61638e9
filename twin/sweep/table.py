"""``sweep.csv``: one row per sample and controller, the sampled values and every metric.

Rows are sorted by sample number and then controller, in the order of the sweep's
controller list (the manifest's ``controllers``), whatever order the samples finished in,
and floats are written with ``repr`` (exact round trip), so the same sweep always gives
the same file byte for byte.
"""
from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

ID_COLUMNS = ("sample", "draw", "level", "seed", "controller", "status", "success")
METRIC_COLUMNS = ("fell", "settling_time_s", "theta_rms_rad", "oscillation_peak_to_peak_rad", "final_theta_rad",
                  "final_distance_m", "final_heading_rad", "final_position_error_m", "final_heading_error_rad",
                  "iae_theta", "control_effort", "max_abs_torque_nm", "estimator_theta_rmse_rad",
                  "rejected_measurements", "duration_s", "end_reason")


def columns(value_columns) -> list[str]:
    return [*ID_COLUMNS, *value_columns, *METRIC_COLUMNS, "error"]


def record_controllers(records) -> list[str]:
    """The controllers that ran in ``records``, in first-seen order (samples in order)."""
    return list(dict.fromkeys(c for rec in sorted(records, key=lambda r: r["sample"]) for c in rec["runs"]))


def rows_of(records, value_columns, controllers: Sequence[str] | None = None) -> list[dict]:
    """Typed rows (see :func:`columns`) from stored sample records, sorted by sample, then
    controller in the order of ``controllers``.

    Every sample has a row for every controller of ``controllers``: one it has no run of
    (its worker failed) has status "error". Runs of controllers not listed are left out.
    ``controllers`` None: :func:`record_controllers` (pass the manifest's list, so that
    a sweep whose samples all failed still has its rows).
    """
    if controllers is None:
        controllers = record_controllers(records)
    elif isinstance(controllers, str):
        controllers = [controllers]
    rows = []
    for rec in sorted(records, key=lambda r: r["sample"]):
        for c in controllers:
            m = rec["runs"].get(c)
            row = {"sample": rec["sample"], "draw": rec["draw"], "level": rec["level"], "seed": rec["seed"],
                   "controller": c, "status": m["status"] if m else "error", "success": bool(m and m["success"])}
            row.update({k: rec["values"].get(k) for k in value_columns})
            row.update({k: (m or {}).get(k) for k in METRIC_COLUMNS})
            # a controller's own error (the others ran), or the whole sample's (none ran)
            row["error"] = (rec.get("errors") or {}).get(c, "" if m else rec["error"])
            rows.append(row)
    return rows


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_sweep_csv(rows, cols, path: Path) -> Path:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(cols)
        for row in rows:
            w.writerow([_cell(row.get(c)) for c in cols])
    return path


def read_sweep_csv(path: Path) -> list[dict]:
    """The rows of a ``sweep.csv``, typed back (empty cells → None)."""
    ints = {"sample", "draw", "seed", "rejected_measurements"}
    texts = {"controller", "status", "end_reason", "error"}
    out = []
    with open(path, newline="", encoding="utf-8") as fh:
        for raw in csv.DictReader(fh):
            row = {}
            for k, v in raw.items():
                if k in texts:
                    row[k] = v
                elif v == "":
                    row[k] = None
                elif v in ("true", "false"):
                    row[k] = v == "true"
                elif k in ints:
                    row[k] = int(v)
                else:
                    row[k] = float(v)
            out.append(row)
    return out

