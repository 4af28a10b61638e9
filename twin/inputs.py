"""Files a user hands the twin, read as hostile input: what a file may ask of the reader is bounded.

* **Regular files only.** A FIFO (named pipe) would block the reader until someone writes to
  it, ``/dev/zero`` or ``/dev/urandom`` never ends, a directory is no text: each is refused in
  one line before a byte is read (:func:`open_regular`: opened without blocking, then asked
  what it is).
* **Bounded size.** A file is read whole only up to a limit given by the caller
  (:func:`read_bytes`, :func:`read_text`), so a symlink to a 10 GB file, or one that grows
  while it is read, is refused in one line instead of filling the memory.
* **Inside its folder where it must be** (:func:`inside`): a sensor log's files are the log's,
  so one that resolves, through ``..`` or a symbolic link, out of the log's directory is
  refused without being opened (nothing of another file is read, nor quoted in a message).
* **Bounded nesting.** :func:`json_loads` parses JSON whose objects and arrays nest at most
  :data:`MAX_JSON_DEPTH` levels deep, and refuses deeper ones with a :class:`TooDeep` (a
  ``ValueError``, so the callers' "not readable as JSON" handling gives its one line); Python's
  recursion limit (a ``RecursionError`` at about 1000 levels) never surfaces.
  :func:`toml_loads` does the same for TOML.

Messages quote none of a file's content (a header or a value of a file that may not be the
user's is never echoed back); :func:`twin.errors.shown` is for values the user typed.
"""
from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path

from twin.errors import TwinError

MAX_JSON_DEPTH = 64  # levels of nested objects and arrays in a JSON file the twin reads (its own nest about 6)
MAX_TOML_DEPTH = 32  # levels of nested tables and arrays in a TOML file (as twin.scenarios.schema.MAX_DEPTH)
MAX_TOML_BYTES = 1 << 20  # 1 MiB: a scenario file, a log's manifest or a check file (the built-ins are ~2 kB)


class TooDeep(ValueError):
    """A JSON or TOML text that nests deeper than the reader takes; ``str()`` says so in a few words."""


def _kind(mode: int) -> str:
    """What a non-regular file is, for a message."""
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def size_text(n: float) -> str:
    """``n`` bytes for a message: 512 bytes, 1.5 kB, 3.2 MB, 4.29 GB (SI prefixes)."""
    if n < 1000:
        return f"{int(n)} bytes"
    for unit, scale in (("kB", 1e3), ("MB", 1e6), ("GB", 1e9), ("TB", 1e12)):
        if n < scale * 1000 or unit == "TB":
            return f"{n / scale:.3g} {unit}"
    return f"{n:g} bytes"  # pragma: no cover -- the loop always returns


def open_regular(path, what: str = "file") -> int:
    """A file descriptor open for reading on ``path``, a regular file (symbolic links followed).

    Opened with ``O_NONBLOCK``, which a regular file ignores and which makes opening a FIFO
    return at once instead of waiting for a writer; then ``fstat`` on the descriptor (not on the
    name, which could change in between) says what it is. A missing file raises
    ``FileNotFoundError`` (callers name what is missing in their own words); anything else is a
    :class:`~twin.errors.TwinError` line naming ``path`` (``what``: what it should have been)."""
    path = os.fspath(path)
    if "\x00" in str(path):
        raise TwinError(f"{path!r}: a file name holding a null character; allowed: a path without one")
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise
    except OSError as exc:
        if exc.errno == errno.ENOENT:
            raise FileNotFoundError(exc.errno, exc.strerror, path) from None
        raise TwinError(f"{path}: cannot be read ({exc.strerror or exc}); allowed: a readable {what}") from None
    try:
        mode = os.fstat(fd).st_mode
    except OSError as exc:
        os.close(fd)
        raise TwinError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise TwinError(f"{path}: {_kind(mode)}, not a regular file; allowed: a {what} that is a regular file")
    return fd


