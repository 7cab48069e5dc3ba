"""ROS 1 and ROS 2 bags of events (``dvs_msgs/EventArray``), written and read with ``rosbags``.

A ROS 1 bag is one ``.bag`` file; a ROS 2 bag is a folder (``metadata.yaml`` and one ``.mcap``
or ``.db3`` storage file) or a bare ``.mcap`` file. ``rosbags`` (pure Python, no ROS install)
writes and reads the bag containers; the ``dvs_msgs/EventArray`` messages themselves, which hold
most of the bytes, are built and parsed here with NumPy structured arrays (13 bytes an event in
ROS 1; 16 a stride, 2 + 2 + 4 + 4 + 1 and CDR's padding, in ROS 2), never one Python object per
event. Both layouts are checked against ``rosbags``' own serializers in the tests.

Time is exact: a bag stores ``ts`` as seconds and nanoseconds, so an int64 nanosecond time
round-trips with no rounding (unlike the microsecond formats). ROS 1 times are unsigned 32-bit
seconds (to 2106), ROS 2 signed (to 2038); a time outside that range is refused.

Messages: one ``EventArray`` per time slice of :data:`SLICE_NS` (10 ms) of the event clock,
as the rpg_dvs_ros driver publishes at a fixed rate (ESIM publishes one per simulator step,
which a file has no record of), split further so that none holds more than
:data:`MAX_EVENTS_PER_MESSAGE`. The header stamp and the bag time of a message are its last
event's time (ESIM's ``eventsToMsg``).
"""

from __future__ import annotations

import functools
import os
import shutil
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from sim._atomic import partial_path
from sim.eventio._events import EVENT_DTYPE, _check_size, _first_error
from sim.eventio._formats import EXTRA_HINT, MissingExtraError
from sim.eventio._writer import _StreamingWriter

__all__ = ["EVENT_ARRAY", "EVENTS_TOPIC", "MAX_EVENTS_PER_MESSAGE",
           "RosEventWriter", "SLICE_NS", "BagFile", "bag_info", "bag_ros_version",
           "decode_event_array", "encode_event_array", "iter_bag_chunks", "open_bag",
           "typestore"]

EVENT_ARRAY = "dvs_msgs/msg/EventArray"
EVENTS_TOPIC = "/dvs/events"
"""The default event topic: the rpg_dvs_ros driver's and the Event-Camera Dataset's."""

SLICE_NS = 10_000_000
"""One EventArray message per 10 ms slice of the event clock (t // SLICE_NS)."""

MAX_EVENTS_PER_MESSAGE = 500_000
"""A slice with more events than this is split into messages of at most this many."""

_NS = 1_000_000_000
_MAX_SEC = {1: 2**32 - 1, 2: 2**31 - 1}

_MSG_DEFS = {
    1: {"dvs_msgs/msg/Event": "uint16 x\nuint16 y\ntime ts\nbool polarity\n",
        "esim_msgs/msg/OpticFlow": ("std_msgs/Header header\nuint32 height\nuint32 width\n"
                                    "float32[] flow_x\nfloat32[] flow_y\n")},
    2: {"dvs_msgs/msg/Event": "uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n",
        "esim_msgs/msg/OpticFlow": ("std_msgs/Header header\nuint32 height\nuint32 width\n"
                                    "float32[] flow_x\nfloat32[] flow_y\n")},
}
_EVENT_ARRAY_DEF = "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n"

# ROS 1: x, y uint16, ts (uint32 sec, uint32 nsec), bool polarity, packed
_ROS1_EVENT = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"),
                        ("p", "u1")])
# ROS 2 (CDR, little endian): a 16-byte stride; the first event is x, y, sec, nsec, p; every
# later one starts 2 bytes before a stride (x), then y, 2 bytes of padding (ts is 4-aligned)
_CDR_EVENT = np.dtype({"names": ["a", "b", "sec", "nsec", "p", "x_next"],
                       "formats": ["<u2", "<u2", "<i4", "<u4", "u1", "<u2"],
                       "offsets": [0, 2, 4, 8, 12, 14], "itemsize": 16})


