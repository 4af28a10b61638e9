"""Accuracy of the EKF state estimator in the loop on the PyBullet twin: against the two
hobby baselines under default sensor noise, under each injected sensor fault, closed-loop
success, and the filter's statistical consistency.

Run from the repository root::

    python benchmarks/estimator_accuracy.py             # 10 seeds, about 1 min
    python benchmarks/estimator_accuracy.py --quick     # 3 seeds, about 15 s
    python benchmarks/estimator_accuracy.py --seeds 20  # more seeds
    python benchmarks/estimator_accuracy.py --markdown docs/_generated/estimator-accuracy.md

``--markdown PATH`` also writes the whole report, as printed, to PATH for the documentation
(a fenced text block under a line naming the command, machine, date and commit; see
``benchmarks/published.py``).

The set-up of every run
-----------------------
The IT2 balance controller of the default LMI design (``design_balance_gains()``,
``build_cascade("it2", ...)``, balance loop only) on the default twin (1 kHz physics,
200 Hz control, default DC motors), the robot released at rest from θ0, with the
default sensors (``SensorConfig()``: MPU-6050-class IMU at 200 Hz with 5 ms latency,
1200-count encoders; see ``twin.sensors.specs``) plus the faults of section B. Seed s
(0 … S−1) draws the sensors' noise, constants and fault outcomes, and nothing else; the
ideal-sensing runs have no randomness. A run is *balanced* if it ran its whole duration
(``status == "ok"``; it "fell" once the tilt passed 1 rad or the body touched the floor).

The estimators: ``ekf`` (``estimation.ekf.EKFEstimator``), ``complementary`` (a = 0.98)
and ``kalman2`` (TKJ Electronics' angle-and-bias Kalman filter), see
``estimation.baselines``. The error of an estimate is what the controllers were (or
would have been) handed at each control instant minus the ground truth then;
RMSE = √(mean of its square) over the rows of the run (all of them: a fallen run up to
its end).

Same data for all three. In sections A and B the EKF is the estimator in the loop; the
baselines are then run offline over the very measurements that run's EKF received, with
that run's commands (``build_estimator(kind, ...)``, ``start`` with the first
measurement, ``step(meas_i, command_{i-1})``), so all three see identical data on the
same trajectory. The script first checks that an offline replay of the EKF over a logged
run reproduces the in-loop estimates bit for bit (the log is complete and the filter
deterministic).

What is reported
----------------
A. Default sensor noise, from θ0 = 0.2 rad and 0.48 rad, 5 s, S seeds: RMSE of θ (mrad),
   θ̇, ψ, ψ̇, α, α̇ (rad, rad/s) of each estimator, median and max over the seeds; the
   EKF's reduction 1 − EKF/baseline of the medians, and on how many seeds the EKF's RMSE
   was the smaller.
B. One row per injected fault (parameters listed with the table), from θ0 = 0.2 rad, 5 s,
   the fault from t = 2 s, S seeds each; the no-fault runs of A (θ0 = 0.2 rad) are the
   reference row, with t ≥ 1.5 s as its window. EKF in the loop: θ RMSE over the run and
   over the fault window (from 0.5 s before the fault starts to 0.5 s after it ends; a
   latency change never ends, so to the end of the run), max |θ error| over the run
   (on a healthy run that is the release transient in the first 0.2 s) and in the
   window, balanced runs, the samples the fault hit, the filter's counters (IMU samples
   rejected as outliers, encoder samples rejected by the χ² gate, forced encoder
   re-synchronisations after ``max_rejects_in_row`` rejections in a row, the library's
   ``predict_only_steps`` and ``unchanged_encoder_samples``, resets after numerical
   failure). Then the baselines' θ RMSE and max |θ error| on the same measurements
   beside the EKF's.
C. Closed-loop success: each estimator in the loop (``simulate_twin(...,
   estimator=kind)``, its own runs; the EKF's are those of A), and ideal sensing (the
   controller reads the truth), from θ0 = 0.2 and 0.48 rad, 5 s, S seeds (C1); and
   under each fault of B, from θ0 = 0.2 rad, each estimator in the loop (C2; the
   EKF's runs are those of B).
D. Consistency of the EKF: ``estimation.consistency.monte_carlo`` over R runs (default
   20, ``--quick`` 8) of 3 s from θ0 = 0.05, 0.2 and 0.48 rad, rows from t = 0.5 s: mean
   NEES (with the standard error of the per-run means) against the state dimension, the
   fraction of rows whose run-averaged NEES lies inside its two-sided 95 % χ² bounds, the
   same for the summed NIS of the encoder updates, and NIS per degree of freedom (1 for a
   consistent filter). Runs that fell are
   left out (the test needs runs of equal length); their number is shown.

The closing "Flags" list is computed from the tables: every comparison the EKF loses
(on the medians or on any seed), runs that fell, gate trouble, inconsistency.

Nothing here is random except through the explicit seeds; wall times use
``time.perf_counter``. The header prints the first digits of the SHA-256 of the
estimator's sources, since the figures change with them.
"""
from __future__ import annotations

