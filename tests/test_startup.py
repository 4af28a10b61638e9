"""A cached ``twin run`` keeps heavy imports off its path (issue 17, item 5), and the figure
drawn by the worker process (twin.outputs.figure_worker) is the one drawn in-process. Timings are
not tested here: benchmarks/bench_startup.py measures them."""
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from twin.outputs import figure_worker
from twin.scenarios import load_scenario
from twin.workflows.run import run_scenario

HEAVY = ("scipy.stats", "filterpy", "filterpy.stats", "cvxpy", "clarabel")

RUN = """
import sys
from twin.cli import main
sys.argv = ["twin", "run", "paper-exp3", "--duration", "1", "--no-video", "--controller", "it2", "--out", {out!r}]
try:
    main()
except SystemExit as exc:
    assert exc.code == 0, exc.code
print("IMPORTED", ",".join(m for m in {heavy!r} if m in sys.modules) or "-")
print("SCIPY", "scipy" in sys.modules)
print("MATPLOTLIB", "matplotlib" in sys.modules)
"""


def _run(tmp_path, **env):
    env = {**__import__("os").environ, "TWIN_CACHE_DIR": str(tmp_path / "cache"), **env}
    r = subprocess.run([sys.executable, "-c", RUN.format(out=str(tmp_path / "out"), heavy=HEAVY)],
                       capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    assert r.returncode == 0, r.stderr
    return dict(line.split(" ", 1) for line in r.stdout.strip().splitlines()[-3:])


def test_a_cached_run_imports_neither_scipy_stats_nor_filterpy(tmp_path):
    cold = _run(tmp_path)
    assert "clarabel" in cold["IMPORTED"]  # solved (the default robust design goes to Clarabel directly), and stored
    warm = _run(tmp_path, TWIN_FIGURE_WORKER="1")
    assert warm["IMPORTED"] == "-", warm  # the EKF's compiled path needs no filterpy, its gates no scipy.stats
    assert warm["SCIPY"] == "False"
    assert warm["MATPLOTLIB"] == "False"  # drawn by the worker
    assert (tmp_path / "out" / "figure.png").stat().st_size > 10_000
    # the figure drawn here instead: matplotlib then, still no scipy.stats nor filterpy
    here = _run(tmp_path, TWIN_FIGURE_WORKER="0")
    assert here["IMPORTED"] == "-" and here["MATPLOTLIB"] == "True"


def test_the_chi2_gates_are_scipys_bit_for_bit():
    from scipy.stats import chi2

    from estimation.gates import _TABLE, chi2_gate

    for (p, dof), value in _TABLE.items():
        assert value == float(chi2.ppf(1.0 - p, dof)), (p, dof)
    assert chi2_gate(0.01, 2) == float(chi2.ppf(0.99, 2))  # not in the table: asked of scipy


def test_the_reference_path_is_filterpys_ekf_and_the_compiled_one_needs_none():
    from filterpy.kalman import ExtendedKalmanFilter

    from estimation.ekf import EKFEstimator, KernelState, TwinEKF, _kernel
    from estimation.model import EstimatorModel

    model = EstimatorModel()
    ref = EKFEstimator(model, compiled=False)
    assert isinstance(ref.kf, TwinEKF) and isinstance(ref.kf, ExtendedKalmanFilter)
    if _kernel is not None:
        fast = EKFEstimator(model)
        assert fast.compiled and isinstance(fast.kf, KernelState)
        np.testing.assert_array_equal(fast.kf.P, ref.kf.P)  # both start at filterpy's P = I
        np.testing.assert_array_equal(fast.kf.x, ref.kf.x)


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    """paper-exp3 for 2 s, the figure by the worker and in this process."""
    sc = load_scenario("paper-exp3", ["duration=2"])
    out = {}
    for name, env in (("worker", "1"), ("here", "0")):
        mp = pytest.MonkeyPatch()
        mp.setenv("TWIN_FIGURE_WORKER", env)
        d = tmp_path_factory.mktemp(name)
        out[name] = (run_scenario(sc, ("it2",), out=d, video=False), d)
        mp.undo()
    return out


def test_the_workers_figure_is_the_one_drawn_here(ran):
    from PIL import Image

    (res_w, dir_w), (res_h, dir_h) = ran["worker"], ran["here"]
    assert not res_w.notes and not res_h.notes
    assert [p.name for p in res_w.files] == [p.name for p in res_h.files] == [
        "metrics.json", "trajectory.csv", "design.json", "figure.png", "manifest.json"]
    a = np.asarray(Image.open(dir_w / "figure.png").convert("RGBA"))
    b = np.asarray(Image.open(dir_h / "figure.png").convert("RGBA"))
    from twin.outputs.figure import DPI, SIZE

    assert a.shape == b.shape == (math.ceil(SIZE[1] * DPI), math.ceil(SIZE[0] * DPI), 4)
    assert np.array_equal(a, b)  # drawn in two processes or here: the same


def test_a_failed_worker_leaves_the_figure_to_this_process(tmp_path, monkeypatch):
    monkeypatch.setenv("TWIN_FIGURE_WORKER", "1")
    started = []
    real = figure_worker.FigureWorker

    class Failing(real):
        def __init__(self):
            monkeypatch.setattr(figure_worker, "_CODE", "import sys; sys.stdin.readline(); sys.exit(3)")
            super().__init__()
            started.append(self)

    monkeypatch.setattr(figure_worker, "FigureWorker", Failing)
    res = run_scenario(load_scenario("paper-exp3", ["duration=1"]), ("it2",), out=tmp_path, video=False)
    assert started and started[0]._proc.returncode == 3  # waited for: no process outlives the call
    assert [n for n in res.notes if "figure worker failed (exit status 3)" in n], res.notes
    assert (tmp_path / "figure.png").stat().st_size > 10_000


def test_no_worker_outlives_a_run_that_raises(monkeypatch):
    monkeypatch.setenv("TWIN_FIGURE_WORKER", "1")
    started = []
    real = figure_worker.FigureWorker

    class Recorded(real):
        def __init__(self):
            super().__init__()
            started.append(self)

    monkeypatch.setattr(figure_worker, "FigureWorker", Recorded)
    import twin.workflows.run as runner

    def boom(*args, **kwargs):
        raise RuntimeError("the simulation broke")

    monkeypatch.setattr(runner, "run_controllers", boom)
    with pytest.raises(RuntimeError, match="broke"), tempfile.TemporaryDirectory() as tmp:
        run_scenario(load_scenario("paper-exp3", ["duration=1"]), ("it2",), out=tmp, video=False)
    assert started and started[0]._proc.returncode is not None


def test_the_worker_is_wanted_only_with_a_cpu_to_spare(monkeypatch):
    monkeypatch.setenv("TWIN_FIGURE_WORKER", "0")
    assert not figure_worker.wanted()
    monkeypatch.setenv("TWIN_FIGURE_WORKER", "1")
    assert figure_worker.wanted()
    monkeypatch.delenv("TWIN_FIGURE_WORKER")
    monkeypatch.setattr(figure_worker.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(figure_worker, "_running_elsewhere", lambda: 0)
    assert figure_worker.wanted()
    monkeypatch.setattr(figure_worker, "_running_elsewhere", lambda: 1)  # the other CPU is busy
    assert not figure_worker.wanted()
    monkeypatch.setattr(figure_worker.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    monkeypatch.setattr(figure_worker, "_running_elsewhere", lambda: 0)
    assert not figure_worker.wanted()  # one CPU: nothing to run it on


def test_a_task_that_runs_for_a_moment_does_not_take_the_worker_away(monkeypatch):
    """The other CPU counts as busy only if a task is runnable at every one of a few looks:
    a moment's task (the kernel writing out files) no longer sends the figure to this process."""
    looks = iter([1, 0, 1])
    monkeypatch.setattr(figure_worker, "_runnable_now", lambda: next(looks))
    assert figure_worker._running_elsewhere() == 0
    looks = iter([1, 1, 1])
    assert figure_worker._running_elsewhere() == 1  # busy at every look: busy
    looks = iter([0])
    assert figure_worker._running_elsewhere() == 0  # free at the first look: one look


def test_a_bad_figure_worker_setting_is_one_line(monkeypatch):
    from twin.errors import TwinError

    monkeypatch.setenv("TWIN_FIGURE_WORKER", "yes")
    with pytest.raises(TwinError, match="TWIN_FIGURE_WORKER must be 1 .* got 'yes'"):
        figure_worker.wanted()


def test_the_figure_drawn_in_two_halves_is_the_whole_figure(ran, tmp_path):
    """The worker's two processes (figure_worker._Half: forked, each drawing half of the rows into
    shared memory) give the figure drawn at once, byte for byte."""
    import pickle

    from twin.outputs.figure import compose, fill_figure, new_figure, save_figure, save_pixels, show_half
    from twin.outputs.report import figure_data

    data = figure_data(ran["here"][0].runs)
    payload = tmp_path / "payload.pickle"
    payload.write_bytes(pickle.dumps(("unused", "a title\nof two lines", data)))
    import gc
    import select

    fig, axes = new_figure()
    half = figure_worker._Half(fig)
    gc.unfreeze()  # (the worker freezes its objects before the fork; this test process lives on)
    half.start(str(payload))
    fill_figure(fig, axes, data, "a title\nof two lines")
    shown = show_half(fig, 0)
    fig.canvas.draw()
    mine = np.asarray(fig.canvas.buffer_rgba()).copy()
    assert select.select([half._status], [], [], 120.0)[0], "the child did not finish its half"
    theirs = half.result()
    assert theirs is not None  # drawn, no label clipped
    assert not np.array_equal(mine, theirs)  # each drew its own half
    whole = compose(mine, theirs)
    assert whole is not None
    show_half(fig, None, shown)
    save_pixels(fig, whole, tmp_path / "halves.png")
    once, axes_once = new_figure()
    fill_figure(once, axes_once, data, "a title\nof two lines")
    save_figure(once, tmp_path / "once.png")
    assert (tmp_path / "halves.png").read_bytes() == (tmp_path / "once.png").read_bytes()


def test_halves_that_touch_are_not_composed():
    from twin.outputs.figure import compose

    a = np.full((6, 4, 4), 255, np.uint8)
    b = a.copy()
    a[1, 2] = (0, 0, 0, 255)
    b[4, 1] = (10, 20, 30, 255)
    whole = compose(a, b)
    assert whole is not None and (whole[1, 2] == a[1, 2]).all() and (whole[4, 1] == b[4, 1]).all()
    b[1, 0] = (0, 0, 0, 255)  # a row both drew in
    assert compose(a, b) is None


def test_the_early_worker_is_taken_once_and_one_not_taken_is_ended(monkeypatch):
    """twin run, as the process's command, starts the figure's worker as the command line loads
    (start_early); run takes it (take_early); one never taken (twin run --help, a usage error)
    is killed at exit (_end_early), not left to draw nothing."""
    monkeypatch.setenv("TWIN_FIGURE_WORKER", "1")
    figure_worker.start_early()
    worker = figure_worker.take_early()
    assert worker is not None and worker._proc.poll() is None
    assert figure_worker.take_early() is None  # taken once
    worker.cancel()
    assert worker._proc.returncode is not None and worker._proc.stdin.closed
    figure_worker.start_early()
    left = figure_worker._EARLY[0]
    figure_worker._end_early()
    assert not figure_worker._EARLY and left._proc.returncode is not None
    monkeypatch.setenv("TWIN_FIGURE_WORKER", "yes")  # a bad setting: no worker; run says it in one line
    figure_worker.start_early()
    assert figure_worker.take_early() is None


def test_a_run_that_fails_before_its_runs_is_one_line(tmp_path):
    """With the worker started as the command line loads (python -m twin is the process's command
    too), a scenario that cannot load is still its one line and exit status 2."""
    import os

    (tmp_path / "bad.toml").write_text("duration = -1\n")
    env = {**os.environ, "TWIN_FIGURE_WORKER": "1"}
    for module in ("twin", "twin.cli"):
        r = subprocess.run([sys.executable, "-m", module, "run", "bad.toml", "--no-video"], cwd=tmp_path, env=env,
                           capture_output=True, text=True)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "duration" in r.stderr


def test_the_figures_png_holds_the_canvas_pixels(tmp_path):
    """figure.write_png (the run figure's writer): PIL reads back every pixel, opaque pictures
    as RGB, others with their alpha; the resolution is the figure's."""
    from PIL import Image

    from twin.outputs.figure import DPI, write_png

    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (37, 53, 4), dtype=np.uint8)
    img[:, :, 3] = 255
    img[10:20] = img[9]  # rows that repeat the one above (the Up filter's zero rows)
    write_png(tmp_path / "a.png", img)
    with Image.open(tmp_path / "a.png") as im:
        assert im.mode == "RGB" and im.info["dpi"] == pytest.approx((DPI, DPI), abs=0.01)
        assert np.array_equal(np.asarray(im), img[:, :, :3])
    img[3, 4, 3] = 17  # one translucent pixel: alpha kept
    write_png(tmp_path / "b.png", img, dpi=72)
    with Image.open(tmp_path / "b.png") as im:
        assert im.mode == "RGBA" and np.array_equal(np.asarray(im), img)


def test_the_command_goes_on_at_the_workers_word_not_its_exit(monkeypatch):
    """finish() returns at the worker's word that figure.png is written (the kernel takes 10-50
    ms to free a process of matplotlib); close() then waits for its exit, unless the worker is
    the command's own (start_early: it dies with the command)."""
    monkeypatch.setenv("TWIN_FIGURE_WORKER", "1")
    # a worker that says it is done, then lives on (close() ends it after 2 s, unless it is left)
    code = "import os, sys, time; sys.stdin.readline(); os.write(1, b'done\\n'); time.sleep(60)"
    monkeypatch.setattr(figure_worker, "_CODE", code)
    for detach in (False, True):
        worker = figure_worker.FigureWorker()
        worker.detach = detach
        proc = worker._proc
        try:
            assert worker.submit({}, "", Path("unused.png"))
            assert worker.finish(timeout=30.0) is None
            assert proc.poll() is None  # said, not yet ended
            worker.close()
            assert (proc.poll() is None) is detach  # ended (waited for), or left to end
        finally:
            proc.kill()
            proc.wait()
