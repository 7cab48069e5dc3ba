"""The ``evfuse`` command line: parses, validates and calls the public API, nothing more."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

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
    from sim.scene import load_scene
    from sim.simulate import simulate

    scene = load_scene(resolve_scene(args.scene), seed=args.seed)
    result = simulate(scene, args.out, duration=args.duration, spp=args.spp,
                      variant=args.variant, overwrite=args.overwrite,
                      progress=not args.quiet)
    print(f"wrote {result.n_frames} frames and depth maps ({result.n_renders} renders, "
          f"{result.variant}, {result.timings['total']:.1f} s) to {result.out}")
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
    simulate.set_defaults(run=_cmd_simulate)
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
