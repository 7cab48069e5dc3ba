"""Event-camera emulator: log-intensity samples in, DVS events out (ESIM's model, v2e's noise).

The input is the log of photocurrent plus dark current, computed as ``L = log(Y + log_eps)``
of the rendered luminance ``Y`` in cd/m^2 with the dark current expressed as a luminance
(:class:`EventParams`, :mod:`sim.radiometry`).

Each pixel keeps a reference log level ``ref``. Between two samples (t0, L0) and (t1, L1) the
log intensity is interpolated linearly in time, and every crossing of ``ref + C_on`` (ON) or
``ref - C_off`` (OFF) emits one event timestamped at its own crossing time, after which the
reference moves by that threshold. Several events per pixel per interval are normal; the
reference is carried from interval to interval. With the photoreceptor low-pass on, the level
that crosses is the filter's output, exact for the linear input (:func:`sim.noise.ramp_response`,
monotonic or turning once inside the interval), and each crossing time is solved on it to
:data:`CROSSING_TOLERANCE_NS` (:func:`interval_levels`, :func:`filtered_crossing_time`).

Choices (documented here because they change the events):

- Refractory period: an event that falls within ``refractory_period`` of the pixel's previous
  *emitted* event is dropped, but the reference still moves, as the comparator reset does in a
  real DVS pixel. So the refractory period never makes a pixel lag behind the signal; it only
  thins bursts.
- Thresholds: ``C_on``/``C_off`` per pixel, drawn once (normal with sigma ``threshold_sigma``
  around the nominal values, floored at 0.01) from the seed.
- Initial reference: the first sample's level (``ideal``), or that level minus a random phase
  in [0, C_on) per pixel (``initial_phase``), so that a scene start does not fire a synchronized
  burst.
- Noise (see :mod:`sim.noise`): photoreceptor low-pass filter on L with a cutoff that falls in
  the dark (solved exactly for the linear ramp between samples, with the logarithmic mean of
  the cutoffs at the interval's two ends), leak (each pixel's reference
  drifts down at its own fixed rate, linearly within an interval, giving ON events stamped
  where the drifting reference meets the level), background activity and hot pixels
  (Poisson events in [t0, t1) merged into the stream). Unlike v2e, a background event does not
  reset the pixel's reference.

Timestamps are int64 nanoseconds. Within an interval, events are sorted by time; ties keep pixel
order (row-major), so results are deterministic with any number of threads.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numba
import numpy as np
from numba.core import types
from numba.extending import overload

from sim.eventio import EVENT_DTYPE
from sim.noise import (
    CAUSE_HOT_PIXEL,
    CAUSE_LEAK,
    CAUSE_SHOT,
    CAUSE_SIGNAL,
    THRESHOLD_FLOOR,
    NoiseParams,
    background_events,
    cutoff_frequency,
    drifted_inputs,
    hot_pixel_events,
    hot_pixel_mask,
    leak_drift,
    leak_rate_map,
    lowpass_exponent,
    merge_labelled_events,
    noise_preset,
    ramp_crossing,
    ramp_response,
    ramp_turn,
    threshold_map,
)
from sim.profile import stage as profile_stage
from sim.radiometry import DVS_DARK_LUMINANCE, DVS_RESPONSIVITY, photocurrent
from sim.validation import integer, positive

__all__ = [
    "CROSSING_TOLERANCE_NS",
    "EVENT_DTYPE",
    "EventEmulator",
    "EventParams",
    "emulate_events",
    "emulate_events_reference",
    "log_intensity",
]


KERNELS = ("auto", "numba", "drjit")
"""The values of an emulator's ``kernel`` (:class:`EventEmulator`)."""

_STATE_ARRAYS = ("ref", "level", "raw", "cutoff", "last_t")
"""The arrays of :meth:`EventEmulator.get_state`."""


@dataclass(frozen=True)
class EventParams:
    """Parameters of the event camera.

    Attributes
    ----------
    contrast_on, contrast_off : float
        Nominal contrast thresholds C+ and C- in log-intensity units (default 0.2).
    log_eps : float, cd/m^2
        The pixel's dark current expressed as the scene luminance whose photocurrent equals it,
        ``I_dark / responsivity``: L = log(Y + log_eps) for luminance Y in cd/m^2, which is
        the log of photocurrent plus dark current, ``log(R Y + I_dark)``, less the constant
        ``log R`` (no event moves; see :mod:`sim.radiometry`). Default
        :data:`~sim.radiometry.DVS_DARK_LUMINANCE` (0.43 cd/m^2, 4 fA at the DAVIS240C's
        assumed responsivity); the same formula as before luminance had units, when it was
        1e-3 of an arbitrary scale.
    responsivity : float, A per cd/m^2
        Photocurrent per unit of scene luminance (:func:`sim.radiometry.responsivity`), default
        the DAVIS240C DVS pixel's :data:`~sim.radiometry.DVS_RESPONSIVITY`. It turns
        ``log_eps`` into a dark current (:attr:`dark_current`) and luminance into photocurrent
        (:meth:`photocurrent`); the events do not depend on it.
    noise : NoiseParams
        Sensor non-idealities; default the ``ideal`` preset (none, thresholds exact, each
        reference starting at the pixel's first level).
    seed : int
        Seed of every random draw of the sensor (thresholds, phases, noise).
    """

    contrast_on: float = 0.2
    contrast_off: float = 0.2
    log_eps: float = DVS_DARK_LUMINANCE
    noise: NoiseParams = field(default_factory=lambda: noise_preset("ideal"))
    seed: int = 0
    responsivity: float = DVS_RESPONSIVITY

    def __post_init__(self) -> None:
        for name in ("contrast_on", "contrast_off", "log_eps", "responsivity"):
            positive(f"EventParams.{name}", getattr(self, name))
        if not isinstance(self.noise, NoiseParams):
            raise ValueError(f"EventParams.noise must be a NoiseParams, got {self.noise!r}")
        integer("EventParams.seed", self.seed, 0)

    @property
    def dark_current(self) -> float:
        """float, amperes: the dark current ``log_eps * responsivity``."""
        return self.log_eps * self.responsivity

    def photocurrent(self, luminance: np.ndarray) -> np.ndarray:
        """Photocurrent (A, float64, the input's shape) of pixels seeing ``luminance`` (cd/m^2),
        dark current not included: ``responsivity * luminance``."""
        return photocurrent(luminance, self.responsivity)

    @classmethod
    def preset(cls, name: str, contrast: float = 0.2, seed: int = 0) -> EventParams:
        """Parameters with the noise preset ``name`` (``ideal`` or ``realistic``)."""
        return cls(contrast_on=contrast, contrast_off=contrast, noise=noise_preset(name),
                   seed=seed)


