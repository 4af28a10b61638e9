"""A sweep directory: its manifest and the finished samples, written as they finish.

- ``sweep.json``: the manifest. What determines the samples: the complete scenario, its
  source and ``--set`` items, the root seed, the controllers, the plugins' source digests
  and the version of the sampling code; ``draws``, the draws of the report this run writes
  (samples.jsonl may hold more, from a larger run: they are kept for a later one);
  ``config_sha256``, the hash of the sample configuration (:func:`config_of`); last, the
  ``environment`` the first samples ran in, with the designs' digests
  (:func:`twin.outputs.fingerprint.record`). A rerun in another environment (another machine, BLAS
  kernel or commit) may resume the sweep, and its environment is added to ``resumed_in``:
  its samples may differ from the others' in the last digits.
- ``samples.jsonl``: one JSON line per finished sample, in finishing order, each carrying
  the ``config`` hash of the configuration that produced it, appended in one write and
  synced to disk as it finishes. An interruption (SIGKILL, a power cut) can at worst
  leave a torn last line (no newline at its end), which the next run drops: its sample
  simply runs again. Any other damage is refused in one line naming the line.

A rerun resumes only samples whose configuration is this sweep's: a ``sweep.json`` of
another configuration, a ``samples.jsonl`` without a ``sweep.json`` (copied from another
sweep), or a line of another configuration is refused in one line naming what differs.
The directory is held (:func:`twin.outputs.rundir.lock`) while the store is open, so that no other
command writes into it meanwhile.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
from pathlib import Path

from twin.errors import TwinError, shown
from twin.inputs import json_loads
from twin.outputs import rundir
from twin.outputs.fingerprint import differences

FORMAT = 2  # 1: before issue 26 (no configuration hash); read and upgraded
ENV, RESUMED = "environment", "resumed_in"  # where the samples ran: recorded, not required to match
CONFIG_KEY = "config_sha256"
LOCK_COMMAND = "twin sweep"
# Scenario keys that cannot change a stored sample: text, what other commands read ('twin
# check''s bounds, 'twin run''s video), the scenario's own default controllers (the sweep's
# are in the configuration), the wall-time and memory guards (a guard decides whether a run
# is stopped, not what it computes; raising one to rerun is not another sweep) and the seed
# (the configuration has it as root_seed).
NOT_IN_CONFIG = ("name", "description", "expect", "video", "limits", "seed")


def _differences(a, b, prefix="") -> list[str]:
    """Dotted paths at which the JSON-like trees ``a`` and ``b`` differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += _differences(a.get(k), b.get(k), f"{prefix}{k}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


def _get(tree, dotted: str):
    for k in dotted.split("."):
        tree = tree.get(k) if isinstance(tree, dict) else None
    return tree


def _stored(v, limit: int = 40) -> str:
    """A value read from the store, as JSON, for a message (:func:`twin.errors.shown`); None
    (a missing key) as "(none)"."""
    return "(none)" if v is None else shown(v, limit, as_json=True)


def _jsonable(tree):
    """Tuples → lists, as JSON will give them back."""
    return json.loads(json.dumps(tree))


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _record_problem(rec: dict, k: int, levels, kinds) -> str:
    """What is wrong with the fields the report reads from sample ``k``'s record ("" if nothing)."""
    draw, i = divmod(k, len(levels))
    if not (_is_int(rec.get("draw")) and rec["draw"] == draw):
        return f"\"draw\" is {_stored(rec.get('draw'), 20)}, not {draw}"
    if not (isinstance(rec.get("level"), (int, float)) and rec["level"] == levels[i]):
        return f"\"level\" is {_stored(rec.get('level'), 20)}, not {levels[i]!r}"
    if not _is_int(rec.get("seed")):
        return f"\"seed\" is {_stored(rec.get('seed'), 20)}, not an integer"
    if not isinstance(rec.get("values"), dict):
        return "no sampled \"values\""
    if not isinstance(rec.get("error"), str):
        return "no \"error\" text"
    runs = rec.get("runs")
    if not isinstance(runs, dict):
        return "no \"runs\""
    for kind, run in runs.items():
        if kind not in kinds:
            return f"a run of {kind!r}, not one of the sweep's controllers"
        if not (isinstance(run, dict) and isinstance(run.get("status"), str) and isinstance(run.get("success"), bool)):
            return f"the run of {kind!r} has no \"status\" and \"success\""
    errors = rec.get("errors", {})
    if not (isinstance(errors, dict) and all(isinstance(v, str) for v in errors.values())):
        return "\"errors\" is not a table of texts"
    return ""


def config_of(manifest: dict) -> dict:
    """What a stored sample depends on, from a manifest: the scenario as resolved (but
    :data:`NOT_IN_CONFIG`), the root seed, the controllers in order, the digests of the
    designs they use (a changed design is another controller), the SHA-256 of each plugin's
    module (a user's code changes without a version number) and the version of the sampling
    code. Not the number of draws (a larger --samples keeps every sample), the workers, the
    backend, the paired statistics' reference, nor the environment: the twin's own commit
    and the machine are recorded in ``environment``/``resumed_in`` and resuming across them
    is allowed, as before (the numbers agree to the last digits)."""
    scenario = manifest["scenario"]
    scenario = {k: v for k, v in scenario.items() if k not in NOT_IN_CONFIG}
    if isinstance(scenario.get("controller"), dict):
        scenario["controller"] = {k: v for k, v in scenario["controller"].items() if k != "kinds"}
    return {"scenario": scenario, "root_seed": manifest["root_seed"], "controllers": manifest["controllers"],
            "designs": (manifest.get(ENV) or {}).get("designs") or {}, "plugins": manifest.get("plugins") or {},
            "sampling": manifest.get("sampling", 1)}


def config_hash(config: dict) -> str:
    """SHA-256 (hex) of the canonical JSON of ``config`` (sorted keys, exact floats)."""
    text = json.dumps(config, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_atomically(path: Path, data: bytes) -> None:
    """``path`` replaced by ``data`` as a whole: written to a hidden file beside it, synced, renamed."""
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()
    _fsync_dir(path.parent)


def refuse_others(out: Path) -> None:
    """One line if ``out`` is another command's output, or holds what no sweep wrote: a sweep
    used to write its store and report over a run's folder (and delete its sensor logs)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise TwinError(f"{out}: exists and is not a directory; give a sweep directory")
    if not out.is_dir():
        return
    rundir.refuse_another_commands(out, LOCK_COMMAND)
    foreign = rundir.foreign_entries(out, LOCK_COMMAND)
    if foreign:
        more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        raise TwinError(f"{out}: holds {', '.join(foreign[:3])}{more}, which no sweep wrote; a sweep writes only "
                        f"into a new, empty or earlier sweep's directory: give another --out, or move them")


class SweepStore:
    """Open (create or resume) the sweep in ``out`` described by ``manifest`` (the runner's,
    without the configuration hash), holding the directory until :meth:`close`."""

    def __init__(self, out: Path, manifest: dict):
        self.out = Path(out)
        self._fd = None
        self._held = contextlib.ExitStack()
        if self.out.is_dir():  # said before the lock creates anything
            self._refuse_others()
        self._held.enter_context(rundir.lock(self.out, LOCK_COMMAND))  # refused in one line if in use
        try:
            self._refuse_others()  # again, holding it
            self._open(manifest)
        except BaseException:
            self._held.close()
            raise

    def _refuse_others(self) -> None:
        refuse_others(self.out)

    def _open(self, manifest: dict) -> None:
        self.environment_changes: list[str] = []  # what this run's environment differs in from the first samples'
        self.dropped_torn = False  # a torn last line (an interrupted write) was dropped
        manifest = _jsonable({"format": FORMAT, **manifest})
        self._config = config_of(manifest)
        self.config = config_hash(self._config)
        env = manifest.pop(ENV, None)
        manifest.pop(RESUMED, None)
        manifest[CONFIG_KEY] = self.config
        if env is not None:
            manifest[ENV] = env  # last, as before
        self.path = self.out / "samples.jsonl"
        for stale in self.out.glob(".sweep.json.partial-*"):  # a write cut short by SIGKILL: we hold the lock
            with contextlib.suppress(OSError):
                stale.unlink()
        old = self._old_manifest(manifest)
        if old is None and self.path.exists() and self.path.stat().st_size > 0:
            raise TwinError(f"{self.path} holds samples, but {self.out} has no sweep.json saying which sweep they "
                            f"belong to (copied from another sweep?), so they cannot be resumed; use another --out, "
                            f"or delete {self.path} to run every sample")
        if old is not None:
            self._resume_environment(old, manifest)
        self.manifest = manifest
        upgrade = old is not None and old.get("format") == 1
        self.records = self._read(accept_unstamped=upgrade)
        if upgrade:  # stamp the format-1 records first: cut short, the next run upgrades again
            self._rewrite_stamped()
        write_atomically(self.out / "sweep.json", (json.dumps(manifest, indent=1) + "\n").encode())
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def _resume_environment(self, old: dict, manifest: dict) -> None:
        """Keep the first samples' environment; add this one to ``resumed_in`` if it differs
        (once: each environment the sweep ran in is listed one time)."""
        if ENV not in manifest:
            return

        here, first = manifest[ENV], old.get(ENV)  # first None: a sweep begun before environments were recorded
        resumed = list(old.get(RESUMED, []))
        changed = ["the first samples' environment is not recorded"] if first is None else differences(here, first)
        if changed and all(differences(here, r) for r in resumed):
            resumed.append(here)
        manifest[ENV] = first
        if resumed:
            manifest[RESUMED] = resumed
        self.environment_changes = changed

    def _old_manifest(self, manifest: dict) -> dict | None:
        """The manifest already in the directory, checked against this sweep's ``manifest`` (None: none there)."""
        path = self.out / "sweep.json"
        if not path.exists():
            return None
        again = f"use another --out, or delete {self.out} to start over"
        try:
            old = json_loads(path.read_text(encoding="utf-8"))  # nesting bounded (twin.inputs)
        except (ValueError, UnicodeDecodeError) as exc:
            raise TwinError(f"{path}: not a sweep manifest ({' '.join(str(exc).split())[:80]}); {again}") from None
        if not isinstance(old, dict) or not all(k in old for k in ("scenario", "root_seed", "controllers")):
            raise TwinError(f"{path}: not a sweep manifest (no scenario, root_seed and controllers); {again}")
        fmt = old.get("format")
        if fmt not in (1, FORMAT):
            raise TwinError(f"{path}: a sweep manifest of format {_stored(fmt)}, which this mtwip-twin does not read "
                            f"(formats 1 and {FORMAT}); resume it with the version that began it, or {again}")
        try:
            if fmt == 1:  # before the plugins and the sampling version were recorded: take this run's
                old_config = config_of({"plugins": manifest.get("plugins"), **old})
            else:
                old_config = config_of(old)
        except (KeyError, TypeError, AttributeError):
            raise TwinError(f"{path}: not a sweep manifest (its scenario is not a table); {again}") from None
        if fmt == FORMAT and config_hash(old_config) != old.get(CONFIG_KEY):
            raise TwinError(f"{path} was changed by hand: its configuration no longer hashes to its {CONFIG_KEY}, so "
                            f"it does not say which samples are there; put it back, or {again}")
        if config_hash(old_config) != self.config:
            new_config = self._config
            diff = _differences(old_config, new_config)
            said = ", ".join(f"{d} (stored {_stored(_get(old_config, d))}, now {_stored(_get(new_config, d))})"
                             for d in diff[:3])
            raise TwinError(f"{self.out} holds a different sweep: its samples were produced with another "
                            f"configuration (differs in: {said}{', …' if len(diff) > 3 else ''}); rerun it as it "
                            f"was, or use another --out, or delete {self.out} to start over")
        return old

    def _read(self, accept_unstamped: bool = False) -> dict[int, dict]:
        """The finished samples, each line checked: a JSON object of a sample of this sweep's
        configuration. A torn last line (no newline: a write cut short) is dropped from the file."""
        if not self.path.exists():
            return {}
        raw = self.path.read_bytes()
        end = raw.rfind(b"\n") + 1
        records: dict[int, dict] = {}
        seen: dict[int, int] = {}
        levels = self.manifest["scenario"]["sweep"]["levels"]
        kinds = set(self.manifest["controllers"])
        for n, line in enumerate(raw[:end].split(b"\n")[:-1], 1):
            rec = self._check_line(n, line, levels, kinds, accept_unstamped)
            k = rec["sample"]
            if k in seen:
                raise self._damaged(n, f"sample {k} again (first on line {seen[k]})")
            seen[k] = n
            records[k] = rec
        if end < len(raw):
            with open(self.path, "r+b") as fh:
                fh.truncate(end)
                os.fsync(fh.fileno())
            self.dropped_torn = True
        return records

    def _damaged(self, n: int, what: str) -> TwinError:
        return TwinError(f"{self.path} line {n}: {what}; the file is damaged: delete that line (its sample then runs "
                         f"again), or use another --out")

    def _check_line(self, n: int, line: bytes, levels, kinds, accept_unstamped: bool) -> dict:
        try:
            rec = json_loads(line)  # nesting bounded (twin.inputs): no RecursionError
        except (ValueError, UnicodeDecodeError) as exc:
            raise self._damaged(n, f"not JSON ({' '.join(str(exc).split())[:60]})") from None
        if not isinstance(rec, dict):
            raise self._damaged(n, f"{shown(rec, 20, as_json=True)} is not a sample record (a JSON object with "
                                   f"\"sample\", \"config\", \"runs\", ...)")
        k = rec.get("sample")
        if isinstance(k, bool) or not isinstance(k, int) or k < 0:
            raise self._damaged(n, "no sample number (\"sample\": a non-negative integer)" if "sample" not in rec
                                else f"\"sample\" is {shown(k, 20, as_json=True)}, not a non-negative integer")
        stamp = rec.get("config")
        if stamp != self.config and not (stamp is None and accept_unstamped):
            if stamp is None:
                raise self._damaged(n, f"sample {k} carries no configuration hash (\"config\"), so what produced it "
                                       f"is unknown")
            raise TwinError(f"{self.path} line {n}: sample {k} was produced by another configuration "
                            f"({shown(stamp, 14, as_json=True)}, this sweep's {self.config[:12]}: appended from "
                            f"another sweep?); delete that line to run its sample again, or use another --out")
        problem = _record_problem(rec, k, levels, kinds)
        if problem:
            raise self._damaged(n, f"sample {k}: {problem}")
        return rec

    def _rewrite_stamped(self) -> None:
        """A format-1 store's lines, each given this configuration's hash, written as a whole."""
        if not self.records:
            return
        lines = []
        for rec in self.records.values():
            rec["config"] = self.config
            lines.append(json.dumps(rec, separators=(",", ":")) + "\n")
        write_atomically(self.path, "".join(lines).encode())

    def append(self, record: dict) -> None:
        """Store one finished sample durably (one write of the whole line, then fsync)."""
        if record.get("config") != self.config:  # a job of another configuration: a bug, never stored
            raise RuntimeError(f"sample {record.get('sample')} carries configuration {record.get('config')!r}, "
                               f"not this store's {self.config}")
        data = (json.dumps(record, separators=(",", ":")) + "\n").encode()
        view = memoryview(data)
        while view:
            view = view[os.write(self._fd, view):]
        os.fsync(self._fd)
        self.records[record["sample"]] = record

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        self._held.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
