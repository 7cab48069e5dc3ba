"""Procedural scenes (issue 24, part 2): ``sim.scene.tabletop_scene`` and ``room_scene``.

What must be shown: 50 seeds of ``tabletop`` all parse and simulate, no two objects
interpenetrate, every view's exact depth lies inside the declared range, the same seed gives the
same scene file. Simulating a scene costs 2-4 s on this 2-core machine (a new scene compiles new
kernels), so all 50 tabletop seeds are parsed, checked for interpenetration and rendered for
their exact depth (at times and a size that the generator's own check does not use), and a
subset of them is simulated (a 32x24 sensor, 0.02 s); the room family likewise on fewer seeds.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest

import sim
from sim.render import Renderer
from sim.scene import Material, SceneError, parse_scene
from sim.scene._meshes import obj_vertices
from sim.scene.procedural import (
    GENERATOR_VERSION,
    OBJECT_KINDS,
    RoomRanges,
    TabletopRanges,
    trajectory_check,
)
from sim.validation import ParameterError

TABLETOP_SEEDS = range(50)
ROOM_SEEDS = range(12)
SIMULATED_TABLETOP = (0, 1, 2, 3, 4, 5)       # both trajectory kinds among them (checked)
SIMULATED_ROOM = (0, 1)


@pytest.fixture(scope="module")
def tabletops() -> dict[int, str]:
    return {seed: sim.tabletop_scene(seed) for seed in TABLETOP_SEEDS}


@pytest.fixture(scope="module")
def rooms() -> dict[int, str]:
    return {seed: sim.scene.room_scene(seed) for seed in ROOM_SEEDS}


def _placed(scene):
    return [obj for obj in scene.objects if obj.name.startswith("obj")]


def _footprint_and_bottom(obj) -> tuple[float, float]:
    """The radius about the centre (x, y) of the object's footprint and the height of its
    lowest point, metres, from the parsed geometry (every vertex or corner in the world)."""
    p = obj.params
    if obj.shape == "sphere":
        return float(p["radius"]), float(obj.center[2] - p["radius"])
    if obj.shape == "cylinder":
        angles = np.linspace(0, 2 * np.pi, 721)
        ring = np.stack([p["radius"] * np.cos(angles), p["radius"] * np.sin(angles),
                         np.zeros_like(angles)], axis=1)
        local = np.concatenate([ring + [0, 0, -p["height"] / 2], ring + [0, 0, p["height"] / 2]])
    elif obj.shape == "box":
        local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)],
                         float) * np.asarray(p["size"]) / 2
    elif obj.shape == "heightfield":
        (sx, sy), (nx, ny) = p["size"], p["resolution"]
        gx, gy = np.meshgrid(np.linspace(-sx / 2, sx / 2, nx), np.linspace(-sy / 2, sy / 2, ny))
        gz = p["amplitude"] * np.sin(2 * np.pi * gx / p["wavelength"][0]) * \
            np.cos(2 * np.pi * gy / p["wavelength"][1])
        local = np.stack([gx, gy, gz], axis=-1).reshape(-1, 3)
    else:
        local = obj_vertices(p["path"]) * p["scale"]
    world = local @ np.asarray(obj.rotation).T
    return float(np.hypot(world[:, 0], world[:, 1]).max()), float(obj.center[2]
                                                                   + world[:, 2].min())


def _layout_faults(scene, support_top: float, region: tuple[float, float]) -> list[str]:
    """Pairs of placed objects whose footprint discs overlap (so that they might
    interpenetrate), objects not resting on the support (lowest point below it, or more than
    0.2 mm above) or reaching past its edges ``region = (half x, half y)``."""
    faults = []
    placed = [(obj, *_footprint_and_bottom(obj)) for obj in _placed(scene)]
    for i, (a, ra, bottom) in enumerate(placed):
        if not support_top - 1e-9 <= bottom <= support_top + 2e-4:
            faults.append(f"{a.name} rests at {bottom} not on {support_top}")
        if abs(a.center[0]) + ra > region[0] + 1e-9 or abs(a.center[1]) + ra > region[1] + 1e-9:
            faults.append(f"{a.name} reaches past the support")
        if a.shape != "sphere" and not np.allclose(np.asarray(a.rotation)[:, 2], [0, 0, 1]):
            faults.append(f"{a.name} is tilted")        # a footprint of an upright object only
        for b, rb, _ in placed[i + 1:]:
            if np.hypot(*(a.center[:2] - b.center[:2])) < ra + rb:
                faults.append(f"{a.name} and {b.name} overlap")
    return faults


def _support(scene) -> tuple[float, tuple[float, float]]:
    names = {obj.name: obj for obj in scene.objects}
    if "table" in names:
        size = names["table"].params["size"]
        return float(names["table"].center[2] + size[2] / 2), (size[0] / 2, size[1] / 2)
    return 0.0, (float(names["wall_east"].center[0]), float(names["wall_north"].center[1]))


def _depth_faults(scene, times, size=(48, 36)) -> list[str]:
    """Views whose exact depth (pixel centres, rendered by the project's renderer) has a pixel
    without a surface or outside the declared ``depth_range``; and placed objects whose centre
    leaves the image at ``times``."""
    near, far = scene.depth_range
    small = dataclasses.replace(
        scene, camera=scene.camera.with_resolution(*size),
        objects=tuple(dataclasses.replace(o, material=Material()) for o in scene.objects))
    renderer = Renderer(small, spp=1, texture_filter=False)
    faults = []
    for t in times:
        depth = renderer.depth(float(t))
        if not ((depth >= near) & (depth <= far)).all():
            faults.append(f"t = {t}: depth [{depth.min()}, {depth.max()}] not in [{near}, {far}]")
        pose = scene.trajectory.pose(float(t))
        for obj in _placed(scene):
            uv = scene.camera.project((obj.center - pose[:3, 3]) @ pose[:3, :3])
            if not scene.camera.in_image(uv[None])[0]:
                faults.append(f"t = {t}: {obj.name} out of view")
    return faults


def _independent_times(duration: float) -> np.ndarray:
    """Four times between the generator's own check times (``linspace(0, duration, 12)``)."""
    return duration * (np.arange(4) + 0.3) / 4


# ------------------------------------------------------------------------------------------


def test_tabletop_fifty_seeds_parse_hold_every_kind_and_keep_depth_in_range(tabletops):
    """Every one of 50 seeds: a scene file that parses, declares the family's depth range,
    names the seed and generator version, holds every object kind, and whose exact depth
    (48x36, at four times the generator did not check) lies inside the range, every object's
    centre in the image."""
    kinds = set()
    for seed, text in tabletops.items():
        first = text.splitlines()[0]
        assert f"seed {seed}," in first and f"version {GENERATOR_VERSION}" in first
        scene = parse_scene(text, f"<tabletop {seed}>")
        assert scene.depth_range == TabletopRanges().depth_range
        assert {obj.shape for obj in _placed(scene)} == set(OBJECT_KINDS)
        low, high = TabletopRanges().objects
        assert low <= len(_placed(scene)) <= high
        assert _depth_faults(scene, _independent_times(scene.duration)) == [], seed
        kinds.add(scene.trajectory.__class__.__name__)
    assert kinds == {"HandheldTrajectory", "SplineTrajectory"}     # hand-held and orbit


def test_depth_stays_in_range_between_the_checked_times(tabletops):
    """The generator renders 12 views; its bounds must hold between them too: a hand-held and
    an orbit scene rendered at 101 times (32x24)."""
    first = {}
    for text in tabletops.values():
        scene = parse_scene(text)
        first.setdefault(scene.trajectory.__class__.__name__, scene)
    for scene in first.values():
        times = np.linspace(0.0, scene.duration, 101)
        assert _depth_faults(scene, times, size=(32, 24)) == [], scene.name


def test_no_two_objects_interpenetrate_and_all_rest_on_the_support(tabletops, rooms):
    """On the parsed geometry (every corner, vertex or rim point in the world): the footprints'
    bounding discs of two upright objects that do not overlap leave them disjoint (an object
    lies inside the vertical prism over its footprint); each rests on the table or floor."""
    for text in [*tabletops.values(), *rooms.values()]:
        scene = parse_scene(text)
        top, region = _support(scene)
        assert _layout_faults(scene, top, region) == [], scene.name


def test_the_layout_check_sees_an_overlap(tabletops):
    """The check above can fail: one object moved onto another is reported."""
    scene = parse_scene(tabletops[0])
    a, b = _placed(scene)[:2]
    moved = dataclasses.replace(b, center=np.array([a.center[0], a.center[1], b.center[2]]))
    scene = dataclasses.replace(scene, objects=tuple(moved if o is b else o
                                                     for o in scene.objects))
    top, region = _support(scene)
    assert f"{a.name} and {b.name} overlap" in _layout_faults(scene, top, region)


def test_some_tabletop_seeds_simulate(tabletops, tmp_path):
    """A subset of the 50 (see the module's text), hand-held and orbit among them: a sequence
    folder that loads back, with events, frames and the exact depth."""
    kinds = set()
    for seed in SIMULATED_TABLETOP:
        scene = parse_scene(tabletops[seed])
        kinds.add(scene.trajectory.__class__.__name__)
        scene = dataclasses.replace(scene, camera=scene.camera.with_resolution(32, 24))
        result = sim.simulate(scene, tmp_path / f"t{seed}", duration=0.02, start=1.0,
                              progress=False, spp=1, event_formats=("txt",),
                              motion_truth=False)
        sequence = sim.load_sequence(tmp_path / f"t{seed}")
        assert result.n_frames >= 1 and len(sequence.image_paths) == result.n_frames
        depth = sim.read_depth(sequence.depth_paths[0])
        near, far = scene.depth_range
        assert depth.shape == (24, 32) and near <= depth.min() and depth.max() <= far
    assert kinds == {"HandheldTrajectory", "SplineTrajectory"}


def test_room_seeds_parse_keep_depth_in_range_and_simulate(rooms, tmp_path):
    for seed, text in rooms.items():
        scene = parse_scene(text)
        assert scene.depth_range == RoomRanges().depth_range
        assert {obj.shape for obj in _placed(scene)} == set(OBJECT_KINDS)
        assert _depth_faults(scene, _independent_times(scene.duration)) == [], seed
    for seed in SIMULATED_ROOM:
        scene = parse_scene(rooms[seed])
        scene = dataclasses.replace(scene, camera=scene.camera.with_resolution(32, 24))
        result = sim.simulate(scene, tmp_path / f"r{seed}", duration=0.02, progress=False,
                              spp=1, event_formats=("txt",), motion_truth=False)
        assert result.n_frames >= 1


def test_same_seed_same_text_in_another_process_and_seeds_differ(tabletops, rooms):
    """The text depends on the seed alone: byte-identical in a fresh interpreter; two seeds
    give different scenes (not just a different seed line)."""
    code = "import sim, sys; sys.stdout.write(sim.tabletop_scene(7) + sim.scene.room_scene(3))"
    again = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                           text=True).stdout
    assert again == tabletops[7] + rooms[3]
    assert sim.tabletop_scene(7) == tabletops[7]

    def body(text: str) -> str:
        return "\n".join(line for line in text.splitlines()
                         if "seed" not in line and not line.startswith("name"))

    assert len({body(text) for text in tabletops.values()}) == len(tabletops)
    assert len({body(text) for text in rooms.values()}) == len(rooms)


