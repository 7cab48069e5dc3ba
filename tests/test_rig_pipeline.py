"""A two-camera rig through evfuse fill: the event map projected into the frame camera.

Each test builds a tiny rig sequence folder by hand (no rendering): a tilted checkerboard plane,
an event camera moving and turning at constant rates (so that ``groundtruth.txt``'s linear
position and slerp are exact between its samples), a frame camera 10 cm to the side with its own
size, lens (distortion) and rotation, its frames and exact depth computed by intersecting each
pixel's ray with the plane (OpenCV's undistortPoints and projectPoints, scipy's rotations:
none of evfuse's camera or pose code), and a map folder whose ``semidense_depth.exr`` holds the
plane's exact depth at the event camera's edge pixels.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.experiments.bench import run_bench
from fusion.fill.dense import fill_frame, fill_inputs
from fusion.fill.projection import rolling_shutter_project
from fusion.map.mapping import _reference_image
from fusion.pipeline import fill_window
from sim.camera import Camera
from sim.exr import read_depth, write_depth
from sim.sequence import load_sequence
from tests.conftest import undistort_points

EVENT = Camera(64, 48, 80.0, 78.0, 31.7, 23.2)
FRAME = Camera(56, 42, 60.0, 58.0, 27.6, 20.7, (-0.15, 0.05, 0.002, -0.001, 0.0))
T_EVENT_FRAME = np.eye(4)
T_EVENT_FRAME[:3, :3] = Rotation.from_euler("XYZ", [1.5, -2.0, 1.0], degrees=True).as_matrix()
T_EVENT_FRAME[:3, 3] = [0.10, 0.005, -0.01]                       # a 10 cm baseline
T_REF = 0.1
FRAME_TIMES = (0.04, 0.09, 0.14)                                  # t_ref 0.1 -> the 0.09 frame
VELOCITY = np.array([0.3, -0.1, 0.05])                            # m/s, world
OMEGA = np.array([2.0, 1.0, 0.5])                                 # rad/s, about a fixed axis
NORMAL = np.array([0.05, -0.04, 1.0]) / np.linalg.norm([0.05, -0.04, 1.0])  # 3.7 deg
OFFSET = float(NORMAL @ [0.0, 0.0, 1.5])                          # plane: NORMAL . X = OFFSET
SQUARE = 0.2                                                      # checker squares, metres


def pose(t) -> np.ndarray:
    """T_world_event(t): at the origin looking +z at T_REF, constant velocity and rotation."""
    t = np.atleast_1d(np.asarray(t, np.float64))
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(np.outer(t - T_REF, OMEGA)).as_matrix()
    T[:, :3, 3] = np.outer(t - T_REF, VELOCITY)
    return T


def rays(camera: Camera) -> np.ndarray:
    """(H, W, 3) rays (X/Z, Y/Z, 1) of every pixel centre, undistorted by OpenCV."""
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    pixels = np.stack([u, v], -1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = undistort_points(pixels, camera.K, camera.distortion, np.eye(3), np.eye(3),
                          criteria).reshape(camera.height, camera.width, 2)
    return np.concatenate([xy, np.ones(xy.shape[:2] + (1,))], -1)


def hit(ray: np.ndarray, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points where camera rays (..., 3) meet the plane, and their z-depth."""
    R, c = T_world_cam[..., :3, :3], T_world_cam[..., :3, 3]
    direction = np.einsum("...ij,...j->...i", R, ray)
    depth = (OFFSET - np.einsum("i,...i->...", NORMAL, c)) / (direction @ NORMAL)
    return c + depth[..., None] * direction, depth


