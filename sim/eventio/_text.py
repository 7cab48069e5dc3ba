"""ECD ``events.txt``: the compiled (Numba) formatter and parser, the line-by-line parser that
names a bad line, the streaming block reader and :class:`TextEventWriter`.

One event a line, ``t[s] x y p``: t in seconds with exactly 9 decimals (written from the int64
nanoseconds with integer arithmetic), x and y integers, p 0 (OFF) or 1 (ON). When the compiled
parser meets a line it does not accept, the block is parsed again line by line in Python, which
names the first bad line (``file:line: ...``) and what was expected.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

import numba
import numpy as np

from sim.eventio._events import _MAX_COORD, _NS_PER_S, EVENT_DTYPE
from sim.eventio._writer import _StreamingWriter

__all__ = ["TextEventWriter"]

# Largest whole second whose nanoseconds (plus up to 999_999_999) still fit in int64.
_MAX_SECONDS = (np.iinfo(np.int64).max - (_NS_PER_S - 1)) // _NS_PER_S
_TEXT_EXPECTED = "'t[s] x y p', e.g. '0.003811000 96 133 0'"
_LINE_MAX = 36  # 11 digits of seconds (int64) + '.' + 9 + ' ' + 5 + ' ' + 5 + ' ' + 1 + '\n'
_WRITE_BLOCK = 1 << 20  # events formatted at a time


@numba.njit(cache=True)
def _put_uint(out, pos, value):  # pragma: no cover - compiled
    if value == 0:
        out[pos] = 48
        return pos + 1
    n = 0
    v = value
    while v > 0:
        n += 1
        v //= 10
    end = pos + n
    k = end - 1
    while value > 0:
        out[k] = 48 + value % 10
        value //= 10
        k -= 1
    return end


@numba.njit(cache=True)
def _format_text(t, x, y, p, out):  # pragma: no cover - compiled
    pos = 0
    for i in range(t.size):
        seconds = t[i] // 1_000_000_000
        frac = t[i] - seconds * 1_000_000_000
        pos = _put_uint(out, pos, seconds)
        out[pos] = 46  # '.'
        for k in range(9):
            out[pos + 9 - k] = 48 + frac % 10
            frac //= 10
        out[pos + 10] = 32
        pos = _put_uint(out, pos + 11, np.int64(x[i]))
        out[pos] = 32
        pos = _put_uint(out, pos + 1, np.int64(y[i]))
        out[pos] = 32
        out[pos + 1] = 49 if p[i] > 0 else 48
        out[pos + 2] = 10
        pos += 3
    return pos


_OK, _BAD_LINE, _BACKWARDS, _OUTSIDE = 0, 1, 2, 3


@numba.njit(cache=True)
def _is_blank(c):  # pragma: no cover - compiled
    return c == 32 or c == 9 or c == 13 or c == 11 or c == 12


@numba.njit(cache=True)
def _parse_coordinate(buf, i):  # pragma: no cover - compiled
    """Skip the blanks before a field and parse its digits: (value, next i); value -1 if bad."""
    size = buf.size
    if i >= size or not _is_blank(buf[i]):
        return -1, i
    while i < size and _is_blank(buf[i]):
        i += 1
    value = 0
    digits = 0
    while i < size and 48 <= buf[i] <= 57:
        value = value * 10 + (buf[i] - 48)
        digits += 1
        i += 1
        if value > 65535:
            return -1, i
    if digits == 0:
        return -1, i
    return value, i


@numba.njit(cache=True)
def _parse_text(buf, t_out, x_out, y_out, p_out, width, height, t_prev):  # pragma: no cover
    """Parse whole lines into the output columns; stop at the first line it does not accept.

    Returns (events parsed, status, 0-based line of the failure within ``buf``).
    """
    size = buf.size
    n = 0
    line = 0
    i = 0
    while i < size:
        while i < size and _is_blank(buf[i]):
            i += 1
        if i >= size:
            break
        if buf[i] == 10:  # blank line
            line += 1
            i += 1
            continue
        if buf[i] == 35:  # '#' comment
            while i < size and buf[i] != 10:
                i += 1
            line += 1
            i += 1
            continue
        # t: digits, optionally '.' and 1 to 9 digits
        seconds = np.int64(0)
        digits = 0
        while i < size and 48 <= buf[i] <= 57:
            seconds = seconds * 10 + (buf[i] - 48)
            digits += 1
            i += 1
            if seconds > 9223372035:
                return n, _BAD_LINE, line
        if digits == 0:
            return n, _BAD_LINE, line
        frac = np.int64(0)
        if i < size and buf[i] == 46:
            i += 1
            digits = 0
            while i < size and 48 <= buf[i] <= 57:
                frac = frac * 10 + (buf[i] - 48)
                digits += 1
                i += 1
            if digits == 0 or digits > 9:
                return n, _BAD_LINE, line
            for _ in range(9 - digits):
                frac *= 10
        t = seconds * 1_000_000_000 + frac
        # x and y: a separator, then digits (<= 65535)
        px, i = _parse_coordinate(buf, i)
        if px < 0:
            return n, _BAD_LINE, line
        py, i = _parse_coordinate(buf, i)
        if py < 0:
            return n, _BAD_LINE, line
        # p: separator, '0' or '1', then the end of the line
        if i >= size or not _is_blank(buf[i]):
            return n, _BAD_LINE, line
        while i < size and _is_blank(buf[i]):
            i += 1
        if i >= size or (buf[i] != 48 and buf[i] != 49):
            return n, _BAD_LINE, line
        polarity = 1 if buf[i] == 49 else -1
        i += 1
        while i < size and _is_blank(buf[i]):
            i += 1
        if i < size and buf[i] != 10:
            return n, _BAD_LINE, line
        if t < t_prev:
            return n, _BACKWARDS, line
        if (width > 0 and px >= width) or (height > 0 and py >= height):
            return n, _OUTSIDE, line
        t_out[n] = t
        x_out[n] = px
        y_out[n] = py
        p_out[n] = polarity
        t_prev = t
        n += 1
        line += 1
        i += 1  # the '\n' (or past the end)
    return n, _OK, line


# --- text: line-by-line parser (explains errors) ---------------------------------------------

_TIME_RE = re.compile(rb"(\d+)(?:\.(\d{1,9}))?")
_UINT_RE = re.compile(rb"\d+")


def _parse_line(fields: list[bytes], where: str, width: int | None, height: int | None,
                t_prev: int) -> tuple[int, int, int, int]:
    """One line's fields to ``(t_ns, x, y, p)``, or a ValueError naming ``where``."""
    if len(fields) != 4:
        text = b" ".join(fields).decode("ascii", "replace")
        raise ValueError(f"{where}: expected 4 fields {_TEXT_EXPECTED}, got {len(fields)}: "
                         f"{text!r}")
    t_field, x_field, y_field, p_field = (f.decode("ascii", "replace") for f in fields)
    match = _TIME_RE.fullmatch(fields[0])
    if match is None or int(match[1]) > _MAX_SECONDS:
        raise ValueError(f"{where}: time {t_field!r} is not a non-negative number of seconds "
                         f"with at most 9 decimals (below {_MAX_SECONDS + 1} s); expected "
                         f"{_TEXT_EXPECTED}")
    frac = match[2] or b""
    t = int(match[1]) * _NS_PER_S + int(frac.ljust(9, b"0") or b"0")
    coords = []
    for name, field, text, size, what in (("x", fields[1], x_field, width, "width"),
                                          ("y", fields[2], y_field, height, "height")):
        if _UINT_RE.fullmatch(field) is None or int(field) > _MAX_COORD:
            raise ValueError(f"{where}: {name} {text!r} is not an integer in [0, {_MAX_COORD}]; "
                             f"expected non-negative integer pixel coordinates in "
                             f"{_TEXT_EXPECTED}")
        value = int(field)
        if size is not None and value >= size:
            raise ValueError(f"{where}: {name} = {value} is outside the sensor ({what} {size}); "
                             f"expected 0 <= {name} < {size}")
        coords.append(value)
    if fields[3] not in (b"0", b"1"):
        raise ValueError(f"{where}: polarity {p_field!r} is not 0 or 1; expected p in {{0, 1}} "
                         "(0 OFF, 1 ON)")
    if t < t_prev:
        raise ValueError(f"{where}: time {t_field} s is before the previous event's "
                         f"{_format_seconds(t_prev)} s; expected non-decreasing times")
    return t, coords[0], coords[1], 1 if fields[3] == b"1" else -1


