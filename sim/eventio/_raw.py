"""Prophesee RAW files (Metavision / OpenEB): EVT 3.0 (default) and EVT 2.0, written and read,
streamed, by compiled (Numba) loops.

A RAW file is a text header of ``% key value`` lines, ended by ``% end``, followed by the event
words, little-endian:

EVT 3.0 (16-bit words, the type in the 4 high bits; Prophesee's "EVT 3.0 Format" page)
    ``EVT_ADDR_Y`` (0x0: y in bits 10..0), ``EVT_ADDR_X`` (0x2: polarity in bit 11, x in bits
    10..0: one event at the current y and time), ``VECT_BASE_X`` (0x3), ``VECT_12`` (0x4) and
    ``VECT_8`` (0x5) (a run of events from a base x, one bit each), ``EVT_TIME_LOW`` (0x6) and
    ``EVT_TIME_HIGH`` (0x8), the lower and higher 12 bits of the 24-bit time base in
    microseconds. The time of an event is ``time_high << 12 | time_low``, the two most recent
    values; a time high smaller than the previous one means the 24-bit base wrapped (every
    2^24 us = 16.78 s), and the reader adds 2^24 us. A time low smaller than the previous one
    says nothing by itself: the time high that follows it carries the step (a reader that
    also counts it, as expelliarmus 1.1.12 does, reads 4,096 us late).
EVT 2.0 (32-bit words)
    ``CD_OFF`` (0x0) and ``CD_ON`` (0x1): time low 6 bits in 27..22, x in 21..11, y in 10..0;
    ``EVT_TIME_HIGH`` (0x8): the time's bits 33..6 in 27..0 (wraps every 2^34 us, 4.8 h).

The EVT 3.0 writer emits an ``EVT_TIME_HIGH`` word for every time-high value between two events
(as a sensor does, about 500 bytes a second of recording) and the EVT 2.0 writer one at least every
half wrap, so that no wrap is ever skipped however long the gap; and the EVT 3.0 writer emits
one ``EVT_ADDR_X`` word per event (vectors are read, not written). Times
are stored as ``t_ns // 1000`` (floor) and read as microseconds * 1000 (the registry's rule).

The header written is the one Metavision writes and reads: ``% evt 3.0`` (or ``2.0``),
``% format EVT3;height=H;width=W`` (or ``EVT2``), ``% geometry WxH``, ``% integrator_name``,
``% end``. The reader honours faery's ``% t0`` key (stored times are relative to it). A RAW file
holds no intrinsics (a recording needs a calibration beside it).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

import numba
import numpy as np

from sim.eventio._events import EVENT_DTYPE, _check_size
from sim.eventio._writer import _StreamingWriter

__all__ = ["RawEventWriter", "evt2_writer", "evt3_writer", "iter_raw_chunks", "raw_info"]

_EVT3_MAX_COORD = 2047        # 11 bits of x and y in both formats
_HEADER_MAX = 1 << 20         # a header longer than this is not a RAW header
_TIME_HIGH_3 = 1 << 12        # us per EVT3 time-high step
_TIME_HIGH_2 = 1 << 6         # us per EVT2 time-high step
_WRAP_3 = 1 << 24             # us of the EVT3 time base
_WRAP_2 = 1 << 34             # us of the EVT2 time base
_HALF_WRAP_2 = 1 << 27        # EVT2 time-high steps in half a wrap


@numba.njit(cache=True)
def _encode_evt3(t_ns, x, y, p, out, state):
    """EVT 3.0 words of events (times in ns, >= 0, stored as ``t_ns // 1000``); ``state`` =
    [time high (full, -1 none), time low, y] is updated. Returns the words written into
    ``out``."""
    n = 0
    high, low, cur_y = state[0], state[1], state[2]
    for i in range(t_ns.size):
        t = t_ns[i] // 1000
        h = t >> 12
        if h != high:
            start = h if high < 0 else high + 1
            for k in range(start, h + 1):
                out[n] = 0x8000 | (k & 0xFFF)
                n += 1
            high = h
            low = -1
        lo = t & 0xFFF
        if lo != low:
            out[n] = 0x6000 | lo
            n += 1
            low = lo
        if y[i] != cur_y:
            out[n] = y[i] & 0x7FF
            n += 1
            cur_y = y[i]
        out[n] = 0x2000 | ((1 if p[i] > 0 else 0) << 11) | (x[i] & 0x7FF)
        n += 1
    state[0], state[1], state[2] = high, low, cur_y
    return n


@numba.njit(cache=True)
def _encode_evt2(t_ns, x, y, p, out, state):
    """EVT 2.0 words of events (times in ns, stored as ``t_ns // 1000``); ``state`` = [time
    high (full, -1 none)] is updated."""
    n = 0
    high = state[0]
    for i in range(t_ns.size):
        t = t_ns[i] // 1000
        h = t >> 6
        if h != high:
            if high >= 0:                     # a gap of half a wrap or more: words between
                k = high + _HALF_WRAP_2
                while k < h:
                    out[n] = np.uint32(0x80000000) | np.uint32(k & 0xFFFFFFF)
                    n += 1
                    k += _HALF_WRAP_2
            out[n] = np.uint32(0x80000000) | np.uint32(h & 0xFFFFFFF)
            n += 1
            high = h
        kind = np.uint32(1) if p[i] > 0 else np.uint32(0)
        out[n] = ((kind << np.uint32(28)) | (np.uint32(t & 0x3F) << np.uint32(22))
                  | (np.uint32(x[i] & 0x7FF) << np.uint32(11)) | np.uint32(y[i] & 0x7FF))
        n += 1
    state[0] = high
    return n


@numba.njit(cache=True)
def _decode_evt3(words, state, t_out, x_out, y_out, p_out):
    """Events of EVT 3.0 words (times in ns). ``state`` = [loops (us), time high, time low, y,
    base x, pol, seen time high (0/1)] is updated. Returns the number of events written."""
    n = 0
    loops, high, low, cur_y, base_x, pol, seen = (state[0], state[1], state[2], state[3],
                                                  state[4], state[5], state[6])
    for i in range(words.size):
        w = np.int64(words[i])
        kind = w >> 12
        if kind == 0x8:
            h = w & 0xFFF
            if seen == 1 and h < high:
                loops += 1 << 24
            high = h
            seen = 1
        elif kind == 0x6:
            low = w & 0xFFF
        elif kind == 0x0:
            cur_y = w & 0x7FF
        elif kind == 0x2:
            t_out[n] = (loops + (high << 12) + low) * 1000
            x_out[n] = w & 0x7FF
            y_out[n] = cur_y
            p_out[n] = 1 if (w >> 11) & 1 else -1
            n += 1
        elif kind == 0x3:
            base_x = w & 0x7FF
            pol = 1 if (w >> 11) & 1 else -1
        elif kind == 0x4 or kind == 0x5:
            bits = 12 if kind == 0x4 else 8
            mask = w & ((1 << bits) - 1)
            for b in range(bits):
                if (mask >> b) & 1:
                    t_out[n] = (loops + (high << 12) + low) * 1000
                    x_out[n] = base_x + b
                    y_out[n] = cur_y
                    p_out[n] = pol
                    n += 1
            base_x += bits
    state[0], state[1], state[2], state[3], state[4], state[5], state[6] = (
        loops, high, low, cur_y, base_x, pol, seen)
    return n


@numba.njit(cache=True)
def _decode_evt2(words, state, t_out, x_out, y_out, p_out):
    """Events of EVT 2.0 words. ``state`` = [loops (us), time high (full, -1 none)]."""
    n = 0
    loops, high = state[0], state[1]
    for i in range(words.size):
        w = np.int64(words[i])
        kind = w >> 28
        if kind == 0x8:
            h = w & 0xFFFFFFF
            if high >= 0 and h < high:
                loops += np.int64(1) << 34
            high = h
        elif kind == 0x0 or kind == 0x1:
            t_out[n] = (loops + (max(high, 0) << 6) + ((w >> 22) & 0x3F)) * 1000
            x_out[n] = (w >> 11) & 0x7FF
            y_out[n] = w & 0x7FF
            p_out[n] = 1 if kind == 0x1 else -1
            n += 1
    state[0], state[1] = loops, high
    return n


class RawEventWriter(_StreamingWriter):
    """Stream events into a Prophesee RAW file (EVT 3.0 or EVT 2.0).

    Parameters
    ----------
    path : str or Path
        The ``.raw`` file; written as ``<path>.partial``, renamed by a successful :meth:`close`.
    sensor_size : (int, int)
        ``(width, height)`` in pixels, each at most 2048 (11-bit addresses).
    evt : {3, 2}
        The encoding.
    resume : dict, optional
        A :meth:`checkpoint` of an interrupted writer of the same path.

    Raises
    ------
    ValueError
        A sensor larger than 2048 x 2048, an unknown ``evt``, or a bad ``resume``.
    """

    def __init__(self, path: str | Path, *, sensor_size: tuple[int, int] | None, evt: int = 3,
                 resume: dict | None = None) -> None:
        self._begin(path)
        if evt not in (2, 3):
            raise ValueError(f"{self.path}: evt must be 2 or 3, got {evt!r}")
        if sensor_size is None:
            raise ValueError(f"{self.path}: a RAW file needs the sensor size (its header holds "
                             "it); expected (width, height)")
        width, height = (int(v) for v in sensor_size)
        _check_size(width, height, str(self.path))
        if width > _EVT3_MAX_COORD + 1 or height > _EVT3_MAX_COORD + 1:
            raise ValueError(f"{self.path}: sensor {width}x{height} is larger than EVT "
                             f"{evt}.0's 2048x2048; expected at most 2048 pixels a side")
        self._width, self._height = width, height
        self._evt = evt
        self._format = f"evt{evt}"
        self._state = np.array([-1, -1, -1] if evt == 3 else [-1], np.int64)
        if resume is None:
            self._handle = self.partial.open("wb")
            self._handle.write(_header(evt, width, height))
            return
        self._handle = self._reopen_bytes(resume, ("state",))
        self._state = np.array(resume["state"], np.int64)

    def write(self, events: np.ndarray) -> None:
        """Append a chunk of time-ordered :data:`EVENT_DTYPE` events (see the class)."""
        self._check_chunk(events)
        if not events.size:
            return
        step = _TIME_HIGH_3 if self._evt == 3 else _TIME_HIGH_2
        last_us = int(events["t"][-1]) // 1000
        first = int(events["t"][0]) // 1000 // step if self._state[0] < 0 else self._state[0]
        highs = last_us // step - first + 2                  # time-high words at most
        if self._evt == 3:
            out = np.empty(3 * events.size + highs, np.uint16)
            n = _encode_evt3(events["t"], events["x"], events["y"], events["p"], out,
                             self._state)
        else:
            out = np.empty(2 * events.size + highs // _HALF_WRAP_2 + 2, np.uint32)
            n = _encode_evt2(events["t"], events["x"], events["y"], events["p"], out,
                             self._state)
        self._handle.write(memoryview(out[:n].astype(out.dtype.newbyteorder("<"),
                                                      copy=False)))
        self.count += events.size
        self._last_t = int(events["t"][-1])

    def _sync(self) -> dict:
        self._handle.flush()
        os.fsync(self._handle.fileno())
        return {"size": self._handle.tell(), "state": [int(v) for v in self._state]}

    def _finish(self) -> None:
        self._handle.flush()
        os.fsync(self._handle.fileno())
        self._handle.close()

    def _abort(self) -> None:
        self._handle.close()


def evt3_writer(path: Path, *, sensor_size: tuple[int, int] | None,
                **options) -> RawEventWriter:
    """The registry's EVT 3.0 writer (:class:`RawEventWriter`)."""
    return RawEventWriter(path, sensor_size=sensor_size, evt=3, **options)


def evt2_writer(path: Path, *, sensor_size: tuple[int, int] | None,
                **options) -> RawEventWriter:
    """The registry's EVT 2.0 writer (:class:`RawEventWriter`)."""
    return RawEventWriter(path, sensor_size=sensor_size, evt=2, **options)


def _header(evt: int, width: int, height: int) -> bytes:
    lines = [f"% evt {evt}.0", f"% format EVT{evt};height={height};width={width}",
             f"% geometry {width}x{height}", "% integrator_name evfuse", "% end"]
    return ("\n".join(lines) + "\n").encode("ascii")


def _read_header(path: Path, handle) -> tuple[int, int | None, int | None, int, int]:
    """(evt, width, height, offset of the first event word, t0 in us) of a RAW file. ``t0`` is
    faery's ``% t0`` key (the time its stored times are relative to), 0 when absent."""
    keys: dict[str, str] = {}
    offset = 0
    while True:
        if handle.read(1) != b"%":
            break
        handle.seek(offset)
        line = handle.readline(_HEADER_MAX)
        if not line.endswith(b"\n"):
            raise ValueError(f"{path}: the RAW header line at byte {offset} does not end; "
                             "expected '% key value' lines ended by a newline")
        offset += len(line)
        text = line[1:].decode("ascii", "replace").strip()
        if text == "end":
            break
        key, _, value = text.partition(" ")
        keys[key] = value.strip()
    handle.seek(offset)
    fmt = keys.get("format", "")
    evt_line = keys.get("evt", "")
    if fmt.upper().startswith("EVT3") or evt_line == "3.0":
        evt = 3
    elif fmt.upper().startswith("EVT2") and not fmt.upper().startswith("EVT21") \
            or evt_line == "2.0":
        evt = 2
    else:
        found = (f"'% format {fmt}'" if fmt else f"'% evt {evt_line}'" if evt_line
                 else "no '%' header")
        raise ValueError(f"{path}: {found}; expected a Prophesee RAW header naming EVT 3.0 or "
                         "2.0 ('% evt 3.0' or '% format EVT3;...')")
    width = height = None
    match = re.search(r"width=(\d+)", fmt), re.search(r"height=(\d+)", fmt)
    if match[0] and match[1]:
        width, height = int(match[0].group(1)), int(match[1].group(1))
    elif re.fullmatch(r"\d+x\d+", keys.get("geometry", "")):
        width, height = (int(v) for v in keys["geometry"].split("x"))
    t0 = keys.get("t0", "0")
    if not t0.isdigit():
        raise ValueError(f"{path}: '% t0 {t0}'; expected a non-negative integer (microseconds)")
    return evt, width, height, offset, int(t0)


def iter_raw_chunks(path: Path, *, chunk_events: int, words: int = 1 << 18,
                    **options) -> Iterator[np.ndarray]:
    """The events of a RAW file (EVT 3.0 or 2.0, as its header says), in file order.

    Parameters
    ----------
    path : Path
        The ``.raw`` file.
    chunk_events : int
        Most events per chunk.
    words : int
        Event words decoded at a time (memory: about 13 bytes x 12 per word at most).

    Raises
    ------
    ValueError
        No RAW header or one that names neither EVT 3.0 nor 2.0, or a file whose data is not a
        whole number of words (truncated).
    """
    with open(path, "rb") as handle:
        evt, _, _, offset, t0_us = _read_header(path, handle)
        size = os.fstat(handle.fileno()).st_size - offset
        word = np.dtype("<u2" if evt == 3 else "<u4")
        if size % word.itemsize:
            raise ValueError(f"{path}: {size} bytes of EVT {evt}.0 data is not a whole number "
                             f"of {word.itemsize}-byte words; expected an untruncated file")
        decode = _decode_evt3 if evt == 3 else _decode_evt2
        state = np.array([t0_us, 0, 0, 0, 0, 1, 0] if evt == 3 else [t0_us, -1], np.int64)
        per_word = 12 if evt == 3 else 1
        while True:
            data = np.frombuffer(handle.read(words * word.itemsize), word)
            if not data.size:
                return
            buffer = np.empty(data.size * per_word, EVENT_DTYPE)    # decoded in place
            n = decode(data, state, buffer["t"], buffer["x"], buffer["y"], buffer["p"])
            events = buffer[:n]
            for begin in range(0, n, chunk_events):
                yield events[begin:begin + chunk_events]


def raw_info(path: Path) -> dict:
    """Format and sensor size from the header (times and count are not cheap: None)."""
    with open(path, "rb") as handle:
        evt, width, height, _, _ = _read_header(path, handle)
    return {"format": f"evt{evt}", "sensor_size": None if width is None else (width, height),
            "t_first_ns": None, "t_last_ns": None, "count": None}
