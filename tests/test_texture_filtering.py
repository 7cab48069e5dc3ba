"""Footprint-filtered textures (sim.textures.TextureFilter): a checkerboard finer than a pixel
fires the events of its area-averaged twin, frames and the event camera see the same filtered
scene, and the filter against analytic and converged references."""

from __future__ import annotations

import numpy as np
import pytest

from sim.render import Renderer
from sim.scene import parse_scene
from sim.shader import EventShader
from sim.simulate import simulate
from tests.conftest import scene_text

CAMERA = "[camera]\nwidth = 48\nheight = 36\nfx = 40.0\nfy = 40.0\ncx = 23.5\ncy = 17.5\n"
SLOW = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
        "velocity = [0.25, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
# A 0.6 x 0.4 m poster 1 m away (24 x 16 pixels of 2.5 cm) before a plain wall 2 m away. Its
# checkerboard's squares are 6.25 mm, a quarter of a pixel: 96 x 64 of them.
POSTER = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 2.0, 0.0]
size = [4.0, 4.0]
material = {{ color = [0.2, 0.2, 0.2] }}

[[objects]]
name = "poster"
type = "rectangle"
center = [0.0, 1.0, 0.0]
size = [0.6, 0.4]
material = {{ {material} }}
{motion}"""
STILL = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
         "velocity = [0.0, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
SLIDING = 'motion = { type = "linear", velocity = [-0.25, 0.0, 0.0] }\n'
CHECKER = ('texture = { type = "checkerboard", squares = [96, 64], color0 = 0.1, '
           "color1 = 0.8 }")
TWIN = "color = [0.45, 0.45, 0.45]"                # the checkerboard's area average
EXTRA = ("[frames]\nrate = 10.0\nexposure = 0.001\nexposure_samples = 1\n"
         "[render]\nspp = 4\n")


def _scene(material: str, duration: float = 0.3, moving_poster: bool = False):
    text = POSTER.format(material=material, motion=SLIDING if moving_poster else "")
    return parse_scene(scene_text(text, camera=CAMERA, trajectory=STILL if moving_poster
                                  else SLOW, duration=duration, extra=EXTRA))


@pytest.mark.parametrize("sampler, moving_poster",
                         [("pixel", False), ("frame", False), ("frame", True)])
def test_a_checkerboard_finer_than_a_pixel_fires_the_events_of_its_blurred_twin(
        tmp_path, sampler, moving_poster):
    """The poster slides 7.5 cm (3 pixels) past a still camera in 0.3 s (the per-pixel sampler
    takes static scenes only: there the camera slides past the still poster instead): the twin
    fires only at the poster's edges. Point-sampled, the checkerboard's squares cross the 4
    sub-samples of every poster pixel and flicker (main's code: 33,417 events against the
    twin's 384 with the per-pixel sampler, 34,311 by frames); filtered over each
    sub-sample's footprint (its half-pixel stratum, two squares on a side), every sub-sample
    reads the checkerboard's mean exactly, as a real pixel integrating its area would."""
    counts = {}
    for name, material in (("checker", CHECKER), ("twin", TWIN)):
        result = simulate(_scene(material, moving_poster=moving_poster), tmp_path / name,
                          progress=False, sampler=sampler,
                          event_formats=("txt",), motion_truth=False)
        counts[name] = result.n_events
    assert counts["twin"] > 100, counts
    assert abs(counts["checker"] - counts["twin"]) <= 0.03 * counts["twin"], counts


def test_frames_and_the_event_camera_see_the_same_filtered_checkerboard():
    """Both cameras' renders of the checkerboard equal those of its twin inside the poster's
    border (the analytic box filter is exact here: every sample's footprint is a whole period of
    the checkerboard; at the border it is clipped to the poster), and with filtering off they
    do not (point samples alias)."""
    t = 0.1
    twin = Renderer(_scene(TWIN), spp=4)
    renders = {}
    for filtering in (True, False):
        checker = Renderer(_scene(CHECKER), spp=4, texture_filter=filtering)
        renders[filtering] = (checker.luminance(t),
                              EventShader(checker, 4, t0=0.0, t1=0.3).frame(t))
    reference = (twin.luminance(t), EventShader(twin, 4, t0=0.0, t1=0.3).frame(t))
    poster = reference[1] > 1.5 * reference[1].min()          # the poster's pixels
    # Inside its border: at the border a sub-sample's footprint is clipped to the poster, part
    # of a period of the checkerboard, whose mean is not the twin's (2 % off here).
    inside = poster.copy()
    inside[:, 1:] &= poster[:, :-1]
    inside[:, :-1] &= poster[:, 1:]
    inside[1:] &= poster[:-1]
    inside[:-1] &= poster[1:]
    for ours, theirs in zip(renders[True], reference, strict=True):
        np.testing.assert_allclose(ours[inside], theirs[inside], rtol=1e-3)
        np.testing.assert_allclose(ours[poster], theirs[poster], rtol=0.03)
        np.testing.assert_allclose(ours, theirs, rtol=0.05, atol=1e-3 * theirs.max())
    for ours, theirs in zip(renders[False], reference, strict=True):
        assert np.max(np.abs(ours - theirs)[poster] / theirs[poster]) > 0.2


def test_the_square_wave_mean_is_its_integral():
    """The checkerboard's box filter against a numerical integral of Mitsuba's mask."""
    import drjit as dr
    import mitsuba as mi

    from sim.textures import _square_wave_mean

    Renderer(_scene(TWIN))                                # sets the variant
    rng = np.random.default_rng(1)
    x, half = rng.uniform(-40.0, 40.0, 200), rng.uniform(0.0, 3.0, 200)
    half[:20] = 0.0
    ours = np.array(_square_wave_mean(mi.Float(x), mi.Float(half)))
    s = np.linspace(-1.0, 1.0, 20001)
    points = x[:, None] + half[:, None] * s[None, :]
    mask = ((points - np.floor(points)) > 0.5).astype(np.float64)
    reference = np.trapezoid(mask, s, axis=1) / 2.0
    np.testing.assert_allclose(ours, reference, atol=2e-3)
    assert dr.width(mi.Float(x)) == 200


# A fine noise texture on a floor 0.4 m below the camera, receding to 40 m.
FLOOR = """
[[objects]]
name = "floor"
type = "rectangle"
center = [0.0, 20.5, -0.4]
size = [24.0, 40.0]
normal = [0.0, 0.0, 1.0]
up = [0.0, 1.0, 0.0]
[objects.material]
texture = { type = "noise", resolution = 512, feature_size = 1.0 }
texture_scale = [8.0, 10.0]
"""
ABOVE = ('[[lights]]\ntype = "directional"\ndirection = [0.0, 0.5, -1.0]\n'
         "illuminance_lux = 400.0\n")


def _floor_errors(floor: str) -> dict[str, np.ndarray]:
    """Relative errors of a floor's pixels below the horizon's row, against 1,024 point
    sub-samples with filtering off: the filtered 4-sample event camera (``filtered``), 4 point
    sub-samples (``point``) and the frames (``frames``)."""
    scene = parse_scene(scene_text(floor, camera=CAMERA, lights=ABOVE, duration=0.3))
    point = Renderer(scene, texture_filter=False)
    reference = EventShader(point, 1024, t0=0.0, t1=0.3).frame(0.1)
    filtered = Renderer(scene)
    images = {"filtered": EventShader(filtered, 4, t0=0.0, t1=0.3).frame(0.1),
              "point": EventShader(point, 4, t0=0.0, t1=0.3).frame(0.1),
              "frames": filtered.luminance(0.1)}
    rows = np.flatnonzero(reference.min(axis=1) > 0)[2:]          # below the horizon's row
    return {name: np.abs(image - reference)[rows] / reference[rows]
            for name, image in images.items()}


def test_filtered_bitmaps_approach_the_converged_point_render():
    """The floor to the horizon (sub-sample footprints from 2 x 4 to hundreds of texels): the
    filtered 4-sample event camera against 1,024 point sub-samples with filtering off, the
    converged box filter of each pixel (256 samples are within 0.5 % of it). The bound: each
    sub-sample's filter is the box of its stratum in mean and variance, and the strata's
    filters tile the pixel (see TextureFilter and sim.shader): measured 0.5 % mean error,
    against 5.2 % for 4 point samples, which alias (main's filter, one to two footprints wide
    and centred on the jittered sub-samples: 2.4 %). The frames' 16 samples (Mitsuba's
    stratified sampler, each filtered over its own footprint, not centred on its stratum):
    1.0 %. The horizon's row (half floor, half nothing: a geometric edge, which filtering does
    not touch) is left out."""
    error = {name: float(np.mean(e)) for name, e in _floor_errors(FLOOR).items()}
    assert error["filtered"] < 0.01, error
    assert error["filtered"] < 0.2 * error["point"], error
    assert error["frames"] < 0.015, error


# The same floor under a fine checkerboard whose squares run at 30 degrees to the image's axes:
# long sub-sample footprints lie diagonally across the squares.
DIAGONAL_CHECKER_FLOOR = """
[[objects]]
name = "floor"
type = "rectangle"
center = [0.0, 20.5, -0.4]
size = [40.0, 40.0]
normal = [0.0, 0.0, 1.0]
up = [0.5, 0.866, 0.0]
material = { texture = { type = "checkerboard", squares = [200, 200], color0 = 0.1, color1 = 0.8 } }
"""


def test_a_diagonal_checkerboard_approaches_the_converged_point_render():
    """The checkerboard's filter tiles each footprint's parallelogram in 4 cells, each the
    exact mean over its cell's bounding box (as a bitmap's taps tile it): a footprint that runs
    diagonally across the squares is no longer widened to the box around all of it, which
    greyed them (dynamic_6dof's ball, at its rim: 30-40 % off 256 sub-samples). Against 1,024
    point sub-samples: measured 1.9 % mean error (6.3 % with one bounding box; 99th
    percentile 13 % against 58 %), 20 % for 4 point samples; the frames 4.4 % (5.3 %)."""
    error = _floor_errors(DIAGONAL_CHECKER_FLOOR)
    assert error["filtered"].mean() < 0.03, error["filtered"].mean()
    assert np.percentile(error["filtered"], 99) < 0.25
    assert error["filtered"].mean() < 0.15 * error["point"].mean()
    assert error["frames"].mean() < 0.05, error["frames"].mean()


def test_a_fine_texture_fires_the_events_of_its_converged_reference(tmp_path):
    """The floor seen from 0.4 m above, looking 27 degrees down (no edge, no horizon in view:
    texture only, white noise at the texel, 2 x 4 to 60 x 300 texels a pixel), the camera
    sliding sideways at 1 m/s for 0.1 s: the default 4 sub-samples fire within 4 % of 64
    sub-samples (64 are within 0.5 % of 256 here). Measured 776 against 762 (+1.8 %); main's
    filter, centred on the jittered sub-samples and one to two footprints wide: 875 against
    756 (+16 %)."""
    from dataclasses import replace

    sliding = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
               "velocity = [1.0, 0.0, 0.0]\nlook_at = [0.0, 1.0, -0.5]\n")
    scene = parse_scene(scene_text(FLOOR, camera=CAMERA, lights=ABOVE, duration=0.1,
                                   trajectory=sliding, extra=EXTRA))
    counts = {}
    for spp in (4, 64):
        result = simulate(replace(scene, render=replace(scene.render, event_spp=spp)),
                          tmp_path / str(spp), progress=False, sampler="pixel",
                          event_formats=("txt",), motion_truth=False)
        counts[spp] = result.n_events
    assert counts[64] > 500, counts
    assert abs(counts[4] / counts[64] - 1.0) < 0.04, counts


