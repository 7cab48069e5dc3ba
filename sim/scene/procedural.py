"""Procedural scenes: a random scene file per seed, so that a dataset has variety.

Two families, each a function of a seed and optional ranges that returns a plain scene TOML
text (``parse_scene`` reads it, ``evfuse simulate`` renders it, alone, from any folder):

- :func:`tabletop_scene`: a table (a textured box) in a closed room, with objects on its top;
- :func:`room_scene`: a closed room with larger objects on its floor.

Per seed (one :class:`numpy.random.Generator` drawn from the seed alone, so the same seed and
ranges give the same text, byte for byte), within the ranges of :class:`TabletopRanges` /
:class:`RoomRanges`:

- a random number of objects with every built-in kind among them (box, sphere, cylinder,
  height field, mesh: :data:`~sim.scene._meshes.BUILTIN_MESHES`), random sizes and turns about
  the vertical, resting on the support (their lowest point on it, at most 0.1 mm above) and
  placed without interpenetration: the footprints' bounding discs (exact for each shape:
  a box's half diagonal, a sphere's or cylinder's radius, a mesh's farthest vertex from its
  axis, a height field's half diagonal) are at least :data:`GAP_M` apart;
- random textures from :mod:`sim.textures` (scikit-image's images, smooth noise, random
  shapes, checkerboards) with random repeat counts;
- point lights under the ceiling: the first (the key) above the objects, its intensity (cd) set
  by the illuminance it gives at the objects' centre, drawn in ``illuminance_lux`` (lux, indoor
  lighting); the others (fills) a drawn fraction of the key's intensity;
- ``[frames] max_exposure`` = :data:`MAX_EXPOSURE_S` (40 ms, the built-in scenes'): a realistic
  frame sensor's auto-exposure (the one a dataset job picks with ``frame_sensor``) exposes the
  frames as a camera would in that light (the file's own sensor is ``ideal``);
- a hand-held (sums of sines about a mean pose) or an orbit (a keyframe spline on a circle
  about the objects) trajectory looking at the objects, accepted only when it keeps the
  objects in view and the whole view inside the declared ``depth_range`` (see
  :func:`trajectory_check`), else drawn again (at most ``max_redraws`` times in all, then a
  :class:`~sim.validation.ParameterError` naming the ranges to widen).

The check's last step renders the exact depth of a few views. This module is part of the scene
model, which the renderer reads, so it does not import the renderer: that step is
:func:`sim.scene_check.exact_depth_check`, above both, which :mod:`sim` hands down here once
(:func:`use_exact_depth_check`) before anything can draw.

The text starts with a comment naming the family, the seed and :data:`GENERATOR_VERSION`; a
change of the generator that changes any drawn text raises the version.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from sim.scene._meshes import BUILTIN_MESHES, builtin_mesh_path, heightfield_mesh, obj_vertices
from sim.scene._model import Scene
from sim.scene._toml import parse_scene
from sim.textures import SKIMAGE_IMAGES
from sim.validation import ParameterError, check_parameter, integer, non_negative, positive

__all__ = ["GAP_M", "GENERATOR_VERSION", "MAX_EXPOSURE_S", "OBJECT_KINDS", "PROCEDURAL_FAMILIES",
           "ExactDepthCheck", "RoomRanges", "SceneRanges", "TabletopRanges", "procedural_scene",
           "room_scene", "tabletop_scene", "trajectory_check", "use_exact_depth_check"]

GENERATOR_VERSION = 2
"""Version of the drawing rules: the same seed, ranges and version give the same text."""
MAX_EXPOSURE_S = 0.04
"""``[frames] max_exposure`` of every drawn scene, seconds: the built-in scenes' (the 24-Hz frame
period less 1.7 ms)."""
GAP_M = 0.005
"""Least gap between two placed objects' footprint discs, metres."""
OBJECT_KINDS = ("box", "sphere", "cylinder", "heightfield", "mesh")
"""The object kinds placed on a support; every drawn scene has each of them at least once."""
_PLACEMENT_TRIES = 200          # positions tried for one object before the layout is redrawn
_WALL_OVERLAP_M = 0.05          # walls reach this far past the room's edges: no crack between
_IMAGE_MARGIN = 0.05            # fraction of the image size kept clear around object centres

ExactDepthCheck = Callable[..., str | None]
"""The exact-depth step of :func:`trajectory_check`: ``check(scene, *, views, size, variant)``
returns why the rendered exact depth is refused, or None
(:func:`sim.scene_check.exact_depth_check`)."""
_exact_depth_check: ExactDepthCheck | None = None
"""The check :func:`use_exact_depth_check` was given (by :mod:`sim`, on import)."""


