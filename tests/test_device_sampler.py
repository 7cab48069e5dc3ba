"""The per-pixel sampler's blocks on Dr.Jit's device (sim._drjit_sampling) against the reference
path (numba and NumPy, sim.pixel_sampling): the shader's device entry point gives its host
values bit for bit, and whole runs of pixel_blocks on non-planar scenes seen from a turning
camera give the same samples, refinements, observed rates and events."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from scenes import resolve_scene
from sim.events import EventParams
from sim.noise import noise_preset
from sim.pixel_sampling import PixelEventEmulator, PixelSamplingStats, pixel_blocks
from sim.render import Renderer
from sim.sampling import SamplingParams
from sim.scene import load_scene
from sim.shader import MIN_LAUNCH, EventShader
from sim.simulate._events import _EventCamera, _ShaderSource

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

CASES = {"boxes_6dof": 3.0, "complex_sphere": 1.0, "poster_6dof": 0.5}
"""Scenes seen from a turning camera (boxes and their shadows, a sphere: non-planar; a poster
under six degrees of freedom) and the start of the window run here, where the check refines
intervals (a height field's or shapes_6dof's windows refined none)."""


def _renderer(name: str, size=(40, 30)) -> Renderer:
    scene = load_scene(resolve_scene(name))
    return Renderer(replace(scene, camera=scene.camera.with_resolution(*size)), spp=1)


def _device(values) -> np.ndarray:
    return np.asarray(values.numpy() if hasattr(values, "numpy") else values)


@pytest.mark.parametrize("count", [7, MIN_LAUNCH + 3, 3000])
def test_luminance_device_is_luminance_bit_for_bit(count, monkeypatch):
    import mitsuba as mi

    renderer = _renderer("boxes_6dof")
    shader = EventShader(renderer, 4, t0=3.0, t1=3.2)
    if count == 3000:            # several launches of one call
        monkeypatch.setattr(shader, "_samples_per_launch", 1024)
    rng = np.random.default_rng(count)
    pixels = np.sort(rng.integers(0, 40 * 30, count))
    times = rng.uniform(3.0, 3.2, count)
    times[:2] = 3.0, 3.2                                   # both ends of the span
    expected = shader.luminance(pixels, times)
    got = _device(shader.luminance_device(mi.UInt32(pixels.astype(np.uint32)),
                                          mi.Float64(times)))
    assert got.dtype == np.float32 and got.shape == expected.shape
    np.testing.assert_array_equal(got, expected)
    wider = _device(shader.luminance_device(mi.UInt32(pixels.astype(np.uint32)),
                                            mi.Float64(times), between=(3.0, 3.2)))
    np.testing.assert_array_equal(wider, expected)             # a pose table from the bounds
    assert np.ptp(expected) > 0                            # a scene that is seen


@pytest.mark.parametrize("limits", [None, (2 * 40 * 30 * 4, 3)])
def test_subsamples_many_are_subsamples_bit_for_bit(limits, monkeypatch):
    """Several frames a launch; with small limits, two frames a launch and a pose table too
    short for the times of one launch (the launch is cut)."""
    shader = EventShader(_renderer("complex_sphere"), 4, t0=1.0, t1=1.2)
    if limits is not None:
        monkeypatch.setattr("sim.shader.MAX_RAYS_PER_LAUNCH", limits[0])
        monkeypatch.setattr("sim.shader.POSE_TABLE_NODES", limits[1])
    times = np.array([1.0, 1.01, 1.0101, 1.05, 1.2])
    frames = shader.subsamples_many(times)
    assert len(frames) == len(times)
    for t, frame in zip(times, frames, strict=True):
        np.testing.assert_array_equal(frame, shader.subsamples(float(t)))
    assert not np.array_equal(frames[0], frames[-1])


def test_luminance_device_refuses_a_span_beyond_one_pose_table(monkeypatch):
    import mitsuba as mi

    shader = EventShader(_renderer("boxes_6dof"), 1, t0=3.0, t1=3.2)
    monkeypatch.setattr("sim.shader.POSE_TABLE_NODES", 4)
    with pytest.raises(ValueError, match="pose grid"):
        shader.luminance_device(mi.UInt32([0, 1]), mi.Float64([3.0, 3.1]))


def _blocks(renderer, start, device, params, sampling, contrast, kernel="numba"):
    camera = _EventCamera(renderer, 4, start, start + 0.06)
    source = _ShaderSource(camera)
    shape = (renderer.camera.height, renderer.camera.width)
    emulator = PixelEventEmulator(shape, params, kernel)
    stats = PixelSamplingStats()
    if contrast is None:
        contrast = np.minimum(emulator.c_on, emulator.c_off)
    blocks = list(pixel_blocks(source, emulator, start, start + 0.06, contrast,
                               params.log_eps, sampling, stats, device=device))
    return blocks, stats, emulator


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("preset", ["ideal", "realistic"])
def test_device_blocks_are_the_reference_blocks(name, preset):
    """Long blocks (25 Hz) and a tight bound, so that the check refines many intervals over
    several levels; each pixel's own threshold (realistic: mismatch) scales its bound."""
    renderer = _renderer(name)
    params = EventParams(noise=noise_preset(preset), seed=5)
    sampling = SamplingParams(lam=0.25, min_rate=25.0)
    ref, ref_stats, ref_emu = _blocks(renderer, CASES[name], None, params, sampling, None)
    dev, dev_stats, dev_emu = _blocks(renderer, CASES[name], "llvm", params, sampling, None)
    assert ref_stats.midpoint_samples > 100 and ref_stats.pixel_samples > 5000
    assert dev_stats == ref_stats
    assert len(dev) == len(ref) >= 2
    for a, b in zip(dev, ref, strict=True):
        assert a.t == b.t
        # The levels' log is Dr.Jit's (within an ulp or two of NumPy's): the slopes agree to
        # about 1e-12 of themselves.
        np.testing.assert_allclose(a.observed, b.observed, rtol=1e-9, atol=0)
        np.testing.assert_array_equal(a.events, b.events)
    assert sum(len(b.events) for b in ref) > 50
    for key, value in ref_emu.get_state().items():
        if np.asarray(value).dtype.kind == "f":
            np.testing.assert_allclose(dev_emu.get_state()[key], value, rtol=0, atol=1e-14,
                                       err_msg=key)
        else:
            np.testing.assert_array_equal(dev_emu.get_state()[key], value, err_msg=key)


