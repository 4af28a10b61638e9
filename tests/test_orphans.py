"""No orphans, nothing mixed (issue 26): a command killed while its workers run takes them along.

Each test starts a real ``twin`` command (a subprocess, in a session of its own), notes every
process descended from it while it runs (children, grandchildren: pool workers,
multiprocessing's resource tracker, the video's panel renderers and ffmpeg, the figure
worker, Ray's daemons and agents; found through the parent pids in /proc, since once the
command is dead they are reparented), sends the signal to the command alone (not to its
process group: a terminal's Ctrl-C would reach the workers too and hide a leak), and then
requires every one of them gone within a few seconds (a zombie left to PID 1 counts as gone:
it runs nothing and holds nothing). Workers are kept busy by a slow plugin controller that
leaves a mark file per process on its first call, so the signal lands while they compute; the
plugin runs in the commands' contained worker processes (twin.containment), never in the
command's own.

The sweeps killed at the test points ``sweep-sample`` and ``sweep-report``
(:func:`twin.outputs.rundir.test_point`) must leave a folder that is never mixed (no manifest.json,
every line of samples.jsonl a whole record of this sweep, a torn last line at most) and that
a rerun finishes byte for byte as an uninterrupted sweep (tests/test_sweep_store.py's
reference). The interrupted runs and records of ``twin run`` and ``twin check --record`` are
in tests/test_rundir.py.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from slow_plugin import write_slow_plugin
from twin.workers import descendants, process_stat
from test_rundir import _one_line
from test_sweep_store import DRAWS, SETS, reference, sweep_cli  # noqa: F401 (reference: a fixture)

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; workers die with "
                                "their parent through prctl(PR_SET_PDEATHSIG), on Linux")

GONE_WITHIN_S = 5.0

SLOW = "orphplug:Slow"


# ---- processes, through /proc ---------------------------------------------------------------------------

def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return "?"


def _descendants(root: int) -> dict:
    """pid -> (start time, command line) of every live process descended from ``root``."""
    return {pid: (start, _cmdline(pid)) for pid, start in descendants(root).items()}


def _alive(noted: dict) -> dict:
    """Those of ``noted`` still running (the same processes: pid and start time), or left as
    zombies of this test process."""
    left = {}
    for pid, (start, cmd) in noted.items():
        st = process_stat(pid)
        if st is not None and st[2] == start and (st[0] != "Z" or st[1] == os.getpid()):
            left[pid] = f"{cmd[:160]} (state {st[0]}, parent {st[1]})"
    return left


class Command:
    """``twin ARGS`` started in ``cwd``, its descendants noted as they come (:meth:`watch`)."""

    def __init__(self, args, cwd: Path, env: dict | None = None, stop_at: str | None = None):
        self.marks = cwd / f"marks-{time.monotonic_ns()}"
        self.marks.mkdir()
        self.marker = cwd / f"stopped-{time.monotonic_ns()}"
        env = {**os.environ, "SLOW_PLUGIN_MARKS": str(self.marks), **(env or {})}
        if stop_at is not None:
            env["TWIN_TEST_STOP_AT"] = f"{stop_at}:{self.marker}"
        self.proc = subprocess.Popen([sys.executable, "-m", "twin.cli", *map(str, args)], cwd=cwd, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
        self.noted: dict = {}

    def marked(self) -> set:
        """Processes of the command that called the slow plugin."""
        return {int(p.name) for p in self.marks.iterdir() if p.name.isdigit()}

    def marked_commands(self) -> dict:
        """pid -> command line of each process that called the slow plugin, as it wrote it
        (a short-lived one, such as the sweep's preflight, may be gone before a poll notes it)."""
        return {int(p.name): p.read_text() for p in self.marks.iterdir() if p.name.isdigit()}

    def watch(self, ready, timeout: float = 120.0) -> dict:
        """Note the command's descendants until ``ready(self)`` holds (the last notes taken
        after it does); the notes."""
        deadline = time.monotonic() + timeout
        while True:
            self.noted.update(_descendants(self.proc.pid))
            if ready(self):
                self.noted.update(_descendants(self.proc.pid))
                return self.noted
            if self.proc.poll() is not None:
                out, err = self.proc.communicate()
                pytest.fail(f"the command ended (status {self.proc.returncode}) before it was ready: {err[-2000:]}")
            assert time.monotonic() < deadline, "not ready in time"
            time.sleep(0.05)

    def kill(self, sig) -> tuple[int, str, str]:
        """Send ``sig`` to the command alone; (exit status, stdout, stderr) once it has ended."""
        os.kill(self.proc.pid, sig)
        out, err = self.proc.communicate(timeout=120)
        return self.proc.returncode, out, err

    def assert_nothing_left(self) -> float:
        """Every process the command started is gone within GONE_WITHIN_S; the seconds it took."""
        t0 = time.monotonic()
        while _alive(self.noted) and time.monotonic() - t0 < GONE_WITHIN_S:
            time.sleep(0.05)
        assert not _alive(self.noted), _alive(self.noted)
        return time.monotonic() - t0

    def clean_up(self) -> None:
        """Whatever happened in the test: nothing of this command runs on into the next."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()
        for pid in _alive(self.noted):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


@pytest.fixture
def command():
    started = []

    def start(*args, **kw) -> Command:
        started.append(Command(*args, **kw))
        return started[-1]

    yield start
    for c in started:
        c.clean_up()


@pytest.fixture
def plugin_dir(tmp_path) -> Path:
    write_slow_plugin(tmp_path, "orphplug", 0.05)
    return tmp_path


def _busy(c: Command) -> set:
    """The command's processes now inside the slow plugin (marked it, and still running)."""
    return {pid for pid in c.marked() - {c.proc.pid} if (process_stat(pid) or ("Z",))[0] != "Z"}


def _named(noted: dict, fragment: str) -> list:
    return [pid for pid, (_, cmd) in noted.items() if fragment in cmd]


def _interrupted(code: int, err: str, sig) -> str:
    """Exit status 128 + the signal's number and one line saying so and what was kept."""
    assert code == 128 + sig, (code, err)
    return _one_line(err, f"interrupted: {signal.Signals(sig).name}; ")


# ---- twin sweep's local workers ------------------------------------------------------------------------

@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
def test_a_killed_sweep_takes_its_busy_workers_and_the_resource_tracker_along(command, plugin_dir, sig):
    """The issue's case: both workers and the resource tracker ran on under PID 1, computing."""
    out = plugin_dir / "sweep"
    c = command(["sweep", "paper-exp2", "--samples", DRAWS, *SETS, "--controller", SLOW, "--workers", 2,
                 "--out", out], plugin_dir)
    noted = c.watch(lambda c: len(_busy(c)) >= 2)  # both workers inside the plugin
    workers = _named(noted, "multiprocessing.spawn")
    # the plugin ran in contained workers only (twin.containment): the busy ones, and the one
    # that planned and preflew it, all spawned, none the command's own process
    assert len(workers) >= 2 and c.proc.pid not in c.marked(), noted
    assert all("multiprocessing.spawn" in cmd for cmd in c.marked_commands().values()), c.marked_commands()
    code, _, err = c.kill(sig)
    if sig == signal.SIGKILL:
        assert code == -signal.SIGKILL, err
    else:
        line = _interrupted(code, err, sig)
        assert f"0 of {2 * DRAWS} samples are stored in {out}" in line, line
    c.assert_nothing_left()
    assert not (out / "manifest.json").exists()


# ---- twin check's pool ---------------------------------------------------------------------------------

def test_a_killed_check_takes_its_busy_workers_along(command, plugin_dir):
    from test_golden import write_short

    f = write_short(plugin_dir)
    c = command(["check", f, "--controller", SLOW, "--seeds", 4, "--workers", 3], plugin_dir)
    noted = c.watch(lambda c: len(_busy(c)) >= 2)  # two workers inside the plugin
    assert len(_named(noted, "multiprocessing.spawn")) >= 2, noted
    code, _, err = c.kill(signal.SIGKILL)
    assert code == -signal.SIGKILL, err
    c.assert_nothing_left()


# ---- twin run with a video: the figure worker, the panel renderers, ffmpeg -----------------------------------

def test_a_run_killed_while_it_simulates_takes_the_figure_worker_along(command, plugin_dir):
    c = command(["run", "paper-exp1", "--duration", 1, "--controller", SLOW, "--video", "--out", "R"], plugin_dir,
                env={"TWIN_FIGURE_WORKER": "1"})
    # the plugin runs in a worker process of the command's (twin.containment)
    noted = c.watch(lambda c: _busy(c) and _named(c.noted, "figure_worker"))
    # one worker, started by the command; with a second CPU it forks the half that draws half the
    # rows (twin.outputs.figure_worker._Half) as soon as it has matplotlib, so the half may be there too
    workers = _named(noted, "figure_worker")
    started = [pid for pid in workers if (process_stat(pid) or (None, None))[1] not in workers]
    assert len(started) == 1 and len(workers) <= 2, noted
    code, _, err = c.kill(signal.SIGKILL)
    assert code == -signal.SIGKILL, err
    c.assert_nothing_left()
    assert not (plugin_dir / "R").exists()  # its staging is hidden beside it, cleared by the next run


def test_a_run_killed_during_its_video_takes_the_panel_renderers_and_ffmpeg_along(command, plugin_dir):
    c = command(["run", "paper-exp1", "--duration", 1, "--controller", f"lqr,{SLOW}", "--video", "--out", "R"],
                plugin_dir, env={"TWIN_FIGURE_WORKER": "1", "SLOW_PLUGIN_SLEEP_S": "0"}, stop_at="video")
    noted = c.watch(lambda c: c.marker.exists())  # the first frame written: the renderers and the encoder at work
    assert len(_named(noted, "twin.render.panels")) == 2, noted
    code, _, err = c.kill(signal.SIGKILL)
    assert code == -signal.SIGKILL, err
    c.assert_nothing_left()
    assert not (plugin_dir / "R").exists()


# ---- Ray ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_killed_sweep_on_a_local_ray_instance_leaves_no_ray_process(command, plugin_dir, sig):
    """Ray fate-shares its daemons with the driver; its agents, left by a killed raylet, waited
    a minute for the dead GCS: the sweep's reaper (twin.workers.Reaper) kills them."""
    pytest.importorskip("ray")
    out = plugin_dir / "sweep"
    c = command(["sweep", "paper-exp2", "--samples", DRAWS, *SETS, "--controller", SLOW, "--workers", 2,
                 "--backend", "ray", "--out", out], plugin_dir)
    noted = c.watch(lambda c: len(c.marked() - {c.proc.pid}) >= 2, timeout=180)  # two Ray workers in the plugin
    assert _named(noted, "raylet") and _named(noted, "gcs_server") and _named(noted, "reaper_main"), noted
    code, _, err = c.kill(sig)
    if sig == signal.SIGKILL:
        assert code == -signal.SIGKILL, err
    else:
        _interrupted(code, err, sig)
    c.assert_nothing_left()


# ---- a sweep killed at its test points: never mixed, and finished by a rerun ------------------------------

def _whole_records(out: Path, torn_allowed: bool) -> int:
    """The records of samples.jsonl, after checking each is a whole record of this sweep (a torn
    last line, without its newline, only where ``torn_allowed``)."""
    from twin.sweep.store import CONFIG_KEY

    config = json.loads((out / "sweep.json").read_text())[CONFIG_KEY]
    raw = (out / "samples.jsonl").read_bytes()
    lines = raw.split(b"\n")
    if lines[-1]:
        assert torn_allowed, raw[-200:]
    for line in lines[:-1]:
        assert json.loads(line)["config"] == config
    return len(lines) - 1


@pytest.mark.parametrize("point, sig", [("sweep-sample", signal.SIGKILL), ("sweep-sample", signal.SIGTERM),
                                        ("sweep-sample", signal.SIGINT), ("sweep-report", signal.SIGKILL),
                                        ("sweep-report", signal.SIGINT)])
def test_a_sweep_killed_at_a_point_is_never_mixed_and_a_rerun_finishes_it(command, reference, tmp_path, point, sig):
    out = tmp_path / "sweep"
    c = command(["sweep", "paper-exp2", "--samples", DRAWS, *SETS, "--workers", 2, "--out", out], tmp_path,
                stop_at=point)
    noted = c.watch(lambda c: c.marker.exists())
    if point == "sweep-sample":  # a sample stored, the other worker at work
        assert len(_named(noted, "multiprocessing.spawn")) == 2, noted
    code, _, err = c.kill(sig)
    if sig == signal.SIGKILL:
        assert code == -signal.SIGKILL, err
    else:
        line = _interrupted(code, err, sig)
        if point == "sweep-report":
            assert f"all {2 * DRAWS} samples are stored in {out}, the report is not finished" in line, line
        else:
            assert f"of {2 * DRAWS} samples are stored in {out}; rerun the same command to finish the rest" in line, line
    c.assert_nothing_left()
    assert not (out / "manifest.json").exists()  # what marks a folder complete: never there before it is
    stored = _whole_records(out, torn_allowed=sig == signal.SIGKILL)
    if point == "sweep-sample":
        assert 1 <= stored < 2 * DRAWS and not (out / "sweep.csv").exists()
    else:
        assert stored == 2 * DRAWS
    r = sweep_cli(out, "--workers", "2")
    assert r.returncode == 0, r.stderr
    n = 2 * DRAWS - stored
    assert f"ran {n} sample{'s' * (n != 1)}" in r.stdout, r.stdout
    assert (out / "sweep.csv").read_bytes() == (reference / "sweep.csv").read_bytes()
    assert json.loads((out / "manifest.json").read_text())["exit_status"] == 0


# ---- the reaper itself ------------------------------------------------------------------------------------

REAPED = """
import subprocess, sys, time
from twin.workers import Reaper

old = subprocess.Popen(["sleep", "60"])  # started before the reaper watched: not its business
reaper = Reaper()
new = subprocess.Popen(["sleep", "60"])
reaper.scan()
time.sleep(0.8)
if sys.argv[1] == "close":
    reaper.close()
print(old.pid, new.pid, flush=True)
time.sleep(60)
"""


@pytest.mark.parametrize("closed", [False, True])
def test_the_reaper_kills_what_its_killed_parent_started_while_it_watched_and_nothing_else(tmp_path, closed):
    proc = subprocess.Popen([sys.executable, "-c", REAPED, "close" if closed else "watch"], stdout=subprocess.PIPE,
                            text=True, cwd=Path(__file__).resolve().parent.parent, start_new_session=True)
    old, new = map(int, proc.stdout.readline().split())
    noted = {pid: (process_stat(pid)[2], _cmdline(pid)) for pid in (old, new)}
    try:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)
        deadline = time.monotonic() + GONE_WITHIN_S
        while new in _alive(noted) and not closed and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3 if closed else 0.0)  # a reaper told it is done kills nothing, now or later
        assert set(_alive(noted)) == ({old, new} if closed else {old})
    finally:
        for pid in _alive(noted):
            os.kill(pid, signal.SIGKILL)


def test_an_interrupt_while_the_pool_starts_its_manager_thread_is_the_interrupt(monkeypatch):
    """SIGTERM landing in Thread.start (the pool's manager thread, started by the first submit)
    left a thread that never started, and the pool's shutdown then raised "cannot join thread
    before it is started" over the interrupt: a traceback and exit status 1 instead of the one
    line and 143 (seen once in a full test run under load)."""
    import signal
    import threading
    from concurrent.futures import process

    from twin.outputs.rundir import Interrupted
    from twin.workers import process_pool

    def interrupted_start(self):
        self._executor_manager_thread = threading.Thread(target=lambda: None)  # made, never started
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(process.ProcessPoolExecutor, "_start_executor_manager_thread", interrupted_start)
    with pytest.raises(Interrupted) as err:
        with process_pool(1) as pool:
            pool.submit(print)
    assert err.value.signum == signal.SIGTERM
