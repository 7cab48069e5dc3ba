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


def test_the_readme_counts_the_built_in_scenes_as_evfuse_scenes_lists_them():
    from scenes import builtin_scenes

    counts = re.findall(r"(\d+) built-in scenes|lists all (\d+)", " ".join(README.split()))
    assert counts
    for pair in counts:
        assert int("".join(pair)) == len(builtin_scenes())


def test_every_object_type_the_readme_lists_is_accepted():
    listed = re.search(r'type = "rectangle" +# (.+)', README).group(1)
    shapes = [s.strip() for s in listed.split(",")]
    assert "box" in shapes and "mesh" in shapes
    block = re.findall(r"```toml\n(.*?)```", README, flags=re.S)[0]
    head = block.split("[[objects]]")[0]
    fields = {"rectangle": "size = [1.0, 1.0]", "box": "size = [0.3, 0.3, 0.3]",
              "sphere": "radius = 0.2", "cylinder": "radius = 0.2\nheight = 0.5",
              "heightfield": "size = [1.0, 1.0]\namplitude = 0.05\nwavelength = [0.4, 0.4]"}
    for shape in shapes:
        if shape == "mesh":                                # needs a file: its own tests
            continue
        text = (f'{head}[[objects]]\ntype = "{shape}"\ncenter = [0.0, 1.5, 0.0]\n'
                f"{fields.get(shape, '')}\n")
        assert parse_scene(text, "README.md").objects[0].shape == shape


def test_the_readmes_say_that_look_at_is_a_point():
    scenes_readme = (ROOT / "scenes" / "README.md").read_text()
    for text in (README, scenes_readme):
        line = re.search(r"^look_at = .*$", text, flags=re.M).group(0)
        assert "point" in line.lower(), line
    # and it is one: the README's camera at (-0.2, 0, 0) looks at (-0.2, 1, 0), along +y
    scene = parse_scene(re.findall(r"```toml\n(.*?)```", README, flags=re.S)[0], "README.md")
    optical_axis = scene.trajectory.pose(0.0)[:3, 2]
    assert abs(optical_axis[1] - 1.0) < 1e-9
