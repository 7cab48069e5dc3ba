"""Textures of scene materials: image files, scikit-image's bundled images, procedural patterns.

Every texture becomes a linear-RGB reflectance in [0, 1] that Mitsuba samples bilinearly, except
``checkerboard``, which uses Mitsuba's analytic (perfectly sharp) checkerboard. Images are
sRGB-encoded, so they are decoded to linear values, then mapped into [0.03, 0.9] as printed paper
reflects: no ink is perfectly black (a zero reflectance would give log(0) to the event camera) and
no paper is perfectly white.

Random textures (``noise``, ``shapes``) are drawn from the scene's seed: the same scene gives the
same texture.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["SKIMAGE_IMAGES", "PAPER_RANGE", "srgb_to_linear", "texture_image", "mitsuba_texture",
           "prefilter"]

SKIMAGE_IMAGES = (
    "astronaut", "brick", "camera", "coffee", "chelsea", "coins", "grass", "gravel", "moon",
    "page", "rocket", "text", "clock", "cell", "colorwheel", "immunohistochemistry", "horse",
)
PAPER_RANGE = (0.03, 0.9)


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """Decode sRGB values in [0, 1] to linear values in [0, 1] (IEC 61966-2-1)."""
    values = np.asarray(values, dtype=np.float64)
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    """Encode linear values in [0, 1] as sRGB values in [0, 1] (IEC 61966-2-1), the inverse of
    :func:`srgb_to_linear`."""
    values = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.where(values <= 0.0031308, values * 12.92, 1.055 * values ** (1 / 2.4) - 0.055)


def _as_paper(image: np.ndarray) -> np.ndarray:
    """uint8/bool/float sRGB image -> float32 linear reflectance in PAPER_RANGE."""
    image = np.asarray(image)
    if image.dtype == bool:
        encoded = image.astype(np.float64)
    elif np.issubdtype(image.dtype, np.integer):
        encoded = image.astype(np.float64) / np.iinfo(image.dtype).max
    else:
        encoded = np.clip(image.astype(np.float64), 0.0, 1.0)
    if encoded.ndim == 3 and encoded.shape[2] == 4:
        encoded = encoded[..., :3]
    low, high = PAPER_RANGE
    return (low + (high - low) * srgb_to_linear(encoded)).astype(np.float32)


def _smooth_noise(resolution: int, feature_size: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian-filtered white noise, periodic, normalised to zero mean and unit std."""
    from scipy.ndimage import gaussian_filter

    white = rng.standard_normal((resolution, resolution))
    smooth = gaussian_filter(white, sigma=feature_size, mode="wrap")
    return (smooth - smooth.mean()) / (smooth.std() + 1e-12)