def use_exact_depth_check(check: ExactDepthCheck) -> None:
    """Set the exact-depth step of :func:`trajectory_check` (and so of every draw).

    :mod:`sim` calls it once on import with :func:`sim.scene_check.exact_depth_check`, which
    renders: the scene model may not import the renderer, so the check is handed down from
    above. Importing this module imports :mod:`sim` first, so the check is set before any draw.

    Parameters
    ----------
    check : callable
        ``check(scene, *, views, size, variant) -> str | None`` (:data:`ExactDepthCheck`).
    """
    global _exact_depth_check
    _exact_depth_check = check


@dataclass(frozen=True)
class SceneRanges:
    """The ranges a procedural scene is drawn in; ``(low, high)`` pairs are drawn uniformly.

    Attributes
    ----------
    duration : float, seconds
        Length of the scene (its trajectory covers ``[0, duration]``).
    objects : (int, int)
        Number of placed objects (at least ``len(OBJECT_KINDS)``: every kind is in each scene).
    object_size : (float, float), metres
        An object's footprint half-size (a sphere's radius, half a box's side, ...).
    room_width, room_depth, room_height : (float, float), metres
        The closed room around everything (x, y and z extent).
    lights : (int, int)
        Number of point lights under the ceiling (the first above the objects; a closed room
        leaves no way in for a directional light).
    illuminance_lux : (float, float), lux
        Illuminance the first (key) light alone gives at the objects' centre on a surface facing
        up, unoccluded; its intensity follows from it (``I = E d^3 / h``, ``d`` its distance to
        that point and ``h`` its height above it). The defaults span indoor lighting from a
        corridor's or a living room's (200 lux) to a bright workplace's (1,000 lux; offices
        300-500). At the floor, with auto-exposure up to 40 ms (``[frames] max_exposure``), the
        DAVIS240C's APS frames of seeds 0-99 of both families had mean greys of 55-103 / 255
        (``benchmarks/bench_procedural_exposure.py --illuminance 200 --seeds 100 --size
        120x90 --end 0.5``).
    fill_fraction : (float, float)
        Each other (fill) light's intensity as a fraction of the key light's.
    texture_scale : (float, float)
        How many times an object's texture repeats along u and along v.
    trajectories : tuple of {"handheld", "orbit"}
        The trajectory kinds drawn from (uniformly).
    camera_distance : (float, float), metres
        Horizontal distance from the camera (mean position, or the orbit's radius) to the point
        it looks at (the objects' centre).
    camera_elevation : (float, float), degrees
        Angle of the camera above that point, seen from it.
    handheld_translation : (float, float), metres
        Amplitude of the hand-held shake along each camera axis.
    handheld_rotation : (float, float), degrees
        Amplitude of the hand-held turn about each camera axis.
    handheld_frequency : (float, float), Hz
        Frequency of each of the six hand-held sines.
    orbit_arc : (float, float), degrees
        How far an orbit turns about the objects over the duration (either way).
    depth_range : (float, float), metres
        The declared working depth range (``depth_range`` of the scene file): every exact depth
        of every view lies inside it (:func:`trajectory_check`).
    check_views : int
        Views rendered at ``check_size`` to check the exact depth (evenly over the duration).
    check_size : (int, int), pixels
        Width and height of those renders.
    max_redraws : int
        Draws (layout, lights, trajectory) tried before giving up with an error.
    """

    duration: float = 10.0
    objects: tuple[int, int] = (5, 8)
    object_size: tuple[float, float] = (0.04, 0.1)
    room_width: tuple[float, float] = (3.0, 3.6)
    room_depth: tuple[float, float] = (3.0, 3.6)
    room_height: tuple[float, float] = (2.4, 2.8)
    lights: tuple[int, int] = (1, 3)
    illuminance_lux: tuple[float, float] = (200.0, 1000.0)
    fill_fraction: tuple[float, float] = (0.2, 1.0)
    texture_scale: tuple[float, float] = (1.0, 4.0)
    trajectories: tuple[str, ...] = ("handheld", "orbit")
    camera_distance: tuple[float, float] = (0.8, 1.3)
    camera_elevation: tuple[float, float] = (30.0, 60.0)
    handheld_translation: tuple[float, float] = (0.01, 0.05)
    handheld_rotation: tuple[float, float] = (1.0, 4.0)
    handheld_frequency: tuple[float, float] = (0.1, 0.5)
    orbit_arc: tuple[float, float] = (20.0, 90.0)
    depth_range: tuple[float, float] = (0.25, 5.0)
    check_views: int = 12
    check_size: tuple[int, int] = (40, 30)
    max_redraws: int = 30

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "trajectories":
                value = _kinds(value)
            elif item.name == "check_size":
                value = tuple(_count(item.name, size) for size in _two(item.name, value))
            elif isinstance(item.default, tuple):
                value = _pair(item.name, value, integers=isinstance(item.default[0], int))
            elif isinstance(item.default, int):
                value = _count(item.name, value)
            else:
                value = check_parameter(positive, item.name, value)
            object.__setattr__(self, item.name, value)
        if self.objects[0] < len(OBJECT_KINDS):
            raise ParameterError(f"{{objects}} {list(self.objects)}: expected at least "
                                 f"{len(OBJECT_KINDS)} objects (one of each kind: "
                                 f"{', '.join(OBJECT_KINDS)})", objects="objects")
        if self.camera_elevation[1] >= 90:
            raise ParameterError(f"{{camera_elevation}} {list(self.camera_elevation)}: expected "
                                 "degrees below 90", camera_elevation="camera_elevation")
        if self.illuminance_lux[0] <= 0:
            raise ParameterError(f"{{illuminance_lux}} {list(self.illuminance_lux)}: expected "
                                 "lux above 0", illuminance_lux="illuminance_lux")
        if not self.depth_range[0] < self.depth_range[1]:
            raise ParameterError(f"{{depth_range}} {list(self.depth_range)}: expected near < far",
                                 depth_range="depth_range")


