"""Image-guided baselines (fusion.methods.baselines): guided filter, joint bilateral, colorization
and the
fast bilateral solver as filling methods, each against analytic cases on 80x60 frames (as
tests/test_methods.py)."""

from __future__ import annotations

import numpy as np
import pytest

import fusion.methods.baselines  # noqa: F401  (registers the baselines until fusion.methods imports it)
from fusion.methods import MethodError, available_methods, run_method
from fusion.methods.baselines import (
    BilateralParams,
    FastBilateralParams,
    GuidedParams,
    colorization_completion,
    colorization_weights,
    fast_bilateral_completion,
    fast_bilateral_solve,
    guided_filter,
)
from sim.camera import Camera

H, W = 60, 80
CAMERA = Camera(width=W, height=H, fx=70.0, fy=65.0, cx=39.5, cy=29.5)
BASELINES = ["guided", "bilateral", "colorization", "fbs"]
EDGE = W // 2                                          # first column of the bright half
V, U = np.mgrid[0:H, 0:W]


def _grid_points(depth: np.ndarray, step: int = 6) -> np.ndarray:
    sparse = np.zeros((H, W), np.float32)
    sparse[2::step, 3::step] = depth[2::step, 3::step]
    return sparse


def _two_regions() -> np.ndarray:
    """Two flat gray regions, dark left (60) and bright right (180), meeting at EDGE."""
    return np.where(U < EDGE, 60, 180).astype(np.uint8)


def _flat() -> np.ndarray:
    return np.full((H, W), 128, np.uint8)


def _step() -> np.ndarray:
    """1 m left of EDGE, 4 m from EDGE on: a depth step on the frame's edge."""
    return np.where(U < EDGE, 1.0, 4.0).astype(np.float32)


def _random_input(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 256, (H, W)).astype(np.uint8)
    sparse = np.where(rng.random((H, W)) < 0.05, rng.uniform(0.5, 5.0, (H, W)), 0)
    return frame, sparse.astype(np.float32)


def test_the_baselines_are_registered_by_name():
    methods = available_methods()
    for name in BASELINES:
        assert methods[name].origin == "built-in" and methods[name].summary


@pytest.mark.parametrize("name", BASELINES)
def test_a_constant_depth_stays_constant(name):
    frame = _two_regions()
    frame[:, EDGE - 1] = 0                              # with an outline, as test_methods' frame
    dense, confidence, _ = run_method(name, frame, _grid_points(np.full((H, W), 1.7)), CAMERA)
    assert dense.dtype == np.float32 and confidence is None
    assert dense.shape == (H, W)
    assert np.all(dense > 0)                            # points 6 px apart: all four fill it all
    np.testing.assert_allclose(dense, 1.7, rtol=1e-6)


@pytest.mark.parametrize("name", BASELINES)
def test_no_map_points_give_zeros(name):
    dense = run_method(name, _two_regions(), np.zeros((H, W), np.float32), CAMERA)[0]
    assert np.all(dense == 0)


@pytest.mark.parametrize("name", BASELINES)
def test_a_random_input_passes_the_checks_within_the_map_depths(name):
    """Noise as frame, 5 % of the pixels map points at 0.5-5 m: run_method's checks pass, map
    points keep their depth, and filled pixels stay within the map depths (a convex combination
    for bilateral, colorization and fbs; clamped for guided, whose weights can be negative)."""
    frame, sparse = _random_input()
    dense = run_method(name, frame, sparse, CAMERA)[0]
    points = sparse > 0
    np.testing.assert_array_equal(dense[points], sparse[points])
    filled = dense[dense > 0]
    assert filled.size > 0.9 * H * W
    assert filled.min() >= sparse[points].min() and filled.max() <= sparse[points].max()


@pytest.mark.parametrize("name", BASELINES)
def test_unknown_or_bad_parameters_are_refused_in_one_line(name):
    with pytest.raises(MethodError, match=f"filling method {name}: unknown parameter 'sigma'; "
                                          "expected "):
        run_method(name, _flat(), _grid_points(np.ones((H, W))), CAMERA, {"sigma": 1.0})
    key = {"colorization": "min_weight", "fbs": "lam"}.get(name, "radius")
    with pytest.raises(MethodError, match=f"raised ValueError: {key} must be "):
        run_method(name, _flat(), _grid_points(np.ones((H, W))), CAMERA, {key: 0})


