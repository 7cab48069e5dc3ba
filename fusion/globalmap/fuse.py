"""Multi-view consistent fusion of key views' depth maps in the world frame (issue 25, parts 2a,
2c and 4).

A point of view ``i`` is *seen* by another view ``j`` when it lies in front of ``j``'s camera
(z > 0), projects (:meth:`sim.camera.Camera.project`, distortion included) onto ``j``'s image
(rounded to the nearest pixel, :func:`fusion.fill.projection.nearest_per_pixel`'s rule) and its
undistorted normalised radius is within ``j``'s field of view (the largest radius of a pixel
centre: a lens polynomial can fold points far outside the field back into the image). A seen
point *agrees* with ``j`` when some point of ``j`` within ``search_radius`` pixels (a square
window around the pixel it lands on) has ``|z_ij - depth_j| <= depth_tolerance * depth_j``,
``z_ij`` the point's depth in ``j``. A point not seen by ``j`` (behind it, outside its image)
neither agrees nor counts against; a point that ``j`` sees behind a nearer surface (occluded)
finds only that surface's depth and does not agree.

Independent evidence only: with ``FusionParams.disjoint_events``, a view ``j`` whose events
overlap ``i``'s (:func:`fusion.globalmap.views.shares_events`: neighbouring key views share half
their events) is not asked, unless no view is disjoint from ``i`` (two or three key views): then
every other view is. Two maps of the same events make the same errors, so their agreement says
less (issue 40, slider_close: 80.4 % of the points confirmed by a view with disjoint events lie
within 1 % of their depth, 73.7 % of those confirmed by an event-sharing one). It is off by
default: with the few key views of a short window, the views left to confirm are the far ones,
which see less of the same surface, and recall falls more than precision rises (measured with
``benchmarks/bench_global.py --goals``' views, end views confirming only, 2 plane steps: on
slider_close 1 s, 5 views, precision at 1 % of depth 0.910 against 0.901, F 0.343 against
0.398; on boxes_6dof 3.5-5.5 s, 4 views, F at 5 cm 0.134 against 0.215).

A seen point that ``j`` does not confirm although ``j`` holds a point in the window where it
lands is *contradicted* by ``j`` (``j`` has its own depth there, another one). A semi-dense map
holds points only on the edges it saw: a view that holds no point where another's point lands
says nothing about it, it neither confirms nor contradicts.

Which points are kept (``FusionParams.reject``): ``"unconfirmed"`` keeps the points that at
least ``min_views`` other views confirm; ``"outvoted"`` also keeps those that no more views
contradict than confirm (:func:`kept_points`). The first throws away every point the others
cannot check: on a short window of key views far apart, most of them (issue 40, boxes_6dof
3.5-5.5 s, 4 views: the fused cloud held half the recall of the views' plain union, F at 5 cm
0.215 against the union's 0.359). The second drops only what the evidence is against: measured
there, F at 5 cm 0.36, precision 0.68 against the union's 0.62 (``benchmarks/bench_global.py
--goals``).

Fusion of the depths (``FusionParams.fuse_depth``, :func:`fused_depth_points`, as ESVO fuses a
point's inverse depth with its neighbours'): each kept point moves along its ray to the mean
inverse depth of its own and its confirming views' depths. Measured on the goal windows
(``map-global``'s other defaults): it raises precision and lowers recall, so it is off by
default. On slider_close 0-1 s the fused semi-dense cloud's precision at 1 % of depth rises
from 0.896 to 0.935 (F 0.413 to 0.411), the filled one's from 0.936 to 0.962 (F 0.775 to
0.782); on boxes_6dof 3.5-5.5 s precision at 5 cm rises from 0.664 to 0.694, recall falls from
0.246 to 0.235, F from 0.359 to 0.351 (under the views' plain union, 0.359).

* :func:`agreement_counts`: per point, how many other views agree (the multi-view check);
  :func:`evidence_counts` also how many contradict.
* :func:`fuse_views`: the kept points, merged per voxel into one world-frame cloud
  (:class:`FusedCloud`).
* :func:`fuse_into_view`: a reference view's own agreed points plus the others' agreed points
  projected into its pixels (a z-buffer): a denser, consistency-checked map in one view.
* :func:`view_agreement`: what a real recording can check without ground truth: the depth
  difference of overlapping views and the share of points other views confirm.

Cost: the match is a compiled kernel (numba) of ``(2 r + 1)^2`` look-ups per point and other
view, ``O(sum_i N_i (V - 1) (2 r + 1)^2)`` for ``V`` views of ``N_i`` points and search radius
``r``, after the same number of point projections in NumPy (``O(sum_i N_i (V - 1))``); memory
``O(max_i N_i)`` per view pair beside the views themselves. Measured on 2 loaded cores
(240x180 views of a room, r = 1): 10 views of 43,200 points in 0.20 s, 30 views of 10,800
points in 0.61 s (50-65 ns per point and other view). :func:`fuse_views` and
:func:`fuse_into_view` take the counts of :func:`agreement_counts` (``counts=``) so that a
caller fusing into every key view computes them once.

Merging: the kept points are binned in cubic voxels of ``voxel_size`` (aligned to the world
origin); each occupied voxel gives the mean of its points, which lies in the voxel (within
``sqrt(3) voxel_size`` of each point merged) and on the surface where the voxel's points lie on
one plane (a mean of coplanar points); where it straddles an edge of two faces, the mean is
off the nearer face by at most half the voxel's extent along that face's normal (the smaller
face's share, at most 1/2, times its points' distance to the other plane): ``voxel_size / 2``
for the faces of an axis-aligned box, ``sqrt(3) voxel_size / 2`` at worst. The default voxel
is one pixel's footprint at the views' typical depth: the median over views of ``median depth
/ fx`` (:func:`default_voxel_size`), so merging thins the cloud to about one point per pixel of
the views' resolution, no coarser.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from fusion.fill.projection import nearest_per_pixel
from fusion.globalmap.views import DepthView, shares_events, to_camera
from sim._summary import summary_repr
from sim.camera import Camera
from sim.validation import ParameterError, check_parameter, integer, positive

__all__ = ["REJECT_RULES", "FusedCloud", "FusionParams", "agreement_counts",
           "default_voxel_size", "evidence_counts", "fuse_into_view", "fuse_views",
           "fused_depth_points", "kept_points", "view_agreement"]

REJECT_RULES = ("unconfirmed", "outvoted")
""":attr:`FusionParams.reject`'s rules: which points the fusion drops."""


