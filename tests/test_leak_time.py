"""Leak events in continuous time: each is stamped where the drifting reference meets the level.

The leak moves a pixel's reference down at ``rate * C_on`` per second (times the interval's
jitter), linearly within each interval between two samples, so a static pixel whose reference
starts ``phi`` below its level fires its k-th leak event when ``phi + C_on * Lambda(t) = k C_on``,
``Lambda`` the pixel's integrated (jittered) rate. The tests solve that by hand:

- no jitter: ``t_k = (k - phi / C_on) / rate``, exactly (to the nanosecond the stamps are
  rounded to), on every emulator (frames and per-pixel samples; numba and Dr.Jit), with the
  photoreceptor low-pass on and off, and with a ramping signal beside the leak;
- with jitter: the same, with the emulator's own normal draws replayed to integrate
  ``Lambda`` piece by piece;
- the distribution: with a uniform initial phase, ``P(t_1 <= t) = rate * t`` exactly (the
  jitter has mean zero), so ``rate * t_1`` of many pixels is uniform on [0, 1]: a
  Kolmogorov-Smirnov test. Stamps on the sampling grid (the old rule: each leak event at the
  start of the interval whose drift caused it) fail it;
- a static scene simulated with the realistic preset: its leak events lie on distinct times,
  none on the 10-ms render grid and none at t = 0.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from sim.eventio import read_events
from sim.events import EventEmulator, EventParams
from sim.noise import CAUSE_LEAK, NoiseParams, noise_preset
from sim.pixel_sampling import PixelEventEmulator
from sim.scene import parse_scene
from sim.simulate import simulate
from tests.conftest import scene_text

STEP_NS = 10_000_000                                  # samples every 10 ms, as a static scene's
C_ON = 0.2
KERNELS = ["numba", "drjit"]


def _params(rate: float, jitter: float = 0.0, cutoff_hz: float = 0.0, cov: float = 0.0,
            seed: int = 4) -> EventParams:
    noise = NoiseParams(leak_rate=rate, leak_jitter=jitter, leak_rate_cov_decades=cov,
                        cutoff_hz=cutoff_hz, initial_phase=True)
    return EventParams(contrast_on=C_ON, contrast_off=C_ON, noise=noise, seed=seed)


def _frames(emulator: EventEmulator, level: np.ndarray, n_steps: int, slope: float = 0.0
            ) -> tuple[np.ndarray, np.ndarray]:
    """Whole frames every 10 ms, the level ramping at ``slope`` per second; the events and
    their causes."""
    lum = np.exp(level)
    events, causes = [], []
    for k in range(1, n_steps + 1):
        t = k * STEP_NS * 1e-9
        events.append(emulator.advance(level + slope * t, t, lum * np.exp(slope * t)))
        causes.append(emulator.last_causes)
    return np.concatenate(events), np.concatenate(causes)


def _samples(emulator: PixelEventEmulator, level: np.ndarray, n_steps: int, per_block: int = 5
             ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel samples every 10 ms of a static level, in blocks of ``per_block`` intervals;
    the events and their causes."""
    n = level.size
    flat = level.reshape(-1)
    events, causes = [], []
    for b0 in range(0, n_steps, per_block):
        times = np.arange(b0, min(b0 + per_block, n_steps) + 1, dtype=np.int64) * STEP_NS
        pixels = np.repeat(np.arange(n, dtype=np.int64), len(times))
        events.append(emulator.advance_samples(
            pixels, np.tile(times, n), np.repeat(flat, len(times)),
            np.repeat(np.exp(flat), len(times)), int(times[-1]), np.exp(level)))
        causes.append(emulator.last_causes)
    return np.concatenate(events), np.concatenate(causes)


def _expected(phi: np.ndarray, rate: np.ndarray, slope: float, t_end_ns: int) -> list:
    """Analytic (t_ns, flat pixel) of every event: ``phi + (slope + rate C) t = k C``."""
    out = []
    for p, (f, r) in enumerate(zip(phi, rate, strict=True)):
        k = 1
        while True:
            t = (k * C_ON - f) / (slope + r * C_ON)
            if t * 1e9 > t_end_ns:
                break
            out.append((t * 1e9, p))
            k += 1
    return sorted(out, key=lambda e: (e[1], e[0]))


