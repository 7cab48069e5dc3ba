"""Event times in the wrong unit: :func:`check_time_units` (judged against the poses) and the
unit naming that the HDF5 reader's own check (``ms_to_idx`` against ``events/t``) shares."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.eventio._formats import format_for

__all__ = ["UNIT_OVERLAP", "UNIT_SLACK", "check_time_units"]

UNIT_SLACK = 10.0
"""Factor by which two time spans that should agree may differ before the times are taken to be
in another unit (the units confused differ by 1000 or more)."""

UNIT_OVERLAP = 0.01
"""Share of the events' time span that must overlap the poses for :func:`check_time_units` to
take their unit as right; below it, another unit that puts them inside the poses is named."""

_UNITS = {"seconds": 1.0, "milliseconds": 1e-3, "microseconds": 1e-6, "nanoseconds": 1e-9}


def _unit_name(ratio: float, stored: str) -> str | None:
    """The unit within a factor 10 of ``stored`` times ``1 / ratio`` (what times read as
    ``stored`` but ``ratio`` times too long or short were written in), else None."""
    if not ratio > 0:
        return None
    scale = _UNITS[stored] / ratio
    name = min(_UNITS, key=lambda unit: abs(np.log10(_UNITS[unit] / scale)))
    return name if abs(np.log10(_UNITS[name] / scale)) < 1 and name != stored else None


def check_time_units(path: str | Path, first_s: float, last_s: float, t_start: float,
                     t_end: float) -> None:
    """Refuse events whose times are in another unit than their format stores, judged by poses.

    Events whose span overlaps the poses ``[t_start, t_end]`` over less than
    :data:`UNIT_OVERLAP` of it and is more than :data:`UNIT_SLACK` times longer (or shorter)
    than theirs, but would lie at least half inside them read in another unit (DSEC
    ``events.h5`` stores microseconds; ECD ``events.txt``, seconds), were written in that unit:
    a mapping over them could only fail later with a less telling message. Events merely
    outside the poses, with a span like theirs, are left to the window checks.

    Parameters
    ----------
    path : str or Path
        The event file (its suffix gives the stored unit).
    first_s, last_s : float, seconds
        First and last event time as read.
    t_start, t_end : float, seconds
        Time span of the poses (``groundtruth.txt``).

    Raises
    ------
    ValueError
        ``"{path}: events/t looks like nanoseconds (events at 3.81-174 s against 0.0223-3.4 s
        of poses); DSEC layout stores microseconds"`` and the like.
    """
    path = Path(path)

    def inside(a: float, b: float) -> float:
        """Share of [a, b] inside the poses (1 or 0 for a single instant)."""
        if b <= a:
            return float(t_start <= a <= t_end)
        return max(0.0, min(b, t_end) - max(a, t_start)) / (b - a)

    if inside(first_s, last_s) >= UNIT_OVERLAP:
        return
    stored = format_for(path).time_unit
    ratio = (last_s - first_s) / max(t_end - t_start, 1e-9)      # events' span / poses'
    for unit, size in _UNITS.items():
        factor = size / _UNITS[stored]
        if unit == stored or inside(first_s * factor, last_s * factor) < 0.5:
            continue
        if not (ratio > UNIT_SLACK if factor < 1 else ratio < 1 / UNIT_SLACK):
            continue
        fmt = format_for(path)
        field = "events/t looks" if fmt.name == "h5" else "the times look"
        layout = ("DSEC layout" if fmt.name == "h5" else fmt.title) + f" stores {stored}"
        raise ValueError(f"{path}: {field} like {unit} (events at {first_s:.4g}-"
                         f"{last_s:.4g} s against {t_start:.4g}-{t_end:.4g} s of poses); "
                         f"{layout}")
