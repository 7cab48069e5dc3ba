"""Per-event labels: which process made each event, and which scene object its pixel sees.

Two labels per event, aligned one-to-one with the event files' order (``events.h5``,
``events.txt``, ``events_depth.txt`` hold the same events in the same order):

- ``cause`` (uint8): :data:`sim.noise.CAUSE_SIGNAL` (0), ``CAUSE_SHOT`` (1, background
  activity), ``CAUSE_LEAK`` (2) or ``CAUSE_HOT_PIXEL`` (3), set by the emulator that made the
  event (:attr:`sim.events.EventEmulator.last_causes`; the leak rule is in :mod:`sim.noise`'s
  docstring). Exact: it records which generator or which count made the event.
- ``object_id`` (int32): the index in the scene file's order (``scene.objects``) of the object
  that the event pixel's centre ray hits at the event's time (the ray whose depth the
  per-event depth gives, :mod:`sim.event_depth`), :data:`NO_OBJECT` (-1) where it hits
  nothing.

  - A static scene on a JIT variant (either sampler): each event's own ray, cast from the
    trajectory's pose at its own time (:meth:`sim.render.Renderer.object_ids_at`, one launch
    per chunk of events). Exact.
  - A dynamic scene, or ``scalar_rgb``: the ids of the pixel in the per-event depth's
    bracketing renders at ``t_a`` and ``t_b`` (:meth:`sim.render.Renderer.object_ids`), and
    the one of the render nearer in time (``t_a`` on a tie; :func:`sim.event_depth.nearer_object`).
    The bound: where the two renders agree, the label is the object the pixel sees at the
    event's time unless another object passed wholly through the ray inside the bracket (at
    most ``1 / sampling.min_rate``, 10 ms by default); where they differ, a boundary crossed
    the ray inside the bracket, and the label is wrong only for the events between that
    crossing and the bracket's midpoint (a time error at most half the bracket).

  ``tests/test_event_labels.py`` checks both against the analytic ids of a scene of known
  geometry.

Files: ``events.h5`` holds them as ``events/cause`` and ``events/object_id`` (beside
``events/depth``); a sequence written with a text event format holds them in
:data:`LABELS_TXT_NAME` (``cause object_id`` a line, the events' order). ``sequence.json``'s
``events.labels`` (:func:`event_labels_record`) names the files, the causes and the objects.
Written with the per-event depth (``simulate(motion_truth=True)``, the default).
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np

from sim.event_depth import (
    DEPTH_TXT_NAME,
    NO_OBJECT,
    _h5_columns,
    _in_window,
)
from sim.event_depth import _read_txt as _depth_rows
from sim.eventio import (
    EVENT_DTYPE,
    TextEventWriter,
    line_offsets,
    read_byte_span,
    read_text_span,
    text_offsets,
)
from sim.noise import CAUSE_HOT_PIXEL, CAUSE_LEAK, CAUSE_SHOT, CAUSE_SIGNAL, CAUSES

__all__ = ["CAUSES", "CAUSE_HOT_PIXEL", "CAUSE_LEAK", "CAUSE_SHOT", "CAUSE_SIGNAL",
           "EVENT_LABEL_DTYPE", "LABELS_TXT_NAME", "NO_OBJECT", "TextEventLabelWriter",
           "event_labels_record", "read_event_label_span", "read_event_labels"]

LABELS_TXT_NAME = "events_labels.txt"
"""The text file of per-event labels: ``cause object_id`` per line, the events' order."""
EVENT_LABEL_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1"),
                              ("cause", "u1"), ("object_id", "<i4")])
"""Events with their labels, as :func:`read_event_labels` returns them: EVENT_DTYPE's fields,
then ``cause`` (uint8, :data:`CAUSES`) and ``object_id`` (int32, :data:`NO_OBJECT` = none)."""
_LABEL_COLUMNS = np.dtype([("cause", "u1"), ("object_id", "<i4")])


