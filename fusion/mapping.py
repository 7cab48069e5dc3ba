"""``evfuse map``: a semi-dense depth map of a sequence folder from its events and poses (EMVS).

Reads a sequence folder (simulated, or a real Event-Camera Dataset folder), streams the events
of a time window into a disparity space image at a reference view, extracts the semi-dense depth
(:mod:`fusion.emvs`), removes radius outliers from the point cloud and, when the sequence was
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
from tqdm.auto import tqdm

from fusion.emvs import (
    DepthMapParams,
    DSIParams,
    depth_planes,
    disparity_space_image,
    semidense_depth,
)
from fusion.figures import depth_colours
from fusion.jsonio import to_json
from fusion.pointcloud import write_ply
from fusion.scoring import depth_errors
from sim.camera import Camera
from sim.eventio import iter_event_chunks
from sim.exr import read_depth, write_depth, write_exr_channels
from sim.sequence import Sequence, atomic_output_dir, load_sequence
from sim.trajectory import read_trajectory

__all__ = ["MapParams", "MapResult", "map_sequence", "radius_outliers", "write_map"]

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
        Event window (default: from the first to the last event, within the poses).
    ref_time : float or None, seconds
        Reference view (default: the middle of the window).
    outlier_radius : float, metres
        Radius outlier removal: a point needs ``outlier_neighbours`` others within this radius,
        scaled by the median depth when that is below 1 m (0.05 m at 1 m, as rpg_emvs).
    outlier_neighbours : int
    check_depth_range : bool
        Refuse a depth range that does not contain the scene (default True): before any work
        when the exact depth is known (a simulated sequence: at least half of it must lie in the
        range), and after extraction when more than 30 % of the map points sit on the two
        planes at either end of the range.
    """

    dsi: DSIParams
    depth: DepthMapParams = field(default_factory=DepthMapParams)
    t0: float | None = None
    t1: float | None = None
    ref_time: float | None = None
    outlier_radius: float = 0.05
    outlier_neighbours: int = 3
    check_depth_range: bool = True


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


def _event_span(path: Path, sensor: Camera) -> tuple[float, float]:
    """First and last event times (s), by one streaming pass over the file."""
    first = last = None
    for chunk in iter_event_chunks(path, 10**6, width=sensor.width, height=sensor.height):
        if len(chunk):
            first = chunk["t"][0] if first is None else first
            last = chunk["t"][-1]
    if first is None:
        raise ValueError(f"{path}: the file holds no events")
    return first * 1e-9, last * 1e-9


def _ground_truth_depth(sequence: Sequence, t_ref: float, pose: np.ndarray,
                        camera: Camera) -> np.ndarray | None:
    """Exact depth of the reference view in the map's own pixel grid, or None without a scene.

    The map lives in ``camera``, the reference view's undistorted virtual camera. The exact
    depth written in ``depth/`` is in the sensor's pixels: it is used only when the sensor is
    that same camera (no distortion) and a depth map was written at ``t_ref`` exactly. Otherwise
    (lens distortion, or no depth map at that time) the scene of ``sequence.json`` is rendered in
    ``camera`` at ``t_ref`` and ``pose``: an exact z-depth at the centres of the map's pixels,
    never an interpolation of the distorted one.

    Parameters
    ----------
    sequence : Sequence
    t_ref : float, seconds
    pose : (4, 4) ndarray, T_world_ref
    camera : Camera, the reference view's virtual camera (no distortion)

    Returns
    -------
    (H, W) float32 ndarray, metres, 0 where no surface; or None (a real recording)
    """
    meta = sequence.metadata or {}
    toml = (meta.get("scene") or {}).get("toml")
    same_grid = sequence.camera == camera
    if same_grid and sequence.depth_times is not None and len(sequence.depth_times):
        k = int(np.argmin(np.abs(sequence.depth_times - t_ref)))
        if abs(sequence.depth_times[k] - t_ref) < 1e-9:
            return read_depth(sequence.depth_paths[k])
    if not toml:
        return None
    from sim.render import Renderer
    from sim.scene import parse_scene

    source = (meta.get("scene") or {}).get("source") or "<sequence.json>"
    scene = replace(parse_scene(toml, source, seed=meta.get("seed")), camera=camera)
    return Renderer(scene, spp=1).depth(t_ref, pose=pose)


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
        raise ValueError(f"depth range [{dsi.min_depth:g}, {dsi.max_depth:g}] m does not contain "
                         f"the scene: {100 * inside:.0f} % of the reference view's exact depth "
                         f"lies in it (the scene spans {low:.3g}-{high:.3g} m); set "
                         "--min-depth/--max-depth around it")


