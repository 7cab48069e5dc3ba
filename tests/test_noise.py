"""sim.noise: v2e's sensor non-idealities as seeded, vectorised functions.

Statistical tests use sizes that put the Poisson error well below the tolerance (the standard
error is written beside each check), with fixed seeds, so they are deterministic and would
only fail if a rate were badly off.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sim.noise import (
    NOISE_PRESETS,
    THRESHOLD_FLOOR,
    NoiseParams,
    background_events,
    cutoff_frequency,
    drifted_inputs,
    hot_pixel_events,
    hot_pixel_mask,
    leak_drift,
    leak_rate_map,
    lowpass_exponent,
    merge_events,
    noise_preset,
    ramp_crossing,
    ramp_response,
    ramp_turn,
    shot_noise_rate_map,
    threshold_map,
)

EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
SHAPE = (180, 240)                                            # DAVIS240C
SECOND = 1_000_000_000


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _events(t, x=0, y=0, p=1) -> np.ndarray:
    t = np.asarray(t, dtype=np.int64)
    events = np.empty(len(t), EVENT_DTYPE)
    events["t"], events["x"], events["y"], events["p"] = t, x, y, p
    return events


# --- parameters and presets --------------------------------------------------------------------

def test_default_params_are_the_ideal_preset_and_have_no_noise():
    assert NoiseParams() == noise_preset("ideal") == NOISE_PRESETS["ideal"]
    ideal = noise_preset("ideal")
    assert not ideal.has_noise
    assert ideal.shot_noise_rate == ideal.leak_rate == ideal.hot_pixel_fraction == 0
    assert ideal.cutoff_hz == ideal.threshold_sigma == ideal.refractory_period == 0
    assert ideal.initial_phase is False


def test_realistic_preset_has_every_noise():
    realistic = noise_preset("realistic")
    assert realistic.has_noise
    assert realistic.shot_noise_rate == pytest.approx(0.1)
    assert realistic.leak_rate == pytest.approx(0.1)
    assert realistic.hot_pixel_fraction == pytest.approx(1e-4)
    assert realistic.hot_pixel_rate == pytest.approx(10.0)
    assert realistic.cutoff_hz == pytest.approx(200.0)
    assert realistic.threshold_sigma == pytest.approx(0.03)
    assert realistic.refractory_period == pytest.approx(0.5e-3)
    assert realistic.initial_phase is True


def test_unknown_preset_lists_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown noise preset 'noisy'; expected one of "
                                         r"\['ideal', 'realistic'\]"):
        noise_preset("noisy")


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"shot_noise_rate": -1.0}, r"NoiseParams\.shot_noise_rate must be a finite number in "
                                r"\[0, inf\), got -1\.0"),
    ({"leak_rate": math.nan}, r"NoiseParams\.leak_rate must be a finite number"),
    ({"cutoff_hz": "200"}, r"NoiseParams\.cutoff_hz must be a number, got '200'"),
    ({"threshold_sigma": True}, r"NoiseParams\.threshold_sigma must be a number"),
    ({"hot_pixel_fraction": 1.5}, r"NoiseParams\.hot_pixel_fraction must be a finite number "
                                  r"in \[0, 1\]"),
    ({"leak_jitter": 1.0}, r"NoiseParams\.leak_jitter must be a finite number in \[0, 1\)"),
    ({"shot_noise_intensity_ref": 0.0}, r"shot_noise_intensity_ref must be a finite number "
                                        r"in \(0, inf\)"),
    ({"shot_noise_bright_factor": 0.0}, r"shot_noise_bright_factor must be a finite number "
                                        r"in \(0, 1\]"),
    ({"cutoff_min_fraction": 2.0}, r"cutoff_min_fraction must be a finite number in \(0, 1\]"),
    ({"initial_phase": 1}, r"NoiseParams\.initial_phase must be a bool, got 1"),
])
def test_bad_parameters_name_the_field(kwargs, message):
    with pytest.raises(ValueError, match=message):
        NoiseParams(**kwargs)


def test_params_are_frozen_and_store_floats():
    params = NoiseParams(hot_pixel_rate=10)
    assert isinstance(params.hot_pixel_rate, float)
    with pytest.raises(AttributeError):
        params.leak_rate = 1.0


# --- contrast thresholds -----------------------------------------------------------------------

def test_threshold_map_has_the_requested_mean_and_std():
    c_on, c_off = threshold_map(SHAPE, 0.2, 0.3, 0.03, _rng())
    assert c_on.shape == c_off.shape == SHAPE
    assert c_on.dtype == c_off.dtype == np.float64
    # 43 200 samples: standard error of the mean 1.4e-4, of the std 0.34 %.
    assert c_on.mean() == pytest.approx(0.2, abs=1e-3)
    assert c_off.mean() == pytest.approx(0.3, abs=1e-3)
    assert c_on.std() == pytest.approx(0.03, rel=0.02)
    assert c_off.std() == pytest.approx(0.03, rel=0.02)
    assert abs(np.corrcoef(c_on.ravel(), c_off.ravel())[0, 1]) < 0.02   # independent maps


def test_threshold_map_floors_small_values():
    c_on, c_off = threshold_map(SHAPE, 0.1, 0.1, 0.2, _rng())
    for c in (c_on, c_off):
        assert c.min() >= THRESHOLD_FLOOR
        # P(N(0.1, 0.2^2) < 0.01) = Phi(-0.45) = 0.326
        assert np.mean(c == THRESHOLD_FLOOR) == pytest.approx(0.326, abs=0.01)
    c_on, _ = threshold_map(SHAPE, 0.1, 0.1, 0.2, _rng(), floor=0.05)
    assert c_on.min() == 0.05


def test_threshold_map_without_mismatch_is_exact_and_seeded():
    # Exactly C (not float32(C)), so the ideal sensor's crossing times are not perturbed.
    c_on, c_off = threshold_map((4, 5), 0.2, 0.25, 0.0, _rng())
    assert np.all(c_on == 0.2) and np.all(c_off == 0.25)
    a = threshold_map(SHAPE, 0.2, 0.2, 0.03, _rng(7))
    b = threshold_map(SHAPE, 0.2, 0.2, 0.03, _rng(7))
    c = threshold_map(SHAPE, 0.2, 0.2, 0.03, _rng(8))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])


@pytest.mark.parametrize(("args", "message"), [
    (((4, 5), 0.0, 0.2, 0.03), r"threshold_map\.C_on must be a finite number in \(0, inf\)"),
    (((4, 5), 0.2, 0.2, -0.1), r"threshold_map\.sigma must be a finite number in \[0, inf\)"),
    (((4,), 0.2, 0.2, 0.03), r"shape must be \(height, width\)"),
    (((0, 5), 0.2, 0.2, 0.03), r"shape must be \(height, width\) with sides in \[1, 65536\]"),
])
def test_threshold_map_rejects_bad_input(args, message):
    with pytest.raises(ValueError, match=message):
        threshold_map(*args, _rng())


def test_a_legacy_random_state_is_rejected():
    with pytest.raises(ValueError, match=r"rng must be a numpy\.random\.Generator"):
        threshold_map((4, 5), 0.2, 0.2, 0.03, np.random.RandomState(0))


# --- background activity -----------------------------------------------------------------------

def _measured_rate(events, shape, seconds) -> float:
    return len(events) / (shape[0] * shape[1] * seconds)


def test_background_rate_on_a_static_scene_matches_the_configured_rate():
    params = NoiseParams(shot_noise_rate=0.25)
    luminance = np.full(SHAPE, params.shot_noise_intensity_ref)
    events = background_events(0, 10 * SECOND, luminance, params, _rng())
    # Expected 108 000 events: Poisson standard error 0.3 %.
    assert _measured_rate(events, SHAPE, 10.0) == pytest.approx(0.25, rel=0.10)
    assert _measured_rate(events, SHAPE, 10.0) == pytest.approx(0.25, rel=0.015)
    # Half ON, half OFF: standard error 0.0015.
    assert np.mean(events["p"] == 1) == pytest.approx(0.5, abs=0.01)
    assert set(np.unique(events["p"])) == {-1, 1}


def test_background_events_are_a_poisson_process_per_pixel():
    params = NoiseParams(shot_noise_rate=0.25)
    events = background_events(0, 10 * SECOND, np.ones(SHAPE), params, _rng(1))
    assert events.dtype == EVENT_DTYPE
    assert np.all(np.diff(events["t"]) >= 0)
    assert events["t"].min() >= 0 and events["t"].max() < 10 * SECOND
    assert events["x"].max() < SHAPE[1] and events["y"].max() < SHAPE[0]
    # Times uniform over the interval: mean 0.5, standard error 0.29 / sqrt(108 000) = 0.0009.
    assert np.mean(events["t"] / (10 * SECOND)) == pytest.approx(0.5, abs=0.005)
    # Counts per pixel Poisson: variance / mean = 1 (standard error sqrt(2 / 43 200) = 0.7 %).
    counts = np.bincount(events["y"].astype(np.int64) * SHAPE[1] + events["x"],
                         minlength=SHAPE[0] * SHAPE[1])
    assert counts.var() / counts.mean() == pytest.approx(1.0, abs=0.05)


def test_background_rate_falls_in_bright_light_as_the_documented_law_says():
    params = NoiseParams(shot_noise_rate=0.25, shot_noise_intensity_ref=2.0)
    luminance = np.empty(SHAPE)
    luminance[:, :120] = 0.5                                  # u = 0.25 -> 4 - 3 * 0.25 = 3.25
    luminance[:, 120:] = 4.0                                  # above the reference -> 1
    rates = shot_noise_rate_map(luminance, params)
    assert np.allclose(rates[:, :120], 0.25 * 3.25) and np.allclose(rates[:, 120:], 0.25)
    assert shot_noise_rate_map(np.zeros((1, 1)), params)[0, 0] == pytest.approx(1.0)  # 4x dark
    events = background_events(0, 10 * SECOND, luminance, params, _rng(2))
    dim = np.count_nonzero(events["x"] < 120)
    bright = len(events) - dim
    # 351 000 and 54 000 events: the ratio's standard error is 0.5 %.
    assert dim / bright == pytest.approx(3.25, rel=0.03)


def test_bright_factor_one_makes_the_rate_independent_of_intensity():
    params = NoiseParams(shot_noise_rate=2.0, shot_noise_bright_factor=1.0)
    rates = shot_noise_rate_map(np.array([[0.0, 0.3, 1.0, 50.0]]), params)
    assert np.allclose(rates, 2.0)


def test_background_events_of_many_short_intervals_tile_the_long_one():
    params = NoiseParams(shot_noise_rate=1.0, shot_noise_intensity_ref=1.0)    # np.ones: at ref
    rng = _rng(3)
    chunks = [background_events(k * SECOND // 100, (k + 1) * SECOND // 100, np.ones(SHAPE),
                                params, rng) for k in range(100)]
    for k, chunk in enumerate(chunks):
        assert np.all(chunk["t"] >= k * SECOND // 100)
        assert np.all(chunk["t"] < (k + 1) * SECOND // 100)
    total = sum(len(c) for c in chunks)
    # 43 200 expected events, standard error 0.5 %.
    assert total / (SHAPE[0] * SHAPE[1]) == pytest.approx(1.0, rel=0.03)


def test_background_events_are_seeded():
    params = noise_preset("realistic")
    luminance = np.linspace(0.0, 2.0, SHAPE[0] * SHAPE[1]).reshape(SHAPE)
    a = background_events(5, 2 * SECOND, luminance, params, _rng(11))
    b = background_events(5, 2 * SECOND, luminance, params, _rng(11))
    c = background_events(5, 2 * SECOND, luminance, params, _rng(12))
    assert len(a) > 1000
    assert np.array_equal(a, b)
    assert len(a) != len(c) or not np.array_equal(a, c)


def test_no_background_events_when_off_or_for_an_empty_interval():
    luminance = np.ones(SHAPE)
    assert len(background_events(0, SECOND, luminance, NoiseParams(), _rng())) == 0
    params = NoiseParams(shot_noise_rate=5.0)
    empty = background_events(SECOND, SECOND, luminance, params, _rng())
    assert len(empty) == 0 and empty.dtype == EVENT_DTYPE


@pytest.mark.parametrize(("args", "message"), [
    ((10, 5, np.ones((4, 5))), r"the interval must go forward in time: t1_ns = 5 < t0_ns = 10"),
    ((0.0, 5, np.ones((4, 5))), r"t0_ns must be an integer number of nanoseconds, got 0\.0"),
    ((0, 5, np.ones(5)), r"luminance must be an \(H, W\) array, got shape \(5,\)"),
    ((0, 5, -np.ones((4, 5))), r"luminance must be finite and >= 0"),
    ((0, 5, np.full((4, 5), np.nan)), r"luminance must be finite and >= 0"),
])
def test_background_events_reject_bad_input(args, message):
    with pytest.raises(ValueError, match=message):
        background_events(*args, NoiseParams(shot_noise_rate=1.0), _rng())


def test_background_events_reject_other_params():
    with pytest.raises(ValueError, match=r"params must be a NoiseParams, got dict"):
        background_events(0, 5, np.ones((4, 5)), {"shot_noise_rate": 1.0}, _rng())


# --- hot pixels --------------------------------------------------------------------------------

def test_hot_pixel_mask_is_a_fixed_seeded_set_of_the_requested_size():
    a = hot_pixel_mask(SHAPE, 1e-3, _rng(5))
    b = hot_pixel_mask(SHAPE, 1e-3, _rng(5))
    c = hot_pixel_mask(SHAPE, 1e-3, _rng(6))
    assert a.dtype == np.bool_ and a.shape == SHAPE
    assert a.sum() == round(1e-3 * SHAPE[0] * SHAPE[1]) == 43
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert hot_pixel_mask(SHAPE, 0.0, _rng()).sum() == 0


def test_hot_pixels_fire_on_events_at_the_configured_rate():
    mask = hot_pixel_mask(SHAPE, 1e-3, _rng(5))
    events = hot_pixel_events(0, 10 * SECOND, mask, 10.0, _rng(9))
    assert events.dtype == EVENT_DTYPE
    assert np.all(np.diff(events["t"]) >= 0)
    assert np.all(events["p"] == 1)
    assert np.all(mask[events["y"], events["x"]])             # only the hot pixels fire
    # 4 300 expected events: standard error 1.5 %.
    assert len(events) / (43 * 10.0) == pytest.approx(10.0, rel=0.10)
    # Every hot pixel fires: Poisson(100) falls outside [50, 160] with probability < 1e-6.
    counts = np.bincount(events["y"].astype(np.int64) * SHAPE[1] + events["x"],
                         minlength=SHAPE[0] * SHAPE[1])[mask.ravel()]
    assert counts.min() >= 50 and counts.max() <= 160


def test_hot_pixel_events_are_seeded():
    mask = hot_pixel_mask(SHAPE, 1e-3, _rng(5))
    a = hot_pixel_events(0, SECOND, mask, 10.0, _rng(1))
    b = hot_pixel_events(0, SECOND, mask, 10.0, _rng(1))
    c = hot_pixel_events(0, SECOND, mask, 10.0, _rng(2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_hot_pixel_events_reject_a_non_boolean_mask():
    with pytest.raises(ValueError, match=r"hot_mask must be an \(H, W\) bool array"):
        hot_pixel_events(0, SECOND, np.ones(SHAPE), 10.0, _rng())


# --- photoreceptor low-pass --------------------------------------------------------------------

def test_cutoff_falls_in_proportion_to_luminance_down_to_a_floor():
    params = NoiseParams(cutoff_hz=200.0, cutoff_intensity_ref=2.0, cutoff_min_fraction=0.05)
    f = cutoff_frequency(np.array([[4.0, 2.0, 1.0, 0.2, 0.0]]), params)
    assert np.allclose(f, [[200.0, 200.0, 100.0, 20.0, 10.0]])


def _ramp_reference(f, y0, a, b, x):
    """tau dy/dt = u - y, u = a + (b - a) t / T, x = T / tau: the textbook ramp response,
    y = u - (b - a) / x + (y0 - a + (b - a) / x) exp(-x f)."""
    return a + (b - a) * f - (b - a) / x + (y0 - a + (b - a) / x) * math.exp(-x * f)


@pytest.mark.parametrize("x", [1e-3, 0.3, 1.2566, 12.566, 300.0])
def test_ramp_response_is_the_exact_solution_of_the_filter(x):
    for y0, a, b in [(0.0, 0.0, 1.0), (0.4, 0.0, 1.0), (-0.2, 0.3, -0.5), (1.0, 1.0, 1.0)]:
        for f in (0.0, 0.25, 0.5, 1.0):
            want = _ramp_reference(f, y0, a, b, x)
            assert ramp_response(f, y0, a, b, x) == pytest.approx(want, rel=1e-9, abs=1e-9)
    # Two half steps give one whole step (the solution is exact, not an integrator).
    half = ramp_response(1.0, 0.1, 0.0, 0.5, x / 2)
    assert ramp_response(1.0, half, 0.5, 1.0, x / 2) == pytest.approx(
        ramp_response(1.0, 0.1, 0.0, 1.0, x), abs=1e-12)
    assert ramp_response(0.3, 5.0, 0.0, 1.0, math.inf) == 0.3       # no filter: the input


@pytest.mark.parametrize("x", [1e-3, 0.3, 1.2566, 12.566, 300.0, math.inf])
def test_drifted_inputs_add_the_drift_to_the_filters_output(x):
    """The response to the drifted input is the level plus ``drift * f`` (the textbook ramp
    response, not the code's own), and no drift changes nothing, bit for bit."""
    for y0, a, b in [(0.0, 0.0, 1.0), (0.4, 0.0, 1.0), (-0.2, 0.3, -0.5), (1.0, 1.0, 1.0)]:
        if x == math.inf:
            y0 = a                               # unfiltered, the level is the input
        for drift in (0.0, 1e-4, 0.07, 0.6):
            a2, b2 = drifted_inputs(a, b, x, drift)
            for f in (0.0, 0.1, 0.5, 0.9, 1.0):
                level = a + (b - a) * f if x == math.inf else _ramp_reference(f, y0, a, b, x)
                assert ramp_response(f, y0, a2, b2, x) == pytest.approx(
                    level + drift * f, rel=1e-9, abs=1e-9)
        assert drifted_inputs(a, b, x, 0.0) == (a, b)


def test_ramp_turn_finds_where_the_output_stops_falling():
    # The output starts above a rising input: it falls, then follows the ramp.
    x, y0, a, b = 4.0, 0.5, 0.0, 1.0
    f = ramp_turn(y0, a, b, x)
    assert f == pytest.approx(math.log(1.0 + x * (y0 - a) / (b - a)) / x)
    assert 0.0 < f < 1.0
    h = 1e-6
    assert ramp_response(f - h, y0, a, b, x) > ramp_response(f, y0, a, b, x)
    assert ramp_response(f + h, y0, a, b, x) > ramp_response(f, y0, a, b, x)
    # Below a rising input, or with the filter off, or a turn after the interval: none.
    assert ramp_turn(-0.5, 0.0, 1.0, x) == ramp_turn(y0, a, b, math.inf) == 1.0
    assert ramp_turn(2.0, 0.0, 1.0, 0.1) == 1.0                      # ln(1.2) / 0.1 > 1


@pytest.mark.parametrize("x", [0.05, 1.2566, 40.0])
def test_ramp_crossing_solves_the_response_to_the_tolerance(x):
    y0, a, b = 0.1, 0.0, 1.0
    y1 = ramp_response(1.0, y0, a, b, x)
    for level in np.linspace(y0, y1, 7)[1:-1]:
        f = ramp_crossing(level, y0, a, b, x, 0.0, y0, 1.0, y1, 1e-12)
        assert ramp_response(f, y0, a, b, x) == pytest.approx(level, abs=1e-10)
    # Levels outside the piece give its nearer end.
    assert ramp_crossing(y1 + 1.0, y0, a, b, x, 0.0, y0, 1.0, y1, 1e-12) == 1.0
    assert ramp_crossing(y0 - 1.0, y0, a, b, x, 0.0, y0, 1.0, y1, 1e-12) == 0.0


def test_lowpass_exponent_uses_the_logarithmic_mean_of_the_cutoffs():
    f0 = np.array([[100.0, 50.0, 0.0, 80.0]])
    f1 = np.array([[100.0, 200.0, 30.0, 80.0 * (1 + 1e-9)]])
    x = lowpass_exponent(1e-3, f0, f1)
    # A cutoff exponential in time from 50 to 200 Hz integrates to (200 - 50) / ln 4 Hz.
    assert x[0, 1] == pytest.approx(2 * math.pi * 1e-3 * 150.0 / math.log(4.0), rel=1e-12)
    assert x[0, 0] == pytest.approx(2 * math.pi * 0.1, rel=1e-15)
    assert x[0, 2] == math.inf                                        # filter off
    assert x[0, 3] == pytest.approx(2 * math.pi * 0.08 * (1 + 0.5e-9), rel=1e-14)
    per_pixel = lowpass_exponent(np.array([1e-3, 2e-3]), f0[0, :2], f1[0, :2])
    assert per_pixel[1] == pytest.approx(2 * x[0, 1], rel=1e-12)


@pytest.mark.parametrize(("call", "message"), [
    (lambda: lowpass_exponent(0.0, np.ones(2), np.ones(2)),
     r"lowpass_exponent\.dt must be a finite number in \(0, inf\), got 0\.0"),
    (lambda: lowpass_exponent(np.array([1e-3, -1.0]), np.ones(2), np.ones(2)),
     r"lowpass_exponent\.dt must hold finite numbers > 0"),
    (lambda: lowpass_exponent(1e-3, np.ones(2), np.ones(3)),
     r"cutoff_start and cutoff_end must be finite cutoffs >= 0 Hz of the same shape"),
    (lambda: lowpass_exponent(1e-3, -np.ones(2), np.ones(2)),
     r"cutoff_start and cutoff_end must be finite cutoffs"),
])
def test_lowpass_rejects_bad_input(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# --- leak --------------------------------------------------------------------------------------

def test_leak_rate_map_is_log_normal_around_the_rate():
    params = NoiseParams(leak_rate=0.1, leak_rate_cov_decades=0.1)
    rates = leak_rate_map(SHAPE, params, _rng())
    assert np.median(rates) == pytest.approx(0.1, rel=0.01)
    assert np.log10(rates).std() == pytest.approx(0.1, rel=0.02)
    flat = leak_rate_map(SHAPE, replace(params, leak_rate_cov_decades=0.0), _rng())
    assert np.allclose(flat, 0.1)


def test_leak_drift_moves_the_reference_down_by_rate_times_threshold():
    params = NoiseParams(leak_rate=0.5, leak_jitter=0.1)
    rates = leak_rate_map(SHAPE, params, _rng(1))
    c_on = np.full(SHAPE, 0.2)
    rng = _rng(2)
    total = sum(leak_drift(0.01, c_on, rates, params, rng) for _ in range(100))   # 1 second
    assert np.all(total < 0)
    # Per pixel the jitter averages out: relative error 0.1 / sqrt(100) = 1 % (std).
    assert np.allclose(total / -(rates * 0.2), 1.0, atol=0.06)
    # So a static pixel crosses its ON threshold leak_rate times a second.
    assert np.mean(-total / c_on) == pytest.approx(np.mean(rates), rel=0.01)


def test_leak_drift_is_seeded_and_zero_without_leak():
    params = NoiseParams(leak_rate=0.5)
    rates = leak_rate_map((4, 5), params, _rng(1))
    a = leak_drift(1e-3, 0.2, rates, params, _rng(3))
    b = leak_drift(1e-3, 0.2, rates, params, _rng(3))
    assert np.array_equal(a, b)
    none = leak_drift(1e-3, 0.2, leak_rate_map((4, 5), NoiseParams(), _rng()), NoiseParams(),
                      _rng())
    assert np.all(none == 0)


def test_leak_drift_rejects_a_threshold_map_of_another_shape():
    rates = np.full((4, 5), 0.1)
    with pytest.raises(ValueError, match=r"c_on must be a number or have the shape of "
                                         r"leak_rates \(4, 5\), got shape \(5, 4\)"):
        leak_drift(1e-3, np.full((5, 4), 0.2), rates, NoiseParams(leak_rate=0.1), _rng())


# --- merging -----------------------------------------------------------------------------------

def test_merge_events_is_sorted_and_keeps_every_event():
    rng = _rng(4)
    arrays = [_events(np.sort(rng.integers(0, 1000, n)), x=rng.integers(0, 50, n),
                      y=rng.integers(0, 50, n), p=rng.choice([-1, 1], n))
              for n in (500, 0, 300, 1)]
    merged = merge_events(*arrays)
    assert merged.dtype == EVENT_DTYPE
    assert np.all(np.diff(merged["t"]) >= 0)
    expected = np.sort(np.concatenate(arrays), order=["t", "x", "y", "p"])
    assert np.array_equal(np.sort(merged, order=["t", "x", "y", "p"]), expected)


def test_merge_events_is_stable_for_equal_times():
    a = _events([1, 5, 5], x=[0, 1, 2])
    b = _events([5, 5, 9], x=[10, 11, 12])
    merged = merge_events(a, b)
    assert merged["x"].tolist() == [0, 1, 2, 10, 11, 12]
    merged = merge_events(b, a)
    assert merged["x"].tolist() == [0, 10, 11, 1, 2, 12]


def test_merge_events_of_nothing_is_empty_and_a_single_array_is_copied():
    assert len(merge_events()) == 0 and merge_events().dtype == EVENT_DTYPE
    a = _events([1, 2])
    merged = merge_events(a, _events([]))
    assert np.array_equal(merged, a) and merged is not a


def test_merge_events_rejects_other_arrays():
    with pytest.raises(ValueError, match=r"argument 1 of merge_events must be a 1-D event "
                                         r"array"):
        merge_events(_events([1]), np.zeros(3))


def test_event_dtype_is_the_emulators():
    from sim.events import EVENT_DTYPE as emulator_dtype

    assert emulator_dtype == EVENT_DTYPE
    events = background_events(0, SECOND, np.ones((8, 8)), NoiseParams(shot_noise_rate=50.0),
                               _rng())
    assert events.dtype == emulator_dtype


def test_background_events_of_a_days_long_interval_are_sorted():
    # (t1 - t0) * H * W overflows int64 here, so the events are sorted another way.
    t1 = 3 * 10**14                                               # 3.5 days
    params = NoiseParams(shot_noise_rate=1e-9)
    events = background_events(0, t1, np.ones(SHAPE), params, _rng())
    assert 0 < len(events) < 100                                  # 13 expected
    assert np.all(np.diff(events["t"]) >= 0)
    assert events["t"].min() >= 0 and events["t"].max() < t1
