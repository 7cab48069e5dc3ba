"""A whole sequence folder as one ROS 1 or ROS 2 bag (:func:`write_sequence_bag`), and a bag
read back as a recording (:class:`BagRecording`).

The bag holds, on the events' clock (every stamp is the time the folder gives, to the
nanosecond):

============================  ==============================  =================================
topic (one camera)            type                            from
============================  ==============================  =================================
``/dvs/events``               ``dvs_msgs/EventArray``         ``events.h5`` or ``events.txt``
``/dvs/image_raw``            ``sensor_msgs/Image`` mono8     ``images.txt`` + ``images/``
``/dvs/depthmap``             ``sensor_msgs/Image`` 32FC1 m   ``depthmaps.txt`` + ``depth/``
``/dvs/camera_info``          ``sensor_msgs/CameraInfo``      ``calib.txt`` (plumb_bob)
``/dvs/pose``                 ``geometry_msgs/PoseStamped``   ``groundtruth.txt``
``/tf``                       ``tf2_msgs/TFMessage``          ``groundtruth.txt`` (map -> dvs)
``/dvs/twist``                ``geometry_msgs/TwistStamped``  ``velocity.txt`` (camera frame)
``/imu``                      ``sensor_msgs/Imu``             ``imu.txt``
``/dvs/optic_flow``           ``esim_msgs/OpticFlow``         motion field (px/s, ESIM's)
``/dvs/forward_flow``,        ``esim_msgs/OpticFlow``         flow to the next / previous
``/dvs/backward_flow``                                        frame (pixels)
============================  ==============================  =================================

The topic names and message layouts are ESIM's and the rpg_dvs_ros driver's (ESIM's rosbag
writer names its one camera ``cam0``; the driver and the Event-Camera Dataset's bags use
``/dvs``, which is what a pipeline recorded on a DAVIS subscribes to). A two-camera rig gives two
namespaces: the event camera's (``/dvs``: events, camera info, pose, its depth if any) and the
frame camera's (``/frame_camera``: frames, depth, camera info, flow), with the frame camera's
extrinsic ``T_event_frame`` on ``/tf_static`` (``dvs -> frame_camera``). Every camera's
``frame_id`` is its namespace without the slash; poses are in the ``map`` frame.

Messages are written in time order of their stamps across topics (the events streamed, the
other files listed first and read one at a time), so memory stays bounded by one frame and one
event message.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sim.eventio._rosbag import (
    EVENT_ARRAY,
    BagFile,
    RosEventWriter,
    bag_ros_version,
    open_bag,
    typestore,
)
from sim.textfile import numeric_rows, text_lines

__all__ = ["BagRecording", "NAMESPACES", "exact_ns", "is_bag", "unpack_bag",
           "write_recording_folder", "write_sequence_bag"]

NAMESPACES = ("/dvs", "/frame_camera")
"""The event camera's and a rig's frame camera's topic namespaces."""

IMU_TOPIC = "/imu"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
WORLD_FRAME = "map"

IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE = "geometry_msgs/msg/PoseStamped"
TWIST = "geometry_msgs/msg/TwistStamped"
IMU = "sensor_msgs/msg/Imu"
TF = "tf2_msgs/msg/TFMessage"
OPTIC_FLOW = "esim_msgs/msg/OpticFlow"

