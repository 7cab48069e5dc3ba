"""A global map scored against the scene's exact geometry, as multi-view-stereo benchmarks do.

DTU (Aanaes et al., "Large-Scale Data for Multiple-View Stereopsis", IJCV 2016) and Tanks and
Temples (Knapitsch et al., SIGGRAPH 2017) score a reconstructed point cloud against a dense
reference cloud by nearest-neighbour distances both ways: *accuracy* (ours to the reference),
*completeness* (the reference to ours), their mean (DTU's "overall", the Chamfer distance), and
at a distance ``tau``: *precision* (share of our points nearer than ``tau`` to the
reference), *recall* (share of the reference nearer than ``tau`` to ours) and their harmonic
mean, the F-score.

Here the reference is exact points: the depth each key view's TRUE camera sees at the exact
pose (:func:`exact_view`, the same rule as a map's own scoring; rendered ``n x n`` per pixel
for a denser sampling), put in the world frame and thinned per voxel (:func:`exact_surface`) so
that a surface that several views see is not counted several times. A sampled surface is
farther from a perfect point than the surface itself: :func:`exact_surface` states by how
much. Scoring only: nothing here feeds the map.

The figure (:func:`draw_global_figure`) and the error-coloured cloud (:func:`error_colours`,
:func:`write_error_cloud`) show where the errors are. OpenCV draws everything (no matplotlib).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from fusion.figures import Legend, panel_grid
from fusion.globalmap.fuse import default_voxel_size
from fusion.globalmap.views import DepthView, to_camera
from fusion.io import write_ply
from fusion.map.mapping import _exact_depth_view
from fusion.scoring import error_image
from sim.camera import Camera
from sim.se3 import look_at
from sim.sequence import Sequence

__all__ = ["FIGURE_PANEL", "KD_LEAF_SIZE", "KEY_VIEW_COLOUR", "RELATIVE_TAU",
           "SURFACE_SUPERSAMPLE", "TAUS_M", "cloud_scores", "draw_global_figure", "error_colours",
           "exact_surface", "exact_view", "nearest_distances", "point_depths",
           "write_error_cloud"]

TAUS_M = (0.01, 0.02, 0.05)
"""Distances (m) at which precision, recall and F-score are given: 1, 2 and 5 cm."""
RELATIVE_TAU = 0.01
"""A further ``tau``: this share of the scene depth (1 %: the keys ``*_rel1pct``)."""
SURFACE_SUPERSAMPLE = 4
"""The ``supersample`` of :func:`exact_view` for the views of a reference surface: a perfect
point then scores about 1 mm (:func:`exact_view`), a tenth of the smallest ``tau``."""


# --- the exact surface --------------------------------------------------------------------------

def exact_view(sequence: Sequence, t_ref: float, supersample: int = 1) -> DepthView | None:
    """The exact depth of the key view at ``t_ref``, with the camera and pose it is exact in.

    Scoring only. The rule of a map's own scoring (:func:`fusion.map.mapping._exact_depth_view`,
    the one reader of the exact files): the TRUE camera (``calib_exact.txt``, undistorted: the
    map's pixel grid) at the EXACT pose (``groundtruth_exact.txt``) at the true time
    (``t_ref`` less the poses' clock offset). A map built from noisy poses or a wrong calibration
    is so scored against where the surface really is.

    Parameters
    ----------
    sequence : Sequence
    t_ref : float, seconds, on the poses' clock (a key view's ``t_ref``)
    supersample : int, >= 1
        1 (default): the map's pixel grid (to compare depth maps pixel by pixel). ``n > 1``:
        each pixel split into ``n x n`` (same field of view, rendered), a denser exact sampling
        for :func:`exact_surface`: a point on the surface is then nearer to a sample, so that
        distances to the reference measure the map and not the reference's sampling (4,
        :data:`SURFACE_SUPERSAMPLE`, puts a DAVIS240C's samples 1.9 mm apart at 1.5 m, 7.5 mm
        with 1). Measured on boxes_6dof (the exact view at 0.5 s, 43,200 perfect points, scored
        against the exact surface of the views at 0.2, 0.45, 0.55 and 0.8 s): accuracy
        0.446 cm and precision at 1 cm 0.981 with 1; 0.230 cm, 0.999 with 2; 0.111 cm, 1.000
        with 4 (each render 240x180 x n^2 px of depth: 8 ms at n = 4 on 2 CPU cores).

    Returns
    -------
    DepthView or None
        ``depth`` (n H, n W) float32 metres, 0 where no surface; ``camera`` the true
        undistorted camera (resampled by ``n``); ``T_world_cam`` the exact pose; ``t`` =
        ``t_ref``. None for a real recording.
    """
    if isinstance(supersample, bool) or int(supersample) != supersample or supersample < 1:
        raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
    exact = _exact_depth_view(sequence, t_ref, int(supersample))
    if exact is None:
        return None
    depth, camera, pose = exact
    return DepthView(depth, camera, pose, t=float(t_ref), name=f"exact {float(t_ref):.6g} s")


def exact_surface(views: list[DepthView], spacing: float | None = None) -> np.ndarray:
    """The union of the exact views' points in the world frame, one point per voxel.

    Several key views see the same surface; their union would count it once per view in the
    completeness (and the recall). So the union is thinned on a grid of cubes of side
    ``spacing`` (origin at the world origin): of the points in a cube, the one nearest its centre
    is kept, an exact point (a mean would leave a curved surface or an edge). Bound: every point
    of the union lies within ``sqrt(3) spacing`` (the cube's diagonal) of a kept one, so a
    distance measured to the thinned surface is at most that larger than to the union. A point
    of a fronto-parallel surface that the views see lies within half a pixel's diagonal of a
    view's sample, so within ``(sqrt(2) / 2 + sqrt(3))`` footprints of the default surface
    (measured on a plane seen by two overlapping views: at most 1.12, on average 0.39
    footprints; the union alone 0.70 and 0.32). Denser views (:func:`exact_view`'s
    ``supersample``) shrink the footprint and with it this bias of accuracy and precision.

    Parameters
    ----------
    views : list of DepthView
        Exact views (:func:`exact_view`), world frame by their poses.
    spacing : float, metres, > 0, optional
        Side of the cubes. Default: one pixel's footprint at the views' typical depth,
        :func:`fusion.globalmap.fuse.default_voxel_size` (the fused cloud's merge voxel: the
        views' own sampling, so one view of a surface loses little and two views of it thin to
        about one).

    Returns
    -------
    (M, 3) float64 ndarray, metres, world frame, ordered by cube (lexicographic cube index);
    (0, 3) without points.
    """
    if spacing is None:
        spacing = default_voxel_size(views)
        if math.isnan(spacing):                          # no points at all
            return np.empty((0, 3))
    spacing = float(spacing)
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a finite number > 0 metres, got {spacing}")
    kept = np.empty((0, 3))
    for view in views:              # one view at a time: memory of the surface and one view
        kept = _thin(np.concatenate([kept, _thin(view.points_world(), spacing)]), spacing)
    return kept


def _thin(points: np.ndarray, spacing: float) -> np.ndarray:
    """Of the points in each cube of side ``spacing``, the one nearest its centre (the first
    on a tie), ordered by cube. Thinning a union of thinned sets gives the union's thinning."""
    if len(points) == 0:
        return points
    cells = np.floor(points / spacing)
    offset = np.linalg.norm(points - (cells + 0.5) * spacing, axis=1)
    cells = cells.astype(np.int64)
    order = np.lexsort((offset, cells[:, 2], cells[:, 1], cells[:, 0]))
    cells = cells[order]
    first = np.ones(len(order), bool)
    first[1:] = np.any(cells[1:] != cells[:-1], axis=1)
    return points[order[first]]


# --- the scores ---------------------------------------------------------------------------------

def _cloud(name: str, points) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.size == 0:
        return np.empty((0, 3))
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must be an (N, 3) array of points, got shape {points.shape}")
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise ValueError(f"{name} must be finite metres, found {int(bad.sum())} points with NaN "
                         "or infinite coordinates")
    return points


KD_LEAF_SIZE = 128
"""Points per leaf of :func:`nearest_distances`' k-d tree (SciPy's default is 16). A point far
from a dense reference is slow to answer: every leaf that the sphere through its nearest point
cuts is searched, and that sphere cuts a wide cap of a curved or many-sided surface, so the
search meets leaves by the hundred. Larger leaves make fewer of them; the answer is the same
(exact either way). Measured on boxes_6dof 3.5-5.5 s's exact surface (1.19 million points),
one core: 5,000 points of a TSDF mesh built from dense fills (60 % of them over 10 cm off)
1.35 s with 16 points a leaf, 0.35 s with 128; 200,000 points within a few mm of the surface
0.34 s and 0.40 s."""


def nearest_distances(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest point of ``reference`` (a k-d tree of
    :data:`KD_LEAF_SIZE` points a leaf, exact).

    Parameters
    ----------
    points : (N, 3) array_like, metres
    reference : (M, 3) array_like, metres, the same frame

    Returns
    -------
    (N,) float64 ndarray, metres; ``inf`` for every point when ``reference`` is empty.
    """
    points, reference = _cloud("points", points), _cloud("reference", reference)
    if len(reference) == 0:
        return np.full(len(points), np.inf)
    if len(points) == 0:
        return np.empty(0)
    # Every core: each query is independent, so the distances are the same on any count.
    return cKDTree(reference, leafsize=KD_LEAF_SIZE).query(points, k=1, workers=-1)[0]


def _tau_name(tau: float) -> str:
    return f"{100 * tau:g}cm"


def point_depths(points: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Each point's z-depth in the camera (of ``poses``) whose centre is nearest to it: the depth
    that sets the point's tolerances (1 % of it, the DSI's plane step at it).

    Parameters
    ----------
    points : (N, 3) array_like, metres, world frame
    poses : (K, 4, 4) array_like, ``T_world_camera`` of the key views (K >= 1)

    Returns
    -------
    (N,) float64 ndarray, metres (negative or 0 for a point behind or beside that camera)
    """
    points = _cloud("points", points)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(poses) == 0:
        raise ValueError("poses must hold at least one camera pose")
    if len(points) == 0:
        return np.empty(0)
    nearest = cKDTree(poses[:, :3, 3]).query(points, k=1)[1]
    axes = poses[nearest, :3, 2]                       # each camera's optical axis, world frame
    return np.einsum("ij,ij->i", points - poses[nearest, :3, 3], axes)


def _share_within(distances: np.ndarray, taus: np.ndarray | float) -> float:
    """Share of ``distances`` strictly under their ``taus`` (0 for none)."""
    return float(np.mean(distances < taus)) if distances.size else 0.0


def _prf(scores: dict, name: str, precision: float, recall: float) -> None:
    total = precision + recall
    scores[f"precision_{name}"] = precision
    scores[f"recall_{name}"] = recall
    scores[f"fscore_{name}"] = 2.0 * precision * recall / total if total > 0 else 0.0


def cloud_scores(points: np.ndarray, reference: np.ndarray, scene_depth: float,
                 taus: tuple[float, ...] = TAUS_M, *, poses: np.ndarray | None = None,
                 inverse_depth_step: float | None = None) -> dict:
    """Accuracy, completeness, Chamfer distance and precision / recall / F-score of a cloud.

    The definitions of DTU and Tanks and Temples, distances to the nearest point both ways:
    ``accuracy_cm`` the mean distance of our points to the reference, ``completeness_cm`` the
    mean distance of the reference's points to ours, ``chamfer_cm`` their mean (DTU's
    "overall"); at each ``tau``, ``precision`` the share of our points nearer than ``tau`` to the
    reference (strictly, as Tanks and Temples), ``recall`` the share of the reference nearer
    than ``tau`` to ours, ``fscore = 2 P R / (P + R)`` (0 where both are 0).

    Parameters
    ----------
    points : (N, 3) array_like, metres
        The map's points (world frame).
    reference : (M, 3) array_like, metres
        The exact surface (:func:`exact_surface`), the same frame.
    scene_depth : float, metres, > 0
        The scene's depth (e.g. the median exact depth of the key views): the further ``tau`` is
        :data:`RELATIVE_TAU` of it.
    taus : tuple of float, metres, > 0
        Default :data:`TAUS_M` (keys ``precision_1cm``, ``recall_1cm``, ``fscore_1cm``, ...).
    poses : (K, 4, 4) array_like or None
        The key views' ``T_world_camera``: with them, tolerances that follow each point's depth
        ``z`` (:func:`point_depths`; our points' for the precision, the reference's for the
        recall): :data:`RELATIVE_TAU` of ``z`` (keys ``*_depth1pct``).
    inverse_depth_step : float or None, 1/metres, > 0
        With ``poses``: the DSI's plane spacing in inverse depth, ``(1/min - 1/max) /
        (planes - 1)``; the further tolerance is the plane step at each point's depth,
        ``z^2 inverse_depth_step`` (keys ``*_step``, with its median over the reference
        ``tau_step_median_cm``): a map that finds each point's plane scores 1 there, one that
        quantises to planes about half.

    Returns
    -------
    dict
        ``accuracy_cm``, ``completeness_cm``, ``chamfer_cm``, ``accuracy_median_cm``,
        ``completeness_median_cm``; ``precision_Xcm``, ``recall_Xcm``, ``fscore_Xcm`` per
        ``tau``; the same at 1 % of ``scene_depth`` (``precision_rel1pct``, ``recall_rel1pct``,
        ``fscore_rel1pct``, with ``tau_rel1pct_cm``); with ``poses`` (and
        ``inverse_depth_step``) the per-point ones above; the counts ``points`` and
        ``reference_points``. Where either cloud is empty the distances are undefined: means
        and medians are NaN (written as ``null`` in JSON), precision and recall 0, so F 0.
    """
    points, reference = _cloud("points", points), _cloud("reference", reference)
    scene_depth = float(scene_depth)
    if not (math.isfinite(scene_depth) and scene_depth > 0):
        raise ValueError(f"scene_depth must be a finite number > 0 metres, got {scene_depth}")
    taus = tuple(float(t) for t in taus)
    if not all(math.isfinite(t) and t > 0 for t in taus):
        raise ValueError(f"taus must be finite numbers > 0 metres, got {list(taus)}")
    both = len(points) > 0 and len(reference) > 0
    accuracy = nearest_distances(points, reference) if both else np.empty(0)
    completeness = nearest_distances(reference, points) if both else np.empty(0)

    def cm(values: np.ndarray, how) -> float:
        return 100.0 * float(how(values)) if values.size else math.nan

    scores: dict = {"accuracy_cm": cm(accuracy, np.mean),
                    "completeness_cm": cm(completeness, np.mean),
                    "accuracy_median_cm": cm(accuracy, np.median),
                    "completeness_median_cm": cm(completeness, np.median)}
    scores["chamfer_cm"] = 0.5 * (scores["accuracy_cm"] + scores["completeness_cm"])
    tau_rel = RELATIVE_TAU * scene_depth
    for name, tau in [(_tau_name(t), t) for t in taus] + [("rel1pct", tau_rel)]:
        _prf(scores, name, _share_within(accuracy, tau), _share_within(completeness, tau))
    scores["tau_rel1pct_cm"] = 100.0 * tau_rel
    if poses is not None:
        z_ours = point_depths(points, poses) if both else np.empty(0)
        z_ref = point_depths(reference, poses) if both else np.empty(0)
        _prf(scores, "depth1pct", _share_within(accuracy, RELATIVE_TAU * z_ours),
             _share_within(completeness, RELATIVE_TAU * z_ref))
        if inverse_depth_step is not None:
            step = float(inverse_depth_step)
            if not (math.isfinite(step) and step > 0):
                raise ValueError(f"inverse_depth_step must be a finite number > 0 per metre, "
                                 f"got {inverse_depth_step}")
            _prf(scores, "step", _share_within(accuracy, step * z_ours ** 2),
                 _share_within(completeness, step * z_ref ** 2))
            scores["tau_step_median_cm"] = (100.0 * step * float(np.median(z_ref)) ** 2
                                            if z_ref.size else math.nan)
    scores["points"] = len(points)
    scores["reference_points"] = len(reference)
    return scores


# --- the error-coloured cloud -------------------------------------------------------------------

def error_colours(errors_m: np.ndarray, max_error_m: float) -> np.ndarray:
    """Errors in colour: OpenCV's TURBO from 0 m (dark blue) to ``max_error_m`` (dark red),
    larger errors clipped to the last colour; the scale of :func:`fusion.scoring.error_image`
    (which makes them: one colour map for every error in evfuse).

    Parameters
    ----------
    errors_m : (N,) array_like, metres, >= 0
        ``inf`` allowed (no reference: :func:`nearest_distances`), drawn as any error above
        ``max_error_m``; NaN refused.
    max_error_m : float, metres, > 0

    Returns
    -------
    (N, 3) uint8 ndarray, BGR
    """
    errors = np.asarray(errors_m, dtype=np.float64).reshape(-1)
    if np.isnan(errors).any() or (errors < 0).any():
        raise ValueError("errors_m must be distances >= 0 metres (inf allowed), found NaN or "
                         "negative values")
    max_error_m = float(max_error_m)
    if not (math.isfinite(max_error_m) and max_error_m > 0):
        raise ValueError(f"max_error_m must be a finite number > 0 metres, got {max_error_m}")
    if errors.size == 0:
        return np.empty((0, 3), np.uint8)
    # error_image scores |depth - gt|: a row of depths 1 + e against 1 m is the error e (those
    # above the maximum clipped first: the same last colour, and inf stays finite)
    errors = np.minimum(errors, max_error_m)
    return error_image(1.0 + errors[None, :], np.ones((1, errors.size)), max_error_m)[0]


def write_error_cloud(path: str | Path, points: np.ndarray, errors_m: np.ndarray,
                      max_error_m: float) -> Path:
    """Write the points coloured by their error (:func:`error_colours`) as a PLY in the world
    frame (:func:`fusion.io.write_ply`, the pose comment ``T_world`` the identity).

    Parameters
    ----------
    path : str or Path
    points : (N, 3) array_like, metres, world frame
    errors_m : (N,) array_like, metres (e.g. :func:`nearest_distances` to the exact surface)
    max_error_m : float, metres, > 0: the error of the last colour

    Returns
    -------
    Path
    """
    points = _cloud("points", points)
    errors = np.asarray(errors_m, dtype=np.float64).reshape(-1)
    if len(errors) != len(points):
        raise ValueError(f"need one error per point, got {len(errors)} errors for "
                         f"{len(points)} points")
    write_ply(path, points, np.eye(4), colours=error_colours(errors, max_error_m),
              frame_name="T_world")
    return Path(path)


# --- the figure ---------------------------------------------------------------------------------

FIGURE_PANEL = (640, 480)
"""Size (width, height, pixels) of each of the figure's two views; the figure is
``(title + 480 + colour bar, 2 x 640)`` (:func:`fusion.figures.panel_grid`)."""
KEY_VIEW_COLOUR = (0, 0, 0)
"""BGR of a key view's marker (a filled disc of :data:`KEY_VIEW_RADIUS` at its centre) and its
index: black, which neither TURBO nor the height scale produces, on the white background."""
KEY_VIEW_RADIUS = 5
TRAJECTORY_COLOUR = (150, 150, 150)
"""BGR of the trajectory's polyline (grey)."""
_BACKGROUND = (255, 255, 255)
_MARGIN = 24
"""Pixels kept free around what a view shows."""
_SPLAT = 2
"""Side of a point's square, pixels."""
_POINT_PERCENTILES = (0.5, 99.5)
"""Share of the points a view is fitted to (outliers may fall outside); the trajectory and the
key views are always inside."""
_AXES = "xyz"


@dataclass(frozen=True)
class _TopView:
    """Orthographic view down the world axis ``down_axis``, seen from its positive side: world
    axis ``axes[0]`` to the right, ``axes[1]`` up the image (so ``axes[0] x axes[1]`` points at
    the viewer)."""

    axes: tuple[int, int]
    down_axis: int
    centre: np.ndarray        # (2,) world coordinates on axes at the panel's centre
    scale: float              # pixels per metre
    size: tuple[int, int]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) float pixel positions (u, v; pixel centres at integers) and (N,) bool: in
        view (always)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        width, height = self.size
        u = (width - 1) / 2 + self.scale * (points[:, self.axes[0]] - self.centre[0])
        v = (height - 1) / 2 - self.scale * (points[:, self.axes[1]] - self.centre[1])
        return np.stack([u, v], 1), np.ones(len(points), bool)

    def depth(self, points: np.ndarray) -> np.ndarray:
        """(N,) distance from the viewer (larger: drawn first)."""
        return -np.asarray(points, dtype=np.float64).reshape(-1, 3)[:, self.down_axis]


@dataclass(frozen=True)
class _PerspectiveView:
    """A pinhole camera (``camera``, no distortion) at pose ``T_world_cam``."""

    camera: Camera
    T_world_cam: np.ndarray
    near: float               # metres: points nearer than this are not drawn

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) float pixel positions and (N,) bool: ahead of the near plane."""
        local = to_camera(points, self.T_world_cam)
        ahead = local[:, 2] > self.near
        z = np.where(ahead, local[:, 2], 1.0)
        uv = np.stack([self.camera.fx * local[:, 0] / z + self.camera.cx,
                       self.camera.fy * local[:, 1] / z + self.camera.cy], 1)
        return uv, ahead

    def depth(self, points: np.ndarray) -> np.ndarray:
        return to_camera(points, self.T_world_cam)[:, 2]


def _fit_points(points: np.ndarray) -> np.ndarray:
    """The points a view is fitted to: within :data:`_POINT_PERCENTILES` on every axis."""
    if len(points) == 0:
        return points
    lo, hi = np.percentile(points, _POINT_PERCENTILES, axis=0)
    return points[np.all((points >= lo) & (points <= hi), axis=1)]


def _top_view(points: np.ndarray, markers: np.ndarray, size: tuple[int, int]) -> _TopView:
    """The top view: down the world axis along which the points (the markers where there are
    none) extend least; fitted to :func:`_fit_points` and every marker, :data:`_MARGIN` free."""
    fitted = _fit_points(points)
    shown = np.concatenate([fitted, markers]) if len(markers) else fitted
    basis = fitted if len(fitted) else shown
    extent = np.ptp(basis, axis=0) if len(basis) else np.array([1.0, 1.0, 0.0])
    down = int(np.argmin(extent))
    axes = ((down + 1) % 3, (down + 2) % 3)
    if len(shown):
        lo, hi = shown[:, axes].min(axis=0), shown[:, axes].max(axis=0)
    else:
        lo, hi = np.zeros(2), np.ones(2)
    span = np.maximum(hi - lo, 1e-6)
    width, height = size
    scale = float(min((width - 2 * _MARGIN) / span[0], (height - 2 * _MARGIN) / span[1]))
    return _TopView(axes, down, 0.5 * (lo + hi), scale, size)


WORLD_UP = np.array([0.0, 0.0, 1.0])
"""The world's up (:func:`sim.se3.look_at`'s default: evfuse's scenes stand on z = 0)."""


