"""The per-pixel emulator's kernel on Dr.Jit's device: every core (``llvm``) or the GPU (``cuda``).

:func:`pixel_events` is :func:`sim.pixel_sampling._pixel_events` (the numba kernel, one CPU
thread) written for Dr.Jit: one lane per pixel's run of samples, each lane walking its pixel's
intervals in time order (the threshold, leak, refractory and photoreceptor low-pass models of
:mod:`sim.events`, step for step), the lanes in order of run length (a SIMD packet or a warp
runs as long as its longest lane). Two launches: the first counts each run's crossings and
leaves every pixel's state at its last sample; after a prefix sum of the counts in pixel order
gives each run its first output slot, the second solves and writes the crossings of the runs
that have any. The low-pass exponents of the intervals are taken in the kernel too, from the
samples' cutoffs. The outputs come back to the host in the numba kernel's order (pixel, then
time), where :meth:`~sim.pixel_sampling.PixelEventEmulator.advance_samples` sorts and packs them
alike (the noise draws stay on the host, from the emulator's one generator). The frame emulator
(:class:`sim.events.EventEmulator`) runs an interval between two frames through it as a block
of two samples a pixel.

Exactness, against the numba kernel:

- Without the low-pass filter (every exponent ``inf``: the ``ideal`` preset, or
  ``cutoff_hz = 0``) the kernel is additions, multiplications, divisions, ``floor`` and
  round-half-to-even on float64 and int64, in the numba kernel's order: on ``llvm`` the events
  and the state carried on are identical, bit for bit (tested). Leak, refractory period and
  threshold mismatch use only such operations and keep this.
- With the filter, the exponents need ``log`` and the ramp response ``exp``, ``expm1`` and
  ``log1p``. Dr.Jit's ``exp`` and ``log`` are its own polynomial approximations (within about
  2 ulp, not NumPy's or libm's values), and ``expm1`` / ``log1p`` are formed from them by
  Kahan's identities (:func:`_expm1`, :func:`_log1p`, a few ulp). The filter's level then
  differs from the numba kernel's by a few ulp (about 1e-15 in log intensity), and a crossing
  time solved on it (to :data:`sim.events.CROSSING_TOLERANCE_NS` either way) by at most 1 ns
  after the rounding to whole nanoseconds; a level within a few ulp of a threshold may fire
  its event one interval earlier or later (at the next sample), and a 1-ns shift may flip a
  refractory drop. Tested: the same number of events, each within 1 ns, on the reference
  test's noisy blocks (``tests/test_drjit_events.py``), and measured on recorded blocks of
  built-in scenes in ``benchmarks/bench_emulator.py``.
- ``cuda`` evaluates the same float64 operations, IEEE and rounded to nearest once Dr.Jit's
  fast-math mode is off (:func:`pixel_events` turns it off for its launches: with it, CUDA's
  division is approximate and the carried levels differed from the numba kernel's by up to
  3 ulp, measured on an H200). Measured on an H200 with ``cuda_ad_rgb`` (2026-11-26): the
  tests below pass there unchanged (bit for bit without the low-pass), and
  ``benchmarks/bench_emulator.py`` found identical events on every recorded block.

Each crossing's cause (signal or leak, :mod:`sim.noise`'s rule) is written beside it, as the
numba kernels do. To add another per-event output: compute it where the crossing is written
(:func:`_write`, which has the lane's interval and piece), add one ``dr.scatter`` beside the
others, one array to :func:`_outputs` and one to the tuple :func:`pixel_events` returns.
"""

from __future__ import annotations

import math
import sys
from types import ModuleType

import drjit as dr
import numpy as np

from sim.noise import CAUSE_LEAK, CAUSE_SIGNAL

__all__ = ["DEVICES", "active_device", "pixel_events", "pixel_events_device"]

DEVICES = ("llvm", "cuda")
"""The Dr.Jit backends :func:`pixel_events` runs on."""

_MAX_NEWTON_STEPS = 200
"""As :func:`sim.noise.ramp_crossing`."""


def _backend(device: str) -> ModuleType:
    """Dr.Jit's array module of ``device`` (``drjit.llvm`` or ``drjit.cuda``)."""
    if device == "cuda":
        import drjit.cuda as module
    elif device == "llvm":
        import drjit.llvm as module
    else:
        raise ValueError(f"device must be one of {DEVICES}, got {device!r}")
    return module


