"""Robust surface fits in inverse depth, one per region: the ``plane`` and ``hybrid`` methods.

The paper fills each selected region with a weighted *mean* of its map depths, so a slanted or
curved surface gets one depth, and a region whose band holds points of two surfaces (the cast
shadow of a sphere: a dark region bounded partly by the sphere's outline, partly by the wall's)
gets a depth between them. Here each region is filled by a surface fitted to its map points, or
left empty when no surface explains them.

**Why inverse depth.** A plane ``n . X = d`` seen by a pinhole camera has
``1 / z = (n_x x + n_y y + n_z) / d``: inverse depth is *exactly* affine in the normalised
coordinates ``(x, y) = (X / Z, Y / Z)``. The coordinates are those of the ray through each pixel
centre, undistorted (:meth:`sim.camera.Camera.normalized_pixel_centres`), so the plane stays
exact under lens distortion. A curved surface is fitted as a *quadric in inverse depth*,
``1 / z`` quadratic in ``(x, y)`` (exact for no physical surface in general, a second-order
one for any smooth surface).

``plane`` (:func:`surface_fill`), on the paper's regions:

1. Segment the frame and select the regions as the paper does
   (:func:`fusion.fill.segmentation.segment_regions`, :func:`fusion.fill.filling.select_regions`,
   their
   default parameters: threshold 3, band 3 px, ring ratio 30 %, inside ratio 5 %).
2. A region's points are its map points *and* those of its band (both sides of its contour),
   exactly those the paper interpolates from (``fusion.fill.filling.region_events``, the helper
   that defines them).
3. Fit ``1 / z`` by RANSAC (MSAC score) and least-squares refinement, the residual being the
   relative depth error ``z_fit / z - 1``, inliers within ``residual_rel`` (2 %). Random samples
   come from a generator seeded with ``(seed, region label)``: the same input gives the same
   output. A plane is fitted first (3-point samples); with at least ``quadric_min_points``
   points a quadric too (6-point samples), chosen when it is a clear improvement: its score
   below ``quadric_gain`` times the plane's while the plane's is above
   ``quadric_floor_rel`` squared (a plane that already fits to 0.1 % is kept).
4. The region is **rejected** (left empty) when it has fewer than ``min_points`` points, when
   fewer than ``min_inlier_share`` of them are inliers (the fit cannot explain the region's own
   points), or when the points do not pin the surface down over the region: the largest
   *leverage* ``h(p) = sqrt(phi(p)^T (Psi^T Psi)^-1 phi(p)) / w(p)`` over its pixels exceeds
   ``max_leverage``, ``phi`` the basis at a pixel, ``Psi`` the inliers' basis rows divided by
   their inverse depths and ``w`` the fitted inverse depth. ``h`` is the fill's relative
   standard error in units of one point's: points on a line leave a plane undetermined
   (``h`` infinite), a plane extrapolated far from its points has ``h > 1``. A quadric that
   fails this test gives way to the plane.
5. Every pixel of an accepted region without a map point takes the fitted depth, except where
   the fit puts it behind the camera (``1 / z <= 0``) or outside the inliers' depth range
   widened by ``depth_margin`` (10 %) on both sides: those stay empty. Map points keep their
   depth (``dense = sparse`` where ``sparse > 0``). The confidence of a filled pixel is its
   region's inlier share; it is 0 elsewhere, map points included (they are the input, not a
   fill).

``hybrid`` (:func:`hybrid_fill`): ``plane``, then each selected region the fit rejected is cut
along the frame's edges (Canny, hysteresis thresholds ``canny_low`` / ``canny_high`` on the
L2 Sobel magnitude, aperture 3) into its 4-connected pieces without edge pixels; pieces smaller
than ``min_subregion`` are dropped. When at least two pieces remain, each is fitted and accepted
or rejected as a region is in ``plane``, its points being those of its own band and interior;
the edge pixels themselves stay empty. A region the edges do not split, and a region that was
not selected (the map does not bound it), stays empty. This is aimed at the regions that region
growing merges through a soft edge (a blurred step, a penumbra), which a gray-level step of at
most 3 per pixel lets through but whose gradient (3 levels per pixel is 24 in Sobel units)
Canny still finds.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import cv2
import numba
import numpy as np
from scipy import ndimage

from fusion.fill.filling import RegionStats, region_events, select_regions
from fusion.fill.segmentation import default_min_region, segment_regions
from fusion.methods._registry import register
from sim.camera import Camera

__all__ = ["HybridParams", "SurfaceFill", "SurfaceFit", "SurfaceFitParams", "check_frame",
           "fit_surface", "hybrid_fill", "solve_small", "surface_fill"]

_MAX_CONDITION = 1e8
"""RANSAC samples whose basis matrix is worse conditioned than this are skipped (collinear
points for a plane, points on a conic for a quadric)."""


# --------------------------------------------------------------------------- parameters

@dataclass(frozen=True)
class SurfaceFitParams:
    """Settings of ``plane`` (:func:`surface_fill`); the method's ``params`` dict overrides them
    by name (:meth:`from_params`).

    Attributes
    ----------
    residual_rel : float
        Inlier threshold on the relative depth error ``|z_fit / z - 1|`` (default 0.02).
    min_points : int
        Fewest map points a region needs to be fitted (default 6).
    min_inlier_share : float
        Smallest share of the region's points that must be inliers (default 0.7).
    max_leverage : float
        Largest relative standard error of the fill, in units of one point's, over the region's
        pixels (default 1.0: nowhere worse determined than a single point).
    quadric_min_points : int
        Fewest points to try a quadric (default 12, twice its 6 coefficients).
    quadric_gain : float
        A quadric is chosen when its MSAC score is below this share of the plane's (default
        0.5).
    quadric_floor_rel : float
        ... and the plane's root score is above this relative error (default 0.001).
    depth_margin : float
        Fitted depths outside ``[(1 - m) z_min, (1 + m) z_max]`` of the inliers' depths stay
        empty (default 0.1).
    ransac_iterations : int
        Random minimal samples per model (default 200).
    refine_iterations : int
        Least-squares refits on the inliers, each re-selecting them (default 5).
    seed : int
        Seeds the samples of region ``r`` with ``(seed, r)`` (default 0).
    """

    residual_rel: float = 0.02
    min_points: int = 6
    min_inlier_share: float = 0.7
    max_leverage: float = 1.0
    quadric_min_points: int = 12
    quadric_gain: float = 0.5
    quadric_floor_rel: float = 1e-3
    depth_margin: float = 0.1
    ransac_iterations: int = 200
    refine_iterations: int = 5
    seed: int = 0

    # Which fields each check covers; a subclass extends these (MeshParams, HybridParams).
    _POSITIVE = ("residual_rel", "max_leverage", "quadric_gain")
    _NON_NEGATIVE = ("quadric_floor_rel", "depth_margin")
    _COUNTS = {"min_points": 3, "quadric_min_points": 6, "ransac_iterations": 1,
               "refine_iterations": 0, "seed": 0}

    def __post_init__(self) -> None:
        for name in self._POSITIVE + self._NON_NEGATIVE:
            value = getattr(self, name)
            positive = name in self._POSITIVE
            if isinstance(value, bool) or not (isinstance(value, (int, float))
                                               and np.isfinite(value)
                                               and (value > 0 if positive else value >= 0)):
                bound = "> 0" if positive else ">= 0"
                raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")
        for name, least in self._COUNTS.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
                raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")
        if not 0 <= self.min_inlier_share <= 1:
            raise ValueError(f"min_inlier_share must be in [0, 1], got {self.min_inlier_share!r}")
        if not self.depth_margin < 1:
            raise ValueError(f"depth_margin must be < 1, got {self.depth_margin!r}")

    @classmethod
    def from_params(cls, params: dict | None, method: str = "plane"):
        """The defaults overridden by a method's ``params`` dict.

        Raises
        ------
        ValueError
            One line naming ``method`` and the unknown key, or the key whose value is wrong.
        """
        params = dict(params or {})
        names = [f.name for f in fields(cls)]
        for key in params:
            if key not in names:
                raise ValueError(f"filling method {method}: unknown param {key!r}; expected one "
                                 f"of {', '.join(names)}")
        try:
            return cls(**params)
        except ValueError as exc:
            raise ValueError(f"filling method {method}: param {exc}") from None


@dataclass(frozen=True)
class HybridParams(SurfaceFitParams):
    """Settings of ``hybrid`` (:func:`hybrid_fill`): those of ``plane`` and the split's.

    Attributes
    ----------
    canny_low, canny_high : float
        Hysteresis thresholds of Canny on the frame, L2 magnitude of the 3x3 Sobel gradient
        (defaults 20 and 40; a ramp of 3 gray levels per pixel, which region growing crosses,
        measures 24).
    min_subregion : int or None, pixels
        Smallest piece fitted; None (default) is the segmentation's smallest region,
        :func:`fusion.fill.segmentation.default_min_region` of the frame's size.
    """

    canny_low: float = 20.0
    canny_high: float = 40.0
    min_subregion: int | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("canny_low", "canny_high"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if self.canny_low > self.canny_high:
            raise ValueError(f"canny_low must be <= canny_high, got {self.canny_low!r} > "
                             f"{self.canny_high!r}")
        if self.min_subregion is not None and (
                isinstance(self.min_subregion, bool)
                or not isinstance(self.min_subregion, (int, np.integer)) or self.min_subregion < 1):
            raise ValueError(f"min_subregion must be an integer >= 1 pixel or None, got "
                             f"{self.min_subregion!r}")


# --------------------------------------------------------------------------- one fit

@dataclass(frozen=True, eq=False)
class SurfaceFit:
    """A surface fitted to a region's map points, accepted or not.

    Attributes
    ----------
    model : str
        ``"plane"``, ``"quadric"``, or ``"none"`` (too few points, or no valid sample).
    coefficients : (3,) or (6,) float64 ndarray
        Of ``1 / z`` (1/m) on the basis ``1, s, t`` (and ``s^2, s t, t^2``) with
        ``(s, t) = ((x, y) - centre) / scale``; empty for ``"none"``.
    centre : (2,) float64 ndarray, normalised coordinates
    scale : float, normalised coordinates
    n_points : int
        The region's points.
    inliers : (n_points,) bool ndarray
    rms_rel : float
        Root-mean-square relative depth error of the inliers (NaN without a model).
    depth_range : tuple of float, metres
        Smallest and largest inlier depth.
    leverage : float
        Largest relative standard error of the fill over the region's pixels, in units of one
        point's (inf when the points do not determine the model).
    accepted : bool
    reason : str
        ``"accepted"`` or why not, e.g. ``"inlier share 0.52 < 0.7"``.
    """

    model: str
    coefficients: np.ndarray
    centre: np.ndarray
    scale: float
    n_points: int
    inliers: np.ndarray
    rms_rel: float
    depth_range: tuple[float, float]
    leverage: float
    accepted: bool
    reason: str

    @property
    def n_inliers(self) -> int:
        """Inliers among the region's points."""
        return int(np.count_nonzero(self.inliers))

    @property
    def inlier_share(self) -> float:
        """``n_inliers / n_points`` (0 without points)."""
        return self.n_inliers / self.n_points if self.n_points else 0.0

    def inverse_depth(self, xy: np.ndarray) -> np.ndarray:
        """``1 / z`` of the fitted surface.

        Parameters
        ----------
        xy : (N, 2) float ndarray, undistorted normalised coordinates

        Returns
        -------
        (N,) float64 ndarray, 1/m (<= 0 behind the camera)
        """
        return _basis(xy, self.centre, self.scale, len(self.coefficients)) @ self.coefficients


