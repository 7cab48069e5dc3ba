"""The event file formats and the codec interface every one of them follows: the format registry.

A format is told by the file's suffix (:func:`format_for`); where one suffix holds more than one
format (Prophesee ``.raw``: EVT 3.0 or EVT 2.0; a ROS 1 or ROS 2 bag), a selector names it
(``evt=2``, ``ros=2``; on the command line ``--evt 2``, ``--ros 2``), and the format marked
``default`` is taken when none is given.

The codec interface (each format's module provides three callables, named in its
:class:`EventFormat` and imported on first use, so that an optional dependency is needed only by
whoever uses that format):

``writer(path, *, sensor_size, **options)``
    A streaming writer like :class:`sim.eventio.TextEventWriter`: a context manager whose
    ``write(events)`` takes consecutive time-ordered :data:`EVENT_DTYPE` chunks and whose
    ``close()`` finishes the file; it writes ``<name>.partial`` (attribute ``partial``) and renames
    it to ``<name>`` (attribute ``path``) only on success, so an interrupted run leaves no
    complete-looking file. ``sensor_size`` is ``(width, height)`` in pixels, or None where the
    format can do without it.
``iter_chunks(path, *, chunk_events, **options)``
    Yields the file's events as consecutive :data:`EVENT_DTYPE` chunks of at most
    ``chunk_events`` events, in file order (never sorted: the caller,
    :func:`sim.eventio.iter_event_chunks`, reports a time out of order with its file and event
    index). Bad input raises :class:`ValueError` with one line naming the file and what was
    expected.
``info(path)``
    A cheap look at the file: a dict with ``format`` (the name), ``sensor_size`` (``(width,
    height)`` or None when the file does not hold it), ``t_first_ns``, ``t_last_ns`` and
    ``count`` (each None when not cheap to know).

Time. Events in memory carry int64 nanoseconds; every format here but ECD text and the DSEC HDF5
layout (whose evfuse extension ``events/t_ns_rem`` keeps the remainder) stores whole
microseconds. The one rule for all of them: a time is written as ``t_ns // 1000`` (floor; times
on disk are >= 0) and read back as ``t_us * 1000``. So a time that is a whole number of
microseconds round-trips exactly, any other loses its sub-microsecond part, and the order of
events is kept.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["EXTRA_HINT", "ROS2_FOLDER", "EventFormat", "MissingExtraError", "event_formats",
           "format_for", "format_named", "is_bag_folder", "register_format", "us_from_ns"]

EXTRA_HINT = "pip install 'evfuse[formats]'"
"""What to run for the optional formats' dependencies (the ``formats`` extra)."""


class MissingExtraError(ValueError):
    """A format's optional dependency is not installed; the message names the extra."""


def us_from_ns(t_ns: np.ndarray) -> np.ndarray:
    """The stored microseconds of in-memory times: floor, ``t_ns // 1000`` (int64)."""
    return np.floor_divide(np.asarray(t_ns, np.int64), 1000)


@dataclass(frozen=True)
class EventFormat:
    """One event file format in the registry.

    Attributes
    ----------
    name : str
        Short name (``"txt"``, ``"h5"``, ``"aedat4"``, ``"evt3"``, ``"evt2"``, ...); what
        ``simulate --format`` takes.
    suffixes : tuple of str
        Lower-case file suffixes with the dot (``(".raw",)``).
    title : str
        What a message calls it (``"Prophesee RAW EVT 3.0"``).
    module : str
        The module that holds the codec (imported on first use).
    writer, reader, info : str
        Names, in ``module``, of the writer factory, the ``iter_chunks`` function and the
        ``info`` function (see the module docstring for their signatures).
    selector : dict
        Selector -> value that names this format among those of its suffix (``{"evt": 2}``).
    default : bool
        The format its suffix means when no selector is given.
    extra : str or None
        The pip extra its dependencies come in, or None when they are evfuse's own.
    time_unit : str
        The unit the file stores times in (``"microseconds"``, ``"seconds"``).
    """

    name: str
    suffixes: tuple[str, ...]
    title: str
    module: str
    writer: str
    reader: str
    info: str
    selector: dict[str, Any] = field(default_factory=dict)
    default: bool = True
    extra: str | None = None
    time_unit: str = "microseconds"

    def _load(self, attr: str) -> Callable[..., Any]:
        try:
            module = importlib.import_module(self.module)
        except ImportError as error:
            if self.extra is None:
                raise
            raise MissingExtraError(f"the {self.title} format needs {error.name}, which is not "
                                    f"installed; expected it from {EXTRA_HINT}") from None
        return getattr(module, attr)

    def open_writer(self, path: str | Path, *, sensor_size: tuple[int, int] | None,
                    **options: Any) -> Any:
        """A streaming writer of this format (see the module docstring)."""
        return self._load(self.writer)(Path(path), sensor_size=sensor_size, **options)

    def iter_chunks(self, path: str | Path, *, chunk_events: int,
                    **options: Any) -> Iterator[np.ndarray]:
        """The file's events, in chunks, in file order (see the module docstring)."""
        return self._load(self.reader)(Path(path), chunk_events=chunk_events, **options)

    def read_info(self, path: str | Path, **options: Any) -> dict:
        """The cheap look at a file (see the module docstring; ``options`` as the reader's)."""
        return self._load(self.info)(Path(path), **options)


