"""evfuse map: semi-dense maps of simulated and real sequences."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from fusion.cli import main
from sim.exr import read_depth
from sim.sequence import load_sequence


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
    # The dartboard (about 2.06 m over the whole prefix) lies near the range's far end, and over
    # the first half's 2.1 cm baseline many of its points peak on the last plane (2.4 m): with
    # them dropped (the default) its median there is 1.23 m against the box's 0.98 m, with them
    # kept (--keep-boundary-planes, as rpg_emvs) 1.56 m. Behind by a fifth, either way.
    for depth in maps:
        assert _median_depth(depth, DARTBOARD) > 1.2 * _median_depth(depth, BOX)


def test_bad_map_input_is_refused_before_work(plane_sequence, tmp_path, capsys):
    cases = [
        (["--min-depth", "2", "--max-depth", "1"], "depth range"),
        (["--min-depth", "-1", "--max-depth", "1"], "depth range"),
        (["--t0", "5", "--t1", "6"], "lies outside the data"),
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
    assert "time window [1, 2] s lies outside the data" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob("none*"))


def test_a_depth_range_beyond_a_real_scene_is_refused(ecd_slider, tmp_path, capsys):
    """No exact depth here: the map's points pile up on the nearest planes instead."""
    out = tmp_path / "far"
    assert main(["map", str(ecd_slider), "--out", str(out), "--min-depth", "3",
                 "--max-depth", "8", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "does not seem to contain the scene" in err and "nearer than" in err
    assert not out.exists()


# --- the event window against the data (issue 11, item 3) -------------------------------------
# Facts of the real prefix, from its text files: the first pose at 0.022291582 s
# (groundtruth.txt), the events from 0.003811 s to 0.174156 s (events.txt), 3251 events before
# the first pose. The simulated plane sequence covers [0, 0.3] s (events and poses).

def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_a_window_past_the_real_events_is_refused_or_clipped_on_request(ecd_slider, tmp_path,
                                                                        capsys):
    common = ["--min-depth", "0.47", "--max-depth", "2.4", "--quiet"]
    out = tmp_path / "past"
    assert main(["map", str(ecd_slider), "--out", str(out), "--t0", "0", "--t1", "1.0",
                 *common]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("evfuse map: error: time window [0, 1] s reaches 0.826 s past")
    for part in ("events [0.003811, 0.174156] s", "poses [0.022292, 3.402486] s",
                 "--t0/--t1 within [0.022292, 0.174156] s", "--clip-window"):
        assert part in line, part
    assert not list(tmp_path.iterdir())
    clipped, whole = tmp_path / "clipped", tmp_path / "whole"
    assert main(["map", str(ecd_slider), "--out", str(clipped), "--t0", "0", "--t1", "1.0",
                 "--clip-window", *common]) == 0
    assert main(["map", str(ecd_slider), "--out", str(whole), *common]) == 0
    meta = json.loads((clipped / "map.json").read_text())
    assert meta["window_requested_s"] == [0.0, 1.0] and meta["window_clipped"] is True
    np.testing.assert_allclose(meta["window_s"], [0.022291582, 0.174156], atol=1e-9)
    assert meta["params"]["clip_window"] is True
    assert meta["events_used"] == 50000 - 3251 and meta["events_dropped_before_poses"] == 3251
    # the reference view: the frame nearest the middle of the window used (as evfuse run)
    sequence = load_sequence(ecd_slider)
    middle = 0.5 * (0.022291582 + 0.174156)
    assert meta["t_ref"] == sequence.image_times[sequence.nearest_frame(middle)]
    assert abs(meta["t_ref"] - middle) < 0.5 * np.diff(sequence.image_times).max()
    # the clipped window is the data's whole span: the same map as without a window
    default = json.loads((whole / "map.json").read_text())
    assert default["window_s"] == meta["window_s"] and default["window_clipped"] is False
    assert default["window_requested_s"] == [None, None]
    np.testing.assert_array_equal(read_depth(clipped / "semidense_depth.exr"),
                                  read_depth(whole / "semidense_depth.exr"))
    assert meta["N1"] == default["N1"] > 200


def test_a_reference_view_without_events_near_it_is_refused(ecd_slider, tmp_path, capsys):
    """A reference at 1 s lies inside the poses but 0.83 s after the last event."""
    assert main(["map", str(ecd_slider), "--out", str(tmp_path / "o"), "--t0", "0.05", "--t1",
                 "0.15", "--ref-time", "1.0", "--quiet"]) == 2
    line = _one_error_line(capsys)
    assert "reference view at 1.000000 s has 0 events of the window [0.050000, 0.150000] s" in line
    assert "--ref-time" in line


def test_a_window_past_a_simulated_sequence_is_refused(plane_sequence, tmp_path, capsys):
    out = tmp_path / "past"
    assert main(["map", str(plane_sequence), "--out", str(out), "--t0", "0.1", "--t1", "0.5",
                 "--quiet"]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("evfuse map: error: time window [0.1, 0.5] s reaches 0.2 s past")
    for part in ("events [0.000000, 0.300000] s", "poses [0.000000, 0.300000] s",
                 "--clip-window to map [0.100000, 0.300000] s"):
        assert part in line, part
    assert not list(tmp_path.iterdir())
    # a window on the last frame at 0.3 s but with no event near it: refused as well
    assert main(["map", str(plane_sequence), "--out", str(out), "--t0", "0.0", "--t1", "0.05",
                 "--ref-time", "0.3", "--quiet"]) == 2
    assert "reference view at 0.300000 s has 0 events" in _one_error_line(capsys)


@pytest.mark.parametrize("argv, used, clipped", [
    (["--t0", "0.05", "--t1", "0.25"], [0.05, 0.25], False),         # inside: used as asked
    (["--t0", "0.1", "--t1", "0.5", "--clip-window"], [0.1, 0.3], True),
    (["--t0", "0.1", "--t1", "0.3005"], [0.1, 0.3], True),            # within WINDOW_SLACK_S
])
def test_map_json_records_the_window_used(argv, used, clipped, plane_sequence, tmp_path):
    out = tmp_path / "map"
    assert main(["map", str(plane_sequence), "--out", str(out), "--min-depth", "0.5",
                 "--max-depth", "3", "--planes", "30", "--quiet", *argv]) == 0
    meta = json.loads((out / "map.json").read_text())
    np.testing.assert_allclose(meta["window_s"], used, atol=1e-12)
    assert meta["window_requested_s"] == [float(argv[1]), float(argv[3])]
    assert meta["window_clipped"] is clipped
    sequence = load_sequence(plane_sequence)                     # the frame nearest the middle
    assert meta["t_ref"] == sequence.image_times[sequence.nearest_frame(0.5 * sum(used))]


def test_time_window_checks_once_for_map_and_run(plane_sequence):
    from fusion.map.mapping import time_window
    from sim.sequence import load_sequence

    sequence = load_sequence(plane_sequence)
    window = time_window(sequence, 0.1, 0.2)
    assert (window.t0, window.t1, window.clipped) == (0.1, 0.2, False)
    assert window.t_ref == pytest.approx(0.15, abs=1e-15)
    assert window.events_span == (0.0, 0.3) and window.poses_span == (0.0, 0.3)
    assert time_window(sequence).requested == (None, None)           # the data's span
    assert (time_window(sequence).t0, time_window(sequence).t1) == (0.0, 0.3)
    assert time_window(sequence, 0.1, 0.1 + 0.2).clipped is False    # 0.30000000000000004
    assert time_window(sequence, 0.1, 0.5, clip=True).t_ref == pytest.approx(0.2)
    with pytest.raises(ValueError, match=r"reaches 0\.2 s past the data"):
        time_window(sequence, 0.1, 0.5, clip=False)


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
    from fusion.map.mapping import _ground_truth_depth
    from fusion.scoring import depth_errors
    from sim.camera import Camera
    from sim.scene import parse_scene
    from sim.sequence import load_sequence
    from sim.simulate import simulate
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
    perfect = _box_depth(camera)
    edges = np.zeros(perfect.shape, bool)                      # both sides of each depth step
    edges[:, 1:] |= perfect[:, 1:] != perfect[:, :-1]
    edges[:, :-1] |= perfect[:, 1:] != perfect[:, :-1]
    edges[1:, :] |= perfect[1:, :] != perfect[:-1, :]
    edges[:-1, :] |= perfect[1:, :] != perfect[:-1, :]
    truth = _ground_truth_depth(sequence, t)
    distorted = read_depth(sequence.depth_paths[0])            # the sensor's pixels
    for name, semidense in (("all pixels", perfect), ("edge pixels", np.where(edges, perfect, 0))):
        right = depth_errors(semidense, truth)
        assert right["n"] == right["points"] == np.count_nonzero(semidense), name
        assert right["mae_cm"] < 1e-3 and right["precision_1pct"] == 1.0, name
        wrong = depth_errors(semidense, distorted)
        assert wrong["mae_cm"] > 1.0 and wrong["precision_1pct"] < 0.99, name   # the old grid


def test_map_json_and_the_summary_give_the_maps_median_depth(plane_sequence, tmp_path, capsys):
    """`evfuse twin --depth` asks for "the median depth of `evfuse map`": both say it."""
    out = tmp_path / "map"
    assert main(["map", str(plane_sequence), "--out", str(out), "--min-depth", "0.5",
                 "--max-depth", "3", "--planes", "30", "--quiet"]) == 0
    meta = json.loads((out / "map.json").read_text())
    depth = read_depth(out / "semidense_depth.exr")
    median = float(np.median(depth[depth > 0]))            # from the map's own file
    assert meta["depth_median_m"] == pytest.approx(median, rel=1e-6)
    assert abs(median - 1.0) < 0.1                         # the wall, 1 m away
    assert f"median depth {median:.3f} m" in capsys.readouterr().out


def test_a_wall_beyond_the_range_piles_on_the_last_plane_and_is_dropped(plane_sequence):
    """Issue 21: the wall is 1 m away; with a 0.4-0.8 m range its rays meet beyond the last
    plane, so rpg_emvs's maps put it at 0.8 m. By default those points are dropped and counted
    in map.json's boundary_plane_points; keep_boundary_planes keeps them (rpg_emvs's parity)."""
    from fusion.map.emvs import DepthMapParams, DSIParams
    from fusion.map.mapping import MapParams, map_sequence

    def mapped(keep: bool):
        params = MapParams(DSIParams(0.4, 0.8, planes=30),
                           DepthMapParams(keep_boundary_planes=keep), check_depth_range=False)
        return map_sequence(plane_sequence, params, progress=False)

    dropped, kept = mapped(False), mapped(True)
    last = np.float32(0.8)
    on_last = int(np.count_nonzero(np.isclose(kept.depth, last)))
    assert on_last > 0.5 * kept.n1                        # rpg_emvs: most points at 0.8 m
    counts = dropped.info["boundary_plane_points"]
    assert counts["dropped"] and counts["far"] >= on_last and counts["far"] > 2 * counts["near"]
    assert not np.isclose(dropped.depth, last).any()
    assert dropped.n1 <= kept.n1 - on_last
    assert kept.info["boundary_plane_points"] == {**counts, "dropped": False}


def test_the_boundary_plane_count_and_setting_are_in_map_json(plane_sequence, tmp_path):
    outs = {}
    for keep in (False, True):
        out = tmp_path / f"map_{keep}"
        assert main(["map", str(plane_sequence), "--out", str(out), "--min-depth", "0.5",
                     "--max-depth", "3", "--planes", "30", "--quiet"]
                    + (["--keep-boundary-planes"] if keep else [])) == 0
        outs[keep] = (json.loads((out / "map.json").read_text()),
                      read_depth(out / "semidense_depth.exr"))
    meta, depth = outs[False]
    assert meta["params"]["depth"]["keep_boundary_planes"] is False
    assert outs[True][0]["params"]["depth"]["keep_boundary_planes"] is True
    counts = meta["boundary_plane_points"]
    assert counts == {**outs[True][0]["boundary_plane_points"], "dropped": True}
    assert 0 < meta["N1"] < outs[True][0]["N1"]
    planes = np.float32(1 / np.linspace(1 / 0.5, 1 / 3.0, 30))
    assert np.isin(outs[True][1], planes[[0, -1]]).any()       # rpg_emvs's map has some
