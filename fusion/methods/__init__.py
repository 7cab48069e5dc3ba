"""Filling methods: a sparse depth map and the standard frame in, a dense depth map out.

A filling method is a function ``method(frame, sparse, camera, params) -> dense`` or
``-> (dense, confidence)``:

- ``frame``: (H, W) uint8 gray standard frame;
- ``sparse``: (H, W) float32 depth in metres of the map points projected into the frame, 0 where
  there is none;
- ``camera``: the frame's :class:`sim.camera.Camera`;
- ``params``: a dict of method-specific settings (``{}`` for the defaults); a built-in declares
  them as a frozen dataclass (:attr:`FillMethod.params`, listed by ``evfuse methods --params``)
  and :func:`check_params` checks a dict against it, coercing each value to its field's type;
- ``dense``: (H, W) float depth in metres, 0 where the method gives none;
- ``confidence`` (optional): (H, W) float in [0, 1], how much the method trusts each pixel.

Built-in methods register under a name (:func:`available_methods` lists them, ``evfuse methods``
prints them). A user's method is given as ``module:function`` (imported from the current
folder, as ``python -m`` does, or from ``sys.path``) or installed under the Python entry-point
group ``evfuse.fill_methods``. :func:`run_method` calls any of them and refuses, in one line
naming the method, an output of the wrong shape, a non-finite or negative depth, or an
exception. A :class:`MethodVariant` is a method with settings of its own, labelled
``NAME{KEY=VALUE,...}`` (:func:`method_label`): what ``evfuse bench`` and ``evfuse reproduce``
run, the same method possibly under several settings.

Built-ins, each with its own analytic test (``tests/test_methods.py``):

- ``paper-idw``, ``paper-gaussian``, ``paper-exponential``: the paper's method (region growing,
  region selection, weighted mean of the region's map depths), one per weighting; IDW is the
  default of ``evfuse fill``.
- ``nearest``: every pixel takes the depth of its nearest map point (Euclidean), as MC-EMVS's
  densification does; fills the whole frame.
- ``telea``: OpenCV's fast-marching inpainting (Telea 2004) of the depth image, radius 5 px,
  on 16-bit depth (:data:`TELEA_LEVELS`).
- ``morphological``: an unguided morphological fill in the manner of IP-Basic (Ku et al. 2018):
  inverted depth (so that the nearer surface wins where two meet), dilation with a 5x5 diamond,
  closing, hole filling with growing kernels, median and Gaussian smoothing, un-inverted.
- ``guided``, ``bilateral``, ``colorization``, ``fbs`` (:mod:`fusion.methods.baselines`):
  image-guided completion by He et al.'s guided filter, a joint-bilateral normalised
  convolution, Levin et al.'s colorization in inverse depth, and Barron & Poole's fast bilateral
  solver in inverse depth.
- ``plane``, ``hybrid`` (:mod:`fusion.methods.surface_fit`): a robust per-region surface fit in
  inverse depth that leaves regions it cannot explain empty, and the same after cutting rejected
  regions along the frame's edges.
- ``mesh`` (:mod:`fusion.methods.mesh`): ``plane``'s fits, then a Delaunay mesh of the cleaned map
  across triangles whose corners lie on one surface, then the paper's fill in the paper's
  regions.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from dataclasses import asdict, dataclass
from importlib import metadata  # noqa: F401  (kept on this path: tests patch its entry_points)

import cv2
import numpy as np

from fusion.fill.filling import FillParams
from fusion.methods._registry import (  # noqa: F401  (re-exported; _BUILT_IN for tests)
    _BUILT_IN,
    ENTRY_POINT_GROUP,
    FillMethod,
    MethodError,
    MethodVariant,
    available_methods,
    check_params,
    coerce_params,
    format_value,
    get_method,
    method_label,
    param_defaults,
    parse_label,
    parse_value,
    register,
    run_method,
    split_labels,
)
from sim.camera import Camera

__all__ = ["ENTRY_POINT_GROUP", "FillMethod", "MethodError", "MethodVariant",
           "PaperExponentialParams", "PaperGaussianParams", "TeleaParams", "available_methods",
           "check_params", "coerce_params", "format_value", "get_method", "method_label",
           "param_defaults", "parse_label", "parse_value", "register", "run_method",
           "split_labels"]


# ------------------------------------------------------------------------------------------------
# Built-in methods
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _NoParams:
    """The settings of a method that takes none."""


@dataclass(frozen=True)
class PaperGaussianParams:
    """Settings of ``paper-gaussian``: the length of :class:`fusion.fill.filling.FillParams`.

    Attributes
    ----------
    sigma : float, pixels
        Standard deviation of the Gaussian weights (default 5, the paper's).
    """

    sigma: float = FillParams.sigma

    def __post_init__(self) -> None:
        FillParams("gaussian", sigma=self.sigma)


@dataclass(frozen=True)
class PaperExponentialParams:
    """Settings of ``paper-exponential``: the length of :class:`fusion.fill.filling.FillParams`.

    Attributes
    ----------
    scale : float, pixels
        Decay length, ``exp(-d / scale)`` (default 1, the paper's ``exp(-d)``).
    """

    scale: float = FillParams.scale

    def __post_init__(self) -> None:
        FillParams("exponential", scale=self.scale)


def _paper(weighting: str, params_class: type) -> Callable:
    def method(frame, sparse, camera, params):
        from fusion.fill.dense import DenseParams, densify

        fill = FillParams(weighting, **asdict(params_class(**params)))
        return densify(frame, sparse, DenseParams(fill=fill))[2]

    method.__doc__ = f"The paper's method with {weighting} weights."
    return method


for _weighting, _summary, _params in (
        ("idw", "the paper's method: region growing, region selection, inverse distance weights",
         _NoParams),
        ("gaussian", "the paper's method with Gaussian weights (sigma 5 px)", PaperGaussianParams),
        ("exponential", "the paper's method with exp(-d) weights", PaperExponentialParams)):
    register(f"paper-{_weighting}", _summary, params=_params)(_paper(_weighting, _params))


@register("nearest", "every pixel takes the depth of its nearest map point (MC-EMVS's "
                     "densification); fills the whole frame", params=_NoParams)
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
                           "depth dilated, closed, holes filled, smoothed", params=_NoParams)
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



# Methods defined in their own modules register on import (fusion.methods._registry.register);
# imported at the end so that the built-ins above come first in available_methods().
import fusion.methods.baselines  # noqa: E402,F401  (registers guided, bilateral, colorization, fbs)
import fusion.methods.mesh  # noqa: E402,F401  (registers mesh)
import fusion.methods.surface_fit  # noqa: E402,F401  (registers plane and hybrid)
