"""The event camera: one driver (:func:`_simulate_events`) that runs either sampler of the event
camera's renders, emulates the events, streams them to the event files and checkpoints its state.

The two samplers differ only in how they give the next luminance samples (and what they record):

- :class:`_FrameSampler`: whole frames at one adaptive rate (:func:`sim.sampling.adaptive_samples`),
  each handed to :class:`sim.events.EventEmulator`;
- :class:`_PixelSampler`: each pixel at its own adaptive times
  (:func:`sim.pixel_sampling.pixel_blocks`, which emulates each pixel's events as it samples it,
  block by block), static scenes on a JIT variant only.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numba
import numpy as np

from sim.event_depth import (
    DEPTH_TXT,
    LABELS_TXT,
    EventDepth,
    EventOutputs,
    H5EventDepthWriter,
    RecentDepth,
    TextEventDepthWriter,
    event_depth_record,
    event_file_name,
)
from sim.event_labels import LABELS_TXT_NAME, TextEventLabelWriter, event_labels_record
from sim.eventio import H5EventWriter, TextEventWriter
from sim.events import EventEmulator, EventParams
from sim.pixel_sampling import (
    PixelEventEmulator,
    PixelSamplingStats,
    pixel_blocks,
    refine_edges,
)
from sim.profile import stage
from sim.progress import progress as progress_stage
from sim.render import Renderer
from sim.sampling import (
    AT_MAX_RATE_NOTE,
    Sample,
    SamplingParams,
    SamplingStats,
    adaptive_samples,
    max_rate_warning,
)
from sim.scene import Scene
from sim.simulate._checkpoint import _Checkpoint, _restore_events
from sim.validation import ParameterError

_SHADING = ("evfuse.shader: direct light from every light in turn, a fixed stratified sub-pixel "
            "pattern")
PIXEL_AT_MAX_RATE_NOTE = (
    "intervals_at_max_rate: per-pixel intervals (of intervals) that still changed the pixel's "
    "log intensity by more than lam * C when 2 / max_rate short (sampling.max_rate); the "
    "emulator interpolates across them. Many of them mean a point light or specular highlight, "
    "or a texture finer than the pixels; above 1 % simulate says so on stderr.")
"""The sentence ``sequence.json`` writes beside ``intervals_at_max_rate`` (per-pixel sampler)."""


class _OnEventClock:
    """An event writer that shifts every event by the event stream's clock offset (ns)."""

    def __init__(self, writer: H5EventWriter | TextEventWriter, offset_ns: int) -> None:
        self._writer, self._offset_ns = writer, offset_ns

    def write(self, events: np.ndarray, **columns: np.ndarray) -> None:
        shifted = events.copy()
        shifted["t"] += self._offset_ns
        self._writer.write(shifted, **columns)

    def checkpoint(self) -> dict:
        return self._writer.checkpoint()


class _EventCamera:
    """The event camera's renders: luminance at its own samples per pixel, exact depth.

    On a JIT variant the event camera is shaded by :class:`sim.shader.EventShader` (every light
    in turn, a fixed sub-pixel pattern), whichever sampler drives it, so that the two samplers
    see the same luminance; on ``scalar_rgb`` by the frames' ``evfuse_direct`` (every light in
    turn too, :func:`sim.render.register_integrator`). With ``edge_spp`` (a JIT variant only) a
    second shader renders the pixels that an edge crosses at ``edge_spp`` sub-samples
    (:func:`sim.pixel_sampling.geometric_edges`): the per-pixel sampler asks for them itself,
    a whole frame (:meth:`luminance`) has them refined at its own time.
    """

    def __init__(self, renderer: Renderer, spp: int, start: float, end: float,
                 edge_spp: int = 0):
        self._renderer, self._spp = renderer, spp
        self.scene, self.camera = renderer.scene, renderer.camera
        # shared by the sampler and per-event depth
        self.depth = RecentDepth(renderer.depth, render_many=renderer.depth_many)
        self.shader = self.fine_shader = None
        self.edge_samples = 0                         # pixels refined by luminance(), so far
        if renderer.variant != "scalar_rgb":
            from sim.shader import EventShader

            self.shader = EventShader(renderer, spp, t0=start, t1=end)
            if edge_spp > spp:
                self.fine_shader = EventShader(renderer, edge_spp, t0=start, t1=end)

    def luminance(self, t: float) -> np.ndarray:
        """The whole frame at ``t``, (H, W) float32, linear; the pixels an edge crosses at
        ``t`` from the fine shader where there is one. A pixel's value depends on ``t`` only
        (which renderer took it too), so a resumed run renders the same frames."""
        if self.shader is None:
            return self._renderer.luminance(t, spp=self._spp)
        frame = self.shader.frame(t)
        if self.fine_shader is not None:
            self.edge_samples += int(np.count_nonzero(refine_edges(
                frame, t, self.shader.geometry, self.fine_shader.luminance)))
        return frame


