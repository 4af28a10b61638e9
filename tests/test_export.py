"""``twin export``: the files are complete and the same bytes every time, the C is clean under gcc
and clang and passes its own host test, the driver's law is the twin's bit for bit, and bad input
is one line."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from twin.actuators.dc_motor import DEFAULT_MOTOR, MotorDriver
from twin.cli import main
from twin.export import sil
from twin.export.generate import LIBRARY
from twin.workflows.export import export

COMPILERS = [c for c in ("gcc", "clang") if shutil.which(c)]
STRICT = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic"]
pytestmark = pytest.mark.skipif(not COMPILERS, reason="no C compiler (gcc or clang) on this machine")


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """it2 with the complementary filter in both precisions, LQR with kalman2: paper-exp3."""
    root = tmp_path_factory.mktemp("exports")
    made = {}
    for name, controller, estimator, precision in (("it2-64", "it2", "complementary", "float64"),
                                                    ("it2-32", "it2", "complementary", "float32"),
                                                    ("lqr-64", "lqr", "kalman2", "float64")):
        export("paper-exp3", controller, estimator, precision, root / name, seconds=0.5)
        made[name] = root / name
    return made


def test_the_same_design_gives_the_same_bytes(exports, tmp_path):
    export("paper-exp3", "it2", "complementary", "float64", tmp_path / "again", seconds=0.5)
    first = {p.relative_to(exports["it2-64"]): p.read_bytes() for p in exports["it2-64"].rglob("*") if p.is_file()}
    again = {p.relative_to(tmp_path / "again"): p.read_bytes() for p in (tmp_path / "again").rglob("*") if p.is_file()}
    assert first == again
    doc = json.loads((exports["it2-64"] / "export.json").read_text())
    assert set(doc["files"]) == {str(p) for p in first if str(p) != "export.json"}
    params = (exports["it2-64"] / "mtwip_params.h").read_text()
    for key in ("version", "design_digest", "robot", "robot_digest", "controller", "estimator", "precision"):
        assert f'#define MTWIP_{key.upper()} "{doc[key]}"' in params
    assert doc["loops"] == {"position": True, "heading": True}


def test_the_library_includes_and_allocates_nothing_else(exports):
    for name in LIBRARY:
        text = (exports["it2-64"] / name).read_text()
        includes = set(re.findall(r'#include\s+[<"]([^>"]+)[>"]', text))
        assert includes <= {"math.h", "stdint.h", "string.h", "mtwip.h", "mtwip_params.h", "mtwip_estimator.h"}, name
        assert not re.search(r"\b(malloc|calloc|realloc|free|printf|fopen)\s*\(", text), name
        # every file-scope object is const: no mutable global state
        for line in text.splitlines():
            if line.startswith("static ") and "(" not in line.split("=")[0]:
                assert line.startswith("static const "), f"{name}: {line}"


@pytest.mark.parametrize("cc", COMPILERS)
@pytest.mark.parametrize("name", ["it2-64", "it2-32", "lqr-64"])
def test_clean_under_strict_flags_and_its_host_test_passes(exports, name, cc, tmp_path):
    d = exports[name]
    flags = STRICT + (["-Wdouble-promotion"] if name.endswith("32") else [])
    exe = tmp_path / "test_host"
    r = subprocess.run([cc, *flags, "-I", str(d), *[str(d / n) for n in LIBRARY if n.endswith(".c")],
                        str(d / "test" / "test_host.c"), "-lm", "-o", str(exe)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    run = subprocess.run([str(exe)], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout
    assert run.stdout.startswith("ok: "), run.stdout
    if name.endswith("64"):  # float64: the twin's numbers, bit for bit
        assert "worst |diff| estimate 0, torque 0 N*m, duty 0" in run.stdout


def test_the_host_test_can_fail(exports, tmp_path):
    """A changed gain must break the host test (the vectors hold the twin's outputs)."""
    d = tmp_path / "changed"
    shutil.copytree(exports["it2-64"], d)
    src = (d / "mtwip_control.c").read_text()
    g1 = re.search(r"G1\[4\] = \{([^,]+),", src).group(1)
    (d / "mtwip_control.c").write_text(src.replace(g1, float.hex(float.fromhex(g1) * 1.01), 1))
    exe = tmp_path / "t"
    subprocess.run(["gcc" if "gcc" in COMPILERS else COMPILERS[0], *STRICT, "-I", str(d),
                    *[str(d / n) for n in LIBRARY if n.endswith(".c")], str(d / "test" / "test_host.c"), "-lm", "-o",
                    str(exe)], check=True)
    run = subprocess.run([str(exe)], capture_output=True, text=True)
    assert run.returncode == 1 and run.stdout.splitlines()[-1].startswith("FAIL")


def test_the_driver_law_is_the_twins_bit_for_bit(exports):
    lib = sil.load(exports["it2-64"])
    driver = MotorDriver(DEFAULT_MOTOR)
    rng = np.random.default_rng(3)
    torques = np.concatenate([rng.normal(0, 0.6, 3000), rng.uniform(-3, 3, 1000), [0.0, -0.0, 1.2, -1.2]])
    omegas = np.concatenate([rng.normal(0, 15, 3000), rng.uniform(-60, 60, 1000), [0.0, 0.0, 35.0, -35.0]])
    saturated = 0
    for tau, w in zip(torques, omegas):
        want = driver.duty(float(tau), float(w))
        assert lib.duty(float(tau), float(w)) == want
        saturated += want[1]
    assert 200 < saturated < 3000  # both branches exercised


def _cli(*args):
    return CliRunner().invoke(main, list(args), catch_exceptions=True)


def test_bad_input_is_one_line(exports, tmp_path):
    r = _cli("export", "--controller", "mylab.ctrl:Mine", "--out", str(tmp_path / "x"))
    assert r.exit_code == 2 and "cannot be exported to C (a Python plugin" in r.output and len(r.output.splitlines()) == 1
    r = _cli("export", "--estimator", "ideal", "--out", str(tmp_path / "x"))
    assert r.exit_code == 2 and "estimator 'ideal' cannot be exported" in r.output
    # not an export
    (tmp_path / "empty").mkdir()
    r = _cli("run", "paper-exp1", "--controller", f"export:{tmp_path / 'empty'}", "--duration", "0.1", "--no-video",
             "--out", str(tmp_path / "r"))
    assert r.exit_code == 2 and "is not an export of the twin" in r.output, r.output
    # made by another version
    other = tmp_path / "other"
    shutil.copytree(exports["it2-64"], other)
    doc = json.loads((other / "export.json").read_text())
    doc["version"] = "0.0.1"
    (other / "export.json").write_text(json.dumps(doc))
    r = _cli("run", "paper-exp1", "--controller", f"export:{other}", "--duration", "0.1", "--no-video",
             "--out", str(tmp_path / "r"))
    assert r.exit_code == 2 and "was exported by twin 0.0.1" in r.output, r.output
    # a compiler error: its first lines, in one line
    broken = tmp_path / "broken"
    shutil.copytree(exports["it2-64"], broken)
    (broken / "mtwip_motor.c").write_text((broken / "mtwip_motor.c").read_text() + "\nthis is not C;\n")
    r = _cli("run", "paper-exp1", "--controller", f"export:{broken}", "--duration", "0.1", "--no-video",
             "--out", str(tmp_path / "r"))
    assert r.exit_code == 2 and "does not compile" in r.output and "mtwip_motor.c" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1 and "Traceback" not in r.output
    # an export without the position loop, run with a position target
    bal = tmp_path / "balance-only"
    export("paper-exp1", "it2", "complementary", "float64", bal, seconds=0.1)
    r = _cli("run", "paper-exp3", "--controller", f"export:{bal}", "--duration", "0.1", "--no-video",
             "--out", str(tmp_path / "r"))
    assert r.exit_code == 2 and "has no position loop" in r.output, r.output


def test_a_robot_log_replays_through_the_exported_estimator_as_through_the_python_one(exports, tmp_path):
    """``twin replay LOG --estimator export:DIR``: the C estimator's estimates of a sensor log are the
    Python one's, bit for bit (float64)."""
    import csv

    d = exports["it2-64"]
    r = _cli("run", "paper-exp1", "--controller", "it2", "--set", "sensors.estimator=complementary", "--set",
             "initial.theta=0.1", "--duration", "2", "--log-sensors", "--no-video", "--out", str(tmp_path / "run"))
    assert r.exit_code == 0, r.output
    r = _cli("replay", str(tmp_path / "run" / "sensor-logs" / "it2"), "--estimator", f"complementary,export:{d}",
             "--out", str(tmp_path / "replay"))
    assert r.exit_code == 0, r.output
    rows = list(csv.reader((tmp_path / "replay" / "estimates.csv").open()))
    by = {}
    for row in rows[1:]:
        by.setdefault(row[1], []).append(row[2:])
    assert len(by["complementary"]) > 300 and by["complementary"] == by[f"export:{d}"]


def test_check_and_golden_files_take_an_export(exports, tmp_path):
    """A scenario file lists the export as a controller; ``twin check`` holds it to the bounds of the
    controller it came from, records golden trajectories of it and compares against them."""
    d = exports["it2-64"]
    sc = tmp_path / "fw.toml"
    sc.write_text(f'base = "paper-exp1"\nname = "fw"\nduration = 1.5\n[controller]\nkinds = ["export:{d}"]\n'
                  '[expect]\nfell = false\n[expect.it2]\niae_theta = "<= 0.0001"\n')
    r = _cli("check", str(sc), "--record", str(tmp_path / "gold"))
    assert r.exit_code == 1 and "iae_theta <= 0.0001" in r.output, r.output  # it2's bound, applied to the C
    sc.write_text(sc.read_text().replace('iae_theta = "<= 0.0001"', 'iae_theta = "<= 1"'))
    r = _cli("check", str(sc), "--golden", str(tmp_path / "gold"))
    assert r.exit_code == 0 and "matches" in r.output, r.output


def test_a_robot_of_ones_own_named_anyhow_exports_and_compiles(tmp_path):
    """A robot file's name goes into mtwip_params.h as a C string: quotes, backslashes and non-ASCII
    letters escaped, the library still compiles and its host test passes."""
    text = (Path(__file__).resolve().parent.parent / "twin" / "robots" / "builtin" / "paper.toml").read_text()
    robot = tmp_path / "mine.toml"
    robot.write_text(text.replace('name = "paper"', 'name = "Zoë\'s \\\\ \\"lab\\" bot"', 1))
    d = tmp_path / "fw"
    r = _cli("export", "--robot", str(robot), "--scenario", "paper-exp1", "--estimator", "complementary",
             "--out", str(d))
    assert r.exit_code == 0, r.output
    assert '#define MTWIP_ROBOT "Zo\\303\\253\'s \\\\ \\"lab\\" bot"' in (d / "mtwip_params.h").read_text()
    exe = tmp_path / "t"
    subprocess.run([COMPILERS[0], *STRICT, "-I", str(d), *[str(d / n) for n in LIBRARY if n.endswith(".c")],
                    str(d / "test" / "test_host.c"), "-lm", "-o", str(exe)], check=True)
    assert subprocess.run([str(exe)], capture_output=True, text=True).stdout.startswith("ok: ")


def test_an_edited_export_that_crashes_is_one_line_and_its_code_is_recorded(exports, tmp_path):
    """An export's C is a user's code once edited: it runs in a worker process (as a Python plugin
    does), so a crash in it ends the command with one line naming it, not the command's process;
    and the run records a digest of its sources, which the edit changes."""
    import sys

    from twin.registry import provenance

    d = tmp_path / "fw"
    shutil.copytree(exports["it2-64"], d)
    kind = f"export:{d}"
    before = provenance("controller", kind)["sha256"]
    src = (d / "mtwip_control.c").read_text()
    at = src.index("{", src.index("void mtwip_control(")) + 1
    (d / "mtwip_control.c").write_text(src[:at] + "\n    if (x) *(volatile int *)0 = 0;\n" + src[at:])
    assert provenance("controller", kind)["sha256"] not in (None, before)
    r = subprocess.run([sys.executable, "-m", "twin", "run", "paper-exp3", "--controller", kind, "--duration", "0.1",
                        "--no-video", "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, (r.returncode, r.stderr[-400:])
    errors = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and "SIGSEGV" in errors[0] and kind in errors[0], r.stderr


def test_an_imu_mounted_turned_reads_in_its_own_axes(tmp_path):
    """A robot whose IMU is mounted turned (imu.orientation): the firmware takes the IMU's readings
    in its own axes and turns them into the body's by the config's imu_to_body (from the robot
    file); the host test's readings are the IMU's own, and it fails if the turn is left out."""
    d = tmp_path / "fw"
    export("paper-exp3", "it2", "ekf", "float64", d, ("sensors.imu_orientation=[0.1, -0.2, 0.3]",), seconds=0.5)
    assert "#define MTWIP_IMU_TO_BODY {{0x1.df61d8" in (d / "mtwip_params.h").read_text()
    cc = "gcc" if "gcc" in COMPILERS else COMPILERS[0]

    def host_test(where):
        exe = where / "t"
        subprocess.run([cc, *STRICT, "-I", str(where), *[str(where / n) for n in LIBRARY if n.endswith(".c")],
                        str(where / "test" / "test_host.c"), "-lm", "-o", str(exe)], check=True)
        return subprocess.run([str(exe)], capture_output=True, text=True)

    run = host_test(d)
    assert run.returncode == 0 and run.stdout.startswith("ok: "), run.stdout  # within 1e-9 (the turn's rounding)
    bad = tmp_path / "unturned"
    shutil.copytree(d, bad)
    src = (bad / "mtwip.c").read_text()
    assert "if (s->imu_turned) {" in src
    (bad / "mtwip.c").write_text(src.replace("if (s->imu_turned) {", "if (0 && s->imu_turned) {"))
    run = host_test(bad)
    assert run.returncode == 1 and run.stdout.splitlines()[-1].startswith("FAIL"), run.stdout
