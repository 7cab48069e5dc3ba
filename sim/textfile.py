"""Reading whitespace-separated numeric text files with errors that name the file and line."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from pathlib import Path

__all__ = ["BOM", "bom_hint", "numeric_rows", "parse_floats", "text_lines"]

BOM = "\ufeff"
"""The byte-order mark some editors put at the start of a UTF-8 file (bytes EF BB BF): invisible
in a message, so it is dropped where a line is read (:func:`text_lines`) and named where a
parser refuses it (:func:`bom_hint`)."""


def bom_hint(text: str) -> str:
    """What to add to a parse error of ``text``: a note if it starts with a byte-order mark
    (which TOML does not allow), else nothing.

    Parameters
    ----------
    text : str
        The whole file, decoded.

    Returns
    -------
    str
        ``" (the file starts with a byte-order mark, U+FEFF: save it as UTF-8 without one)"``
        or ``""``.
    """
    return (" (the file starts with a byte-order mark, U+FEFF: save it as UTF-8 without one)"
            if text.startswith(BOM) else "")


def text_lines(path: str | Path) -> Iterator[tuple[int, str]]:
    """The lines of a UTF-8 text file, numbered from 1, without their line ends.

    Lines end at ``\\n`` (a ``\\r`` before it is dropped), as in the event files' reader, and
    each line is decoded on its own, so that bytes that are not UTF-8 are named by their line. A
    byte-order mark at the start of the file (:data:`BOM`) is dropped.

    Parameters
    ----------
    path : str or Path

    Yields
    ------
    lineno : int, 1-based
    line : str

    Raises
    ------
    ValueError
        ``"{path}:{lineno}: not UTF-8 text (byte 0x80 at column 1); expected ..."``.
    OSError
        The file cannot be opened.
    """
    path = Path(path)
    with path.open("rb") as handle:
        for lineno, raw in enumerate(handle, start=1):
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise ValueError(f"{path}:{lineno}: not UTF-8 text (byte 0x{raw[exc.start]:02x} "
                                 f"at column {exc.start + 1}); expected a text file") from None
            if lineno == 1:
                line = line.removeprefix(BOM)        # an editor's mark, not a character
            yield lineno, line.rstrip("\r\n")


def parse_floats(
    fields: Sequence[str], path: str | Path, lineno: int, expected: str
) -> list[float]:
    """Convert the fields of one line to finite floats.

    Parameters
    ----------
    fields : sequence of str
        The line's whitespace-separated fields.
    path : str or Path
        File being read (for the message).
    lineno : int
        1-based line number (for the message).
    expected : str
        What a line should look like, e.g. ``"t px py pz qx qy qz qw"``.

    Returns
    -------
    list of float

    Raises
    ------
    ValueError
        ``"{path}:{lineno}: 'x' is not a number; expected ..."`` or ``... is not finite ...``.
    """
    values = []
    for field in fields:
        try:
            value = float(field)
        except ValueError:
            raise ValueError(f"{path}:{lineno}: {field!r} is not a number; expected {expected}"
                             ) from None
        if not math.isfinite(value):
            raise ValueError(f"{path}:{lineno}: {field!r} is not finite; expected finite numbers")
        values.append(value)
    return values


def numeric_rows(path: str | Path, columns: int, expected: str
                 ) -> Iterator[tuple[int, list[str], list[float]]]:
    """The lines of a whitespace-separated numeric file, blank and ``#`` lines skipped.

    Parameters
    ----------
    path : str or Path
    columns : int
        How many numbers each line must hold.
    expected : str
        What a line should look like (for the messages).

    Yields
    ------
    lineno : int, 1-based
    fields : list of str
    values : list of float, finite

    Raises
    ------
    ValueError
        ``"{path}:{lineno}: expected ..., got N fields"`` or :func:`parse_floats`'s messages.
    """
    path = Path(path)
    for lineno, line in text_lines(path):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = text.split()
        if len(fields) != columns:
            raise ValueError(f"{path}:{lineno}: expected {expected}, got {len(fields)} fields")
        yield lineno, fields, parse_floats(fields, path, lineno, expected)