def _count(name: str, value: object) -> int:
    return integer(name, value, 0)


@dataclass(frozen=True)
class FusionParams:
    """Parameters of the multi-view consistency check and the merge.

    Attributes
    ----------
    min_views : int
        k: a point that at least this many OTHER views agree with is kept (0 keeps every
        point).
    depth_tolerance : float
        Relative depth tolerance of an agreement: ``|z_seen - z_view| <= depth_tolerance *
        z_view`` (default 0.02, 2 %).
    search_radius : int, pixels
        A projected point agrees with any point of the other view within this many pixels
        (a square window around the pixel it lands on; semi-dense maps are thin edges).
    voxel_size : float or None, metres
        The merge voxel; None: :func:`default_voxel_size` of the views.
    disjoint_events : bool
        Count only the views whose events are disjoint from the point's view's
        (:func:`fusion.globalmap.views.shares_events`; default False, see the module's
        docstring). Views without a recorded event window are always counted.
    inverse_depth_tolerance : float or None, 1/metres
        A further agreement: ``|1/z_seen - 1/z_view| <= inverse_depth_tolerance`` (either one
        suffices). An EMVS map's depth is resolved in steps uniform in inverse depth, so its
        errors grow as ``z^2``: a relative tolerance that fits near points is under one plane
        step far away. None (default): the relative tolerance alone.
    reject : str
        Which points are dropped (:data:`REJECT_RULES`, :func:`kept_points`):
        ``"unconfirmed"`` (default), those that fewer than ``min_views`` other views agree
        with; ``"outvoted"``, only those of them that more other views contradict than agree
        with (a point no other view can check is kept).
    fuse_depth : bool
        Each kept point's depth is the mean, in inverse depth, of its own and of the depths
        that the views confirming it hold there (:func:`fused_depth_points`); default False
        (each point keeps its view's depth: measured in the module's docstring).
    """

    min_views: int = 1
    depth_tolerance: float = 0.02
    search_radius: int = 1
    voxel_size: float | None = None
    disjoint_events: bool = False
    inverse_depth_tolerance: float | None = None
    reject: str = "unconfirmed"
    fuse_depth: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "min_views", check_parameter(_count, "min_views",
                                                              self.min_views))
        object.__setattr__(self, "search_radius", check_parameter(_count, "search_radius",
                                                                  self.search_radius))
        object.__setattr__(self, "depth_tolerance", check_parameter(
            positive, "depth_tolerance", self.depth_tolerance))
        if self.voxel_size is not None:
            object.__setattr__(self, "voxel_size", check_parameter(
                positive, "voxel_size", self.voxel_size))
        if self.inverse_depth_tolerance is not None:
            object.__setattr__(self, "inverse_depth_tolerance", check_parameter(
                positive, "inverse_depth_tolerance", self.inverse_depth_tolerance))
        for name in ("disjoint_events", "fuse_depth"):
            if not isinstance(getattr(self, name), bool):
                raise ParameterError(f"{{{name}}} must be True or False, got "
                                     f"{getattr(self, name)!r}", **{name: name})
        if self.reject not in REJECT_RULES:
            raise ParameterError(f"{{reject}} must be one of {', '.join(REJECT_RULES)}, got "
                                 f"{ParameterError.literal(self.reject)}", reject="reject")


