"""What ``evfuse simulate`` costs per simulated second, stage by stage; and the two samplers'
agreement.

**Cost (the default).** For each built-in scene at 240x180 and at 640x480 (the scene's field of
view: its camera, or a rig's event camera, resampled by :meth:`sim.camera.Camera.with_resolution`
and written as explicit intrinsics into a copy of the scene file), with each sampler (``pixel``
and ``frame``; ``frame`` only for a scene with moving objects, which the per-pixel sampler
refuses): the whole ``evfuse simulate`` command, run as a process as a user runs it (defaults:
events in h5 and txt, motion ground truth, the scene's frame sensor), over a short window, after
one run of the same command over 0.045 s that fills Dr.Jit's kernel cache. Reported: wall
seconds per simulated second (the whole process over the window), the same without the one-off
start (process start, imports, scene, renderer set-up: what a long run amortises), and the
share of the wall time of each stage from ``sequence.json``'s ``timings_s``: set-up (renderer),
frames (renders, depth maps, writing), event render, emulate, event write (and checkpoints),
per-event depth, motion truth (IMU, flow, motion fields), and the rest (process start, imports,
scene parsing, rig and index files).

Windows (:func:`cost_cases`): from the paper's window start for Table 1 scenes, else from
min(1 s, half the scene); 0.1 s at 240x180, 0.05 s at 640x480. ``--quick``: slider_close,
boxes_6dof and garden_wall at 240x180, slider_close at 640x480.

**Agreement (``--agreement``).** For each case of :data:`CASES`, in one process: ``simulate``
with ``--sampler pixel`` and ``--sampler frame`` (default lam 0.5), and the frame sampler at
lam / 4 as the reference, over the same window. Reported per sampler: pixel samples per
simulated second (a whole frame counts H W), whole-frame renders, events, and the wall time of
the event camera (rendering, emulation, writing); and the agreement of each with the reference
(:func:`benchmarks.agreement.event_agreement`: count error, worst 16x16 block with >= 100
events, median and 95th percentile of the matched events' time differences). Each sampler first
simulates a :data:`WARM_S` window once (kernel tracing and compilation are not counted; a
shorter window holds no frame, which ``simulate`` refuses).

Run: ``PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_sampling.py [--quick]`` (on 2 shared
cores, ``llvm_ad_rgb``: ``--quick`` about 6 minutes; the full cost table about two hours, an
estimate from the quick rows). ``--agreement`` (about 12 minutes;
``--no-reference`` skips the lam / 4 runs). ``--scenes`` picks scenes, ``--start`` rows of the
agreement. Results are printed and written to ``benchmarks/results/simulate_cost.json`` and
``benchmarks/results/sampling.json`` (a subset replaces its own rows there).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from benchmarks.agreement import event_agreement
from fusion.experiments.reproduce import PAPER
from scenes import builtin_scenes, resolve_scene
from sim.eventio import read_events
from sim.sampling import SamplingParams
from sim.scene import load_scene
from sim.simulate import simulate

RESULTS = Path(__file__).resolve().parent / "results"
CASES = [("slider_close", "240x180", 0.0, 0.25), ("slider_far", "240x180", 0.0, 0.25),
         ("poster_6dof", "240x180", 2.0, 0.25), ("poster_6dof", "240x180", 40.0, 0.25),
         ("boxes_6dof", "240x180", 3.5, 0.25),
         ("complex_sphere", "240x180", 1.0, 0.25), ("slider_close", "640x480", 0.0, 0.05)]
"""(scene, resolution, start, seconds) of each row."""
EVENT_STAGES = ("event_render", "emulate", "event_write", "checkpoint")
ROOT = Path(__file__).resolve().parent.parent
SIZES = {"240x180": 0.1, "640x480": 0.05}
"""Sensor sizes of the cost table and the seconds simulated at each."""
QUICK_COST = [("slider_close", "240x180"), ("boxes_6dof", "240x180"), ("garden_wall", "240x180"),
              ("slider_close", "640x480")]
"""(scene, size) of ``--quick``'s cost rows."""
WARM_S = 0.045
"""Seconds of the warm-up run (the shortest that holds one frame at a 0.04-s exposure)."""
STAGES = {"setup": ("setup",),
          "frames": ("frame_setup", "depth", "exposure_control", "frame_motion", "frame_edges",
                     "render", "frame_sensor", "write"),
          "event render": ("event_render",), "emulate": ("emulate",),
          "event write": ("event_write", "checkpoint"), "per-event depth": ("event_depth",),
          "motion truth": ("imu", "flow")}