def test_a_fractional_num_iter_is_refused():
    with pytest.raises(MethodError, match=r"raised ValueError: num_iter must be an integer >= 1, "
                                          r"got 2\.5"):
        run_method("fbs", _flat(), _grid_points(np.ones((H, W))), CAMERA, {"num_iter": 2.5})


def test_a_min_weight_of_one_is_refused():
    with pytest.raises(MethodError, match=r"min_weight must be in \(0, 1\), got 1"):
        run_method("colorization", _flat(), _grid_points(np.ones((H, W))), CAMERA,
                   {"min_weight": 1})


# --------------------------------------------------------------------------- depth step on an edge

@pytest.mark.parametrize("name, near, far", [("guided", 0.003, 0.0015), ("bilateral", 1e-6, 1e-6)])
def test_a_depth_step_on_the_frame_edge_stays_sharp(name, near, far):
    """Map points on both sides of a 1 m | 4 m step on the edge between two flat regions.

    Joint bilateral: the range weight across the edge is exp(-120^2 / 200) = 5e-32 and every
    pixel has map points of its own side in its window, so each side keeps its depth exactly.
    Guided filter: in a window straddling the edge the guide takes two values, and the linear
    model fitted to a two-valued guide gives each side the mean of its own side's samples, up
    to eps / var(I) (1e-4 against >= 0.0122 here): relative errors below 0.3 % within 2 px of
    the edge, 0.15 % beyond. On a flat frame the same points make a blurred step (> 50 %)."""
    truth = _step()
    sparse = _grid_points(truth)
    error = np.abs(run_method(name, _two_regions(), sparse, CAMERA)[0] / truth - 1)
    beyond = np.abs(U - (EDGE - 0.5)) > 2
    assert error[~beyond].max() < near and error[beyond].max() < far
    unguided = np.abs(run_method(name, _flat(), sparse, CAMERA)[0] / truth - 1)
    assert unguided.max() > 0.5


def test_colorization_keeps_each_side_of_the_frame_edge_at_its_own_depth():
    """The affinity across the edge is exp(-7.5) = 5.5e-4 of a same-side one (see
    test_colorization_weights_follow_the_authors_code): each side keeps its depth within 1.5 %
    (the leak is largest on the far side, next to the edge), and the depth crosses 2.5 m exactly
    at the edge; on a flat frame the step is smoothed (> 50 % off)."""
    truth = _step()
    sparse = _grid_points(truth)
    dense = run_method("colorization", _two_regions(), sparse, CAMERA)[0]
    assert np.abs(dense / truth - 1).max() < 0.015
    assert np.all(dense[:, EDGE - 1] < 2.5) and np.all(dense[:, EDGE] > 2.5)
    unguided = run_method("colorization", _flat(), sparse, CAMERA)[0]
    assert np.abs(unguided / truth - 1).max() > 0.5


# --------------------------------------------------------------------------- colorization

def test_colorization_weights_follow_the_authors_code():
    """At (30, EDGE - 1), left of the edge, the 3x3 window holds 6 pixels at Y1 = 60/255 and 3 at
    Y2 = 180/255: variance 2/9 dY^2, c = 0.6 of it, so a neighbour across the edge weighs
    exp(-dY^2 / c) = exp(-7.5) against 1 for the 5 on the same side. In a flat frame every
    weight is 1/8; at a corner, 1/3 for the 3 neighbours inside the image."""
    weights = colorization_weights(_two_regions())
    across = np.exp(-7.5)
    expected = np.array([1, 1, across, 1, across, 1, 1, across]) / (5 + 3 * across)
    np.testing.assert_allclose(weights[:, 30, EDGE - 1], expected, rtol=1e-12)
    flat = colorization_weights(_flat())
    np.testing.assert_allclose(flat[:, 30, 30], 1 / 8, rtol=1e-12)
    np.testing.assert_allclose(flat[:, 0, 0], [0, 0, 0, 0, 1 / 3, 0, 1 / 3, 1 / 3], rtol=1e-12)
    np.testing.assert_allclose(weights.sum(axis=0), 1.0, rtol=1e-12)


