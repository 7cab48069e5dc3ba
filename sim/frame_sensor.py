"""A physical model of the standard camera's sensor: electrons, noise, fixed pattern, exposure.

The ``ideal`` frame camera (:func:`sim.frames.luminance_to_frame`) maps luminance to gray values
through a gain and no noise. A :class:`FrameSensor` instead counts electrons, as a DAVIS's APS
or a machine-vision camera does. For a pixel (u, v) with luminance L (cd/m^2, averaged over the
exposure) and an exposure of t seconds::

    rate  = R * L * G(u, v)                          photo-electrons per second
    Q     = min(Poisson((rate + I_dark) * t), FW)   collected charge, e- (shot noise of the
                                                    signal and of the dark current; the well
                                                    overflows at its full well FW)
    S     = Q + O_col(u) + O_pix(u, v) + N(0, sigma_read^2)      e-
    x     = S / FW                                  fraction of full scale
    DN    = clip(floor(255 * clip(x, 0, 1) ** (1 / gamma) + 0.5), 0, 255)   uint8

* ``R`` is the responsivity (e-/s per cd/m^2, :attr:`FrameSensor.responsivity_e`): a lens of
  f-number N and transmittance tau makes an image-plane illuminance
  ``E = pi * tau * L / (4 N^2)`` lux (camera equation, object far away, on the axis); a pixel of
  pitch p receives ``E * p^2 * K`` photons per second, with ``K = lambda / (683 lm/W * h * c)``
  = 4.09e15 photons s^-1 m^-2 lx^-1 at lambda = 555 nm (:data:`PHOTONS_PER_LUX_SECOND_M2`), and
  turns a fraction eta (quantum efficiency x fill factor) of them into electrons::

      R = eta * p^2 * K * pi * tau / (4 N^2)

  Light of another spectrum gives a different number of photons per lux (white light about 2-3
  times more than 555 nm): that factor is folded into eta. ``responsivity`` overrides the
  formula.
* ``G(u, v) = V(u, v) * (1 + PRNU(u, v))``: vignetting times the pixel's gain (photo-response
  non-uniformity). ``V = cos^4(theta)``, theta the angle of the pixel's ray from the optical
  axis in the pinhole model, ``cos(theta) = 1 / sqrt(1 + ((u - cx) / fx)^2 + ((v - cy) / fy)^2)``
  (natural vignetting; lens distortion ignored), or 1 with ``vignetting = "none"``.
* ``O_col``, ``O_pix`` (column and pixel offsets, e-) and ``PRNU`` are the fixed-pattern noise:
  drawn once per sensor from its seed (:func:`fixed_pattern`), the same in every frame.
* The conversion gain is ``255 / FW`` DN per electron: an 8-bit ADC that spans the well. Noise
  that takes the signal below 0 clips at 0 DN (no black-level pedestal).

Auto-exposure (:func:`next_exposure`), like a DAVIS's APS under libcaer's auto-exposure or a
machine-vision camera's "exposure auto": after each frame the camera measures the mean level of
that frame, ``m = mean((DN / 255) ** gamma)`` (linear, fraction of full scale), and sets the next
frame's exposure to ``t * clip(AE_TARGET / m, 1 / AE_MAX_STEP, AE_MAX_STEP)``, clipped to
``[min_exposure, max_exposure]``: a proportional controller towards a mean of
:data:`AE_TARGET` = 0.4 of full scale that changes by at most a factor :data:`AE_MAX_STEP` = 2
per frame (a saturated or black frame says only "too much" or "too little"). The first frame's
exposure is the controller's settled value on that frame's view (:func:`settled_exposure`): the
camera was running before the recording began.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.validation import non_negative, positive

__all__ = ["AE_MAX_STEP", "AE_TARGET", "FRAME_SENSORS", "PHOTONS_PER_LUX_SECOND_M2",
           "FixedPattern", "FrameSensor", "fixed_pattern", "next_exposure", "sensor_frame",
           "settled_exposure", "vignetting_map"]

PHOTONS_PER_LUX_SECOND_M2 = 555e-9 / (683.0 * 6.62607015e-34 * 299792458.0)
"""Photons per second and square metre in one lux of 555 nm light: lambda / (683 lm/W h c)."""
AE_TARGET = 0.4
"""Mean level (linear, fraction of full scale) the auto-exposure steers each frame to."""
AE_MAX_STEP = 2.0
"""Largest factor by which auto-exposure changes the exposure from one frame to the next."""
AE_SETTLE_ITERATIONS = 40
"""Controller steps on the first view that :func:`settled_exposure` runs (2^40 covers any
plausible distance from the initial exposure; the rule converges in one step once unsaturated)."""
VIGNETTING = ("cos4", "none")
"""Vignetting models: natural cos^4 falloff from the intrinsics, or none."""


@dataclass(frozen=True)
class FrameSensor:
    """A frame camera's sensor; see the module docstring for the model.

    Attributes
    ----------
    name : str
        Preset it came from (``davis240c_aps``, ``machine_vision``) or ``custom``.
    pixel_pitch : float, metres
    f_number : float
        Of the lens.
    quantum_efficiency : float in (0, 1]
        Quantum efficiency times fill factor, at 555 nm.
    lens_transmittance : float in (0, 1]
    responsivity : float or None, e-/s per cd/m^2
        None: from the optics (:attr:`responsivity_e`); a number overrides the formula.
    full_well : float, electrons
        Charge at saturation; the 8-bit full scale.
    read_noise : float, electrons rms
        Temporal noise of the readout, drawn anew in every frame.
    dark_current : float, electrons / second
        With its own shot noise (Poisson, with the signal's).
    column_fpn, pixel_fpn : float, electrons rms
        Fixed offsets of each column and of each pixel (dark-signal non-uniformity).
    prnu : float, fraction rms in [0, 0.5)
        Fixed per-pixel gain spread (photo-response non-uniformity).
    vignetting : str
        ``cos4`` or ``none``.
    auto_exposure : bool
        Choose each frame's exposure from the previous frame (module docstring); the scene's
        ``[frames] max_exposure`` (default its ``exposure``) is then the longest exposure
        allowed.
    min_exposure : float, seconds
        Shortest exposure auto-exposure may choose.
    """

    name: str = "custom"
    pixel_pitch: float = 18.5e-6
    f_number: float = 2.0
    quantum_efficiency: float = 0.1
    lens_transmittance: float = 0.9
    responsivity: float | None = None
    full_well: float = 20000.0
    read_noise: float = 56.0
    dark_current: float = 2000.0
    column_fpn: float = 60.0
    pixel_fpn: float = 80.0
    prnu: float = 0.01
    vignetting: str = "cos4"
    auto_exposure: bool = True
    min_exposure: float = 1e-5

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"FrameSensor.name must be a non-empty string, got {self.name!r}")
        for field in ("pixel_pitch", "f_number", "full_well", "min_exposure"):
            set_(self, field, positive(f"FrameSensor.{field}", getattr(self, field)))
        for field in ("quantum_efficiency", "lens_transmittance"):
            value = positive(f"FrameSensor.{field}", getattr(self, field))
            if value > 1:
                raise ValueError(f"FrameSensor.{field} must be a fraction in (0, 1], got {value}")
            set_(self, field, value)
        for field in ("read_noise", "dark_current", "column_fpn", "pixel_fpn", "prnu"):
            set_(self, field, non_negative(f"FrameSensor.{field}", getattr(self, field)))
        if self.prnu >= 0.5:
            raise ValueError(f"FrameSensor.prnu must be a fraction in [0, 0.5), got {self.prnu}")
        if self.responsivity is not None:
            set_(self, "responsivity", positive("FrameSensor.responsivity", self.responsivity))
        if self.vignetting not in VIGNETTING:
            raise ValueError(f"FrameSensor.vignetting must be one of {', '.join(VIGNETTING)}, "
                             f"got {self.vignetting!r}")
        if not isinstance(self.auto_exposure, bool):
            raise ValueError(f"FrameSensor.auto_exposure must be true or false, got "
                             f"{self.auto_exposure!r}")

    @property
    def responsivity_e(self) -> float:
        """Photo-electrons per second per cd/m^2 of scene luminance, on the axis.

        ``responsivity`` if given, else ``eta p^2 K pi tau / (4 N^2)`` (module docstring).
        """
        if self.responsivity is not None:
            return self.responsivity
        image_lux_per_cd_m2 = math.pi * self.lens_transmittance / (4.0 * self.f_number ** 2)
        return (self.quantum_efficiency * self.pixel_pitch ** 2 * PHOTONS_PER_LUX_SECOND_M2
                * image_lux_per_cd_m2)


_DAVIS_DR_DB = 51.0
_DAVIS_FULL_WELL = 20000.0
_DAVIS_FPN = 0.005
FRAME_SENSORS: dict[str, FrameSensor] = {
    # DAVIS240C APS. Published (Brandli et al., "A 240x180 130 dB 3 us latency global shutter
    # spatiotemporal vision sensor", IEEE JSSC 49(10), 2014, abstract): 18.5 um pixels, APS
    # dynamic range 51 dB, APS FPN 0.5 %. Assumed, not found published: full well 20 ke-; read
    # noise from the dynamic range, 20 ke- / 10^(51/20) = 56 e-; the 0.5 % FPN (of full
    # scale, 100 e-) split into 0.4 % per pixel (80 e-) and 0.3 % per column (60 e-), which add
    # in quadrature to 0.5 %; PRNU 1 %; dark current 2,000 e-/s; QE x fill factor 0.1; an f/2
    # lens of transmittance 0.9 (R = 2.5e4 e-/s per cd/m^2).
    "davis240c_aps": FrameSensor(
        name="davis240c_aps", pixel_pitch=18.5e-6, f_number=2.0, quantum_efficiency=0.1,
        lens_transmittance=0.9, full_well=_DAVIS_FULL_WELL,
        read_noise=round(_DAVIS_FULL_WELL / 10 ** (_DAVIS_DR_DB / 20.0), 1),
        dark_current=2000.0, column_fpn=0.6 * _DAVIS_FPN * _DAVIS_FULL_WELL,
        pixel_fpn=0.8 * _DAVIS_FPN * _DAVIS_FULL_WELL, prnu=0.01, vignetting="cos4",
        auto_exposure=True, min_exposure=1e-5),
    # A global-shutter machine-vision CMOS of the Sony Pregius class (IMX250 / IMX264): values
    # typical of the EMVA 1288 sheets of cameras built on them, rounded and quoted from memory,
    # not checked against a sheet here: 3.45 um pixels, QE 0.65 near 550 nm, full well 10.5 ke-,
    # temporal dark noise 2.4 e-, dark current 5 e-/s, DSNU 2 e- (pixel) and 1 e- (column),
    # PRNU 0.5 %; an f/2 lens of transmittance 0.9 (R = 5.6e3 e-/s per cd/m^2).
    "machine_vision": FrameSensor(
        name="machine_vision", pixel_pitch=3.45e-6, f_number=2.0, quantum_efficiency=0.65,
        lens_transmittance=0.9, full_well=10500.0, read_noise=2.4, dark_current=5.0,
        column_fpn=1.0, pixel_fpn=2.0, prnu=0.005, vignetting="cos4", auto_exposure=True,
        min_exposure=1.5e-5),
}
"""The realistic presets, by name (``ideal`` is :func:`sim.frames.luminance_to_frame`)."""


@dataclass(frozen=True)
class FixedPattern:
    """A sensor's fixed-pattern noise and vignetting, the same in every frame.

    Attributes
    ----------
    gain : (H, W) float64 ndarray
        Vignetting times (1 + PRNU): multiplies the photo-electron rate.
    offset : (H, W) float64 ndarray, electrons
        Column offset plus pixel offset.
    """

    gain: np.ndarray
    offset: np.ndarray


def vignetting_map(sensor: FrameSensor, width: int, height: int, fx: float, fy: float,
                   cx: float, cy: float) -> np.ndarray:
    """Relative illumination of each pixel, 1 on the optical axis.

    Parameters
    ----------
    sensor : FrameSensor
    width, height : int, pixels
    fx, fy, cx, cy : float, pixels
        Pinhole intrinsics (pixel centres at integer coordinates, as OpenCV).

    Returns
    -------
    (height, width) float64 ndarray
        ``cos^4(theta)`` with ``cos(theta) = 1 / sqrt(1 + ((u - cx)/fx)^2 + ((v - cy)/fy)^2)``,
        or ones for ``vignetting = "none"``.
    """
    if sensor.vignetting == "none":
        return np.ones((height, width), np.float64)
    x = (np.arange(width, dtype=np.float64) - cx) / fx
    y = (np.arange(height, dtype=np.float64) - cy) / fy
    tan2 = x[None, :] ** 2 + y[:, None] ** 2
    return 1.0 / (1.0 + tan2) ** 2                   # cos^4 = (1 / (1 + tan^2))^2


def fixed_pattern(sensor: FrameSensor, vignetting: np.ndarray, seed: int) -> FixedPattern:
    """Draw a sensor's fixed-pattern noise from its seed.

    Parameters
    ----------
    sensor : FrameSensor
    vignetting : (H, W) float ndarray
        :func:`vignetting_map` of the camera.
    seed : int
        The sensor's identity: the same seed gives the same pattern, another seed another.

    Returns
    -------
    FixedPattern
        Column offsets ~ N(0, column_fpn^2) (one per column), pixel offsets
        ~ N(0, pixel_fpn^2), gains ``vignetting * max(1 + N(0, prnu^2), 0)``.
    """
    vignetting = np.asarray(vignetting, np.float64)
    if vignetting.ndim != 2 or vignetting.size == 0:
        raise ValueError(f"vignetting must be a non-empty (H, W) array, got shape "
                         f"{vignetting.shape}")
    height, width = vignetting.shape
    rng = np.random.default_rng([int(seed), 0x46504E])          # "FPN": a stream of its own
    column = rng.normal(0.0, 1.0, width) * sensor.column_fpn
    pixel = rng.normal(0.0, 1.0, (height, width)) * sensor.pixel_fpn
    prnu = np.maximum(1.0 + rng.normal(0.0, 1.0, (height, width)) * sensor.prnu, 0.0)
    return FixedPattern(gain=vignetting * prnu, offset=column[None, :] + pixel)


def _luminance(luminance: np.ndarray, pattern: FixedPattern) -> np.ndarray:
    array = np.asarray(luminance)
    if array.shape != pattern.gain.shape:
        raise ValueError(f"luminance has shape {array.shape}; the sensor's fixed pattern is "
                         f"{pattern.gain.shape}")
    if not np.issubdtype(array.dtype, np.floating):
        raise ValueError(f"luminance must be floating point (cd/m^2), got dtype {array.dtype}")
    if not np.isfinite(array).all() or (array < 0).any():
        raise ValueError("luminance must be finite and >= 0 (cd/m^2)")
    return array.astype(np.float64)


def _mean_electrons(luminance: np.ndarray, exposure: float, sensor: FrameSensor,
                    pattern: FixedPattern) -> np.ndarray:
    rate = sensor.responsivity_e * _luminance(luminance, pattern) * pattern.gain
    return (rate + sensor.dark_current) * exposure


def sensor_frame(luminance: np.ndarray, exposure: float, sensor: FrameSensor,
                 pattern: FixedPattern, gamma: float, rng: np.random.Generator) -> np.ndarray:
    """The 8-bit frame a sensor reads out after an exposure (module docstring's model).

    Parameters
    ----------
    luminance : (H, W) float ndarray, cd/m^2
        Scene luminance at each pixel, averaged over the exposure.
    exposure : float, seconds
    sensor : FrameSensor
    pattern : FixedPattern
        :func:`fixed_pattern` of this sensor, shape (H, W).
    gamma : float
        Output gamma: 1 for the linear raw values of a DAVIS or a machine-vision camera.
    rng : numpy.random.Generator
        Source of this frame's temporal noise (shot and read noise).

    Returns
    -------
    (H, W) uint8 ndarray
    """
    exposure = positive("exposure", exposure)
    gamma = positive("gamma", gamma)
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {rng!r}")
    well = sensor.full_well
    # Expected counts are capped 10 standard deviations above the well, which overflows anyway.
    expected = np.minimum(_mean_electrons(luminance, exposure, sensor, pattern),
                          well + 10.0 * math.sqrt(well) + 10.0)
    charge = np.minimum(rng.poisson(expected).astype(np.float64), well)
    signal = charge + pattern.offset
    if sensor.read_noise > 0:
        signal = signal + rng.normal(0.0, sensor.read_noise, size=signal.shape)
    value = 255.0 * np.clip(signal / well, 0.0, 1.0) ** (1.0 / gamma)
    return np.clip(np.floor(value + 0.5), 0, 255).astype(np.uint8)


def next_exposure(frame: np.ndarray, exposure: float, sensor: FrameSensor, gamma: float,
                  max_exposure: float) -> float:
    """Auto-exposure: the next frame's exposure from this frame (module docstring's rule).

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
        The frame just read out.
    exposure : float, seconds
        Its exposure.
    sensor : FrameSensor
        Gives ``min_exposure``.
    gamma : float
        The output gamma the frame was encoded with (undone to measure the linear level).
    max_exposure : float, seconds

    Returns
    -------
    float, seconds
        ``exposure * clip(AE_TARGET / m, 1 / AE_MAX_STEP, AE_MAX_STEP)`` clipped to
        ``[min_exposure, max_exposure]``; ``m`` the frame's mean linear level.
    """
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 2:
        raise ValueError(f"frame must be an (H, W) uint8 array, got {frame.dtype} "
                         f"{frame.shape}")
    level = float(np.mean((frame.astype(np.float64) / 255.0) ** positive("gamma", gamma)))
    return _step(level, exposure, sensor, max_exposure)


def _step(level: float, exposure: float, sensor: FrameSensor, max_exposure: float) -> float:
    ratio = AE_TARGET / level if level > 0 else AE_MAX_STEP
    ratio = min(max(ratio, 1.0 / AE_MAX_STEP), AE_MAX_STEP)
    return min(max(exposure * ratio, sensor.min_exposure), max_exposure)


def settled_exposure(luminance: np.ndarray, sensor: FrameSensor, pattern: FixedPattern,
                     max_exposure: float) -> float:
    """The exposure auto-exposure settles on for a still view (the first frame's exposure).

    Runs the rule of :func:`next_exposure` :data:`AE_SETTLE_ITERATIONS` times from
    ``max_exposure`` on the noise-free level of the view, ``mean(clip(Q + O, 0, FW)) / FW``
    with ``Q = min(E[electrons], FW)``.

    Parameters
    ----------
    luminance : (H, W) float ndarray, cd/m^2
    sensor : FrameSensor
    pattern : FixedPattern
    max_exposure : float, seconds

    Returns
    -------
    float, seconds
        In ``[min_exposure, max_exposure]``.
    """
    max_exposure = positive("max_exposure", max_exposure)
    per_second = _mean_electrons(luminance, 1.0, sensor, pattern)
    well = sensor.full_well
    exposure = max_exposure
    for _ in range(AE_SETTLE_ITERATIONS):
        charge = np.minimum(per_second * exposure, well)
        level = float(np.mean(np.clip(charge + pattern.offset, 0.0, well))) / well
        exposure = _step(level, exposure, sensor, max_exposure)
    return exposure
