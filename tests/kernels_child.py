"""One child process of tests/test_across_kernels.py: under the BLAS kernel and numpy SIMD
targets its environment selects, with an empty design cache, solve the designs, run the
refactor-hash cases (every built-in acceptance scenario with it2, t1 and lqr, and three
variants), and record or check golden trajectories;
print one JSON object of digests on the last line of stdout.

Usage: python tests/kernels_child.py OUT_DIR GOLDEN_DIR (record|check)
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
CONTROLLERS = ("it2", "lqr")  # of the golden check


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def metrics_bytes(path: Path) -> bytes:
    """metrics.json without its environment fingerprint (which names the kernel by design),
    serialised as twin.outputs.report.write_json does."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    doc.pop("environment", None)
    return (json.dumps(doc, indent=2, ensure_ascii=False) + "\n").encode("utf-8")


def outputs(directory: Path) -> dict:
    return {"trajectory.csv": sha((directory / "trajectory.csv").read_bytes()),
            "metrics.json": sha(metrics_bytes(directory / "metrics.json"))}


def main() -> None:
    out, golden, mode = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
    from twin.outputs import fingerprint
    from twin.controllers.designs import balance_design
    from twin.controllers.lmi import NOMINAL_DESIGN, design_balance_gains
    from twin.controllers.lqr import LQRController
    from twin.params import NOMINAL
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    env = fingerprint.environment()
    result = {"kernel": env["blas"].get("kernel"), "numpy_simd": env["numpy_simd"]["dispatched"],
              "libm": env["libm"],
              "build": "".join("c" if v else "p" for v in env["kernels"].values())}
    default = balance_design(cache=True, hold=False)
    result["designs"] = {"default": default.digest(), "default_unique": default.unique,
                         "nominal": balance_design(**NOMINAL_DESIGN, cache=True, hold=False).digest(),
                         # a region and a box with the paper's relaxation (slack variables)
                         "relaxed_region_box": design_balance_gains(decay_rate=2.5, damping=0.4, all_vertices=False,
                                                                    uncertain={"l": 0.1, "m_b": 0.1}).digest(),
                         "lqr": LQRController(NOMINAL).design_digest()}
    cases = json.loads((HERE / "data" / "refactor_hashes.json").read_text(encoding="utf-8"))["cases"]
    hashes = {}
    for case, spec in sorted(cases.items()):
        d = out / "refactor" / case
        run_scenario(load_scenario(spec["scenario"], spec["set"]), tuple(spec["controllers"]), out=d, video=False)
        hashes[case] = outputs(d)
    result["refactor"] = hashes
    from twin.cli import main as twin_main

    args = ["check", "paper-exp1", "--controller", ",".join(CONTROLLERS),
            "--record" if mode == "record" else "--golden", str(golden)]
    import contextlib
    import io

    text = io.StringIO()
    with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        try:
            twin_main(args)
            code = 0
        except SystemExit as exc:
            code = exc.code
    result["golden_" + mode] = code
    result["golden_output"] = text.getvalue()[-4000:]
    print(json.dumps(result, sort_keys=True))


if __name__ == "__main__":
    main()
