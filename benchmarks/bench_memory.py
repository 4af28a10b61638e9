"""Peak memory (resident set) of long ``twin run``s, with and without ``--log-every``, against
the code before the logs were stored as arrays.

Run from the repository root::

    python benchmarks/bench_memory.py             # 600 s and 3600 s runs: about 20 min
    python benchmarks/bench_memory.py --quick     # 60 s and 360 s runs: about 3 min
    python benchmarks/bench_memory.py --no-before # this checkout only
    python benchmarks/bench_memory.py -- --controller it2,t1   # more options for every 'twin run'

What is measured: ``twin run paper-exp2 --controller it2 --no-video --duration D`` in a
subprocess of its own, its peak resident set size from ``os.wait4`` (what ``/usr/bin/time -v``
reports as "Maximum resident set size"), its wall time and the trajectory file's size, for

* **this checkout**: every step in trajectory.csv (the default) and ``--log-every 20`` (10 Hz
  at 200 Hz control: the reference a long run is meant to use), at both durations; at the
  longer one also ``--log-format csv.gz`` and ``--log-every 10`` in both formats (file sizes);
* **before**: the same run on the code of commit ``--before`` (default 3bd0277, the last one
  that kept every control step as Python tuples and Measurement objects), exported with
  ``git archive`` beside this checkout's compiled kernels.

Target: an hour (3600 s simulated) under 1 GB peak. The growth per simulated hour is the
difference between the two durations, scaled to an hour; what a run costs at t = 0 (the
interpreter, PyBullet, numpy, matplotlib for the figure) is the rest.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGET_BYTES = 1e9


def peak_run(code: Path, out: Path, duration: float, extra=()) -> dict:
    """Run ``twin run`` from ``code`` in a child process; its peak RSS (bytes), wall time and files."""
    env = dict(os.environ, PYTHONPATH=str(code))
    cmd = [sys.executable, "-m", "twin.cli", "run", "paper-exp2", "--controller", "it2", "--no-video",
           "--duration", f"{duration:g}", "--out", str(out), *extra]
    t0 = time.perf_counter()
    with open(out.parent / f"{out.name}.log", "w") as log:
        p = subprocess.Popen(cmd, env=env, cwd=tempfile.gettempdir(), stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}); see {out.parent / out.name}.log")
    traj = next(f for f in (out / "trajectory.csv", out / "trajectory.csv.gz") if f.exists())
    return {"rss": usage.ru_maxrss * 1024, "wall": wall, "file": traj.name, "size": traj.stat().st_size}


def export_before(rev: str, into: Path) -> Path | None:
    """The code of ``rev`` in ``into`` with this checkout's compiled extensions, or None without git."""
    from published import export_code

    if shutil.which("git") is None:
        return None
    try:
        return export_code(rev, into, "before")
    except RuntimeError as exc:
        print(f"(no 'before' reference: {exc})")
        return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="60 s and 360 s runs instead of 600 s and 3600 s")
    ap.add_argument("--before", default="3bd0277", metavar="REV", help="the reference commit (default: %(default)s)")
    ap.add_argument("--no-before", action="store_true", help="measure this checkout only")
    ap.add_argument("extra", nargs="*", metavar="TWIN-RUN-OPTION",
                    help="more options for every 'twin run', after --, e.g. -- --controller it2,t1")
    args = ap.parse_args(argv)
    short, long = (60.0, 360.0) if args.quick else (600.0, 3600.0)
    print(f"peak resident memory of 'twin run paper-exp2 --controller it2 --no-video --duration D"
          f"{''.join(' ' + a for a in args.extra)}' "
          f"(one subprocess per run, os.wait4)\nPython {sys.version.split()[0]}, {os.cpu_count()} cores\n")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        before = None if args.no_before else export_before(args.before, tmp)
        both, once = (short, long), (long,)
        cases = [("this checkout, every step, csv", ROOT, (), both),
                 ("this checkout, --log-every 20, csv", ROOT, ("--log-every", "20"), both),
                 ("this checkout, every step, csv.gz", ROOT, ("--log-format", "csv.gz"), once),
                 ("this checkout, --log-every 10, csv", ROOT, ("--log-every", "10"), once),
                 ("this checkout, --log-every 10, csv.gz", ROOT, ("--log-every", "10", "--log-format", "csv.gz"),
                  once)]
        if before is not None:
            cases.insert(0, (f"before ({args.before}), every step, csv", before, (), both))
        for label, code, extra, durations in cases:
            for d in durations:
                out = tmp / f"run{len(rows)}"
                r = peak_run(code, out, d, extra + tuple(args.extra))
                shutil.rmtree(out)
                rows.append((label, d, r))
                print(f"  {label:40} {d:6g} s  peak RSS {r['rss'] / 1e6:7.0f} MB  {r['file']:18} "
                      f"{r['size'] / 1e6:8.1f} MB  wall {r['wall']:6.1f} s", flush=True)
    print("\ngrowth per simulated hour (from the two durations):")
    for label in dict.fromkeys(lab for lab, _, _ in rows):
        got = {d: r["rss"] for lab, d, r in rows if lab == label}
        if len(got) == 2:
            per_hour = (got[long] - got[short]) / (long - short) * 3600.0
            hour = got[long] + (3600.0 - long) * per_hour / 3600.0  # measured, or extrapolated from --quick
            print(f"  {label:40} {per_hour / 1e6:7.0f} MB per simulated hour; an hour: {hour / 1e6:.0f} MB "
                  f"({'measured' if long == 3600.0 else 'extrapolated'}), "
                  f"{'within' if hour < TARGET_BYTES else 'over'} the 1 GB target")
    return 0


if __name__ == "__main__":
    sys.exit(main())
