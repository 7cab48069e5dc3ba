"""Where the depth range of the DSI comes from: the user, the scene's declaration, or a default.

EMVS needs the depth range of its disparity space image before it sees an event. A real rig
declares one (rpg_emvs's configuration files give ``min_depth`` / ``max_depth`` per sequence);
evfuse takes it, in this order of precedence:

1. the user's ``--min-depth`` / ``--max-depth`` (each bound on its own);
2. the working range the scene file declares (top-level ``depth_range``; a simulated sequence
   carries its scene file in ``sequence.json``);
3. a wide default, 0.2 to 5 m (:data:`DEFAULT_RANGE`).

None of these reads the exact depth: the pipeline is blind. ``oracle=True`` (``--depth-range
oracle``) opts in to the exact depth of the frame nearest the reference view, widened by 20 %
each way (:data:`ORACLE_MARGIN`); every output made with it says so (``oracle: true`` in its
JSON, a line on its figures), since its errors used the answer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.scene import declared_depth_range
from sim.sequence import Sequence
from sim.validation import ParameterError, check_parameter, depth_metres

__all__ = ["DEFAULT_RANGE", "ORACLE_MARGIN", "DSIRange", "declared_range", "oracle_header",
           "resolve_dsi_range"]

DEFAULT_RANGE = (0.2, 5.0)
"""Depth range (m) of the DSI when neither the user nor the scene gives one."""

ORACLE_MARGIN = 1.2
"""The oracle range is [min / 1.2, max * 1.2] of the exact depth at the reference view."""


@dataclass(frozen=True)
class DSIRange:
    """A DSI depth range and where it came from.

    Attributes
    ----------
    min_depth, max_depth : float, metres
    source : str
        How each bound was chosen, for the JSON and the report, e.g. ``"given"``,
        ``"scene file (declared working range)"``, ``"default 0.2-5 m"``,
        ``"oracle: exact depth at the reference view, widened by 20 %"``.
    oracle : bool
        True when the range was taken from the exact depth.
    """

    min_depth: float
    max_depth: float
    source: str
    oracle: bool = False

    def as_dict(self) -> dict:
        """The JSON entries every output of a map carries."""
        return {"depth_range_m": [self.min_depth, self.max_depth],
                "depth_range_from": self.source, "oracle": self.oracle}


def oracle_header(oracle: bool) -> list[str]:
    """The line every figure of a result made with the oracle range carries (none otherwise)."""
    return ["DSI depth range from the exact depth (oracle): not a blind result"] if oracle else []


def declared_range(sequence: Sequence) -> tuple[float, float] | None:
    """The working range (m) declared by the scene file a simulated sequence was made from.

    Read from the scene text kept in ``sequence.json`` by the scene parser
    (:func:`sim.scene.declared_depth_range`).

    Returns None for a real recording or a scene without ``depth_range``.

    Raises
    ------
    ValueError
        The recorded scene is not valid TOML or its ``depth_range`` is not ``[near, far]``
        metres with ``0 < near < far``; the message names ``sequence.json`` and the key.
    """
    text = ((sequence.metadata or {}).get("scene") or {}).get("toml")
    if not text:
        return None
    source = f"the scene recorded in {Path(sequence.folder) / 'sequence.json'}"
    return declared_depth_range(text, source)


ORACLE_TERMS = {"oracle": "oracle=True", "min_depth": "min_depth", "max_depth": "max_depth"}
"""The parameters the oracle's refusals name (:class:`sim.validation.ParameterError`)."""


def _oracle(sequence: Sequence, t_ref: float | None) -> DSIRange:
    where = ParameterError.literal(sequence.folder)
    if not sequence.depth_paths:
        raise ParameterError(f"{{oracle}} needs the exact depth of a simulated sequence; {where} "
                             "has none (a real recording): give {min_depth}/{max_depth}",
                             **ORACLE_TERMS)
    if t_ref is None:
        raise ParameterError("{oracle} needs the reference time", **ORACLE_TERMS)
    from sim.exr import read_depth

    depth = read_depth(sequence.depth_paths[sequence.nearest_depth(t_ref, tolerance=np.inf)])
    valid = depth[depth > 0]
    if valid.size == 0:
        raise ParameterError(f"{{oracle}}: the exact depth at {t_ref:.6f} s in {where} holds no "
                             "surface", **ORACLE_TERMS)
    return DSIRange(float(valid.min()) / ORACLE_MARGIN, float(valid.max()) * ORACLE_MARGIN,
                    "oracle: exact depth at the reference view, widened by 20 %", True)


def resolve_dsi_range(sequence: Sequence, min_depth: float | None = None,
                      max_depth: float | None = None, oracle: bool = False,
                      t_ref: float | None = None) -> DSIRange:
    """The DSI's depth range for a sequence (see the module docstring for the precedence).

    Parameters
    ----------
    sequence : Sequence
    min_depth, max_depth : float or None, metres
        The user's bounds (``--min-depth`` / ``--max-depth``).
    oracle : bool
        Take the range from the exact depth (opt-in; refused with either bound given).
    t_ref : float or None, seconds
        Reference view, needed by the oracle only.

    Returns
    -------
    DSIRange

    Raises
    ------
    ValueError
        Oracle with a given bound or without exact depth; a range with near >= far; a bound
        in millimetres (:func:`sim.validation.depth_metres`); a bound missing and the
        recorded scene's ``depth_range`` malformed (:func:`declared_range`).
    """
    if oracle:
        if min_depth is not None or max_depth is not None:
            raise ParameterError("{oracle} takes the range from the exact depth: drop "
                                 "{min_depth}/{max_depth}, or drop {oracle}", **ORACLE_TERMS)
        return _oracle(sequence, t_ref)
    # The scene's range is read (and a malformed one refused) only when a bound is missing.
    declared = None if (min_depth is not None and max_depth is not None) else \
        declared_range(sequence)
    fallback = (declared, "scene file (declared working range)") if declared else (
        DEFAULT_RANGE, f"default {DEFAULT_RANGE[0]:g}-{DEFAULT_RANGE[1]:g} m")
    low = fallback[0][0] if min_depth is None else float(min_depth)
    high = fallback[0][1] if max_depth is None else float(max_depth)
    given = (min_depth is not None, max_depth is not None)
    if all(given):
        source = "given (--min-depth, --max-depth)"
    elif any(given):
        which = "--min-depth" if given[0] else "--max-depth"
        source = f"given ({which}), the other bound from the {fallback[1]}"
    else:
        source = fallback[1]
    if not (np.isfinite(low) and np.isfinite(high) and 0 < low < high):
        raise ParameterError(f"depth range [{low:g}, {high:g}] m ({ParameterError.literal(source)})"
                             ": expected 0 < {min_depth} < {max_depth}, in metres",
                             min_depth="min_depth", max_depth="max_depth")
    declared_key = f"depth_range of the scene in {sequence.folder / 'sequence.json'}"
    for name, value, was_given in (("min_depth", low, given[0]), ("max_depth", high, given[1])):
        if was_given:                                                      # millimetres?
            check_parameter(depth_metres, name, value)
        else:
            depth_metres(declared_key, value)
    return DSIRange(low, high, source)
