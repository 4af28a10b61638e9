"""Issue 39, signals at unlucky moments: SIGINT or SIGTERM at any moment of ``twin run`` ends it
with 130 or 143 and one line ``interrupted: SIGNAL; <what was kept>`` on stderr (after the
progress bar's), no traceback, and leaves the run directory as it was, or complete with a
manifest whose exit status is the command's (or 0, for a run committed before the signal
came: the command then still ends with 130 or 143).

Before, about 5 % of the moments between 0.55 s and 1.25 s broke that. Each cause has a test
below that sends the signal at its exact moment, from inside the process (a launcher named
``twin``, so that the command line is the process's command, as the installed script is):

* ``solver``: in Clarabel's solve (Rust), which imports SciPy's LAPACK on its first use; the
  handler's exception there became a Rust panic (a traceback, exit status 1);
* ``cython``: in a Cython module's initialisation, whose ``try: Sequence.register(...) except:
  pass`` swallowed the interrupt: the command ran on and ended with exit status 0;
* ``connect``: between ``pybullet.connect`` and BulletClient's keeping the server's id: its
  ``__del__`` printed an AttributeError traceback after the one line;
* ``matplotlib``: in the initialisation of matplotlib's C++ modules (pybind11), which made an
  ``ImportError: initialization failed`` of it (exit status 1, the manifest saying "error
  during the figure") and left the module half made, the interpreter aborting as it ended (-6);
* ``finalizer``: in a finalizer (here the garbage collector's callback; a ``__del__``, a
  weakref callback such as importlib's module locks' alike), where an exception is only
  printed ("Exception ignored") and the signal was lost (exit status 0);
* ``startup``: while the command line loads, before its handlers were there (a
  KeyboardInterrupt traceback; SIGTERM's death, -15);
* ``exit``: after the command, as the interpreter ends, where Python had put the default
  handlers back (-15, or a KeyboardInterrupt).

And a seeded test at random moments over the whole command, two commands at a time.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="POSIX signals; the moment a handler is in place is read from /proc")

RUN = ("run", "paper-exp3", "--set", "duration=2", "--controller", "it2", "--no-cache", "--no-video")
# 1 - 0.95**32 = 81 %: a cause hit by 5 % of the moments shows up here (each known cause has its own test
# above); TWIN_SIGNAL_MOMENTS=64 (96 %) for a thorough run, as before a change to the signal handling
MOMENTS = int(os.environ.get("TWIN_SIGNAL_MOMENTS", "32"))
SEED = 39
BAD = ("Traceback", "panicked", "Exception ignored", "Fatal Python error", "Error in sys.excepthook")
PROGRESS = re.compile(r"^\s+(run \S+|video)(\s|$)")  # the progress bar's label (no bar: stderr is not a terminal)

# The command, with a signal sent to itself at one chosen moment (TWIN_TEST_SIGNAL_AT=KIND:SIGNUM);
# named "twin", as the installed script is: the command line is then the process's command.
LAUNCHER = r'''
import os, sys

_kind, _, _sig = os.environ.get("TWIN_TEST_SIGNAL_AT", "").partition(":")
_done = []


def _fire():
    if not _done:
        _done.append(1)
        os.kill(os.getpid(), int(_sig))


def _in_init(name):
    """Whether the extension module ``name`` is being initialised below the caller."""
    f = sys._getframe(2)
    while f is not None:
        if f.f_code.co_name == "_call_with_frames_removed":
            a = f.f_locals.get("args") or ()
            if a and name in (getattr(a[0], "name", None), getattr(a[0], "__name__", None)):
                return True
        f = f.f_back
    return False


if _kind == "startup":  # while the command line loads (twin.cli imports twin.controllers.lmi)
    sys.addaudithook(lambda event, args: event == "import" and args[0] == "twin.controllers.lmi" and _fire())
elif _kind == "solver":  # in Clarabel's first solve, which imports SciPy's LAPACK from Rust
    sys.addaudithook(lambda event, args: event == "import" and args[0] == "scipy.linalg" and _fire())
elif _kind == "cython":  # in a Cython module's initialisation: Sequence.register(...) in a bare try/except
    import abc

    _register = abc.ABCMeta.register

    def _registering(cls, sub):
        if sys._getframe(1).f_code.co_name == "_call_with_frames_removed":
            _fire()
        return _register(cls, sub)

    abc.ABCMeta.register = _registering
elif _kind == "connect":  # between pybullet.connect and BulletClient's keeping the server's id
    from twin.plant.bullet import quiet_native_output

    with quiet_native_output():
        import pybullet
    _connect = pybullet.connect

    def _connecting(*args, **kwargs):
        cid = _connect(*args, **kwargs)
        _fire()
        return cid

    pybullet.connect = _connecting
elif _kind == "matplotlib":  # in the initialisation of matplotlib.ft2font (C++), which makes Python enums
    import enum

    _create = enum.EnumType._create_

    def _creating(*args, **kwargs):
        if _in_init("matplotlib.ft2font"):
            _fire()
        return _create(*args, **kwargs)

    enum.EnumType._create_ = _creating
elif _kind == "finalizer":  # in a garbage collector's callback (as in a __del__): an exception there is printed
    import gc

    def _collecting(phase, info):
        if phase == "start" and "twin.workflows.run" in sys.modules:
            _fire()

    gc.callbacks.append(_collecting)
elif _kind == "exit":  # as the interpreter ends, after the command (the last atexit function)
    import atexit

    atexit.register(_fire)

from twin.cli import main  # noqa: E402

sys.exit(main())
'''


# ---- what every moment must leave ------------------------------------------------------------------

def _snapshot(directory: Path) -> dict | None:
    """Every file under ``directory`` with its SHA-256 (None: there is no such directory)."""
    if not directory.exists():
        return None
    return {str(p.relative_to(directory)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(directory.rglob("*")) if p.is_file()}


def _check(code: int, err: str, sig: int, out: Path, before: dict | None, what: str) -> None:
    """The promise, for a command that ``sig`` reached: its exit status, its one line, and its
    run directory as it was or complete with a manifest that says the command's exit status."""
    why = f"{what}: exit status {code}\n{err}"
    assert code == 128 + sig, why
    assert not any(word in err for word in BAD), why
    lines = [line for line in re.split(r"[\r\n]", err) if line.strip() and not PROGRESS.match(line)]
    assert len(lines) == 1 and lines[0].startswith(f"interrupted: {signal.Signals(sig).name}"), why
    assert err.rstrip().endswith(lines[0]), why  # nothing after it
    assert not [p.name for p in out.parent.iterdir() if "twin-partial" in p.name], why  # no staging left
    after = _snapshot(out)
    if after == before:  # as it was (absent, or the earlier run)
        return
    assert after is not None and "manifest.json" in after, why
    doc = json.loads((out / "manifest.json").read_text())
    for name, entry in doc["files"].items():  # every file listed is there, as listed
        data = (out / name).read_bytes()
        assert (len(data), hashlib.sha256(data).hexdigest()) == (entry["bytes"], entry["sha256"]), why
    assert set(after) - {"manifest.json", ".twin.lock"} == set(doc["files"]), why  # and nothing else
    # the command's exit status, or 0: committed complete before the signal came, and said so
    assert doc["exit_status"] == code or (doc["exit_status"] == 0 and doc["complete"]), (doc, why)


