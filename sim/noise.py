"""Sensor non-idealities of a DVS pixel array, after v2e (Hu, Liu & Delbruck, CVPRW 2021).

Pure functions that :mod:`sim.events` calls once per interval ``[t0, t1)`` between two renders.
Every random draw comes from a :class:`numpy.random.Generator` passed by the caller, so the same
generator state gives the same output. The models, and where they follow or leave v2e
(``v2ecore/emulator.py`` and ``emulator_utils.py``):

Contrast-threshold mismatch (:func:`threshold_map`)
    ``C = N(C_nominal, threshold_sigma**2)`` per pixel, independently for ON and OFF, sigma in
    absolute log-intensity units, floored at :data:`THRESHOLD_FLOOR` = 0.01. As v2e.

Physical units (see :mod:`sim.radiometry`)
    Luminance ``Y`` is the rendered scene luminance in cd/m^2, which the photocurrent is
    proportional to (``I = R Y``). v2e scales its cutoff and its shot-noise rate with an
    intensity normalised to the white of its 8-bit input (``inten01``, DN 255 = 1); here the
    same laws take ``Y / Y_ref`` with reference luminances in cd/m^2, by default
    :data:`~sim.radiometry.OFFICE_WHITE_LUMINANCE` (100 cd/m^2, a white sheet under ~400 lux)
    in the role of v2e's DN 255. So the ``realistic`` preset's bandwidth and background rate
    follow the scene's illuminance: a twin lit 100 times dimmer has a 100 times lower cutoff
    (down to the floor) and the dark background rate.

Photoreceptor low-pass (:func:`cutoff_frequency`, :func:`lowpass_exponent`, :func:`ramp_response`)
    A first-order low-pass on the log intensity whose 3 dB cutoff is proportional to the
    photocurrent, ``f(Y) = cutoff_hz * clip(Y / cutoff_intensity_ref, cutoff_min_fraction, 1)``.
    v2e uses ``f = cutoff_hz * (DN + 20) / 275`` for an 8-bit input DN: affine in DN, from
    20/275 at DN 0 to 1 at DN 255 (SensorsINI/v2e at cac6384, ``v2ecore/emulator_utils.py``:
    ``rescale_intensity_frame`` returns ``(new_frame + 20) / 275`` and ``low_pass_filter``
    multiplies its step ``delta_time / tau`` by it). Here ``f`` is proportional to luminance,
    with ``cutoff_intensity_ref`` (cd/m^2) in the role of DN 255 and v2e's 20/275 as the
    default floor ``cutoff_min_fraction`` (they differ by at most 0.07 of ``cutoff_hz`` in
    between). v2e
    integrates with a forward-Euler step clamped at 1 and interpolates its output linearly;
    here the filter is solved exactly for the emulator's input, linear between two samples
    (:func:`ramp_response`, stable for any interval), with the cutoff's logarithmic mean over
    the interval (:func:`lowpass_exponent`), and each threshold crossing of the filtered
    level is found on that solution (:func:`ramp_turn`, :func:`ramp_crossing`; used by
    :mod:`sim.events`).

Leak events (:func:`leak_rate_map`, :func:`leak_drift`, :func:`drifted_inputs`)
    Junction leakage in the reset switch moves each pixel's reference *down* by
    ``rate * C_on`` per second, so a static pixel fires ON events at ``rate``. The per-pixel
    rate is log-normal, ``leak_rate * 10 ** (leak_rate_cov_decades * N(0, 1))`` (fixed), and
    each step's drift is scaled by ``1 - leak_jitter * N(0, 1)`` (temporal jitter, floored at
    0 so the reference never moves up). As v2e's ``subtract_leak_current``. Unlike v2e, which
    moves the reference once per frame, the drift is continuous: linear within each interval
    between two samples, and a leak event is stamped at the moment the drifting reference
    meets the (filtered) level, solved as the signal's crossings are (:func:`drifted_inputs`),
    not at the interval's start or end.

Background activity / shot noise (:func:`shot_noise_rate_map`, :func:`background_events`)
    A Poisson process per pixel, half ON and half OFF as in v2e's ``generate_shot_noise``
    (``v2ecore/emulator_utils.py``: ``(shot_noise_rate_hz / 2) * delta_time *
    ((shot_noise_inten_factor - 1) * inten01 + 1)`` per polarity, with
    ``SHOT_NOISE_INTEN_FACTOR = 0.25`` in ``v2ecore/emulator.py``), with v2e's intensity
    dependence: the rate falls linearly with normalised intensity
    ``u = clip(Y / shot_noise_intensity_ref, 0, 1)`` (both in cd/m^2) from the dark value to
    ``shot_noise_bright_factor`` (v2e's ``SHOT_NOISE_INTEN_FACTOR`` = 0.25) times it at
    ``u = 1``. evfuse quotes the rate at the reference intensity, so::

        rate(Y) = shot_noise_rate * (1 / k - (1 / k - 1) * u),   k = shot_noise_bright_factor

    i.e. ``shot_noise_rate`` for ``Y >= shot_noise_intensity_ref`` and ``shot_noise_rate / k``
    (4x) in the dark. Differences from v2e: v2e draws at most one noise event per pixel per
    frame, stamped at the frame's end, and scales the rate by ``C_nominal / C_pixel``; here
    each pixel draws a Poisson number of events with uniform times in ``[t0, t1)``, so long
    intervals are exact, and the rate does not depend on the pixel's threshold. v2e also
    resets a pixel's reference after a noise event; that is the emulator's business.

Hot pixels (:func:`hot_pixel_mask`, :func:`hot_pixel_events`)
    Not in v2e. A fixed, seeded set of ``round(hot_pixel_fraction * H * W)`` pixels fires ON
    events as a Poisson process at ``hot_pixel_rate``.

Events are the project's structured array (``t`` int64 ns, ``x``/``y`` uint16, ``p`` int8
+1/-1), sorted by ``t``; :func:`merge_events` merges streams stably, and
:func:`merge_labelled_events` merges them with each event's cause (:data:`CAUSES`).

Causes (each event's label, :mod:`sim.event_labels`)
    :data:`CAUSE_SIGNAL` a threshold crossing of the signal; :data:`CAUSE_SHOT` a
    background-activity event (:func:`background_events`); :data:`CAUSE_LEAK` a crossing that
    the interval's leak drift added (the emulators' rule: between two samples of a pixel, its
    crossings are counted twice on each monotonic piece of its level plus the drift so far,
    against the reference the interval started with: once for that sum (the events emitted)
    and once for the level alone at the piece's end (the *leak-free* count); the crossings
    beyond the leak-free count, the last ones of the piece, are leak, the others signal);
    :data:`CAUSE_HOT_PIXEL` an event of a hot pixel (:func:`hot_pixel_events`). A leak
    event is always ON (the drift lowers the reference); without leak (``leak_rate`` 0) no
    event is one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numba
import numpy as np

from sim.radiometry import OFFICE_WHITE_LUMINANCE
from sim.validation import bounded

__all__ = [
    "CAUSES",
    "CAUSE_HOT_PIXEL",
    "CAUSE_LEAK",
    "CAUSE_SHOT",
    "CAUSE_SIGNAL",
    "NOISE_PRESETS",
    "THRESHOLD_FLOOR",
    "NoiseParams",
    "background_events",
    "cutoff_frequency",
    "drifted_inputs",
    "hot_pixel_events",
    "hot_pixel_mask",
    "leak_drift",
    "leak_rate_map",
    "lowpass_exponent",
    "merge_events",
    "merge_labelled_events",
    "noise_preset",
    "ramp_crossing",
    "ramp_response",
    "ramp_turn",
    "shot_noise_rate_map",
    "threshold_map",
]

# The project's event layout. Identical to sim.events.EVENT_DTYPE, which cannot be imported
# here because sim.events imports this module.
_EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])

CAUSE_SIGNAL = 0
"""An event's cause: a threshold crossing of the signal (leak-free reference)."""
CAUSE_SHOT = 1
"""An event's cause: background activity (shot noise, :func:`background_events`)."""
CAUSE_LEAK = 2
"""An event's cause: a crossing the interval's leak drift added (see the module docstring)."""
CAUSE_HOT_PIXEL = 3
"""An event's cause: a hot pixel (:func:`hot_pixel_events`)."""
CAUSES = {CAUSE_SIGNAL: "signal", CAUSE_SHOT: "shot", CAUSE_LEAK: "leak",
          CAUSE_HOT_PIXEL: "hot_pixel"}
