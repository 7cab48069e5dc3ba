"""Number validators shared by the parameter dataclasses of :mod:`sim`.

Each returns the value as a float or raises ``ValueError`` naming the field, so that a
dataclass's ``__post_init__`` says what was wrong in one line.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["non_negative", "positive"]


def positive(name: str, value: object) -> float:
    """``value`` as a finite float > 0, or a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ValueError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value}")
    return value


def non_negative(name: str, value: object) -> float:
    """``value`` as a finite float >= 0, or a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ValueError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value}")
    return value
