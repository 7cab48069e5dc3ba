"""JSON documents of results (``map.json``, ``fill.json``, ``report.json``): strict JSON.

A metric with nothing to evaluate is NaN in memory and ``null`` on disk (strict JSON has no NaN);
NumPy scalars and arrays are written as numbers and lists.
"""

from __future__ import annotations

from sim.sequence import json_text

__all__ = ["to_json"]


def to_json(document: dict) -> str:
    """The document as indented, key-sorted, strict JSON text (:func:`sim.sequence.json_text`,
    the one writer of evfuse's JSON: NaN and infinity are ``null``).

    Parameters
    ----------
    document : dict
        Nested dicts, lists, numbers (NumPy included), strings, None.

    Returns
    -------
    str
    """
    return json_text(document)
