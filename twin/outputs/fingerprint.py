"""The environment a result came from, and a digest of each controller design it used.

Recorded beside every result (``metrics.json``, golden files, ``sweep.json``, the JUnit
file) so that a user who sees two results differ can tell a changed environment from a
changed controller. :func:`environment` is what this process runs on; :func:`differences`
names, one short phrase each, what two recorded environments disagree on.

What is recorded, and why each item can change a result:

* ``project``: this package's version and, when it runs from a git checkout, the commit;
* ``python``, ``platform``, ``machine`` (the architecture: x86_64, aarch64, ...);
* ``packages``: numpy, scipy, pybullet, cvxpy, clarabel, scs (installed versions);
* ``blas``: numpy's BLAS library, its version, the kernel it selected for this CPU
  (OpenBLAS picks one at load time, e.g. Haswell or SkylakeX; ``OPENBLAS_CORETYPE``
  overrides it) and its thread count; read with threadpoolctl;
* ``numpy_simd``: the SIMD targets numpy dispatches its own loops to on this CPU (its
  baseline and the enabled ones of AVX2/AVX-512/...; ``NPY_DISABLE_CPU_FEATURES`` narrows them);
* ``kernels``: which of the optional compiled kernels run (the fuzzy engine, the EKF, the
  physics fast path); the compiled and pure-Python paths agree to ~1e-12, not bit for bit;
* ``libm``: the C library and, on x86-64 with glibc, which code paths its maths functions
  run (``x86_paths``: "fma" on CPUs with AVX2 and FMA, "fma4" on AMD's that have FMA4 only,
  "sse2" elsewhere): PyBullet's physics calls them every step, and the paths differ in last
  bits (see :func:`libm`);
* ``designs`` (added by the caller): a digest of each design used, from
  :func:`design_digest`.

Nothing here is a timing, and nothing changes from one run to the next on one machine, so
a result file stays byte-identical when the same scenario runs again in the same place.

This module imports only the standard library at import time (numpy and threadpoolctl when
:func:`environment` is first called).
"""
from __future__ import annotations

import os
import platform
import sys
from pathlib import Path

import twin
from estimation import ekf_core
# exact digests and versions, named here as before
from twin.digests import design_digest, dist_version  # noqa: F401
from twin.fuzzy import mamdani
from twin.plant import bullet

PACKAGES = ("numpy", "scipy", "pybullet", "cvxpy", "clarabel", "scs")
_memo: dict | None = None



def _commit() -> str | None:
    """The git commit of the checkout this package runs from (None if it is not one, e.g.
    an installed wheel), read from .git without running git."""
    root = Path(__file__).resolve().parents[2]
    git = root / ".git"
    try:
        if git.is_file():  # a worktree: "gitdir: <path>"
            text = git.read_text(encoding="utf-8").strip()
            if not text.startswith("gitdir:"):
                return None
            git = (root / text[len("gitdir:"):].strip()).resolve()
        head = (git / "HEAD").read_text(encoding="utf-8").strip()
        if not head.startswith("ref:"):
            return head if len(head) == 40 else None
        ref = head[len("ref:"):].strip()
        common = git
        if (git / "commondir").is_file():
            common = (git / (git / "commondir").read_text(encoding="utf-8").strip()).resolve()
        for base in (git, common):
            f = base / ref
            if f.is_file():
                return f.read_text(encoding="utf-8").strip()
        packed = common / "packed-refs"
        if packed.is_file():
            for line in packed.read_text(encoding="utf-8").splitlines():
                parts = line.split()
                if len(parts) == 2 and parts[1] == ref:
                    return parts[0]
    except OSError:
        return None
    return None


def _blas() -> dict:
    """numpy's BLAS: library, version, the kernel selected for this CPU, threads."""
    import numpy as np  # noqa: F401 (loads the library threadpoolctl looks for)

    try:
        from threadpoolctl import threadpool_info
    except ImportError:  # pragma: no cover - a dependency; say so rather than fail
        return {"library": "unknown (threadpoolctl is not installed)"}
    numpy_dir = Path(np.__file__).resolve().parent
    libs = [i for i in threadpool_info() if i.get("user_api") == "blas"]
    # numpy's own copy: in numpy.libs (wheels) or linked from numpy's directory
    own = [i for i in libs if "numpy" in Path(i.get("filepath", "")).parent.name
           or Path(i.get("filepath", "")).resolve().parent == numpy_dir]
    pick = (own or libs or [None])[0]
    if pick is None:
        return {"library": "none found"}
    return {"library": pick.get("internal_api"), "version": pick.get("version"),
            "kernel": pick.get("architecture"), "threads": pick.get("num_threads")}


def _numpy_simd() -> dict:
    try:
        from numpy._core._multiarray_umath import __cpu_baseline__, __cpu_dispatch__, __cpu_features__
    except ImportError:  # pragma: no cover - numpy < 2
        from numpy.core._multiarray_umath import __cpu_baseline__, __cpu_dispatch__, __cpu_features__
    return {"baseline": list(__cpu_baseline__),
            "dispatched": [k for k in __cpu_dispatch__ if __cpu_features__.get(k)]}


def kernels() -> dict:
    """Which optional compiled kernels run in this process ({name: True/False})."""
    return {"fuzzy": mamdani.compiled_kernel_loaded(), "ekf": ekf_core.compiled_kernel_loaded(),
            "physics": bullet.compiled_kernel_loaded()}


