"""``twin calibrate``'s wall time against the log's length, beside the twin's own closed-loop run
of the same log as the reference.

Run from the repository root::

    python benchmarks/bench_calibrate.py           # about 3 minutes
    python benchmarks/bench_calibrate.py --quick   # the 15 s log only

For each length (15, 30 and 60 s of paper-exp3 with a 12 N push every 15 s, IT2, the EKF, DC
motors; logged with ``write_log``): the wall time of ``simulate`` (the twin's closed loop at
1 kHz, the reference) and of :func:`twin.calibrate.run.calibrate` with the default parameters
(EKF replay, stages 0–2, the IMU latency's profile, intervals and bootstrap), in one process on
one core. Target (issue 30): under 2 minutes for a 60 s log on 2 cores.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model  # noqa: E402

TARGET_60_S = 120.0  # s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the 15 s log only")
    args = ap.parse_args(argv)
    from twin.calibrate.run import calibrate
    from twin.logs.format import read_log, write_log
    from twin.scenarios import load_scenario
    from twin.sim.simulate import simulate

    lengths = (15.0,) if args.quick else (15.0, 30.0, 60.0)
    print(f"machine: {cpu_model()}")
    print(f"{'log s':>6} {'windows':>8} {'twin run s':>11} {'calibrate s':>12} {'ratio':>6}  m_b / truth")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for T in lengths:
            pushes = ", ".join(f"{{force=[12,0,0], start={s:g}, duration=0.1}}" for s in range(8, int(T), 15))
            sc = load_scenario("paper-exp3", [f"duration={T:g}", f"pushes=[{pushes}]"])
            t0 = pc()
            run = simulate(sc.run_spec("it2"))
            t_run = pc() - t0
            log = read_log(write_log(run, Path(tmp) / f"log-{T:g}", sc))
            t0 = pc()
            cal = calibrate([log])
            t_cal = pc() - t0
            worst = t_cal if T == 60.0 else worst
            truth = sc.true_params().m_b
            print(f"{T:6g} {cal.fit.windows.count:8d} {t_run:11.2f} {t_cal:12.2f} {t_cal / t_run:6.1f}  "
                  f"{cal.fit.values['m_b'] / truth:.4f}")
    if not args.quick:
        verdict = "met" if worst <= TARGET_60_S else "NOT met"
        print(f"60 s log: {worst:.1f} s against the target {TARGET_60_S:g} s: {verdict}")
        return 0 if worst <= TARGET_60_S else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
