"""sim.frames: frame timing, exposure sampling, automatic gain and the 8-bit camera response."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.frames import (
    FrameParams,
    auto_gain,
    exposure_sample_times,
    frame_times,
    luminance_to_frame,
)

NOISELESS_LINEAR = FrameParams(gamma=1.0)


# --- FrameParams -----------------------------------------------------------------------------

def test_defaults_are_a_noiseless_davis_like_camera():
    params = FrameParams()
    assert (params.rate, params.exposure, params.exposure_samples) == (24.0, 0.005, 4)
    assert (params.gamma, params.gain, params.full_well, params.read_noise) == (2.2, None, 0.0, 0.0)


def test_integer_values_are_stored_as_floats():
    params = FrameParams(rate=20, gain=2, full_well=1000)
    assert isinstance(params.rate, float) and isinstance(params.gain, float)
    assert isinstance(params.full_well, float) and params.rate == 20.0


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"rate": 0.0}, r"FrameParams\.rate must be a finite number > 0, got 0\.0"),
    ({"rate": math.nan}, r"FrameParams\.rate must be a finite number > 0"),
    ({"rate": "24"}, r"FrameParams\.rate must be a number, got '24'"),
    ({"exposure": -0.001}, r"FrameParams\.exposure must be a finite number > 0"),
    ({"rate": 24.0, "exposure": 0.05}, r"exposure must be at most the frame period"),
    ({"exposure_samples": 0}, r"FrameParams\.exposure_samples must be an integer >= 1, got 0"),
    ({"exposure_samples": 2.5}, r"exposure_samples must be an integer"),
    ({"exposure_samples": True}, r"exposure_samples must be an integer"),
    ({"gamma": 0.0}, r"FrameParams\.gamma must be a finite number > 0"),
    ({"gain": -1.0}, r"FrameParams\.gain must be a finite number > 0"),
    ({"full_well": -5.0}, r"FrameParams\.full_well must be a finite number >= 0"),
    ({"read_noise": math.inf}, r"FrameParams\.read_noise must be a finite number >= 0"),
])
def test_bad_parameters_name_the_field(kwargs, message):
    with pytest.raises(ValueError, match=message):
        FrameParams(**kwargs)


def test_params_are_frozen():
    with pytest.raises(AttributeError):
        FrameParams().rate = 30.0


# --- timing ----------------------------------------------------------------------------------

def test_frame_times_start_exposures_on_the_frame_clock():
    params = FrameParams(rate=10.0, exposure=0.05)
    # exposures [0, .05], [.1, .15], ..., [.9, .95] fit in 1 s; [1.0, 1.05] does not
    np.testing.assert_allclose(frame_times(1.0, params), 0.025 + 0.1 * np.arange(10), atol=1e-15)


def test_an_exposure_ending_exactly_at_duration_is_kept():
    params = FrameParams(rate=10.0, exposure=0.05)
    # (0.35 - 0.05) * 10 is 2.9999999999999996 in floating point: the fourth frame still fits
    assert len(frame_times(0.35, params)) == 4
    assert len(frame_times(0.349, params)) == 3


@pytest.mark.parametrize(("duration", "rate", "exposure"), [
    (1.0, 24.0, 0.005), (0.3, 20.0, 0.01), (2.0 / 3.0, 30.0, 1.0 / 30.0), (5.123, 7.0, 0.1),
])
def test_every_exposure_lies_in_the_interval_and_no_frame_is_missing(duration, rate, exposure):
    params = FrameParams(rate=rate, exposure=exposure)
    times = frame_times(duration, params)
    assert times.dtype == np.float64 and len(times) >= 1
    assert times[0] - exposure / 2 >= 0.0
    assert times[-1] + exposure / 2 <= duration + 1e-9 / rate
    np.testing.assert_allclose(np.diff(times), 1.0 / rate, rtol=1e-12)
    assert times[-1] + 1.0 / rate + exposure / 2 > duration      # the next one would not fit


def test_too_short_duration_gives_no_frames_and_bad_duration_is_rejected():
    params = FrameParams(exposure=0.005)
    assert frame_times(0.004, params).shape == (0,)
    assert frame_times(0.0, params).shape == (0,)
    with pytest.raises(ValueError, match="duration must be a finite number of seconds >= 0"):
        frame_times(-1.0, params)


def test_exposure_samples_are_sub_interval_centres():
    params = FrameParams(exposure=0.004, exposure_samples=4)
    # four 1 ms sub-intervals of [0.998, 1.002]: centres at 0.9985, 0.9995, 1.0005, 1.0015
    np.testing.assert_allclose(exposure_sample_times(1.0, params),
                               [0.9985, 0.9995, 1.0005, 1.0015], atol=1e-15)
    one = exposure_sample_times(0.25, FrameParams(exposure_samples=1))
    assert one.tolist() == [0.25]


# --- gain and response -----------------------------------------------------------------------

def test_auto_gain_maps_the_99th_percentile_to_80_percent_and_ignores_highlights():
    luminance = np.full((100, 100), 2.0, np.float32)
    luminance.flat[:50] = 1000.0                          # 0.5 % specular highlights
    assert auto_gain(luminance) == pytest.approx(0.8 / 2.0)


def test_auto_gain_guards_black_images():
    assert auto_gain(np.zeros((10, 10), np.float32)) == 1.0
    mostly_black = np.zeros((100, 100), np.float32)
    mostly_black.flat[:10] = 4.0                          # 0.1 % lit: the percentile is 0
    assert auto_gain(mostly_black) == pytest.approx(0.8 / 4.0)


def test_gamma_response_on_known_values():
    params = FrameParams(gamma=2.0)
    luminance = np.array([[0.0, 0.25, 1.0, 3.0, 0.0625]], np.float32)
    frame = luminance_to_frame(luminance, 1.0, params, None)
    # sqrt(0.25) = 0.5 -> 127.5 -> 128 (half up); saturated -> 255; sqrt(1/16) * 255 = 63.75 -> 64
    assert frame.dtype == np.uint8
    assert frame.tolist() == [[0, 128, 255, 255, 64]]


def test_default_gamma_and_gain_scaling():
    frame = luminance_to_frame(np.array([[0.25]], np.float32), 2.0, FrameParams(), None)
    # 255 * 0.5 ** (1 / 2.2) = 255 * 0.72974 = 186.08
    assert frame.tolist() == [[186]]


def test_noiseless_frames_do_not_depend_on_or_consume_the_rng():
    luminance = np.random.default_rng(5).uniform(0, 2, (16, 16)).astype(np.float32)
    params = FrameParams()
    rng = np.random.default_rng(1)
    a = luminance_to_frame(luminance, 0.6, params, rng)
    b = luminance_to_frame(luminance, 0.6, params, np.random.default_rng(2))
    c = luminance_to_frame(luminance, 0.6, params, None)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    assert rng.random() == np.random.default_rng(1).random()   # no draw was taken


def test_shot_noise_variance_is_poisson():
    params = FrameParams(gamma=1.0, full_well=1000.0)
    flat = np.full((512, 512), 0.25, np.float32)
    frame = luminance_to_frame(flat, 1.0, params, np.random.default_rng(0)).astype(np.float64)
    # 250 electrons on average, variance 250 (Poisson); 1 electron = 0.255 DN;
    # rounding to integers adds a uniform error of variance 1/12
    assert frame.mean() == pytest.approx(255 * 0.25, abs=0.05)
    assert frame.var() == pytest.approx(0.255**2 * 250 + 1 / 12, rel=0.04)


def test_overexposed_pixels_saturate_despite_shot_noise():
    params = FrameParams(gamma=1.0, full_well=100.0)
    # 3x the full well on average: P(Poisson(300) < 100) is about 1e-40, so every pixel overflows
    frame = luminance_to_frame(np.full((64, 64), 3.0, np.float32), 1.0, params,
                               np.random.default_rng(0))
    assert (frame == 255).all()


def test_read_noise_std_in_digital_numbers():
    params = FrameParams(gamma=1.0, read_noise=2.0)
    flat = np.full((512, 512), 100.0, np.float32)
    frame = luminance_to_frame(flat, 1.0 / 255.0, params, np.random.default_rng(0))
    values = frame.astype(np.float64)
    # 100 DN + N(0, 2^2), rounded: std sqrt(4 + 1/12)
    assert values.mean() == pytest.approx(100.0, abs=0.05)
    assert values.std() == pytest.approx(math.sqrt(4 + 1 / 12), rel=0.03)


def test_noisy_frames_are_reproducible_from_the_seed():
    params = FrameParams(full_well=500.0, read_noise=1.0)
    flat = np.full((32, 32), 0.3, np.float32)
    a = luminance_to_frame(flat, 1.0, params, np.random.default_rng(7))
    b = luminance_to_frame(flat, 1.0, params, np.random.default_rng(7))
    c = luminance_to_frame(flat, 1.0, params, np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert (a != c).any()


@pytest.mark.parametrize(("luminance", "gain", "message"), [
    (np.ones((2, 2, 3), np.float32), 1.0, r"\(H, W\) array, got shape \(2, 2, 3\)"),
    (np.array([[1.0, np.nan]], np.float32), 1.0, "NaN or infinite"),
    (np.array([[1.0, -1.0]], np.float32), 1.0, "negative"),
    (np.ones((2, 2), np.uint8), 1.0, "floating point"),
    (np.ones((2, 2), np.float32), 0.0, r"gain must be a finite number > 0, got 0\.0"),
    (np.ones((2, 2), np.float32), None, "gain must be a number, got None"),
])
def test_bad_input_is_rejected(luminance, gain, message):
    with pytest.raises(ValueError, match=message):
        luminance_to_frame(luminance, gain, NOISELESS_LINEAR, None)


def test_noise_needs_a_generator():
    with pytest.raises(ValueError, match="rng must be a numpy.random.Generator"):
        luminance_to_frame(np.ones((2, 2), np.float32), 1.0, FrameParams(read_noise=1.0), None)
