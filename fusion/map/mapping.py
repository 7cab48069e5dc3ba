"""``evfuse map``: a semi-dense depth map of a sequence folder from its events and poses (EMVS).

Reads a sequence folder (simulated, or a real Event-Camera Dataset folder), streams the events
of a time window into a disparity space image at a reference view, extracts the semi-dense depth
(:mod:`fusion.map.emvs`), removes radius outliers from the point cloud and, when the sequence was
simulated, scores the map against the exact depth of the reference view with
:func:`fusion.scoring.depth_errors` (errors, completeness and precision), the exact depth taken in
the map's own pixel grid: rendered in the undistorted virtual camera when the sensor has
distortion (``depth/`` holds the sensor's distorted pixels).

The reference view's virtual camera uses the sensor's intrinsics without distortion (rpg_emvs
re-centres the principal point; evfuse keeps the sensor's, so that the map lines up with the
sensor's undistorted frames). Event coordinates are undistorted once per pixel with a lookup
table.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from fusion.figures import add_header, depth_colours, depth_scale, panel_grid
from fusion.io import to_json, write_ply
from fusion.map.dsi_range import DSIRange, oracle_header
from fusion.map.emvs import (
    DepthMapParams,
    DSIParams,
    depth_planes,
    disparity_space_image,
    semidense_depth,
)
from fusion.scoring import depth_errors, errors_by_motion, motion_regions, recorded_scene
from sim._summary import summary_repr
from sim.camera import Camera
from sim.eventio import check_time_units, event_time_span, iter_event_chunks, read_window
from sim.exr import read_depth, write_depth, write_exr_channels
from sim.output import atomic_output_dir
from sim.progress import progress as progress_stage
from sim.sequence import EXACT_TIME_S, Sequence, load_sequence
from sim.trajectory import read_trajectory
from sim.validation import ParameterError

__all__ = ["MapParams", "MapResult", "TimeWindow", "map_sequence", "radius_outliers",
           "time_window", "write_map"]

DSI_MEMORY_LIMIT = 8 * 2**30
"""Largest DSI (bytes) accepted before any work is done: a third of the 24 GiB machine."""


@dataclass(frozen=True)
class MapParams:
    """Parameters of ``evfuse map``.

    Attributes
    ----------
    dsi : DSIParams
        Depth range, planes, packet size.
    depth : DepthMapParams
        Adaptive threshold, median filter, border.
    t0, t1 : float or None, seconds
        Event window (default: from the first to the last event, within the poses). A window
        that reaches past the events or the poses is refused (see :func:`time_window`) unless
        ``clip_window``.
    ref_time : float or None, seconds
        Reference view (default: the middle of the window).
    clip_window : bool
        Map the part of ``[t0, t1]`` that the events and the poses cover instead of refusing
        a window that reaches past them (default False); ``map.json`` records both windows.
    outlier_radius : float, metres
        Radius outlier removal: a point needs ``outlier_neighbours`` others within this radius,
        scaled by the median depth when that is below 1 m (0.05 m at 1 m, as rpg_emvs).
    outlier_neighbours : int
    check_depth_range : bool
        Refuse a depth range that does not contain the scene (default True): when more than
        30 % of the map points sit on the two planes at either end of the range, and, for a
        simulated sequence, when its scoring finds less than half of the exact depth in the
        range (checked after the map is made: no stage but the scoring reads the exact depth).
    dsi_range : DSIRange or None
        Where the DSI's depth range came from (:func:`fusion.map.dsi_range.resolve_dsi_range`),
        recorded in ``map.json``; None: given by the caller.
    """

    dsi: DSIParams
    depth: DepthMapParams = field(default_factory=DepthMapParams)
    t0: float | None = None
    t1: float | None = None
    ref_time: float | None = None
    clip_window: bool = False
    outlier_radius: float = 0.05
    outlier_neighbours: int = 3
    check_depth_range: bool = True
    dsi_range: DSIRange | None = None


@dataclass
class MapResult:
    """A semi-dense map at a reference view.

    Attributes
    ----------
    depth : (H, W) float32 ndarray, metres, 0 where no map point (the final map)
    confidence : (H, W) float32 ndarray, votes of the best plane
    mask : (H, W) bool ndarray, the final map points
    camera : Camera, the reference view's virtual camera
    t_ref : float, seconds
    T_world_ref : (4, 4) ndarray
    info : dict, counts, window, timings and, with ground truth, ``errors``
        (:func:`fusion.scoring.depth_errors` in the map's undistorted pixel grid)
    sequence : Sequence, the sequence folder it was built from
    """

    depth: np.ndarray
    confidence: np.ndarray
    mask: np.ndarray
    camera: Camera
    t_ref: float
    T_world_ref: np.ndarray
    info: dict
    sequence: Sequence

    __repr__ = summary_repr
    _summary_counts = ("n1",)

    @property
    def n1(self) -> int:
        """Number of map points."""
        return int(np.count_nonzero(self.depth))

    def points(self) -> np.ndarray:
        """Map points (N, 3) float32 in the reference camera frame, metres."""
        v, u = np.nonzero(self.depth)
        return self.camera.backproject(np.stack([u, v], 1), self.depth[v, u]).astype(np.float32)


def radius_outliers(points: np.ndarray, radius: float, neighbours: int) -> np.ndarray:
    """Mask (N,) of points with at least ``neighbours`` other points within ``radius``."""
    if len(points) == 0:
        return np.zeros(0, bool)
    counts = cKDTree(points).query_ball_point(points, radius, return_length=True)
    return counts - 1 >= neighbours


WINDOW_TERMS = {"t0": "t0", "t1": "t1", "ref_time": "ref_time", "clip_window": "clip_window=True"}
"""The parameters a refused time window names (:class:`sim.validation.ParameterError`)."""
RANGE_TERMS = {"min_depth": "min_depth", "max_depth": "max_depth"}
"""The parameters a refused depth range names."""
WINDOW_SLACK_S = 1e-3
"""How far (s) a window asked for may reach past the data and still be used without
``clip_window`` (it is then clipped, and recorded as clipped): the first and last events of a
real recording only bound when it started and ended, by the time between two events (about
10 us on the ECD slider, at 300 events per ms), far below a millisecond."""
REF_TOLERANCE_SHARE = 0.1
"""The reference view needs events of the window within this share of the window's length of
it (or within :data:`REF_TOLERANCE_MIN_S`, whichever is wider)."""
REF_TOLERANCE_MIN_S = 0.025
"""Smallest neighbourhood (s) of the reference view searched for events: half the frame
interval of a 20 Hz camera, so that the frame nearest to any time of the window is never
refused for being between two frames."""
REF_MIN_EVENTS = 100
"""Fewest events of the window that must lie near the reference view (a map made of events
seen only from far away is not a map of that view)."""


@dataclass(frozen=True)
class TimeWindow:
    """The event window of a map: as asked for, and as used.

    Attributes
    ----------
    requested : (float or None, float or None), seconds
        ``t0``, ``t1`` as asked for (None where left to the default, the data's span).
    t0, t1 : float, seconds
        The window used: the one asked for within the events' and the poses' spans.
    clipped : bool
        ``[t0, t1]`` is narrower than a bound that was asked for (by more than
        :data:`sim.sequence.EXACT_TIME_S`: a bound that close to the data's is kept as asked).
    t_ref : float, seconds
        The reference view: the one asked for, else the middle of ``[t0, t1]``.
    events_span, poses_span : (float, float), seconds
        What the data covers: the events (a simulated sequence's simulated interval from its
        ``sequence.json``, else the first and last event) and the poses (``groundtruth.txt``).
    """

    requested: tuple[float | None, float | None]
    t0: float
    t1: float
    clipped: bool
    t_ref: float
    events_span: tuple[float, float]
    poses_span: tuple[float, float]


def _events_span(sequence: Sequence, events_path: Path) -> tuple[float, float]:
    """The time the events cover (s): a simulated sequence's whole simulated interval on the
    event camera's clock (the event camera watched all of it, quiet or not; ``events.span_s``,
    else ``start`` and ``duration``), else the first and last event."""
    meta = sequence.metadata or {}
    span = (meta.get("events") or {}).get("span_s")
    if (isinstance(span, list) and len(span) == 2
            and all(isinstance(v, int | float) for v in span) and span[1] > span[0]):
        return float(span[0]), float(span[1])
    start, duration = meta.get("start"), meta.get("duration")
    if isinstance(start, int | float) and isinstance(duration, int | float) and duration > 0:
        return float(start), float(start) + float(duration)
    return event_time_span(events_path, width=sequence.camera.width,
                           height=sequence.camera.height)


def _span(span: tuple[float, float]) -> str:
    return f"[{span[0]:.6f}, {span[1]:.6f}] s"


def time_window(sequence: Sequence, t0: float | None = None, t1: float | None = None, *,
                ref_time: float | None = None, clip: bool = False) -> TimeWindow:
    """Check an event window against the data, once for ``evfuse map`` and ``evfuse run``.

    Parameters
    ----------
    sequence : Sequence
        With ``groundtruth.txt`` and an event file.
    t0, t1 : float or None, seconds
        The window asked for; None: the data's span (from the first to the last event within
        the poses). Without ``t0``, ``t1`` and ``ref_time`` nothing is refused but an empty
        overlap of events and poses.
    ref_time : float or None, seconds
        The reference view (default: the middle of the window used).
    clip : bool
        Clip a window that reaches past the data to the part the data covers, instead of
        refusing it.

    Returns
    -------
    TimeWindow

    Raises
    ------
    ValueError
        One line naming the window, the events' span, the poses' span and the flag to change:
        a window that reaches more than :data:`WINDOW_SLACK_S` past the events or the poses
        (without ``clip``), one that does not overlap them at all, an empty one, a reference
        view outside the poses, or one with fewer than :data:`REF_MIN_EVENTS` events of the
        window within ``max(REF_TOLERANCE_SHARE * length, REF_TOLERANCE_MIN_S)`` of it.
    """
    if sequence.groundtruth_path is None:
        raise ValueError(f"{sequence.folder}: no groundtruth.txt (the camera poses are needed)")
    events_path = sequence.events_h5 or sequence.events_txt
    if events_path is None:
        raise ValueError(f"{sequence.folder}: no events.h5 or events.txt")
    trajectory = read_trajectory(sequence.groundtruth_path)
    poses = (float(trajectory.t_start), float(trajectory.t_end))
    events = _events_span(sequence, events_path)
    check_time_units(events_path, *events, *poses)           # events/t in ns, say, named as such
    data = f"events {_span(events)}, poses {_span(poses)}"
    lo, hi = max(events[0], poses[0]), min(events[1], poses[1])
    if not hi > lo:
        raise ValueError(f"{sequence.folder}: the events and the poses do not overlap ({data})")
    a = lo if t0 is None else float(t0)
    b = hi if t1 is None else float(t1)
    asked = f"time window [{a:g}, {b:g}] s"
    if not a < b:
        raise ParameterError(f"empty {asked}; expected {{t0}} < {{t1}}", **WINDOW_TERMS)
    # a bound within EXACT_TIME_S of the data's is the same instant (float round-off of t0 + length)
    used = (a if a >= lo - EXACT_TIME_S else lo, b if b <= hi + EXACT_TIME_S else hi)
    if not used[0] < used[1]:
        raise ParameterError(f"{asked} lies outside the data ({data}); choose {{t0}}/{{t1}} "
                             f"within {_span((lo, hi))}", **WINDOW_TERMS)
    past = max(lo - a, b - hi)
    if past > WINDOW_SLACK_S and not clip:
        raise ParameterError(f"{asked} reaches {past:.3g} s past the data ({data}); choose "
                             f"{{t0}}/{{t1}} within {_span((lo, hi))}, or add {{clip_window}} to "
                             f"map {_span(used)}", **WINDOW_TERMS)
    clipped = (t0 is not None and used[0] != a) or (t1 is not None and used[1] != b)
    t_ref = 0.5 * (used[0] + used[1]) if ref_time is None else float(ref_time)
    if not poses[0] <= t_ref <= poses[1]:
        raise ParameterError(f"reference time {t_ref} s is outside the poses {_span(poses)}; "
                             "choose {ref_time} within them", **WINDOW_TERMS)
    if t0 is not None or t1 is not None or ref_time is not None:
        half = max(REF_TOLERANCE_SHARE * (used[1] - used[0]), REF_TOLERANCE_MIN_S)
        near = (max(t_ref - half, used[0]), min(t_ref + half, used[1]))
        count = len(read_window(events_path, int(round(near[0] * 1e9)),
                                int(round(near[1] * 1e9)))) if near[1] > near[0] else 0
        if count < REF_MIN_EVENTS:
            raise ParameterError(f"the reference view at {t_ref:.6f} s has {count} events of "
                                 f"the window {_span(used)} within {1e3 * half:.0f} ms of it (at "
                                 f"least {REF_MIN_EVENTS} needed; {data}); move {{t0}}/{{t1}} (or "
                                 "{ref_time}) to where the events are", **WINDOW_TERMS)
    return TimeWindow((t0, t1), used[0], used[1], clipped, t_ref, events, poses)


def _exact_reference(sequence: Sequence, t_ref: float
                     ) -> tuple[Camera, np.ndarray, float, bool] | None:
    """The TRUE camera of the reference view at ``t_ref``, or None without a scene (a real
    recording). Scoring only: the one place that reads the rig's exact files.

    With a perfect rig that is the pose and calibration the map was built with. With an
    imperfect one (:mod:`sim.capture_errors`) it is the true camera at that instant: the exact
    pose (``groundtruth_exact.txt``) at the true time ``t_ref - poses_offset`` and the true
    intrinsics (``calib_exact.txt``) without distortion.

    Parameters
    ----------
    sequence : Sequence
    t_ref : float, seconds, on the poses' clock (as ``map.json``'s ``t_ref``)

    Returns
    -------
    camera : Camera
        The true intrinsics, undistorted (the map's pixel grid).
    T_world_cam : (4, 4) float64 ndarray
        The exact pose at the true time (camera to world).
    t_true : float, seconds
        The true time of ``t_ref``.
    distorted : bool
        The true sensor has lens distortion (its ``depth/`` images are not in ``camera``'s
        pixels).
    """
    meta = sequence.metadata or {}
    toml = (meta.get("scene") or {}).get("toml")
    if not toml:
        return None
    from sim.capture_errors import exact_camera, exact_trajectory, true_time

    sensor = exact_camera(sequence)
    camera = Camera(sensor.width, sensor.height, sensor.fx, sensor.fy, sensor.cx, sensor.cy)
    t_true = true_time(meta, t_ref, "poses")
    pose = exact_trajectory(sequence).pose(t_true)
    return camera, pose, t_true, sensor.has_distortion


def _exact_depth_view(sequence: Sequence, t_ref: float, supersample: int = 1
                      ) -> tuple[np.ndarray, Camera, np.ndarray] | None:
    """Exact depth of the reference view with the camera and pose it is exact in, or None
    without a scene. Scoring only (:func:`_ground_truth_depth` of a map, and
    :func:`fusion.globalmap.score.exact_view` of a global map's key views).

    The map is the depth seen from the reference view: the TRUE camera at that instant
    (:func:`_exact_reference`), in that camera's undistorted pixels. So a map built from noisy
    poses or a wrong calibration is scored against what it should have been, and its errors
    include theirs; it is never compared with a truth rendered at its own (wrong) pose.

    The exact depth written in ``depth/`` is used when it is that very image (a sensor without
    distortion and a depth map at the true reference time; ``depthmaps.txt`` is on the frames'
    clock); otherwise the scene of ``sequence.json`` is rendered in the true undistorted camera at
    the true pose and time: an exact z-depth at the centres of the map's pixels, never an
    interpolation of the distorted one.

    Parameters
    ----------
    sequence : Sequence
    t_ref : float, seconds, on the poses' clock (as ``map.json``'s ``t_ref``)
    supersample : int, >= 1
        Each pixel split into ``supersample x supersample`` (the same field of view,
        :meth:`Camera.with_resolution`), always rendered: a denser exact sampling of the surface
        (default 1: the map's own pixels).

    Returns
    -------
    depth : (H, W) float32 ndarray, metres, 0 where no surface
        (``supersample`` times ``H`` and ``W``)
    camera : Camera
        The true camera, undistorted: ``depth``'s pixel grid.
    T_world_cam : (4, 4) float64 ndarray
        The exact pose of ``camera`` at the true time (camera to world).
    Or None (a real recording).
    """
    reference = _exact_reference(sequence, t_ref)
    if reference is None:
        return None
    camera, pose, t_true, distorted = reference
    n = int(supersample)
    if n > 1:
        camera = camera.with_resolution(n * camera.width, n * camera.height)
    k = None
    if not distorted and n == 1:
        from sim.capture_errors import true_time

        frames_offset = t_ref - true_time(sequence.metadata, t_ref, "frames")
        k = sequence.nearest_depth(t_true + frames_offset)
    if k is not None:
        return read_depth(sequence.depth_paths[k]), camera, pose
    from sim.render import Renderer

    scene = replace(recorded_scene(sequence.metadata), camera=camera)
    return Renderer(scene, spp=1).depth(t_true, pose=pose), camera, pose


def _ground_truth_depth(sequence: Sequence, t_ref: float) -> np.ndarray | None:
    """Exact depth of the reference view, in the pixel grid the map should have, or None
    without a scene: the depth of :func:`_exact_depth_view` (the true camera, undistorted, at
    the exact pose and the true time). Scoring only.

    Parameters
    ----------
    sequence : Sequence
    t_ref : float, seconds, on the poses' clock (as ``map.json``'s ``t_ref``)

    Returns
    -------
    (H, W) float32 ndarray, metres, 0 where no surface; or None (a real recording)
    """
    exact = _exact_depth_view(sequence, t_ref)
    return None if exact is None else exact[0]


def _motion_regions(sequence: Sequence, t_ref: float, window: tuple[float, float]
                    ) -> np.ndarray | None:
    """:func:`fusion.scoring.motion_regions` of the reference view (the true camera, undistorted,
    at the true pose and time: :func:`_exact_reference`), or None for a real recording or a
    scene whose objects do not move. Scoring only."""
    meta = sequence.metadata or {}
    scene = recorded_scene(meta)
    if scene is None or not scene.is_dynamic:
        return None
    from sim.capture_errors import true_time

    camera, pose, t_true, _ = _exact_reference(sequence, t_ref)
    return motion_regions(scene, camera, pose, t_true,
                          tuple(true_time(meta, t, "events") for t in window))


RANGE_SHARE = 0.5
"""Share of the reference view's exact depth that the DSI's depth range must contain."""
PILE_UP_SHARE = 0.3
"""Largest share of map points allowed on the two planes at either end of the range."""


def _check_range_contains(truth: np.ndarray, dsi: DSIParams) -> None:
    """Refuse a depth range that misses most of the scene (known exactly: simulated)."""
    valid = truth[truth > 0]
    if valid.size == 0:
        return
    inside = float(np.mean((valid >= dsi.min_depth) & (valid <= dsi.max_depth)))
    if inside < RANGE_SHARE:
        low, high = np.percentile(valid, [1, 99])
        raise ParameterError(f"depth range [{dsi.min_depth:g}, {dsi.max_depth:g}] m does not "
                             f"contain the scene: {100 * inside:.0f} % of the reference view's "
                             f"exact depth lies in it (the scene spans {low:.3g}-{high:.3g} m); "
                             "set {min_depth}/{max_depth} around it", **RANGE_TERMS)


def _extract(dsi: np.ndarray, planes: np.ndarray, depth_params: DepthMapParams,
             camera: Camera, params: MapParams, counts: dict | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    """The map of a DSI: :func:`fusion.map.emvs.semidense_depth`, then the radius outliers removed.

    Returns
    -------
    depth, confidence, mask : as :func:`fusion.map.emvs.semidense_depth`'s, outliers removed
    radius : float, metres, the outlier radius used
    removed : int, outliers removed
    """
    depth, confidence, mask = semidense_depth(dsi, planes, depth_params, counts=counts)
    v, u = np.nonzero(mask)
    points = camera.backproject(np.stack([u, v], 1), depth[v, u])
    radius = params.outlier_radius * min(1.0, float(np.median(depth[mask])) if mask.any()
                                         else 1.0)
    inlier = radius_outliers(points, radius, params.outlier_neighbours)
    mask[v[~inlier], u[~inlier]] = False
    depth[~mask] = 0.0
    return depth, confidence, mask, radius, int((~inlier).sum())


def _check_no_pile_up(depths: np.ndarray, planes: np.ndarray, dsi: DSIParams) -> None:
    """Refuse a map whose points pile up at one end of the range: the scene lies beyond it.

    ``depths`` are the points of rpg_emvs's map (the points whose DSI maximum lies on the first
    or last plane kept, :class:`fusion.map.emvs.DepthMapParams` ``keep_boundary_planes``): they are
    the evidence.

    Rays of a scene outside the range meet in no plane, and the argmax then sits on the plane
    nearest to where they would: the first or last ones. Measured on the real ECD slider prefix
    (scene at 0.5-2.4 m): 2 % of points on the end planes with 0.47-2.4 m, 58 % with 3-8 m.
    A range entirely in front of a scene does not pile up this way; with ground truth it is
    caught by the exact depth instead.
    """
    if depths.size < 50:
        return
    ends = np.isin(np.asarray(depths, np.float32), np.asarray(planes, np.float32)[[0, 1, -2, -1]])
    near = np.isin(np.asarray(depths, np.float32), np.asarray(planes, np.float32)[[0, 1]])
    share = float(np.mean(ends))
    if share > PILE_UP_SHARE:
        where = "nearer than" if near.sum() >= ends.sum() - near.sum() else "beyond"
        raise ParameterError(f"depth range [{dsi.min_depth:g}, {dsi.max_depth:g}] m does not "
                             f"seem to contain the scene: {100 * share:.0f} % of the map points "
                             f"lie on the planes at its ends (the scene is probably {where} that "
                             "range); set {min_depth}/{max_depth} around it", **RANGE_TERMS)


DSI_TIMING = ("excludes compilation: the DSI kernels are compiled (or loaded from numba's "
              "cache) on one event into a 2-plane DSI before the clock starts; that time is "
              "timings.dsi_compile_s")
"""What ``map.json``'s ``dsi_mev_per_s`` (events used / ``timings.dsi_s``) measures."""


