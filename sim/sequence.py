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
import re
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from sim._summary import summary_repr
from sim.textfile import text_lines

if TYPE_CHECKING:
    from sim.camera import Camera

__all__ = ["EXACT_TIME_S", "FLOW_INDEXES", "FRAME_CAMERA_FOLDER", "SEQUENCE_FOLDER_NEEDS",
           "FileIndex", "FrameCameraFiles", "Sequence", "describe_data_file", "frame_name",
           "json_text", "load_sequence", "read_index", "read_sequence_json", "write_index",
           "write_sequence_json"]


SEQUENCE_FOLDER_NEEDS = ("calib.txt (one line 'fx fy cx cy k1 k2 p1 p2 k3'), images.txt with "
                         "images/, groundtruth.txt (poses) and events.txt or events.h5")
"""What a sequence folder needs to be mapped (CONVENTIONS.md), as the messages say it."""


_FRAME_FOLDERS = {"png": "images", "exr": "depth"}

FLOW_INDEXES = {"forward_flow": "flow_forward.txt", "backward_flow": "flow_backward.txt",
                "motion_field": "motionfield.txt", "object_masks": "masks.txt"}
"""Index files of a simulated sequence's motion ground truth (:mod:`sim.flow`), by the
:class:`Sequence` field that reads them."""

EXACT_TIME_S = 1e-6
"""Two times this close (s) are the same instant: index files hold whole nanoseconds, and a
time that went through float arithmetic (a window's middle, a JSON round trip) is off by far
less than a microsecond; frames are never closer than that."""


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
    for number, line in text_lines(path):
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

