"""The per-pixel sampler (sim.pixel_sampling) on analytic sources: exact event times, no events
from a static view, the bound on every interval, the same models as the frame emulator, and
resuming from any block."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sim.camera import Camera
from sim.events import EventEmulator, EventParams
from sim.noise import NoiseParams, cutoff_frequency, noise_preset
from sim.pixel_sampling import (
    EDGE_COS,
    MAX_DILATION,
    PixelEventEmulator,
    PixelSamplingStats,
    geometric_edges,
    pixel_blocks,
    rate_map,
)
from sim.sampling import SamplingParams
from tests.conftest import filtered_reference_events

C = 0.2
EPS = 1e-3


class Ramp:
    """Log intensity of pixel (x, y): ``L0 + clip(s (t - x' / v), 0, A)``, x' = x + 0.1 y.

    A ramp in log intensity sweeping along x: piecewise linear in time, so the emulator's
    interpolation is exact wherever a sample interval does not straddle a kink. ``A`` is
    5.7 C: the crossings of L0 + C ... L0 + 5 C lie inside the linear part, at least 0.3 C
    from the kinks, more than the bound lam C = 0.1 away.
    """

    def __init__(self, width: int = 16, height: int = 3, slope: float = 200.0,
                 speed: float = 400.0, still: bool = False) -> None:
        self.camera = Camera(width=width, height=height, fx=20.0, fy=20.0, cx=width / 2,
                             cy=height / 2)
        self.slope, self.speed, self.still = slope, speed, still
        self.top = 5.7 * C
        self.base = np.log(0.2)
        self.calls: list[int] = []

    def level(self, pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
        x = pixels % self.camera.width + 0.1 * (pixels // self.camera.width)
        if self.still:
            times = np.zeros_like(times)
        return self.base + np.clip(self.slope * (times - x / self.speed), 0.0, self.top)

    def luminance(self, pixels, times):
        pixels, times = np.asarray(pixels), np.asarray(times, dtype=np.float64)
        self.calls.append(len(pixels))
        return np.exp(self.level(pixels, times)) - EPS

    def frame(self, t):
        n = self.camera.width * self.camera.height
        return self.luminance(np.arange(n), np.full(n, t)).reshape(self.camera.height, -1)

    def subsamples(self, t):
        return self.frame(t)

    def depth(self, t):
        return np.zeros((self.camera.height, self.camera.width))

    def camera_velocity(self, t):
        return np.zeros(3), np.zeros(3)


def _run(source, t1=0.06, params=None, events=None, stats=None):
    cam = source.camera
    emulator = PixelEventEmulator((cam.height, cam.width), events or EventParams())
    stats = stats if stats is not None else PixelSamplingStats()
    blocks = list(pixel_blocks(source, emulator, 0.0, t1, C, EPS, params or SamplingParams(),
                               stats))
    return blocks, stats, emulator


def test_a_log_ramp_fires_every_event_at_its_exact_time():
    source = Ramp()
    blocks, stats, _ = _run(source)
    events = np.concatenate([b.events for b in blocks])
    expected = []
    for y in range(3):
        for x in range(16):
            start = (x + 0.1 * y) / source.speed
            expected += [(round((start + i * C / source.slope) * 1e9), x, y) for i in range(1, 6)]
    expected = np.array(sorted(expected))
    got = np.stack([events["t"], events["x"], events["y"]], axis=1).astype(np.int64)
    assert np.all(events["p"] == 1)
    assert np.all(np.diff(events["t"]) >= 0)                      # in time order
    assert len(got) == len(expected) == 240
    order = np.lexsort((got[:, 0], got[:, 2], got[:, 1]))
    order_expected = np.lexsort((expected[:, 0], expected[:, 2], expected[:, 1]))
    assert np.abs(got[order] - expected[order_expected]).max() <= 1000      # 1 microsecond
    assert stats.blocks == 6 and stats.full_renders == 7      # sub-sample frames at the block ends
    # Each pixel rises over 5.7 C / 200 = 5.7 ms: it needs samples inside its blocks, the
    # flat pixels (before and after the ramp) none.
    assert 0 < stats.pixel_samples < 48 * 6 * 100


def test_a_view_that_does_not_change_gives_no_events_and_no_pixel_samples():
    blocks, stats, _ = _run(Ramp(still=True))
    assert sum(len(b.events) for b in blocks) == 0
    assert stats.pixel_samples == 0 and stats.full_renders == 7


def test_every_interval_meets_the_bound_or_is_counted(monkeypatch):
    intervals = []
    real = PixelEventEmulator.advance_samples

    def spy(self, pixels, times, levels, *args):
        same = pixels[1:] == pixels[:-1]
        intervals.append((np.abs(np.diff(levels))[same], np.diff(times)[same]))
        return real(self, pixels, times, levels, *args)

    monkeypatch.setattr(PixelEventEmulator, "advance_samples", spy)
    params = SamplingParams(lam=0.5, min_rate=100.0, max_rate=1000.0)   # dt_min 1 ms
    _, stats, _ = _run(Ramp(slope=400.0), params=params)
    change = np.concatenate([c for c, _ in intervals])
    length = np.concatenate([d for _, d in intervals])
    broken = change > 0.5 * C
    assert stats.intervals == len(change)
    assert np.all(length[broken] < 2 * 1_000_000)                      # only at the max rate
    assert stats.at_max_rate == np.count_nonzero(broken) > 0


@pytest.mark.parametrize("preset", ["ideal", "realistic"])
def test_fed_with_whole_frames_it_gives_the_frame_emulators_events(preset):
    """One sample per pixel per block at common times: exactly EventEmulator's events."""
    rng = np.random.default_rng(0)
    shape = (9, 11)
    params = EventParams(contrast_on=C, contrast_off=C, noise=noise_preset(preset), seed=5)
    times = np.cumsum(rng.uniform(1e-4, 2e-3, 40))
    walk = np.cumsum(rng.normal(0, 0.15, (40, *shape)), axis=0)
    luminance = np.exp(walk) * 0.3
    frame = EventEmulator(shape, params)
    pixel = PixelEventEmulator(shape, params)
    log = np.log(luminance + EPS)
    frame.start(log[0], times[0], luminance[0])
    pixel.start(log[0], times[0], luminance[0])
    n = shape[0] * shape[1]
    pixels = np.repeat(np.arange(n), 2)
    for k in range(1, len(times)):
        want = frame.advance(log[k], times[k], luminance[k])
        t_ns = np.tile([round(times[k - 1] * 1e9), round(times[k] * 1e9)], n)
        levels = np.stack([log[k - 1].ravel(), log[k].ravel()], axis=1).ravel()
        lums = np.stack([luminance[k - 1].ravel(), luminance[k].ravel()], axis=1).ravel()
        got = pixel.advance_samples(pixels, t_ns.astype(np.int64), levels, lums,
                                    round(times[k] * 1e9), luminance[k])
        np.testing.assert_array_equal(got, want)
    state_frame, state_pixel = frame.get_state(), pixel.get_state()
    np.testing.assert_array_equal(state_pixel["last_t"], state_frame["last_t"])
    for key in ("ref", "level", "raw", "cutoff"):   # compiled kernels may round the last bit apart
        np.testing.assert_allclose(state_pixel[key], state_frame[key], rtol=0, atol=1e-12)


def test_continuing_after_any_block_gives_the_same_blocks():
    params = EventParams.preset("realistic", contrast=C, seed=2)
    reference, _, _ = _run(Ramp(), events=params)
    source = Ramp()
    emulator = PixelEventEmulator((3, 16), params)
    stats = PixelSamplingStats()
    run = pixel_blocks(source, emulator, 0.0, 0.06, C, EPS, SamplingParams(), stats)
    first = [next(run), next(run)]
    state, saved_stats = emulator.get_state(), replace(stats)
    resumed = PixelEventEmulator((3, 16), params)
    resumed.set_state(state)
    rest = list(pixel_blocks(Ramp(), resumed, 0.0, 0.06, C, EPS, SamplingParams(),
                             saved_stats, after=(first[-1].t, first[-1].observed)))
    assert len(first) + len(rest) == len(reference)
    for want, got in zip(reference, first + rest, strict=True):
        assert want.t == got.t
        np.testing.assert_array_equal(got.events, want.events)
    assert saved_stats == _run(Ramp(), events=params)[1]


def test_the_predicted_rate_spreads_over_the_distance_an_edge_travels():
    camera = Camera(width=64, height=8, fx=50.0, fy=50.0, cx=32.0, cy=4.0)
    log = np.zeros((8, 64))
    log[:, 32:] = 1.0                                       # one vertical edge
    depth = np.full((8, 64), 2.0)
    v = np.array([-1.0, 0.0, 0.0])                          # the image moves at 25 px/s in +x
    rate = rate_map(camera, np.exp(log), depth, [(v, np.zeros(3))], 0.2, 0.0)   # 5 px a block
    row = rate[4]
    assert row[31] == pytest.approx(25.0) and row[32] == pytest.approx(25.0)
    assert np.all(row[26:38] == pytest.approx(25.0)) and row[25] == row[38] == 0.0
    far = rate_map(camera, np.exp(log), depth, [(v * 100, np.zeros(3))], 0.2, 0.0)  # capped
    assert np.count_nonzero(far[4]) == 64 and MAX_DILATION < 500


@pytest.mark.parametrize("base", [1.0, 0.3, 0.1, 0.03])
def test_filtered_crossings_are_within_a_microsecond_at_several_illuminances(base):
    """A ramp of 1.1 log units over 1.1 ms from luminance ``base``: the cutoff (200 Hz at 1, down
    to its floor of 14.5 Hz at 0.0727 and below) changes with the luminance along the ramp.
    Sampled as the sampler's bound allows (every lam C = 0.1 log units), the events are those
    of the filter integrated with its cutoff varying continuously, within 1 us."""
    noise = NoiseParams(cutoff_hz=200.0, cutoff_intensity_ref=1.0)
    start = math.log(base)

    def u(t):
        return start + min(max(t / 1e-3, 0.0), 1.1)

    def omega(t):
        return 2 * math.pi * float(cutoff_frequency(np.full((1, 1), math.exp(u(t))), noise)[0, 0])

    times = np.r_[np.arange(12) * 100_000, 2_000_000, 5_000_000, 20_000_000, 40_000_000]
    levels = np.array([u(t * 1e-9) for t in times])
    emulator = PixelEventEmulator((1, 1), EventParams(noise=noise))
    emulator.start(levels[:1].reshape(1, 1), 0.0, np.exp(levels[:1]).reshape(1, 1))
    events = emulator.advance_samples(np.zeros(len(times), np.int64), times, levels,
                                      np.exp(levels), int(times[-1]),
                                      np.exp(levels[-1:]).reshape(1, 1))
    want = filtered_reference_events(u, omega, 0.04, C, start, step=2e-7)
    assert len(events) == len(want) == 5 and np.all(events["p"] == 1)
    assert np.abs(events["t"] - np.array([t for t, _ in want]) * 1e9).max() <= 1_000


def test_a_pixel_with_a_low_threshold_is_sampled_at_lam_of_its_own_threshold(monkeypatch):
    """Threshold mismatch sigma 0.03: the lowest of 48 pixels is ~2.5 sigma low. Held to the
    nominal C it would see changes of lam C = 0.1 per interval, 0.1 / C_p of its own
    threshold; held to its own, at most lam = 0.5 of it."""
    intervals = []
    real = PixelEventEmulator.advance_samples

    def spy(self, pixels, times, levels, *args):
        intervals.append((pixels[1:][pixels[1:] == pixels[:-1]],
                          np.abs(np.diff(levels))[pixels[1:] == pixels[:-1]]))
        return real(self, pixels, times, levels, *args)

    monkeypatch.setattr(PixelEventEmulator, "advance_samples", spy)
    params = EventParams(noise=NoiseParams(threshold_sigma=0.03), seed=3)

    def effective_lam(contrast_of):
        intervals.clear()
        source = Ramp()
        emulator = PixelEventEmulator((3, 16), params)
        own = np.minimum(emulator.c_on, emulator.c_off)
        stats = PixelSamplingStats()
        list(pixel_blocks(source, emulator, 0.0, 0.06, contrast_of(own), EPS, SamplingParams(),
                          stats))
        assert stats.at_max_rate == 0
        pix = np.concatenate([p for p, _ in intervals])
        change = np.concatenate([c for _, c in intervals])
        worst = np.zeros(48)
        np.maximum.at(worst, pix, change / own.ravel()[pix])
        return worst, own.ravel()

    own_lam, thresholds = effective_lam(lambda own: own)
    nominal_lam, _ = effective_lam(lambda own: C)
    low = int(np.argmin(thresholds))
    assert thresholds[low] < C - 2 * 0.03
    assert np.all(own_lam <= 0.5 + 1e-12)                       # every pixel, its own bound
    # Held to the nominal C it breaks its own bound (up to 0.1 / C_p = 0.87 allowed).
    assert nominal_lam[low] > 0.6


def _flat_grid(height: int, width: int, n: int = 2):
    """Sub-sample keys and normals of one lit plane facing the camera, (H n, W n)."""
    key = np.full((height * n, width * n), 1 | (1 << 16), dtype=np.uint32)
    normal = np.zeros((height * n, width * n, 3), dtype=np.float32)
    normal[..., 1] = -1.0
    return key, normal


def test_geometric_edges_mark_the_pixels_of_both_sub_samples_of_a_pair():
    key, normal = _flat_grid(4, 6)
    assert not geometric_edges(key, normal, (4, 6)).any()
    key[:, 7:] = 2 | (1 << 16)             # another shape from sub-sample column 7: pixel 3's
    edges = geometric_edges(key, normal, (4, 6))
    np.testing.assert_array_equal(edges, np.repeat([[0, 0, 0, 1, 0, 0]], 4, axis=0) > 0)
    key[:, 7:] = 1 | (1 << 16)
    key[:, 6:] = 2 | (1 << 16)             # between pixels 2 and 3: both
    edges = geometric_edges(key, normal, (4, 6))
    np.testing.assert_array_equal(edges, np.repeat([[0, 0, 1, 1, 0, 0]], 4, axis=0) > 0)


def test_geometric_edges_see_shadows_and_creases_not_curvature_or_the_sky():
    key, normal = _flat_grid(4, 6)
    key[6:, :] = 1                         # a shadow's edge (no light) between rows 2 and 3
    np.testing.assert_array_equal(geometric_edges(key, normal, (4, 6)).any(axis=1),
                                  [False, False, True, True])
    key, normal = _flat_grid(4, 6)
    turn = math.acos(EDGE_COS) * 1.1       # a crease a little sharper than the threshold
    normal[:, 6:] = [math.sin(turn), -math.cos(turn), 0.0]
    np.testing.assert_array_equal(geometric_edges(key, normal, (4, 6)).any(axis=0),
                                  [False, False, True, True, False, False])
    key, normal = _flat_grid(4, 6)         # a cylinder turning 0.9 EDGE's angle per sub-sample
    angle = np.arange(12) * math.acos(EDGE_COS) * 0.9
    normal[..., 0], normal[..., 1] = np.sin(angle), -np.cos(angle)
    assert not geometric_edges(key, normal, (4, 6)).any()
    key[:] = 0                             # nothing hit: normals are not looked at
    normal = np.random.default_rng(0).normal(size=normal.shape).astype(np.float32)
    assert not geometric_edges(key, normal, (4, 6)).any()


class EdgedRamp(Ramp):
    """The ramp, with a geometric edge between pixel columns ``column - 1`` and ``column`` in
    every sub-sample grid, and a fine renderer that differs from the coarse one by ``gain``
    (1: the same values)."""

    def __init__(self, column: int, gain: float = 1.0, **kwargs) -> None:
        super().__init__(**kwargs)
        self.column, self.gain = column, gain
        self.fine_calls: list[np.ndarray] = []
        self.geometry_calls = 0

    def geometry(self, t):
        height, width = self.camera.height, self.camera.width
        key, normal = _flat_grid(height, width, 1)
        key[:, self.column:] = 2
        self.geometry_calls += 1
        return key, normal

    def fine_luminance(self, pixels, times):
        self.fine_calls.append(np.asarray(pixels))
        return (np.exp(self.level(np.asarray(pixels), np.asarray(times, np.float64)))
                - EPS) * self.gain


def _run_edged(source, **kwargs):
    cam = source.camera
    emulator = PixelEventEmulator((cam.height, cam.width), EventParams())
    stats = PixelSamplingStats()
    blocks = list(pixel_blocks(source, emulator, 0.0, 0.06, C, EPS, SamplingParams(), stats,
                               **kwargs))
    return blocks, stats


def test_edge_pixels_go_to_the_fine_renderer_and_nothing_else_changes():
    plain, plain_stats = _run_edged(Ramp())
    source = EdgedRamp(column=7)
    edged, stats = _run_edged(source, edges=True)
    for want, got in zip(plain, edged, strict=True):        # same values: same events
        np.testing.assert_array_equal(got.events, want.events)
    fine = np.concatenate(source.fine_calls)
    assert set(np.unique(fine % 16)) == {6, 7}              # the two columns at the edge
    assert stats.edge_samples == len(fine) > 0
    assert source.geometry_calls == plain_stats.full_renders == 7     # each block boundary
    assert stats.pixel_samples == plain_stats.pixel_samples
    # Without ``edges`` the geometry is never asked for.
    source = EdgedRamp(column=7)
    _run_edged(source)
    assert source.geometry_calls == 0 and not source.fine_calls


def test_an_edge_pixel_takes_the_fine_value_at_boundaries_and_inside_blocks():
    """A fine renderer 10 % brighter: the edge columns' block-end values are its values, and
    their events are those of a ramp 10 % brighter (the same crossings of ref + k C, as the
    emulator starts from the fine value), the other columns' are unchanged."""
    plain, _ = _run_edged(Ramp())
    edged, _ = _run_edged(EdgedRamp(column=7, gain=1.1), edges=True)
    for want, got in zip(plain, edged, strict=True):
        columns = np.arange(16)
        edge = (columns == 6) | (columns == 7)
        np.testing.assert_array_equal(got.luminance[:, ~edge], want.luminance[:, ~edge])
        np.testing.assert_allclose(got.luminance[:, edge], want.luminance[:, edge] * 1.1,
                                   rtol=1e-6)
    want, got = (np.concatenate([b.events for b in run]) for run in (plain, edged))
    at_edge = np.isin(got["x"], [6, 7]), np.isin(want["x"], [6, 7])
    np.testing.assert_array_equal(got[~at_edge[0]], want[~at_edge[1]])
    assert np.count_nonzero(at_edge[0]) == np.count_nonzero(at_edge[1]) > 0