def _perspective_view(points: np.ndarray, markers: np.ndarray, start: np.ndarray,
                      size: tuple[int, int]) -> _PerspectiveView:
    """A camera behind and above the trajectory's start looking at the points' median (the
    markers' mean where there are no points): with ``d`` = median - start, at
    ``start - d / 2 + |d| / 2 up`` (:data:`WORLD_UP`; +y where ``d`` is vertical), its focal
    length fitted so that :func:`_fit_points` and every marker ahead are in view."""
    fitted = _fit_points(points)
    target = np.median(fitted, axis=0) if len(fitted) else (
        markers.mean(axis=0) if len(markers) else start + [0.0, 1.0, 0.0])
    d = target - start
    length = float(np.linalg.norm(d))
    if length < 1e-9:
        d, length = np.array([0.0, 1.0, 0.0]), 1.0
        target = start + d
    up = WORLD_UP if np.linalg.norm(np.cross(d / length, WORLD_UP)) > 1e-6 else np.eye(3)[1]
    eye = start - 0.5 * d + 0.5 * length * up
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = look_at(eye, target, up), eye
    near = 0.05 * length
    width, height = size
    shown = np.concatenate([fitted, markers]) if len(markers) else fitted
    local = to_camera(shown, pose)
    local = local[local[:, 2] > near]
    reach = (np.abs(local[:, :2]) / local[:, 2:]).max(axis=0) if len(local) else np.ones(2)
    reach = np.maximum(reach, 1e-6)
    focal = float(min((width / 2 - _MARGIN) / reach[0], (height / 2 - _MARGIN) / reach[1]))
    camera = Camera(width, height, focal, focal, (width - 1) / 2, (height - 1) / 2)
    return _PerspectiveView(camera, pose, near)


