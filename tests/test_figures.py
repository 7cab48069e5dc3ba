"""Figures: colour scales whose legends are the scales the panels used, and the panel grid."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.figures import (
    Legend,
    depth_colours,
    depth_legend,
    depth_range,
    error_legend,
    panel_grid,
    point_cloud_view,
)
from fusion.scoring import error_image


def test_depth_legend_runs_from_the_colour_of_lo_to_the_colour_of_hi():
    depth = np.array([[0.5, 1.0, 2.0, 0.0]])
    colours = depth_colours(depth, 0.5, 2.0)
    legend = depth_legend(0.5, 2.0)
    assert legend.colours.shape == (256, 3) and legend.colours.dtype == np.uint8
    np.testing.assert_array_equal(legend.colours[0], colours[0, 0])      # near: red end
    np.testing.assert_array_equal(legend.colours[-1], colours[0, 2])     # far: blue end
    near, far = legend.colours[0].astype(int), legend.colours[-1].astype(int)
    assert near[2] > near[0] + 100 and far[0] > far[2] + 100       # BGR: red, then blue
    assert (legend.low, legend.high) == ("0.5 m", "2 m")


def test_error_legend_is_the_scale_of_error_image():
    truth = np.ones((1, 3))
    image = error_image(truth + np.array([[0.0, 0.01, 0.02]]), truth, max_error=0.02)
    legend = error_legend(0.02)
    np.testing.assert_array_equal(legend.colours[0], image[0, 0])
    np.testing.assert_array_equal(legend.colours[-1], image[0, 2])
    assert (legend.low, legend.high) == ("0 cm", "2 cm")


def test_depth_range_ignores_the_outlying_percent_and_empty_maps():
    depth = np.zeros((10, 100))
    depth[0] = np.linspace(1.0, 2.0, 100)
    depth[1, 0] = 50.0                                    # one outlier of 101 valid pixels
    lo, hi = depth_range(depth)
    assert 1.0 <= lo < 1.05 and 1.95 < hi <= 2.0
    assert depth_range(np.zeros((3, 3))) == (None, None)


def test_panel_grid_draws_each_legend_under_its_panel_only():
    image = np.full((20, 40, 3), 128, np.uint8)
    red_to_blue = Legend(np.array([[0, 0, 255]] * 128 + [[255, 0, 0]] * 128, np.uint8),
                         "1 m", "2 m")
    plain = panel_grid([image, image], ["a", "b"], columns=2, scale=8)
    grid = panel_grid([image, image], ["a", "b"], columns=2, scale=8,
                      legends=[red_to_blue, None])
    assert plain.shape == (26 + 160, 640, 3)
    assert grid.shape == (26 + 160 + 22, 640, 3)
    np.testing.assert_array_equal(grid[:26 + 160], plain)
    strip = grid[26 + 160:]
    left, right = strip[:, :320], strip[:, 320:]
    assert (left == [0, 0, 255]).all(axis=2).sum() > 10 * 100       # the bar's red half
    assert (left == [255, 0, 0]).all(axis=2).sum() > 10 * 100       # and its blue half
    red_cols = np.flatnonzero((left == [0, 0, 255]).all(axis=2).any(axis=0))
    blue_cols = np.flatnonzero((left == [255, 0, 0]).all(axis=2).any(axis=0))
    assert red_cols.max() < blue_cols.min()                          # low end on the left
    assert (right == 255).all()                                      # no legend: blank
    with pytest.raises(ValueError, match="one title and one legend"):
        panel_grid([image], ["a"], legends=[None, None])


def test_point_cloud_view_puts_the_centre_in_the_middle_and_near_over_far():
    points = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    colours = np.array([[0, 0, 255]] * 3, np.uint8)
    image = point_cloud_view(points, colours, (64, 48), yaw_deg=0.0, pitch_deg=0.0)
    lit = np.argwhere(image.any(axis=2))
    assert len(lit) == 4 and np.abs(lit.mean(axis=0) - [23.5, 31.5]).max() <= 0.5
    # Two points on the view axis: the nearer one (blue) covers the farther one (green).
    points = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.5, 0.0, 1.5], [-0.5, 0.0, 1.5]])
    colours = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [0, 0, 255]], np.uint8)
    image = point_cloud_view(points, colours, (64, 48), yaw_deg=0.0, pitch_deg=0.0)
    assert (image == [255, 0, 0]).all(axis=2).any()
    assert not (image == [0, 255, 0]).all(axis=2).any()
