"""The simulator's commands of ``evfuse``: ``simulate``, ``events``, ``twin``, ``convert``,
``scenes``, ``generate`` and ``dataset`` (each a parser builder and a handler that parses, calls
:mod:`sim`'s public API and prints), and the parser pieces every evfuse command shares: the typed
number flags, the one-line refusal parser and the help of ``--overwrite``.

:func:`fusion.cli.main` is the ``evfuse`` entry point: it adds these commands to its parser with
:func:`add_command` and runs them. This module never imports :mod:`fusion` (the simulator is the
lower layer); the one figure ``events --out`` draws is made by a function the caller passes in.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import numpy as np

from sim.validation import MAX_SEED, finite, non_negative, positive

__all__ = ["COMMANDS", "FINITE", "NON_NEGATIVE", "OVERWRITE_HELP", "PNG_OVERWRITE_HELP",
           "POSITIVE", "RECORDING_HELP", "SEED", "OneLineParser", "add_command",
           "add_recording_options", "count_type", "number_type", "open_recording"]

COMMANDS = ("scenes", "simulate", "events", "twin", "convert", "generate", "dataset")
"""The subcommands this module builds (:func:`add_command`)."""

OVERWRITE_HELP = ("replace OUT if it is a folder evfuse wrote (it holds evfuse's .evfuse marker), "
                  "once the new one is complete; any other folder is never replaced")
"""The help of every command's ``--overwrite`` that replaces a folder."""
PNG_OVERWRITE_HELP = ("replace OUT if it is a PNG evfuse wrote (its 'Software: evfuse' text "
                      "chunk); any other file is never replaced")
"""The help of ``--overwrite`` where OUT is one PNG (``events --out``, ``show --out``)."""


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose refusals are one line (``evfuse CMD: error: ...``, exit 2), as
    every other refusal of evfuse is, instead of argparse's usage block before the error."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def number_type(check: Callable[[str, object], float], what: str) -> Callable[[str], float]:
    """An argparse ``type=``: the text as a float that passes ``check``.

    Parameters
    ----------
    check : callable
        A validator of :mod:`sim.validation` (``check(name, value)`` returns the float or raises
        ValueError).
    what : str
        What is expected, for the refusal (``a finite number > 0``).

    Returns
    -------
    callable
        ``str -> float``; argparse prints ``argument --flag: expected WHAT, got 'TEXT'``.
    """
    def parse(text: str) -> float:
        try:
            return check("value", float(text))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    parse.__name__ = what
    return parse


