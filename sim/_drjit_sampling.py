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

Both take ``B`` consecutive blocks at once (a pass of :func:`sim.pixel_sampling.pixel_blocks`'
wavefront): a block axis on the prediction's images, the pixels of block ``b`` numbered
``b P + p`` in the samples. Every operation on a value stays within its block (no gradient,
dilation or interval crosses from one block's image into another's), so each block gets what
a pass of that block alone gives it, bit for bit; only the launches are shared.

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


def device_block(shade: Callable, inner: np.ndarray, t_b, length, log_b: np.ndarray,
                 lum_b: np.ndarray, log_e: np.ndarray, lum_e: np.ndarray, t0: float, t1: float,
                 bound: float, scale: np.ndarray | None, dt_min_ns: int, log_eps: float,
                 stats, device: str = "llvm", total: int | None = None
                 ) -> tuple[tuple, np.ndarray, np.ndarray, object]:
    """A block's samples, shaded, checked and refined on the device; or those of ``B``
    consecutive blocks at once (a pass of the wavefront), each block's pixels on their own.

    Parameters
    ----------
    shade : callable
        ``shade(pixels, seconds, between)`` -> linear luminance: device arrays (UInt32 flat
        pixels, Float64 seconds) and the bounds of the seconds in, a device Float32 array out
        (:meth:`sim.shader.EventShader.luminance_device`).
    inner : (B P,) int64 ndarray or Dr.Jit UInt32 array
        Samples each pixel takes strictly inside its block (:func:`sim.pixel_sampling.
        _intra_counts`, or :func:`device_prediction`'s, on the device, with their ``total``),
        block after block. Any of the (B P,) float64 arrays below may be given as a Dr.Jit
        Float64 array on the device too.
    t_b, length : int or (B,) sequence of int, ns
        Each block's start and length (the blocks consecutive).
    log_b, lum_b, log_e, lum_e : (B P,) float64 ndarray
        Each pixel's level and luminance at its block's start and end.
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
        Every sample's pixel (UInt32, ``b P + p`` for pixel ``p`` of block ``b``) and time
        (Int64, ns), sorted by block, pixel, then time (so each block's samples are one run),
        its log intensity and linear luminance (Float64): what
        :meth:`sim.pixel_sampling.PixelEventEmulator.advance_device` takes of one block
        (``.numpy()`` of each: :meth:`~sim.pixel_sampling.PixelEventEmulator.advance_samples`').
    counts : (B P,) int64 ndarray
        Each pixel's samples in its block.
    observed : (B P,) float64 ndarray, 1/s
        Each pixel's largest ``|dL/dt|`` over its intervals in its block that met the bound.
    observed_device : (B P,) Dr.Jit Float64 array
        The same, left on the device.

    Notes
    -----
    The blocks of a pass are independent: each sample's operations are those of its block
    alone (the pixels ``b P + p`` only index; a block's pixel is shaded as ``p``), so a pass
    gives each block what a pass of that block alone gives it, bit for bit
    (``tests/test_wavefront.py``).
    """
    from sim._drjit_events import _device_array

    m = _module(device)
    starts = np.atleast_1d(np.asarray(t_b, np.int64))
    lengths = np.atleast_1d(np.asarray(length, np.int64))
    if dr.is_array_v(inner):
        n_pixels, n_mid = dr.width(inner), int(total)
    else:
        n_pixels, n_mid = len(inner), int(inner.sum())
    image = n_pixels // len(starts)             # the pixels of one block's image
    total = n_mid + 2 * n_pixels

    def on(kind, values):                       # host arrays sent, device ones as they are
        return values if dr.is_array_v(values) else _device_array(kind, values)
    fast = dr.flag(dr.JitFlag.FastMath)

    span = (min(max(int(starts[0]) * 1e-9, t0), t1),
            min(max(int(starts[-1] + lengths[-1]) * 1e-9, t0), t1))

    def render(pixels, seconds):                # the shader under the caller's flags
        with dr.scoped_set_flag(dr.JitFlag.FastMath, fast):
            return shade(pixels if len(starts) == 1 else pixels % image, seconds, span)

    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        counts = on(m.UInt32, inner)
        first = dr.prefix_sum(counts + 2)
        mark = dr.zeros(m.UInt32, total)
        dr.scatter(mark, 1, first, dr.arange(m.UInt32, n_pixels) > 0)
        pix = dr.cumsum(mark)
        k = dr.arange(m.UInt32, total) - _take(first, pix)
        k_in = _take(counts, pix)
        if len(starts) == 1:
            t_b, length = int(starts[0]), int(lengths[0])
        else:                                   # each sample's block's start and length
            block = pix // image
            t_b = _take(_device_array(m.Int64, starts), block)
            length = _take(_device_array(m.Int64, lengths), block)
        times = t_b + (m.Int64(k) * length) // m.Int64(k_in + 1)
        start = k == 0
        levels = dr.select(start, _take(on(m.Float64, log_b), pix),
                           _take(on(m.Float64, log_e), pix))
        lums = dr.select(start, _take(on(m.Float64, lum_b), pix),
                         _take(on(m.Float64, lum_e), pix))
        scale_d = None if scale is None else on(m.Float64, scale)
        if scale_d is not None and len(starts) > 1:      # each block's pixels scaled alike
            scale_d = _take(scale_d, dr.arange(m.UInt32, n_pixels) % image)
        middle = (k > 0) & (k <= k_in)
        dr.eval(pix, times, levels, lums, middle, *([] if scale_d is None else [scale_d]))
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