def _draw_view(view: _TopView | _PerspectiveView, points: np.ndarray, colours: np.ndarray,
               trajectory: np.ndarray, key_views: np.ndarray) -> np.ndarray:
    """One panel: the points as squares (far first), the trajectory, the key views' markers
    with their indices."""
    width, height = view.size if isinstance(view, _TopView) else view.camera.resolution
    image = np.empty((height, width, 3), np.uint8)
    image[:] = _BACKGROUND
    if len(points):
        uv, ahead = view.project(points)
        order = np.argsort(-view.depth(points), kind="stable")
        order = order[ahead[order]]
        u = np.round(uv[order, 0]).astype(np.int64)
        v = np.round(uv[order, 1]).astype(np.int64)
        inside = (u >= 0) & (u < width - _SPLAT + 1) & (v >= 0) & (v < height - _SPLAT + 1)
        u, v, c = u[inside], v[inside], colours[order][inside]
        for du in range(_SPLAT):
            for dv in range(_SPLAT):
                image[v + dv, u + du] = c
    if len(trajectory) > 1:
        uv, ahead = view.project(trajectory)
        for k in range(len(trajectory) - 1):
            if ahead[k] and ahead[k + 1] and np.all(np.abs(uv[k:k + 2]) < 1e5):
                a = tuple(int(x) for x in np.round(uv[k]))
                b = tuple(int(x) for x in np.round(uv[k + 1]))
                cv2.line(image, a, b, TRAJECTORY_COLOUR, 1, cv2.LINE_8)
    if len(key_views):
        uv, ahead = view.project(key_views)
        for k in np.nonzero(ahead & np.all(np.abs(uv) < 1e5, axis=1))[0]:
            centre = (int(round(uv[k, 0])), int(round(uv[k, 1])))
            cv2.circle(image, centre, KEY_VIEW_RADIUS, KEY_VIEW_COLOUR, -1, cv2.LINE_8)
        for k in np.nonzero(ahead & np.all(np.abs(uv) < 1e5, axis=1))[0]:
            corner = (int(round(uv[k, 0])) + KEY_VIEW_RADIUS + 2,
                      int(round(uv[k, 1])) - KEY_VIEW_RADIUS - 2)
            cv2.putText(image, str(k), corner, cv2.FONT_HERSHEY_SIMPLEX, 0.4, KEY_VIEW_COLOUR,
                        1, cv2.LINE_AA)
    return image


