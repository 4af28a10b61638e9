"""A sweep directory: its manifest and the finished samples, written as they finish.

- ``sweep.json``: the manifest, everything that determines the samples (the complete
  scenario, its source and ``--set`` items, the root seed). A rerun in the same
  directory must match it, except for the number of draws, which may grow. Last, the
  ``environment`` the first samples ran in, with the designs' digests
  (:func:`twin.fingerprint.record`); a rerun in another environment (another machine,
  BLAS kernel or commit) may resume the sweep, and its environment is added to
  ``resumed_in``: its samples may differ from the others' in the last digits.
- ``samples.jsonl``: one JSON line per finished sample, appended, flushed and synced to
  disk as each finishes, in finishing order. An interruption can at worst leave a torn
  last line, which the next run drops (its sample simply runs again).
- ``.lock``: held while a sweep writes the directory, so two sweeps cannot interleave.
"""
from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path

from twin.errors import TwinError

FORMAT = 1
ENV, RESUMED = "environment", "resumed_in"  # where the samples ran: recorded, not required to match


def _differences(a, b, prefix="") -> list[str]:
    """Dotted paths at which the JSON-like trees ``a`` and ``b`` differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += _differences(a.get(k), b.get(k), f"{prefix}{k}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


def _jsonable(tree):
    """Tuples → lists, as JSON will give them back."""
    return json.loads(json.dumps(tree))


class SweepStore:
    """Open (create or resume) the sweep in ``out`` described by ``manifest``."""

    def __init__(self, out: Path, manifest: dict):
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self._lock = open(self.out / ".lock", "w")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock.close()
            raise TwinError(f"{self.out}: another sweep is writing this directory; wait for it or use another --out")
        self.environment_changes: list[str] = []  # what this run's environment differs in from the first samples'
        manifest = _jsonable({"format": FORMAT, **manifest})
        path = self.out / "sweep.json"
        if path.exists():
            try:
                old = json.loads(path.read_text(encoding="utf-8"))
            except ValueError as exc:
                self.close()
                raise TwinError(f"{path}: not a sweep manifest ({exc}); use another --out") from None
            diff = [d for d in _differences(old, manifest)
                    if d != "draws" and d.split(".")[0] not in (ENV, RESUMED)]
            if diff:
                self.close()
                raise TwinError(f"{self.out} holds a different sweep (differs in: {', '.join(diff[:6])}"
                                f"{', …' if len(diff) > 6 else ''}); rerun it as it was, or use another --out")
            manifest["draws"] = max(manifest["draws"], old["draws"])
            self._resume_environment(old, manifest)
        path.write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
        self.manifest = manifest
        self.path = self.out / "samples.jsonl"
        self.records = self._read()
        self._fh = open(self.path, "a", encoding="utf-8")

    def _resume_environment(self, old: dict, manifest: dict) -> None:
        """Keep the first samples' environment; add this one to ``resumed_in`` if it differs
        (once: each environment the sweep ran in is listed one time)."""
        if ENV not in manifest:
            return
        from twin.fingerprint import differences

        here, first = manifest[ENV], old.get(ENV)  # first None: a sweep begun before environments were recorded
        resumed = list(old.get(RESUMED, []))
        changed = ["the first samples' environment is not recorded"] if first is None else differences(here, first)
        if changed and all(differences(here, r) for r in resumed):
            resumed.append(here)
        manifest[ENV] = first
        if resumed:
            manifest[RESUMED] = resumed
        self.environment_changes = changed

    def _read(self) -> dict[int, dict]:
        if not self.path.exists():
            return {}
        raw = self.path.read_bytes()
        records, good = {}, 0
        for line in raw.splitlines(keepends=True):
            try:
                if not line.endswith(b"\n"):
                    raise ValueError("torn line")
                rec = json.loads(line)
            except ValueError:
                break  # a torn last line from an interruption: keep what precedes it
            records[rec["sample"]] = rec
            good += len(line)
        if good < len(raw):
            rest = raw[good:].splitlines()
            if len(rest) > 1:
                raise TwinError(f"{self.path}: unreadable line {len(records) + 1} is not the last; "
                                "the file is damaged: move it away to rerun every sample")
            with open(self.path, "r+b") as fh:
                fh.truncate(good)
        return records

    def append(self, record: dict) -> None:
        """Store one finished sample durably."""
        self._fh.write(json.dumps(record, separators=(",", ":")) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.records[record["sample"]] = record

    def close(self) -> None:
        fh = getattr(self, "_fh", None)
        if fh is not None and not fh.closed:
            fh.close()
        if not self._lock.closed:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self._lock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
