"""Per-event depth: the z-depth of the scene at each event's pixel and time.

Both event samplers render the exact z-depth of the whole image (one ray per pixel centre, no
shading) at the times that bracket every chunk of events they emit: the per-pixel sampler at
each block's ends (:func:`sim.pixel_sampling.pixel_blocks`; every event of a block lies in
``[t_b, t_e]``), the frame sampler at each accepted sample (:func:`sim.sampling.adaptive_samples`;
the events between two samples lie between their times). Those renders are kept
(:class:`RecentDepth`), so annotating costs one extra depth render only where the sampler made
none (the end of the run, the first half of an interval kept after a step, a resume's first
sample) and the interpolation itself.

The depth of an event at pixel (x, y) and time t, between the bracketing renders ``z_a`` at
``t_a`` and ``z_b`` at ``t_b`` of that pixel (:func:`interpolate_depth`):

- both > 0 and ``|z_b - z_a| <= EDGE_JUMP * min(z_a, z_b)``: linear in time,
  ``z = z_a + (t - t_a) / (t_b - t_a) (z_b - z_a)``, flag 0;
- both > 0 and they differ by more: a depth edge crossed the pixel between the renders; the
  depth of the sample nearer in time (``t_a`` on a tie), flag :data:`FLAG_EDGE`;
- one of them 0 (a surface appeared or left the pixel): the nearer sample's depth, which may
  be 0, flag :data:`FLAG_NO_SURFACE`;
- both 0: 0 (no surface), flag 0.

Interpolated in depth, not inverse depth: the z-depth seen by a fixed pixel on a plane is
``d / (n . r)`` (plane ``n . X = d`` in the camera frame, ``r`` the pixel's ray), affine in the
camera's position, so linear in time for a translation at constant velocity; inverse depth is
not. Under rotation neither is linear, and over one bracket (at most ``1 / min_rate``, 10 ms by
default) both are smooth to second order.

The bound. Where the pixel sees one smooth surface over ``[t_a, t_b]``, the error of linear
interpolation is ``|z(t) - z_lin(t)| <= (t - t_a)(t_b - t) / 2 * max |z''| <= dt^2 / 8 *
max |z''|`` with ``dt = t_b - t_a <= 1 / min_rate``. Across a depth edge too small to flag,
both ``z(t)`` and the interpolated value lie between the two surfaces' depths (for a depth that
is monotone over the bracket), so the error is at most ``|z_b - z_a| <= EDGE_JUMP *
min(z_a, z_b)`` plus the term above. An edge that enters a pixel and leaves it again within one
bracket (a hand-held camera reversing at an object's border) is seen by neither render: such an
event gets the surface behind it, unflagged and outside the bound; in the test's hand-held
scene 1 of 200 sampled events. ``tests/test_event_depth.py`` checks the bounds against a direct
depth render at each event's own time, and counts those crossings.
"""

from __future__ import annotations

import io
import math
import time
import warnings
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import numpy as np

from sim.eventio import EVENT_DTYPE, H5EventWriter, TextEventWriter, read_byte_span
from sim.profile import stage as profile_stage

__all__ = ["DEPTH_TXT", "DEPTH_TXT_NAME", "EDGE_JUMP", "EVENT_DEPTH_DTYPE", "FLAG_EDGE",
           "FLAG_NO_SURFACE", "LABELS_TXT", "NO_OBJECT", "EventDepth", "EventOutputs",
           "H5EventDepthWriter", "RecentDepth", "TextEventDepthWriter", "event_depth_record",
           "event_file_name", "interpolate_depth", "nearer_object", "read_event_depth",
           "read_event_depth_span"]

EDGE_JUMP = 0.05
"""Relative change between the two bracketing depth renders of a pixel above which a depth edge
crossed it (the event is flagged :data:`FLAG_EDGE`). A surface seen by a pixel changes its depth
by well under 5 % in 10 ms at hand-held speeds (1 m/s at 1 m: 1 %)."""
FLAG_EDGE = 1
"""``events/depth_flag``: the two renders differ by more than :data:`EDGE_JUMP` (a depth edge)."""
FLAG_NO_SURFACE = 2
"""``events/depth_flag``: one of the two renders sees no surface at the pixel (depth 0)."""
NO_OBJECT = -1
"""``object_id`` of an event whose pixel sees no object (:mod:`sim.event_labels`)."""
DEPTH_TXT = "depth-txt"
"""The event format (``simulate(event_formats=...)``, ``--event-format``) of events_depth.txt."""
LABELS_TXT = "labels-txt"
"""The event stage's writer key (and checkpoint entry) of
:data:`sim.event_labels.LABELS_TXT_NAME`; not an event format of its own."""
DEPTH_TXT_NAME = "events_depth.txt"
"""The text file of per-event depth: ``t[s] x y p depth[m] flag`` per line."""

