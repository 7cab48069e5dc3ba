"""The per-pixel emulator's Dr.Jit kernel (:mod:`sim._drjit_events`) against its numba kernel.

Both kernels see the same blocks (the reference test's random walks: several crossings per
interval, both polarities, per-pixel thresholds, plus a pixel ramping up then down by five
thresholds within one interval each); on a CPU Dr.Jit's ``llvm`` backend (every core), on a GPU
machine with ``cuda_ad_rgb`` active its ``cuda`` one (run there on an H200, 2026-11-26).
Without the photoreceptor low-pass the events and the state carried on are identical bit for
bit (leak, refractory period, shot noise and hot pixels on); with it, within the bound the
module states: the same events, each within 1 ns, the filtered level within 1e-12.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

from sim.events import EventEmulator, EventParams
from sim.noise import CAUSE_LEAK, noise_preset
from sim.pixel_sampling import PixelEventEmulator
from tests.test_emulator_reference import EPS, NOISY, SHAPE, _blocks

UNFILTERED = dataclasses.replace(NOISY, cutoff_hz=0.0)
"""Every noise of the noisy case but the low-pass: leak, refractory, shot noise, hot pixels."""


def _with_ramps(blocks):
    """The random blocks, with pixel 0 ramping up by 1.5 over one interval and down by 1.8
    over the next in the first block (seven ON, then seven OFF crossings at C = 0.2, fewer at
    0.25)."""
    pix, times, levels, lums, t_e, end = blocks[0]
    run = np.flatnonzero(pix == 0)
    t_b = times[run[0]]
    base = levels[run[0]]
    new_t = np.array([t_b, t_b + 400_000, t_b + 800_000, t_e], np.int64)
    new_l = np.array([base, base + 1.5, base - 0.3, levels[run[-1]]])
    pix = np.r_[np.zeros(4, np.int64), pix[run[-1] + 1:]]
    times = np.r_[new_t, times[run[-1] + 1:]]
    levels = np.r_[new_l, levels[run[-1] + 1:]]
    lums = np.r_[np.exp(new_l) - EPS, lums[run[-1] + 1:]]
    return [(pix, times, levels, lums, t_e, end)] + blocks[1:]


def _run(kernel: str, noise, seed: int = 1) -> tuple[list[np.ndarray], dict]:
    params = EventParams(contrast_on=0.2, contrast_off=0.25, log_eps=EPS, noise=noise, seed=3)
    start, blocks = _blocks(seed=seed, n_blocks=12)
    emulator = PixelEventEmulator(SHAPE, params, kernel=kernel)
    assert emulator.kernel == kernel
    emulator.start(np.log(start + EPS), 0.0, start)
    events = []
    for block in _with_ramps(blocks):
        events.append(emulator.advance_samples(*block))
        events.append(emulator.last_causes)              # each event's cause, in order
    return events, emulator.get_state()


@pytest.mark.parametrize("noise", [noise_preset("ideal"), UNFILTERED],
                         ids=["ideal", "noisy-unfiltered"])
def test_without_the_low_pass_the_drjit_kernel_gives_the_numba_kernels_events_bit_for_bit(
        noise):
    numba_events, numba_state = _run("numba", noise, seed=2)
    drjit_events, drjit_state = _run("drjit", noise, seed=2)
    assert sum(len(e) for e in numba_events[0::2]) > 100
    # the ramp's interval fires several events of one pixel
    first = numba_events[0]
    assert np.count_nonzero((first["x"] == 0) & (first["y"] == 0) & (first["p"] > 0)) >= 3
    assert np.count_nonzero((first["x"] == 0) & (first["y"] == 0) & (first["p"] < 0)) >= 3
    for a, b in zip(numba_events, drjit_events, strict=True):        # events, then causes
        np.testing.assert_array_equal(a, b)
    if noise.leak_rate > 0:                                  # the leak's events are told apart
        assert np.any(np.concatenate(numba_events[1::2]) == CAUSE_LEAK)
    for key in ("ref", "level", "raw", "cutoff", "last_t"):
        np.testing.assert_array_equal(numba_state[key], drjit_state[key])
    assert numba_state["rng"] == drjit_state["rng"]


@pytest.mark.parametrize("noise", [noise_preset("realistic"), NOISY], ids=["realistic", "noisy"])
def test_with_the_low_pass_the_drjit_kernel_is_within_its_stated_bound(noise):
    numba_events, numba_state = _run("numba", noise)
    drjit_events, drjit_state = _run("drjit", noise)
    assert sum(len(e) for e in numba_events[0::2]) > 100
    _assert_within_bound(numba_events, drjit_events)
    np.testing.assert_allclose(drjit_state["level"], numba_state["level"], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(drjit_state["ref"], numba_state["ref"])


def _assert_within_bound(numba_events: list, drjit_events: list) -> None:
    """The same events, each within 1 ns (ties within 1 ns may swap places: pixels and
    polarities compared as sets, causes as counts)."""
    for a, b in zip(numba_events[0::2], drjit_events[0::2], strict=True):
        assert len(a) == len(b)
        assert np.abs(a["t"] - b["t"]).max(initial=0) <= 1
        np.testing.assert_array_equal(np.sort(a[["y", "x", "p"]]), np.sort(b[["y", "x", "p"]]))
    for a, b in zip(numba_events[1::2], drjit_events[1::2], strict=True):
        np.testing.assert_array_equal(np.bincount(a, minlength=4), np.bincount(b, minlength=4))


def test_a_block_without_crossings_leaves_the_levels_and_fires_nothing():
    params = EventParams(log_eps=EPS, noise=noise_preset("ideal"))
    emulator = PixelEventEmulator((1, 3), params, kernel="drjit")
    emulator.start(np.zeros((1, 3)), 0.0)
    pix = np.array([0, 0, 1, 1, 2, 2, 2], np.int64)
    times = np.array([0, 10**6, 0, 10**6, 0, 5 * 10**5, 10**6], np.int64)
    levels = np.array([0.0, 0.1, 0.0, -0.1, 0.0, 0.15, 0.05])
    events = emulator.advance_samples(pix, times, levels, np.exp(levels), 10**6,
                                      np.ones((1, 3)))
    assert len(events) == 0
    np.testing.assert_array_equal(emulator.level, [[0.1, -0.1, 0.05]])
    np.testing.assert_array_equal(emulator.ref, np.zeros((1, 3)))


def test_the_kernel_is_chosen_by_a_stated_rule():
    params = EventParams()
    with pytest.raises(ValueError, match="kernel must be one of"):
        PixelEventEmulator((2, 2), params, kernel="gpu")
    # auto: the numba kernel, unless a cuda variant is active (the suite on a GPU machine)
    from sim._drjit_events import active_device

    expected = "drjit" if active_device() == "cuda" else "numba"
    assert PixelEventEmulator((2, 2), params).kernel == expected
    emulator = PixelEventEmulator((2, 2), params, kernel="drjit")
    assert emulator.warm_up() > 0
    assert emulator.seconds == 0.0


def test_auto_is_the_drjit_kernel_on_the_gpu_under_a_cuda_variant(monkeypatch):
    """The rule's other half, without a GPU: with a ``cuda_*`` Mitsuba variant active, ``auto``
    is the Dr.Jit kernel on the ``cuda`` device (nothing runs here)."""
    import types

    from sim import _drjit_events

    fake = types.SimpleNamespace(variant=lambda: "cuda_ad_rgb")
    monkeypatch.setitem(sys.modules, "mitsuba", fake)
    assert _drjit_events.active_device() == "cuda"
    emulator = PixelEventEmulator((2, 2), EventParams())
    assert emulator.kernel == "drjit" and emulator._device == "cuda"
    monkeypatch.setitem(sys.modules, "mitsuba", types.SimpleNamespace(
        variant=lambda: "llvm_ad_rgb"))
    assert PixelEventEmulator((2, 2), EventParams()).kernel == "numba"


def _frames(seed: int = 4, n: int = 10):
    """Random log-intensity frames (6x8, a random walk with steps of 0.35, several crossings
    per interval) at uneven times."""
    rng = np.random.default_rng(seed)
    logs = np.log(np.exp(rng.normal(3.0, 1.0, (6, 8))) + EPS) + np.cumsum(
        rng.normal(0.0, 0.35, (n, 6, 8)), axis=0)
    return logs, np.cumsum(rng.uniform(0.5e-3, 2e-3, n))


def _frame_events(kernel: str, noise) -> tuple[list[np.ndarray], dict]:
    logs, times = _frames()
    emulator = EventEmulator(logs.shape[1:], EventParams(
        contrast_on=0.2, contrast_off=0.25, log_eps=EPS, noise=noise, seed=3), kernel=kernel)
    assert emulator.kernel == kernel
    emulator.start(logs[0], times[0])
    events = []
    for frame, t in zip(logs[1:], times[1:], strict=True):
        events.append(emulator.advance(frame, t))
        events.append(emulator.last_causes)              # each event's cause, in order
    return events, emulator.get_state()


@pytest.mark.parametrize("noise", [noise_preset("ideal"), UNFILTERED, noise_preset("realistic"),
                                   NOISY], ids=["ideal", "noisy-unfiltered", "realistic", "noisy"])
def test_the_frame_emulator_on_drjit_gives_the_numba_kernels_events(noise):
    """The frame emulator's interval as a block of two samples a pixel: without the low-pass
    bit for bit, with it within the stated bound."""
    numba_events, numba_state = _frame_events("numba", noise)
    drjit_events, drjit_state = _frame_events("drjit", noise)
    assert sum(len(e) for e in numba_events[0::2]) > 100
    if noise.cutoff_hz == 0:
        for a, b in zip(numba_events, drjit_events, strict=True):     # events, then causes
            np.testing.assert_array_equal(a, b)
        if noise.leak_rate > 0:                              # the leak's events told apart
            assert np.any(np.concatenate(numba_events[1::2]) == CAUSE_LEAK)
    else:
        _assert_within_bound(numba_events, drjit_events)
    for key in ("ref", "level", "raw", "cutoff", "last_t"):
        if noise.cutoff_hz == 0 or key != "level":
            np.testing.assert_array_equal(numba_state[key], drjit_state[key])
        else:
            np.testing.assert_allclose(drjit_state[key], numba_state[key], rtol=0, atol=1e-12)


def test_the_frame_emulator_on_drjit_refuses_a_non_finite_level():
    emulator = EventEmulator((1, 2), EventParams(), kernel="drjit")
    emulator.start(np.zeros((1, 2)), 0.0)
    with pytest.raises(ValueError, match="non-finite"):
        emulator.advance(np.array([[0.0, np.nan]]), 1e-3)


def test_host_arrays_reach_drjit_with_one_copy_at_most():
    """On ``llvm`` an array already 128-byte aligned is mapped as it is (no copy: a change to
    it shows in the Dr.Jit array), any other is copied once into an aligned buffer; the values
    are the same either way."""
    import drjit as dr
    import drjit.llvm as m

    if not dr.has_backend(dr.JitBackend.LLVM):
        pytest.skip("Dr.Jit's llvm backend does not work here (no LLVM library)")

    from sim._drjit_events import ALIGNMENT, _device_array

    buffer = np.empty(100 * 8 + ALIGNMENT, np.uint8)
    start = -buffer.ctypes.data % ALIGNMENT
    aligned = buffer[start:start + 800].view(np.float64)
    aligned[:] = np.arange(100.0)
    mapped = _device_array(m.Float64, aligned)
    aligned[0] = 42.0
    assert mapped.numpy()[0] == 42.0
    values = np.arange(101.0)[1:]
    if values.ctypes.data % ALIGNMENT == 0:                  # (allocators differ)
        values = np.arange(102.0)[2:]
    copied = _device_array(m.Float64, values)
    values[0] = -1.0
    assert np.array_equal(copied.numpy(), np.arange(1.0, 101.0))
    assert np.array_equal(_device_array(m.Int64, np.arange(5, dtype=np.int32)).numpy(),
                          np.arange(5))