def _plain(value: Any) -> Any:
    """``value`` with only JSON types: dicts (keys as strings), lists, str, int, float, bool,
    None. NumPy scalars and arrays become numbers and lists, paths strings, dataclasses dicts,
    sets sorted lists; a float that is NaN or infinite becomes None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _plain(dataclasses.asdict(value))
    if isinstance(value, set | frozenset):
        return _plain(sorted(value))
    if value is None or isinstance(value, str | int | float):
        return value
    raise TypeError(f"cannot write a {type(value).__name__} to JSON: {value!r}")


def json_text(document: dict) -> str:
    """The one JSON form of evfuse's files: indented by 2, keys sorted, strict JSON.

    Strict JSON has no NaN or infinity: a figure that is undefined (NaN in memory, e.g. an
    error over no pixel) is written ``null``, and the document carries its coverage beside it.
    ``sequence.json`` (:func:`write_sequence_json`) and the results of ``fusion``
    (``map.json``, ``fill.json``, ``report.json``: :func:`fusion.io.to_json`) are written
    by it.

    Parameters
    ----------
    document : dict
        Nested dicts, lists, tuples, numbers (NumPy scalars and arrays included), strings,
        None; paths, dataclasses and sets are converted.

    Returns
    -------
    str
        The text, ending in a newline.

    Raises
    ------
    TypeError
        A value that has no JSON form.
    """
    return json.dumps(_plain(document), indent=2, sort_keys=True, allow_nan=False) + "\n"


def write_sequence_json(path: str | Path, data: dict) -> None:
    """Write a JSON metadata file (``sequence.json`` and the pipeline's ``*.json``).

    Parameters
    ----------
    path : str or Path
        File to write.
    data : dict
        JSON-able data, written by :func:`json_text`: NumPy scalars and arrays, paths,
        dataclasses and sets are converted, NaN and infinity are written ``null``. Keys are
        sorted and indented by 2, so files diff cleanly.

    Raises
    ------
    ValueError
        ``data`` is not a dict, or holds a value that has no JSON form.
    """
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a dict at the top level, got {type(data).__name__}")
    try:
        text = json_text(data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: cannot write as JSON: {exc}") from None
    Path(path).write_text(text, encoding="utf-8")


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
        text = path.read_text(encoding="utf-8")
        data = json.loads(text)
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte {exc.start}); expected JSON") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}:{exc.lineno}: invalid JSON: {exc.msg} (column "
                         f"{exc.colno})") from None
    _refuse_non_finite_json(path, text)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object at the top level, got "
                         f"{type(data).__name__}")
    return data


_JSON_NON_FINITE = re.compile(r'"(?:[^"\\]|\\.)*"|(-?Infinity|NaN)')


def _refuse_non_finite_json(path: Path, text: str) -> None:
    """Python's JSON reader takes ``NaN`` and ``Infinity``, which strict JSON (and every writer
    of the project) has not: refuse them, naming the line."""
    for match in _JSON_NON_FINITE.finditer(text):
        if match[1]:
            line = text.count("\n", 0, match.start()) + 1
            raise ValueError(f"{path}:{line}: {match[1]} is not a finite number; expected "
                             "strict JSON (finite numbers)")


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

FRAME_CAMERA_FOLDER = "frame_camera"
"""Sub-folder of a two-camera rig's sequence folder holding the frame camera's files (README,
"A two-camera rig"): ``calib.txt``, ``images.txt`` + ``images/``, ``depthmaps.txt`` + ``depth/``
and ``T_event_frame.txt``."""


def _nearest(times: np.ndarray | None, t: float, tolerance: float) -> int | None:
    """Index of the time of ``times`` nearest ``t`` (the earlier on a tie), None when there is
    none within ``tolerance``."""
    if times is None or len(times) == 0:
        return None
    k = int(np.argmin(np.abs(times - t)))
    return k if abs(float(times[k]) - t) <= tolerance else None


def _finite_time(folder: Path, t: float, what: str) -> None:
    if not math.isfinite(t):
        raise ValueError(f"{folder}: {what} to t = {t!r}; expected a finite time in seconds")


@dataclass(frozen=True, eq=False)
class FileIndex:
    """The files an index lists, and their times.

    Attributes
    ----------
    times : (N,) float64 ndarray, seconds
        Read-only.
    paths : tuple of N Path
    """

    times: np.ndarray
    paths: tuple[Path, ...]

    __repr__ = summary_repr

    def at(self, t: float, tolerance: float = EXACT_TIME_S) -> Path | None:
        """The file at time ``t`` (the nearest within ``tolerance``, the earlier on a tie), or
        None when there is none that close (e.g. no forward flow at the last frame)."""
        k = _nearest(self.times, t, tolerance)
        return None if k is None else self.paths[k]


@dataclass(frozen=True, eq=False)
class FrameCameraFiles:
    """The standard frames of a sequence: a rig's frame camera, read from ``frame_camera/``,
    or the top level of a one-camera sequence (:meth:`Sequence.standard_frames`).

    Attributes
    ----------
    folder : Path
        The ``frame_camera/`` folder (the sequence folder itself for one camera).
    camera : sim.camera.Camera
        Its intrinsics from ``frame_camera/calib.txt``, its size from ``sequence.json``'s
        ``frame_camera`` record or else from its first frame.
    image_times : (N,) float64 ndarray, seconds
        Frame times (mid-exposure; a rolling shutter's middle row's), read-only.
    image_paths : tuple of N Path
        Its frames (8-bit grayscale PNG).
    depth_times : (M,) float64 ndarray, seconds, or None
        Times of its exact depth maps (simulated sequences only).
    depth_paths : tuple of M Path, or None
        Its exact z-depth (float32 EXR, metres; each row at its own time for a rolling shutter).
    T_event_frame : (4, 4) float64 ndarray
        Its pose in the event camera's frame (maps frame-camera coordinates to event-camera
        coordinates), from ``frame_camera/T_event_frame.txt``; the identity for one camera.
    shutter : {"global", "rolling"}
    readout_s : float, seconds
        Time from the first row to the last; 0 for a global shutter.
    forward_flow, backward_flow, motion_field, object_masks : FileIndex or None
        The frame camera's motion ground truth, as :class:`Sequence`'s (``frame_camera/``
        holds the same index files, each row at its own time for a rolling shutter).
    """

    folder: Path
    camera: Camera
    image_times: np.ndarray
    image_paths: tuple[Path, ...]
    depth_times: np.ndarray | None
    depth_paths: tuple[Path, ...] | None
    T_event_frame: np.ndarray
    shutter: str
    readout_s: float
    forward_flow: FileIndex | None = None
    backward_flow: FileIndex | None = None
    motion_field: FileIndex | None = None
    object_masks: FileIndex | None = None

    __repr__ = summary_repr

    def row_times(self, t_frame: float) -> np.ndarray:
        """Each row's exposure time of the frame at ``t_frame``.

        Parameters
        ----------
        t_frame : float, seconds
            The frame's time (its middle row's).

        Returns
        -------
        (H,) float64 ndarray, seconds
            ``t_frame + (r / (H - 1) - 0.5) * readout_s`` for row ``r`` (all ``t_frame`` for a
            global shutter).
        """
        height = self.camera.height
        rows = np.arange(height, dtype=np.float64)
        fraction = rows / (height - 1) - 0.5 if height > 1 else np.zeros(1)
        return float(t_frame) + fraction * self.readout_s

    def nearest_frame(self, t: float) -> int:
        """Index of the frame nearest to time ``t`` (the earlier on a tie).

        Raises
        ------
        ValueError
            ``images.txt`` lists no frames, or ``t`` is not finite.
        """
        _finite_time(self.folder, t, "nearest frame")
        k = _nearest(self.image_times, t, math.inf)
        if k is None:
            raise ValueError(f"{self.folder / 'images.txt'} lists no frames; expected at least "
                             "one standard frame")
        return k

    def nearest_depth(self, t: float, tolerance: float = EXACT_TIME_S) -> int | None:
        """Index of this camera's depth map at time ``t`` (within ``tolerance``), else None."""
        _finite_time(self.folder, t, "nearest depth map")
        return _nearest(self.depth_times, t, tolerance)


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
    forward_flow, backward_flow : FileIndex or None
        Exact optical flow of frame k to k + 1 (every frame but the last) and to k - 1 (every
        frame but the first), at frame k's time (simulated sequences; :func:`sim.flow.read_flow`).
    motion_field : FileIndex or None
        Exact image velocity at each frame time (:func:`sim.flow.read_motion_field`).
    object_masks : FileIndex or None
        Which object each pixel sees at each frame time (:func:`sim.flow.read_object_mask`).
    object_names : tuple of str or None
        The objects of the masks: mask value ``i`` is ``object_names[i - 1]``.
    velocity_path : Path or None
        ``velocity.txt`` (camera-frame twist at the pose rate; simulated sequences only), read
        by :meth:`read_velocity`.
    imu_path : Path or None
        ``imu.txt`` (ECD layout), read by :meth:`read_imu`.
    frame_camera : FrameCameraFiles or None
        A two-camera rig's frame camera (``frame_camera/``); None for one camera. The top level
        is then the event camera's, with no frames of its own.
    events_depth_txt : Path or None
        ``events_depth.txt`` (per-event depth as text), if present.
    events_labels_txt : Path or None
        ``events_labels.txt`` (per-event labels as text, :mod:`sim.event_labels`), if present.
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
    forward_flow: FileIndex | None = None
    backward_flow: FileIndex | None = None
    motion_field: FileIndex | None = None
    object_masks: FileIndex | None = None
    object_names: tuple[str, ...] | None = None
    velocity_path: Path | None = None
    imu_path: Path | None = None
    frame_camera: FrameCameraFiles | None = None
    events_depth_txt: Path | None = None
    events_labels_txt: Path | None = None

    __repr__ = summary_repr

    def read_velocity(self) -> np.ndarray | None:
        """``velocity.txt`` as (N, 7) float64 ``t vx vy vz wx wy wz`` (s, m/s, rad/s, camera
        frame, true clock), or None without one (:func:`sim.imu.read_velocity`)."""
        from sim.imu import read_velocity

        return None if self.velocity_path is None else read_velocity(self.velocity_path)

    def read_imu(self) -> np.ndarray | None:
        """``imu.txt`` as (N, 7) float64 ``t ax ay az gx gy gz`` (s, m/s^2, rad/s, IMU frame,
        the IMU's clock), or None without one (:func:`sim.imu.read_imu`)."""
        from sim.imu import read_imu

        return None if self.imu_path is None else read_imu(self.imu_path)

    def standard_frames(self) -> FrameCameraFiles:
        """The frames the pipeline fills and scores in: the frame camera's for a rig, else the
        top level's (the same sensor as the events: identity ``T_event_frame``, global
        shutter). The one place that says where "the standard frame nearest t" comes from."""
        return self.frame_camera if self.frame_camera is not None else self._own_frames()

    def _own_frames(self) -> FrameCameraFiles:
        """The top level's frames and depth maps (the event camera's own, for a rig: none)."""
        return FrameCameraFiles(folder=self.folder, camera=self.camera,
                                image_times=self.image_times, image_paths=self.image_paths,
                                depth_times=self.depth_times, depth_paths=self.depth_paths,
                                T_event_frame=np.eye(4), shutter="global", readout_s=0.0,
                                **{field: getattr(self, field) for field in FLOW_INDEXES})

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

    def event_labels(self, t0_ns: int | None = None, t1_ns: int | None = None
                     ) -> np.ndarray | None:
        """Events in ``[t0_ns, t1_ns)`` with their labels (simulated sequences): ``cause``
        (uint8: 0 signal, 1 shot / background, 2 leak, 3 hot pixel) and ``object_id`` (int32:
        the index of the object the pixel sees in the scene file's order, -1 none; its name is
        ``metadata["events"]["labels"]["objects"][str(object_id)]``).

        From ``events.h5`` (``events/cause``, ``events/object_id``) or else ``events.txt`` /
        ``events_depth.txt`` with ``events_labels.txt``; None when the folder has no labels (a
        real recording, or a run without motion truth). See
        :func:`sim.event_labels.read_event_labels`.
        """
        from sim.event_labels import read_event_labels

        texts = (self.events_txt, self.events_depth_txt) if self.events_labels_txt else ()
        for path in (self.events_h5, *texts):
            found = None if path is None else read_event_labels(path, t0_ns, t1_ns)
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
        return self._own_frames().nearest_frame(t)

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
        return self._own_frames().nearest_depth(t, tolerance)