def test_ranges_are_used_and_checked():
    text = sim.tabletop_scene(1, objects=(7, 7), duration=4.0, depth_range=[0.2, 6.0])
    scene = parse_scene(text)
    assert len(_placed(scene)) == 7 and scene.duration == 4.0
    assert scene.depth_range == (0.2, 6.0)
    with pytest.raises(ParameterError, match=r"'colour' is not a range of TabletopRanges"):
        sim.tabletop_scene(1, colour=(0, 1))
    with pytest.raises(ParameterError, match=r"object_size \(0.2, 0.1\): expected \(low, high\)"):
        sim.tabletop_scene(1, object_size=(0.2, 0.1))
    with pytest.raises(ParameterError, match=r"objects \[3, 4\]: expected at least 5 objects"):
        sim.scene.room_scene(1, objects=(3, 4))
    with pytest.raises(ParameterError, match=r"seed -1: expected an integer >= 0"):
        sim.tabletop_scene(-1)
    with pytest.raises(ParameterError, match=r"family 'kitchen': expected one of tabletop, room"):
        sim.scene.procedural_scene("kitchen", 1)


def test_a_depth_range_no_trajectory_can_keep_is_refused_after_the_redraws():
    """The far end below the room's size: every draw is refused, then one clear error."""
    with pytest.raises(ParameterError, match=r"no tabletop scene for seed 2 in max_redraws 3 "
                                             r"draws \(most often: .*\); widen "
                                             r"camera_distance or depth_range"):
        sim.tabletop_scene(2, depth_range=(0.25, 1.5), max_redraws=3)


