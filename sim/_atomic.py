"""evfuse's atomic outputs: the one suffix of everything not yet complete, shared by every writer
(:mod:`sim.sequence` for folders, :mod:`sim.eventio` for event files), and the one policy for a
single file (:func:`atomic_file`). A leaf module (it imports no other module of the project), so
that any writer can import it without an import loop."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["PARTIAL_SUFFIX", "atomic_file", "partial_path", "write_bytes_atomically"]

PARTIAL_SUFFIX = ".partial"
"""Suffix of a folder or file evfuse is still writing: ``<out>.partial`` is renamed to ``<out>``
only once complete, so nothing under the final name is ever half-written."""


def partial_path(path: Path) -> Path:
    """The name ``path`` is written under until complete: ``<path>.partial``."""
    return path.with_name(path.name + PARTIAL_SUFFIX)


@contextmanager
def atomic_file(path: Path) -> Iterator[Path]:
    """Write one file atomically: the body writes the yielded ``<path>.partial``; when it returns,
    the file is flushed to disk (fsync) and renamed to ``path`` (replacing it).

    Parameters
    ----------
    path : Path
        The file to write (its folder must exist).

    Yields
    ------
    Path
        ``<path>.partial``, for the body to write (by name: any writer that takes a path).

    Notes
    -----
    If the body (or the fsync or rename) raises, ``<path>.partial`` is removed, ``path`` is
    untouched and the exception propagates: nothing under the final name is ever half-written,
    and no partial file is left behind. (The streaming event writers of :mod:`sim.eventio` keep
    their ``.partial`` file on failure, for a resumed run: they do not use this helper.)
    """
    partial = partial_path(path)
    try:
        yield partial
        with partial.open("rb") as handle:
            os.fsync(handle.fileno())
        os.replace(partial, path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def write_bytes_atomically(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through :func:`atomic_file`: never half-written.

    Parameters
    ----------
    path : Path
        The file to write (its folder must exist); replaced if it exists.
    data : bytes
        The file's contents.
    """
    with atomic_file(path) as partial:
        partial.write_bytes(data)
