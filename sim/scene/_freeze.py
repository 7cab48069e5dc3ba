"""A dynamic scene with its moving objects frozen at one time (:func:`freeze_scene`, a control:
the same scene, nothing moving), through TOML text written from the scene's own."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from typing import Any

import numpy as np

from sim.scene._model import Scene
from sim.scene._toml import parse_scene

__all__ = ["euler_from_rotation", "freeze_scene"]


def euler_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """Euler angles (3,) in DEGREES of a rotation, the inverse of
    :func:`sim.se3.rotation_from_euler` (``R = Rz @ Ry @ Rx``; at ``Ry = +-90`` degrees, where
    only ``Rz - Rx`` or ``Rz + Rx`` is defined, ``Rx = 0``)."""
    r = np.asarray(rotation, dtype=np.float64)
    cos_b = math.hypot(r[0, 0], r[1, 0])
    b = math.atan2(-r[2, 0], cos_b)
    if cos_b > 1e-9:
        a, c = math.atan2(r[2, 1], r[2, 2]), math.atan2(r[1, 0], r[0, 0])
    else:
        a, c = 0.0, math.atan2(-r[0, 1], r[1, 1])
    return np.degrees([a, b, c])


def _toml_key(key: str) -> str:
    import json
    import re

    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _toml_value(value: Any) -> str:
    """A TOML value as inline text (tables inline)."""
    import json

    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return repr(float(value))          # nan, inf and -inf are TOML's own spellings
    if isinstance(value, str):
        return json.dumps(value)           # a TOML basic string (its escapes are JSON's)
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}"
                               for k, v in value.items()) + "}"
    if isinstance(value, list | tuple | np.ndarray):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")


def _toml_text(document: Mapping[str, Any]) -> str:
    """TOML text of a parsed scene document: top-level values, then tables and arrays of
    tables, each entry on its own line with nested tables inline."""
    def is_tables(value):
        return isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value)

    lines = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in document.items()
             if not isinstance(v, Mapping) and not is_tables(v)]
    for key, value in document.items():
        if isinstance(value, Mapping):
            lines += ["", f"[{_toml_key(key)}]"]
            lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()]
        elif is_tables(value):
            for table in value:
                lines += ["", f"[[{_toml_key(key)}]]"]
                lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def freeze_scene(scene: Scene, t: float) -> Scene:
    """The same scene with every moving object frozen where it is at time ``t``.

    Each object with a ``motion`` loses it and takes its pose at ``t``
    (:meth:`SceneObject.pose`) as its ``center`` and ``rotation`` (Euler degrees, replacing a
    rectangle's ``normal`` / ``up``); everything else is the scene's own. The scene is rebuilt
    from TOML text written from its own (``Scene.text``), so that the frozen scene's text, which
    a simulated sequence records and its scoring re-reads, describes it. Its name gets
    ``_frozen``.

    Parameters
    ----------
    scene : Scene
        Parsed from its text (``Scene.text``), as :func:`parse_scene` and :func:`load_scene`
        make it.
    t : float, seconds

    Returns
    -------
    Scene
        With ``source`` and ``seed`` the scene's (its textures and meshes are found as before).

    Raises
    ------
    ValueError
        ``t`` not finite, or a scene without its TOML text.
    """
    if not math.isfinite(t):
        raise ValueError(f"t must be a finite time in seconds, got {t}")
    if not scene.text:
        raise ValueError("the scene has no TOML text (Scene.text) to freeze")
    document = tomllib.loads(scene.text)
    raw_objects = document["objects"]
    for obj, raw in zip(scene.objects, raw_objects, strict=True):
        if obj.motion is None:
            continue
        pose = obj.pose(float(t))
        raw.pop("motion")
        raw["center"] = [float(v) for v in pose[:3, 3]]
        if not np.array_equal(pose[:3, :3], obj.rotation):
            for key in ("rotation", "normal", "up"):
                raw.pop(key, None)
            raw["rotation"] = [float(v) for v in euler_from_rotation(pose[:3, :3])]
    document["name"] = f"{scene.name}_frozen"
    document["description"] = (f"{scene.description} (moving objects frozen where they are "
                               f"at {float(t):g} s)").strip()
    source = scene.source if scene.source is not None else "<frozen scene>"
    return parse_scene(_toml_text(document), source, seed=scene.seed)