@dataclass(frozen=True)
class TabletopRanges(SceneRanges):
    """:class:`SceneRanges` of the ``tabletop`` family, plus the table's size.

    Attributes
    ----------
    table_width, table_depth, table_height : (float, float), metres
        The table (a box standing on the floor in the room's middle): its top's x and y extent
        and the height of its top.
    """

    table_width: tuple[float, float] = (0.9, 1.4)
    table_depth: tuple[float, float] = (0.6, 1.0)
    table_height: tuple[float, float] = (0.7, 0.8)


@dataclass(frozen=True)
class RoomRanges(SceneRanges):
    """:class:`SceneRanges` of the ``room`` family: larger objects on the floor of a larger
    room, seen from further away (see :class:`SceneRanges` for the other fields).

    Attributes
    ----------
    object_area : (float, float), metres
        Side of the square in the middle of the floor that the objects stand on.
    """

    objects: tuple[int, int] = (5, 8)
    object_size: tuple[float, float] = (0.08, 0.22)
    object_area: tuple[float, float] = (1.0, 1.6)
    room_width: tuple[float, float] = (4.5, 6.0)
    room_depth: tuple[float, float] = (4.5, 6.0)
    room_height: tuple[float, float] = (2.5, 3.0)
    camera_distance: tuple[float, float] = (2.0, 3.0)
    camera_elevation: tuple[float, float] = (25.0, 45.0)
    handheld_translation: tuple[float, float] = (0.02, 0.08)
    depth_range: tuple[float, float] = (0.25, 10.0)


def _two(name: str, value) -> tuple:
    if not isinstance(value, tuple | list) or len(value) != 2:
        raise ParameterError(f"{{{name}}} {ParameterError.literal(repr(value))}: expected two "
                             "values, (low, high)", **{name: name})
    return tuple(value)


def _pair(name: str, value, *, integers: bool) -> tuple:
    """A range ``(low, high)`` of numbers >= 0 (integers where ``integers``), low <= high."""
    check = (lambda key, v: integer(key, v, 0)) if integers else non_negative
    low, high = (check_parameter(check, name, v) for v in _two(name, value))
    if low > high:
        raise ParameterError(f"{{{name}}} {ParameterError.literal(repr(value))}: expected "
                             "(low, high) with low <= high", **{name: name})
    return low, high


def _count(name: str, value) -> int:
    return check_parameter(lambda key, v: integer(key, v, 1), name, value)


def _kinds(value) -> tuple[str, ...]:
    if (not isinstance(value, tuple | list) or not value
            or any(v not in ("handheld", "orbit") for v in value)):
        raise ParameterError(f"{{trajectories}} {ParameterError.literal(repr(value))}: expected "
                             "a non-empty list of 'handheld' and/or 'orbit'",
                             trajectories="trajectories")
    return tuple(value)


def _ranges(cls: type[SceneRanges], given: dict) -> SceneRanges:
    known = {item.name for item in fields(cls)}
    unknown = sorted(set(given) - known)
    if unknown:
        raise ParameterError(f"{{range}} {ParameterError.literal(repr(unknown[0]))} is not a "
                             f"range of {cls.__name__}; expected one of {', '.join(sorted(known))}",
                             range="range")
    return cls(**given)


# --------------------------------------------------------------------------------------------
# Drawing
# --------------------------------------------------------------------------------------------


def _f(x: float) -> str:
    """A number as written into the scene file (4 decimals: 0.1 mm)."""
    text = f"{x:.4f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def _r(x: float) -> float:
    """``x`` as the scene file will hold it (:func:`_f`), so that checks use the written value."""
    return float(f"{x:.4f}")


def _up(x: float) -> float:
    """``x`` rounded up to the written precision (never below ``x``)."""
    return math.ceil(round(x * 1e4, 6)) / 1e4


def _vec(values) -> str:
    return "[" + ", ".join(_f(v) for v in values) + "]"


def _draw(rng: np.random.Generator, pair: tuple[float, float]) -> float:
    return float(rng.uniform(pair[0], pair[1]))


