"""A rig of two cameras: [event_camera] + [frame_camera], their files and their exact depth.

Every ground truth is checked against an independent computation: the rig's extrinsic from
SciPy's rotations, the event camera's pose written out by hand, OpenCV's undistortion, and a
ray-plane intersection in NumPy.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim.exr import read_depth
from sim.scene import SceneError, load_scene, parse_scene
from tests.conftest import scene_text, undistort_points

EVENT = "[event_camera]\nwidth = 64\nheight = 48\nfx = 60.0\nfy = 45.0\ncx = 30.3\ncy = 22.7\n"
FRAME = ("[frame_camera]\nwidth = 80\nheight = 60\nfx = 70.0\nfy = 66.0\ncx = 40.2\n"
         "cy = 29.6\ndistortion = [-0.2, 0.05, 0.001, -0.002, 0.0]\n")
EXTRINSIC = "T_event_frame = { translation = [0.1, 0.0, 0.0], rotation = [2.0, -5.0, 3.0] }\n"
DISTORTION = (-0.2, 0.05, 0.001, -0.002, 0.0)
# The event camera slides and climbs while looking along +y (z up): OpenCV axes x right,
# y down, z forward, so its rotation has columns (1, 0, 0), (0, 0, -1), (0, 1, 0).
VELOCITY = np.array([0.3, 0.2, 0.1])
R_WORLD_EVENT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
MOVING = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
          "velocity = [0.3, 0.2, 0.1]\nlook_at = [0.0, 1.0, 0.0]\n")
# A slanted plane (not fronto-parallel): centre C, front normal N (facing the camera).
PLANE_C = np.array([0.1, 1.2, 0.05])
PLANE_N = np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
PLANE = f"""
[[objects]]
name = "plane"
type = "rectangle"
center = {PLANE_C.tolist()}
size = [8.0, 8.0]
normal = {PLANE_N.tolist()}
[objects.material]
texture_scale = [8.0, 8.0]
texture = {{ type = "shapes", resolution = 256, count = 30, min_size = 10, max_size = 40 }}
"""
FRAMES = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 2\n[render]\nspp = 4\n"


def rig_text(frame_extra: str = EXTRINSIC, *, objects: str = PLANE, trajectory: str = MOVING,
             duration: float = 0.15) -> str:
    return scene_text(objects, camera=EVENT + "\n" + FRAME + frame_extra, trajectory=trajectory,
                      duration=duration, extra=FRAMES)


def T_event_frame() -> np.ndarray:
    """The extrinsic of :data:`EXTRINSIC`, from SciPy (extrinsic x, y, z = Rz Ry Rx)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [2.0, -5.0, 3.0], degrees=True).as_matrix()
    T[:3, 3] = [0.1, 0.0, 0.0]
    return T


