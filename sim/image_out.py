"""Single PNG outputs (``evfuse events --stats --out F.png``, ``evfuse show --out F.png``): each
PNG evfuse writes carries a ``tEXt`` chunk ``Software: evfuse``, and an existing ``--out`` is
replaced only with ``--overwrite`` and only if it carries that chunk (a user's picture is
never replaced). Checked before any work."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

from sim.output import OutputError
from sim.validation import ParameterError

__all__ = ["PNG_SOFTWARE", "check_png_output", "is_evfuse_png", "mark_png"]

PNG_SOFTWARE = b"Software\x00evfuse"
"""The ``tEXt`` chunk (keyword, NUL, text) that marks a PNG evfuse wrote."""

_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))


def mark_png(encoded: bytes) -> bytes:
    """``encoded`` (a PNG file's bytes) with the ``Software: evfuse`` chunk after its header.

    Parameters
    ----------
    encoded : bytes
        A PNG file (``cv2.imencode(".png", ...)``).

    Returns
    -------
    bytes
        The same image, marked.
    """
    if not encoded.startswith(_SIGNATURE):
        raise ValueError("not a PNG file")
    end_of_header = len(_SIGNATURE) + 8 + struct.unpack(">I", encoded[8:12])[0] + 4
    return encoded[:end_of_header] + _chunk(b"tEXt", PNG_SOFTWARE) + encoded[end_of_header:]


def is_evfuse_png(path: str | Path) -> bool:
    """True if ``path`` is a PNG file with evfuse's ``Software: evfuse`` chunk before its
    image data."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return False
    if not data.startswith(_SIGNATURE):
        return False
    at = len(_SIGNATURE)
    while at + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[at:at + 8])
        if kind == b"tEXt" and data[at + 8:at + 8 + length] == PNG_SOFTWARE:
            return True
        if kind in (b"IDAT", b"IEND"):
            return False
        at += 12 + length
    return False


def check_png_output(out: str | Path, overwrite: bool, parameter: str = "out") -> None:
    """Refuse, before any work, a PNG output that evfuse cannot or may not write.

    Parameters
    ----------
    out : str or Path
        The file to write.
    overwrite : bool
        Whether an existing ``out`` that evfuse wrote may be replaced.
    parameter : str
        The caller's name for ``out`` (a placeholder the command line renames to its flag).

    Raises
    ------
    OutputError
        ``out`` does not end in ``.png``; or exists and ``overwrite`` is false; or exists and
        is not a PNG evfuse wrote.
    """
    path = Path(out)
    shown = ParameterError.literal(out)
    if path.suffix.lower() != ".png":
        raise OutputError(f"{{{parameter}}} {shown}: expected a file name ending in .png (the "
                          "image is written as PNG)", **{parameter: parameter})
    if not (path.exists() or path.is_symlink()) or path.is_dir():
        return                                  # a folder is check_output_file's to refuse
    if not overwrite:
        raise OutputError(f"output file {shown} exists; choose another {{{parameter}}}, or add "
                          "{overwrite} to replace it", **{parameter: parameter},
                          overwrite="overwrite=True")
    if path.is_symlink() or not is_evfuse_png(path):
        raise OutputError(f"output file {shown} exists and was not written by evfuse (no "
                          "'Software: evfuse' PNG text chunk); {overwrite} replaces only a PNG "
                          f"evfuse wrote: choose another {{{parameter}}}, or delete it yourself",
                          **{parameter: parameter}, overwrite="overwrite=True")
