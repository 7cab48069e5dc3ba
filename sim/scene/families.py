"""Scene families with a difficulty knob, for ``evfuse bench --family`` and sweeps
(``family = ...`` in a sweep file, :mod:`sim.dataset`).

Each family writes a scene file (TOML text) from a few parameters that set how hard its surface
is to fill; everything else (the DAVIS240C camera, a slider moving 10 cm/s, two lights, a
textured brick wall 1.6 m away) stays fixed, so that a table over one knob shows what that knob
costs. Every parameter has a default (the middle of its useful range) and a valid range, checked
in one line naming it:

=============  ==========================================================================
family         knobs
=============  ==========================================================================
``staircase``  ``steps`` (1-12 boxes, the first 0.6 m away), ``step_depth`` (m between
               two steps, default min(0.2, 0.8 / (steps - 1)); the last step must stay
               0.2 m in front of the wall)
``sphere``     ``radius`` (m), ``distance`` (m), ``shadow`` (0/1: a point light that casts
               the sphere's shadow on the wall, or light from the camera's side only); its
               front, ``distance - radius``, must stay 0.2 m from the camera
``cylinder``   ``radius`` (m), ``distance`` (m); as the sphere's, its front 0.2 m away
``slanted``    ``angle`` (degrees between the poster and the image plane, 0-75)
``heightfield`` ``amplitude`` (m), ``wavelength`` (m)
=============  ==========================================================================

and every family takes ``texture`` (1: textured objects, 0: plain gray ones, which give events
only at their outlines).

Each member declares the working depth range that its own geometry spans (see
:func:`geometry_depth_range`): the DSI's range, so that the map covers every surface from the
nearest object to the wall.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sim.scene import parse_scene
from sim.validation import ParameterError

__all__ = ["FAMILIES", "KNOBS", "family_scene", "family_variants", "geometry_depth_range",
           "write_family"]

MIN_FRONT_M = 0.2
"""Nearest a sphere's or cylinder's front (``distance - radius``) may come to the camera, m."""
DEPTH_MARGIN = 0.1
"""Relative margin of :func:`geometry_depth_range` on both sides of the geometry's bounds."""

_COMMON = """duration = 3.0
seed = {seed}

[camera]
preset = "davis240c"

[frames]
rate = 24.0
exposure = 0.005

[trajectory]
type = "linear"
position = [-0.15, 0.0, 0.0]
velocity = [0.1, 0.0, 0.0]
look_at = [-0.05, 1.0, 0.0]

[[lights]]
type = "directional"
direction = [0.3, 1.0, -0.5]
illuminance_lux = 400.0

[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 1.6, 0.0]
size = [4.0, 3.0]
normal = [0.0, -1.0, 0.0]
material = {{ texture = {{ type = "skimage", name = "brick" }}, texture_scale = [4.0, 3.0] }}
"""

FAMILIES: dict[str, dict[str, tuple[float, float, float]]] = {
    "staircase": {"steps": (4, 1, 12), "step_depth": (0.2, 0.05, 0.8)},
    "sphere": {"radius": (0.25, 0.05, 0.5), "distance": (0.9, 0.5, 1.4), "shadow": (1, 0, 1)},
    "cylinder": {"radius": (0.2, 0.05, 0.5), "distance": (0.9, 0.5, 1.4)},
    "slanted": {"angle": (50.0, 0.0, 75.0)},
    "heightfield": {"amplitude": (0.08, 0.0, 0.2), "wavelength": (0.4, 0.1, 1.0)},
}
"""Each family's knobs: (default, lowest, highest); ``texture`` (0 or 1, default 1) on top."""

KNOBS = ("steps", "step_depth", "radius", "distance", "shadow", "angle", "amplitude",
         "wavelength", "texture")
"""Every knob of every family, in the order ``evfuse bench`` lists them."""


def _material(textured: bool, kind: str) -> str:
    if not textured:
        return '{ color = [0.5, 0.5, 0.5] }'
    return '{ texture = { type = "noise", feature_size = 4.0, contrast = 0.6 } }'