def _compare(events: np.ndarray, width: int, expected: list, bound_ns: float = 1.0) -> None:
    pixel = events["y"].astype(np.int64) * width + events["x"]
    order = np.lexsort((events["t"], pixel))
    got_t, got_p = events["t"][order], pixel[order]
    want_t = np.array([t for t, _ in expected])
    want_p = np.array([p for _, p in expected])
    assert len(got_t) == len(want_t)
    np.testing.assert_array_equal(got_p, want_p)
    assert np.max(np.abs(got_t - want_t)) <= bound_ns


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("cutoff_hz", [0.0, 200.0], ids=["unfiltered", "low-pass"])
@pytest.mark.parametrize("emulator_class", [EventEmulator, PixelEventEmulator],
                         ids=["frames", "per-pixel"])
def test_a_static_pixel_leaks_where_the_drifting_reference_meets_its_level(emulator_class,
                                                                          cutoff_hz, kernel):
    """No jitter, no spread: the k-th leak event of a static pixel at (k - phi / C) / rate,
    within 1 ns (the rounding of the stamps), every one labelled leak and none at t = 0."""
    shape, rate = (3, 4), 23.0
    emulator = emulator_class(shape, _params(rate, cutoff_hz=cutoff_hz), kernel=kernel)
    level = np.log(np.linspace(20.0, 200.0, 12).reshape(shape))
    emulator.start(level, 0.0, np.exp(level))
    phi = (level - emulator.ref).reshape(-1)
    assert np.all((phi >= 0) & (phi < C_ON))
    n_steps = 50                                                           # 0.5 s
    run = _frames if emulator_class is EventEmulator else _samples
    events, causes = run(emulator, level, n_steps)
    _compare(events, shape[1], _expected(phi, np.full(phi.size, rate), 0.0, n_steps * STEP_NS))
    assert np.all(causes == CAUSE_LEAK) and np.all(events["p"] == 1)
    assert np.count_nonzero(events["t"] % STEP_NS == 0) == 0


@pytest.mark.parametrize("kernel", KERNELS)
def test_leak_and_a_ramping_signal_cross_together(kernel):
    """A level rising at ``s`` per second and a reference falling at ``rate C``: the events at
    ``(k C - phi) / (s + rate C)``, to 1 ns."""
    shape, rate, slope = (2, 3), 30.0, 1.5
    emulator = EventEmulator(shape, _params(rate), kernel=kernel)
    level = np.log(np.linspace(30.0, 90.0, 6).reshape(shape))
    emulator.start(level, 0.0, np.exp(level))
    phi = (level - emulator.ref).reshape(-1)
    events, causes = _frames(emulator, level, 30, slope=slope)
    _compare(events, shape[1], _expected(phi, np.full(phi.size, rate), slope, 30 * STEP_NS))
    # The level gains 1.5 a second, the drift 6: about 6 / 7.5 of the crossings are the leak's.
    share = np.count_nonzero(causes == CAUSE_LEAK) / len(causes)
    assert 0.7 < share < 0.85