def active_device() -> str:
    """``cuda`` when the active Mitsuba variant is a ``cuda_*`` one, else ``llvm`` (the
    device of :func:`pixel_events` that keeps the emulation beside the renders)."""
    mitsuba = sys.modules.get("mitsuba")
    variant = mitsuba.variant() if mitsuba is not None else None
    return "cuda" if variant is not None and variant.startswith("cuda") else "llvm"


# --- the model's scalar steps (sim.events, sim.noise), lane by lane ---------------------------

def _expm1(z):
    """``exp(z) - 1`` to a few ulp (Kahan: ``(u - 1) z / log u`` with ``u = exp(z)``)."""
    u = dr.exp(z)
    um1 = u - 1.0
    return dr.select(u == 1.0, z, dr.select(um1 == -1.0, -1.0, um1 * z / dr.log(u)))


def _log1p(z):
    """``log(1 + z)`` to a few ulp (Kahan: ``log(u) z / (u - 1)`` with ``u = 1 + z``)."""
    u = 1.0 + z
    return dr.select(u == 1.0, z, dr.log(u) * z / (u - 1.0))


def _ramp_response(f, y0, a, b, x):
    """:func:`sim.noise.ramp_response` (finite ``x`` only)."""
    one_minus_e = -_expm1(-x * f)
    return a + (y0 - a) * (1.0 - one_minus_e) + (b - a) * (f - one_minus_e / x)


def _ramp_turn(y0, a, b, x):
    """:func:`sim.noise.ramp_turn` (finite ``x`` only)."""
    slope = b - a
    lead = x * (y0 - a)
    turns = (slope != 0.0) & (lead != 0.0) & ((lead > 0.0) == (slope > 0.0))
    f = _log1p(lead / slope) / x
    return dr.select(turns & (f > 0.0) & (f < 1.0), f, 1.0)


def _interval_levels(y0, a, b, x, filtered: bool):
    """:func:`sim.events.interval_levels`; ``filtered`` False: every ``x`` is ``inf``."""
    if not filtered:
        return 1.0, b, b
    off = x == math.inf
    y1 = _ramp_response(1.0, y0, a, b, x)
    f_turn = _ramp_turn(y0, a, b, x)
    turns = ~off & (f_turn < 1.0)
    y_turn = dr.select(turns, _ramp_response(f_turn, y0, a, b, x), y1)
    return (dr.select(turns, f_turn, 1.0), dr.select(off, b, y_turn), dr.select(off, b, y1))


def _drifted_inputs(a, b, x, drift, filtered: bool):
    """:func:`sim.noise.drifted_inputs`; ``filtered`` False: every ``x`` is ``inf``."""
    if not filtered:
        return a, b + drift
    off = x == math.inf
    lead = drift / x
    return dr.select(off, a, a + lead), dr.select(off, b + drift, b + drift + lead)


def _threshold_crossings(level, ref, c_on, c_off):
    """:func:`sim.events.threshold_crossings`: ``(count, signed step, polarity)``, the count a
    float64 holding a whole number."""
    up = level >= ref + c_on
    down = ~up & (level <= ref - c_off)
    # One division for both: the same operands as the numba kernel's taken branch.
    count = dr.floor(dr.select(up, level - ref, ref - level) / dr.select(up, c_on, c_off))
    return dr.select(up | down, count, 0.0), dr.select(up, c_on, dr.select(down, -c_off, 0.0)), \
        dr.select(up, 1, dr.select(down, -1, 0))


def _crossing_time(m, level, a, slope, t0, dt):
    """:func:`sim.events.crossing_time`."""
    frac = dr.select(slope != 0.0, (level - a) / slope, 1.0)
    frac = dr.select(frac < 0.0, 0.0, dr.select(frac > 1.0, 1.0, frac))
    return t0 + m.Int64(dr.round(frac * dt))


