"""The event camera's luminance for chosen pixels at chosen times, each at its own camera pose.

:class:`EventShader` renders any set of (pixel, time) samples of a scene with static geometry in
one Dr.Jit launch, every sample seen from the camera pose at its own time: what a per-pixel event
sampler needs, where :meth:`sim.render.Renderer.luminance` renders whole frames at one pose.

Shading is the expected value of Mitsuba's ``direct`` integrator (point, spot and directional
lights, diffuse BSDFs, no interreflection), without its noise: ``direct`` picks ONE light at
random per sub-sample (and weights it by the number of lights), which leaves a fixed pattern of
light-selection noise; here every sub-sample adds the contribution of EVERY light, each with its
own shadow ray (:func:`sim.render.direct_light`, which the frames' ``evfuse_direct`` integrator
calls too). Missed rays give 0 (evfuse scenes have no environment light).

Textures are read filtered over each sub-sample's footprint on the surface, its stratum of the
pixel (``1 / sqrt(spp)`` pixel on a side, projected through the pinhole at the hit, at that
sample's pose and distance): :func:`sim.textures.filtered_scale`, the lookup that the frames'
``evfuse_direct`` integrator makes too (:func:`sim.render.register_integrator`). The filter is
centred on the stratum's centre, not on the jittered sub-sample: the hit's uv moved back by
the jitter along the footprint's uv partials, so that on a plane the sub-samples' footprints
tile the pixel and their mean is the texture's box integral over the pixel (footprints
centred on the jittered points overlap and leave gaps: on boxes_6dof's gravel floor a pixel's
log luminance varied 1.5 times as much as the 256-sample reference's). What point
sub-samples still sample is geometry (an object's edge, a shadow's edge) and where the
texture comes from (which object, which face); see :class:`sim.textures.TextureFilter` for
the filters' bounds.

:meth:`EventShader.geometry` traces the same sub-samples for what they see rather than their
light (the hit surface, which lights reach it, its normal): ``[render] edge_spp`` finds there
the pixels that an edge crosses (:mod:`sim.pixel_sampling`), at the per-pixel sampler's block
boundaries and in each of the frame sampler's frames.

Sub-pixel positions are a fixed stratified jittered pattern per pixel (``sqrt(spp) x sqrt(spp)``
strata, jitter from ``numpy.random.default_rng(renderer.seed)``), the same at every time: the
same pose gives bit-identical values, and a pixel's value is a continuous function of the pose.
Their camera-frame ray directions (lens distortion inverted by :meth:`sim.camera.Camera.undistort`
in float64) are computed once and stay on the device.

A call is one launch (one per :data:`MAX_RAYS_PER_LAUNCH` rays for larger calls): one thread
per sample, looping over its sub-samples.

Poses come from a fine time grid of ``trajectory.pose`` (step at most ``pose_step``), linearly
interpolated entry by entry (the 12 entries of ``[R | t]``) inside the kernel: per sample, NumPy
computes only the grid interval it falls in and the fraction within it; per launch, the grid nodes
that the launch's times span are uploaded as one float32 table, from which each thread gathers its
interval's two nodes and interpolates in float32; the kernel normalises each world direction. The
grid is evaluated lazily in blocks of :data:`POSE_BLOCK_NODES` nodes (a 60 s sequence at the
default 10 us step has 6 million nodes; only the blocks that samples' times span are evaluated,
and at most :data:`POSE_CACHE_BLOCKS` are kept), each block always from the same call, and the
interval and fraction of a time do not depend on the call's other times, so that the same time
always gets the same pose.
"""

from __future__ import annotations

import gc
import math
from collections import OrderedDict
from contextlib import contextmanager

import numpy as np

from sim.camera import Camera
from sim.render import Renderer, direct_light
from sim.textures import filtered_scale, set_footprint
from sim.trajectory import Trajectory

__all__ = ["EventShader", "subsample_directions", "subsample_jitter"]

MAX_RAYS_PER_LAUNCH = 1 << 22
"""Most rays (samples times spp) that one launch traces; larger calls are split into launches of
whole samples, with identical results (each sample is shaded on its own)."""
POSE_BLOCK_NODES = 4096
"""Nodes of the pose grid evaluated together (one ``trajectory.pose`` call)."""
POSE_CACHE_BLOCKS = 64
"""Blocks of the pose grid kept in memory (64 x 4097 x 12 float64, 25 MB)."""
POSE_TABLE_NODES = 1 << 16
"""Most grid intervals that the pose table of one launch spans (65537 nodes, 3 MB of float32):
a call whose times span more is split into launches of samples whose times lie closer together,
with identical results."""
MIN_LAUNCH = 4096
"""Fewest samples of a launch: a smaller call (a block's tail) is padded with copies of its last
sample, whose results are dropped. Dr.Jit's frozen kernel cannot replay a launch whose size
equals that of an array in the scene (a box's 36 indices, say): it records the function again
(boxes_6dof's 0.6 s from 2.25 s: launches of 1, 28, 36 and 48 samples, 4 extra recordings; a
4.5-s window reached Dr.Jit's warning at 10). A padded launch costs microseconds."""
POSE_BOUND_SAFETY = 4.0
"""Factor on the second-difference estimate of the interpolation error: it covers a second
derivative that peaks between nodes and a kink in the trajectory (a sampled trajectory's knot),
where the error is up to 4 times the estimate from the neighbouring second differences."""