"""The cost table's stages and the ``timings_s`` keys each sums; the rest of the wall time is
``other`` (process start, imports, scene parsing, rig and index files)."""


def _scene(name: str, resolution: str):
    scene = load_scene(resolve_scene(name))
    width, height = (int(v) for v in resolution.split("x"))
    if (width, height) != (scene.camera.width, scene.camera.height):
        scene = replace(scene, camera=scene.camera.with_resolution(width, height))
    return scene


def event_pixel_samples(scene, events: dict) -> int:
    """Pixels the event camera rendered: a whole-frame render counts H W, plus the per-pixel
    sampler's own (``events``: ``sequence.json``'s ``events``)."""
    pixels = scene.camera.width * scene.camera.height
    return events["full_renders"] * pixels + events["pixel_samples"]


def _run(scene, folder: Path, start: float, seconds: float, sampler: str, lam: float) -> dict:
    result = simulate(scene, folder, start=start, duration=seconds, progress=False,
                      event_formats=("h5",), sampler=sampler, sampling=SamplingParams(lam=lam),
                      overwrite=True)
    info = json.loads((folder / "sequence.json").read_text())["events"]
    samples = event_pixel_samples(scene, info)
    return {"sampler": sampler, "lam": lam, "events": result.n_events,
            "full_renders": info["full_renders"], "pixel_samples": info["pixel_samples"],
            "samples_per_s": samples / seconds,
            "wall_s": sum(result.timings[k] for k in EVENT_STAGES),
            "intervals_at_max_rate": info["intervals_at_max_rate"]}


def cost_cases(names: list[str] | None = None, quick: bool = False
               ) -> list[tuple[str, str, float, float, str]]:
    """(scene, size, start, seconds, sampler) of the cost table's rows.

    Every built-in scene (or ``names``) at each of :data:`SIZES`, both samplers (``frame`` only
    where objects move); ``quick``: the (scene, size) pairs of :data:`QUICK_COST`.
    """
    pairs = QUICK_COST if quick else [(n, size) for n in builtin_scenes() for size in SIZES]
    if names is not None:
        pairs = [(n, size) for n in names for size in SIZES]
    cases = []
    for name, size in pairs:
        scene = load_scene(resolve_scene(name))
        seconds = SIZES[size]
        table1 = PAPER["table1"].get(name)
        start = table1["window_s"][0] if table1 else min(1.0, scene.duration / 2)
        start = min(start, scene.duration - seconds)
        for sampler in ("frame",) if scene.is_dynamic else ("pixel", "frame"):
            cases.append((name, size, start, seconds, sampler))
    return cases