class _TimedCamera:
    """The event camera as :func:`sim.sampling.adaptive_samples` sees it (scene, camera,
    frames, depth), timing its renders."""

    def __init__(self, camera: _EventCamera) -> None:
        self._camera = camera
        self.scene, self.camera, self.shader = camera.scene, camera.camera, camera.shader
        self.seconds = 0.0

    @property
    def edge_samples(self) -> int:
        """Pixels the fine shader refined in :meth:`luminance`'s frames, so far."""
        return self._camera.edge_samples

    def luminance(self, t: float) -> np.ndarray:
        tick = time.perf_counter()
        try:
            with stage("event_render"):
                return self._camera.luminance(t)
        finally:
            self.seconds += time.perf_counter() - tick

    def depth(self, t: float) -> np.ndarray:
        tick = time.perf_counter()
        try:
            with stage("event_render"):
                return self._camera.depth(t)
        finally:
            self.seconds += time.perf_counter() - tick


class _ShaderSource:
    """:class:`sim.pixel_sampling.PixelSource` of a renderer's scene, timing its renders."""

    def __init__(self, camera: _EventCamera) -> None:
        self._camera = camera
        self.camera = camera.camera
        self.seconds = 0.0
        self.refines_edges = camera.fine_shader is not None

    def _timed(self, function, *args):
        tick = time.perf_counter()
        try:
            with stage("event_render"):
                return function(*args)
        finally:
            self.seconds += time.perf_counter() - tick

    def luminance(self, pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
        return self._timed(self._camera.shader.luminance, pixels, times)

    @property
    def pass_span_ns(self) -> int:
        """The longest span of times (ns) one :meth:`luminance_device` call takes: one pose
        table (:data:`sim.shader.POSE_TABLE_NODES` steps of the pose grid, less two for the
        ends' rounding), which bounds a pass of :func:`sim.pixel_sampling.pixel_blocks`."""
        from sim import shader

        return int((shader.POSE_TABLE_NODES - 2) * self._camera.shader.pose_step * 1e9)

    def luminance_device(self, pixels, times, between=None):
        """:meth:`sim.shader.EventShader.luminance_device`, evaluated (so that its time is
        the render's: Dr.Jit runs its launches asynchronously, this waits for them)."""
        import drjit as dr

        def shade():
            values = self._camera.shader.luminance_device(pixels, times, between)
            dr.eval(values)
            dr.sync_thread()
            return values

        return self._timed(shade)

    def subsamples(self, t: float) -> np.ndarray:
        return self._timed(self._camera.shader.subsamples, t)

    def subsamples_many(self, times: np.ndarray) -> list[np.ndarray]:
        return self._timed(self._camera.shader.subsamples_many, times)

    def geometry(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self._timed(self._camera.shader.geometry, t)

    def fine_luminance(self, pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
        return self._timed(self._camera.fine_shader.luminance, pixels, times)

    def depth(self, t: float) -> np.ndarray:
        return self._timed(self._camera.depth, t)

    def depth_many(self, times: np.ndarray) -> list[np.ndarray]:
        return self._timed(self._camera.depth.many, times)

    def camera_velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self._camera.scene.trajectory.camera_velocity(t)


def _choose_sampler(scene: Scene, variant: str, requested: str | None) -> tuple[str, str]:
    """The event camera's sampler (see :func:`sim.simulate.simulate`) and why it was chosen."""
    if requested == "pixel" and variant == "scalar_rgb":
        raise ParameterError("{sampler} pixel: the per-pixel sampler traces batches of rays "
                             "and needs a JIT variant (llvm_ad_rgb or cuda_ad_rgb); scalar_rgb "
                             "renders whole frames only ({sampler} frame)", sampler="sampler")
    if requested is not None:
        chosen, why = requested, "as asked (--sampler)"
    elif scene.is_dynamic:
        chosen, why = "frame", "the scene has moving objects"
    elif variant == "scalar_rgb":
        chosen, why = "frame", "scalar_rgb cannot trace per-pixel batches"
    else:
        chosen, why = "pixel", "static scene"
    return chosen, why


@contextmanager
def _event_stage(scene: Scene, folder: Path, formats: tuple[str, ...], positions: dict,
                 seconds: float, progress: bool, depth: EventDepth | None, timings: dict,
                 cpu_render: bool = True):
    """The event stage's progress bar and event writers (resumed at ``positions``, behind
    :class:`sim.event_depth.EventOutputs`, which adds ``depth`` where a file holds it, and the
    per-event labels with it: :mod:`sim.event_labels`), with numba's kernels on one thread
    where the renders run on the CPU (``cpu_render``); all undone on exit."""
    camera = scene.camera
    bar = progress_stage(total=round(seconds, 6), desc=f"events {scene.name}", unit="s",
                         noun="s simulated", enabled=progress,
                         bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} s "
                                    "[{elapsed}<{remaining}{postfix}]")
    with ExitStack() as stack:
        stack.callback(bar.close)
        # On the CPU (llvm), Dr.Jit's worker threads stay busy between renders, and numba's
        # parallel regions then fight them for the cores (14 ms instead of 0.6 ms a step at
        # 240x180): interleaved with rendering, the emulator and the sampler's kernels run on one
        # thread. On a GPU (cuda) the cores are free for them.
        if cpu_render:
            threads = numba.get_num_threads()
            numba.set_num_threads(1)
            stack.callback(numba.set_num_threads, threads)
        writers: dict[str, H5EventWriter | TextEventWriter] = {}
        labels = _labelled(formats, depth is not None)
        if "h5" in formats and depth is None:
            writers["h5"] = stack.enter_context(H5EventWriter(
                folder / "events.h5", camera.width, camera.height, resume=positions.get("h5")))
        elif "h5" in formats:
            writers["h5"] = stack.enter_context(H5EventDepthWriter(
                folder / "events.h5", camera.width, camera.height, resume=positions.get("h5"),
                labels=labels))
        if "txt" in formats:
            writers["txt"] = stack.enter_context(TextEventWriter(
                folder / "events.txt", resume=positions.get("txt")))
        if DEPTH_TXT in formats:
            writers[DEPTH_TXT] = stack.enter_context(TextEventDepthWriter(
                folder / event_file_name(DEPTH_TXT), resume=positions.get(DEPTH_TXT)))
        if labels and ("txt" in formats or DEPTH_TXT in formats):
            writers[LABELS_TXT] = stack.enter_context(TextEventLabelWriter(
                folder / LABELS_TXT_NAME, resume=positions.get(LABELS_TXT)))
        offset_ns = round(scene.rig.events_offset * 1e9)
        if offset_ns:
            writers = {fmt: _OnEventClock(writer, offset_ns) for fmt, writer in writers.items()}
        with_depth = depth is not None and ("h5" in formats or DEPTH_TXT in formats)
        yield bar, EventOutputs(writers, depth if with_depth or labels else None, timings,
                                labels=labels)


def _labelled(formats: tuple[str, ...], motion_truth: bool) -> bool:
    """Whether the event files get per-event labels (:mod:`sim.event_labels`): with the
    motion truth (the object ids are found beside the per-event depth, by its
    :class:`sim.event_depth.EventDepth`), in ``events.h5`` and beside a text format."""
    return motion_truth and any(fmt in formats for fmt in ("h5", "txt", DEPTH_TXT))


def _event_info(params: EventParams, formats: tuple[str, ...], sampling: SamplingParams,
                scene: Scene, count: int, on: int, motion_truth: bool = True,
                own_rays: bool = True) -> dict:
    """The part of ``sequence.json``'s ``events`` both samplers write alike (``own_rays``:
    the labels' object ids from each event's own ray, :mod:`sim.event_labels`)."""
    return {
        "count": count,
        "on": on,
        "off": count - on,
        "files": [event_file_name(fmt) for fmt in formats],
        "depth": event_depth_record(formats),
        "labels": (event_labels_record(formats, [obj.name for obj in scene.objects], own_rays)
                   if _labelled(formats, motion_truth) else None),
        "contrast_on": params.contrast_on,
        "contrast_off": params.contrast_off,
        "log_eps": params.log_eps,
        "luminance_unit": "cd/m^2",
        "responsivity_a_per_cd_m2": params.responsivity,
        "dark_current_a": params.dark_current,
        "seed": params.seed,
        "noise": asdict(params.noise),
        "sampling": asdict(sampling),
        "event_spp": scene.render.event_spp,
    }


# --- the two samplers --------------------------------------------------------------------------

@dataclass
class _Step:
    """What a sampler gives the driver at each step: the events up to ``t`` (None or empty: none)
    and the state a checkpoint saves after them.

    Attributes
    ----------
    t : float, seconds
        The time the step ends at.
    events : structured ndarray or None
        The step's events (:data:`sim.events.EVENT_DTYPE`).
    causes : (N,) uint8 ndarray or None
        Each event's cause (:attr:`sim.events.EventEmulator.last_causes`).
    sample : Sample
        The sample at ``t`` (its luminance and log intensity, (H, W) float32) a resumed run
        continues from.
    pending : bool
        More of the same sampling interval follows at once (a frame sample with
        ``tail_pending``): no checkpoint may be taken here.
    extra : dict of str to ndarray
        Arrays a checkpoint saves beside the sample (the per-pixel sampler's
        ``observed_rates``).
    resumable : bool
        The sampler can continue from here (False inside a pass of the per-pixel sampler's
        wavefront): no checkpoint may be taken otherwise.
    """

    t: float
    events: np.ndarray | None
    sample: Sample
    pending: bool = False
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    causes: np.ndarray | None = None
    resumable: bool = True


class _FrameSampler:
    """Whole frames at one adaptive rate (:func:`sim.sampling.adaptive_samples`), each frame
    handed to :class:`sim.events.EventEmulator`.

    Parameters
    ----------
    camera : _EventCamera
        The event camera whose frames are rendered.
    """

    name = "frame"
    emulator_type = EventEmulator
    emulator_kernel = "auto"
    stats_type = SamplingStats

    def __init__(self, camera: _EventCamera) -> None:
        self._camera = _TimedCamera(camera)
        self._after: Sample | None = None

    @property
    def render_seconds(self) -> float:
        """Seconds spent rendering (frames and the sampler's depth maps), so far."""
        return self._camera.seconds

    def resume(self, saved: tuple[dict, dict] | None) -> float | None:
        """Continue after the checkpoint's sample (None: a fresh start); return its time."""
        if saved is None:
            return None
        arrays, state = saved
        self._after = Sample.from_state(state["sample"], arrays["sample_luminance"],
                                        arrays["sample_log"])
        return self._after.t

    def steps(self, emulator: EventEmulator, start: float, end: float, contrast: np.ndarray,
              params: EventParams, sampling: SamplingParams, stats: SamplingStats
              ) -> Iterator[_Step]:
        """Render frames over ``[start, end]`` and emulate their events, one step a frame."""
        refined = stats.edge_samples - self._camera.edge_samples   # a resumed run's, before
        for sample in adaptive_samples(self._camera, start, end, contrast, params.log_eps,
                                       sampling, stats, after=self._after):
            stats.edge_samples = refined + self._camera.edge_samples
            if emulator.time_ns is None:
                emulator.start(sample.log, sample.t, sample.luminance)
                chunk, causes = None, None
            else:
                chunk = emulator.advance(sample.log, sample.t, sample.luminance)
                causes = emulator.last_causes
            yield _Step(sample.t, chunk, sample, pending=sample.tail_pending, causes=causes)

    @staticmethod
    def progress(stats: SamplingStats, why: str) -> str:
        return f"frame sampler ({why}): {stats.renders:,} renders"

    def record(self, stats: SamplingStats, sampling: SamplingParams, contrast: np.ndarray,
               why: str) -> dict:
        """``sequence.json``'s ``events`` entries of this sampler."""
        return {
            "sampler": "frame",
            "sampler_reason": why,
            "renders": stats.renders,
            "full_renders": stats.renders,
            "pixel_samples": 0,
            "edge_samples": stats.edge_samples,
            "samples": stats.accepted,
            "midpoint_renders": stats.refined,
            "step_intervals": stats.steps,
            "intervals_at_max_rate": stats.at_max_rate,
            "intervals_at_max_rate_note": AT_MAX_RATE_NOTE,
            "sampling_warning": max_rate_warning(stats.at_max_rate, max(stats.accepted - 1, 0),
                                                 sampling.max_rate,
                                                 sampling.lam * float(contrast.min())),
            "shading": (_SHADING if self._camera.shader is not None
                        else "mitsuba direct integrator"),
        }


class _PixelSampler:
    """Each pixel at its own adaptive times (:func:`sim.pixel_sampling.pixel_blocks`, which
    emulates a pixel's events as it samples it), one step a block; checkpoints at the ends of
    passes (:attr:`sim.sampling.SamplingParams.wavefront`).

    Parameters
    ----------
    camera : _EventCamera
        The event camera (on a JIT variant: its shader traces the pixels' rays).
    """

    name = "pixel"
    emulator_type = PixelEventEmulator
    emulator_kernel = "auto"
    """The emulator's kernel (:class:`sim.events.EventEmulator`): ``auto`` runs Dr.Jit's on
    ``cuda``, fed the device path's samples where they are
    (:meth:`sim.pixel_sampling.PixelEventEmulator.advance_device`), numba's on the CPU."""
    stats_type = PixelSamplingStats
    on_device = True
    """Build and refine the blocks' samples on the renders' Dr.Jit device
    (:func:`sim._drjit_sampling.device_block`); False: the reference path (numba, NumPy)."""

    def __init__(self, camera: _EventCamera) -> None:
        self._source = _ShaderSource(camera)
        self._after: tuple[float, np.ndarray] | None = None
        variant = camera._renderer.variant
        self._device = (("cuda" if variant.startswith("cuda") else "llvm")
                        if self.on_device and camera.shader is not None else None)

    @property
    def render_seconds(self) -> float:
        """Seconds spent rendering, so far."""
        return self._source.seconds

    def resume(self, saved: tuple[dict, dict] | None) -> float | None:
        """Continue after the checkpoint's block (None: a fresh start); return its end time."""
        if saved is None:
            return None
        arrays, state = saved
        self._after = (state["sample"]["t"], arrays["observed_rates"])
        return self._after[0]

    def steps(self, emulator: PixelEventEmulator, start: float, end: float,
              contrast: np.ndarray, params: EventParams, sampling: SamplingParams,
              stats: PixelSamplingStats) -> Iterator[_Step]:
        """Sample every pixel over ``[start, end]`` with its events, one step a block."""
        for block in pixel_blocks(self._source, emulator, start, end, contrast, params.log_eps,
                                  sampling, stats, after=self._after,
                                  edges=self._source.refines_edges, device=self._device):
            # Inside a pass of the wavefront no checkpoint: a resumed run starts a pass.
            yield _Step(block.t, block.events, Sample(block.t, block.luminance, block.log, 0.0,
                                                      True),
                        resumable=block.floor is not None,
                        extra={} if block.floor is None else {"observed_rates": block.floor},
                        causes=emulator.last_causes)     # of the block just emulated

    @staticmethod
    def progress(stats: PixelSamplingStats, why: str) -> str:
        return (f"per-pixel sampler ({why}): {stats.full_renders:,} frames, "
                f"{stats.pixel_samples:,} pixel samples")

    @staticmethod
    def record(stats: PixelSamplingStats, sampling: SamplingParams, contrast: np.ndarray,
               why: str) -> dict:
        """``sequence.json``'s ``events`` entries of this sampler."""
        return {
            "sampler": "pixel",
            "sampler_reason": why,
            "renders": stats.full_renders,
            "full_renders": stats.full_renders,
            "pixel_samples": stats.pixel_samples,
            "edge_samples": stats.edge_samples,
            "midpoint_samples": stats.midpoint_samples,
            "depth_renders": stats.depth_renders,
            "blocks": stats.blocks,
            "intervals": stats.intervals,
            "step_intervals": stats.steps,
            "intervals_at_max_rate": stats.at_max_rate,
            "intervals_at_max_rate_note": PIXEL_AT_MAX_RATE_NOTE,
            "sampling_warning": max_rate_warning(stats.at_max_rate, stats.intervals,
                                                 sampling.max_rate,
                                                 sampling.lam * float(contrast.min())),
            "shading": _SHADING,
        }


_SAMPLERS = {sampler.name: sampler for sampler in (_FrameSampler, _PixelSampler)}


# --- the driver --------------------------------------------------------------------------------

def _simulate_events(scene: Scene, renderer: Renderer, folder: Path, start: float, end: float,
                     params: EventParams, sampling: SamplingParams, formats: tuple[str, ...],
                     checkpoint: _Checkpoint, progress: bool, timings: dict,
                     sampler: str = "frame", why: str = "as asked",
                     event_depth: bool = True) -> dict:
    """Drive the emulator with ``sampler``'s samples over [start, end]; stream the events out.

    Continues from the checkpoint's event state when there is one, and saves that state at
    step boundaries the sampler allows (see :meth:`_Checkpoint.due`).

    Parameters
    ----------
    sampler : {"frame", "pixel"}
        :class:`_FrameSampler` or :class:`_PixelSampler`.
    why : str
        Why that sampler was chosen (shown and recorded).

    Returns
    -------
    dict
        ``sequence.json``'s ``events`` (less its ``span_s``).
    """
    cam = scene.camera
    kind = _SAMPLERS[sampler]
    emulator = kind.emulator_type((cam.height, cam.width), params, kind.emulator_kernel)
    stats, count, on, positions, saved = _restore_events(checkpoint, emulator, kind.stats_type)
    contrast = np.minimum(emulator.c_on, emulator.c_off)      # each pixel's own threshold
    # Edges at more sub-samples need the shader (a JIT variant); scalar_rgb says so.
    edge_spp = scene.render.edge_spp if renderer.variant != "scalar_rgb" else 0
    event_camera = _EventCamera(renderer, scene.render.event_spp, start, end, edge_spp)
    source = kind(event_camera)
    resumed_at = source.resume(saved)
    # Per-event labels' object ids: each event's own ray (a static scene, a JIT variant), else
    # the bracketing renders' (sim.event_labels).
    labelled = _labelled(formats, event_depth)
    own_rays = labelled and not scene.is_dynamic and renderer.variant != "scalar_rgb"
    objects_at = renderer.object_ids_at if own_rays else None
    objects = RecentDepth(renderer.object_ids, np.uint16) if labelled and not own_rays else None
    with _event_stage(scene, folder, formats, positions, end - start, progress,
                      EventDepth(event_camera.depth, start if resumed_at is None else resumed_at,
                                 objects=objects, objects_at=objects_at)
                      if event_depth else None,
                      timings, cpu_render=not renderer.variant.startswith("cuda")
                      ) as (bar, writers), checkpoint.in_background():
        # The sampler's step splits into its renders (event_render), the emulator's own time
        # (emulate) and the rest: choosing the samples (event_sample).
        with stage("emulate_compile"):
            timings["emulate_compile"] += emulator.warm_up()
        since, saved_at = 0, time.perf_counter()
        tick = time.perf_counter()
        rendered, emulated = source.render_seconds, emulator.seconds
        # Profiled (sim.profile): the renders' and the emulator's kernels are their own stages
        # inside the step; what else the step runs is the sampler's.
        with stage("event_sample"):
            for step in source.steps(emulator, start, end, contrast, params, sampling, stats):
                tock = time.perf_counter()
                render = source.render_seconds - rendered
                emulate = emulator.seconds - emulated
                timings["event_render"] += render
                timings["emulate"] += emulate
                timings["event_sample"] += (tock - tick) - render - emulate
                with stage("event_write"):
                    writers.write(step.events, step.t, pending=step.pending,
                                  causes=step.causes)
                if step.events is not None and len(step.events):
                    count += len(step.events)
                    on += int(np.count_nonzero(step.events["p"] > 0))
                tick = time.perf_counter()
                timings["event_write"] += tick - tock
                since += 1
                # Only where the sampler can be restarted from this step (no tail pending,
                # not inside a pass).
                if not step.pending and step.resumable \
                        and checkpoint.due(since, tick - saved_at):
                    with stage("checkpoint"):
                        checkpoint.save_events(step.sample, emulator, stats, count, on,
                                               writers.writers, **step.extra)
                    since, saved_at = 0, time.perf_counter()
                    timings["checkpoint"] += saved_at - tick
                    tick = saved_at
                rendered, emulated = source.render_seconds, emulator.seconds
                bar.n = round(step.t - start, 6)
                bar.set_postfix_str(f"{count:,} events, {source.progress(stats, why)}",
                                    refresh=False)
                bar.update(0)
    ignored = (f"[render] edge_spp = {scene.render.edge_spp} needs a JIT variant's shader "
               f"(llvm_ad_rgb or cuda_ad_rgb): {renderer.variant} rendered every pixel at "
               f"event_spp = {scene.render.event_spp}"
               ) if scene.render.edge_spp and not edge_spp else None
    return {**_event_info(params, formats, sampling, scene, count, on, event_depth, own_rays),
            **source.record(stats, sampling, contrast, why),
            "edge_spp": edge_spp, "edge_spp_warning": ignored,
            "emulator_kernel": emulator.kernel}