def _checked(family: str, knobs: dict) -> dict:
    if family not in FAMILIES:
        raise ParameterError(f"{{family}} {ParameterError.literal(family)}: expected one of "
                             f"{', '.join(FAMILIES)}", family="family")
    allowed = {**FAMILIES[family], "texture": (1, 0, 1)}
    unknown = sorted(set(knobs) - set(allowed))
    if unknown:
        raise ParameterError(f"{{family}} {family} has no knob "
                             f"{ParameterError.literal(repr(unknown[0]))}; its knobs: "
                             f"{', '.join(allowed)}", family="family")
    values = {}
    for name, (default, low, high) in allowed.items():
        value = float(knobs.get(name, default))
        if not (math.isfinite(value) and low <= value <= high):
            raise ParameterError(f"{{{name}}} {value:g}: expected {low:g} to {high:g} for the "
                                 f"{family} family", **{name: name})
        values[name] = value
    return values


def family_scene(family: str, **knobs: float) -> str:
    """The scene file (TOML text) of one member of a family.

    Parameters
    ----------
    family : str
        One of :data:`FAMILIES`.
    **knobs : float
        The family's knobs (see the module docstring); missing ones take their defaults.

    Returns
    -------
    str
        A complete scene file; its ``name`` says the family and every knob's value.

    Raises
    ------
    ValueError
        An unknown family or knob, or a value outside the knob's range (one line naming it).
    """
    given_steps = knobs.get("steps", FAMILIES["staircase"]["steps"][0])
    if family == "staircase" and "step_depth" not in knobs and math.isfinite(given_steps):
        # By default the steps share 0.8 m (at most 0.2 m each): any count fits before the wall.
        # (A NaN or infinite count is left to _checked, which names the knob.)
        steps = round(given_steps)
        knobs = {**knobs, "step_depth": math.floor(1e4 * min(0.2, 0.8 / max(steps - 1, 1))) / 1e4}
    k = _checked(family, knobs)
    textured = k.pop("texture") >= 0.5
    name = f"{family}_" + "_".join(f"{key}{value:g}" for key, value in k.items()) + \
        ("" if textured else "_plain")
    objects = []
    lights = ""
    if family in ("sphere", "cylinder") and k["distance"] - k["radius"] < MIN_FRONT_M:
        raise ParameterError(f"{{radius}} {k['radius']:g} with {{distance}} {k['distance']:g}: "
                             f"the {family}'s front would come within {MIN_FRONT_M:g} m of the "
                             f"camera; expected distance - radius >= {MIN_FRONT_M:g} m",
                             radius="radius", distance="distance")
    if family == "staircase":
        steps = int(round(k["steps"]))
        if 0.6 + (steps - 1) * k["step_depth"] > 1.4:
            raise ParameterError(f"{{steps}} {steps} with {{step_depth}} {k['step_depth']:g}: the "
                                 "last step would stand at or behind the wall (1.6 m); expected "
                                 "0.6 + (steps - 1) step_depth <= 1.4 m", steps="steps",
                                 step_depth="step_depth")
        for i in range(steps):
            depth = 0.6 + i * k["step_depth"]
            height = 0.3 + 0.15 * i
            objects.append(("box", f'center = [{-0.45 + 0.9 * i / max(steps - 1, 1):.3f}, '
                                   f'{depth:.3f}, {-0.4 + height / 2:.3f}]\n'
                                   f'size = [{0.9 / steps:.3f}, 0.2, {height:.3f}]'))
    elif family == "sphere":
        objects.append(("sphere", f'center = [0.0, {k["distance"]:.3f}, 0.0]\n'
                                  f'radius = {k["radius"]:.3f}'))
        if k["shadow"] >= 0.5:
            lights = ('[[lights]]\ntype = "point"\nposition = [-0.5, 0.2, 0.5]\n'
                      'intensity_cd = 80.0\n\n')
    elif family == "cylinder":
        objects.append(("cylinder", f'center = [0.0, {k["distance"]:.3f}, 0.0]\n'
                                    f'radius = {k["radius"]:.3f}\nheight = 1.5'))
    elif family == "slanted":
        angle = math.radians(k["angle"])
        normal = f"[{math.sin(angle):.4f}, {-math.cos(angle):.4f}, 0.0]"
        objects.append(("rectangle", f'center = [0.0, 1.0, 0.0]\nsize = [0.9, 0.7]\n'
                                     f'normal = {normal}'))
    else:
        objects.append(("heightfield", f'center = [0.0, 1.0, 0.0]\nsize = [1.6, 1.2]\n'
                                       'rotation = [90.0, 0.0, 0.0]\n'
                                       f'amplitude = {k["amplitude"]:.4f}\n'
                                       f'wavelength = [{k["wavelength"]:.3f}, '
                                       f'{k["wavelength"]:.3f}]\nresolution = [160, 120]'))
    text = [f'# Generated by fusion.experiments.families: the {family} family, {name}.\n'
            f'name = "{name}"\n'
            f'description = "{family} family ({", ".join(f"{a} {b:g}" for a, b in k.items())}'
            f'{", plain" if not textured else ""})"\n',
            _COMMON.format(seed=17), lights]
    for i, (shape, body) in enumerate(objects):
        text.append(f'[[objects]]\nname = "{family}{i}"\ntype = "{shape}"\n{body}\n'
                    f'material = {_material(textured, str(i + 1))}\n\n')
    body = "\n".join(text)
    near, far = geometry_depth_range(parse_scene(body, f"<{name}>"))
    # The declared range goes right after the duration (top-level keys precede the tables).
    # The texts keep naming fusion.experiments.families (the module's old path, still
    # importable): the scene files, and the simulations cached by their text, stay the same.
    return body.replace("duration = 3.0\n", f"duration = 3.0\ndepth_range = [{near:.2f}, "
                        f"{far:.2f}]   # from the geometry (fusion.experiments.families)\n", 1)


