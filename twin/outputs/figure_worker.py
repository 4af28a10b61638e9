"""The run figure drawn by a second process while the runs are simulated.

Why: of a 20 s ``twin run`` process on the project's 2-core machine, matplotlib took about
0.45 s to import and the figure 0.3-0.5 s to draw, one after the other after the
simulation. A worker started before the scenario loads (``twin run``) or when the runs
start imports matplotlib and builds the empty figure (its tick objects made) on the other
core while this process simulates, then forks: two processes, each to draw half of the rows
(:class:`_Half`). They wait without drawing anything: a warm-up draw of the empty figure in
both (fonts loaded, text sizes cached) saved 15 ms of the drawing later but, competing with
the simulation for the two CPUs, cost it 25 ms. When the runs end their figure data (plain
arrays and strings, :func:`twin.outputs.report.figure_data`) is handed over, and the worker's
two processes draw their halves and write figure.png while this process writes
trajectory.csv and metrics.json.

The command waits for the worker's word that figure.png is written (:meth:`FigureWorker.finish`)
and always ends it (:meth:`FigureWorker.close`): figure.png is complete when the command
returns, and no process outlives the command: killed, the command takes the worker with it,
and the worker its forked half (:mod:`twin.workers`: each dies with its parent). As the
process's command, ``twin run`` does not wait for the worker's exit after its word (the kernel
freeing a process of matplotlib takes 10-50 ms): it dies with the command, if it has not ended
by then. A worker that fails leaves the figure to this process, as before,
with a one-line note. The worker is started only where a CPU is free for it (:func:`wanted`;
``TWIN_FIGURE_WORKER=1`` forces it, ``0`` turns it off): sharing the simulation's CPU, it
would slow the command down. Drawn here or there, the figure is the same, pixel for pixel.

The hand-over: the data is pickled to a private temporary file whose name goes down the
worker's stdin (one line, so the write never waits on a worker that is still building the figure);
EOF on stdin tells the worker that no figure is wanted.
"""
from __future__ import annotations

import atexit
import gc
import mmap
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from twin.errors import TwinError
from twin.workers import die_with_parent, subprocess_env, subprocess_worker_init

# NumPy and matplotlib are imported only where the drawing starts: `twin run` imports this
# module before its own imports, to start the worker sooner (start_early)

_ROOT = str(Path(__file__).resolve().parents[2])  # the directory holding this twin package
# the worker imports this very twin package (not another one on its path or in its cwd)
_CODE = f"import sys; sys.path.insert(0, {_ROOT!r}); from twin.outputs.figure_worker import main; main()"


def wanted() -> bool:
    """True where a worker would draw on a CPU of its own. ``TWIN_FIGURE_WORKER=1`` forces it,
    ``0`` turns it off; by default, where this process may run on at least two CPUs and no
    other process keeps running on them (on Linux, /proc/loadavg's count of runnable tasks,
    the fewest of a few looks: :func:`_running_elsewhere`). A worker that has to share the simulation's CPU makes the command slower than
    drawing here: 2.3 s against 2.1 s, with another job busy on one of the two CPUs."""
    flag = os.environ.get("TWIN_FIGURE_WORKER", "").strip()
    if flag in ("0", "1"):
        return flag == "1"
    if flag:
        raise TwinError(f"TWIN_FIGURE_WORKER must be 1 (draw the figure in a worker), 0 (draw it here) or unset "
                        f"(decide by the free CPUs), got {flag!r}")
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        cpus = os.cpu_count() or 1
    return cpus >= 2 and _running_elsewhere() < cpus - 1


BUSY_SAMPLES, BUSY_SPACING_S = 3, 0.002  # looks at the runnable tasks, and the time between them


