"""The estimator's cost per control step, against the twin's physics in the same run
(target: at most 25 % of the physics' cost per simulated second).

Run from the repository root::

    python benchmarks/bench_estimator.py            # about 20 s
    python benchmarks/bench_estimator.py --quick    # a few seconds

What is measured
----------------
* **physics** – ``BulletTwin(TwinConfig()).step(0.0, 0.0)``: one 5 ms control period
  (5 physics steps at 1 kHz, motor driver, ground-truth read) per call, over windows of
  1 s of simulated time from upright (as in ``bench_twin.py``). Per simulated second:
  200 calls.
* **estimators** – each estimator replays the same recorded sensor stream: the
  measurements and commands of one closed-loop twin run (IT2 balance from θ0 = 0.2 rad,
  default MPU-6050-class IMU and 1200-count encoders, seed 0). Timed: ``start`` and every
  ``step(measurement, command)``, i.e. everything the estimator does per control
  period (sample queues, gating, the filter step, the forward prediction across the
  latency). Variants: the EKF's compiled kernel (the default where it is built), the
  EKF's pure-Python path on filterpy (the reference), the complementary filter and the
  two-state angle+bias Kalman filter (the baselines).
* **sensors** – the simulated IMU and encoders (``SensorSuite.read``) per control period,
  for scale (not part of the target).

Windows of all variants are interleaved over several rounds; reported are the median
and the best per-step time. Nothing here is random except the recorded run's seeded
sensor noise; ``time.perf_counter`` is the clock.
"""
from __future__ import annotations

import argparse
import gc
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_twin import cpu_model, pybullet_version  # noqa: E402

from twin.registry import build_estimator_for as build_estimator  # noqa: E402
from estimation import ekf as ekf_module  # noqa: E402
from twin.controllers.cascade import build_cascade  # noqa: E402
from twin.experiments import Experiment  # noqa: E402
from twin.sim.bullet_loop import simulate_twin  # noqa: E402
from twin.controllers.lmi import design_balance_gains  # noqa: E402
from twin.params import NOMINAL  # noqa: E402
from twin.plant.bullet import BulletTwin, TwinConfig  # noqa: E402
from twin.sensors import SensorConfig, SensorSuite  # noqa: E402

TARGET = 0.25
pc = time.perf_counter


def physics_window(periods: int) -> float:
    """Seconds per control period of the twin's physics over one window."""
    with BulletTwin(TwinConfig()) as twin:
        step = twin.step
        t0 = pc()
        for _ in range(periods):
            step(0.0, 0.0)
        return (pc() - t0) / periods


def estimator_window(kind: str, compiled, sensors, run) -> float:
    """Seconds per control step of one estimator replaying the recorded run."""
    f = build_estimator(kind, sensors, run.config.control_rate, run.config.motor, NOMINAL, compiled=compiled)
    meas = list(run.measurements)  # the Measurement objects, built once: not timed below
    cmds = [tuple(c) for c in run.commands[:, :2].tolist()]
    step = f.step
    t0 = pc()
    f.start(meas[0])
    for i in range(1, len(meas)):
        step(meas[i], cmds[i - 1])
    return (pc() - t0) / len(meas)


def sensors_window(sensors, run) -> float:
    """Seconds per control period of the simulated sensors (true inputs from the run)."""
    import numpy as np

    suite = SensorSuite(sensors, run.config.control_rate, np.random.default_rng(0))
    tr = run.truth
    ql, qr = (tr[:, 3] - tr[:, 1]).tolist(), (tr[:, 4] - tr[:, 1]).tolist()
    gyro, accel = (0.0, 0.01, 0.0), (0.0, 0.0, 9.81)
    suite.start(gyro, accel, ql[0], qr[0])
    read = suite.read
    t0 = pc()
    for i in range(len(ql)):
        read(i, gyro, accel, ql[i], qr[i])
    return (pc() - t0) / len(ql)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer rounds (smoke run)")
    args = ap.parse_args(argv)
    rounds = 3 if args.quick else 9
    duration = 2.0 if args.quick else 5.0
    print(f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs; Python {platform.python_version()}; "
          f"PyBullet {pybullet_version()}")
    print(f"EKF compiled kernel built: {ekf_module._kernel is not None}")
    sensors = SensorConfig()
    design = design_balance_gains()
    exp = Experiment("bench", "IT2 balance from 0.2 rad", theta0=0.2, duration=duration)
    run = simulate_twin(build_cascade("it2", design, exp.targets), exp, sensors=sensors, seed=0)
    if run.status != "ok":
        raise SystemExit(f"the recorded run did not balance ({run.status}); nothing to measure")
    variants = [("physics (BulletTwin.step, 1 control period)", lambda: physics_window(200))]
    if ekf_module._kernel is not None:
        variants.append(("EKF, compiled kernel (default)", lambda: estimator_window("ekf", None, sensors, run)))
    variants += [
        ("EKF, pure Python on filterpy (reference)", lambda: estimator_window("ekf", False, sensors, run)),
        ("complementary filter (baseline)", lambda: estimator_window("complementary", None, sensors, run)),
        ("two-state angle+bias Kalman (baseline)", lambda: estimator_window("kalman2", None, sensors, run)),
        ("simulated IMU + encoders (SensorSuite.read)", lambda: sensors_window(sensors, run)),
    ]
    times = {name: [] for name, _ in variants}
    for k in range(rounds):
        order = variants[k % len(variants):] + variants[:k % len(variants)]
        for name, fn in order:
            gc.collect()
            times[name].append(fn())
    phys = statistics.median(times[variants[0][0]])
    print(f"\n{len(run.measurements)} control steps replayed per estimator window; {rounds} rounds, interleaved\n")
    print(f"{'variant':48s} {'median µs/step':>15s} {'best µs/step':>13s} {'ms per sim. s':>14s} {'vs physics':>11s}")
    for name, _ in variants:
        med, best = statistics.median(times[name]), min(times[name])
        print(f"{name:48s} {med * 1e6:15.1f} {best * 1e6:13.1f} {med * 200 * 1e3:14.2f} {med / phys:10.1%}")
    default = "EKF, compiled kernel (default)" if ekf_module._kernel is not None else \
        "EKF, pure Python on filterpy (reference)"
    frac = statistics.median(times[default]) / phys
    print(f"\nthe default EKF costs {frac:.1%} of the twin's physics per simulated second "
          f"(target ≤ {TARGET:.0%}: {'met' if frac <= TARGET else 'MISSED'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
