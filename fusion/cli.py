"""The ``evfuse`` command line: parses, validates and calls the public API, nothing more.

:func:`main` is the entry point. This module holds the fusion commands (``map``, ``fill``,
``run``, ``show``, ``bench``, ``reproduce``, ``methods``); the simulator's (``simulate``,
``events``, ``twin``, ``convert``, ``scenes``) and the parser pieces both share live in
:mod:`sim.cli`, which this parser composes.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sim.cli import (
    FINITE,
    NON_NEGATIVE,
    OVERWRITE_HELP,
    POSITIVE,
    OneLineParser,
    add_command,
    count_type,
)
from sim.validation import (
    PLAUSIBLE_DEPTH_M,  # noqa: F401  (the bound of --min/--max-depth)
    ParameterError,
    depth_metres,
)

__all__ = ["main"]


def _check_depth_flags(args: argparse.Namespace) -> None:
    """Refuse depth bounds that are implausible in metres (:func:`sim.validation.depth_metres`),
    before any work."""
    for flag, value in (("--min-depth", args.min_depth), ("--max-depth", args.max_depth)):
        if value is not None:
            depth_metres(flag, value)


def _cmd_methods(args: argparse.Namespace) -> int:
    from fusion.methods import available_methods, format_value, param_defaults

    methods = available_methods()
    width = max(len(name) for name in methods)
    for name, method in methods.items():
        origin = "" if method.origin == "built-in" else f" [{method.origin}]"
        print(f"{name:<{width}}  {method.summary}{origin}")
        if args.params:
            defaults = param_defaults(method)
            text = ("not declared (--param is passed on as given)" if defaults is None else
                    ", ".join(f"{k}={format_value(v)}" for k, v in defaults.items()) or "none")
            print(f"{'':<{width}}  params: {text}")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from fusion.experiments.bench import (
        INPUTS,
        BenchParams,
        bench_cache,
        bench_command,
        bench_sources,
        run_bench,
    )
    from fusion.methods import MethodVariant, available_methods, method_variants, split_labels
    from sim.output import check_output_dir
    from sim.scene.families import KNOBS, write_family

    given = split_labels(",".join(args.method or []))
    variants = method_variants(given, args.param or [])
    defaults = [] if args.only else [MethodVariant(name) for name in available_methods()]
    methods = list({v.label: v for v in [*defaults, *variants]}.values())    # one row a label
    if not methods:
        raise ValueError("--only needs at least one --method")
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    inputs = [s.strip() for s in args.input.split(",") if s.strip()]
    # Everything refusable is refused before the cache (and a family's files in it) is made.
    if not inputs or not set(inputs) <= set(INPUTS):
        raise ValueError(f"--input {args.input}: expected among {', '.join(INPUTS)}")
    params = BenchParams(noise=args.noise, outliers=args.outliers,
                         keep_boundary_planes=args.keep_boundary_planes)
    cache = bench_cache(args.out, args.cache)
    check_output_dir(args.out, args.overwrite, bench_sources([] if args.family else scenes,
                                                             cache))
    given_knobs = {k: getattr(args, k) for k in KNOBS if getattr(args, k) is not None}
    if args.family:
        values = {}
        for name, text in given_knobs.items():
            try:
                values[name] = [float(v) for v in text.split(",") if v.strip()]
            except ValueError:
                raise ValueError(f"--{name.replace('_', '-')} {text}: expected numbers "
                                 "separated by commas") from None
        scenes = [str(path) for path in write_family(args.family, values, cache / "families")]
    elif given_knobs:
        raise ValueError(f"--{next(iter(given_knobs)).replace('_', '-')} is a knob of a scene "
                         "family: give --family too (staircase, sphere, cylinder, slanted, "
                         "heightfield)")
    command = bench_command(args.out, scenes=args.scenes, inputs=args.input, methods=given,
                            params=args.param or [], only=args.only,
                            keep_boundary_planes=args.keep_boundary_planes, noise=args.noise,
                            outliers=args.outliers, cache=args.cache, family=args.family,
                            knobs=given_knobs)
    rows = run_bench(methods, scenes, inputs, args.out, cache=args.cache, params=params,
                     overwrite=args.overwrite, progress=not args.quiet, command=command)
    failed = sum(row["status"] != "ok" for row in rows)
    print(f"{len(rows)} fills ({failed} failed) of {len(methods)} methods; written to "
          f"{Path(args.out) / 'bench.md'}, bench.csv, figures/")
    return 0


def _cmd_map(args: argparse.Namespace) -> int:
    from fusion.map.emvs import DepthMapParams
    from fusion.pipeline import map_window
    from sim.output import check_output_dir

    _check_depth_flags(args)
    check_output_dir(args.out, args.overwrite, [args.sequence])   # fail before the long work
    result, params = map_window(
        args.sequence, args.out, args.t0, args.t1, ref_time=args.ref_time,
        min_depth=args.min_depth, max_depth=args.max_depth,
        oracle_depth_range=args.depth_range == "oracle", planes=args.planes,
        depth=DepthMapParams(kernel=args.kernel, c=args.c, median=args.median,
                             keep_boundary_planes=args.keep_boundary_planes),
        clip_window=args.clip_window, overwrite=args.overwrite, progress=not args.quiet)
    out = Path(args.out)
    info = result.info
    dsi = params.dsi_range
    print(f"DSI depth range {dsi.min_depth:g}-{dsi.max_depth:g} m ({dsi.source})")
    median = info.get("depth_median_m")
    line = (f"N1 = {result.n1} map points from {info['events_used']} events "
            f"({info['events_dropped_before_poses'] + info['events_dropped_after_poses']} "
            f"outside the poses dropped), reference at {result.t_ref:.6f} s"
            + ("" if median is None else f", median depth {median:.3f} m"))
    if "errors" in info and info["errors"].get("points"):
        line += f"; against exact depth: {_error_line(info['errors'])}"
    print(line)
    boundary = info["boundary_plane_points"]
    if boundary["near"] or boundary["far"]:
        print(f"{boundary['near'] + boundary['far']} points with their DSI maximum on the first "
              f"({boundary['near']}) or last ({boundary['far']}) plane: "
              + ("dropped (their depth lies outside the range; --keep-boundary-planes keeps "
                 "them)" if boundary["dropped"] else "kept (--keep-boundary-planes)"))
    for text in _motion_lines(info.get("errors_by_motion"), "  "):
        print(text)
    print(f"written to {out}")
    return 0


def _fill_method(args: argparse.Namespace):
    """The filling method the flags name, resolved with its settings and the fill stage's
    parameters (:func:`fusion.methods.fill_request`)."""
    from fusion.fill.dense import DenseParams
    from fusion.fill.filling import FillParams, SelectionParams
    from fusion.fill.segmentation import SegmentationParams
    from fusion.methods import fill_request

    stages = DenseParams(
        segmentation=SegmentationParams(args.threshold, args.min_region),
        selection=SelectionParams(args.ring, args.min_ring_ratio, args.max_inside_ratio),
        fill=FillParams(args.weighting or "idw", sigma=args.sigma, scale=args.scale))
    return fill_request(args.method, args.param or [], weighting=args.weighting, stages=stages)


def _cmd_fill(args: argparse.Namespace) -> int:
    from fusion.fill.dense import fill_frame, write_fill
    from fusion.methods import method_label
    from fusion.pipeline import fill_sources, fill_window
    from sim.camera import read_calib
    from sim.exr import read_depth
    from sim.output import check_output_dir
    from sim.statistics import read_gray

    method = _fill_method(args)
    single = (args.frame, args.sparse_depth, args.calib)
    if args.map is not None and any(single):
        raise ValueError("give either a map folder or --frame, --sparse-depth and --calib")
    inputs = (fill_sources(args.map) if args.map is not None
              else [p for p in (*single, args.truth) if p is not None])
    check_output_dir(args.out, args.overwrite, inputs)
    if args.map is not None:
        result = fill_window(args.map, args.out, overwrite=args.overwrite, method=method)
    elif all(single):
        frame = read_gray(args.frame)
        camera = read_calib(args.calib, frame.shape[1], frame.shape[0])
        truth = read_depth(args.truth) if args.truth else None
        result = fill_frame(frame, read_depth(args.sparse_depth), camera, truth=truth,
                            info={"frame": str(args.frame), "sparse_depth": str(args.sparse_depth)},
                            method=method)
        write_fill(result, args.out, method.params, overwrite=args.overwrite, inputs=inputs)
    else:
        raise ValueError("give a map folder, or all of --frame, --sparse-depth and --calib")
    out = Path(args.out)
    info = result.info
    regions = ("no segmentation" if info["regions"] is None
               else f"{info['regions_filled']} of {info['regions']} regions filled")
    line = (f"N1 = {info['N1']} ({info['N1_in_frame']} in the frame), N2 = {info['N2']} "
            f"({regions}), beta = {info['beta']:.4f}, method "
            f"{method_label(info['method'], info['method_params'])}")
    print(line)
    if "errors" in info:
        e = info["errors"]
        for name, key in (("map points", "map"), ("filled pixels", "filled"), ("dense map", "all")):
            print(f"  {name}: {_error_line(e[key]['overall'])}")
            for text in _motion_lines((info.get("errors_by_motion") or {}).get(key), "    "):
                print(text)
    print(f"written to {out}")
    return 0


def _global_params(args: argparse.Namespace, method):
    """The global map's parameters from the flags (``map-global``, ``run --global``)."""
    from dataclasses import replace

    from fusion.globalmap import FusionParams, GlobalParams, KeyViewParams, TSDFParams
    from fusion.map.emvs import DepthMapParams

    keyviews = {key: value for key, value in (("baseline", args.baseline),
                                              ("angle_deg", args.angle),
                                              ("max_events", args.max_events))
                if value is not None}
    fusion = {key: value for key, value in (("min_views", args.min_views),
                                            ("depth_tolerance", args.depth_tolerance),
                                            ("voxel_size", args.voxel)) if value is not None}
    return GlobalParams(
        keyviews=KeyViewParams(**keyviews), fusion=replace(FusionParams(), **fusion),
        tsdf=TSDFParams(voxel_size=args.voxel), method=method.method.name,
        method_params=method.settings, dense=method.params, min_depth=args.min_depth,
        max_depth=args.max_depth, planes=args.planes,
        depth=DepthMapParams(kernel=args.kernel, c=args.c, median=args.median,
                             keep_boundary_planes=args.keep_boundary_planes),
        workers=args.workers)


