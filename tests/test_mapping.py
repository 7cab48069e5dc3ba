"""evfuse map: semi-dense maps of simulated and real sequences."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

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


# Windows of slider_depth's frame (sensor pixels, rows then columns) around objects whose order
# in depth the frame shows by occlusion: the box covers the dartboard's lower-left corner, the
# ball covers the box's lower-right corner. So: dartboard behind box behind ball.
DARTBOARD = (slice(2, 75), slice(165, 228))
BOX = (slice(62, 118), slice(124, 162))                         # above the ball
BALL = (slice(126, 150), slice(145, 175))


def _median_depth(depth, window):
    values = depth[window]
    values = values[values > 0]
    assert len(values) >= 30, f"only {len(values)} map points in {window}"
    return float(np.median(values))


def test_real_ecd_slider_map_puts_the_objects_in_their_order(ecd_slider, tmp_path):
    """The real recording has no dense ground truth, but its frame shows which object hides
    which: the map must put the dartboard well behind the box and the ball before the box."""
    out = tmp_path / "real"
    assert main(["map", str(ecd_slider), "--out", str(out), "--min-depth", "0.47",
                 "--max-depth", "2.4", "--quiet"]) == 0
    meta = json.loads((out / "map.json").read_text())
    assert meta["events_dropped_before_poses"] == 3251             # before the first pose
    assert meta["events_used"] == 50000 - 3251
    depth = read_depth(out / "semidense_depth.exr")
    assert meta["N1"] == int(np.count_nonzero(depth)) > 200
    assert "errors" not in meta                                  # no dense ground truth
    dartboard, box, ball = (_median_depth(depth, w) for w in (DARTBOARD, BOX, BALL))
    assert dartboard > 1.5 * box                                  # a wall behind a desk
    assert ball < 0.95 * box


def test_real_ecd_slider_maps_of_two_half_windows_agree(ecd_slider, tmp_path):
    """The two halves of the events (0.0223-0.0982 s, 0.0982-0.1742 s), mapped into the same
    reference view (0.0982 s), see the scene from baselines of 2.1 and 2.4 cm on opposite
    sides: where both have a point, their inverse depths must agree to within one pixel of
    disparity over the shorter baseline (fx b |1/z_a - 1/z_b| < 1 px at the median, edges
    being located to about a pixel), and both must put the dartboard behind the box."""
    ref = 0.098224
    maps = []
    for k, (t0, t1) in enumerate([(0.0223, ref), (ref, 0.1742)]):
        out = tmp_path / f"half{k}"
        assert main(["map", str(ecd_slider), "--out", str(out), "--min-depth", "0.47",
                     "--max-depth", "2.4", "--t0", str(t0), "--t1", str(t1), "--ref-time",
                     str(ref), "--quiet"]) == 0
        assert json.loads((out / "map.json").read_text())["t_ref"] == pytest.approx(ref)
        maps.append(read_depth(out / "semidense_depth.exr"))
    first, second = maps
    both = (first > 0) & (second > 0)
    assert both.sum() > 500
    poses = np.loadtxt(ecd_slider / "groundtruth.txt")
    x = np.interp([0.0223, ref, 0.1742], poses[:, 0], poses[:, 1])  # the slider moves along x
    baseline = min(x[1] - x[0], x[2] - x[1])
    fx = float((ecd_slider / "calib.txt").read_text().split()[0])
    disparity = fx * baseline * np.abs(1 / first[both] - 1 / second[both])
    assert np.median(disparity) < 1.0
    for depth in maps:
        assert _median_depth(depth, DARTBOARD) > 1.3 * _median_depth(depth, BOX)


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
