"""A truncated signed distance volume integrated from depth views, and its mesh.

The projective TSDF of Curless and Levoy (1996) as KinectFusion runs it: every voxel centre is
projected into a view (its camera model, distortion included), the depth of the nearest pixel
is read, and the voxel's signed distance is ``sdf = depth - z_voxel`` **along the camera's z
axis** (the projective distance: positive in front of the surface, negative behind it). The
distance is clipped to ``[-truncation, truncation]``; a voxel behind the surface by more than
the truncation, outside the image, behind the camera or on a pixel without depth is left as it
was. Each voxel keeps the weighted running mean of its distances: an observation weighs 1 in
front of the surface and less behind it, linearly from 1 at the surface to 0 at the
truncation (voxblox's behind-surface drop-off, Oleynikova et al. 2017, there from one voxel
behind): a view that sees a voxel only as hidden behind another face must not outvote a view
that sees it as free space. The
integration is compiled with numba and runs over the volume's x slices in parallel; it holds
the volume (float32 distance + float32 weight, 8 bytes a voxel) and one view, nothing more.

The mesh is the zero level set by :func:`skimage.measure.marching_cubes`, computed only in the
cubes whose eight corners were observed (weight > 0), so that no surface appears between an
observed and an unobserved voxel; its vertices are in world metres.

Defaults from the data (:func:`tsdf_grid`, one place for each rule):

* voxel size: :data:`VOXEL_FOOTPRINTS` (2) times the median one-pixel footprint ``z / f`` of
  the views' points (``f = sqrt(fx fy)``, the footprint at the principal point), enlarged
  where needed until the volume holds at most ``max_voxels`` voxels;
* truncation: :data:`TRUNCATION_VOXELS` (2) voxels. A wider band lets views that see a voxel as
  hidden (behind a face at a box's edge) pull the surface off the edge: on two views of a box
  (the test's), the worst mesh vertex lies 0.31 voxel off the box at 2 voxels, 0.54 at 3 and
  1.98 at 4 (with the drop-off; 2.9 at 4 without it);
* bounds: the box around every view's points (their back-projected depth), padded by the
  largest truncation on every side.

Truncation that follows each view's depth uncertainty (issue 40): an EMVS view resolves depth in
steps of its DSI's planes, uniform in inverse depth, so its depth error at depth ``d`` grows as
``sigma_d ~ d^2 step_w`` (``step_w`` the planes' spacing in inverse depth, 1/m). With
``TSDFParams.inverse_depth_step``, an observation of a pixel of depth ``d`` is truncated at
``max(truncation, TRUNCATION_STEPS d^2 step_w)``: a band narrower than the views' errors leaves
the views' surfaces side by side, each voting the others' space free, and the mesh shows none
(issue 40: boxes_6dof's 3.3 cm band against views 6-11 cm off). The behind-surface drop-off
follows the same band.

Sparse views (issue 40): a filled key view holds depth on a share of its pixels only (on
boxes_6dof 3.5-5.5 s, 3-13 %: the segments the fill reached), in patches and strips a few
pixels wide. A voxel is meshed only where the eight corners of its cube were observed, so a
strip narrower than about two voxels' footprint leaves no surface. With
``TSDFParams.search_radius`` ``r``, a voxel whose pixel holds no depth takes the depth of the
nearest pixel with one in the ``(2 r + 1)^2`` window around it (each pixel's depth then covers
the pixels up to ``r`` away, as a splat): a surface seen with depth ``d`` extends at most ``r``
pixels past its view's last pixel, at that pixel's depth, so off the true surface there by at
most ``r (d / f) tan(theta)`` for a plane at ``theta`` to the image plane (0 for a
fronto-parallel one, which the tests check). Measured on the goal windows of
``benchmarks/bench_global.py --goals``: boxes_6dof's mesh F at 5 cm 0.18 with ``r = 0``, 0.35
with 1, 0.43 with 2; slider_close's F at 1 % of depth 0.66, 0.74, 0.77.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from fusion.globalmap.views import DepthView
from sim._summary import summary_repr
from sim.validation import ParameterError, check_parameter, integer, positive

__all__ = [
    "GLOBAL_SEARCH_RADIUS",
    "TRUNCATION_STEPS",
    "TRUNCATION_VOXELS",
    "VOXEL_FOOTPRINTS",
    "Mesh",
    "TSDFParams",
    "TSDFVolume",
    "tsdf_grid",
    "tsdf_mesh",
]

#: Default voxel size in one-pixel footprints (median over the views' points).
VOXEL_FOOTPRINTS = 2.0
#: Default truncation distance in voxels.
TRUNCATION_VOXELS = 2.0
#: With ``TSDFParams.inverse_depth_step``: the truncation at depth ``d`` is at least this many
#: plane steps, ``d^2 inverse_depth_step`` each.
TRUNCATION_STEPS = 2.0
#: The global map's :attr:`TSDFParams.search_radius` (pixels): see the module's docstring.
GLOBAL_SEARCH_RADIUS = 2


@dataclass(frozen=True)
class TSDFParams:
    """Parameters of a TSDF volume; ``None`` takes the value from the data (:func:`tsdf_grid`).

    Attributes
    ----------
    voxel_size : float or None, metres
        Edge of a voxel. None: :data:`VOXEL_FOOTPRINTS` median one-pixel footprints, enlarged
        so that the volume fits ``max_voxels``.
    truncation : float or None, metres
        Distances are clipped to ``[-truncation, truncation]``; at least one voxel. None:
        :data:`TRUNCATION_VOXELS` voxels.
    bounds : ((3,), (3,)) tuple of float or None, metres, world frame
        The volume's box ``(lo, hi)``. None: the views' points padded by the truncation.
    max_voxels : int
        A volume with more voxels is refused (8 bytes a voxel: 50 million is 400 MB).
    inverse_depth_step : float or None, 1/metres
        The views' depth resolution in inverse depth (an EMVS map's plane spacing): each
        observation of depth ``d`` is truncated at ``max(truncation, TRUNCATION_STEPS d^2
        inverse_depth_step)``. None: ``truncation`` everywhere.
    search_radius : int, pixels
        A voxel whose pixel holds no depth takes the nearest depth within this many pixels
        (the module's docstring states the bound; default 0, the pixel's own depth only).
    """

    voxel_size: float | None = None
    truncation: float | None = None
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    max_voxels: int = 50_000_000
    inverse_depth_step: float | None = None
    search_radius: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "search_radius", check_parameter(
            lambda n, v: integer(n, v, 0), "search_radius", self.search_radius))


@dataclass
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    vertices : (V, 3) float64 ndarray, metres, world frame
    faces : (F, 3) int32 ndarray, indices into ``vertices``
    """

    vertices: np.ndarray
    faces: np.ndarray

    __repr__ = summary_repr

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(self.faces, dtype=np.int32).reshape(-1, 3)

    def areas(self) -> np.ndarray:
        """(F,) float64 ndarray, square metres: the area of each triangle."""
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)

    def sample(self, spacing: float, seed: int = 0) -> np.ndarray:
        """Points drawn uniformly by area on the triangles.

        Parameters
        ----------
        spacing : float, metres
            Mean spacing of the samples: ``ceil(area / spacing^2)`` points in all.
        seed : int
            Seed of the generator (the same seed gives the same points).

        Returns
        -------
        (M, 3) float64 ndarray, metres, world frame; empty for a mesh without area
        """
        spacing = check_parameter(positive, "spacing", spacing)
        areas = self.areas()
        total = float(areas.sum())
        if total <= 0.0:
            return np.empty((0, 3))
        rng = np.random.default_rng(seed)
        count = math.ceil(total / spacing**2)
        face = rng.choice(len(areas), size=count, p=areas / total)
        r1, r2 = rng.random(count), rng.random(count)
        s = np.sqrt(r1)  # uniform on a triangle: (1 - s, s (1 - r2), s r2)
        a, b, c = (self.vertices[self.faces[face, i]] for i in range(3))
        return (1.0 - s)[:, None] * a + (s * (1.0 - r2))[:, None] * b + (s * r2)[:, None] * c


