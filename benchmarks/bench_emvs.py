"""DSI construction throughput of ``fusion.emvs.disparity_space_image``, and a 2-s window.

Million events per second (events / wall time of building the DSI, as rpg_emvs logs it) at
240x180x100 and 640x480x100 planes, on 1 and 2 threads, for 1 M events, either uniformly random
over the image or on 40 edges (what real events look like). Beside each figure, in the same
process, a baseline: rpg_emvs's loop (for each packet, planes in parallel, events of the packet
in time order, float64 positions), compiled with numba; the ratio is ours / baseline.
rpg_emvs (C++, as its authors build it) on a machine like ours, 240x180x100: 1.1-1.3 Mev/s on
one thread, 2.0-2.1 on two; the goal is twice that.

Then the total time of ``map_sequence`` (reading, undistorting, DSI, depth map, outliers) for a
2-second window of ``runs/slider_close`` when that simulated sequence exists
(``evfuse simulate slider_close --out runs/slider_close``), on 1 and 2 threads.

Printed and written to ``benchmarks/results/emvs.json``.
Run: ``.venv/bin/python benchmarks/bench_emvs.py [--events N]``.
"""

from __future__ import annotations

import argparse
import json
import time
from functools import partial
from pathlib import Path

import numba
import numpy as np

from fusion.emvs import DepthMapParams, DSIParams, depth_planes, disparity_space_image
from fusion.mapping import MapParams, map_sequence
from sim.camera import camera_preset
from sim.trajectory import LinearTrajectory

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


@numba.njit(parallel=True)
def _rpg_emvs_loop(coeffs, inv_depth, fx, fy, cx, cy, packet_size, dsi):  # pragma: no cover
    """rpg_emvs's accumulation order (baseline only): per packet, planes in parallel."""
    planes, height, width = dsi.shape
    n = coeffs.shape[0]
    for start in range(0, n, packet_size):
        stop = min(start + packet_size, n)
        for k in numba.prange(planes):
            w = inv_depth[k]
            for i in range(start, stop):
                u = fx * (coeffs[i, 0] + coeffs[i, 1] * w) + cx
                v = fy * (coeffs[i, 2] + coeffs[i, 3] * w) + cy
                if not (u >= 0.0 and v >= 0.0 and u <= width - 1 and v <= height - 1):
                    continue
                u0 = min(int(u), width - 2)
                v0 = min(int(v), height - 2)
                fu = u - u0
                fv = v - v0
                dsi[k, v0, u0] += (1.0 - fu) * (1.0 - fv)
                dsi[k, v0, u0 + 1] += fu * (1.0 - fv)
                dsi[k, v0 + 1, u0] += (1.0 - fu) * fv
                dsi[k, v0 + 1, u0 + 1] += fu * fv


def _baseline(xy, times, trajectory, T_world_ref, camera, params):
    from fusion.emvs import ray_coefficients
    from sim.se3 import invert_pose

    n_packets = -(-len(xy) // params.packet_size)
    middle = np.minimum(np.arange(n_packets) * params.packet_size + params.packet_size // 2,
                        len(xy) - 1)
    T = invert_pose(T_world_ref) @ trajectory.pose(times[middle])
    coeffs = np.concatenate([ray_coefficients(xy[j * params.packet_size:
                                                 (j + 1) * params.packet_size], T[j])
                             for j in range(n_packets)])
    dsi = np.zeros((params.planes, camera.height, camera.width), np.float32)
    _rpg_emvs_loop(coeffs, 1 / depth_planes(params), camera.fx, camera.fy, camera.cx, camera.cy,
                   params.packet_size, dsi)
    return dsi


def _events(kind: str, n: int, rng) -> np.ndarray:
    if kind == "uniform":
        return np.stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.45, 0.45, n)], axis=1)
    edge = rng.integers(0, 40, n)                   # 20 vertical and 20 horizontal edges
    along = rng.uniform(-0.5, 0.5, n)
    across = np.linspace(-0.4, 0.4, 20)[edge % 20] + rng.normal(0.0, 0.002, n)
    vertical = edge < 20
    return np.stack([np.where(vertical, across, along), np.where(vertical, along, across)], 1)