def _figure_views(points: np.ndarray, trajectory: np.ndarray, key_views: np.ndarray
                  ) -> tuple[_TopView, _PerspectiveView]:
    """The two views of :func:`draw_global_figure` (its panels' projections)."""
    markers = np.concatenate([trajectory, key_views])
    start = trajectory[0] if len(trajectory) else (
        key_views[0] if len(key_views) else np.zeros(3))
    return (_top_view(points, markers, FIGURE_PANEL),
            _perspective_view(points, markers, start, FIGURE_PANEL))


def draw_global_figure(points: np.ndarray, errors_m: np.ndarray | None, trajectory: np.ndarray,
                       key_views: np.ndarray, max_error_m: float) -> np.ndarray:
    """The global map seen from above and in perspective, with the trajectory and key views.

    Left, a top view: orthographic, down the world axis along which the points extend least
    (the two axes of largest extent in the image), seen from that axis' positive side; right, a
    perspective view from behind and above the trajectory's start looking at the points' median
    (:func:`_perspective_view`). Both are fitted to the points (0.5th-99.5th percentile per axis)
    and the whole trajectory. Points are 2-pixel squares coloured by their error
    (:func:`error_colours`, the colour bar in cm) or, where ``errors_m`` is None (a real
    recording), by their height: their coordinate along the top view's axis, on the same
    TURBO scale from its lowest to its highest point (the bar in m); the trajectory is a grey
    polyline, each key view a black disc (:data:`KEY_VIEW_COLOUR`) at its centre with its index.

    Parameters
    ----------
    points : (N, 3) array_like, metres, world frame (N = 0 allowed)
    errors_m : (N,) array_like, metres, >= 0, or None
    trajectory : (T, 3) array_like, metres, world frame: camera centres in time order
    key_views : (K, 3) array_like, metres, world frame: the key views' centres
    max_error_m : float, metres, > 0
        The error of the last colour (larger errors clipped to it; the bar says ">=").

    Returns
    -------
    (26 + 480 + 22, 1280, 3) uint8 ndarray, BGR (:data:`FIGURE_PANEL` panels side by side
    under their titles, above their colour bars)
    """
    points = _cloud("points", points)
    trajectory = _cloud("trajectory", trajectory)
    key_views = _cloud("key_views", key_views)
    top, perspective = _figure_views(points, trajectory, key_views)
    if errors_m is not None:
        errors = np.asarray(errors_m, dtype=np.float64).reshape(-1)
        if len(errors) != len(points):
            raise ValueError(f"need one error per point, got {len(errors)} errors for "
                             f"{len(points)} points")
        colours = error_colours(errors, max_error_m)
        ramp = error_colours(np.linspace(0.0, max_error_m, 256), max_error_m)
        clipped = bool((errors > max_error_m).any())
        legend = Legend(ramp, "error 0 cm",
                        f"{'>= ' if clipped else ''}{100 * float(max_error_m):.3g} cm")
        colour_by = "error"
    else:
        height = points[:, top.down_axis]
        lo, hi = (float(height.min()), float(height.max())) if len(points) else (0.0, 1.0)
        hi = max(hi, lo + 1e-6)
        colours = error_colours(height - lo, hi - lo)        # TURBO, low to high
        legend = Legend(error_colours(np.linspace(0.0, hi - lo, 256), hi - lo),
                        f"{_AXES[top.down_axis]} {lo:.3g} m", f"{hi:.3g} m")
        colour_by = f"world {_AXES[top.down_axis]}"
    names = f"{_AXES[top.axes[0]]}-{_AXES[top.axes[1]]}"
    titles = [f"top view (world {names}, from +{_AXES[top.down_axis]}): {len(points):,} points "
              f"by {colour_by}",
              f"from behind and above the start; {len(key_views)} key views"]
    panels = [_draw_view(view, points, colours, trajectory, key_views)
              for view in (top, perspective)]
    return panel_grid(panels, titles, columns=2, scale=1.0, legends=[legend, legend])
