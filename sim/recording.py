"""Recordings given as one file: the one place where an event file (AEDAT4, Prophesee RAW, and
any format that registers an unpacker, such as a bag) becomes the sequence folder the pipeline
reads (:func:`recording_folder`), and where a sequence folder becomes one file
(:func:`write_sequence_file`).

A ROS 2 bag is a folder (``metadata.yaml``), read as one recording like a file.
A one-file recording is unpacked once into a cache folder outside its input (inputs are never
written next to): ``$EVFUSE_CACHE`` or ``~/.cache/evfuse``, under ``recordings/<key>``, where
the key hashes the file's absolute path, size and modification time and the contents of the
calibration and pose files given. The folder has the ECD layout (CONVENTIONS.md): ``calib.txt``
(the ``calib`` given: a RAW or AEDAT4 file holds no intrinsics), ``events.h5`` (the events,
exact: the file's microseconds), ``images.txt`` and ``images/`` (the file's frames, if any),
``imu.txt`` (its IMU samples, if any) and ``groundtruth.txt`` (the ``poses`` given, else the
file's pose stream, if any). It
is written as ``<key>.partial`` and renamed when complete, so an interrupted unpacking is never
read.

A format adds what it holds beyond events with :func:`register_unpacker` (``name`` of its
:class:`sim.eventio._formats.EventFormat`, and a function ``(src, folder) -> None`` that writes
the folder's ``images.txt``/``images/``, ``imu.txt``, ``groundtruth.txt`` or ``calib.txt``).
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sim.validation import ParameterError

__all__ = ["cache_root", "is_recording_file", "recording_folder", "register_unpacker",
           "write_sequence_file"]

_UNPACKERS: dict[str, Callable[..., None]] = {}


def register_unpacker(format_name: str, unpack: Callable[[Path, Path], None]) -> None:
    """Let ``format_name``'s files bring more than events into the unpacked folder."""
    _UNPACKERS[format_name] = unpack


def cache_root() -> Path:
    """Where unpacked recordings are kept: ``$EVFUSE_CACHE`` or ``~/.cache/evfuse``."""
    return Path(os.environ.get("EVFUSE_CACHE") or Path.home() / ".cache" / "evfuse")


def is_recording_file(path: str | Path) -> bool:
    """Whether ``path`` is a recording given as one file: a file of a registered event format
    other than ECD text and the DSEC layout (those are a sequence folder's events, and a command
    given one says to give its folder), or a ROS 2 bag folder."""
    from sim.eventio._formats import event_formats, is_bag_folder

    path = Path(path)
    suffixes = {s for f in event_formats() if f.name not in ("txt", "h5") for s in f.suffixes}
    return (path.is_file() and path.suffix.lower() in suffixes) or is_bag_folder(path)


def _digest(*parts: str | bytes) -> str:
    hasher = hashlib.sha256()
    for part in parts:
        hasher.update(part if isinstance(part, bytes) else part.encode())
        hasher.update(b"\0")
    return hasher.hexdigest()[:20]


