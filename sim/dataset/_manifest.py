"""The dataset's manifest: one row per job (``DIR/manifest.csv``, and ``DIR/manifest.parquet``
when pyarrow is importable), each job folder's counts (:func:`job_record`) and its output hash
(:func:`output_hash`). Both files are rewritten atomically whenever a job finishes, so that a
killed ``generate`` leaves a true manifest."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
from pathlib import Path

from sim._atomic import partial_path, write_bytes_atomically
from sim.output import MARKER
from sim.validation import ParameterError

__all__ = ["MANIFEST_CSV", "MANIFEST_PARQUET", "SOFTWARE_COLUMNS", "job_record",
           "manifest_columns", "output_hash", "read_manifest", "write_manifest"]

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


def output_hash(folder: str | Path) -> str:
    """sha256 over a sequence folder's files: each file's relative path (sorted, ``/``
    separated) then its bytes; ``sequence.json`` without its timings (``timings_s``, the
    only wall-clock content of a sequence folder) and without the scene file's path
    (``scene.source``: a built-in scene's path is the worker's install, while the scene's text,
    ``scene.toml``, stays in), re-serialised with sorted keys; the ``.evfuse`` marker (who
    wrote the folder, from which real input paths) is left out.

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
        if name == MARKER:
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


def write_manifest(folder: str | Path, rows: list[dict], parameters: list[str]) -> Path:
    """Write ``manifest.csv`` (and ``manifest.parquet`` when pyarrow is importable)
    atomically: each file is written beside and renamed into place.

    Parameters
    ----------
    folder : str or Path
        The dataset folder.
    rows : list of dict
        One per job (missing columns are empty).
    parameters : list of str
        The sweep's parameter names (one column each).

    Returns
    -------
    Path
        ``manifest.csv``.
    """
    folder = Path(folder)
    columns = manifest_columns(parameters)
    text = io.StringIO()
    writer = csv.DictWriter(text, columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if row.get(k) is None else row[k]) for k in columns})
    path = folder / MANIFEST_CSV
    write_bytes_atomically(path, text.getvalue().encode())
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return path
    table = pa.table({k: _column(pa, [row.get(k) for row in rows]) for k in columns})
    target = folder / MANIFEST_PARQUET
    pq.write_table(table, partial_path(target))
    os.replace(partial_path(target), target)
    return path


def _column(pa, values: list) -> object:
    """A manifest column as Parquet stores it: its values' own type (empty cells null), text
    where they mix types."""
    values = [None if v is None or v == "" else v for v in values]
    try:
        return pa.array(values)
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return pa.array([None if v is None else str(v) for v in values])


def read_manifest(folder: str | Path) -> list[dict]:
    """The rows of ``DIR/manifest.csv`` (values as text; empty cells ``""``), checked: the
    folder exists, it holds a manifest with the columns ``job_id``, ``path`` and ``status``,
    and each status is one of :data:`STATUSES`. The one reader of the manifest (``generate
    --resume``, :func:`sim.open_dataset`, ``evfuse dataset``).

    Raises
    ------
    ParameterError
        Not a folder, no manifest, a missing column or an unknown status (naming the line).
    """
    folder = Path(folder)
    path = folder / MANIFEST_CSV
    if not folder.is_dir():
        raise ParameterError(f"dataset folder {ParameterError.literal(folder)} does not exist "
                             "or is not a folder")
    if not path.is_file():
        raise ParameterError(f"{ParameterError.literal(folder)} has no {MANIFEST_CSV}: not a "
                             "dataset folder (evfuse generate writes one)")
    with path.open(newline="", encoding="utf-8") as handle:
        reader = csv.DictReader(handle)
        missing = [c for c in ("job_id", "path", "status") if c not in (reader.fieldnames or ())]
        if missing:
            raise ParameterError(f"{ParameterError.literal(path)}: no column "
                                 f"{', '.join(missing)}; expected job_id, path, status, ...")
        rows = list(reader)
    for number, row in enumerate(rows, 2):
        if row["status"] not in STATUSES:
            raise ParameterError(f"{ParameterError.literal(path)}:{number}: status "
                                 f"{row['status']!r}; expected done, failed or pending")
    return rows
