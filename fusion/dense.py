"""``evfuse fill``: a dense depth map from a semi-dense map and a standard frame.

Steps 2-4 of "Standard and Event Cameras Fusion for Dense Mapping", wired together: the map
points are projected into the standard frame (the *event image*), the frame is segmented by
region growing (:mod:`fusion.segmentation`), the regions bounded by map points are selected and
filled (:mod:`fusion.filling`), and the filling score is computed. With the exact depth of the
frame (a simulated sequence) the result is scored (:mod:`fusion.scoring`): separately for the map
points, the filled pixels and all, and apart in a band around true depth discontinuities.

The frame is the standard frame nearest in time to the map's reference view. The map points are
projected with the frame's own pose and the sensor's calibration (distortion included), so a frame
a little off the reference time, or a distorted real frame, still gets its map points where they
belong. The dense depth lives in the frame's pixels.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from fusion.dsi_range import oracle_header
from fusion.figures import (
    add_header,
    depth_colours,
    depth_scale,
    error_panel,
    label_colours,
    panel_grid,
    point_cloud_view,
)
from fusion.filling import (
    FillParams,
    RegionStats,
    SelectionParams,
    fill_regions,
    filling_score,
    select_regions,
)
from fusion.jsonio import to_json
from fusion.pointcloud import write_ply
from fusion.scoring import depth_errors, discontinuity_band
from fusion.segmentation import SegmentationParams, segment_regions
from sim.camera import Camera
from sim.exr import read_depth, write_depth
from sim.se3 import invert_pose
from sim.sequence import atomic_output_dir, load_sequence
from sim.trajectory import read_trajectory

__all__ = ["DenseParams", "DenseResult", "dense_errors", "densify", "fill_frame", "fill_map",
           "project_map", "write_fill"]


@dataclass(frozen=True)
class DenseParams:
    """Parameters of ``evfuse fill`` (each stage's defaults are the paper's).

    Attributes
    ----------
    segmentation : SegmentationParams
        Region growing threshold (3 gray levels) and smallest region.
    selection : SelectionParams
        Ring width (3 px), ring ratio (30 %), inside ratio (5 %).
    fill : FillParams
        Weighting (inverse distance; Gaussian sigma 5, exponential).
    band : int, pixels
        Width of the band around true depth discontinuities scored apart (default 3).
    """

    segmentation: SegmentationParams = field(default_factory=SegmentationParams)
    selection: SelectionParams = field(default_factory=SelectionParams)
    fill: FillParams = field(default_factory=FillParams)
    band: int = 3

    def as_dict(self) -> dict:
        """The parameters as plain JSON-ready values."""
        return {"segmentation": asdict(self.segmentation), "selection": asdict(self.selection),
                "fill": asdict(self.fill), "band": self.band}


@dataclass
class DenseResult:
    """A filled map in the pixels of a standard frame.

    Attributes
    ----------
    frame : (H, W) uint8 ndarray, the standard frame
    sparse : (H, W) float32 ndarray, metres, the event image (projected map points), 0 = none
    labels : (H, W) int32 ndarray, regions 1..K, 0 = too small
    regions : RegionStats
    dense : (H, W) float32 ndarray, metres, map points and filled pixels, 0 = none
    camera : Camera, the frame's camera (with its distortion)
    T_world_frame : (4, 4) ndarray or None
    truth : (H, W) float32 ndarray or None, exact depth of the frame
    info : dict, N1, N1_in_frame, N2, Res, beta, beta_counts, timings, frame, and ``errors``
        with a truth
    """

    frame: np.ndarray
    sparse: np.ndarray
    labels: np.ndarray
    regions: RegionStats
    dense: np.ndarray
    camera: Camera
    T_world_frame: np.ndarray | None
    truth: np.ndarray | None
    info: dict

    @property
    def n1_in_frame(self) -> int:
        """Map points that land in the frame (non-zero pixels of the event image)."""
        return int(np.count_nonzero(self.sparse))

    @property
    def n2(self) -> int:
        """Map points in the frame plus filled pixels (non-zero pixels of the dense map)."""
        return int(np.count_nonzero(self.dense))


def project_map(depth_ref: np.ndarray, camera_ref: Camera, T_world_ref: np.ndarray,
                camera: Camera, T_world_frame: np.ndarray) -> np.ndarray:
    """The event image: map points projected into a frame, the nearest one per pixel.

    Parameters
    ----------
    depth_ref : (h, w) float ndarray, metres, 0 = no map point
        The semi-dense map at the reference view.
    camera_ref : Camera
        The reference view's (undistorted) camera.
    T_world_ref, T_world_frame : (4, 4) ndarray
        Poses of the reference view and of the frame.
    camera : Camera
        The frame's camera (distortion included).

    Returns
    -------
    (H, W) float32 ndarray, metres
        z-depth in the frame of each projected point, rounded to the nearest pixel; 0 elsewhere.
    """
    depth_ref = np.asarray(depth_ref, dtype=np.float64)
    if depth_ref.shape != (camera_ref.height, camera_ref.width):
        raise ValueError(f"the map is {depth_ref.shape[1]}x{depth_ref.shape[0]} but its camera "
                         f"is {camera_ref.width}x{camera_ref.height}")
    v, u = np.nonzero(depth_ref > 0)
    out = np.zeros((camera.height, camera.width), np.float32)
    if len(v) == 0:
        return out
    points = camera_ref.backproject(np.stack([u, v], 1).astype(np.float64), depth_ref[v, u])
    T = invert_pose(np.asarray(T_world_frame, np.float64)) @ np.asarray(T_world_ref, np.float64)
    local = points @ T[:3, :3].T + T[:3, 3]
    uv = camera.project(local)
    col = np.round(uv[:, 0])
    row = np.round(uv[:, 1])
    inside = (np.isfinite(col) & np.isfinite(row) & (col >= 0) & (col < camera.width)
              & (row >= 0) & (row < camera.height))
    col, row, z = col[inside].astype(np.int64), row[inside].astype(np.int64), local[inside, 2]
    order = np.argsort(-z)                                  # far first: the nearest is kept
    out[row[order], col[order]] = z[order]
    return out


def densify(frame: np.ndarray, sparse: np.ndarray, params: DenseParams | None = None
            ) -> tuple[np.ndarray, RegionStats, np.ndarray, dict]:
    """Segment, select and fill: the three stages on arrays.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray, gray
    sparse : (H, W) float ndarray, metres, the event image
    params : DenseParams, optional

    Returns
    -------
    labels : (H, W) int32 ndarray
    regions : RegionStats
    dense : (H, W) float32 ndarray, metres
    timings : dict, seconds per stage (``segment_s``, ``select_s``, ``fill_s``)
    """
    params = params or DenseParams()
    frame = np.asarray(frame)
    sparse = np.asarray(sparse)
    if frame.ndim != 2:
        raise ValueError(f"the frame must be a gray (H, W) image, got shape {frame.shape}")
    if frame.shape != sparse.shape:
        raise ValueError(f"the frame is {frame.shape[1]}x{frame.shape[0]} but the sparse depth is "
                         f"{sparse.shape[1]}x{sparse.shape[0]}: they must be the same size")
    tick = time.perf_counter()
    labels = segment_regions(frame, params.segmentation)
    tock = time.perf_counter()
    regions = select_regions(labels, sparse, params.selection)
    tack = time.perf_counter()
    dense = fill_regions(labels, sparse, regions, params.fill)
    end = time.perf_counter()
    return labels, regions, dense, {"segment_s": tock - tick, "select_s": tack - tock,
                                    "fill_s": end - tack}


def dense_errors(dense: np.ndarray, sparse: np.ndarray, truth: np.ndarray, band: int = 3
                 ) -> dict:
    """Errors against the exact depth, for the map points, the filled pixels and all, overall,
    in the ``band``-pixel band around true discontinuities and in the region interiors.

    Returns
    -------
    dict
        ``{"map" | "filled" | "all": {"overall" | "band" | "interior": depth_errors(...)}}``
        (:func:`fusion.scoring.depth_errors`, the same definitions as ``map.json``'s):
        completeness is the share of the pixels with a true depth that have a depth of that
        kind; ``points`` and the precisions count every point of that kind, those where the
        exact depth is 0 (no surface) included.
    """
    sparse = np.asarray(sparse, np.float32)
    dense = np.asarray(dense, np.float32)
    filled = np.where(sparse > 0, 0.0, dense).astype(np.float32)
    near = discontinuity_band(truth, width=band)
    out = {}
    for name, depth in (("map", sparse), ("filled", filled), ("all", dense)):
        out[name] = {"overall": depth_errors(depth, truth),
                     "band": depth_errors(depth, truth, near),
                     "interior": depth_errors(depth, truth, ~near)}
    return out


def fill_frame(frame: np.ndarray, sparse: np.ndarray, camera: Camera,
               params: DenseParams | None = None, truth: np.ndarray | None = None,
               T_world_frame: np.ndarray | None = None, info: dict | None = None,
               n1: int | None = None) -> DenseResult:
    """Fill any frame from its event image (the ``--frame --sparse-depth`` form of the command).

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
    sparse : (H, W) float ndarray, metres, 0 = no map point
    camera : Camera, the frame's calibration (for the point cloud)
    params : DenseParams, optional
    truth : (H, W) float ndarray, metres, optional: the exact depth, to score against
    T_world_frame : (4, 4) ndarray, optional: written into the point cloud
    info : dict, optional: extra entries for ``fill.json``
    n1 : int, optional
        ``N1``, the map's points before projection (``map.json``'s); default the non-zero pixels
        of ``sparse``.

    Returns
    -------
    DenseResult
        ``info`` holds the counts: ``N1`` (map points), ``N1_in_frame`` (non-zero pixels of
        ``sparse``), ``N2`` (non-zero pixels of the dense map: ``N1_in_frame`` plus the filled
        pixels), ``Res`` (pixels of the frame), ``beta`` (the filling score
        ``(N2 - N1_in_frame) / (Res + N1_in_frame / Res)``) and ``beta_counts`` (which counts
        it used), ``N2_over_N1_in_frame``.
    """
    params = params or DenseParams()
    start = time.perf_counter()
    if (camera.height, camera.width) != np.shape(frame)[:2]:
        raise ValueError(f"the calibration is for {camera.width}x{camera.height} but the frame "
                         f"is {np.shape(frame)[1]}x{np.shape(frame)[0]}")
    sparse = np.asarray(sparse, np.float32)
    labels, regions, dense, timings = densify(frame, sparse, params)
    in_frame, n2 = int(np.count_nonzero(sparse)), int(np.count_nonzero(dense))
    if n1 is None:
        n1 = in_frame
    elif isinstance(n1, bool) or int(n1) != n1 or n1 < in_frame:
        raise ValueError(f"n1 must be the map's point count, an integer >= the {in_frame} points "
                         f"in the frame, got {n1!r}")
    res = int(frame.shape[0] * frame.shape[1])
    timings["total_s"] = time.perf_counter() - start
    document = {
        "N1": int(n1), "N1_in_frame": in_frame, "N2": n2, "Res": res,
        "beta": filling_score(in_frame, n2, res),
        "beta_counts": "(N2 - N1_in_frame) / (Res + N1_in_frame / Res)",
        "N2_over_N1_in_frame": n2 / in_frame if in_frame else None,
        "regions": int(regions.n_regions), "regions_filled": int(regions.selected.sum()),
        "timings": timings, **(info or {}),
    }
    if truth is not None:
        truth = np.asarray(truth, np.float32)
        if truth.shape != sparse.shape:
            raise ValueError(f"the exact depth is {truth.shape[1]}x{truth.shape[0]} but the frame "
                             f"is {sparse.shape[1]}x{sparse.shape[0]}")
        document["errors"] = dense_errors(dense, sparse, truth, params.band)
    return DenseResult(np.asarray(frame), sparse, labels, regions, dense, camera,
                       T_world_frame, truth, document)


def fill_map(map_folder: str | Path, params: DenseParams | None = None) -> DenseResult:
    """Fill the map written by ``evfuse map`` with the standard frame nearest its reference view.

    Parameters
    ----------
    map_folder : str or Path
        Holds ``map.json`` and ``semidense_depth.exr``; ``map.json`` names the sequence.
    params : DenseParams, optional

    Returns
    -------
    DenseResult
        With ``errors`` when the sequence is simulated (exact depth at the frame's time).
    """
    map_folder = Path(map_folder)
    meta_path = map_folder / "map.json"
    if not meta_path.is_file():
        raise ValueError(f"{map_folder}: no map.json (write a map with evfuse map first)")
    try:
        meta = json.loads(meta_path.read_text())
        t_ref = float(meta["t_ref"])
        T_world_ref = np.array(meta["T_world_ref"], dtype=np.float64).reshape(4, 4)
        c = meta["camera"]
        camera_ref = Camera(int(c["width"]), int(c["height"]), c["fx"], c["fy"], c["cx"],
                            c["cy"])
        sequence_folder = map_folder / meta["sequence"]          # relative, or absolute
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{meta_path}: not a map.json written by evfuse map ({exc})") from exc
    depth_path = map_folder / "semidense_depth.exr"
    if not depth_path.is_file():
        raise ValueError(f"{map_folder}: no semidense_depth.exr")
    depth_ref = read_depth(depth_path)
    sequence = load_sequence(sequence_folder)
    if len(sequence.image_times) == 0:
        raise ValueError(f"{sequence_folder}: no standard frames (images.txt) to fill with")
    k = sequence.nearest_frame(t_ref)
    t_frame = float(sequence.image_times[k])
    frame = cv2.imread(str(sequence.image_paths[k]), cv2.IMREAD_GRAYSCALE)
    if frame is None:
        raise ValueError(f"cannot read the frame {sequence.image_paths[k]}")
    trajectory = read_trajectory(sequence.groundtruth_path)
    if not trajectory.t_start <= t_frame <= trajectory.t_end:
        raise ValueError(f"the frame nearest the reference time ({t_frame} s) is outside the "
                         f"poses [{trajectory.t_start}, {trajectory.t_end}] s")
    T_world_frame = trajectory.pose(t_frame)
    camera = sequence.camera
    if (camera.height, camera.width) != frame.shape:
        camera = camera.with_resolution(frame.shape[1], frame.shape[0])
    sparse = project_map(depth_ref, camera_ref, T_world_ref, camera, T_world_frame)
    if not sparse.any():
        raise ValueError(f"{map_folder}: no map point lands in the frame at {t_frame} s "
                         f"(N1 = {int(np.count_nonzero(depth_ref))} in the map)")
    truth = None
    j = sequence.nearest_depth(t_frame)
    if j is not None:
        truth = read_depth(sequence.depth_paths[j])
    info = {"map": str(map_folder.resolve()),
            # an oracle DSI range (the exact depth) makes every figure downstream an oracle's
            "oracle": bool(meta.get("oracle", False)),
            "depth_range_from": meta.get("depth_range_from", "given"),
            "sequence": str(Path(sequence.folder).resolve()),
            "frame": os.path.relpath(sequence.image_paths[k], sequence.folder),
            "t_frame": t_frame, "t_ref": t_ref, "T_world_frame": T_world_frame.tolist()}
    return fill_frame(frame, sparse, camera, params, truth, T_world_frame, info,
                      n1=int(np.count_nonzero(depth_ref)))


def _figure(result: DenseResult, params: DenseParams) -> np.ndarray:
    """The paper's Figure 2 for one frame, as one image of six panels."""
    panels, titles, legends, header = _figure_panels(result, params)
    return add_header(panel_grid(panels, titles, columns=3, legends=legends), header)


def _figure_panels(result: DenseResult, params: DenseParams
                   ) -> tuple[list[np.ndarray], list[str], list, list[str]]:
    """The panels of Figure 2, their titles, their legends (the depth scale spans the exact
    depth where there is one, and both maps) and the header lines (the oracle warning)."""
    raw = segment_regions(result.frame, SegmentationParams(params.segmentation.threshold, 1))
    points, colours, _ = _cloud(result)
    size = (result.frame.shape[1], result.frame.shape[0])
    scale = depth_scale(result.sparse, result.dense, truth=result.truth)
    lo_hi = (scale.lo, scale.hi) if scale else (None, None)
    legend = scale.legend() if scale else None
    view, caption = point_cloud_view(points, colours, size)
    panels = [
        depth_colours(result.sparse, *lo_hi, base=result.frame),
        label_colours(raw),
        label_colours(result.labels),
        label_colours(result.labels, highlight=result.regions.selected),
        depth_colours(result.dense, *lo_hi),
        view,
    ]
    titles = [f"(a) frame + {result.n1_in_frame} projected map points",
              f"(b) raw segmentation ({int(raw.max())})",
              f"(c) valid regions ({result.regions.n_regions})",
              f"(d) regions to fill ({int(result.regions.selected.sum())})",
              f"(e) range image (N2 = {result.n2})",
              "(f) point cloud: map points red, filled green"]
    header = oracle_header(bool(result.info.get("oracle")))
    return panels, titles, [legend, None, None, None, legend, caption], header


def _error_figure(result: DenseResult) -> np.ndarray:
    """``error.png``: |error| of the dense map with its legend (scale in cm, no value, no
    surface); needs ``result.truth``."""
    image, legend = error_panel(result.dense, result.truth)
    return panel_grid([image], ["|error| of the dense map (map points and filled)"], columns=1,
                      legends=[legend])


def _cloud(result: DenseResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of the dense map in the frame's camera, red for map points, green for filled."""
    v, u = np.nonzero(result.dense > 0)
    points = result.camera.backproject(np.stack([u, v], 1).astype(np.float64),
                                       result.dense[v, u].astype(np.float64))
    source = (result.sparse[v, u] == 0).astype(np.uint8)          # 0 event map, 1 filled
    colours = np.where(source[:, None] == 0, [[0, 0, 255]], [[0, 200, 0]]).astype(np.uint8)
    return points, colours, source


def write_fill(result: DenseResult, out: str | Path, params: DenseParams,
               overwrite: bool = False) -> Path:
    """Write ``dense_depth.exr``, ``segments.png``, ``filled_mask.png``, ``figure.png``,
    ``dense.ply`` and ``fill.json`` (plus ``error.png`` with a truth) into ``out``, atomically.
    """
    with atomic_output_dir(out, overwrite=overwrite) as tmp:
        write_depth(tmp / "dense_depth.exr", result.dense)
        labels16 = np.clip(result.labels, 0, 65535).astype(np.uint16)
        if not cv2.imwrite(str(tmp / "segments.png"), labels16):
            raise OSError(f"cannot write {tmp / 'segments.png'}")
        filled = (result.dense > 0) & (result.sparse == 0)
        cv2.imwrite(str(tmp / "filled_mask.png"), filled.astype(np.uint8) * 255)
        cv2.imwrite(str(tmp / "figure.png"), _figure(result, params))
        points, colours, source = _cloud(result)
        pose = result.T_world_frame if result.T_world_frame is not None else np.eye(4)
        write_ply(tmp / "dense.ply", points, pose, colours, source, frame_name="T_world_frame")
        if result.truth is not None:
            cv2.imwrite(str(tmp / "error.png"), _error_figure(result))
        document = {"params": params.as_dict(),
                    "camera": {"width": result.camera.width, "height": result.camera.height,
                               "fx": result.camera.fx, "fy": result.camera.fy,
                               "cx": result.camera.cx, "cy": result.camera.cy,
                               "distortion": list(result.camera.distortion)},
                    "files": {"segments.png": "region labels, 16-bit (0 = region too small)",
                              "dense.ply": "property source: 0 event map point, 1 filled"},
                    **result.info}
        for key in ("map", "sequence"):             # relative to this folder, as in map.json
            if key in document:
                document[key] = os.path.relpath(Path(document[key]).resolve(), tmp.resolve())
        (tmp / "fill.json").write_text(to_json(document))
    return Path(out)
