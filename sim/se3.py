"""Rotations and rigid transforms: SO(3) and SE(3) in NumPy, float64.

Conventions (CONVENTIONS.md):

- A rotation vector ``w`` (3,) in radians has direction = axis and norm = angle; ``so3_exp`` maps
  it to a rotation matrix and ``so3_log`` back (angle in [0, pi]).
- A pose is a (4, 4) homogeneous matrix ``T_a_b`` mapping coordinates in frame b to frame a;
  the camera's pose is ``T_world_camera``.
- A twist ``xi = (rho, phi)`` (6,) is translation part first, rotation part last; ``se3_exp``
  maps it to a pose with the right-handed convention ``T = [[exp(phi), J_l(phi) rho], [0, 1]]``.
- Quaternions are ``(qx, qy, qz, qw)``, scalar LAST, as in ECD ``groundtruth.txt`` and TUM.
- Camera frame: OpenCV's (x right, y down, z forward).

Every function accepts leading batch axes where noted and returns float64 arrays.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "hat",
    "interpolate_pose",
    "invert_pose",
    "look_at",
    "make_pose",
    "quat_to_rot",
    "rot_to_quat",
    "rotation_from_euler",
    "se3_exp",
    "se3_log",
    "so3_exp",
    "so3_left_jacobian",
    "so3_log",
    "so3_right_jacobian",
    "so3_right_jacobian_rate",
    "vee",
]

# Below this angle (rad) the Jacobian coefficients use their Taylor series (error < 1e-16).
_SMALL_ANGLE = 0.1
# Above pi minus this angle (rad) so3_log takes the axis from the symmetric part of R.
_NEAR_PI = 1e-2


def _vectors(x: ArrayLike, name: str, size: int = 3) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim < 1 or arr.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}), got shape {arr.shape}")
    return arr


def _matrices(x: ArrayLike, name: str, size: int) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[-2:] != (size, size):
        raise ValueError(f"{name} must have shape (..., {size}, {size}), got shape {arr.shape}")
    return arr


def hat(w: ArrayLike) -> np.ndarray:
    """Skew-symmetric matrix of a vector: ``hat(w) @ v == cross(w, v)``.

    Parameters
    ----------
    w : (..., 3) array_like

    Returns
    -------
    (..., 3, 3) float64 ndarray
    """
    w = _vectors(w, "w")
    out = np.zeros(w.shape + (3,), dtype=np.float64)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    out[..., 0, 1], out[..., 0, 2] = -z, y
    out[..., 1, 0], out[..., 1, 2] = z, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


def vee(m: ArrayLike) -> np.ndarray:
    """Inverse of :func:`hat`: the vector of the antisymmetric part of ``m``.

    Parameters
    ----------
    m : (..., 3, 3) array_like

    Returns
    -------
    (..., 3) float64 ndarray
        ``vee(hat(w)) == w``; for a non-skew ``m`` the result is ``vee((m - m^T) / 2)``.
    """
    m = _matrices(m, "m", 3)
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
        axis=-1,
    )


def _exp_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``sin t / t``, ``(1 - cos t) / t^2`` and ``(t - sin t) / t^3``, without cancellation."""
    a = np.sinc(theta / np.pi)
    b = 0.5 * np.sinc(theta / (2.0 * np.pi)) ** 2
    t2 = theta * theta
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    c = np.where(
        small,
        1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2 * t2 * t2 / 362880.0,
        (safe - np.sin(safe)) / safe**3,
    )
    return a, b, c