import argparse
import hashlib
import math
import os
import platform
import sys
import textwrap
import time
import unicodedata
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_twin import cpu_model  # noqa: E402

from twin.registry import build_estimator_for as build_estimator  # noqa: E402
from estimation import replay as replay_estimator  # noqa: E402
from estimation.consistency import monte_carlo  # noqa: E402
from twin.controllers.cascade import build_cascade  # noqa: E402
from twin.experiments import Experiment  # noqa: E402
from twin.sim.bullet_loop import simulate_twin  # noqa: E402
from twin.controllers.lmi import design_balance_gains  # noqa: E402
from twin.params import NOMINAL  # noqa: E402
from twin.sensors import Dropout, LatencyChange, SensorConfig, Spikes, Stuck  # noqa: E402

pc = time.perf_counter
DURATION = 5.0  # s, sections A–C
FAULT_T = 2.0  # s, when every fault of section B starts
WINDOW_MARGIN = 0.5  # s, before and after the fault
MC_DURATION = 3.0  # s, section D
MC_START = 0.5  # s, section D: rows from here on
QUANTITIES = ("theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot")
Q_LABEL = {"theta": ("θ", "mrad", 1e3), "theta_dot": ("θ̇", "rad/s", 1.0), "psi": ("ψ", "rad", 1.0),
           "psi_dot": ("ψ̇", "rad/s", 1.0), "alpha": ("α", "rad", 1.0), "alpha_dot": ("α̇", "rad/s", 1.0)}
BASELINES = ("complementary", "kalman2")
MAX_IN_ROW = "max_rejects_in_row"  # replaced by the EKF's own setting in main()


@dataclass(frozen=True)
class FaultCase:
    label: str
    faults: tuple
    detail: str


FAULT_CASES = (
    FaultCase("IMU dropout 0.2 s", (Dropout("imu", FAULT_T, 0.2),),
              "gyro and accelerometer deliver nothing for 0.2 s (40 samples), e.g. an I²C bus hang"),
    FaultCase("encoder dropout 0.2 s", (Dropout("encoders", FAULT_T, 0.2),),
              "both encoders deliver nothing for 0.2 s (40 samples)"),
    FaultCase("all dropout 0.1 s", (Dropout("all", FAULT_T, 0.1),),
              "IMU and encoders deliver nothing for 0.1 s (20 periods), e.g. a blocked control task"),
    FaultCase("gyro stuck 0.1 s", (Stuck("gyro", FAULT_T, 0.1),),
              "the gyro repeats its last sample for 0.1 s (20 samples)"),
    FaultCase("encoder stuck 0.2 s", (Stuck("encoders", FAULT_T, 0.2),),
              "both encoders repeat their last counts for 0.2 s (40 samples)"),
    FaultCase("IMU spikes", (Spikes("imu", FAULT_T, 1.0, rate=10.0, magnitude=1.0),),
              "for 1 s, each gyro and each accelerometer sample is an outlier with probability 10/s x 5 ms "
              "(~10 per sensor), every axis offset by ±1 rad/s (gyro) / ±1 m/s² (accelerometer)"),
    FaultCase("accel spikes", (Spikes("accel", FAULT_T, 1.0, rate=10.0, magnitude=1.0),),
              "for 1 s, each accelerometer sample is an outlier with probability 10/s x 5 ms (~10), every axis "
              "offset by ±1 m/s²; the gyro is clean"),
    FaultCase("encoder spikes", (Spikes("encoders", FAULT_T, 1.0, rate=10.0, magnitude=0.1),),
              "for 1 s, each encoder sample is an outlier with probability 10/s x 5 ms (~10), both wheels "
              "offset by ±0.1 rad (±19 counts)"),
    FaultCase("gyro latency 5->10 ms", (LatencyChange("gyro", FAULT_T, 0.010),),
              "from 2 s the gyro reports 10 ms late (DLPF 20 Hz: 8.3 ms, rounded up to 2 periods); "
              "the accelerometer stays at 5 ms; the EKF still assumes 5 ms"),
    FaultCase("gyro latency 5->15 ms", (LatencyChange("gyro", FAULT_T, 0.015),),
              "the same, 15 ms (DLPF 10 Hz: 13.4 ms, rounded up to 3 periods)"),
    FaultCase("gyro latency 5->20 ms", (LatencyChange("gyro", FAULT_T, 0.020),),
              "the same, 20 ms (DLPF 5 Hz: 18.6 ms, rounded up to 4 periods)"),
    FaultCase("IMU latency 5->20 ms", (LatencyChange("imu", FAULT_T, 0.020),),
              "from 2 s gyro and accelerometer both report 20 ms late (EKF assumes 5 ms)"),
)


