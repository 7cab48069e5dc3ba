"""The two event file formats, told apart by suffix: ECD text (``.txt``) and the DSEC HDF5 layout
(``.h5``, ``.hdf5``)."""

from __future__ import annotations

from pathlib import Path

_TEXT_SUFFIXES = (".txt",)
_H5_SUFFIXES = (".h5", ".hdf5")


def _kind(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in _TEXT_SUFFIXES:
        return "txt"
    if suffix in _H5_SUFFIXES:
        return "h5"
    raise ValueError(f"{path}: unknown event file type {suffix!r}; expected .txt (ECD text) or "
                     ".h5 (DSEC HDF5)")
