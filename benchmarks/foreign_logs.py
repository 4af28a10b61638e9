"""Issue 40's baseline: ``twin replay`` and ``twin calibrate`` on logs the twin did not write.

The logs come from the independent simulator kept as a test fixture,
``tests/foreign/robot_sim.py`` (equation (1) by RK4 at 1 kHz, its own LQR on its own estimates,
its own IMU and encoders, none of the twin's code; see its docstring):

* **A** (the issue's "independent simulator"): 20 logs of 20 s (seeds 0–19): 200 Hz, 5 ms
  interval means delivered 5 ms late, 1 % scale factors, a true plant of m_b × 1.15, l × 0.9,
  d_b and d_w × 1.5, drives, turns and 3–6 N pushes. ``twin replay`` with the EKF, the
  complementary filter and kalman2: the Monte Carlo mean NEES against its 95 % bounds, the
  logs outside one run's interval, NIS/dof, θ RMSE, rejected readings, events; and where the
  EKF's excess NEES lies, each state's mean e²/P (the EKF replayed through the Python API with
  its diagnostics, from 0.5 s on as the NEES).
* **A, no scale factors**: the same 20 logs' plants and schedules with every true scale factor
  zero: the NEES, and the forward accelerometer scale factor the EKF learned (its estimate and
  σ at the end of each log).
* **A, clip** (a sharper catch from 0.35–0.45 rad that clips the gyro and the accelerometer)
  and **A, push** (10–12 N pushes): 10 logs each: NEES, the ψ error at the end, rejected
  readings, the "latency changed" events.
* **B** (real-robot-shaped): 5 logs (seeds 0–4) of a 0.8 kg robot: 33 Hz rows decimated from a
  1 kHz loop, an IMU pitched 0.07 rad, sampled voltage commands, vibration noise, a start from
  lying at about 0.5 rad. Replayed with the datasheet noise (version 2: the log leaves its white
  noise out; version 1: what the log's scenario says), and the EKF once more told the real noise
  (version 2: the log's ``sigma``; version 1: sensors.gyro/accel.noise_density set so that the
  per-sample σ is the sidecar's), and with ``--noise datasheet``: NIS/dof, whiteness, rejected
  readings, θ's error 0.5 s after the start. With version 2, also the EKF per log with its
  diagnostics (NEES, where it lies), on those logs and on the same begun 15 ms into the stand-up.

The logs are written in format version 2 (``--format-version 1``: version 1, whose reader
assumes the sensors from a scenario: no accelerometer bias, held commands, mean samples).
* **Calibration**: ``twin calibrate`` on profile-A logs of 30, 45 and 60 s (seeds 100–102):
  each physical parameter's error against the simulator's true plant and whether the truth is
  inside the reported 95 % interval, and the wall time.

Run from the repository root::

    python benchmarks/foreign_logs.py                     # about 25 min on 2 cores
    python benchmarks/foreign_logs.py --quick             # 5/3/2 logs, one 30 s calibration: about 6 min
    python benchmarks/foreign_logs.py --code HEAD         # measure a commit's code (git archive; this
                                                          # checkout's compiled kernels), not the work tree
    python benchmarks/foreign_logs.py --markdown docs/_generated/foreign-logs.md

``--markdown PATH`` also writes the tables to PATH for the documentation (under a line naming the
command, machine, date and commit; see ``benchmarks/published.py``). Every ``twin`` command runs
in a subprocess of its own (``python -m twin.cli``, PYTHONPATH the code measured).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "tests"))

from foreign import robot_sim  # noqa: E402

# issue 40's figures, for the comparison columns
ISSUE = {
    "A": "NEES 22.8 against [9.16, 15.2] over 10 logs, 6 of 10 logs outside one run's interval; NIS/dof 0.98; "
         "θ RMSE 1.00 mrad (0.83–1.14); excess in the accelerometer scale factors (forward e²/P ≈ 6.3, vertical "
         "≈ 3.1) and the pitch gyro bias (≈ 2.0)",
    "zero": "with every true scale factor zero, the EKF learned a forward accelerometer scale of +1.2 % at σ 0.39 %",
    "clip": "a sharper catch that clipped gyro and accelerometer: a permanent ψ offset of 0.017 rad, NEES 125",
    "push": "10–12 N pushes that saturated the accelerometer: NEES 536–1515, up to 421 rejected readings, a false "
            "\"gyro latency changed: now about 15 ms\" event",
    "B": "with the datasheet noise: NIS/dof 89–121, 35–100 % of whiteness lags outside, 282–488 of 351–569 readings "
         "rejected, θ off by 0.03–0.07 rad RMS; told the real noise: NIS/dof 2.3–4.4",
    "cal": "m_b and l within 3 % (truth inside the 95 % interval for m_b in 3/5, for l in 1/5), n_yb +7 … +23 %, "
           "n_zb +88 … +107 % (±2 %, reported as identified), d_b −19 … −51 %, d_w +2 … +5 %, all outside their "
           "intervals; 168–395 s per 30–60 s log",
}
STATES = ("θ", "ψ", "v (IMU point)", "α", "gyro bias y", "gyro bias z", "encoder zero (mean)", "gyro scale y",
          "encoder zero (half-difference)", "gyro scale z", "accel scale x", "accel scale z")
ONE_RUN = (4.40, 23.34)  # the two-sided 95 % interval of one row's χ²₁₂ (estimation.consistency.ONE_RUN_NEES_BOUNDS)
PHYSICAL = ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w")


# ---- running the code measured --------------------------------------------------------------------------
def export(rev: str, into: Path) -> Path:
    """The code of commit ``rev`` (git archive) in ``into``, with this checkout's compiled extensions."""
    from published import export_code

    try:
        return export_code(rev, into)
    except RuntimeError as exc:
        raise SystemExit(str(exc)) from None


