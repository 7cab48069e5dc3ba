"""``evfuse fill``: a dense depth map from a semi-dense map and a standard frame.

Steps 2-4 of "Standard and Event Cameras Fusion for Dense Mapping", wired together: the map
points are projected into the standard frame (the *event image*), the frame is segmented by
region growing (:mod:`fusion.fill.segmentation`), the regions bounded by map points are selected and
filled (:mod:`fusion.fill.filling`), and the filling score is computed. With the exact depth of the
frame (a simulated sequence) the result is scored (:mod:`fusion.scoring`): separately for the map
points, the filled pixels and all, and apart in a band around true depth discontinuities.

The frame is the standard frame nearest in time to the map's reference view
(:meth:`sim.sequence.Sequence.standard_frames`: on a two-camera rig, the frame camera's). The map
points are projected with the frame's own pose and its camera's calibration (distortion
included), so a frame a little off the reference time, a distorted real frame, or a rig's frame
camera (pose ``T_world_event(t) @ T_event_frame``, its own lens and size; a rolling shutter row by
row, :mod:`fusion.fill.projection`) still gets its map points where they belong. The dense depth
lives in the frame's pixels and is scored against that camera's exact depth.

The filling method is selectable (``--method``, :mod:`fusion.methods`) and resolved once, where
it is asked for (:func:`resolve_method`, :func:`fusion.methods.fill_request`), into a
:class:`fusion.methods.ResolvedMethod` that the fill stage calls
(:meth:`fusion.methods.FillMethod.fill`) without asking which method it is. The paper's
(``paper-idw``, the default, ``paper-gaussian``, ``paper-exponential``;
:mod:`fusion.methods.paper`) runs the three stages (:func:`densify`) and keeps its segmentation
for the figures and ``segments.png``; any other method is run through
:func:`fusion.methods.run_method`, and its result has no segmentation (all-zero labels,
``regions`` None). Either way ``N2`` counts the non-zero pixels of the dense map and ``beta``
uses the paper's formula, so that for another method it measures that method's fill. A
method's own settings (``method_params``, ``--param``) are checked before any work and
recorded in ``fill.json`` (``method_params``); the paper's methods take their weighting's
length (``sigma``, ``scale``) that way too.

Here: the fill stage (:func:`fill_map`, :func:`fill_inputs`, :func:`fill_frame`,
:func:`densify`, :func:`write_fill`). Its records (:class:`DenseParams`, :class:`FillInputs`,
:class:`DenseResult`) are :mod:`fusion.fill.records`, the projection is
:mod:`fusion.fill.projection`, the scores :mod:`fusion.scoring`
(:func:`fusion.scoring.dense_errors`), Figure 2 :mod:`fusion.figures`
(:func:`fusion.figures.fill_figure`) and the point cloud :mod:`fusion.io`.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from fusion.figures import fill_error_figure, fill_figure
from fusion.fill.filling import RegionStats, fill_regions, filling_score, select_regions
from fusion.fill.projection import (
    ROLLING_ITERATIONS,
    frame_record,
    project_map,
    project_map_rolling,
)
from fusion.fill.records import DenseParams, DenseResult, FillInputs
from fusion.fill.segmentation import segment_regions
from fusion.io import dense_cloud, to_json, write_ply
from fusion.methods._registry import ResolvedMethod, check_params, get_method
from fusion.scoring import dense_errors, errors_by_motion, frame_motion_regions
from sim.camera import Camera
from sim.exr import read_depth, write_depth, write_exr_channels
from sim.output import atomic_output_dir
from sim.sequence import load_sequence
from sim.trajectory import read_trajectory

# project_map, project_map_rolling (fusion.fill.projection), dense_errors and
# frame_motion_regions (fusion.scoring) are also importable from here, where they were; so are
# the stage's records, DenseParams, DenseResult and FillInputs (fusion.fill.records).
__all__ = ["DenseParams", "DenseResult", "FillInputs", "densify", "fill_frame", "fill_inputs",
           "fill_map", "resolve_method", "write_fill"]


def resolve_method(method: str | ResolvedMethod | None, params: DenseParams | None = None,
                   method_params: dict | None = None) -> ResolvedMethod:
    """The filling method to run, its settings and the fill stage's parameters that go with it.

    Parameters
    ----------
    method : str, ResolvedMethod or None
        A method's name or ``module:function`` (:func:`fusion.methods.get_method`); None: the
        paper's method with ``params.fill.weighting`` (``paper-idw`` by default); a
        ResolvedMethod is returned as it is (then ``params`` and ``method_params`` must be
        None).
    params : DenseParams, optional
        The fill stage's parameters (:meth:`fusion.methods.FillMethod.stage_params`: the
        paper's methods set their weighting and its length; any other method uses only
        ``band``).
    method_params : dict, optional
        The method's own settings, checked (:func:`fusion.methods.check_params`).

    Returns
    -------
    ResolvedMethod

    Raises
    ------
    fusion.methods.MethodError
        An unknown method, or a setting it refuses (a ValueError, one line).
    ValueError
        Parameters that contradict the method (e.g. a paper's method whose weighting is not
        ``params.fill.weighting``), or a ResolvedMethod given with parameters.
    """
    if isinstance(method, ResolvedMethod):
        if params is not None or method_params is not None:
            raise ValueError("a resolved method carries its parameters: expected params and "
                             "method_params None with it")
        return method
    if method is None:
        method = f"paper-{(params or DenseParams()).fill.weighting}"
    found = get_method(method)
    settings = check_params(found, method_params)
    return ResolvedMethod(found, settings, found.stage_params(params, settings) or DenseParams())


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


def fill_frame(frame: np.ndarray, sparse: np.ndarray, camera: Camera,
               params: DenseParams | None = None, truth: np.ndarray | None = None,
               T_world_frame: np.ndarray | None = None, info: dict | None = None,
               n1: int | None = None, method: str | ResolvedMethod | None = None,
               method_params: dict | None = None,
               motion: np.ndarray | None = None) -> DenseResult:
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
    method : str or ResolvedMethod, optional
        The filling method (:func:`resolve_method`; default the paper's with
        ``params.fill.weighting``, ``paper-idw``), run by its
        :meth:`fusion.methods.FillMethod.fill`; resolved already, it carries ``params`` and
        ``method_params`` (then None here).
    method_params : dict, optional
        The method's own settings (:func:`fusion.methods.check_params`; default none, its
        defaults); for the paper's, they replace those of ``params.fill``.
    motion : (H, W) uint8 ndarray, optional
        :func:`fusion.scoring.motion_regions` of the frame (a scene whose objects move): with
        ``truth``, ``info["errors_by_motion"]`` holds the errors of each kind of depth (``map``,
        ``filled``, ``all``) split by region (:func:`fusion.scoring.errors_by_motion`).

    Returns
    -------
    DenseResult
        ``info`` holds ``method``, ``method_origin`` and ``method_params`` (the settings
        given, coerced), and the counts: ``N1`` (map points),
        ``N1_in_frame`` (non-zero pixels of ``sparse``), ``N2`` (non-zero pixels of the dense
        map: ``N1_in_frame`` plus the filled pixels), ``Res`` (pixels of the frame), ``beta``
        (the filling score ``(N2 - N1_in_frame) / (Res + N1_in_frame / Res)``; for a method
        other than the paper's, the share of the frame that method filled) and ``beta_counts``
        (which counts it used), ``N2_over_N1_in_frame``; ``segmentation``, ``regions`` and
        ``regions_filled``, None for a method that does not segment the frame.

    Raises
    ------
    ValueError
        Bad input, an unknown method, or a method that returns no depth at some map points
        (``N2`` and ``beta`` would then not count the pixels it filled).
    """
    resolved = resolve_method(method, params, method_params)
    fill_method, method_params, params = resolved.method, resolved.settings, resolved.params
    start = time.perf_counter()
    if (camera.height, camera.width) != np.shape(frame)[:2]:
        raise ValueError(f"the calibration is for {camera.width}x{camera.height} but the frame "
                         f"is {np.shape(frame)[1]}x{np.shape(frame)[0]}")
    sparse = np.asarray(sparse, np.float32)
    filled = fill_method.fill(frame, sparse, camera, method_params, params)
    labels, regions, dense, confidence, timings = (filled.labels, filled.regions, filled.dense,
                                                   filled.confidence, filled.timings)
    in_frame, n2 = int(np.count_nonzero(sparse)), int(np.count_nonzero(dense))
    dropped = int(np.count_nonzero((sparse > 0) & (dense == 0)))
    if dropped:
        raise ValueError(f"filling method {fill_method.name} left {dropped} of the {in_frame} "
                         "map points in the frame without a depth: expected a depth at every "
                         "map point (N2 counts the map points and the filled pixels)")
    if n1 is None:
        n1 = in_frame
    elif isinstance(n1, bool) or int(n1) != n1 or n1 < in_frame:
        raise ValueError(f"n1 must be the map's point count, an integer >= the {in_frame} points "
                         f"in the frame, got {n1!r}")
    res = int(frame.shape[0] * frame.shape[1])
    timings["total_s"] = time.perf_counter() - start
    document = {
        "method": fill_method.name, "method_origin": fill_method.origin,
        "method_params": method_params,
        "N1": int(n1), "N1_in_frame": in_frame, "N2": n2, "Res": res,
        "beta": filling_score(in_frame, n2, res),
        "beta_counts": "(N2 - N1_in_frame) / (Res + N1_in_frame / Res)",
        "N2_over_N1_in_frame": n2 / in_frame if in_frame else None,
        "segmentation": None if regions is None else "region growing",
        "regions": None if regions is None else int(regions.n_regions),
        "regions_filled": None if regions is None else int(regions.selected.sum()),
        "timings": timings, **(info or {}),
    }
    if truth is not None:
        truth = np.asarray(truth, np.float32)
        if truth.shape != sparse.shape:
            raise ValueError(f"the exact depth is {truth.shape[1]}x{truth.shape[0]} but the frame "
                             f"is {sparse.shape[1]}x{sparse.shape[0]}")
        document["errors"] = dense_errors(dense, sparse, truth, params.band)
        if motion is not None:
            filled = np.where(sparse > 0, 0.0, dense).astype(np.float32)
            document["errors_by_motion"] = {
                name: errors_by_motion(depth, truth, motion)
                for name, depth in (("map", sparse), ("filled", filled), ("all", dense))}
    return DenseResult(np.asarray(frame), sparse, labels, regions, dense, camera,
                       T_world_frame, truth, document, fill_method.name, confidence)