def texture_image(spec: Mapping[str, Any], seed: int = 0) -> np.ndarray:
    """Reflectance image of a bitmap texture.

    Parameters
    ----------
    spec : mapping
        ``{"type": "image", "path": ...}``, ``{"type": "skimage", "name": ...}``,
        ``{"type": "noise", "resolution": 512, "feature_size": 6, "contrast": 0.35,
        "mean": 0.45}`` (smooth random noise, feature size in texels) or
        ``{"type": "shapes", "resolution": 512, "count": 40, "min_size": 20, "max_size": 120,
        "background": 0.9}`` (random dark shapes, scikit-image's ``random_shapes``).
    seed : int
        Seed of the random textures.

    Returns
    -------
    (H, W) or (H, W, 3) float32 ndarray
        Linear reflectance in [0, 1]; row 0 is the top of the texture (v = 0).
    """
    kind = spec["type"]
    rng = np.random.default_rng(seed)
    if kind == "image":
        import cv2

        image = cv2.imread(str(spec["path"]), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"{spec['path']}: cannot read the texture image")
        if image.ndim == 3:
            image = cv2.cvtColor(image[..., :3], cv2.COLOR_BGR2RGB)
        return _as_paper(image)
    if kind == "skimage":
        import skimage.data

        if spec["name"] not in SKIMAGE_IMAGES:
            raise ValueError(f"unknown scikit-image texture {spec['name']!r}; expected one of "
                             f"{', '.join(SKIMAGE_IMAGES)}")
        return _as_paper(getattr(skimage.data, spec["name"])())
    if kind == "noise":
        resolution = int(spec.get("resolution", 512))
        noise = _smooth_noise(resolution, float(spec.get("feature_size", 6.0)), rng)
        value = float(spec.get("mean", 0.45)) + float(spec.get("contrast", 0.35)) * noise / 3.0
        return np.clip(value, *PAPER_RANGE).astype(np.float32)
    if kind == "shapes":
        from skimage.draw import random_shapes

        resolution = int(spec.get("resolution", 512))
        background = float(spec.get("background", 0.9))
        image, _ = random_shapes(
            (resolution, resolution),
            max_shapes=int(spec.get("count", 40)),
            min_shapes=max(1, int(spec.get("count", 40)) // 2),
            min_size=int(spec.get("min_size", 20)),
            max_size=int(spec.get("max_size", 120)),
            channel_axis=None,
            intensity_range=(0, 200),
            rng=rng,
        )
        linear = np.where(image == 255, background, _as_paper(image))
        return np.clip(linear, *PAPER_RANGE).astype(np.float32)
    raise ValueError(f"texture type {kind!r} has no bitmap; expected image, skimage, noise or "
                     "shapes")


def prefilter(image: np.ndarray, max_texels: tuple[float, float] | None) -> np.ndarray:
    """Area-average a texture down to at most ``max_texels`` (u, v) texels, as a mipmap does.

    Parameters
    ----------
    image : (H, W) or (H, W, C) float32 ndarray
    max_texels : (float, float) or None
        Most texels worth keeping along u (width) and v (height); None keeps the image.

    Returns
    -------
    float32 ndarray
        The image, or its area-averaged reduction (never enlarged).
    """
    if max_texels is None:
        return image
    import cv2

    height, width = image.shape[:2]
    new_w = int(min(width, max(8, round(max_texels[0]))))
    new_h = int(min(height, max(8, round(max_texels[1]))))
    if (new_w, new_h) == (width, height):
        return image
    return cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_AREA).astype(np.float32)


def mitsuba_texture(spec: Mapping[str, Any], scale: tuple[float, float], seed: int, *,
                    flip_v: bool = False,
                    max_texels: tuple[float, float] | None = None) -> dict:
    """Mitsuba texture dictionary for a material's texture spec.

    Parameters
    ----------
    spec : mapping
        Texture description (see :func:`texture_image`; plus ``{"type": "checkerboard",
        "squares": [8, 8], "color0": 0.05, "color1": 0.85}``, a sharp analytic checkerboard).
    scale : (2,) tuple of float
        Repetitions of the texture along u and v.
    seed : int
        Seed of the random textures.
    flip_v : bool
        Use v -> 1 - v, for shapes whose v grows upwards (Mitsuba's rectangle and cylinder) so
        that the image's top row is at the top of the object.
    max_texels : (float, float), optional
        Texels along u and v beyond which the bitmap is area-averaged down (see
        :func:`prefilter`): Mitsuba's bitmap texture has no mipmaps, and a texture much finer
        than a pixel's footprint aliases under point sampling, making renders flicker as the
        camera moves by a fraction of a pixel.

    Returns
    -------
    dict
        A Mitsuba plugin dictionary (requires an active variant).
    """
    import mitsuba as mi

    to_uv = mi.ScalarTransform4f().scale([scale[0], scale[1], 1.0])
    if flip_v:
        to_uv = to_uv @ mi.ScalarTransform4f().translate([0.0, 1.0, 0.0]).scale([1.0, -1.0, 1.0])
    if spec["type"] == "checkerboard":
        squares = spec.get("squares", [8, 8])
        to_uv = to_uv @ mi.ScalarTransform4f().scale([squares[0] / 2, squares[1] / 2, 1.0])
        return {
            "type": "checkerboard",
            "color0": {"type": "rgb", "value": [float(spec.get("color0", 0.05))] * 3},
            "color1": {"type": "rgb", "value": [float(spec.get("color1", 0.85))] * 3},
            "to_uv": to_uv,
        }
    image = prefilter(texture_image(spec, seed), max_texels)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    return {
        "type": "bitmap",
        "bitmap": mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32)),
        "raw": True,
        "filter_type": "bilinear",
        "wrap_mode": "repeat",
        "to_uv": to_uv,
    }
