"""``--views N`` (issue 25, part 2c): the fused reference map against the one-view map, and the
sweep that chose its rule.

Table (:data:`CASES`): boxes_6dof's paper window, 3.5-5.5 s, and three windows that were not
used to choose the rule: garden_wall 2-4 s, slider_close 1-2 s (the paper's slider extraction,
kernel 15, c = 7) and boxes_6dof 1.5-3.5 s. Each is simulated once over a span its neighbours
fit in (:func:`sim.simulate.window.cached_window`, the scene's defaults, cached in
``runs/bench_views``), mapped at the frame nearest its middle (:func:`fusion.pipeline.map_window`,
the scene's declared DSI range, 100 planes: ``evfuse map``'s defaults), fused by
:func:`fusion.globalmap.neighbours.fused_reference_map` under each rule of :data:`RULES` (the
rule before the candidates: every view at the one-view map's own threshold, one other view
agreeing, neighbours half a window apart; and the default: candidates at c = 0, two other
views, a quarter window apart) with N views, filled by :func:`fusion.pipeline.fill_window` (the
paper's defaults) and scored against the exact depth of the reference view. Per row: N1 (and
its ratio to the one view's), the event map's precision within 5 % and MAE (median), the dense
map's N2, precision, MAE (median) and completeness, and the fusion's wall time (the views'
mapping included, in a warm process).

``--sweep``: how the default was chosen. For the Table 1 windows of boxes_6dof, poster_6dof and
shapes_6dof (each simulated over the window and 2.5 s on each side, within the scene), every
view is mapped at each threshold of :data:`SWEEP_C` (once per view and threshold), and the maps
are fused into the reference view (:func:`fusion.globalmap.fuse.fuse_into_view`) with k = 1 or
2 other views agreeing within 2 %, neighbours half or a quarter of the window apart, N = 3 or
5; per combination N1 (ratio to the one view's at c = 5) and precision within 5 %.

Run: ``PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_views.py [--sweep]``. Results are
printed (markdown) and written to ``benchmarks/results/views.json`` (``views_sweep.json``).
Times are wall-clock seconds on whatever machine runs it: compare them only within one run.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from fusion.globalmap.fuse import FusionParams, fuse_into_view
from fusion.globalmap.neighbours import fused_reference_map, neighbour_times
from fusion.globalmap.views import DepthView
from fusion.map.emvs import DepthMapParams
from fusion.map.mapping import _ground_truth_depth
from fusion.pipeline import fill_window, map_window
from fusion.scoring import depth_errors
from scenes import resolve_scene
from sim.scene import load_scene
from sim.sequence import load_sequence
from sim.simulate.window import cached_window
from sim.validation import ParameterError

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
CACHE = ROOT / "runs" / "bench_views"

CASES = [
    # label, scene, simulated (start, length), window (t0, t1), extraction
    ("boxes_6dof 3.5-5.5 s", "boxes_6dof", (1.0, 7.0), (3.5, 5.5), DepthMapParams()),
    ("garden_wall 2-4 s (held out)", "garden_wall", (1.0, 4.0), (2.0, 4.0), DepthMapParams()),
    ("slider_close 1-2 s (held out)", "slider_close", (0.0, 3.0), (1.0, 2.0),
     DepthMapParams(kernel=15, c=7.0)),
    ("boxes_6dof 1.5-3.5 s (held out)", "boxes_6dof", (0.0, 6.0), (1.5, 3.5), DepthMapParams()),
]
"""The table's windows."""

RULES = {
    "before": {"views": (3, 5), "c": None, "fusion": FusionParams(min_views=1),
               "spacing_share": 0.5},
    "default": {"views": (3, 5, 7, 9), "c": 0.0, "fusion": None, "spacing_share": None},
}
"""Rule name -> fused_reference_map's settings (None: its default) and the views tried;
views that the simulated span cannot hold are skipped."""