def log_intensity(luminance: np.ndarray, eps: float = DVS_DARK_LUMINANCE) -> np.ndarray:
    """L = log(Y + eps) of linear luminance Y (cd/m^2), float64 (..., H, W); ``eps`` is the
    dark current as a luminance (:attr:`EventParams.log_eps`)."""
    return np.log(np.asarray(luminance, dtype=np.float64) + eps)


# ------------------------------------------------------------------------------------------------
# Compiled kernels. With the low-pass or the leak on, the interval is processed in two parallel
# passes over rows: count the events of every row, then (after a prefix sum gives each row its
# slot) write them. Without either, one fused pass over chunks of rows (_linear_chunks). Either
# way the events are then put in time order by a bucket sort (_time_sorted).
# ------------------------------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def threshold_crossings(level, ref, c_on, c_off):  # pragma: no cover - compiled
    """Crossings of ``ref + i C_on`` (ON) or ``ref - i C_off`` (OFF) on the way to ``level``:
    ``(count, signed step, polarity)``, ``(0, 0.0, 0)`` when none. Shared by every emulator
    kernel (frames here, per-pixel samples in :mod:`sim.pixel_sampling`)."""
    if level >= ref + c_on:
        return int(math.floor((level - ref) / c_on)), c_on, 1
    if level <= ref - c_off:
        return int(math.floor((ref - level) / c_off)), -c_off, -1
    return 0, 0.0, 0


@numba.njit(cache=True, inline="always")
def crossing_time(level, a, slope, t0, dt):  # pragma: no cover - compiled
    """Time (int64 ns) at which ``L``, linear from ``a`` at ``t0`` with change ``slope``
    over ``dt`` ns, reaches ``level``; clamped to ``[t0, t0 + dt]``."""
    frac = (level - a) / slope if slope != 0.0 else 1.0
    if frac < 0.0:
        frac = 0.0
    elif frac > 1.0:
        frac = 1.0
    return t0 + np.int64(round(frac * dt))


CROSSING_TOLERANCE_NS = 0.01
"""Largest error (ns) of a crossing time solved on the filter's output, before the timestamp is
rounded to the nanosecond (:func:`filtered_crossing_time`)."""


@numba.njit(cache=True, inline="always")
def interval_levels(y0, a, b, x):  # pragma: no cover - compiled
    """The pixel's (filtered) level over an interval, as two monotonic pieces.

    ``y0`` is the filter's output at the start, ``a`` and ``b`` its input (the unfiltered
    samples) at the two ends, ``x`` the interval in time constants (``inf``: no filter, the
    level is the input). Returns ``(f_turn, y_turn, y1)``: the fraction of the interval where
    the level turns and its value there, and the level at the end; ``f_turn = 1.0`` and
    ``y_turn = y1`` when it is monotonic. Without the filter ``y1`` is ``b`` itself.
    """
    if x == math.inf:
        return 1.0, b, b
    y1 = ramp_response(1.0, y0, a, b, x)
    f_turn = ramp_turn(y0, a, b, x)
    if f_turn >= 1.0:
        return 1.0, y1, y1
    return f_turn, ramp_response(f_turn, y0, a, b, x), y1


@numba.njit(cache=True, inline="always")
def filtered_crossing_time(level, y0, a, b, x, f_lo, y_lo, f_hi, y_hi, t0,
                           dt):  # pragma: no cover - compiled
    """Time (int64 ns) at which the level of :func:`interval_levels` reaches ``level`` on its
    monotonic piece from fraction ``f_lo`` (level ``y_lo``) to ``f_hi`` (``y_hi``) of the
    interval ``[t0, t0 + dt]``; clamped to the piece. Without the filter (``x = inf``) it is
    :func:`crossing_time` on the line from ``y0`` to ``y_hi``, bit for bit."""
    if x == math.inf:
        return crossing_time(level, y0, y_hi - y0, t0, dt)
    f = ramp_crossing(level, y0, a, b, x, f_lo, y_lo, f_hi, y_hi, CROSSING_TOLERANCE_NS / dt)
    return t0 + np.int64(round(f * dt))


@numba.njit(cache=True, inline="always")
def interval_count(r, c_on, c_off, y0, a, b, x):  # pragma: no cover - compiled
    """Number of threshold crossings of the level of :func:`interval_levels` from reference
    ``r``, over both its pieces, and the level at the end: ``(count, y1)``."""
    f_turn, y_turn, y1 = interval_levels(y0, a, b, x)
    n, c, _ = threshold_crossings(y_turn, r, c_on, c_off)
    if f_turn < 1.0:
        n += threshold_crossings(y1, r + n * c, c_on, c_off)[0]
    return n, y1


@numba.njit(cache=True, parallel=True)
def _count_rows(L0, raw0, raw1, x, ref, c_on, c_off, drift, L1):  # pragma: no cover - compiled
    """Events per row; -1 for a row holding a non-finite level. Writes each pixel's level at
    the end of the interval (filtered when ``x`` is finite) into ``L1``. ``drift`` is each
    pixel's leak drift over the interval ((H, W), >= 0; empty without leak): the crossings are
    those of the level against the reference as it drifts (:func:`sim.noise.drifted_inputs`)."""
    height, width = raw1.shape
    counts = np.zeros(height, dtype=np.int64)
    leaky = drift.size > 0
    for y in numba.prange(height):
        n = 0
        for i in range(width):
            v = raw1[y, i]
            if not math.isfinite(v):
                n = -1
                break
            if leaky:
                a, b = drifted_inputs(raw0[y, i], v, x[y, i], drift[y, i])
                m, _ = interval_count(ref[y, i], c_on[y, i], c_off[y, i], L0[y, i], a, b,
                                      x[y, i])
                L1[y, i] = interval_levels(L0[y, i], raw0[y, i], v, x[y, i])[2]
            else:
                m, L1[y, i] = interval_count(ref[y, i], c_on[y, i], c_off[y, i], L0[y, i],
                                             raw0[y, i], v, x[y, i])
            n += m
        counts[y] = n
    return counts