EVENT_DEPTH_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1"),
                              ("depth", "<f4"), ("flag", "u1")])
"""Events with their depth, as :func:`read_event_depth` returns them: EVENT_DTYPE's fields, then
``depth`` (float32 m, 0 = none) and ``flag`` (uint8, 0, :data:`FLAG_EDGE` or
:data:`FLAG_NO_SURFACE`)."""


def event_file_name(fmt: str) -> str:
    """The file an event format writes: ``events.h5``, ``events.txt`` or ``events_depth.txt``."""
    return DEPTH_TXT_NAME if fmt == DEPTH_TXT else f"events.{fmt}"


def event_depth_record(formats: tuple[str, ...]) -> dict | None:
    """``sequence.json``'s ``events.depth``: where per-event depth is and how it was made (None
    when no format holds it)."""
    files = [name for fmt, name in (("h5", "events.h5 events/depth, events/depth_flag"),
                                    (DEPTH_TXT, DEPTH_TXT_NAME)) if fmt in formats]
    if not files:
        return None
    return {"files": files, "kind": "z", "units": "m, 0 = no surface",
            "interpolation": "linear in time between the exact depth renders that bracket the "
                             "event (block ends / accepted samples)",
            "edge_jump": EDGE_JUMP,
            "flags": {"0": "interpolated (or no surface at either render)",
                      str(FLAG_EDGE): f"the two renders differ by more than {EDGE_JUMP:g} "
                                      "relative: the depth of the render nearer in time",
                      str(FLAG_NO_SURFACE): "one render sees no surface: the depth of the render "
                                            "nearer in time (may be 0)"}}


def interpolate_depth(depth_a: np.ndarray, depth_b: np.ndarray, weight: np.ndarray,
                      jump: float = EDGE_JUMP) -> tuple[np.ndarray, np.ndarray]:
    """Depth between two renders of the same pixels, with the flag of an edge between them.

    Parameters
    ----------
    depth_a, depth_b : (N,) float32 ndarray, metres, 0 where nothing is seen
        Each event's pixel in the renders at ``t_a`` and ``t_b``.
    weight : (N,) float64 ndarray
        ``(t - t_a) / (t_b - t_a)`` of each event, in [0, 1].
    jump : float
        Relative difference above which an edge crossed the pixel (default :data:`EDGE_JUMP`).

    Returns
    -------
    depth : (N,) float32 ndarray, metres
        Interpolated where unflagged, else the nearer render's depth (``t_a`` on a tie).
    flag : (N,) uint8 ndarray
        0, :data:`FLAG_EDGE` or :data:`FLAG_NO_SURFACE` (see the module docstring).
    """
    a = np.asarray(depth_a, np.float64)
    b = np.asarray(depth_b, np.float64)
    w = np.asarray(weight, np.float64)
    nearer = np.where(w <= 0.5, a, b)
    seen_a, seen_b = a > 0, b > 0
    edge = seen_a & seen_b & (np.abs(b - a) > jump * np.minimum(a, b))
    none = seen_a != seen_b
    flag = np.where(edge, FLAG_EDGE, np.where(none, FLAG_NO_SURFACE, 0)).astype(np.uint8)
    depth = np.where(flag > 0, nearer, a + w * (b - a))
    return depth.astype(np.float32), flag