def read_bytes(path, limit: int, what: str = "file") -> bytes:
    """The bytes of regular file ``path`` (:func:`open_regular`), at most ``limit`` of them: a
    larger file (or one that grows past the limit while it is read) is a one-line error."""
    fd = open_regular(path, what)
    with os.fdopen(fd, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > limit:
            raise TwinError(f"{path}: {size_text(size)}; allowed: a {what} of at most {size_text(limit)}")
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise TwinError(f"{path}: more than {size_text(limit)} (it grew while read); allowed: a {what} of at most "
                        f"{size_text(limit)}")
    return data


def read_text(path, limit: int, what: str = "file") -> str:
    """:func:`read_bytes` decoded as UTF-8; a file that is not UTF-8 is a one-line error naming
    the line of the first bad byte (quoting none of it)."""
    data = read_bytes(path, limit, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise TwinError(f"{path}: line {line}: not UTF-8 text; allowed: a {what} in UTF-8") from None


def inside(path, root, what: str = "file") -> Path:
    """``path`` resolved (symbolic links and ``..`` followed), which must lie in directory
    ``root`` (resolved alike); a one-line error naming ``path`` and ``root`` otherwise (the
    target is not named: it is no business of the message)."""
    root_r = Path(root).resolve()
    try:
        real = Path(path).resolve()
    except (OSError, RuntimeError, ValueError):  # a symlink loop; a null character
        raise TwinError(f"{path}: cannot be resolved (a loop of symbolic links?); allowed: a {what} inside "
                        f"{root}") from None
    if real != root_r and root_r not in real.parents:
        raise TwinError(f"{path}: leads out of {root} (through '..', an absolute path or a symbolic link); allowed: "
                        f"a {what} inside {root}")
    return real


def depth_problem(value, limit: int) -> str:
    """"" if ``value`` (parsed JSON or TOML: dicts and lists) nests at most ``limit`` levels deep,
    else a few words saying it does not. Walked with a stack, never by recursion; only the
    containers are visited (a list of a million numbers costs no more than its own scan)."""
    stack = [(value, 0)]
    while stack:
        v, depth = stack.pop()
        if depth > limit:
            return f"nested deeper than {limit} levels"
        if isinstance(v, dict):
            stack.extend((c, depth + 1) for c in v.values() if isinstance(c, (dict, list)))
        elif isinstance(v, list):
            stack.extend((c, depth + 1) for c in v if isinstance(c, (dict, list)))
    return ""


def json_loads(text, limit: int = MAX_JSON_DEPTH):
    """``json.loads(text)`` whose objects and arrays nest at most ``limit`` levels deep; deeper
    is a :class:`TooDeep` ("nested deeper than 64 levels"), as is what Python's recursion limit
    stops. Other errors are ``json.loads``' own (``ValueError``, its ``JSONDecodeError`` and an
    integer beyond Python's 4300-digit conversion among them)."""
    try:
        value = json.loads(text)
    except RecursionError:
        raise TooDeep(f"nested deeper than {limit} levels") from None
    problem = depth_problem(value, limit)
    if problem:
        raise TooDeep(problem)
    return value


def toml_loads(text: str, limit: int = MAX_TOML_DEPTH) -> dict:
    """``tomllib.loads(text)`` nesting at most ``limit`` levels deep (:class:`TooDeep` otherwise,
    as for :func:`json_loads`); an integer beyond Python's 4300-digit conversion is a
    ``ValueError`` saying so in one line. ``tomllib.TOMLDecodeError`` passes through."""
    import tomllib

    try:
        value = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        raise
    except RecursionError:
        raise TooDeep(f"nested deeper than {limit} levels of tables and arrays") from None
    except ValueError as exc:
        if "digits" in str(exc):
            raise ValueError("an integer with more than 4300 digits") from None
        raise
    problem = depth_problem(value, limit)
    if problem:
        raise TooDeep(f"{problem} of tables and arrays")
    return value


__all__ = ["MAX_JSON_DEPTH", "MAX_TOML_BYTES", "MAX_TOML_DEPTH", "TooDeep", "depth_problem", "inside", "json_loads",
           "open_regular", "read_bytes", "read_text", "size_text", "toml_loads"]
