"""The frame stage of a two-camera rig: the frame camera's files and the event camera's depth.

A rig scene (``[event_camera]`` + ``[frame_camera]``, :mod:`sim.frame_camera`) writes its
sequence folder as an ECD folder of the EVENT camera, with the frame camera beside it
(README, "A rig of two cameras"):

- ``frame_camera/images.txt`` + ``images/``: the frame camera's frames, rendered from
  ``T_world_frame(t) = T_world_event(t) @ T_event_frame`` with the same frame model as a single
  sensor's (:func:`sim.simulate._frames._simulate_frames`: exposure, sensor, noise; a global
  shutter's frames of a static scene pixel by pixel, :mod:`sim.frame_shader`);
- ``frame_camera/depthmaps.txt`` + ``depth/``: its exact z-depth at the same times;
- ``frame_camera/calib.txt`` and ``frame_camera/T_event_frame.txt`` (exact: the rig's
  imperfections, :mod:`sim.capture_errors`, apply to the event camera's files only);
- ``depthmaps.txt`` + ``depth/`` at the top: the event camera's exact z-depth at the frame
  camera's frame times; ``images.txt`` lists no frames (the event camera has none).

Rolling shutter: row ``r`` of a frame is exposed around its own time
``t_r = t_mid + (r / (H - 1) - 0.5) readout_s`` (:func:`sim.frame_camera.row_times`). Each
render gives every row its own exact pose ``T_world_frame(t_r + offset)`` (the sensor's
per-row poses, :class:`sim.render.Renderer` ``rows=True``), whole frames, one per exposure
sample; the depth map casts each row's rays from its own pose at ``t_r``. Nothing is banded or
interpolated: the only approximation is the exposure's (``exposure_samples`` renders averaged,
4 if not given).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim._atomic import atomic_file
from sim.camera import write_calib
from sim.exr import write_depth
from sim.frame_camera import FrameCamera, RigTrajectory
from sim.render import Renderer
from sim.scene import Scene
from sim.se3 import rot_to_quat
from sim.sequence import frame_name, write_index

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ["FRAME_CAMERA_FOLDER", "RollingShutterView", "frame_camera_scene",
           "simulate_frame_camera", "write_extrinsic"]

FRAME_CAMERA_FOLDER = "frame_camera"
"""Sub-folder of a rig's sequence folder that holds the frame camera's files."""


def frame_camera_scene(scene: Scene) -> Scene:
    """The scene as the frame camera sees it: its camera, its trajectory ``T_world_frame(t)``.

    Parameters
    ----------
    scene : Scene
        A rig scene (``scene.frame_camera`` set).

    Returns
    -------
    Scene
        ``camera`` = the frame camera, ``trajectory`` = :class:`RigTrajectory`, no frame camera.
    """
    rig = scene.frame_camera
    if rig is None:
        raise ValueError(f"scene {scene.name} has no [frame_camera]")
    return replace(scene, camera=rig.camera,
                   trajectory=RigTrajectory(scene.trajectory, rig.T_event_frame),
                   frame_camera=None)


class RollingShutterView:
    """A frame camera whose rows are exposed one after another, rendered row-exactly.

    Offers the two calls the frame stage makes of a :class:`~sim.render.Renderer`:
    ``luminance(t)`` and ``depth(t)``, with ``t`` the frame's (middle row's) time.

    Parameters
    ----------
    scene : Scene
        The frame camera's scene (:func:`frame_camera_scene`).
    frame_camera : FrameCamera
        Gives the readout time.
    spp, variant :
        As for :class:`~sim.render.Renderer`.
    """

    def __init__(self, scene: Scene, frame_camera: FrameCamera, *, spp: int | None = None,
                 variant: str | None = None) -> None:
        self.renderer = Renderer(scene, spp=spp, variant=variant, rows=True)
        self.scene, self.frame_camera = scene, frame_camera
        self.camera, self.spp, self.seed = scene.camera, self.renderer.spp, self.renderer.seed
        self.variant = self.renderer.variant

    def row_poses(self, t: float) -> np.ndarray:
        """``T_world_frame`` (H, 4, 4) of every row of the frame whose middle row is at ``t``."""
        return self.scene.trajectory.pose(self.frame_camera.row_times(t))

    def luminance(self, t: float, pose: np.ndarray | None = None, spp: int | None = None
                  ) -> np.ndarray:
        """Linear luminance (H, W) float32, cd/m^2: row ``r`` seen at ``t + row offset``."""
        if pose is not None:
            raise ValueError("a rolling-shutter view takes its row poses from the trajectory")
        return self.renderer.luminance_rows(t, self.row_poses(t), spp)

    def depth(self, t: float, pose: np.ndarray | None = None) -> np.ndarray:
        """Exact z-depth (H, W) float32, metres, each row from its pose at its own time."""
        if pose is not None:
            raise ValueError("a rolling-shutter view takes its row poses from the trajectory")
        return self.renderer.depth_rows(t, self.row_poses(t))


def write_extrinsic(path: str | Path, T_event_frame: np.ndarray) -> None:
    """Write ``T_event_frame.txt``: one line ``px py pz qx qy qz qw`` (quaternion scalar last,
    ``qw >= 0``, full float precision), as ``groundtruth.txt`` without the time."""
    T = np.asarray(T_event_frame, dtype=np.float64)
    values = (*T[:3, 3], *rot_to_quat(T[:3, :3]))
    Path(path).write_text(" ".join(repr(float(v)) for v in values) + "\n", encoding="utf-8")


def simulate_frame_camera(scene: Scene, event_renderer: Renderer, folder: Path,
                          times: np.ndarray, frames_offset: float,
                          simulate_frames: Callable, *, spp: int | None, variant: str | None,
                          **stage) -> tuple[float | None, list[float], tuple]:
    """Write a rig's frame-camera files and the event camera's depth at the frame times.

    Parameters
    ----------
    scene : Scene
        A rig scene (``scene.frame_camera`` set; ``scene.camera`` is the event camera).
    event_renderer : Renderer
        The event camera's renderer (for its depth maps).
    folder : Path
        The sequence folder being written (``<out>.partial``).
    times : (N,) float64 ndarray, seconds
        The frames' mid-exposure times (true clock).
    frames_offset : float, seconds
        The frames' clock offset (``[rig] frames_offset``): written times are ``times + it``.
    simulate_frames : callable
        :func:`sim.simulate._frames._simulate_frames` (the frame model of a single sensor),
        called as ``simulate_frames(scene, renderer, folder, times, **stage)``.
    spp, variant :
        Samples per pixel and Mitsuba variant of the frame camera's renders.
    **stage
        ``checkpoint``, ``progress``, ``timings``: passed on to ``simulate_frames``.

    Returns
    -------
    gain : float or None
        The frame camera's gain (ideal sensor).
    exposures : list of float
        Each frame's exposure (realistic sensor).
    view : tuple
        ``(scene, renderer, folder, depth_names, readout_s)`` of the frame camera, for the
        motion ground truth of :func:`sim.flow.write_motion_ground_truth` (a rolling shutter's
        renderer casts each row from its own pose; ``readout_s`` is 0 for a global shutter).
    """
    rig = scene.frame_camera
    view_scene = frame_camera_scene(scene)
    renderer = (RollingShutterView(view_scene, rig, spp=spp, variant=variant) if rig.rolling
                else Renderer(view_scene, spp=spp, variant=variant))
    sub = folder / FRAME_CAMERA_FOLDER
    sub.mkdir(exist_ok=True)
    gain, exposures, image_names, depth_names = simulate_frames(view_scene, renderer, sub, times,
                                                                **stage)
    write_calib(sub / "calib.txt", rig.camera)
    write_extrinsic(sub / "T_event_frame.txt", rig.T_event_frame)
    write_index(sub / "images.txt", times + frames_offset, image_names)
    write_index(sub / "depthmaps.txt", times + frames_offset, depth_names)
    # The event camera: no frames, its exact depth at the frame camera's (middle row's) times.
    (folder / "depth").mkdir(exist_ok=True)
    names = [frame_name(index, "exr") for index in range(len(times))]
    for name, t in zip(names, times, strict=True):
        path = folder / name
        if not path.is_file():                             # written atomically: complete
            with atomic_file(path) as partial:
                write_depth(partial, event_renderer.depth(float(t)))
    write_index(folder / "images.txt", times[:0], [])
    write_index(folder / "depthmaps.txt", times + frames_offset, names)
    view = (view_scene, renderer.renderer if rig.rolling else renderer, sub, depth_names,
            rig.readout_s if rig.rolling else 0.0)
    return gain, exposures, view