def _rosbags() -> Any:
    """Import ``rosbags`` or say in one line which extra installs it
    (:class:`sim.eventio._formats.MissingExtraError`, a ValueError)."""
    try:
        import rosbags.rosbag1
        import rosbags.rosbag2
        import rosbags.typesys
    except ImportError:
        raise MissingExtraError(f"ROS bags need rosbags, which is not installed; expected it "
                                f"from {EXTRA_HINT}") from None
    return rosbags


@functools.cache
def typestore(ros: int) -> Any:
    """The ``rosbags`` type store of ROS 1 (Noetic) or ROS 2 (Humble) with ``dvs_msgs/Event``,
    ``dvs_msgs/EventArray`` and ESIM's ``esim_msgs/OpticFlow`` registered from their ``.msg``
    definitions (and, for ROS 1, ``tf2_msgs/TFMessage``, Noetic's ``/tf`` type)."""
    rosbags = _rosbags()
    from rosbags.typesys import Stores, get_types_from_msg

    store = rosbags.typesys.get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    types: dict = {}
    for name, text in _MSG_DEFS[ros].items():
        types.update(get_types_from_msg(text, name))
    types.update(get_types_from_msg(_EVENT_ARRAY_DEF, EVENT_ARRAY))
    if "tf2_msgs/msg/TFMessage" not in store.types:     # Noetic's /tf type
        types.update(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n",
                                        "tf2_msgs/msg/TFMessage"))
    store.register(types)
    return store


def _check_ros(ros: int) -> int:
    if ros not in (1, 2):
        raise ValueError(f"ROS version must be 1 or 2, got {ros!r}")
    return ros