def test_colorization_reproduces_a_slanted_plane_in_inverse_depth():
    """A slanted plane: inverse depth 0.5 + 0.01 u + 0.004 v 1/m (depth 0.7-2 m), an affine
    function of the pixel, equal to its mean over any full 3x3 neighbourhood (the weights of a
    flat frame). With map points on a 6 px grid and on the image border, every unknown pixel
    has a full neighbourhood, so the plane is the exact solution: float32 rounding only.
    Colorizing depth instead (the same solve on 1 / depth, inverted back) misses it by 0.8 %.
    With the grid alone the border's truncated neighbourhoods bend it (10 % at the border):
    within 1.5 % from 8 px inside the border, 0.5 % from 12 px."""
    plane = 1.0 / (0.5 + 0.01 * U + 0.004 * V)
    outlined = np.zeros((H, W), bool)
    outlined[2::6, 3::6] = outlined[[0, -1], :] = outlined[:, [0, -1]] = True
    dense = colorization_completion(_flat(), np.where(outlined, plane, 0))
    np.testing.assert_allclose(dense, plane, rtol=2e-7)
    in_depth = 1.0 / colorization_completion(_flat(), np.where(outlined, 1.0 / plane, 0))
    assert np.abs(in_depth / plane - 1).max() > 0.005
    error = np.abs(colorization_completion(_flat(), _grid_points(plane)) / plane - 1)
    assert error[8:-8, 8:-8].max() < 0.015 and error[12:-12, 12:-12].max() < 0.005


# --------------------------------------------------------------------------- guided filter

def _clipped_box_mean(image: np.ndarray, radius: int) -> np.ndarray:
    """The mean over each (2r + 1)^2 window clipped to the image, by loops (a reference)."""
    out = np.empty(image.shape)
    for y in range(image.shape[0]):
        for x in range(image.shape[1]):
            out[y, x] = image[max(y - radius, 0):y + radius + 1,
                              max(x - radius, 0):x + radius + 1].mean()
    return out


def test_the_guided_filter_reduces_to_its_limits():
    """He et al.: with the source as its own guide and eps -> 0 the filter keeps the source
    (a = 1, b = 0 in every window with contrast, a = 0, b = p in flat ones); with eps -> inf
    a = 0 and b = mean(p), so q is the mean of the window means (windows clipped at the
    border)."""
    guide = _two_regions() / 255.0
    np.testing.assert_allclose(guided_filter(guide, guide, 3, 1e-12), guide, atol=1e-9)
    source = np.random.default_rng(1).random((H, W))
    twice = _clipped_box_mean(_clipped_box_mean(source, 2), 2)
    np.testing.assert_allclose(guided_filter(guide, source, 2, 1e12), twice, rtol=1e-9)
    stacked = guided_filter(guide, np.dstack([source, 2 * source]), 2, 1e-4)
    np.testing.assert_allclose(stacked[:, :, 1], 2 * guided_filter(guide, source, 2, 1e-4),
                               rtol=1e-12)


def test_guided_on_a_flat_frame_is_a_normalised_convolution():
    """A flat guide has no variance: a = 0, b = mean(p), so GF(p) is the mean of the window
    means, a positive kernel, and the method is the normalised convolution
    mean(mean(z m)) / mean(mean(m)) (no clamping involved): checked against loops on a noisy
    set of map depths."""
    _, sparse = _random_input(seed=5)
    mask = (sparse > 0).astype(float)
    expected = (_clipped_box_mean(_clipped_box_mean(sparse * mask, 8), 8)
                / _clipped_box_mean(_clipped_box_mean(mask, 8), 8))
    expected[mask > 0] = sparse[mask > 0]
    dense = run_method("guided", _flat(), sparse, CAMERA)[0]
    np.testing.assert_allclose(dense, expected, rtol=1e-6)


def test_guided_fills_within_two_radii_of_a_map_point():
    """One map point: the filtered mask is 0 where no window holds it, i.e. beyond Chebyshev
    distance 2r, and positive (above the floor) close to it."""
    sparse = np.zeros((H, W), np.float32)
    sparse[30, 40] = 2.0
    params = GuidedParams(radius=4)
    dense = run_method("guided", _flat(), sparse, CAMERA, {"radius": params.radius})[0]
    chebyshev = np.maximum(np.abs(V - 30), np.abs(U - 40))
    assert np.all(dense[chebyshev > 2 * params.radius] == 0)
    assert np.all(dense[chebyshev <= params.radius] == 2.0)


