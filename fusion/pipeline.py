"""``evfuse run``: simulate (or read) a sequence, map it, fill the map, score it, draw it.

The one place where the stages are wired together::

    scene  --simulate-->  sequence/  --map-->  map/  --fill-->  fill/  -->  overview.png,
                                                                            report.json

A real recording (an Event-Camera Dataset folder) or an existing simulated sequence folder is read
where it is; a scene (a built-in name or a ``.toml`` file) is simulated into ``<out>/sequence``
over the time window only. Everything is written into ``<out>.partial`` and renamed to ``<out>``
when complete; an interrupted run leaves ``<out>.partial`` for ``resume`` (its simulation goes on
from its checkpoint). ``<out>`` never is, holds or lies in the source.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from fusion.figures import (
    add_header,
    depth_colours,
    depth_scale,
    error_panel,
    event_legend,
    grid_scale,
    highlight_pixels,
    label_colours,
    panel_grid,
    point_cloud_view,
    point_radius,
    write_image,
)
from fusion.fill.dense import (
    DenseParams,
    DenseResult,
    fill_map,
    resolve_method,
    write_fill,
)
from fusion.io import read_ply, to_json
from fusion.map.dsi_range import oracle_header, resolve_dsi_range
from fusion.map.emvs import DepthMapParams, DSIParams
from fusion.map.mapping import MapParams, MapResult, map_sequence, time_window, write_map
from fusion.methods import ResolvedMethod
from sim.eventio import read_window
from sim.exr import read_depth
from sim.output import (
    PARTIAL_SUFFIX,
    atomic_output_dir,
    check_output_dir,
    resumable_partial,
    resume_differences,
)
from sim.progress import progress as progress_stage
from sim.sequence import load_sequence
from sim.statistics import event_frame
from sim.validation import ParameterError, finite

__all__ = ["ExtraMap", "RunParams", "draw_overview", "fill_sources", "fill_window",
           "is_sequence_folder", "map_window", "run_pipeline", "run_sources"]

DEFAULT_WINDOW = 1.0
"""Seconds of a scene simulated and mapped when no window is given."""


@dataclass(frozen=True)
class RunParams:
    """Parameters of ``evfuse run``.

    Attributes
    ----------
    t0, t1 : float or None, seconds
        Time window. For a scene, default ``[0, min(1, duration)]``, and ``t1`` 1 s after a
        given ``t0``: a ``t0`` that leaves the scene less than 1 s is refused (with
        ``clip_window``, mapped to the scene's end and recorded as clipped); for a folder, all
        events.
    min_depth, max_depth : float or None, metres
        Depth range of the DSI. Default: the working range the scene file declares, else
        0.2 to 5 m (:func:`fusion.map.dsi_range.resolve_dsi_range`); never the exact depth.
    oracle_depth_range : bool
        Opt in to the exact depth of the reference view, widened by 20 %, as the DSI's range
        (``--depth-range oracle``); every output then says so.
    planes : int
        DSI planes (100).
    depth : DepthMapParams
        Semi-dense extraction (kernel 5, c 5, median 5).
    dense : DenseParams
        Segmentation, selection and filling (the paper's defaults).
    method : str or None
        The filling method, a name or ``module:function`` (:mod:`fusion.methods`); None (the
        default): the paper's with ``dense.fill.weighting``, ``paper-idw``; resolved once,
        before any work (:func:`fusion.fill.dense.resolve_method`).
    method_params : dict
        The method's own settings (:func:`fusion.methods.check_params`; default none: its
        defaults), recorded in ``report.json``.
    spp : int or None
        Samples per pixel of the simulated frames (default: the scene's).
    seed : int or None
        Seed of the simulation (default: the scene's).
    clip_window : bool
        Map the part of ``[t0, t1]`` that a folder's events and poses (or a scene) cover
        instead of refusing a window that reaches past them (``MapParams.clip_window``;
        default False).
    """

    t0: float | None = None
    t1: float | None = None
    min_depth: float | None = None
    max_depth: float | None = None
    oracle_depth_range: bool = False
    planes: int = 100
    depth: DepthMapParams = field(default_factory=DepthMapParams)
    dense: DenseParams = field(default_factory=DenseParams)
    method: str | None = None
    method_params: dict = field(default_factory=dict)
    spp: int | None = None
    seed: int | None = None
    clip_window: bool = False

    def __post_init__(self) -> None:
        # Ranges and units are checked where the window and the DSI range are resolved.
        for name in ("t0", "t1", "min_depth", "max_depth"):
            if getattr(self, name) is not None:
                finite(name, getattr(self, name))


def is_sequence_folder(source: str | Path) -> bool:
    """True for a folder with the layout of CONVENTIONS.md (``calib.txt`` and ``images.txt``)."""
    path = Path(source)
    return path.is_dir() and (path / "calib.txt").is_file()


def map_window(sequence_folder: str | Path, out: str | Path, t0: float | None = None,
               t1: float | None = None, *, ref_time: float | None = None,
               min_depth: float | None = None, max_depth: float | None = None,
               oracle_depth_range: bool = False, planes: int = 100,
               depth: DepthMapParams | None = None, clip_window: bool = False,
               overwrite: bool = False, progress: bool = True) -> tuple[MapResult, MapParams]:
    """The map stage as ``evfuse map`` and ``evfuse run`` both run it: reference view, DSI
    range, EMVS, files.

    The reference view defaults to the standard frame nearest the middle of the window (the
    frame the map is filled with); the DSI's range comes from
    :func:`fusion.map.dsi_range.resolve_dsi_range` (the user's bounds, the scene's declared range,
    or 0.2-5 m; the exact depth only with ``oracle_depth_range``).

    Parameters
    ----------
    sequence_folder : str or Path
    out : str or Path
        Map folder to write (:func:`fusion.map.mapping.write_map`).
    t0, t1 : float or None, seconds
        Event window (default: the data's span).
    ref_time : float or None, seconds
        Reference view (default: the frame nearest the middle of the window).
    min_depth, max_depth : float or None, metres
    oracle_depth_range : bool
    planes : int
    depth : DepthMapParams, optional
    clip_window : bool
        Map the part of ``[t0, t1]`` the events and poses cover instead of refusing a window
        past them (recorded in ``map.json``).
    overwrite : bool
    progress : bool

    Returns
    -------
    MapResult, MapParams
    """
    sequence = load_sequence(sequence_folder)
    if sequence.groundtruth_path is None:
        raise ValueError(f"{sequence_folder}: no groundtruth.txt (the camera poses are "
                         "needed to map)")
    if ref_time is None:
        middle = time_window(sequence, t0, t1, clip=clip_window).t_ref
        frames = sequence.standard_frames()      # a rig's: the frame camera's frame times
        ref_time = (float(frames.image_times[frames.nearest_frame(middle)])
                    if len(frames.image_times) else middle)
    dsi_range = resolve_dsi_range(sequence, min_depth, max_depth, oracle_depth_range, ref_time)
    params = MapParams(DSIParams(dsi_range.min_depth, dsi_range.max_depth, planes=planes),
                       depth or DepthMapParams(), t0=t0, t1=t1, ref_time=ref_time,
                       clip_window=clip_window, dsi_range=dsi_range)
    check_output_dir(out, overwrite, inputs=[sequence_folder])     # before the long work
    mapped = map_sequence(sequence_folder, params, progress=progress)
    write_map(mapped, out, params, overwrite=overwrite)
    return mapped, params


def fill_window(map_folder: str | Path, out: str | Path, params: DenseParams | None = None,
                overwrite: bool = False, method: str | ResolvedMethod | None = None,
                method_params: dict | None = None) -> DenseResult:
    """The fill stage as ``evfuse fill`` and ``evfuse run`` both run it: fill, score, files.

    ``method`` is the filling method (default: the paper's with ``params.fill.weighting``),
    ``method_params`` its own settings, resolved here once
    (:func:`fusion.fill.dense.resolve_method`; a ResolvedMethod carries both and ``params``).
    ``out`` must not be, hold or lie in the map folder or its sequence folder (refused before
    any work)."""
    resolved = resolve_method(method, params, method_params)
    check_output_dir(out, overwrite, inputs=fill_sources(map_folder))
    filled = fill_map(map_folder, method=resolved)
    write_fill(filled, out, resolved.params, overwrite=overwrite)
    return filled


def fill_sources(map_folder: str | Path) -> list[Path]:
    """What filling ``map_folder`` reads: the folder and the sequence folder its ``map.json``
    names (when it names one; a malformed ``map.json`` is refused later, by the fill)."""
    map_folder = Path(map_folder)
    sources = [map_folder]
    try:
        sources.append(map_folder / json.loads((map_folder / "map.json").read_text())["sequence"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return sources


def run_sources(run_folder: str | Path) -> list[Path]:
    """What re-drawing a run reads: its folder and the sequence folder its ``report.json``
    names (when it names one; a missing report is refused later, by the drawing)."""
    run_folder = Path(run_folder)
    sources = [run_folder]
    try:
        report = json.loads((run_folder / "report.json").read_text())
        sources.append(run_folder / report["sequence"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return sources


RESUME_FILE = ".run.json"
"""The identity of an unfinished ``evfuse run`` in ``<out>.partial`` (source, the scene file's
SHA-256, every parameter, evfuse's version), compared by a resumed run."""


def _run_identity(source: str | Path, scene, params: RunParams) -> dict:
    """What a resumed run must share with the interrupted one."""
    from sim.output import evfuse_version

    return json.loads(to_json({
        "source": str(source),
        "scene_sha256": None if scene is None else hashlib.sha256(
            scene.text.encode()).hexdigest(),
        "params": asdict(params), "version": evfuse_version()}))


def _check_run_resumable(out: Path, overwrite: bool, inputs: list, identity: dict) -> None:
    """Raise ValueError unless ``<out>.partial`` holds an interrupted run like this one."""
    partial = resumable_partial(out, overwrite, inputs, needs=RESUME_FILE)
    saved = partial / RESUME_FILE
    differences = resume_differences(json.loads(saved.read_text()), identity,
                                     saved_as="in the interrupted run")
    if differences:
        raise ValueError(f"{partial} was left by a run with other inputs: "
                         f"{'; '.join(differences)}; expected the same source, scene file, "
                         "parameters and software to resume (or run without resuming to start "
                         "again)")


class ExtraMap(Protocol):
    """A second map of the run's reference view, made from its map and filled like it
    (``evfuse run --views N``: :class:`fusion.globalmap.neighbours.FusedViews`). The pipeline
    never imports what makes it: the caller passes it to :func:`run_pipeline`.

    Attributes
    ----------
    name : str
        Its folder in the run (``<name>/map/``, ``<name>/fill/``) and its block in
        ``report.json``.
    """

    name: str

    def span(self, t0: float, t1: float, duration: float,
             slack: float = 0.0) -> tuple[float, float]:
        """The part ``(start, end)`` of a scene's ``[0, duration]`` to simulate for a map of
        ``[t0, t1]`` (containing it); ``slack``, seconds: the rig's largest clock offset."""

    def __call__(self, map_folder: Path, out: Path, progress: bool) -> dict:
        """Write the map folder ``out/map`` from the run's map ``map_folder``; return its
        description (recorded in ``report.json``)."""


def run_pipeline(source: str | Path, out: str | Path, params: RunParams | None = None,
                 overwrite: bool = False, progress: bool = True, resume: bool = False,
                 extra_map: ExtraMap | None = None, profile: bool = False) -> dict:
    """Run simulate -> map -> fill -> score on a scene or a sequence folder.

    Parameters
    ----------
    source : str or Path
        A built-in scene name, a scene ``.toml`` file, or a sequence folder (simulated or ECD).
    out : str or Path
        Run folder to create: ``sequence/`` (scenes only), ``map/``, ``fill/``,
        ``overview.png``, ``report.json``.
    params : RunParams, optional
    overwrite : bool
        Replace an existing ``out`` (a folder evfuse wrote) once the new one is complete.
    progress : bool
        Progress bars.
    resume : bool
        Continue the run an interruption left in ``<out>.partial`` (Ctrl-C, SIGTERM, a crash):
        its simulation resumes from its checkpoint (as :func:`sim.simulate.simulate` with
        ``resume``) or is re-used when it was complete; the map and the fill are made again.
        Refused when the source, the scene file or a parameter differ.
    extra_map : ExtraMap, optional
        A second map of the reference view (``evfuse run --views N``), written into
        ``<out>/<name>/map/``, filled into ``<out>/<name>/fill/`` with the same method and
        scored like the first; ``report.json`` gets its block under ``name``. A scene is then
        simulated over ``extra_map.span`` (the run's window is mapped as without it).
    profile : bool
        The simulation also writes ``sequence/profile.json`` (:mod:`sim.profile`); refused
        for a sequence folder (nothing is simulated).

    Returns
    -------
    dict
        The content of ``report.json``.

    Raises
    ------
    ValueError
        Bad input; an ``out`` that is, holds or lies in the source (a sequence folder, the scene
        file or a file it names), an existing ``out`` without ``overwrite`` or not written by
        evfuse (:func:`sim.output.check_output_dir`), all before any work.

    Notes
    -----
    Interrupted while it simulates a scene, the run leaves ``<out>.partial`` for ``resume``;
    a failure on bad input removes it.
    """
    from scenes import resolve_scene
    from sim.scene import load_scene
    from sim.simulate import scene_files

    params = params or RunParams()
    method = resolve_method(params.method, params.dense, params.method_params)  # up front
    out = Path(out)
    scene = (None if is_sequence_folder(source)
             else load_scene(resolve_scene(source), seed=params.seed))
    if profile and scene is None:
        raise ParameterError(f"{{profile}}: {ParameterError.literal(str(source))} is a sequence "
                             "folder, nothing is simulated to profile", profile="profile=True")
    inputs = [Path(source)] if scene is None else scene_files(scene)
    identity = _run_identity(source, scene, params)
    if extra_map is not None:
        identity["extra_map"] = repr(extra_map)
    if resume:
        _check_run_resumable(out, overwrite, inputs, identity)
    else:
        check_output_dir(out, overwrite, inputs)
    try:
        return _run(source, scene, out, params, method, overwrite, progress, resume, inputs,
                    identity, extra_map, profile)
    except ValueError as exc:
        # Bad input (found after the run folder was started): nothing worth keeping. The
        # message must not send the user to the folder deleted here: it names the run folder.
        partial = out.with_name(out.name + PARTIAL_SUFFIX)
        shutil.rmtree(partial, ignore_errors=True)
        if isinstance(exc, ParameterError):      # the sentence the command line words
            exc.template = exc.template.replace(ParameterError.literal(partial),
                                                ParameterError.literal(out))
        if len(exc.args) == 1 and isinstance(exc.args[0], str):
            exc.args = (exc.args[0].replace(str(partial), str(out)),)
        raise


def _run(source, scene, out: Path, params: RunParams, method: ResolvedMethod, overwrite: bool,
         progress: bool, resume: bool, inputs: list, identity: dict,
         extra_map: ExtraMap | None = None, profile: bool = False) -> dict:
    clock = time.perf_counter()
    timings: dict[str, float] = {}
    with atomic_output_dir(out, overwrite=overwrite, resume=resume, inputs=inputs,
                           command="evfuse run", keep_failed=scene is not None) as tmp:
        (tmp / RESUME_FILE).write_text(json.dumps(identity))
        if scene is None:
            sequence_folder = Path(source)
            simulated_here = False
            t0, t1 = params.t0, params.t1
        else:
            sequence_folder, t0, t1 = _simulate_window(scene, tmp / "sequence", params,
                                                       progress, timings, resume, extra_map,
                                                       profile)
            simulated_here = True
        tick = time.perf_counter()
        # A window simulated here is all the data there is: a rig's clock offsets
        # (sim.capture_errors)
        # leave its events and poses a few ms short of it at one end, so it is clipped to them
        # (recorded as clipped) instead of refused.
        mapped, map_params = map_window(
            sequence_folder, tmp / "map", t0, t1, min_depth=params.min_depth,
            max_depth=params.max_depth, oracle_depth_range=params.oracle_depth_range,
            planes=params.planes, depth=params.depth,
            clip_window=params.clip_window or simulated_here, overwrite=resume,
            progress=progress)
        timings["map_s"] = time.perf_counter() - tick
        tick = time.perf_counter()
        unit, noun = method.method.progress_units()
        stage = progress_stage(desc="fill", unit=unit, noun=noun, enabled=progress)
        filled = fill_window(tmp / "map", tmp / "fill", method=method, overwrite=resume)
        stage.update(filled.info["regions_filled"] if filled.regions is not None
                     else filled.n2 - filled.n1_in_frame)
        stage.close()
        timings["fill_s"] = time.perf_counter() - tick
        info = filled.info
        errors = info.get("errors")
        summary = _errors_summary(mapped.info.get("errors"), errors)
        report = {
            "source": str(source),
            "method": info["method"], "method_origin": info["method_origin"],
            "method_params": info["method_params"],
            "sequence": os.path.relpath(Path(sequence_folder).resolve(), tmp.resolve()),
            "simulated": simulated_here,
            "window_s": mapped.info["window_s"],
            "window_requested_s": mapped.info["window_requested_s"],
            "window_clipped": mapped.info["window_clipped"],
            "t_ref": mapped.t_ref,
            "t_frame": info["t_frame"],
            **map_params.dsi_range.as_dict(),
            "events": mapped.info["events_used"],
            "events_dropped": (mapped.info["events_dropped_before_poses"]
                               + mapped.info["events_dropped_after_poses"]),
            "N1": info["N1"], "N1_in_frame": info["N1_in_frame"], "N2": info["N2"],
            "Res": info["Res"], "beta": info["beta"], "beta_counts": info["beta_counts"],
            "ground_truth": errors is not None,
            # a two-camera rig: filled in the frame camera, scored against its exact depth
            "rig": info.get("rig"), "truth": info.get("truth"),
            "errors_summary": summary,
            "mae_cm": None if summary is None else {
                k: None if v is None else v["mae_cm"] for k, v in summary.items()},
            "map_errors_at_reference": mapped.info.get("errors"),
            # a scene whose objects move: the errors split by fusion.scoring.motion_regions
            "errors_by_motion": None if "errors_by_motion" not in mapped.info else {
                "map": mapped.info["errors_by_motion"],
                **{name: (info.get("errors_by_motion") or {}).get(key)
                   for name, key in (("map_in_frame", "map"), ("filled", "filled"),
                                     ("all", "all"))}},
            "files": {"overview": "overview.png", "map": "map/", "fill": "fill/",
                      "figure": "fill/figure.png", "point_cloud": "fill/dense.ply",
                      **({} if filled.confidence is None
                         else {"confidence": "fill/confidence.exr"})},
        }
        if extra_map is not None:
            tick = time.perf_counter()
            report[extra_map.name] = _extra_map(extra_map, tmp, method, progress, resume)
            timings[f"{extra_map.name}_s"] = time.perf_counter() - tick
        write_image(tmp / "overview.png", draw_overview(tmp, report))
        timings["total_s"] = time.perf_counter() - clock
        report["timings"] = timings
        (tmp / "report.json").write_text(to_json(report))
        (tmp / RESUME_FILE).unlink()
    return report


def _extra_map(extra_map: ExtraMap, run: Path, method: ResolvedMethod, progress: bool,
               resume: bool = False) -> dict:
    """Make, fill and score a run's extra map; its ``report.json`` block: its description,
    N1, N1 in frame, N2, Res, beta and the errors as the run's own (``errors_summary``,
    ``mae_cm``, ``map_errors_at_reference``), its files. A resumed run makes it again (as
    its map and fill): what an interruption left of it is removed first."""
    folder = run / extra_map.name
    if resume:
        for stale in (folder, folder.with_name(folder.name + PARTIAL_SUFFIX)):
            shutil.rmtree(stale, ignore_errors=True)
    description = extra_map(run / "map", folder, progress)
    filled = fill_window(folder / "map", folder / "fill", method=method)
    mapped = json.loads((folder / "map" / "map.json").read_text())
    info = filled.info
    summary = _errors_summary(mapped.get("errors"), info.get("errors"))
    return {**description,
            "N1": info["N1"], "N1_in_frame": info["N1_in_frame"], "N2": info["N2"],
            "Res": info["Res"], "beta": info["beta"], "beta_counts": info["beta_counts"],
            "errors_summary": summary,
            "mae_cm": None if summary is None else {
                k: None if v is None else v["mae_cm"] for k, v in summary.items()},
            "map_errors_at_reference": mapped.get("errors"),
            "files": {"map": f"{extra_map.name}/map/", "fill": f"{extra_map.name}/fill/"}}


SUMMARY_KEYS = ("mae_cm", "median_cm", "n", "completeness", "points", "no_surface",
                "precision_5pct", "precision_1pct")
"""The figures of each :func:`fusion.scoring.depth_errors` block kept in ``errors_summary``."""


def _errors_summary(map_errors: dict | None, fill_errors: dict | None) -> dict | None:
    """Each MAE of a run with the coverage it was measured on, for ``report.json``.

    Parameters
    ----------
    map_errors : dict or None
        ``map.json``'s ``errors``: the N1 map points in the reference view's own grid.
    fill_errors : dict or None
        ``fill.json``'s ``errors`` (:func:`fusion.scoring.dense_errors`), in the frame's pixels.

    Returns
    -------
    dict or None
        ``{"map" | "map_in_frame" | "filled" | "all": {key: value}}`` with the keys of
        :data:`SUMMARY_KEYS`: ``map`` is the event map at the reference view (None without its
        exact depth), ``map_in_frame`` its N1_in_frame points in the frame, ``filled`` the filled
        pixels, ``all`` the dense map. None without any exact depth (a real recording).
    """
    if map_errors is None and fill_errors is None:
        return None

    def pick(errors: dict | None) -> dict | None:
        return None if errors is None else {k: errors[k] for k in SUMMARY_KEYS}

    fill = fill_errors or {}
    return {"map": pick(map_errors),
            **{name: pick(fill.get(key, {}).get("overall"))
               for name, key in (("map_in_frame", "map"), ("filled", "filled"), ("all", "all"))}}


def _simulate_window(scene, folder: Path, params: RunParams, progress: bool, timings: dict,
                     resume: bool = False, extra_map: ExtraMap | None = None,
                     profile: bool = False):
    """Simulate the run's window into ``folder`` (:func:`sim.simulate.window.simulate_window`:
    with ``resume``, a complete ``folder`` is re-used and the checkpoint an interruption left in
    its ``.partial`` continued; ``profile``: with its ``profile.json``); return the folder and the
    window ``(t0, t1)`` the map is asked (with ``clip_window``, ``t1`` may lie past the
    simulated end, the scene's)."""
    from sim.simulate.window import is_simulated, simulate_window

    t0 = 0.0 if params.t0 is None else float(params.t0)
    t1 = min(t0 + DEFAULT_WINDOW, scene.duration) if params.t1 is None else float(params.t1)
    end = t1                        # simulated to here; t1 is what the map is asked
    if params.t0 is not None and params.t1 is None and t0 + DEFAULT_WINDOW > scene.duration:
        # The default window is DEFAULT_WINDOW long: one that the scene cannot hold is
        # refused (or, with clip_window, mapped to the scene's end and recorded as clipped).
        if not params.clip_window:
            latest = max(scene.duration - DEFAULT_WINDOW, 0.0)
            clip = (f", or {{clip_window}} to map [{t0:g}, {scene.duration:g}] s"
                    if t0 < scene.duration else "")
            raise ParameterError(
                f"{{t0}} {t0:g}: the default {DEFAULT_WINDOW:g} s window, "
                f"[{t0:g}, {t0 + DEFAULT_WINDOW:g}] s, reaches past the end of scene "
                f"{ParameterError.literal(scene.name)} ([0, {scene.duration:g}] s); give {{t0}} "
                f"at most {latest:g} or {{t1}} at most {scene.duration:g}{clip}",
                t0="t0", t1="t1", clip_window="clip_window=True")
        t1 = t0 + DEFAULT_WINDOW
    if not end > t0:
        raise ValueError(f"empty time window [{t0}, {end}] s")
    if resume and is_simulated(folder):
        return folder, t0, t1                 # simulated before the interruption
    start = t0
    if extra_map is not None:                 # its maps may need more of the scene
        start, end = extra_map.span(t0, min(t1, scene.duration), scene.duration,
                                    slack=max(map(abs, scene.rig.offsets.values())))
    tick = time.perf_counter()
    simulate_window(scene, folder, start, end - start, resume=resume, progress=progress,
                    spp=params.spp, profile=profile)
    timings["simulate_s"] = time.perf_counter() - tick
    return folder, t0, t1


def draw_overview(run_folder: str | Path, report: dict | None = None) -> np.ndarray:
    """The overview of a run, from its saved files: frame, events, semi-dense map, segmentation
    (for a filling method without one, the frame with the filled pixels in green), dense map,
    with ground truth the exact depth and the error of the dense map, and the point cloud;
    depth and error panels carry their colour scale, the events panel its ON/OFF swatches, the
    point cloud its viewpoint and axes. A run whose DSI range came from the exact depth
    (``report["oracle"]``) says so in a header line above the panels.

    The depth panels share one scale: the exact depth's range where there is one, else the maps'
    1st-99th percentile; map depths beyond it are drawn in colours of their own, which the
    legend shows at the ends of its bar (:func:`fusion.figures.depth_scale`). Large frames are
    reduced to a grid at most 1920 px wide (:func:`fusion.figures.grid_scale`), their sparse
    points drawn larger so that they stay visible.

    Parameters
    ----------
    run_folder : str or Path
        A folder written by :func:`run_pipeline` (or its ``.partial`` while it is written).
    report : dict, optional
        Its ``report.json`` (default: read from the folder).

    Returns
    -------
    (H', W', 3) uint8 ndarray, BGR
    """
    panels, titles, legends, header = _overview_panels(run_folder, report)
    grid = panel_grid(panels, titles, columns=_overview_columns(len(panels)), legends=legends)
    return add_header(grid, header)


OVERVIEW_INPUTS = ("fill/fill.json", "fill/segments.png", "fill/filled_mask.png",
                   "fill/dense_depth.exr", "fill/dense.ply", "map/semidense_depth.exr")
"""The files of a run folder, besides ``report.json``, that its overview is drawn from."""


def _overview_columns(panels: int) -> int:
    """Columns of the overview's grid: 4 for the 8 panels of a run with an exact depth, else 3."""
    return 4 if panels > 6 else 3


def _overview_panels(run_folder: str | Path, report: dict | None = None
                    ) -> tuple[list[np.ndarray], list[str], list, list[str]]:
    """The panels of :func:`draw_overview`, before they are laid out.

    Returns
    -------
    panels : list of (H, W, 3) uint8 ndarrays, BGR
    titles : list of str
    legends : list of Legend, Caption or None, one per panel
    header : list of str, lines above the grid (the oracle warning, or none)
    """
    run_folder = Path(run_folder)
    if report is None:
        path = run_folder / "report.json"
        if not path.is_file():
            raise ValueError(f"{run_folder}: no report.json (not a folder written by evfuse run)")
        report = json.loads(path.read_text())
    for name in OVERVIEW_INPUTS:
        if not (run_folder / name).is_file():
            raise ValueError(f"{run_folder / name} does not exist; evfuse show needs the files "
                             f"evfuse run writes ({', '.join(OVERVIEW_INPUTS)})")
    fill_meta = json.loads((run_folder / "fill" / "fill.json").read_text())
    sequence = load_sequence(run_folder / report["sequence"])
    frame = cv2.imread(str(sequence.folder / fill_meta["frame"]), cv2.IMREAD_GRAYSCALE)
    if frame is None:
        raise ValueError(f"cannot read the frame {sequence.folder / fill_meta['frame']}")
    semidense = read_depth(run_folder / "map" / "semidense_depth.exr")
    dense = read_depth(run_folder / "fill" / "dense_depth.exr")
    labels = cv2.imread(str(run_folder / "fill" / "segments.png"), cv2.IMREAD_UNCHANGED)
    if labels is None:
        raise ValueError(f"cannot read {run_folder / 'fill' / 'segments.png'}")
    filled_mask = cv2.imread(str(run_folder / "fill" / "filled_mask.png"), cv2.IMREAD_GRAYSCALE)
    if filled_mask is None:
        raise ValueError(f"cannot read {run_folder / 'fill' / 'filled_mask.png'}")
    if fill_meta.get("segmentation", "region growing") is None:     # the method did not segment
        segments = highlight_pixels(frame, filled_mask > 0)
        segments_title = f"no segmentation (method {fill_meta['method']}; filled green)"
    else:
        selected = np.zeros(int(labels.max()) + 1, bool)
        selected[np.unique(labels[(filled_mask > 0) & (labels > 0)])] = True
        segments = label_colours(labels, highlight=selected)
        segments_title = "segmentation (filled in colour)"
    t = float(report["t_frame"])
    width, height = frame.shape[1], frame.shape[0]
    events_path = sequence.events_h5 or sequence.events_txt
    events = read_window(events_path, int(round((t - 0.01) * 1e9)), int(round((t + 0.01) * 1e9)))
    events_image = cv2.cvtColor(event_frame(events, sequence.camera.width,
                                            sequence.camera.height), cv2.COLOR_RGB2BGR)
    truth = None
    frames = sequence.standard_frames()          # the frame's camera: a rig's frame camera
    k = frames.nearest_depth(t)
    if k is not None:
        truth = read_depth(frames.depth_paths[k])
    scale = depth_scale(semidense, dense, truth=truth)
    lo_hi = (scale.lo, scale.hi) if scale else (None, None)
    legend = scale.legend() if scale else None
    # a large frame is reduced in the grid: sparse points are drawn that much larger
    shown = width * grid_scale(width, _overview_columns(8 if truth is not None else 6))
    radius, frame_radius = point_radius(semidense.shape[1], shown), point_radius(width, shown)
    cloud, _ = read_ply(run_folder / "fill" / "dense.ply")
    points = np.stack([cloud["x"], cloud["y"], cloud["z"]], 1)
    colours = np.stack([cloud["blue"], cloud["green"], cloud["red"]], 1)
    n1 = report["N1"]
    in_frame = report.get("N1_in_frame")
    map_title = (f"semi-dense map (N1 = {n1})" if in_frame is None
                 else f"semi-dense map (N1 = {n1}, {in_frame} in the frame)")
    panels = [cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR), events_image,
              depth_colours(semidense, *lo_hi, radius=radius), segments,
              depth_colours(dense, *lo_hi, radius=frame_radius)]
    titles = [f"frame at {t:.3f} s", f"events +-10 ms ({len(events)})", map_title,
              segments_title,
              f"dense map (N2 = {report['N2']}, beta {report['beta']:.3f})"]
    legends = [None, event_legend(), legend, None, legend]
    if truth is not None:
        error, error_key = error_panel(dense, truth, radius=frame_radius)
        panels += [depth_colours(truth, *lo_hi), error]
        titles += ["exact depth", "|error| of the dense map"]
        legends += [legend, error_key]
    view, caption = point_cloud_view(points, colours, (width, height),
                                     splat=max(2, 2 * frame_radius + 1))
    panels.append(view)
    titles.append("point cloud: map points red, filled green")
    legends.append(caption)
    header = oracle_header(bool(report.get("oracle")))
    return panels, titles, legends, header