def fill_map(map_folder: str | Path, params: DenseParams | None = None,
             method: str | ResolvedMethod | None = None, method_params: dict | None = None
             ) -> DenseResult:
    """Fill the map written by ``evfuse map`` with the standard frame nearest its reference view.

    Parameters
    ----------
    map_folder : str or Path
        Holds ``map.json`` and ``semidense_depth.exr``; ``map.json`` names the sequence.
    params : DenseParams, optional
    method : str or ResolvedMethod, optional
        The filling method (default the paper's, :func:`fill_frame`).
    method_params : dict, optional
        Its own settings (:func:`fill_frame`).

    Returns
    -------
    DenseResult
        With ``errors`` when the sequence is simulated (exact depth at the frame's time).
    """
    inputs = fill_inputs(map_folder)
    return fill_frame(inputs.frame, inputs.sparse, inputs.camera, params, inputs.truth,
                      inputs.T_world_frame, inputs.info, n1=inputs.n1, method=method,
                      method_params=method_params, motion=frame_motion_regions(inputs))


def fill_inputs(map_folder: str | Path) -> FillInputs:
    """Read a map folder's fill inputs (:class:`FillInputs`) without filling.

    Raises
    ------
    ValueError
        No such folder, no or a malformed ``map.json``, no ``semidense_depth.exr``, a sequence
        without frames, a frame outside the poses, or no map point landing in the frame (one
        line each).
    """
    map_folder = Path(map_folder)
    meta_path = map_folder / "map.json"
    if not map_folder.is_dir():
        raise ValueError(f"map folder {map_folder} does not exist or is not a folder (write a "
                         "map with evfuse map first)")
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
    frames = sequence.standard_frames()
    rig = sequence.frame_camera is not None
    if len(frames.image_times) == 0:
        raise ValueError(f"{frames.folder}: no standard frames (images.txt) to fill with")
    k = frames.nearest_frame(t_ref)
    t_frame = float(frames.image_times[k])
    frame = cv2.imread(str(frames.image_paths[k]), cv2.IMREAD_GRAYSCALE)
    if frame is None:
        raise ValueError(f"cannot read the frame {frames.image_paths[k]}")
    trajectory = read_trajectory(sequence.groundtruth_path)
    row_times = frames.row_times(t_frame)
    if not trajectory.t_start <= row_times[0] <= row_times[-1] <= trajectory.t_end:
        raise ValueError(f"the frame nearest the reference time ({t_frame} s, rows exposed "
                         f"{row_times[0]}-{row_times[-1]} s) is outside the poses "
                         f"[{trajectory.t_start}, {trajectory.t_end}] s")
    T_world_frame = trajectory.pose(t_frame) @ frames.T_event_frame
    camera = frames.camera
    if (camera.height, camera.width) != frame.shape:
        if rig:
            raise ValueError(f"{frames.image_paths[k]} is {frame.shape[1]}x{frame.shape[0]} but "
                             f"the frame camera is {camera.width}x{camera.height} "
                             "(sequence.json's frame_camera); expected the same size")
        camera = camera.with_resolution(frame.shape[1], frame.shape[0])
    extra: dict = {}
    if frames.shutter == "rolling":
        sparse, last_step = project_map_rolling(depth_ref, camera_ref, T_world_ref, frames,
                                                trajectory, t_frame)
        extra["rolling_shutter"] = {"iterations": ROLLING_ITERATIONS,
                                    "max_last_step_px": last_step}
    else:
        sparse = project_map(depth_ref, camera_ref, T_world_ref, camera, T_world_frame)
    if not sparse.any():
        raise ValueError(f"{map_folder}: no map point lands in the frame at {t_frame} s "
                         f"(N1 = {int(np.count_nonzero(depth_ref))} in the map)")
    truth = None
    j = frames.nearest_depth(t_frame)
    if j is not None:
        truth = read_depth(frames.depth_paths[j])
    info = {"map": str(map_folder.resolve()),
            # an oracle DSI range (the exact depth) makes every figure downstream an oracle's
            "oracle": bool(meta.get("oracle", False)),
            "depth_range_from": meta.get("depth_range_from", "given"),
            "sequence": str(Path(sequence.folder).resolve()),
            "frame": os.path.relpath(frames.image_paths[k], sequence.folder),
            "t_frame": t_frame, "t_ref": t_ref, "T_world_frame": T_world_frame.tolist(),
            # a rig: the map (event camera) was projected into the frame camera and scored
            # against the frame camera's own exact depth
            "rig": frame_record(frames) if rig else None,
            "truth": None if j is None else os.path.relpath(frames.depth_paths[j],
                                                            sequence.folder),
            **extra}
    return FillInputs(frame, sparse, camera, T_world_frame, truth, info,
                      int(np.count_nonzero(depth_ref)))


