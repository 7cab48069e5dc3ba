"""Converting an event file between any two registered formats, streamed
(:func:`convert_events`)."""

from __future__ import annotations

from pathlib import Path

from sim.eventio._formats import format_for, is_bag_folder
from sim.eventio._read import iter_event_chunks
from sim.validation import ParameterError

__all__ = ["convert_events"]


def convert_events(src: str | Path, dst: str | Path, width: int | None = None,
                   height: int | None = None, *, src_selectors: dict | None = None,
                   dst_selectors: dict | None = None, src_options: dict | None = None,
                   dst_options: dict | None = None) -> None:
    """Convert an event file between any two registered formats (by suffix), streaming.

    Parameters
    ----------
    src, dst : str or Path
        ``.txt`` (ECD text), ``.h5``/``.hdf5`` (DSEC), ``.aedat4``, ``.raw`` (EVT 3.0 by
        default) or any other registered suffix (:func:`sim.eventio._formats.event_formats`);
        ``dst`` is written atomically and replaced if it exists.
    width, height : int, optional
        Sensor size. Needed by a ``dst`` format that stores it (HDF5, AEDAT4, RAW) unless
        ``src`` holds it (an HDF5 file's attributes, an AEDAT4 stream's resolution, a RAW
        header: copied; given values take precedence). When given, every event is checked to
        lie inside the sensor. An HDF5 source's ``t_offset`` is kept in an HDF5 ``dst``.
    src_selectors, dst_selectors : dict, optional
        Which format of a suffix that holds more than one (``{"evt": 2}``; ``{"ros": 2}`` makes
        a new folder name a ROS 2 bag).
    src_options, dst_options : dict, optional
        What the source's reader and the output's writer take besides the file (a bag's
        ``{"topic": "/dvs/events"}``).

    Raises
    ------
    ValueError
        Unknown suffixes, ``src`` and ``dst`` are the same file, the sensor size is unknown for
        a ``dst`` that needs it (a :class:`sim.validation.ParameterError` whose ``sensor`` a
        front end names its way), the source is malformed (as
        :func:`sim.eventio.iter_event_chunks`), or a format's optional dependency is missing
        (the message names ``pip install 'evfuse[formats]'``); then, as on any failure, no
        ``dst`` and no ``<dst>.partial`` is left.
    """
    src, dst = Path(src), Path(dst)
    src_fmt = format_for(src, **(src_selectors or {}))
    dst_fmt = format_for(dst, **(dst_selectors or {}))
    if not (src.is_file() or is_bag_folder(src)):
        raise ValueError(f"event file {src} does not exist")
    if dst.exists() and dst.resolve() == src.resolve():
        raise ValueError(f"cannot convert {src} onto itself; expected a different output path")
    options = dict(dst_options or {})
    if src_fmt.name != "txt":
        info = src_fmt.read_info(src, **(src_options or {}))
        if info.get("sensor_size") is not None:
            width = width if width is not None else info["sensor_size"][0]
            height = height if height is not None else info["sensor_size"][1]
        if dst_fmt.name == "h5" and info.get("t_offset_us") is not None:
            options["t_offset_us"] = info["t_offset_us"]
    if (width is None or height is None) and dst_fmt.name != "txt":
        literal = ParameterError.literal
        what = "an events.h5" if dst_fmt.name == "h5" else f"a {dst_fmt.title} file"
        raise ParameterError(f"converting {literal(src)} to {literal(dst)}: {what} needs the "
                             "sensor size; expected width and height ({sensor})",
                             sensor="pass width= and height=")
    sensor = None if width is None or height is None else (int(width), int(height))
    writer = dst_fmt.open_writer(dst, sensor_size=sensor, **options)
    try:
        with writer:
            for chunk in iter_event_chunks(src, 1 << 20, width=width, height=height,
                                           selectors=src_selectors, options=src_options):
                writer.write(chunk)
    except BaseException:                 # a failed conversion leaves nothing (not resumable)
        _remove(writer.partial)
        raise


def _remove(partial: Path) -> None:
    """Remove an unfinished output (a file, or the folder an AEDAT4 writer keeps it in)."""
    if partial.is_dir():
        for child in partial.iterdir():
            child.unlink()
        partial.rmdir()
    else:
        partial.unlink(missing_ok=True)
