"""Converting an event file between ECD text and the DSEC HDF5 layout, streamed
(:func:`convert_events`)."""

from __future__ import annotations

from pathlib import Path

from sim.eventio._formats import _kind
from sim.eventio._hdf5 import H5EventWriter, _H5Source
from sim.eventio._read import iter_event_chunks
from sim.eventio._text import TextEventWriter
from sim.validation import ParameterError

__all__ = ["convert_events"]


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
        an HDF5 output (a :class:`sim.validation.ParameterError` whose ``sensor`` a front end
        names its way), or the source is malformed (as :func:`iter_event_chunks`); then, as on
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
            literal = ParameterError.literal
            raise ParameterError(f"converting {literal(src)} to {literal(dst)}: an events.h5 "
                                 "needs the sensor size; expected width and height ({sensor})",
                                 sensor="pass width= and height=")
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
