"""Figures: colour scales whose legends are the scales the panels used, and the panel grid."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fusion.figures import (
    AXIS_COLOURS,
    Caption,
    Legend,
    add_header,
    depth_colours,
    depth_legend,
    depth_scale,
    error_legend,
    error_panel,
    fill_figure_panels,
    panel_grid,
    point_cloud_view,
)
from fusion.fill.dense import DenseParams, fill_frame, write_fill
from fusion.scoring import ERROR_NO_SURFACE, ERROR_NO_VALUE, error_image
from sim.camera import Camera


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


def test_depth_scale_spans_the_exact_depth_and_marks_what_it_clips():
    estimate = np.zeros((10, 100))
    estimate[0] = np.linspace(1.0, 1.2, 100)              # the map found 1.0-1.2 m
    truth = np.zeros((10, 100))
    truth[:5] = np.linspace(0.8, 1.73, 100)               # the scene reaches 1.73 m
    scale = depth_scale(estimate, truth=truth)             # the scene's scale, not the map's
    assert (scale.lo, scale.hi, scale.below, scale.above) == (0.8, 1.73, False, False)
    assert scale.source == "exact depth"
    estimate[1, 0] = 2.5                                  # an outlier beyond the scene: clipped,
    estimate[1, 1] = 0.3                                  # and one in front of it, and said so
    scale = depth_scale(None, estimate, truth=truth)
    assert (scale.lo, scale.hi, scale.below, scale.above) == (0.8, 1.73, True, True)
    assert (scale.legend().low, scale.legend().high) == ("< 0.8 m", "> 1.73 m")
    # without truth: the maps' 1st-99th percentile, so one outlier does not flatten the panels
    maps_only = depth_scale(estimate)
    assert maps_only.source.startswith("maps") and maps_only.above and maps_only.below
    assert 0.99 < maps_only.lo < 1.01 and 1.19 < maps_only.hi < 1.21
    # a flat scene (the slider's poster at 0.231 m) still gets a span of 10 % of its depth
    flat = depth_scale(np.full((3, 3), 0.2), truth=np.full((3, 3), 0.231))
    assert (round(flat.lo, 6), round(flat.hi, 6)) == (0.21945, 0.24255) and flat.below
    assert depth_scale(np.zeros((3, 3))) is None and depth_scale(None) is None


def _plane_frame(truth_far: float):
    """A square bounded by map points at 2 m on a 40x30 frame, and an exact depth of 2 m with a
    far strip at ``truth_far`` metres and a column of sky (0) under one of the map points."""
    frame = np.full((30, 40), 100, np.uint8)
    frame[10:20, 14:26] = 160
    sparse = np.zeros((30, 40), np.float32)
    sparse[9, 13:27] = sparse[20, 13:27] = 2.0
    sparse[9:21, 13] = sparse[9:21, 26] = 2.0
    truth = np.full((30, 40), 2.0, np.float32)
    truth[:, 30:] = truth_far
    truth[:, 13] = 0.0                                     # no surface under map points
    return fill_frame(frame, sparse, Camera(40, 30, 35.0, 30.0, 19.5, 14.5), DenseParams(),
                      truth=truth)


def test_figure_2_depth_scale_covers_the_exact_depth_beyond_the_maps():
    result = _plane_frame(truth_far=3.5)
    assert result.dense.max() == 2.0                      # the maps hold 2 m only
    panels, titles, legends, header = fill_figure_panels(result, DenseParams())
    assert (legends[0].low, legends[0].high) == ("2 m", "3.5 m")
    assert legends[4] is legends[0]                        # (a) and (e) share it
    assert titles[0] == f"(a) frame + {np.count_nonzero(result.sparse)} projected map points"
    assert isinstance(legends[5], Caption) and "deg left" in legends[5].text
    assert header == []
    oracle = fill_frame(result.frame, result.sparse, result.camera, DenseParams(),
                        truth=result.truth, info={"oracle": True})
    assert "oracle" in fill_figure_panels(oracle, DenseParams())[3][0]


def test_no_error_colour_is_taken_by_no_value_or_no_surface():
    turbo = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None], cv2.COLORMAP_TURBO)[0]
    for colour in (ERROR_NO_VALUE, ERROR_NO_SURFACE):
        distance = np.linalg.norm(turbo.astype(float) - colour, axis=1)
        assert distance.min() > 100, colour               # far from every level, not only unequal
    # turbo's cold end is nearly black: black must not mean "no value"
    assert np.linalg.norm(turbo[0].astype(float)) < 100
    depth = np.array([[1.0, 1.5, 0.0, 2.0, 0.0]])
    gt = np.array([[1.0, 1.0, 1.0, 0.0, 0.0]])
    image = error_image(depth, gt)
    assert tuple(image[0, 2]) == ERROR_NO_VALUE           # no estimate
    assert tuple(image[0, 4]) == ERROR_NO_VALUE           # neither estimate nor surface
    assert tuple(image[0, 3]) == ERROR_NO_SURFACE         # an estimate where there is nothing


def test_error_panel_scale_ends_at_the_99th_percentile_and_says_so():
    truth = np.ones((1, 200))
    depth = truth + np.r_[np.linspace(0.0, 0.02, 199), 1.0][None, :]   # one 1-m outlier
    image, legend = error_panel(depth, truth)
    top = np.percentile(np.abs(depth - truth), 99)
    assert legend.high == f">= {100 * top:.3g} cm" and legend.low == "0 cm"
    np.testing.assert_array_equal(image[0, -1], legend.colours[-1])     # the outlier: last colour
    assert [name for name, _ in legend.keys] == ["no value", "no surface"]
    assert dict(legend.keys) == {"no value": ERROR_NO_VALUE, "no surface": ERROR_NO_SURFACE}
    exact = error_panel(truth, truth)[1]                  # nothing clipped: no ">="
    assert not exact.high.startswith(">=")


def test_error_png_has_its_legend_and_shows_no_value_and_no_surface(tmp_path):
    result = _plane_frame(truth_far=2.0)
    result.dense[:3, :3] = 0.0                             # a corner left unfilled: no value
    write_fill(result, tmp_path / "fill", DenseParams())
    image = cv2.imread(str(tmp_path / "fill" / "error.png"))
    assert image.shape[0] > result.dense.shape[0] and image.shape[1] >= 320
    panel, legend = error_panel(result.dense, result.truth)
    expected = panel_grid([panel], ["x"], columns=1, legends=[legend])
    strip = image[-22:]                                    # the legend line, drawn
    np.testing.assert_array_equal(strip, expected[-22:])
    assert (strip == ERROR_NO_VALUE).all(axis=2).sum() >= 64          # its two swatches
    assert (strip == ERROR_NO_SURFACE).all(axis=2).sum() >= 64
    tile = image[26:-22]
    assert (tile == ERROR_NO_SURFACE).all(axis=2).any()   # map points over the sky column
    assert (tile == ERROR_NO_VALUE).all(axis=2).any()     # pixels not filled
    assert not (tile == 0).all(axis=2).any()              # nothing black


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
    image, _ = point_cloud_view(points, colours, (64, 48), left_deg=0.0, above_deg=0.0,
                                axes=False)
    lit = np.argwhere(image.any(axis=2))
    assert len(lit) == 4 and np.abs(lit.mean(axis=0) - [23.5, 31.5]).max() <= 0.5
    # Two points on the view axis: the nearer one (blue) covers the farther one (green).
    points = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.5, 0.0, 1.5], [-0.5, 0.0, 1.5]])
    colours = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [0, 0, 255]], np.uint8)
    image, _ = point_cloud_view(points, colours, (64, 48), left_deg=0.0, above_deg=0.0,
                                axes=False)
    assert (image == [255, 0, 0]).all(axis=2).any()
    assert not (image == [0, 255, 0]).all(axis=2).any()


def _axis_points(marked: int):
    """Six points 0.3 m along +-x, +-y, +-z around (0, 0, 2) (index 0-2: +x, +y, +z; 3-5: the
    minus ones), all red but ``marked`` blue and its opposite green."""
    points = np.vstack([0.3 * np.eye(3), -0.3 * np.eye(3)]) + [0.0, 0.0, 2.0]
    colours = np.full((6, 3), [0, 0, 255], np.uint8)
    colours[marked] = [255, 0, 0]
    colours[(marked + 3) % 6] = [0, 255, 0]
    return points, colours


def _pixel_of(image, colour):
    return np.argwhere((image == colour).all(axis=2)).mean(axis=0)[::-1]     # (u, v)


def test_point_cloud_view_from_the_left_sees_forward_on_its_left_and_up_above():
    # From 90 deg left, level, looking along +x (y down): +z is on the viewer's left, -y up.
    size = (160, 120)
    centre = np.array([size[0] / 2, size[1] / 2])
    for marked, (du_sign, dv_sign) in ((2, (-1, 0)), (5, (1, 0)), (4, (0, -1)), (1, (0, 1))):
        image, _ = point_cloud_view(*_axis_points(marked), size, left_deg=90.0, above_deg=0.0,
                                    axes=False)
        du, dv = _pixel_of(image, [255, 0, 0]) - centre
        for d, sign in ((du, du_sign), (dv, dv_sign)):
            assert (d < -10) if sign < 0 else (d > 10) if sign > 0 else abs(d) < 3, marked


def test_point_cloud_view_draws_each_axis_on_the_side_of_points_along_it():
    # The median is (0, 0, 2), the spread 0.3 m, the axes 20 cm (the round length below the
    # spread).
    size = (200, 150)
    for axis in range(3):
        points, colours = _axis_points(axis)
        image, caption = point_cloud_view(points, colours, size)
        assert caption.text == "seen from 30 deg left, 20 deg above the camera; axes 20 cm"
        plain, _ = point_cloud_view(points, colours, size, axes=False)
        plus, minus = _pixel_of(plain, [255, 0, 0]), _pixel_of(plain, [0, 255, 0])
        arrow = (image == AXIS_COLOURS[axis]).all(axis=2) & ~(image == plain).all(axis=2)
        assert arrow.sum() >= 5, "xyz"[axis]
        tip = np.argwhere(arrow).mean(axis=0)[::-1] - 0.5 * (plus + minus)
        assert np.dot(plus - minus, tip) > 0, "xyz"[axis]
    _, caption = point_cloud_view(points, colours, size, left_deg=-15.0, above_deg=-5.0)
    assert caption.text.startswith("seen from 15 deg right, 5 deg below the camera")


def test_add_header_puts_lines_above_and_leaves_the_image_as_it_is():
    image = np.full((30, 400, 3), 90, np.uint8)
    assert add_header(image, []) is image
    out = add_header(image, ["DSI depth range from the exact depth (oracle)"])
    assert out.shape == (24 + 30, 400, 3)
    np.testing.assert_array_equal(out[24:], image)
    assert (out[:24] != 255).any()                          # the text is drawn


def _contrast(bgr_a, bgr_b) -> float:
    """WCAG 2.1 contrast ratio of two sRGB colours (given BGR): 3 is its minimum for graphics."""
    def luminance(bgr):
        c = np.asarray(bgr, np.float64) / 255
        c = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        return 0.0722 * c[..., 0] + 0.7152 * c[..., 1] + 0.2126 * c[..., 2]
    a, b = luminance(bgr_a), luminance(bgr_b)
    return (np.maximum(a, b) + 0.05) / (np.minimum(a, b) + 0.05)


def test_depth_beyond_the_scale_is_drawn_in_a_colour_the_scale_does_not_use():
    # dynamic_6dof's map: points on the DSI's first and last planes (0.5 m, 5 m) drawn on the
    # scale of the exact depth (0.8-1.73 m) must not take the colours of 0.8 m and 1.73 m
    truth = np.zeros((4, 50))
    truth[:2] = np.linspace(0.8, 1.73, 50)
    estimate = np.zeros((4, 50))
    estimate[2, :3] = (1.0, 0.5, 5.0)
    scale = depth_scale(estimate, truth=truth)
    image = depth_colours(estimate, scale.lo, scale.hi)
    legend = scale.legend()
    ramp = legend.colours.astype(float)
    for u in (1, 2):                                      # 0.5 m and 5 m
        distance = np.linalg.norm(ramp - image[2, u].astype(float), axis=1)
        assert distance.min() > 100, (u, image[2, u])     # no colour of the scale
    assert tuple(image[2, 1]) != tuple(image[2, 2])       # nearer and farther told apart
    assert np.linalg.norm(ramp - image[2, 0].astype(float), axis=1).min() < 10   # 1 m: on it
    # the legend shows both colours, at the ends of its bar, and says what they are
    assert (legend.low, legend.high) == ("< 0.8 m", "> 1.73 m")
    assert tuple(legend.under) == tuple(image[2, 1]) and tuple(legend.over) == tuple(image[2, 2])
    grid = panel_grid([image], ["map"], columns=1, legends=[legend], scale=8)
    strip = grid[-22:]
    for colour in (legend.under, legend.over):
        assert (strip == colour).all(axis=2).sum() >= 20, colour
    inside = depth_scale(np.full((2, 2), 1.2), truth=truth).legend()   # nothing beyond
    assert inside.under is None and inside.over is None and inside.low == "0.8 m"


def test_every_depth_colour_stands_out_from_the_no_value_grey():
    # far map points on the dark "no value" background must be visible: WCAG's 3:1 for
    # graphics against it, for every colour of the scale and for the two beyond it
    no_value = depth_colours(np.zeros((1, 1)))[0, 0]
    legend = depth_legend(0.5, 2.0, below=True, above=True)
    contrast = _contrast(legend.colours, no_value)
    assert contrast.min() >= 3.0, (contrast.argmin(), legend.colours[contrast.argmin()])
    assert _contrast(legend.under, no_value) >= 3 and _contrast(legend.over, no_value) >= 3


def test_bench_figure_draws_every_method_on_one_error_scale(monkeypatch):
    import fusion.figures
    from fusion.experiments.bench import _figure

    truth = np.ones((20, 40))
    good = truth + 0.05                                   # 5 cm everywhere
    bad = truth + 0.05
    bad[:, 20:] += 1.0                                    # 5 cm on the left, 105 cm on the right
    rows = [{"status": "ok", "method": name, "mae_cm": 100 * float(np.abs(d - truth).mean()),
             "_dense": d, "_truth": truth, "_frame": np.full((20, 40), 128, np.uint8)}
            for name, d in (("good", good), ("bad", bad))]
    drawn = {}
    real = fusion.figures.panel_grid

    def keep(images, titles, columns=3, scale=None, legends=None):
        drawn.update(images=images, titles=titles, legends=legends)
        return real(images, titles, columns, scale, legends)

    monkeypatch.setattr(fusion.figures, "panel_grid", keep)
    _figure(rows)
    errors = [k for k, title in enumerate(drawn["titles"]) if title.startswith("|error|")]
    assert len(errors) == 2
    good_panel, bad_panel = (drawn["images"][k] for k in errors)
    # the same 5 cm error: the same colour in both panels
    np.testing.assert_array_equal(good_panel[5, 5], bad_panel[5, 5])
    assert not np.array_equal(bad_panel[5, 5], bad_panel[5, 30])
    legends = [drawn["legends"][k] for k in errors]
    assert legends[0].high == legends[1].high and legends[0].low == legends[1].low
    np.testing.assert_array_equal(legends[0].colours, legends[1].colours)


def test_a_rig_sized_overview_stays_screen_wide_and_keeps_its_map_points():
    # eight 1280x720 panels in four columns were 5120 px wide, with 15 px titles
    frame = np.full((720, 1280, 3), 90, np.uint8)
    grid = panel_grid([frame] * 8, [f"panel {k}" for k in range(8)], columns=4)
    assert grid.shape[1] <= 1920
    from fusion.figures import grid_scale, point_radius

    assert panel_grid([frame[:180, :240]] * 8, ["x"] * 8, columns=4).shape[1] == 4 * 320
    # a sparse map's one-pixel points stay visible in the reduced panel
    sparse = np.zeros((720, 1280))
    sparse[100:600:50, 100:1200:50] = 1.0
    shown = 1280 * grid_scale(1280, 4)
    image = depth_colours(sparse, 0.5, 2.0, radius=point_radius(1280, shown))
    tile = panel_grid([image] * 4, ["map"] * 4, columns=4)[26:, :int(shown)]
    on_scale = depth_colours(np.array([[1.0]]), 0.5, 2.0)[0, 0].astype(int)
    close = np.abs(tile.astype(int) - on_scale).max(axis=2) <= 12   # the point's own colour
    assert close.sum() >= np.count_nonzero(sparse)
    assert point_radius(240, 320) == 0                    # not reduced: one pixel, as before


def test_events_stats_figure_says_which_colour_is_on_and_which_off(plane_sequence, tmp_path):
    from fusion.cli import main
    from sim.sequence import load_sequence

    camera = load_sequence(plane_sequence).camera
    out = tmp_path / "frame.png"
    assert main(["events", str(plane_sequence), "--stats", "--out", str(out)]) == 0
    image = cv2.imread(str(out))
    assert image.shape[0] > camera.height                 # a legend line under the frame
    strip = image[-22:]
    on, off = (0, 0, 255), (255, 0, 0)                    # BGR: red ON, blue OFF
    assert (strip == on).all(axis=2).sum() >= 64 and (strip == off).all(axis=2).sum() >= 64