@dr.syntax
def _ramp_crossing(m, level, y0, a, b, x, f_lo, y_lo, f_hi, y_hi, tolerance, active):
    """:func:`sim.noise.ramp_crossing`: safeguarded Newton, lane by lane (only the
    ``active`` ones)."""
    rising = y_hi >= y_lo
    at_lo = ((level <= y_lo) == rising) | (level == y_lo)
    at_hi = ~at_lo & (((level >= y_hi) == rising) | (level == y_hi))
    done = at_lo | at_hi | ~active
    result = dr.select(at_lo, f_lo, f_hi)
    lo, hi = m.Float64(f_lo), m.Float64(f_hi)
    f = f_lo + (f_hi - f_lo) * (level - y_lo) / (y_hi - y_lo)        # the chord's guess
    slope = b - a
    steps = dr.zeros(m.UInt32, dr.width(level))
    while ~done & (steps < _MAX_NEWTON_STEPS):
        g = _ramp_response(f, y0, a, b, x) - level
        zero = g == 0.0
        above = (g > 0.0) == rising
        hi = dr.select(~zero & above, f, hi)
        lo = dr.select(~zero & ~above, f, lo)
        narrow = ~zero & (hi - lo <= tolerance)
        e = dr.exp(-x * f)
        derivative = slope * (1.0 - e) - x * (y0 - a) * e            # dy/df
        step = dr.select(derivative != 0.0, g / derivative, math.inf)
        f_new = f - step
        inside = (lo < f_new) & (f_new < hi)
        f_new = dr.select(inside, f_new, 0.5 * (lo + hi))
        small = ~zero & ~narrow & inside & (dr.abs(step) <= tolerance)
        result = dr.select(zero, f, dr.select(narrow, 0.5 * (lo + hi), f_new))
        done = zero | narrow | small
        f = dr.select(done, f, f_new)
        steps += 1
    return dr.select(done, result, f)


def _filtered_crossing_time(m, level, y0, a, b, x, f_lo, y_lo, f_hi, y_hi, t0, dt,
                            filtered: bool, tolerance_ns: float):
    """:func:`sim.events.filtered_crossing_time`."""
    linear = _crossing_time(m, level, y0, y_hi - y0, t0, dt)
    if not filtered:
        return linear
    off = x == math.inf
    f = _ramp_crossing(m, level, y0, a, b, dr.select(off, 1.0, x), f_lo, y_lo, f_hi, y_hi,
                       tolerance_ns / dt, ~off)
    return dr.select(off, linear, t0 + m.Int64(dr.round(f * dt)))


def _lowpass_exponent(m, cutoff, j, dt):
    """:func:`sim.noise._lowpass_exponent` of the interval from sample ``j - 1`` to ``j``
    (``dt`` ns): ``2 pi dt`` times the logarithmic mean of the two cutoffs; ``inf`` where one
    is 0."""
    f0 = dr.gather(m.Float64, cutoff, j - 1)
    f1 = dr.gather(m.Float64, cutoff, j)
    ratio = f1 / f0
    mean = dr.select(dr.abs(ratio - 1.0) < 1e-6, 0.5 * (f0 + f1), (f1 - f0) / dr.log(ratio))
    return dr.select((f0 == 0.0) | (f1 == 0.0), math.inf,
                     2.0 * math.pi * (m.Float64(dt) * 1e-9) * mean)


# --- the kernel --------------------------------------------------------------------------------

@dr.syntax
def _write(m, out, n, last, p, level, lb, x, ta, dt, pieces, refractory: int, filtered: bool,
           tolerance_ns: float):
    """Write a lane's crossings of one interval from slot ``n`` on (refractory drops flagged),
    those of the level's first monotonic piece, then those of its second; return the lane's
    next slot and last event. ``pieces`` holds, per piece, ``(count, step, polarity,
    reference before it, f_lo, y_lo, f_hi, y_hi, count and polarity against the leak-free
    reference)``: a crossing beyond that count, or of the other polarity, is the leak's.
    ``level`` is the filter's output and input at the interval's start and ``lb`` the input at
    its end, all with the leak drift added (:func:`_drifted_inputs`)."""
    out_t, out_pix, out_p, out_cause, keep = out
    lf, la = level
    first, second = pieces
    count = first[0]
    i = dr.full(m.Float64, 1.0, dr.width(count))
    while i <= count + second[0]:
        on_second = i > count
        piece = [dr.select(on_second, second[q], first[q]) for q in range(10)]
        _, c, sign, r, f_lo, y_lo, f_hi, y_hi, n_free, sign_free = piece
        index = dr.select(on_second, i - count, i)
        te = _filtered_crossing_time(m, r + index * c, lf, la, lb, x, f_lo, y_lo, f_hi, y_hi,
                                     ta, dt, filtered, tolerance_ns)
        cause = dr.select((sign_free != sign) | (index > n_free), CAUSE_LEAK, CAUSE_SIGNAL)
        kept = m.Bool(True)
        if refractory > 0:
            kept = ~(te - last < refractory)
        dr.scatter(out_t, te, n)
        dr.scatter(out_pix, p, n)
        dr.scatter(out_p, sign, n)
        dr.scatter(out_cause, m.UInt8(cause), n)
        dr.scatter(keep, kept, n)
        last = dr.select(kept, te, last)
        n += 1
        i += 1.0
    return n, last


