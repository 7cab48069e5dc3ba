"""Image-guided depth-completion baselines, as filling methods (:mod:`fusion.methods`).

Four classic ways of spreading sparse depths over a frame with the frame's edges as a guide,
each registered under a name and run like any filling method
(``method(frame, sparse, camera, params) -> dense``). Map points keep their depth (completion,
not denoising), as in the paper's method; the frame is the (H, W) uint8 standard frame.

``guided``
    He, Sun & Tang's guided filter (ECCV 2010, TPAMI 2013) used for normalised convolution: the
    sparse depth ``z m`` and the validity mask ``m`` are each guided-filtered with the frame,
    scaled to [0, 1], as guide, and ``dense = GF(z m) / GF(m)`` where ``GF(m)`` exceeds
    ``min_support / (2 r + 1)^2`` (a fraction of one map point per window), 0 elsewhere.
    Defaults ``radius`` r = 8 px, ``eps`` = 0.01^2 on the [0, 1] frame (``(0.01 * 255)^2`` in
    grey levels). Box filters only (``cv2.boxFilter``, normalised): O(1) per pixel.

    *Fails*: the guided filter's weights are not all positive, so next to an edge the ratio can
    leave the range of the map depths (clamped to it here, see :func:`guided_completion`); where
    a depth edge has no frame edge, or the frame's contrast is below ``sqrt(eps)``, depth is
    smoothed across it over 2r pixels; frame texture on one surface bends the local linear
    model and prints into the depth; nothing is filled beyond 2r pixels of every map point.

``bilateral``
    Joint-bilateral normalised convolution: each pixel gets ``sum w z / sum w`` over the map
    points ``q`` of its (2k + 1)^2 window, ``w = exp(-|p - q|^2 / 2 sigma_s^2)
    exp(-(I_p - I_q)^2 / 2 sigma_r^2)``, intensities in grey levels. Defaults ``radius`` k = 8 px,
    ``sigma_s`` = 4 px, ``sigma_r`` = 10 grey levels. Numba, rows in parallel (``prange``).

    *Fails*: a pixel with no map point in its window stays 0, so holes wider than 2k + 1 pixels
    stay; a weighted mean is flat, so a slanted surface is pulled towards the local mean depth of
    its points (worst where the points are one-sided, at the end of a cluster); a pixel whose
    window holds only map points of the other side of a frame edge takes their depth, however
    small the range weight (it cancels in the ratio); range weights that underflow to 0 (a very
    small ``sigma_r``) leave the pixel at 0.

``colorization``
    Levin, Lischinski & Weiss's colorization (SIGGRAPH 2004) with inverse depth in place of
    chrominance: minimise ``sum_p (x_p - sum_q w_pq x_q)^2`` over the pixels without a map point,
    ``x = 1 / z``, ``x`` fixed at the map points, 3x3 neighbourhoods, ``w_pq`` proportional to
    ``exp(-(Y_p - Y_q)^2 / c_p)`` and summing to 1 over ``q``. ``c_p`` is the authors' code's
    (``getColorExact.m``): 0.6 times the variance of the frame (scaled to [0, 1]) over the 3x3
    window, raised so that the most similar neighbour keeps an unnormalised weight >= 0.01,
    and to at least 2e-6. The minimum is the solution of the sparse linear system
    ``x_p - sum_q w_pq x_q = 0`` (``scipy.sparse.linalg.spsolve``, the unknown pixels only).

    Inverse depth, not depth, because a plane's inverse depth is affine in the pixel coordinates
    ``(u, v)``, and an affine function equals its mean over any symmetric 3x3 neighbourhood: in a
    flat region of the frame (equal weights) a slanted plane is then reproduced exactly, which
    depth, a ratio of affine functions there, is not. The weights are non-negative and sum to 1,
    so the result is a convex combination of the map points' inverse depths: it stays within
    their range (positive, finite), and a constant depth is kept. Cost: one sparse direct solve
    (SuperLU) of about H W unknowns, 9 non-zeros a row; on one core, median of 5, a synthetic
    frame of 12 rectangles with 4 % of its pixels map points: 0.45 s at 240x180 (41,558
    unknowns), 8.2 s and 1.3 GB peak process memory at 640x480 (295,051 unknowns), against 6
    and 44 ms for ``guided``, 17 and 157 ms for ``bilateral``.

    *Fails*: it assumes depth edges coincide with frame edges: a depth step in uniform intensity
    is smoothed into a ramp, and texture on a flat surface bends it; the affinity across a frame
    edge is small but never 0 (unnormalised, at least ``exp(-30)``: the variance of a 3x3
    window holding two values ``dY`` apart is at least ``dY^2 / 18``), so a region without a
    map point takes its depth from its neighbours across the edge; it fills the whole frame,
    background included; its time grows faster than the pixel count (18 times the time for 7
    times the pixels, above).

``fbs``
    Barron & Poole's fast bilateral solver (ECCV 2016) in inverse depth: minimise
    ``lam / 2 sum_ij W_ij (x_i - x_j)^2 + sum_i c_i (x_i - t_i)^2`` with ``t = 1 / z`` and
    ``c = 1`` at the map points, ``c = 0`` elsewhere, ``W`` the bistochastized affinity of the
    paper's simplified bilateral grid: each pixel lies on one vertex, ``(floor(y / 8),
    floor(x / 8), floor(I / 8))`` (``sigma_spatial`` 8 px, ``sigma_luma`` 8 grey levels), and
    the problem is solved on the vertices by Jacobi-preconditioned conjugate gradient
    (:func:`fast_bilateral_solve`), then clamped to the map's depth range. NumPy/SciPy, not
    OpenCV's ``cv2.ximgproc.fastBilateralSolverFilter``: that needs OpenCV built with Eigen,
    and the PyPI wheels are not (opencv-contrib-python-headless 4.10 and 5.0 checked: it
    raises "not implemented"). ``lam`` is 1, not the paper's 128, which is for a confidence at
    every pixel: with map points on a few % of the pixels the data term is that much weaker,
    and on ``benchmarks/bench_fill.py``'s 240x180 input the mean relative error off the map
    points is 2.0 % at ``lam`` 1, 6.1 % at 128 and 1.7 % at 0.1, but 3.1 % at 1 against 3.9 %
    at 0.1 when 10 % of the map points are off by a factor 2. Inverse depth gives 2.0 %, depth
    2.2 %. Cost, one core, that input: 8, 49 and 146 ms at 240x180, 640x480 and 1280x720 (47,
    73 and 123 iterations to a residual of 1e-5), against 6, 47 and 145 ms for ``guided``.

    *Fails*: the solution is constant over a vertex (an 8x8 px cell within one luma bin), so a
    slanted surface comes back in steps, and ``lam`` flattens it towards its mean: a plane in
    inverse depth with points 6 px apart is missed by up to 9 % at a corner of an 80x60 frame
    (2.4 % with ``lam`` 0.01; tested). A frame edge couples both sides where their intensities
    fall in the same or in neighbouring luma bins of one cell (a 120 | 130 edge inside a cell
    smooths a depth step over the frame; on a cell boundary the same edge cuts it), and cuts
    them completely where they are two bins or more apart; a part of the grid cut off that way
    with no map point of its own is left empty (0), however close to map points it is.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import cv2
import numba
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg

from fusion.methods._registry import register
from sim.camera import Camera
from sim.validation import integer, positive

__all__ = ["BilateralParams", "ColorizationParams", "FastBilateralParams", "GuidedParams",
           "bilateral_grid", "colorization_completion", "colorization_weights",
           "fast_bilateral_completion", "fast_bilateral_solve", "guided_completion",
           "guided_filter", "joint_bilateral_completion"]


# --------------------------------------------------------------------------- parameters

_INTEGER_FIELDS = ("radius", "num_iter")


@dataclass(frozen=True)
class _Params:
    """Settings of a method: ``radius`` and ``num_iter`` integers >= 1, every other field a
    number > 0 (checked by :mod:`sim.validation`, stored as int / float)."""

    def __post_init__(self):
        for field in fields(self):
            value = getattr(self, field.name)
            value = (integer(field.name, value, 1) if field.name in _INTEGER_FIELDS
                     else positive(field.name, value))
            object.__setattr__(self, field.name, value)

    @classmethod
    def from_dict(cls, method: str, params: dict):
        """The settings of ``params`` (a filling method's dict), refusing an unknown key."""
        names = [field.name for field in fields(cls)]
        unknown = sorted(set(params) - set(names))
        if unknown:
            raise ValueError(f"filling method {method}: unknown parameter {unknown[0]!r}; "
                             f"expected {', '.join(names)}")
        return cls(**params)


@dataclass(frozen=True)
class GuidedParams(_Params):
    """Settings of the ``guided`` method.

    Attributes
    ----------
    radius : int, pixels
        Half-width r of the guided filter's (2r + 1)^2 box windows.
    eps : float, (frame scaled to [0, 1])^2
        Regulariser of the local linear model: edges of contrast well above ``sqrt(eps)``
        (here 0.01, 2.55 grey levels) are kept.
    min_support : float, map points per window
        A pixel is filled where the filtered mask exceeds ``min_support / (2r + 1)^2``.
    """

    radius: int = 8
    eps: float = 0.01 ** 2
    min_support: float = 0.25


@dataclass(frozen=True)
class BilateralParams(_Params):
    """Settings of the ``bilateral`` method.

    Attributes
    ----------
    radius : int, pixels
        Half-width k of the (2k + 1)^2 window.
    sigma_s : float, pixels
        Spatial standard deviation.
    sigma_r : float, grey levels (0-255)
        Range standard deviation on the frame's intensities.
    """

    radius: int = 8
    sigma_s: float = 4.0
    sigma_r: float = 10.0


@dataclass(frozen=True)
class ColorizationParams(_Params):
    """Settings of the ``colorization`` method (Levin et al.'s code's constants).

    Attributes
    ----------
    variance_factor : float
        ``c_p`` is this times the 3x3 variance of the frame scaled to [0, 1] (0.6 in the code).
    min_weight : float, in (0, 1)
        The most similar neighbour's unnormalised weight is at least this (0.01).
    min_scale : float, (frame scaled to [0, 1])^2
        Floor of ``c_p`` (2e-6).
    """

    variance_factor: float = 0.6
    min_weight: float = 0.01
    min_scale: float = 2e-6

    def __post_init__(self):
        super().__post_init__()
        if self.min_weight >= 1:
            raise ValueError(f"min_weight must be in (0, 1), got {self.min_weight!r}")


@dataclass(frozen=True)
class FastBilateralParams(_Params):
    """Settings of the ``fbs`` method (names as OpenCV's ``fastBilateralSolverFilter``).

    Attributes
    ----------
    sigma_spatial : float, pixels
        Size of a grid cell along x and y: pixels ``floor(x / sigma_spatial)`` apart share a
        vertex (8, the paper's and OpenCV's).
    sigma_luma : float, grey levels (0-255)
        Size of a grid cell along the frame's intensity (8; the paper's code uses 4 on colour
        images).
    lam : float
        Smoothness weight ``lambda`` against a data weight of 1 per map point. The paper's 128
        is for a confidence at every pixel; with a map point on a few % of the pixels it
        over-smooths (see the module docstring), hence 1.
    num_iter : int
        At most this many conjugate-gradient iterations.
    max_tol : float
        Conjugate gradient stops at this residual relative to the right-hand side.
    """

    sigma_spatial: float = 8.0
    sigma_luma: float = 8.0
    lam: float = 1.0
    num_iter: int = 200
    max_tol: float = 1e-5


def _inputs(frame: np.ndarray, sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    frame = np.asarray(frame)
    sparse = np.asarray(sparse, dtype=np.float64)
    if frame.ndim != 2 or frame.dtype != np.uint8 or sparse.shape != frame.shape:
        raise ValueError(f"expected a (H, W) uint8 frame and a sparse depth of its shape, got "
                         f"{frame.dtype} {frame.shape} and {sparse.shape}")
    if not np.isfinite(sparse).all() or (sparse < 0).any():
        raise ValueError("sparse depth must be finite and >= 0 metres (0 = no map point)")
    return frame, sparse


def _completed(sparse: np.ndarray, filled: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """The dense map: ``depth`` (metres, one per ``filled`` pixel) clamped to the range of the
    map depths, each map point's own depth, 0 elsewhere; (H, W) float32."""
    points = sparse > 0
    depths = sparse[points]
    dense = np.zeros(sparse.shape)
    dense[filled] = np.clip(depth, depths.min(), depths.max())
    dense[points] = sparse[points]
    return dense.astype(np.float32)


# --------------------------------------------------------------------------- guided filter

def _box_sum(image: np.ndarray, radius: int) -> np.ndarray:
    """Sum over the (2r + 1)^2 window, zero outside the image, O(1) per pixel."""
    size = (2 * radius + 1, 2 * radius + 1)
    return cv2.boxFilter(image, cv2.CV_64F, size, normalize=False,
                         borderType=cv2.BORDER_CONSTANT)


def guided_filter(guide: np.ndarray, source: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """He et al.'s guided filter (gray guide), Algorithm 1 of the TPAMI 2013 paper.

    In each (2r + 1)^2 window ``k`` the output is the linear model ``a_k I + b_k`` of the guide
    closest to the source: ``a_k = cov_k(I, p) / (var_k(I) + eps)``,
    ``b_k = mean_k(p) - a_k mean_k(I)``; each pixel averages the models of the windows covering
    it: ``q = mean(a) I + mean(b)``. Windows are clipped to the image, as in He et al.'s
    code.

    Parameters
    ----------
    guide : (H, W) float ndarray
        The guide ``I``, in the units of ``sqrt(eps)``.
    source : (H, W) or (H, W, C) float ndarray, C <= 4
        The image(s) ``p`` to filter, each channel separately.
    radius : int, pixels, >= 1
    eps : float, guide units squared, > 0

    Returns
    -------
    (H, W) or (H, W, C) float64 ndarray
        The filtered ``q``, linear in ``p``.
    """
    radius = integer("radius", radius, 1)
    eps = positive("eps", eps)
    guide = np.asarray(guide, dtype=np.float64)
    source = np.asarray(source, dtype=np.float64)
    if guide.ndim != 2 or source.shape[:2] != guide.shape or source.ndim not in (2, 3):
        raise ValueError(f"expected a (H, W) guide and a (H, W) or (H, W, C) source, got "
                         f"{guide.shape} and {source.shape}")
    count = _box_sum(np.ones(guide.shape), radius)       # pixels of each window in the image
    if source.ndim == 3:
        guide = guide[:, :, None]

    def mean(image):                                     # He et al.'s boxfilter(x) ./ N
        return _box_sum(image, radius).reshape(image.shape) / (
            count if image.ndim == 2 else count[:, :, None])

    mean_I = mean(guide)
    var_I = mean(guide * guide) - mean_I * mean_I
    mean_p = mean(source)
    cov_Ip = mean(guide * source) - mean_I * mean_p
    a = cov_Ip / (var_I + eps)
    b = mean_p - a * mean_I
    return mean(a) * guide + mean(b)


def guided_completion(frame: np.ndarray, sparse: np.ndarray,
                      params: GuidedParams | None = None) -> np.ndarray:
    """Dense depth by guided-filter normalised convolution (``guided``).

    ``dense = GF(z m) / GF(m)`` with ``m`` the map points' mask, the frame scaled to [0, 1] as
    guide; 0 where ``GF(m) <= min_support / (2r + 1)^2``. The guided filter's weights can be
    negative near a frame edge, so the ratio is clamped to the range of the map depths (the
    range any normalised convolution with positive weights stays in). Map points keep their
    depth.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
    sparse : (H, W) float ndarray, metres, 0 where no map point
    params : GuidedParams, optional

    Returns
    -------
    (H, W) float32 ndarray, metres
        0 where the filtered mask is at or below its floor, which includes every pixel more
        than 2r pixels (Chebyshev) from all map points.
    """
    params = params or GuidedParams()
    frame, sparse = _inputs(frame, sparse)
    points = sparse > 0
    if not points.any():
        return np.zeros(sparse.shape, np.float32)
    mask = points.astype(np.float64)
    filtered = guided_filter(frame / 255.0, np.dstack([sparse * mask, mask]), params.radius,
                             params.eps)
    support = filtered[:, :, 1]
    floor = params.min_support / (2 * params.radius + 1) ** 2
    filled = support > floor
    return _completed(sparse, filled, filtered[:, :, 0][filled] / support[filled])


# --------------------------------------------------------------------------- joint bilateral

@numba.njit(cache=True, parallel=True)
def _joint_bilateral(frame, sparse, spatial, range_table, radius, out):  # pragma: no cover
    height, width = sparse.shape
    for y in numba.prange(height):
        for x in range(width):
            if sparse[y, x] > 0.0:
                out[y, x] = sparse[y, x]               # a map point keeps its depth
                continue
            centre = frame[y, x]
            num = 0.0
            den = 0.0
            for qy in range(max(y - radius, 0), min(y + radius + 1, height)):
                row = spatial[qy - y + radius]
                for qx in range(max(x - radius, 0), min(x + radius + 1, width)):
                    z = sparse[qy, qx]
                    if z > 0.0:
                        w = row[qx - x + radius] * range_table[abs(frame[qy, qx] - centre)]
                        num += w * z
                        den += w
            if den > 0.0:
                out[y, x] = num / den


def joint_bilateral_completion(frame: np.ndarray, sparse: np.ndarray,
                               params: BilateralParams | None = None) -> np.ndarray:
    """Dense depth by joint-bilateral normalised convolution (``bilateral``).

    Each pixel ``p`` without a map point gets ``sum_q w_pq z_q / sum_q w_pq`` over the map points
    ``q`` of its (2k + 1)^2 window (clipped at the image border),
    ``w_pq = exp(-|p - q|^2 / 2 sigma_s^2) exp(-(I_p - I_q)^2 / 2 sigma_r^2)``, sums in float64;
    0 where the window holds no map point (or all its weights underflow).

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
    sparse : (H, W) float ndarray, metres, 0 where no map point
    params : BilateralParams, optional

    Returns
    -------
    (H, W) float32 ndarray, metres
        0 more than k pixels (Chebyshev) from every map point, and where every weight
        underflows.
    """
    params = params or BilateralParams()
    frame, sparse = _inputs(frame, sparse)
    k = params.radius
    offsets = np.arange(-k, k + 1, dtype=np.float64)
    spatial = np.exp(-(offsets[:, None] ** 2 + offsets[None, :] ** 2)
                     / (2.0 * params.sigma_s ** 2))
    levels = np.arange(256, dtype=np.float64)
    range_table = np.exp(-levels ** 2 / (2.0 * params.sigma_r ** 2))
    out = np.zeros(sparse.shape)
    _joint_bilateral(frame.astype(np.int32), sparse, spatial, range_table, k, out)
    return out.astype(np.float32)


# --------------------------------------------------------------------------- colorization

_NEIGHBOURS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]


def colorization_weights(frame: np.ndarray, params: ColorizationParams | None = None
                         ) -> np.ndarray:
    """Levin et al.'s affinities of each pixel to its 8 neighbours, as in their
    ``getColorExact.m``.

    With ``Y`` the frame scaled to [0, 1], ``w_pq = exp(-(Y_p - Y_q)^2 / c_p) / norm`` for the
    neighbours ``q`` inside the image, ``c_p = max(variance_factor * var_p,
    min_q (Y_p - Y_q)^2 / -log(min_weight), min_scale)``, ``var_p`` the (population) variance of
    ``Y`` over the 3x3 window around ``p`` clipped to the image, ``norm`` making the weights
    sum to 1.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
    params : ColorizationParams, optional

    Returns
    -------
    (8, H, W) float64 ndarray
        ``weights[n, y, x]``, the weight of neighbour ``(y, x) + NEIGHBOURS[n]`` (offsets
        ``(dy, dx)`` in row-major order, the centre left out); 0 outside the image; each
        pixel's 8 weights sum to 1.
    """
    params = params or ColorizationParams()
    frame = np.asarray(frame)
    if frame.ndim != 2 or frame.dtype != np.uint8:
        raise ValueError(f"expected a (H, W) uint8 frame, got {frame.dtype} {frame.shape}")
    height, width = frame.shape
    padded = np.pad(frame / 255.0, 1, constant_values=np.nan)
    luma = padded[1:-1, 1:-1]
    neighbours = np.stack([padded[1 + dy:1 + dy + height, 1 + dx:1 + dx + width]
                           for dy, dx in _NEIGHBOURS])
    inside = ~np.isnan(neighbours)
    window = np.concatenate([np.where(inside, neighbours, 0.0), luma[None]])
    count = inside.sum(axis=0) + 1.0
    mean = window.sum(axis=0) / count
    variance = (np.where(inside, (neighbours - mean) ** 2, 0.0).sum(axis=0)
                + (luma - mean) ** 2) / count
    difference2 = np.where(inside, (neighbours - luma) ** 2, np.inf)
    scale = np.maximum.reduce([params.variance_factor * variance,
                               difference2.min(axis=0) / -np.log(params.min_weight),
                               np.full_like(variance, params.min_scale)])
    weights = np.exp(-difference2 / scale)                  # exp(-inf) = 0 outside the image
    return weights / weights.sum(axis=0)


def colorization_completion(frame: np.ndarray, sparse: np.ndarray,
                            params: ColorizationParams | None = None) -> np.ndarray:
    """Dense depth by Levin et al.'s colorization of inverse depth (``colorization``).

    Solves ``x_p - sum_q w_pq x_q = 0`` at every pixel ``p`` without a map point, ``x = 1 / z``
    fixed at the map points, ``w`` from :func:`colorization_weights`, with one sparse direct
    solve over the unknown pixels. Every weight is positive inside the image (see the module
    docstring), so with one map point the system is non-singular and the whole frame is filled.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
    sparse : (H, W) float ndarray, metres, 0 where no map point
    params : ColorizationParams, optional

    Returns
    -------
    (H, W) float32 ndarray, metres; all 0 when there is no map point
    """
    frame, sparse = _inputs(frame, sparse)
    points = sparse > 0
    if not points.any():
        return np.zeros(sparse.shape, np.float32)
    height, width = sparse.shape
    weights = colorization_weights(frame, params)
    unknown = ~points
    index = np.full(sparse.shape, -1, np.int64)             # row of each unknown pixel
    index[unknown] = np.arange(np.count_nonzero(unknown))
    known = np.where(points, 1.0 / np.where(points, sparse, 1.0), 0.0)
    padded_index = np.pad(index, 1, constant_values=-1)
    padded_known = np.pad(known, 1)
    rows, cols, values = [index[unknown]], [index[unknown]], [np.ones(index[unknown].size)]
    rhs = np.zeros(index[unknown].size)
    for n, (dy, dx) in enumerate(_NEIGHBOURS):
        w = weights[n][unknown]
        neighbour = padded_index[1 + dy:1 + dy + height, 1 + dx:1 + dx + width][unknown]
        free = (neighbour >= 0) & (w > 0)
        rows.append(index[unknown][free])
        cols.append(neighbour[free])
        values.append(-w[free])
        rhs += w * padded_known[1 + dy:1 + dy + height, 1 + dx:1 + dx + width][unknown]
    system = scipy.sparse.csc_matrix(
        (np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
        shape=(rhs.size, rhs.size))
    inverse = known.copy()
    if rhs.size:
        # SuperLU's default column ordering (COLAMD): 0.45 s at 240x180 where the symmetric
        # MMD_AT_PLUS_A took 90 s.
        inverse[unknown] = scipy.sparse.linalg.spsolve(system, rhs, permc_spec="COLAMD")
    return (1.0 / inverse).astype(np.float32)


# --------------------------------------------------------------------------- fast bilateral solver

A_DIAG_MIN = 1e-5
"""Floor of the diagonal in the Jacobi preconditioner (the paper's code's ``A_diag_min``)."""

BISTOCHASTIC_ITERATIONS = 10
"""Iterations of the bistochastization (the paper's code's and OpenCV's)."""


def bilateral_grid(frame: np.ndarray, sigma_spatial: float, sigma_luma: float
                   ) -> tuple[np.ndarray, scipy.sparse.csr_matrix]:
    """Barron & Poole's simplified bilateral grid of a gray frame.

    Each pixel ``(x, y)`` of intensity ``I`` lies on the vertex ``(floor(y / sigma_spatial),
    floor(x / sigma_spatial), floor(I / sigma_luma))`` (OpenCV's rounding; no interpolation:
    splatting is a sum over the pixels of a vertex, slicing reads the vertex's value). Only
    vertices holding a pixel exist. The blur is ``[1, 2, 1]`` along each of the 3 grid axes
    between existing vertices: ``B = 6 I + (adjacency)``.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
    sigma_spatial : float, pixels, > 0
    sigma_luma : float, grey levels, > 0

    Returns
    -------
    index : (H * W,) int64 ndarray
        The vertex of each pixel (row-major), in ``[0, V)``.
    blur : (V, V) float64 scipy.sparse.csr_matrix
        ``B``, symmetric, 6 on the diagonal and 1 between grid neighbours.
    """
    sigma_spatial = positive("sigma_spatial", sigma_spatial)
    sigma_luma = positive("sigma_luma", sigma_luma)
    frame = np.asarray(frame)
    rows, cols = np.indices(frame.shape)
    coords = [np.floor(values / sigma).astype(np.int64).ravel() + 1      # + 1: room for -1
              for values, sigma in ((rows, sigma_spatial), (cols, sigma_spatial),
                                    (frame.astype(np.float64), sigma_luma))]
    shape = tuple(int(c.max()) + 2 for c in coords)                     # and for + 1
    keys, index = np.unique(np.ravel_multi_index(coords, shape), return_inverse=True)
    strides = (shape[1] * shape[2], shape[2], 1)
    pairs = []
    for stride in strides:
        for step in (-stride, stride):
            found = np.minimum(np.searchsorted(keys, keys + step), keys.size - 1)
            neighbour = keys[found] == keys + step
            pairs.append((np.flatnonzero(neighbour), found[neighbour]))
    first = np.concatenate([p[0] for p in pairs])
    second = np.concatenate([p[1] for p in pairs])
    size = keys.size
    adjacency = scipy.sparse.csr_matrix((np.ones(first.size), (first, second)),
                                        shape=(size, size))
    return index.ravel(), (adjacency + 2 * len(strides) * scipy.sparse.identity(size)).tocsr()


def _initial_guess(blur: scipy.sparse.csr_matrix, weight: np.ndarray, weighted: np.ndarray,
                   defined: np.ndarray) -> np.ndarray:
    """Each vertex with data gets its weighted mean target, then each ring of vertices around
    them the mean of its neighbours already set, until every defined vertex is set."""
    known = weight > 0
    guess = np.zeros(weight.size)
    guess[known] = weighted[known] / weight[known]
    for _ in range(weight.size):             # each round sets a ring: at most V rounds
        todo = defined & ~known
        if not todo.any():
            break
        total = blur @ np.where(known, guess, 0.0)
        count = blur @ known.astype(np.float64)
        ring = todo & (count > 0)
        guess[ring] = total[ring] / count[ring]
        known |= ring
    return guess


def fast_bilateral_solve(frame: np.ndarray, target: np.ndarray, confidence: np.ndarray,
                         params: FastBilateralParams | None = None) -> np.ndarray:
    """Barron & Poole's fast bilateral solver (ECCV 2016) on a gray frame.

    Minimises ``lam / 2 sum_ij W_ij (x_i - x_j)^2 + sum_i c_i (x_i - t_i)^2`` with ``W`` the
    bistochastized bilateral affinity of :func:`bilateral_grid`, in the grid's vertices ``y``
    (``x = S^T y``): ``A y = b`` with ``A = lam (D_m - D_n B D_n) + diag(S c)``,
    ``b = S (c t)``, ``m = S 1``, ``n`` from 10 bistochastization steps
    (``n <- sqrt(n m / B n)``, then ``m <- n B n``), by conjugate gradient with the Jacobi
    preconditioner ``1 / max(diag A, 1e-5)``, as in the paper's code.

    A zero confidence removes a pixel from the data term: its target is never read, and no
    normalisation is needed: ``D_m - D_n B D_n`` has zero row sums (``m = n B n``), so a
    constant is the exact solution for a constant target, and its off-diagonal entries are
    <= 0, so ``A`` is an M-matrix and the exact solution is a convex combination of the
    confident targets. The initial guess spreads the targets ring by ring over the grid
    (:func:`_initial_guess`), in the manner of OpenCV's smoothed initial guess: the paper's
    code starts from ``b / diag A``, 0 away from the data; from the like ``b / S c`` on
    ``benchmarks/bench_fill.py``'s 1280x720 input the solve took 290 iterations instead of
    123, and 25 (OpenCV's default) left 17 % of the pixels empty.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
        The guide.
    target : (H, W) float ndarray
        ``t``, any units; only read where ``confidence > 0``.
    confidence : (H, W) float ndarray, >= 0
        ``c``.
    params : FastBilateralParams, optional

    Returns
    -------
    (H, W) float64 ndarray
        ``x``; NaN on the vertices (hence pixels) whose connected component of the grid holds
        no confident pixel, where the problem has no unique solution.
    """
    params = params or FastBilateralParams()
    frame = np.asarray(frame)
    target = np.asarray(target, dtype=np.float64)
    confidence = np.asarray(confidence, dtype=np.float64)
    if (frame.ndim != 2 or frame.dtype != np.uint8 or target.shape != frame.shape
            or confidence.shape != frame.shape):
        raise ValueError(f"expected a (H, W) uint8 frame and a target and a confidence of its "
                         f"shape, got {frame.dtype} {frame.shape}, {target.shape} and "
                         f"{confidence.shape}")
    if not np.isfinite(confidence).all() or (confidence < 0).any():
        raise ValueError("confidence must be finite and >= 0")
    confident = confidence > 0
    if not np.isfinite(target[confident]).all():
        raise ValueError("target must be finite where confidence > 0")
    index, blur = bilateral_grid(frame, params.sigma_spatial, params.sigma_luma)
    size = blur.shape[0]
    counts = np.bincount(index, minlength=size).astype(np.float64)
    n = np.ones(size)
    for _ in range(BISTOCHASTIC_ITERATIONS):
        n = np.sqrt(n * counts / (blur @ n))
    m = n * (blur @ n)
    weight = np.bincount(index, confidence.ravel(), size)
    weighted = np.bincount(index, (confidence * np.where(confident, target, 0.0)).ravel(),
                           size)
    _, component = scipy.sparse.csgraph.connected_components(blur, directed=False)
    defined = (np.bincount(component, weight) > 0)[component]
    laplacian = scipy.sparse.diags(m) - scipy.sparse.diags(n) @ blur @ scipy.sparse.diags(n)
    system = (params.lam * laplacian + scipy.sparse.diags(weight)).tocsr()
    system = system[defined][:, defined]
    diagonal = np.maximum(system.diagonal(), A_DIAG_MIN)
    guess = _initial_guess(blur, weight, weighted, defined)[defined]
    solution = np.full(size, np.nan)
    if defined.any():
        solution[defined], _ = scipy.sparse.linalg.cg(
            system, weighted[defined], x0=guess, rtol=params.max_tol, atol=0.0,
            maxiter=params.num_iter, M=scipy.sparse.diags(1.0 / diagonal))
    return solution[index].reshape(frame.shape)


def fast_bilateral_completion(frame: np.ndarray, sparse: np.ndarray,
                              params: FastBilateralParams | None = None) -> np.ndarray:
    """Dense depth by the fast bilateral solver in inverse depth (``fbs``).

    :func:`fast_bilateral_solve` with target ``1 / z`` and confidence 1 at the map points, 0
    elsewhere, inverted back, clamped to the range of the map depths; map points keep their
    depth.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
    sparse : (H, W) float ndarray, metres, 0 where no map point
    params : FastBilateralParams, optional

    Returns
    -------
    (H, W) float32 ndarray, metres
        0 where the solution is undefined: pixels of a part of the grid that no map point's
        vertex is connected to.
    """
    params = params or FastBilateralParams()
    frame, sparse = _inputs(frame, sparse)
    points = sparse > 0
    if not points.any():
        return np.zeros(sparse.shape, np.float32)
    inverse = fast_bilateral_solve(frame, np.where(points, 1.0 / np.where(points, sparse, 1.0),
                                                   0.0), points.astype(np.float64), params)
    filled = np.isfinite(inverse) & (inverse > 0)
    return _completed(sparse, filled, 1.0 / inverse[filled])


# --------------------------------------------------------------------------- registered methods

@register("guided", "He et al.'s guided filter (r 8 px, eps 0.01^2) as normalised "
                    "convolution: GF(depth) / GF(mask), the frame as guide", params=GuidedParams)
def guided(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict) -> np.ndarray:
    """Guided-filter normalised convolution (:func:`guided_completion`); ``params`` are
    :class:`GuidedParams`' fields."""
    return guided_completion(frame, sparse, GuidedParams.from_dict("guided", params))


@register("bilateral", "joint-bilateral normalised convolution over the map points of a 17x17 "
                       "window (sigma_s 4 px, sigma_r 10 grey levels)", params=BilateralParams)
def bilateral(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict
              ) -> np.ndarray:
    """Joint-bilateral normalised convolution (:func:`joint_bilateral_completion`); ``params``
    are :class:`BilateralParams`' fields."""
    return joint_bilateral_completion(frame, sparse,
                                      BilateralParams.from_dict("bilateral", params))


@register("colorization", "Levin et al.'s colorization of inverse depth: frame affinities over "
                          "3x3 neighbourhoods, one sparse solve; fills the whole frame",
          params=ColorizationParams)
def colorization(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict
                 ) -> np.ndarray:
    """Levin et al.'s colorization of inverse depth (:func:`colorization_completion`);
    ``params`` are :class:`ColorizationParams`' fields."""
    return colorization_completion(frame, sparse,
                                   ColorizationParams.from_dict("colorization", params))


@register("fbs", "Barron & Poole's fast bilateral solver of inverse depth on a simplified "
                 "bilateral grid (8 px, 8 grey levels); fills every part of the grid with a "
                 "map point", params=FastBilateralParams)
def fbs(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict) -> np.ndarray:
    """The fast bilateral solver in inverse depth (:func:`fast_bilateral_completion`);
    ``params`` are :class:`FastBilateralParams`' fields."""
    return fast_bilateral_completion(frame, sparse, FastBilateralParams.from_dict("fbs", params))
