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

import re
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["SKIMAGE_IMAGES", "PAPER_RANGE", "srgb_to_linear", "texture_image", "mitsuba_texture",
           "prefilter", "LUMINANCE_WEIGHTS", "mip_pyramid", "TextureFilter", "filtered_reflectance",
           "filtered_scale", "set_footprint", "box_matched_lod"]

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


# ------------------------------------------------------------------------------------------------
# Footprint-filtered lookups (the event camera's kernel and the frames' integrator alike)

MAX_MIP_LEVELS = 24
"""Most levels of a texture's pyramid (a 2^23-texel side; every real texture has fewer)."""
ANISOTROPY_TAPS = 4
"""Trilinear taps of a bitmap lookup, tiling the footprint: a 2 x 2 grid, or a row of 4 along
the footprint's longer side where it is more than twice the shorter (footprints up to 4 times
longer than wide are filtered at their width's level of detail)."""
NO_TEXTURE, BITMAP, CHECKERBOARD = 0, 1, 2
"""Kinds of a material in a :class:`TextureFilter` table."""


LUMINANCE_WEIGHTS = (0.212671, 0.715160, 0.072169)
"""Weights of linear R, G, B in luminance, as ``mitsuba.luminance`` takes them."""


def mip_pyramid(image: np.ndarray) -> list[np.ndarray]:
    """Area-averaged levels of a texture's luminance, from the image itself down to one texel.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) float32 ndarray
        Linear reflectance.

    Returns
    -------
    list of (H_l, W_l) float32 ndarrays
        Level 0 is the image's luminance (:data:`LUMINANCE_WEIGHTS`; a grey image as it is);
        level ``l + 1`` is level ``l`` area-averaged to ``max(1, W_l // 2) x max(1, H_l // 2)``
        texels (``cv2.INTER_AREA``).
    """
    import cv2

    level = np.asarray(image, dtype=np.float32)
    if level.ndim == 3:
        level = (level[..., :3] @ np.array(LUMINANCE_WEIGHTS)).astype(np.float32)
    levels = [np.ascontiguousarray(level)]
    while level.shape[0] > 1 or level.shape[1] > 1:
        size = (max(1, level.shape[1] // 2), max(1, level.shape[0] // 2))
        level = cv2.resize(level, size, interpolation=cv2.INTER_AREA).astype(np.float32)
        levels.append(np.ascontiguousarray(level.reshape(size[1], size[0])))
    return levels[:MAX_MIP_LEVELS]


def to_uv_affine(spec: Mapping[str, Any], scale: tuple[float, float], *,
                 flip_v: bool = False) -> tuple[float, float, float, float]:
    """The texture-space coordinates of :func:`mitsuba_texture`'s ``to_uv``, as ``u' = a_u u +
    b_u``, ``v' = a_v v + b_v``.

    Returns
    -------
    (a_u, b_u, a_v, b_v) : tuple of float
        For a bitmap, texture coordinates in repeats (1 = the whole image); for the
        checkerboard, in periods of two squares (Mitsuba's checkerboard has one period on [0, 1)).

    Notes
    -----
    ``to_uv`` is ``scale @ flip @ squares``: the squares' factor is applied first, then the
    flip ``v -> 1 - v``, then the repeats, so a flipped checkerboard's offset is ``scale_v``
    (not ``scale_v squares_v / 2``; the two agree only where their difference is a whole
    number of periods, such as 8 squares at 1 repeat).
    """
    a_u, a_v = float(scale[0]), float(scale[1])
    b_v = a_v if flip_v else 0.0
    if flip_v:
        a_v = -a_v
    if spec["type"] == "checkerboard":
        squares = spec.get("squares", [8, 8])
        a_u *= squares[0] / 2
        a_v *= squares[1] / 2
    return a_u, 0.0, a_v, b_v


class TextureFilter:
    """Every textured material of a loaded Mitsuba scene, for lookups filtered over a footprint.

    A bitmap texture's lookup is trilinear in an area-averaged mip pyramid (:func:`mip_pyramid`,
    built once from the image that Mitsuba's own bitmap holds, :func:`prefilter`'s reduction to
    about a texel per pixel at the closest approach): :data:`ANISOTROPY_TAPS` taps tile the
    footprint's parallelogram (``duv_dx``, ``duv_dy``) in cells, a 2 x 2 grid or, where the
    footprint is more than twice as long as wide, a row of 4 along its longer side; each tap
    filters its cell at the level of detail whose trilinear filter has the variance of a box
    of the cell's longer side (:func:`box_matched_lod`), clamped to the pyramid. The analytic
    checkerboard's lookup tiles the footprint in the same cells and is exact for each cell's
    box: Mitsuba's square wave (``frac(u) > 1/2``) integrated over the axis-aligned bounding
    box of the cell, along u and v separately, and the two masks combined as independent
    (exact for a box: the box is a product of its u and v extents).

    Bounds (what a filtered sample approximates). The checkerboard's value is the mean of the
    exact means over its cells' bounding boxes: exact where the footprint is axis-aligned in
    (u, v) (a surface seen square on, its texture axes along the image axes), otherwise each
    cell's box is up to ``|du_dx| + |du_dy|`` of the cell wide where the cell is narrower; a
    long footprint across the squares (a sphere's rim) is widened by a quarter of its length,
    not all of it. On a fine checkerboard receding to the horizon at 30 degrees to the image's
    axes, 4 sub-samples so filtered are 1.9 % from 1,024 point samples, mean per pixel (one
    bounding box: 6.3 %; ``tests/test_texture_filtering.py``). A bitmap's value is the sum
    of the taps' trilinear filters: the footprint's box in mean and variance along both of its
    sides (where it is at most 4 times longer than wide; longer ones are blurred along their
    shorter side to a quarter of the longer), smoother than the box's edges (a tap is a tent
    of one to two cells), and exact for a texture that is constant, or linear, over the
    filter's support. On a floor receding to the horizon, 4 sub-samples so filtered are 0.5 %
    from 1,024 point samples, mean per pixel (``log2`` of the footprint's side, one to two
    footprints wide: 2.4 %; ``tests/test_texture_filtering.py``). The footprint is the
    linearisation of the camera's ray differentials at the hit point (a plane's footprint
    exactly; a curved surface's to first order in the footprint's size over the curvature
    radius); lens distortion's change of the pixel's size is left out (a few percent at the
    image corners of a typical lens).

    Parameters
    ----------
    mitsuba_scene : mi.Scene
        The loaded scene; a material is found by its BSDF's id, ``o{index}_bsdf`` followed by
        anything (see ``sim.render._bsdf_dict``).
    materials : list of (spec, scale, seed, flip_v, max_texels, bounded) or None
        Per scene object (index ``i``), its texture spec, texture scale, seed, ``flip_v`` and
        ``max_texels`` as :func:`mitsuba_texture` takes them, and whether the shape's faces
        end at (u, v) = 0 and 1 (a rectangle's, a box's: footprints are clipped there, see
        :func:`filtered_reflectance`), or None for an untextured material.
    """

    def __init__(self, mitsuba_scene, materials: list[tuple | None]):
        import drjit as dr
        import mitsuba as mi

        kinds, affine, colors, bounds = [NO_TEXTURE], [1.0, 0.0, 1.0, 0.0], [0.0] * 2, [0]
        levels = [0] * (3 * MAX_MIP_LEVELS)
        counts = [1]
        texels: list[np.ndarray] = []
        used = 0
        record_of_object: dict[int, int] = {}
        for index, material in enumerate(materials):
            if material is None:
                continue
            spec, scale, seed, flip_v, max_texels, bounded = material
            record_of_object[index] = len(kinds)
            bounds.append(int(bool(bounded)))
            affine += to_uv_affine(spec, scale, flip_v=flip_v)
            pyramid: list[np.ndarray] = []
            if spec["type"] == "checkerboard":
                kinds.append(CHECKERBOARD)
                colors += [float(spec.get("color0", 0.05)), float(spec.get("color1", 0.85))]
            else:
                kinds.append(BITMAP)
                colors += [0.0] * 2
                pyramid = mip_pyramid(prefilter(texture_image(spec, seed), max_texels))
            row = [0] * (3 * MAX_MIP_LEVELS)
            for level, image in enumerate(pyramid):
                row[3 * level:3 * level + 3] = [used, image.shape[1], image.shape[0]]
                texels.append(image.ravel())
                used += image.shape[0] * image.shape[1]
            levels += row
            counts.append(max(1, len(pyramid)))
        ids = {}
        for shape in mitsuba_scene.shapes():
            bsdf = shape.bsdf()
            found = None if bsdf is None else re.match(r"o(\d+)_bsdf", bsdf.id())
            if found and int(found.group(1)) in record_of_object:
                key = int(dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(bsdf))[0])
                ids[key] = record_of_object[int(found.group(1))]
        record = np.zeros(max(ids, default=0) + 1, dtype=np.uint32)
        for key, value in ids.items():
            record[key] = value
        data = np.concatenate(texels) if texels else np.zeros(1, dtype=np.float32)
        self.textured = bool(ids)
        """bool: whether any shape of the scene has a texture that the filter reads."""
        self.arrays = {
            "record": mi.UInt32(record), "kind": mi.UInt32(np.array(kinds, dtype=np.uint32)),
            "affine": mi.Float(np.array(affine, dtype=np.float32)),
            "colors": mi.Float(np.array(colors, dtype=np.float32)),
            "levels": mi.UInt32(np.array(levels, dtype=np.uint32)),
            "counts": mi.UInt32(np.array(counts, dtype=np.uint32)),
            "bounded": mi.UInt32(np.array(bounds, dtype=np.uint32)),
            "texels": mi.Float(np.ascontiguousarray(data, dtype=np.float32)),
        }
        """dict of Dr.Jit arrays: the tables that :func:`filtered_reflectance` reads (pass them
        into frozen functions as an argument)."""
        for value in self.arrays.values():
            dr.make_opaque(value)


def _square_wave_mean(x, half):
    """Mean of Mitsuba's checkerboard mask ``frac(s) > 1/2`` over ``[x - half, x + half]``."""
    import drjit as dr

    x = x - dr.floor(x)                          # the mean is periodic; keeps float32 exact

    def integral(s):                             # of the mask from 0 to s
        whole = dr.floor(s)
        return 0.5 * whole + dr.maximum(s - whole - 0.5, 0.0)

    width = dr.maximum(2.0 * half, 1e-6)
    mean = (integral(x + half) - integral(x - half)) / width
    return dr.select(half > 1e-6, dr.clip(mean, 0.0, 1.0), dr.select(x > 0.5, 1.0, 0.0))


def _level(arrays, level_row, level, active):
    """Offset (texels), width and height of one pyramid level."""
    import drjit as dr
    import mitsuba as mi

    base = level_row + 3 * level
    return tuple(dr.gather(mi.UInt32, arrays["levels"], base + k, active) for k in range(3))


def _bilinear(arrays, level, u, v, active):
    """Bilinear lookup (wrap: repeat) of one pyramid level (:func:`_level`), Mitsuba's bitmap
    convention (texel ``i`` centred at ``(i + 1/2) / W``, row 0 at v = 0)."""
    import drjit as dr
    import mitsuba as mi

    offset, width, height = level
    w, h = mi.Float(width), mi.Float(height)
    x = (u - dr.floor(u)) * w - 0.5
    y = (v - dr.floor(v)) * h - 0.5
    x0, y0 = dr.floor(x), dr.floor(y)
    fx, fy = x - x0, y - y0
    ix0 = mi.Int32(x0)
    iy0 = mi.Int32(y0)
    ix1, iy1 = ix0 + 1, iy0 + 1
    wi, hi = mi.Int32(width), mi.Int32(height)
    ix0 = dr.select(ix0 < 0, wi - 1, ix0)
    iy0 = dr.select(iy0 < 0, hi - 1, iy0)
    ix1 = dr.select(ix1 >= wi, 0, ix1)
    iy1 = dr.select(iy1 >= hi, 0, iy1)
    row0 = offset + mi.UInt32(iy0) * width
    row1 = offset + mi.UInt32(iy1) * width

    def texel(row, ix):
        return dr.gather(mi.Float, arrays["texels"], row + mi.UInt32(ix), active)

    top = dr.lerp(texel(row0, ix0), texel(row0, ix1), fx)
    bottom = dr.lerp(texel(row1, ix0), texel(row1, ix1), fx)
    return dr.lerp(top, bottom, fy)


def box_matched_lod(side):
    """Level of detail whose trilinear lookup has the variance of a box ``side`` texels wide over
    the bilinear texture.

    Variances along an axis, in level-0 texels squared, relative to the texels as samples: the
    texture that Mitsuba renders is their bilinear interpolant (a tent, ``1/6``), a box of
    ``side`` over it adds ``side^2 / 12``. A level-``l`` texel area-averages ``2^l`` level-0
    texels (``(4^l - 1) / 12``) and its bilinear lookup adds a tent of half-width ``2^l``
    (``4^l / 6``); the trilinear blend of levels ``n`` and ``n + 1`` with weight ``w`` has
    ``4^n (1 + 3 w) / 4 - 1 / 12``. They are equal at ``n = floor(t)``,
    ``w = (4^(t - n) - 1) / 3``, with ``t = log4(side^2 / 3 + 1)`` (level 0 for a point).
    ``log2(side)``, the usual choice, has 3 to 3.75 times the box's variance: a blur that
    removes detail that a pixel sees.

    Parameters
    ----------
    side : mi.Float
        The box's side in level-0 texels.

    Returns
    -------
    mi.Float
        The level of detail ``n + w``, >= 0 (clamp it to the pyramid's levels).
    """
    import drjit as dr

    t = 0.5 * dr.log2(dr.square(side) / 3.0 + 1.0)
    n = dr.floor(t)
    return n + (dr.exp2(2.0 * (t - n)) - 1.0) / 3.0


def filtered_reflectance(arrays, si, active, shift=None):
    """Reflectance of each hit's texture filtered over its footprint, its point value, and
    whether it has one.

    Parameters
    ----------
    arrays : dict
        :attr:`TextureFilter.arrays`.
    si : mi.SurfaceInteraction3f
        Hits with ``uv`` and ``duv_dx``, ``duv_dy`` (``compute_uv_partials``): the footprint
        of one sample, in the shape's (u, v).
    active : mi.Bool
    shift : mi.Vector2f, optional
        The footprint's centre less ``uv``, in the shape's (u, v) (default: the hit itself).
        The event camera centres each sub-sample's footprint on its stratum of the pixel,
        the jitter undone along the surface, so that the footprints tile the pixel.

    Returns
    -------
    reflectance : mi.Float
        The luminance of the filtered reflectance (see :class:`TextureFilter` for the filters
        and their bounds), over the footprint centred at ``uv + shift``.
    point : mi.Float
        The luminance of the point lookup that Mitsuba's texture makes at ``uv`` (the
        checkerboard's mask; level 0 of the pyramid, bilinear: Mitsuba's bitmap's lookup of
        the same image, up to float rounding).
    textured : mi.Bool
        True where the hit's material has a texture that the table holds.
    """
    import drjit as dr
    import mitsuba as mi

    key = dr.reinterpret_array(mi.UInt32, si.bsdf())
    known = active & (key < dr.width(arrays["record"]))
    record = dr.gather(mi.UInt32, arrays["record"], key, known)
    kind = dr.gather(mi.UInt32, arrays["kind"], record, known)
    textured = known & (kind != NO_TEXTURE)
    a_u, b_u, a_v, b_v = dr.gather(mi.Vector4f, arrays["affine"], record, textured)
    u, v = a_u * si.uv.x + b_u, a_v * si.uv.y + b_v              # the point lookup's
    centre = mi.Point2f(si.uv) if shift is None else si.uv + shift   # the filter's centre
    partials = [dr.select(dr.isfinite(d), d, 0.0)
                for d in (si.duv_dx.x, si.duv_dy.x, si.duv_dx.y, si.duv_dy.y)]
    # On a bounded face the footprint's bounding box is clipped to it: what lies beyond the
    # face's edge is another face or another object (a face seen edge-on has a footprint far
    # larger than the face), not this texture repeated.
    bounded = textured & (dr.gather(mi.UInt32, arrays["bounded"], record, textured) != 0)
    scales = []
    for axis in range(2):
        half = 0.5 * (dr.abs(partials[2 * axis]) + dr.abs(partials[2 * axis + 1]))
        low = dr.clip(centre[axis] - half, 0.0, 1.0)
        high = dr.clip(centre[axis] + half, 0.0, 1.0)
        centre[axis] = dr.select(bounded, 0.5 * (low + high), centre[axis])
        scales.append(dr.select(bounded & (half > 0.0),
                                (high - low) / dr.maximum(2.0 * half, 1e-30), 1.0))
    u_f, v_f = a_u * centre.x + b_u, a_v * centre.y + b_v
    dudx, dudy = a_u * scales[0] * partials[0], a_u * scales[0] * partials[1]
    dvdx, dvdy = a_v * scales[1] * partials[2], a_v * scales[1] * partials[3]

    checker = textured & (kind == CHECKERBOARD)
    color0 = dr.gather(mi.Float, arrays["colors"], record * 2, checker)
    color1 = dr.gather(mi.Float, arrays["colors"], record * 2 + 1, checker)
    # The footprint's parallelogram tiled in TAPS cells as the bitmaps' (below): each cell's
    # bounding box exactly, so that a long footprint that runs diagonally across the squares
    # (a sphere's grazing rim) is not widened to the box around all of it.
    c_row, _, _, c_long, c_short = _cells(dudx, dudy, dvdx, dvdy, 1.0, 1.0)
    long_share = dr.select(c_row, 0.25, 0.5)                 # of the long side, per cell
    short_share = dr.select(c_row, 1.0, 0.5)
    half_u = 0.5 * (long_share * dr.abs(c_long[0]) + short_share * dr.abs(c_short[0]))
    half_v = 0.5 * (long_share * dr.abs(c_long[1]) + short_share * dr.abs(c_short[1]))
    same = mi.Float(0.0)
    for tu, tv in _tap_centres(u_f, v_f, c_row, c_long, c_short):
        pu, pv = _square_wave_mean(tu, half_u), _square_wave_mean(tv, half_v)
        same += pu * pv + (1.0 - pu) * (1.0 - pv)
    same *= 1.0 / ANISOTROPY_TAPS
    checker_value = color0 * same + color1 * (1.0 - same)
    point_same = (u - dr.floor(u) > 0.5) == (v - dr.floor(v) > 0.5)
    checker_point = dr.select(point_same, color0, color1)

    bitmap = textured & (kind == BITMAP)
    level_row = record * (3 * MAX_MIP_LEVELS)
    width = mi.Float(dr.gather(mi.UInt32, arrays["levels"], level_row + 1, bitmap))
    height = mi.Float(dr.gather(mi.UInt32, arrays["levels"], level_row + 2, bitmap))
    # TAPS trilinear taps tile the footprint's parallelogram: a 2 x 2 grid, or a row of 4
    # along its longer side where that is more than twice the shorter; each tap filters its
    # own cell (a box of the cell's longer side, variance-matched: box_matched_lod).
    row, major, minor, long, short = _cells(dudx, dudy, dvdx, dvdy, width, height)
    cell = dr.select(row, dr.maximum(major / 4.0, minor), 0.5 * major)
    count = dr.gather(mi.UInt32, arrays["counts"], record, bitmap)
    lod = dr.clip(box_matched_lod(cell), 0.0, mi.Float(count - 1))
    fine = dr.minimum(mi.UInt32(dr.floor(lod)), count - 1)
    coarse = dr.minimum(fine + 1, count - 1)
    weight = lod - mi.Float(fine)
    fine, coarse = (_level(arrays, level_row, level, bitmap) for level in (fine, coarse))
    bitmap_point = _bilinear(arrays, _level(arrays, level_row, 0, bitmap), u, v, bitmap)
    bitmap_value = mi.Float(0.0)
    for tu, tv in _tap_centres(u_f, v_f, row, long, short):
        bitmap_value += dr.lerp(_bilinear(arrays, fine, tu, tv, bitmap),
                                _bilinear(arrays, coarse, tu, tv, bitmap), weight)
    bitmap_value *= 1.0 / ANISOTROPY_TAPS
    return (dr.select(checker, checker_value, bitmap_value),
            dr.select(checker, checker_point, bitmap_point), textured)


def _cells(dudx, dudy, dvdx, dvdy, width, height):
    """How :data:`ANISOTROPY_TAPS` cells tile a footprint (its sides ``(dudx, dvdx)`` and
    ``(dudy, dvdy)``, measured in units ``1 / width`` along u and ``1 / height`` along v): a row
    of 4 along its longer side where that is more than twice the shorter, else a 2 x 2 grid.

    Returns ``row`` (mi.Bool), the longer and shorter sides' lengths (mi.Float, in those units)
    and the longer and shorter sides as (u, v) pairs."""
    import drjit as dr

    side_x = dr.sqrt(dr.square(dudx * width) + dr.square(dvdx * height))
    side_y = dr.sqrt(dr.square(dudy * width) + dr.square(dvdy * height))
    along_x = side_x >= side_y
    major = dr.maximum(side_x, side_y)
    minor = dr.minimum(side_x, side_y)
    long = (dr.select(along_x, dudx, dudy), dr.select(along_x, dvdx, dvdy))
    short = (dr.select(along_x, dudy, dudx), dr.select(along_x, dvdy, dvdx))
    return major > 2.0 * minor, major, minor, long, short


def _tap_centres(u, v, row, long, short):
    """The (u, v) centres of the :func:`_cells` of a footprint centred at ``(u, v)``."""
    import drjit as dr

    for tap in range(ANISOTROPY_TAPS):
        along = dr.select(row, (tap + 0.5) / 4.0 - 0.5, (tap % 2 + 0.5) / 2.0 - 0.5)
        across = dr.select(row, 0.0, (tap // 2 + 0.5) / 2.0 - 0.5)
        yield (u + along * long[0] + across * short[0], v + along * long[1] + across * short[1])


def filtered_scale(arrays, si, bsdf, active, shift=None):
    """Factor that turns a BSDF value with the point lookup of its texture into one with the
    footprint-filtered lookup: ``filtered / point`` luminance of the reflectance (1 where there
    is no texture).

    The materials of evfuse scenes are diffuse (``twosided``), whose value is linear in the
    reflectance, so ``bsdf.eval(...) * filtered_scale(...)`` is the BSDF of the filtered texture
    in luminance, exactly where the texture or the lights are grey (every built-in scene's
    lights are): one factor for R, G and B keeps the point sample's chromaticity, so a coloured
    light on a coloured texture is off by the texture's change of chromaticity within the
    footprint, weighted by the light's colour.

    Parameters
    ----------
    arrays : dict
        :attr:`TextureFilter.arrays`.
    si : mi.SurfaceInteraction3f
        With uv partials (see :func:`filtered_reflectance`).
    bsdf : mi.BSDFPtr
        ``si.bsdf()`` (unused: the point value comes from the same table, no BSDF call).
    active : mi.Bool
    shift : mi.Vector2f, optional
        The footprint's centre less ``uv`` (see :func:`filtered_reflectance`).

    Returns
    -------
    mi.Float
    """
    import drjit as dr

    filtered, point, textured = filtered_reflectance(arrays, si, active, shift)
    return dr.select(textured & (point > 0.0), filtered / dr.maximum(point, 1e-12), 1.0)


def set_footprint(si, ray, axes, scale: float) -> None:
    """Give hits the uv partials of a footprint of ``scale`` pixels, from the camera's axes.

    The differential rays are the pinhole rays one pixel (times ``scale``) to the right and down
    of each ray, ``d / (d . forward) + scale * right / fx`` and ``... + scale * down / fy``:
    lens distortion's change of the pixel's size is left out.

    Parameters
    ----------
    si : mi.SurfaceInteraction3f
        Hits of ``ray`` (``RayFlags.All``); its ``duv_dx``, ``duv_dy`` are set.
    ray : mi.Ray3f
        The primary rays (unit directions).
    axes : tuple of three mi.Vector3f
        The camera's right / fx, down / fy and forward axes in world coordinates.
    scale : float
        Footprint side in pixels (``1 / sqrt(spp)``: each sample's stratum).
    """
    import drjit as dr
    import mitsuba as mi

    right, down, forward = axes
    along = ray.d / dr.maximum(dr.dot(ray.d, forward), 1e-6)
    differential = mi.RayDifferential3f(ray)
    differential.o_x = ray.o
    differential.o_y = ray.o
    differential.d_x = dr.normalize(along + right * scale)
    differential.d_y = dr.normalize(along + down * scale)
    differential.has_differentials = True
    si.compute_uv_partials(differential)
