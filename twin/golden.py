"""Golden trajectories: a run stored as a reference, and where a later run departs from it.

``twin check --record DIR`` stores every checked run (scenario, controller, seed) as
``DIR/<scenario>/<controller>/seed-<S>.npz`` (numpy's compressed archive): the time
vector, every logged signal (ground truth, estimates, commands, actuation, pushes; the
columns of ``trajectory.csv``), their names and units, the run's status, and the build
it came from (whether the compiled kernels ran). ``twin check --golden DIR`` compares a
new run with it, signal by signal, and reports the first time and signal where they part.

What is compared how, and why:

* **The same build** (the compiled kernels on both sides, or the pure-Python paths on
  both): every value **bit for bit**. The twin is deterministic (one seeded generator, one
  physics server per run, sums in a fixed order), so any difference at all is a change in
  the code, the scenario or the libraries, and the first one is reported where it appears.
* **Another build**: the compiled and pure-Python paths of the fuzzy engine, the EKF and
  the physics agree to about 1e-13, not bit for bit, and the estimates and commands differ
  by that much. Every signal is then compared with the tolerance
  ``|run − reference| ≤ ATOL + RTOL · |reference|`` (ATOL = 1e-9 in the signal's SI unit,
  RTOL = 1e-9): four orders above the paths' disagreement, far below any physical change
  (a 1 % heavier body moves θ by about 1e-4 rad within 0.1 s).
* Either way the row count and the status ("ok", "fell", "diverged") must match exactly:
  a run that falls earlier departs where the shorter one ends.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twin.errors import TwinError

ATOL = 1e-9  # in each signal's SI unit
RTOL = 1e-9
FORMAT = 1


def build() -> str:
    """"compiled" if every optional kernel runs here, "pure" if none does, "mixed" otherwise."""
    from estimation import ekf
    from twin.fuzzy import mamdani
    from twin.plant import bullet

    built = [bullet._fastpath is not None, ekf._kernel is not None, mamdani._kernel is not None]
    return "compiled" if all(built) else "pure" if not any(built) else "mixed"


def path_for(root: Path, scenario: str, controller: str, seed: int) -> Path:
    """Where the reference of (scenario, controller, seed) lives under ``root``."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", controller)
    return Path(root) / re.sub(r"[^A-Za-z0-9_.-]+", "_", scenario) / safe / f"seed-{seed}.npz"


@dataclass(frozen=True)
class Trajectory:
    """A run's logged signals: ``names`` (k,), ``units`` (k,), ``data`` (n, k), ``status``."""

    names: tuple
    units: tuple
    data: np.ndarray
    status: str

    @classmethod
    def of(cls, run) -> "Trajectory":
        names, units, data = run.columns()
        return cls(tuple(names), tuple(units), np.asarray(data, dtype=float), run.status)


def record(path: Path, traj: Trajectory, meta: dict) -> Path:
    """Store ``traj`` (with ``meta``: scenario, controller, seed, ...) at ``path``, compressed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    info = {"format": FORMAT, "build": build(), "status": traj.status, **meta}
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, data=traj.data, names=np.array(traj.names), units=np.array(traj.units),
                        meta=np.array(json.dumps(info, sort_keys=True)))
    tmp.replace(path)
    return path


def load(path: Path) -> tuple[Trajectory, dict]:
    """The reference at ``path`` and its metadata; a one-line error if it is missing or not one."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            traj = Trajectory(tuple(str(n) for n in z["names"]), tuple(str(u) for u in z["units"]),
                              np.array(z["data"], dtype=float), meta["status"])
    except FileNotFoundError:
        raise TwinError(f"{path}: no golden trajectory here; record one with 'twin check --record DIR'") from None
    except (OSError, ValueError, KeyError) as exc:
        raise TwinError(f"{path}: not a golden trajectory of 'twin check --record' ({exc})") from None
    if meta.get("format") != FORMAT:
        raise TwinError(f"{path}: golden format {meta.get('format')!r}, this version reads {FORMAT}; record it again")
    return traj, meta


@dataclass(frozen=True)
class Departure:
    """Where a run first parts from its reference: ``t`` s, ``signal`` (with ``unit``), the two
    values and the tolerance used (0: bit for bit); ``why`` for a structural difference."""

    t: float
    signal: str
    unit: str
    run: float
    reference: float
    tolerance: float
    why: str = ""

    def __str__(self) -> str:
        if self.why:
            return f"departs at t = {self.t:.3f} s: {self.why}"
        how = "bit for bit" if self.tolerance == 0 else f"tolerance {self.tolerance:.3g} {self.unit}"
        return (f"departs at t = {self.t:.3f} s in {self.signal}: {self.run!r} against the reference's "
                f"{self.reference!r} {self.unit} ({how})")


def compare(run: Trajectory, ref: Trajectory, exact: bool) -> Departure | None:
    """The first departure of ``run`` from ``ref`` (None: they agree); see the module docstring."""
    if run.names != ref.names:
        differ = sorted(set(ref.names) ^ set(run.names))
        why = (f"the logged signals differ ({', '.join(differ[:5])})" if differ else
               "the logged signals are the same but in another order")
        return Departure(0.0, "", "", 0.0, 0.0, 0.0, why)
    n = min(len(run.data), len(ref.data))
    a, b = run.data[:n], ref.data[:n]
    if exact:
        bad = ~((a == b) | (np.isnan(a) & np.isnan(b)))
        tol = np.zeros_like(b)
    else:
        tol = ATOL + RTOL * np.abs(b)
        with np.errstate(invalid="ignore"):
            # equal values (inf included) and NaN on both sides agree, as they do bit for bit
            bad = ~((a == b) | (np.isnan(a) & np.isnan(b)) | (np.abs(a - b) <= tol))
    rows = np.nonzero(bad.any(axis=1))[0]
    t_col = run.names.index("t")
    if len(rows):
        i = int(rows[0])
        j = int(np.nonzero(bad[i])[0][0])
        return Departure(float(b[i, t_col]), run.names[j], run.units[j], float(a[i, j]), float(b[i, j]),
                         float(tol[i, j]))
    if len(run.data) != len(ref.data) or run.status != ref.status:
        t = float(b[-1, t_col]) if n else 0.0
        return Departure(t, "", "", 0.0, 0.0, 0.0, f"the run ends {run.status!r} after {len(run.data)} rows, the "
                                                   f"reference {ref.status!r} after {len(ref.data)}")
    return None


__all__ = ["ATOL", "RTOL", "Departure", "Trajectory", "build", "compare", "load", "path_for", "record"]