def nearer_object(ids_a: np.ndarray, ids_b: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Object id of events from the renders that bracket them: the nearer one's.

    Parameters
    ----------
    ids_a, ids_b : (N,) integer ndarray
        Each event pixel's :meth:`sim.render.Renderer.object_ids` (0 = nothing, ``i`` =
        ``scene.objects[i - 1]``) at the bracket's start ``t_a`` and end ``t_b``.
    weight : (N,) float64 ndarray
        ``(t - t_a) / (t_b - t_a)`` of each event, in [0, 1].

    Returns
    -------
    (N,) int32 ndarray
        The index into ``scene.objects`` seen at ``t_a`` where ``weight <= 0.5``, else at
        ``t_b``; :data:`NO_OBJECT` where nothing is seen.
    """
    ids = np.where(np.asarray(weight) <= 0.5, ids_a, ids_b)
    return ids.astype(np.int32) - 1


class RecentDepth:
    """A depth render function that keeps its last renders (renders are deterministic in time).

    The event stage and the sampler that drives it ask for the depth at the same times; this
    renders it once. :meth:`many` renders several times at once (the per-pixel sampler's
    block starts, ahead of their blocks) and keeps them until they are asked for. The arrays
    returned are read-only (they are shared).

    Parameters
    ----------
    render : callable
        ``render(t) -> (H, W) float32 ndarray``, z-depth in metres (``Renderer.depth``), or
        another per-pixel render of time (``Renderer.object_ids``, with its ``dtype``).
    dtype : numpy dtype
        Of the kept render (default float32).
    render_many : callable, optional
        ``render_many(times) -> (K, H, W)``, the same maps as ``render`` at each time
        (``Renderer.depth_many``); default ``render`` a time.
    """

    KEEP = 20
    """Renders kept at most: the last asked for and those :meth:`many` made ahead (the
    per-pixel sampler asks for 16 at a time)."""

    def __init__(self, render: Callable[[float], np.ndarray], dtype=np.float32,
                 render_many: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self._render, self._dtype = render, np.dtype(dtype)
        self._render_many = render_many
        self._kept: dict[float, np.ndarray] = {}
        self.renders = 0
        """Depth renders made (maps)."""

    def _keep(self, t: float, depth) -> np.ndarray:
        depth = np.array(depth, dtype=self._dtype)
        depth.flags.writeable = False
        self._kept[t] = depth
        while len(self._kept) > self.KEEP:
            del self._kept[next(iter(self._kept))]           # the oldest first
        self.renders += 1
        return depth

    def __call__(self, t: float) -> np.ndarray:
        if t not in self._kept:
            return self._keep(t, self._render(t))
        return self._kept[t]

    def many(self, times) -> list[np.ndarray]:
        """The maps at ``times`` (seconds), those not kept rendered together."""
        times = [float(t) for t in np.asarray(times, dtype=np.float64).reshape(-1)]
        missing = list(dict.fromkeys(t for t in times if t not in self._kept))
        if len(missing) > 1 and self._render_many is not None:
            for t, depth in zip(missing, self._render_many(np.array(missing)), strict=True):
                self._keep(t, depth)
        else:
            for t in missing:
                self._keep(t, self._render(t))
        return [self._kept[t] for t in times]


class EventDepth:
    """Per-event depth of the chunks an event sampler emits, in time order.

    Parameters
    ----------
    depth : callable
        ``depth(t) -> (H, W)`` z-depth in metres at time ``t`` seconds (a :class:`RecentDepth`
        shared with the sampler, so that no time is rendered twice).
    t : float, seconds
        Where the events start: the start of the run, or the sample a resumed run goes on from.
    jump : float
        See :func:`interpolate_depth`.
    objects : callable, optional
        ``objects(t) -> (H, W)`` ids of the objects the pixel-centre rays hit (the rays of
        ``depth``; :meth:`sim.render.Renderer.object_ids`, 0 = none, ``i`` =
        ``scene.objects[i - 1]``): :meth:`annotate` then labels each event with its object
        (:func:`nearer_object`) in :attr:`object_id`.
    objects_at : callable, optional
        ``objects_at(pixels, times) -> (N,)`` the same ids of flat pixels each at its own time
        in seconds (:meth:`sim.render.Renderer.object_ids_at`, static scenes): each event's
        id is then its own pixel-centre ray's at its own time, exactly (``objects`` unused).

    Attributes
    ----------
    object_id : (N,) int32 ndarray or None
        With ``objects``: the object id of each event of the last :meth:`annotate` call (-1:
        none); else None.
    """

    def __init__(self, depth: Callable[[float], np.ndarray], t: float,
                 jump: float = EDGE_JUMP,
                 objects: Callable[[float], np.ndarray] | None = None,
                 objects_at: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
                 ) -> None:
        self._depth, self._jump, self._objects = depth, jump, objects
        self._objects_at = objects_at
        self._t = float(t)
        self._at_t: np.ndarray | None = None        # rendered lazily (the sampler may first)
        self._ids_at_t: np.ndarray | None = None
        self.object_id: np.ndarray | None = None

    def annotate(self, events: np.ndarray | None, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Depth and flag (and, with ``objects``, :attr:`object_id`) of the events between
        the previous call's time and ``t``.

        Call it at every bracketing time (every block end or accepted sample), with or without
        events: ``t`` becomes the start of the next bracket.

        Parameters
        ----------
        events : (N,) EVENT_DTYPE ndarray or None
            Events with times (ns, on the simulation's clock) in the bracket.
        t : float, seconds
            The bracket's end (not before the previous one).

        Returns
        -------
        depth : (N,) float32 ndarray, metres, 0 where no surface
        flag : (N,) uint8 ndarray
        """
        t = float(t)
        if t < self._t:
            raise ValueError(f"per-event depth: bracket end t = {t} s comes before its start "
                             f"{self._t} s; expected brackets in time order")
        events = np.zeros(0, EVENT_DTYPE) if events is None else events
        if len(events) and self._at_t is None:
            self._at_t = self._depth(self._t)
        at_end = self._depth(t)
        ids_end = None
        if self._objects is not None:
            if len(events) and self._ids_at_t is None:
                self._ids_at_t = self._objects(self._t)
            ids_end = self._objects(t)
        labelled = self._objects is not None or self._objects_at is not None
        self.object_id = np.zeros(0, np.int32) if labelled else None
        if len(events):
            t_a_ns, t_b_ns = round(self._t * 1e9), round(t * 1e9)
            span = max(t_b_ns - t_a_ns, 1)
            weight = np.clip((events["t"] - t_a_ns) / span, 0.0, 1.0)
            y, x = events["y"].astype(np.intp), events["x"].astype(np.intp)
            result = interpolate_depth(self._at_t[y, x], at_end[y, x], weight, self._jump)
            if self._objects_at is not None:          # each event's own ray, at its time
                # (seconds within the bracket: a time rounded to the ns may lie past its end)
                seconds = np.clip(events["t"] / 1e9, self._t, t)
                cast = self._objects_at(y * at_end.shape[1] + x, seconds)
                self.object_id = np.asarray(cast, np.int32) - 1
            elif ids_end is not None:
                self.object_id = nearer_object(self._ids_at_t[y, x], ids_end[y, x], weight)
        else:
            result = np.zeros(0, np.float32), np.zeros(0, np.uint8)
        self._t, self._at_t, self._ids_at_t = t, at_end, ids_end
        return result


