"""Exact optical flow, motion field and object masks of the standard camera's frames.

All three come from the exact depth of a frame (one ray per pixel centre, see
:mod:`sim.render`), the true camera poses, and each object's own rigid motion; nothing is
estimated from images.

- **Optical flow** between consecutive frames: pixel ``p`` of frame ``k`` sees the surface point
  ``P = z (x, y, 1)`` (``(x, y)`` the undistorted ray of the pixel centre, ``z`` its depth). The
  point is carried to the time of frame ``j = k +- 1`` (fixed in the world, or with the object
  it lies on: ``X_j = O(t_j) O(t_k)^-1 X_k`` for the object's pose ``O``), expressed in camera
  ``j`` and projected with the lens distortion. The flow is ``uv_j - p`` in pixels of the real
  (distorted) image. Flags: :data:`NO_SURFACE` (the ray of ``p`` hits nothing),
  :data:`OUT_OF_VIEW` (the point lands off the sensor, behind camera ``j`` or beyond the radius
  where the lens's radial distortion folds back), :data:`OCCLUDED` (it lands on the sensor but
  frame ``j`` sees something nearer there, see :func:`occluded`).
- **Motion field** at each frame time: ``d(u, v)/dt`` in pixels per second, distortion
  included, from the camera's twist and each object's (:meth:`sim.scene.ObjectMotion.twist`),
  analytically: ``dP/dt = R^T (dX/dt - v - w x (X - c))`` in the camera frame, through the
  projection's Jacobian.
- **Object masks**: which object each pixel centre's ray hits first
  (:meth:`sim.render.Renderer.object_ids`; 0 = none, ``i`` = ``scene.objects[i - 1]``).

Files (written by :func:`write_motion_ground_truth` into a sequence folder; indexes in the
``t[s] relpath`` form of ``depthmaps.txt``, on the frames' clock):

- ``flow_forward.txt``, ``flow/forward_%08d.exr``: frame ``k`` -> ``k + 1`` for every frame but
  the last; ``flow_backward.txt``, ``flow/backward_%08d.exr``: ``k`` -> ``k - 1`` for every frame
  but the first. The time of a line is frame ``k``'s. EXR channels ``du``, ``dv`` (float32,
  pixels) and ``flags`` (small integers stored as float32). Read with :func:`read_flow`.
- ``motionfield.txt``, ``motion/frame_%08d.exr``: channels ``du_dt``, ``dv_dt`` (float32,
  pixels per second). Read with :func:`read_motion_field`.
- ``masks.txt``, ``masks/frame_%08d.png``: 16-bit PNG. Read with :func:`read_object_mask`.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numba
import numpy as np

from sim._atomic import atomic_file, write_bytes_atomically
from sim.camera import Camera
from sim.exr import read_depth, read_exr_channels, write_exr_channels
from sim.scene import Scene, SceneObject
from sim.sequence import FLOW_INDEXES, write_index

__all__ = ["BACKWARD_INDEX", "FORWARD_INDEX", "MASK_INDEX", "MOTION_INDEX", "NO_SURFACE",
           "OCCLUDED", "OCCLUSION_RTOL", "OUT_OF_VIEW", "motion_field", "occluded",
           "optical_flow", "read_flow", "read_motion_field", "read_object_mask",
           "surface_points", "transport", "write_motion_ground_truth"]

NO_SURFACE = 1
"""Flag bit: the pixel's ray hits nothing (flow 0)."""
OUT_OF_VIEW = 2
"""Flag bit: the point lands off the sensor (flow kept), or behind the camera or beyond the
lens model's range (flow 0)."""
OCCLUDED = 4
"""Flag bit: the point lands on the sensor but the target frame sees something nearer there."""
OCCLUSION_RTOL = 0.005
"""Relative depth margin of :func:`occluded`."""

FORWARD_INDEX = FLOW_INDEXES["forward_flow"]
BACKWARD_INDEX = FLOW_INDEXES["backward_flow"]
MOTION_INDEX = FLOW_INDEXES["motion_field"]
MASK_INDEX = FLOW_INDEXES["object_masks"]
_FLOW_CHANNELS = ("du", "dv", "flags")
_MOTION_CHANNELS = ("du_dt", "dv_dt")


# --- geometry ------------------------------------------------------------------------------------

