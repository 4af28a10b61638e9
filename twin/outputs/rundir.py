"""Output directories: written as a unit, checked when read, and who is using one.

* **Written as a unit.** ``twin run`` writes its run directory as a
  whole (:class:`StagedDirectory`: staged beside the target, renamed into its place when
  complete); ``twin check --record`` adds its references to a golden directory as one batch
  (:class:`FileBatch`). Either way a ``manifest.json`` is written last: every file with its
  size in bytes and SHA-256, the command, its exit status and whether every output it was
  asked for is there (``complete``, ``missing``, ``stopped``: what stopped it).
* **Checked when read.** A reader (:mod:`twin.outputs.compare`, :mod:`twin.outputs.golden`, ``twin check
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
import sys
import tempfile
from pathlib import Path

from twin.errors import TwinError, shown
from twin.inputs import json_loads
# the interrupts (a process-wide concern, below the outputs), used here and named here as before
from twin.interrupts import (SIGNAL_NAMES, Interrupted, deferred_signals, exit_status_of, hold_from_start,  # noqa: F401
                             interrupts_raise, keep_so_far, kept, kept_so_far, kept_text, leaving, signal_name,
                             signal_received, started, test_point)

LOCK_NAME = ".twin.lock"

try:  # POSIX
    import fcntl
except ImportError:  # pragma: no cover - Windows: no locking, as before
    fcntl = None


LOCK_SUFFIX = ".twin-lock"  # the lock beside an output directory: .NAME.twin-lock in its parent

_HELD: dict = {}  # lock file → [fd, count, command]: what this process holds (a command may hold one twice)


def _holder(path: Path) -> str:
    try:
        with open(path, "rb") as fh:
            text = fh.read(200).decode("utf-8", "replace").strip()
    except OSError:
        return "another process"
    return shown(text, 120)[1:-1] if text and not text.isprintable() else (text or "another process")


def lock_path(directory: Path) -> Path:
    """The lock file of ``directory``: beside it, in its parent (``runs/.NAME.twin-lock``), so
    that it survives the directory's being swapped for a new one as a whole, and so that a
    command holds a directory that does not exist yet."""
    d = Path(directory)
    with contextlib.suppress(OSError, RuntimeError, ValueError):
        d = d.resolve()
    return d.parent / f".{d.name}{LOCK_SUFFIX}"


def in_use(directory: Path, command: str | None = None) -> str | None:
    """Who holds ``directory`` ("'twin sweep' (process 123)"), or None if nobody does (or this
    process does, for ``command``: a command holds its directory again while it writes it)."""
    if fcntl is None:
        return None
    for path in (lock_path(directory), Path(directory) / LOCK_NAME):  # and an earlier version's lock inside it
        if str(path) in _HELD:
            if _HELD[str(path)][2] == command:
                continue
            return f"'{_HELD[str(path)][2]}' (process {os.getpid()})"
        try:
            fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
        except OSError:
            continue
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except OSError:
                return _holder(path)
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)
    return None


def acquire(directory: Path, command: str) -> str:
    """Hold ``directory`` for ``command`` ("twin run") until :func:`release`: a one-line
    TwinError if another process holds it. A process may hold a directory more than once
    (``twin run`` holds its output directory from the start, and the run writing it again)."""
    path = lock_path(directory)
    key = str(path)
    if key in _HELD:
        if _HELD[key][2] != command:  # another command of this process (a test's, a script's)
            raise TwinError(f"{directory} is in use by '{_HELD[key][2]}' (process {os.getpid()}); wait for it to "
                            f"finish or choose another directory")
        _HELD[key][1] += 1
        return key
    if fcntl is None:  # pragma: no cover - Windows: no locking, as before
        _HELD[key] = [None, 1, command]
        return key
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise TwinError(f"{directory} is in use by {_holder(path)}; wait for it to finish or choose another "
                            f"directory") from None
        try:  # the file a releaser unlinked after this process opened it is no lock: open it anew
            same = os.fstat(fd).st_ino == os.stat(path, follow_symlinks=False).st_ino
        except OSError:
            same = False
        if same:
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.write(fd, f"'{command}' (process {os.getpid()})\n".encode())
    _HELD[key] = [fd, 1, command]
    return key


def release(key: str) -> None:
    """Let go of what :func:`acquire` held (the lock file goes when the last hold ends)."""
    entry = _HELD.get(key)
    if entry is None:
        return
    entry[1] -= 1
    if entry[1] > 0:
        return
    del _HELD[key]
    fd = entry[0]
    if fd is None:
        return
    with contextlib.suppress(OSError):
        os.unlink(key)  # while still held: a command opening it now finds it unlinked and starts anew
    with contextlib.suppress(OSError):
        fcntl.flock(fd, fcntl.LOCK_UN)
    os.close(fd)


@contextlib.contextmanager
def lock(directory: Path, command: str):
    """Hold ``directory`` (created if missing) for ``command`` ("twin sweep") until the block
    ends; a one-line TwinError if another process holds it."""
    key = acquire(directory, command)
    try:
        Path(directory).mkdir(parents=True, exist_ok=True)
        yield
    finally:
        release(key)


def refuse_if_in_use(directory: Path, command: str | None = None) -> None:
    """A one-line TwinError if another command holds ``directory`` (``command``: this one, which
    may hold it already)."""
    who = in_use(directory, command)
    if who is not None:
        raise TwinError(f"{directory} is in use by {who}; wait for it to finish or choose another directory")


# ---- manifests ---------------------------------------------------------------------------------------

MANIFEST = "manifest.json"
RECORD_COMMAND = "twin check --record"  # the command whose manifest a golden directory has
MANIFEST_FORMAT = 1
PARTIAL = ".twin-partial-"  # in the name of every file or directory a command has not finished
INCOMPLETE = "-incomplete"  # NAME-incomplete: a new result kept beside an earlier complete one (commit_incomplete)
# what 'twin run' writes into a run directory (and older versions left there, 'twin analytic''s
# trajectory_<controller>.csv among them): a run may replace a directory holding these and nothing else
RUN_OUTPUTS = ("metrics.json", "trajectory.csv", "trajectory.csv.gz", "figure.png", "video.mp4", "design.json",
               MANIFEST, LOCK_NAME)
_RUN_PATTERNS = ("trajectory_*.csv", ".video.*.partial.mp4")
SWEEP_COMMAND = "twin sweep"
# Each command's output directory, by the names it writes there (patterns; "NAME/" a directory):
# a directory holding only these, with no manifest of another command's, may be that command's
# output. Every command that writes a directory refuses one another command wrote (owner()):
# a replay's --out over a run's folder deleted the run.
OUTPUTS = {
    "twin run": (*RUN_OUTPUTS, *_RUN_PATTERNS, "sensor-logs/"),
    "twin replay": ("replay.json", "estimates.csv", "figure.png", "figure-*.png", MANIFEST, LOCK_NAME),
    "twin calibrate": ("report.json", "calibration.toml", "figure.png", MANIFEST, LOCK_NAME),
    "twin compare": ("comparison.json", "comparison.png", MANIFEST, LOCK_NAME),
    SWEEP_COMMAND: ("sweep.json", "samples.jsonl", "sweep.csv", "summary.md", "summary.json", "success.png",
                    "distributions.png", "paired.png", "sensor-logs/", ".sweep.json.partial-*", MANIFEST, LOCK_NAME),
}
RUN_COMMANDS = ("twin run",)  # what wrote a run directory that twin compare reads
_SAME = {"twin run": ("twin run", "twin analytic")}  # what a command may replace besides its own ('twin analytic' gave way to 'twin run')
MANIFEST_BYTES = 64 << 20  # a manifest larger than this is not one (a file per line: about 150 bytes each)


def owner(directory: Path) -> str | None:
    """Which command wrote ``directory``: its manifest's ``command``, else ``"twin sweep"`` for a
    sweep not yet finished (its sweep.json), else None (none of ours, or not one yet)."""
    directory = Path(directory)
    path = directory / MANIFEST
    try:
        if path.is_file() and path.stat().st_size <= MANIFEST_BYTES:
            doc = json.loads(path.read_bytes().decode("utf-8"))
            command = doc.get("command") if isinstance(doc, dict) else None
            if isinstance(command, str):
                return command
    except (OSError, ValueError, RecursionError):
        pass
    if (directory / "sweep.json").is_file():
        return SWEEP_COMMAND
    return None


def refuse_another_commands(directory: Path, command: str, what: str = "directory") -> None:
    """A one-line TwinError if ``directory`` is the output of another command than ``command``
    (its manifest says so, or it holds a sweep): a command never writes over, mixes with or
    deletes another's results."""
    who = owner(directory)
    if who is None or who == command or who in _SAME.get(command, ()):
        return
    why = "its sweep.json" if who == SWEEP_COMMAND and not (Path(directory) / MANIFEST).is_file() else \
        f"its {MANIFEST}"
    raise TwinError(f"{directory}: holds the output of {shown(who, 40)} ({why} says so); '{command}' writes only "
                    f"into a new, empty or earlier '{command}' {what}: give another --out")


