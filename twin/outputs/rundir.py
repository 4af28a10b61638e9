"""Output directories: written as a unit, checked when read, and who is using one.

* **Written as a unit.** ``twin run`` writes its run directory as a
  whole (:class:`StagedDirectory`: staged beside the target, renamed into its place when
  complete); ``twin check --record`` adds its references to a golden directory as one batch
  (:class:`FileBatch`). Either way a ``manifest.json`` is written last: every file with its
  size in bytes and SHA-256, the command, its exit status and whether every output it was
  asked for is there (``complete``, ``missing``, ``stopped``: what stopped it).
* **Checked when read.** A reader (:mod:`twin.outputs.compare`, :mod:`twin.verify.golden`, ``twin check
  --golden``) refuses, in one line (:class:`Incomplete`), a directory without a manifest, with
  a damaged one, or whose files are not the ones listed (:func:`read_manifest`,
  :func:`check_listed`).
* **Interrupts.** SIGINT and SIGTERM raise :class:`Interrupted` (:func:`interrupts_raise`,
  installed for every command by the command line), held while a commit renames
  (:func:`deferred_signals`); the command says what it kept (:func:`kept`) and exits 130 or
  143 (:func:`exit_status_of`).
* **Where outputs may go.** :func:`child_of`: a default output directory derived from a
  scenario's name stays one directory inside ``runs/``, whatever the name is.
* **Who is using one.** A command that writes into a directory for a while (``twin sweep``
  fills its store for minutes or hours, and is resumed there) holds ``lock(dir, command)``;
  any other command that would write there asks :func:`in_use` first and refuses with one
  line. The lock is an advisory ``flock`` on ``DIR/.twin.lock``: the kernel drops it when
  the holder exits, however it exits (SIGKILL included), so a stale lock file never blocks
  anyone. The file records the holder's command and process id for the message.
"""
from __future__ import annotations

import contextlib
import errno
import fnmatch
import glob
import hashlib
import json
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

from twin.errors import TwinError

LOCK_NAME = ".twin.lock"

try:  # POSIX
    import fcntl
except ImportError:  # pragma: no cover - Windows: no locking, as before
    fcntl = None


def _holder(path: Path) -> str:
    try:
        text = path.read_text(encoding="utf-8").strip()
    except OSError:
        return "another process"
    return text or "another process"


def in_use(directory: Path) -> str | None:
    """Who holds ``directory``'s lock ("'twin sweep' (process 123)"), or None if nobody does."""
    if fcntl is None:
        return None
    path = Path(directory) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return _holder(path)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