def _print_global(document: dict, out: Path) -> None:
    """The global map's summary: key views, rounds, and the scores (or the views' agreement)."""
    rounds = document["rounds"]
    print(f"{document['key_views']} key views after {len(rounds)} round(s) of selection"
          f"{'' if document['rounds_converged'] else ' (not settled: the last round stands)'}")

    def scores(m: dict | None) -> str:
        if m is None:
            return "-"
        if not m["points"] or not m["reference_points"]:
            return (f"not scored ({m['points']:,} points against {m['reference_points']:,} "
                    "exact ones)")
        return (f"accuracy {m['accuracy_cm']:.2f} cm, completeness {m['completeness_cm']:.2f} cm,"
                f" F-score {100 * m['fscore_1cm']:.1f} / {100 * m['fscore_2cm']:.1f} / "
                f"{100 * m['fscore_5cm']:.1f} % at 1 / 2 / 5 cm, on {m['points']:,} points "
                f"against {m['reference_points']:,} exact ones")

    for view in document["views"]:
        line = f"  {view['folder']}: t_ref {view['t_ref']:.3f} s, N1 {view['N1']:,}"
        if document["simulated"]:
            line += f"; semi-dense {scores(view['semidense'])}"
        if view["fill_error"]:
            line += f"; not filled: {view['fill_error']}"
        print(line)
    if document["simulated"]:
        for name in ("semidense", "filled", "tsdf"):
            print(f"  global {name}: {scores(document['global'][name])}")
    else:
        agreement = document["view_agreement"]
        median = agreement.get("median_abs_difference_m")
        overlap = agreement.get("overlap_points") or 0
        points = agreement.get("points") or 0
        print("  no exact depth (real data): views agree within "
              + ("- (no overlap)" if median is None or not math.isfinite(median) or not overlap
                 else f"{100 * median:.2f} cm (median of {overlap:,} overlapping points)")
              + (f", {agreement['confirmed_points']:,} of {points:,} points "
                 f"({100 * agreement['confirmed_share']:.1f} %) confirmed by another view"
                 if points else ", no map points"))
    files = document["files"]
    mesh = out / files["mesh"] if files["mesh"] else "-"
    print(f"fused points: {out / files['global']}\nmesh: {mesh}\n"
          f"figure: {out / files['figure']}\nwritten to {out}")