def _texture(rng: np.random.Generator) -> str:
    kind = ("skimage", "noise", "shapes", "checkerboard")[int(rng.integers(4))]
    if kind == "skimage":
        name = SKIMAGE_IMAGES[int(rng.integers(len(SKIMAGE_IMAGES)))]
        return f'{{ type = "skimage", name = "{name}" }}'
    if kind == "noise":
        return (f'{{ type = "noise", resolution = 256, feature_size = {_f(_draw(rng, (2, 10)))}, '
                f'contrast = {_f(_draw(rng, (0.3, 0.8)))} }}')
    if kind == "shapes":
        return (f'{{ type = "shapes", resolution = 256, count = {int(rng.integers(8, 31))}, '
                f'min_size = 10, max_size = 60, background = {_f(_draw(rng, (0.6, 0.9)))} }}')
    squares = rng.integers(2, 11, size=2)
    return f'{{ type = "checkerboard", squares = [{squares[0]}, {squares[1]}] }}'


def _material(rng: np.random.Generator, scale: tuple[float, float]) -> str:
    texture = _texture(rng)
    return f"{{ texture = {texture}, texture_scale = {_vec(scale)} }}"


@dataclass(frozen=True)
class _Placed:
    """One drawn object: its TOML body (without name and material) and what the checks use."""

    kind: str
    body: str
    center: np.ndarray          # (3,), metres: the written centre
    footprint: float            # radius of its footprint's bounding disc, metres
    top: float                  # height of its highest point, metres (every shape drawn here
                                # is as high above its centre as its lowest point is below)


def _shape(rng: np.random.Generator, kind: str, size: float) -> tuple[str, float, float]:
    """An object of ``kind`` at about ``size`` (m): its TOML body (shape keys and rotation),
    its footprint radius and the height of its centre above the support it rests on."""
    yaw = _r(_draw(rng, (0.0, 360.0)))
    if kind == "box":
        sides = [_r(2 * size * _draw(rng, (0.5, 1.0))) for _ in range(3)]
        return (f"size = {_vec(sides)}\nrotation = {_vec([0, 0, yaw])}",
                math.hypot(sides[0], sides[1]) / 2, sides[2] / 2)
    if kind == "sphere":
        radius = _r(size)
        turn = [_r(_draw(rng, (0.0, 360.0))) for _ in range(3)]
        return f"radius = {_f(radius)}\nrotation = {_vec(turn)}", radius, radius
    if kind == "cylinder":
        radius = _r(size * _draw(rng, (0.5, 1.0)))
        height = _r(2 * size * _draw(rng, (0.6, 1.5)))
        return (f"radius = {_f(radius)}\nheight = {_f(height)}\nrotation = {_vec([0, 0, yaw])}",
                radius, height / 2)
    if kind == "heightfield":
        sides = [_r(2 * size * _draw(rng, (0.8, 1.2))) for _ in range(2)]
        amplitude = _r(size * _draw(rng, (0.05, 0.2)))
        wavelength = [_r(side * _draw(rng, (0.3, 0.8))) for side in sides]
        resolution = [48, 48]
        lowest = float(heightfield_mesh(sides, amplitude, wavelength, resolution)[0][:, 2].min())
        return (f"size = {_vec(sides)}\namplitude = {_f(amplitude)}\n"
                f"wavelength = {_vec(wavelength)}\nresolution = [48, 48]\n"
                f"rotation = {_vec([0, 0, yaw])}", math.hypot(*sides) / 2, -lowest)
    name = BUILTIN_MESHES[int(rng.integers(len(BUILTIN_MESHES)))]
    vertices = obj_vertices(builtin_mesh_path(name))
    scale = _r(size / float(np.hypot(vertices[:, 0], vertices[:, 1]).max()))
    footprint = scale * float(np.hypot(vertices[:, 0], vertices[:, 1]).max())
    return (f'path = "builtin:{name}"\nscale = {_f(scale)}\nrotation = {_vec([0, 0, yaw])}',
            footprint, -scale * float(vertices[:, 2].min()))


def _place(rng: np.random.Generator, ranges: SceneRanges, region: tuple[float, ...],
           top: float) -> list[_Placed] | None:
    """Objects resting on the rectangle ``region = (x0, x1, y0, y1)`` at height ``top``, their
    footprint discs :data:`GAP_M` apart; None when one does not fit (the caller redraws)."""
    count = int(rng.integers(ranges.objects[0], ranges.objects[1] + 1))
    kinds = list(OBJECT_KINDS) + [OBJECT_KINDS[int(rng.integers(len(OBJECT_KINDS)))]
                                  for _ in range(count - len(OBJECT_KINDS))]
    kinds = [kinds[i] for i in rng.permutation(len(kinds))]
    x0, x1, y0, y1 = region
    placed: list[_Placed] = []
    for kind in kinds:
        body, footprint, lift = _shape(rng, kind, _draw(rng, ranges.object_size))
        if x1 - x0 < 2 * footprint or y1 - y0 < 2 * footprint:
            return None
        spot = None
        for _ in range(_PLACEMENT_TRIES):
            xy = np.array([_r(_draw(rng, (x0 + footprint, x1 - footprint))),
                           _r(_draw(rng, (y0 + footprint, y1 - footprint)))])
            if all(np.hypot(*(xy - p.center[:2])) >= footprint + p.footprint + GAP_M
                   for p in placed):
                spot = xy
                break
        if spot is None:
            return None
        center = np.array([spot[0], spot[1], _up(top + lift)])
        placed.append(_Placed(kind, f"center = {_vec(center)}\n{body}", center, footprint,
                              center[2] + lift))
    return placed