# ---- helpers ------------------------------------------------------------------------------
def versions() -> str:
    from importlib.metadata import version

    out = []
    for name in ("numpy", "scipy", "filterpy", "pybullet"):
        try:
            out.append(f"{name} {version(name)}")
        except Exception:
            out.append(f"{name} ?")
    return ", ".join(out)


def controller(design, exp):
    return build_cascade("it2", design, exp.targets)


def truth6(run) -> np.ndarray:
    return np.column_stack([run.signal(q) for q in QUANTITIES])


def replay(kind: str, run) -> np.ndarray:
    """Estimates (n, 6) of ``kind`` run offline over ``run``'s measurements and commands."""
    f = build_estimator(kind, run.sensor_config, run.config.control_rate, run.config.motor, run.model_params)
    return replay_estimator(f, run)


def errors(run) -> dict[str, np.ndarray]:
    """{estimator: error (n, 6)}: the EKF in the loop, the baselines offline on its data."""
    tru = truth6(run)
    out = {"ekf": run.estimates - tru}
    for kind in BASELINES:
        out[kind] = replay(kind, run) - tru
    return out


def rmse(e: np.ndarray, mask=None) -> float:
    if mask is not None:
        e = e[mask]
    return float(np.sqrt(np.mean(e * e))) if e.size else math.nan


def med(v) -> float:
    v = [x for x in v if not math.isnan(x)]
    return float(np.median(v)) if v else math.nan


def mx(v) -> float:
    v = [x for x in v if not math.isnan(x)]
    return float(np.max(v)) if v else math.nan


def note(text: str) -> None:
    """A paragraph of explanation, indented under a section title."""
    print(textwrap.fill(text, width=114, initial_indent="   ", subsequent_indent="   "))


def pad(s: str, w: int) -> str:
    """``s`` left-aligned in ``w`` terminal columns (combining marks such as the dot of θ̇ take none)."""
    return s + " " * max(0, w - sum(not unicodedata.combining(c) for c in s))


def f(v: float, w: int, p: int) -> str:
    return f"{'n/a':>{w}}" if v is None or math.isnan(v) else f"{v:{w}.{p}f}"


def g(v: float, w: int) -> str:
    """A value of any magnitude in ``w`` characters, 3 significant digits."""
    return f"{'n/a':>{w}}" if math.isnan(v) else f"{v:{w}.3g}"


def fault_window(case: FaultCase, t: np.ndarray) -> np.ndarray:
    lo, hi = math.inf, -math.inf
    for fl in case.faults:
        if isinstance(fl, LatencyChange):
            lo, hi = min(lo, fl.time), math.inf
        else:
            lo, hi = min(lo, fl.start), max(hi, fl.start + fl.duration)
    return (t >= lo - WINDOW_MARGIN - 1e-9) & (t <= hi + WINDOW_MARGIN + 1e-9)


def window_text(case: FaultCase) -> str:
    lo, hi = math.inf, -math.inf
    for fl in case.faults:
        if isinstance(fl, LatencyChange):
            lo, hi = min(lo, fl.time), math.inf
        else:
            lo, hi = min(lo, fl.start), max(hi, fl.start + fl.duration)
    a = lo - WINDOW_MARGIN
    b = "end" if hi == math.inf else f"{hi + WINDOW_MARGIN:g} s"
    return f"[{a:g} s, {b}]"


# ---- sections ------------------------------------------------------------------------------
def ekf_runs(design, theta0: float, seeds, faults=(), duration=DURATION, log_filter=False):
    exp = Experiment("estimator-accuracy", "", theta0=theta0, duration=duration)
    sc = SensorConfig(faults=faults)
    return [simulate_twin(controller(design, exp), exp, sensors=sc, seed=s, log_filter=log_filter) for s in seeds]


