"""Reading event files of either format: :func:`iter_event_chunks` (streamed, optionally a time
window; dispatched on the suffix), :func:`read_events`, :func:`read_window` and
:func:`event_time_span`; for text files, which have no index of their own, :func:`text_offsets`
(where given times begin, found in one streaming pass), :func:`read_text_span` (the events of
a byte range) and :func:`line_offsets` (where given lines begin in a per-event text file aligned
line for line with the events: ``events_depth.txt``, ``events_labels.txt``)."""

from __future__ import annotations

import functools
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from sim.eventio._events import EVENT_DTYPE, _check_size, _first_error
from sim.eventio._formats import _kind, format_for, is_bag_folder
from sim.eventio._hdf5 import H5EventWriter, _H5Source
from sim.eventio._text import TextEventWriter, _iter_text_blocks, _line_blocks, _parse_block

__all__ = ["event_time_span", "iter_event_chunks", "line_offsets", "read_byte_span", "read_events",
           "read_text_span", "read_window", "text_offsets"]


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
        chunks = (source.read(begin, min(begin + chunk_events, stop))
                  for begin in range(start, stop, chunk_events))
        yield from _checked_window(path, chunks, start, t0_ns, t1_ns, width, height)
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
                      height: int | None = None, selectors: dict | None = None,
                      options: dict | None = None) -> Iterator[np.ndarray]:
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
    selectors : dict, optional
        Which format of a suffix that holds more than one (``{"evt": 2}``; see
        :func:`sim.eventio._formats.format_for`).
    options : dict, optional
        What the format's reader takes besides the file (a bag's ``{"topic": "/dvs/events"}``).

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
    kind = format_for(path, **(selectors or {})).name
    if isinstance(chunk_events, bool) or not isinstance(chunk_events, int) or chunk_events < 1:
        raise ValueError(f"chunk_events must be a positive integer, got {chunk_events!r}")
    _check_window(t0_ns, t1_ns)
    _check_size(width, height, str(path))
    if not (path.is_file() or is_bag_folder(path)):
        raise ValueError(f"event file {path} does not exist")
    if kind in ("h5", "txt"):
        if options:
            raise ValueError(f"{path}: {', '.join(options)} do(es) not apply to a {kind} file")
        iterate = _iter_h5 if kind == "h5" else _iter_txt
        yield from iterate(path, chunk_events, t0_ns, t1_ns, width, height)
        return
    # a time out of order is reported with the file and its event index, never sorted
    chunks = format_for(path, **(selectors or {})).iter_chunks(path, chunk_events=chunk_events,
                                                               **(options or {}))
    yield from _checked_window(path, chunks, 0, t0_ns, t1_ns, width, height)


def _checked_window(path: Path, chunks, first: int, t0_ns: int | None, t1_ns: int | None,
                    width: int | None, height: int | None) -> Iterator[np.ndarray]:
    """Consecutive chunks of a file's events, from its event ``first`` on, checked (time order
    across chunks, the sensor: the first bad event named by its index in the file) and cut to
    ``[t0_ns, t1_ns)``; stops at the first chunk that reaches ``t1_ns``."""
    t_prev = None
    count = first
    for events in chunks:
        error = _first_error(events, width, height, t_prev)
        if error is not None:
            raise ValueError(f"{path}: event {count + error[0]}: {error[1]}")
        count += events.size
        if not events.size:
            continue
        t_prev = int(events["t"][-1])
        lo = 0 if t0_ns is None else int(np.searchsorted(events["t"], t0_ns, side="left"))
        hi = (events.size if t1_ns is None
              else int(np.searchsorted(events["t"], t1_ns, side="left")))
        if hi > lo:
            yield events[lo:hi]
        if hi < events.size:
            return


def _txt_writer(path: Path, *, sensor_size: tuple[int, int] | None = None,
                **options) -> TextEventWriter:
    """The registry's writer of ECD text (the sensor size is not stored)."""
    return TextEventWriter(path, **options)


def _h5_writer(path: Path, *, sensor_size: tuple[int, int] | None,
               **options) -> H5EventWriter:
    """The registry's writer of the DSEC HDF5 layout (it needs the sensor size)."""
    if sensor_size is None:
        raise ValueError(f"{path}: an events.h5 needs the sensor size; expected (width, height)")
    return H5EventWriter(path, int(sensor_size[0]), int(sensor_size[1]), **options)


def _txt_chunks(path: Path, *, chunk_events: int, **options) -> Iterator[np.ndarray]:
    return _iter_txt(path, chunk_events, None, None, options.get("width"), options.get("height"))


