"""Region growing on the gray levels of a standard frame (step 2 of the map-filling method).

"Standard and Event Cameras Fusion for Dense Mapping" splits the frame of the standard camera into
regions of nearly constant intensity, on the assumption that such a region is one smooth surface
whose depth can be interpolated from the map points around it. Two 4-neighbours belong to the same
region when their gray levels differ by at most a threshold (3 gray levels in the paper). The
regions are the connected components of the graph whose edges join 4-neighbours ``p, q`` with
``|I(p) - I(q)| <= threshold``: the comparison is from neighbour to neighbour, so a smooth ramp
of small steps grows into one region however far its ends differ. The components are found with
a union-find over the pixels in raster order (one pass, then a relabelling pass).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from sim.validation import integer

__all__ = ["SegmentationParams", "default_min_region", "region_contours", "segment_regions"]


def default_min_region(height: int, width: int) -> int:
    """Smallest region kept by default: ``max(20, Res // 1000)`` pixels, Res = height x width.

    Two reasons, one per term. A region of fewer than 20 pixels cannot tell "no projected event
    inside" from "too many": the inside rule allows fewer than 5 % of the area, and 5 % of 20 is one
    event. And a region of less than a thousandth of the image changes the filling score by less
    than 0.001 when filled, while such specks are mostly noise or texture of the frame, whose
    3-pixel ring is dominated by its neighbours' map points rather than its own surface. At
    240 x 180 this keeps regions of at least 43 pixels, at 640 x 480 307, at 1280 x 720 921.

    Parameters
    ----------
    height, width : int, pixels

    Returns
    -------
    int, pixels
    """
    if height < 1 or width < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    return max(20, (height * width) // 1000)


@dataclass(frozen=True)
class SegmentationParams:
    """Parameters of :func:`segment_regions`.

    Attributes
    ----------
    threshold : float, gray levels (units of the frame)
        Largest intensity difference between two 4-neighbours of one region (default 3, the
        paper's value for 8-bit frames; scale it for a float frame in [0, 1], e.g. 3 / 255).
    min_region : int or None, pixels
        Regions with fewer pixels are labelled 0 (ignored). None (default) means
        :func:`default_min_region` of the frame's size.
    """

    threshold: float = 3
    min_region: int | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.threshold) and self.threshold >= 0):
            raise ValueError(f"threshold must be a finite number >= 0 gray levels, got "
                             f"{self.threshold}")
        if self.min_region is not None:
            integer("min_region", self.min_region, 1)


@numba.njit(cache=True)
def _find(parent, i):  # pragma: no cover - compiled
    while parent[i] != i:
        parent[i] = parent[parent[i]]                  # path halving
        i = parent[i]
    return i


@numba.njit(cache=True)
def _union(parent, a, b):  # pragma: no cover - compiled
    ra = _find(parent, a)
    rb = _find(parent, b)
    if ra < rb:                                        # the root is the first pixel in raster order
        parent[rb] = ra
    elif rb < ra:
        parent[ra] = rb


@numba.njit(cache=True)
def _grow(image, threshold, min_region):  # pragma: no cover - compiled
    height, width = image.shape
    n = height * width
    parent = np.arange(n)
    for y in range(height):
        for x in range(width):
            i = y * width + x
            v = image[y, x]
            if x > 0 and abs(v - image[y, x - 1]) <= threshold:
                _union(parent, i, i - 1)
            if y > 0 and abs(v - image[y - 1, x]) <= threshold:
                _union(parent, i, i - width)
    size = np.zeros(n, np.int64)
    for i in range(n):
        root = _find(parent, i)
        parent[i] = root
        size[root] += 1
    # Every root is the smallest index of its set, so it is met before any other of its pixels.
    label_of_root = np.zeros(n, np.int32)
    labels = np.empty((height, width), np.int32)
    next_label = 1
    for i in range(n):
        root = parent[i]
        if root == i and size[i] >= min_region:
            label_of_root[i] = next_label
            next_label += 1
        labels[i // width, i % width] = label_of_root[root]
    return labels


def segment_regions(frame: np.ndarray, params: SegmentationParams | None = None) -> np.ndarray:
    """Regions of nearly constant gray level of a frame, grown between 4-neighbours.

    Parameters
    ----------
    frame : (H, W) uint8 or float ndarray, gray levels
        The standard camera's frame (one channel, finite values).
    params : SegmentationParams, optional

    Returns
    -------
    (H, W) int32 ndarray
        Region labels 1..K, numbered in the raster order (row by row) of each region's first
        pixel; 0 for the pixels of regions smaller than ``min_region``.

    Raises
    ------
    ValueError
        If the frame is not a non-empty 2-D array of finite gray levels.
    """
    params = params or SegmentationParams()
    frame = np.asarray(frame)
    if frame.ndim != 2 or frame.size == 0:
        raise ValueError(f"frame must be a non-empty (H, W) gray image, got shape {frame.shape}")
    if not (np.issubdtype(frame.dtype, np.integer) or np.issubdtype(frame.dtype, np.floating)):
        raise ValueError(f"frame must hold integer or float gray levels, got dtype {frame.dtype}")
    image = np.ascontiguousarray(frame, dtype=np.float64)
    if not np.isfinite(image).all():
        raise ValueError(f"frame must be finite, found {int((~np.isfinite(image)).sum())} "
                         f"NaN or infinite pixels")
    min_region = params.min_region
    if min_region is None:
        min_region = default_min_region(*frame.shape)
    # No region is larger than the frame: any larger bound keeps none, as frame size + 1 does
    # (and a bound past int64 would not reach the compiled loop).
    return _grow(image, float(params.threshold), min(int(min_region), image.size + 1))


def region_contours(labels: np.ndarray) -> np.ndarray:
    """Contour pixels of the regions: region pixels with a 4-neighbour outside their region.

    A 4-neighbour outside the region is one with another label, 0 included; the image border is
    not a contour (nothing beyond it can hold a map point), so a region touching the border has a
    contour only where it meets other regions. The contour length of a region, as
    :func:`fusion.fill.filling.select_regions` uses it, is its number of contour pixels.

    Parameters
    ----------
    labels : (H, W) int ndarray
        Region labels, 0 = no region (never a contour).

    Returns
    -------
    (H, W) bool ndarray
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"labels must be an (H, W) array, got shape {labels.shape}")
    contour = np.zeros(labels.shape, bool)
    horizontal = labels[:, 1:] != labels[:, :-1]
    vertical = labels[1:, :] != labels[:-1, :]
    contour[:, 1:] |= horizontal
    contour[:, :-1] |= horizontal
    contour[1:, :] |= vertical
    contour[:-1, :] |= vertical
    contour &= labels != 0
    return contour
