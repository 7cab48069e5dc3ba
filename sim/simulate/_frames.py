"""The standard camera's frames: each frame's exposure (pixel by pixel,
:class:`sim.frame_shader.FrameShader`, or whole-frame renders averaged), the camera response or
the frame sensor's model, written atomically as ``images/<k>.png`` with the exact depth
``depth/<k>.exr`` at its time; and ``sequence.json``'s ``frames`` and ``frame_cost`` records.

Their seconds in ``timings_s``: ``frame_setup`` (the frame shader's sub-sample patterns),
``depth`` (the exact depth maps), ``exposure_control`` (auto-exposure's first look, the ideal
camera's gain read again on a resume), ``frame_motion`` (the image motion during each
exposure), ``frame_edges`` (the looks for the pixels an edge crosses), ``render`` (shading every
sub-sample of every exposure time; whole-frame renders), ``frame_sensor`` (luminance to 8-bit:
the response, the sensor's noise) and ``write`` (PNG, EXR, checkpoint)."""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from sim._atomic import atomic_file, write_bytes_atomically
from sim.exr import write_depth
from sim.frame_sensor import (
    FixedPattern,
    fixed_pattern,
    next_exposure,
    sensor_frame,
    settled_exposure,
    vignetting_map,
)
from sim.frame_shader import ExposureCost, FrameShader
from sim.frames import (
    FrameParams,
    auto_gain,
    exposure_sample_times,
    luminance_to_frame,
)
from sim.profile import stage
from sim.progress import progress as progress_stage
from sim.render import Renderer
from sim.scene import Scene
from sim.sequence import frame_name
from sim.simulate._checkpoint import _Checkpoint

FRAME_NOISE_STREAM = 1
"""Frame ``k`` draws its noise from ``np.random.default_rng([seed, FRAME_NOISE_STREAM, k])``."""



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


def _choose_frame_renderer(scene: Scene, renderer) -> tuple[str, str]:
    """How the frames are rendered, and why: ``pixel`` (:class:`sim.frame_shader.FrameShader`)
    for a static scene seen by a :class:`Renderer` with one pose per image on a JIT variant,
    else ``frame`` (whole-frame renders, :meth:`Renderer.luminance`)."""
    if scene.is_dynamic:
        return "frame", "the scene has moving objects"
    if not isinstance(renderer, Renderer) or renderer.rows:
        return "frame", "a rolling shutter gives each row its own pose"
    if renderer.variant == "scalar_rgb":
        return "frame", "scalar_rgb cannot trace per-pixel batches"
    return "pixel", "static scene"


class _Exposures:
    """One frame's exposure luminance and its cost, by either renderer
    (:func:`_choose_frame_renderer`)."""

    def __init__(self, scene: Scene, renderer, times: np.ndarray) -> None:
        self.params = scene.frames
        self.renderer = renderer
        self.kind, self.why = _choose_frame_renderer(scene, renderer)
        self.spp = renderer.spp
        self.flat_spp = min(scene.render.flat_spp, renderer.spp)
        self.shader = None
        if self.kind == "pixel":
            margin = self.params.longest_exposure
            trajectory = scene.trajectory
            self.shader = FrameShader(renderer, self.flat_spp, self.spp,
                                      t0=max(float(times[0]) - margin, trajectory.t_start),
                                      t1=min(float(times[-1]) + margin, trajectory.t_end))

    def record(self) -> dict:
        """The stage's part of ``sequence.json``'s ``frame_cost``."""
        return {"renderer": self.kind, "renderer_reason": self.why, "spp": self.spp,
                "flat_spp": self.flat_spp if self.kind == "pixel" else None}

    def take_seconds(self) -> tuple[float, float]:
        """Seconds the frame shader spent measuring the motion and looking for edges since the
        last call (0 with whole-frame renders)."""
        if self.shader is None:
            return 0.0, 0.0
        seconds = self.shader.seconds
        taken = seconds["motion"], seconds["edges"]
        seconds["motion"] = seconds["edges"] = 0.0
        return taken

    def still(self, t: float) -> np.ndarray:
        """The view at ``t`` (auto-exposure's first look), (H, W) float32 cd/m^2."""
        return self.shader.still(t) if self.shader is not None else self.renderer.luminance(t)

    def __call__(self, t: float, exposure: float | None, depth: np.ndarray
                 ) -> tuple[np.ndarray, ExposureCost]:
        """The luminance a frame integrates over its exposure (``exposure`` None: the
        longest), (H, W) float32, and what it cost."""
        params = self.params
        length = params.longest_exposure if exposure is None else exposure
        if self.shader is not None:
            return self.shader.exposure(t, length, depth, params.exposure_samples)
        renders = [self.renderer.luminance(ts)
                   for ts in exposure_sample_times(t, params, exposure)]
        camera = self.renderer.camera
        cost = ExposureCost(times=len(renders), motion_px=None, bound=None, checks=0,
                            edge_pixels=0, pixel_samples=len(renders) * self.spp
                            * camera.width * camera.height)
        return np.mean(renders, axis=0, dtype=np.float64).astype(np.float32), cost