def _scalars(m, values, width: int, block=None) -> list:
    """Float64 scalars the kernels read from memory (as :func:`_opaque`'s), sent in one copy:
    each gathered inside the kernels that use it, over ``width`` lanes, instead of one memory
    fill (a launch on a GPU) each. With ``block`` (UInt32, each lane's block), ``values`` is a
    (B, V) table and each lane reads its own block's row."""
    from sim._drjit_events import _device_array

    values = np.asarray(values, np.float64)
    table = _device_array(m.Float64, values.reshape(-1))
    size = values.shape[-1]
    lanes = dr.zeros(m.UInt32, width) if block is None else block * size
    return [dr.gather(m.Float64, table, lanes + i) for i in range(size)]


def _per_block(values, blocks: int) -> list:
    """A per-block argument as a list of ``blocks`` items (one value: the same for all)."""
    if isinstance(values, (list, tuple)):
        return list(values)
    return [values] * blocks


def device_prediction(weight: np.ndarray, logw: np.ndarray, shape: tuple[int, int], fx: float,
                      fy: float, centres, depth: np.ndarray, twists: np.ndarray,
                      dilation, seconds, log_b, log_e, observed, scale, per_sample: float,
                      most, device: str = "llvm") -> tuple[object, int, object]:
    """:func:`sim.pixel_sampling.rate_map` and :func:`sim.pixel_sampling._intra_counts` on the
    device: the samples each pixel takes strictly inside a block, or inside each of ``B``
    blocks at once (a leading block axis on ``weight``, ``logw``, ``depth`` and ``twists``;
    each block's image on its own: no gradient or dilation crosses from one into another).

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
    weight, logw : (H n, W n) or (B, H n, W n) float32 ndarray
        The block start's sub-samples plus ``log_eps`` and their float32 ``log``
        (``n < 8``: the pairwise sums of wider pixels are not ported).
    shape : (int, int)
        (H, W).
    fx, fy : float
        Focal lengths, pixels.
    centres : tuple
        The x and y of ``camera.normalized_pixel_centres()``, flat, on the device
        (:func:`device_centres`).
    depth : (H, W) or (B, H, W) ndarray, metres
        Exact depth at the block's start (0 where nothing is seen).
    twists : (K, 6) or (B, K, 6) float64 ndarray
        :func:`sim.sampling._twist` of each velocity the block spans.
    dilation : callable or list of callables
        ``dilation(top)`` -> the rate map's dilation in pixels, from the largest ``du^2 + dv^2``
        over the block's pixels and twists (NaN where one is not finite); one per block.
    seconds : float or list of float
        The block's length (each block's).
    log_b, log_e : (B P,) Dr.Jit Float64 arrays
        Each pixel's level at its block's start and end.
    observed : (P,) or (B P,) Dr.Jit Float64 array or None
        The rates the counts take as a floor (:func:`sim.pixel_sampling._intra_counts`'
        ``observed``): one for every block, or each block's.
    scale : (P,) Dr.Jit Float64 array or None
        :func:`sim.sampling.contrast_scale`'s.
    per_sample : float
        The change a sample may see (``MARGIN lam C``).
    most : int or list of int
        Samples a pixel takes at most (the block's length over the shortest interval, at
        least 1).
    device : {"llvm", "cuda"}

    Returns
    -------
    inner : (B P,) Dr.Jit UInt32 array
        :func:`sim.pixel_sampling._intra_counts`'s, block after block.
    total : int
        Their sum.
    radius : int or list of int
        The dilation (pixels): each block's where ``weight`` has a block axis.
    """
    m = _module(device)
    rate, radius = device_rate(weight, logw, shape, fx, fy, centres, depth, twists, dilation,
                               device)
    blocks = len(radius) if isinstance(radius, list) else 1
    image = dr.width(rate) // blocks
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        # _intra_counts: at least the net change, the last block's rates; times the scale.
        table = np.stack([_per_block(seconds, blocks), [per_sample] * blocks,
                          [float(x) for x in _per_block(most, blocks)]], axis=1)
        if blocks == 1:
            secs, per, top = _scalars(m, table[0], dr.width(rate))
        else:
            lane = dr.arange(m.UInt32, dr.width(rate))
            secs, per, top = _scalars(m, table, dr.width(rate), lane // image)

        def each(values):                       # a (P,) array read by every block's pixels
            return values if dr.width(values) == dr.width(rate) else _take(values, lane % image)
        r = _nan_max(rate, dr.abs(log_e - log_b) / secs)
        if observed is not None:
            r = _nan_max(r, each(observed))
        if scale is not None:
            r = r * each(scale)
        wanted = dr.ceil(r * secs / per)
        wanted = dr.select((wanted != wanted) | (wanted == math.inf), 0.0, wanted)
        inner = m.UInt32(dr.minimum(dr.maximum(wanted, 1.0), top) - 1.0)
        dr.eval(inner)                              # once, then summed
        total = dr.sum(m.UInt64(inner))
        return inner, int(total[0]), radius


def device_rate(weight: np.ndarray, logw: np.ndarray, shape: tuple[int, int], fx: float,
                fy: float, centres: tuple, depth: np.ndarray, twists: np.ndarray,
                dilation, device: str = "llvm") -> tuple[object, object]:
    """:func:`sim.pixel_sampling.rate_map` on the device (the arguments are
    :func:`device_prediction`'s): the rate map, flat ((B H W,) Dr.Jit Float64), and its
    dilation (pixels; a list, each block's, where ``weight`` has a block axis)."""
    from sim._drjit_events import _device_array

    m = _module(device)
    height, width = shape
    weight, logw = np.asarray(weight), np.asarray(logw)
    single = weight.ndim == 2
    blocks, rows, cols = weight.reshape(-1, *weight.shape[-2:]).shape
    n = rows // height
    if n >= 8:
        raise ValueError(f"device_prediction takes at most 7x7 sub-samples a pixel, got {n}x{n}")
    image = height * width
    dilations = _per_block(dilation, blocks)
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        w_d = _device_array(m.Float32, weight.reshape(-1))
        l_d = _device_array(m.Float32, logw.reshape(-1))
        size = blocks * rows * cols
        # One lane per (block, pixel row, sub-sample column): its n sub-sample rows summed in
        # float32; the neighbours only within the lane's block.
        lane = dr.arange(m.UInt32, blocks * height * cols)
        base = 0 if blocks == 1 else (lane // (height * cols)) * (rows * cols)
        y, c = (lane if blocks == 1 else lane % (height * cols)) // cols, lane % cols
        zero = m.Float32(0.0)
        acc = None
        for j in range(n):
            r = y * n + j
            at = base + r * cols + c
            level = _take(l_d, at)
            gu = dr.select(c + 1 < cols, dr.abs(_take(l_d, dr.minimum(at + 1, size - 1))
                                                - level), zero)
            gu = dr.select(c > 0, _nan_max(gu, dr.abs(level - _take(l_d, dr.maximum(at, 1) - 1))),
                           gu)
            gv = dr.select(r + 1 < rows, dr.abs(_take(l_d, dr.minimum(at + cols, size - 1))
                                                - level), zero)
            gv = dr.select(r > 0, _nan_max(gv, dr.abs(level - _take(l_d, dr.maximum(at, cols)
                                                                      - cols))), gv)
            w = _take(w_d, at)
            acc = ((w, gu * w, gv * w) if acc is None
                   else (acc[0] + w, acc[1] + gu * w, acc[2] + gv * w))
        dr.eval(acc)
        # Each pixel's n column sums in float64, in order (-0.0 + a is a).
        pixel = dr.arange(m.UInt32, blocks * image)
        if blocks == 1:
            block, own = None, pixel
            first = (pixel // width) * cols + (pixel % width) * n
        else:
            block, own = pixel // image, pixel % image
            first = block * (height * cols) + (own // width) * cols + (own % width) * n
        sums = [m.Float64(_take(a, first)) for a in acc]
        for i in range(1, n):
            sums = [s_ + m.Float64(_take(a, first + i)) for s_, a in zip(sums, acc, strict=True)]
        # Opaque: Dr.Jit turns a division by a literal into a product by its reciprocal.
        twists = np.asarray(twists, np.float64).reshape(blocks, -1, 6)
        if blocks == 1:
            nn, n_d, fx_d, fy_d, *motion = _scalars(m, [float(n * n), float(n), fx, fy,
                                                        *twists.reshape(-1)], image)
        else:
            nn, n_d, fx_d, fy_d = _scalars(m, [float(n * n), float(n), fx, fy], blocks * image)
            motion = _scalars(m, twists.reshape(blocks, -1), blocks * image, block)
        mean = sums[0] / nn
        slope_u = sums[1] / nn * (n_d / mean)
        slope_v = sums[2] / nn * (n_d / mean)
        # The motion field of each twist (sim.sampling._point_flow, its operations in order).
        x, yy = centres if blocks == 1 else (_take(centres[0], own), _take(centres[1], own))
        z = _device_array(m.Float64, np.asarray(depth, np.float64).reshape(-1))
        seen = z > 0.0
        best = m.Float64(0.0)
        squares = None
        for k in range(twists.shape[1]):
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
        # Each block's largest square (a maximum: exact in any order), inf where one is not
        # finite.
        finite = dr.select(dr.isfinite(squares), squares, math.inf)
        tops = ([float(dr.max(finite)[0])] if blocks == 1
                else dr.block_reduce(dr.ReduceOp.Max, finite, image).numpy().tolist())
        radii = [dilate(top if math.isfinite(top) else math.nan)
                 for dilate, top in zip(dilations, tops, strict=True)]
        rate = best
        if max(radii) > 0:                          # the maximum over the clamped window
            rate = _dilate(m, rate, height, width, radii)
        dr.eval(rate)
        return rate, (radii[0] if single else radii)


def _dilate(m, values, height: int, width: int, radii: list[int]):
    """The largest of ``values`` ((B H W,) Float64, each block's image row-major) over the
    ``(2 radius + 1)^2`` window of each pixel (its block's radius), the window clamped to the
    block's image (``cv2.dilate`` with a square kernel and ``BORDER_REPLICATE``): along the
    rows, then the columns, one symbolic loop each."""
    image = height * width
    pixel = dr.arange(m.UInt32, len(radii) * image)
    own = pixel % image
    py, px = m.Int32(own // width), m.Int32(own % width)
    if len(radii) == 1:
        r = _opaque(m.Int32, radii[0])
    else:
        r = _take(m.Int32(np.asarray(radii, np.int32)), pixel // image)
    for along, size in ((px, width), (py, height)):
        step = 1 if along is px else width
        src = values
        out = _take(src, pixel)
        d = dr.zeros(m.Int32, len(radii) * image) - r

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
