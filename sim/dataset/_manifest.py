"""The dataset's manifest: one row per job (``DIR/manifest.csv``, and ``DIR/manifest.parquet``
when pyarrow is importable), each job folder's counts (:func:`job_record`) and its output hash
(:func:`output_hash`). Both files are rewritten atomically whenever a job finishes, so that a
killed ``generate`` leaves a true manifest.

One schema (:data:`COLUMN_TYPES`, :func:`column_types`) types both files and the rows
:func:`read_manifest` returns: the writer turns every row into the CSV's text first and types
the Parquet columns from that text, as the reader types what it reads, so a manifest keeps its
types however its rows were made (a fresh run, ``--resume``, ``--retries``, failed jobs)."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
from pathlib import Path

from sim._atomic import partial_path, write_bytes_atomically
from sim.output import MARKER
from sim.profile import PROFILE_JSON
from sim.validation import ParameterError

__all__ = ["COLUMN_TYPES", "MANIFEST_CSV", "MANIFEST_PARQUET", "SOFTWARE_COLUMNS",
           "column_types", "job_record", "manifest_columns", "output_hash", "read_manifest",
           "write_manifest"]

MANIFEST_CSV = "manifest.csv"
MANIFEST_PARQUET = "manifest.parquet"
STATUSES = ("done", "failed", "pending")
"""A job's status in the manifest."""
_TIMING_KEYS = ("timings_s",)
"""``sequence.json``'s keys that hold wall-clock times, left out of :func:`output_hash`."""
_HEAD = ("job_id", "path", "status", "error", "scene", "seed", "attempts")
_COUNTS = ("events", "frames", "renders", "pixel_samples", "duration_s", "wall_s",
           "output_hash")
SOFTWARE_COLUMNS = ("evfuse_version", "mitsuba_version", "drjit_version", "numpy_version")
"""The manifest's software columns (from each job's ``sequence.json``)."""

COLUMN_TYPES: dict[str, type] = {
    "job_id": str, "path": str, "status": str, "error": str, "scene": str, "seed": int,
    "attempts": int, "events": int, "frames": int, "renders": int, "pixel_samples": int,
    "duration_s": float, "wall_s": float, "output_hash": str,
    **{name: str for name in SOFTWARE_COLUMNS},
}
"""The type of each fixed column of the manifest: ``int`` (Parquet int64), ``float`` (float64)
or ``str`` (string). An empty cell is None (null) in any column. A sweep parameter's column is
typed by :func:`column_types` from its cells."""

_ARROW = {int: "int64", float: "float64", str: "string"}


def output_hash(folder: str | Path) -> str:
    """sha256 over a sequence folder's files: each file's relative path (sorted, ``/``
    separated) then its bytes; ``sequence.json`` without its timings (``timings_s``, the
    wall-clock content of a sequence folder besides ``profile.json``) and without the scene
    file's path (``scene.source``: a built-in scene's path is the worker's install, while the
    scene's text, ``scene.toml``, stays in), re-serialised with sorted keys; the ``.evfuse``
    marker (who wrote the folder, from which real input paths) and ``profile.json`` (wall and
    device seconds, :mod:`sim.profile`) are left out.

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    str
        64 hex digits: equal for two runs of the same job whatever the worker, order, thread
        count or restart.
    """
    folder = Path(folder)
    digest = hashlib.sha256()
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    for path in sorted(files, key=lambda p: p.relative_to(folder).as_posix()):
        name = path.relative_to(folder).as_posix()
        if name in (MARKER, PROFILE_JSON):
            continue
        data = path.read_bytes()
        if name == "sequence.json":
            record = json.loads(data)
            for key in _TIMING_KEYS:
                record.pop(key, None)
            if isinstance(record.get("scene"), dict):
                record["scene"].pop("source", None)
            data = json.dumps(record, sort_keys=True).encode()
        digest.update(name.encode() + b"\0" + len(data).to_bytes(8, "little") + data)
    return digest.hexdigest()


def job_record(folder: str | Path) -> dict:
    """The manifest's counts of a complete sequence folder, read from its ``sequence.json``.

    Returns
    -------
    dict
        ``events`` (None without events), ``frames``, ``renders`` (whole-frame renders of both
        cameras), ``pixel_samples``, ``duration_s`` (simulated), ``output_hash``, the software
        columns (:data:`SOFTWARE_COLUMNS`).
    """
    folder = Path(folder)
    record = json.loads((folder / "sequence.json").read_text())
    events = record.get("events") or {}
    software = record.get("software", {})
    return {
        "events": events.get("count"),
        "frames": record["frames"]["count"],
        "renders": record["render"]["renders"] + events.get("renders", 0),
        "pixel_samples": events.get("pixel_samples", 0),
        "duration_s": record["duration"],
        "output_hash": output_hash(folder),
        **{f"{name}_version": software.get(name, "") for name in
           ("evfuse", "mitsuba", "drjit", "numpy")},
    }


def manifest_columns(parameters: list[str]) -> list[str]:
    """The manifest's columns: job, status, scene, seed, attempts, one per parameter (sorted),
    counts, output hash, software versions."""
    return [*_HEAD, *sorted(parameters), *_COUNTS, *SOFTWARE_COLUMNS]


