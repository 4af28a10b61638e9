"""A sensor log's CSV streams, read row by row into arrays, each row checked as it comes.

:func:`read_stream` reads a stream file (one of :data:`twin.logs.format.STREAMS`) in chunks of
:data:`CHUNK_BYTES` and parses each row straight into a growing array of doubles: no list of
rows, no object per value, so a stream of N rows costs 8 bytes per value and the file's size
never sits in memory. Every bound of :mod:`twin.logs.bounds` is checked on the row that
exceeds it (the file's size before the first byte is read), so a log cannot make the reader
allocate more than its rows hold.

What a row may hold is the format's (:mod:`twin.logs.format`): numbers as Python's ``float``
reads them (``repr`` of a float reads back exactly), integers of ASCII digits for the encoders'
counts, an empty group where nothing arrived; fields may be quoted as CSV quotes them (a row
with a ``"`` goes through :mod:`csv`). Messages quote a field of the row at fault (shortened,
on one line, :func:`twin.errors.shown`): the file is the log's own, inside its directory
(:func:`twin.inputs.inside` saw to that before it was opened).
"""
from __future__ import annotations

import array
import csv
import math
import os
import re
from pathlib import Path

import numpy as np

from twin.errors import TwinError, shown
from twin.inputs import open_regular, size_text
from twin.logs.bounds import (MAX_COUNT, MAX_DURATION_S, MAX_LINE_CHARS, MAX_ROWS, MAX_STREAM_BYTES,
                              MAX_TIME_S)

CHUNK_BYTES = 1 << 20  # read at a time: the lines it holds are parsed before the next is read
_INTEGER = re.compile(r"[+-]?[0-9]{1,16}\Z")  # counts: ASCII digits, at most 16 (2⁵³ has 16)
# a row of t and counts as the twin writes it: counts of at most 15 digits are within 2⁵³ (a 16-digit
# one, blanks, anything else: field by field, _cell)
_INTEGER_ROW = re.compile(r"[^,]*(?:,[+-]?[0-9]{1,15})+\Z")


