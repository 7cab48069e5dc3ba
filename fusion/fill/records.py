"""The fill stage's records: its parameters (:class:`DenseParams`), what it reads from a map
folder (:class:`FillInputs`) and what it returns (:class:`DenseResult`).

They live below the stage (:mod:`fusion.fill.dense`) because the modules the stage calls take
and return them too: the point cloud of a result (:func:`fusion.io.dense_cloud`), its figures
(:func:`fusion.figures.fill_figure`), the motion regions of its inputs
(:func:`fusion.scoring.frame_motion_regions`) and a filling method's stage parameters
(:meth:`fusion.methods.FillMethod.stage_params`). Here they import only the stages' own
parameters and the camera, so those modules import them without importing the stage. The stage
re-exports them (``from fusion.fill.dense import DenseParams`` works, as does ``from fusion
import DenseParams``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from fusion.fill.filling import FillParams, RegionStats, SelectionParams
from fusion.fill.segmentation import SegmentationParams
from sim._summary import summary_repr
from sim.camera import Camera
from sim.validation import integer

__all__ = ["DenseParams", "DenseResult", "FillInputs"]


@dataclass(frozen=True)
class DenseParams:
    """Parameters of ``evfuse fill`` (each stage's defaults are the paper's).

    Attributes
    ----------
    segmentation : SegmentationParams
        Region growing threshold (3 gray levels) and smallest region.
    selection : SelectionParams
        Ring width (3 px), ring ratio (30 %), inside ratio (5 %).
    fill : FillParams
        Weighting (inverse distance; Gaussian sigma 5, exponential).
    band : int, pixels
        Width of the band around true depth discontinuities scored apart (default 3).
    """

    segmentation: SegmentationParams = field(default_factory=SegmentationParams)
    selection: SelectionParams = field(default_factory=SelectionParams)
    fill: FillParams = field(default_factory=FillParams)
    band: int = 3

    def __post_init__(self) -> None:
        integer("band", self.band, 0)

    def as_dict(self) -> dict:
        """The parameters as plain JSON-ready values."""
        return {"segmentation": asdict(self.segmentation), "selection": asdict(self.selection),
                "fill": asdict(self.fill), "band": self.band}


@dataclass
class DenseResult:
    """A filled map in the pixels of a standard frame.

    Attributes
    ----------
    frame : (H, W) uint8 ndarray, the standard frame
    sparse : (H, W) float32 ndarray, metres, the event image (projected map points), 0 = none
    labels : (H, W) int32 ndarray, regions 1..K, 0 = too small; all 0 for a method that does
        not segment the frame (any but the paper's)
    regions : RegionStats or None
        None for a method that does not segment the frame.
    dense : (H, W) float32 ndarray, metres, map points and filled pixels, 0 = none (for a
        method other than the paper's, whatever it returned)
    camera : Camera, the frame's camera (with its distortion)
    T_world_frame : (4, 4) ndarray or None
    truth : (H, W) float32 ndarray or None, exact depth of the frame
    info : dict, method, method_origin, N1, N1_in_frame, N2, Res, beta, beta_counts,
        segmentation, regions, regions_filled, timings, frame, and ``errors`` with a truth
    method : str
        The filling method's name (``paper-idw``, ``nearest``, ``module:function``...).
    confidence : (H, W) float32 ndarray in [0, 1], or None
        The method's confidence in each pixel, where it returns one.
    """

    __repr__ = summary_repr
    _summary_counts = ("n1_in_frame", "n2")

    frame: np.ndarray
    sparse: np.ndarray
    labels: np.ndarray
    regions: RegionStats | None
    dense: np.ndarray
    camera: Camera
    T_world_frame: np.ndarray | None
    truth: np.ndarray | None
    info: dict
    method: str = "paper-idw"
    confidence: np.ndarray | None = None

    @property
    def n1_in_frame(self) -> int:
        """Map points that land in the frame (non-zero pixels of the event image)."""
        return int(np.count_nonzero(self.sparse))

    @property
    def n2(self) -> int:
        """Map points in the frame plus filled pixels (non-zero pixels of the dense map)."""
        return int(np.count_nonzero(self.dense))



@dataclass(frozen=True)
class FillInputs:
    """What filling a map needs: the standard frame nearest the map's reference view, the map
    projected into it, and the frame's pose and exact depth (see
    :func:`fusion.fill.dense.fill_inputs`).

    Attributes
    ----------
    frame : (H, W) uint8 ndarray
    sparse : (H, W) float32 ndarray, metres, the projected map points, 0 = none
    camera : Camera, the frame's
    T_world_frame : (4, 4) ndarray
    truth : (H, W) float32 ndarray or None, the frame's exact depth (simulated sequences)
    info : dict, the entries :func:`fusion.fill.dense.fill_map` writes into ``fill.json``
        (map, sequence, frame, times, pose, oracle, depth_range_from)
    n1 : int, the map's points before projection
    """

    __repr__ = summary_repr

    frame: np.ndarray
    sparse: np.ndarray
    camera: Camera
    T_world_frame: np.ndarray
    truth: np.ndarray | None
    info: dict
    n1: int