def geometry_depth_range(scene) -> tuple[float, float]:
    """A working depth range that contains every exact depth the scene can show, m.

    Bounds the z-depth, in the camera along the trajectory (at 11 times over ``[0, duration]``,
    which are exact for a linear trajectory: z-depth is affine in the camera's position), of
    the corners of every object's bounding box (at rest; meshes are not supported), widened by
    :data:`DEPTH_MARGIN` on both sides and rounded outwards to centimetres. Every surface point
    lies in its object's box, so every exact depth lies in the range.

    Parameters
    ----------
    scene : sim.scene.Scene
        A scene without meshes or moving objects (the families').

    Returns
    -------
    (float, float)
        ``(near, far)``, metres, ``0 < near < far``.

    Raises
    ------
    ValueError
        A mesh or a moving object, or an object that reaches the camera (no positive near).
    """
    corners = []
    unit = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    for obj in scene.objects:
        if obj.shape == "mesh" or obj.motion is not None:
            raise ValueError(f"object {obj.name!r}: a mesh or a moving object has no bounds here")
        corners.append(obj.center + (unit * obj.half_extents()) @ np.asarray(obj.rotation).T)
    points = np.concatenate(corners)
    poses = scene.trajectory.pose(np.linspace(0.0, scene.duration, 11))
    # z-depth of world point P in camera (R, C): the third row of R^T (P - C).
    z = np.einsum("ni,nki->nk", poses[:, :3, 2], points[None] - poses[:, None, :3, 3])
    near, far = float(z.min()), float(z.max())
    if not near > 0:
        raise ValueError(f"an object reaches the camera (nearest bound {near:.3g} m): no "
                         "positive depth range")
    return (math.floor(100 * near * (1 - DEPTH_MARGIN)) / 100,
            math.ceil(100 * far * (1 + DEPTH_MARGIN)) / 100)


def family_variants(family: str, knobs: dict[str, list[float]]) -> list[str]:
    """The scene files of every combination of the knobs' values (others at their defaults).

    Parameters
    ----------
    family : str
    knobs : dict of str to list of float
        Values of each knob to vary, e.g. ``{"steps": [2, 4, 8]}``.

    Returns
    -------
    list of str
        One scene file (TOML text) per combination, in the order of the values.
    """
    combos: list[dict] = [{}]
    for name, values in knobs.items():
        combos = [{**combo, name: value} for combo in combos for value in values]
    return [family_scene(family, **combo) for combo in combos]


def write_family(family: str, knobs: dict[str, list[float]], folder: str | Path) -> list[Path]:
    """Write the scene file of each member of a family (:func:`family_variants`) into a folder.

    Parameters
    ----------
    family : str
        One of :data:`FAMILIES`.
    knobs : dict of str to list of float
        Values of each knob to vary.
    folder : str or Path
        Created if missing; each member is written to ``<folder>/<its scene name>.toml``
        (replacing a file of that name).

    Returns
    -------
    list of Path
        The scene files, in the order of :func:`family_variants`.

    Raises
    ------
    ParameterError
        An unknown family or knob, or a value out of range (before any file is written).
    """
    texts = family_variants(family, knobs)           # refused knobs: before any folder
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for text in texts:
        name = text.split('name = "', 1)[1].split('"', 1)[0]
        path = folder / f"{name}.toml"
        path.write_text(text)
        files.append(path)
    return files