@pytest.mark.parametrize("name", ["boxes_6dof", "complex_sphere"])
@pytest.mark.parametrize("preset", ["ideal", "realistic"])
def test_the_emulator_fed_on_the_device_fires_the_reference_events(name, preset):
    """The device path's samples handed to the Dr.Jit emulator without leaving the device
    (advance_device): without the low-pass (ideal) the reference's events bit for bit; with
    it (realistic) the same events, each within 1 ns (Dr.Jit's exp and log,
    sim._drjit_events)."""
    renderer = _renderer(name)
    params = EventParams(noise=noise_preset(preset), seed=5)
    sampling = SamplingParams(lam=0.25, min_rate=25.0)
    ref, ref_stats, _ = _blocks(renderer, CASES[name], None, params, sampling, None)
    dev, dev_stats, emu = _blocks(renderer, CASES[name], "llvm", params, sampling, None,
                                  kernel="drjit")
    assert emu.kernel == "drjit" and dev_stats == ref_stats
    got = np.concatenate([b.events for b in dev])
    expected = np.concatenate([b.events for b in ref])
    assert len(expected) > 50
    if preset == "ideal":
        np.testing.assert_array_equal(got, expected)
    else:
        assert len(got) == len(expected)
        for key in ("x", "y", "p"):
            np.testing.assert_array_equal(np.sort(got[key]), np.sort(expected[key]))
        assert np.max(np.abs(np.sort(got["t"]) - np.sort(expected["t"]))) <= 1


