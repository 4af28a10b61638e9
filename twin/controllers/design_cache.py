"""On-disk cache of LMI balance designs, keyed by everything the answer depends on.

A design is a pure function of its inputs, but solving it means importing cvxpy (about
1 s) and running the SDP solver; a cached design skips both, so a ``twin run`` process
that finds its design here never imports cvxpy.

Where: ``$TWIN_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/mtwip-twin``, else
``~/.cache/mtwip-twin``; one file ``lmi-<key>.json`` per design.

Key: SHA-256 of a canonical JSON of what the design's numbers depend on, and nothing else:
the robot parameters, the design options (ε, ρ, decay rate, gain bound, requested solver,
damping ratio, the robust design's parameter box, whether every vertex closed loop is
certified), this file's format number and a hash of the design code's source (lmi.py,
lmi_regions.py, lmi_center.py, ts_model.py, params.py): change any of them and the old
entries are simply never looked up again. Not the versions of cvxpy, Clarabel, SCS, numpy
or Python, nor the machine: the design is the program's unique central point computed in
exact decimal arithmetic (:mod:`twin.controllers.lmi_center`), so they do not change its
numbers; a solver only says where the search for it starts. (Should that point not be
found, a rare numerical limit, the solver's own answer is used and cached, with a note; it
is then this machine's answer.)

Every float is stored as ``float.hex`` so that a cached design equals a fresh one bit for
bit. An entry is used only if it parses, carries the key it was looked up by and the
inputs it was made for, matches its own checksum, has arrays of the right shapes with
finite values, a positive definite P with P Q = I, and gains that still make V = xᵀPx
decrease at the design's rate on the TS model of every plant model the design certifies
(and keep its damping ratio; checked here with numpy). Anything else is
ignored with a one-line note on stderr and the design is solved again; the fresh design
then replaces the bad file. Writes go to a temporary file renamed into place, so a
reader never sees half a file.

This module imports only the standard library and numpy: it is on the path of every run.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import tempfile
from dataclasses import fields
from pathlib import Path

import numpy as np

from twin.controllers import lmi_regions
from twin.controllers.lmi import BalanceDesign, Certificate
from twin.digests import dist_version
from twin.interrupts import deferred_signals

FORMAT = 3  # bump when the file layout or what is stored changes (2: damping ratio, parameter box; 3: the
#            unique central point, keyed without package versions)
_PREFIX = "lmi-"
_SUFFIX = ".json"
_SHAPES = {"gains": (2, 4), "P": (4, 4), "Q": (4, 4)}
_enabled = True


def set_enabled(flag: bool) -> None:
    """Turn the cache on or off for this process (``--no-cache``: neither read nor written)."""
    global _enabled
    _enabled = bool(flag)


def enabled() -> bool:
    return _enabled


def cache_dir() -> Path:
    """``$TWIN_CACHE_DIR``, else ``$XDG_CACHE_HOME/mtwip-twin``, else ``~/.cache/mtwip-twin``."""
    explicit = os.environ.get("TWIN_CACHE_DIR")
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    # the XDG spec says a relative $XDG_CACHE_HOME is invalid and must be ignored
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache"
    return base / "mtwip-twin"


def clear() -> tuple[Path, int]:
    """Delete every cached design (only this cache's own files); returns (directory, count)."""
    d = cache_dir()
    n = 0
    if d.is_dir():
        for f in d.iterdir():
            # our entries and the temporary files of an interrupted write; nothing else
            if f.is_file() and f.name.startswith(_PREFIX) and (f.name.endswith(_SUFFIX) or ".tmp" in f.name):
                f.unlink(missing_ok=True)
                n += 1
    return d, n


def _note(text: str) -> None:
    print(f"note: design cache: {text}", file=sys.stderr)


# ---- the key ---------------------------------------------------------------------------------
def _hex(v) -> str | None:
    return None if v is None else float(v).hex()


_versions_memo: dict | None = None


def _versions() -> dict:
    global _versions_memo
    if _versions_memo is None:
        here = Path(__file__).resolve().parent
        code = hashlib.sha256()
        for f in (here / "lmi.py", here / "lmi_regions.py", here / "lmi_center.py",
                  here.parent / "plant" / "ts_model.py", here.parent / "params.py"):
            try:
                code.update(f.read_bytes())
            except OSError:  # pragma: no cover - source not on disk (zipped install): key on the package version
                code.update(dist_version("mtwip-twin").encode())
        _versions_memo = {"design_code_sha256": code.hexdigest()}
    return _versions_memo


def inputs_of(params, epsilon, rho, decay_rate, max_gain, solver, damping=0.0, uncertain=(),
              all_vertices=False) -> dict:
    """What the design depends on, as canonical JSON-able values (floats as hex).
    ``uncertain`` is the checked box, ((name, relative half-range), ...) in Table III order."""
    return {
        "format": FORMAT,
        "function": "twin.controllers.lmi.design_balance_gains",
        "params": {f.name: _hex(getattr(params, f.name)) for f in fields(params)},
        "options": {"epsilon": _hex(epsilon), "rho": _hex(rho), "decay_rate": _hex(decay_rate),
                    "max_gain": _hex(max_gain), "solver": solver, "damping": _hex(damping),
                    "uncertain": _box_doc(uncertain), "all_vertices": bool(all_vertices)},
        "versions": _versions(),
    }


def _box_doc(box) -> list:
    return [[name, _hex(v)] for name, v in box]


def _canonical(doc) -> bytes:
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()


def key_of(inputs: dict) -> str:
    return hashlib.sha256(_canonical(inputs)).hexdigest()


def path_of(key: str) -> Path:
    return cache_dir() / f"{_PREFIX}{key}{_SUFFIX}"


# ---- storing ---------------------------------------------------------------------------------
def _array(a) -> dict:
    a = np.asarray(a, dtype=np.float64)
    return {"shape": list(a.shape), "hex": [float(v).hex() for v in a.ravel()]}


def _design_doc(d) -> dict:
    c = d.certificate
    return {
        "gains": _array(d.gains), "P": _array(d.P), "Q": _array(d.Q),
        "epsilon": _hex(d.epsilon), "rho": _hex(d.rho), "decay_rate": _hex(d.decay_rate),
        "max_gain": _hex(d.max_gain), "peak_input": _hex(d.peak_input), "solve_time_s": _hex(d.solve_time_s),
        "solver": d.solver, "slowest_vertex_pole": _hex(d.slowest_vertex_pole),
        "damping": _hex(d.damping), "uncertain": _box_doc(d.uncertain), "all_vertices": bool(d.all_vertices),
        "unique": bool(d.unique),
        # a list, not an object: the margins' order is part of the design (it is printed)
        "certificate": {"lmi_margins": [[k, _hex(v)] for k, v in c.lmi_margins.items()],
                        "lyapunov_margin": _hex(c.lyapunov_margin), "epsilon_margin": _hex(c.epsilon_margin),
                        "rho_margin": _hex(c.rho_margin), "passed": bool(c.passed),
                        "region_margin": _hex(c.region_margin), "models": c.models,
                        "sampled_margin": _hex(c.sampled_margin), "sampled_plants": c.sampled_plants},
    }


def store(key: str, inputs: dict, design) -> None:
    """Write ``design`` under ``key`` atomically; a failure to write is a note, not an error
    (the design in hand is good either way)."""
    body = _design_doc(design)
    doc = {"format": FORMAT, "key": key, "inputs": inputs, "design": body,
           "checksum": hashlib.sha256(_canonical(body)).hexdigest()}
    target = path_of(key)
    tmp = None
    # signals held while it writes (a few ms), delivered after: an interrupt between mkstemp and its
    # name's being kept, or in the clean-up below, left a temporary file in the store
    with deferred_signals():
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f"{_PREFIX}{key[:16]}.", suffix=".tmp", dir=target.parent)
            with os.fdopen(fd, "wb") as f:
                f.write(json.dumps(doc, indent=1, sort_keys=True).encode())
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, target)  # atomic: readers see the old file or the whole new one
            tmp = None
        except OSError as exc:
            _note(f"could not write {target} ({exc.strerror or exc}); the design is used but not cached")
        finally:
            if tmp is not None:
                try:
                    os.unlink(tmp)
                except OSError:
                    pass


