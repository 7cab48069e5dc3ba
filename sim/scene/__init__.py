"""Scene files: a TOML description of a camera, its motion, lights and textured objects.

A scene file is validated completely before anything is rendered: an unknown key, a missing
field or a wrong type raises :class:`SceneError` naming the file, the key and what was expected.
The format is documented field by field in ``scenes/README.md``; ``scenes/*.toml`` are examples.

World frame: any right-handed frame; the built-in scenes use z up. Lengths in metres, angles in
degrees in scene files (radians inside the code), times in seconds.

Modules (private; everything public is re-exported here):

- ``_model``: the parsed scene's dataclasses (:class:`Scene`, :class:`SceneObject`, ...) and
  :class:`SceneError`.
- ``_toml``: the scene file parser (:func:`load_scene`, :func:`parse_scene`,
  :func:`declared_depth_range`) and its limits (``MAX_*``).
- ``_freeze``: :func:`freeze_scene`, a dynamic scene with its objects frozen at one time.
- ``_meshes``: the built-in meshes (``path = "builtin:NAME"`` in a scene file,
  :func:`builtin_mesh_path`, :func:`obj_vertices`) and a height field's grid
  (:func:`heightfield_mesh`), a mesh's vertex normals summed in a fixed order
  (:func:`vertex_normals`).
- ``procedural``: random scene files per seed, the ``tabletop`` and ``room`` families
  (:func:`tabletop_scene`, :func:`room_scene`, :data:`PROCEDURAL_FAMILIES`, their ranges
  :class:`TabletopRanges` / :class:`RoomRanges`, and :func:`trajectory_check`).
- ``families`` (public, imported by name): scene families with a difficulty knob
  (:func:`sim.scene.families.family_scene`), for ``evfuse bench --family`` and sweeps.
"""

from __future__ import annotations

from sim.scene._freeze import euler_from_rotation, freeze_scene
from sim.scene._meshes import (
    BUILTIN_MESH_PREFIX,
    BUILTIN_MESHES,
    builtin_mesh_path,
    heightfield_mesh,
    obj_vertices,
    vertex_normals,
)
from sim.scene._model import (
    Light,
    Material,
    ObjectMotion,
    RenderParams,
    Scene,
    SceneError,
    SceneObject,
)
from sim.scene._toml import (
    MAX_ILLUMINANCE_LUX,
    MAX_INTENSITY_CD,
    MAX_NEAREST_SURFACE_M,
    MAX_OBJECT_SIZE_M,
    declared_depth_range,
    load_scene,
    parse_scene,
)
from sim.scene.procedural import (
    GAP_M,
    GENERATOR_VERSION,
    OBJECT_KINDS,
    PROCEDURAL_FAMILIES,
    RoomRanges,
    SceneRanges,
    TabletopRanges,
    procedural_scene,
    room_scene,
    tabletop_scene,
    trajectory_check,
)

__all__ = [
    "BUILTIN_MESHES",
    "BUILTIN_MESH_PREFIX",
    "GAP_M",
    "GENERATOR_VERSION",
    "Light",
    "MAX_ILLUMINANCE_LUX",
    "MAX_INTENSITY_CD",
    "MAX_NEAREST_SURFACE_M",
    "MAX_OBJECT_SIZE_M",
    "Material",
    "OBJECT_KINDS",
    "ObjectMotion",
    "PROCEDURAL_FAMILIES",
    "RenderParams",
    "RoomRanges",
    "Scene",
    "SceneError",
    "SceneObject",
    "SceneRanges",
    "TabletopRanges",
    "builtin_mesh_path",
    "declared_depth_range",
    "euler_from_rotation",
    "freeze_scene",
    "heightfield_mesh",
    "load_scene",
    "obj_vertices",
    "parse_scene",
    "procedural_scene",
    "room_scene",
    "tabletop_scene",
    "trajectory_check",
    "vertex_normals",
]
