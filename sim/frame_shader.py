"""The standard camera's exposures rendered pixel by pixel: few samples where the image is smooth,
many where an edge crosses the pixel, as many exposure times as the image motion needs.

A frame integrates the luminance over its pixel's area and its exposure. A whole-frame render
(:meth:`sim.render.Renderer.luminance`) spends the same samples on every pixel, at
``exposure_samples`` times; :class:`FrameShader` spends them where the error is, with the event
camera's per-pixel kernel (:class:`sim.shader.EventShader`: static scenes, JIT variants):

- **Flat pixels**: ``flat_spp`` sub-samples (4 by default). A pixel that no edge crosses sees
  one surface under the same lights, and its samples read the texture filtered over their own
  stratum of the pixel, centred on it, so that on a plane their mean is the texture's box
  integral over the pixel whatever their number (:mod:`sim.shader`); the shading varies
  smoothly across it.
- **Edge pixels**: ``spp`` sub-samples (16 by default) where an edge of the geometry or of a
  shadow crosses the pixel at some time of the exposure (:func:`sim.pixel_sampling.geometric_edges`
  on the flat sub-samples' geometry at the exposure's start, its end, and between them so that
  two looks are less than a pixel of image motion apart: an edge cannot cross a pixel unseen).
  Point samples see such a pixel's coverage only to within a stratum.
- **Exposure times**: the exposure is cut into ``N`` equal parts, each rendered at its centre
  (the midpoint rule, every pixel at the same ``N`` times), ``N`` sized from the image motion
  ``d`` (:meth:`FrameShader.motion`, pixels, the path of the fastest surface point seen at a
  pixel centre): ``N = ceil(d sqrt(flat_spp))``, so that the image moves at most one flat
  stratum (``1 / sqrt(flat_spp)`` pixel) per part; a given ``exposure_samples`` overrides it.

Bound of the exposure times (the midpoint rule against the exact time average): a pixel's box
moved by ``(dx, dy)`` pixels gains and loses an area of at most ``|dx| + |dy|``, so its value
changes by at most that times the range ``R`` of the luminance it sweeps. Over a part of length
``e / N`` in which the image moves ``d / N`` at a constant speed, the mean distance from the
part's centre is a quarter of that: the average differs from the centre's value by at most
``R sqrt(2) d / (4 N)`` (``sqrt(2)`` from the Euclidean path to ``|dx| + |dy|``), at most
``R sqrt(2) / (4 sqrt(flat_spp))`` with the default ``N``: an eighth of ``R`` at 4 samples, and
only where an edge is swept (a smooth texture's change is second order in the motion).
:func:`exposure_bound` gives it, ``tests/test_frame_shader.py`` checks it against the exact
average of a moving edge.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from sim._summary import summary_repr
from sim.flow import surface_points
from sim.pixel_sampling import geometric_edges
from sim.profile import stage as profile_stage
from sim.render import Renderer
from sim.shader import EventShader

__all__ = ["MAX_EXPOSURE_TIMES", "ExposureCost", "FrameShader", "exposure_bound",
           "exposure_times"]

MAX_EXPOSURE_TIMES = 256
"""Most exposure times of one frame (``N`` above): a frame whose image moves more than
``MAX_EXPOSURE_TIMES / sqrt(flat_spp)`` pixels during its exposure keeps this many, and its
bound (:func:`exposure_bound`, recorded per frame) grows with the motion."""
_CHECK_STEP_PX = 0.9
"""Most image motion between two looks for edges, pixels (below one: an edge cannot cross a
pixel between them)."""


def exposure_times(motion_px: float, flat_spp: int) -> int:
    """How many times an exposure needs: ``ceil(motion_px sqrt(flat_spp))`` (less a millionth),
    1 to :data:`MAX_EXPOSURE_TIMES`.

    Parameters
    ----------
    motion_px : float, pixels
        The image motion during the exposure (:meth:`FrameShader.motion`), >= 0.
    flat_spp : int
        Sub-samples per flat pixel (a perfect square): the image moves at most one stratum,
        ``1 / sqrt(flat_spp)`` pixel, per part of the exposure.

    Returns
    -------
    int
    """
    # A motion within a millionth of a whole number of strata counts as that number: float32
    # depth puts a plane's exact 3 pixels at 3.0000002.
    parts = math.ceil(float(motion_px) * math.isqrt(int(flat_spp)) * (1.0 - 1e-6))
    return min(max(parts, 1), MAX_EXPOSURE_TIMES)


def exposure_bound(motion_px: float, times: int) -> float:
    """Bound on the midpoint rule's error over an exposure, as a fraction of the range of the
    luminance a pixel sweeps (module docstring): ``sqrt(2) motion_px / (4 times)``.

    Parameters
    ----------
    motion_px : float, pixels
        The image motion during the exposure, at a constant speed.
    times : int
        The exposure's equal parts, each rendered at its centre.

    Returns
    -------
    float
    """
    return math.sqrt(2.0) * float(motion_px) / (4.0 * int(times))


@dataclass(frozen=True)
class ExposureCost:
    """What one frame's exposure cost (``sequence.json``'s ``frames.cost``, one per frame).

    Attributes
    ----------
    times : int
        Exposure times rendered (``N``).
    motion_px : float or None, pixels
        The image motion during the exposure (None: not measured, a whole-frame render at the
        given ``exposure_samples``).
    bound : float or None
        :func:`exposure_bound` of the motion and the times (None with the motion).
    checks : int
        Looks for edges (a geometry trace of every flat sub-sample each).
    edge_pixels : int
        Pixels rendered at ``spp``, at every time.
    pixel_samples : int
        Sub-samples shaded (primary ray, then a shadow ray per light): ``times`` x (flat pixels x
        ``flat_spp`` + edge pixels x ``spp``), or ``times`` x ``spp`` x H x W for a whole frame.
    """

    times: int
    motion_px: float | None
    bound: float | None
    checks: int
    edge_pixels: int
    pixel_samples: int

    __repr__ = summary_repr

    def as_dict(self) -> dict:
        """The record, as ``sequence.json`` holds it."""
        return asdict(self)


class FrameShader:
    """A static scene's frames rendered pixel by pixel (module docstring).

    Parameters
    ----------
    renderer : Renderer
        Its scene (static: no moving objects) on a JIT variant, one pose per image.
    flat_spp : int
        Sub-samples of a pixel that no edge crosses (a perfect square).
    spp : int
        Sub-samples of a pixel that an edge crosses, at least ``flat_spp`` (a perfect square);
        equal to it, every pixel is rendered alike and no edge is looked for.
    t0, t1 : float, seconds
        The times exposures may span, ``t0 < t1``.

    Raises
    ------
    ValueError
        A scene with moving objects, a ``scalar_rgb`` renderer or one with a pose per row, or
        ``flat_spp`` above ``spp``.
    """

    def __init__(self, renderer: Renderer, flat_spp: int, spp: int, *, t0: float, t1: float):
        if renderer.scene.is_dynamic or renderer.rows:
            raise ValueError("FrameShader renders static scenes seen with one pose per image; "
                             "render frames with Renderer.luminance instead")
        flat_spp, spp = int(flat_spp), int(spp)
        if flat_spp > spp:
            raise ValueError(f"flat_spp ({flat_spp}) must be at most spp ({spp})")
        self.renderer, self.flat_spp, self.spp = renderer, flat_spp, spp
        camera = renderer.camera
        self.shape = (camera.height, camera.width)
        self._flat = EventShader(renderer, flat_spp, t0=t0, t1=t1)
        self._edges = EventShader(renderer, spp, t0=t0, t1=t1) if spp > flat_spp else None
        self._rays = camera.normalized_pixel_centres()
        self._centres = camera.pixel_centres().reshape(-1, 2)
        self.seconds = {"motion": 0.0, "edges": 0.0, "shade": 0.0}
        """Wall time spent so far, seconds: measuring the motion, looking for edges, shading
        the exposures' sub-samples."""

    def motion(self, depth: np.ndarray, t: float, exposure: float) -> float:
        """The image motion during an exposure: the longest path of a surface point seen at a
        pixel centre at ``t``, from ``t - exposure / 2`` to ``t + exposure / 2``.

        Parameters
        ----------
        depth : (H, W) float ndarray, metres, 0 where nothing is hit
            The exact z-depth at ``t`` (:meth:`sim.render.Renderer.depth`).
        t : float, seconds
        exposure : float, seconds

        Returns
        -------
        float, pixels
            Max over the pixels of ``|uv(t - e/2) - p| + |uv(t + e/2) - p|`` (the path through
            its middle; 0 where nothing is seen).
        """
        points = surface_points(self._rays, depth).reshape(-1, 3)
        seen = np.isfinite(points).all(axis=1)
        if not seen.any():
            return 0.0
        trajectory = self.renderer.scene.trajectory
        middle = trajectory.pose(float(t))
        path = np.zeros(int(seen.sum()))
        for end in (t - exposure / 2.0, t + exposure / 2.0):
            moved = np.linalg.inv(trajectory.pose(float(end))) @ middle     # camera t -> end
            uv = self.renderer.camera.project(points[seen] @ moved[:3, :3].T + moved[:3, 3])
            path += np.linalg.norm(uv - self._centres[seen], axis=1)
        path = path[np.isfinite(path)]
        return float(path.max()) if len(path) else 0.0

    def still(self, t: float) -> np.ndarray:
        """Every pixel at ``t`` with ``flat_spp`` sub-samples, (H, W) float32 cd/m^2 (a first
        look for auto-exposure)."""
        pixels = np.arange(self.shape[0] * self.shape[1])
        return self._flat.luminance(pixels, np.full(len(pixels), float(t))).reshape(self.shape)

    def edges(self, times: np.ndarray) -> np.ndarray:
        """Pixels an edge crosses at any of ``times``, (H, W) bool
        (:func:`sim.pixel_sampling.geometric_edges` of the flat sub-samples)."""
        marked = np.zeros(self.shape, dtype=bool)
        for t in times:
            marked |= geometric_edges(*self._flat.geometry(float(t)), self.shape)
        return marked

    def exposure(self, t: float, exposure: float, depth: np.ndarray,
                 times: int | None = None) -> tuple[np.ndarray, ExposureCost]:
        """The mean luminance over an exposure, and what it cost.

        Parameters
        ----------
        t : float, seconds
            The middle of the exposure.
        exposure : float, seconds
            Its length, > 0.
        depth : (H, W) float ndarray, metres
            The exact z-depth at ``t`` (for :meth:`motion`).
        times : int, optional
            Exposure times (``exposure_samples``); default :func:`exposure_times` of the motion.

        Returns
        -------
        luminance : (H, W) float32 ndarray, cd/m^2
        cost : ExposureCost
        """
        tick = time.perf_counter()
        with profile_stage("frame_motion"):
            motion = self.motion(depth, t, exposure)
        count = exposure_times(motion, self.flat_spp) if times is None else int(times)
        centres = t + exposure * ((np.arange(count) + 0.5) / count - 0.5)
        pixels = self.shape[0] * self.shape[1]
        checks, edge = 0, np.zeros(0, dtype=np.int64)
        tock = time.perf_counter()
        self.seconds["motion"] += tock - tick
        with profile_stage("frame_edges"):
            if self._edges is not None:
                looks = 1 if motion == 0 else math.floor(motion / _CHECK_STEP_PX) + 2
                checks = looks
                edge = np.flatnonzero(self.edges(np.linspace(
                    t - exposure / 2, t + exposure / 2, looks)).reshape(-1))
            flat = np.setdiff1d(np.arange(pixels), edge, assume_unique=True)
        tick = time.perf_counter()
        self.seconds["edges"] += tick - tock
        total = np.zeros(pixels, dtype=np.float64)
        for centre in centres:
            total[flat] += self._flat.luminance(flat, np.full(len(flat), centre))
            if len(edge):
                total[edge] += self._edges.luminance(edge, np.full(len(edge), centre))
        luminance = (total / count).astype(np.float32).reshape(self.shape)
        self.seconds["shade"] += time.perf_counter() - tick
        samples = count * (len(flat) * self.flat_spp + len(edge) * self.spp)
        return luminance, ExposureCost(times=count, motion_px=motion,
                                       bound=exposure_bound(motion, count), checks=checks,
                                       edge_pixels=int(len(edge)), pixel_samples=int(samples))
