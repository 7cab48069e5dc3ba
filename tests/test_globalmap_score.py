"""fusion.globalmap.score: the exact surface of key views, DTU / Tanks and Temples scores of a
cloud, the error-coloured cloud and the global figure."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from fusion.figures import _TITLE_H
from fusion.globalmap.fuse import default_voxel_size
from fusion.globalmap.score import (
    FIGURE_PANEL,
    KEY_VIEW_COLOUR,
    TAUS_M,
    _figure_views,
    cloud_scores,
    draw_global_figure,
    error_colours,
    exact_surface,
    exact_view,
    nearest_distances,
    write_error_cloud,
)
from fusion.globalmap.views import DepthView
from fusion.io import read_ply
from sim.camera import Camera
from sim.capture_errors import RIG_PRESETS
from sim.scene import parse_scene
from sim.sequence import load_sequence
from sim.simulate import simulate
from sim.trajectory import read_trajectory
from tests.conftest import FAST, WALL, scene_text

SMALL = "[camera]\nwidth = 48\nheight = 36\nfx = 45.0\nfy = 44.0\ncx = 23.5\ncy = 17.5\n"
FRAMES = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 1\n"


# --- exact_view: the TRUE camera at the EXACT pose ----------------------------------------------

@pytest.fixture(scope="module")
def lab_sequence(tmp_path_factory):
    """conftest's wall 1 m ahead (the plane y = 1), a 48x36 camera sliding along x at 1 m/s,
    0.1 s, simulated through the ``lab`` rig (pose noise, a 3 ms poses clock offset, a drawn
    calibration with distortion): no events."""
    scene = parse_scene(scene_text(WALL, camera=SMALL, trajectory=FAST, duration=0.1,
                                   extra=FRAMES))
    out = tmp_path_factory.mktemp("lab") / "wall"
    simulate(scene, out, progress=False, with_events=False, rig=RIG_PRESETS["lab"])
    return scene, load_sequence(out)


@pytest.mark.parametrize("late", [0.003, 0.0217])
def test_exact_view_lies_on_the_wall_at_the_true_pose(lab_sequence, late):
    """The exact view's points lie on the wall (y = 1 m) within 10 um in the exact world frame,
    its pose is the scene's at the true time (t_ref - 3 ms) and its camera the true undistorted
    one, whether its depth is a frame's depth map (3 ms late: the true time is a frame's) or a
    render (21.7 ms). The same depth placed by the written (noisy) pose and calibration is off
    the wall by over 0.1 mm: the test tells the two apart."""
    scene, sequence = lab_sequence
    t_ref = float(sequence.image_times[1]) + late
    view = exact_view(sequence, t_ref)
    assert view.t == t_ref and view.valid.all()
    assert view.camera == Camera(48, 36, 45.0, 44.0, 23.5, 17.5)
    t_true = t_ref - RIG_PRESETS["lab"].poses_offset
    np.testing.assert_allclose(view.T_world_cam, scene.trajectory.pose(t_true), atol=1e-9)
    assert abs(view.centre[0] - scene.trajectory.pose(t_ref)[0, 3]) > 2.9e-3   # 3 ms at 1 m/s
    points = view.points_world()
    np.testing.assert_allclose(points[:, 1], 1.0, atol=1e-5)
    written = sequence.camera
    noisy = DepthView(view.depth, Camera(48, 36, written.fx, written.fy, written.cx, written.cy),
                      read_trajectory(sequence.folder / "groundtruth.txt").pose(t_ref))
    assert np.abs(noisy.points_world()[:, 1] - 1.0).max() > 1e-4


def test_a_supersampled_exact_view_splits_each_pixel(lab_sequence):
    """supersample 3: a 144x108 render of the same field of view at the same exact pose, on the
    wall; the middle sub-pixel of each pixel is that pixel's ray, so its depth is the pixel's."""
    _, sequence = lab_sequence
    t_ref = float(sequence.image_times[1]) + 0.003
    coarse, fine = exact_view(sequence, t_ref), exact_view(sequence, t_ref, supersample=3)
    assert fine.depth.shape == (108, 144)
    assert fine.camera == coarse.camera.with_resolution(144, 108)
    np.testing.assert_array_equal(fine.T_world_cam, coarse.T_world_cam)
    np.testing.assert_allclose(fine.points_world()[:, 1], 1.0, atol=1e-5)
    np.testing.assert_allclose(fine.depth[1::3, 1::3], coarse.depth, atol=1e-5)
    with pytest.raises(ValueError, match="supersample"):
        exact_view(sequence, t_ref, supersample=0)


def test_exact_view_of_a_real_recording_is_none(ecd_slider):
    sequence = load_sequence(ecd_slider)
    assert exact_view(sequence, float(sequence.image_times[3])) is None


# --- exact_surface: the union, one point per cube -----------------------------------------------

def _wall_view(x: float = 0.0, depth: float = 1.0, fx: float = 50.0, fy: float = 50.0
               ) -> DepthView:
    """A 40x30 camera at (x, 0, 0) looking along world +z at the plane z = ``depth``."""
    pose = np.eye(4)
    pose[0, 3] = x
    camera = Camera(40, 30, fx, fy, 19.5, 14.5)
    return DepthView(np.full((30, 40), depth, np.float32), camera, pose)


def test_exact_surface_keeps_one_exact_point_per_cube_within_its_diagonal():
    """Two overlapping views of the plane z = 1 (footprint 2 cm): the kept points are points of
    the union, no two share a cube of the spacing, and every point of the union lies within
    the cube's diagonal (sqrt(3) spacing) of a kept one; a view given twice adds nothing."""
    views = [_wall_view(0.0), _wall_view(0.25)]
    union = np.concatenate([v.points_world() for v in views])
    for spacing in (None, 0.013):
        kept = exact_surface(views, spacing)
        side = 0.02 if spacing is None else spacing                  # the footprint: 1 m / 50
        assert nearest_distances(kept, union).max() == 0.0           # exact points
        best: dict = {}                         # per cube, the union's point nearest its centre
        for point in union:
            cube = tuple(np.floor(point / side).astype(int))
            offset = np.linalg.norm(point - (np.array(cube) + 0.5) * side)
            if cube not in best or offset < best[cube][0]:
                best[cube] = (offset, point)
        np.testing.assert_array_equal(kept, [best[c][1] for c in sorted(best)])
        cells = np.floor(kept / side).astype(np.int64)
        assert len(np.unique(cells, axis=0)) == len(kept)
        assert nearest_distances(union, kept).max() <= math.sqrt(3) * side
        assert len(kept) < len(union)
        np.testing.assert_array_equal(exact_surface(views + [views[0]], spacing), kept)
    # the default spacing is the fused cloud's merge voxel (here 1 m / 50 px)
    assert default_voxel_size(views) == 0.02
    # one cube per footprint: the 2 views of 40x30 px overlap by 27.5 of their 40 columns
    assert len(exact_surface(views)) == pytest.approx(52.5 * 30, rel=0.1)
    assert exact_surface([]).shape == (0, 3)
    with pytest.raises(ValueError, match="spacing"):
        exact_surface(views, 0.0)