class H5EventDepthWriter(H5EventWriter):
    """:class:`~sim.eventio.H5EventWriter` with two (four, with ``labels``) more per-event
    datasets.

    - ``events/depth``: float32 z-depth in metres at the event's pixel and time, 0 = none;
    - ``events/depth_flag``: uint8, 0, :data:`FLAG_EDGE` or :data:`FLAG_NO_SURFACE`;
    - with ``labels``: ``events/cause`` (uint8) and ``events/object_id`` (int32), the
      per-event labels of :mod:`sim.event_labels`.

    Chunked, compressed, checkpointed, resumed and packed as the other ``events/`` datasets (the
    DSEC readers ignore them). :meth:`write` takes each chunk's columns beside it.
    """

    _DEPTH_COLUMNS = (("depth", np.float32), ("depth_flag", np.uint8))
    _LABEL_COLUMNS = (("cause", np.uint8), ("object_id", np.int32))

    def __init__(self, path: str | Path, width: int, height: int, chunk_size: int = 2**16,
                 t_offset_us: int | None = None, *, resume: dict | None = None,
                 labels: bool = False) -> None:
        self._columns = self._DEPTH_COLUMNS + (self._LABEL_COLUMNS if labels else ())
        self._EVENT_FIELDS = (*H5EventWriter._EVENT_FIELDS, *self._columns)
        self._pending_columns: list[tuple[np.ndarray, ...]] = []
        super().__init__(path, width, height, chunk_size, t_offset_us, resume=resume)
        if resume is None:
            return
        try:
            missing = [name for name, _ in self._columns if f"events/{name}" not in self._file]
            if missing:
                raise ValueError(f"{self.partial}: no dataset events/{', events/'.join(missing)}; "
                                 "expected the file a per-event depth writer left")
            for name, _ in self._columns:
                dataset = self._file[f"events/{name}"]
                if dataset.shape[0] < self._stored:
                    raise self._too_short(f"events in {dataset.name}", dataset.shape[0],
                                          self._stored)
                dataset.resize((self._stored,))
                self._datasets[name] = dataset
        except BaseException:
            self._file.close()
            raise

    def write(self, events: np.ndarray, depth: np.ndarray | None = None,
              depth_flag: np.ndarray | None = None, **labels: np.ndarray) -> None:
        """Append a chunk of events with their depth and flag (and, for a writer with
        ``labels``, ``cause`` and ``object_id``), arrays as long as ``events``.

        Raises
        ------
        ValueError
            As :meth:`H5EventWriter.write`, or a column is missing, unknown or of another
            length.
        """
        n = len(events)
        given = {"depth": depth, "depth_flag": depth_flag, **labels}
        unknown = set(given) - {name for name, _ in self._columns}
        if unknown:
            raise ValueError(f"{self.path}: no per-event column {', '.join(sorted(unknown))}; "
                             f"this writer holds {', '.join(n for n, _ in self._columns)}")
        for name, _ in self._columns:
            column = given.get(name)
            if column is None or np.shape(column) != (n,):
                got = None if column is None else np.shape(column)
                raise ValueError(f"{self.path}: {name} must be an array of one value per event "
                                 f"({n}), got {got}")
        if not n:
            return super().write(events)
        self._pending_columns.append(tuple(np.asarray(given[name], dtype)
                                           for name, dtype in self._columns))
        try:
            super().write(events)
        except BaseException:
            self._pending_columns.pop()
            raise

    def _flush(self) -> None:
        if not self._pending:
            return
        columns = [np.concatenate(parts) for parts in zip(*self._pending_columns, strict=True)]
        self._pending_columns = []
        super()._flush()
        for (name, _), values in zip(self._columns, columns, strict=True):
            self._append(self._datasets[name], values)


