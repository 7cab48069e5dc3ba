"""The ``plane`` and ``hybrid`` filling methods (fusion.methods.surface_fit) on analytic cases.

Frames are flat gray patches (80x60): an 8-px border at gray 20 around an inner rectangle (rows
8-51, columns 8-71), so that region growing gives exactly two regions. Map points lie on the
rectangle's outline (its contour pixels, in the band of both regions) and a few inside it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import fusion.methods.surface_fit  # noqa: F401  (registers plane and hybrid; fusion.methods will import it)
from fusion.fill.segmentation import segment_regions
from fusion.methods import MethodError, run_method
from fusion.methods.surface_fit import HybridParams, SurfaceFitParams, hybrid_fill, surface_fill
from sim.camera import Camera

H, W = 60, 80
CAMERA = Camera(width=W, height=H, fx=70.0, fy=65.0, cx=39.5, cy=29.5)
TOP, BOTTOM, LEFT, RIGHT = 8, 51, 8, 71                  # the inner rectangle, inclusive
INSIDE = [(20, 24), (20, 56), (30, 40), (40, 24), (40, 56), (30, 20)]   # (row, column)


def _frame(inner: np.ndarray | int = 100) -> np.ndarray:
    frame = np.full((H, W), 20, np.uint8)
    frame[TOP:BOTTOM + 1, LEFT:RIGHT + 1] = inner
    return frame


def _outline() -> np.ndarray:
    """The inner rectangle's contour pixels."""
    mask = np.zeros((H, W), bool)
    mask[TOP:BOTTOM + 1, LEFT:RIGHT + 1] = True
    mask[TOP + 1:BOTTOM, LEFT + 1:RIGHT] = False
    return mask


def _points(truth: np.ndarray, inside=INSIDE) -> np.ndarray:
    sparse = np.where(_outline(), truth, 0).astype(np.float32)
    for row, col in inside:
        sparse[row, col] = truth[row, col]
    return sparse


def _inner() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[TOP:BOTTOM + 1, LEFT:RIGHT + 1] = True
    return mask


