"""The global map (``evfuse map-global``, issue 25): time, memory and F-scores on long windows.

For each case (:data:`CASES`: ``slider_close`` over its whole 6.5 s, ``boxes_6dof`` over 6 s),
the window is simulated once into a cache folder (``runs/bench_global``,
:func:`sim.simulate.window.cached_window`) and mapped by
:func:`fusion.globalmap.pipeline.map_global` with the defaults (key views at 10 % of the median
depth or 10 degrees, the default fill (``paper-colorization``), fusion with one other view
agreeing within 2 %, the TSDF of the filled views). Reported per case:

- time per key view (map and fill, median and total over the rounds), of the fusion, of the
  TSDF and of the scoring; the key views, the rounds, the workers;
- memory peak (MiB): the main process's and the largest worker's (``getrusage``);
- F-score at 1, 2 and 5 cm (and accuracy, completeness) of the semi-dense, filled and TSDF maps
  against the exact surface of the key views;
- the gain of fusion over the best single view, both scored against the same exact surface:
  the fused map's recall over the view's at 1, 2, 5 cm and its accuracy change (cm).

``--quick``: 1-second windows (slider_close [0, 1] s, boxes_6dof [3.5, 4.5] s). The times are
wall-clock seconds on whatever machine runs it (the table says how many cores); compare them
only within one run.

``--goals``: issue 40's goals (:data:`GOALS`: boxes_6dof 3.5-5.5 s, slider_close 0-1 s), each map
scored against the same exact surface (the key views' union): the best single key view, the
fused semi-dense map, the plain union of the views' points (``min_views`` 0, from the same
views), the fused filled map and the TSDF mesh, at 5 cm, at 1 % of each point's depth and at the
DSI's plane step at each point's depth; then each goal, met or not. ``--label`` names the run in
the JSON (``benchmarks/results/global_goals.json`` keeps one entry per label: before / after);
``--method`` (a filling method) and ``--fuse-depth`` change the maps as ``map-global``'s flags
do.

Run: ``PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_global.py [--quick | --goals]
[--workers N]``. Results are printed and written to ``benchmarks/results/global.json``
(``global_quick.json`` for ``--quick``, ``global_goals.json`` for ``--goals``).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from fusion.globalmap.pipeline import GlobalParams, map_global
from scenes import resolve_scene
from sim.scene import load_scene
from sim.simulate.window import cached_window

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
CACHE = ROOT / "runs" / "bench_global"
CASES = {"slider_close": (0.0, 6.5), "boxes_6dof": (0.0, 6.0)}
"""Scene -> (start, length) in seconds: the issue's windows."""
QUICK = {"slider_close": (0.0, 1.0), "boxes_6dof": (3.5, 1.0)}
"""``--quick``'s windows."""
GOALS = {"boxes_6dof": (3.5, 2.0), "slider_close": (0.0, 1.0)}
"""``--goals``' windows (issue 40)."""


def run_case(name: str, start: float, length: float, workers: int | None) -> dict:
    """Simulate (cached) and map one case globally; the row of the table."""
    scene = load_scene(resolve_scene(name))
    tick = time.perf_counter()
    folder = cached_window(scene, CACHE, name, start, length, progress=True)
    simulate_s = time.perf_counter() - tick
    with tempfile.TemporaryDirectory() as tmp:
        document = map_global(folder, Path(tmp) / "global", GlobalParams(workers=workers),
                              progress=True)
    views = document["views"]
    per_view = np.array([v["timings"]["map_s"] + v["timings"]["fill_s"] for v in views])
    timings = document["timings"]
    row = {
        "scene": name, "window_s": [start, start + length], "simulate_s": simulate_s,
        "key_views": len(views), "rounds": len(document["rounds"]),
        "selection": document["rounds"],
        "rounds_converged": document["rounds_converged"],
        "workers": document["params"]["workers"] or os.cpu_count(),
        "view_s_median": float(np.median(per_view)), "views_s_total": timings["map_fill_s"],
        "fusion_s": timings["fusion_s"], "tsdf_s": timings["tsdf_s"],
        "scoring_s": timings["scoring_s"], "total_s": timings["total_s"],
        "memory_peak_mb": document["memory_peak_mb"],
        "fused_points": document["fused"], "mesh": document["mesh"],
        "scores": document["global"], "gain_over_best_view": document["gain_over_best_view"],
        "views": [{"t_ref": v["t_ref"], "N1": v["N1"], "semidense": v["semidense"],
                   "filled": v["filled"]} for v in views],
    }
    return row


