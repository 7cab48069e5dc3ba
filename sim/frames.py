"""The standard (APS) camera: frame timing, motion-blur sampling and the 8-bit response.

A frame integrates the scene's linear luminance over its exposure (approximated by the mean of
renders at the centres of equal parts of it, see :func:`exposure_sample_times`: as many as the
image motion needs where frames are rendered pixel by pixel, :mod:`sim.frame_shader`, else
``exposure_samples``) and turns it into an 8-bit gray value through its sensor
(``FrameParams.sensor``):

* ``ideal`` (the default): :func:`luminance_to_frame`, no noise of any kind::

      x  = clip(gain * Y, 0, 1)                    normalised signal (1 = full scale)
      DN = clip(floor(255 * x ** (1 / gamma) + 0.5), 0, 255)   round half up, as uint8

  with the gain fixed for the sequence (``gain``, or :func:`auto_gain` of the first frame).
* a :class:`sim.frame_sensor.FrameSensor` (presets ``davis240c_aps``, ``machine_vision``):
  electrons, shot, read and dark noise, fixed-pattern noise, vignetting, auto-exposure; see
  :mod:`sim.frame_sensor`.

Frame k's exposure window is ``[k / rate, k / rate + exposure]`` and its timestamp the middle
of it, ``k / rate + exposure / 2`` (see :func:`frame_times`). A sensor with auto-exposure
chooses its own exposure ``e_k <= max_exposure`` per frame (``max_exposure`` defaults to
``exposure``), centred on the timestamp of a window laid out with ``max_exposure``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from sim.frame_sensor import FRAME_SENSORS, FrameSensor
from sim.validation import ParameterError, positive

__all__ = ["FRAME_SENSOR_NAMES", "WHOLE_FRAME_EXPOSURE_SAMPLES", "FrameParams", "auto_gain",
           "check_frame_sensor", "exposure_sample_times", "frame_times", "luminance_to_frame",
           "with_frame_sensor"]

AUTO_GAIN_PERCENTILE = 99.0
"""Percentile of the luminance that :func:`auto_gain` maps to ``AUTO_GAIN_LEVEL``."""
AUTO_GAIN_LEVEL = 0.8
"""Fraction of full scale (before the gamma response) that the percentile is mapped to."""
_TIME_TOLERANCE = 1e-9
"""Relative slack (in frame periods) for floating-point rounding in :func:`frame_times`."""
IDEAL = "ideal"
"""The noiseless frame camera of :func:`luminance_to_frame`."""
FRAME_SENSOR_NAMES = (IDEAL, *FRAME_SENSORS)
"""Every frame-sensor preset: ``ideal`` and the realistic ones of :mod:`sim.frame_sensor`."""
IDEAL_GAMMA = 2.2
"""The ideal camera's display gamma; a realistic sensor's output is linear (gamma 1)."""
WHOLE_FRAME_EXPOSURE_SAMPLES = 4
"""Renders a whole-frame exposure averages when ``exposure_samples`` is not given (frames of a
scene with moving objects, of a rolling shutter, or on ``scalar_rgb``)."""


@dataclass(frozen=True)
class FrameParams:
    """Parameters of the standard camera's frames.

    Attributes
    ----------
    rate : float, Hz
        Frame rate. The DAVIS240C frames of the ECD come at about 24 Hz.
    exposure : float, seconds
        Exposure time, > 0 and at most the frame period ``1 / rate``: the ``ideal`` camera's
        and a sensor's without auto-exposure.
    max_exposure : float or None, seconds
        The longest exposure a sensor's auto-exposure may choose, > 0 and at most ``1 / rate``;
        None (default): ``exposure``. Not used by the ``ideal`` camera or a sensor without
        auto-exposure (see :attr:`longest_exposure`).
    exposure_samples : int or None
        Times averaged over the exposure (motion blur), >= 1: the centres of as many equal
        parts of it. None (default): sized from the image motion during each exposure where
        frames are rendered pixel by pixel (:func:`sim.frame_shader.exposure_times`), else
        :data:`WHOLE_FRAME_EXPOSURE_SAMPLES`.
    gamma : float or None
        Output gamma: the 8-bit value is ``255 * x ** (1 / gamma)`` of the normalised signal x.
        None (default): the sensor's own, :data:`IDEAL_GAMMA` = 2.2 for ``ideal`` and 1 (linear
        raw values) for a realistic sensor; see :attr:`output_gamma`.
    gain : float or None
        ``ideal`` only: linear luminance -> normalised signal (1 = saturation); None =
        automatic (:func:`auto_gain` of the first frame, then fixed for the sequence). A
        realistic sensor's level is set by its exposure instead.
    sensor : str or FrameSensor
        ``ideal`` (default: :func:`luminance_to_frame`, no noise), a preset name of
        :data:`sim.frame_sensor.FRAME_SENSORS` (``davis240c_aps``, ``machine_vision``) or a
        :class:`~sim.frame_sensor.FrameSensor`. A name is replaced by its preset.
    """

    rate: float = 24.0
    exposure: float = 0.005
    exposure_samples: int | None = None
    gamma: float | None = None
    gain: float | None = None
    sensor: str | FrameSensor = IDEAL
    max_exposure: float | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "rate", positive("FrameParams.rate", self.rate))
        set_(self, "exposure", positive("FrameParams.exposure", self.exposure))
        if self.exposure > 1.0 / self.rate:
            raise ValueError(f"FrameParams.exposure must be at most the frame period 1/rate = "
                             f"{1.0 / self.rate} s, got {self.exposure} s")
        if self.max_exposure is not None:
            set_(self, "max_exposure", positive("FrameParams.max_exposure", self.max_exposure))
            if self.max_exposure > 1.0 / self.rate:
                raise ValueError(f"FrameParams.max_exposure must be at most the frame period "
                                 f"1/rate = {1.0 / self.rate} s, got {self.max_exposure} s")
        samples = self.exposure_samples
        if samples is not None:
            if (isinstance(samples, bool) or not isinstance(samples, int | np.integer)
                    or samples < 1):
                raise ValueError(f"FrameParams.exposure_samples must be an integer >= 1 or "
                                 f"None (sized from the motion), got {samples!r}")
            set_(self, "exposure_samples", int(samples))
        if self.gamma is not None:
            set_(self, "gamma", positive("FrameParams.gamma", self.gamma))
        if self.gain is not None:
            set_(self, "gain", positive("FrameParams.gain", self.gain))
        if isinstance(self.sensor, str):
            if self.sensor not in FRAME_SENSOR_NAMES:
                raise ValueError(f"FrameParams.sensor must be one of "
                                 f"{', '.join(FRAME_SENSOR_NAMES)} or a FrameSensor, got "
                                 f"{self.sensor!r}")
            if self.sensor != IDEAL:
                set_(self, "sensor", FRAME_SENSORS[self.sensor])
        elif not isinstance(self.sensor, FrameSensor):
            raise ValueError(f"FrameParams.sensor must be a preset name or a FrameSensor, got "
                             f"{self.sensor!r}")
        if self.gain is not None and not self.ideal:
            raise ValueError(f"FrameParams.gain is the ideal camera's luminance gain; sensor "
                             f"{self.sensor.name} sets its level by its exposure: leave gain "
                             "unset or use the ideal sensor")

    def with_sensor(self, sensor: str | FrameSensor) -> FrameParams:
        """These parameters with another sensor (the gamma, if unset, follows the sensor).

        Raises ValueError for an unknown preset, or a realistic sensor while ``gain`` is set.
        """
        return dataclasses.replace(self, sensor=sensor)

    @property
    def ideal(self) -> bool:
        """Whether the frames come from the noiseless :func:`luminance_to_frame`."""
        return self.sensor == IDEAL

    @property
    def sensor_name(self) -> str:
        """``ideal`` or the sensor's name."""
        return IDEAL if self.ideal else self.sensor.name

    @property
    def auto_exposure(self) -> bool:
        """Whether each frame's exposure is chosen by the sensor's auto-exposure."""
        return not self.ideal and self.sensor.auto_exposure

    @property
    def longest_exposure(self) -> float:
        """The longest exposure a frame may have, seconds: ``max_exposure`` (else ``exposure``)
        under auto-exposure, else ``exposure``. Frames are laid out with it
        (:func:`frame_times`)."""
        if self.auto_exposure and self.max_exposure is not None:
            return self.max_exposure
        return self.exposure

    @property
    def output_gamma(self) -> float:
        """``gamma`` if given, else 2.2 for ``ideal`` and 1.0 (linear) for a sensor."""
        if self.gamma is not None:
            return self.gamma
        return IDEAL_GAMMA if self.ideal else 1.0


