"""What a sensor log may ask of the twin: its size, length and time span, each bounded.

A log is input from outside (a robot's, or anybody's): one row with a wild timestamp must not
make ``twin replay`` allocate a time step per control period up to it, nor a file that never
ends be read until the memory runs out. Every bound below is checked while the log is read
(:func:`twin.logs.format.read_log`), before anything is allocated from what the log says, and
each one that is exceeded is a one-line :class:`~twin.errors.TwinError` naming the file, the
row and the bound. They are generous for a robot's log: a day of it at 200 Hz stays far inside
(except :data:`MAX_INSTANTS`, 13.9 h at 200 Hz).

The replay's memory grows with the log (:mod:`twin.logs.replay`: about 0.3 kB per control
instant with every stream at the control rate, arrays only, no object per row), so these
bounds bound it too: a few GB at the very most.
"""
from __future__ import annotations

MAX_STREAM_BYTES = 4 << 30  # bytes in one stream file (4 GiB: 10⁷ rows of the widest stream, truth.csv, fit)
MAX_ROWS = 10_000_000  # data rows in one stream file (the header aside)
MAX_LINE_CHARS = 4096  # characters in one row, its line break aside (the widest row the twin writes: about 300)
MAX_TIME_S = 4.0e9  # s: |t| of any row; a clock in seconds since 1970 fits (until 2096), with < 1 µs resolution
MAX_DURATION_S = 86_400.0  # s: from a stream's first row to any later one (a day)
MAX_INSTANTS = 10_000_000  # control instants of a replay: (last command − first command) × control_rate + 1
MAX_COUNT = 2 ** 53  # |encoder counts|: every count a float holds exactly
MAX_MANIFEST_BYTES = 1 << 20  # log.toml, the scenario beside it, a check file: 1 MiB
MAX_STREAMS = 32  # streams log.toml declares in [streams.NAME] (version 2), the format's own among them


def bounds_text() -> str:
    """The bounds in a few words, for the documentation and messages."""
    return (f"at most {MAX_ROWS:,} rows and {MAX_STREAM_BYTES >> 30} GiB per stream, {MAX_LINE_CHARS} characters "
            f"per row, |t| up to {MAX_TIME_S:g} s, {MAX_DURATION_S:g} s from a stream's first row to its last, "
            f"{MAX_INSTANTS:,} control instants")


__all__ = ["MAX_COUNT", "MAX_DURATION_S", "MAX_INSTANTS", "MAX_LINE_CHARS", "MAX_MANIFEST_BYTES", "MAX_ROWS",
           "MAX_STREAMS", "MAX_STREAM_BYTES", "MAX_TIME_S", "bounds_text"]