def recording_folder(path: str | Path, *, calib: str | Path | None = None,
                     poses: str | Path | None = None, cache: str | Path | None = None,
                     topic: str | None = None) -> Path:
    """The sequence folder of a recording.

    Parameters
    ----------
    path : str or Path
        A sequence folder (returned as it is) or one event file of a registered format.
    calib : str or Path, optional
        ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``) of the event camera. Required for one
        file (a RAW or AEDAT4 file holds no intrinsics) unless its format's unpacker writes one.
    poses : str or Path, optional
        ``groundtruth.txt`` (``t px py pz qx qy qz qw``, T_world_camera) of the recording.
    cache : str or Path, optional
        Cache folder (default :func:`cache_root`).
    topic : str, optional
        A bag's event topic (default: its one ``dvs_msgs/EventArray`` topic; a bag with several
        needs it); its frames, camera, poses and IMU are the topics in its namespace.

    Returns
    -------
    Path
        A folder :func:`sim.sequence.load_sequence` reads.

    Raises
    ------
    ValueError
        ``calib``/``poses`` given with a folder; no calibration for a file (a
        :class:`sim.validation.ParameterError` naming ``{calib}``); the file is malformed (as
        :func:`sim.eventio.iter_event_chunks`, naming the file).
    """
    from sim.eventio import convert_events
    from sim.eventio._formats import format_for, is_bag_folder

    path = Path(path)
    literal = ParameterError.literal
    if path.is_dir() and not is_bag_folder(path):
        if calib is not None or poses is not None:
            raise ParameterError(f"{literal(path)} is a sequence folder, which has its own "
                                 "calib.txt and groundtruth.txt; expected {calib} and {poses} "
                                 "only with a recording given as one file",
                                 calib="calib", poses="poses")
        return path
    if not (path.is_file() or is_bag_folder(path)):
        raise ValueError(f"recording {path} does not exist; expected a sequence folder or an "
                         "event file")
    fmt = format_for(path)
    extra = [Path(p) for p in (calib, poses) if p is not None]
    for given in extra:
        if not given.is_file():
            raise ValueError(f"{given} does not exist; expected a text file")
    stat = path.stat()
    is_bag = fmt.name in ("ros1", "ros2")
    if topic is not None and not is_bag:
        raise ParameterError(f"{literal(path)} is a {fmt.title} file, which has no topics; "
                             "expected {topic} only with a ROS bag", topic="topic")
    key = _digest(str(path.resolve()), str(stat.st_size), str(stat.st_mtime_ns),
                  *(p.read_bytes() for p in extra), "calib" if calib else "", "poses" if poses
                  else "", f"topic {topic}" if topic else "")
    folder = Path(cache or cache_root()) / "recordings" / f"{path.stem}-{key}"
    if folder.is_dir():
        return folder
    partial = folder.with_name(folder.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    try:
        unpack = _UNPACKERS.get(fmt.name)
        if unpack is not None:
            unpack(path, partial, **({"topic": topic} if is_bag else {}))
        if calib is not None:
            shutil.copyfile(calib, partial / "calib.txt")
        if not (partial / "calib.txt").is_file():
            raise ParameterError(f"{literal(path)}: a {fmt.title} file holds no intrinsics; "
                                 "expected {calib} (a calib.txt: fx fy cx cy k1 k2 p1 p2 k3)",
                                 calib="calib=")
        if poses is not None:
            shutil.copyfile(poses, partial / "groundtruth.txt")
        if not (partial / "images.txt").is_file():
            (partial / "images.txt").write_text("")
        convert_events(path, partial / "events.h5",
                       src_options={"topic": topic} if is_bag and topic else None)
        os.replace(partial, folder)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return folder


def _unpack_aedat4(src: Path, folder: Path) -> None:
    """An AEDAT4 file's frames (``images/``, ``images.txt``), IMU (``imu.txt``) and poses
    (``groundtruth.txt``)."""
    import cv2

    from sim.eventio._aedat4 import read_aedat4_frames, read_aedat4_imu, read_aedat4_poses
    from sim.sequence import frame_name, write_index

    times, names = [], []
    for index, (t_ns, image) in enumerate(read_aedat4_frames(src)):
        name = frame_name(index, "png")
        (folder / "images").mkdir(exist_ok=True)
        if not cv2.imwrite(str(folder / name), image):
            raise ValueError(f"{folder / name}: cannot be written")
        times.append(t_ns * 1e-9)
        names.append(name)
    if names:
        write_index(folder / "images.txt", np.array(times), names)
    imu = read_aedat4_imu(src)
    if len(imu):
        np.savetxt(folder / "imu.txt", imu, fmt="%.9f")
    poses = read_aedat4_poses(src)          # replaced by the poses given, if any
    if len(poses):
        np.savetxt(folder / "groundtruth.txt", poses, fmt=["%.6f"] + ["%.9g"] * 7)


register_unpacker("aedat4", _unpack_aedat4)


def _unpack_bag(src: Path, folder: Path, topic: str | None = None) -> None:
    """A bag's camera info (``calib.txt``), frames, poses and IMU, each topic found by its
    message type, in the namespace of the event topic ``topic`` where given
    (:func:`sim.sequence_bag.unpack_bag`)."""
    from sim.sequence_bag import BagRecording, unpack_bag

    unpack_bag(BagRecording(src, events_topic=topic), folder)


register_unpacker("ros1", _unpack_bag)
register_unpacker("ros2", _unpack_bag)


def write_sequence_file(folder: str | Path, dst: str | Path) -> tuple[int, int, int]:
    """Write a sequence folder as one AEDAT4 file: events, frames, IMU (``imu.txt``) and poses
    (``groundtruth.txt``, a pose stream of float32 values).

    Parameters
    ----------
    folder : str or Path
        A sequence folder (:func:`sim.sequence.load_sequence`) with ``events.h5`` or
        ``events.txt``.
    dst : str or Path
        ``*.aedat4``, written atomically.

    Returns
    -------
    (int, int, int)
        Events, frames and IMU samples written.

    Raises
    ------
    ValueError
        ``dst`` is not ``.aedat4``, or the folder has no events.
    """
    from sim.eventio import iter_event_chunks
    from sim.eventio._aedat4 import write_sequence_aedat4
    from sim.sequence import load_sequence

    dst = Path(dst)
    if dst.suffix.lower() != ".aedat4":
        raise ValueError(f"{dst}: a whole sequence is written as one .aedat4 file; expected that "
                         "suffix (other formats hold events only: convert events.h5)")
    sequence = load_sequence(folder)
    source = sequence.events_h5 or sequence.events_txt
    if source is None:
        raise ValueError(f"sequence folder {folder} has no events.h5 or events.txt")
    camera = sequence.camera
    frames = [(round(float(t) * 1e9), p) for t, p in zip(sequence.image_times,
                                                         sequence.image_paths, strict=True)]
    imu = sequence.read_imu()
    poses = (None if sequence.groundtruth_path is None
             else np.loadtxt(sequence.groundtruth_path, comments="#", ndmin=2))
    events = iter_event_chunks(source, 1 << 20, width=camera.width, height=camera.height)
    return write_sequence_aedat4(Path(folder), dst, events, (camera.width, camera.height),
                                 frames, imu, poses)
