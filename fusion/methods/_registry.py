"""The registry of filling methods and its machinery (see :mod:`fusion.methods`).

:func:`register`, :class:`FillMethod`, the settings checks, the ``NAME{KEY=VALUE}`` label
grammar, method lookup (built-in, ``module:function``, entry point) and :func:`run_method`.
Everything here is re-exported by :mod:`fusion.methods`, which is the public path.

It imports no method module, so the modules that define methods (:mod:`fusion.methods.baselines`,
:mod:`fusion.methods.surface_fit`, :mod:`fusion.methods.mesh`, and :mod:`fusion.methods` itself)
and the
code that runs them (:mod:`fusion.fill.dense`) import it without an import loop; a method module
registers on import, and :mod:`fusion.methods` imports them all, so that the built-ins are
registered once ``fusion.methods`` (or ``fusion``) is imported.
"""

from __future__ import annotations

import ast
import importlib
import math
import numbers
import os
import sys
import time
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from sim.camera import Camera

__all__ = ["ENTRY_POINT_GROUP", "FillMethod", "MethodError", "MethodVariant", "available_methods",
           "check_params", "coerce_params", "format_value", "get_method", "method_label",
           "param_defaults", "parse_label", "parse_value", "register", "run_method",
           "split_labels"]


ENTRY_POINT_GROUP = "evfuse.fill_methods"
"""The entry-point group under which installed packages offer filling methods."""


class MethodError(ValueError):
    """A filling method failed or returned something that is not a dense depth map."""


@dataclass(frozen=True)
class FillMethod:
    """A named filling method.

    Attributes
    ----------
    name : str
        What it is called by (``evfuse fill --method NAME``).
    summary : str
        One line saying what it does.
    function : callable
        ``function(frame, sparse, camera, params) -> dense | (dense, confidence)``.
    origin : str
        ``built-in``, ``module:function`` or ``entry point <distribution>``.
    params : type or None
        The frozen dataclass of the method's settings: one field per key its ``params`` dict
        takes, with its type and default; constructing it checks the values (a dataclass
        without fields: the method takes none). None: not declared (a user's method), any
        dict is passed on unchecked.
    """

    name: str
    summary: str
    function: Callable
    origin: str = "built-in"
    params: type | None = None


_BUILT_IN: dict[str, FillMethod] = {}


def register(name: str, summary: str, params: type | None = None
             ) -> Callable[[Callable], Callable]:
    """Register a built-in filling method under ``name`` (a decorator); ``params`` is the
    frozen dataclass of its settings (:attr:`FillMethod.params`)."""
    if params is not None and not (isinstance(params, type) and is_dataclass(params)):
        raise ValueError(f"filling method {name}: params must be a dataclass, got {params!r}")

    def decorate(function: Callable) -> Callable:
        if name in _BUILT_IN:
            raise ValueError(f"a filling method named {name!r} is already registered")
        _BUILT_IN[name] = FillMethod(name, summary, function, params=params)
        return function

    return decorate


# ------------------------------------------------------------------------------------------------
# Settings of a method
# ------------------------------------------------------------------------------------------------


def param_defaults(method: FillMethod) -> dict | None:
    """The settings ``method`` declares, each with its default (in its dataclass's field
    order); ``{}`` for a method that takes none, None where it declares nothing."""
    if method.params is None:
        return None
    return {f.name: (f.default if f.default is not MISSING else f.default_factory())
            for f in fields(method.params)}


def coerce_params(method: FillMethod | str, params: Mapping | None) -> dict:
    """``params`` with each key checked against the settings ``method`` declares and each value
    coerced to its field's type (an integer for a float field becomes a float); the values
    themselves are checked by :func:`check_params`.

    Parameters
    ----------
    method : FillMethod or str
        A method or its spec (:func:`get_method`).
    params : mapping or None
        Setting name -> value. For a method that declares no settings
        (``FillMethod.params`` None), returned as a dict unchecked (but for non-finite
        numbers, refused for every method).

    Returns
    -------
    dict
        The settings given (not the defaults of the others), coerced.

    Raises
    ------
    MethodError
        One line naming the method and the key: unknown (with the keys expected), a value of
        the wrong type (with the type expected) or a number that is not finite.
    """
    method = get_method(method) if isinstance(method, str) else method
    params = dict(params or {})
    for key, value in params.items():             # no setting takes one, declared or not
        if isinstance(value, numbers.Real) and not isinstance(value, bool) \
                and not math.isfinite(value):
            raise MethodError(f"filling method {method.name}: {key} expects a finite number, "
                              f"got {value}")
    if method.params is None:
        return params
    declared = [f.name for f in fields(method.params)]
    for key in params:
        if key not in declared:
            expected = (f"expected one of {', '.join(declared)}" if declared
                        else f"{method.name} takes no parameters")
            raise MethodError(f"filling method {method.name}: unknown parameter {key!r}; "
                              f"{expected}")
    hints = typing.get_type_hints(method.params)
    return {key: _coerced(method.name, key, value, hints.get(key, typing.Any))
            for key, value in params.items()}


