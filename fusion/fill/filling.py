"""Map filling: selection of regions and interpolation of their depth (steps 3 and 4 of the method).

"Standard and Event Cameras Fusion for Dense Mapping" fills the regions of the standard frame
(:mod:`fusion.fill.segmentation`) that the semi-dense event map bounds. Its map points, projected
into
the frame, form an *event image*: a sparse depth map, one depth per pixel (the nearest point where
several land on one pixel), 0 elsewhere. Then:

1. **Selection.** A region is filled when the map points around its contour are many and those
   inside it few: at least ``min_ring_ratio`` x its contour length (default 30 %) of pixels holding
   a map point in its ``ring``-pixel band (default 3), and fewer than ``max_inside_ratio`` x its
   area (default 5 %) inside it, away from the band. Many points inside mean texture or a surface
   that is not smooth, where the region is not one surface.
2. **Filling.** Each pixel ``p`` of a selected region gets the normalised weighted mean
   ``lambda * sum_k w(d_k) D(m_k)``, ``lambda = 1 / sum_k w(d_k)``, of the depths ``D(m_k)`` of
   *all* the region's map points ``m_k`` (those of its band and those inside it), ``d_k`` the
   Euclidean pixel distance from ``p`` to ``m_k``; pixels holding a map point keep its depth.
3. **Score.** The filling score beta compares the filled pixels with the image size.

Definitions chosen here, where the paper leaves a choice:

* **Contour** of a region: its pixels with a 4-neighbour of another label (0 included) inside the
  image (:func:`fusion.fill.segmentation.region_contours`); its length is their number.
* **Ring** (band) of a region ``r``: the pixels within Chebyshev distance ``ring`` of one of its
  contour pixels, on *both* sides of the contour, inside ``r`` and outside it. The paper counts the
  projected events "in the 3-pixel ring of the region" because the DSI's discretisation puts them
  near the contour, not on it, and on either side: a map point counts in ``r``'s ring when it
  lies in this band, wherever it lands. The band may cross other regions and ignored (label 0)
  pixels; it stops at the image border. Its outer half is exactly the dilation of ``r`` by a
  ``(2 ring + 1)``-pixel square minus ``r``: a pixel ``p`` outside ``r`` within ``ring`` of a
  pixel of ``r`` is within ``ring`` of a contour pixel, where a 4-path from that pixel to ``p``
  inside ``p``'s ``(2 ring + 1)`` square leaves ``r``.
* **Inside** points of ``r``: its map points that are *not* in its band. A region no wider than
  ``2 ring + 1`` pixels lies entirely in its band and never has inside points.
* **Points of a region** (those that interpolate it, step 2): the map points of its band and of
  its interior, i.e. of its dilation by a ``(2 ring + 1)``-pixel square.
* A region without a contour (one covering the whole image) is never selected: nothing bounds it.

Weights are a function of the pixel distance only, so they are tabulated once per call over the
integer offsets ``(dy, dx)`` with the public weighting functions, and the interpolation sums every
map point of the region, without truncation. Where the sum of a pixel's weights underflows in
float64 (Gaussian weights, sigma = 5, beyond ~180 px from every map point; the paper's
exponential ``exp(-d)`` beyond ~640 px), the pixel is recomputed in the log domain, relative to
its largest weight: the same normalised mean.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numba
import numpy as np

from fusion.fill.segmentation import region_contours
from sim._summary import summary_repr
from sim.validation import integer

__all__ = ["WEIGHTINGS", "FillParams", "RegionStats", "SelectionParams", "Weighting",
           "exponential_weights",
           "fill_regions", "filling_score", "gaussian_weights", "inverse_distance_weights",
           "region_events", "select_regions"]

_UNDERFLOW = 1e-280
"""Sum of weights below which a pixel is recomputed in the log domain."""

_NEGLIGIBLE = 1e-300
"""Tabulated weights below this are set to 0: even 10^8 of them, next to a sum of weights above
``_UNDERFLOW``, change nothing in float64; and subnormal numbers would slow the sums tenfold."""


# --------------------------------------------------------------------------- weightings

def _distances(d) -> np.ndarray:
    d = np.asarray(d, dtype=np.float64)
    if not np.isfinite(d).all() or (d < 0).any():
        raise ValueError("distances must be finite and >= 0 pixels")
    return d


def inverse_distance_weights(d) -> np.ndarray:
    """Inverse distance weights (Shepard, power 1): ``1 / d``, and 1 where ``d < 1`` px.

    Parameters
    ----------
    d : array_like of float, pixels, >= 0

    Returns
    -------
    float64 ndarray of d's shape, in (0, 1]
    """
    return 1.0 / np.maximum(_distances(d), 1.0)


def gaussian_weights(d, sigma: float = 5.0) -> np.ndarray:
    """Gaussian weights ``exp(-d^2 / (2 sigma^2))``, the paper's with ``sigma`` 5 px.

    The paper's factor ``1 / (sqrt(2 pi) sigma)`` is left out: it cancels in the normalised mean.

    Parameters
    ----------
    d : array_like of float, pixels, >= 0
    sigma : float, pixels, > 0

    Returns
    -------
    float64 ndarray of d's shape, in [0, 1]
    """
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be a finite number > 0 pixels, got {sigma}")
    d = _distances(d)
    return np.exp(-(d * d) / (2.0 * sigma * sigma))


def exponential_weights(d, scale: float = 1.0) -> np.ndarray:
    """Exponential weights ``exp(-d / scale)``; the paper's are ``exp(-d)`` (``scale`` 1 px).

    Parameters
    ----------
    d : array_like of float, pixels, >= 0
    scale : float, pixels, > 0
        Decay length (default 1, the paper's).

    Returns
    -------
    float64 ndarray of d's shape, in [0, 1]
    """
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a finite number > 0 pixels, got {scale}")
    return np.exp(-_distances(d) / scale)


@numba.njit(cache=True)
def _log_weight(d2, code, parameter):  # pragma: no cover - compiled
    """log w of a squared pixel distance ``d2``: the log form of the weighting ``code``."""
    if code == 1:                                      # Gaussian, sigma = parameter
        return -d2 / (2.0 * parameter * parameter)
    if code == 2:                                      # exponential, scale = parameter
        return -np.sqrt(d2) / parameter
    return -0.5 * np.log(max(d2, 1.0))                 # inverse distance


@numba.njit(cache=True)
def _log_weights(d2, code, parameter):  # pragma: no cover - compiled
    out = np.empty(d2.shape[0])
    for i in range(d2.shape[0]):
        out[i] = _log_weight(d2[i], code, parameter)
    return out


@dataclass(frozen=True)
class Weighting:
    """A weighting of the pixel distance, in the two forms the filling uses.

    :meth:`weights` (the public functions above) fills the tabulated weights; :meth:`log_weights`
    (compiled, as the filling's log-domain kernel calls it) recomputes the pixels where the sum
    of the weights underflows. ``log_weights == log(weights)`` for every weighting (tested).

    Attributes
    ----------
    name : str
        Its name in ``FillParams.weighting`` and ``--weighting``.
    function : callable
        The linear form, ``function(d, *parameter)``.
    parameter : str or None
        The ``FillParams`` attribute holding its length (``"sigma"``, ``"scale"``) or None.
    code : int
        Selects its log form in the compiled kernels.
    """

    name: str
    function: Callable[..., np.ndarray]
    parameter: str | None
    code: int

    def weights(self, d, parameter: float | None = None) -> np.ndarray:
        """``w(d)``: float64 ndarray of d's shape (d in pixels, >= 0)."""
        return self.function(d) if self.parameter is None else self.function(d, parameter)

    def log_weights(self, d, parameter: float | None = None) -> np.ndarray:
        """``log w(d)``: float64 ndarray of d's shape, finite where ``w(d)`` underflows."""
        d = _distances(d)
        if self.parameter is not None:
            self.function(0.0, parameter)              # the same checks of the parameter
        value = 0.0 if parameter is None else float(parameter)
        return _log_weights((d * d).ravel(), self.code, value).reshape(d.shape)


WEIGHTINGS = {w.name: w for w in (Weighting("idw", inverse_distance_weights, None, 0),
                                  Weighting("gaussian", gaussian_weights, "sigma", 1),
                                  Weighting("exponential", exponential_weights, "scale", 2))}
"""The weightings by name, as ``FillParams.weighting`` accepts them (iterates over the names)."""


# --------------------------------------------------------------------------- parameters

@dataclass(frozen=True)
class SelectionParams:
    """Which regions are filled (:func:`select_regions`).

    Attributes
    ----------
    ring : int, pixels
        Half-width of the band on both sides of a region's contour where its bounding map points
        are counted (default 3, the paper's "3-pixel ring").
    min_ring_ratio : float
        A region needs at least this many band pixels holding a map point per contour pixel
        (default 0.30, the paper's "30 % of the contour length").
    max_inside_ratio : float
        A region needs fewer map points inside it (off its band) than this share of its area
        (default 0.05, the paper's "5 % of the region size").
    """

    ring: int = 3
    min_ring_ratio: float = 0.30
    max_inside_ratio: float = 0.05

    def __post_init__(self) -> None:
        integer("ring", self.ring, 1)
        if not (np.isfinite(self.min_ring_ratio) and self.min_ring_ratio >= 0):
            raise ValueError(f"min_ring_ratio must be a finite number >= 0, got "
                             f"{self.min_ring_ratio}")
        if not (np.isfinite(self.max_inside_ratio) and self.max_inside_ratio >= 0):
            raise ValueError(f"max_inside_ratio must be a finite number >= 0, got "
                             f"{self.max_inside_ratio}")


@dataclass(frozen=True)
class FillParams:
    """How a selected region is interpolated (:func:`fill_regions`).

    Attributes
    ----------
    weighting : str
        ``"idw"`` (:func:`inverse_distance_weights`, default: the first of the paper's Table 3,
        which finds the errors insensitive to the choice), ``"gaussian"``
        (:func:`gaussian_weights`) or ``"exponential"`` (:func:`exponential_weights`).
    sigma : float, pixels
        Standard deviation of the Gaussian weights (default 5, the paper's).
    scale : float, pixels
        Decay length of the exponential weights, ``exp(-d / scale)`` (default 1: the paper's
        ``exp(-d)``).
    """

    weighting: str = "idw"
    sigma: float = 5.0
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.weighting not in WEIGHTINGS:
            raise ValueError(f"weighting must be one of {', '.join(WEIGHTINGS)}, got "
                             f"{self.weighting!r}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"sigma must be a finite number > 0 pixels, got {self.sigma}")
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be a finite number > 0 pixels, got {self.scale}")

    @property
    def length(self) -> float | None:
        """The chosen weighting's length parameter, pixels (None for ``idw``)."""
        name = WEIGHTINGS[self.weighting].parameter
        return None if name is None else float(getattr(self, name))

    def weights(self) -> Callable[[np.ndarray], np.ndarray]:
        """The weighting as a function of the pixel distance, ``w(d)``."""
        return partial(WEIGHTINGS[self.weighting].weights, parameter=self.length)


@dataclass(frozen=True, eq=False)
class RegionStats:
    """Per-region statistics of the selection, indexed by label (index 0: the ignored pixels).

    Attributes
    ----------
    area : (K + 1,) int64 ndarray, pixels
    contour : (K + 1,) int64 ndarray, pixels
        Contour length: pixels with a 4-neighbour of another label (0 for index 0).
    ring_events : (K + 1,) int64 ndarray
        Pixels of the band (both sides of the contour) holding a map point (0 for index 0).
    inside_events : (K + 1,) int64 ndarray
        Pixels of the region off its band holding a map point (index 0: every map point on an
        ignored pixel).
    selected : (K + 1,) bool ndarray
        Regions to fill (never index 0).
    ring : int, pixels
        Band half-width the counts were made with; :func:`fill_regions` interpolates from the
        map points of the same band and of the region.
    """

    __repr__ = summary_repr
    _summary_counts = ("n_regions",)

    area: np.ndarray
    contour: np.ndarray
    ring_events: np.ndarray
    inside_events: np.ndarray
    selected: np.ndarray
    ring: int

    @property
    def n_regions(self) -> int:
        """K, the number of regions (labels 1..K)."""
        return len(self.area) - 1


# --------------------------------------------------------------------------- selection

def _check_inputs(labels, sparse_depth) -> tuple[np.ndarray, np.ndarray]:
    labels = np.asarray(labels)
    sparse = np.asarray(sparse_depth)
    if labels.ndim != 2 or labels.size == 0:
        raise ValueError(f"labels must be a non-empty (H, W) array, got shape {labels.shape}")
    if not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be integers, got dtype {labels.dtype}")
    if sparse.shape != labels.shape:
        raise ValueError(f"sparse_depth has shape {sparse.shape} but the labels (of the frame) "
                         f"have shape {labels.shape}: expected the same (H, W)")
    if not (np.issubdtype(sparse.dtype, np.floating) or np.issubdtype(sparse.dtype, np.integer)):
        raise ValueError(f"sparse_depth must hold depths in metres, got dtype {sparse.dtype}")
    sparse = np.ascontiguousarray(sparse, dtype=np.float64)
    bad = ~np.isfinite(sparse)
    if bad.any():
        raise ValueError(f"sparse_depth must be finite metres (0 = no map point), found "
                         f"{int(bad.sum())} NaN or infinite pixels")
    negative = sparse < 0
    if negative.any():
        raise ValueError(f"sparse_depth must be >= 0 metres (0 = no map point), found "
                         f"{int(negative.sum())} negative pixels (min {sparse.min():g} m)")
    if not (sparse > 0).any():
        raise ValueError("no map points: sparse_depth has no pixel > 0, nothing to fill from")
    if labels.min() < 0:
        raise ValueError(f"labels must be >= 0 (0 = no region), got min {labels.min()}")
    return np.ascontiguousarray(labels, dtype=np.int32), sparse


@numba.njit(cache=True)
def _count_events(labels, contour_labels, ev_y, ev_x, n_labels, ring):  # pragma: no cover
    """Map points in each region's band (within ``ring`` of a contour pixel) and off it inside."""
    height, width = labels.shape
    ring_events = np.zeros(n_labels, np.int64)
    inside = np.zeros(n_labels, np.int64)
    seen = np.full(n_labels, -1, np.int64)             # last event counted for each label
    for k in range(ev_y.shape[0]):
        y = ev_y[k]
        x = ev_x[k]
        for yy in range(max(0, y - ring), min(height, y + ring + 1)):
            for xx in range(max(0, x - ring), min(width, x + ring + 1)):
                lab = contour_labels[yy, xx]           # 0 off every contour
                if lab != 0 and seen[lab] != k:
                    seen[lab] = k
                    ring_events[lab] += 1
        own = labels[y, x]
        if seen[own] != k:                             # label 0 has no contour: always counted
            inside[own] += 1
    return ring_events, inside


def select_regions(labels: np.ndarray, sparse_depth: np.ndarray,
                   params: SelectionParams | None = None) -> RegionStats:
    """Count the map points around and inside each region and select the regions to fill.

    Region ``r`` is selected when ``contour[r] > 0``,
    ``ring_events[r] >= min_ring_ratio * contour[r]`` and
    ``inside_events[r] < max_inside_ratio * area[r]``, the ring being the band of half-width
    ``params.ring`` on both sides of the contour (see the module's definitions).

    Parameters
    ----------
    labels : (H, W) int ndarray
        Regions 1..K of the frame (:func:`fusion.fill.segmentation.segment_regions`), 0 = ignored.
    sparse_depth : (H, W) float ndarray, metres, 0 where no map point
        The event image: the map points projected into the frame.
    params : SelectionParams, optional

    Returns
    -------
    RegionStats

    Raises
    ------
    ValueError
        If the shapes differ, a depth is NaN, infinite or negative, or there is no map point.
    """
    params = params or SelectionParams()
    labels, sparse = _check_inputs(labels, sparse_depth)
    n_labels = int(labels.max()) + 1
    ev_y, ev_x = np.nonzero(sparse > 0)
    on_contour = region_contours(labels)
    contour_labels = np.where(on_contour, labels, 0).astype(np.int32)
    # A band wider than the frame covers all of it, as one of the frame's size does (and a
    # width past int64 would not reach the compiled loop).
    ring = min(int(params.ring), max(labels.shape))
    ring_events, inside = _count_events(labels, contour_labels, ev_y, ev_x, n_labels, ring)
    area = np.bincount(labels.ravel(), minlength=n_labels).astype(np.int64)
    contour = np.bincount(labels[on_contour], minlength=n_labels).astype(np.int64)
    # Products rounded to 1e-9 so that decimal ratios act as written (0.07 x 100 is 7, not 7 + ulp).
    selected = ((contour > 0) & (ring_events >= np.round(params.min_ring_ratio * contour, 9))
                & (inside < np.round(params.max_inside_ratio * area, 9)))
    selected[0] = False
    return RegionStats(area=area, contour=contour, ring_events=ring_events,
                       inside_events=inside, selected=selected, ring=ring)


# --------------------------------------------------------------------------- filling

@numba.njit(cache=True)
def region_events(labels, ev_y, ev_x, selected, ring):  # pragma: no cover - compiled
    """Events of each selected region (in its band or inside it), as CSR: start, index.

    The band and the region together are the region's dilation by a ``(2 ring + 1)`` square (see
    the module's definitions), so a point belongs to every selected label in its square.
    """
    height, width = labels.shape
    n_labels = selected.shape[0]
    start = np.zeros(n_labels + 1, np.int64)
    seen = np.full(n_labels, -1, np.int64)
    index = np.empty(0, np.int64)
    fill = np.empty(0, np.int64)
    for sweep in range(2):
        if sweep == 1:
            for lab in range(n_labels):
                start[lab + 1] += start[lab]
            index = np.empty(start[n_labels], np.int64)
            fill = start[:-1].copy()
            seen[:] = -1
        for k in range(ev_y.shape[0]):
            y = ev_y[k]
            x = ev_x[k]
            for yy in range(max(0, y - ring), min(height, y + ring + 1)):
                for xx in range(max(0, x - ring), min(width, x + ring + 1)):
                    lab = labels[yy, xx]
                    if lab == 0 or not selected[lab] or seen[lab] == k:
                        continue
                    seen[lab] = k
                    if sweep == 0:
                        start[lab + 1] += 1
                    else:
                        index[fill[lab]] = k
                        fill[lab] += 1
    return start, index


@numba.njit(cache=True)
def _runs(labels, selected):  # pragma: no cover - compiled
    """Row runs (y, x0, length, label) of the pixels of the selected regions."""
    height, width = labels.shape
    n = 0
    run_y = np.empty(0, np.int64)
    run_x0 = np.empty(0, np.int64)
    run_len = np.empty(0, np.int64)
    run_label = np.empty(0, np.int64)
    for sweep in range(2):
        if sweep == 1:
            run_y = np.empty(n, np.int64)
            run_x0 = np.empty(n, np.int64)
            run_len = np.empty(n, np.int64)
            run_label = np.empty(n, np.int64)
            n = 0
        for y in range(height):
            x = 0
            while x < width:
                lab = labels[y, x]
                x0 = x
                while x < width and labels[y, x] == lab:
                    x += 1
                if lab != 0 and selected[lab]:
                    if sweep == 1:
                        run_y[n] = y
                        run_x0[n] = x0
                        run_len[n] = x - x0
                        run_label[n] = lab
                    n += 1
    return run_y, run_x0, run_len, run_label


@numba.njit(cache=True)
def _extent(run_y, run_x0, run_len, run_label, start, reg_y, reg_x):  # pragma: no cover
    """Largest |dy|, |dx| between a pixel of a selected region and one of its map points."""
    n_labels = start.shape[0] - 1
    big = 1 << 40
    y_lo = np.full(n_labels, big, np.int64)
    y_hi = np.full(n_labels, -big, np.int64)
    x_lo = np.full(n_labels, big, np.int64)
    x_hi = np.full(n_labels, -big, np.int64)
    for r in range(run_y.shape[0]):
        lab = run_label[r]
        y_lo[lab] = min(y_lo[lab], run_y[r])
        y_hi[lab] = max(y_hi[lab], run_y[r])
        x_lo[lab] = min(x_lo[lab], run_x0[r])
        x_hi[lab] = max(x_hi[lab], run_x0[r] + run_len[r] - 1)
    dy = 0
    dx = 0
    for lab in range(n_labels):
        for j in range(start[lab], start[lab + 1]):
            dy = max(dy, abs(reg_y[j] - y_lo[lab]), abs(reg_y[j] - y_hi[lab]))
            dx = max(dx, abs(reg_x[j] - x_lo[lab]), abs(reg_x[j] - x_hi[lab]))
    return dy, dx


@numba.njit(cache=True, parallel=True)
def _fill_runs(run_y, run_x0, run_len, run_label, start, reg_y, reg_x, reg_d, table, centre,
               sparse, out, underflow):  # pragma: no cover - compiled
    for r in numba.prange(run_y.shape[0]):
        lab = run_label[r]
        if start[lab] == start[lab + 1]:
            continue                                   # no map point: nothing to interpolate
        y = run_y[r]
        x0 = run_x0[r]
        n = run_len[r]
        num = np.zeros(n)
        den = np.zeros(n)
        for j in range(start[lab], start[lab + 1]):
            row = table[abs(y - reg_y[j])]
            base = centre + x0 - reg_x[j]              # table column of pixel x0
            depth = reg_d[j]
            for i in range(n):
                w = row[base + i]
                num[i] += w * depth
                den[i] += w
        for i in range(n):
            if sparse[y, x0 + i] > 0.0:
                continue                               # a map point keeps its depth
            if den[i] > underflow:
                out[y, x0 + i] = num[i] / den[i]
            else:
                out[y, x0 + i] = np.nan                # recomputed in the log domain


@numba.njit(cache=True, fastmath=True)
def _nearest_d2(y, x, reg_y, reg_x):  # pragma: no cover - compiled
    nearest = np.inf
    for j in range(reg_y.shape[0]):
        dy = y - reg_y[j]
        dx = x - reg_x[j]
        nearest = min(nearest, dy * dy + dx * dx)
    return nearest


@numba.njit(cache=True, parallel=True)
def _fill_log_domain(pix_y, pix_x, labels, start, reg_y, reg_x, reg_d, code, parameter,
                     out):  # pragma: no cover - compiled
    """Normalised weighted means relative to each pixel's largest weight (its nearest point)."""
    for p in numba.prange(pix_y.shape[0]):
        y = float(pix_y[p])
        x = float(pix_x[p])
        lab = labels[pix_y[p], pix_x[p]]
        lo = start[lab]
        hi = start[lab + 1]
        top = _log_weight(_nearest_d2(y, x, reg_y[lo:hi], reg_x[lo:hi]), code, parameter)
        num = 0.0
        den = 0.0
        for j in range(lo, hi):
            d2 = (y - reg_y[j]) ** 2 + (x - reg_x[j]) ** 2
            log_w = _log_weight(d2, code, parameter)
            if log_w - top > -750.0:                   # exp() of less is 0.0 in float64
                w = np.exp(log_w - top)
                num += w * reg_d[j]
                den += w
        out[pix_y[p], pix_x[p]] = num / den


def fill_regions(labels: np.ndarray, sparse_depth: np.ndarray, regions: RegionStats,
                 params: FillParams | None = None) -> np.ndarray:
    """Dense depth: the map points plus the selected regions filled by weighted interpolation.

    Each pixel of a selected region without a map point gets
    ``sum_k w(d_k) D(m_k) / sum_k w(d_k)`` over every map point ``m_k`` inside the region or in
    its band of half-width ``regions.ring`` (both sides of its contour), ``d_k`` the Euclidean
    pixel distance and ``w`` the weighting of ``params``. Sums run in float64 over all the
    points (no neighbourhood truncation).

    Parameters
    ----------
    labels : (H, W) int ndarray
        The regions ``regions`` was computed on.
    sparse_depth : (H, W) float ndarray, metres, 0 where no map point
        The event image.
    regions : RegionStats
        From :func:`select_regions`; ``regions.selected`` says which regions to fill (replace it
        with ``dataclasses.replace`` to fill another choice).
    params : FillParams, optional

    Returns
    -------
    (H, W) float32 ndarray, metres
        Map points (every pixel > 0 of ``sparse_depth``) and filled pixels; 0 elsewhere.
        ``N2 = (result > 0).sum()``.

    Raises
    ------
    ValueError
        If the shapes differ, a depth is NaN, infinite or negative, there is no map point, or
        ``regions`` does not match ``labels``.
    """
    params = params or FillParams()
    labels, sparse = _check_inputs(labels, sparse_depth)
    n_labels = int(labels.max()) + 1
    selected = np.asarray(regions.selected, dtype=bool)
    if selected.shape != (n_labels,):
        raise ValueError(f"regions has statistics for {len(selected)} labels but labels has "
                         f"{n_labels} (0..{n_labels - 1}): compute them with select_regions on "
                         f"these labels")
    out = sparse.astype(np.float32)
    if not selected[1:].any():
        return out
    ev_y, ev_x = np.nonzero(sparse > 0)
    ev_d = sparse[ev_y, ev_x]
    start, index = region_events(labels, ev_y, ev_x, selected, int(regions.ring))
    reg_y, reg_x, reg_d = ev_y[index], ev_x[index], ev_d[index]   # points region by region
    runs = _runs(labels, selected)
    # numba's prange gives each thread a contiguous block of runs: shuffle them (golden-ratio
    # sequence, deterministic) so that each block samples the whole image and costs the same.
    order = np.argsort((np.arange(len(runs[0])) * 0.6180339887498949) % 1.0, kind="stable")
    run_y, run_x0, run_len, run_label = (r[order] for r in runs)
    max_dy, max_dx = _extent(run_y, run_x0, run_len, run_label, start, reg_y, reg_x)
    half = params.weights()(np.hypot(np.arange(max_dy + 1)[:, None],
                                     np.arange(max_dx + 1)[None, :]))
    half[half < _NEGLIGIBLE] = 0.0
    table = np.ascontiguousarray(np.concatenate([half[:, :0:-1], half], axis=1))
    _fill_runs(run_y, run_x0, run_len, run_label, start, reg_y, reg_x, reg_d, table, max_dx,
               sparse, out, _UNDERFLOW)
    pix_y, pix_x = np.nonzero(np.isnan(out))
    if len(pix_y):
        length = params.length
        _fill_log_domain(pix_y, pix_x, labels, start, reg_y.astype(np.float64),
                         reg_x.astype(np.float64), reg_d, WEIGHTINGS[params.weighting].code,
                         0.0 if length is None else length, out)
    return out


# --------------------------------------------------------------------------- score

def filling_score(n1: int, n2: int, res: int) -> float:
    """Filling score ``beta = (N2 - N1) / (Res + N1 / Res)``, as the paper defines it.

    Parameters
    ----------
    n1 : int
        Map points (non-zero pixels of the semi-dense depth).
    n2 : int
        Non-zero pixels of the dense depth, map points included (``n2 >= n1``).
    res : int, pixels
        Resolution of the frame, width x height.

    Returns
    -------
    float
    """
    if res <= 0:
        raise ValueError(f"res must be the number of pixels (> 0), got {res}")
    if n1 < 0 or n2 < n1:
        raise ValueError(f"expected 0 <= n1 <= n2 (the dense map includes the map points), got "
                         f"n1 = {n1}, n2 = {n2}")
    return (n2 - n1) / (res + n1 / res)