@numba.njit(cache=True, parallel=True)
def _integrate(tsdf, weight, lo, voxel, truncation, R_cw, t_cw, fx, fy, cx, cy, coeffs,
               distorted, depth, band, radius):  # pragma: no cover - compiled
    """Fuse one depth image into the volume (see the module's docstring)."""
    nx, ny, nz = tsdf.shape
    height, width = depth.shape
    k1, k2, p1, p2, k3 = coeffs[0], coeffs[1], coeffs[2], coeffs[3], coeffs[4]
    for i in numba.prange(nx):
        px = lo[0] + i * voxel
        for j in range(ny):
            py = lo[1] + j * voxel
            # camera-frame coordinates are affine along k: start and step
            x0 = R_cw[0, 0] * px + R_cw[0, 1] * py + R_cw[0, 2] * lo[2] + t_cw[0]
            y0 = R_cw[1, 0] * px + R_cw[1, 1] * py + R_cw[1, 2] * lo[2] + t_cw[1]
            z0 = R_cw[2, 0] * px + R_cw[2, 1] * py + R_cw[2, 2] * lo[2] + t_cw[2]
            for k in range(nz):
                z = z0 + k * voxel * R_cw[2, 2]
                if z <= 0.0:
                    continue
                x = (x0 + k * voxel * R_cw[0, 2]) / z
                y = (y0 + k * voxel * R_cw[1, 2]) / z
                if distorted:
                    # sim.camera.Camera.distort (OpenCV's model), pinned by a test
                    r2 = x * x + y * y
                    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
                    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
                    x, y = xd, yd
                u = fx * x + cx
                v = fy * y + cy
                if not (u > -0.5 and v > -0.5 and u < width - 0.5 and v < height - 0.5):
                    continue
                col = int(u + 0.5)
                row = int(v + 0.5)
                d = depth[row, col]
                if not d > 0.0 and radius > 0:
                    # the nearest pixel with depth in the window (see the module's docstring)
                    nearest = np.inf
                    for yy in range(max(row - radius, 0), min(row + radius + 1, height)):
                        for xx in range(max(col - radius, 0), min(col + radius + 1, width)):
                            candidate = depth[yy, xx]
                            if candidate > 0.0:
                                dist2 = (xx - u) * (xx - u) + (yy - v) * (yy - v)
                                if dist2 < nearest:
                                    nearest = dist2
                                    d = candidate
                if not d > 0.0:
                    continue
                sdf = d - z
                trunc = max(truncation, band * d * d)
                if sdf < -trunc:
                    continue
                if sdf > trunc:
                    sdf = trunc
                # behind the surface the weight drops linearly to 0 at -trunc
                observation = 1.0 if sdf >= 0.0 else 1.0 + sdf / trunc
                if not observation > 0.0:
                    # at -truncation (to rounding) the weight is 0: adding it to an unseen
                    # voxel would write 0 / 0, a NaN that no later view could replace
                    continue
                w = weight[i, j, k]
                tsdf[i, j, k] = (tsdf[i, j, k] * w + sdf * observation) / (w + observation)
                weight[i, j, k] = w + observation


