"""The sequence folder of CONVENTIONS.md: write it atomically, read it back.

The layout is the Event-Camera Dataset's (``calib.txt``, ``images.txt`` + ``images/``,
``groundtruth.txt``, ``events.txt``), plus, for simulated sequences only, ``depthmaps.txt`` +
``depth/`` and ``sequence.json``. :func:`load_sequence` reads a real ECD folder and a
simulated one alike; what a folder lacks comes back as ``None``.

Index files (``images.txt``, ``depthmaps.txt``) hold one ``t[s] relpath`` line per file, with
t written to 9 decimals (whole nanoseconds) and strictly increasing.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import uuid
from collections.abc import Iterator
from collections.abc import Sequence as SequenceABC
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

if TYPE_CHECKING:
    from sim.camera import Camera

__all__ = ["EXACT_TIME_S", "SEQUENCE_FOLDER_NEEDS", "Sequence", "atomic_output_dir",
           "check_output_dir", "describe_data_file", "frame_name", "load_sequence",
           "partial_dir", "read_index", "read_sequence_json", "write_index",
           "write_sequence_json"]

SEQUENCE_FOLDER_NEEDS = ("calib.txt (one line 'fx fy cx cy k1 k2 p1 p2 k3'), images.txt with "
                         "images/, groundtruth.txt (poses) and events.txt or events.h5")
"""What a sequence folder needs to be mapped (CONVENTIONS.md), as the messages say it."""

PARTIAL_SUFFIX = ".partial"
"""Suffix of the folder a sequence is written into before it is complete."""

_FRAME_FOLDERS = {"png": "images", "exr": "depth"}

EXACT_TIME_S = 1e-6
"""Two times this close (s) are the same instant: index files hold whole nanoseconds, and a
time that went through float arithmetic (a window's middle, a JSON round trip) is off by far
less than a microsecond; frames are never closer than that."""


# --- atomic output ---------------------------------------------------------------------------

def _is_nonempty_dir(path: Path) -> bool:
    with os.scandir(path) as entries:
        return any(True for _ in entries)


def check_output_dir(out: str | Path, overwrite: bool = False) -> None:
    """Raise ValueError if :func:`atomic_output_dir` would refuse ``out`` (call it early, before
    long work, to fail fast)."""
    out = Path(out)
    if not out.exists() and not out.is_symlink():
        return
    if not out.is_dir() or out.is_symlink():
        raise ValueError(f"output {out} exists and is not a folder (a file or a link); expected "
                         "a folder or a new path (anything else is never replaced)")
    if not overwrite and _is_nonempty_dir(out):
        raise ValueError(f"output folder {out} exists and is not empty; pass --overwrite "
                         "(overwrite=True) to replace it, or choose another path")


def partial_dir(out: str | Path) -> Path:
    """The folder :func:`atomic_output_dir` writes ``out`` into: ``<out>.partial``."""
    out = Path(out)
    return out.with_name(out.name + PARTIAL_SUFFIX)


@contextmanager
def atomic_output_dir(out: str | Path, overwrite: bool = False, *,
                      resume: bool = False) -> Iterator[Path]:
    """Write a folder under a temporary name and rename it into place when complete.

    Parameters
    ----------
    out : str or Path
        The folder to create. Its parents are created if needed.
    overwrite : bool
        Replace an existing non-empty ``out``. The old folder is removed only once the new one
        is complete: it is renamed aside, the new one renamed in, then the old one deleted.
        An existing empty folder is replaced without ``overwrite``.
    resume : bool
        Keep the ``.partial`` folder an earlier, interrupted run left, with its contents, for
        the body to continue (it is created if there is none). The body must check that what
        it holds is what it expects.

    Yields
    ------
    Path
        The folder ``<out.parent>/<out.name>.partial`` to write into: fresh and empty (a
        stale one from an earlier failed run is removed first) unless ``resume``.

    Raises
    ------
    ValueError
        ``out`` exists and is not a folder, or is a non-empty folder and ``overwrite`` is
        false (checked on entry, and again before the rename).

    Notes
    -----
    If the body raises, the ``.partial`` folder is left for inspection or for a run with
    ``resume`` to continue (its name cannot be mistaken for a complete result), ``out`` is
    untouched, and the exception propagates.
    ``out`` itself is never seen half-written.
    """
    out = Path(out)
    if not out.name:
        raise ValueError(f"output path {str(out)!r} has no folder name")
    check_output_dir(out, overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = partial_dir(out)
    if partial.is_symlink() or partial.is_file():
        partial.unlink()
    elif partial.exists() and not resume:
        shutil.rmtree(partial)
    partial.mkdir(exist_ok=resume)
    yield partial
    check_output_dir(out, overwrite)
    old = None
    if out.exists():
        old = out.with_name(f"{out.name}.old-{uuid.uuid4().hex[:12]}")
        out.rename(old)
    try:
        partial.rename(out)
    except BaseException:
        if old is not None:
            old.rename(out)
        raise
    if old is not None:
        shutil.rmtree(old)


# --- index files -----------------------------------------------------------------------------

def frame_name(index: int, ext: str) -> str:
    """Relative file name of frame ``index`` in a sequence folder.

    Parameters
    ----------
    index : int
        Frame number, >= 0.
    ext : {"png", "exr"}
        ``"png"`` for a standard-camera frame (``images/``), ``"exr"`` for a depth map
        (``depth/``); a leading dot is allowed.

    Returns
    -------
    str
        e.g. ``"images/frame_00000012.png"`` or ``"depth/frame_00000012.exr"`` (always with
        ``/``, as written into the index files).
    """
    ext = ext.lower().lstrip(".")
    if ext not in _FRAME_FOLDERS:
        raise ValueError(f"frame extension must be one of {sorted(_FRAME_FOLDERS)}, got {ext!r}")
    if isinstance(index, bool) or not isinstance(index, int | np.integer) or index < 0:
        raise ValueError(f"frame index must be an integer >= 0, got {index!r}")
    return f"{_FRAME_FOLDERS[ext]}/frame_{int(index):08d}.{ext}"


def write_index(path: str | Path, times: np.ndarray, relpaths: SequenceABC[str]) -> None:
    """Write an index file (``images.txt``, ``depthmaps.txt``): one ``t[s] relpath`` a line.

    Parameters
    ----------
    path : str or Path
        File to write.
    times : (N,) float ndarray, seconds
        Strictly increasing, finite; written with 9 decimals (nanoseconds).
    relpaths : sequence of N str
        File names relative to the index's folder, without whitespace.

    Raises
    ------
    ValueError
        Lengths differ, a time is not finite, times are not strictly increasing (after rounding
        to nanoseconds), or a name is empty or contains whitespace.
    """
    times = np.asarray(times, dtype=np.float64)
    if times.ndim != 1:
        raise ValueError(f"{path}: times must be 1-D, got shape {times.shape}")
    relpaths = list(relpaths)
    if len(relpaths) != len(times):
        raise ValueError(f"{path}: {len(times)} times but {len(relpaths)} file names; expected "
                         "one name per time")
    if not np.isfinite(times).all():
        raise ValueError(f"{path}: times must be finite, got {times[~np.isfinite(times)][:3]}")
    texts = [f"{t:.9f}" for t in times]
    rounded = np.array([float(s) for s in texts])
    bad = np.flatnonzero(np.diff(rounded) <= 0)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{path}: times must be strictly increasing (to the nanosecond), got "
                         f"{texts[i]} then {texts[i + 1]} at entries {i} and {i + 1}")
    for name in relpaths:
        if not isinstance(name, str) or not name or any(c.isspace() for c in name):
            raise ValueError(f"{path}: file names must be non-empty without whitespace, "
                             f"got {name!r}")
    lines = [f"{t} {name}\n" for t, name in zip(texts, relpaths, strict=True)]
    Path(path).write_text("".join(lines), encoding="utf-8")


def read_index(path: str | Path, check_files: bool = True) -> tuple[np.ndarray, list[str]]:
    """Read an index file (``images.txt``, ``depthmaps.txt``).

    Blank lines and lines starting with ``#`` are skipped.

    Parameters
    ----------
    path : str or Path
        Index file; the listed names are relative to its folder.
    check_files : bool
        Check that every listed file exists.

    Returns
    -------
    times : (N,) float64 ndarray, seconds
        Strictly increasing.
    relpaths : list of N str
        Names as written (relative to the index's folder).

    Raises
    ------
    ValueError
        The file is missing, or a line (named ``file:line``) does not have 2 columns, has a
        time that is not a finite number, has a time not after the previous one, or names a
        file that does not exist.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"index file {path} does not exist")
    times: list[float] = []
    relpaths: list[str] = []
    with path.open(encoding="utf-8") as handle:
        for number, line in enumerate(handle, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            where = f"{path}:{number}"
            columns = text.split()
            if len(columns) != 2:
                raise ValueError(f"{where}: expected 2 columns 't[s] relpath', got "
                                 f"{len(columns)}: {text!r}")
            try:
                t = float(columns[0])
            except ValueError:
                raise ValueError(f"{where}: expected a time in seconds, got "
                                 f"{columns[0]!r}") from None
            if not math.isfinite(t):
                raise ValueError(f"{where}: expected a finite time in seconds, got {columns[0]!r}")
            if times and t <= times[-1]:
                raise ValueError(f"{where}: time {columns[0]} is not after the previous "
                                 f"line's {times[-1]:.9f}; expected strictly increasing times")
            if check_files and not (path.parent / columns[1]).is_file():
                raise ValueError(f"{where}: listed file {path.parent / columns[1]} does not "
                                 "exist")
            times.append(t)
            relpaths.append(columns[1])
    return np.array(times, dtype=np.float64), relpaths


# --- sequence.json ---------------------------------------------------------------------------

def _to_json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    if isinstance(value, set | frozenset):
        return sorted(value)
    raise TypeError(f"cannot write a {type(value).__name__} to JSON: {value!r}")


def write_sequence_json(path: str | Path, data: dict) -> None:
    """Write a JSON metadata file (``sequence.json`` and the pipeline's ``*.json``).

    Parameters
    ----------
    path : str or Path
        File to write.
    data : dict
        JSON-able data; NumPy scalars and arrays, paths, dataclasses and sets are converted.
        Keys are sorted and indented by 2, so files diff cleanly.

    Raises
    ------
    ValueError
        ``data`` is not a dict, holds a value that has no JSON form, or holds NaN or inf
        (strict JSON has neither).
    """
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a dict at the top level, got {type(data).__name__}")
    try:
        text = json.dumps(data, sort_keys=True, indent=2, default=_to_json, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: cannot write as JSON: {exc}") from None
    Path(path).write_text(text + "\n", encoding="utf-8")


def read_sequence_json(path: str | Path) -> dict:
    """Read a JSON metadata file written by :func:`write_sequence_json`.

    Returns
    -------
    dict

    Raises
    ------
    ValueError
        The file is missing, is not valid JSON (the message names ``file:line``), or its top
        level is not an object.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"JSON file {path} does not exist")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}:{exc.lineno}: invalid JSON: {exc.msg} (column "
                         f"{exc.colno})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object at the top level, got "
                         f"{type(data).__name__}")
    return data


# --- what a file is ---------------------------------------------------------------------------

_SEQUENCE_FILES = {
    "calib.txt": "the calibration of a sequence folder",
    "images.txt": "the frame index of a sequence folder",
    "depthmaps.txt": "the depth-map index of a sequence folder",
    "groundtruth.txt": "the poses of a sequence folder",
    "imu.txt": "the IMU readings of a sequence folder",
    "sequence.json": "the metadata of a sequence folder",
}
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def describe_data_file(path: str | Path) -> str | None:
    """What a file of the project's data formats is, by its name and first bytes; else None.

    Used to say "this is an event file" instead of a parser's complaint when such a file is
    given where a scene file is expected.

    Parameters
    ----------
    path : str or Path
        An existing file.

    Returns
    -------
    str or None
        e.g. ``"an event file (HDF5, DSEC layout)"``, ``"an event file (ECD text, t x y p)"``,
        ``"the poses of a sequence folder"``; None for anything else (a scene file among them).
    """
    path = Path(path)
    try:
        with path.open("rb") as handle:
            head = handle.read(4096)
    except OSError:
        return None
    if head.startswith(_HDF5_SIGNATURE) or path.suffix.lower() in (".h5", ".hdf5"):
        return "an event file (HDF5, DSEC layout)"
    if path.name in _SEQUENCE_FILES:
        return _SEQUENCE_FILES[path.name]
    for line in head.decode("utf-8", errors="replace").splitlines():
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        try:
            [float(f) for f in fields]
        except ValueError:
            return None
        return "an event file (ECD text, t x y p)" if len(fields) == 4 else None
    return None


# --- a whole sequence ------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Sequence:
    """A sequence folder, read by :func:`load_sequence`.

    Attributes
    ----------
    folder : Path
        The sequence folder.
    camera : sim.camera.Camera
        Intrinsics and distortion from ``calib.txt``, with the sensor size (``width``,
        ``height``) from ``sequence.json`` or else from the first frame.
    image_times : (N,) float64 ndarray, seconds
        Standard-camera frame times (read-only).
    image_paths : tuple of N Path
        Frame files (8-bit grayscale PNG).
    depth_times : (M,) float64 ndarray, seconds, or None
        Depth-map times (simulated sequences only).
    depth_paths : tuple of M Path, or None
        Depth maps (float32 EXR, channel ``Z``, metres).
    groundtruth_path : Path or None
        ``groundtruth.txt`` (T_world_camera), if present.
    events_txt : Path or None
        ``events.txt``, if present.
    events_h5 : Path or None
        ``events.h5``, if present.
    metadata : dict or None
        ``sequence.json`` (simulated sequences only).
    events_depth_txt : Path or None
        ``events_depth.txt`` (per-event depth as text), if present.
    """

    folder: Path
    camera: Camera
    image_times: np.ndarray
    image_paths: tuple[Path, ...]
    depth_times: np.ndarray | None
    depth_paths: tuple[Path, ...] | None
    groundtruth_path: Path | None
    events_txt: Path | None
    events_h5: Path | None
    metadata: dict | None
    events_depth_txt: Path | None = None

    def event_depth(self, t0_ns: int | None = None, t1_ns: int | None = None
                    ) -> np.ndarray | None:
        """Events in ``[t0_ns, t1_ns)`` with their exact depth and flag (simulated sequences).

        From ``events.h5`` (``events/depth``) or else ``events_depth.txt``; None when the
        folder has neither (a real recording). See :func:`sim.event_depth.read_event_depth`.
        """
        from sim.event_depth import read_event_depth

        for path in (self.events_h5, self.events_depth_txt):
            found = None if path is None else read_event_depth(path, t0_ns, t1_ns)
            if found is not None:
                return found
        return None

    def nearest_frame(self, t: float) -> int:
        """Index of the standard frame nearest to time ``t``.

        Parameters
        ----------
        t : float, seconds

        Returns
        -------
        int
            Index into ``image_times`` / ``image_paths``; on a tie (``t`` half-way between two
            frames) the earlier frame.

        Raises
        ------
        ValueError
            ``images.txt`` lists no frames, or ``t`` is not finite.
        """
        if not math.isfinite(t):
            raise ValueError(f"{self.folder}: nearest frame to t = {t!r}; expected a finite "
                             "time in seconds")
        if len(self.image_times) == 0:
            raise ValueError(f"{self.folder / 'images.txt'} lists no frames; expected at least "
                             "one standard frame")
        return int(np.argmin(np.abs(self.image_times - t)))

    def nearest_depth(self, t: float, tolerance: float = EXACT_TIME_S) -> int | None:
        """Index of the depth map at time ``t``, if there is one within ``tolerance``.

        Parameters
        ----------
        t : float, seconds
        tolerance : float, seconds
            Largest distance between ``t`` and the depth map's time (default
            :data:`EXACT_TIME_S`: the same instant); ``math.inf`` for the nearest whatever its
            distance.

        Returns
        -------
        int or None
            Index into ``depth_times`` / ``depth_paths`` of the nearest depth map (the earlier
            on a tie), or None when the sequence has no depth maps (a real recording) or the
            nearest is farther than ``tolerance``.
        """
        if not math.isfinite(t):
            raise ValueError(f"{self.folder}: nearest depth map to t = {t!r}; expected a finite "
                             "time in seconds")
        if self.depth_times is None or len(self.depth_times) == 0:
            return None
        k = int(np.argmin(np.abs(self.depth_times - t)))
        return k if abs(float(self.depth_times[k]) - t) <= tolerance else None


def _size_from_metadata(path: Path, metadata: dict) -> tuple[int, int] | None:
    camera = metadata.get("camera")
    if not isinstance(camera, dict) or "width" not in camera or "height" not in camera:
        return None
    width, height = camera["width"], camera["height"]
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise ValueError(f"{path}: camera.{name} must be a positive integer, got {value!r}")
    return width, height


def _size_from_frame(path: Path) -> tuple[int, int]:
    frame = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if frame is None:
        raise ValueError(f"cannot read frame {path} as an image (needed for the sensor size)")
    height, width = frame.shape[:2]
    return width, height


def load_sequence(folder: str | Path) -> Sequence:
    """Read a sequence folder (CONVENTIONS.md): a real ECD folder or a simulated one.

    Parameters
    ----------
    folder : str or Path
        Folder with at least ``calib.txt`` and ``images.txt`` (and the frames it lists).

    Returns
    -------
    Sequence
        Optional parts the folder lacks (depth, ground truth, events, ``sequence.json``) are
        ``None``.

    Raises
    ------
    ValueError
        The folder, ``calib.txt`` or ``images.txt`` is missing; an index or JSON file is
        malformed or lists a missing file; or the sensor size cannot be found (no
        ``sequence.json`` with ``camera.width/height`` and no frame to read it from).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"sequence folder {folder} does not exist or is not a folder")
    for required in ("calib.txt", "images.txt"):
        if not (folder / required).is_file():
            raise ValueError(f"sequence folder {folder} has no {required}; a sequence folder "
                             f"needs {SEQUENCE_FOLDER_NEEDS}")
    image_times, image_names = read_index(folder / "images.txt")
    image_paths = tuple(folder / name for name in image_names)

    metadata = None
    size = None
    if (folder / "sequence.json").is_file():
        metadata = read_sequence_json(folder / "sequence.json")
        size = _size_from_metadata(folder / "sequence.json", metadata)
    if size is None:
        if not image_paths:
            raise ValueError(f"{folder / 'images.txt'} lists no frames and there is no "
                             "sequence.json with camera.width/height: the sensor size is unknown")
        size = _size_from_frame(image_paths[0])
    width, height = size
    from sim.camera import read_calib  # lazily: sim.camera is not needed by the writers

    camera = read_calib(folder / "calib.txt", width, height)

    depth_times = depth_paths = None
    if (folder / "depthmaps.txt").is_file():
        depth_times, depth_names = read_index(folder / "depthmaps.txt")
        depth_paths = tuple(folder / name for name in depth_names)
        depth_times.setflags(write=False)
    image_times.setflags(write=False)

    def optional(name: str) -> Path | None:
        return folder / name if (folder / name).is_file() else None

    return Sequence(folder=folder, camera=camera, image_times=image_times,
                    image_paths=image_paths, depth_times=depth_times, depth_paths=depth_paths,
                    groundtruth_path=optional("groundtruth.txt"),
                    events_txt=optional("events.txt"), events_h5=optional("events.h5"),
                    metadata=metadata, events_depth_txt=optional("events_depth.txt"))
