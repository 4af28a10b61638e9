"""Re-record tests/data/refactor_hashes.json after a DELIBERATE change of behaviour.

    python tests/data/record_refactor_hashes.py "why the outputs changed"

Runs every case on the compiled path and, in a subprocess, on the pure-Python path
(TWIN_PURE_PYTHON=1), and writes the new hashes with the reason in ``history``.
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).parent
FILE = HERE / "refactor_hashes.json"
sys.path.insert(0, str(HERE.parent))
from kernels_child import metrics_bytes  # noqa: E402


def hashes() -> dict:
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    data = json.loads(FILE.read_text(encoding="utf-8"))
    out = {}
    for case, spec in sorted(data["cases"].items()):
        with tempfile.TemporaryDirectory() as tmp:
            run_scenario(load_scenario(spec["scenario"], spec["set"]), tuple(spec["controllers"]), out=Path(tmp),
                         video=False)
            out[case] = {"trajectory.csv": hashlib.sha256((Path(tmp) / "trajectory.csv").read_bytes()).hexdigest(),
                         # without its environment fingerprint (the kernel, the commit)
                         "metrics.json": hashlib.sha256(metrics_bytes(Path(tmp) / "metrics.json")).hexdigest()}
    return out


if __name__ == "__main__":
    if sys.argv[1:2] == ["--print"]:
        print(json.dumps(hashes()))
        sys.exit(0)
    if len(sys.argv) != 2:
        sys.exit("usage: record_refactor_hashes.py REASON")
    runs = {}
    for path, env in (("compiled", {}), ("pure", {"TWIN_PURE_PYTHON": "1"})):
        res = subprocess.run([sys.executable, __file__, "--print"], env={**os.environ, **env}, check=True,
                             capture_output=True, text=True)
        runs[path] = json.loads(res.stdout.strip().splitlines()[-1])
    data = json.loads(FILE.read_text(encoding="utf-8"))
    for case in data["cases"]:
        for path in ("compiled", "pure"):
            data["cases"][case][path] = runs[path][case]
    data.setdefault("history", []).append(sys.argv[1])
    data["about"] = ("SHA-256 of trajectory.csv and of metrics.json without its 'environment' member, 'twin run' "
                     "outputs of each case (its controllers); 'compiled': with the C kernels, 'pure': TWIN_PURE_PYTHON=1; "
                     "the same under every OpenBLAS kernel and numpy SIMD level (tests/test_across_kernels.py)")
    FILE.write_text(json.dumps(data, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    print(f"re-recorded {len(data['cases'])} cases on both paths")
