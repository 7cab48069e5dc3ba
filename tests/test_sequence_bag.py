"""A sequence folder as one bag (sim.sequence_bag.write_sequence_bag) with every topic read back
by rosbags, and a bag read as a recording (BagRecording): the ECD prefix gives back the same
events, frames, poses and calibration."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.highlevel import AnyReader  # noqa: E402

from sim.camera import read_calib  # noqa: E402
from sim.eventio import TextEventWriter, make_events, read_events  # noqa: E402
from sim.exr import write_depth, write_exr_channels  # noqa: E402
from sim.sequence_bag import BagRecording, exact_ns, write_sequence_bag  # noqa: E402
from tests.conftest import run_cli  # noqa: E402

NS = 1_000_000_000
W, H = 32, 24


def _all_messages(path):
    """Every message of a bag, deserialized by rosbags: {topic: [(stamp, message)]}."""
    out = {}
    with AnyReader([Path(path)]) as reader:
        for connection, stamp, data in reader.messages():
            out.setdefault(connection.topic, []).append(
                (stamp, reader.deserialize(data, connection.msgtype)))
    return out


def _stamp(header):
    return header.stamp.sec * NS + header.stamp.nanosec


def _camera_files(folder, times, seed):
    """Frames, exact depth and forward flow at ``times`` (strings of seconds) in ``folder``."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "calib.txt").write_text("30.5 29.5 15.25 11.75 -0.1 0.02 0.001 -0.002 0.0003\n")
    for sub in ("images", "depth", "flow"):
        (folder / sub).mkdir()
    images, depths, flows = [], [], []
    for k, t in enumerate(times):
        cv2.imwrite(str(folder / f"images/frame_{k:08d}.png"),
                    rng.integers(0, 256, (H, W), dtype=np.uint8))
        write_depth(folder / f"depth/frame_{k:08d}.exr",
                    rng.uniform(0.5, 3.0, (H, W)).astype(np.float32))
        write_exr_channels(folder / f"flow/forward_{k:08d}.exr",
                           {"du": rng.normal(size=(H, W)).astype(np.float32),
                            "dv": rng.normal(size=(H, W)).astype(np.float32),
                            "flags": np.zeros((H, W), np.float32)})
        images.append(f"{t} images/frame_{k:08d}.png\n")
        depths.append(f"{t} depth/frame_{k:08d}.exr\n")
        flows.append(f"{t} flow/forward_{k:08d}.exr\n")
    (folder / "images.txt").write_text("".join(images))
    (folder / "depthmaps.txt").write_text("".join(depths))
    (folder / "flow_forward.txt").write_text("".join(flows))


def _simulated(folder, rig=False):
    """A hand-made simulated sequence: events, frames, depth, flow, poses, IMU, velocity; for
    a rig the frames, depth and flow are the frame camera's."""
    times = ["0.010000000", "0.043333333", "0.076666667"]
    folder.mkdir()
    if rig:
        (folder / "calib.txt").write_text("31 31 16 12 0 0 0 0 0\n")
        (folder / "images.txt").write_text("")
        (folder / "sequence.json").write_text(f'{{"camera": {{"width": {W}, "height": {H}}}}}')
        _camera_files(folder / "frame_camera", times, 1)
        (folder / "frame_camera" / "T_event_frame.txt").write_text(
            "0.05 0 0 0 0 0.0499791692706783 0.998750260394966\n")
    else:
        _camera_files(folder, times, 1)
    (folder / "groundtruth.txt").write_text(
        "".join(f"{0.005 * k:.9f} {0.01 * k} 0.5 -0.25 0 0 0.0499791692706783 "
                "0.998750260394966\n" for k in range(20)))
    (folder / "imu.txt").write_text(
        "".join(f"{0.002 * k:.9f} 0.1 -9.81 0.3 0.01 0.02 {0.001 * k}\n" for k in range(45)))
    (folder / "velocity.txt").write_text(
        "".join(f"{0.005 * k:.9f} 1 0 0 0 0 0.5\n" for k in range(20)))
    rng = np.random.default_rng(2)
    n = 3000
    events = make_events(np.sort(rng.integers(0, 90_000_000, n)), rng.integers(0, W, n),
                         rng.integers(0, H, n), rng.choice([-1, 1], n))
    with TextEventWriter(folder / "events.txt") as writer:
        writer.write(events)
    return events