_NS = 1_000_000_000


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` names a ROS bag: ``.bag``, ``.mcap``, ``.db3``, or an existing ROS 2 bag
    folder (it holds ``metadata.yaml``)."""
    from sim.eventio._formats import is_bag_folder

    path = Path(path)
    return path.suffix.lower() in (".bag", ".mcap", ".db3") or is_bag_folder(path)


def exact_ns(field: str, where: str) -> int:
    """A decimal number of seconds as whole nanoseconds, exactly (Decimal, never float64);
    digits past the ninth decimal are rounded half to even."""
    try:
        value = Decimal(field)
    except InvalidOperation:
        raise ValueError(f"{where}: time {field!r} is not a number of seconds") from None
    if not value.is_finite():
        raise ValueError(f"{where}: time {field!r} is not a finite number of seconds")
    return int((value * _NS).quantize(Decimal(1), rounding=ROUND_HALF_EVEN))


def _index_rows(path: Path) -> list[tuple[int, Path]]:
    """``t relpath`` rows of an index file (``images.txt``, ``depthmaps.txt``, flow indexes)
    as exact nanoseconds and paths; the file is checked by :func:`sim.sequence.read_index`."""
    from sim.sequence import read_index

    times, names = read_index(path)
    rows = []
    for number, line in text_lines(path):
        fields = line.split()
        if fields and not fields[0].startswith("#"):
            rows.append((exact_ns(fields[0], f"{path}:{number}"), path.parent / fields[1]))
    if len(rows) != len(names):
        raise ValueError(f"{path}: {len(rows)} rows read exactly but {len(names)} indexed")
    return rows


def _table_rows(path: Path, columns: int, form: str) -> list[tuple[int, list[float]]]:
    """Rows ``t v1 .. v{columns-1}`` with t as exact nanoseconds."""
    return [(exact_ns(fields[0], f"{path}:{number}"), values[1:])
            for number, fields, values in numeric_rows(path, columns, form)]


def _stamp(store: Any, t_ns: int) -> Any:
    return store.types["builtin_interfaces/msg/Time"](sec=t_ns // _NS, nanosec=t_ns % _NS)


class _Messages:
    """Builds the messages of one bag's type store (ROS 1 or ROS 2 field names)."""

    def __init__(self, bag: BagFile) -> None:
        self.bag = bag
        self.store = bag.store
        self.types = bag.store.types
        self.seq = 0

    def header(self, t_ns: int, frame_id: str) -> Any:
        kwargs = {"seq": self.seq} if self.bag.ros == 1 else {}
        self.seq += 1
        return self.types["std_msgs/msg/Header"](stamp=_stamp(self.store, t_ns),
                                                 frame_id=frame_id, **kwargs)

    def image(self, t_ns: int, frame_id: str, pixels: np.ndarray) -> Any:
        height, width = pixels.shape[:2]
        if pixels.dtype == np.uint8:
            encoding, step, data = "mono8", width, np.ascontiguousarray(pixels).ravel()
        else:
            data = np.ascontiguousarray(pixels, dtype="<f4").view(np.uint8).ravel()
            encoding, step = "32FC1", 4 * width
        return self.types[IMAGE](header=self.header(t_ns, frame_id), height=height, width=width,
                                 encoding=encoding, is_bigendian=0, step=step, data=data)

    def camera_info(self, t_ns: int, frame_id: str, camera: Any) -> Any:
        k = np.array([camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0])
        p = np.array([camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0,
                      0.0, 0.0, 1.0, 0.0])
        fields = {"d": np.array(camera.distortion, np.float64), "k": k,
                  "r": np.eye(3).ravel(), "p": p}
        if self.bag.ros == 1:
            fields = {name.upper(): value for name, value in fields.items()}
        roi = self.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                              width=0, do_rectify=False)
        return self.types[CAMERA_INFO](header=self.header(t_ns, frame_id), height=camera.height,
                                       width=camera.width, distortion_model="plumb_bob",
                                       binning_x=0, binning_y=0, roi=roi, **fields)

    def vector(self, values: Any) -> Any:
        return self.types["geometry_msgs/msg/Vector3"](x=float(values[0]), y=float(values[1]),
                                                       z=float(values[2]))

    def quaternion(self, values: Any) -> Any:
        return self.types["geometry_msgs/msg/Quaternion"](
            x=float(values[0]), y=float(values[1]), z=float(values[2]), w=float(values[3]))

    def pose(self, t_ns: int, values: list[float]) -> Any:
        pose = self.types["geometry_msgs/msg/Pose"](
            position=self.types["geometry_msgs/msg/Point"](x=values[0], y=values[1],
                                                           z=values[2]),
            orientation=self.quaternion(values[3:7]))
        return self.types[POSE](header=self.header(t_ns, WORLD_FRAME), pose=pose)

    def tf(self, t_ns: int, parent: str, child: str, values: Any) -> Any:
        transform = self.types["geometry_msgs/msg/Transform"](
            translation=self.vector(values[:3]), rotation=self.quaternion(values[3:7]))
        stamped = self.types["geometry_msgs/msg/TransformStamped"](
            header=self.header(t_ns, parent), child_frame_id=child, transform=transform)
        return self.types[TF](transforms=[stamped])

    def twist(self, t_ns: int, frame_id: str, values: list[float]) -> Any:
        twist = self.types["geometry_msgs/msg/Twist"](linear=self.vector(values[:3]),
                                                      angular=self.vector(values[3:6]))
        return self.types[TWIST](header=self.header(t_ns, frame_id), twist=twist)

    def imu(self, t_ns: int, frame_id: str, values: list[float]) -> Any:
        unknown = np.zeros(9)
        unknown[0] = -1.0                     # REP 145: no orientation estimate
        return self.types[IMU](header=self.header(t_ns, frame_id),
                               orientation=self.quaternion((0.0, 0.0, 0.0, 1.0)),
                               orientation_covariance=unknown,
                               angular_velocity=self.vector(values[3:6]),
                               angular_velocity_covariance=np.zeros(9),
                               linear_acceleration=self.vector(values[:3]),
                               linear_acceleration_covariance=np.zeros(9))

    def flow(self, t_ns: int, frame_id: str, flow: np.ndarray) -> Any:
        height, width = flow.shape[:2]
        return self.types[OPTIC_FLOW](header=self.header(t_ns, frame_id), height=height,
                                      width=width,
                                      flow_x=np.ascontiguousarray(flow[..., 0], np.float32).ravel(),
                                      flow_y=np.ascontiguousarray(flow[..., 1], np.float32).ravel())


@dataclass(frozen=True)
class _Item:
    """One non-event message to write: its stamp, topic, type and how to build it."""

    t_ns: int
    order: int
    topic: str
    msgtype: str
    build: Any


def _read_png(path: Path) -> np.ndarray:
    pixels = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if pixels is None:
        raise ValueError(f"cannot read frame {path} as an 8-bit grayscale image")
    return pixels


def _flow_channels(path: Path, names: tuple[str, str]) -> np.ndarray:
    from sim.exr import read_exr_channels

    channels = read_exr_channels(path)
    if any(name not in channels for name in names):
        raise ValueError(f"{path}: expected the channels {list(names)}, the file has "
                         f"{sorted(channels)}")
    return np.stack([channels[names[0]], channels[names[1]]], axis=-1).astype(np.float32)


_FLOWS = (("motion_field", "optic_flow", ("du_dt", "dv_dt")),
          ("forward_flow", "forward_flow", ("du", "dv")),
          ("backward_flow", "backward_flow", ("du", "dv")))


def _camera_items(files: Any, camera: Any, namespace: str, first_ns: int) -> list[_Item]:
    """Frames, depth maps, camera info and flow of one camera (:class:`FrameCameraFiles`)."""
    from sim.exr import read_depth

    frame = namespace.strip("/")
    items: list[_Item] = []
    folder = files.folder
    images = _index_rows(folder / "images.txt")
    info_times = [t for t, _ in images] or [first_ns]
    for t_ns in info_times:
        items.append(_Item(t_ns, 0, f"{namespace}/camera_info", CAMERA_INFO,
                           lambda m, t=t_ns: m.camera_info(t, frame, camera)))
    for t_ns, path in images:
        items.append(_Item(t_ns, 1, f"{namespace}/image_raw", IMAGE,
                           lambda m, t=t_ns, p=path: m.image(t, frame, _read_png(p))))
    if (folder / "depthmaps.txt").is_file():
        for t_ns, path in _index_rows(folder / "depthmaps.txt"):
            items.append(_Item(t_ns, 2, f"{namespace}/depthmap", IMAGE,
                               lambda m, t=t_ns, p=path: m.image(t, frame, read_depth(p))))
    from sim.sequence import FLOW_INDEXES

    for field, name, channels in _FLOWS:
        if getattr(files, field) is None:
            continue
        for t_ns, path in _index_rows(folder / FLOW_INDEXES[field]):
            items.append(_Item(t_ns, 3, f"{namespace}/{name}", OPTIC_FLOW,
                               lambda m, t=t_ns, p=path, c=channels:
                               m.flow(t, frame, _flow_channels(p, c))))
    return items


def _pose_values(matrix: np.ndarray) -> list[float]:
    from sim.se3 import rot_to_quat

    return [*map(float, matrix[:3, 3]), *map(float, rot_to_quat(matrix[:3, :3]))]


def _sequence_items(sequence: Any, namespaces: tuple[str, str], first_ns: int) -> list[_Item]:
    """Every non-event message of a sequence, unsorted."""
    event_ns, frame_ns = namespaces
    event_frame = event_ns.strip("/")
    items: list[_Item] = []
    if sequence.frame_camera is None:
        items += _camera_items(sequence.standard_frames(), sequence.camera, event_ns, first_ns)
    else:
        rig = sequence.frame_camera
        items.append(_Item(first_ns, 0, f"{event_ns}/camera_info", CAMERA_INFO,
                           lambda m: m.camera_info(first_ns, event_frame, sequence.camera)))
        if sequence.depth_times is not None:
            for t_ns, path in _index_rows(sequence.folder / "depthmaps.txt"):
                from sim.exr import read_depth

                items.append(_Item(t_ns, 2, f"{event_ns}/depthmap", IMAGE,
                                   lambda m, t=t_ns, p=path: m.image(t, event_frame,
                                                                     read_depth(p))))
        items += _camera_items(rig, rig.camera, frame_ns, first_ns)
        extrinsic = _pose_values(np.asarray(rig.T_event_frame))
        items.append(_Item(first_ns, 0, TF_STATIC_TOPIC, TF,
                           lambda m: m.tf(first_ns, event_frame, frame_ns.strip("/"),
                                          extrinsic)))
    folder = sequence.folder
    if sequence.groundtruth_path is not None:
        form = "t px py pz qx qy qz qw (T_world_camera, quaternion scalar last)"
        for t_ns, values in _table_rows(sequence.groundtruth_path, 8, form):
            items.append(_Item(t_ns, 4, f"{event_ns}/pose", POSE,
                               lambda m, t=t_ns, v=values: m.pose(t, v)))
            items.append(_Item(t_ns, 5, TF_TOPIC, TF,
                               lambda m, t=t_ns, v=values: m.tf(t, WORLD_FRAME, event_frame, v)))
    if sequence.velocity_path is not None:
        for t_ns, values in _table_rows(folder / "velocity.txt", 7, "t vx vy vz wx wy wz"):
            items.append(_Item(t_ns, 6, f"{event_ns}/twist", TWIST,
                               lambda m, t=t_ns, v=values: m.twist(t, event_frame, v)))
    if sequence.imu_path is not None:
        for t_ns, values in _table_rows(sequence.imu_path, 7, "t ax ay az gx gy gz"):
            items.append(_Item(t_ns, 7, IMU_TOPIC, IMU,
                               lambda m, t=t_ns, v=values: m.imu(t, event_frame, v)))
    return items


def write_sequence_bag(folder: str | Path, dst: str | Path, *, ros: int | None = None,
                       storage: str = "mcap", namespaces: tuple[str, str] = NAMESPACES,
                       events_topic: str | None = None) -> dict[str, int]:
    """Write a sequence folder as one bag: events, frames, depth, camera info, poses, IMU, flow.

    Parameters
    ----------
    folder : str or Path
        A sequence folder (:func:`sim.sequence.load_sequence`): a real ECD folder or a
        simulated one, one camera or a rig.
    dst : str or Path
        ``.bag`` (ROS 1), a folder name or ``.mcap`` (ROS 2); written as ``<dst>.partial`` and
        renamed when complete.
    ros : {1, 2}, optional
        Where the name of ``dst`` cannot say.
    storage : {"mcap", "sqlite3"}
        ROS 2 storage.
    namespaces : (str, str)
        The event camera's and a rig's frame camera's topic namespaces (module docstring).
    events_topic : str, optional
        Default ``<event namespace>/events``.

    Returns
    -------
    dict
        Messages written per topic.

    Raises
    ------
    ValueError
        Not a sequence folder, no events file, a malformed file in it (as the readers say),
        or a time outside a ROS time; nothing is left at ``dst``.
    """
    from sim.eventio import iter_event_chunks
    from sim.sequence import load_sequence

    sequence = load_sequence(folder)
    events_path = sequence.events_h5 or sequence.events_txt
    if events_path is None:
        raise ValueError(f"sequence folder {sequence.folder} has no events.h5 or events.txt; "
                         "expected the events of the sequence")
    for namespace in namespaces:
        if not namespace.startswith("/") or namespace.endswith("/") or len(namespace) < 2:
            raise ValueError(f"topic namespace {namespace!r} must look like '/dvs'")
    camera = sequence.camera
    chunks = iter_event_chunks(events_path, 1 << 20, width=camera.width, height=camera.height)
    first = next(chunks, None)
    first_ns = int(first["t"][0]) if first is not None and first.size else 0
    items = sorted(_sequence_items(sequence, namespaces, first_ns),
                   key=lambda item: (item.t_ns, item.order))
    bag = BagFile(dst, bag_ros_version(dst, ros), storage)
    messages = _Messages(bag)
    counts: dict[str, int] = {}
    position = 0

    def side_until(t_ns: float) -> None:
        nonlocal position
        while position < len(items) and items[position].t_ns <= t_ns:
            item = items[position]
            if item.t_ns < 0:
                raise ValueError(f"{sequence.folder}: {item.topic} at t = {item.t_ns} ns is "
                                 "before 0; expected times a bag can stamp")
            data = bag.serialize(item.build(messages), item.msgtype)
            bag.write(item.topic, item.msgtype, item.t_ns, data)
            counts[item.topic] = counts.get(item.topic, 0) + 1
            position += 1

    topic = events_topic or f"{namespaces[0]}/events"
    events = RosEventWriter(dst, camera.width, camera.height, ros=bag.ros, topic=topic,
                            frame_id=namespaces[0].strip("/"), bag=bag)
    events.before_message = side_until
    try:
        with events:
            if first is not None:
                events.write(first)
                for chunk in chunks:
                    events.write(chunk)
        side_until(math.inf)
        bag.close()
    except BaseException:
        bag.abort()
        raise
    counts[topic] = events._messages
    return dict(sorted(counts.items()))


# --- reading a bag as a recording -------------------------------------------------------------

_ROS1_INFO = {"d": "D", "k": "K", "r": "R", "p": "P"}


class BagRecording:
    """A ROS 1 or ROS 2 bag read as a recording: events, frames, camera info, poses and IMU,
    each topic found by its message type (or given).

    Parameters
    ----------
    path : str or Path
        ``.bag``, a ROS 2 bag folder, ``.mcap`` or ``.db3``.
    ros : {1, 2}, optional
        Where the name cannot say.
    events_topic, image_topic, camera_info_topic, pose_topic, imu_topic : str, optional
        The topics to read (``--topic``). By default the one topic of each type
        (``dvs_msgs/EventArray``, ``sensor_msgs/Image`` with a non-float encoding,
        ``sensor_msgs/CameraInfo``, ``geometry_msgs/PoseStamped``, ``sensor_msgs/Imu``); where a
        type has several, the one in the event topic's namespace, else an error naming them.

    Attributes
    ----------
    path : Path
    ros : int
    topics : dict
        Every topic of the bag and its message type.
    events_topic : str
    image_topic, camera_info_topic, pose_topic, imu_topic : str or None
        None where the bag has no such topic.

    Raises
    ------
    ValueError
        Not a readable bag, no event topic, or a given topic that is not there or not of the
        expected type: one line naming the file.
    """

    def __init__(self, path: str | Path, *, ros: int | None = None,
                 events_topic: str | None = None, image_topic: str | None = None,
                 camera_info_topic: str | None = None, pose_topic: str | None = None,
                 imu_topic: str | None = None) -> None:
        self.path = Path(path)
        reader, self.ros = open_bag(self.path, ros)
        self.store = typestore(self.ros)
        try:
            self.topics = {c.topic: c.msgtype for c in reader.connections}
            self._counts = {c.topic: c.msgcount for c in reader.connections}
            self.events_topic = self._pick(EVENT_ARRAY, events_topic, None, required=True)
            namespace = self.events_topic.rsplit("/", 1)[0]
            self.image_topic = self._pick(IMAGE, image_topic, namespace,
                                          skip=self._float_images(reader))
            self.camera_info_topic = self._pick(CAMERA_INFO, camera_info_topic, namespace)
            self.pose_topic = self._pick(POSE, pose_topic, namespace)
            self.imu_topic = self._pick(IMU, imu_topic, namespace)
        finally:
            reader.close()

    def _float_images(self, reader: Any) -> set[str]:
        """Image topics whose first message is a float image (depth maps)."""
        floats = set()
        for connection in reader.connections:
            if connection.msgtype != IMAGE:
                continue
            for _, _, data in reader.messages(connections=[connection]):
                encoding = self._deserialize(data, IMAGE).encoding
                if encoding.startswith("32F") or encoding.startswith("64F"):
                    floats.add(connection.topic)
                break
        return floats

    def _pick(self, msgtype: str, given: str | None, namespace: str | None, *,
              required: bool = False, skip: set[str] | None = None) -> str | None:
        if given is not None:
            if given not in self.topics:
                raise ValueError(f"{self.path}: no topic {given!r}; expected one of "
                                 f"{sorted(self.topics)}")
            if self.topics[given] != msgtype:
                raise ValueError(f"{self.path}: topic {given!r} is {self.topics[given]}; "
                                 f"expected {msgtype}")
            return given
        found = sorted(t for t, m in self.topics.items() if m == msgtype and t not in
                       (skip or set()))
        if len(found) > 1 and namespace is not None:
            found = [t for t in found if t.rsplit("/", 1)[0] == namespace] or found
        if not found:
            if required:
                raise ValueError(f"{self.path}: no {msgtype} topic; expected a bag with events "
                                 f"(its topics: {sorted(self.topics)})")
            return None
        if len(found) > 1:
            raise ValueError(f"{self.path}: {len(found)} {msgtype} topics {found}; expected "
                             "the one to read named (--topic)")
        return found[0]

    def _deserialize(self, data: bytes, msgtype: str) -> Any:
        if self.ros == 1:
            return self.store.deserialize_ros1(data, msgtype)
        return self.store.deserialize_cdr(data, msgtype)

    def _messages(self, topic: str | None) -> Iterator[tuple[int, Any]]:
        """``(bag time ns, message)`` of a topic, in bag order."""
        if topic is None:
            return
        reader, _ = open_bag(self.path, self.ros)
        try:
            connections = [c for c in reader.connections if c.topic == topic]
            for _, stamp, data in reader.messages(connections=connections):
                yield stamp, self._deserialize(data, self.topics[topic])
        finally:
            reader.close()

    def iter_events(self, chunk_events: int = 10**6, t0_ns: int | None = None,
                    t1_ns: int | None = None, *, width: int | None = None,
                    height: int | None = None) -> Iterator[np.ndarray]:
        """The events of the event topic in chunks (:func:`sim.eventio.iter_event_chunks`:
        checked, time-ordered, optionally a window ``t0_ns <= t < t1_ns``)."""
        from sim.eventio import iter_event_chunks

        yield from iter_event_chunks(self.path, chunk_events, t0_ns, t1_ns, width=width,
                                     height=height, options={"topic": self.events_topic,
                                                             "ros": self.ros})

    def camera(self) -> Any:
        """The first camera info as a :class:`sim.camera.Camera` (intrinsics and plumb_bob /
        rational-free radial-tangential distortion; up to 5 coefficients).

        Raises
        ------
        ValueError
            No camera info topic, or a distortion model other than ``plumb_bob`` (or none).
        """
        from sim.camera import Camera

        for _, info in self._messages(self.camera_info_topic):
            fields = {name: np.asarray(getattr(info, _ROS1_INFO[name] if self.ros == 1
                                               else name)) for name in ("d", "k")}
            model = info.distortion_model
            coeffs = [float(c) for c in fields["d"]]
            if (model not in ("plumb_bob", "") or len(coeffs) > 5
                    or (model == "" and any(coeffs))):
                raise ValueError(f"{self.path}: {self.camera_info_topic} has distortion model "
                                 f"{model!r} with {len(coeffs)} coefficients; expected "
                                 "plumb_bob (k1 k2 p1 p2 k3)")
            k = fields["k"]
            return Camera(width=int(info.width), height=int(info.height), fx=float(k[0]),
                          fy=float(k[4]), cx=float(k[2]), cy=float(k[5]),
                          distortion=tuple(coeffs + [0.0] * (5 - len(coeffs))))
        raise ValueError(f"{self.path}: no sensor_msgs/CameraInfo topic; expected the camera's "
                         "intrinsics and distortion in the bag")

    def frames(self) -> Iterator[tuple[int, np.ndarray]]:
        """``(t ns, (H, W) uint8)`` of the image topic, one at a time (mono8, or rgb8 / bgr8
        converted to gray with OpenCV's weights); its header stamps."""
        for _, image in self._messages(self.image_topic):
            pixels = np.asarray(image.data, np.uint8)
            if image.encoding in ("mono8", "8UC1"):
                frame = pixels.reshape(image.height, image.step)[:, :image.width]
            elif image.encoding in ("rgb8", "bgr8"):
                rgb = pixels.reshape(image.height, image.step)[:, :3 * image.width]
                code = cv2.COLOR_RGB2GRAY if image.encoding == "rgb8" else cv2.COLOR_BGR2GRAY
                frame = cv2.cvtColor(rgb.reshape(image.height, image.width, 3), code)
            else:
                raise ValueError(f"{self.path}: {self.image_topic} has encoding "
                                 f"{image.encoding!r}; expected mono8, rgb8 or bgr8 frames")
            yield _header_ns(image.header), np.ascontiguousarray(frame)

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """The pose topic's header stamps (N,) int64 ns and poses (N, 7) float64
        ``px py pz qx qy qz qw`` (T_world_camera, as ``groundtruth.txt``)."""
        times, rows = [], []
        for _, message in self._messages(self.pose_topic):
            p, q = message.pose.position, message.pose.orientation
            times.append(_header_ns(message.header))
            rows.append((p.x, p.y, p.z, q.x, q.y, q.z, q.w))
        return np.asarray(times, np.int64), np.asarray(rows, np.float64).reshape(-1, 7)

    def imu(self) -> tuple[np.ndarray, np.ndarray]:
        """The IMU topic's stamps (N,) int64 ns and samples (N, 6) float64
        ``ax ay az gx gy gz`` (m/s^2, rad/s, as ``imu.txt``)."""
        times, rows = [], []
        for _, message in self._messages(self.imu_topic):
            a, g = message.linear_acceleration, message.angular_velocity
            times.append(_header_ns(message.header))
            rows.append((a.x, a.y, a.z, g.x, g.y, g.z))
        return np.asarray(times, np.int64), np.asarray(rows, np.float64).reshape(-1, 6)


def _header_ns(header: Any) -> int:
    return int(header.stamp.sec) * _NS + int(header.stamp.nanosec)


def _seconds(t_ns: int) -> str:
    """Whole nanoseconds as seconds with 9 decimals, by integer arithmetic (exact)."""
    sign = "-" if t_ns < 0 else ""
    whole, fraction = divmod(abs(int(t_ns)), _NS)
    return f"{sign}{whole}.{fraction:09d}"


def unpack_bag(recording: BagRecording, folder: Path) -> None:
    """Write what a bag holds besides its events into a sequence folder being written:
    ``calib.txt`` (from the camera info, when the bag has one), ``images.txt`` + ``images/``
    (its frames, when they are in the event topic's namespace: a rig's frame camera's are not
    the event camera's), ``groundtruth.txt`` (its poses) and ``imu.txt`` (its IMU), each only
    where the bag has the topic; every time with 9 decimals from the integer nanoseconds, every
    value with ``repr`` (exact)."""
    from sim.camera import write_calib
    from sim.sequence import frame_name

    if recording.camera_info_topic is not None:
        write_calib(folder / "calib.txt", recording.camera())
    lines = []
    frames = recording.frames()
    if recording.image_topic is not None and (recording.image_topic.rsplit("/", 1)[0]
                                              != recording.events_topic.rsplit("/", 1)[0]):
        frames = iter(())   # another camera's frames (a rig's frame camera): not the events'
    for k, (t_ns, frame) in enumerate(frames):
        name = frame_name(k, "png")
        (folder / "images").mkdir(exist_ok=True)
        if not cv2.imwrite(str(folder / name), frame):
            raise ValueError(f"cannot write {folder / name}")
        lines.append(f"{_seconds(t_ns)} {name}\n")
    if lines:
        (folder / "images.txt").write_text("".join(lines))
    for name, (times, rows) in (("groundtruth.txt", recording.poses()),
                                ("imu.txt", recording.imu())):
        if times.size:
            (folder / name).write_text("".join(
                f"{_seconds(t)} " + " ".join(repr(float(v)) for v in row) + "\n"
                for t, row in zip(times.tolist(), rows, strict=True)))


def write_recording_folder(recording: BagRecording, out: str | Path, *,
                           overwrite: bool = False) -> Path:
    """Write a bag's recording as an ECD sequence folder, which every command reads.

    Parameters
    ----------
    recording : BagRecording
        The bag and its topics.
    out : str or Path
        The folder to write (atomically, :func:`sim.output.atomic_output_dir`): ``calib.txt``
        from the camera info, ``images.txt`` + ``images/`` from the frames, ``groundtruth.txt``
        from the poses, ``imu.txt`` from the IMU (when the bag has one) and ``events.h5``
        (the events, exact to the nanosecond); every time written with 9 decimals from the
        integer nanoseconds, every value with ``repr`` (exact).
    overwrite : bool
        Replace a folder evfuse wrote.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    ValueError
        The bag has no camera info or no frames (the sequence folder needs both), or as the
        readers.
    """
    from sim.eventio import H5EventWriter
    from sim.output import atomic_output_dir

    camera = recording.camera()
    if recording.image_topic is None:
        raise ValueError(f"{recording.path}: no sensor_msgs/Image topic with frames; a sequence "
                         "folder needs images.txt with its frames")
    with atomic_output_dir(out, overwrite, inputs=[recording.path],
                           command="sim.sequence_bag.write_recording_folder") as folder:
        unpack_bag(recording, folder)
        with H5EventWriter(folder / "events.h5", camera.width, camera.height) as writer:
            for chunk in recording.iter_events(1 << 20, width=camera.width,
                                               height=camera.height):
                writer.write(chunk)
    return Path(out)
