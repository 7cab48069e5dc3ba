"""Events in memory and on disk: the ECD text format and the DSEC HDF5 layout, streamed, and the
formats of the cameras (AEDAT4, Prophesee RAW) through a registry.

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

Modules (private; everything public is re-exported here):

- ``_events``: :data:`EVENT_DTYPE`, :func:`make_events`, :func:`check_events` (events in memory).
- ``_formats``: the format registry: which format a file is, by its suffix (and a selector such
  as ``evt=2`` where the suffix cannot say), and the codec interface every format follows
  (streaming writer, ``iter_chunks``, ``info``); the floor-to-microseconds rule.
- ``_raw``: Prophesee RAW, EVT 3.0 and EVT 2.0 (evfuse's own compiled codec).
- ``_aedat4``: AEDAT4 through dv-processing (the ``formats`` extra): events, frames, IMU.
- ``_rosbag``: ROS 1 and ROS 2 bags of ``dvs_msgs/EventArray`` (rosbags; the messages built and
  parsed with NumPy).
- ``_writer``: the streaming writers' common part (``.partial`` file, checkpoint and resume).
- ``_text``: the ECD text codec (compiled and line-by-line) and :class:`TextEventWriter`.
- ``_hdf5``: :class:`H5EventWriter` and the checked reader of the DSEC layout.
- ``_units``: :func:`check_time_units` (times in another unit than the format stores).
- ``_read``: :func:`iter_event_chunks`, :func:`read_events`, :func:`read_window`,
  :func:`event_time_span`; :func:`text_offsets` and :func:`read_text_span` (a text file read
  window by window), :func:`line_offsets` (the same windows' lines in a per-event text file),
  :func:`read_byte_span` (the bytes of such a span).
- ``_convert``: :func:`convert_events`.
"""

from __future__ import annotations

from sim._atomic import PARTIAL_SUFFIX  # the one suffix of everything unfinished
from sim.eventio._convert import convert_events
from sim.eventio._events import EVENT_DTYPE, check_events, make_events
from sim.eventio._hdf5 import MAX_EMPTY_MS, H5EventWriter
from sim.eventio._read import (
    event_time_span,
    iter_event_chunks,
    line_offsets,
    read_byte_span,
    read_events,
    read_text_span,
    read_window,
    text_offsets,
)
from sim.eventio._text import TextEventWriter
from sim.eventio._units import UNIT_OVERLAP, UNIT_SLACK, check_time_units

__all__ = [
    "EVENT_DTYPE",
    "H5EventWriter",
    "MAX_EMPTY_MS",
    "PARTIAL_SUFFIX",
    "TextEventWriter",
    "UNIT_OVERLAP",
    "UNIT_SLACK",
    "check_events",
    "check_time_units",
    "event_time_span",
    "convert_events",
    "iter_event_chunks",
    "line_offsets",
    "read_byte_span",
    "make_events",
    "read_events",
    "read_text_span",
    "read_window",
    "text_offsets",
]