@dataclass
class FusedCloud:
    """The fused point cloud.

    Attributes
    ----------
    points : (N, 3) float64 ndarray, metres, world frame
        One point per occupied voxel: the mean of the kept points in it.
    support : (N,) int32 ndarray
        The most views that agreed on a point merged into the voxel, the point's own view
        included (``>= 1 + min_views`` unless ``FusionParams.reject`` is ``"outvoted"``).
    view : (N,) int32 ndarray
        Index of the view the voxel's first point came from (views in order, then each view's
        points in the order of :meth:`DepthView.pixels`).
    voxel_size : float, metres
        The merge voxel used (NaN when there was no point to derive it from).
    """

    points: np.ndarray
    support: np.ndarray
    view: np.ndarray
    voxel_size: float

    __repr__ = summary_repr


def _check_views(views: list[DepthView]) -> list[DepthView]:
    views = list(views)
    if not views:
        raise ParameterError("{views} is empty: fusion needs at least one depth view",
                             views="views")
    for index, view in enumerate(views):
        if not isinstance(view, DepthView):
            raise ParameterError(f"{{views}}[{index}] is a {type(view).__name__}, expected a "
                                 "DepthView", views="views")
    return views


def default_voxel_size(views: list[DepthView]) -> float:
    """The merge voxel from the data: one pixel's footprint at the views' typical depth.

    The rule: the median over the views that hold points of ``median(depth) / fx``.

    Parameters
    ----------
    views : list of DepthView

    Returns
    -------
    float, metres
        NaN when no view holds a point.
    """
    sizes = [float(np.median(view.depth[view.valid])) / view.camera.fx
             for view in views if view.valid.any()]
    return float(np.median(sizes)) if sizes else math.nan


def _field_radius2(camera: Camera) -> float:
    """The largest squared undistorted normalised radius of a pixel centre (inf without
    distortion: a pinhole's projection never folds)."""
    if not camera.has_distortion:
        return math.inf
    xy = camera.normalized_pixel_centres()
    return float(np.nanmax(np.sum(xy * xy, axis=-1)))


