"""Built-in scenes: TOML scene files shipped with evfuse (see ``scenes/README.md``).

Twins of the Event-Camera Dataset sequences that the paper uses (sliders, 6-DoF scenes) and
complex surfaces for stress-testing map filling.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

__all__ = ["SCENE_DIR", "builtin_scenes", "describe_scenes", "resolve_scene"]

SCENE_DIR = Path(__file__).resolve().parent


def builtin_scenes() -> dict[str, Path]:
    """Names of the built-in scenes and their files, sorted by name."""
    return {path.stem: path for path in sorted(SCENE_DIR.glob("*.toml"))}


def describe_scenes() -> dict[str, str]:
    """One-line description of every built-in scene (its ``description`` field)."""
    out = {}
    for name, path in builtin_scenes().items():
        with path.open("rb") as handle:
            out[name] = tomllib.load(handle).get("description", "")
    return out


def resolve_scene(name_or_path: str | Path) -> Path:
    """The file of a built-in scene name, or the given path if it is a scene file.

    Raises
    ------
    ValueError
        Neither a built-in scene nor an existing file (the message lists the built-in names); a
        folder (a sequence folder, said so; any other: the message says what it lacks); a file
        of a sequence folder, such as an event file (the message names the folder holding it).
    """
    from sim.sequence import SEQUENCE_FOLDER_NEEDS, describe_data_file

    scenes = builtin_scenes()
    if str(name_or_path) in scenes:
        return scenes[str(name_or_path)]
    path = Path(name_or_path)
    if path.is_dir():
        lacks = [name for name in ("calib.txt", "images.txt") if not (path / name).is_file()]
        if not lacks:
            raise ValueError(f"{path} is a sequence folder, not a scene: a scene is a built-in "
                             "name or a .toml file; evfuse run, map, events and twin take a "
                             "sequence folder")
        raise ValueError(f"{path}: this folder lacks {' and '.join(lacks)}, so it is not a "
                         f"sequence folder (one needs {SEQUENCE_FOLDER_NEEDS}); a scene is a "
                         "built-in name or a .toml file")
    if path.is_file():
        what = describe_data_file(path)
        if what is None:
            return path
        folder = path.resolve().parent
        if (folder / "calib.txt").is_file():
            hint = f"give the sequence folder holding it, {folder}, to evfuse run or map"
        else:
            hint = (f"evfuse run and map take the sequence folder (with {SEQUENCE_FOLDER_NEEDS})"
                    f"; {folder} has no calib.txt")
        raise ValueError(f"{path} is {what}, not a scene: a scene is a built-in name or a .toml "
                         f"file; {hint}")
    raise ValueError(
        f"{name_or_path}: no such scene file, and not a built-in scene "
        f"(built-in: {', '.join(scenes)})"
    )