@numba.njit(cache=True, parallel=True)
def _write_rows(L0, raw0, raw1, x, ref, c_on, c_off, last_t, offsets, t0, dt, refractory,
                drift, out_t, out_x, out_y, out_p, out_cause,
                keep):  # pragma: no cover - compiled
    """Write the crossings :func:`_count_rows` counted, each with its cause, and leave each
    reference where the interval ends it (its leak ``drift`` included). The crossings are
    those of the level plus the drift so far against the reference the interval started with
    (:func:`sim.noise.drifted_inputs`); on each monotonic piece of that sum, a crossing beyond
    the count of the level alone (the leak-free count) is :data:`~sim.noise.CAUSE_LEAK`, the
    others :data:`~sim.noise.CAUSE_SIGNAL`."""
    height, width = raw1.shape
    leaky = drift.size > 0
    for y in numba.prange(height):
        k = offsets[y]
        for i in range(width):
            r = ref[y, i]
            rf = r
            d = drift[y, i] if leaky else 0.0
            y0, a, b, xi = L0[y, i], raw0[y, i], raw1[y, i], x[y, i]
            if leaky:
                a, b = drifted_inputs(a, b, xi, d)
            f_turn, y_turn, y1 = interval_levels(y0, a, b, xi)
            last = last_t[y, i]
            # The level's monotonic pieces: up to the turn, then (if it turns) to the end.
            f_lo, y_lo, f_hi, y_hi = 0.0, y0, f_turn, y_turn
            while True:
                n, c, sign = threshold_crossings(y_hi, r, c_on[y, i], c_off[y, i])
                nf, cf, sf = n, c, sign
                if leaky:
                    nf, cf, sf = threshold_crossings(y_hi - d * f_hi, rf, c_on[y, i],
                                                     c_off[y, i])
                for j in range(1, n + 1):
                    t = filtered_crossing_time(r + j * c, y0, a, b, xi, f_lo, y_lo, f_hi, y_hi,
                                               t0, dt)
                    out_t[k] = t
                    out_x[k] = i
                    out_y[k] = y
                    out_p[k] = sign
                    out_cause[k] = CAUSE_LEAK if sf != sign or j > nf else CAUSE_SIGNAL
                    if refractory > 0 and t - last < refractory:
                        keep[k] = False
                    else:
                        keep[k] = True
                        last = t
                    k += 1
                r += n * c
                rf += nf * cf
                if f_hi >= 1.0:
                    break
                f_lo, y_lo, f_hi, y_hi = f_hi, y_hi, 1.0, y1
            last_t[y, i] = last
            ref[y, i] = r - d if leaky else r


# The common case, no low-pass and no leak: the level is the line from the last sample's level
# to the new one, and every crossing is a signal's. :func:`_count_rows` and :func:`_write_rows`
# reduced to it, step for step (the same arithmetic, so the same events), without the arrays
# and branches the filter and the leak need, and fused: each chunk of rows counts a row (then
# in cache) and writes it where its share of the output, sized from the last interval's events,
# has room (:meth:`EventEmulator._linear_crossings`).


@numba.njit(cache=True)
def _all_finite(values):  # pragma: no cover - compiled
    """Whether every element of the C-contiguous float64 ``values`` is finite: no element
    has the exponent bits all set (infinities and NaNs), tested on the integers so that the
    loop vectorises."""
    bits = values.reshape(-1).view(np.uint64)
    exponent = np.uint64(0x7FF0000000000000)
    bad = np.uint64(0)
    for k in range(bits.size):
        bad |= np.uint64((bits[k] & exponent) == exponent)
    return bad == 0


@numba.njit(cache=True)
def _count_rows_linear(L1, ref, c_on, c_off):  # pragma: no cover - compiled
    """:func:`_count_rows` without filter or leak, on finite levels: events per row of the
    interval ending at ``L1`` (H, W); thresholds as in :func:`_linear_chunks`."""
    height, width = L1.shape
    counts = np.zeros(height, dtype=np.int64)
    for y in range(height):
        n = 0
        for i in range(width):
            n += threshold_crossings(L1[y, i], ref[y, i], _at(c_on, y, i), _at(c_off, y, i))[0]
        counts[y] = n
    return counts


_CHUNKS = 16
"""Chunks of rows of :func:`_linear_chunks` (fewer on a sensor of fewer rows)."""


def _at(values, y, i):
    """A threshold at pixel ``(y, i)`` in a compiled kernel: ``values[y, i]`` of a map, or
    ``values`` itself when it is one number for every pixel (a uniform sensor's), which keeps
    the maps out of the kernel's memory traffic."""
    return values if np.ndim(values) == 0 else values[y, i]


@overload(_at, inline="always")
def _at_compiled(values, y, i):
    if isinstance(values, types.Float):
        return lambda values, y, i: values
    return lambda values, y, i: values[y, i]


@numba.njit(cache=True, parallel=True)
def _linear_chunks(L0, L1, ref, c_on, c_off, last_t, t0, dt, refractory, lo, hi, start, end,
                   out_t, out_x, out_y, out_p, keep, filled, reached):  # pragma: no cover
    """:func:`_write_rows` without filter or leak, on finite levels: the crossings of the line
    from ``L0`` to ``L1`` (:func:`crossing_time`), chunk by chunk of rows.

    Chunk ``c`` holds rows ``lo[c]`` to ``hi[c]`` (excluded) and writes its events, in pixel
    order, from ``start[c]`` up to ``end[c]`` of the outputs; a row is counted first (each
    pixel's count kept) and written only if it fits, and the chunk stops at the first row
    that does not. It leaves the next free slot in ``filled[c]`` and the first row not
    written in ``reached[c]`` (``hi[c]`` when done). ``c_on`` and ``c_off`` are (H, W) maps
    or one number each (:func:`_at`). ``keep`` (written only when ``refractory`` > 0) is
    False for an event the refractory period drops. Moves the written rows' references and
    last kept times; the rows not written are untouched.
    """
    width = L1.shape[1]
    for c in numba.prange(len(lo)):
        counts = np.empty(width, np.int64)
        k = start[c]
        y = lo[c]
        while y < hi[c]:
            n = 0
            for i in range(width):
                m = threshold_crossings(L1[y, i], ref[y, i], _at(c_on, y, i),
                                        _at(c_off, y, i))[0]
                counts[i] = m
                n += m
            if k + n > end[c]:
                break
            for i in range(width if n > 0 else 0):
                if counts[i] == 0:
                    continue
                r = ref[y, i]
                b = L1[y, i]
                m, step, sign = threshold_crossings(b, r, _at(c_on, y, i), _at(c_off, y, i))
                a = L0[y, i]
                last = last_t[y, i]
                for j in range(1, m + 1):
                    t = crossing_time(r + j * step, a, b - a, t0, dt)
                    out_t[k] = t
                    out_x[k] = i
                    out_y[k] = y
                    out_p[k] = sign
                    if refractory > 0:
                        if t - last < refractory:
                            keep[k] = False
                        else:
                            keep[k] = True
                            last = t
                    else:
                        last = t
                    k += 1
                last_t[y, i] = last
                ref[y, i] = r + m * step
            y += 1
        filled[c] = k
        reached[c] = y