def twin(code: Path, args: list, cwd: Path, log: Path) -> float:
    """``python -m twin.cli ARGS`` with the code of ``code``; its output to ``log``; the wall time (s)."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        r = subprocess.run([sys.executable, "-m", "twin.cli", *map(str, args)], cwd=cwd, env=env, stdout=fh,
                           stderr=subprocess.STDOUT)
    if r.returncode != 0:
        raise SystemExit(f"twin {' '.join(map(str, args[:2]))} ... failed (exit {r.returncode}); see {log}")
    return time.perf_counter() - t0


def per_state(code: Path, logs: list, out: Path, cwd: Path) -> dict:
    """:func:`_per_state_main` in a subprocess with the code measured: {log: {...}}."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    r = subprocess.run([sys.executable, __file__, "--_per-state", str(out), *map(str, logs)], cwd=cwd, env=env,
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"the per-state replay failed:\n{r.stderr[-3000:]}")
    return json.loads(out.read_text())


def _per_state_main(out: str, logs: list) -> int:
    """The EKF replayed with its diagnostics on each log: each state's mean e²/P from 0.5 s on, its
    final estimate and σ, and the final ψ error (run with the code measured on sys.path)."""
    from estimation.consistency import filter_truth
    from twin.logs.format import read_log
    from twin.logs.replay import NEES_START, build_for, filter_record, replay

    doc = {}
    for p in logs:
        log = read_log(p)
        est = build_for(log, "ekf")  # (told the log's sampling and, on jittered rows, its periods, as twin replay)
        r = replay(log, est, "ekf", diagnostics=True)
        rec = filter_record(log, r)
        x, P = rec.filter_log["x"], rec.filter_log["P"]
        truth = filter_truth(rec)
        keep = (rec.t >= NEES_START - 1e-9) & np.isfinite(truth).all(axis=1)
        e = x[keep] - truth[keep]
        var = np.diagonal(P[keep], axis1=1, axis2=2)
        from twin.logs.replay import consistency, instants_of

        k = instants_of(log, r.t, log.truth_t)

        c = consistency(r, log)
        ok = (k >= 0) & (k < len(r.estimates))
        th_err = r.estimates[k[ok], 0] - log.truth[ok, 0]
        j = int(np.searchsorted(log.truth_t[ok], log.truth_t[ok][0] + 0.5))
        doc[str(p)] = {"e2_over_p": (e * e / var).mean(axis=0).tolist(), "final_x": x[-1].tolist(),
                       "final_sigma": np.sqrt(np.diagonal(P[-1])).tolist(),
                       "final_truth": truth[-1].tolist(),
                       "psi_error_end": float(r.estimates[k[-1], 2] - log.truth[-1, 2]),
                       "nis_per_dof": c.get("nis_per_dof"), "nees_mean": c.get("nees_mean"),
                       "theta_rmse": float(np.sqrt(np.mean(th_err ** 2))), "theta_error_after_0_5_s": float(th_err[j]),
                       "latency_events": sum(1 for m in r.stats.get("events", []) if "latency changed" in m),
                       "rejected_total": int(r.stats.get("rejected_total", 0))}
    Path(out).write_text(json.dumps(doc))
    return 0


