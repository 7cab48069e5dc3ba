"""Depth maps and other float maps as float32 OpenEXR files.

A depth map (CONVENTIONS.md) is a single-part scanline EXR with one float32 channel ``Z``:
z-depth in metres at pixel centres, 0 where there is no value. Files are ZIP-compressed
(lossless), so a write followed by a read gives back the same bits.

Multi-channel maps (a depth and its confidence, say) use :func:`write_exr_channels` and
:func:`read_exr_channels`, which keep every channel separate under its own name (the
bindings would otherwise merge ``R``, ``G``, ``B``, ``A`` into one array).

Built on the ``OpenEXR`` Python bindings, version 3 (``OpenEXR.File``).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import OpenEXR

__all__ = ["DEPTH_CHANNEL", "read_depth", "read_exr_channels", "write_depth",
           "write_exr_channels"]

DEPTH_CHANNEL = "Z"
"""Name of the channel that holds z-depth in metres."""


def _check_map(name: str, values: np.ndarray, *, depth: bool) -> np.ndarray:
    """Validate one (H, W) map and return it as a C-contiguous float32 array."""
    array = np.asarray(values)
    if array.ndim != 2:
        raise ValueError(f"channel {name!r}: expected a 2-D (H, W) array, got shape {array.shape}")
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise ValueError(f"channel {name!r}: expected a non-empty (H, W) array, "
                         f"got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"channel {name!r}: expected real numbers, got dtype {array.dtype}")
    if array.dtype != np.float32:
        array = array.astype(np.float32)
    if depth:
        if np.isnan(array).any():
            raise ValueError(f"depth: {int(np.isnan(array).sum())} NaN pixel(s); expected metres "
                             "or 0 for no value")
        if np.isinf(array).any():
            raise ValueError(f"depth: {int(np.isinf(array).sum())} infinite pixel(s); expected "
                             "finite metres or 0 for no value")
        if (array < 0).any():
            raise ValueError(f"depth: {int((array < 0).sum())} negative pixel(s), minimum "
                             f"{float(array.min())}; expected metres >= 0 (0 for no value)")
    return np.ascontiguousarray(array)


def write_exr_channels(path: str | Path, channels: Mapping[str, np.ndarray]) -> None:
    """Write float32 maps of one size as the channels of one EXR file.

    Parameters
    ----------
    path : str or Path
        File to write (its folder must exist); replaced if it exists.
    channels : mapping of str to (H, W) float32 ndarray
        Channel name -> values. All maps must have the same shape. Other real dtypes are
        rounded to float32 (the stored type); NaN and inf are stored as is.

    Raises
    ------
    ValueError
        No channels, a bad channel name, a map that is not 2-D or not real, or shapes that
        differ.
    OSError
        The file cannot be written.
    """
    if not channels:
        raise ValueError(f"{path}: expected at least one channel, got none")
    arrays: dict[str, np.ndarray] = {}
    shape = None
    for name, values in channels.items():
        if not isinstance(name, str) or not name or any(c.isspace() for c in name):
            raise ValueError(f"{path}: channel names must be non-empty strings without spaces, "
                             f"got {name!r}")
        array = _check_map(name, values, depth=False)
        if shape is not None and array.shape != shape:
            raise ValueError(f"{path}: channel {name!r} has shape {array.shape}, expected "
                             f"{shape} like the others")
        shape = array.shape
        arrays[name] = array
    _write(path, arrays)


def _write(path: str | Path, arrays: dict[str, np.ndarray]) -> None:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    try:
        with OpenEXR.File(header, arrays) as exr:
            exr.write(str(path))
    except RuntimeError as exc:
        raise OSError(f"cannot write EXR file {path}: {exc}") from None


def read_exr_channels(path: str | Path) -> dict[str, np.ndarray]:
    """Read every channel of a single-part EXR file.

    Parameters
    ----------
    path : str or Path
        EXR file.

    Returns
    -------
    dict of str to (H, W) ndarray
        Channel name -> values, each channel separate (``R``, ``G``, ``B`` are not merged).
        float32 and half channels come back as float32 (half -> float32 is exact); uint
        channels as uint32.

    Raises
    ------
    ValueError
        The file is missing or is not a readable EXR file.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"EXR file {path} does not exist")
    if not OpenEXR.isOpenExrFile(str(path)):
        raise ValueError(f"{path} is not an OpenEXR file (bad magic number)")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            channels = exr.channels()
            result = {}
            for name, channel in channels.items():
                pixels = np.asarray(channel.pixels)
                if pixels.dtype == np.float16:
                    pixels = pixels.astype(np.float32)
                result[name] = pixels
    except (RuntimeError, ValueError) as exc:     # OpenEXR: "Invalid part index '0': ..."
        reason = " ".join(str(exc).split())
        raise ValueError(f"cannot read EXR file {path}: {reason}") from None
    return result


def write_depth(path: str | Path, depth: np.ndarray) -> None:
    """Write a depth map as a float32 EXR with the single channel ``Z``.

    Parameters
    ----------
    path : str or Path
        File to write (its folder must exist); replaced if it exists.
    depth : (H, W) float32 ndarray, metres, 0 where unknown
        z-depth at pixel centres. Other real dtypes are rounded to float32, the stored type;
        float32 input comes back bit-exact from :func:`read_depth`.

    Raises
    ------
    ValueError
        ``depth`` is not 2-D, is empty, or holds NaN, inf or negative values.
    OSError
        The file cannot be written.
    """
    _write(path, {DEPTH_CHANNEL: _check_map("depth", depth, depth=True)})


def read_depth(path: str | Path) -> np.ndarray:
    """Read a depth map written by :func:`write_depth` (or any EXR with a ``Z`` channel).

    Parameters
    ----------
    path : str or Path
        EXR file.

    Returns
    -------
    (H, W) float32 ndarray, metres, 0 where unknown
        The ``Z`` channel, bit-exact as written.

    Raises
    ------
    ValueError
        The file is missing, is not an EXR file, has no ``Z`` channel (the message lists the
        channels it has), its ``Z`` channel is not floating point, or a pixel holds NaN, inf
        or a negative depth (what :func:`write_depth` refuses to write; the first is named).
    """
    channels = read_exr_channels(path)
    if DEPTH_CHANNEL not in channels:
        raise ValueError(f"{path}: no depth channel {DEPTH_CHANNEL!r}; the file has channels "
                         f"{sorted(channels)}")
    depth = channels[DEPTH_CHANNEL]
    if depth.dtype != np.float32:
        raise ValueError(f"{path}: channel {DEPTH_CHANNEL!r} holds {depth.dtype} values, "
                         "expected float32 (or half) metres")
    bad = ~np.isfinite(depth) | (depth < 0)
    if bad.any():
        v, u = (int(i) for i in np.argwhere(bad)[0])
        count, value = int(bad.sum()), float(depth[v, u])
        shown = "NaN" if value != value else repr(value)
        raise ValueError(f"{path}: pixel (u={u}, v={v}) of channel {DEPTH_CHANNEL!r} holds "
                         f"{shown} ({count} pixel{'s' if count > 1 else ''} "
                         "like it); expected finite depths in metres >= 0 (0 = none)")
    return depth
