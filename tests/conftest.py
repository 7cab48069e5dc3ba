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
        '[[lights]]\ntype = "directional"\ndirection = [0.0, 1.0, 0.0]\nirradiance = 1.0\n'
    )
    return (f'name = "test"\ndescription = "test scene"\nduration = {duration}\nseed = 3\n'
            f"{extra}\n{camera}\n{trajectory}\n{lights}\n{objects}\n")


@pytest.fixture(scope="session")
def ecd_slider() -> Path:
    """The real ECD slider_depth prefix, or skip when ../shared/data is absent."""
    if not ECD_SLIDER.is_dir():
        pytest.skip(f"{ECD_SLIDER} is absent")
    return ECD_SLIDER