"""Cause code (uint8) -> name."""

THRESHOLD_FLOOR = 0.01
"""Smallest contrast threshold (log units) that :func:`threshold_map` returns (v2e's clamp)."""

_MAX_SENSOR_SIDE = np.iinfo(np.uint16).max + 1
"""Pixel coordinates are uint16, so a sensor side is at most 65536 pixels."""


@dataclass(frozen=True)
class NoiseParams:
    """Sensor non-idealities; the defaults are the ``ideal`` sensor (no noise of any kind).

    The ``realistic`` preset (:data:`NOISE_PRESETS`) says where its numbers come from. Fields
    that only shape a noise (jitters, reference intensities) default to v2e's values and have
    no effect while the noise they shape is off.

    Attributes
    ----------
    shot_noise_rate : float, Hz per pixel
        Background-activity rate (ON + OFF) at ``shot_noise_intensity_ref`` and brighter;
        4x this in the dark with the default ``shot_noise_bright_factor`` (see the module
        docstring for the law). 0 = off. v2e's ``shot_noise_rate_hz`` (CLI default 0.001 Hz,
        ``noisy`` preset 5 Hz) is the dark rate, i.e. ``shot_noise_rate / k``.
    shot_noise_intensity_ref : float, cd/m^2
        Luminance at which the background rate equals ``shot_noise_rate`` (v2e's white level,
        DN 255). Default :data:`~sim.radiometry.OFFICE_WHITE_LUMINANCE`, 100 cd/m^2.
    shot_noise_bright_factor : float in (0, 1]
        Bright-to-dark ratio ``k`` of the background rate (v2e's ``SHOT_NOISE_INTEN_FACTOR``
        0.25); 1 makes the rate independent of intensity.
    leak_rate : float, Hz per pixel
        Median leak-event rate: each reference drifts down by ``leak_rate * C_on`` per second.
        0 = off. v2e: CLI default 0.01 Hz, ``noisy`` preset 0.1 Hz.
    leak_jitter : float in [0, 1)
        Standard deviation of the per-step relative jitter of the leak drift (v2e's
        ``leak_jitter_fraction``, 0.1).
    leak_rate_cov_decades : float, decades
        Standard deviation of log10 of the per-pixel leak rate (v2e's ``noise_rate_cov_decades``,
        0.1): fixed-pattern spread of the leak rate across the array.
    hot_pixel_fraction : float in [0, 1]
        Fraction of pixels that are hot (not modelled by v2e). 0 = none.
    hot_pixel_rate : float, Hz
        ON-event rate of each hot pixel (Poisson).
    cutoff_hz : float, Hz
        3 dB cutoff of the photoreceptor low-pass at ``cutoff_intensity_ref`` and brighter.
        0 = no filter (infinite bandwidth). v2e: CLI default 300 Hz, ``noisy`` preset 30 Hz.
    cutoff_intensity_ref : float, cd/m^2
        Luminance at which the cutoff reaches ``cutoff_hz`` (v2e's DN 255). Default
        :data:`~sim.radiometry.OFFICE_WHITE_LUMINANCE`, 100 cd/m^2.
    cutoff_min_fraction : float in (0, 1]
        Floor of ``f(Y) / cutoff_hz`` in the dark (v2e's 20/275 = 0.0727 at DN 0).
    threshold_sigma : float, log-intensity units
        Standard deviation of the per-pixel contrast thresholds (absolute, not relative to C).
        v2e's ``sigma_thres`` (default 0.03).
    refractory_period : float, seconds
        Dead time after each emitted event (v2e's ``refractory_period``, default 0.5 ms).
    initial_phase : bool
        Start each pixel's reference a random fraction of its ON threshold below the first
        level, uniform in ``[0, C_on)``, so that the first events are not synchronised.
    """

    shot_noise_rate: float = 0.0
    shot_noise_intensity_ref: float = OFFICE_WHITE_LUMINANCE
    shot_noise_bright_factor: float = 0.25
    leak_rate: float = 0.0
    leak_jitter: float = 0.1
    leak_rate_cov_decades: float = 0.1
    hot_pixel_fraction: float = 0.0
    hot_pixel_rate: float = 0.0
    cutoff_hz: float = 0.0
    cutoff_intensity_ref: float = OFFICE_WHITE_LUMINANCE
    cutoff_min_fraction: float = 20.0 / 275.0
    threshold_sigma: float = 0.0
    refractory_period: float = 0.0
    initial_phase: bool = False

    def __post_init__(self) -> None:
        ranges = {
            "shot_noise_intensity_ref": {"low_open": True},
            "shot_noise_bright_factor": {"low_open": True, "high": 1.0},
            "leak_jitter": {"high": 1.0, "high_open": True},
            "hot_pixel_fraction": {"high": 1.0},
            "cutoff_intensity_ref": {"low_open": True},
            "cutoff_min_fraction": {"low_open": True, "high": 1.0},
        }
        for f in fields(self):
            if f.name == "initial_phase":
                continue
            value = bounded("NoiseParams", f.name, getattr(self, f.name), **ranges.get(f.name, {}))
            object.__setattr__(self, f.name, value)
        if not isinstance(self.initial_phase, bool | np.bool_):
            raise ValueError(f"NoiseParams.initial_phase must be a bool, "
                             f"got {self.initial_phase!r}")
        object.__setattr__(self, "initial_phase", bool(self.initial_phase))

    @property
    def has_noise(self) -> bool:
        """True when any random or non-ideal behaviour is switched on."""
        return bool(self.shot_noise_rate > 0 or self.leak_rate > 0
                    or (self.hot_pixel_fraction > 0 and self.hot_pixel_rate > 0)
                    or self.cutoff_hz > 0 or self.threshold_sigma > 0
                    or self.refractory_period > 0 or self.initial_phase)


