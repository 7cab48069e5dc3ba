"""evfuse run end to end on a scene that catches a wrong convention.

Boxes at 1.0 and 1.4 m before a wall at 2 m, a lens with DAVIS240C-like barrel distortion, fx != fy,
and a camera that translates and turns: a pixel shifted, a distortion applied twice or not at all,
or a pose inverted moves map points across depth edges, and the figures below change.

The bounds come from the DSI's geometry, not from a previous run: 100 planes uniform in inverse
depth over the declared 0.5-3 m are 0.0168 1/m apart, so a map point on the right plane is within
half of that, 0.85 % of its depth at 1 m and 1.7 % at 2 m.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fusion.map.mapping import _ground_truth_depth
from fusion.scoring import depth_errors, discontinuity_band
from sim.exr import read_depth
from sim.sequence import load_sequence
from tests.conftest import run_cli, scene_text

CAMERA = ("[camera]\nwidth = 96\nheight = 72\nfx = 90.0\nfy = 80.0\ncx = 47.3\ncy = 35.6\n"
          "distortion = [-0.3, 0.1, 0.001, -0.0005, 0.0]\n")
TRAJECTORY = """[trajectory]
type = "spline"
keyframes = [
  { t = 0.0, position = [-0.15, 0.0, 0.0], look_at = [-0.3, 1.5, -0.03] },
  { t = 0.15, position = [0.0, 0.0, 0.02], look_at = [0.0, 1.5, 0.0] },
  { t = 0.3, position = [0.15, 0.0, 0.0], look_at = [0.3, 1.5, 0.04] },
]
"""
OBJECTS = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 2.0, 0.0]
size = [6.0, 6.0]
[objects.material]
texture_scale = [2.0, 2.0]
texture = { type = "shapes", resolution = 256, count = 30, min_size = 10, max_size = 40 }

[[objects]]
name = "near_box"
type = "box"
center = [-0.25, 1.0, 0.0]
size = [0.3, 0.2, 0.4]
[objects.material]
texture = { type = "shapes", resolution = 128, count = 12, min_size = 10, max_size = 30 }

[[objects]]
name = "middle_box"
type = "box"
center = [0.3, 1.4, 0.05]
size = [0.35, 0.2, 0.5]
[objects.material]
texture = { type = "shapes", resolution = 128, count = 8, min_size = 20, max_size = 50 }
"""
EXTRA = ("depth_range = [0.5, 3.0]\n"
         "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n")
PLANE_STEP = (1 / 0.5 - 1 / 3.0) / 99                 # inverse-depth spacing of the planes, 1/m


@pytest.fixture(scope="module")
def boxes_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("boxes")
    scene = folder / "boxes.toml"
    scene.write_text(scene_text(OBJECTS, camera=CAMERA, trajectory=TRAJECTORY, duration=0.3,
                                extra=EXTRA))
    out = folder / "out"
    assert run_cli(["run", str(scene), "--t0", "0.0", "--t1", "0.3", "--out", str(out),
                 "--quiet"]) == 0
    return out


def _map_and_truth(out):
    mapped = json.loads((out / "map" / "map.json").read_text())
    sequence = load_sequence(out / "sequence")
    truth = _ground_truth_depth(sequence, mapped["t_ref"])
    return mapped, read_depth(out / "map" / "semidense_depth.exr"), truth


def test_map_of_boxes_seen_through_a_distorting_lens_is_at_the_right_depths(boxes_run):
    mapped, depth, truth = _map_and_truth(boxes_run)
    errors = mapped["errors"]
    assert errors["points"] == mapped["N1"] > 150 and errors["no_surface"] == 0
    # median relative error within the plane quantisation (<= 1.7 % at 2 m) plus a little
    both = (depth > 0) & (truth > 0)
    relative = np.abs(depth[both] - truth[both]) / truth[both]
    assert np.median(relative) < 0.02
    # Away from the boxes' silhouettes nearly every point is on its surface; on them a point's
    # pixel may hold either side's depth, so the share over all points is lower.
    interior = depth_errors(depth, truth, ~discontinuity_band(truth, width=2))
    assert interior["precision_5pct"] > 0.8 and interior["points"] > 0.4 * errors["points"]
    assert errors["precision_5pct"] > 0.5
    # the objects come out in their order: near box, middle box, wall
    near, middle, wall = (both & (truth > lo) & (truth < hi)
                          for lo, hi in ((0.85, 1.15), (1.25, 1.6), (1.85, 2.6)))
    assert min(near.sum(), middle.sum(), wall.sum()) > 20
    assert (np.median(depth[near]) < 1.15 < np.median(depth[middle]) < 1.6
            < np.median(depth[wall]))


