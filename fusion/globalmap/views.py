"""Depth views in the world frame: the unit every part of the global map works on.

A :class:`DepthView` is one depth image (a key view's semi-dense map, its filled map, or the
exact depth of its pose) with the camera of its pixel grid and its world pose. Fusion
(:mod:`fusion.globalmap.fuse`), the TSDF (:mod:`fusion.globalmap.tsdf`) and the scoring
(:mod:`fusion.globalmap.score`) all take lists of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fusion.fill.projection import map_points_world
from sim._summary import summary_repr
from sim.camera import Camera

__all__ = ["DepthView", "shares_events", "to_camera", "to_world"]


def to_world(points: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """Camera-frame points in the world frame.

    Parameters
    ----------
    points : (N, 3) array_like, metres, camera frame
    T_world_cam : (4, 4) array_like, the camera's pose (camera to world)

    Returns
    -------
    (N, 3) float64 ndarray, metres, world frame
    """
    T = np.asarray(T_world_cam, dtype=np.float64)
    return np.asarray(points, dtype=np.float64).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]


def to_camera(points: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """World points in a camera's frame (the inverse of :func:`to_world`).

    Parameters
    ----------
    points : (N, 3) array_like, metres, world frame
    T_world_cam : (4, 4) array_like, the camera's pose (camera to world)

    Returns
    -------
    (N, 3) float64 ndarray, metres, camera frame
    """
    T = np.asarray(T_world_cam, dtype=np.float64)
    return (np.asarray(points, dtype=np.float64).reshape(-1, 3) - T[:3, 3]) @ T[:3, :3]


@dataclass(frozen=True)
class DepthView:
    """One depth image placed in the world.

    Attributes
    ----------
    depth : (H, W) float32 ndarray, metres
        z-depth in ``camera``'s pixels; 0 (or not finite) where the view has no point.
    camera : Camera
        The camera of ``depth``'s pixel grid (``H, W`` its resolution; distortion allowed:
        :meth:`Camera.backproject` undistorts).
    T_world_cam : (4, 4) float64 ndarray
        The camera's pose, camera to world.
    t : float, seconds
        The view's time on the poses' clock.
    name : str
        A label for reports (e.g. ``"view 3 semidense"``).
    events : (float, float) or None, seconds
        The window ``[t0, t1]`` of the events the view was made from (None: not known, e.g.
        exact depth): two views whose windows overlap share evidence
        (:func:`shares_events`).
    """

    depth: np.ndarray
    camera: Camera
    T_world_cam: np.ndarray
    t: float = 0.0
    name: str = ""
    events: tuple[float, float] | None = None

    __repr__ = summary_repr

    def __post_init__(self) -> None:
        depth = np.asarray(self.depth, dtype=np.float32)
        if depth.shape != (self.camera.height, self.camera.width):
            raise ValueError(f"depth has shape {depth.shape}, expected the camera's "
                             f"{(self.camera.height, self.camera.width)}")
        pose = np.asarray(self.T_world_cam, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"T_world_cam must be 4x4, got shape {pose.shape}")
        object.__setattr__(self, "depth", np.where(np.isfinite(depth), depth, 0.0)
                           .astype(np.float32))
        object.__setattr__(self, "T_world_cam", pose)
        if self.events is not None:
            t0, t1 = (float(t) for t in self.events)
            if not (np.isfinite(t0) and np.isfinite(t1) and t0 <= t1):
                raise ValueError(f"events must be a window (t0, t1) of seconds with t0 <= t1, "
                                 f"got {self.events!r}")
            object.__setattr__(self, "events", (t0, t1))

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool ndarray: pixels with a point (depth > 0)."""
        return self.depth > 0

    def pixels(self) -> np.ndarray:
        """(N, 2) int64 ndarray, ``(u, v)`` of the pixels with a point, row-major order."""
        v, u = np.nonzero(self.valid)
        return np.stack([u, v], 1)

    def points_camera(self) -> np.ndarray:
        """(N, 3) float64 ndarray, metres: the points in the view's camera frame, in the order
        of :meth:`pixels`."""
        uv = self.pixels()
        return self.camera.backproject(uv.astype(np.float64), self.depth[uv[:, 1], uv[:, 0]])

    def points_world(self) -> np.ndarray:
        """(N, 3) float64 ndarray, metres: the points in the world frame, in the order of
        :meth:`pixels` (the map's own back-projection,
        :func:`fusion.fill.projection.map_points_world`)."""
        return map_points_world(self.depth, self.camera, self.T_world_cam)

    @property
    def centre(self) -> np.ndarray:
        """(3,) float64 ndarray, metres: the camera centre in the world frame."""
        return self.T_world_cam[:3, 3].copy()


def shares_events(a: DepthView, b: DepthView) -> bool:
    """Whether two views are known to share events: both record their event window and the
    windows overlap by more than a point (windows that only touch, ``a.t1 == b.t0``, share
    none). A view without a window is not known to share any.

    Parameters
    ----------
    a, b : DepthView

    Returns
    -------
    bool
    """
    if a.events is None or b.events is None:
        return False
    return min(a.events[1], b.events[1]) > max(a.events[0], b.events[0])