def read_stream(path: Path, layouts, *, tolerance: float, integers: bool = False, need_all: bool = False,
                also: str = "") -> tuple[np.ndarray, tuple]:
    """(rows (N, C) float array in file order, the header's columns) of stream file ``path``.

    ``layouts``: the headers allowed, each (columns, groups): the columns as the header names
    them (``t`` first) and the groups of columns that arrive together (``(a, b)``: columns a …
    b−1), empty all together (NaN: nothing arrived) or given all together (``need_all``: never
    empty). ``integers``: the columns after ``t`` are whole numbers (the encoders' counts).
    ``tolerance`` s: how much earlier than the latest row before it a row may be and count as
    simultaneous. ``also``: what the header message adds about the other layouts.
    FileNotFoundError if ``path`` does not exist (the caller says whether that is an error)."""
    fd = open_regular(path, "stream (CSV text)")
    with os.fdopen(fd, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > MAX_STREAM_BYTES:
            raise TwinError(f"{path}: {size_text(size)}; allowed: a stream of at most {size_text(MAX_STREAM_BYTES)} "
                            f"({MAX_ROWS:,} rows)")
        chunks = _lines(fh, path)
        first = next(chunks, (1, []))[1]
        header = _cells(first[0], path, 1) if first else []
        header = tuple(h.strip() for h in header)
        for cols, groups in layouts:
            if header == tuple(cols):
                break
        else:
            cols = layouts[0][0]
            got = ",".join(header) if first else ""
            raise TwinError(f"{path}: row 1: the header must be {','.join(cols)}{also}, got {shown(got)}")
        parse = _Rows(path, tuple(cols), tuple(groups), tolerance, integers, need_all)
        parse.lines(first[1:], 2)
        for start, lines in chunks:
            parse.lines(lines, start)
    return parse.array(), tuple(cols)


def _lines(fh, path: Path):
    """(number of the first line, [its lines]) per chunk of the file, each line decoded, without
    its line break. A line longer than :data:`MAX_LINE_CHARS` is an error as soon as it is seen."""
    rest = b""
    n = 0  # lines handed out
    read = 0
    while True:
        chunk = fh.read(CHUNK_BYTES)
        if not chunk:
            break
        read += len(chunk)
        if read > MAX_STREAM_BYTES:
            raise TwinError(f"{path}: more than {size_text(MAX_STREAM_BYTES)} (it grew while read); allowed: a "
                            f"stream of at most {size_text(MAX_STREAM_BYTES)}")
        data = rest + chunk if rest else chunk
        cut = data.rfind(b"\n") + 1
        rest = data[cut:]
        if len(rest) > 4 * MAX_LINE_CHARS:  # a UTF-8 character is at most 4 bytes
            row = n + data.count(b"\n", 0, cut) + 1
            raise TwinError(f"{path}: row {row}: longer than {MAX_LINE_CHARS} characters; allowed: rows of at most "
                            f"{MAX_LINE_CHARS}")
        if cut:
            lines = _decode(data[:cut], path, n).split("\n")
            lines.pop()  # after the last line break
            yield n + 1, lines
            n += len(lines)
    if rest:
        yield n + 1, [_decode(rest, path, n)]


def _decode(data: bytes, path: Path, before: int) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        row = before + data.count(b"\n", 0, exc.start) + 1
        raise TwinError(f"{path}: row {row}: not UTF-8 text; allowed: a CSV stream in UTF-8") from None


def _cells(line: str, path: Path, row: int) -> list:
    """The fields of one line: split at commas, or read as CSV where a field is quoted."""
    if line.endswith("\r"):
        line = line[:-1]
    if len(line) > MAX_LINE_CHARS:
        raise TwinError(f"{path}: row {row}: {len(line)} characters; allowed: rows of at most {MAX_LINE_CHARS}")
    if not line:
        return []  # as csv reads a blank line: no field
    if '"' not in line:
        return line.split(",")
    try:
        return next(csv.reader([line]), [])
    except csv.Error as exc:
        raise TwinError(f"{path}: row {row}: not CSV ({' '.join(str(exc).split())})") from None


class _Rows:
    """The rows of one stream as they are parsed: checked, appended to one array of doubles."""

    def __init__(self, path, cols, groups, tolerance, integers, need_all):
        self.path, self.cols, self.groups = path, cols, groups
        self.tolerance, self.integers, self.need_all = tolerance, integers, need_all
        self.values = array.array("d")
        self.rows = 0
        self.last = -math.inf  # the latest t so far
        self.first = None  # the first row's t

    def lines(self, lines: list, start: int) -> None:
        """Parse ``lines``, the first of which is line ``start`` of the file (the header is line 1)."""
        if self.rows + len(lines) > MAX_ROWS:
            raise TwinError(f"{self.path}: row {MAX_ROWS + 2}: more than {MAX_ROWS:,} rows; allowed: at most "
                            f"{MAX_ROWS:,} per stream (split a longer log)")
        path, ncols, integers = self.path, len(self.cols), self.integers
        extend, isfinite, tol = self.values.extend, math.isfinite, self.tolerance
        last, first = self.last, self.first
        integer_row = _INTEGER_ROW.match
        for row, line in enumerate(lines, start):
            if '"' in line or len(line) > MAX_LINE_CHARS or not line or line[-1] == "\r":
                cells = _cells(line, path, row)
            else:
                cells = line.split(",")
            if len(cells) != ncols:
                raise TwinError(f"{path}: row {row}: {len(cells)} fields; allowed: {ncols} ({','.join(self.cols)})")
            try:  # the common row: every field a finite number (counts: whole ones, within 2⁵³)
                if integers and not integer_row(line):
                    raise ValueError
                vals = list(map(float, cells))
                if not isfinite(sum(vals)):  # a NaN or an infinity (or a sum that overflows): field by field
                    vals = self._slow(cells, row)
            except ValueError:
                vals = self._slow(cells, row)
            t = vals[0]
            if not -MAX_TIME_S <= t <= MAX_TIME_S:
                raise TwinError(f"{path}: row {row}: t = {t!r} s; allowed: |t| at most {MAX_TIME_S:g} s (seconds on "
                                f"the log's clock; since 1970 fits)")
            if t < last - tol:
                raise TwinError(f"{path}: row {row}: t = {t!r} s runs backwards ({last!r} s on the row before); "
                                f"allowed: rows in time order (equal times, or up to {tol:g} s earlier, count as "
                                f"simultaneous)")
            if t > last:
                last = t
                if first is None:
                    first = t
                elif t - first > MAX_DURATION_S:
                    raise TwinError(f"{path}: row {row}: t = {t!r} s is {t - first:.6g} s after the stream's first row "
                                    f"(t = {first!r} s); allowed: at most {MAX_DURATION_S:g} s from a stream's first "
                                    f"row to its last (split a longer log)")
            extend(vals)
        self.rows += len(lines)
        self.last, self.first = last, first

    def _slow(self, cells: list, row: int) -> list:
        """The row field by field: an empty group is NaN, anything else wrong one line naming it."""
        path, cols = self.path, self.cols
        cells = [c.strip() for c in cells]
        t = _cell(cells[0], path, row, "t")
        if t is None:
            raise TwinError(f"{path}: row {row}: t is empty; every row needs its time in s")
        out = [t] + [math.nan] * (len(cols) - 1)
        for a, b in self.groups:
            vals = [_cell(cells[j], path, row, cols[j], self.integers) for j in range(a, b)]
            empty = [v is None for v in vals]
            if all(empty) and not self.need_all:
                continue
            if any(empty):
                missing = cols[a + empty.index(True)]
                raise TwinError(f"{path}: row {row}: {missing} is empty while {', '.join(cols[a:b])} are not; "
                                f"allowed: all of them, or none (nothing arrived)" if not self.need_all else
                                f"{path}: row {row}: {missing} is empty; every row needs {' and '.join(cols[a:b])}")
            out[a:b] = vals
        return out

    def array(self) -> np.ndarray:
        return np.frombuffer(self.values, dtype=float).reshape(self.rows, len(self.cols))


def _cell(text: str, path: Path, line: int, col: str, integer: bool = False):
    """One field: None if empty, else its value (a finite float; a whole number of counts for
    ``integer``), or a one-line error."""
    if text == "":
        return None
    if integer:
        if not _INTEGER.match(text):
            digits = text[1:] if text[:1] in "+-" else text
            if digits.isascii() and digits.isdigit():  # a whole number, too long to be a count
                raise TwinError(f"{path}: row {line}: {col} = {shown(text, 40)} has {len(digits)} digits; allowed: "
                                f"counts within ±{MAX_COUNT} (2^53)")
            raise TwinError(f"{path}: row {line}: {col} = {shown(text)} is not a whole number of counts; "
                            f"allowed: integers (encoders count, they do not measure angles)")
        v = int(text)
        if abs(v) > MAX_COUNT:
            raise TwinError(f"{path}: row {line}: {col} = {text}; allowed: counts within ±{MAX_COUNT} (2^53)")
        return float(v)
    try:
        v = float(text)
    except ValueError:
        raise TwinError(f"{path}: row {line}: {col} = {shown(text)} is not a number") from None
    if not math.isfinite(v):
        said = text if len(text) <= 40 and text.isprintable() else shown(text, 40)
        raise TwinError(f"{path}: row {line}: {col} = {said}; allowed: a finite number (an empty field: nothing "
                        f"arrived)")
    return v


__all__ = ["CHUNK_BYTES", "read_stream"]
