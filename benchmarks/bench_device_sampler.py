"""The per-pixel sampler's host time, reference path against device path (issue 36, item 2).

Runs ``evfuse simulate`` (``--no-motion-truth``, the case's ``--seed``) once per path in a
fresh process each, the paths alternating, ``--repeat`` times, and reports per path the event
camera's wall time (``sequence.json``'s ``event_render + event_sample + emulate +
emulate_compile``), the Dr.Jit kernels' execution time inside the event stage
(``dr.kernel_history()``, ``execution_time`` summed), the host time (wall less kernel time),
the launches, the events, the pixel samples and the CPU time of the whole event stage (every
thread: Dr.Jit's workers, numba, Python; ``getrusage``, less sensitive to other processes than
wall time); the fastest repeat of each path
is kept. Paths:

- ``reference``: the blocks' samples built, shaded, checked and refined by numba and NumPy
  (``_PixelSampler.on_device = False``);
- ``device``: by :func:`sim._drjit_sampling.device_block` on the variant's device, the
  emulator's kernel chosen as ``simulate`` does (numba on the CPU, Dr.Jit on a GPU);
- ``device-drjit``: the same with Dr.Jit's emulator fed on the device
  (:meth:`sim.pixel_sampling.PixelEventEmulator.advance_device`) on any device;
- ``device-wavefront``: the device path with ``--wavefront`` blocks a pass of device launches
  (:attr:`sim.sampling.SamplingParams.wavefront`; default 4), the emulator's kernel as for
  ``device``;
- ``frame``: the frame sampler (``--sampler frame``), for the ratio the per-pixel sampler must
  keep (>= 8x cheaper in event-camera wall time on slider_close).

Results are printed as a table and written to ``benchmarks/results/device_sampler.json``
(``--out`` to change). The development machine is shared: compare the ratios of one run.
Timings only; nothing is asserted.
"""

from __future__ import annotations

import argparse
import importlib
import json
import resource
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
CASES = {"240x180": ("slider_close", None, 0.0, 0.5, 3),
         "640x480": ("slider_close", "vga", 0.0, 0.1, 3)}
"""name: (scene, camera preset or None for the scene's, start s, duration s, seed)."""
PATHS = ("reference", "device", "device-drjit", "device-wavefront", "frame")
TIMED = ("event_render", "event_sample", "emulate", "emulate_compile")
"""``sequence.json``'s ``timings_s`` entries that make up the event camera."""


def child(case: str, path: str, wavefront: int = 1) -> dict:
    """One run of ``case`` by ``path`` in this process (``evfuse simulate``); its figures
    (``wavefront``: the ``device-wavefront`` path's blocks a pass)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import drjit as dr
    from bench_host import _scene

    from fusion.cli import main as evfuse

    events_module = importlib.import_module("sim.simulate._events")
    run_module = importlib.import_module("sim.simulate._run")
    events_module._PixelSampler.on_device = path.startswith("device")
    if path == "device-drjit":
        events_module._PixelSampler.emulator_kernel = "drjit"
    if path == "device-wavefront":           # the command line's sampling, with the passes
        sampling = importlib.import_module("sim.sampling")     # read by simulate_inputs
        sampling.SamplingParams = partial(sampling.SamplingParams, wavefront=wavefront)
    kernels: dict = {}
    stage = run_module._simulate_events

    def measured(*args, **kwargs):
        dr.kernel_history()                                    # cleared
        before = resource.getrusage(resource.RUSAGE_SELF)
        try:
            return stage(*args, **kwargs)
        finally:
            after = resource.getrusage(resource.RUSAGE_SELF)
            kernels["cpu"] = (after.ru_utime + after.ru_stime - before.ru_utime
                              - before.ru_stime)
            history = dr.kernel_history()
            kernels["seconds"] = sum(k.get("execution_time", 0.0) for k in history) / 1e3
            kernels["launches"] = len(history)

    run_module._simulate_events = measured
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    scene_name, preset, start, duration, seed = CASES[case]
    scene, tmp_toml = _scene(scene_name, preset)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            evfuse(["simulate", str(tmp_toml or scene_name), "--start", str(start),
                    "--duration", str(duration), "--seed", str(seed), "--sampler",
                    "frame" if path == "frame" else "pixel", "--no-motion-truth", "--out",
                    str(Path(tmp) / "seq")])
            record = json.loads((Path(tmp) / "seq" / "sequence.json").read_text())
    finally:
        if tmp_toml is not None:
            tmp_toml.unlink()
    timings, events = record["timings_s"], record["events"]
    wall = sum(timings[k] for k in TIMED)
    if path == "device-wavefront":
        assert record["events"]["sampling"]["wavefront"] == wavefront
    return {"case": case, "path": path, "shape": [scene.camera.height, scene.camera.width],
            "wavefront": record["events"]["sampling"].get("wavefront", 1),
            "duration_s": duration, "variant": record["render"]["variant"],
            "emulator_kernel": events["emulator_kernel"], "wall_s": round(wall, 4),
            "kernel_s": round(kernels["seconds"], 4),
            "host_s": round(wall - kernels["seconds"], 4), "launches": kernels["launches"],
            "event_stage_cpu_s": round(kernels["cpu"], 3),
            "events": events["count"], "pixel_samples": events["pixel_samples"],
            "timings_s": {k: timings[k] for k in TIMED}}


def main(argv=None) -> list:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=["240x180"])
    parser.add_argument("--paths", nargs="+", choices=PATHS, default=list(PATHS))
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS / "device_sampler.json")
    parser.add_argument("--wavefront", type=int, default=4,
                        help="blocks a pass of the device-wavefront path (default 4)")
    parser.add_argument("--child", nargs=2, metavar=("CASE", "PATH"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(*args.child, args.wavefront)))
        return []
    best: dict = {}
    for case in args.cases:
        for _ in range(args.repeat):
            for path in args.paths:
                out = subprocess.run([sys.executable, __file__, "--child", case, path,
                                      "--wavefront", str(args.wavefront)],
                                     capture_output=True, text=True, check=True)
                row = json.loads(out.stdout.strip().splitlines()[-1])
                key = (case, path)
                if key not in best or row["wall_s"] < best[key]["wall_s"]:
                    best[key] = row
    rows = list(best.values())
    for case in args.cases:
        frame = best.get((case, "frame"))
        for path in ("reference", "device", "device-drjit", "device-wavefront"):
            row = best.get((case, path))
            if row is not None and frame is not None:
                row["frame_over_pixel_wall"] = round(frame["wall_s"] / row["wall_s"], 2)
    print(f"{'case':8} {'path':16} {'wall s':>8} {'kernel s':>9} {'host s':>8} "
          f"{'host s/sim s':>12} {'launches':>9} {'events':>10} {'pixel samples':>14} "
          f"{'frame/pixel':>11} {'cpu s':>7}")
    for row in rows:
        print(f"{row['case']:8} {row['path']:16} {row['wall_s']:8.3f} {row['kernel_s']:9.3f} "
              f"{row['host_s']:8.3f} {row['host_s'] / row['duration_s']:12.3f} "
              f"{row['launches']:9d} {row['events']:10,d} {row['pixel_samples']:14,d} "
              f"{row.get('frame_over_pixel_wall', float('nan')):11.2f} "
              f"{row['event_stage_cpu_s']:7.2f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"date": time.strftime("%Y-%m-%d"), "repeat": args.repeat,
                                    "wavefront": args.wavefront, "rows": rows},
                                   indent=1) + "\n")
    return rows


if __name__ == "__main__":
    main()
