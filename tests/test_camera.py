"""sim.camera: the OpenCV camera model against OpenCV itself, presets and calib.txt."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim.camera import CAMERA_PRESETS, Camera, camera_preset, read_calib, write_calib
from tests.conftest import undistort_points

# ECD DAVIS240C calibration (shapes_*, poster_*), real lens distortion included.
DAVIS = Camera(240, 180, 199.092366542, 198.82882047, 132.192071378, 110.712660011,
               (-0.368436311798, 0.150947243557, -0.000296130534385, -0.000759431726241, 0.0))
# fx != fy, principal point off-centre, all five coefficients non-zero.
ODD = Camera(64, 48, 60.0, 45.0, 30.3, 22.7, (-0.2, 0.05, 0.001, -0.002, 0.01))
TIGHT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)


def points_in_view(camera: Camera, n: int = 200, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.5, 5.0, n)
    uv = np.c_[rng.uniform(0, camera.width - 1, n), rng.uniform(0, camera.height - 1, n)]
    xy = (uv - [camera.cx, camera.cy]) / [camera.fx, camera.fy]
    return np.c_[xy * z[:, None], z]


def test_intrinsics_and_properties():
    cam = Camera(64, 48, 60.0, 45.0, 30.3, 22.7)
    np.testing.assert_array_equal(cam.K, [[60.0, 0.0, 30.3], [0.0, 45.0, 22.7], [0.0, 0.0, 1.0]])
    assert cam.resolution == (64, 48)
    assert not cam.has_distortion and ODD.has_distortion
    listed = Camera(64, 48, 60.0, 45.0, 30.3, 22.7, [0, 0, 0.001, 0, 0])
    assert listed.distortion == (0.0, 0.0, 0.001, 0.0, 0.0)
    assert all(isinstance(c, float) for c in listed.distortion)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"width": 0}, "width must be a positive integer"),
        ({"height": 4.5}, "height must be a positive integer"),
        ({"fx": -1.0}, "fx must be a positive focal length"),
        ({"fy": float("inf")}, "fy must be a finite number"),
        ({"distortion": (0.1, 0.0, 0.0, 0.0)}, "5 finite numbers"),
        ({"distortion": (0.1, 0.0, 0.0, 0.0, float("nan"))}, "5 finite numbers"),
    ],
)
def test_invalid_cameras_are_rejected(kwargs, message):
    args = {"width": 64, "height": 48, "fx": 60.0, "fy": 45.0, "cx": 30.3, "cy": 22.7, **kwargs}
    with pytest.raises(ValueError, match=message):
        Camera(**args)


def test_project_applies_the_pinhole_formula_with_fx_ne_fy():
    cam = Camera(64, 48, 60.0, 45.0, 30.3, 22.7)
    uv = cam.project([[0.2, -0.4, 2.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(uv, [[60.0 * 0.1 + 30.3, 45.0 * -0.2 + 22.7], [30.3, 22.7]])
    behind = cam.project([[0.1, 0.1, 0.0], [0.1, 0.1, -1.0]])
    assert np.isnan(behind).all()


@pytest.mark.parametrize("camera", [DAVIS, ODD, camera_preset("davis240c")])
def test_project_matches_cv2_project_points(camera):
    points = points_in_view(camera)
    expected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.K,
                                    np.array(camera.distortion))
    np.testing.assert_allclose(camera.project(points), expected[:, 0], atol=1e-10)


@pytest.mark.parametrize("camera", [DAVIS, ODD])
def test_undistort_matches_cv2_undistort_points(camera):
    uv = camera.pixel_centres().reshape(-1, 2)
    expected = undistort_points(uv[:, None, :], camera.K, camera.distortion,
                                criteria=TIGHT)[:, 0]
    ours = camera.normalized_pixel_centres().reshape(-1, 2)
    np.testing.assert_allclose(ours, expected, atol=1e-9)
    # And it really inverts the distortion.
    xy_d = (uv - [camera.cx, camera.cy]) / [camera.fx, camera.fy]
    np.testing.assert_allclose(camera.distort(ours), xy_d, atol=1e-12)


@pytest.mark.parametrize("camera", [DAVIS, ODD, camera_preset("davis346")])
def test_project_backproject_round_trip(camera):
    points = points_in_view(camera, seed=1)
    uv = camera.project(points)
    np.testing.assert_allclose(camera.backproject(uv, points[:, 2]), points, atol=1e-11)


def test_undistort_marks_points_beyond_the_lens_model_as_nan():
    # With k1 < 0 alone, r_d = r (1 + k1 r^2) never exceeds 2 / (3 sqrt(-3 k1)).
    cam = Camera(64, 48, 60.0, 45.0, 30.3, 22.7, (-0.5, 0.0, 0.0, 0.0, 0.0))
    r_max = 2.0 / (3.0 * np.sqrt(1.5))
    xy = cam.undistort([[0.5 * r_max, 0.0], [1.2 * r_max, 0.0]])
    assert np.isfinite(xy[0]).all() and np.isnan(xy[1]).all()


def test_pixel_centres_and_rays():
    cam = Camera(5, 3, 10.0, 20.0, 2.0, 1.0)
    centres = cam.pixel_centres()
    assert centres.shape == (3, 5, 2) and centres.dtype == np.float64
    np.testing.assert_array_equal(centres[2, 4], [4.0, 2.0])
    rays = cam.normalized_pixel_centres()
    np.testing.assert_allclose(rays[2, 4], [(4.0 - 2.0) / 10.0, (2.0 - 1.0) / 20.0])


def test_in_image_uses_the_pixel_area():
    cam = Camera(5, 3, 10.0, 20.0, 2.0, 1.0)
    uv = [[-0.5, -0.5], [4.49, 2.49], [4.5, 0.0], [0.0, 2.5], [-0.51, 0.0], [np.nan, 1.0]]
    np.testing.assert_array_equal(cam.in_image(uv), [True, True, False, False, False, False])


def test_with_resolution_keeps_projections_consistent():
    point = np.array([[0.3, -0.1, 2.0]])
    for camera in (DAVIS, ODD):
        big = camera.with_resolution(2 * camera.width, 3 * camera.height)
        u, v = camera.project(point)[0]
        # Pixel i covers [i - 0.5, i + 0.5): scaling by s maps u to (u + 0.5) s - 0.5.
        np.testing.assert_allclose(big.project(point)[0], [(u + 0.5) * 2 - 0.5,
                                                           (v + 0.5) * 3 - 0.5], atol=1e-12)
        back = big.with_resolution(camera.width, camera.height)
        for name in ("fx", "fy", "cx", "cy"):
            assert getattr(back, name) == pytest.approx(getattr(camera, name), rel=1e-14)
        assert back.distortion == camera.distortion
    with pytest.raises(ValueError, match="positive integer"):
        DAVIS.with_resolution(0, 10)


def test_presets():
    d240 = camera_preset("davis240c")
    assert (d240.width, d240.height) == (240, 180)
    assert (d240.fx, d240.fy, d240.cx, d240.cy) == (199.092366542, 198.82882047,
                                                    132.192071378, 110.712660011)
    assert not d240.has_distortion
    d346 = camera_preset("davis346")
    assert (d346.width, d346.height, d346.fx, d346.cy) == (346, 260, 226.38018519795807,
                                                          133.73271487507847)
    assert not d346.has_distortion
    for name, (w, h) in (("vga", (640, 480)), ("hd", (1280, 720))):
        cam = camera_preset(name)
        assert cam.resolution == (w, h)
        assert cam.fx == cam.fy == pytest.approx(199.092366542 * w / 240)
        assert (cam.cx, cam.cy) == ((w - 1) / 2, (h - 1) / 2)
        # Same horizontal field of view as the DAVIS240C: tan(fov/2) = (W/2) / fx.
        assert (w / 2) / cam.fx == pytest.approx(120 / 199.092366542)
    assert set(CAMERA_PRESETS) == {"davis240c", "davis346", "vga", "hd"}
    with pytest.raises(ValueError, match="davis240c, davis346, hd, vga"):
        camera_preset("davis640")


def test_calib_round_trip(tmp_path):
    path = tmp_path / "calib.txt"
    write_calib(path, ODD)
    text = path.read_text()
    assert text.endswith("\n") and len(text.split()) == 9
    assert read_calib(path, ODD.width, ODD.height) == ODD
    odd_values = Camera(10, 10, 1 / 3, 2 / 7, 1e-17, 123456.789012345678)
    write_calib(path, odd_values)
    assert read_calib(path, 10, 10) == odd_values  # repr keeps every bit


def test_calib_with_4_or_8_numbers_has_zero_missing_coefficients(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text("\n100 101 50.5 40.5\n\n")
    assert read_calib(path, 100, 80) == Camera(100, 80, 100.0, 101.0, 50.5, 40.5)
    path.write_text("100 101 50.5 40.5 -0.1 0.01 0.001 0.002\n")
    assert read_calib(path, 100, 80).distortion == (-0.1, 0.01, 0.001, 0.002, 0.0)


@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        ("100 101 50 40 0.1\n", ":1:", "expected 'fx fy cx cy"),
        ("\n100 101 abc 40\n", ":2:", "'abc' is not a number"),
        ("100 101 50 nan\n", ":1:", "not finite"),
        ("100 101 50 40\n100 101 50 40\n", ":2:", "second non-empty line"),
        ("-100 101 50 40\n", ":1:", "fx must be a positive focal length"),
        ("\n  \n", ": ", "no non-empty line"),
    ],
)
def test_malformed_calib_names_file_and_line(tmp_path, text, where, message):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        read_calib(path, 100, 80)
    assert str(info.value).startswith(f"{path}{where}")


def test_real_ecd_calib_parses(ecd_slider):
    cam = read_calib(ecd_slider / "calib.txt", 240, 180)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (335.419462958, 335.352935612, 129.924663379,
                                                99.1864303447)
    assert cam.distortion == (-0.138592767408, 0.0933736664192, -0.000335586987532,
                              0.000173720158228, 0.0)
    assert np.isfinite(cam.normalized_pixel_centres()).all()
