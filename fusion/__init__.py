"""evfuse's fusion pipeline: consumers of sequence folders.

Stages, each a set of pure functions on arrays with a frozen dataclass of parameters:

* :mod:`fusion.emvs` -- the disparity space image and the semi-dense depth (EMVS),
* :mod:`fusion.segmentation` -- region growing on the standard frame,
* :mod:`fusion.filling` -- region selection, weighted filling and the filling score,
* :mod:`fusion.methods` -- filling methods by name (the paper's and baselines, or a user's),
* :mod:`fusion.scoring` -- errors against exact depth.

Wired together by :mod:`fusion.mapping` (``evfuse map``), :mod:`fusion.dense` (``evfuse fill``),
:mod:`fusion.pipeline` (``evfuse run``) and :mod:`fusion.reproduce` (``evfuse reproduce``); the
command line (:mod:`fusion.cli`) only parses arguments and calls these.
"""

from fusion.benchmark import BenchParams, bench, run_bench
from fusion.dense import (
    DenseParams,
    DenseResult,
    FillInputs,
    dense_errors,
    densify,
    fill_frame,
    fill_inputs,
    fill_map,
    project_map,
    write_fill,
)
from fusion.dsi_range import DSIRange, resolve_dsi_range
from fusion.emvs import (
    DepthMapParams,
    DSIParams,
    depth_planes,
    disparity_space_image,
    semidense_depth,
)
from fusion.filling import (
    FillParams,
    RegionStats,
    SelectionParams,
    exponential_weights,
    fill_regions,
    filling_score,
    gaussian_weights,
    inverse_distance_weights,
    select_regions,
)
from fusion.mapping import MapParams, MapResult, TimeWindow, map_sequence, time_window, write_map
from fusion.methods import (
    FillMethod,
    MethodError,
    MethodVariant,
    available_methods,
    check_params,
    get_method,
    run_method,
)
from fusion.pipeline import RunParams, draw_overview, fill_window, map_window, run_pipeline
from fusion.pointcloud import read_ply, write_ply
from fusion.reproduce import ReproduceParams, reproduce
from fusion.scoring import depth_errors, discontinuity_band, error_image
from fusion.segmentation import SegmentationParams, segment_regions

__all__ = [
    "BenchParams", "DSIParams", "DSIRange", "DenseParams", "DenseResult", "DepthMapParams",
    "FillInputs", "FillMethod", "FillParams", "MapParams", "MapResult", "MethodError",
    "MethodVariant", "RegionStats", "ReproduceParams", "RunParams", "SegmentationParams",
    "SelectionParams", "TimeWindow", "available_methods", "bench", "check_params",
    "dense_errors", "densify", "depth_errors",
    "depth_planes", "discontinuity_band", "disparity_space_image", "draw_overview",
    "error_image", "exponential_weights", "fill_frame", "fill_inputs", "fill_map",
    "fill_regions", "fill_window", "filling_score", "gaussian_weights", "get_method",
    "inverse_distance_weights", "map_sequence", "map_window", "project_map", "read_ply",
    "reproduce", "resolve_dsi_range", "run_bench", "run_method", "run_pipeline",
    "segment_regions", "select_regions", "semidense_depth", "time_window", "write_fill",
    "write_map", "write_ply",
]
