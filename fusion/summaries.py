"""The text summaries of evfuse's results: what ``evfuse map``, ``fill``, ``run`` and
``map-global`` print once they have written their folder.

Each summary is built from the result the library returned (a
:class:`~fusion.map.mapping.MapResult`, a fill's ``info``, ``report.json``'s or ``global.json``'s
document), never from the command line's flags, so that any caller can print the same lines.
Every function returns the text without a final newline: ``print(run_summary(report, out))``
prints what ``evfuse run`` prints.

Errors are given with the coverage they were measured on (:func:`error_line`), and a scene with
moving objects splits them by region (:func:`motion_lines`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

from fusion.methods import method_label

if TYPE_CHECKING:
    from fusion.map.mapping import MapParams, MapResult

__all__ = ["MOTION_NAMES", "error_line", "fill_summary", "global_summary", "map_summary",
           "motion_lines", "run_summary"]

MOTION_NAMES = {"moving": "on moving objects", "crossed": "static, crossed by one",
                "static": "static, the rest"}
"""Key of :func:`fusion.scoring.errors_by_motion`'s split -> the words a summary gives it."""


def motion_lines(split: dict | None, indent: str) -> list[str]:
    """The errors of a scene with moving objects, one line per region.

    Parameters
    ----------
    split : dict or None
        :func:`fusion.scoring.errors_by_motion`'s split (``moving``, ``crossed``, ``static``,
        each with ``error_share``, ``mae_cm``, ``median_cm``, ``n`` and ``points``), or None.
    indent : str
        Put before each line.

    Returns
    -------
    list of str
        One line per region with its share of the error, MAE and median; none without a split.
    """
    if not split:
        return []
    lines = []
    for key, name in MOTION_NAMES.items():
        e = split[key]
        share = e["error_share"]
        what = (f"{e['points']:,} points, none on a surface" if not e["n"] else
                f"{100 * share:.0f} % of the error, MAE {e['mae_cm']:.2f} cm, median "
                f"{e['median_cm']:.2f} cm on {e['n']:,} px")
        lines.append(f"{indent}{name}: {what}")
    return lines


def error_line(e: dict | None) -> str:
    """One line of errors with the coverage they were measured on.

    Parameters
    ----------
    e : dict or None
        :func:`fusion.scoring.depth_errors`'s dict, or None where the view has no exact depth.

    Returns
    -------
    str
        MAE and median (cm) on the pixels with both depths, completeness, and the precision
        within 5 % / 1 % of the points, with their count.
    """
    if e is None:
        return "not scored (no exact depth in this view)"
    if not e.get("points"):
        return "no point to score"
    mae = ("no point on a surface" if not e["n"] else
           f"MAE {e['mae_cm']:.2f} cm on {e['n']:,} px, median {e['median_cm']:.2f} cm")
    return (f"{mae} (completeness {100 * e['completeness']:.1f} %), precision "
            f"{100 * e['precision_5pct']:.1f} % within 5 % / {100 * e['precision_1pct']:.1f} % "
            f"within 1 % of {e['points']:,} points ({e['no_surface']:,} off any surface)")


def map_summary(result: MapResult, params: MapParams, out: str | Path) -> str:
    """What ``evfuse map`` prints: the DSI's depth range, the map's counts, its errors.

    Parameters
    ----------
    result : MapResult
        The map (:func:`fusion.pipeline.map_window`).
    params : MapParams
        Its parameters, with the DSI range it used (``params.dsi_range``).
    out : str or Path
        The map folder written.

    Returns
    -------
    str
        Lines: the DSI range and where it came from; N1, the events used and dropped, the
        reference time, the median depth and (with exact depth) the errors; the points on the
        first or last plane, where any; the errors split by motion, where the scene moves; the
        folder.
    """
    info = result.info
    dsi = params.dsi_range
    lines = [f"DSI depth range {dsi.min_depth:g}-{dsi.max_depth:g} m ({dsi.source})"]
    median = info.get("depth_median_m")
    line = (f"N1 = {result.n1} map points from {info['events_used']} events "
            f"({info['events_dropped_before_poses'] + info['events_dropped_after_poses']} "
            f"outside the poses dropped), reference at {result.t_ref:.6f} s"
            + ("" if median is None else f", median depth {median:.3f} m"))
    if "errors" in info and info["errors"].get("points"):
        line += f"; against exact depth: {error_line(info['errors'])}"
    lines.append(line)
    boundary = info["boundary_plane_points"]
    if boundary["near"] or boundary["far"]:
        lines.append(f"{boundary['near'] + boundary['far']} points with their DSI maximum on "
                     f"the first ({boundary['near']}) or last ({boundary['far']}) plane: "
                     + ("dropped (their depth lies outside the range; --keep-boundary-planes "
                        "keeps them)" if boundary["dropped"] else "kept (--keep-boundary-planes)"))
    lines += motion_lines(info.get("errors_by_motion"), "  ")
    lines.append(f"written to {Path(out)}")
    return "\n".join(lines)


