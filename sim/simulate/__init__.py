"""The simulator pipeline: a scene in, a sequence folder (CONVENTIONS.md) out.

Stages, in order: camera calibration -> ground-truth poses (``groundtruth.txt`` at the scene's
``pose_rate``) -> motion truth (``velocity.txt``, ``imu.txt``, ``imu_exact.txt``,
:mod:`sim.imu`) -> standard-camera frames (renders averaged over the exposure, camera response,
noise) and the exact depth at each frame time -> events: the event emulator driven by renders at
adaptively chosen times (:mod:`sim.sampling`), streamed to ``events.h5`` and ``events.txt`` ->
indexes and ``sequence.json``.

Everything is written into ``<out>.partial`` and renamed to ``<out>`` only when complete.

An interrupted run can be resumed (``simulate(..., resume=True)``, ``evfuse simulate --resume``)
and gives the same files as an uninterrupted one. Three things make that possible:

- Every frame is written atomically (a temporary name, then a rename) and draws its noise from
  its own generator, ``default_rng([seed, FRAME_NOISE_STREAM, index])``: a frame whose files
  exist is complete, and any frame can be made alone.
- Renders are deterministic in time (a fixed sampler seed), so the event stage can go on from
  any sample at which the sampler, the emulator and the writers were saved.
- ``<out>.partial/.checkpoint/`` holds what a resumed run needs (see :class:`_Checkpoint`):
  the run's identity (scene text, seed, times, parameters, software), the frames' gain and the
  event stage's state, saved at a sample boundary every :data:`CHECKPOINT_SECONDS` of wall
  time or :data:`CHECKPOINT_SAMPLES` samples, whichever comes first. It is removed before the
  folder is renamed into place.
"""

from __future__ import annotations

import hashlib
import io
import json
import platform
import sys
import time
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, replace
from importlib import metadata
from pathlib import Path

import cv2
import numba
import numpy as np

from sim._atomic import atomic_file, write_bytes_atomically
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
from sim.event_depth import (
    DEPTH_TXT,
    EventDepth,
    EventOutputs,
    H5EventDepthWriter,
    RecentDepth,
    TextEventDepthWriter,
    event_depth_record,
    event_file_name,
)
from sim.eventio import H5EventWriter, TextEventWriter
from sim.events import EventEmulator, EventParams
from sim.exr import write_depth
from sim.flow import write_motion_ground_truth
from sim.frame_sensor import (
    FixedPattern,
    fixed_pattern,
    next_exposure,
    sensor_frame,
    settled_exposure,
    vignetting_map,
)
from sim.frames import (
    FrameParams,
    auto_gain,
    exposure_sample_times,
    frame_times,
    luminance_to_frame,
)
from sim.imu import write_motion_truth
from sim.pixel_sampling import PixelEventEmulator, PixelSamplingStats, pixel_blocks
from sim.progress import progress as progress_stage
from sim.render import Renderer
from sim.sampling import (
    AT_MAX_RATE_NOTE,
    Sample,
    SamplingParams,
    SamplingStats,
    adaptive_samples,
    max_rate_warning,
)
from sim.scene import Scene
from sim.sequence import (
    atomic_output_dir,
    check_output_dir,
    evfuse_version,
    frame_name,
    resumable_partial,
    resume_differences,
    write_index,
    write_sequence_json,
)
from sim.trajectory import sample_times, write_trajectory
from sim.two_camera import simulate_frame_camera

__all__ = ["CHECKPOINT_SAMPLES", "CHECKPOINT_SECONDS", "SimulationResult", "scene_files",
           "simulate"]

CHECKPOINT_SECONDS = 1.0
"""Wall-clock seconds between two checkpoints of the event stage."""
CHECKPOINT_SAMPLES = 1000
"""Most event-camera samples between two checkpoints of the event stage, however fast."""
CHECKPOINT_FOLDER = ".checkpoint"
"""Folder of ``<out>.partial`` that holds the state a resumed run continues from."""
FRAME_NOISE_STREAM = 1
"""Frame ``k`` draws its noise from ``np.random.default_rng([seed, FRAME_NOISE_STREAM, k])``."""

_CHECKPOINT_FORMAT = "evfuse checkpoint 2"
_EMULATOR_ARRAYS = ("ref", "level", "raw", "cutoff", "last_t")
_SHADING = ("evfuse.shader: direct light from every light in turn, a fixed stratified sub-pixel "
            "pattern")
PIXEL_AT_MAX_RATE_NOTE = (
    "intervals_at_max_rate: per-pixel intervals (of intervals) that still changed the pixel's "
    "log intensity by more than lam * C when 2 / max_rate short (sampling.max_rate); the "
    "emulator interpolates across them. Many of them mean a point light or specular highlight, "
    "or a texture finer than the pixels; above 1 % simulate says so on stderr.")