def bag_ros_version(path: str | Path, ros: int | None = None) -> int:
    """Which ROS a bag path is: ``.bag`` is ROS 1; ``.mcap``, ``.db3`` or a folder holding
    ``metadata.yaml`` is ROS 2; any other name needs ``ros`` (the ``--ros`` flag).

    Raises
    ------
    ValueError
        The path says nothing and ``ros`` is None, or ``ros`` contradicts the suffix.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    said = 1 if suffix == ".bag" else 2 if suffix in (".mcap", ".db3") else None
    if said is None and path.is_dir() and (path / "metadata.yaml").is_file():
        said = 2
    if ros is not None:
        _check_ros(ros)
        if said is not None and said != ros:
            raise ValueError(f"{path}: a {suffix or 'ROS 2 folder'} is a ROS {said} bag, not "
                             f"ROS {ros}; expected a matching ROS version")
        return ros
    if said is None:
        raise ValueError(f"{path}: cannot tell the ROS version from the name; expected .bag "
                         "(ROS 1), .mcap or a ROS 2 bag folder, or the ROS version given")
    return said


def _stamp_parts(t_ns: np.ndarray, ros: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    sec, nsec = np.divmod(t_ns, _NS)
    if sec.size and (sec.min() < 0 or sec.max() > _MAX_SEC[ros]):
        bad = int(np.flatnonzero((sec < 0) | (sec > _MAX_SEC[ros]))[0])
        raise ValueError(f"{where}: t = {int(t_ns[bad])} ns is outside a ROS {ros} time "
                         f"(0 to {_MAX_SEC[ros]} s)")
    return sec, nsec


def _ros_string(text: str, ros: int) -> bytes:
    raw = text.encode()
    if ros == 1:
        return struct.pack("<I", len(raw)) + raw
    raw += b"\0"
    return struct.pack("<I", len(raw)) + raw + b"\0" * (-len(raw) % 4)


def encode_event_array(events: np.ndarray, width: int, height: int, ros: int,
                       frame_id: str = "", seq: int = 0) -> bytes:
    """Serialize events as one ``dvs_msgs/EventArray`` message, vectorised.

    Parameters
    ----------
    events : (N,) EVENT_DTYPE ndarray, N >= 1
        Time-ordered; times in nanoseconds, written exactly as seconds and nanoseconds.
    width, height : int, pixels
        The message's sensor size.
    ros : {1, 2}
        ROS 1 serialization or ROS 2 CDR (little endian).
    frame_id : str
    seq : int
        The ROS 1 header's sequence number (ROS 2 has none).

    Returns
    -------
    bytes
        What ``rosbags``' ``serialize_ros1`` / ``serialize_cdr`` gives for the same message;
        the header stamp is the last event's time.
    """
    n = events.size
    sec, nsec = _stamp_parts(events["t"], ros, "EventArray")
    stamp = (int(sec[-1]), int(nsec[-1])) if n else (0, 0)
    if ros == 1:
        head = (struct.pack("<III", seq & 0xFFFFFFFF, *stamp) + _ros_string(frame_id, 1)
                + struct.pack("<III", height, width, n))
        body = np.empty(n, _ROS1_EVENT)
        body["x"], body["y"], body["sec"], body["nsec"] = events["x"], events["y"], sec, nsec
        body["p"] = events["p"] > 0
        return head + body.tobytes()
    head = (b"\x00\x01\x00\x00" + struct.pack("<iI", *stamp) + _ros_string(frame_id, 2)
            + struct.pack("<III", height, width, n))
    if not n:
        return head
    body = np.zeros(n, _CDR_EVENT)
    body["a"][0], body["b"][0] = events["x"][0], events["y"][0]
    body["a"][1:] = events["y"][1:]
    body["x_next"][:-1] = events["x"][1:]
    body["sec"], body["nsec"], body["p"] = sec, nsec, events["p"] > 0
    return head + body.tobytes()[:16 * (n - 1) + 13]


def _malformed(where: str, what: str) -> ValueError:
    return ValueError(f"{where}: {what}; expected a dvs_msgs/EventArray message")


def decode_event_array(data: bytes | memoryview, ros: int, where: str = "EventArray"
                       ) -> tuple[np.ndarray, int, int]:
    """Parse one serialized ``dvs_msgs/EventArray``, vectorised.

    Parameters
    ----------
    data : bytes
        ROS 1 serialization or ROS 2 CDR (little endian).
    ros : {1, 2}
    where : str
        Names the message in errors (file and message index).

    Returns
    -------
    events : (N,) EVENT_DTYPE ndarray
        In the message's order (not checked here); polarity true is +1, false -1.
    width, height : int

    Raises
    ------
    ValueError
        The bytes are shorter or longer than the message they announce, or big-endian CDR.
    """
    buf = memoryview(data).cast("B")
    try:
        if ros == 1:
            (length,) = struct.unpack_from("<I", buf, 12)
            pos = 16 + length
            height, width, n = struct.unpack_from("<III", buf, pos)
            pos += 12
            size = 13 * n
        else:
            if bytes(buf[:2]) != b"\x00\x01":
                raise _malformed(where, f"CDR encapsulation {bytes(buf[:2]).hex()} is not "
                                 "little-endian CDR (0001)")
            (length,) = struct.unpack_from("<I", buf, 12)
            pos = 16 + length
            pos += -(pos - 4) % 4
            height, width, n = struct.unpack_from("<III", buf, pos)
            pos += 12
            size = 16 * (n - 1) + 13 if n else 0
    except struct.error:
        raise _malformed(where, f"{len(buf)} bytes are too few for a header") from None
    if len(buf) - pos != size:
        raise _malformed(where, f"{n} events need {size} bytes after the header, the message "
                         f"has {len(buf) - pos}")
    events = np.empty(n, EVENT_DTYPE)
    if not n:
        return events, width, height
    if ros == 1:
        body = np.frombuffer(buf, _ROS1_EVENT, n, pos)
        events["x"], events["y"] = body["x"], body["y"]
    else:
        padded = np.empty(16 * n, np.uint8)
        padded[:size] = np.frombuffer(buf, np.uint8, size, pos)
        body = padded.view(_CDR_EVENT)
        events["x"][0], events["y"][0] = body["a"][0], body["b"][0]
        events["x"][1:] = body["x_next"][:-1]
        events["y"][1:] = body["a"][1:]
    events["t"] = body["sec"].astype(np.int64) * _NS + body["nsec"]
    events["p"] = np.where(body["p"] != 0, 1, -1)
    return events, width, height


class BagFile:
    """A ROS 1 or ROS 2 bag being written, by raw serialized messages.

    Written under ``<path>.partial`` (a file for ROS 1, a folder for ROS 2) and renamed to
    ``<path>`` by :meth:`close`; :meth:`abort` removes the partial output (a bag cannot be
    resumed).

    Parameters
    ----------
    path : str or Path
        ``.bag`` (ROS 1); a folder name or ``.mcap`` (ROS 2: a folder with ``metadata.yaml``,
        or, for ``.mcap``, the bare storage file).
    ros : {1, 2}
    storage : {"mcap", "sqlite3"}
        ROS 2 storage (``sqlite3`` writes a ``.db3``; a bare ``.mcap`` output needs ``mcap``).
    """

    def __init__(self, path: str | Path, ros: int, storage: str = "mcap") -> None:
        rosbags = _rosbags()
        self.path = Path(path)
        self.ros = _check_ros(ros)
        self.partial = partial_path(self.path)
        self.store = typestore(ros)
        if storage not in ("mcap", "sqlite3"):
            raise ValueError(f"ROS 2 storage must be 'mcap' or 'sqlite3', got {storage!r}")
        if ros == 2 and self.path.suffix.lower() == ".mcap" and storage != "mcap":
            raise ValueError(f"{self.path}: a .mcap file is mcap storage; expected "
                             "storage='mcap' or a folder name")
        _remove(self.partial)               # an earlier interrupted run's
        self._connections: dict[str, Any] = {}
        if ros == 1:
            self._writer = rosbags.rosbag1.Writer(self.partial)
        else:
            from rosbags.rosbag2 import StoragePlugin

            self._inner = self.partial / (self.path.stem if self.path.suffix.lower() == ".mcap"
                                          else self.path.name)
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self._writer = rosbags.rosbag2.Writer(self._inner, version=9, storage_plugin=plugin)
        self._writer.open()

    def connection(self, topic: str, msgtype: str) -> Any:
        """The connection of ``topic`` (added on first use, with ``msgtype``)."""
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(topic, msgtype,
                                                                   typestore=self.store)
        return self._connections[topic]

    def write(self, topic: str, msgtype: str, t_ns: int, data: bytes | memoryview) -> None:
        """Write one serialized message at bag time ``t_ns`` (nanoseconds)."""
        self._writer.write(self.connection(topic, msgtype), int(t_ns), data)

    def serialize(self, message: object, msgtype: str) -> bytes:
        """A message object of :attr:`store` in this bag's serialization."""
        if self.ros == 1:
            return bytes(self.store.serialize_ros1(message, msgtype))
        return bytes(self.store.serialize_cdr(message, msgtype))

    def close(self) -> None:
        """Finish the bag and move it to its final name (replacing a bag there)."""
        self._writer.close()
        if self.ros == 1:
            os.replace(self.partial, self.path)
            return
        if self.path.suffix.lower() == ".mcap":
            os.replace(self._inner / f"{self._inner.name}.mcap", self.path)
        else:
            _remove(self.path)
            os.replace(self._inner, self.path)
        _remove(self.partial)

    def abort(self) -> None:
        """Stop writing and remove the partial output."""
        try:
            if self.ros == 1:
                self._writer.abort()
            elif self._writer.storage is not None:
                self._writer.close()
        finally:
            _remove(self.partial)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _message_slices(t: np.ndarray, slice_ns: int, max_events: int) -> np.ndarray:
    """Where the messages of time-ordered times ``t`` begin: at each new ``t // slice_ns``
    and every ``max_events`` within a slice."""
    slot = t // slice_ns
    starts = np.flatnonzero(np.r_[True, slot[1:] != slot[:-1]])
    ends = np.r_[starts[1:], t.size]
    pieces = [np.arange(s, e, max_events) for s, e in zip(starts, ends, strict=True)
              if e - s > max_events]
    if pieces:
        starts = np.unique(np.concatenate([starts, *pieces]))
    return starts


