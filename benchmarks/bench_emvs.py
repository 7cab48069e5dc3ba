"""DSI construction throughput of ``fusion.emvs.disparity_space_image``.

Million events per second (events / wall time of building the DSI, as rpg_emvs logs it) at
240x180x100 and 640x480x100 planes, on 1 and 2 threads, for 1 M events with uniformly random
coordinates and a linear trajectory. rpg_emvs (C++, as its authors build it) on a machine like
ours, 240x180x100: 1.1-1.3 Mev/s on one thread, 2.0-2.1 on two. Results are printed and written
to ``benchmarks/results/emvs.json``.

Run: ``.venv/bin/python benchmarks/bench_emvs.py [--events N]``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numba
import numpy as np

from fusion.emvs import DSIParams, disparity_space_image
from sim.camera import camera_preset
from sim.trajectory import LinearTrajectory

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=1_000_000)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    n = args.events
    xy = np.stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.45, 0.45, n)], axis=1)
    times = np.sort(rng.uniform(0.0, 1.0, n))
    trajectory = LinearTrajectory(np.zeros(3), np.array([0.1, 0.0, 0.0]), np.eye(3))
    params = DSIParams(0.5, 3.0, planes=100)
    rows = []
    default_threads = numba.get_num_threads()
    for preset in ("davis240c", "vga"):
        camera = camera_preset(preset)
        disparity_space_image(xy[:4096], times[:4096], trajectory, trajectory.pose(0.5), camera,
                              params)                                  # compile
        for threads in (1, 2):
            numba.set_num_threads(min(threads, default_threads))
            best = np.inf
            for _ in range(2):
                start = time.perf_counter()
                disparity_space_image(xy, times, trajectory, trajectory.pose(0.5), camera, params)
                best = min(best, time.perf_counter() - start)
            rows.append({"dsi": f"{camera.width}x{camera.height}x{params.planes}",
                         "threads": threads, "mev_per_s": n / best / 1e6})
    numba.set_num_threads(default_threads)
    print(f"\nDSI construction, {n} events")
    for r in rows:
        print(f"  {r['dsi']:>12}  {r['threads']} thread(s)  {r['mev_per_s']:.2f} Mev/s")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "emvs.json").write_text(json.dumps(rows, indent=2))
    print(f"written to {RESULTS / 'emvs.json'}")
    return rows


if __name__ == "__main__":
    main()