def test_the_exact_surface_covers_the_plane_within_its_bound():
    """Points drawn on the plane z = 1 where the two views see it are within
    (sqrt(2) / 2 + sqrt(3)) footprints (2 cm) of the default exact surface, on average under
    half a footprint (measured 1.12 and 0.39 footprints)."""
    views = [_wall_view(0.0), _wall_view(0.25)]
    rng = np.random.default_rng(0)
    n = 20000                       # the area seen: pixel centres +-19.5 x 14.5 px of 2 cm
    plane = np.stack([rng.uniform(-0.39, 0.64, n), rng.uniform(-0.29, 0.29, n), np.ones(n)], 1)
    d = nearest_distances(plane, exact_surface(views))
    assert d.max() <= (math.sqrt(2) / 2 + math.sqrt(3)) * 0.02
    assert d.mean() < 0.5 * 0.02


# --- cloud_scores: hand-computed values ---------------------------------------------------------

REFERENCE = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [1.0, 0, 0]])
OFFSETS = np.array([0.005, 0.015, 0.03, 0.08])
OURS = REFERENCE[:4] + OFFSETS[:, None] * [0.0, 1.0, 0.0]


def test_cloud_scores_by_hand():
    """Four points 0.5, 1.5, 3 and 8 cm off the first four of five reference points on a line
    (10 cm apart; the fifth 1 m away, 70.46 cm from our nearest): accuracy is the mean offset,
    completeness adds the fifth's distance, F = 2PR / (P + R), and the 1 % tau of a 9 m scene
    is 9 cm."""
    s = cloud_scores(OURS, REFERENCE, scene_depth=9.0)
    far = math.hypot(0.7, 0.08)
    assert s["accuracy_cm"] == pytest.approx(100 * OFFSETS.mean(), rel=1e-12)
    assert s["completeness_cm"] == pytest.approx(100 * (OFFSETS.sum() + far) / 5, rel=1e-12)
    assert s["chamfer_cm"] == pytest.approx(0.5 * (s["accuracy_cm"] + s["completeness_cm"]))
    assert s["accuracy_median_cm"] == pytest.approx(2.25, rel=1e-12)
    assert s["completeness_median_cm"] == pytest.approx(3.0, rel=1e-12)
    expected = {"1cm": (1 / 4, 1 / 5, 2 / 9), "2cm": (2 / 4, 2 / 5, 4 / 9),
                "5cm": (3 / 4, 3 / 5, 2 / 3), "rel1pct": (1.0, 4 / 5, 8 / 9)}
    for name, (p, r, f) in expected.items():
        assert s[f"precision_{name}"] == pytest.approx(p, rel=1e-12)
        assert s[f"recall_{name}"] == pytest.approx(r, rel=1e-12)
        assert s[f"fscore_{name}"] == pytest.approx(f, rel=1e-12)
    assert s["tau_rel1pct_cm"] == pytest.approx(9.0)
    assert (s["points"], s["reference_points"]) == (4, 5)
    assert TAUS_M == (0.01, 0.02, 0.05)