def _rectangle(name: str, center, size, normal, material: str, up=None) -> str:
    up_line = f"up = {_vec(up)}\n" if up is not None else ""
    return (f'[[objects]]\nname = "{name}"\ntype = "rectangle"\ncenter = {_vec(center)}\n'
            f"size = {_vec(size)}\nnormal = {_vec(normal)}\n{up_line}material = {material}\n")


def _room(rng: np.random.Generator, width: float, depth: float, height: float) -> str:
    """Floor, four walls and a ceiling of a room centred on the origin (floor at z = 0)."""
    e = _WALL_OVERLAP_M

    def big(extent_u: float, extent_v: float) -> str:
        period = _draw(rng, (0.5, 1.5))
        return _material(rng, (_r(extent_u / period), _r(extent_v / period)))

    out = [_rectangle("floor", [0, 0, 0], [width + 2 * e, depth + 2 * e], [0, 0, 1],
                      big(width, depth), up=[0, 1, 0]),
           _rectangle("ceiling", [0, 0, height], [width + 2 * e, depth + 2 * e], [0, 0, -1],
                      "{ color = 0.8 }", up=[0, 1, 0])]
    for name, center, size, normal in (
            ("wall_north", [0, depth / 2, height / 2], [width + 2 * e, height + 2 * e],
             [0, -1, 0]),
            ("wall_south", [0, -depth / 2, height / 2], [width + 2 * e, height + 2 * e],
             [0, 1, 0]),
            ("wall_east", [width / 2, 0, height / 2], [depth + 2 * e, height + 2 * e],
             [-1, 0, 0]),
            ("wall_west", [-width / 2, 0, height / 2], [depth + 2 * e, height + 2 * e],
             [1, 0, 0])):
        out.append(_rectangle(name, center, size, normal, big(size[0], size[1])))
    return "\n".join(out)


def _key_intensity(illuminance: float, position: np.ndarray, target: np.ndarray) -> float:
    """Intensity (cd) of a point light at ``position`` (3,) that gives ``illuminance`` (lux) at
    ``target`` (3,) on a surface facing up: ``E = I cos(theta) / d^2 = I h / d^3``, ``h`` the
    light's height above the target and ``d`` its distance (inverse-square law, unoccluded)."""
    offset = np.asarray(position, float) - np.asarray(target, float)
    distance = float(np.linalg.norm(offset))
    return illuminance * distance ** 3 / float(offset[2])


def _lights(rng: np.random.Generator, ranges: SceneRanges, width: float, depth: float,
            height: float, target: np.ndarray, highest: float) -> str | None:
    """Point lights under the ceiling and at least 0.2 m above ``highest`` (the objects' top):
    the first (the key) within 0.5 m (x, y) of ``target``, its intensity giving an illuminance
    drawn in ``ranges.illuminance_lux`` there (:func:`_key_intensity`); the others (fills)
    anywhere in the room (0.3 m from the walls), each a fraction of the key's intensity drawn in
    ``ranges.fill_fraction``. Each light's ``intensity_cd`` is commented with its drawn value.
    None when the objects leave no room under the ceiling."""
    low = max(0.6 * height, highest + 0.2)
    if low > height - 0.1:
        return None
    count = int(rng.integers(ranges.lights[0], ranges.lights[1] + 1))
    out = []
    key = 0.0
    for i in range(count):
        if i == 0:
            x = _draw(rng, (target[0] - 0.5, target[0] + 0.5))
            y = _draw(rng, (target[1] - 0.5, target[1] + 0.5))
        else:
            x = _draw(rng, (-width / 2 + 0.3, width / 2 - 0.3))
            y = _draw(rng, (-depth / 2 + 0.3, depth / 2 - 0.3))
        position = [_r(x), _r(y), _r(_draw(rng, (low, height - 0.1)))]
        if i == 0:
            lux = _draw(rng, ranges.illuminance_lux)
            key = _r(_key_intensity(lux, np.array(position), target))
            intensity, note = key, f"key light: {lux:.0f} lux on the objects' centre"
        else:
            fraction = _draw(rng, ranges.fill_fraction)
            intensity = _r(fraction * key)
            note = f"fill light: {fraction:.3f} of the key's intensity"
        out.append(f'[[lights]]\ntype = "point"\nposition = {_vec(position)}\n'
                   f"intensity_cd = {_f(intensity)}   # {note}\n")
    return "\n".join(out)