@numba.njit(cache=True)
def _kept(keep, first, stop):  # pragma: no cover - compiled
    """Number of events from ``first[s]`` to ``stop[s]`` of each segment ``s`` that ``keep``
    keeps (all of them when it is empty)."""
    kept = 0
    for s in range(len(first)):
        if keep.size == 0:
            kept += stop[s] - first[s]
        else:
            for k in range(first[s], stop[s]):
                kept += keep[k]
    return kept


_SMALL_BUCKET = 32
"""Largest bucket of :func:`_time_sorted` left to the insertion sort; a larger one is
merge-sorted first."""


@numba.njit(cache=True)
def _time_sorted(t, xs, ys, p, cause, keep, first, stop, t0, dt, width, pixels, out,
                 out_cause):  # pragma: no cover - compiled
    """Write the kept events into ``out`` (EVENT_DTYPE) in time order, ties in pixel order,
    with their causes into ``out_cause`` (unless ``cause`` is empty).

    The input is the events from ``first[s]`` to ``stop[s]`` of each segment ``s``, with times
    in ``[t0, t0 + dt]``; ``keep`` is empty when every event is kept; ``out`` has room for the
    kept events exactly (:func:`_kept`); ``width`` and ``pixels`` are the sensor's. A bucket
    sort on the key ``(t - t0) * pixels + pixel`` (unique but for one pixel's events in the
    same nanosecond, which keep their input order): as many buckets as events over the
    interval's times, then a stable insertion sort, which moves events within their bucket
    only (a bucket of more than :data:`_SMALL_BUCKET` events is merge-sorted first).
    """
    kept = len(out)
    if kept == 0:
        return
    scale = kept / (dt + 1.0)
    bound = np.zeros(kept + 1, dtype=np.int64)       # bucket b: bound[b] to bound[b + 1]
    bucket = np.empty(len(t), dtype=np.int32)
    for s in range(len(first)):
        for k in range(first[s], stop[s]):
            if keep.size == 0 or keep[k]:
                b = min(int((t[k] - t0) * scale), kept - 1)
                bucket[k] = b
                bound[b + 1] += 1
    for b in range(kept):
        bound[b + 1] += bound[b]
    fill = bound[:-1].copy()
    key = np.empty(kept, dtype=np.int64)
    source = np.empty(kept, dtype=np.int64)
    for s in range(len(first)):
        for k in range(first[s], stop[s]):
            if keep.size == 0 or keep[k]:
                m = fill[bucket[k]]
                fill[bucket[k]] = m + 1
                key[m] = (t[k] - t0) * pixels + np.int64(ys[k]) * width + xs[k]
                source[m] = k
    for b in range(kept):
        if bound[b + 1] - bound[b] > _SMALL_BUCKET:
            lo, hi = bound[b], bound[b + 1]
            order = np.argsort(key[lo:hi], kind="mergesort")
            key[lo:hi] = key[lo:hi][order]
            source[lo:hi] = source[lo:hi][order]
    for m in range(1, kept):
        km = key[m]
        if key[m - 1] <= km:
            continue
        sm = source[m]
        q = m
        while q > 0 and key[q - 1] > km:             # never past the bucket's start
            key[q] = key[q - 1]
            source[q] = source[q - 1]
            q -= 1
        key[q] = km
        source[q] = sm
    for m in range(kept):
        k = source[m]
        out[m].t = t[k]
        out[m].x = xs[k]
        out[m].y = ys[k]
        out[m].p = p[k]
        if cause.size > 0:
            out_cause[m] = cause[k]


