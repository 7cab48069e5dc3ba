"""EventShader: scattered samples at their own times, and whole frames, against ``mi.render``.

On one scene at its own resolution (boxes_6dof: 240x180, two lights, a turning camera), warm:
- ``luminance()`` of a random tenth of the pixels, each at its own random time in a window;
- ``luminance()`` of a per-pixel sampler's block: a million samples sorted by pixel (duplicates
  allowed), at random times within 10 ms;
- ``frame(t)`` against ``Renderer.luminance(t, spp)`` (``mi.render``) at the same spp;
- agreement of ``frame(t)`` with ``mi.render`` at 64 spp: image means, and the median per-pixel
  relative difference beside that of ``mi.render`` with another seed (its own noise).
Results are printed and written to ``benchmarks/results/shader.json``.

Run: ``make bench`` or ``.venv/bin/python benchmarks/bench_shader.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from scenes import resolve_scene
from sim.render import Renderer
from sim.scene import load_scene
from sim.shader import EventShader


def _best_ms(call, calls: int, repeats: int) -> float:
    call()                                                         # compile / warm up
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            call()
        best = min(best, (time.perf_counter() - start) / calls)
    return 1e3 * best


def _median_relative(a: np.ndarray, b: np.ndarray) -> float:
    lit = b > 0
    return float(np.median(np.abs(a - b)[lit] / b[lit]))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="boxes_6dof")
    parser.add_argument("--spp", type=int, default=4)
    parser.add_argument("--time", type=float, default=20.0, help="start of the window, s")
    parser.add_argument("--window", type=float, default=0.05, help="window of sample times, s")
    parser.add_argument("--block", type=float, default=0.01,
                        help="window of the million samples' times, s")
    parser.add_argument("--repeats", type=int, default=5, help="best of N runs")
    args = parser.parse_args(argv)
    import mitsuba as mi

    scene = load_scene(resolve_scene(args.scene))
    renderer = Renderer(scene, spp=args.spp)
    t0, t1 = args.time, args.time + args.window
    shader = EventShader(renderer, args.spp, t0=t0, t1=t1)
    height, width = shader.shape
    rng = np.random.default_rng(0)
    pixels = rng.choice(height * width, height * width // 10, replace=False)
    times = rng.uniform(t0, t1, len(pixels))
    block_pixels = np.sort(rng.integers(0, height * width, 10**6))
    block_times = t0 + rng.uniform(0.0, min(args.block, args.window), len(block_pixels))
    mid = (t0 + t1) / 2
    row = {
        "scene": args.scene, "resolution": f"{width}x{height}", "variant": renderer.variant,
        "spp": args.spp, "samples": len(pixels),
        "luminance_ms": _best_ms(lambda: shader.luminance(pixels, times), 50, args.repeats),
        "block_samples": len(block_pixels), "block_window_s": min(args.block, args.window),
        "luminance_block_ms": _best_ms(lambda: shader.luminance(block_pixels, block_times), 1,
                                       args.repeats),
        "frame_ms": _best_ms(lambda: shader.frame(mid), 10, args.repeats),
        "mi_render_ms": _best_ms(lambda: renderer.luminance(mid, spp=args.spp), 10,
                                 args.repeats),
    }
    exact = EventShader(renderer, 64, t0=t0, t1=t1).frame(mid)
    reference = renderer.luminance(mid, spp=64)
    other = np.asarray(mi.render(renderer.mitsuba_scene, seed=renderer.seed + 1, spp=64))
    row |= {"mean_ratio": float(exact.mean() / reference.mean()),
            "median_relative": _median_relative(exact, reference),
            "median_relative_other_seed": _median_relative(other.reshape(reference.shape),
                                                           reference)}
    print(f"\n{row['scene']} {row['resolution']} {row['variant']}, spp {row['spp']}, warm, "
          f"best of {args.repeats}")
    print(f"luminance() of {row['samples']} scattered samples: {row['luminance_ms']:.2f} ms")
    print(f"luminance() of {row['block_samples']} samples sorted by pixel within "
          f"{1e3 * row['block_window_s']:g} ms: {row['luminance_block_ms']:.1f} ms")
    print(f"frame(): {row['frame_ms']:.2f} ms; Renderer.luminance (mi.render): "
          f"{row['mi_render_ms']:.2f} ms")
    print(f"64 spp against mi.render: mean ratio {row['mean_ratio']:.4f}, median relative "
          f"difference {100 * row['median_relative']:.2f} % (mi.render with another seed: "
          f"{100 * row['median_relative_other_seed']:.2f} %)")
    out = Path(__file__).resolve().parent / "results" / "shader.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(row, indent=2))
    print(f"written to {out}")
    return row


if __name__ == "__main__":
    main()