NOISE_PRESETS: dict[str, NoiseParams] = {
    "ideal": NoiseParams(),
    "realistic": NoiseParams(
        # Background activity of DAVIS240-class sensors at room light is of order 0.1 Hz/px;
        # v2e's "noisy" examples use 1-5 Hz, its CLI default 0.001 Hz (dark rate).
        shot_noise_rate=0.1,
        # v2e's "noisy" preset; leak is the dominant BA source in bright light.
        leak_rate=0.1,
        # Not modelled by v2e: a few DAVIS240C pixels (~1e-4) fire at ~10 Hz.
        hot_pixel_fraction=1e-4,
        hot_pixel_rate=10.0,
        # DAVIS photoreceptor bandwidth in bright light is a few hundred Hz (v2e CLI: 300 Hz),
        # reached from 100 cd/m^2 (white under ~400 lux) up; 14.5 Hz (the floor) below 7 cd/m^2.
        cutoff_hz=200.0,
        threshold_sigma=0.03,          # v2e CLI default sigma_thres
        refractory_period=0.5e-3,      # v2e CLI default refractory_period
        initial_phase=True,
    ),
}
"""Named noise settings: ``ideal`` (none) and ``realistic`` (DAVIS240C-like)."""


def noise_preset(name: str) -> NoiseParams:
    """The :class:`NoiseParams` of preset ``name`` (``ideal`` or ``realistic``)."""
    try:
        return NOISE_PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown noise preset {name!r}; expected one of "
                         f"{sorted(NOISE_PRESETS)}") from None


