"""Adaptive time sampling of the renderer for the event emulator (as ESIM does).

The next render time is chosen so that no pixel's log intensity changes by more than
``lam * C`` between two samples. The change is *predicted* from the exact depth and the camera's
velocity: the motion field of a static scene (pixel velocity from depth and the camera twist)
times the log-intensity gradient (brightness constancy, dL/dt = -grad L . flow). It is then
*checked* on the render itself: if some pixel changed by more than ``lam * C`` (a moving object,
a shadow, a specular change the prediction cannot see), the interval is halved and rendered
again, down to the maximum rate. Minimum and maximum sampling rates bound the interval.

Refinement stops when it no longer helps. A pixel is rendered from a fixed set of sub-pixel
samples, so its luminance steps whenever an edge crosses one of them, and a step does not shrink
when the interval does. When an interval breaks the bound, its midpoint is rendered: a violating
pixel whose change splits between the two halves (the first half holds between ``SPLIT`` and
``1 - SPLIT`` of it) is changing continuously, and the first half is refined further; if every
violating pixel changed in one half only (steps), both halves are kept (no render is wasted)
and sampling goes on. Such samples have ``subdivided`` True and may have ``bound_met`` False.

Each pixel's own threshold. With threshold mismatch every pixel has its own ``C_p`` (the smaller
of its ON and OFF thresholds, :func:`sim.noise.threshold_map`), and the bound is ``lam * C_p``
per pixel: the prediction takes the largest ``rate_p / C_p`` and the check compares each
pixel's change with its own bound (:func:`contrast_scale`). A pixel 3 sigma low (C = 0.11 for
C = 0.2, sigma 0.03) is then sampled at ``lam`` of its threshold, not at 0.9.

The photoreceptor low-pass. The emulator solves the filter exactly for an input that is linear
between two samples and finds each crossing on that solution (:mod:`sim.events`), so what the
sampler must bound is how far the real input is from that line, as without the filter: the
bound stays on the *unfiltered* change. The filter cannot make that error larger: a first-order
low-pass has a positive impulse response of unit area, so ``|y - y_lin| <= max |u - u_lin|``
(L-infinity gain 1). What remains of the filter is the cutoff's change inside an interval,
taken as the logarithmic mean of its ends (:func:`sim.noise.lowpass_exponent`); the README
states that bound.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numba
import numpy as np

from sim.camera import Camera
from sim.validation import ParameterError, positive

__all__ = ["AT_MAX_RATE_NOTE", "AT_MAX_RATE_WARN_SHARE", "Sample", "SamplingParams",
           "SamplingStats", "adaptive_samples", "check_sampler", "contrast_scale", "log_rate_bound",
           "max_rate_warning", "motion_field"]

MARGIN = 0.75
"""The prediction aims at MARGIN * lam * C: a slight underestimate then costs no refinement."""
SPLIT = 0.25
"""A violating change is continuous when its first half holds between SPLIT and 1 - SPLIT of it."""
AT_MAX_RATE_WARN_SHARE = 0.01
"""Share of intervals still breaking the bound at the maximum rate above which
:func:`max_rate_warning` warns: a few such intervals are sub-pixel-sample steps that happen to
split (the checker scene of the tests has at most one in 200), more is a scene the rate cannot
resolve."""
AT_MAX_RATE_NOTE = (
    "intervals_at_max_rate: sampling intervals (of samples - 1) that still changed some pixel's "
    "log intensity by more than lam * C after being halved down to the maximum rate "
    "(sampling.max_rate); the emulator interpolates across them, so their events are spread "
    "over a change larger than the bound. Many of them mean a point light or specular "
    "highlight, or a texture finer than the pixels; above 1 % of the intervals simulate says "
    "so on stderr (max_rate_warning).")
"""The sentence ``sequence.json`` writes beside ``intervals_at_max_rate``."""


@dataclass(frozen=True)
class SamplingParams:
    """Adaptive sampling bounds.

    Attributes
    ----------
    lam : float
        Largest allowed change of L between samples, as a fraction of the contrast threshold
        (default 0.5).
    min_rate, max_rate : float, Hz
        Bounds of the sampling rate (default 100 Hz and 20 kHz).
    wavefront : int
        Blocks of the per-pixel sampler (:func:`sim.pixel_sampling.pixel_blocks`) handled in
        one pass of device launches (default 1): each block of a pass takes as its floor the
        rates observed in the last block before the pass, not in the block just before it.
        1: every block its predecessor's. A pass holds its blocks' samples at once (memory
        grows with it: about 9 million samples a block at 1280x720).
    """

    lam: float = 0.5
    min_rate: float = 100.0
    max_rate: float = 20000.0
    wavefront: int = 1

    def __post_init__(self) -> None:
        if not 0 < self.lam <= 1:
            raise ValueError(f"SamplingParams.lam must be in (0, 1], got {self.lam}")
        for name in ("min_rate", "max_rate"):
            positive(f"SamplingParams.{name}", getattr(self, name))
        if isinstance(self.wavefront, bool) or not isinstance(self.wavefront, int) \
                or self.wavefront < 1:
            raise ValueError(f"SamplingParams.wavefront must be a whole number >= 1, got "
                             f"{self.wavefront!r}")
        if not 0 < self.min_rate <= self.max_rate:
            raise ValueError(f"SamplingParams needs 0 < min_rate <= max_rate, got "
                             f"{self.min_rate} and {self.max_rate}")


def check_sampler(wavefront: int | None, sampler: str | None) -> None:
    """Refuse a wavefront asked of the frame sampler, which has no blocks
    (:attr:`SamplingParams.wavefront` is the per-pixel sampler's).

    Raises
    ------
    sim.validation.ParameterError
        ``wavefront`` given with ``sampler`` ``"frame"``, naming ``{wavefront}`` and
        ``{sampler}``.
    """
    if wavefront is not None and sampler == "frame":
        raise ParameterError(f"{{wavefront}} {wavefront}: only the per-pixel sampler takes it "
                             "({sampler} pixel), not {sampler} frame", wavefront="wavefront",
                             sampler="sampler")


@dataclass(frozen=True)
class Sample:
    """One accepted render.

    Attributes
    ----------
    t : float, seconds
    luminance : (H, W) float32 ndarray, linear
    log : (H, W) float64 ndarray, L = log(Y + eps)
    max_change : float
        Largest |L - L_previous| over the pixels (0 for the first sample), each pixel's change
        scaled by ``C / C_p`` when the thresholds differ (:func:`contrast_scale`).
    bound_met : bool
        max_change <= lam * C (C the smallest threshold): every pixel met its own bound.
    subdivided : bool
        The interval was shortened (its midpoint rendered, once or more) after the render at the
        predicted time broke the bound. A checkpoint stores it under the key ``refined``
        (:meth:`state`), as before the name was split from :attr:`SamplingStats.refined`.
    tail_pending : bool
        The second half of the same interval (kept after a step, see the module docstring)
        is the next sample. Sampling can be continued from a sample (``after`` of
        :func:`adaptive_samples`) only when this is False.
    """

    t: float
    luminance: np.ndarray
    log: np.ndarray
    max_change: float
    bound_met: bool
    subdivided: bool = False
    tail_pending: bool = False

    def state(self) -> dict:
        """The sample without its images, JSON-able, for a checkpoint: ``t``, ``max_change``,
        ``bound_met`` and ``refined`` (the key of :attr:`subdivided` in checkpoint files)."""
        return {"t": self.t, "max_change": self.max_change, "bound_met": self.bound_met,
                "refined": self.subdivided}

    @classmethod
    def from_state(cls, state: dict, luminance: np.ndarray, log: np.ndarray) -> Sample:
        """The sample a checkpoint saved: :meth:`state` and its two images.

        Parameters
        ----------
        state : dict
            From :meth:`state`.
        luminance : (H, W) float32 ndarray, linear
        log : (H, W) float64 ndarray
        """
        return cls(state["t"], luminance, log, state["max_change"], state["bound_met"],
                   subdivided=state["refined"])


@dataclass
class SamplingStats:
    """Counts of an adaptive run (filled while iterating).

    ``renders`` counts every render (rejected ones too), ``accepted`` the samples yielded,
    ``refined`` the midpoint renders (a count; each sample shortened by them has
    :attr:`Sample.subdivided`; the name is kept: checkpoints store these fields by name, and
    ``sequence.json`` records it as ``midpoint_renders``), ``steps`` the intervals whose only
    violations were sub-pixel-sample steps, ``at_max_rate`` the samples that still broke the
    bound at the maximum rate, ``edge_samples`` the pixels of those renders that an edge
    crosses, rendered again at ``[render] edge_spp`` sub-samples (0 without).
    """

    renders: int = 0
    accepted: int = 0
    refined: int = 0
    steps: int = 0
    at_max_rate: int = 0
    edge_samples: int = 0


def max_rate_warning(at_max_rate: int, intervals: int, max_rate: float, bound: float,
                     share: float = AT_MAX_RATE_WARN_SHARE) -> str | None:
    """The line to print when too many intervals still break the bound at the maximum rate.

    Parameters
    ----------
    at_max_rate : int
        Intervals that broke the bound at the maximum rate (``SamplingStats.at_max_rate``).
    intervals : int
        Intervals sampled (accepted samples - 1).
    max_rate : float, Hz
        The maximum sampling rate.
    bound : float, log units
        The bound, ``lam * C``.
    share : float
        Warn when ``at_max_rate > share * intervals`` (default :data:`AT_MAX_RATE_WARN_SHARE`).

    Returns
    -------
    str or None
        One line naming the count, the share, the bound, the rate, the likely causes and the
        remedies; None when there is nothing to say.

    Notes
    -----
    A warning, not a refusal: :func:`sim.simulate.simulate` prints it and records it as it is in
    ``sequence.json`` (``events.sampling_warning``). Its wording is therefore part of that file,
    and it names the remedy both ways, ``--max-rate (SamplingParams.max_rate)``, rather than
    through a :class:`sim.validation.ParameterError` placeholder.
    """
    if not (0 <= at_max_rate <= intervals):
        raise ValueError(f"expected 0 <= at_max_rate <= intervals, got {at_max_rate} of "
                         f"{intervals}")
    if intervals == 0 or at_max_rate <= share * intervals:
        return None
    percent = 100.0 * at_max_rate / intervals
    rate = f"{max_rate / 1000:g} kHz" if max_rate >= 1000 else f"{max_rate:g} Hz"
    return (f"{at_max_rate:,} of {intervals:,} intervals ({percent:.0f} %) still changed log "
            f"intensity by more than lambda*C = {bound:g} at the maximum rate {rate}: a point "
            f"light / specular highlight or texture too fine for the event camera's pixels; "
            f"their events are interpolated across larger changes; raise --max-rate "
            f"(SamplingParams.max_rate) or prefilter the texture")


def contrast_scale(contrast: float | np.ndarray) -> tuple[float, np.ndarray | None]:
    """The samplers' threshold: the smallest one, and each pixel's scale to it.

    Parameters
    ----------
    contrast : float or (H, W) array_like, log-intensity units
        One threshold for all pixels, or each pixel's own (the smaller of its ON and OFF
        thresholds), > 0.

    Returns
    -------
    C : float
        The smallest threshold.
    scale : (H, W) float64 ndarray or None
        ``C / C_p`` (<= 1): a change ``d`` of pixel ``p`` meets ``lam * C_p`` exactly when
        ``d * scale`` meets ``lam * C``. None when every pixel has the same threshold (then
        the samplers do exactly what they do with a number).
    """
    values = np.asarray(contrast, dtype=np.float64)
    if values.size == 0 or not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise ValueError("contrast must be a finite threshold > 0 (log units) or an (H, W) map "
                         f"of them, got {contrast!r}" if values.ndim == 0 else
                         "contrast must be a finite threshold > 0 (log units) or an (H, W) map "
                         "of them; the map holds a value <= 0 or not finite")
    smallest = float(values.min())
    if values.ndim == 0 or np.all(values == smallest):
        return smallest, None
    return smallest, smallest / values


def motion_field(camera: Camera, depth: np.ndarray, v_cam: np.ndarray, w_cam: np.ndarray,
                 centres: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pixel velocities of a static scene seen by a moving camera.

    Parameters
    ----------
    camera : Camera
    depth : (H, W) float ndarray, metres, 0 where nothing is seen
    v_cam, w_cam : (3,) array_like
        The camera's linear (m/s) and angular (rad/s) velocity in the camera frame.
    centres : (H, W, 2) ndarray, optional
        ``camera.normalized_pixel_centres()``, when the caller keeps it (it inverts the
        distortion, the costly part).

    Returns
    -------
    (H, W) float64 ndarray, (H, W) float64 ndarray
        du/dt and dv/dt in pixels per second (0 where depth is 0).
    """
    xy = camera.normalized_pixel_centres() if centres is None else centres
    depth = np.asarray(depth)
    flow_u = np.empty(depth.shape)
    flow_v = np.empty(depth.shape)
    _motion_field_kernel(float(camera.fx), float(camera.fy), np.asarray(xy, np.float64), depth,
                         _twist(v_cam, w_cam), flow_u, flow_v)
    return flow_u, flow_v


