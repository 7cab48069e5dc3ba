"""Triangle meshes of scene objects: the built-in meshes and a height field's grid.

evfuse's built-in meshes are small closed triangle meshes with texture coordinates, shipped in
``sim/scene/meshes/`` (a cone, a globe, a torus, a trefoil knot and a vase; each centred on the
origin and about 2 units across). A scene file names one as ``path = "builtin:NAME"`` in a
``mesh`` object, so that a scene text that uses it needs no file beside it (the scenes that
:mod:`sim.scene.procedural` draws are written into any folder). :func:`heightfield_mesh` is the
one definition of the grid a ``heightfield`` object is rendered as. :func:`vertex_normals` gives
a mesh's smooth normals in a fixed order (the renderer's, instead of Mitsuba's own: see there)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["BUILTIN_MESHES", "BUILTIN_MESH_PREFIX", "builtin_mesh_path", "heightfield_mesh",
           "obj_vertices", "vertex_normals"]

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


def heightfield_mesh(size, amplitude: float, wavelength, resolution
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangle mesh of ``z = amplitude sin(2 pi x / lx) cos(2 pi y / ly)`` over the size, in
    the height field's local frame (what a ``heightfield`` object is rendered as).

    Parameters
    ----------
    size : (2,) float, metres
        Extent along local x and y, centred on the origin.
    amplitude : float, metres
    wavelength : (2,) float, metres
        ``(lx, ly)``.
    resolution : (2,) int
        Vertices along x and along y, ``(nx, ny)``.

    Returns
    -------
    vertices : (ny * nx, 3) float64 ndarray, metres
        Row by row (y), x fastest.
    uv : (ny * nx, 2) float64 ndarray
        Texture coordinates, v = 1 at the lowest y.
    faces : (2 (ny - 1) (nx - 1), 3) int ndarray
        Vertex indices of the triangles.
    """
    sx, sy = size
    nx, ny = resolution
    lx, ly = wavelength
    xs, ys = np.linspace(-sx / 2, sx / 2, nx), np.linspace(-sy / 2, sy / 2, ny)
    gx, gy = np.meshgrid(xs, ys)
    gz = amplitude * np.sin(2 * np.pi * gx / lx) * np.cos(2 * np.pi * gy / ly)
    vertices = np.stack([gx, gy, gz], axis=-1).reshape(-1, 3)
    uv = np.stack(np.meshgrid(np.linspace(0, 1, nx), np.linspace(1, 0, ny)), -1).reshape(-1, 2)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)]).reshape(-1, 3)
    return vertices, uv, faces


def vertex_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Smooth vertex normals of a triangle mesh, each face's unit normal weighted by its angle at
    the vertex (Thuermer and Wuethrich, JGT 1998: Mitsuba's ``recompute_vertex_normals``), summed
    in face order: the same bits whatever the thread count.

    Mitsuba's JIT variants sum them with atomic float additions (``dr.scatter_reduce``) whose
    order follows Dr.Jit's worker threads, so a mesh loaded twice got normals that differed in
    their last bits, and renders and events with them (1 to 4 ns event times on a procedural
    tabletop, 1 in 8 runs). Sums here are in float64, rounded once to float32: they differ from
    Mitsuba's float32 sums by about an ulp of float32. Degenerate faces (zero area) add nothing; a
    vertex of degenerate faces only gets ``(1, 0, 0)``, as Mitsuba's scalar variants give it.

    Parameters
    ----------
    positions : (V, 3) float ndarray
        Vertex positions (any unit).
    faces : (F, 3) int ndarray
        Vertex indices of the triangles, counter-clockwise seen from the front.

    Returns
    -------
    (V, 3) float32 ndarray
        Unit normals.
    """
    v = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    corners = v[f]                                             # (F, 3 corners, 3)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    valid = length[:, 0] > 0.0
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0.0)
    weighted = np.empty((len(f), 3, 3))
    for i in range(3):
        d0 = corners[:, (i + 1) % 3] - corners[:, i]
        d1 = corners[:, (i + 2) % 3] - corners[:, i]
        d0 /= np.maximum(np.linalg.norm(d0, axis=1, keepdims=True), np.finfo(float).tiny)
        d1 /= np.maximum(np.linalg.norm(d1, axis=1, keepdims=True), np.finfo(float).tiny)
        angle = np.arccos(np.clip(np.sum(d0 * d1, axis=1), -1.0, 1.0))
        weighted[:, i] = normal * np.where(valid, angle, 0.0)[:, None]
    # bincount adds its weights in input order: face by face, corner by corner.
    index = f.ravel()
    sums = np.stack([np.bincount(index, weighted[:, :, c].ravel(), minlength=len(v))
                     for c in range(3)], axis=1)
    norm = np.linalg.norm(sums, axis=1, keepdims=True)
    out = np.divide(sums, norm, out=np.zeros_like(sums), where=norm > 0.0)
    out[norm[:, 0] == 0.0] = (1.0, 0.0, 0.0)
    return out.astype(np.float32)
