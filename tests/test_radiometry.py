"""Radiometry in physical units: photometric lights, luminance in cd/m^2, the DVS's dark current.

Analytic cases through the real renderer (a Lambertian plane under a known light must render
rho E / pi cd/m^2), the log response's invariance to the light level, and the HDR twin's dark
half firing like its bright half.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from scenes import builtin_scenes, resolve_scene
from sim.events import EventParams, emulate_events, log_intensity
from sim.radiometry import (
    DVS_DARK_CURRENT,
    DVS_DARK_LUMINANCE,
    DVS_RESPONSIVITY,
    image_illuminance,
    lambertian_luminance,
    photocurrent,
    responsivity,
)
from sim.render import Renderer
from sim.scene import SceneError, load_scene, parse_scene
from tests.conftest import scene_text

ALBEDO = 0.8


def _plane(material: str) -> str:
    """A 4 m square fronto-parallel rectangle 1 m ahead of the test camera."""
    return ('[[objects]]\nname = "plane"\ntype = "rectangle"\ncenter = [0.0, 1.0, 0.0]\n'
            f'size = [4.0, 4.0]\nnormal = [0.0, -1.0, 0.0]\nmaterial = {material}\n')


WHITE_PLANE = _plane(f"{{ color = {ALBEDO} }}")
TEXTURED_PLANE = _plane('{ texture = { type = "noise", feature_size = 4.0, contrast = 0.6 } }')


def _directional(lux: float, direction=(0.0, 1.0, 0.0)) -> str:
    return (f'[[lights]]\ntype = "directional"\ndirection = {list(direction)}\n'
            f"illuminance_lux = {lux}\n")


def _point(cd: float, position=(0.0, 0.0, 0.0)) -> str:
    return f'[[lights]]\ntype = "point"\nposition = {list(position)}\nintensity_cd = {cd}\n'


def test_white_plane_under_a_directional_light_renders_rho_e_over_pi():
    """300 lux along the optical axis on a fronto-parallel plane of albedo 0.8: every pixel is
    0.8 * 300 / pi = 76.39 cd/m^2, to float32 rounding (rtol 1e-5)."""
    scene = parse_scene(scene_text(WHITE_PLANE, lights=_directional(300.0)))
    image = Renderer(scene, spp=4).luminance(0.0)
    np.testing.assert_allclose(image, lambertian_luminance(300.0, ALBEDO), rtol=1e-5)
    assert lambertian_luminance(300.0, ALBEDO) == pytest.approx(76.394, abs=1e-3)


def test_oblique_directional_light_gives_the_cosine_law():
    """The light at 60 degrees from the plane's normal gives half its lux: rho E cos / pi."""
    direction = (math.sin(math.radians(60.0)), math.cos(math.radians(60.0)), 0.0)
    scene = parse_scene(scene_text(WHITE_PLANE, lights=_directional(500.0, direction)))
    image = Renderer(scene, spp=4).luminance(0.0)
    np.testing.assert_allclose(image, lambertian_luminance(250.0, ALBEDO), rtol=1e-5)


def test_every_light_is_shaded_in_frames_and_the_event_camera_at_one_sample_per_pixel():
    """Three directional lights: 300 lux along the optical axis, 500 lux at 60 degrees from the
    plane's normal (250 lux on it) and 400 lux from behind the plane (none on its lit face).
    Every pixel is rho (300 + 250) / pi, to float32 rounding, at ONE sample per pixel in the
    frames and in the event camera: both shade every light (sim.render.direct_light), where
    Mitsuba's direct integrator picks one at random per sample (each pixel then 3 rho E_i / pi
    for one light i: 229, 191 or 0 cd/m^2)."""
    from sim.shader import EventShader

    oblique = (math.sin(math.radians(60.0)), math.cos(math.radians(60.0)), 0.0)
    lights = (_directional(300.0) + _directional(500.0, oblique)
              + _directional(400.0, (0.0, -1.0, 0.0)))
    scene = parse_scene(scene_text(WHITE_PLANE, lights=lights))
    renderer = Renderer(scene, spp=1)
    expected = lambertian_luminance(550.0, ALBEDO)
    np.testing.assert_allclose(renderer.luminance(0.0), expected, rtol=1e-5)
    np.testing.assert_allclose(EventShader(renderer, 1, t0=0.0, t1=1.0).frame(0.5), expected,
                               rtol=1e-5)


def test_point_light_in_candela_gives_inverse_square_illuminance():
    """A 100 cd point light at the camera, the plane 1 m ahead: a surface point at distance r
    gets E = I cos / r^2 = I / r^3 lux, so its pixel renders rho I / (pi r^3) cd/m^2. Pixels
    integrate their square (box filter) and the prediction is at the pixel centre: the
    curvature of 1 / r^3 over a pixel (1/60 rad) bounds the difference by 1e-4 relative; the
    tolerance is 2e-3 for the 16 stratified sub-samples."""
    scene = parse_scene(scene_text(WHITE_PLANE, lights=_point(100.0)))
    image = Renderer(scene, spp=16).luminance(0.0).astype(np.float64)
    rays = scene.camera.normalized_pixel_centres()
    r = np.sqrt(1.0 + (rays ** 2).sum(axis=-1))          # the plane at depth 1: p = (x, y, 1)
    expected = lambertian_luminance(100.0 / r**3, ALBEDO)
    np.testing.assert_allclose(image, expected, rtol=2e-3)


