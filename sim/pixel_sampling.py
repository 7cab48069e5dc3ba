"""Per-pixel adaptive sampling of the event camera: each pixel renders at its own times.

For a scene whose objects and lights do not move, a pixel's luminance at time t depends only on
that pixel's rays from the camera pose at t. So instead of rendering whole frames at the rate the
fastest pixel needs (:mod:`sim.sampling`), every pixel keeps its own time line:

- Time advances in *blocks* of ``1 / min_rate`` seconds. A full frame is rendered at every block
  boundary; it is a sample of every pixel (so no pixel is sampled more rarely than
  ``min_rate``), and its log intensity and the exact depth there give the prediction for the
  block that follows.
- Prediction, per pixel: the motion field of the static scene (exact depth, the camera twist at
  both ends of the block) times the one-sided log-intensity gradient (brightness constancy, as
  :func:`sim.sampling.log_rate_bound` does for the whole image), dilated over the distance the
  fastest image point travels during the block (an edge that is a few pixels away at the start
  of the block arrives during it), and at least the pixel's net change over the block (which the
  frame at the block's end already shows). A pixel whose rate is ``r`` gets
  ``ceil(r B / (MARGIN lam C)) - 1`` evenly spaced samples inside the block (at most one per
  ``1 / max_rate``). All these samples, each at its own time and pose, are traced in one launch.
- Check, per pixel: every interval between two consecutive samples of a pixel whose log change
  exceeds ``lam C`` gets its midpoint rendered (only that pixel), level by level, one launch per
  level, and each half that still exceeds it is split again, down to ``2 / max_rate``
  (intervals that short still breaking the bound are counted in ``at_max_rate``). Unlike the
  frame sampler, a pixel's *step* (an edge crossing one of its sub-pixel samples, which
  refinement cannot shrink) is split down to that limit too: it costs one single-pixel render
  per level, not a whole frame, and it pins the step's time (a kink that only looks like a step
  at the first split is then resolved; ``steps`` counts the splits that found the change in one
  half). No render is discarded.
- The emulator then runs over every pixel's samples in time order (:class:`PixelEventEmulator`):
  each crossing of ``ref +/- C`` between two samples of a pixel gets its own interpolated
  timestamp, as in :class:`sim.events.EventEmulator` (the same threshold, leak, refractory and
  photoreceptor low-pass models, each pixel with its own time step). Background and hot-pixel
  events are drawn per block. All samples of a block lie in ``[t_b, t_e]`` and every pixel has a
  sample at ``t_e``, so the block's events are final when it ends: they leave sorted by time, one
  block at a time, in memory bounded by one pass (see Passes).

- Passes (:attr:`sim.sampling.SamplingParams.wavefront`, ``B``; the device path): ``B``
  consecutive blocks are predicted, built, shaded, checked and refined in one set of device
  launches, each block's image on its own, then emulated block after block (a pixel's samples
  reach the emulator in time order). The one change to the method: every block of a pass takes
  as its floor the observed rates of the last block before the pass (the most recent ones
  known when the pass starts), not those of the block just before it. ``B = 1`` is the method
  above, event for event. A run can be continued only after a pass (:attr:`PixelBlock.floor`).

- Edges (``edges``, ``[render] edge_spp``): point sub-samples alias where an edge of the
  geometry or of a shadow crosses a pixel (textures are filtered over each sub-sample's
  stratum, :mod:`sim.shader`; edges are not): as the edge jitters across a sub-sample, the
  pixel's value jumps by a quarter of the edge's contrast at 4 samples, over the threshold
  both ways, where the pixel's true, area-integrated value would hardly move. The pixels whose
  sub-samples, or theirs and a neighbour's, see different surfaces or lights, or normals more
  than 18 degrees apart (:func:`geometric_edges`) at either end of a block are rendered with
  ``edge_spp`` sub-samples throughout the block.

Exactness: the emulator sees every pixel's luminance at the pixel's own sample times, so its
interpolation error per interval is bounded by the change ``lam C`` the check enforces (except
in the steps and ``at_max_rate`` intervals, which are counted), the same guarantee as frame
sampling, per pixel.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from typing import Protocol

import cv2
import numba
import numpy as np

from sim.camera import Camera
from sim.eventio import EVENT_DTYPE
from sim.events import (
    CROSSING_TOLERANCE_NS,
    EventEmulator,
    EventParams,
    clocked,
    crossing_time,
    filtered_crossing_time,
    interval_levels,
    threshold_crossings,
)
from sim.noise import (
    CAUSE_LEAK,
    CAUSE_SIGNAL,
    _cutoff,
    _lowpass_exponent,
    drifted_inputs,
)
from sim.sampling import SPLIT, SamplingParams, _point_flow, _twist, contrast_scale

__all__ = ["EDGE_COS", "MAX_DILATION", "PixelBlock", "PixelEventEmulator", "PixelSamplingStats",
           "PixelSource", "geometric_edges", "pixel_blocks", "rate_map", "refine_edges"]

MARGIN = 0.5
"""The prediction aims at MARGIN * lam * C (frame sampling: 0.75)."""
EDGE_COS = 0.95
"""Two neighbouring sub-samples on one surface whose normals are more than arccos(0.95) = 18
degrees apart straddle a crease (a box's edge): :func:`geometric_edges`. A sphere or a
height field seen at 240x180 turns its normal by a few degrees a pixel."""
FRAMES_AHEAD = 16
"""Block-end frames the device path renders together (:meth:`sim.shader.EventShader.
subsamples_many`, launches of at most its ray limit): they do not depend on the samples."""
MAX_DILATION = 64
"""Largest radius (pixels) over which the predicted rate is spread within a block; faster image
motion is left to the check (it then costs bisection renders, never accuracy)."""


class PixelSource(Protocol):
    """What the per-pixel sampler renders from (see :class:`sim.shader.EventShader`).

    The mean of a pixel's sub-samples at ``t`` (:func:`pixel_means`) must be exactly the value
    ``luminance`` gives for that pixel at ``t``.
    """

    camera: Camera

    def luminance(self, pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Linear luminance (N,) of flat pixel indices (N,) at their own times (N,) seconds."""

    def subsamples(self, t: float) -> np.ndarray:
        """Linear luminance of every sub-sample at ``t`` on the sub-sample grid (H n, W n)."""

    def depth(self, t: float) -> np.ndarray:
        """Exact z-depth (H, W) in metres at pixel centres, 0 where nothing is seen."""

    def camera_velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The camera's (v, w) in the camera frame, m/s and rad/s."""

    def geometry(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """What every sub-sample sees at ``t`` (:meth:`sim.shader.EventShader.geometry`):
        key (H n, W n) uint32 and normal (H n, W n, 3); needed with ``edges`` only."""

    def fine_luminance(self, pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
        """As :meth:`luminance`, with more sub-samples per pixel (the pixels an edge
        crosses); needed with ``edges`` only."""


@dataclass
class PixelSamplingStats:
    """Counts of a per-pixel run (filled while iterating).

    Attributes
    ----------
    pixel_samples : int
        Single-pixel renders between the frames (scheduled ones and midpoints).
    midpoint_samples : int
        Of those, the midpoints rendered because an interval broke the bound.
    full_renders : int
        Whole frames rendered: one at each block boundary, and every sub-sample of the frame at
        each block's start (for the prediction).
    depth_renders : int
        Exact-depth renders made for the prediction (one per block).
    blocks : int
        Blocks done.
    intervals : int
        Per-pixel intervals the emulator went through.
    steps : int
        Splits whose midpoint found the whole change in one half (a sub-pixel-sample step, or
        a kink); they are split further all the same (see the module docstring).
    at_max_rate : int
        Intervals still breaking the bound at the maximum rate.
    edge_samples : int
        Renders of single pixels with ``source.fine_luminance`` (``edges``): those of the
        pixel samples that an edge's pixels took, and their re-renders at block boundaries.
    """

    pixel_samples: int = 0
    midpoint_samples: int = 0
    full_renders: int = 0
    depth_renders: int = 0
    blocks: int = 0
    intervals: int = 0
    steps: int = 0
    at_max_rate: int = 0
    edge_samples: int = 0


@dataclass(frozen=True)
class PixelBlock:
    """One finished block.

    Attributes
    ----------
    t : float, seconds
        The block's end (every pixel has a sample there).
    luminance : (H, W) float32 ndarray
        The frame rendered at ``t`` (the pixels an edge crosses there by
        ``source.fine_luminance``, with ``edges``).
    log : (H, W) float64 ndarray
        ``log(luminance + log_eps)``.
    events : (N,) EVENT_DTYPE ndarray
        The block's events, sorted by time (ties in pixel order).
    observed : (H W,) float64 ndarray
        Each pixel's largest observed |dL/dt| in the block (over the intervals that met the
        bound), 1/s.
    floor : (H W,) float64 ndarray or None, 1/s
        At the last block of a pass (:attr:`sim.sampling.SamplingParams.wavefront`): the
        rates the next pass's prediction takes as a floor (this block's ``observed``), which
        continuing after this block (``after`` of :func:`pixel_blocks`) needs. None inside a
        pass: the run cannot be continued from there.
    """

    t: float
    luminance: np.ndarray
    log: np.ndarray
    events: np.ndarray
    observed: np.ndarray
    floor: np.ndarray | None = None


def rate_map(camera: Camera, subsamples: np.ndarray, depth: np.ndarray,
             twists: list[tuple[np.ndarray, np.ndarray]], seconds: float,
             log_eps: float, centres: np.ndarray | None = None) -> np.ndarray:
    """Predicted |dL/dt| of every pixel over a block, 1/s.

    A pixel's value is the mean of its sub-samples, and each sub-sample sees the scene at its
    own point: a texture finer than the pixel changes the pixel's value faster than the
    pixel-level gradient says. So the gradient is taken on the sub-sample grid, each
    sub-sample's rate is its one-sided log gradient times the pixel's motion field, and the
    pixel's rate is ``sum_s (Y_s + eps) |dL_s/dt| / (spp (mean Y + eps))``, a bound of
    ``|d log(mean Y + eps) / dt|`` by the triangle inequality.

    Parameters
    ----------
    camera : Camera
    subsamples : (H n, W n) array_like
        Linear luminance of every sub-sample at the block's start, laid out on the sub-sample
        grid (:meth:`sim.shader.EventShader.subsamples`); ``n = 1`` for the pixels themselves.
    depth : (H, W) array_like, metres
        Exact depth at the block's start (0 where nothing is seen).
    twists : list of (v, w)
        Camera velocities (camera frame) at the times the block spans (its two ends).
    seconds : float
        The block's length.
    log_eps : float
        L = log(Y + log_eps).
    centres : (H, W, 2) ndarray, optional
        ``camera.normalized_pixel_centres()``, if the caller keeps it.

    Returns
    -------
    (H, W) float64 ndarray
        The largest predicted rate over the twists, dilated by the distance the fastest pixel
        moves in ``seconds`` (at most :data:`MAX_DILATION`).
    """
    height, width = camera.height, camera.width
    weight, logw, n = _log_weights(camera, subsamples, log_eps)
    slope_u, slope_v = _weighted_slopes(logw, weight, height, width, n)
    args = _flow_args(camera, camera.normalized_pixel_centres() if centres is None else centres,
                      depth, twists)
    rate, squares = _predicted_rate(*args, slope_u, slope_v)
    radius = _dilation_radius(squares, seconds, partial(_flow_speeds, *args))
    if radius > 0:
        kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
        rate = cv2.dilate(rate, kernel, borderType=cv2.BORDER_REPLICATE)
    return rate


def _flow_args(camera: Camera, centres: np.ndarray, depth: np.ndarray, twists: list) -> tuple:
    """The motion field's inputs as the kernels take them (:func:`_predicted_rate`,
    :func:`_flow_speeds`): ``fx``, ``fy``, the (H, W, 2) float64 pixel centres, the depth and
    the (K, 6) float64 twists (:func:`sim.sampling._twist`)."""
    return (float(camera.fx), float(camera.fy), np.asarray(centres, np.float64),
            np.asarray(depth), np.array([_twist(v, w) for v, w in twists]).reshape(-1, 6))


def _log_weights(camera: Camera, subsamples: np.ndarray, log_eps: float,
                 out: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`rate_map`'s weights ``Y_s + eps`` of the sub-samples ((H n, W n) float32: a rate,
    not a level), their float32 ``log`` (NumPy's: numba's and Dr.Jit's may differ in the last
    bit, so the host takes it for every path) and ``n``; written into ``out`` where given."""
    height, width = camera.height, camera.width
    luminance = np.asarray(subsamples, dtype=np.float32)
    n = luminance.shape[0] // height
    if luminance.shape != (height * n, width * n) or n < 1:
        raise ValueError(f"subsamples must have shape (H n, W n) for the camera's {height}x"
                         f"{width} pixels, got {luminance.shape}")
    weight, logw = out if out is not None else (None, None)
    weight = np.add(luminance, np.float32(log_eps), out=weight)
    return weight, np.log(weight, out=logw), n


# The prediction's per-pixel work, compiled (rows in parallel): each kernel gives exactly the
# NumPy expression of the issue-23 code it replaced, float for float (the same float32 and
# float64 operations in the same order; tests/test_sampler_kernels.py checks them bit for bit
# on random inputs).


@numba.njit(cache=True, inline="always")
def _nan_max(a, b):  # pragma: no cover - compiled
    """``np.maximum(a, b)``: the larger, NaN if either is."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a >= b else b


@numba.njit(cache=True)
def _pairwise_leaf(values, lo, n):  # pragma: no cover - compiled
    """:func:`_pairwise_sum` of at most 128 terms."""
    if n < 8:
        res = -0.0
        for i in range(n):
            res += np.float64(values[lo + i])
        return res
    r = np.empty(8)
    for q in range(8):
        r[q] = np.float64(values[lo + q])
    i = 8
    while i < n - n % 8:
        for q in range(8):
            r[q] += np.float64(values[lo + i + q])
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += np.float64(values[lo + i])
        i += 1
    return res


@numba.njit(cache=True)
def _pairwise_sum(values, lo, n):  # pragma: no cover - compiled
    """``values[lo:lo + n]`` (float32) summed in float64 as NumPy's ``sum(dtype=float64)``
    does: its pairwise summation (a plain loop under 8 terms, 8 partial sums up to 128, then
    the two halves' sums added; the halves walked with a stack, not by recursion, which
    numba's cache cannot link)."""
    if n <= 128:
        return _pairwise_leaf(values, lo, n)
    starts = np.empty(64, np.int64)
    sizes = np.empty(64, np.int64)
    stages = np.empty(64, np.int64)
    sums = np.empty(64)
    top, done = 0, 0
    starts[0], sizes[0], stages[0] = lo, n, 0
    while top >= 0:
        start, size = starts[top], sizes[top]
        if size <= 128:
            sums[done] = _pairwise_leaf(values, start, size)
            done += 1
            top -= 1
            continue
        half = size // 2
        half -= half % 8
        if stages[top] == 2:                     # both halves summed: add them
            sums[done - 2] = sums[done - 2] + sums[done - 1]
            done -= 1
            top -= 1
            continue
        stages[top] += 1
        first = stages[top] == 1
        top += 1
        starts[top] = start if first else start + half
        sizes[top] = half if first else size - half
        stages[top] = 0
    return sums[0]


@numba.njit(cache=True, parallel=True)
def _weighted_slopes(logw, weight, height, width, n):  # pragma: no cover - compiled
    """Each pixel's ``sum_s w_s |dL_s/du|`` and ``|dL_s/dv|`` (one-sided, the larger of the two
    differences on the sub-sample grid) over its ``n x n`` sub-samples, divided by
    ``sum_s w_s / n``: :func:`rate_map`'s slopes (H, W) float64. ``logw`` and ``weight`` are
    the (H n, W n) float32 log weights and weights; a pixel row's ``n`` sub-sample rows are
    summed in float32, in order, then each pixel's ``n`` column sums in float64 (in NumPy's
    order: :func:`_pairwise_sum`, a plain loop under 8 terms). The motion field is one value
    per pixel, so the sub-sample sum factors: the weighted gradients are averaged once (times
    ``n``: per pixel, not per sub-sample spacing)."""
    rows, cols = logw.shape
    zero = np.float32(0.0)
    slope_u = np.empty((height, width))
    slope_v = np.empty((height, width))
    nn = n * n
    for y in numba.prange(height):
        acc_w = np.empty(cols, np.float32)
        acc_u = np.empty(cols, np.float32)
        acc_v = np.empty(cols, np.float32)
        for j in range(n):
            r = y * n + j
            for c in range(cols):
                level = logw[r, c]
                gu = abs(logw[r, c + 1] - level) if c + 1 < cols else zero
                if c > 0:
                    gu = _nan_max(gu, abs(level - logw[r, c - 1]))
                gv = abs(logw[r + 1, c] - level) if r + 1 < rows else zero
                if r > 0:
                    gv = _nan_max(gv, abs(level - logw[r - 1, c]))
                w = weight[r, c]
                if j == 0:
                    acc_w[c], acc_u[c], acc_v[c] = w, gu * w, gv * w
                else:
                    acc_w[c] = acc_w[c] + w
                    acc_u[c] = acc_u[c] + gu * w
                    acc_v[c] = acc_v[c] + gv * w
        for x in range(width):
            lo = x * n
            if n < 8:
                s_w, s_u, s_v = -0.0, -0.0, -0.0
                for i in range(lo, lo + n):
                    s_w += np.float64(acc_w[i])
                    s_u += np.float64(acc_u[i])
                    s_v += np.float64(acc_v[i])
            else:
                s_w = _pairwise_sum(acc_w, lo, n)
                s_u = _pairwise_sum(acc_u, lo, n)
                s_v = _pairwise_sum(acc_v, lo, n)
            mean = s_w / nn
            slope_u[y, x] = s_u / nn * (n / mean)
            slope_v[y, x] = s_v / nn * (n / mean)
    return slope_u, slope_v


@numba.njit(cache=True, parallel=True)
def _predicted_rate(fx, fy, xy, depth, twists, slope_u, slope_v):  # pragma: no cover
    """Each pixel's largest ``slope_u |du/dt| + slope_v |dv/dt|`` over the twists (motion field
    :func:`sim.sampling._point_flow`, 0 where ``depth`` <= 0), (H, W) float64, and per twist
    the largest ``du^2 + dv^2`` (0 at least, NaN if any is): the fastest pixel's speed squared,
    rounded (:func:`_flow_speeds` gives the speeds themselves; :func:`_dilation_radius`)."""
    height, width = depth.shape
    n_twists = twists.shape[0]
    rate = np.empty((height, width))
    tops = np.zeros((height, n_twists))
    for y in numba.prange(height):
        for x in range(width):
            z = np.float64(depth[y, x])
            best = 0.0
            for k in range(n_twists):
                du, dv = 0.0, 0.0
                if z > 0.0:
                    du, dv = _point_flow(fx, fy, xy[y, x, 0], xy[y, x, 1], z, twists[k])
                best = _nan_max(best, slope_u[y, x] * abs(du) + slope_v[y, x] * abs(dv))
                tops[y, k] = _nan_max(tops[y, k], du * du + dv * dv)
            rate[y, x] = best
    squares = np.zeros(n_twists)
    for k in range(n_twists):
        for y in range(height):
            squares[k] = _nan_max(squares[k], tops[y, k])
    return rate, squares


@numba.njit(cache=True)
def _flow_speeds(fx, fy, xy, depth, twists):  # pragma: no cover - compiled
    """Per twist the largest ``hypot(du/dt, dv/dt)`` over the pixels of :func:`_predicted_rate`
    (0 at least, NaN if any is), pixels/s: the exact speeds, where :func:`_dilation_radius`
    cannot decide from the squares."""
    height, width = depth.shape
    speeds = np.zeros(twists.shape[0])
    for k in range(twists.shape[0]):
        for y in range(height):
            for x in range(width):
                z = np.float64(depth[y, x])
                du, dv = 0.0, 0.0
                if z > 0.0:
                    du, dv = _point_flow(fx, fy, xy[y, x, 0], xy[y, x, 1], z, twists[k])
                speeds[k] = _nan_max(speeds[k], math.hypot(du, dv))
    return speeds


SPEED_SLACK = 1e-12
"""Relative gap :func:`_dilation_radius` allows between ``sqrt`` of a twist's largest
``du^2 + dv^2`` and its largest ``hypot(du, dv)``: each is within 2 ulp (4.5e-16) of the
exact value, so the pixel radius ``ceil(speed seconds)`` taken from the squares is the one
taken from ``hypot`` whenever no integer lies within this slack of ``speed seconds``."""


def _dilation_radius(squares: np.ndarray, seconds: float, exact: Callable[[], np.ndarray]
                     ) -> int:
    """The prediction's dilation in pixels: ``min(MAX_DILATION, ceil(speed seconds))`` with
    ``speed`` the largest over the twists of the fastest pixel's ``hypot(du, dv)`` (a NaN
    twist skipped), as it was computed from every pixel's ``hypot``.

    From ``sqrt`` of each twist's largest ``du^2 + dv^2`` (``squares``, :func:`_predicted_rate`:
    no ``hypot`` per pixel, half the kernel's time) when that decides the integer within
    :data:`SPEED_SLACK`; else, or where the squares are not finite or all (nearly) 0 (a
    speed of 1e-170 squares to 0), from ``exact()``
    (:func:`_flow_speeds`), so the radius is always ``hypot``'s
    (``tests/test_sampler_kernels.py``)."""
    squares = np.asarray(squares, np.float64)
    if np.all(np.isfinite(squares)) and squares.max(initial=0.0) > 1e-280:
        product = math.sqrt(float(squares.max())) * seconds
        if math.ceil(product * (1.0 - SPEED_SLACK)) == math.ceil(product * (1.0 + SPEED_SLACK)):
            return min(MAX_DILATION, math.ceil(product))
    speed = 0.0
    for top in exact():           # as ``max(speed, np.max(hypot))``: a NaN twist is skipped
        speed = max(speed, float(top))
    return min(MAX_DILATION, math.ceil(speed * seconds))


def pixel_means(subsamples: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Each pixel's value from its sub-samples, as :class:`sim.shader.EventShader` sums them.

    Parameters
    ----------
    subsamples : (H n, W n) float32 ndarray
        Sub-sample luminance on the sub-sample grid.
    shape : (int, int)
        (H, W).

    Returns
    -------
    (H, W) float32 ndarray
        ``(((s_0 + s_1) + s_2) + ...) * (1 / spp)`` in float32, sub-samples in stratum order
        (row-major within the pixel): bit-identical to the shader's pixel values
        (``tests/test_shader.py`` checks it).
    """
    height, width = shape
    n = subsamples.shape[0] // height
    strata = np.asarray(subsamples, np.float32).reshape(height, n, width, n).transpose(0, 2, 1, 3)
    total = np.zeros(shape, np.float32)
    for j in range(n):
        for i in range(n):
            total = total + strata[:, :, j, i]
    return total * np.float32(1.0 / (n * n))


# ------------------------------------------------------------------------------------------------
# The emulator over per-pixel samples
# ------------------------------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _write_crossing(out_t, out_pix, out_p, out_cause, keep, n, te, p, sign, cause, last,
                    refractory):  # pragma: no cover - compiled
    """Crossing ``n`` of the per-pixel kernels (time ``te`` ns, pixel ``p``, polarity, cause),
    ``keep`` False where it falls within the refractory period after the pixel's last kept
    one; returns the pixel's last kept time."""
    out_t[n] = te
    out_pix[n] = p
    out_p[n] = sign
    out_cause[n] = cause
    if refractory > 0 and te - last < refractory:
        keep[n] = False
        return last
    keep[n] = True
    return te


@numba.njit(cache=True)
def _pixel_events(pix, t, L, exponent, ref, level, raw, last_t, c_on, c_off, leak, normals,
                  refractory, out_t, out_pix, out_p, out_cause,
                  keep):  # pragma: no cover - compiled
    """Threshold crossings of per-pixel samples sorted by (pixel, time); the first sample of
    each pixel is its state at the block start. Returns their number and leaves each pixel's
    state (``ref``, ``level``, ``raw``, ``last_t``) at its last sample.

    One pass: the first ``len(out_t)`` crossings are written (time solved once, ``keep``
    False for those the refractory period drops, and each one's cause in ``out_cause``:
    :data:`~sim.noise.CAUSE_LEAK` beyond the count of the level alone, without the leak drift,
    on its piece; else :data:`~sim.noise.CAUSE_SIGNAL`, the rule of :mod:`sim.noise`), the
    rest only counted (no time solved). The leak drifts each reference linearly within an
    interval, and a crossing is timed where the level meets the drifting reference
    (:func:`sim.noise.drifted_inputs`). A return above ``len(out_t)`` means the outputs were
    too short: restore the state and call again with outputs that long
    (:meth:`PixelEventEmulator._numba_crossings`).

    ``exponent[j - 1]`` is the interval from sample ``j - 1`` to ``j`` in time constants of
    the low-pass (:func:`sim.noise.lowpass_exponent`; ``inf``: no filter); ``leak`` is (rate
    per pixel (P,), jitter), with one normal draw per interval in sample order.

    One thread: in ``simulate`` the event stage runs numba on one thread beside Dr.Jit's
    workers (:func:`sim.simulate._events._event_stage`), and a parallel version (spans of whole
    pixels over numba's threads, the same events) was slower than this one on the 2-core
    development machine even in a process without Dr.Jit (boxes_6dof's realistic blocks, 0.8 M
    samples each: 0.40 s against 0.24 s for five). The same kernel on Dr.Jit's device (every
    core or the GPU) is :func:`sim._drjit_events.pixel_events`.
    """
    capacity = len(out_t)
    j, end, k, n = 0, len(pix), 0, 0
    leak_rates, leak_jitter = leak
    while j < end:
        p = pix[j]
        r = ref[p]
        lf = level[p]
        la = raw[p]
        ta = t[j]
        last = last_t[p]
        j += 1
        while j < end and pix[j] == p:
            tb = t[j]
            lb = L[j]
            dt = tb - ta
            x = exponent[j - 1]
            rf = r                                  # the interval's leak-free reference
            # The leak drifts the reference down by d over the interval, linearly: the
            # crossings are the level plus the drift so far against r (drifted_inputs).
            d, a, b = 0.0, la, lb
            if leak_rates.size:
                jitter = 1.0 - leak_jitter * normals[k]
                if jitter < 0.0:
                    jitter = 0.0
                d = (dt * 1e-9) * leak_rates[p] * jitter * c_on[p]
                a, b = drifted_inputs(la, lb, x, d)
            f_turn, y_turn, y_end = interval_levels(lf, a, b, x)
            lf_new = interval_levels(lf, la, lb, x)[2] if leak_rates.size else y_end
            # The monotonic pieces of the level plus drift: up to the turn, then (if it turns)
            # to the end.
            f_lo, y_lo, f_hi, y_hi = 0.0, lf, f_turn, y_turn
            while True:
                count, c, sign = threshold_crossings(y_hi, r, c_on[p], c_off[p])
                nf, cf, sf = threshold_crossings(y_hi - d * f_hi, rf, c_on[p], c_off[p])
                rf += nf * cf
                if n + count <= capacity:
                    for i in range(1, count + 1):
                        te = filtered_crossing_time(r + i * c, lf, a, b, x, f_lo, y_lo, f_hi,
                                                    y_hi, ta, float(dt))
                        last = _write_crossing(
                            out_t, out_pix, out_p, out_cause, keep, n, te, p, sign,
                            CAUSE_LEAK if sf != sign or i > nf else CAUSE_SIGNAL, last,
                            refractory)
                        n += 1
                else:
                    n += count
                r += count * c
                if f_hi >= 1.0:
                    break
                f_lo, y_lo, f_hi, y_hi = f_hi, y_hi, 1.0, y_end
            r -= d
            lf, la, ta = lf_new, lb, tb
            j += 1
            k += 1
        ref[p] = r
        level[p] = lf
        raw[p] = la
        last_t[p] = last
    return n


@numba.njit(cache=True)
def _pixel_events_direct(pix, t, L, ref, level, raw, last_t, c_on, c_off, refractory, out_t,
                         out_pix, out_p, out_cause, keep):  # pragma: no cover - compiled
    """:func:`_pixel_events` without the low-pass filter and without leak (``exponent`` all
    ``inf``, ``leak`` empty): the common case, in one threshold test per interval.

    The same crossings, times, causes and pixel states bit for bit: without the filter the
    level is the input (:func:`sim.events.interval_levels` gives ``(1.0, b, b)``), the
    leak-free count is the count, every crossing's cause is the signal, and each time is
    :func:`sim.events.filtered_crossing_time`'s at ``x = inf``, :func:`sim.events.crossing_time`
    on the line from the last level (``tests/test_sampler_kernels.py`` compares the two
    kernels on random blocks). It skips the general kernel's second threshold test, its
    per-interval filter and leak branches and the ``exponent`` array (a float64 per sample).
    """
    capacity = len(out_t)
    j, end, n = 0, len(pix), 0
    while j < end:
        p = pix[j]
        r = ref[p]
        lf = level[p]
        ta = t[j]
        last = last_t[p]
        con, coff = c_on[p], c_off[p]
        j += 1
        while j < end and pix[j] == p:
            tb = t[j]
            lb = L[j]
            count, c, sign = threshold_crossings(lb, r, con, coff)
            if count:
                if n + count <= capacity:
                    dt = float(tb - ta)
                    for i in range(1, count + 1):
                        te = crossing_time(r + i * c, lf, lb - lf, ta, dt)
                        last = _write_crossing(out_t, out_pix, out_p, out_cause, keep, n, te, p,
                                               sign, CAUSE_SIGNAL, last, refractory)
                        n += 1
                else:
                    n += count
            r += count * c                          # also when 0: -0.0 becomes 0.0, as there
            lf, ta = lb, tb
            j += 1
        ref[p] = r
        level[p] = lf
        raw[p] = lf
        last_t[p] = last
    return n


def _outputs(n: int) -> tuple[np.ndarray, ...]:
    """Times (int64 ns), flat pixels (int64), polarities (int8), causes (uint8) and keep
    flags of ``n`` crossings."""
    return np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int8), \
        np.empty(n, np.uint8), np.empty(n, np.bool_)


class PixelEventEmulator(EventEmulator):
    """:class:`~sim.events.EventEmulator` fed with per-pixel samples, a block at a time.

    The same sensor (thresholds, hot pixels, leak rates drawn from the seed in the same order),
    the same state (:meth:`get_state` / :meth:`set_state`) and the same models; only the
    samples differ: each pixel has its own times. :meth:`start` sets the first frame.

    ``kernel`` (:class:`~sim.events.EventEmulator`): ``numba`` solves a block's crossings with
    :func:`_pixel_events` on one CPU thread, ``drjit`` with
    :func:`sim._drjit_events.pixel_events` on the variant's device.
    """

    def __init__(self, shape: tuple[int, int], params: EventParams | None = None,
                 kernel: str = "auto") -> None:
        super().__init__(shape, params, kernel)
        self._last_count = 0                 # the last block's crossings (sizes the outputs)

    def warm_up(self) -> float:
        """:meth:`EventEmulator.warm_up` for this emulator's kernel (a throwaway 1x2 sensor fed
        one block of per-pixel samples); this emulator's state is untouched."""
        tick = time.perf_counter()
        spare = type(self)((1, 2), self.params, self.kernel)
        spare.profile_stage = "emulate_compile"
        spare.start(np.zeros((1, 2)), 0.0)
        pixels = np.array([0, 0, 0, 1, 1], np.int64)
        times = np.array([0, 500_000, 1_000_000, 0, 1_000_000], np.int64)
        levels = np.array([0.0, 0.5, 1.0, 0.0, -1.0])
        spare.advance_samples(pixels, times, levels, np.exp(levels), 1_000_000,
                              np.array([[np.e, np.exp(-1.0)]]))
        return time.perf_counter() - tick

    @clocked
    def advance_samples(self, pixels: np.ndarray, times_ns: np.ndarray, levels: np.ndarray,
                        luminance: np.ndarray, t_end_ns: int, end_luminance: np.ndarray
                        ) -> np.ndarray:
        """Process one block of per-pixel samples.

        Parameters
        ----------
        pixels : (S,) int64 ndarray
            Flat pixel index of each sample, sorted by pixel; within a pixel, ``times_ns``
            increases. Each pixel's first sample is its sample at the block start (its state,
            already processed) and its last one is at ``t_end_ns``.
        times_ns : (S,) int64 ndarray, nanoseconds
        levels : (S,) float64 ndarray
            Unfiltered log intensity of each sample.
        luminance : (S,) float64 ndarray
            Linear luminance of each sample (sets the low-pass cutoff).
        t_end_ns : int
            The block's end.
        end_luminance : (H, W) array_like
            Luminance at the block's end (background-activity rates).

        Returns
        -------
        (N,) EVENT_DTYPE ndarray
            Events with block start < t <= block end (threshold crossings) and noise events in
            [block start, block end), sorted by time, ties in pixel order.
        """
        if self.ref is None:
            raise ValueError("call start() before advance_samples()")
        noise = self.params.noise
        t0_ns = self._t
        if np.shares_memory(self._L, self._raw):       # start() sets both to the same array
            self._L = self._L.copy()
        ref, level, raw = self.ref.reshape(-1), self._L.reshape(-1), self._raw.reshape(-1)
        last_t = self._last_t.reshape(-1)
        normals, leak = self._leak_draws(pixels)
        cutoff = None
        if noise.cutoff_hz > 0:
            same = pixels[1:] == pixels[:-1]
            cutoff = _cutoff(np.asarray(luminance, np.float64), noise)
            dt = np.diff(times_ns)
            if not (np.all(np.isfinite(cutoff)) and np.all(cutoff >= 0)
                    and np.all((dt > 0) | ~same)):
                raise ValueError("luminance must be finite and >= 0 and each pixel's times "
                                 "must increase")
        refractory = int(round(noise.refractory_period * 1e9))
        c_on, c_off = self.c_on.reshape(-1), self.c_off.reshape(-1)
        state = (ref, level, raw, last_t, c_on, c_off, leak, normals, refractory)
        if self.kernel == "drjit":        # the low-pass exponents too are taken on the device
            from sim._drjit_events import pixel_events

            crossings = pixel_events(pixels, times_ns, levels, cutoff, *state,
                                     CROSSING_TOLERANCE_NS, device=self._device)
        else:
            if cutoff is None and not len(normals):     # no filter, no leak: the short kernel
                crossings = self._numba_crossings(
                    _pixel_events_direct, (pixels, times_ns, levels, ref, level, raw, last_t,
                                           c_on, c_off, refractory), 3)
                return self._events_of(crossings, refractory, t0_ns, t_end_ns, end_luminance)
            if cutoff is None:
                exponent = np.full(max(len(pixels) - 1, 0), np.inf)
            else:
                # Every pair of consecutive samples at once, then inf between two pixels: the
                # same values as lowpass_exponent on the pixels' own intervals.
                exponent = _lowpass_exponent(dt * 1e-9, cutoff[:-1], cutoff[1:])
                exponent[~same] = np.inf
            crossings = self._numba_crossings(_pixel_events, (pixels, times_ns, levels,
                                                              exponent, *state), 4)
        return self._events_of(crossings, refractory, t0_ns, t_end_ns, end_luminance)

    @clocked
    def advance_device(self, counts: np.ndarray, times_ns, levels, luminance, t_end_ns: int,
                       end_luminance: np.ndarray) -> np.ndarray:
        """:meth:`advance_samples` of samples left on the Dr.Jit device (``kernel`` drjit):
        the same events for the same samples.

        Parameters
        ----------
        counts : (P,) int64 ndarray
            Samples of each pixel (its start sample, the inner ones, its end sample), the
            samples in pixel order.
        times_ns, levels, luminance : (S,) Dr.Jit Int64, Float64, Float64 arrays
            Each sample's time (ns), unfiltered log intensity and linear luminance, sorted by
            pixel, then time (:func:`sim._drjit_sampling.device_block`).
        t_end_ns : int
        end_luminance : (H, W) array_like

        Returns
        -------
        (N,) EVENT_DTYPE ndarray
            As :meth:`advance_samples`.
        """
        if self.ref is None:
            raise ValueError("call start() before advance_device()")
        if self.kernel != "drjit":
            raise ValueError("advance_device needs the drjit kernel (PixelEventEmulator(..., "
                             "kernel='drjit'))")
        import drjit as dr

        from sim._drjit_events import pixel_events_device

        noise = self.params.noise
        if np.shares_memory(self._L, self._raw):       # start() sets both to the same array
            self._L = self._L.copy()
        counts = np.asarray(counts, np.int64)
        normals, leak = np.zeros(0), (np.zeros(0), 0.0)
        if noise.leak_rate > 0:                         # one draw per interval, in order
            normals = self._rng.standard_normal(int(counts.sum()) - len(counts))
            leak = (self.leak_rates.reshape(-1), float(noise.leak_jitter))
        cutoff = None
        if noise.cutoff_hz > 0:                         # sim.noise._cutoff, IEEE on the device
            with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
                cutoff = dr.clip(luminance / noise.cutoff_intensity_ref,
                                 noise.cutoff_min_fraction, 1.0) * noise.cutoff_hz
        refractory = int(round(noise.refractory_period * 1e9))
        crossings = pixel_events_device(
            counts, times_ns, levels, cutoff, self.ref.reshape(-1), self._L.reshape(-1),
            self._raw.reshape(-1), self._last_t.reshape(-1), self.c_on.reshape(-1),
            self.c_off.reshape(-1), leak, normals, refractory, CROSSING_TOLERANCE_NS,
            device=self._device)
        return self._events_of(crossings, refractory, self._t, t_end_ns, end_luminance)

    def _events_of(self, crossings: tuple[np.ndarray, ...], refractory: int, t0_ns: int,
                   t_end_ns: int, end_luminance: np.ndarray) -> np.ndarray:
        """A block's events from its crossings (those the refractory period keeps, sorted by
        time, ties in pixel order), noise merged in by :meth:`_close_block`."""
        n_pixels = self.shape[0] * self.shape[1]
        out_t, out_pix, out_p, out_cause, keep = crossings
        if refractory > 0 and not keep.all():
            out_t, out_pix, out_p, out_cause = (out_t[keep], out_pix[keep], out_p[keep],
                                                out_cause[keep])
        order = np.argsort((out_t - t0_ns) * n_pixels + out_pix)
        total = len(order)
        events = np.empty(total, EVENT_DTYPE)
        events["t"] = out_t[order]
        events["y"], events["x"] = np.divmod(out_pix[order], self.shape[1])
        events["p"] = out_p[order]
        return self._close_block(events, t0_ns, t_end_ns, end_luminance, out_cause[order])

    def _numba_crossings(self, kernel: Callable, args: tuple,
                         first_state: int) -> tuple[np.ndarray, ...]:
        """``kernel`` (:func:`_pixel_events` or :func:`_pixel_events_direct`, whose pixel
        state ``ref, level, raw, last_t`` is ``args[first_state:first_state + 4]``) in one
        pass, with outputs sized from the last block's count (twice it, at least 4,096); when
        they are too short, the pixels' state is restored and the kernel runs again with
        outputs of the exact size. Returns the crossings' times, pixels, polarities, causes
        and keep flags, in (pixel, time) order."""
        state = args[first_state:first_state + 4]
        saved = [a.copy() for a in state]
        outputs = _outputs(max(2 * self._last_count, 4096))
        n = kernel(*args, *outputs)
        if n > len(outputs[0]):
            for a, b in zip(state, saved, strict=True):
                a[...] = b
            outputs = _outputs(n)
            kernel(*args, *outputs)
        self._last_count = n
        return tuple(a[:n] for a in outputs)

    def _leak_draws(self, pixels: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, float]]:
        """The leak's normal draws of a block (one per interval within a pixel's run, drawn
        from the emulator's generator in order) and ``(rates, jitter)``; empty without leak.

        Parameters
        ----------
        pixels : (N,) int64 ndarray
            Flat pixel index of each sample, each pixel's samples consecutive.

        Returns
        -------
        normals : float64 ndarray
        leak : (float64 ndarray of the pixels' rates, float jitter)
        """
        noise = self.params.noise
        if noise.leak_rate <= 0:
            return np.zeros(0), (np.zeros(0), 0.0)
        intervals = len(pixels) - 1 - int(np.count_nonzero(pixels[1:] != pixels[:-1]))
        return (self._rng.standard_normal(intervals),
                (self.leak_rates.reshape(-1), float(noise.leak_jitter)))

    def _close_block(self, events: np.ndarray, t0_ns: int, t_end_ns: int,
                     end_luminance: np.ndarray, causes: np.ndarray | None = None) -> np.ndarray:
        """A block's crossing events with its shot-noise and hot-pixel events merged in (drawn
        in that order from the emulator's generator; :attr:`last_causes` set), and the
        emulator moved to ``t_end_ns``.

        Parameters
        ----------
        events : EVENT_DTYPE ndarray
            The block's threshold-crossing events, in time order.
        t0_ns, t_end_ns : int
            The block's start and end, ns.
        end_luminance : (H, W) ndarray
            Each pixel's luminance at ``t_end_ns``, cd/m^2.
        causes : (N,) uint8 ndarray, optional
            Each crossing's cause (default all :data:`~sim.noise.CAUSE_SIGNAL`).

        Returns
        -------
        EVENT_DTYPE ndarray
        """
        if causes is None:
            causes = np.full(len(events), CAUSE_SIGNAL, np.uint8)
        events = self._with_noise(events, causes, t0_ns, t_end_ns,
                                  np.asarray(end_luminance, np.float64))
        self._cutoff = self._cutoff_at(self._raw, end_luminance)
        self._t = int(t_end_ns)
        return events


# ------------------------------------------------------------------------------------------------
# The scheduler
# ------------------------------------------------------------------------------------------------


# ------------------------------------------------------------------------------------------------
# The scheduler's bookkeeping, compiled: one pass per array instead of NumPy's temporaries (at
# 1280x720 a block holds millions of samples; the NumPy version took about 130 ns a sample).
# Each kernel does exactly what the NumPy expression in its docstring does (the same integer and
# float64 operations: the samples are identical, tests/test_sampler_kernels.py).


@numba.njit(cache=True)
def _block_offsets(inner):  # pragma: no cover - compiled
    """Where each pixel's samples of a block start (``first``: its start sample, then
    ``inner[p]`` middle ones and its end sample) and where its middle ones start among all
    middle samples (``mid_first``), with the totals of both."""
    n_pixels = inner.shape[0]
    first = np.empty(n_pixels, np.int64)
    mid_first = np.empty(n_pixels, np.int64)
    total, middle = 0, 0
    for p in range(n_pixels):
        first[p], mid_first[p] = total, middle
        total += inner[p] + 2
        middle += inner[p]
    return first, mid_first, total, middle


@numba.njit(cache=True, parallel=True)
def _block_samples(inner, t_b, length, log_b, lum_b, log_e, lum_e, t0, t1):  # pragma: no cover
    """Every pixel's samples of a block, sorted by (pixel, time): its start sample, ``inner[p]``
    evenly spaced ones at ``t_b + (k * length) // (inner[p] + 1)`` ns, its end sample; the
    start and end ones hold the frames' levels and luminances, the middle ones are returned as
    pixels and seconds (``clip(ns * 1e-9, t0, t1)``) to render."""
    n_pixels = inner.shape[0]
    first, mid_first, total, middle = _block_offsets(inner)
    pix = np.empty(total, np.int64)
    times = np.empty(total, np.int64)
    levels = np.empty(total)
    lums = np.empty(total)
    mid_pix = np.empty(middle, np.int64)
    mid_s = np.empty(middle)
    for p in numba.prange(n_pixels):
        f, k_in, m = first[p], inner[p], mid_first[p]
        for k in range(k_in + 2):
            t = t_b + (k * length) // (k_in + 1)
            pix[f + k] = p
            times[f + k] = t
            if 0 < k <= k_in:
                mid_pix[m + k - 1] = p
                mid_s[m + k - 1] = min(max(t * 1e-9, t0), t1)
        levels[f], lums[f] = log_b[p], lum_b[p]
        levels[f + k_in + 1], lums[f + k_in + 1] = log_e[p], lum_e[p]
    return pix, times, levels, lums, mid_pix, mid_s


@numba.njit(cache=True, parallel=True)
def _fill_middle(inner, values, logs, levels, lums):  # pragma: no cover - compiled
    """Write the middle samples' luminances and levels (in :func:`_block_samples`' order) into
    the block's arrays."""
    n_pixels = inner.shape[0]
    first, mid_first, total, middle = _block_offsets(inner)
    for p in numba.prange(n_pixels):
        f, m = first[p], mid_first[p]
        for k in range(inner[p]):
            lums[f + 1 + k] = values[m + k]
            levels[f + 1 + k] = logs[m + k]


@numba.njit(cache=True, parallel=True)
def _plus(values, offset, out):  # pragma: no cover - compiled
    """``out[...] = np.asarray(values, np.float64) + offset``, in one pass."""
    for i in numba.prange(values.shape[0]):
        out[i] = np.float64(values[i]) + offset


@numba.njit(cache=True)
def _max_met_slopes(pix, times, levels, bound, scale, n_pixels):  # pragma: no cover
    """Each pixel's largest ``|dL| / max(dt, 1) * 1e9`` over its intervals whose (scaled)
    change is at most ``bound`` (0 where none); ``scale`` empty: all thresholds equal."""
    out = np.zeros(n_pixels)
    scaled = scale.shape[0] > 0
    for i in range(pix.shape[0] - 1):
        p = pix[i]
        if pix[i + 1] != p:
            continue
        change = abs(levels[i + 1] - levels[i])
        if (change * scale[p] if scaled else change) <= bound:
            slope = change / max(times[i + 1] - times[i], 1) * 1e9
            if slope > out[p]:
                out[p] = slope
    return out


@numba.njit(cache=True)
def _breaking_intervals(pix, levels, bound, scale):  # pragma: no cover - compiled
    """Indices ``i`` of the intervals ``(i, i + 1)`` within one pixel whose (scaled) change
    ``|levels[i + 1] - levels[i]|`` exceeds ``bound``; ``scale`` empty: all thresholds equal."""
    scaled = scale.shape[0] > 0
    out = np.empty(max(pix.shape[0] - 1, 0), np.int64)
    count = 0
    for i in range(pix.shape[0] - 1):
        p = pix[i]
        if pix[i + 1] != p:
            continue
        change = abs(levels[i + 1] - levels[i])
        if (change * scale[p] if scaled else change) > bound:
            out[count] = i
            count += 1
    return out[:count]


@numba.njit(cache=True, parallel=True)
def _insert_samples(pix, times, levels, lums, at, new_p, new_t, new_l, new_y):  # pragma: no cover
    """``np.insert(a, at, new_a)`` of the four arrays at once (``at`` non-decreasing: each new
    sample goes before the old one at its index, new ones at one index in their order). The
    old samples between two insertion points move as one run, the runs in parallel."""
    n, m = pix.shape[0], at.shape[0]
    out_p = np.empty(n + m, np.int64)
    out_t = np.empty(n + m, np.int64)
    out_l = np.empty(n + m)
    out_y = np.empty(n + m)
    for i in numba.prange(m + 1):
        lo = at[i - 1] if i > 0 else 0
        hi = at[i] if i < m else n
        for j in range(lo, hi):
            out_p[i + j] = pix[j]
            out_t[i + j] = times[j]
            out_l[i + j] = levels[j]
            out_y[i + j] = lums[j]
        if i < m:
            out_p[i + hi] = new_p[i]
            out_t[i + hi] = new_t[i]
            out_l[i + hi] = new_l[i]
            out_y[i + hi] = new_y[i]
    return out_p, out_t, out_l, out_y


def _intra_counts(rate: np.ndarray, log_b: np.ndarray, log_e: np.ndarray,
                  observed: np.ndarray | None, scale: np.ndarray | None, block_ns: int,
                  bound: float, dt_min_ns: int) -> np.ndarray:
    """Samples each pixel needs strictly inside a block, from its predicted rate.

    Parameters
    ----------
    rate : (P,) float64 ndarray, 1/s
        :func:`rate_map`'s prediction, flat.
    log_b, log_e : (P,) float64 ndarray
        Each pixel's log intensity at the block's start and end: the rate is at least their
        net change over the block.
    observed : (P,) float64 ndarray or None, 1/s
        The last block's observed rates (:attr:`PixelBlock.observed`): at least those too.
    scale : (P,) float64 ndarray or None
        :func:`sim.sampling.contrast_scale`'s, flat (None: all thresholds equal).
    block_ns, dt_min_ns : int, ns
        The block's length and the shortest interval.
    bound : float
        ``lam C``.

    Returns
    -------
    (P,) int64 ndarray
        ``ceil(r B / (MARGIN bound)) - 1`` clipped to ``[0, B / dt_min - 1]`` (0 where that is
        NaN or infinite).
    """
    most = max(block_ns // dt_min_ns, 1)
    return _intra_kernel(rate, log_b, log_e, np.empty(0) if observed is None else observed,
                         np.empty(0) if scale is None else scale, block_ns * 1e-9,
                         MARGIN * bound, float(most))


@numba.njit(cache=True, parallel=True)
def _intra_kernel(rate, log_b, log_e, observed, scale, seconds, per_sample,
                  most):  # pragma: no cover - compiled
    """:func:`_intra_counts`, per pixel; ``observed`` and ``scale`` empty: not given."""
    n_pixels = rate.shape[0]
    out = np.empty(n_pixels, np.int64)
    for p in numba.prange(n_pixels):
        r = _nan_max(rate[p], abs(log_e[p] - log_b[p]) / seconds)
        if observed.shape[0] > 0:
            r = _nan_max(r, observed[p])
        if scale.shape[0] > 0:
            r = r * scale[p]
        wanted = np.ceil(r * seconds / per_sample)
        if wanted != wanted or wanted == np.inf:
            wanted = 0.0
        out[p] = np.int64(min(max(wanted, 1.0), most) - 1.0)
    return out


def pixel_blocks(source: PixelSource, emulator: PixelEventEmulator, t0: float, t1: float,
                 contrast: float, log_eps: float, params: SamplingParams | None = None,
                 stats: PixelSamplingStats | None = None,
                 after: tuple[float, np.ndarray] | None = None,
                 edges: bool = False, device: str | None = None) -> Iterator[PixelBlock]:
    """Sample every pixel at its own times from t0 to t1 and emulate its events, block by block.

    Parameters
    ----------
    source : PixelSource
        Renders the sub-samples of every pixel, single pixels at their own times, and exact
        depth.
    emulator : PixelEventEmulator
        Started here at ``t0`` (unless ``after``); its state moves with the blocks.
    t0, t1 : float, seconds
    contrast : float or (H, W) array_like
        The contrast threshold C (log units): one for all pixels, or each pixel's own (the
        smaller of its ON and OFF thresholds); each pixel is then held to ``lam`` of its own
        (:func:`sim.sampling.contrast_scale`).
    log_eps : float
        L = log(Y + log_eps).
    params : SamplingParams, optional
        ``lam``, and ``min_rate`` (blocks of ``1 / min_rate`` seconds, a frame at each
        boundary), ``max_rate`` (no pixel interval is split below ``2 / max_rate``) and
        ``wavefront`` (blocks a pass, each taking the floor known at the pass's start; the
        reference path keeps that rule too, block by block).
    stats : PixelSamplingStats, optional
        Filled while iterating.
    after : (float, ndarray), optional
        Continue from the end of a pass this function yielded: its last block's ``t`` and
        ``floor``, with the emulator's state as it was after that block. The blocks that
        follow are exactly those an uninterrupted run gives (renders are deterministic in
        time).
    edges : bool
        Render the pixels that an edge crosses with ``source.fine_luminance`` (more
        sub-samples): at a block boundary, those :func:`geometric_edges` finds in
        ``source.geometry`` there; inside a block, those it finds at either end. A pixel's
        value at a boundary depends on that time only, so a pixel changes from one
        renderer to the other at a boundary where no edge crosses it, where both agree up to
        the texture filter's bound.
    device : {"llvm", "cuda"}, optional
        Predict (:func:`sim._drjit_sampling.device_prediction`), build, shade, check and refine
        each pass's samples (``params.wavefront`` blocks, one at a time with ``edges``, and no
        pass spanning more than ``source.pass_span_ns`` where the source has it) on this Dr.Jit
        device
        (:func:`sim._drjit_sampling.device_block`, shading through
        ``source.luminance_device``) instead of the reference path (numba and NumPy, shading
        through ``source.luminance``), the block-end frames :data:`FRAMES_AHEAD` at a time
        (``source.subsamples_many``, where the source has it) and the block starts' depth maps
        with them (``source.depth_many``, where it has it); the blocks that ``edges``
        renders with ``source.fine_luminance`` take the reference path. The same samples
        and events up to the levels' ``log`` (see :mod:`sim._drjit_sampling`).

    Yields
    ------
    PixelBlock
        One per block, in time order; the first block starts at t0 (or ``after``).
    """
    params = params or SamplingParams()
    stats = stats if stats is not None else PixelSamplingStats()
    camera = source.camera
    shape = (camera.height, camera.width)
    n_pixels = shape[0] * shape[1]
    contrast, scale = contrast_scale(contrast)
    if scale is not None:
        scale = scale.reshape(-1)
    bound = params.lam * contrast
    block_ns = max(int(round(1e9 / params.min_rate)), 1)
    dt_min_ns = max(int(round(1e9 / params.max_rate)), 1)
    t0_ns, t1_ns = int(round(t0 * 1e9)), int(round(t1 * 1e9))

    def seconds(ns):                       # nanoseconds -> seconds, never outside [t0, t1]
        return np.clip(np.asarray(ns) * 1e-9, t0, t1)

    def log_of(luminance: np.ndarray) -> np.ndarray:
        return np.log(np.asarray(luminance, dtype=np.float64) + log_eps)

    def boundary(sub: np.ndarray, t_ns: int,
                 counted: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """A block boundary's pixel values, with the pixels an edge crosses there (``edges``)
        rendered by ``source.fine_luminance``, and those pixels (flat; None without edges)."""
        lum = pixel_means(sub, shape)
        if not edges:
            return lum, None
        fine = refine_edges(lum, float(seconds(t_ns)), source.geometry, source.fine_luminance)
        stats.edge_samples += int(np.count_nonzero(fine)) if counted else 0
        return lum, fine

    if after is None:
        t_b = t0_ns
        sub_b = source.subsamples(t0)
        stats.full_renders += 1
    else:                     # the block end's sub-samples again (deterministic; not counted)
        t_b = int(round(after[0] * 1e9))
        sub_b = source.subsamples(float(seconds(t_b)))
    lum_b, fine_b = boundary(sub_b, t_b, counted=after is None)
    log_b = log_of(lum_b)
    if after is None:
        emulator.start(log_b, t0, lum_b)
    floor = None if after is None else np.asarray(after[1], dtype=np.float64)
    centres = camera.normalized_pixel_centres()
    ends = _block_ends(t_b, t1_ns, block_ns, dt_min_ns)
    ahead: dict[int, np.ndarray] = {}
    depths: dict[int, np.ndarray] = {}                 # block starts' depth maps, batched too
    batched = device is not None and hasattr(source, "subsamples_many")
    on: dict = {}                  # what the device path keeps on the device between passes
    done = 0
    for size in _passes(ends, t_b, 1 if edges else params.wavefront,
                        getattr(source, "pass_span_ns", None)):
        # The pass's blocks: their boundary frames, depth maps and twists, on the host.
        blocks = []
        for i in range(done, done + size):
            t_e = ends[i]
            if batched and t_e not in ahead:           # the next frames, several a launch
                chunk = ends[i:i + FRAMES_AHEAD]
                ahead = dict(zip(chunk, source.subsamples_many(seconds(np.array(chunk))),
                                 strict=True))
                if hasattr(source, "depth_many"):
                    starts = [t_b, *chunk[:-1]]
                    depths = dict(zip(starts, source.depth_many(seconds(np.array(starts))),
                                      strict=True))
            sub_e = ahead.pop(t_e) if batched else source.subsamples(float(seconds(t_e)))
            stats.full_renders += 1
            lum_e, fine_e = boundary(sub_e, t_e)
            depth = depths.pop(t_b) if t_b in depths else source.depth(float(seconds(t_b)))
            stats.depth_renders += 1
            blocks.append(_Block(t_b, t_e, sub_b, lum_b, log_b, fine_b, lum_e, log_of(lum_e),
                                 fine_e, depth,
                                 [source.camera_velocity(float(seconds(t_b))),
                                  source.camera_velocity(float(seconds(t_e)))]))
            t_b, sub_b, lum_b, log_b, fine_b = t_e, sub_e, lum_e, blocks[-1].log_e, fine_e
        done += size
        observed = []
        # Every pixel: its block-start sample, `inner` evenly spaced samples, its block-end one,
        # every block of the pass taking the same floor (the rates observed before the pass).
        if device is not None and all(b.fine_b is None or not (b.fine_b | b.fine_e).any()
                                      for b in blocks):
            for block, events, rates in _device_pass(source, emulator, blocks, device, on,
                                                     camera, centres, floor, scale, bound,
                                                     dt_min_ns, log_eps, float(t0), float(t1),
                                                     stats):
                observed.append(rates)
                stats.blocks += 1
                last = len(observed) == len(blocks)
                yield PixelBlock(float(seconds(block.t_e)), block.lum_e, block.log_e, events,
                                 rates, _floor(observed) if last else None)
            floor = _floor(observed)
            continue
        on.clear()                                     # nothing left on the device
        for block in blocks:
            shade = partial(_shade, source, stats,
                            None if block.fine_e is None else block.fine_b | block.fine_e)
            inner = _host_counts(camera, block.sub_b, block.depth, block.twists, block.length,
                                 log_eps, centres, block.log_b, block.log_e, floor, scale,
                                 bound, dt_min_ns)
            pix, times, levels, lums, mid_pix, mid_s = _block_samples(
                inner, block.t_b, block.length, block.log_b.reshape(-1),
                block.lum_b.reshape(-1), block.log_e.reshape(-1), block.lum_e.reshape(-1),
                float(t0), float(t1))
            if len(mid_pix):
                values = shade(mid_pix, mid_s)
                logs = np.empty(len(values))                # log(float64(value) + log_eps):
                _plus(values, log_eps, logs)                # NumPy's log, in place
                np.log(logs, out=logs)
                _fill_middle(inner, values, logs, levels, lums)     # (values: float32)
                stats.pixel_samples += len(mid_pix)
            pix, times, levels, lums = _refine(shade, pix, times, levels, lums, bound, scale,
                                               dt_min_ns, log_eps, stats, seconds)
            stats.intervals += len(pix) - n_pixels
            observed.append(_observed_rates(pix, times, levels, bound, scale))
            events = emulator.advance_samples(pix, times, levels, lums, block.t_e, block.lum_e)
            stats.blocks += 1
            last = len(observed) == len(blocks)
            yield PixelBlock(float(seconds(block.t_e)), block.lum_e, block.log_e, events,
                             observed[-1], _floor(observed) if last else None)
        floor = _floor(observed)


@dataclass
class _Block:
    """What a block's samples start from: its ends (ns), the frames there (the start's
    sub-samples, each end's pixel values, levels and pixels an edge crosses), the depth map at
    its start and the camera's twists at both ends."""

    t_b: int
    t_e: int
    sub_b: np.ndarray
    lum_b: np.ndarray
    log_b: np.ndarray
    fine_b: np.ndarray | None
    lum_e: np.ndarray
    log_e: np.ndarray
    fine_e: np.ndarray | None
    depth: np.ndarray
    twists: list

    @property
    def length(self) -> int:
        return self.t_e - self.t_b


def _floor(observed: list[np.ndarray]) -> np.ndarray:
    """The rates the next pass's prediction takes as its floor, from each block's observed
    rates in this pass: the last block's (see :attr:`SamplingParams.wavefront`)."""
    return observed[-1]


def _passes(ends: list[int], t_b: int, wavefront: int, span_ns: int | None) -> list[int]:
    """The number of blocks of each pass over the blocks ending at ``ends`` (from ``t_b``):
    ``wavefront`` each, fewer in the last, and fewer where a pass would span more than
    ``span_ns`` (the source's longest span of one launch; None: no limit), at least one."""
    sizes, i = [], 0
    while i < len(ends):
        size = 1
        start = t_b if i == 0 else ends[i - 1]
        while (size < wavefront and i + size < len(ends)
               and (span_ns is None or ends[i + size] - start <= span_ns)):
            size += 1
        sizes.append(size)
        i += size
    return sizes


def _device_pass(source: PixelSource, emulator: PixelEventEmulator, blocks: list[_Block],
                 device: str, on: dict, camera: Camera, centres: np.ndarray,
                 floor: np.ndarray | None, scale: np.ndarray | None, bound: float,
                 dt_min_ns: int, log_eps: float, t0: float, t1: float,
                 stats: PixelSamplingStats) -> Iterator[tuple[_Block, np.ndarray, np.ndarray]]:
    """One pass of the wavefront on the device: every block's counts predicted in one set of
    launches (:func:`_predicted_on_device`), their samples built, shaded, checked and refined
    together (:func:`sim._drjit_sampling.device_block`), then each block's samples emulated
    in time order. Yields each block, its events and its observed rates."""
    from sim._drjit_events import _device_array, aligned_empty
    from sim._drjit_sampling import _module, device_block

    m = _module(device)
    # Each pixel's luminance and level at its block's start and end, block after block, each
    # filled in place into an aligned array that Dr.Jit maps without a copy (on llvm).
    image = blocks[0].lum_b.size
    sent = {}
    for name in ("lum_b", "log_b", "lum_e", "log_e"):
        values = aligned_empty((len(blocks), image), np.float64)
        for k, block in enumerate(blocks):
            values[k] = getattr(block, name).reshape(-1)
        sent[name] = _device_array(m.Float64, values.reshape(-1))
    inner, total = _predicted_on_device(device, on, camera, blocks, sent["log_b"],
                                        sent["log_e"], log_eps, centres, floor, scale, bound,
                                        dt_min_ns)
    samples, counts, observed, _ = device_block(
        source.luminance_device, inner, [b.t_b for b in blocks], [b.length for b in blocks],
        sent["log_b"], sent["lum_b"], sent["log_e"], sent["lum_e"], t0, t1, bound,
        on.get("scale"), dt_min_ns, log_eps, stats, device, total=total)
    sizes = counts.reshape(len(blocks), image).sum(axis=1)
    offsets = np.cumsum(sizes) - sizes
    host = None if emulator.kernel == "drjit" else [a.numpy() for a in samples]
    for k, block in enumerate(blocks):
        lo, hi = int(offsets[k]), int(offsets[k] + sizes[k])
        own = slice(k * image, (k + 1) * image)
        if host is None:                               # the samples stay on the device
            part = samples if len(blocks) == 1 else [
                _slice(a, lo, hi, m) for a in samples]
            events = emulator.advance_device(counts[own], *part[1:], block.t_e, block.lum_e)
        else:
            pix, times, levels, lums = (a[lo:hi] for a in host)
            pix = pix.astype(np.int64)
            if k:                                      # block k's pixels are k P + p
                pix -= k * image
            events = emulator.advance_samples(pix, times, levels, lums, block.t_e, block.lum_e)
        yield block, events, observed[own]


def _slice(values, lo: int, hi: int, m):
    """``values[lo:hi]`` of a Dr.Jit array, on the device."""
    import drjit as dr

    return dr.gather(type(values), values, dr.arange(m.UInt32, hi - lo) + lo)


def _host_counts(camera: Camera, sub_b: np.ndarray, depth: np.ndarray, twists: list,
                 length: int, log_eps: float, centres: np.ndarray, log_b: np.ndarray,
                 log_e: np.ndarray, observed: np.ndarray | None, scale: np.ndarray | None,
                 bound: float, dt_min_ns: int) -> np.ndarray:
    """A block's :func:`_intra_counts` from its :func:`rate_map`, by numba on the host."""
    rate = rate_map(camera, sub_b, depth, twists, length * 1e-9, log_eps, centres)
    return _intra_counts(rate.reshape(-1), log_b.reshape(-1), log_e.reshape(-1), observed, scale,
                         length, bound, dt_min_ns)


def _predicted_on_device(device: str, on: dict, camera: Camera, blocks: list[_Block], log_b,
                         log_e, log_eps: float, centres: np.ndarray, floor: np.ndarray | None,
                         scale: np.ndarray | None, bound: float, dt_min_ns: int
                         ) -> tuple[object, int]:
    """The blocks' :func:`_intra_counts` (each block's floor ``floor``) on ``device``
    (:func:`sim._drjit_sampling.device_prediction`, every block in one set of launches: the
    same counts), left there block after block, with their sum. ``log_b`` and ``log_e`` are
    the blocks' levels on the device ((B P,) Float64); ``on`` keeps what the device keeps
    between passes (the pixel centres, the scale). Where a pixel has 8x8 sub-samples or
    more, the counts are numba's (:func:`_host_counts`), sent to the device."""
    from sim._drjit_events import _device_array, aligned_empty
    from sim._drjit_sampling import _module, device_centres, device_prediction

    m = _module(device)
    if "centres" not in on:
        on["centres"] = device_centres(centres, device)
    if scale is not None and "scale" not in on:
        on["scale"] = _device_array(m.Float64, scale)
    weight, logw = (aligned_empty((len(blocks), *blocks[0].sub_b.shape), np.float32)
                    for _ in range(2))
    for k, block in enumerate(blocks):                 # in place: one upload each, mapped
        n = _log_weights(camera, block.sub_b, log_eps, (weight[k], logw[k]))[2]
    if n >= 8:
        inner = np.concatenate([
            _host_counts(camera, b.sub_b, b.depth, b.twists, b.length, log_eps, centres,
                         b.log_b, b.log_e, floor, scale, bound, dt_min_ns) for b in blocks])
        return _device_array(m.UInt32, inner), int(inner.sum())
    flows = [_flow_args(camera, centres, b.depth, b.twists) for b in blocks]
    depth = aligned_empty((len(blocks), camera.height, camera.width), np.float64)
    for k, b in enumerate(blocks):
        depth[k] = b.depth
    inner, total, _ = device_prediction(
        weight, logw, (camera.height, camera.width), flows[0][0], flows[0][1], on["centres"],
        depth, np.stack([f[4] for f in flows]),
        [_dilation_of(f, b.length * 1e-9) for f, b in zip(flows, blocks, strict=True)],
        [b.length * 1e-9 for b in blocks], log_b, log_e,
        None if floor is None else _device_array(m.Float64, floor), on.get("scale"),
        MARGIN * bound, [max(b.length // dt_min_ns, 1) for b in blocks], device)
    return inner, total


def _dilation_of(flow: tuple, seconds: float) -> Callable[[float], int]:
    """``dilation(top)``: :func:`_dilation_radius` of a block from the largest ``du^2 + dv^2``
    over its pixels and twists (``top``, NaN where one is not finite), every pixel's ``hypot``
    by :func:`_flow_speeds` of ``flow`` (:func:`_flow_args`) where that cannot decide: what
    :func:`sim._drjit_sampling.device_prediction` asks its caller."""
    return lambda top: _dilation_radius(np.array([top]), seconds, partial(_flow_speeds, *flow))


def _block_ends(t_b: int, t1_ns: int, block_ns: int, dt_min_ns: int) -> list[int]:
    """The ends (ns) of the blocks from ``t_b`` to ``t1_ns``: every ``block_ns``, the last one
    stretched to ``t1_ns`` rather than leave a sliver shorter than ``dt_min_ns``."""
    ends = []
    while t_b < t1_ns:
        t_e = min(t_b + block_ns, t1_ns)
        if t1_ns - t_e < dt_min_ns:                 # no sliver of a block at the end
            t_e = t1_ns
        ends.append(t_e)
        t_b = t_e
    return ends


def _shade(source: PixelSource, stats: PixelSamplingStats, fine: np.ndarray | None,
           pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Luminance (N,) of pixels at their times (the sources' dtype, float32 for
    :class:`sim.shader.EventShader`), those marked in ``fine`` (flat bool; None: none) by
    ``source.fine_luminance``."""
    if fine is None or not (sel := fine[pixels]).any():
        return np.asarray(source.luminance(pixels, times))
    coarse = np.asarray(source.luminance(pixels[~sel], times[~sel]))
    fine_values = np.asarray(source.fine_luminance(pixels[sel], times[sel]))
    out = np.empty(len(pixels), dtype=np.result_type(coarse, fine_values))
    out[~sel], out[sel] = coarse, fine_values
    stats.edge_samples += int(np.count_nonzero(sel))
    return out


def geometric_edges(key: np.ndarray, normal: np.ndarray, shape: tuple[int, int],
                    cos_angle: float = EDGE_COS) -> np.ndarray:
    """Pixels that an edge of the geometry or of a shadow crosses: where two neighbouring
    sub-samples see different surfaces, different lights, or normals apart by more than
    ``arccos(cos_angle)``.

    Parameters
    ----------
    key : (H n, W n) uint32 ndarray
        What each sub-sample sees (:meth:`sim.shader.EventShader.geometry`): 0 for a miss,
        else its shape and which lights reach it.
    normal : (H n, W n, 3) float32 ndarray
        Its geometric normal (unit, world frame).
    shape : (int, int)
        ``(H, W)``, pixels.
    cos_angle : float
        Neighbours on one surface whose normals' dot product is below it are a crease.

    Returns
    -------
    (H, W) bool ndarray
        Pixels holding either sub-sample of such a pair (horizontal and vertical neighbours on
        the sub-sample grid, across pixel borders too): an edge that runs between two
        sub-samples marks both their pixels.

    Notes
    -----
    What no pair of sub-samples straddles is not seen: a corner or a feature narrower than
    the sub-sample spacing that clips a pixel between its sub-samples, and an edge between an
    image-border pixel's outermost sub-samples and the image's border (no neighbour there).
    """
    height, width = shape
    n = key.shape[0] // height
    big = np.zeros(key.shape, dtype=bool)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        a, b = tuple(a), tuple(b)
        differ = key[a] != key[b]
        differ |= (key[a] != 0) & (np.einsum("ijk,ijk->ij", normal[a], normal[b]) < cos_angle)
        big[a] |= differ
        big[b] |= differ
    return big.reshape(height, n, width, n).any(axis=(1, 3))


def refine_edges(frame: np.ndarray, t: float,
                 geometry: Callable[[float], tuple[np.ndarray, np.ndarray]],
                 fine_luminance: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Render again, in place, the pixels of a frame that an edge crosses at its time.

    Parameters
    ----------
    frame : (H, W) float32 ndarray
        Linear luminance at ``t``; its marked pixels are overwritten.
    t : float, seconds
        The frame's time.
    geometry : callable
        ``geometry(t)`` -> ``(key, normal)`` of every sub-sample
        (:meth:`sim.shader.EventShader.geometry`).
    fine_luminance : callable
        ``fine_luminance(pixels, times)`` -> (N,) luminance at more sub-samples.

    Returns
    -------
    (H W,) bool ndarray
        The pixels rendered again, flat (:func:`geometric_edges`).
    """
    marked = geometric_edges(*geometry(t), frame.shape).reshape(-1)
    index = np.flatnonzero(marked)
    if len(index):
        frame.reshape(-1)[index] = fine_luminance(index, np.full(len(index), float(t)))
    return marked


def _scaled(change: np.ndarray, pix: np.ndarray, scale: np.ndarray | None) -> np.ndarray:
    """Changes of pixels ``pix`` in units of the smallest threshold (``scale`` from
    :func:`sim.sampling.contrast_scale`, flat; None when all thresholds are equal)."""
    return change if scale is None else change * scale[pix]


def _observed_rates(pix: np.ndarray, times: np.ndarray, levels: np.ndarray, bound: float,
                    scale: np.ndarray | None) -> np.ndarray:
    """Each pixel's largest |dL/dt| over its intervals of the block that met the bound, 1/s
    (steps left at the maximum rate would ask for the maximum rate everywhere)."""
    return _max_met_slopes(pix, times, levels, bound,
                           np.empty(0) if scale is None else scale, int(pix[-1]) + 1)


def _refine(shade: Callable[[np.ndarray, np.ndarray], np.ndarray], pix: np.ndarray,
            times: np.ndarray, levels: np.ndarray, lums: np.ndarray, bound: float,
            scale: np.ndarray | None, dt_min_ns: int, log_eps: float,
            stats: PixelSamplingStats, seconds) -> tuple[np.ndarray, ...]:
    """Split every interval of a pixel that breaks the bound (``lam`` of its own threshold:
    ``bound`` on the change scaled by ``scale``) at its midpoint, level by level (one launch
    per level, only the intervals still breaking it; ``shade(pixels, times)`` renders the
    midpoints); then merge the midpoints into the samples, which stay sorted by pixel and
    time."""
    index = _breaking_intervals(pix, levels, bound, np.empty(0) if scale is None else scale)
    # The intervals still to split: pixel, start time and level, end time and level, and the
    # sample the original interval starts at (each of its midpoints goes in after it).
    p, ta, la, tb, lb, o = pix[index], times[index], levels[index], times[index + 1], \
        levels[index + 1], index
    found: list[tuple[np.ndarray, ...]] = []
    while len(p):
        splittable = tb - ta >= 2 * dt_min_ns
        stats.at_max_rate += int(np.count_nonzero(~splittable))
        p, ta, la, tb, lb, o = (a[splittable] for a in (p, ta, la, tb, lb, o))
        if not len(p):
            break
        mt = (ta + tb) // 2
        my = np.asarray(shade(p, seconds(mt)), np.float64)
        ml = np.log(my + log_eps)
        stats.pixel_samples += len(p)
        stats.midpoint_samples += len(p)
        share = np.abs(ml - la) / np.abs(lb - la)
        continuous = (share > SPLIT) & (share < 1 - SPLIT)
        stats.steps += int(np.count_nonzero(~continuous))
        found.append((p, mt, ml, my, o))
        first = _scaled(np.abs(ml - la), p, scale) > bound
        second = _scaled(np.abs(lb - ml), p, scale) > bound
        p, ta, la, tb, lb, o = (np.concatenate([x[first], y[second]]) for x, y in (
            (p, p), (ta, mt), (la, ml), (mt, tb), (ml, lb), (o, o)))
    if not found:
        return pix, times, levels, lums
    new_p, new_t, new_l, new_y, new_o = (np.concatenate(parts)
                                         for parts in zip(*found, strict=True))
    # Samples sorted by (pixel, time): a midpoint lies strictly inside its original interval,
    # so it goes in before sample new_o + 1, the midpoints of one interval in time order.
    order = np.lexsort((new_t, new_o))
    return _insert_samples(pix, times, levels, lums, new_o[order] + 1, new_p[order],
                           new_t[order], new_l[order], new_y[order])
