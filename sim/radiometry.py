"""Physical units of light: scene illuminance, rendered luminance, a pixel's photocurrent.

evfuse renders in photometric units. A scene's lights are declared in lux (a directional light's
illuminance on a surface facing it, TOML key ``illuminance_lux``) and candela (a point or spot
light's luminous intensity, ``intensity_cd``); the renderer is linear in them, so what it returns
is LUMINANCE IN cd/m^2. A white Lambertian surface of albedo ``rho`` under illuminance ``E`` lux
has luminance ``rho E / pi`` cd/m^2 (:func:`lambertian_luminance`; tested through the renderer).
A light given as an RGB triple is in lux (or cd) per channel; its luminance-weighted sum
(Rec. 709 weights, what ``mi.luminance`` uses) is its photometric value, and a grey number is the
photometric value itself.

A camera turns scene luminance ``L`` into illuminance on its sensor by the camera equation (on
axis, no vignetting, object far compared with the focal length)::

    E_image = pi T L / (4 N^2)   lux                                  (image_illuminance)

and a photodiode of area ``A`` turns it into a photocurrent ``I = E_image A S`` with ``S`` the
silicon's responsivity to white light in A/lm. The product is one number per camera, its
responsivity ``R`` in A per cd/m^2 (:func:`responsivity`), so that ``I = R L``
(:func:`photocurrent`); ``I / q`` electrons per second (:data:`ELEMENTARY_CHARGE`) for a
frame camera's well.

The event camera (:class:`sim.events.EventParams`) takes the log of photocurrent plus dark
current, ``log(R Y + I_dark)``. It computes ``log(Y + log_eps)`` with ``log_eps = I_dark / R``,
the dark current expressed as the luminance whose photocurrent equals it
(:data:`DVS_DARK_LUMINANCE`): the two differ by the constant ``log R``, which moves no threshold
crossing, so the events are the same (tested).

The DAVIS240C numbers below are ORDER-OF-MAGNITUDE assumptions, not a calibration: each is
stated with its source or reasoning, and together they put the DVS's dark-current floor at a
chip illuminance of about 0.08 lux, the low end of the 120-130 dB dynamic range published DVS
pixels reach below ~100 klux (Lichtsteiner et al., JSSC 2008; Brandli et al., JSSC 2014).
"""

from __future__ import annotations

import math

import numpy as np

from sim.validation import bounded

__all__ = [
    "DAVIS240C_F_NUMBER",
    "DAVIS240C_PHOTODIODE_AREA",
    "DVS_DARK_CURRENT",
    "DVS_DARK_LUMINANCE",
    "DVS_RESPONSIVITY",
    "ELEMENTARY_CHARGE",
    "LENS_TRANSMISSION",
    "OFFICE_WHITE_LUMINANCE",
    "SILICON_RESPONSIVITY",
    "image_illuminance",
    "lambertian_luminance",
    "photocurrent",
    "responsivity",
]

ELEMENTARY_CHARGE = 1.602176634e-19
"""Coulombs per electron (exact, SI 2019): a photocurrent ``I`` fills a well with ``I / q``
electrons per second."""

SILICON_RESPONSIVITY = 7e-4
"""A/lm: photocurrent of a silicon photodiode per lumen of white light falling on it. A quantum
efficiency of about 0.5 over the visible gives ``0.5 q lambda / (h c)`` = 0.22 A/W at 550 nm;
white light (daylight, white LEDs) carries about 300 lm per watt of radiation: 7e-4 A/lm,
good to a factor 2 across common light sources."""

LENS_TRANSMISSION = 0.9
"""Share of the light entering the lens that reaches the sensor (a coated lens), used by
:func:`image_illuminance` by default."""

DAVIS240C_F_NUMBER = 2.0
"""f-number assumed for the DAVIS240C's lens (the ECD does not publish it; event cameras are
mostly used at f/1.4 to f/2.8)."""

DAVIS240C_PHOTODIODE_AREA = 0.22 * (18.5e-6) ** 2
"""m^2: the DAVIS240C's 18.5 um pixel (Brandli et al., JSSC 2014) at an assumed 22 % fill
factor (no microlenses), 7.5e-11 m^2."""

DVS_DARK_CURRENT = 4e-15
"""A: photodiode dark current of a DVS pixel at room temperature, the order Lichtsteiner et al.
(JSSC 2008) report for the DVS128 (4 fA)."""

