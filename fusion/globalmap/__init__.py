"""One global map from many key views (issue 25).

* :mod:`fusion.globalmap.views` -- :class:`DepthView`: a depth image with its camera and world pose.
* :mod:`fusion.globalmap.fuse` -- multi-view consistency: agreement counts, the fused point cloud,
  the fused map in one reference view, and the agreement of overlapping views (no ground truth).
"""

from fusion.globalmap.fuse import (
    FusedCloud,
    FusionParams,
    agreement_counts,
    default_voxel_size,
    fuse_into_view,
    fuse_views,
    view_agreement,
)
from fusion.globalmap.views import DepthView, to_camera, to_world

__all__ = [
    "DepthView", "FusedCloud", "FusionParams", "agreement_counts", "default_voxel_size",
    "fuse_into_view", "fuse_views", "to_camera", "to_world", "view_agreement",
]