def _size_from_metadata(path: Path, metadata: dict, key: str = "camera"
                        ) -> tuple[int, int] | None:
    camera = metadata.get(key)
    if not isinstance(camera, dict) or "width" not in camera or "height" not in camera:
        return None
    width, height = camera["width"], camera["height"]
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise ValueError(f"{path}: {key}.{name} must be a positive integer, got {value!r}")
    return width, height


def _size_from_events(path: Path) -> tuple[int, int] | None:
    """The sensor size an ``events.h5`` states (its ``width``/``height``), or None."""
    from sim.eventio._read import _h5_info

    return _h5_info(path)["sensor_size"]


def _size_from_frame(path: Path) -> tuple[int, int]:
    frame = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if frame is None:
        raise ValueError(f"cannot read frame {path} as an image (needed for the sensor size)")
    height, width = frame.shape[:2]
    return width, height


def _read_depth_index(folder: Path) -> tuple[np.ndarray | None, tuple[Path, ...] | None]:
    """``depthmaps.txt`` of ``folder``: read-only times and the depth maps' paths, or
    ``(None, None)`` when there is none (a real recording)."""
    if not (folder / "depthmaps.txt").is_file():
        return None, None
    depth_times, depth_names = read_index(folder / "depthmaps.txt")
    depth_times.setflags(write=False)
    return depth_times, tuple(folder / name for name in depth_names)


