"""Filling methods: a sparse depth map and the standard frame in, a dense depth map out.

A filling method is a function ``method(frame, sparse, camera, params) -> dense`` or
``-> (dense, confidence)``:

- ``frame``: (H, W) uint8 gray standard frame;
- ``sparse``: (H, W) float32 depth in metres of the map points projected into the frame, 0 where
  there is none;
- ``camera``: the frame's :class:`sim.camera.Camera`;
- ``params``: a dict of method-specific settings (``{}`` for the defaults); a built-in declares
  them as a frozen dataclass (:attr:`FillMethod.params`, listed by ``evfuse methods --params``)
  and :func:`check_params` checks a dict against it, coercing each value to its field's type;
- ``dense``: (H, W) float depth in metres, 0 where the method gives none;
- ``confidence`` (optional): (H, W) float in [0, 1], how much the method trusts each pixel.

Built-in methods register under a name (:func:`available_methods` lists them, ``evfuse methods``
prints them). A user's method is given as ``module:function`` (imported from the current
folder, as ``python -m`` does, or from ``sys.path``) or installed under the Python entry-point
group ``evfuse.fill_methods``. :func:`run_method` calls any of them and refuses, in one line
naming the method, an output of the wrong shape, a non-finite or negative depth, or an
exception. A :class:`MethodVariant` is a method with settings of its own, labelled
``NAME{KEY=VALUE,...}`` (:func:`method_label`): what ``evfuse bench`` and ``evfuse reproduce``
run, the same method possibly under several settings.

Built-ins, each with its own analytic test (``tests/test_methods.py``):

- ``paper-idw``, ``paper-gaussian``, ``paper-exponential``: the paper's method (region growing,
  region selection, weighted mean of the region's map depths), one per weighting; IDW is the
  default of ``evfuse fill``.
- ``nearest``: every pixel takes the depth of its nearest map point (Euclidean), as MC-EMVS's
  densification does; fills the whole frame.
- ``telea``: OpenCV's fast-marching inpainting (Telea 2004) of the depth image, radius 5 px,
  on 16-bit depth (:data:`TELEA_LEVELS`).
- ``morphological``: an unguided morphological fill in the manner of IP-Basic (Ku et al. 2018):
  inverted depth (so that the nearer surface wins where two meet), dilation with a 5x5 diamond,
  closing, hole filling with growing kernels, median and Gaussian smoothing, un-inverted.
- ``guided``, ``bilateral``, ``colorization``, ``fbs`` (:mod:`fusion.baselines`): image-guided
  completion by He et al.'s guided filter, a joint-bilateral normalised convolution, Levin
  et al.'s colorization in inverse depth, and Barron & Poole's fast bilateral solver in inverse
  depth.
- ``plane``, ``hybrid`` (:mod:`fusion.surface_fit`): a robust per-region surface fit in inverse
  depth that leaves regions it cannot explain empty, and the same after cutting rejected
  regions along the frame's edges.
- ``mesh`` (:mod:`fusion.mesh_fill`): ``plane``'s fits, then a Delaunay mesh of the cleaned map
  across triangles whose corners lie on one surface, then the paper's fill in the paper's
  regions.
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
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass
from importlib import metadata
from pathlib import Path

import cv2
import numpy as np

from fusion.filling import FillParams
from sim.camera import Camera

__all__ = ["ENTRY_POINT_GROUP", "FillMethod", "MethodError", "MethodVariant",
           "PaperExponentialParams", "PaperGaussianParams", "TeleaParams", "available_methods",
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


# ------------------------------------------------------------------------------------------------
# Built-in methods
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _NoParams:
    """The settings of a method that takes none."""


@dataclass(frozen=True)
class PaperGaussianParams:
    """Settings of ``paper-gaussian``: the length of :class:`fusion.filling.FillParams`.

    Attributes
    ----------
    sigma : float, pixels
        Standard deviation of the Gaussian weights (default 5, the paper's).
    """

    sigma: float = FillParams.sigma

    def __post_init__(self) -> None:
        FillParams("gaussian", sigma=self.sigma)


@dataclass(frozen=True)
class PaperExponentialParams:
    """Settings of ``paper-exponential``: the length of :class:`fusion.filling.FillParams`.

    Attributes
    ----------
    scale : float, pixels
        Decay length, ``exp(-d / scale)`` (default 1, the paper's ``exp(-d)``).
    """

    scale: float = FillParams.scale

    def __post_init__(self) -> None:
        FillParams("exponential", scale=self.scale)


def _paper(weighting: str, params_class: type) -> Callable:
    def method(frame, sparse, camera, params):
        from fusion.dense import DenseParams, densify

        fill = FillParams(weighting, **asdict(params_class(**params)))
        return densify(frame, sparse, DenseParams(fill=fill))[2]

    method.__doc__ = f"The paper's method with {weighting} weights."
    return method


for _weighting, _summary, _params in (
        ("idw", "the paper's method: region growing, region selection, inverse distance weights",
         _NoParams),
        ("gaussian", "the paper's method with Gaussian weights (sigma 5 px)", PaperGaussianParams),
        ("exponential", "the paper's method with exp(-d) weights", PaperExponentialParams)):
    register(f"paper-{_weighting}", _summary, params=_params)(_paper(_weighting, _params))


@register("nearest", "every pixel takes the depth of its nearest map point (MC-EMVS's "
                     "densification); fills the whole frame", params=_NoParams)
def nearest(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict) -> np.ndarray:
    """The depth of the nearest map point (exact Euclidean distance in pixels) at every pixel."""
    from scipy.ndimage import distance_transform_edt

    points = sparse > 0
    if not points.any():
        return np.zeros_like(sparse)
    rows, cols = distance_transform_edt(~points, return_distances=False, return_indices=True)
    return sparse[rows, cols]


TELEA_LEVELS = 65535
"""Telea inpaints 16-bit depth: OpenCV's 32-bit float path overshoots (a constant 1.7 m came
back as -1.5 to 4.7 m), the 16-bit one does not. Depth is scaled so that the largest map depth
is 65535 levels; with Telea's own integer rounding a constant depth comes back within a few
levels, 5e-5 of it (tested)."""


@dataclass(frozen=True)
class TeleaParams:
    """Settings of ``telea``.

    Attributes
    ----------
    radius : float, pixels
        Radius of the neighbourhood each pixel is inpainted from (default 5).
    """

    radius: float = 5.0

    def __post_init__(self) -> None:
        if not (isinstance(self.radius, numbers.Real) and np.isfinite(self.radius)
                and self.radius > 0):
            raise ValueError(f"radius must be a finite number > 0 pixels, got {self.radius!r}")


@register("telea", "OpenCV's fast-marching inpainting (Telea 2004) of the depth image, "
                   "radius 5 px", params=TeleaParams)
def telea(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict) -> np.ndarray:
    """Inpaint every pixel without a map point from the map points around it (16-bit depth,
    see :data:`TELEA_LEVELS`); ``params`` are :class:`TeleaParams`' fields."""
    radius = float(TeleaParams(**params).radius)
    points = sparse > 0
    if not points.any():
        return np.zeros_like(sparse)
    top = float(sparse.max())
    levels = np.round(sparse / top * TELEA_LEVELS).astype(np.uint16)
    filled = cv2.inpaint(levels, (~points).astype(np.uint8), radius, cv2.INPAINT_TELEA)
    return (filled.astype(np.float32) * np.float32(top / TELEA_LEVELS)).astype(np.float32)


_DIAMOND_5 = np.array([[0, 0, 1, 0, 0], [0, 1, 1, 1, 0], [1, 1, 1, 1, 1], [0, 1, 1, 1, 0],
                       [0, 0, 1, 0, 0]], np.uint8)


@register("morphological", "unguided morphological fill in the manner of IP-Basic: inverted "
                           "depth dilated, closed, holes filled, smoothed", params=_NoParams)
def morphological(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict
                  ) -> np.ndarray:
    """IP-Basic's fast fill (Ku et al. 2018) on our depths.

    Depth is inverted as ``top - d`` with ``top`` 1.2 times the largest map depth (IP-Basic
    uses a fixed 100 m for KITTI), so that dilation, which keeps the largest value, keeps the
    *nearest* surface where two meet. Then: dilation with a 5x5 diamond, closing with a full
    5x5 kernel, empty pixels filled from a 7x7 dilation, then from a 31x31 one, a 5x5 median
    and a 5x5 Gaussian blur over the filled pixels, and the inversion undone.
    """
    points = sparse > 0
    if not points.any():
        return np.zeros_like(sparse)
    top = np.float32(1.2 * float(sparse.max()))
    depth = np.where(points, top - sparse, 0).astype(np.float32)
    depth = cv2.dilate(depth, _DIAMOND_5)
    depth = cv2.morphologyEx(depth, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    for size in (7, 31):
        grown = cv2.dilate(depth, np.ones((size, size), np.uint8))
        depth = np.where(depth > 0.1 * top, depth, grown)
    valid = depth > 0.1 * top
    blurred = cv2.medianBlur(depth, 5)
    depth = np.where(valid, blurred, depth)
    blurred = cv2.GaussianBlur(depth, (5, 5), 0)
    depth = np.where(valid, blurred, depth)
    return np.where(depth > 0.1 * top, top - depth, 0).astype(np.float32)


# Methods defined in their own modules register on import (at the end: they use register).
import fusion.baselines  # noqa: E402,F401  (registers guided, bilateral, colorization, fbs)
import fusion.mesh_fill  # noqa: E402,F401  (registers mesh)
import fusion.surface_fit  # noqa: E402,F401  (registers plane and hybrid)
