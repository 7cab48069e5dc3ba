"""Region growing: flat patches, ramps, the threshold's edge, small regions and contours."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.fill.segmentation import (
    SegmentationParams,
    default_min_region,
    region_contours,
    segment_regions,
)

ALL = SegmentationParams(min_region=1)                 # keep every region


def test_flat_patches_separated_by_steps_come_back_exactly():
    frame = np.zeros((12, 16), np.uint8)
    frame[:6, :8] = 50
    frame[:6, 8:] = 60                                  # step of 10 > 3 gray levels
    frame[6:, :] = 40
    frame[8:11, 3:7] = 44                               # step of 4: one level past the threshold
    expected = np.zeros((12, 16), np.int32)
    expected[:6, :8] = 1                                # numbered by first pixel in raster order
    expected[:6, 8:] = 2
    expected[6:, :] = 3
    expected[8:11, 3:7] = 4
    np.testing.assert_array_equal(segment_regions(frame, ALL), expected)


def test_smooth_ramp_of_small_steps_is_one_region():
    """Neighbour to neighbour: 3-level steps chain into one region 45 levels from end to end."""
    ramp = np.tile(np.arange(16, dtype=np.uint8) * 3, (5, 1))
    assert (segment_regions(ramp, ALL) == 1).all()
    steep = np.tile(np.arange(16, dtype=np.uint8) * 4, (5, 1))
    np.testing.assert_array_equal(segment_regions(steep, ALL),
                                  np.tile(np.arange(1, 17, dtype=np.int32), (5, 1)))


def test_regions_join_only_through_4_neighbours():
    frame = np.array([[0, 100],
                      [100, 0]], np.uint8)              # diagonal pixels do not connect
    np.testing.assert_array_equal(segment_regions(frame, ALL), [[1, 2], [3, 4]])


def test_regions_below_min_region_are_labelled_zero_and_labels_stay_consecutive():
    frame = np.full((10, 10), 100, np.uint8)
    frame[2:4, 2:4] = 200                               # 4 pixels: below min_region = 5
    frame[6:9, 6:9] = 10                                # 9 pixels: kept
    labels = segment_regions(frame, SegmentationParams(min_region=5))
    assert (labels[2:4, 2:4] == 0).all()
    assert (labels[6:9, 6:9] == 2).all()
    background = np.ones((10, 10), bool)
    background[2:4, 2:4] = background[6:9, 6:9] = False
    assert (labels[background] == 1).all()
    assert labels.dtype == np.int32


def test_default_min_region_scales_with_resolution():
    assert default_min_region(180, 240) == 43           # 43200 // 1000
    assert default_min_region(480, 640) == 307
    assert default_min_region(10, 10) == 20             # floor of 20 pixels
    frame = np.zeros((180, 240), np.uint8)
    frame[10:16, 10:17] = 90                            # 42 pixels: one short of the default
    frame[50:56, 50:58] = 90                            # 48 pixels
    labels = segment_regions(frame)
    assert (labels[10:16, 10:17] == 0).all() and (labels[50:56, 50:58] == 2).all()


def test_float_frame_uses_the_threshold_in_its_own_units():
    ramp = np.tile(np.arange(16) * 3 / 255.0, (4, 1))
    assert (segment_regions(ramp, SegmentationParams(threshold=3.01 / 255, min_region=1))
            == 1).all()
    assert segment_regions(ramp, SegmentationParams(threshold=2.9 / 255, min_region=1)).max() == 16


def test_large_frame_is_segmented():
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 2, (480, 640)).astype(np.uint8) * 100   # salt: every pixel alone
    labels = segment_regions(frame, ALL)
    # Pixels of one level connect when 4-adjacent: count components independently with scipy.
    from scipy import ndimage
    n_expected = sum(ndimage.label(frame == level)[1] for level in (0, 100))
    assert labels.max() == n_expected
    assert labels.min() == 1


def test_contours_are_region_pixels_next_to_another_label_not_the_image_border():
    labels = np.ones((5, 5), np.int32)
    labels[1:4, 1:4] = 2
    contour = region_contours(labels)
    square = np.zeros((5, 5), bool)
    square[1:4, 1:4] = True
    square[2, 2] = False                                # centre of the square: not a contour
    np.testing.assert_array_equal(contour & (labels == 2), square)
    assert (contour & (labels == 1)).sum() == 12        # 3 on each side, no corner
    assert not contour[0, 0]
    labels[0, 0] = 0
    assert not region_contours(labels)[0, 0]            # label 0 is never a contour


@pytest.mark.parametrize("frame, message", [
    (np.zeros((4, 4, 3), np.uint8), r"\(H, W\) gray image"),
    (np.zeros((0, 4), np.uint8), r"\(H, W\) gray image"),
    (np.array([[1.0, np.nan]]), "finite"),
    (np.array([["a", "b"]]), "gray levels"),
])
def test_bad_frames_are_refused(frame, message):
    with pytest.raises(ValueError, match=message):
        segment_regions(frame)


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="threshold must be"):
        SegmentationParams(threshold=-1)
    with pytest.raises(ValueError, match="min_region must be"):
        SegmentationParams(min_region=0)
