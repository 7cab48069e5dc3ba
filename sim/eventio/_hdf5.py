"""DSEC ``events.h5``: :class:`H5EventWriter` (streamed, packed on close) and ``_H5Source``, the
reader that checks every value it reads against the layout and names the file when it fails.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from sim._atomic import atomic_file
from sim.eventio._events import _MAX_COORD, EVENT_DTYPE, _check_size
from sim.eventio._units import UNIT_SLACK, _unit_name
from sim.eventio._writer import _StreamingWriter

__all__ = ["MAX_EMPTY_MS", "H5EventWriter"]

MAX_EMPTY_MS = 10**7
"""Most consecutive empty milliseconds (about 2.8 hours: 80 MB of ``ms_to_idx``) an ``events.h5``
may have before its first event or between two events; see :class:`H5EventWriter`."""


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
                try:          # cut, and the chunk the next write continues must read back
                    dataset.resize((length,))
                    dataset[max(length - dataset.chunks[0], 0):length]
                except (OSError, RuntimeError) as exc:
                    raise ValueError(
                        f"{self.partial}: {dataset.name} is damaged where the checkpoint ends "
                        f"(a chunk half-written when the process was stopped: {exc}); expected "
                        "the file the checkpointed writer left: it cannot be continued, "
                        "simulate again from the start") from None
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
        offset = np.int64(0 if self.t_offset_us is None else self.t_offset_us)
        block = self.chunk_size * max(1, 2**20 // self.chunk_size)
        with atomic_file(self.partial) as packed:          # replaces the .partial file whole
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