def _format_seconds(t_ns: int) -> str:
    return f"{t_ns // _NS_PER_S}.{t_ns % _NS_PER_S:09d}"


def _parse_lines(block: bytes, path: Path, first_line: int, width: int | None,
                 height: int | None, t_prev: int) -> np.ndarray:
    """Parse ``block`` line by line (slow); raise at the first bad line, naming it."""
    rows = []
    for number, line in enumerate(block.split(b"\n"), start=first_line):
        fields = line.split()
        if not fields or fields[0].startswith(b"#"):
            continue
        row = _parse_line(fields, f"{path}:{number}", width, height, t_prev)
        t_prev = row[0]
        rows.append(row)
    return np.array(rows, dtype=EVENT_DTYPE) if rows else np.empty(0, EVENT_DTYPE)


def _parse_block(block: bytes, path: Path, first_line: int, width: int | None,
                 height: int | None, t_prev: int) -> tuple[np.ndarray, int]:
    """Parse whole lines of an ``events.txt`` (fast path, line-by-line fallback on errors).

    Returns the events and the number of newlines in ``block``.
    """
    newlines = block.count(b"\n")
    buf = np.frombuffer(block, dtype=np.uint8)
    events = np.empty(newlines + 1, EVENT_DTYPE)
    n, status, _ = _parse_text(buf, events["t"], events["x"], events["y"], events["p"],
                               width or 0, height or 0, t_prev)
    if status == _OK:
        return events[:n], newlines
    # The compiled parser stopped at a line it does not accept: the line-by-line parser, which
    # accepts exactly the same lines, finds it again and says what is wrong with it.
    return _parse_lines(block, path, first_line, width, height, t_prev), newlines


