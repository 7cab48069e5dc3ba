"""A simulated twin of a real recording: same camera, same trajectory, a poster like its view.

:func:`write_twin` reads a recording in the Event-Camera Dataset layout (``calib.txt``,
``groundtruth.txt``, ``images.txt`` + ``images/``, events) and writes a scene folder that
``evfuse simulate`` runs:

- ``scene.toml``: the recording's camera (size from its frames, intrinsics and distortion from
  ``calib.txt``), its trajectory (``groundtruth.txt``, copied beside the scene and read as a
  ``file`` trajectory), its frame rate, and one poster;
- ``groundtruth.txt``: the recording's poses of the window, times shifted by ``-t0`` (a scene's
  time starts at 0: the twin's ``t`` is the recording's ``t - t0``);
- ``poster.png``: the recording's first frame of the window, undistorted, as the poster's
  texture. The frame's gray levels are taken as ``(DN / 255) ** frame_gamma`` of the light
  (``frame_gamma`` 1: a DAVIS APS is linear) and written sRGB-encoded in 16 bits, so that the
  renderer, which decodes image textures as sRGB, gets back a reflectance proportional to
  them (on the paper range of :data:`sim.textures.PAPER_RANGE`). Reading a linear frame as sRGB
  would raise its log contrast about 2.2 times, and the event rate with it.

**The poster.** A plane facing the camera's first pose of the window at ``depth`` metres (z in
that camera's frame), sized so that the undistorted first frame covers exactly the view at that
depth, and extended by mirroring the frame's borders so that the view stays covered over the
whole window's motion (plus 10 %). The twin's first frame is then the recording's (up to the
renderer's shading of the reflectance, and the frame camera's response); a real scene's
parallax (objects at other depths) is not: every point of the twin lies at ``depth``.

Only the *camera's* and the *view's* statistics are copied; the illumination is a light along
the optical axis giving ``illuminance`` lux on the poster (the recording's is unknown).
``depth`` is not read from the recording (there is no depth ground truth): give the depth that
matters, e.g. the median of ``evfuse map`` on the recording.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from sim.output import atomic_output_dir, check_output_dir
from sim.scene import MAX_ILLUMINANCE_LUX
from sim.sequence import load_sequence
from sim.statistics import frame_noise
from sim.textures import linear_to_srgb
from sim.validation import (
    PLAUSIBLE_DEPTH_M,
    ParameterError,
    check_parameter,
    depth_metres,
    positive,
)

__all__ = ["write_twin"]


def _window_poses(trajectory, t0: float, t1: float) -> np.ndarray:
    times = np.linspace(t0, t1, 64)
    return trajectory.pose(times)


_MAX_POSTER_PIXELS = 2**28
"""The largest poster (pixels, one byte each): a depth so small that the camera's motion over the
window is thousands of views wide is refused before the padding is allocated."""


def write_twin(recording: str | Path, out: str | Path, depth: float,
               window: tuple[float, float] | None = None, illuminance: float = 400.0,
               frame_sensor: str = "davis240c_aps", frame_gamma: float = 1.0,
               overwrite: bool = False) -> Path:
    """Write a scene folder that simulates ``recording``'s camera and trajectory.

    Parameters
    ----------
    recording : str or Path
        An Event-Camera Dataset folder (``calib.txt``, ``groundtruth.txt``, ``images.txt``).
    out : str or Path
        Folder to write (``scene.toml``, ``groundtruth.txt``, ``poster.png``); created.
    depth : float, metres
        The poster's depth in the camera of the window's first pose.
    window : (t0, t1) in seconds, optional
        The part of the recording to copy; default the span of its poses. The poster is the
        frame nearest ``t0`` and covers the view over the whole window.
    illuminance : float, lux
        On the poster, from a light along the first pose's optical axis (default 400: an
        office; the recording's own light level is unknown).
    frame_sensor : str
        The standard camera's sensor (:data:`sim.frame_sensor.FRAME_SENSORS` or ``ideal``;
        default ``davis240c_aps``, the ECD's camera).
    frame_gamma : float
        The recording's frames are ``255 * light ** (1 / frame_gamma)`` (default 1: linear, as
        a DAVIS APS; 2.2 for a gamma-encoded camera).
    overwrite : bool
        Replace an existing ``out`` that evfuse wrote (:func:`sim.output.atomic_output_dir`;
        ``out`` is written atomically and must not be, hold or lie in ``recording``).

    Returns
    -------
    Path
        ``out / "scene.toml"``.

    Raises
    ------
    ValueError
        One line naming the file or value: no poses, a window outside the poses; a
        :class:`sim.validation.ParameterError` naming the parameter for a reversed or empty
        ``window``, ``depth <= 0`` or in millimetres (:func:`sim.validation.depth_metres`), or
        ``frame_gamma`` / ``illuminance`` not a finite number > 0.
    """
    from sim.trajectory import read_trajectory

    recording, out = Path(recording), Path(out)
    depth = check_parameter(depth_metres, "depth", check_parameter(positive, "depth", depth))
    frame_gamma = check_parameter(positive, "frame_gamma", frame_gamma)
    illuminance = check_parameter(positive, "illuminance", illuminance)
    if illuminance > MAX_ILLUMINANCE_LUX:                 # the bound simulate reads it with
        raise ParameterError(f"{{illuminance}} {illuminance:g} lux is brighter than the "
                             f"{MAX_ILLUMINANCE_LUX:,.0f} lux a scene may declare (direct "
                             "sunlight is about 100,000 lux)", illuminance="illuminance")
    check_output_dir(out, overwrite, [recording])
    sequence = load_sequence(recording)
    if sequence.groundtruth_path is None or not len(sequence.image_paths):
        raise ValueError(f"{recording}: a twin needs groundtruth.txt and images.txt")
    trajectory = read_trajectory(sequence.groundtruth_path)
    t_start, t_end = float(trajectory.t_start), float(trajectory.t_end)
    t0, t1 = window if window is not None else (t_start, t_end)
    if not t0 < t1:
        raise ParameterError(f"{{window}} {t0:g},{t1:g}: expected T0 < T1 (the window's start "
                             "before its end, in seconds)", window="window")
    if not (t_start <= t0 < t1 <= t_end):
        raise ValueError(f"window [{t0}, {t1}] s is not inside {sequence.groundtruth_path.name}'s "
                         f"poses [{t_start:.6f}, {t_end:.6f}] s")
    camera = sequence.camera
    frame_index = int(np.argmin(np.abs(np.asarray(sequence.image_times) - t0)))
    frame = cv2.imread(str(sequence.image_paths[frame_index]), cv2.IMREAD_GRAYSCALE)
    if frame is None:
        raise ValueError(f"{sequence.image_paths[frame_index]}: cannot read the frame")
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])
    # The frame's own noise is not the scene's texture: moving past it, it would fire events a
    # real camera never sees. Non-local means at three times the noise measured in flat areas.
    noise = frame_noise(frame)
    if np.isfinite(noise) and noise > 0:
        frame = cv2.fastNlMeansDenoising(frame, None, h=float(3 * noise), templateWindowSize=7,
                                         searchWindowSize=21)
    undistorted = cv2.undistort(frame, K, np.asarray(camera.distortion))

    # The view at `depth` from the first pose spans x in [-cx, W - cx] * depth / fx (camera
    # frame; pixel (0, 0)'s centre at 0, so the image spans [-0.5, W - 0.5]).
    width_m = camera.width / camera.fx * depth
    height_m = camera.height / camera.fy * depth
    left = -(camera.cx + 0.5) / camera.fx * depth
    top = -(camera.cy + 0.5) / camera.fy * depth
    # How far the view moves over the window, in the first camera's frame, at that depth.
    poses = _window_poses(trajectory, t0, t1)
    first = np.linalg.inv(poses[0])
    centres = (first @ poses)[:, :3, 3]
    shift = np.abs(centres[:, :2]).max(axis=0) * 1.1 + 1e-3
    with np.errstate(over="ignore", divide="ignore"):     # a tiny depth: inf, refused below
        pad = (shift[0] / width_m * camera.width, shift[1] / height_m * camera.height)
        pixels = (camera.width + 2 * pad[0]) * (camera.height + 2 * pad[1])
    if not pixels <= _MAX_POSTER_PIXELS:
        raise ParameterError(
            f"{{depth}} {depth:g} m: the camera moves {float(shift.max()):.3g} m over the window, "
            f"{max(pad[0] / camera.width, pad[1] / camera.height):.3g} times the view's width "
            f"at that depth: the poster would need {pixels:.3g} pixels (at most "
            f"{_MAX_POSTER_PIXELS:.3g}); expected the depth of the scene in metres",
            depth="depth")
    pad_x, pad_y = (int(math.ceil(p)) for p in pad)
    poster = cv2.copyMakeBorder(undistorted, pad_y, pad_y, pad_x, pad_x, cv2.BORDER_REFLECT)
    size = (width_m * poster.shape[1] / camera.width, height_m * poster.shape[0] / camera.height)
    centre_cam = np.array([left + size[0] / 2 - pad_x * width_m / camera.width,
                           top + size[1] / 2 - pad_y * height_m / camera.height, depth, 1.0])
    centre = (poses[0] @ centre_cam)[:3]
    rotation = poses[0][:3, :3]
    normal = -rotation[:, 2]                  # facing the camera
    up = -rotation[:, 1]                      # texture rows run along the camera's y (down)

    light = (poster.astype(np.float64) / 255.0) ** frame_gamma
    # A scene's time starts at 0: the poses are copied with t - t0 (the twin's t = 0 is the
    # recording's t0), those from just before t0 to just after t1.
    rows = np.loadtxt(sequence.groundtruth_path, ndmin=2)
    inside = np.flatnonzero((rows[:, 0] >= t0) & (rows[:, 0] <= t1))
    keep = np.arange(max(inside[0] - 1, 0), min(inside[-1] + 2, len(rows))) if inside.size \
        else np.flatnonzero((rows[:, 0] >= rows[rows[:, 0] <= t0, 0].max())
                            & (rows[:, 0] <= rows[rows[:, 0] >= t1, 0].min()))
    rows = rows[keep]
    rows[:, 0] -= t0
    # The times are written to the nanosecond, the last pose's rounded to the nearest: the
    # duration, rounded down to the nanosecond, stays inside the poses as they are read back.
    duration = math.floor(round((t1 - t0) * 1e9, 3)) / 1e9
    frame_times = np.asarray(sequence.image_times)
    rate = 1.0 / float(np.median(np.diff(frame_times))) if len(frame_times) > 1 else 24.0
    # Auto-exposure may go to 40 ms, as on the built-in twins (a DAVIS240C APS frame at an
    # office's 300-500 lux needs 15-40 ms), and never past the frame period.
    max_exposure = min(0.04, math.floor(1e6 / float(f"{rate:.6g}")) / 1e6)   # rate as written
    name = f"twin_{recording.resolve().name}"
    vec = lambda v: "[" + ", ".join(f"{x:.9g}" for x in v) + "]"  # noqa: E731
    scene = f"""# Twin of the recording {recording.resolve()} (evfuse twin): its camera, its