def section_a(runs_by_theta: dict, seeds) -> dict:
    print()
    print(f"A. Default sensor noise: EKF in the loop, baselines offline on the same measurements "
          f"({len(seeds)} seeds, {DURATION:g} s)")
    print("   RMSE of the estimate handed to the controllers; median and max over the seeds. "
          "Reduction = 1 - EKF/baseline")
    print("   of the medians (negative: the EKF is worse); (k/S): seeds on which the EKF's RMSE is the smaller.")
    flags = []
    for theta0, (runs, errs) in runs_by_theta.items():
        n_ok = sum(r.status == "ok" for r in runs)
        print()
        print(f"   θ0 = {theta0:g} rad: {n_ok}/{len(runs)} EKF runs balanced")
        hdr1 = (f"   {'quantity':10}{'unit':>7}{'EKF':^18}{'complementary':^18}{'kalman2':^18}"
                f"{'reduction vs CF':>19}{'reduction vs K2':>19}")
        hdr2 = f"   {'':10}{'':>7}" + f"{'median':>9}{'max':>9}" * 3 + f"{'':>19}{'':>19}"
        print(hdr1)
        print(hdr2)
        print("   " + "-" * (len(hdr1) - 3))
        for j, q in enumerate(QUANTITIES):
            sym, unit, scale = Q_LABEL[q]
            vals = {k: [rmse(e[k][:, j]) * scale for e in errs] for k in ("ekf",) + BASELINES}
            cells = "".join(g(med(vals[k]), 9) + g(mx(vals[k]), 9) for k in ("ekf",) + BASELINES)
            reds = ""
            for b in BASELINES:
                red = 1.0 - med(vals["ekf"]) / med(vals[b]) if med(vals[b]) > 0 else math.nan
                wins = sum(a < c for a, c in zip(vals["ekf"], vals[b]))
                reds += f"{f(100 * red, 9, 1)}% ({wins:>2}/{len(errs):<2})"
                if wins < len(errs):
                    flags.append(f"A, θ0 = {theta0:g} rad: the {b} baseline has a smaller {sym} RMSE than the EKF "
                                 f"on {len(errs) - wins}/{len(errs)} seeds (medians: EKF {med(vals['ekf']):.3g}, "
                                 f"{b} {med(vals[b]):.3g} {unit})")
            print(f"   {pad(sym, 10)}{unit:>7}{cells}{reds}")
    note("(both baselines take ψ from the same odometry plus their own θ, α from the encoders alone and α̇ "
         "from the raw gyro, so their α and α̇ rows coincide)")
    return {"flags": flags}


REF_WINDOW_START = FAULT_T - WINDOW_MARGIN  # s: the reference row's "window" is from here to the end


def times(n: int) -> str:
    return f"{n} time{'s' if n != 1 else ''}"