def surface_points(centres: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Camera-frame points seen at the pixel centres.

    Parameters
    ----------
    centres : (H, W, 2) float64 ndarray
        ``camera.normalized_pixel_centres()``: undistorted ``(X/Z, Y/Z)`` of each pixel's ray.
    depth : (H, W) float ndarray, metres, 0 where nothing is hit

    Returns
    -------
    (H, W, 3) float64 ndarray, metres, camera frame
        ``z (x, y, 1)``; NaN where the depth is 0 or the ray is undefined.
    """
    z = np.where(depth > 0, depth, np.nan).astype(np.float64)
    return np.concatenate([centres, np.ones_like(z)[..., None]], axis=-1) * z[..., None]


def _object_groups(objects: tuple[SceneObject, ...], ids: np.ndarray):
    """``(mask, object)`` for every moving object seen, ``(rest, None)`` for the static rest."""
    rest = np.ones(ids.shape, dtype=bool)
    groups = []
    for i, obj in enumerate(objects):
        if obj.motion is None:
            continue
        mask = ids == i + 1
        if mask.any():
            groups.append((mask, obj))
            rest &= ~mask
    return [(rest, None), *groups]


def transport(points: np.ndarray, ids: np.ndarray, objects: tuple[SceneObject, ...],
              pose_src: np.ndarray, t_src: float, pose_dst: np.ndarray, t_dst: float
              ) -> np.ndarray:
    """Carry the points seen at ``t_src`` to where they are at ``t_dst``, in camera ``dst``.

    Parameters
    ----------
    points : (H, W, 3) float64 ndarray, metres, frame of camera ``src``
    ids : (H, W) uint16 ndarray
        Object of each point (0 none, ``i`` for ``objects[i - 1]``); points on a moving object
        move rigidly with it, the others stay fixed in the world.
    objects : tuple of SceneObject
    pose_src, pose_dst : (4, 4) ndarray
        ``T_world_camera`` at ``t_src`` and ``t_dst``.
    t_src, t_dst : float, seconds

    Returns
    -------
    (H, W, 3) float64 ndarray, metres, frame of camera ``dst``
    """
    out = np.empty_like(points)
    world_to_dst = np.linalg.inv(pose_dst)
    for mask, obj in _object_groups(objects, ids):
        moved = world_to_dst @ pose_src
        if obj is not None:
            moved = world_to_dst @ obj.pose(t_dst) @ np.linalg.inv(obj.pose(t_src)) @ pose_src
        out[mask] = points[mask] @ moved[:3, :3].T + moved[:3, 3]
    return out


def _fold_radius2(camera: Camera) -> float:
    """Largest r^2 = x^2 + y^2 up to which the radial distortion r (1 + k1 r^2 + k2 r^4 +
    k3 r^6) still grows with r (inf where it never folds back)."""
    k1, k2, _, _, k3 = camera.distortion
    roots = np.roots([7 * k3, 5 * k2, 3 * k1, 1.0]) if any((k1, k2, k3)) else []
    positive = [r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
    return min(positive, default=np.inf)


def _project(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of camera-frame points, and whether the lens model holds there (in front of the
    camera, inside the fold radius); NaN where it does not."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r2 = (points[..., 0] ** 2 + points[..., 1] ** 2) / points[..., 2] ** 2
        valid = (points[..., 2] > 0) & (r2 < _fold_radius2(camera))
    uv = camera.project(np.where(valid[..., None], points, np.nan))
    return uv, valid


def occluded(uv: np.ndarray, z: np.ndarray, depth_dst: np.ndarray,
             rtol: float = OCCLUSION_RTOL) -> np.ndarray:
    """Whether points that land on the sensor are hidden in the target frame.

    A point at z-depth ``z`` landing at ``uv`` is occluded when each of the four pixel centres
    around ``uv`` sees a surface nearer than ``z / (1 + rtol)`` (a centre that sees nothing
    counts as far). A visible point is never flagged: the z-depth of a plane over one pixel
    square is at most its largest corner value (1/z is affine in the undistorted image), so
    ``rtol`` only has to cover float32 depth and the lens's curvature over one pixel. Within one
    pixel of an occluder's outline in the target frame a hidden point may count as visible.

    Parameters
    ----------
    uv : (H, W, 2) float64 ndarray, pixels of the target frame (on the sensor)
    z : (H, W) float64 ndarray, metres, z-depth of the points in the target camera
    depth_dst : (H, W) float32 ndarray, metres, the target frame's exact depth, 0 = none
    rtol : float
        Relative depth margin (default :data:`OCCLUSION_RTOL`).

    Returns
    -------
    (H, W) bool ndarray
        False where ``uv`` is NaN.
    """
    height, width = depth_dst.shape
    far = np.where(depth_dst > 0, depth_dst, np.inf)
    finite = np.isfinite(uv).all(axis=-1)
    u = np.where(finite, uv[..., 0], 0.0)
    v = np.where(finite, uv[..., 1], 0.0)
    u0 = np.clip(np.floor(u).astype(np.int64), 0, width - 1)
    v0 = np.clip(np.floor(v).astype(np.int64), 0, height - 1)
    u1, v1 = np.minimum(u0 + 1, width - 1), np.minimum(v0 + 1, height - 1)
    nearest_far = np.maximum.reduce([far[v0, u0], far[v0, u1], far[v1, u0], far[v1, u1]])
    with np.errstate(invalid="ignore"):
        return finite & (z > (1.0 + rtol) * nearest_far)


def optical_flow(camera: Camera, depth_src: np.ndarray, ids_src: np.ndarray,
                 depth_dst: np.ndarray, objects: tuple[SceneObject, ...],
                 pose_src: np.ndarray, t_src: float, pose_dst: np.ndarray, t_dst: float,
                 centres: np.ndarray | None = None, rtol: float = OCCLUSION_RTOL
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Exact optical flow from frame ``src`` to frame ``dst`` (see the module's notes).

    Parameters
    ----------
    camera : Camera
    depth_src : (H, W) float32 ndarray, metres, 0 = none
        Exact z-depth of frame ``src``.
    ids_src : (H, W) uint16 ndarray
        Object mask of frame ``src`` (:meth:`sim.render.Renderer.object_ids`).
    depth_dst : (H, W) float32 ndarray, metres, 0 = none
        Exact z-depth of frame ``dst`` (for the occlusion flag).
    objects : tuple of SceneObject
        The scene's objects (moving ones carry their points).
    pose_src, pose_dst : (4, 4) ndarray, T_world_camera
    t_src, t_dst : float, seconds
    centres : (H, W, 2) ndarray, optional
        ``camera.normalized_pixel_centres()`` when the caller keeps it.
    rtol : float
        Relative depth margin of the occlusion test (:func:`occluded`).

    Returns
    -------
    flow : (H, W, 2) float32 ndarray, pixels
        ``(du, dv)``: where the pixel centre's surface point lands in frame ``dst``, minus the
        pixel centre; 0 where the point has no projection (:data:`NO_SURFACE`, or
        :data:`OUT_OF_VIEW` behind the camera or beyond the lens model).
    flags : (H, W) uint8 ndarray
        Bitwise OR of :data:`NO_SURFACE`, :data:`OUT_OF_VIEW`, :data:`OCCLUDED`; 0 = valid.
    """
    centres = camera.normalized_pixel_centres() if centres is None else centres
    points = surface_points(centres, depth_src)
    seen = np.isfinite(points).all(axis=-1)
    moved = transport(points, ids_src, objects, pose_src, t_src, pose_dst, t_dst)
    uv, valid = _project(camera, moved)
    return _flow_and_flags(camera, seen, moved, uv, valid & seen, depth_dst, rtol)


def _flow_and_flags(camera: Camera, seen: np.ndarray, moved: np.ndarray, uv: np.ndarray,
                    valid: np.ndarray, depth_dst: np.ndarray, rtol: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The flow and flags of points seen in the source frame (``seen``, (H, W)) that land at
    ``uv`` (H, W, 2) with camera-frame coordinates ``moved`` (H, W, 3) in the target frame,
    where the lens model holds (``valid``)."""
    in_view = valid & camera.in_image(uv)
    hidden = in_view & occluded(uv, moved[..., 2], depth_dst, rtol)
    flags = np.where(seen, 0, NO_SURFACE).astype(np.uint8)
    flags[seen & ~in_view] |= OUT_OF_VIEW
    flags[hidden] |= OCCLUDED
    flow = np.where(valid[..., None], uv - camera.pixel_centres(), 0.0)
    return flow.astype(np.float32), flags


ROLLING_TOLERANCE_PX = 1e-4
"""A rolling shutter's landing row is iterated until no point's row moves more than this."""
ROLLING_MAX_ITERATIONS = 12


@numba.njit(cache=True)
def _seen_from_rows(world: np.ndarray, row: np.ndarray, rotations: np.ndarray,
                    centres: np.ndarray) -> np.ndarray:
    """World points (N, 3) in the camera of (continuous) row ``row`` (N,): the blend of the
    poses (``rotations`` (H, 3, 3), ``centres`` (H, 3)) of the two rows around it, compiled."""
    height = rotations.shape[0]
    out = np.empty_like(world)
    for n in range(world.shape[0]):
        at = min(max(row[n], 0.0), height - 1.0)
        low = min(int(np.floor(at)), height - 1)
        high = min(low + 1, height - 1)
        b = at - low
        d0 = world[n, 0] - ((1.0 - b) * centres[low, 0] + b * centres[high, 0])
        d1 = world[n, 1] - ((1.0 - b) * centres[low, 1] + b * centres[high, 1])
        d2 = world[n, 2] - ((1.0 - b) * centres[low, 2] + b * centres[high, 2])
        for j in range(3):                               # R^T d, R blended between the rows
            out[n, j] = (((1.0 - b) * rotations[low, 0, j] + b * rotations[high, 0, j]) * d0
                         + ((1.0 - b) * rotations[low, 1, j] + b * rotations[high, 1, j]) * d1
                         + ((1.0 - b) * rotations[low, 2, j] + b * rotations[high, 2, j]) * d2)
    return out


def rolling_optical_flow(camera: Camera, depth_src: np.ndarray, depth_dst: np.ndarray,
                         trajectory, rows_src: np.ndarray, t_dst: float, readout_s: float,
                         centres: np.ndarray | None = None, rtol: float = OCCLUSION_RTOL
                         ) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`optical_flow` for a rolling shutter in a static scene: each row is seen at its
    own time, in the source frame and in the target frame.

    A pixel of row ``r`` of the source frame sees its point at ``rows_src[r]``, from the pose
    there. In the target frame the point is seen by the row it lands on, whose time depends on
    that row: the landing row ``v`` is iterated, ``v <- row of the point projected from the
    pose at t_dst + (v / (H - 1) - 0.5) readout_s``, from the middle row, until no point's row
    moves more than :data:`ROLLING_TOLERANCE_PX` (or :data:`ROLLING_MAX_ITERATIONS`; the
    iteration contracts by the rows the image moves per row of readout, far below 1). Rows are
    continuous here: a point between two rows' centres is seen at the time between theirs, from
    the blend of their poses (within a row's motion squared of the exact pose).

    Parameters
    ----------
    camera : Camera
    depth_src, depth_dst : (H, W) float32 ndarray, metres, 0 = none
        The frames' exact depth, each row at its own time.
    trajectory : sim.trajectory.Trajectory
        ``T_world_camera(t)`` of this camera.
    rows_src : (H,) float64 ndarray, seconds
        The source frame's row times.
    t_dst : float, seconds
        The target frame's (middle row's) time.
    readout_s : float, seconds
        From the first row to the last.
    centres, rtol :
        As for :func:`optical_flow`.

    Returns
    -------
    flow, flags :
        As :func:`optical_flow`'s.
    residual : float, pixels
        The last iteration's largest change of a landing row (0 when no point lands).
    """
    height = camera.height
    centres = camera.normalized_pixel_centres() if centres is None else centres
    points = surface_points(centres, depth_src)
    seen = np.isfinite(points).all(axis=-1)
    poses = trajectory.pose(np.asarray(rows_src, dtype=np.float64))
    world = (np.einsum("rij,rcj->rci", poses[:, :3, :3], points)
             + poses[:, None, :3, 3])[seen]
    # The target rows' poses, and between two rows' centres the linear blend of theirs: off
    # the exact pose by at most (w dt)^2 / 8 in rotation and (a dt^2) / 8 in position over a
    # row's time dt (1e-9 rad for 1 rad/s and 30 us), far below a pixel.
    targets = trajectory.pose(t_dst + (np.arange(height) / max(height - 1, 1) - 0.5)
                              * readout_s)
    row = np.full(len(world), (height - 1) / 2.0)
    residual = 0.0
    rotations = np.ascontiguousarray(targets[:, :3, :3])
    centres_w = np.ascontiguousarray(targets[:, :3, 3])
    for _ in range(ROLLING_MAX_ITERATIONS):
        local = _seen_from_rows(world, row, rotations, centres_w)
        uv, valid = _project(camera, local)
        landed = np.where(valid, uv[:, 1], row)
        residual = float(np.max(np.abs(landed - row), initial=0.0))
        row = landed
        if residual < ROLLING_TOLERANCE_PX:
            break
    moved = np.full(points.shape, np.nan)
    moved[seen] = local
    uv_all = np.full(points.shape[:2] + (2,), np.nan)
    uv_all[seen] = uv
    ok = np.zeros(seen.shape, dtype=bool)
    ok[seen] = valid
    return (*_flow_and_flags(camera, seen, moved, uv_all, ok, depth_dst, rtol), residual)


def _distortion_jacobian(xy: np.ndarray, coeffs: tuple[float, ...]) -> np.ndarray:
    """(..., 2, 2) d(x_d, y_d)/d(x, y) of OpenCV's radial-tangential distortion."""
    k1, k2, p1, p2, k3 = coeffs
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    slope = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)              # d radial / d r^2
    cross = 2.0 * x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y
    jac = np.empty(xy.shape[:-1] + (2, 2))
    jac[..., 0, 0] = radial + 2.0 * x * x * slope + 2.0 * p1 * y + 6.0 * p2 * x
    jac[..., 0, 1] = cross
    jac[..., 1, 0] = cross
    jac[..., 1, 1] = radial + 2.0 * y * y * slope + 6.0 * p1 * y + 2.0 * p2 * x
    return jac


def motion_field(camera: Camera, depth: np.ndarray, ids: np.ndarray,
                 objects: tuple[SceneObject, ...], pose: np.ndarray,
                 velocity: tuple[np.ndarray, np.ndarray], t: float,
                 centres: np.ndarray | None = None) -> np.ndarray:
    """Instantaneous image velocity of each pixel's surface point, distortion included.

    Parameters
    ----------
    camera : Camera
    depth : (H, W) float32 ndarray, metres, 0 = none
    ids : (H, W) uint16 ndarray
        Object mask (a point on a moving object moves with it).
    objects : tuple of SceneObject
    pose : (4, 4) ndarray
        ``T_world_camera`` at ``t``.
    velocity : ((3,), (3,)) ndarrays
        The camera's world-frame twist at ``t`` (:meth:`sim.trajectory.Trajectory.velocity`):
        velocity of its centre (m/s) and angular velocity (rad/s, ``dR/dt = hat(w) R``).
    t : float, seconds
    centres : (H, W, 2) ndarray, optional
        ``camera.normalized_pixel_centres()`` when the caller keeps it.

    Returns
    -------
    (H, W, 2) float32 ndarray, pixels per second
        ``(du/dt, dv/dt)`` in the real (distorted) image; 0 where nothing is seen.
    """
    centres = camera.normalized_pixel_centres() if centres is None else centres
    points = surface_points(centres, depth)
    rotation, centre = pose[:3, :3], pose[:3, 3]
    v_cam, w_cam = (np.asarray(a, dtype=np.float64) for a in velocity)
    world = points @ rotation.T + centre
    world_rate = np.zeros_like(world)                            # dX/dt of each point
    for mask, obj in _object_groups(objects, ids):
        if obj is not None:
            v_obj, w_obj = obj.motion.twist(t)
            world_rate[mask] = v_obj + np.cross(w_obj, world[mask] - obj.pose(t)[:3, 3])
    rate = (world_rate - v_cam - np.cross(w_cam, world - centre)) @ rotation   # R^T (...)
    z = points[..., 2]
    xy_rate = (rate[..., :2] - centres * rate[..., 2:3]) / z[..., None]
    if camera.has_distortion:
        jac = _distortion_jacobian(centres, camera.distortion)
        xy_rate = (jac @ xy_rate[..., None])[..., 0]
    field = xy_rate * [camera.fx, camera.fy]
    return np.where(np.isfinite(field), field, 0.0).astype(np.float32)


# --- files ----------------------------------------------------------------------------------------

def _names(kind: str, index: int, ext: str = "exr") -> str:
    folder, stem = {"forward": ("flow", "forward"), "backward": ("flow", "backward"),
                    "motion": ("motion", "frame"), "mask": ("masks", "frame")}[kind]
    return f"{folder}/{stem}_{index:08d}.{ext}"


def _write_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    with atomic_file(path) as partial:
        write_exr_channels(partial, channels)


def _write_flow(path: Path, flow: np.ndarray, flags: np.ndarray) -> None:
    _write_exr(path, {"du": flow[..., 0], "dv": flow[..., 1], "flags": flags})


def _write_mask(path: Path, ids: np.ndarray) -> None:
    ok, png = cv2.imencode(".png", ids.astype(np.uint16))
    if not ok:
        raise OSError(f"cannot encode {path} as PNG")
    write_bytes_atomically(path, png.tobytes())


def write_motion_ground_truth(scene: Scene, renderer, folder: Path, times: np.ndarray,
                              depth_names: list[str], clock_offset: float = 0.0,
                              readout_s: float = 0.0) -> dict:
    """Write the flows, motion fields and object masks of every frame (see the module's notes).

    Parameters
    ----------
    scene : Scene
    renderer : sim.render.Renderer
        The scene's renderer (for :meth:`~sim.render.Renderer.object_ids`: one ray cast a
        frame; ``rows=True`` for a rolling shutter, :meth:`~sim.render.Renderer.object_ids_rows`).
    folder : Path
        The sequence folder being written, which already holds the depth maps.
    times : (N,) float64 ndarray, seconds
        The frames' true times (poses and object motions are taken there; a rolling shutter's
        middle row's).
    depth_names : list of N str
        The depth maps, relative to ``folder``.
    clock_offset : float, seconds
        The frames' clock offset: index times are ``times + clock_offset``, as in
        ``depthmaps.txt``.
    readout_s : float, seconds
        A rolling shutter's readout (0: a global shutter): row ``r`` of every frame is seen at
        ``t + (r / (H - 1) - 0.5) readout_s``, its flow by :func:`rolling_optical_flow` and its
        motion field at its own time. Static scenes only.

    Returns
    -------
    dict
        The entries of ``sequence.json`` that describe these files.
    """
    camera, objects = scene.camera, scene.objects
    if readout_s > 0 and scene.is_dynamic:
        raise ValueError("the motion ground truth of a rolling shutter needs a static scene")
    centres = camera.normalized_pixel_centres()
    height = camera.height
    share = np.arange(height) / max(height - 1, 1) - 0.5

    def rows(t: float) -> np.ndarray:
        return float(t) + share * readout_s

    for sub in ("flow", "motion", "masks"):
        (folder / sub).mkdir(exist_ok=True)
    n = len(times)
    poses = None if readout_s > 0 else scene.trajectory.pose(times)   # a global shutter's
    residual = 0.0
    previous = None                                    # (depth, ids) of frame k - 1
    for k, t in enumerate(times):
        depth = read_depth(folder / depth_names[k])
        if readout_s > 0:
            row_times = rows(t)
            row_poses = scene.trajectory.pose(row_times)
            ids = renderer.object_ids_rows(float(t), row_poses)
            velocity = scene.trajectory.velocity(row_times)
            field = np.concatenate([motion_field(
                camera, depth[r:r + 1], ids[r:r + 1], objects, row_poses[r],
                (velocity[0][r], velocity[1][r]), float(row_times[r]), centres[r:r + 1])
                for r in range(height)])
        else:
            ids = renderer.object_ids(float(t))
            field = motion_field(camera, depth, ids, objects, poses[k],
                                 scene.trajectory.velocity(float(t)), float(t), centres)
        _write_mask(folder / _names("mask", k, "png"), ids)
        _write_exr(folder / _names("motion", k), {"du_dt": field[..., 0],
                                                  "dv_dt": field[..., 1]})
        if previous is not None:
            depth_prev, ids_prev = previous
            t_prev = float(times[k - 1])
            if readout_s > 0:
                *forward, step = rolling_optical_flow(camera, depth_prev, depth,
                                                      scene.trajectory, rows(t_prev), float(t),
                                                      readout_s, centres)
                *backward, back = rolling_optical_flow(camera, depth, depth_prev,
                                                       scene.trajectory, rows(t), t_prev,
                                                       readout_s, centres)
                residual = max(residual, step, back)
            else:
                forward = optical_flow(camera, depth_prev, ids_prev, depth, objects,
                                       poses[k - 1], t_prev, poses[k], float(t), centres)
                backward = optical_flow(camera, depth, ids, depth_prev, objects, poses[k],
                                        float(t), poses[k - 1], t_prev, centres)
            _write_flow(folder / _names("forward", k - 1), *forward)
            _write_flow(folder / _names("backward", k), *backward)
        previous = depth, ids
    stamps = np.asarray(times, dtype=np.float64) + clock_offset
    write_index(folder / FORWARD_INDEX, stamps[:-1], [_names("forward", k) for k in range(n - 1)])
    write_index(folder / BACKWARD_INDEX, stamps[1:],
                [_names("backward", k) for k in range(1, n)])
    write_index(folder / MOTION_INDEX, stamps, [_names("motion", k) for k in range(n)])
    write_index(folder / MASK_INDEX, stamps, [_names("mask", k, "png") for k in range(n)])
    flags = {str(NO_SURFACE): "no surface", str(OUT_OF_VIEW): "out of view",
             str(OCCLUDED): "occluded"}
    return {
        "flow": {"forward": FORWARD_INDEX, "backward": BACKWARD_INDEX,
                 "channels": list(_FLOW_CHANNELS), "units": "pixels of the distorted image",
                 "flags": flags, "occlusion_rtol": OCCLUSION_RTOL,
                 "exact": "from each frame's exact depth, the true poses and object motions"},
        "motion_field": {"index": MOTION_INDEX, "channels": list(_MOTION_CHANNELS),
                         "units": "pixels/s of the distorted image", "exact": "analytic"},
        "object_masks": {"index": MASK_INDEX, "encoding": "uint16 PNG, 0 = none, i = objects[i-1]",
                         "objects": [obj.name for obj in objects]},
        **({"rolling_shutter": {"readout_s": readout_s, "row_residual_px": residual,
                                "rows": "each row at its own time; the target row iterated"}}
           if readout_s > 0 else {}),
    }


def read_flow(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an optical-flow file (``flow/forward_*.exr``, ``flow/backward_*.exr``).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    flow : (H, W, 2) float32 ndarray, pixels
        ``(du, dv)``.
    flags : (H, W) uint8 ndarray
        :data:`NO_SURFACE`, :data:`OUT_OF_VIEW`, :data:`OCCLUDED` bits; 0 = valid.

    Raises
    ------
    ValueError
        The file is missing, not an EXR, or lacks one of the channels ``du``, ``dv``, ``flags``.
    """
    channels = _channels(path, _FLOW_CHANNELS)
    flow = np.stack([channels["du"], channels["dv"]], axis=-1).astype(np.float32)
    return flow, channels["flags"].astype(np.uint8)


def read_motion_field(path: str | Path) -> np.ndarray:
    """Read a motion-field file (``motion/frame_*.exr``).

    Returns
    -------
    (H, W, 2) float32 ndarray, pixels per second
        ``(du/dt, dv/dt)``, 0 where nothing is seen.
    """
    channels = _channels(path, _MOTION_CHANNELS)
    return np.stack([channels["du_dt"], channels["dv_dt"]], axis=-1).astype(np.float32)


def read_object_mask(path: str | Path) -> np.ndarray:
    """Read an object mask (``masks/frame_*.png``).

    Returns
    -------
    (H, W) uint16 ndarray
        0 where nothing is seen, ``i`` where ``sequence.json``'s
        ``object_masks.objects[i - 1]`` is.
    """
    mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if mask is None or mask.ndim != 2 or mask.dtype != np.uint16:
        got = "an unreadable file" if mask is None else f"{mask.dtype} {mask.shape}"
        raise ValueError(f"{path}: expected a single-channel 16-bit PNG object mask, got {got}")
    return mask


def _channels(path: str | Path, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    channels = read_exr_channels(path)
    missing = [name for name in names if name not in channels]
    if missing:
        raise ValueError(f"{path}: no channel(s) {missing}; expected {list(names)}, the file "
                         f"has {sorted(channels)}")
    return channels
