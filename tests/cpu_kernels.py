"""The CPU kernels a test can switch between on this machine (issue 25), as environment
variables for child processes: the OpenBLAS kernels the CPU can run (``OPENBLAS_CORETYPE``,
x86-64 Linux only, told by /proc/cpuinfo's flags) and numpy's SIMD targets narrowed step by
step down to its baseline (``NPY_DISABLE_CPU_FEATURES``). Used by tests/test_lqr.py and
tests/test_cpu_independence.py."""
from __future__ import annotations

import platform

# OpenBLAS core types and the /proc/cpuinfo flags each needs (Prescott: any x86-64)
CORETYPES = {"Prescott": (), "SandyBridge": ("avx",), "Haswell": ("avx2", "fma"), "Zen": ("avx2", "fma"),
             "SkylakeX": ("avx512f", "avx512bw", "avx512dq", "avx512vl")}


def cpu_flags() -> set | None:
    """The CPU's flags from /proc/cpuinfo; None where there is none (not Linux)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            text = f.read()
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return None


def kernel_environments() -> dict[str, dict[str, str]]:
    """{label: environment variables} of every kernel and SIMD level to try here ({} if none)."""
    try:
        from numpy._core import _multiarray_umath as mu
    except ImportError:  # numpy 1.x
        from numpy.core import _multiarray_umath as mu

    envs: dict[str, dict[str, str]] = {}
    flags = cpu_flags() if platform.machine().lower() in ("x86_64", "amd64") else None
    if flags is not None:
        for core, needs in CORETYPES.items():
            if set(needs) <= flags:
                envs[core] = {"OPENBLAS_CORETYPE": core}
    active = [f for f in mu.__cpu_dispatch__ if mu.__cpu_features__.get(f)]
    for i in range(len(active)):
        envs[f"numpy without {' '.join(active[i:])}"] = {"NPY_DISABLE_CPU_FEATURES": " ".join(active[i:])}
    if flags is not None and active:  # the oldest machine: generic BLAS kernel, numpy's baseline only
        envs["Prescott, numpy baseline"] = {"OPENBLAS_CORETYPE": "Prescott",
                                            "NPY_DISABLE_CPU_FEATURES": " ".join(active)}
    return envs