class RosEventWriter(_StreamingWriter):
    """Stream events into a ROS 1 or ROS 2 bag as ``dvs_msgs/EventArray`` messages.

    Parameters
    ----------
    path : str or Path
        ``.bag`` (ROS 1) or a ROS 2 bag (folder name or ``.mcap``); see :class:`BagFile`.
    width, height : int
        Sensor size (every message carries it; events outside it are refused).
    ros : {1, 2}, optional
        Needed when the name does not say (:func:`bag_ros_version`).
    topic : str
        Event topic, default :data:`EVENTS_TOPIC`.
    frame_id : str
        The messages' ``header.frame_id``.
    storage : {"mcap", "sqlite3"}
        ROS 2 storage.
    slice_ns, max_events : int
        One message per ``slice_ns`` of the event clock, at most ``max_events`` each.

    Notes
    -----
    Like the other writers: ``write`` takes consecutive time-ordered EVENT_DTYPE chunks, the
    bag is ``<path>.partial`` until :meth:`close`; unlike them a bag cannot be checkpointed and
    resumed, and an exception inside the ``with`` removes the partial bag.
    """

    _format = "bag"
    before_message: Any = None
    """Called with each event message's stamp (ns) before it is written (a whole-sequence bag
    writes the other topics' earlier messages there, keeping the bag in time order)."""

    def __init__(self, path: str | Path, width: int, height: int, *, ros: int | None = None,
                 topic: str = EVENTS_TOPIC, frame_id: str = "", storage: str = "mcap",
                 slice_ns: int = SLICE_NS, max_events: int = MAX_EVENTS_PER_MESSAGE,
                 bag: BagFile | None = None) -> None:
        self._begin(path)
        _check_size(width, height, str(self.path))
        if width is None or height is None:
            raise ValueError(f"{self.path}: a bag's EventArray needs the sensor size; expected "
                             "width and height")
        for name, value in (("slice_ns", slice_ns), ("max_events", max_events)):
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        self._width, self._height = int(width), int(height)
        self.topic, self.frame_id = topic, frame_id
        self._slice_ns, self._max_events = slice_ns, max_events
        self._own_bag = bag is None
        self.bag = BagFile(self.path, bag_ros_version(self.path, ros), storage) if bag is None \
            else bag
        self.partial = self.bag.partial
        self._pending = np.empty(0, EVENT_DTYPE)
        self._messages = 0

    def write(self, events: np.ndarray) -> None:
        """Append a time-ordered EVENT_DTYPE chunk (see :class:`RosEventWriter`)."""
        self._check_chunk(events)
        if not events.size:
            return
        _stamp_parts(events["t"][[0, -1]], self.bag.ros, f"{self.path}: chunk at event "
                     f"{self.count}")
        self.count += events.size
        self._last_t = int(events["t"][-1])
        pending = np.concatenate([self._pending, events]) if self._pending.size else events
        starts = _message_slices(pending["t"], self._slice_ns, self._max_events)
        # the last message may go on in the next chunk: held back (at most max_events), so
        # that the messages do not depend on how the stream was cut into chunks
        last = int(starts[-1])
        if last:
            self._emit(pending[:last], starts[:-1])
        self._pending = pending[last:].copy()

    def _emit(self, events: np.ndarray, starts: np.ndarray) -> None:
        ends = np.r_[starts[1:], events.size]
        for s, e in zip(starts, ends, strict=True):
            part = events[s:e]
            data = encode_event_array(part, self._width, self._height, self.bag.ros,
                                      self.frame_id, self._messages)
            if self.before_message is not None:
                self.before_message(int(part["t"][-1]))
            self.bag.write(self.topic, EVENT_ARRAY, int(part["t"][-1]), data)
            self._messages += 1

    def flush(self) -> None:
        """Write the events still held for the current slice as a message now."""
        if self._pending.size:
            self._emit(self._pending, _message_slices(self._pending["t"], self._slice_ns,
                                                      self._max_events))
            self._pending = np.empty(0, EVENT_DTYPE)

    def checkpoint(self) -> dict:
        """Refused: a bag cannot be resumed (``rosbags`` writes new bags only)."""
        raise ValueError(f"{self.path}: a ROS bag cannot be checkpointed and resumed; expected "
                         "an events.txt or events.h5 output for a resumable run")

    def _finish(self) -> None:
        self.flush()
        if self._own_bag:
            self.bag.close()

    def _abort(self) -> None:
        if self._own_bag:
            self.bag.abort()

    def _publish(self) -> None:
        """Nothing: :meth:`BagFile.close` (in :meth:`_finish`) gave the bag its name, or the
        whole-sequence writer that owns the bag will."""


