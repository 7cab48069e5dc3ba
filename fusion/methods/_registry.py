"""The registry of filling methods and its machinery (see :mod:`fusion.methods`).

:func:`register`, :class:`FillMethod` (what the fill stage calls: :meth:`FillMethod.fill`,
:meth:`FillMethod.stage_params`), the settings checks, :class:`MethodVariant`, method lookup
(built-in, ``module:function``, entry point) and :func:`run_method`. The label grammar is
:mod:`fusion.methods._labels`. Everything here is re-exported by :mod:`fusion.methods`, which is
the public path.

It imports no method module and not the fill stage (the stage's parameters come from
:mod:`fusion.fill.records`, below it), so the modules that define methods
(:mod:`fusion.methods.classic`, :mod:`fusion.methods.paper`, :mod:`fusion.methods.baselines`,
:mod:`fusion.methods.surface_fit`, :mod:`fusion.methods.mesh`) and the code that runs them
(:mod:`fusion.fill.dense`) import it without an import loop; a method module registers on
import, and :mod:`fusion.methods` imports them all, so that the built-ins are registered once
``fusion.methods`` (or ``fusion``) is imported.
"""

from __future__ import annotations

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

from fusion.fill.filling import RegionStats
from fusion.fill.records import DenseParams
from fusion.methods._errors import MethodError
from fusion.methods._labels import format_value, label_parts, method_label
from sim._summary import summary_repr
from sim.camera import Camera
from sim.validation import ParameterError

__all__ = ["ENTRY_POINT_GROUP", "FillMethod", "Filled", "MethodError", "MethodVariant", "NoParams",
           "ResolvedMethod",
           "available_methods", "check_event_image", "check_params", "coerce_params",
           "add_built_in", "get_method", "param_defaults", "parse_label", "register",
           "run_method"]


ENTRY_POINT_GROUP = "evfuse.fill_methods"
"""The entry-point group under which installed packages offer filling methods."""


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

    def fill(self, frame: np.ndarray, sparse: np.ndarray, camera: Camera, settings: dict,
             params: DenseParams) -> Filled:
        """Fill one frame, as the fill stage (:func:`fusion.fill.dense.fill_frame`) calls it.

        This one checks the event image (:func:`check_event_image`) and runs :attr:`function`
        through :func:`run_method`: no segmentation (all-zero labels, ``regions`` None), its
        run time as ``timings["method_s"]``. A method that runs stages of its own (the
        paper's, :mod:`fusion.methods.paper`) overrides it.

        Parameters
        ----------
        frame : (H, W) uint8 ndarray
        sparse : (H, W) float32 ndarray, metres, 0 = no map point
        camera : Camera, the frame's
        settings : dict, the method's own settings, checked (:func:`check_params`)
        params : DenseParams, the fill stage's parameters (:meth:`stage_params`)

        Returns
        -------
        Filled
        """
        check_event_image(frame, sparse)
        dense, confidence, seconds = run_method(self, frame, sparse, camera, settings)
        return Filled(dense, confidence, np.zeros(sparse.shape, np.int32), None,
                      {"method_s": seconds})

    def stage_params(self, params: DenseParams | None, settings: dict) -> DenseParams | None:
        """The fill stage's parameters that go with this method under ``settings``: here
        ``params`` as given (a method that runs no stage of the paper's uses only its
        ``band``; None: the defaults)."""
        return params

    def requested_stages(self, stages: DenseParams, weighting: str | None, settings: dict,
                         spec: str) -> DenseParams:
        """The fill stage's parameters of a request that sets them one by one (``evfuse fill``
        and ``run``, :func:`fusion.methods.fill_request`), refused where they contradict this
        method: here any stage parameter off its default, and any ``weighting`` (this method
        runs none of the paper's stages).

        Parameters
        ----------
        stages : DenseParams
            The stage parameters as requested (``fill.weighting``: ``weighting`` or ``idw``).
        weighting : str or None
            The weighting requested, None where none was.
        settings : dict
            The method's own settings, checked.
        spec : str
            The method as it was asked for (a label), for the messages.

        Raises
        ------
        sim.validation.ParameterError
            The first parameter set, named as ``{name}`` with its value, and the methods that
            use it.
        """
        defaults = type(stages)()
        given = [("weighting", weighting, None)]
        for group in ("segmentation", "selection", "fill"):
            given += [(f.name, getattr(getattr(stages, group), f.name),
                       getattr(getattr(defaults, group), f.name))
                      for f in fields(getattr(stages, group)) if f.name != "weighting"]
        for name, value, default in given:
            if value != default:
                value = f"{value:g}" if isinstance(value, float) else value      # as typed
                users = ", ".join(m.name for m in _BUILT_IN.values()
                                  if type(m).requested_stages is not FillMethod.requested_stages)
                raise ParameterError(
                    f"{{method}} {ParameterError.literal(spec)} and {{{name}}} "
                    f"{ParameterError.literal(value)} contradict each other: only the paper's "
                    f"methods ({users}) use {{{name}}} (drop it, or give one of them)",
                    method="method", **{name: name})
        return stages

    def progress_units(self) -> tuple[str, str]:
        """What the fill stage's progress counts: its unit and the noun of its total."""
        return "px", f"pixels filled by {self.name}"


