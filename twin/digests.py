"""Exact digests and versions: what a controller design is, bit for bit, and which version of a
distribution is installed. Small and of no domain, so the controllers (their designs'
digests) and the records of a result (:mod:`twin.outputs.fingerprint`, which names these
too) use them alike.
"""
from __future__ import annotations

import hashlib
import os
import sys


def dist_version(name: str) -> str:
    """An installed distribution's version ("absent" if it is not installed), found by its
    .dist-info directory on sys.path.

    importlib.metadata would do, but importing it costs ~30 ms (the email package) on a
    path whose point is to start fast; it remains the fallback."""
    want = name.lower().replace("-", "_")
    for entry in sys.path:
        try:
            names = os.listdir(entry or ".")
        except OSError:
            continue
        for n in names:
            if n.endswith(".dist-info"):
                dist, _, version = n[:-len(".dist-info")].partition("-")
                if dist.lower().replace("-", "_").replace(".", "_") == want and version:
                    return version
    try:
        from importlib.metadata import PackageNotFoundError, version
    except ImportError:  # pragma: no cover
        return "unknown"
    try:
        return version(name)
    except PackageNotFoundError:
        return "absent"


def design_digest(**arrays) -> str:
    """SHA-256 (hex) of named arrays of floats, by their exact bits: equal digests mean the
    designs' numbers are identical. ``design_digest(gains=G, P=P)``."""
    import numpy as np

    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.asarray(arrays[name], dtype=np.float64)
        h.update(f"{name}{list(a.shape)}:".encode())
        h.update(",".join(float(v).hex() for v in a.ravel()).encode())
        h.update(b";")
    return h.hexdigest()
