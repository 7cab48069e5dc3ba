"""``evfuse map-global`` and ``evfuse run --global``: key views, maps, fills, fusion, TSDF, scores.

The one place where the global map's stages are wired together::

    sequence/ --key views--> views/NNN/map, views/NNN/fill  (each as evfuse map and evfuse fill)
              --fuse-->      global.ply (semi-dense views), global_filled.ply (filled views)
              --TSDF-->      mesh.ply (filled views)
              --score-->     global.json, global_error.ply, global.png

Key views (:mod:`fusion.globalmap.keyviews`) are chosen on the poses of ``groundtruth.txt`` with
a depth scale: first the DSI range's middle in inverse depth; once mapped, each key view's own
median map depth. The views whose selection changes are re-mapped until every view was
selected with a depth scale within ``GlobalParams.depth_scale_tolerance`` of its own median
depth (or the selection repeats), for at most ``GlobalParams.max_rounds`` rounds (recorded in
``global.json``'s ``rounds``). Each key view maps the events from the previous key view's time
to the next's with its reference at the standard frame nearest it
(:func:`fusion.pipeline.map_window`), fills with that frame (:func:`fusion.pipeline.fill_window`;
a two-camera rig fills in the frame camera), in parallel over ``workers`` processes (``spawn``;
numba's threads 1 in each).

A simulated sequence is scored against the exact surface of its key views
(:mod:`fusion.globalmap.score`); a real recording (no exact depth) reports what can be checked
without it: the agreement of overlapping views (:func:`fusion.globalmap.fuse.view_agreement`).
Everything is written into ``<out>.partial`` and renamed when complete
(:func:`sim.output.atomic_output_dir`); the source is never written into.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from fusion.figures import write_image
from fusion.fill.dense import DenseParams, resolve_method
from fusion.globalmap.fuse import FusionParams, fuse_views, view_agreement
from fusion.globalmap.keyviews import (
    KeyViewParams,
    inverse_depth_middle,
    key_view_windows,
    rotation_angle_deg,
    select_key_views,
)
from fusion.globalmap.score import (
    SURFACE_SUPERSAMPLE,
    TAUS_M,
    cloud_scores,
    draw_global_figure,
    exact_surface,
    exact_view,
    nearest_distances,
    write_error_cloud,
)
from fusion.globalmap.tsdf import GLOBAL_SEARCH_RADIUS, TSDFParams, tsdf_mesh
from fusion.globalmap.views import DepthView
from fusion.io import to_json, write_mesh_ply, write_ply
from fusion.map.dsi_range import resolve_dsi_range
from fusion.map.emvs import DepthMapParams
from fusion.map.mapping import time_window
from fusion.pipeline import (
    RunParams,
    _simulate_window,
    fill_window,
    is_sequence_folder,
    map_window,
    run_sources,
)
from sim.camera import Camera
from sim.eventio import iter_event_chunks
from sim.exr import read_depth
from sim.output import atomic_output_dir, check_output_dir
from sim.progress import progress as progress_stage
from sim.sequence import Sequence, load_sequence
from sim.trajectory import read_trajectory
from sim.validation import ParameterError, check_parameter, integer, positive

__all__ = ["GLOBAL_FILL_METHOD", "GlobalParams", "map_and_fill_view", "map_global", "run_global",
           "sequence_poses"]

END_VIEWS_MIN = 5
"""Key views from which the end views only confirm (:attr:`GlobalParams.end_views_confirm`):
at least three inner views then hold the map. With four, the two inner ones alone lose too much
of what the ends see: measured on boxes_6dof 3.5-5.5 s (4 views, 2 plane steps), the fused map's
F at 5 cm is 0.165 with the ends confirming only, 0.215 with their points."""
AGREEMENT_STEPS = 2.0
"""The fusion's agreement in inverse depth, in DSI plane steps
(:attr:`fusion.globalmap.fuse.FusionParams.inverse_depth_tolerance`, when not given): a
relative 2 % is under one plane step at boxes_6dof's depths (planes 4.5-9.9 cm apart there,
issue 40). Measured there (4 views): F at 5 cm 0.151 with none, 0.180 with 1 step, 0.215 with
2; on slider_close (0.23 m, 2 % is 2 steps) it changes nothing."""
GLOBAL_FILL_METHOD = "paper-colorization"
"""The key views' default filling method (:attr:`GlobalParams.method`): the paper's, completed
by colorization where it leaves pixels empty (:mod:`fusion.methods.completed`). The paper's
alone leaves 39-44 % of each slider_close key view empty, and the fused filled map's F at 1 %
of depth is then 0.774 on slider_close 0-1 s; completed, 0.906 (``benchmarks/bench_global.py
--goals``, ``--method paper-idw`` beside the default)."""
WORK_FOLDER = ".keyviews"
"""Where the key views of every round are mapped inside ``<out>.partial``; the final ones are
moved to ``views/NNN`` and the folder removed."""


@dataclass(frozen=True)
class GlobalParams:
    """Parameters of ``evfuse map-global`` (and ``evfuse run --global``).

    Attributes
    ----------
    keyviews : KeyViewParams
        When a new key view is taken.
    fusion : FusionParams
        Multi-view consistency and the merge voxel of the fused clouds (its
        ``inverse_depth_tolerance`` None: :data:`AGREEMENT_STEPS` of the DSI's plane steps).
        Default: a point is dropped only where more views contradict it than confirm it
        (``reject="outvoted"``, :func:`fusion.globalmap.fuse.kept_points`).
    tsdf : TSDFParams
        The TSDF volume of the filled views (its ``inverse_depth_step`` None: the DSI's plane
        spacing, so that the truncation follows the views' depth resolution). Default: a
        voxel without depth at its pixel takes the nearest within
        :data:`fusion.globalmap.tsdf.GLOBAL_SEARCH_RADIUS` pixels (the filled views are
        sparse).
    method : str or None
        Filling method (default :data:`GLOBAL_FILL_METHOD`, ``paper-colorization``; None: the
        paper's, ``paper-idw``); resolved once, before any work.
    method_params : dict
        The method's own settings.
    dense : DenseParams
        The paper's fill stages' parameters.
    min_depth, max_depth : float or None, metres
        The DSI range (default: the scene's declared range, else 0.2-5 m:
        :func:`fusion.map.dsi_range.resolve_dsi_range`, never the exact depth).
    planes : int
        DSI depth planes.
    depth : DepthMapParams
        The semi-dense map's extraction from the DSI (default: rpg_emvs's, with the depth
        refined between the planes, ``subplane``).
    t0, t1 : float or None, seconds
        The span to map (default: the data's).
    workers : int or None
        Key views mapped at once, one process each (default ``os.cpu_count()``; 1: in this
        process).
    max_rounds : int
        Most rounds of key-view selection (the first with the DSI's middle depth, each next
        with the mapped views' median depths).
    depth_scale_tolerance : float
        The selection stands once every key view's depth scale (the one it was selected with)
        lies within this share of its own map's median depth (default 0.1; a view without map
        points has no say); else the views are selected and mapped again.
    end_views_confirm : bool
        With at least :data:`END_VIEWS_MIN` key views, the first and the last (their event
        windows lie on one side of their reference: issue 40 measured 40-49 % of their points
        within 0.23 cm on slider_close, 89.7 % of the inner views') confirm the other views'
        points in the fused clouds but add none of their own (default True).
    """

    keyviews: KeyViewParams = field(default_factory=KeyViewParams)
    fusion: FusionParams = field(default_factory=lambda: FusionParams(reject="outvoted"))
    tsdf: TSDFParams = field(
        default_factory=lambda: TSDFParams(search_radius=GLOBAL_SEARCH_RADIUS))
    method: str | None = GLOBAL_FILL_METHOD
    method_params: dict = field(default_factory=dict)
    dense: DenseParams = field(default_factory=DenseParams)
    min_depth: float | None = None
    max_depth: float | None = None
    planes: int = 100
    depth: DepthMapParams = field(default_factory=lambda: DepthMapParams(subplane=True))
    t0: float | None = None
    t1: float | None = None
    workers: int | None = None
    max_rounds: int = 3
    depth_scale_tolerance: float = 0.1
    end_views_confirm: bool = True

    def __post_init__(self) -> None:
        check_parameter(positive, "depth_scale_tolerance", self.depth_scale_tolerance)
        for name in ("workers", "max_rounds"):
            if getattr(self, name) is not None or name == "max_rounds":
                object.__setattr__(self, name, check_parameter(
                    partial(integer, minimum=1), name, getattr(self, name)))

    @property
    def worker_count(self) -> int:
        """Processes that map key views: ``workers``, or the machine's cores."""
        return self.workers or os.cpu_count() or 1


@dataclass(frozen=True)
class _Job:
    """One key view to map and fill: its selected time, reference time and event window."""

    t_key: float
    t_ref: float
    t0: float | None
    t1: float | None

    @property
    def key(self) -> tuple:
        return (self.t_ref, self.t0, self.t1)


def map_global(source: str | Path, out: str | Path, params: GlobalParams | None = None,
               overwrite: bool = False, progress: bool = True) -> dict:
    """Map a sequence from key views, fuse them, build a TSDF mesh and score them.

    Parameters
    ----------
    source : str or Path
        A sequence folder (simulated, or a real ECD recording), or a folder ``evfuse run``
        wrote (its sequence is mapped; ``out`` may then lie in it).
    out : str or Path
        Folder to write: ``views/NNN/map``, ``views/NNN/fill``, ``global.ply``,
        ``global_filled.ply``, ``mesh.ply``, ``global.png``, ``global.json`` (and
        ``global_error.ply`` for a simulated sequence).
    params : GlobalParams, optional
    overwrite : bool
        Replace an existing ``out`` that evfuse wrote, once the new one is complete.
    progress : bool
        One line (or a bar on a terminal) per stage.

    Returns
    -------
    dict
        The content of ``global.json``: ``views`` (per key view ``t_ref``, ``semidense`` and
        ``filled`` scores), ``global`` (``semidense``, ``filled``, ``tsdf`` scores), each score
        None for a real recording, which has ``view_agreement`` instead; plus ``rounds``,
        ``timings``, ``memory_peak_mb`` and ``params``.

    Raises
    ------
    ValueError
        Not a sequence folder, an unknown filling method, an ``out`` that is, holds or lies in
        the source, or an existing ``out`` without ``overwrite`` (before any work).
    """
    params = params or GlobalParams()
    given, source = Path(source), _sequence_folder(source)
    inputs = [source]
    if source != given:         # a run folder: its own products are inputs too (never replaced)
        inputs += [child for child in sorted(given.iterdir()) if child != source
                   and not (child / "global.json").exists()]
    resolve_method(params.method, params.dense, params.method_params)        # up front
    check_output_dir(out, overwrite, inputs)
    with atomic_output_dir(out, overwrite=overwrite, inputs=inputs,
                           command="evfuse map-global") as tmp:
        return _map_global(Path(source), tmp, params, progress, {})


def _sequence_folder(source: str | Path) -> Path:
    """The sequence folder of ``source``: itself, or the one an ``evfuse run`` folder's
    ``report.json`` names (so that ``evfuse map-global runs/boxes --out runs/boxes/global``
    maps the sequence that run simulated)."""
    source = Path(source)
    if is_sequence_folder(source):
        return source
    sequence = [path for path in run_sources(source)[1:] if is_sequence_folder(path)]
    if sequence:
        return sequence[0]
    raise ValueError(f"{source}: not a sequence folder (calib.txt, images.txt, events and "
                     "groundtruth.txt) nor a folder written by evfuse run; simulate a scene "
                     "first, or use evfuse run SCENE --global")


def run_global(scene: str | Path, out: str | Path, t0: float | None = None,
               t1: float | None = None, params: GlobalParams | None = None,
               spp: int | None = None, seed: int | None = None, overwrite: bool = False,
               progress: bool = True, profile: bool = False) -> dict:
    """Simulate a scene's window into ``out/sequence`` (as ``evfuse run`` does), then map it
    globally into ``out`` (:func:`map_global`).

    Parameters
    ----------
    scene : str or Path
        A built-in scene name or a scene ``.toml`` file.
    out : str or Path
    t0, t1 : float or None, seconds
        The window simulated and mapped (default: the whole scene).
    params : GlobalParams, optional
        Its ``t0``/``t1`` are replaced by the window.
    spp, seed : int or None
        Samples per pixel and seed of the simulation (default: the scene's).
    overwrite, progress : bool
    profile : bool
        The simulation also writes ``sequence/profile.json`` (:mod:`sim.profile`).

    Returns
    -------
    dict
        ``global.json``'s content, with ``timings["simulate_s"]``.

    Raises
    ------
    ValueError
        ``scene`` is a sequence folder (:func:`map_global` maps those).
    """
    from scenes import resolve_scene
    from sim.scene import load_scene
    from sim.simulate import scene_files

    params = params or GlobalParams()
    if is_sequence_folder(scene):
        raise ParameterError(f"{ParameterError.literal(scene)} is a sequence folder, not a "
                             "scene: {map_global} maps a sequence folder ({run_global} "
                             "simulates a scene first)", map_global="map_global",
                             run_global="run_global")
    resolve_method(params.method, params.dense, params.method_params)        # up front
    loaded = load_scene(resolve_scene(scene), seed=seed)
    t0 = 0.0 if t0 is None else float(t0)
    t1 = float(loaded.duration) if t1 is None else float(t1)
    inputs = scene_files(loaded)
    check_output_dir(out, overwrite, inputs)
    timings: dict = {}
    with atomic_output_dir(out, overwrite=overwrite, inputs=inputs,
                           command="evfuse run --global") as tmp:
        folder, t0, t1 = _simulate_window(loaded, tmp / "sequence",
                                          RunParams(t0=t0, t1=t1, spp=spp, seed=seed),
                                          progress, timings, profile=profile)
        return _map_global(folder, tmp, replace(params, t0=t0, t1=t1), progress, timings)


def _map_global(source: Path, tmp: Path, params: GlobalParams, progress: bool,
                timings: dict) -> dict:
    """The body of :func:`map_global`, writing into the open output folder ``tmp``."""
    clock = time.perf_counter()
    sequence = load_sequence(source)
    jobs, results, rounds, converged = _key_views(sequence, tmp, params, progress, timings)
    if len(jobs) < 2:
        raise _too_few_key_views(sequence, params, len(jobs), rounds)
    views_root = tmp / "views"
    views_root.mkdir()
    entries = []
    for index, job in enumerate(jobs):
        folder = views_root / f"{index:03d}"
        results[job.key]["folder"].rename(folder)
        entries.append({"folder": f"views/{folder.name}", **_view_entry(job, results[job.key])})
    shutil.rmtree(tmp / WORK_FOLDER)
    semidense = [_semidense_view(views_root / f"{k:03d}" / "map") for k in range(len(jobs))]
    filled = [_filled_view(views_root / f"{k:03d}" / "fill") for k in range(len(jobs))]
    filled_views = [view for view in filled if view is not None]

    dsi = resolve_dsi_range(sequence, params.min_depth, params.max_depth)
    step = (1.0 / dsi.min_depth - 1.0 / dsi.max_depth) / (params.planes - 1)
    fusion = (params.fusion if params.fusion.inverse_depth_tolerance is not None
              else replace(params.fusion, inverse_depth_tolerance=AGREEMENT_STEPS * step))
    tick = time.perf_counter()
    stage = progress_stage(desc="fuse", unit="view", noun="views", enabled=progress)
    fused = fuse_views(semidense, fusion, contributors=_contributors(semidense, params))
    if not len(fused.points):
        points = sum(int(np.count_nonzero(view.depth > 0)) for view in semidense)
        raise ParameterError(
            f"the fused map of {ParameterError.literal(str(sequence.folder))} is empty: no "
            f"point of its {len(jobs)} key views' maps ({points:,} points) is confirmed by "
            f"{{min_views}} {params.fusion.min_views} other views"
            + (" or contradicted by no more views than confirm it"
               if params.fusion.reject == "outvoted" else "") + "; key views "
            f"{{baseline}} {params.keyviews.baseline:g} of the depth apart may see too little "
            "in common: lower {baseline}, or lower {min_views}",
            baseline="baseline", min_views="min_views")
    fused_filled = (fuse_views(filled_views, fusion,
                               contributors=_contributors(filled, params, filled_views))
                    if filled_views else None)
    stage.update(len(semidense) + len(filled_views))
    stage.close()
    timings["fusion_s"] = time.perf_counter() - tick
    write_ply(tmp / "global.ply", fused.points, np.eye(4), frame_name="T_world")
    if fused_filled is not None:
        write_ply(tmp / "global_filled.ply", fused_filled.points, np.eye(4),
                  frame_name="T_world")

    tick = time.perf_counter()
    stage = progress_stage(desc="TSDF", unit="view", noun="views", enabled=progress)
    tsdf = (params.tsdf if params.tsdf.inverse_depth_step is not None
            else replace(params.tsdf, inverse_depth_step=step))
    mesh = tsdf_mesh(filled_views, tsdf) if filled_views else None
    stage.update(len(filled_views))
    stage.close()
    timings["tsdf_s"] = time.perf_counter() - tick
    if mesh is not None:
        write_mesh_ply(tmp / "mesh.ply", mesh.vertices, mesh.faces)

    tick = time.perf_counter()
    stage = progress_stage(desc="score", unit="view", noun="views", enabled=progress)
    # the exact surface sampled SURFACE_SUPERSAMPLE^2 times per pixel (score's measured bias)
    exact = [exact_view(sequence, entry["t_ref"], SURFACE_SUPERSAMPLE) for entry in entries]
    simulated = all(view is not None for view in exact)
    document: dict = {"views": entries, "global": None}
    trajectory = _trajectory_positions(sequence, jobs)
    centres = np.array([view.centre for view in semidense]).reshape(-1, 3)
    if simulated:
        errors = _score(document, semidense, filled, fused, fused_filled, mesh, exact, step)
        write_error_cloud(tmp / "global_error.ply", fused.points, errors, max(TAUS_M))
        figure = draw_global_figure(fused.points, errors, trajectory, centres, max(TAUS_M))
    else:
        for entry in entries:
            entry["semidense"] = entry["filled"] = None
            entry["semidense_global"] = entry["filled_global"] = None
        document["global"] = {"semidense": None, "filled": None, "tsdf": None}
        document["view_agreement"] = view_agreement(semidense, fusion)
        figure = draw_global_figure(fused.points, None, trajectory, centres, max(TAUS_M))
    stage.update(len(entries))
    stage.close()
    timings["scoring_s"] = time.perf_counter() - tick
    write_image(tmp / "global.png", figure)

    timings["total_s"] = time.perf_counter() - clock + timings.get("simulate_s", 0.0)
    document.update({
        "sequence": os.path.relpath(sequence.folder.resolve(), tmp.resolve()),
        "simulated": simulated,
        "key_views": len(jobs), "rounds": rounds, "rounds_converged": converged,
        "fused": {"semidense_points": len(fused.points), "voxel_size_m": fused.voxel_size,
                  "support_median": (float(np.median(fused.support)) if len(fused.points)
                                     else None),
                  "filled_points": None if fused_filled is None else len(fused_filled.points)},
        "mesh": None if mesh is None else {"vertices": len(mesh.vertices),
                                           "faces": len(mesh.faces)},
        "timings": timings,
        "memory_peak_mb": _memory_peak_mb(),
        "params": json.loads(to_json(asdict(params))),
        "files": {"views": "views/NNN/map, views/NNN/fill", "global": "global.ply",
                  "global_filled": "global_filled.ply" if fused_filled is not None else None,
                  "mesh": "mesh.ply" if mesh is not None else None,
                  "error_cloud": "global_error.ply" if simulated else None,
                  "figure": "global.png"},
    })
    (tmp / "global.json").write_text(to_json(document))
    return document


def _contributors(views: list[DepthView | None], params: GlobalParams,
                  kept: list[DepthView] | None = None) -> list[bool]:
    """Per view of ``kept`` (default ``views``, the key views in time order, None where a view
    has none): whether its points enter the fused cloud (not an end view, or
    :attr:`GlobalParams.end_views_confirm` off, or fewer than :data:`END_VIEWS_MIN` key
    views)."""
    ends = params.end_views_confirm and len(views) >= END_VIEWS_MIN
    flags = [not (ends and k in (0, len(views) - 1)) for k in range(len(views))]
    return [flag for flag, view in zip(flags, views, strict=True) if view is not None] \
        if kept is not None else flags


def _too_few_key_views(sequence: Sequence, params: GlobalParams, count: int,
                       rounds: list[dict]) -> ParameterError:
    """The refusal of a window with fewer than two key views: how far the camera moved in it,
    against the criteria that would have taken a second view."""
    window = time_window(sequence, params.t0, params.t1)
    times, poses = sequence_poses(sequence, window.t0, window.t1)
    travel = float(np.max(np.linalg.norm(poses[:, :3, 3] - poses[0, :3, 3], axis=1)))
    turn = float(np.max(rotation_angle_deg(poses[0, :3, :3], poses[:, :3, :3])))
    scales = rounds[-1]["depth_scale_m"] if rounds else []
    scale = f"{scales[0]:.2f} m" if scales else "the depth"
    keys = params.keyviews
    return ParameterError(
        f"{ParameterError.literal(str(sequence.folder))} over [{window.t0:g}, {window.t1:g}] s "
        f"gives {count} key view: the camera moved {100 * travel:.1f} cm and turned "
        f"{turn:.1f} deg, short of {{baseline}} {keys.baseline:g} x {scale} = "
        f"{100 * keys.baseline * (scales[0] if scales else 1.0):.1f} cm"
        + ("" if scales else " of depth") + f" and {{angle_deg}} {keys.angle_deg:g} deg; a "
        "global map fuses at least 2 key views: lower {baseline} or {angle_deg}, or give a "
        "longer window ({t0}, {t1})",
        baseline="baseline", angle_deg="angle_deg", t0="t0", t1="t1")


def _key_views(sequence: Sequence, tmp: Path, params: GlobalParams, progress: bool,
               timings: dict) -> tuple[list[_Job], dict, list[dict], bool]:
    """Select, map and fill the key views, re-selecting with the maps' median depths.

    Returns
    -------
    jobs : list of _Job, the final key views in time order
    results : dict, each mapped job's result by its key (every round's)
    rounds : list of dict, per round the key views' times and how many were mapped
    converged : bool, whether the last selection was confirmed by the maps' depths
    """
    tick = time.perf_counter()
    window = time_window(sequence, params.t0, params.t1)     # past the data: refused
    times, poses = sequence_poses(sequence, window.t0, window.t1)
    dsi = resolve_dsi_range(sequence, params.min_depth, params.max_depth)
    initial = inverse_depth_middle(dsi.min_depth, dsi.max_depth)
    events = (_event_times(sequence, window.t0, window.t1)
              if params.keyviews.max_events is not None else None)
    frames = sequence.standard_frames()
    medians: dict[float, float] = {}
    results: dict[tuple, dict] = {}
    rounds: list[dict] = []
    previous: list[float] | None = None
    converged = False
    jobs: list[_Job] = []
    timings["key_views_s"] = time.perf_counter() - tick
    timings["map_fill_s"] = 0.0

    def scale(t: float) -> float:
        """A key view's depth scale: its map's median depth; before it is mapped (or where its
        map is empty) the nearest mapped key view's; before any, the DSI range's middle."""
        if not medians:
            return initial
        return medians[min(medians, key=lambda key: abs(key - t))]

    with _Workers(params.worker_count) as workers:
        for number in range(1, params.max_rounds + 1):
            keys = select_key_views(times, poses, params.keyviews, scale, event_times=events)
            scales = [scale(t) for t in keys]
            if keys == previous:
                converged = True
                break
            jobs = _plan(keys, frames, params.t0, params.t1)
            todo = [job for job in jobs if job.key not in results]
            tick = time.perf_counter()
            for job, result in zip(todo, _map_and_fill(workers, sequence.folder, tmp, todo, params,
                                                       len(results), number, progress),
                                   strict=True):
                results[job.key] = result
            timings["map_fill_s"] += time.perf_counter() - tick
            for job in jobs:
                median = results[job.key]["depth_median_m"]
                if median is not None:
                    medians[job.t_key] = float(median)
            rounds.append({"round": number, "key_times": keys,
                           "t_ref": [job.t_ref for job in jobs], "mapped": len(todo),
                           "depth_scale_m": scales})
            previous = keys
            used = dict(zip(keys, scales, strict=True))
            if all(abs(used[job.t_key] - medians[job.t_key])
                   <= params.depth_scale_tolerance * medians[job.t_key]
                   for job in jobs if job.t_key in medians):
                converged = True              # every view was selected with its own depth
                break
    return jobs, results, rounds, converged


def sequence_poses(sequence: Sequence, t0: float | None = None, t1: float | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The poses key views are chosen on: ``groundtruth.txt``'s samples (blind: never
    ``groundtruth_exact.txt``) in ``[t0, t1)``, with the pose at ``t0`` first.

    Parameters
    ----------
    sequence : Sequence
    t0, t1 : float or None, seconds
        The span (default: the data's, :func:`fusion.map.mapping.time_window`).

    Returns
    -------
    times : (N,) float64 ndarray, seconds
    poses : (N, 4, 4) float64 ndarray, ``T_world_camera``
    """
    if t0 is None or t1 is None:
        window = time_window(sequence, t0, t1, clip=True)
        t0, t1 = window.t0, window.t1
    trajectory = read_trajectory(sequence.groundtruth_path)
    inside = (trajectory.times >= t0) & (trajectory.times < t1)
    times = np.unique(np.r_[t0, trajectory.times[inside]])
    return times, trajectory.pose(times)


def _plan(keys: list[float], frames, t0: float | None, t1: float | None) -> list[_Job]:
    """One job per key view: its reference at the standard frame nearest it (map_window's rule;
    the key time where there are no frames), two key views on one frame made one."""
    windows = key_view_windows(keys, t0, t1)
    jobs: list[_Job] = []
    for t_key, (w0, w1) in zip(keys, windows, strict=True):
        t_ref = (float(frames.image_times[frames.nearest_frame(t_key)])
                 if len(frames.image_times) else t_key)
        if jobs and jobs[-1].t_ref == t_ref:
            continue
        jobs.append(_Job(t_key, t_ref, w0, w1))
    # a dropped key view's neighbours take its window: each maps from its neighbours' times
    kept = [job.t_key for job in jobs]
    return [replace(job, t0=w0, t1=w1)
            for job, (w0, w1) in zip(jobs, key_view_windows(kept, t0, t1), strict=True)]


class _Workers:
    """The processes that map key views: a ``spawn`` pool of ``count`` processes (numba's
    threads 1 in each), started on the first batch of more than one view and kept for every
    round; with ``count`` 1, this process."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.pool: ProcessPoolExecutor | None = None

    def __enter__(self) -> _Workers:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)

    def map(self, tasks: list[dict], stage) -> list[dict]:
        """:func:`map_and_fill_view` of each task, in order, ``stage`` updated per view."""
        results: list[dict] = [{}] * len(tasks)
        if self.count <= 1 or len(tasks) <= 1 and self.pool is None:
            for k, task in enumerate(tasks):
                results[k] = map_and_fill_view(task)
                stage.update(1)
            return results
        if self.pool is None:
            self.pool = ProcessPoolExecutor(max_workers=self.count,
                                            mp_context=get_context("spawn"),
                                            initializer=_single_threaded)
        futures = {self.pool.submit(map_and_fill_view, task): k for k, task in enumerate(tasks)}
        for future in as_completed(futures):
            results[futures[future]] = future.result()
            stage.update(1)
        return results


def _map_and_fill(workers: _Workers, sequence_folder: Path, tmp: Path, jobs: list[_Job],
                  params: GlobalParams, first: int, number: int, progress: bool) -> list[dict]:
    """Map and fill ``jobs`` into ``tmp/.keyviews/NNN`` (numbered from ``first``) on
    ``workers``; results in the order of ``jobs``."""
    tasks = [{"sequence": str(sequence_folder),
              "folder": str(tmp / WORK_FOLDER / f"{first + k:03d}"),
              "t_ref": job.t_ref, "t0": job.t0, "t1": job.t1,
              "min_depth": params.min_depth, "max_depth": params.max_depth,
              "planes": params.planes, "depth": params.depth, "dense": params.dense,
              "method": params.method, "method_params": params.method_params}
             for k, job in enumerate(jobs)]
    stage = progress_stage(desc=f"key views, round {number}", unit="view", noun="views",
                           total=len(tasks), enabled=progress)
    results = workers.map(tasks, stage)
    stage.close()
    return results


def _single_threaded() -> None:
    """A worker's initialiser: one numba thread (the processes share the cores)."""
    import numba

    numba.set_num_threads(1)


def map_and_fill_view(task: dict) -> dict:
    """Map and fill one key view (a worker's job): ``folder/map`` as ``evfuse map`` writes it,
    ``folder/fill`` as ``evfuse fill`` does.

    Parameters
    ----------
    task : dict
        ``sequence``, ``folder``, ``t_ref``, ``t0``, ``t1`` and the map's and the fill's
        parameters (see :func:`_map_and_fill`).

    Returns
    -------
    dict
        ``folder`` (Path), ``t_ref``, ``t_frame``, ``N1``, ``depth_median_m``, ``window_s``,
        ``events``, ``fill_error`` (None, or why the view could not be filled) and
        ``timings`` (``map_s``, ``fill_s``).
    """
    folder = Path(task["folder"])
    folder.mkdir(parents=True)
    tick = time.perf_counter()
    mapped, _ = map_window(task["sequence"], folder / "map", task["t0"], task["t1"],
                           ref_time=task["t_ref"], min_depth=task["min_depth"],
                           max_depth=task["max_depth"], planes=task["planes"],
                           depth=task["depth"], clip_window=True, progress=False)
    map_s = time.perf_counter() - tick
    tick = time.perf_counter()
    fill_error = t_frame = None
    try:
        filled = fill_window(folder / "map", folder / "fill", params=task["dense"],
                             method=task["method"], method_params=task["method_params"])
        t_frame = filled.info["t_frame"]
    except ValueError as exc:             # e.g. no map point lands in the frame
        fill_error = str(exc)
    return {"folder": folder, "t_ref": mapped.t_ref, "t_frame": t_frame, "N1": mapped.n1,
            "depth_median_m": mapped.info.get("depth_median_m"),
            "window_s": mapped.info["window_s"], "events": mapped.info["events_used"],
            "fill_error": fill_error,
            "timings": {"map_s": map_s, "fill_s": time.perf_counter() - tick}}


def _view_entry(job: _Job, result: dict) -> dict:
    """A key view's line in ``global.json`` (its scores are added by :func:`_score`)."""
    return {"t_ref": result["t_ref"], "t_key": job.t_key, "t_frame": result["t_frame"],
            "window_s": result["window_s"], "events": result["events"], "N1": result["N1"],
            "depth_median_m": result["depth_median_m"], "fill_error": result["fill_error"],
            "semidense": None, "filled": None, "semidense_global": None, "filled_global": None,
            "timings": result["timings"]}


def _camera(record: dict) -> Camera:
    """The camera a ``map.json`` or ``fill.json`` records."""
    return Camera(int(record["width"]), int(record["height"]), float(record["fx"]),
                  float(record["fy"]), float(record["cx"]), float(record["cy"]),
                  tuple(record.get("distortion", (0.0,) * 5)))


def _semidense_view(map_folder: Path) -> DepthView:
    """A key view's semi-dense map (``evfuse map``'s folder) as a DepthView: the map's
    undistorted pixel grid at its reference pose (``groundtruth.txt``'s)."""
    meta = json.loads((map_folder / "map.json").read_text())
    return DepthView(read_depth(map_folder / "semidense_depth.exr"), _camera(meta["camera"]),
                     np.array(meta["T_world_ref"], np.float64), float(meta["t_ref"]),
                     f"semidense {map_folder.parent.name}", events=_events_window(meta))


def _events_window(meta: dict) -> tuple[float, float] | None:
    """The event window ``[t0, t1]`` (s) a ``map.json`` records (None where it records none:
    the view is then not known to share events with any other)."""
    if "window_s" not in meta:
        return None
    t0, t1 = meta["window_s"]
    return float(t0), float(t1)


def _filled_view(fill_folder: Path) -> DepthView | None:
    """A key view's filled map (``evfuse fill``'s folder) as a DepthView in the frame's camera
    (a rig's frame camera) at the frame's pose; None where the view was not filled."""
    if not (fill_folder / "fill.json").is_file():
        return None
    meta = json.loads((fill_folder / "fill.json").read_text())
    events = json.loads((fill_folder.parent / "map" / "map.json").read_text())
    return DepthView(read_depth(fill_folder / "dense_depth.exr"), _camera(meta["camera"]),
                     np.array(meta["T_world_frame"], np.float64), float(meta["t_frame"]),
                     f"filled {fill_folder.parent.name}", events=_events_window(events))


def _score(document: dict, semidense: list[DepthView], filled: list[DepthView | None],
           fused, fused_filled, mesh, exact: list[DepthView], inverse_depth_step: float
           ) -> np.ndarray:
    """Score every key view and the global maps against the exact surface into ``document``;
    return the fused semi-dense points' distances to it (metres).

    Each view is scored twice: against its own exact view (``semidense``, ``filled``) and, as
    the global maps are, against the union of the key views' exact views (``semidense_global``,
    ``filled_global``): only the latter compare with the global maps. The tolerances that follow
    the depth (1 % of it, the DSI's plane step ``inverse_depth_step`` at it) take each point's
    depth in the nearest key view (:func:`fusion.globalmap.score.point_depths`)."""
    reference = exact_surface(exact)
    depths = np.concatenate([view.depth[view.valid] for view in exact])
    scene_depth = float(np.median(depths)) if len(depths) else 1.0
    poses = np.stack([view.T_world_cam for view in semidense])

    def score(points: np.ndarray, surface: np.ndarray) -> dict:
        return cloud_scores(points, surface, scene_depth, poses=poses,
                            inverse_depth_step=inverse_depth_step)

    for entry, own, dense, truth in zip(document["views"], semidense, filled, exact,
                                        strict=True):
        surface = exact_surface([truth])
        entry["semidense"] = score(own.points_world(), surface)
        entry["semidense_global"] = score(own.points_world(), reference)
        if dense is None:
            entry["filled"] = entry["filled_global"] = None
            continue
        # A rig's filled view is the frame camera's, which sees another surface than the
        # event camera's exact view: it is scored against the global exact surface instead.
        same = _same_view(own, dense)
        entry["filled"] = score(dense.points_world(), surface if same else reference)
        entry["filled_against"] = "view" if same else "global"
        entry["filled_global"] = score(dense.points_world(), reference)
    document["global"] = {
        "semidense": score(fused.points, reference),
        "filled": None if fused_filled is None else score(fused_filled.points, reference),
        "tsdf": (None if mesh is None
                 else score(mesh.sample(fused_filled.voxel_size / 2), reference)),
    }
    document["scene_depth_m"] = scene_depth
    document["inverse_depth_step_per_m"] = inverse_depth_step
    document["gain_over_best_view"] = {
        name: _gain(document["global"][name], [entry[f"{name}_global"]
                                               for entry in document["views"]])
        for name in ("semidense", "filled")}
    return nearest_distances(fused.points, reference)


def _same_view(a: DepthView, b: DepthView) -> bool:
    """Whether two views are one camera at one pose (a key view's map and its fill, but for a
    two-camera rig, whose fill is in the frame camera)."""
    return (a.camera.resolution == b.camera.resolution
            and np.allclose(a.camera.K, b.camera.K)
            and np.allclose(a.T_world_cam, b.T_world_cam, atol=1e-9))


def _gain(fused: dict | None, views: list[dict | None]) -> dict | None:
    """The fused map against the best single key view, both scored against the same (global)
    exact surface: the view with the highest F-score at the largest tau, its scores, and the
    fused map's recall over that view's at each tau and its accuracy and completeness changes
    (cm; negative: better). None without a fused map or a view."""
    scored = [(k, scores) for k, scores in enumerate(views) if scores is not None]
    if fused is None or not scored:
        return None
    widest = f"fscore_{round(100 * max(TAUS_M))}cm"
    best, scores = max(scored, key=lambda item: item[1][widest])
    gain: dict = {"view": best, "view_scores": scores}
    for tau in TAUS_M:
        key = f"recall_{round(100 * tau)}cm"
        gain[f"recall_ratio_{round(100 * tau)}cm"] = (fused[key] / scores[key] if scores[key]
                                                      else None)
    for key in ("accuracy_cm", "completeness_cm"):
        both = fused[key] is not None and scores[key] is not None
        gain[f"{key.removesuffix('_cm')}_change_cm"] = fused[key] - scores[key] if both else None
    return gain


def _trajectory_positions(sequence: Sequence, jobs: list[_Job]) -> np.ndarray:
    """(N, 3) camera centres of ``groundtruth.txt`` over the key views' span, for the figure."""
    trajectory = read_trajectory(sequence.groundtruth_path)
    lo = min(job.t0 if job.t0 is not None else trajectory.t_start for job in jobs)
    hi = max(job.t1 if job.t1 is not None else trajectory.t_end for job in jobs)
    inside = (trajectory.times >= lo) & (trajectory.times <= hi)
    return trajectory.poses[inside][:, :3, 3]


def _event_times(sequence: Sequence, t0: float, t1: float) -> np.ndarray:
    """(M,) float64 seconds: the times of the events in ``[t0, t1]`` (for the event budget)."""
    path = sequence.events_h5 or sequence.events_txt
    chunks = [chunk["t"] * 1e-9 for chunk in iter_event_chunks(
        path, 10**6, int(round(t0 * 1e9)), int(round(t1 * 1e9)) + 1)]
    return np.concatenate(chunks) if chunks else np.zeros(0)


def _memory_peak_mb() -> dict:
    """Peak resident memory, MiB: this process's and the largest worker's."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    workers = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return {"main": own, "largest_worker": workers}
