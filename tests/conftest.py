"""Shared fixtures: small scenes written as TOML text, so tests exercise the real parser."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ECD_SLIDER = SHARED_DATA / "ecd_slider_depth_first50k"


def scene_text(objects: str, *, camera: str | None = None, trajectory: str | None = None,
               lights: str | None = None, duration: float = 1.0, extra: str = "") -> str:
    """TOML of a small test scene: 64x48 camera with fx != fy, static at the origin looking +y."""
    camera = camera or (
        "[camera]\nwidth = 64\nheight = 48\nfx = 60.0\nfy = 45.0\ncx = 30.3\ncy = 22.7\n"
    )
    trajectory = trajectory or (
        '[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
        "velocity = [0.0, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n"
    )
    lights = lights or (
        '[[lights]]\ntype = "directional"\ndirection = [0.0, 1.0, 0.0]\n'
        'illuminance_lux = 400.0\n'
    )
    return (f'name = "test"\ndescription = "test scene"\nduration = {duration}\nseed = 3\n'
            f"{extra}\n{camera}\n{trajectory}\n{lights}\n{objects}\n")


@pytest.fixture(scope="session")
def ecd_slider() -> Path:
    """The real ECD slider_depth prefix, or skip when ../shared/data is absent."""
    if not ECD_SLIDER.is_dir():
        pytest.skip(f"{ECD_SLIDER} is absent")
    return ECD_SLIDER


WALL = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 1.0, 0.0]
size = [6.0, 6.0]
[objects.material]
texture_scale = [6.0, 6.0]
texture = { type = "shapes", resolution = 256, count = 30, min_size = 10, max_size = 40 }
"""
FAST = ('[trajectory]\ntype = "linear"\nposition = [-0.15, 0.0, 0.0]\n'
        "velocity = [1.0, 0.0, 0.0]\nlook_at = [-0.15, 1.0, 0.0]\n")


@pytest.fixture(scope="session")
def plane_sequence(tmp_path_factory):
    """A 64x48 camera sliding 0.3 m past a fronto-parallel textured wall 1 m away."""
    from sim.scene import parse_scene
    from sim.simulate import simulate

    extra = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n"
    scene = parse_scene(scene_text(WALL, trajectory=FAST, duration=0.3, extra=extra))
    out = tmp_path_factory.mktemp("seq") / "plane"
    return simulate(scene, out, progress=False).out