def scene_file_at(name: str, size: str, folder: Path) -> Path:
    """A built-in scene's file with its (event) camera at ``size``, its field of view kept.

    The ``preset`` line of ``[camera]`` (a rig: ``[event_camera]``) becomes the explicit
    intrinsics of :meth:`~sim.camera.Camera.with_resolution`; the file is written to ``folder``
    (built-in scenes name no files by relative path). The scene's own file at its own size.
    """
    path = resolve_scene(name)
    scene = load_scene(path)
    width, height = (int(v) for v in size.split("x"))
    if (width, height) == (scene.camera.width, scene.camera.height):
        return path
    camera = scene.camera.with_resolution(width, height)
    section = "event_camera" if scene.frame_camera is not None else "camera"
    text = path.read_text()
    match = re.search(rf"^\[{section}\][^\[]*?^(preset *= *\"\w+\".*)$", text, flags=re.M)
    if match is None:
        raise ValueError(f"{path}: no preset line in [{section}] to replace")
    explicit = (f"width = {camera.width}\nheight = {camera.height}\nfx = {camera.fx!r}\n"
                f"fy = {camera.fy!r}\ncx = {camera.cx!r}\ncy = {camera.cy!r}")
    out = folder / f"{name}_{size}.toml"
    out.write_text(text[:match.start(1)] + explicit + text[match.end(1):])
    return out