def _refuse_for_global(args: argparse.Namespace) -> None:
    """Refuse, in one line, the map flags a global map cannot honour."""
    refused = [flag for flag, on in (("--resume", getattr(args, "resume", False)),
                                     ("--views", (getattr(args, "views", 1) or 1) > 1),
                                     ("--clip-window", args.clip_window),
                                     ("--depth-range oracle", args.depth_range == "oracle"))
               if on]
    if refused:
        raise ValueError(f"{', '.join(refused)} cannot be used with a global map (its key "
                         "views' windows are clipped to the data, its DSI range blind)")


def _cmd_map_global(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from fusion.globalmap import map_global

    _refuse_for_global(args)
    _check_depth_flags(args)
    params = replace(_global_params(args, _fill_method(args)), t0=args.t0, t1=args.t1)
    document = map_global(args.sequence, args.out, params, overwrite=args.overwrite,
                          progress=not args.quiet)
    _print_global(document, Path(args.out))
    return 0


def _cmd_run_global(args: argparse.Namespace) -> int:
    from fusion.globalmap import run_global

    _refuse_for_global(args)
    _check_depth_flags(args)
    params = _global_params(args, _fill_method(args))
    document = run_global(args.source, args.out, args.t0, args.t1, params, spp=args.spp,
                          seed=args.seed, overwrite=args.overwrite, progress=not args.quiet)
    _print_global(document, Path(args.out))
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from fusion.map.emvs import DepthMapParams
    from fusion.pipeline import RunParams, is_sequence_folder, run_pipeline

    if args.global_map:
        return _cmd_run_global(args)
    given = [flag for flag, name in args.global_flags if getattr(args, name) is not None]
    if given:
        raise ValueError(f"{', '.join(given)}: only with --global (the global map's flags)")
    _check_depth_flags(args)
    method = _fill_method(args)
    params = RunParams(t0=args.t0, t1=args.t1, min_depth=args.min_depth,
                       max_depth=args.max_depth,
                       oracle_depth_range=args.depth_range == "oracle", planes=args.planes,
                       depth=DepthMapParams(kernel=args.kernel, c=args.c, median=args.median,
                                            keep_boundary_planes=args.keep_boundary_planes),
                       dense=method.params, method=method.method.name,
                       method_params=method.settings,
                       spp=args.spp, seed=args.seed,
                       clip_window=args.clip_window)
    if is_sequence_folder(args.source):       # nothing to resume: map and fill start over
        args.interrupted = ("no complete output was written; the same command starts over "
                            "(it maps and fills again)")
    extra_map = None
    if args.views > 1:
        from fusion.globalmap import FusedViews

        extra_map = FusedViews(views=args.views)
    report = run_pipeline(args.source, args.out, params, overwrite=args.overwrite,
                          progress=not args.quiet, resume=args.resume, extra_map=extra_map)
    _print_report(report, Path(args.out))
    return 0


MOTION_NAMES = {"moving": "on moving objects", "crossed": "static, crossed by one",
                "static": "static, the rest"}


def _motion_lines(split: dict | None, indent: str) -> list[str]:
    """The errors of a scene with moving objects, split (fusion.scoring.errors_by_motion):
    one line per region with its share of the error, MAE and median."""
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


def _error_line(e: dict | None) -> str:
    """One line of errors with the coverage they were measured on (a depth_errors dict)."""
    if e is None:
        return "not scored (no exact depth in this view)"
    if not e.get("points"):
        return "no point to score"
    mae = ("no point on a surface" if not e["n"] else
           f"MAE {e['mae_cm']:.2f} cm on {e['n']:,} px, median {e['median_cm']:.2f} cm")
    return (f"{mae} (completeness {100 * e['completeness']:.1f} %), precision "
            f"{100 * e['precision_5pct']:.1f} % within 5 % / {100 * e['precision_1pct']:.1f} % "
            f"within 1 % of {e['points']:,} points ({e['no_surface']:,} off any surface)")


def _print_report(report: dict, out: Path) -> None:
    from fusion.methods import method_label

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
            rows.append((name, _error_line(summary[key])))
            rows += [("", text) for text in _motion_lines(split.get(key), "  ")]
    fused = report.get("fused")
    if fused is not None:
        rows += [(f"fused, {fused['views']} views", f"N1 {fused['N1']:,} (one view "
                  f"{fused['N1_reference']:,}), N1 in the frame {fused['N1_in_frame']:,}, N2 "
                  f"{fused['N2']:,}, beta {fused['beta']:.4f}")]
        if fused["errors_summary"] is not None:
            rows += [(f"fused {name}", _error_line(fused["errors_summary"][key]))
                     for name, key in (("event map", "map"), ("dense map", "all"))]
    width = max(len(k) for k, _ in rows)
    print()
    for key, value in rows:
        print(f"  {key:<{width}}  {value}")
    if summary is not None:
        print("  (MAE on the pixels with both depths; completeness: share of the pixels with "
              "exact depth that have one; precision: share of the points within 5 % / 1 % of "
              "the exact surface, none where there is no surface)")
    print(f"\noverview: {out / 'overview.png'}\nFigure 2: {out / 'fill' / 'figure.png'}\n"
          f"point cloud: {out / 'fill' / 'dense.ply'}\nwritten to {out}")


def _cmd_show(args: argparse.Namespace) -> int:
    from fusion.figures import write_image
    from fusion.pipeline import draw_overview, run_sources
    from sim.output import check_output_file

    out = Path(args.out)
    check_output_file(out, run_sources(args.run_folder))   # the run folder is only read
    image = draw_overview(args.run_folder)
    write_image(out, image)
    print(f"written to {out}")
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from fusion.experiments.reproduce import ReproduceParams, reproduce
    from fusion.methods import method_variants, split_labels

    tables = tuple(t.strip() for t in args.tables.split(",") if t.strip())
    scenes = tuple(s.strip() for s in args.scenes.split(",")) if args.scenes else None
    methods = tuple(method_variants(split_labels(",".join(args.method or [])),
                                    args.param or []))
    params = ReproduceParams(window=args.window, long_window=args.long_window, tables=tables,
                             scenes=scenes, methods=methods, frame_sensor=args.frame_sensor,
                             event_noise=args.event_noise,
                             keep_boundary_planes=args.keep_boundary_planes)
    report = reproduce(args.out, params, cache=args.cache, overwrite=args.overwrite,
                       progress=not args.quiet, views=args.views)
    print(f"{len(report['rows'])} windows in {report['total_s'] / 60:.1f} min")
    print(f"written to {Path(args.out) / 'report.md'}")
    return 0


VARIANT_FLAG_NAMES = {"variant": "--variant"}
"""Every command's name of a forced Mitsuba variant (see :func:`_in_flags`); a command's own
``flag_names`` replace this table, so those of commands that render include it."""

MAP_FLAG_NAMES = {**VARIANT_FLAG_NAMES, "oracle": "--depth-range oracle"}
"""The library parameters that ``map`` and ``run`` name by another flag (see :func:`_in_flags`):
``resolve_dsi_range(oracle=True)`` is ``--depth-range oracle``."""

GLOBAL_FLAG_NAMES = {**MAP_FLAG_NAMES, "angle_deg": "--angle", "voxel_size": "--voxel",
                     "min_views": "--min-views", "depth_tolerance": "--depth-tolerance"}
"""The library parameters that ``map-global`` and ``run --global`` name by another flag."""

KEEP_BOUNDARY_HELP = ("keep the map points whose DSI maximum lies on the first or the last "
                      "depth plane, as rpg_emvs does (default: dropped, and counted in "
                      "map.json's boundary_plane_points: such a maximum says the depth lies "
                      "outside the range, not at its edge)")


def _add_map_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--t0", type=FINITE, default=None,
                        help="window start, s (default: where the events and the poses begin; "
                             "for a scene, 0)")
    parser.add_argument("--t1", type=FINITE, default=None,
                        help="window end, s (default: where the events or the poses end; for a "
                             "scene, 1 s after --t0, refused where the scene ends sooner)")
    parser.add_argument("--clip-window", action="store_true",
                        help="map the part of --t0/--t1 that the events and poses (or the "
                             "scene) cover (recorded in map.json) instead of refusing a window "
                             "past them")
    parser.add_argument("--min-depth", type=FINITE, default=None,
                        help="nearest DSI plane, m (default: the near end of the working range "
                             "the scene file declares, else 0.2 m)")
    parser.add_argument("--max-depth", type=FINITE, default=None,
                        help="farthest DSI plane, m (default: the far end of the working range "
                             "the scene file declares, else 5 m)")
    parser.add_argument("--depth-range", choices=("auto", "oracle"), default="auto",
                        help="auto (default): --min-depth/--max-depth, else the scene's declared "
                             "range, else 0.2-5 m, never the exact depth; oracle: the exact "
                             "depth at the reference view widened by 20 %% (simulated sequences "
                             "only; every output then says it used the answer)")
    parser.add_argument("--planes", type=count_type(2), default=100,
                        help="depth planes, uniform in inverse depth (default 100, the paper's "
                             "240x180x100 grid)")
    parser.add_argument("--kernel", type=count_type(3), default=5,
                        help="adaptive threshold block size, odd (default 5, rpg_emvs's; the "
                             "paper's sliders: 15)")
    parser.add_argument("--c", type=FINITE, default=5.0,
                        help="adaptive threshold constant (default 5, rpg_emvs's; the paper's "
                             "sliders: 7)")
    parser.add_argument("--median", type=count_type(1), default=5,
                        help="median filter size, px (default 5, rpg_emvs's)")
    parser.add_argument("--keep-boundary-planes", action="store_true",
                        help=KEEP_BOUNDARY_HELP)


