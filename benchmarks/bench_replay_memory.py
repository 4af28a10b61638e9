"""Wall time and peak memory (resident set) of ``twin replay`` on long sensor logs, 10⁴, 10⁵ and
10⁶ rows per stream, against the code before the replay streamed its log.

Run from the repository root::

    python benchmarks/bench_replay_memory.py                # 10⁴, 10⁵, 10⁶ rows: about 6 min
    python benchmarks/bench_replay_memory.py --quick        # 10³, 10⁴, 10⁵ rows: about 1 min
    python benchmarks/bench_replay_memory.py --no-before    # this checkout only
    python benchmarks/bench_replay_memory.py --markdown docs/_generated/replay-memory.md

``--markdown PATH`` also writes the table to PATH for the documentation (under a line naming the
command, machine, date and commit; see ``benchmarks/published.py``).

The logs: the twin's own (``twin run paper-exp1 --controller it2 --duration 50 --log-sensors``:
10 001 rows in each of imu, encoders, commands, truth with the state truth, duty), repeated end
to end on one clock to the length wanted (the robot jumps back to its start at each joint,
which the EKF takes as an encoder glitch; the cost per instant is what is measured here). What
is measured: ``twin replay LOG --estimator ekf`` in a subprocess of its own, its peak resident
set size from ``os.wait4`` (what ``/usr/bin/time -v`` reports as "Maximum resident set size")
and its wall time (reading the log, the replay, replay.json, estimates.csv, the figure), for

* **this checkout**, and
* **before**: the same command on the code of commit ``--before`` (default 7854716, the last
  one that read every row into a list and kept a Measurement and the EKF's diagnostics, its
  12 × 12 covariance among them, per instant), exported with ``git archive`` beside this
  checkout's compiled kernels; up to ``--before-max-rows`` rows (10⁶ rows took 8.7 GB).

Both write the same replay.json (but the wall time per step) and estimates.csv, byte for byte:
checked and said for each log.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from bench_memory import export_before  # noqa: E402
from bench_twin import cpu_model  # noqa: E402

STREAMS = ("imu", "encoders", "commands", "truth", "duty")
BASE_SECONDS = 50.0  # the twin run that is repeated: 10 001 rows per stream at 200 Hz


def twin_log(tmp: Path) -> Path:
    """The twin's log of a BASE_SECONDS run (this checkout's twin run)."""
    out = tmp / "run"
    cmd = [sys.executable, "-m", "twin.cli", "run", "paper-exp1", "--controller", "it2", "--duration",
           f"{BASE_SECONDS:g}", "--log-sensors", "--no-video", "--out", str(out)]
    r = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    return out / "sensor-logs" / "it2"


def repeated(src: Path, dst: Path, rows: int) -> Path:
    """``src``'s streams repeated end to end, on one clock, to ``rows`` data rows each."""
    dst.mkdir(parents=True)
    shutil.copy2(src / "log.toml", dst / "log.toml")
    for name in STREAMS:
        lines = (src / f"{name}.csv").read_text(encoding="utf-8").splitlines()
        head, body = lines[0], [ln.split(",", 1) for ln in lines[1:]]
        times = [float(t) for t, _ in body]
        span = times[-1] + (times[-1] - times[-2])  # the next period after the last row
        with open(dst / f"{name}.csv", "w", encoding="utf-8") as fh:
            fh.write(head + "\n")
            k = 0
            while k < rows:
                off = (k // len(body)) * span
                for t, (_, rest) in zip(times, body):
                    if k >= rows:
                        break
                    fh.write(f"{t + off!r},{rest}\n")
                    k += 1
    return dst


def peak_replay(code: Path, log: Path, out: Path) -> dict:
    """``twin replay LOG --estimator ekf --out OUT`` from ``code`` in a child process: wall time, peak RSS."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    cmd = [sys.executable, "-m", "twin.cli", "replay", str(log), "--estimator", "ekf", "--out", str(out)]
    t0 = time.perf_counter()
    with open(out.parent / f"{out.name}.log", "w") as fh:
        p = subprocess.Popen(cmd, env=env, cwd=out.parent, stdout=fh, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(cmd)} failed; see {out.parent / out.name}.log")
    doc = json.loads((out / "replay.json").read_text())
    entry = next(iter(doc["logs"].values()))
    return {"wall": wall, "rss": usage.ru_maxrss * 1024, "instants": entry["instants"],
            "step_us": entry["estimators"]["ekf"]["step_us"]}


def same_outputs(a: Path, b: Path) -> bool:
    """replay.json (but the wall time per step) and estimates.csv of two replays of one log, equal."""
    def doc(p: Path) -> dict:
        d = json.loads((p / "replay.json").read_text())
        for entry in d["logs"].values():
            for e in entry["estimators"].values():
                e.pop("step_us", None)
        return d

    return doc(a) == doc(b) and (a / "estimates.csv").read_bytes() == (b / "estimates.csv").read_bytes()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="10³, 10⁴ and 10⁵ rows instead of 10⁴, 10⁵ and 10⁶")
    ap.add_argument("--before", default="7854716", metavar="REV", help="the reference commit (default: %(default)s)")
    ap.add_argument("--no-before", action="store_true", help="measure this checkout only")
    ap.add_argument("--before-max-rows", type=int, default=1_000_000, metavar="N",
                    help="replay the reference only on logs of at most N rows (default: %(default)s)")
    ap.add_argument("--markdown", metavar="PATH", help="also write the table to PATH (docs/_generated/...)")
    args = ap.parse_args(argv)
    sizes = (1_000, 10_000, 100_000) if args.quick else (10_000, 100_000, 1_000_000)
    table: list[str] = []

    def row(line: str = "") -> None:
        print(line, flush=True)
        table.append(line)

    print(f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs; Python {sys.version.split()[0]}; "
          f"date {time.strftime('%Y-%m-%d')}\n")
    row(f"`twin replay LOG --estimator ekf`, one process per replay (peak resident set from `os.wait4`); the "
        f"log: the twin's own of a {BASE_SECONDS:g} s run of paper-exp1 (IT2, 200 Hz, the state truth and the "
        f"duty included) repeated to N rows in each of its five streams. Wall time: reading, replaying, "
        f"replay.json, estimates.csv and the figure; growth: the peak's growth per control instant from the "
        f"shorter log before; µs per instant: the EKF's own cost per step (its diagnostics included).")
    row()
    row("| rows per stream | code | wall [s] | peak RSS [MB] | growth [bytes per instant] | EKF µs per instant | "
        "same output |")
    row("|---|---|---|---|---|---|---|")
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        before = None if args.no_before else export_before(args.before, tmp)
        base = twin_log(tmp)
        codes = [("this checkout", ROOT)] + ([] if before is None else [(f"before ({args.before})", before)])
        last = {}  # code -> (instants, peak RSS) of the shorter log
        for n in sizes:
            log = repeated(base, tmp / f"log-{n}", n)
            outs = {}
            for label, code in codes:
                if code is before and n > args.before_max_rows:
                    row(f"| {n:,} | {label} | – | – | – | – | not run (--before-max-rows) |")
                    continue
                out = tmp / f"out-{n}-{len(outs)}"
                r = peak_replay(code, log, out)
                outs[label] = out
                same = "–" if len(outs) == 1 else ("yes" if same_outputs(outs["this checkout"], out) else "**no**")
                growth = "–" if label not in last else \
                    f"{(r['rss'] - last[label][1]) / (r['instants'] - last[label][0]):.0f}"
                last[label] = (r["instants"], r["rss"])
                row(f"| {n:,} | {label} | {r['wall']:.1f} | {r['rss'] / 1e6:.0f} | {growth} | {r['step_us']:.1f} | "
                    f"{same} |")
            for out in outs.values():
                shutil.rmtree(out)
            shutil.rmtree(log)
    print(f"\nwall time {time.perf_counter() - t_all:.0f} s")
    if args.markdown:
        from published import write_markdown

        write_markdown(args.markdown, "\n".join(table), argv=None if argv is None else [sys.argv[0], *argv])
    return 0


if __name__ == "__main__":
    sys.exit(main())