def _slanted_plane() -> np.ndarray:
    """Inverse depth affine in the pixel (so in the normalised coordinates of an undistorted
    camera): a plane, 0.8 m at the top left corner, 2.0 m at the bottom right one."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return 1.0 / (1.25 - 0.6 * u / (W - 1) - 0.15 * v / (H - 1))


def _relative_error(dense: np.ndarray, truth: np.ndarray, sparse: np.ndarray) -> np.ndarray:
    """|dense / truth - 1| on the filled pixels (map points excluded)."""
    filled = (dense > 0) & (sparse == 0)
    return np.abs(dense[filled] / truth[filled] - 1)


def test_the_frames_are_two_regions():
    labels = segment_regions(_frame())
    assert set(np.unique(labels)) == {1, 2} and np.all(labels[_inner()] == 2)


def test_a_slanted_plane_is_filled_with_the_plane_and_the_mean_is_not():
    truth = _slanted_plane()
    sparse = _points(truth)
    dense, confidence, _ = run_method("plane", _frame(), sparse, CAMERA)
    assert np.all(dense[_inner()] > 0)                  # the whole rectangle is filled
    assert np.all(dense[sparse > 0] == sparse[sparse > 0])
    assert _relative_error(dense, truth, sparse).max() < 1e-4
    filled = (dense > 0) & (sparse == 0)
    assert np.all(confidence[filled] == 1.0) and np.all(confidence[~filled] == 0)
    paper = run_method("paper-idw", _frame(), sparse, CAMERA)[0]
    assert np.all(paper[_inner()] > 0)                  # the paper fills the same pixels...
    assert _relative_error(paper, truth, sparse).max() > 0.05    # ... with its mean depths
    result = surface_fill(_frame(), sparse, CAMERA)
    assert {fit.model for fit in result.fits.values()} == {"plane"}


def test_a_quadric_in_inverse_depth_is_fitted_as_a_quadric():
    xy = CAMERA.normalized_pixel_centres()
    x, y = xy[..., 0], xy[..., 1]
    truth = 1.0 / (0.8 + 0.1 * x - 0.9 * x * x + 0.3 * x * y - 0.9 * y * y)   # 1.25 m to 3 m
    sparse = _points(truth)
    result = surface_fill(_frame(), sparse, CAMERA)
    inner = result.fits[2]
    assert inner.accepted and inner.model == "quadric"
    assert np.all(result.dense[_inner()] > 0)
    assert _relative_error(result.dense, truth, sparse).max() < 1e-3
    plane_only = surface_fill(_frame(), sparse, CAMERA,
                              SurfaceFitParams(quadric_min_points=10 ** 6))
    assert not plane_only.fits[2].accepted              # no plane explains these points


def test_a_plane_seen_through_a_distorting_lens_is_still_exact():
    camera = dataclasses.replace(CAMERA, distortion=(-0.25, 0.08, 1e-3, -5e-4, 0.0))
    normal, distance = np.array([0.3, -0.2, 1.0]), 1.2  # the plane n . X = d, metres
    xy = camera.normalized_pixel_centres()
    truth = distance / (xy @ normal[:2] + normal[2])
    # The truth is the plane: its points, projected with the lens model, land on their pixels.
    points = np.concatenate([xy, np.ones((H, W, 1))], axis=-1) * truth[..., None]
    np.testing.assert_allclose(points @ normal, distance, rtol=1e-12)
    v, u = np.mgrid[0:H, 0:W]
    np.testing.assert_allclose(camera.project(points.reshape(-1, 3)),
                               np.stack([u, v], -1).reshape(-1, 2), atol=1e-6)
    sparse = _points(truth)
    dense = run_method("plane", _frame(), sparse, camera)[0]
    assert np.all(dense[_inner()] > 0)
    assert _relative_error(dense, truth, sparse).max() < 1e-4
    # The lens matters: the same fit in distorted coordinates is off by more than 1e-4.
    ignored = dataclasses.replace(camera, distortion=(0.0,) * 5)
    naive = run_method("plane", _frame(), sparse, ignored)[0]
    assert _relative_error(naive, truth, sparse).max() > 1e-3


def test_a_fifth_of_wrong_depths_leaves_the_plane_exact():
    truth = _slanted_plane()
    sparse = _points(truth)
    rng = np.random.default_rng(3)
    rows, cols = np.nonzero(sparse)
    wrong = rng.choice(len(rows), size=len(rows) // 5, replace=False)
    factors = np.where(rng.random(len(wrong)) < 0.5, rng.uniform(0.5, 0.8, len(wrong)),
                       rng.uniform(1.25, 2.0, len(wrong)))
    sparse[rows[wrong], cols[wrong]] *= factors.astype(np.float32)
    result = surface_fill(_frame(), sparse, CAMERA)
    assert np.all(result.dense[_inner()] > 0)
    assert _relative_error(result.dense, truth, sparse).max() < 1e-3
    inner = result.fits[2]
    assert inner.accepted and 0.7 < inner.inlier_share < 0.85
    filled = (result.dense > 0) & (sparse == 0) & _inner()
    assert np.all(result.confidence[filled] == np.float32(inner.inlier_share))


def _two_depths() -> np.ndarray:
    """A wall at 2 m on the right and a nearer surface at 1 m on the left (columns < 40)."""
    return np.where(np.arange(W)[None, :] < 40, 1.0, 2.0).repeat(H, axis=0)


def test_a_shadow_bounded_by_two_surfaces_is_left_empty_where_the_mean_fills_it():
    truth = _two_depths()
    sparse = _points(truth)
    dense = run_method("plane", _frame(), sparse, CAMERA)[0]
    assert not np.any(dense[sparse == 0])               # neither region is filled
    result = surface_fill(_frame(), sparse, CAMERA)
    assert all(not fit.accepted and fit.reason.startswith("inlier share")
               for fit in result.fits.values())
    paper = run_method("paper-idw", _frame(), sparse, CAMERA)[0]
    assert np.all(paper[_inner()] > 0)
    assert np.abs(paper[_inner()] - truth[_inner()]).max() > 0.3
    hybrid = run_method("hybrid", _frame(), sparse, CAMERA)[0]  # no frame edge inside it
    assert not np.any(hybrid[sparse == 0])


def _ramp_frame() -> np.ndarray:
    """The inner rectangle at gray 100 on the left, 130 on the right, joined by a ramp of
    3 levels a pixel (columns 36-45): region growing (threshold 3) merges the two halves,
    Canny finds the ramp (an edge along column 36)."""
    inner = np.full((BOTTOM - TOP + 1, RIGHT - LEFT + 1), 100, np.uint8)
    for i, col in enumerate(range(36, 46)):
        inner[:, col - LEFT] = 103 + 3 * i
    inner[:, 46 - LEFT:] = 130
    return _frame(inner)


def test_hybrid_fills_the_two_halves_of_a_region_split_by_a_frame_edge():
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    near = 1.0 / (1.0 + 0.003 * u - 0.002 * v)          # a plane about 1 m away, left
    far = 1.0 / (0.5 - 0.002 * u + 0.001 * v)           # a plane about 2.5 m away, right
    truth = np.where(u < 36, near, far)
    sparse = _points(truth, inside=[])
    sparse[:, 36] = 0                                   # no point on the ramp's first column
    sparse[TOP + 4:BOTTOM - 3:2, 34] = near[TOP + 4:BOTTOM - 3:2, 34]   # both sides of it
    sparse[TOP + 4:BOTTOM - 3:2, 38] = far[TOP + 4:BOTTOM - 3:2, 38]
    frame = _ramp_frame()
    assert np.all(segment_regions(frame)[_inner()] == 2)         # one region
    plane = surface_fill(frame, sparse, CAMERA)
    assert not plane.fits[2].accepted and not np.any(plane.dense[_inner() & (sparse == 0)])
    hybrid = hybrid_fill(frame, sparse, CAMERA)
    assert sorted(hybrid.piece_parent.values()) == [2, 2]
    assert all(fit.accepted and fit.model == "plane" for fit in hybrid.piece_fits.values())
    filled = (hybrid.dense > 0) & (sparse == 0) & _inner()
    empty = _inner() & (hybrid.dense == 0)
    assert np.all(u[empty] == 36)                        # only the edge's column stays empty
    left, right = filled & (u < 36), filled & (u > 36)
    assert left.sum() > 1000 and right.sum() > 1000
    np.testing.assert_allclose(hybrid.dense[left], near[left], rtol=1e-4)
    np.testing.assert_allclose(hybrid.dense[right], far[right], rtol=1e-4)
    dense, confidence, _ = run_method("hybrid", frame, sparse, CAMERA)
    np.testing.assert_array_equal(dense, hybrid.dense)
    assert np.all((confidence[filled] > 0.7) & (confidence[filled] <= 1))


@pytest.mark.parametrize("name", ["plane", "hybrid"])
def test_the_same_input_gives_the_same_output(name):
    truth = _slanted_plane()
    sparse = _points(truth)
    rng = np.random.default_rng(5)
    rows, cols = np.nonzero(sparse)
    # Noise of the order of the inlier threshold: which points are inliers, hence the fitted
    # depths, depend on the random samples drawn (another seed gives other depths).
    sparse[rows, cols] *= (1 + rng.normal(0, 0.012, len(rows))).astype(np.float32)
    wrong = rng.choice(len(rows), size=len(rows) // 8, replace=False)
    sparse[rows[wrong], cols[wrong]] *= np.float32(1.5)
    first = run_method(name, _ramp_frame(), sparse, CAMERA)
    second = run_method(name, _ramp_frame(), sparse.copy(), CAMERA)
    assert np.all(first[0][_inner()] > 0)
    assert np.array_equal(first[0], second[0]) and np.array_equal(first[1], second[1])
    other_seed = run_method(name, _ramp_frame(), sparse, CAMERA, {"seed": 1})
    assert not np.array_equal(first[0], other_seed[0])


def test_parameters_are_overridden_by_name():
    truth = _slanted_plane()
    sparse = _points(truth)
    # Neighbouring points alternately 3 % too near and too far: no plane is within 2 % (the
    # default) of two neighbours, the true one is within 3 % of all.
    rows, cols = np.nonzero(sparse)
    sparse[rows, cols] *= np.where((rows + cols) % 2 == 0, 1.03, 0.97).astype(np.float32)
    strict = run_method("plane", _frame(), sparse, CAMERA)[0]
    loose = run_method("plane", _frame(), sparse, CAMERA, {"residual_rel": 0.05})[0]
    assert not np.any(strict[_inner() & (sparse == 0)])
    assert np.all(loose[_inner()] > 0)
    assert HybridParams.from_params({"canny_low": 5}, "hybrid").canny_low == 5


@pytest.mark.parametrize("name, params, message", [
    ("plane", {"threshold": 3}, "filling method plane: unknown param 'threshold'; expected one of"),
    ("plane", {"residual_rel": -1}, "param residual_rel must be a finite number > 0, got -1"),
    ("hybrid", {"canny_low": 50, "canny_high": 10}, "param canny_low must be <= canny_high"),
    ("plane", {"canny_low": 5}, "unknown param 'canny_low'"),
    ("hybrid", {"min_points": 2.5}, "param min_points must be an integer >= 3, got 2.5"),
])
def test_a_bad_parameter_is_named_in_one_line(name, params, message):
    with pytest.raises(MethodError) as info:
        run_method(name, _frame(), _points(_slanted_plane()), CAMERA, params)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_no_map_point_fills_nothing():
    dense, confidence, _ = run_method("hybrid", _frame(), np.zeros((H, W), np.float32), CAMERA)
    assert not dense.any() and not confidence.any()