def open_bag(path: str | Path, ros: int | None = None) -> Any:
    """An opened ``rosbags`` reader of a ROS 1 or ROS 2 bag (close it), its ROS version.

    Raises
    ------
    ValueError
        No such bag, or ``rosbags`` cannot read it (truncated, not a bag): one line naming
        the file and what was expected.
    """
    rosbags = _rosbags()
    path = Path(path)
    if not path.exists():
        raise ValueError(f"bag {path} does not exist")
    ros = bag_ros_version(path, ros)
    reader = rosbags.rosbag1.Reader(path) if ros == 1 else None
    try:
        if reader is None:
            reader = rosbags.rosbag2.Reader(path)
        reader.open()
    except (rosbags.rosbag1.ReaderError, rosbags.rosbag2.ReaderError, FileNotFoundError,
            OSError, KeyError, struct.error) as exc:
        raise ValueError(f"{path}: not a readable ROS {ros} bag ({exc}); expected a complete "
                         f"{'ROS 1 .bag' if ros == 1 else 'ROS 2 bag (mcap or sqlite3)'}"
                         ) from None
    return reader, ros


def _event_connections(reader: Any, path: Path, topic: str | None) -> list:
    """The connections of the event topic: ``topic`` if given, else the one topic whose type is
    ``dvs_msgs/EventArray``."""
    if topic is not None:
        found = [c for c in reader.connections if c.topic == topic]
        if not found:
            raise ValueError(f"{path}: no topic {topic!r}; expected one of "
                             f"{sorted({c.topic for c in reader.connections})}")
        if any(c.msgtype != EVENT_ARRAY for c in found):
            raise ValueError(f"{path}: topic {topic!r} is {found[0].msgtype}; expected "
                             f"{EVENT_ARRAY}")
        return found
    found = [c for c in reader.connections if c.msgtype == EVENT_ARRAY]
    topics = sorted({c.topic for c in found})
    if not topics:
        raise ValueError(f"{path}: no {EVENT_ARRAY} topic; expected a bag with events (its "
                         f"topics: {sorted({c.topic for c in reader.connections})})")
    if len(topics) > 1:
        raise ValueError(f"{path}: {len(topics)} {EVENT_ARRAY} topics {topics}; expected the "
                         "event topic named (--topic)")
    return found


