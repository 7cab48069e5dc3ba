"""The ``evfuse`` command line: parses, validates and calls the public API, nothing more."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["main"]


def _cmd_scenes(args: argparse.Namespace) -> int:
    from scenes import describe_scenes

    scenes = describe_scenes()
    width = max(len(name) for name in scenes)
    for name, description in scenes.items():
        print(f"{name:<{width}}  {description}")
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from scenes import resolve_scene
    from sim.events import EventParams
    from sim.sampling import SamplingParams
    from sim.scene import load_scene
    from sim.simulate import simulate

    scene = load_scene(resolve_scene(args.scene), seed=args.seed)
    events = EventParams.preset(args.noise, contrast=args.contrast, seed=scene.seed)
    sampling = SamplingParams(lam=args.lam, min_rate=args.min_rate, max_rate=args.max_rate)
    formats = tuple(f.strip() for f in args.event_format.split(",") if f.strip())
    result = simulate(scene, args.out, duration=args.duration, start=args.start, spp=args.spp,
                      variant=args.variant, overwrite=args.overwrite, progress=not args.quiet,
                      events=events, sampling=sampling, with_events=not args.no_events,
                      event_formats=formats)
    what = f"{result.n_frames} frames and depth maps ({result.n_renders} renders)"
    if result.n_events is not None:
        what += f", {result.n_events} events ({result.event_renders} renders)"
    print(f"wrote {what} with {result.variant} in {result.timings['total']:.1f} s to "
          f"{result.out}")
    return 0


def _events_file(folder: Path) -> Path:
    for name in ("events.h5", "events.txt"):
        if (folder / name).is_file():
            return folder / name
    raise ValueError(f"{folder}: no events.h5 or events.txt in this folder")


def _cmd_events(args: argparse.Namespace) -> int:
    import cv2

    from sim.eventio import event_frame, event_stats, read_events
    from sim.sequence import load_sequence

    folder = Path(args.sequence)
    sequence = load_sequence(folder)
    width, height = sequence.camera.width, sequence.camera.height
    path = _events_file(folder)
    events = read_events(path, width, height)
    if not args.stats:
        print(f"{path}: {len(events)} events (add --stats for statistics)")
        return 0
    stats = event_stats(events, width, height)
    print(f"{path}  ({width}x{height})")
    for key, value in stats.items():
        shown = f"{value:.6g}" if isinstance(value, float) else value
        print(f"  {key:<24} {shown}")
    out = Path(args.out) if args.out else folder / "event_frame.png"
    window = events
    if args.window is not None and len(events):
        t_end = int(events["t"][0] + args.window * 1e9)
        window = events[events["t"] < t_end]
    if not cv2.imwrite(str(out), cv2.cvtColor(event_frame(window, width, height),
                                              cv2.COLOR_RGB2BGR)):
        raise OSError(f"cannot write {out}")
    print(f"event frame of {len(window)} events written to {out}")
    return 0


def _cmd_map(args: argparse.Namespace) -> int:
    from fusion.emvs import DepthMapParams, DSIParams
    from fusion.mapping import MapParams, map_sequence, write_map
    from sim.sequence import check_output_dir

    params = MapParams(
        dsi=DSIParams(args.min_depth, args.max_depth, planes=args.planes),
        depth=DepthMapParams(kernel=args.kernel, c=args.c, median=args.median),
        t0=args.t0, t1=args.t1, ref_time=args.ref_time)
    check_output_dir(args.out, args.overwrite)                  # fail before the long work
    result = map_sequence(args.sequence, params, progress=not args.quiet)
    out = write_map(result, args.out, params, overwrite=args.overwrite)
    info = result.info
    line = (f"N1 = {result.n1} map points from {info['events_used']} events "
            f"({info['events_dropped_before_poses'] + info['events_dropped_after_poses']} "
            f"outside the poses dropped), reference at {result.t_ref:.6f} s")
    if "errors" in info and info["errors"].get("points"):
        e = info["errors"]
        line += (f"; against exact depth: MAE {e['mae_cm']:.2f} cm, median {e['median_cm']:.2f} "
                 f"cm, {100 * e['within_1pct']:.1f} % within 1 %")
    print(line)
    print(f"written to {out}")
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    from sim.eventio import convert_events

    width = height = None
    if args.sensor:
        try:
            width, height = (int(v) for v in args.sensor.lower().split("x"))
        except ValueError:
            raise ValueError(f"--sensor must look like 240x180, got {args.sensor!r}") from None
    else:
        folder = Path(args.src).resolve().parent
        if (folder / "images.txt").is_file() or (folder / "sequence.json").is_file():
            from sim.sequence import load_sequence

            camera = load_sequence(folder).camera
            width, height = camera.width, camera.height
    convert_events(args.src, args.dst, width=width, height=height)
    print(f"converted {args.src} to {args.dst}")
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="evfuse",
        description="Simulate event and standard cameras in ground-truthed scenes, and fuse them "
                    "into dense depth.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True)

    scenes = sub.add_parser("scenes", help="list the built-in scenes")
    scenes.set_defaults(run=_cmd_scenes)

    simulate = sub.add_parser(
        "simulate", help="render a scene into a sequence folder",
        description="Render a built-in scene (by name, see `evfuse scenes`) or a scene file into "
                    "a sequence folder: calib.txt, groundtruth.txt, images/, depth/, "
                    "sequence.json.")
    simulate.add_argument("scene", help="built-in scene name or path of a .toml scene file")
    simulate.add_argument("--out", required=True, help="sequence folder to write")
    simulate.add_argument("--duration", type=float, default=None,
                          help="seconds to simulate (default: the scene's duration)")
    simulate.add_argument("--start", type=float, default=0.0,
                          help="time of the scene's trajectory to start at, s (default 0)")
    simulate.add_argument("--seed", type=int, default=None,
                          help="seed of every random draw (default: the scene's seed)")
    simulate.add_argument("--spp", type=int, default=None,
                          help="samples per pixel, a perfect square (default: the scene's)")
    simulate.add_argument("--variant", default=None,
                          help="Mitsuba variant: cuda_ad_rgb, llvm_ad_rgb or scalar_rgb "
                               "(default: EVFUSE_VARIANT, else the fastest that works)")
    simulate.add_argument("--overwrite", action="store_true",
                          help="replace an existing output folder once the new one is complete")
    simulate.add_argument("--quiet", action="store_true", help="no progress bar")
    simulate.add_argument("--contrast", type=float, default=0.2,
                          help="contrast thresholds C+ = C- of the event camera (default 0.2)")
    simulate.add_argument("--noise", choices=("ideal", "realistic"), default="ideal",
                          help="event-camera noise preset (default ideal: no noise)")
    simulate.add_argument("--lambda", dest="lam", type=float, default=0.5,
                          help="adaptive sampling: largest change of log intensity between "
                               "renders, as a fraction of C (default 0.5)")
    simulate.add_argument("--min-rate", type=float, default=100.0,
                          help="lowest render rate for the event camera, Hz (default 100)")
    simulate.add_argument("--max-rate", type=float, default=20000.0,
                          help="highest render rate for the event camera, Hz (default 20000)")
    simulate.add_argument("--event-format", default="h5,txt",
                          help="event files to write: h5, txt or both (default h5,txt)")
    simulate.add_argument("--no-events", action="store_true",
                          help="render frames and depth only")
    simulate.set_defaults(run=_cmd_simulate)

    events = sub.add_parser("events", help="statistics and an event frame of a sequence's events")
    events.add_argument("sequence", help="sequence folder with events.h5 or events.txt")
    events.add_argument("--stats", action="store_true",
                        help="print count, rate, ON/OFF balance and write an event-frame PNG")
    events.add_argument("--window", type=float, default=None,
                        help="seconds of events from the start drawn in the event frame "
                             "(default: all)")
    events.add_argument("--out", default=None,
                        help="event-frame PNG (default: SEQUENCE/event_frame.png)")
    events.set_defaults(run=_cmd_events)

    mapping = sub.add_parser(
        "map", help="semi-dense depth map of a sequence from its events and poses (EMVS)",
        description="EMVS: events of a time window back-projected into a disparity space image "
                    "at a reference view; writes semidense_depth.exr, confidence.exr, mask.png, "
                    "overlay.png, map.ply and map.json (with errors against the exact depth for "
                    "simulated sequences).")
    mapping.add_argument("sequence", help="sequence folder (simulated or ECD)")
    mapping.add_argument("--out", required=True, help="folder to write the map into")
    mapping.add_argument("--t0", type=float, default=None, help="window start, s")
    mapping.add_argument("--t1", type=float, default=None, help="window end, s")
    mapping.add_argument("--ref-time", type=float, default=None,
                         help="reference view time, s (default: the middle of the window)")
    mapping.add_argument("--min-depth", type=float, default=0.2, help="nearest plane, m")
    mapping.add_argument("--max-depth", type=float, default=5.0, help="farthest plane, m")
    mapping.add_argument("--planes", type=int, default=100, help="depth planes (default 100)")
    mapping.add_argument("--kernel", type=int, default=5,
                         help="adaptive threshold block size (default 5)")
    mapping.add_argument("--c", type=float, default=5.0,
                         help="adaptive threshold constant (default 5)")
    mapping.add_argument("--median", type=int, default=5, help="median filter size (default 5)")
    mapping.add_argument("--overwrite", action="store_true")
    mapping.add_argument("--quiet", action="store_true", help="no progress bar")
    mapping.set_defaults(run=_cmd_map)

    convert = sub.add_parser("convert", help="convert events between ECD text and HDF5",
                             description="Convert events.txt (ECD) <-> events.h5 (DSEC layout), "
                                         "streaming. The format follows the file suffix.")
    convert.add_argument("src", help="events.txt or events.h5")
    convert.add_argument("dst", help="events.h5 or events.txt")
    convert.add_argument("--sensor", default=None,
                         help="sensor size WxH for HDF5 output (default: from the sequence "
                              "folder of SRC)")
    convert.set_defaults(run=_cmd_convert)
    return parser


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
        unless ``--debug``), 130 when interrupted.
    """
    args = _parser().parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"evfuse {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"evfuse {args.command}: interrupted; no complete output was written",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
