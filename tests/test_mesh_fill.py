"""The ``mesh`` filling method (fusion.methods.mesh) on analytic cases.

Frames are 80x60. A *textured* frame (seeded noise, gray 0-255) splits into many tiny regions
that region growing discards, so the paper's regions (stages 1, 3, 4) are empty and the mesh
(stage 2) does the work; a *flat* frame is one region, which the paper selects.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fusion.methods import MethodError, run_method
from fusion.methods.mesh import (
    MeshParams,
    _cubic_patch,
    _locate,
    _triangulation,
    _vertex_slopes,
    clean_map,
    mesh_fill,
)
from sim.camera import Camera

H, W = 60, 80
CAMERA = Camera(width=W, height=H, fx=70.0, fy=65.0, cx=39.5, cy=29.5,
                distortion=(-0.25, 0.08, 1e-3, -5e-4, 0.0))


def _textured() -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, (H, W)).astype(np.uint8)


def _flat() -> np.ndarray:
    return np.full((H, W), 120, np.uint8)


def _random_points(truth: np.ndarray, share: float = 0.04, seed: int = 1) -> np.ndarray:
    mask = np.random.default_rng(seed).random((H, W)) < share
    return np.where(mask, truth, 0).astype(np.float32)


def _plane(camera: Camera = CAMERA) -> np.ndarray:
    """A plane n . X = d (0.9-1.6 m), exact in inverse depth through the camera's lens."""
    xy = camera.normalized_pixel_centres()
    return 1.2 / (xy @ np.array([0.3, -0.2]) + 1.0)


def _relative(dense: np.ndarray, truth: np.ndarray, where: np.ndarray) -> np.ndarray:
    return np.abs(dense[where] / truth[where] - 1)


def test_a_plane_through_a_distorting_lens_is_filled_exactly_by_the_mesh():
    truth = _plane()
    sparse = _random_points(truth)
    result = mesh_fill(_textured(), sparse, CAMERA)
    filled = result.stage > 0
    assert np.all(result.stage[filled] == 2)               # no region: the mesh alone
    assert filled.sum() > 0.8 * H * W
    assert _relative(result.dense, truth, filled).max() < 1e-5
    assert np.all(result.dense[sparse > 0] == sparse[sparse > 0])
    # The lens matters: the same mesh in distorted coordinates is off by more than 1e-4.
    naive = mesh_fill(_textured(), sparse, dataclasses.replace(CAMERA, distortion=(0.0,) * 5))
    assert _relative(naive.dense, truth, naive.stage > 0).max() > 1e-4


def test_constant_depth_stays_constant():
    truth = np.full((H, W), 1.7)
    sparse = _random_points(truth, 0.02)
    for frame in (_textured(), _flat()):
        dense, confidence, _ = run_method("mesh", frame, sparse, CAMERA)
        filled = (dense > 0) & (sparse == 0)
        assert filled.sum() > 0.8 * H * W
        np.testing.assert_allclose(dense[dense > 0], 1.7, rtol=1e-6)
        assert np.all(confidence[filled] > 0) and np.all(confidence[sparse > 0] == 0)


def test_a_quadric_patch_is_fitted_by_the_surface_stage():
    # As in test_surface_fit: an inner rectangle (rows 8-51, columns 8-71) on a darker border,
    # map points on its outline and six inside.
    xy = CAMERA.normalized_pixel_centres()
    x, y = xy[..., 0], xy[..., 1]
    truth = 1.0 / (0.8 + 0.1 * x - 0.9 * x * x + 0.3 * x * y - 0.9 * y * y)
    frame = np.full((H, W), 20, np.uint8)
    frame[8:52, 8:72] = 100
    inner = frame == 100
    outline = inner & ~np.pad(inner[1:-1, 1:-1] & inner[:-2, 1:-1] & inner[2:, 1:-1]
                              & inner[1:-1, :-2] & inner[1:-1, 2:], 1)
    sparse = np.where(outline, truth, 0).astype(np.float32)
    for row, col in [(20, 24), (20, 56), (30, 40), (40, 24), (40, 56), (30, 20)]:
        sparse[row, col] = truth[row, col]
    result = mesh_fill(frame, sparse, CAMERA)
    assert np.all(result.stage[inner & (sparse == 0)] == 1)   # the rectangle's quadric
    assert _relative(result.dense, truth, inner & (sparse == 0)).max() < 1e-3


