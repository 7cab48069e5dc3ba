"""Events in memory and on disk: the ECD text format and the DSEC HDF5 layout, streamed.

In memory (CONVENTIONS.md, "Events") events are a structured array of :data:`EVENT_DTYPE`:
``t`` int64 nanoseconds, ``x``/``y`` uint16 pixel column/row, ``p`` int8 (+1 ON, -1 OFF),
sorted by ``t``.

On disk, two formats:

``events.txt`` (Event-Camera Dataset)
    One event a line, ``t[s] x y p``: t in seconds with exactly 9 decimals (whole nanoseconds,
    written from the int64 with integer arithmetic, so any time round-trips exactly), x and y
    as integers, p as 0 (OFF) or 1 (ON), separated by one space, lines ended by ``\\n``.
    The reader also accepts 0 to 9 decimals, any run of spaces or tabs between fields, ``\\r\\n``
    line ends, blank lines and ``#`` comment lines; times are converted to int64 nanoseconds by
    parsing the integer and fractional parts as integers (never through float64).

``events.h5`` (DSEC layout, see :class:`H5EventWriter`)
    ``events/t`` (int64 microseconds, relative to ``t_offset``), ``events/x``, ``events/y``
    (uint16), ``events/p`` (uint8, 1 ON / 0 OFF), ``ms_to_idx`` (int64) and ``t_offset``
    (int64 microseconds), plus the evfuse extension ``events/t_ns_rem`` (uint16, the
    sub-microsecond part) that makes the round trip to int64 nanoseconds lossless.

Writers stream: :meth:`write` takes consecutive time-ordered chunks, so a sequence never has to
fit in memory, and a file is written as ``<name>.partial`` and renamed to ``<name>`` only by a
successful :meth:`close` (an exception inside the ``with`` leaves only the ``.partial`` file).
Readers stream too (:func:`iter_event_chunks`); :func:`read_events` and :func:`read_window` are
built on them.

Text is formatted and parsed by two small compiled (Numba) loops; when the parser meets
anything it does not accept, the block it was reading is parsed again line by line in Python,
which names the first bad line (``file:line: ...``) and what was expected.
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import numba
import numpy as np

from sim._atomic import PARTIAL_SUFFIX, partial_path  # the one suffix of everything unfinished

__all__ = [
    "EVENT_DTYPE",
    "H5EventWriter",
    "MAX_EMPTY_MS",
    "PARTIAL_SUFFIX",
    "TextEventWriter",
    "check_events",
    "check_time_units",
    "event_time_span",
    "convert_events",
    "iter_event_chunks",
    "make_events",
    "read_events",
    "read_window",
]

EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
"""Events in memory: t int64 ns, x/y uint16 pixels, p int8 (+1 ON, -1 OFF)."""

MAX_EMPTY_MS = 10**7
"""Most consecutive empty milliseconds (about 2.8 hours: 80 MB of ``ms_to_idx``) an ``events.h5``
may have before its first event or between two events; see :class:`H5EventWriter`."""

UNIT_SLACK = 10.0
"""Factor by which two time spans that should agree may differ before the times are taken to be
in another unit (the units confused differ by 1000 or more)."""

UNIT_OVERLAP = 0.01
"""Share of the events' time span that must overlap the poses for :func:`check_time_units` to
take their unit as right; below it, another unit that puts them inside the poses is named."""

_NS_PER_S = 1_000_000_000
_MAX_COORD = 65535
# Largest whole second whose nanoseconds (plus up to 999_999_999) still fit in int64.
_MAX_SECONDS = (np.iinfo(np.int64).max - (_NS_PER_S - 1)) // _NS_PER_S
_TEXT_EXPECTED = "'t[s] x y p', e.g. '0.003811000 96 133 0'"
_TEXT_SUFFIXES = (".txt",)
_H5_SUFFIXES = (".h5", ".hdf5")


# --- events in memory ------------------------------------------------------------------------

def make_events(t: Any, x: Any, y: Any, p: Any) -> np.ndarray:
    """Build an event array from its columns.

    Parameters
    ----------
    t : (N,) integer array-like, nanoseconds
        Integer times (floats are refused: event times are never floating point).
    x, y : (N,) integer array-like, pixels
        Column and row, in [0, 65535].
    p : (N,) integer array-like
        +1 (ON) or -1 (OFF).

    Returns
    -------
    (N,) EVENT_DTYPE ndarray
        In the given order (not sorted; see :func:`check_events`).

    Raises
    ------
    ValueError
        Columns are not 1-D of one length, t is not integer, x or y is outside [0, 65535], or
        p is not +-1 (the first offending index is named).
    """
    columns = {name: np.asarray(value) for name, value in
               (("t", t), ("x", x), ("y", y), ("p", p))}
    lengths = {name: c.shape for name, c in columns.items()}
    if any(c.ndim != 1 for c in columns.values()) or len({c.size for c in columns.values()}) > 1:
        raise ValueError(f"make_events: t, x, y, p must be 1-D of one length, got shapes "
                         f"{lengths}")
    for name, column in columns.items():
        if column.size and not np.issubdtype(column.dtype, np.integer):
            what = "nanoseconds" if name == "t" else "values"
            raise ValueError(f"make_events: {name} must hold integer {what}, got dtype "
                             f"{column.dtype}")
    for name in ("x", "y"):
        bad = np.flatnonzero((columns[name] < 0) | (columns[name] > _MAX_COORD))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"make_events: {name}[{i}] = {columns[name][i]} is outside "
                             f"[0, {_MAX_COORD}]; expected pixel coordinates")
    bad = np.flatnonzero(np.abs(columns["p"]) != 1)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"make_events: p[{i}] = {columns['p'][i]}; expected +1 (ON) or -1 "
                         "(OFF)")
    events = np.empty(columns["t"].size, EVENT_DTYPE)
    for name, column in columns.items():
        events[name] = column
    return events


def _first_error(events: np.ndarray, width: int | None, height: int | None,
                 t_prev: int | None) -> tuple[int, str] | None:
    """The first index at which ``events`` breaks the contract, and what is wrong there."""
    t = events["t"]
    if t_prev is not None and t.size and t[0] < t_prev:
        return 0, (f"t = {int(t[0])} ns is before the previous event's {t_prev} ns; expected "
                   "time-ordered events")
    bad = np.flatnonzero(t[1:] < t[:-1])
    if bad.size:
        i = int(bad[0]) + 1
        return i, (f"t = {int(t[i])} ns is before the previous event's {int(t[i - 1])} ns; "
                   "expected events sorted by t")
    for name, size, what in (("x", width, "width"), ("y", height, "height")):
        if size is not None:
            bad = np.flatnonzero(events[name] >= size)
            if bad.size:
                i = int(bad[0])
                return i, (f"{name} = {int(events[name][i])} is outside the sensor ({what} "
                           f"{size}); expected 0 <= {name} < {size}")
    bad = np.flatnonzero(np.abs(events["p"]) != 1)
    if bad.size:
        i = int(bad[0])
        return i, f"p = {int(events['p'][i])}; expected +1 (ON) or -1 (OFF)"
    return None


def _check_size(width: int | None, height: int | None, source: str) -> None:
    for name, value in (("width", width), ("height", height)):
        if value is None:
            continue
        if (isinstance(value, bool) or not isinstance(value, int | np.integer)
                or not 0 < value <= _MAX_COORD + 1):
            raise ValueError(f"{source}: sensor {name} must be an integer in [1, "
                             f"{_MAX_COORD + 1}], got {value!r}")


def _check_array(events: Any, source: str) -> None:
    if not isinstance(events, np.ndarray) or events.dtype != EVENT_DTYPE or events.ndim != 1:
        what = (f"dtype {events.dtype} and shape {events.shape}"
                if isinstance(events, np.ndarray) else type(events).__name__)
        raise ValueError(f"{source}: expected a 1-D array of EVENT_DTYPE {EVENT_DTYPE}, got "
                         f"{what}")


def check_events(events: np.ndarray, width: int | None = None, height: int | None = None,
                 source: str = "events") -> None:
    """Check that an array is a valid event stream (CONVENTIONS.md, "Events").

    Parameters
    ----------
    events : (N,) EVENT_DTYPE ndarray
        Events to check.
    width, height : int, optional
        Sensor size in pixels; when given, every x must be < width and every y < height.
    source : str
        What the events are (a file name, ``"chunk 3"``), used in the message.

    Raises
    ------
    ValueError
        ``"{source}: event {i}: ..."`` naming the first index that is out of time order, outside
        the sensor or has p not +-1; or the array is not a 1-D EVENT_DTYPE array.
    """
    _check_array(events, source)
    _check_size(width, height, source)
    error = _first_error(events, width, height, None)
    if error is not None:
        raise ValueError(f"{source}: event {error[0]}: {error[1]}")


# --- atomic files ----------------------------------------------------------------------------

def _partial_path(path: Path) -> Path:
    """``<path>.partial`` (:func:`sim._atomic.partial_path`). The streaming writers keep their own
    class, not :func:`sim._atomic.atomic_file`: they hold the file open for a whole simulation and
    keep the ``.partial`` file when interrupted, for a resumed run."""
    if not path.name:
        raise ValueError(f"output path {str(path)!r} has no file name")
    return partial_path(path)


class _StreamingWriter:
    """What both writers share: the ``.partial`` file, the chunk-order check, the context."""

    path: Path
    partial: Path
    count: int
    _last_t: int | None
    _closed: bool
    _format: str
    _width: int | None = None
    _height: int | None = None

    def _begin(self, path: str | Path) -> None:
        self.path = Path(path)
        self.partial = _partial_path(self.path)
        self.count = 0
        self._last_t = None
        self._closed = False

    def _check_chunk(self, events: np.ndarray) -> None:
        source = f"{self.path}: chunk starting at event {self.count}"
        if self._closed:
            raise ValueError(f"{self.path}: write() after close(); expected writes before close")
        _check_array(events, source)
        if not events.size:
            return
        if self._last_t is not None and int(events["t"][0]) < self._last_t:
            raise ValueError(f"{source}: the chunk starts at t = {int(events['t'][0])} ns, before "
                             f"the previous chunk's last event at {self._last_t} ns; expected "
                             "consecutive, time-ordered chunks")
        error = _first_error(events, self._width, self._height, None)
        if error is not None:
            raise ValueError(f"{source}: event {self.count + error[0]}: {error[1]}")
        if int(events["t"][0]) < 0:
            raise ValueError(f"{source}: t = {int(events['t'][0])} ns is negative; expected "
                             "times >= 0 on disk")

    def checkpoint(self) -> dict:
        """Put every event written so far on disk and say where the file stands.

        The file stays open and writing goes on. After an interruption (the ``.partial`` file is
        left), a new writer of the same path given this as ``resume`` continues exactly here.

        Returns
        -------
        dict
            JSON-able: ``format`` (``"txt"`` or ``"h5"``), ``count`` (events written),
            ``last_t`` (ns of the last event, or None) and what the format needs to continue.

        Raises
        ------
        ValueError
            The writer is closed.
        """
        if self._closed:
            raise ValueError(f"{self.path}: checkpoint() after close(); expected an open writer")
        return {"format": self._format, "count": self.count, "last_t": self._last_t,
                **self._sync()}

    def _reopen(self, resume: dict, keys: tuple[str, ...]) -> None:
        """Check a :meth:`checkpoint`, restore the counts and find the file to continue."""
        if not isinstance(resume, dict) or resume.get("format") != self._format:
            got = resume.get("format") if isinstance(resume, dict) else type(resume).__name__
            raise ValueError(f"{self.path}: resume must be a checkpoint() of a {self._format} "
                             f"event writer, got {got!r}")
        missing = [key for key in ("count", "last_t", *keys) if key not in resume]
        if missing:
            raise ValueError(f"{self.path}: the checkpoint lacks {', '.join(missing)}; expected "
                             f"a dict from {type(self).__name__}.checkpoint()")
        if not self.partial.exists() and self.path.is_file():
            os.replace(self.path, self.partial)      # closed after the checkpoint: reopen it
        if not self.partial.is_file():
            raise ValueError(f"{self.partial}: no such file to resume; expected the file the "
                             "checkpointed writer left")
        self.count = int(resume["count"])
        self._last_t = None if resume["last_t"] is None else int(resume["last_t"])

    def _too_short(self, what: str, has: int, needs: int) -> ValueError:
        return ValueError(f"{self.partial} holds {has} {what}, fewer than the {needs} the "
                          "checkpoint counted; expected the file the checkpointed writer left")

    def _sync(self) -> dict:  # pragma: no cover - overridden
        raise NotImplementedError

    def _finish(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def _abort(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:
        """Finish the file and rename ``<name>.partial`` to ``<name>`` (replacing it).

        Closing twice is harmless.
        """
        if self._closed:
            return
        self._closed = True
        try:
            self._finish()
        except BaseException:
            self._abort()
            raise
        os.replace(self.partial, self.path)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        elif not self._closed:
            self._closed = True
            self._abort()


# --- text: compiled formatter and parser ----------------------------------------------------

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


def _iter_text_blocks(path: Path, block_bytes: int, width: int | None,
                      height: int | None) -> Iterator[np.ndarray]:
    t_prev = -1
    first_line = 1
    carry = b""
    with path.open("rb") as handle:
        while True:
            data = handle.read(block_bytes)
            at_end = not data
            data = carry + data
            if at_end:
                block, carry = data, b""
            else:
                cut = data.rfind(b"\n")
                if cut < 0:  # one very long line: read on
                    carry = data
                    continue
                block, carry = data[:cut + 1], data[cut + 1:]
            if block:
                events, newlines = _parse_block(block, path, first_line, width, height, t_prev)
                first_line += newlines
                if events.size:
                    t_prev = int(events["t"][-1])
                    yield events
            if at_end:
                return


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
        self._reopen(resume, ("size",))
        size = int(resume["size"])
        handle = self.partial.open("r+b")
        has = handle.seek(0, os.SEEK_END)
        if has < size:
            handle.close()
            raise self._too_short("bytes", has, size)
        handle.truncate(size)
        handle.seek(size)
        self._handle = handle

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


# --- HDF5 (DSEC layout) ----------------------------------------------------------------------

def _import_h5py():
    import h5py  # lazily: text-only users do not pay for it

    return h5py


class H5EventWriter(_StreamingWriter):
    """Stream events into an ``events.h5`` with the layout of DSEC.

    Datasets (all 1-D, resizable, chunked, shuffled and gzip-compressed at level 1, which every
    HDF5 build can read without plugins):

    - ``events/t``: int64 microseconds, relative to ``t_offset``: ``t_ns // 1000 - t_offset``.
    - ``events/x``, ``events/y``: uint16 pixel column and row.
    - ``events/p``: uint8, 1 ON / 0 OFF.
    - ``events/t_ns_rem``: uint16, ``t_ns % 1000``. An evfuse extension that DSEC readers
      ignore: microseconds drop the sub-microsecond part of a time, and this puts it back, so
      that ``t_ns = (events/t + t_offset) * 1000 + events/t_ns_rem`` is exactly the int64
      nanoseconds that were written (a lossless round trip).
    - ``ms_to_idx``: int64, DSEC's index from milliseconds to events. With ``t`` the values of
      ``events/t`` (relative microseconds), ``ms_to_idx[ms]`` is the index of the first event at
      or after ``ms`` milliseconds: ``t[ms_to_idx[ms]] >= 1000 * ms`` and
      ``t[ms_to_idx[ms] - 1] < 1000 * ms`` (so ``ms_to_idx[0] == 0``, and an empty millisecond
      gets the index of the next event). It has one entry for each ms from 0 to the last
      event's millisecond + 1 inclusive; that last entry is the number of events. The events of
      the milliseconds [a, b) are ``ms_to_idx[a]:ms_to_idx[b]``. It is built incrementally while
      streaming (an entry is written once the events that decide it have arrived).
    - ``t_offset``: scalar int64 microseconds, as in DSEC (absolute µs = ``events/t`` +
      ``t_offset``).

    Root attributes: ``width``, ``height`` (pixels) and ``t_offset`` (the same value as the
    dataset, for readers that look for an attribute).

    Parameters
    ----------
    path : str or Path
        The file to write, written as ``<path>.partial`` and renamed to ``path`` (replacing an
        existing file) by a successful :meth:`close`, which first rewrites it in one pass, so
        that the file's bytes depend only on what was written (not on checkpoints or a resume:
        the same events give the same bytes). Packing costs about as much again as writing.
    width, height : int
        Sensor size in pixels; every event must lie inside it.
    chunk_size : int
        HDF5 chunk length in events; events are also buffered and appended in blocks of at
        least this many.
    t_offset_us : int or None
        ``t_offset`` in microseconds. ``None`` (default): 0 when the first event comes within
        :data:`MAX_EMPTY_MS` ms of t = 0 (every simulated sequence), else the first event's
        time rounded down to a whole millisecond (recordings stamped with Unix time, where an
        offset of 0 would need an ``ms_to_idx`` of about 1.5e12 entries). An explicit offset
        must not come after the first event nor leave more than :data:`MAX_EMPTY_MS` empty
        milliseconds before it. Two consecutive events may not be more than
        :data:`MAX_EMPTY_MS` ms apart either.
    resume : dict, optional
        A :meth:`checkpoint` of an interrupted writer of the same path (and the same
        ``t_offset_us``): its ``.partial`` file (or ``path``, if it was closed after the
        checkpoint) is reopened, its datasets cut back to the checkpoint's lengths, and
        writing goes on from there. The datasets then hold exactly what one uninterrupted
        writer would have written (``ms_to_idx`` does not depend on where blocks were cut).

    Raises
    ------
    ValueError
        Bad sensor size or chunk size; ``resume`` is not an HDF5 writer's checkpoint, or its file
        is missing, unreadable or shorter than the checkpoint says; from :meth:`write`, a chunk
        out of order, outside the sensor, before ``t_offset``, or too far after it or after the
        previous event.
    """

    _format = "h5"
    _STATE = ("stored", "next_ms", "last_ms", "t_offset_us")

    def __init__(self, path: str | Path, width: int, height: int, chunk_size: int = 2**16,
                 t_offset_us: int | None = None, *, resume: dict | None = None) -> None:
        path = Path(path)
        if width is None or height is None:
            raise ValueError(f"{path}: an events.h5 needs the sensor size; expected width and "
                             f"height, got {width!r} and {height!r}")
        _check_size(width, height, str(path))
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
            raise ValueError(f"{path}: chunk_size must be a positive integer, got {chunk_size!r}")
        if t_offset_us is not None and (isinstance(t_offset_us, bool)
                                        or not isinstance(t_offset_us, int | np.integer)):
            raise ValueError(f"{path}: t_offset_us must be an integer (microseconds) or None, got "
                             f"{t_offset_us!r}")
        h5py = _import_h5py()
        self._begin(path)
        self._width, self._height = int(width), int(height)
        self.chunk_size = chunk_size
        self.t_offset_us = None if t_offset_us is None else int(t_offset_us)
        self._auto_offset = t_offset_us is None
        self._pending: list[np.ndarray] = []
        self._pending_count = 0
        self._stored = 0       # events appended to the datasets
        self._next_ms = 0      # first ms_to_idx entry not yet written
        self._last_ms = 0      # relative millisecond of the last event accepted
        if resume is None:
            self._create(h5py)
        else:
            self._resume(h5py, resume)

    _EVENT_FIELDS = (("t", np.int64), ("x", np.uint16), ("y", np.uint16), ("p", np.uint8),
                     ("t_ns_rem", np.uint16))

    def _create(self, h5py: Any) -> None:
        self._file = h5py.File(self.partial, "w")
        self._datasets, self._ms_to_idx = self._layout(self._file, 0, 0)

    def _layout(self, file: Any, events: int, ms_entries: int) -> tuple[dict, Any]:
        """Create the datasets of the layout in ``file``, ``events`` and ``ms_entries`` long."""
        compression = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
        group = file.create_group("events")
        datasets = {
            name: group.create_dataset(name, shape=(events,), maxshape=(None,), dtype=dtype,
                                       chunks=(self.chunk_size,), **compression)
            for name, dtype in self._EVENT_FIELDS
        }
        datasets["t_ns_rem"].attrs["description"] = (
            "evfuse extension (DSEC readers ignore it): t_ns % 1000, the sub-microsecond part; "
            "t_ns = (events/t + t_offset) * 1000 + events/t_ns_rem")
        ms_to_idx = file.create_dataset(
            "ms_to_idx", shape=(ms_entries,), maxshape=(None,), dtype=np.int64,
            chunks=(min(self.chunk_size, 2**14),), **compression)
        return datasets, ms_to_idx

    def _resume(self, h5py: Any, resume: dict) -> None:
        self._reopen(resume, self._STATE)
        stored, next_ms = int(resume["stored"]), int(resume["next_ms"])
        try:
            self._file = h5py.File(self.partial, "r+")
        except OSError as exc:
            raise ValueError(f"{self.partial}: cannot reopen as HDF5 ({exc}); expected the file "
                             "the checkpointed writer left") from None
        try:
            names = ("t", "x", "y", "p", "t_ns_rem")
            missing = [key for key in (*(f"events/{n}" for n in names), "ms_to_idx")
                       if key not in self._file]
            if missing:
                raise ValueError(f"{self.partial}: no dataset {', '.join(missing)}; expected the "
                                 "file the checkpointed writer left")
            self._datasets = {name: self._file[f"events/{name}"] for name in names}
            self._ms_to_idx = self._file["ms_to_idx"]
            for dataset, length, what in [*((d, stored, f"events in {d.name}")
                                            for d in self._datasets.values()),
                                          (self._ms_to_idx, next_ms, "ms_to_idx entries")]:
                if dataset.shape[0] < length:
                    raise self._too_short(what, dataset.shape[0], length)
                dataset.resize((length,))
            if "t_offset" in self._file:          # written by a close() after the checkpoint
                del self._file["t_offset"]
        except BaseException:
            self._file.close()
            raise
        self._stored, self._next_ms, self._last_ms = stored, next_ms, int(resume["last_ms"])
        offset = resume["t_offset_us"]
        if offset is not None:
            if not self._auto_offset and int(offset) != self.t_offset_us:
                self._file.close()
                raise ValueError(f"{self.path}: the checkpoint's t_offset_us = {offset} differs "
                                 f"from the given {self.t_offset_us}; expected the same offset "
                                 "(or None)")
            self.t_offset_us = int(offset)

    def _sync(self) -> dict:
        self._flush()
        self._file.flush()
        return {"stored": self._stored, "next_ms": self._next_ms, "last_ms": self._last_ms,
                "t_offset_us": self.t_offset_us}

    def _offset_for(self, first_t_ns: int) -> int:
        first_ms = first_t_ns // 1_000_000
        if self._auto_offset:
            return 0 if first_ms < MAX_EMPTY_MS else first_ms * 1000
        assert self.t_offset_us is not None
        relative_us = first_t_ns // 1000 - self.t_offset_us
        if relative_us < 0:
            raise ValueError(f"{self.path}: the first event at t = {first_t_ns} ns comes before "
                             f"t_offset_us = {self.t_offset_us}; expected t_offset_us <= "
                             f"{first_t_ns // 1000}")
        if relative_us // 1000 >= MAX_EMPTY_MS:
            raise ValueError(f"{self.path}: the first event at t = {first_t_ns} ns is "
                             f"{relative_us // 1000} ms after t_offset_us = {self.t_offset_us}, "
                             f"which would need that many empty ms_to_idx entries (at most "
                             f"{MAX_EMPTY_MS}); expected an offset close to the first event, "
                             "or t_offset_us=None")
        return self.t_offset_us

    def write(self, events: np.ndarray) -> None:
        """Append a chunk of events.

        Parameters
        ----------
        events : (N,) EVENT_DTYPE ndarray
            Sorted by t, starting at or after the previous chunk's last t, with t >= 0, inside
            the sensor and p = +-1. An empty chunk is allowed.

        Raises
        ------
        ValueError
            As :class:`H5EventWriter` says; nothing of a refused chunk is written.
        """
        self._check_chunk(events)
        if not events.size:
            return
        offset = self._offset_for(int(events["t"][0])) if self.count == 0 else self.t_offset_us
        assert offset is not None
        ms = (events["t"] // 1000 - offset) // 1000
        gaps = np.diff(ms, prepend=ms[0] if self.count == 0 else self._last_ms)
        bad = np.flatnonzero(gaps > MAX_EMPTY_MS)
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"{self.path}: event {self.count + i} at t = {int(events['t'][i])} "
                             f"ns comes {int(gaps[i])} ms after the previous event; ms_to_idx "
                             f"indexes every millisecond and allows at most {MAX_EMPTY_MS} empty "
                             "ones in a row; expected a recording without such a gap (split it, "
                             "or keep it as text)")
        self.t_offset_us = offset
        self._last_ms = int(ms[-1])
        self._pending.append(events)
        self._pending_count += events.size
        self.count += events.size
        self._last_t = int(events["t"][-1])
        if self._pending_count >= self.chunk_size:
            self._flush()

    @staticmethod
    def _append(dataset: Any, values: np.ndarray) -> None:
        start = dataset.shape[0]
        dataset.resize((start + values.size,))
        dataset[start:] = values

    def _flush(self) -> None:
        if not self._pending:
            return
        events = (self._pending[0] if len(self._pending) == 1
                  else np.concatenate(self._pending))
        self._pending, self._pending_count = [], 0
        assert self.t_offset_us is not None
        t_us = events["t"] // 1000 - self.t_offset_us
        self._append(self._datasets["t"], t_us)
        self._append(self._datasets["x"], events["x"])
        self._append(self._datasets["y"], events["y"])
        self._append(self._datasets["p"], (events["p"] > 0).astype(np.uint8))
        self._append(self._datasets["t_ns_rem"], (events["t"] % 1000).astype(np.uint16))
        # Every ms up to the last event's is now decided: the first event at or after it is in
        # this block (all earlier events are before it, or it would have been decided earlier).
        last_ms = int(t_us[-1]) // 1000
        if last_ms >= self._next_ms:
            bounds = np.arange(self._next_ms, last_ms + 1, dtype=np.int64) * 1000
            self._append(self._ms_to_idx,
                         self._stored + np.searchsorted(t_us, bounds, side="left"))
            self._next_ms = last_ms + 1
        self._stored += events.size

    def _finish(self) -> None:
        try:
            self._flush()
            self._append(self._ms_to_idx, np.array([self._stored], dtype=np.int64))
        finally:
            self._file.close()
        self._pack()

    def _pack(self) -> None:
        """Rewrite the finished ``.partial`` file in one sequential pass.

        Where blocks were appended (a :meth:`checkpoint` appends what is buffered) and what an
        interrupted run wrote past its checkpoint leave their traces in an HDF5 file's layout;
        the packed file's bytes depend on its contents only, so that a resumed run and an
        uninterrupted one write the same bytes, and the same seed gives the same file.
        """
        h5py = _import_h5py()
        packed = self.partial.with_name(self.partial.name + ".pack")
        offset = np.int64(0 if self.t_offset_us is None else self.t_offset_us)
        block = self.chunk_size * max(1, 2**20 // self.chunk_size)
        try:
            with h5py.File(self.partial, "r") as source, h5py.File(packed, "w") as target:
                ms_to_idx = source["ms_to_idx"]
                datasets, target_ms = self._layout(target, self._stored, ms_to_idx.shape[0])
                pairs = [(source[f"events/{name}"], datasets[name]) for name in datasets]
                for src, dst in [*pairs, (ms_to_idx, target_ms)]:
                    for start in range(0, src.shape[0], block):
                        dst[start:start + block] = src[start:start + block]
                target.create_dataset("t_offset", data=offset)
                target.attrs["t_offset"] = offset
                target.attrs["width"] = np.int64(self._width)
                target.attrs["height"] = np.int64(self._height)
            os.replace(packed, self.partial)
        finally:
            packed.unlink(missing_ok=True)

    def _abort(self) -> None:
        self._file.close()


_H5_LAYOUT = "expected an events.h5 in the DSEC layout"
_MAX_T_US = np.iinfo(np.int64).max // 1000 - 1   # largest time in µs whose ns fit in int64


@contextlib.contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Turn what h5py raises on a damaged file (overwritten or truncated bytes: OSError,
    KeyError, RuntimeError, or a ValueError that does not name the file) into one ValueError
    line that names the file and what is wrong."""
    try:
        yield
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise _damaged(path, exc) from None
    except (OSError, KeyError, RuntimeError) as exc:
        raise _damaged(path, exc) from None