def _simulate_frames(scene: Scene, renderer: Renderer, folder: Path, times: np.ndarray,
                     checkpoint: _Checkpoint, progress: bool, timings: dict
                     ) -> tuple[float | None, list[float], list[str], list[str]]:
    """Write every frame and depth map that is not on disk yet; return the gain (ideal camera,
    else None), each frame's exposure and the names. Each frame's cost
    (:class:`sim.frame_shader.ExposureCost`) and the stage's (:meth:`_Exposures.record`) go
    into the checkpoint (``frame_costs``, ``frame_stage``), for ``sequence.json``'s
    ``frame_cost``."""
    params = scene.frames
    (folder / "images").mkdir(exist_ok=True)
    (folder / "depth").mkdir(exist_ok=True)
    gain = params.gain if params.gain is not None else checkpoint.gain
    pattern = None if params.ideal else _fixed_pattern(scene)
    exposures = checkpoint.exposures
    image_names = [frame_name(index, "png") for index in range(len(times))]
    depth_names = [frame_name(index, "exr") for index in range(len(times))]
    tick = time.perf_counter()
    with stage("frame_setup"):
        expose = _Exposures(scene, renderer, times)
    timings["frame_setup"] = timings.get("frame_setup", 0.0) + time.perf_counter() - tick
    checkpoint.set_frame_stage(expose.record())
    bar = progress_stage(times, desc=f"simulate {scene.name}", unit="frame", noun="frames",
                         enabled=progress)
    previous = None                                      # the last frame read out, uint8
    for index, t in enumerate(bar):
        image, depth_map = folder / image_names[index], folder / depth_names[index]
        if image.is_file() and depth_map.is_file():       # written atomically: complete
            previous = None
            continue
        tick = time.perf_counter()
        with stage("depth"):
            depth = renderer.depth(t)
        tock = time.perf_counter()
        timings["depth"] += tock - tick
        if not params.ideal and index >= len(exposures):
            if previous is None and index > 0:            # resumed: read frame index-1 back
                previous = cv2.imread(str(folder / image_names[index - 1]),
                                      cv2.IMREAD_UNCHANGED)
            with stage("exposure_control"):
                exposures.append(_frame_exposure(scene, expose, t, pattern, previous,
                                                 exposures[-1] if exposures else None))
            checkpoint.set_exposures(exposures)           # before the frame is written
            tack = time.perf_counter()
            timings["exposure_control"] += tack - tock
            tock = tack
        with stage("render"):
            luminance, cost = expose(t, None if params.ideal else exposures[index], depth)
        tack = time.perf_counter()
        motion, edges = expose.take_seconds()
        timings["frame_motion"] += motion
        timings["frame_edges"] += edges
        timings["render"] += tack - tock - motion - edges
        rng = np.random.default_rng([scene.seed, FRAME_NOISE_STREAM, index])
        if params.ideal:
            if gain is None:                          # resumed: frame 0's exposure again
                with stage("exposure_control"):
                    first = luminance if index == 0 else expose(times[0], None,
                                                                renderer.depth(times[0]))[0]
                    gain = auto_gain(first)
                    checkpoint.set_gain(gain)             # before the first frame is written
                motion, edges = expose.take_seconds()
                tick = time.perf_counter()
                timings["frame_motion"] += motion
                timings["frame_edges"] += edges
                timings["exposure_control"] += tick - tack - motion - edges
                tack = tick
            with stage("frame_sensor"):
                frame = luminance_to_frame(luminance, gain, params)
        else:
            with stage("frame_sensor"):
                frame = sensor_frame(luminance, exposures[index], params.sensor, pattern,
                                     params.output_gamma, rng)
        tock = time.perf_counter()
        timings["frame_sensor"] += tock - tack
        previous = frame
        ok, png = cv2.imencode(".png", frame)
        if not ok:
            raise OSError(f"cannot encode {image} as PNG")
        checkpoint.set_frame_cost(index, cost.as_dict())  # before the frame is written
        with stage("write"):
            write_bytes_atomically(image, png.tobytes())
            with atomic_file(depth_map) as partial:
                write_depth(partial, depth)
        timings["write"] += time.perf_counter() - tock
    if params.ideal and gain is None:  # every frame was on disk, but the gain was not saved
        tick = time.perf_counter()
        with stage("exposure_control"):
            gain = auto_gain(expose(times[0], None, renderer.depth(times[0]))[0])
        motion, edges = expose.take_seconds()
        timings["frame_motion"] += motion
        timings["frame_edges"] += edges
        timings["exposure_control"] += time.perf_counter() - tick - motion - edges
    return gain, exposures, image_names, depth_names


