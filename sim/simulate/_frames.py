"""The standard camera's frames: each frame's exposure renders averaged, the camera response or
the frame sensor's model, written atomically as ``images/<k>.png`` with the exact depth
``depth/<k>.exr`` at its time; and ``sequence.json``'s ``frames`` record."""

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
from sim.frames import (
    FrameParams,
    auto_gain,
    exposure_sample_times,
    luminance_to_frame,
)
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