def require_jit_variant(variant: str) -> None:
    """Refuse a Mitsuba variant that cannot trace many rays in one launch.

    Parameters
    ----------
    variant : str
        A Mitsuba variant name, such as ``"llvm_ad_rgb"``.

    Raises
    ------
    ValueError
        For a variant that is not ``llvm_*`` or ``cuda_*`` (``scalar_rgb``).
    """
    if not variant.startswith(("llvm_", "cuda_")):
        raise ValueError(f"EventShader needs a JIT Mitsuba variant (llvm_* or cuda_*), got "
                         f"{variant}; render whole frames with Renderer.luminance instead")


def subsample_jitter(camera: Camera, spp: int, seed: int) -> np.ndarray:
    """Offset of each sub-sample from the centre of its stratum, pixels.

    Sub-sample ``k`` of a pixel lies in stratum ``(k % n, k // n)`` of the ``n x n`` grid over the
    pixel's square (``n = sqrt(spp)``), at a uniform jitter within it.

    Parameters
    ----------
    camera : Camera
        The camera model (its size).
    spp : int
        Sub-samples per pixel, a perfect square.
    seed : int
        Seed of ``numpy.random.default_rng`` that draws the jitter, shape ``(H * W, spp, 2)``.

    Returns
    -------
    (H * W * spp, 2) float64 ndarray, pixels
        ``(dx, dy)`` in ``[-1 / (2 n), 1 / (2 n))``, sub-sample ``k`` of flat pixel
        ``p = y W + x`` at row ``p * spp + k``.
    """
    n = math.isqrt(spp)
    jitter = np.random.default_rng(seed).random((camera.height * camera.width, spp, 2))
    return ((jitter - 0.5) / n).reshape(-1, 2)


