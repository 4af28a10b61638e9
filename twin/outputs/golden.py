"""Golden trajectories: a run stored as a reference, and where a later run departs from it.

``twin check --record DIR`` stores every checked run (scenario, controller, seed) as
``DIR/<scenario>/<controller>/seed-<S>.npz`` (numpy's compressed archive): the time
vector, every logged signal (ground truth, estimates, commands, actuation, pushes; the
columns of ``trajectory.csv``), their names and units, the run's status and metrics, the
build it came from (whether the compiled kernels ran) and its environment with a digest
of each design it used (:mod:`twin.outputs.fingerprint`). ``twin check --golden DIR`` compares a
new run with it, signal by signal, and reports the first time and signal where they part,
and whether the environment or a design differs from the reference's.

A record is written as a unit (:class:`twin.outputs.rundir.FileBatch`): ``DIR/manifest.json`` lists
every reference with its size and SHA-256. :func:`load` refuses a reference that sits in a
record directory whose manifest is missing or does not list it as it is (a record that was
killed, or a file changed since); a reference copied out of its directory is read on its
own (it was written whole, by a rename, and its archive's checksums catch damage).

What is compared how, and why:

* **The same build** (the compiled kernels on both sides, or the pure-Python paths on
  both): every value **bit for bit**, unless tolerances are set (:mod:`twin.outputs.tolerances`).
  The twin is deterministic (one seeded generator, one physics server per run, sums in a
  fixed order), so any difference at all is a change in the code, the scenario, the
  libraries or the machine's arithmetic (another BLAS kernel), and the first one is
  reported where it appears, with what the environments differ in.
* **Another build**: the compiled and pure-Python paths of the fuzzy engine, the EKF and
  the physics agree to about 1e-13, not bit for bit, and the estimates and commands differ
  by that much. Every signal is then compared with the tolerance
  ``|run − reference| ≤ ATOL + RTOL · |reference|``, each at least ATOL = 1e-9 in the
  signal's SI unit and RTOL = 1e-9: four orders above the paths' disagreement, far below
  any physical change (a 1 % heavier body moves θ by about 1e-4 rad within 0.1 s).
* A run of another length or status ("ok", "fell", "diverged") is reported as such, with
  its rows, last time and status beside the reference's, and where the rows both have
  first part.
"""
from __future__ import annotations

import io
import json
import os
import re
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from twin.errors import TwinError
from twin.outputs import rundir
from twin.outputs.fingerprint import kernels
from twin.outputs.rundir import PARTIAL
from twin.outputs.tolerances import BUILD_ATOL, BUILD_RTOL, Tolerances

ATOL, RTOL = BUILD_ATOL, BUILD_RTOL  # the tolerance between builds (in each signal's SI unit; a fraction)
FORMAT = 2  # 2: the meta records the environment and the design digests (twin.outputs.fingerprint)


def build() -> str:
    """"compiled" if every optional kernel runs here, "pure" if none does, "mixed" otherwise."""
    built = list(kernels().values())
    return "compiled" if all(built) else "pure" if not any(built) else "mixed"


