"""Converting an event file between ECD text, the DSEC HDF5 layout and ROS bags, streamed
(:func:`convert_events`)."""

from __future__ import annotations

from pathlib import Path

from sim.eventio._formats import _kind
from sim.eventio._hdf5 import H5EventWriter, _H5Source
from sim.eventio._read import iter_event_chunks
from sim.eventio._rosbag import EVENTS_TOPIC, RosEventWriter, bag_info
from sim.eventio._text import TextEventWriter
from sim.validation import ParameterError

__all__ = ["convert_events"]


def _bag_kind(path: Path, ros: int | None) -> str:
    """:func:`_kind`, with a ROS version given making any other name a ROS bag."""
    try:
        return _kind(path)
    except ValueError:
        if ros is None:
            raise
        return "bag"


def convert_events(src: str | Path, dst: str | Path, width: int | None = None,
                   height: int | None = None, *, topic: str | None = None,
                   ros: int | None = None, src_ros: int | None = None) -> None:
    """Convert an event file between ECD text, DSEC HDF5 and ROS bags (by suffix), streaming.

    Parameters
    ----------
    src, dst : str or Path
        ``.txt``, ``.h5``/``.hdf5``, ``.bag`` (ROS 1), ``.mcap`` or a ROS 2 bag folder each
        (any combination; ``dst`` is written atomically and replaced if it exists).
    topic : str, optional
        The event topic: read from a bag ``src`` (default its one ``dvs_msgs/EventArray``
        topic) and written to a bag ``dst`` (default ``/dvs/events``).
    ros, src_ros : {1, 2}, optional
        The ROS version of a bag ``dst`` / ``src`` whose name cannot say (``--ros``).
    width, height : int, optional
        Sensor size. Required for an HDF5 ``dst`` unless ``src`` is an HDF5 file with
        ``width``/``height`` attributes (they are copied; given values take precedence). When
        given, every event is checked to lie inside the sensor. An HDF5 source's ``t_offset``
        is kept; a text source gets the writer's default (see :class:`H5EventWriter`).

    Raises
    ------
    ValueError
        Unknown suffixes, ``src`` and ``dst`` are the same file, the sensor size is unknown for
        an HDF5 output (a :class:`sim.validation.ParameterError` whose ``sensor`` a front end
        names its way), or the source is malformed (as :func:`iter_event_chunks`); then, as on
        any failure, no ``dst`` and no ``<dst>.partial`` is left.
    """
    src, dst = Path(src), Path(dst)
    src_kind, dst_kind = _bag_kind(src, src_ros), _bag_kind(dst, ros)
    if not (src.is_file() or (src_kind == "bag" and src.is_dir())):
        raise ValueError(f"event file {src} does not exist")
    if dst.exists() and dst.resolve() == src.resolve():
        raise ValueError(f"cannot convert {src} onto itself; expected a different output path")
    t_offset_us = None
    read_options = {"topic": topic, "ros": src_ros} if src_kind == "bag" else {}
    if src_kind == "bag" and (width is None or height is None):
        info = bag_info(src, topic=topic, ros=src_ros)
        width = width if width is not None else info["width"]
        height = height if height is not None else info["height"]
    if src_kind == "h5":
        source = _H5Source(src)
        try:
            width = width if width is not None else source.width
            height = height if height is not None else source.height
            t_offset_us = source.t_offset_us
        finally:
            source.close()
    writer: TextEventWriter | H5EventWriter | RosEventWriter
    if dst_kind in ("h5", "bag"):
        if width is None or height is None:
            literal = ParameterError.literal
            what = "an events.h5" if dst_kind == "h5" else "a bag's EventArray"
            raise ParameterError(f"converting {literal(src)} to {literal(dst)}: {what} "
                                 "needs the sensor size; expected width and height ({sensor})",
                                 sensor="pass width= and height=")
    if dst_kind == "bag":
        writer = RosEventWriter(dst, width, height, ros=ros, topic=topic or EVENTS_TOPIC)
    elif dst_kind == "h5":
        writer = H5EventWriter(dst, width, height, t_offset_us=t_offset_us)
    else:
        writer = TextEventWriter(dst)
    try:
        with writer:
            for chunk in iter_event_chunks(src, 1 << 20, width=width, height=height,
                                           **read_options):
                writer.write(chunk)
    except BaseException:                 # a failed conversion leaves nothing (not resumable)
        if writer.partial.is_file():
            writer.partial.unlink()
        raise
