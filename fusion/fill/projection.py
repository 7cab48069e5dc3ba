"""The event image: map points projected into a standard frame, whichever camera took it.

A map lives in the event camera's reference view; it is filled in a standard frame: the same
sensor's (a DAVIS-like camera) or, on a two-camera rig, the frame camera's, whose pose is
``T_world_frame(t) = T_world_event(t) @ T_event_frame`` with its own lens and size
(:meth:`sim.sequence.Sequence.standard_frames`). A global shutter sees the whole frame at one
pose (:func:`project_map`); a rolling shutter exposes row ``r`` at its own time
(:meth:`sim.sequence.FrameCameraFiles.row_times`), so a point must be projected with the pose of
the row it lands on (:func:`rolling_shutter_project`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sim.camera import Camera
from sim.se3 import invert_pose
from sim.sequence import FrameCameraFiles

__all__ = ["ROLLING_ITERATIONS", "frame_record", "map_points_world", "nearest_per_pixel",
           "project_map", "project_map_rolling", "rolling_shutter_project"]

ROLLING_ITERATIONS = 3
"""Fixed-point iterations of :func:`rolling_shutter_project` (the middle row's pose, then 3
re-projections at the row found)."""


def map_points_world(depth_ref: np.ndarray, camera_ref: Camera, T_world_ref: np.ndarray
                     ) -> np.ndarray:
    """The map's points in the world.

    Parameters
    ----------
    depth_ref : (h, w) float ndarray, metres, 0 = no map point
    camera_ref : Camera, the reference view's (undistorted) camera
    T_world_ref : (4, 4) ndarray, the reference view's pose

    Returns
    -------
    (N, 3) float64 ndarray, metres, world frame (row-major order of the map's pixels)
    """
    depth_ref = np.asarray(depth_ref, dtype=np.float64)
    if depth_ref.shape != (camera_ref.height, camera_ref.width):
        raise ValueError(f"the map is {depth_ref.shape[1]}x{depth_ref.shape[0]} but its camera "
                         f"is {camera_ref.width}x{camera_ref.height}")
    v, u = np.nonzero(depth_ref > 0)
    points = camera_ref.backproject(np.stack([u, v], 1).astype(np.float64), depth_ref[v, u])
    T = np.asarray(T_world_ref, np.float64)
    return points @ T[:3, :3].T + T[:3, 3]


def nearest_per_pixel(uv: np.ndarray, z: np.ndarray, camera: Camera) -> np.ndarray:
    """Splat projected points into an image, the nearest one kept per pixel.

    Parameters
    ----------
    uv : (N, 2) float ndarray, pixels (NaN for points behind the camera)
    z : (N,) float ndarray, metres, z-depth in that camera
    camera : Camera, the image's size

    Returns
    -------
    (H, W) float32 ndarray, metres
        ``z`` at the pixel nearest each projection, the smallest where several land; 0 elsewhere.
    """
    col, row = np.round(uv[:, 0]), np.round(uv[:, 1])
    inside = (np.isfinite(col) & np.isfinite(row) & (col >= 0) & (col < camera.width)
              & (row >= 0) & (row < camera.height))
    col, row, z = col[inside].astype(np.int64), row[inside].astype(np.int64), z[inside]
    out = np.zeros((camera.height, camera.width), np.float32)
    order = np.argsort(-z)                                  # far first: the nearest is kept
    out[row[order], col[order]] = z[order]
    return out


def rolling_shutter_project(points_world: np.ndarray, camera: Camera,
                            pose_at_row: Callable[[np.ndarray], np.ndarray],
                            iterations: int = ROLLING_ITERATIONS
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project world points into a rolling-shutter frame, each with the pose of its own row.

    A point lands on row ``v`` when it is projected with the pose of the time row ``v`` was
    exposed: ``v = f(v)``, ``f(v)`` the row of its projection at ``pose_at_row(v)``. Iterated
    from the middle row: ``v_0 = (H - 1) / 2``, ``v_{k+1} = f(v_k)``. With ``q = f'(v)``, the
    point's vertical image speed (rows/s) times the readout time per row (``readout_s / (H -
    1)``), so the rows it moves per row of readout (``|q| < 1`` whenever the image moves less than
    the frame's height during the readout): ``|v_k - v*| <= |q|^k |v_0 - v*|`` and ``|v_k - v*|
    <= |q| / (1 - |q|) |v_k - v_{k-1}|``: the last step returned bounds the residual.

    Parameters
    ----------
    points_world : (N, 3) float ndarray, metres
    camera : Camera, the frame's (distortion included)
    pose_at_row : callable
        ``(N,) float rows -> (N, 4, 4) T_world_frame`` at each (fractional) row's time; rows are
        clipped to ``[0, H - 1]`` before it is called (a point rounded onto the first or last
        row is seen at that row's time).
    iterations : int
        Re-projections after the first at the middle row (default 3).

    Returns
    -------
    uv : (N, 2) float64 ndarray, pixels (NaN for a point behind the camera)
    z : (N,) float64 ndarray, metres, z-depth at the point's row pose
    last_step : (N,) float64 ndarray, pixels, ``|v_k - v_{k-1}|`` of the last iteration
    """
    points = np.asarray(points_world, np.float64)
    rows = np.full(len(points), 0.5 * (camera.height - 1))
    last_step = np.full(len(points), np.inf)
    uv = np.full((len(points), 2), np.nan)
    z = np.full(len(points), np.nan)
    for _ in range(iterations + 1):
        T = invert_pose(pose_at_row(np.clip(rows, 0.0, camera.height - 1.0)))
        local = np.einsum("nij,nj->ni", T[:, :3, :3], points) + T[:, :3, 3]
        uv = camera.project(local)
        z = local[:, 2]
        new_rows = uv[:, 1]
        last_step = np.abs(new_rows - rows)
        rows = np.where(np.isfinite(new_rows), new_rows, rows)
    return uv, z, last_step


def frame_record(frames: FrameCameraFiles) -> dict:
    """What ``fill.json`` / ``report.json`` record of a rig's frame camera: its size and lens,
    ``T_event_frame`` (4x4, frame-camera to event-camera coordinates), shutter and readout."""
    camera = frames.camera
    return {"width": camera.width, "height": camera.height, "fx": camera.fx, "fy": camera.fy,
            "cx": camera.cx, "cy": camera.cy, "distortion": list(camera.distortion),
            "T_event_frame": np.asarray(frames.T_event_frame).tolist(),
            "shutter": frames.shutter, "readout_s": frames.readout_s}


def project_map(depth_ref: np.ndarray, camera_ref: Camera, T_world_ref: np.ndarray,
                camera: Camera, T_world_frame: np.ndarray) -> np.ndarray:
    """The event image: map points projected into a frame, the nearest one per pixel.

    Parameters
    ----------
    depth_ref : (h, w) float ndarray, metres, 0 = no map point
        The semi-dense map at the reference view.
    camera_ref : Camera
        The reference view's (undistorted) camera.
    T_world_ref, T_world_frame : (4, 4) ndarray
        Poses of the reference view and of the frame.
    camera : Camera
        The frame's camera (distortion included).

    Returns
    -------
    (H, W) float32 ndarray, metres
        z-depth in the frame of each projected point, rounded to the nearest pixel; 0 elsewhere.
    """
    points = map_points_world(depth_ref, camera_ref, T_world_ref)
    T = invert_pose(np.asarray(T_world_frame, np.float64))
    local = points @ T[:3, :3].T + T[:3, 3]
    return nearest_per_pixel(camera.project(local), local[:, 2], camera)


def project_map_rolling(depth_ref: np.ndarray, camera_ref: Camera, T_world_ref: np.ndarray,
                        frames: FrameCameraFiles, trajectory, t_frame: float
                        ) -> tuple[np.ndarray, float]:
    """The event image of a rolling-shutter frame: each map point projected with the pose of
    the row it lands on (:func:`rolling_shutter_project`).

    Parameters
    ----------
    depth_ref, camera_ref, T_world_ref : as :func:`project_map`
    frames : FrameCameraFiles
        The frame camera (its ``camera``, ``T_event_frame`` and :meth:`row_times`).
    trajectory : sim.trajectory.Trajectory
        ``T_world_event(t)``; the frame camera's pose is ``T_world_event(t) @ T_event_frame``.
    t_frame : float, seconds, the frame's (middle row's) time

    Returns
    -------
    sparse : (H, W) float32 ndarray, metres, 0 elsewhere
    last_step : float, pixels
        The largest last fixed-point step of the points that land in the frame (0 without any):
        it bounds each point's row error by ``|q| / (1 - |q|)`` times itself.
    """
    camera = frames.camera
    row_times = frames.row_times(t_frame)
    per_row = (row_times[-1] - row_times[0]) / max(camera.height - 1, 1)   # linear in the row

    def pose_at_row(v: np.ndarray) -> np.ndarray:
        return trajectory.pose(row_times[0] + per_row * v) @ frames.T_event_frame

    points = map_points_world(depth_ref, camera_ref, T_world_ref)
    uv, z, last_step = rolling_shutter_project(points, camera, pose_at_row)
    landed = camera.in_image(uv) & (z > 0)
    return (nearest_per_pixel(uv, z, camera),
            float(last_step[landed].max()) if landed.any() else 0.0)
