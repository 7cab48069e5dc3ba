"""Short summaries of evfuse's objects for the REPL: a few lines, never every array.

:func:`summary_repr` is the ``__repr__`` of the public data and result classes (a sample of a
dataset, a sequence, a scene, a map, ...): set ``__repr__ = summary_repr`` in a dataclass's body
(a dataclass keeps a ``__repr__`` its class defines). Only the printed text changes: equality,
hashing, pickling and the fields are the dataclass's own. A class may name properties to show
first, its counts, in a class attribute ``_summary_counts`` (e.g. ``("n1",)``: ``n1=314``).

What a summary shows, for each field in order:

- numbers, booleans and short strings as Python writes them; a long string cut, with its length;
- an ndarray as its shape and dtype (``(180, 240) float32``), with its unit in brackets where the
  class's numpydoc docstring gives one (``depth : (H, W) float32 ndarray, metres`` -> ``[m]``);
  a structured array's dtype as its field names (``(1229,) {x, y, t, p}``); a 1-D array of at
  most :data:`SMALL` numbers (a position, a colour) as its values;
- a path as text, relative to the object's root folder (its first path field) when inside it:
  ``events_txt=folder/'events.txt'``;
- a tuple, list or dict as itself when short, else its count (``tuple of 4 Job``,
  ``{12 keys: 'camera', 'depth', ...}``);
- another dataclass as a glimpse of one line: its counts, root folder and arrays first, then its
  other fields (None ones left out, numbers to 6 digits), cut with ``...``; any other object as
  its repr when that is one short line, else ``Name(...)``;
- a field left at a default of None is left out.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import re
from pathlib import PurePath
from typing import Any

import numpy as np

__all__ = ["NESTED", "SMALL", "UNITS", "WIDTH", "brief", "field_units", "summary_repr"]

WIDTH = 100
"""Characters per line of a summary (the source's line length)."""

NESTED = 48
"""Characters one value of a summary may take: a nested object's glimpse, a sequence, a string."""

SMALL = 4
"""A 1-D numeric array of at most this many elements is shown by its values."""

UNITS = {"metres": "m", "meters": "m", "m": "m", "seconds": "s", "s": "s",
         "nanoseconds": "ns", "ns": "ns", "microseconds": "us", "us": "us",
         "pixels": "px", "px": "px", "pixels per second": "px/s", "radians": "rad",
         "rad": "rad", "degrees": "deg", "hz": "Hz", "m/s": "m/s", "rad/s": "rad/s",
         "m/s^2": "m/s^2", "1/s": "1/s", "lux": "lx"}
"""Unit words of numpydoc type lines, and the symbol a summary writes for each."""

_ATTRIBUTE = re.compile(r"^(\w+(?:, \w+)*) : (.+)$", re.MULTILINE)
_ASIDE = re.compile(r"\s*\(.*?\)\s*$")                  # "m/s (linear)" -> "m/s"


@functools.cache
def field_units(cls: type) -> dict[str, str]:
    """The unit of each attribute of ``cls`` whose docstring type line gives one.

    Parameters
    ----------
    cls : type
        A class with a numpydoc docstring: lines ``name : type, unit, ...`` (or
        ``a, b : ...``) in its Attributes or Parameters section.

    Returns
    -------
    dict of str to str
        Attribute name to unit symbol (:data:`UNITS`), for the attributes whose type line has
        a unit word among its comma-separated parts after the first.
    """
    units: dict[str, str] = {}
    for names, kind in _ATTRIBUTE.findall(inspect.cleandoc(cls.__doc__ or "")):
        words = [_ASIDE.sub("", part).strip().lower() for part in kind.split(",")[1:]]
        unit = next((UNITS[word] for word in words if word in UNITS), None)
        if unit is not None:
            units.update(dict.fromkeys(names.split(", "), unit))
    return units


def summary_repr(self: Any) -> str:
    """A dataclass instance in a few lines: its class name and each field abbreviated.

    Meant as ``__repr__ = summary_repr`` in a dataclass's body; the rules are the module's.

    Returns
    -------
    str
        ``Name(count=..., field=value, ...)``, wrapped at :data:`WIDTH` characters,
        continuation lines indented by 4.
    """
    items = [f"{name}={text}" for name, text in _items(self, depth=0)]
    lines, line = [], f"{type(self).__name__}("
    for k, item in enumerate(items):
        piece = item + (", " if k < len(items) - 1 else "")
        if len(line) + len(piece.rstrip()) > WIDTH and line.strip():
            lines.append(line.rstrip())
            line = "    "
        line += piece
    return "\n".join([*lines, line + ")"])


def brief(value: Any, unit: str | None = None, *, width: int = NESTED,
          root: tuple[str, PurePath] | None = None, depth: int = 0) -> str:
    """One value of a summary, on one line (the module's rules).

    Parameters
    ----------
    value : object
    unit : str, optional
        Its unit symbol, written after an array.
    width : int
        Characters a sequence, a string or a nested object may take before it is abbreviated.
    root : (str, Path), optional
        The name and path of the enclosing object's root folder: paths inside it are shown
        relative to it.
    depth : int
        0 for a field of the summarised object; from 1 (inside a glimpse or a sequence) a
        nested object is only its class name and a float has 6 digits.

    Returns
    -------
    str
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, np.ndarray):
        return _array(value, unit)
    if isinstance(value, float) and depth > 0:
        text = f"{value:.6g}"
        return text if any(c in text for c in ".ein") else text + ".0"
    if isinstance(value, str):
        return _string(value, width)
    if isinstance(value, PurePath):
        if root is not None and value != root[1] and value.is_relative_to(root[1]):
            return f"{root[0]}/{str(value.relative_to(root[1]))!r}"
        return repr(str(value))
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _glimpse(value, width, depth)
    if isinstance(value, tuple | list):
        return _sequence(value, width, depth)
    if isinstance(value, dict):
        return _mapping(value, width, depth)
    text = repr(value)
    return f"{type(value).__name__}(...)" if "\n" in text or len(text) > width else text


def _items(obj: Any, depth: int) -> list[tuple[str, str]]:
    """``(name, text)`` of the counts and shown fields of dataclass ``obj``: every field but
    those left at a default of None at depth 0, the non-None ones (root folder and arrays
    first) in a glimpse."""
    units = field_units(type(obj))
    fields = [(f.name, getattr(obj, f.name), f.default) for f in dataclasses.fields(obj)
              if f.repr]
    root = next(((name, value) for name, value, _ in fields if isinstance(value, PurePath)),
                None)
    shown = [(name, value) for name, value, default in fields
             if value is not None or (depth == 0 and default is not None)]
    if depth:
        shown.sort(key=lambda item: 0 if item[0] == (root or ("",))[0]
                   else 1 if isinstance(item[1], np.ndarray) else 2)
    counts = [(name, repr(getattr(obj, name))) for name in getattr(obj, "_summary_counts", ())]
    return counts + [(name, brief(value, units.get(name), root=root, depth=depth))
                     for name, value in shown]


def _glimpse(obj: Any, width: int, depth: int) -> str:
    """A nested dataclass on one line of about ``width`` characters at most."""
    name = type(obj).__name__
    if depth >= 1:
        return f"{name}(...)"
    text = f"{name}("
    items = [f"{key}={value}" for key, value in _items(obj, depth=1)]
    for k, item in enumerate(items):
        if len(text) + len(item) > width and k:
            return text + "...)"
        text += item + ", "
    return text.removesuffix(", ") + ")"


def _array(array: np.ndarray, unit: str | None) -> str:
    suffix = f" [{unit}]" if unit else ""
    if array.ndim == 1 and array.size <= SMALL and array.dtype.kind in "biuf":
        return "[" + ", ".join(brief(v, depth=1) for v in array.tolist()) + "]" + suffix
    shape = "(" + ", ".join(map(str, array.shape)) + ("," if array.ndim == 1 else "") + ")"
    kind = ("{" + ", ".join(array.dtype.names) + "}" if array.dtype.names
            else str(array.dtype))
    return f"{shape} {kind}{suffix}"


def _string(text: str, width: int) -> str:
    shown = repr(text)
    if len(shown) <= width:
        return shown
    head = repr(text[:width // 2])
    return f"{head[:-1]}...{head[-1]} ({len(text)} chars)"


def _sequence(values: tuple | list, width: int, depth: int) -> str:
    parts = [brief(v, width=width, depth=depth + 1) for v in values[:width]]
    if isinstance(values, tuple):
        text = "(" + ", ".join(parts) + ("," if len(values) == 1 else "") + ")"
    else:
        text = "[" + ", ".join(parts) + "]"
    if len(values) <= width and len(text) <= width:
        return text
    kinds = {"Path" if isinstance(v, PurePath) else type(v).__name__ for v in values}
    return (f"{type(values).__name__} of {len(values)}"
            + (f" {kinds.pop()}" if len(kinds) == 1 else ""))


def _mapping(values: dict, width: int, depth: int) -> str:
    text = "{" + ", ".join(f"{key!r}: {brief(value, width=width, depth=depth + 1)}"
                           for key, value in list(values.items())[:width]) + "}"
    if len(values) <= width and len(text) <= width:
        return text
    text = f"{{{len(values)} keys: "
    for k, key in enumerate(values):
        if len(text) + len(repr(key)) > width and k:
            return text + "...}"
        text += f"{key!r}, "
    return text.removesuffix(", ") + "}"