STRIPE = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 1.0, 0.0]
size = [6.0, 6.0]
material = { color = 0.05 }

[[objects]]
name = "stripe"
type = "rectangle"
center = [0.025, 0.999, 0.0]
size = [0.05, 2.0]
material = { color = 0.9 }
"""
TURN = """[trajectory]
type = "spline"
keyframes = [
  { t = 0.0, position = [0.0, 0.0, 0.0], look_at = [-0.3, 1.5, 0.02] },
  { t = 0.1, position = [0.0, 0.0, 0.0], look_at = [0.0, 1.5, 0.0] },
  { t = 0.2, position = [0.0, 0.0, 0.0], look_at = [0.3, 1.5, -0.02] },
]
"""
SLIDE = ('[trajectory]\ntype = "linear"\nposition = [-0.1, 0.0, 0.0]\n'
         "velocity = [1.0, 0.0, 0.0]\nlook_at = [-0.1, 1.0, 0.0]\n")


@pytest.mark.parametrize("trajectory", [TURN, SLIDE], ids=["turning", "sliding"])
def test_events_fire_where_the_pose_and_the_lens_put_an_edge(trajectory, tmp_path):
    """A white stripe (x in [0, 5] cm) on a black wall 1 m away, seen through the distorting
    lens by a camera that turns (pure rotation) or slides: each event of an edge fires within
    half a pixel of where the pose at the event's own time and the lens model put that edge, ON
    where the bright stripe arrives and OFF where it leaves. A time offset between renders and
    poses, an inverted rotation or a lens applied the wrong way moves them by pixels."""
    from sim.eventio import read_events
    from sim.scene import parse_scene
    from sim.simulate import simulate
    from sim.trajectory import read_trajectory

    extra = "[frames]\nrate = 20.0\nexposure = 0.005\nexposure_samples = 1\n[render]\nspp = 4\n"
    scene = parse_scene(scene_text(STRIPE, camera=CAMERA, trajectory=trajectory, duration=0.2,
                                   extra=extra))
    out = simulate(scene, tmp_path / "seq", progress=False).out
    events = read_events(out / "events.h5")
    poses = read_trajectory(out / "groundtruth.txt").pose(events["t"] * 1e-9)
    # each event's ray, undistorted with OpenCV's model (the camera's lookup table)
    ray = scene.camera.normalized_pixel_centres()[events["y"], events["x"]]     # (N, 2)
    for edge_x, polarity in ((0.0, 1), (0.05, -1)):            # the image moves left
        # the vertical edge X = edge_x, Y = 0.999 (world z free) in the camera at each time:
        # the point of it on the event's ray height, then its column in undistorted pixels
        a = np.einsum("nji,j->ni", poses[:, :3, :3], np.array([edge_x, 0.999, 0.0])
                      ) - np.einsum("nji,nj->ni", poses[:, :3, :3], poses[:, :3, 3])
        b = poses[:, 2, :3]                                    # d(local)/d(world z) = R^T e_z
        s = (ray[:, 1] * a[:, 2] - a[:, 1]) / (b[:, 1] - ray[:, 1] * b[:, 2])
        edge = (a[:, 0] + s * b[:, 0]) / (a[:, 2] + s * b[:, 2])
        offset = scene.camera.fx * (ray[:, 0] - edge)          # pixels, undistorted
        near = np.abs(offset) < 2.5
        own = near & (events["p"] == polarity)
        assert own.sum() > 0.95 * near.sum() and own.sum() > 1000, (edge_x, own.sum())
        assert abs(float(np.median(offset[own]))) < 0.5, edge_x


def test_the_map_projected_into_the_distorted_frame_and_the_dense_map_are_scored(boxes_run):
    """Through the lens and the frame's own pose: the map points keep their depths in the frame
    (a projection without distortion, or with the wrong pose, puts them on the wrong side of the
    boxes' edges), and every figure carries its coverage."""
    report = json.loads((boxes_run / "report.json").read_text())
    fill = json.loads((boxes_run / "fill" / "fill.json").read_text())
    assert fill["camera"]["distortion"][0] == -0.3
    in_frame = fill["errors"]["map"]["overall"]
    assert in_frame["points"] == report["N1_in_frame"] > 150
    assert in_frame["median_cm"] < 100 * 2.0 * 0.02            # < 2 % of the wall's 2 m
    assert in_frame["precision_5pct"] > 0.5
    dense = fill["errors"]["all"]["overall"]
    assert dense["points"] == report["N2"] and dense["completeness"] > in_frame["completeness"]
    for block in report["errors_summary"].values():
        assert 0 < block["completeness"] <= 1 and block["points"] > 0
    assert report["oracle"] is False and report["depth_range_m"] == [0.5, 3.0]
