"""How much memory a simulation needs, estimated before any work, and the refusal of one that
cannot fit this machine.

The renders hold every sample of a pass at once (Mitsuba's wavefront, with the per-pixel
sampler's jitter and rays): the peak grows with pixels x samples per pixel. Measured on
``evfuse simulate slider_close --duration 0.05`` (240x180, llvm_ad_rgb): peak resident memory
419 MB at spp 1, 582 MB at 64, 1492 MB at 256, 5121 MB at 1024, i.e. about 100-106 bytes per
extra sample; :data:`BYTES_PER_SAMPLE` rounds it up.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

from sim.validation import ParameterError

__all__ = ["BASE_BYTES", "BYTES_PER_SAMPLE", "MAX_SENSOR_SIDE", "check_simulation_memory",
           "device_memory", "is_out_of_memory", "machine_memory", "simulation_bytes"]

BYTES_PER_SAMPLE = 112
"""Peak bytes per pixel sample of a render pass (measured 100-106, see the module's notes)."""
BASE_BYTES = 512 * 2**20
"""Peak bytes of a simulation apart from its samples (Python, Mitsuba, Dr.Jit: 419 MB measured
at 240x180 and spp 1)."""
MAX_SENSOR_SIDE = 65536
"""Largest sensor width or height, px (the sensor noise model's pixel indices are 16-bit)."""


def simulation_bytes(width: int, height: int, spp: int) -> int:
    """Estimated peak memory of a simulation, bytes.

    Parameters
    ----------
    width, height : int, px
        The largest camera's sensor.
    spp : int
        The most samples per pixel of any render pass (frames ``spp``, ``event_spp``,
        ``edge_spp``).

    Returns
    -------
    int
        :data:`BASE_BYTES` + width x height x spp x :data:`BYTES_PER_SAMPLE`.
    """
    return BASE_BYTES + int(width) * int(height) * int(spp) * BYTES_PER_SAMPLE


def machine_memory() -> int:
    """This machine's physical memory, bytes (``SC_PHYS_PAGES`` x ``SC_PAGE_SIZE``)."""
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_simulation_memory(width: int, height: int, spp: int, *, at_least: bool = False,
                            sensor: str = "sensor", samples: str = "spp") -> int:
    """Refuse a simulation that cannot fit this machine's memory, before any work.

    Parameters
    ----------
    width, height : int, px
    spp : int
        Samples per pixel of the largest render pass.
    at_least : bool
        Say that the estimate is a lower bound (the samples per pixel are not known yet).
    sensor, samples : str
        The caller's names of the sensor size and the samples per pixel (placeholders a command
        line renames to its flags).

    Returns
    -------
    int
        The estimate, bytes.

    Raises
    ------
    ParameterError
        A side outside 1..:data:`MAX_SENSOR_SIDE`, or an estimate above :func:`machine_memory`.
    """
    if not (1 <= width <= MAX_SENSOR_SIDE and 1 <= height <= MAX_SENSOR_SIDE):
        raise ParameterError(f"{{{sensor}}} {width}x{height}: each side must be 1 to "
                             f"{MAX_SENSOR_SIDE} px", **{sensor: sensor})
    need, have = simulation_bytes(width, height, spp), machine_memory()
    if need > have:
        raise ParameterError(
            f"a {width}x{height} sensor at {spp} samples per pixel needs "
            f"{'at least ' if at_least else ''}about {need / 2**30:.1f} GiB of memory, more than "
            f"this machine's {have / 2**30:.1f} GiB: use a smaller {{{sensor}}} or fewer "
            f"{{{samples}}}", **{sensor: sensor, samples: samples})
    return need


_OUT_OF_MEMORY = ("out of memory", "cuda_error_out_of_memory", "cudaerrormemoryallocation")
"""How Dr.Jit (``jit_malloc(): out of memory! Could not allocate N bytes of device memory.``)
and CUDA say that an allocation failed, lower case."""


def is_out_of_memory(error: BaseException) -> bool:
    """Whether ``error``, or an error it was raised from, is an allocation that failed
    (:class:`MemoryError`, or Dr.Jit's or CUDA's out-of-memory message)."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        if isinstance(error, MemoryError):
            return True
        if any(key in str(error).lower() for key in _OUT_OF_MEMORY):
            return True
        error = error.__cause__ or error.__context__
    return False


@contextmanager
def device_memory(scene, sampling=None, sampler: str | None = None) -> Iterator[None]:
    """Turn an out-of-memory inside the renders into one line that says what to lower.

    Parameters
    ----------
    scene : sim.scene.Scene
        Its event camera's sensor and samples per pixel are named.
    sampling : sim.sampling.SamplingParams, optional
        The per-pixel sampler's block length (``1 / min_rate``) and blocks a pass
        (``wavefront``) are named.
    sampler : {"pixel", "frame"} or None
        The event camera's sampler (None: no events).

    Raises
    ------
    ParameterError
        In place of an allocation that failed (:func:`is_out_of_memory`): the device, the
        sensor's resolution, the samples per pixel and the block length, and what to lower
        (``{spp}``, ``{event_spp}``, ``{sensor}``, ``{min_rate}``, ``{wavefront}``
        placeholders).
    """
    try:
        yield
    except Exception as exc:
        if not is_out_of_memory(exc):
            raise
        import sys

        mitsuba = sys.modules.get("mitsuba")
        variant = mitsuba.variant() if mitsuba is not None else None
        where = "the GPU" if variant and variant.startswith("cuda") else "this machine"
        camera, render = scene.camera, scene.render
        block, lower = "", ""
        if sampler == "pixel" and sampling is not None:
            blocks = sampling.wavefront
            held = "a block" if blocks == 1 else f"a pass of {blocks} blocks"
            block = (f", the per-pixel sampler's blocks of {1e3 / sampling.min_rate:g} ms "
                     f"(all pixels' samples of {held} are held at once)")
            lower = (", or shorten the blocks with a higher {min_rate}" if blocks == 1 else
                     ", or take fewer blocks a pass with a lower {wavefront} or shorter ones "
                     "with a higher {min_rate}")
        raise ParameterError(
            f"{where} ran out of memory ({variant}) rendering a {camera.width}x{camera.height} "
            f"sensor at {render.spp} samples per pixel for frames and {render.event_spp} for "
            f"events{block}: lower the {{sensor}}, the {{spp}} or {{event_spp}}{lower}"
            + f" ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})",
            sensor="sensor size", spp="spp", event_spp="[render] event_spp",
            min_rate="sampling min_rate", wavefront="sampling wavefront") from None