def check_params(method: FillMethod | str, params: Mapping | None) -> dict:
    """:func:`coerce_params`, then the method's dataclass built from them, which checks the
    values (ranges, and the settings against each other).

    Returns
    -------
    dict
        The settings given, coerced.

    Raises
    ------
    MethodError
        One line naming the method: what :func:`coerce_params` refuses, or the reason the
        dataclass gives.
    """
    method = get_method(method) if isinstance(method, str) else method
    coerced = coerce_params(method, params)
    if method.params is not None:
        try:
            method.params(**coerced)
        except (TypeError, ValueError) as exc:
            raise MethodError(f"filling method {method.name}: {exc}") from None
    return coerced


_KINDS = {bool: "true or false", int: "an integer", float: "a number", str: "a string",
          type(None): "none"}


def _coerced(method: str, key: str, value, kind):
    """``value`` as the type ``kind`` (a field's type hint), or a MethodError saying which
    type was expected. Types other than bool, int, float, str and None are not checked."""
    options = (typing.get_args(kind) if typing.get_origin(kind) in (typing.Union, types.UnionType)
               else (kind,))
    if any(option not in _KINDS for option in options):
        return value
    number = isinstance(value, numbers.Real) and not isinstance(value, bool)
    for option in options:
        if option is type(None) and value is None:
            return None
        if option is bool and isinstance(value, bool | np.bool_):
            return bool(value)
        if option is int and number and isinstance(value, numbers.Integral):
            return int(value)
        if option is float and number:
            return float(value)
        if option is str and isinstance(value, str):
            return value
    expected = " or ".join(_KINDS[option] for option in options)
    raise MethodError(f"filling method {method}: {key} expects {expected}, got "
                      f"{format_value(value)}")


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


def parse_label(text: str) -> MethodVariant:
    """A variant from its label, ``NAME`` or ``NAME{KEY=VALUE,...}`` (:func:`method_label`),
    values read by :func:`parse_value`; the settings are not checked (:func:`check_params`).

    Raises
    ------
    MethodError
        Braces that do not close the text, an item without ``=`` or a key that is not a name,
        a key given twice; one line naming the label and what was expected.
    """
    text = text.strip()
    if "{" not in text and "}" not in text:
        return MethodVariant(text)
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
    return MethodVariant(name.strip(), params)


def method_label(name: str, params: Mapping | None = None) -> str:
    """``name``, or ``name{key=value,...}`` with the settings in key order: how a method's
    variant is shown in tables, and what ``--method`` takes back."""
    if not params:
        return name
    items = (f"{key}={format_value(params[key])}" for key in sorted(params))
    return name + "{" + ",".join(items) + "}"


@dataclass(frozen=True)
class MethodVariant:
    """A filling method with settings of its own: what a label ``NAME{KEY=VALUE,...}`` names,
    a row of ``evfuse bench``; one method may appear as several variants.

    Attributes
    ----------
    spec : str
        The method (:func:`get_method`).
    params : dict
        Its settings (:func:`check_params`); ``{}`` for its defaults.
    """

    spec: str
    params: dict = field(default_factory=dict)

    @classmethod
    def of(cls, method: str | MethodVariant) -> MethodVariant:
        """A variant as given, or read from its label (:func:`parse_label`: a spec alone is
        the method with its defaults)."""
        return method if isinstance(method, MethodVariant) else parse_label(method)

    @property
    def label(self) -> str:
        """``spec`` or ``spec{key=value,...}`` (:func:`method_label`)."""
        return method_label(self.spec, self.params)

    def checked(self) -> MethodVariant:
        """The same variant with its settings checked and coerced (:func:`check_params`); a
        MethodError for an unknown method or a bad setting."""
        return MethodVariant(self.spec, check_params(get_method(self.spec), self.params))


def _entry_points() -> dict[str, FillMethod]:
    found = {}
    for point in metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(point.dist, "name", None) or "unknown"
        found[point.name] = FillMethod(point.name, f"{point.value} (from {dist})", point.load,
                                       f"entry point {dist}")
    return found


def available_methods() -> dict[str, FillMethod]:
    """The built-in methods, then those installed under :data:`ENTRY_POINT_GROUP`.

    An installed method is loaded when it is run (its ``function`` is the entry point's
    loader until :func:`get_method` resolves it).
    """
    methods = dict(_BUILT_IN)
    for name, method in _entry_points().items():
        methods.setdefault(name, method)
    return methods


def _current_folder_on_path() -> None:
    """Put the current folder first on ``sys.path``, as ``python -m`` does, so that a user's
    ``module:function`` in the folder they run evfuse from imports (the ``evfuse`` script's own
    ``sys.path`` starts with its ``bin/`` folder instead)."""
    here = os.path.realpath(os.getcwd())
    if not any(os.path.realpath(entry or os.curdir) == here for entry in sys.path):
        sys.path.insert(0, here)
        importlib.invalidate_caches()


