"""Map filling: the paper's filling score, region selection, weightings and interpolation."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from fusion.cli import main
from fusion.fill.filling import (
    WEIGHTINGS,
    FillParams,
    SelectionParams,
    exponential_weights,
    fill_regions,
    filling_score,
    gaussian_weights,
    inverse_distance_weights,
    select_regions,
)
from fusion.fill.segmentation import SegmentationParams, segment_regions

RES_DAVIS = 240 * 180


# --------------------------------------------------------------------------- filling score

@pytest.mark.parametrize("sequence, n1, n2, beta", [
    ("boxes_6dof", 2289, 10489, 0.1898),
    ("dynamic_6dof", 2270, 9125, 0.1587),
    ("poster_6dof", 4748, 19338, 0.3377),
    ("shapes_6dof", 954, 2137, 0.0274),
])
def test_filling_score_reproduces_table_1(sequence, n1, n2, beta):
    """Every row of the paper's Table 1 (../shared/paper/README.md): its N1 and N2 at the
    DAVIS240C's 240 x 180 = 43,200 pixels give its beta to the 4 decimals it prints."""
    assert round(filling_score(n1, n2, RES_DAVIS), 4) == beta
    assert filling_score(n1, n2, RES_DAVIS) == pytest.approx((n2 - n1) / (43200 + n1 / 43200))


def test_filling_score_extremes_and_bad_counts():
    assert filling_score(100, 100, 1000) == 0.0
    assert filling_score(0, 1000, 1000) == 1.0
    with pytest.raises(ValueError, match="n1 <= n2"):
        filling_score(10, 5, 100)
    with pytest.raises(ValueError, match="res must be"):
        filling_score(1, 2, 0)


# --------------------------------------------------------------------------- weightings

def test_weightings_by_hand():
    d = np.array([0.0, 0.5, 1.0, 2.0, 4.0, 5.0])
    np.testing.assert_allclose(inverse_distance_weights(d), [1, 1, 1, 0.5, 0.25, 0.2])
    np.testing.assert_allclose(gaussian_weights(d, sigma=5.0),
                               np.exp(-np.array([0, 0.25, 1, 4, 16, 25]) / 50.0))
    assert gaussian_weights(5.0, sigma=5.0) == pytest.approx(np.exp(-0.5))
    np.testing.assert_allclose(exponential_weights(d, scale=5.0),
                               np.exp(-np.array([0, 0.1, 0.2, 0.4, 0.8, 1.0])))
    assert exponential_weights(5.0, scale=5.0) == pytest.approx(np.exp(-1.0))


def test_default_weightings_are_the_papers():
    """The paper: w = exp(-d) (d in px), Gaussian sigma = 5 px (its 1 / (sqrt(2 pi) sigma)
    cancels in the normalised mean)."""
    d = np.array([0.0, 0.5, 1.0, 2.0, 7.5])
    np.testing.assert_allclose(exponential_weights(d), np.exp(-d))
    np.testing.assert_allclose(gaussian_weights(d), np.exp(-d ** 2 / 50.0))
    assert (FillParams().weighting, FillParams().sigma, FillParams().scale) == ("idw", 5.0, 1.0)
    np.testing.assert_allclose(FillParams(weighting="exponential").weights()(d), np.exp(-d))


@pytest.mark.parametrize("name, length", [("idw", None), ("gaussian", 5.0), ("gaussian", 2.0),
                                          ("exponential", 1.0), ("exponential", 4.0)])
def test_each_weighting_knows_its_linear_and_log_forms(name, length):
    """The log form the filling falls back on where sums underflow is the log of the linear
    form, where that is representable, and finite beyond (d up to 2,000 px)."""
    weighting = WEIGHTINGS[name]
    d = np.array([0.0, 0.3, 1.0, 1.5, 7.0, 40.0])
    np.testing.assert_allclose(weighting.log_weights(d, length),
                               np.log(weighting.weights(d, length)), rtol=1e-12, atol=1e-12)
    far = np.array([[150.0, 800.0, 2000.0]])
    assert weighting.log_weights(far, length).shape == (1, 3)
    assert np.isfinite(weighting.log_weights(far, length)).all()
    params = FillParams(weighting=name, **({} if length is None else
                                           {weighting.parameter: length}))
    assert params.length == length
    np.testing.assert_array_equal(params.weights()(d), weighting.weights(d, length))