# ---- loading ---------------------------------------------------------------------------------
class _Bad(Exception):
    """Why an entry is not used (one line)."""


def _float(v, what: str, finite: bool = True) -> float:
    if not isinstance(v, str):
        raise _Bad(f"{what} is not a hex float")
    try:
        x = float.fromhex(v)
    except (ValueError, OverflowError):
        raise _Bad(f"{what} is not a hex float") from None
    if finite and not math.isfinite(x):
        raise _Bad(f"{what} is not finite")
    return x


def _count(v, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise _Bad(f"{what} is not a count")
    return v


def _load_array(doc, name: str) -> np.ndarray:
    item = doc.get(name)
    if not isinstance(item, dict) or not isinstance(item.get("hex"), list):
        raise _Bad(f"{name} is missing")
    if item.get("shape") != list(_SHAPES[name]) or len(item["hex"]) != math.prod(_SHAPES[name]):
        raise _Bad(f"{name} has shape {item.get('shape')}, expected {list(_SHAPES[name])}")
    return np.array([_float(v, name) for v in item["hex"]], dtype=np.float64).reshape(_SHAPES[name])


def _parse(raw: bytes, key: str, inputs: dict, params):
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        raise _Bad("not valid JSON (truncated or garbled)") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise _Bad("not a design-cache entry of this format")
    if doc.get("key") != key or doc.get("inputs") != inputs:
        raise _Bad("made for other inputs (stale or misplaced)")
    body = doc.get("design")
    if not isinstance(body, dict) or doc.get("checksum") != hashlib.sha256(_canonical(body)).hexdigest():
        raise _Bad("checksum mismatch (corrupted)")
    try:
        gains, P, Q = (_load_array(body, n) for n in ("gains", "P", "Q"))
        opts = inputs["options"]
        for name in ("epsilon", "rho", "decay_rate", "max_gain", "damping", "uncertain", "all_vertices"):
            if body.get(name) != opts[name]:
                raise _Bad(f"{name} differs from the request")
        c = body["certificate"]
        margins = c["lmi_margins"]
        if not isinstance(margins, list) or not margins or not all(
                isinstance(m, list) and len(m) == 2 and isinstance(m[0], str) for m in margins):
            raise _Bad("certificate margins are malformed")
        cert = Certificate(
            lmi_margins={k: _float(v, f"margin {k}") for k, v in margins},
            lyapunov_margin=_float(c["lyapunov_margin"], "lyapunov margin"),
            epsilon_margin=_float(c["epsilon_margin"], "epsilon margin"),
            rho_margin=_float(c["rho_margin"], "rho margin"),
            passed=c["passed"] is True,
            region_margin=None if c["region_margin"] is None else _float(c["region_margin"], "region margin"),
            models=_count(c["models"], "models"),
            sampled_margin=None if c["sampled_margin"] is None else _float(c["sampled_margin"], "sampled margin"),
            sampled_plants=_count(c["sampled_plants"], "sampled plants"),
        )
        solver = body["solver"]
        if solver not in ("CLARABEL", "SCS"):
            raise _Bad(f"unknown solver {solver!r}")
        design = BalanceDesign(
            gains=gains, P=P, Q=Q,
            epsilon=_float(body["epsilon"], "epsilon"), rho=_float(body["rho"], "rho"),
            decay_rate=_float(body["decay_rate"], "decay_rate"),
            max_gain=None if body["max_gain"] is None else _float(body["max_gain"], "max_gain"),
            peak_input=_float(body["peak_input"], "peak_input"),
            solve_time_s=_float(body["solve_time_s"], "solve_time_s"),
            solver=solver, certificate=cert, params=params,
            slowest_vertex_pole=_float(body["slowest_vertex_pole"], "slowest_vertex_pole"),
            damping=_float(body["damping"], "damping"),
            uncertain=tuple((name, _float(v, f"range of {name}")) for name, v in body["uncertain"]),
            all_vertices=body["all_vertices"] is True,
            unique=body["unique"] is True,
            from_cache=True,
        )
    except (KeyError, TypeError, AttributeError):
        raise _Bad("a field is missing or of the wrong type") from None
    _check_design(design)
    return design


def _check_design(d) -> None:
    """What the design claims, re-checked from its own numbers: a checksum only proves the
    file is as written, not that what was written is a working design."""
    if not d.certificate.passed or d.certificate.lyapunov_margin <= 0 or min(d.certificate.lmi_margins.values()) <= 0:
        raise _Bad("its certificate did not pass")
    if not (d.peak_input <= d.rho) or not (d.slowest_vertex_pole < 0):
        raise _Bad("its peak input or poles contradict the design")
    if not np.array_equal(d.P, d.P.T):  # the design symmetrises P exactly
        raise _Bad("P is not symmetric")
    if np.linalg.eigvalsh(d.P).min() <= 0:
        raise _Bad("P is not positive definite")
    if np.abs(d.P @ d.Q - np.eye(4)).max() > 1e-6:
        raise _Bad("P and Q are not inverses")
    if d.certificate.models != 1 + (2 ** len(d.uncertain) if d.uncertain else 0) or (
            (d.damping > 0) != (d.certificate.region_margin is not None)):
        raise _Bad("its certificate does not cover the plant models and region it was made for")
    # V = xᵀPx must fall at rate 2a for every weight mix, on every certified plant model
    # (and, with a damping ratio, every frozen mix keep its eigenvalues in the sector)
    models = lmi_regions.models_of(lmi_regions.box_params(d.params, d.uncertain))
    Acl = lmi_regions.closed_loops(models, d.gains, np.linspace(0.0, 1.0, 11), d.all_vertices)
    lyap, sector = lmi_regions.frozen_margins(Acl, d.P, d.decay_rate, d.damping)
    if not lyap > 0:
        raise _Bad("its gains do not make V = xᵀPx decrease at the design's rate")
    if sector is not None and not sector > 0:
        raise _Bad("its gains do not keep the closed-loop poles in the design's sector")


def load(key: str, inputs: dict, params):
    """The cached design for ``key``, or None (absent, or unusable: then a one-line note)."""
    path = path_of(key)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as exc:
        _note(f"ignored {path} (unreadable: {exc.strerror or exc}); solving the design again")
        return None
    try:
        return _parse(raw, key, inputs, params)
    except _Bad as exc:
        _note(f"ignored {path} ({exc}); solving the design again")
        return None
