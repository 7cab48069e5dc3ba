"""Events in memory: :data:`EVENT_DTYPE`, building an event array (:func:`make_events`) and
checking one against the contract of CONVENTIONS.md, "Events" (:func:`check_events`), with the
checks that the writers and readers share."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["EVENT_DTYPE", "check_events", "make_events"]

EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
"""Events in memory: t int64 ns, x/y uint16 pixels, p int8 (+1 ON, -1 OFF)."""

_NS_PER_S = 1_000_000_000
_MAX_COORD = 65535


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
