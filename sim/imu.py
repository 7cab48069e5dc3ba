"""Motion ground truth: the camera's velocity and an inertial measurement unit (IMU).

Three files beside ``groundtruth.txt`` (:func:`write_motion_truth`, called once by
:func:`sim.simulate.simulate`):

- ``velocity.txt``: ``t vx vy vz wx wy wz``, the camera's linear and angular velocity in the
  CAMERA frame (m/s, rad/s; :meth:`sim.trajectory.Trajectory.camera_velocity`), at the times of
  ``groundtruth_exact.txt`` (the pose rate) on the TRUE clock. Exact.
- ``imu.txt``: what the IMU gives, in the Event-Camera Dataset's layout ``t ax ay az gx gy gz``
  (s, m/s^2, rad/s), at ``[imu] rate`` over the simulated window, stamped by the IMU's clock
  (true time + ``[rig] imu_offset``), with the noise of :class:`ImuParams`.
- ``imu_exact.txt``: the same samples noiseless, at the true times (scoring only, like
  ``groundtruth_exact.txt``). With the ``ideal`` IMU and no ``imu_offset`` it has the bytes of
  ``imu.txt``.

The IMU frame is the camera frame unless ``[imu] T_camera_imu`` declares an extrinsic (the pose
of the IMU in the camera frame: ``p_camera = R_ci p_imu + t_ci``). With ``R = R_world_camera``,
the camera-frame twist ``(v, w)``, angular acceleration ``alpha`` and lever arm ``r = t_ci``:

- gyroscope ``= R_ci^T w`` (the angular velocity is the same for every point of a rigid body);
- accelerometer ``= R_ci^T (R^T a + alpha x r + w x (w x r) - R^T g)``: the specific force
  at the IMU's origin, ``g = -gravity * up`` the gravity vector of the world (the scene's
  top-level ``up``, default ``+z``; ``[imu] gravity``, default 9.80665 m/s^2). At rest it reads
  ``+gravity`` along ``up``.

``a`` and ``alpha`` are the trajectory's analytic derivatives
(:meth:`sim.trajectory.Trajectory.acceleration`), so both are exact.

Noise, in Kalibr's continuous-time parameters and discretisation (Kalibr wiki, "IMU Noise Model"),
per axis, with ``dt = 1 / rate``: ``y_k = y_true(t_k) + b_k + sigma / sqrt(dt) n_k`` and
``b_0 = 0``, ``b_{k+1} = b_k + sigma_b sqrt(dt) n'_k`` (``n``, ``n'`` standard normal), with
``sigma`` the noise density and ``sigma_b`` the bias random walk. The draws come from
``numpy.random.default_rng([seed, IMU_STREAM])``, a stream of their own.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from sim.textfile import numeric_rows
from sim.trajectory import Trajectory, sample_times
from sim.validation import non_negative, positive

__all__ = ["EXACT_IMU", "IMU_FILE", "IMU_PRESETS", "IMU_STREAM", "STANDARD_GRAVITY",
           "VELOCITY_FILE", "ImuParams", "gravity_vector", "imu_generator", "imu_noise",
           "imu_times", "ideal_imu", "read_imu", "read_velocity", "write_motion_truth"]

STANDARD_GRAVITY = 9.80665
"""m/s^2, the standard acceleration of gravity (the default ``[imu] gravity``)."""
IMU_STREAM = 0x494D55
"""The IMU noise draws from ``default_rng([seed, IMU_STREAM])`` ("IMU" in ASCII)."""
VELOCITY_FILE = "velocity.txt"
IMU_FILE = "imu.txt"
EXACT_IMU = "imu_exact.txt"
"""The noiseless IMU at the true times, beside the noisy ``imu.txt`` (scoring only)."""

_NOISE_FIELDS = ("accelerometer_noise_density", "accelerometer_random_walk",
                 "gyroscope_noise_density", "gyroscope_random_walk")
_IDENTITY = tuple(tuple(float(v) for v in row) for row in np.eye(4))


@dataclass(frozen=True)
class ImuParams:
    """The IMU: its rate, extrinsic, gravity and noise (all zero noise: the ``ideal`` preset).

    Attributes
    ----------
    rate : float, Hz
        Sampling rate (> 0). Default 1000.
    accelerometer_noise_density : float, m/s^2/sqrt(Hz)
        White noise density of the accelerometer (Kalibr's name).
    accelerometer_random_walk : float, m/s^3/sqrt(Hz)
        Density of the accelerometer bias's random walk.
    gyroscope_noise_density : float, rad/s/sqrt(Hz)
        White noise density of the gyroscope.
    gyroscope_random_walk : float, rad/s^2/sqrt(Hz)
        Density of the gyroscope bias's random walk.
    gravity : float, m/s^2
        Magnitude of gravity (> 0), along ``-up``.
    T_camera_imu : 4x4 tuple of float
        The IMU's pose in the camera frame (maps IMU coordinates to camera coordinates);
        identity by default.
    preset : str
        The preset these values started from (``custom`` when changed).
    """

    rate: float = 1000.0
    accelerometer_noise_density: float = 0.0
    accelerometer_random_walk: float = 0.0
    gyroscope_noise_density: float = 0.0
    gyroscope_random_walk: float = 0.0
    gravity: float = STANDARD_GRAVITY
    T_camera_imu: tuple[tuple[float, ...], ...] = _IDENTITY
    preset: str = "ideal"

    def __post_init__(self) -> None:
        if not isinstance(self.preset, str) or not self.preset:
            raise ValueError(f"imu preset must be a name, got {self.preset!r}")
        object.__setattr__(self, "T_camera_imu", _extrinsic(self.T_camera_imu))
        for name in ("rate", "gravity"):
            object.__setattr__(self, name, positive(f"imu {name}", getattr(self, name)))
        for name in _NOISE_FIELDS:
            object.__setattr__(self, name, non_negative(f"imu {name}", getattr(self, name)))

    @classmethod
    def from_preset(cls, name: str, **changes: object) -> ImuParams:
        """A preset of :data:`IMU_PRESETS` with some fields changed (then named ``custom``
        unless a noise field changed to another value; the rate, gravity and extrinsic are
        the rig's, not the sensor's, and keep the preset's name)."""
        if name not in IMU_PRESETS:
            raise ValueError(f"imu preset {name!r}: expected one of {', '.join(IMU_PRESETS)}")
        base = IMU_PRESETS[name]
        changed = replace(base, **changes)
        if any(getattr(changed, f) != getattr(base, f) for f in _NOISE_FIELDS):
            changed = replace(changed, preset="custom")
        return changed

    @property
    def extrinsic(self) -> np.ndarray:
        """(4, 4) float64 ndarray: ``T_camera_imu``."""
        return np.array(self.T_camera_imu, dtype=np.float64)

    @property
    def is_ideal(self) -> bool:
        """True when the IMU adds no noise and no bias."""
        return all(getattr(self, f) == 0.0 for f in _NOISE_FIELDS)

    def as_dict(self) -> dict:
        """The parameters as JSON values (for ``sequence.json``)."""
        return {**asdict(self), "T_camera_imu": [list(row) for row in self.T_camera_imu]}


def _extrinsic(value: object) -> tuple[tuple[float, ...], ...]:
    T = np.array(value, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"imu T_camera_imu must be a finite 4x4 rigid transform, got shape "
                         f"{T.shape}")
    R = T[:3, :3]
    if (np.abs(R.T @ R - np.eye(3)).max() > 1e-9 or np.linalg.det(R) <= 0
            or not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12)):
        raise ValueError("imu T_camera_imu must be a rigid transform (rotation R^T R = I, "
                         "det +1, last row [0, 0, 0, 1])")
    return tuple(tuple(float(v) for v in row) for row in T)


IMU_PRESETS: dict[str, ImuParams] = {
    "ideal": ImuParams(),
    # The DAVIS240C's IMU is an InvenSense MPU-6150. White noise from the MPU-6000/MPU-6050
    # product specification (PS-MPU-6000A-00 rev. 3.4, tables 6.1 and 6.2), whose gyroscope and
    # accelerometer the MPU-6150 shares (assumed): rate noise spectral density 0.005 deg/s/sqrt(Hz)
    # and accelerometer power spectral density 400 ug/sqrt(Hz). The datasheet gives no bias
    # instability; the random walks are those of Kalibr's example imu.yaml (wiki, "IMU Noise
    # Model"): 0.0002 m/s^3/sqrt(Hz) and 4e-6 rad/s^2/sqrt(Hz), assumed.
    "mpu6150": ImuParams(accelerometer_noise_density=400e-6 * STANDARD_GRAVITY,
                         accelerometer_random_walk=2e-4,
                         gyroscope_noise_density=math.radians(0.005),
                         gyroscope_random_walk=4e-6, preset="mpu6150"),
}
"""The named IMUs: ``ideal`` (no noise, the default) and ``mpu6150`` (the DAVIS240C's)."""


def imu_generator(seed: int) -> np.random.Generator:
    """The generator of the IMU's noise for a seed (its own stream, :data:`IMU_STREAM`)."""
    return np.random.default_rng([int(seed), IMU_STREAM])


def gravity_vector(up: ArrayLike, gravity: float = STANDARD_GRAVITY) -> np.ndarray:
    """The world's gravity vector ``-gravity * up / |up|`` (m/s^2, (3,) float64)."""
    up = np.asarray(up, dtype=np.float64)
    norm = float(np.linalg.norm(up))
    if up.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise ValueError(f"up must be a non-zero finite 3-vector, got {up.tolist()}")
    return -float(gravity) * up / norm


def imu_times(start: float, end: float, rate: float) -> np.ndarray:
    """The IMU's sample times ``start + k / rate`` for every k with the time <= ``end``.

    Parameters
    ----------
    start, end : float, seconds (``end >= start``)
    rate : float, Hz

    Returns
    -------
    (M,) float64 ndarray, seconds, steps of exactly ``1 / rate`` (up to rounding)
    """
    count = math.floor((end - start) * rate + 1e-9) + 1
    return start + np.arange(count) / rate


def ideal_imu(trajectory: Trajectory, times: ArrayLike, gravity: ArrayLike,
              T_camera_imu: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The noiseless accelerometer and gyroscope of an IMU riding with the camera.

    Parameters
    ----------
    trajectory : Trajectory
        ``T_world_camera(t)``.
    times : (N,) array_like, seconds
    gravity : (3,) array_like, m/s^2
        Gravity in the world frame (:func:`gravity_vector`).
    T_camera_imu : (4, 4) array_like, optional
        The IMU's pose in the camera frame (default identity).

    Returns
    -------
    accelerometer : (N, 3) float64 ndarray, m/s^2, IMU frame
        The specific force ``R_wi^T (a_imu - g)`` (see the module docstring).
    gyroscope : (N, 3) float64 ndarray, rad/s, IMU frame
    """
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    T_ci = np.eye(4) if T_camera_imu is None else np.asarray(T_camera_imu, dtype=np.float64)
    R_ci, r = T_ci[:3, :3], T_ci[:3, 3]
    Rt = np.swapaxes(trajectory.pose(times)[:, :3, :3], -1, -2)
    v_w, w_w = trajectory.velocity(times)
    a_w, alpha_w = trajectory.acceleration(times)
    w = (Rt @ w_w[:, :, None])[:, :, 0]
    alpha = (Rt @ alpha_w[:, :, None])[:, :, 0]
    a = (Rt @ (a_w - np.asarray(gravity, dtype=np.float64))[:, :, None])[:, :, 0]
    lever = np.cross(alpha, r) + np.cross(w, np.cross(w, r))
    return (a + lever) @ R_ci, w @ R_ci


def imu_noise(count: int, params: ImuParams, rng: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray]:
    """White noise plus bias of ``count`` IMU samples (Kalibr's discretisation).

    Parameters
    ----------
    count : int
    params : ImuParams
    rng : numpy.random.Generator

    Returns
    -------
    noise : (count, 6) float64 ndarray
        What to add to ``[accelerometer, gyroscope]`` (m/s^2, rad/s): white plus bias.
    bias : (count, 6) float64 ndarray
        The bias alone (``b_0 = 0``).
    """
    dt = 1.0 / params.rate
    density = np.repeat([params.accelerometer_noise_density,
                         params.gyroscope_noise_density], 3)
    walk = np.repeat([params.accelerometer_random_walk, params.gyroscope_random_walk], 3)
    draws = rng.standard_normal((2, count, 6))
    bias = np.zeros((count, 6))
    bias[1:] = np.cumsum(draws[1, :-1] * (walk * math.sqrt(dt)), axis=0)
    return draws[0] * (density / math.sqrt(dt)) + bias, bias


def _write_table(path: Path, times: np.ndarray, values: np.ndarray) -> None:
    """``t`` with 9 decimals, then the values at full precision (``repr``), one row a line."""
    lines = [f"{t:.9f} " + " ".join(map(repr, row))
             for t, row in zip(times.tolist(), values.tolist(), strict=True)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_motion_truth(folder: Path, scene, start: float, end: float) -> dict:
    """Write ``velocity.txt``, ``imu.txt`` and ``imu_exact.txt`` for ``[start, end]``.

    Parameters
    ----------
    folder : Path
        The sequence folder being written.
    scene : sim.scene.Scene
        Its trajectory, ``up``, ``imu``, ``rig.imu_offset`` and seed are used.
    start, end : float, seconds (true clock)

    Returns
    -------
    dict
        ``sequence.json``'s ``imu`` record.
    """
    params: ImuParams = scene.imu
    trajectory = scene.trajectory
    pose_times = sample_times(start, end, scene.render.pose_rate)
    v, w = trajectory.camera_velocity(pose_times)
    _write_table(folder / VELOCITY_FILE, pose_times, np.concatenate([v, w], axis=1))
    times = imu_times(start, end, params.rate)
    g = gravity_vector(scene.up, params.gravity)
    exact = np.concatenate(ideal_imu(trajectory, times, g, params.extrinsic), axis=1)
    noise, bias = imu_noise(len(times), params, imu_generator(scene.seed))
    offset = scene.rig.imu_offset
    _write_table(folder / IMU_FILE, times + offset, exact + noise)
    _write_table(folder / EXACT_IMU, times, exact)
    return {
        "ideal": params.is_ideal,
        "params": params.as_dict(),
        "units": "rate Hz; noise densities m/s^2/sqrt(Hz), rad/s/sqrt(Hz); random walks "
                 "m/s^3/sqrt(Hz), rad/s^2/sqrt(Hz); gravity m/s^2",
        "up": [float(x) for x in np.asarray(scene.up) / np.linalg.norm(scene.up)],
        "gravity_world_m_s2": g.tolist(),
        "count": len(times),
        "span_s": [float(times[0] + offset), float(times[-1] + offset)],
        "offset_s": offset,
        "seed": scene.seed,
        "stream": [scene.seed, IMU_STREAM],
        "noise_model": "Kalibr: y_k = y(t_k) + b_k + sigma/sqrt(dt) n_k, b_0 = 0, "
                       "b_{k+1} = b_k + sigma_b sqrt(dt) n'_k",
        "final_bias": {"accelerometer": bias[-1, :3].tolist(),
                       "gyroscope": bias[-1, 3:].tolist()},
        "velocity": {"file": VELOCITY_FILE, "frame": "camera", "clock": "true",
                     "rate_hz": scene.render.pose_rate},
        "exact_files": [EXACT_IMU, VELOCITY_FILE],
    }


def _read_table(path: str | Path, columns: tuple[str, ...]) -> np.ndarray:
    expected = f"'{' '.join(columns)}' ({len(columns)} numbers)"
    rows: list[list[float]] = []
    for lineno, fields, values in numeric_rows(path, len(columns), expected):
        if rows and values[0] <= rows[-1][0]:
            raise ValueError(f"{path}:{lineno}: time {fields[0]} is not after "
                             f"{rows[-1][0]!r}; expected strictly increasing times")
        rows.append(values)
    return np.array(rows, dtype=np.float64).reshape(-1, len(columns))


def read_velocity(path: str | Path) -> np.ndarray:
    """Read ``velocity.txt``: (N, 7) float64, columns ``t vx vy vz wx wy wz`` (s, m/s, rad/s,
    camera frame). Raises ValueError naming the file and line for a malformed line."""
    return _read_table(path, ("t", "vx", "vy", "vz", "wx", "wy", "wz"))


def read_imu(path: str | Path) -> np.ndarray:
    """Read ``imu.txt`` / ``imu_exact.txt`` (ECD layout): (N, 7) float64, columns
    ``t ax ay az gx gy gz`` (s, m/s^2, rad/s, IMU frame). Raises ValueError naming the file
    and line for a malformed line."""
    return _read_table(path, ("t", "ax", "ay", "az", "gx", "gy", "gz"))