def get_method(spec: str) -> FillMethod:
    """The filling method named ``spec``: a built-in name, an installed entry point's name, or
    ``module:function``.

    Raises
    ------
    MethodError
        One line naming ``spec`` and what was expected.
    """
    if not isinstance(spec, str) or not spec:
        raise MethodError(f"filling method {spec!r}: expected a name or module:function")
    if spec in _BUILT_IN:
        return _BUILT_IN[spec]
    if ":" in spec:
        module_name, _, attribute = spec.partition(":")
        _current_folder_on_path()
        try:
            module = importlib.import_module(module_name)
        except Exception as exc:                       # any import failure, said in one line
            raise MethodError(f"filling method {spec}: cannot import module {module_name!r} "
                              f"({type(exc).__name__}: {exc}; looked in the current folder "
                              f"{Path.cwd()} and on PYTHONPATH)") from None
        function = getattr(module, attribute, None)
        if not callable(function):
            raise MethodError(f"filling method {spec}: module {module_name!r} has no function "
                              f"{attribute!r}")
        summary = (function.__doc__ or "").strip().splitlines()[0] if function.__doc__ else spec
        return FillMethod(spec, summary, function, "module:function")
    installed = _entry_points()
    if spec in installed:
        entry = installed[spec]
        try:
            function = entry.function()
        except Exception as exc:
            raise MethodError(f"filling method {spec}: its entry point cannot be loaded "
                              f"({type(exc).__name__}: {exc})") from None
        return FillMethod(spec, entry.summary, function, entry.origin)
    names = ", ".join(sorted(available_methods()))
    raise MethodError(f"unknown filling method {spec!r}; expected one of {names}, or "
                      "module:function")


def run_method(method: FillMethod | str, frame: np.ndarray, sparse: np.ndarray, camera: Camera,
               params: dict | None = None) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Run a filling method and check what it returns.

    Parameters
    ----------
    method : FillMethod or str
        A method or its spec (see :func:`get_method`).
    frame : (H, W) uint8 ndarray
    sparse : (H, W) float ndarray, metres, 0 = no map point
    camera : Camera
        The frame's calibration (H, W must match).
    params : dict, optional
        Method-specific settings (passed as given; :func:`check_params` checks them).

    Returns
    -------
    dense : (H, W) float32 ndarray, metres, 0 = none
    confidence : (H, W) float32 ndarray in [0, 1], or None
    seconds : float
        The method's own run time.

    Raises
    ------
    MethodError
        The method raised, or returned the wrong shape, a non-finite or negative depth, or a
        confidence outside [0, 1]; one line naming the method.
    """
    method = get_method(method) if isinstance(method, str) else method
    frame = np.asarray(frame)
    sparse = np.asarray(sparse, dtype=np.float32)
    shape = (camera.height, camera.width)
    if frame.shape != shape or sparse.shape != shape or frame.dtype != np.uint8:
        raise MethodError(f"filling method {method.name}: expected a uint8 frame and a sparse "
                          f"depth of the camera's {shape[1]}x{shape[0]}, got {frame.dtype} "
                          f"{frame.shape} and {sparse.shape}")
    tick = time.perf_counter()
    try:
        output = method.function(frame, sparse, camera, dict(params or {}))
    except Exception as exc:
        raise MethodError(f"filling method {method.name} raised {type(exc).__name__}: "
                          f"{exc}") from None
    seconds = time.perf_counter() - tick
    confidence = None
    if isinstance(output, tuple):
        if len(output) != 2:
            raise MethodError(f"filling method {method.name} returned a tuple of {len(output)}; "
                              "expected dense or (dense, confidence)")
        output, confidence = output
    dense = _checked(method.name, "dense depth", output, shape)
    if np.any(dense < 0):
        raise MethodError(f"filling method {method.name} returned negative depths (down to "
                          f"{float(dense.min()):g} m); expected metres >= 0, 0 = none")
    if confidence is not None:
        confidence = _checked(method.name, "confidence", confidence, shape)
        if np.any((confidence < 0) | (confidence > 1)):
            raise MethodError(f"filling method {method.name} returned a confidence outside "
                              "[0, 1]")
    return dense, confidence, seconds


def _checked(name: str, what: str, value, shape: tuple[int, int]) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float32)
    except (TypeError, ValueError):
        raise MethodError(f"filling method {name} returned a {what} that is not an array "
                          f"({type(value).__name__})") from None
    if array.shape != shape:
        raise MethodError(f"filling method {name} returned a {what} of shape {array.shape}; "
                          f"expected the frame's {shape}")
    if not np.all(np.isfinite(array)):
        raise MethodError(f"filling method {name} returned a {what} with NaN or infinite "
                          "values; expected finite numbers (0 = none)")
    return array
