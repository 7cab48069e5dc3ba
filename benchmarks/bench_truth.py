"""The cost of the motion ground truth: ``evfuse simulate`` with and without it.

``boxes_6dof`` (240x180, its own spp, the per-pixel sampler) is simulated over one window
(default 0.5 s from t = 10 s) ``--repeats`` times with the motion ground truth (camera velocity
and IMU, optical flow, motion fields and object masks, per-event depth) and as many times
without it (``motion_truth=False``), alternating, into a temporary folder. Two figures:

- **A/B**: the median wall time with it minus the median without it, as a share of the median
  with it. Run-to-run noise on a busy machine is a few per cent of the total, so this is the
  honest figure only when the repeats agree (their spread is printed);
- **stages**: the seconds ``sequence.json`` counts for the new stages (``timings_s.imu``,
  ``flow``, ``event_depth``), as a share of the run's total. An upper bound:
  ``event_depth`` includes the depth renders that the sampler then takes from the same cache
  (it would have made them anyway; see :mod:`sim.event_depth`).

Both per simulated second as well. The target (issue 15) is under 10 % of simulate's time.
Printed and written to ``benchmarks/results/truth.json``.

Run: ``.venv/bin/python benchmarks/bench_truth.py [--duration 0.5] [--repeats 2]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from scenes import resolve_scene
from sim.scene import load_scene
from sim.sequence import read_sequence_json
from sim.simulate import simulate

RESULTS = Path(__file__).resolve().parent / "results"
STAGES = ("imu", "flow", "event_depth")


def run_once(scene, folder: Path, start: float, duration: float, motion_truth: bool) -> dict:
    """One simulate; its wall time and the stages' seconds from ``sequence.json``."""
    tick = time.perf_counter()
    simulate(scene, folder, start=start, duration=duration, overwrite=True, progress=False,
             motion_truth=motion_truth)
    wall = time.perf_counter() - tick
    timings = read_sequence_json(folder / "sequence.json")["timings_s"]
    return {"wall_s": wall, "stages_s": {k: float(timings.get(k, 0.0)) for k in STAGES}}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="boxes_6dof")
    parser.add_argument("--start", type=float, default=10.0)
    parser.add_argument("--duration", type=float, default=0.5)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args(argv)
    scene = load_scene(resolve_scene(args.scene))
    runs: dict[bool, list[dict]] = {True: [], False: []}
    with tempfile.TemporaryDirectory(prefix="evfuse-bench-truth-") as tmp:
        for repeat in range(args.repeats):
            for truth in (True, False):
                run = run_once(scene, Path(tmp) / f"seq_{truth}", args.start, args.duration,
                               truth)
                runs[truth].append(run)
                state = "on " if truth else "off"
                print(f"repeat {repeat + 1}/{args.repeats}, motion truth {state}: "
                      f"{run['wall_s']:.1f} s", flush=True)
    with_truth = statistics.median(r["wall_s"] for r in runs[True])
    without = statistics.median(r["wall_s"] for r in runs[False])
    stages = {k: statistics.median(r["stages_s"][k] for r in runs[True]) for k in STAGES}
    result = {
        "scene": args.scene, "start_s": args.start, "duration_s": args.duration,
        "repeats": args.repeats,
        "wall_s": {"with": [r["wall_s"] for r in runs[True]],
                   "without": [r["wall_s"] for r in runs[False]]},
        "median_with_s": with_truth, "median_without_s": without,
        "ab_share": (with_truth - without) / with_truth,
        "ab_s_per_simulated_s": (with_truth - without) / args.duration,
        "stages_s": stages,
        "stages_share_upper_bound": sum(stages.values()) / with_truth,
        "stages_s_per_simulated_s": sum(stages.values()) / args.duration,
        "target_share": 0.10,
    }
    print(f"\n{args.scene}, {args.duration:g} s from {args.start:g} s, {args.repeats} repeats:")
    print(f"  simulate with the motion truth    {with_truth:7.1f} s (median)")
    print(f"  simulate without it               {without:7.1f} s")
    print(f"  A/B: its cost                     {100 * result['ab_share']:6.1f} % "
          f"({result['ab_s_per_simulated_s']:.2f} s per simulated second)")
    print("  stages: " + ", ".join(f"{k} {v:.2f} s" for k, v in stages.items())
          + f" = {100 * result['stages_share_upper_bound']:.1f} % (an upper bound)")
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / "truth.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"written to {out}")


if __name__ == "__main__":
    main()
