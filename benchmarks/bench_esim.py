"""The frame emulator beside ESIM's, in one run: ``emulate_events`` against esim_py.

esim_py is ESIM's event simulator (uzh-rpg/rpg_vid2e) built from its own sources, with the
in-memory frame method ``generateFromFrames`` that ``../shared/anchors/`` adds
(``esim_bindings.cpp``, ``REBUILD.sh``); it is not part of evfuse and not in this repository.
Both get ``bench_events.py``'s input (a smooth random texture moving 2.5 px a frame, contrast
0.17, C = 0.2, frames 1 ms apart, held in memory: float64 for evfuse, float32 for esim_py,
whose ``cv::Mat`` frames are float32) at 240x180, 640x480 and 1280x720. Each repetition times
both tools on every size, alternating which goes first; the ratio of a repetition is esim_py's
wall time over evfuse's (the events are the same, so it is the ratio of their event rates),
and the table gives the median over the repetitions and its spread (lowest and highest).
evfuse runs on numba's default threads (both cores of the development machine) and, for
reference, on one.

The events are checked once per size: the same number, and event for event (each tool's
events ordered by pixel, then time) the same pixel and polarity, with times that agree to the
difference printed, largest and how many are more than 1 us apart (esim_py keeps levels and
references in float32, so a crossing on a nearly flat interval moves; evfuse works in float64
and rounds to the nanosecond).

Where esim_py cannot be imported, evfuse alone is timed and the figures measured beside
esim_py in earlier runs are printed as history, not as a ratio of this run.

Run: ``.venv/bin/python benchmarks/bench_esim.py --esim DIR`` (``DIR`` holds the built
``esim_py`` module; or set ``ESIM_PY=DIR``, or ``ANCHORS`` to the folder ``REBUILD.sh``
built in, whose ``esim_py_src/build/lib*`` is then used). Written to
``benchmarks/results/events_vs_esim.json``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np

from benchmarks.bench_events import SIZES, checked_sizes, moving_texture
from sim.events import emulate_events

RESULTS = Path(__file__).resolve().parent / "results"
CONTRAST = 0.2
HISTORY = {
    "source": "evfuse / esim_py measured side by side on the 2-core development machine "
              "(../shared/anchors/README.md; issue 36), evfuse on 2 threads",
    "ratios": {
        "ed63122 (2026-11-23)": {"240x180": 1.24, "640x480": 1.39, "1280x720": 1.54},
        "ffa23ad (physical radiometry)": {"240x180": 1.09, "640x480": 1.13, "1280x720": 1.22},
        "ae61552 (2026-11-28)": {"240x180": 0.83, "640x480": 0.92, "1280x720": 1.13},
    },
}
"""Ratios measured beside esim_py before this benchmark existed: printed when it is absent."""


def find_esim(path: str | None):
    """The esim_py module from ``path``, ``$ESIM_PY`` or ``$ANCHORS/esim_py_src/build/lib*``,
    or None (with the reason) when none of them holds it."""
    folders = [path or os.environ.get("ESIM_PY")]
    if folders[0] is None and os.environ.get("ANCHORS"):
        folders = sorted(str(p) for p in
                         Path(os.environ["ANCHORS"]).glob("esim_py_src/build/lib*"))
    folders = [f for f in folders if f]
    if not folders:
        return None, "no esim_py given (--esim DIR, ESIM_PY=DIR or ANCHORS=DIR)"
    sys.path[:0] = folders
    try:
        return importlib.import_module("esim_py"), None
    except ImportError as error:
        return None, f"esim_py not importable from {', '.join(folders)}: {error}"


def frames_for(label: str, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """bench_events' input at a sensor size: (N, H, W) float64 log frames and times (s)."""
    shape = SIZES[label]
    n = n_frames if shape[0] <= 180 else max(12, n_frames // 4)
    return moving_texture(shape, n, 2.5, contrast=0.17), np.arange(n) / 1000.0


def run_esim(esim, frames32: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, float]:
    """esim_py's events ((N, 4): x, y, t in s, p) and the call's wall time (s)."""
    simulator = esim.EventSimulator(CONTRAST, CONTRAST, 0.0, 1e-3, False)
    start = time.perf_counter()
    events, _ = simulator.generateFromFrames(frames32, list(times))
    return events, time.perf_counter() - start


def run_evfuse(frames: np.ndarray, times: np.ndarray, threads: int) -> tuple[np.ndarray, float]:
    """``emulate_events``' events on ``threads`` numba threads and the call's wall time (s)."""
    default = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        start = time.perf_counter()
        events = emulate_events(frames, times)
        return events, time.perf_counter() - start
    finally:
        numba.set_num_threads(default)


def compare(esim_events: np.ndarray, events: np.ndarray) -> dict:
    """Whether two tools gave the same events: counts, and event for event (both ordered by
    pixel, then time) pixels and polarities, and the largest time difference (ns)."""
    same_count = len(esim_events) == len(events)
    result = {"esim_events": len(esim_events), "evfuse_events": len(events),
              "same_pixels_and_polarities": False, "max_time_difference_ns": None,
              "median_time_difference_ns": None, "events_over_1us_apart": None}
    if not same_count:
        return result
    t_esim = np.round(esim_events[:, 2] * 1e9).astype(np.int64)
    a = np.lexsort((t_esim, esim_events[:, 0], esim_events[:, 1]))
    b = np.lexsort((events["t"], events["x"], events["y"]))
    result["same_pixels_and_polarities"] = bool(
        np.array_equal(esim_events[a, 0], events["x"][b])
        and np.array_equal(esim_events[a, 1], events["y"][b])
        and np.array_equal(esim_events[a, 3], events["p"][b]))
    difference = np.abs(t_esim[a] - events["t"][b])
    result["max_time_difference_ns"] = int(difference.max(initial=0))
    result["median_time_difference_ns"] = float(np.median(difference)) if len(difference) else 0.0
    result["events_over_1us_apart"] = int(np.count_nonzero(difference > 1000))
    return result


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--esim", help="folder holding the built esim_py module")
    parser.add_argument("--reps", type=int, default=5, help="repetitions (default 5)")
    parser.add_argument("--frames", type=int, default=60,
                        help="frames at 240x180 (a quarter of it, at least 12, above)")
    parser.add_argument("--sizes", default=",".join(SIZES),
                        help=f"sensors, among {','.join(SIZES)} (default all)")
    args = parser.parse_args(argv)
    sizes = checked_sizes(parser, args.sizes)
    if args.reps < 1:
        parser.error(f"--reps must be at least 1, got {args.reps}")
    if args.frames < 4:
        parser.error(f"--frames must be at least 4, got {args.frames}")
    esim, why = find_esim(args.esim)
    threads = numba.get_num_threads()
    data = {label: frames_for(label, args.frames) for label in sizes}
    emulate_events(*frames_for("240x180", 4))                      # compile outside the timing
    frames32 = {label: np.ascontiguousarray(frames, np.float32)
                for label, (frames, _) in data.items()}
    rows: list[dict] = []
    first: dict[tuple[str, str], np.ndarray] = {}              # each tool's events, rep 0
    for rep in range(args.reps):
        for label, (frames, times) in data.items():
            tools = ["esim_py"] * (esim is not None) + ["evfuse", "evfuse_1t"]
            for tool in tools if rep % 2 == 0 else tools[::-1]:
                if tool == "esim_py":
                    events, wall = run_esim(esim, frames32[label], times)
                else:
                    events, wall = run_evfuse(frames, times, 1 if tool == "evfuse_1t" else threads)
                if rep == 0:
                    first[label, tool] = events
                rows.append({"rep": rep, "size": label, "tool": tool, "events": len(events),
                             "s": wall})
    checks = {label: compare(first[label, "esim_py"], first[label, "evfuse"])
              for label in sizes if esim is not None}
    if any(not np.array_equal(first[label, "evfuse"], first[label, "evfuse_1t"])
           for label in sizes):
        raise RuntimeError("emulate_events gave different events on 1 thread and on "
                           f"{threads}")
    summary = {}
    for label in sizes:
        def walls(tool, label=label):
            return np.array([r["s"] for r in rows if r["size"] == label and r["tool"] == tool])

        events = next(r["events"] for r in rows if r["size"] == label and r["tool"] == "evfuse")
        entry = {"frames": len(data[label][1]), "events": events}
        for tool in ("esim_py", "evfuse", "evfuse_1t")[esim is None:]:
            entry[f"{tool}_mev_per_s"] = float(np.median(events / walls(tool) / 1e6))
        if esim is not None:
            for tool in ("evfuse", "evfuse_1t"):
                ratio = walls("esim_py") / walls(tool)                 # per repetition
                entry[f"{tool}_over_esim"] = {"median": float(np.median(ratio)),
                                              "min": float(ratio.min()),
                                              "max": float(ratio.max())}
            entry["events_check"] = checks[label]
        summary[label] = entry
    print(f"\nevfuse's emulate_events beside esim_py: bench_events' input, {args.reps} "
          f"repetitions, medians (Mev/s = events / wall time of the call); evfuse on "
          f"{threads} threads and on 1; the machine may be shared: the ratios are per "
          "repetition, with their spread")
    if esim is None:
        print(f"esim_py absent ({why}): evfuse alone; earlier ratios, as history only:")
        for commit, ratios in HISTORY["ratios"].items():
            print(f"  {commit}: " + ", ".join(f"{k} {v:.2f}x" for k, v in ratios.items()))
        print(f"  ({HISTORY['source']})")
        print(f"{'size':>9} {'events':>9} {'evfuse':>7} {'1 thread':>9}")
        for label, e in summary.items():
            print(f"{label:>9} {e['events']:>9} {e['evfuse_mev_per_s']:>7.2f} "
                  f"{e['evfuse_1t_mev_per_s']:>9.2f}")
    else:
        print(f"{'size':>9} {'events':>9} {'esim_py':>8} {'evfuse':>7} {'ratio (min-max)':>19} "
              f"{'1 thread':>9} {'ratio (min-max)':>19}  same events (max |dt|, > 1 us)")
        for label, e in summary.items():
            r, r1, c = e["evfuse_over_esim"], e["evfuse_1t_over_esim"], e["events_check"]
            same = (c["esim_events"] == c["evfuse_events"] and c["same_pixels_and_polarities"])
            print(f"{label:>9} {e['events']:>9} {e['esim_py_mev_per_s']:>8.2f} "
                  f"{e['evfuse_mev_per_s']:>7.2f} {r['median']:>6.2f}x ({r['min']:.2f}-"
                  f"{r['max']:.2f}) {e['evfuse_1t_mev_per_s']:>9.2f} {r1['median']:>6.2f}x "
                  f"({r1['min']:.2f}-{r1['max']:.2f})  {'yes' if same else 'NO'} "
                  f"({c['max_time_difference_ns']} ns, {c['events_over_1us_apart']} > 1 us)")
    result = {"esim_py": None if esim is None else {"module": esim.__file__},
              "esim_py_absent_because": why, "threads": threads, "reps": args.reps,
              "summary": summary, "rows": rows, "history": HISTORY}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "events_vs_esim.json").write_text(json.dumps(result, indent=2))
    print(f"\nwritten to {RESULTS / 'events_vs_esim.json'}")
    return result


if __name__ == "__main__":
    main()
