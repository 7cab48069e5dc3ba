"""Time of map filling's three stages: ``segment_regions``, ``select_regions``, ``fill_regions``.

At 240x180, 640x480 and 1280x720, on 1 and 2 numba threads, the median of several repeats of each
stage (and of the three together) on a synthetic, piecewise-planar input: a frame with a shaded,
slanted background plane and a dozen rectangles and discs of other gray levels (fronto-parallel
planes, one of them textured with a fine checker, as a poster would be), mild sensor noise, and a
semi-dense map like EMVS's: the pixels within 1 px of the objects' outlines, 80 % of them kept, at
their plane's depth with 1 % noise (about 2k map points at 240x180). The target for the three
stages together on one core at 240x180 with 2-5k map points is 50 ms. Every weighting is timed
for the fill. Results are printed and written to ``benchmarks/results/bench_fill.json``.

Then every filling method of :func:`fusion.methods.available_methods` (the paper's, the
baselines, ours) on the same inputs, on one core (numba and OpenCV at one thread), median of
``--repeats`` after one untimed call (at most 3 repeats where one call takes over a second;
a method over 5 s at one size is not run at the larger ones),
through :func:`fusion.methods.run_method`; written to
``benchmarks/results/bench_fill_methods.json``. The built-ins' target: under 50 ms at 240x180.

Run: ``.venv/bin/python benchmarks/bench_fill.py [--repeats N] [--no-methods]``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numba
import numpy as np

from fusion.fill.filling import (
    WEIGHTINGS,
    FillParams,
    fill_regions,
    filling_score,
    select_regions,
)
from fusion.fill.segmentation import segment_regions

RESULTS = Path(__file__).resolve().parent / "results"
SIZES = ((240, 180), (640, 480), (1280, 720))


def synthetic_input(width: int, height: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A piecewise-planar frame and its semi-dense map on the outlines of its objects.

    Returns
    -------
    frame : (H, W) uint8 ndarray, gray levels
    sparse_depth : (H, W) float32 ndarray, metres, 0 where no map point
    """
    rng = np.random.default_rng(seed)
    s = width / 240.0                                   # shapes scale with the image
    y, x = np.mgrid[:height, :width]
    gray = 60.0 + 40.0 * x / width + 20.0 * y / height  # smooth shading: <= 1 level per pixel
    depth = 1.0 / (1 / 4.0 + 0.05 * (x / width - 0.5))  # slanted background plane, ~4 m
    objects = np.zeros((height, width), np.int32)
    for i in range(12):
        level = rng.uniform(120, 240)
        z = rng.uniform(1.0, 3.0)
        cx, cy = rng.uniform(0.1, 0.9) * width, rng.uniform(0.1, 0.9) * height
        if i % 3 == 2:
            r = rng.uniform(8, 22) * s
            inside = (x - cx) ** 2 + (y - cy) ** 2 <= r * r
        else:
            hw, hh = rng.uniform(8, 30, 2) * s
            inside = (np.abs(x - cx) <= hw) & (np.abs(y - cy) <= hh)
        gray[inside] = level
        if i == 0:                                      # a textured object: many small regions
            checker = ((x // max(1, round(2 * s))) + (y // max(1, round(2 * s)))) % 2
            gray[inside] = level - 60 * checker[inside]
        depth[inside] = z
        objects[inside] = i + 1
    frame = np.clip(np.round(gray + rng.normal(0.0, 0.6, gray.shape)), 0, 255).astype(np.uint8)
    outline = np.zeros_like(objects, dtype=bool)
    outline[:, 1:] |= objects[:, 1:] != objects[:, :-1]
    outline[1:, :] |= objects[1:, :] != objects[:-1, :]
    outline = cv2.dilate(outline.astype(np.uint8), np.ones((2, 2), np.uint8)).astype(bool)
    keep = outline & (rng.random(outline.shape) < 0.8)
    sparse = np.where(keep, depth * (1 + 0.01 * rng.standard_normal(depth.shape)), 0.0)
    return frame, sparse.astype(np.float32)


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-methods", action="store_true",
                        help="time the three stages only, not every filling method")
    args = parser.parse_args(argv)
    default_threads = numba.get_num_threads()
    rows = []
    for width, height in SIZES:
        frame, sparse = synthetic_input(width, height)
        labels = segment_regions(frame)                # compile and warm up
        regions = select_regions(labels, sparse)
        for weighting in WEIGHTINGS:
            fill_regions(labels, sparse, regions, FillParams(weighting=weighting))
        dense = fill_regions(labels, sparse, regions)
        n1, n2 = int((sparse > 0).sum()), int((dense > 0).sum())
        for threads in (1, 2):
            numba.set_num_threads(min(threads, default_threads))
            row = {"size": f"{width}x{height}", "threads": min(threads, default_threads),
                   "map_points": n1, "regions": regions.n_regions,
                   "selected": int(regions.selected.sum()), "n2": n2,
                   "beta": filling_score(n1, n2, width * height),
                   "segment_ms": 1e3 * _median_time(lambda f=frame: segment_regions(f),
                                                    args.repeats),
                   "select_ms": 1e3 * _median_time(
                       lambda lab=labels, sp=sparse: select_regions(lab, sp), args.repeats)}
            for weighting in WEIGHTINGS:
                fill = FillParams(weighting=weighting)
                row[f"fill_{weighting}_ms"] = 1e3 * _median_time(
                    lambda lab=labels, sp=sparse, reg=regions, p=fill: fill_regions(lab, sp,
                                                                                    reg, p),
                    args.repeats)
            row["total_idw_ms"] = row["segment_ms"] + row["select_ms"] + row["fill_idw_ms"]
            rows.append(row)
    numba.set_num_threads(default_threads)
    print(f"\nMap filling, median of {args.repeats} runs (ms)")
    print(f"  {'size':>9} thr  points regions sel   beta   segment  select  fill idw  "
          f"gauss   expo  total(idw)")
    for r in rows:
        print(f"  {r['size']:>9} {r['threads']:>3} {r['map_points']:>7} {r['regions']:>7} "
              f"{r['selected']:>3} {r['beta']:6.3f} {r['segment_ms']:9.2f} {r['select_ms']:7.2f} "
              f"{r['fill_idw_ms']:9.2f} {r['fill_gaussian_ms']:6.2f} "
              f"{r['fill_exponential_ms']:6.2f} {r['total_idw_ms']:11.2f}")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "bench_fill.json").write_text(json.dumps(rows, indent=2))
    print(f"written to {RESULTS / 'bench_fill.json'}")
    if not args.no_methods:
        bench_methods(args.repeats)
    return rows