def test_precision_counts_distances_strictly_below_tau():
    """Tanks and Temples counts d < tau: a point 2 cm off (exactly representable: 2**-6 m off
    scaled) is outside tau = its own distance, inside any larger tau."""
    d = 2.0 ** -6                                              # 1.5625 cm, exact in binary
    s = cloud_scores([[0.0, d, 0.0]], [[0.0, 0.0, 0.0]], 1.0, taus=(d, 0.02))
    assert s[f"precision_{100 * d:g}cm"] == 0.0 and s["precision_2cm"] == 1.0


def test_a_cloud_scored_against_itself_is_perfect():
    cloud = np.random.default_rng(1).uniform(-1, 1, (500, 3))
    s = cloud_scores(cloud, cloud, scene_depth=1.0)
    assert s["accuracy_cm"] == s["completeness_cm"] == s["chamfer_cm"] == 0.0
    assert all(s[f"{k}_{n}"] == 1.0 for k in ("precision", "recall", "fscore")
               for n in ("1cm", "2cm", "5cm", "rel1pct"))


@pytest.mark.parametrize("ours, reference", [(np.empty((0, 3)), REFERENCE),
                                             (OURS, np.empty((0, 3))),
                                             (np.empty((0, 3)), np.empty((0, 3)))])
def test_empty_clouds_score_nan_distances_and_zero_shares(ours, reference):
    s = cloud_scores(ours, reference, scene_depth=1.0)
    for key in ("accuracy_cm", "completeness_cm", "chamfer_cm", "accuracy_median_cm",
                "completeness_median_cm"):
        assert math.isnan(s[key])
    assert all(s[f"{k}_{n}"] == 0.0 for k in ("precision", "recall", "fscore")
               for n in ("1cm", "2cm", "5cm", "rel1pct"))
    assert (s["points"], s["reference_points"]) == (len(ours), len(reference))


def test_cloud_scores_refuse_bad_inputs():
    with pytest.raises(ValueError, match="scene_depth"):
        cloud_scores(OURS, REFERENCE, scene_depth=0.0)
    with pytest.raises(ValueError, match="finite"):
        cloud_scores(np.array([[0.0, math.nan, 0.0]]), REFERENCE, scene_depth=1.0)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        cloud_scores(np.zeros((4, 2)), REFERENCE, scene_depth=1.0)


# --- the error-coloured cloud -------------------------------------------------------------------

TURBO = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0]