def section_b(design, seeds, reference) -> list[str]:
    """Faults; ``reference`` the no-fault θ0 = 0.2 rad runs and errors of section A."""
    print()
    print(f"B. Injected faults: θ0 = 0.2 rad, {DURATION:g} s, fault from t = {FAULT_T:g} s, {len(seeds)} seeds "
          f"each; EKF in the loop")
    print("   faults (twin.sensors.faults) and their windows (fault ± 0.5 s):")
    for c in FAULT_CASES:
        print(f"   {c.label:24}{', '.join(repr(x) for x in c.faults)}")
        print(f"   {'':24}{c.detail}; window {window_text(c)}")
    print(f"   {'no fault (reference)':24}the runs of A (θ0 = 0.2 rad); its window is [{REF_WINDOW_START:g} s, end]")
    rows = [("no fault (reference)", None, reference)]
    for c in FAULT_CASES:
        runs = ekf_runs(design, 0.2, seeds, faults=c.faults)
        rows.append((c.label, c, (runs, [errors(r) for r in runs])))

    # B1: the EKF in the loop
    print()
    note("B1. EKF in the loop: θ error over the whole run and over the fault window; counts per run, median and "
         "max over the seeds. faulty = samples the fault dropped, froze or spiked (all sensors); rej. IMU / "
         "rej. enc = IMU samples the EKF rejected as outliers / encoder samples its χ² gate rejected; resync = "
         f"encoder samples force-accepted after {MAX_IN_ROW} rejections in a row; pred-only, unch. enc = the EKF's "
         "predict_only_steps and unchanged_encoder_samples (most of both, see the no-fault row, are steps where no "
         "encoder edge was crossed)")
    h1 = (f"   {'fault':23}{'θ RMSE run':^14}{'θ RMSE window':^14}{'max |θ err|':^14}{'balanced':>9}"
          f"{'faulty':>7}{'rej. IMU':>10}{'rej. enc':>10}{'resync':>7}{'pred-only':>10}{'unch. enc':>10}{'resets':>7}")
    h2 = (f"   {'':23}{'[mrad]':^14}{'[mrad]':^14}{'[mrad]':^14}{'[runs]':>9}{'':>7}{'[samples]':>10}"
          f"{'[samples]':>10}{'':>7}{'[steps]':>10}{'[samples]':>10}{'[all]':>7}")
    h3 = (f"   {'':23}{'med':>7}{'max':>7}{'med':>7}{'max':>7}{'run':>7}{'window':>7}{'':>9}{'med':>7}"
          f"{'med':>5}{'max':>5}{'med':>5}{'max':>5}{'max':>7}{'med':>10}{'med':>10}{'':>7}")
    print(h1)
    print(h2)
    print(h3)
    print("   " + "-" * (len(h1) - 3))
    table2 = []
    flags = []
    in_loop = {}
    for label, case, (runs, errs) in rows:
        masks = [r.t >= REF_WINDOW_START - 1e-9 if case is None else fault_window(case, r.t) for r in runs]
        per = {}
        for k in ("ekf",) + BASELINES:
            per[k] = {"run": [rmse(e[k][:, 0]) * 1e3 for e in errs],
                      "window": [rmse(e[k][:, 0], m) * 1e3 for e, m in zip(errs, masks)],
                      "max_run": [float(np.max(np.abs(e[k][:, 0]))) * 1e3 for e in errs],
                      "max_window": [float(np.max(np.abs(e[k][m, 0]))) * 1e3 if m.any() else math.nan
                                     for e, m in zip(errs, masks)]}
        st = [r.estimator_stats for r in runs]
        faulty = [sum(c["dropped"] + c["stuck"] + c["spiked"] for c in r.sensor_counts.values()) for r in runs]
        rej_imu = [s["rejected"]["gyro"] for s in st]
        rej_enc = [s["rejected"]["encoders"] for s in st]
        resync = [sum("re-synchronising" in ev for ev in s["events"]) for s in st]
        pred = [s["predict_only_steps"] for s in st]
        unch = [s["unchanged_encoder_samples"] for s in st]
        resets = sum(s["resets"] for s in st)
        n_ok = sum(r.status == "ok" for r in runs)
        e = per["ekf"]
        print(f"   {label:23}{g(med(e['run']), 7)}{g(mx(e['run']), 7)}{g(med(e['window']), 7)}"
              f"{g(mx(e['window']), 7)}{g(mx(e['max_run']), 7)}{g(mx(e['max_window']), 7)}"
              f"{f'{n_ok}/{len(runs)}':>9}{int(np.median(faulty)):7d}{int(np.median(rej_imu)):5d}{max(rej_imu):5d}"
              f"{int(np.median(rej_enc)):5d}{max(rej_enc):5d}{max(resync):7d}{int(np.median(pred)):10d}"
              f"{int(np.median(unch)):10d}{resets:7d}")
        table2.append((label, case, per, len(runs)))
        in_loop[label] = (n_ok, len(runs), med(e["run"]))
        if n_ok < len(runs):
            fell_t = sorted(float(r.t[-1]) for r in runs if r.status != "ok")
            flags.append(f"B, {label}: {len(runs) - n_ok}/{len(runs)} EKF runs fell (at t = "
                         f"{', '.join(f'{x:.2f}' for x in fell_t)} s)")
        if max(resync) > 0:
            flags.append(f"B, {label}: the EKF's χ² gate rejected {MAX_IN_ROW} encoder samples in a row and forced a "
                         f"re-synchronisation (in {sum(x > 0 for x in resync)}/{len(runs)} runs, up to "
                         f"{times(max(resync))} in a run; encoder samples rejected per run: median "
                         f"{int(np.median(rej_enc))}, max {max(rej_enc)})")
        if case is not None and any(isinstance(x, Spikes) for x in case.faults):
            for grp, chans, rej in (("IMU", ("gyro", "accel"), rej_imu), ("encoder", ("encoders",), rej_enc)):
                spiked = [sum(r.sensor_counts[ch]["spiked"] for ch in chans) for r in runs]
                if sum(spiked):
                    flags.append(f"B, {label}: the EKF rejected a median {int(np.median(rej))} (max {max(rej)}) "
                                 f"{grp} samples per run; the fault spiked a median {int(np.median(spiked))} "
                                 f"(max {max(spiked)}) {grp} samples per run"
                                 + (" (gyro and accelerometer counted separately)" if grp == "IMU" else ""))
        if resets:
            flags.append(f"B, {label}: {resets} numerical resets of the EKF")
        acc_out = [s.get("accel_outliers", 0) for s in st]
        if sum(acc_out):
            spiked_a = [r.sensor_counts["accel"]["spiked"] for r in runs]
            flags.append(f"B, {label}: accelerometer samples replaced by the model's (gyro kept) per run: median "
                         f"{int(np.median(acc_out))} (max {max(acc_out)}); accelerometer samples spiked: median "
                         f"{int(np.median(spiked_a))}")
        if case is not None and any(isinstance(x, LatencyChange) for x in case.faults):
            det = []
            for s in st:
                ts = [float(ev.split(" s:")[0][4:]) for ev in s["events"] if "latency changed" in ev]
                det.append(ts[0] - FAULT_T if ts else math.nan)
            n_det = sum(not math.isnan(x) for x in det)
            flags.append(f"B, {label}: the latency change was logged in {n_det}/{len(runs)} runs"
                         + (f", {min(x for x in det if not math.isnan(x)):.2f}-"
                            f"{max(x for x in det if not math.isnan(x)):.2f} s after it" if n_det else ""))
        elif sum(s.get("latency_changes", 0) for s in st):
            flags.append(f"B, {label}: a latency change was logged in a run without one (false alarm)")

    # B2: against the baselines on the same data
    print()
    note("B2. θ error of the three estimators on the same measurements (baselines offline on the EKF runs' "
         "data): median over the seeds of the RMSE, max over the seeds of max |θ err| in the window; (k/S): seeds "
         "on which the EKF's window RMSE is below both baselines'")
    h1 = (f"   {'fault':23}{'θ RMSE run [mrad]':^24}{'θ RMSE window [mrad]':^24}{'':>7}"
          f"{'max |θ err| window [mrad]':^27}")
    h2 = f"   {'':23}" + f"{'EKF':>8}{'CF':>8}{'K2':>8}" * 2 + f"{'':>7}" + f"{'EKF':>9}{'CF':>9}{'K2':>9}"
    print(h1)
    print(h2)
    print("   " + "-" * (len(h1) - 3))
    for label, case, per, n in table2:
        ks = ("ekf",) + BASELINES
        wins = sum(all(per["ekf"]["window"][i] < per[b]["window"][i] for b in BASELINES) for i in range(n))
        print(f"   {label:23}" + "".join(g(med(per[k]["run"]), 8) for k in ks)
              + "".join(g(med(per[k]["window"]), 8) for k in ks) + f"{f'({wins}/{n})':>7}"
              + "".join(g(mx(per[k]["max_window"]), 9) for k in ks))
        for b in BASELINES:
            worse = []
            for what in ("run", "window"):
                e_v, b_v = per["ekf"][what], per[b][what]
                k = sum(x > y for x, y in zip(e_v, b_v))
                if med(e_v) > med(b_v):
                    worse.append(f"{what} RMSE median {med(e_v):.3g} vs {med(b_v):.3g} mrad (worse on {k}/{n} seeds)")
                elif k:
                    worse.append(f"{what} RMSE worse on {k}/{n} seeds (medians {med(e_v):.3g} vs {med(b_v):.3g} mrad)")
            if mx(per["ekf"]["max_window"]) > mx(per[b]["max_window"]):
                worse.append(f"max |θ err| in the window {mx(per['ekf']['max_window']):.3g} vs "
                             f"{mx(per[b]['max_window']):.3g} mrad")
            if worse:
                flags.append(f"B, {label}: EKF behind {b}: " + "; ".join(worse))
    return flags, in_loop


