"""The frame emulator's fast paths give the events of its general path, in every configuration.

:class:`sim.events.EventEmulator` takes shortcuts where a feature is off: a fused kernel
without low-pass or leak (:func:`sim.events._linear_chunks`, outputs sized from the last
interval and run again where too short), exact thresholds passed as numbers, a bucket sort
(:func:`sim.events._time_sorted`), no merge without noise events, the sensor's draws deferred
until its generator is used (:func:`sim.events._uniform_sensor`) and ``emulate_events``
writing every interval into one array (:class:`sim.events._EventStack`). ``_General`` below is
the emulator without any of them, as it was before they were added: the general kernels
(:func:`sim.events._count_rows`, :func:`sim.events._write_rows`) for every interval, NumPy's
argsort on the key ``(t - t0) * pixels + pixel``, every interval merged with
:func:`sim.noise.merge_labelled_events`, and every map drawn at construction. Each case
compares events, causes and the final state (references, levels, last event times, the
generator) between the two.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sim.eventio import EVENT_DTYPE
from sim.events import (
    EventEmulator,
    EventParams,
    _all_finite,
    _count_rows,
    _EventStack,
    _sensor_maps,
    _time_sorted,
    _write_rows,
    emulate_events,
)
from sim.noise import merge_labelled_events, noise_preset


class _General(EventEmulator):
    """The emulator with none of its fast paths (see the module's docstring)."""

    def __init__(self, shape, params=None):
        super().__init__(shape, params, kernel="numba")
        generator = np.random.default_rng(self.params.seed)
        self.c_on, self.c_off, self.hot_mask, self.leak_rates = _sensor_maps(
            self.shape, self.params, generator)
        self._generator, self._draws_pending = generator, False
        self._thresholds = (self.c_on, self.c_off)

    def _linear_crossings(self, L1, t0_ns, dt_ns):
        return self._crossings(self._L, self._raw, L1, np.full(self.shape, np.inf), t0_ns, dt_ns,
                               np.zeros((0, 0)))

    def _crossings(self, L0, raw0, raw1, x, t0_ns, dt_ns, drift):
        L1 = np.empty(self.shape)
        counts = _count_rows(L0, raw0, raw1, x, self.ref, self.c_on, self.c_off, drift, L1)
        if np.any(counts < 0):
            raise ValueError("L1 has non-finite values; expected log intensities")
        total = int(counts.sum())
        offsets = np.zeros(len(counts), dtype=np.int64)
        np.cumsum(counts[:-1], out=offsets[1:])
        t, xs, y = np.empty(total, np.int64), np.empty(total, np.uint16), np.empty(total, np.uint16)
        p, keep, cause = np.empty(total, np.int8), np.empty(total, bool), np.empty(total, np.uint8)
        refractory = int(round(self.params.noise.refractory_period * 1e9))
        _write_rows(L0, raw0, raw1, x, self.ref, self.c_on, self.c_off, self._last_t, offsets,
                    t0_ns, float(dt_ns), refractory, drift, t, xs, y, p, cause, keep)
        key = (t - t0_ns) * (self.shape[0] * self.shape[1]) + (y.astype(np.int64)
                                                               * self.shape[1] + xs)
        order = np.argsort(key, kind="stable")
        if refractory > 0:
            order = order[keep[order]]
        events = np.empty(len(order), EVENT_DTYPE)
        events["t"], events["x"], events["y"], events["p"] = t[order], xs[order], y[order], p[order]
        return events, cause[order], L1

    def _with_noise(self, events, causes, t0_ns, t1_ns, luminance):
        from sim.noise import CAUSE_HOT_PIXEL, CAUSE_SHOT, background_events, hot_pixel_events

        noise = self.params.noise
        parts = [(events, causes)]
        if noise.shot_noise_rate > 0:
            shot = background_events(t0_ns, t1_ns, luminance, noise, self._rng)
            parts.append((shot, np.full(len(shot), CAUSE_SHOT, np.uint8)))
        if noise.hot_pixel_fraction > 0 and noise.hot_pixel_rate > 0:
            hot = hot_pixel_events(t0_ns, t1_ns, self.hot_mask, noise.hot_pixel_rate, self._rng)
            parts.append((hot, np.full(len(hot), CAUSE_HOT_PIXEL, np.uint8)))
        events, causes = merge_labelled_events(*parts)
        self.last_causes = causes.astype(np.uint8)
        return events


_IDEAL, _REAL = noise_preset("ideal"), noise_preset("realistic")
CONFIGS = {
    "ideal": _IDEAL,
    "refractory": replace(_IDEAL, refractory_period=2e-4),
    "threshold_sigma": replace(_IDEAL, threshold_sigma=0.03),
    "initial_phase": replace(_IDEAL, initial_phase=True),
    "lowpass": replace(_IDEAL, cutoff_hz=_REAL.cutoff_hz),
    "leak": replace(_IDEAL, leak_rate=_REAL.leak_rate),
    "shot": replace(_IDEAL, shot_noise_rate=_REAL.shot_noise_rate),
    "hot": replace(_IDEAL, hot_pixel_fraction=0.01, hot_pixel_rate=200.0),
    "realistic": _REAL,
    "realistic_refractory": replace(_REAL, refractory_period=5e-4),
}


def _texture(shape, n, seed):
    """(n, H, W) log frames: a random texture drifting sideways, a brightening band, a flat
    pixel, a still interval and then a jump (more events than the interval before: the fused
    kernel's outputs are too short and it runs again)."""
    rng = np.random.default_rng(seed)
    base = rng.normal(0.0, 0.4, (shape[0], shape[1] + n))
    frames = np.stack([base[:, k:k + shape[1]] + 0.3 * k / n for k in range(n)])
    frames[:, : max(1, shape[0] // 3)] += np.linspace(0.0, 1.5, n)[:, None, None]
    frames[:, -1, -1] = frames[0, -1, -1]
    frames[3] = frames[2] + 1e-3
    frames[4] = frames[3] + rng.normal(0.0, 1.0, shape)
    return frames


def _run(emulator, frames, times):
    emulator.start(frames[0], times[0])
    events, causes = [], []
    for frame, t in zip(frames[1:], times[1:], strict=True):
        events.append(emulator.advance(frame, t))
        causes.append(emulator.last_causes.copy())
    return np.concatenate(events), np.concatenate(causes), emulator.get_state()


@pytest.mark.parametrize("name", sorted(CONFIGS))
@pytest.mark.parametrize("shape", [(24, 33), (5, 7), (1, 40), (40, 3)])
def test_fast_paths_give_the_general_paths_events(name, shape):
    frames = _texture(shape, 9, seed=shape[0])
    times = np.cumsum(np.r_[0.0, np.random.default_rng(1).uniform(2e-5, 4e-3, len(frames) - 1)])
    params = EventParams(contrast_on=0.2, contrast_off=0.25, noise=CONFIGS[name], seed=7)
    fast = _run(EventEmulator(shape, params, kernel="numba"), frames, times)
    general = _run(_General(shape, params), frames, times)
    assert len(general[0]) > 50
    assert np.array_equal(fast[0], general[0])
    assert np.array_equal(fast[1], general[1])
    for key, value in general[2].items():
        if isinstance(value, np.ndarray):
            assert np.array_equal(fast[2][key], value), key
        else:
            assert fast[2][key] == value, key


@pytest.mark.parametrize("name", ["ideal", "refractory", "realistic"])
def test_emulate_events_is_the_streamed_events(name):
    frames = _texture((20, 30), 12, seed=2)
    times = np.arange(12) * 1e-3
    params = EventParams(noise=CONFIGS[name], seed=3)
    events = emulate_events(frames, times, params)
    assert np.array_equal(events, _run(_General((20, 30), params), frames, times)[0])


def test_the_event_stack_grows_and_copies_what_it_did_not_reserve():
    stack = _EventStack(3)
    first = stack.reserve(2)
    first["t"] = [1, 2]
    stack.append(first)
    other = np.zeros(5, EVENT_DTYPE)
    other["t"] = np.arange(3, 8)
    stack.reserve(1)                                  # reserved, then not used
    stack.append(other)
    third = stack.reserve(40)                         # more than the estimate: grows
    third["t"] = np.arange(8, 48)
    stack.append(third)
    assert np.array_equal(stack.events()["t"], np.arange(1, 48))
    fourth = stack.reserve(100)                       # one interval more than announced
    fourth["t"] = np.arange(48, 148)
    stack.append(fourth)
    assert np.array_equal(stack.events()["t"], np.arange(1, 148))


def test_time_sorted_is_a_stable_sort_on_time_then_pixel():
    rng = np.random.default_rng(0)
    n, width, pixels, t0, dt = 3000, 13, 13 * 11, 5_000, 1_000
    t = t0 + np.sort(rng.integers(0, dt + 1, n))
    t[:400] = t0 + 17                                 # one large bucket: merge-sorted
    xs = rng.integers(0, width, n).astype(np.uint16)
    ys = rng.integers(0, 11, n).astype(np.uint16)
    p = rng.choice(np.array([-1, 1], np.int8), n)
    cause = rng.integers(0, 4, n).astype(np.uint8)
    keep = rng.random(n) < 0.8
    first, stop = np.array([0, 1000, 2500]), np.array([800, 2400, 3000])
    take = np.concatenate([np.arange(a, b) for a, b in zip(first, stop, strict=True)])
    take = take[keep[take]]
    key = (t[take] - t0) * pixels + ys[take].astype(np.int64) * width + xs[take]
    expected = take[np.argsort(key, kind="stable")]
    out = np.empty(len(expected), EVENT_DTYPE)
    out_cause = np.empty(len(expected), np.uint8)
    _time_sorted(t, xs, ys, p, cause, keep, first, stop, t0, float(dt), width, pixels, out,
                 out_cause)
    assert np.array_equal(out["t"], t[expected]) and np.array_equal(out["x"], xs[expected])
    assert np.array_equal(out["y"], ys[expected]) and np.array_equal(out["p"], p[expected])
    assert np.array_equal(out_cause, cause[expected])


@pytest.mark.parametrize("name", ["ideal", "leak"])
def test_a_non_finite_level_leaves_the_emulator_as_it_was(name):
    frames = _texture((12, 20), 6, seed=4)
    params = EventParams(noise=CONFIGS[name], seed=1)
    clean, broken = (EventEmulator((12, 20), params) for _ in range(2))
    for emulator in (clean, broken):
        emulator.start(frames[0], 0.0)
        emulator.advance(frames[1], 1e-3)
    bad = frames[2].copy()
    bad[7, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        broken.advance(bad, 2e-3)
    if name == "ideal":                               # (the leak's draw was made: not comparable)
        assert np.array_equal(broken.advance(frames[2], 2e-3), clean.advance(frames[2], 2e-3))
        assert np.array_equal(broken.ref, clean.ref)


def test_deferred_draws_are_made_before_the_generator_is_used():
    uniform = EventEmulator((30, 40), EventParams(seed=5))
    assert uniform._draws_pending
    eager = _General((30, 40), EventParams(seed=5))
    assert uniform.get_state()["rng"] == eager.get_state()["rng"]
    assert np.array_equal(uniform.c_on, eager.c_on) and np.array_equal(uniform.c_off, eager.c_off)
    assert not uniform.hot_mask.any() and not uniform.leak_rates.any()
    assert not EventEmulator((30, 40), EventParams.preset("realistic"))._draws_pending


@pytest.mark.parametrize("value, finite", [(np.inf, False), (-np.inf, False), (np.nan, False),
                                           (np.finfo(float).max, True), (-5e-324, True),
                                           (0.0, True)])
def test_all_finite_tells_infinities_and_nans_from_every_finite_number(value, finite):
    levels = np.random.default_rng(0).normal(size=(7, 9))
    levels[6, 8] = value
    assert _all_finite(levels) is finite


@pytest.mark.parametrize("name", ["ideal", "realistic"])
def test_a_reused_frame_buffer_gives_the_events_of_fresh_frames(name):
    """The emulator keeps its own copy of the last sample: a caller that renders every frame
    into one buffer (and overwrites it after each call) gets the events of fresh arrays."""
    shape = (12, 17)
    frames = _texture(shape, 8, seed=4)
    times = np.arange(8) * 2e-3
    params = EventParams(noise=CONFIGS[name], seed=5)
    fresh = _run(EventEmulator(shape, params, kernel="numba"), frames, times)
    emulator = EventEmulator(shape, params, kernel="numba")
    buffer = np.empty(shape)
    events = []
    for k, (frame, t) in enumerate(zip(frames, times, strict=True)):
        buffer[...] = frame
        if k == 0:
            emulator.start(buffer, t)
        else:
            events.append(emulator.advance(buffer, t))
        buffer[...] = -1e3                  # the caller reuses its buffer
    assert len(fresh[0]) > 20
    assert np.array_equal(np.concatenate(events), fresh[0])