"""The sentence ``sequence.json`` writes beside ``intervals_at_max_rate`` (per-pixel sampler)."""


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
        Number of luminance renders (frames x exposure samples).
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


def _versions() -> dict[str, str]:
    versions = {"python": platform.python_version(), "evfuse": evfuse_version()}
    for package in ("mitsuba", "drjit", "numpy", "opencv-python-headless", "scikit-image",
                    "OpenEXR"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def simulate(scene: Scene, out: str | Path, *, duration: float | None = None,
             start: float = 0.0, spp: int | None = None, variant: str | None = None,
             overwrite: bool = False,
             progress: bool = True, events: EventParams | None = None,
             sampling: SamplingParams | None = None, with_events: bool = True,
             event_formats: tuple[str, ...] = ("h5", "txt"),
             resume: bool = False, sampler: str | None = None,
             rig: RigParams | None = None, motion_truth: bool = True) -> SimulationResult:
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
        per-event depth too (``events/depth``, ``events/depth_flag``).
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
        each event's depth (:mod:`sim.event_depth`). False keeps the frames, depth maps,
        poses and events only (smaller, and a little faster).

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
        (the message names them).

    Notes
    -----
    If interrupted (KeyboardInterrupt or any exception), ``<out>.partial`` is left with its
    last checkpoint in ``.checkpoint/``.
    """
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
    if rig is not None:
        scene = replace(scene, rig=rig)
    for stream, offset in scene.rig.offsets.items():
        if start + offset < 0:
            raise ValueError(f"rig {stream}_offset {offset:g} s would write {stream} times "
                             f"before 0 s from --start {start:g} s; expected start + offset "
                             ">= 0 (simulate from a later --start or use a positive offset)")
    params = scene.frames
    times = start + frame_times(duration, params)
    if len(times) == 0:
        raise ValueError(f"duration {duration} s is too short for one frame at {params.rate} Hz "
                         f"with a {params.longest_exposure} s exposure")
    events = events or EventParams(seed=scene.seed)
    sampling = sampling or SamplingParams()
    event_formats = tuple(event_formats)
    unknown = set(event_formats) - {"h5", "txt", DEPTH_TXT}
    if with_events and (unknown or not event_formats):
        raise ValueError(f"event formats must be among h5, txt, {DEPTH_TXT}; got {event_formats}")
    if not motion_truth and DEPTH_TXT in event_formats:
        raise ValueError(f"event format {DEPTH_TXT} holds each event's depth, which is motion "
                         "ground truth: drop it or keep the motion truth")
    out = Path(out)
    if sampler not in (None, "pixel", "frame"):
        raise ValueError(f"sampler {sampler!r}: expected 'pixel', 'frame' or None (automatic)")
    if with_events and sampler == "pixel" and scene.is_dynamic:
        raise ValueError(f"--sampler pixel: scene {scene.name} has moving objects, and the "
                         "per-pixel sampler needs a static scene; use --sampler frame")
    identity = _identity(scene, start, duration, spp, events if with_events else None, sampling,
                         event_formats, sampler)
    identity["motion_truth"] = bool(motion_truth)
    inputs = scene_files(scene)
    if resume:                                        # refuse before loading the renderer
        _check_resumable(out, overwrite, identity, inputs)
    else:
        check_output_dir(out, overwrite, inputs)
    timings = {"setup": 0.0, "render": 0.0, "depth": 0.0, "write": 0.0, "event_render": 0.0,
               "emulate": 0.0, "event_write": 0.0, "event_depth": 0.0, "checkpoint": 0.0}
    clock = time.perf_counter()
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
        imu_record = write_motion_truth(tmp, scene, start, end) if motion_truth else None
        timings["imu"] = time.perf_counter() - tick
        tick = None
        if scene.frame_camera is None:
            gain, exposures, image_names, depth_names = _simulate_frames(
                scene, renderer, tmp, times, checkpoint, progress, timings)
            # depth map k is frame k's (rendered at its true time): both on the frames' clock
            write_index(tmp / "images.txt", times + scene.rig.frames_offset, image_names)
            write_index(tmp / "depthmaps.txt", times + scene.rig.frames_offset, depth_names)
            if motion_truth:
                tick = time.perf_counter()
                flow_record = write_motion_ground_truth(scene, renderer, tmp, times, depth_names,
                                                        scene.rig.frames_offset)
        else:                     # a rig: frame_camera/, and the event camera's depth at its times
            gain, exposures, frame_view = simulate_frame_camera(
                scene, renderer, tmp, times, scene.rig.frames_offset, _simulate_frames, spp=spp,
                variant=renderer.variant, checkpoint=checkpoint, progress=progress,
                timings=timings)
            if motion_truth:                               # the frame camera's, in its folder
                view_scene, view_renderer, view_folder, view_depths, readout = frame_view
                tick = time.perf_counter()
                flow_record = write_motion_ground_truth(view_scene, view_renderer, view_folder,
                                                        times, view_depths,
                                                        scene.rig.frames_offset, readout)
                flow_record["motion_truth_folder"] = view_folder.name
        if tick is not None:
            timings["flow"] = time.perf_counter() - tick
        event_info = checkpoint.events_done
        if with_events and event_info is None:
            simulate_events = (_simulate_events_per_pixel if sampler == "pixel"
                               else _simulate_events)
            event_info = simulate_events(scene, renderer, tmp, start, end, events, sampling,
                                         event_formats, checkpoint, progress, timings, why,
                                         event_depth=motion_truth)
            checkpoint.set_events_done(event_info)
        if with_events and event_info.get("sampling_warning"):
            print(f"simulate {scene.name}: warning: {event_info['sampling_warning']}",
                  file=sys.stderr, flush=True)
        cam = scene.camera
        write_sequence_json(tmp / "sequence.json", {
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
                       "pose_rate": scene.render.pose_rate, "renders": len(times)
                       * params.exposure_samples},
            "depth": {"kind": "z", "units": "m", "at": "pixel centres, frame mid-exposure times"},
            **(flow_record if motion_truth else {"flow": None, "motion_field": None,
                                                 "object_masks": None}),
            "motion_truth": motion_truth,
            "events": {**event_info, "span_s": [start + scene.rig.events_offset,
                                                end + scene.rig.events_offset]}
                      if with_events else None,
            "rig": rig_record,
            "imu": imu_record,
            **({"frame_camera": scene.frame_camera.as_record()} if scene.frame_camera else {}),
            "software": _versions(),
            "timings_s": {k: round(v, 3) for k, v in timings.items()},
        })
        checkpoint.remove()
    timings["total"] = time.perf_counter() - clock
    return SimulationResult(out, len(times), len(times) * params.exposure_samples,
                            renderer.variant, timings,
                            event_info["count"] if with_events else None,
                            event_info["renders"] if with_events else 0,
                            event_info.get("pixel_samples", 0) if with_events else 0,
                            event_info.get("sampler", "frame") if with_events else None)


# --- the rig: written poses and calibration, the exact ones beside them -----------------------

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


class _OnEventClock:
    """An event writer that shifts every event by the event stream's clock offset (ns)."""

    def __init__(self, writer: H5EventWriter | TextEventWriter, offset_ns: int) -> None:
        self._writer, self._offset_ns = writer, offset_ns

    def write(self, events: np.ndarray, **columns: np.ndarray) -> None:
        shifted = events.copy()
        shifted["t"] += self._offset_ns
        self._writer.write(shifted, **columns)

    def checkpoint(self) -> dict:
        return self._writer.checkpoint()


# --- standard-camera frames --------------------------------------------------------------------

def _frames_record(params: FrameParams, gain: float | None, exposures: list[float],
                   count: int) -> dict:
    """``sequence.json``'s ``frames``: the parameters, the sensor and what was chosen."""
    record = {**asdict(params), "gamma_used": params.output_gamma, "count": count}
    if params.ideal:
        record["gain_used"] = gain
    else:
        record["sensor"]["responsivity_e_per_s_per_cd_m2"] = params.sensor.responsivity_e
        record["exposures_s"] = exposures
    return record


def _exposure(renderer: Renderer, t: float, params: FrameParams,
              exposure: float | None = None) -> np.ndarray:
    """The luminance a frame integrates: its exposure renders averaged, (H, W) float32."""
    exposure = [renderer.luminance(ts) for ts in exposure_sample_times(t, params, exposure)]
    return np.mean(exposure, axis=0, dtype=np.float64).astype(np.float32)


def _simulate_frames(scene: Scene, renderer: Renderer, folder: Path, times: np.ndarray,
                     checkpoint: _Checkpoint, progress: bool, timings: dict
                     ) -> tuple[float | None, list[float], list[str], list[str]]:
    """Write every frame and depth map that is not on disk yet; return the gain (ideal camera,
    else None), each frame's exposure and the names."""
    params = scene.frames
    (folder / "images").mkdir(exist_ok=True)
    (folder / "depth").mkdir(exist_ok=True)
    gain = params.gain if params.gain is not None else checkpoint.gain
    pattern = None if params.ideal else _fixed_pattern(scene)
    exposures = checkpoint.exposures
    image_names = [frame_name(index, "png") for index in range(len(times))]
    depth_names = [frame_name(index, "exr") for index in range(len(times))]
    bar = progress_stage(times, desc=f"simulate {scene.name}", unit="frame", noun="frames",
                         enabled=progress)
    previous = None                                      # the last frame read out, uint8
    for index, t in enumerate(bar):
        image, depth_map = folder / image_names[index], folder / depth_names[index]
        if image.is_file() and depth_map.is_file():       # written atomically: complete
            previous = None
            continue
        tick = time.perf_counter()
        if params.ideal:
            luminance = _exposure(renderer, t, params)
        else:
            if index >= len(exposures):
                if previous is None and index > 0:        # resumed: read frame index-1 back
                    previous = cv2.imread(str(folder / image_names[index - 1]),
                                          cv2.IMREAD_UNCHANGED)
                exposures.append(_frame_exposure(scene, renderer, t, pattern, previous,
                                                 exposures[-1] if exposures else None))
                checkpoint.set_exposures(exposures)       # before the frame is written
            luminance = _exposure(renderer, t, params, exposures[index])
        tock = time.perf_counter()
        depth = renderer.depth(t)
        tack = time.perf_counter()
        rng = np.random.default_rng([scene.seed, FRAME_NOISE_STREAM, index])
        if params.ideal:
            if gain is None:
                first = luminance if index == 0 else _exposure(renderer, times[0], params)
                gain = auto_gain(first)
                checkpoint.set_gain(gain)                 # before the first frame is written
            frame = luminance_to_frame(luminance, gain, params)
        else:
            frame = sensor_frame(luminance, exposures[index], params.sensor, pattern,
                                 params.output_gamma, rng)
        previous = frame
        ok, png = cv2.imencode(".png", frame)
        if not ok:
            raise OSError(f"cannot encode {image} as PNG")
        write_bytes_atomically(image, png.tobytes())
        with atomic_file(depth_map) as partial:
            write_depth(partial, depth)
        timings["render"] += tock - tick
        timings["depth"] += tack - tock
        timings["write"] += time.perf_counter() - tack
    if params.ideal and gain is None:  # every frame was on disk, but the gain was not saved
        gain = auto_gain(_exposure(renderer, times[0], params))
    return gain, exposures, image_names, depth_names


def _fixed_pattern(scene: Scene) -> FixedPattern:
    """The frame sensor's fixed pattern: vignetting from the camera, noise from the seed."""
    cam = scene.camera
    vignetting = vignetting_map(scene.frames.sensor, cam.width, cam.height, cam.fx, cam.fy,
                                cam.cx, cam.cy)
    return fixed_pattern(scene.frames.sensor, vignetting, scene.seed)


def _frame_exposure(scene: Scene, renderer: Renderer, t: float, pattern: FixedPattern,
                    previous: np.ndarray | None, previous_exposure: float | None) -> float:
    """A realistic sensor's exposure for the frame at ``t``: fixed, or auto-exposure's choice
    (settled on the view at ``t`` for the first frame, else from the previous frame)."""
    params = scene.frames
    sensor = params.sensor
    if not sensor.auto_exposure:
        return params.exposure
    if previous is None:
        return settled_exposure(renderer.luminance(t), sensor, pattern,
                                params.longest_exposure)
    return next_exposure(previous, previous_exposure, sensor, params.output_gamma,
                         params.longest_exposure)


# --- events ------------------------------------------------------------------------------------

def _simulate_events(scene: Scene, renderer: Renderer, folder: Path, start: float, end: float,
                     params: EventParams, sampling: SamplingParams, formats: tuple[str, ...],
                     checkpoint: _Checkpoint, progress: bool, timings: dict,
                     why: str = "as asked", event_depth: bool = True) -> dict:
    """Drive the emulator with adaptive renders over [start, end]; stream the events out.

    Continues from the checkpoint's event state when there is one, and saves that state at
    sample boundaries (see :data:`CHECKPOINT_SECONDS`, :data:`CHECKPOINT_SAMPLES`).
    """
    cam = scene.camera
    emulator = EventEmulator((cam.height, cam.width), params)
    stats, count, on, positions, saved = _restore_events(checkpoint, emulator, SamplingStats)
    after: Sample | None = None
    if saved is not None:
        arrays, state = saved
        after = Sample.from_state(state["sample"], arrays["sample_luminance"],
                                  arrays["sample_log"])
    contrast = np.minimum(emulator.c_on, emulator.c_off)      # each pixel's own threshold
    event_camera = _EventCamera(renderer, scene.render.event_spp, start, end)
    with _event_stage(scene, folder, formats, positions, end - start, progress,
                      EventDepth(event_camera.depth, start if after is None else after.t)
                      if event_depth else None,
                      timings) as (bar, writers):
        since, saved_at = 0, time.perf_counter()
        tick = time.perf_counter()
        for sample in adaptive_samples(event_camera, start, end, contrast, params.log_eps, sampling,
                                       stats, after=after):
            tock = time.perf_counter()
            timings["event_render"] += tock - tick
            if emulator.time_ns is None:
                emulator.start(sample.log, sample.t, sample.luminance)
                chunk = None
            else:
                chunk = emulator.advance(sample.log, sample.t, sample.luminance)
            tack = time.perf_counter()
            timings["emulate"] += tack - tock
            writers.write(chunk, sample.t, pending=sample.tail_pending)
            if chunk is not None and len(chunk):
                count += len(chunk)
                on += int(np.count_nonzero(chunk["p"] > 0))
            tick = time.perf_counter()
            timings["event_write"] += tick - tack
            since += 1
            # Only where the sampler can be restarted from this sample (no tail pending).
            if not sample.tail_pending and (since >= CHECKPOINT_SAMPLES
                                            or tick - saved_at >= CHECKPOINT_SECONDS):
                checkpoint.save_events(sample, emulator, stats, count, on, writers.writers)
                since, saved_at = 0, time.perf_counter()
                timings["checkpoint"] += saved_at - tick
                tick = saved_at
            bar.n = round(sample.t - start, 6)
            bar.set_postfix_str(f"{count:,} events, frame sampler ({why}): {stats.renders:,} "
                                "renders", refresh=False)
            bar.update(0)
    return {
        **_event_info(params, formats, sampling, scene, count, on),
        "sampler": "frame",
        "sampler_reason": why,
        "renders": stats.renders,
        "full_renders": stats.renders,
        "pixel_samples": 0,
        "samples": stats.accepted,
        "midpoint_renders": stats.refined,
        "step_intervals": stats.steps,
        "intervals_at_max_rate": stats.at_max_rate,
        "intervals_at_max_rate_note": AT_MAX_RATE_NOTE,
        "sampling_warning": max_rate_warning(stats.at_max_rate, max(stats.accepted - 1, 0),
                                             sampling.max_rate,
                                             sampling.lam * float(contrast.min())),
        "shading": _SHADING if event_camera.shader is not None else "mitsuba direct integrator",
    }


class _EventCamera:
    """The event camera's renders: luminance at its own samples per pixel, exact depth.

    On a JIT variant the event camera is shaded by :class:`sim.shader.EventShader` (every light
    in turn, a fixed sub-pixel pattern), whichever sampler drives it, so that the two samplers
    see the same luminance; on ``scalar_rgb`` by Mitsuba's ``direct`` integrator.
    """

    def __init__(self, renderer: Renderer, spp: int, start: float, end: float):
        self._renderer, self._spp = renderer, spp
        self.scene, self.camera = renderer.scene, renderer.camera
        self.depth = RecentDepth(renderer.depth)     # shared by the sampler and per-event depth
        self.shader = None
        if renderer.variant != "scalar_rgb":
            from sim.shader import EventShader

            self.shader = EventShader(renderer, spp, t0=start, t1=end)

    def luminance(self, t: float) -> np.ndarray:
        if self.shader is not None:
            return self.shader.frame(t)
        return self._renderer.luminance(t, spp=self._spp)


class _ShaderSource:
    """:class:`sim.pixel_sampling.PixelSource` of a renderer's scene, timing its renders."""

    def __init__(self, camera: _EventCamera) -> None:
        self._camera = camera
        self.camera = camera.camera
        self.seconds = 0.0

    def _timed(self, function, *args):
        tick = time.perf_counter()
        try:
            return function(*args)
        finally:
            self.seconds += time.perf_counter() - tick

    def luminance(self, pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
        return self._timed(self._camera.shader.luminance, pixels, times)

    def subsamples(self, t: float) -> np.ndarray:
        return self._timed(self._camera.shader.subsamples, t)

    def depth(self, t: float) -> np.ndarray:
        return self._timed(self._camera.depth, t)

    def camera_velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self._camera.scene.trajectory.camera_velocity(t)


def _choose_sampler(scene: Scene, variant: str, requested: str | None) -> tuple[str, str]:
    """The event camera's sampler (see :func:`simulate`) and why it was chosen."""
    if requested == "pixel" and variant == "scalar_rgb":
        raise ValueError("--sampler pixel: the per-pixel sampler traces batches of rays and "
                         "needs a JIT variant (llvm_ad_rgb or cuda_ad_rgb); scalar_rgb renders "
                         "whole frames only (--sampler frame)")
    if requested is not None:
        chosen, why = requested, "as asked (--sampler)"
    elif scene.is_dynamic:
        chosen, why = "frame", "the scene has moving objects"
    elif variant == "scalar_rgb":
        chosen, why = "frame", "scalar_rgb cannot trace per-pixel batches"
    else:
        chosen, why = "pixel", "static scene"
    return chosen, why


def _restore_events(checkpoint: _Checkpoint, emulator: EventEmulator, stats_type: type
                    ) -> tuple[object, int, int, dict, tuple[dict, dict] | None]:
    """The event stage's counters, restored from the checkpoint when it holds a saved state
    (the emulator is set to it): stats, events written, ON events, the writers' positions, and
    the saved ``(arrays, state)`` (None for a fresh start)."""
    saved = checkpoint.load_events()
    if saved is None:
        return stats_type(), 0, 0, {}, None
    arrays, state = saved
    emulator.set_state({**state["emulator"],
                        **{key: arrays[f"emulator_{key}"] for key in _EMULATOR_ARRAYS}})
    return (stats_type(**state["stats"]), state["count"], state["on"], state["writers"],
            saved)


@contextmanager
def _event_stage(scene: Scene, folder: Path, formats: tuple[str, ...], positions: dict,
                 seconds: float, progress: bool, depth: EventDepth | None, timings: dict):
    """The event stage's progress bar and event writers (resumed at ``positions``, behind
    :class:`sim.event_depth.EventOutputs`, which adds ``depth`` where a file holds it), with
    the emulator on one thread; all undone on exit."""
    camera = scene.camera
    bar = progress_stage(total=round(seconds, 6), desc=f"events {scene.name}", unit="s",
                         noun="s simulated", enabled=progress,
                         bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} s "
                                    "[{elapsed}<{remaining}{postfix}]")
    with ExitStack() as stack:
        stack.callback(bar.close)
        # Dr.Jit's worker threads stay busy between renders, and numba's parallel regions then
        # fight them for the two cores (14 ms instead of 0.6 ms a step at 240x180): interleaved
        # with rendering, the emulator runs on one thread.
        threads = numba.get_num_threads()
        numba.set_num_threads(1)
        stack.callback(numba.set_num_threads, threads)
        writers: dict[str, H5EventWriter | TextEventWriter] = {}
        if "h5" in formats:
            writers["h5"] = stack.enter_context((H5EventWriter if depth is None else
                                                 H5EventDepthWriter)(
                folder / "events.h5", camera.width, camera.height, resume=positions.get("h5")))
        if "txt" in formats:
            writers["txt"] = stack.enter_context(TextEventWriter(
                folder / "events.txt", resume=positions.get("txt")))
        if DEPTH_TXT in formats:
            writers[DEPTH_TXT] = stack.enter_context(TextEventDepthWriter(
                folder / event_file_name(DEPTH_TXT), resume=positions.get(DEPTH_TXT)))
        offset_ns = round(scene.rig.events_offset * 1e9)
        if offset_ns:
            writers = {fmt: _OnEventClock(writer, offset_ns) for fmt, writer in writers.items()}
        with_depth = depth is not None and ("h5" in formats or DEPTH_TXT in formats)
        yield bar, EventOutputs(writers, depth if with_depth else None, timings)


def _simulate_events_per_pixel(scene: Scene, renderer: Renderer, folder: Path, start: float,
                               end: float, params: EventParams, sampling: SamplingParams,
                               formats: tuple[str, ...], checkpoint: _Checkpoint,
                               progress: bool, timings: dict, why: str = "as asked",
                               event_depth: bool = True) -> dict:
    """Drive the emulator with per-pixel samples over [start, end]; stream the events out.

    Checkpoints are taken at block ends (see :func:`sim.pixel_sampling.pixel_blocks`).
    """
    cam = scene.camera
    emulator = PixelEventEmulator((cam.height, cam.width), params)
    stats, count, on, positions, saved = _restore_events(checkpoint, emulator,
                                                         PixelSamplingStats)
    after = None
    if saved is not None:
        arrays, state = saved
        after = (state["sample"]["t"], arrays["observed_rates"])
    contrast = np.minimum(emulator.c_on, emulator.c_off)      # each pixel's own threshold
    event_camera = _EventCamera(renderer, scene.render.event_spp, start, end)
    source = _ShaderSource(event_camera)
    with _event_stage(scene, folder, formats, positions, end - start, progress,
                      EventDepth(event_camera.depth, start if after is None else after[0])
                      if event_depth else None,
                      timings) as (bar, writers):
        since, saved_at = 0, time.perf_counter()
        tick = time.perf_counter()
        rendered = source.seconds
        for block in pixel_blocks(source, emulator, start, end, contrast, params.log_eps,
                                  sampling, stats, after=after):
            tock = time.perf_counter()
            timings["event_render"] += source.seconds - rendered
            timings["emulate"] += (tock - tick) - (source.seconds - rendered)
            writers.write(block.events, block.t)
            if len(block.events):
                count += len(block.events)
                on += int(np.count_nonzero(block.events["p"] > 0))
            tick = time.perf_counter()
            timings["event_write"] += tick - tock
            since += 1
            if since >= CHECKPOINT_SAMPLES or tick - saved_at >= CHECKPOINT_SECONDS:
                sample = Sample(block.t, block.luminance, block.log, 0.0, True)
                checkpoint.save_events(sample, emulator, stats, count, on, writers.writers,
                                       observed_rates=block.observed)
                since, saved_at = 0, time.perf_counter()
                timings["checkpoint"] += saved_at - tick
                tick = saved_at
            rendered = source.seconds
            bar.n = round(block.t - start, 6)
            bar.set_postfix_str(f"{count:,} events, per-pixel sampler ({why}): "
                                f"{stats.full_renders:,} frames, {stats.pixel_samples:,} pixel "
                                "samples", refresh=False)
            bar.update(0)
    return {
        **_event_info(params, formats, sampling, scene, count, on),
        "sampler": "pixel",
        "sampler_reason": why,
        "renders": stats.full_renders,
        "full_renders": stats.full_renders,
        "pixel_samples": stats.pixel_samples,
        "midpoint_samples": stats.midpoint_samples,
        "depth_renders": stats.depth_renders,
        "blocks": stats.blocks,
        "intervals": stats.intervals,
        "step_intervals": stats.steps,
        "intervals_at_max_rate": stats.at_max_rate,
        "intervals_at_max_rate_note": PIXEL_AT_MAX_RATE_NOTE,
        "sampling_warning": max_rate_warning(stats.at_max_rate, stats.intervals,
                                             sampling.max_rate,
                                             sampling.lam * float(contrast.min())),
        "shading": _SHADING,
    }


def _event_info(params: EventParams, formats: tuple[str, ...], sampling: SamplingParams,
                scene: Scene, count: int, on: int) -> dict:
    """The part of ``sequence.json``'s ``events`` both samplers write alike."""
    return {
        "count": count,
        "on": on,
        "off": count - on,
        "files": [event_file_name(fmt) for fmt in formats],
        "depth": event_depth_record(formats),
        "contrast_on": params.contrast_on,
        "contrast_off": params.contrast_off,
        "log_eps": params.log_eps,
        "luminance_unit": "cd/m^2",
        "responsivity_a_per_cd_m2": params.responsivity,
        "dark_current_a": params.dark_current,
        "seed": params.seed,
        "noise": asdict(params.noise),
        "sampling": asdict(sampling),
        "event_spp": scene.render.event_spp,
    }


# --- checkpoints -------------------------------------------------------------------------------

def _identity(scene: Scene, start: float, duration: float, spp: int | None,
              events: EventParams | None, sampling: SamplingParams,
              formats: tuple[str, ...], sampler: str | None = None) -> dict:
    """What decides a run's output, as JSON values (the variant is added once it is known).

    The scene enters by its TOML text (hashed) and the parsed parts a caller may replace;
    files the text refers to (image textures, meshes) are not read.
    """
    identity = {
        "scene_toml_sha256": hashlib.sha256(scene.text.encode("utf-8")).hexdigest(),
        "scene": {"duration": scene.duration, "camera": asdict(scene.camera),
                  "frames": asdict(scene.frames), "render": asdict(scene.render),
                  "rig": scene.rig.as_dict(), "imu": scene.imu.as_dict(),
                  "up": list(scene.up)},
        "seed": scene.seed,
        "start": start,
        "duration": duration,
        "spp": int(spp if spp is not None else scene.render.spp),
        "events": None if events is None else {"params": asdict(events),
                                               "sampling": asdict(sampling),
                                               "formats": list(formats),
                                               "sampler": sampler},
        "software": _versions(),
    }
    return json.loads(json.dumps(identity))           # tuples -> lists, as read back


def _fingerprint(identity: dict) -> str:
    return hashlib.sha256(json.dumps(identity, sort_keys=True).encode("utf-8")).hexdigest()


def _check_resumable(out: Path, overwrite: bool, identity: dict, inputs: list) -> None:
    """Raise ValueError unless ``<out>.partial`` holds a checkpoint of a run like this one."""
    partial = resumable_partial(out, overwrite, inputs)
    saved = _Checkpoint.read(partial / CHECKPOINT_FOLDER)["identity"]
    differences = resume_differences(saved, identity, skip=("variant",))
    if differences:
        raise ValueError(_mismatch(partial, differences))


def _mismatch(partial: Path, differences: list[str]) -> str:
    return (f"{partial} was left by a run with other inputs: {'; '.join(differences)}; expected "
            "the same scene, seed, times, parameters and software to resume (or run without "
            "--resume to start again)")


class _Checkpoint:
    """The state of an unfinished simulation, in ``<out>.partial/.checkpoint/``.

    ``checkpoint.json`` holds ``format``, the run's ``identity`` (see :func:`_identity`) and
    its SHA-256 ``fingerprint``, the frames' ``gain`` once known (saved before the first frame
    is written) and the event stage's ``events`` summary once it is done. ``events.npz`` holds
    the event stage's last saved state: the arrays ``sample_luminance``, ``sample_log`` (the
    sampler's last sample; with the per-pixel sampler, the frame at the end of the last block),
    ``observed_rates`` (per-pixel sampler only: each pixel's observed rate in that block, which
    the next block's prediction uses) and ``emulator_ref``, ``emulator_level``,
    ``emulator_raw``, ``emulator_cutoff``, ``emulator_last_t`` (see
    :meth:`EventEmulator.get_state`), and under ``state`` the JSON
    text of the sample's time and flags, the emulator's time and generator state, the sampling
    counters, the event counts and each writer's :meth:`checkpoint`. Both files are written
    under a temporary name and renamed over the old one.

    Parameters
    ----------
    folder : Path
        The ``.checkpoint`` folder.
    identity : dict
        This run's identity, variant included.
    resume : bool
        Read the folder (its identity must match) rather than start a new one.
    """

    def __init__(self, folder: Path, identity: dict, resume: bool) -> None:
        self.folder = folder
        fingerprint = _fingerprint(identity)
        if resume:
            self.data = self.read(folder)
            if self.data["fingerprint"] != fingerprint:
                differences = resume_differences(self.data["identity"], identity)
                raise ValueError(_mismatch(folder.parent, differences or ["fingerprint"]))
        else:
            folder.mkdir()
            self.data = {"format": _CHECKPOINT_FORMAT, "fingerprint": fingerprint,
                         "identity": identity, "gain": None, "events": None}
            self._save()

    @staticmethod
    def read(folder: Path) -> dict:
        """The contents of ``checkpoint.json``, or a ValueError saying what is wrong."""
        path = folder / "checkpoint.json"
        if not path.is_file():
            raise ValueError(f"{folder.parent} holds no checkpoint ({path} does not exist): the "
                             "run stopped before its first one; run without --resume to start "
                             "again")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}:{exc.lineno}: invalid JSON: {exc.msg}") from None
        if not isinstance(data, dict) or data.get("format") != _CHECKPOINT_FORMAT:
            got = data.get("format") if isinstance(data, dict) else type(data).__name__
            raise ValueError(f"{path}: format {got!r}; expected {_CHECKPOINT_FORMAT!r}")
        return data

    def _save(self) -> None:
        text = json.dumps(self.data, sort_keys=True, indent=1, allow_nan=False)
        write_bytes_atomically(self.folder / "checkpoint.json", text.encode("utf-8"))

    @property
    def gain(self) -> float | None:
        """The frames' automatic gain, once the first frame has fixed it."""
        return self.data["gain"]

    def set_gain(self, gain: float) -> None:
        self.data["gain"] = float(gain)
        self._save()

    @property
    def exposures(self) -> list[float]:
        """A realistic frame sensor's exposure of each frame chosen so far, seconds."""
        return list(self.data.get("exposures", []))

    def set_exposures(self, exposures: list[float]) -> None:
        self.data["exposures"] = [float(e) for e in exposures]
        self._save()

    @property
    def events_done(self) -> dict | None:
        """The event stage's summary (``sequence.json``'s ``events``) once it is complete."""
        return self.data["events"]

    def set_events_done(self, info: dict) -> None:
        self.data["events"] = json.loads(json.dumps(info))
        self._save()

    def save_events(self, sample: Sample, emulator: EventEmulator, stats, count: int, on: int,
                    writers: dict, **extra: np.ndarray) -> None:
        """Save the event stage after ``sample`` (which has no pending tail); ``extra`` arrays
        (the per-pixel sampler's ``observed_rates``) are saved beside the others."""
        emulator_state = emulator.get_state()
        arrays = {f"emulator_{key}": emulator_state.pop(key) for key in _EMULATOR_ARRAYS}
        state = {"sample": sample.state(),
                 "emulator": emulator_state, "stats": asdict(stats), "count": count, "on": on,
                 "writers": {fmt: writer.checkpoint() for fmt, writer in writers.items()}}
        buffer = io.BytesIO()
        np.savez(buffer, sample_luminance=sample.luminance, sample_log=sample.log,
                 state=np.array(json.dumps(state)), **arrays, **extra)
        write_bytes_atomically(self.folder / "events.npz", buffer.getvalue())

    def load_events(self) -> tuple[dict, dict] | None:
        """The arrays and state saved by :meth:`save_events`, or None if there are none."""
        path = self.folder / "events.npz"
        if not path.is_file():
            return None
        try:
            with np.load(path) as saved:
                arrays = {key: saved[key] for key in saved.files if key != "state"}
                state = json.loads(str(saved["state"]))
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"{path}: cannot read the event checkpoint ({exc}); run without "
                             "--resume to start again") from None
        return arrays, state

    def remove(self) -> None:
        """Delete the folder, ``checkpoint.json`` last (until then a resume still works)."""
        for path in sorted(self.folder.iterdir(), key=lambda p: p.name == "checkpoint.json"):
            path.unlink()
        self.folder.rmdir()
