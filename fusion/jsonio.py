"""JSON documents of results (``map.json``, ``fill.json``, ``report.json``): strict JSON.

A metric with nothing to evaluate is NaN in memory and ``null`` on disk (strict JSON has no NaN);
NumPy scalars and arrays are written as numbers and lists.
"""

from __future__ import annotations

import json
import math

import numpy as np

__all__ = ["to_json"]


def _plain(value):
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def to_json(document: dict) -> str:
    """The document as indented, key-sorted, strict JSON text.

    Parameters
    ----------
    document : dict
        Nested dicts, lists, numbers (NumPy included), strings, None.

    Returns
    -------
    str
    """
    return json.dumps(_plain(document), indent=2, sort_keys=True, allow_nan=False) + "\n"
