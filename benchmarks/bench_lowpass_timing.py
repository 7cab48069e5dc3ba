"""Event timing under the photoreceptor low-pass filter (issue 14), printed as a table.

1. The issue's case: a 1-log-unit ramp over 1 ms at full cutoff (200 Hz, tau = 0.8 ms), sampled
   where the frame sampler samples it (the ramp's two ends, then 10 ms later), against 1 us
   sampling of the same pixel.
2. The cutoff varying along the ramp: a 1.1-log-unit ramp over 1.1 ms from luminance 1, 0.3,
   0.1 and 0.03 (cutoff from 200 Hz down to its floor of 14.5 Hz), sampled once over the ramp
   and every lam C = 0.1 log units (the samplers' bound at the defaults), against the filter
   integrated with its cutoff varying continuously (SciPy, rtol 1e-12). The first column shows
   what the logarithmic mean of the end cutoffs leaves when one interval spans the whole ramp;
   the second what remains at the sampler's bound.

Run: ``.venv/bin/python benchmarks/bench_lowpass_timing.py`` (a few seconds).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim.events import EventParams  # noqa: E402
from sim.noise import NoiseParams, cutoff_frequency  # noqa: E402
from sim.pixel_sampling import PixelEventEmulator  # noqa: E402
from tests.conftest import filtered_reference_events  # noqa: E402

NOISE = NoiseParams(cutoff_hz=200.0)                    # the filter alone, no noise


def _events(level, times_ns):
    """Events of one pixel with log intensity ``level(t)``, luminance exp(level), sampled at
    ``times_ns``."""
    levels = np.array([level(t * 1e-9) for t in times_ns])
    emulator = PixelEventEmulator((1, 1), EventParams(noise=NOISE))
    emulator.start(levels[:1].reshape(1, 1), times_ns[0] * 1e-9, np.exp(levels[:1]).reshape(1, 1))
    return emulator.advance_samples(np.zeros(len(times_ns), np.int64), np.asarray(times_ns),
                                    levels, np.exp(levels), int(times_ns[-1]),
                                    np.exp(levels[-1:]).reshape(1, 1))


def main() -> None:
    def ramp(t):
        return min(max(t / 1e-3, 0.0), 1.0)

    coarse = _events(ramp, np.array([0, 1_000_000, 11_000_000]))["t"]
    dense = _events(ramp, np.arange(11001) * 1000)["t"]
    print("1. 1-log-unit ramp over 1 ms, cutoff 200 Hz")
    print(f"   3 samples: {np.round(coarse / 1e6, 4).tolist()} ms")
    print(f"   1 us:      {np.round(dense / 1e6, 4).tolist()} ms")
    print(f"   largest difference {np.abs(coarse - dense).max() / 1e3:.3f} us")
    print("2. cutoff varying along a 1.1-log-unit ramp over 1.1 ms: largest timing error, us")
    print("   luminance | cutoff start-end, Hz | one interval | every 0.1 log unit")
    for base in (1.0, 0.3, 0.1, 0.03):
        start = math.log(base)

        def u(t, start=start):
            return start + min(max(t / 1e-3, 0.0), 1.1)

        def f(t, u=u):
            return float(cutoff_frequency(np.full((1, 1), math.exp(u(t))), NOISE)[0, 0])

        want = np.array([t for t, _ in filtered_reference_events(
            u, lambda t, f=f: 2 * math.pi * f(t), 0.04, 0.2, start, step=2e-7)]) * 1e9
        tail = [2_000_000, 5_000_000, 20_000_000, 40_000_000]
        errors = []
        for times in (np.r_[0, 1_100_000, tail], np.r_[np.arange(12) * 100_000, tail]):
            got = _events(u, times)["t"]
            errors.append(np.abs(got - want).max() / 1e3 if len(got) == len(want) else math.nan)
        print(f"   {base:9g} | {f(0):7.1f} - {f(2e-3):6.1f}        | {errors[0]:12.3f} | "
              f"{errors[1]:.3f}")


if __name__ == "__main__":
    main()