def frame_times(duration: float, params: FrameParams) -> np.ndarray:
    """Mid-exposure timestamps of the frames that fit in ``[0, duration]``.

    Frame k's exposure is ``[k / rate, k / rate + exposure]``, so its timestamp is
    ``k / rate + exposure / 2``: the first exposure starts at t = 0 and frames are kept while
    the whole exposure ends by ``duration`` (up to floating-point rounding, 1e-9 of a frame
    period). No exposure falls outside ``[0, duration]``. ``exposure`` is
    :attr:`FrameParams.longest_exposure`: under auto-exposure a frame's own, shorter exposure
    is centred on the same timestamp.

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
    exposure = params.longest_exposure
    if duration < exposure:
        return np.zeros(0, dtype=np.float64)
    count = math.floor((duration - exposure) * params.rate + _TIME_TOLERANCE) + 1
    return np.arange(count, dtype=np.float64) / params.rate + exposure / 2


def exposure_sample_times(t_mid: float, params: FrameParams,
                          exposure: float | None = None, count: int | None = None) -> np.ndarray:
    """Render times whose average approximates one frame's exposure.

    The exposure ``[t_mid - exposure/2, t_mid + exposure/2]`` is cut into ``count`` equal
    sub-intervals and each is represented by its centre (midpoint rule), so a single
    sample is ``t_mid`` itself and no sample lies on the exposure's ends.

    Parameters
    ----------
    t_mid : float, seconds
        Mid-exposure timestamp of the frame.
    params : FrameParams
    exposure : float or None, seconds
        This frame's exposure (auto-exposure), at most :attr:`FrameParams.longest_exposure`;
        default that longest exposure (``params.exposure`` without auto-exposure).
    count : int or None
        Sub-intervals, >= 1; default ``params.exposure_samples``, else
        :data:`WHOLE_FRAME_EXPOSURE_SAMPLES`.

    Returns
    -------
    (count,) float64 ndarray, seconds
        Increasing times, symmetric about ``t_mid``.
    """
    t_mid = float(t_mid)
    if not math.isfinite(t_mid):
        raise ValueError(f"t_mid must be a finite time in seconds, got {t_mid}")
    longest = params.longest_exposure
    exposure = longest if exposure is None else positive("exposure", exposure)
    if exposure > longest * (1 + _TIME_TOLERANCE):
        raise ValueError(f"exposure {exposure} s is longer than the frame's longest exposure "
                         f"{longest} s")
    n = count or params.exposure_samples or WHOLE_FRAME_EXPOSURE_SAMPLES
    offsets = (np.arange(n, dtype=np.float64) + 0.5) / n - 0.5
    return t_mid + exposure * offsets


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


def luminance_to_frame(luminance: np.ndarray, gain: float, params: FrameParams) -> np.ndarray:
    """The ideal camera's 8-bit frame from the luminance it integrated (no noise).

    See the module docstring for the model. Computed in float64.

    Parameters
    ----------
    luminance : (H, W) float32 ndarray, linear luminance >= 0
        Already averaged over the exposure.
    gain : float
        Linear luminance -> normalised signal, > 0 (``params.gain`` or :func:`auto_gain`).
    params : FrameParams
        Gives the gamma (:attr:`FrameParams.output_gamma`); ``params.gain`` is not used here:
        pass it as ``gain``.

    Returns
    -------
    (H, W) uint8 ndarray
        Gray values, rounded half up and clipped to [0, 255].
    """
    array = _check_luminance(luminance)
    gain = positive("gain", gain)
    signal = np.clip(gain * array.astype(np.float64), 0.0, 1.0)
    value = 255.0 * signal ** (1.0 / params.output_gamma)
    return np.clip(np.floor(value + 0.5), 0, 255).astype(np.uint8)


def check_frame_sensor(sensor: str | FrameSensor) -> str | FrameSensor:
    """A frame sensor as a caller names it: a :class:`FrameSensor`, or a preset's name.

    Parameters
    ----------
    sensor : str or FrameSensor

    Returns
    -------
    str or FrameSensor
        ``sensor``.

    Raises
    ------
    ParameterError
        A name not among :data:`FRAME_SENSOR_NAMES`; the parameter is ``frame_sensor``.
    """
    if isinstance(sensor, FrameSensor) or (isinstance(sensor, str)
                                           and sensor in FRAME_SENSOR_NAMES):
        return sensor
    raise ParameterError(f"{{frame_sensor}} {ParameterError.literal(repr(sensor))}: expected "
                         f"one of {', '.join(FRAME_SENSOR_NAMES)}", frame_sensor="frame_sensor")


def with_frame_sensor(scene, sensor: str | FrameSensor):
    """A scene with its standard camera's sensor replaced.

    Parameters
    ----------
    scene : sim.scene.Scene
        Any object with a ``frames`` (:class:`FrameParams`) field, a frozen dataclass.
    sensor : str or FrameSensor
        One of :data:`FRAME_SENSOR_NAMES`, or a sensor.

    Returns
    -------
    sim.scene.Scene
        A copy with ``frames.with_sensor(sensor)`` (:meth:`FrameParams.with_sensor`).

    Raises
    ------
    ParameterError
        An unknown preset (:func:`check_frame_sensor`), or a sensor the scene's frames refuse (a
        realistic one while their ``gain`` is set); the parameter is ``frame_sensor``.
    """
    check_frame_sensor(sensor)
    try:
        return dataclasses.replace(scene, frames=scene.frames.with_sensor(sensor))
    except ValueError as exc:
        name = sensor if isinstance(sensor, str) else sensor.name
        raise ParameterError(f"{{frame_sensor}} {ParameterError.literal(name)}: "
                             f"{ParameterError.literal(exc)}",
                             frame_sensor="frame_sensor") from None
