"""Depth errors on hand-made maps, discontinuity bands on steps, error images."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion import scoring
from fusion.scoring import depth_errors, discontinuity_band, error_image

GT = np.array([[1.0, 2.0, 4.0, 2.0]])
DEPTH = np.array([[1.1, 2.0, 5.0, 0.0]])               # errors 0.1, 0, 1.0 m; last not estimated


def test_depth_errors_by_hand():
    e = depth_errors(DEPTH, GT)
    assert e["n"] == 3
    assert e["mae_cm"] == pytest.approx(100 * 1.1 / 3)
    assert e["rmse_cm"] == pytest.approx(100 * math.sqrt((0.01 + 0 + 1.0) / 3))
    assert e["abs_rel"] == pytest.approx((0.1 / 1 + 0 + 1.0 / 4) / 3)
    assert e["imae_per_m"] == pytest.approx((abs(1 / 1.1 - 1) + 0 + abs(1 / 5 - 1 / 4)) / 3)
    # ratios 1.1, 1.0, 1.25: 1.25 is not < 1.25
    assert (e["delta_1.25"], e["delta_1.05"], e["delta_1.01"]) == pytest.approx((2 / 3, 1 / 3,
                                                                                  1 / 3))
    assert e["completeness"] == pytest.approx(3 / 4)


def test_mask_restricts_evaluation_and_completeness():
    mask = np.array([[True, False, False, True]])
    e = depth_errors(DEPTH, GT, mask)
    assert e["n"] == 1 and e["mae_cm"] == pytest.approx(10.0)
    assert e["completeness"] == pytest.approx(1 / 2)


def test_pixels_without_truth_are_not_evaluated():
    e = depth_errors(np.array([[1.0, 3.0]]), np.array([[1.0, 0.0]]))
    assert e["n"] == 1 and e["mae_cm"] == 0.0 and e["completeness"] == 1.0


def test_nothing_to_evaluate_gives_nan_not_an_error():
    e = depth_errors(np.zeros((2, 2)), np.ones((2, 2)))
    assert e["n"] == 0 and e["completeness"] == 0.0 and e["points"] == e["no_surface"] == 0
    counts = ("n", "completeness", "points", "no_surface")
    assert all(math.isnan(v) for k, v in e.items() if k not in counts)
    e = depth_errors(np.ones((2, 2)), np.zeros((2, 2)))
    assert e["n"] == 0 and math.isnan(e["completeness"])
    # four points in front of no surface: none is precise
    assert e["points"] == e["no_surface"] == 4 and e["precision_5pct"] == 0.0


def test_precision_by_hand():
    # errors 10 %, 0 %, 25 % where there is a surface; 3 % and 0.5 % are within 5 %, 1 %
    gt = np.array([[1.0, 2.0, 4.0, 2.0, 1.0, 2.0]])
    depth = np.array([[1.1, 2.0, 5.0, 0.0, 1.03, 2.01]])
    e = depth_errors(depth, gt)
    assert e["points"] == e["n"] == 5 and e["no_surface"] == 0
    assert e["precision_5pct"] == pytest.approx(3 / 5)        # 2.0, 1.03, 2.01
    assert e["precision_1pct"] == pytest.approx(2 / 5)        # 2.0, 2.01
    assert e["median_cm"] == pytest.approx(3.0)               # of 10, 0, 100, 3, 1 cm


def test_points_in_front_of_no_surface_lose_precision_not_accuracy():
    """The sky costs precision: MAE, n and completeness are measured where there is a surface."""
    gt = np.zeros((4, 6))
    gt[:, :3] = 2.0                                           # a wall on the left, sky on the right
    map_ = np.zeros((4, 6))
    map_[:, 0] = 2.0                                          # exact points on the wall
    map_[:, 1] = 2.03                                         # 1.5 % off: within 5 %, not 1 %
    clean = depth_errors(map_, gt)
    sky = map_.copy()
    sky[:, 4] = 3.0                                           # four points floating in the sky
    dirty = depth_errors(sky, gt)
    for key in ("n", "mae_cm", "rmse_cm", "median_cm", "completeness", "delta_1.01"):
        assert dirty[key] == clean[key], key
    assert clean["points"] == 8 and clean["no_surface"] == 0
    assert dirty["points"] == 12 and dirty["no_surface"] == 4
    assert clean["precision_5pct"] == 1.0 and clean["precision_1pct"] == pytest.approx(0.5)
    assert dirty["precision_5pct"] == pytest.approx(8 / 12)
    assert dirty["precision_1pct"] == pytest.approx(4 / 12)
    assert clean["completeness"] == pytest.approx(8 / 12)     # 2 of the wall's 3 columns


def test_precision_counts_only_the_points_of_the_mask():
    gt = np.array([[1.0, 0.0, 1.0, 0.0]])
    depth = np.array([[1.0, 1.0, 1.5, 1.0]])
    e = depth_errors(depth, gt, np.array([[True, True, False, False]]))
    assert (e["points"], e["no_surface"], e["n"]) == (2, 1, 1)
    assert e["precision_5pct"] == pytest.approx(1 / 2)


@pytest.mark.parametrize("depth, gt, mask, message", [
    (np.ones((2, 2)), np.ones((2, 3)), None, r"depth has shape \(2, 2\) but gt has shape"),
    (np.ones((2, 2)), np.ones((2, 2)), np.ones((3, 2), bool), "mask has shape"),
    (np.full((2, 2), np.nan), np.ones((2, 2)), None, "depth must be finite"),
    (np.ones((2, 2)), -np.ones((2, 2)), None, "gt must be >= 0"),
    (np.ones(4), np.ones(4), None, r"depth must be an \(H, W\) depth map"),
])
def test_bad_maps_are_refused(depth, gt, mask, message):
    with pytest.raises(ValueError, match=message):
        depth_errors(depth, gt, mask)


def test_discontinuity_band_of_a_step():
    gt = np.ones((10, 12))
    gt[:, 5:] = 2.0                                     # step between columns 4 and 5
    columns = np.zeros(12, bool)
    columns[1:9] = True                                 # 4 and 5, and 3 px either side
    np.testing.assert_array_equal(discontinuity_band(gt, width=3), np.tile(columns, (10, 1)))
    pair = np.zeros(12, bool)
    pair[4:6] = True
    np.testing.assert_array_equal(discontinuity_band(gt, width=0), np.tile(pair, (10, 1)))


def test_small_relative_steps_and_slanted_planes_are_not_discontinuities():
    gt = np.ones((6, 8))
    gt[:, 4:] = 1.04                                    # 4 % < 5 %
    assert not discontinuity_band(gt).any()
    assert discontinuity_band(gt, jump=0.03).any()
    slant = 1.0 + 0.02 * np.arange(8)[None, :].repeat(6, 0)
    assert not discontinuity_band(slant).any()


def test_silhouette_against_no_depth_is_a_discontinuity():
    gt = np.zeros((9, 9))
    gt[4, 4] = 3.0
    band = discontinuity_band(gt, width=1)
    expected = np.zeros((9, 9), bool)
    expected[2:7, 2:7] = True                           # the cross of pairs, dilated by 1
    expected[2, 2] = expected[2, 6] = expected[6, 2] = expected[6, 6] = False
    np.testing.assert_array_equal(band, expected)


def test_discontinuity_band_refuses_bad_parameters():
    with pytest.raises(ValueError, match="width must be"):
        discontinuity_band(np.ones((3, 3)), width=-1)
    with pytest.raises(ValueError, match="jump must be"):
        discontinuity_band(np.ones((3, 3)), jump=0.0)


def test_error_image_colours():
    depth = np.array([[1.0, 1.5, 0.0, 2.0]])
    gt = np.array([[1.0, 1.0, 1.0, 0.0]])
    image = error_image(depth, gt)
    assert image.shape == (1, 4, 3) and image.dtype == np.uint8
    assert (image[0, 2] == scoring.ERROR_NO_VALUE).all()        # no estimate: not an error
    assert (image[0, 3] == scoring.ERROR_NO_SURFACE).all()      # an estimate, no surface
    blue, _, red = image[0, 0].astype(int)              # no error: the cold end (BGR)
    assert blue > red
    blue, _, red = image[0, 1].astype(int)              # largest error: the hot end
    assert red > blue
    clipped = error_image(depth, gt, max_error=0.25)    # 0.5 m clipped to the hot end
    np.testing.assert_array_equal(clipped[0, 1], image[0, 1])
    with pytest.raises(ValueError, match="max_error must be"):
        error_image(depth, gt, max_error=0.0)
