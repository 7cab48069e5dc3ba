"""Reading whitespace-separated numeric text files with errors that name the file and line."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

__all__ = ["parse_floats"]


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