def test_the_trajectory_check_refuses_views_outside_the_range(tabletops):
    """The generator's check (bounds, then the rendered exact depth) fails on a scene whose
    declared range is too narrow at either end, and passes on the scene as drawn."""
    scene = parse_scene(tabletops[4])
    names = tuple(obj.name for obj in _placed(scene))
    assert trajectory_check(scene, names) is None
    far = trajectory_check(dataclasses.replace(scene, depth_range=(0.25, 2.0)), names)
    assert far is not None and "beyond 2.0 m" in far
    near = trajectory_check(dataclasses.replace(scene, depth_range=(1.0, 5.0)), names)
    assert near is not None and "nearer than 1.0 m" in near


def test_the_exact_depth_step_is_handed_down_from_above(tabletops, monkeypatch):
    """The scene model does not import the renderer (tests/test_import_graph.py): sim hands it
    the rendering step (sim.scene_check), which trajectory_check runs last, with its views,
    size and variant; without one, it says so."""
    import sim.scene.procedural as procedural
    from sim.scene_check import exact_depth_check

    assert procedural._exact_depth_check is exact_depth_check
    scene = parse_scene(tabletops[4])
    names = tuple(obj.name for obj in _placed(scene))
    calls = []
    monkeypatch.setattr(procedural, "_exact_depth_check",
                        lambda drawn, **given: calls.append((drawn, given)) or "planted")
    assert trajectory_check(scene, names, views=3, size=(8, 6), variant="x") == "planted"
    assert calls == [(scene, {"views": 3, "size": (8, 6), "variant": "x"})]
    far = trajectory_check(dataclasses.replace(scene, depth_range=(0.25, 2.0)), names)
    assert "beyond 2.0 m" in far and len(calls) == 1          # the bounds refuse first
    monkeypatch.setattr(procedural, "_exact_depth_check", None)
    with pytest.raises(RuntimeError, match="no exact-depth check for procedural scenes"):
        trajectory_check(scene, names)


