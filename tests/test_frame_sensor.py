"""sim.frame_sensor: electrons, shot / read / dark noise, fixed pattern, vignetting, exposure.

Every expected value comes from the model's statistics written out by hand (Poisson variance =
mean; independent noises add their variances; rounding to integers adds 1/12 DN^2), never from
the code's own output. Flat fields of 256 x 256 pixels: a sample variance of N = 65,536
Gaussian-like values has a relative standard error sqrt(2 / N) = 0.55 %, so 3 % is > 5 sigma.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sim.frame_sensor import (
    AE_TARGET,
    FRAME_SENSORS,
    FixedPattern,
    FrameSensor,
    fixed_pattern,
    next_exposure,
    sensor_frame,
    settled_exposure,
    vignetting_map,
)

SIZE = (256, 256)
# A sensor whose numbers make every term visible: 1e5 e-/s per cd/m^2, a 10 ke- well,
# 30 e- read noise, 2e5 e-/s dark current; no fixed pattern, no vignetting.
CLEAN = FrameSensor(responsivity=1e5, full_well=10000.0, read_noise=30.0, dark_current=2e5,
                    column_fpn=0.0, pixel_fpn=0.0, prnu=0.0, vignetting="none")
DN_PER_E = 255.0 / CLEAN.full_well


def _flat_pattern(shape=SIZE) -> FixedPattern:
    return FixedPattern(gain=np.ones(shape), offset=np.zeros(shape))


def _frame(luminance: float, exposure: float, sensor=CLEAN, pattern=None, seed=0) -> np.ndarray:
    flat = np.full(SIZE, luminance, np.float32)
    pattern = pattern if pattern is not None else _flat_pattern()
    return sensor_frame(flat, exposure, sensor, pattern, 1.0,
                        np.random.default_rng(seed)).astype(np.float64)


@pytest.mark.parametrize("luminance", [40.0, 0.0])
def test_flat_field_mean_and_variance_are_shot_read_and_dark_noise(luminance):
    exposure = 1e-3
    electrons = (CLEAN.responsivity * luminance + CLEAN.dark_current) * exposure  # 4,200 or 200
    frame = _frame(luminance, exposure)
    variance = DN_PER_E ** 2 * (electrons + CLEAN.read_noise ** 2) + 1 / 12
    # the mean of N values has standard error sqrt(variance / N): 5 of them
    assert frame.mean() == pytest.approx(DN_PER_E * electrons,
                                         abs=5 * math.sqrt(variance / frame.size))
    assert frame.var() == pytest.approx(variance, rel=0.03)


def test_dark_current_has_its_own_shot_noise():
    # No light, no read noise: 2,000 e- of dark charge, Poisson: variance 2,000 e-^2, 1.14 DN
    # rms (a dark current without shot noise would give a constant 51 DN, variance 0). Above
    # about 1 DN rms, rounding adds 1/12 DN^2 and no bias (Sheppard; the error falls as
    # exp(-2 pi^2 sigma^2), 1e-11 here).
    frame = _frame(0.0, 1e-3, replace(CLEAN, read_noise=0.0, dark_current=2e6))
    variance = DN_PER_E ** 2 * 2000 + 1 / 12
    assert frame.mean() == pytest.approx(DN_PER_E * 2000,
                                         abs=5 * math.sqrt(variance / frame.size))
    assert frame.var() == pytest.approx(variance, rel=0.03)


def test_a_saturated_pixel_clips_at_full_well_before_read_noise():
    # 10x the well on average: the charge is the full well exactly, then N(0, 30^2) e- of read
    # noise, then the ADC clips at 255: the mean lacks E[max(0, -N)] = 30 / sqrt(2 pi) e-.
    frame = _frame(100.0, 1e-2)
    assert frame.max() == 255.0
    expected = 255.0 - DN_PER_E * CLEAN.read_noise / math.sqrt(2 * math.pi)
    assert frame.mean() == pytest.approx(expected, abs=0.03)
    assert (_frame(100.0, 1e-2, replace(CLEAN, read_noise=0.0)) == 255).all()


def test_fixed_pattern_is_the_same_in_every_frame_and_differs_across_seeds():
    sensor = replace(CLEAN, column_fpn=40.0, pixel_fpn=60.0, prnu=0.02)
    ones = np.ones(SIZE)
    a, b, c = (fixed_pattern(sensor, ones, seed) for seed in (7, 7, 8))
    np.testing.assert_array_equal(a.offset, b.offset)
    np.testing.assert_array_equal(a.gain, b.gain)
    assert np.abs(a.offset - c.offset).mean() > 10 and (a.gain != c.gain).all()
    # Its statistics: column offsets constant down a column, spread as drawn.
    columns = a.offset.mean(axis=0)
    assert columns.std() == pytest.approx(40.0, rel=0.15)          # 256 columns: ~4.4 % error
    assert (a.offset - columns).std() == pytest.approx(60.0, rel=0.03)
    assert a.gain.std() == pytest.approx(0.02, rel=0.03)
    # Two frames of the same sensor: their difference holds temporal noise only (the fixed
    # pattern cancels); each frame's own spread holds both.
    luminance, exposure = 40.0, 1e-3
    f1 = _frame(luminance, exposure, sensor, a, seed=1)
    f2 = _frame(luminance, exposure, sensor, a, seed=2)
    electrons = (sensor.responsivity * luminance + sensor.dark_current) * exposure
    temporal = DN_PER_E ** 2 * (electrons + sensor.read_noise ** 2) + 1 / 12
    fixed = DN_PER_E ** 2 * (40.0 ** 2 + 60.0 ** 2 + (0.02 * 4000.0) ** 2)
    assert (f1 - f2).var() == pytest.approx(2 * temporal, rel=0.03)
    assert f1.var() == pytest.approx(temporal + fixed, rel=0.06)   # + 256-column sampling


def test_cos4_vignetting_falls_off_as_specified():
    sensor = replace(CLEAN, vignetting="cos4")
    v = vignetting_map(sensor, width=201, height=101, fx=100.0, fy=50.0, cx=100.0, cy=50.0)
    assert v.shape == (101, 201) and v[50, 100] == 1.0                      # on the axis
    assert v[50, 200] == pytest.approx(0.25, abs=1e-12)       # 45 deg: cos^4 = (1/sqrt 2)^4
    assert v[0, 100] == pytest.approx(0.25, abs=1e-12)        # fy differs: still 45 deg
    assert v[0, 200] == pytest.approx(1 / 9, abs=1e-12)       # tan^2 = 2: (1 / 3)^2
    assert (vignetting_map(CLEAN, 20, 10, 5.0, 5.0, 10.0, 5.0) == 1.0).all()  # none
    # Through the sensor: the corner collects a quarter of the centre's light.
    v = vignetting_map(sensor, *SIZE, 128.0, 128.0, 0.0, 0.0)
    pattern = FixedPattern(gain=v, offset=np.zeros(SIZE))
    frame = _frame(80.0, 1e-3, replace(sensor, dark_current=0.0, read_noise=0.0), pattern)
    corner, centre = frame[118:138, 118:138].mean(), frame[:10, :10].mean()
    expected = v[118:138, 118:138].mean() / v[:10, :10].mean()
    assert corner / centre == pytest.approx(expected, rel=0.01)


def test_responsivity_is_the_camera_equation():
    h, c = 6.62607015e-34, 299792458.0
    photons_per_lux = 555e-9 / (683.0 * h * c)                       # 4.09e15 s^-1 m^-2
    davis = FRAME_SENSORS["davis240c_aps"]
    expected = 0.1 * (18.5e-6) ** 2 * photons_per_lux * math.pi * 0.9 / (4 * 2.0 ** 2)
    assert davis.responsivity_e == pytest.approx(expected, rel=1e-12)
    assert davis.responsivity_e == pytest.approx(2.474e4, rel=1e-3)
    assert replace(davis, f_number=4.0).responsivity_e == pytest.approx(expected / 4)
    assert replace(davis, responsivity=123.0).responsivity_e == 123.0


def test_davis_preset_follows_the_published_dynamic_range_and_fpn():
    davis = FRAME_SENSORS["davis240c_aps"]
    assert 20 * math.log10(davis.full_well / davis.read_noise) == pytest.approx(51.0, abs=0.01)
    fpn = math.hypot(davis.column_fpn, davis.pixel_fpn) / davis.full_well
    assert fpn == pytest.approx(0.005, rel=1e-9)


def test_auto_exposure_rule():
    frame = np.full((10, 10), round(0.2 * 255), np.uint8)       # level 0.2: twice too dark
    assert next_exposure(frame, 1e-3, CLEAN, 1.0, 1.0) == pytest.approx(2e-3, rel=0.01)
    frame = np.full((10, 10), 255, np.uint8)                    # saturated: halve
    assert next_exposure(frame, 1e-3, CLEAN, 1.0, 1.0) == pytest.approx(0.5e-3)
    frame = np.full((10, 10), 0, np.uint8)                      # black: double, up to the max
    assert next_exposure(frame, 1e-3, CLEAN, 1.0, 1.5e-3) == 1.5e-3
    frame = np.full((10, 10), 128, np.uint8)                    # gamma 2 undone: 0.252 linear
    assert next_exposure(frame, 1e-3, CLEAN, 2.0, 1.0) == pytest.approx(
        1e-3 * AE_TARGET / (128 / 255) ** 2)
    assert next_exposure(np.full((2, 2), 255, np.uint8), 1e-5, CLEAN, 1.0, 1.0) == \
        CLEAN.min_exposure


def test_settled_exposure_puts_a_flat_field_at_the_target_and_tracks_a_step():
    pattern = _flat_pattern()
    exposure = settled_exposure(np.full(SIZE, 40.0), CLEAN, pattern, 0.04)
    rate = CLEAN.responsivity * 40.0 + CLEAN.dark_current
    assert rate * exposure == pytest.approx(AE_TARGET * CLEAN.full_well, rel=1e-9)
    # The scene brightens 8x: the controller halves per frame while saturated, then lands.
    levels, e = [], exposure
    for k in range(6):
        frame = _frame(320.0, e, seed=k).astype(np.uint8)
        levels.append(frame.mean() / 255)
        e = next_exposure(frame, e, CLEAN, 1.0, 0.04)
    assert levels[0] == pytest.approx(1.0, abs=0.01)              # saturated at first
    assert all(abs(level - AE_TARGET) < 0.01 for level in levels[-2:])


def test_auto_exposure_divides_out_the_luminance_scale():
    # 1000x the luminance, 1/1000 of the exposure: the same electrons, the same frames. Exact
    # where the dark current and the offsets are negligible (here: zero); in the dark, the
    # dark current's share grows, as on a real sensor.
    sensor = replace(FRAME_SENSORS["davis240c_aps"], dark_current=0.0, column_fpn=0.0,
                     pixel_fpn=0.0)
    scene = np.random.default_rng(3).uniform(0.2, 1.0, SIZE)
    pattern = fixed_pattern(sensor, np.ones(SIZE), 1)               # PRNU only
    e1 = settled_exposure(scene, sensor, pattern, 10.0)
    e2 = settled_exposure(scene * 1000, sensor, pattern, 10.0)
    assert e1 / e2 == pytest.approx(1000, rel=1e-9)
    f1 = sensor_frame(scene, e1, sensor, pattern, 1.0, np.random.default_rng(4))
    f2 = sensor_frame(scene * 1000, e2, sensor, pattern, 1.0, np.random.default_rng(4))
    assert np.abs(f1.astype(int) - f2).max() <= 1        # rounding of e1 * R * L only


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"full_well": 0.0}, r"FrameSensor\.full_well must be a finite number > 0"),
    ({"quantum_efficiency": 1.5}, r"quantum_efficiency must be a fraction in \(0, 1\]"),
    ({"prnu": 0.5}, r"prnu must be a fraction in \[0, 0\.5\)"),
    ({"read_noise": -1.0}, r"read_noise must be a finite number >= 0"),
    ({"vignetting": "cos3"}, r"vignetting must be one of cos4, none, got 'cos3'"),
    ({"auto_exposure": 1}, r"auto_exposure must be true or false"),
    ({"responsivity": 0.0}, r"responsivity must be a finite number > 0"),
])
def test_bad_sensor_parameters_name_the_field(kwargs, message):
    with pytest.raises(ValueError, match=message):
        FrameSensor(**kwargs)


def test_bad_inputs_are_refused():
    pattern = _flat_pattern((4, 4))
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"luminance has shape \(4, 5\)"):
        sensor_frame(np.ones((4, 5)), 1e-3, CLEAN, pattern, 1.0, rng)
    with pytest.raises(ValueError, match="finite and >= 0"):
        sensor_frame(-np.ones((4, 4)), 1e-3, CLEAN, pattern, 1.0, rng)
    with pytest.raises(ValueError, match="rng must be a numpy.random.Generator"):
        sensor_frame(np.ones((4, 4)), 1e-3, CLEAN, pattern, 1.0, None)
    with pytest.raises(ValueError, match="exposure must be a finite number > 0"):
        sensor_frame(np.ones((4, 4)), 0.0, CLEAN, pattern, 1.0, rng)
