"""Real-time factor of a scenario run without video, against the twin's bare physics.

Run from the repository root::

    python benchmarks/bench_run.py            # about 20 s
    python benchmarks/bench_run.py --quick    # a few seconds

What is measured, in one process, rounds interleaved:

* **closed loop** – ``simulate_twin`` on the ``paper-exp3`` scenario (1 kHz physics,
  200 Hz control, DC motors, the mismatched true plant, simulated IMU and encoders, the
  EKF, and all three IT2 controllers: PDC balance, Mamdani position and direction), 15 s
  simulated; wall time per simulated second and the real-time factor (targets: ≥ 20×).
* **twin physics** – the same ``TwinConfig`` stepped with ``BulletTwin.step(0, 0)``
  (motor drivers, ground truth, end checks; no sensors, estimator or controllers): the
  cost of the physics alone per simulated second. The closed loop's cost against it is
  the target's ratio (≤ 2×).
* **twin run** – ``run_scenario`` with both controllers and all outputs but the video
  (design, two runs, trajectory.csv, metrics.json, figure.png), wall time per simulated
  second of the two runs, for reference.
"""
from __future__ import annotations

import argparse
import gc
import statistics
import sys
import tempfile
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model, pybullet_version, twin_window  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run")
    args = ap.parse_args(argv)
    from twin.controllers.cascade import build_cascade
    from twin.sim.bullet_loop import simulate_twin
    from twin.controllers.lmi import design_balance_gains
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    rounds = 2 if args.quick else 5
    sc = load_scenario("paper-exp3", ["duration=5"] if args.quick else [])
    exp, config, sensors = sc.experiment(), sc.twin_config(), sc.sensor_config()
    design = design_balance_gains(**sc.design_options())
    print("scenario run without video against the twin's bare physics")
    print(f"machine: {cpu_model()}; Python {sys.version.split()[0]}; PyBullet {pybullet_version()}")
    print(f"scenario {sc.name}: {sc.duration:g} s, {config.physics_rate:g} Hz physics, {config.control_rate:g} Hz "
          f"control, estimator {sc.data['sensors']['estimator']}, IT2 balance + position + direction\n")
    loop, physics, full = [], [], []
    n_window = int(config.control_rate)  # 1 s per window
    for r in range(rounds + 1):  # round 0 warms up
        ctrl = build_cascade("it2", design, exp.targets, **sc.cascade_options())
        gc.collect()
        t0 = pc()
        run = simulate_twin(ctrl, exp, config, duration=sc.duration, controller_name="it2", sensors=sensors,
                            seed=r)
        wall = pc() - t0
        assert run.status == "ok", run.end_reason
        sim = float(run.t[-1])
        phys = [twin_window(config, n_window)[0] * config.physics_rate for _ in range(3)]
        with tempfile.TemporaryDirectory() as tmp:
            t0 = pc()
            res = run_scenario(sc, out=Path(tmp), video=False)
            wall_full = pc() - t0
        if r == 0:
            continue
        loop.append(wall / sim)
        physics.append(min(phys))
        full.append(wall_full / sum(float(x.t[-1]) for x in res.runs))
    med = statistics.median
    lp, ph, fu = med(loop), med(physics), med(full)
    rows = [
        ("closed loop (sensors, EKF, 3 IT2 controllers)", lp, 1.0 / lp, lp / ph),
        ("twin physics alone (BulletTwin.step)", ph, 1.0 / ph, 1.0),
        ("twin run, both controllers, all outputs but video", fu, 1.0 / fu, fu / ph),
    ]
    print(f"{'variant':52}{'ms per sim. s':>15}{'real-time factor':>18}{'vs physics':>12}")
    for name, v, rtf, ratio in rows:
        print(f"{name:52}{v * 1e3:15.2f}{rtf:18.1f}{ratio:11.2f}×")
    print(f"\n({rounds} rounds after a warm-up; medians; closed loop range "
          f"{min(loop) * 1e3:.2f}–{max(loop) * 1e3:.2f} ms per simulated second)")
    print(f"real-time factor {1 / lp:.1f} (target ≥ 20: {'met' if 1 / lp >= 20 else 'missed'}); closed loop "
          f"{lp / ph:.2f}× the physics (target ≤ 2×: {'met' if lp / ph <= 2 else 'missed'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