def count_type(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An argparse ``type=``: the text as an integer >= ``minimum`` (and <= ``maximum``).

    Parameters
    ----------
    minimum : int
    maximum : int, optional

    Returns
    -------
    callable
        ``str -> int``.
    """
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum or (maximum is not None and value > maximum):
            expected = (f"an integer >= {minimum}" if maximum is None
                        else f"an integer in {minimum}..{maximum}")
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value
    parse.__name__ = (f"integer >= {minimum}" if maximum is None
                      else f"integer in {minimum}..{maximum}")
    return parse


SEED = count_type(0, MAX_SEED)
"""``type=`` of a ``--seed`` flag: 0..2**32 - 1 (:data:`sim.validation.MAX_SEED`)."""


FINITE = number_type(finite, "a finite number")
"""``type=`` of a flag that takes any finite number."""
POSITIVE = number_type(positive, "a finite number > 0")
"""``type=`` of a flag that takes a finite number > 0."""
NON_NEGATIVE = number_type(non_negative, "a finite number >= 0")
"""``type=`` of a flag that takes a finite number >= 0."""


RECORDING_HELP = (" (or one event file: .aedat4 with its frames and IMU, .raw; with --calib "
                  "and --poses; or a ROS bag, .bag, .mcap or a ROS 2 bag folder, with its "
                  "camera info, frames, poses and IMU)")
"""What a recording argument's help adds: it may be one event file (:mod:`sim.recording`)."""


def add_recording_options(parser: argparse.ArgumentParser) -> None:
    """``--calib`` and ``--poses`` of a command that reads a recording given as one file."""
    parser.add_argument("--recording-calib", "--calib", dest="recording_calib", default=None,
                        metavar="CALIB",
                        help="calib.txt (fx fy cx cy k1 k2 p1 p2 k3) of a recording given as "
                             "one event file (.raw, .aedat4 hold no intrinsics)")
    parser.add_argument("--poses", dest="recording_poses", default=None, metavar="POSES",
                        help="groundtruth.txt (t px py pz qx qy qz qw) of a recording given as "
                             "one event file")
    parser.add_argument("--topic", dest="recording_topic", default=None, metavar="TOPIC",
                        help="event topic of a recording given as a ROS bag (default: its one "
                             "dvs_msgs/EventArray topic; frames, camera info, poses and IMU "
                             "are then found by message type in its namespace)")


def open_recording(args: argparse.Namespace, attr: str) -> None:
    """Replace ``args.<attr>``, a recording given as one event file, by the sequence folder it
    is unpacked into (:func:`sim.recording.recording_folder`, a cache outside the input); a
    folder or a scene is left as it is."""
    from sim.recording import is_recording_file, recording_folder
    from sim.validation import ParameterError

    given = getattr(args, attr)
    calib, poses = args.recording_calib, args.recording_poses
    topic = getattr(args, "recording_topic", None)
    if not is_recording_file(given):
        if (calib or poses or topic) and Path(given).is_dir():
            raise ValueError(f"{given} is a sequence folder, which has its own calib.txt and "
                             "groundtruth.txt; --calib, --poses and --topic go with a "
                             "recording given as one event file or bag")
        return
    try:
        setattr(args, attr, str(recording_folder(given, calib=calib, poses=poses,
                                                 topic=topic)))
    except ParameterError as error:
        raise ValueError(error.rephrase({"calib": "--calib CALIB", "poses": "--poses",
                                         "topic": "--topic"})) from None


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
    from sim.simulate import simulate, simulate_inputs

    # Said in the flags' terms, before the dataclasses would say it in their fields' names.
    if not (math.isfinite(args.contrast) and args.contrast > 0):
        raise ValueError(f"--contrast {args.contrast:g}: expected a contrast threshold > 0 (log "
                         "intensity units, e.g. 0.2)")
    if not 0 < args.lam <= 1:
        raise ValueError(f"--lambda {args.lam:g}: expected a fraction of the contrast threshold "
                         "in (0, 1]")
    if not 0 < args.min_rate <= args.max_rate:
        raise ValueError(f"--min-rate {args.min_rate:g} and --max-rate {args.max_rate:g}: "
                         "expected 0 < --min-rate <= --max-rate (Hz)")
    scene, inputs = simulate_inputs(
        load_scene(resolve_scene(args.scene), seed=args.seed), start=args.start,
        duration=args.duration, contrast=args.contrast, noise=args.noise, lam=args.lam,
        min_rate=args.min_rate, max_rate=args.max_rate, wavefront=args.wavefront,
        sampler=args.sampler, spp=args.spp, frame_sensor=args.frame_sensor, rig=args.rig,
        motion_truth=not args.no_motion_truth)
    formats = tuple(f.strip() for f in args.event_format.split(",") if f.strip())
    formats += tuple(name for name in args.format or () if name not in formats)
    result = simulate(scene, args.out, variant=args.variant, overwrite=args.overwrite,
                      progress=not args.quiet, with_events=not args.no_events,
                      event_formats=formats, resume=args.resume, profile=args.profile, **inputs)
    what = f"{result.n_frames} frames and depth maps ({result.n_renders} renders)"
    if result.n_events is not None and result.sampler == "pixel":
        what += (f", {result.n_events} events ({result.event_renders} frames and "
                 f"{result.event_pixel_samples:,} pixel samples)")
    elif result.n_events is not None:
        what += f", {result.n_events} events ({result.event_renders} renders)"
    if not args.no_motion_truth:
        parts = ["velocity", "IMU", "flow", "motion field", "object masks"]
        if result.n_events is not None and "h5" in formats:
            parts.append("per-event depth")
        if result.n_events is not None:
            parts.append("per-event labels")
        what += f", the motion ground truth ({', '.join(parts)})"
    print(f"wrote {what} with {result.variant} in {result.timings['total']:.1f} s to "
          f"{result.out}")
    if result.profile is not None:
        from sim.profile import PROFILE_JSON, profile_table

        print(profile_table(result.profile))
        print(f"profile written to {Path(result.out) / PROFILE_JSON}")
    return 0


def _cmd_events(args: argparse.Namespace) -> int:
    from sim.image_out import check_png_output
    from sim.output import check_output_file
    from sim.statistics import (
        compare_stats,
        event_frame,
        first_seconds,
        read_recording,
        recording_stats,
    )

    open_recording(args, "sequence")
    if args.compare is not None:
        from sim.recording import is_recording_file, recording_folder

        if is_recording_file(args.compare):          # the same camera's calibration
            args.compare = str(recording_folder(args.compare, calib=args.recording_calib,
                                                poses=args.recording_poses))
    folder = Path(args.sequence)
    if args.compare is not None and not args.stats:
        raise ValueError("--compare compares statistics: add --stats")
    if args.out is not None and not args.stats:
        raise ValueError("--out is the event frame of --stats: add --stats")
    if args.out is not None:                     # never into a recording it reads
        check_output_file(args.out, [folder, args.compare])
        check_png_output(args.out, args.overwrite)
    elif args.overwrite:
        raise ValueError("--overwrite replaces the --out PNG: add --out")
    sequence, path, events = read_recording(folder)
    if not args.stats:
        print(f"{path}: {len(events)} events (add --stats for statistics)")
        return 0
    stats = recording_stats(sequence, events)
    width, height = sequence.camera.width, sequence.camera.height
    show = lambda v: f"{v:.6g}" if isinstance(v, float) else str(v)  # noqa: E731
    if args.compare is None:
        print(f"{path}  ({width}x{height})")
        for key, value in stats.items():
            print(f"  {key:<24} {show(value)}")
    else:
        other_sequence, other_path, other_events = read_recording(Path(args.compare))
        other = recording_stats(other_sequence, other_events)
        print(f"A: {path}\nB: {other_path}")
        print(f"  {'':<24} {'A':>12} {'B':>12} {'B / A':>8}")
        for key, a, b, ratio in compare_stats(stats, other):
            print(f"  {key:<24} {show(a):>12} {show(b):>12} "
                  f"{'' if ratio is None else f'{ratio:.3g}':>8}")
    if args.out is None:
        print("(add --out PNG to draw the event frame; evfuse never writes into the recording)")
        return 0
    out = Path(args.out)
    window = first_seconds(events, args.window)
    args.event_figure(out, event_frame(window, width, height),
                      f"event frame: latest polarity of {len(window)} events")
    print(f"event frame of {len(window)} events written to {out}")
    return 0


def _cmd_twin(args: argparse.Namespace) -> int:
    from sim.twin import write_twin

    open_recording(args, "recording")
    window = None
    if args.window is not None:
        try:
            window = tuple(float(v) for v in args.window.split(","))
        except ValueError:
            window = ()
        if len(window) != 2 or not all(math.isfinite(t) for t in window):
            raise ValueError(f"--window: expected T0,T1 in seconds (finite), got "
                             f"{args.window!r}")
    scene = write_twin(args.recording, args.out, args.depth, window, args.illuminance,
                       args.frame_sensor, args.frame_gamma, overwrite=args.overwrite)
    print(f"twin scene written to {scene}; simulate it with: evfuse simulate {scene} "
          f"--out SEQUENCE")
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    from sim.eventio import convert_events
    from sim.output import check_not_input, check_output_file
    from sim.sequence import load_sequence

    src, dst = Path(args.src), Path(args.dst)
    if src.is_dir() and not _is_bag(src):               # a whole sequence as one file
        if _is_bag(dst) or dst.suffix == "" or args.ros is not None:
            return _convert_sequence(args)
        from sim.recording import write_sequence_file

        check_output_file(args.dst, [args.src], parameter="dst")
        if Path(args.dst).exists() and not args.overwrite:
            raise ValueError(f"{args.dst} exists; add --overwrite to replace it")
        events, frames, imu = write_sequence_file(args.src, args.dst)
        print(f"converted sequence {args.src} ({events} events, {frames} frames, {imu} IMU "
              f"samples) to {args.dst}")
        return 0
    if _is_bag(src) and dst.suffix == "" and args.ros is None:
        return _convert_bag_to_folder(args)
    width = height = None
    if args.sensor:
        try:
            width, height = (int(v) for v in args.sensor.lower().split("x"))
        except ValueError:
            raise ValueError(f"--sensor must look like 240x180, got {args.sensor!r}") from None
    else:
        folder = src.resolve().parent
        if (folder / "images.txt").is_file() or (folder / "sequence.json").is_file():
            camera = load_sequence(folder).camera
            width, height = camera.width, camera.height
    read = [args.src] + [src.resolve().parent / name for name in
                         ("calib.txt", "images.txt", "sequence.json")]       # for its size
    _check_bag_output(dst, read, check_not_input, check_output_file)
    if dst.exists() and not args.overwrite:
        raise ValueError(f"{args.dst} exists; add --overwrite to replace it")
    topic = {"topic": args.topic} if args.topic is not None else None
    convert_events(args.src, args.dst, width=width, height=height,
                   dst_selectors={"evt": args.evt, "ros": args.ros},
                   src_options=topic if _is_bag(src) else None,
                   dst_options=topic if _is_bag(dst) or args.ros is not None else None)
    print(f"converted {args.src} to {args.dst}")
    return 0


def _check_bag_output(dst: Path, read: list, check_not_input, check_output_file) -> None:
    """A ROS 2 bag is a folder: an existing one may be replaced (--overwrite), any other folder
    may not; every other output is one file."""
    if dst.is_dir():
        check_not_input(dst, read, "output bag", "dst")
        if not (dst / "metadata.yaml").is_file():
            raise ValueError(f"{dst} is an existing folder that is not a ROS 2 bag; expected "
                             "a new path or a bag to replace")
    else:
        check_output_file(dst, read, parameter="dst")


def _is_bag(path: Path) -> bool:
    from sim.sequence_bag import is_bag

    return is_bag(path)


def _convert_bag_to_folder(args: argparse.Namespace) -> int:
    """``evfuse convert in.bag FOLDER``: the bag's recording as an ECD sequence folder."""
    from sim.sequence_bag import BagRecording, write_recording_folder

    if args.sensor:
        raise ValueError("--sensor applies to an event file; a bag's camera info gives its size")
    recording = BagRecording(args.src, events_topic=args.topic)
    write_recording_folder(recording, args.dst, overwrite=args.overwrite)
    print(f"converted {args.src} to the sequence folder {args.dst} (events from "
          f"{recording.events_topic}, frames from {recording.image_topic}, camera from "
          f"{recording.camera_info_topic}, poses from {recording.pose_topic})")
    return 0


def _convert_sequence(args: argparse.Namespace) -> int:
    """``evfuse convert SEQUENCE_FOLDER out.bag``: the whole sequence as one bag."""
    from sim.output import check_not_input, check_output_file
    from sim.sequence_bag import write_sequence_bag

    src, dst = Path(args.src), Path(args.dst)
    if args.sensor:
        raise ValueError("--sensor applies to an event file; a sequence folder gives its size")
    _check_bag_output(dst, [src], check_not_input, check_output_file)
    if dst.exists() and not args.overwrite:
        raise ValueError(f"{args.dst} exists; add --overwrite to replace it")
    counts = write_sequence_bag(src, dst, ros=args.ros, events_topic=args.topic)
    print(f"converted {args.src} to {args.dst}: " + ", ".join(f"{topic} {count}" for topic,
                                                              count in counts.items()))
    return 0


def _cmd_generate(args: argparse.Namespace) -> int:
    from sim.dataset import estimate_jobs, estimate_report, generate, load_sweep

    sweep = load_sweep(args.sweep)
    if args.out is None and not args.dry_run:
        raise ValueError("--out DIR: the dataset folder to write is required (unless "
                         "--dry-run)")
    if args.dry_run:
        print(estimate_report(sweep, estimate_jobs(sweep, variant=args.variant)))
        return 0
    result = generate(sweep, args.out, scheduler=args.scheduler, workers=args.workers,
                      threads=args.threads, resume=args.resume, overwrite=args.overwrite,
                      retries=args.retries, variant=args.variant, gpu=args.gpu_per_job,
                      profile=args.profile,
                      report=(lambda line: print(line, flush=True)) if args.quiet else None)
    print(f"generate: {result.ran} jobs simulated, {result.skipped} already complete, "
          f"{result.failed} failed, in {result.wall_s:.1f} s on {result.cluster}; manifest "
          f"{result.out / 'manifest.csv'}")
    if args.profile:
        from sim.profile import PROFILE_JSON, profiles_summary

        print(profiles_summary(sorted((result.out / "jobs").glob(f"*/{PROFILE_JSON}"))))
    if result.ran:
        from sim.dataset import cost_table

        print(cost_table([result.out / r["path"] for r in result.rows if r["status"] == "done"],
                         {worker["device"] for worker in result.workers}))
    if result.failed:
        print(f"generate: {result.failed} jobs failed (their errors are in the manifest); "
              "retry them with the same command plus --resume", file=sys.stderr)
        return 1
    return 0


def _cmd_dataset(args: argparse.Namespace) -> int:
    from sim.dataset import CARD, dataset_summary, write_card

    summary = dataset_summary(args.folder) if args.no_card else write_card(args.folder)
    print(summary.text(), end="")
    if not args.no_card:
        print(f"wrote {Path(args.folder) / CARD}")
    return 0


def _add_dataset(sub) -> None:
    dataset = sub.add_parser(
        "dataset", help="summary and card of a dataset folder (evfuse generate's output)",
        description="Prints the summary of a dataset folder (sequences done / failed, events, "
                    "frames, simulated seconds, event rate, depth range, speeds) and writes "
                    "DIR/card.md with DIR/card/contact_sheet.png (per sequence: a frame, its "
                    "events, its exact depth) and the distributions over sequences. Nothing "
                    "else in DIR is written.")
    dataset.add_argument("folder", metavar="DIR", help="a dataset folder (with manifest.csv)")
    dataset.add_argument("--no-card", action="store_true",
                         help="print the summary only; write nothing")
    dataset.set_defaults(run=_cmd_dataset)


def _add_scenes(sub) -> None:
    scenes = sub.add_parser("scenes", help="list the built-in scenes")
    scenes.set_defaults(run=_cmd_scenes)


def _add_simulate(sub) -> None:
    simulate = sub.add_parser(
        "simulate", help="render a scene into a sequence folder",
        description="Render a built-in scene (by name, see `evfuse scenes`) or a scene file into "
                    "a sequence folder: calib.txt, groundtruth.txt, images/, depth/, "
                    "sequence.json.")
    simulate.add_argument("scene", help="built-in scene name or path of a .toml scene file")
    simulate.add_argument("--out", required=True, help="sequence folder to write")
    simulate.add_argument("--duration", type=POSITIVE, default=None,
                          help="seconds to simulate (default: the scene's duration)")
    simulate.add_argument("--start", type=FINITE, default=0.0,
                          help="time of the scene's trajectory to start at, s (default 0)")
    simulate.add_argument("--seed", type=SEED, default=None,
                          help="seed of every random draw (default: the scene's seed)")
    simulate.add_argument("--spp", type=count_type(1), default=None,
                          help="samples per pixel, a perfect square (default: the scene's)")
    simulate.add_argument("--variant", default=None,
                          help="Mitsuba variant: cuda_ad_rgb, llvm_ad_rgb or scalar_rgb "
                               "(default: EVFUSE_VARIANT, else the fastest that works)")
    simulate.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    simulate.add_argument("--quiet", action="store_true", help="no progress bar")
    simulate.add_argument("--contrast", type=FINITE, default=0.2,
                          help="contrast thresholds C+ = C- of the event camera (default 0.2)")
    simulate.add_argument("--noise", choices=("ideal", "realistic"), default="ideal",
                          help="event-camera noise preset (default ideal: no noise)")
    simulate.add_argument("--frame-sensor", default=None, metavar="NAME",
                          help="the standard camera's sensor: ideal (no noise), davis240c_aps "
                               "or machine_vision (default: the scene's [frames] sensor)")
    simulate.add_argument("--lambda", dest="lam", type=FINITE, default=0.5,
                          help="adaptive sampling: largest change of log intensity between "
                               "renders, as a fraction of C (default 0.5)")
    simulate.add_argument("--min-rate", type=FINITE, default=100.0,
                          help="lowest render rate for the event camera, Hz (default 100)")
    simulate.add_argument("--max-rate", type=FINITE, default=20000.0,
                          help="highest render rate for the event camera, Hz (default 20000)")
    simulate.add_argument("--wavefront", type=count_type(1), default=None, metavar="B",
                          help="per-pixel sampler on the device: blocks (1 / --min-rate each) "
                               "predicted, shaded and refined in one pass of launches, each "
                               "taking the rates observed before its pass as its floor "
                               "(default 1: fewest samples; larger passes make fewer launches "
                               "and hold B blocks' samples at once)")
    simulate.add_argument("--sampler", choices=("pixel", "frame"), default=None,
                          help="how the event camera is sampled: pixel (each pixel at its own "
                               "adaptive times; static scenes) or frame (whole frames at one "
                               "adaptive rate) (default: pixel for static scenes on a JIT "
                               "variant, else frame)")
    simulate.add_argument("--event-format", default="h5,txt",
                          help="event files to write, comma-separated: h5 (with per-event "
                               "depth, events/depth), txt, depth-txt (events_depth.txt: t x y p "
                               "depth flag) (default h5,txt)")
    simulate.add_argument("--format", action="append", default=None, metavar="FMT",
                          choices=("aedat4", "evt3", "evt2"),
                          help="also write the events as events.<suffix> in this format: "
                               "aedat4, evt3 or evt2 (Prophesee RAW events.raw); repeatable; "
                               "converted exactly from events.h5 at the end of the event stage")
    simulate.add_argument("--no-events", action="store_true",
                          help="render frames and depth only")
    simulate.add_argument("--no-motion-truth", action="store_true",
                          help="skip the motion ground truth (velocity.txt, imu.txt, optical "
                               "flow, motion fields, object masks, per-event depth and labels): "
                               "frames, depth maps, poses and events only")
    simulate.add_argument("--rig", choices=("perfect", "mocap", "lab"), default=None,
                          help="pose noise, clock offsets and calibration error of the written "
                               "groundtruth.txt, time stamps and calib.txt: perfect, mocap "
                               "(0.5 mm / 0.1 deg jitter, drift, poses 3 ms late) or lab (mocap "
                               "plus calibration error); the truth is kept in "
                               "groundtruth_exact.txt and calib_exact.txt (default: the scene's "
                               "[rig], else perfect)")
    simulate.add_argument("--profile", action="store_true",
                          help="also write profile.json and print it: each stage's wall seconds "
                               "beside its Dr.Jit kernels (device seconds, launches, compilation, "
                               "copies), and the event camera's host and device seconds per "
                               "simulated second")
    simulate.add_argument("--resume", action="store_true",
                          help="continue an interrupted run of the same command from the "
                               "checkpoint it left in OUT.partial (the result is the same as an "
                               "uninterrupted run's)")
    simulate.set_defaults(run=_cmd_simulate,
                          interrupted="resume with the same command plus --resume",
                          flag_names={"spp": "--spp", "min_rate": "--min-rate",
                                      "wavefront": "--wavefront", "sampler": "--sampler"})


def _add_events(sub, event_figure: Callable[[Path, np.ndarray, str], object]) -> None:
    events = sub.add_parser("events", help="statistics and an event frame of a sequence's events")
    events.add_argument("sequence", help="sequence folder with events.h5 or events.txt"
                                         + RECORDING_HELP)
    events.add_argument("--stats", action="store_true",
                        help="print count, rate, ON/OFF balance (and draw the event frame into "
                             "--out)")
    events.add_argument("--window", type=POSITIVE, default=None,
                        help="seconds of events from the start drawn in the event frame "
                             "(default: all)")
    events.add_argument("--out", default=None,
                        help="with --stats: the event-frame PNG to write (default none; never "
                             "inside SEQUENCE or OTHER, which are only read)")
    events.add_argument("--overwrite", action="store_true", help=PNG_OVERWRITE_HELP)
    events.add_argument("--compare", default=None, metavar="OTHER",
                        help="with --stats: another sequence folder (a twin and its recording), "
                             "or one event file read with the same --calib, printed side by "
                             "side with the ratio OTHER / SEQUENCE")
    add_recording_options(events)
    events.set_defaults(run=_cmd_events, event_figure=event_figure)


def _add_twin(sub) -> None:
    twin = sub.add_parser(
        "twin", help="write a scene that simulates a recording's camera and trajectory",
        description="Writes OUT/scene.toml, OUT/groundtruth.txt (the recording's poses of the "
                    "window, times shifted to start at 0) and OUT/poster.png (the recording's "
                    "frame at the window's start, undistorted): the recording's camera, "
                    "trajectory and frame rate, and a poster like its view at --depth.")
    twin.add_argument("recording", help="an Event-Camera Dataset folder (calib.txt, "
                                        "groundtruth.txt, images.txt)" + RECORDING_HELP)
    add_recording_options(twin)
    twin.add_argument("--depth", type=POSITIVE, required=True,
                      help="the poster's depth, m, in the camera at the window's start (e.g. "
                           "the median depth that `evfuse map` prints for the recording and "
                           "writes to map.json as depth_median_m)")
    twin.add_argument("--window", default=None, metavar="T0,T1",
                      help="seconds of the recording to copy (default: its poses' span)")
    twin.add_argument("--illuminance", type=POSITIVE, default=400.0,
                      help="lux on the poster, from a light along the optical axis (default 400, "
                           "an office)")
    twin.add_argument("--frame-sensor", default="davis240c_aps",
                      choices=("ideal", "davis240c_aps", "machine_vision"),
                      help="the standard camera's sensor (default davis240c_aps, the ECD's)")
    twin.add_argument("--frame-gamma", type=POSITIVE, default=1.0,
                      help="the recording's frames are 255 * light^(1/GAMMA) (default 1: linear, "
                           "as a DAVIS APS; 2.2 for a gamma-encoded camera)")
    twin.add_argument("--out", required=True, help="folder to write")
    twin.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    twin.set_defaults(run=_cmd_twin)


def _add_convert(sub) -> None:
    convert = sub.add_parser("convert", help="convert events between file formats",
                             description="Convert events between ECD text (.txt), the DSEC "
                                         "layout (.h5), AEDAT4 (.aedat4), Prophesee RAW "
                                         "(.raw, EVT 3.0 or --evt 2) and ROS bags (.bag ROS 1; "
                                         ".mcap or a folder with --ros 2 ROS 2), streaming. The "
                                         "format follows the file suffix (a RAW source: its "
                                         "header). A sequence folder as SRC is written whole "
                                         "as one .aedat4 (events, frames, IMU) or one bag "
                                         "(events, frames, depth, camera info, poses, IMU, "
                                         "flow); a bag as SRC and a folder name as DST writes "
                                         "an ECD sequence folder.")
    convert.add_argument("src", help="the event file to read (.txt, .h5, .aedat4, .raw, .bag, "
                                     ".mcap, a ROS 2 bag folder), or a sequence folder")
    convert.add_argument("dst", help="the event file to write (.txt, .h5, .aedat4, .raw, .bag, "
                                     ".mcap, a ROS 2 bag folder with --ros 2), or, from a bag, "
                                     "a sequence folder (a name without suffix, no --ros)")
    convert.add_argument("--evt", type=count_type(2, 3), default=None,
                         help="RAW encoding of a .raw DST: 3 (EVT 3.0, default) or 2 (EVT 2.0)")
    convert.add_argument("--ros", type=count_type(1, 2), default=None,
                         help="ROS version of a bag DST whose name cannot say (a folder name)")
    convert.add_argument("--topic", default=None,
                         help="event topic to read from a bag SRC or write to a bag DST "
                              "(default: the bag's one dvs_msgs/EventArray topic; /dvs/events)")
    convert.add_argument("--overwrite", action="store_true", help="replace an existing DST")
    convert.add_argument("--sensor", default=None,
                         help="sensor size WxH for HDF5 output (default: from the sequence "
                              "folder of SRC)")
    convert.set_defaults(run=_cmd_convert)
    convert.set_defaults(flag_names={"dst": "DST", "sensor": "evfuse convert reads them from "
                                     "the sequence folder, or pass --sensor WxH"})


def _add_generate(sub) -> None:
    generate = sub.add_parser(
        "generate", help="a dataset: a sweep file's jobs simulated on Dask",
        description="Simulate every job of a sweep file (scenes x grid x seeds, see "
                    "sweeps/README.md) into DIR/jobs/<job_id>/, each one `evfuse simulate`, on "
                    "a Dask LocalCluster (one single-threaded worker per core) or an existing "
                    "scheduler; DIR/manifest.csv lists every job with its status, counts and "
                    "output hash.")
    generate.add_argument("sweep", help="sweep file (.toml)")
    generate.add_argument("--out", required=False, default=None, metavar="DIR",
                          help="dataset folder to write (required unless --dry-run)")
    generate.add_argument("--dry-run", action="store_true",
                          help="list the jobs and their cost estimated from a short probe "
                               "simulation of each distinct scene; write nothing")
    generate.add_argument("--scheduler", default=None, metavar="ADDRESS",
                          help="address of a running Dask scheduler (tcp://head:8786; start "
                               "one with `dask scheduler` and `dask worker ADDRESS`) instead of "
                               "a local cluster")
    generate.add_argument("--workers", type=count_type(0), default=None,
                          help="local cluster: worker processes (default: one per core; 0 "
                               "runs the jobs one by one in this process, without Dask)")
    generate.add_argument("--threads", type=count_type(1), default=None,
                          help="local cluster: threads per worker (default 1)")
    generate.add_argument("--retries", type=count_type(0), default=1,
                          help="times a failing job is tried again before it is recorded as "
                               "failed (default 1)")
    generate.add_argument("--gpu-per-job", type=POSITIVE, default=None, metavar="FRACTION",
                          help="each job's share of a worker's GPU resource (e.g. 0.0625: 16 "
                               "jobs per GPU; workers started with --resources GPU=1)")
    generate.add_argument("--variant", default=None,
                          help="Mitsuba variant of every job (default: each worker's fastest)")
    generate.add_argument("--profile", action="store_true",
                          help="each job also writes profile.json (evfuse simulate --profile); "
                               "the jobs' event camera is summed up at the end")
    generate.add_argument("--resume", action="store_true",
                          help="continue DIR (same sweep file): complete jobs are kept, "
                               "interrupted ones resume from their checkpoint, failed ones are "
                               "tried again")
    generate.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    generate.add_argument("--quiet", action="store_true",
                          help="one line per finished job on stdout, no progress bar")
    generate.set_defaults(run=_cmd_generate,
                          flag_names={"gpu": "--gpu-per-job", "variant": "--variant"},
                          interrupted="finished jobs are kept (with --overwrite, in DIR.partial; "
                                      "the old DIR is untouched until the new one is "
                                      "complete); continue with the same command plus "
                                      "--resume")


def add_command(subparsers, name: str, *,
                event_figure: Callable[[Path, np.ndarray, str], object] | None = None) -> None:
    """Add one of the simulator's subcommands to a command line.

    Parameters
    ----------
    subparsers : argparse subparsers action
        What ``ArgumentParser.add_subparsers`` returned; the subcommand is added last.
    name : str
        One of :data:`COMMANDS`. Each handler is set as the subcommand's ``run`` default and
        takes the parsed arguments, returning the exit status.
    event_figure : callable, optional
        Needed for ``events``: ``event_figure(path, frame, title)`` writes the event frame
        (``(H, W, 3) uint8`` RGB, :func:`sim.statistics.event_frame`) as a titled PNG.

    Raises
    ------
    ValueError
        An unknown name, or ``events`` without ``event_figure``.
    """
    if name == "events":
        if event_figure is None:
            raise ValueError("add_command: the events command needs event_figure")
        _add_events(subparsers, event_figure)
        return
    builders = {"scenes": _add_scenes, "simulate": _add_simulate, "twin": _add_twin,
                "convert": _add_convert, "generate": _add_generate, "dataset": _add_dataset}
    if name not in builders:
        raise ValueError(f"add_command: {name!r} is not one of {', '.join(COMMANDS)}")
    builders[name](subparsers)
