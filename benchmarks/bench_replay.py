"""Replaying an estimator on a sensor log against the twin's closed loop over the same log
length, and a log's size per simulated minute.

Run from the repository root::

    python benchmarks/bench_replay.py           # about 20 s
    python benchmarks/bench_replay.py --quick   # a few seconds

What is measured, in one process, rounds interleaved (round 0 warms up and is dropped):

* **closed loop** – ``simulate`` on ``paper-exp3`` (15 s simulated, IT2, the EKF, simulated
  IMU and encoders, PyBullet at 1 kHz): wall time per control period;
* **replay** – the same run's sensor log (``write_log``, read back with ``read_log``) replayed
  with each estimator (the compiled EKF, the complementary filter, the two-state Kalman
  filter; no physics, no controller): wall time per control instant, reading the log
  excluded, and the real-time factor (target for the EKF: well over 100×);
* **log size** – the log directory's bytes per simulated minute (CSV text, truth included).
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run")
    args = ap.parse_args(argv)
    from twin.logs.format import read_log, write_log
    from twin.logs.replay import build_for, replay
    from twin.scenarios import load_scenario
    from twin.sim.simulate import simulate

    duration = 3.0 if args.quick else 15.0
    rounds = 2 if args.quick else 5
    sc = load_scenario("paper-exp3", [f"duration={duration}"])
    kinds = ("ekf", "complementary", "kalman2")
    times = {k: [] for k in ("closed loop",) + kinds}
    with tempfile.TemporaryDirectory() as tmp:
        run = simulate(sc.run_spec("it2"))
        path = write_log(run, Path(tmp) / "log", sc)
        size = sum(p.stat().st_size for p in path.iterdir())
        log = read_log(path)
        n = len(run.t)
        for r in range(rounds + 1):
            spec = sc.run_spec("it2")
            t0 = pc()
            simulate(spec)
            dt = pc() - t0
            if r:
                times["closed loop"].append(dt / n)
            for k in kinds:
                est = build_for(log, k)
                res = replay(log, est, k)
                if r:
                    times[k].append(res.step_s)
    period = 1.0 / log.control_rate
    print("replay of a sensor log against the closed loop over the same length")
    print(f"machine: {cpu_model()}; Python {sys.version.split()[0]}")
    print(f"log: paper-exp3, {duration:g} s at {log.control_rate:g} Hz, {n} instants, {size / 1e3:.0f} kB "
          f"({size / duration * 60 / 1e6:.2f} MB per simulated minute)\n")
    print(f"{'variant':44}{'µs per instant':>16}{'real-time factor':>18}{'vs closed loop':>16}")
    base = statistics.median(times["closed loop"])
    for name, v in times.items():
        m = statistics.median(v)
        label = name if name == "closed loop" else f"replay, {name}"
        print(f"{label:44}{m * 1e6:>16.1f}{period / m:>18.0f}{base / m:>15.1f}×")
    print(f"\n({rounds} rounds after a warm-up; medians)")
    ekf = period / statistics.median(times["ekf"])
    print(f"EKF replay {ekf:.0f}× real time (target: well over 100×: {'met' if ekf > 100 else 'missed'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
