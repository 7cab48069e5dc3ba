"""Camera motion: the pose ``T_world_camera(t)`` and its velocity, plus ``groundtruth.txt`` I/O.

Every trajectory answers ``pose(t)`` (4x4 ``T_world_camera``, CONVENTIONS.md) and
``velocity(t) -> (v, w)``: ``v`` the velocity of the camera centre and ``w`` the angular velocity,
both in the WORLD frame (``dR/dt = hat(w) R``); ``camera_velocity(t)`` gives the same twist in the
camera frame, and ``acceleration(t) -> (a, alpha)`` the analytic time derivatives of ``v`` and
``w`` (world frame, m/s^2 and rad/s^2). Times are seconds; each trajectory has a valid range
``[t_start, t_end]`` (infinite for the analytic ones) and raises ``ValueError`` outside it.

Trajectories:

- :class:`LinearTrajectory`: constant velocity, fixed orientation.
- :class:`HandheldTrajectory`: smooth 6-DoF shake, sums of sines with an optional chirp.
- :class:`SplineTrajectory`: C2 cubic B-spline through keyframe poses (cumulative on SO(3)).
- :class:`SampledTrajectory`: geodesic interpolation between sampled poses (motion capture).
- :class:`TimeScaledTrajectory`: another trajectory run ``scale`` times as fast (a sweep's
  ``speed``).

Files: ECD ``groundtruth.txt`` / TUM, ``t px py pz qx qy qz qw`` (quaternion scalar last).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from scipy import sparse
from scipy.interpolate import BSpline
from scipy.sparse.linalg import spsolve

from sim._summary import summary_repr
from sim.se3 import (
    interpolate_pose,
    invert_pose,
    make_pose,
    quat_to_rot,
    rot_to_quat,
    se3_exp,
    se3_log,
    so3_exp,
    so3_log,
    so3_right_jacobian,
    so3_right_jacobian_rate,
)
from sim.textfile import numeric_rows
from sim.validation import non_negative, positive

__all__ = [
    "HandheldTrajectory",
    "LinearTrajectory",
    "SampledTrajectory",
    "SplineTrajectory",
    "TimeScaledTrajectory",
    "Trajectory",
    "read_trajectory",
    "sample_times",
    "write_trajectory",
]

# How far from orthonormal (max abs entry of R^T R - I) an input rotation may be; it is then
# projected onto SO(3).
ROTATION_TOLERANCE = 1e-6


# ----------------------------------------------------------------------------------------------
# Base class
# ----------------------------------------------------------------------------------------------


class Trajectory(ABC):
    """A camera motion ``T_world_camera(t)``.

    Subclasses implement ``_poses`` and ``_velocities`` on a 1-D array of valid times; this class
    checks the times and handles scalars.

    Attributes
    ----------
    t_start, t_end : float, seconds
        The valid time range (``-inf`` / ``inf`` for analytic trajectories).
    """

    @property
    def t_start(self) -> float:
        """float, seconds: first valid time."""
        return -math.inf

    @property
    def t_end(self) -> float:
        """float, seconds: last valid time."""
        return math.inf

    def pose(self, t: ArrayLike) -> np.ndarray:
        """Camera pose ``T_world_camera`` at time(s) ``t``.

        Parameters
        ----------
        t : float or (N,) array_like, seconds
            Within ``[t_start, t_end]``.

        Returns
        -------
        (4, 4) or (N, 4, 4) float64 ndarray

        Raises
        ------
        ValueError
            For a time outside the valid range or not finite.
        """
        times, shape = self._check_times(t)
        return self._poses(times).reshape(shape + (4, 4))

    def velocity(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Linear and angular velocity in the WORLD frame at time(s) ``t``.

        Parameters
        ----------
        t : float or (N,) array_like, seconds
            Within ``[t_start, t_end]``.

        Returns
        -------
        v : (3,) or (N, 3) float64 ndarray, m/s
            Velocity of the camera centre, world frame.
        w : (3,) or (N, 3) float64 ndarray, rad/s
            Angular velocity in the world frame: ``dR/dt = hat(w) @ R``.
        """
        times, shape = self._check_times(t)
        v, w = self._velocities(times)
        return v.reshape(shape + (3,)), w.reshape(shape + (3,))

    def camera_velocity(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """The twist of :meth:`velocity` expressed in the camera frame: ``(R^T v, R^T w)``.

        Parameters
        ----------
        t : float or (N,) array_like, seconds

        Returns
        -------
        v : (3,) or (N, 3) float64 ndarray, m/s, camera frame
        w : (3,) or (N, 3) float64 ndarray, rad/s, camera frame (``R^T dR/dt = hat(w)``)
        """
        times, shape = self._check_times(t)
        R = self._poses(times)[:, :3, :3]
        v, w = self._velocities(times)
        Rt = np.swapaxes(R, -1, -2)
        v_c = (Rt @ v[..., None])[..., 0]
        w_c = (Rt @ w[..., None])[..., 0]
        return v_c.reshape(shape + (3,)), w_c.reshape(shape + (3,))

    def acceleration(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Linear and angular acceleration in the WORLD frame at time(s) ``t``.

        The time derivatives of :meth:`velocity`, analytic for every trajectory (for a
        :class:`SampledTrajectory` the derivative inside the segment holding ``t``).

        Parameters
        ----------
        t : float or (N,) array_like, seconds
            Within ``[t_start, t_end]``.

        Returns
        -------
        a : (3,) or (N, 3) float64 ndarray, m/s^2
            Acceleration of the camera centre, world frame (``dv/dt``; gravity not included).
        alpha : (3,) or (N, 3) float64 ndarray, rad/s^2
            Angular acceleration ``dw/dt`` in the world frame; in the camera frame it is
            ``R^T alpha``, the derivative of the camera-frame angular velocity.
        """
        times, shape = self._check_times(t)
        a, alpha = self._accelerations(times)
        return a.reshape(shape + (3,)), alpha.reshape(shape + (3,))

    def _check_times(self, t: ArrayLike) -> tuple[np.ndarray, tuple[int, ...]]:
        arr = np.asarray(t, dtype=np.float64)
        flat = arr.reshape(-1)
        bad = ~((flat >= self.t_start) & (flat <= self.t_end))
        if np.any(bad):
            first = float(flat[np.argmax(bad)])
            raise ValueError(
                f"time {first!r} s is outside the valid range [{self.t_start!r}, "
                f"{self.t_end!r}] s of this {type(self).__name__}"
            )
        return flat, arr.shape

    @abstractmethod
    def _poses(self, t: np.ndarray) -> np.ndarray:
        """(N, 4, 4) poses at valid times (N,)."""

    @abstractmethod
    def _velocities(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame ``(v, w)``, (N, 3) each, at valid times (N,)."""

    @abstractmethod
    def _accelerations(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame ``(dv/dt, dw/dt)``, (N, 3) each, at valid times (N,)."""


# ----------------------------------------------------------------------------------------------
# Input checks
# ----------------------------------------------------------------------------------------------


def _vector(x: ArrayLike, name: str, size: int, *, nonneg: bool = False) -> np.ndarray:
    arr = np.array(x, dtype=np.float64)
    if arr.shape != (size,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be {size} finite numbers, got {np.asarray(x).tolist()}")
    if nonneg and np.any(arr < 0):
        raise ValueError(f"{name} must be {size} numbers >= 0, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def _rotations(R: ArrayLike, name: str) -> np.ndarray:
    """Check (..., 3, 3) rotations and project them onto SO(3) (they are nearly orthonormal)."""
    R = np.array(R, dtype=np.float64)
    if R.ndim < 2 or R.shape[-2:] != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"{name} must be finite (3, 3) rotation matrices, got shape {R.shape}")
    error = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(R)
    if np.any(error > ROTATION_TOLERANCE) or np.any(det <= 0):
        raise ValueError(
            f"{name} must be rotation matrices (R^T R = I within {ROTATION_TOLERANCE}, det +1), "
            f"got max |R^T R - I| = {error.max():.3g}, min det = {det.min():.3g}"
        )
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def _poses_array(poses: ArrayLike, name: str) -> np.ndarray:
    T = np.array(poses, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name} must be finite (N, 4, 4) poses, got shape {T.shape}")
    if not np.allclose(T[:, 3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12):
        raise ValueError(f"{name} must be rigid transforms with last row [0, 0, 0, 1]")
    return make_pose(_rotations(T[:, :3, :3], name), T[:, :3, 3])


def _keyframe_times(times: ArrayLike, n: int, name: str) -> np.ndarray:
    t = np.array(times, dtype=np.float64)
    if t.shape != (n,) or not np.all(np.isfinite(t)):
        raise ValueError(f"{name} must be {n} finite times (one per pose), got shape {t.shape}")
    if n < 2:
        raise ValueError(f"{name} must hold at least 2 times, got {n}")
    if np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise ValueError(
            f"{name} must be strictly increasing, got {t[i]!r} then {t[i + 1]!r} at index {i + 1}"
        )
    t.setflags(write=False)
    return t


# ----------------------------------------------------------------------------------------------
# Analytic trajectories
# ----------------------------------------------------------------------------------------------


class LinearTrajectory(Trajectory):
    """Constant-velocity translation with a fixed orientation: ``p(t) = start + velocity t``.

    Immutable, like the dataclasses below; it is a plain class only because its constructor
    argument ``velocity`` would clash with the method :meth:`Trajectory.velocity` (the value is
    stored as ``linear_velocity``).

    Parameters
    ----------
    start : (3,) array_like, metres, world frame
        Camera centre at ``t = 0``.
    velocity : (3,) array_like, m/s, world frame
    rotation : (3, 3) array_like
        ``R_world_camera``, constant.

    Attributes
    ----------
    start : (3,) ndarray, metres
    linear_velocity : (3,) ndarray, m/s
    rotation : (3, 3) ndarray
    """

    def __init__(self, start: ArrayLike, velocity: ArrayLike, rotation: ArrayLike) -> None:
        object.__setattr__(self, "start", _vector(start, "start", 3))
        object.__setattr__(self, "linear_velocity", _vector(velocity, "velocity", 3))
        rotation = _rotations(rotation, "rotation")
        if rotation.shape != (3, 3):
            raise ValueError(f"rotation must be one (3, 3) matrix, got shape {rotation.shape}")
        rotation.setflags(write=False)
        object.__setattr__(self, "rotation", rotation)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"LinearTrajectory is immutable: cannot assign {name!r}")

    def __repr__(self) -> str:
        return (f"LinearTrajectory(start={self.start.tolist()}, "
                f"velocity={self.linear_velocity.tolist()}, rotation={self.rotation.tolist()})")

    def _poses(self, t: np.ndarray) -> np.ndarray:
        return make_pose(self.rotation, self.start + t[:, None] * self.linear_velocity)

    def _velocities(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.tile(self.linear_velocity, (len(t), 1)), np.zeros((len(t), 3))

    def _accelerations(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros((len(t), 3)), np.zeros((len(t), 3))


@dataclass(frozen=True, eq=False)
class HandheldTrajectory(Trajectory):
    """Smooth hand-held 6-DoF motion about a mean pose: sums of sines, optionally speeding up.

    With ``phase_i(t) = 2 pi f_i (t + chirp t^2 / 2) + phases_i`` (instantaneous frequency
    ``f_i (1 + chirp t)``), the offsets ``d(t) = translation_amplitude * sin(phase[:3])`` and
    ``r(t) = rotation_amplitude * sin(phase[3:])`` (camera axes of the mean pose) give
    ``p(t) = position + rotation @ d(t)`` and ``R(t) = rotation @ so3_exp(r(t))``. Velocities are
    analytic: the body angular velocity is ``J_r(r) dr/dt``.

    Attributes
    ----------
    rotation : (3, 3) ndarray
        Mean orientation ``R0`` (``R_world_camera``).
    position : (3,) ndarray, metres, world frame
        Mean camera centre ``p0``.
    translation_amplitude : (3,) ndarray, metres
        Along the x, y, z axes of the mean camera frame, >= 0.
    rotation_amplitude : (3,) ndarray, radians
        About the x, y, z axes of the mean camera frame, >= 0.
    frequencies : (6,) ndarray, Hz
        3 translation then 3 rotation components, >= 0.
    phases : (6,) ndarray, radians
    chirp : float, 1/s
        Relative frequency increase per second, >= 0 (0: stationary motion).
    """

    rotation: np.ndarray
    position: np.ndarray
    translation_amplitude: np.ndarray
    rotation_amplitude: np.ndarray
    frequencies: np.ndarray
    phases: np.ndarray
    chirp: float = 0.0

    __repr__ = summary_repr

    def __post_init__(self) -> None:
        rotation = _rotations(self.rotation, "rotation")
        if rotation.shape != (3, 3):
            raise ValueError(f"rotation must be one (3, 3) matrix, got shape {rotation.shape}")
        rotation.setflags(write=False)
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "position", _vector(self.position, "position", 3))
        for name in ("translation_amplitude", "rotation_amplitude"):
            object.__setattr__(self, name, _vector(getattr(self, name), name, 3, nonneg=True))
        object.__setattr__(self, "frequencies",
                           _vector(self.frequencies, "frequencies", 6, nonneg=True))
        object.__setattr__(self, "phases", _vector(self.phases, "phases", 6))
        object.__setattr__(self, "chirp", non_negative("chirp", self.chirp))

    def _phase(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tt = t[:, None]
        omega = 2.0 * np.pi * self.frequencies
        phase = omega * (tt + 0.5 * self.chirp * tt * tt) + self.phases
        rate = omega * (1.0 + self.chirp * tt)
        return phase, rate

    def _poses(self, t: np.ndarray) -> np.ndarray:
        phase, _ = self._phase(t)
        d = self.translation_amplitude * np.sin(phase[:, :3])
        r = self.rotation_amplitude * np.sin(phase[:, 3:])
        return make_pose(self.rotation @ so3_exp(r), self.position + d @ self.rotation.T)

    def _velocities(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        phase, rate = self._phase(t)
        d_dot = self.translation_amplitude * np.cos(phase[:, :3]) * rate[:, :3]
        r = self.rotation_amplitude * np.sin(phase[:, 3:])
        r_dot = self.rotation_amplitude * np.cos(phase[:, 3:]) * rate[:, 3:]
        w_body = (so3_right_jacobian(r) @ r_dot[:, :, None])[:, :, 0]
        R = self.rotation @ so3_exp(r)
        return d_dot @ self.rotation.T, (R @ w_body[:, :, None])[:, :, 0]

    def _accelerations(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        phase, rate = self._phase(t)
        rate_dot = 2.0 * np.pi * self.frequencies * self.chirp       # d(rate)/dt, constant
        sin, cos = np.sin(phase), np.cos(phase)
        second = -sin * rate * rate + cos * rate_dot                  # d^2 sin(phase) / dt^2
        d_ddot = self.translation_amplitude * second[:, :3]
        r = self.rotation_amplitude * sin[:, 3:]
        r_dot = self.rotation_amplitude * cos[:, 3:] * rate[:, 3:]
        r_ddot = self.rotation_amplitude * second[:, 3:]
        # w_body = J_r(r) r_dot, so alpha_body = J_r(r) r_ddot + (d/dt J_r(r)) r_dot, and the
        # world angular acceleration is R alpha_body (d/dt (R w_body) = R hat(w_b) w_b + R w_b').
        alpha_body = (so3_right_jacobian(r) @ r_ddot[:, :, None]
                      + so3_right_jacobian_rate(r, r_dot) @ r_dot[:, :, None])[:, :, 0]
        R = self.rotation @ so3_exp(r)
        return d_ddot @ self.rotation.T, (R @ alpha_body[:, :, None])[:, :, 0]


# ----------------------------------------------------------------------------------------------
# Keyframe spline
# ----------------------------------------------------------------------------------------------

# Newton refinement of the spline's control rotations (see SplineTrajectory).
_SPLINE_MAX_ITERATIONS = 50
_SPLINE_TOLERANCE = 1e-12
_SPLINE_FD_STEP = 1e-6


def _polyval(coeffs: np.ndarray, s: np.ndarray, derivative: int) -> np.ndarray:
    """Evaluate cubics ``sum_p coeffs[..., p] s^p`` (or their 1st/2nd derivative) at ``s``.

    ``coeffs`` is (N, K, 4) (powers 0..3) and ``s`` is (N,); returns (N, K).
    """
    s = s[:, None]
    c0, c1, c2, c3 = np.moveaxis(coeffs, -1, 0)
    if derivative == 0:
        return c0 + s * (c1 + s * (c2 + s * c3))
    if derivative == 1:
        return c1 + s * (2.0 * c2 + s * 3.0 * c3)
    return 2.0 * c2 + 6.0 * c3 * s


def _increments(control: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """Rotation vectors ``Omega_i`` of ``C_{i-1}^T C_i`` (i >= 1), (M, 3) with a zero row 0.

    Without ``reference`` the shortest ones (``|Omega_i| <= pi``); with it, for each i the
    rotation vector of the same rotation closest to ``reference[i]`` (``Omega_i + 2 pi k n``),
    so that increments vary continuously and may exceed pi.
    """
    out = np.zeros((len(control), 3))
    out[1:] = so3_log(np.swapaxes(control[:-1], -1, -2) @ control[1:])
    if reference is None:
        return out
    theta = np.linalg.norm(out, axis=-1)
    ref_norm = np.linalg.norm(reference, axis=-1)
    axis = np.where((theta > 1e-12)[:, None], out / np.maximum(theta, 1e-300)[:, None],
                    reference / np.maximum(ref_norm, 1e-300)[:, None])
    k = np.round((np.sum(reference * axis, axis=-1) - theta) / (2.0 * np.pi))
    return out + (2.0 * np.pi * k)[:, None] * axis


class _TimedTrajectory(Trajectory):
    """A trajectory defined over strictly increasing ``times`` (keyframes or samples)."""

    times: np.ndarray

    @property
    def t_start(self) -> float:
        """float, seconds: the first time."""
        return float(self.times[0])

    @property
    def t_end(self) -> float:
        """float, seconds: the last time."""
        return float(self.times[-1])

    def _store_samples(self) -> tuple[np.ndarray, np.ndarray]:
        """Validate ``times`` and ``poses``, store them read-only, and return them."""
        poses = _poses_array(self.poses, "poses")
        times = _keyframe_times(self.times, len(poses), "times")
        poses.setflags(write=False)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "poses", poses)
        return times, poses

    def _span(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Index j of the interval [times[j], times[j+1]] holding each t, and t - times[j]."""
        j = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2)
        return j, t - self.times[j]


@dataclass(frozen=True, eq=False)
class SplineTrajectory(_TimedTrajectory):
    """C2 cubic B-spline through keyframe poses, exactly interpolating them.

    Position: the natural cubic spline through the keyframe positions, written as a clamped
    cubic B-spline with knots at the keyframe times (``p(t) = sum_i B_i(t) c_i``, zero
    acceleration at both ends). Rotation: the cumulative cubic B-spline on SO(3) of Kim, Kim and
    Shin (1995), ``R(t) = C_0 prod_i exp(Btilde_i(t) Omega_i)`` where ``Omega_i`` is a rotation
    vector of ``C_{i-1}^T C_i`` and the basis is the same (``Btilde_i = sum_{j >= i} B_j``); it is
    C2 because the basis is. The control rotations ``C_i`` are solved for (Newton's method from
    the keyframes' shortest turns, misfit < 1e-12 rad) so that ``R(t_k)`` equals every keyframe
    rotation and the angular acceleration is zero at both ends, the analogue of the natural
    spline. ``Omega_i`` is kept continuous during the solve, so it may exceed pi when the camera
    turns fast; between consecutive keyframes the camera turns the short way, so a turn near
    180 deg between two keyframes is ambiguous and needs a keyframe in between.

    Velocities are analytic: ``v = sum_i B_i'(t) c_i`` and, in a span whose increments are
    ``Omega_1..3`` with factors ``A_k = exp(Btilde_k Omega_k)``, the body angular velocity is
    ``A_3^T A_2^T Btilde_1' Omega_1 + A_3^T Btilde_2' Omega_2 + Btilde_3' Omega_3``.
    Accelerations are analytic too: ``a = sum_i B_i''(t) c_i`` and the body angular acceleration
    is the exact time derivative of that sum (with ``d/dt A_k^T = -hat(Btilde_k' Omega_k)
    A_k^T``, as in Sommer et al., "Efficient Derivative Computation for Cumulative B-Splines on
    Lie Groups", CVPR 2020); both are continuous (C2 spline).

    Attributes
    ----------
    times : (N,) ndarray, seconds
        Keyframe times, strictly increasing, ``N >= 2``.
    poses : (N, 4, 4) ndarray
        Keyframe ``T_world_camera``.

    Raises
    ------
    ValueError
        For invalid keyframes, or keyframe rotations so far apart that no rotation spline is
        found (add keyframes in between).
    """

    times: np.ndarray
    poses: np.ndarray

    __repr__ = summary_repr

    def __post_init__(self) -> None:
        times, poses = self._store_samples()
        n = len(times)
        m = n + 2
        knots = np.concatenate([[times[0]] * 3, times, [times[-1]] * 3])
        basis = BSpline(knots, np.eye(m), 3)  # all m basis functions; right-continuous
        # Per-span polynomial coefficients (powers 0..3 of t - times[j]) of the 4 active basis
        # functions B_j..B_{j+3}, from the right-hand derivatives at the span's start.
        spans = np.arange(n - 1)
        active = spans[:, None] + np.arange(4)
        coeffs = np.stack(
            [basis(times[:-1], nu)[spans[:, None], active] / math.factorial(nu)
             for nu in range(4)],
            axis=-1,
        )  # (n - 1, 4 basis, 4 powers)
        cumulative = np.cumsum(coeffs[:, ::-1], axis=1)[:, ::-1][:, 1:]  # Btilde_{j+1..j+3}
        object.__setattr__(self, "_basis", coeffs)
        object.__setattr__(self, "_cumulative", cumulative)
        # Interpolation system: B(t_k) c = y_k for every keyframe, natural ends B''(t) c = 0.
        second = basis(times[[0, -1]], 2)
        system = np.concatenate([basis(times), second])
        rhs = np.concatenate([poses[:, :3, 3], np.zeros((2, 3))])
        object.__setattr__(self, "_points", np.linalg.solve(system, rhs))
        # Natural ends in cumulative form: sum_i Btilde_i'' Omega_i = 0, Btilde_i'' = sum_j>=i.
        object.__setattr__(self, "_end_rows", np.cumsum(second[:, ::-1], axis=1)[:, ::-1])
        control, increments = self._fit_rotations(knots)
        object.__setattr__(self, "_control", control)
        object.__setattr__(self, "_increments", increments)

    # ---- construction ------------------------------------------------------------------------
    def _residual(self, control: np.ndarray, increments: np.ndarray) -> np.ndarray:
        """(M, 3) misfit of control rotations: keyframe rotations (body frame), then the ends."""
        curve, _ = self._rotation_factors(control, increments, self.times, derivative=False)
        keys = so3_log(np.swapaxes(curve, -1, -2) @ self.poses[:, :3, :3])
        return np.concatenate([keys, self._end_rows @ increments])

    def _fit_rotations(self, knots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Control rotations (M, 3, 3) and their increments (M, 3) (Newton's method)."""
        times, n = self.times, len(self.times)
        m = n + 2
        # Start: the keyframes' geodesic interpolation at the Greville abscissae (where each
        # control point "sits" in time).
        greville = (knots[1:m + 1] + knots[2:m + 2] + knots[3:m + 3]) / 3.0
        j = np.clip(np.searchsorted(times, greville, side="right") - 1, 0, n - 2)
        s = (greville - times[j]) / (times[j + 1] - times[j])
        control = interpolate_pose(self.poses[j], self.poses[j + 1], s)[:, :3, :3]
        increments = _increments(control)
        # Every residual row depends on at most 4 consecutive control rotations (rows of
        # keyframe k: the controls of its span; the end rows: the first / last 3), so a
        # finite-difference Jacobian needs 4 colours x 3 axes x 2 evaluations. Increments are
        # kept continuous (they may exceed pi when the camera turns fast between keyframes).
        first = np.concatenate([np.clip(np.arange(n), 0, n - 2), [0, m - 4]])
        rows = np.arange(m)
        residual = self._residual(control, increments)
        norm = np.abs(residual).max()
        h = _SPLINE_FD_STEP
        for _ in range(_SPLINE_MAX_ITERATIONS):
            if norm < _SPLINE_TOLERANCE:
                return control, increments
            entries, row_index, col_index = [], [], []
            for colour in range(4):
                col = first + (colour - first) % 4  # the control of this colour in each row
                valid = col < m
                for axis in range(3):
                    step = np.zeros((m, 3))
                    step[colour::4, axis] = h
                    diff = []
                    for sign in (1.0, -1.0):
                        moved = control @ so3_exp(sign * step)
                        diff.append(self._residual(moved, _increments(moved, increments)))
                    entries.append(((diff[0] - diff[1]) / (2 * h))[valid].ravel())
                    row_index.append((3 * rows[valid, None] + np.arange(3)).ravel())
                    col_index.append(np.repeat(3 * col[valid] + axis, 3))
            jac = sparse.csc_matrix(
                (np.concatenate(entries), (np.concatenate(row_index), np.concatenate(col_index))),
                shape=(3 * m, 3 * m),
            )
            delta = spsolve(jac, -residual.ravel()).reshape(m, 3)
            # Backtrack if the full Newton step does not reduce the misfit.
            for _ in range(30):
                trial = control @ so3_exp(delta)
                trial_increments = _increments(trial, increments)
                trial_residual = self._residual(trial, trial_increments)
                trial_norm = np.abs(trial_residual).max()
                if trial_norm < norm:
                    break
                delta = 0.5 * delta
            else:
                break
            control, increments = trial, trial_increments
            residual, norm = trial_residual, trial_norm
        if norm < _SPLINE_TOLERANCE:
            return control, increments
        R = self.poses[:, :3, :3]
        turns = np.linalg.norm(so3_log(np.swapaxes(R[:-1], -1, -2) @ R[1:]), axis=-1)
        raise ValueError(
            "could not fit a rotation spline through the keyframes (misfit "
            f"{norm:.2g} rad; turns between consecutive keyframes up to "
            f"{np.degrees(turns.max()):.1f} deg); expected smaller turns between keyframes: "
            "add keyframes in between"
        )

    # ---- evaluation --------------------------------------------------------------------------
    def _rotation_factors(self, control: np.ndarray, increments: np.ndarray, t: np.ndarray,
                          derivative: bool, second: bool = False
                          ) -> tuple[np.ndarray, np.ndarray | None]:
        """Rotations (N, 3, 3) and, if ``derivative``, body angular velocities (N, 3), or with
        ``second`` too, body angular accelerations (N, 3) instead."""
        j, s = self._span(t)
        b = _polyval(self._cumulative[j], s, 0)  # (N, 3)
        omega = increments[j[:, None] + np.arange(1, 4)]  # (N, 3 increments, 3)
        A = so3_exp(b[:, :, None] * omega)  # (N, 3, 3, 3)
        R = control[j] @ A[:, 0] @ A[:, 1] @ A[:, 2]
        if not derivative:
            return R, None
        u = _polyval(self._cumulative[j], s, 1)[:, :, None] * omega  # Btilde_k' Omega_k
        A2t, A3t = np.swapaxes(A[:, 1], -1, -2), np.swapaxes(A[:, 2], -1, -2)
        y = (A2t @ u[:, 0, :, None])[:, :, 0] + u[:, 1]   # w_body = A3^T y + u_3
        if not second:
            return R, (A3t @ y[:, :, None])[:, :, 0] + u[:, 2]
        # d/dt A_k^T = -hat(u_k) A_k^T, so with u_k' = Btilde_k'' Omega_k:
        # y' = -u_2 x (A2^T u_1) + A2^T u_1' + u_2', w_body' = -u_3 x (A3^T y) + A3^T y' + u_3'.
        u_dot = _polyval(self._cumulative[j], s, 2)[:, :, None] * omega
        a2u1 = (A2t @ u[:, 0, :, None])[:, :, 0]
        y_dot = (-np.cross(u[:, 1], a2u1) + (A2t @ u_dot[:, 0, :, None])[:, :, 0]
                 + u_dot[:, 1])
        a3y = (A3t @ y[:, :, None])[:, :, 0]
        return R, -np.cross(u[:, 2], a3y) + (A3t @ y_dot[:, :, None])[:, :, 0] + u_dot[:, 2]

    def _positions(self, t: np.ndarray, derivative: int) -> np.ndarray:
        j, s = self._span(t)
        weights = _polyval(self._basis[j], s, derivative)  # (N, 4)
        points = self._points[j[:, None] + np.arange(4)]  # (N, 4, 3)
        return np.einsum("nk,nkd->nd", weights, points)

    def _poses(self, t: np.ndarray) -> np.ndarray:
        R, _ = self._rotation_factors(self._control, self._increments, t, derivative=False)
        return make_pose(R, self._positions(t, 0))

    def _velocities(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, w_body = self._rotation_factors(self._control, self._increments, t, derivative=True)
        return self._positions(t, 1), (R @ w_body[:, :, None])[:, :, 0]

    def _accelerations(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, alpha_body = self._rotation_factors(self._control, self._increments, t,
                                               derivative=True, second=True)
        return self._positions(t, 2), (R @ alpha_body[:, :, None])[:, :, 0]


# ----------------------------------------------------------------------------------------------
# Sampled poses
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SampledTrajectory(_TimedTrajectory):
    """Poses sampled at given times (e.g. motion capture), interpolated geodesically in SE(3).

    Between samples ``k`` and ``k + 1`` the pose is
    ``interpolate_pose(T_k, T_k+1, (t - t_k) / (t_k+1 - t_k))``: constant body twist
    ``xi_k / dt_k`` with ``xi_k = se3_log(inv(T_k) T_k+1) = (rho_k, phi_k)``. The velocity is that
    segment's twist: ``v = R(t) rho_k / dt_k`` and ``w = R(t) phi_k / dt_k`` (world frame), so it
    is piecewise constant in the camera frame and jumps at the samples; at a sample time the
    segment that starts there is used (the last segment at the last sample). The acceleration
    is the exact derivative of this interpolant inside a segment: ``a = R(t) (w_b x v_b)`` with
    the segment's body twist ``(v_b, w_b) = (rho_k, phi_k) / dt_k`` (the velocity turns with the
    camera) and zero angular acceleration; the jumps of velocity at the samples (impulses) are
    not in it, so an IMU integrated over a sampled trajectory drifts from its samples.

    Attributes
    ----------
    times : (N,) ndarray, seconds
        Strictly increasing, ``N >= 2``.
    poses : (N, 4, 4) ndarray
        ``T_world_camera`` at those times.
    """

    times: np.ndarray
    poses: np.ndarray

    __repr__ = summary_repr

    def __post_init__(self) -> None:
        times, poses = self._store_samples()
        twists = se3_log(invert_pose(poses[:-1]) @ poses[1:])
        object.__setattr__(self, "_twists", twists)
        object.__setattr__(self, "_rates", twists / np.diff(times)[:, None])

    def _segment(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        j, dt = self._span(t)
        return j, dt / (self.times[j + 1] - self.times[j])

    def _poses(self, t: np.ndarray) -> np.ndarray:
        j, s = self._segment(t)
        return self.poses[j] @ se3_exp(s[:, None] * self._twists[j])

    def _velocities(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        j, _ = self._segment(t)
        R = self._poses(t)[:, :3, :3]
        rate = self._rates[j]
        return (R @ rate[:, :3, None])[:, :, 0], (R @ rate[:, 3:, None])[:, :, 0]

    def _accelerations(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Constant body twist (v_b, w_b) in the segment: dR/dt = R hat(w_b), so
        # a = d(R v_b)/dt = R (w_b x v_b), and dw/dt = d(R w_b)/dt = R (w_b x w_b) = 0.
        j, _ = self._segment(t)
        R = self._poses(t)[:, :3, :3]
        rate = self._rates[j]
        a_body = np.cross(rate[:, 3:], rate[:, :3])
        return (R @ a_body[:, :, None])[:, :, 0], np.zeros((len(t), 3))


# ----------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------

_TRAJECTORY_FORMAT = "'t px py pz qx qy qz qw' (8 numbers)"
TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"
MAX_POSITION_M = 1e9
"""Largest position coordinate :func:`read_trajectory` accepts, metres: far beyond any Earth-fixed
frame (ECEF ~6.4e6 m, UTM northings ~1e7 m); beyond it the relative motions between poses, which
the interpolation works on, lose every digit (and overflow near 1e154)."""


def read_trajectory(path: str | Path) -> SampledTrajectory:
    """Read ECD ``groundtruth.txt`` or a TUM trajectory: ``t px py pz qx qy qz qw`` per line.

    Blank lines and lines starting with ``#`` are skipped. Quaternions are scalar last and are
    normalised. Times may be large Unix timestamps (kept as float64 seconds).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    SampledTrajectory
        ``T_world_camera`` at the file's times.

    Raises
    ------
    ValueError
        ``"{path}:{line}: ..."`` for a wrong number of columns, a non-number, a non-finite value,
        a zero quaternion or a time not after the previous one; ``"{path}: ..."`` for fewer than
        2 poses.
    """
    path = Path(path)
    times: list[float] = []
    rows: list[list[float]] = []
    previous_line = 0
    for lineno, fields, values in numeric_rows(path, 8, _TRAJECTORY_FORMAT):
        if not any(values[4:]):
            raise ValueError(
                f"{path}:{lineno}: the quaternion (qx, qy, qz, qw) is zero; "
                "expected a non-zero (normally unit) quaternion"
            )
        far = next((name for name, v in zip("xyz", values[1:4], strict=True)
                    if abs(v) > MAX_POSITION_M), None)
        if far is not None:
            raise ValueError(
                f"{path}:{lineno}: position p{far} = {fields[1 + 'xyz'.index(far)]} is beyond "
                f"{MAX_POSITION_M:g} m; expected positions in metres"
            )
        # Scaled by its largest component before quat_to_rot normalises it, so that a quaternion
        # written at any scale (1e200 or 1e-200, whose squares overflow or vanish) keeps its
        # direction.
        quaternion = values[4:]
        largest = max(abs(v) for v in quaternion)
        values[4:] = [v / largest for v in quaternion]
        if times and values[0] <= times[-1]:
            raise ValueError(
                f"{path}:{lineno}: time {fields[0]} is not after {times[-1]!r} (line "
                f"{previous_line}); expected strictly increasing times"
            )
        times.append(values[0])
        rows.append(values[1:])
        previous_line = lineno
    if len(times) < 2:
        raise ValueError(f"{path}: found {len(times)} pose(s); expected at least 2 lines "
                         f"{_TRAJECTORY_FORMAT}")
    data = np.array(rows)
    poses = make_pose(quat_to_rot(data[:, 3:]), data[:, :3])
    return SampledTrajectory(np.array(times), poses)


def write_trajectory(
    path: str | Path, times: ArrayLike, poses: ArrayLike, format: str = "ecd"
) -> None:
    """Write poses as ECD ``groundtruth.txt`` or TUM: ``t px py pz qx qy qz qw`` per line.

    Times are written with 9 decimals (nanoseconds), positions and quaternions (scalar last,
    ``qw >= 0``) at full float precision, so :func:`read_trajectory` gives back the poses to
    1e-9.

    Parameters
    ----------
    path : str or Path
    times : (N,) array_like, seconds
        Strictly increasing (also after rounding to nanoseconds).
    poses : (N, 4, 4) array_like
        ``T_world_camera``.
    format : {"ecd", "tum"}
        ``"tum"`` adds the header line ``# timestamp tx ty tz qx qy qz qw``.
    """
    if format not in ("ecd", "tum"):
        raise ValueError(f"format must be 'ecd' or 'tum', got {format!r}")
    poses = _poses_array(poses, "poses")
    times = _keyframe_times(times, len(poses), "times")
    if np.any(np.diff(np.round(times, 9)) <= 0):
        raise ValueError("times must stay strictly increasing at nanosecond resolution "
                         "(9 decimals), got two times closer than 1 ns")
    quats = rot_to_quat(poses[:, :3, :3])
    lines = [TUM_HEADER] if format == "tum" else []
    for t, T, q in zip(times, poses, quats, strict=True):
        values = (*T[:3, 3], *q)
        lines.append(f"{t:.9f} " + " ".join(repr(float(v)) for v in values))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def sample_times(t0: float, t1: float, rate: float) -> np.ndarray:
    """Uniform grid from ``t0`` to ``t1`` inclusive, at ``rate`` Hz or slightly more.

    Parameters
    ----------
    t0, t1 : float, seconds
        ``t1 >= t0``; both are in the grid.
    rate : float, Hz
        Minimum sampling rate: the step is ``(t1 - t0) / ceil((t1 - t0) rate)`` <= ``1 / rate``.

    Returns
    -------
    (M,) float64 ndarray, seconds
        ``M = ceil((t1 - t0) rate) + 1`` (``[t0]`` when ``t1 == t0``).
    """
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 >= t0):
        raise ValueError(f"expected finite times with t1 >= t0, got t0={t0!r}, t1={t1!r}")
    rate = positive("rate", rate)
    # The 1e-9 guards against (t1 - t0) * rate landing just above an integer by rounding.
    steps = math.ceil((t1 - t0) * rate - 1e-9)
    if steps <= 0:
        return np.array([float(t0)])
    return np.linspace(t0, t1, steps + 1)


class TimeScaledTrajectory(Trajectory):
    """Another trajectory played ``scale`` times as fast about ``t = 0``: the same path, each
    pose reached at ``t / scale``; velocities scale by ``scale``, accelerations by ``scale**2``
    (exact: the chain rule on ``pose(scale t)``).

    Parameters
    ----------
    base : Trajectory
        The trajectory to replay.
    scale : float
        Speed factor, > 0 (2: twice as fast, over half the time range).
    """

    def __init__(self, base: Trajectory, scale: float) -> None:
        if not isinstance(base, Trajectory):
            raise ValueError(f"TimeScaledTrajectory.base must be a Trajectory, got {base!r}")
        self.base = base
        self.scale = positive("TimeScaledTrajectory.scale", scale)

    def __repr__(self) -> str:
        return f"TimeScaledTrajectory({self.base!r}, scale={self.scale!r})"

    @property
    def t_start(self) -> float:
        """float, seconds: the base's first valid time divided by ``scale``."""
        return self.base.t_start / self.scale

    @property
    def t_end(self) -> float:
        """float, seconds: the base's last valid time divided by ``scale``."""
        return self.base.t_end / self.scale

    def _base_times(self, t: np.ndarray) -> np.ndarray:
        # Rounding may put scale * t a hair outside the base's range at its ends.
        return np.clip(self.scale * t, self.base.t_start, self.base.t_end)

    def _poses(self, t: np.ndarray) -> np.ndarray:
        return self.base._poses(self._base_times(t))

    def _velocities(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v, w = self.base._velocities(self._base_times(t))
        return self.scale * v, self.scale * w

    def _accelerations(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a, alpha = self.base._accelerations(self._base_times(t))
        return self.scale ** 2 * a, self.scale ** 2 * alpha
