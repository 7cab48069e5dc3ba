"""The mapping commands of ``evfuse``: ``map``, ``map-global``, ``fill``, ``run`` and ``show``
(each a parser builder and a handler that translates the flags, calls :mod:`fusion`'s public API
and prints the result's summary from :mod:`fusion.summaries`).

:func:`fusion.cli.build_parser` adds them to the ``evfuse`` parser with :func:`add_command`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fusion.cli_options import (
    DEFAULT_METHOD_HELP,
    GLOBAL_FLAG_NAMES,
    GLOBAL_METHOD_HELP,
    MAP_FLAG_NAMES,
    add_dense_options,
    add_global_options,
    add_map_options,
    add_subcommand,
)
from sim.cli import (
    FINITE,
    OVERWRITE_HELP,
    PNG_OVERWRITE_HELP,
    RECORDING_HELP,
    SEED,
    add_recording_options,
    count_type,
    open_recording,
)
from sim.validation import depth_metres

__all__ = ["COMMANDS", "add_command"]

COMMANDS = ("map", "map-global", "fill", "run", "show")
"""The subcommands this module builds (:func:`add_command`)."""


def _check_depth_flags(args: argparse.Namespace) -> None:
    """Refuse depth bounds that are implausible in metres (:func:`sim.validation.depth_metres`),
    before any work."""
    for flag, value in (("--min-depth", args.min_depth), ("--max-depth", args.max_depth)):
        if value is not None:
            depth_metres(flag, value)


def _cmd_map(args: argparse.Namespace) -> int:
    from fusion.map.emvs import DepthMapParams
    from fusion.pipeline import map_window
    from fusion.summaries import map_summary
    from sim.output import check_output_dir

    _check_depth_flags(args)
    open_recording(args, "sequence")
    check_output_dir(args.out, args.overwrite, [args.sequence])   # fail before the long work
    result, params = map_window(
        args.sequence, args.out, args.t0, args.t1, ref_time=args.ref_time,
        min_depth=args.min_depth, max_depth=args.max_depth,
        oracle_depth_range=args.depth_range == "oracle", planes=args.planes,
        depth=DepthMapParams(kernel=args.kernel, c=args.c, median=args.median,
                             keep_boundary_planes=args.keep_boundary_planes),
        clip_window=args.clip_window, overwrite=args.overwrite, progress=not args.quiet)
    print(map_summary(result, params, args.out))
    return 0


def _fill_method(args: argparse.Namespace, default: str | None = None):
    """The filling method the flags name (``default`` where neither ``--method`` nor
    ``--weighting`` names one; None: the paper's), resolved with its settings and the fill
    stage's parameters (:func:`fusion.methods.fill_request`)."""
    from fusion.fill.dense import DenseParams
    from fusion.fill.filling import FillParams, SelectionParams
    from fusion.fill.segmentation import SegmentationParams
    from fusion.methods import fill_request

    stages = DenseParams(
        segmentation=SegmentationParams(args.threshold, args.min_region),
        selection=SelectionParams(args.ring, args.min_ring_ratio, args.max_inside_ratio),
        fill=FillParams(args.weighting or "idw", sigma=args.sigma, scale=args.scale))
    named = args.method is not None or args.weighting is not None
    return fill_request(args.method if named else default, args.param or [],
                        weighting=args.weighting, stages=stages)


def _cmd_fill(args: argparse.Namespace) -> int:
    from fusion.fill.dense import fill_frame, write_fill
    from fusion.pipeline import fill_sources, fill_window
    from fusion.summaries import fill_summary
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
    print(fill_summary(result.info, args.out))
    return 0


def _global_fill_method(args: argparse.Namespace):
    """:func:`_fill_method` with the global map's default method
    (:data:`fusion.globalmap.GLOBAL_FILL_METHOD`)."""
    from fusion.globalmap import GLOBAL_FILL_METHOD

    return _fill_method(args, GLOBAL_FILL_METHOD)


def _global_params(args: argparse.Namespace, method):
    """The global map's parameters from the flags (``map-global``, ``run --global``)."""
    from dataclasses import replace

    from fusion.globalmap import GlobalParams, KeyViewParams
    from fusion.map.emvs import DepthMapParams

    keyviews = {key: value for key, value in (("baseline", args.baseline),
                                              ("angle_deg", args.angle),
                                              ("max_events", args.max_events))
                if value is not None}
    fusion = {key: value for key, value in (("min_views", args.min_views),
                                            ("depth_tolerance", args.depth_tolerance),
                                            ("reject", args.reject),
                                            ("fuse_depth", args.fuse_depth),
                                            ("voxel_size", args.voxel)) if value is not None}
    return GlobalParams(
        keyviews=KeyViewParams(**keyviews), fusion=replace(GlobalParams().fusion, **fusion),
        tsdf=replace(GlobalParams().tsdf, voxel_size=args.voxel), method=method.method.name,
        method_params=method.settings, dense=method.params, min_depth=args.min_depth,
        max_depth=args.max_depth, planes=args.planes,
        depth=DepthMapParams(kernel=args.kernel, c=args.c, median=args.median,
                             keep_boundary_planes=args.keep_boundary_planes, subplane=True),
        workers=args.workers)


def _refuse_for_global(args: argparse.Namespace) -> None:
    """Refuse, in one line, the map flags a global map cannot honour."""
    refused = [flag for flag, on in (("--resume", getattr(args, "resume", False)),
                                     ("--views", (getattr(args, "views", 1) or 1) > 1),
                                     ("--clip-window", getattr(args, "clip_window", False)),
                                     ("--depth-range oracle",
                                      getattr(args, "depth_range", "auto") == "oracle"))
               if on]
    if refused:
        raise ValueError(f"{', '.join(refused)} cannot be used with a global map (its key "
                         "views' windows are clipped to the data, its DSI range blind)")


def _cmd_map_global(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from fusion.globalmap import map_global
    from fusion.summaries import global_summary

    _refuse_for_global(args)
    _check_depth_flags(args)
    open_recording(args, "sequence")
    params = replace(_global_params(args, _global_fill_method(args)), t0=args.t0, t1=args.t1)
    document = map_global(args.sequence, args.out, params, overwrite=args.overwrite,
                          progress=not args.quiet)
    print(global_summary(document, args.out))
    return 0


def _cmd_run_global(args: argparse.Namespace) -> int:
    from fusion.globalmap import run_global
    from fusion.summaries import global_summary

    _refuse_for_global(args)
    _check_depth_flags(args)
    params = _global_params(args, _global_fill_method(args))
    document = run_global(args.source, args.out, args.t0, args.t1, params, spp=args.spp,
                          seed=args.seed, overwrite=args.overwrite, progress=not args.quiet,
                          profile=args.profile)
    print(global_summary(document, args.out))
    _print_profile(args)
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from fusion.map.emvs import DepthMapParams
    from fusion.pipeline import RunParams, is_sequence_folder, run_pipeline
    from fusion.summaries import run_summary

    open_recording(args, "source")
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
                          progress=not args.quiet, resume=args.resume, extra_map=extra_map,
                          profile=args.profile)
    print(run_summary(report, args.out))
    _print_profile(args)
    return 0


def _print_profile(args: argparse.Namespace) -> None:
    """With ``--profile``, the run's simulation profile (``OUT/sequence/profile.json``)."""
    if not args.profile:
        return
    import json

    from sim.profile import PROFILE_JSON, profile_table

    path = Path(args.out) / "sequence" / PROFILE_JSON
    if path.is_file():          # a resumed run whose simulation was complete before has none
        print(profile_table(json.loads(path.read_text(encoding="utf-8"))))
        print(f"profile written to {path}")
    else:
        print(f"no profile: the simulation in {path.parent} was complete before this run")


def _cmd_show(args: argparse.Namespace) -> int:
    from fusion.figures import write_image
    from fusion.pipeline import draw_overview, run_sources
    from sim.image_out import check_png_output
    from sim.output import check_output_file

    out = Path(args.out)
    check_output_file(out, run_sources(args.run_folder))   # the run folder is only read
    check_png_output(out, args.overwrite)
    image = draw_overview(args.run_folder)
    write_image(out, image)
    print(f"written to {out}")
    return 0


def _add_map(sub) -> None:
    """``evfuse map``."""
    mapping = sub.add_parser(
        "map", help="semi-dense depth map of a sequence from its events and poses (EMVS)",
        description="EMVS: events of a time window back-projected into a disparity space image "
                    "at a reference view; writes semidense_depth.exr, confidence.exr, mask.png, "
                    "overlay.png, map.ply and map.json (with errors against the exact depth for "
                    "simulated sequences).")
    mapping.add_argument("sequence", help="sequence folder (simulated or ECD)" + RECORDING_HELP)
    add_recording_options(mapping)
    mapping.add_argument("--out", required=True, help="folder to write the map into")
    mapping.add_argument("--ref-time", type=FINITE, default=None,
                         help="reference view time, s (default: the standard frame nearest the "
                              "middle of the window, the frame the map is filled with)")
    add_map_options(mapping)
    mapping.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    mapping.add_argument("--quiet", action="store_true", help="no progress bar")
    mapping.set_defaults(run=_cmd_map, flag_names=MAP_FLAG_NAMES)


def _add_map_global(sub) -> None:
    """``evfuse map-global``."""
    map_global = sub.add_parser(
        "map-global", help="one global map of a sequence from many key views: fused points, "
                           "a TSDF mesh, scores",
        description="Key views along the sequence (EMVS's criteria: --baseline, --angle, "
                    "--max-events), each mapped and filled as evfuse map and evfuse fill do "
                    "(views/NNN/map, views/NNN/fill), fused in the world frame (global.ply: "
                    "points that --min-views other views confirm or no more views "
                    "contradict), integrated into a TSDF "
                    "(mesh.ply), scored against the exact surface (simulated sequences) or "
                    "checked by the views' agreement (real recordings): global.json, "
                    "global_error.ply, global.png.")
    map_global.add_argument("sequence",
                            help="sequence folder (simulated or ECD)" + RECORDING_HELP)
    add_recording_options(map_global)
    map_global.add_argument("--out", required=True, help="folder to write")
    add_map_options(map_global, global_map=True)
    add_global_options(map_global)
    add_dense_options(map_global, GLOBAL_METHOD_HELP)
    map_global.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    map_global.add_argument("--quiet", action="store_true", help="no progress lines")
    map_global.set_defaults(run=_cmd_map_global, flag_names=GLOBAL_FLAG_NAMES)


def _add_fill(sub) -> None:
    """``evfuse fill``."""
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
    add_dense_options(fill)
    fill.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    fill.set_defaults(run=_cmd_fill)


def _add_run(sub) -> None:
    """``evfuse run`` (and ``run --global``)."""
    run = sub.add_parser(
        "run", help="simulate (or read), map, fill and score in one go",
        description="SOURCE is a built-in scene, a scene .toml file (simulated over the window "
                    "into OUT/sequence) or a sequence folder (simulated or a real ECD "
                    "recording). Writes map/, fill/, overview.png and report.json into OUT.")
    run.add_argument("source", help="scene name, scene file or sequence folder" + RECORDING_HELP)
    add_recording_options(run)
    run.add_argument("--out", required=True, help="run folder to write")
    add_map_options(run)
    run.add_argument("--spp", type=count_type(1), default=None, help="samples per pixel (scenes)")
    run.add_argument("--seed", type=SEED, default=None, help="simulation seed (scenes)")
    run.add_argument("--profile", action="store_true",
                     help="the simulation also writes OUT/sequence/profile.json, printed at the "
                          "end (as simulate --profile; scenes)")
    add_dense_options(run, f"{DEFAULT_METHOD_HELP}; with --global, {GLOBAL_METHOD_HELP}")
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
    add_global_options(run)
    run.set_defaults(run=_cmd_run, flag_names={**GLOBAL_FLAG_NAMES, "ref_time": "--ref-time",
                                                "map_global": "evfuse map-global",
                                                "run_global": "run --global",
                                                "profile": "--profile"},
                     interrupted="resume with the same command plus --resume (a simulation "
                                 "continues from its last checkpoint)")


def _add_show(sub) -> None:
    """``evfuse show``."""
    show = sub.add_parser("show", help="re-draw the overview of a run from its saved results")
    show.add_argument("run_folder", metavar="RUN", help="folder written by evfuse run")
    show.add_argument("--out", required=True,
                      help="PNG to write (outside RUN: the run folder is only read)")
    show.add_argument("--overwrite", action="store_true", help=PNG_OVERWRITE_HELP)
    show.set_defaults(run=_cmd_show)


def add_command(subparsers, name: str) -> None:
    """Add one of the mapping subcommands to a command line.

    Parameters
    ----------
    subparsers : argparse subparsers action
        What ``ArgumentParser.add_subparsers`` returned; the subcommand is added last.
    name : str
        One of :data:`COMMANDS`. Each handler is set as the subcommand's ``run`` default and
        takes the parsed arguments, returning the exit status.

    Raises
    ------
    ValueError
        An unknown name.
    """
    add_subcommand(dict(zip(COMMANDS, (_add_map, _add_map_global, _add_fill, _add_run,
                                       _add_show), strict=True)), subparsers, name)