@contextlib.contextmanager
def lock(directory: Path, command: str):
    """Hold ``directory`` (created if missing) for ``command`` ("twin sweep") until the block
    ends; a one-line TwinError if another process holds it."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    if fcntl is None:  # pragma: no cover
        yield
        return
    path = directory / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise TwinError(f"{directory} is in use by {_holder(path)}; wait for it to finish or choose another "
                            f"directory") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"'{command}' (process {os.getpid()})\n".encode())
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def refuse_if_in_use(directory: Path) -> None:
    """A one-line TwinError if another command holds ``directory``."""
    who = in_use(directory)
    if who is not None:
        raise TwinError(f"{directory} is in use by {who}; wait for it to finish or choose another directory")


# ---- interrupts: SIGINT and SIGTERM as an exception that says which --------------------------------

SIGNAL_NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM, raised where the main thread was. A KeyboardInterrupt, so that every
    ``except KeyboardInterrupt`` clean-up (a sweep's, a pool's) runs for SIGTERM too; the exit
    status is the shell's convention, 128 + the signal's number (130, 143)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        return SIGNAL_NAMES.get(self.signum, f"signal {self.signum}")


def exit_status_of(exc: BaseException) -> int:
    """The exit status a command ends with when ``exc`` stops it: 128 + the signal for an
    interrupt (a bare KeyboardInterrupt is SIGINT's 130), 2 for a user error or a file error
    (the command line's one-line errors), 1 for anything else (a traceback)."""
    if isinstance(exc, Interrupted):
        return 128 + exc.signum
    if isinstance(exc, KeyboardInterrupt):
        return 128 + signal.SIGINT
    if isinstance(exc, (TwinError, OSError)):
        return 2
    return 1


def signal_name(exc: BaseException) -> str:
    return exc.name if isinstance(exc, Interrupted) else "SIGINT"


_deferred: list = []  # signals received while a commit could not be interrupted (see deferred_signals)


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


@contextlib.contextmanager
def interrupts_raise():
    """While the block runs, SIGINT and SIGTERM raise :class:`Interrupted` in the main thread
    (SIGTERM would otherwise end the process where it stands: no clean-up, no message, and
    SIGINT's KeyboardInterrupt does not say which signal came). The handlers before are put
    back afterwards. Outside the main thread, nothing changes (Python allows handlers there
    only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _raise_interrupted) for s in SIGNAL_NAMES}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


@contextlib.contextmanager
def deferred_signals():
    """SIGINT and SIGTERM held while the block runs (a commit's renames and its manifest: cut
    short, they would leave a directory neither old nor new), then delivered to the handlers
    there were before. Python-level, not a signal mask: a mask holds a signal for one thread,
    and the kernel hands a process's signal to any thread that does not block it (the video
    encoder's, a pool's), whose C handler would still raise in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    start = len(_deferred)
    old = {s: signal.signal(s, lambda signum, frame: _deferred.append(signum)) for s in SIGNAL_NAMES}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        got = _deferred[start:]
        del _deferred[start:]
        if got:
            signal.raise_signal(got[0])  # now, to the handler that was there: Interrupted, or the default


def kept(exc: BaseException, text: str) -> BaseException:
    """Attach to ``exc`` what the command kept of its outputs (one clause, said after its
    message); the first one attached stands."""
    if not getattr(exc, "twin_kept", None):
        try:
            exc.twin_kept = text
        except AttributeError:  # pragma: no cover - exceptions without a __dict__
            pass
    return exc


def kept_text(exc: BaseException) -> str:
    """What the command that ``exc`` stopped kept ("" if it did not say)."""
    return getattr(exc, "twin_kept", "") or ""


# ---- a hook for the kill tests ---------------------------------------------------------------------

_reached: set = set()

def test_point(name: str) -> None:
    """Where a test may stop the command: with ``TWIN_TEST_STOP_AT=NAME:MARKER`` in the
    environment, reaching point ``NAME`` writes this process's id to the file MARKER and waits
    there (up to 60 s) for the test's signal. Why a hook and not timing: the stages a kill
    test aims at (a trajectory half written, a commit under way) last milliseconds, and a
    test that guesses when to send its signal fails on a busy machine. Off (one dictionary
    look-up) without the variable."""
    spec = os.environ.get("TWIN_TEST_STOP_AT")
    if not spec or spec.partition(":")[0] != name or name in _reached:
        return
    _reached.add(name)  # the first time only: a point inside a loop stops it once
    marker = spec.partition(":")[2]
    start = len(_deferred)
    Path(marker).write_text(str(os.getpid()), encoding="ascii")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(_deferred) == start:  # a held signal ends the wait too
        time.sleep(0.01)


# ---- manifests ---------------------------------------------------------------------------------------

MANIFEST = "manifest.json"
RECORD_COMMAND = "twin check --record"  # the command whose manifest a golden directory has
MANIFEST_FORMAT = 1
PARTIAL = ".twin-partial-"  # in the name of every file or directory a command has not finished
# what 'twin run' writes into a run directory (and older versions left there, 'twin analytic''s
# trajectory_<controller>.csv among them): a run may replace a directory holding these and nothing else
RUN_OUTPUTS = ("metrics.json", "trajectory.csv", "trajectory.csv.gz", "figure.png", "video.mp4", "design.json",
               MANIFEST, LOCK_NAME)
_RUN_PATTERNS = ("trajectory_*.csv", ".video.*.partial.mp4")


def digest(path: Path) -> tuple[int, str]:
    """(size in bytes, SHA-256 in hex) of the file at ``path``."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        while True:
            block = fh.read(1 << 20)
            if not block:
                break
            size += len(block)
            h.update(block)
    return size, h.hexdigest()


def manifest_doc(command: str, files: dict, exit_status: int = 0, missing=(), stopped: str | None = None) -> dict:
    """The manifest: which command wrote the directory, how it ended (its exit status; whether
    every output it was asked for is there, and if not which are missing and what stopped it),
    and every file with its size and SHA-256 (``files``: relative path → (size, sha256))."""
    return {"format": MANIFEST_FORMAT, "command": command, "exit_status": int(exit_status),
            "complete": not missing, "missing": sorted(missing), "stopped": stopped,
            "files": {name: {"bytes": size, "sha256": sha} for name, (size, sha) in sorted(files.items())}}


def _write_json_atomically(path: Path, doc: dict) -> None:
    tmp = path.with_name(f".{path.name}{PARTIAL}{os.getpid()}")
    # a member a line, a file a line: readable, and diffable between two runs
    lines = [f"  {json.dumps(k)}: {json.dumps(v, ensure_ascii=False)}" for k, v in doc.items() if k != "files"]
    files = [f"    {json.dumps(k, ensure_ascii=False)}: {json.dumps(v)}" for k, v in doc.get("files", {}).items()]
    lines.append('  "files": {' + ("\n" + ",\n".join(files) + "\n  }" if files else "}"))
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write("{\n" + ",\n".join(lines) + "\n}\n")
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _listed_files(directory: Path) -> dict:
    """relative path → (size, sha256) of every file under ``directory`` but the manifest and the lock."""
    out = {}
    for path in sorted(directory.rglob("*")):
        if path.is_file() and path.name not in (MANIFEST, LOCK_NAME):
            out[path.relative_to(directory).as_posix()] = digest(path)
    return out


class Incomplete(TwinError):
    """A directory without a complete manifest, or whose files are not the ones it lists."""


def read_manifest(directory: Path, commands=None, what: str = "directory",
                  again: str = "run the command that writes it again") -> dict:
    """``directory``'s manifest; :class:`Incomplete` (one line, ending in ``again``: what to do)
    if it has none, a damaged one or one of another command (``commands``: the ones
    accepted, None: any)."""
    directory = Path(directory)
    path = directory / MANIFEST
    if not path.is_file():
        raise Incomplete(f"{directory}: an incomplete {what}: no {MANIFEST} (the command writing it was interrupted "
                         f"or failed, or it is older than manifests); {again}")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise Incomplete(f"{path}: not readable as a manifest ({' '.join(str(exc).split())}); {again}") from None
    files = doc.get("files") if isinstance(doc, dict) else None
    if not isinstance(files, dict) or doc.get("format") != MANIFEST_FORMAT or not all(
            isinstance(v, dict) and isinstance(v.get("bytes"), int) and isinstance(v.get("sha256"), str)
            for v in files.values()):
        raise Incomplete(f"{path}: not a manifest of this mtwip-twin (format {MANIFEST_FORMAT}, files with bytes "
                         f"and sha256); {again}")
    if commands is not None and doc.get("command") not in commands:
        raise Incomplete(f"{directory}: written by {doc.get('command')!r}, not {' or '.join(map(repr, commands))}")
    return doc


def check_listed(directory: Path, doc: dict, name: str, data: bytes | None = None) -> None:
    """:class:`Incomplete` unless ``directory/name`` is listed in the manifest ``doc`` and has the
    size and SHA-256 listed there (``data``: its bytes, if already read)."""
    directory = Path(directory)
    entry = doc["files"].get(name)
    path = directory / name
    if entry is None:
        raise Incomplete(f"{path}: not listed in {directory / MANIFEST} (written by another command, or by one "
                         f"that did not finish); run the command again")
    if data is None:
        try:
            size, sha = digest(path)
        except FileNotFoundError:
            raise Incomplete(f"{path}: listed in {directory / MANIFEST} but missing; the directory is incomplete") \
                from None
    else:
        size, sha = len(data), hashlib.sha256(data).hexdigest()
    if size != entry["bytes"] or sha != entry["sha256"]:
        how = (f"{size} bytes, the manifest lists {entry['bytes']}" if size != entry["bytes"]
               else "its SHA-256 is not the one listed")
        raise Incomplete(f"{path}: not the file {directory / MANIFEST} lists ({how}): changed or cut short after "
                         f"it was written")


def check_all_present(directory: Path, doc: dict) -> None:
    """:class:`Incomplete` if a file the manifest lists is missing or of another size (a stat
    each: the contents are checked where they are read, :func:`check_listed`)."""
    directory = Path(directory)
    for name, entry in doc["files"].items():
        try:
            size = (directory / name).stat().st_size
        except OSError:
            raise Incomplete(f"{directory / name}: listed in {directory / MANIFEST} but missing; the directory is "
                             f"incomplete") from None
        if size != entry["bytes"]:
            raise Incomplete(f"{directory / name}: not the file {directory / MANIFEST} lists ({size} bytes, the "
                             f"manifest lists {entry['bytes']}): changed or cut short after it was written")


def seal(directory: Path, command: str, exit_status: int = 0, missing=(), stopped: str | None = None) -> dict:
    """Write ``directory``'s manifest over the files it holds now (for tests and tools that
    build a directory by hand; the commands write theirs as they finish)."""
    doc = manifest_doc(command, _listed_files(Path(directory)), exit_status, missing, stopped)
    _write_json_atomically(Path(directory) / MANIFEST, doc)
    return doc


# ---- where outputs may go ------------------------------------------------------------------------------

def child_of(base: Path, name: str, what: str) -> Path:
    """``base/name`` if it is one directory directly inside ``base`` once resolved, else a
    one-line TwinError: a name with a path separator, ``.``, ``..``, an absolute path, a NUL,
    or a symbolic link elsewhere would put the outputs outside ``base``. The second line of
    defence behind the scenario schema's rule for names: it holds whatever a name is."""
    base = Path(base)
    try:
        root = base.resolve()
        path = (base / name).resolve()
        ok = "\x00" not in name and path.parent == root and name not in ("", ".", "..")
    except (ValueError, OSError, RuntimeError):  # a NUL (ValueError), a symlink loop (RuntimeError)
        path, ok = None, False
    if not ok:
        where = f" would put the outputs at {path}," if path is not None and path != root else ""
        raise TwinError(f"{what} {name!r}{where} not in a directory of its own inside {root}/; give --out DIR, "
                        f"or a name without path separators, '.', '..' or NUL")
    return base / name