GOAL_KEYS = ("5cm", "depth1pct", "step")
"""The tolerances of ``--goals``' table: 5 cm, 1 % of each point's depth, the plane step there."""


def goal_case(name: str, start: float, length: float, workers: int | None,
              method: str | None = None, fuse_depth: bool = False) -> dict:
    """Map one goal window globally and score every map against the same exact surface."""
    from fusion.globalmap.fuse import FusionParams, fuse_views
    from fusion.globalmap.pipeline import _semidense_view
    from fusion.globalmap.score import SURFACE_SUPERSAMPLE, cloud_scores, exact_surface, exact_view
    from fusion.globalmap.tsdf import Mesh
    from fusion.io import read_mesh_ply, read_ply
    from fusion.map.dsi_range import resolve_dsi_range
    from sim.sequence import load_sequence

    scene = load_scene(resolve_scene(name))
    folder = cached_window(scene, CACHE, name, start, length, progress=True)
    sequence = load_sequence(folder)
    params = GlobalParams(workers=workers)
    params = params if method is None else replace(params, method=method)
    params = replace(params, fusion=replace(params.fusion, fuse_depth=fuse_depth))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "global"
        tick = time.perf_counter()
        document = map_global(folder, out, params, progress=False)
        wall = time.perf_counter() - tick
        count = document["key_views"]
        semidense = [_semidense_view(out / "views" / f"{k:03d}" / "map") for k in range(count)]
        clouds = {name: _xyz(read_ply(out / file)[0])
                  for name, file in (("fused", "global.ply"), ("filled", "global_filled.ply"))
                  if (out / file).exists()}
        clouds["union"] = fuse_views(semidense, FusionParams(min_views=0)).points
        if (out / "mesh.ply").exists():
            vertices, faces, _ = read_mesh_ply(out / "mesh.ply")
            clouds["tsdf"] = Mesh(vertices, faces).sample(document["fused"]["voxel_size_m"] / 2)
    exact = [exact_view(sequence, view.t, SURFACE_SUPERSAMPLE) for view in semidense]
    reference = exact_surface(exact)
    scene_depth = float(np.median(np.concatenate([v.depth[v.valid] for v in exact])))
    dsi = resolve_dsi_range(sequence, params.min_depth, params.max_depth)
    step = (1.0 / dsi.min_depth - 1.0 / dsi.max_depth) / (params.planes - 1)
    poses = np.stack([view.T_world_cam for view in semidense])

    def score(points: np.ndarray) -> dict:
        return cloud_scores(points, reference, scene_depth, poses=poses, inverse_depth_step=step)

    views = [score(view.points_world()) for view in semidense]
    best = max(range(count), key=lambda k: views[k]["fscore_5cm"])
    maps = {"best view": views[best], **{k: score(v) for k, v in clouds.items()}}
    return {"scene": name, "window_s": [start, start + length], "key_views": count,
            "method": document["params"]["method"], "fuse_depth": fuse_depth,
            "best_view": best, "wall_s": wall, "maps": maps, "views": views,
            "document_global": document["global"]}


def _xyz(record: np.ndarray) -> np.ndarray:
    return np.stack([record["x"], record["y"], record["z"]], 1).astype(np.float64)


def goals(rows: list[dict]) -> list[tuple[str, float, float, bool]]:
    """Issue 40's goals: (goal, measured, target, met)."""
    out = []
    for r in rows:
        m = r["maps"]

        def f(name: str, key: str, m: dict = m) -> float:
            return m[name][key] if name in m else 0.0

        if r["scene"] == "boxes_6dof":
            out += [("boxes: fused F 5 cm >= 1.5 x best view", f("fused", "fscore_5cm"),
                     1.5 * f("best view", "fscore_5cm")),
                    ("boxes: fused F 5 cm >= plain union", f("fused", "fscore_5cm"),
                     f("union", "fscore_5cm")),
                    ("boxes: TSDF F 5 cm >= fused", f("tsdf", "fscore_5cm"),
                     f("fused", "fscore_5cm"))]
        elif r["scene"] == "slider_close":
            out += [("slider: fused P 1 % >= best view", f("fused", "precision_depth1pct"),
                     f("best view", "precision_depth1pct")),
                    ("slider: filled F 1 % >= 0.9", f("filled", "fscore_depth1pct"), 0.9),
                    ("slider: TSDF F 1 % >= fused", f("tsdf", "fscore_depth1pct"),
                     f("fused", "fscore_depth1pct"))]
    return [(name, value, target, value >= target) for name, value, target in out]