def foreign_entries(directory: Path, command: str) -> list[str]:
    """The entries of ``directory`` that ``command`` did not write: neither its known outputs
    (:data:`OUTPUTS`) nor files its own manifest lists ("NAME/" for a directory)."""
    directory = Path(directory)
    listed: set = set()
    if owner(directory) == command:
        with contextlib.suppress(Exception):
            listed = set(json.loads((directory / MANIFEST).read_text(encoding="utf-8"))["files"])
    tops = {name.split("/", 1)[0] + "/" for name in listed if "/" in name}
    patterns = OUTPUTS.get(command, (MANIFEST, LOCK_NAME))
    out = []
    for entry in sorted(directory.iterdir()):
        name = entry.name
        if entry.is_dir() and not entry.is_symlink():
            ours = name + "/" in patterns or name + "/" in tops
        else:
            ours = name in listed or any(fnmatch.fnmatch(name, p) for p in patterns if not p.endswith("/"))
        if not ours:
            out.append(name + ("/" if entry.is_dir() else ""))
    return out


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
        doc = json_loads(path.read_text(encoding="utf-8"))  # nesting bounded (twin.inputs): no RecursionError
    except (OSError, ValueError) as exc:
        raise Incomplete(f"{path}: not readable as a manifest ({' '.join(str(exc).split())}); {again}") from None
    files = doc.get("files") if isinstance(doc, dict) else None
    if not isinstance(files, dict) or doc.get("format") != MANIFEST_FORMAT or not all(
            isinstance(v, dict) and isinstance(v.get("bytes"), int) and isinstance(v.get("sha256"), str)
            for v in files.values()):
        raise Incomplete(f"{path}: not a manifest of this mtwip-twin (format {MANIFEST_FORMAT}, files with bytes "
                         f"and sha256); {again}")
    if commands is not None and doc.get("command") not in commands:
        raise TwinError(f"{directory}: holds the output of {shown(doc.get('command'), 40)}, not a {what} (one of "
                        f"{' or '.join(map(repr, commands))})")
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
        self._hold: str | None = None
        self.committed = False
        self.aside: Path | None = None  # where an incomplete result went instead of the target (commit_aside)
        self.check()
        # held from now to the end (discard): a second command writing here is refused at its start; it used to
        # run alongside, and both said "wrote" while the last one's results stood
        self._hold = acquire(self.shown, command)
        try:
            self.check()  # again, holding it: what another command left meanwhile
        except BaseException:
            self.discard()
            raise

    # -- before anything is written --
    def check(self) -> None:
        """One line if the target cannot become this run's directory: a file, a directory
        another command holds or wrote, one holding files no run wrote, or the current
        directory (or one above it), which would be swapped from under the shell that runs
        the command."""
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
            if self._hold is None:
                refuse_if_in_use(self.shown, self.command)
            refuse_another_commands(self.shown, self.command)
            foreign = self._foreign()
            if foreign:
                more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
                raise TwinError(f"{self.shown}: holds {', '.join(foreign[:3])}{more}, which no "
                                f"{self.command[5:] if self.command.startswith('twin ') else self.command} wrote; a "
                                f"{self.what} replaces its whole directory, so it writes only into a new, empty or "
                                f"earlier {self.what}'s directory: give another --out, or move them")

    def _foreign(self) -> list[str]:
        """The entries of the target that no run of this command wrote."""
        out = foreign_entries(self.target, self.command)
        for same in _SAME.get(self.command, ()):  # an earlier command's directory that this one replaces
            if same != self.command and owner(self.target) == same:
                out = [n for n in out if n in foreign_entries(self.target, same)]
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
            self._swap(staging, self.target)
        return self.files()

    def _swap(self, staging: Path, target: Path) -> None:
        """Put ``staging`` in ``target``'s place in one step and delete what was there (the
        directory is held: nobody else writes it meanwhile)."""
        if target.is_dir():
            foreign = foreign_entries(target, self.command) if target != self.target else self._foreign()
            if foreign:
                raise TwinError(f"{target}: gained {', '.join(foreign[:3])} while this {self.what} ran; "
                                f"nothing was replaced: give another --out, or move them")
        if not target.exists():
            os.rename(staging, target)
            old = None
        elif _exchange(staging, target):
            old = staging
        else:
            old = target.with_name(f".{target.name}{PARTIAL}old-{os.getpid()}")
            os.rename(target, old)
            try:
                os.rename(staging, target)
            except OSError:
                os.rename(old, target)
                raise
        self.committed = True
        keep_so_far(self.unchanged())  # what a signal from now on says stands: this output, complete
        self._staging = old  # the earlier directory, if there was one
        test_point("exchanged")
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def holds_complete(self) -> bool:
        """Whether the target holds an earlier complete output of this command (its manifest says so)."""
        if not self.target.is_dir() or owner(self.target) not in (self.command, *_SAME.get(self.command, ())):
            return False
        with contextlib.suppress(Exception):
            return bool(json.loads((self.target / MANIFEST).read_text(encoding="utf-8")).get("complete"))
        return False

    def commit_incomplete(self, exit_status: int, missing=(), stopped: str | None = None) -> Path:
        """Keep an incomplete result (the data of a run whose figure or video failed): in the
        target, unless it holds an earlier complete one, which is kept until a new one is
        complete; then beside it, in ``NAME-incomplete`` (replacing an earlier incomplete one
        there, never anything else). Where it went."""
        if not self.holds_complete():
            self.commit(exit_status, missing, stopped)
            return self.shown
        aside = self.target.with_name(f"{self.target.name}{INCOMPLETE}")
        hold = acquire(aside, self.command)
        try:
            if aside.exists() and (not aside.is_dir() or owner(aside) not in (self.command, None)
                                   or foreign_entries(aside, self.command) or self._complete(aside)):
                raise TwinError(f"{aside}: exists and is not an incomplete {self.what}'s directory; the new "
                                f"{self.what} was not kept")
            staging = self.path
            _write_json_atomically(staging / MANIFEST, manifest_doc(self.command, _listed_files(staging),
                                                                    exit_status, missing, stopped))
            with deferred_signals():
                self._swap(staging, aside)
        finally:
            release(hold)
        self.aside = self.shown.with_name(aside.name)
        return self.aside

    @staticmethod
    def _complete(directory: Path) -> bool:
        with contextlib.suppress(Exception):
            return bool(json.loads((directory / MANIFEST).read_text(encoding="utf-8")).get("complete"))
        return False

    def files(self) -> list[Path]:
        """The files of the committed directory, as the user named them (the manifest last)."""
        where, shown_as = (self.target, self.shown) if self.aside is None else (
            self.target.with_name(self.aside.name), self.aside)
        names = sorted(p.name for p in where.iterdir() if p.is_file() and p.name not in (MANIFEST, LOCK_NAME))
        return [shown_as / n for n in names] + [shown_as / MANIFEST]

    def discard(self) -> None:
        """Remove the staging (if not committed) and let go of it and of the target; the target is
        as it was."""
        if self._staging is not None and not self.committed:
            shutil.rmtree(self._staging, ignore_errors=True)
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        if self._hold is not None:
            release(self._hold)
            self._hold = None

    close = discard

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.discard()

    def unchanged(self) -> str:
        """What an interrupted or failed command leaves, as a clause: nothing of its own."""
        if self.committed and self.aside is not None:
            return (f"this {self.what}'s data are in {self.aside}, incomplete; {self.shown} still holds the earlier "
                    f"complete {self.what}")
        if self.committed:
            return f"this {self.what} was complete: {self.shown} holds it, with its {MANIFEST}"
        return (f"nothing of this {self.what} was written: {self.shown} is as it was" if self.existed else
                f"nothing of this {self.what} was written ({self.shown} was not created)")