def _absolute(path: Path) -> Path:
    """``path`` resolved (a symbolic link to a directory is the directory it names); one line
    if it cannot be."""
    try:
        return Path(path).resolve()
    except (ValueError, OSError, RuntimeError) as exc:
        raise TwinError(f"{str(path)!r}: not a usable output path ({' '.join(str(exc).split())})") from None


def _try_lock_dir(path: Path):
    """An fd holding an exclusive flock on the directory ``path``, or None if another process
    holds it (or it is gone)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return None
    if fcntl is not None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            return None
    return fd


def _remove_stale(candidates) -> None:
    """Remove the stagings nobody holds (left by a command killed with SIGKILL, or by a power
    cut): their flock is free once their process is gone."""
    for path in candidates:
        if path.is_dir() and not path.is_symlink():
            fd = _try_lock_dir(path)
            if fd is not None:
                try:
                    shutil.rmtree(path, ignore_errors=True)
                finally:
                    os.close(fd)
        else:
            with contextlib.suppress(OSError):
                path.unlink()


_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap the directories ``a`` and ``b`` in one step (Linux's renameat2 RENAME_EXCHANGE);
    False where that is not available (another kernel or file system)."""
    if sys.platform != "linux":
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.EXDEV):
        return False
    raise OSError(err, os.strerror(err), str(b))