@dataclass(frozen=True)
class Filled:
    """What a method gave for one frame (:meth:`FillMethod.fill`).

    Attributes
    ----------
    dense : (H, W) float32 ndarray, metres, 0 = none
    confidence : (H, W) float32 ndarray in [0, 1], or None
    labels : (H, W) int32 ndarray, regions 1..K, 0 = too small; all 0 for a method that does not
        segment the frame
    regions : RegionStats or None, None for a method that does not segment the frame
    timings : dict, seconds per step
    """

    __repr__ = summary_repr

    dense: np.ndarray
    confidence: np.ndarray | None
    labels: np.ndarray
    regions: RegionStats | None
    timings: dict


@dataclass(frozen=True)
class ResolvedMethod:
    """A filling method resolved once, with what it runs under: what the fill stage is handed
    (:func:`resolve_method`, :func:`fusion.methods.fill_request`).

    Attributes
    ----------
    method : FillMethod
        The method (:func:`fusion.methods.get_method`).
    settings : dict
        Its own settings, checked and coerced (:func:`fusion.methods.check_params`).
    params : DenseParams
        The fill stage's parameters that go with it
        (:meth:`fusion.methods.FillMethod.stage_params`).
    """

    method: FillMethod
    settings: dict
    params: DenseParams


def check_event_image(frame: np.ndarray, sparse: np.ndarray) -> None:
    """Refuse, in one line, an event image that is not finite metres >= 0 with a map point in
    the frame's size (what :func:`fusion.fill.dense.densify` refuses for the paper's method)."""
    if np.shape(frame) != sparse.shape:
        raise ValueError(f"the frame is {np.shape(frame)[1]}x{np.shape(frame)[0]} but the sparse "
                         f"depth is {sparse.shape[1]}x{sparse.shape[0]}: they must be the same "
                         "size")
    bad = int(np.count_nonzero(~np.isfinite(sparse)))
    if bad:
        raise ValueError(f"the sparse depth must be finite metres (0 = no map point), found {bad} "
                         "NaN or infinite pixels")
    if np.any(sparse < 0):
        raise ValueError(f"the sparse depth must be >= 0 metres (0 = no map point), found "
                         f"{int(np.count_nonzero(sparse < 0))} negative pixels")
    if not np.any(sparse > 0):
        raise ValueError("no map points: the sparse depth has no pixel > 0, nothing to fill from")


_BUILT_IN: dict[str, FillMethod] = {}


@dataclass(frozen=True)
class NoParams:
    """The settings of a method that takes none (its :attr:`FillMethod.params`)."""


def register(name: str, summary: str, params: type | None = None
             ) -> Callable[[Callable], Callable]:
    """Register a built-in filling method under ``name`` (a decorator); ``params`` is the
    frozen dataclass of its settings (:attr:`FillMethod.params`)."""
    if params is not None and not (isinstance(params, type) and is_dataclass(params)):
        raise ValueError(f"filling method {name}: params must be a dataclass, got {params!r}")

    def decorate(function: Callable) -> Callable:
        add_built_in(FillMethod(name, summary, function, params=params))
        return function

    return decorate


def add_built_in(method: FillMethod) -> FillMethod:
    """Register ``method`` as it is (a :class:`FillMethod` of a subclass of its own, e.g. the
    paper's, :mod:`fusion.methods.paper`); :func:`register` for a plain function."""
    if method.name in _BUILT_IN:
        raise ValueError(f"a filling method named {method.name!r} is already registered")
    _BUILT_IN[method.name] = method
    return method


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


def parse_label(text: str) -> MethodVariant:
    """A variant from its label, ``NAME`` or ``NAME{KEY=VALUE,...}`` (:func:`method_label`),
    read by :func:`fusion.methods._labels.label_parts`; the settings are not checked
    (:func:`check_params`).

    Raises
    ------
    MethodError
        Braces that do not close the text, an item without ``=`` or a key that is not a name,
        a key given twice; one line naming the label and what was expected.
    """
    return MethodVariant(*label_parts(text))


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