def frame_cost_record(stage: dict, costs: dict[int, dict], camera, auto_exposure: bool) -> dict:
    """``sequence.json``'s ``frame_cost``: what the frames cost and why.

    Parameters
    ----------
    stage : dict
        :meth:`_Exposures.record` (renderer, its reason, ``spp``, ``flat_spp``).
    costs : dict of int to dict
        Each frame's :class:`sim.frame_shader.ExposureCost` record, by index.
    camera : sim.camera.Camera
        The frames' camera (its size).
    auto_exposure : bool
        Whether the sensor chose its first exposure on a look at the first view (one more
        render: a whole frame at ``spp``, or pixel by pixel at ``flat_spp``).

    Returns
    -------
    dict
        See ``docs/guides/performance.md`` ("What a frame costs").
    """
    frames = [costs[k] for k in sorted(costs)]
    pixels = camera.width * camera.height
    pixel = stage["renderer"] == "pixel"
    control = int(auto_exposure)
    control_samples = control * pixels * (stage["flat_spp"] if pixel else stage["spp"])
    times = [c["times"] for c in frames]
    checks = sum(c["checks"] for c in frames)
    bounds = [c["bound"] for c in frames if c["bound"] is not None]
    motions = [c["motion_px"] for c in frames if c["motion_px"] is not None]
    return {
        **stage,
        "frames": len(frames),
        "pixels": pixels,
        "exposure_times": sum(times),
        "exposure_times_per_frame": [min(times), max(times)] if times else None,
        "motion_px_max": max(motions) if motions else None,
        "exposure_bound_max": max(bounds) if bounds else None,
        "edge_pixels_mean": (sum(c["edge_pixels"] for c in frames) / len(frames)
                             if frames and pixel else None),
        "edge_checks": checks,
        "control_renders": control,
        "depth_renders": len(frames),
        "pixel_samples": sum(c["pixel_samples"] for c in frames) + control_samples,
        "geometry_samples": checks * pixels * (stage["flat_spp"] if pixel else 0),
        "depth_rays": len(frames) * pixels,
        "per_frame": frames,
    }


def _fixed_pattern(scene: Scene) -> FixedPattern:
    """The frame sensor's fixed pattern: vignetting from the camera, noise from the seed."""
    cam = scene.camera
    vignetting = vignetting_map(scene.frames.sensor, cam.width, cam.height, cam.fx, cam.fy,
                                cam.cx, cam.cy)
    return fixed_pattern(scene.frames.sensor, vignetting, scene.seed)


def _frame_exposure(scene: Scene, expose: _Exposures, t: float, pattern: FixedPattern,
                    previous: np.ndarray | None, previous_exposure: float | None) -> float:
    """A realistic sensor's exposure for the frame at ``t``: fixed, or auto-exposure's choice
    (settled on the view at ``t`` for the first frame, else from the previous frame)."""
    params = scene.frames
    sensor = params.sensor
    if not sensor.auto_exposure:
        return params.exposure
    if previous is None:
        return settled_exposure(expose.still(t), sensor, pattern,
                                params.longest_exposure)
    return next_exposure(previous, previous_exposure, sensor, params.output_gamma,
                         params.longest_exposure)