class TextEventDepthWriter(TextEventWriter):
    """Stream events with their depth into ``events_depth.txt``: ``t[s] x y p depth flag``.

    t in seconds with 9 decimals and p in {0, 1}, as ``events.txt`` (ECD); depth in metres with
    9 significant digits (a float32 reads back exactly), 0 = none; flag as ``events/depth_flag``.
    Checkpointed and resumed as :class:`~sim.eventio.TextEventWriter`.
    """

    def write(self, events: np.ndarray, depth: np.ndarray | None = None,
              depth_flag: np.ndarray | None = None) -> None:
        """Append a chunk of events with their depth and flag (arrays as long as ``events``)."""
        self._check_chunk(events)
        n = len(events)
        if depth is None or depth_flag is None or np.shape(depth) != (n,) \
                or np.shape(depth_flag) != (n,):
            raise ValueError(f"{self.path}: depth and depth_flag must be arrays of one value per "
                             f"event ({n})")
        if not n:
            return
        seconds, nanos = np.divmod(events["t"], 10**9)
        text = "".join(f"{s}.{f:09d} {x} {y} {1 if p > 0 else 0} {d:.9g} {g}\n" for s, f, x, y,
                       p, d, g in zip(seconds.tolist(), nanos.tolist(), events["x"].tolist(),
                                      events["y"].tolist(), events["p"].tolist(),
                                      np.asarray(depth, np.float32).tolist(),
                                      np.asarray(depth_flag, np.uint8).tolist(), strict=True))
        self._handle.write(text.encode("ascii"))
        self.count += n
        self._last_t = int(events["t"][-1])


