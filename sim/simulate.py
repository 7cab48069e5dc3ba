"""The simulator pipeline: a scene in, a sequence folder (CONVENTIONS.md) out.

Stages, in order: camera calibration -> ground-truth poses (``groundtruth.txt`` at the scene's
``pose_rate``) -> standard-camera frames (renders averaged over the exposure, camera response,
noise) and the exact depth at each frame time -> events: the event emulator driven by renders at
adaptively chosen times (:mod:`sim.sampling`), streamed to ``events.h5`` and ``events.txt`` ->
indexes and ``sequence.json``.

Everything is written into ``<out>.partial`` and renamed to ``<out>`` only when complete.
"""

from __future__ import annotations

import platform
import time
from contextlib import ExitStack
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

import cv2
import numba
import numpy as np
from tqdm.auto import tqdm

from sim.camera import write_calib
from sim.eventio import H5EventWriter, TextEventWriter
from sim.events import EventEmulator, EventParams
from sim.exr import write_depth
from sim.frames import auto_gain, exposure_sample_times, frame_times, luminance_to_frame
from sim.render import Renderer
from sim.sampling import SamplingParams, SamplingStats, adaptive_samples
from sim.scene import Scene
from sim.sequence import (
    atomic_output_dir,
    check_output_dir,
    frame_name,
    write_index,
    write_sequence_json,
)
from sim.trajectory import sample_times, write_trajectory

__all__ = ["SimulationResult", "simulate"]


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
        Renders made for the event camera (refined intervals included).
    variant : str
        Mitsuba variant used.
    timings : dict
        Seconds spent per stage.
    """

    out: Path
    n_frames: int
    n_renders: int
    variant: str
    timings: dict
    n_events: int | None = None
    event_renders: int = 0


def _versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for package in ("evfuse", "mitsuba", "drjit", "numpy", "opencv-python-headless",
                    "scikit-image", "OpenEXR"):
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
             event_formats: tuple[str, ...] = ("h5", "txt")) -> SimulationResult:
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
    event_formats : tuple of {"h5", "txt"}
        Files to write the events to (``events.h5``, ``events.txt``).

    Returns
    -------
    SimulationResult

    Raises
    ------
    ValueError
        A duration that is not positive or not covered by the trajectory, or an existing ``out``
        without ``overwrite``.
    """
    start = float(start)
    duration = float(scene.duration - start if duration is None else duration)
    traj = scene.trajectory
    if not np.isfinite(start):
        raise ValueError(f"start must be a finite time in seconds, got {start}")
    if not duration > 0:
        raise ValueError(f"duration must be positive, got {duration}")
    end = start + duration
    if not (traj.t_start <= start and end <= traj.t_end + 1e-9):
        raise ValueError(f"the trajectory covers [{traj.t_start}, {traj.t_end}] s, which does not "
                         f"contain the simulated [{start}, {end}] s")
    params = scene.frames
    times = start + frame_times(duration, params)
    if len(times) == 0:
        raise ValueError(f"duration {duration} s is too short for one frame at {params.rate} Hz "
                         f"with a {params.exposure} s exposure")
    out = Path(out)
    check_output_dir(out, overwrite)                  # refuse before loading the renderer
    timings = {"setup": 0.0, "render": 0.0, "depth": 0.0, "write": 0.0, "event_render": 0.0,
               "emulate": 0.0, "event_write": 0.0}
    clock = time.perf_counter()
    renderer = Renderer(scene, spp=spp, variant=variant)
    rng = np.random.default_rng(scene.seed)
    timings["setup"] = time.perf_counter() - clock
    with atomic_output_dir(out, overwrite=overwrite) as tmp:
        write_calib(tmp / "calib.txt", scene.camera)
        pose_times = sample_times(start, end, scene.render.pose_rate)
        write_trajectory(tmp / "groundtruth.txt", pose_times, traj.pose(pose_times))
        (tmp / "images").mkdir()
        (tmp / "depth").mkdir()
        gain = params.gain
        image_names, depth_names = [], []
        bar = tqdm(times, desc=f"simulate {scene.name}", unit="frame", disable=not progress)
        for index, t in enumerate(bar):
            tick = time.perf_counter()
            exposure = [renderer.luminance(ts) for ts in exposure_sample_times(t, params)]
            luminance = np.mean(exposure, axis=0, dtype=np.float64).astype(np.float32)
            tock = time.perf_counter()
            depth = renderer.depth(t)
            tack = time.perf_counter()
            if gain is None:
                gain = auto_gain(luminance)
            frame = luminance_to_frame(luminance, gain, params, rng)
            image_names.append(frame_name(index, "png"))
            depth_names.append(frame_name(index, "exr"))
            if not cv2.imwrite(str(tmp / image_names[-1]), frame):
                raise OSError(f"cannot write {tmp / image_names[-1]}")
            write_depth(tmp / depth_names[-1], depth)
            timings["render"] += tock - tick
            timings["depth"] += tack - tock
            timings["write"] += time.perf_counter() - tack
        event_info = None
        if with_events:
            event_info = _simulate_events(scene, renderer, tmp, start, end, events, sampling,
                                          event_formats, progress, timings)
        write_index(tmp / "images.txt", times, image_names)
        write_index(tmp / "depthmaps.txt", times, depth_names)
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
            "frames": {**asdict(params), "gain_used": gain, "count": len(times)},
            "render": {"spp": renderer.spp, "sampler_seed": renderer.seed,
                       "variant": renderer.variant, "integrator": "direct",
                       "pose_rate": scene.render.pose_rate, "renders": len(times)
                       * params.exposure_samples},
            "depth": {"kind": "z", "units": "m", "at": "pixel centres, frame mid-exposure times"},
            "events": event_info,
            "software": _versions(),
            "timings_s": {k: round(v, 3) for k, v in timings.items()},
        })
    timings["total"] = time.perf_counter() - clock
    return SimulationResult(out, len(times), len(times) * params.exposure_samples,
                            renderer.variant, timings,
                            event_info["count"] if event_info else None,
                            event_info["renders"] if event_info else 0)


