"""Where the per-pixel sampler's host time goes, block by block (issue 23, item 4).

On a GPU the event camera's renders and emulation are fast and what is left is host work per
block: the prediction (``rate_map``: motion field, sub-sample gradients, dilation; then the
samples each pixel gets, ``_intra_counts``), the block's sample arrays (``_block_samples``,
``_fill_middle``), the check (``_refine``: midpoints, merging them in), the observed rates
(``_observed_rates``), the frames' pixel values (``pixel_means``), and the emulator's own host
side. This bench runs ``simulate`` in-process (``--no-motion-truth``, per-pixel sampler) with a
timer around each of those functions of :mod:`sim.pixel_sampling` and prints, per case, the
stages' seconds per block beside ``sequence.json``'s ``event_render``, ``emulate`` and
``event_sample``; ``rest`` is ``event_sample`` less the timed stages (the block loop's own NumPy:
logs of the frames and of the samples, the clock).

With ``--drjit`` the first blocks the emulator was fed are replayed through the Dr.Jit kernel
(:mod:`sim._drjit_events`) on the active variant's device, timing its host side: the copies
into Dr.Jit arrays (``_device_array``), the lanes' order (``_lanes``) and the whole call.

Before / after: run this file with another checkout's code first on the path, e.g.
``PYTHONPATH=/path/to/old/checkout .venv/bin/python benchmarks/bench_host.py`` (the stages it
does not have are skipped), alternating with today's in one session; compare ratios only (the
development machine is shared). Results are printed and written to
``benchmarks/results/host.json`` (``--out`` to change). Timings only; nothing is asserted.
"""

from __future__ import annotations

import argparse
import copy
import functools
import json
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
CASES = {"slider": ("slider_close", None, 0.0, 0.2, 3),
         "boxes": ("boxes_6dof", None, 3.5, 0.05, None),
         "hd": ("slider_close", "hd", 0.0, 0.05, 3)}
"""name: (scene, camera preset or None for the scene's, start s, duration s, seed or None)."""
STAGES = ("rate_map", "_intra_counts", "_block_samples", "_fill_middle", "_refine",
          "_observed_rates", "pixel_means")
"""The functions of :mod:`sim.pixel_sampling` timed (those the loaded code has)."""


def _scene(name: str, preset: str | None):
    from scenes import resolve_scene
    from sim.scene import load_scene

    path = Path(resolve_scene(name))
    if preset is None:
        return load_scene(path), None
    text = path.read_text()
    start = text.index("[camera]")
    line_end = text.index("\n", text.index("preset", start))
    text = text[:start] + f'[camera]\npreset = "{preset}"' + text[line_end:]
    tmp = tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False)
    tmp.write(text)
    tmp.close()
    return load_scene(Path(tmp.name)), Path(tmp.name)


def run_case(name: str, record_blocks: int) -> tuple[dict, list]:
    """One ``simulate`` run of case ``name`` with the stages timed; and (``record_blocks`` >
    0) the first blocks the emulator was fed, each with its state before."""
    import sim.pixel_sampling as ps
    from sim.events import EventParams
    from sim.simulate import simulate

    scene_name, preset, start, duration, seed = CASES[name]
    scene, tmp_toml = _scene(scene_name, preset)
    seed = scene.seed if seed is None else seed
    spent = {stage: 0.0 for stage in STAGES if hasattr(ps, stage)}
    originals = {stage: getattr(ps, stage) for stage in spent}

    first_call = {stage: None for stage in spent}

    def timed(stage, function):
        @functools.wraps(function)
        def wrapper(*args, **kwargs):
            # _refine renders its midpoints: their seconds (event_render's) are left out.
            source = args[0] if stage == "_refine" else None
            rendered = getattr(source, "seconds", 0.0)
            tick = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                took = time.perf_counter() - tick - (getattr(source, "seconds", 0.0)
                                                     - rendered)
                spent[stage] += took
                if first_call[stage] is None:
                    first_call[stage] = took
        return wrapper

    record: list = []
    advance = ps.PixelEventEmulator.advance_samples

    def recording(self, *args):
        if self.shape != (1, 2) and len(record) < record_blocks:        # not warm_up's sensor
            record.append((copy.deepcopy(self.get_state()), copy.deepcopy(args)))
        return advance(self, *args)

    for stage, function in originals.items():
        setattr(ps, stage, timed(stage, function))
    ps.PixelEventEmulator.advance_samples = recording
    try:
        with tempfile.TemporaryDirectory() as tmp:
            result = simulate(scene, Path(tmp) / "seq", start=start, duration=duration,
                              progress=False, sampler="pixel", motion_truth=False,
                              events=EventParams.preset("ideal", seed=seed))
    finally:
        for stage, function in originals.items():
            setattr(ps, stage, function)
        ps.PixelEventEmulator.advance_samples = advance
        if tmp_toml is not None:
            tmp_toml.unlink()
    t = result.timings
    blocks = max(result.event_renders - 1, 1)      # a frame at each block boundary
    row = {"case": name, "scene": scene_name, "shape": [scene.camera.height, scene.camera.width],
           "start_s": start, "duration_s": duration, "events": result.n_events,
           "variant": result.variant, "event_render_s": t["event_render"],
           "emulate_s": t["emulate"], "event_sample_s": t["event_sample"],
           "pixel_samples": result.event_pixel_samples,
           "stages_s": {k: round(v, 4) for k, v in spent.items()}}
    row["stages_s"]["rest"] = round(t["event_sample"] - sum(spent.values()), 4)
    # The first call of each stage loads its compiled kernels from numba's cache (or compiles
    # them): in event_sample's first block, not in the blocks after it.
    row["first_calls_s"] = {k: round(v or 0.0, 4) for k, v in first_call.items()}
    row["blocks"] = blocks
    row["event_sample_ms_per_block"] = round(1e3 * t["event_sample"] / blocks, 2)
    return row, record