class EventOutputs:
    """The event stage's writers, with per-event depth (and labels) for those that hold them.

    Parameters
    ----------
    writers : dict
        Format (``h5``, ``txt``, :data:`DEPTH_TXT`, :data:`LABELS_TXT`) -> writer; the ``h5``
        and :data:`DEPTH_TXT` ones take the depth columns (:class:`H5EventDepthWriter`,
        :class:`TextEventDepthWriter`), the ``h5`` one (made with ``labels``) and the
        :data:`LABELS_TXT` one (:class:`sim.event_labels.TextEventLabelWriter`) the labels,
        maybe behind a clock offset that passes them on.
    depth : EventDepth or None
        Annotates the chunks (None when no writer holds depth).
    timings : dict, optional
        ``timings["event_depth"]`` accumulates the seconds spent on depth and object ids (the
        renders included, those the sampler then reuses too), taken out of
        ``timings["event_write"]`` (the caller times the whole :meth:`write` as writing).
    labels : bool
        Write each event's ``cause`` (given to :meth:`write`) and ``object_id`` (from
        ``depth``, made with ``objects``).
    """

    def __init__(self, writers: Mapping, depth: EventDepth | None,
                 timings: dict | None = None, labels: bool = False) -> None:
        if labels and depth is None:
            raise ValueError("per-event labels need the per-event depth's renders (an "
                             "EventDepth with objects)")
        self.writers = dict(writers)
        self._depth = depth
        self._timings = timings
        self._labels = labels
        self._held: tuple[np.ndarray | None, np.ndarray | None] | None = None

    def write(self, events: np.ndarray | None, t: float, pending: bool = False,
              causes: np.ndarray | None = None) -> None:
        """Write a chunk (None or empty: nothing) whose events end the bracket at ``t`` s.

        ``pending``: more of the same sampling interval follows at once (a frame sample with
        ``tail_pending``, after which no checkpoint is taken): the chunk is held and written
        with the next one, bracketed by the depth at the interval's ends, so that the
        interval's midpoint costs no depth render. ``causes``: each event's cause (uint8,
        :data:`sim.noise.CAUSES`; needed with ``labels``).
        """
        if self._labels and events is not None and np.shape(causes) != (len(events),):
            raise ValueError(f"per-event labels: {np.shape(causes)} causes for {len(events)} "
                             "events; expected one cause per event")
        if self._held is not None:
            held, held_causes = self._held
            if events is None:
                events, causes = held, held_causes
            elif held is not None:
                events = np.concatenate([held, events])
                if self._labels:
                    causes = np.concatenate([held_causes, causes])
        self._held = None
        if pending:
            self._held = (events, causes)
            return
        columns = {}
        if self._depth is not None:
            tick = time.perf_counter()
            with profile_stage("event_depth"):
                depth, flag = self._depth.annotate(events, t)
            columns = {"depth": depth, "depth_flag": flag, "object_id": self._depth.object_id}
            if self._timings is not None:           # counted here, not in event_write
                seconds = time.perf_counter() - tick
                self._timings["event_depth"] = self._timings.get("event_depth", 0.0) + seconds
                self._timings["event_write"] = self._timings.get("event_write", 0.0) - seconds
        if events is None or not len(events):
            return
        labels = {}
        if self._labels:
            labels = {"cause": np.asarray(causes, np.uint8), "object_id": columns["object_id"]}
        depth = {name: columns[name] for name in ("depth", "depth_flag") if name in columns}
        for fmt, writer in self.writers.items():
            if fmt == "h5":
                writer.write(events, **depth, **labels)
            elif fmt == DEPTH_TXT:
                writer.write(events, **depth)
            elif fmt == LABELS_TXT:
                writer.write(events, **labels)
            else:
                writer.write(events)


# --- reading -----------------------------------------------------------------------------------

def _h5_columns(path: Path, t0_ns: int | None, t1_ns: int | None, columns: dict[str, str],
                dtype: np.dtype) -> tuple[np.ndarray, int] | None:
    """Events of ``[t0_ns, t1_ns)`` of an ``events.h5`` with per-event datasets beside them
    (field -> dataset under ``events/``), as ``dtype`` (EVENT_DTYPE's fields, then those), and
    the index of the first; None when a dataset is missing. Shared by the per-event depth and
    labels (:mod:`sim.event_labels`)."""
    from sim.eventio._hdf5 import _H5Source, _reading

    source = _H5Source(path)
    try:
        if any(f"events/{name}" not in source.file for name in columns.values()):
            return None
        start = 0 if t0_ns is None else source.index_at(t0_ns)
        stop = source.size if t1_ns is None else source.index_before(t1_ns)
        events = source.read(start, max(start, stop))
        out = np.empty(len(events), dtype)
        for name in EVENT_DTYPE.names:
            out[name] = events[name]
        with _reading(path):
            for field, name in columns.items():
                values = source.file[f"events/{name}"][start:start + len(events)]
                if len(values) != len(events):
                    raise ValueError(f"{path}: events/{name} holds {len(values)} values from "
                                     f"event {start}; expected one per event ({len(events)})")
                out[field] = values
    finally:
        source.close()
    return out, start


def _in_window(out: np.ndarray, t0_ns: int | None, t1_ns: int | None) -> np.ndarray:
    """The events of ``out`` with ``t0_ns <= t < t1_ns`` (either bound None: open)."""
    keep = np.ones(len(out), bool)
    if t0_ns is not None:
        keep &= out["t"] >= t0_ns
    if t1_ns is not None:
        keep &= out["t"] < t1_ns
    return out[keep]