def section_c(design, seeds, ekf_by_theta: dict, ekf_faults: dict) -> list[str]:
    print()
    print(f"C1. Closed-loop success: each estimator in the loop ({len(seeds)} seeds, {DURATION:g} s; the EKF runs are "
          "those of A);")
    print("   ideal sensing = the controller reads the truth (no randomness: one run). θ RMSE: of the estimator in "
          "the loop,")
    print("   median over the balanced runs; fell at: median time of the fall over the runs that fell")
    thetas = tuple(ekf_by_theta)
    h1 = f"   {'sensing':16}" + "".join(f"{f'θ0 = {th:g} rad':>38}" for th in thetas)
    h2 = f"   {'':16}" + f"{'balanced':>10}{'θ RMSE [mrad]':>15}{'fell at [s]':>13}" * len(thetas)
    print(h1)
    print(h2)
    print("   " + "-" * (len(h1) - 3))
    flags = []
    for kind in ("ekf",) + BASELINES + ("ideal",):
        cells = ""
        for th in thetas:
            exp = Experiment("estimator-accuracy", "", theta0=th, duration=DURATION)
            if kind == "ekf":
                runs = ekf_by_theta[th]
            elif kind == "ideal":
                runs = [simulate_twin(controller(design, exp), exp, sensors=None)]
            else:
                runs = [simulate_twin(controller(design, exp), exp, sensors=SensorConfig(), estimator=kind, seed=s)
                        for s in seeds]
            ok = [r for r in runs if r.status == "ok"]
            fell = [float(r.t[-1]) for r in runs if r.status != "ok"]
            rm = med([r.estimation_rmse("theta") * 1e3 for r in ok]) if kind != "ideal" else 0.0
            fell_c = f"{'-':>13}" if not fell else f"{np.median(fell):13.2f}"
            cells += f"{f'{len(ok)}/{len(runs)}':>10}{g(rm, 15)}{fell_c}"
            if len(ok) < len(runs):
                flags.append(f"C1, θ0 = {th:g} rad: {kind} in the loop balanced {len(ok)}/{len(runs)} runs "
                             f"(falls at t = {', '.join(f'{x:.2f}' for x in sorted(fell))} s)")
        print(f"   {kind:16}{cells}")

    # C2: under the faults of B, each estimator in the loop
    print()
    print(f"C2. Closed-loop success under the faults of B (θ0 = 0.2 rad, {len(seeds)} seeds, {DURATION:g} s), each "
          "estimator in the loop")
    print("   (the EKF's runs are those of B); θ RMSE: of the estimator in the loop over the whole run, median over "
          "all runs")
    h1 = f"   {'fault':23}" + "".join(f"{k:^24}" for k in ("EKF", "complementary", "kalman2"))
    h2 = f"   {'':23}" + f"{'balanced':>10}{'θ RMSE [mrad]':>14}" * 3
    print(h1)
    print(h2)
    print("   " + "-" * (len(h1) - 3))
    for label, (n_ok, n, rm) in ekf_faults.items():
        case = next((c for c in FAULT_CASES if c.label == label), None)
        exp = Experiment("estimator-accuracy", "", theta0=0.2, duration=DURATION)
        sc = SensorConfig(faults=() if case is None else case.faults)
        cells = f"{f'{n_ok}/{n}':>10}{g(rm, 14)}"
        for kind in BASELINES:
            runs = [simulate_twin(controller(design, exp), exp, sensors=sc, estimator=kind, seed=s) for s in seeds]
            ok = sum(r.status == "ok" for r in runs)
            cells += f"{f'{ok}/{len(runs)}':>10}{g(med([r.estimation_rmse('theta') * 1e3 for r in runs]), 14)}"
            if ok < len(runs):
                flags.append(f"C2, {label}: {kind} in the loop balanced {ok}/{len(runs)} runs")
            if ok > n_ok:
                flags.append(f"C2, {label}: {kind} in the loop balanced more runs than the EKF ({ok} vs {n_ok})")
        print(f"   {label:23}{cells}")
    return flags