def test_ten_times_the_light_shifts_log_intensity_by_log_10_and_nothing_else():
    """Every light x10: luminance x10 exactly (rtol 1e-6), the same depth, and
    L = log(Y + log_eps) moves by log((10 Y + d) / (Y + d)): by log(10) within 0.01 where the
    dark current d is negligible (Y > 100 d: the gap is at most 0.9 d / Y < 0.009)."""
    lights = _directional(400.0, (0.2, 1.0, -0.3)) + _point(80.0, (-0.3, 0.2, 0.4))
    brighter = _directional(4000.0, (0.2, 1.0, -0.3)) + _point(800.0, (-0.3, 0.2, 0.4))
    eps = EventParams().log_eps
    views = [Renderer(parse_scene(scene_text(TEXTURED_PLANE, lights=text)), spp=4).render(0.0)
             for text in (lights, brighter)]
    (dim, bright) = views
    np.testing.assert_allclose(bright.luminance, 10.0 * dim.luminance, rtol=1e-6)
    np.testing.assert_array_equal(bright.depth, dim.depth)
    shift = log_intensity(bright.luminance, eps) - log_intensity(dim.luminance, eps)
    y = dim.luminance.astype(np.float64)
    np.testing.assert_allclose(shift, np.log((10.0 * y + eps) / (y + eps)), atol=1e-6)
    negligible = y > 100.0 * eps
    assert 0.1 < negligible.mean() < 0.9                 # the test sees both kinds of pixel
    assert np.abs(shift[negligible] - math.log(10.0)).max() < 0.01
    assert np.abs(shift[~negligible] - math.log(10.0)).max() > 0.01  # the dark current shows


def test_log_of_photocurrent_plus_dark_current_gives_the_same_events():
    """log(R Y + I_dark) = log R + log(Y + log_eps): the constant moves no threshold crossing,
    so the emulator fires the same events (same pixels, polarities, times within 1 ns)."""
    rng = np.random.default_rng(4)
    times = np.linspace(0.0, 0.02, 21)
    luminance = 50.0 * np.exp(np.cumsum(rng.normal(0.0, 0.15, (21, 12, 16)), axis=0))
    params = EventParams()
    ours = emulate_events(log_intensity(luminance, params.log_eps), times, params)
    current = np.log(params.photocurrent(luminance) + params.dark_current)
    physical = emulate_events(current, times, params)
    assert len(ours) > 100
    assert len(physical) == len(ours)
    for name in ("x", "y", "p"):
        np.testing.assert_array_equal(physical[name], ours[name])
    assert np.abs(physical["t"] - ours["t"]).max() <= 1


def test_dvs_constants_follow_from_the_documented_chain():
    """Responsivity = pi T / (4 N^2) A S; the dark luminance is the dark current over it."""
    assert image_illuminance(1.0, f_number=2.0, transmission=0.9) == pytest.approx(
        math.pi * 0.9 / 16.0)
    assert DVS_RESPONSIVITY == pytest.approx(responsivity(0.22 * 18.5e-6 ** 2, 2.0))
    assert DVS_DARK_LUMINANCE * DVS_RESPONSIVITY == pytest.approx(DVS_DARK_CURRENT)
    assert EventParams().log_eps == DVS_DARK_LUMINANCE
    assert EventParams().dark_current == pytest.approx(4e-15)
    # A white sheet in office light (100 cd/m^2) gives about a picoampere.
    assert 0.3e-12 < photocurrent(100.0) < 3e-12
    with pytest.raises(ValueError, match="f_number must be a finite number"):
        image_illuminance(1.0, f_number=0.0)
    with pytest.raises(ValueError, match="EventParams.responsivity must be a finite number"):
        EventParams(responsivity=-1.0)


@pytest.mark.parametrize("old, new", [("irradiance", "illuminance_lux"),
                                      ("intensity", "intensity_cd")])
def test_lights_in_old_arbitrary_units_are_refused_naming_the_key(old, new):
    lights = (f'[[lights]]\ntype = "{"directional" if old == "irradiance" else "point"}"\n'
              f'{"direction" if old == "irradiance" else "position"} = [0.0, 1.0, 0.0]\n'
              f"{old} = 2.0\n")
    with pytest.raises(SceneError) as info:
        parse_scene(scene_text(WHITE_PLANE, lights=lights))
    message = str(info.value)
    assert "\n" not in message
    assert f"[[lights]][0].{old}: lights are photometric" in message and f"'{new}'" in message