# ------------------------------------------------------------------------------------------------
# Input checks
# ------------------------------------------------------------------------------------------------


def _check_params(params) -> NoiseParams:
    if not isinstance(params, NoiseParams):
        raise ValueError(f"params must be a NoiseParams, got {type(params).__name__}")
    return params


def _check_shape(shape) -> tuple[int, int]:
    try:
        height, width = (int(s) for s in shape)
    except (TypeError, ValueError):
        raise ValueError(f"shape must be (height, width), got {shape!r}") from None
    if not (0 < height <= _MAX_SENSOR_SIDE and 0 < width <= _MAX_SENSOR_SIDE):
        raise ValueError(f"shape must be (height, width) with sides in [1, {_MAX_SENSOR_SIDE}], "
                         f"got {tuple(shape)!r}")
    return height, width


def _check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator (np.random.default_rng(seed)), "
                         f"got {type(rng).__name__}")
    return rng


def _check_luminance(luminance, name: str = "luminance") -> np.ndarray:
    luminance = np.asarray(luminance, dtype=np.float64)
    if luminance.ndim != 2:
        raise ValueError(f"{name} must be an (H, W) array, got shape {luminance.shape}")
    _check_shape(luminance.shape)
    if not np.all(np.isfinite(luminance)) or np.any(luminance < 0):
        raise ValueError(f"{name} must be finite and >= 0 (luminance, cd/m^2)")
    return luminance


