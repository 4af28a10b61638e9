"""Robot logs, and the other files the twin reads back, as hostile input (issue 39).

What a sensor log may ask of the twin is bounded (twin/logs/bounds.py): no allocation from an
unchecked timestamp, regular files only, of bounded size, inside the log's directory; JSON and
TOML of bounded nesting (twin/inputs.py). Each refusal is one line naming the file, the row or
key and what is allowed, and quotes nothing of a file that is not the log's. ``twin replay``
keeps no object per control instant: its memory grows by a few hundred bytes an instant
(the 10⁶-row figures are benchmarks/bench_replay_memory.py's).

The cases that exhaust memory or hang on a reader without bounds run in a child process with
its address space capped and an alarm per case, so that the code before this change fails
them quickly instead of taking the machine down.
"""
from __future__ import annotations

import hashlib
import json
import os
import resource
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from twin.errors import TwinError
from twin.logs.format import read_log
from twin.scenarios import load_scenario

from test_sensor_logs import MANIFEST  # the smallest valid log.toml

HERE = Path(__file__).resolve().parent
CHILD_MEMORY = 3 << 30  # bytes of address space a child may take: a reader without bounds fails fast
CASE_SECONDS = 20  # a case that takes longer hangs


def write_log(d: Path, n: int = 201, moving: bool = False, manifest: str = MANIFEST) -> Path:
    """A robot standing still for n control instants at 200 Hz (``moving``: the wheels turn
    back and forth, so the EKF's encoder updates and innovations are exercised)."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "log.toml").write_text(manifest, encoding="utf-8")
    rng = np.random.default_rng(3)
    t = (np.arange(n) / 200.0).tolist()
    gyro = rng.normal(0.0, 1e-3, (n, 3)).tolist()
    acc = (np.array([-0.49, 0.0, 9.8]) + rng.normal(0.0, 0.02, (n, 3))).tolist()
    counts = np.round(20.0 * np.sin(np.arange(n) / 40.0)).astype(int).tolist() if moving else [0] * n
    with open(d / "imu.csv", "w", encoding="utf-8") as fh:
        fh.write("t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n")
        fh.writelines(f"{t[k]!r},{g[0]!r},{g[1]!r},{g[2]!r},{a[0]!r},{a[1]!r},{a[2]!r}\n"
                      for k, g, a in zip(range(n), gyro, acc))
    with open(d / "encoders.csv", "w", encoding="utf-8") as fh:
        fh.write("t,left,right\n")
        fh.writelines(f"{t[k]!r},{counts[k]},{counts[k]}\n" for k in range(n))
    with open(d / "commands.csv", "w", encoding="utf-8") as fh:
        fh.write("t,ul,ur\n")
        fh.writelines(f"{t[k]!r},0.0,0.0\n" for k in range(n))
    with open(d / "truth.csv", "w", encoding="utf-8") as fh:
        fh.write("t,theta,theta_dot,psi,psi_dot,alpha,alpha_dot\n")
        fh.writelines(f"{t[k]!r},0.05,0.0,0.0,0.0,0.0,0.0\n" for k in range(n))
    return d


def one_line(exc: pytest.ExceptionInfo | BaseException, *fragments: str) -> str:
    msg = str(exc.value if isinstance(exc, pytest.ExceptionInfo) else exc)
    assert "\n" not in msg and msg.isprintable(), msg
    for f in fragments:
        assert f in msg, (f, msg)
    return msg


def edit_row(path: Path, row: int, text: str) -> None:
    """Row ``row`` (1: the header) of a CSV file replaced by ``text``."""
    lines = path.read_text(encoding="utf-8").splitlines()
    lines[row - 1] = text
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    """A log that reads and replays (copied by the tests that break it)."""
    d = write_log(tmp_path_factory.mktemp("good") / "log")
    read_log(d)  # the scenario's design solved once for this module's process
    return d


def copy_log(src: Path, dst: Path) -> Path:
    dst.mkdir(parents=True)
    for f in src.iterdir():
        (dst / f.name).write_bytes(f.read_bytes())
    return dst


# ---- in a capped child: what exhausted the memory or hung ---------------------------------------------------------

CHILD = textwrap.dedent("""
    import json, resource, signal, sys
    resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))

    class Hung(BaseException):  # not an OSError: no reader's "cannot be read" may take it for one
        pass

    def _alarm(*_):
        raise Hung("hung")

    signal.signal(signal.SIGALRM, _alarm)
    from twin.errors import TwinError
    from twin.logs.format import read_log
    from twin.scenarios import load_scenario

    for name, kind, target in json.loads(sys.argv[1]):
        signal.alarm({seconds})
        try:
            read_log(target) if kind == "log" else load_scenario(target)
            out = {{"outcome": "ok"}}
        except TwinError as exc:
            out = {{"outcome": "error", "message": str(exc)}}
        except BaseException as exc:
            out = {{"outcome": "crash", "message": type(exc).__name__ + ": " + str(exc)[:200]}}
        finally:
            signal.alarm(0)
        print(json.dumps({{"case": name, **out}}), flush=True)