def _trajectory(rng: np.random.Generator, ranges: SceneRanges, target: np.ndarray,
                spread: float) -> tuple[str, str]:
    """A trajectory looking at ``target``: its kind and its ``[trajectory]`` table."""
    kind = ranges.trajectories[int(rng.integers(len(ranges.trajectories)))]
    distance = _draw(rng, ranges.camera_distance)
    elevation = math.radians(_draw(rng, ranges.camera_elevation))
    azimuth = _draw(rng, (0.0, 2 * math.pi))

    def position(angle: float) -> np.ndarray:
        return target + distance * np.array([math.cos(elevation) * math.cos(angle),
                                             math.cos(elevation) * math.sin(angle),
                                             math.sin(elevation)])

    if kind == "handheld":
        look = target + np.append(rng.normal(0.0, 0.1 * spread, 2), 0.0)
        trans = [_r(_draw(rng, ranges.handheld_translation)) for _ in range(3)]
        rot = [_r(_draw(rng, ranges.handheld_rotation)) for _ in range(3)]
        freqs = [_r(_draw(rng, ranges.handheld_frequency)) for _ in range(6)]
        phases = [_r(_draw(rng, (0.0, 2 * math.pi))) for _ in range(6)]
        return kind, (f'[trajectory]\ntype = "handheld"\nposition = {_vec(position(azimuth))}\n'
                      f"look_at = {_vec(look)}\ntranslation_amplitude = {_vec(trans)}\n"
                      f"rotation_amplitude = {_vec(rot)}\nfrequencies = {_vec(freqs)}\n"
                      f"phases = {_vec(phases)}\n")
    arc = math.radians(_draw(rng, ranges.orbit_arc)) * (1 if rng.random() < 0.5 else -1)
    keys = max(3, math.ceil(abs(math.degrees(arc)) / 15.0) + 1)
    frames = []
    for i in range(keys):
        t = ranges.duration * i / (keys - 1)
        where = position(azimuth + arc * i / (keys - 1))
        frames.append(f"  {{ t = {_f(t)}, position = {_vec(where)}, look_at = {_vec(target)} }},")
    return kind, ('[trajectory]\ntype = "spline"\nkeyframes = [\n' + "\n".join(frames) + "\n]\n")


def _text(family: str, seed: int, ranges: SceneRanges, kind: str, parts: list[str]) -> str:
    near, far = ranges.depth_range
    head = (f"# Drawn by sim.scene.procedural: the {family} family, seed {seed}, generator "
            f"version {GENERATOR_VERSION}.\n"
            f"# Re-draw it with sim.scene.{family}_scene({seed}) (same ranges, same version).\n"
            f'name = "{family}_{seed}"\n'
            f'description = "Procedural {family} scene (seed {seed}, {kind} trajectory)"\n'
            f"duration = {_f(ranges.duration)}\n"
            f"depth_range = {_vec([near, far])}   # declared; every view's exact depth is "
            f"inside it\nseed = {seed}\n\n"
            '[camera]\npreset = "davis240c"\n\n'
            f"[frames]\nrate = 24.0\nexposure = 0.005\nmax_exposure = {MAX_EXPOSURE_S}   # the "
            "longest a sensor's auto-exposure may choose (indoor light: 15-40 ms)\n\n")
    return head + "\n".join(parts)


def _corner_cosine(scene: Scene) -> float:
    """Cosine of the widest angle between the optical axis and a ray through the image (its
    corners, at any resolution of the same field of view)."""
    cam = scene.camera
    corners = np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5], [-0.5, cam.height - 0.5],
                        [cam.width - 0.5, cam.height - 0.5]])
    xy = (corners - [cam.cx, cam.cy]) / [cam.fx, cam.fy]
    if cam.has_distortion:
        xy = cam.undistort(xy)
    return float((1.0 / np.sqrt(1.0 + (xy ** 2).sum(axis=1))).min())


def _bounding_distance(scene: Scene, positions: np.ndarray) -> np.ndarray:
    """Least distance (N,) from camera positions (N, 3) to any object's bounding volume: the
    sphere itself, a mesh's bounding sphere (about its centre), every other shape's bounding
    box. No surface point is nearer."""
    out = np.full(len(positions), np.inf)
    for obj in scene.objects:
        if obj.shape == "mesh":
            reach = obj.params["scale"] * np.linalg.norm(obj_vertices(obj.params["path"]),
                                                         axis=1).max()
            gap = np.maximum(np.linalg.norm(positions - obj.center, axis=1) - reach, 0.0)
        else:
            gap = obj.distance_to(positions)
        out = np.minimum(out, gap)
    return out


