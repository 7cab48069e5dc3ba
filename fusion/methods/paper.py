"""The paper's filling method, one registered method per weighting (see :mod:`fusion.methods`):
``paper-idw`` (inverse distance, the default of ``evfuse fill``), ``paper-gaussian`` and
``paper-exponential``.

It is a :class:`PaperMethod`, a :class:`fusion.methods.FillMethod` that runs the paper's three
stages (region growing, region selection, weighted filling; :func:`fusion.fill.dense.densify`)
and so keeps its segmentation for the figures and ``segments.png``; its
:meth:`~PaperMethod.stage_params` sets the stages' weighting and the weighting's length
(``sigma``, ``scale``, its own settings). Everything the fill stage does differently for the
paper's method is here: the fill stage only calls the method it was given.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

# The module, not its names: fusion.fill.dense imports the registry, which runs this package's
# __init__, which imports this module while fusion.fill.dense is still being imported.
from fusion.fill import dense as fill_stage
from fusion.fill.filling import FillParams
from fusion.fill.records import DenseParams
from fusion.methods._labels import method_label
from fusion.methods._registry import Filled, FillMethod, NoParams, add_built_in
from sim.camera import Camera
from sim.validation import ParameterError

__all__ = ["PaperExponentialParams", "PaperGaussianParams", "PaperMethod"]


@dataclass(frozen=True)
class PaperGaussianParams:
    """Settings of ``paper-gaussian``: the length of :class:`fusion.fill.filling.FillParams`.

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
    """Settings of ``paper-exponential``: the length of :class:`fusion.fill.filling.FillParams`.

    Attributes
    ----------
    scale : float, pixels
        Decay length, ``exp(-d / scale)`` (default 1, the paper's ``exp(-d)``).
    """

    scale: float = FillParams.scale

    def __post_init__(self) -> None:
        FillParams("exponential", scale=self.scale)


@dataclass(frozen=True)
class PaperMethod(FillMethod):
    """The paper's method with one weighting.

    Attributes
    ----------
    weighting : str
        ``idw``, ``gaussian`` or ``exponential`` (:class:`fusion.fill.filling.FillParams`).
    """

    weighting: str = "idw"

    def fill(self, frame: np.ndarray, sparse: np.ndarray, camera: Camera, settings: dict,
             params: DenseParams) -> Filled:
        """The three stages (:func:`fusion.fill.dense.densify`) under ``params`` (whose fill
        already holds ``settings``, :meth:`stage_params`): the segmentation kept, no
        confidence, the time of each stage."""
        labels, regions, dense, timings = fill_stage.densify(frame, sparse, params)
        return Filled(dense, None, labels, regions, timings)

    def stage_params(self, params: DenseParams | None, settings: dict) -> DenseParams:
        """``params`` (default: the paper's with this weighting) with ``settings`` (``sigma``,
        ``scale``) as their fill's.

        Raises
        ------
        ValueError
            ``params.fill.weighting`` that is not this method's.
        """
        if params is None:
            params = DenseParams(fill=FillParams(self.weighting))
        elif params.fill.weighting != self.weighting:
            raise ValueError(f"filling method {self.name} uses {self.weighting} weights but "
                             f"params.fill.weighting is {params.fill.weighting!r}: expected the "
                             "same weighting, or method None")
        return replace(params, fill=replace(params.fill, **settings))

    def requested_stages(self, stages: DenseParams, weighting: str | None, settings: dict,
                         spec: str) -> DenseParams:
        """The stages as requested, with this weighting and ``settings``; refused: another
        ``weighting``, or ``sigma`` / ``scale`` set both in ``stages`` (off its default) and
        in ``settings`` (see :meth:`fusion.methods.FillMethod.requested_stages`)."""
        if weighting not in (None, self.weighting):
            raise ParameterError(
                f"{{method}} {ParameterError.literal(spec)} and {{weighting}} "
                f"{ParameterError.literal(weighting)} contradict each other: "
                f"{ParameterError.literal(spec)} uses {self.weighting} weights (give {{method}} "
                f"paper-{ParameterError.literal(weighting)}, or drop {{weighting}})",
                method="method", weighting="weighting")
        for key in settings:
            value = getattr(stages.fill, key)
            if value != getattr(FillParams, key):
                raise ParameterError(
                    f"{{{key}}} {value:g} contradicts "
                    f"{ParameterError.literal(method_label(self.name, settings))}: set {key} "
                    f"once ({{{key}}} or {{param}} {key}=...)", param="param", **{key: key})
        fill = replace(stages.fill, weighting=self.weighting, **settings)
        return replace(stages, fill=fill)

    def progress_units(self) -> tuple[str, str]:
        """Regions: the paper's method fills region by region."""
        return "region", "regions filled"


def _paper_function(weighting: str, params_class: type):
    """The method as a plain function (:func:`fusion.methods.run_method`, ``evfuse bench``):
    the dense depth of the three stages with their defaults and this weighting."""
    def method(frame, sparse, camera, params):
        fill = FillParams(weighting, **asdict(params_class(**params)))
        return fill_stage.densify(frame, sparse, DenseParams(fill=fill))[2]

    method.__doc__ = f"The paper's method with {weighting} weights."
    return method


for _weighting, _summary, _params in (
        ("idw", "the paper's method: region growing, region selection, inverse distance weights",
         NoParams),
        ("gaussian", "the paper's method with Gaussian weights (sigma 5 px)", PaperGaussianParams),
        ("exponential", "the paper's method with exp(-d) weights", PaperExponentialParams)):
    add_built_in(PaperMethod(f"paper-{_weighting}", _summary, _paper_function(_weighting, _params),
                             params=_params, weighting=_weighting))