def _project(points_world: np.ndarray, view: DepthView, field_r2: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """World points in ``view``'s pixels: ``(uv (N, 2) float64, NaN where not seen; z (N,)
    float64, the depth in the view)``; not seen: behind the camera, beyond its field."""
    local = to_camera(points_world, view.T_world_cam)
    z = local[:, 2]
    uv = view.camera.project(local)
    if math.isfinite(field_r2):
        with np.errstate(all="ignore"):
            r2 = (local[:, 0] ** 2 + local[:, 1] ** 2) / (z * z)
        uv[~(r2 <= field_r2)] = np.nan
    return uv, z


@numba.njit(cache=True)
def _match(col, row, z, depth, radius, tolerance, inverse_tolerance, agree,
           nearest, matched):  # pragma: no cover - compiled
    """Per projected point (pixel ``(col, row)``, -1 where not seen, depth ``z``): ``agree``
    whether a point of ``depth`` in the window of ``radius`` pixels is within ``tolerance *
    depth`` or ``inverse_tolerance`` in inverse depth; ``nearest`` the depth of the window's
    point nearest the pixel (NaN: none); ``matched`` the depth of the agreeing point nearest
    ``z`` in inverse depth (NaN: none)."""
    height, width = depth.shape
    for n in range(z.shape[0]):
        agree[n] = False
        nearest[n] = np.nan
        matched[n] = np.nan
        c = col[n]
        r = row[n]
        if c < 0:
            continue
        zn = z[n]
        best = np.inf
        closest = np.inf
        for y in range(max(r - radius, 0), min(r + radius + 1, height)):
            for x in range(max(c - radius, 0), min(c + radius + 1, width)):
                d = np.float64(depth[y, x])
                if not d > 0.0:
                    continue
                if abs(zn - d) <= tolerance * d or (
                        zn > 0.0 and abs(1.0 / zn - 1.0 / d) <= inverse_tolerance):
                    agree[n] = True
                    gap = abs(1.0 / zn - 1.0 / d) if zn > 0.0 else np.inf
                    if gap < closest or matched[n] != matched[n]:
                        closest = gap
                        matched[n] = d
                dist2 = (x - c) * (x - c) + (y - r) * (y - r)
                if dist2 < best:
                    best = dist2
                    nearest[n] = d


def _pixels(uv: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Nearest pixel of each projection (``nearest_per_pixel``'s rounding), -1 where it is not
    on the image."""
    with np.errstate(invalid="ignore"):
        col, row = np.round(uv[:, 0]), np.round(uv[:, 1])
        inside = (np.isfinite(col) & np.isfinite(row) & (col >= 0) & (col < camera.width)
                  & (row >= 0) & (row < camera.height))
    col = np.where(inside, col, -1).astype(np.int64)
    row = np.where(inside, row, -1).astype(np.int64)
    return col, row


def _askers(views: list[DepthView], i: int, params: FusionParams) -> set[int]:
    """The views asked to confirm view ``i``'s points: the others; with
    ``params.disjoint_events`` those that share no events with it, where there are any."""
    others = {j for j in range(len(views)) if j != i}
    if not params.disjoint_events:
        return others
    disjoint = {j for j in others if not shares_events(views[i], views[j])}
    return disjoint or others


def _matches(views: list[DepthView], params: FusionParams):
    """Yield ``(i, j, agree, nearest, z, matched)`` for every ordered pair of distinct views
    (with ``params.disjoint_events``, only those that share no events): whether each point of
    ``i`` agrees with ``j``, the depth of ``j``'s nearest point to where it lands (NaN: not seen
    or no point of ``j`` in the window), its depth in ``j`` and the depth of ``j``'s agreeing
    point nearest it in inverse depth (NaN: none)."""
    points = [view.points_world() for view in views]
    fields = [_field_radius2(view.camera) for view in views]
    askers = [_askers(views, i, params) for i in range(len(views))]
    for i in range(len(views)):
        n = len(points[i])
        agree = np.empty(n, np.bool_)
        nearest = np.empty(n, np.float64)
        matched = np.empty(n, np.float64)
        for j, other in enumerate(views):
            if j == i or j not in askers[i]:
                continue
            uv, z = _project(points[i], other, fields[j])
            col, row = _pixels(uv, other.camera)
            _match(col, row, np.ascontiguousarray(z), other.depth, params.search_radius,
                   params.depth_tolerance, params.inverse_depth_tolerance or -1.0, agree,
                   nearest, matched)
            yield i, j, agree, nearest, z, matched


def agreement_counts(views: list[DepthView], params: FusionParams) -> list[np.ndarray]:
    """How many other views agree with each point of each view.

    Parameters
    ----------
    views : list of DepthView
    params : FusionParams
        ``depth_tolerance`` and ``search_radius`` are used.

    Returns
    -------
    list of (N_i,) int32 ndarray
        Per view, in the order of :meth:`DepthView.pixels`: the number of OTHER views (with
        ``params.disjoint_events``, of those that share no events with it) that see the point
        and hold a point within the tolerance near where it lands (0 to V - 1).
    """
    return evidence_counts(views, params)[0]


def evidence_counts(views: list[DepthView], params: FusionParams
                    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """How many other views confirm and how many contradict each point of each view.

    Parameters
    ----------
    views : list of DepthView
    params : FusionParams
        As :func:`agreement_counts` uses it.

    Returns
    -------
    agree : list of (N_i,) int32 ndarray
        :func:`agreement_counts`.
    contradict : list of (N_i,) int32 ndarray
        Per view, in the order of :meth:`DepthView.pixels`: the number of OTHER views (asked
        as for ``agree``) that see the point and hold a point within ``search_radius`` pixels
        of where it lands, none of them within the tolerance (0 to V - 1; ``agree +
        contradict`` is the number of views that could check the point).
    """
    views = _check_views(views)
    agree = [np.zeros(int(view.valid.sum()), np.int32) for view in views]
    contradict = [np.zeros_like(a) for a in agree]
    for i, _j, agreed, nearest, _z, _matched in _matches(views, params):
        agree[i] += agreed
        contradict[i] += np.isfinite(nearest) & ~agreed
    return agree, contradict


def fused_depth_points(views: list[DepthView], params: FusionParams) -> list[np.ndarray]:
    """Each view's points with the depth the views that confirm them agree on.

    For a point ``p`` of view ``i`` that view ``j`` confirms, ``j``'s agreeing point nearest it
    in inverse depth (depth ``d_j``, where ``p`` lies at depth ``z_j`` in ``j``) says the
    surface lies on ``j``'s ray through ``p`` at ``q = C_j + (p - C_j) d_j / z_j``; its depth
    in ``i`` is one estimate of ``p``'s. The fused depth is the mean of ``1 / z_i`` (the point's
    own) and of these estimates' inverse depths (an EMVS depth's error is about uniform in
    inverse depth, one plane step), and the point moves along ``i``'s ray to it. Each estimate
    lies within the agreement's tolerance of the point in ``j``, so the mean does; where two
    views share one pose it is exactly the mean of their inverse depths (the tests check it).

    Parameters
    ----------
    views : list of DepthView
    params : FusionParams
        As :func:`agreement_counts` uses it.

    Returns
    -------
    list of (N_i, 3) float64 ndarray, metres, world frame
        Per view, in the order of :meth:`DepthView.pixels` (a point no view confirms keeps its
        place).
    """
    views = _check_views(views)
    points = [view.points_world() for view in views]
    axes = [view.T_world_cam[:3, 2] for view in views]
    own = [(p - view.centre) @ axis for p, view, axis in zip(points, views, axes, strict=True)]
    inverse = [1.0 / z for z in own]
    count = [np.ones(len(z)) for z in own]
    for i, j, agree, _nearest, z, matched in _matches(views, params):
        a = agree & np.isfinite(matched) & (z > 0)
        centre = views[j].centre
        moved = centre + (points[i][a] - centre) * (matched[a] / z[a])[:, None]
        depth = (moved - views[i].centre) @ axes[i]
        ok = depth > 0
        index = np.flatnonzero(a)[ok]
        inverse[i][index] += 1.0 / depth[ok]
        count[i][index] += 1
    return [view.centre + (p - view.centre) * (c / w / z)[:, None]
            for p, view, w, c, z in zip(points, views, inverse, count, own, strict=True)]


def kept_points(agree: np.ndarray, contradict: np.ndarray | None, params: FusionParams
                ) -> np.ndarray:
    """Which points the fusion keeps, from the other views' evidence.

    Parameters
    ----------
    agree : (N,) int ndarray
        Other views that confirm each point (:func:`evidence_counts`).
    contradict : (N,) int ndarray or None
        Other views that contradict it; needed by ``params.reject`` ``"outvoted"`` only.
    params : FusionParams
        ``min_views`` and ``reject`` are used.

    Returns
    -------
    (N,) bool ndarray
        ``agree >= min_views``; with ``reject`` ``"outvoted"``, or ``agree >= contradict``.
    """
    keep = np.asarray(agree) >= params.min_views
    if params.reject == "outvoted":
        if contradict is None:
            raise ParameterError("{reject} outvoted needs the contradicting views' counts",
                                 reject="reject")
        keep |= np.asarray(agree) >= np.asarray(contradict)
    return keep


def _kept(views: list[DepthView], params: FusionParams,
          counts: list[np.ndarray] | None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per view: the kept points' mask (:func:`kept_points`) and their support (count + 1, the
    point's own view included); at k = 0 every point is kept. ``counts``:
    :func:`agreement_counts`' (computed when None, checked against the views otherwise; with
    ``reject`` ``"outvoted"`` the contradictions are counted again beside them)."""
    contradict: list[np.ndarray] | list[None] = [None] * len(views)
    if counts is None:
        if params.reject == "outvoted":
            counts, contradict = evidence_counts(views, params)
        else:
            counts = agreement_counts(views, params)
    else:
        counts = [np.asarray(c) for c in counts]
        sizes = [int(view.valid.sum()) for view in views]
        if [c.shape for c in counts] != [(n,) for n in sizes]:
            raise ParameterError(f"{{counts}} must hold one count per point of each view, "
                                 f"{sizes} points, got shapes {[c.shape for c in counts]}",
                                 counts="counts")
        if params.reject == "outvoted":
            contradict = evidence_counts(views, params)[1]
    keep = [kept_points(c, d, params) for c, d in zip(counts, contradict, strict=True)]
    return keep, [c + 1 for c in counts]


