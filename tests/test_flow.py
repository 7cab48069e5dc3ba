"""Optical flow, motion field and object masks (sim/flow.py), each against an independent
computation: image warping, the rotation homography, analytic ray casts against boxes and planes,
and finite differences."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from sim.exr import read_depth
from sim.flow import (
    NO_SURFACE,
    OCCLUDED,
    OUT_OF_VIEW,
    motion_field,
    read_flow,
    read_motion_field,
    read_object_mask,
    transport,
)
from sim.render import Renderer
from sim.scene import parse_scene
from sim.sequence import load_sequence
from sim.simulate import simulate
from tests.conftest import scene_text

LENS = ("[camera]\nwidth = 64\nheight = 48\nfx = 60.0\nfy = 45.0\ncx = 30.3\ncy = 22.7\n"
        "distortion = [-0.3, 0.1, 0.002, -0.001, 0.0]\n")
FRAMES = "[frames]\nrate = 20.0\nexposure = 0.002\nexposure_samples = 1\n[render]\nspp = 16\n"
WALL = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 2.0, 0.0]
size = [8.0, 8.0]
material = { texture = { type = "noise", resolution = 64 } }
"""
# Two boxes of the same plain material: a static scene's Mitsuba load merges them into one mesh.
BOXES = """
[[objects]]
name = "left box"
type = "box"
center = [-0.25, 1.0, 0.05]
size = [0.3, 0.3, 0.3]
[[objects]]
name = "right box"
type = "box"
center = [0.3, 1.3, -0.1]
size = [0.25, 0.4, 0.3]
"""
MOVING_BOX = """
[[objects]]
name = "box"
type = "box"
center = [-0.1, 1.0, 0.0]
size = [0.3, 0.3, 0.3]
material = { texture = { type = "noise", resolution = 32 } }
motion = { type = "linear", velocity = [1.0, 0.0, 0.3], angular_velocity = [20.0, 0.0, 60.0] }
"""
TURNING = ('[trajectory]\ntype = "spline"\nkeyframes = [\n'
           '  { t = 0.0, position = [0.0, 0.0, 0.0], look_at = [0.0, 1.0, 0.0] },\n'
           '  { t = 0.5, position = [0.0, 0.0, 0.0], look_at = [0.5, 1.0, 0.2] },\n]\n')
MOVING_TURNING = ('[trajectory]\ntype = "spline"\nkeyframes = [\n'
                  '  { t = 0.0, position = [0.0, 0.0, 0.0], look_at = [0.0, 1.0, 0.0] },\n'
                  '  { t = 0.5, position = [0.15, 0.05, 0.05], look_at = [0.4, 1.0, 0.15] },\n]\n')
SLIDING = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
           "velocity = [0.2, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
SLANTED_PLANE = """
[[objects]]
name = "plane"
type = "rectangle"
center = [0.0, 1.2, 0.0]
size = [4.0, 4.0]
normal = [0.35, -1.0, 0.2]
material = { texture = { type = "noise", resolution = 48, feature_size = 3.0, contrast = 1.0 } }
"""


def _simulate(tmp_path_factory, name: str, objects: str, trajectory: str):
    scene = parse_scene(scene_text(objects, camera=LENS, trajectory=trajectory, duration=0.25,
                                   extra=FRAMES))
    out = tmp_path_factory.mktemp("flow") / name
    simulate(scene, out, progress=False, with_events=False)
    return scene, load_sequence(out)


@pytest.fixture(scope="module")
def turning(tmp_path_factory):
    """A pure rotation, through a distorting lens, of a wall with two boxes in front (static)."""
    return _simulate(tmp_path_factory, "turning", WALL + BOXES, TURNING)


@pytest.fixture(scope="module")
def plane(tmp_path_factory):
    """A textured slanted plane seen through a distorting lens, the camera turning and moving."""
    return _simulate(tmp_path_factory, "plane", SLANTED_PLANE, MOVING_TURNING)