@pytest.mark.parametrize("name", ["seq.bag", "seq.mcap"])
def test_a_simulated_sequence_gives_every_topic_read_back_by_rosbags(tmp_path, name):
    events = _simulated(tmp_path / "s")
    counts = write_sequence_bag(tmp_path / "s", tmp_path / name)
    topics = {"/dvs/events": 9, "/dvs/image_raw": 3, "/dvs/depthmap": 3, "/dvs/camera_info": 3,
              "/dvs/pose": 20, "/tf": 20, "/dvs/twist": 20, "/imu": 45, "/dvs/forward_flow": 3}
    assert counts == dict(sorted(topics.items()))
    messages = _all_messages(tmp_path / name)
    assert {topic: len(m) for topic, m in messages.items()} == topics
    stamps = [s for m in messages.values() for s, _ in m]
    with AnyReader([tmp_path / name]) as reader:              # the bag is in time order
        assert [s for _, s, _ in reader.messages()] == sorted(stamps)
    got = [(e.ts.sec * NS + e.ts.nanosec, e.x, e.y) for _, m in messages["/dvs/events"]
           for e in m.events]
    np.testing.assert_array_equal(np.array(got), np.stack([events["t"], events["x"],
                                                           events["y"]], axis=1))
    folder = tmp_path / "s"
    for k, (stamp, image) in enumerate(messages["/dvs/image_raw"]):
        assert stamp == _stamp(image.header) == exact_ns(
            (folder / "images.txt").read_text().split()[2 * k], "")
        assert (image.encoding, image.width, image.height, image.step) == ("mono8", W, H, W)
        png = cv2.imread(str(folder / f"images/frame_{k:08d}.png"), cv2.IMREAD_GRAYSCALE)
        np.testing.assert_array_equal(image.data.reshape(H, W), png)
    from sim.exr import read_depth

    for k, (_, depth) in enumerate(messages["/dvs/depthmap"]):
        assert (depth.encoding, depth.step, depth.is_bigendian) == ("32FC1", 4 * W, 0)
        np.testing.assert_array_equal(depth.data.view("<f4").reshape(H, W),
                                      read_depth(folder / f"depth/frame_{k:08d}.exr"))
    _, info = messages["/dvs/camera_info"][0]
    ros1 = name.endswith(".bag")
    d, k = (info.D, info.K) if ros1 else (info.d, info.k)
    assert info.distortion_model == "plumb_bob"
    np.testing.assert_array_equal(d, [-0.1, 0.02, 0.001, -0.002, 0.0003])
    np.testing.assert_array_equal(k, [30.5, 0, 15.25, 0, 29.5, 11.75, 0, 0, 1])
    stamp, pose = messages["/dvs/pose"][3]
    assert stamp == 15_000_000 and pose.header.frame_id == "map"
    assert (pose.pose.position.x, pose.pose.orientation.w) == (0.03, 0.998750260394966)
    _, tf = messages["/tf"][3]
    assert (tf.transforms[0].header.frame_id, tf.transforms[0].child_frame_id) == ("map", "dvs")
    assert tf.transforms[0].transform.translation.x == 0.03
    stamp, imu = messages["/imu"][44]
    assert stamp == 88_000_000
    assert (imu.linear_acceleration.y, imu.angular_velocity.z) == (-9.81, 0.044)
    assert imu.orientation_covariance[0] == -1
    _, twist = messages["/dvs/twist"][0]
    assert (twist.twist.linear.x, twist.twist.angular.z) == (1.0, 0.5)
    from sim.flow import read_flow

    _, flow = messages["/dvs/forward_flow"][1]
    exact, _ = read_flow(folder / "flow/forward_00000001.exr")
    np.testing.assert_array_equal(flow.flow_x.reshape(H, W), exact[..., 0])
    np.testing.assert_array_equal(flow.flow_y.reshape(H, W), exact[..., 1])


def test_a_rig_gives_two_namespaces_and_the_extrinsic_on_tf_static(tmp_path):
    _simulated(tmp_path / "r", rig=True)
    counts = write_sequence_bag(tmp_path / "r", tmp_path / "rig", ros=2, storage="sqlite3")
    assert set(counts) == {"/dvs/events", "/dvs/camera_info", "/dvs/pose", "/dvs/twist", "/tf",
                           "/tf_static", "/imu", "/frame_camera/image_raw",
                           "/frame_camera/depthmap", "/frame_camera/camera_info",
                           "/frame_camera/forward_flow"}
    messages = _all_messages(tmp_path / "rig")
    _, static = messages["/tf_static"][0]
    transform = static.transforms[0]
    assert (transform.header.frame_id, transform.child_frame_id) == ("dvs", "frame_camera")
    assert transform.transform.translation.x == pytest.approx(0.05, abs=1e-15)
    assert transform.transform.rotation.w == pytest.approx(0.998750260394966, abs=1e-15)
    infos = {topic: messages[topic][0][1] for topic in ("/dvs/camera_info",
                                                       "/frame_camera/camera_info")}
    assert infos["/dvs/camera_info"].k[0] == 31.0 and infos["/frame_camera/camera_info"].k[0] \
        == 30.5
    assert messages["/frame_camera/image_raw"][0][1].header.frame_id == "frame_camera"
    recording = BagRecording(tmp_path / "rig")
    assert recording.image_topic == "/frame_camera/image_raw"
    assert recording.camera_info_topic == "/dvs/camera_info"      # the events' namespace