def _egg_crate() -> np.ndarray:
    """A height field (1.12-1.28 m) that neither a plane nor a quadric explains."""
    v, u = np.mgrid[0:H, 0:W]
    return 1.2 + 0.08 * np.sin(u / 9.0) * np.cos(v / 8.0)


def test_a_curved_surface_is_followed_by_the_mesh_within_its_linear_bound():
    # Points 3 % of the pixels (about 6 px apart); linear interpolation errs by up to
    # h^2 / 8 max|z''| = 36 / 8 * 0.08 / 64 m = 0.5 % of the depth, more in the few larger
    # triangles. The cleaning's local planes miss the crests by more than 2 % over 12
    # neighbours: 10 of the 134 points are dropped (a limit of the method, documented).
    truth = _egg_crate()
    sparse = _random_points(truth, 0.03)
    result = mesh_fill(_textured(), sparse, CAMERA)
    filled = result.stage > 0
    assert result.kept.sum() >= 0.9 * (sparse > 0).sum()
    assert filled.sum() > 0.65 * H * W and np.all(result.stage[filled] == 2)
    error = _relative(result.dense, truth, filled)
    assert np.mean(error) < 0.006 and np.percentile(error, 99) < 0.03
    nearest = run_method("nearest", _textured(), sparse, CAMERA)[0]
    assert np.mean(_relative(nearest, truth, filled)) > 1.5 * np.mean(error)   # 1.8x


def test_the_regions_triangles_follow_curvature_better_smooth_than_linear():
    # Stage 3 alone (no triangle is consistent at 1e-9, no quadric is tried): the inner
    # rectangle of the quadric test, its outline and 2 % of its pixels as map points.
    truth = _egg_crate()
    frame = np.full((H, W), 20, np.uint8)
    frame[8:52, 8:72] = 100
    inner = frame == 100
    outline = inner & ~np.pad(inner[1:-1, 1:-1] & inner[:-2, 1:-1] & inner[2:, 1:-1]
                              & inner[1:-1, :-2] & inner[1:-1, 2:], 1)
    chosen = (np.random.default_rng(1).random((H, W)) < 0.02) & inner
    sparse = np.where(outline | chosen, truth, 0).astype(np.float32)
    errors = {}
    for smooth in (True, False):
        result = mesh_fill(frame, sparse, CAMERA, MeshParams(
            consistency_rel=1e-9, quadric_min_points=10 ** 6, smooth=smooth))
        assert np.all(result.stage[inner & (sparse == 0)] == 3)
        errors[smooth] = _relative(result.dense, truth, inner & (sparse == 0))
    assert np.mean(errors[True]) < 0.0025 and np.percentile(errors[True], 99) < 0.01
    assert np.mean(errors[True]) < 0.5 * np.mean(errors[False])


def test_a_depth_step_is_never_bridged():
    # Left half at 1.0 m, right half at 1.5 m: a triangle with corners on both sides is not
    # consistent (stage 2) and its jump (50 %) is above max_jump_rel (stage 3).
    truth = np.where(np.arange(W) < 40, 1.0, 1.5)[None, :].repeat(H, axis=0)
    sparse = _random_points(truth, 0.05)
    result = mesh_fill(_textured(), sparse, CAMERA)
    mesh = result.stage == 2
    assert _relative(result.dense, truth, mesh).max() < 1e-6
    # No filled pixel has a depth between the two sides.
    filled = result.dense[result.stage > 0]
    assert np.all((np.abs(filled - 1.0) < 1e-5) | (np.abs(filled - 1.5) < 1.5e-5))
    # What is left empty is the strip between the step's nearest points (and the border).
    empty = (result.dense == 0)
    assert empty.mean() < 0.25
    assert empty[:, 5:35].mean() < 0.1 and empty[:, 45:75].mean() < 0.1