def _add_dense_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--method", default=None,
                        help="filling method: a name listed by `evfuse methods` or "
                             "module:function (default paper-idw, the paper's; "
                             "paper-WEIGHTING with --weighting), or NAME{KEY=VALUE,...} with "
                             "settings (as --param). The flags from --threshold on are the "
                             "paper's methods': with any other, one set off its default is "
                             "refused")
    parser.add_argument("--param", action="append", default=None, metavar="KEY=VALUE",
                        help="a setting of the filling method (repeatable), e.g. --method "
                             "plane --param residual_rel=0.03 (or plane.residual_rel=0.03); "
                             "VALUE is read as true, false, none or a number where it is one, "
                             "else as text, and coerced to the setting's type. `evfuse methods "
                             "--params` lists each method's settings and defaults; recorded as "
                             "method_params in fill.json / report.json")
    parser.add_argument("--threshold", type=NON_NEGATIVE, default=3.0,
                        help="region growing threshold, gray levels (default 3, the paper's)")
    parser.add_argument("--min-region", type=count_type(1), default=None,
                        help="smallest region kept, pixels (default max(20, Res / 1000), ours: "
                             "the paper ignores 'small regions' without a size)")
    parser.add_argument("--ring", type=count_type(1), default=3,
                        help="half-width of the band on both sides of a region's contour where "
                             "its map points are counted, px (default 3, the paper's "
                             "'3-pixel ring')")
    parser.add_argument("--min-ring-ratio", type=NON_NEGATIVE, default=0.30,
                        help="band map points per contour pixel needed to fill (default 0.30, "
                             "the paper's '30 %% of the contour length')")
    parser.add_argument("--max-inside-ratio", type=NON_NEGATIVE, default=0.05,
                        help="map points inside, off the band, per region pixel allowed "
                             "(default 0.05, the paper's '5 %% of the region size')")
    parser.add_argument("--weighting", choices=("idw", "gaussian", "exponential"),
                        default=None,
                        help="interpolation weights (default idw, the first of the paper's "
                             "Table 3, which finds the errors insensitive to it); --weighting W "
                             "is --method paper-W")
    parser.add_argument("--sigma", type=POSITIVE, default=5.0,
                        help="Gaussian weights' sigma, px (default 5, the paper's)")
    parser.add_argument("--scale", type=POSITIVE, default=1.0,
                        help="exponential weights' decay length, px: exp(-d / scale) "
                             "(default 1, the paper's exp(-d))")