def iter_bag_chunks(path: str | Path, chunk_events: int = 10**6, *, topic: str | None = None,
                    ros: int | None = None) -> Iterator[np.ndarray]:
    """The events of a bag's ``dvs_msgs/EventArray`` topic in chunks, in the bag's order: the
    format registry's reader (:func:`sim.eventio.iter_event_chunks` checks the time order across
    chunks, the sensor and a window, and names an event out of order by its index).

    Parameters
    ----------
    path : str or Path
        A ``.bag``, a ROS 2 bag folder, or ``.mcap`` / ``.db3`` (``ros`` where the name cannot
        say).
    chunk_events : int
        Most events per chunk.
    topic : str, optional
        The event topic; default the one topic of type ``dvs_msgs/EventArray``.

    Yields
    ------
    (M,) EVENT_DTYPE ndarray
        Consecutive chunks of 1 to ``chunk_events`` events. Each message's events are checked
        against the message's own sensor size and time order (``"{path}: event {i}: ..."``).

    Raises
    ------
    ValueError
        Not a readable bag, no (or more than one) event topic, a ``topic`` that is not there,
        a malformed message (named by its index), an event outside its message's sensor.
    """
    path = Path(path)
    reader, ros = open_bag(path, ros)
    try:
        connections = _event_connections(reader, path, topic)
        pending: list[np.ndarray] = []
        held = index = 0
        for k, (_, _, data) in enumerate(reader.messages(connections=connections)):
            events, width, height = decode_event_array(data, ros, f"{path}: event message {k}")
            error = _first_error(events, width, height, None)
            if error is not None:
                raise ValueError(f"{path}: event {index + error[0]}: {error[1]}")
            index += events.size
            if events.size:
                pending.append(events)
                held += events.size
            while held >= chunk_events:
                joined = np.concatenate(pending)
                yield joined[:chunk_events]
                pending, held = [joined[chunk_events:]], joined.size - chunk_events
        if held:
            yield np.concatenate(pending)
    finally:
        reader.close()