def _simulate_events(scene: Scene, renderer: Renderer, folder: Path, start: float, end: float,
                     params: EventParams | None, sampling: SamplingParams | None,
                     formats: tuple[str, ...], progress: bool, timings: dict) -> dict:
    """Drive the emulator with adaptive renders over [start, end]; stream the events out."""
    params = params or EventParams(seed=scene.seed)
    sampling = sampling or SamplingParams()
    unknown = set(formats) - {"h5", "txt"}
    if unknown or not formats:
        raise ValueError(f"event formats must be among h5, txt; got {formats}")
    cam = scene.camera
    emulator = EventEmulator((cam.height, cam.width), params)
    stats = SamplingStats()
    count = on = 0
    contrast = min(params.contrast_on, params.contrast_off)
    fast = _FastRenderer(renderer, scene.render.event_spp)
    bar = tqdm(total=round(end - start, 6), desc=f"events {scene.name}", unit="s",
               disable=not progress, bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} s "
               "[{elapsed}<{remaining}{postfix}]")
    with ExitStack() as stack:
        stack.callback(bar.close)
        # Dr.Jit's worker threads stay busy between renders, and numba's parallel regions then
        # fight them for the two cores (14 ms instead of 0.6 ms a step at 240x180): interleaved
        # with rendering, the emulator runs on one thread.
        threads = numba.get_num_threads()
        numba.set_num_threads(1)
        stack.callback(numba.set_num_threads, threads)
        writers = []
        if "h5" in formats:
            writers.append(stack.enter_context(
                H5EventWriter(folder / "events.h5", cam.width, cam.height)))
        if "txt" in formats:
            writers.append(stack.enter_context(TextEventWriter(folder / "events.txt")))
        tick = time.perf_counter()
        for sample in adaptive_samples(fast, start, end, contrast, params.log_eps, sampling,
                                       stats):
            tock = time.perf_counter()
            timings["event_render"] += tock - tick
            if emulator.time_ns is None:
                emulator.start(sample.log, sample.t)
                chunk = None
            else:
                chunk = emulator.advance(sample.log, sample.t, sample.luminance)
            tack = time.perf_counter()
            timings["emulate"] += tack - tock
            if chunk is not None and len(chunk):
                for writer in writers:
                    writer.write(chunk)
                count += len(chunk)
                on += int(np.count_nonzero(chunk["p"] > 0))
            tick = time.perf_counter()
            timings["event_write"] += tick - tack
            bar.n = round(sample.t - start, 6)
            bar.set_postfix_str(f"{count} events, {stats.renders} renders", refresh=False)
            bar.update(0)
    noise = params.noise
    return {
        "count": count,
        "on": on,
        "off": count - on,
        "files": [f"events.{fmt}" for fmt in formats],
        "contrast_on": params.contrast_on,
        "contrast_off": params.contrast_off,
        "log_eps": params.log_eps,
        "seed": params.seed,
        "noise": asdict(noise),
        "sampling": asdict(sampling),
        "renders": stats.renders,
        "samples": stats.accepted,
        "midpoint_renders": stats.refined,
        "step_intervals": stats.steps,
        "intervals_at_max_rate": stats.at_max_rate,
        "event_spp": scene.render.event_spp,
    }


class _FastRenderer:
    """The renderer with the event camera's samples per pixel (depth unchanged)."""

    def __init__(self, renderer: Renderer, spp: int):
        self._renderer, self._spp = renderer, spp
        self.scene, self.camera = renderer.scene, renderer.camera

    def luminance(self, t: float) -> np.ndarray:
        return self._renderer.luminance(t, spp=self._spp)

    def depth(self, t: float) -> np.ndarray:
        return self._renderer.depth(t)