def _second_piece(m, f_turn, y1, r, c_on, c_off, filtered: bool):
    """The crossings of the level's second monotonic piece (after its turn), as
    :func:`_threshold_crossings`; none where it does not turn."""
    if not filtered:
        return m.Float64(0.0), m.Float64(0.0), m.Int32(0)
    count, c, sign = _threshold_crossings(y1, r, c_on, c_off)
    return dr.select(f_turn < 1.0, count, 0.0), c, sign


@dr.syntax
def _kernel(m, samples, runs, out, leak_jitter: float, refractory: int, filtered: bool,
            leaky: bool, given: bool, tolerance_ns: float):
    """One lane per run of a pixel's samples: its crossings counted (``out`` None; returns
    the counts) or written from the run's slot on (returns the run's state at its end).
    ``leaky``: the leak drift of each interval is drawn from ``normals``; ``given``: that of
    each run's first interval is the run's ``drift`` instead (the frame emulator's)."""
    t, L, cutoff, normals = samples
    p, first, end, k, r, lf, la, last, c_on, c_off, rate, drift, n = runs
    # Copies: the loop updates its state in place, and ``runs`` serves both launches.
    k, r, lf, la, last, n = (type(v)(v) for v in (k, r, lf, la, last, n))
    ta = dr.gather(m.Int64, t, first)
    j = first + 1
    while j < end:
        tb = dr.gather(m.Int64, t, j)
        lb = dr.gather(m.Float64, L, j)
        dt = tb - ta
        x = _lowpass_exponent(m, cutoff, j, dt) if filtered else m.Float64(math.inf)
        # The leak drifts the reference down by d over the interval, linearly: the crossings
        # are the level plus the drift so far against the interval's first reference r (its
        # leak-free reference too), on the input _drifted_inputs gives.
        rf = m.Float64(r)
        d = m.Float64(0.0)
        a, b = la, lb
        if leaky or given:
            if leaky:
                jitter = 1.0 - leak_jitter * dr.gather(m.Float64, normals, k)
                jitter = dr.select(jitter < 0.0, 0.0, jitter)
                d = (m.Float64(dt) * 1e-9) * rate * jitter * c_on
            if given:
                d = dr.select(j == first + 1, drift, d)
            a, b = _drifted_inputs(la, lb, x, d, filtered)
        f_turn, y_turn, y_end = _interval_levels(lf, a, b, x, filtered)
        lf_new = y_end
        if leaky or given:
            lf_new = _interval_levels(lf, la, lb, x, filtered)[2]
        # The monotonic pieces of the level plus drift: up to the turn, then (if it turns) to
        # the end.
        count, c, sign = _threshold_crossings(y_turn, r, c_on, c_off)
        r_turn = r + count * c
        count_2, c_2, sign_2 = _second_piece(m, f_turn, y_end, r_turn, c_on, c_off, filtered)
        free_count, free_c, free_sign = _threshold_crossings(y_turn - d * f_turn, rf, c_on,
                                                             c_off)
        free_count_2, _, free_sign_2 = _second_piece(m, f_turn, y_end - d * 1.0,
                                                    rf + free_count * free_c, c_on, c_off,
                                                    filtered)
        if out is None:
            n += m.UInt32(count + count_2)
        else:
            n, last = _write(m, out, n, last, p, (lf, a), b, x, ta, m.Float64(dt),
                             ((count, c, sign, r, 0.0, lf, f_turn, y_turn, free_count,
                               free_sign),
                              (count_2, c_2, sign_2, r_turn, f_turn, y_turn, 1.0, y_end,
                               free_count_2, free_sign_2)),
                             refractory, filtered, tolerance_ns)
        r = r_turn + count_2 * c_2
        if leaky or given:
            r = r - d
        lf, la, ta = lf_new, lb, tb
        j += 1
        k += 1
    return n, r, lf, la, last