def test_advance_device_needs_the_drjit_kernel():
    emulator = PixelEventEmulator((2, 2), EventParams(), "numba")
    emulator.start(np.zeros((2, 2)), 0.0)
    with pytest.raises(ValueError, match="drjit kernel"):
        emulator.advance_device(np.full(4, 2), None, None, None, 1000, np.ones((2, 2)))


def test_a_run_can_fail_the_comparison():
    """The comparison above sees a changed sample: the reference with another bound differs."""
    renderer = _renderer("complex_sphere")
    params = EventParams(noise=noise_preset("ideal"), seed=5)
    dev = _blocks(renderer, 1.0, "llvm", params, SamplingParams(lam=0.25, min_rate=25.0), None)
    ref = _blocks(renderer, 1.0, None, params, SamplingParams(lam=0.3, min_rate=25.0), None)
    assert dev[1] != ref[1]


def test_simulate_writes_the_reference_events_with_the_device_path(tmp_path, monkeypatch):
    """End to end (the driver, its checkpoints every block, the event files): the device path,
    simulate's default on a JIT variant, writes the reference path's events."""
    from sim.eventio import read_events
    from sim.simulate import simulate
    from sim.simulate._events import _PixelSampler

    scene = load_scene(resolve_scene("complex_sphere"))
    scene = replace(scene, camera=scene.camera.with_resolution(48, 36))
    runs = {}
    for on_device in (False, True):
        monkeypatch.setattr(_PixelSampler, "on_device", on_device)
        folder = tmp_path / str(on_device)
        result = simulate(scene, folder, start=1.0, duration=0.04, progress=False,
                          with_events=True, event_formats=("h5",), sampler="pixel",
                          motion_truth=False, events=EventParams.preset("realistic", seed=2),
                          sampling=SamplingParams(lam=0.25, min_rate=50.0))
        runs[on_device] = (result, read_events(folder / "events.h5"))
    (ref, ref_events), (dev, dev_events) = runs[False], runs[True]
    assert len(ref_events) > 50 and dev.n_events == ref.n_events
    assert dev.event_pixel_samples == ref.event_pixel_samples
    for key in ("t", "x", "y", "p"):
        np.testing.assert_array_equal(dev_events[key], ref_events[key])


def _variant_device(variant: str) -> str:
    """The Dr.Jit device of the suite's variant (the prediction runs on the CPU's ``llvm``
    under ``scalar_rgb``)."""
    return "cuda" if variant.startswith("cuda") else "llvm"


