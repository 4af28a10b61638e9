"""Twenty seeded "true robots" for ``twin calibrate``: each a Table III plant with m_b, l and n_yb
scaled within ±30 %, d_b and d_w within ×0.5–×2 (log-uniform), and a gyro turn-on bias of
its own, logged by the twin (``twin run paper-exp3 --log-sensors``, noisy sensors, the EKF in
the loop, a 12 N push at 8 s). Used by tests/test_calibrate_acceptance.py and
benchmarks/bench_calibrate.py.

    python benchmarks/calibration_plants.py OUT_DIR [COUNT]

writes OUT_DIR/plant-K/ (the run, with sensor-logs/it2) and OUT_DIR/plants.json (the truth).
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT_SEED = 30  # the generator's seed: the same twenty robots on every machine
PUSH = "pushes=[{force=[12,0,0], start=8, duration=0.1}]"


def draw(count: int = 20, seed: int = ROOT_SEED) -> list[dict]:
    """The plants: ``scale`` (factors of Table III), ``gyro_turn_on_bias`` (rad/s, the σ the
    twin draws the run's gyro bias with) and the run's ``seed``."""
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    out = []
    for k in range(count):
        scale = {n: float(rng.uniform(0.7, 1.3)) for n in ("m_b", "l", "n_yb")}
        scale.update({n: float(math.exp(rng.uniform(math.log(0.5), math.log(2.0)))) for n in ("d_b", "d_w")})
        out.append({"plant": k, "scale": scale, "gyro_turn_on_bias": float(rng.uniform(0.005, 0.03)),
                    "seed": int(rng.integers(0, 2**31))})
    return out


def command(plant: dict, out: Path, held_out: bool = False) -> list[str]:
    """``twin run`` logging ``plant``; ``held_out``: another run of the same robot for validation
    (another seed, so other noise and another gyro bias, and no push)."""
    sets = ([] if held_out else [PUSH]) + [f"sensors.gyro.turn_on_bias={plant['gyro_turn_on_bias']!r}"]
    sets += [f"plant.scale.{n}={v!r}" for n, v in plant["scale"].items()]
    cmd = [sys.executable, "-m", "twin.cli", "run", "paper-exp3", "--controller", "it2", "--no-video", "--log-sensors",
           "--seed", str(plant["seed"] + (1 if held_out else 0)), "--out", str(out)]
    for s in sets:
        cmd += ["--set", s]
    return cmd


def generate(out_dir, count: int = 20) -> list[dict]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plants = draw(count)
    for p in plants:
        run = out_dir / f"plant-{p['plant']}"
        subprocess.run(command(p, run), check=True, stdout=subprocess.DEVNULL)
        p["log"] = str(run / "sensor-logs" / "it2")
        runs = json.loads((run / "metrics.json").read_text()).get("runs")
        p["status"] = str(runs[0].get("status")) if isinstance(runs, list) and runs else None
    (out_dir / "plants.json").write_text(json.dumps(plants, indent=1))
    return plants


if __name__ == "__main__":
    generate(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 20)
