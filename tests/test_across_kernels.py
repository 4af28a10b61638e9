"""The same scenario and seed give the same bytes under every OpenBLAS kernel this CPU runs.

numpy and scipy bundle OpenBLAS built for many CPUs (DYNAMIC_ARCH); it picks a kernel at
load time, and OPENBLAS_CORETYPE overrides the pick. Kernels round differently (FMA or not,
other blockings), which used to change the controller designs at 1e-5 and, through the
wheels' stick and slip, whole trajectories. Here one child process per kernel (Prescott,
Haswell and SkylakeX, those this CPU supports; SandyBridge and Zen too with
TWIN_ALL_BLAS_KERNELS=1: they add a minute and no code path the three do not cover), each
with an empty design cache, solves the designs, runs the refactor-hash cases (every built-in
acceptance scenario with it2, t1 and lqr, and three variants), and checks golden trajectories
recorded by the first kernel.
One more child runs the first kernel with numpy's own SIMD dispatch narrowed to its
baseline (NPY_DISABLE_CPU_FEATURES), as on an older CPU. Every child must give identical
designs, identical trajectory.csv and metrics.json (its environment fingerprint aside,
which names the kernel), the recorded refactor hashes, and golden checks that pass.

What is not the same everywhere, and is checked to be said so: glibc's maths functions
(sin, cos, exp, pow, ...) run FMA code on CPUs with AVX2 and FMA and SSE2 code elsewhere,
and PyBullet calls them every physics step. A last child masks those features
(GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA,-FMA4), as an older CPU or a virtual machine
that hides them would: its designs must still be identical (they use no libm but sqrt),
and where its runs part from the golden files the departure must name the libm paths.
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from twin.outputs import golden

HERE = Path(__file__).resolve().parent
CHILD = HERE / "kernels_child.py"
# the kernels and the CPU flags each needs (OpenBLAS's own requirements)
KERNELS = {"Prescott": set(), "SandyBridge": {"avx"}, "Haswell": {"avx2", "fma"}, "Zen": {"avx2", "fma"},
           "SkylakeX": {"avx512f", "avx512bw", "avx512dq", "avx512vl"}}
ALIASES = {"zen": "haswell"}
GUIDE_KERNELS = ("Prescott", "Haswell", "SkylakeX")  # the kernels every change is checked under


def supported_kernels() -> list[str]:
    if platform.machine() not in ("x86_64", "AMD64"):
        return []
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8")
    except OSError:
        return []
    flags = set()
    for line in text.splitlines():
        if line.startswith("flags"):
            flags = set(line.split(":", 1)[1].split())
            break
    every = os.environ.get("TWIN_ALL_BLAS_KERNELS") == "1"
    return [k for k, need in KERNELS.items() if need <= flags and (every or k in GUIDE_KERNELS)]


def _numpy_baseline_only() -> str:
    """NPY_DISABLE_CPU_FEATURES that leaves numpy its baseline (every dispatched target off)."""
    from numpy._core._multiarray_umath import __cpu_baseline__, __cpu_dispatch__

    return " ".join(k for k in __cpu_dispatch__ if k not in __cpu_baseline__)


def _child(tmp: Path, tag: str, gold: Path, mode: str, env_extra: dict) -> dict:
    env = {**os.environ, **env_extra, "TWIN_CACHE_DIR": str(tmp / f"cache-{tag}"), "MPLBACKEND": "Agg"}
    r = subprocess.run([sys.executable, str(CHILD), str(tmp / f"out-{tag}"), str(gold), mode],
                       capture_output=True, text=True, env=env, timeout=1200)
    assert r.returncode == 0, f"{tag}: {r.stderr[-3000:]}"
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(len(supported_kernels()) < 2, reason="needs an x86-64 CPU with at least two OpenBLAS kernels")
def test_every_kernel_gives_the_same_designs_trajectories_metrics_and_golden_checks(tmp_path):
    kernels = supported_kernels()
    gold = tmp_path / "golden"
    first = kernels[0]
    results = {first: _child(tmp_path, first, gold, "record", {"OPENBLAS_CORETYPE": first})}
    assert results[first]["golden_record"] == 0
    variants = {k: {"OPENBLAS_CORETYPE": k} for k in kernels[1:]}
    variants[f"{first}+numpy-baseline"] = {"OPENBLAS_CORETYPE": first,
                                           "NPY_DISABLE_CPU_FEATURES": _numpy_baseline_only()}
    from twin.outputs.fingerprint import libm

    sse2 = f"{first}+libm-sse2"
    if libm().get("x86_paths") == "fma":
        variants[sse2] = {"OPENBLAS_CORETYPE": first, "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA,-FMA4"}
    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {tag: pool.submit(_child, tmp_path, tag, gold, "check", extra) for tag, extra in variants.items()}
        results.update({tag: f.result() for tag, f in futures.items()})
    # each child ran the kernel it was asked for (OpenBLAS reports its pick; some builds run
    # Zen with the Haswell kernels)
    for tag, extra in variants.items():
        if "NPY_DISABLE_CPU_FEATURES" in extra or "GLIBC_TUNABLES" in extra:  # (may report older names: Katmai)
            continue
        asked = extra["OPENBLAS_CORETYPE"].lower()
        assert str(results[tag]["kernel"]).lower() in (asked, ALIASES.get(asked)), (tag, results[tag]["kernel"])
    assert results[f"{first}+numpy-baseline"]["numpy_simd"] == []
    ref = results[first]
    assert ref["designs"]["default_unique"] is True
    if sse2 in results:
        res = results.pop(sse2)
        assert res["libm"]["x86_paths"] == "sse2"
        assert res["designs"] == ref["designs"], "the designs differ with glibc's SSE2 maths paths"
        if res["golden_check"] != 0:
            assert "libm code paths sse2, the reference's fma" in res["golden_output"], res["golden_output"]
    for tag, res in results.items():
        assert res["designs"] == ref["designs"], f"{tag}: designs differ from {first}'s"
        assert res["refactor"] == ref["refactor"], f"{tag}: refactor-hash cases differ from {first}'s"
        if tag != first:
            assert res["golden_check"] == 0, f"{tag}: the golden trajectories recorded under {first} do not pass"
    # and they are the recorded refactor hashes (those of this build's path)
    build = golden.build()
    if build != "mixed":
        data = json.loads((HERE / "data" / "refactor_hashes.json").read_text(encoding="utf-8"))
        for case, spec in data["cases"].items():
            assert ref["refactor"][case] == spec[build], f"{case}: differs from the recorded {build} hashes"