SWEEP_CASES = [("boxes_6dof", (3.5, 5.5)), ("poster_6dof", (2.0, 4.0)),
               ("shapes_6dof", (2.0, 4.0))]
"""The sweep's windows: Table 1's."""
SWEEP_C = (5.0, 2.0, 1.0, 0.0, -1.0)
"""The adaptive threshold's c tried by the sweep."""


def _percent(errors: dict) -> str:
    return f"{100 * errors['precision_5pct']:.1f} %"


def _mae(errors: dict) -> str:
    return f"{errors['mae_cm']:.2f} ({errors['median_cm']:.2f}) cm"


def _dense(fill_folder: Path, map_folder: Path) -> dict:
    info = fill_window(map_folder, fill_folder, overwrite=True).info
    return {"N2": info["N2"], "errors": info["errors"]["all"]["overall"]}


def table_case(label: str, scene_name: str, span: tuple[float, float],
               window: tuple[float, float], depth: DepthMapParams, tmp: Path) -> list[dict]:
    """The table's rows of one window: the one-view map, then each rule and N."""
    scene = load_scene(resolve_scene(scene_name))
    sequence = cached_window(scene, CACHE, scene_name, span[0], span[1], progress=True)
    folder = tmp / scene_name / f"{window[0]:g}"
    mapped, _ = map_window(sequence, folder / "map", *window, depth=depth, overwrite=True,
                           progress=False)
    one = {"label": label, "map": "one view", "N1": mapped.n1,
           "map_errors": mapped.info["errors"], **_dense(folder / "fill", folder / "map")}
    rows = [one]
    for rule, settings in RULES.items():
        share = settings["spacing_share"]
        spacing = None if share is None else share * (window[1] - window[0])
        for views in settings["views"]:
            tick = time.perf_counter()
            try:
                description = fused_reference_map(
                    folder / "map", folder / "fused", views, settings["fusion"],
                    spacing=spacing, c=settings["c"], overwrite=True, progress=False)
            except ValueError as exc:              # the span cannot hold that many views
                print(f"{label}: {rule}, {views} views skipped: {exc}")
                continue
            seconds = time.perf_counter() - tick
            meta = json.loads((folder / "fused" / "map" / "map.json").read_text())
            check = description["fusion"]
            name = (f"{views} views, c = {description['c']:g}, k = {check['min_views']}, "
                    f"h = {description['spacing_s']:g} s")
            rows.append({"label": label, "map": name, "rule": rule, "views": views,
                         "N1": description["N1"], "ratio": description["N1"] / mapped.n1,
                         "map_errors": meta["errors"], "fusion_s": seconds,
                         **_dense(folder / "fused" / "fill", folder / "fused" / "map")})
    return rows