_REGISTRY: dict[str, EventFormat] = {}


def register_format(fmt: EventFormat) -> EventFormat:
    """Add a format to the registry (a module's own formats register at import of this one).

    Raises
    ------
    ValueError
        The name is taken, or a suffix already has a default format and this one is a default.
    """
    if fmt.name in _REGISTRY:
        raise ValueError(f"event format {fmt.name!r} is registered twice")
    if fmt.default:
        for other in _REGISTRY.values():
            shared = set(fmt.suffixes) & set(other.suffixes)
            if other.default and shared:
                raise ValueError(f"event formats {other.name!r} and {fmt.name!r} are both the "
                                 f"default of {sorted(shared)}")
    _REGISTRY[fmt.name] = fmt
    return fmt


def event_formats() -> tuple[EventFormat, ...]:
    """Every registered format, in registration order."""
    return tuple(_REGISTRY.values())


def _known() -> str:
    def names(fmt: EventFormat) -> str:
        return " or ".join("a folder (with ros=2)" if s == ROS2_FOLDER else s
                           for s in fmt.suffixes)

    return ", ".join(f"{names(f)} ({f.title})" for f in _REGISTRY.values() if f.default)


def format_named(name: str) -> EventFormat:
    """The format of a name (``"evt2"``).

    Raises
    ------
    ValueError
        No such format; the message lists the names.
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown event format {name!r}; expected one of "
                         f"{', '.join(_REGISTRY)}") from None


def format_for(path: str | Path, **selectors: Any) -> EventFormat:
    """The format of a file, by its suffix and the selectors given (None = not given).

    Parameters
    ----------
    path : str or Path
        The file (only its suffix is read).
    **selectors
        ``evt=2``, ``ros=2``, ...: which of the formats sharing the suffix. A selector given
        for a suffix none of whose formats takes it is an error (not ignored).

    Raises
    ------
    ValueError
        Unknown suffix (the known ones listed), a selector that does not apply to the suffix,
        or a value no format has.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if not suffix and (is_bag_folder(path) or str(selectors.get("ros")) == "2"):
        suffix = ROS2_FOLDER
    found = [f for f in _REGISTRY.values() if suffix in f.suffixes]
    if not found:
        raise ValueError(f"{path}: unknown event file type {suffix!r}; expected {_known()}")
    for key, value in selectors.items():
        if value is None:
            continue
        values = [f.selector[key] for f in found if key in f.selector]
        if not values:
            raise ValueError(f"{path}: {key}={value!r} does not apply to a {suffix} file "
                             f"({found[0].title}); expected it only where a suffix holds more "
                             "than one format")
        if str(value) not in {str(v) for v in values}:
            raise ValueError(f"{path}: {key}={value!r} is not a {suffix} format; expected one of "
                             f"{', '.join(str(v) for v in values)}")
        found = [f for f in found if str(f.selector.get(key)) == str(value)]
    defaults = [f for f in found if f.default]
    return (defaults or found)[0]


ROS2_FOLDER = "/"
"""The pseudo-suffix of a ROS 2 bag folder (``metadata.yaml`` and its storage file): an
existing one, or a new folder name with ``ros=2``."""


def is_bag_folder(path: str | Path) -> bool:
    """Whether ``path`` is an existing ROS 2 bag folder (it holds ``metadata.yaml``)."""
    path = Path(path)
    return path.is_dir() and (path / "metadata.yaml").is_file()


def _kind(path: Path) -> str:
    """The format name of a file, by its suffix (its default format)."""
    return format_for(path).name


for _fmt in (
    EventFormat("txt", (".txt",), "ECD text", "sim.eventio._read", "_txt_writer", "_txt_chunks",
                "_txt_info", time_unit="seconds"),
    EventFormat("h5", (".h5", ".hdf5"), "DSEC HDF5", "sim.eventio._read", "_h5_writer",
                "_h5_chunks", "_h5_info"),
    EventFormat("aedat4", (".aedat4",), "AEDAT4", "sim.eventio._aedat4", "aedat4_writer",
                "iter_aedat4_chunks", "aedat4_info", extra="formats"),
    EventFormat("evt3", (".raw",), "Prophesee RAW EVT 3.0", "sim.eventio._raw", "evt3_writer",
                "iter_raw_chunks", "raw_info", selector={"evt": 3}),
    EventFormat("evt2", (".raw",), "Prophesee RAW EVT 2.0", "sim.eventio._raw", "evt2_writer",
                "iter_raw_chunks", "raw_info", selector={"evt": 2}, default=False),
    EventFormat("ros1", (".bag",), "ROS 1 bag", "sim.eventio._rosbag", "ros1_writer",
                "iter_ros_chunks", "ros_info", selector={"ros": 1}, extra="formats",
                time_unit="seconds"),
    EventFormat("ros2", (".mcap", ".db3", ROS2_FOLDER), "ROS 2 bag", "sim.eventio._rosbag",
                "ros2_writer", "iter_ros_chunks", "ros_info", selector={"ros": 2},
                extra="formats", time_unit="seconds"),
):
    register_format(_fmt)