def section_d(design, n_runs: int) -> list[str]:
    print()
    print(f"D. EKF consistency (estimation.consistency.monte_carlo, 95 % two-sided χ² bounds): {n_runs} runs x "
          f"{MC_DURATION:g} s per θ0 (seeds 0-{n_runs - 1}), rows from t = {MC_START:g} s")
    h1 = (f"   {'θ0':>6}{'runs':>8}{'rows':>6}{'NEES':>9}{'s.e.':>7}{'dim':>5}{'bounds on run-avg NEES':>24}"
          f"{'NEES inside':>13}{'NIS inside':>12}{'NIS/dof':>9}")
    h2 = (f"   {'[rad]':>6}{'[used]':>8}{'':>6}{'mean':>9}{'':>7}{'':>5}{'':>24}{'[% rows]':>13}{'[% rows]':>12}"
          f"{'[1]':>9}")
    print(h1)
    print(h2)
    print("   " + "-" * (len(h1) - 3))
    flags = []
    for th in (0.05, 0.2, 0.48):
        runs = ekf_runs(design, th, range(n_runs), duration=MC_DURATION, log_filter=True)
        ok = [r for r in runs if r.status == "ok"]
        if len(ok) < 2:
            print(f"   {th:6.2f}{f'{len(ok)}/{len(runs)}':>8}   fewer than 2 balanced runs: no test")
            continue
        m = monte_carlo(ok, start=MC_START)
        lo, hi = m["nees_bounds"]
        se = float(np.std(m["nees_run_means"], ddof=1)) / math.sqrt(len(ok))  # of the per-run means
        print(f"   {th:6.2f}{f'{len(ok)}/{len(runs)}':>8}{m['rows']:6d}{m['nees_mean']:9.2f}{se:7.2f}{m['dim']:5d}"
              f"{f'[{lo:.2f}, {hi:.2f}]':>24}{100 * m['nees_inside']:13.1f}{100 * m['nis_inside']:12.1f}"
              f"{m['nis_per_dof']:9.2f}")
        if not (lo <= m["nees_mean"] <= hi) or m["nees_inside"] < 0.9:
            flags.append(f"D, θ0 = {th:g} rad: mean NEES {m['nees_mean']:.2f} for dimension {m['dim']}, "
                         f"{100 * m['nees_inside']:.0f}% of rows inside the 95% bounds")
        if m["nis_inside"] < 0.9 or not (0.8 <= m["nis_per_dof"] <= 1.25):
            flags.append(f"D, θ0 = {th:g} rad: NIS per dof {m['nis_per_dof']:.2f}, "
                         f"{100 * m['nis_inside']:.0f}% of rows inside the 95% bounds")
        if len(ok) < len(runs):
            flags.append(f"D, θ0 = {th:g} rad: {len(runs) - len(ok)}/{len(runs)} runs fell (left out)")
    return flags