def test_fill_options_say_their_defaults_and_where_they_come_from(capsys):
    """Each of fill's options names its default, the same as the parameters' dataclasses (the
    one place defaults live), and whether it is the paper's or ours."""
    from fusion.cli import _parser
    from fusion.fill.segmentation import SegmentationParams

    with pytest.raises(SystemExit):
        main(["fill", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    fill = FillParams()
    selection = SelectionParams()
    expected = {"threshold": SegmentationParams().threshold, "ring": selection.ring,
                "min_ring_ratio": selection.min_ring_ratio,
                "max_inside_ratio": selection.max_inside_ratio,
                "weighting": fill.weighting, "sigma": fill.sigma, "scale": fill.scale,
                "min_region": SegmentationParams().min_region}
    for command in ("fill", "run"):
        sub = next(a for a in _parser()._actions if a.dest == "command").choices[command]
        actions = {a.dest: a for a in sub._actions}
        for dest, value in expected.items():
            action = actions[dest]
            # --weighting has no argparse default, so that a --method it contradicts can be
            # told from one left alone; its help still names the default (idw).
            assert action.default == (None if dest == "weighting" else value), (command, dest)
            assert "(default" in action.help and ("paper's" in action.help
                                                  or "ours" in action.help), (command, dest)
            shown = f"{value:g}" if isinstance(value, float) else str(value)
            if value is not None:
                assert f"default {shown}" in action.help.replace("0.30", "0.3"), (dest, shown)
    assert "(default 1, the paper's exp(-d))" in text


@pytest.mark.parametrize("weights", [inverse_distance_weights, gaussian_weights,
                                     exponential_weights])
def test_weightings_refuse_negative_or_nan_distances(weights):
    with pytest.raises(ValueError, match="distances must be finite and >= 0"):
        weights(np.array([1.0, -1.0]))
    with pytest.raises(ValueError, match="distances must be finite and >= 0"):
        weights(np.array([np.nan]))


def _one_pixel_between_two_points(width=4):
    """Pixel (0, 1) is region 1; map points at x = 0 (1 m, 1 px away) and x = 3 (2 m, 2 px)."""
    labels = np.zeros((1, width), np.int32)
    labels[0, 1] = 1
    sparse = np.zeros((1, width), np.float32)
    sparse[0, 0], sparse[0, 3] = 1.0, 2.0
    return labels, sparse


@pytest.mark.parametrize("weighting, expected", [
    ("idw", (1 * 1 + 0.5 * 2) / 1.5),
    ("gaussian", (np.exp(-1 / 50) * 1 + np.exp(-4 / 50) * 2) / (np.exp(-1 / 50)
                                                                  + np.exp(-4 / 50))),
    ("exponential", (np.exp(-1) * 1 + np.exp(-2) * 2) / (np.exp(-1) + np.exp(-2))),
])
def test_tiny_fill_matches_hand_computed_weighted_mean(weighting, expected):
    labels, sparse = _one_pixel_between_two_points()
    regions = select_regions(labels, sparse)
    assert regions.selected.tolist() == [False, True]
    dense = fill_regions(labels, sparse, regions, FillParams(weighting=weighting))
    assert dense.dtype == np.float32
    assert dense[0, 1] == pytest.approx(expected, rel=1e-6)
    np.testing.assert_array_equal(dense[0, [0, 2, 3]], [1.0, 0.0, 2.0])   # map points kept


def test_points_beyond_the_ring_are_not_used():
    labels, sparse = _one_pixel_between_two_points(width=8)
    sparse[0, 5] = 100.0                                # 4 px from the region: outside the ring
    dense = fill_regions(labels, sparse, select_regions(labels, sparse))
    assert dense[0, 1] == pytest.approx(4 / 3, rel=1e-6)
    assert dense[0, 5] == 100.0
    wide = select_regions(labels, sparse, SelectionParams(ring=4))
    assert wide.ring_events[1] == 3
    assert fill_regions(labels, sparse, wide)[0, 1] == pytest.approx(
        (1 * 1 + 0.5 * 2 + 0.25 * 100) / 1.75, rel=1e-6)


def test_points_inside_the_region_are_used_and_kept():
    labels = np.zeros((1, 30), np.int32)
    labels[0, 1:29] = 1                                 # area 28, contour 2 (x = 1 and x = 28)
    sparse = np.zeros((1, 30), np.float32)
    sparse[0, [0, 10, 29]] = [1.0, 2.0, 3.0]            # one inside: 1 < 5 % of 28 = 1.4
    regions = select_regions(labels, sparse)
    assert (regions.area[1], regions.contour[1], regions.ring_events[1],
            regions.inside_events[1], regions.selected[1]) == (28, 2, 2, 1, True)
    dense = fill_regions(labels, sparse, regions)
    x = np.arange(30.0)
    points, depths = np.array([0.0, 10.0, 29.0]), np.array([1.0, 2.0, 3.0])
    w = 1.0 / np.maximum(np.abs(x[:, None] - points[None]), 1.0)
    expected = (w * depths).sum(1) / w.sum(1)
    expected[[0, 10, 29]] = depths
    np.testing.assert_allclose(dense[0], expected, rtol=1e-6)


# --------------------------------------------------------------------------- planes

def _square_bounded_by_points(depth=1.7, size=10, pad=6):
    """Region 2, a size x size square in region 1, with every pixel of its 1-px ring a map point."""
    n = size + 2 * pad
    labels = np.ones((n, n), np.int32)
    labels[pad:pad + size, pad:pad + size] = 2
    sparse = np.zeros((n, n), np.float32)
    sparse[pad - 1:pad + size + 1, pad - 1:pad + size + 1] = depth
    sparse[pad:pad + size, pad:pad + size] = 0.0
    return labels, sparse, (slice(pad, pad + size), slice(pad, pad + size))


@pytest.mark.parametrize("weighting", WEIGHTINGS)
def test_fronto_parallel_plane_is_filled_with_its_depth(weighting):
    labels, sparse, square = _square_bounded_by_points()
    regions = select_regions(labels, sparse)
    assert regions.selected[2]
    dense = fill_regions(labels, sparse, regions, FillParams(weighting=weighting))
    assert (dense[square] == np.float32(1.7)).all()


def test_plane_from_a_frame_is_segmented_selected_and_filled():
    """End to end: a square of another gray level, map points on its outline at 2.5 m."""
    frame = np.full((40, 50), 80, np.uint8)
    frame[10:30, 15:40] = 160
    labels = segment_regions(frame)
    outline = cv2.dilate((labels == 2).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    outline &= labels != 2
    sparse = np.where(outline, 2.5, 0.0).astype(np.float32)
    regions = select_regions(labels, sparse)
    assert regions.selected[2]
    # The outside's contour (the image border is none) is the outline itself, every pixel of it
    # a map point in its band: by the paper's rule it is selected too. Fill the square alone.
    assert regions.selected[1] and regions.ring_events[1] >= regions.contour[1]
    dense = fill_regions(labels, sparse, replace(regions, selected=np.array([False, False, True])))
    assert (dense[10:30, 15:40] == 2.5).all()
    assert (dense[outline] == 2.5).all() and (dense[(labels == 1) & ~outline] == 0).all()
    n1, n2 = int((sparse > 0).sum()), int((dense > 0).sum())
    assert n2 - n1 == 20 * 25


def test_selection_rules_at_their_edges():
    """20 x 20 square: area 100, contour 76; ring rule '>=', inside rule '<'. With ring 3 the
    band covers the square's rows and columns 0-3 and 16-19: its inside is the 12 x 12 centre."""
    labels, sparse, square = _square_bounded_by_points(size=20)
    ring_pixels = np.argwhere(sparse > 0)
    params = SelectionParams(min_ring_ratio=0.5)                     # needs 38 of 76
    few = np.zeros_like(sparse)
    few[tuple(ring_pixels[:38].T)] = 1.7
    stats = select_regions(labels, few, params)
    assert (stats.area[2], stats.contour[2], stats.ring_events[2]) == (400, 76, 38)
    assert stats.selected[2]
    few[tuple(ring_pixels[37])] = 0.0
    assert not select_regions(labels, few, params).selected[2]
    inside = sparse.copy()
    centre = inside[square][4:16, 4:16]                              # a view: writes go through
    centre.flat[:19] = 1.7                                           # 19 < 5 % of 400
    inside[square][3, 10] = 1.7                                      # in the band: not inside
    stats = select_regions(labels, inside)
    assert stats.inside_events[2] == 19 and stats.ring_events[2] == 84 + 1
    assert stats.selected[2]
    centre.flat[19] = 1.7                                            # 20 is not < 20
    stats = select_regions(labels, inside)
    assert stats.inside_events[2] == 20 and not stats.selected[2]


def test_decimal_ratios_act_as_written():
    """0.07 x 100 is 7.000000000000001 in float64; 7 points out of 100 must be 7 %."""
    labels = np.ones((9, 110), np.int32)
    labels[4, 5:105] = 2                                # a line: area 100, contour 100
    sparse = np.zeros((9, 110), np.float32)
    sparse[3, 10:80:10] = 1.0                           # 7 points on its ring
    stats = select_regions(labels, sparse, SelectionParams(min_ring_ratio=0.07))
    assert (stats.area[2], stats.contour[2], stats.ring_events[2]) == (100, 100, 7)
    assert stats.selected[2]
    labels, sparse, square = _square_bounded_by_points(size=10)     # area 100; with ring 1 the
    sparse[square][2:8, 2:8].flat[:7] = 1.7                          # inside is the 6 x 6 centre
    stats = select_regions(labels, sparse, SelectionParams(ring=1, max_inside_ratio=0.07))
    assert stats.inside_events[2] == 7 and not stats.selected[2]     # 7 is not < 7 %


def test_region_with_too_few_ring_points_or_too_many_inside_is_not_filled():
    labels, sparse, square = _square_bounded_by_points(size=20)
    sparse_few = np.zeros_like(sparse)
    sparse_few[5, 5:27] = 1.7                                        # 22 of 76 < 30 %
    regions = select_regions(labels, sparse_few)
    assert regions.ring_events[2] == 22 and not regions.selected[2]
    np.testing.assert_array_equal(fill_regions(labels, sparse_few, regions)[square],
                                  sparse_few[square])
    crowded = sparse.copy()
    crowded[square][::2, ::2] = 1.7                                  # 36 of them off the band
    regions = select_regions(labels, crowded)
    assert regions.inside_events[2] == 36 and not regions.selected[2]   # 36 >= 5 % of 400
    np.testing.assert_array_equal(fill_regions(labels, crowded, regions)[square],
                                  crowded[square])


# --------------------------------------------------------------------------- the band

def _square_outline(n, top, size):
    """Pixels of the outline of the size x size square whose top-left pixel is (top, top)."""
    mask = np.zeros((n, n), bool)
    mask[top:top + size, top:top + size] = True
    mask[top + 1:top + size - 1, top + 1:top + size - 1] = False
    return mask


def _square_with_edge_points(size, offset, pad=8, depth=1.7):
    """Region 2, a size x size square in region 1, map points on its outline moved ``offset`` px
    outward (0: on its own contour pixels, -1: one pixel inside, +1: one pixel outside)."""
    n = size + 2 * pad
    labels = np.ones((n, n), np.int32)
    labels[pad:pad + size, pad:pad + size] = 2
    points = _square_outline(n, pad - offset, size + 2 * offset)
    return labels, np.where(points, depth, 0.0).astype(np.float32)


@pytest.mark.parametrize("side", ["on its contour", "one pixel outside", "half on each side"])
def test_30_px_square_is_selected_wherever_its_edge_points_land(side):
    """The paper counts the points in a 3-pixel ring because they land near the contour, on
    either side: 116 points on the square's own contour pixels, 124 one pixel outward, or every
    other one of each, all hold map points in the band and none inside."""
    if side == "on its contour":
        labels, sparse = _square_with_edge_points(30, 0)
    elif side == "one pixel outside":
        labels, sparse = _square_with_edge_points(30, +1)
    else:
        labels, on = _square_with_edge_points(30, 0)
        _, out = _square_with_edge_points(30, +1)
        parity = np.add.outer(np.arange(46), np.arange(46)) % 2
        sparse = np.where(parity == 0, on, out)
        assert 50 <= (on * (parity == 0) > 0).sum() <= 66            # about half on each side
        assert 50 <= (out * (parity == 1) > 0).sum() <= 66
    n_points = int((sparse > 0).sum())
    stats = select_regions(labels, sparse)
    assert (stats.area[2], stats.contour[2]) == (900, 116)
    assert stats.ring_events[2] == n_points and stats.inside_events[2] == 0
    assert stats.selected[2]
    dense = fill_regions(labels, sparse, replace(stats, selected=np.array([False, False, True])))
    assert (dense[8:38, 8:38] == np.float32(1.7)).all()             # a plane: filled exactly


@pytest.mark.parametrize("size", [10, 30, 60, 100])
@pytest.mark.parametrize("offset", [0, -1, -3])
def test_squares_with_edge_points_on_the_inside_side_are_selected(size, offset):
    """Edge points on the contour, one pixel in, or three (the band's inner edge): in the band,
    not inside, whatever the square's size."""
    labels, sparse = _square_with_edge_points(size, offset)
    stats = select_regions(labels, sparse)
    assert stats.ring_events[2] == (sparse > 0).sum() and stats.inside_events[2] == 0
    assert stats.selected[2]
    dense = fill_regions(labels, sparse, stats)
    assert (dense[8:8 + size, 8:8 + size] == np.float32(1.7)).all()


def test_band_is_ring_pixels_wide_on_the_inside():
    """A point ``ring`` px inside the contour is in the band; one more pixel in, it is inside."""
    labels, _ = _square_with_edge_points(30, 0)
    for ring in (1, 3, 5):
        for depth_in, in_band in ((ring, True), (ring + 1, False)):
            sparse = np.zeros(labels.shape, np.float32)
            sparse[8 + depth_in, 20] = 1.0                           # from the top edge, row 8
            stats = select_regions(labels, sparse, SelectionParams(ring=ring))
            assert (stats.ring_events[2], stats.inside_events[2]) == (int(in_band),
                                                                      int(not in_band))


def test_square_with_many_interior_points_is_still_rejected():
    """Edge points on the contour (selected alone), plus 64 points every 3 px off the band:
    64 >= 5 % of 900, textured, not one surface."""
    labels, sparse = _square_with_edge_points(30, 0)
    sparse[12:36:3, 12:36:3] = 2.0                         # rows/cols 12..33; the band ends at 11
    stats = select_regions(labels, sparse)
    assert stats.inside_events[2] == 64 and stats.ring_events[2] == 116
    assert not stats.selected[2]


def test_region_covering_the_image_is_never_selected():
    labels = np.ones((6, 6), np.int32)
    sparse = np.zeros((6, 6), np.float32)
    sparse[0, 0] = 1.0
    stats = select_regions(labels, sparse)
    assert stats.contour[1] == 0 and not stats.selected[1]


def test_fill_agrees_with_a_brute_force_reference():
    """Random regions and points against an independent NumPy implementation of the definitions:
    contour = region pixels with a 4-neighbour of another label in the image, band = its
    dilation by a (2 r + 1) square, inside = region off the band, weights over band and region."""
    rng = np.random.default_rng(4)
    frame = cv2.resize(rng.integers(0, 6, (6, 8)).astype(np.uint8) * 40, (48, 36),
                       interpolation=cv2.INTER_NEAREST)
    labels = segment_regions(frame, SegmentationParams(min_region=1))
    edges = cv2.Canny(frame, 10, 30) > 0
    edges = cv2.dilate(edges.astype(np.uint8), np.ones((2, 2), np.uint8)) > 0
    sparse = np.where(edges & (rng.random(edges.shape) < 0.7),
                      rng.uniform(1.0, 4.0, edges.shape), 0.0).astype(np.float32)
    sparse[rng.random(edges.shape) < 0.03] = 2.0                     # a few inside points
    params = SelectionParams(ring=1, min_ring_ratio=1.2, max_inside_ratio=0.02)  # 6x6 cells
    stats = select_regions(labels, sparse, params)
    assert 3 <= stats.selected.sum() <= stats.n_regions - 3       # some filled, some not
    assert (stats.inside_events[1:] > 0).sum() >= 3               # some with points inside
    dense = fill_regions(labels, sparse, stats, FillParams(weighting="exponential", scale=4.0))
    expected = sparse.astype(np.float64).copy()
    yy, xx = np.mgrid[:labels.shape[0], :labels.shape[1]]
    square = np.ones((3, 3), np.uint8)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    for lab in range(1, labels.max() + 1):
        region = (labels == lab).astype(np.uint8)
        contour = (region > 0) & (cv2.erode(region, cross, borderType=cv2.BORDER_REPLICATE) == 0)
        band = cv2.dilate(contour.astype(np.uint8), square) > 0
        assert stats.contour[lab] == contour.sum()
        assert stats.ring_events[lab] == (band & (sparse > 0)).sum()
        assert stats.inside_events[lab] == ((region > 0) & ~band & (sparse > 0)).sum()
        if not stats.selected[lab]:
            continue
        points = (band | (region > 0)) & (sparse > 0)
        py, px, pd = yy[points], xx[points], sparse[points].astype(np.float64)
        fill = (region > 0) & (sparse == 0)
        d = np.hypot(yy[fill][:, None] - py[None], xx[fill][:, None] - px[None])
        w = np.exp(-d / 4.0)
        expected[fill] = (w * pd).sum(1) / w.sum(1)
    np.testing.assert_allclose(dense, expected, rtol=1e-6)


def test_gaussian_weights_far_from_every_point_do_not_underflow():
    """Points at x = 0 (1 m) and x = 1 (2 m); pixel x is x and x - 1 px away, so its depth is
    (1 + 2 r) / (1 + r) = 2 - 1 / (1 + r), r = exp((2 x - 1) / 50): even where both weights,
    exp(-x^2 / 50), are 0.0 in float64 (x > ~190)."""
    labels = np.zeros((1, 300), np.int32)
    labels[0, 2:] = 1
    sparse = np.zeros((1, 300), np.float32)
    sparse[0, :2] = [1.0, 2.0]
    regions = select_regions(labels, sparse)
    dense = fill_regions(labels, sparse, regions, FillParams(weighting="gaussian", sigma=5.0))
    x = np.arange(2, 300)
    np.testing.assert_allclose(dense[0, 2:], 2.0 - 1.0 / (1.0 + np.exp((2 * x - 1) / 50.0)),
                               rtol=1e-6)
    assert gaussian_weights(299.0) == 0.0 and gaussian_weights(298.0) == 0.0


def test_exponential_weights_far_from_every_point_do_not_underflow():
    """Points at x = 0 (1 m) and x = 1 (2 m), the paper's exp(-d): pixel x >= 1 weighs them
    exp(-x) and exp(-(x - 1)), so its depth is (1 + 2 e) / (1 + e) at every x, even where both
    weights are 0.0 in float64 (x > ~745)."""
    labels = np.zeros((1, 1000), np.int32)
    labels[0, 2:] = 1
    sparse = np.zeros((1, 1000), np.float32)
    sparse[0, :2] = [1.0, 2.0]
    dense = fill_regions(labels, sparse, select_regions(labels, sparse),
                         FillParams(weighting="exponential"))
    np.testing.assert_allclose(dense[0, 2:], (1 + 2 * np.e) / (1 + np.e), rtol=1e-6)
    assert exponential_weights(999.0) == 0.0


# --------------------------------------------------------------------------- bad input

def test_frame_and_sparse_depth_of_different_sizes_are_refused():
    labels = segment_regions(np.zeros((10, 12), np.uint8))
    with pytest.raises(ValueError, match=r"sparse_depth has shape \(10, 13\) but the labels"):
        select_regions(labels, np.ones((10, 13), np.float32))


def test_empty_map_is_refused():
    labels, sparse, _ = _square_bounded_by_points()
    regions = select_regions(labels, sparse)
    with pytest.raises(ValueError, match="no map points"):
        select_regions(labels, np.zeros_like(sparse))
    with pytest.raises(ValueError, match="no map points"):
        fill_regions(labels, np.zeros_like(sparse), regions)


@pytest.mark.parametrize("value, message", [(np.nan, "NaN or infinite"),
                                            (np.inf, "NaN or infinite"),
                                            (-1.0, "negative")])
def test_bad_depths_are_refused(value, message):
    labels, sparse, _ = _square_bounded_by_points()
    regions = select_regions(labels, sparse)
    sparse[0, 0] = value
    with pytest.raises(ValueError, match=message):
        select_regions(labels, sparse)
    with pytest.raises(ValueError, match=message):
        fill_regions(labels, sparse, regions)


def test_statistics_of_other_labels_are_refused():
    labels, sparse, _ = _square_bounded_by_points()
    regions = select_regions(labels, sparse)
    more = labels.copy()
    more[0, 0] = 3
    with pytest.raises(ValueError, match="compute them with select_regions"):
        fill_regions(more, sparse, regions)
    chosen = replace(regions, selected=np.array([False, True, True]))  # a choice of one's own
    assert fill_regions(labels, sparse, chosen).min() > 0


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="weighting must be one of idw, gaussian, exponential"):
        FillParams(weighting="nearest")
    with pytest.raises(ValueError, match="sigma must be"):
        FillParams(sigma=0.0)
    with pytest.raises(ValueError, match="ring must be an integer >= 1"):
        SelectionParams(ring=0)
    with pytest.raises(ValueError, match="min_ring_ratio must be"):
        SelectionParams(min_ring_ratio=-0.1)