def _compile_dsi(trajectory, T_world_ref: np.ndarray, t_ref: float, camera: Camera,
                 dsi: DSIParams) -> float:
    """Compile (or load) the DSI kernels on one event; return the seconds it took."""
    clock = time.perf_counter()
    disparity_space_image(np.zeros((1, 2)), np.array([t_ref]), trajectory, T_world_ref, camera,
                          DSIParams(dsi.min_depth, dsi.max_depth, 2, dsi.packet_size))
    return time.perf_counter() - clock


def map_sequence(folder: str | Path, params: MapParams, progress: bool = True) -> MapResult:
    """Build the semi-dense map of a sequence folder (see the module docstring).

    Raises
    ------
    ValueError
        Missing events or poses, a window with no events or outside the poses, a DSI that
        would not fit in memory: each before any heavy work.
    """
    timings: dict[str, float] = {}
    start = time.perf_counter()
    sequence = load_sequence(folder)
    if sequence.groundtruth_path is None:
        raise ValueError(f"{folder}: no groundtruth.txt (the camera poses are needed)")
    events_path = sequence.events_h5 or sequence.events_txt
    if events_path is None:
        raise ValueError(f"{folder}: no events.h5 or events.txt")
    sensor = sequence.camera
    trajectory = read_trajectory(sequence.groundtruth_path)
    dsi_bytes = 4 * params.dsi.planes * sensor.width * sensor.height
    if dsi_bytes > DSI_MEMORY_LIMIT:
        limit = DSI_MEMORY_LIMIT / 2**30
        raise ParameterError(f"a {sensor.width}x{sensor.height}x{params.dsi.planes} DSI needs "
                         f"{dsi_bytes / 2**30:.1f} GiB, more than the {limit:.0f} GiB allowed: "
                         "use fewer {planes}", planes="planes")
    window = time_window(sequence, params.t0, params.t1, ref_time=params.ref_time,
                         clip=params.clip_window)
    t0, t1, t_ref = window.t0, window.t1, window.t_ref
    T_world_ref = trajectory.pose(t_ref)
    camera = Camera(sensor.width, sensor.height, sensor.fx, sensor.fy, sensor.cx, sensor.cy)
    lut = sensor.normalized_pixel_centres()            # undistorted (X/Z, Y/Z) of each pixel
    dsi = np.zeros((params.dsi.planes, sensor.height, sensor.width), np.float32)
    used = dropped_before = dropped_after = 0
    # Without an explicit window every event is read, so that those outside the poses are counted;
    # with one, the events of the window asked for (those outside the poses are dropped and
    # counted likewise, leaving the window used).
    t0_ns = None if params.t0 is None else int(round(params.t0 * 1e9))
    t1_ns = None if params.t1 is None else int(round(params.t1 * 1e9))
    timings["setup_s"] = time.perf_counter() - start
    timings["dsi_compile_s"] = _compile_dsi(trajectory, T_world_ref, t_ref, camera, params.dsi)
    tick = time.perf_counter()
    dsi_time = 0.0
    bar = progress_stage(desc="map", unit="ev", noun="events", enabled=progress)
    for chunk in iter_event_chunks(events_path, 10**6, t0_ns, t1_ns, width=sensor.width,
                                   height=sensor.height):
        t = chunk["t"] * 1e-9
        before, after = t < trajectory.t_start, t > trajectory.t_end
        dropped_before += int(before.sum())
        dropped_after += int(after.sum())
        keep = ~(before | after)
        chunk, t = chunk[keep], t[keep]
        xy = lut[chunk["y"], chunk["x"]]
        valid = np.all(np.isfinite(xy), axis=1)
        clock = time.perf_counter()
        disparity_space_image(xy[valid], t[valid], trajectory, T_world_ref, camera, params.dsi,
                              dsi)
        dsi_time += time.perf_counter() - clock
        used += int(valid.sum())
        bar.update(len(keep))
    bar.close()
    timings["events_s"] = time.perf_counter() - tick
    timings["dsi_s"] = dsi_time
    if used == 0:
        raise ValueError(f"{events_path}: no events in the window [{t0}, {t1}] s covered by "
                         f"the poses [{trajectory.t_start}, {trajectory.t_end}] s")
    tick = time.perf_counter()
    planes = depth_planes(params.dsi)
    boundary: dict = {}
    depth, confidence, mask, radius, removed = _extract(dsi, planes, params.depth, camera,
                                                        params, boundary)
    timings["depth_map_s"] = time.perf_counter() - tick
    timings["total_s"] = time.perf_counter() - start
    info = {
        **(params.dsi_range or DSIRange(params.dsi.min_depth, params.dsi.max_depth,
                                        "given")).as_dict(),
        "events_used": used, "events_dropped_before_poses": dropped_before,
        "events_dropped_after_poses": dropped_after, "window_s": [t0, t1],
        "window_requested_s": list(window.requested), "window_clipped": window.clipped,
        "dsi_mev_per_s": used / dsi_time / 1e6 if dsi_time > 0 else None,
        "dsi_timing": DSI_TIMING,
        "outlier_radius_m": radius, "outliers_removed": removed,
        "boundary_plane_points": boundary,
        # the map's own depths (blind): what `evfuse twin --depth` asks for; None without points
        "depth_median_m": float(np.median(depth[mask])) if mask.any() else None,
        "timings": timings,
    }
    # Scoring, the only step that reads the exact depth (a simulated sequence's), and only after
    # the map is made: a range that misses the scene is refused with the scene's true span.
    truth = _ground_truth_depth(sequence, t_ref)
    if truth is not None and params.check_depth_range:
        _check_range_contains(truth, params.dsi)
    if params.check_depth_range:
        # on rpg_emvs's map, the end planes' points kept: those are what pile up
        kept = depth if params.depth.keep_boundary_planes else _extract(
            dsi, planes, replace(params.depth, keep_boundary_planes=True), camera, params)[0]
        _check_no_pile_up(kept[kept > 0], planes, params.dsi)
    if truth is not None:
        info["errors"] = depth_errors(depth, truth)
        regions = _motion_regions(sequence, t_ref, (t0, t1))
        if regions is not None:
            info["errors_by_motion"] = errors_by_motion(depth, truth, regions)
    return MapResult(depth, confidence, mask, camera, t_ref, T_world_ref, info, sequence)


