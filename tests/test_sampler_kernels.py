"""The per-pixel sampler's compiled per-block kernels against the NumPy expressions they
replaced (issue 23, item 4), bit for bit on random inputs: the motion field, the predicted rate
map (one-sided sub-sample gradients, their weighted per-pixel sums, the motion field of each
twist, the dilation) and the samples each pixel gets inside a block."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from sim.camera import Camera
from sim.pixel_sampling import (
    MARGIN,
    MAX_DILATION,
    _block_samples,
    _fill_middle,
    _insert_samples,
    _intra_counts,
    _pairwise_sum,
    _plus,
    rate_map,
)
from sim.sampling import _one_sided_gradient, motion_field


def _numpy_motion_field(camera, depth, v_cam, w_cam, centres=None):
    """``sim.sampling.motion_field`` as it was in NumPy (commit 0b557af)."""
    xy = camera.normalized_pixel_centres() if centres is None else centres
    x, y = xy[..., 0], xy[..., 1]
    z = np.where(depth > 0, depth, np.inf)
    vx, vy, vz = np.asarray(v_cam, dtype=np.float64)
    wx, wy, wz = np.asarray(w_cam, dtype=np.float64)
    px = -vx - z * (wy - wz * y)
    py = -vy - z * (wz * x - wx)
    pz = -vz - z * (wx * y - wy * x)
    with np.errstate(invalid="ignore", divide="ignore"):
        du = camera.fx * (px - x * pz) / z
        dv = camera.fy * (py - y * pz) / z
    seen = depth > 0
    return np.where(seen, du, 0.0), np.where(seen, dv, 0.0)


def _numpy_rate_map(camera, subsamples, depth, twists, seconds, log_eps, centres=None):
    """``sim.pixel_sampling.rate_map`` as it was in NumPy (commit 0b557af)."""
    height, width = camera.height, camera.width
    luminance = np.asarray(subsamples, dtype=np.float32)
    n = luminance.shape[0] // height
    weight = luminance + np.float32(log_eps)
    grad_u, grad_v = _one_sided_gradient(np.log(weight))      # (NumPy, kept)

    def per_pixel(values):
        rows = values.reshape(height, n, width * n).sum(axis=1)
        return rows.reshape(height, width, n).sum(axis=2, dtype=np.float64) / (n * n)

    mean = per_pixel(weight)
    grad_u *= weight
    grad_v *= weight
    slope_u = per_pixel(grad_u) * (n / mean)
    slope_v = per_pixel(grad_v) * (n / mean)
    rate = np.zeros((height, width))
    speed = 0.0
    for v_cam, w_cam in twists:
        flow_u, flow_v = _numpy_motion_field(camera, depth, v_cam, w_cam, centres)
        rate = np.maximum(rate, slope_u * np.abs(flow_u) + slope_v * np.abs(flow_v))
        speed = max(speed, float(np.max(np.hypot(flow_u, flow_v), initial=0.0)))
    radius = min(MAX_DILATION, math.ceil(speed * seconds))
    if radius > 0:
        kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
        rate = cv2.dilate(rate, kernel, borderType=cv2.BORDER_REPLICATE)
    return rate


def _numpy_intra_counts(rate, log_b, log_e, observed, scale, block_ns, bound, dt_min_ns):
    """``pixel_blocks``' rate floor and ``_intra_counts`` as they were in NumPy."""
    rate = np.maximum(rate, np.abs(log_e - log_b) / (block_ns * 1e-9))
    if observed is not None:
        rate = np.maximum(rate, observed)
    if scale is not None:
        rate = rate * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        wanted = np.ceil(rate * (block_ns * 1e-9) / (MARGIN * bound))
    wanted = np.nan_to_num(wanted, nan=0.0, posinf=0.0)
    most = max(block_ns // dt_min_ns, 1)
    return (np.clip(wanted, 1, most) - 1).astype(np.int64)


def _camera(width, height, distorted):
    return Camera(width=width, height=height, fx=0.9 * width, fy=0.95 * width,
                  cx=width / 2 - 0.3, cy=height / 2 + 0.2,
                  distortion=(-0.2, 0.05, 0.001, -0.002, 0.0) if distorted else (0.0,) * 5)


def _luminance(rng, shape):
    """Sub-sample luminances over decades, with exact zeros, ties and a few extreme values (the
    float32 sums then round in the order they are taken)."""
    values = (10.0 ** rng.uniform(-4, 4, shape)).astype(np.float32)
    values[rng.random(shape) < 0.05] = 0.0
    values[rng.random(shape) < 0.05] = 1.0
    values[rng.random(shape) < 0.01] = np.float32(3e7)
    return values


@pytest.mark.parametrize("distorted", [False, True])
def test_the_motion_field_kernel_is_numpys_expression(distorted):
    rng = np.random.default_rng(1)
    camera = _camera(37, 23, distorted)
    depth = rng.uniform(0.05, 20.0, (23, 37))
    depth[rng.random(depth.shape) < 0.2] = 0.0
    depth[0, 0], depth[1, 1] = np.nan, -1.0
    for dtype in (np.float64, np.float32):
        for _ in range(5):
            v, w = rng.normal(size=3) * 2.0, rng.normal(size=3)
            got = motion_field(camera, depth.astype(dtype), v, w)
            want = _numpy_motion_field(camera, depth.astype(dtype), v, w)
            for a, b in zip(got, want, strict=True):
                assert a.dtype == np.float64
                assert np.array_equal(a.view(np.int64), b.view(np.int64))


@pytest.mark.parametrize("n", [1, 2, 3, 4, 8, 9])
def test_the_rate_map_kernels_are_numpys_expression(n):
    rng = np.random.default_rng(n)
    width, height = 29, 17
    camera = _camera(width, height, distorted=n % 2 == 0)
    for trial in range(3):
        sub = _luminance(rng, (height * n, width * n))
        depth = rng.uniform(0.1, 8.0, (height, width)).astype(np.float32)
        depth[rng.random(depth.shape) < 0.1] = 0.0
        twists = [(rng.normal(size=3) * 0.5, rng.normal(size=3) * 0.3) for _ in range(2)]
        seconds = [0.01, 1e-4, 0.0][trial]
        eps = [0.43, 1e-3, 5.0][trial]
        got = rate_map(camera, sub, depth, twists, seconds, eps)
        want = _numpy_rate_map(camera, sub, depth, twists, seconds, eps)
        assert got.dtype == np.float64 and got.shape == (height, width)
        assert np.array_equal(got, want)


def test_the_rate_map_kernels_match_at_a_built_in_sensors_size():
    """240x180 with 2x2 sub-samples (the default ``event_spp`` = 4): NumPy's reductions run
    over long rows here, so their order is checked where it matters."""
    rng = np.random.default_rng(7)
    camera = _camera(240, 180, distorted=True)
    sub = _luminance(rng, (360, 480))
    depth = rng.uniform(0.2, 3.0, (180, 240))
    twists = [(np.array([0.3, 0.0, 0.01]), np.array([0.0, 0.1, 0.0])),
              (np.array([0.31, 0.0, 0.0]), np.array([0.02, 0.1, 0.0]))]
    centres = camera.normalized_pixel_centres()
    got = rate_map(camera, sub, depth, twists, 0.01, 0.43, centres)
    assert np.array_equal(got, _numpy_rate_map(camera, sub, depth, twists, 0.01, 0.43, centres))


def test_the_intra_counts_kernel_is_numpys_expression():
    rng = np.random.default_rng(3)
    size = 5000
    rate = 10.0 ** rng.uniform(-3, 6, size)
    rate[:4] = [np.nan, np.inf, 0.0, 1e300]
    log_b = rng.normal(size=size)
    log_e = log_b + rng.normal(size=size) * rng.choice([0.0, 0.01, 3.0], size)
    observed = 10.0 ** rng.uniform(-3, 5, size)
    observed[4:6] = [np.nan, np.inf]
    scale = rng.uniform(0.5, 2.0, size)
    for obs in (None, observed):
        for sc in (None, scale):
            for block_ns, dt_min_ns in ((10_000_000, 50_000), (3_333_333, 50_000),
                                        (40_000, 50_000)):
                got = _intra_counts(rate, log_b, log_e, obs, sc, block_ns, 0.1, dt_min_ns)
                want = _numpy_intra_counts(rate, log_b, log_e, obs, sc, block_ns, 0.1,
                                           dt_min_ns)
                assert got.dtype == np.int64
                assert np.array_equal(got, want)


@pytest.mark.parametrize("n", [2, 3, 7, 8, 9, 16, 17, 130, 300, 1000])
def test_float64_sums_of_float32_take_numpys_order(n):
    """Terms of 1 and 2^-53 (half an ulp of 1): each order of summation rounds differently, so
    only NumPy's own (a loop under 8 terms, 8 partial sums, halves over 128) gives its sums."""
    rng = np.random.default_rng(n)
    values = np.where(rng.random((6, 5, n)) < 0.2, 1.0, 2.0 ** -53).astype(np.float32)
    want = values.sum(axis=2, dtype=np.float64)
    got = np.array([[_pairwise_sum(values[i, j], 0, n) for j in range(5)] for i in range(6)])
    assert np.array_equal(got, want)


def test_the_block_samples_kernels_are_numpys_expression():
    rng = np.random.default_rng(5)
    n_pixels = 3000
    inner = rng.integers(0, 30, n_pixels)
    inner[:5] = [0, 0, 1, 199, 0]
    log_b, lum_b, log_e, lum_e = rng.normal(size=(4, n_pixels))
    t_b, length, t0, t1 = 1_234_567_891, 9_999_991, 1.2345, 1.2395
    pix, times, levels, lums, mid_pix, mid_s = _block_samples(
        inner, t_b, length, log_b, lum_b, log_e, lum_e, t0, t1)
    counts = inner + 2
    want_pix = np.repeat(np.arange(n_pixels), counts)
    k = np.arange(len(want_pix)) - np.repeat(np.cumsum(counts) - counts, counts)
    want_times = t_b + (k * length) // (inner[want_pix] + 1)
    middle = (k > 0) & (k <= inner[want_pix])
    assert np.array_equal(pix, want_pix) and np.array_equal(times, want_times)
    assert np.array_equal(mid_pix, want_pix[middle])
    assert np.array_equal(mid_s, np.clip(want_times[middle] * 1e-9, t0, t1))
    start, end = k == 0, k == inner[want_pix] + 1
    assert np.array_equal(levels[start], log_b) and np.array_equal(lums[start], lum_b)
    assert np.array_equal(levels[end], log_e) and np.array_equal(lums[end], lum_e)
    values = rng.random(len(mid_pix))
    _fill_middle(inner, values, np.log(values), levels, lums)
    assert np.array_equal(lums[middle], values) and np.array_equal(levels[middle], np.log(values))
    assert np.array_equal(levels[start], log_b) and np.array_equal(lums[end], lum_e)


def test_the_insert_kernel_is_numpys_insert():
    rng = np.random.default_rng(6)
    n, m = 5000, 700
    arrays = (rng.integers(0, 99, n), rng.integers(0, 10**12, n), rng.normal(size=n),
              rng.random(n))
    at = np.sort(rng.integers(0, n + 1, m))
    at[:3] = [0, 0, 0]
    at[-2:] = n
    new = (rng.integers(0, 99, m), rng.integers(0, 10**12, m), rng.normal(size=m), rng.random(m))
    got = _insert_samples(*arrays, at, *new)
    for a, b, g in zip(arrays, new, got, strict=True):
        assert g.dtype == np.result_type(a, b) and np.array_equal(g, np.insert(a, at, b))


def test_the_shifted_luminance_kernel_is_numpys_expression():
    rng = np.random.default_rng(8)
    for values in (_luminance(rng, 4097), rng.random(100)):
        out = np.empty(len(values))
        _plus(values, 0.43, out)
        assert np.array_equal(out, np.asarray(values, np.float64) + 0.43)


@pytest.mark.parametrize("case", ["at an integer", "NaN twist", "at rest", "tiny", "fast"])
def test_the_dilation_radius_from_the_squares_is_hypots(case):
    """:func:`sim.pixel_sampling.rate_map` takes its dilation from each twist's largest
    ``du^2 + dv^2`` (no ``hypot`` per pixel) unless that cannot decide ``ceil(speed seconds)``:
    the map is NumPy's, ``hypot`` and all, where ``speed seconds`` is an integer to the last bit,
    where a twist is NaN, where the camera is at rest or creeps (speeds whose squares underflow)
    and where it outruns the dilation's cap."""
    from sim.pixel_sampling import _dilation_radius

    rng = np.random.default_rng(11)
    camera = _camera(23, 19, distorted=True)
    sub = _luminance(rng, (38, 46))
    depth = rng.uniform(0.2, 3.0, (19, 23))
    twists = [(np.array([0.3, -0.1, 0.05]), np.array([0.02, 0.1, -0.03])),
              (np.array([0.2, 0.0, 0.0]), np.array([0.0, 0.05, 0.0]))]
    if case == "NaN twist":
        twists[1] = (np.array([np.nan, 0.0, 0.0]), np.zeros(3))
    elif case == "at rest":
        twists = [(np.zeros(3), np.zeros(3))] * 2
    elif case == "tiny":
        twists = [(np.array([1e-170, 0.0, 0.0]), np.zeros(3))] * 2
    elif case == "fast":
        twists = [(np.array([50.0, 0.0, 0.0]), np.zeros(3))] * 2
    centres = camera.normalized_pixel_centres()
    speed = 0.0
    for v, w in twists:
        flow = _numpy_motion_field(camera, depth, v, w, centres)
        speed = max(speed, float(np.max(np.hypot(*flow), initial=0.0)))
    seconds = 3.0 / speed if case == "at an integer" else 0.01
    want = _numpy_rate_map(camera, sub, depth, twists, seconds, 0.43, centres)
    got = rate_map(camera, sub, depth, twists, seconds, 0.43, centres)
    np.testing.assert_array_equal(got, want)                # NaN where NumPy's is NaN
    if case == "at an integer":           # the squares alone cannot say: hypot decides
        calls = []
        _dilation_radius(np.array([(3.0 / seconds) ** 2]), seconds,
                         lambda: calls.append(1) or np.array([3.0 / seconds]))
        assert calls
    if case == "tiny":
        assert math.ceil(speed * seconds) == 1          # not 0: the squares were 0
