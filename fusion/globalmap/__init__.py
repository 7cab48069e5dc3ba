"""One global map from many key views (issue 25).

* :mod:`fusion.globalmap.views` -- :class:`DepthView`: a depth image with its camera and world pose.
"""

from fusion.globalmap.views import DepthView, to_camera, to_world

__all__ = ["DepthView", "to_camera", "to_world"]
