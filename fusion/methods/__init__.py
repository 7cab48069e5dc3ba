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

Methods asked for as text (``evfuse ... --method LABEL --param [METHOD.]KEY=VALUE``) become
checked variants through :func:`method_variants`, and the one method of a fill, with the fill
stage's parameters, a :class:`fusion.methods.ResolvedMethod` through :func:`fill_request`:
a method is resolved once, where it is asked for, and the fill stage calls the object it is
handed (:meth:`FillMethod.fill`).

The package's modules:

- ``_errors``: :class:`MethodError`;
- ``_labels``: the label grammar (``NAME{KEY=VALUE,...}``, a setting's value as text);
- ``_registry``: :func:`register`, :class:`FillMethod`, the settings checks,
  :class:`MethodVariant`, method lookup and :func:`run_method`;
- ``_variants``: labels and ``--param`` settings into variants, the fill's method resolved;
- ``paper``, ``classic``, ``baselines``, ``surface_fit``, ``mesh``, ``completed``: the built-in
  methods, each module registering its own on import.

Built-ins, each with its own analytic test (``tests/test_methods.py``):

- ``paper-idw``, ``paper-gaussian``, ``paper-exponential`` (:mod:`fusion.methods.paper`): the
  paper's method (region growing, region selection, weighted mean of the region's map depths),
  one per weighting; IDW is the default of ``evfuse fill``.
- ``nearest`` (:mod:`fusion.methods.classic`, as the next two): every pixel takes the depth
  of its nearest map point (Euclidean), as MC-EMVS's densification does; fills the whole frame.
- ``telea``: OpenCV's fast-marching inpainting (Telea 2004) of the depth image, radius 5 px,
  on 16-bit depth (:data:`TELEA_LEVELS`).
- ``morphological``: an unguided morphological fill in the manner of IP-Basic (Ku et al. 2018):
  inverted depth (so that the nearer surface wins where two meet), dilation with a 5x5 diamond,
  closing, hole filling with growing kernels, median and Gaussian smoothing, un-inverted.
- ``guided``, ``bilateral``, ``colorization``, ``fbs`` (:mod:`fusion.methods.baselines`):
  image-guided completion by He et al.'s guided filter, a joint-bilateral normalised
  convolution, Levin et al.'s colorization in inverse depth, and Barron & Poole's fast bilateral
  solver in inverse depth.
- ``plane``, ``hybrid`` (:mod:`fusion.methods.surface_fit`): a robust per-region surface fit in
  inverse depth that leaves regions it cannot explain empty, and the same after cutting rejected
  regions along the frame's edges.
- ``mesh`` (:mod:`fusion.methods.mesh`): ``plane``'s fits, then a Delaunay mesh of the cleaned map
  across triangles whose corners lie on one surface, then the paper's fill in the paper's
  regions.
- ``paper-colorization`` (:mod:`fusion.methods.completed`): the paper's method, then Levin et
  al.'s colorization from its depths into the pixels it left empty (``evfuse map-global``'s
  default).
"""

from __future__ import annotations

from importlib import metadata  # noqa: F401  (kept on this path: tests patch its entry_points)

# The built-ins register on import, in the order available_methods() lists them: the paper's,
# the classic ones, then the other modules' (surface_fit's plane and hybrid before mesh).
# isort: off
import fusion.methods.paper  # noqa: F401  (registers paper-idw, paper-gaussian, paper-exponential)
import fusion.methods.classic  # noqa: F401  (registers nearest, telea, morphological)
import fusion.methods.baselines  # noqa: F401  (registers guided, bilateral, colorization, fbs)
import fusion.methods.surface_fit  # noqa: F401  (registers plane and hybrid)
import fusion.methods.mesh  # noqa: F401  (registers mesh)
import fusion.methods.completed  # noqa: F401  (registers paper-colorization)
# isort: on
from fusion.methods._errors import MethodError
from fusion.methods._labels import format_value, method_label, parse_value, split_labels
from fusion.methods._registry import (  # noqa: F401  (_BUILT_IN re-exported for tests)
    _BUILT_IN,
    ENTRY_POINT_GROUP,
    Filled,
    FillMethod,
    MethodVariant,
    ResolvedMethod,
    available_methods,
    check_params,
    coerce_params,
    get_method,
    param_defaults,
    parse_label,
    register,
    run_method,
)
from fusion.methods._variants import fill_request, method_variants, parse_param
from fusion.methods.classic import TELEA_LEVELS, TeleaParams
from fusion.methods.paper import PaperExponentialParams, PaperGaussianParams, PaperMethod

__all__ = ["ENTRY_POINT_GROUP", "TELEA_LEVELS", "FillMethod", "Filled", "MethodError",
           "MethodVariant", "PaperExponentialParams", "PaperGaussianParams", "PaperMethod",
           "ResolvedMethod", "TeleaParams", "available_methods", "check_params", "coerce_params",
           "fill_request", "format_value", "get_method", "method_label", "method_variants",
           "param_defaults", "parse_label", "parse_param", "parse_value", "register",
           "run_method", "split_labels"]
