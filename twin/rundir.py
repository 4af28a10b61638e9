"""Output directories: who is using one.

A command that writes into a directory for a while (``twin sweep`` fills its store for
minutes or hours, and is resumed there) holds ``lock(dir, command)``; any other command
that would write there asks :func:`in_use` first and refuses with one line. The lock is an
advisory ``flock`` on ``DIR/.twin.lock``: the kernel drops it when the holder exits, however
it exits (SIGKILL included), so a stale lock file never blocks anyone. The file records the
holder's command and process id for the message.
"""
from __future__ import annotations

import contextlib
import os
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


__all__ = ["LOCK_NAME", "in_use", "lock", "refuse_if_in_use"]
