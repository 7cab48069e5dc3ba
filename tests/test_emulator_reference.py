"""The per-pixel emulator's kernel against a plain reference, noise included.

:class:`sim.pixel_sampling.PixelEventEmulator` solves and writes the threshold crossings in
one pass into outputs sized from the last block's count (run again from the block's state when
they are too short), flagging those the refractory period drops (left out afterwards), takes
every low-pass exponent of the block at once, and sorts the block's events by one integer key.
The reference below is the model written as directly as possible: one Python loop over the
samples in order, the model's scalar steps (:func:`sim.events.interval_levels`,
:func:`~sim.events.threshold_crossings`, :func:`~sim.events.filtered_crossing_time`), a list of
events sorted by (time, pixel) and the noise functions of :mod:`sim.noise` drawn in the same
order. Every noise of the ``realistic``
preset is on (refractory period, leak, shot noise, hot pixels, photoreceptor low-pass,
threshold mismatch, initial phase), turned up so that each one changes the events of a small
random input; the events must be identical, bit for bit, and so must the state carried on.
The frame emulator gives the per-pixel emulator's events when both see whole frames
(``tests/test_pixel_sampling.py``), so this pins it too.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim.eventio import EVENT_DTYPE
from sim.events import (
    EventEmulator,
    EventParams,
    filtered_crossing_time,
    interval_levels,
    threshold_crossings,
)
from sim.noise import (
    _cutoff,
    drifted_inputs,
    lowpass_exponent,
    noise_preset,
)
from sim.pixel_sampling import PixelEventEmulator

EPS = 0.43
SHAPE = (5, 7)


def reference_block(emulator: PixelEventEmulator, pixels, times_ns, levels, luminance,
                    t_end_ns: int, end_luminance) -> np.ndarray:
    """:meth:`PixelEventEmulator.advance_samples`, one sample after another in Python."""
    noise = emulator.params.noise
    t0 = emulator._t
    width = emulator.shape[1]
    if np.shares_memory(emulator._L, emulator._raw):
        emulator._L = emulator._L.copy()
    ref, level, raw = emulator.ref.reshape(-1), emulator._L.reshape(-1), emulator._raw.reshape(-1)
    last_t, c_on, c_off = (emulator._last_t.reshape(-1), emulator.c_on.reshape(-1),
                           emulator.c_off.reshape(-1))
    same = pixels[1:] == pixels[:-1]
    normals = emulator._rng.standard_normal(int(same.sum())) if noise.leak_rate > 0 else None
    exponent = np.full(len(pixels) - 1, np.inf)
    if noise.cutoff_hz > 0:
        cutoff = _cutoff(np.asarray(luminance, np.float64), noise)
        exponent[same] = lowpass_exponent(np.diff(times_ns)[same] * 1e-9, cutoff[:-1][same],
                                          cutoff[1:][same])
    refractory = int(round(noise.refractory_period * 1e9))
    found = []
    k = 0
    for j in range(1, len(pixels)):
        p = int(pixels[j])
        if pixels[j - 1] != p:                       # a pixel's first sample: its state
            continue
        ta, tb, la, lb, x = int(times_ns[j - 1]), int(times_ns[j]), raw[p], levels[j], \
            exponent[j - 1]
        # The leak moves the reference down by d, linearly over the interval: the crossings
        # are those of the level plus the drift so far (drifted_inputs) against ref[p].
        d, a, b = 0.0, la, lb
        if normals is not None:
            jitter = max(1.0 - noise.leak_jitter * normals[k], 0.0)
            d = ((tb - ta) * 1e-9) * emulator.leak_rates.reshape(-1)[p] * jitter * c_on[p]
            a, b = drifted_inputs(la, lb, x, d)
        k += 1
        y0 = level[p]
        f_turn, y_turn, y_end = interval_levels(y0, a, b, x)
        pieces = [(0.0, y0, f_turn, y_turn)] + ([(f_turn, y_turn, 1.0, y_end)] if f_turn < 1.0
                                                 else [])
        for f_lo, y_lo, f_hi, y_hi in pieces:
            n, c, sign = threshold_crossings(y_hi, ref[p], c_on[p], c_off[p])
            for i in range(1, n + 1):
                t = int(filtered_crossing_time(ref[p] + i * c, y0, a, b, x, f_lo, y_lo, f_hi,
                                               y_hi, ta, float(tb - ta)))
                if refractory > 0 and t - last_t[p] < refractory:
                    continue
                last_t[p] = t
                found.append((t, p, sign))
            ref[p] += n * c
        ref[p] -= d
        level[p], raw[p] = interval_levels(y0, la, lb, x)[2], lb
    found.sort(key=lambda e: (e[0], e[1]))
    events = np.empty(len(found), EVENT_DTYPE)
    for e, (t, p, sign) in zip(events, found, strict=True):
        e["t"], e["y"], e["x"], e["p"] = t, p // width, p % width, sign
    # the block's noise events and the emulator's move to t_end: the emulator's own step (what
    # this reference checks is the crossings above)
    return emulator._close_block(events, t0, t_end_ns, end_luminance)


def _blocks(seed: int, n_blocks: int = 6):
    """Random per-pixel samples: each pixel a random walk of its own length per block."""
    rng = np.random.default_rng(seed)
    n = SHAPE[0] * SHAPE[1]
    block = 2_000_000                                                        # 2 ms
    state = rng.normal(3.0, 1.0, n)
    start = np.exp(state).reshape(SHAPE)
    blocks = []
    for b in range(n_blocks):
        t_b, t_e = b * block, (b + 1) * block
        inner = rng.integers(0, 6, n)
        pix, times, lums = [], [], []
        for p in range(n):
            middle = np.sort(rng.choice(np.arange(t_b + 1, t_e), inner[p], replace=False))
            walk = state[p] + np.cumsum(rng.normal(0, 0.35, inner[p] + 1))
            pix += [p] * (inner[p] + 2)
            times += [t_b, *middle, t_e]
            lums += [np.exp(state[p]), *np.exp(walk)]
            state[p] = walk[-1]
        lums = np.array(lums)
        blocks.append((np.array(pix, np.int64), np.array(times, np.int64),
                       np.log(lums + EPS), lums, t_e, np.exp(state).reshape(SHAPE)))
    return start, blocks


NOISY = dataclasses.replace(noise_preset("realistic"), shot_noise_rate=300.0, leak_rate=80.0,
                            hot_pixel_fraction=0.1, hot_pixel_rate=2000.0,
                            refractory_period=0.2e-3)
"""Every noise of the realistic preset on, turned up to change the events of 35 pixels over
12 ms."""


REFRACTORY = dataclasses.replace(noise_preset("ideal"), refractory_period=0.2e-3)
"""No filter and no leak (the short kernel, :func:`sim.pixel_sampling._pixel_events_direct`)
but a refractory period."""


@pytest.mark.parametrize("noise", [noise_preset("ideal"), REFRACTORY, noise_preset("realistic"),
                                   NOISY], ids=["ideal", "refractory", "realistic", "noisy"])
def test_the_kernel_gives_the_plain_references_events_bit_for_bit(noise):
    params = EventParams(contrast_on=0.2, contrast_off=0.25, log_eps=EPS, noise=noise, seed=3)
    start, blocks = _blocks(seed=1)
    fast, slow = PixelEventEmulator(SHAPE, params), PixelEventEmulator(SHAPE, params)
    for emulator in (fast, slow):
        emulator.start(np.log(start + EPS), 0.0, start)
    total = 0
    for block in blocks:
        got = fast.advance_samples(*block)
        want = reference_block(slow, *block)
        np.testing.assert_array_equal(got, want)
        total += len(got)
    assert total > 100
    state_fast, state_slow = fast.get_state(), slow.get_state()
    for key in ("ref", "level", "raw", "cutoff", "last_t"):
        np.testing.assert_array_equal(state_fast[key], state_slow[key])
    assert state_fast["rng"] == state_slow["rng"]


def test_each_noise_of_the_noisy_case_changes_the_events():
    """The noisy case above is only a check if every noise it turns on acts on this input."""
    start, blocks = _blocks(seed=1)

    def events(noise):
        emulator = PixelEventEmulator(SHAPE, EventParams(contrast_on=0.2, contrast_off=0.25,
                                                         log_eps=EPS, noise=noise, seed=3))
        emulator.start(np.log(start + EPS), 0.0, start)
        return np.concatenate([emulator.advance_samples(*block) for block in blocks])

    full = events(NOISY)
    for field, off in (("refractory_period", 0.0), ("leak_rate", 0.0), ("shot_noise_rate", 0.0),
                       ("hot_pixel_rate", 0.0), ("cutoff_hz", 0.0)):
        other = events(dataclasses.replace(NOISY, **{field: off}))
        assert len(other) != len(full) or not np.array_equal(other, full), field


@pytest.mark.parametrize("kind", [EventEmulator, PixelEventEmulator])
def test_warm_up_leaves_the_emulator_alone_and_seconds_counts_only_its_own_calls(kind):
    """``simulate`` warms the kernels before its clock (timings_s.emulate_compile) and times
    the emulator by ``seconds`` (timings_s.emulate): the warm-up must not draw from the
    sensor's generator, move its state or count as emulation."""
    params = EventParams(log_eps=EPS, noise=NOISY, seed=3)
    emulator, twin = kind(SHAPE, params), kind(SHAPE, params)
    assert emulator.warm_up() > 0
    assert emulator.seconds == 0.0
    assert emulator.get_state()["rng"] == twin.get_state()["rng"]
    start, blocks = _blocks(seed=2, n_blocks=1)
    emulator.start(np.log(start + EPS), 0.0, start)
    if kind is PixelEventEmulator:
        emulator.advance_samples(*blocks[0])
    else:
        emulator.advance(np.log(blocks[0][5] + EPS), 2e-3, blocks[0][5])
    assert emulator.seconds > 0


