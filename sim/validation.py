"""Number validators shared by the parameter dataclasses of :mod:`sim`, and the error that names a
parameter so that a front end can name its own flag instead.

Each validator returns the value as a float or raises ``ValueError`` naming the field, so that a
dataclass's ``__post_init__`` says what was wrong in one line.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping

import numpy as np

__all__ = ["MAX_SEED", "PLAUSIBLE_DEPTH_M", "ParameterError", "bounded", "check_parameter",
           "depth_metres", "finite", "integer", "non_negative", "positive", "seed"]

PLAUSIBLE_DEPTH_M = 100.0
"""Largest depth accepted where a depth is given (a scene's ``depth_range``, ``--min-depth`` /
``--max-depth``, a twin's poster depth), metres: beyond it the value is taken for millimetres
(the ECD's 0.47-2.4 m written 470-2400) and refused. Event-based mapping over a window's
baseline (centimetres to metres) resolves no depth out there anyway."""

MAX_SEED = 2**32 - 1
"""Largest seed accepted anywhere (``--seed``, a scene file's ``seed`` and ``[render] seed``, a
sweep's ``seeds``): Mitsuba's ``render(seed=...)`` takes an unsigned 32-bit integer (2**32 raises
a TypeError from ``sample_tea_32``); numpy's ``default_rng`` takes any integer >= 0."""


class ParameterError(ValueError):
    """A refused request, in the library's terms, whose parameters a front end can name its way.

    The library speaks of its own parameters (``out``, ``overwrite=True``, ``t0``); a command
    line speaks of flags (``--out``, ``--overwrite``, ``--t0``). The message is written once, with
    each parameter it mentions as a ``{name}`` placeholder; ``str(error)`` fills each with the
    library's wording given in ``terms``, and :meth:`rephrase` with the front end's. So the
    library never names a flag, and the command line never re-words a library sentence.

    Parameters
    ----------
    message : str
        One line; ``{name}`` for each parameter of ``terms``. Text that may hold braces (a path)
        goes in through :meth:`literal`; other braces are left as they are.
    **terms : str
        Parameter name -> the library's wording of it (``overwrite="overwrite=True"``).

    Examples
    --------
    >>> error = ParameterError("pass {overwrite} to replace it", overwrite="overwrite=True")
    >>> str(error)
    'pass overwrite=True to replace it'
    >>> error.rephrase({"overwrite": "--overwrite"})
    'pass --overwrite to replace it'
    """

    def __init__(self, message: str, **terms: str) -> None:
        self.template = message
        self.terms = terms
        super().__init__(self.rephrase({}))

    def rephrase(self, names: Mapping[str, str]) -> str:
        """The message with each parameter named by ``names`` (the library's term where absent).

        Parameters
        ----------
        names : mapping of str to str
            Parameter name -> a front end's name for it (a flag).

        Returns
        -------
        str
        """
        def fill(match: re.Match) -> str:
            name = match.group(1)
            if name is None:                       # a doubled brace from literal()
                return match.group(0)[0]
            if name not in self.terms:
                return match.group(0)
            return names.get(name, self.terms[name])
        return re.sub(r"\{\{|\}\}|\{(\w+)\}", fill, self.template)

    @staticmethod
    def literal(value: object) -> str:
        """``value`` as text to put in a message as it is (its braces doubled, so that a path
        holding ``{out}`` is never taken for a placeholder).

        Parameters
        ----------
        value : object
            A path, a number, any text.

        Returns
        -------
        str
        """
        return str(value).replace("{", "{{").replace("}", "}}")


def finite(name: str, value: object) -> float:
    """``value`` as a finite float, or a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ValueError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value}")
    return value


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


def integer(name: str, value: object, minimum: int) -> int:
    """``value`` as an int >= ``minimum`` (an integral float such as 3.0 is taken), or a
    ValueError naming ``name`` (a bool, NaN, an infinity or a fraction is refused)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if not (math.isfinite(value) and float(value).is_integer() and value >= minimum):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def seed(name: str, value: object) -> int:
    """``value`` as a seed, an int in 0..:data:`MAX_SEED`, or a ValueError naming ``name``."""
    if (isinstance(value, bool) or not isinstance(value, int | np.integer)
            or not 0 <= value <= MAX_SEED):
        raise ValueError(f"{name} must be an integer in 0..{MAX_SEED} (2**32 - 1), got {value!r}")
    return int(value)


def depth_metres(name: str, value: object) -> float:
    """``value`` as a depth in metres, finite and at most :data:`PLAUSIBLE_DEPTH_M`, or a
    ValueError naming ``name`` (beyond that bound: saying it looks like millimetres). Its sign
    is the caller's to check (with :func:`positive`, or against the other bound of a range)."""
    value = finite(name, value)
    if value > PLAUSIBLE_DEPTH_M:
        raise ValueError(f"depths are in metres: {name} {value:g} looks like millimetres "
                         f"({value / 1000:g} m?); depths above {PLAUSIBLE_DEPTH_M:g} m are "
                         "refused")
    return value


def bounded(cls: str, name: str, value, *, low: float = 0.0, low_open: bool = False,
            high: float | None = None, high_open: bool = False) -> float:
    """``value`` as a float in the given range, or a ValueError naming ``cls.name``.

    The range is ``[low, high]``, each end open where ``low_open`` / ``high_open``; no ``high``:
    no upper bound (used by :mod:`sim.noise` and :mod:`sim.radiometry`).
    """
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"{cls}.{name} must be a number, got {value!r}")
    value = float(value)
    too_low = value <= low if low_open else value < low
    too_high = high is not None and (value >= high if high_open else value > high)
    if not math.isfinite(value) or too_low or too_high:
        left = "(" if low_open else "["
        right = "]" if high is None else (")" if high_open else "]")
        upper = "inf)" if high is None else f"{high:g}{right}"
        raise ValueError(f"{cls}.{name} must be a finite number in {left}{low:g}, {upper}, "
                         f"got {value!r}")
    return value


def check_parameter(check: Callable[[str, object], float], name: str, value: object) -> float:
    """``check(name, value)`` for a library function's parameter ``name``: a refusal is a
    :class:`ParameterError` naming the parameter, so that a front end names its own flag.

    Parameters
    ----------
    check : callable
        A validator of this module (:func:`positive`, :func:`depth_metres`, ...).
    name : str
        The parameter's name (``depth``), a ``{name}`` placeholder in the message.
    value : object

    Returns
    -------
    float
        What ``check`` returns.

    Examples
    --------
    >>> try:
    ...     check_parameter(positive, "depth", -1)
    ... except ParameterError as error:
    ...     print(error, "|", error.rephrase({"depth": "--depth"}))
    depth must be a finite number > 0, got -1.0 | --depth must be a finite number > 0, got -1.0
    """
    try:
        return check(f"{{{name}}}", value)
    except ParameterError:
        raise
    except ValueError as exc:
        raise ParameterError(str(exc), **{name: name}) from None