_DTYPES = {dr.VarType.Int64: np.int64, dr.VarType.UInt32: np.uint32,
           dr.VarType.Float64: np.float64, dr.VarType.Float32: np.float32}


def _device_array(kind, values: np.ndarray):
    """``values`` as a Dr.Jit array of type ``kind``.

    On ``llvm`` Dr.Jit maps a host array without copying it, and the alignment it sees enters
    the compiled kernel, so that arrays at other alignments would compile the kernel again (a
    cache miss, 20-35 ms, on most blocks): an array already 128-byte aligned is mapped as it
    is, any other goes through a 128-byte aligned copy. On ``cuda`` too (the path measured on
    an H200; Dr.Jit then copies the aligned array into device memory)."""
    values = np.ascontiguousarray(values, dtype=_DTYPES[dr.type_v(kind)])
    if values.ctypes.data % ALIGNMENT == 0:
        return kind(values)
    aligned = aligned_empty(values.shape, values.dtype)
    aligned[...] = values
    return kind(aligned)


ALIGNMENT = 128
"""Bytes to which the host arrays Dr.Jit maps on ``llvm`` are aligned (:func:`_device_array`)."""


def aligned_empty(shape, dtype) -> np.ndarray:
    """An uninitialised host array whose data starts on an :data:`ALIGNMENT`-byte boundary:
    filled in place, :func:`_device_array` hands it to Dr.Jit without another copy."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape)) * dtype.itemsize
    buffer = np.empty(size + ALIGNMENT, np.uint8)
    start = -buffer.ctypes.data % ALIGNMENT
    return buffer[start:start + size].view(dtype).reshape(shape)


PACKET = 32
"""Lanes that run side by side: a CUDA warp, two AVX-512 packets of float64."""


def _lanes(lengths: np.ndarray) -> np.ndarray:
    """The order of the runs on the lanes: by length within each group of :data:`PACKET`
    lanes (a SIMD packet or a warp runs as long as its longest lane: runs of like length side
    by side waste almost none of it, at random a third to a half on built-in scenes'
    blocks), the groups in a fixed shuffled order (so that each block of lanes a thread or a
    streaming multiprocessor takes holds long and short runs alike)."""
    # Lengths beyond 65,535 samples only share a group with the longest: a 16-bit key (a radix
    # sort, linear) orders them as well as the full one would.
    order = np.argsort(np.minimum(lengths, 65535).astype(np.uint16), kind="stable")
    groups = -(-len(order) // PACKET)
    padded = np.full(groups * PACKET, -1, np.int64)
    padded[:len(order)] = order
    shuffled = padded.reshape(groups, PACKET)[np.random.default_rng(0).permutation(groups)]
    shuffled = shuffled.reshape(-1)
    return shuffled[shuffled >= 0]


def _outputs(m, n: int) -> tuple:
    """Times (int64 ns), flat pixels (int64), polarities (int32), causes (uint8) and keep
    flags of ``n`` crossings, on the device."""
    out = (dr.zeros(m.Int64, n), dr.zeros(m.Int64, n), dr.zeros(m.Int32, n),
           dr.zeros(m.UInt8, n), dr.zeros(m.Bool, n))
    dr.eval(out)              # in memory before the kernel scatters into them
    return out


def pixel_events(pix: np.ndarray, t: np.ndarray, L: np.ndarray, cutoff: np.ndarray | None,
                 ref: np.ndarray, level: np.ndarray, raw: np.ndarray, last_t: np.ndarray,
                 c_on: np.ndarray, c_off: np.ndarray, leak: tuple[np.ndarray, float],
                 normals: np.ndarray, refractory: int, tolerance_ns: float,
                 device: str = "llvm", drift: np.ndarray | None = None
                 ) -> tuple[np.ndarray, ...]:
    """The threshold crossings of a block of per-pixel samples, on Dr.Jit's ``device``.

    The arguments are :func:`sim.pixel_sampling._pixel_events`'s (less its outputs), with the
    same meaning, but for the samples' cutoffs in place of the intervals' exponents;
    ``ref``, ``level``, ``raw`` and ``last_t`` (flat, (P,)) are left at each pixel's last
    sample, in place.

    Parameters
    ----------
    pix : (S,) int64 ndarray
        Flat pixel of each sample, each pixel's samples consecutive (its first one is its
        state at the block start).
    t : (S,) int64 ndarray, ns
    L : (S,) float64 ndarray
        Unfiltered log intensity of each sample.
    cutoff : (S,) float64 ndarray or None
        Each sample's low-pass cutoff, Hz (:func:`sim.noise.cutoff_frequency`); None: no
        filter. The numba kernel takes the intervals' exponents instead; here they are taken
        on the device (:func:`_lowpass_exponent`).
    ref, level, raw : (P,) float64 ndarray
    last_t : (P,) int64 ndarray, ns
    c_on, c_off : (P,) float64 ndarray
    leak : ((P,) float64 ndarray of rates in Hz, or empty; float jitter)
    normals : float64 ndarray
        One normal draw per interval in sample order (empty without leak).
    refractory : int, ns
    tolerance_ns : float, ns
        Largest error of a crossing time solved on the filter's output
        (:data:`sim.events.CROSSING_TOLERANCE_NS`, passed in: :mod:`sim.events` imports this
        module).
    device : {"llvm", "cuda"}
    drift : (P,) float64 ndarray, optional
        Each pixel's leak drift over its first interval (log units, >= 0), where the caller
        drew it (the frame emulator); default: the kernel's, from ``leak`` and ``normals``
        (none without leak). The reference drifts linearly within an interval and each
        crossing is timed where the level meets it (:func:`sim.noise.drifted_inputs`); a
        crossing beyond the count of the level alone, on its piece, is the leak's
        (:data:`sim.noise.CAUSE_LEAK`), the others the signal's (:mod:`sim.noise`'s rule).

    Returns
    -------
    times : (N,) int64 ndarray, ns
    pixels : (N,) int64 ndarray
    polarities : (N,) int8 ndarray
    causes : (N,) uint8 ndarray
        :data:`~sim.noise.CAUSE_SIGNAL` or :data:`~sim.noise.CAUSE_LEAK`.
    keep : (N,) bool ndarray
        False for the crossings the refractory period drops.
        In (pixel, time) order, as the numba kernel gives them.
    """
    # Strict IEEE arithmetic on every device: Dr.Jit's default fast-math mode divides
    # approximately on CUDA (measured on an H200: the carried levels then differed from the
    # numba kernel's by up to 3 ulp) and folds ``a * 0`` to 0.
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        return _pixel_events(pix, t, L, cutoff, ref, level, raw, last_t, c_on, c_off, leak,
                             normals, refractory, tolerance_ns, device, drift)


def _pixel_events(pix, t, L, cutoff, ref, level, raw, last_t, c_on, c_off, leak, normals,
                  refractory, tolerance_ns, device, drift):
    """:func:`pixel_events`' body, under strict IEEE arithmetic."""
    m = _backend(device)
    if len(pix) == 0:
        return _no_crossings()
    starts = np.flatnonzero(np.r_[True, pix[1:] != pix[:-1]])
    ends = np.r_[starts[1:], len(pix)]
    on = _device_array
    samples = (on(m.Int64, t), on(m.Float64, L),
               on(m.Float64, cutoff if cutoff is not None else np.zeros(1)),
               on(m.Float64, normals if leak[0].size > 0 else np.zeros(1)))
    return _runs(m, pix[starts], starts, ends, samples, cutoff is not None, ref, level, raw,
                 last_t, c_on, c_off, leak, refractory, tolerance_ns, drift)


