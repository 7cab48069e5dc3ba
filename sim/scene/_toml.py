"""Scene files (TOML) to a :class:`~sim.scene.Scene`: :func:`parse_scene`, :func:`load_scene`
and :func:`declared_depth_range`, the one reader of a scene's ``depth_range``. Every value is
checked before anything is rendered; a refusal is a :class:`~sim.scene.SceneError` naming the
file, the key and what was expected. Numbers are checked by :mod:`sim.validation`'s
validators, their refusals re-worded in the scene file's terms (file and key)."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from sim import validation
from sim.camera import Camera, camera_preset
from sim.capture_errors import RIG_PRESETS, RigParams
from sim.frame_camera import SHUTTERS, FrameCamera
from sim.frame_sensor import FRAME_SENSORS, FrameSensor
from sim.frames import FRAME_SENSOR_NAMES, FrameParams
from sim.imu import IMU_PRESETS, ImuParams
from sim.scene._meshes import BUILTIN_MESH_PREFIX, builtin_mesh_path
from sim.scene._model import (
    Light,
    Material,
    ObjectMotion,
    RenderParams,
    Scene,
    SceneError,
    SceneObject,
)
from sim.se3 import look_at, make_pose, quat_to_rot, rotation_from_euler
from sim.textfile import bom_hint
from sim.trajectory import (
    HandheldTrajectory,
    LinearTrajectory,
    SplineTrajectory,
    Trajectory,
    read_trajectory,
)
from sim.validation import MAX_SEED, depth_metres, finite, integer, non_negative

__all__ = ["MAX_ILLUMINANCE_LUX", "MAX_INTENSITY_CD", "MAX_NEAREST_SURFACE_M",
           "MAX_OBJECT_SIZE_M", "declared_depth_range", "load_scene", "parse_scene"]


MAX_OBJECT_SIZE_M = 1000.0
"""Largest size, radius or height of an object accepted in a scene file, metres. A scene written
in millimetres (a 1.2 m poster as 1200) is refused instead of being simulated 1000 times too big.
"""
MAX_ILLUMINANCE_LUX = 200_000.0
"""Brightest directional light a scene file may declare, lux (direct sunlight is about
100,000 lux): a value beyond it is a unit mistake, refused naming the key."""
MAX_INTENSITY_CD = 10_000_000.0
"""Brightest point or spot light a scene file may declare, candela (a searchlight; a 50 W
halogen spot is 1,000-3,000 cd)."""
MAX_NEAREST_SURFACE_M = 100.0
"""Farthest the nearest object's surface may stay from the camera over the whole trajectory,
metres (meshes and object motion aside). No scene for event-based depth is seen from beyond
100 m only; a scene in millimetres (a poster 231 mm away written 231) is refused."""


# --------------------------------------------------------------------------------------------
# Validation helpers: each returns the converted value or raises SceneError with the key path.
# --------------------------------------------------------------------------------------------


class _Ctx:
    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, message: str) -> SceneError:
        return SceneError(f"{self.source}: {key}: {message}")

    def table(self, value: Any, key: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key, f"expected a table, got {_show(value)}")
        return value

    def keys(self, table: Mapping[str, Any], key: str, required: set[str], optional: set[str]):
        unknown = sorted(set(table) - required - optional)
        if unknown:
            allowed = ", ".join(sorted(required | optional))
            raise self.fail(key, f"unknown key {unknown[0]!r} (expected one of: {allowed})")
        missing = sorted(required - set(table))
        if missing:
            raise self.fail(key, f"missing required key {missing[0]!r}")


def _show(value: Any) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text[:60]}"


def _checked(ctx: _Ctx, check: Callable[[str, Any], Any], value: Any, key: str,
             message: str) -> Any:
    """``check(key, value)`` (a validator of :mod:`sim.validation`), its refusal re-worded in the
    scene file's terms: ``message``, naming the file and the key (by ``ctx``)."""
    try:
        return check(key, value)
    except ValueError:
        raise ctx.fail(key, message) from None


def _number(ctx: _Ctx, value: Any, key: str, *, positive=False, nonneg=False) -> float:
    """``value`` checked by :func:`sim.validation.finite` (and :func:`~sim.validation.positive`
    or :func:`~sim.validation.non_negative`), refused in the scene file's terms."""
    number = _checked(ctx, finite, value, key, f"expected a finite number, got {_show(value)}")
    if positive:
        _checked(ctx, validation.positive, number, key,
                 f"expected a positive number, got {value}")
    if nonneg:
        _checked(ctx, non_negative, number, key, f"expected a number >= 0, got {value}")
    return number