# ---- the logs ---------------------------------------------------------------------------------------------
FORMAT_VERSION = 2  # of the logs written (--format-version)


def make_logs(where: Path, profile: str, seeds, **options) -> list:
    """Logs of ``profile`` (robot_sim.generate with ``options``) in format :data:`FORMAT_VERSION`.
    Version 2 states the sensors' figures; where every true scale factor is zero
    (``scale_sigma=0``) it still states the part's 1 % tolerance, as its owner would (the
    datasheet's figure, not the drawn value)."""
    options.setdefault("version", FORMAT_VERSION)
    paths = []
    for s in seeds:
        p = where / f"{profile.lower()}-{options.get('variant', 'default')}-{s:03d}"
        if options.get("scale_sigma") == 0.0:
            p = p.with_name(p.name + "-noscale")
        if options.get("log_start"):
            p = p.with_name(p.name + f"-from-{options['log_start']:g}s")
        if options.get("noise_figures") is False:
            p = p.with_name(p.name + "-datasheet")
        robot_sim.generate(p, profile, s, **options)
        if options.get("scale_sigma") == 0.0 and options["version"] == 2:
            toml = p / "log.toml"
            toml.write_text(toml.read_text().replace("scale_factor_error = 0.0", "scale_factor_error = 0.01"))
        paths.append(p)
    return paths


def _fmt(v, digits=3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:.{digits}g}"


def _range(vals, scale=1.0, digits=3) -> str:
    vals = [v * scale for v in vals if v is not None and math.isfinite(v)]
    if not vals:
        return "–"
    return f"{_fmt(float(np.mean(vals)), digits)} ({_fmt(min(vals), digits)}–{_fmt(max(vals), digits)})"


def replay_group(code: Path, logs: list, kinds: str, tmp: Path, name: str, *extra) -> tuple[dict, float, Path]:
    out = tmp / f"replay-{name}"
    wall = twin(code, ["replay", *logs, "--estimator", kinds, *extra, "--out", out], tmp, tmp / f"replay-{name}.txt")
    return json.loads((out / "replay.json").read_text()), wall, out


def estimator_rows(doc: dict, kinds) -> list[str]:
    rows = []
    for kind in kinds:
        ents = [e["estimators"][kind] for e in doc["logs"].values()]
        th = [e["errors"]["theta_rmse_rad"] for e in ents]
        psi = [e["errors"]["psi_rmse_rad"] for e in ents]
        nis = [e["consistency"].get("nis_per_dof") for e in ents]
        nees = [e["consistency"].get("nees_mean") for e in ents]
        outside = sum(1 for v in nees if v is not None and not ONE_RUN[0] <= v <= ONE_RUN[1])
        mc = (doc["estimators"][kind] or {}).get("monte_carlo")
        mc_txt = "–" if not mc else f"{mc['nees_mean']:.3g} in [{mc['nees_bounds'][0]:.3g}, {mc['nees_bounds'][1]:.3g}]"
        events = sum(len(e["events"]) for e in ents)
        latency = sum(1 for e in ents for m in e["events"] if "latency changed" in str(m))
        rows.append(f"| {kind} | {_range(th, 1e3)} | {_range(psi, 1e3)} | {_range(nis)} | {mc_txt} | "
                    f"{'–' if not any(v is not None for v in nees) else f'{outside} of {len(nees)}'} | "
                    f"{sum(e['rejected_total'] for e in ents)} | {events} ({latency}) |")
    return rows


ESTIMATOR_HEAD = ["| estimator | θ RMSE [mrad], mean (range) | ψ RMSE [mrad] | NIS/dof | Monte Carlo mean NEES in its "
                  "95 % bounds | logs outside one run's [4.40, 23.34] | rejected readings (all logs) | events "
                  "(latency-change events) |", "|---|---|---|---|---|---|---|---|"]