def _twist(v_cam: np.ndarray, w_cam: np.ndarray) -> np.ndarray:
    """``(vx, vy, vz, wx, wy, wz)`` as a float64 (6,) array (the kernels' twist)."""
    return np.concatenate([np.asarray(v_cam, np.float64).reshape(3),
                           np.asarray(w_cam, np.float64).reshape(3)])


@numba.njit(cache=True, inline="always")
def _point_flow(fx, fy, x, y, z, twist):  # pragma: no cover - compiled
    """Image velocity (du/dt, dv/dt), pixels/s, of the static point at depth ``z`` > 0 seen at
    normalized coordinates ``(x, y)`` by a camera with twist ``(vx, vy, vz, wx, wy, wz)`` (camera
    frame): ``P = z (x, y, 1)`` moves as ``dP/dt = -v - w x P``. The one home of the formula:
    :func:`motion_field` and the per-pixel sampler's rate kernel
    (:func:`sim.pixel_sampling.rate_map`) both call it, float64 operations in this order."""
    vx, vy, vz, wx, wy, wz = twist[0], twist[1], twist[2], twist[3], twist[4], twist[5]
    px = -vx - z * (wy - wz * y)
    py = -vy - z * (wz * x - wx)
    pz = -vz - z * (wx * y - wy * x)
    return fx * (px - x * pz) / z, fy * (py - y * pz) / z


