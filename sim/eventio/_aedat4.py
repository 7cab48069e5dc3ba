"""AEDAT4 files (iniVation DV), written and read through dv-processing, streamed.

dv-processing (iniVation's own library, ``pip install dv-processing``, a binary wheel) writes
and reads the format its cameras record: LZ4-compressed FlatBuffers packets of events, frames and
IMU samples, with the event resolution in the stream's metadata. Its Python API streams both ways
(``MonoCameraWriter.writeEvents`` per chunk; ``MonoCameraRecording.getNextEventBatch``), so it is
used rather than a codec of our own. Times are int64 microseconds: written as ``t_ns // 1000``
(floor), read as microseconds * 1000 (the registry's rule).

Frames and IMU (a whole sequence as one file, :func:`write_sequence_aedat4`) follow DV's
conventions: frames 8-bit grayscale at their exposure time; IMU accelerations in g
(``9.81 m/s^2``) and angular velocities in degrees per second, converted from the sequence's
``imu.txt`` (m/s^2, rad/s) and back on reading (:func:`read_aedat4_frames`,
:func:`read_aedat4_imu`).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from sim.eventio._events import EVENT_DTYPE, _check_size
from sim.eventio._formats import us_from_ns
from sim.eventio._writer import _StreamingWriter

try:
    import dv_processing as dv
except ImportError as error:          # the registry names the extra (sim.eventio._formats)
    raise ImportError(str(error), name="dv-processing") from None

__all__ = ["STANDARD_GRAVITY", "Aedat4EventWriter", "aedat4_info", "iter_aedat4_chunks",
           "read_aedat4_frames", "read_aedat4_imu", "read_aedat4_poses"]

STANDARD_GRAVITY = 9.80665
"""m/s^2 per g, DV's unit of acceleration."""

_CAMERA_NAME = "evfuse"


def _open(path: Path) -> dv.io.MonoCameraRecording:
    """A recording, or one line naming the file (a truncated or foreign file)."""
    try:
        head = path.open("rb").read(14)
    except OSError as error:
        raise ValueError(f"{path}: cannot be read ({error.strerror}); expected an AEDAT4 "
                         "file") from None
    if not head.startswith(b"#!AER-DAT4.0"):
        raise ValueError(f"{path}: does not begin with '#!AER-DAT4.0'; expected an AEDAT4 file")
    try:
        return dv.io.MonoCameraRecording(str(path))
    except RuntimeError as error:
        raise ValueError(f"{path}: dv-processing cannot open it ({error}); expected a whole "
                         "AEDAT4 file (truncated?)") from None


