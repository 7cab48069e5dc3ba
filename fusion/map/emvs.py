"""Event-based multi-view stereo (EMVS): a disparity space image from events and poses.

Rebecq, Gallego, Mueggler, Scaramuzza, "EMVS: Event-Based Multi-View Stereo", IJCV 2018; the
reference implementation is uzh-rpg/rpg_emvs. Events are back-projected as rays from the event
camera's centre into a volume of depth planes in front of a reference view (the disparity space
image, DSI); each ray votes for the voxels it crosses, and the ray density peaks where edges are.

For an event with undistorted normalised coordinates (x, y) seen from camera centre C (in the
reference camera frame) along direction d = R (x, y, 1), the ray meets the plane Z = z at
reference-image coordinates::

    x_ref(z) = a_x + b_x / z,    a_x = d_x / d_z,    b_x = C_x - C_z a_x    (likewise for y)

i.e. an affine function of the inverse depth: the per-plane scale and offset of the EMVS paper
(its eq. 15 maps the point on the farthest plane to the others the same way). Votes are bilinear.
Planes are uniform in inverse depth. Events share the pose of their packet's middle event
(packets of 1024, as rpg_emvs).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from sim.camera import Camera
from sim.se3 import invert_pose
from sim.validation import finite

__all__ = ["DSIParams", "DepthMapParams", "depth_planes", "disparity_space_image",
           "masked_median", "ray_coefficients", "semidense_depth", "subplane_inverse_depth"]


@dataclass(frozen=True)
class DSIParams:
    """Geometry of the disparity space image.

    Attributes
    ----------
    min_depth, max_depth : float, metres
        Range of the depth planes (0 < min < max).
    planes : int
        Number of depth planes, uniform in inverse depth (default 100).
    packet_size : int
        Events sharing one pose (default 1024, as rpg_emvs).
    """

    min_depth: float
    max_depth: float
    planes: int = 100
    packet_size: int = 1024

    def __post_init__(self) -> None:
        if not (np.isfinite(self.min_depth) and np.isfinite(self.max_depth)
                and 0 < self.min_depth < self.max_depth):
            raise ValueError(f"depth range must satisfy 0 < min_depth < max_depth, got "
                             f"[{self.min_depth}, {self.max_depth}] m")
        if self.planes < 2:
            raise ValueError(f"planes must be >= 2, got {self.planes}")
        if self.packet_size < 1:
            raise ValueError(f"packet_size must be >= 1, got {self.packet_size}")


def depth_planes(params: DSIParams) -> np.ndarray:
    """Depths of the planes, (planes,) float64 metres, uniform in inverse depth, near to far."""
    inverse = np.linspace(1.0 / params.min_depth, 1.0 / params.max_depth, params.planes)
    return 1.0 / inverse


def ray_coefficients(xy: np.ndarray, T_ref_event: np.ndarray) -> np.ndarray:
    """Coefficients (a_x, b_x, a_y, b_y) of the rays of events in the reference view.

    Parameters
    ----------
    xy : (N, 2) float ndarray
        Undistorted normalised coordinates of the events in their own camera.
    T_ref_event : (N, 4, 4) or (4, 4) float ndarray
        Pose of the event camera in the reference camera frame (one per event, or shared).

    Returns
    -------
    (N, 4) float64 ndarray
        The ray meets plane Z = z at x = a_x + b_x / z, y = a_y + b_y / z (normalised
        reference coordinates). Rays with d_z <= 0 (pointing away) get NaN.
    """
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    T = np.asarray(T_ref_event, dtype=np.float64)
    shared = T.ndim == 2
    T = T[None] if shared else T
    return _packet_coefficients(xy, np.ascontiguousarray(T[:, :3, :3]),
                                np.ascontiguousarray(T[:, :3, 3]),
                                max(len(xy), 1) if shared else 1)


@numba.njit(cache=True, parallel=True)
def _packet_coefficients(xy, rotations, centres, packet_size):  # pragma: no cover - compiled
    n = xy.shape[0]
    out = np.empty((n, 4))
    for i in numba.prange(n):
        j = i // packet_size
        x = xy[i, 0]
        y = xy[i, 1]
        dx = rotations[j, 0, 0] * x + rotations[j, 0, 1] * y + rotations[j, 0, 2]
        dy = rotations[j, 1, 0] * x + rotations[j, 1, 1] * y + rotations[j, 1, 2]
        dz = rotations[j, 2, 0] * x + rotations[j, 2, 1] * y + rotations[j, 2, 2]
        if dz <= 0.0:
            out[i, 0] = np.nan
            out[i, 1] = np.nan
            out[i, 2] = np.nan
            out[i, 3] = np.nan
            continue
        a_x = dx / dz
        a_y = dy / dz
        out[i, 0] = a_x
        out[i, 1] = centres[j, 0] - centres[j, 2] * a_x
        out[i, 2] = a_y
        out[i, 3] = centres[j, 1] - centres[j, 2] * a_y
    return out


_CHUNK = 8192
"""Events voted per pass over the planes (their pixel coefficients stay in cache for all planes)."""


@numba.njit(cache=True)
def _pixel_coefficients(coeffs, fx, fy, cx, cy, w_mid, height):  # pragma: no cover - compiled
    """Rays in reference pixels, u = u0 + ub w, v = v0 + vb w (w inverse depth), float32, in
    order of their row at the middle plane (a counting sort: votes of neighbouring events then hit
    neighbouring memory in every plane, which is what keeps 640x480 planes in cache)."""
    n = coeffs.shape[0]
    rows = np.empty(n, np.int64)
    counts = np.zeros(height + 2, np.int64)
    for i in range(n):
        if coeffs[i, 0] != coeffs[i, 0]:             # NaN: ray pointing away, sorted last
            r = height + 1
        else:
            v = fy * (coeffs[i, 2] + coeffs[i, 3] * w_mid) + cy
            r = int(min(max(v, -1.0), float(height))) + 1 if v == v else height + 1
        rows[i] = r
        counts[r] += 1
    start = np.zeros(height + 2, np.int64)
    for r in range(1, height + 2):
        start[r] = start[r - 1] + counts[r - 1]
    out = np.empty((4, n), np.float32)
    for i in range(n):
        r = rows[i]
        j = start[r]
        start[r] += 1
        out[0, j] = fx * coeffs[i, 0] + cx
        out[1, j] = fx * coeffs[i, 1]
        out[2, j] = fy * coeffs[i, 2] + cy
        out[3, j] = fy * coeffs[i, 3]
    return out


@numba.njit(cache=True, parallel=True, fastmath=True)
def _vote(pixel_coeffs, inv_depth, dsi):  # pragma: no cover - compiled
    """Bilinear votes of every ray in every plane; dsi (planes, H, W) float32, updated in place.

    One thread owns each plane (no write races, the result does not depend on the number of
    threads). Per plane and chunk, positions are computed first in a loop the compiler vectorises,
    then the votes are scattered.
    """
    planes, height, width = dsi.shape
    n = pixel_coeffs.shape[1]
    u_0, u_b, v_0, v_b = pixel_coeffs[0], pixel_coeffs[1], pixel_coeffs[2], pixel_coeffs[3]
    u_max = np.float32(width - 1)
    v_max = np.float32(height - 1)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    for start in range(0, n, _CHUNK):
        stop = min(start + _CHUNK, n)
        m = stop - start
        for k in numba.prange(planes):
            w = np.float32(inv_depth[k])
            plane = dsi[k].reshape(-1)
            index = np.empty(m, np.int32)
            frac_u = np.empty(m, np.float32)
            frac_v = np.empty(m, np.float32)
            for j in range(m):
                u = u_0[start + j] + u_b[start + j] * w
                v = v_0[start + j] + v_b[start + j] * w
                inside = (u >= zero) & (v >= zero) & (u <= u_max) & (v <= v_max)   # NaN: False
                u = min(max(u, zero), u_max)
                v = min(max(v, zero), v_max)
                col = min(np.int32(u), width - 2)    # u = W - 1 votes fully into the last column
                row = min(np.int32(v), height - 2)
                frac_u[j] = u - np.float32(col)
                frac_v[j] = v - np.float32(row)
                index[j] = row * width + col if inside else -1
            for j in range(m):
                i = index[j]
                if i < 0:
                    continue
                fu = frac_u[j]
                fv = frac_v[j]
                plane[i] += (one - fu) * (one - fv)
                plane[i + 1] += fu * (one - fv)
                plane[i + width] += (one - fu) * fv
                plane[i + width + 1] += fu * fv


def disparity_space_image(xy: np.ndarray, times: np.ndarray, trajectory, T_world_ref: np.ndarray,
                          camera: Camera, params: DSIParams,
                          dsi: np.ndarray | None = None) -> np.ndarray:
    """Accumulate events into a DSI anchored at a reference view.

    Parameters
    ----------
    xy : (N, 2) float ndarray
        Undistorted normalised coordinates of the events (see ``Camera.undistort``).
    times : (N,) float ndarray, seconds
        Event times (sorted), inside the trajectory's range.
    trajectory : sim.trajectory.Trajectory
        ``T_world_camera(t)`` of the event camera.
    T_world_ref : (4, 4) ndarray
        Pose of the reference view.
    camera : Camera
        The reference view's virtual camera (its intrinsics and size; no distortion is applied).
    params : DSIParams
    dsi : (planes, H, W) float32 ndarray, optional
        Accumulate into this volume (for streaming windows); default a new zero volume.

    Returns
    -------
    (planes, H, W) float32 ndarray
        Ray counts (bilinear votes) per voxel; plane k at ``depth_planes(params)[k]``.
    """
    xy = np.asarray(xy, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or times.shape != (len(xy),):
        raise ValueError(f"xy must be (N, 2) and times (N,), got {xy.shape} and {times.shape}")
    shape = (params.planes, camera.height, camera.width)
    if dsi is None:
        dsi = np.zeros(shape, dtype=np.float32)
    elif dsi.shape != shape or dsi.dtype != np.float32:
        raise ValueError(f"dsi must be a float32 array of shape {shape}, got {dsi.dtype} "
                         f"{dsi.shape}")
    if len(xy) == 0:
        return dsi
    n_packets = -(-len(xy) // params.packet_size)
    middle = np.minimum(np.arange(n_packets) * params.packet_size + params.packet_size // 2,
                        len(xy) - 1)
    T_ref_world = invert_pose(np.asarray(T_world_ref, dtype=np.float64))
    T_ref_event = T_ref_world @ trajectory.pose(times[middle])          # (packets, 4, 4)
    coeffs = _packet_coefficients(np.ascontiguousarray(xy),
                                  np.ascontiguousarray(T_ref_event[:, :3, :3]),
                                  np.ascontiguousarray(T_ref_event[:, :3, 3]), params.packet_size)
    inv_depth = 1.0 / depth_planes(params)
    pixel_coeffs = _pixel_coefficients(coeffs, camera.fx, camera.fy, camera.cx, camera.cy,
                                       float(inv_depth[len(inv_depth) // 2]), camera.height)
    _vote(pixel_coeffs, inv_depth.astype(np.float32), dsi)
    return dsi


@dataclass(frozen=True)
class DepthMapParams:
    """Extraction of the semi-dense depth map from a DSI (rpg_emvs's options and defaults).

    Attributes
    ----------
    kernel : int
        Block size of the adaptive threshold (odd, default 5; the paper used 15 on the sliders).
    c : float
        A pixel is kept when its 8-bit confidence exceeds the Gaussian-weighted local mean by
        more than ``c`` (default 5; the paper used 7 on the sliders).
    median : int
        Size of the median filter of the depth inside the mask (odd, default 5; 1 = off).
    border : int
        Pixels cleared along the image border (default 1).
    keep_boundary_planes : bool
        Keep the points whose DSI maximum lies on the first or the last plane (default False:
        they are dropped before the median filter). Rays of a surface outside the depth range
        meet in no plane, and their argmax then sits on the plane nearest to where they would
        meet: such a maximum says the depth lies outside the range, not at its edge. rpg_emvs
        keeps them (True gives its maps).
    subplane : bool
        Refine each pixel's depth between the planes (:func:`subplane_inverse_depth`: the
        parabola through the maximum and its two neighbours, in inverse depth) instead of the
        most-voted plane's depth. Default False: rpg_emvs's extraction, which ``evfuse map``,
        ``evfuse bench`` and the paper's reproduction (``evfuse reproduce``) record; the global
        map (:class:`fusion.globalmap.pipeline.GlobalParams`) refines. Measured on inner key
        views of ``benchmarks/bench_global.py --goals`` (100 planes, median filter 5): on
        slider_close the median error halves (0.104 to 0.055 cm) but the share within 1 % of
        the depth stays (0.887, 0.883: the points that miss are not quantised, they are wrong);
        on boxes_6dof the median error falls from 4.88 to 4.45 cm and the share within 1 % rises
        from 0.228 to 0.259 (without the median filter 4.25 to 2.91 cm, 0.296 to 0.357).
    """

    kernel: int = 5
    c: float = 5.0
    median: int = 5
    border: int = 1
    keep_boundary_planes: bool = False
    subplane: bool = False

    def __post_init__(self) -> None:
        for name in ("kernel", "median", "border"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise ValueError(f"{name} must be an integer, got {value!r}")
        object.__setattr__(self, "c", finite("c", self.c))
        if self.kernel < 3 or self.kernel % 2 == 0:
            raise ValueError(f"kernel must be an odd integer >= 3, got {self.kernel}")
        if self.median < 1 or self.median % 2 == 0:
            raise ValueError(f"median must be an odd integer >= 1, got {self.median}")
        if self.border < 0:
            raise ValueError(f"border must be >= 0, got {self.border}")
        for name in ("keep_boundary_planes", "subplane"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")


@numba.njit(cache=True)
def _masked_median(values, mask, half):  # pragma: no cover - compiled
    height, width = values.shape
    out = values.copy()
    window = np.empty((2 * half + 1) ** 2, dtype=values.dtype)
    for y in range(height):
        for x in range(width):
            if not mask[y, x]:
                continue
            n = 0
            for yy in range(max(0, y - half), min(height, y + half + 1)):
                for xx in range(max(0, x - half), min(width, x + half + 1)):
                    if mask[yy, xx]:
                        window[n] = values[yy, xx]
                        n += 1
            out[y, x] = np.median(window[:n])
    return out


def masked_median(values: np.ndarray, mask: np.ndarray, size: int) -> np.ndarray:
    """Median of each masked pixel over the masked pixels of its size x size window.

    Parameters
    ----------
    values : (H, W) float ndarray
    mask : (H, W) bool ndarray
    size : int, odd

    Returns
    -------
    (H, W) ndarray of the values' dtype; unmasked pixels are returned unchanged.
    """
    if size <= 1:
        return np.array(values, copy=True)
    # A window reaching past the image on every side sees the whole image: the same medians
    # as any larger one, without allocating for a size far beyond the image.
    half = min(size // 2, max(np.shape(values)))
    return _masked_median(np.ascontiguousarray(values), np.ascontiguousarray(mask, dtype=bool),
                          half)


def subplane_inverse_depth(dsi: np.ndarray, best: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """Inverse depth of each pixel's DSI maximum, refined between the planes.

    The parabola through the votes ``f(k-1), f(k), f(k+1)`` of the most-voted plane ``k`` and
    its neighbours, in inverse depth ``w`` (the planes' axis: :func:`depth_planes` spaces them
    uniformly in ``w``, as the rays' image positions are affine in it), peaks at::

        w = w_k + delta (w_{k+1} - w_{k-1}) / 2,
        delta = (f(k-1) - f(k+1)) / (2 (f(k-1) - 2 f(k) + f(k+1)))

    Bound: ``f(k)`` is the maximum, so ``|delta| <= 1/2``: the refined depth never leaves the
    half steps around the plane it refines (it cannot be worse than the plane by more than half a
    step). Exact (to rounding) where the votes are a parabola in ``w`` near the maximum; for a
    Gaussian profile of votes of width ``sigma`` planes the worst error over peak positions is
    0.095 step at ``sigma`` = 0.7 and 0.048 step at ``sigma`` >= 1, for a triangular one of
    half-width ``h`` planes 0.17 step at ``h`` = 1 and 0.086 step at ``h`` >= 1.5 (the tests
    check these), against up to 0.5 step for the plane itself. A maximum on the first or last
    plane (no neighbour on one side) or on a flat top (``f(k-1) = f(k) = f(k+1)``) keeps its
    plane.

    Parameters
    ----------
    dsi : (planes, H, W) float ndarray
        Votes per voxel.
    best : (H, W) int ndarray
        The most-voted plane of each pixel (``argmax`` over axis 0).
    planes : (planes,) float ndarray, metres
        The planes' depths, uniform in inverse depth.

    Returns
    -------
    (H, W) float64 ndarray, 1/metres
    """
    inverse = 1.0 / np.asarray(planes, dtype=np.float64)
    count = len(inverse)
    inner = np.clip(best, 1, count - 2)
    f_minus = np.take_along_axis(dsi, (inner - 1)[None], axis=0)[0].astype(np.float64)
    f_zero = np.take_along_axis(dsi, inner[None], axis=0)[0].astype(np.float64)
    f_plus = np.take_along_axis(dsi, (inner + 1)[None], axis=0)[0].astype(np.float64)
    curvature = f_minus - 2.0 * f_zero + f_plus
    refine = (best == inner) & (curvature < 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(refine, 0.5 * (f_minus - f_plus) / curvature, 0.0)
    delta = np.clip(delta, -0.5, 0.5)
    return inverse[best] + delta * 0.5 * (inverse[inner + 1] - inverse[inner - 1])


def semidense_depth(dsi: np.ndarray, planes: np.ndarray, params: DepthMapParams | None = None,
                    *, counts: dict | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Semi-dense depth, confidence and mask from a DSI, as rpg_emvs extracts them.

    Depth per pixel is the depth of the plane with most votes (refined between the planes with
    ``params.subplane``: :func:`subplane_inverse_depth`) and confidence that count; a
    pixel is kept where the confidence, normalised to 8 bits, exceeds its Gaussian-weighted local
    mean by more than ``c`` (OpenCV's adaptive threshold) and the border is cleared; unless
    ``params.keep_boundary_planes``, the kept pixels whose most-voted plane is the first or the
    last are then dropped (their depth lies outside the range); the depth is median-filtered
    inside the mask.

    Parameters
    ----------
    dsi : (planes, H, W) float ndarray
    planes : (planes,) float ndarray, metres
    params : DepthMapParams, optional
    counts : dict, optional
        Receives ``near`` and ``far`` (int): the pixels that passed the threshold and the border
        with their maximum on the first, resp. the last plane (dropped unless
        ``params.keep_boundary_planes``), and ``dropped`` (bool).

    Returns
    -------
    depth : (H, W) float32 ndarray, metres, 0 outside the mask
    confidence : (H, W) float32 ndarray, votes of the best plane
    mask : (H, W) bool ndarray
    """
    params = params or DepthMapParams()
    dsi = np.asarray(dsi)
    if dsi.ndim != 3 or len(planes) != dsi.shape[0]:
        raise ValueError(f"dsi must be (planes, H, W) with {len(planes)} planes, got "
                         f"{dsi.shape}")
    best = np.argmax(dsi, axis=0)
    confidence = np.take_along_axis(dsi, best[None], axis=0)[0].astype(np.float32)
    if params.subplane and len(planes) >= 3:
        depth = (1.0 / subplane_inverse_depth(dsi, best, planes)).astype(np.float32)
    else:
        depth = np.asarray(planes, dtype=np.float32)[best]
    top = float(confidence.max())
    if counts is not None:
        counts.update(near=0, far=0, dropped=not params.keep_boundary_planes)
    if top <= 0:
        return np.zeros_like(depth), confidence, np.zeros(depth.shape, bool)
    confidence_8bit = np.round(confidence * (255.0 / top)).astype(np.uint8)
    mask = cv2.adaptiveThreshold(confidence_8bit, 1, cv2.ADAPTIVE_THRESH_GAUSSIAN_C,
                                 cv2.THRESH_BINARY, params.kernel, -params.c).astype(bool)
    if params.border:
        b = params.border
        mask[:b], mask[-b:], mask[:, :b], mask[:, -b:] = False, False, False, False
    near, far = mask & (best == 0), mask & (best == len(planes) - 1)
    if counts is not None:
        counts.update(near=int(near.sum()), far=int(far.sum()))
    if not params.keep_boundary_planes:
        mask &= ~(near | far)
    depth = masked_median(depth, mask, params.median)
    depth[~mask] = 0.0
    return depth.astype(np.float32), confidence, mask
