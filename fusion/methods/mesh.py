"""The ``mesh`` filling method: robust surfaces where a region has one, a triangle mesh of the
map where its points agree, and never a depth between two surfaces the map tells apart.

The paper fills a selected region with one weighted *mean* depth; ``plane``
(:mod:`fusion.methods.surface_fit`) fits one surface per region and leaves a region empty when no
plane
or quadric explains it, which is most of a height field. ``mesh`` keeps ``plane``'s fits and
fills much of the rest from a Delaunay triangulation of the map, interpolating *inverse depth*
in the undistorted normalised coordinates of the pixels (exact for any plane: see
:mod:`fusion.methods.surface_fit`), but only across triangles whose corners lie on one surface.

Steps, each on the output of the one before:

1. **Clean the map.** Each map point gets a local plane in inverse depth: least squares over
   itself and its ``neighbours`` nearest map points (pixel distance) whose depth is within
   ``similar_rel`` (15 %) of its own, all weighted 1. The point is kept when that plane
   predicts its own depth and at least ``min_support`` (3) of its neighbours' within
   ``agree_rel`` (2 %).
   Points along an edge or on a slanted surface support each other; an isolated wrong depth
   (an EMVS outlier, ``oracle-noisy``'s outliers) does not. Every later step sees the kept
   points only.
2. **Surfaces** (stage 1): ``plane`` on the kept points
   (:func:`fusion.methods.surface_fit.surface_fill` with this method's ``SurfaceFitParams``
   fields): accepted regions take the fitted surface.
3. **Consistent triangles** (stage 2): each kept point's local plane is fitted again, among
   the kept points only and the point itself weighted 10. A Delaunay triangle of the kept points is
   *consistent* when each corner's local plane predicts the other two corners' depths within
   ``consistency_rel`` (5 %): its three corners lie on one smooth surface, and a triangle that
   spans a depth discontinuity (corners on both sides of a step, a silhouette) is not. Pixels in
   a consistent triangle take the barycentric (linear) interpolation of its corners' inverse
   depths: exact for a plane, wherever the triangle is.
4. **Other triangles of the paper's regions** (stage 3): in the regions the paper selects
   (:func:`fusion.fill.filling.select_regions` on the kept points), pixels still empty in a triangle
   whose corners' depths span at most ``max_jump_rel`` (20 %) take a cubic interpolation of
   inverse depth, clipped to the range of the triangle's corners (``smooth=False``: linear):
   one cubic Bezier triangle per triangle, from its corners' values and gradients (PN
   triangles' centre rule, so that a quadratic is reproduced exactly from exact gradients;
   continuous across edges, C1 at the corners). The gradients are Nielson's global estimate
   (the one SciPy's Clough-Tocher interpolator uses: the least squared second derivative along
   every mesh edge), over the edges to similar corners (``similar_rel``) only. A smooth surface
   sampled sparsely (a height field) is followed closely; a step larger than ``max_jump_rel``
   is never bridged.
5. **Beyond the mesh** (stage 4): pixels of the selected regions *outside* the mesh (beyond the
   convex hull of the kept points, at the frame's borders) take the depth of their nearest kept
   point (pixel distance). Its local plane extrapolated over tens of pixels did worse (the
   height field with a map on the frame's Canny edges: 4.9 cm against 3.7). Inside the mesh, a
   pixel that no consistent or small-jump triangle covers lies between surfaces the map tells
   apart (the sphere's cast shadow, bounded by the sphere's outline and
   the wall's): it stays empty, where the paper's weighted mean puts it between them.

The mesh is OpenCV's Delaunay triangulation (:func:`_triangulation`); each pixel is located in
it by testing, in the mesh's own coordinates, the pixels near each triangle
(:data:`LOCATE_MARGIN_PX`), and the hot loops (RANSAC's hypotheses, the local planes, the
location, the gradients and the patches) are compiled with numba.

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
import numba
import numpy as np
from scipy import ndimage

from fusion.methods.surface_fit import (
    SurfaceFitParams,
    _method,
    check_frame,
    solve_small,
    surface_fill,
)
from sim.camera import Camera

__all__ = ["MeshFill", "MeshParams", "clean_map", "consistent_triangles", "local_planes",
           "mesh_fill"]

_CORNER_PAIRS = np.array([[0, 1], [0, 2], [1, 0], [1, 2], [2, 0], [2, 1]], np.int64)
"""The ordered pairs of a triangle's corners."""
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
        Stage 3 interpolates with cubic patches (True, default) or linearly (False).
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
    k = near.shape[1]
    agree = _predicts(xy, w, planes, np.repeat(np.arange(len(w)), k), near.ravel(),
                      agree_rel).reshape(-1, k)
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
    near = _nearest_pixels(np.ascontiguousarray(np.rint(pixels), np.int64),
                           min(neighbours + 1, len(w)))
    planes = _fit_local_planes(np.ascontiguousarray(xy, np.float64),
                               np.ascontiguousarray(w, np.float64), near, similar_rel,
                               float(self_weight))
    return planes, near