JOURNAL = ".twin-journal.json"  # a FileBatch's commit under way: what goes where, and the manifest after


class FileBatch:
    """Files added to a directory that keeps the others (``twin check --record``: golden
    references accumulate across commands, a scenario's beside another's; ``twin surface``).

    Each file is written under a hidden name (``.<name>.twin-partial-XXXX.npz``) beside its
    place. When all are written, a journal (:data:`JOURNAL`: each hidden file's place, and the
    new manifest, which lists every file the directory will hold with its size and SHA-256
    and the command's exit status) is written in one step, then each file takes its place by a
    rename, then the manifest, then the journal goes. A command killed anywhere in between,
    SIGKILL included, leaves a journal that the next command to read or write the directory
    carries through (:func:`finish_batch`), so the directory is the earlier one or the new one,
    whole, never a mix (a killed record's references used to be refused until recorded again).
    SIGINT and SIGTERM are held meanwhile. Why not a staged copy of the directory (as run
    directories are written): a golden directory keeps every scenario's references, and
    copying it for each record would cost in proportion to all of them.
    The directory is held (:func:`acquire`) while the batch runs: two records into it would
    each write a manifest without the other's files. A directory another command wrote is
    refused (:func:`refuse_another_commands`)."""

    def __init__(self, root: Path, command: str):
        self.root = Path(root)
        self.command = command
        self._pending: dict = {}
        self.committed = False
        if self.root.exists() and not self.root.is_dir():
            raise TwinError(f"{self.root}: exists and is not a directory; give a directory")
        refuse_if_in_use(self.root)
        if self.root.is_dir():
            refuse_another_commands(self.root, command)
        self._hold = None

    def __enter__(self):
        self._hold = acquire(self.root, self.command)
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            refuse_another_commands(self.root, self.command)
            finish_batch(self.root, held=True)  # a commit a killed command began: carried through first
            # we hold the directory: whatever else is unfinished in it was left by a killed command
            _remove_stale(p for p in self.root.rglob(f"*{PARTIAL}*") if p.name.startswith("."))
        except BaseException:
            release(self._hold)
            raise
        return self

    def __exit__(self, *exc):
        for tmp in self._pending.values():
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._pending.clear()
        release(self._hold)
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
        files.update(new)
        moves = {name: Path(os.path.relpath(tmp, self.root)).as_posix() for name, tmp in self._pending.items()}
        _write_json_atomically(self.root / JOURNAL, {"format": MANIFEST_FORMAT, "moves": moves,
                                                     "manifest": manifest_doc(self.command, files, exit_status)})
        with deferred_signals():
            for i, (name, tmp) in enumerate(list(self._pending.items())):
                os.replace(tmp, self.root / name)
                del self._pending[name]
                if i == 0:
                    test_point("record-commit")
            _finish(self.root)
            self.committed = True
            keep_so_far(f"the record is complete: {self.root} holds {len(new)} new file{'s' * (len(new) != 1)} "
                        f"({MANIFEST})")
        return len(new)