class TSDFVolume:
    """A dense TSDF volume on a regular grid of voxel centres.

    Parameters
    ----------
    lo, hi : (3,) array_like, metres, world frame
        Corners of the box; the grid points are ``lo + (i, j, k) * voxel_size`` up to ``hi``.
    voxel_size : float, metres
    truncation : float, metres, at least ``voxel_size``
    max_voxels : int
        A larger grid is refused with a :class:`~sim.validation.ParameterError`.
    inverse_depth_step : float or None, 1/metres
        :attr:`TSDFParams.inverse_depth_step`: the truncation at depth ``d`` is at least
        ``TRUNCATION_STEPS d^2 inverse_depth_step``.
    search_radius : int, pixels
        :attr:`TSDFParams.search_radius`.

    Attributes
    ----------
    tsdf : (NX, NY, NZ) float32 ndarray, metres
        Running mean of the clipped signed distances (0 where unobserved).
    weight : (NX, NY, NZ) float32 ndarray
        Sum of the observations' weights (> 0: observed).
    """

    def __init__(self, lo, hi, voxel_size: float, truncation: float,
                 max_voxels: int = TSDFParams.max_voxels,
                 inverse_depth_step: float | None = None, search_radius: int = 0) -> None:
        voxel_size = check_parameter(positive, "voxel_size", voxel_size)
        truncation = check_parameter(positive, "truncation", truncation)
        max_voxels = int(check_parameter(lambda n, v: integer(n, v, 1), "max_voxels",
                                         max_voxels))
        if truncation < voxel_size:
            raise ParameterError(
                f"{{truncation}} {truncation:g} m is under one voxel ({{voxel_size}} "
                f"{voxel_size:g} m): the surface would fall between voxels unseen",
                truncation="truncation", voxel_size="voxel_size")
        lo = np.asarray(lo, dtype=np.float64).reshape(3)
        hi = np.asarray(hi, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise ParameterError(f"{{bounds}} must be finite with hi > lo on every axis, got "
                                 f"lo {lo.tolist()}, hi {hi.tolist()}", bounds="bounds")
        shape = _grid_shape(lo, hi, voxel_size)
        count = math.prod(shape)
        if count > max_voxels:
            raise ParameterError(
                f"a TSDF volume of {count:,} voxels ({shape[0]} x {shape[1]} x {shape[2]} at "
                f"{{voxel_size}} {voxel_size:g} m) is over {{max_voxels}} {max_voxels:,}: pass "
                "a larger {voxel_size} or smaller {bounds}",
                voxel_size="voxel_size", max_voxels="max_voxels", bounds="bounds")
        self.lo = lo
        self.hi = lo + (np.asarray(shape) - 1) * voxel_size
        self.voxel_size = voxel_size
        self.truncation = truncation
        self.tsdf = np.zeros(shape, dtype=np.float32)
        self.weight = np.zeros(shape, dtype=np.float32)
        self.inverse_depth_step = (None if inverse_depth_step is None else check_parameter(
            positive, "inverse_depth_step", inverse_depth_step))
        self.search_radius = TSDFParams(search_radius=search_radius).search_radius

    @property
    def shape(self) -> tuple[int, int, int]:
        """(int, int, int): grid points along x, y, z."""
        return self.tsdf.shape

    def integrate(self, view: DepthView) -> None:
        """Fuse one depth view into the volume (in place).

        Parameters
        ----------
        view : DepthView
            Its depth is read at the nearest pixel of each voxel's projection.
        """
        camera = view.camera
        R_wc = view.T_world_cam[:3, :3]
        R_cw = np.ascontiguousarray(R_wc.T)
        t_cw = -R_cw @ view.T_world_cam[:3, 3]
        _integrate(self.tsdf, self.weight, self.lo, self.voxel_size, self.truncation, R_cw,
                   t_cw, float(camera.fx), float(camera.fy), float(camera.cx),
                   float(camera.cy), np.asarray(camera.distortion, dtype=np.float64),
                   bool(camera.has_distortion), np.ascontiguousarray(view.depth),
                   TRUNCATION_STEPS * (self.inverse_depth_step or 0.0), self.search_radius)

    def observed_cubes(self) -> np.ndarray:
        """(NX, NY, NZ) bool ndarray: ``[i, j, k]`` is True where the cube between grid
        points ``i-1..i, j-1..j, k-1..k`` has all eight corners observed (the index
        :func:`skimage.measure.marching_cubes` reads its ``mask`` at: a cube's far corner)."""
        seen = self.weight > 0
        cube = seen[:-1, :-1, :-1].copy()
        for di in (0, 1):
            for dj in (0, 1):
                for dk in (0, 1):
                    cube &= seen[di:di + seen.shape[0] - 1, dj:dj + seen.shape[1] - 1,
                                 dk:dk + seen.shape[2] - 1]
        mask = np.zeros_like(seen)
        mask[1:, 1:, 1:] = cube
        return mask

    def mesh(self) -> Mesh:
        """The zero level set by marching cubes, in observed cubes only.

        Returns
        -------
        Mesh
            Vertices in world metres; empty where no observed cube holds a surface.
        """
        from skimage.measure import marching_cubes

        mask = self.observed_cubes()
        if not mask.any():
            return Mesh(np.empty((0, 3)), np.empty((0, 3), np.int32))
        try:
            vertices, faces, _, _ = marching_cubes(self.tsdf, level=0.0, mask=mask,
                                                   spacing=(self.voxel_size,) * 3)
        except RuntimeError:  # "No surface found at the given iso value."
            return Mesh(np.empty((0, 3)), np.empty((0, 3), np.int32))
        return Mesh(vertices.astype(np.float64) + self.lo, faces)


def _grid_shape(lo: np.ndarray, hi: np.ndarray, voxel: float) -> tuple[int, int, int]:
    """Grid points along each axis covering ``[lo, hi]`` at ``voxel`` spacing."""
    n = np.ceil((np.asarray(hi) - np.asarray(lo)) / voxel - 1e-9).astype(np.int64) + 1
    return tuple(int(v) for v in np.maximum(n, 2))


def _footprint(views: list[DepthView]) -> float:
    """Median one-pixel footprint ``z / sqrt(fx fy)`` over every view's points, metres."""
    parts = [view.depth[view.valid] / math.sqrt(view.camera.fx * view.camera.fy)
             for view in views]
    values = np.concatenate(parts) if parts else np.empty(0)
    return float(np.median(values)) if values.size else math.nan


def _widest_band(views: list[DepthView], inverse_depth_step: float | None) -> float:
    """The largest depth-following truncation, ``TRUNCATION_STEPS d^2 inverse_depth_step`` at
    the views' largest depth ``d`` (0 without a step), metres."""
    if inverse_depth_step is None:
        return 0.0
    step = check_parameter(positive, "inverse_depth_step", inverse_depth_step)
    deepest = max((float(view.depth.max()) for view in views if view.valid.any()), default=0.0)
    return TRUNCATION_STEPS * deepest ** 2 * step


def tsdf_grid(views: list[DepthView], params: TSDFParams = TSDFParams()
              ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The volume's box, voxel size and truncation: ``params``' values, the rest from the data.

    Parameters
    ----------
    views : list of DepthView
    params : TSDFParams

    Returns
    -------
    lo, hi : (3,) float64 ndarray, metres, world frame
    voxel_size : float, metres
    truncation : float, metres
        The smallest truncation (with ``params.inverse_depth_step``, an observation's grows with
        its depth; the box is padded by the largest).

    Raises
    ------
    ParameterError
        A given voxel size whose volume is over ``max_voxels``, or no point to take a default
        from.
    """
    max_voxels = int(check_parameter(lambda n, v: integer(n, v, 1), "max_voxels",
                                     params.max_voxels))
    voxel = None if params.voxel_size is None else check_parameter(
        positive, "voxel_size", params.voxel_size)
    truncation = None if params.truncation is None else check_parameter(
        positive, "truncation", params.truncation)
    if params.bounds is None or voxel is None:
        footprint = _footprint(views)
        if not math.isfinite(footprint):
            raise ParameterError("no view has a point to size the TSDF volume from: pass "
                                 "{voxel_size} and {bounds}", voxel_size="voxel_size",
                                 bounds="bounds")
    if params.bounds is not None:
        fixed = np.asarray(params.bounds, dtype=np.float64)
        if fixed.shape != (2, 3):
            raise ParameterError(f"{{bounds}} must be ((x, y, z), (x, y, z)), got "
                                 f"{ParameterError.literal(params.bounds)}", bounds="bounds")
        points_lo, points_hi = fixed
    else:
        points = [view.points_world() for view in views]
        points = np.concatenate(points) if points else np.empty((0, 3))
        points = points[np.all(np.isfinite(points), axis=1)]
        points_lo, points_hi = points.min(0), points.max(0)

    band = _widest_band(views, params.inverse_depth_step)

    def box(v: float) -> tuple[np.ndarray, np.ndarray, float]:
        trunc = truncation if truncation is not None else TRUNCATION_VOXELS * v
        if params.bounds is not None:
            return points_lo, points_hi, trunc
        pad = max(trunc, band)
        return points_lo - pad, points_hi + pad, trunc

    if voxel is not None:
        lo, hi, trunc = box(voxel)
        return lo, hi, voxel, trunc
    voxel = VOXEL_FOOTPRINTS * footprint
    for _ in range(100):
        lo, hi, trunc = box(voxel)
        count = math.prod(_grid_shape(lo, hi, voxel))
        if count <= max_voxels:
            return lo, hi, voxel, trunc
        voxel *= 1.001 * (count / max_voxels) ** (1.0 / 3.0)
    raise ParameterError(f"no voxel size fits the volume into {{max_voxels}} {max_voxels:,} "
                         "voxels: pass a larger {max_voxels}", max_voxels="max_voxels")


def tsdf_mesh(views: list[DepthView], params: TSDFParams = TSDFParams()) -> Mesh:
    """Integrate every view into one TSDF volume and extract its mesh.

    Parameters
    ----------
    views : list of DepthView
        Dense (filled) or exact depth maps; a view's pixels without depth are skipped.
    params : TSDFParams

    Returns
    -------
    Mesh
        Vertices in world metres.
    """
    lo, hi, voxel, truncation = tsdf_grid(views, params)
    volume = TSDFVolume(lo, hi, voxel, truncation, max_voxels=params.max_voxels,
                        inverse_depth_step=params.inverse_depth_step,
                        search_radius=params.search_radius)
    for view in views:
        volume.integrate(view)
    return volume.mesh()