def _integer(ctx: _Ctx, value: Any, key: str, *, minimum: int | None = None) -> int:
    """A TOML integer (a float such as 3.0 is refused: a scene file writes counts as integers),
    at least ``minimum`` by :func:`sim.validation.integer`."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ctx.fail(key, f"expected an integer, got {_show(value)}")
    if minimum is not None:
        _checked(ctx, lambda k, v: integer(k, v, minimum), value, key,
                 f"expected an integer >= {minimum}, got {value}")
    return int(value)


def _seed(ctx: _Ctx, value: Any, key: str) -> int:
    """A seed: a TOML integer in 0..:data:`sim.validation.MAX_SEED` (Mitsuba's 32-bit seed)."""
    value = _integer(ctx, value, key)
    if not 0 <= value <= MAX_SEED:
        raise ctx.fail(key, f"expected an integer in 0..{MAX_SEED} (2**32 - 1), got {value}")
    return value


def _string(ctx: _Ctx, value: Any, key: str, choices: tuple[str, ...] | None = None) -> str:
    if not isinstance(value, str):
        raise ctx.fail(key, f"expected a string, got {_show(value)}")
    if choices is not None and value not in choices:
        raise ctx.fail(key, f"expected one of {', '.join(choices)}; got {value!r}")
    return value


def _vector(ctx: _Ctx, value: Any, key: str, n: int, *, positive=False, nonneg=False):
    what = f"a list of {n} {'positive ' if positive else ''}numbers{' >= 0' if nonneg else ''}"
    if not isinstance(value, list) or len(value) != n:
        raise ctx.fail(key, f"expected {what}, got {_show(value)}")
    out = []
    for i, item in enumerate(value):
        check = validation.positive if positive else non_negative if nonneg else finite
        out.append(_checked(ctx, check, item, key,
                            f"expected {what}, got {_show(value)} (item {i})"))
    return np.array(out)


def _color(ctx: _Ctx, value: Any, key: str) -> np.ndarray:
    """A light's value: a positive number, or one per colour channel (3 numbers >= 0, not all
    0)."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return np.full(3, _number(ctx, value, key, positive=True))
    expected = "expected a positive number or a list of 3 numbers >= 0 (one per colour channel)"
    if not isinstance(value, list):
        raise ctx.fail(key, f"{expected}, got {_show(value)}")
    vec = _vector(ctx, value, key, 3, nonneg=True)
    if not vec.max() > 0:
        raise ctx.fail(key, f"{expected}, not all 0, got {_show(value)}")
    return vec


def _get(ctx, table, key, name, convert: Callable, default=None):
    if name not in table:
        return default
    return convert(ctx, table[name], f"{key}.{name}" if key else name)


# --------------------------------------------------------------------------------------------
# Sections
# --------------------------------------------------------------------------------------------

_CAMERA_FIELDS = ("width", "height", "fx", "fy", "cx", "cy")


def _depth_range(ctx: _Ctx, value: Any, key: str) -> tuple[float, float]:
    low, high = _vector(ctx, value, key, 2, positive=True)
    for end in (low, high):
        try:
            depth_metres(key, end)
        except ValueError as exc:
            raise SceneError(f"{ctx.source}: {exc}") from None
    if not low < high:
        raise ctx.fail(key, f"expected [near, far] metres with near < far, got {_show(value)}")
    return float(low), float(high)


def _parse_camera(ctx: _Ctx, raw: Any, key: str = "[camera]",
                  extra: frozenset[str] = frozenset()) -> Camera:
    """``[camera]`` (or ``[event_camera]``, ``[frame_camera]``, whose ``extra`` keys the
    caller reads): a ``preset`` and/or the intrinsics."""
    table = ctx.table(raw, key)
    ctx.keys(table, key, set(), {"preset", "distortion", *_CAMERA_FIELDS, *extra})
    if "preset" in table:
        name = _string(ctx, table["preset"], f"{key}.preset")
        try:
            camera = camera_preset(name)
        except ValueError as exc:
            raise ctx.fail(f"{key}.preset", str(exc)) from None
        values = {f: getattr(camera, f) for f in _CAMERA_FIELDS}
        distortion = tuple(camera.distortion)
    else:
        missing = [f for f in _CAMERA_FIELDS if f not in table]
        if missing:
            raise ctx.fail(key, f"missing required key {missing[0]!r} (or give a 'preset')")
        values, distortion = {}, (0.0,) * 5
    for name in _CAMERA_FIELDS:
        if name in table:
            conv = _integer if name in ("width", "height") else _number
            extra = ({"minimum": 1} if name in ("width", "height")
                     else {"positive": True} if name in ("fx", "fy") else {})
            values[name] = conv(ctx, table[name], f"{key}.{name}", **extra)
    if "distortion" in table:
        distortion = tuple(_vector(ctx, table["distortion"], f"{key}.distortion", 5))
    try:
        return Camera(distortion=distortion, **values)
    except ValueError as exc:
        raise ctx.fail(key, str(exc)) from None


_FRAME_CAMERA_KEYS = frozenset({"T_event_frame", "shutter", "readout_s"})


def _parse_extrinsic(ctx: _Ctx, raw: Any, key: str) -> np.ndarray:
    """``T_event_frame = { translation = [x, y, z], rotation = [rx, ry, rz] }`` (metres, XYZ
    Euler degrees) or ``quaternion = [qx, qy, qz, qw]`` instead of ``rotation``."""
    table = ctx.table(raw, key)
    ctx.keys(table, key, {"translation"}, {"rotation", "quaternion"})
    translation = _vector(ctx, table["translation"], f"{key}.translation", 3)
    if "rotation" in table and "quaternion" in table:
        raise ctx.fail(key, "expected either 'rotation' (degrees) or 'quaternion', not both")
    if "quaternion" in table:
        q = _vector(ctx, table["quaternion"], f"{key}.quaternion", 4)
        if not np.any(q):
            raise ctx.fail(f"{key}.quaternion", "expected a non-zero quaternion [qx, qy, qz, qw]")
        rotation = quat_to_rot(q)
    else:
        rotation = rotation_from_euler(_get(ctx, table, key, "rotation",
                                            lambda c, v, k: _vector(c, v, k, 3), np.zeros(3)))
    return make_pose(rotation, translation)


def _parse_frame_camera(ctx: _Ctx, raw: Any) -> FrameCamera:
    """``[frame_camera]``: the intrinsics of ``[camera]`` plus ``T_event_frame`` (required),
    ``shutter`` (default global) and ``readout_s`` (rolling shutter only, required there)."""
    key = "[frame_camera]"
    camera = _parse_camera(ctx, raw, key, _FRAME_CAMERA_KEYS)
    if "T_event_frame" not in raw:
        raise ctx.fail(key, "missing required key 'T_event_frame' (the frame camera's pose in "
                            "the event camera's frame: { translation = [x, y, z], rotation = "
                            "[rx, ry, rz] })")
    extrinsic = _parse_extrinsic(ctx, raw["T_event_frame"], f"{key}.T_event_frame")
    shutter = _get(ctx, raw, key, "shutter",
                   lambda c, v, k: _string(c, v, k, SHUTTERS), "global")
    if shutter == "rolling" and "readout_s" not in raw:
        raise ctx.fail(key, "shutter = \"rolling\" needs readout_s (seconds from the first "
                            "row to the last)")
    if shutter == "global" and "readout_s" in raw:
        raise ctx.fail(f"{key}.readout_s", "is a rolling shutter's readout time; set shutter "
                                           "= \"rolling\" or remove it")
    readout = _get(ctx, raw, key, "readout_s", lambda c, v, k: _number(c, v, k, nonneg=True),
                   0.0)
    return FrameCamera(camera, extrinsic, shutter, readout)


def _parse_cameras(ctx: _Ctx, raw: dict[str, Any]) -> tuple[Camera, FrameCamera | None]:
    """``[camera]`` alone (one DAVIS-like sensor), or ``[event_camera]`` and
    ``[frame_camera]`` (a rig of two cameras): the event camera and the frame camera."""
    given = [name for name in ("camera", "event_camera", "frame_camera") if name in raw]
    if given == ["camera"]:
        return _parse_camera(ctx, raw["camera"]), None
    if given == ["event_camera", "frame_camera"]:
        return (_parse_camera(ctx, raw["event_camera"], "[event_camera]"),
                _parse_frame_camera(ctx, raw["frame_camera"]))
    if "camera" in given and len(given) > 1:
        raise ctx.fail(f"[{given[1]}]", "expected either [camera] (one sensor) or "
                                        "[event_camera] with [frame_camera] (a rig), not both")
    if given:
        missing = "frame_camera" if given == ["event_camera"] else "event_camera"
        raise ctx.fail(f"[{given[0]}]", f"a rig needs both [event_camera] and [frame_camera]; "
                                        f"[{missing}] is missing")
    raise ctx.fail("top level", "missing required key 'camera' (or [event_camera] with "
                                "[frame_camera] for a rig of two cameras)")


def _parse_frames(ctx: _Ctx, raw: Any) -> FrameParams:
    key = "[frames]"
    table = ctx.table(raw, key)
    for gone in ("full_well", "read_noise"):
        if gone in table:
            raise ctx.fail(f"{key} {gone}", "the frame noise is now a sensor's: use sensor = "
                           "\"davis240c_aps\" or \"machine_vision\", or sensor = { preset = "
                           f"..., {gone} = ... }} in electrons")
    names = {"rate", "exposure", "max_exposure", "exposure_samples", "gamma", "gain", "sensor"}
    ctx.keys(table, key, set(), names)
    values: dict[str, Any] = {}
    for name, item in table.items():
        if name == "exposure_samples":
            values[name] = _integer(ctx, item, f"{key}.{name}", minimum=1)
        elif name == "sensor":
            values[name] = _parse_frame_sensor(ctx, item, f"{key}.sensor")
        else:
            values[name] = _number(ctx, item, f"{key}.{name}", positive=True)
    # The one constraint between two keys, said in the file's own terms (given or default).
    defaults = FrameParams()
    rate = values.get("rate", defaults.rate)
    exposure = values.get("exposure", defaults.exposure)
    if exposure > 1.0 / rate:
        given = "" if "exposure" in values else " (the default)"
        rate_given = "" if "rate" in values else ", the default"
        raise ctx.fail(f"{key} exposure = {exposure:g}{given}",
                       f"must be at most the frame interval 1/rate = {1.0 / rate:.4g} s (rate = "
                       f"{rate:g} Hz{rate_given})")
    if values.get("max_exposure", 0.0) > 1.0 / rate:
        rate_given = "" if "rate" in values else ", the default"
        raise ctx.fail(f"{key} max_exposure = {values['max_exposure']:g}",
                       f"must be at most the frame interval 1/rate = {1.0 / rate:.4g} s (rate = "
                       f"{rate:g} Hz{rate_given})")
    try:
        return FrameParams(**values)
    except ValueError as exc:                       # name the TOML key, not the dataclass field
        raise ctx.fail(key, str(exc).replace("FrameParams.", f"{key} ")) from None


_RIG_KEYS = {  # TOML key -> (RigParams field, factor to SI units)
    "position_sigma": ("position_sigma", 1.0),
    "rotation_sigma": ("rotation_sigma", math.pi / 180),       # degrees in scene files
    "position_walk": ("position_walk", 1.0),
    "rotation_walk": ("rotation_walk", math.pi / 180),         # deg/sqrt(s)
    "events_offset": ("events_offset", 1.0),
    "frames_offset": ("frames_offset", 1.0),
    "poses_offset": ("poses_offset", 1.0),
    "imu_offset": ("imu_offset", 1.0),
    "focal_sigma": ("focal_sigma", 1.0),
    "principal_point_sigma": ("principal_point_sigma", 1.0),
}


def _preset_table(ctx: _Ctx, raw: Any, key: str, presets: Mapping[str, Any], default: str,
                  names: set[str]) -> tuple[dict[str, Any], str]:
    """A table of optional ``names`` plus ``preset`` (one of ``presets``, default
    ``default``): the table and the preset's name."""
    table = ctx.table(raw, key)
    ctx.keys(table, key, set(), {"preset", *names})
    preset = _get(ctx, table, key, "preset",
                  lambda c, v, k: _string(c, v, k, tuple(presets)), default)
    return table, preset


def _parse_rig(ctx: _Ctx, raw: Any) -> RigParams:
    """``[rig]``: a ``preset`` (default ``perfect``) and any of its fields replaced."""
    key = "[rig]"
    table, preset = _preset_table(ctx, raw, key, RIG_PRESETS, "perfect",
                                  {"distortion_sigma", *_RIG_KEYS})
    changes: dict[str, Any] = {}
    for name, (attribute, factor) in _RIG_KEYS.items():
        if name in table:
            nonneg = not name.endswith("_offset")
            changes[attribute] = factor * _number(ctx, table[name], f"{key}.{name}",
                                                  nonneg=nonneg)
    if "distortion_sigma" in table:
        changes["distortion_sigma"] = tuple(_vector(ctx, table["distortion_sigma"],
                                                    f"{key}.distortion_sigma", 5, nonneg=True))
    return RigParams.from_preset(preset, **changes)


def _parse_up(ctx: _Ctx, value: Any, key: str) -> tuple[float, float, float]:
    """Top-level ``up``: a non-zero 3-vector, normalised."""
    vec = _vector(ctx, value, key, 3)
    vec = vec / max(np.abs(vec).max(), np.finfo(float).tiny)   # at any scale: no overflow
    norm = float(np.linalg.norm(vec))
    if not norm > 0:
        raise ctx.fail(key, f"expected a non-zero direction [x, y, z], got {_show(value)}")
    return tuple(float(x) for x in vec / norm)


_IMU_NUMBERS = ("rate", "gravity", "accelerometer_noise_density", "accelerometer_random_walk",
                "gyroscope_noise_density", "gyroscope_random_walk")


def _parse_imu(ctx: _Ctx, raw: Any) -> ImuParams:
    """``[imu]``: a ``preset`` (default ``ideal``), any of its numbers replaced, and
    ``T_camera_imu = { translation = [m x3], rotation = [deg x3] }`` (Euler, as objects')."""
    key = "[imu]"
    table, preset = _preset_table(ctx, raw, key, IMU_PRESETS, "ideal",
                                  {"T_camera_imu", *_IMU_NUMBERS})
    changes: dict[str, Any] = {}
    for name in _IMU_NUMBERS:
        if name in table:
            positive = name in ("rate", "gravity")
            changes[name] = _number(ctx, table[name], f"{key}.{name}", positive=positive,
                                    nonneg=not positive)
    if "T_camera_imu" in table:
        sub = f"{key}.T_camera_imu"
        extrinsic = ctx.table(table["T_camera_imu"], sub)
        ctx.keys(extrinsic, sub, set(), {"translation", "rotation"})
        vec3 = lambda c, v, k: _vector(c, v, k, 3)  # noqa: E731
        translation = _get(ctx, extrinsic, sub, "translation", vec3, np.zeros(3))
        rotation = rotation_from_euler(_get(ctx, extrinsic, sub, "rotation", vec3, np.zeros(3)))
        changes["T_camera_imu"] = make_pose(rotation, translation)
    return ImuParams.from_preset(preset, **changes)


def _parse_frame_sensor(ctx: _Ctx, raw: Any, key: str) -> str | FrameSensor:
    """``sensor = "name"`` or ``sensor = { preset = "name", field = value, ... }``."""
    if isinstance(raw, str):
        return _string(ctx, raw, key, FRAME_SENSOR_NAMES)
    table = ctx.table(raw, key)
    numeric = {f.name for f in fields(FrameSensor)} - {"name", "vignetting", "auto_exposure"}
    ctx.keys(table, key, {"preset"}, numeric | {"vignetting", "auto_exposure"})
    preset = _string(ctx, table["preset"], f"{key}.preset", tuple(FRAME_SENSORS))
    changes: dict[str, Any] = {}
    for name, item in table.items():
        if name in numeric:
            changes[name] = _number(ctx, item, f"{key}.{name}")
        elif name == "vignetting":
            changes[name] = _string(ctx, item, f"{key}.{name}", ("cos4", "none"))
        elif name == "auto_exposure":
            if not isinstance(item, bool):
                raise ctx.fail(f"{key}.{name}", f"expected true or false, got {_show(item)}")
            changes[name] = item
    if not changes:
        return preset
    try:
        return replace(FRAME_SENSORS[preset], name=f"{preset}+custom", **changes)
    except ValueError as exc:                       # name the TOML key, not the dataclass field
        raise ctx.fail(key, str(exc).replace("FrameSensor.", "")) from None


def _parse_render(ctx: _Ctx, raw: Any) -> RenderParams:
    key = "[render]"
    table = ctx.table(raw, key)
    ctx.keys(table, key, set(), {"spp", "flat_spp", "pose_rate", "event_spp", "edge_spp",
                                 "seed"})
    counts = {}
    for name, default in (("spp", 16), ("flat_spp", 4), ("event_spp", 4)):
        value = _get(ctx, table, key, name, lambda c, v, k: _integer(c, v, k, minimum=1), default)
        if math.isqrt(value) ** 2 != value:
            raise ctx.fail(f"{key}.{name}",
                           f"expected a perfect square (stratified sampler), got {value}")
        counts[name] = value
    pose_rate = _get(ctx, table, key, "pose_rate", _number, 1000.0)
    if pose_rate < 200:
        raise ctx.fail(f"{key}.pose_rate", f"expected at least 200 Hz, got {pose_rate}")
    edge_spp = _get(ctx, table, key, "edge_spp", lambda c, v, k: _integer(c, v, k, minimum=0), 0)
    if edge_spp and (math.isqrt(edge_spp) ** 2 != edge_spp or edge_spp <= counts["event_spp"]):
        raise ctx.fail(f"{key}.edge_spp", f"expected 0 (off) or a perfect square above "
                                          f"event_spp = {counts['event_spp']}, got {edge_spp}")
    seed = _get(ctx, table, key, "seed", _seed, None)
    return RenderParams(spp=counts["spp"], pose_rate=pose_rate, event_spp=counts["event_spp"],
                        edge_spp=edge_spp, seed=seed, flat_spp=counts["flat_spp"])


def _orientation(ctx: _Ctx, table: Mapping[str, Any], key: str, position: np.ndarray):
    """Camera orientation from ``look_at`` (+ ``up``) or ``rotation`` (Euler degrees)."""
    if ("look_at" in table) == ("rotation" in table):
        raise ctx.fail(key, "expected exactly one of 'look_at' or 'rotation'")
    if "rotation" in table:
        return rotation_from_euler(_vector(ctx, table["rotation"], f"{key}.rotation", 3))
    target = _vector(ctx, table["look_at"], f"{key}.look_at", 3)
    up = _get(ctx, table, key, "up", lambda c, v, k: _vector(c, v, k, 3), np.array([0, 0, 1.0]))
    try:
        return look_at(position, target, up)
    except ValueError as exc:
        raise ctx.fail(key, str(exc)) from None


def _parse_trajectory(ctx: _Ctx, raw: Any, base_dir: Path, seed: int) -> Trajectory:
    key = "[trajectory]"
    table = ctx.table(raw, key)
    if "type" not in table:
        raise ctx.fail(key, "missing required key 'type' (linear, handheld, spline or file)")
    kind = _string(ctx, table["type"], f"{key}.type", ("linear", "handheld", "spline", "file"))
    vec3 = lambda c, v, k: _vector(c, v, k, 3)  # noqa: E731
    if kind == "linear":
        ctx.keys(table, key, {"type", "position", "velocity"}, {"look_at", "up", "rotation"})
        position = vec3(ctx, table["position"], f"{key}.position")
        velocity = vec3(ctx, table["velocity"], f"{key}.velocity")
        return LinearTrajectory(position, velocity, _orientation(ctx, table, key, position))
    if kind == "handheld":
        ctx.keys(
            table, key,
            {"type", "position", "translation_amplitude", "rotation_amplitude"},
            {"look_at", "up", "rotation", "frequencies", "phases", "chirp"},
        )
        position = vec3(ctx, table["position"], f"{key}.position")
        rotation = _orientation(ctx, table, key, position)
        trans = _vector(ctx, table["translation_amplitude"], f"{key}.translation_amplitude", 3,
                        nonneg=True)
        rot = _vector(ctx, table["rotation_amplitude"], f"{key}.rotation_amplitude", 3, nonneg=True)
        rng = np.random.default_rng(seed)
        freqs = _get(ctx, table, key, "frequencies", lambda c, v, k: _vector(c, v, k, 6,
                     positive=True), rng.uniform(0.2, 0.6, 6))
        phases = _get(ctx, table, key, "phases", lambda c, v, k: _vector(c, v, k, 6),
                      rng.uniform(0, 2 * np.pi, 6))
        chirp = _get(ctx, table, key, "chirp", lambda c, v, k: _number(c, v, k, nonneg=True), 0.0)
        return HandheldTrajectory(rotation, position, trans, np.radians(rot), freqs, phases, chirp)
    if kind == "spline":
        ctx.keys(table, key, {"type", "keyframes"}, {"up"})
        frames = table["keyframes"]
        if not isinstance(frames, list) or len(frames) < 2:
            raise ctx.fail(f"{key}.keyframes", "expected a list of at least 2 keyframe tables")
        times, poses = [], []
        for i, item in enumerate(frames):
            sub = f"{key}.keyframes[{i}]"
            frame = ctx.table(item, sub)
            ctx.keys(frame, sub, {"t", "position"}, {"look_at", "up", "rotation"})
            if "up" in table and "up" not in frame:
                frame = {**frame, "up": table["up"]}
            position = vec3(ctx, frame["position"], f"{sub}.position")
            times.append(_number(ctx, frame["t"], f"{sub}.t"))
            poses.append(make_pose(_orientation(ctx, frame, sub, position), position))
        if np.any(np.diff(times) <= 0):
            raise ctx.fail(f"{key}.keyframes", f"expected strictly increasing times, got {times}")
        return SplineTrajectory(np.array(times), np.stack(poses))
    ctx.keys(table, key, {"type", "path"}, set())
    path = base_dir / _string(ctx, table["path"], f"{key}.path")
    if not path.is_file():
        raise ctx.fail(f"{key}.path", f"trajectory file {path} does not exist")
    return read_trajectory(path)


_OLD_LIGHT_KEYS = {
    "irradiance": "give 'illuminance_lux' instead: lux on a surface facing the light (office "
                  "light is 300-500 lux, daylight through a window 1,000-10,000)",
    "intensity": "give 'intensity_cd' instead: luminous intensity in candela (a 60 W "
                 "incandescent bulb is about 70 cd, a 50 W halogen spot 1,000-3,000 cd)",
}


def _photometric(ctx: _Ctx, table: Mapping[str, Any], key: str, name: str) -> np.ndarray:
    """A light's photometric value (``illuminance_lux`` or ``intensity_cd``), refused beyond
    :data:`MAX_ILLUMINANCE_LUX` or :data:`MAX_INTENSITY_CD` (a unit mistake)."""
    value = _color(ctx, table[name], f"{key}.{name}")
    limit, unit, example = ((MAX_ILLUMINANCE_LUX, "lux", "direct sunlight is about 100,000 lux")
                            if name == "illuminance_lux" else
                            (MAX_INTENSITY_CD, "cd", "a 50 W halogen spot is 1,000-3,000 cd"))
    if value.max() > limit:
        raise ctx.fail(f"{key}.{name}", f"{value.max():g} {unit} is brighter than the "
                                         f"{limit:,.0f} {unit} a scene may declare ({example})")
    return value


def _parse_light(ctx: _Ctx, raw: Any, key: str) -> Light:
    table = ctx.table(raw, key)
    if "type" not in table:
        raise ctx.fail(key, "missing required key 'type' (point, spot or directional)")
    for old, advice in _OLD_LIGHT_KEYS.items():
        if old in table:
            raise ctx.fail(f"{key}.{old}", f"lights are photometric (see scenes/README.md); "
                                           f"{advice}")
    kind = _string(ctx, table["type"], f"{key}.type", ("point", "spot", "directional"))
    vec3 = lambda c, v, k: _vector(c, v, k, 3)  # noqa: E731
    if kind == "point":
        ctx.keys(table, key, {"type", "position", "intensity_cd"}, set())
        return Light(kind, _photometric(ctx, table, key, "intensity_cd"),
                     position=vec3(ctx, table["position"], f"{key}.position"))
    if kind == "spot":
        ctx.keys(table, key, {"type", "position", "look_at", "intensity_cd"},
                 {"cutoff_angle", "beam_width"})
        cutoff = _get(ctx, table, key, "cutoff_angle", _number, 20.0)
        beam = _get(ctx, table, key, "beam_width", _number, cutoff * 0.75)
        if not 0 < beam <= cutoff < 90:
            raise ctx.fail(key, f"expected 0 < beam_width <= cutoff_angle < 90 degrees, got "
                                f"beam_width {beam}, cutoff_angle {cutoff}")
        return Light(kind, _photometric(ctx, table, key, "intensity_cd"),
                     position=vec3(ctx, table["position"], f"{key}.position"),
                     target=vec3(ctx, table["look_at"], f"{key}.look_at"),
                     cutoff_angle=cutoff, beam_width=beam)
    ctx.keys(table, key, {"type", "direction", "illuminance_lux"}, set())
    direction = vec3(ctx, table["direction"], f"{key}.direction")
    if not np.abs(direction).max() > 0:
        raise ctx.fail(f"{key}.direction", "expected a non-zero vector")
    direction = direction / np.abs(direction).max()     # at any scale: no overflow in the norm
    return Light(kind, _photometric(ctx, table, key, "illuminance_lux"),
                 direction=direction / np.linalg.norm(direction))


_TEXTURE_FIELDS = {
    "image": ({"type", "path"}, set()),
    "skimage": ({"type", "name"}, set()),
    "checkerboard": ({"type"}, {"squares", "color0", "color1"}),
    "noise": ({"type"}, {"resolution", "feature_size", "contrast", "mean"}),
    "shapes": ({"type"}, {"resolution", "count", "min_size", "max_size", "background"}),
}


def _parse_texture(ctx: _Ctx, raw: Any, key: str, base_dir: Path) -> dict[str, Any]:
    table = ctx.table(raw, key)
    if "type" not in table:
        raise ctx.fail(key, f"missing required key 'type' ({', '.join(_TEXTURE_FIELDS)})")
    kind = _string(ctx, table["type"], f"{key}.type", tuple(_TEXTURE_FIELDS))
    required, optional = _TEXTURE_FIELDS[kind]
    ctx.keys(table, key, required, optional)
    spec: dict[str, Any] = {"type": kind}
    for name, value in table.items():
        sub = f"{key}.{name}"
        if name == "type":
            continue
        if name == "path":
            path = base_dir / _string(ctx, value, sub)
            if not path.is_file():
                raise ctx.fail(sub, f"image file {path} does not exist")
            spec[name] = str(path)
        elif name == "name":
            from sim.textures import SKIMAGE_IMAGES

            spec[name] = _string(ctx, value, sub, SKIMAGE_IMAGES)
        elif name == "squares":
            spec[name] = [int(v) for v in _vector(ctx, value, sub, 2, positive=True)]
        elif name in ("resolution", "count"):
            spec[name] = _integer(ctx, value, sub, minimum=1)
        else:
            spec[name] = _number(ctx, value, sub, nonneg=True)
    return spec


def _parse_material(ctx: _Ctx, raw: Any, key: str, base_dir: Path) -> Material:
    table = ctx.table(raw, key)
    ctx.keys(table, key, set(), {"color", "texture", "texture_scale"})
    color = _get(ctx, table, key, "color", _color, np.array([0.5, 0.5, 0.5]))
    texture = None
    if "texture" in table:
        texture = _parse_texture(ctx, table["texture"], f"{key}.texture", base_dir)
    scale = _get(ctx, table, key, "texture_scale",
                 lambda c, v, k: _vector(c, v, k, 2, positive=True), np.ones(2))
    return Material(tuple(color), texture, tuple(scale))


def _parse_motion(ctx: _Ctx, raw: Any, key: str) -> ObjectMotion:
    table = ctx.table(raw, key)
    if "type" not in table:
        raise ctx.fail(key, "missing required key 'type' (linear or sine)")
    kind = _string(ctx, table["type"], f"{key}.type", ("linear", "sine"))
    vec3 = lambda c, v, k: _vector(c, v, k, 3)  # noqa: E731
    if kind == "linear":
        ctx.keys(table, key, {"type"}, {"velocity", "angular_velocity"})
        return ObjectMotion(
            kind,
            velocity=_get(ctx, table, key, "velocity", vec3, np.zeros(3)),
            angular_velocity=np.radians(_get(ctx, table, key, "angular_velocity", vec3,
                                             np.zeros(3))),
        )
    ctx.keys(table, key, {"type", "amplitude", "frequency"}, {"phase"})
    return ObjectMotion(
        kind,
        amplitude=vec3(ctx, table["amplitude"], f"{key}.amplitude"),
        frequency=_number(ctx, table["frequency"], f"{key}.frequency", nonneg=True),
        phase=_get(ctx, table, key, "phase", _number, 0.0),
    )


# shape -> (required keys, optional keys) beyond the common ones
_SHAPES: dict[str, tuple[set[str], set[str]]] = {
    "rectangle": ({"size"}, {"normal", "up"}),
    "box": ({"size"}, set()),
    "sphere": ({"radius"}, set()),
    "cylinder": ({"radius", "height"}, {"caps"}),
    "heightfield": ({"size", "amplitude", "wavelength"}, {"resolution"}),
    "mesh": ({"path"}, {"scale"}),
}
_COMMON = {"type", "name", "material", "motion", "center", "rotation"}


def _parse_object(ctx: _Ctx, raw: Any, key: str, base_dir: Path) -> SceneObject:
    table = ctx.table(raw, key)
    if "type" not in table:
        raise ctx.fail(key, f"missing required key 'type' ({', '.join(_SHAPES)})")
    shape = _string(ctx, table["type"], f"{key}.type", tuple(_SHAPES))
    required, optional = _SHAPES[shape]
    ctx.keys(table, key, required | {"type", "center"}, optional | _COMMON)
    center = _vector(ctx, table["center"], f"{key}.center", 3)
    params: dict[str, Any] = {}
    if shape == "rectangle":
        params["size"] = _vector(ctx, table["size"], f"{key}.size", 2, positive=True)
        if "rotation" in table and ("normal" in table or "up" in table):
            raise ctx.fail(key, "expected either 'rotation' or 'normal'/'up', not both")
        if "rotation" not in table:
            # The textured front face looks along `normal`; texture v runs along -`up`.
            normal = _get(ctx, table, key, "normal", lambda c, v, k: _vector(c, v, k, 3),
                          np.array([0.0, -1.0, 0.0]))
            up = _get(ctx, table, key, "up", lambda c, v, k: _vector(c, v, k, 3),
                      np.array([0.0, 0.0, 1.0]))
            try:
                # look_at gives an OpenCV camera frame looking *into* the face: x right, y down.
                frame = look_at(np.zeros(3), -normal, up)
            except ValueError as exc:
                raise ctx.fail(key, str(exc)) from None
            # Local rectangle frame: x right, y up, z = front normal.
            rotation = frame @ np.diag([1.0, -1.0, -1.0])
        else:
            rotation = rotation_from_euler(_vector(ctx, table["rotation"], f"{key}.rotation", 3))
    else:
        rotation = rotation_from_euler(
            _get(ctx, table, key, "rotation", lambda c, v, k: _vector(c, v, k, 3), np.zeros(3))
        )
    if shape == "box":
        params["size"] = _vector(ctx, table["size"], f"{key}.size", 3, positive=True)
    elif shape == "sphere":
        params["radius"] = _number(ctx, table["radius"], f"{key}.radius", positive=True)
    elif shape == "cylinder":
        params["radius"] = _number(ctx, table["radius"], f"{key}.radius", positive=True)
        params["height"] = _number(ctx, table["height"], f"{key}.height", positive=True)
        caps = table.get("caps", True)
        if not isinstance(caps, bool):
            raise ctx.fail(f"{key}.caps", f"expected true or false, got {_show(caps)}")
        params["caps"] = caps
    elif shape == "heightfield":
        params["size"] = _vector(ctx, table["size"], f"{key}.size", 2, positive=True)
        params["amplitude"] = _number(ctx, table["amplitude"], f"{key}.amplitude", nonneg=True)
        params["wavelength"] = _vector(ctx, table["wavelength"], f"{key}.wavelength", 2,
                                       positive=True)
        res = table.get("resolution", [128, 128])
        params["resolution"] = [int(v) for v in _vector(ctx, res, f"{key}.resolution", 2,
                                                        positive=True)]
        if min(params["resolution"]) < 2 or any(v != int(v) for v in res):
            raise ctx.fail(f"{key}.resolution", f"expected 2 integers >= 2, got {res}")
    elif shape == "mesh":
        given = _string(ctx, table["path"], f"{key}.path")
        if given.startswith(BUILTIN_MESH_PREFIX):
            try:
                path = builtin_mesh_path(given[len(BUILTIN_MESH_PREFIX):])
            except ValueError as exc:
                raise ctx.fail(f"{key}.path", str(exc)) from None
        else:
            path = base_dir / given
        if path.suffix.lower() not in (".obj", ".ply"):
            raise ctx.fail(f"{key}.path", f"expected an .obj or .ply file, got {path.name}")
        if not path.is_file():
            raise ctx.fail(f"{key}.path", f"mesh file {path} does not exist")
        params["path"] = str(path)
        params["scale"] = _get(ctx, table, key, "scale", lambda c, v, k: _number(c, v, k,
                               positive=True), 1.0)
    material = _parse_material(ctx, table.get("material", {}), f"{key}.material", base_dir)
    motion = _parse_motion(ctx, table["motion"], f"{key}.motion") if "motion" in table else None
    name = _string(ctx, table["name"], f"{key}.name") if "name" in table else key
    return SceneObject(name, shape, center, rotation, params, material, motion)


def _check_metres(ctx: _Ctx, objects: tuple[SceneObject, ...], trajectory: Trajectory,
                  duration: float) -> None:
    """Refuse a scene whose lengths are implausible in metres (written in millimetres).

    Bounds: :data:`MAX_OBJECT_SIZE_M` on every ``size``, ``radius`` and ``height``, and
    :data:`MAX_NEAREST_SURFACE_M` on the distance from the camera (at 100 times over
    ``[0, duration]``) to the nearest object's bounding box (meshes are skipped: their size is
    in their file; object motion is ignored).
    """
    for i, obj in enumerate(objects):
        for name in ("size", "radius", "height"):
            if name not in obj.params:
                continue
            value = np.atleast_1d(obj.params[name])
            if value.max() > MAX_OBJECT_SIZE_M:
                shown = obj.params[name]
                shown = [float(v) for v in shown] if np.ndim(shown) else float(shown)
                raise ctx.fail(f"[[objects]][{i}].{name} = {shown}",
                               f"scenes are in metres: {value.max():g} m is larger than the "
                               f"{MAX_OBJECT_SIZE_M:g} m an object may measure (millimetres?)")
    times = np.linspace(max(trajectory.t_start, 0.0), min(trajectory.t_end, duration), 100)
    with np.errstate(over="ignore", invalid="ignore"):      # checked just below
        positions = trajectory.pose(times)[:, :3, 3]
    if not np.isfinite(positions).all():
        raise ctx.fail("[trajectory]", "the camera's position overflows over [0, duration] "
                                       "(expected metres and m/s of a real scene)")
    nearest, which = np.inf, None
    for i, obj in enumerate(objects):
        if obj.shape == "mesh":                     # its extent is unknown before loading
            continue
        gaps = obj.distance_to(positions)
        if gaps.min() < nearest:
            nearest, which = float(gaps.min()), i
    if which is not None and nearest > MAX_NEAREST_SURFACE_M:
        obj = objects[which]
        raise ctx.fail(f"[[objects]][{which}].center = {[float(v) for v in obj.center]}",
                       f"scenes are in metres: the nearest object, {obj.name!r}, comes no "
                       f"nearer than {nearest:.4g} m to the camera, beyond the "
                       f"{MAX_NEAREST_SURFACE_M:g} m allowed (millimetres?)")


def parse_scene(text: str, source: str | Path = "<scene>", *, seed: int | None = None) -> Scene:
    """Parse and validate the TOML text of a scene.

    Parameters
    ----------
    text : str
        TOML document.
    source : str or Path
        Where it came from, for messages and for resolving relative paths.
    seed : int, optional
        Replaces the file's ``seed`` (random textures, default trajectory phases, noise).

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        Invalid TOML, an unknown key, a missing field or a wrong type; the message names the
        file, the key and what was expected.
    """
    ctx = _Ctx(str(source))
    source_path = Path(source) if not str(source).startswith("<") else None
    base_dir = source_path.parent if source_path is not None else Path.cwd()
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{source}: not valid TOML: {exc}{bom_hint(text)}") from None
    top_required = {"duration", "trajectory", "objects"}
    top_optional = {"name", "description", "seed", "frames", "render", "lights", "depth_range",
                    "rig", "up", "imu", "camera", "event_camera", "frame_camera"}
    ctx.keys(raw, "top level", top_required, top_optional)
    name = _get(ctx, raw, "", "name", _string, source_path.stem if source_path else "scene")
    description = _get(ctx, raw, "", "description", _string, "")
    duration = _number(ctx, raw["duration"], "duration", positive=True)
    file_seed = _get(ctx, raw, "", "seed", _seed, 0)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)
                             or not 0 <= seed <= MAX_SEED):
        raise SceneError(f"seed {seed!r} (given to replace the seed of {source}): expected an "
                         f"integer in 0..{MAX_SEED} (2**32 - 1)")
    seed = file_seed if seed is None else seed
    depth_range = _declared_depth_range(ctx, raw)
    camera, frame_camera = _parse_cameras(ctx, raw)
    frames = _parse_frames(ctx, raw.get("frames", {}))
    render = _parse_render(ctx, raw.get("render", {}))
    rig = _parse_rig(ctx, raw.get("rig", {}))
    up = _get(ctx, raw, "", "up", _parse_up, (0.0, 0.0, 1.0))
    imu = _parse_imu(ctx, raw.get("imu", {}))
    trajectory = _parse_trajectory(ctx, raw["trajectory"], base_dir, seed)
    if not (trajectory.t_start <= 0 and duration <= trajectory.t_end):
        raise ctx.fail("duration", f"the trajectory covers [{trajectory.t_start}, "
                                   f"{trajectory.t_end}] s, which does not contain [0, {duration}]")
    lights_raw = raw.get("lights", [])
    if not isinstance(lights_raw, list) or not lights_raw:
        raise ctx.fail("[[lights]]", "expected at least one [[lights]] table")
    lights = tuple(_parse_light(ctx, item, f"[[lights]][{i}]") for i, item in
                   enumerate(lights_raw))
    objects_raw = raw["objects"]
    if not isinstance(objects_raw, list) or not objects_raw:
        raise ctx.fail("[[objects]]", "expected at least one [[objects]] table")
    objects = tuple(_parse_object(ctx, item, f"[[objects]][{i}]", base_dir)
                    for i, item in enumerate(objects_raw))
    names = [obj.name for obj in objects]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate is not None:
        raise ctx.fail("[[objects]]", f"object name {duplicate!r} is used twice")
    _check_metres(ctx, objects, trajectory, duration)
    if frame_camera is not None and frame_camera.rolling and any(o.motion for o in objects):
        raise ctx.fail("[frame_camera].shutter", "a rolling shutter is simulated for static "
                       "scenes only (each row has its own pose, the objects one time per "
                       "render); remove the objects' motion or use shutter = \"global\"")
    return Scene(name, description, duration, seed, camera, frames, render, trajectory, lights,
                 objects, source_path, text, depth_range, rig, up, imu, frame_camera)


