"""A Mitsuba sensor that follows evfuse's camera model exactly.

Mitsuba's built-in ``perspective`` sensor has square pixels only (fx == fy), so evfuse registers
its own sensor, ``evfuse_pinhole``: an OpenCV pinhole camera (fx != fy allowed, principal point
anywhere, optional radial-tangential distortion) whose ray for film position (u, v) passes
through pixel (u, v) of the model, with the centre of pixel (0, 0) at (0.0, 0.0). Its frame is
OpenCV's (x right, y down, z forward) and its pose is ``T_world_camera``, given as the parameters
``R`` (3x3) and ``t`` (3,) so that one loaded scene is re-rendered for many poses without
recompiling. Rays start at the camera centre (not on a near plane).

With the property ``rows = true`` (a rolling shutter) every image row ``r`` has its own pose
instead, the parameter ``row_pose``: a flat array of ``12 H`` floats, row ``r``'s rotation
(row-major, 9 values) then its position (3 values), and every sample of that row's pixels
(whatever its sub-pixel position) leaves from that pose. JIT variants only.
"""

from __future__ import annotations

__all__ = ["SENSOR_PLUGIN", "register_sensor"]

SENSOR_PLUGIN = "evfuse_pinhole"
UNDISTORT_ITERATIONS = 20

_registered: str | None = None


def register_sensor() -> None:
    """Register the ``evfuse_pinhole`` sensor with the active Mitsuba variant (idempotent)."""
    global _registered
    import drjit as dr
    import mitsuba as mi

    if _registered == mi.variant():
        return

    class PinholeSensor(mi.Sensor):
        """OpenCV pinhole (+ radial-tangential distortion) sensor; see the module docstring."""

        def __init__(self, props):
            super().__init__(props)
            self.fx, self.fy = props.get("fx"), props.get("fy")
            self.cx, self.cy = props.get("cx"), props.get("cy")
            self.k = [props.get(name, 0.0) for name in ("k1", "k2", "p1", "p2", "k3")]
            self.distorted = any(c != 0.0 for c in self.k)
            size = self.film().size()
            self.width, self.height = int(size[0]), int(size[1])
            self.R = mi.Matrix3f(1, 0, 0, 0, 1, 0, 0, 0, 1)
            self.t = mi.Point3f(0.0, 0.0, 0.0)
            dr.make_opaque(self.R, self.t)
            self.rows = bool(props.get("rows", False))
            if self.rows:
                identity = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0, 0, 0, 0] * self.height
                self.row_pose = mi.Float(identity)
                dr.make_opaque(self.row_pose)

        def traverse(self, callback):
            callback.put("R", self.R, mi.ParamFlags.NonDifferentiable)
            callback.put("t", self.t, mi.ParamFlags.NonDifferentiable)
            if self.rows:
                callback.put("row_pose", self.row_pose, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys=None):
            dr.make_opaque(self.R, self.t)
            if self.rows:
                dr.make_opaque(self.row_pose)

        def _undistort(self, xd, yd):
            # Fixed-point inversion of the distortion, as OpenCV's undistortPoints does.
            k1, k2, p1, p2, k3 = self.k
            x, y = xd, yd
            for _ in range(UNDISTORT_ITERATIONS):
                r2 = x * x + y * y
                inv = dr.rcp(1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
                dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
                dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
                x, y = (xd - dx) * inv, (yd - dy) * inv
            return x, y

        def _pinhole(self, position_sample):
            # Film position in [0, 1]^2 -> continuous pixel coordinate; pixel i spans
            # [i, i + 1) on the film, its centre is at i + 0.5, i.e. at u = i in our convention.
            u = position_sample.x * self.width - 0.5
            v = position_sample.y * self.height - 0.5
            x = (u - self.cx) / self.fx
            y = (v - self.cy) / self.fy
            if self.distorted:
                x, y = self._undistort(x, y)
            if self.rows:
                R, t = self._row_pose(position_sample.y)
            else:
                R, t = self.R, self.t
            return x, y, R, t

        def sample_ray(self, time, wavelength_sample, position_sample, aperture_sample,
                       active=True):
            x, y, R, t = self._pinhole(position_sample)
            ray = mi.Ray3f(t, dr.normalize(R @ mi.Vector3f(x, y, 1.0)))
            ray.time = time
            return ray, mi.Spectrum(1.0)

        def _row_pose(self, film_y):
            # The row a film position lies in (pixel row r spans [r, r + 1) / H), its pose.
            row = dr.clip(mi.Int32(dr.floor(film_y * self.height)), 0, self.height - 1)
            values = [dr.gather(mi.Float, self.row_pose, row * 12 + k) for k in range(12)]
            return mi.Matrix3f(*values[:9]), mi.Point3f(*values[9:])

        def sample_ray_differential(self, time, wavelength_sample, position_sample,
                                    aperture_sample, active=True):
            x, y, R, t = self._pinhole(position_sample)
            ray = mi.RayDifferential3f(mi.Ray3f(t, dr.normalize(R @ mi.Vector3f(x, y, 1.0))))
            ray.time = time
            # The pinhole rays one pixel right and down: the footprint of filtered textures
            # (sim.textures; distortion's change of the pixel's size left out).
            ray.o_x = ray.o_y = t
            ray.d_x = dr.normalize(R @ mi.Vector3f(x + 1.0 / self.fx, y, 1.0))
            ray.d_y = dr.normalize(R @ mi.Vector3f(x, y + 1.0 / self.fy, 1.0))
            ray.has_differentials = True
            return ray, mi.Spectrum(1.0)

        def to_string(self):
            return (f"PinholeSensor[fx={self.fx}, fy={self.fy}, cx={self.cx}, cy={self.cy}, "
                    f"distortion={self.k}]")

    mi.register_sensor(SENSOR_PLUGIN, lambda props: PinholeSensor(props))
    _registered = mi.variant()