def _line_blocks(path: Path, block_bytes: int) -> Iterator[bytes]:
    """The bytes of a text file in consecutive blocks of whole lines (about ``block_bytes``
    each; a longer line makes its block longer; the last block may lack its final newline)."""
    carry = b""
    with path.open("rb") as handle:
        while True:
            data = handle.read(block_bytes)
            if not data:
                if carry:
                    yield carry
                return
            data = carry + data
            cut = data.rfind(b"\n")
            if cut < 0:  # one very long line: read on
                carry = data
                continue
            carry = data[cut + 1:]
            yield data[:cut + 1]


def _iter_text_blocks(path: Path, block_bytes: int, width: int | None,
                      height: int | None) -> Iterator[np.ndarray]:
    t_prev = -1
    first_line = 1
    for block in _line_blocks(path, block_bytes):
        events, newlines = _parse_block(block, path, first_line, width, height, t_prev)
        first_line += newlines
        if events.size:
            t_prev = int(events["t"][-1])
            yield events


class TextEventWriter(_StreamingWriter):
    """Stream events into an ECD ``events.txt``: one ``t[s] x y p`` line per event.

    t is written in seconds with exactly 9 decimals, computed from the int64 nanoseconds with
    integer arithmetic (``f"{t // 10**9}.{t % 10**9:09d}"``), so every time round-trips exactly;
    p is written as 1 (ON) or 0 (OFF). Formatting is compiled (tens of millions of events per
    second).

    Parameters
    ----------
    path : str or Path
        The file to write. It is written as ``<path>.partial`` and renamed to ``path``
        (replacing an existing file) by a successful :meth:`close`; an exception inside the
        ``with`` block leaves only the ``.partial`` file.
    resume : dict, optional
        A :meth:`checkpoint` of an interrupted writer of the same path: its ``.partial`` file
        (or ``path``, if it was closed after the checkpoint) is cut back to the checkpoint's
        size and appended to.

    Raises
    ------
    ValueError
        ``resume`` is not a text writer's checkpoint, or the file to resume is missing or
        shorter than the checkpoint says.

    Examples
    --------
    >>> with TextEventWriter("events.txt") as writer:            # doctest: +SKIP
    ...     for chunk in chunks:
    ...         writer.write(chunk)
    """

    _format = "txt"

    def __init__(self, path: str | Path, *, resume: dict | None = None) -> None:
        self._begin(path)
        self._buffer = np.empty(0, np.uint8)
        if resume is None:
            self._handle = self.partial.open("wb")
            return
        self._handle = self._reopen_bytes(resume, ())

    def write(self, events: np.ndarray) -> None:
        """Append a chunk of events.

        Parameters
        ----------
        events : (N,) EVENT_DTYPE ndarray
            Sorted by t, starting at or after the previous chunk's last t, with t >= 0 and
            p = +-1. An empty chunk is allowed.

        Raises
        ------
        ValueError
            The chunk goes back in time (within itself or against the previous chunk), has a
            negative t or p not +-1, or the writer is closed. Nothing of the chunk is written.
        """
        self._check_chunk(events)
        for start in range(0, events.size, _WRITE_BLOCK):
            part = events[start:start + _WRITE_BLOCK]
            if self._buffer.size < part.size * _LINE_MAX:
                self._buffer = np.empty(part.size * _LINE_MAX, np.uint8)
            end = _format_text(part["t"], part["x"], part["y"], part["p"], self._buffer)
            self._handle.write(self._buffer[:end])
        if events.size:
            self.count += events.size
            self._last_t = int(events["t"][-1])

    def _sync(self) -> dict:
        self._handle.flush()
        os.fsync(self._handle.fileno())
        return {"size": self._handle.tell()}

    def _finish(self) -> None:
        self._handle.close()

    def _abort(self) -> None:
        self._handle.close()
