"""evfuse's fusion pipeline: consumers of sequence folders.

Stages, each a set of pure functions on arrays with a frozen dataclass of parameters:

* :mod:`fusion.map.emvs` -- the disparity space image and the semi-dense depth (EMVS),
* :mod:`fusion.fill.segmentation` -- region growing on the standard frame,
* :mod:`fusion.fill.filling` -- region selection, weighted filling and the filling score,
* :mod:`fusion.methods` -- filling methods by name (the paper's and baselines, or a user's),
* :mod:`fusion.scoring` -- errors against exact depth.

Wired together by :mod:`fusion.map.mapping` (``evfuse map``), :mod:`fusion.fill.dense`
(``evfuse fill``), :mod:`fusion.pipeline` (``evfuse run``) and :mod:`fusion.experiments.reproduce`
(``evfuse reproduce``); the command line (:mod:`fusion.cli`) only parses arguments and calls these.
"""

import sys

from fusion.experiments.bench import BenchParams, bench, run_bench
from fusion.experiments.reproduce import ReproduceParams, reproduce
from fusion.fill.dense import (
    DenseParams,
    DenseResult,
    FillInputs,
    densify,
    fill_frame,
    fill_inputs,
    fill_map,
    write_fill,
)
from fusion.fill.filling import (
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
from fusion.fill.projection import project_map
from fusion.fill.segmentation import SegmentationParams, segment_regions
from fusion.io import read_ply, write_ply
from fusion.map.dsi_range import DSIRange, resolve_dsi_range
from fusion.map.emvs import (
    DepthMapParams,
    DSIParams,
    depth_planes,
    disparity_space_image,
    semidense_depth,
)
from fusion.map.mapping import (
    MapParams,
    MapResult,
    TimeWindow,
    map_sequence,
    time_window,
    write_map,
)
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
from fusion.scoring import dense_errors, depth_errors, discontinuity_band, error_image
from sim._moved import alias_modules as _alias_modules

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

# Old module paths (before the subpackages of issue 22), kept importable: see sim._moved.
_alias_modules(sys.modules[__name__], {
    "fusion.emvs": "fusion.map.emvs",
    "fusion.dsi_range": "fusion.map.dsi_range",
    "fusion.mapping": "fusion.map.mapping",
    "fusion.segmentation": "fusion.fill.segmentation",
    "fusion.filling": "fusion.fill.filling",
    "fusion.frame_projection": "fusion.fill.projection",
    "fusion.dense": "fusion.fill.dense",
    "fusion.baselines": "fusion.methods.baselines",
    "fusion.mesh_fill": "fusion.methods.mesh",
    "fusion.surface_fit": "fusion.methods.surface_fit",
    "fusion.benchmark": "fusion.experiments.bench",
    "fusion.reproduce": "fusion.experiments.reproduce",
    "fusion.families": "sim.scene.families",
    "fusion.experiments.families": "sim.scene.families",   # issue 24: it writes scenes only
    "fusion.jsonio": "fusion.io",
    "fusion.pointcloud": "fusion.io",
})
