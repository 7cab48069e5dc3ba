"""A rig's separate frame camera: its lens, its pose on the rig and its shutter.

A scene that declares ``[event_camera]`` and ``[frame_camera]`` (scenes/README.md) describes a
rig of two cameras: the event camera follows the trajectory, ``T_world_event(t)``, and the frame
camera is fixed to it at ``T_event_frame`` (the frame camera's pose in the event camera's frame:
it maps frame-camera coordinates to event-camera coordinates), so that

    T_world_frame(t) = T_world_event(t) @ T_event_frame.

Shutter: ``global`` exposes every row at once, around the frame's mid-exposure time ``t_mid``;
``rolling`` exposes row ``r`` of ``H`` around its own time
``t_mid + (r / (H - 1) - 0.5) * readout_s`` (first row first), so the middle row's time is the
frame's timestamp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim._summary import summary_repr
from sim.camera import Camera
from sim.se3 import hat
from sim.trajectory import Trajectory

__all__ = ["SHUTTERS", "FrameCamera", "RigTrajectory", "row_times"]

SHUTTERS = ("global", "rolling")
"""The frame camera's shutters."""


def row_times(t_mid: float, height: int, readout_s: float) -> np.ndarray:
    """Exposure (middle) time of every row of a rolling-shutter frame.

    Parameters
    ----------
    t_mid : float, seconds
        The frame's timestamp: its middle row's mid-exposure time.
    height : int
        Rows of the image.
    readout_s : float, seconds
        Time from the first row to the last (0 for a global shutter).

    Returns
    -------
    (height,) float64 ndarray, seconds
        ``t_mid + (r / (height - 1) - 0.5) * readout_s`` for row ``r`` (``t_mid`` for a single
        row).
    """
    if height == 1:
        return np.full(1, float(t_mid))
    rows = np.arange(height, dtype=np.float64)
    return float(t_mid) + (rows / (height - 1) - 0.5) * float(readout_s)


@dataclass(frozen=True)
class FrameCamera:
    """The frame camera of a two-camera rig.

    Attributes
    ----------
    camera : Camera
        Its intrinsics, distortion and image size.
    T_event_frame : (4, 4) float64 ndarray
        Its pose in the event camera's frame (maps frame-camera coordinates to event-camera
        coordinates), metres.
    shutter : {"global", "rolling"}
    readout_s : float, seconds
        Rolling shutter: time from the first row to the last; 0 for a global shutter.
    """

    camera: Camera
    T_event_frame: np.ndarray
    shutter: str = "global"
    readout_s: float = 0.0

    __repr__ = summary_repr

    def __post_init__(self) -> None:
        T = np.array(self.T_event_frame, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError(f"T_event_frame must be a finite (4, 4) rigid transform, got shape "
                             f"{T.shape}")
        R = T[:3, :3]
        if not (np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0
                and np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])):
            raise ValueError("T_event_frame must be a rigid transform (a rotation and a "
                             "translation, last row 0 0 0 1)")
        T.setflags(write=False)
        object.__setattr__(self, "T_event_frame", T)
        if self.shutter not in SHUTTERS:
            raise ValueError(f"frame camera shutter must be one of {', '.join(SHUTTERS)}, got "
                             f"{self.shutter!r}")
        readout = float(self.readout_s)
        if not math.isfinite(readout) or readout < 0:
            raise ValueError(f"frame camera readout_s must be a finite number of seconds >= 0, "
                             f"got {self.readout_s!r}")
        if self.shutter == "global" and readout != 0.0:
            raise ValueError(f"frame camera readout_s is a rolling shutter's; a global shutter "
                             f"has none, got {readout}")
        object.__setattr__(self, "readout_s", readout)

    @property
    def rolling(self) -> bool:
        """Whether the rows are exposed one after another."""
        return self.shutter == "rolling"

    def row_times(self, t_mid: float) -> np.ndarray:
        """Each row's exposure time (H,) float64, seconds, for the frame at ``t_mid`` (see
        :func:`row_times`; all ``t_mid`` for a global shutter)."""
        return row_times(t_mid, self.camera.height, self.readout_s)

    def as_record(self) -> dict:
        """``sequence.json``'s ``frame_camera`` record (JSON values)."""
        cam = self.camera
        return {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy,
                "cx": cam.cx, "cy": cam.cy, "distortion": list(cam.distortion),
                "T_event_frame": self.T_event_frame.tolist(), "shutter": self.shutter,
                "readout_s": self.readout_s}


class RigTrajectory(Trajectory):
    """The frame camera's motion: ``T_world_frame(t) = T_world_event(t) @ T_event_frame``.

    Parameters
    ----------
    event : Trajectory
        ``T_world_event(t)``.
    T_event_frame : (4, 4) ndarray
        The rig's extrinsic.
    """

    def __init__(self, event: Trajectory, T_event_frame: np.ndarray) -> None:
        self.event = event
        self.T_event_frame = np.array(T_event_frame, dtype=np.float64)

    @property
    def t_start(self) -> float:
        return self.event.t_start

    @property
    def t_end(self) -> float:
        return self.event.t_end

    def _poses(self, t: np.ndarray) -> np.ndarray:
        return self.event.pose(t) @ self.T_event_frame

    def _velocities(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # The frame camera's centre is c_f = c_e + R_e p: dc_f/dt = v_e + w x (R_e p).
        v, w = self.event.velocity(t)
        lever = self.event.pose(t)[:, :3, :3] @ self.T_event_frame[:3, 3]
        return v + (hat(w) @ lever[..., None])[..., 0], w

    def _accelerations(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # d/dt (v_e + w x l) with l = R_e p, dl/dt = w x l: a_e + alpha x l + w x (w x l).
        a, alpha = self.event.acceleration(t)
        _, w = self.event.velocity(t)
        lever = self.event.pose(t)[:, :3, :3] @ self.T_event_frame[:3, 3]
        return a + np.cross(alpha, lever) + np.cross(w, np.cross(w, lever)), alpha