def _add_global_options(parser: argparse.ArgumentParser) -> None:
    """The global map's flags (all unset by default: the library's defaults apply), recorded
    as ``args.global_flags`` (flag, dest) for ``run``, which refuses them without --global."""
    group = parser.add_argument_group("global map")
    actions = []

    def add(*flags, **options) -> None:
        actions.append(group.add_argument(*flags, **options))

    add("--baseline", type=POSITIVE, default=None,
        help="a new key view when the camera has moved this share of the last "
             "key view's median map depth (default 0.1)")
    add("--angle", type=POSITIVE, default=None,
        help="... or rotated this many degrees (default 10)")
    add("--max-events", type=count_type(1), default=None,
        help="... or this many events have come since it (default: no budget)")
    add("--min-views", type=count_type(0), default=None,
        help="k: other views that must agree on a point for the fused cloud to "
             "keep it (default 1; 0 keeps every point)")
    add("--depth-tolerance", type=POSITIVE, default=None,
        help="views agree on a point within this share of its depth "
             "(default 0.02)")
    add("--voxel", type=POSITIVE, default=None,
        help="voxel of the fused clouds and the TSDF, m (default: from the data)")
    add("--workers", type=count_type(1), default=None,
        help="key views mapped at once, one process each (default: the "
             "machine's cores)")
    parser.set_defaults(global_flags=tuple((action.option_strings[0], action.dest)
                                           for action in actions))


def _write_event_figure(path: Path, frame: np.ndarray, title: str) -> None:
    """``evfuse events --out``'s figure: the event frame (``(H, W, 3) uint8`` RGB) under its
    title, with the polarity legend, written to ``path``."""
    import cv2

    from fusion.figures import event_legend, panel_grid, write_image

    write_image(path, panel_grid([cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)], [title], columns=1,
                                 legends=[event_legend()]))