def _simulate_command(scene_file: Path, out: Path, start: float, seconds: float,
                      sampler: str) -> float:
    """Run ``evfuse simulate`` as a process (the defaults, no progress bar); its wall seconds."""
    command = [sys.executable, "-m", "fusion.cli", "simulate", str(scene_file), "--out",
               str(out), "--start", repr(start), "--duration", repr(seconds), "--sampler",
               sampler, "--quiet", "--overwrite"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
    tick = time.perf_counter()
    subprocess.run(command, check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - tick


def cost_row(name: str, size: str, start: float, seconds: float, sampler: str,
             folder: Path) -> dict:
    """One row of the cost table: wall seconds per simulated second and each stage's share."""
    scene_file = scene_file_at(name, size, folder)
    _simulate_command(scene_file, folder / "warm", start, WARM_S, sampler)
    wall = _simulate_command(scene_file, folder / "run", start, seconds, sampler)
    record = json.loads((folder / "run" / "sequence.json").read_text())
    timings = record["timings_s"]
    stages = {stage: sum(timings.get(k, 0.0) for k in keys) for stage, keys in STAGES.items()}
    stages["other"] = wall - sum(stages.values())
    one_off = stages["other"] + stages["setup"]
    return {"scene": name, "size": size, "sampler": sampler, "window_s": [start, start + seconds],
            "wall_s": wall, "wall_per_sim_s": wall / seconds,
            "steady_per_sim_s": (wall - one_off) / seconds,
            "stages_s": stages, "shares": {k: v / wall for k, v in stages.items()},
            "events": record["events"]["count"], "variant": record["render"]["variant"]}


def cost_table(rows: list[dict]) -> str:
    """The printed cost table: one line a row, shares in % of the wall time."""
    stages = list(STAGES) + ["other"]
    widths = [max(8, len(s)) for s in stages]
    lines = ["scene                size     sampler  wall s/sim s  w/o start    events  "
             + "  ".join(s.rjust(w) for s, w in zip(stages, widths, strict=True))]
    for row in rows:
        shares = "  ".join(f"{100 * row['shares'][s]:.1f} %".rjust(w)
                           for s, w in zip(stages, widths, strict=True))
        lines.append(f"{row['scene']:<20} {row['size']:<8} {row['sampler']:<7} "
                     f"{row['wall_per_sim_s']:12.1f} {row['steady_per_sim_s']:10.1f} "
                     f"{row['events']:9,}  {shares}")
    return "\n".join(lines)


def bench(cases, reference: bool, folder: Path) -> list[dict]:
    rows = []
    warmed = set()
    for name, resolution, start, seconds in cases:
        scene = _scene(name, resolution)
        shape = (scene.camera.height, scene.camera.width)
        if (name, resolution) not in warmed:                 # trace and compile once
            for sampler in ("pixel", "frame"):
                _run(scene, folder / "warm", start, WARM_S, sampler, 0.5)
            warmed.add((name, resolution))
        tick = time.perf_counter()
        pixel = _run(scene, folder / "pixel", start, seconds, "pixel", 0.5)
        frame = _run(scene, folder / "frame", start, seconds, "frame", 0.5)
        row = {"scene": name, "resolution": resolution, "window_s": [start, start + seconds],
               "pixel": pixel, "frame": frame}
        if reference:
            row["reference"] = _run(scene, folder / "reference", start, seconds, "frame", 0.125)
            want = read_events(folder / "reference" / "events.h5")
            for key in ("pixel", "frame"):
                got = read_events(folder / key / "events.h5")
                row[key]["agreement"] = event_agreement(want, got, shape).as_dict()
        print(f"{name} {resolution}: {time.perf_counter() - tick:.0f} s", flush=True)
        rows.append(row)
    return rows


def _agreement(run: dict) -> str:
    a = run.get("agreement")
    if a is None:
        return ""
    return (f" {100 * a['count_error']:+6.2f} % {100 * a['worst_block_error']:5.1f} % "
            f"{a['dt_median_us']:6.1f} {a['dt_p95_us']:7.1f}")


def _write_rows(path: Path, rows: list[dict], key) -> None:
    """Write ``rows`` to ``path``: a subset replaces its own rows and keeps an earlier run's."""
    RESULTS.mkdir(exist_ok=True)
    kept = json.loads(path.read_text()) if path.is_file() else []
    mine = {key(r) for r in rows}
    path.write_text(json.dumps([r for r in kept if key(r) not in mine] + rows, indent=2))
    print(f"\nwritten to {path}")


def main_cost(args: argparse.Namespace) -> None:
    """The cost table (see the module docstring)."""
    names = None if args.scenes is None else args.scenes.split(",")
    rows, tick = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for case in cost_cases(names, args.quick):
            rows.append(cost_row(*case, Path(tmp)))
            print(f"{case[0]} {case[1]} {case[4]}: {rows[-1]['wall_s']:.1f} s", flush=True)
    print(f"\nevfuse simulate, wall seconds per simulated second and the share of each stage "
          f"({rows[0]['variant'] if rows else ''}; whole run {time.perf_counter() - tick:.0f} s)")
    print(cost_table(rows))
    _write_rows(RESULTS / "simulate_cost.json", rows,
                lambda r: (r["scene"], r["size"], r["sampler"]))


def main_agreement(args: argparse.Namespace) -> None:
    """The samplers' agreement table (see the module docstring)."""
    cases = CASES if args.scenes is None else [c for c in CASES
                                               if c[0] in args.scenes.split(",")]
    cases = [c for c in cases if args.start is None or c[2] == args.start]
    with tempfile.TemporaryDirectory() as tmp:
        rows = bench(cases, not args.no_reference, Path(tmp))
    print("\nscene          size     sampler  samples/s  renders  pixel samples  events  "
          "wall s  count  worst block  dt med us  dt p95 us")
    for row in rows:
        for key in ("pixel", "frame"):
            run = row[key]
            print(f"{row['scene']:<14} {row['resolution']:<8} {key:<8} "
                  f"{run['samples_per_s']:9.3g} {run['full_renders']:8,} "
                  f"{run['pixel_samples']:14,} {run['events']:7,} {run['wall_s']:7.1f}"
                  f"{_agreement(run)}")
    _write_rows(RESULTS / "sampling.json", rows,
                lambda r: (r["scene"], r["resolution"], r["window_s"][0]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="cost table: slider_close, boxes_6dof and garden_wall at 240x180, "
                             "slider_close at 640x480")
    parser.add_argument("--agreement", action="store_true",
                        help="the samplers' agreement table instead of the cost table")
    parser.add_argument("--scenes", default=None,
                        help="comma-separated scene names (default: every built-in scene; "
                             "--agreement: the rows of CASES)")
    parser.add_argument("--no-reference", action="store_true",
                        help="--agreement: skip the lam / 4 reference runs and the agreement")
    parser.add_argument("--start", type=float, default=None,
                        help="--agreement: only the rows starting at this time, s")
    args = parser.parse_args()
    (main_agreement if args.agreement else main_cost)(args)


if __name__ == "__main__":
    main()