def _declared_depth_range(ctx: _Ctx, raw: Mapping[str, Any]) -> tuple[float, float] | None:
    return _get(ctx, raw, "", "depth_range", _depth_range)


def declared_depth_range(text: str, source: str | Path = "<scene>") -> tuple[float, float] | None:
    """The working depth range a scene's TOML text declares (top-level ``depth_range``).

    The one reader of ``depth_range``: :func:`parse_scene` uses it, and so does whoever needs the
    range of a scene kept as text (the scene a simulated sequence recorded in its
    ``sequence.json``) without building the whole scene.

    Parameters
    ----------
    text : str
        TOML document of a scene.
    source : str or Path
        Where it came from, for messages.

    Returns
    -------
    (float, float) or None, metres
        ``(near, far)``, or None when the scene declares none.

    Raises
    ------
    SceneError
        Invalid TOML, or a ``depth_range`` that is not ``[near, far]`` metres with
        ``0 < near < far``; the message names ``source`` and the key.
    """
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{source}: not valid TOML: {exc}{bom_hint(text)}") from None
    return _declared_depth_range(_Ctx(str(source)), raw)


def load_scene(path: str | Path, *, seed: int | None = None) -> Scene:
    """Read and validate a scene file (see :func:`parse_scene`; ``seed`` replaces the file's).

    Raises
    ------
    SceneError
        The file is missing or unreadable, or its content is invalid.
    """
    from sim.sequence import describe_data_file

    path = Path(path)
    what = describe_data_file(path) if path.suffix.lower() != ".toml" else None
    if what is not None:
        raise SceneError(f"{path} is {what}, not a scene file (TOML); expected a .toml scene")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path}: cannot read scene file: {exc}") from None
    return parse_scene(text, path, seed=seed)