def test_a_light_brighter_than_sunlight_is_refused():
    with pytest.raises(SceneError, match=r"\[\[lights\]\]\[0\]\.illuminance_lux: 2e\+06 lux is "
                                         r"brighter than the 200,000 lux"):
        parse_scene(scene_text(WHITE_PLANE, lights=_directional(2e6)))
    with pytest.raises(SceneError, match=r"intensity_cd: 1e\+08 cd is brighter"):
        parse_scene(scene_text(WHITE_PLANE, lights=_point(1e8)))


def _illuminance_at(scene, point: np.ndarray) -> tuple[float, float]:
    """(spot-lit lux, other lux) at ``point`` on a surface facing each light, no shadows."""
    spot, other = 0.0, 0.0
    for light in scene.lights:
        value = float(np.mean(light.intensity))
        if light.kind == "directional":
            other += value
            continue
        lux = value / float(np.sum((point - light.position) ** 2))
        if light.kind == "spot":
            spot += lux
        else:
            other += lux
    return spot, other


@pytest.mark.parametrize("name", sorted(builtin_scenes()))
def test_every_builtin_twin_declares_a_plausible_illuminance(name):
    """Office twins: 300-500 lux on their first object (a wall, floor or poster). HDR twins:
    their spot gives at least 2.5 decades more than the fill light elsewhere, which stays at
    5 lux or more (a grey card there is above the DVS's dark-current luminance)."""
    scene = load_scene(builtin_scenes()[name])
    spot, other = _illuminance_at(scene, scene.objects[0].center)
    if "hdr" in name:
        assert spot / other > 10 ** 2.5
        assert lambertian_luminance(other, 0.5) > DVS_DARK_LUMINANCE
    else:
        assert spot == 0.0
        assert 300.0 <= other <= 500.0


def test_hdr_twin_dark_half_fires_within_a_factor_3_of_the_bright_half():
    """slider_hdr_close seen by a 48x36 crop of the DAVIS240C (its fx, fy): 0.2 s in the fill
    light (t = 0.05 s, camera at x = -0.32 m) and 0.2 s inside the spot (t = 4.05 s, x =
    0.08 m). The poster's texture repeats every 0.4 m, so both windows see the same texture
    moving the same way under lights three decades apart: a logarithmic sensor fires about
    as often in both; only the dark current (0.43 cd/m^2, half the crop's median luminance in
    the fill light) thins the dark half. Rendered at 1 kHz (0.09 px of motion per render),
    ideal sensor, C = 0.2. Measured: 1.15 times fewer events in the dark (2.1 times with
    issue 14's lights, ten times dimmer; 6.7 times with the former arbitrary units;
    ``benchmarks/bench_radiometry.py``)."""
    text = resolve_scene("slider_hdr_close").read_text()
    crop = ("width = 48\nheight = 36\nfx = 199.092366542\nfy = 198.82882047\n"
            "cx = 23.5\ncy = 17.5\n")
    text, swapped = re.subn(r'preset = "davis240c"\n', crop, text)
    assert swapped == 1
    renderer = Renderer(parse_scene(text), spp=4)
    params = EventParams()
    rates, medians = [], []
    for t0 in (0.05, 4.05):
        times = t0 + np.arange(201) * 1e-3
        luminance = np.stack([renderer.luminance(t) for t in times])
        events = emulate_events(log_intensity(luminance, params.log_eps), times, params)
        rates.append(len(events) / (0.2 * 48 * 36))
        medians.append(float(np.median(luminance)))
    dark, bright = rates
    assert medians[1] / medians[0] > 300                 # 2.5 decades apart
    assert dark > 0 and 1 / 3 <= dark / bright <= 3, (dark, bright)


def test_realistic_noise_follows_the_illuminance_in_cd_per_m2():
    """The ``realistic`` preset's cutoff reaches 200 Hz from white under ~400 lux
    (100 cd/m^2) and falls in proportion below, down to v2e's 20/275 floor (14.5 Hz); its
    background rate is 0.1 Hz there and rises to 0.4 Hz (1 / 0.25) in the dark (v2e's law)."""
    from sim.noise import cutoff_frequency, noise_preset, shot_noise_rate_map

    realistic = noise_preset("realistic")
    lux = np.array([[400.0, 40.0, 4.0, 0.0]])
    luminance = lambertian_luminance(lux, math.pi / 4.0)       # 100, 10, 1, 0 cd/m^2
    np.testing.assert_allclose(cutoff_frequency(luminance, realistic),
                               [[200.0, 20.0, 200.0 * 20.0 / 275.0, 200.0 * 20.0 / 275.0]])
    np.testing.assert_allclose(shot_noise_rate_map(luminance, realistic),
                               [[0.1, 0.1 * (4.0 - 3.0 * 0.1), 0.1 * (4.0 - 3.0 * 0.01), 0.4]])