@pytest.mark.parametrize("n", [1, 2, 3, 5, 7])
def test_the_prediction_on_the_device_is_numbas_bit_for_bit(n, variant):
    """:func:`sim._drjit_sampling.device_rate` and ``device_prediction`` against
    :func:`sim.pixel_sampling.rate_map` and ``_intra_counts`` (numba, themselves NumPy's bit
    for bit: tests/test_sampler_kernels.py) on random sub-samples over decades, zero depths,
    a distorted camera, blocks whose dilation is 0 (a camera at rest), 1 or tens of pixels,
    with and without the last block's rates and the pixels' threshold scale."""
    from sim._drjit_sampling import _module, device_centres, device_prediction, device_rate
    from sim.pixel_sampling import (
        MARGIN,
        _dilation_of,
        _flow_args,
        _intra_counts,
        _log_weights,
        rate_map,
    )
    from sim.sampling import _twist
    from tests.test_sampler_kernels import _camera, _luminance

    device = _variant_device(variant)
    m = _module(device)
    rng = np.random.default_rng(n)
    width, height = 31, 19
    radii = set()
    for trial in range(4):
        camera = _camera(width, height, distorted=trial % 2 == 0)
        sub = _luminance(rng, (height * n, width * n))
        eps = [0.43, 1e-3, 5.0, 0.1][trial]
        depth = rng.uniform(0.1, 8.0, (height, width)).astype(np.float32)
        depth[rng.random(depth.shape) < 0.1] = 0.0
        twists = [(rng.normal(size=3) * 0.5, rng.normal(size=3) * 0.3) for _ in range(2)]
        if trial == 2:                    # at rest: no dilation (hypot decides, by numba)
            twists = [(np.zeros(3), np.zeros(3))] * 2
        block_ns = [10_000_000, 100_000, 1_000, 200_000_000][trial]
        centres = camera.normalized_pixel_centres()
        weight, logw, _ = _log_weights(camera, sub, eps)
        args = (weight, logw, (height, width), float(camera.fx), float(camera.fy),
                device_centres(centres, device), depth,
                np.array([_twist(v, w) for v, w in twists]),
                _dilation_of(_flow_args(camera, centres, depth, twists), block_ns * 1e-9))
        rate, radius = device_rate(*args, device=device)
        want = rate_map(camera, sub, depth, twists, block_ns * 1e-9, eps, centres)
        np.testing.assert_array_equal(rate.numpy().reshape(height, width), want)
        radii.add(min(radius, 2))
        log_b = rng.normal(size=height * width)
        log_e = log_b + rng.normal(size=height * width) * 0.1
        observed = 10.0 ** rng.uniform(-3, 5, height * width)
        scale = rng.uniform(0.5, 2.0, height * width)
        for obs, sc in ((None, None), (observed, scale)):
            inner, total, _ = device_prediction(
                *args, block_ns * 1e-9, m.Float64(log_b), m.Float64(log_e),
                None if obs is None else m.Float64(obs), None if sc is None else m.Float64(sc),
                MARGIN * 0.1, max(block_ns // 50_000, 1), device)
            counts = _intra_counts(want.reshape(-1), log_b, log_e, obs, sc, block_ns, 0.1,
                                   50_000)
            np.testing.assert_array_equal(inner.numpy().astype(np.int64), counts)
            assert total == counts.sum()
    assert radii == {0, 1, 2}


def test_the_prediction_of_wide_pixels_is_numbas_sent_to_the_device(variant):
    """8x8 sub-samples a pixel and more (NumPy's pairwise sums, not ported): the device path
    takes numba's counts, and device_prediction refuses them."""
    from sim._drjit_sampling import _module, device_centres, device_prediction
    from sim.pixel_sampling import (
        _Block,
        _intra_counts,
        _log_weights,
        _predicted_on_device,
        rate_map,
    )
    from tests.test_sampler_kernels import _camera, _luminance

    device = _variant_device(variant)
    rng = np.random.default_rng(8)
    camera = _camera(7, 5, distorted=True)
    sub = _luminance(rng, (40, 56))
    depth = rng.uniform(0.1, 8.0, (5, 7))
    twists = [(np.array([0.3, 0.0, 0.1]), np.array([0.0, 0.2, 0.0]))] * 2
    centres = camera.normalized_pixel_centres()
    log_b, log_e = rng.normal(size=35), rng.normal(size=35)
    m = _module(device)
    block = _Block(0, 10_000_000, sub, None, log_b, None, None, log_e, None, depth, twists)
    kept: dict = {}
    inner, total = _predicted_on_device(device, kept, camera, [block], m.Float64(log_b),
                                        m.Float64(log_e), 0.43, centres, None, None, 0.1,
                                        50_000)
    want = _intra_counts(rate_map(camera, sub, depth, twists, 0.01, 0.43, centres).reshape(-1),
                         log_b, log_e, None, None, 10_000_000, 0.1, 50_000)
    np.testing.assert_array_equal(inner.numpy().astype(np.int64), want)
    assert total == want.sum() and "centres" in kept
    weight, logw, _ = _log_weights(camera, sub, 0.43)
    with pytest.raises(ValueError, match="7x7"):
        device_prediction(weight, logw, (5, 7), 1.0, 1.0, device_centres(centres, device),
                          depth, np.zeros((1, 6)), lambda top: 0, 0.01, None, None, None, None,
                          0.05, 200, device)
