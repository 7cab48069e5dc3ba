"""The event emulator: exact crossing times, the reference carried across intervals, noise."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from sim.events import (
    EVENT_DTYPE,
    EventEmulator,
    EventParams,
    emulate_events,
    emulate_events_reference,
)
from sim.noise import NoiseParams, noise_preset
from sim.pixel_sampling import PixelEventEmulator
from tests.conftest import filtered_reference_events


def _pixel(values, times):
    """(N, 1, 1) log frames of one pixel."""
    return np.asarray(values, dtype=np.float64)[:, None, None], np.asarray(times, float)


@pytest.mark.parametrize("samples", [2, 12, 111])
def test_ramp_up_fires_exactly_five_on_events_at_their_crossing_times(samples):
    times = np.linspace(0.0, 1.1, samples)
    frames, times = _pixel(1.0 * times, times)                # L rises at 1.0 per second
    events = emulate_events(frames, times)
    assert events.dtype == EVENT_DTYPE
    assert len(events) == 5 and np.all(events["p"] == 1)
    np.testing.assert_allclose(events["t"], [2e8, 4e8, 6e8, 8e8, 1e9], atol=1000)  # 1 us


def test_ramp_down_fires_off_events():
    frames, times = _pixel([0.0, -0.7], [0.0, 0.7])
    events = emulate_events(frames, times)
    assert list(events["p"]) == [-1, -1, -1]
    np.testing.assert_allclose(events["t"], [2e8, 4e8, 6e8], atol=1000)


def test_up_and_down_carries_the_reference_across_intervals():
    # Up to 1.1 (ON at 0.2 .. 1.0, the reference ends at 1.0), then down to -0.1 by t = 2.3:
    # OFF crossings at 0.8, 0.6, 0.4, 0.2, 0.0, i.e. 0.3 .. 1.1 s after the peak.
    frames, times = _pixel([0.0, 0.55, 1.1, 0.5, -0.1], [0.0, 0.55, 1.1, 1.7, 2.3])
    events = emulate_events(frames, times)
    assert list(events["p"]) == [1] * 5 + [-1] * 5
    np.testing.assert_allclose(events["t"][5:], np.array([1.4, 1.6, 1.8, 2.0, 2.2]) * 1e9,
                               atol=1000)
    assert np.all(np.diff(events["t"]) > 0)


def test_many_crossings_in_one_interval_are_all_emitted():
    frames, times = _pixel([0.0, 2.05], [0.0, 1.0])            # 10 thresholds in one interval
    events = emulate_events(frames, times)
    np.testing.assert_allclose(events["t"], np.arange(1, 11) * 0.2 / 2.05 * 1e9, atol=2)


def test_static_input_gives_no_events():
    rng = np.random.default_rng(0)
    frame = rng.normal(size=(20, 30))
    assert len(emulate_events(np.stack([frame] * 5), np.arange(5) * 0.01)) == 0


def _moving_texture(n=12, shape=(24, 32), shift=0.7, seed=1):
    """Log frames of a smooth random texture translated by `shift` px per frame."""
    from scipy.ndimage import gaussian_filter
    from scipy.ndimage import shift as nd_shift

    rng = np.random.default_rng(seed)
    base = gaussian_filter(rng.normal(size=(shape[0], shape[1] + 40)), 2.0) * 3.0
    frames = [nd_shift(base, (0, -shift * k), order=3, mode="wrap")[:, :shape[1]]
              for k in range(n)]
    return np.stack(frames), np.arange(n) * 1e-3


def test_compiled_emulator_matches_the_per_pixel_reference_exactly():
    frames, times = _moving_texture()
    fast = emulate_events(frames, times)
    slow = emulate_events_reference(frames, times)
    assert len(fast) > 200
    np.testing.assert_array_equal(fast, slow)
    assert np.all(np.diff(fast["t"]) >= 0)


def test_events_are_sorted_and_within_their_interval():
    frames, times = _moving_texture()
    emulator = EventEmulator(frames.shape[1:])
    emulator.start(frames[0], times[0])
    for k in range(1, len(times)):
        chunk = emulator.advance(frames[k], times[k])
        assert np.all(np.diff(chunk["t"]) >= 0)
        assert np.all((chunk["t"] > round(times[k - 1] * 1e9)) | (len(chunk) == 0))
        assert np.all(chunk["t"] <= round(times[k] * 1e9))


def test_refractory_period_drops_events_but_moves_the_reference():
    frames, times = _pixel([0.0, 1.1, 1.1, 1.15], [0.0, 0.011, 0.5, 0.6])
    noise = replace(noise_preset("ideal"), refractory_period=0.003)
    events = emulate_events(frames, times, EventParams(noise=noise))
    # Crossings every 2 ms; with a 3 ms refractory period every other one is dropped...
    np.testing.assert_allclose(events["t"], [2e6, 6e6, 10e6], atol=1000)
    # ...and the reference still moved to 1.0: 1.15 does not reach 1.2, so nothing more fires.
    frames2, times2 = _pixel([0.0, 1.1, 1.1, 1.25], [0.0, 0.011, 0.5, 0.6])
    more = emulate_events(frames2, times2, EventParams(noise=noise))
    assert len(more) == 4 and more["t"][-1] > 5e8


def test_realistic_preset_is_seeded():
    frames, times = _moving_texture()
    a = emulate_events(frames, times, EventParams.preset("realistic", seed=3))
    b = emulate_events(frames, times, EventParams.preset("realistic", seed=3))
    c = emulate_events(frames, times, EventParams.preset("realistic", seed=4))
    np.testing.assert_array_equal(a, b)
    assert len(a) != len(c) or not np.array_equal(a, c)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="strictly increasing"):
        emulate_events(np.zeros((3, 2, 2)), [0.0, 0.1, 0.1])
    with pytest.raises(ValueError, match=r"\(N, H, W\)"):
        emulate_events(np.zeros((3, 2)), [0.0, 0.1, 0.2])
    emulator = EventEmulator((2, 2))
    with pytest.raises(ValueError, match="start"):
        emulator.advance(np.zeros((2, 2)), 0.1)
    emulator.start(np.zeros((2, 2)), 0.0)
    with pytest.raises(ValueError, match="non-finite"):
        emulator.advance(np.full((2, 2), np.nan), 0.1)
    with pytest.raises(ValueError, match="forward"):
        emulator.advance(np.zeros((2, 2)), 0.0)


# --- crossings under the photoreceptor low-pass (issue 14) ---------------------------------------

LOWPASS = EventParams(noise=NoiseParams(cutoff_hz=200.0, cutoff_intensity_ref=1.0))  # filter only


def _one_pixel(level, times, params=LOWPASS, luminance=None):
    """Events of one pixel with log intensity ``level(t)`` and luminance exp(level(t)) (or
    ``luminance`` throughout)."""
    emulator = EventEmulator((1, 1), params)
    at = [np.full((1, 1), level(t)) for t in times]
    lum = [np.exp(L) if luminance is None else np.full((1, 1), luminance) for L in at]
    emulator.start(at[0], times[0], lum[0])
    return np.concatenate([emulator.advance(L, t, Y) for L, t, Y in zip(
        at[1:], times[1:], lum[1:], strict=True)])


def test_a_1_log_unit_ramp_over_1_ms_fires_at_the_dense_sampling_times():
    """Issue 14: interpolating the filtered level linearly fired at 3.97 and 7.49 ms instead
    of 1.28 and 1.83 ms (tau = 0.8 ms). Three samples (what the sampler takes: the ramp's
    ends, then 10 ms of nothing) must give the times of 1 us sampling, within 10 us."""
    def ramp(t):
        return min(max(t / 1e-3, 0.0), 1.0)

    coarse = _one_pixel(ramp, [0.0, 1e-3, 11e-3])
    # Dense: 1 us samples, fed in one call to the per-pixel emulator (the same kernels).
    times = np.arange(11001) * 1000
    levels = np.array([ramp(t * 1e-9) for t in times])
    dense_emulator = PixelEventEmulator((1, 1), LOWPASS)
    dense_emulator.start(levels[:1].reshape(1, 1), 0.0, np.exp(levels[:1]).reshape(1, 1))
    dense = dense_emulator.advance_samples(np.zeros(len(times), np.int64), times, levels,
                                           np.exp(levels), int(times[-1]),
                                           np.exp(levels[-1:]).reshape(1, 1))
    assert len(coarse) == len(dense) == 4 and np.all(coarse["p"] == 1)
    assert np.abs(coarse["t"] - dense["t"]).max() <= 10_000
    # And the closed form: y = (t - tau (1 - e^(-t / tau))) / T on the ramp, then an
    # exponential approach to 1 from y(T); crossings of 0.2, 0.4, 0.6, 0.8.
    tau, T = 1.0 / (2 * math.pi * 200.0), 1e-3
    y_T = (T - tau * (1 - math.exp(-T / tau))) / T

    def y(t):
        if t <= T:
            return (t - tau * (1 - math.exp(-t / tau))) / T
        return 1.0 - (1.0 - y_T) * math.exp(-(t - T) / tau)

    exact = [brentq(lambda t, lv=lv: y(t) - lv, 0.0, 11e-3, xtol=1e-13) for lv in
             (0.2, 0.4, 0.6, 0.8)]
    assert np.abs(coarse["t"] - np.array(exact) * 1e9).max() <= 1_000          # 1 us
    assert 1.2e6 < coarse["t"][2] < 1.3e6 and 1.8e6 < coarse["t"][3] < 1.9e6


def test_a_filtered_level_that_turns_inside_an_interval_fires_both_ways():
    """The input drops by 1 in 0.2 ms and then ramps up by 2 over 5 ms: the lagging filtered
    level goes on falling inside the long interval before it rises, so the interval holds OFF
    events and then ON events (one sample at each end)."""
    params = EventParams(noise=NoiseParams(cutoff_hz=50.0, cutoff_intensity_ref=1.0))

    def u(t):
        return -t / 2e-4 if t <= 2e-4 else -1.0 + 2.0 * (t - 2e-4) / 5e-3

    events = _one_pixel(u, [0.0, 2e-4, 5.2e-3], params, luminance=1.0)     # 50 Hz throughout
    omega = 2 * math.pi * 50.0
    want = filtered_reference_events(u, lambda t: omega, 5.2e-3, 0.2, 0.0)
    assert [int(p) for p in events["p"]] == [p for _, p in want]
    assert -1 in events["p"] and 1 in events["p"]
    later = events["t"] > 2e5                      # OFF events inside the long interval too
    assert np.any(events["p"][later] == -1)
    assert np.abs(events["t"] - np.array([t for t, _ in want]) * 1e9).max() <= 1_000