@pytest.fixture(scope="module")
def dynamic(tmp_path_factory):
    """A spinning box moving in front of a wall, the camera sliding."""
    return _simulate(tmp_path_factory, "dynamic", WALL + MOVING_BOX, SLIDING)


# --- independent geometry: rays through the pixel centres against planes and boxes -------------

def _rays(camera, pose):
    """World origin and (N, 3) directions scaled so that the ray parameter is the z-depth."""
    uv = camera.pixel_centres().reshape(-1, 2)
    xy = camera.undistort((uv - [camera.cx, camera.cy]) / [camera.fx, camera.fy])
    return pose[:3, 3], np.c_[xy, np.ones(len(xy))] @ pose[:3, :3].T


def _hit(obj, t, origin, directions):
    """Ray parameter of the first hit of each ray on the object (box or rectangle), inf if none."""
    pose = obj.pose(t)
    o = (origin - pose[:3, 3]) @ pose[:3, :3]
    d = directions @ pose[:3, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        if obj.shape == "rectangle":
            s = -o[2] / d[:, 2]
            local = o[:2] + s[:, None] * d[:, :2]
            inside = np.all(np.abs(local) <= np.asarray(obj.params["size"]) / 2, axis=1)
            return np.where(inside & (s > 0), s, np.inf)
        half = obj.half_extents()
        a, b = (-half - o) / d, (half - o) / d
        near, far = np.minimum(a, b).max(axis=1), np.maximum(a, b).min(axis=1)
        return np.where((far >= near) & (near > 0), near, np.inf)


def _expected_mask(scene, t):
    camera = scene.camera
    origin, directions = _rays(camera, scene.trajectory.pose(t))
    hits = np.stack([_hit(obj, t, origin, directions) for obj in scene.objects])
    first = np.argmin(hits, axis=0) + 1
    return np.where(np.isfinite(hits.min(axis=0)), first, 0).reshape(camera.height,
                                                                      camera.width)


# --- the files -----------------------------------------------------------------------------------

def test_files_round_trip_through_load_sequence(dynamic):
    scene, seq = dynamic
    n = len(seq.image_times)
    assert n >= 5
    np.testing.assert_array_equal(seq.forward_flow.times, seq.image_times[:-1])
    np.testing.assert_array_equal(seq.backward_flow.times, seq.image_times[1:])
    np.testing.assert_array_equal(seq.motion_field.times, seq.image_times)
    np.testing.assert_array_equal(seq.object_masks.times, seq.image_times)
    assert seq.object_names == ("wall", "box")
    # The standard frames of one camera carry the same files as a rig's frame camera does.
    assert seq.standard_frames().forward_flow is seq.forward_flow
    assert seq.standard_frames().object_masks is seq.object_masks
    flow, flags = read_flow(seq.forward_flow.paths[0])
    assert flow.shape == (48, 64, 2) and flow.dtype == np.float32 and flags.dtype == np.uint8
    assert read_motion_field(seq.motion_field.paths[0]).shape == (48, 64, 2)
    mask = read_object_mask(seq.object_masks.paths[0])
    assert mask.dtype == np.uint16 and set(np.unique(mask)) == {1, 2}
    meta = json.loads((seq.folder / "sequence.json").read_text())
    assert meta["object_masks"]["objects"] == ["wall", "box"]
    assert meta["flow"]["flags"] == {"1": "no surface", "2": "out of view", "4": "occluded"}


def test_readers_refuse_the_wrong_file_in_one_line(dynamic, tmp_path):
    _, seq = dynamic
    with pytest.raises(ValueError, match=r"no channel\(s\) \['du', 'dv', 'flags'\].*has \['Z'\]"):
        read_flow(seq.depth_paths[0])
    with pytest.raises(ValueError, match="expected a single-channel 16-bit PNG"):
        read_object_mask(seq.image_paths[0])


# --- masks ---------------------------------------------------------------------------------------

def test_masks_of_a_static_scene_with_merged_meshes_match_ray_casts(turning):
    scene, seq = turning
    renderer = Renderer(scene)
    shapes = renderer.mitsuba_scene.shapes()
    assert len(shapes) < len(scene.objects)          # Mitsuba merged meshes: ids not per shape
    for k in (0, len(seq.image_times) - 1):
        mask = read_object_mask(seq.object_masks.paths[k])
        expected = _expected_mask(scene, float(seq.image_times[k]))
        assert set(np.unique(expected)) == {1, 2, 3}
        assert np.count_nonzero(mask != expected) <= 2, k     # grazing rays at most


def test_masks_of_a_moving_object_match_ray_casts(dynamic):
    scene, seq = dynamic
    for k in range(len(seq.image_times)):
        mask = read_object_mask(seq.object_masks.paths[k])
        expected = _expected_mask(scene, float(seq.image_times[k]))
        assert np.count_nonzero(expected == 2) > 100
        assert np.count_nonzero(mask != expected) <= 2, k


def test_masks_of_an_object_on_a_phase_shifted_sine_match_its_pose():
    """The rendered object sits at ``SceneObject.pose(t)`` (the renderer once added the motion's
    offset at t = 0 twice, which a sine with a phase makes non-zero)."""
    box = MOVING_BOX.replace('type = "linear", velocity = [1.0, 0.0, 0.3], angular_velocity = '
                             '[20.0, 0.0, 60.0]', 'type = "sine", amplitude = [0.2, 0.0, 0.1], '
                             'frequency = 1.0, phase = 1.3')
    scene = parse_scene(scene_text(WALL + box, camera=LENS, trajectory=SLIDING, extra=FRAMES))
    renderer = Renderer(scene)
    for t in (0.0, 0.2):
        expected = _expected_mask(scene, t)
        assert np.count_nonzero(expected == 2) > 100
        assert np.count_nonzero(renderer.object_ids(t) != expected) <= 2


# --- optical flow --------------------------------------------------------------------------------

def test_pure_rotation_flow_is_the_homography_with_distortion(turning):
    scene, seq = turning
    camera = scene.camera
    uv = camera.pixel_centres().reshape(-1, 2)
    xy = camera.undistort((uv - [camera.cx, camera.cy]) / [camera.fx, camera.fy])
    checked = 0
    times = seq.image_times
    for k in range(len(times) - 1):
        for path, t_src, t_dst in ((seq.forward_flow.paths[k], times[k], times[k + 1]),
                                   (seq.backward_flow.paths[k], times[k + 1], times[k])):
            flow, flags = read_flow(path)
            r_src = scene.trajectory.pose(t_src)[:3, :3]
            r_dst = scene.trajectory.pose(t_dst)[:3, :3]
            rays = np.c_[xy, np.ones(len(xy))] @ (r_dst.T @ r_src).T
            target = camera.distort(rays[:, :2] / rays[:, 2:]) * [camera.fx, camera.fy]
            expected = (target + [camera.cx, camera.cy] - uv).reshape(48, 64, 2)
            valid = flags == 0
            assert valid.mean() > 0.8
            np.testing.assert_allclose(flow[valid], expected[valid], atol=1e-5)
            assert np.abs(expected).max() > 2.0                      # the camera does turn
            # A rotation hides nothing: no point is occluded, whatever its depth.
            assert not np.any(flags & OCCLUDED)
            checked += 1
    assert checked == 2 * (len(seq.image_times) - 1)


def test_warping_the_next_frame_by_the_flow_gives_back_the_frame(plane):
    scene, seq = plane
    errors, still = [], []
    for k in range(len(seq.image_times) - 1):
        frame = cv2.imread(str(seq.image_paths[k]), cv2.IMREAD_UNCHANGED).astype(np.float32)
        after = cv2.imread(str(seq.image_paths[k + 1]), cv2.IMREAD_UNCHANGED).astype(np.float32)
        flow, flags = read_flow(seq.forward_flow.paths[k])
        grid = scene.camera.pixel_centres().astype(np.float32)
        warped = cv2.remap(after, grid[..., 0] + flow[..., 0], grid[..., 1] + flow[..., 1],
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        inner = np.zeros_like(flags, dtype=bool)
        inner[2:-2, 2:-2] = True
        landed = grid + flow
        inner &= (landed[..., 0] > 1) & (landed[..., 0] < 62) & (landed[..., 1] > 1) & (
            landed[..., 1] < 46)
        valid = (flags == 0) & inner
        assert valid.mean() > 0.5
        assert np.abs(flow[valid]).max() > 2.0
        errors.append(np.abs(warped - frame)[valid].mean())
        still.append(np.abs(after - frame)[valid].mean())
    errors, still = np.array(errors), np.array(still)
    # 8-bit frames rendered at 16 spp: the warp is within about one grey level, ten times less
    # than the frames differ unwarped.
    assert errors.max() < 1.5, errors
    assert np.all(errors < 0.15 * still), (errors, still)


def test_a_moving_object_pixels_move_with_the_object(dynamic):
    scene, seq = dynamic
    camera, box = scene.camera, scene.objects[1]
    for k in range(len(seq.image_times) - 1):
        t0, t1 = float(seq.image_times[k]), float(seq.image_times[k + 1])
        origin, directions = _rays(camera, scene.trajectory.pose(t0))
        s = _hit(box, t0, origin, directions)
        on_box = np.isfinite(s)
        world = origin + s[on_box, None] * directions[on_box]
        local = (world - box.pose(t0)[:3, 3]) @ box.pose(t0)[:3, :3]      # box frame
        moved = local @ box.pose(t1)[:3, :3].T + box.pose(t1)[:3, 3]
        pose1 = scene.trajectory.pose(t1)
        expected = camera.project((moved - pose1[:3, 3]) @ pose1[:3, :3])
        expected -= camera.pixel_centres().reshape(-1, 2)[on_box]
        flow, flags = read_flow(seq.forward_flow.paths[k])
        flow = flow.reshape(-1, 2)[on_box]
        assert on_box.sum() > 100 and not np.any(flags.reshape(-1)[on_box] & NO_SURFACE)
        np.testing.assert_allclose(flow, expected, atol=1e-4)
        # ... and not with the world: the box moves several pixels a frame on its own.
        static = camera.project((world - pose1[:3, 3]) @ pose1[:3, :3])
        static -= camera.pixel_centres().reshape(-1, 2)[on_box]
        assert np.median(np.linalg.norm(static - expected, axis=1)) > 2.0


def test_occlusion_flags_of_a_wall_behind_a_moving_box(dynamic):
    """A wall point is occluded when the box (at the target time) cuts the segment from the
    target camera to it; flags may differ from that only within one pixel of the box's outline
    in the target frame."""
    scene, seq = dynamic
    camera, wall, box = scene.camera, scene.objects[0], scene.objects[1]
    hidden_total = 0
    for k in range(len(seq.image_times) - 1):
        for src, dst, index in ((k, k + 1, seq.forward_flow.paths[k]),
                                (k + 1, k, seq.backward_flow.paths[k])):
            t_src, t_dst = float(seq.image_times[src]), float(seq.image_times[dst])
            origin, directions = _rays(camera, scene.trajectory.pose(t_src))
            s_wall, s_box = _hit(wall, t_src, origin, directions), _hit(box, t_src, origin,
                                                                       directions)
            on_wall = np.isfinite(s_wall) & (s_wall < s_box)
            points = origin + s_wall[on_wall, None] * directions[on_wall]
            centre = scene.trajectory.pose(t_dst)[:3, 3]
            cut = _hit(box, t_dst, centre, points - centre)       # ray parameter 1 = the point
            expected = cut < 1.0 - 1e-9
            flow, flags = read_flow(index)
            flags = flags.reshape(-1)[on_wall]
            landed = camera.pixel_centres().reshape(-1, 2)[on_wall] + flow.reshape(-1, 2)[on_wall]
            in_view = (flags & OUT_OF_VIEW) == 0
            got = (flags & OCCLUDED) > 0
            mask = read_object_mask(seq.object_masks.paths[dst])
            u0 = np.clip(np.floor(landed[:, 0]).astype(int), 0, 62)
            v0 = np.clip(np.floor(landed[:, 1]).astype(int), 0, 46)
            corners = np.stack([mask[v0, u0], mask[v0, u0 + 1], mask[v0 + 1, u0],
                                mask[v0 + 1, u0 + 1]])
            outline = (corners == 2).any(axis=0) & (corners != 2).any(axis=0)
            wrong = in_view & (got != expected)
            assert not np.any(wrong & ~outline), (k, src, dst, np.flatnonzero(wrong & ~outline))
            assert not np.any(got & ~expected)              # never flags a visible point
            hidden_total += int(np.count_nonzero(got))
    assert hidden_total > 40


# --- motion field --------------------------------------------------------------------------------

def test_motion_field_is_the_limit_of_the_flow(dynamic, plane):
    """The written motion field against a central difference of the transport over +-0.1 ms
    (its error, second order in the step, is below 1e-7 of the field here: 6e-8 measured, about
    float32's resolution of the stored field)."""
    for scene, seq in (dynamic, plane):
        camera = scene.camera
        centres = camera.normalized_pixel_centres()
        for k in (0, len(seq.image_times) - 1):
            t = float(seq.image_times[k])
            depth = read_depth(seq.depth_paths[k])
            ids = read_object_mask(seq.object_masks.paths[k])
            points = np.concatenate([centres, np.ones((48, 64, 1))], axis=-1) * depth[..., None]
            pose = scene.trajectory.pose(t)
            h = 1e-4
            ends = [camera.project(transport(points, ids, scene.objects, pose, t,
                                             scene.trajectory.pose(t + s), t + s))
                    for s in (-h, h)]
            expected = (ends[1] - ends[0]) / (2 * h)
            field = read_motion_field(seq.motion_field.paths[k])
            seen = depth > 0
            assert seen.mean() > 0.9 and np.abs(expected[seen]).max() > 20.0
            np.testing.assert_allclose(field[seen], expected[seen], rtol=1e-6, atol=1e-4)
            assert np.all(field[~seen] == 0)
            # the same call on the arrays gives the file's values (float32)
            again = motion_field(camera, depth, ids, scene.objects, pose,
                                 scene.trajectory.velocity(t), t, centres)
            np.testing.assert_array_equal(again, field)


def test_without_the_motion_truth_only_frames_depth_poses_and_events_are_written(tmp_path):
    scene = parse_scene(scene_text(WALL, camera=LENS, trajectory=TURNING, duration=0.5,
                                   extra=FRAMES))
    simulate(scene, tmp_path / "seq", duration=0.12, progress=False, motion_truth=False)
    seq = load_sequence(tmp_path / "seq")
    assert seq.velocity_path is None and seq.imu_path is None
    assert seq.forward_flow is None and seq.motion_field is None and seq.object_masks is None
    assert seq.event_depth() is None                    # events.h5 without events/depth
    assert seq.events_h5 is not None and len(seq.depth_paths) == len(seq.image_paths) > 0
    assert json.loads((tmp_path / "seq" / "sequence.json").read_text())["motion_truth"] is False
    with pytest.raises(ValueError, match="depth-txt holds each event's depth"):
        simulate(scene, tmp_path / "other", progress=False, motion_truth=False,
                 event_formats=("h5", "depth-txt"))
