"""What a Dask worker of ``evfuse generate`` does once, before its first job (:func:`warm_worker`
and its plugin, :func:`worker_plugin`), and the one on-disk kernel cache its workers share
(:func:`kernel_cache_dir`).

A worker process is started once and runs many jobs; each job is a
:func:`sim.simulate.simulate` in it (:func:`sim.dataset.run_job`). Once per worker, before its
first job, the plugin sets its Dr.Jit thread pool, imports Mitsuba and evfuse's stages, sets the
variant and simulates a few milliseconds of the sweep's first job, at its sensor size, into a
temporary folder: the variant's probe, the imports, numba's and Dr.Jit's kernels of that scene
are paid there, not in a job's own time. The worker stays warm: its interpreter, variant and
compiled kernels are kept for every job it runs.

Dr.Jit 1.5 keeps the kernels it compiles on disk, in ``DRJIT_CACHE_DIR`` when set, else in
``$HOME/.drjit`` (read once, when ``drjit`` is imported; ``DRJIT_CACHE_MAXSIZE`` bounds it). A
local cluster's workers are started with ``DRJIT_CACHE_DIR`` set to the folder this process
resolves, so that they all read and fill one cache: a kernel one worker compiled is loaded by
the others, and by the next ``generate``, instead of compiled again. A remote cluster's workers
must be started with the same variable pointing at one folder per machine (or a shared one).
"""

from __future__ import annotations

import os
import platform
import tempfile
import time
from pathlib import Path

__all__ = ["KERNEL_CACHE_ENV", "device_name", "kernel_cache_dir", "warm_worker", "worker_plugin"]

KERNEL_CACHE_ENV = "DRJIT_CACHE_DIR"
"""The environment variable Dr.Jit 1.5 reads for its on-disk kernel cache's folder."""
WARM_SECONDS = 0.002
"""Simulated seconds of a worker's warm-up run, or one frame's exposure if longer (one frame is
rendered whatever the length), or the job's own length if shorter."""

_warm: dict = {}
"""This process's warm-up record (:func:`warm_worker`), empty before it."""


def kernel_cache_dir() -> Path:
    """The folder Dr.Jit keeps compiled kernels in, for a process started with this
    environment: ``DRJIT_CACHE_DIR`` when set, else ``$HOME/.drjit``.

    Returns
    -------
    Path
        Absolute; it may not exist yet (Dr.Jit creates it).
    """
    folder = os.environ.get(KERNEL_CACHE_ENV)
    if folder:
        return Path(folder).expanduser().absolute()
    return Path(os.path.expanduser("~")).absolute() / ".drjit"


def device_name(variant: str) -> str:
    """What a variant renders on, in words: the CUDA device's name (device 0 of those visible,
    Dr.Jit's default) for ``cuda_ad_rgb``, else the CPU's model and core count.

    Parameters
    ----------
    variant : str
        A Mitsuba variant.

    Returns
    -------
    str
        E.g. ``NVIDIA H200`` or ``Intel(R) Xeon(R) ... (2 cores)``; ``unknown CUDA device`` when
        the CUDA driver does not answer.
    """
    if variant.startswith("cuda"):
        import ctypes

        try:
            cuda = ctypes.CDLL("libcuda.so.1")
            device, name = ctypes.c_int(), ctypes.create_string_buffer(256)
            if (cuda.cuInit(0) or cuda.cuDeviceGet(ctypes.byref(device), 0)
                    or cuda.cuDeviceGetName(name, len(name), device)):
                return "unknown CUDA device"
            return name.value.decode(errors="replace")
        except OSError:
            return "unknown CUDA device"
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as handle:
            model = next((line.split(":", 1)[1].strip() for line in handle
                          if line.startswith("model name")), model)
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{model} ({cores} cores)"


def warm_worker(job=None, variant: str | None = None) -> dict:
    """Warm this process for jobs: the variant set, evfuse's stages imported and, with ``job``,
    :data:`WARM_SECONDS` of it simulated (at least one frame) into a temporary folder that is
    removed. Done once per process; later calls return the first call's record.

    Parameters
    ----------
    job : sim.dataset.Job, optional
        The job whose scene and sensor compile the kernels (a sweep's first job).
    variant : str, optional
        The Mitsuba variant (default: :func:`sim.variant.use_variant`'s choice).

    Returns
    -------
    dict
        ``variant``, ``device`` (:func:`device_name`), ``kernel_cache`` (the folder),
        ``kernel_cache_files`` (its files after the warm-up), ``warm_s`` (seconds it took) and
        ``warm_error`` (the one-line error of a warm-up run that failed, which only leaves the
        job to compile its own kernels; "" when none).
    """
    if _warm:
        return dict(_warm)
    tick = time.perf_counter()
    # Mitsuba, Dr.Jit, numba, h5py and OpenCV imported here, once
    from sim.simulate import simulate
    from sim.variant import use_variant

    chosen = use_variant(variant)
    error = ""
    if job is not None:
        from sim.dataset._jobs import _ONE_AT_A_TIME, job_inputs, job_scene, scene_text

        try:
            with _ONE_AT_A_TIME, tempfile.TemporaryDirectory(prefix="evfuse-warm-") as tmp:
                text = scene_text(job, variant) if job.generated else None
                scene, kwargs = job_inputs(job, job_scene(job, text))
                duration = min(kwargs["duration"],
                               max(WARM_SECONDS, scene.frames.longest_exposure))
                simulate(scene, Path(tmp) / "warm", variant=variant, progress=False,
                         **dict(kwargs, duration=duration))
        except Exception as exc:                 # the job itself will say what is wrong
            error = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
    cache = kernel_cache_dir()
    _warm.update(variant=chosen, device=device_name(chosen), kernel_cache=str(cache),
                 kernel_cache_files=len(os.listdir(cache)) if cache.is_dir() else 0,
                 warm_s=time.perf_counter() - tick, warm_error=error)
    return dict(_warm)


def worker_plugin(threads: int | None, job=None, variant: str | None = None,
                  warm: bool = True):
    """A Dask worker plugin that sets each worker's Dr.Jit thread pool to ``threads`` and,
    with ``warm``, warms it (:func:`warm_worker`) once, as it starts (also a worker restarted
    after a crash).

    Parameters
    ----------
    threads : int or None
        Dr.Jit threads of each worker (None: left as the worker has it).
    job : sim.dataset.Job, optional
        The job the warm-up simulates a few milliseconds of.
    variant : str, optional
    warm : bool
        Warm the worker (False: the thread pool only).
    """
    from distributed import WorkerPlugin

    class EvfuseWorker(WorkerPlugin):
        name = "evfuse-worker"

        def setup(self, worker) -> None:
            if threads is not None:
                import drjit

                drjit.set_thread_count(threads)
            if warm:
                worker.evfuse_warm = warm_worker(job, variant)

    return EvfuseWorker()