def _runnable_now() -> int:
    """Tasks running or ready to run now besides this one (0 where that is not known)."""
    try:
        with open("/proc/loadavg", encoding="ascii") as fh:
            running = int(fh.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return 0
    return max(0, running - 1)  # this process is one of them


def _running_elsewhere() -> int:
    """Tasks that keep running besides this one: the fewest of :data:`BUSY_SAMPLES` looks 2 ms
    apart. One look was taken in by a task that runs for a moment (the kernel writing out
    the files of the command before, on this machine in 1 run of 10 when commands ran back
    to back), and the figure was then drawn here, 0.4-0.5 s slower; a job that keeps a CPU
    busy is there at every look."""
    fewest = _runnable_now()
    for _ in range(BUSY_SAMPLES - 1):
        if fewest == 0:
            break
        time.sleep(BUSY_SPACING_S)
        fewest = min(fewest, _runnable_now())
    return fewest


def start() -> FigureWorker | None:
    """A started worker, or None where none is wanted (:func:`wanted`) or it cannot start."""
    if not wanted():
        return None
    try:
        return FigureWorker()
    except OSError:
        return None


_EARLY: list = []  # the worker start_early() started, until twin run takes it (take_early)


def start_early() -> None:
    """``twin run`` as the process's command: start the worker now, before the command line's
    own imports, so that it is ready sooner (the worker was the last to finish when the runs
    were quick); :func:`take_early` hands it over. Nothing if none is wanted; a bad
    ``TWIN_FIGURE_WORKER`` is left to :func:`start` to say, in one line. A worker not taken
    (``twin run --help``, a usage error) is ended when the process ends."""
    try:
        worker = start()
    except Exception:  # noqa: BLE001 - said by start() when the command asks for its worker
        return
    if worker is not None:
        worker.detach = True  # the command's own: its exit is not waited for (the module's docstring)
        _EARLY.append(worker)
        atexit.register(_end_early)


def take_early() -> FigureWorker | None:
    """The worker :func:`start_early` started, now the caller's to use and end; None if none."""
    return _EARLY.pop() if _EARLY else None


def _end_early() -> None:
    while _EARLY:
        _EARLY.pop().cancel()


class FigureWorker:
    """One figure drawn in a child process: :meth:`submit` the data, :meth:`finish` to wait."""

    def __init__(self):
        self._stderr = tempfile.TemporaryFile()

        # no BLAS thread pool for a process that only draws (its start costs 60 ms here); it dies with this process
        env = subprocess_env({**os.environ, "OPENBLAS_NUM_THREADS": "1"})
        # stdin: the payload's name (EOF: none); stdout: its word that the figure is written
        self._proc = subprocess.Popen([sys.executable, "-c", _CODE], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=self._stderr, env=env)
        self._payload = None
        self._done = False  # it said the figure is written
        self.detach = False  # True: close() leaves a worker that is done to end by itself (start_early)

    def submit(self, data: dict, title: str, path: Path) -> bool:
        """Hand over the figure's data (:func:`twin.outputs.report.figure_data`), its title and the
        PNG's path; False if the worker is gone (then draw it here)."""
        fd, self._payload = tempfile.mkstemp(prefix="mtwip-figure-", suffix=".pickle")
        with os.fdopen(fd, "wb") as fh:
            pickle.dump((str(path), title, data), fh, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            self._proc.stdin.write(self._payload.encode("utf-8") + b"\n")
            self._proc.stdin.close()
        except OSError:
            return False
        return True

    def finish(self, timeout: float = 600.0) -> str | None:
        """Wait for the figure: None once written (the worker's word, :data:`DONE`), else why
        not (one line: its exit status and last line of stderr)."""
        import select

        try:
            said = (self._proc.stdout.readline() if select.select([self._proc.stdout], [], [], timeout)[0]
                    else None)
            self._done = said == DONE
            code = 0 if self._done else None if said is None else self._proc.wait(timeout)
        except subprocess.TimeoutExpired:
            code = None
        finally:
            self._remove_payload()
        if code is None:
            self.close()
            return f"the figure worker took more than {timeout:g} s"
        self._stderr.seek(0)
        err = self._stderr.read().decode("utf-8", "replace").strip()
        self._stderr.close()
        if code != 0:
            return f"the figure worker failed (exit status {code}): {err.splitlines()[-1] if err else 'no message'}"
        if err:  # warnings: shown as they would have been, had the figure been drawn here
            print(err, file=sys.stderr)
        return None

    def close(self) -> None:
        """End the worker if it still runs (EOF first, so that it can exit by itself); one that
        is done and :attr:`detach` ed is left to end by itself."""
        if self._proc.poll() is None and not (self._done and self.detach):
            try:
                if not self._proc.stdin.closed:
                    self._proc.stdin.close()
                self._proc.wait(2.0)
            except (OSError, subprocess.TimeoutExpired):
                self._proc.kill()
                self._proc.wait()
        for end in (self._proc.stdin, self._proc.stdout):  # our ends of its pipes, whoever ended it
            try:
                if not end.closed:
                    end.close()
            except OSError:
                pass
        self._remove_payload()
        if not self._stderr.closed:
            self._stderr.close()

    def cancel(self) -> None:
        """End the worker now if it still runs (killed: nothing it holds is wanted), e.g. when
        the command fails before its runs; nothing if it has ended."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self.close()

    def _remove_payload(self) -> None:
        if self._payload is not None:
            try:
                os.unlink(self._payload)
            except OSError:
                pass
            self._payload = None


DONE = b"done\n"  # the worker's word on its stdout: figure.png is written


class _Half:
    """The second half of the drawing (:data:`twin.outputs.figure.HALVES`): a process forked
    from the worker once the empty figure is built, drawing half of the rows into memory it
    shares with the worker, which draws the other half and writes the PNG.

    Why: once the runs end, the figure's draw (0.3-0.45 s) is what the command waits for,
    and the command itself has only trajectory.csv and metrics.json left to write (about
    0.1 s). Forked after the figure is built, each process draws only its half. A fork at
    the draw costs as much as it saves (the copy on write of every Python object the draw
    touches), so it happens while the runs simulate. The child dies with the worker (its own
    parent-death signal); the worker reaps it (:meth:`reap`) once figure.png is written, not
    before: the kernel's freeing of a process takes 10-50 ms."""

    def __init__(self, fig):
        w, h = fig.canvas.get_width_height()
        self.shape = (h, w, 4)
        self.pixels = mmap.mmap(-1, h * w * 4)  # shared with the child (MAP_SHARED, anonymous)
        self._to_child_r, self._to_child = os.pipe()  # the payload's name, or EOF
        self._status, status_w = os.pipe()  # one byte: 0 drawn, 1 its labels are clipped (EOF: it failed)
        parent = os.getpid()
        # the objects made so far go to the GC's permanent generation: a collection in either
        # process would otherwise write to every one of them, copying their pages
        gc.freeze()
        try:
            self.pid = os.fork()
        except OSError:
            for fd in (self._to_child_r, self._to_child, self._status, status_w):
                os.close(fd)
            self.pixels.close()
            gc.unfreeze()
            raise
        if self.pid == 0:
            os.close(self._to_child)
            os.close(self._status)
            code = 2
            try:
                die_with_parent(parent)  # the kernel's PDEATHSIG is not inherited across fork
                code = self._draw(fig, status_w)
            finally:
                os._exit(code)
        os.close(self._to_child_r)
        os.close(status_w)

    def _draw(self, fig, status_w: int) -> int:
        """The child: its half drawn from the payload the worker names."""
        from twin.outputs.figure import _clipped, fill_figure, show_half  # heavy: matplotlib, in the worker alone

        with os.fdopen(self._to_child_r, "rb") as fh:
            line = fh.readline().strip()
        if not line:
            return 0
        with open(line, "rb") as fh:
            _, title, data = pickle.load(fh)
        fill_figure(fig, fig.get_axes(), data, title)
        show_half(fig, 1)
        fig.canvas.draw()
        import numpy as np

        np.frombuffer(self.pixels, np.uint8)[:] = np.asarray(fig.canvas.buffer_rgba()).reshape(-1)
        os.write(status_w, bytes([1 if _clipped(fig) else 0]))
        return 0

    def start(self, payload: str | None) -> None:
        """Hand the child the payload's name (None: nothing to draw, it exits). A child that
        has died already is found by :meth:`result`."""
        try:
            if payload is not None:
                os.write(self._to_child, payload.encode("utf-8") + b"\n")
        except OSError:  # (BrokenPipeError) the child is gone: result() says so, the worker draws alone
            pass
        finally:
            os.close(self._to_child)

    def result(self):
        """The child's half (an RGBA array), or None if it failed or its labels are clipped."""
        status = os.read(self._status, 1)
        os.close(self._status)
        if status != b"\0":
            return None
        import numpy as np

        return np.frombuffer(self.pixels, np.uint8).reshape(self.shape)

    def end(self) -> None:
        """Nothing to draw: the child told so, and waited for."""
        self.start(None)
        os.close(self._status)
        self.reap()

    def reap(self) -> None:
        """Wait for the child's exit (after :meth:`result` or :meth:`end`)."""
        os.waitpid(self.pid, 0)


def _halves_wanted() -> bool:
    """Draw in two processes where fork exists and a second CPU is there for it."""
    if not hasattr(os, "fork"):  # pragma: no cover - not on POSIX
        return False
    try:
        return len(os.sched_getaffinity(0)) >= 2
    except AttributeError:  # pragma: no cover - not on Linux
        return (os.cpu_count() or 1) >= 2


def main() -> None:
    """The worker: the empty figure, then two processes waiting for the data (each to draw its
    half of the rows: :class:`_Half`); then the data, drawn and written, and the word
    (:data:`DONE`) on stdout."""
    subprocess_worker_init()  # first: it goes with a killed parent at once, not when its imports end
    # Ctrl-C (SIGINT to the terminal's process group) is the command's to handle: it ends this worker
    # (EOF, or a kill) when it stops; a KeyboardInterrupt here only wrote a traceback for it to read
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # heavy: matplotlib, in the worker alone (the command's process never imports it for the figure)
    from twin.outputs.figure import _clipped, compose, fill_figure, new_figure, save_figure, save_pixels, show_half

    fig, axes = new_figure()
    try:
        half = _Half(fig) if _halves_wanted() else None
    except OSError:  # no process to spare (a limit on processes, memory): the whole figure here
        half = None
    line = sys.stdin.readline().strip()
    if not line:  # EOF: the command ended without a figure to draw
        if half is not None:
            half.end()
        return
    if half is not None:
        half.start(line)
    with open(line, "rb") as fh:
        path, title, data = pickle.load(fh)
    fill_figure(fig, axes, data, title)
    whole = None
    if half is not None:
        shown = show_half(fig, 0)
        fig.canvas.draw()
        import numpy as np

        mine = None if _clipped(fig) else np.asarray(fig.canvas.buffer_rgba())
        theirs = half.result()
        whole = None if mine is None or theirs is None else compose(mine, theirs)
        show_half(fig, None, shown)
    if whole is not None:
        save_pixels(fig, whole, path)
    else:  # one process (or the halves touch, or a label is clipped): the whole figure, as drawn here
        save_figure(fig, path)  # written and closed
    # done: said at once (the command need not wait for this process's exit), then leave
    # without the interpreter's teardown of matplotlib and NumPy (0.1 s); stderr is unbuffered
    sys.stderr.flush()
    os.write(sys.stdout.fileno(), DONE)
    if half is not None:
        half.reap()
    os._exit(0)