def bench_methods(repeats: int) -> list[dict]:
    """Every available filling method at every size, one core; printed and written."""
    from fusion.methods import available_methods, get_method, run_method
    from sim.camera import Camera

    default_threads = numba.get_num_threads()
    numba.set_num_threads(1)
    cv2.setNumThreads(1)
    rows = []
    names = list(available_methods())
    slow: set[str] = set()                 # over 5 s at a smaller size: not run at larger ones
    for width, height in SIZES:
        frame, sparse = synthetic_input(width, height)
        camera = Camera(width=width, height=height, fx=0.8 * width, fy=0.8 * width,
                        cx=(width - 1) / 2, cy=(height - 1) / 2)
        for name in names:
            if name in slow:
                rows.append({"size": f"{width}x{height}", "method": name, "ms": None,
                             "repeats": 0, "skipped": "over 5 s at a smaller size"})
                continue
            method = get_method(name)
            tick = time.perf_counter()
            run_method(method, frame, sparse, camera)                 # compile, warm up
            once = time.perf_counter() - tick
            n = repeats if once < 1.0 else min(repeats, 3)
            ms = 1e3 * _median_time(lambda m=method, f=frame, sp=sparse, c=camera:
                                    run_method(m, f, sp, c), n)
            rows.append({"size": f"{width}x{height}", "method": name, "ms": ms, "repeats": n})
            if ms > 5000:
                slow.add(name)
    numba.set_num_threads(default_threads)
    cv2.setNumThreads(-1)
    print("\nEvery filling method, one core, median (ms)")
    print(f"  {'method':<18}" + "".join(f"{w}x{h:<8}" for w, h in SIZES))
    for name in names:
        cells = [next(r["ms"] for r in rows if r["method"] == name and r["size"] == f"{w}x{h}")
                 for w, h in SIZES]
        print(f"  {name:<18}" + "".join("skipped     " if c is None else f"{c:<12.1f}"
                                         for c in cells))
    (RESULTS / "bench_fill_methods.json").write_text(json.dumps(rows, indent=2))
    print(f"written to {RESULTS / 'bench_fill_methods.json'}")
    return rows


if __name__ == "__main__":
    main()