def _text(value) -> str:
    """A cell as the CSV holds it: empty for None, else ``str`` (which round-trips floats)."""
    return "" if value is None else str(value)


def _parses(text: str, kind: type) -> bool:
    try:
        kind(text)
    except ValueError:
        return False
    return True


def column_types(columns: list[str], rows: list[dict[str, str]]) -> dict[str, type]:
    """The type of each manifest column: :data:`COLUMN_TYPES` for the fixed ones; for a sweep
    parameter's, ``int`` when each non-empty cell is an integer, else ``float`` when each is a
    number, else ``str`` (from the cells' text, so that the writer and the reader agree).

    Parameters
    ----------
    columns : list of str
    rows : list of dict
        The rows as the CSV's text (``""`` for an empty cell).
    """
    types = {}
    for column in columns:
        if column in COLUMN_TYPES:
            types[column] = COLUMN_TYPES[column]
            continue
        cells = [row.get(column, "") for row in rows]
        cells = [cell for cell in cells if cell != ""]
        types[column] = next((kind for kind in (int, float)
                              if cells and all(_parses(cell, kind) for cell in cells)), str)
    return types


def _typed(rows: list[dict[str, str]], types: dict[str, type], path: Path) -> list[dict]:
    """The text rows with each cell of its column's type (None where empty); a cell of a fixed
    column that is not of its type is refused, naming the file, its line and the column."""
    typed = []
    for number, row in enumerate(rows, 2):
        out = {}
        for column, kind in types.items():
            cell = row.get(column, "")
            if cell is None or cell == "":
                out[column] = None
                continue
            try:
                out[column] = kind(cell)
            except ValueError:
                expected = "an integer" if kind is int else "a number"
                raise ParameterError(f"{ParameterError.literal(path)}:{number}: {column} "
                                     f"{cell!r}; expected {expected}") from None
        typed.append(out)
    return typed


def write_manifest(folder: str | Path, rows: list[dict], parameters: list[str]) -> Path:
    """Write ``manifest.csv`` (and ``manifest.parquet`` when pyarrow is importable)
    atomically: each file is written beside and renamed into place.

    Parameters
    ----------
    folder : str or Path
        The dataset folder.
    rows : list of dict
        One per job (missing columns are empty): values of any type whose ``str`` is the
        cell, e.g. the rows :func:`read_manifest` returns.
    parameters : list of str
        The sweep's parameter names (one column each).

    Returns
    -------
    Path
        ``manifest.csv``.
    """
    folder = Path(folder)
    columns = manifest_columns(parameters)
    cells = [{k: _text(row.get(k)) for k in columns} for row in rows]
    text = io.StringIO()
    writer = csv.DictWriter(text, columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(cells)
    path = folder / MANIFEST_CSV
    write_bytes_atomically(path, text.getvalue().encode())
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return path
    types = column_types(columns, cells)
    typed = _typed(cells, types, path)
    schema = pa.schema([(k, getattr(pa, _ARROW[types[k]])()) for k in columns])
    table = pa.Table.from_pylist(typed, schema=schema)
    target = folder / MANIFEST_PARQUET
    pq.write_table(table, partial_path(target))
    os.replace(partial_path(target), target)
    return path


def read_manifest(folder: str | Path) -> list[dict]:
    """The rows of ``DIR/manifest.csv``, typed (:func:`column_types`: ``int``, ``float`` or
    ``str``; None for an empty cell), checked: the folder exists, it holds a manifest with the
    columns ``job_id``, ``path`` and ``status``, each status is one of :data:`STATUSES` and
    each fixed column's cells are of its type. The one reader of the manifest (``generate
    --resume``, :func:`sim.open_dataset`, ``evfuse dataset``).

    Raises
    ------
    ParameterError
        Not a folder, no manifest, a missing column, an unknown status or a cell not of its
        column's type (naming the line).
    """
    folder = Path(folder)
    path = folder / MANIFEST_CSV
    if not folder.is_dir():
        raise ParameterError(f"dataset folder {ParameterError.literal(folder)} does not exist "
                             "or is not a folder")
    if not path.is_file():
        raise ParameterError(f"{ParameterError.literal(folder)} has no {MANIFEST_CSV}: not a "
                             "dataset folder (evfuse generate writes one)")
    with path.open(newline="", encoding="utf-8-sig") as handle:     # a BOM (an editor's) dropped
        reader = csv.DictReader(handle)
        missing = [c for c in ("job_id", "path", "status") if c not in (reader.fieldnames or ())]
        if missing:
            raise ParameterError(f"{ParameterError.literal(path)}: no column "
                                 f"{', '.join(missing)}; expected job_id, path, status, ...")
        columns = list(reader.fieldnames)
        rows = list(reader)
    for number, row in enumerate(rows, 2):
        if row["status"] not in STATUSES:
            raise ParameterError(f"{ParameterError.literal(path)}:{number}: status "
                                 f"{row['status']!r}; expected done, failed or pending")
        if None in row or None in row.values():
            raise ParameterError(f"{ParameterError.literal(path)}:{number}: not "
                                 f"{len(columns)} cells, one per column of its header")
    return _typed(rows, column_types(columns, rows), path)