def _no_crossings() -> tuple[np.ndarray, ...]:
    return (np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.int8),
            np.empty(0, np.uint8), np.empty(0, np.bool_))


def pixel_events_device(counts: np.ndarray, t, L, cutoff, ref: np.ndarray, level: np.ndarray,
                        raw: np.ndarray, last_t: np.ndarray, c_on: np.ndarray,
                        c_off: np.ndarray, leak: tuple[np.ndarray, float], normals: np.ndarray,
                        refractory: int, tolerance_ns: float, device: str = "llvm"
                        ) -> tuple[np.ndarray, ...]:
    """:func:`pixel_events` of samples already on the device, every pixel in its turn.

    Parameters
    ----------
    counts : (P,) int64 ndarray
        Samples of each pixel (at least 2: its start and end samples), the samples in pixel
        order: pixel ``p``'s are ``sum(counts[:p])`` onwards.
    t, L : (S,) Dr.Jit Int64 and Float64 arrays of ``device``
        Each sample's time (ns) and unfiltered log intensity (AD types are detached).
    cutoff : (S,) Dr.Jit Float64 array or None
        Each sample's low-pass cutoff, Hz; None: no filter.
    ref, level, raw, last_t, c_on, c_off, leak, normals, refractory, tolerance_ns
        As :func:`pixel_events` (host arrays; the state left in place).
    device : {"llvm", "cuda"}

    Returns
    -------
    As :func:`pixel_events`: the same crossings for the same samples, bit for bit.
    """
    m = _backend(device)
    if len(counts) == 0:
        return _no_crossings()
    counts = np.asarray(counts, np.int64)
    ends = np.cumsum(counts)
    starts = ends - counts
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        samples = (m.Int64(dr.detach(t)), m.Float64(dr.detach(L)),
                   m.Float64(dr.detach(cutoff)) if cutoff is not None else m.Float64(0.0),
                   _device_array(m.Float64, normals if leak[0].size > 0 else np.zeros(1)))
        return _runs(m, np.arange(len(counts)), starts, ends, samples, cutoff is not None,
                     ref, level, raw, last_t, c_on, c_off, leak, refractory, tolerance_ns,
                     None)