def _read_extrinsic(path: Path) -> np.ndarray:
    """``T_event_frame.txt``: one line ``px py pz qx qy qz qw`` -> (4, 4) float64."""
    from sim.se3 import make_pose, quat_to_rot
    from sim.textfile import parse_floats

    form = "one line 'px py pz qx qy qz qw' (metres, quaternion scalar last)"
    if not path.is_file():
        raise ValueError(f"{path} does not exist; expected {form}")
    lines = [(n, line.split()) for n, line in text_lines(path) if line.strip()]
    if len(lines) != 1 or len(lines[0][1]) != 7:
        where = f"{path}:{lines[1][0] if len(lines) > 1 else lines[0][0]}" if lines else path
        raise ValueError(f"{where}: expected {form}")
    number, fields = lines[0]
    values = parse_floats(fields, path, number, form)
    try:
        rotation = quat_to_rot(values[3:])
    except ValueError as exc:
        raise ValueError(f"{path}:{number}: {exc}") from None
    return make_pose(rotation, values[:3])


def _load_frame_camera(folder: Path, metadata: dict | None) -> FrameCameraFiles:
    """Read ``folder`` = a sequence's ``frame_camera/`` (see :class:`FrameCameraFiles`)."""
    from sim.camera import read_calib

    for required in ("calib.txt", "images.txt", "T_event_frame.txt"):
        if not (folder / required).is_file():
            raise ValueError(f"frame-camera folder {folder} has no {required}; it needs "
                             "calib.txt, images.txt with images/ and T_event_frame.txt")
    image_times, image_names = read_index(folder / "images.txt")
    image_paths = tuple(folder / name for name in image_names)
    record = (metadata or {}).get("frame_camera")
    size = _size_from_metadata(folder.parent / "sequence.json",
                               {"camera": record}) if isinstance(record, dict) else None
    if size is None:
        if not image_paths:
            raise ValueError(f"{folder / 'images.txt'} lists no frames and sequence.json has "
                             "no frame_camera.width/height: the frame camera's size is unknown")
        size = _size_from_frame(image_paths[0])
    camera = read_calib(folder / "calib.txt", *size)
    depth_times, depth_paths = _read_depth_index(folder)
    image_times.setflags(write=False)
    record = record if isinstance(record, dict) else {}
    shutter = record.get("shutter", "global")
    readout = record.get("readout_s", 0.0)
    if shutter not in ("global", "rolling"):
        raise ValueError(f"{folder.parent / 'sequence.json'}: frame_camera.shutter must be "
                         f"'global' or 'rolling', got {shutter!r}")
    if (isinstance(readout, bool) or not isinstance(readout, int | float)
            or not math.isfinite(readout) or readout < 0):
        raise ValueError(f"{folder.parent / 'sequence.json'}: frame_camera.readout_s must be a "
                         f"number of seconds >= 0, got {readout!r}")
    extrinsic = _read_extrinsic(folder / "T_event_frame.txt")
    extrinsic.setflags(write=False)
    return FrameCameraFiles(folder=folder, camera=camera, image_times=image_times,
                            image_paths=image_paths, depth_times=depth_times,
                            depth_paths=depth_paths, T_event_frame=extrinsic, shutter=shutter,
                            readout_s=float(readout), **_flow_indexes(folder))