# ---- main ---------------------------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds, 8 consistency runs (about 15 s)")
    ap.add_argument("--seeds", type=int, help="seeds per configuration in A-C (default 10; quick 3)")
    ap.add_argument("--markdown", metavar="PATH", help="also write the report to PATH (docs/_generated/...)")
    args = ap.parse_args(argv)
    if args.markdown:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from published import Tee, as_text_block, write_markdown

        with Tee() as tee:
            status = report(args, ap)
        write_markdown(args.markdown, as_text_block(tee.text), argv=None if argv is None else [sys.argv[0], *argv])
        return status
    return report(args, ap)


def report(args, ap) -> int:
    n_seeds = args.seeds or (3 if args.quick else 10)
    if n_seeds < 1:
        ap.error("--seeds must be at least 1")
    n_mc = 8 if args.quick else 20
    seeds = range(n_seeds)
    t_start = pc()

    print("EKF state estimator on the PyBullet twin: accuracy, faults, closed-loop success, consistency")
    print(f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs; Python {platform.python_version()} "
          f"({platform.python_implementation()}); {versions()}")
    root = Path(__file__).resolve().parents[1]
    digests = ", ".join(f"{n} {hashlib.sha256((root / n).read_bytes()).hexdigest()[:12]}"
                        for n in ("estimation/ekf.py", "estimation/model.py", "estimation/baselines.py"))
    print(f"sources (sha256, first 12 hex digits): {digests}")
    sc = SensorConfig()
    print(f"sensors: IMU {sc.imu.rate:g} Hz, latency {1e3 * sc.imu.latency:g} ms, gyro noise "
          f"{sc.imu.gyro.noise_density:.3g} rad/s/√Hz, turn-on bias σ {sc.imu.gyro.turn_on_bias:.3g} rad/s; "
          f"encoders {sc.encoders.counts_per_rev} counts/rev, latency {1e3 * sc.encoders.latency:g} ms")
    print(f"controller: IT2 PDC balance (default LMI design), 200 Hz; seeds 0-{n_seeds - 1}"
          f"{' (--quick)' if args.quick else ''}")
    global MAX_IN_ROW
    probe = build_estimator("ekf", sc, 200.0, None, NOMINAL)
    MAX_IN_ROW = getattr(probe, "max_rejects_in_row", "?")
    gates = getattr(probe, "gates", {})
    gate_text = ", ".join(f"{v:.3g} ({k} dof)" for k, v in sorted(gates.items()))
    print(f"EKF settings: χ² gate on the encoders {gate_text}; after {MAX_IN_ROW} rejections in a row the next "
          "encoder sample is accepted")
    design = design_balance_gains()

    # ---- A (its EKF runs also serve B's reference row and C's EKF row)
    t0 = pc()
    by_theta, ekf_runs_by_theta = {}, {}
    for th in (0.2, 0.48):
        runs = ekf_runs(design, th, seeds)
        by_theta[th] = (runs, [errors(r) for r in runs])
        ekf_runs_by_theta[th] = runs
    r0 = by_theta[0.2][0][0]
    diff = float(np.max(np.abs(replay("ekf", r0) - r0.estimates)))
    print(f"check: the EKF replayed offline over run (θ0 = 0.2 rad, seed 0) reproduces its in-loop estimates: "
          f"max |difference| = {diff:.3g}{'' if diff == 0.0 else '  WARNING: not identical'}")
    res_a = section_a(by_theta, seeds)
    t_a = pc() - t0

    t0 = pc()
    flags_b, ekf_faults = section_b(design, seeds, by_theta[0.2])
    t_b = pc() - t0
    t0 = pc()
    flags_c = section_c(design, seeds, ekf_runs_by_theta, ekf_faults)
    t_c = pc() - t0
    t0 = pc()
    flags_d = section_d(design, n_mc)
    t_d = pc() - t0

    flags = res_a["flags"] + flags_b + flags_c + flags_d
    print()
    print("Flags (computed from the tables above: every case where the EKF is not ahead, runs that fell, "
          "gate trouble, inconsistency):")
    for fl in flags or ["none"]:
        print(f"  - {fl}")
    print()
    print(f"wall time: {pc() - t_start:.1f} s (A {t_a:.1f} s, B {t_b:.1f} s, C {t_c:.1f} s, D {t_d:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