def _read_h5(path: Path, t0_ns: int | None, t1_ns: int | None) -> np.ndarray | None:
    found = _h5_columns(path, t0_ns, t1_ns, {"depth": "depth", "flag": "depth_flag"},
                        EVENT_DEPTH_DTYPE)
    if found is None:
        return None
    out, start = found
    bad = np.flatnonzero(~np.isfinite(out["depth"]) | (out["depth"] < 0))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{path}: event {start + i}: events/depth = {float(out['depth'][i])!r}; "
                         "expected a finite depth in metres >= 0 (0 = none)")
    return out


_TXT_FIELDS = np.dtype([("t", "S32"), ("x", "<u2"), ("y", "<u2"), ("p", "S2"), ("depth", "<f4"),
                        ("flag", "u1")])
"""An ``events_depth.txt`` line's fields as the fast parser reads them (t and p as text, checked
and converted exactly by :func:`_exact_times`)."""
_MAX_SECONDS = (np.iinfo(np.int64).max - (10**9 - 1)) // 10**9


def _exact_times(text: np.ndarray) -> np.ndarray | None:
    """Times ``S+[.D{0,9}]`` (seconds, up to 9 decimals, below 2**63 ns) of an S32 array to
    int64 nanoseconds, exactly (integer arithmetic, a column of bytes at a time); None when
    any is of another form (the line-by-line parser then decides)."""
    raw = np.ascontiguousarray(text).view(np.uint8).reshape(len(text), text.dtype.itemsize)
    length = np.count_nonzero(raw, axis=1)
    is_dot = raw == 46
    dots = np.count_nonzero(is_dot, axis=1)
    point = np.where(dots == 1, np.argmax(is_dot, axis=1), length)
    decimals = np.clip(length - point - 1, 0, None)
    ok = (dots <= 1) & (point >= 1) & (point <= 10) & (decimals <= 9) \
        & (length < raw.shape[1])
    if not ok.all():
        return None
    whole = np.zeros(len(text), np.int64)
    frac = np.zeros(len(text), np.int64)
    for column in range(int(length.max(initial=0))):     # at most 21 (10 + '.' + 9)
        byte = raw[:, column]
        digit = (byte - 48).astype(np.int64)
        in_whole, in_frac = column < point, (column > point) & (column < length)
        if not ((digit <= 9) | ~(in_whole | in_frac)).all():   # byte - 48 wraps below '0'
            return None
        whole[in_whole] = whole[in_whole] * 10 + digit[in_whole]
        frac[in_frac] = frac[in_frac] * 10 + digit[in_frac]
    if (whole > _MAX_SECONDS).any():
        return None
    return whole * 10**9 + frac * 10 ** (9 - decimals)


def _parse_block(path: Path, block: bytes, first_line: int) -> np.ndarray:
    """The rows of whole lines of an ``events_depth.txt`` (blank and ``#`` lines skipped): a
    compiled reading (:func:`numpy.loadtxt`, times converted exactly by :func:`_exact_times`)
    where every line is ``t x y p depth flag`` as the writer writes it, else line by line in
    Python (:func:`_parse_lines`), which accepts the same lines and names the first bad one."""
    if not block.strip():
        return np.empty(0, EVENT_DEPTH_DTYPE)
    if b"#" not in block:                       # a comment only at a line's start: line by line
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # a deprecated reading too: line by line
                fields = np.loadtxt(io.BytesIO(block), dtype=_TXT_FIELDS, ndmin=1,
                                    encoding="ascii")
        except (ValueError, UnicodeDecodeError, OverflowError, Warning):
            fields = None
        if fields is not None:
            times = _exact_times(fields["t"])
            on, off = fields["p"] == b"1", fields["p"] == b"0"
            if times is not None and (on | off).all() and np.isfinite(fields["depth"]).all():
                out = np.empty(len(fields), EVENT_DEPTH_DTYPE)
                out["t"], out["x"], out["y"] = times, fields["x"], fields["y"]
                out["p"] = np.where(on, 1, -1)
                out["depth"], out["flag"] = fields["depth"], fields["flag"]
                return out
    return _parse_lines(path, enumerate(block.split(b"\n"), first_line))


