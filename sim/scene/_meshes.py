"""evfuse's built-in meshes: small closed triangle meshes with texture coordinates, shipped in
``sim/scene/meshes/`` (a cone, a globe, a torus, a trefoil knot and a vase; each centred on the
origin and about 2 units across). A scene file names one as ``path = "builtin:NAME"`` in a
``mesh`` object, so that a scene text that uses it needs no file beside it (the scenes that
:mod:`sim.scene.procedural` draws are written into any folder)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["BUILTIN_MESHES", "BUILTIN_MESH_PREFIX", "builtin_mesh_path", "obj_vertices"]

MESH_DIR = Path(__file__).resolve().parent / "meshes"
BUILTIN_MESH_PREFIX = "builtin:"
"""A mesh ``path`` that starts with this names a built-in mesh instead of a file."""
BUILTIN_MESHES = ("cone", "globe", "torus", "trefoil", "vase")
"""The names of the built-in meshes (``sim/scene/meshes/<name>.obj``)."""


def builtin_mesh_path(name: str) -> Path:
    """The file of the built-in mesh ``name`` (one of :data:`BUILTIN_MESHES`).

    Raises
    ------
    ValueError
        An unknown name; the message lists the built-in ones.
    """
    if name not in BUILTIN_MESHES:
        raise ValueError(f"unknown built-in mesh {name!r}; expected one of "
                         f"{', '.join(BUILTIN_MESHES)}")
    return MESH_DIR / f"{name}.obj"


def obj_vertices(path: str | Path) -> np.ndarray:
    """The vertex positions of a Wavefront OBJ file (its ``v`` lines).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    (N, 3) float64 ndarray
        In the file's units and local frame.
    """
    rows = [line.split()[1:4] for line in Path(path).read_text().splitlines()
            if line.startswith("v ")]
    return np.array(rows, dtype=np.float64).reshape(-1, 3)