def load_sequence(folder: str | Path) -> Sequence:
    """Read a sequence folder (CONVENTIONS.md): a real ECD folder or a simulated one.

    Parameters
    ----------
    folder : str or Path
        Folder with at least ``calib.txt`` and ``images.txt`` (and the frames it lists).

    Returns
    -------
    Sequence
        Optional parts the folder lacks (depth, ground truth, events, ``sequence.json``, a
        rig's ``frame_camera/``) are ``None``. ``images.txt`` may list no frames (a rig's
        event camera has none) when ``sequence.json`` gives ``camera.width/height``.

    Raises
    ------
    ValueError
        The folder, ``calib.txt`` or ``images.txt`` is missing; an index or JSON file is
        malformed or lists a missing file; or the sensor size cannot be found (no
        ``sequence.json`` with ``camera.width/height``, no frame to read it from and no
        ``events.h5`` that states it).
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
    if size is None and not image_paths and (folder / "events.h5").is_file():
        size = _size_from_events(folder / "events.h5")    # a recording of events alone
    if size is None:
        if not image_paths:
            raise ValueError(f"{folder / 'images.txt'} lists no frames and there is no "
                             "sequence.json with camera.width/height: the sensor size is unknown")
        size = _size_from_frame(image_paths[0])
    width, height = size
    from sim.camera import read_calib  # lazily: sim.camera is not needed by the writers

    camera = read_calib(folder / "calib.txt", width, height)

    depth_times, depth_paths = _read_depth_index(folder)
    image_times.setflags(write=False)

    def optional(name: str) -> Path | None:
        return folder / name if (folder / name).is_file() else None

    masks = (metadata or {}).get("object_masks") or {}
    if not isinstance(masks, dict):
        raise ValueError(f"{folder / 'sequence.json'}: object_masks is {masks!r}; expected an "
                         "object with the key objects")
    names = masks.get("objects")
    if names is not None and not isinstance(names, list):
        raise ValueError(f"{folder / 'sequence.json'}: object_masks.objects is {names!r}; "
                         "expected a list of object names")
    frame_camera = None
    if (folder / FRAME_CAMERA_FOLDER).is_dir():
        frame_camera = _load_frame_camera(folder / FRAME_CAMERA_FOLDER, metadata)
    return Sequence(folder=folder, camera=camera, image_times=image_times,
                    image_paths=image_paths, depth_times=depth_times, depth_paths=depth_paths,
                    groundtruth_path=optional("groundtruth.txt"),
                    events_txt=optional("events.txt"), events_h5=optional("events.h5"),
                    metadata=metadata, **_flow_indexes(folder),
                    object_names=None if names is None else tuple(str(n) for n in names),
                    velocity_path=optional("velocity.txt"), imu_path=optional("imu.txt"),
                    frame_camera=frame_camera,
                    events_depth_txt=optional("events_depth.txt"),
                    events_labels_txt=optional("events_labels.txt"))


def _flow_indexes(folder: Path) -> dict[str, FileIndex | None]:
    """The motion ground truth's indexes in ``folder`` (:data:`FLOW_INDEXES`), by field."""
    return {field: _file_index(folder / name) for field, name in FLOW_INDEXES.items()}


def _file_index(path: Path) -> FileIndex | None:
    """The index at ``path`` (its files checked), or None when there is none."""
    if not path.is_file():
        return None
    times, names = read_index(path)
    times.setflags(write=False)
    return FileIndex(times, tuple(path.parent / name for name in names))
