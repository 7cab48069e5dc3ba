"""Radiometry on the HDR twin: how much of slider_hdr_close the event camera can see.

1. Luminance statistics of ``slider_hdr_close`` at 240x180 (4 spp) at t = 0 (the view in the
   dark half), 3.25 s (in the spot) and 5.5 s (both), and the share of neighbouring pixel
   pairs (horizontal and vertical) whose log intensity ``log(Y + log_eps)`` differs by more
   than C = 0.2: an upper bound on the pixels an edge sweeping past can fire.
2. Events per pixel per second of the ideal sensor (C = 0.2) on a 48x36 crop of the DAVIS240C
   (its fx, fy) over 0.2 s rendered at 1 kHz, in the fill light (t = 0.05 s) and in the spot
   (t = 4.05 s): the poster's texture repeats every 0.4 m, so both windows see the same
   texture moving the same way (``tests/test_radiometry.py`` asserts the ratio is at most 3),
   with the ``ideal`` and the ``realistic`` sensor (seed 0).

``log_eps`` is ``EventParams().log_eps`` (the dark current in cd/m^2 since issue 14; 1e-3 of an
arbitrary scale before), or ``--eps``. Run: ``.venv/bin/python benchmarks/bench_radiometry.py``.
Prints only (no timing is asserted).
"""

from __future__ import annotations

import argparse
import re

import numpy as np

from scenes import resolve_scene
from sim.events import EventParams, emulate_events, log_intensity
from sim.render import Renderer
from sim.scene import load_scene, parse_scene

CROP = "width = 48\nheight = 36\nfx = 199.092366542\nfy = 198.82882047\ncx = 23.5\ncy = 17.5\n"


def pair_share(luminance: np.ndarray, eps: float, contrast: float = 0.2) -> float:
    """Share of horizontal and vertical neighbour pairs whose L differs by more than C."""
    level = log_intensity(luminance, eps)
    steps = np.concatenate([np.abs(np.diff(level, axis=0)).ravel(),
                            np.abs(np.diff(level, axis=1)).ravel()])
    return float(np.mean(steps > contrast))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eps", type=float, default=EventParams().log_eps)
    args = parser.parse_args(argv)
    eps = args.eps
    path = resolve_scene("slider_hdr_close")
    renderer = Renderer(load_scene(path), spp=4)
    print(f"slider_hdr_close, log_eps = {eps:.4g}")
    for t in (0.0, 3.25, 5.5):
        y = renderer.luminance(t).astype(np.float64)
        print(f"  t = {t:4.2f} s: Y median {np.median(y):.3g}, 1st pct {np.percentile(y, 1):.3g}, "
              f"99th pct {np.percentile(y, 99):.3g}; {100 * pair_share(y, eps):.2f} % of "
              f"neighbour pairs differ by more than C = 0.2")
    text, swapped = re.subn(r'preset = "davis240c"\n', CROP, path.read_text())
    assert swapped == 1
    crop = Renderer(parse_scene(text), spp=4)
    windows = {}
    for name, t0 in (("dark half", 0.05), ("spot", 4.05)):
        times = t0 + np.arange(201) * 1e-3
        windows[name] = (times, np.stack([crop.luminance(t) for t in times]))
    for preset in ("ideal", "realistic"):
        params = EventParams(log_eps=eps, noise=EventParams.preset(preset).noise)
        rates = {}
        for name, (times, luminance) in windows.items():
            events = emulate_events(log_intensity(luminance, eps), times, params)
            rates[name] = len(events) / (0.2 * 48 * 36)
            print(f"  48x36 crop, {preset} sensor, {name} ({times[0]:.2f}-{times[-1]:.2f} s): "
                  f"median Y {np.median(luminance):.3g}, {rates[name]:.2f} events per pixel "
                  f"per second")
        print(f"  {preset} sensor, spot / dark half: {rates['spot'] / rates['dark half']:.2f}")


if __name__ == "__main__":
    main()