def fill_summary(info: dict, out: str | Path) -> str:
    """What ``evfuse fill`` prints: the counts, the filling score, the method, the errors.

    Parameters
    ----------
    info : dict
        The fill's ``info`` (:class:`fusion.fill.dense.DenseResult`, ``fill.json``).
    out : str or Path
        The fill folder written.

    Returns
    -------
    str
        Lines: N1 (in the frame), N2, the regions filled, beta and the method with its settings;
        with exact depth, the errors of the map points, the filled pixels and the dense map
        (each split by motion where the scene moves); the folder.
    """
    regions = ("no segmentation" if info["regions"] is None
               else f"{info['regions_filled']} of {info['regions']} regions filled")
    lines = [f"N1 = {info['N1']} ({info['N1_in_frame']} in the frame), N2 = {info['N2']} "
             f"({regions}), beta = {info['beta']:.4f}, method "
             f"{method_label(info['method'], info['method_params'])}"]
    if "errors" in info:
        e = info["errors"]
        for name, key in (("map points", "map"), ("filled pixels", "filled"), ("dense map", "all")):
            lines.append(f"  {name}: {error_line(e[key]['overall'])}")
            lines += motion_lines((info.get("errors_by_motion") or {}).get(key), "    ")
    lines.append(f"written to {Path(out)}")
    return "\n".join(lines)


def run_summary(report: dict, out: str | Path) -> str:
    """What ``evfuse run`` prints: a table of the run's counts and errors, then its files.

    Parameters
    ----------
    report : dict
        ``report.json``'s document (:func:`fusion.pipeline.run_pipeline`).
    out : str or Path
        The run folder.

    Returns
    -------
    str
        An empty line; one row per count (events, N1, N1 in the frame, N2, beta, the method)
        and per error (event map, map in the frame, filled pixels, dense map, each split by
        motion where the scene moves; the fused map's where ``--views`` fused one); a note on
        the measures where there are errors; an empty line; the overview, Figure 2, the point
        cloud and the folder.
    """
    out = Path(out)
    summary = report.get("errors_summary")
    rows = [("events", f"{report['events']:,}"), ("N1 (map points)", f"{report['N1']:,}"),
            ("N1 in the frame", f"{report['N1_in_frame']:,}"),
            ("N2 (after filling)", f"{report['N2']:,}"), ("beta", f"{report['beta']:.4f}"),
            ("filling method", f"{method_label(report['method'], report.get('method_params'))} "
                               f"({report['method_origin']})")]
    if summary is None:
        rows.append(("errors", "no ground truth (real data): not scored"))
    else:
        split = report.get("errors_by_motion") or {}
        for name, key in (("event map", "map"), ("map in the frame", "map_in_frame"),
                          ("filled pixels", "filled"), ("dense map", "all")):
            rows.append((name, error_line(summary[key])))
            rows += [("", text) for text in motion_lines(split.get(key), "  ")]
    fused = report.get("fused")
    if fused is not None:
        rows += [(f"fused, {fused['views']} views", f"N1 {fused['N1']:,} (one view "
                  f"{fused['N1_reference']:,}), N1 in the frame {fused['N1_in_frame']:,}, N2 "
                  f"{fused['N2']:,}, beta {fused['beta']:.4f}")]
        if fused["errors_summary"] is not None:
            rows += [(f"fused {name}", error_line(fused["errors_summary"][key]))
                     for name, key in (("event map", "map"), ("dense map", "all"))]
    width = max(len(k) for k, _ in rows)
    lines = [""] + [f"  {key:<{width}}  {value}" for key, value in rows]
    if summary is not None:
        lines.append("  (MAE on the pixels with both depths; completeness: share of the pixels "
                     "with exact depth that have one; precision: share of the points within 5 % "
                     "/ 1 % of the exact surface, none where there is no surface)")
    lines.append(f"\noverview: {out / 'overview.png'}\nFigure 2: {out / 'fill' / 'figure.png'}\n"
                 f"point cloud: {out / 'fill' / 'dense.ply'}\nwritten to {out}")
    return "\n".join(lines)