def subsample_directions(camera: Camera, spp: int, seed: int) -> np.ndarray:
    """Camera-frame unit ray directions of a fixed stratified jittered pattern in every pixel.

    Sub-sample ``k`` of a pixel lies in stratum ``(k % n, k // n)`` of the ``n x n`` grid over the
    pixel's square (``n = sqrt(spp)``; pixel ``(u, v)`` covers ``[u - 0.5, u + 0.5) x
    [v - 0.5, v + 0.5)``), at :func:`subsample_jitter`'s offset from the stratum's centre.

    Parameters
    ----------
    camera : Camera
        The camera model (its distortion is inverted in float64).
    spp : int
        Sub-samples per pixel, a perfect square.
    seed : int
        Seed of the jitter (:func:`subsample_jitter`).

    Returns
    -------
    (H * W * spp, 3) float64 ndarray
        Unit directions (x right, y down, z forward), sub-sample ``k`` of flat pixel ``p = y W + x``
        at row ``p * spp + k``; ``(0, 0, 0)`` where the lens model cannot be inverted.
    """
    n = math.isqrt(spp)
    strata = np.arange(spp)
    centres = camera.pixel_centres().reshape(-1, 1, 2)
    offsets = (np.stack([strata % n, strata // n], axis=-1) + 0.5) / n - 0.5
    offsets = offsets + subsample_jitter(camera, spp, seed).reshape(-1, spp, 2)
    xy_d = (centres + offsets - [camera.cx, camera.cy]) / [camera.fx, camera.fy]
    xy = camera.undistort(xy_d.reshape(-1, 2))
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    rays[~np.all(np.isfinite(rays), axis=1)] = 0.0
    return rays


def _aligned_empty(size: int, dtype: type) -> np.ndarray:
    """An uninitialised (size,) array of ``dtype`` in a 64-byte aligned buffer.

    Dr.Jit's LLVM backend uses a contiguous NumPy array's memory without copying and compiles the
    pointer's alignment into the kernel: arrays at varying alignments recompile the kernel.
    """
    itemsize = np.dtype(dtype).itemsize
    buffer = np.empty(size + 64 // itemsize, dtype=dtype)
    start = (-buffer.ctypes.data % 64) // itemsize
    return buffer[start:start + size]


def _aligned(values: np.ndarray, dtype: type) -> np.ndarray:
    """A copy of ``values`` (N,) as ``dtype`` in a 64-byte aligned buffer (see
    :func:`_aligned_empty`)."""
    out = _aligned_empty(len(values), dtype)
    out[:] = values
    return out


class _PoseGrid:
    """``[R | t]`` of a trajectory on a uniform time grid, linearly interpolated.

    The grid has ``count + 1`` nodes ``t0 + k (t1 - t0) / count``, ``count`` the smallest (at
    least 2) that makes the step at most ``step``. Blocks of :data:`POSE_BLOCK_NODES` intervals
    are evaluated when first needed and kept (at most :data:`POSE_CACHE_BLOCKS`) as (B + 1, 12)
    arrays, node by node the 12 entries of ``[R | t]`` row by row.
    """

    def __init__(self, trajectory: Trajectory, t0: float, t1: float, step: float):
        self.trajectory, self.t0, self.t1 = trajectory, t0, t1
        self.count = max(2, math.ceil((t1 - t0) / step))
        self.step = (t1 - t0) / self.count
        self._blocks: OrderedDict[int, np.ndarray] = OrderedDict()
        self._second: dict[int, tuple[float, float]] = {}

    def _evaluate(self, block: int) -> np.ndarray:
        """Nodes ``b B .. (b + 1) B`` of block ``b`` (fewer in the last one), (<= B + 1, 12).

        Records the block's largest second differences of R's entries and of t, from one
        node more on each side so that every node of the block has one.
        """
        first = block * POSE_BLOCK_NODES
        last = min(first + POSE_BLOCK_NODES, self.count)
        lo, hi = max(first - 1, 0), min(last + 1, self.count)
        times = np.minimum(self.t0 + np.arange(lo, hi + 1) * self.step, self.t1)
        entries = self.trajectory.pose(times)[:, :3, :].reshape(-1, 12)
        second = np.abs(entries[2:] - 2.0 * entries[1:-1] + entries[:-2])
        second = second.reshape(-1, 3, 4)
        self._second[block] = (float(second[:, :, :3].max()), float(second[:, :, 3].max()))
        return np.ascontiguousarray(entries[first - lo:last + 1 - lo])

    def _block(self, block: int) -> np.ndarray:
        entries = self._blocks.get(block)
        if entries is None:
            entries = self._blocks[block] = self._evaluate(block)
            if len(self._blocks) > POSE_CACHE_BLOCKS:
                self._blocks.popitem(last=False)
        else:
            self._blocks.move_to_end(block)
        return entries

    def locate(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The interval of each time and the fraction of the step it lies in.

        Parameters
        ----------
        times : (N,) float64 ndarray, seconds
            Within ``[t0, t1]``.

        Returns
        -------
        node : (N,) float64 ndarray
            Index ``k`` of the interval's first node, an integer in ``[0, count - 1]``.
        fraction : (N,) float64 ndarray
            ``(time - t0) / step - k``, in ``[0, 1]``.
        """
        fraction = times - self.t0
        fraction /= self.step
        node = np.floor(fraction)
        np.clip(node, 0, self.count - 1, out=node)
        fraction -= node
        np.clip(fraction, 0.0, 1.0, out=fraction)
        return node, fraction

    def nodes(self, first: int, last: int) -> np.ndarray:
        """(last - first + 1, 12) float64 entries of nodes ``first .. last`` (``<= count``)."""
        out = np.empty((last - first + 1, 12))
        for block in range(first // POSE_BLOCK_NODES, max(last - 1, first) // POSE_BLOCK_NODES + 1):
            start = block * POSE_BLOCK_NODES
            lo, hi = max(first, start), min(last, start + POSE_BLOCK_NODES)
            out[lo - first:hi - first + 1] = self._block(block)[lo - start:hi - start + 1]
        return out

    def interpolate(self, times: np.ndarray) -> np.ndarray:
        """(N, 12) float64 entries of ``[R | t]`` (row by row) at times (N,) in ``[t0, t1]``."""
        node, fraction = self.locate(times)
        node = node.astype(np.int64)
        block = node // POSE_BLOCK_NODES
        out = np.empty((len(times), 12))
        for b in np.unique(block):
            sel = np.flatnonzero(block == b)
            entries = self._block(int(b))
            i = node[sel] - b * POSE_BLOCK_NODES
            start = entries[i]
            out[sel] = start + fraction[sel, None] * (entries[i + 1] - start)
        return out

    def error_bound(self) -> tuple[float, float]:
        """Bounds on the interpolation error of R's entries and of t (metres), whole grid."""
        for b in range((self.count - 1) // POSE_BLOCK_NODES + 1):
            if b not in self._second:
                self._evaluate(b)
        rotation = max(r for r, _ in self._second.values())
        translation = max(t for _, t in self._second.values())
        return (POSE_BOUND_SAFETY * rotation / 8.0, POSE_BOUND_SAFETY * translation / 8.0)


class EventShader:
    """Linear luminance of chosen pixels at chosen times (static geometry), one Dr.Jit launch per
    call.

    Parameters
    ----------
    renderer : Renderer
        Its loaded scene, camera and seed are used; it must run a JIT variant (``llvm_*`` or
        ``cuda_*``).
    spp : int
        Sub-samples per pixel (a perfect square).
    t0, t1 : float, seconds
        The times that samples may have, ``t0 < t1`` within the trajectory's range.
    pose_step : float, seconds
        Largest step of the pose grid (default 10 us).

    Notes
    -----
    Device memory: the sub-sample directions, ``12 H W spp`` bytes (2 MB at 240x180, spp 4).
    A call is one launch of at most :data:`MAX_RAYS_PER_LAUNCH` primary rays (larger calls, and
    calls whose times span more than :data:`POSE_TABLE_NODES` intervals of the pose grid, are
    split), a frozen Dr.Jit function (``dr.freeze``): the first call traces the Python code and
    compiles the kernel, later calls of any size replay it (about 3 ms less per call). Dr.Jit
    records it again for a launch whose size equals that of an array in the scene (a mesh's
    vertex count, say) or of the launch's pose table (12 floats per node): the same kernel,
    traced again. Launches of fewer than :data:`MIN_LAUNCH` samples are padded, so that the
    small arrays of a scene are never matched.

    Examples
    --------
    >>> shader = EventShader(Renderer(scene), 4, t0=0.0, t1=scene.duration)   # doctest: +SKIP
    >>> shader.luminance(np.array([0, 5]), np.array([0.1, 0.2]))              # doctest: +SKIP
    array([0.31, 0.29], dtype=float32)
    """

    def __init__(self, renderer: Renderer, spp: int, *, t0: float, t1: float,
                 pose_step: float = 1e-5):
        require_jit_variant(renderer.variant)
        spp = int(spp)
        if spp < 1 or math.isqrt(spp) ** 2 != spp:
            raise ValueError(f"spp must be a perfect square >= 1, got {spp}")
        t0, t1, pose_step = float(t0), float(t1), float(pose_step)
        trajectory = renderer.scene.trajectory
        if not (trajectory.t_start <= t0 < t1 <= trajectory.t_end):
            raise ValueError(f"expected t_start <= t0 < t1 <= t_end of the trajectory "
                             f"[{trajectory.t_start}, {trajectory.t_end}] s, got t0 = {t0}, "
                             f"t1 = {t1}")
        if not (math.isfinite(pose_step) and pose_step > 0.0):
            raise ValueError(f"pose_step must be a positive number of seconds, got {pose_step}")
        import drjit as dr
        import mitsuba as mi

        self._mi, self._dr = mi, dr
        self.renderer, self.spp, self.t0, self.t1 = renderer, spp, t0, t1
        camera = renderer.camera
        self.shape = (camera.height, camera.width)
        self._poses = _PoseGrid(trajectory, t0, t1, pose_step)
        rays = subsample_directions(camera, spp, renderer.seed).astype(np.float32)
        self._directions = mi.Vector3f(*(rays[:, i] for i in range(3)))
        jitter = subsample_jitter(camera, spp, renderer.seed).astype(np.float32)
        self._jitter = mi.Vector2f(jitter[:, 0], jitter[:, 1])
        self._samples_per_launch = max(1, MAX_RAYS_PER_LAUNCH // spp)

        textures = renderer.texture_filter
        lens = (float(camera.fx), float(camera.fy))

        def trace(scene, directions, jitter, pixels, nodes, fractions, table, zeros, filtering):
            return _trace(scene, directions, jitter, pixels, nodes, fractions, table, zeros,
                          filtering, spp=spp, lens=lens)

        def trace_one(scene, directions, jitter, pixels, nodes, fractions, table, zeros,
                      filtering):
            return _trace(scene, directions, jitter, pixels, nodes, fractions, table, zeros,
                          filtering, spp=1, lens=lens, footprint=1.0 / math.isqrt(spp))

        self._filtering = None if textures is None else textures.arrays

        # A scene whose objects move is re-traced at every call: replaying a frozen kernel
        # after objects moved (their shapes' buffers and the BVH rebuilt) gave NaN luminance
        # and flicker on dynamic_6dof's 2-s window.
        freeze = (lambda f: f) if renderer.scene.is_dynamic else dr.freeze
        self._trace = freeze(trace)
        self._trace_subsamples = freeze(trace_one)
        self._trace_geometry = freeze(_geometry)

    # ----------------------------------------------------------------------------------------
    @property
    def pose_step(self) -> float:
        """float, seconds: the step of the pose grid (at most the ``pose_step`` asked for)."""
        return self._poses.step

    @property
    def pose_error_bound(self) -> float:
        """float: largest deviation of any entry of the interpolated ``[R | t]`` (see
        :meth:`pose`) from the trajectory's exact pose, at any time in ``[t0, t1]``.

        Entries of R are dimensionless (an error of e in every entry turns a ray by at most 3 e
        radians), entries of t are in metres. Linear interpolation between nodes ``h`` apart is
        off by at most ``h^2 / 8 max|f''|``; ``h^2 f''`` is estimated by the grid's largest second
        difference, times :data:`POSE_BOUND_SAFETY`. The first access evaluates the grid blocks
        not seen yet (about 2 s per million nodes for a hand-held trajectory).

        The kernel's pose differs from :meth:`pose` by float32 rounding on top of this: it
        interpolates the nodes rounded to float32 with the fraction rounded to float32, in
        float32, each entry within a few units of relative rounding (``2^-24``, 6e-8) of its
        magnitude (the camera's distance from the world origin, for t).
        """
        return max(self._poses.error_bound())

    def pose(self, times: np.ndarray) -> np.ndarray:
        """The camera poses the shader renders at: the pose grid interpolated entry by entry.

        The kernel renders at these poses up to float32 rounding (see :attr:`pose_error_bound`);
        the same time always gives the kernel the same float32 pose.

        Parameters
        ----------
        times : (N,) float64 ndarray, seconds
            Within ``[t0, t1]``.

        Returns
        -------
        (N, 4, 4) float64 ndarray
            ``T_world_camera``, R not exactly orthonormal (off by at most
            :attr:`pose_error_bound`; the kernel normalises each ray direction).
        """
        times = self._check_times(times)
        poses = np.zeros((len(times), 4, 4))
        poses[:, :3, :] = self._poses.interpolate(times).reshape(-1, 3, 4)
        poses[:, 3, 3] = 1.0
        return poses

    def luminance(self, pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Linear luminance of pixels, each at its own time and camera pose.

        Parameters
        ----------
        pixels : (N,) int ndarray
            Flat pixel indices ``y W + x`` (duplicates allowed).
        times : (N,) float64 ndarray, seconds
            Within ``[t0, t1]``. In a scene with moving objects, all equal.

        Returns
        -------
        (N,) float32 ndarray
            Linear luminance, the mean over the pixel's ``spp`` sub-samples, in the units of
            :meth:`Renderer.luminance`.

        Raises
        ------
        ValueError
            For pixels or times of the wrong shape or out of range, or different times in a
            scene whose objects move (the shader traces static geometry only).
        """
        pixels = np.asarray(pixels)
        times = self._check_times(times)
        if pixels.shape != times.shape:
            raise ValueError(f"expected pixels and times of the same shape (N,), got "
                             f"{pixels.shape} and {times.shape}")
        size = self.shape[0] * self.shape[1]
        if len(pixels) and not np.issubdtype(pixels.dtype, np.integer):
            raise ValueError(f"pixels must be integer flat indices y*W+x, got {pixels.dtype}")
        if len(pixels) and (pixels.min() < 0 or pixels.max() >= size):
            raise ValueError(f"pixels must be flat indices y*W+x in [0, {size}), got "
                             f"[{pixels.min()}, {pixels.max()}]")
        if len(pixels) == 0:
            return np.zeros(0, dtype=np.float32)
        if self.renderer.scene.is_dynamic:
            if np.any(times != times[0]):
                raise ValueError("objects move in this scene: EventShader.luminance takes one "
                                 "time per call here (the shader traces static geometry)")
            self.renderer.set_time(float(times[0]))
        # Shaded in pixel order, so that neighbouring rays run side by side (scattered pixels
        # run 1.5 times faster); each sample's value does not depend on the others.
        if np.all(pixels[1:] >= pixels[:-1]):
            return self._shade(pixels, *self._poses.locate(times))
        order = np.argsort(pixels, kind="stable")
        values = np.empty(len(pixels), dtype=np.float32)
        values[order] = self._shade(pixels[order], *self._poses.locate(times[order]))
        return values

    def luminance_device(self, pixels, times, between: tuple[float, float] | None = None):
        """:meth:`luminance` of device arrays, left on the device (no host round trip).

        Parameters
        ----------
        pixels : (N,) UInt32 Dr.Jit array of the variant's backend
            Flat pixel indices ``y W + x``, non-decreasing (the caller's order: shaded as
            given), within the image (not checked here: they index the device arrays).
        times : (N,) Float64 Dr.Jit array, seconds
            Within ``[t0, t1]`` (not checked); a static scene only.
        between : (float, float), seconds, optional
            Bounds of ``times`` that the caller knows (a block's ends): the pose table is
            then taken from them, with no reduction and wait on the device (a table wider
            than the times need gives the same values).

        Returns
        -------
        (N,) Float32 Dr.Jit array
            The values :meth:`luminance` gives for the same pixels and times, bit for bit:
            the pose interval and fraction are :meth:`_PoseGrid.locate`'s float64 operations
            on the device, the launches the same frozen kernel. Times spanning more than
            :data:`POSE_TABLE_NODES` intervals of the pose grid are refused (ValueError).
        """
        mi, dr = self._mi, self._dr
        count = dr.width(pixels)
        if count == 0:
            return dr.zeros(mi.Float, 0)
        if self.renderer.scene.is_dynamic:
            raise ValueError("EventShader.luminance_device traces static scenes only")
        grid = self._poses
        with dr.scoped_set_flag(dr.JitFlag.FastMath, False):       # IEEE, as NumPy's
            fraction = (times - self.t0) / grid.step
            node = dr.clip(dr.floor(fraction), 0, grid.count - 1)
            fraction = dr.clip(fraction - node, 0.0, 1.0)
            node = type(pixels)(node)
            if between is None:
                lo, hi = dr.min(node), dr.max(node)
                dr.eval(node, fraction, lo, hi)
                first, last = int(lo[0]), int(hi[0]) + 1
            else:
                dr.eval(node, fraction)
                ends = grid.locate(self._check_times(np.asarray(between, np.float64)))[0]
                first, last = int(ends[0]), int(ends[1]) + 1
        if last - first > POSE_TABLE_NODES:
            raise ValueError(f"times span {last - first} intervals of the pose grid; "
                             f"luminance_device takes at most {POSE_TABLE_NODES}")
        table = self._table(first, last)
        step = self._samples_per_launch
        parts = []
        for start in range(0, count, step):
            stop = min(start + step, count)
            size = max(stop - start, MIN_LAUNCH)       # small launches padded (MIN_LAUNCH)
            index = dr.minimum(dr.arange(mi.UInt32, size) + start, stop - 1)
            inputs = (dr.gather(mi.UInt32, pixels, index),
                      dr.gather(mi.UInt32, node, index) - first,
                      mi.Float(dr.gather(type(fraction), fraction, index)),
                      dr.zeros(mi.Float, size))
            total = self._traced(self._trace, inputs, table)
            parts.append(total if size == stop - start
                         else dr.gather(mi.Float, total, dr.arange(mi.UInt32, stop - start)))
        return parts[0] if len(parts) == 1 else dr.concat(parts)

    def frame(self, t: float) -> np.ndarray:
        """Every pixel at time ``t``: the values of :meth:`luminance` for those pixels and time.

        Parameters
        ----------
        t : float, seconds
            Within ``[t0, t1]``; objects that move are moved to ``t``.

        Returns
        -------
        (H, W) float32 ndarray
            Linear luminance.
        """
        return self._all_at(t, self.shape[0] * self.shape[1]).reshape(self.shape)

    def subsamples(self, t: float) -> np.ndarray:
        """Every sub-sample of every pixel at time ``t``, laid out on the sub-sample grid.

        Parameters
        ----------
        t : float, seconds
            Within ``[t0, t1]``; objects that move are moved to ``t``.

        Returns
        -------
        (H n, W n) float32 ndarray, ``n = sqrt(spp)``
            Linear luminance of sub-sample ``k`` of pixel ``(x, y)`` at row ``y n + k // n``,
            column ``x n + k % n`` (its stratum; see :func:`subsample_directions`). A pixel's
            value (:meth:`frame`) is the mean of its ``spp`` sub-samples summed in stratum
            order in float32 (:func:`sim.pixel_sampling.pixel_means`: bit for bit, tested).
        """
        # One thread per sub-sample: "pixels" index the sub-sample directions, spp = 1.
        values = self._all_at(t, self.shape[0] * self.shape[1] * self.spp,
                              self._trace_subsamples, MAX_RAYS_PER_LAUNCH)
        return self._on_grid(values)

    def subsamples_many(self, times: np.ndarray) -> list[np.ndarray]:
        """:meth:`subsamples` at each of several times (a static scene), several frames a
        launch: their values bit for bit (each sub-sample is shaded on its own, from the same
        pose interval and fraction), with fewer launches and host round trips.

        Parameters
        ----------
        times : (K,) float64 ndarray, seconds
            Within ``[t0, t1]``.

        Returns
        -------
        list of K (H n, W n) float32 ndarray
        """
        mi, dr = self._mi, self._dr
        times = self._check_times(times)
        if self.renderer.scene.is_dynamic:
            raise ValueError("EventShader.subsamples_many traces static scenes only")
        count = self.shape[0] * self.shape[1] * self.spp
        node, fraction = self._poses.locate(times)
        frames: list[np.ndarray] = []
        per_launch = max(1, MAX_RAYS_PER_LAUNCH // count)
        start = 0
        while start < len(times):
            stop = min(start + per_launch, len(times))
            first = int(node[start:stop].min())
            while int(node[start:stop].max()) + 1 - first > POSE_TABLE_NODES:
                stop -= 1                              # one pose table a launch
            table = self._table(first, int(node[start:stop].max()) + 1)
            size = max((stop - start) * count, MIN_LAUNCH)
            index = dr.minimum(dr.arange(mi.UInt32, size), (stop - start) * count - 1)
            frame = index // count
            inputs = (index - frame * count,
                      dr.gather(mi.UInt32, mi.UInt32(node[start:stop] - first), frame),
                      dr.gather(mi.Float, mi.Float(fraction[start:stop].astype(np.float32)),
                                frame),
                      dr.zeros(mi.Float, size))
            values = self._traced(self._trace_subsamples, inputs, table, to_host=True)
            frames += [self._on_grid(values[k * count:(k + 1) * count])
                       for k in range(stop - start)]
            start = stop
        return frames

    def _on_grid(self, values: np.ndarray) -> np.ndarray:
        """(H W spp, ...) per-sub-sample values, pixel by pixel, laid out on the sub-sample grid
        (H n, W n, ...) as :meth:`subsamples` describes."""
        n = math.isqrt(self.spp)
        height, width = self.shape
        values = values.reshape(height, width, n, n, *values.shape[1:])
        return values.swapaxes(1, 2).reshape(height * n, width * n, *values.shape[4:])

    def geometry(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """What every sub-sample sees at time ``t``: its surface, lights and normal.

        Parameters
        ----------
        t : float, seconds
            Within ``[t0, t1]``; objects that move are moved to ``t``.

        Returns
        -------
        key : (H n, W n) uint32 ndarray
            On the sub-sample grid (:meth:`subsamples`): 0 where the ray misses, else the hit
            shape (low 16 bits) and which lights reach the hit (bit ``16 + i``: light ``i``
            of the first 15).
        normal : (H n, W n, 3) float32 ndarray
            The hit's geometric normal, world frame (0 for a miss).
        """
        count = self.shape[0] * self.shape[1] * self.spp
        node, fraction = self._at(t, count)
        first = int(node[0])
        table = self._table(first, first + 1)
        keys = np.empty(count, dtype=np.uint32)
        normals = np.empty((count, 3), dtype=np.float32)
        for start in range(0, count, MAX_RAYS_PER_LAUNCH):
            stop = min(start + MAX_RAYS_PER_LAUNCH, count)
            index, nodes, fractions, _ = self._kernel_inputs(
                np.arange(start, stop), node[start:stop], fraction[start:stop], first)
            with _no_cyclic_gc():
                key, normal = self._trace_geometry(self.renderer.mitsuba_scene,
                                                   self._directions, index, nodes, fractions,
                                                   table)
                keys[start:stop] = np.asarray(key)[:stop - start]
                normals[start:stop] = np.asarray(normal).T[:stop - start]
        return self._on_grid(keys), self._on_grid(normals)

    # ----------------------------------------------------------------------------------------
    def _all_at(self, t: float, count: int, trace=None,
                samples_per_launch: int | None = None) -> np.ndarray:
        """Samples ``0 .. count - 1`` (pixels, or sub-samples with their own ``trace``) all at
        time ``t``, with the interval and fraction :meth:`luminance` computes for a sample at
        ``t``; objects that move are moved to ``t`` first."""
        node, fraction = self._at(t, count)
        return self._shade(np.arange(count), node, fraction, trace, samples_per_launch)

    def _at(self, t: float, count: int) -> tuple[np.ndarray, np.ndarray]:
        """The pose grid interval and fraction (each (count,), read-only) of ``count`` samples
        all at time ``t``, as :meth:`luminance` computes them; objects that move are moved to
        ``t`` first."""
        times = self._check_times(np.array([t], dtype=np.float64))
        if self.renderer.scene.is_dynamic:
            self.renderer.set_time(float(times[0]))
        node, fraction = self._poses.locate(times)
        return np.broadcast_to(node, count), np.broadcast_to(fraction, count)

    def _check_times(self, times: np.ndarray) -> np.ndarray:
        times = np.asarray(times, dtype=np.float64)
        if times.ndim != 1:
            raise ValueError(f"times must have shape (N,), got {times.shape}")
        if len(times) and not (times.min() >= self.t0 and times.max() <= self.t1):   # NaN too
            bad = times[~((times >= self.t0) & (times <= self.t1))][0]
            raise ValueError(f"times must lie in [t0, t1] = [{self.t0}, {self.t1}] s of this "
                             f"EventShader, got {bad}")
        return times

    def _shade(self, pixels: np.ndarray, node: np.ndarray, fraction: np.ndarray, trace=None,
               samples_per_launch: int | None = None) -> np.ndarray:
        """Luminance of samples, launch by launch.

        Parameters
        ----------
        pixels : (N,) int ndarray
            Flat pixel indices (rows of the sub-sample directions for ``_trace_subsamples``).
        node, fraction : (N,) float64 ndarray
            Pose grid interval and fraction of each sample (:meth:`_PoseGrid.locate`).
        trace : frozen function, optional
            ``self._trace`` by default.
        samples_per_launch : int, optional
            ``self._samples_per_launch`` by default.

        Returns
        -------
        (N,) float32 ndarray
        """
        trace = trace or self._trace
        step = samples_per_launch or self._samples_per_launch
        values = np.empty(len(pixels), dtype=np.float32)
        for sel, first, last in _pose_groups(node):
            table = self._table(first, last)
            group = (pixels, node, fraction) if sel is None else (
                pixels[sel], node[sel], fraction[sel])
            out = values if sel is None else np.empty(len(group[0]), dtype=np.float32)
            for i in range(0, len(out), step):
                out[i:i + step] = self._launch(*(a[i:i + step] for a in group), first, table,
                                               trace)
            if sel is not None:
                values[sel] = out
        return values

    def _table(self, first: int, last: int):
        """Pose grid nodes ``first .. last`` as one mi.Float, node-major (12 entries each)."""
        table = self._mi.Float(_aligned(self._poses.nodes(first, last).ravel(), np.float32))
        self._dr.make_opaque(table)
        return table

    def _launch(self, pixels: np.ndarray, node: np.ndarray, fraction: np.ndarray, first: int,
                table, trace) -> np.ndarray:
        inputs = self._kernel_inputs(pixels, node, fraction, first)
        return self._traced(trace, inputs, table, to_host=True)[:len(pixels)]

    def _traced(self, trace, inputs: tuple, table, to_host: bool = False):
        """One launch of the frozen kernel ``trace`` (:meth:`_trace`,
        :meth:`_trace_subsamples`) on its device inputs ``(index, node, fraction, zeros)``,
        evaluated and made opaque first (their sizes change per call, the kernel not), without
        cyclic garbage collection while it runs (:func:`_no_cyclic_gc`). Returns its Float
        values, as a float32 ndarray with ``to_host``."""
        dr = self._dr
        dr.eval(inputs)
        dr.make_opaque(*inputs)
        with _no_cyclic_gc():
            total = trace(self.renderer.mitsuba_scene, self._directions, self._jitter,
                          *inputs[:3], table, inputs[3], self._filtering)
            return np.asarray(total, dtype=np.float32) if to_host else total

    def _kernel_inputs(self, pixels: np.ndarray, node: np.ndarray, fraction: np.ndarray,
                       first: int) -> tuple:
        """One launch's device arrays: sample indices (mi.UInt32), their intervals relative to
        the pose table's node ``first`` (mi.UInt32), fractions (mi.Float) and zeros (mi.Float),
        padded to :data:`MIN_LAUNCH` samples (with copies of the last: the caller drops their
        results beyond ``len(pixels)``)."""
        mi, dr = self._mi, self._dr
        count = len(pixels)
        if 0 < count < MIN_LAUNCH:                  # a small launch, padded (MIN_LAUNCH)
            pad = np.full(MIN_LAUNCH - count, count - 1)
            pixels, node, fraction = (np.concatenate([a, a[pad]])
                                      for a in (pixels, node, fraction))
        index = mi.UInt32(_aligned(pixels, np.uint32))
        relative = _aligned_empty(len(node), np.uint32)
        np.subtract(node, first, out=relative, casting="unsafe")      # integers: exact
        nodes = mi.UInt32(relative)
        fractions = mi.Float(_aligned(fraction, np.float32))
        zeros = dr.zeros(mi.Float, len(pixels))
        dr.make_opaque(index, nodes, fractions, zeros)   # sizes change per call, the kernel not
        return index, nodes, fractions, zeros


@contextmanager
def _no_cyclic_gc():
    """No cyclic garbage collection while a frozen function records or replays: Python's
    collector, run at a random moment inside it, freed Dr.Jit variables of an earlier scene (a
    test suite's, or reproduce's previous window) and Dr.Jit aborted the process."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if collecting:
            gc.enable()


def _pose_groups(node: np.ndarray):
    """Split samples so that each group's times span at most :data:`POSE_TABLE_NODES` intervals.

    Parameters
    ----------
    node : (N,) float64 ndarray
        Pose grid interval of each sample, integers (:meth:`_PoseGrid.locate`).

    Yields
    ------
    sel : None or (M,) int64 ndarray
        ``None`` for all samples (one group), else the group's samples, in their order.
    first, last : int
        The group's pose table: nodes ``first .. last``, its smallest interval to one past its
        largest.
    """
    first, last = int(node.min()), int(node.max()) + 1
    if last - first <= POSE_TABLE_NODES:
        yield None, first, last
        return
    group = (node - first) // POSE_TABLE_NODES
    order = np.argsort(group, kind="stable")
    bounds = np.flatnonzero(np.diff(group[order])) + 1
    for sel in np.split(order, bounds):
        yield sel, int(node[sel].min()), int(node[sel].max()) + 1


def _trace(scene, directions, jitter, pixels, nodes, fractions, table, zeros, filtering, *,
           spp: int, lens: tuple[float, float], footprint: float | None = None):
    """Mean luminance over the ``spp`` sub-samples of each (pixel, pose) sample.

    The pose of each sample is interpolated entry by entry between two nodes of the pose table,
    in float32: ``a + fraction (b - a)``. One thread per sample loops over its sub-samples:
    primary ray, then every light's direct light (:func:`sim.render.direct_light`: per light
    its (delta) direction, a shadow ray and the BSDF times its weight); luminance summed in
    sub-sample order. With ``filtering``, the BSDF's
    texture is read filtered over the sub-sample's footprint, its stratum (``1 / sqrt(spp)``
    of the pixel on a side): :func:`sim.textures.filtered_scale`.

    Parameters
    ----------
    scene : mi.Scene
    directions : mi.Vector3f, (H W spp,)
        Camera-frame unit directions of the sub-samples (:func:`subsample_directions`).
    jitter : mi.Vector2f, (H W spp,)
        Their offsets from their strata's centres, pixels (:func:`subsample_jitter`).
    pixels : mi.UInt32, (N,)
        Flat pixel indices.
    nodes : mi.UInt32, (N,)
        Row ``k`` of the table holding the first node of each sample's interval (``k + 1`` the
        second).
    fractions : mi.Float, (N,)
        Fraction of the interval, in ``[0, 1]``.
    table : mi.Float, (12 (K + 1),)
        Pose grid nodes, node by node the entries of ``[R | t]`` row by row
        (``T_world_camera``, t in metres).
    zeros : mi.Float, (N,)
        The initial sums.
    filtering : dict or None
        :attr:`sim.textures.TextureFilter.arrays`, or None for point lookups.
    spp : int
        Sub-samples per sample.
    lens : (float, float)
        The camera's ``fx, fy`` in pixels (the footprint's differential rays).
    footprint : float, optional
        The footprint's side in pixels, default ``1 / sqrt(spp)``.

    Returns
    -------
    mi.Float, (N,)
    """
    import drjit as dr
    import mitsuba as mi

    rotation, origin = _pose(table, nodes, fractions)
    first = pixels * spp
    if filtering is not None:
        scale = 1.0 / math.isqrt(spp) if footprint is None else footprint
        axes = tuple(mi.Vector3f(rotation[0][c], rotation[1][c], rotation[2][c])
                     for c in range(3))
        axes = (axes[0] * (1.0 / lens[0]), axes[1] * (1.0 / lens[1]), axes[2])

    def body(k, total):
        local = dr.gather(mi.Vector3f, directions, first + k)
        valid = local.z > 0.0                    # (0, 0, 0): the lens model is not invertible
        ray = mi.Ray3f(origin, dr.normalize(rotation @ local))
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True, active=valid)
        hit = valid & si.is_valid()
        bsdf = si.bsdf()
        texture = mi.Float(1.0)
        if filtering is not None:
            set_footprint(si, ray, axes, scale)
            # The filter's box is the sub-sample's stratum: centred on the stratum's centre,
            # the jitter undone along the surface (the footprint's uv partials per stratum).
            offset = dr.gather(mi.Vector2f, jitter, first + k) * (-1.0 / scale)
            shift = si.duv_dx * offset.x + si.duv_dy * offset.y
            texture = filtered_scale(filtering, si, bsdf, hit, shift)
        return k + 1, total + mi.luminance(direct_light(scene, si, bsdf, hit, texture))

    _, total = dr.while_loop((mi.UInt32(0), zeros), lambda k, total: k < spp, body)
    return total * (1.0 / spp)


def _pose(table, nodes, fractions):
    """Each sample's ``R`` (mi.Matrix3f) and camera centre (mi.Point3f), interpolated entry by
    entry between its interval's two nodes of the pose table, in float32."""
    import drjit as dr
    import mitsuba as mi

    # Row r of node k: entries 12 k + 4 r .. 12 k + 4 r + 3 of the table, one packet each.
    rows = []
    for r in range(3):
        a = dr.gather(mi.Vector4f, table, nodes * 3 + r)
        b = dr.gather(mi.Vector4f, table, nodes * 3 + (3 + r))
        rows.append(a + fractions * (b - a))
    rotation = mi.Matrix3f(*(rows[r][c] for r in range(3) for c in range(3)))
    origin = mi.Point3f(rows[0][3], rows[1][3], rows[2][3])
    return rotation, origin


def _geometry(scene, directions, pixels, nodes, fractions, table):
    """What each sub-sample sees, for telling a geometric edge from a smooth change.

    Parameters as :func:`_trace`'s, ``pixels`` indexing sub-samples (one thread each).

    Returns
    -------
    key : mi.UInt32, (N,)
        0 for a miss; else the hit shape's index + 1 in the low 16 bits and, in bit 16 + i,
        whether light ``i`` (of the first 15) reaches the hit (its shadow ray is free).
    normal : mi.Vector3f, (N,)
        The hit's geometric normal, world frame (0 for a miss).
    """
    import drjit as dr
    import mitsuba as mi

    rotation, origin = _pose(table, nodes, fractions)
    local = dr.gather(mi.Vector3f, directions, pixels)
    valid = local.z > 0.0
    ray = mi.Ray3f(origin, dr.normalize(rotation @ local))
    si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True, active=valid)
    hit = valid & si.is_valid()
    key = dr.select(hit, (dr.reinterpret_array(mi.UInt32, si.shape) & 0xFFFF) + 1, 0)
    centre = mi.Point2f(0.5, 0.5)                # delta lights ignore their sample
    for i, emitter in enumerate(scene.emitters()[:15]):
        ds, _ = emitter.sample_direction(si, centre, hit)
        lit = hit & (ds.pdf != 0.0)
        lit = dr.select(scene.ray_test(si.spawn_ray_to(ds.p), lit), False, lit)
        key = key | dr.select(lit, mi.UInt32(1 << (16 + i)), 0)
    normal = dr.select(hit, si.n, mi.Vector3f(0.0))
    return key, normal