def _runs(m, pixels, starts, ends, samples, filtered, ref, level, raw, last_t, c_on, c_off,
          leak, refractory, tolerance_ns, drift):
    """The two launches over the runs ``starts[i]:ends[i]`` of samples of pixel
    ``pixels[i]`` (runs in pixel order, ``samples`` on the device)."""
    lane = _lanes(ends - starts)
    # Each run's first normal: one per interval before it.
    first_normal = (starts - np.arange(len(starts)))[lane]
    starts, ends = starts[lane], ends[lane]
    p = pixels[lane]
    leak_rates, leak_jitter = leak
    leaky = leak_rates.size > 0
    on = _device_array
    runs = [on(m.Int64, p), on(m.UInt32, starts), on(m.UInt32, ends),
            on(m.UInt32, first_normal), on(m.Float64, ref[p]), on(m.Float64, level[p]),
            on(m.Float64, raw[p]), on(m.Int64, last_t[p]), on(m.Float64, c_on[p]),
            on(m.Float64, c_off[p]), on(m.Float64, leak_rates[p] if leaky else np.zeros(len(p))),
            on(m.Float64, np.zeros(len(p)) if drift is None else drift[p]),
            dr.zeros(m.UInt32, len(p))]
    flags = (float(leak_jitter), int(refractory), filtered, leaky, drift is not None,
             float(tolerance_ns))
    # The counting launch leaves every run at its end (only ``last_t`` waits for the writing).
    counts, r, lf, la, _ = _kernel(m, samples, runs, None, *flags)
    dr.eval(counts, r, lf, la)
    ref[p], level[p], raw[p] = r.numpy(), lf.numpy(), la.numpy()
    counts = counts.numpy().astype(np.int64)
    # Each run's first slot: the runs' counts summed in pixel order (the numba kernel's).
    in_order = np.empty_like(counts)
    in_order[lane] = counts
    offsets = np.cumsum(in_order) - in_order
    total = int(in_order.sum())
    out = _outputs(m, max(total, 1))                  # (an empty array cannot be scattered to)
    # The writing launch: only the runs that cross (still in order of length).
    firing = np.flatnonzero(counts)
    if len(firing):
        index = on(m.UInt32, firing)
        runs = [dr.gather(type(v), v, index) for v in runs[:-1]] + [
            on(m.UInt32, offsets[lane][firing])]
        last = _kernel(m, samples, runs, out, *flags)[4]
        dr.eval(out, last)
        last_t[p[firing]] = last.numpy()
    out_t, out_pix, out_p, out_cause, keep = out
    return (out_t.numpy()[:total], out_pix.numpy()[:total],
            out_p.numpy()[:total].astype(np.int8), out_cause.numpy()[:total],
            keep.numpy()[:total])
