"""Every built-in scene gives usable frames with a realistic frame sensor (issue 21).

The frame of each built-in scene at the reference times of its ``evfuse reproduce`` windows
(Table 1: the middle of the paper's window; Table 2: the middle of each of the six 1-s slider
windows; the complex surfaces: the middle of their 2-s window from 1 s; a rig: the middle of
its sequence) is made as ``evfuse simulate`` makes it: the scene's own realistic sensor, else
``davis240c_aps`` (``machine_vision`` for a rig's frame camera); auto-exposure settled on the
view (the first frame's rule, which later frames track) within ``[frames] max_exposure``; the
exposure's renders averaged; electrons, noise and fixed pattern. Its mean grey must lie in
``MEAN_GREY``: within a factor 2 of auto-exposure's target (0.4 of full scale, 102 / 255; the
middle grey libcaer's DAVIS auto-exposure also aims at), 0.2-0.8 of full scale. Below it,
texture is a few grey levels and region growing (threshold 3) merges the frame: at the 5 ms
the ECD twins allowed, dynamic_6dof's frame had a mean of 11 / 255.

Rendered at 120 pixels wide (the mean grey averages the view, and the settled exposure is a
function of it: 52.3 at 120 x 90 against 52.1 at 240 x 180 on slider_hdr_close at 0.5 s, 89.3
against 87.4 at 1280 x 720 on rig_boxes), at the scene's own samples per pixel for frames
(fewer bias the HDR twins: a spot sampled once per pixel saturates more pixels).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fusion.experiments.reproduce import COMPLEX, PAPER, SLIDERS, ReproduceParams
from scenes import builtin_scenes
from sim.frame_sensor import AE_TARGET, sensor_frame
from sim.render import Renderer
from sim.scene import load_scene
from sim.simulate._frames import _Exposures, _fixed_pattern, _frame_exposure
from sim.two_camera import frame_camera_scene

MEAN_GREY = (255 * AE_TARGET / 2, 255 * min(2 * AE_TARGET, 1.0))
"""Mean grey (of 255) a usable frame has: within a factor 2 of auto-exposure's target."""
WIDTH = 120
"""Width the frames are rendered at (height in the camera's aspect ratio)."""


def _reference_times(name: str, scene) -> list[float]:
    """The middle of each window ``evfuse reproduce`` maps this scene on (default protocol)."""
    params = ReproduceParams()
    if name in PAPER["table1"]:
        t0, t1 = PAPER["table1"][name]["window_s"]
        return [(t0 + t1) / 2]
    if name in SLIDERS:
        return [k + 0.5 for k in range(params.slider_windows)]
    if name in COMPLEX:
        return [params.complex_start + params.long_window / 2]
    return [scene.duration / 2]


def realistic_frame_greys(scene, times: list[float], rig: bool = False
                          ) -> tuple[list[float], list[float], str]:
    """Mean grey (of 255) and exposure (ms) of ``scene``'s frames at ``times`` as ``evfuse
    simulate`` makes them with a realistic sensor (the scene's own, else ``davis240c_aps``, or
    ``machine_vision`` for a rig's frame camera), rendered :data:`WIDTH` pixels wide; and the
    sensor's name."""
    if rig:
        scene = frame_camera_scene(scene)
    frames = scene.frames
    if frames.ideal:
        frames = frames.with_sensor("machine_vision" if rig else "davis240c_aps")
    camera = scene.camera.with_resolution(WIDTH, round(WIDTH * scene.camera.height
                                                       / scene.camera.width))
    scene = dataclasses.replace(scene, camera=camera, frames=frames)
    renderer = Renderer(scene)                        # the frames' own spp, as simulate
    pattern = _fixed_pattern(scene)
    expose = _Exposures(scene, renderer, np.asarray(times, dtype=np.float64))
    means, exposures = [], []
    for t in times:
        exposure = _frame_exposure(scene, expose, t, pattern, None, None)
        luminance, _ = expose(t, exposure, renderer.depth(t))
        frame = sensor_frame(luminance, exposure, frames.sensor, pattern, frames.output_gamma,
                             np.random.default_rng(0))
        means.append(round(float(frame.mean()), 1))
        exposures.append(round(exposure * 1e3, 2))
    return means, exposures, frames.sensor.name


@pytest.mark.parametrize("name", sorted(builtin_scenes()))
def test_builtin_scene_gives_mid_grey_frames_with_a_realistic_sensor(name):
    scene = load_scene(builtin_scenes()[name])
    times = _reference_times(name, scene)
    means, exposures, sensor = realistic_frame_greys(scene, times, scene.frame_camera is not None)
    low, high = MEAN_GREY
    assert all(low <= m <= high for m in means), (
        f"{name} ({sensor}): mean grey {means} at t = {times} s (exposures "
        f"{exposures} ms), expected within [{low:.0f}, {high:.0f}]")