def _basis(xy: np.ndarray, centre: np.ndarray, scale: float, size: int) -> np.ndarray:
    """(N, size) basis ``1, s, t[, s^2, s t, t^2]`` of the scaled coordinates."""
    st = (np.asarray(xy, np.float64) - centre) / scale
    s, t = st[:, 0], st[:, 1]
    columns = [np.ones_like(s), s, t]
    if size == 6:
        columns += [s * s, s * t, t * t]
    return np.stack(columns, axis=1)


def _relative_errors(predicted: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``z_fit / z - 1 = w / w_fit - 1``; inf where the fit is at or behind the camera."""
    w = w.reshape((-1,) + (1,) * (predicted.ndim - 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(predicted > 0, w / np.where(predicted > 0, predicted, 1.0) - 1, np.inf)


def _msac(errors: np.ndarray, tolerance: float) -> np.ndarray:
    """Mean truncated squared error (MSAC's score), over the first axis."""
    return np.minimum(errors * errors, tolerance * tolerance).mean(axis=0)


@dataclass(frozen=True, eq=False)
class _Model:
    coefficients: np.ndarray
    errors: np.ndarray                                 # relative depth errors of the points
    score: float                                       # MSAC
    inliers: np.ndarray


def _model(coefficients: np.ndarray, phi: np.ndarray, w: np.ndarray, tolerance: float
           ) -> _Model:
    errors = _relative_errors(phi @ coefficients, w)
    return _Model(coefficients, errors, float(_msac(errors, tolerance)),
                  np.abs(errors) <= tolerance)


@numba.njit(cache=True)
def solve_small(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> bool:
    """Solve ``a x = b`` in place (Gaussian elimination, partial pivoting; ``a`` and ``b`` are
    overwritten); False when a pivot is exactly 0."""
    size = b.shape[0]
    for col in range(size):
        pivot = col
        for row in range(col + 1, size):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if a[pivot, col] == 0.0:
            return False
        if pivot != col:
            for j in range(size):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
            b[col], b[pivot] = b[pivot], b[col]
        for row in range(col + 1, size):
            factor = a[row, col] / a[col, col]
            for j in range(col, size):
                a[row, j] -= factor * a[col, j]
            b[row] -= factor * b[col]
    _back_substitute(a, b, x)
    return True


@numba.njit(cache=True)
def _back_substitute(r: np.ndarray, b: np.ndarray, x: np.ndarray) -> None:
    """Solve the upper-triangular ``r[:n, :n] x = b[:n]`` into ``x`` (n,), compiled; a zero on
    the diagonal gives a zero coefficient."""
    n = x.shape[0]
    for row in range(n - 1, -1, -1):
        x[row] = 0.0
        if r[row, row] == 0.0:
            continue
        total = b[row]
        for j in range(row + 1, n):
            total -= r[row, j] * x[j]
        x[row] = total / r[row, row]


@numba.njit(cache=True)
def _best_sample(phi: np.ndarray, w: np.ndarray, samples: np.ndarray, tolerance: float,
                 max_condition: float) -> np.ndarray:
    """RANSAC's hypotheses, compiled: the exact solution of each minimal sample of distinct,
    well-conditioned points (2-norm condition number below ``max_condition``), scored by MSAC
    over all points; the best one's coefficients (empty when no sample qualifies), the first
    of equal scores. A hypothesis's score stops accumulating once it cannot beat the best so
    far, and the condition number is computed only for a hypothesis that would become the
    best: both leave the choice unchanged."""
    m, size = samples.shape
    n = phi.shape[0]
    tol2 = tolerance * tolerance
    best = np.empty(0)
    best_total = np.inf
    a = np.empty((size, size))
    work = np.empty((size, size))
    b = np.empty(size)
    c = np.empty(size)
    for k in range(m):
        distinct = True
        for i in range(size):
            for j in range(i + 1, size):
                if samples[k, i] == samples[k, j]:
                    distinct = False
        if not distinct:
            continue
        for i in range(size):
            for j in range(size):
                a[i, j] = phi[samples[k, i], j]
                work[i, j] = a[i, j]
            b[i] = w[samples[k, i]]
        if not solve_small(work, b, c):
            continue
        total = 0.0
        for p in range(n):
            predicted = 0.0
            for j in range(size):
                predicted += phi[p, j] * c[j]
            e2 = tol2                 # an outlier, or at or behind the camera: truncated
            diff = w[p] - predicted   # e = w / predicted - 1 = diff / predicted
            if predicted > 0 and abs(diff) <= tolerance * predicted:
                e = diff / predicted
                e2 = min(e * e, tol2)
            total += e2                                 # not NaN: c is finite here
            if total >= best_total:
                break
        if total >= best_total:
            continue
        singular = np.linalg.svd(a)[1]
        if not (singular[size - 1] > 0 and singular[0] / singular[size - 1] < max_condition):
            continue
        best_total = total
        best = c.copy()
    return best


def _robust_fit(phi: np.ndarray, w: np.ndarray, params: SurfaceFitParams,
                rng: np.random.Generator) -> _Model | None:
    """RANSAC (MSAC score) over minimal samples, then least squares on the inliers."""
    n, size = phi.shape
    tolerance = params.residual_rel
    samples = rng.integers(0, n, size=(params.ransac_iterations, size))
    best = _best_sample(np.ascontiguousarray(phi, np.float64), np.ascontiguousarray(w, np.float64),
                        samples, tolerance, _MAX_CONDITION)
    if not best.size:
        return None
    return _model(_refine(phi, w, best, tolerance, params.refine_iterations), phi, w, tolerance)


@numba.njit(cache=True)
def _inliers(phi: np.ndarray, w: np.ndarray, c: np.ndarray, tolerance: float) -> np.ndarray:
    """Points whose relative depth error under ``c`` is within ``tolerance`` (ahead only)."""
    n, size = phi.shape
    out = np.zeros(n, np.bool_)
    for p in range(n):
        predicted = 0.0
        for j in range(size):
            predicted += phi[p, j] * c[j]
        out[p] = predicted > 0 and abs(w[p] / predicted - 1) <= tolerance
    return out


@numba.njit(cache=True)
def _least_squares(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``argmin |a x - b|`` for a tall (m, n) ``a`` of full column rank, compiled: Householder
    QR (as stable as LAPACK's, without its call overhead on these small systems); ``a`` and
    ``b`` are overwritten. A zero column gives a zero coefficient."""
    m, n = a.shape
    for col in range(n):
        norm = 0.0
        for row in range(col, m):
            norm += a[row, col] * a[row, col]
        norm = np.sqrt(norm)
        if norm == 0.0:
            continue
        alpha = -norm if a[col, col] >= 0 else norm
        a[col, col] -= alpha                                # v = x - alpha e1, in place
        vnorm2 = 0.0
        for row in range(col, m):
            vnorm2 += a[row, col] * a[row, col]
        for j in range(col + 1, n):                         # H = I - 2 v v^T / v^T v
            dot = 0.0
            for row in range(col, m):
                dot += a[row, col] * a[row, j]
            factor = 2.0 * dot / vnorm2
            for row in range(col, m):
                a[row, j] -= factor * a[row, col]
        dot = 0.0
        for row in range(col, m):
            dot += a[row, col] * b[row]
        factor = 2.0 * dot / vnorm2
        for row in range(col, m):
            b[row] -= factor * a[row, col]
        a[col, col] = alpha                                 # R's diagonal
    x = np.zeros(n)
    _back_substitute(a, b, x)
    return x


@numba.njit(cache=True)
def _refine(phi: np.ndarray, w: np.ndarray, coefficients: np.ndarray, tolerance: float,
            iterations: int) -> np.ndarray:
    """Least squares of the relative residuals on the inliers, again on the new inliers, up to
    ``iterations`` times, compiled: stops when the inliers are fewer than the coefficients,
    would shrink, or no longer change."""
    n, size = phi.shape
    inliers = _inliers(phi, w, coefficients, tolerance)
    for _ in range(iterations):
        count = inliers.sum()
        if count < size:
            break
        rows = np.empty((count, size))
        k = 0
        for p in range(n):
            if inliers[p]:
                for j in range(size):
                    rows[k, j] = phi[p, j] / w[p]      # relative residuals w_fit / w - 1
                k += 1
        refined = _least_squares(rows, np.ones(count))
        new = _inliers(phi, w, refined, tolerance)
        if new.sum() < count:
            break
        coefficients = refined
        if np.array_equal(new, inliers):
            break
        inliers = new
    return coefficients


def _leverage(model: _Model, phi: np.ndarray, w: np.ndarray, region: np.ndarray,
              centre: np.ndarray, scale: float) -> float:
    """Largest ``sqrt(phi(p)^T (Psi^T Psi)^-1 phi(p)) / w_fit(p)`` over the region's pixels
    ``region`` (M, 2) ahead of the camera (``Psi``: the inliers' rows over their inverse
    depths; ``phi`` the basis of :func:`_basis` about ``centre``, ``scale``)."""
    rows = phi[model.inliers] / w[model.inliers, None]
    gram = rows.T @ rows
    if len(rows) < phi.shape[1] or np.linalg.cond(gram) > _MAX_CONDITION ** 2:
        return float("inf")
    return _largest_spread(np.ascontiguousarray(region, np.float64), centre[0], centre[1],
                           scale, model.coefficients, np.linalg.inv(gram))


@numba.njit(cache=True)
def _largest_spread(region: np.ndarray, cx: float, cy: float, scale: float,
                    coefficients: np.ndarray, inverse: np.ndarray) -> float:
    """:func:`_leverage`'s maximum over the pixels ahead of the camera (0 when none is),
    compiled, with each pixel's basis (:func:`_basis`) formed on the fly."""
    size = coefficients.shape[0]
    largest = 0.0
    basis = np.empty(size)
    for p in range(region.shape[0]):
        s = (region[p, 0] - cx) / scale
        t = (region[p, 1] - cy) / scale
        basis[0], basis[1], basis[2] = 1.0, s, t
        if size == 6:
            basis[3], basis[4], basis[5] = s * s, s * t, t * t
        predicted = 0.0
        for j in range(size):
            predicted += basis[j] * coefficients[j]
        if not predicted > 0:
            continue
        spread = 0.0
        for j in range(size):
            inner = 0.0
            for k in range(size):
                inner += inverse[j, k] * basis[k]
            spread += basis[j] * inner
        largest = max(largest, max(spread, 0.0) / (predicted * predicted))
    return np.sqrt(largest)


def fit_surface(xy: np.ndarray, depth: np.ndarray, xy_region: np.ndarray,
                params: SurfaceFitParams | None = None,
                rng: np.random.Generator | None = None) -> SurfaceFit:
    """Fit a plane, or a quadric, in inverse depth to a region's points and decide whether it
    explains them (steps 3 and 4 of the module's description).

    Parameters
    ----------
    xy : (N, 2) float ndarray, undistorted normalised coordinates of the points
    depth : (N,) float ndarray, metres, > 0
    xy_region : (M, 2) float ndarray, undistorted normalised coordinates of the region's pixels
        (for the leverage test).
    params : SurfaceFitParams, optional
    rng : numpy.random.Generator, optional
        Draws the RANSAC samples (default ``default_rng(params.seed)``).

    Returns
    -------
    SurfaceFit
    """
    params = params or SurfaceFitParams()
    rng = rng if rng is not None else np.random.default_rng(params.seed)
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    depth = np.asarray(depth, np.float64).ravel()
    if len(depth) != len(xy) or np.any(~(depth > 0)) or not np.isfinite(xy).all():
        raise ValueError("fit_surface: expected finite (N, 2) coordinates and N depths > 0 m")
    n = len(depth)
    if n < params.min_points:
        return _no_fit(n, f"{n} points < min_points {params.min_points}")
    w = 1.0 / depth
    centre = xy.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((xy - centre) ** 2, axis=1)))) or 1.0
    phis = {size: _basis(xy, centre, scale, size) for size in (3, 6)}
    plane = _robust_fit(phis[3], w, params, rng)
    if plane is None:
        return _no_fit(n, "no three points span a plane")
    choices = [("plane", plane)]
    if n >= params.quadric_min_points and np.sqrt(plane.score) > params.quadric_floor_rel:
        quadric = _robust_fit(phis[6], w, params, rng)
        if quadric is not None and quadric.score < params.quadric_gain * plane.score:
            choices.insert(0, ("quadric", quadric))
    region = np.asarray(xy_region, np.float64).reshape(-1, 2)
    for name, model in choices:                        # the quadric first, when it is better
        leverage = _leverage(model, phis[len(model.coefficients)], w, region, centre, scale)
        if leverage <= params.max_leverage or name == "plane":
            break
    share = np.count_nonzero(model.inliers) / n
    if share < params.min_inlier_share:
        reason = f"inlier share {share:.2f} < {params.min_inlier_share}"
    elif not leverage <= params.max_leverage:
        reason = f"leverage {leverage:.3g} > {params.max_leverage}"
    else:
        reason = "accepted"
    inlier_depths = depth[model.inliers]
    errors = model.errors[model.inliers]
    return SurfaceFit(
        model=name, coefficients=model.coefficients, centre=centre, scale=scale, n_points=n,
        inliers=model.inliers, rms_rel=float(np.sqrt(np.mean(errors ** 2))) if len(errors)
        else float("nan"),
        depth_range=(float(inlier_depths.min()), float(inlier_depths.max())) if len(errors)
        else (float("nan"), float("nan")),
        leverage=leverage, accepted=reason == "accepted", reason=reason)


def _no_fit(n: int, reason: str) -> SurfaceFit:
    return SurfaceFit(model="none", coefficients=np.zeros(0), centre=np.zeros(2), scale=1.0,
                      n_points=n, inliers=np.zeros(n, bool), rms_rel=float("nan"),
                      depth_range=(float("nan"), float("nan")), leverage=float("inf"),
                      accepted=False, reason=reason)


# --------------------------------------------------------------------------- frames

@dataclass(frozen=True, eq=False)
class SurfaceFill:
    """The result of :func:`surface_fill` or :func:`hybrid_fill`.

    Attributes
    ----------
    dense : (H, W) float32 ndarray, metres, 0 = none
        Map points and filled pixels.
    confidence : (H, W) float32 ndarray in [0, 1]
        The inlier share of the fit that filled a pixel, 0 elsewhere (map points included).
    labels : (H, W) int32 ndarray
        The paper's regions 1..K (0 = too small).
    regions : RegionStats or None
        The paper's selection (None when there is no map point).
    fits : dict of int to SurfaceFit
        One per selected region, by label.
    pieces : (H, W) int32 ndarray
        ``hybrid``: the pieces 1..P of the rejected regions that were fitted (0 elsewhere);
        ``plane``: all 0.
    piece_fits : dict of int to SurfaceFit
        One per piece.
    piece_parent : dict of int to int
        The region label each piece was cut from.
    """

    dense: np.ndarray
    confidence: np.ndarray
    labels: np.ndarray
    regions: RegionStats | None
    fits: dict[int, SurfaceFit]
    pieces: np.ndarray
    piece_fits: dict[int, SurfaceFit] = field(default_factory=dict)
    piece_parent: dict[int, int] = field(default_factory=dict)


def check_frame(frame: np.ndarray, sparse: np.ndarray, camera: Camera
                ) -> tuple[np.ndarray, np.ndarray]:
    """The frame and the sparse depth (float32) of a surface-fitting method (``plane``,
    ``hybrid``, ``mesh``), or a ValueError: not the camera's size, or a depth that is not
    finite metres >= 0."""
    frame = np.asarray(frame)
    sparse = np.asarray(sparse, np.float32)
    shape = (camera.height, camera.width)
    if frame.shape != shape or sparse.shape != shape:
        raise ValueError(f"expected a frame and a sparse depth of the camera's "
                         f"{shape[1]}x{shape[0]}, got {frame.shape} and {sparse.shape}")
    if not np.isfinite(sparse).all() or (sparse < 0).any():
        raise ValueError("sparse depth must be finite metres >= 0 (0 = no map point)")
    return frame, sparse


def _fill_pieces(labels: np.ndarray, wanted: list[int], sparse: np.ndarray, xy: np.ndarray,
                 ring: int, params: SurfaceFitParams, seeds: dict[int, tuple[int, ...]],
                 dense: np.ndarray, confidence: np.ndarray) -> dict[int, SurfaceFit]:
    """Fit each region of ``labels`` in ``wanted`` to its points (its band's and interior's,
    as the paper takes them) and fill ``dense``, ``confidence`` where the fit is accepted."""
    selected = np.zeros(int(labels.max()) + 1, bool)
    selected[wanted] = True
    ev_y, ev_x = np.nonzero(sparse > 0)
    start, index = region_events(labels, ev_y, ev_x, selected, ring)
    boxes = ndimage.find_objects(labels)
    fits = {}
    for label in wanted:
        points = index[start[label]:start[label + 1]]
        py, px = ev_y[points], ev_x[points]
        point_xy = xy[py, px]
        usable = np.isfinite(point_xy).all(axis=1)      # NaN where undistortion fails
        box = boxes[label - 1]
        ry, rx = np.nonzero(labels[box] == label)
        ry, rx = ry + box[0].start, rx + box[1].start
        region_xy = xy[ry, rx]
        inside = np.isfinite(region_xy).all(axis=1)
        ry, rx, region_xy = ry[inside], rx[inside], region_xy[inside]
        fit = fit_surface(point_xy[usable], sparse[py[usable], px[usable]], region_xy, params,
                          np.random.default_rng(list(seeds[label])))
        fits[label] = fit
        if not fit.accepted:
            continue
        w = fit.inverse_depth(region_xy)
        with np.errstate(divide="ignore"):
            z = np.where(w > 0, 1.0 / np.where(w > 0, w, 1.0), 0.0)
        low, high = fit.depth_range
        keep = ((w > 0) & (z >= (1 - params.depth_margin) * low)
                & (z <= (1 + params.depth_margin) * high) & (sparse[ry, rx] == 0))
        dense[ry[keep], rx[keep]] = z[keep]
        confidence[ry[keep], rx[keep]] = fit.inlier_share
    return fits


def surface_fill(frame: np.ndarray, sparse: np.ndarray, camera: Camera,
                 params: SurfaceFitParams | None = None) -> SurfaceFill:
    """``plane``: the paper's regions, each filled with a robust surface fitted to its points in
    inverse depth, or left empty when none explains them (see the module's description).

    Parameters
    ----------
    frame : (H, W) uint8 ndarray, gray
    sparse : (H, W) float ndarray, metres, 0 = no map point
    camera : Camera
        The frame's calibration (its distortion is undone).
    params : SurfaceFitParams, optional

    Returns
    -------
    SurfaceFill

    Raises
    ------
    ValueError
        If the frame or the sparse depth is not of the camera's size, or a depth is not finite
        metres >= 0.
    """
    params = params or SurfaceFitParams()
    frame, sparse = check_frame(frame, sparse, camera)
    labels = segment_regions(frame)
    dense = sparse.copy()
    confidence = np.zeros(sparse.shape, np.float32)
    if not (sparse > 0).any():
        return SurfaceFill(dense, confidence, labels, None, {}, np.zeros_like(labels))
    regions = select_regions(labels, sparse)
    wanted = [int(label) for label in np.flatnonzero(regions.selected)]
    xy = camera.normalized_pixel_centres()
    seeds = {label: (params.seed, label) for label in wanted}
    fits = _fill_pieces(labels, wanted, sparse, xy, regions.ring, params, seeds, dense,
                        confidence)
    return SurfaceFill(dense, confidence, labels, regions, fits, np.zeros_like(labels))


def hybrid_fill(frame: np.ndarray, sparse: np.ndarray, camera: Camera,
                params: HybridParams | None = None) -> SurfaceFill:
    """``hybrid``: :func:`surface_fill`, then the regions it rejected cut along the frame's
    Canny edges and their pieces fitted one by one (see the module's description).

    Parameters
    ----------
    frame : (H, W) uint8 ndarray, gray
    sparse : (H, W) float ndarray, metres, 0 = no map point
    camera : Camera
    params : HybridParams, optional

    Returns
    -------
    SurfaceFill
        With the pieces, their fits and the regions they were cut from.
    """
    params = params or HybridParams()
    first = surface_fill(frame, sparse, camera, params)
    frame, sparse = check_frame(frame, sparse, camera)
    rejected = [label for label, fit in first.fits.items() if not fit.accepted]
    if not rejected:
        return first
    edges = cv2.Canny(np.ascontiguousarray(frame, np.uint8), params.canny_low,
                      params.canny_high, L2gradient=True) > 0
    smallest = (params.min_subregion if params.min_subregion is not None
                else default_min_region(*frame.shape))
    labels = first.labels
    boxes = ndimage.find_objects(labels)
    pieces = np.zeros_like(labels)
    parent: dict[int, int] = {}
    seeds: dict[int, tuple[int, ...]] = {}
    for label in rejected:
        box = boxes[label - 1]
        parts, count = ndimage.label((labels[box] == label) & ~edges[box])   # 4-connected
        sizes = np.bincount(parts.ravel(), minlength=count + 1)
        kept = [k for k in range(1, count + 1) if sizes[k] >= smallest]
        if len(kept) < 2:
            continue                                   # the edges do not split it
        for k in kept:
            piece = len(parent) + 1
            pieces[box][parts == k] = piece
            parent[piece] = label
            seeds[piece] = (params.seed, label, k)
    dense, confidence = first.dense.copy(), first.confidence.copy()
    piece_fits = {}
    if parent:
        piece_fits = _fill_pieces(pieces, list(parent), sparse, camera.normalized_pixel_centres(),
                                  first.regions.ring, params, seeds, dense, confidence)
    return SurfaceFill(dense, confidence, labels, first.regions, first.fits, pieces, piece_fits,
                       parent)


# --------------------------------------------------------------------------- methods

def _method(name: str, summary: str, fill, params_class: type[SurfaceFitParams]):
    """Register ``fill`` under ``name``, its parameters read from the method's ``params``."""

    def method(frame: np.ndarray, sparse: np.ndarray, camera: Camera, params: dict
               ) -> tuple[np.ndarray, np.ndarray]:
        result = fill(frame, sparse, camera, params_class.from_params(params, name))
        return result.dense, result.confidence

    method.__doc__ = (f"``{name}``: :func:`{fill.__name__}` with :class:`{params_class.__name__}`"
                      " from ``params``.")
    return register(name, summary, params=params_class)(method)


plane_method = _method("plane", "per region, a robust plane (or quadric) in inverse depth "
                                "fitted to the paper's points; regions no surface explains stay "
                                "empty", surface_fill, SurfaceFitParams)
hybrid_method = _method("hybrid", "plane, then the regions it rejects cut along the frame's "
                                  "Canny edges and each piece fitted alone", hybrid_fill,
                        HybridParams)