def test_the_exact_depth_check_renders_the_depth(tabletops):
    """sim.scene_check.exact_depth_check on its own: the scene as drawn passes; the camera at
    least 0.8 m (camera_distance) from the objects it looks at cannot see all within 0.5 m;
    without a floor, a ray looking down leaves the room."""
    from sim.scene_check import exact_depth_check

    scene = parse_scene(tabletops[4])
    assert exact_depth_check(scene, views=2, size=(8, 6)) is None
    close = exact_depth_check(dataclasses.replace(scene, depth_range=(0.25, 0.5)), views=2,
                              size=(8, 6))
    assert close.startswith("exact depth [") and close.endswith("outside [0.25, 0.5]")
    floorless = tuple(dataclasses.replace(obj, params={**obj.params, "size": np.full(2, 0.01)})
                      if obj.name == "floor" else obj for obj in scene.objects)
    assert (exact_depth_check(dataclasses.replace(scene, objects=floorless), views=2, size=(8, 6))
            == "a ray at t = 0.000 s leaves the room (no surface)")


def test_builtin_meshes_in_a_scene_file(tmp_path):
    """``path = "builtin:NAME"`` needs no file beside the scene; an unknown name is refused
    naming the key and the built-in names."""
    body = ('duration = 1.0\n[camera]\npreset = "davis240c"\n[trajectory]\ntype = "linear"\n'
            'position = [0.0, 0.0, 0.0]\nvelocity = [0.0, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n'
            '[[lights]]\ntype = "point"\nposition = [0.0, 0.0, 1.0]\nintensity_cd = 50\n'
            '[[objects]]\ntype = "mesh"\npath = "builtin:{name}"\ncenter = [0.0, 1.0, 0.0]\n'
            'scale = 0.2\n')
    scene = parse_scene(body.format(name="torus"), tmp_path / "elsewhere.toml")
    vertices = obj_vertices(scene.objects[0].params["path"])
    assert math.isclose(np.hypot(vertices[:, 0], vertices[:, 1]).max(), 1.0, rel_tol=1e-6)
    depth = Renderer(dataclasses.replace(scene, camera=scene.camera.with_resolution(24, 18)),
                     spp=1).depth(0.0)
    hit = depth[depth > 0]         # the front of a torus 0.2 m across (its box: 0.8 to 1.2 m)
    assert hit.size > 0 and abs(hit.min() - 0.8) < 0.005 and hit.max() <= 1.2
    with pytest.raises(SceneError, match=r"\[\[objects\]\]\[0\].path: unknown built-in mesh "
                                         r"'teapot'; expected one of cone, globe, torus"):
        parse_scene(body.format(name="teapot"))