@numba.njit(cache=True, parallel=True)
def _motion_field_kernel(fx, fy, xy, depth, twist, flow_u, flow_v):  # pragma: no cover
    """:func:`motion_field` into ``flow_u``, ``flow_v`` (H, W): :func:`_point_flow` where
    ``depth`` > 0, else 0 (rows in parallel)."""
    height, width = depth.shape
    for i in numba.prange(height):
        for j in range(width):
            z = np.float64(depth[i, j])
            if z > 0.0:
                flow_u[i, j], flow_v[i, j] = _point_flow(fx, fy, xy[i, j, 0], xy[i, j, 1], z,
                                                        twist)
            else:
                flow_u[i, j] = 0.0
                flow_v[i, j] = 0.0


def _one_sided_gradient(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|d/du| and |d/dv| as the larger of the two one-sided differences at each pixel."""
    grad_u = np.zeros_like(image)
    grad_v = np.zeros_like(image)
    du = np.abs(np.diff(image, axis=1))
    dv = np.abs(np.diff(image, axis=0))
    grad_u[:, :-1] = du
    grad_u[:, 1:] = np.maximum(grad_u[:, 1:], du)
    grad_v[:-1] = dv
    grad_v[1:] = np.maximum(grad_v[1:], dv)
    return grad_u, grad_v


def log_rate_bound(log: np.ndarray, flow_u: np.ndarray, flow_v: np.ndarray) -> float:
    """Largest predicted |dL/dt| over the pixels (1/s), from brightness constancy.

    The gradient of L along each axis is the larger one-sided difference, so that an edge one
    pixel wide counts with its full slope (a central difference would halve it). On the dark
    side of a sharp edge the prediction can still fall short (log is steep near 0); the check
    after the render catches that. (A bound computed on linear luminance divided by the
    pixel's level never falls short, but forces far higher rates near shadows and black ink:
    measured 3x more renders on complex_staircase, 30 % fewer on slider_close.)
    """
    grad_u, grad_v = _one_sided_gradient(np.asarray(log, dtype=np.float64))
    return float(np.max(grad_u * np.abs(flow_u) + grad_v * np.abs(flow_v)))


def adaptive_samples(renderer, t0: float, t1: float, contrast: float, log_eps: float,
                     params: SamplingParams | None = None, stats: SamplingStats | None = None,
                     after: Sample | None = None) -> Iterator[Sample]:
    """Render samples from t0 to t1 (both included) at adaptively chosen times.

    Parameters
    ----------
    renderer : sim.render.Renderer
        Renders luminance and depth of the scene at any time.
    t0, t1 : float, seconds
    contrast : float or (H, W) array_like
        The contrast threshold C (log units): one for all pixels, or each pixel's own (the
        smaller of its ON and OFF thresholds); each pixel is then held to ``lam`` of its own.
    log_eps : float
        L = log(Y + log_eps).
    params : SamplingParams, optional
    stats : SamplingStats, optional
        Filled with counts while iterating (renders, refinements).
    after : Sample, optional
        Continue an earlier run from this sample, which it yielded (with ``tail_pending``
        False): it is not rendered or yielded again, and the samples that follow are exactly
        those the earlier run would have yielded next (renders are deterministic in time).
        Pass that run's ``stats`` (as they were after the sample) to keep counting.

    Yields
    ------
    Sample
        In increasing time; consecutive samples differ by at most ``lam * C`` per pixel, unless
        the interval was refined (down to the maximum rate, or until only sub-pixel-sample steps
        broke the bound); ``bound_met`` and ``subdivided`` say which.

    Raises
    ------
    ValueError
        ``after`` has a pending tail, or its time is outside [t0, t1] (on the first ``next``).
    """
    if after is not None:
        if after.tail_pending:
            raise ValueError(f"cannot continue sampling from the sample at t = {after.t} s: the "
                             "second half of its interval is pending; expected a sample with "
                             "tail_pending False")
        if not t0 <= after.t <= t1:
            raise ValueError(f"cannot continue sampling from t = {after.t} s; expected a sample "
                             f"in [{t0}, {t1}] s")
    params = params or SamplingParams()
    stats = stats if stats is not None else SamplingStats()
    trajectory = renderer.scene.trajectory
    contrast, scale = contrast_scale(contrast)
    bound = params.lam * contrast
    dt_min, dt_max = 1.0 / params.max_rate, 1.0 / params.min_rate

    def render(t):
        stats.renders += 1
        luminance = renderer.luminance(t)
        return luminance, np.log(luminance.astype(np.float64) + log_eps)

    if after is None:
        t = float(t0)
        luminance, log = render(t)
        stats.accepted += 1
        yield Sample(t, luminance, log, 0.0, True)
    else:
        t, log = float(after.t), np.asarray(after.log, dtype=np.float64)
        if math.isclose(t, t1, rel_tol=0, abs_tol=1e-12):
            return
    while t < t1:
        v_cam, w_cam = trajectory.camera_velocity(t)
        flow_u, flow_v = motion_field(renderer.camera, renderer.depth(t), v_cam, w_cam)
        if scale is not None:                 # rates in units of the smallest threshold
            flow_u, flow_v = flow_u * scale, flow_v * scale
        rate = log_rate_bound(log, flow_u, flow_v)
        dt = dt_max if rate == 0 else min(dt_max, max(dt_min, MARGIN * bound / rate))
        t_next = min(t + dt, t1)
        lum_next, log_next = render(t_next)
        change = _scaled(np.abs(log_next - log), scale)
        subdivided = False
        tail: tuple | None = None                      # a second half kept after a step
        while True:
            violating = change > bound
            if not violating.any() or t_next - t < 2 * dt_min * (1 - 1e-9):
                break
            t_half = t + (t_next - t) / 2
            lum_half, log_half = render(t_half)
            first = _scaled(np.abs(log_half - log), scale)
            stats.refined += 1
            subdivided = True
            share = first[violating] / change[violating]
            if not np.any((share > SPLIT) & (share < 1 - SPLIT)):
                stats.steps += 1                       # steps only: keep both halves
                tail = (t_next, lum_next, log_next,
                        float(np.max(_scaled(np.abs(log_next - log_half), scale))))
                t_next, lum_next, log_next, change = t_half, lum_half, log_half, first
                break
            t_next, lum_next, log_next, change = t_half, lum_half, log_half, first
        kept = [(t_next, lum_next, log_next, float(change.max()))]
        if tail is not None:
            kept.append(tail)
        for k, (t_s, lum_s, log_s, largest) in enumerate(kept):
            met = largest <= bound
            if not met and t_s - t < 2 * dt_min * (1 - 1e-9):
                stats.at_max_rate += 1
            stats.accepted += 1
            t, log = t_s, log_s
            yield Sample(t, lum_s, log, largest, met, subdivided,
                         tail_pending=k + 1 < len(kept))
        if math.isclose(t, t1, rel_tol=0, abs_tol=1e-12):
            break


def _scaled(change: np.ndarray, scale: np.ndarray | None) -> np.ndarray:
    """Each pixel's change in units of the smallest threshold (see :func:`contrast_scale`)."""
    return change if scale is None else change * scale