def _sensor_maps(shape: tuple[int, int], params: EventParams, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The sensor's fixed maps, drawn from ``rng`` in this order: ON and OFF thresholds
    (:func:`sim.noise.threshold_map`), hot pixels (:func:`sim.noise.hot_pixel_mask`) and leak
    rates (:func:`sim.noise.leak_rate_map`), each (H, W)."""
    noise = params.noise
    c_on, c_off = threshold_map(shape, params.contrast_on, params.contrast_off,
                                noise.threshold_sigma, rng)
    return (c_on, c_off, hot_pixel_mask(shape, noise.hot_pixel_fraction, rng),
            leak_rate_map(shape, noise, rng))


def _uniform_sensor(shape: tuple[int, int], params: EventParams) -> bool:
    """Whether :func:`_sensor_maps` gives maps that do not depend on its draws: exact
    thresholds (each ``max(C, floor)``), no hot pixel and no leak (rates all 0)."""
    noise = params.noise
    return (noise.threshold_sigma == 0 and noise.leak_rate == 0
            and round(noise.hot_pixel_fraction * shape[0] * shape[1]) == 0)


def clocked(method):
    """Add the wall time of each call of an emulator's ``method`` to its ``seconds`` (and, in a
    profiled run, its Dr.Jit kernels to the stage ``profile_stage``: :func:`sim.profile.stage`)."""

    @functools.wraps(method)
    def timed(self, *args, **kwargs):
        tick = time.perf_counter()
        try:
            with profile_stage(self.profile_stage):
                return method(self, *args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - tick

    return timed


class EventEmulator:
    """Streaming event emulator: feed log-intensity samples in time order, get events.

    Parameters
    ----------
    shape : (int, int)
        Sensor height and width.
    params : EventParams, optional
        Default: the ``ideal`` preset, C = 0.2.
    kernel : {"auto", "numba", "drjit"}
        Where the threshold crossings are solved: ``numba``, the compiled kernels here (this
        class: threads over rows; :class:`~sim.pixel_sampling.PixelEventEmulator`: one
        thread); ``drjit``, :func:`sim._drjit_events.pixel_events` on the device of the
        active Mitsuba variant (every core with ``llvm_*``, the GPU with ``cuda_*``);
        ``auto`` (default), ``drjit`` under a ``cuda_*`` variant (the renders' device) and
        ``numba`` otherwise, the faster of the two on the 2-core development machine
        (``benchmarks/bench_emulator.py``). Both give identical events without the
        photoreceptor low-pass; with it, within the bound :mod:`sim._drjit_events` states.

    Examples
    --------
    >>> emulator = EventEmulator((180, 240))                          # doctest: +SKIP
    >>> emulator.start(L0, 0.0)                                       # doctest: +SKIP
    >>> events = emulator.advance(L1, 0.001)                          # doctest: +SKIP

    Attributes
    ----------
    seconds : float
        Wall time spent in :meth:`start` and :meth:`advance` (and
        :meth:`~sim.pixel_sampling.PixelEventEmulator.advance_samples`) so far; not
        :meth:`warm_up`'s.
    kernel : str
        ``numba`` or ``drjit``, as resolved.
    last_causes : (N,) uint8 ndarray
        The cause of each event the last :meth:`advance` (or ``advance_samples``) returned,
        in the same order: :data:`sim.noise.CAUSE_SIGNAL`, ``CAUSE_SHOT``, ``CAUSE_LEAK`` or
        ``CAUSE_HOT_PIXEL`` (the rule: :mod:`sim.noise`'s docstring). Empty before.
    """

    def __init__(self, shape: tuple[int, int], params: EventParams | None = None,
                 kernel: str = "auto"):
        if kernel not in KERNELS:
            raise ValueError(f"{type(self).__name__}.kernel must be one of {KERNELS}, got "
                             f"{kernel!r}")
        self._device = "llvm"
        if kernel != "numba":           # (Dr.Jit loads here, not with the package)
            from sim._drjit_events import active_device

            self._device = active_device()
        if kernel == "auto":
            kernel = "drjit" if self._device == "cuda" else "numba"
        self.kernel = kernel
        self.params = params or EventParams()
        self.shape = (int(shape[0]), int(shape[1]))
        self._generator = np.random.default_rng(self.params.seed)
        self._draws_pending = _uniform_sensor(self.shape, self.params)
        if self._draws_pending:
            self.c_on, self.c_off = (np.full(self.shape, max(c, THRESHOLD_FLOOR)) for c in
                                     (self.params.contrast_on, self.params.contrast_off))
            self.hot_mask = np.zeros(self.shape, dtype=bool)
            self.leak_rates = np.zeros(self.shape)
        else:
            self.c_on, self.c_off, self.hot_mask, self.leak_rates = _sensor_maps(
                self.shape, self.params, self._generator)
        self.ref: np.ndarray | None = None
        self._L: np.ndarray | None = None
        self._raw: np.ndarray | None = None
        self._cutoff: np.ndarray | None = None
        self._t: int | None = None
        self._last_t = np.full(self.shape, np.iinfo(np.int64).min // 2, dtype=np.int64)
        # Exact thresholds are one number each: the kernels take them so (_at).
        self._thresholds = ((max(self.params.contrast_on, THRESHOLD_FLOOR),
                             max(self.params.contrast_off, THRESHOLD_FLOOR))
                            if self.params.noise.threshold_sigma == 0 else (self.c_on, self.c_off))
        bounds = np.linspace(0, self.shape[0], min(self.shape[0], _CHUNKS) + 1).astype(np.int64)
        self._chunk_rows = (bounds[:-1], bounds[1:])      # of _linear_crossings
        self._chunk_events: np.ndarray | None = None      # each chunk's events last interval
        self._work: tuple[np.ndarray, ...] | None = None  # its buffers
        self._allocate = None           # where the sorted crossings go (_EventStack.reserve)
        self.seconds = 0.0
        self.profile_stage = "emulate"        # timings_s's stage of its kernels (sim.profile)
        self.last_causes = np.zeros(0, np.uint8)

    @property
    def _rng(self) -> np.random.Generator:
        """The sensor's generator, past the draws of its maps (:func:`_sensor_maps`): when
        they were not needed (:func:`_uniform_sensor`), it makes them on first use, so that
        every later draw is the one it would have been."""
        if self._draws_pending:
            self._draws_pending = False
            _sensor_maps(self.shape, self.params, self._generator)
        return self._generator

    def warm_up(self) -> float:
        """Compile the emulator's kernels (or load them from numba's cache) and start their
        threads, on a throwaway 1x2 sensor with these parameters, so that the first interval
        does not pay for it; this emulator's state is untouched. Returns the seconds it took."""
        tick = time.perf_counter()
        spare = type(self)((1, 2), self.params, self.kernel)
        spare.profile_stage = "emulate_compile"
        spare.start(np.zeros((1, 2)), 0.0)
        spare.advance(np.array([[0.0, 1.0]]), 1e-3)
        return time.perf_counter() - tick

    @property
    def time_ns(self) -> int | None:
        """Time of the last sample, ns (None before :meth:`start`)."""
        return self._t

    @property
    def level(self) -> np.ndarray | None:
        """The (filtered) log intensity of the last sample, (H, W) float64."""
        return self._L

    def get_state(self) -> dict:
        """Everything the emulator carries from one sample to the next, as copies.

        Returns
        -------
        dict
            ``time_ns`` (int or None before :meth:`start`), ``rng`` (the generator's
            ``bit_generator.state``, a JSON-able dict) and, after :meth:`start`, the (H, W)
            arrays ``ref`` (float64 references), ``level`` (float64 filtered log intensity of
            the last sample), ``raw`` (float64 unfiltered log intensity of the last sample),
            ``cutoff`` (float64 low-pass cutoff of each pixel at the last sample, Hz; 0 without
            the filter) and ``last_t`` (int64 ns of each pixel's last event). The threshold,
            hot-pixel and leak maps are not included: they follow from ``params`` alone.
        """
        state: dict = {"time_ns": self._t, "rng": self._rng.bit_generator.state}
        if self.ref is not None:
            state.update(ref=self.ref.copy(), level=np.array(self._L, dtype=np.float64),
                         raw=np.array(self._raw, dtype=np.float64),
                         cutoff=self._cutoff.copy(), last_t=self._last_t.copy())
        return state

    def set_state(self, state: dict) -> None:
        """Continue from a state returned by :meth:`get_state` of an emulator with the same
        shape and parameters; the events that follow are exactly those it would have given.

        Raises
        ------
        ValueError
            A key is missing, or an array does not have the sensor's shape.
        """
        missing = [key for key in ("time_ns", "rng") if key not in state]
        if state.get("time_ns") is not None:
            missing += [key for key in _STATE_ARRAYS if key not in state]
        if missing:
            raise ValueError(f"emulator state lacks {', '.join(missing)}; expected a dict from "
                             "EventEmulator.get_state()")
        if state["time_ns"] is None:
            arrays = {}
        else:
            arrays = {key: np.array(state[key], dtype=np.int64 if key == "last_t" else np.float64)
                      for key in _STATE_ARRAYS}
        for key, value in arrays.items():
            if value.shape != self.shape:
                raise ValueError(f"emulator state: {key} has shape {value.shape}; expected the "
                                 f"sensor's {self.shape}")
        self._draws_pending = False
        self._generator.bit_generator.state = state["rng"]
        self._t = None if state["time_ns"] is None else int(state["time_ns"])
        self.ref = arrays.get("ref")
        self._L, self._raw = arrays.get("level"), arrays.get("raw")
        self._cutoff = arrays.get("cutoff")
        if "last_t" in arrays:
            self._last_t = arrays["last_t"]

    def _check(self, L: np.ndarray, name: str, finite: bool = True) -> np.ndarray:
        """``L`` as the emulator's own float64 array (always a copy: the emulator keeps the
        last sample as its state, so a caller may reuse its frame buffer), shape and
        finiteness checked."""
        L = np.array(L, dtype=np.float64, order="C")
        if L.shape != self.shape:
            raise ValueError(f"{name} must have shape {self.shape}, got {L.shape}")
        if finite and not np.all(np.isfinite(L)):
            raise ValueError(f"{name} has non-finite values; expected log intensities")
        return L

    @clocked
    def start(self, L0: np.ndarray, t0: float, luminance: np.ndarray | None = None) -> None:
        """Set the first sample (t0 in seconds) and the references; emits nothing.

        ``luminance`` (H, W), linear luminance at t0, sets the low-pass cutoff there (default
        exp(L0), as in :meth:`advance`).
        """
        L0 = self._check(L0, "L0")
        self.ref = L0.copy()
        if self.params.noise.initial_phase:
            self.ref -= self._rng.random(self.shape) * self.c_on
        self._L = self._raw = L0
        self._cutoff = self._cutoff_at(L0, luminance)
        self._t = int(round(t0 * 1e9))

    def _cutoff_at(self, L: np.ndarray, luminance: np.ndarray | None) -> np.ndarray:
        """Each pixel's low-pass cutoff (Hz, 0 without the filter) at a sample."""
        if self.params.noise.cutoff_hz == 0:
            return np.zeros(self.shape)
        return cutoff_frequency(np.exp(L) if luminance is None else luminance, self.params.noise)

    @clocked
    def advance(self, L1: np.ndarray, t1: float, luminance: np.ndarray | None = None
                ) -> np.ndarray:
        """Process the interval from the previous sample to (t1, L1).

        Parameters
        ----------
        L1 : (H, W) array_like, log intensity at t1
        t1 : float, seconds, after the previous sample
        luminance : (H, W) array_like, optional
            Linear luminance at t1, for the intensity-dependent noise (default exp(L1)).

        Returns
        -------
        (N,) EVENT_DTYPE ndarray
            Events of the interval, sorted by time: threshold crossings with previous t < t <=
            t1, noise events with previous t <= t < t1.
        """
        if self.ref is None:
            raise ValueError("call start() before advance()")
        L1 = self._check(L1, "L1", finite=False)       # the counting kernel checks finiteness
        t1_ns = int(round(t1 * 1e9))
        if t1_ns <= self._t:
            raise ValueError(f"samples must go forward in time: t1 = {t1} s is not after "
                             f"{self._t / 1e9} s")
        if (t1_ns - self._t) * self.shape[0] * self.shape[1] >= 2**62:
            raise ValueError(f"interval of {(t1_ns - self._t) / 1e9} s is too long for one step "
                             "at this sensor size; add samples in between")
        noise = self.params.noise
        dt_ns = t1_ns - self._t
        needs_light = noise.cutoff_hz > 0 or noise.shot_noise_rate > 0
        Y = None
        if needs_light:
            Y = np.exp(L1) if luminance is None else np.asarray(luminance, dtype=np.float64)
        cutoff = self._cutoff
        x = None                                    # no filter: the level is the input
        if noise.cutoff_hz > 0:
            if not np.all(np.isfinite(L1)):
                raise ValueError("L1 has non-finite values; expected log intensities")
            cutoff = cutoff_frequency(Y, noise)
            x = lowpass_exponent(dt_ns * 1e-9, self._cutoff, cutoff)
        drift = None
        if noise.leak_rate > 0:
            drift = -leak_drift(dt_ns * 1e-9, self.c_on, self.leak_rates, noise, self._rng)
        raw = L1
        if self.kernel == "drjit":
            events, causes, L1 = self._drjit_crossings(
                raw, cutoff if noise.cutoff_hz > 0 else None, self._t, dt_ns,
                np.zeros((0, 0)) if drift is None else drift)
        elif x is None and drift is None:
            events, causes, L1 = self._linear_crossings(raw, self._t, dt_ns)
        else:
            events, causes, L1 = self._crossings(
                self._L, self._raw, raw, np.full(self.shape, np.inf) if x is None else x,
                self._t, dt_ns, np.zeros((0, 0)) if drift is None else drift)
        events = self._with_noise(events, causes, self._t, t1_ns, Y)
        self._L, self._raw, self._cutoff, self._t = L1, raw, cutoff, t1_ns
        return events

    def _with_noise(self, events: np.ndarray, causes: np.ndarray, t0_ns: int, t1_ns: int,
                    luminance: np.ndarray | None) -> np.ndarray:
        """The interval's crossing events (``causes``: each one's) with its shot-noise and
        hot-pixel events of ``[t0_ns, t1_ns)`` merged in, drawn in that order from the
        emulator's generator; sets :attr:`last_causes`.

        Parameters
        ----------
        events : EVENT_DTYPE ndarray
            Threshold crossings, sorted by time.
        causes : (N,) uint8 ndarray
        t0_ns, t1_ns : int
        luminance : (H, W) float64 ndarray or None
            Luminance for the background-activity rate (None only without shot noise).
        """
        noise = self.params.noise
        parts = [(events, causes)]
        if noise.shot_noise_rate > 0:
            shot = background_events(t0_ns, t1_ns, luminance, noise, self._rng)
            parts.append((shot, np.full(len(shot), CAUSE_SHOT, np.uint8)))
        if noise.hot_pixel_fraction > 0 and noise.hot_pixel_rate > 0:
            hot = hot_pixel_events(t0_ns, t1_ns, self.hot_mask, noise.hot_pixel_rate, self._rng)
            parts.append((hot, np.full(len(hot), CAUSE_HOT_PIXEL, np.uint8)))
        if len(parts) == 1:                         # nothing to merge: no copy
            self.last_causes = causes
            return events
        events, self.last_causes = merge_labelled_events(*parts)
        self.last_causes = self.last_causes.astype(np.uint8, copy=False)
        return events

    def _crossings(self, L0, raw0, raw1, x, t0_ns: int, dt_ns: int, drift: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The interval's threshold crossings (sorted events), their causes (uint8, signal or
        leak: ``drift`` is each pixel's leak drift over the interval (H, W), >= 0, or empty
        without leak) and each pixel's level at its end (H, W): ``raw1`` itself without the
        filter (``x`` all inf)."""
        L1 = np.empty(self.shape)
        counts = _count_rows(L0, raw0, raw1, x, self.ref, self.c_on, self.c_off, drift, L1)
        if np.any(counts < 0):
            raise ValueError("L1 has non-finite values; expected log intensities")
        total = int(counts.sum())
        offsets = np.zeros(len(counts), dtype=np.int64)
        np.cumsum(counts[:-1], out=offsets[1:])
        t = np.empty(total, np.int64)
        xs = np.empty(total, np.uint16)
        y = np.empty(total, np.uint16)
        p = np.empty(total, np.int8)
        keep = np.empty(total, np.bool_)
        cause = np.empty(total, np.uint8)
        refractory = int(round(self.params.noise.refractory_period * 1e9))
        _write_rows(L0, raw0, raw1, x, self.ref, self.c_on, self.c_off, self._last_t, offsets,
                    t0_ns, float(dt_ns), refractory, drift, t, xs, y, p, cause, keep)
        events, causes = _sort_events(t, xs, y, p, cause, keep if refractory > 0 else keep[:0],
                                      np.zeros(1, np.int64), np.array([total], np.int64), t0_ns,
                                      dt_ns, self.shape, self._allocate)
        return events, causes, L1

    def _linear_crossings(self, L1, t0_ns: int, dt_ns: int
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_crossings` without filter or leak (the same events): the crossings of the
        line from the last level to ``L1`` (H, W), every one a signal's; the level at the
        interval's end is ``L1`` itself.

        One fused pass (:func:`_linear_chunks`) over chunks of rows, into buffers kept from
        interval to interval, each chunk given room for its events of the last interval and a
        quarter more (its exact count on the first); the rows that did not fit run again,
        with room for their exact count."""
        if not _all_finite(L1):
            raise ValueError("L1 has non-finite values; expected log intensities")
        lo, hi = self._chunk_rows
        if self._chunk_events is None:
            room = np.add.reduceat(_count_rows_linear(L1, self.ref, *self._thresholds), lo)
        else:
            room = self._chunk_events + self._chunk_events // 4 + 256
        buffers = self._buffers(int(room.sum()))
        first, stop, reached = self._linear_pass(L1, t0_ns, dt_ns, lo, hi, room, buffers)
        self._chunk_events = stop - first
        if np.any(reached < hi):                     # too little room: the rest, exactly
            todo = np.flatnonzero(reached < hi)
            per_row = np.concatenate(([0], np.cumsum(
                _count_rows_linear(L1, self.ref, *self._thresholds))))
            room = per_row[hi[todo]] - per_row[reached[todo]]
            more = tuple(np.empty(int(room.sum()), a.dtype) for a in buffers)
            first2, stop2, _ = self._linear_pass(L1, t0_ns, dt_ns, reached[todo], hi[todo],
                                                 room, more)
            self._chunk_events[todo] += stop2 - first2
            buffers = tuple(np.concatenate([a[i:j] for i, j in zip(first, stop, strict=True)]
                                           + [b[i:j] for i, j in zip(first2, stop2, strict=True)])
                            for a, b in zip(buffers, more, strict=True))
            first, stop = np.zeros(1, np.int64), np.array([len(buffers[0])], np.int64)
        t, xs, y, p, keep = buffers
        if self.params.noise.refractory_period <= 0:
            keep = keep[:0]
        events, _ = _sort_events(t, xs, y, p, np.zeros(0, np.uint8), keep, first, stop, t0_ns,
                                 dt_ns, self.shape, self._allocate)
        return events, np.full(len(events), CAUSE_SIGNAL, np.uint8), L1

    def _linear_pass(self, L1, t0_ns, dt_ns, lo, hi, room, buffers
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`_linear_chunks` on chunks of rows ``lo[c]`` to ``hi[c]``, each with ``room``
        events in ``buffers`` (t, x, y, p, keep), one after the other; returns each chunk's
        first and next free slots and its first row not written."""
        stop = np.cumsum(room)
        first = stop - room
        filled, reached = np.empty_like(first), np.empty_like(first)
        refractory = int(round(self.params.noise.refractory_period * 1e9))
        _linear_chunks(self._L, L1, self.ref, *self._thresholds, self._last_t, t0_ns,
                       float(dt_ns), refractory, lo, hi, first, stop, *buffers, filled, reached)
        return first, filled, reached

    def _buffers(self, size: int) -> tuple[np.ndarray, ...]:
        """The crossings' work arrays (t int64, x uint16, y uint16, p int8, keep bool) with
        at least ``size`` elements, kept from call to call (grown by half when short)."""
        if self._work is None or len(self._work[0]) < size:
            size = max(size, 0 if self._work is None else len(self._work[0]) * 3 // 2)
            self._work = tuple(np.empty(size, dtype) for dtype in
                               (np.int64, np.uint16, np.uint16, np.int8, np.bool_))
        return self._work

    def _drjit_crossings(self, raw1: np.ndarray, cutoff1: np.ndarray | None, t0_ns: int,
                         dt_ns: int, drift: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_crossings` on Dr.Jit's device: the interval as a block of per-pixel samples,
        two a pixel (:func:`sim._drjit_events.pixel_events`, given each pixel's leak
        ``drift`` over it, or empty); ``cutoff1`` each pixel's cutoff at the interval's end
        (None: no filter)."""
        from sim._drjit_events import pixel_events

        if not np.all(np.isfinite(raw1)):
            raise ValueError("L1 has non-finite values; expected log intensities")
        height, width = self.shape
        n = height * width
        ends = (self._raw.reshape(-1), raw1.reshape(-1))
        cutoff = None if cutoff1 is None else np.stack(
            (self._cutoff.reshape(-1), cutoff1.reshape(-1)), axis=1).reshape(-1)
        level = np.array(self._L, dtype=np.float64).reshape(-1)       # becomes L1
        raw = np.array(self._raw, dtype=np.float64).reshape(-1)
        refractory = int(round(self.params.noise.refractory_period * 1e9))
        t, pix, p, cause, keep = pixel_events(
            np.repeat(np.arange(n, dtype=np.int64), 2),
            np.tile(np.array([t0_ns, t0_ns + dt_ns], np.int64), n),
            np.stack(ends, axis=1).reshape(-1), cutoff, self.ref.reshape(-1), level, raw,
            self._last_t.reshape(-1), self.c_on.reshape(-1), self.c_off.reshape(-1),
            (np.zeros(0), 0.0), np.zeros(0), refractory, CROSSING_TOLERANCE_NS,
            device=self._device, drift=drift.reshape(-1) if drift.size else None)
        # The order of _crossings: time, ties in pixel order.
        order = np.argsort((t - t0_ns) * n + pix)
        if refractory > 0:
            order = order[keep[order]]
        events = np.empty(len(order), EVENT_DTYPE)
        events["t"], events["p"] = t[order], p[order]
        events["y"], events["x"] = np.divmod(pix[order], width)
        return events, cause[order], level.reshape(self.shape)


def _sort_events(t, xs, y, p, cause, keep, first, stop, t0_ns: int, dt_ns: int,
                 shape: tuple[int, int], allocate=None) -> tuple[np.ndarray, np.ndarray]:
    """The kept crossings (``keep`` empty: all) of the segments ``first[s]`` to ``stop[s]``
    as events in time order, ties in pixel order (sensor ``shape``), and their causes (empty
    when ``cause`` is): :func:`_time_sorted`. ``allocate(n)`` gives the events' array
    (default a new one; :class:`_EventStack`)."""
    kept = _kept(keep, first, stop)
    events = np.empty(kept, EVENT_DTYPE) if allocate is None else allocate(kept)
    causes = np.empty(kept if cause.size else 0, np.uint8)
    _time_sorted(t, xs, y, p, cause, keep, first, stop, t0_ns, float(dt_ns), shape[1],
                 shape[0] * shape[1], events, causes)
    return events, causes


def _check_stack(log_frames, times) -> tuple[np.ndarray, np.ndarray]:
    log_frames = np.asarray(log_frames, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    if log_frames.ndim != 3:
        raise ValueError(f"log_frames must be (N, H, W), got shape {log_frames.shape}")
    if times.shape != (len(log_frames),):
        raise ValueError(f"times must be (N,) = ({len(log_frames)},), got shape {times.shape}")
    if len(times) < 2:
        raise ValueError("need at least 2 samples to emulate events")
    if np.any(np.diff(times) <= 0):
        raise ValueError("times must be strictly increasing")
    return log_frames, times


def emulate_events(log_frames: np.ndarray, times: np.ndarray,
                   params: EventParams | None = None) -> np.ndarray:
    """Events of a stack of log-intensity frames.

    Parameters
    ----------
    log_frames : (N, H, W) array_like
        Log intensity L = log(Y + eps) of linear luminance (never 8-bit gamma values) at each
        sample time, from the renderer or a user's own high-frame-rate video.
    times : (N,) array_like, seconds
        Strictly increasing sample times.
    params : EventParams, optional
        Default: the ``ideal`` preset with C = 0.2.

    Returns
    -------
    (M,) EVENT_DTYPE ndarray
        Fields t (int64 ns), x, y (uint16), p (int8, +1 ON / -1 OFF), sorted by t.
    """
    log_frames, times = _check_stack(log_frames, times)
    emulator = EventEmulator(log_frames.shape[1:], params)
    emulator.start(log_frames[0], times[0])
    stack = _EventStack(len(times) - 1)
    emulator._allocate = stack.reserve
    for frame, t in zip(log_frames[1:], times[1:], strict=True):
        stack.append(emulator.advance(frame, t))
    return stack.events()


class _EventStack:
    """The events of successive intervals in one growing array, each interval's sorted
    crossings written straight into it (:meth:`reserve`, the emulator's ``_allocate``):
    no array per interval and no concatenation.

    Parameters
    ----------
    intervals : int
        How many intervals will be appended: the array grows to the events so far plus, for
        each interval left, as many as the last one had, and a quarter more.
    """

    def __init__(self, intervals: int):
        self._array = np.empty(0, EVENT_DTYPE)
        self._size = 0
        self._left = intervals
        self._reserved: np.ndarray | None = None

    def reserve(self, count: int) -> np.ndarray:
        """Room for ``count`` events after those appended, (count,) EVENT_DTYPE."""
        need = self._size + count
        if need > len(self._array):
            grown = np.empty(max(need + count * max(self._left - 1, 0),
                                 3 * len(self._array) // 2) * 5 // 4, EVENT_DTYPE)
            grown[:self._size] = self._array[:self._size]
            self._array = grown
        self._reserved = self._array[self._size:need]
        return self._reserved

    def append(self, events: np.ndarray) -> None:
        """Append an interval's events (a copy unless they are the room just reserved)."""
        if events is not self._reserved:
            self.reserve(len(events))[:] = events
        self._size += len(events)
        self._left -= 1
        self._reserved = None

    def events(self) -> np.ndarray:
        """(N,) EVENT_DTYPE: every event appended, in order; a copy only where the array has
        more than a quarter of room left."""
        events = self._array[:self._size]
        return events.copy() if 4 * self._size < 3 * len(self._array) else events


def emulate_events_reference(log_frames: np.ndarray, times: np.ndarray,
                             contrast: float = 0.2) -> np.ndarray:
    """A plain per-pixel Python loop of the ideal model, for validation and benchmarks only.

    Same model as :func:`emulate_events` with the ``ideal`` preset (exact thresholds, no noise,
    reference = first level), written as directly as possible. Slow: use small inputs.
    """
    log_frames, times = _check_stack(log_frames, times)
    _, height, width = log_frames.shape
    ref = log_frames[0].copy()
    out = []
    for k in range(1, len(times)):
        t0 = int(round(times[k - 1] * 1e9))
        dt = float(int(round(times[k] * 1e9)) - t0)
        interval = []
        for y in range(height):
            for x in range(width):
                a, b, r = log_frames[k - 1, y, x], log_frames[k, y, x], ref[y, x]
                if b >= r + contrast:
                    sign, n = 1, math.floor((b - r) / contrast)
                elif b <= r - contrast:
                    sign, n = -1, math.floor((r - b) / contrast)
                else:
                    continue
                for i in range(1, n + 1):
                    level = r + i * sign * contrast
                    frac = min(max((level - a) / (b - a), 0.0), 1.0) if b != a else 1.0
                    interval.append((t0 + int(round(frac * dt)), x, y, sign))
                ref[y, x] = r + n * sign * contrast
        interval.sort(key=lambda e: e[0])                      # stable: ties keep pixel order
        out.extend(interval)
    return np.array(out, dtype=EVENT_DTYPE) if out else np.empty(0, EVENT_DTYPE)
