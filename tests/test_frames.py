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
    assert (params.rate, params.exposure, params.exposure_samples) == (24.0, 0.005, None)
    assert (params.gamma, params.gain, params.sensor) == (None, None, "ideal")
    assert params.ideal and params.output_gamma == 2.2


def test_integer_values_are_stored_as_floats():
    params = FrameParams(rate=20, gain=2, gamma=1)
    assert isinstance(params.rate, float) and isinstance(params.gain, float)
    assert isinstance(params.gamma, float) and params.rate == 20.0


def test_a_sensor_name_becomes_its_preset_and_its_gamma_is_linear():
    from sim.frame_sensor import FRAME_SENSORS

    params = FrameParams(sensor="machine_vision")
    assert params.sensor is FRAME_SENSORS["machine_vision"] and not params.ideal
    assert params.output_gamma == 1.0 and FrameParams(sensor="machine_vision",
                                                      gamma=2.0).output_gamma == 2.0
    assert params.with_sensor("ideal").output_gamma == 2.2          # gamma follows the sensor


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"rate": 0.0}, r"FrameParams\.rate must be a finite number > 0, got 0\.0"),
    ({"rate": math.nan}, r"FrameParams\.rate must be a finite number > 0"),
    ({"rate": "24"}, r"FrameParams\.rate must be a number, got '24'"),
    ({"exposure": -0.001}, r"FrameParams\.exposure must be a finite number > 0"),
    ({"rate": 24.0, "exposure": 0.05}, r"exposure must be at most the frame period"),
    ({"exposure_samples": 0}, r"FrameParams\.exposure_samples must be an integer >= 1 or None "
                              r"\(sized from the motion\), got 0"),
    ({"exposure_samples": 2.5}, r"exposure_samples must be an integer"),
    ({"exposure_samples": True}, r"exposure_samples must be an integer"),
    ({"gamma": 0.0}, r"FrameParams\.gamma must be a finite number > 0"),
    ({"gain": -1.0}, r"FrameParams\.gain must be a finite number > 0"),
    ({"sensor": "davis"}, r"FrameParams\.sensor must be one of ideal, davis240c_aps, "
                         r"machine_vision or a FrameSensor, got 'davis'"),
    ({"sensor": 3}, r"FrameParams\.sensor must be a preset name or a FrameSensor, got 3"),
    ({"sensor": "davis240c_aps", "gain": 2.0}, r"FrameParams\.gain is the ideal camera's"),
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
    # not given: a whole frame's 4 (WHOLE_FRAME_EXPOSURE_SAMPLES); count overrides either
    assert len(exposure_sample_times(1.0, FrameParams(exposure=0.004))) == 4
    np.testing.assert_allclose(exposure_sample_times(1.0, params, count=2), [0.999, 1.001],
                               atol=1e-15)


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
    frame = luminance_to_frame(luminance, 1.0, params)
    # sqrt(0.25) = 0.5 -> 127.5 -> 128 (half up); saturated -> 255; sqrt(1/16) * 255 = 63.75 -> 64
    assert frame.dtype == np.uint8
    assert frame.tolist() == [[0, 128, 255, 255, 64]]


def test_default_gamma_and_gain_scaling():
    frame = luminance_to_frame(np.array([[0.25]], np.float32), 2.0, FrameParams())
    # 255 * 0.5 ** (1 / 2.2) = 255 * 0.72974 = 186.08
    assert frame.tolist() == [[186]]


def test_ideal_frames_are_todays_formula_byte_for_byte():
    # The ideal camera before the sensor model, written out: gain, clip, gamma 2.2, half up.
    luminance = np.random.default_rng(5).uniform(0, 2, (36, 48)).astype(np.float32)
    old = 255.0 * np.clip(0.6 * luminance.astype(np.float64), 0.0, 1.0) ** (1.0 / 2.2)
    expected = np.clip(np.floor(old + 0.5), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(luminance_to_frame(luminance, 0.6, FrameParams()), expected)


def test_exposure_samples_follow_a_shorter_auto_exposure():
    params = FrameParams(exposure=0.004, exposure_samples=2)
    np.testing.assert_allclose(exposure_sample_times(1.0, params, 0.002), [0.9995, 1.0005],
                               atol=1e-15)
    with pytest.raises(ValueError, match="longer than the frame's longest exposure"):
        exposure_sample_times(1.0, params, 0.005)


def test_max_exposure_bounds_auto_exposure_and_leaves_the_ideal_camera_alone():
    """Issue 21: a sensor's auto-exposure may run longer than the ideal camera's exposure; its
    frames are laid out with the longest one, the ideal camera's as before."""
    ideal = FrameParams(rate=24.0, exposure=0.005, max_exposure=0.04)
    assert ideal.longest_exposure == 0.005
    np.testing.assert_allclose(frame_times(0.5, ideal), frame_times(0.5, FrameParams()))
    davis = ideal.with_sensor("davis240c_aps")
    assert davis.longest_exposure == 0.04
    times = frame_times(0.5, davis)
    np.testing.assert_allclose(times, 0.02 + np.arange(12) / 24.0, atol=1e-15)
    assert times[-1] + 0.02 <= 0.5
    np.testing.assert_allclose(exposure_sample_times(1.0, davis, 0.03),
                               [0.98875, 0.99625, 1.00375, 1.01125], atol=1e-15)
    with pytest.raises(ValueError, match="longer than the frame's longest exposure 0.04 s"):
        exposure_sample_times(1.0, davis, 0.041)
    with pytest.raises(ValueError, match="FrameParams.max_exposure must be at most the frame "
                                         "period"):
        FrameParams(rate=24.0, max_exposure=0.05)


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
        luminance_to_frame(luminance, gain, NOISELESS_LINEAR)