def _env(tmp: Path, **extra) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWIN_TEST_")}
    env.update({"MPLBACKEND": "Agg", "TWIN_CACHE_DIR": str(tmp / "cache"), **extra})
    return env


# ---- each cause, at its moment ---------------------------------------------------------------------

@pytest.mark.parametrize("kind, sig", [
    ("solver", signal.SIGTERM), ("cython", signal.SIGINT), ("connect", signal.SIGTERM),
    ("matplotlib", signal.SIGINT), ("finalizer", signal.SIGTERM), ("startup", signal.SIGINT),
    ("exit", signal.SIGTERM)])
def test_a_signal_at_an_unlucky_moment_is_130_or_143_and_one_line(tmp_path, kind, sig):
    launcher = tmp_path / "bin" / "twin"
    launcher.parent.mkdir()
    launcher.write_text(LAUNCHER)
    out = tmp_path / "out"
    # the figure drawn here (matplotlib imported in this process, not in the figure's worker)
    env = _env(tmp_path, TWIN_TEST_SIGNAL_AT=f"{kind}:{int(sig)}", TWIN_FIGURE_WORKER="0")
    p = subprocess.run([sys.executable, str(launcher), *RUN, "--out", str(out)], capture_output=True, text=True,
                       env=env, cwd=tmp_path, timeout=300)
    _check(p.returncode, p.stderr, sig, out, None, kind)
    if kind == "exit":  # after the command: its run is complete, and the line says so
        assert json.loads((out / "manifest.json").read_text())["complete"]
        assert f"this run was complete: {out} holds it, with its manifest.json" in p.stderr, p.stderr
    elif kind in ("solver", "cython", "connect", "startup", "finalizer"):  # before anything was written
        assert not out.exists()