# trajectory (groundtruth.txt, copied), its frame rate, and its first frame of the window
# undistorted on a poster at {depth} m. Window of the recording: {t0:.6f}-{t1:.6f} s.
name = "{name}"
description = "Twin of {recording.resolve().name}: its camera and poses, poster at {depth} m"
# the recording's {t0:.6f}-{t1:.6f} s; twin time = recording time - {t0:.6f}
duration = {duration:.9f}
depth_range = [{depth / 2:.6g}, {min(depth * 2, PLAUSIBLE_DEPTH_M):.6g}]
seed = 1

[camera]
width = {camera.width}
height = {camera.height}
fx = {camera.fx:.9g}
fy = {camera.fy:.9g}
cx = {camera.cx:.9g}
cy = {camera.cy:.9g}
distortion = {vec(camera.distortion)}

[frames]
rate = {rate:.6g}
sensor = "{frame_sensor}"
max_exposure = {max_exposure:.6f}   # s: auto-exposure's longest (office light needs 15-40 ms)

[trajectory]
type = "file"
path = "groundtruth.txt"

[[lights]]
type = "directional"
direction = {vec(rotation[:, 2])}
illuminance_lux = {illuminance:.6g}

[[objects]]
name = "poster"
type = "rectangle"
center = {vec(centre)}
size = {vec(size)}
normal = {vec(normal)}
up = {vec(up)}
material = {{ texture = {{ type = "image", path = "poster.png" }} }}
"""
    with atomic_output_dir(out, overwrite=overwrite, inputs=[recording],
                           command="evfuse twin") as tmp:
        cv2.imwrite(str(tmp / "poster.png"),
                    np.round(linear_to_srgb(light) * 65535).astype(np.uint16))
        np.savetxt(tmp / "groundtruth.txt", rows, fmt="%.9f")
        (tmp / "scene.toml").write_text(scene)
    return out / "scene.toml"