def test_error_colours_are_turbo_from_zero_to_the_maximum_clipped():
    """0, 2, 10 and 30 cm with a 10 cm maximum: TURBO's levels 0, 51 (2/10 of 255), 255, 255."""
    colours = error_colours([0.0, 0.02, 0.1, 0.3, math.inf], 0.1)
    np.testing.assert_array_equal(colours, TURBO[[0, 51, 255, 255, 255]])
    assert error_colours([], 0.1).shape == (0, 3)
    with pytest.raises(ValueError, match="errors_m"):
        error_colours([math.nan], 0.1)
    with pytest.raises(ValueError, match="max_error_m"):
        error_colours([0.01], 0.0)


def test_the_error_cloud_is_written_in_the_world_frame(tmp_path):
    write_error_cloud(tmp_path / "e.ply", OURS, OFFSETS, 0.05)
    record, header = read_ply(tmp_path / "e.ply")
    assert header["comment"] == "T_world"
    np.testing.assert_array_equal(header["pose"], np.eye(4))
    np.testing.assert_allclose(np.stack([record["x"], record["y"], record["z"]], 1), OURS,
                               atol=1e-7)
    bgr = np.stack([record["blue"], record["green"], record["red"]], 1)
    np.testing.assert_array_equal(bgr, error_colours(OFFSETS, 0.05))


# --- the figure ---------------------------------------------------------------------------------

GRID = np.stack(np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 1, 11), [0.0]), -1
                ).reshape(-1, 3)
"""A square metre of the floor z = 0, a point every 10 cm."""
TRAJECTORY = np.stack([np.linspace(0.2, 0.8, 13), np.full(13, 0.6), np.full(13, 0.5)], 1)
KEY_VIEWS = TRAJECTORY[[0, 6, 12]]
FIGURE_SHAPE = (_TITLE_H + FIGURE_PANEL[1] + 22, 2 * FIGURE_PANEL[0], 3)


def _panel(figure: np.ndarray, k: int) -> np.ndarray:
    width, height = FIGURE_PANEL
    return figure[_TITLE_H:_TITLE_H + height, k * width:(k + 1) * width]


def test_the_figure_marks_the_key_views_where_they_project():
    """Top view of the floor: seen from +z (the points' least extent), x right, y up, fitted
    to the 1 m square with 24 px free: 432 px/m about the centre (319.5, 239.5). Key view
    (0.2, 0.6) lands at (189.9, 196.3) -> pixel (190, 196), black; in the perspective view each
    key view's disc is where the view's camera projects it. Without key views, those pixels
    are not black. A floor point's square has its error's colour."""
    errors = np.full(len(GRID), 0.02)
    figure = draw_global_figure(GRID, errors, TRAJECTORY, KEY_VIEWS, max_error_m=0.1)
    assert figure.shape == FIGURE_SHAPE and figure.dtype == np.uint8
    top = _panel(figure, 0)
    scale = (480 - 48) / 1.0
    for x, y, _ in KEY_VIEWS:
        u, v = 319.5 + scale * (x - 0.5), 239.5 - scale * (y - 0.5)
        assert tuple(top[int(round(v)), int(round(u))]) == KEY_VIEW_COLOUR
    u, v = 319.5 + scale * (0.0 - 0.5), 239.5 - scale * (0.0 - 0.5)          # corner (0, 0)
    np.testing.assert_array_equal(top[math.ceil(v), math.ceil(u)], TURBO[51])
    _, perspective_view = _figure_views(GRID, TRAJECTORY, KEY_VIEWS)
    uv, ahead = perspective_view.project(KEY_VIEWS)
    assert ahead.all()
    perspective = _panel(figure, 1)
    bare = draw_global_figure(GRID, errors, TRAJECTORY, np.empty((0, 3)), max_error_m=0.1)
    for u, v in np.round(uv).astype(int):
        assert 0 <= u < FIGURE_PANEL[0] and 0 <= v < FIGURE_PANEL[1]
        assert tuple(perspective[v, u]) == KEY_VIEW_COLOUR
        assert tuple(_panel(bare, 1)[v, u]) != KEY_VIEW_COLOUR
    # behind and above the start: the start is nearer the camera than the floor's centre
    start, centre = perspective_view.project(TRAJECTORY[:1])[0][0], np.array([319.5, 239.5])
    assert perspective_view.depth(TRAJECTORY[:1])[0] < perspective_view.depth(GRID).mean()
    assert np.linalg.norm(start - centre) < 300


