"""What the README shows must work: its scene file parses, its demo is the Makefile's."""

from __future__ import annotations

import re
from pathlib import Path

from sim.scene import parse_scene

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_the_commented_scene_in_the_readme_is_valid():
    blocks = re.findall(r"```toml\n(.*?)```", README, flags=re.S)
    assert len(blocks) == 1
    scene = parse_scene(blocks[0], "README.md")
    assert scene.name == "two_boxes" and len(scene.objects) == 2
    assert (scene.camera.width, scene.camera.height) == (240, 180)


def test_the_readme_demo_command_is_the_makefile_demo():
    makefile = (ROOT / "Makefile").read_text()
    assert "$(BIN)/evfuse run $(DEMO_SCENE) --t0 $(DEMO_T0) --t1 $(DEMO_T1)" in makefile
    assert "DEMO_SCENE ?= complex_sphere" in makefile and "DEMO_T0 ?= 1.0" in makefile
    assert "DEMO_T1 ?= 3.0" in makefile
    assert "evfuse run complex_sphere --t0 1 --t1 3 --out runs/demo" in " ".join(README.split())


def test_every_name_the_readme_python_example_imports_exists():
    blocks = re.findall(r"```python\n(.*?)```", README, flags=re.S)
    assert blocks
    imports = re.findall(r"^from (\w+) import (?:\(([^)]*)\)|(.+)$)", blocks[0], flags=re.M)
    assert {module for module, _, _ in imports} == {"scenes", "sim", "fusion"}
    assert sum(len((g or s).split(",")) for _, g, s in imports) > 12
    for module, grouped, single in imports:
        package = __import__(module)
        for name in (n.strip() for n in (grouped or single).split(",") if n.strip()):
            assert hasattr(package, name), f"README imports {name} from {module}"
