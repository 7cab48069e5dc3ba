"""Per-pixel against frame sampling of the event camera: work, wall time and agreement.

For each scene, in one process: ``simulate`` with ``--sampler pixel`` and ``--sampler frame``
(default lam 0.5), and the frame sampler at lam / 4 as the reference, over the same window.
Reported per sampler: pixel samples per simulated second (a whole frame counts H W), whole-frame
renders, events, and the wall time of the event camera (rendering, emulation, writing; the
frames of the standard camera and the set-up are not counted); the ratio frame / pixel of the
wall times; and the agreement of each with the reference
(:func:`benchmarks.agreement.event_agreement`:
count error, worst 16x16 block with >= 100 events, median and 95th percentile of the matched
events' time differences).

Default: ``slider_close``, ``slider_far``, ``poster_6dof``, ``boxes_6dof`` and
``complex_sphere`` at 240x180 over 0.25 s each (the 6-DoF scenes from the start of the paper's
windows; ``poster_6dof`` also at 40 s, where its hand-held motion has sped up), and
``slider_close`` at 640x480 (same field of view) over 0.05 s. Each sampler first simulates a
0.01 s window once (kernel tracing and compilation are not counted).

Run: ``.venv/bin/python benchmarks/bench_sampling.py`` (about 12 minutes on 2 cores;
``--no-reference`` skips the lam / 4 runs; ``--scenes`` and ``--start`` pick rows). Results
are printed and written to ``benchmarks/results/sampling.json`` (a subset replaces its own
rows there).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from benchmarks.agreement import event_agreement
from scenes import resolve_scene
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


def bench(cases, reference: bool, folder: Path) -> list[dict]:
    rows = []
    warmed = set()
    for name, resolution, start, seconds in cases:
        scene = _scene(name, resolution)
        shape = (scene.camera.height, scene.camera.width)
        if (name, resolution) not in warmed:                 # trace and compile once
            for sampler in ("pixel", "frame"):
                _run(scene, folder / "warm", start, 0.01, sampler, 0.5)
            warmed.add((name, resolution))
        tick = time.perf_counter()
        pixel = _run(scene, folder / "pixel", start, seconds, "pixel", 0.5)
        frame = _run(scene, folder / "frame", start, seconds, "frame", 0.5)
        row = {"scene": name, "resolution": resolution, "window_s": [start, start + seconds],
               "pixel": pixel, "frame": frame, "speedup": frame["wall_s"] / pixel["wall_s"]}
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=None,
                        help="comma-separated scene names (default: the rows of CASES)")
    parser.add_argument("--no-reference", action="store_true",
                        help="skip the lam / 4 reference runs and the agreement")
    parser.add_argument("--start", type=float, default=None,
                        help="only the rows starting at this time, s")
    args = parser.parse_args()
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
        print(f"{'':<24}frame / pixel wall time: {row['speedup']:.1f}x")
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / "sampling.json"
    # A subset replaces its own rows and keeps the others of an earlier run.
    kept = json.loads(path.read_text()) if path.is_file() else []
    mine = {(r["scene"], r["resolution"], r["window_s"][0]) for r in rows}
    kept = [r for r in kept if (r["scene"], r["resolution"], r["window_s"][0]) not in mine]
    path.write_text(json.dumps(kept + rows, indent=2))
    print(f"\nwritten to {RESULTS / 'sampling.json'}")


if __name__ == "__main__":
    main()
