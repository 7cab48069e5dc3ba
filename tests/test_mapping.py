"""evfuse map: semi-dense maps of simulated and real sequences."""

from __future__ import annotations

import json

import cv2
import numpy as np

from fusion.cli import main
from sim.exr import read_depth


def test_map_of_a_plane_comes_back_at_its_depth(plane_sequence, tmp_path):
    out = tmp_path / "map"
    assert main(["map", str(plane_sequence), "--out", str(out), "--min-depth", "0.5",
                 "--max-depth", "3", "--planes", "30", "--quiet"]) == 0
    for name in ("semidense_depth.exr", "confidence.exr", "mask.png", "overlay.png", "map.ply",
                 "map.json"):
        assert (out / name).is_file(), name
    meta = json.loads((out / "map.json").read_text())
    depth = read_depth(out / "semidense_depth.exr")
    assert meta["N1"] == int(np.count_nonzero(depth)) > 30
    planes = 1 / np.linspace(1 / 0.5, 1 / 3.0, 30)
    spacing = abs(1 / planes[1] - 1 / planes[0])
    assert abs(1 / np.median(depth[depth > 0]) - 1.0) <= spacing   # the wall is 1 m away
    errors = meta["errors"]
    assert errors["points"] == meta["N1"] and errors["median_cm"] < 100 * 0.1
    mask = cv2.imread(str(out / "mask.png"), cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(mask > 0, depth > 0)
    header = (out / "map.ply").read_bytes()[:400].decode("ascii", "replace")
    assert f"element vertex {meta['N1']}" in header and "T_world_ref" in header


def test_real_ecd_slider_map(ecd_slider, tmp_path):
    out = tmp_path / "real"
    assert main(["map", str(ecd_slider), "--out", str(out), "--min-depth", "0.47",
                 "--max-depth", "2.4", "--quiet"]) == 0
    meta = json.loads((out / "map.json").read_text())
    assert meta["events_dropped_before_poses"] == 3251             # before the first pose
    assert meta["events_used"] == 50000 - 3251
    depth = read_depth(out / "semidense_depth.exr")
    assert meta["N1"] == int(np.count_nonzero(depth)) > 200
    assert depth[depth > 0].min() >= 0.47 - 1e-6 and depth.max() <= 2.4 + 1e-6
    assert "errors" not in meta                                  # no dense ground truth


def test_bad_map_input_is_refused_before_work(plane_sequence, tmp_path, capsys):
    cases = [
        (["--min-depth", "2", "--max-depth", "1"], "depth range"),
        (["--min-depth", "-1", "--max-depth", "1"], "depth range"),
        (["--t0", "5", "--t1", "6"], "outside the poses"),
        (["--t0", "0.2", "--t1", "0.1"], "empty time window"),
        (["--planes", "1000000"], "GiB"),
        (["--min-depth", "2", "--max-depth", "5"], "does not contain the scene: 0 %"),
    ]
    for extra, message in cases:
        code = main(["map", str(plane_sequence), "--out", str(tmp_path / "x"), "--quiet",
                     *extra])
        assert code == 2 and message in capsys.readouterr().err, extra
    assert main(["map", str(tmp_path / "nowhere"), "--out", str(tmp_path / "y")]) == 2


def test_window_inside_the_poses_without_events_is_refused(ecd_slider, tmp_path, capsys):
    """The prefix's events end at 0.174 s while its poses run to 3.4 s."""
    out = tmp_path / "none"
    assert main(["map", str(ecd_slider), "--out", str(out), "--t0", "1.0", "--t1", "2.0",
                 "--min-depth", "0.47", "--max-depth", "2.4", "--quiet"]) == 2
    assert "no events in the window [1.0, 2.0] s" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob("none*"))


def test_a_depth_range_beyond_a_real_scene_is_refused(ecd_slider, tmp_path, capsys):
    """No exact depth here: the map's points pile up on the nearest planes instead."""
    out = tmp_path / "far"
    assert main(["map", str(ecd_slider), "--out", str(out), "--min-depth", "3",
                 "--max-depth", "8", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "does not seem to contain the scene" in err and "nearer than" in err
    assert not out.exists()


# A box whose front face is 1 m ahead (x in [-0.4, 0.4] m, height in [-0.3, 0.3] m) before a
# wall at 2 m, seen by a 64x48 camera with a DAVIS240C-like barrel distortion.
BOX_BEFORE_WALL = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 2.0, 0.0]
size = [8.0, 8.0]
[[objects]]
name = "box"
type = "box"
center = [0.0, 1.2, 0.0]
size = [0.8, 0.4, 0.6]
"""
DISTORTED = ("[camera]\nwidth = 64\nheight = 48\nfx = 60.0\nfy = 45.0\ncx = 30.3\ncy = 22.7\n"
             "distortion = [-0.35, 0.1, 0.0, 0.0, 0.0]\n")


def _box_depth(camera) -> np.ndarray:
    """The exact z-depth of BOX_BEFORE_WALL at the pixel centres of an undistorted camera."""
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    x, y = (u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy
    # the face's edges are 0.2 px or more from any pixel centre: no rounding question
    assert np.abs(np.abs(x) - 0.4).min() * camera.fx > 0.15
    assert np.abs(np.abs(y) - 0.3).min() * camera.fy > 0.15
    return np.where((np.abs(x) < 0.4) & (np.abs(y) < 0.3), 1.0, 2.0)


def test_map_is_scored_in_its_own_undistorted_grid(tmp_path):
    """A perfect map (the analytic depth of the undistorted view) scores 0 against the exact
    depth the mapping uses, but not against the distorted depth/ of the same time."""
    from fusion.mapping import _ground_truth_depth
    from fusion.scoring import depth_errors
    from sim.camera import Camera
    from sim.scene import parse_scene
    from sim.sequence import load_sequence
    from sim.simulate import simulate
    from sim.trajectory import read_trajectory
    from tests.conftest import scene_text

    extra = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 1\n"
    scene = parse_scene(scene_text(BOX_BEFORE_WALL, camera=DISTORTED, duration=0.05,
                                   extra=extra))
    folder = simulate(scene, tmp_path / "seq", progress=False, with_events=False).out
    sequence = load_sequence(folder)
    sensor = sequence.camera
    assert sensor.has_distortion
    camera = Camera(sensor.width, sensor.height, sensor.fx, sensor.fy, sensor.cx, sensor.cy)
    t = float(sequence.depth_times[0])
    pose = read_trajectory(sequence.groundtruth_path).pose(t)
    perfect = _box_depth(camera)
    edges = np.zeros(perfect.shape, bool)                      # both sides of each depth step
    edges[:, 1:] |= perfect[:, 1:] != perfect[:, :-1]
    edges[:, :-1] |= perfect[:, 1:] != perfect[:, :-1]
    edges[1:, :] |= perfect[1:, :] != perfect[:-1, :]
    edges[:-1, :] |= perfect[1:, :] != perfect[:-1, :]
    truth = _ground_truth_depth(sequence, t, pose, camera)
    distorted = read_depth(sequence.depth_paths[0])            # the sensor's pixels
    for name, semidense in (("all pixels", perfect), ("edge pixels", np.where(edges, perfect, 0))):
        right = depth_errors(semidense, truth)
        assert right["n"] == right["points"] == np.count_nonzero(semidense), name
        assert right["mae_cm"] < 1e-3 and right["precision_1pct"] == 1.0, name
        wrong = depth_errors(semidense, distorted)
        assert wrong["mae_cm"] > 1.0 and wrong["precision_1pct"] < 0.99, name   # the old grid