def trajectory_check(scene: Scene, placed_names: tuple[str, ...], *, views: int = 12,
                     size: tuple[int, int] = (40, 30), variant: str | None = None) -> str | None:
    """Why a procedural scene's trajectory is refused, or None when it is accepted.

    Accepted when, over ``[0, duration]``:

    1. every placed object's centre projects into the image, at least 5 % of its size from
       the border, in front of the camera, at 50 times per second of trajectory;
    2. at those times the camera keeps from every object's bounding volume (as
       :func:`_bounding_distance`) a distance ``d`` with ``(d - s) cos(a) >= near``, where
       ``s`` is the largest step of the camera between two of those times (so that it holds
       between them too) and ``a`` the widest angle of a ray from the optical axis: no surface
       point can then show a z-depth below ``near``; and the room's farthest corner stays
       within ``far`` of the camera (every ray ends on the closed room): none above ``far``;
    3. the exact depth rendered by :class:`sim.render.Renderer` at ``size`` pixels at
       ``views`` times evenly over the duration has a surface at every pixel and lies inside
       ``[near, far]`` (the exact-depth check, :func:`sim.scene_check.exact_depth_check`,
       handed down by :func:`use_exact_depth_check`; 2. implies it, so a failure here is a
       surface the bounds missed).

    Parameters
    ----------
    scene : Scene
        A scene drawn by :func:`tabletop_scene` or :func:`room_scene` (its ``depth_range``
        declared, a closed room named ``floor``, ``ceiling``, ``wall_*``).
    placed_names : tuple of str
        The names of the objects to keep in view.
    views : int
        Renders of the exact depth.
    size : (int, int)
        Their width and height, pixels (same field of view as the scene's camera).
    variant : str, optional
        Mitsuba variant (see :func:`sim.variant.use_variant`).

    Returns
    -------
    str or None
        One line saying what failed first, or None.

    Raises
    ------
    RuntimeError
        No exact-depth check was handed down (:func:`use_exact_depth_check`; :mod:`sim` does on
        import).
    """
    near, far = scene.depth_range
    times = np.linspace(0.0, scene.duration, max(int(50 * scene.duration), 2) + 1)
    poses = scene.trajectory.pose(times)
    rotations, positions = poses[:, :3, :3], poses[:, :3, 3]
    cam = scene.camera
    for obj in scene.objects:
        if obj.name not in placed_names:
            continue
        local = np.einsum("nji,nj->ni", rotations, obj.center - positions)
        z = local[:, 2]
        if not (z > near).all():
            return f"{obj.name} falls behind the camera or nearer than {near} m"
        u, v = cam.fx * local[:, 0] / z + cam.cx, cam.fy * local[:, 1] / z + cam.cy
        mx, my = _IMAGE_MARGIN * cam.width, _IMAGE_MARGIN * cam.height
        if not ((u >= mx - 0.5) & (u <= cam.width - 0.5 - mx)
                & (v >= my - 0.5) & (v <= cam.height - 0.5 - my)).all():
            return f"{obj.name} leaves the image"
    step = float(np.linalg.norm(np.diff(positions, axis=0), axis=1).max())
    nearest = float(_bounding_distance(scene, positions).min())
    cosine = _corner_cosine(scene)
    if (nearest - step) * cosine < near:
        return (f"a surface may come within {(nearest - step) * cosine:.3f} m (z-depth) of the "
                f"camera, nearer than {near} m")
    walls = {obj.name: obj.center for obj in scene.objects}
    lo = np.array([walls["wall_west"][0], walls["wall_south"][1], walls["floor"][2]])
    hi = np.array([walls["wall_east"][0], walls["wall_north"][1], walls["ceiling"][2]])
    corners = np.array([[x, y, z] for x in (lo[0] - _WALL_OVERLAP_M, hi[0] + _WALL_OVERLAP_M)
                        for y in (lo[1] - _WALL_OVERLAP_M, hi[1] + _WALL_OVERLAP_M)
                        for z in (lo[2] - _WALL_OVERLAP_M, hi[2] + _WALL_OVERLAP_M)])
    farthest = float(np.linalg.norm(corners[None] - positions[:, None], axis=2).max())
    if farthest > far:
        return f"the room's far corner is {farthest:.3f} m from the camera, beyond {far} m"
    if _exact_depth_check is None:
        raise RuntimeError("no exact-depth check for procedural scenes: expected "
                           "sim.scene_check.exact_depth_check, handed down by importing sim")
    return _exact_depth_check(scene, views=views, size=size, variant=variant)


