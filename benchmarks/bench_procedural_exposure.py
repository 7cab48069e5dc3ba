"""Mean grey of procedural scenes' frames, as a dataset job writes them (issue 38).

For each family (``tabletop``, ``room``) and seed (default 0-7), the scene is drawn
(:func:`sim.scene.procedural.procedural_scene` at its default ranges, or with the key light's
illuminance fixed by ``--illuminance``) and simulated as a job of ``sweeps/tabletop.toml``
simulates it: the DAVIS240C's 240x180 pixels, ``frame_sensor = "davis240c_aps"``, ``t0 = 0``,
``t1 = 2`` (:func:`sim.simulate.simulate_inputs`, then :func:`sim.simulate.simulate`), the frames
only (``with_events=False``: the frames do not depend on the events). Each written PNG's mean is
read back; a sequence's mean grey is the mean of its frames' means (of 255). The goal is every
sequence's mean grey in :data:`GOAL` = [40, 215]; the script exits with status 1 when one is
outside.

Run: ``python -m benchmarks.record -- python -m benchmarks.bench_procedural_exposure`` (16
sequences of 48 frames: about 2-4 minutes on the shared 2-core machine). Written to
``benchmarks/results/procedural_exposure.json``, only for that default job (not with
``--illuminance``, ``--size``, ``--end`` or ``--no-write``). The floor of the default range, for
example, on 100 seeds of each family, smaller and shorter: ``--illuminance 200 --first 0
--seeds 100 --size 120x90 --end 0.5``.

It uses only what the project had before issue 38, so the same script run with an older checkout
first on ``PYTHONPATH`` measures the frames as they were.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
OUTPUT = "procedural_exposure.json"
GOAL = (40.0, 215.0)
"""Range (of 255) every sequence's mean grey must lie in."""
JOB = {"sensor": (240, 180), "frame_sensor": "davis240c_aps", "start": 0.0, "end": 2.0}
"""The keyword arguments of :func:`sim.simulate.simulate_inputs` (``sweeps/tabletop.toml``)."""


def sequence_greys(family: str, seed: int, illuminance: float | None = None,
                   job: dict | None = None) -> dict:
    """Draw and simulate one sequence's frames (see the module's text); its row.

    Parameters
    ----------
    family : str
        ``tabletop`` or ``room``.
    seed : int
        The job's seed (of the drawing and of the simulation).
    illuminance : float, lux, optional
        The key light's illuminance, instead of the family's range.
    job : dict, optional
        :data:`JOB`'s keyword arguments of :func:`sim.simulate.simulate_inputs` (default
        :data:`JOB`).

    Returns
    -------
    dict
        ``family``, ``seed``, ``frames`` (count), ``mean_grey`` (mean of the frames' means),
        ``frame_mean_min``, ``frame_mean_max``, ``p99_grey`` (99th percentile of every pixel of
        every frame), ``exposure_ms`` ([shortest, longest] of the frames'), ``wall_s``.
    """
    from sim.scene import parse_scene
    from sim.scene.procedural import procedural_scene
    from sim.simulate import simulate, simulate_inputs

    tick = time.perf_counter()
    ranges = {} if illuminance is None else {"illuminance_lux": (illuminance, illuminance)}
    text = procedural_scene(family, seed, **ranges)
    scene, kwargs = simulate_inputs(parse_scene(text, seed=seed), **(job or JOB))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sequence"
        simulate(scene, out, with_events=False, progress=False, **kwargs)
        frames = np.stack([cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
                           for path in sorted((out / "images").glob("*.png"))])
        record = json.loads((out / "sequence.json").read_text())["frames"]
    exposures = record.get("exposures_s") or [record["exposure"]]
    means = frames.reshape(len(frames), -1).mean(axis=1)
    return {"family": family, "seed": seed, "frames": len(frames),
            "mean_grey": round(float(means.mean()), 1),
            "frame_mean_min": round(float(means.min()), 1),
            "frame_mean_max": round(float(means.max()), 1),
            "p99_grey": round(float(np.percentile(frames, 99)), 1),
            "exposure_ms": [round(1e3 * min(exposures), 2), round(1e3 * max(exposures), 2)],
            "wall_s": round(time.perf_counter() - tick, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", default="tabletop,room",
                        help="comma-separated families (default tabletop,room)")
    parser.add_argument("--first", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--seeds", type=int, default=8, help="number of seeds (default 8)")
    parser.add_argument("--illuminance", type=float, default=None,
                        help="draw every key light at this illuminance, lux (not written)")
    parser.add_argument("--size", default="240x180",
                        help="sensor WIDTHxHEIGHT, px (default 240x180; not written otherwise)")
    parser.add_argument("--end", type=float, default=2.0,
                        help="end of the window, s (default 2.0; not written otherwise)")
    parser.add_argument("--no-write", action="store_true",
                        help=f"print only; do not write benchmarks/results/{OUTPUT}")
    args = parser.parse_args(argv)
    job = {**JOB, "sensor": tuple(int(v) for v in args.size.split("x")), "end": args.end}
    rows = []
    print(f"{'family':9} {'seed':>4} {'frames':>6} {'mean':>6} {'min':>6} {'max':>6} "
          f"{'p99':>5} {'exposure ms':>14} {'wall s':>6}")
    for family in args.families.split(","):
        for seed in range(args.first, args.first + args.seeds):
            row = sequence_greys(family, seed, args.illuminance, job)
            rows.append(row)
            low, high = row["exposure_ms"]
            print(f"{family:9} {seed:4d} {row['frames']:6d} {row['mean_grey']:6.1f} "
                  f"{row['frame_mean_min']:6.1f} {row['frame_mean_max']:6.1f} "
                  f"{row['p99_grey']:5.0f} {low:6.2f}-{high:<7.2f} {row['wall_s']:6.1f}",
                  flush=True)
    outside = [f"{r['family']} {r['seed']}" for r in rows
               if not GOAL[0] <= r["mean_grey"] <= GOAL[1]]
    from sim.scene.procedural import GENERATOR_VERSION
    from sim.variant import active_variant

    print(f"generator version {GENERATOR_VERSION}: "
          + (f"outside [{GOAL[0]:g}, {GOAL[1]:g}]: {', '.join(outside)}" if outside
             else f"every mean grey within [{GOAL[0]:g}, {GOAL[1]:g}]"))
    if args.illuminance is None and job == JOB and not args.no_write:
        result = {"goal_mean_grey": list(GOAL), "generator_version": GENERATOR_VERSION,
                  "job": {**JOB, "sensor": "x".join(map(str, JOB["sensor"]))},
                  "variant": active_variant(),
                  "all_within_goal": not outside, "rows": rows}
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / OUTPUT).write_text(json.dumps(result, indent=2) + "\n")
        print(f"written to {RESULTS / OUTPUT}")
    return 1 if outside else 0


if __name__ == "__main__":
    sys.exit(main())