def theta_after(rep_dir: Path, doc: dict, kind: str, seconds: float = 0.5) -> dict:
    """{log: |θ̂ − θ| (rad) at the first instant ``seconds`` or more after the replay's first} from
    estimates.csv and the log's truth (as tests/test_ekf_foreign.py reads it)."""
    est: dict = {}
    with open(rep_dir / "estimates.csv", newline="", encoding="utf-8") as fh:
        rd = csv.reader(fh)
        next(rd)
        for row in rd:
            if row[1] == kind:
                est.setdefault(row[0], []).append((float(row[2]), float(row[3])))
    out = {}
    for log, rows in est.items():
        t, th = np.array(rows).T
        truth = np.loadtxt(Path(log) / "truth.csv", delimiter=",", skiprows=1, usecols=(0, 1))
        i = min(int(np.searchsorted(t, t[0] + seconds - 1e-9)), len(t) - 1)
        j = int(np.argmin(np.abs(truth[:, 0] - t[i])))
        out[log] = abs(th[i] - truth[j, 1])
    return out


def told_real_noise(src: Path, dst: Path) -> Path:
    """A copy of profile-B log ``src`` whose scenario tells the estimators the real per-sample noise
    (datasheet white noise and vibration, from robot_sim.json) as a noise density at the log's rate."""
    shutil.copytree(src, dst)
    side = json.loads((src / "robot_sim.json").read_text())
    imu, rate = side["imu"], side["log"]["control_rate_hz"]
    sg = math.hypot(imu["white_sigma_per_sample"][0], imu["vibration_gyro"])
    sa = math.hypot(imu["white_sigma_per_sample"][1], imu["vibration_accel"])
    text = (dst / "log.toml").read_text()
    extra = (f'"sensors.gyro.noise_density={sg / math.sqrt(rate)!r}", '
             f'"sensors.accel.noise_density={sa / math.sqrt(rate)!r}", ')
    text = text.replace("set = [", "set = [" + extra, 1)
    (dst / "log.toml").write_text(text)
    return dst