def test_an_isolated_wrong_depth_is_dropped_and_replaced_by_the_surface():
    truth = _plane()
    sparse = _random_points(truth)
    rows, cols = np.nonzero(sparse)
    k = len(rows) // 2
    sparse[rows[k], cols[k]] *= 1.5
    result = mesh_fill(_textured(), sparse, CAMERA)
    assert not result.kept[rows[k], cols[k]] and result.kept.sum() == len(rows) - 1
    assert result.stage[rows[k], cols[k]] == 2
    assert abs(result.dense[rows[k], cols[k]] / truth[rows[k], cols[k]] - 1) < 1e-5
    assert _relative(result.dense, truth, result.stage > 0).max() < 1e-5
    # Without the cleaning the wrong point bends the mesh around it.
    raw = mesh_fill(_textured(), sparse, CAMERA, MeshParams(min_support=0))
    assert raw.dense[rows[k], cols[k]] == sparse[rows[k], cols[k]]


def test_clean_map_keeps_points_along_an_edge_and_drops_isolated_ones():
    sparse = np.zeros((H, W), np.float32)
    sparse[30, 10:70] = 2.0                                # an edge at one depth
    sparse[10, 40] = 2.0                                   # alone, far from the edge...
    sparse[31, 40] = 1.0                                   # ... and next to it, but 50 % off
    kept = clean_map(sparse, CAMERA)
    assert kept[30, 10:70].all() and not kept[31, 40]
    assert kept[10, 40]                                    # its 12 nearest agree, far or not
    assert clean_map(sparse, CAMERA, min_support=0).sum() == (sparse > 0).sum()
    assert not clean_map(sparse * 0, CAMERA).any()


def test_degenerate_maps_give_no_fill_without_failing():
    empty = np.zeros((H, W), np.float32)
    dense, confidence, _ = run_method("mesh", _textured(), empty, CAMERA)
    assert not dense.any() and not confidence.any()
    line = np.zeros((H, W), np.float32)
    line[30, 10:70] = 1.5                                  # collinear: no triangle
    dense = run_method("mesh", _textured(), line, CAMERA)[0]
    assert np.all(dense[line > 0] == 1.5)


def test_bad_params_are_refused_in_one_line():
    sparse = _random_points(_plane())
    with pytest.raises(MethodError, match="mesh.*unknown param 'bogus'"):
        run_method("mesh", _textured(), sparse, CAMERA, {"bogus": 1})
    with pytest.raises(MethodError, match="max_jump_rel must be a finite number > 0"):
        run_method("mesh", _textured(), sparse, CAMERA, {"max_jump_rel": 0})
    with pytest.raises(ValueError, match="min_support must be <= neighbours"):
        MeshParams(min_support=20)


def test_a_region_bounded_by_two_surfaces_gets_neither_mean_nor_bridge():
    # A cast shadow: a uniform region whose outline is at 1.0 m on its left half and 1.6 m on
    # its right half (a near object's edge, a far wall's). The paper's method fills it with a
    # mean between the two; mesh fills no pixel between them.
    frame = np.full((H, W), 20, np.uint8)
    frame[8:52, 8:72] = 100
    inner = frame == 100
    outline = inner & ~np.pad(inner[1:-1, 1:-1] & inner[:-2, 1:-1] & inner[2:, 1:-1]
                              & inner[1:-1, :-2] & inner[1:-1, 2:], 1)
    depth = np.where(np.arange(W) < 40, 1.0, 1.6)[None, :].repeat(H, axis=0)
    sparse = np.where(outline, depth, 0).astype(np.float32)
    paper = run_method("paper-idw", frame, sparse, CAMERA)[0]
    between = lambda d: (d > 1.05) & (d < 1.55)           # noqa: E731
    assert between(paper[inner & (sparse == 0)]).mean() > 0.9
    result = mesh_fill(frame, sparse, CAMERA)
    assert not between(result.dense).any()
    filled = result.dense > 0
    left = np.arange(W)[None, :] < 40
    np.testing.assert_allclose(result.dense[filled & left], 1.0, rtol=1e-6)
    np.testing.assert_allclose(result.dense[filled & ~left], 1.6, rtol=1e-6)
    assert (result.dense[inner] == 0).sum() > H // 2         # a strip down the middle