def _check_interval(t0_ns, t1_ns) -> tuple[int, int]:
    for name, value in (("t0_ns", t0_ns), ("t1_ns", t1_ns)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise ValueError(f"{name} must be an integer number of nanoseconds, got {value!r}")
    t0_ns, t1_ns = int(t0_ns), int(t1_ns)
    if t1_ns < t0_ns:
        raise ValueError(f"the interval must go forward in time: t1_ns = {t1_ns} < t0_ns = {t0_ns}")
    return t0_ns, t1_ns


def _check_dt(where: str, dt) -> float:
    return bounded(where, "dt", dt, low_open=True)


# ------------------------------------------------------------------------------------------------
# Contrast thresholds
# ------------------------------------------------------------------------------------------------


def threshold_map(shape: tuple[int, int], C_on: float, C_off: float, sigma: float,
                  rng: np.random.Generator, *, floor: float = THRESHOLD_FLOOR
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel ON and OFF contrast thresholds with fixed-pattern mismatch.

    Parameters
    ----------
    shape : (int, int)
        Sensor height and width.
    C_on, C_off : float, log-intensity units
        Nominal thresholds, > 0.
    sigma : float, log-intensity units
        Standard deviation of the mismatch (absolute, not a fraction of C), >= 0.
    rng : numpy.random.Generator
        Source of the draws: the ON map is drawn first, then the OFF map; the generator
        advances by the same amount whatever ``sigma`` is (0 included).
    floor : float, log-intensity units
        Values below it are raised to it (default 0.01, v2e's clamp).

    Returns
    -------
    c_on, c_off : (H, W) float64 ndarray, log-intensity units
        ``max(N(C, sigma**2), floor)``, independently per pixel and polarity. float64 (not
        float32) so that ``sigma = 0`` gives exactly ``C``: float32(0.2) would move every
        crossing time of the ideal sensor by a rounding error.
    """
    height, width = _check_shape(shape)
    C_on = bounded("threshold_map", "C_on", C_on, low_open=True)
    C_off = bounded("threshold_map", "C_off", C_off, low_open=True)
    sigma = bounded("threshold_map", "sigma", sigma)
    floor = bounded("threshold_map", "floor", floor, low_open=True)
    rng = _check_rng(rng)
    maps = []
    for nominal in (C_on, C_off):
        c = nominal + sigma * rng.standard_normal((height, width))
        maps.append(np.maximum(c, floor))
    return maps[0], maps[1]


# ------------------------------------------------------------------------------------------------
# Photoreceptor low-pass filter
# ------------------------------------------------------------------------------------------------


def cutoff_frequency(luminance: np.ndarray, params: NoiseParams) -> np.ndarray:
    """3 dB cutoff of each pixel's photoreceptor, falling in the dark.

    Parameters
    ----------
    luminance : (H, W) array_like, cd/m^2, >= 0
    params : NoiseParams

    Returns
    -------
    (H, W) float64 ndarray, Hz
        ``cutoff_hz * clip(Y / cutoff_intensity_ref, cutoff_min_fraction, 1)``; all 0 when
        ``cutoff_hz`` is 0 (filter off).
    """
    return _cutoff(_check_luminance(luminance), _check_params(params))


def _cutoff(luminance: np.ndarray, params: NoiseParams) -> np.ndarray:
    """The law of :func:`cutoff_frequency` on already-checked values of any shape (the
    per-pixel emulator's samples are a flat array)."""
    fraction = np.clip(luminance / params.cutoff_intensity_ref, params.cutoff_min_fraction, 1.0)
    return params.cutoff_hz * fraction


def lowpass_exponent(dt: float | np.ndarray, cutoff_start: np.ndarray, cutoff_end: np.ndarray
                     ) -> np.ndarray:
    """Length of an interval in time constants of each pixel's low-pass, ``x = dt / tau``.

    Inside an interval the log intensity is linear in time, so the photocurrent (and the
    cutoff, proportional to it) is exponential in time between its two end values. The filter
    is solved with a constant cutoff over the interval (:func:`ramp_response`); the one that
    gives the exact integral of ``2 pi f(t)`` over the interval is the *logarithmic mean* of
    the end cutoffs, ``(f1 - f0) / ln(f1 / f0)`` (their common value when equal). What is left
    is second order in the cutoff's change over the interval (see ``README.md``, "Exact timing
    under the low-pass filter", for the bound).

    Parameters
    ----------
    dt : float or array_like, seconds, > 0
        The interval's length (one for all, or one per cutoff).
    cutoff_start, cutoff_end : array_like, Hz
        Each pixel's cutoff at the start and at the end of the interval
        (:func:`cutoff_frequency`), same shape; 0 = no filter.

    Returns
    -------
    ndarray of float64, same shape
        ``2 pi dt fbar``; ``inf`` (infinite bandwidth: the filter passes its input) where a
        cutoff is 0.
    """
    if isinstance(dt, np.ndarray):
        if not (np.all(np.isfinite(dt)) and np.all(dt > 0)):
            raise ValueError("lowpass_exponent.dt must hold finite numbers > 0 (seconds)")
    else:
        dt = _check_dt("lowpass_exponent", dt)
    f0 = np.asarray(cutoff_start, dtype=np.float64)
    f1 = np.asarray(cutoff_end, dtype=np.float64)
    if f0.shape != f1.shape or not (np.all(np.isfinite(f0)) and np.all(np.isfinite(f1))) \
            or np.any(f0 < 0) or np.any(f1 < 0):
        raise ValueError(f"cutoff_start and cutoff_end must be finite cutoffs >= 0 Hz of the "
                         f"same shape, got shapes {f0.shape} and {f1.shape}")
    return _lowpass_exponent(dt, f0, f1)


def _lowpass_exponent(dt, f0: np.ndarray, f1: np.ndarray) -> np.ndarray:
    """The law of :func:`lowpass_exponent` on already-checked values (float64 arrays of one
    shape; ``dt`` a number or such an array), element by element: the per-pixel emulator
    applies it to all its sample pairs at once."""
    off = (f0 == 0) | (f1 == 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = f1 / f0
        # Below a relative difference of 1e-6 the arithmetic mean is the logarithmic one to
        # 1e-13 (their difference is (r - 1)**2 / 12 of it).
        mean = np.where(np.abs(ratio - 1.0) < 1e-6, 0.5 * (f0 + f1),
                        (f1 - f0) / np.log(ratio))
        return np.where(off, np.inf, 2.0 * np.pi * dt * mean)


@numba.njit(cache=True, inline="always")
def ramp_response(f, y0, a, b, x):  # pragma: no cover - compiled
    """The filter's output at fraction ``f`` of an interval over which its input ramps.

    The exact solution of ``tau dy/dt = u - y`` for ``u`` linear from ``a`` to ``b`` over the
    interval, ``y = y0`` at its start, ``x`` = the interval in time constants::

        y(f) = a + (y0 - a) E + (b - a) (f - (1 - E) / x),   E = exp(-x f)

    written so that neither a small nor a large ``x`` loses precision. ``x = inf`` (no
    filter) gives the input itself, ``a + (b - a) f``.
    """
    if x == math.inf:
        return a + (b - a) * f
    one_minus_e = -math.expm1(-x * f)
    return a + (y0 - a) * (1.0 - one_minus_e) + (b - a) * (f - one_minus_e / x)


@numba.njit(cache=True, inline="always")
def ramp_turn(y0, a, b, x):  # pragma: no cover - compiled
    """Fraction in (0, 1) of the interval at which :func:`ramp_response` turns; 1.0 if none.

    ``y'' `` never changes sign on the interval, so the output is monotonic or turns once: it
    turns when it starts on the other side of the input from where the input goes (it first
    moves towards the input, then follows the ramp), at ``f = ln(1 + x (y0 - a) / (b - a)) / x``.
    """
    slope = b - a
    if x == math.inf or slope == 0.0:
        return 1.0
    lead = x * (y0 - a)
    if lead == 0.0 or (lead > 0.0) != (slope > 0.0):
        return 1.0
    f = math.log1p(lead / slope) / x
    return f if 0.0 < f < 1.0 else 1.0


@numba.njit(cache=True, inline="always")
def drifted_inputs(a, b, x, drift):  # pragma: no cover - compiled
    """The input ramp whose response is the level *plus* a drift linear over the interval.

    The leak moves a pixel's reference down by ``drift`` (log units, >= 0) linearly over the
    interval, so the pixel fires when its level *minus* the moving reference crosses a
    threshold: the level plus ``drift * f`` against the reference the interval started with.
    That sum is itself the filter's response (:func:`ramp_response`, same ``y0`` and ``x``)
    to the input ramp from ``a + drift / x`` to ``b + drift + drift / x``: with ``tau``
    the filter's time constant, ``tau d(y + D f)/dt = (u + D f + D / x) - (y + D f)``. Without
    the filter (``x = inf``) it is the line from ``a`` to ``b + drift``. So the crossings of
    the drifting reference are solved in continuous time by the same code as the signal's
    (:func:`ramp_turn`, :func:`ramp_crossing`). ``drift / x`` is ``rate C_on / (2 pi f)``
    whatever the interval's length, so it stays small. ``drift = 0`` returns ``a, b``
    exactly.
    """
    if x == math.inf:
        return a, b + drift
    lead = drift / x
    return a + lead, b + drift + lead


@numba.njit(cache=True)
def ramp_crossing(level, y0, a, b, x, f_lo, y_lo, f_hi, y_hi, tolerance):  # pragma: no cover
    """Fraction ``f`` in ``[f_lo, f_hi]`` at which :func:`ramp_response` equals ``level``.

    The response must be monotonic on the bracket (split it at :func:`ramp_turn`), with values
    ``y_lo`` and ``y_hi`` at its ends. A level outside them gives the nearer end. Safeguarded
    Newton: a Newton step from the end nearer the level, a bisection whenever the step would
    leave the bracket; stops when the bracket (or the step) is shorter than ``tolerance``
    (a fraction of the interval), or after 200 steps (bisection alone needs about 60 for
    double precision).
    """
    rising = y_hi >= y_lo
    if (level <= y_lo) == rising or level == y_lo:
        return f_lo
    if (level >= y_hi) == rising or level == y_hi:
        return f_hi
    lo, hi = f_lo, f_hi
    f = f_lo + (f_hi - f_lo) * (level - y_lo) / (y_hi - y_lo)        # the chord's guess
    slope = b - a
    for _ in range(200):
        g = ramp_response(f, y0, a, b, x) - level
        if g == 0.0:
            return f
        if (g > 0.0) == rising:
            hi = f
        else:
            lo = f
        if hi - lo <= tolerance:
            return 0.5 * (lo + hi)
        e = math.exp(-x * f)
        derivative = slope * (1.0 - e) - x * (y0 - a) * e            # dy/df
        step = g / derivative if derivative != 0.0 else math.inf
        f_new = f - step
        if not lo < f_new < hi:
            f_new = 0.5 * (lo + hi)
        elif abs(step) <= tolerance:
            return f_new
        f = f_new
    return f


# ------------------------------------------------------------------------------------------------
# Leak
# ------------------------------------------------------------------------------------------------


def leak_rate_map(shape: tuple[int, int], params: NoiseParams, rng: np.random.Generator
                  ) -> np.ndarray:
    """Fixed per-pixel leak-event rates (drawn once per sensor).

    Parameters
    ----------
    shape : (int, int)
    params : NoiseParams
    rng : numpy.random.Generator
        One standard normal per pixel is drawn, whatever the parameters.

    Returns
    -------
    (H, W) float64 ndarray, Hz
        ``leak_rate * 10 ** (leak_rate_cov_decades * N(0, 1))``: log-normal with median
        ``leak_rate`` (mean higher by ``exp((cov ln 10)**2 / 2)``, 2.7 % for 0.1 decade).
    """
    shape = _check_shape(shape)
    params = _check_params(params)
    rng = _check_rng(rng)
    z = rng.standard_normal(shape)
    return params.leak_rate * 10.0 ** (params.leak_rate_cov_decades * z)


def leak_drift(dt: float, c_on: np.ndarray, leak_rates: np.ndarray, params: NoiseParams,
               rng: np.random.Generator) -> np.ndarray:
    """Increment of each pixel's reference level over ``dt`` due to leakage (<= 0).

    Parameters
    ----------
    dt : float, seconds, >= 0
    c_on : (H, W) array_like or float, log-intensity units
        Each pixel's ON threshold: a drift of ``rate * c_on`` per second gives ``rate``
        ON events per second.
    leak_rates : (H, W) array_like, Hz
        From :func:`leak_rate_map`.
    params : NoiseParams
        ``leak_jitter`` is used.
    rng : numpy.random.Generator
        One standard normal per pixel is drawn.

    Returns
    -------
    (H, W) float64 ndarray, log-intensity units
        ``-dt * leak_rates * max(0, 1 - leak_jitter * N(0, 1)) * c_on``: add it to the
        reference, which moves *down*, so that a static pixel emits ON events (v2e).
    """
    dt = bounded("leak_drift", "dt", dt)
    params = _check_params(params)
    rng = _check_rng(rng)
    leak_rates = np.asarray(leak_rates, dtype=np.float64)
    if leak_rates.ndim != 2 or not np.all(np.isfinite(leak_rates)) or np.any(leak_rates < 0):
        raise ValueError(f"leak_rates must be a finite (H, W) array of rates >= 0 Hz, "
                         f"got shape {leak_rates.shape}")
    c_on = np.asarray(c_on, dtype=np.float64)
    if c_on.shape not in ((), leak_rates.shape):
        raise ValueError(f"c_on must be a number or have the shape of leak_rates "
                         f"{leak_rates.shape}, got shape {c_on.shape}")
    jitter = np.maximum(0.0, 1.0 - params.leak_jitter * rng.standard_normal(leak_rates.shape))
    return -(dt * leak_rates * jitter * c_on)


# ------------------------------------------------------------------------------------------------
# Poisson events: background activity and hot pixels
# ------------------------------------------------------------------------------------------------


def _poisson_events(t0_ns: int, t1_ns: int, flat_index: np.ndarray, counts: np.ndarray,
                    shape: tuple[int, int], random_polarity: bool, rng: np.random.Generator
                    ) -> np.ndarray:
    """Events of pixels ``flat_index`` (row-major), ``counts[i]`` each, in [t0, t1).

    Times are uniform; polarity is ON, or ON/OFF at 1/2 each when ``random_polarity``. Sorted
    by time, ties in pixel order. Draws the times, then the polarities (in sorted order: they
    are independent of time and pixel, so the order they are assigned in does not matter).
    """
    total = int(counts.sum())
    n_pixels = shape[0] * shape[1]
    offset = rng.integers(0, t1_ns - t0_ns, size=total, dtype=np.int64)
    pixel = np.repeat(flat_index.astype(np.int64), counts)
    if (t1_ns - t0_ns) < np.iinfo(np.int64).max // n_pixels:
        # One sort of a combined key (time major, pixel minor): faster than a stable argsort.
        key = offset * n_pixels + pixel
        key.sort()
        offset, pixel = np.divmod(key, n_pixels)
    else:                                                    # intervals longer than ~8 hours
        order = np.lexsort((pixel, offset))
        offset, pixel = offset[order], pixel[order]
    events = np.empty(total, _EVENT_DTYPE)
    events["t"] = offset + t0_ns
    events["y"], events["x"] = np.divmod(pixel, shape[1])
    if random_polarity:
        bits = np.unpackbits(np.frombuffer(rng.bytes((total + 7) // 8), dtype=np.uint8))
        events["p"] = 2 * bits[:total].astype(np.int8) - 1
    else:
        events["p"] = 1
    return events


def shot_noise_rate_map(luminance: np.ndarray, params: NoiseParams) -> np.ndarray:
    """Background-activity rate (ON + OFF) of each pixel.

    Parameters
    ----------
    luminance : (H, W) array_like, cd/m^2, >= 0
    params : NoiseParams

    Returns
    -------
    (H, W) float64 ndarray, Hz
        ``shot_noise_rate * (1/k - (1/k - 1) * clip(Y / shot_noise_intensity_ref, 0, 1))``
        with ``k = shot_noise_bright_factor``: ``shot_noise_rate`` at and above the reference
        intensity, ``shot_noise_rate / k`` in the dark (v2e's law, see the module docstring).
    """
    return _shot_rate(_check_luminance(luminance), _check_params(params))


def _shot_rate(luminance: np.ndarray, params: NoiseParams) -> np.ndarray:
    """The law of :func:`shot_noise_rate_map` on already-checked values of any shape."""
    u = np.clip(luminance / params.shot_noise_intensity_ref, 0.0, 1.0)
    inverse_k = 1.0 / params.shot_noise_bright_factor
    return params.shot_noise_rate * (inverse_k - (inverse_k - 1.0) * u)


def background_events(t0_ns: int, t1_ns: int, luminance: np.ndarray, params: NoiseParams,
                      rng: np.random.Generator) -> np.ndarray:
    """Background-activity (shot-noise) events of the interval ``[t0_ns, t1_ns)``.

    Each pixel fires a Poisson process of rate ``rate(Y)`` (:func:`shot_noise_rate_map`), at
    times uniform in the interval, each event ON or OFF with probability 1/2 (v2e splits the
    rate equally). Drawn by thinning, so that the cost follows the number of events, not of
    pixels: candidates at the highest rate (the dark rate) land uniformly over pixels and time,
    and each is kept with probability rate(pixel) / highest rate. That is exact for Poisson
    processes, and only the candidates' pixels need their luminance looked at.

    Parameters
    ----------
    t0_ns, t1_ns : int, nanoseconds
        The interval, ``t1_ns >= t0_ns`` (empty output when equal).
    luminance : (H, W) array_like, cd/m^2, >= 0
        Luminance over the interval (use the newer render's).
    params : NoiseParams
    rng : numpy.random.Generator
        Draw order: the candidate count, their pixels, the acceptance draws, then times,
        then polarities.

    Returns
    -------
    (N,) structured ndarray
        Fields ``t`` (int64 ns), ``x``, ``y`` (uint16), ``p`` (int8, +1/-1), sorted by ``t``;
        ties keep row-major pixel order.
    """
    t0_ns, t1_ns = _check_interval(t0_ns, t1_ns)
    rng = _check_rng(rng)
    params = _check_params(params)
    luminance = _check_luminance(luminance)
    if t1_ns == t0_ns or params.shot_noise_rate == 0:
        return np.empty(0, _EVENT_DTYPE)
    n_pixels = luminance.size
    top_rate = params.shot_noise_rate / params.shot_noise_bright_factor
    n_candidates = rng.poisson(top_rate * n_pixels * ((t1_ns - t0_ns) * 1e-9))
    candidates = np.sort(rng.integers(0, n_pixels, size=n_candidates, dtype=np.int64))
    keep = rng.random(n_candidates) * top_rate < _shot_rate(luminance.ravel()[candidates], params)
    flat_index, counts = np.unique(candidates[keep], return_counts=True)
    return _poisson_events(t0_ns, t1_ns, flat_index, counts, luminance.shape, True, rng)


def hot_pixel_mask(shape: tuple[int, int], fraction: float, rng: np.random.Generator
                   ) -> np.ndarray:
    """A fixed, seeded set of hot pixels.

    Parameters
    ----------
    shape : (int, int)
    fraction : float in [0, 1]
        ``round(fraction * H * W)`` pixels are chosen, uniformly without replacement.
    rng : numpy.random.Generator

    Returns
    -------
    (H, W) bool ndarray
        True at the hot pixels.
    """
    height, width = _check_shape(shape)
    fraction = bounded("hot_pixel_mask", "fraction", fraction, high=1.0)
    rng = _check_rng(rng)
    mask = np.zeros(height * width, dtype=bool)
    mask[rng.choice(height * width, size=round(fraction * height * width), replace=False)] = True
    return mask.reshape(height, width)


def hot_pixel_events(t0_ns: int, t1_ns: int, hot_mask: np.ndarray, rate: float,
                     rng: np.random.Generator) -> np.ndarray:
    """ON events of the hot pixels in the interval ``[t0_ns, t1_ns)``.

    Parameters
    ----------
    t0_ns, t1_ns : int, nanoseconds
        The interval, ``t1_ns >= t0_ns``.
    hot_mask : (H, W) bool ndarray
        From :func:`hot_pixel_mask`.
    rate : float, Hz
        Poisson rate of each hot pixel.
    rng : numpy.random.Generator

    Returns
    -------
    (N,) structured ndarray
        ON events (``p`` = +1), sorted by ``t``; ties keep row-major pixel order.
    """
    t0_ns, t1_ns = _check_interval(t0_ns, t1_ns)
    hot_mask = np.asarray(hot_mask)
    if hot_mask.dtype != np.bool_ or hot_mask.ndim != 2:
        raise ValueError(f"hot_mask must be an (H, W) bool array, got {hot_mask.dtype} "
                         f"with shape {hot_mask.shape}")
    _check_shape(hot_mask.shape)
    rate = bounded("hot_pixel_events", "rate", rate)
    rng = _check_rng(rng)
    flat_index = np.flatnonzero(hot_mask)
    if t1_ns == t0_ns or rate == 0 or flat_index.size == 0:
        return np.empty(0, _EVENT_DTYPE)
    counts = rng.poisson(rate * ((t1_ns - t0_ns) * 1e-9), size=flat_index.size)
    return _poisson_events(t0_ns, t1_ns, flat_index, counts, hot_mask.shape, False, rng)


def _check_event_arrays(where: str, arrays) -> None:
    for i, array in enumerate(arrays):
        if not isinstance(array, np.ndarray) or array.dtype != _EVENT_DTYPE or array.ndim != 1:
            got = array.dtype if isinstance(array, np.ndarray) else type(array).__name__
            raise ValueError(f"argument {i} of {where} must be a 1-D event array with "
                             f"dtype {_EVENT_DTYPE}, got {got}")


def _merge_order(arrays: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray | None]:
    """The concatenation of the time-sorted ``arrays`` and the stable order that sorts it by
    ``t`` (None when at most one array is non-empty: already sorted)."""
    merged = np.concatenate(arrays) if arrays else np.empty(0, _EVENT_DTYPE)
    if sum(1 for a in arrays if len(a)) <= 1:
        return merged, None
    return merged, np.argsort(merged["t"], kind="stable")


def merge_events(*arrays: np.ndarray) -> np.ndarray:
    """Merge time-sorted event arrays into one, stably.

    Parameters
    ----------
    *arrays : (N_i,) structured ndarrays
        Each with the event dtype and sorted by ``t``.

    Returns
    -------
    (sum N_i,) structured ndarray
        Every input event, sorted by ``t``; events with equal times keep the order of the
        arguments (and their order within an argument).
    """
    _check_event_arrays("merge_events", arrays)
    merged, order = _merge_order(list(arrays))
    return merged if order is None else merged[order]


def merge_labelled_events(*parts: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`merge_events` of event arrays that carry one label each (their causes).

    Parameters
    ----------
    *parts : ((N_i,) structured ndarray, (N_i,) ndarray)
        Events sorted by ``t`` and their labels.

    Returns
    -------
    events : (sum N_i,) structured ndarray
        As :func:`merge_events` of the events.
    labels : (sum N_i,) ndarray
        Each merged event's label.
    """
    _check_event_arrays("merge_labelled_events", [events for events, _ in parts])
    for i, (events, labels) in enumerate(parts):
        if np.shape(labels) != (len(events),):
            raise ValueError(f"argument {i} of merge_labelled_events: {np.shape(labels)} labels "
                             f"for {len(events)} events; expected one label per event")
    merged, order = _merge_order([events for events, _ in parts])
    labels = (np.concatenate([np.asarray(labels) for _, labels in parts]) if parts
              else np.empty(0, np.uint8))
    return (merged, labels) if order is None else (merged[order], labels[order])
