"""The standard (APS) camera: frame timing, motion-blur sampling and the 8-bit response.

A frame integrates the scene's linear luminance over its exposure (approximated by averaging
``exposure_samples`` renders, see :func:`exposure_sample_times`) and turns it into an 8-bit
gray value through :func:`luminance_to_frame`::

    x  = gain * Y                                 normalised signal (1 = full well)
    x <- Poisson(x * full_well) / full_well       shot noise, if full_well > 0
    x <- clip(x, 0, 1)                            the well saturates
    v  = 255 * x ** (1 / gamma) + N(0, read_noise^2)
    DN = clip(floor(v + 0.5), 0, 255)             round half up, as uint8

Frame k's exposure starts at ``k / rate`` and lasts ``exposure`` seconds; its timestamp is the
middle of the exposure, ``k / rate + exposure / 2`` (see :func:`frame_times`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FrameParams", "auto_gain", "exposure_sample_times", "frame_times",
           "luminance_to_frame"]

AUTO_GAIN_PERCENTILE = 99.0
"""Percentile of the luminance that :func:`auto_gain` maps to ``AUTO_GAIN_LEVEL``."""
AUTO_GAIN_LEVEL = 0.8
"""Fraction of full scale (before the gamma response) that the percentile is mapped to."""
_TIME_TOLERANCE = 1e-9
"""Relative slack (in frame periods) for floating-point rounding in :func:`frame_times`."""


def _positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ValueError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value}")
    return value


def _non_negative(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ValueError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value}")
    return value


@dataclass(frozen=True)
class FrameParams:
    """Parameters of the standard camera's frames.

    Attributes
    ----------
    rate : float, Hz
        Frame rate. The DAVIS240C frames of the ECD come at about 24 Hz.
    exposure : float, seconds
        Exposure time, > 0 and at most the frame period ``1 / rate``.
    exposure_samples : int
        Renders averaged over the exposure (motion blur), >= 1.
    gamma : float
        Display gamma: the 8-bit value is ``255 * clip(gain * Y, 0, 1) ** (1 / gamma)``.
    gain : float or None
        Linear luminance -> normalised signal (1 = saturation); None = automatic
        (:func:`auto_gain` of the first frame, then fixed for the sequence).
    full_well : float, electrons
        Electrons at saturation, for Poisson shot noise; 0 = no shot noise.
    read_noise : float, DN
        Standard deviation of Gaussian read noise in 8-bit digital numbers; 0 = none.
    """

    rate: float = 24.0
    exposure: float = 0.005
    exposure_samples: int = 4
    gamma: float = 2.2
    gain: float | None = None
    full_well: float = 0.0
    read_noise: float = 0.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "rate", _positive("FrameParams.rate", self.rate))
        set_(self, "exposure", _positive("FrameParams.exposure", self.exposure))
        if self.exposure > 1.0 / self.rate:
            raise ValueError(f"FrameParams.exposure must be at most the frame period 1/rate = "
                             f"{1.0 / self.rate} s, got {self.exposure} s")
        samples = self.exposure_samples
        if isinstance(samples, bool) or not isinstance(samples, int | np.integer) or samples < 1:
            raise ValueError(f"FrameParams.exposure_samples must be an integer >= 1, "
                             f"got {samples!r}")
        set_(self, "exposure_samples", int(samples))
        set_(self, "gamma", _positive("FrameParams.gamma", self.gamma))
        if self.gain is not None:
            set_(self, "gain", _positive("FrameParams.gain", self.gain))
        set_(self, "full_well", _non_negative("FrameParams.full_well", self.full_well))
        set_(self, "read_noise", _non_negative("FrameParams.read_noise", self.read_noise))


def frame_times(duration: float, params: FrameParams) -> np.ndarray:
    """Mid-exposure timestamps of the frames that fit in ``[0, duration]``.

    Frame k's exposure is ``[k / rate, k / rate + exposure]``, so its timestamp is
    ``k / rate + exposure / 2``: the first exposure starts at t = 0 and frames are kept while
    the whole exposure ends by ``duration`` (up to floating-point rounding, 1e-9 of a frame
    period). No exposure falls outside ``[0, duration]``.

    Parameters
    ----------
    duration : float, seconds
        Length of the simulated interval, >= 0.
    params : FrameParams

    Returns
    -------
    (N,) float64 ndarray, seconds
        Increasing timestamps; empty when ``duration < exposure``.
    """
    duration = float(duration)
    if not (math.isfinite(duration) and duration >= 0):
        raise ValueError(f"duration must be a finite number of seconds >= 0, got {duration}")
    if duration < params.exposure:
        return np.zeros(0, dtype=np.float64)
    count = math.floor((duration - params.exposure) * params.rate + _TIME_TOLERANCE) + 1
    return np.arange(count, dtype=np.float64) / params.rate + params.exposure / 2


def exposure_sample_times(t_mid: float, params: FrameParams) -> np.ndarray:
    """Render times whose average approximates one frame's exposure.

    The exposure ``[t_mid - exposure/2, t_mid + exposure/2]`` is cut into ``exposure_samples``
    equal sub-intervals and each is represented by its centre (midpoint rule), so a single
    sample is ``t_mid`` itself and no sample lies on the exposure's ends.

    Parameters
    ----------
    t_mid : float, seconds
        Mid-exposure timestamp of the frame.
    params : FrameParams

    Returns
    -------
    (exposure_samples,) float64 ndarray, seconds
        Increasing times, symmetric about ``t_mid``.
    """
    t_mid = float(t_mid)
    if not math.isfinite(t_mid):
        raise ValueError(f"t_mid must be a finite time in seconds, got {t_mid}")
    n = params.exposure_samples
    offsets = (np.arange(n, dtype=np.float64) + 0.5) / n - 0.5
    return t_mid + params.exposure * offsets


def _check_luminance(luminance: np.ndarray) -> np.ndarray:
    array = np.asarray(luminance)
    if array.ndim != 2 or array.size == 0:
        raise ValueError(f"luminance must be a non-empty (H, W) array, got shape {array.shape}")
    if not np.issubdtype(array.dtype, np.floating):
        raise ValueError(f"luminance must be floating point (linear), got dtype {array.dtype}")
    if not np.isfinite(array).all():
        raise ValueError(f"luminance has {int((~np.isfinite(array)).sum())} NaN or infinite "
                         "pixel(s); expected finite linear luminance >= 0")
    if (array < 0).any():
        raise ValueError(f"luminance has {int((array < 0).sum())} negative pixel(s), minimum "
                         f"{float(array.min())}; expected linear luminance >= 0")
    return array


def auto_gain(luminance: np.ndarray) -> float:
    """Gain that maps the 99th percentile of the luminance to 0.8 of full scale.

    A few specular highlights (under 1 % of the pixels) may saturate; the rest of the image
    keeps headroom.

    Parameters
    ----------
    luminance : (H, W) float ndarray, linear luminance >= 0

    Returns
    -------
    float
        ``0.8 / percentile_99``. If the percentile is 0 but some pixels are lit, the maximum is
        used instead (a mostly black image with a small bright object); for an all-black image
        there is nothing to expose for and the gain is 1.0.
    """
    array = _check_luminance(luminance)
    level = float(np.percentile(array, AUTO_GAIN_PERCENTILE))
    if level <= 0:
        level = float(array.max())
    if level <= 0:
        return 1.0
    return AUTO_GAIN_LEVEL / level


def luminance_to_frame(luminance: np.ndarray, gain: float, params: FrameParams,
                       rng: np.random.Generator | None) -> np.ndarray:
    """The standard camera's 8-bit frame from the luminance it integrated.

    See the module docstring for the model. Computed in float64.

    Parameters
    ----------
    luminance : (H, W) float32 ndarray, linear luminance >= 0
        Already averaged over the exposure.
    gain : float
        Linear luminance -> normalised signal, > 0 (``params.gain`` or :func:`auto_gain`).
    params : FrameParams
        Gamma and noise levels (``params.gain`` is not used here: pass it as ``gain``).
    rng : numpy.random.Generator or None
        Source of the noise. Not drawn from when ``full_well == 0`` and ``read_noise == 0``
        (then the frame does not depend on it and None is allowed).

    Returns
    -------
    (H, W) uint8 ndarray
        Gray values, rounded half up and clipped to [0, 255].
    """
    array = _check_luminance(luminance)
    gain = _positive("gain", gain)
    noisy = params.full_well > 0 or params.read_noise > 0
    if noisy and not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator when noise is on (full_well = "
                         f"{params.full_well}, read_noise = {params.read_noise}), got {rng!r}")
    signal = gain * array.astype(np.float64)
    if params.full_well > 0:
        # The well fills with Poisson(expected) electrons and overflows at full_well, so an
        # overexposed pixel saturates rather than scattering around full scale. Expected counts
        # are capped 10 standard deviations above the well, where the well overflows anyway.
        well = params.full_well
        expected = np.minimum(signal * well, well + 10.0 * math.sqrt(well) + 10.0)
        signal = rng.poisson(expected) / well
    signal = np.clip(signal, 0.0, 1.0)
    value = 255.0 * signal ** (1.0 / params.gamma)
    if params.read_noise > 0:
        value = value + rng.normal(0.0, params.read_noise, size=value.shape)
    return np.clip(np.floor(value + 0.5), 0, 255).astype(np.uint8)
