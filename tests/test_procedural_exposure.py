"""Procedural scenes are exposed as a real camera exposes them (issue 38, part 2).

What must be shown: every seed 0-7 of both families (``tabletop``, ``room``) gives DAVIS240C
APS frames, as a dataset job writes them (``sweeps/tabletop.toml``: ``frame_sensor =
"davis240c_aps"``), with a mean grey in :data:`GOAL` = [40, 215]. With a fixed 5 ms exposure
and lights drawn in candela, seed 1 of ``tabletop`` had a mean grey of 4.8.

The rule under test (:mod:`sim.scene.procedural`): the drawn file's ``[frames]`` lets a sensor's
auto-exposure choose up to ``max_exposure = 0.04`` s (the built-in scenes' 40 ms), and the key
light's intensity is set by the illuminance it gives at the objects' centre, drawn in indoor
lighting's range (``illuminance_lux``); the fills are a drawn fraction of the key.

The first frame of each seed is made as ``evfuse simulate`` makes it (the exposure auto-exposure
settles on for that view, its renders averaged, electrons, noise and fixed pattern:
``tests.test_builtin_frames.realistic_frame_greys``), rendered 120 pixels wide; about 0.5 s a
seed on 2 cores. ``benchmarks/bench_procedural_exposure.py`` simulates the 2-s sequences of
the same 16 seeds at 240x180, every frame, and records them in
``benchmarks/results/procedural_exposure.json``.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from sim.frames import frame_times, with_frame_sensor
from sim.scene import parse_scene
from sim.scene.procedural import (
    MAX_EXPOSURE_S,
    RoomRanges,
    TabletopRanges,
    procedural_scene,
)
from sim.validation import ParameterError
from tests.test_builtin_frames import realistic_frame_greys

GOAL = (40.0, 215.0)
"""Mean grey (of 255) every procedural seed's frames must have."""
SEEDS = range(8)
RANGES = {"tabletop": TabletopRanges(), "room": RoomRanges()}


@pytest.mark.parametrize("family", ["tabletop", "room"])
@pytest.mark.parametrize("seed", SEEDS)
def test_every_seed_gives_exposed_davis240c_frames(family, seed):
    scene = with_frame_sensor(parse_scene(procedural_scene(family, seed), seed=seed),
                              "davis240c_aps")
    assert scene.frames.max_exposure == MAX_EXPOSURE_S <= 1.0 / scene.frames.rate
    first = float(frame_times(scene.duration, scene.frames)[0])    # max_exposure / 2
    means, exposures, _ = realistic_frame_greys(scene, [first])
    assert GOAL[0] <= means[0] <= GOAL[1], (
        f"{family} {seed}: mean grey {means[0]} (exposure {exposures[0]} ms), expected "
        f"within {list(GOAL)}")
    assert exposures[0] <= 1e3 * MAX_EXPOSURE_S


def _key_illuminance(scene) -> float:
    """Lux the first light gives, unoccluded, on a surface facing up at the placed objects'
    mean centre (x, y and z of the centres averaged): ``I cos(theta) / d^2``."""
    centres = np.array([obj.center for obj in scene.objects if obj.name.startswith("obj")])
    offset = np.asarray(scene.lights[0].position) - centres.mean(axis=0)
    distance = float(np.linalg.norm(offset))
    return float(scene.lights[0].intensity[0]) * (offset[2] / distance) / distance ** 2


@pytest.mark.parametrize("family", ["tabletop", "room"])
def test_the_key_light_gives_an_indoor_illuminance_and_the_fills_a_fraction_of_it(family):
    """Seeds 0-7: the key light's illuminance at the objects (the inverse-square law, from the
    parsed file) lies in the family's ``illuminance_lux`` and is the one its comment states;
    each fill light has a fraction of the key's intensity in ``fill_fraction``."""
    ranges = RANGES[family]
    for seed in SEEDS:
        text = procedural_scene(family, seed)
        scene = parse_scene(text)
        lux = _key_illuminance(scene)
        low, high = ranges.illuminance_lux
        assert low * (1 - 1e-3) <= lux <= high * (1 + 1e-3), (family, seed, lux)
        stated = float(re.search(r"# key light: (\d+) lux", text).group(1))
        assert math.isclose(lux, stated, abs_tol=0.6), (family, seed, lux, stated)
        key = float(scene.lights[0].intensity[0])
        for fill in scene.lights[1:]:
            fraction = float(fill.intensity[0]) / key
            assert ranges.fill_fraction[0] - 1e-3 <= fraction <= ranges.fill_fraction[1] + 1e-3


def test_the_illuminance_range_is_used_and_checked():
    """A given range is the key light's; lux of 0 (no light) is refused naming the range."""
    scene = parse_scene(procedural_scene("tabletop", 5, illuminance_lux=(300.0, 300.0)))
    assert math.isclose(_key_illuminance(scene), 300.0, rel_tol=1e-3)
    with pytest.raises(ParameterError, match=r"illuminance_lux \[0.0, 100.0\]: expected lux "
                                             r"above 0"):
        procedural_scene("room", 1, illuminance_lux=(0.0, 100.0))