def event_labels_record(formats: tuple[str, ...], object_names: list[str],
                        own_rays: bool = True) -> dict | None:
    """``sequence.json``'s ``events.labels``: where the labels are, the causes, the objects
    and how their ids were found (``own_rays``: each event's own ray, else the bracketing
    renders'); None when no event format holds them (none of ``h5``, ``txt``,
    ``depth-txt``)."""
    files = []
    if "h5" in formats:
        files.append("events.h5 events/cause, events/object_id")
    if "txt" in formats or "depth-txt" in formats:
        files.append(LABELS_TXT_NAME)
    if not files:
        return None
    return {"files": files,
            "causes": {str(code): name for code, name in CAUSES.items()},
            "leak_rule": "a crossing beyond the count against the pixel's leak-free reference "
                         "(its reference less the interval's leak drift) on its piece of the "
                         "interval between two samples",
            "objects": {str(NO_OBJECT): None,
                        **{str(i): name for i, name in enumerate(object_names)}},
            "object_rule": ("the object hit by the event pixel's centre ray at the event's "
                            "own time (exact)" if own_rays else
                            "the object hit by the pixel-centre ray in the depth render nearer "
                            "in time of the two that bracket the event (the per-event depth's)")}


class TextEventLabelWriter(TextEventWriter):
    """Stream per-event labels into :data:`LABELS_TXT_NAME`: ``cause object_id`` per line.

    One line per event of the chunks written, in their order (the events themselves are not
    written: they are in ``events.txt`` / ``events.h5``, in the same order). Checkpointed and
    resumed as :class:`~sim.eventio.TextEventWriter`.
    """

    def write(self, events: np.ndarray, cause: np.ndarray | None = None,
              object_id: np.ndarray | None = None) -> None:
        """Append the labels of a chunk of events (arrays as long as ``events``).

        Raises
        ------
        ValueError
            As :meth:`TextEventWriter.write`, or a label array is missing or of another
            length.
        """
        self._check_chunk(events)
        n = len(events)
        if cause is None or object_id is None or np.shape(cause) != (n,) \
                or np.shape(object_id) != (n,):
            raise ValueError(f"{self.path}: cause and object_id must be arrays of one value per "
                             f"event ({n})")
        if not n:
            return
        text = "".join(f"{c} {o}\n" for c, o in zip(np.asarray(cause, np.uint8).tolist(),
                                                    np.asarray(object_id, np.int32).tolist(),
                                                    strict=True))
        self._handle.write(text.encode("ascii"))
        self.count += n
        self._last_t = int(events["t"][-1])


def _read_h5(path: Path, t0_ns: int | None, t1_ns: int | None) -> np.ndarray | None:
    found = _h5_columns(path, t0_ns, t1_ns, {"cause": "cause", "object_id": "object_id"},
                        EVENT_LABEL_DTYPE)
    if found is None:
        return None
    out, start = found
    _check_range(out["cause"], out["object_id"], start, path)
    return out


def _read_txt(path: Path, labels: Path, t0_ns: int | None, t1_ns: int | None) -> np.ndarray:
    """The events of ``[t0_ns, t1_ns)`` of an event text file with their labels, streamed: the
    window's events and label lines are read, the rest of both files only scanned (one pass
    each, to find the window and to check that the label file has one line per event)."""
    if path.name == DEPTH_TXT_NAME:
        events, first, total = _depth_rows(path, t0_ns, t1_ns)
    else:
        end = np.iinfo(np.int64).max                  # after every event (t < 2**63 - 1)
        low = 0 if t0_ns is None else max(int(t0_ns), 0)
        high = end if t1_ns is None else max(int(t1_ns), low)
        offsets, lines, counts = text_offsets(path, np.array([low, high, end], np.int64))
        events = read_text_span(path, int(offsets[0]), int(offsets[1]), int(lines[0]))
        first, total = int(counts[0]), int(counts[2])
    at, numbers, found = line_offsets(labels, np.array([first, first + len(events)]))
    if found != total:
        raise ValueError(f"{labels}: {found} lines for the {total} events of {path}; expected "
                         "one line per event")
    values = read_event_label_span(labels, int(at[0]), int(at[1]), int(numbers[0]), first)
    if len(values) != len(events):             # a line the parser took but not as data
        raise ValueError(f"{labels}: {len(values)} label lines from line {int(numbers[0])} for "
                         f"{len(events)} events; expected one line per event")
    out = np.empty(len(events), EVENT_LABEL_DTYPE)
    for name in EVENT_DTYPE.names:
        out[name] = events[name]
    out["cause"], out["object_id"] = values["cause"], values["object_id"]
    return out