# --------------------------------------------------------------------------- joint bilateral

def test_bilateral_weights_two_points_by_distance_and_intensity():
    """Two map points on a flat frame, 1 m at (30, 36) and 3 m at (30, 44): at (30, 38) the
    weights are exp(-4 / 2 s^2) and exp(-36 / 2 s^2), s = 4 px. A frame edge at column 44
    multiplies the second by exp(-120^2 / 2 sigma_r^2). Pixels with neither point in their
    17x17 window stay 0."""
    sparse = np.zeros((H, W), np.float32)
    sparse[30, 36], sparse[30, 44] = 1.0, 3.0
    params = BilateralParams()
    w1, w2 = np.exp(-4 / 32), np.exp(-36 / 32)
    dense = run_method("bilateral", _flat(), sparse, CAMERA)[0]
    assert dense[30, 38] == pytest.approx((w1 + 3 * w2) / (w1 + w2), rel=1e-6)
    reach = np.zeros((H, W), bool)
    for x in (36, 44):
        reach |= np.maximum(np.abs(V - 30), np.abs(U - x)) <= params.radius
    assert np.all((dense > 0) == reach)
    frame = np.where(U < 44, 60, 180).astype(np.uint8)
    w2 *= np.exp(-120 ** 2 / (2 * params.sigma_r ** 2))
    dense = run_method("bilateral", frame, sparse, CAMERA)[0]
    assert dense[30, 38] == pytest.approx((w1 + 3 * w2) / (w1 + w2), rel=1e-6)


# --------------------------------------------------------------------------- fast bilateral solver

@pytest.mark.parametrize("edge", [EDGE, 36])
def test_fbs_keeps_a_depth_step_on_a_strong_frame_edge_exact(edge):
    """Grey levels 60 | 180 lie in luma bins 7 | 22 (sigma_luma 8): no grid vertex of one side
    neighbours one of the other (neighbours differ by 1 on one axis), so the grid falls apart
    into the two sides and each solves for its own constant depth, exactly, whether the edge
    is on a cell boundary (column 40) or inside a cell (36). On a flat frame the same points
    give a step smoothed over the whole frame (> 50 % off)."""
    frame = np.where(U < edge, 60, 180).astype(np.uint8)
    truth = np.where(U < edge, 1.0, 4.0).astype(np.float32)
    sparse = _grid_points(truth)
    np.testing.assert_array_equal(run_method("fbs", frame, sparse, CAMERA)[0], truth)
    unguided = np.abs(run_method("fbs", _flat(), sparse, CAMERA)[0] / truth - 1)
    assert unguided.max() > 0.5


def test_fbs_leaves_a_part_of_the_grid_without_map_points_empty():
    """A bright square (200) in a dark frame (60), map points only outside it: the square's
    vertices (luma bin 25) are not connected to the others (bin 7), so the solution there is
    undefined and the method returns 0; the dark part is filled."""
    frame = np.full((H, W), 60, np.uint8)
    square = (np.abs(U - 40) < 12) & (np.abs(V - 30) < 12)
    frame[square] = 200
    sparse = np.where(square, 0, _grid_points(np.full((H, W), 2.0))).astype(np.float32)
    dense = run_method("fbs", frame, sparse, CAMERA)[0]
    assert np.all(dense[square] == 0)
    np.testing.assert_array_equal(dense[~square], 2.0)


