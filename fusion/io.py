"""fusion's result files: JSON documents and point clouds.

* JSON (``map.json``, ``fill.json``, ``report.json``): strict JSON through sim's one writer
  (:func:`sim.sequence.json_text`): a metric with nothing to evaluate is NaN in memory and ``null``
  on disk; NumPy scalars and arrays are written as numbers and lists.
* Point clouds as binary PLY: float32 x, y, z in a camera frame, that frame's world pose in a
  header comment, optional per-point colours and a per-point source flag; a filled frame's
  cloud (:func:`dense_cloud`, ``dense.ply`` and Figure 2's panel).
* Triangle meshes as binary PLY (:func:`write_mesh_ply`, :func:`read_mesh_ply`): float32 vertices
  in world metres with optional colours, triangles as ``element face`` lists (``mesh.ply``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fusion.fill.records import DenseResult
from sim.sequence import json_text

__all__ = ["dense_cloud", "read_mesh_ply", "read_ply", "to_json", "write_mesh_ply", "write_ply"]


def to_json(document: dict) -> str:
    """The document as indented, key-sorted, strict JSON text (:func:`sim.sequence.json_text`,
    the one writer of evfuse's JSON: NaN and infinity are ``null``).

    Parameters
    ----------
    document : dict
        Nested dicts, lists, numbers (NumPy included), strings, None.

    Returns
    -------
    str
    """
    return json_text(document)


def write_ply(path: str | Path, points: np.ndarray, T_world_frame: np.ndarray,
              colours: np.ndarray | None = None, source: np.ndarray | None = None,
              frame_name: str = "T_world_ref") -> None:
    """Write a binary little-endian PLY.

    Parameters
    ----------
    path : str or Path
    points : (N, 3) float ndarray, metres, in the camera frame of the view
    T_world_frame : (4, 4) ndarray
        World pose of that frame, written row-major in the comment ``<frame_name> ...``.
    colours : (N, 3) uint8 ndarray, BGR, optional
        Written as ``red``, ``green``, ``blue`` properties.
    source : (N,) uint8 ndarray, optional
        Written as a ``source`` property (e.g. 0 = event map point, 1 = filled).
    frame_name : str
        Name of the pose in the comment.
    """
    points = np.asarray(points, dtype="<f4").reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colours is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if source is not None:
        fields += [("source", "u1")]
    record = np.empty(len(points), dtype=fields)
    record["x"], record["y"], record["z"] = points.T
    if colours is not None:
        colours = np.asarray(colours, np.uint8).reshape(-1, 3)
        record["blue"], record["green"], record["red"] = colours.T
    if source is not None:
        record["source"] = np.asarray(source, np.uint8)
    pose = " ".join(f"{v:.9g}" for v in np.asarray(T_world_frame, dtype=np.float64).ravel())
    types = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0",
              f"comment {frame_name} (row-major 4x4) {pose}", f"element vertex {len(points)}"]
    header += [f"property {types[t]} {name}" for name, t in fields]
    header.append("end_header\n")
    with open(path, "wb") as handle:
        handle.write("\n".join(header).encode("ascii"))
        handle.write(record.tobytes())


def read_ply(path: str | Path) -> tuple[np.ndarray, dict]:
    """Read a PLY written by :func:`write_ply`.

    Returns
    -------
    record : (N,) structured ndarray with the vertex properties
    header : dict
        ``pose`` ((4, 4) ndarray or None) and ``comment`` (the pose's name).
    """
    data, lines, body = _ply_header(path)
    fields, count, pose, name = [], None, None, None
    for line in lines:
        words = line.split()
        if words[:2] == ["element", "vertex"]:
            count = int(words[2])
        elif words[0] == "property":
            fields.append((words[2], _ply_type(path, words[1])))
        elif words[0] == "comment" and len(words) == 20 and words[2] == "(row-major":
            name, pose = words[1], np.array([float(v) for v in words[4:]]).reshape(4, 4)
    if count is None:
        raise ValueError(f"{path}: no 'element vertex' line")
    record = np.frombuffer(data, dtype=fields, count=count, offset=body)
    return record, {"pose": pose, "comment": name}


_PLY_TYPES = {"float": "<f4", "uchar": "u1", "int": "<i4"}


def _ply_header(path: str | Path) -> tuple[bytes, list[str], int]:
    """The bytes of a binary little-endian PLY, its header lines and where its body starts."""
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' / 'end_header')")
    lines = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise ValueError(f"{path}: only binary little-endian PLY is read")
    return data, lines, end + len(b"end_header\n")


def _ply_type(path: str | Path, name: str) -> str:
    """The NumPy type of a PLY scalar type this module writes (``float``, ``uchar``, ``int``)."""
    if name not in _PLY_TYPES:
        raise ValueError(f"{path}: unsupported property type {name!r}")
    return _PLY_TYPES[name]


def write_mesh_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray,
                   colours: np.ndarray | None = None) -> None:
    """Write a triangle mesh as a binary little-endian PLY.

    Parameters
    ----------
    path : str or Path
    vertices : (V, 3) float ndarray, metres, world frame
        Written as float32 ``x``, ``y``, ``z``.
    faces : (F, 3) int ndarray
        Vertex indices of each triangle, written as ``element face`` with
        ``property list uchar int vertex_indices``.
    colours : (V, 3) uint8 ndarray, BGR, optional
        Per-vertex ``red``, ``green``, ``blue`` properties.
    """
    vertices = np.asarray(vertices, dtype="<f4").reshape(-1, 3)
    faces = np.asarray(faces).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"faces index vertices 0..{len(vertices) - 1}, got indices "
                         f"{faces.min()}..{faces.max()}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colours is not None:
        colours = np.asarray(colours, np.uint8).reshape(-1, 3)
        if len(colours) != len(vertices):
            raise ValueError(f"colours must have one row per vertex ({len(vertices)}), "
                             f"got {len(colours)}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    record = np.empty(len(vertices), dtype=fields)
    record["x"], record["y"], record["z"] = vertices.T
    if colours is not None:
        record["blue"], record["green"], record["red"] = colours.T
    triangles = np.empty(len(faces), dtype=[("n", "u1"), ("index", "<i4", (3,))])
    triangles["n"] = 3
    triangles["index"] = faces
    types = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", "comment evfuse mesh, world frame, metres",
              f"element vertex {len(vertices)}"]
    header += [f"property {types[t]} {name}" for name, t in fields]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices",
               "end_header\n"]
    with open(path, "wb") as handle:
        handle.write("\n".join(header).encode("ascii"))
        handle.write(record.tobytes())
        handle.write(triangles.tobytes())


def read_mesh_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read a mesh written by :func:`write_mesh_ply`.

    Returns
    -------
    vertices : (V, 3) float64 ndarray, metres
    faces : (F, 3) int32 ndarray
    colours : (V, 3) uint8 ndarray, BGR, or None where the file has none
    """
    data, lines, body = _ply_header(path)
    fields, vertex_count, face_count, element = [], None, None, None
    for line in lines:
        words = line.split()
        if words[:1] == ["element"]:
            element = words[1]
            if element == "vertex":
                vertex_count = int(words[2])
            elif element == "face":
                face_count = int(words[2])
            else:
                raise ValueError(f"{path}: unsupported element {element!r}")
        elif words[:1] == ["property"] and element == "vertex":
            fields.append((words[2], _ply_type(path, words[1])))
        elif words[:1] == ["property"] and element == "face":
            if words != ["property", "list", "uchar", "int", "vertex_indices"]:
                raise ValueError(f"{path}: faces must be 'property list uchar int "
                                 f"vertex_indices', got {line!r}")
    if vertex_count is None or face_count is None:
        raise ValueError(f"{path}: a mesh needs 'element vertex' and 'element face' lines")
    record = np.frombuffer(data, dtype=fields, count=vertex_count, offset=body)
    triangles = np.frombuffer(data, dtype=[("n", "u1"), ("index", "<i4", (3,))],
                              count=face_count, offset=body + record.nbytes)
    if np.any(triangles["n"] != 3):
        raise ValueError(f"{path}: only triangles are read")
    vertices = np.stack([record["x"], record["y"], record["z"]], 1).astype(np.float64)
    colours = None
    if {"red", "green", "blue"} <= set(record.dtype.names):
        colours = np.stack([record["blue"], record["green"], record["red"]], 1)
    return vertices, triangles["index"].astype(np.int32), colours


def dense_cloud(result: DenseResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of the dense map in the frame's camera, red for map points, green for filled."""
    v, u = np.nonzero(result.dense > 0)
    points = result.camera.backproject(np.stack([u, v], 1).astype(np.float64),
                                       result.dense[v, u].astype(np.float64))
    source = (result.sparse[v, u] == 0).astype(np.uint8)          # 0 event map, 1 filled
    colours = np.where(source[:, None] == 0, [[0, 0, 255]], [[0, 200, 0]]).astype(np.uint8)
    return points, colours, source
