"""Requests that cannot give a meaningful result are refused in one line (issue 21, "No silent
garbage"): non-finite numbers, declared depth ranges that miss the scene, windows the sequence
cannot hold, millimetres, and a twin scene that its own simulation refuses."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BUILTIN_SCENES = sorted((ROOT / "scenes").glob("*.toml"))


# --------------------------------------------------------------------------------------------
# Declared depth ranges contain the exact depth
# --------------------------------------------------------------------------------------------

def _exact_depth_span(scene, times: int = 4, size: tuple[int, int] = (40, 30)):
    """(min, max) exact z-depth over ``times`` instants of ``[0, duration]``, rendered by
    Mitsuba on a small sensor of the same field of view (plain materials: geometry only)."""
    from sim.render import Renderer
    from sim.scene import Material

    objects = tuple(dataclasses.replace(o, material=Material()) for o in scene.objects)
    small = dataclasses.replace(scene, camera=scene.camera.with_resolution(*size),
                                objects=objects)
    renderer = Renderer(small, spp=1)
    low, high = np.inf, 0.0
    for t in np.linspace(0.0, scene.duration, times):
        depth = renderer.depth(float(t))
        hit = depth[depth > 0]
        assert hit.size, f"{scene.name}: nothing in view at t = {t}"
        low, high = min(low, float(hit.min())), max(high, float(hit.max()))
    return low, high


def _family_members():
    """Every family's knob-range corners and a few interior values (texture does not move
    geometry; shadow only adds a light)."""
    from fusion.families import FAMILIES

    for family, knobs in FAMILIES.items():
        names = list(knobs)
        values = [(low, high, default, (low + high) / 2) for default, low, high in
                  knobs.values()]
        for combo in itertools.product(*values):
            yield family, dict(zip(names, combo, strict=True))


def test_every_family_member_declares_a_range_that_contains_its_exact_depth():
    from fusion.families import FAMILIES, family_scene
    from sim.scene import parse_scene

    made = {family: 0 for family in FAMILIES}
    for family, knobs in _family_members():
        try:
            text = family_scene(family, **knobs)
        except ValueError as exc:                  # a refused combination says so in one line
            assert "\n" not in str(exc) and str(exc).startswith("--")
            continue
        scene = parse_scene(text)
        low, high = _exact_depth_span(scene)
        near, far = scene.depth_range
        assert near <= low and high <= far, (family, knobs, (low, high), (near, far))
        made[family] += 1
    assert all(n >= 4 for n in made.values()), made


def test_a_sphere_or_cylinder_touching_the_camera_is_refused():
    from fusion.families import family_scene

    for family in ("sphere", "cylinder"):
        with pytest.raises(ValueError, match="--radius 0.5 with --distance 0.5"):
            family_scene(family, radius=0.5, distance=0.5)


@pytest.mark.parametrize("path", BUILTIN_SCENES, ids=lambda p: p.stem)
def test_every_builtin_scene_declares_a_range_that_contains_its_exact_depth(path):
    from sim.scene import load_scene

    scene = load_scene(path)
    low, high = _exact_depth_span(scene, times=5)
    near, far = scene.depth_range
    assert near <= low and high <= far, ((low, high), (near, far))