# ---- random moments ---------------------------------------------------------------------------------

def _handling(pid: int) -> bool:
    """Whether process ``pid`` catches SIGTERM (its handler is in place: Python's own catches
    SIGINT only). Before, the interpreter is still starting, which nothing of the twin can help."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return True  # gone: it ended
    caught = int(re.search(r"^SigCgt:\s*([0-9a-f]+)", status, re.M).group(1), 16)
    return bool(caught >> (signal.SIGTERM - 1) & 1)


def _exiting(pid: int) -> bool:
    """Whether process ``pid`` is ending (the kernel's PF_EXITING: it called exit, and its memory is
    being freed, which takes some milliseconds after a run): a signal now comes too late for it."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return bool(int(stat.rsplit(")", 1)[1].split()[6]) & 0x4)


def _start(tmp: Path, out: Path, env: dict) -> tuple[subprocess.Popen, float, float]:
    """``twin run`` started (``python -m twin.cli``, the command line as its process's command):
    (the process, when it started, when its handlers were in place)."""
    t0 = time.monotonic()
    p = subprocess.Popen([sys.executable, "-m", "twin.cli", *RUN, "--out", str(out)], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, env=env, cwd=tmp, start_new_session=True)
    while p.poll() is None and not _handling(p.pid):
        time.sleep(0.001)
    return p, t0, time.monotonic()


def _moment(args) -> tuple[str, bool]:
    """One attempt: the signal at ``delay`` s after the handlers were in place; (what it was,
    whether the signal reached the command)."""
    i, tmp, sig, delay, group, earlier, worker = args
    tmp.mkdir()
    out = tmp / "out"
    if earlier is not None:
        shutil.copytree(earlier, out)
    before = _snapshot(out)
    p, _, ready = _start(tmp, out, _env(tmp, TWIN_FIGURE_WORKER=worker))
    what = (f"moment {i}: {signal.Signals(sig).name} to the {'group' if group else 'process'} {delay:.3f} s after its "
            f"handlers, {'over an earlier run' if earlier else 'fresh'}, figure worker {worker}")
    try:
        p.wait(max(0.0, ready + delay - time.monotonic()))
    except subprocess.TimeoutExpired:
        late = _exiting(p.pid)
        (os.killpg if group else os.kill)(p.pid, sig)
        late = late or _exiting(p.pid)
    else:  # it ended before the moment came
        return what, False
    err = p.communicate(timeout=120)[1]
    if late and p.returncode == 0 and "interrupted" not in err:  # it had ended already, but for its memory
        return what, False
    _check(p.returncode, err, sig, out, before, what)
    return what, True


def _reference(tmp: Path) -> float:
    """A run without a signal into ``tmp``/out: how long it ran after its handlers were in place (s)."""
    tmp.mkdir()
    p, _, ready = _start(tmp, tmp / "out", _env(tmp))
    err = p.communicate(timeout=300)[1]
    assert p.returncode == 0, err
    return time.monotonic() - ready


def test_sigint_or_sigterm_at_random_moments_keeps_the_promise(tmp_path):
    # two runs without a signal, side by side as the moments' commands run: how long a run takes
    # here, and the earlier run that half of the moments find in their --out
    with ThreadPoolExecutor(2) as pool:
        span = min(pool.map(_reference, [tmp_path / "ref", tmp_path / "ref2"]))
    ref = tmp_path / "ref"
    rng = np.random.default_rng(SEED)
    sigs = rng.permutation(np.repeat([signal.SIGINT, signal.SIGTERM], MOMENTS // 2))
    delays = rng.uniform(0.0, span, MOMENTS)  # from the handlers' being in place to the run's end
    groups = rng.random(MOMENTS) < 0.25  # to the process group, as a terminal's Ctrl-C
    earlier = rng.random(MOMENTS) < 0.5
    workers = rng.choice(["0", "1"], MOMENTS)
    jobs = [(i, tmp_path / f"m{i}", int(sigs[i]), float(delays[i]), bool(groups[i]),
             ref / "out" if earlier[i] else None, str(workers[i])) for i in range(MOMENTS)]
    with ThreadPoolExecutor(2) as pool:  # two commands at a time: the CI machine's two cores
        done = list(pool.map(_moment, jobs))
    reached = sum(hit for _, hit in done)
    assert reached >= 0.6 * MOMENTS, f"only {reached} of {MOMENTS} moments came before the command ended"