@pytest.mark.parametrize("kernel", KERNELS)
def test_with_jitter_each_interval_drifts_at_its_own_rate(kernel):
    """Jitter 0.5: the emulator's normal draws replayed (one per pixel and interval, in its
    order), the drift integrated interval by interval and each crossing solved by hand."""
    shape, rate, jitter = (2, 5), 17.0, 0.5
    params = _params(rate, jitter=jitter, cov=0.2)
    emulator = PixelEventEmulator(shape, params, kernel=kernel)
    level = np.log(np.linspace(10.0, 300.0, 10).reshape(shape))
    emulator.start(level, 0.0, np.exp(level))
    phi = (level - emulator.ref).reshape(-1)
    rates = emulator.leak_rates.reshape(-1)
    replay = np.random.default_rng()
    replay.bit_generator.state = emulator.get_state()["rng"]
    n_steps, per_block = 40, 5
    normals = []
    for _ in range(n_steps // per_block):               # the draws of each block, pixel-major
        normals.append(replay.standard_normal(shape[0] * shape[1] * per_block)
                       .reshape(-1, per_block))
    normals = np.concatenate(normals, axis=1)
    events, causes = _samples(emulator, level, n_steps, per_block)
    expected = []
    for p in range(phi.size):
        gained = phi[p]                                  # level minus reference, log units
        k = 1
        for i in range(n_steps):
            d = STEP_NS * 1e-9 * rates[p] * max(0.0, 1.0 - jitter * normals[p, i]) * C_ON
            while gained + d >= k * C_ON:
                expected.append((i * STEP_NS + (k * C_ON - gained) / d * STEP_NS, p))
                k += 1
            gained += d
    expected.sort(key=lambda e: (e[1], e[0]))
    _compare(events, shape[1], expected)
    assert np.all(causes == CAUSE_LEAK)


def test_first_leak_times_follow_the_models_law():
    """``P(t_1 <= t) = rate_p t`` for a uniform initial phase (the jitter's mean is 0), so
    ``rate_p t_1`` is uniform on [0, 1]: Kolmogorov-Smirnov over 3,072 static pixels with the
    realistic preset's jitter and spread of rates. Stamps on the 10-ms grid (spacing about
    0.05 in ``rate_p t``) fail it (checked: p < 1e-6)."""
    shape = (48, 64)
    params = _params(5.0, jitter=0.1, cov=0.1, seed=11)
    emulator = PixelEventEmulator(shape, params, kernel="numba")
    level = np.full(shape, np.log(100.0))
    emulator.start(level, 0.0, np.exp(level))
    rates = emulator.leak_rates.reshape(-1)
    n_steps = 70                                                     # 0.7 s
    events, causes = _samples(emulator, level, n_steps, per_block=10)
    assert np.all(causes == CAUSE_LEAK)
    pixel = events["y"].astype(np.int64) * shape[1] + events["x"]
    first = np.full(rates.size, np.inf)
    np.minimum.at(first, pixel, events["t"] * 1e-9)
    sure = rates * n_steps * STEP_NS * 1e-9 >= 1.0        # pixels certain to fire in the run
    assert sure.sum() > 3000 and np.all(np.isfinite(first[sure]))
    u = rates[sure] * first[sure]
    assert stats.kstest(u, "uniform").pvalue > 0.01
    gridded = rates[sure] * np.floor(first[sure] / (STEP_NS * 1e-9)) * STEP_NS * 1e-9
    assert stats.kstest(gridded, "uniform").pvalue < 1e-6


def test_a_static_scene_fires_leak_events_off_the_render_grid(tmp_path):
    """The issue's case, smaller: a static scene, realistic noise (leak 0.1 Hz per pixel)
    turned up to 2 Hz, 48x36, 0.5 s. Every leak event on its own time, none on the 10-ms
    grid and none at t = 0."""
    objects = ('[[objects]]\nname = "wall"\ntype = "rectangle"\ncenter = [0.0, 1.5, 0.0]\n'
               'size = [4.0, 3.0]\nnormal = [0.0, -1.0, 0.0]\n'
               'material = { texture = { type = "checkerboard", squares = [6, 4] } }\n')
    camera = "[camera]\nwidth = 48\nheight = 36\nfx = 40.0\nfy = 40.0\ncx = 23.5\ncy = 17.5\n"
    scene = parse_scene(scene_text(objects, camera=camera, duration=0.5,
                                   extra="[render]\nspp = 1\n"))
    noise = dataclasses.replace(noise_preset("realistic"), leak_rate=2.0)
    simulate(scene, tmp_path / "seq", progress=False, event_formats=("h5",),
             events=EventParams(seed=scene.seed, noise=noise))
    from sim.sequence import load_sequence

    labels = load_sequence(tmp_path / "seq").event_labels()
    leak = labels[labels["cause"] == CAUSE_LEAK]["t"]
    assert len(leak) > 600                                   # about 48 * 36 * 2 * 0.5 = 1,728
    assert len(np.unique(leak)) > 0.99 * len(leak)
    assert np.count_nonzero(leak % STEP_NS == 0) == 0
    assert leak.min() > 0
    assert len(read_events(tmp_path / "seq" / "events.h5")) == len(labels)
