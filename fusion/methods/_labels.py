"""The label grammar of filling methods (see :mod:`fusion.methods`): a setting's value as text
(:func:`parse_value`, :func:`format_value`), comma-separated labels (:func:`split_labels`) and a
label ``NAME{KEY=VALUE,...}`` read (:func:`label_parts`) and written (:func:`method_label`).

Text only: it knows no method (the registry, :mod:`fusion.methods._registry`, checks the names and
settings), so the registry imports it without an import loop.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Mapping

from fusion.methods._errors import MethodError

__all__ = ["format_value", "label_parts", "method_label", "parse_value", "split_labels"]


def parse_value(text: str):
    """A setting's value from text: ``true`` / ``false``, ``none``, an int or float literal, a
    quoted string; any other text is itself (a string).

    Raises
    ------
    MethodError
        A literal that overflows to infinity (``1e999``): no setting takes one. (``nan`` and
        ``inf`` are not literals: they are text, which a number setting refuses.)
    """
    stripped = text.strip()
    lowered = stripped.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    if lowered == "none":
        return None
    try:
        value = ast.literal_eval(stripped)
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        return stripped
    if isinstance(value, float) and not math.isfinite(value):
        raise MethodError(f"{stripped}: expected a finite number")
    return value if isinstance(value, bool | int | float | str) else stripped


def format_value(value) -> str:
    """A setting's value as :func:`parse_value` reads it back: true, false, none, numbers, bare
    words, other strings quoted."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "none"
    if isinstance(value, str):
        bare = value and all(c.isalnum() or c in "_-.+/:" for c in value)
        return value if bare and parse_value(value) == value else repr(value)
    return repr(value) if isinstance(value, float) else str(value)


def split_labels(text: str) -> list[str]:
    """Comma-separated method labels (``plane,plane{residual_rel=0.03,min_points=4}``) apart:
    commas inside braces or quotes do not separate; blanks dropped."""
    parts, depth, quote, start = [], 0, "", 0
    for i, char in enumerate(text):
        if quote:
            quote = "" if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char in "{}":
            depth += 1 if char == "{" else -1
        elif char == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [part.strip() for part in parts if part.strip()]


def label_parts(text: str) -> tuple[str, dict]:
    """A label, ``NAME`` or ``NAME{KEY=VALUE,...}`` (:func:`method_label`), apart: the name and
    the settings, values read by :func:`parse_value`; nothing is checked against a method
    (:func:`fusion.methods.parse_label` makes the :class:`fusion.methods.MethodVariant`).

    Raises
    ------
    MethodError
        Braces that do not close the text, an item without ``=`` or a key that is not a name,
        a key given twice; one line naming the label and what was expected.
    """
    text = text.strip()
    if "{" not in text and "}" not in text:
        return text, {}
    name, _, body = text.partition("{")
    expected = f"{text}: expected NAME or NAME{{KEY=VALUE,...}}"
    if not name.strip() or "}" in name or not body.endswith("}"):
        raise MethodError(expected)
    params = {}
    for item in split_labels(body[:-1]):
        key, equals, value = item.partition("=")
        key = key.strip()
        if not equals or not key.isidentifier():
            raise MethodError(f"{expected}; got {item!r}")
        if key in params:
            raise MethodError(f"{text}: {key} given twice")
        try:
            params[key] = parse_value(value)
        except MethodError as exc:
            raise MethodError(f"{text}: {key}={exc}") from None
    return name.strip(), params


def method_label(name: str, params: Mapping | None = None) -> str:
    """``name``, or ``name{key=value,...}`` with the settings in key order: how a method's
    variant is shown in tables, and what ``--method`` takes back."""
    if not params:
        return name
    items = (f"{key}={format_value(params[key])}" for key in sorted(params))
    return name + "{" + ",".join(items) + "}"
