"""One global map from many key views (issue 25).

* :mod:`fusion.globalmap.views` -- :class:`DepthView`: a depth image with its camera and world pose.
* :mod:`fusion.globalmap.fuse` -- multi-view consistency: agreement and contradiction counts,
  the fused point cloud (optionally with fused depths), the fused map in one reference view, and
  the agreement of overlapping views (no ground truth).
* :mod:`fusion.globalmap.tsdf` -- the truncated signed distance volume integrated from depth views
  (a numba kernel) and its marching-cubes mesh.
* :mod:`fusion.globalmap.score` -- scoring against the exact geometry (simulated sequences only):
  the key views' exact depth, the exact surface, accuracy / completeness / F-scores, the
  error-coloured cloud and the figure.
* :mod:`fusion.globalmap.keyviews` -- key views along a trajectory (EMVS's criteria: baseline,
  angle, event budget) and their event windows.
* :mod:`fusion.globalmap.neighbours` -- one reference view's map fused with its neighbours' maps
  (``evfuse run --views N``, ``evfuse reproduce --views N``).
* :mod:`fusion.globalmap.pipeline` -- ``evfuse map-global`` / ``evfuse run --global``: key views
  mapped and filled in parallel, fused, meshed, scored, written.
"""

from fusion.globalmap.fuse import (
    FusedCloud,
    FusionParams,
    agreement_counts,
    default_voxel_size,
    evidence_counts,
    fuse_into_view,
    fuse_views,
    fused_depth_points,
    kept_points,
    view_agreement,
)
from fusion.globalmap.keyviews import KeyViewParams, key_view_windows, select_key_views
from fusion.globalmap.neighbours import FusedViews, fused_reference_map, neighbour_times
from fusion.globalmap.pipeline import GLOBAL_FILL_METHOD, GlobalParams, map_global, run_global
from fusion.globalmap.score import (
    TAUS_M,
    cloud_scores,
    draw_global_figure,
    error_colours,
    exact_surface,
    exact_view,
    write_error_cloud,
)
from fusion.globalmap.tsdf import Mesh, TSDFParams, TSDFVolume, tsdf_grid, tsdf_mesh
from fusion.globalmap.views import DepthView, to_camera, to_world

__all__ = [
    "GLOBAL_FILL_METHOD", "TAUS_M", "DepthView", "FusedCloud", "FusedViews", "FusionParams",
    "GlobalParams", "KeyViewParams", "Mesh", "TSDFParams", "TSDFVolume", "agreement_counts",
    "cloud_scores", "default_voxel_size", "draw_global_figure", "error_colours", "evidence_counts",
    "exact_surface", "exact_view", "fuse_into_view", "fuse_views", "fused_depth_points",
    "fused_reference_map", "key_view_windows", "kept_points", "map_global", "neighbour_times",
    "run_global", "select_key_views", "to_camera", "to_world", "tsdf_grid", "tsdf_mesh",
    "view_agreement", "write_error_cloud",
]
