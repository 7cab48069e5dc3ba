"""The classic built-in filling methods, each one function registered under its name (see
:mod:`fusion.methods`): ``nearest`` (MC-EMVS's densification), ``telea`` (OpenCV's fast-marching
inpainting) and ``morphological`` (IP-Basic's fast fill)."""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import cv2
import numpy as np

from fusion.methods._registry import NoParams, register
from sim.camera import Camera

__all__ = ["TELEA_LEVELS", "TeleaParams", "morphological", "nearest", "telea"]


@register("nearest", "every pixel takes the depth of its nearest map point (MC-EMVS's "
                     "densification); fills the whole frame", params=NoParams)
def nearest(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict) -> np.ndarray:
    """The depth of the nearest map point (exact Euclidean distance in pixels) at every pixel."""
    from scipy.ndimage import distance_transform_edt

    points = sparse > 0
    if not points.any():
        return np.zeros_like(sparse)
    rows, cols = distance_transform_edt(~points, return_distances=False, return_indices=True)
    return sparse[rows, cols]


TELEA_LEVELS = 65535
"""Telea inpaints 16-bit depth: OpenCV's 32-bit float path overshoots (a constant 1.7 m came
back as -1.5 to 4.7 m), the 16-bit one does not. Depth is scaled so that the largest map depth
is 65535 levels; with Telea's own integer rounding a constant depth comes back within a few
levels, 5e-5 of it (tested)."""


@dataclass(frozen=True)
class TeleaParams:
    """Settings of ``telea``.

    Attributes
    ----------
    radius : float, pixels
        Radius of the neighbourhood each pixel is inpainted from (default 5).
    """

    radius: float = 5.0

    def __post_init__(self) -> None:
        if not (isinstance(self.radius, numbers.Real) and np.isfinite(self.radius)
                and self.radius > 0):
            raise ValueError(f"radius must be a finite number > 0 pixels, got {self.radius!r}")


@register("telea", "OpenCV's fast-marching inpainting (Telea 2004) of the depth image, "
                   "radius 5 px", params=TeleaParams)
def telea(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict) -> np.ndarray:
    """Inpaint every pixel without a map point from the map points around it (16-bit depth,
    see :data:`TELEA_LEVELS`); ``params`` are :class:`TeleaParams`' fields."""
    radius = float(TeleaParams(**params).radius)
    points = sparse > 0
    if not points.any():
        return np.zeros_like(sparse)
    top = float(sparse.max())
    levels = np.round(sparse / top * TELEA_LEVELS).astype(np.uint16)
    filled = cv2.inpaint(levels, (~points).astype(np.uint8), radius, cv2.INPAINT_TELEA)
    return (filled.astype(np.float32) * np.float32(top / TELEA_LEVELS)).astype(np.float32)


_DIAMOND_5 = np.array([[0, 0, 1, 0, 0], [0, 1, 1, 1, 0], [1, 1, 1, 1, 1], [0, 1, 1, 1, 0],
                       [0, 0, 1, 0, 0]], np.uint8)


@register("morphological", "unguided morphological fill in the manner of IP-Basic: inverted "
                           "depth dilated, closed, holes filled, smoothed", params=NoParams)
def morphological(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict
                  ) -> np.ndarray:
    """IP-Basic's fast fill (Ku et al. 2018) on our depths.

    Depth is inverted as ``top - d`` with ``top`` 1.2 times the largest map depth (IP-Basic
    uses a fixed 100 m for KITTI), so that dilation, which keeps the largest value, keeps the
    *nearest* surface where two meet. Then: dilation with a 5x5 diamond, closing with a full
    5x5 kernel, empty pixels filled from a 7x7 dilation, then from a 31x31 one, a 5x5 median
    and a 5x5 Gaussian blur over the filled pixels, and the inversion undone.
    """
    points = sparse > 0
    if not points.any():
        return np.zeros_like(sparse)
    top = np.float32(1.2 * float(sparse.max()))
    depth = np.where(points, top - sparse, 0).astype(np.float32)
    depth = cv2.dilate(depth, _DIAMOND_5)
    depth = cv2.morphologyEx(depth, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    for size in (7, 31):
        grown = cv2.dilate(depth, np.ones((size, size), np.uint8))
        depth = np.where(depth > 0.1 * top, depth, grown)
    valid = depth > 0.1 * top
    blurred = cv2.medianBlur(depth, 5)
    depth = np.where(valid, blurred, depth)
    blurred = cv2.GaussianBlur(depth, (5, 5), 0)
    depth = np.where(valid, blurred, depth)
    return np.where(depth > 0.1 * top, top - depth, 0).astype(np.float32)