def checker(points: np.ndarray) -> np.ndarray:
    e1 = np.cross(NORMAL, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(NORMAL, e1)
    s, t = points @ e1 / SQUARE, points @ e2 / SQUARE
    return ((np.floor(s) + np.floor(t)) % 2).astype(np.uint8)


def frame_row_poses(t_frame: float, readout: float) -> np.ndarray:
    """(H, 4, 4) T_world_frame of each row (all the same for a global shutter)."""
    h = FRAME.height
    times = t_frame + (np.arange(h) / (h - 1) - 0.5) * readout
    return pose(times) @ T_EVENT_FRAME


def write_rig(folder: Path, shutter: str = "global", readout: float = 0.0) -> Path:
    """The rig sequence folder and its map folder (``folder/map``); returns the map folder."""
    seq = folder / "sequence"
    (seq / "frame_camera" / "images").mkdir(parents=True)
    (seq / "frame_camera" / "depth").mkdir()
    k = EVENT
    (seq / "calib.txt").write_text(f"{k.fx} {k.fy} {k.cx} {k.cy} 0 0 0 0 0\n")
    (seq / "images.txt").write_text("")                        # the event camera has no frames
    times = np.arange(0.0, 0.2001, 0.005)
    T = pose(times)
    quats = Rotation.from_matrix(T[:, :3, :3]).as_quat()           # scalar last
    (seq / "groundtruth.txt").write_text("".join(
        f"{t:.9f} {' '.join(repr(float(x)) for x in (*p[:3, 3], *q))}\n"
        for t, p, q in zip(times, T, quats, strict=True)))
    (seq / "events.txt").write_text("".join(f"{0.095 + 1e-4 * i:.9f} {3 + i} 7 1\n"
                                            for i in range(20)))
    f = FRAME
    (seq / "frame_camera" / "calib.txt").write_text(
        f"{f.fx} {f.fy} {f.cx} {f.cy} {' '.join(str(c) for c in f.distortion)}\n")
    q = Rotation.from_matrix(T_EVENT_FRAME[:3, :3]).as_quat()
    (seq / "frame_camera" / "T_event_frame.txt").write_text(
        " ".join(repr(float(x)) for x in (*T_EVENT_FRAME[:3, 3], *q)) + "\n")
    frame_rays = rays(FRAME)
    lines = []
    for i, t in enumerate(FRAME_TIMES):
        row_poses = frame_row_poses(t, readout)[:, None]            # (H, 1, 4, 4)
        points, depth = hit(frame_rays, row_poses)
        image = (60 + 140 * checker(points)).astype(np.uint8)
        cv2.imwrite(str(seq / "frame_camera" / "images" / f"frame_{i:08d}.png"), image)
        write_depth(seq / "frame_camera" / "depth" / f"frame_{i:08d}.exr",
                    depth.astype(np.float32))
        lines.append(f"{t:.9f} %s/frame_{i:08d}.%s\n")
    (seq / "frame_camera" / "images.txt").write_text("".join(s % ("images", "png")
                                                             for s in lines))
    (seq / "frame_camera" / "depthmaps.txt").write_text("".join(s % ("depth", "exr")
                                                                for s in lines))
    record = {"width": f.width, "height": f.height, "fx": f.fx, "fy": f.fy, "cx": f.cx,
              "cy": f.cy, "distortion": list(f.distortion),
              "T_event_frame": T_EVENT_FRAME.tolist(), "shutter": shutter, "readout_s": readout}
    (seq / "sequence.json").write_text(json.dumps(
        {"camera": {"width": k.width, "height": k.height}, "frame_camera": record}))
    # the map: the plane's exact depth at the event camera's edge pixels (both sides of each
    # checker edge), at the reference view
    points, depth = hit(rays(EVENT), pose(T_REF)[0])
    board = checker(points).astype(int)
    edge = np.zeros(board.shape, bool)
    edge[:, :-1] |= board[:, :-1] != board[:, 1:]
    edge[:, 1:] |= board[:, :-1] != board[:, 1:]
    edge[:-1] |= board[:-1] != board[1:]
    edge[1:] |= board[:-1] != board[1:]
    mapped = folder / "map"
    mapped.mkdir()
    write_depth(mapped / "semidense_depth.exr", np.where(edge, depth, 0).astype(np.float32))
    (mapped / "map.json").write_text(json.dumps({
        "t_ref": T_REF, "T_world_ref": pose(T_REF)[0].tolist(), "sequence": "../sequence",
        "camera": {"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy, "cx": k.cx,
                   "cy": k.cy}}))
    return mapped


def expected_event_image(mapped: Path, t_frame: float, readout: float = 0.0) -> np.ndarray:
    """The map's points projected into the frame by OpenCV, nearest kept: for a rolling shutter
    each point with the pose of the row it lands on, found by a brute-force search over rows."""
    depth_ref = read_depth(mapped / "semidense_depth.exr")
    v, u = np.nonzero(depth_ref)
    ray = np.stack([(u - EVENT.cx) / EVENT.fx, (v - EVENT.cy) / EVENT.fy, np.ones(len(u))], -1)
    world = pose(T_REF)[0] @ np.vstack([(ray * depth_ref[v, u, None]).T, np.ones(len(u))])
    row_poses = frame_row_poses(t_frame, readout)
    uv, z, _ = brute_force_rows(world[:3].T, row_poses)
    image = np.zeros((FRAME.height, FRAME.width), np.float32)
    col, row = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    for c, r, d in sorted(zip(col, row, z, strict=True), key=lambda x: -x[2]):
        if 0 <= c < FRAME.width and 0 <= r < FRAME.height:
            image[r, c] = d
    return image


def brute_force_rows(world: np.ndarray, row_poses: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project world points (N, 3) with every row's pose (OpenCV); keep, for each point, the
    fractional row where its projected row equals the row of the pose (linear between the two
    integer rows that bracket it). Returns uv (N, 2), z (N,) and q (N,), the rows its
    projection moves per row there (the fixed-point iteration's contraction factor)."""
    h = len(row_poses)
    uv_all = np.empty((h, len(world), 2))
    z_all = np.empty((h, len(world)))
    for r in range(h):
        T_cam_world = np.linalg.inv(row_poses[r])
        local = world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        rvec, _ = cv2.Rodrigues(np.eye(3))
        uv_all[r] = cv2.projectPoints(local, rvec, np.zeros(3), FRAME.K,
                                      np.array(FRAME.distortion))[0][:, 0]
        z_all[r] = local[:, 2]
    g = uv_all[:, :, 1] - np.arange(h)[:, None]                    # projected row - pose row
    uv, z, q = np.empty((len(world), 2)), np.empty(len(world)), np.empty(len(world))
    for n in range(len(world)):
        sign = np.flatnonzero(np.diff(np.sign(g[:, n])) != 0)
        r = int(sign[0]) if sign.size else (0 if g[0, n] < 0 else h - 2)
        s = g[r, n] / (g[r, n] - g[r + 1, n]) if sign.size else (0.0 if r == 0 else 1.0)
        uv[n] = (1 - s) * uv_all[r, n] + s * uv_all[r + 1, n]
        z[n] = (1 - s) * z_all[r, n] + s * z_all[r + 1, n]
        q[n] = uv_all[r + 1, n, 1] - uv_all[r, n, 1]
    return uv, z, q


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> Path:
    return write_rig(tmp_path_factory.mktemp("rig"))


def test_load_sequence_reads_the_frame_camera(rig):
    sequence = load_sequence(rig / "../sequence")
    frames = sequence.standard_frames()
    assert frames is sequence.frame_camera and len(sequence.image_times) == 0
    assert frames.camera == FRAME and sequence.camera.resolution == (64, 48)
    np.testing.assert_allclose(frames.T_event_frame, T_EVENT_FRAME, atol=1e-12)
    assert frames.shutter == "global" and frames.readout_s == 0.0
    np.testing.assert_array_equal(frames.row_times(0.09), np.full(42, 0.09))
    assert frames.nearest_frame(0.1) == 1 and frames.nearest_depth(0.09) == 1


def test_fill_inputs_projects_into_the_frame_camera(rig):
    inputs = fill_inputs(rig)
    assert inputs.frame.shape == inputs.sparse.shape == inputs.truth.shape == (42, 56)
    assert inputs.camera == FRAME
    assert inputs.info["t_frame"] == 0.09
    assert inputs.info["frame"] == "frame_camera/images/frame_00000001.png"
    assert inputs.info["truth"] == "frame_camera/depth/frame_00000001.exr"
    np.testing.assert_allclose(inputs.T_world_frame, pose(0.09)[0] @ T_EVENT_FRAME, atol=1e-9)
    expected = expected_event_image(rig, 0.09)
    assert np.count_nonzero(expected) > 300
    np.testing.assert_array_equal(inputs.sparse > 0, expected > 0)
    np.testing.assert_allclose(inputs.sparse, expected, rtol=1e-6)
    # and against the frame camera's exact depth (ray-plane), up to rounding to the pixel
    at = inputs.sparse > 0
    relative = np.abs(inputs.sparse[at] / inputs.truth[at] - 1)
    assert relative.max() < 3e-3 and np.median(relative) < 1e-3
    # the frame camera's own pose matters: the event camera's would put the points elsewhere
    from fusion.fill.projection import project_map

    depth_ref = read_depth(rig / "semidense_depth.exr")
    wrong = project_map(depth_ref, EVENT, pose(T_REF)[0], FRAME, pose(0.09)[0])
    assert np.count_nonzero((wrong > 0) != at) > 0.5 * at.sum()


@pytest.mark.parametrize("method", ["paper-idw", "plane", "mesh"])
def test_a_plane_seen_by_the_rig_is_filled_with_its_depth(rig, method):
    """Filled in the frame camera with the plane's depth there. The event image's points are
    rounded to the frame's pixels, each keeping its own depth (off by up to half a pixel of the
    plane's slope, 0.04 % here): ``plane`` fits through that to 1e-3; ``mesh`` too wherever it
    reproduces the plane exactly from exact depths at the same pixels (its interpolation
    between far-apart points is its own, not the rig's); the paper's inverse-distance weights
    stay within the map's depths."""
    inputs = fill_inputs(rig)
    result = fill_frame(inputs.frame, inputs.sparse, inputs.camera, truth=inputs.truth,
                        method=method)
    filled = (result.dense > 0) & (inputs.sparse == 0)
    assert filled.sum() > 0.4 * filled.size, filled.sum()
    relative = np.abs(result.dense / np.where(inputs.truth > 0, inputs.truth, 1) - 1)
    if method == "paper-idw":
        # each filled depth is a convex combination of map depths of its region and ring, so
        # it lies between the smallest and largest of them
        lo, hi = inputs.sparse[inputs.sparse > 0].min(), inputs.sparse.max()
        assert lo - 1e-6 <= result.dense[filled].min() and result.dense[filled].max() <= hi + 1e-6
        assert np.abs(result.dense - inputs.truth)[filled].max() <= hi - lo
        assert np.median(relative[filled]) < 0.005
        return
    if method == "mesh":
        exact_points = np.where(inputs.sparse > 0, inputs.truth, 0).astype(np.float32)
        ideal = fill_frame(inputs.frame, exact_points, inputs.camera, method=method).dense
        exact = filled & (np.abs(ideal / np.where(inputs.truth > 0, inputs.truth, 1) - 1) < 1e-6)
        assert exact.sum() > 0.6 * filled.sum()
        filled = exact
    assert relative[filled].max() < 1e-3, relative[filled].max()


def test_rolling_shutter_projection_matches_a_search_over_rows():
    rng = np.random.default_rng(4)
    readout = 0.03
    uv_pix = rng.uniform([2, 2], [FRAME.width - 3, FRAME.height - 3], (200, 2))
    row_poses = frame_row_poses(0.09, readout)
    # points seen at random pixels from the middle row's pose, at 1-3 m
    mid = row_poses[FRAME.height // 2]
    xy = undistort_points(uv_pix.reshape(-1, 1, 2), FRAME.K, FRAME.distortion, np.eye(3),
                          np.eye(3)).reshape(-1, 2)
    local = np.concatenate([xy, np.ones((200, 1))], 1) * rng.uniform(1, 3, (200, 1))
    world = local @ mid[:3, :3].T + mid[:3, 3]
    times = 0.09 + (np.arange(FRAME.height) / (FRAME.height - 1) - 0.5) * readout

    def pose_at_row(v):
        return pose(np.interp(v, np.arange(FRAME.height), times)) @ T_EVENT_FRAME

    uv, z, last_step = rolling_shutter_project(world, FRAME, pose_at_row)
    expected_uv, expected_z, q = brute_force_rows(world, row_poses)
    inside = (expected_uv[:, 1] > 0) & (expected_uv[:, 1] < FRAME.height - 1)
    assert inside.sum() > 150
    q = np.abs(q[inside])
    assert 0.05 < q.max() < 0.2                       # a fast turn: 0.1 rows per row of readout
    # the shutter matters here: the middle row's pose alone is pixels off
    first_uv, *_ = rolling_shutter_project(world, FRAME, pose_at_row, iterations=0)
    assert np.abs(first_uv - expected_uv)[inside].max() > 1.0
    # the stated bound: |v_k - v*| <= q / (1 - q) |v_k - v_(k-1)|, plus the brute force's own
    # error (linear between two rows: 1.4e-5 px here, measured with 7 iterations)
    error = np.abs(uv - expected_uv)[inside]
    assert np.all(error[:, 1] <= q / (1 - q) * last_step[inside] + 1e-4)
    # and with 3 iterations, at q = 0.1 from a middle row up to 20 rows away: 20 * 0.1^4 px
    assert error.max() < 3e-3
    np.testing.assert_allclose(z[inside], expected_z[inside], rtol=5e-5)   # at that row error


def test_fill_inputs_with_a_rolling_shutter(tmp_path):
    mapped = write_rig(tmp_path, shutter="rolling", readout=0.03)
    inputs = fill_inputs(mapped)
    assert inputs.info["rig"]["shutter"] == "rolling"
    assert inputs.info["rolling_shutter"]["max_last_step_px"] < 0.05
    expected = expected_event_image(mapped, 0.09, readout=0.03)
    np.testing.assert_array_equal(inputs.sparse > 0, expected > 0)
    np.testing.assert_allclose(inputs.sparse, expected, rtol=5e-5)    # 3 iterations: 1.4e-5
    at = inputs.sparse > 0
    assert np.median(np.abs(inputs.sparse[at] / inputs.truth[at] - 1)) < 1e-3


def test_fill_json_records_the_rig_and_scores_against_the_frame_camera(rig, tmp_path):
    out = tmp_path / "fill"
    fill_window(rig, out, method="plane")
    meta = json.loads((out / "fill.json").read_text())
    assert meta["rig"]["width"] == 56 and meta["rig"]["height"] == 42
    np.testing.assert_allclose(meta["rig"]["T_event_frame"], T_EVENT_FRAME, atol=1e-12)
    assert meta["truth"] == "frame_camera/depth/frame_00000001.exr"
    assert meta["camera"]["width"] == 56 and meta["camera"]["distortion"][0] == -0.15
    dense = read_depth(out / "dense_depth.exr")
    # the exact depth of the frame camera, computed here: rays of its pixels meet the plane
    _, truth = hit(rays(FRAME), pose(0.09)[0] @ T_EVENT_FRAME)
    both = (dense > 0) & (truth > 0)
    assert meta["errors"]["all"]["overall"]["n"] == both.sum()
    assert meta["errors"]["all"]["overall"]["mae_cm"] == pytest.approx(
        100 * np.abs(dense[both] - truth[both]).mean(), rel=1e-4)


def test_bench_refuses_a_rig_in_one_line(rig, tmp_path):
    with pytest.raises(ValueError, match="does not take a two-camera rig") as caught:
        run_bench(["nearest"], [str(rig)], ["emvs"], tmp_path / "bench", progress=False)
    assert "\n" not in str(caught.value)


def test_map_overlay_without_event_frames_draws_the_events(rig):
    sequence = load_sequence(rig / "../sequence")
    image = _reference_image(sequence, 0.096)
    assert image.shape == (48, 64)
    fired = image == 0
    assert fired.sum() == 20 and fired[7, 3:23].all()


def test_overview_of_a_rig_run_draws_each_camera_at_its_own_size(rig, tmp_path):
    import shutil

    from fusion.pipeline import _overview_panels

    run = tmp_path / "run"
    shutil.copytree(rig, run / "map")
    meta = json.loads((rig / "map.json").read_text())
    meta["sequence"] = str((rig / meta["sequence"]).resolve())
    (run / "map" / "map.json").write_text(json.dumps(meta))
    info = fill_window(run / "map", run / "fill", method="plane").info
    report = {"sequence": meta["sequence"], "t_frame": info["t_frame"], "N1": info["N1"],
              "N1_in_frame": info["N1_in_frame"], "N2": info["N2"], "beta": info["beta"]}
    panels, titles, _, _ = _overview_panels(run, report)
    shapes = dict(zip(titles, (p.shape[:2] for p in panels), strict=True))
    assert shapes["frame at 0.090 s"] == (42, 56)
    assert shapes["events +-10 ms (20)"] == (48, 64)              # the event camera's size
    assert shapes["exact depth"] == (42, 56)                      # the frame camera's truth