""")


def in_capped_child(cases) -> dict:
    """{case: outcome} of each (name, "log" or "scenario", path) read in one child process with
    its address space capped at CHILD_MEMORY and CASE_SECONDS per case."""
    code = CHILD.format(limit=CHILD_MEMORY, seconds=CASE_SECONDS)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, "-c", code, json.dumps([[n, k, str(p)] for n, k, p in cases])],
                       capture_output=True, text=True, env=env, timeout=CASE_SECONDS * (len(cases) + 2))
    got = {}
    for line in r.stdout.splitlines():
        rec = json.loads(line)
        got[rec.pop("case")] = rec
    assert set(got) == {n for n, _, _ in cases}, (r.returncode, r.stdout, r.stderr[-2000:])
    return got


def test_devices_fifos_and_huge_files_are_refused_before_they_are_read(good, tmp_path):
    """A scenario beside the log (or a scenario file, or its base) that is /dev/zero was read
    until MemoryError; a FIFO hung; a huge stream was read whole. Each is one line now."""
    cases = []
    zero = copy_log(good, tmp_path / "zero")
    (zero / "log.toml").write_text(MANIFEST + 'scenario = "scenario.toml"\n', encoding="utf-8")
    (zero / "scenario.toml").symlink_to("/dev/zero")
    cases.append(("log scenario /dev/zero", "log", zero))
    fifo = copy_log(good, tmp_path / "fifo")
    (fifo / "log.toml").write_text(MANIFEST + 'scenario = "scenario.toml"\n', encoding="utf-8")
    os.mkfifo(fifo / "scenario.toml")
    cases.append(("log scenario FIFO", "log", fifo))
    os.mkfifo(tmp_path / "pipe.toml")
    cases.append(("scenario FIFO", "scenario", tmp_path / "pipe.toml"))
    (tmp_path / "devzero.toml").symlink_to("/dev/zero")
    cases.append(("scenario /dev/zero", "scenario", tmp_path / "devzero.toml"))
    (tmp_path / "derived.toml").write_text('base = "devzero.toml"\nduration = 1.0\n', encoding="utf-8")
    cases.append(("base /dev/zero", "scenario", tmp_path / "derived.toml"))
    big = copy_log(good, tmp_path / "big")
    with open(big / "truth.csv", "r+b") as fh:
        fh.truncate(5 << 30)  # 5 GiB, sparse: no disk used
    cases.append(("stream of 5 GiB", "log", big))
    huge = copy_log(good, tmp_path / "huge")
    with open(huge / "log.toml", "ab") as fh:
        fh.truncate(3 << 30)
    cases.append(("manifest of 3 GiB", "log", huge))
    got = in_capped_child(cases)
    expect = {"log scenario /dev/zero": ["scenario.toml: leads out of"],  # not the log's: refused before it is opened
              "log scenario FIFO": ["scenario.toml", "a FIFO (named pipe), not a regular file"],
              "scenario FIFO": ["pipe.toml", "a FIFO (named pipe), not a regular file"],
              "scenario /dev/zero": ["devzero.toml", "a character device, not a regular file"],
              "base /dev/zero": ["derived.toml: base:", "a character device"],
              "stream of 5 GiB": ["truth.csv", "5.37 GB; allowed: a stream of at most 4.29 GB"],
              "manifest of 3 GiB": ["log.toml", "3.22 GB; allowed: a sensor log's manifest (log.toml) of at most"]}
    for name, fragments in expect.items():
        assert got[name]["outcome"] == "error", (name, got[name])
        one_line(TwinError(got[name]["message"]), *fragments)


def test_a_command_far_in_the_future_is_one_line_not_a_time_step_per_period(good, tmp_path):
    """One commands.csv row at t = 1e12 s made twin replay build a time step per control period
    up to it (2·10¹⁴): out of memory. Now the row is named, and nothing is written."""
    d = copy_log(good, tmp_path / "future")
    with open(d / "commands.csv", "a", encoding="utf-8") as fh:
        fh.write("1e12,0.0,0.0\n")

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (CHILD_MEMORY, CHILD_MEMORY))

    r = subprocess.run([sys.executable, "-m", "twin.cli", "replay", str(d), "--out", str(tmp_path / "out")],
                       capture_output=True, text=True, preexec_fn=cap, timeout=120,
                       env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and line.startswith("error: "), line
    assert f"{d / 'commands.csv'}: row 203: t = 1000000000000.0 s; allowed: |t| at most 4e+09 s" in line
    assert not (tmp_path / "out").exists()


# ---- bounds on what a log's rows ask for ---------------------------------------------------------------------------

@pytest.mark.parametrize("stream, row, text, fragments", [
    # a reading at 1e300 s overflowed int64 and landed at instant 0: exit 0, every estimate wrong
    ("imu.csv", 202, "1e300,0.0,0.0,0.0,-0.49,0.0,9.8",
     ["imu.csv: row 202: t = 1e+300 s; allowed: |t| at most 4e+09 s"]),
    ("encoders.csv", 30, "-1e12,0,0", ["encoders.csv: row 30: t = -1000000000000.0 s; allowed: |t| at most"]),
    ("commands.csv", 203, "1e9,0.0,0.0", ["commands.csv: row 203: t = 1000000000.0 s is 1e+09 s after the stream's "
                                          "first row (t = 0.0 s); allowed: at most 86400 s"]),
    ("truth.csv", 202, "90000.0,0.05,0.0,0.0,0.0,0.0,0.0",
     ["truth.csv: row 202: t = 90000.0 s is 90000 s after the stream's first row", "at most 86400 s"]),
    # an encoder count of 5000 digits: ValueError (Python's int conversion limit)
    ("encoders.csv", 5, "0.015," + "1" * 5000 + ",0",
     ["encoders.csv: row 5: 5008 characters; allowed: rows of at most 4096"]),
    ("encoders.csv", 5, "0.015," + "7" * 4000 + ",0", ["encoders.csv: row 5: left = '7777", "has 4000 digits",
                                                      "allowed: counts within ±9007199254740992"]),
    ("encoders.csv", 5, "0.015,12345678901234567,0", ["row 5: left = '12345678901234567' has 17 digits"]),
    ("encoders.csv", 5, "0.015,9999999999999999,0", ["row 5: left = 9999999999999999; allowed: counts within"]),
    ("encoders.csv", 5, "0.015,0, -9999999999999999", ["row 5: right = -9999999999999999; allowed: counts within"]),
    ("encoders.csv", 5, "0.015,²,0", ["row 5: left = '²' is not a whole number of counts"]),
    # a field over 131072 characters: _csv.Error
    ("imu.csv", 7, "0.025," + "1" * 140000 + ",0,0,0,0,9.8",
     ["imu.csv: row 7: 140018 characters; allowed: rows of at most"]),
    ("commands.csv", 9, '"0.035","' + "2" * 5000 + '",0', ["commands.csv: row 9: 5012 characters"]),
    ("imu.csv", 4, "0.015,0,0,0,0,0,9.8\x00", ["imu.csv: row 4: accel_z = '9.8\\x00' is not a number"]),
])
def test_a_row_beyond_the_bounds_is_one_line_naming_it(good, tmp_path, stream, row, text, fragments):
    d = copy_log(good, tmp_path / "bad")
    path = d / stream
    if row > len(path.read_text().splitlines()):
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(text + "\n")
    else:
        edit_row(path, row, text)
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, str(path), *fragments)


def test_a_line_without_end_is_refused_before_it_is_read_whole(good, tmp_path):
    d = copy_log(good, tmp_path / "endless")
    with open(d / "imu.csv", "a", encoding="utf-8") as fh:
        fh.write("0" * (3 << 20))  # 3 MB and no line break: never one row in memory
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, f"{d / 'imu.csv'}: row 203: longer than 4096 characters")


def test_rows_and_instants_are_bounded(good, tmp_path, monkeypatch):
    import twin.logs.bounds as bounds
    import twin.logs.format as fmt
    import twin.logs.streams as streams

    d = copy_log(good, tmp_path / "rows")
    monkeypatch.setattr(streams, "MAX_ROWS", 150)
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, f"{d / 'imu.csv'}: row 152: more than 150 rows; allowed: at most 150 per stream")
    monkeypatch.undo()
    # 201 instants at 200 Hz; at 10⁵ Hz the same second asks for 10⁵ + 1 of them
    monkeypatch.setattr(fmt, "MAX_INSTANTS", 50_000)
    fast = copy_log(good, tmp_path / "fast")
    (fast / "log.toml").write_text(MANIFEST.replace("control_rate = 200.0", "control_rate = 100000.0"),
                                   encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        read_log(fast)
    one_line(exc, f"{fast / 'commands.csv'}: row 102: t = 0.5 s is 50000 control periods after the first command",
             "allowed: a replay of at most 50,000 control instants")
    assert bounds.MAX_INSTANTS == 10_000_000


def test_the_schedule_never_turns_a_wild_timestamp_into_an_index(good):
    """A SensorLog made otherwise than by read_log: the replay's own check, before any allocation."""
    from dataclasses import replace

    from twin.logs.replay import schedule

    log = read_log(good)
    far = replace(log, commands_t=np.concatenate([log.commands_t[:-1], [1e12]]))
    with pytest.raises(TwinError) as exc:
        schedule(far)
    one_line(exc, "commands.csv: the commands span 1e+12 s at 200 Hz", "at most 10,000,000 control instants")
    wild = replace(log, imu_t=np.concatenate([log.imu_t[:-1], [1e300]]))
    s = schedule(wild)  # the reading at 1e300 s arrives after the last instant: never
    assert len(s.t) == 201 and (s.gyro != len(log.imu_t) - 1).all() and s.gyro[0] == 0