def test_fbs_needs_no_normalisation_where_the_confidence_is_zero():
    """A pixel of confidence 0 is out of the data term: its target is never read (NaN there
    changes nothing), and a constant target comes back constant with no division by a solved
    confidence (the smoothness term has zero row sums). With no confident pixel the solution is
    undefined everywhere (NaN)."""
    frame, sparse = _random_input(seed=4)
    confidence = np.where(sparse > 0, 0.2 + (sparse > 2), 0.0)    # 0.2 or 1.2 at the points
    target = np.where(sparse > 0, 1.0 / np.where(sparse > 0, sparse, 1.0), 0.0)
    solved = fast_bilateral_solve(frame, target, confidence)
    np.testing.assert_array_equal(
        fast_bilateral_solve(frame, np.where(sparse > 0, target, np.nan), confidence), solved)
    assert np.all(solved >= target[sparse > 0].min()) and np.all(solved <= target.max())
    constant = fast_bilateral_solve(frame, np.full((H, W), 0.37), confidence)
    np.testing.assert_allclose(constant, 0.37, rtol=1e-12)
    assert np.all(np.isnan(fast_bilateral_solve(frame, target, np.zeros((H, W)))))


def test_fbs_slices_a_constant_over_each_grid_cell():
    """On a flat frame every pixel of an 8x8 cell (rows and columns floor(. / 8)) lies on one
    vertex, so the solution is constant over it: a plane whose inverse depth rises by 0.002 1/m
    a column and 0.001 a row spans 7 * 0.003 over a cell, so no solution can come closer to it
    than half that, 0.0105 1/m, somewhere in the cell."""
    inverse = 0.5 + 0.002 * U + 0.001 * V
    points = _grid_points(np.ones((H, W))) > 0
    solved = fast_bilateral_solve(_flat(), np.where(points, inverse, 0.0), points * 1.0)
    cells = solved[:56].reshape(7, 8, 10, 8)                     # rows 56-59: a cell of 4 rows
    assert np.ptp(cells, axis=(1, 3)).max() == 0 and np.ptp(solved[56:], axis=0).max() == 0
    assert np.abs(solved - inverse).max() >= 3.5 * 0.003


@pytest.mark.parametrize("texture", ["flat", "noise"])
def test_fbs_fills_a_slanted_plane_within_derived_bounds(texture):
    """The plane of the previous test (inverse depth 0.5 + 0.002 u + 0.001 v 1/m), map points on
    a 6 px grid, on a flat frame and on noise of grey levels 100-155 (8 luma bins).

    Bounds derived, not measured:

    - Everywhere, any lam: the solver solves (C + lam L) x = C t with L a graph Laplacian
      (L 1 = 0) and C >= 0, so each vertex is a convex combination of the targets: every
      pixel's inverse depth lies within the map points' [min, max], here [0.508, 0.706] 1/m
      (points at (u, v) = (3, 2) and (75, 56)).
    - Flat frame, lam 0.01: every 8x8 cell holds a map point (points 6 px apart), its vertex
      takes its points' mean inverse depth, and a pixel and the points of its cell are at most
      7 columns and 7 rows apart: at most 7 * 0.003 = 0.021 1/m apart on the plane. The
      smoothness term moves a vertex from its data mean by at most lam times its 4 neighbour
      differences (a cell's step, 8 * 0.003 = 0.024, plus that spread: < 0.05 each) over a data
      weight of at least 1: 0.01 * 4 * 0.05 = 0.002 1/m. So |1/d - 1/z| <= 0.023 1/m, and the
      relative depth error |d / z - 1| = |1/z - 1/d| / (1/d) <= 0.023 / 0.508 < 0.046.

    (Measured with the defaults, lam 1, for the record only: at most 8.8 % / 9.0 % off at the
    corner (0, 0), where the smoothness term flattens the plane towards its mean; with lam 0.01
    on the flat frame 2.4 %.)"""
    inverse = 0.5 + 0.002 * U + 0.001 * V
    plane = 1.0 / inverse
    frame = (_flat() if texture == "flat"
             else np.random.default_rng(0).integers(100, 156, (H, W)).astype(np.uint8))
    points = _grid_points(plane)
    at_points = inverse[points > 0]
    assert (at_points.min(), at_points.max()) == pytest.approx((0.508, 0.706))
    default = run_method("fbs", frame, points, CAMERA)[0]                   # lam 1
    sharp = fast_bilateral_completion(frame, points, FastBilateralParams(lam=0.01))
    for dense in (default, sharp):
        assert np.all(dense > 0)
        assert np.all(1 / dense >= 0.508 * (1 - 1e-6)) and np.all(1 / dense <= 0.706 * (1 + 1e-6))
    if texture == "flat":
        assert np.abs(sharp / plane - 1).max() < 0.046
