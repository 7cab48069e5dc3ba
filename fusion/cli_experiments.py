"""The experiment commands of ``evfuse``: ``methods``, ``bench`` and ``reproduce`` (each a parser
builder and a handler that translates the flags, calls :mod:`fusion.methods` or
:mod:`fusion.experiments` and prints what they did).

:func:`fusion.cli.build_parser` adds them to the ``evfuse`` parser with :func:`add_command`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fusion.cli_options import KEEP_BOUNDARY_HELP, VARIANT_FLAG_NAMES, add_subcommand
from sim.cli import NON_NEGATIVE, OVERWRITE_HELP, POSITIVE, count_type

__all__ = ["COMMANDS", "add_command"]

COMMANDS = ("methods", "bench", "reproduce")
"""The subcommands this module builds (:func:`add_command`)."""


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
    from sim.output import check_cache_dir, check_output_dir
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
    if not (args.noise < 1 and args.outliers <= 1):        # the flags' own bounds, >= 0 there
        raise ValueError(f"--noise {args.noise:g} --outliers {args.outliers:g}: expected "
                         "--noise in [0, 1) and --outliers in [0, 1]")
    params = BenchParams(noise=args.noise, outliers=args.outliers,
                         keep_boundary_planes=args.keep_boundary_planes)
    cache = bench_cache(args.out, args.cache)
    sources = bench_sources([] if args.family else scenes, cache)
    check_output_dir(args.out, args.overwrite, sources)
    check_cache_dir(cache, sources[1:])
    for variant in methods:                     # refused before a family's files are written
        MethodVariant.of(variant).checked()
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


def _add_methods(sub) -> None:
    """``evfuse methods``."""
    methods = sub.add_parser("methods", help="list the filling methods, one line each, name "
                                             "first (built-in and installed)")
    methods.add_argument("--params", action="store_true",
                         help="under each method, the settings --param takes, with their "
                              "defaults")
    methods.set_defaults(run=_cmd_methods)


def _add_bench(sub) -> None:
    """``evfuse bench``."""
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


def _add_reproduce(sub) -> None:
    """``evfuse reproduce``."""
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


def add_command(subparsers, name: str) -> None:
    """Add one of the experiment subcommands to a command line.

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
    add_subcommand(dict(zip(COMMANDS, (_add_methods, _add_bench, _add_reproduce), strict=True)),
                   subparsers, name)
