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

from sim.validation import ParameterError

__all__ = ["BASE_BYTES", "BYTES_PER_SAMPLE", "MAX_SENSOR_SIDE", "check_simulation_memory",
           "machine_memory", "simulation_bytes"]

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