def _parse_lines(path: Path, lines: Iterable[tuple[int, bytes]]) -> np.ndarray:
    """Numbered lines of an ``events_depth.txt`` parsed one by one (blank and ``#`` lines
    skipped); a bad line is named."""
    rows = []
    for number, line in lines:
        fields = line.split()
        if not fields or fields[0].startswith(b"#"):
            continue
        try:
            if len(fields) != 6:
                raise ValueError
            whole, _, frac = fields[0].partition(b".")
            t = int(whole) * 10**9 + int((frac + b"000000000")[:9])
            row = (t, int(fields[1]), int(fields[2]), 1 if fields[3] == b"1" else -1,
                   float(fields[4]), int(fields[5]))
            if fields[3] not in (b"0", b"1") or not math.isfinite(row[4]):
                raise ValueError
        except ValueError:
            text = line.strip()[:60].decode("ascii", "replace")
            raise ValueError(f"{path}:{number}: expected 't[s] x y p depth flag' (p 0 or 1, "
                             f"depth in metres), got {text!r}") from None
        rows.append(row)
    return np.array(rows, dtype=EVENT_DEPTH_DTYPE) if rows else np.empty(0, EVENT_DEPTH_DTYPE)


def _read_txt(path: Path, t0_ns: int | None = None, t1_ns: int | None = None
              ) -> tuple[np.ndarray, int, int]:
    """The rows of a whole ``events_depth.txt`` with ``t0_ns <= t < t1_ns`` (None: open),
    streamed in blocks of lines (memory: a block and the kept rows): ``(rows, number of rows
    with t < t0_ns (the index of the first kept row, the rows being sorted by t), number of
    rows)``."""
    kept = []
    first = count = 0
    number = 1
    with path.open("rb") as handle:
        while lines := handle.readlines(_TXT_BLOCK):
            rows = _parse_block(path, b"".join(lines), number)
            number += len(lines)
            count += len(rows)
            keep = np.ones(len(rows), bool)
            if t0_ns is not None:
                keep &= rows["t"] >= t0_ns
                first += int(np.count_nonzero(rows["t"] < t0_ns))
            if t1_ns is not None:
                keep &= rows["t"] < t1_ns
            kept.append(rows[keep])
    out = np.concatenate(kept) if kept else np.empty(0, EVENT_DEPTH_DTYPE)
    return out, first, count


_TXT_BLOCK = 1 << 20
"""Bytes of an ``events_depth.txt`` parsed at a time by a whole-file reading (1 MiB: its
memory is a few times that)."""


def read_event_depth_span(path: str | Path, start: int, stop: int,
                          first_line: int = 1) -> np.ndarray:
    """The events with their depth of bytes ``[start, stop)`` of an ``events_depth.txt``
    (whole lines: offsets from :func:`sim.eventio.line_offsets`), without the rest of the file.

    Parameters
    ----------
    path : str or Path
        An ``events_depth.txt``.
    start, stop : int, bytes
        ``0 <= start <= stop``, each at the start of a line or the file's end.
    first_line : int
        The 1-based line number at ``start``, for messages.

    Returns
    -------
    (M,) EVENT_DEPTH_DTYPE ndarray

    Raises
    ------
    ValueError
        A bad range, or a malformed line (``"{path}:{line}: ..."``).
    """
    path = Path(path)
    block = read_byte_span(path, start, stop)
    return _parse_block(path, block, int(first_line))


def read_event_depth(path: str | Path, t0_ns: int | None = None,
                     t1_ns: int | None = None) -> np.ndarray | None:
    """Events with their depth in ``[t0_ns, t1_ns)``, from ``events.h5`` or ``events_depth.txt``.

    Parameters
    ----------
    path : str or Path
        An ``events.h5`` (with ``events/depth``) or an ``events_depth.txt``.
    t0_ns, t1_ns : int, optional
        The window, nanoseconds on the event clock (default: everything).

    Returns
    -------
    (N,) EVENT_DEPTH_DTYPE ndarray or None
        Sorted by t; None for an ``events.h5`` without per-event depth (a real recording).

    Raises
    ------
    ValueError
        The file cannot be read (the message names it and the line or dataset).
    """
    path = Path(path)
    if path.suffix == ".h5":
        out = _read_h5(path, t0_ns, t1_ns)
        if out is None:
            return None
    else:
        out = _read_txt(path, t0_ns, t1_ns)[0]   # streamed: the window's rows only
    return _in_window(out, t0_ns, t1_ns)