class Aedat4EventWriter(_StreamingWriter):
    """Stream events (and, optionally, frames and IMU samples) into an AEDAT4 file.

    Parameters
    ----------
    path : str or Path
        The ``.aedat4`` file; written as ``<path>.partial``, renamed by a successful
        :meth:`close`.
    sensor_size : (int, int)
        ``(width, height)`` in pixels (the event stream's resolution).
    frames, imu, poses : bool
        Whether the file gets a frame stream, an IMU stream (DV's DAVIS layout) and a pose
        stream besides the events.

    Raises
    ------
    ValueError
        No sensor size, or a resume (AEDAT4 files are not resumable: dv-processing writes its
        index on close).
    """

    _format = "aedat4"

    def __init__(self, path: str | Path, *, sensor_size: tuple[int, int] | None,
                 frames: bool = False, imu: bool = False, poses: bool = False,
                 resume: dict | None = None) -> None:
        self._begin(path)
        if resume is not None:
            raise ValueError(f"{self.path}: AEDAT4 files cannot be resumed; expected a fresh "
                             "writer")
        if sensor_size is None:
            raise ValueError(f"{self.path}: an AEDAT4 file needs the sensor size; expected "
                             "(width, height)")
        width, height = (int(v) for v in sensor_size)
        _check_size(width, height, str(self.path))
        self._width, self._height = width, height
        config = dv.io.MonoCameraWriter.Config(_CAMERA_NAME, dv.CompressionType.LZ4)
        config.addEventStream((width, height))
        if frames:
            config.addFrameStream((width, height))
        if imu:
            config.addImuStream()
        if poses:
            config.addPoseStream()
        # dv-processing refuses a name not ending in .aedat4: the unfinished file is
        # <name>.partial/<name>, a folder of the one suffix of everything unfinished
        if self.partial.is_dir():
            shutil.rmtree(self.partial)
        else:
            self.partial.unlink(missing_ok=True)
        self.partial.mkdir()
        self._file = self.partial / self.path.name
        self._writer = dv.io.MonoCameraWriter(str(self._file), config)

    def write(self, events: np.ndarray) -> None:
        """Append a chunk of time-ordered :data:`EVENT_DTYPE` events."""
        self._check_chunk(events)
        if not events.size:
            return
        store = dv.EventStore()
        push = store.push_back
        for t, x, y, p in zip(us_from_ns(events["t"]).tolist(), events["x"].tolist(),
                              events["y"].tolist(), (events["p"] > 0).tolist(), strict=True):
            push(t, x, y, p)
        self._writer.writeEvents(store)
        self.count += events.size
        self._last_t = int(events["t"][-1])

    def write_frame(self, t_ns: int, image: np.ndarray) -> None:
        """Add an 8-bit grayscale frame ``(H, W) uint8`` taken at ``t_ns`` (ns)."""
        self._writer.writeFrame(dv.Frame(int(t_ns) // 1000, np.ascontiguousarray(image,
                                                                                  np.uint8)))

    def write_imu(self, t_ns: int, accel: np.ndarray, gyro: np.ndarray) -> None:
        """Add an IMU sample: ``accel`` (3,) m/s^2 and ``gyro`` (3,) rad/s at ``t_ns`` (ns)."""
        a = np.asarray(accel, float) / STANDARD_GRAVITY
        g = np.degrees(np.asarray(gyro, float))
        self._writer.writeImu(dv.IMU(int(t_ns) // 1000, 0.0, *a, *g, 0.0, 0.0, 0.0))

    def write_pose(self, t_ns: int, position: np.ndarray, quaternion: np.ndarray) -> None:
        """Add a pose T_world_camera: ``position`` (3,) m, ``quaternion`` (4,) ``qx qy qz qw``
        (scalar last, as ``groundtruth.txt``), at ``t_ns`` (ns). DV stores float32."""
        qx, qy, qz, qw = (float(v) for v in quaternion)
        self._writer.writePose(dv.Pose(int(t_ns) // 1000, tuple(float(v) for v in position),
                                       (qw, qx, qy, qz), "world", "camera"))

    def _sync(self) -> dict:
        raise ValueError(f"{self.path}: AEDAT4 files cannot be checkpointed (dv-processing "
                         "writes its index on close); expected a writer run to the end")

    def _finish(self) -> None:
        del self._writer                      # dv-processing finishes the file on destruction

    def _abort(self) -> None:
        self._writer = None

    def _publish(self) -> None:
        """Move the finished file (inside the ``.partial`` folder: dv-processing wants an
        ``.aedat4`` name) to ``path``, and drop the folder."""
        os.replace(self._file, self.path)
        self.partial.rmdir()


def aedat4_writer(path: Path, *, sensor_size: tuple[int, int] | None,
                  **options) -> Aedat4EventWriter:
    """The registry's AEDAT4 writer (:class:`Aedat4EventWriter`)."""
    return Aedat4EventWriter(path, sensor_size=sensor_size, **options)


def iter_aedat4_chunks(path: Path, *, chunk_events: int, **options) -> Iterator[np.ndarray]:
    """The events of an AEDAT4 file's ``events`` stream, in file order.

    Raises
    ------
    ValueError
        Not an AEDAT4 file, a truncated one, or one without an event stream.
    """
    recording = _open(path)
    if not recording.isEventStreamAvailable():
        raise ValueError(f"{path}: no event stream (streams: "
                         f"{', '.join(recording.getStreamNames()) or 'none'}); expected one "
                         "named 'events'")
    buffer = np.empty(chunk_events, EVENT_DTYPE)   # dv-processing's packets (10,000 events),
    held = 0                                       # gathered into chunks
    while (batch := recording.getNextEventBatch()) is not None:
        array = batch.numpy()
        start = 0
        while start < array.size:
            take = min(array.size - start, chunk_events - held)
            part, source = buffer[held:held + take], array[start:start + take]
            np.multiply(source["timestamp"], 1000, out=part["t"])
            part["x"], part["y"] = source["x"], source["y"]
            np.multiply(source["polarity"], 2, out=part["p"])
            part["p"] -= 1                                  # 0/1 -> -1/+1
            held += take
            start += take
            if held == chunk_events:
                yield buffer
                buffer, held = np.empty(chunk_events, EVENT_DTYPE), 0
    if held:
        yield buffer[:held]


def aedat4_info(path: Path) -> dict:
    """Sensor size and time span from the file's index."""
    recording = _open(path)
    first = last = None
    if recording.isEventStreamAvailable():
        first, last = recording.getTimeRange()          # of every stream: events, frames, IMU
    resolution = recording.getEventResolution()
    return {"format": "aedat4", "sensor_size": None if resolution is None else tuple(resolution),
            "t_first_ns": None if first is None else int(first) * 1000,
            "t_last_ns": None if last is None else int(last) * 1000, "count": None,
            "frames": recording.isFrameStreamAvailable(),
            "imu": recording.isImuStreamAvailable()}


def read_aedat4_frames(path: Path) -> Iterator[tuple[int, np.ndarray]]:
    """The frames of an AEDAT4 file: ``(t_ns, (H, W) uint8 image)`` in file order (colour frames
    are converted to gray by their mean over channels)."""
    recording = _open(path)
    if not recording.isFrameStreamAvailable():
        return
    while True:
        frame = recording.getNextFrame()
        if frame is None:
            return
        image = np.asarray(frame.image)
        if image.ndim == 3:
            image = image.mean(axis=2).round().astype(np.uint8)
        yield int(frame.timestamp) * 1000, image


def read_aedat4_poses(path: Path) -> np.ndarray:
    """The poses of an AEDAT4 file: ``(K, 8) float64``, ``t[s] px py pz qx qy qz qw`` (the
    layout of ``groundtruth.txt``), empty when it has none."""
    recording = _open(path)
    rows = []
    if "poses" in recording.getStreamNames():
        while (pose := recording.getNextPose()) is not None:
            qw, qx, qy, qz = pose.rotation
            rows.append((pose.timestamp * 1e-6, *pose.translation, qx, qy, qz, qw))
    return np.array(rows, float).reshape(-1, 8)


def read_aedat4_imu(path: Path) -> np.ndarray:
    """The IMU samples of an AEDAT4 file: ``(N, 7) float64``, ``t[s] ax ay az gx gy gz``
    (m/s^2, rad/s; the layout of ``imu.txt``), empty when it has none."""
    recording = _open(path)
    rows = []
    if recording.isImuStreamAvailable():
        while (batch := recording.getNextImuBatch()) is not None:
            for s in batch:
                rows.append((s.timestamp * 1e-6,
                             *(np.array([s.accelerometerX, s.accelerometerY, s.accelerometerZ])
                               * STANDARD_GRAVITY),
                             *np.radians([s.gyroscopeX, s.gyroscopeY, s.gyroscopeZ])))
    return np.array(rows, float).reshape(-1, 7)


def write_sequence_aedat4(folder: Path, dst: Path, events: Iterator[np.ndarray],
                          sensor_size: tuple[int, int],
                          frames: list[tuple[int, Path]], imu: np.ndarray | None,
                          poses: np.ndarray | None = None) -> tuple[int, int, int]:
    """Write a whole sequence as one AEDAT4 file: its events, frames and IMU samples.

    Parameters
    ----------
    folder : Path
        The sequence folder (named in messages).
    dst : Path
        The ``.aedat4`` file (written atomically).
    events : iterator of EVENT_DTYPE chunks
        The sequence's events, time-ordered.
    sensor_size : (int, int)
        ``(width, height)``.
    frames : list of (int, Path)
        Frame times (ns) and their 8-bit grayscale image files.
    imu : (N, 7) float ndarray or None
        ``imu.txt`` rows: ``t[s] ax ay az gx gy gz`` (m/s^2, rad/s).
    poses : (K, 8) float ndarray or None
        ``groundtruth.txt`` rows: ``t[s] px py pz qx qy qz qw`` (T_world_camera).

    Returns
    -------
    (int, int, int)
        Events, frames and IMU samples written.
    """
    import cv2

    writer = Aedat4EventWriter(dst, sensor_size=sensor_size, frames=bool(frames),
                               imu=imu is not None and len(imu) > 0,
                               poses=poses is not None and len(poses) > 0)
    with writer:
        for t_ns, image_path in frames:
            image = cv2.imread(str(image_path), cv2.IMREAD_GRAYSCALE)
            if image is None:
                raise ValueError(f"{folder}: cannot read frame {image_path}; expected an 8-bit "
                                 "image")
            writer.write_frame(t_ns, image)
        for row in (() if imu is None else imu):
            writer.write_imu(round(float(row[0]) * 1e9), row[1:4], row[4:7])
        for row in (() if poses is None else poses):
            writer.write_pose(round(float(row[0]) * 1e9), row[1:4], row[4:8])
        for chunk in events:
            writer.write(chunk)
    return writer.count, len(frames), 0 if imu is None else len(imu)