# ---- a log's files are the log's ------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["../outside/evil.toml", "ABSOLUTE", "sub/scenario.toml", "a\u0000.toml"])
def test_the_scenario_must_lie_beside_log_toml(good, tmp_path, name):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "evil.toml").write_text('base = "paper-exp1"\n', encoding="utf-8")
    d = copy_log(good, tmp_path / "log")
    (d / "sub").mkdir()
    (d / "sub" / "scenario.toml").write_text('base = "paper-exp1"\n', encoding="utf-8")
    if name == "ABSOLUTE":
        name = str(outside / "evil.toml")
    (d / "log.toml").write_text(MANIFEST + f"scenario = {json.dumps(name)}\n", encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, f"{d / 'log.toml'}: scenario:", "is not beside log.toml; allowed: a built-in name or the name of "
                                                  "a .toml file beside log.toml")


def test_a_scenario_or_its_base_leading_out_of_the_log_is_refused(good, tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "evil.toml").write_text('base = "paper-exp1"\n', encoding="utf-8")
    d = copy_log(good, tmp_path / "link")
    (d / "log.toml").write_text(MANIFEST + 'scenario = "scenario.toml"\n', encoding="utf-8")
    (d / "scenario.toml").symlink_to(outside / "evil.toml")
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, f"{d / 'scenario.toml'}: leads out of {d}", "allowed: a scenario file inside")
    (d / "scenario.toml").unlink()
    (d / "scenario.toml").write_text('base = "../outside/evil.toml"\n', encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, "scenario.toml: base:", "leads out of")
    (d / "scenario.toml").write_text('base = "paper-exp1"\nduration = 2.0\n', encoding="utf-8")
    assert read_log(d).scenario.duration == 2.0  # a file of the log's, with a built-in base: as before


