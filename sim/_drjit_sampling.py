"""The per-pixel sampler's block on Dr.Jit's device: every core (``llvm``) or the GPU (``cuda``).

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

from collections.abc import Callable

import drjit as dr
import numpy as np

from sim.sampling import SPLIT

__all__ = ["device_block"]


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
                 stats, device: str = "llvm") -> tuple[tuple, np.ndarray, np.ndarray]:
    """A block's samples, shaded, checked and refined on the device.

    Parameters
    ----------
    shade : callable
        ``shade(pixels, seconds, between)`` -> linear luminance: device arrays (UInt32 flat
        pixels, Float64 seconds) and the bounds of the seconds in, a device Float32 array out
        (:meth:`sim.shader.EventShader.luminance_device`).
    inner : (P,) int64 ndarray
        Samples each pixel takes strictly inside the block (:func:`sim.pixel_sampling.
        _intra_counts`).
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
    """
    from sim._drjit_events import _device_array

    m = _module(device)
    n_pixels = len(inner)
    n_mid = int(inner.sum())
    total = n_mid + 2 * n_pixels
    on = _device_array
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
        return (pix, times, levels, lums), counts.numpy().astype(np.int64), observed.numpy()


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
