"""The paper's fill completed by colorization: the ``paper-colorization`` method.

The paper fills only the regions its map bounds (a region whose 3-pixel ring holds map points
on 30 % of its contour and whose inside holds under 5 % of its area); the rest of the frame stays
empty. On a textured surface region growing (threshold 3) breaks the frame into thousands of
small regions that no map bounds: on ``slider_close`` the paper's fill leaves 39-44 % of each
240x180 key view empty, and a global map of such views cannot cover the scene (the views' plain
union reaches 70 % recall at 1 % of depth, measured with ``benchmarks/bench_global.py
--goals``' first window).

``paper-colorization`` runs the paper's three stages (:class:`fusion.methods.paper.PaperMethod`
with inverse distance weights and every stage parameter of the paper's, so ``--threshold``,
``--ring`` and the rest apply), then fills each pixel they left empty by Levin et al.'s
colorization of inverse depth (:func:`fusion.methods.baselines.colorization_completion`, its
default settings) with every pixel the paper filled, map points included, as a known value. A
pixel the paper filled keeps the paper's depth exactly; a pixel it left empty takes the
weighted mean, in inverse depth, of its 3x3 neighbours, weighted by their grey-level affinity,
solved jointly over the empty pixels. Where the paper filled nothing and the frame has no map
point, nothing is filled.

*Bound:* colorization's weights at a pixel sum to 1, so the completed inverse depth is a
convex combination of known values: every completed depth lies within the range of the paper's
depths (tested), and a surface at one depth is completed at that depth exactly (to rounding).

*Fails* as colorization does: across an edge of the frame that does not separate two
surfaces the depth leaks, and a region the paper filled with a wrong depth (the mean of two
surfaces' points) spreads its error to the empty pixels beside it.

It is :func:`fusion.globalmap.pipeline.map_global`'s default fill (issue 40): measured with
``benchmarks/bench_global.py --goals`` (``--method`` paper-idw against the default), the
fused filled map of slider_close 0-1 s goes from F 0.774 to 0.906 at 1 % of depth (precision
0.936 to 0.943), and boxes_6dof 3.5-5.5 s keeps its TSDF above its fused points (F at 5 cm
0.419 against 0.359).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from fusion.fill.records import DenseParams
from fusion.methods._registry import Filled, NoParams, add_built_in
from fusion.methods.baselines import colorization_completion
from fusion.methods.paper import PaperMethod, _paper_function
from sim.camera import Camera

__all__ = ["CompletedPaperMethod", "complete_by_colorization"]


def complete_by_colorization(frame: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """Fill the pixels a fill left empty by colorization, keeping the others as they are.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray
        The gray frame the fill used.
    filled : (H, W) float32 ndarray, metres, 0 = empty
        A fill's dense depth, map points included.

    Returns
    -------
    (H, W) float32 ndarray, metres
        ``filled`` where it is > 0; elsewhere the colorization of its inverse depth
        (:func:`fusion.methods.baselines.colorization_completion`); all 0 where ``filled`` is.
    """
    filled = np.asarray(filled, dtype=np.float32)
    if not (filled > 0).any():
        return np.zeros(filled.shape, np.float32)
    completed = colorization_completion(frame, filled)
    return np.where(filled > 0, filled, completed).astype(np.float32)


@dataclass(frozen=True)
class CompletedPaperMethod(PaperMethod):
    """The paper's method (inverse distance weights), then :func:`complete_by_colorization`.

    It keeps the paper's segmentation for the figures and ``segments.png``; ``filled_mask.png``
    then holds every pixel with a depth.
    """

    def fill(self, frame: np.ndarray, sparse: np.ndarray, camera: Camera, settings: dict,
             params: DenseParams) -> Filled:
        """The paper's three stages (:meth:`PaperMethod.fill`), then the completion, timed as
        ``timings["completion_s"]``."""
        paper = super().fill(frame, sparse, camera, settings, params)
        tick = time.perf_counter()
        dense = complete_by_colorization(frame, paper.dense)
        return Filled(dense, None, paper.labels, paper.regions,
                      {**paper.timings, "completion_s": time.perf_counter() - tick})


_paper_idw = _paper_function("idw", NoParams)


def _completed_paper(frame: np.ndarray, sparse: np.ndarray, camera: Camera,
                     params: dict) -> np.ndarray:
    """``paper-colorization`` as a plain function (:func:`fusion.methods.run_method`, ``evfuse
    bench``): ``paper-idw``'s (the paper's stages with their defaults), then the completion."""
    return complete_by_colorization(frame, _paper_idw(frame, sparse, camera, params))


add_built_in(CompletedPaperMethod(
    "paper-colorization", "the paper's method (inverse distance weights), then Levin et al.'s "
    "colorization of inverse depth from its depths into the pixels it left empty",
    _completed_paper, params=NoParams, weighting="idw"))