def print_goals(rows: list[dict]) -> None:
    """Per case the maps' P/R/F at each of :data:`GOAL_KEYS`, then the goals."""
    print("\n| scene | map | points | " + " | ".join(f"P/R/F {k} %" for k in GOAL_KEYS) + " |")
    print("|---|---|---|" + "---|" * len(GOAL_KEYS))
    for r in rows:
        for name, m in r["maps"].items():
            cells = " | ".join(" / ".join(_f(m[f"{x}_{k}"], 100) for x in
                                          ("precision", "recall", "fscore")) for k in GOAL_KEYS)
            print(f"| {r['scene']} | {name} | {m['points']:,} | {cells} |")
    print("\n| goal | measured | target | met |\n|---|---|---|---|")
    for name, value, target, met in goals(rows):
        print(f"| {name} | {100 * value:.1f} | {100 * target:.1f} | {'yes' if met else 'no'} |")


def _f(value: float | None, scale: float = 1.0, digits: int = 1) -> str:
    return "-" if value is None else f"{scale * value:.{digits}f}"


def print_table(rows: list[dict]) -> None:
    """The rows as two tables: time and memory; scores and gain."""
    print("\n| scene | window s | key views (rounds) | s per view (median) | views s | "
          "fusion s | TSDF s | scoring s | memory MiB (main / worker) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        memory = r["memory_peak_mb"]
        print(f"| {r['scene']} | {r['window_s'][0]:g}-{r['window_s'][1]:g} | {r['key_views']} "
              f"({r['rounds']}) | {r['view_s_median']:.1f} | {r['views_s_total']:.1f} | "
              f"{r['fusion_s']:.1f} | {r['tsdf_s']:.1f} | {r['scoring_s']:.1f} | "
              f"{memory['main']:.0f} / {memory['largest_worker']:.0f} |")
    print("\n| scene | map | accuracy cm | completeness cm | F 1 cm % | F 2 cm % | F 5 cm % | "
          "recall x best view 1 / 2 / 5 cm | accuracy change cm |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        for name in ("semidense", "filled", "tsdf"):
            m = r["scores"][name]
            gain = (r["gain_over_best_view"] or {}).get(name)
            ratios = "-" if gain is None else " / ".join(
                _f(gain[f"recall_ratio_{x}cm"], digits=2) for x in (1, 2, 5))
            change = "-" if gain is None else _f(gain["accuracy_change_cm"], digits=2)
            if m is None:
                print(f"| {r['scene']} | {name} | - | - | - | - | - | - | - |")
                continue
            print(f"| {r['scene']} | {name} | {_f(m['accuracy_cm'], digits=2)} | "
                  f"{_f(m['completeness_cm'], digits=2)} | {_f(m['fscore_1cm'], 100)} | "
                  f"{_f(m['fscore_2cm'], 100)} | {_f(m['fscore_5cm'], 100)} | {ratios} | "
                  f"{change} |")


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1-second windows")
    parser.add_argument("--goals", action="store_true", help="issue 40's goal windows")
    parser.add_argument("--label", default="run", help="--goals: the run's name in the JSON")
    parser.add_argument("--scenes", default=None, help="comma-separated subset of the cases")
    parser.add_argument("--method", default=None,
                        help="--goals: the filling method (default: map-global's)")
    parser.add_argument("--fuse-depth", action="store_true",
                        help="--goals: fuse each point's depth with its confirming views'")
    parser.add_argument("--workers", type=int, default=None,
                        help="key views mapped at once (default: the machine's cores)")
    args = parser.parse_args(argv)
    if args.goals:
        names = args.scenes.split(",") if args.scenes else list(GOALS)
        rows = [goal_case(name, *GOALS[name], args.workers, args.method, args.fuse_depth)
                for name in names]
        print_goals(rows)
        path = RESULTS / "global_goals.json"
        recorded = json.loads(path.read_text()) if path.exists() else {}
        recorded[args.label] = {"cores": os.cpu_count(), "rows": rows,
                                "goals": [list(g) for g in goals(rows)]}
        RESULTS.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(recorded, indent=2, default=float))
        print(f"written to {path}")
        return rows
    cases = QUICK if args.quick else CASES
    names = args.scenes.split(",") if args.scenes else list(cases)
    rows = [run_case(name, *cases[name], args.workers) for name in names]
    print_table(rows)
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / ("global_quick.json" if args.quick else "global.json")
    path.write_text(json.dumps({"cores": os.cpu_count(), "rows": rows}, indent=2,
                               default=float))
    print(f"written to {path}")
    return rows


if __name__ == "__main__":
    main()