OFFICE_WHITE_LUMINANCE = 100.0
"""cd/m^2: a white surface (albedo 0.8) under about 400 lux of office light, ``0.8 * 400 /
pi``. The luminance that the noise model's reference intensities default to (the role of
v2e's white level, DN 255, see :mod:`sim.noise`)."""


def image_illuminance(luminance: np.ndarray | float, f_number: float = DAVIS240C_F_NUMBER,
                      transmission: float = LENS_TRANSMISSION) -> np.ndarray:
    """Illuminance on the sensor behind a lens, by the camera equation.

    Parameters
    ----------
    luminance : array_like, cd/m^2
        Scene luminance seen by each pixel (what the renderer returns).
    f_number : float
        The lens's f-number ``N`` (> 0).
    transmission : float in (0, 1]
        The lens's transmission ``T``.

    Returns
    -------
    ndarray of the input's shape, float64, lux
        ``pi T L / (4 N^2)``: on axis, without vignetting (``cos^4``) and for objects far
        compared with the focal length (a 4.5 mm lens at 0.23 m: 2 % too bright).
    """
    _positive("f_number", f_number)
    _positive("transmission", transmission)
    if transmission > 1:
        raise ValueError(f"radiometry.transmission must be at most 1, got {transmission}")
    return math.pi * transmission / (4.0 * f_number**2) * np.asarray(luminance, dtype=np.float64)


def responsivity(photodiode_area: float, f_number: float,
                 transmission: float = LENS_TRANSMISSION,
                 silicon: float = SILICON_RESPONSIVITY) -> float:
    """A camera's photocurrent per unit of scene luminance.

    Parameters
    ----------
    photodiode_area : float, m^2
        Light-sensitive area of one pixel (pitch^2 times fill factor).
    f_number : float
        The lens's f-number.
    transmission : float in (0, 1]
        The lens's transmission.
    silicon : float, A/lm
        The photodiode's responsivity to white light.

    Returns
    -------
    float, A per cd/m^2
        ``pi T / (4 N^2) * A * S``: multiply a luminance by it to get the photocurrent.
    """
    _positive("photodiode_area", photodiode_area)
    _positive("silicon", silicon)
    return float(image_illuminance(1.0, f_number, transmission)) * photodiode_area * silicon


DVS_RESPONSIVITY = (math.pi * LENS_TRANSMISSION / (4.0 * DAVIS240C_F_NUMBER**2)
                    * DAVIS240C_PHOTODIODE_AREA * SILICON_RESPONSIVITY)
"""A per cd/m^2: the DAVIS240C DVS pixel's photocurrent per unit of scene luminance under the
assumptions above, :func:`responsivity` of them (9.3e-15: about 1 pA from a white sheet in
office light)."""

DVS_DARK_LUMINANCE = DVS_DARK_CURRENT / DVS_RESPONSIVITY
"""cd/m^2: the scene luminance whose photocurrent equals the DVS dark current (0.43 cd/m^2, a
grey card of albedo 0.5 under 2.7 lux). The event camera's default ``log_eps``: below it the
log response flattens and events die out, as a real DVS's do in the dark."""


def photocurrent(luminance: np.ndarray | float, responsivity_a: float = DVS_RESPONSIVITY
                 ) -> np.ndarray:
    """Photocurrent of pixels that see the given scene luminance.

    Parameters
    ----------
    luminance : array_like, cd/m^2, >= 0
    responsivity_a : float, A per cd/m^2
        The camera's responsivity (:func:`responsivity`); default the DAVIS240C DVS pixel's.

    Returns
    -------
    ndarray of the input's shape, float64, amperes
        ``responsivity_a * luminance`` (dark current not included).
    """
    _positive("responsivity_a", responsivity_a)
    return responsivity_a * np.asarray(luminance, dtype=np.float64)


def lambertian_luminance(illuminance: np.ndarray | float, albedo: np.ndarray | float
                         ) -> np.ndarray:
    """Luminance of a Lambertian surface: ``albedo * illuminance / pi``.

    Parameters
    ----------
    illuminance : array_like, lux
        Illuminance on the surface (the light's lux times the cosine of its incidence).
    albedo : array_like in [0, 1]
        Diffuse reflectance.

    Returns
    -------
    ndarray, float64, cd/m^2
    """
    return np.asarray(albedo, dtype=np.float64) * np.asarray(illuminance, dtype=np.float64) \
        / math.pi


def _positive(name: str, value: float) -> None:
    """Refuse a value that is not a finite number > 0 (:func:`sim.validation.bounded`)."""
    bounded("radiometry", name, value, low_open=True)