def environment() -> dict:
    """This process's environment (see the module docstring); computed once, then a copy."""
    global _memo
    if _memo is None:
        _memo = {
            "project": {"name": "mtwip-twin", "version": twin.__version__, "commit": _commit()},
            "python": platform.python_version(),
            "implementation": platform.python_implementation(),
            "platform": f"{platform.system()}-{platform.release()}",
            "machine": platform.machine(),
            "packages": {name: dist_version(name) for name in PACKAGES},
            "blas": _blas(),
            "numpy_simd": _numpy_simd(),
            "kernels": kernels(),
            "libm": libm(),
        }
    return _copy(_memo)


def _cpu_flags() -> set:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def libm() -> dict:
    """The C library whose maths functions (sin, cos, exp, pow, ...) the physics engine and the
    twin call, and, on x86-64 with glibc, which of its code paths this CPU gets: glibc picks
    FMA versions on CPUs with AVX2 and FMA (x86-64-v3 and later), FMA4 versions on AMD CPUs
    that have only FMA4, and SSE2 versions elsewhere, and they differ in the last bit for a fraction of the arguments (sin: about 1 in 1200),
    which is enough for a twin run to part within seconds. ``GLIBC_TUNABLES`` can mask the
    features (glibc.cpu.hwcaps=-AVX2,-FMA), as a virtual machine that hides them does."""
    lib, version = platform.libc_ver()
    out = {"library": f"{lib} {version}".strip() or "unknown"}
    if platform.machine() in ("x86_64", "AMD64") and lib == "glibc":
        flags = _cpu_flags()
        masked = set()
        for tunable in os.environ.get("GLIBC_TUNABLES", "").split(":"):  # name=value:name=value
            name, _, value = tunable.partition("=")
            if name.strip() == "glibc.cpu.hwcaps":
                masked |= {v.strip()[1:].upper() for v in value.split(",") if v.strip().startswith("-")}
        if {"fma", "avx2"} <= flags and not ({"FMA", "AVX2"} & masked):
            out["x86_paths"] = "fma"
        elif "fma4" in flags and "FMA4" not in masked:  # AMD's 2011–2014 CPUs have a third path
            out["x86_paths"] = "fma4"
        else:
            out["x86_paths"] = "sse2"
    return out


def _copy(doc):
    if isinstance(doc, dict):
        return {k: _copy(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_copy(v) for v in doc]
    return doc



def digests(balance=None, controllers=()) -> dict:
    """The ``designs`` of a result: ``balance``, the LMI balance design's digest (pass the design
    only if the run used it), then each (kind, controller) whose controller has a callable
    ``design_digest()``, under its kind."""
    out = {}
    if balance is not None and callable(getattr(balance, "digest", None)):
        out["balance"] = str(balance.digest())
    for kind, controller in controllers:
        own = getattr(controller, "design_digest", None)
        if callable(own):
            out[kind] = str(own())
    return out


def record(designs: dict | None = None) -> dict:
    """What a result file records under "environment": :func:`environment` and its ``designs``
    (name → digest, from :func:`digests`).

    Without the BLAS thread count: it is a setting of the process, not of the machine (the
    ``twin`` command sets one thread, a Python session keeps OpenBLAS's default), it does not
    change the twin's numbers (its matrices are too small for OpenBLAS to split), and with it
    the same run written from the command line and from Python would differ."""
    env = environment()
    env["blas"].pop("threads", None)
    return {**env, "designs": dict(designs or {})}


# The items whose difference can change a result's numbers, and how a difference is named.
_WHAT = (
    (("machine",), "architecture"),
    (("blas", "kernel"), "BLAS kernel"),
    (("blas", "library"), "BLAS library"),
    (("blas", "version"), "BLAS version"),
    (("numpy_simd", "dispatched"), "numpy SIMD targets"),
    (("kernels",), "compiled kernels"),
    (("libm", "library"), "C library"),
    (("libm", "x86_paths"), "libm code paths"),
    (("python",), "Python"),
    (("platform",), "platform"),
    (("project", "version"), "mtwip-twin version"),
    (("project", "commit"), "commit"),
) + tuple((("packages", p), p) for p in PACKAGES)


def _get(doc, path):
    for k in path:
        if not isinstance(doc, dict) or k not in doc:
            return None
        doc = doc[k]
    return doc


def differences(run: dict | None, reference: dict | None) -> list[str]:
    """What two recorded environments disagree on, one phrase each ("BLAS kernel SkylakeX,
    the reference's Haswell"); the designs are compared too. [] if they agree (or a side
    recorded nothing: then one phrase says so)."""
    if not run or not reference:
        return ["the reference records no environment" if not reference else "this run records no environment"]
    out = []
    for path, label in _WHAT:
        a, b = _get(run, path), _get(reference, path)
        if a != b:
            out.append(f"{label} {_short(a)}, the reference's {_short(b)}")
    da, db = run.get("designs") or {}, reference.get("designs") or {}
    for name in sorted(set(da) | set(db)):
        if da.get(name) != db.get(name):
            out.append(f"design {name} {_short(da.get(name))}, the reference's {_short(db.get(name))}")
    return out


def _short(v) -> str:
    if v is None:
        return "(not recorded)"
    if isinstance(v, dict):
        return ", ".join(f"{k} {'on' if x is True else 'off' if x is False else x}" for k, x in v.items())
    if isinstance(v, list):
        return "+".join(map(str, v)) or "(none)"
    s = str(v)
    return s[:12] if len(s) == 64 or len(s) == 40 else s  # digests and commits, shortened


__all__ = ["PACKAGES", "design_digest", "differences", "digests", "dist_version", "environment", "kernels", "record"]