def _check_no_pile_up(depths: np.ndarray, planes: np.ndarray, dsi: DSIParams) -> None:
    """Refuse a map whose points pile up at one end of the range: the scene lies beyond it.

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
        raise ValueError(f"depth range [{dsi.min_depth:g}, {dsi.max_depth:g}] m does not seem to "
                         f"contain the scene: {100 * share:.0f} % of the map points lie on the "
                         f"planes at its ends (the scene is probably {where} that range); "
                         "set --min-depth/--max-depth around it")


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
        raise ValueError(f"a {sensor.width}x{sensor.height}x{params.dsi.planes} DSI needs "
                         f"{dsi_bytes / 2**30:.1f} GiB, more than the {limit:.0f} GiB allowed: "
                         "use fewer --planes")
    if params.t0 is None or params.t1 is None:
        first, last = _event_span(events_path, sensor)
        t0 = max(first, trajectory.t_start) if params.t0 is None else params.t0
        t1 = min(last, trajectory.t_end) if params.t1 is None else params.t1
    else:
        t0, t1 = params.t0, params.t1
    if not t0 < t1:
        raise ValueError(f"empty time window [{t0}, {t1}] s")
    if t1 <= trajectory.t_start or t0 >= trajectory.t_end:
        raise ValueError(f"time window [{t0}, {t1}] s lies outside the poses "
                         f"[{trajectory.t_start}, {trajectory.t_end}] s")
    lo, hi = max(t0, trajectory.t_start), min(t1, trajectory.t_end)
    t_ref = 0.5 * (lo + hi) if params.ref_time is None else params.ref_time
    if not trajectory.t_start <= t_ref <= trajectory.t_end:
        raise ValueError(f"reference time {t_ref} s is outside the poses "
                         f"[{trajectory.t_start}, {trajectory.t_end}] s")
    T_world_ref = trajectory.pose(t_ref)
    camera = Camera(sensor.width, sensor.height, sensor.fx, sensor.fy, sensor.cx, sensor.cy)
    truth = _ground_truth_depth(sequence, t_ref, T_world_ref, camera)
    if truth is not None and params.check_depth_range:
        _check_range_contains(truth, params.dsi)
    lut = sensor.normalized_pixel_centres()            # undistorted (X/Z, Y/Z) of each pixel
    dsi = np.zeros((params.dsi.planes, sensor.height, sensor.width), np.float32)
    used = dropped_before = dropped_after = 0
    # Without an explicit window every event is read, so that those outside the poses are counted.
    t0_ns = None if params.t0 is None else int(round(t0 * 1e9))
    t1_ns = None if params.t1 is None else int(round(t1 * 1e9))
    timings["setup_s"] = time.perf_counter() - start
    tick = time.perf_counter()
    dsi_time = 0.0
    bar = tqdm(desc="map: events", unit="ev", disable=not progress)
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
    depth, confidence, mask = semidense_depth(dsi, planes, params.depth)
    v, u = np.nonzero(mask)
    points = camera.backproject(np.stack([u, v], 1), depth[v, u])
    radius = params.outlier_radius * min(1.0, float(np.median(depth[mask])) if mask.any()
                                         else 1.0)
    inlier = radius_outliers(points, radius, params.outlier_neighbours)
    mask[v[~inlier], u[~inlier]] = False
    depth[~mask] = 0.0
    timings["depth_map_s"] = time.perf_counter() - tick
    timings["total_s"] = time.perf_counter() - start
    info = {
        "events_used": used, "events_dropped_before_poses": dropped_before,
        "events_dropped_after_poses": dropped_after, "window_s": [t0, t1],
        "dsi_mev_per_s": used / dsi_time / 1e6 if dsi_time > 0 else None,
        "outlier_radius_m": radius, "outliers_removed": int((~inlier).sum()),
        "timings": timings,
    }
    if params.check_depth_range:
        _check_no_pile_up(depth[mask], planes, params.dsi)
    result = MapResult(depth, confidence, mask, camera, t_ref, T_world_ref, info, sequence)
    if truth is not None:
        info["errors"] = depth_errors(depth, truth)
    return result


def _reference_image(sequence: Sequence, t_ref: float) -> np.ndarray:
    """The standard frame nearest to the reference time, undistorted, gray (H, W) uint8."""
    k = int(np.argmin(np.abs(sequence.image_times - t_ref)))
    image = cv2.imread(str(sequence.image_paths[k]), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError(f"cannot read {sequence.image_paths[k]}")
    camera = sequence.camera
    if camera.has_distortion:                      # the map lives in undistorted coordinates
        image = cv2.undistort(image, camera.K, np.array(camera.distortion))
    return image


def write_map(result: MapResult, out: str | Path, params: MapParams,
              overwrite: bool = False) -> Path:
    """Write ``semidense_depth.exr``, ``confidence.exr``, ``mask.png``, ``overlay.png``,
    ``map.ply`` and ``map.json`` into ``out`` (atomically)."""
    sequence = result.sequence
    with atomic_output_dir(out, overwrite=overwrite) as tmp:
        write_depth(tmp / "semidense_depth.exr", result.depth)
        write_exr_channels(tmp / "confidence.exr", {"Y": result.confidence})
        cv2.imwrite(str(tmp / "mask.png"), result.mask.astype(np.uint8) * 255)
        overlay = depth_colours(result.depth, base=_reference_image(sequence, result.t_ref))
        cv2.imwrite(str(tmp / "overlay.png"), overlay)
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
                       "outlier_radius": params.outlier_radius,
                       "outlier_neighbours": params.outlier_neighbours},
            "camera": {"width": result.camera.width, "height": result.camera.height,
                       "fx": result.camera.fx, "fy": result.camera.fy, "cx": result.camera.cx,
                       "cy": result.camera.cy},
            **result.info,
        }
        (tmp / "map.json").write_text(to_json(document))
    return Path(out)