# --- the compiled pieces, each against an independent computation ---------------------------

def test_the_triangulation_is_scipys_delaunay_on_points_in_general_position():
    from scipy.spatial import Delaunay

    points = np.random.default_rng(3).random((300, 2)) * [1.3, 0.9] - [0.6, 0.4]
    ours = _triangulation(points)
    theirs = Delaunay(points).simplices
    as_set = lambda t: {tuple(sorted(row)) for row in t.tolist()}      # noqa: E731
    assert as_set(ours) == as_set(theirs)
    assert _triangulation(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])) is None


def test_every_pixel_is_located_in_the_triangle_that_contains_it_through_the_lens():
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(4)
    pixels = np.unique(rng.integers([0, 0], [W, H], (150, 2)), axis=0)
    query = CAMERA.normalized_pixel_centres().reshape(-1, 2)
    points = query[pixels[:, 1] * W + pixels[:, 0]]
    triangles = Delaunay(points).simplices
    simplex, bary = _locate(points, triangles, pixels, query, (H, W),
                            np.ones(len(triangles), bool))
    expected = Delaunay(points).find_simplex(query)
    # Inside the mesh, every pixel is found; on an edge either triangle is right.
    inside = expected >= 0
    assert np.all(simplex[inside] >= 0) and np.all(simplex[~inside] < 0)
    corners = points[triangles[simplex[inside]]]                       # (n, 3, 2)
    np.testing.assert_allclose(np.einsum("nk,nkd->nd", bary[inside], corners), query[inside],
                               atol=1e-12)
    assert bary[inside].min() > -1e-9


def test_the_cubic_patches_reproduce_a_quadratic_from_its_values_and_slopes():
    rng = np.random.default_rng(5)
    points = rng.random((40, 2))
    quadratic = lambda p: 0.7 + 0.3 * p[:, 0] - 0.2 * p[:, 1] + 0.5 * p[:, 0] ** 2 \
        - 0.4 * p[:, 0] * p[:, 1] + 0.25 * p[:, 1] ** 2                  # noqa: E731
    x, y = points[:, 0], points[:, 1]
    slopes = np.stack([0.3 + x - 0.4 * y, -0.2 - 0.4 * x + 0.5 * y], axis=1)
    triangles = _triangulation(points)
    simplex = rng.integers(0, len(triangles), 500)
    bary = rng.dirichlet([1, 1, 1], 500)
    inside = np.einsum("nk,nkd->nd", bary, points[triangles[simplex]])
    values = _cubic_patch(points, quadratic(points), slopes, triangles, simplex, bary)
    np.testing.assert_allclose(values, quadratic(inside), atol=1e-12)


def test_the_vertex_slopes_of_a_plane_are_its_slopes_and_steps_are_ignored():
    rng = np.random.default_rng(6)
    points = rng.random((200, 2))
    values = 0.8 + 0.3 * points[:, 0] - 0.1 * points[:, 1]
    triangles = _triangulation(points)
    slopes = _vertex_slopes(points, values, triangles, 0.15, np.zeros((200, 2)))
    np.testing.assert_allclose(slopes, np.tile([0.3, -0.1], (200, 1)), atol=1e-6)
    # A second plane twice as far (half the inverse depth) to the right: no edge across the
    # step enters either side's slopes.
    right = points[:, 0] > 0.5
    stepped = np.where(right, 0.5 * values, values)
    slopes = _vertex_slopes(points, stepped, triangles, 0.15, np.zeros((200, 2)))
    np.testing.assert_allclose(slopes[~right], np.tile([0.3, -0.1], ((~right).sum(), 1)),
                               atol=1e-6)
    np.testing.assert_allclose(slopes[right], np.tile([0.15, -0.05], (right.sum(), 1)),
                               atol=1e-6)