def replay_drjit(row: dict, record: list, repeats: int) -> dict:
    """Seconds of the Dr.Jit emulator's host side over the recorded blocks (best of
    ``repeats``): the whole ``advance_samples``, its copies into Dr.Jit arrays and the lanes'
    order."""
    import sim._drjit_events as dj
    from sim.events import EventParams
    from sim.pixel_sampling import PixelEventEmulator

    parts = {"_device_array": 0.0, "_lanes": 0.0}
    originals = {name: getattr(dj, name) for name in parts}

    def timed(name, function):
        def wrapper(*args, **kwargs):
            tick = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                parts[name] += time.perf_counter() - tick
        return wrapper

    best = None
    emulator = PixelEventEmulator(tuple(row["shape"]), EventParams(), kernel="drjit")
    emulator.warm_up()
    for name, function in originals.items():
        setattr(dj, name, timed(name, function))
    try:
        for _ in range(repeats):
            for name in parts:
                parts[name] = 0.0
            total = 0.0
            for state, args in record:
                emulator.set_state(copy.deepcopy(state))
                tick = time.perf_counter()
                emulator.advance_samples(*args)
                total += time.perf_counter() - tick
            if best is None or total < best["advance_samples"]:
                best = {"advance_samples": total, **dict(parts)}
    finally:
        for name, function in originals.items():
            setattr(dj, name, function)
    best = {k: round(v, 4) for k, v in best.items()}
    best["blocks"] = len(record)
    best["samples"] = int(sum(len(args[0]) for _, args in record))
    return best


def main(argv=None) -> list:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", default=["slider", "boxes"],
                        help=f"cases to run, of {sorted(CASES)} (default slider boxes)")
    parser.add_argument("--drjit", action="store_true",
                        help="replay the first blocks through the Dr.Jit kernel, timing its "
                             "host side")
    parser.add_argument("--blocks", type=int, default=2,
                        help="blocks to record for --drjit (default 2)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS / "host.json")
    args = parser.parse_args(argv)
    rows = []
    for name in args.cases:
        row, record = run_case(name, args.blocks if args.drjit else 0)
        if args.drjit and record:
            row["drjit_host_s"] = replay_drjit(row, record, args.repeats)
        del record
        rows.append(row)
        stages = "  ".join(f"{k} {v:.3f}" for k, v in row["stages_s"].items())
        first = sum(row["first_calls_s"].values())
        print(f"{name} {row['shape'][1]}x{row['shape'][0]} ({row['variant']}): event_render "
              f"{row['event_render_s']:.2f} s, emulate {row['emulate_s']:.2f} s, event_sample "
              f"{row['event_sample_s']:.2f} s ({row['event_sample_ms_per_block']:.1f} ms a block, "
              f"{row['blocks']} blocks) = {stages}; first calls {first:.3f}")
        if "drjit_host_s" in row:
            print(f"  drjit replay: {row['drjit_host_s']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"date": time.strftime("%Y-%m-%d"), "rows": rows},
                                   indent=1, default=lambda o: np.asarray(o).tolist()))
    return rows


if __name__ == "__main__":
    main()
