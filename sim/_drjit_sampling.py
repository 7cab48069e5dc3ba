"""The per-pixel sampler's block on Dr.Jit's device: every core (``llvm``) or the GPU (``cuda``).

:func:`device_prediction` is the block's prediction (:func:`sim.pixel_sampling.rate_map` and
``_intra_counts``: the sub-samples' weighted gradients, the motion field of each twist, the
dilation, the samples each pixel takes) on the device, the same counts bit for bit; the host
takes only the float32 ``log`` of the sub-samples (NumPy's) and reads back the fastest pixel's
squared speed and the counts' sum.

:func:`device_block` is the part of :func:`sim.pixel_sampling.pixel_blocks` between the
prediction and the emulator, written as Dr.Jit array operations on device arrays: the block's
samples (each pixel's start sample, its evenly spaced inner ones, its end sample), their
shading straight from the device arrays (:meth:`sim.shader.EventShader.luminance_device`),
the check and refinement of the intervals that break the bound (one launch per level over all
pixels, the intervals still to split compacted with ``dr.compress``), the merge of the
midpoints into the samples (each old sample moved by a prefix sum of the midpoints before it)
and the observed rates (``dr.scatter_reduce`` of the slopes, a maximum). The host sends the
sample counts per pixel and the frames' levels, and sees per level only the number of
intervals still to split; it sorts only the midpoints found (few: one in slider_close's
half second) by their interval and time.

Exactness, against the reference (:func:`sim.pixel_sampling._block_samples`,
:func:`sim.pixel_sampling._refine`, :func:`sim.pixel_sampling._observed_rates`, numba and
NumPy):

- Sample times, pixels, the intervals' checks and the observed rates are the same integer and
  float64 operations (``//`` on non-negative int64, IEEE ``+ - * /``, compared alike; Dr.Jit's
  fast-math mode off), so they agree bit for bit wherever the levels do.
- The luminance of every sample is the shader's, bit for bit (the same frozen kernel, the same
  pose interval and fraction computed in float64 on the device as
  :meth:`sim.shader._PoseGrid.locate` computes them on the host).
- A sample's level ``log(y + log_eps)`` uses Dr.Jit's ``log`` (its own polynomial, within
  about 2 ulp; NumPy's differs in the last bit on about 7 % of arguments). A level within an
  ulp or two of a threshold, or an interval's change within that of the bound, can fire an
  event or split an interval differently; measured on slider_close (seed 3, 0.5 s) in
  ``benchmarks/bench_device_sampler.py``, tested against the reference on small scenes in
  ``tests/test_device_sampler.py``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import drjit as dr
import numpy as np

from sim.sampling import SPLIT

__all__ = ["device_block", "device_centres", "device_prediction"]


def _module(device: str):
    """The array module of the renders' variants on ``device`` (``drjit.llvm.ad`` or
    ``drjit.cuda.ad``, whose arrays the shader takes)."""
    if device == "cuda":
        import drjit.cuda.ad as module
    elif device == "llvm":
        import drjit.llvm.ad as module
    else:
        raise ValueError(f"device must be 'llvm' or 'cuda', got {device!r}")
    return module


def _concat(parts):
    """Device arrays of one type joined end to end (``dr.concat``, empty ones skipped)."""
    parts = [a for a in parts if dr.width(a) > 0]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else dr.concat(parts)


def _take(values, index):
    """``values[index]`` on the device."""
    return dr.gather(type(values), values, index)


def device_block(shade: Callable, inner: np.ndarray, t_b: int, length: int, log_b: np.ndarray,
                 lum_b: np.ndarray, log_e: np.ndarray, lum_e: np.ndarray, t0: float, t1: float,
                 bound: float, scale: np.ndarray | None, dt_min_ns: int, log_eps: float,
                 stats, device: str = "llvm", total: int | None = None
                 ) -> tuple[tuple, np.ndarray, np.ndarray, object]:
    """A block's samples, shaded, checked and refined on the device.

    Parameters
    ----------
    shade : callable
        ``shade(pixels, seconds, between)`` -> linear luminance: device arrays (UInt32 flat
        pixels, Float64 seconds) and the bounds of the seconds in, a device Float32 array out
        (:meth:`sim.shader.EventShader.luminance_device`).
    inner : (P,) int64 ndarray or Dr.Jit UInt32 array
        Samples each pixel takes strictly inside the block (:func:`sim.pixel_sampling.
        _intra_counts`, or :func:`device_prediction`'s, on the device, with their ``total``).
        Any of the (P,) float64 arrays below may be given as a Dr.Jit Float64 array on the
        device too.
    t_b, length : int, ns
        The block's start and length.
    log_b, lum_b, log_e, lum_e : (P,) float64 ndarray
        Each pixel's level and luminance at the block's start and end.
    t0, t1 : float, seconds
        The run's span (a sample's time in seconds is clipped to it).
    bound : float
        ``lam C`` of the smallest threshold.
    scale : (P,) float64 ndarray or None
        :func:`sim.sampling.contrast_scale`'s, flat (None: all thresholds equal).
    dt_min_ns : int, ns
        No interval is split below ``2 dt_min_ns``.
    log_eps : float
    stats : PixelSamplingStats
        Its ``pixel_samples``, ``midpoint_samples``, ``steps``, ``at_max_rate`` and
        ``intervals`` grow as in :func:`sim.pixel_sampling.pixel_blocks`.
    device : {"llvm", "cuda"}
    total : int, optional
        ``inner``'s sum, where ``inner`` is on the device.

    Returns
    -------
    samples : tuple of (S,) Dr.Jit arrays on the device
        Every sample's flat pixel (UInt32) and time (Int64, ns), sorted by pixel, then time,
        its log intensity and linear luminance (Float64): what
        :meth:`sim.pixel_sampling.PixelEventEmulator.advance_device` takes (``.numpy()`` of
        each: :meth:`~sim.pixel_sampling.PixelEventEmulator.advance_samples`').
    counts : (P,) int64 ndarray
        Each pixel's samples.
    observed : (P,) float64 ndarray, 1/s
        Each pixel's largest ``|dL/dt|`` over its intervals that met the bound.
    observed_device : (P,) Dr.Jit Float64 array
        The same, left on the device.
    """
    from sim._drjit_events import _device_array

    m = _module(device)
    if dr.is_array_v(inner):
        n_pixels, n_mid = dr.width(inner), int(total)
    else:
        n_pixels, n_mid = len(inner), int(inner.sum())
    total = n_mid + 2 * n_pixels

    def on(kind, values):                       # host arrays sent, device ones as they are
        return values if dr.is_array_v(values) else _device_array(kind, values)
    fast = dr.flag(dr.JitFlag.FastMath)

    span = (min(max(t_b * 1e-9, t0), t1), min(max((t_b + length) * 1e-9, t0), t1))

    def render(pixels, seconds):                # the shader under the caller's flags
        with dr.scoped_set_flag(dr.JitFlag.FastMath, fast):
            return shade(pixels, seconds, span)

    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        counts = on(m.UInt32, inner)
        first = dr.prefix_sum(counts + 2)
        mark = dr.zeros(m.UInt32, total)
        dr.scatter(mark, 1, first, dr.arange(m.UInt32, n_pixels) > 0)
        pix = dr.cumsum(mark)
        k = dr.arange(m.UInt32, total) - _take(first, pix)
        k_in = _take(counts, pix)
        times = m.Int64(t_b) + (m.Int64(k) * length) // m.Int64(k_in + 1)
        start = k == 0
        levels = dr.select(start, _take(on(m.Float64, log_b), pix),
                           _take(on(m.Float64, log_e), pix))
        lums = dr.select(start, _take(on(m.Float64, lum_b), pix),
                         _take(on(m.Float64, lum_e), pix))
        scale_d = None if scale is None else on(m.Float64, scale)
        middle = (k > 0) & (k <= k_in)
        dr.eval(pix, times, levels, lums, middle)
        if n_mid:
            index = dr.compress(middle)
            y, level = _shaded(m, render, _take(pix, index), _take(times, index), t0, t1,
                               log_eps)
            dr.scatter(levels, level, index)
            dr.scatter(lums, y, index)
            stats.pixel_samples += n_mid
        pix, times, levels, lums = _refine(m, render, pix, times, levels, lums, bound, scale_d,
                                           dt_min_ns, log_eps, t0, t1, stats)
        observed = _observed(m, pix, times, levels, bound, scale_d, n_pixels)
        counts = dr.zeros(m.UInt32, n_pixels)
        dr.scatter_reduce(dr.ReduceOp.Add, counts, m.UInt32(1), pix)
        dr.eval(pix, times, levels, lums, observed, counts)
        stats.intervals += dr.width(pix) - n_pixels
        return ((pix, times, levels, lums), counts.numpy().astype(np.int64), observed.numpy(),
                observed)


def _shaded(m, shade, pixels, times, t0: float, t1: float, log_eps: float):
    """Luminance (Float64) and level of samples at ``times`` (Int64 ns), shaded on the
    device by ``shade`` (which runs its kernel under the caller's Dr.Jit flags)."""
    seconds = dr.clip(m.Float64(times) * 1e-9, t0, t1)
    y = m.Float64(shade(pixels, seconds))
    return y, dr.log(y + log_eps)


def _intervals(m, pix, levels, scale):
    """Each interval ``(i, i + 1)``'s start index (UInt32), whether both samples are one
    pixel's, and its change in units of the smallest threshold."""
    n = dr.width(pix) - 1
    i = dr.arange(m.UInt32, n)
    p = _take(pix, i)
    same = _take(pix, i + 1) == p
    change = dr.abs(_take(levels, i + 1) - _take(levels, i))
    if scale is not None:
        change = change * _take(scale, p)
    return i, same, change


def _refine(m, shade, pix, times, levels, lums, bound, scale, dt_min_ns, log_eps, t0, t1,
            stats):
    """:func:`sim.pixel_sampling._refine` on the device: every interval breaking the bound
    split at its midpoint level by level (one shading launch per level), then the midpoints
    merged in, the samples staying sorted by (pixel, time)."""
    i, same, change = _intervals(m, pix, levels, scale)
    index = dr.compress(same & (change > bound))
    if dr.width(index) == 0:
        return pix, times, levels, lums
    p, ta, la, tb, lb, o = (_take(pix, index), _take(times, index), _take(levels, index),
                            _take(times, index + 1), _take(levels, index + 1), index)
    found = []
    while dr.width(p):
        splittable = tb - ta >= 2 * dt_min_ns
        keep = dr.compress(splittable)
        stats.at_max_rate += dr.width(p) - dr.width(keep)
        if dr.width(keep) == 0:
            break
        p, ta, la, tb, lb, o = (_take(a, keep) for a in (p, ta, la, tb, lb, o))
        mt = (ta + tb) // 2
        my, ml = _shaded(m, shade, p, mt, t0, t1, log_eps)
        stats.pixel_samples += dr.width(p)
        stats.midpoint_samples += dr.width(p)
        share = dr.abs(ml - la) / dr.abs(lb - la)
        continuous = (share > SPLIT) & (share < 1 - SPLIT)
        dr.eval(my, ml, continuous)
        stats.steps += dr.width(p) - int(dr.count(continuous)[0])
        found.append((p, mt, ml, my, o))
        s = None if scale is None else _take(scale, p)
        d1, d2 = dr.abs(ml - la), dr.abs(lb - ml)
        if s is not None:
            d1, d2 = d1 * s, d2 * s
        a, b = dr.compress(d1 > bound), dr.compress(d2 > bound)
        p, ta, la, tb, lb, o = (_concat([_take(x, a), _take(y, b)]) for x, y in (
            (p, p), (ta, mt), (la, ml), (mt, tb), (ml, lb), (o, o)))
        if p is None:
            break
    if not found:
        return pix, times, levels, lums
    new_p, new_t, new_l, new_y, new_o = (_concat(list(parts))
                                         for parts in zip(*found, strict=True))
    # Sorted by (interval, time) on the host: the midpoints are few. Each goes in before the
    # old sample after its interval (np.insert at new_o + 1), old samples move past those.
    order = np.lexsort((new_t.numpy(), new_o.numpy()))
    sel = m.UInt32(order.astype(np.uint32))
    new_p, new_t, new_l, new_y, new_o = (_take(a, sel) for a in (new_p, new_t, new_l, new_y,
                                                                 new_o))
    n, added = dr.width(pix), len(order)
    before = dr.zeros(m.UInt32, n + 1)
    dr.scatter_reduce(dr.ReduceOp.Add, before, m.UInt32(1), new_o + 1)
    shift = dr.cumsum(before)                   # midpoints going in at or before each index
    old = dr.arange(m.UInt32, n)
    moved = old + _take(shift, old)
    placed = new_o + 1 + dr.arange(m.UInt32, added)
    out = []
    for values, extra in ((pix, new_p), (times, new_t), (levels, new_l), (lums, new_y)):
        merged = dr.zeros(type(values), n + added)
        dr.scatter(merged, values, moved)
        dr.scatter(merged, extra, placed)
        out.append(merged)
    dr.eval(out)
    return tuple(out)


def _observed(m, pix, times, levels, bound, scale, n_pixels):
    """:func:`sim.pixel_sampling._observed_rates` on the device."""
    i, same, change = _intervals(m, pix, levels, scale)
    raw = dr.abs(_take(levels, i + 1) - _take(levels, i))
    dt = _take(times, i + 1) - _take(times, i)
    slope = raw / m.Float64(dr.maximum(dt, 1)) * 1e9
    out = dr.zeros(m.Float64, n_pixels)
    dr.scatter_reduce(dr.ReduceOp.Max, out, slope, _take(pix, i), same & (change <= bound))
    return out


# --- the prediction ------------------------------------------------------------------------------


def _nan_max(a, b):
    """``np.maximum(a, b)`` (:func:`sim.pixel_sampling._nan_max`): the larger, NaN if either
    is (Dr.Jit's ``maximum`` drops a NaN)."""
    return dr.select(a != a, a, dr.select(b != b, b, dr.select(a >= b, a, b)))


def _opaque(kind, value):
    """A scalar the kernels read from memory: a new value each block, the same kernels."""
    out = kind(value)
    dr.make_opaque(out)
    return out


def _scalars(m, values, width: int) -> list:
    """Float64 scalars the kernels read from memory (as :func:`_opaque`'s), sent in one copy:
    each gathered inside the kernels that use it, over ``width`` lanes, instead of one memory
    fill (a launch on a GPU) each."""
    from sim._drjit_events import _device_array

    table = _device_array(m.Float64, np.asarray(values, np.float64))
    lanes = dr.zeros(m.UInt32, width)
    return [dr.gather(m.Float64, table, lanes + i) for i in range(len(values))]


def device_prediction(weight: np.ndarray, logw: np.ndarray, shape: tuple[int, int], fx: float,
                      fy: float, centres, depth: np.ndarray, twists: np.ndarray,
                      dilation: Callable[[float], int], seconds: float, log_b, log_e, observed,
                      scale, per_sample: float, most: int,
                      device: str = "llvm") -> tuple[object, int, int]:
    """:func:`sim.pixel_sampling.rate_map` and :func:`sim.pixel_sampling._intra_counts` on the
    device: the samples each pixel takes strictly inside a block.

    The same integer and float64 / float32 operations in the same order as the numba kernels
    (:func:`sim.pixel_sampling._weighted_slopes`, ``_predicted_rate``, ``_intra_kernel``;
    Dr.Jit's fast-math mode off), so the counts are theirs bit for bit wherever the rates are
    finite (``tests/test_device_sampler.py``). Two parts stay on the host: the float32
    ``log`` of the sub-samples' weights (NumPy's; Dr.Jit's differs in the last bit), which the
    caller passes, and the dilation's radius from the fastest pixel's squared speed, which
    the caller's ``dilation`` decides (:func:`sim.pixel_sampling._dilation_radius`, from every
    pixel's ``hypot`` by numba where the square cannot decide it). The dilation is a maximum
    over the clamped window, as ``cv2.dilate`` with ``BORDER_REPLICATE``; a NaN rate (never
    from a finite render) spreads over the window here.

    Parameters
    ----------
    weight, logw : (H n, W n) float32 ndarray
        The block start's sub-samples plus ``log_eps`` and their float32 ``log``
        (``n < 8``: the pairwise sums of wider pixels are not ported).
    shape : (int, int)
        (H, W).
    fx, fy : float
        Focal lengths, pixels.
    centres : tuple
        The x and y of ``camera.normalized_pixel_centres()``, flat, on the device
        (:func:`device_centres`).
    depth : (H, W) ndarray, metres
        Exact depth at the block's start (0 where nothing is seen).
    twists : (K, 6) float64 ndarray
        :func:`sim.sampling._twist` of each velocity the block spans.
    dilation : callable
        ``dilation(top)`` -> the rate map's dilation in pixels, from the largest ``du^2 + dv^2``
        over the pixels and twists (NaN where one is not finite).
    seconds : float
        The block's length.
    log_b, log_e : (P,) Dr.Jit Float64 arrays
        Each pixel's level at the block's start and end.
    observed, scale : (P,) Dr.Jit Float64 arrays or None
        The last block's observed rates and :func:`sim.sampling.contrast_scale`'s.
    per_sample : float
        The change a sample may see (``MARGIN lam C``).
    most : int
        Samples a pixel takes at most (the block's length over the shortest interval, at
        least 1).
    device : {"llvm", "cuda"}

    Returns
    -------
    inner : (P,) Dr.Jit UInt32 array
        :func:`sim.pixel_sampling._intra_counts`'s.
    total : int
        Their sum.
    radius : int
        The dilation (pixels).
    """
    m = _module(device)
    rate, radius = device_rate(weight, logw, shape, fx, fy, centres, depth, twists, dilation,
                               device)
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        # _intra_counts: at least the net change, the last block's rates; times the scale.
        secs, per, top = _scalars(m, [seconds, per_sample, float(most)], dr.width(rate))
        r = _nan_max(rate, dr.abs(log_e - log_b) / secs)
        if observed is not None:
            r = _nan_max(r, observed)
        if scale is not None:
            r = r * scale
        wanted = dr.ceil(r * secs / per)
        wanted = dr.select((wanted != wanted) | (wanted == math.inf), 0.0, wanted)
        inner = m.UInt32(dr.minimum(dr.maximum(wanted, 1.0), top) - 1.0)
        dr.eval(inner)                              # once, then summed
        total = dr.sum(m.UInt64(inner))
        return inner, int(total[0]), radius


def device_rate(weight: np.ndarray, logw: np.ndarray, shape: tuple[int, int], fx: float,
                fy: float, centres: tuple, depth: np.ndarray, twists: np.ndarray,
                dilation: Callable[[float], int], device: str = "llvm") -> tuple[object, int]:
    """:func:`sim.pixel_sampling.rate_map` on the device (the arguments are
    :func:`device_prediction`'s): the rate map, flat ((H W,) Dr.Jit Float64), and its
    dilation (pixels)."""
    from sim._drjit_events import _device_array

    m = _module(device)
    height, width = shape
    rows, cols = weight.shape
    n = rows // height
    if n >= 8:
        raise ValueError(f"device_prediction takes at most 7x7 sub-samples a pixel, got {n}x{n}")
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        w_d = _device_array(m.Float32, weight.reshape(-1))
        l_d = _device_array(m.Float32, logw.reshape(-1))
        # One lane per (pixel row, sub-sample column): its n sub-sample rows summed in float32.
        lane = dr.arange(m.UInt32, height * cols)
        y, c = lane // cols, lane % cols
        zero = m.Float32(0.0)
        acc = None
        for j in range(n):
            r = y * n + j
            at = r * cols + c
            level = _take(l_d, at)
            gu = dr.select(c + 1 < cols, dr.abs(_take(l_d, dr.minimum(at + 1, rows * cols - 1))
                                                - level), zero)
            gu = dr.select(c > 0, _nan_max(gu, dr.abs(level - _take(l_d, dr.maximum(at, 1) - 1))),
                           gu)
            gv = dr.select(r + 1 < rows, dr.abs(_take(l_d, dr.minimum(at + cols, rows * cols - 1))
                                                - level), zero)
            gv = dr.select(r > 0, _nan_max(gv, dr.abs(level - _take(l_d, dr.maximum(at, cols)
                                                                      - cols))), gv)
            w = _take(w_d, at)
            acc = ((w, gu * w, gv * w) if acc is None
                   else (acc[0] + w, acc[1] + gu * w, acc[2] + gv * w))
        dr.eval(acc)
        # Each pixel's n column sums in float64, in order (-0.0 + a is a).
        pixel = dr.arange(m.UInt32, height * width)
        first = (pixel // width) * cols + (pixel % width) * n
        sums = [m.Float64(_take(a, first)) for a in acc]
        for i in range(1, n):
            sums = [s_ + m.Float64(_take(a, first + i)) for s_, a in zip(sums, acc, strict=True)]
        # Opaque: Dr.Jit turns a division by a literal into a product by its reciprocal.
        twists = np.asarray(twists, np.float64).reshape(-1, 6)
        nn, n_d, fx_d, fy_d, *motion = _scalars(m, [float(n * n), float(n), fx, fy,
                                                    *twists.reshape(-1)], height * width)
        mean = sums[0] / nn
        slope_u = sums[1] / nn * (n_d / mean)
        slope_v = sums[2] / nn * (n_d / mean)
        # The motion field of each twist (sim.sampling._point_flow, its operations in order).
        x, yy = centres
        z = _device_array(m.Float64, np.asarray(depth, np.float64).reshape(-1))
        seen = z > 0.0
        best = m.Float64(0.0)
        squares = None
        for k in range(len(twists)):
            vx, vy, vz, wx, wy, wz = motion[6 * k:6 * k + 6]
            px = -vx - z * (wy - wz * yy)
            py = -vy - z * (wz * x - wx)
            pz = -vz - z * (wx * yy - wy * x)
            du = dr.select(seen, fx_d * (px - x * pz) / z, 0.0)
            dv = dr.select(seen, fy_d * (py - yy * pz) / z, 0.0)
            best = _nan_max(best, slope_u * dr.abs(du) + slope_v * dr.abs(dv))
            square = du * du + dv * dv
            squares = square if squares is None else _nan_max(squares, square)
        dr.eval(best, squares)                      # one kernel, then one reduction
        top = float(dr.max(dr.select(dr.isfinite(squares), squares, math.inf))[0])
        radius = dilation(top if math.isfinite(top) else math.nan)
        rate = best
        if radius > 0:                              # the maximum over the clamped window
            rate = _dilate(m, rate, height, width, radius)
        dr.eval(rate)
        return rate, radius


def _dilate(m, values, height: int, width: int, radius: int):
    """The largest of ``values`` ((H W,) Float64, row-major) over the ``(2 radius + 1)^2``
    window of each pixel, the window clamped to the image (``cv2.dilate`` with a square kernel
    and ``BORDER_REPLICATE``): along the rows, then the columns, one symbolic loop each."""
    pixel = dr.arange(m.UInt32, height * width)
    py, px = m.Int32(pixel // width), m.Int32(pixel % width)
    r = _opaque(m.Int32, radius)
    for along, size in ((px, width), (py, height)):
        step = 1 if along is px else width
        src = values
        out = _take(src, pixel)
        d = dr.zeros(m.Int32, height * width) - r

        def body(d, out, along=along, size=size, step=step, src=src):
            other = dr.clip(along + d, 0, size - 1)
            index = m.UInt32(m.Int32(pixel) + (other - along) * step)
            return d + 1, _nan_max(out, _take(src, index))

        d, out = dr.while_loop((d, out), lambda d, out: d <= r, body)
        values = out
        dr.eval(values)
    return values


def device_centres(xy: np.ndarray, device: str = "llvm") -> tuple:
    """``camera.normalized_pixel_centres()`` ((H, W, 2) ndarray) as :func:`device_prediction`
    takes it: its x and y, flat, on the device (uploaded once a run)."""
    from sim._drjit_events import _device_array

    m = _module(device)
    xy = np.asarray(xy, np.float64)
    return (_device_array(m.Float64, xy[..., 0].reshape(-1)),
            _device_array(m.Float64, xy[..., 1].reshape(-1)))