def _finish(root: Path) -> None:
    """Carry the journal of ``root`` through: the renames not yet made, the manifest, then the
    journal goes (held by the caller)."""
    journal = Path(root) / JOURNAL
    doc = json.loads(journal.read_text(encoding="utf-8"))
    for name, tmp in doc["moves"].items():
        src, dst = Path(root) / tmp, Path(root) / name
        inside = Path(root).resolve()
        if PARTIAL not in src.name or inside not in dst.resolve().parents or inside not in src.resolve().parents:
            raise Incomplete(f"{journal}: not a journal of this mtwip-twin's (it names {shown(tmp, 60)}); delete it "
                             f"and record again")
        if src.exists():
            os.replace(src, dst)
    _write_json_atomically(Path(root) / MANIFEST, doc["manifest"])
    journal.unlink()


def finish_batch(root: Path, held: bool = False) -> bool:
    """If a command was killed while it committed a :class:`FileBatch` into ``root`` (a journal
    is there), finish that commit now: the directory becomes the complete new one. True if it
    did. ``held``: the caller holds ``root`` already (else it is held here; a one-line error if
    another command holds it)."""
    root = Path(root)
    if not (root / JOURNAL).is_file():
        return False
    key = None if held else acquire(root, "finishing an interrupted record")
    try:
        if not (root / JOURNAL).is_file():
            return False
        try:
            with deferred_signals():
                _finish(root)
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise Incomplete(f"{root / JOURNAL}: not readable ({' '.join(str(exc).split())[:80]}); delete it and "
                             f"record again") from None
        return True
    finally:
        if key is not None:
            release(key)


__all__ = ["FileBatch", "INCOMPLETE", "Incomplete", "Interrupted", "JOURNAL", "LOCK_NAME", "MANIFEST", "OUTPUTS",
           "RUN_COMMANDS", "StagedDirectory", "acquire", "check_all_present", "check_listed", "child_of",
           "deferred_signals", "digest", "exit_status_of", "finish_batch", "foreign_entries", "in_use",
           "hold_from_start", "interrupts_raise", "keep_so_far", "kept", "kept_so_far", "kept_text", "leaving", "lock",
           "lock_path", "owner", "read_manifest", "refuse_another_commands", "refuse_if_in_use", "release", "seal",
           "signal_received", "started", "test_point"]