@contextlib.contextmanager
def written_whole(out, command: str):
    """``with written_whole(out, "twin replay") as path:`` write the files into ``path``; they
    replace ``out`` as a whole when the block ends, and nothing of them when it raises (the error
    then says what ``out`` still holds, :func:`kept`)."""
    staged = StagedDirectory(out, command)
    try:
        yield staged.path
        staged.commit(0)
    except BaseException as exc:
        staged.discard()
        raise kept(exc, staged.unchanged())
    finally:
        staged.discard()


class StagedDirectory:
    """A run directory written as a unit (``twin run``).

    The outputs are written into a hidden directory beside the target,
    ``.<name>.twin-partial-XXXX``, with a manifest last (every file's size and SHA-256 and
    the command's exit status), and the finished directory then takes the target's place in
    one rename (an exchange: the earlier run's directory goes as a whole and is deleted).

    Why this and not atomic writes of each file with a manifest written last in the target
    itself: a run directory is one result (metrics, trajectory, figure, video of the same
    runs), and replacing it file by file leaves, for as long as the writing takes, and for
    good after SIGKILL or a full disk, a directory mixing the new run's files with the
    earlier one's (the old video beside new metrics) or holding neither run whole. Staged,
    the target is at every instant either the earlier run, untouched, or the new one,
    complete; a failure or an interrupt before the commit loses nothing the directory held.
    The price: the target is replaced as a whole, so a run refuses a directory holding files
    it did not write (a user's notes, a sweep) instead of deleting them with it, and the
    staging needs the space of one more run until the commit. Manifests are still written:
    they tell a complete directory from one an older version or an interrupted command
    left, and a reader checks the files it reads against them.

    Files are not fsync'ed: what is guarded against is the process ending (a signal, an
    error, a full disk), after which the kernel still writes what it was given; a power cut
    may lose the last run (the manifest then no longer matches, and readers say so).

    A staging is held by an flock on its directory while its command runs; one nobody holds
    was left by a process killed with SIGKILL, and the next command writing beside it
    removes it."""

    def __init__(self, target: Path, command: str, what: str = "run"):
        self.shown = Path(target)
        self.target = _absolute(target)
        self.command = command
        self.what = what
        self.existed = self.target.is_dir()
        self._staging: Path | None = None
        self._fd: int | None = None
        self.committed = False
        self.check()

    # -- before anything is written --
    def check(self) -> None:
        """One line if the target cannot become this run's directory: a file, a directory
        another command holds, one holding files no run wrote, or the current directory (or
        one above it), which would be swapped from under the shell that runs the command."""
        t = self.target
        if t.exists() and not t.is_dir():
            raise TwinError(f"{self.shown}: exists and is not a directory; give an output directory")
        try:
            cwd = Path.cwd().resolve()
        except OSError:
            cwd = None
        if cwd is not None and (cwd == t or t in cwd.parents):
            raise TwinError(f"{self.shown}: is the current directory or holds it; a {self.what} replaces its "
                            f"directory as a whole: give a directory of its own, e.g. --out runs/NAME")
        if os.path.ismount(t):  # it cannot be swapped, and the staging beside it would be on another disk
            raise TwinError(f"{self.shown}: is a mount point; a {self.what} replaces its directory as a whole: give "
                            f"a directory inside it, e.g. --out {self.shown / 'run'}")
        if t.is_dir():
            refuse_if_in_use(t)
            foreign = self._foreign()
            if foreign:
                more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
                raise TwinError(f"{self.shown}: holds {', '.join(foreign[:3])}{more}, which no run wrote; a "
                                f"{self.what} replaces its whole directory, so it writes only into a new, empty or "
                                f"earlier run's directory: give another --out, or move them")

    def _foreign(self) -> list[str]:
        """The entries of the target that no run wrote (a manifest's files and the known outputs
        are a run's)."""
        listed: set = set()
        with contextlib.suppress(Exception):
            listed = set(json.loads((self.target / MANIFEST).read_text(encoding="utf-8"))["files"])
        out = []
        for entry in sorted(self.target.iterdir()):
            name = entry.name
            ours = (name in RUN_OUTPUTS or name in listed or any(fnmatch.fnmatch(name, p) for p in _RUN_PATTERNS))
            if not ours or (entry.is_dir() and not entry.is_symlink()):
                out.append(name + ("/" if entry.is_dir() else ""))
        return out

    # -- while writing --
    @property
    def path(self) -> Path:
        """The staging directory to write into (made on first use)."""
        if self._staging is None:
            parent = self.target.parent
            parent.mkdir(parents=True, exist_ok=True)
            prefix = f".{self.target.name}{PARTIAL}"
            _remove_stale(parent.glob(glob.escape(prefix) + "*"))
            while True:
                staging = Path(tempfile.mkdtemp(prefix=prefix, dir=parent))
                fd = os.open(staging, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
                if fcntl is not None:
                    fcntl.flock(fd, fcntl.LOCK_EX)
                if staging.is_dir():  # not taken for stale by another command between mkdtemp and flock
                    break
                os.close(fd)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(staging, 0o777 & ~umask)  # mkdtemp made it private; a run directory is an ordinary one
            self._staging, self._fd = staging, fd
        return self._staging

    @property
    def started(self) -> bool:
        """Whether anything was written (into the staging) yet."""
        return self._staging is not None

    # -- at the end --
    def commit(self, exit_status: int = 0, missing=(), stopped: str | None = None) -> list[Path]:
        """Write the manifest over what the staging holds, then put it in the target's place
        (SIGINT and SIGTERM held meanwhile); the files, as the user named them."""
        if self.committed:
            return self.files()
        staging = self.path
        _write_json_atomically(staging / MANIFEST, manifest_doc(self.command, _listed_files(staging), exit_status,
                                                                missing, stopped))
        test_point("commit")
        with deferred_signals():
            with lock(self.target, self.command):  # a sweep that took the target meanwhile is refused here
                foreign = self._foreign()
                if foreign:
                    raise TwinError(f"{self.shown}: gained {', '.join(foreign[:3])} while this {self.what} ran; "
                                    f"nothing was replaced: give another --out, or move them")
                if not _exchange(staging, self.target):
                    old = self.target.with_name(f".{self.target.name}{PARTIAL}old-{os.getpid()}")
                    os.rename(self.target, old)
                    try:
                        os.rename(staging, self.target)
                    except OSError:
                        os.rename(old, self.target)
                        raise
                    staging = old
                test_point("exchanged")
                self.committed = True
                self._staging = staging  # now the earlier directory (or the empty one lock() made)
                shutil.rmtree(staging, ignore_errors=True)
        return self.files()

    def files(self) -> list[Path]:
        """The files of the committed directory, as the user named them (the manifest last)."""
        names = sorted(p.name for p in self.target.iterdir() if p.is_file() and p.name not in (MANIFEST, LOCK_NAME))
        return [self.shown / n for n in names] + [self.shown / MANIFEST]

    def discard(self) -> None:
        """Remove the staging (if not committed) and let go of it; the target is as it was."""
        if self._staging is not None and not self.committed:
            shutil.rmtree(self._staging, ignore_errors=True)
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def unchanged(self) -> str:
        """What an interrupted or failed command leaves, as a clause: nothing of its own."""
        if self.committed:
            return f"this {self.what} was complete: {self.shown} holds it, with its {MANIFEST}"
        return (f"nothing of this {self.what} was written: {self.shown} is as it was" if self.existed else
                f"nothing of this {self.what} was written ({self.shown} was not created)")


class FileBatch:
    """Files added to a directory that keeps the others (``twin check --record``: golden
    references accumulate across commands, a scenario's beside another's).

    Each file is written under a hidden name (``.<name>.twin-partial-XXXX.npz``) beside its
    place; when all are written, the manifest goes, each takes its place by a rename, and the
    new manifest lists every file the directory holds (those listed before, still there,
    and the new ones) with its size and SHA-256 and the command's exit status: SIGINT and
    SIGTERM are held meanwhile, so an interrupt leaves the directory as it was or complete.
    Why not a staged copy of the directory (as run directories are written): a golden
    directory keeps every scenario's references, and copying it for each record would cost
    in proportion to all of them, and a record replaces some files, never the whole.
    The directory is locked (:func:`lock`) while the batch runs: two records into it would
    each write a manifest without the other's files."""

    def __init__(self, root: Path, command: str):
        self.root = Path(root)
        self.command = command
        self._pending: dict = {}
        self.committed = False
        if self.root.exists() and not self.root.is_dir():
            raise TwinError(f"{self.root}: exists and is not a directory; give a directory")
        refuse_if_in_use(self.root)
        self._lock = None

    def __enter__(self):
        self._lock = lock(self.root, self.command)
        self._lock.__enter__()
        # we hold the directory: whatever is unfinished in it was left by a killed command
        _remove_stale(p for p in self.root.rglob(f"*{PARTIAL}*") if p.name.startswith("."))
        return self

    def __exit__(self, *exc):
        for tmp in self._pending.values():
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._pending.clear()
        self._lock.__exit__(*exc)
        return False

    def temp(self, relative: str) -> Path:
        """Where to write the file that will be ``root/relative`` (a hidden name beside it)."""
        final = self.root / relative
        root = self.root.resolve()
        if root not in final.resolve().parents:
            raise TwinError(f"{final}: outside {self.root}; refused")
        final.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{final.stem}{PARTIAL}", suffix=final.suffix, dir=final.parent)
        os.close(fd)
        self._pending[relative] = Path(tmp)
        return Path(tmp)

    def commit(self, exit_status: int = 0) -> int:
        """Put every written file in its place and write the manifest; the number of files."""
        files = {}
        with contextlib.suppress(Incomplete):
            old = read_manifest(self.root)
            for name, entry in old["files"].items():  # kept if still there as listed
                with contextlib.suppress(OSError):
                    if name not in self._pending and (self.root / name).stat().st_size == entry["bytes"]:
                        files[name] = (entry["bytes"], entry["sha256"])
        new = {name: digest(tmp) for name, tmp in self._pending.items()}
        with deferred_signals():
            (self.root / MANIFEST).unlink(missing_ok=True)  # cut short from here on, it reads as incomplete
            for i, (name, tmp) in enumerate(list(self._pending.items())):
                os.replace(tmp, self.root / name)
                del self._pending[name]
                if i == 0:
                    test_point("record-commit")
            files.update(new)
            _write_json_atomically(self.root / MANIFEST, manifest_doc(self.command, files, exit_status))
            self.committed = True
        return len(new)


__all__ = ["Incomplete", "Interrupted", "FileBatch", "LOCK_NAME", "MANIFEST", "StagedDirectory", "check_all_present",
           "check_listed", "child_of", "deferred_signals", "digest", "exit_status_of", "in_use", "interrupts_raise",
           "kept", "kept_text", "lock", "read_manifest", "refuse_if_in_use", "seal", "test_point"]
