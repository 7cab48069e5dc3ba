"""The ``mesh`` filling method: robust surfaces where a region has one, a triangle mesh of the
map where its points agree, and never a depth between two surfaces the map tells apart.

The paper fills a selected region with one weighted *mean* depth; ``plane``
(:mod:`fusion.surface_fit`) fits one surface per region and leaves a region empty when no plane
or quadric explains it, which is most of a height field. ``mesh`` keeps ``plane``'s fits and
fills much of the rest from a Delaunay triangulation of the map, interpolating *inverse depth*
in the undistorted normalised coordinates of the pixels (exact for any plane: see
:mod:`fusion.surface_fit`), but only across triangles whose corners lie on one surface.

Steps, each on the output of the one before:

1. **Clean the map.** Each map point gets a local plane in inverse depth: least squares over
   itself and its ``neighbours`` nearest map points (pixel distance) whose depth is within
   ``similar_rel`` (15 %) of its own, all weighted 1. The point is kept when that plane
   predicts its own depth and at least ``min_support`` (3) of its neighbours' within
   ``agree_rel`` (2 %).
   Points along an edge or on a slanted surface support each other; an isolated wrong depth
   (an EMVS outlier, ``oracle-noisy``'s outliers) does not. Every later step sees the kept
   points only.
2. **Surfaces** (stage 1): ``plane`` on the kept points (:func:`fusion.surface_fit.surface_fill`
   with this method's ``SurfaceFitParams`` fields): accepted regions take the fitted surface.
3. **Consistent triangles** (stage 2): each kept point's local plane is fitted again, among
   the kept points only and the point itself weighted 10. A Delaunay triangle of the kept points is
   *consistent* when each corner's local plane predicts the other two corners' depths within
   ``consistency_rel`` (5 %): its three corners lie on one smooth surface, and a triangle that
   spans a depth discontinuity (corners on both sides of a step, a silhouette) is not. Pixels in
   a consistent triangle take the barycentric (linear) interpolation of its corners' inverse
   depths: exact for a plane, wherever the triangle is.
4. **Other triangles of the paper's regions** (stage 3): in the regions the paper selects
   (:func:`fusion.filling.select_regions` on the kept points), pixels still empty in a triangle
   whose corners' depths span at most ``max_jump_rel`` (20 %) take a Clough-Tocher (C1,
   piecewise cubic) interpolation of inverse depth, clipped to the range of the triangle's
   corners (``smooth=False``: linear). A smooth surface sampled sparsely (a height field) is
   followed closely; a step larger than ``max_jump_rel`` is never bridged.
5. **Beyond the mesh** (stage 4): pixels of the selected regions *outside* the mesh (beyond the
   convex hull of the kept points, at the frame's borders) take the depth of their nearest kept
   point (pixel distance). Its local plane extrapolated over tens of pixels did worse (the
   height field with a map on the frame's Canny edges: 4.9 cm against 3.7). Inside the mesh, a
   pixel that no consistent or small-jump triangle covers lies between surfaces the map tells
   apart (the sphere's cast shadow, bounded by the sphere's outline and
   the wall's): it stays empty, where the paper's weighted mean puts it between them.

Map points keep their own depth. A point step 1 dropped takes the depth a stage gives its
pixel, else keeps its own (the bench and ``evfuse fill`` require every map point to have a
depth). The confidence is ordinal, by stage: stage 1 the fit's inlier share (>= 0.7 by
default), stage 2 0.75, stage 3 0.5, stage 4 0.25; 0 for map points and empty pixels.

Where it fails: a map that outlines a region without points inside it (a plain wall between two
edges) gets the linear interpolation between the edges, right only if the wall is flat; regions
the paper does not select, and no consistent triangle covers, stay empty, and so does the inside
of the mesh where the map's own errors break its triangles (on the event map of the height
field, 52 % of the frame filled where the paper fills 95 %); a smooth surface that
curves more than ``consistency_rel`` between map points is left to stages 3-4, and one that
curves more than ``agree_rel`` across a point's neighbours loses points to the cleaning (10 of
134 on the egg crate of ``tests/test_mesh_fill.py``); on a map noisier than ``agree_rel`` the
cleaning keeps the points nearest their neighbours' plane, fewer as the noise grows.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.interpolate import CloughTocher2DInterpolator
from scipy.spatial import Delaunay, QhullError, cKDTree

from fusion.surface_fit import SurfaceFitParams, _check_frame, _method, surface_fill
from sim.camera import Camera

__all__ = ["MeshFill", "MeshParams", "clean_map", "consistent_triangles", "local_planes",
           "mesh_fill"]

STAGE_CONFIDENCE = {2: 0.75, 3: 0.5, 4: 0.25}
"""Confidence of the pixels filled by stages 2-4 (stage 1 takes its fit's inlier share)."""
SELF_WEIGHT_CLEANING = 3.0
"""Weight of a point in its own plane when the map is cleaned (its neighbours weigh 1 each)."""


@dataclass(frozen=True)
class MeshParams(SurfaceFitParams):
    """Settings of ``mesh`` (:func:`mesh_fill`): those of ``plane`` (stage 1) and the mesh's.

    Attributes
    ----------
    neighbours : int
        Nearest map points a point is compared with (cleaning) and fitted over (local planes)
        (default 12).
    agree_rel : float
        A neighbour supports a point when their depths differ by at most this share
        (default 0.02).
    min_support : int
        Fewest supporting neighbours a point needs to be kept (default 3; 0 keeps every point).
    similar_rel : float
        Neighbours within this relative depth of a point enter its local plane (default 0.15).
    consistency_rel : float
        A triangle is consistent when every corner's local plane predicts the other corners'
        depths within this share (default 0.05).
    max_jump_rel : float
        Stage 3 uses a triangle when its corners' largest depth is at most ``1 + max_jump_rel``
        times its smallest (default 0.2).
    smooth : bool
        Stage 3 interpolates with Clough-Tocher (True, default) or linearly (False).
    """

    neighbours: int = 12
    agree_rel: float = 0.02
    min_support: int = 3
    similar_rel: float = 0.15
    consistency_rel: float = 0.05
    max_jump_rel: float = 0.2
    smooth: bool = True

    _POSITIVE = SurfaceFitParams._POSITIVE + ("agree_rel", "similar_rel", "consistency_rel",
                                              "max_jump_rel")
    _COUNTS = {**SurfaceFitParams._COUNTS, "neighbours": 3, "min_support": 0}

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_support > self.neighbours:
            raise ValueError(f"min_support must be <= neighbours, got {self.min_support} > "
                             f"{self.neighbours}")
        if not isinstance(self.smooth, bool):
            raise ValueError(f"smooth must be true or false, got {self.smooth!r}")


@dataclass(frozen=True, eq=False)
class MeshFill:
    """The result of :func:`mesh_fill`.

    Attributes
    ----------
    dense : (H, W) float32 ndarray, metres, 0 = none
        Map points and filled pixels.
    confidence : (H, W) float32 ndarray in [0, 1]
        By stage (see the module's description); 0 for map points and empty pixels.
    stage : (H, W) uint8 ndarray
        The stage 1-4 that filled a pixel; 0 for map points and empty pixels.
    kept : (H, W) bool ndarray
        The map points the cleaning kept.
    """

    dense: np.ndarray
    confidence: np.ndarray
    stage: np.ndarray
    kept: np.ndarray


def clean_map(sparse: np.ndarray, camera: Camera, neighbours: int = 12,
              agree_rel: float = 0.02, similar_rel: float = 0.15, min_support: int = 3
              ) -> np.ndarray:
    """The map points that enough of their neighbours agree with (step 1 of ``mesh``).

    Each point's local plane in inverse depth (:func:`local_planes`) is fitted to it and its
    similar neighbours, all weighted 1; a neighbour *supports* the point when that plane
    predicts the neighbour's depth within ``agree_rel``, and the point is kept when the plane
    predicts its own depth too and ``min_support`` neighbours support it. On a slanted or curved
    surface the neighbours lie on the point's plane and support it; an isolated wrong depth
    has no similar neighbour, its plane is flat through itself, and nothing supports it.

    Parameters
    ----------
    sparse : (H, W) float ndarray, metres, 0 = no map point
    camera : Camera
        The map's calibration (planes are fitted in undistorted normalised coordinates).
    neighbours : int
        Nearest other map points (Euclidean pixel distance) each point is compared with.
    agree_rel : float
        Largest relative depth error of a supporting neighbour.
    similar_rel : float
        Neighbours within this relative depth of the point enter its plane.
    min_support : int
        Fewest supporting neighbours a kept point has (0 keeps every point).

    Returns
    -------
    (H, W) bool ndarray
        True at the kept map points.
    """
    xy_all = camera.normalized_pixel_centres()
    ys, xs = np.nonzero((sparse > 0) & np.isfinite(xy_all).all(axis=2))
    kept = np.zeros(sparse.shape, bool)
    if min_support == 0:
        kept[sparse > 0] = True
        return kept
    if ys.size <= min_support:
        return kept
    xy, w = xy_all[ys, xs], 1.0 / sparse[ys, xs].astype(np.float64)
    planes, near = local_planes(xy, w, np.stack([xs, ys], axis=1).astype(np.float64),
                                neighbours, similar_rel, SELF_WEIGHT_CLEANING)
    offset = xy[near] - xy[:, None, :]
    predicted = planes[:, None, 0] + (planes[:, None, 1:] * offset).sum(axis=2)
    agree = np.abs(predicted / w[near] - 1) <= agree_rel
    keep = agree[:, 0] & (agree[:, 1:].sum(axis=1) >= min_support)
    kept[ys[keep], xs[keep]] = True
    return kept


def local_planes(xy: np.ndarray, w: np.ndarray, pixels: np.ndarray, neighbours: int,
                 similar_rel: float, self_weight: float = 10.0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per point, a plane in inverse depth about it, fitted to its similar neighbours.

    Parameters
    ----------
    xy : (N, 2) float ndarray
        Undistorted normalised coordinates of the points.
    w : (N,) float ndarray, 1/m
        Their inverse depths.
    pixels : (N, 2) float ndarray, pixels
        Their pixel coordinates (neighbours are the nearest in the image).
    neighbours : int
        Nearest other points considered.
    similar_rel : float
        Neighbours whose inverse depth is within this share of the point's enter the fit (the
        point itself with weight 10, each neighbour with weight 1).

    Returns
    -------
    planes : (N, 3) float ndarray
        ``(a, b, c)``: ``w(p) = a + b (p - p_i)_x + c (p - p_i)_y``, least squares. A point
        whose similar neighbours are collinear gets the flattest plane through them.
    near : (N, k) int ndarray
        Each point's index followed by its ``k - 1 = min(neighbours, N - 1)`` nearest.
    """
    _, near = cKDTree(pixels).query(pixels, k=min(neighbours + 1, len(w)))
    weight = (np.abs(w[near] / w[:, None] - 1) <= similar_rel).astype(np.float64)
    weight[:, 0] = self_weight                            # the point itself
    offset = xy[near] - xy[:, None, :]
    basis = np.stack([np.ones(near.shape), offset[..., 0], offset[..., 1]], axis=-1)
    root = np.sqrt(weight)[..., None]
    a, b = basis * root, w[near] * root[..., 0]
    normal = np.einsum("nki,nkj->nij", a, a)
    normal[:, 1, 1] += 1e-12                              # a tiny ridge on the slopes only
    normal[:, 2, 2] += 1e-12
    planes = np.linalg.solve(normal, np.einsum("nki,nk->ni", a, b)[..., None])[..., 0]
    return planes, near


def consistent_triangles(xy: np.ndarray, inverse_depth: np.ndarray, triangles: np.ndarray,
                         planes: np.ndarray, consistency_rel: float) -> np.ndarray:
    """Whether each triangle's corners lie on one surface (step 3 of ``mesh``).

    Parameters
    ----------
    xy : (N, 2) float ndarray
        The points' undistorted normalised coordinates.
    inverse_depth : (N,) float ndarray, 1/m
    triangles : (T, 3) int ndarray
        Indices of each triangle's corners.
    planes : (N, 3) float ndarray
        Each point's local plane ``(a, b, c)``: ``w(p) = a + b (p - p_i)_x + c (p - p_i)_y``.
    consistency_rel : float
        Largest relative error of a corner's depth predicted by another corner's plane.

    Returns
    -------
    (T,) bool ndarray
    """
    ok = np.ones(len(triangles), bool)
    for i in range(3):
        for j in range(3):
            if i == j:
                continue
            a, b = triangles[:, i], triangles[:, j]
            offset = xy[b] - xy[a]
            predicted = planes[a, 0] + (planes[a, 1:] * offset).sum(axis=1)
            # |z_b / z_predicted - 1| = |w_predicted / w_b - 1|
            ok &= np.abs(predicted / inverse_depth[b] - 1) <= consistency_rel
    return ok


def _triangulation(xy: np.ndarray) -> Delaunay | None:
    """Delaunay triangulation of the points, None when there is none (fewer than 3 points, or
    all on a line)."""
    if len(xy) < 3:
        return None
    try:
        return Delaunay(xy)
    except QhullError:
        return None


def _barycentric(mesh: Delaunay, simplex: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) barycentric coordinates of points (N, 2) in their triangles (N,) of ``mesh``."""
    transform = mesh.transform[simplex]
    bary = np.einsum("nij,nj->ni", transform[:, :2], points - transform[:, 2])
    return np.column_stack([bary, 1 - bary.sum(axis=1)])


def _locate(mesh: Delaunay, pixels: np.ndarray, query: np.ndarray, finite: np.ndarray,
            shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The triangle of ``mesh`` each pixel lies in (-1 outside), and the barycentric
    coordinates of the pixels inside (in flat pixel order): the triangles are rasterised by
    their corners' pixels (fast), and the few pixels whose barycentric coordinates in the
    mesh's own (undistorted) coordinates come out negative, where the lens bends an edge, are
    located exactly (:meth:`scipy.spatial.Delaunay.find_simplex`)."""
    index = np.full(shape, -1, np.int32)
    corners = pixels[mesh.simplices].astype(np.int32)
    for label, triangle in enumerate(corners):
        cv2.fillConvexPoly(index, triangle, label)
    simplex = np.where(finite, index.reshape(-1), -1)
    inside = np.flatnonzero(simplex >= 0)
    bary = _barycentric(mesh, simplex[inside], query[inside])
    wrong = inside[(bary < -1e-9).any(axis=1)]
    # Pixels just outside the rasterised triangles (an edge bent outward) may lie in the mesh.
    covered = (index >= 0).astype(np.uint8)
    rim = cv2.dilate(covered, np.ones((5, 5), np.uint8)).astype(bool) & ~covered.astype(bool)
    missed = np.flatnonzero(finite & rim.reshape(-1))
    recheck = np.concatenate([wrong, missed])
    if recheck.size:
        simplex[recheck] = mesh.find_simplex(query[recheck])
        inside = np.flatnonzero(simplex >= 0)
        bary = _barycentric(mesh, simplex[inside], query[inside])
    return simplex, bary


def mesh_fill(frame: np.ndarray, sparse: np.ndarray, camera: Camera,
              params: MeshParams | None = None) -> MeshFill:
    """``mesh``: surfaces, consistent triangles, smooth triangles, extrapolation (see the
    module).

    ``frame``, ``sparse``, ``camera`` and the errors raised are those of
    :func:`fusion.surface_fit.surface_fill`; ``params`` defaults to ``MeshParams()``.
    Returns a :class:`MeshFill`.
    """
    params = params or MeshParams()
    frame, sparse = _check_frame(frame, sparse, camera)
    kept = clean_map(sparse, camera, params.neighbours, params.agree_rel, params.similar_rel,
                     params.min_support)
    clean = np.where(kept, sparse, 0).astype(np.float32)
    out = np.zeros(sparse.shape, np.float32)
    confidence = np.zeros(sparse.shape, np.float32)
    stage = np.zeros(sparse.shape, np.uint8)

    def take(values: np.ndarray, where: np.ndarray, level: int, conf) -> None:
        where = where & (stage == 0) & ~kept & (values > 0) & np.isfinite(values)
        out[where] = values[where]
        confidence[where] = conf[where] if isinstance(conf, np.ndarray) else conf
        stage[where] = level

    if kept.any():
        surfaces = surface_fill(frame, clean, camera, params)     # reads plane's fields only
        take(surfaces.dense, surfaces.confidence > 0, 1, surfaces.confidence)

        xy_all = camera.normalized_pixel_centres()
        ys, xs = np.nonzero(kept & np.isfinite(xy_all).all(axis=2))
        xy, w = xy_all[ys, xs], 1.0 / clean[ys, xs].astype(np.float64)
        mesh = _triangulation(xy)
        if mesh is not None:
            planes = local_planes(xy, w, np.stack([xs, ys], axis=1).astype(np.float64),
                                  params.neighbours, params.similar_rel)[0]
            good = consistent_triangles(xy, w, mesh.simplices, planes, params.consistency_rel)
            query = xy_all.reshape(-1, 2)
            finite = np.isfinite(query).all(axis=1)
            simplex, bary = _locate(mesh, np.stack([xs, ys], axis=1), query, finite,
                                    sparse.shape)
            inside = simplex >= 0
            corners = np.full((len(query), 3), np.nan)
            corners[inside] = w[mesh.simplices[simplex[inside]]]

            # Stage 2: barycentric interpolation on the consistent triangles.
            linear = np.zeros(len(query))
            linear[inside] = 1.0 / (bary * corners[inside]).sum(axis=1)
            use = inside.copy()
            use[inside] = good[simplex[inside]]
            take(linear.reshape(sparse.shape), use.reshape(sparse.shape), 2,
                 STAGE_CONFIDENCE[2])

            # Stage 3: the other triangles of the paper's regions, small jumps only.
            region = (np.zeros(sparse.shape, bool) if surfaces.regions is None
                      else surfaces.regions.selected[surfaces.labels])
            low, high = np.full(len(query), np.inf), np.zeros(len(query))
            low[inside], high[inside] = corners[inside].min(axis=1), corners[inside].max(axis=1)
            use = (inside & region.reshape(-1) & (stage.reshape(-1) == 0)
                   & (high <= (1 + params.max_jump_rel) * low))
            smooth = np.zeros(len(query))
            if use.any():
                at = use[inside]                    # the inside pixels stage 3 fills
                if params.smooth:
                    values = CloughTocher2DInterpolator(mesh, w)(query[use])
                else:
                    values = (bary[at] * corners[use]).sum(axis=1)
                smooth[use] = 1.0 / np.clip(values, low[use], high[use])
            take(smooth.reshape(sparse.shape), use.reshape(sparse.shape), 3,
                 STAGE_CONFIDENCE[3])
            # Stage 4: beyond the mesh, in the paper's regions, the nearest kept point's depth.
            beyond = region.reshape(-1) & finite & (simplex < 0) & (stage.reshape(-1) == 0)
            extrapolated = np.zeros(len(query))
            if beyond.any():
                v, u = np.divmod(np.flatnonzero(beyond), sparse.shape[1])
                _, nearest = cKDTree(np.stack([xs, ys], axis=1)).query(np.stack([u, v], axis=1))
                extrapolated[beyond] = 1.0 / w[nearest]
            take(extrapolated.reshape(sparse.shape), beyond.reshape(sparse.shape), 4,
                 STAGE_CONFIDENCE[4])

    dense = np.where(kept, sparse, out)
    dropped = (sparse > 0) & ~kept & (stage == 0)
    dense[dropped] = sparse[dropped]
    return MeshFill(dense.astype(np.float32), confidence, stage, kept)


mesh_method = _method("mesh", "plane's surfaces, then a Delaunay mesh of the cleaned map across "
                             "triangles on one surface; never a depth between two surfaces; "
                             "inverse depth", mesh_fill, MeshParams)
