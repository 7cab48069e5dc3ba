"""The camera model: OpenCV pinhole with radial-tangential distortion, presets, ``calib.txt``.

Conventions (CONVENTIONS.md): camera frame x right, y down, z forward; pixel ``(u, v)`` =
(column, row) with the centre of pixel (0, 0) at (0.0, 0.0). A camera-frame point (X, Y, Z) has
normalised coordinates ``x = X/Z, y = Y/Z``; OpenCV's distortion (k1, k2, p1, p2, k3) maps them to
``(x_d, y_d)`` and the pixel is ``u = fx x_d + cx, v = fy y_d + cy``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from numbers import Integral, Real
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from sim.textfile import parse_floats, text_lines

__all__ = [
    "CAMERA_PRESETS",
    "Camera",
    "camera_preset",
    "read_calib",
    "write_calib",
]

# Fixed-point iterations of `Camera.undistort` (it stops earlier once converged) and the
# accuracy it must reach in normalised coordinates, below which a point is not invertible.
UNDISTORT_MAX_ITERATIONS = 200
UNDISTORT_TOLERANCE = 1e-12


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with OpenCV's radial-tangential distortion.

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    fx, fy : float, pixels
        Focal lengths (``fx != fy`` allowed).
    cx, cy : float, pixels
        Principal point, with the centre of pixel (0, 0) at (0.0, 0.0).
    distortion : tuple of 5 float
        ``(k1, k2, p1, p2, k3)``, OpenCV's order; all zero for an ideal pinhole.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Integral) or value <= 0:
                raise ValueError(f"camera {name} must be a positive integer, got {value!r}")
            object.__setattr__(self, name, int(value))
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value):
                raise ValueError(f"camera {name} must be a finite number of pixels, got {value!r}")
            object.__setattr__(self, name, float(value))
        for name in ("fx", "fy"):
            if getattr(self, name) <= 0.0:
                raise ValueError(
                    f"camera {name} must be a positive focal length in pixels, "
                    f"got {getattr(self, name)!r}"
                )
        try:
            coeffs = tuple(float(c) for c in self.distortion)
        except (TypeError, ValueError):
            raise ValueError(
                "camera distortion must be 5 numbers (k1, k2, p1, p2, k3), "
                f"got {self.distortion!r}"
            ) from None
        if len(coeffs) != 5 or not all(math.isfinite(c) for c in coeffs):
            raise ValueError(
                "camera distortion must be 5 finite numbers (k1, k2, p1, p2, k3), "
                f"got {self.distortion!r}"
            )
        object.__setattr__(self, "distortion", coeffs)

    # ------------------------------------------------------------------------------------
    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 ndarray: intrinsic matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        """bool: whether any distortion coefficient is non-zero."""
        return any(c != 0.0 for c in self.distortion)

    @property
    def resolution(self) -> tuple[int, int]:
        """(int, int): ``(width, height)`` in pixels."""
        return (self.width, self.height)

    # ------------------------------------------------------------------------------------
    def distort(self, xy: ArrayLike) -> np.ndarray:
        """Apply the lens distortion to normalised coordinates (OpenCV's model).

        Parameters
        ----------
        xy : (N, 2) array_like
            Undistorted normalised coordinates ``(X/Z, Y/Z)``.

        Returns
        -------
        (N, 2) float64 ndarray
            ``x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)`` and
            ``y_d = y (1 + ...) + p1 (r^2 + 2 y^2) + 2 p2 x y``, ``r^2 = x^2 + y^2``.
        """
        xy = _points(xy, "xy", 2)
        return _distort(xy, self.distortion)

    def undistort(self, xy_d: ArrayLike) -> np.ndarray:
        """Invert :meth:`distort` by fixed-point iteration, as OpenCV's ``undistortPoints``.

        Iterates ``x <- (x_d - tangential(x)) / radial(x)`` until the step is below 1e-15 or
        for at most 200 iterations. The iteration converges where the distortion is invertible
        (inside the radius where it folds back), fast for typical lenses: 26 iterations reach
        1e-15 over the whole DAVIS240C image with its real distortion (k1 = -0.37), where
        OpenCV's default of 5 iterations is off by up to 2e-4.

        Parameters
        ----------
        xy_d : (N, 2) array_like
            Distorted normalised coordinates ``((u - cx)/fx, (v - cy)/fy)``.

        Returns
        -------
        (N, 2) float64 ndarray
            Undistorted normalised coordinates; NaN where the iteration did not reach
            ``|distort(x) - x_d| <= 1e-12`` (a point outside the lens model's invertible range).
        """
        xy_d = _points(xy_d, "xy_d", 2)
        if not self.has_distortion:
            return xy_d.copy()
        return _undistort(xy_d, self.distortion)

    def project(self, points: ArrayLike) -> np.ndarray:
        """Pixel coordinates of camera-frame points (distortion included).

        Parameters
        ----------
        points : (N, 3) array_like, metres, camera frame

        Returns
        -------
        (N, 2) float64 ndarray, pixels
            ``(u, v)``; NaN for points with ``Z <= 0`` (at or behind the camera centre).
        """
        points = _points(points, "points", 3)
        z = points[..., 2:3]
        ahead = z > 0.0
        xy = np.where(ahead, points[..., :2] / np.where(ahead, z, 1.0), np.nan)
        xy_d = _distort(xy, self.distortion) if self.has_distortion else xy
        return xy_d * [self.fx, self.fy] + [self.cx, self.cy]

    def backproject(self, uv: ArrayLike, depth: ArrayLike) -> np.ndarray:
        """Camera-frame points at the given z-depth through the given pixels (undistorting).

        Parameters
        ----------
        uv : (N, 2) array_like, pixels
        depth : (N,) array_like, metres
            z-depth (the Z coordinate, not the distance along the ray).

        Returns
        -------
        (N, 3) float64 ndarray, metres, camera frame
        """
        uv = _points(uv, "uv", 2)
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != uv.shape[:-1]:
            raise ValueError(
                f"depth must have one value per pixel, shape {uv.shape[:-1]}, got {depth.shape}"
            )
        xy = self.undistort((uv - [self.cx, self.cy]) / [self.fx, self.fy])
        return np.concatenate([xy, np.ones_like(depth)[..., None]], axis=-1) * depth[..., None]

    def pixel_centres(self) -> np.ndarray:
        """(u, v) of every pixel centre.

        Returns
        -------
        (H, W, 2) float64 ndarray, pixels
            ``[v, u] == (u, v)``: column then row index.
        """
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64),
                           np.arange(self.height, dtype=np.float64))
        return np.stack([u, v], axis=-1)

    def normalized_pixel_centres(self) -> np.ndarray:
        """Undistorted normalised coordinates of the ray through every pixel centre.

        Returns
        -------
        (H, W, 2) float64 ndarray
            ``(X/Z, Y/Z)`` of the points that project onto each pixel centre (NaN where the
            distortion cannot be inverted; never for an undistorted camera). Read-only: the
            last few cameras' are kept, since every filling method asks for them.
        """
        return _normalized_pixel_centres(self)

    def in_image(self, uv: ArrayLike) -> np.ndarray:
        """Whether pixel coordinates fall on the sensor.

        Pixel ``(i, j)`` covers ``[i - 0.5, i + 0.5) x [j - 0.5, j + 0.5)``, so the image is
        ``-0.5 <= u < width - 0.5`` and ``-0.5 <= v < height - 0.5``.

        Parameters
        ----------
        uv : (N, 2) array_like, pixels

        Returns
        -------
        (N,) bool ndarray
            False for NaN coordinates.
        """
        uv = _points(uv, "uv", 2)
        u, v = uv[..., 0], uv[..., 1]
        return (u >= -0.5) & (u < self.width - 0.5) & (v >= -0.5) & (v < self.height - 0.5)

    def with_resolution(self, width: int, height: int) -> Camera:
        """The same camera resampled to another image size (same field of view).

        ``fx, cx`` scale with ``s = width / self.width`` and ``fy, cy`` with
        ``height / self.height``; with pixel centres at integers, ``cx' = (cx + 0.5) s - 0.5``.
        The distortion acts on normalised coordinates and is unchanged.

        Parameters
        ----------
        width, height : int
            New image size in pixels.

        Returns
        -------
        Camera
        """
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, Integral) or value <= 0:
                raise ValueError(
                    f"with_resolution {name} must be a positive integer, got {value!r}"
                )
        sx, sy = width / self.width, height / self.height
        return replace(self, width=int(width), height=int(height),
                       fx=self.fx * sx, fy=self.fy * sy,
                       cx=(self.cx + 0.5) * sx - 0.5, cy=(self.cy + 0.5) * sy - 0.5)


@functools.lru_cache(maxsize=8)
def _normalized_pixel_centres(camera: Camera) -> np.ndarray:
    xy_d = (camera.pixel_centres() - [camera.cx, camera.cy]) / [camera.fx, camera.fy]
    xy = camera.undistort(xy_d.reshape(-1, 2)).reshape(camera.height, camera.width, 2)
    xy.setflags(write=False)
    return xy


def _points(x: ArrayLike, name: str, size: int) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim < 1 or arr.shape[-1] != size:
        raise ValueError(f"{name} must have shape (N, {size}), got shape {arr.shape}")
    return arr


def _distort(xy: np.ndarray, coeffs: tuple[float, ...]) -> np.ndarray:
    k1, k2, p1, p2, k3 = coeffs
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def _undistort(xy_d: np.ndarray, coeffs: tuple[float, ...]) -> np.ndarray:
    k1, k2, p1, p2, k3 = coeffs
    xd, yd = xy_d[..., 0], xy_d[..., 1]
    x, y = xd.copy(), yd.copy()
    with np.errstate(all="ignore"):
        for _ in range(UNDISTORT_MAX_ITERATIONS):
            r2 = x * x + y * y
            inv = 1.0 / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x_new, y_new = (xd - dx) * inv, (yd - dy) * inv
            step = np.nanmax(np.abs(np.concatenate([(x_new - x).ravel(), (y_new - y).ravel()])),
                             initial=0.0)
            x, y = x_new, y_new
            if step < 1e-15:
                break
        xy = np.stack([x, y], axis=-1)
        residual = np.max(np.abs(_distort(xy, coeffs) - xy_d), axis=-1)
    xy[~(residual <= UNDISTORT_TOLERANCE)] = np.nan
    return xy


# ----------------------------------------------------------------------------------------------
# Presets
# ----------------------------------------------------------------------------------------------

_DAVIS240C_F = 199.092366542


def _wide(width: int, height: int) -> Camera:
    f = _DAVIS240C_F * width / 240.0
    return Camera(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)


CAMERA_PRESETS: dict[str, Camera] = {
    # DAVIS240C of the Event-Camera Dataset (its calib.txt of e.g. shapes_*, poster_*), without
    # its distortion (-0.3684, 0.1509, -0.0003, -0.0008, 0): the simulator renders an ideal,
    # undistorted DAVIS by default. Give `distortion` explicitly for the real lens.
    "davis240c": Camera(240, 180, 199.092366542, 198.82882047, 132.192071378, 110.712660011),
    # Left DAVIS346 of MVSEC (indoor_flying calibration), without distortion.
    "davis346": Camera(346, 260, 226.38018519795807, 226.15002947047415,
                       173.6470807871759, 133.73271487507847),
    # The DAVIS240C's horizontal field of view at larger sizes, square pixels, centred.
    "vga": _wide(640, 480),
    "hd": _wide(1280, 720),
}


def camera_preset(name: str) -> Camera:
    """A named camera from :data:`CAMERA_PRESETS`.

    Presets: ``davis240c`` (240x180, ECD's DAVIS240C intrinsics, rendered WITHOUT distortion),
    ``davis346`` (346x260, MVSEC's left DAVIS346 intrinsics, no distortion), ``vga`` (640x480)
    and ``hd`` (1280x720) with the DAVIS240C's horizontal field of view
    (``fx = fy = 199.092366542 W / 240``) and the principal point at the image centre.

    Parameters
    ----------
    name : str

    Returns
    -------
    Camera

    Raises
    ------
    ValueError
        For an unknown name; the message lists the valid ones.
    """
    try:
        return CAMERA_PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown camera preset {name!r}; expected one of {', '.join(sorted(CAMERA_PRESETS))}"
        ) from None


# ----------------------------------------------------------------------------------------------
# calib.txt
# ----------------------------------------------------------------------------------------------

_CALIB_FORMAT = "'fx fy cx cy [k1 k2 p1 p2 [k3]]' (4, 8 or 9 numbers)"


def read_calib(path: str | Path, width: int, height: int) -> Camera:
    """Read an ECD ``calib.txt``: one line ``fx fy cx cy [k1 k2 p1 p2 [k3]]``.

    Parameters
    ----------
    path : str or Path
    width, height : int
        Image size in pixels (``calib.txt`` does not store it).

    Returns
    -------
    Camera
        Missing distortion coefficients are 0 (4 numbers: none; 8 numbers: k3 = 0).

    Raises
    ------
    ValueError
        ``"{path}:{line}: ..."`` for a line with the wrong count of numbers, a non-number, a
        non-finite value, invalid intrinsics or a second non-empty line; ``"{path}: ..."`` for a
        file without any non-empty line.
    """
    path = Path(path)
    found: tuple[int, list[str]] | None = None
    for lineno, line in text_lines(path):
        fields = line.split()
        if not fields:
            continue
        if found is not None:
            raise ValueError(
                f"{path}:{lineno}: unexpected second non-empty line (the first is line "
                f"{found[0]}); expected exactly one line {_CALIB_FORMAT}"
            )
        found = (lineno, fields)
    if found is None:
        raise ValueError(f"{path}: file has no non-empty line; expected one line {_CALIB_FORMAT}")
    lineno, fields = found
    if len(fields) not in (4, 8, 9):
        raise ValueError(f"{path}:{lineno}: expected {_CALIB_FORMAT}, got {len(fields)} fields")
    values = parse_floats(fields, path, lineno, _CALIB_FORMAT)
    values += [0.0] * (9 - len(values))
    try:
        return Camera(width, height, *values[:4], distortion=tuple(values[4:]))
    except ValueError as exc:
        raise ValueError(f"{path}:{lineno}: {exc}") from None


def write_calib(path: str | Path, camera: Camera) -> None:
    """Write ``calib.txt``: one line ``fx fy cx cy k1 k2 p1 p2 k3`` at full float precision.

    Parameters
    ----------
    path : str or Path
    camera : Camera
        Its image size is not stored (ECD's format has no place for it).
    """
    values = (camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion)
    Path(path).write_text(" ".join(repr(float(v)) for v in values) + "\n", encoding="utf-8")