def _scene_text(family: str, seed: int, ranges: SceneRanges, variant: str | None) -> str:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ParameterError(f"{{seed}} {ParameterError.literal(repr(seed))}: expected an "
                             "integer >= 0", seed="seed")
    seed = int(seed)
    rng = np.random.default_rng(seed)
    reasons = []
    for _ in range(ranges.max_redraws):
        width, depth = _r(_draw(rng, ranges.room_width)), _r(_draw(rng, ranges.room_depth))
        height = _r(_draw(rng, ranges.room_height))
        parts = []
        if isinstance(ranges, TabletopRanges):
            tw, td = _r(_draw(rng, ranges.table_width)), _r(_draw(rng, ranges.table_depth))
            th = 2 * _r(_draw(rng, ranges.table_height) / 2)     # its centre written exactly
            top, region = th, (-tw / 2, tw / 2, -td / 2, td / 2)
            scale = (_r(_draw(rng, ranges.texture_scale)), _r(_draw(rng, ranges.texture_scale)))
            parts.append(f'[[objects]]\nname = "table"\ntype = "box"\n'
                         f"center = {_vec([0, 0, th / 2])}\nsize = {_vec([tw, td, th])}\n"
                         f"material = {_material(rng, scale)}\n")
        else:
            side = _r(_draw(rng, ranges.object_area))
            half_x, half_y = min(side, width - 0.4) / 2, min(side, depth - 0.4) / 2
            top, region = 0.0, (-half_x, half_x, -half_y, half_y)
        placed = _place(rng, ranges, region, top)
        if placed is None:
            reasons.append("the objects did not fit on the support")
            continue
        names = []
        for i, item in enumerate(placed):
            name = f"obj{i}_{item.kind}"
            names.append(name)
            scale = (_r(_draw(rng, ranges.texture_scale)), _r(_draw(rng, ranges.texture_scale)))
            parts.append(f'[[objects]]\nname = "{name}"\ntype = "{item.kind}"\n{item.body}\n'
                         f"material = {_material(rng, scale)}\n")
        centres = np.array([p.center for p in placed])
        target = np.array([_r(v) for v in (*centres[:, :2].mean(axis=0),
                                           float(centres[:, 2].mean()))])
        spread = float(max(np.hypot(*(p.center[:2] - target[:2])) + p.footprint
                           for p in placed))
        lights = _lights(rng, ranges, width, depth, height, target,
                         max(p.top for p in placed))
        if lights is None:
            reasons.append("the objects reach the ceiling")
            continue
        kind, trajectory = _trajectory(rng, ranges, target, spread)
        text = _text(family, seed, ranges, kind,
                     [trajectory, lights, _room(rng, width, depth, height), *parts])
        scene = parse_scene(text, f"<{family} {seed}>")
        reason = trajectory_check(scene, tuple(names), views=ranges.check_views,
                                  size=ranges.check_size, variant=variant)
        if reason is None:
            return text
        reasons.append(reason)
    common = max(set(reasons), key=reasons.count)
    raise ParameterError(f"no {family} scene for {{seed}} {seed} in {{max_redraws}} "
                         f"{ranges.max_redraws} draws (most often: {ParameterError.literal(common)}"
                         "); widen {camera_distance} or {depth_range}, or lower {object_size}",
                         seed="seed", max_redraws="max_redraws",
                         camera_distance="camera_distance", depth_range="depth_range",
                         object_size="object_size")


def tabletop_scene(seed: int, *, variant: str | None = None, **ranges) -> str:
    """A random tabletop scene: objects on a table in a closed room (see the module's text).

    Parameters
    ----------
    seed : int
        >= 0; the only source of randomness: the same seed and ranges give the same text.
    variant : str, optional
        Mitsuba variant of the exact-depth check (:func:`trajectory_check`).
    **ranges
        Fields of :class:`TabletopRanges` to replace (``objects=(6, 6)``,
        ``depth_range=(0.3, 4.0)``, ...).

    Returns
    -------
    str
        A scene file (TOML), with ``depth_range`` and a comment naming the seed and
        :data:`GENERATOR_VERSION`.

    Raises
    ------
    ParameterError
        A bad seed or range (naming it), or no draw accepted in ``max_redraws``.
    """
    return _scene_text("tabletop", seed, _ranges(TabletopRanges, ranges), variant)


def room_scene(seed: int, *, variant: str | None = None, **ranges) -> str:
    """A random room scene: objects on the floor of a closed room (see the module's text).

    The parameters, result and errors are :func:`tabletop_scene`'s, the ranges
    :class:`RoomRanges`' fields.
    """
    return _scene_text("room", seed, _ranges(RoomRanges, ranges), variant)


PROCEDURAL_FAMILIES: dict[str, Callable[..., str]] = {"tabletop": tabletop_scene,
                                                      "room": room_scene}
"""The procedural families by name: ``PROCEDURAL_FAMILIES[name](seed, **ranges) -> str``."""


def procedural_scene(family: str, seed: int, **ranges) -> str:
    """The scene text of ``family`` (a key of :data:`PROCEDURAL_FAMILIES`) for ``seed``.

    Raises
    ------
    ParameterError
        An unknown family (naming the known ones), or as the family's function.
    """
    if family not in PROCEDURAL_FAMILIES:
        raise ParameterError(f"{{family}} {ParameterError.literal(repr(family))}: expected one "
                             f"of {', '.join(PROCEDURAL_FAMILIES)}", family="family")
    return PROCEDURAL_FAMILIES[family](seed, **ranges)
