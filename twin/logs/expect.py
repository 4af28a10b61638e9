"""Regression bounds on replays: an ``[expect]`` table over the metrics of estimators replayed
on a sensor log, checked by ``twin check`` and the pytest plugin like a scenario's.

Two places hold the bounds:

* the log's own ``log.toml``::

      [expect.ekf]                        # per estimator kind (quote an import path)
      theta_rmse_rad = "<= 0.005"         # rad, against the log's truth
      nis_per_dof = "<= 2"                # 1 for an honest filter; needs no truth
      rejected_total = "<= 20"

* or a file of its own beside one's tests (a log recorded on a robot stays as it was)::

      log = "logs/hallway-2026-11-20"     # the log's directory, relative to this file
      [expect.ekf]
      nis_per_dof = "<= 2"

Bounds in ``[expect]`` itself apply to every estimator named in a sub-table (an estimator is
replayed because a sub-table names it); :func:`twin.verify.check.run_log_checks` replays and
judges them. The metrics are
:data:`twin.scenarios.expectations.REPLAY_METRICS`; one that is undefined (an error without
truth, NIS from an estimator that reports none) fails its bound.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from twin.errors import TwinError, shown
from twin.inputs import read_text, toml_loads
from twin.logs.bounds import MAX_MANIFEST_BYTES
from twin.scenarios.expectations import ALL, parse_expect, REPLAY_METRICS


@dataclass(frozen=True)
class LogCheck:
    """A log with bounds: its ``name`` (the log directory's), ``source`` (the file the bounds
    are in), the log's directory, the estimator kinds to replay and the parsed bounds."""

    name: str
    source: str
    log: Path
    kinds: tuple
    bounds: dict


def is_log_target(target) -> bool:
    """A sensor log's directory, or a .toml file that names one (``log = "..."``)."""
    p = Path(target)
    if p.is_dir():
        return (p / "log.toml").is_file()
    if p.suffix == ".toml" and p.is_file():
        try:  # bounded as every file read (twin.inputs): a file it cannot read is left to the scenario reader
            return "log" in toml_loads(read_text(p, MAX_MANIFEST_BYTES, "check file"))
        except (TwinError, ValueError, OSError):  # TOMLDecodeError and TooDeep are ValueErrors
            return False
    return False


def load_log_check(target) -> LogCheck:
    """The bounds of ``target`` (see the module docstring); a one-line error without any."""
    p = Path(target)
    file = p / "log.toml" if p.is_dir() else p
    try:
        doc = toml_loads(read_text(file, MAX_MANIFEST_BYTES, "check file"))
    except FileNotFoundError:
        raise TwinError(f"{file}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise TwinError(f"{file}: not valid TOML ({' '.join(str(exc).split())})") from None
    except TwinError:
        raise
    except ValueError as exc:  # nested too deeply, an integer of 5000 digits
        raise TwinError(f"{file}: cannot be read: {exc}") from None
    if p.is_dir():
        log = p
    else:
        extra = sorted(set(doc) - {"log", "expect"})
        if extra:
            raise TwinError(f"{file}: unknown key {extra[0]!r}; a replay check holds log = \"DIR\" and [expect]")
        if not isinstance(doc["log"], str) or not doc["log"] or not doc["log"].isprintable():
            raise TwinError(f"{file}: log must be the log's directory (relative to this file), got "
                            f"{shown(doc['log'])}")
        log = (file.parent / doc["log"]).resolve() if not Path(doc["log"]).is_absolute() else Path(doc["log"])
        if not (log / "log.toml").is_file():
            raise TwinError(f"{file}: log: {log} is not a sensor log (no log.toml there)")
    table = doc.get("expect")
    if not table:
        raise TwinError(f"{file}: no [expect] table, so nothing to check; add bounds such as [expect.ekf] "
                        f"nis_per_dof = \"<= 2\" (see docs/howto/robot-logs.md)")
    bounds = parse_expect(table, f"{file}: expect", REPLAY_METRICS, "estimator")
    kinds = tuple(k for k in bounds if k != ALL)
    if not kinds:
        raise TwinError(f"{file}: expect: no [expect.KIND] table names an estimator to replay; add one, e.g. "
                        f"[expect.ekf]")
    for bad in ("seeds", "golden"):
        if bad in kinds:
            raise TwinError(f"{file}: expect.{bad}: a replay has no seeds or golden trajectory; allowed: "
                            f"[expect.KIND] for an estimator kind")
    name = log.name if p.is_dir() else file.stem
    return LogCheck(name, str(file), log, kinds, bounds)


def replay_metrics(entry: dict) -> dict:
    """The :data:`~twin.scenarios.expectations.REPLAY_METRICS` of one estimator's replay entry
    (``replay_logs``'s ``doc["logs"][path]["estimators"][kind]``); None where undefined."""
    errors, c = entry.get("errors") or {}, entry.get("consistency") or {}
    out = {k: errors.get(k) for k in REPLAY_METRICS if k.startswith(("theta_", "psi_", "alpha_"))}
    out["nis_per_dof"] = c.get("nis_per_dof")
    out["nees_mean"] = c.get("nees_mean")  # needs the log's state truth (twin logs hold it)
    out["whiteness_outside_fraction"] = c.get("whiteness_outside_fraction")
    out["rejected_total"] = entry.get("rejected_total")
    return out


__all__ = ["LogCheck", "is_log_target", "load_log_check", "replay_metrics"]