def test_a_stream_leading_out_of_the_log_is_refused_and_nothing_of_it_quoted(good, tmp_path):
    """imu.csv a symlink to /etc/passwd printed its first line in the header error."""
    secret = tmp_path / "secret.txt"
    secret.write_text("SECRET-FIRST-LINE:x:0:0\nmore\n", encoding="utf-8")
    d = copy_log(good, tmp_path / "leak")
    (d / "imu.csv").unlink()
    (d / "imu.csv").symlink_to(secret)
    with pytest.raises(TwinError) as exc:
        read_log(d)
    msg = one_line(exc, f"{d / 'imu.csv'}: leads out of {d}", "allowed: a stream inside")
    assert "SECRET" not in msg and "secret.txt" not in msg
    (d / "imu.csv").unlink()
    (d / "data").mkdir()
    (d / "data" / "imu-2026.csv").write_bytes((good / "imu.csv").read_bytes())
    (d / "imu.csv").symlink_to(Path("data") / "imu-2026.csv")  # inside the log: as good as the file itself
    assert len(read_log(d).imu_t) == 201


def test_the_manifest_is_a_regular_file_of_the_log(good, tmp_path):
    d = copy_log(good, tmp_path / "m")
    (d / "log.toml").unlink()
    (d / "log.toml").symlink_to(good / "log.toml")
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, f"{d / 'log.toml'}: leads out of {d}")
    (d / "log.toml").unlink()
    (d / "log.toml").mkdir()
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, f"{d / 'log.toml'}: a directory, not a regular file")