@numba.njit(cache=True)
def _nearest_pixels(pixels: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` nearest points of each point (itself first), compiled, by rings of pixels.

    Parameters
    ----------
    pixels : (N, 2) int64 ndarray, distinct pixel columns and rows
    k : int, <= N

    Returns
    -------
    (N, k) int64 ndarray
        Indices by increasing Euclidean distance, the lower index first among equal ones.
        Exact: the square rings around a point are searched until the next ring lies farther
        than the k-th nearest found.
    """
    n = pixels.shape[0]
    u0, v0 = pixels[:, 0].min(), pixels[:, 1].min()
    width = pixels[:, 0].max() - u0 + 1
    height = pixels[:, 1].max() - v0 + 1
    grid = np.full((height, width), -1, np.int64)
    for i in range(n):
        grid[pixels[i, 1] - v0, pixels[i, 0] - u0] = i
    near = np.empty((n, k), np.int64)
    dist = np.empty(k, np.int64)
    for i in range(n):
        u, v = pixels[i, 0] - u0, pixels[i, 1] - v0
        found = 0
        r = 0
        while True:
            for dv in range(-r, r + 1):
                vv = v + dv
                if vv < 0 or vv >= height:
                    continue
                step = 1 if abs(dv) == r else 2 * r        # the ring only
                for du in range(-r, r + 1, max(step, 1)):
                    uu = u + du
                    if uu < 0 or uu >= width:
                        continue
                    j = grid[vv, uu]
                    if j < 0:
                        continue
                    d = du * du + dv * dv
                    if found == k and (d > dist[k - 1] or (d == dist[k - 1]
                                                           and j > near[i, k - 1])):
                        continue
                    at = min(found, k - 1)                 # insert, sorted by (d, index)
                    while at > 0 and (dist[at - 1] > d or (dist[at - 1] == d
                                                           and near[i, at - 1] > j)):
                        if at < k:
                            dist[at] = dist[at - 1]
                            near[i, at] = near[i, at - 1]
                        at -= 1
                    dist[at] = d
                    near[i, at] = j
                    found = min(found + 1, k)
            if found == k and r * r > dist[k - 1]:
                break
            if r > width + height:
                break
            r += 1
    return near


@numba.njit(cache=True)
def _fit_local_planes(xy: np.ndarray, w: np.ndarray, near: np.ndarray, similar_rel: float,
                      self_weight: float) -> np.ndarray:
    """:func:`local_planes`' weighted least squares, compiled: per point, the normal equations
    of ``(1, dx, dy)`` over its row of ``near`` (itself first), with a 1e-12 ridge on the
    slopes."""
    n, k = near.shape
    planes = np.zeros((n, 3))
    normal = np.empty((3, 3))
    rhs = np.empty(3)
    row = np.empty(3)
    for i in range(n):
        normal[:] = 0.0
        rhs[:] = 0.0
        for m in range(k):
            j = near[i, m]
            if m == 0:
                weight = self_weight
            elif abs(w[j] / w[i] - 1.0) <= similar_rel:
                weight = 1.0
            else:
                continue
            row[0], row[1], row[2] = 1.0, xy[j, 0] - xy[i, 0], xy[j, 1] - xy[i, 1]
            for a in range(3):
                rhs[a] += weight * row[a] * w[j]
                for b in range(3):
                    normal[a, b] += weight * row[a] * row[b]
        normal[1, 1] += 1e-12
        normal[2, 2] += 1e-12
        solve_small(normal, rhs, planes[i])
    return planes


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
    for i, j in _CORNER_PAIRS:
        ok &= _predicts(xy, inverse_depth, planes, triangles[:, i], triangles[:, j],
                        consistency_rel)
    return ok


@numba.njit(cache=True)
def _predicts(xy: np.ndarray, inverse_depth: np.ndarray, planes: np.ndarray, a: np.ndarray,
              b: np.ndarray, tolerance: float) -> np.ndarray:
    """Whether point ``a[k]``'s local plane predicts point ``b[k]``'s depth within
    ``tolerance`` (``|z_b / z_predicted - 1| = |w_predicted / w_b - 1|``), compiled."""
    out = np.empty(a.shape[0], np.bool_)
    for k in range(a.shape[0]):
        p, q = a[k], b[k]
        predicted = (planes[p, 0] + planes[p, 1] * (xy[q, 0] - xy[p, 0])
                     + planes[p, 2] * (xy[q, 1] - xy[p, 1]))
        out[k] = abs(predicted / inverse_depth[q] - 1.0) <= tolerance
    return out


def _triangulation(xy: np.ndarray) -> np.ndarray | None:
    """Delaunay triangulation of the points (OpenCV's ``Subdiv2D``, 3-10 times faster than
    Qhull's here; on the points scaled to 4096 units and rounded to float32, which moves none
    by more than 1e-7 of their spread: only the choice between near-cocircular triangulations
    can differ from an exact one).

    Returns
    -------
    (T, 3) int64 ndarray or None
        Each triangle's point indices; None when there is none (fewer than 3 points, or all on
        a line).
    """
    if len(xy) < 3:
        return None
    low = xy.min(axis=0)
    spread = float((xy.max(axis=0) - low).max())
    if not spread > 0:
        return None
    scaled = ((xy - low) * (4096.0 / spread) + 1.0).astype(np.float32)
    # OpenCV's three outer vertices lie a few rectangle sizes away: with the points in a
    # rectangle just around them, they would take some thin triangles of the hull.
    far = 1 << 20
    subdiv = cv2.Subdiv2D((-far, -far, 2 * far + 4100, 2 * far + 4100))
    subdiv.insert(scaled.tolist())
    corners = np.asarray(subdiv.getTriangleList(), np.float32).reshape(-1, 3, 2)
    if not len(corners):
        return None
    key = scaled.view(np.uint64).ravel()                # (x, y) float32 bits as one integer
    order = np.argsort(key)
    found = np.searchsorted(key[order], np.ascontiguousarray(corners).view(np.uint64)[..., 0])
    return order[np.minimum(found, len(order) - 1)].astype(np.int64)


@numba.njit(cache=True)
def _ring_fit(points: np.ndarray, values: np.ndarray, start: np.ndarray, ring: np.ndarray,
              similar_rel: float, initial: np.ndarray, tolerance: float, max_iterations: int
              ) -> np.ndarray:
    """Each vertex's gradient, compiled: the gradients that minimise the squared second
    derivative of the cubic along every mesh edge (Nielson's global estimate, the one
    SciPy's Clough-Tocher interpolator uses), by Gauss-Seidel sweeps from ``initial`` until no
    gradient changes by more than ``tolerance`` (relative to max(1, |gradient|)) or
    ``max_iterations``. Only the neighbours whose value is within ``similar_rel`` of the
    vertex's take part (an edge across a depth step says nothing of either side's slope); a
    vertex with fewer than 2 of them keeps ``initial``'s row.

    Vertex ``i``'s update solves ``Q_i g_i = c_i - 2 sum_k M_k g_k`` with, over its edges
    ``e_k`` (length ``L_k``), ``M_k = e_k e_k^T / L_k^3``, ``Q_i = 4 sum_k M_k`` and
    ``c_i = 6 sum_k (f_k - f_i) e_k / L_k^3``: all but the neighbours' gradients are fixed, and
    computed once."""
    n = points.shape[0]
    grad = initial.copy()
    m = np.zeros((ring.shape[0], 3))                   # M_k: xx, xy, yy
    use = np.zeros(ring.shape[0], np.bool_)
    inverse = np.zeros((n, 3))                         # Q_i^-1: xx, xy, yy
    constant = np.zeros((n, 2))
    active = np.zeros(n, np.bool_)
    for i in range(n):
        q00 = q01 = q11 = c0 = c1 = 0.0
        count = 0
        for k in range(start[i], start[i + 1]):
            j = ring[k]
            if abs(values[j] / values[i] - 1.0) > similar_rel:
                continue
            ex = points[j, 0] - points[i, 0]
            ey = points[j, 1] - points[i, 1]
            length3 = (ex * ex + ey * ey) ** 1.5
            if length3 == 0.0:
                continue
            count += 1
            use[k] = True
            m[k, 0], m[k, 1], m[k, 2] = ex * ex / length3, ex * ey / length3, ey * ey / length3
            q00 += 4.0 * m[k, 0]
            q01 += 4.0 * m[k, 1]
            q11 += 4.0 * m[k, 2]
            c0 += 6.0 * (values[j] - values[i]) * ex / length3
            c1 += 6.0 * (values[j] - values[i]) * ey / length3
        det = q00 * q11 - q01 * q01
        if count >= 2 and det != 0.0:
            active[i] = True
            inverse[i, 0], inverse[i, 1], inverse[i, 2] = q11 / det, -q01 / det, q00 / det
            constant[i, 0], constant[i, 1] = c0, c1
    for _ in range(max_iterations):
        change = 0.0
        for i in range(n):
            if not active[i]:
                continue
            s0, s1 = constant[i, 0], constant[i, 1]
            for k in range(start[i], start[i + 1]):
                if use[k]:
                    j = ring[k]
                    s0 -= 2.0 * (m[k, 0] * grad[j, 0] + m[k, 1] * grad[j, 1])
                    s1 -= 2.0 * (m[k, 1] * grad[j, 0] + m[k, 2] * grad[j, 1])
            g0 = inverse[i, 0] * s0 + inverse[i, 1] * s1
            g1 = inverse[i, 1] * s0 + inverse[i, 2] * s1
            step = max(abs(g0 - grad[i, 0]), abs(g1 - grad[i, 1]))
            change = max(change, step / max(1.0, abs(g0), abs(g1)))
            grad[i, 0], grad[i, 1] = g0, g1
        if change < tolerance:
            break
    return grad


GRADIENT_TOLERANCE = 1e-6
"""Stop the gradients' sweeps when none changes by more than this (relative)."""
GRADIENT_MAX_ITERATIONS = 400
"""At most this many sweeps (SciPy's default for its Clough-Tocher gradients)."""


def _vertex_slopes(points: np.ndarray, values: np.ndarray, triangles: np.ndarray,
                   similar_rel: float, initial: np.ndarray) -> np.ndarray:
    """(N, 2) gradient of ``values`` at each mesh vertex (:func:`_ring_fit`)."""
    start, ring = _neighbours(triangles, len(points))
    return _ring_fit(np.ascontiguousarray(points, np.float64), values, start, ring,
                     similar_rel, np.ascontiguousarray(initial, np.float64),
                     GRADIENT_TOLERANCE, GRADIENT_MAX_ITERATIONS)


@numba.njit(cache=True)
def _neighbours(triangles: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex's neighbours in a mesh, compiled: ``ring[start[i]:start[i + 1]]`` are the
    distinct vertices that share an edge with vertex ``i``, in order of first appearance."""
    degree = np.zeros(n + 1, np.int64)
    for t in range(triangles.shape[0]):
        for i in range(3):
            degree[triangles[t, i] + 1] += 2
    start = np.cumsum(degree)
    ring = np.empty(start[n], np.int64)
    count = np.zeros(n, np.int64)
    for t in range(triangles.shape[0]):
        for pair in range(6):
            a = triangles[t, _CORNER_PAIRS[pair, 0]]
            b = triangles[t, _CORNER_PAIRS[pair, 1]]
            seen = False
            for k in range(start[a], start[a] + count[a]):
                if ring[k] == b:
                    seen = True
                    break
            if not seen:
                ring[start[a] + count[a]] = b
                count[a] += 1
    compact = np.empty(count.sum(), np.int64)
    first = np.zeros(n + 1, np.int64)
    for a in range(n):
        first[a + 1] = first[a] + count[a]
        compact[first[a]:first[a + 1]] = ring[start[a]:start[a] + count[a]]
    return first, compact


@numba.njit(cache=True)
def _cubic_patch(points: np.ndarray, values: np.ndarray, slopes: np.ndarray,
                 simplices: np.ndarray, simplex: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """A cubic Bezier triangle per triangle, evaluated at barycentric coordinates, compiled.

    The edge control points follow each corner's slope along the edge (so the patch is C1 at
    its corners and two patches meet continuously along their shared edge, which depends on
    that edge's corners only); the centre point is the one that makes the patch reproduce any
    quadratic whose values and slopes the corners carry (PN triangles' rule,
    ``b111 = E + (E - V) / 2``).

    Parameters
    ----------
    points : (N, 2) float64, corners' coordinates
    values : (N,) float64, their values
    slopes : (N, 2) float64, their gradients
    simplices : (T, 3) int, triangles
    simplex : (M,) int, each query's triangle
    bary : (M, 3) float64, each query's barycentric coordinates

    Returns
    -------
    (M,) float64 ndarray
    """
    out = np.empty(simplex.shape[0])
    edge = np.empty((3, 3))                     # edge[i, j]: control point near i toward j
    for q in range(simplex.shape[0]):
        t = simplex[q]
        sum_edges = 0.0
        for pair in range(6):
            i, j = _CORNER_PAIRS[pair, 0], _CORNER_PAIRS[pair, 1]
            a, b = simplices[t, i], simplices[t, j]
            edge[i, j] = values[a] + (slopes[a, 0] * (points[b, 0] - points[a, 0])
                                      + slopes[a, 1] * (points[b, 1] - points[a, 1])) / 3.0
            sum_edges += edge[i, j]
        f0, f1, f2 = values[simplices[t, 0]], values[simplices[t, 1]], values[simplices[t, 2]]
        e = sum_edges / 6.0
        centre = e + (e - (f0 + f1 + f2) / 3.0) / 2.0
        l0, l1, l2 = bary[q, 0], bary[q, 1], bary[q, 2]
        out[q] = (f0 * l0 ** 3 + f1 * l1 ** 3 + f2 * l2 ** 3
                  + 3.0 * (edge[0, 1] * l0 * l0 * l1 + edge[0, 2] * l0 * l0 * l2
                           + edge[1, 0] * l1 * l1 * l0 + edge[1, 2] * l1 * l1 * l2
                           + edge[2, 0] * l2 * l2 * l0 + edge[2, 1] * l2 * l2 * l1)
                  + 6.0 * centre * l0 * l1 * l2)
    return out


LOCATE_MARGIN_PX = 2
"""A pixel is tested against a triangle when it lies within this many pixels of the bounding
box of the triangle's corners' pixels: exact wherever the lens moves a point of a triangle's
edge less than this far from the chord between its corners (a straight edge in the
undistorted coordinates is a curve in the image)."""


@numba.njit(cache=True)
def _rasterise(points: np.ndarray, pixels: np.ndarray, simplices: np.ndarray,
               query: np.ndarray, height: int, width: int, margin: int, eps: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Locate every pixel in the triangles of a mesh, compiled.

    Parameters
    ----------
    points : (N, 2) float64 ndarray, the mesh's vertices (undistorted normalised coordinates)
    pixels : (N, 2) int64 ndarray, their pixel columns and rows
    simplices : (T, 3) int ndarray, the triangles' vertex indices
    query : (H * W, 2) float64 ndarray, every pixel's undistorted coordinates (NaN: none)
    height, width : int
    margin : int, pixels around a triangle's corners' bounding box that are tested
    eps : float, barycentric coordinates down to ``-eps`` count as inside

    Returns
    -------
    simplex : (H * W,) int32 ndarray, the triangle of each pixel, -1 outside every triangle
    bary : (H * W, 3) float64 ndarray, its barycentric coordinates (undefined outside)
    """
    simplex = np.full(height * width, -1, np.int32)
    bary = np.zeros((height * width, 3))
    for t in range(simplices.shape[0]):
        i0, i1, i2 = simplices[t, 0], simplices[t, 1], simplices[t, 2]
        x0, y0 = points[i0, 0], points[i0, 1]
        e1x, e1y = points[i1, 0] - x0, points[i1, 1] - y0
        e2x, e2y = points[i2, 0] - x0, points[i2, 1] - y0
        det = e1x * e2y - e2x * e1y
        if det == 0.0:
            continue
        u_lo = max(min(pixels[i0, 0], pixels[i1, 0], pixels[i2, 0]) - margin, 0)
        u_hi = min(max(pixels[i0, 0], pixels[i1, 0], pixels[i2, 0]) + margin, width - 1)
        v_lo = max(min(pixels[i0, 1], pixels[i1, 1], pixels[i2, 1]) - margin, 0)
        v_hi = min(max(pixels[i0, 1], pixels[i1, 1], pixels[i2, 1]) + margin, height - 1)
        for v in range(v_lo, v_hi + 1):
            for u in range(u_lo, u_hi + 1):
                k = v * width + u
                if simplex[k] >= 0:
                    continue
                qx, qy = query[k, 0] - x0, query[k, 1] - y0
                b1 = (qx * e2y - e2x * qy) / det
                b2 = (e1x * qy - qx * e1y) / det
                b0 = 1.0 - b1 - b2
                if b0 >= -eps and b1 >= -eps and b2 >= -eps:   # NaN fails every test
                    simplex[k] = t
                    bary[k, 0], bary[k, 1], bary[k, 2] = b0, b1, b2
    return simplex, bary


def _locate(points: np.ndarray, simplices: np.ndarray, pixels: np.ndarray, query: np.ndarray,
            shape: tuple[int, int], first: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The triangle of a mesh each pixel lies in (-1 outside) and the barycentric coordinates
    of every pixel in it (flat pixel order), tested in the mesh's own (undistorted) coordinates
    ``points`` (N, 2) for the pixels near each triangle (:data:`LOCATE_MARGIN_PX`). A pixel on
    an edge shared by two triangles goes to the one ``first`` (T,) bool marks, else to the
    lower index."""
    order = np.argsort(~first, kind="stable")
    simplex, bary = _rasterise(np.ascontiguousarray(points, np.float64),
                               np.ascontiguousarray(pixels, np.int64),
                               np.ascontiguousarray(simplices[order]),
                               np.ascontiguousarray(query), shape[0], shape[1],
                               LOCATE_MARGIN_PX, 1e-9)
    inside = simplex >= 0
    simplex[inside] = order[simplex[inside]]
    return simplex, bary


def mesh_fill(frame: np.ndarray, sparse: np.ndarray, camera: Camera,
              params: MeshParams | None = None) -> MeshFill:
    """``mesh``: surfaces, consistent triangles, smooth triangles, extrapolation (see the
    module).

    ``frame``, ``sparse``, ``camera`` and the errors raised are those of
    :func:`fusion.methods.surface_fit.surface_fill`; ``params`` defaults to ``MeshParams()``.
    Returns a :class:`MeshFill`.
    """
    params = params or MeshParams()
    frame, sparse = check_frame(frame, sparse, camera)
    kept = clean_map(sparse, camera, params.neighbours, params.agree_rel, params.similar_rel,
                     params.min_support)
    clean = np.where(kept, sparse, 0).astype(np.float32)
    out = np.zeros(sparse.shape, np.float32)
    confidence = np.zeros(sparse.shape, np.float32)
    stage = np.zeros(sparse.shape, np.uint8)

    flat_stage, flat_kept = stage.reshape(-1), kept.reshape(-1)
    flat_out, flat_confidence = out.reshape(-1), confidence.reshape(-1)

    def take(where: np.ndarray, values: np.ndarray, level: int, conf=None) -> None:
        """Fill the empty pixels ``where`` (flat indices) with depths ``values``."""
        ok = (flat_stage[where] == 0) & ~flat_kept[where] & (values > 0) & np.isfinite(values)
        flat_out[where[ok]] = values[ok]
        flat_confidence[where[ok]] = STAGE_CONFIDENCE[level] if conf is None else conf[ok]
        flat_stage[where[ok]] = level

    if kept.any():
        surfaces = surface_fill(frame, clean, camera, params)     # reads plane's fields only
        fitted = np.flatnonzero(surfaces.confidence > 0)
        take(fitted, surfaces.dense.reshape(-1)[fitted], 1,
             surfaces.confidence.reshape(-1)[fitted])

        xy_all = camera.normalized_pixel_centres()
        ys, xs = np.nonzero(kept & np.isfinite(xy_all).all(axis=2))
        xy, w = xy_all[ys, xs], 1.0 / clean[ys, xs].astype(np.float64)
        triangles = _triangulation(xy)
        if triangles is not None:
            planes = local_planes(xy, w, np.stack([xs, ys], axis=1).astype(np.float64),
                                  params.neighbours, params.similar_rel)[0]
            good = consistent_triangles(xy, w, triangles, planes, params.consistency_rel)
            query = xy_all.reshape(-1, 2)
            simplex, bary = _locate(xy, triangles, np.stack([xs, ys], axis=1), query,
                                    sparse.shape, good)
            inside = np.flatnonzero(simplex >= 0)
            triangle = simplex[inside]
            corners = w[triangles[triangle]]                           # (n, 3) 1/m
            weights = bary[inside]

            # Stage 2: barycentric interpolation on the consistent triangles.
            use = good[triangle]
            take(inside[use], 1.0 / (weights[use] * corners[use]).sum(axis=1), 2)

            # Stage 3: the other triangles of the paper's regions, small jumps only.
            region = (np.zeros(sparse.shape, bool) if surfaces.regions is None
                      else surfaces.regions.selected[surfaces.labels]).reshape(-1)
            low = np.minimum(np.minimum(corners[:, 0], corners[:, 1]), corners[:, 2])
            high = np.maximum(np.maximum(corners[:, 0], corners[:, 1]), corners[:, 2])
            use = (region[inside] & (flat_stage[inside] == 0)
                   & (high <= (1 + params.max_jump_rel) * low))
            if use.any():
                if params.smooth:
                    slopes = _vertex_slopes(xy, w, triangles, params.similar_rel,
                                            planes[:, 1:])
                    values = _cubic_patch(xy, w, slopes, triangles, triangle[use],
                                          weights[use])
                else:
                    values = (weights[use] * corners[use]).sum(axis=1)
                take(inside[use], 1.0 / np.clip(values, low[use], high[use]), 3)

            # Stage 4: beyond the mesh, in the paper's regions, the nearest kept point's depth.
            finite = np.isfinite(query).all(axis=1)
            beyond = np.flatnonzero(region & finite & (simplex < 0) & (flat_stage == 0))
            if beyond.size:
                points = np.ones(sparse.shape, bool)
                points[ys, xs] = False
                rows, cols = ndimage.distance_transform_edt(points, return_distances=False,
                                                            return_indices=True)
                nearest = np.zeros(sparse.shape, np.float64)
                nearest[ys, xs] = 1.0 / w
                take(beyond, nearest[rows.reshape(-1)[beyond], cols.reshape(-1)[beyond]], 4)

    dense = np.where(kept, sparse, out)
    dropped = (sparse > 0) & ~kept & (stage == 0)
    dense[dropped] = sparse[dropped]
    return MeshFill(dense.astype(np.float32), confidence, stage, kept)


mesh_method = _method("mesh", "plane's surfaces, then a Delaunay mesh of the cleaned map across "
                             "triangles on one surface; never a depth between two surfaces; "
                             "inverse depth", mesh_fill, MeshParams)