def _global_scores(m: dict | None) -> str:
    """One global-map score (:mod:`fusion.globalmap.score`) as text: accuracy and F-scores at
    2 and 5 cm, at 1 % of each point's depth and at the DSI's plane step there (where scored),
    with the point counts, or why it was not scored."""
    if m is None:
        return "-"
    if not m["points"] or not m["reference_points"]:
        return (f"not scored ({m['points']:,} points against {m['reference_points']:,} "
                "exact ones)")
    relative = "".join(f" / {100 * m[f'fscore_{key}']:.1f}" for key in ("depth1pct", "step")
                       if f"fscore_{key}" in m)
    names = "".join(f" / {name}" for key, name in (("depth1pct", "1 % of depth"),
                                                    ("step", "plane step"))
                    if f"fscore_{key}" in m)
    return (f"accuracy {m['accuracy_cm']:.2f} cm, F-score {100 * m['fscore_2cm']:.1f} / "
            f"{100 * m['fscore_5cm']:.1f}{relative} % at 2 / 5 cm{names}, precision "
            f"{100 * m['precision_5cm']:.1f} % at 5 cm, on {m['points']:,} points against "
            f"{m['reference_points']:,} exact ones")


def global_summary(document: dict, out: str | Path) -> str:
    """What ``evfuse map-global`` and ``evfuse run --global`` print: key views, rounds, scores.

    Parameters
    ----------
    document : dict
        ``global.json``'s document (:func:`fusion.globalmap.map_global`,
        :func:`fusion.globalmap.run_global`).
    out : str or Path
        The global map's folder.

    Returns
    -------
    str
        Lines: the key views and rounds of selection; one line per view (its time, N1, its
        semi-dense scores on a simulated sequence against the global maps' exact surface, why it
        was not filled where it was not); the global semi-dense, filled and TSDF scores, or on
        real data the views' agreement; the fused points, the mesh, the figure and the folder.
    """
    out = Path(out)
    rounds = document["rounds"]
    lines = [f"{document['key_views']} key views after {len(rounds)} round(s) of selection"
             f"{'' if document['rounds_converged'] else ' (not settled: the last round stands)'}"]
    for view in document["views"]:
        line = f"  {view['folder']}: t_ref {view['t_ref']:.3f} s, N1 {view['N1']:,}"
        if document["simulated"]:        # against the global maps' reference, as they are
            line += f"; semi-dense {_global_scores(view.get('semidense_global'))}"
        if view["fill_error"]:
            line += f"; not filled: {view['fill_error']}"
        lines.append(line)
    if document["simulated"]:
        for name in ("semidense", "filled", "tsdf"):
            lines.append(f"  global {name}: {_global_scores(document['global'][name])}")
        lines.append("  (every map against the same exact surface: the union of the key views' "
                     "exact views)")
    else:
        agreement = document["view_agreement"]
        median = agreement.get("median_abs_difference_m")
        overlap = agreement.get("overlap_points") or 0
        points = agreement.get("points") or 0
        lines.append("  no exact depth (real data): views agree within "
                     + ("- (no overlap)" if median is None or not math.isfinite(median)
                        or not overlap
                        else f"{100 * median:.2f} cm (median of {overlap:,} overlapping points)")
                     + (f", {agreement['confirmed_points']:,} of {points:,} points "
                        f"({100 * agreement['confirmed_share']:.1f} %) confirmed by another view"
                        if points else ", no map points"))
    files = document["files"]
    mesh = out / files["mesh"] if files["mesh"] else "-"
    lines.append(f"fused points: {out / files['global']}\nmesh: {mesh}\n"
                 f"figure: {out / files['figure']}\nwritten to {out}")
    return "\n".join(lines)