def _parser() -> argparse.ArgumentParser:
    from sim.output import evfuse_version

    parser = OneLineParser(
        prog="evfuse",
        description="Simulate event and standard cameras in ground-truthed scenes, and fuse them "
                    "into dense depth.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"evfuse {evfuse_version()}",
                        help="print evfuse's version and exit")
    sub = parser.add_subparsers(dest="command", required=True)
    # A forced Mitsuba variant is named --variant (simulate's flag; the other commands that render
    # take it from EVFUSE_VARIANT) by every command, as before; a command's own flag_names replace
    # this table (convert, which renders nothing).
    parser.set_defaults(flag_names=VARIANT_FLAG_NAMES)

    add_command(sub, "scenes")
    methods = sub.add_parser("methods", help="list the filling methods, one line each, name "
                                             "first (built-in and installed)")
    methods.add_argument("--params", action="store_true",
                         help="under each method, the settings --param takes, with their "
                              "defaults")
    methods.set_defaults(run=_cmd_methods)
    bench = sub.add_parser(
        "bench", help="every filling method x scene x input, scored against exact depth and "
                      "ranked (bench.md, bench.csv, figures/)",
        description="Simulates and maps one window per scene (cached in --cache), fills the "
                    "frame at its middle with every method from each input (emvs: the event "
                    "map; oracle: exact depth at the map's pixels; oracle-edges: exact depth "
                    "at every pixel that fired; oracle-noisy: oracle with noise and "
                    "outliers; oracle-canny: exact depth on the frame's Canny edges), and ranks "
                    "the methods.")
    bench.add_argument("--scenes", default="complex",
                       help="built-in scenes, 'complex', 'sliders' or map folders, "
                            "comma-separated (default complex)")
    bench.add_argument("--input", default="oracle",
                       help="inputs, comma-separated, among emvs, oracle, oracle-edges, "
                            "oracle-noisy, oracle-canny (default oracle)")
    bench.add_argument("--method", action="append", default=None,
                       help="a method to add to the built-in ones: a name or "
                            "module:function, or NAME{KEY=VALUE,...} for it with settings of "
                            "its own, e.g. 'plane{residual_rel=0.03}' (repeatable or "
                            "comma-separated; one method under several settings gives a row "
                            "each, labelled so)")
    bench.add_argument("--param", action="append", default=None, metavar="METHOD.KEY=VALUE",
                       help="a setting of every --method entry of METHOD, e.g. "
                            "plane.residual_rel=0.03 (repeatable); a bare KEY=VALUE only with "
                            "one --method. The built-ins that bench adds itself run at their "
                            "defaults; `evfuse methods --params` lists the settings")
    bench.add_argument("--family", default=None,
                       help="instead of --scenes, a scene family with a difficulty knob: "
                            "staircase, sphere, cylinder, slanted, heightfield (see "
                            "sim.scene.families); vary its knobs with the flags below")
    for knob, what in (("steps", "staircase: boxes (default 4)"),
                       ("step_depth", "staircase: m between steps (default 0.2)"),
                       ("radius", "sphere / cylinder: m (default 0.25 / 0.2)"),
                       ("distance", "sphere / cylinder: m (default 0.9)"),
                       ("shadow", "sphere: 1 a light casts its shadow, 0 not (default 1)"),
                       ("angle", "slanted: degrees from the image plane (default 50)"),
                       ("amplitude", "heightfield: m (default 0.08)"),
                       ("wavelength", "heightfield: m (default 0.4)"),
                       ("texture", "every family: 1 textured, 0 plain (default 1)")):
        bench.add_argument(f"--{knob.replace('_', '-')}", dest=knob, default=None,
                           help=f"comma-separated values; {what}")
    bench.add_argument("--keep-boundary-planes", action="store_true", help=KEEP_BOUNDARY_HELP)
    bench.add_argument("--only", action="store_true",
                       help="bench only the --method ones, not every built-in")
    bench.add_argument("--noise", type=NON_NEGATIVE, default=0.02,
                       help="relative depth noise of oracle-noisy (default 0.02)")
    bench.add_argument("--outliers", type=NON_NEGATIVE, default=0.05,
                       help="share of outliers in oracle-noisy (default 0.05)")
    bench.add_argument("--out", required=True, help="folder to write")
    bench.add_argument("--cache", default=None,
                       help="folder of simulated and mapped windows, re-used (default "
                            "OUT-cache)")
    bench.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    bench.add_argument("--quiet", action="store_true", help="no progress bar")
    bench.set_defaults(run=_cmd_bench, flag_names={**VARIANT_FLAG_NAMES, "inputs": "--input"})

    for name in ("simulate", "events", "twin"):
        add_command(sub, name, event_figure=_write_event_figure)

    mapping = sub.add_parser(
        "map", help="semi-dense depth map of a sequence from its events and poses (EMVS)",
        description="EMVS: events of a time window back-projected into a disparity space image "
                    "at a reference view; writes semidense_depth.exr, confidence.exr, mask.png, "
                    "overlay.png, map.ply and map.json (with errors against the exact depth for "
                    "simulated sequences).")
    mapping.add_argument("sequence", help="sequence folder (simulated or ECD)")
    mapping.add_argument("--out", required=True, help="folder to write the map into")
    mapping.add_argument("--ref-time", type=FINITE, default=None,
                         help="reference view time, s (default: the standard frame nearest the "
                              "middle of the window, the frame the map is filled with)")
    _add_map_options(mapping)
    mapping.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    mapping.add_argument("--quiet", action="store_true", help="no progress bar")
    mapping.set_defaults(run=_cmd_map, flag_names=MAP_FLAG_NAMES)

    map_global = sub.add_parser(
        "map-global", help="one global map of a sequence from many key views: fused points, "
                           "a TSDF mesh, scores",
        description="Key views along the sequence (EMVS's criteria: --baseline, --angle, "
                    "--max-events), each mapped and filled as evfuse map and evfuse fill do "
                    "(views/NNN/map, views/NNN/fill), fused in the world frame (global.ply: "
                    "points that --min-views other views confirm), integrated into a TSDF "
                    "(mesh.ply), scored against the exact surface (simulated sequences) or "
                    "checked by the views' agreement (real recordings): global.json, "
                    "global_error.ply, global.png.")
    map_global.add_argument("sequence", help="sequence folder (simulated or ECD)")
    map_global.add_argument("--out", required=True, help="folder to write")
    _add_map_options(map_global)
    _add_global_options(map_global)
    _add_dense_options(map_global)
    map_global.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    map_global.add_argument("--quiet", action="store_true", help="no progress lines")
    map_global.set_defaults(run=_cmd_map_global, flag_names=GLOBAL_FLAG_NAMES)

    fill = sub.add_parser(
        "fill", help="fill a semi-dense map into a dense one with the standard frame",
        description="Fill the map points projected into the standard frame nearest the map's "
                    "reference view (by default the paper's way: segment the frame by region "
                    "growing, fill the regions bounded by map points; --method another), score "
                    "the result (against the exact depth for a simulated sequence). Writes "
                    "dense_depth.exr, segments.png, filled_mask.png, figure.png, dense.ply, "
                    "fill.json (and error.png with ground truth, confidence.exr where the "
                    "method gives one).")
    fill.add_argument("map", nargs="?", default=None, help="folder written by evfuse map")
    fill.add_argument("--frame", default=None, help="any gray frame (instead of a map)")
    fill.add_argument("--sparse-depth", default=None,
                      help="EXR z-depth of the map points in that frame's pixels, 0 = none")
    fill.add_argument("--calib", default=None, help="calib.txt of that frame's camera")
    fill.add_argument("--truth", default=None, help="EXR exact depth of that frame, to score")
    fill.add_argument("--out", required=True, help="folder to write")
    _add_dense_options(fill)
    fill.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    fill.set_defaults(run=_cmd_fill)

    run = sub.add_parser(
        "run", help="simulate (or read), map, fill and score in one go",
        description="SOURCE is a built-in scene, a scene .toml file (simulated over the window "
                    "into OUT/sequence) or a sequence folder (simulated or a real ECD "
                    "recording). Writes map/, fill/, overview.png and report.json into OUT.")
    run.add_argument("source", help="scene name, scene file or sequence folder")
    run.add_argument("--out", required=True, help="run folder to write")
    _add_map_options(run)
    run.add_argument("--spp", type=count_type(1), default=None, help="samples per pixel (scenes)")
    run.add_argument("--seed", type=count_type(0), default=None, help="simulation seed (scenes)")
    _add_dense_options(run)
    run.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    run.add_argument("--resume", action="store_true",
                     help="continue an interrupted run of the same command from OUT.partial: "
                          "its simulation resumes from its checkpoint (as simulate --resume), "
                          "then the map and the fill are made again")
    run.add_argument("--views", type=count_type(1), default=1, metavar="N",
                     help="also fuse the map with those of N-1 neighbouring views (reference "
                          "times t_ref +- k quarter-windows, windows of the same length; every "
                          "view's candidates at c = 0, kept where two other views agree within "
                          "2 %%) into the reference view, fill and score it: OUT/fused/ and "
                          "report.json's fused block (default 1: the one-view map only; 5 "
                          "is a good start)")
    run.add_argument("--quiet", action="store_true", help="no progress bars")
    run.add_argument("--global", dest="global_map", action="store_true",
                     help="one global map from many key views (as evfuse map-global) over the "
                          "window, by default the whole scene")
    _add_global_options(run)
    run.set_defaults(run=_cmd_run, flag_names={**GLOBAL_FLAG_NAMES, "ref_time": "--ref-time",
                                                "map_global": "evfuse map-global",
                                                "run_global": "run --global"},
                     interrupted="resume with the same command plus --resume (a simulation "
                                 "continues from its last checkpoint)")

    show = sub.add_parser("show", help="re-draw the overview of a run from its saved results")
    show.add_argument("run_folder", metavar="RUN", help="folder written by evfuse run")
    show.add_argument("--out", required=True,
                      help="PNG to write (outside RUN: the run folder is only read)")
    show.set_defaults(run=_cmd_show)

    repro = sub.add_parser(
        "reproduce", help="the paper's three tables (and complex surfaces) on the twin scenes",
        description="Simulates the paper's windows of the twin scenes (cached in --cache), maps, "
                    "fills and scores them, and writes report.md with the paper's numbers "
                    "beside ours, report.json, figures/ and runs/.")
    repro.add_argument("--out", required=True, help="report folder to write")
    repro.add_argument("--cache", default=None,
                       help="folder of simulated windows, re-used (default OUT-cache)")
    repro.add_argument("--window", type=POSITIVE, default=1.0,
                       help="slider window length, s (default 1, as the paper)")
    repro.add_argument("--long-window", type=POSITIVE, default=2.0,
                       help="6-DoF and complex-surface window length, s (default 2, as the "
                            "paper's Table 1)")
    repro.add_argument("--tables", default="1,2,3,complex",
                       help="tables to make, among 1,2,3,complex (default all)")
    repro.add_argument("--scenes", default=None, help="only these scenes (comma-separated)")
    repro.add_argument("--frame-sensor", default=None, metavar="NAME",
                       help="every scene's standard-camera sensor: ideal, davis240c_aps or "
                            "machine_vision (default: each scene's own)")
    repro.add_argument("--event-noise", choices=("ideal", "realistic"), default="ideal",
                       help="the event camera's noise preset (default ideal; realistic: "
                            "threshold mismatch, refractory period, the photoreceptor's low-pass "
                            "filter, leak and shot-noise events, hot pixels)")
    repro.add_argument("--method", action="append", default=None,
                       help="a filling method to run on every window besides the paper's "
                            "(repeatable or comma-separated; NAME{KEY=VALUE,...} with settings "
                            "of its own; default none: the paper's tables use its three "
                            "weightings, inverse distance first)")
    repro.add_argument("--param", action="append", default=None, metavar="METHOD.KEY=VALUE",
                       help="a setting of every --method entry of METHOD (repeatable); a bare "
                            "KEY=VALUE only with one --method. Never changes the paper's "
                            "tables; `evfuse methods --params` lists the settings")
    repro.add_argument("--keep-boundary-planes", action="store_true", help=KEEP_BOUNDARY_HELP)
    repro.add_argument("--views", type=count_type(1), default=1, metavar="N",
                       help="Table 1 also with each map fused with N-1 neighbouring views' "
                            "(as evfuse run --views), beside the one-view columns (default 1: "
                            "one view only)")
    repro.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    repro.add_argument("--quiet", action="store_true", help="no progress bar")
    repro.set_defaults(run=_cmd_reproduce)

    add_command(sub, "convert")
    add_command(sub, "generate")
    add_command(sub, "dataset")
    for command in sub.choices.values():         # --debug after the command works too
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help="show tracebacks on errors")
        # the flags a library error's parameters may be named by (see _in_flags)
        command.set_defaults(option_strings=frozenset(command._option_string_actions))
    return parser