@pytest.mark.parametrize("noise", [noise_preset("ideal"), NOISY], ids=["ideal", "noisy"])
def test_a_block_with_more_crossings_than_its_outputs_hold_is_run_again_from_its_state(noise):
    """The kernel writes into outputs sized from the last block's count (at least 4,096) and
    only counts past their end; a block that fires more (here 35 pixels ramping by 50, then
    by 160 log units: about 8,000 and 27,000 crossings without the filter) must be run again
    from the state it started with, and still give the plain reference's events and state."""
    params = EventParams(contrast_on=0.2, contrast_off=0.25, log_eps=EPS, noise=noise, seed=3)
    n = SHAPE[0] * SHAPE[1]
    start = np.full(SHAPE, 1.0)
    fast, slow = PixelEventEmulator(SHAPE, params), PixelEventEmulator(SHAPE, params)
    for emulator in (fast, slow):
        emulator.start(np.log(start + EPS), 0.0, start)
    level, capacity = np.log(1.0 + EPS), 4096
    for b, ramp in enumerate((50.0, 160.0)):
        t_b, t_e = b * 2_000_000, (b + 1) * 2_000_000
        pix = np.repeat(np.arange(n, dtype=np.int64), 3)
        times = np.tile(np.array([t_b, (t_b + t_e) // 2, t_e], np.int64), n)
        levels = np.tile([level, level + ramp / 2, level + ramp], n) + np.repeat(
            np.linspace(0.0, 0.1, n), 3)
        block = (pix, times, levels, np.exp(levels), t_e, np.exp(levels[2::3]).reshape(SHAPE))
        got = fast.advance_samples(*block)
        want = reference_block(slow, *block)
        assert fast._last_count > capacity                 # the outputs were too short
        capacity = 2 * fast._last_count
        np.testing.assert_array_equal(got, want)
        level += ramp
    for key in ("ref", "level", "raw", "last_t"):
        np.testing.assert_array_equal(fast.get_state()[key], slow.get_state()[key])


@pytest.mark.parametrize("refractory", [0, 200_000])
def test_the_short_kernel_is_the_general_one_without_filter_and_leak(refractory):
    """Without the low-pass filter and the leak, :meth:`PixelEventEmulator.advance_samples`
    runs :func:`~sim.pixel_sampling._pixel_events_direct`: the same crossings (times, pixels,
    polarities, causes, keep flags) and pixel states as :func:`~sim.pixel_sampling.
    _pixel_events` given ``exponent`` all ``inf`` and no leak, block after block."""
    from sim.pixel_sampling import _outputs, _pixel_events, _pixel_events_direct

    start, blocks = _blocks(seed=4)
    n = SHAPE[0] * SHAPE[1]
    rng = np.random.default_rng(5)
    c_on, c_off = rng.uniform(0.15, 0.3, n), rng.uniform(0.15, 0.3, n)
    states = [[np.log(start + EPS).reshape(-1).copy() for _ in range(3)]
              + [np.full(n, -10**12, np.int64)] for _ in range(2)]
    total = 0
    for pix, times, levels, *_ in blocks:
        general, short = _outputs(20_000), _outputs(20_000)
        m = _pixel_events(pix, times, levels, np.full(len(pix) - 1, np.inf), *states[0], c_on,
                          c_off, (np.zeros(0), 0.0), np.zeros(0), refractory, *general)
        k = _pixel_events_direct(pix, times, levels, *states[1], c_on, c_off, refractory,
                                 *short)
        assert m == k
        for a, b in zip(general, short, strict=True):
            np.testing.assert_array_equal(a[:m], b[:k])
        for a, b in zip(*states, strict=True):
            np.testing.assert_array_equal(a, b)
        total += m
        if refractory:
            assert not general[4][:m].all()             # the refractory period dropped some
    assert total > 100
