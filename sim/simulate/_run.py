"""The simulator's run: :func:`simulate` (a scene in, a sequence folder out), its steps, and what
it returns (:class:`SimulationResult`)."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sim._summary import summary_repr
from sim.camera import write_calib
from sim.capture_errors import (
    EXACT_CALIB,
    EXACT_POSES,
    RIG_STREAM,
    RigParams,
    calibration_error,
    noisy_poses,
    pose_noise,
    rig_generator,
)
from sim.event_depth import DEPTH_TXT
from sim.events import EventParams
from sim.flow import write_motion_ground_truth
from sim.frames import frame_times
from sim.imu import write_motion_truth
from sim.output import atomic_output_dir, check_output_dir
from sim.profile import PROFILE_JSON, STAGES, profile_record, recording, stage
from sim.render import Renderer
from sim.sampling import SamplingParams
from sim.scene import Scene
from sim.sequence import write_index, write_sequence_json
from sim.simulate._checkpoint import (
    CHECKPOINT_FOLDER,
    _check_resumable,
    _Checkpoint,
    _identity,
    _versions,
)
from sim.simulate._events import _choose_sampler, _simulate_events
from sim.simulate._frames import _frames_record, _simulate_frames, frame_cost_record
from sim.simulate.memory import device_memory
from sim.trajectory import sample_times, write_trajectory
from sim.two_camera import simulate_frame_camera
from sim.validation import ParameterError


@dataclass(frozen=True)
class SimulationResult:
    """What :func:`simulate` wrote.

    Attributes
    ----------
    out : Path
        The sequence folder.
    n_frames : int
        Number of standard-camera frames (and depth maps).
    n_renders : int
        Exposure times rendered, all frames together (``frame_cost.exposure_times`` of
        ``sequence.json``: a whole-frame render each, or one pass of the frame shader).
    n_events : int or None
        Number of events written (None when events were not simulated).
    event_renders : int
        Whole-frame renders made for the event camera (refined intervals included).
    event_pixel_samples : int
        Single-pixel renders of the per-pixel sampler (0 with the frame sampler).
    sampler : str or None
        ``pixel`` or ``frame`` (None when events were not simulated).
    variant : str
        Mitsuba variant used.
    timings : dict
        Seconds spent per stage (by this call: a resumed run counts only what it did).
    profile : dict or None
        ``profile.json`` (:func:`sim.profile.profile_record`) when asked for (``profile``).
    """

    out: Path
    n_frames: int
    n_renders: int
    variant: str
    timings: dict
    n_events: int | None = None
    event_renders: int = 0
    event_pixel_samples: int = 0
    sampler: str | None = None
    profile: dict | None = None

    __repr__ = summary_repr


def scene_files(scene: Scene) -> list[Path]:
    """The files a scene reads: its scene file (for a built-in scene, the packaged one) and
    every file it names (``path`` keys: a trajectory, a texture image, a mesh), relative to its
    folder as the parser takes them. An output must not be, hold or lie in any of them."""
    import tomllib

    if scene.source is None:
        return []
    files = [Path(scene.source)]
    try:
        raw = tomllib.loads(scene.text)
    except (tomllib.TOMLDecodeError, TypeError):
        return files
    stack: list = [raw]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            for key, value in item.items():
                if key == "path" and isinstance(value, str):
                    files.append(scene.base_dir / value)
                else:
                    stack.append(value)
        elif isinstance(item, list):
            stack.extend(item)
    return files


def _check_memory(scene: Scene, spp: int | None, with_events: bool) -> None:
    """Refuse, before any work, a simulation whose renders cannot fit this machine's memory
    (:func:`sim.simulate.memory.check_simulation_memory`): the largest camera at the most
    samples per pixel of any pass."""
    from sim.simulate.memory import check_simulation_memory

    render = scene.render
    samples = max(spp if spp is not None else render.spp, render.flat_spp,
                  *((render.event_spp, render.edge_spp) if with_events else ()))
    cameras = [scene.camera] + ([scene.frame_camera.camera] if scene.frame_camera else [])
    largest = max(cameras, key=lambda c: c.width * c.height)
    check_simulation_memory(largest.width, largest.height, samples)


def simulate(scene: Scene, out: str | Path, *, duration: float | None = None,
             start: float = 0.0, spp: int | None = None, variant: str | None = None,
             overwrite: bool = False,
             progress: bool = True, events: EventParams | None = None,
             sampling: SamplingParams | None = None, with_events: bool = True,
             event_formats: tuple[str, ...] = ("h5", "txt"),
             resume: bool = False, sampler: str | None = None,
             rig: RigParams | None = None, motion_truth: bool = True,
             profile: bool = False) -> SimulationResult:
    """Render a scene into a sequence folder.

    Parameters
    ----------
    scene : Scene
        The validated scene (its seed drives every random draw).
    out : str or Path
        Sequence folder to create.
    duration : float, optional
        Seconds to simulate from ``start``, default the scene's duration minus ``start``.
    start : float, seconds
        Time of the trajectory at which the simulation begins (default 0): frames, poses and
        events cover ``[start, start + duration]``; the event camera starts there without
        history, as a real one switched on at that time.
    spp : int, optional
        Samples per pixel (a perfect square), default the scene's ``render.spp``.
    variant : str, optional
        Mitsuba variant (see :func:`sim.variant.use_variant`).
    overwrite : bool
        Replace an existing non-empty ``out`` (only once the new one is complete).
    progress : bool
        Show a progress bar.
    events : EventParams, optional
        The event camera (default: the ``ideal`` preset, C = 0.2, seeded with the scene seed).
    sampling : SamplingParams, optional
        Adaptive sampling of the renders that drive the event camera.
    with_events : bool
        Simulate the event camera (default True).
    event_formats : tuple of {"h5", "txt", "depth-txt"}
        Files to write the events to (``events.h5``, ``events.txt``, ``events_depth.txt``:
        the events with their depth, :mod:`sim.event_depth`); ``events.h5`` holds the
        per-event depth too (``events/depth``, ``events/depth_flag``). With the motion truth,
        each event's labels (cause, object id; :mod:`sim.event_labels`) are in ``events.h5``
        (``events/cause``, ``events/object_id``) and, with a text format, ``events_labels.txt``.
    resume : bool
        Continue the interrupted run that left ``<out>.partial``, from its last checkpoint:
        frames already written are kept, the event stage goes on from its last saved sample.
        The run must have had the same scene text, seed, times, parameters, variant and
        software versions; the files come out the same as an uninterrupted run's
        (``sequence.json`` apart from its timings). Without ``resume``, a stale
        ``<out>.partial`` is discarded.
    sampler : {"pixel", "frame"}, optional
        How the event camera is sampled: ``pixel`` renders each pixel at its own adaptive
        times (:mod:`sim.pixel_sampling`; static scenes on a JIT variant only), ``frame``
        renders whole frames at one adaptive rate (:mod:`sim.sampling`). Default: ``pixel``
        where it applies, else ``frame``; the choice is said once on stderr and recorded in
        ``sequence.json``.
    rig : RigParams, optional
        Pose noise, clock offsets and calibration error of the written files (default the
        scene's ``[rig]``, perfect unless it says otherwise; :mod:`sim.capture_errors`). The truth
        is written beside them: ``groundtruth_exact.txt``, ``calib_exact.txt``; ``depth/`` is
        always exact, indexed by the frames' written times.
    motion_truth : bool
        Write the motion ground truth (default True): camera velocity and IMU
        (:mod:`sim.imu`), optical flow, motion fields and object masks (:mod:`sim.flow`) and
        each event's depth and labels (:mod:`sim.event_depth`, :mod:`sim.event_labels`).
        False keeps the frames, depth maps,
        poses and events only (smaller, and a little faster).
    profile : bool
        Also write ``profile.json``: each stage's wall seconds beside the Dr.Jit kernels it ran
        (device seconds, launches, compilation, copies) and the event camera's host and device
        seconds per simulated second (:mod:`sim.profile`). Each stage then waits for its
        kernels at its end, which can add a few percent of wall time. On ``scalar_rgb`` (no
        Dr.Jit kernels) the wall times alone, with a note.

    Returns
    -------
    SimulationResult

    Raises
    ------
    ValueError
        A duration that is not positive, a window ``[start, start + duration]`` outside the
        scene (its duration, and its trajectory's valid range), a rig offset that would write
        a time before 0 s, or an existing ``out``
        without ``overwrite``. With ``resume``: a complete ``out`` (without ``overwrite``), no
        ``<out>.partial`` or no checkpoint in it, or a checkpoint of a run with other inputs
        (the message names them). The refusals that name a parameter (``start``, ``sampler``,
        ``resume``) are :class:`sim.validation.ParameterError`, which a front end words in its
        own terms.

    Notes
    -----
    If interrupted (KeyboardInterrupt or any exception), ``<out>.partial`` is left with its
    last checkpoint in ``.checkpoint/``.
    """
    start, duration = _window(scene, start, duration)
    end = start + duration
    if rig is not None:
        scene = replace(scene, rig=rig)
    _check_offsets(scene, start)
    times = start + frame_times(duration, scene.frames)
    if len(times) == 0:
        raise ValueError(f"duration {duration} s is too short for one frame at "
                         f"{scene.frames.rate} Hz with a {scene.frames.longest_exposure} s "
                         "exposure")
    events = events or EventParams(seed=scene.seed)
    sampling = sampling or SamplingParams()
    event_formats = tuple(event_formats)
    _check_events(scene, with_events, event_formats, motion_truth, sampler)
    out = Path(out)
    identity = _identity(scene, start, duration, spp, events if with_events else None, sampling,
                         event_formats, sampler)
    identity["motion_truth"] = bool(motion_truth)
    inputs = scene_files(scene)
    _check_memory(scene, spp, with_events)
    if resume:                                        # refuse before loading the renderer
        _check_resumable(out, overwrite, identity, inputs)
    else:
        check_output_dir(out, overwrite, inputs)
    timings = dict.fromkeys(STAGES, 0.0)
    clock = time.perf_counter()
    with recording(profile) as ledger:
        with stage("setup"):
            renderer = Renderer(scene, spp=spp, variant=variant)
            identity["variant"] = renderer.variant
            if with_events:
                sampler, why = _choose_sampler(scene, renderer.variant, sampler)
        timings["setup"] = time.perf_counter() - clock
        with atomic_output_dir(out, overwrite=overwrite, resume=resume, inputs=inputs,
                               command="evfuse simulate", keep_failed=True) as tmp:
            checkpoint = _Checkpoint(tmp / CHECKPOINT_FOLDER, identity, resume)
            rig_record = _write_rig(tmp, scene, sample_times(start, end, scene.render.pose_rate))
            tick = time.perf_counter()
            with stage("imu"):
                imu_record = write_motion_truth(tmp, scene, start, end) if motion_truth else None
            timings["imu"] = time.perf_counter() - tick
            with device_memory(scene, sampling, sampler if with_events else None):
                gain, exposures, flow_record = _write_frames(
                    scene, renderer, tmp, times, spp, checkpoint, progress, timings,
                    motion_truth)
                event_info = checkpoint.events_done
                if with_events and event_info is None:
                    event_info = _simulate_events(
                        scene, renderer, tmp, start, end, events, sampling, event_formats,
                        checkpoint, progress, timings, sampler, why, event_depth=motion_truth)
                    checkpoint.set_events_done(event_info)
            for key in ("sampling_warning", "edge_spp_warning"):
                if with_events and event_info.get(key):
                    print(f"simulate {scene.name}: warning: {event_info[key]}", file=sys.stderr,
                          flush=True)
            frame_camera = scene.frame_camera.camera if scene.frame_camera else scene.camera
            frame_cost = frame_cost_record(checkpoint.frame_stage, checkpoint.frame_costs,
                                           frame_camera, scene.frames.auto_exposure)
            write_sequence_json(tmp / "sequence.json", _sequence_record(
                scene, renderer, start, duration, times, gain, exposures, flow_record,
                motion_truth, event_info if with_events else None, rig_record, imu_record,
                frame_cost, timings))
            profiled = None
            if profile:
                ledger.lap("other")
                profiled = profile_record(
                    {**timings, "total": time.perf_counter() - clock},
                    ledger if renderer.variant != "scalar_rgb" else None, renderer.variant,
                    end - start if with_events else None)
                write_sequence_json(tmp / PROFILE_JSON, profiled)
            checkpoint.remove()
    timings["total"] = time.perf_counter() - clock
    n_renders = frame_cost["exposure_times"]
    if not with_events:
        return SimulationResult(out, len(times), n_renders, renderer.variant, timings,
                                profile=profiled)
    return SimulationResult(out, len(times), n_renders, renderer.variant, timings,
                            event_info["count"], event_info["renders"],
                            event_info.get("pixel_samples", 0),
                            event_info.get("sampler", "frame"), profile=profiled)


# --- the steps of simulate() -------------------------------------------------------------------

def _window(scene: Scene, start: float, duration: float | None) -> tuple[float, float]:
    """The simulated window ``(start, duration)`` in seconds, or a ValueError saying why it
    cannot be simulated."""
    start = float(start)
    traj = scene.trajectory
    if not np.isfinite(start):
        raise ValueError(f"start must be a finite time in seconds, got {start}")
    if duration is None and not start < scene.duration:       # the rest of a scene it is past
        raise ValueError(f"start {start:g} s is not before the end of scene {scene.name} "
                         f"({scene.duration:g} s)")
    duration = float(scene.duration - start if duration is None else duration)
    if not duration > 0:
        raise ValueError(f"duration must be positive, got {duration}")
    end = start + duration
    lo, hi = max(0.0, traj.t_start), min(scene.duration, traj.t_end)
    if not (lo <= start and end <= hi + 1e-9):
        raise ValueError(f"time window [{start}, {end}] s is outside the scene {scene.name}, "
                         f"which covers [{lo}, {hi}] s (its duration and trajectory)")
    return start, duration


def _check_offsets(scene: Scene, start: float) -> None:
    """Refuse a rig clock offset that would write a time before 0 s."""
    for stream, offset in scene.rig.offsets.items():
        if start + offset < 0:
            raise ParameterError(
                f"rig {stream}_offset {offset:g} s would write {stream} times before 0 s from "
                f"{{start}} {start:g} s; expected start + offset >= 0 (simulate from a later "
                "{start} or use a positive offset)", start="start")


def _check_events(scene: Scene, with_events: bool, formats: tuple[str, ...], motion_truth: bool,
                  sampler: str | None) -> None:
    """Refuse event formats, or a sampler, that this run cannot have."""
    unknown = set(formats) - {"h5", "txt", DEPTH_TXT}
    if with_events and (unknown or not formats):
        raise ValueError(f"event formats must be among h5, txt, {DEPTH_TXT}; got {formats}")
    if not motion_truth and DEPTH_TXT in formats:
        raise ValueError(f"event format {DEPTH_TXT} holds each event's depth, which is motion "
                         "ground truth: drop it or keep the motion truth")
    if sampler not in (None, "pixel", "frame"):
        raise ValueError(f"sampler {sampler!r}: expected 'pixel', 'frame' or None (automatic)")
    if with_events and sampler == "pixel" and scene.is_dynamic:
        raise ParameterError(f"{{sampler}} pixel: scene {ParameterError.literal(scene.name)} has "
                             "moving objects, and the per-pixel sampler needs a static scene; "
                             "use {sampler} frame", sampler="sampler")


def _write_frames(scene: Scene, renderer: Renderer, folder: Path, times: np.ndarray,
                  spp: int | None, checkpoint: _Checkpoint, progress: bool, timings: dict,
                  motion_truth: bool) -> tuple[float | None, list[float], dict | None]:
    """The standard camera's frames and depth maps (with a rig, the frame camera's in its
    folder) and their motion ground truth; return the gain, the exposures and the motion truth's
    ``sequence.json`` record (None without ``motion_truth``)."""
    flow_record, tick = None, None
    offset = scene.rig.frames_offset
    if scene.frame_camera is None:
        gain, exposures, image_names, depth_names = _simulate_frames(
            scene, renderer, folder, times, checkpoint, progress, timings)
        # depth map k is frame k's (rendered at its true time): both on the frames' clock
        write_index(folder / "images.txt", times + offset, image_names)
        write_index(folder / "depthmaps.txt", times + offset, depth_names)
        if motion_truth:
            tick = time.perf_counter()
            with stage("flow"):
                flow_record = write_motion_ground_truth(scene, renderer, folder, times,
                                                        depth_names, offset)
    else:                         # a rig: frame_camera/, and the event camera's depth at its times
        gain, exposures, frame_view = simulate_frame_camera(
            scene, renderer, folder, times, offset, _simulate_frames, spp=spp,
            variant=renderer.variant, checkpoint=checkpoint, progress=progress,
            timings=timings)
        if motion_truth:                               # the frame camera's, in its folder
            view_scene, view_renderer, view_folder, view_depths, readout = frame_view
            tick = time.perf_counter()
            with stage("flow"):
                flow_record = write_motion_ground_truth(view_scene, view_renderer, view_folder,
                                                        times, view_depths, offset, readout)
            flow_record["motion_truth_folder"] = view_folder.name
    if tick is not None:
        timings["flow"] = time.perf_counter() - tick
    return gain, exposures, flow_record


def _sequence_record(scene: Scene, renderer: Renderer, start: float, duration: float,
                     times: np.ndarray, gain: float | None, exposures: list[float],
                     flow_record: dict | None, motion_truth: bool, event_info: dict | None,
                     rig_record: dict, imu_record: dict | None, frame_cost: dict,
                     timings: dict) -> dict:
    """The content of ``sequence.json`` (``event_info`` None: no events simulated)."""
    cam, params = scene.camera, scene.frames
    end = start + duration
    return {
        "format": "evfuse sequence 1",
        "scene": {"name": scene.name, "description": scene.description,
                  "source": str(scene.source) if scene.source else None,
                  "toml": scene.text},
        "start": start,
        "duration": duration,
        "seed": scene.seed,
        "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy,
                   "cx": cam.cx, "cy": cam.cy, "distortion": list(cam.distortion)},
        "frames": _frames_record(params, gain, exposures, len(times)),
        "render": {"spp": renderer.spp, "sampler_seed": renderer.seed,
                   "variant": renderer.variant, "integrator": "direct",
                   "pose_rate": scene.render.pose_rate,
                   "renders": frame_cost["exposure_times"]},
        "depth": {"kind": "z", "units": "m", "at": "pixel centres, frame mid-exposure times"},
        **(flow_record if motion_truth else {"flow": None, "motion_field": None,
                                             "object_masks": None}),
        "motion_truth": motion_truth,
        "events": {**event_info, "span_s": [start + scene.rig.events_offset,
                                            end + scene.rig.events_offset]}
                  if event_info is not None else None,
        "rig": rig_record,
        "imu": imu_record,
        **({"frame_camera": scene.frame_camera.as_record()} if scene.frame_camera else {}),
        "software": _versions(),
        "frame_cost": frame_cost,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }


def _write_rig(folder: Path, scene: Scene, pose_times: np.ndarray) -> dict:
    """Write ``calib.txt`` and ``groundtruth.txt`` as the rig gives them
    (:mod:`sim.capture_errors`), and ``calib_exact.txt`` and ``groundtruth_exact.txt`` (the
    truth, for scoring only); return
    ``sequence.json``'s ``rig`` record. A perfect rig writes the same bytes twice."""
    rig, seed = scene.rig, scene.seed
    poses = scene.trajectory.pose(pose_times)
    camera, drawn = calibration_error(scene.camera, rig, rig_generator(seed, "calibration"))
    dp, dw = pose_noise(pose_times, rig, rig_generator(seed, "poses"))
    write_calib(folder / "calib.txt", camera)
    write_calib(folder / EXACT_CALIB, scene.camera)
    write_trajectory(folder / "groundtruth.txt", pose_times + rig.poses_offset,
                     noisy_poses(poses, dp, dw))
    write_trajectory(folder / EXACT_POSES, pose_times, poses)
    return {
        "perfect": rig.is_perfect,
        "params": rig.as_dict(),
        "units": "m, rad, m/sqrt(s), rad/sqrt(s), s; focal_sigma relative, "
                 "principal_point_sigma px",
        "seed": seed,
        "streams": {"poses": [seed, RIG_STREAM, 0], "calibration": [seed, RIG_STREAM, 1]},
        "clock": "the true (scene) clock is the reference: a stream's written time = true "
                 "time + its offset",
        "offsets_s": rig.offsets,
        "calibration_error": drawn,
        "pose_error_rms": {"position_m": float(np.sqrt(np.mean(dp ** 2))),
                           "rotation_rad": float(np.sqrt(np.mean(dw ** 2)))},
        "exact_files": [EXACT_POSES, EXACT_CALIB, "depthmaps.txt", "depth/"],
    }