class _Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a job scheduler's time limit), taken down the path of Ctrl-C: files
    are closed, ``.partial`` outputs and checkpoints stay, and the user is told how to resume."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise _Terminated


def _interruption(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM behind ``exc``, if any: raised inside a Python callback of
    Mitsuba's renderer, it comes out wrapped in Dr.Jit's RuntimeError (as its ``__cause__``)."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


def _interrupted(args: argparse.Namespace, exc: KeyboardInterrupt) -> int:
    terminated = isinstance(exc, _Terminated)
    hint = getattr(args, "interrupted", "no complete output was written")
    print(f"evfuse {args.command}: {'terminated' if terminated else 'interrupted'}; {hint}",
          file=sys.stderr)
    return 143 if terminated else 130


def _quiet_opencv() -> None:
    """OpenCV's own warnings (``[ WARN:0@0.1] ... imread_(...)``) off: evfuse checks every image
    it reads and says what is wrong in its own one line."""
    import cv2

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def _stdout_is_closed() -> bool:
    """Whether standard output is a pipe whose reader has gone (``evfuse methods | head``); True
    where it cannot be told."""
    import select

    try:
        fd = sys.stdout.fileno()
        poller = select.poll()
    except (OSError, ValueError, AttributeError):
        return True
    poller.register(fd, select.POLLOUT)
    return any(event & (select.POLLERR | select.POLLHUP) for _, event in poller.poll(0))


def _quit_on_closed_stdout() -> int:
    """Exit quietly when the reader of standard output has gone, as Python's documentation of
    SIGPIPE recommends: the rest of the output goes to the null device (so that the flush at
    exit does not fail again), and the status is that of a process ended by SIGPIPE."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    finally:
        os.close(devnull)
    return 128 + signal.SIGPIPE if hasattr(signal, "SIGPIPE") else 1


def _in_flags(exc: Exception, args: argparse.Namespace) -> str:
    """A library error in the command line's terms: each parameter a
    :class:`sim.validation.ParameterError` names becomes the subcommand's flag of that name
    (``out`` -> ``--out``, ``overwrite`` -> ``--overwrite``), or the flag the subcommand maps it
    to (``args.flag_names``, set with ``set_defaults``); a parameter with no flag keeps the
    library's wording. Any other error is printed as it is."""
    if not isinstance(exc, ParameterError):
        return str(exc)
    options = getattr(args, "option_strings", ())
    names = {name: f"--{name.replace('_', '-')}" for name in exc.terms
             if f"--{name.replace('_', '-')}" in options}
    names.update(getattr(args, "flag_names", {}))
    return exc.rephrase(names)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``evfuse`` command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 on success, 2 for bad input (one line on standard error, no traceback
        unless ``--debug``), 1 for an unexpected error (also one line), 130 when interrupted
        (Ctrl-C) and 143 when terminated (SIGTERM), both with one line that says what is left,
        and 141 (SIGPIPE's), silently, when the reader of standard output has gone
        (``evfuse methods --params | head``).
    """
    _quiet_opencv()
    args = _parser().parse_args(argv)
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_terminated) if in_main_thread else None
    try:
        code = args.run(args)
        sys.stdout.flush()                        # a closed pipe fails here, not at exit
        return code
    except BrokenPipeError as exc:
        if not _stdout_is_closed():
            if args.debug:
                raise
            print(f"evfuse {args.command}: error: {exc}", file=sys.stderr)
            return 2
        return _quit_on_closed_stdout()
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"evfuse {args.command}: error: {_in_flags(exc, args)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        return _interrupted(args, exc)
    except Exception as exc:                      # a bug or an unforeseen failure: still one line
        interruption = _interruption(exc)
        if interruption is not None:
            return _interrupted(args, interruption)
        if args.debug:
            raise
        print(f"evfuse {args.command}: unexpected error: {type(exc).__name__}: {exc} (run with "
              "--debug for the traceback)", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