def write_fill(result: DenseResult, out: str | Path, params: DenseParams,
               overwrite: bool = False, inputs: Iterable[str | Path] = ()) -> Path:
    """Write ``dense_depth.exr``, ``segments.png``, ``filled_mask.png``, ``figure.png``,
    ``dense.ply`` and ``fill.json`` (plus ``error.png`` with a truth, and ``confidence.exr``,
    float32 channel ``Y`` in [0, 1], where the method returned a confidence) into ``out``,
    atomically.

    For a method that does not segment the frame, ``segments.png`` is all 0 and ``fill.json``'s
    ``params`` holds only ``band`` (the paper's stages did not run).

    ``inputs``: the files and folders the fill read besides ``result.info``'s ``map`` and
    ``sequence`` (e.g. the frame and sparse depth of a single frame); ``out`` must not be, hold or
    lie in any of them (:func:`sim.output.atomic_output_dir`).
    """
    segmented = result.regions is not None
    files = {"segments.png": ("region labels, 16-bit (0 = region too small)" if segmented else
                              f"all 0: {result.method} does not segment the frame"),
             "dense.ply": "property source: 0 event map point, 1 filled"}
    if result.confidence is not None:
        files["confidence.exr"] = (f"confidence of {result.method} in each pixel, float32 "
                                   "channel Y, 0 to 1")
    read = [*inputs, *(result.info[key] for key in ("map", "sequence")
                       if isinstance(result.info.get(key), str | Path))]
    with atomic_output_dir(out, overwrite=overwrite, inputs=read,
                           command="evfuse fill") as tmp:
        write_depth(tmp / "dense_depth.exr", result.dense)
        labels16 = np.clip(result.labels, 0, 65535).astype(np.uint16)
        if not cv2.imwrite(str(tmp / "segments.png"), labels16):
            raise OSError(f"cannot write {tmp / 'segments.png'}")
        filled = (result.dense > 0) & (result.sparse == 0)
        cv2.imwrite(str(tmp / "filled_mask.png"), filled.astype(np.uint8) * 255)
        cv2.imwrite(str(tmp / "figure.png"), fill_figure(result, params))
        points, colours, source = dense_cloud(result)
        pose = result.T_world_frame if result.T_world_frame is not None else np.eye(4)
        write_ply(tmp / "dense.ply", points, pose, colours, source, frame_name="T_world_frame")
        if result.truth is not None:
            cv2.imwrite(str(tmp / "error.png"), fill_error_figure(result))
        if result.confidence is not None:
            write_exr_channels(tmp / "confidence.exr",
                               {"Y": result.confidence.astype(np.float32)})
        document = {"params": params.as_dict() if segmented else {"band": params.band},
                    "camera": {"width": result.camera.width, "height": result.camera.height,
                               "fx": result.camera.fx, "fy": result.camera.fy,
                               "cx": result.camera.cx, "cy": result.camera.cy,
                               "distortion": list(result.camera.distortion)},
                    "files": files, **result.info}
        for key in ("map", "sequence"):             # relative to this folder, as in map.json
            if key in document:
                document[key] = os.path.relpath(Path(document[key]).resolve(), tmp.resolve())
        (tmp / "fill.json").write_text(to_json(document))
    return Path(out)