def _damaged(path: Path, exc: BaseException) -> ValueError:
    detail = " ".join(str(exc).strip("'\"").split()) or type(exc).__name__
    return ValueError(f"{path}: the HDF5 file is damaged (h5py: {detail}); expected an intact "
                      "events.h5 in the DSEC layout: copy or convert it again")


class _H5Source:
    """An open ``events.h5`` (DSEC layout, with or without evfuse's ``t_ns_rem``).

    Every read names the file when it fails: a damaged file (bytes overwritten, truncated), a
    missing dataset, a dataset of the wrong type, or values outside what the layout allows.
    """

    _INTEGER = {"events/t": "integer microseconds (int64)", "events/x": "integer pixels (uint16)",
                "events/y": "integer pixels (uint16)", "events/p": "integers 0/1 (uint8)",
                "events/t_ns_rem": "integer nanoseconds (uint16)",
                "ms_to_idx": "integer event indexes (int64)"}

    def __init__(self, path: Path) -> None:
        h5py = _import_h5py()
        self.path = path
        with _reading(path):
            try:
                self.file = h5py.File(path, "r")
            except OSError as exc:
                raise ValueError(f"{path}: cannot open as HDF5 ({exc}); {_H5_LAYOUT}") from None
            try:
                self._open()
            except BaseException:
                self.file.close()
                raise

    def _open(self) -> None:
        path = self.path
        missing = [f"events/{name}" for name in "txyp" if f"events/{name}" not in self.file]
        if missing:
            raise ValueError(f"{path}: no dataset {', '.join(missing)}; expected the DSEC layout "
                             "(events/t, events/x, events/y, events/p)")
        for name, what in self._INTEGER.items():
            if name not in self.file:
                continue
            dataset = self.file[name]
            if not isinstance(dataset, _import_h5py().Dataset):
                raise ValueError(f"{path}: {name} is a group, not a dataset; expected "
                                 f"{what}")
            if dataset.dtype.kind not in "iu":
                raise ValueError(f"{path}: {name} has dtype {dataset.dtype}; expected {what}")
        self.t, self.x, self.y, self.p = (self.file[f"events/{name}"] for name in "txyp")
        self.rem = self.file["events/t_ns_rem"] if "events/t_ns_rem" in self.file else None
        self.ms_to_idx = self.file["ms_to_idx"] if "ms_to_idx" in self.file else None
        lengths = {ds.name: ds.shape for ds in (self.t, self.x, self.y, self.p, self.rem)
                   if ds is not None}
        if len(set(lengths.values())) != 1 or self.t.ndim != 1:
            raise ValueError(f"{path}: event datasets must be 1-D of one length, got {lengths}")
        self.size = self.t.shape[0]
        if self.ms_to_idx is not None and self.ms_to_idx.ndim != 1:
            raise ValueError(f"{path}: ms_to_idx must be 1-D, got shape {self.ms_to_idx.shape}")
        if "t_offset" in self.file:
            offset = self.file["t_offset"][()]
            where = "the dataset t_offset"
        else:
            offset, where = self.file.attrs.get("t_offset", 0), "the attribute t_offset"
        self.t_offset_us = self._integer(offset, where, 0, _MAX_T_US, "microseconds")
        self.width = self._size_attr("width")
        self.height = self._size_attr("height")
        self._check_ms_to_idx()

    def _integer(self, value: Any, where: str, low: int, high: int, what: str) -> int:
        """A scalar attribute or dataset as an int in [low, high], or a ValueError naming it."""
        value = np.asarray(value)
        if value.shape not in ((), (1,)) or value.dtype.kind not in "iu" \
                or not low <= int(value.reshape(-1)[0]) <= high:
            raise ValueError(f"{self.path}: {where} is {value.tolist()!r}; expected an integer "
                             f"number of {what} in [{low}, {high}]")
        return int(value.reshape(-1)[0])

    def _check_ms_to_idx(self) -> None:
        """Refuse ``events/t`` in another unit than ``ms_to_idx`` says (nanoseconds, typically).

        ``ms_to_idx`` has one entry per millisecond up to the last event's (DSEC: its length is
        the recording's in ms), so the last ``events/t`` (relative µs) over 1000 must be about
        its length: more than :data:`UNIT_SLACK` times it (and a second) off is a mismatch, named
        as a unit when it is about a factor of 1000 (or 10^6), else described as it is.
        """
        if self.ms_to_idx is None or self.size == 0 or self.ms_to_idx.shape[0] < 2:
            return

        def agree(a: float, b: float) -> bool:
            return abs(a - b) <= 1.0 or 1 / UNIT_SLACK <= a / b <= UNIT_SLACK

        last_s = float(self.t[-1]) * 1e-6
        index_s = self.ms_to_idx.shape[0] * 1e-3
        if last_s <= 0 or agree(last_s, index_s):
            return
        self._refuse_unsorted()                   # not a unit: the last time is out of order
        span_s = last_s - float(self.t[0]) * 1e-6
        unit = _unit_name(last_s / index_s, "microseconds")
        if agree(span_s, index_s):
            raise ValueError(f"{self.path}: ms_to_idx covers {index_s:.4g} s from the first "
                             f"event, but events/t runs to {last_s:.4g} s after t_offset; DSEC "
                             "layout indexes ms_to_idx from t_offset (events/t // 1000)")
        if unit is None:
            raise ValueError(f"{self.path}: events/t runs to {last_s:.4g} s but ms_to_idx "
                             f"{index_s:.4g} s; DSEC layout stores microseconds, with one "
                             "ms_to_idx entry per millisecond")
        raise ValueError(f"{self.path}: events/t looks like {unit} (span {last_s:.4g} s from "
                         f"t_offset against {index_s:.4g} s of ms_to_idx); DSEC layout stores "
                         "microseconds")

    def _refuse_unsorted(self) -> None:
        """Name the first event of ``events/t`` out of order, if any (the cause of an index or
        a span that disagrees with the times)."""
        unsorted = self._first_unsorted()
        if unsorted is not None:
            i, t_us, t_prev_us = unsorted
            raise ValueError(f"{self.path}: event {i}: events/t = {t_us} us is before the "
                             f"previous event's {t_prev_us} us; expected events sorted by t")

    def _first_unsorted(self, block: int = 1 << 20) -> tuple[int, int, int] | None:
        """The first event whose ``events/t`` is below its predecessor's: (index, its t, the
        previous t), in µs relative to t_offset; None when they are sorted."""
        previous = None
        for start in range(0, self.size, block):
            t = self.t[start:start + block].astype(np.int64)
            if previous is not None:
                t = np.concatenate(([previous], t))
            bad = np.flatnonzero(t[1:] < t[:-1])
            if bad.size:
                i = int(bad[0]) + 1
                return start + i - (previous is not None), int(t[i]), int(t[i - 1])
            previous = int(t[-1]) if t.size else previous
        return None

    def _size_attr(self, name: str) -> int | None:
        value = self.file.attrs.get(name)
        if value is None:
            return None
        return self._integer(value, f"the attribute {name}", 1, _MAX_COORD + 1, "pixels")

    def close(self) -> None:
        self.file.close()

    def index_at(self, t_ns: int) -> int:
        """A lower bound of the index of the first event at or after ``t_ns`` (via ms_to_idx)."""
        if self.ms_to_idx is None:
            return 0
        ms = (t_ns // 1000 - self.t_offset_us) // 1000
        if ms <= 0:
            return 0
        if ms >= self.ms_to_idx.shape[0]:
            return self.size
        return self._index(ms)

    def index_before(self, t_ns: int) -> int:
        """An upper bound of the index after the last event before ``t_ns`` (via ms_to_idx)."""
        if self.ms_to_idx is None:
            return self.size
        # Events before t_ns have t_us <= (t_ns - 1) // 1000; the first index of the next ms
        # is past them.
        ms = ((t_ns - 1) // 1000 - self.t_offset_us) // 1000 + 1
        if ms <= 0:
            return 0
        if ms >= self.ms_to_idx.shape[0]:
            return self.size
        return self._index(ms)

    def _index(self, ms: int) -> int:
        """``ms_to_idx[ms]``, checked against ``events/t``: the first event at or after ``ms``
        milliseconds (a wrong index would silently drop or add events to a window)."""
        with _reading(self.path):
            index = int(self.ms_to_idx[ms])
            bound = ms * 1000
            if not (0 <= index <= self.size
                    and (index == 0 or int(self.t[index - 1]) < bound)
                    and (index == self.size or int(self.t[index]) >= bound)):
                self._refuse_unsorted()           # the cause, where events/t is out of order
                raise ValueError(f"{self.path}: ms_to_idx[{ms}] = {index} is not the index of "
                                 f"the first event at or after {ms} ms (of {self.size} events); "
                                 "expected the DSEC layout's index")
        return index

    def read(self, start: int, stop: int) -> np.ndarray:
        """Events [start, stop) as EVENT_DTYPE, every value checked against the layout: p 0/1,
        t_ns_rem < 1000, x and y in [0, 65535], times from 0 to int64 nanoseconds."""
        with _reading(self.path):
            return self._read(start, stop)

    def _first_bad(self, start: int, bad: np.ndarray, message: Callable[[int], str]) -> None:
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"{self.path}: event {start + i}: {message(i)}")

    def _read(self, start: int, stop: int) -> np.ndarray:
        events = np.empty(stop - start, EVENT_DTYPE)
        t_us = self.t[start:stop].astype(np.int64)
        p = self.p[start:stop]
        self._first_bad(start, np.flatnonzero((p != 0) & (p != 1)),
                        lambda i: f"events/p = {int(p[i])}; expected 1 (ON) or 0 (OFF)")
        low, high = -self.t_offset_us, _MAX_T_US - self.t_offset_us
        self._first_bad(start, np.flatnonzero((t_us < low) | (t_us > high)),
                        lambda i: f"events/t = {int(t_us[i])} us (t_offset {self.t_offset_us} "
                                  f"us) is outside [{low}, {high}]; expected times from 0 to "
                                  "int64 nanoseconds")
        t_ns = (t_us + self.t_offset_us) * 1000
        if self.rem is not None:
            rem = self.rem[start:stop].astype(np.int64)
            self._first_bad(start, np.flatnonzero((rem < 0) | (rem >= 1000)),
                            lambda i: f"events/t_ns_rem = {int(rem[i])}; expected 0 to 999 ns")
            t_ns += rem
        events["t"] = t_ns
        for name, dataset in (("x", self.x), ("y", self.y)):
            values = dataset[start:stop]
            if values.dtype != np.uint16 and values.dtype != np.uint8:
                self._first_bad(start, np.flatnonzero((values < 0) | (values > _MAX_COORD)),
                                lambda i, v=values, n=name: f"events/{n} = {int(v[i])}; "
                                f"expected pixel coordinates in [0, {_MAX_COORD}]")
            events[name] = values
        events["p"] = np.where(p == 1, 1, -1)
        return events


# --- time units --------------------------------------------------------------------------------

_UNITS = {"seconds": 1.0, "milliseconds": 1e-3, "microseconds": 1e-6, "nanoseconds": 1e-9}


def _unit_name(ratio: float, stored: str) -> str | None:
    """The unit within a factor 10 of ``stored`` times ``1 / ratio`` (what times read as
    ``stored`` but ``ratio`` times too long or short were written in), else None."""
    if not ratio > 0:
        return None
    scale = _UNITS[stored] / ratio
    name = min(_UNITS, key=lambda unit: abs(np.log10(_UNITS[unit] / scale)))
    return name if abs(np.log10(_UNITS[name] / scale)) < 1 and name != stored else None


def check_time_units(path: str | Path, first_s: float, last_s: float, t_start: float,
                     t_end: float) -> None:
    """Refuse events whose times are in another unit than their format stores, judged by poses.

    Events whose span overlaps the poses ``[t_start, t_end]`` over less than
    :data:`UNIT_OVERLAP` of it and is more than :data:`UNIT_SLACK` times longer (or shorter)
    than theirs, but would lie at least half inside them read in another unit (DSEC
    ``events.h5`` stores microseconds; ECD ``events.txt``, seconds), were written in that unit:
    a mapping over them could only fail later with a less telling message. Events merely
    outside the poses, with a span like theirs, are left to the window checks.

    Parameters
    ----------
    path : str or Path
        The event file (its suffix gives the stored unit).
    first_s, last_s : float, seconds
        First and last event time as read.
    t_start, t_end : float, seconds
        Time span of the poses (``groundtruth.txt``).

    Raises
    ------
    ValueError
        ``"{path}: events/t looks like nanoseconds (events at 3.81-174 s against 0.0223-3.4 s
        of poses); DSEC layout stores microseconds"`` and the like.
    """
    path = Path(path)

    def inside(a: float, b: float) -> float:
        """Share of [a, b] inside the poses (1 or 0 for a single instant)."""
        if b <= a:
            return float(t_start <= a <= t_end)
        return max(0.0, min(b, t_end) - max(a, t_start)) / (b - a)

    if inside(first_s, last_s) >= UNIT_OVERLAP:
        return
    stored = "microseconds" if _kind(path) == "h5" else "seconds"
    ratio = (last_s - first_s) / max(t_end - t_start, 1e-9)      # events' span / poses'
    for unit, size in _UNITS.items():
        factor = size / _UNITS[stored]
        if unit == stored or inside(first_s * factor, last_s * factor) < 0.5:
            continue
        if not (ratio > UNIT_SLACK if factor < 1 else ratio < 1 / UNIT_SLACK):
            continue
        field = "events/t looks" if stored == "microseconds" else "the times look"
        layout = "DSEC layout stores microseconds" if stored == "microseconds" else \
            "ECD text stores seconds"
        raise ValueError(f"{path}: {field} like {unit} (events at {first_s:.4g}-"
                         f"{last_s:.4g} s against {t_start:.4g}-{t_end:.4g} s of poses); "
                         f"{layout}")


def event_time_span(path: str | Path, width: int | None = None,
                    height: int | None = None) -> tuple[float, float]:
    """First and last event time of a file, seconds (an HDF5 file: read at its two ends).

    Raises
    ------
    ValueError
        The file holds no events, or as :func:`iter_event_chunks`.
    """
    path = Path(path)
    if _kind(path) == "h5" and path.is_file():
        source = _H5Source(path)
        try:
            if source.size:
                return (int(source.read(0, 1)["t"][0]) * 1e-9,
                        int(source.read(source.size - 1, source.size)["t"][0]) * 1e-9)
        finally:
            source.close()
        raise ValueError(f"{path}: the file holds no events")
    stat = path.stat()
    return _text_time_span(str(path.resolve()), stat.st_size, stat.st_mtime_ns, width, height)


@functools.lru_cache(maxsize=16)
def _text_time_span(path: str, size: int, mtime_ns: int, width: int | None,
                    height: int | None) -> tuple[float, float]:
    """:func:`event_time_span` of a text file: one streaming pass, remembered per file version
    (size and modification time), so that the window checks of map and run read it once."""
    first = last = None
    for chunk in iter_event_chunks(path, 10**6, width=width, height=height):
        if len(chunk):
            first = chunk["t"][0] if first is None else first
            last = chunk["t"][-1]
    if first is None:
        raise ValueError(f"{path}: the file holds no events")
    return int(first) * 1e-9, int(last) * 1e-9


# --- reading ---------------------------------------------------------------------------------

def _kind(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in _TEXT_SUFFIXES:
        return "txt"
    if suffix in _H5_SUFFIXES:
        return "h5"
    raise ValueError(f"{path}: unknown event file type {suffix!r}; expected .txt (ECD text) or "
                     ".h5 (DSEC HDF5)")


def _check_window(t0_ns: int | None, t1_ns: int | None) -> None:
    for name, value in (("t0_ns", t0_ns), ("t1_ns", t1_ns)):
        if value is not None and (isinstance(value, bool)
                                  or not isinstance(value, int | np.integer)):
            raise ValueError(f"{name} must be an integer number of nanoseconds or None, got "
                             f"{value!r}")
    if t0_ns is not None and t1_ns is not None and t1_ns < t0_ns:
        raise ValueError(f"time window [{t0_ns}, {t1_ns}) ns ends before it starts; expected "
                         "t0_ns <= t1_ns")


def _iter_h5(path: Path, chunk_events: int, t0_ns: int | None, t1_ns: int | None,
             width: int | None, height: int | None) -> Iterator[np.ndarray]:
    source = _H5Source(path)
    try:
        start = 0 if t0_ns is None else source.index_at(t0_ns)
        stop = source.size if t1_ns is None else source.index_before(t1_ns)
        t_prev = None
        for begin in range(start, stop, chunk_events):
            events = source.read(begin, min(begin + chunk_events, stop))
            error = _first_error(events, width, height, t_prev)
            if error is not None:
                raise ValueError(f"{path}: event {begin + error[0]}: {error[1]}")
            t_prev = int(events["t"][-1])
            lo = 0 if t0_ns is None else int(np.searchsorted(events["t"], t0_ns, side="left"))
            hi = (events.size if t1_ns is None
                  else int(np.searchsorted(events["t"], t1_ns, side="left")))
            if hi > lo:
                yield events[lo:hi]
            if hi < events.size:
                return
    finally:
        source.close()


def _iter_txt(path: Path, chunk_events: int, t0_ns: int | None, t1_ns: int | None,
              width: int | None, height: int | None) -> Iterator[np.ndarray]:
    block_bytes = int(np.clip(chunk_events * 24, 1 << 20, 64 << 20))
    for block in _iter_text_blocks(path, block_bytes, width, height):
        lo = 0 if t0_ns is None else int(np.searchsorted(block["t"], t0_ns, side="left"))
        hi = (block.size if t1_ns is None
              else int(np.searchsorted(block["t"], t1_ns, side="left")))
        for begin in range(lo, hi, chunk_events):
            yield block[begin:min(begin + chunk_events, hi)]
        if hi < block.size:
            return


def iter_event_chunks(path: str | Path, chunk_events: int = 10**6, t0_ns: int | None = None,
                      t1_ns: int | None = None, *, width: int | None = None,
                      height: int | None = None) -> Iterator[np.ndarray]:
    """Stream the events of a file in chunks, never holding the whole file.

    Parameters
    ----------
    path : str or Path
        ``.txt`` (ECD text) or ``.h5``/``.hdf5`` (DSEC layout).
    chunk_events : int
        Most events per chunk.
    t0_ns, t1_ns : int, optional
        Only events with ``t0_ns <= t < t1_ns`` (nanoseconds). HDF5 files seek to ``t0_ns`` with
        ``ms_to_idx`` and stop at ``t1_ns``; text files are parsed from the start and stop at
        ``t1_ns``.
    width, height : int, optional
        Sensor size; events outside it are an error.

    Yields
    ------
    (M,) EVENT_DTYPE ndarray
        Consecutive, time-ordered chunks of 1 to ``chunk_events`` events.

    Raises
    ------
    ValueError
        Unknown suffix; a malformed line (``"{path}:{line}: ..."``: not 4 fields ``t x y p``,
        a time that is not seconds with up to 9 decimals, x or y not a non-negative integer,
        p not 0/1), a time before the previous line's, a pixel outside the sensor; for HDF5,
        missing datasets or bad values (``"{path}: event {i}: ..."``).
    """
    path = Path(path)
    kind = _kind(path)
    if isinstance(chunk_events, bool) or not isinstance(chunk_events, int) or chunk_events < 1:
        raise ValueError(f"chunk_events must be a positive integer, got {chunk_events!r}")
    _check_window(t0_ns, t1_ns)
    _check_size(width, height, str(path))
    if not path.is_file():
        raise ValueError(f"event file {path} does not exist")
    iterate = _iter_h5 if kind == "h5" else _iter_txt
    yield from iterate(path, chunk_events, t0_ns, t1_ns, width, height)


def _concatenate(chunks: Iterator[np.ndarray]) -> np.ndarray:
    parts = list(chunks)
    if not parts:
        return np.empty(0, EVENT_DTYPE)
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def read_events(path: str | Path, width: int | None = None,
                height: int | None = None) -> np.ndarray:
    """Read a whole event file.

    Parameters
    ----------
    path : str or Path
        ``.txt`` (ECD text) or ``.h5``/``.hdf5`` (DSEC layout).
    width, height : int, optional
        Sensor size; events outside it are an error (naming the line or event).

    Returns
    -------
    (N,) EVENT_DTYPE ndarray
        t in int64 nanoseconds (exact: text times are parsed as integers, HDF5 times restored
        from microseconds + ``t_ns_rem``), p +-1.

    Raises
    ------
    ValueError
        As :func:`iter_event_chunks`.
    """
    return _concatenate(iter_event_chunks(path, 1 << 26, width=width, height=height))


def read_window(path: str | Path, t0_ns: int, t1_ns: int) -> np.ndarray:
    """Read the events with ``t0_ns <= t < t1_ns``.

    Parameters
    ----------
    path : str or Path
        ``.txt`` or ``.h5``. For HDF5 only the milliseconds around the window are read (found
        with ``ms_to_idx``, then trimmed exactly with a binary search on the nanosecond times).
    t0_ns, t1_ns : int
        Window in nanoseconds, ``t0_ns <= t1_ns``.

    Returns
    -------
    (M,) EVENT_DTYPE ndarray

    Raises
    ------
    ValueError
        A bad window, or as :func:`iter_event_chunks`.
    """
    if t0_ns is None or t1_ns is None:
        raise ValueError(f"read_window needs both t0_ns and t1_ns, got {t0_ns!r} and {t1_ns!r}")
    return _concatenate(iter_event_chunks(path, 1 << 26, t0_ns, t1_ns))


# --- conversion ------------------------------------------------------------------------------

def convert_events(src: str | Path, dst: str | Path, width: int | None = None,
                   height: int | None = None) -> None:
    """Convert an event file between ECD text and DSEC HDF5 (by suffix), streaming.

    Parameters
    ----------
    src, dst : str or Path
        ``.txt`` or ``.h5``/``.hdf5`` each (any combination; ``dst`` is written atomically and
        replaced if it exists).
    width, height : int, optional
        Sensor size. Required for an HDF5 ``dst`` unless ``src`` is an HDF5 file with
        ``width``/``height`` attributes (they are copied; given values take precedence). When
        given, every event is checked to lie inside the sensor. An HDF5 source's ``t_offset``
        is kept; a text source gets the writer's default (see :class:`H5EventWriter`).

    Raises
    ------
    ValueError
        Unknown suffixes, ``src`` and ``dst`` are the same file, the sensor size is unknown for
        an HDF5 output, or the source is malformed (as :func:`iter_event_chunks`); then, as on
        any failure, no ``dst`` and no ``<dst>.partial`` is left.
    """
    src, dst = Path(src), Path(dst)
    src_kind, dst_kind = _kind(src), _kind(dst)
    if not src.is_file():
        raise ValueError(f"event file {src} does not exist")
    if dst.exists() and dst.resolve() == src.resolve():
        raise ValueError(f"cannot convert {src} onto itself; expected a different output path")
    t_offset_us = None
    if src_kind == "h5":
        source = _H5Source(src)
        try:
            width = width if width is not None else source.width
            height = height if height is not None else source.height
            t_offset_us = source.t_offset_us
        finally:
            source.close()
    writer: TextEventWriter | H5EventWriter
    if dst_kind == "h5":
        if width is None or height is None:
            raise ValueError(f"converting {src} to {dst}: an events.h5 needs the sensor size; "
                             "expected width and height (evfuse convert reads them from the "
                             "sequence folder, or pass --sensor WxH)")
        writer = H5EventWriter(dst, width, height, t_offset_us=t_offset_us)
    else:
        writer = TextEventWriter(dst)
    try:
        with writer:
            for chunk in iter_event_chunks(src, 1 << 20, width=width, height=height):
                writer.write(chunk)
    except BaseException:                 # a failed conversion leaves nothing (not resumable)
        writer.partial.unlink(missing_ok=True)
        raise