def fuse_views(views: list[DepthView], params: FusionParams, *,
               counts: list[np.ndarray] | None = None,
               contributors: list[bool] | None = None) -> FusedCloud:
    """The fused cloud: the points :func:`kept_points` keeps (at least ``min_views`` other views
    agree with them; with ``reject`` ``"outvoted"`` also those no more views contradict),
    merged per voxel.

    Parameters
    ----------
    views : list of DepthView
    params : FusionParams
    counts : list of (N_i,) int ndarray, optional
        :func:`agreement_counts` of ``views`` with ``params``, if already computed.
    contributors : list of bool, optional
        Per view, whether its points may enter the cloud (default: every view's); the others
        only confirm (e.g. key views whose event window lies on one side of them).

    Returns
    -------
    FusedCloud
        One point per occupied voxel (the mean of its kept points), in the order of the voxels'
        first points; points that cannot be back-projected (outside the lens model's invertible
        range) are left out.
    """
    views = _check_views(views)
    voxel = params.voxel_size if params.voxel_size is not None else default_voxel_size(views)
    keep, support = _kept(views, params, counts)
    if contributors is not None:
        if len(contributors) != len(views):
            raise ParameterError(f"{{contributors}} must hold one flag per view ({len(views)}), "
                                 f"got {len(contributors)}", contributors="contributors")
        keep = [k & bool(c) for k, c in zip(keep, contributors, strict=True)]
    source = (fused_depth_points(views, params) if params.fuse_depth
              else [view.points_world() for view in views])
    points = np.concatenate([p[k] for p, k in zip(source, keep, strict=True)])
    sup = np.concatenate([s[k] for s, k in zip(support, keep, strict=True)]).astype(np.int32)
    origin = np.concatenate([np.full(int(k.sum()), i, np.int32) for i, k in enumerate(keep)])
    finite = np.isfinite(points).all(axis=1)
    points, sup, origin = points[finite], sup[finite], origin[finite]
    if len(points) == 0:
        return FusedCloud(np.zeros((0, 3)), np.zeros(0, np.int32), np.zeros(0, np.int32),
                          float(voxel))
    keys = np.floor(points / voxel).astype(np.int64)
    _, first, inverse, members = np.unique(keys, axis=0, return_index=True,
                                           return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    merged = np.stack([np.bincount(inverse, weights=points[:, c]) for c in range(3)], 1)
    merged /= members[:, None]
    best = np.zeros(len(first), np.int32)
    np.maximum.at(best, inverse, sup)
    order = np.argsort(first, kind="stable")                # voxels in order of first point
    return FusedCloud(merged[order], best[order], origin[first[order]], float(voxel))


def fuse_into_view(views: list[DepthView], ref: int, params: FusionParams, *,
                   counts: list[np.ndarray] | None = None) -> np.ndarray:
    """A denser, consistency-checked depth map in one view: its own agreed points plus the
    other views' agreed points projected into its pixels, the nearest per pixel.

    Parameters
    ----------
    views : list of DepthView
    ref : int
        Index of the reference view in ``views``.
    params : FusionParams
        ``voxel_size`` is not used (no merge: each pixel holds one depth).
    counts : list of (N_i,) int ndarray, optional
        :func:`agreement_counts` of ``views`` with ``params``, if already computed.

    Returns
    -------
    (H, W) float32 ndarray, metres
        Depth in ``views[ref]``'s pixels; 0 where no point lands. A pixel where several points
        land holds the nearest (a z-buffer), its own point included.
    """
    views = _check_views(views)
    if isinstance(ref, bool) or not isinstance(ref, int | np.integer) or not (
            -len(views) <= ref < len(views)):
        raise ParameterError(f"{{ref}} must be the index of one of the {len(views)} views, "
                             f"got {ref!r}", ref="ref")
    ref = int(ref) % len(views)
    keep, _ = _kept(views, params, counts)
    target = views[ref]
    own = np.zeros_like(target.depth)
    uv = target.pixels()[keep[ref]]
    own[uv[:, 1], uv[:, 0]] = target.depth[uv[:, 1], uv[:, 0]]
    others = [views[i].points_world()[keep[i]] for i in range(len(views)) if i != ref]
    if not others:
        return own
    uv, z = _project(np.concatenate(others), target, _field_radius2(target.camera))
    projected = nearest_per_pixel(uv, z, target.camera)
    return np.where((own > 0) & ((projected <= 0) | (own <= projected)), own,
                    projected).astype(np.float32)


def view_agreement(views: list[DepthView], params: FusionParams) -> dict:
    """What a recording without ground truth can check: whether overlapping views agree.

    For each pair of views ``a < b`` (with ``params.disjoint_events``, that share no events),
    a point of either that the other sees and near which the
    other holds a point is an *overlap point*; its difference is its depth in the other view
    minus the depth of the other's point nearest where it lands (both directions pooled).

    Parameters
    ----------
    views : list of DepthView
    params : FusionParams
        ``min_views``, ``depth_tolerance`` and ``search_radius`` are used.

    Returns
    -------
    dict
        ``pairs``: one entry per pair with overlap points, ``{"a", "b", "overlap_points",
        "agreeing_points", "agreeing_share", "median_abs_difference_m",
        "median_rel_difference"}`` (relative: to the other view's depth);
        ``median_abs_difference_m`` and ``median_rel_difference`` over all overlap points
        (NaN where there are none) with ``overlap_points``; ``points`` (all views' points),
        ``confirmed_points`` (those with at least ``max(1, min_views)`` agreeing other views)
        and ``confirmed_share``; ``min_views_confirmed``, the threshold used.
    """
    views = _check_views(views)
    need = max(1, params.min_views)
    counts = [np.zeros(int(view.valid.sum()), np.int32) for view in views]
    pairs: dict[tuple[int, int], list] = {}
    for i, j, agree, nearest, z, _matched in _matches(views, params):
        counts[i] += agree
        seen = np.isfinite(nearest)
        entry = pairs.setdefault((min(i, j), max(i, j)), [[], [], 0])
        entry[0].append(z[seen] - nearest[seen])
        entry[1].append(nearest[seen])
        entry[2] += int(np.count_nonzero(agree))
    rows, all_abs, all_rel = [], [], []
    for (a, b), (diffs, depths, agreeing) in sorted(pairs.items()):
        diff, depth = np.concatenate(diffs), np.concatenate(depths)
        if len(diff) == 0:
            continue
        abs_diff, rel = np.abs(diff), np.abs(diff) / depth
        all_abs.append(abs_diff)
        all_rel.append(rel)
        rows.append({"a": a, "b": b, "overlap_points": len(diff), "agreeing_points": agreeing,
                     "agreeing_share": agreeing / len(diff),
                     "median_abs_difference_m": float(np.median(abs_diff)),
                     "median_rel_difference": float(np.median(rel))})
    abs_all = np.concatenate(all_abs) if all_abs else np.zeros(0)
    rel_all = np.concatenate(all_rel) if all_rel else np.zeros(0)
    points = int(sum(len(c) for c in counts))
    confirmed = int(sum(int(np.count_nonzero(c >= need)) for c in counts))
    return {"pairs": rows,
            "overlap_points": len(abs_all),
            "median_abs_difference_m": float(np.median(abs_all)) if len(abs_all) else math.nan,
            "median_rel_difference": float(np.median(rel_all)) if len(rel_all) else math.nan,
            "points": points, "confirmed_points": confirmed,
            "confirmed_share": confirmed / points if points else math.nan,
            "min_views_confirmed": need}