@pytest.mark.parametrize("name", ["ecd.bag", "ecd"])
def test_the_ecd_prefix_read_back_from_a_bag_is_the_same_recording(tmp_path, name, ecd_slider):
    write_sequence_bag(ecd_slider, tmp_path / name, ros=2 if name == "ecd" else None)
    recording = BagRecording(tmp_path / name)
    assert recording.topics == {"/dvs/events": "dvs_msgs/msg/EventArray",
                                "/dvs/image_raw": "sensor_msgs/msg/Image",
                                "/dvs/camera_info": "sensor_msgs/msg/CameraInfo",
                                "/dvs/pose": "geometry_msgs/msg/PoseStamped",
                                "/tf": "tf2_msgs/msg/TFMessage"}
    assert recording.imu_topic is None
    np.testing.assert_array_equal(np.concatenate(list(recording.iter_events(7_000))),
                                  read_events(ecd_slider / "events.txt"))
    assert recording.camera() == read_calib(ecd_slider / "calib.txt", 240, 180)
    rows = [line.split() for line in (ecd_slider / "images.txt").read_text().splitlines()]
    frames = list(recording.frames())
    assert [t for t, _ in frames] == [exact_ns(r[0], "") for r in rows]
    for (_, frame), row in zip(frames[::20], rows[::20], strict=True):
        np.testing.assert_array_equal(frame, cv2.imread(str(ecd_slider / row[1]),
                                                        cv2.IMREAD_GRAYSCALE))
    times, poses = recording.poses()
    text = np.loadtxt(ecd_slider / "groundtruth.txt")
    assert times.tolist() == [exact_ns(line.split()[0], "") for line in
                              (ecd_slider / "groundtruth.txt").read_text().splitlines()]
    np.testing.assert_array_equal(poses, text[:, 1:])


def test_bag_recording_topics_are_found_or_named(tmp_path):
    _simulated(tmp_path / "s")
    write_sequence_bag(tmp_path / "s", tmp_path / "s.bag")
    recording = BagRecording(tmp_path / "s.bag")
    assert recording.image_topic == "/dvs/image_raw"            # not the 32FC1 depth map
    times, imu = recording.imu()
    assert times[1] == 2_000_000 and imu[1].tolist() == [0.1, -9.81, 0.3, 0.01, 0.02, 0.001]
    with pytest.raises(ValueError, match=r"s\.bag: no topic '/cam/x'; expected one of "):
        BagRecording(tmp_path / "s.bag", image_topic="/cam/x")
    with pytest.raises(ValueError, match=r"s\.bag: topic '/imu' is sensor_msgs/msg/Imu; "
                                         r"expected sensor_msgs/msg/Image"):
        BagRecording(tmp_path / "s.bag", image_topic="/imu")
    depth = BagRecording(tmp_path / "s.bag", image_topic="/dvs/depthmap")
    with pytest.raises(ValueError, match="has encoding '32FC1'; expected mono8"):
        next(depth.frames())