def so3_exp(w: ArrayLike) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues' formula, exact for tiny angles).

    Parameters
    ----------
    w : (..., 3) array_like, radians
        Axis times angle.

    Returns
    -------
    (..., 3, 3) float64 ndarray
        ``R = I + sin(t)/t hat(w) + (1 - cos t)/t^2 hat(w)^2`` with ``t = |w|``.
    """
    w = _vectors(w, "w")
    theta = np.linalg.norm(w, axis=-1)
    a, b, _ = _exp_coefficients(theta)
    k = hat(w)
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def so3_log(R: ArrayLike) -> np.ndarray:
    """Rotation vector of a rotation matrix, stable near 0 and near pi.

    Parameters
    ----------
    R : (..., 3, 3) array_like
        Rotation matrices (orthonormal, det +1).

    Returns
    -------
    (..., 3) float64 ndarray, radians
        ``w`` with ``|w|`` in [0, pi] and ``so3_exp(w) == R``. At exactly pi both ``w`` and
        ``-w`` are valid; the one returned is unspecified.

    Notes
    -----
    The angle is ``atan2(|vee(R - R^T)| / 2, (tr R - 1) / 2)``, accurate at every angle. The axis
    comes from the antisymmetric part, except within 1e-2 rad of pi where it is taken from the
    symmetric part ``(R + R^T) / 2 - cos(t) I = (1 - cos t) n n^T`` (largest column), with the
    sign of the antisymmetric part.
    """
    R = _matrices(R, "R", 3)
    v = vee(R)
    s = np.linalg.norm(v, axis=-1)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    theta = np.arctan2(s, c)
    # General case: w = theta / sin(theta) * vee(R).
    ratio = np.where(s > 0.0, theta / np.where(s > 0.0, s, 1.0), 1.0)
    w = ratio[..., None] * v
    near_pi = theta > np.pi - _NEAR_PI
    if np.any(near_pi):
        Rn, cn, vn, tn = R[near_pi], c[near_pi], v[near_pi], theta[near_pi]
        B = 0.5 * (Rn + np.swapaxes(Rn, -1, -2)) - cn[:, None, None] * np.eye(3)
        i = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        n = np.take_along_axis(B, i[:, None, None], axis=-1)[..., 0]
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        sign = np.where(np.sum(n * vn, axis=-1) < 0.0, -1.0, 1.0)
        w[near_pi] = (sign * tn)[:, None] * n
    return w


def so3_right_jacobian(w: ArrayLike) -> np.ndarray:
    """Right Jacobian of SO(3): ``exp(w + d) ~= exp(w) exp(J_r(w) d)`` for small ``d``.

    It maps the rate of a rotation vector to the body angular velocity:
    ``R(t) = exp(w(t))`` has ``R^T dR/dt = hat(J_r(w) dw/dt)``.

    Parameters
    ----------
    w : (..., 3) array_like, radians

    Returns
    -------
    (..., 3, 3) float64 ndarray
        ``I - (1 - cos t)/t^2 hat(w) + (t - sin t)/t^3 hat(w)^2``.
    """
    w = _vectors(w, "w")
    _, b, c = _exp_coefficients(np.linalg.norm(w, axis=-1))
    k = hat(w)
    return np.eye(3) - b[..., None, None] * k + c[..., None, None] * (k @ k)


def so3_right_jacobian_rate(w: ArrayLike, w_dot: ArrayLike) -> np.ndarray:
    """Time derivative of :func:`so3_right_jacobian` along a path ``w(t)`` with rate ``w_dot``.

    With ``J_r = I - b(t) K + c(t) K^2`` (``K = hat(w)``, ``t = |w|``, ``b, c`` as in
    :func:`so3_right_jacobian`) and ``dt/dt = w . w_dot / t``:
    ``dJ_r = -(b'/t)(w . w_dot) K - b hat(w_dot) + (c'/t)(w . w_dot) K^2
    + c (hat(w_dot) K + K hat(w_dot))``. It gives the body angular acceleration of
    ``R(t) = exp(w(t))``: ``J_r(w) w_ddot + dJ_r w_dot``.

    Parameters
    ----------
    w : (..., 3) array_like, radians
    w_dot : (..., 3) array_like, rad/s

    Returns
    -------
    (..., 3, 3) float64 ndarray, 1/s

    Notes
    -----
    ``b'/t`` and ``c'/t`` are taken from their Taylor series below :data:`_SMALL_ANGLE` (terms
    to ``t^6``; the first omitted one is below 1e-16 there), where the closed forms cancel.
    """
    w = _vectors(w, "w")
    w_dot = _vectors(w_dot, "w_dot")
    theta = np.linalg.norm(w, axis=-1)
    t2 = theta * theta
    _, b, c = _exp_coefficients(theta)
    small = theta < _SMALL_ANGLE
    s = np.where(small, 1.0, theta)
    half = np.sin(s / 2)
    db = np.where(small, -1 / 12 + t2 / 180 - t2 * t2 / 6720 + t2 ** 3 / 453600,
                  np.sin(s) / s ** 3 - 4.0 * half * half / s ** 4)
    dc = np.where(small, -1 / 60 + t2 / 1260 - t2 * t2 / 60480 + t2 ** 3 / 4989600,
                  2.0 * half * half / s ** 4 - 3.0 * (s - np.sin(s)) / s ** 5)
    dot = np.sum(w * w_dot, axis=-1)[..., None, None]
    k, kd = hat(w), hat(w_dot)
    return (-db[..., None, None] * dot * k - b[..., None, None] * kd
            + dc[..., None, None] * dot * (k @ k) + c[..., None, None] * (kd @ k + k @ kd))


def so3_left_jacobian(w: ArrayLike) -> np.ndarray:
    """Left Jacobian of SO(3): ``J_l(w) = J_r(-w) = R J_r(w)``, used by :func:`se3_exp`.

    Parameters
    ----------
    w : (..., 3) array_like, radians

    Returns
    -------
    (..., 3, 3) float64 ndarray
        ``I + (1 - cos t)/t^2 hat(w) + (t - sin t)/t^3 hat(w)^2``.
    """
    return so3_right_jacobian(-np.asarray(w, dtype=np.float64))


def _left_jacobian_inverse(w: np.ndarray) -> np.ndarray:
    """``J_l(w)^-1 = I - hat(w)/2 + (1/t^2 - cot(t/2)/(2t)) hat(w)^2`` for ``t`` in [0, pi]."""
    theta = np.linalg.norm(w, axis=-1)
    t2 = theta * theta
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    d = np.where(
        small,
        1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0 + t2 * t2 * t2 / 1209600.0,
        1.0 / safe**2 - np.cos(safe / 2) / (2.0 * safe * np.sin(safe / 2)),
    )
    k = hat(w)
    return np.eye(3) - 0.5 * k + d[..., None, None] * (k @ k)


def quat_to_rot(q: ArrayLike) -> np.ndarray:
    """Rotation matrix of a quaternion given scalar LAST, ``(qx, qy, qz, qw)``.

    Parameters
    ----------
    q : (..., 4) array_like
        Any non-zero finite quaternion; it is normalised first. ``q`` and ``-q`` give the same R.

    Returns
    -------
    (..., 3, 3) float64 ndarray

    Raises
    ------
    ValueError
        If a quaternion is zero or not finite.
    """
    q = _vectors(q, "q", 4)
    norm = np.linalg.norm(q, axis=-1)
    if not np.all(np.isfinite(q)):
        raise ValueError("quaternion must be finite (qx, qy, qz, qw), got a NaN or inf")
    if np.any(norm == 0.0):
        raise ValueError("quaternion must be non-zero (qx, qy, qz, qw), got (0, 0, 0, 0)")
    x, y, z, w = np.moveaxis(q / norm[..., None], -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def rot_to_quat(R: ArrayLike) -> np.ndarray:
    """Unit quaternion ``(qx, qy, qz, qw)`` (scalar LAST, ``qw >= 0``) of a rotation matrix.

    Parameters
    ----------
    R : (..., 3, 3) array_like
        Rotation matrices.

    Returns
    -------
    (..., 4) float64 ndarray
        Computed by Shepperd's method (from the largest of ``qw, qx, qy, qz``), then the sign is
        chosen so that ``qw >= 0``.
    """
    R = _matrices(R, "R", 3)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    # 4 q_i^2 for (x, y, z, w), from the diagonal.
    squares = np.stack([1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22, 1 + tr], -1)
    best = np.argmax(squares, axis=-1)
    d21 = R[..., 2, 1] - R[..., 1, 2]
    d02 = R[..., 0, 2] - R[..., 2, 0]
    d10 = R[..., 1, 0] - R[..., 0, 1]
    s01 = R[..., 0, 1] + R[..., 1, 0]
    s02 = R[..., 0, 2] + R[..., 2, 0]
    s12 = R[..., 1, 2] + R[..., 2, 1]
    # Each candidate is 4 q_i q (i = the largest component), valid whenever its square is large.
    candidates = np.stack(
        [
            np.stack([squares[..., 0], s01, s02, d21], -1),
            np.stack([s01, squares[..., 1], s12, d02], -1),
            np.stack([s02, s12, squares[..., 2], d10], -1),
            np.stack([d21, d02, d10, squares[..., 3]], -1),
        ],
        axis=-2,
    )
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def make_pose(R: ArrayLike, t: ArrayLike) -> np.ndarray:
    """Homogeneous transform from a rotation and a translation.

    Parameters
    ----------
    R : (..., 3, 3) array_like
    t : (..., 3) array_like, metres
        Batch axes of ``R`` and ``t`` broadcast together.

    Returns
    -------
    (..., 4, 4) float64 ndarray
        ``[[R, t], [0, 0, 0, 1]]``.
    """
    R = _matrices(R, "R", 3)
    t = _vectors(t, "t")
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(batch + (4, 4), dtype=np.float64)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_pose(T: ArrayLike) -> np.ndarray:
    """Inverse of a rigid transform, ``[[R^T, -R^T t], [0, 1]]``.

    Parameters
    ----------
    T : (..., 4, 4) array_like

    Returns
    -------
    (..., 4, 4) float64 ndarray
    """
    T = _matrices(T, "T", 4)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_pose(Rt, -(Rt @ T[..., :3, 3:4])[..., 0])


def se3_exp(xi: ArrayLike) -> np.ndarray:
    """Pose of a twist ``xi = (rho, phi)``: ``[[so3_exp(phi), J_l(phi) rho], [0, 1]]``.

    Parameters
    ----------
    xi : (..., 6) array_like
        ``rho`` (metres, first 3) and ``phi`` (radians, last 3).

    Returns
    -------
    (..., 4, 4) float64 ndarray
    """
    xi = _vectors(xi, "xi", 6)
    rho, phi = xi[..., :3], xi[..., 3:]
    t = (so3_left_jacobian(phi) @ rho[..., None])[..., 0]
    return make_pose(so3_exp(phi), t)


def se3_log(T: ArrayLike) -> np.ndarray:
    """Twist ``xi = (rho, phi)`` of a pose, the inverse of :func:`se3_exp` (``|phi| <= pi``).

    Parameters
    ----------
    T : (..., 4, 4) array_like

    Returns
    -------
    (..., 6) float64 ndarray
        ``rho`` (metres) then ``phi`` (radians).
    """
    T = _matrices(T, "T", 4)
    phi = so3_log(T[..., :3, :3])
    rho = (_left_jacobian_inverse(phi) @ T[..., :3, 3:4])[..., 0]
    return np.concatenate([rho, phi], axis=-1)


def interpolate_pose(T0: ArrayLike, T1: ArrayLike, s: ArrayLike) -> np.ndarray:
    """Geodesic interpolation in SE(3): ``T0 @ se3_exp(s * se3_log(inv(T0) @ T1))``.

    The camera moves with a constant body twist (constant speed along a screw): ``s = 0`` gives
    ``T0``, ``s = 1`` gives ``T1`` and equal steps of ``s`` give equal relative motions.

    Parameters
    ----------
    T0, T1 : (..., 4, 4) array_like
        End poses.
    s : float or (N,) array_like
        Fractions (any real; outside [0, 1] extrapolates). Broadcast against the batch axes of
        ``T0`` and ``T1``.

    Returns
    -------
    (4, 4) or (N, 4, 4) float64 ndarray
    """
    T0 = _matrices(T0, "T0", 4)
    T1 = _matrices(T1, "T1", 4)
    s = np.asarray(s, dtype=np.float64)
    delta = se3_log(invert_pose(T0) @ T1)
    return T0 @ se3_exp(s[..., None] * delta)


def rotation_from_euler(deg: ArrayLike) -> np.ndarray:
    """Rotation from Euler angles in DEGREES, extrinsic X then Y then Z: ``R = Rz @ Ry @ Rx``.

    Parameters
    ----------
    deg : (3,) array_like, degrees
        Angles about the fixed x, y and z axes, applied in that order.

    Returns
    -------
    (3, 3) float64 ndarray
    """
    deg = np.asarray(deg, dtype=np.float64)
    if deg.shape != (3,) or not np.all(np.isfinite(deg)):
        raise ValueError(f"Euler angles must be 3 finite numbers in degrees, got {deg.tolist()}")
    rx, ry, rz = np.radians(deg)
    return so3_exp([0.0, 0.0, rz]) @ so3_exp([0.0, ry, 0.0]) @ so3_exp([rx, 0.0, 0.0])


def look_at(
    position: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)
) -> np.ndarray:
    """Orientation ``R_world_camera`` of an OpenCV camera at ``position`` looking at ``target``.

    Camera axes (the columns of R, in world coordinates): z = unit(target - position) (forward),
    x = unit(z x up) (right), y = z x x (down). World ``up`` therefore appears UP in the image
    (towards negative v) and the image is not rolled.

    Parameters
    ----------
    position, target : (3,) array_like, metres, world frame
    up : (3,) array_like, world frame
        Any vector not parallel to the view direction (default +z).

    Returns
    -------
    (3, 3) float64 ndarray
        Rotation whose columns are the camera's x, y, z axes in the world.

    Raises
    ------
    ValueError
        If ``target == position``, ``up`` is zero, or ``up`` is parallel to the view direction.
    """
    position = np.asarray(position, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    for name, v in (("position", position), ("target", target), ("up", up)):
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"look_at {name} must be 3 finite numbers, got {v.tolist()}")
    forward = target - position
    distance = np.linalg.norm(forward)
    if distance <= 1e-12 * max(1.0, np.linalg.norm(position)):
        raise ValueError(
            f"look_at target {target.tolist()} equals the position {position.tolist()}; "
            "expected a target away from the camera"
        )
    if np.linalg.norm(up) == 0.0:
        raise ValueError("look_at up must be a non-zero vector, got [0, 0, 0]")
    z = forward / distance
    x = np.cross(z, up / np.linalg.norm(up))
    norm = np.linalg.norm(x)
    if norm < 1e-9:
        raise ValueError(
            f"look_at up {up.tolist()} is parallel to the view direction {z.tolist()}; "
            "expected an up vector not parallel to target - position"
        )
    x /= norm
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)
