"""Imperfect rigs: pose noise, clock offsets and calibration error on the files a user gets.

A real rig never hands the pipeline the truth: its motion capture jitters and drifts, its
event stream, frames and poses are stamped by clocks that disagree by a few milliseconds, and its
calibration is an estimate. :class:`RigParams` declares all three; :func:`simulate` applies them
to the files it WRITES for the pipeline (``groundtruth.txt``, ``calib.txt``, the time stamps of
``events.*``, ``images.txt`` and ``depthmaps.txt``) and keeps the truth apart for scoring:

- ``groundtruth_exact.txt``: the true poses at the true times (what ``groundtruth.txt`` was
  before rigs existed);
- ``calib_exact.txt``: the true calibration (the one the renders used);
- ``depth/``: always rendered with the true camera at the true pose of each frame, indexed in
  ``depthmaps.txt`` by the frame's WRITTEN time, so that depth map k pairs with frame k.

Only scoring reads the ``*_exact.txt`` files (:func:`exact_camera`, :func:`exact_trajectory`);
``evfuse map`` / ``fill`` / ``run`` use the noisy ones, as a user would.

Models, each drawn from its own seeded generator (:func:`rig_generator`):

- Pose noise, at the pose rate: ``p' = p + w_p + b_p(t)`` and ``R' = R exp(w_r + b_r(t))``
  (the rotation error in the camera frame), with white ``w ~ N(0, sigma^2)`` per axis at every
  pose and a random walk ``b(t_0) = 0``, ``b(t_k) = b(t_{k-1}) + N(0, q^2 (t_k - t_{k-1}))`` per
  axis (``q`` a continuous-time density in m/sqrt(s) or rad/sqrt(s): after ``t`` seconds the
  walk's standard deviation per axis is ``q sqrt(t)``).
- Clock offsets: a stream's written time is ``t_written = t_true + offset`` for the event stream,
  the frames, the poses and the IMU each. The reference is the TRUE clock, the scene's (the clock of
  ``groundtruth_exact.txt``, of the renders and of ``sequence.json``'s ``start``); an offset of 0
  leaves a stream on it. Only differences between offsets are observable by the pipeline.
- Calibration error: ``f' = f (1 + e_f)`` (one relative draw for ``fx`` and ``fy``: a
  calibration's aspect ratio is far better known than its scale), ``c' = c + e_c`` per axis (px)
  and ``k' = k + e_k`` per distortion coefficient.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from sim.camera import Camera, read_calib
from sim.se3 import so3_exp
from sim.trajectory import SampledTrajectory, read_trajectory

__all__ = ["EXACT_CALIB", "EXACT_POSES", "RIG_PRESETS", "RIG_STREAM", "RigParams",
           "calibration_error", "exact_camera", "exact_trajectory", "noisy_poses",
           "pose_noise", "rig_generator", "true_time"]

EXACT_POSES = "groundtruth_exact.txt"
"""The true poses at the true times, beside the noisy ``groundtruth.txt`` (scoring only)."""
EXACT_CALIB = "calib_exact.txt"
"""The true calibration, beside the noisy ``calib.txt`` (scoring only)."""
RIG_STREAM = 2
"""The rig draws from ``default_rng([seed, RIG_STREAM, k])``: k = 0 the poses, 1 the
calibration (the frames' noise is stream 1, :data:`sim.simulate.FRAME_NOISE_STREAM`)."""
_POSES, _CALIBRATION = 0, 1


@dataclass(frozen=True)
class RigParams:
    """How the written files depart from the truth (all zero: a perfect rig, the default).

    Attributes
    ----------
    position_sigma : float, metres
        White position jitter per axis, at every pose.
    rotation_sigma : float, radians
        White rotation jitter per axis (a rotation vector in the camera frame), at every pose.
    position_walk : float, m/sqrt(s)
        Random-walk density of the position error per axis.
    rotation_walk : float, rad/sqrt(s)
        Random-walk density of the rotation error per axis.
    events_offset, frames_offset, poses_offset, imu_offset : float, seconds
        Each stream's written time minus the true time (the reference clock is the true one;
        ``imu_offset`` stamps ``imu.txt``, :mod:`sim.imu`).
    focal_sigma : float
        Relative error of the focal length (one draw for ``fx`` and ``fy``).
    principal_point_sigma : float, pixels
        Error of ``cx`` and of ``cy`` (one draw each).
    distortion_sigma : tuple of 5 float
        Error of ``k1, k2, p1, p2, k3`` (one draw each).
    preset : str
        The preset these values started from (``custom`` when none was named).
    """

    position_sigma: float = 0.0
    rotation_sigma: float = 0.0
    position_walk: float = 0.0
    rotation_walk: float = 0.0
    events_offset: float = 0.0
    frames_offset: float = 0.0
    poses_offset: float = 0.0
    imu_offset: float = 0.0
    focal_sigma: float = 0.0
    principal_point_sigma: float = 0.0
    distortion_sigma: tuple[float, float, float, float, float] = (0.0,) * 5
    preset: str = "perfect"

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "preset":
                if not isinstance(value, str) or not value:
                    raise ValueError(f"rig preset must be a name, got {value!r}")
                continue
            values = (value,) if item.name != "distortion_sigma" else tuple(value)
            if item.name == "distortion_sigma" and len(values) != 5:
                raise ValueError(f"rig distortion_sigma must be 5 numbers (k1, k2, p1, p2, k3), "
                                 f"got {value!r}")
            for number in values:
                if (isinstance(number, bool) or not isinstance(number, int | float)
                        or not math.isfinite(number)):
                    raise ValueError(f"rig {item.name} must be a finite number, got {value!r}")
                if not item.name.endswith("_offset") and number < 0:
                    raise ValueError(f"rig {item.name} must be >= 0 (a standard deviation or "
                                     f"density), got {value!r}")
            if item.name == "distortion_sigma":
                object.__setattr__(self, item.name, tuple(float(v) for v in values))
            else:
                object.__setattr__(self, item.name, float(value))

    @classmethod
    def from_preset(cls, name: str, **changes: float) -> RigParams:
        """A preset of :data:`RIG_PRESETS`, with some fields changed (then named ``custom``
        unless every change equals the preset's value)."""
        if name not in RIG_PRESETS:
            raise ValueError(f"rig preset {name!r}: expected one of {', '.join(RIG_PRESETS)}")
        base = RIG_PRESETS[name]
        changed = replace(base, **changes)
        return changed if changed == base else replace(changed, preset="custom")

    @property
    def is_perfect(self) -> bool:
        """True when the written files are the exact ones (every field zero)."""
        return replace(self, preset="perfect") == RigParams()

    @property
    def offsets(self) -> dict[str, float]:
        """``{"events" | "frames" | "poses" | "imu": offset in seconds}``."""
        return {"events": self.events_offset, "frames": self.frames_offset,
                "poses": self.poses_offset, "imu": self.imu_offset}

    def as_dict(self) -> dict:
        """The parameters as JSON values (for ``sequence.json``)."""
        return {**asdict(self), "distortion_sigma": list(self.distortion_sigma)}


RIG_PRESETS: dict[str, RigParams] = {
    "perfect": RigParams(),
    # A Vicon/OptiTrack-class motion capture at the camera: sub-millimetre jitter and about 0.1
    # degree of orientation noise (Merriaux et al., "A Study of Vicon System Positioning
    # Performance", Sensors 17(7) 1591, 2017, measure sub-millimetre static noise and about
    # 1-2 mm in motion), a slow drift of the marker-to-camera registration, and a 3 ms offset
    # between the poses and the camera's clock (offsets of a few ms between a camera and
    # another sensor are what temporal calibration finds: Furgale, Rehder and Siegwart,
    # IROS 2013). Events and frames come from one DAVIS and share a clock. Plausible values,
    # not a measured rig.
    "mocap": RigParams(position_sigma=5e-4, rotation_sigma=math.radians(0.1),
                       position_walk=1e-4, rotation_walk=math.radians(0.01),
                       poses_offset=3e-3, preset="mocap"),
    # The mocap rig above with the calibration a checkerboard gives a 240x180 sensor: 0.5 %
    # on the focal length, 1 px on the principal point, 0.01 on k1 (plausible values).
    "lab": RigParams(position_sigma=5e-4, rotation_sigma=math.radians(0.1),
                     position_walk=1e-4, rotation_walk=math.radians(0.01),
                     poses_offset=3e-3, focal_sigma=5e-3, principal_point_sigma=1.0,
                     distortion_sigma=(1e-2, 5e-3, 5e-4, 5e-4, 0.0), preset="lab"),
}
"""The named rigs: ``perfect`` (the default), ``mocap`` (pose noise and a clock offset),
``lab`` (``mocap`` plus calibration error)."""


def rig_generator(seed: int, part: str) -> np.random.Generator:
    """The generator of one part of the rig (``poses`` or ``calibration``) for a seed."""
    k = {"poses": _POSES, "calibration": _CALIBRATION}[part]
    return np.random.default_rng([int(seed), RIG_STREAM, k])


def pose_noise(times: np.ndarray, params: RigParams, rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray]:
    """The position and rotation errors of the written poses (see the module docstring).

    Parameters
    ----------
    times : (N,) float ndarray, seconds, strictly increasing
        The poses' true times.
    params : RigParams
    rng : numpy.random.Generator

    Returns
    -------
    dp : (N, 3) float64 ndarray, metres, world frame
    dw : (N, 3) float64 ndarray, radians, rotation vector in the camera frame
    """
    times = np.asarray(times, dtype=np.float64)
    if times.ndim != 1 or len(times) == 0 or np.any(np.diff(times) <= 0):
        raise ValueError(f"pose times must be 1-D and strictly increasing, got shape "
                         f"{times.shape}")
    n = len(times)
    white = rng.standard_normal((2, n, 3))
    steps = rng.standard_normal((2, n - 1, 3)) * np.sqrt(np.diff(times))[None, :, None]
    walk = np.zeros((2, n, 3))
    walk[:, 1:] = np.cumsum(steps, axis=1)
    dp = params.position_sigma * white[0] + params.position_walk * walk[0]
    dw = params.rotation_sigma * white[1] + params.rotation_walk * walk[1]
    return dp, dw


def noisy_poses(poses: np.ndarray, dp: np.ndarray, dw: np.ndarray) -> np.ndarray:
    """Apply errors to poses: ``p' = p + dp``, ``R' = R exp(dw)``.

    Parameters
    ----------
    poses : (N, 4, 4) float ndarray, T_world_camera
    dp : (N, 3) float ndarray, metres, world frame
    dw : (N, 3) float ndarray, radians, camera frame

    Returns
    -------
    (N, 4, 4) float64 ndarray
    """
    out = np.array(poses, dtype=np.float64, copy=True)
    out[:, :3, :3] = out[:, :3, :3] @ so3_exp(dw)
    out[:, :3, 3] += dp
    return out


def calibration_error(camera: Camera, params: RigParams, rng: np.random.Generator
                      ) -> tuple[Camera, dict]:
    """The calibration a user would have: the true one with drawn errors.

    Parameters
    ----------
    camera : Camera, the true one
    params : RigParams
    rng : numpy.random.Generator

    Returns
    -------
    Camera
        ``fx (1 + e_f)``, ``fy (1 + e_f)``, ``cx + e_cx``, ``cy + e_cy``, distortion ``+ e_k``.
    dict
        The draws: ``focal_relative``, ``cx_px``, ``cy_px``, ``distortion`` (5), for
        ``sequence.json``.
    """
    e_f = params.focal_sigma * rng.standard_normal()
    e_c = params.principal_point_sigma * rng.standard_normal(2)
    e_k = np.asarray(params.distortion_sigma) * rng.standard_normal(5)
    written = Camera(camera.width, camera.height, camera.fx * (1 + e_f), camera.fy * (1 + e_f),
                     camera.cx + e_c[0], camera.cy + e_c[1],
                     tuple(float(k) for k in np.asarray(camera.distortion) + e_k))
    # + 0.0: a zero sigma's draw is -0.0 half the time; the record says 0.0
    return written, {"focal_relative": float(e_f) + 0.0, "cx_px": float(e_c[0]) + 0.0,
                     "cy_px": float(e_c[1]) + 0.0, "distortion": [float(k) + 0.0 for k in e_k]}


# --- what scoring reads ------------------------------------------------------------------------

def _rig_record(metadata: dict | None) -> dict | None:
    return (metadata or {}).get("rig")


def _exact_path(sequence, exact: str, written: str) -> Path:
    """``exact`` in the sequence folder; ``written`` where there is no ``exact`` and the rig was
    perfect (its written file is the true one) or unrecorded (a sequence from before rigs)."""
    folder = Path(sequence.folder)
    if (folder / exact).is_file():
        return folder / exact
    record = _rig_record(sequence.metadata)
    if record is not None and not record.get("perfect", False):
        raise ValueError(f"{folder}: sequence.json declares an imperfect rig but there is no "
                         f"{exact}; expected the truth beside {written}")
    return folder / written


def exact_camera(sequence) -> Camera:
    """The true calibration of a simulated sequence (scoring only): ``calib_exact.txt``, else
    ``calib.txt`` for a perfect rig or a sequence from before rigs.

    Raises
    ------
    ValueError
        The sequence declares an imperfect rig but has no ``calib_exact.txt``.
    """
    path = _exact_path(sequence, EXACT_CALIB, "calib.txt")
    return read_calib(path, sequence.camera.width, sequence.camera.height)


def exact_trajectory(sequence) -> SampledTrajectory:
    """The true poses of a simulated sequence at the true times (scoring only):
    ``groundtruth_exact.txt``, else ``groundtruth.txt`` for a perfect rig or a sequence from
    before rigs.

    Raises
    ------
    ValueError
        The sequence declares an imperfect rig but has no ``groundtruth_exact.txt``.
    """
    return read_trajectory(_exact_path(sequence, EXACT_POSES, "groundtruth.txt"))


def true_time(metadata: dict | None, t: float, stream: str) -> float:
    """The true time of a time stamped by ``stream`` (``events``, ``frames``, ``poses``, ``imu``):
    ``t - offset`` from ``sequence.json``'s ``rig`` record (scoring only; 0 without one)."""
    record = _rig_record(metadata) or {}
    offsets = record.get("offsets_s") or {}
    return float(t) - float(offsets.get(stream, 0.0))
