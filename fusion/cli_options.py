"""The flags several fusion commands of ``evfuse`` share: the map's (``map``, ``map-global``,
``run``), the fill's (``fill``, ``map-global``, ``run``) and the global map's (``map-global``,
``run --global``), and the tables that name a library parameter by its flag in an error
(``flag_names``, read by :func:`fusion.cli.main`).
"""

from __future__ import annotations

import argparse

from sim.cli import FINITE, NON_NEGATIVE, POSITIVE, count_type

__all__ = ["DEFAULT_METHOD_HELP", "GLOBAL_FLAG_NAMES", "GLOBAL_METHOD_HELP", "KEEP_BOUNDARY_HELP",
           "MAP_FLAG_NAMES", "VARIANT_FLAG_NAMES", "add_dense_options", "add_global_options",
           "add_map_options", "add_subcommand"]

VARIANT_FLAG_NAMES = {"variant": "--variant"}
"""Every command's name of a forced Mitsuba variant (see :func:`fusion.cli.main`); a command's own
``flag_names`` replace this table, so those of commands that render include it."""

MAP_FLAG_NAMES = {**VARIANT_FLAG_NAMES, "oracle": "--depth-range oracle"}
"""The library parameters that ``map`` and ``run`` name by another flag (see
:func:`fusion.cli.main`): ``resolve_dsi_range(oracle=True)`` is ``--depth-range oracle``."""

GLOBAL_FLAG_NAMES = {**MAP_FLAG_NAMES, "angle_deg": "--angle", "voxel_size": "--voxel",
                     "min_views": "--min-views", "depth_tolerance": "--depth-tolerance"}
"""The library parameters that ``map-global`` and ``run --global`` name by another flag."""

KEEP_BOUNDARY_HELP = ("keep the map points whose DSI maximum lies on the first or the last "
                      "depth plane, as rpg_emvs does (default: dropped, and counted in "
                      "map.json's boundary_plane_points: such a maximum says the depth lies "
                      "outside the range, not at its edge)")


def add_map_options(parser: argparse.ArgumentParser, global_map: bool = False) -> None:
    """Add the map flags (``map``, ``map-global``, ``run``): the window, the DSI's depth range
    and planes, and the depth map's detection (:class:`fusion.map.emvs.DepthMapParams`).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The subcommand's parser.
    global_map : bool
        For ``map-global``: without ``--clip-window`` and ``--depth-range`` (a global map's key
        views' windows are clipped to the data, its DSI range is blind).
    """
    parser.add_argument("--t0", type=FINITE, default=None,
                        help="window start, s (default: where the events and the poses begin; "
                             "for a scene, 0)")
    parser.add_argument("--t1", type=FINITE, default=None,
                        help="window end, s (default: where the events or the poses end; for a "
                             "scene, 1 s after --t0, refused where the scene ends sooner)")
    if not global_map:
        parser.add_argument("--clip-window", action="store_true",
                            help="map the part of --t0/--t1 that the events and poses (or the "
                                 "scene) cover (recorded in map.json) instead of refusing a "
                                 "window past them")
    parser.add_argument("--min-depth", type=FINITE, default=None,
                        help="nearest DSI plane, m (default: the near end of the working range "
                             "the scene file declares, else 0.2 m)")
    parser.add_argument("--max-depth", type=FINITE, default=None,
                        help="farthest DSI plane, m (default: the far end of the working range "
                             "the scene file declares, else 5 m)")
    if not global_map:
        parser.add_argument("--depth-range", choices=("auto", "oracle"), default="auto",
                            help="auto (default): --min-depth/--max-depth, else the scene's "
                                 "declared range, else 0.2-5 m, never the exact depth; oracle: "
                                 "the exact depth at the reference view widened by 20 %% "
                                 "(simulated sequences only; every output then says it used "
                                 "the answer)")
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


DEFAULT_METHOD_HELP = "paper-idw, the paper's"
"""``--method``'s default as ``evfuse fill`` and ``evfuse run`` state it."""
GLOBAL_METHOD_HELP = ("paper-colorization: the paper's, completed by colorization where it "
                      "leaves pixels empty")
"""``--method``'s default as ``evfuse map-global`` states it
(:data:`fusion.globalmap.GLOBAL_FILL_METHOD`, tested)."""


def add_dense_options(parser: argparse.ArgumentParser,
                      default_method: str = DEFAULT_METHOD_HELP) -> None:
    """Add the fill flags (``fill``, ``map-global``, ``run``): the filling method and its
    settings, and the paper's segmentation, selection and weights.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The subcommand's parser.
    default_method : str
        What ``--method``'s help says its default is.
    """
    parser.add_argument("--method", default=None,
                        help="filling method: a name listed by `evfuse methods` or "
                             f"module:function (default {default_method}; "
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


def add_global_options(parser: argparse.ArgumentParser) -> None:
    """Add the global map's flags (``map-global``, ``run --global``), all unset by default (the
    library's defaults apply), recorded as ``args.global_flags`` (flag, dest) for ``run``,
    which refuses them without --global.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The subcommand's parser.
    """
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
        help="k: a point that k other views agree with is kept in the fused "
             "clouds (default 1; 0 keeps every point)")
    add("--reject", choices=("outvoted", "unconfirmed"), default=None,
        help="which of the other points are dropped: those that more views "
             "contradict than confirm (outvoted, default) or all (unconfirmed)")
    add("--fuse-depth", action="store_true", default=None,
        help="move each fused point to the mean inverse depth of the views that "
             "confirm it (more precise, less recall; default: its view's depth)")
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


def add_subcommand(builders: dict, subparsers, name: str) -> None:
    """Add the subcommand ``name`` with its builder, for a command group's ``add_command``.

    Parameters
    ----------
    builders : dict
        The group's subcommands, in its help order: name -> ``builder(subparsers)``.
    subparsers : argparse subparsers action
        What ``ArgumentParser.add_subparsers`` returned; the subcommand is added last.
    name : str
        One of the group's subcommands.

    Raises
    ------
    ValueError
        An unknown name.
    """
    if name not in builders:
        raise ValueError(f"add_command: {name!r} is not one of {', '.join(builders)}")
    builders[name](subparsers)