def test_convert_of_a_sequence_folder_writes_the_bag_and_refuses_an_existing_one(tmp_path,
                                                                                 capsys):
    _simulated(tmp_path / "s")
    assert run_cli(["convert", str(tmp_path / "s"), str(tmp_path / "out"), "--ros", "2"]) == 0
    assert "/dvs/events 9" in capsys.readouterr().out
    assert (tmp_path / "out" / "metadata.yaml").is_file()
    assert run_cli(["convert", str(tmp_path / "s"), str(tmp_path / "out"), "--ros", "2"]) == 2
    assert "exists; add --overwrite" in capsys.readouterr().err
    assert run_cli(["convert", str(tmp_path / "s"), str(tmp_path / "out"), "--ros", "2",
                    "--overwrite"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "s"]


def test_a_ros1_bag_declares_the_md5sums_of_the_ros_packages(tmp_path):
    """ROS 1 players refuse a message whose md5sum differs from their package's; these are
    the md5sums in rpg_dvs_ros's generated dvs_msgs headers and in ROS Noetic's packages."""
    from rosbags.rosbag1 import Reader

    _simulated(tmp_path / "s")
    write_sequence_bag(tmp_path / "s", tmp_path / "s.bag")
    with Reader(tmp_path / "s.bag") as reader:
        digests = {c.msgtype: c.digest for c in reader.connections}
    assert digests["dvs_msgs/msg/EventArray"] == "5e8beee5a6c107e504c2e78903c224b8"
    assert digests["sensor_msgs/msg/Image"] == "060021388200f6f0f447d0fcd9c64743"
    assert digests["sensor_msgs/msg/CameraInfo"] == "c9a58c1b0b154e0e6da7578cb991d214"
    assert digests["geometry_msgs/msg/PoseStamped"] == "d3812c3cbc69362b77dc0b19b345f8f5"
    assert digests["sensor_msgs/msg/Imu"] == "6a62c6daae103f4ff57a132d6f95cec2"
    assert digests["tf2_msgs/msg/TFMessage"] == "94810edda583a504dfda3829e70d7eec"


def test_the_ecd_prefix_maps_identically_from_text_a_ros1_bag_and_a_ros2_bag(
        tmp_path, ecd_slider, capsys, monkeypatch):
    """ECD folder -> bag -> ``evfuse map BAG`` (unpacked into the cache) and -> ``evfuse convert
    BAG FOLDER`` -> ``evfuse map``: the same map points, bit for bit, as mapping the ECD folder
    itself."""
    from sim.exr import read_depth

    monkeypatch.setenv("EVFUSE_CACHE", str(tmp_path / "cache"))

    depth_range = ["--min-depth", "0.47", "--max-depth", "2.4", "--quiet"]
    assert run_cli(["map", str(ecd_slider), "--out", str(tmp_path / "map-txt"),
                    *depth_range]) == 0
    reference = read_depth(tmp_path / "map-txt" / "semidense_depth.exr")
    for bag in ("ecd.bag", "ecd.mcap"):
        assert run_cli(["convert", str(ecd_slider), str(tmp_path / bag)]) == 0
        folder = tmp_path / f"folder_{bag.replace('.', '_')}"
        assert run_cli(["convert", str(tmp_path / bag), str(folder)]) == 0
        assert (folder / "images.txt").read_text() == (ecd_slider / "images.txt").read_text()
        np.testing.assert_array_equal(read_events(folder / "events.h5"),
                                      read_events(ecd_slider / "events.txt"))
        assert run_cli(["map", str(folder), "--out", str(tmp_path / f"map-{bag}"),
                        *depth_range]) == 0
        depth = read_depth(tmp_path / f"map-{bag}" / "semidense_depth.exr")
        assert (depth > 0).sum() > 1000
        np.testing.assert_array_equal(depth, reference)
        assert run_cli(["map", str(tmp_path / bag), "--out", str(tmp_path / f"direct-{bag}"),
                        *depth_range]) == 0                      # the bag as one recording
        np.testing.assert_array_equal(
            read_depth(tmp_path / f"direct-{bag}" / "semidense_depth.exr"), reference)
    capsys.readouterr()


def test_simulate_format_ros1_ros2_writes_bags_beside_events_h5_exactly(tmp_path):
    from tests.test_formats import simulated_formats

    _, out, exact = simulated_formats(tmp_path, ("h5", "ros1", "ros2"))
    assert exact.size > 0 and (exact["t"] % 1000).any()        # sub-microsecond times kept
    np.testing.assert_array_equal(read_events(out / "events.bag"), exact)
    np.testing.assert_array_equal(read_events(out / "events.mcap"), exact)


def test_a_rig_bag_unpacks_without_the_frame_cameras_frames(tmp_path):
    """The frames of /frame_camera are another camera's: the event camera's folder gets none."""
    from sim.sequence_bag import unpack_bag

    _simulated(tmp_path / "r", rig=True)
    write_sequence_bag(tmp_path / "r", tmp_path / "rig.bag")
    (tmp_path / "out").mkdir()
    unpack_bag(BagRecording(tmp_path / "rig.bag"), tmp_path / "out")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["calib.txt",
                                                                   "groundtruth.txt", "imu.txt"]
    assert (tmp_path / "out" / "calib.txt").read_text().split()[0] == "31.0"