def T_world_event(t: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_WORLD_EVENT, VELOCITY * t
    return T


def plane_depth(T_world_cam: np.ndarray, K: np.ndarray, distortion, width: int,
                height: int) -> np.ndarray:
    """z-depth (H, W) of the plane through PLANE_C with normal PLANE_N at every pixel centre:
    OpenCV undistorts the pixel, the ray from the centre meets the plane."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    uv = np.stack([u.ravel(), v.ravel()], axis=-1)[:, None, :]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = undistort_points(uv, K, distortion, criteria=criteria)[:, 0, :]
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)        # z = 1: s is the depth
    directions = rays @ T_world_cam[:3, :3].T
    s = (PLANE_N @ (PLANE_C - T_world_cam[:3, 3])) / (directions @ PLANE_N)
    return s.reshape(height, width)


# --- parsing -------------------------------------------------------------------------------

def test_rig_parses_event_camera_frame_camera_and_extrinsic():
    scene = parse_scene(rig_text())
    assert (scene.camera.width, scene.camera.height, scene.camera.fx) == (64, 48, 60.0)
    rig = scene.frame_camera
    assert (rig.camera.width, rig.camera.height, rig.camera.fy) == (80, 60, 66.0)
    assert rig.camera.distortion == DISTORTION
    np.testing.assert_allclose(rig.T_event_frame, T_event_frame(), atol=1e-12)
    assert (rig.shutter, rig.readout_s) == ("global", 0.0)


def test_quaternion_extrinsic_and_rolling_shutter():
    # 90 degrees about the event camera's z: the frame camera's x axis is the event camera's y.
    half = np.sqrt(0.5)
    extra = (f"shutter = \"rolling\"\nreadout_s = 0.02\nT_event_frame = {{ translation = "
             f"[0.0, 0.1, 0.0], quaternion = [0.0, 0.0, {half}, {half}] }}\n")
    rig = parse_scene(rig_text(extra)).frame_camera
    np.testing.assert_allclose(rig.T_event_frame[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0],
                               atol=1e-12)
    assert (rig.shutter, rig.readout_s) == ("rolling", 0.02)
    times = rig.row_times(1.0)
    assert times[0] == pytest.approx(0.99) and times[-1] == pytest.approx(1.01)


def test_camera_alone_keeps_one_sensor():
    scene = parse_scene(scene_text(PLANE))
    assert scene.frame_camera is None and scene.camera.width == 64


@pytest.mark.parametrize("cameras, expected", [
    ("", "missing required key 'camera' (or [event_camera] with [frame_camera]"),
    (EVENT, "[event_camera]: a rig needs both [event_camera] and [frame_camera]; "
            "[frame_camera] is missing"),
    (FRAME + EXTRINSIC, "[frame_camera]: a rig needs both"),
    ("[camera]\npreset = \"davis240c\"\n" + EVENT, "[event_camera]: expected either [camera]"),
    (EVENT + FRAME, "[frame_camera]: missing required key 'T_event_frame'"),
    (EVENT + FRAME + EXTRINSIC + "readout = 0.01\n", "[frame_camera]: unknown key 'readout'"),
    (EVENT + FRAME + EXTRINSIC + "shutter = \"rolling\"\n",
     "[frame_camera]: shutter = \"rolling\" needs readout_s"),
    (EVENT + FRAME + EXTRINSIC + "readout_s = 0.01\n",
     "[frame_camera].readout_s: is a rolling shutter's readout time"),
    (EVENT + FRAME + EXTRINSIC + "shutter = \"fast\"\n",
     "[frame_camera].shutter: expected one of global, rolling; got 'fast'"),
    (EVENT + FRAME + "T_event_frame = { translation = [0.1, 0.0], rotation = [0, 0, 0] }\n",
     "[frame_camera].T_event_frame.translation: expected a list of 3 numbers"),
    (EVENT + FRAME + "T_event_frame = { translation = [0.1, 0, 0], rotation = [0, 0, 0], "
     "quaternion = [0, 0, 0, 1] }\n", "expected either 'rotation' (degrees) or 'quaternion'"),
    (EVENT + FRAME + "T_event_frame = { translation = [0.1, 0, 0], quaternion = [0, 0, 0, 0] }\n",
     "[frame_camera].T_event_frame.quaternion: expected a non-zero quaternion"),
    (EVENT + FRAME + "T_event_frame = { translation = [0.1, 0, 0], scale = 2 }\n",
     "[frame_camera].T_event_frame: unknown key 'scale'"),
    (EVENT.replace("fx = 60.0", "fx = -1.0") + FRAME + EXTRINSIC,
     "[event_camera].fx: expected a positive number"),
])
def test_bad_rig_declarations_are_refused_in_one_line(cameras, expected):
    text = scene_text(PLANE, camera="[render]\nspp = 4\n").replace(
        "[render]\nspp = 4\n", cameras, 1)
    with pytest.raises(SceneError) as caught:
        parse_scene(text, "rig.toml")
    message = str(caught.value)
    assert message.startswith("rig.toml: ") and expected in message and "\n" not in message


def test_rolling_shutter_is_refused_with_moving_objects():
    moving = PLANE.replace("[objects.material]", "motion = { type = \"linear\", velocity = "
                           "[0.1, 0.0, 0.0] }\n[objects.material]")
    text = rig_text(EXTRINSIC + "shutter = \"rolling\"\nreadout_s = 0.01\n", objects=moving)
    with pytest.raises(SceneError, match=r"\[frame_camera\]\.shutter: a rolling shutter is "
                                         "simulated for static scenes only"):
        parse_scene(text)


# --- a simulated rig: files, exact depth of both cameras, loading ----------------------------

@pytest.fixture(scope="module")
def rig_sequence(tmp_path_factory) -> Path:
    from sim.simulate import simulate

    out = tmp_path_factory.mktemp("rig") / "seq"
    return simulate(parse_scene(rig_text()), out, progress=False).out


def test_frame_camera_depth_is_the_plane_in_its_own_pose(rig_sequence):
    folder = rig_sequence / "frame_camera"
    lines = (folder / "depthmaps.txt").read_text().split("\n")[:-1]
    assert len(lines) == 3
    K = np.array([[70.0, 0.0, 40.2], [0.0, 66.0, 29.6], [0.0, 0.0, 1.0]])
    for line in lines:
        t, name = float(line.split()[0]), line.split()[1]
        depth = read_depth(folder / name)
        assert depth.shape == (60, 80)
        expected = plane_depth(T_world_event(t) @ T_event_frame(), K, DISTORTION, 80, 60)
        np.testing.assert_allclose(depth, expected, rtol=2e-6)
        # The event camera's pose instead would be 10 cm off: far beyond the tolerance.
        wrong = plane_depth(T_world_event(t), K, DISTORTION, 80, 60)
        assert np.abs(depth - wrong).max() > 1e-2


def test_event_camera_depth_at_the_frame_times(rig_sequence):
    lines = (rig_sequence / "depthmaps.txt").read_text().split("\n")[:-1]
    frame_lines = (rig_sequence / "frame_camera" / "images.txt").read_text().split("\n")[:-1]
    assert [line.split()[0] for line in lines] == [line.split()[0] for line in frame_lines]
    K = np.array([[60.0, 0.0, 30.3], [0.0, 45.0, 22.7], [0.0, 0.0, 1.0]])
    for line in lines:
        t, name = float(line.split()[0]), line.split()[1]
        depth = read_depth(rig_sequence / name)
        assert depth.shape == (48, 64)
        np.testing.assert_allclose(depth, plane_depth(T_world_event(t), K, (0.0,) * 5, 64, 48),
                                   rtol=2e-6)


def test_rig_folder_loads_as_ecd_folder_with_its_frame_camera(rig_sequence):
    from sim.sequence import load_sequence
    from sim.trajectory import read_trajectory

    assert (rig_sequence / "images.txt").read_text() == ""
    seq = load_sequence(rig_sequence)
    assert (seq.camera.width, seq.camera.height, seq.camera.fx, seq.camera.cy) == (
        64, 48, 60.0, 22.7)
    assert len(seq.image_times) == 0 and seq.image_paths == ()
    assert seq.events_h5 is not None and seq.groundtruth_path is not None
    np.testing.assert_allclose(read_trajectory(seq.groundtruth_path).pose(0.1),
                               T_world_event(0.1), atol=1e-9)
    fc = seq.frame_camera
    assert fc.folder == rig_sequence / "frame_camera"
    assert (fc.camera.width, fc.camera.height, fc.camera.fx, fc.camera.fy, fc.camera.cx,
            fc.camera.cy) == (80, 60, 70.0, 66.0, 40.2, 29.6)
    assert fc.camera.distortion == DISTORTION
    times = 0.005 + 0.05 * np.arange(3)                 # mid-exposure: k / 20 Hz + 10 ms / 2
    np.testing.assert_allclose(fc.image_times, times, atol=1e-9)
    np.testing.assert_allclose(fc.depth_times, times, atol=1e-9)
    np.testing.assert_allclose(seq.depth_times, times, atol=1e-9)
    assert [p.name for p in fc.image_paths] == [f"frame_{k:08d}.png" for k in range(3)]
    frame = cv2.imread(str(fc.image_paths[0]), cv2.IMREAD_UNCHANGED)
    assert frame.shape == (60, 80) and frame.dtype == np.uint8 and frame.std() > 5
    assert len(fc.depth_paths) == 3 and all(p.is_file() for p in fc.depth_paths)
    np.testing.assert_allclose(fc.T_event_frame, T_event_frame(), atol=1e-12)
    assert (fc.shutter, fc.readout_s) == ("global", 0.0)
    np.testing.assert_array_equal(fc.row_times(0.055), np.full(60, 0.055))
    record = json.loads((rig_sequence / "sequence.json").read_text())["frame_camera"]
    np.testing.assert_allclose(record["T_event_frame"], T_event_frame(), atol=1e-12)
    assert (record["width"], record["shutter"], record["readout_s"]) == (80, "global", 0.0)
    assert json.loads((rig_sequence / "sequence.json").read_text())["camera"]["width"] == 64


def test_row_times_of_loaded_rolling_shutter(rig_sequence):
    from sim.sequence import load_sequence

    fc = replace(load_sequence(rig_sequence).frame_camera, shutter="rolling", readout_s=0.03)
    times = fc.row_times(2.0)
    assert times.shape == (60,)
    assert times[0] == pytest.approx(1.985) and times[-1] == pytest.approx(2.015)
    np.testing.assert_allclose(np.diff(times), 0.03 / 59)


def test_rolling_shutter_depth_is_each_row_in_its_own_pose():
    from sim.two_camera import RollingShutterView, frame_camera_scene

    scene = parse_scene(rig_text(EXTRINSIC + "shutter = \"rolling\"\nreadout_s = 0.04\n"))
    view = RollingShutterView(frame_camera_scene(scene), scene.frame_camera)
    depth = view.depth(0.1)
    K = np.array([[70.0, 0.0, 40.2], [0.0, 66.0, 29.6], [0.0, 0.0, 1.0]])
    for row in (0, 17, 59):
        t_row = 0.1 + (row / 59 - 0.5) * 0.04
        expected = plane_depth(T_world_event(t_row) @ T_event_frame(), K, DISTORTION, 80, 60)
        np.testing.assert_allclose(depth[row], expected[row], rtol=2e-6)
    # Row 0 is 20 ms before the middle: at 0.39 m/s that changes its depth measurably.
    middle = plane_depth(T_world_event(0.1) @ T_event_frame(), K, DISTORTION, 80, 60)
    assert np.abs(depth[0] - middle[0]).max() > 1e-3


# --- rolling shutter: a vertical edge under a pure rotation about y shears -------------------

EDGE = """
[[objects]]
name = "edge"
type = "rectangle"
center = [-1.5, 1.0, 0.0]
size = [3.0, 3.0]
normal = [0.0, -1.0, 0.0]
material = { color = 0.6 }
"""


def _yaw_keyframe(t: float, degrees: float) -> str:
    a = np.radians(degrees)
    return (f"{{ t = {t}, position = [0.0, 0.0, 0.0], look_at = [{float(np.sin(a))!r}, "
            f"{float(np.cos(a))!r}, 0.0] }}")


# The rig turns about the vertical (the cameras' y axis) at about 3.5 rad/s, in place.
YAW = ('[trajectory]\ntype = "spline"\nkeyframes = [' + ", ".join(
    _yaw_keyframe(t, d) for t, d in ((0.0, -20.0), (0.1, 0.0), (0.2, 20.0))) + "]\n")


def _edge_column(luminance: np.ndarray) -> np.ndarray:
    """Sub-pixel column (H,) of the bright area's right edge in each row: the bright area
    covers [-0.5, edge) and every pixel integrates its own square (a box filter)."""
    bright = np.median(luminance[:, :4])
    return -0.5 + luminance.sum(axis=1) / bright


def _edge_u(T_world_cam: np.ndarray, row: int) -> float:
    """Column at which the edge (the world line x = 0, y = 1) crosses image row ``row`` for
    a camera at ``T_world_cam``: the line sampled densely and projected by OpenCV."""
    line = np.stack([np.zeros(4001), np.ones(4001), np.linspace(-1.0, 1.0, 4001)], axis=1)
    points = (line - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
    K = np.array([[70.0, 0.0, 40.2], [0.0, 66.0, 29.6], [0.0, 0.0, 1.0]])
    uv = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, np.array(DISTORTION))[0][:, 0]
    order = np.argsort(uv[:, 1])
    return float(np.interp(row, uv[order, 1], uv[order, 0]))


def test_rolling_shutter_shears_a_vertical_edge_by_the_predicted_amount():
    from sim.two_camera import RollingShutterView, frame_camera_scene

    readout = 0.04
    extra = ("T_event_frame = { translation = [0.0, 0.0, 0.0] }\nshutter = \"rolling\"\n"
             f"readout_s = {readout}\n")
    text = rig_text(extra, objects=EDGE, trajectory=YAW, duration=0.2).replace(
        "spp = 4", "spp = 64")
    scene = parse_scene(text)
    view = RollingShutterView(frame_camera_scene(scene), scene.frame_camera)
    t_mid = 0.1
    rows = np.arange(60)
    measured = _edge_column(view.luminance(t_mid))
    # Independent prediction: where the edge (the world line x = 0, y = 1) projects at each
    # row's time, with each row's own pose; the frame camera sits on the event camera here.
    predicted = np.array([_edge_u(scene.trajectory.pose(t_mid + (row / 59 - 0.5) * readout),
                                  row) for row in rows])
    assert abs(predicted[-1] - predicted[0]) > 5.0                 # several pixels of shear
    np.testing.assert_allclose(measured, predicted, atol=0.15)
    # The same instant seen by a global shutter: all rows at t_mid, the edge (bent only by
    # the lens) where the pose at t_mid puts it.
    from sim.render import Renderer

    still = _edge_column(Renderer(frame_camera_scene(scene)).luminance(t_mid))
    straight = np.array([_edge_u(scene.trajectory.pose(t_mid), row) for row in rows])
    np.testing.assert_allclose(still, straight, atol=0.15)
    assert np.abs(still - measured).max() > 2.0
    # Depth rows too: the first empty pixel of every row is the one just past the edge.
    depth = view.depth(t_mid)
    first_empty = np.argmax(depth == 0, axis=1)
    assert np.all(np.abs(first_empty - 0.5 - predicted) <= 0.5 + 1e-3)


# --- built-in rig scenes ---------------------------------------------------------------------

@pytest.mark.parametrize("name", ["rig_boxes", "rig_complex_sphere"])
def test_builtin_rig_scenes_load(name):
    from scenes import resolve_scene

    scene = load_scene(resolve_scene(name))
    assert (scene.camera.width, scene.camera.height) == (640, 480)
    rig = scene.frame_camera
    assert (rig.camera.width, rig.camera.height) == (1280, 720)
    np.testing.assert_allclose(np.linalg.norm(rig.T_event_frame[:3, 3]), 0.08)
    # The frame camera, 8 cm aside (seen at 256x144 here), sees the scene within its range.
    from sim.render import Renderer
    from sim.two_camera import frame_camera_scene

    view = frame_camera_scene(replace(scene, frame_camera=replace(
        rig, camera=rig.camera.with_resolution(256, 144))))
    depth = Renderer(view, spp=1).depth(scene.duration / 2)
    hit = depth > 0
    near, far = scene.depth_range
    assert hit.mean() > 0.95 and near < depth[hit].min() and depth[hit].max() < far


def test_builtin_rig_scene_simulates_at_reduced_size(tmp_path):
    from scenes import resolve_scene
    from sim.sequence import load_sequence
    from sim.simulate import simulate

    scene = load_scene(resolve_scene("rig_boxes"))
    rig = scene.frame_camera
    small = replace(scene, camera=scene.camera.with_resolution(48, 36),
                    frame_camera=replace(rig, camera=rig.camera.with_resolution(64, 36)))
    out = simulate(small, tmp_path / "rig", duration=0.09, spp=1, with_events=False,
                   progress=False).out
    seq = load_sequence(out)
    assert seq.frame_camera.camera.width == 64 and len(seq.frame_camera.image_times) == 2
    assert read_depth(seq.depth_paths[0]).shape == (36, 48)
    assert (read_depth(seq.frame_camera.depth_paths[0]) > 0).mean() > 0.9


def test_the_frame_cameras_acceleration_is_the_derivative_of_its_velocity():
    from sim.frame_camera import RigTrajectory
    from sim.trajectory import HandheldTrajectory

    event = HandheldTrajectory(rotation=Rotation.from_euler("xyz", [80, 5, 10],
                                                            degrees=True).as_matrix(),
                               position=np.zeros(3),
                               translation_amplitude=np.array([0.1, 0.05, 0.08]),
                               rotation_amplitude=np.radians([10.0, 12.0, 8.0]),
                               frequencies=np.array([0.5, 0.7, 0.6, 0.8, 0.9, 0.4]),
                               phases=np.zeros(6), chirp=0.1)
    extrinsic = np.eye(4)
    extrinsic[:3, 3] = [0.08, -0.02, 0.01]
    rig = RigTrajectory(event, extrinsic)
    t, h = np.linspace(0.2, 1.8, 9), 1e-5
    a, alpha = rig.acceleration(t)
    v_plus, w_plus = rig.velocity(t + h)
    v_minus, w_minus = rig.velocity(t - h)
    np.testing.assert_allclose(a, (v_plus - v_minus) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(alpha, (w_plus - w_minus) / (2 * h), atol=1e-6)


def test_the_pipeline_maps_in_the_event_camera_and_fills_in_the_frame_camera(rig_sequence,
                                                                             tmp_path):
    # End to end on the simulated rig: events of the 64x48 camera mapped there, the map
    # projected into the 80x60 distorted frame camera 10 cm away, filled and scored there.
    from fusion.map.emvs import DepthMapParams
    from fusion.pipeline import RunParams, fill_window, run_pipeline
    from sim.exr import write_depth
    from sim.sequence import load_sequence

    run = tmp_path / "run"
    # rpg_emvs's point set (the DSI's end planes kept): 189 points against 137, a finer mesh
    # in the distorted frame (with 137 its worst filled pixel, at the border, is 2.7 % off)
    report = run_pipeline(rig_sequence, run, RunParams(
        min_depth=0.4, max_depth=3.0, depth=DepthMapParams(keep_boundary_planes=True)),
        progress=False)
    assert report["rig"]["width"] == 80 and read_depth(run / "fill" / "dense_depth.exr").shape \
        == (60, 80)
    # This tiny, short rig's event map is poor (tens of cm): to test the geometry alone, give
    # the map's own pixels their exact depth in the event camera (read from the sequence, the
    # depth map at the reference time), then fill again.
    t_ref = json.loads((run / "map" / "map.json").read_text())["t_ref"]
    sequence = load_sequence(rig_sequence)
    exact = read_depth(sequence.depth_paths[sequence.nearest_depth(t_ref)])
    points = read_depth(run / "map" / "semidense_depth.exr") > 0
    write_depth(run / "map" / "semidense_depth.exr", np.where(points, exact, 0).astype(np.float32))
    filled = fill_window(run / "map", tmp_path / "fill", method="mesh")
    K = np.array([[70.0, 0.0, 40.2], [0.0, 66.0, 29.6], [0.0, 0.0, 1.0]])
    t_frame = filled.info["t_frame"]
    truth = plane_depth(T_world_event(t_frame) @ T_event_frame(), K, DISTORTION, 80, 60)
    dense = read_depth(tmp_path / "fill" / "dense_depth.exr")
    inside = dense > 0
    # Map points land on the nearest pixel (half a pixel of the plane's slope); between them
    # the mesh is exact for a plane through the lens: within 1 % almost wherever it fills. The
    # triangles along the map's outline depend on which points the events gave: with the
    # footprint-filtered texture (195 points) one triangle at the frame's left border, 19 of
    # 3,265 filled pixels, is up to 2.7 % off, as the 137-point set's border was above.
    assert inside.mean() > 0.3
    error = np.abs(dense[inside] / truth[inside] - 1)
    assert error.max() < 0.03 and np.mean(error > 0.01) < 0.01
    fill = json.loads((tmp_path / "fill" / "fill.json").read_text())
    assert fill["truth"].startswith("frame_camera/")
    own = 100 * np.mean(np.abs(dense - truth)[inside])
    assert fill["errors"]["all"]["overall"]["mae_cm"] == pytest.approx(own, rel=1e-3, abs=1e-4)


def test_rolling_shutter_flow_lands_each_point_on_the_row_that_sees_it(tmp_path):
    # A rolling-shutter frame camera (30 ms readout) sliding past the slanted plane: for
    # sampled pixels, the plane's point at the pixel's row time (an analytic ray-plane hit)
    # projected by OpenCV from the pose of the target row found by brute force over rows.
    from sim.flow import read_flow
    from sim.sequence import load_sequence
    from sim.simulate import simulate

    extra = 'shutter = "rolling"\nreadout_s = 0.03\n' + EXTRINSIC
    out = simulate(parse_scene(rig_text(extra)), tmp_path / "seq", with_events=False,
                   progress=False).out
    frames = load_sequence(out).frame_camera
    assert frames.forward_flow is not None and frames.object_masks is not None
    record = json.loads((out / "sequence.json").read_text())["rolling_shutter"]
    assert record["readout_s"] == 0.03 and record["row_residual_px"] < 1e-4
    K = np.array([[70.0, 0.0, 40.2], [0.0, 66.0, 29.6], [0.0, 0.0, 1.0]])
    t_src, t_dst = frames.image_times[0], frames.image_times[1]
    flow, flags = read_flow(frames.forward_flow.paths[0])
    rows = np.linspace(0.0, 59.0, 59001)                           # target rows, 0.001 apart
    rng = np.random.default_rng(2)
    checked = 0
    for v, u in zip(rng.integers(2, 58, 40), rng.integers(2, 78, 40), strict=True):
        if flags[v, u]:
            continue
        pose = T_world_event(t_src + (v / 59 - 0.5) * 0.03) @ T_event_frame()
        depth = plane_depth(pose, K, DISTORTION, 80, 60)[v, u]
        xy = undistort_points(np.array([[[u, v]]], np.float64), K, DISTORTION,
                              criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                                           200, 1e-15))[0, 0]
        world = pose[:3, :3] @ (depth * np.array([*xy, 1.0])) + pose[:3, 3]
        landed = []
        for r in rows[::50]:                                          # coarse, then fine
            target = T_world_event(t_dst + (r / 59 - 0.5) * 0.03) @ T_event_frame()
            local = target[:3, :3].T @ (world - target[:3, 3])
            uv = cv2.projectPoints(local[None], np.zeros(3), np.zeros(3), K,
                                   np.array(DISTORTION))[0][0, 0]
            landed.append((abs(uv[1] - r), r, uv))
        _, r0, _ = min(landed, key=lambda item: item[0])
        best = None
        for r in rows[(rows > r0 - 0.06) & (rows < r0 + 0.06)]:
            target = T_world_event(t_dst + (r / 59 - 0.5) * 0.03) @ T_event_frame()
            local = target[:3, :3].T @ (world - target[:3, 3])
            uv = cv2.projectPoints(local[None], np.zeros(3), np.zeros(3), K,
                                   np.array(DISTORTION))[0][0, 0]
            if best is None or abs(uv[1] - r) < best[0]:
                best = (abs(uv[1] - r), uv)
        np.testing.assert_allclose(flow[v, u] + [u, v], best[1], atol=5e-3)
        checked += 1
    assert checked >= 30