def test_a_stream_that_is_no_regular_file_is_named_as_what_it_is(good, tmp_path):
    d = copy_log(good, tmp_path / "pipe")
    (d / "imu.csv").unlink()
    os.mkfifo(d / "imu.csv")  # opened without blocking, then refused: nobody writes to it
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, f"{d / 'imu.csv'}: a FIFO (named pipe), not a regular file; allowed: a stream (CSV text)")


# ---- nesting, digits, null characters: tracebacks before ----------------------------------------------------------

def _deep(n: int) -> str:
    return "[" * n + "]" * n


def test_a_deeply_nested_log_toml_is_one_line(good, tmp_path):
    d = copy_log(good, tmp_path / "deep")
    (d / "log.toml").write_text(MANIFEST + f"x = {_deep(5000)}\n", encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, f"{d / 'log.toml'}: cannot be read: nested deeper than 32 levels")
    (d / "log.toml").write_text(MANIFEST + f"x = {_deep(40)}\n", encoding="utf-8")  # within the recursion limit
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, "nested deeper than 32 levels")
    (d / "log.toml").write_text(MANIFEST + "x = " + "9" * 5000 + "\n", encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        read_log(d)
    one_line(exc, "cannot be read: an integer with more than 4300 digits")


def test_a_deeply_nested_check_file_naming_a_log_is_one_line(good, tmp_path):
    from twin.logs.expect import is_log_target, load_log_check

    f = tmp_path / "twin_deep.toml"
    f.write_text(f'log = "{good}"\n[expect.ekf]\nx = {_deep(5000)}\n', encoding="utf-8")
    assert is_log_target(f) is False  # unreadable as a check: the scenario reader says why, in one line
    f.write_text(f'log = "{good}"\n[expect.ekf]\nnis_per_dof = "<= 2"\nx = {_deep(5000)}\n', encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        load_log_check(f)
    one_line(exc, f"{f}: cannot be read: nested deeper than 32 levels")
    f.write_text('log = "a\\u0000b"\n[expect.ekf]\nnis_per_dof = "<= 2"\n', encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        load_log_check(f)
    one_line(exc, "log must be the log's directory", "'a\\x00b'")


def test_a_null_character_in_a_base_or_a_scenario_name_is_one_line(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('base = "a\\u0000.toml"\n', encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        load_scenario(str(f))
    one_line(exc, f"{f}: base: 'a\\x00.toml' holds a null character; allowed:")
    with pytest.raises(TwinError) as exc:
        load_scenario(str(tmp_path / "b\x00.toml"))
    one_line(exc, "a name with a null character")


def _run_dir(tmp_path: Path, metrics: bytes) -> Path:
    """A run directory as compare reads one: metrics.json, trajectory.csv and the manifest listing them."""
    from twin.outputs import rundir

    d = tmp_path / "run"
    d.mkdir()
    (d / "metrics.json").write_bytes(metrics)
    (d / "trajectory.csv").write_bytes(b"controller,t [s]\n")
    files = {n: {"bytes": len(b), "sha256": hashlib.sha256(b).hexdigest()}
             for n, b in ((n, (d / n).read_bytes()) for n in ("metrics.json", "trajectory.csv"))}
    (d / rundir.MANIFEST).write_text(json.dumps({"format": rundir.MANIFEST_FORMAT, "command": "twin run",
                                                 "files": files}), encoding="utf-8")
    return d


def test_a_deeply_nested_metrics_json_is_one_line(tmp_path):
    from twin.outputs.compare import load

    d = _run_dir(tmp_path, _deep(5000).encode())
    with pytest.raises(TwinError) as exc:
        load(d)
    one_line(exc, f"{d / 'metrics.json'}: not readable as JSON (nested deeper than 64 levels)")


def test_a_deeply_nested_manifest_json_is_one_line(tmp_path):
    """Needs twin/outputs/rundir.py's read_manifest to parse with twin.inputs.json_loads."""
    from twin.outputs.compare import load

    d = _run_dir(tmp_path, b'{"runs": {}}')
    (d / "manifest.json").write_text(_deep(5000), encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        load(d)
    one_line(exc, f"{d / 'manifest.json'}: not readable as a manifest (nested deeper than 64 levels)")


def test_deeply_nested_sweep_files_are_one_line(tmp_path):
    from twin.sweep.store import SweepStore

    manifest = {"scenario": {"sweep": {"levels": [0.0]}}, "root_seed": 0, "controllers": ["it2"]}
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "sweep.json").write_text(_deep(5000), encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        SweepStore(out, manifest)
    one_line(exc, f"{out / 'sweep.json'}: not a sweep manifest (nested deeper than 64 levels)")
    (out / "sweep.json").unlink()
    SweepStore(out, manifest).close()  # a store of this configuration, then a line nested 5000 deep in it
    (out / "samples.jsonl").write_text('{"sample": ' + _deep(5000) + "}\n", encoding="utf-8")
    with pytest.raises(TwinError) as exc:
        SweepStore(out, manifest)
    one_line(exc, f"{out / 'samples.jsonl'} line 1: not JSON (nested deeper than 64 levels)")


# ---- replay in memory that does not grow by objects per instant ---------------------------------------------------

def _replay_peak(path: Path) -> int:
    """Peak bytes traced while a log is read and replayed with the EKF as twin replay does, and its
    estimates.csv written."""
    from twin.logs.replay import replay_logs, write_estimates_csv

    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        doc, replays = replay_logs([path], ["ekf"])
        write_estimates_csv(replays, path.parent / f"{path.name}-estimates.csv")
        assert doc["logs"][str(path)]["instants"] > 0
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_replay_memory_grows_by_a_few_hundred_bytes_an_instant(tmp_path, monkeypatch):
    """Before: every row as a list of strings, every instant a Measurement and the EKF's
    diagnostics (its 12 × 12 covariance) as a dict: about 9 kB an instant (10⁵ rows: 555 MB).
    Now: arrays only, the diagnostics as a few numbers an instant (twin.logs.diagnostics):
    about 0.4 kB an instant with every stream at the control rate, the log's arrays included.
    (Chunks of 256 instants, so that both logs fill several and what a chunk holds while it is
    replayed is the same for both.)"""
    import twin.logs.replay as replay_module

    monkeypatch.setattr(replay_module, "CHUNK", 256, raising=False)
    small, large = 600, 2_600
    _replay_peak(write_log(tmp_path / "warm", 300, moving=True))  # imports, the design: not the log's
    a = _replay_peak(write_log(tmp_path / "small", small, moving=True))
    b = _replay_peak(write_log(tmp_path / "large", large, moving=True))
    per_instant = (b - a) / (large - small)
    assert per_instant < 800, f"{per_instant:.0f} bytes per control instant"