def _best_time(function, repeats: int = 2) -> float:
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=1_000_000)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    n = args.events
    times = np.sort(rng.uniform(0.0, 1.0, n))
    trajectory = LinearTrajectory(np.zeros(3), np.array([0.1, 0.0, 0.0]), np.eye(3))
    T_ref = trajectory.pose(0.5)
    params = DSIParams(0.5, 3.0, planes=100)
    rows = []
    default_threads = numba.get_num_threads()
    for preset in ("davis240c", "vga"):
        camera = camera_preset(preset)
        for kind in ("uniform", "edges"):
            xy = _events(kind, n, rng)
            args_ = (xy, times, trajectory, T_ref, camera, params)
            ours = partial(disparity_space_image, *args_)
            base = partial(_baseline, *args_)
            ours(), base()                                            # compile, warm caches
            for threads in (1, 2):
                numba.set_num_threads(min(threads, default_threads))
                t_ours, t_base = _best_time(ours), _best_time(base)
                rows.append({"dsi": f"{camera.width}x{camera.height}x{params.planes}",
                             "events": kind, "threads": threads,
                             "mev_per_s": n / t_ours / 1e6,
                             "baseline_mev_per_s": n / t_base / 1e6,
                             "ratio": t_base / t_ours})
    numba.set_num_threads(default_threads)
    print(f"\nDSI construction, {n} events (baseline: rpg_emvs's loop order, compiled, "
          "same process)")
    print(f"  {'DSI':>12} {'events':>8} {'threads':>7} {'Mev/s':>7} {'baseline':>9} "
          f"{'ratio':>6}")
    for r in rows:
        print(f"  {r['dsi']:>12} {r['events']:>8} {r['threads']:>7} {r['mev_per_s']:>7.2f} "
              f"{r['baseline_mev_per_s']:>9.2f} {r['ratio']:>6.2f}")
    report: dict = {"dsi": rows, "window_2s": []}
    folder = ROOT / "runs" / "slider_close"
    if (folder / "sequence.json").is_file():
        map_params = MapParams(DSIParams(0.15, 0.6, planes=100),
                               DepthMapParams(kernel=15, c=7.0), t0=2.0, t1=4.0)
        map_sequence(folder, map_params, progress=False)              # warm the file cache
        for threads in (1, 2):
            numba.set_num_threads(min(threads, default_threads))
            start = time.perf_counter()
            result = map_sequence(folder, map_params, progress=False)
            wall = time.perf_counter() - start
            timings = result.info["timings"]
            report["window_2s"].append({
                "sequence": "slider_close [2, 4] s", "threads": threads, "wall_s": wall,
                "events": result.info["events_used"], "N1": result.n1,
                "dsi_s": timings["dsi_s"], "events_s": timings["events_s"],
                "depth_map_s": timings["depth_map_s"],
                "dsi_mev_per_s": result.info["dsi_mev_per_s"]})
        numba.set_num_threads(default_threads)
        print("\nmap_sequence on a 2-s window of runs/slider_close (240x180x100)")
        for r in report["window_2s"]:
            print(f"  {r['threads']} thread(s): {r['wall_s']:.2f} s total for {r['events']:,} "
                  f"events (reading+DSI {r['events_s']:.2f} s, of which DSI {r['dsi_s']:.2f} s "
                  f"= {r['dsi_mev_per_s']:.2f} Mev/s; depth map {r['depth_map_s']:.2f} s)")
    else:
        print(f"\n(no {folder}: simulate it to time a 2-s window: "
              "evfuse simulate slider_close --out runs/slider_close)")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "emvs.json").write_text(json.dumps(report, indent=2))
    print(f"written to {RESULTS / 'emvs.json'}")
    return report


if __name__ == "__main__":
    main()