def read_event_label_span(path: str | Path, start: int, stop: int, first_line: int = 1,
                          first_event: int = 0) -> np.ndarray:
    """The labels of bytes ``[start, stop)`` of a :data:`LABELS_TXT_NAME` (whole lines: offsets
    from :func:`sim.eventio.line_offsets`), without the rest of the file.

    Parameters
    ----------
    path : str or Path
        A :data:`LABELS_TXT_NAME`.
    start, stop : int, bytes
        ``0 <= start <= stop``, each at the start of a line or the file's end.
    first_line : int
        The 1-based line number at ``start``, for messages.
    first_event : int
        The index of the event of the span's first line, for messages.

    Returns
    -------
    (M,) structured ndarray
        Fields ``cause`` (uint8, :data:`CAUSES`) and ``object_id`` (int32, :data:`NO_OBJECT`
        = none), one row per ``cause object_id`` line (blank and ``#`` lines skipped).

    Raises
    ------
    ValueError
        A bad range, a line that is not two integers, or a cause or id out of range (the
        message names the file, and the line or event).
    """
    path = Path(path)
    block = read_byte_span(path, start, stop)
    out = np.empty(0, _LABEL_COLUMNS)
    if block.strip():
        try:
            with warnings.catch_warnings():       # a span of comments only holds no data
                warnings.filterwarnings("ignore", "loadtxt: input contained no data")
                values = np.loadtxt(io.StringIO(block.decode("ascii")), dtype=np.int64,
                                    ndmin=2, comments="#")
        except (ValueError, UnicodeDecodeError) as error:
            raise ValueError(f"{path}: expected 'cause object_id' integer lines, from line "
                             f"{first_line} ({error})") from None
        if values.size and values.shape[1] != 2:
            raise ValueError(f"{path}: expected 2 integers a line ('cause object_id'), got "
                             f"{values.shape[1]}, from line {first_line}")
        values = values.reshape(-1, 2)
        _check_range(values[:, 0], values[:, 1], first_event, path)
        out = np.empty(len(values), _LABEL_COLUMNS)
        out["cause"], out["object_id"] = values[:, 0], values[:, 1]
    return out


def _check_range(cause: np.ndarray, object_id: np.ndarray, start: int, path: Path) -> None:
    """Refuse a cause outside :data:`CAUSES` or an object id below :data:`NO_OBJECT` (or past
    int32), naming event ``start + i``."""
    bad = np.flatnonzero((cause < 0) | (cause > max(CAUSES)) | (object_id < NO_OBJECT)
                         | (object_id > np.iinfo(np.int32).max))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{path}: event {start + i}: cause {int(cause[i])}, object_id "
                         f"{int(object_id[i])}; expected a cause in {sorted(CAUSES)} and an "
                         f"object_id >= {NO_OBJECT}")


def read_event_labels(path: str | Path, t0_ns: int | None = None, t1_ns: int | None = None
                      ) -> np.ndarray | None:
    """Events in ``[t0_ns, t1_ns)`` with their labels, from ``events.h5`` or an event text
    file and the :data:`LABELS_TXT_NAME` beside it.

    Parameters
    ----------
    path : str or Path
        An ``events.h5`` (with ``events/cause``), or an ``events.txt`` / ``events_depth.txt``
        whose folder holds :data:`LABELS_TXT_NAME`.
    t0_ns, t1_ns : int, optional
        The window, nanoseconds on the event clock (default: everything).

    Returns
    -------
    (N,) EVENT_LABEL_DTYPE ndarray or None
        Sorted by t, in the files' order; None for an ``events.h5`` without labels, or a text
        file without :data:`LABELS_TXT_NAME` beside it (a real recording).

    Raises
    ------
    ValueError
        A file cannot be read, the label file is not one line per event, or a cause or id is
        out of range (the message names the file).
    """
    path = Path(path)
    if path.suffix == ".h5":
        out = _read_h5(path, t0_ns, t1_ns)
    elif (path.parent / LABELS_TXT_NAME).is_file():
        return _read_txt(path, path.parent / LABELS_TXT_NAME, t0_ns, t1_ns)
    else:
        return None
    return None if out is None else _in_window(out, t0_ns, t1_ns)
