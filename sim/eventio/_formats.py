"""The event file formats, told apart by suffix: ECD text (``.txt``), the DSEC HDF5 layout
(``.h5``, ``.hdf5``) and ROS bags (``.bag`` ROS 1; ``.mcap``, ``.db3`` or a folder holding
``metadata.yaml`` ROS 2; :mod:`sim.eventio._rosbag`)."""

from __future__ import annotations

from pathlib import Path

_TEXT_SUFFIXES = (".txt",)
_H5_SUFFIXES = (".h5", ".hdf5")
_BAG_SUFFIXES = (".bag", ".mcap", ".db3")


def _kind(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in _TEXT_SUFFIXES:
        return "txt"
    if suffix in _H5_SUFFIXES:
        return "h5"
    if suffix in _BAG_SUFFIXES or (path.is_dir() and (path / "metadata.yaml").is_file()):
        return "bag"
    raise ValueError(f"{path}: unknown event file type {suffix!r}; expected .txt (ECD text), "
                     ".h5 (DSEC HDF5), .bag (ROS 1), or .mcap or a ROS 2 bag folder (a new "
                     "folder needs the ROS version given)")