OVERLAY_EVENTS_S = 0.01
"""Half-width (s) of the event window drawn under the map when the event camera has no frames."""


def _reference_image(sequence: Sequence, t_ref: float) -> np.ndarray:
    """The event camera's own frame nearest to the reference time, undistorted, gray (H, W)
    uint8; where it has none (a two-camera rig's event camera), its events within
    :data:`OVERLAY_EVENTS_S` of the reference time (gray 0 where any fired, 255 elsewhere)."""
    camera = sequence.camera
    if len(sequence.image_times):
        k = sequence.nearest_frame(t_ref)
        image = cv2.imread(str(sequence.image_paths[k]), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ValueError(f"cannot read {sequence.image_paths[k]}")
    else:
        events = read_window(sequence.events_h5 or sequence.events_txt,
                             int(round((t_ref - OVERLAY_EVENTS_S) * 1e9)),
                             int(round((t_ref + OVERLAY_EVENTS_S) * 1e9)))
        image = np.full((camera.height, camera.width), 255, np.uint8)
        image[events["y"].astype(np.int64), events["x"].astype(np.int64)] = 0
    if camera.has_distortion:                      # the map lives in undistorted coordinates
        image = cv2.undistort(image, camera.K, np.array(camera.distortion))
    return image


def _overlay(result: MapResult) -> np.ndarray:
    """``overlay.png``: the map points over the event camera's frame nearest the reference time
    (or its events there, :func:`_reference_image`), coloured on
    the map's own depths (1st-99th percentile, :func:`fusion.figures.depth_scale`; the map is
    blind, so no exact depth here), with the colour bar and, for a DSI range taken from the exact
    depth (``info["oracle"]``), a header saying so."""
    scale = depth_scale(result.depth)
    lo_hi = (scale.lo, scale.hi) if scale else (None, None)
    overlay = depth_colours(result.depth, *lo_hi,
                            base=_reference_image(result.sequence, result.t_ref))
    legend = scale.legend() if scale else None
    grid = panel_grid([overlay], [f"map at {result.t_ref:.3f} s (N1 = {result.n1})"], columns=1,
                      legends=[legend])
    header = oracle_header(bool(result.info.get("oracle")))
    return add_header(grid, header)


def write_map(result: MapResult, out: str | Path, params: MapParams,
              overwrite: bool = False) -> Path:
    """Write ``semidense_depth.exr``, ``confidence.exr``, ``mask.png``, ``overlay.png``,
    ``map.ply`` and ``map.json`` into ``out`` (atomically; :func:`sim.output.atomic_output_dir`
    refuses an ``out`` that is, holds or lies in the sequence folder)."""
    sequence = result.sequence
    with atomic_output_dir(out, overwrite=overwrite, inputs=[sequence.folder],
                           command="evfuse map") as tmp:
        write_depth(tmp / "semidense_depth.exr", result.depth)
        write_exr_channels(tmp / "confidence.exr", {"Y": result.confidence})
        cv2.imwrite(str(tmp / "mask.png"), result.mask.astype(np.uint8) * 255)
        cv2.imwrite(str(tmp / "overlay.png"), _overlay(result))
        write_ply(tmp / "map.ply", result.points(), result.T_world_ref)
        document = {
            "N1": result.n1,
            "t_ref": result.t_ref,
            "T_world_ref": result.T_world_ref.tolist(),
            # relative to this folder (its .partial sibling has the same relation), so that a
            # run folder can be moved whole
            "sequence": os.path.relpath(Path(sequence.folder).resolve(), tmp.resolve()),
            "params": {"dsi": asdict(params.dsi), "depth": asdict(params.depth),
                       "t0": params.t0, "t1": params.t1, "ref_time": params.ref_time,
                       "clip_window": params.clip_window,
                       "outlier_radius": params.outlier_radius,
                       "outlier_neighbours": params.outlier_neighbours},
            "camera": {"width": result.camera.width, "height": result.camera.height,
                       "fx": result.camera.fx, "fy": result.camera.fy, "cx": result.camera.cx,
                       "cy": result.camera.cy},
            **result.info,
        }
        (tmp / "map.json").write_text(to_json(document))
    return Path(out)