@pytest.mark.parametrize("points", [np.empty((0, 3)), GRID])
def test_the_figure_draws_empty_clouds_and_heights(points):
    """No errors (a real recording): coloured by height; empty clouds and no trajectory: the
    figure still has its size."""
    for trajectory, key_views in ((TRAJECTORY, KEY_VIEWS), (np.empty((0, 3)), np.empty((0, 3)))):
        figure = draw_global_figure(points, None, trajectory, key_views, max_error_m=0.1)
        assert figure.shape == FIGURE_SHAPE
    empty = draw_global_figure(np.empty((0, 3)), np.empty(0), TRAJECTORY, KEY_VIEWS, 0.1)
    assert empty.shape == FIGURE_SHAPE
    no_reference = nearest_distances(GRID, np.empty((0, 3)))            # inf: the last colour
    figure = draw_global_figure(GRID, no_reference, TRAJECTORY, KEY_VIEWS, 0.1)
    assert figure.shape == FIGURE_SHAPE


def test_tolerances_that_follow_each_points_depth_by_hand():
    """Three reference points on a camera's axis at 1, 2 and 4 m, ours 0.5, 1.5 and 5 cm beside
    them: at 1 % of depth the taus are 1, 2 and 4 cm (the last misses), at the plane step of a
    DSI 0.01 / m apart in inverse depth they are z^2 / 100 = 1, 4 and 16 cm (all pass)."""
    reference = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 4.0]])
    ours = reference + np.array([[0.005, 0, 0], [0.015, 0, 0], [0.05, 0, 0]])
    s = cloud_scores(ours, reference, 2.0, poses=np.eye(4)[None], inverse_depth_step=0.01)
    for name, (p, r) in {"depth1pct": (2 / 3, 2 / 3), "step": (1.0, 1.0)}.items():
        assert s[f"precision_{name}"] == pytest.approx(p)
        assert s[f"recall_{name}"] == pytest.approx(r)
        assert s[f"fscore_{name}"] == pytest.approx(2 * p * r / (p + r))
    assert s["tau_step_median_cm"] == pytest.approx(4.0)
    assert "fscore_step" not in cloud_scores(ours, reference, 2.0, poses=np.eye(4)[None])
    assert "fscore_depth1pct" not in cloud_scores(ours, reference, 2.0)
    with pytest.raises(ValueError, match="inverse_depth_step"):
        cloud_scores(ours, reference, 2.0, poses=np.eye(4)[None], inverse_depth_step=0.0)


def test_point_depths_take_the_nearest_cameras_axis():
    from fusion.globalmap.score import point_depths

    turned = np.eye(4)
    turned[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]    # looks along world +y ...
    turned[:3, 3] = [5.0, 0.0, 0.0]                        # ... from x = 5 m
    points = np.array([[0.1, 0.2, 1.5], [5.0, 2.5, 0.3]])
    np.testing.assert_allclose(point_depths(points, np.stack([np.eye(4), turned])), [1.5, 2.5])


def test_nearest_distances_are_the_brute_force_ones_near_and_far():
    """The k-d tree's larger leaves (KD_LEAF_SIZE) change no distance: against every pairwise
    distance, for points on, near and far from a curved two-sided surface."""
    rng = np.random.default_rng(7)
    u = rng.normal(size=(3000, 3))
    sphere = 0.5 * u / np.linalg.norm(u, axis=1, keepdims=True)
    floor = np.column_stack([rng.uniform(-2, 2, 3000), np.full(3000, -0.6),
                             rng.uniform(-2, 2, 3000)])
    reference = np.concatenate([sphere, floor])
    points = np.concatenate([reference[:300] + rng.normal(0, 0.002, (300, 3)),
                             rng.uniform(-3.0, 3.0, (700, 3))])
    brute = np.sqrt(((points[:, None, :] - reference[None, :, :]) ** 2).sum(-1)).min(1)
    found = nearest_distances(points, reference)
    np.testing.assert_allclose(found, brute, rtol=1e-12, atol=0)
    assert found.max() > 1.0 and found.min() < 0.01