def _h5_chunks(path: Path, *, chunk_events: int, **options) -> Iterator[np.ndarray]:
    return _iter_h5(path, chunk_events, None, None, options.get("width"), options.get("height"))


def _txt_info(path: Path) -> dict:
    first, last = event_time_span(path)
    return {"format": "txt", "sensor_size": None, "t_first_ns": round(first * 1e9),
            "t_last_ns": round(last * 1e9), "count": None}


def _h5_info(path: Path) -> dict:
    source = _H5Source(path)
    try:
        size = source.size
        first = int(source.read(0, 1)["t"][0]) if size else None
        last = int(source.read(size - 1, size)["t"][0]) if size else None
        sensor = (None if source.width is None or source.height is None
                  else (int(source.width), int(source.height)))
        return {"format": "h5", "sensor_size": sensor, "t_first_ns": first, "t_last_ns": last,
                "count": size, "t_offset_us": source.t_offset_us}
    finally:
        source.close()


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


_TEXT_BLOCK = 1 << 22
"""Bytes of an ``events.txt`` parsed at a time by :func:`text_offsets` (4 MiB: its memory)."""


def _event_line_starts(block: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Byte offset and 0-based line number, within ``block`` (whole lines), of each line that
    holds an event: its first byte after spaces and tabs is a digit (every other line the text
    parser accepts is blank or a ``#`` comment)."""
    buf = np.frombuffer(block, dtype=np.uint8)
    starts = np.concatenate(([0], np.flatnonzero(buf == 10) + 1))
    starts = starts[starts < buf.size]
    first = buf[starts]
    digit = (first >= 48) & (first <= 57)
    for k in np.flatnonzero((first == 32) | (first == 9)):   # rare: indented lines
        text = block[starts[k]:block.find(b"\n", starts[k]) % (len(block) + 1)].lstrip(b" \t")
        digit[k] = text[:1].isdigit()
    lines = np.flatnonzero(digit)
    return starts[lines], lines


def text_offsets(path: str | Path, times_ns: np.ndarray, *, width: int | None = None,
                 height: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each of ``times_ns`` begins in an ``events.txt``: the byte offset, line number and
    index of its first event at or after that time, found in one streaming pass (which stops
    after the last of ``times_ns``).

    With them, the events of ``[times_ns[k], times_ns[k + 1])`` are the bytes between two
    offsets (:func:`read_text_span`): a text file read window by window without parsing it from
    the start each time; and, being events ``counts[k]`` to ``counts[k + 1]``, their lines in a
    per-event file aligned with the events are found with :func:`line_offsets`.

    Parameters
    ----------
    path : str or Path
        An ECD ``events.txt``.
    times_ns : (K,) int64 ndarray, nanoseconds
        Non-decreasing.
    width, height : int, optional
        Sensor size; events outside it are an error.

    Returns
    -------
    offsets : (K,) int64 ndarray, bytes
        Offset of the line of the first event with ``t >= times_ns[k]`` (the file's size when
        there is none).
    lines : (K,) int64 ndarray
        Its 1-based line number (one past the last line when there is none), for messages.
    counts : (K,) int64 ndarray
        Its 0-based index among the file's events: the number of events before it (with
        ``t < times_ns[k]``; the number of events in the file when there is none).

    Raises
    ------
    ValueError
        ``times_ns`` not non-decreasing, or as :func:`iter_event_chunks`.
    """
    path = Path(path)
    times = np.asarray(times_ns, dtype=np.int64).reshape(-1)
    if np.any(np.diff(times) < 0):
        raise ValueError(f"text_offsets: times_ns must be non-decreasing, got {times[:5]}...")
    _check_size(width, height, str(path))
    if not path.is_file():
        raise ValueError(f"event file {path} does not exist")
    offsets = np.full(times.size, path.stat().st_size, np.int64)
    lines = np.zeros(times.size, np.int64)
    counts = np.zeros(times.size, np.int64)
    found = 0                                     # times placed so far
    position, first_line, t_prev, ended, seen = 0, 1, -1, True, 0
    for block in _line_blocks(path, _TEXT_BLOCK):
        if found == times.size:
            break
        events, newlines = _parse_block(block, path, first_line, width, height, t_prev)
        if events.size:
            starts, numbers = _event_line_starts(block)
            if starts.size != events.size:        # cannot happen for a file the parser took
                raise ValueError(f"{path}: {events.size} events but {starts.size} event lines "
                                 f"from line {first_line}")
            t_prev = int(events["t"][-1])
            last = found + int(np.searchsorted(times[found:], t_prev, side="right"))
            at = np.searchsorted(events["t"], times[found:last], side="left")
            offsets[found:last] = position + starts[at]
            lines[found:last] = first_line + numbers[at]
            counts[found:last] = seen + at
            found = last
            seen += events.size
        position += len(block)
        first_line += newlines
        ended = block.endswith(b"\n")
    lines[found:] = first_line + (0 if ended else 1)
    counts[found:] = seen
    return offsets, lines, counts


def line_offsets(path: str | Path, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Where given data lines begin in a text file: the byte offset and line number of its
    ``indices[k]``-th line that holds data, in one streaming pass over the whole file.

    A data line is one whose first byte after spaces and tabs is a digit (blank lines and
    ``#`` comments are not): in a per-event text file aligned line for line with the events
    (``events_depth.txt``, ``events_labels.txt``), data line ``i`` belongs to event ``i``, so
    the lines of events ``[counts[k], counts[k + 1])`` (:func:`text_offsets`) are the bytes
    between two of these offsets, read without the rest of the file.

    Parameters
    ----------
    path : str or Path
        A text file.
    indices : (K,) int64 ndarray
        0-based data-line indexes, non-decreasing, >= 0.

    Returns
    -------
    offsets : (K,) int64 ndarray, bytes
        Offset of data line ``indices[k]`` (the file's size when the file has no such line).
    lines : (K,) int64 ndarray
        Its 1-based line number in the file (one past the last line when there is none), for
        messages.
    total : int
        The number of data lines in the file (to check it against the number of events).

    Raises
    ------
    ValueError
        ``indices`` negative or not non-decreasing, or no such file.
    """
    path = Path(path)
    wanted = np.asarray(indices, dtype=np.int64).reshape(-1)
    if np.any(np.diff(wanted) < 0) or np.any(wanted < 0):
        raise ValueError(f"line_offsets: indices must be non-decreasing and >= 0, got "
                         f"{wanted[:5]}...")
    if not path.is_file():
        raise ValueError(f"{path} does not exist")
    offsets = np.full(wanted.size, path.stat().st_size, np.int64)
    lines = np.zeros(wanted.size, np.int64)
    found = 0
    position, first_line, total, ended = 0, 1, 0, True
    for block in _line_blocks(path, _TEXT_BLOCK):
        starts, numbers = _event_line_starts(block)
        last = found + int(np.searchsorted(wanted[found:], total + starts.size, side="left"))
        at = wanted[found:last] - total
        offsets[found:last] = position + starts[at]
        lines[found:last] = first_line + numbers[at]
        found = last
        total += starts.size
        position += len(block)
        first_line += block.count(b"\n")
        ended = block.endswith(b"\n")
    lines[found:] = first_line + (0 if ended else 1)
    return offsets, lines, total


def read_text_span(path: str | Path, start: int, stop: int, first_line: int = 1, *,
                   width: int | None = None, height: int | None = None) -> np.ndarray:
    """The events of bytes ``[start, stop)`` of an ``events.txt`` (offsets from
    :func:`text_offsets`: whole lines).

    Parameters
    ----------
    path : str or Path
        An ECD ``events.txt``.
    start, stop : int, bytes
        ``0 <= start <= stop``; both at the start of a line (or the file's end).
    first_line : int
        The line number at ``start`` (1-based), for messages.
    width, height : int, optional
        Sensor size; events outside it are an error.

    Returns
    -------
    (M,) EVENT_DTYPE ndarray
        Time-ordered (the order is checked within the span).

    Raises
    ------
    ValueError
        A bad range, or a malformed line (``"{path}:{line}: ..."``, as
        :func:`iter_event_chunks`).
    """
    path = Path(path)
    _check_size(width, height, str(path))
    block = read_byte_span(path, start, stop)
    return _parse_block(block, path, int(first_line), width, height, -1)[0]


def read_byte_span(path: str | Path, start: int, stop: int) -> bytes:
    """Bytes ``[start, stop)`` of a file: a span of a text file found by :func:`text_offsets`
    or :func:`line_offsets` (the per-event files' span readers parse it).

    Raises
    ------
    ValueError
        ``start`` or ``stop`` not a byte offset >= 0, ``stop < start``, or no such file.
    """
    path = Path(path)
    for name, value in (("start", start), ("stop", stop)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
            raise ValueError(f"{path}: {name} must be a byte offset >= 0, got {value!r}")
    if stop < start:
        raise ValueError(f"{path}: byte range [{start}, {stop}) ends before it starts")
    if not path.is_file():
        raise ValueError(f"{path} does not exist")
    with path.open("rb") as handle:
        handle.seek(int(start))
        return handle.read(int(stop) - int(start))