def _centre_hits(renderer: Renderer, pose: np.ndarray):
    """Mitsuba's hits (``RayFlags.All``) of the renderer's pixel-centre rays from ``pose``, and
    which rays hit."""
    import mitsuba as mi

    rays = renderer._rays_np @ pose[:3, :3].T
    ray = mi.Ray3f(mi.Point3f(*pose[:3, 3].astype(np.float32).tolist()),
                   mi.Vector3f(*(rays[:, i].astype(np.float32) for i in range(3))))
    si = renderer.mitsuba_scene.ray_intersect(ray, mi.RayFlags.All, True)
    return si, si.is_valid()


def test_the_tables_point_lookup_is_mitsubas():
    """The point value that a filtered lookup divides by (level 0 of the pyramid, the
    checkerboard's mask) is Mitsuba's own texture value (its luminance) on every textured
    object of boxes_6dof (four bitmaps, grey and RGB, and a checkerboard), and a zero footprint
    filters nothing."""
    from dataclasses import replace

    import drjit as dr
    import mitsuba as mi

    from scenes import resolve_scene
    from sim.scene import load_scene
    from sim.textures import filtered_reflectance

    scene = load_scene(resolve_scene("boxes_6dof"))
    renderer = Renderer(replace(scene, camera=scene.camera.with_resolution(96, 72)))
    pose = scene.trajectory.pose(2.0)
    si, hit = _centre_hits(renderer, pose)
    filtered, point, textured = filtered_reflectance(renderer.texture_filter.arrays, si, hit)
    mitsuba = mi.luminance(si.bsdf().eval_diffuse_reflectance(si, hit))
    textured = np.array(textured)
    assert textured.mean() > 0.8 and dr.width(filtered) == 96 * 72
    # On cuda_* variants Mitsuba's bitmap reads through the GPU's texture units, whose bilinear
    # weights have 8 fractional bits: within 1/256 of the exact lookup (texel values <= 1;
    # measured on an H200: 0.0017). The table's lookup is the exact one on every variant.
    atol = 1 / 256 if mi.variant().startswith("cuda") else 1e-6
    np.testing.assert_allclose(np.array(point)[textured], np.array(mitsuba)[textured],
                               rtol=1e-4, atol=atol)
    np.testing.assert_allclose(np.array(filtered)[textured], np.array(point)[textured],
                               rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("shape", ["rectangle", "cylinder"])
def test_a_flipped_checkerboard_s_point_lookup_is_mitsubas(shape):
    """Shapes whose v is flipped (rectangle, cylinder) with a checkerboard whose squares and
    repeats do not make the flip's offset a whole number of periods: tabletop_0's north wall,
    3 x 10 squares repeated 2.6747 x 1.9329 times. Main's table put the flip's offset after the
    squares' factor (1.9329 x 5 instead of Mitsuba's 1.9329, 0.73 of a period apart): its
    point lookup was the other colour on 6,787 of 172,800 sub-samples of tabletop_0's frame at
    4 samples per pixel, each then scaled by 0.85 / 0.05 or its inverse (frames 34 dB from the
    converged render there)."""
    import mitsuba as mi

    from sim.textures import filtered_reflectance

    params = ('size = [1.6, 1.2]\nnormal = [0.0, -1.0, 0.0]\nup = [0.0, 0.0, 1.0]'
              if shape == "rectangle" else 'radius = 0.5\nheight = 1.5\ncaps = false')
    obj = (f'[[objects]]\nname = "wall"\ntype = "{shape}"\ncenter = [0.0, 1.2, 0.0]\n{params}\n'
           'material = { texture = { type = "checkerboard", squares = [3, 10] }, '
           "texture_scale = [2.6747, 1.9329] }\n")
    scene = parse_scene(scene_text(obj, camera=CAMERA, trajectory=STILL, duration=0.3))
    renderer = Renderer(scene)
    si, hit = _centre_hits(renderer, scene.trajectory.pose(0.0))
    _, point, textured = filtered_reflectance(renderer.texture_filter.arrays, si, hit)
    textured = np.array(textured)
    mitsuba = np.array(mi.luminance(si.bsdf().eval_diffuse_reflectance(si, hit)))
    assert textured.mean() > 0.5
    assert set(np.round(mitsuba[textured].astype(float), 2)) == {0.05, 0.85}   # both seen
    np.testing.assert_allclose(np.array(point)[textured], mitsuba[textured], rtol=1e-5)


def test_a_footprint_that_crosses_a_face_s_edge_is_clipped_to_the_face():
    """A 2 x 2 checkerboard tile seen square on, every hit given a footprint 0.4 of the tile
    wide (uv partials set by hand): the filtered value is the checkerboard's exact mean over the
    footprint's box clipped to the tile's (u, v) in [0, 1] (what lies beyond the edge is not
    this face), where main's wrapped round to the opposite edge; a footprint inside the tile is
    not touched."""
    import mitsuba as mi

    from sim.textures import filtered_reflectance, to_uv_affine

    tile = ('[[objects]]\nname = "tile"\ntype = "rectangle"\ncenter = [0.03, 1.0, 0.02]\n'
            'size = [0.7, 0.7]\nmaterial = { texture = { type = "checkerboard", '
            "squares = [2, 2], color0 = 0.1, color1 = 0.8 } }\n")
    scene = parse_scene(scene_text(tile, camera=CAMERA, trajectory=STILL, duration=0.3))
    renderer = Renderer(scene)
    pose = scene.trajectory.pose(0.0)
    si, hit = _centre_hits(renderer, pose)
    half = 0.2
    si.duv_dx = mi.Vector2f(2.0 * half, 0.0)
    si.duv_dy = mi.Vector2f(0.0, 2.0 * half)
    filtered, _, textured = filtered_reflectance(renderer.texture_filter.arrays, si, hit)
    on = np.array(textured)
    uv = np.array(si.uv).T[on]                                   # (N, 2)
    a_u, b_u, a_v, b_v = to_uv_affine({"type": "checkerboard", "squares": [2, 2]}, (1.0, 1.0),
                                      flip_v=True)
    s = np.linspace(0.0, 1.0, 2001)

    def mask_mean(low, high, a, b):              # of frac(a x + b) > 1/2 over [low, high]
        x = a * (low[:, None] + (high - low)[:, None] * s[None, :]) + b
        return np.trapezoid(((x - np.floor(x)) > 0.5).astype(float), s, axis=1)

    pu = mask_mean(np.clip(uv[:, 0] - half, 0, 1), np.clip(uv[:, 0] + half, 0, 1), a_u, b_u)
    pv = mask_mean(np.clip(uv[:, 1] - half, 0, 1), np.clip(uv[:, 1] + half, 0, 1), a_v, b_v)
    same = pu * pv + (1.0 - pu) * (1.0 - pv)
    expected = 0.1 * same + 0.8 * (1.0 - same)
    crossing = np.any((uv < half) | (uv > 1.0 - half), axis=1)
    assert on.sum() > 300 and crossing.sum() > 100 and (~crossing).sum() > 20
    np.testing.assert_allclose(np.array(filtered)[on], expected, atol=2e-3)
