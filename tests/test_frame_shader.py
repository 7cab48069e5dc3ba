"""Frames rendered pixel by pixel (sim.frame_shader) and what a frame costs (sequence.json's
frame_cost): the exposure times sized from the image motion against the exact time average of a
moving edge, and the cost record against the counts its parameters give."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sim.frame_shader import (
    MAX_EXPOSURE_TIMES,
    FrameShader,
    exposure_bound,
    exposure_times,
)
from sim.render import Renderer
from sim.scene import SceneError, parse_scene
from sim.simulate import simulate
from tests.conftest import scene_text

CAMERA = "[camera]\nwidth = 48\nheight = 36\nfx = 40.0\nfy = 40.0\ncx = 23.5\ncy = 17.5\n"
FX, CX, DEPTH = 40.0, 23.5, 1.0
EXPOSURE, SPEED, ALBEDO, LUX = 0.01, 7.5, 0.8, 400.0
MOTION_PX = FX * SPEED * EXPOSURE / DEPTH            # 3 pixels during an exposure
# A white poster 1 m ahead from x = 0 to 2 m, nothing beside it; the camera slides along +x at
# 7.5 m/s from x = -0.375 m, so that the poster's left edge is at u = cx at t = 0.05 s (a frame's
# middle at 10 Hz) and sweeps 3 pixels to the left during its 10-ms exposure.
POSTER = (f'[[objects]]\nname = "poster"\ntype = "rectangle"\ncenter = [1.0, {DEPTH}, 0.0]\n'
          f"size = [2.0, 2.0]\nmaterial = {{ color = [{ALBEDO}, {ALBEDO}, {ALBEDO}] }}\n")
SLIDE = ('[trajectory]\ntype = "linear"\nposition = [-0.375, 0.0, 0.0]\n'
         f"velocity = [{SPEED}, 0.0, 0.0]\nlook_at = [-0.375, 1.0, 0.0]\n")
FRAMES = f"[frames]\nrate = 10.0\nexposure = {EXPOSURE}\n"


def _scene(extra: str = "", objects: str = POSTER):
    return parse_scene(scene_text(objects, camera=CAMERA, trajectory=SLIDE, duration=0.2,
                                  extra=FRAMES + extra))


def _edge_average(t: float, exposure: float) -> np.ndarray:
    """The exact exposure average of each pixel column, in units of the poster's luminance: the
    time average of the share of the pixel's box [u - 1/2, u + 1/2] right of the edge at
    u_e(t) = cx + fx (0 - x(t)) / Z (piecewise linear in t; 20,001 points)."""
    times = np.linspace(t - exposure / 2, t + exposure / 2, 20001)
    edge = CX - FX * (-0.375 + SPEED * times) / DEPTH
    u = np.arange(48.0)[:, None]
    return np.trapezoid(np.clip(u + 0.5 - edge[None, :], 0.0, 1.0), times, axis=1) / exposure


def test_exposure_times_follow_the_motion_one_flat_stratum_per_part():
    assert exposure_times(0.0, 4) == 1 and exposure_times(0.5, 4) == 1   # half a pixel per part
    assert exposure_times(0.51, 4) == 2 and exposure_times(3.0, 4) == 6
    assert exposure_times(3.0, 256) == 48                                # 1/16 pixel per part
    assert exposure_times(1e6, 4) == MAX_EXPOSURE_TIMES
    assert exposure_bound(3.0, 6) == pytest.approx(math.sqrt(2) / 8)


@pytest.mark.parametrize("angle", [0.0, 30.0, 45.0])
def test_the_midpoint_bound_holds_for_an_edge_swept_across_a_pixel(angle):
    """The exact time average of a pixel's coverage by a straight edge (the share of the unit
    box on one side, integrated column by column over 1,000 columns) moving along its normal at
    a constant speed, against the mean of its values at the centres of N equal parts: within
    exposure_bound (a fraction of the luminance range) for every offset, motion and N, and
    reached within a factor 4 (a kink at a part's centre: 1 / (2 sqrt(2)) of the bound)."""
    nx, ny = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    x = (np.arange(1000) + 0.5) / 1000 - 0.5

    def coverage(offset):                   # (k,) offsets of the edge -> (k,) shares of the box
        offset = np.asarray(offset, dtype=np.float64)[:, None]
        if ny == 0.0:
            return np.clip(offset[:, 0] + 0.5, 0.0, 1.0)
        return np.clip((offset - nx * x[None, :]) / ny + 0.5, 0.0, 1.0).mean(axis=1)

    worst = 0.0
    for motion in (0.2, 0.7, 2.5):
        for parts in (1, 2, 5):
            for start in np.linspace(-1.5 - motion, 1.5, 31):
                exact = coverage(start + motion * (np.arange(2000) + 0.5) / 2000).mean()
                centres = start + motion * (np.arange(parts) + 0.5) / parts
                error = abs(coverage(centres).mean() - exact)
                bound = exposure_bound(motion, parts)
                assert error <= bound + 1e-5, (motion, parts, start)
                worst = max(worst, error / bound)
    assert worst > 0.25


@pytest.fixture(scope="module")
def poster_renderer():
    renderer = Renderer(_scene())
    if renderer.variant == "scalar_rgb":
        pytest.skip("the frame shader needs a JIT variant")
    return renderer


def test_a_swept_edge_matches_its_exact_blur_within_the_bound(poster_renderer):
    """The poster's edge sweeps 3 pixels in the exposure: sized from that motion (6 times, half
    a pixel apart), every pixel is within the bound of the exact average plus the edge pixels'
    spatial error (1,024 samples: a 32 x 32 grid that a vertical edge cuts in one column, 1/32);
    the flat pixels are exact; one time (the sharp edge at the middle) is not within it."""
    t, luminance = 0.05, ALBEDO * LUX / math.pi                 # rho E / pi, cd/m^2
    shader = FrameShader(poster_renderer, 4, 1024, t0=0.0, t1=0.1)
    depth = poster_renderer.depth(t)
    exact = luminance * _edge_average(t, EXPOSURE)[None, :] * np.ones((36, 1))
    frame, cost = shader.exposure(t, EXPOSURE, depth)
    assert cost.motion_px == pytest.approx(MOTION_PX, rel=1e-5)
    assert cost.times == 6 and cost.checks == 5 and cost.edge_pixels >= 4 * 36
    tolerance = luminance * (exposure_bound(MOTION_PX, 6) + 1 / 32)
    assert np.abs(frame - exact).max() <= tolerance
    flat = (exact == 0) | (exact == luminance)
    np.testing.assert_allclose(frame[flat], exact[flat], rtol=1e-5, atol=1e-5)
    sharp, one = shader.exposure(t, EXPOSURE, depth, times=1)
    assert one.times == 1 and np.abs(sharp - exact).max() > tolerance


def test_equal_flat_and_edge_samples_render_every_pixel_alike(poster_renderer):
    """flat_spp == spp (a brute-force reference): no edge is looked for."""
    shader = FrameShader(poster_renderer, 16, 16, t0=0.0, t1=0.1)
    _, cost = shader.exposure(0.05, EXPOSURE, poster_renderer.depth(0.05))
    assert (cost.checks, cost.edge_pixels) == (0, 0)
    assert cost.pixel_samples == cost.times * 48 * 36 * 16
    with pytest.raises(ValueError, match=r"flat_spp \(16\) must be at most spp \(4\)"):
        FrameShader(poster_renderer, 16, 4, t0=0.0, t1=0.1)


def test_sequence_json_says_what_the_frames_cost(tmp_path, poster_renderer):
    """frame_cost's counts are the settings' (spp, flat_spp, exposure times from the exact
    motion, one depth render a frame) and its totals their sums; timings_s splits the frame
    stage."""
    result = simulate(_scene(), tmp_path / "seq", progress=False, with_events=False,
                      motion_truth=False)
    record = json.loads((result.out / "sequence.json").read_text())
    cost, pixels = record["frame_cost"], 48 * 36
    assert (cost["renderer"], cost["spp"], cost["flat_spp"]) == ("pixel", 16, 4)
    assert cost["frames"] == result.n_frames == 2 and cost["pixels"] == pixels
    frames = cost["per_frame"]
    for frame in frames:
        assert frame["motion_px"] == pytest.approx(MOTION_PX, rel=1e-5)
        assert frame["times"] == exposure_times(MOTION_PX, 4) == 6
        flat = pixels - frame["edge_pixels"]
        assert frame["pixel_samples"] == 6 * (flat * 4 + frame["edge_pixels"] * 16)
    # the edge, seen in both frames (at u = 37 and 7), crosses 4-6 columns in each exposure
    assert all(4 * 36 <= f["edge_pixels"] <= 6 * 36 for f in frames)
    assert cost["exposure_times"] == 12 == result.n_renders == record["render"]["renders"]
    assert cost["exposure_times_per_frame"] == [6, 6]
    assert cost["pixel_samples"] == sum(f["pixel_samples"] for f in frames)   # ideal: no look
    assert cost["control_renders"] == 0
    assert cost["depth_renders"] == 2 and cost["depth_rays"] == 2 * pixels
    assert cost["geometry_samples"] == cost["edge_checks"] * pixels * 4 == 10 * pixels * 4
    assert cost["exposure_bound_max"] == pytest.approx(exposure_bound(MOTION_PX, 6), rel=1e-5)
    assert {"frame_setup", "depth", "exposure_control", "frame_motion", "frame_edges", "render",
            "frame_sensor", "write"} <= set(record["timings_s"])


def test_whole_frame_renders_cost_their_renders_times_spp(tmp_path):
    """A scene with moving objects renders whole frames: 4 renders a frame (exposure_samples not
    given), spp samples at every pixel of each, plus auto-exposure's first look."""
    moving = POSTER + 'motion = { type = "linear", velocity = [0.0, 0.0, 0.1] }\n'
    scene = _scene('sensor = "davis240c_aps"\n[render]\nspp = 4\n', objects=moving)
    result = simulate(scene, tmp_path / "seq", progress=False, with_events=False,
                      motion_truth=False)
    cost = json.loads((result.out / "sequence.json").read_text())["frame_cost"]
    assert (cost["renderer"], cost["renderer_reason"]) == ("frame",
                                                           "the scene has moving objects")
    assert cost["exposure_times"] == 2 * 4 == result.n_renders
    assert cost["control_renders"] == 1 and cost["edge_checks"] == 0
    assert cost["pixel_samples"] == (2 * 4 + 1) * 4 * 48 * 36
    assert cost["per_frame"][0]["motion_px"] is None and cost["flat_spp"] is None


def test_flat_spp_is_read_from_the_scene_file():
    assert _scene("[render]\nflat_spp = 9\n").render.flat_spp == 9
    assert _scene().render.flat_spp == 4
    with pytest.raises(SceneError, match=r"\[render\]\.flat_spp.*perfect square.*got 5"):
        _scene("[render]\nflat_spp = 5\n")