def _part(name: str) -> str:
    """A name as one path component: characters other than letters, digits, '_', '.' and '-'
    become '_', and a name of dots alone ('.', '..') or none is made of '_' (it would name the
    directory itself or its parent)."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name))
    return safe if safe.strip(".") else "_" * max(len(safe), 1)


def path_for(root: Path, scenario: str, controller: str, seed: int) -> Path:
    """Where the reference of (scenario, controller, seed) lives under ``root``: always inside
    it, whatever the names are."""
    return Path(root) / _part(scenario) / _part(controller) / f"seed-{int(seed)}.npz"


RECORD_AGAIN = "record it again with 'twin check --record DIR'"


def _in_record(path: Path, meta: dict) -> bool:
    """Whether ``path`` sits where a record puts the reference ``meta`` describes
    (ROOT/<scenario>/<controller>/seed-<S>.npz), so that ROOT's manifest must list it; a
    reference copied elsewhere on its own is read on its own (each is written whole, by a
    rename, and its archive's checksums catch damage)."""
    try:
        return path == path_for(path.parents[2], meta["scenario"], meta["controller"], meta["seed"])
    except (KeyError, IndexError, TypeError, ValueError):
        return False


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
    # under a hidden name, renamed when complete: the reference at ``path`` is always whole
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}{PARTIAL}", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, data=traj.data, names=np.array(traj.names), units=np.array(traj.units),
                                meta=np.array(json.dumps(info, sort_keys=True)))
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp made it private; a reference is an ordinary file
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def load(path: Path) -> tuple[Trajectory, dict]:
    """The reference at ``path`` and its metadata; a one-line error naming the file if it is
    missing, is not a golden trajectory (another file, a foreign or damaged archive), is
    of an older format, or sits in a record directory whose manifest does not list it as it
    is (the record was interrupted, or the file changed since)."""
    path = Path(path)
    if not path.is_file():
        why = "a directory, not a file" if path.is_dir() else "no golden trajectory here"
        raise TwinError(f"{path}: {why}; record one with 'twin check --record DIR'")
    not_ours = f"{path}: not a golden trajectory of 'twin check --record'"
    try:
        with open(path, "rb") as fh:
            head = fh.read(6)
    except OSError as exc:
        raise TwinError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if head.startswith(b"\x93NUMPY"):
        raise TwinError(f"{not_ours} (a single .npy array, not an .npz archive)")
    if not head.startswith(b"PK"):  # every zip archive, .npz included, starts so
        raise TwinError(f"{not_ours} (not an .npz archive, nor any zip file)")
    damaged = f"{not_ours} (a damaged or truncated .npz archive"
    try:
        # from memory: np.load(path) leaves its file open when the archive is damaged
        # (a ResourceWarning later), and a reference is small (~0.5 MB for 15 s)
        raw = path.read_bytes()
        z = np.load(io.BytesIO(raw), allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 -- whatever numpy makes of a broken archive, it is one line here
        raise TwinError(f"{damaged}: {_one_line(exc)})") from None
    try:
        with z:
            missing = [k for k in ("meta", "names", "units", "data") if k not in z.files]
            if missing:
                raise TwinError(f"{not_ours} (an .npz archive without {', '.join(missing)})")
            meta = json.loads(str(z["meta"]))
            names, units = tuple(str(n) for n in z["names"]), tuple(str(u) for u in z["units"])
            data = np.array(z["data"], dtype=float)
    except TwinError:
        raise
    except Exception as exc:  # noqa: BLE001 -- zipfile, zlib, json and numpy's errors on a damaged member
        if "allow_pickle" in str(exc):
            raise TwinError(f"{not_ours} (it holds Python objects, which are not read)") from None
        raise TwinError(f"{damaged}: {_one_line(exc)})") from None
    if not isinstance(meta, dict):
        raise TwinError(f"{not_ours} (its meta is not a JSON object)")
    if meta.get("format") != FORMAT:
        raise TwinError(f"{path}: golden format {meta.get('format')!r} (an older mtwip-twin's), this version reads "
                        f"format {FORMAT}; record it again with 'twin check --record DIR'")
    if data.ndim != 2 or data.shape[1] != len(names) or len(units) != len(names) or "t" not in names:
        raise TwinError(f"{not_ours} (data of shape {data.shape} for {len(names)} signals)")
    if "status" not in meta:
        raise TwinError(f"{not_ours} (its meta has no status)")
    if _in_record(path, meta):
        root = path.parents[2]
        rundir.finish_batch(root)  # a record killed while it committed: carried through first
        doc = rundir.read_manifest(root, (rundir.RECORD_COMMAND,), "golden directory", RECORD_AGAIN)
        rundir.check_listed(root, doc, path.relative_to(root).as_posix(), raw)
    return Trajectory(names, units, data, str(meta["status"])), meta


def _one_line(exc: BaseException) -> str:
    name = type(exc).__name__
    name = f"{type(exc).__module__} error" if name == "error" else name  # zlib.error, say
    return " ".join(f"{name}: {exc}".split())


@dataclass(frozen=True)
class Departure:
    """Where a run first parts from its reference: ``t`` s, ``signal`` (with ``unit``), the two
    values and the tolerance there (``atol + rtol·|reference|``; 0: bit for bit); ``why`` for a
    structural difference (other signals, another length or status), with or without a value
    departure over the rows both have; ``environment``: what the run's environment and
    designs differ in from the reference's (() none, None not compared)."""

    t: float
    signal: str
    unit: str
    run: float
    reference: float
    tolerance: float
    why: str = ""
    environment: tuple | None = None

    def value_text(self) -> str:
        how = "bit for bit" if self.tolerance == 0 else f"tolerance {self.tolerance:.3g} {self.unit}"
        return (f"departs at t = {self.t:.3f} s in {self.signal}: {self.run!r} against the reference's "
                f"{self.reference!r} {self.unit} (difference {self.run - self.reference:.3g} {self.unit}, {how})")

    def __str__(self) -> str:
        if self.why:
            text = self.why + (f"; over the rows both have it {self.value_text()}" if self.signal else "")
        else:
            text = self.value_text()
        if self.environment is not None:
            text += "; " + environment_text(self.environment)
        return text


def environment_text(differences) -> str:
    """What a run's environment and designs differ in from its reference's, for a departure."""
    if not differences:
        return "environment and designs identical to the reference's (so the code or the scenario changed)"
    return "differs from the reference in: " + "; ".join(differences)


def common_rows(a: Trajectory, b: Trajectory) -> int:
    """The rows two trajectories' values can be compared on: those both have, less the shorter
    one's last row when their lengths differ (nothing is applied after a run's last row: it
    repeats the period before it, so there it differs from a longer run's by construction)."""
    n = min(len(a.data), len(b.data))
    return n - 1 if len(a.data) != len(b.data) and n else n


def first_departures(run: Trajectory, ref: Trajectory, same_build: bool = True,
                     tolerances: Tolerances | None = None) -> list[Departure]:
    """Each signal's first departure of ``run`` from ``ref`` over their :func:`common_rows`, in
    the order of time (then of the signals); signals only one of them logs are left out."""
    tolerances = tolerances or Tolerances()
    names = [n for n in ref.names if n in run.names]
    n = common_rows(run, ref)
    a = run.data[:n, [run.names.index(k) for k in names]]
    b = ref.data[:n, [ref.names.index(k) for k in names]]
    atol, rtol = tolerances.arrays(names, same_build)
    with np.errstate(invalid="ignore"):  # 0 · inf: an infinite reference agrees only with itself
        tol = atol + rtol * np.abs(b)
        # equal values (inf included) and NaN on both sides agree
        bad = ~((a == b) | (np.isnan(a) & np.isnan(b)) | (np.abs(a - b) <= tol))
    t = b[:, names.index("t")] if "t" in names else np.arange(n, dtype=float)
    out = []
    for j in np.nonzero(bad.any(axis=0))[0]:
        i = int(np.argmax(bad[:, j]))
        out.append(Departure(float(t[i]), names[j], ref.units[ref.names.index(names[j])], float(a[i, j]),
                             float(b[i, j]), float(tol[i, j])))
    out.sort(key=lambda d: (d.t, names.index(d.signal)))
    return out


def ends_text(a: Trajectory, b: Trajectory, names=("the run", "the reference")) -> str | None:
    """How two trajectories end, if they end otherwise (rows, last time, status); None if alike."""
    if len(a.data) == len(b.data) and a.status == b.status:
        return None

    def end(tr):
        return float(tr.data[-1, tr.names.index("t")]) if len(tr.data) else 0.0

    return (f"{names[0]} has {len(a.data)} rows (ends at t = {end(a):.3f} s, status {a.status}), "
            f"{names[1]} {len(b.data)} rows (t = {end(b):.3f} s, status {b.status})")


def signals_text(a: Trajectory, b: Trajectory, names=("the run", "the reference")) -> str | None:
    """How two trajectories' logged signals differ, if they do; None if alike."""
    if a.names == b.names:
        return None
    only_a, only_b = [n for n in a.names if n not in b.names], [n for n in b.names if n not in a.names]
    if not only_a and not only_b:
        return "the logged signals are the same but in another order"
    return "the logged signals differ (" + "; ".join(
        f"only {who} logs {', '.join(only)}" for who, only in zip(names, (only_a, only_b)) if only) + ")"


def compare(run: Trajectory, ref: Trajectory, same_build: bool = True,
            tolerances: Tolerances | None = None) -> Departure | None:
    """The first departure of ``run`` from ``ref`` (None: they agree); see the module docstring.
    ``same_build``: both from the same build (compiled kernels, or pure-Python paths, on both
    sides); ``tolerances``: per signal (none set: bit for bit on one build)."""
    structural = signals_text(run, ref)
    if structural is not None:
        return Departure(0.0, "", "", 0.0, 0.0, 0.0, structural)
    found = first_departures(run, ref, same_build, tolerances)
    first = found[0] if found else None
    ends = ends_text(run, ref)
    if ends is not None:  # another length or status: said first, as it is the larger difference
        if first is not None:
            return replace(first, why=ends)
        how = (tolerances or Tolerances()).describe(same_build)
        return Departure(0.0, "", "", 0.0, 0.0, 0.0, f"{ends}; the rows both have agree ({how})")
    return first


__all__ = ["ATOL", "RTOL", "Departure", "Trajectory", "build", "common_rows", "compare", "ends_text", "environment_text",
           "first_departures", "load", "path_for", "record", "signals_text"]
