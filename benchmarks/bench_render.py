"""Render time per frame (luminance + depth) against a bare ``mi.render`` loop on the same scene.

For each resolution the same loaded scene is timed two ways in the same process:
- bare: ``mi.render(scene, seed, spp)`` in a loop with the pose fixed at a trajectory pose
  (Mitsuba's own cost for the same view);
- evfuse: ``Renderer.render(t)`` along the trajectory: pose update through the parameter API,
  the same ``mi.render``, the conversion to NumPy, and the pixel-centre depth pass.
The overhead is evfuse / bare - 1 (the goal is under 15 %). Results are printed as a table and
written to ``benchmarks/results/render.json``.

Run: ``make bench`` or ``.venv/bin/python benchmarks/bench_render.py [--frames N]``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from scenes import resolve_scene
from sim.camera import camera_preset
from sim.render import Renderer
from sim.scene import load_scene

RESOLUTIONS = {"240x180": "davis240c", "640x480": "vga"}


def _time_loop(step, frames: int) -> float:
    step(0)                                                        # compile / warm up
    start = time.perf_counter()
    for i in range(frames):
        step(i)
    return (time.perf_counter() - start) / frames


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="slider_close")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3, help="best of N alternating runs")
    args = parser.parse_args(argv)
    rows = []
    for label, preset in RESOLUTIONS.items():
        scene = load_scene(resolve_scene(args.scene))
        scene = replace(scene, camera=camera_preset(preset))
        renderer = Renderer(scene, spp=args.spp)
        import mitsuba as mi

        mscene = renderer.mitsuba_scene
        times = np.linspace(0.0, scene.duration, args.frames)

        # The bare loop renders the same view (the trajectory's pose at mid-sequence): a camera
        # left at its initial identity pose may look at nothing, which is cheaper to render.
        renderer.render(float(times[len(times) // 2]))

        def bare(i, mscene=mscene, renderer=renderer):
            np.asarray(mi.render(mscene, seed=renderer.seed, spp=renderer.spp))

        def ours(i, renderer=renderer, times=times):
            renderer.render(float(times[i]))

        bare_s, ours_s = [], []
        for _ in range(args.repeats):                              # alternate to share drift
            bare_s.append(_time_loop(bare, args.frames))
            ours_s.append(_time_loop(ours, args.frames))
        b, o = min(bare_s), min(ours_s)
        rows.append({"resolution": label, "variant": renderer.variant, "spp": renderer.spp,
                     "bare_ms": 1e3 * b, "evfuse_ms": 1e3 * o, "overhead": o / b - 1})
    print(f"\nscene {args.scene}, {args.frames} frames, best of {args.repeats}")
    print(f"{'resolution':>10} {'variant':>12} {'spp':>4} {'bare mi.render':>15} "
          f"{'evfuse lum+depth':>17} {'overhead':>9}")
    for r in rows:
        print(f"{r['resolution']:>10} {r['variant']:>12} {r['spp']:>4} {r['bare_ms']:>12.2f} ms "
              f"{r['evfuse_ms']:>14.2f} ms {100 * r['overhead']:>8.1f}%")
    out = Path(__file__).resolve().parent / "results" / "render.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"scene": args.scene, "frames": args.frames, "rows": rows},
                              indent=2))
    print(f"written to {out}")
    return {"rows": rows}


if __name__ == "__main__":
    main()