# ---- main ----------------------------------------------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="5 logs of A, 3 per variant, 2 of B, one 30 s calibration")
    ap.add_argument("--code", metavar="REV", help="measure the code of commit REV (git archive) instead of this "
                    "checkout's work tree")
    ap.add_argument("--no-calibrate", action="store_true", help="leave out the calibrations")
    ap.add_argument("--markdown", metavar="PATH", help="also write the tables to PATH (docs/_generated/...)")
    ap.add_argument("--format-version", type=int, choices=(1, 2), default=2,
                    help="the logs' format version (default 2: they state the sensors' figures, the IMU's sampling "
                         "and mounting and the commands' semantics; 1: the reader assumes them from a scenario)")
    ap.add_argument("--_per-state", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args._per_state:
        return _per_state_main(args._per_state[0], args._per_state[1:])
    global FORMAT_VERSION
    FORMAT_VERSION = args.format_version
    n_a, n_var, n_b = (5, 3, 2) if args.quick else (20, 10, 5)
    cal_lengths = (30.0,) if args.quick else (30.0, 45.0, 60.0)
    table: list[str] = []

    def row(line: str = "") -> None:
        print(line, flush=True)
        table.append(line)

    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        code = ROOT if args.code is None else export(args.code, tmp)
        what = "this checkout's work tree" if args.code is None else f"commit {args.code} (git archive)"
        if args.code is not None:
            r = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", args.code], capture_output=True,
                               text=True)
            what = f"commit {r.stdout.strip() or args.code} (git archive, this checkout's compiled kernels)"
        logs = tmp / "logs"
        row(f"Logs from the independent simulator `tests/foreign/robot_sim.py` (none of the twin's code; "
            f"format version {FORMAT_VERSION}), replayed and calibrated by the code of {what}, each `twin` command in a "
            f"subprocess of its own. The figures first reported (on other logs of the same kind) are quoted "
            f"under each table.")
        row()

        # ---- A -----------------------------------------------------------------------------------------
        t0 = time.perf_counter()
        a_logs = make_logs(logs, "A", range(n_a))
        gen = (time.perf_counter() - t0) / n_a
        doc, wall, _ = replay_group(code, a_logs, "ekf,complementary,kalman2", tmp, "a")
        row(f"**Profile A**, {n_a} logs of 20 s (seeds 0–{n_a - 1}; {gen:.2f} s each to generate): "
            f"`twin replay LOGS --estimator ekf,complementary,kalman2` ({wall:.0f} s)")
        row()
        for line in ESTIMATOR_HEAD + estimator_rows(doc, ("ekf", "complementary", "kalman2")):
            row(line)
        row()
        row(f"First reported: {ISSUE['A']}.")
        row()
        ps = per_state(code, a_logs, tmp / "per-state-a.json", tmp)
        e2p = np.array([v["e2_over_p"] for v in ps.values()])
        row(f"Where the EKF's NEES lies: each state's mean e²/P over the {n_a} logs (1 for an honest state; the NEES "
            f"is their sum with the correlations), from 0.5 s on:")
        row()
        row("| " + " | ".join(STATES) + " |")
        row("|" + "---|" * len(STATES))
        row("| " + " | ".join(f"{v:.2f}" for v in e2p.mean(axis=0)) + " |")
        row()

        # ---- A without the accelerometer's bias -------------------------------------------------------
        nb_logs = make_logs(logs / "no-accel-bias", "A", range(n_a), accel_bias_sigma=0.0)
        nbdoc, wall, _ = replay_group(code, nb_logs, "ekf", tmp, "no-accel-bias")
        nbps = per_state(code, nb_logs, tmp / "per-state-no-accel-bias.json", tmp)
        nb2p = np.array([v["e2_over_p"] for v in nbps.values()]).mean(axis=0)
        row(f"**Profile A without the accelerometer's bias** (the same {n_a} logs but for a constant accelerometer "
            f"bias of σ {robot_sim.ImuModel().accel_bias_sigma:g} m/s² per axis, which the EKF carries as a consider "
            f"parameter of θ and the encoder zero where the log states it (version 2), and a version-1 log cannot; "
            f"{wall:.0f} s):")
        row()
        for line in ESTIMATOR_HEAD + estimator_rows(nbdoc, ("ekf",)):
            row(line)
        row()
        row("Mean e²/P: " + ", ".join(f"{n} {v:.2f}" for n, v in zip(STATES, nb2p)) + ".")
        row()

        # ---- A without scale factors -----------------------------------------------------------------
        z_logs = make_logs(logs, "A", range(n_a), scale_sigma=0.0)
        zdoc, wall, _ = replay_group(code, z_logs, "ekf", tmp, "zero")
        zps = per_state(code, z_logs, tmp / "per-state-zero.json", tmp)
        sx = [v["final_x"][10] for v in zps.values()]
        sxs = [v["final_sigma"][10] for v in zps.values()]
        sz = [v["final_x"][11] for v in zps.values()]
        row(f"**Profile A with every true scale factor zero** (the same {n_a} plants and schedules; {wall:.0f} s):")
        row()
        for line in ESTIMATOR_HEAD + estimator_rows(zdoc, ("ekf",)):
            row(line)
        row()
        z2p = np.array([v["e2_over_p"] for v in zps.values()]).mean(axis=0)
        row(f"The forward accelerometer scale factor the EKF ends with (truth 0): {_range(sx, 100)} %, its σ "
            f"{_range(sxs, 100)} %; the vertical one {_range(sz, 100)} %. Mean e²/P: accel scale x "
            f"{z2p[10]:.2f}, accel scale z {z2p[11]:.2f}, gyro bias y {z2p[4]:.2f}, gyro scale y {z2p[7]:.2f}.")
        row()
        row(f"First reported: {ISSUE['zero']}.")
        row()

        # ---- variants ------------------------------------------------------------------------------------
        for variant, seeds in (("clip", range(200, 200 + n_var)), ("push", range(300, 300 + n_var))):
            v_logs = make_logs(logs, "A", seeds, variant=variant)
            vdoc, wall, _ = replay_group(code, v_logs, "ekf", tmp, variant)
            vps = per_state(code, v_logs, tmp / f"per-state-{variant}.json", tmp)
            clips = [json.loads((p / "robot_sim.json").read_text())["clipped_samples"] for p in v_logs]
            g = [sum(c["gyro"]) for c in clips]
            a = [sum(c["accel"]) for c in clips]
            nees = [e["estimators"]["ekf"]["consistency"].get("nees_mean") for e in vdoc["logs"].values()]
            psi_end = [abs(v["psi_error_end"]) for v in vps.values()]
            events = [m for e in vdoc["logs"].values() for m in e["estimators"]["ekf"]["events"]]
            latency = [m for m in events if "latency changed" in str(m)]
            what_v = ("a catch from 0.35–0.45 rad with stiffer gains" if variant == "clip" else "pushes of 10–12 N")
            row(f"**Profile A, {variant}** ({what_v}), {n_var} logs of 20 s (seeds {seeds[0]}–{seeds[-1]}; "
                f"{wall:.0f} s); clipped samples per log: gyro {_range(g)}, accelerometer {_range(a)}:")
            row()
            for line in ESTIMATOR_HEAD + estimator_rows(vdoc, ("ekf",)):
                row(line)
            row()
            row(f"Per log: NEES {_range(nees)}; |ψ̂ − ψ| at the end {_range(psi_end, 1e3)} mrad; "
                f"{len(latency)} latency-change event(s)"
                + (f", e.g. \"{latency[0]}\"" if latency else "") + ".")
            row()
            row(f"First reported: {ISSUE[variant]}.")
            row()

        # ---- B -------------------------------------------------------------------------------------------------
        if FORMAT_VERSION == 2:  # without noise figures (the replay measures them), and with the true ones
            b_logs = make_logs(logs, "B", range(n_b), noise_figures=False)
            told = make_logs(logs, "B", range(n_b))
        else:
            b_logs = make_logs(logs, "B", range(n_b))
            told = [told_real_noise(p, p.with_name(p.name + "-told")) for p in b_logs]
        bdoc, wall, bdir = replay_group(code, b_logs, "ekf,complementary,kalman2", tmp, "b")
        ddoc, wall_d, ddir = replay_group(code, b_logs, "ekf,kalman2", tmp, "b-datasheet", "--noise", "datasheet")
        tdoc, wall_t, tdir = replay_group(code, told, "ekf,kalman2", tmp, "b-told")
        durations = [json.loads((p / "robot_sim.json").read_text())["duration_s"] for p in b_logs]
        measured = "measured from the log" if FORMAT_VERSION == 2 else "the log's scenario's (datasheet)"
        row(f"**Profile B**, {n_b} logs of {min(durations):.1f}–{max(durations):.1f} s (seeds 0–{n_b - 1}): "
            f"`twin replay` on logs without noise figures ({measured}; {wall:.0f} s), the same with "
            f"`--noise datasheet` ({wall_d:.0f} s), and on logs that give the real per-sample noise ({wall_t:.0f} s):")
        row()
        row("| estimator | noise | NIS/dof, mean (range) | whiteness lags outside | rejected readings of IMU rows, "
            "per log | θ RMSE [rad] | θ's error 0.5 s after the start, absolute [rad] |")
        row("|---|---|---|---|---|---|---|")
        for d, rdir, noise, kinds in ((bdoc, bdir, measured, ("ekf", "complementary", "kalman2")),
                                      (ddoc, ddir, "datasheet", ("ekf", "kalman2")),
                                      (tdoc, tdir, "real (told)", ("ekf", "kalman2"))):
            for kind in kinds:
                ents = {k: e["estimators"][kind] for k, e in d["logs"].items()}
                nis = [e["consistency"].get("nis_per_dof") for e in ents.values()]
                white = [e["consistency"].get("whiteness_outside_fraction") for e in ents.values()]
                rej = [f"{e['rejected_total']}/{sum(1 for _ in open(Path(k) / 'imu.csv')) - 1}"
                       for k, e in ents.items()]
                th = [e["errors"]["theta_rmse_rad"] for e in ents.values()]
                after = theta_after(rdir, d, kind)
                row(f"| {kind} | {noise} | {_range(nis)} | "
                    f"{_range(white, 100) + ' %' if any(w is not None for w in white) else '–'} | {', '.join(rej)} | "
                    f"{_range(th)} | {_range(list(after.values()))} |")
        row()
        row(f"First reported: {ISSUE['B']}. The simulator's IMU is mounted pitched 0.07 rad, which version 1 cannot say: "
            f"a filter that trusts the accelerometer's tilt is off by about that much.")
        row()
        if FORMAT_VERSION == 2:
            # the EKF per log, with its diagnostics (the NEES: the logs carry the state truth at their rows)
            m_logs = make_logs(logs, "B", range(n_b), log_start=0.015)
            row(f"**Profile B, the EKF per log** (as `twin replay` builds it: point samples rebuilt as interval means, "
                f"their shared noise carried, the rows the instants with each step over its own period, the latency "
                f"watch off for sampled commands), the real noise, the same {n_b} logs and the same begun 15 ms into "
                f"the stand-up (θ̇ about −4 rad/s at the first row). The NEES from 0.5 s on, with the mean e²/P of ψ and "
                f"the encoder zero (mean) where it lies:")
            row()
            row("| logs | NIS/dof, mean (range) | θ RMSE [rad] | θ's error 0.5 s after the start, absolute [rad], per "
                "log | NEES per log | e²/P of θ, ψ, encoder zero, mean | latency-change events | rejected readings "
                "(all logs) |")
            row("|---|---|---|---|---|---|---|---|")
            for name, group in (("from lying still", told), ("begun mid-motion", m_logs)):
                ps_b = per_state(code, group, tmp / f"per-state-b-{len(name)}.json", tmp)
                vals = list(ps_b.values())
                after = ", ".join(f"{abs(v['theta_error_after_0_5_s']):.3f}" for v in vals)
                nees = ", ".join(_fmt(v["nees_mean"]) for v in vals)
                e2 = np.mean([v["e2_over_p"] for v in vals], axis=0)
                row(f"| {name} | {_range([v['nis_per_dof'] for v in vals])} | "
                    f"{_range([v['theta_rmse'] for v in vals])} | {after} | {nees} | "
                    f"{e2[0]:.2f}, {e2[1]:.2f}, {e2[6]:.2f} | "
                    f"{sum(v['latency_events'] for v in vals)} | {sum(v['rejected_total'] for v in vals)} |")
            row()

        # ---- calibration -------------------------------------------------------------------------------------
        if not args.no_calibrate:
            row(f"**`twin calibrate LOG`** (defaults) on profile-A logs of {', '.join(f'{d:g}' for d in cal_lengths)} "
                f"s (seeds 100–{100 + len(cal_lengths) - 1}): each physical parameter's error against the "
                f"simulator's true plant, ✓ where the truth is inside the reported 95 % interval, (n) where the "
                f"report says not identified:")
            row()
            row("| log | wall [s] | " + " | ".join(PHYSICAL) + " |")
            row("|---|---|" + "---|" * len(PHYSICAL))
            for i, dur in enumerate(cal_lengths):
                p = make_logs(logs / f"cal-{dur:g}", "A", [100 + i], duration=dur)[0]
                out = tmp / f"cal-{i}"
                wall = twin(code, ["calibrate", p, "--out", out], tmp, tmp / f"cal-{i}.txt")
                rep = json.loads((out / "report.json").read_text())
                true = json.loads((p / "robot_sim.json").read_text())["plant_true"]
                cells = []
                for name in PHYSICAL:
                    q = rep["parameters"].get(name)
                    if q is None:
                        cells.append("not fitted")
                        continue
                    err = q["value"] / true[name] - 1.0
                    inside = q["ci95"][0] <= true[name] <= q["ci95"][1]
                    cells.append(f"{err * 100:+.1f} % {'✓' if inside else '✗'}{'' if q['identifiable'] else ' (n)'}")
                row(f"| {dur:g} s | {wall:.0f} | " + " | ".join(cells) + " |")
            row()
            row(f"First reported: {ISSUE['cal']}.")
    print(f"\nwall time {time.perf_counter() - t_all:.0f} s")
    if args.markdown:
        from published import write_markdown

        write_markdown(args.markdown, "\n".join(table), argv=None if argv is None else [sys.argv[0], *argv])
    return 0


if __name__ == "__main__":
    sys.exit(main())