def table_markdown(rows: list[dict]) -> str:
    lines = ["| window | map | N1 | event map: within 5 % | MAE (median) | dense map: N2, "
             "within 5 % | MAE (median) | completeness | time |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        n1 = f"{r['N1']:,}" + (f" ({r['ratio']:.2f}x)" if "ratio" in r else "")
        e = r["errors"]
        time_s = f"{r['fusion_s']:.0f} s" if "fusion_s" in r else "-"
        lines.append(f"| {r['label']} | {r['map']} | {n1} | {_percent(r['map_errors'])} | "
                     f"{_mae(r['map_errors'])} | {r['N2']:,}, {_percent(e)} | {_mae(e)} | "
                     f"{100 * e['completeness']:.1f} % | {time_s} |")
    return "\n".join(lines)


def sweep_case(scene_name: str, window: tuple[float, float], tmp: Path) -> list[dict]:
    """The sweep's rows of one window."""
    scene = load_scene(resolve_scene(scene_name))
    start = max(0.0, window[0] - 2.5)
    end = min(scene.duration, window[1] + 2.5)
    sequence = cached_window(scene, CACHE, scene_name, start, end - start, progress=True)
    reference, _ = map_window(sequence, tmp / scene_name / "ref", *window, overwrite=True,
                              progress=False)
    t_ref, length = reference.t_ref, window[1] - window[0]
    truth = _ground_truth_depth(load_sequence(sequence), t_ref)           # scoring only
    views: dict = {}

    def view(t: float, c: float) -> DepthView:
        key = (round(t, 9), c)
        if key not in views:
            shift = t - t_ref
            mapped, _ = map_window(sequence, tmp / scene_name / "v", window[0] + shift,
                                   window[1] + shift, ref_time=t,
                                   depth=DepthMapParams(c=c), overwrite=True, progress=False)
            views[key] = DepthView(mapped.depth, mapped.camera, mapped.T_world_ref, t)
        return views[key]

    span = (start, end)
    rows = []
    for c in SWEEP_C:
        for share in (0.5, 0.25):
            for n in (3, 5):
                try:
                    times = neighbour_times(t_ref, window, n, span, share * length)
                except ValueError:
                    continue
                try:
                    depth_views = [view(t_ref, c)] + [view(t, c) for t in times]
                except ParameterError as exc:    # the map stage refused a view's map at c
                    rows.append({"scene": scene_name, "window": list(window), "c": c,
                                 "spacing_share": share, "views": n, "refused": str(exc)})
                    print(f"{scene_name}: c = {c:g}, spacing {share:g}, {n} views: {exc}")
                    continue
                for k in (1, 2):
                    if k >= n:
                        continue
                    fused = fuse_into_view(depth_views, 0, FusionParams(min_views=k))
                    errors = depth_errors(fused, truth)
                    rows.append({"scene": scene_name, "window": list(window), "c": c,
                                 "spacing_share": share, "views": n, "k": k,
                                 "N1": int(np.count_nonzero(fused)),
                                 "ratio": int(np.count_nonzero(fused)) / reference.n1,
                                 "precision_5pct": errors["precision_5pct"],
                                 "mae_cm": errors["mae_cm"]})
    rows.insert(0, {"scene": scene_name, "window": list(window), "one_view": True,
                    "N1": reference.n1,
                    "precision_5pct": reference.info["errors"]["precision_5pct"],
                    "mae_cm": reference.info["errors"]["mae_cm"]})
    return rows


def sweep_markdown(rows: list[dict]) -> str:
    lines = ["| scene | c | spacing (window) | N | k | N1 (x one view) | within 5 % | MAE (cm) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "refused" in r:
            reason = r["refused"].split(":")[0]          # its first clause; whole in the JSON
            lines.append(f"| {r['scene']} | {r['c']:g} | {r['spacing_share']:g} | {r['views']} "
                         f"| - | refused by the map stage: {reason} | - | - |")
            continue
        if r.get("one_view"):
            lines.append(f"| {r['scene']} | one view (c = 5) | - | 1 | - | {r['N1']:,} | "
                         f"{100 * r['precision_5pct']:.1f} % | {r['mae_cm']:.2f} |")
            continue
        lines.append(f"| {r['scene']} | {r['c']:g} | {r['spacing_share']:g} | {r['views']} | "
                     f"{r['k']} | {r['N1']:,} ({r['ratio']:.2f}x) | "
                     f"{100 * r['precision_5pct']:.1f} % | {r['mae_cm']:.2f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweep", action="store_true",
                        help="the rule's choice on Table 1's windows instead of the table")
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    tick = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        if args.sweep:
            rows = [r for scene, window in SWEEP_CASES
                    for r in sweep_case(scene, window, Path(tmp))]
            text, name = sweep_markdown(rows), "views_sweep.json"
        else:
            rows = [r for case in CASES for r in table_case(*case, Path(tmp))]
            text, name = table_markdown(rows), "views.json"
    print(text)
    (RESULTS / name).write_text(json.dumps({"rows": rows, "wall_s": time.perf_counter() - tick},
                                           indent=1, default=float) + "\n")
    print(f"{time.perf_counter() - tick:.0f} s; written to {RESULTS / name}")


if __name__ == "__main__":
    main()