def bag_info(path: str | Path, *, topic: str | None = None, ros: int | None = None) -> dict:
    """What a bag says cheaply about its events: its first and last messages only.

    Returns
    -------
    dict
        ``format`` (``"ros1"`` or ``"ros2"``), ``topic``, ``messages`` (EventArray messages),
        ``width``/``height`` (the first message's), ``t_first_ns`` (its first event) and
        ``t_last_message_ns`` (the bag time of the last event message).
    """
    path = Path(path)
    reader, ros = open_bag(path, ros)
    try:
        connections = _event_connections(reader, path, topic)
        info = {"format": f"ros{ros}", "topic": connections[0].topic,
                "messages": sum(c.msgcount for c in connections), "width": None,
                "height": None, "t_first_ns": None}
        for _, _, data in reader.messages(connections=connections):
            events, width, height = decode_event_array(data, ros, f"{path}: event message 0")
            info.update(width=width, height=height,
                        t_first_ns=int(events["t"][0]) if events.size else None)
            break
        info["t_last_ns"] = None
        if info["messages"]:                # the bag's last message, if it is an event message
            for _, _, data in reader.messages(connections=connections,
                                              start=int(reader.end_time) - 1):
                events, _, _ = decode_event_array(data, ros, f"{path}: last event message")
                info["t_last_ns"] = int(events["t"][-1]) if events.size else None
        info["bag_span_ns"] = (int(reader.start_time), int(reader.end_time))
        return info
    finally:
        reader.close()


# --- the format registry's codec interface (sim.eventio._formats) ----------------------------

def ros1_writer(path: Path, *, sensor_size: tuple[int, int] | None,
                **options: Any) -> RosEventWriter:
    """The registry's writer of a ROS 1 bag (:func:`ros_writer`)."""
    return ros_writer(path, sensor_size=sensor_size, ros=1, **options)


def ros2_writer(path: Path, *, sensor_size: tuple[int, int] | None,
                **options: Any) -> RosEventWriter:
    """The registry's writer of a ROS 2 bag (:func:`ros_writer`): a folder, or ``.mcap``."""
    return ros_writer(path, sensor_size=sensor_size, ros=2, **options)


def ros_writer(path: Path, *, sensor_size: tuple[int, int] | None, ros: int | None = None,
               topic: str | None = None, **options: Any) -> RosEventWriter:
    """A writer of a ROS 1 or ROS 2 bag (:class:`RosEventWriter`; it needs the sensor size,
    which every EventArray carries)."""
    if sensor_size is None:
        raise ValueError(f"{path}: a bag's EventArray needs the sensor size; expected "
                         "(width, height)")
    return RosEventWriter(path, int(sensor_size[0]), int(sensor_size[1]), ros=ros,
                          topic=topic or EVENTS_TOPIC, **options)


def iter_ros_chunks(path: Path, *, chunk_events: int, topic: str | None = None,
                    ros: int | None = None, **options: Any) -> Iterator[np.ndarray]:
    """The registry's reader: :func:`iter_bag_chunks`."""
    return iter_bag_chunks(path, chunk_events, topic=topic, ros=ros)


def ros_info(path: Path, *, topic: str | None = None, ros: int | None = None) -> dict:
    """The registry's cheap look at a bag (:func:`bag_info`, with the registry's keys:
    ``sensor_size``, ``t_first_ns``, ``t_last_ns`` and ``count``, None: not cheap)."""
    info = bag_info(path, topic=topic, ros=ros)
    sensor = None if info["width"] is None else (info["width"], info["height"])
    return {**info, "sensor_size": sensor, "count": None}
