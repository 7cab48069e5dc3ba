"""Does the event emulator keep up with the renderer? (issue 23, item 4)

1. Stages of ``simulate`` on built-in scenes at the defaults (``evfuse simulate`` with
   ``--no-motion-truth``), per-pixel and frame sampler, ideal and realistic noise:
   ``sequence.json``'s ``timings_s`` split into the renders (``event_render``), the emulator's
   own time (``emulate``), the sampler's choice of samples (``event_sample``) and the kernels'
   compilation or cache load before the clock (``emulate_compile``). Goal: ``emulate`` under a
   third of ``event_render``.
2. Before / after in the same run: every block the per-pixel emulator was fed in (1) is
   recorded with the emulator's state, then replayed through the emulator evfuse had before
   (``_serial_advance_samples``, the code of commit c7d2105: a count pass then a write pass,
   every crossing time solved twice, the low-pass exponents gathered and checked pixel pair
   by pixel pair), through today's :meth:`PixelEventEmulator.advance_samples` with its numba
   kernel (``after``: one pass) and with its Dr.Jit kernel (``drjit``,
   :mod:`sim._drjit_events`, on the device of the variant that rendered: every core on
   ``llvm_ad_rgb``). ``before`` and ``after`` must give identical events; the Dr.Jit kernel's
   are compared with them (identical, with ``after``'s causes too, or the largest time
   difference). The ratios of their seconds are the speed-ups; where ``after``'s seconds go
   is printed too (leak draws, the kernel, noise events, and the rest: exponents, sort by
   time, packing).
3. The frame sampler's first :data:`FRAME_INTERVALS` frames of each run in (1), replayed
   through the frame emulator with its numba kernel (one thread, as in ``simulate``) and with
   its Dr.Jit kernel: their seconds, ratio and events (identical, or the largest time
   difference).

Run: ``.venv/bin/python benchmarks/bench_emulator.py`` (about 1-2 minutes on 2 cores;
``--skip-frame`` leaves out the frame sampler's slow runs). Results are printed and written to
``benchmarks/results/emulator.json``. Timings only; nothing here is asserted.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from sim.eventio import EVENT_DTYPE
from sim.events import (
    EventEmulator,
    EventParams,
    filtered_crossing_time,
    interval_levels,
    threshold_crossings,
)
from sim.noise import _cutoff, lowpass_exponent
from sim.pixel_sampling import PixelEventEmulator

RESULTS = Path(__file__).resolve().parent / "results"
CASES = [("slider_close", 0.0, 0.2), ("boxes_6dof", 3.5, 0.05)]
"""(scene, start s, duration s): the windows issue 23 measures."""
FRAME_INTERVALS = 200
"""Frames of each frame-sampler run replayed through both frame kernels (the first ones)."""


@numba.njit(cache=True)
def _serial_pixel_events(pix, t, L, exponent, ref, level, raw, last_t, c_on, c_off, leak,
                         normals, refractory, write, out_t, out_pix,
                         out_p):  # pragma: no cover - compiled
    """The per-pixel kernel as of commit c7d2105 (one thread), kept as the baseline."""
    leak_rates, leak_jitter = leak
    n = 0
    S = len(pix)
    j = 0
    k = 0
    while j < S:
        p = pix[j]
        r = ref[p]
        lf = level[p]
        la = raw[p]
        ta = t[j]
        last = last_t[p]
        j += 1
        while j < S and pix[j] == p:
            tb = t[j]
            lb = L[j]
            dt = tb - ta
            x = exponent[j - 1]
            if leak_rates.size:
                jitter = 1.0 - leak_jitter * normals[k]
                if jitter < 0.0:
                    jitter = 0.0
                r += -((dt * 1e-9) * leak_rates[p] * jitter * c_on[p])
            f_turn, y_turn, lf_new = interval_levels(lf, la, lb, x)
            f_lo, y_lo, f_hi, y_hi = 0.0, lf, f_turn, y_turn
            while True:
                count, c, sign = threshold_crossings(y_hi, r, c_on[p], c_off[p])
                for i in range(1, count + 1):
                    te = filtered_crossing_time(r + i * c, lf, la, lb, x, f_lo, y_lo, f_hi, y_hi,
                                                ta, float(dt))
                    if refractory > 0 and te - last < refractory:
                        continue
                    last = te
                    if write:
                        out_t[n] = te
                        out_pix[n] = p
                        out_p[n] = sign
                    n += 1
                r += count * c
                if f_hi >= 1.0:
                    break
                f_lo, y_lo, f_hi, y_hi = f_hi, y_hi, 1.0, lf_new
            lf, la, ta = lf_new, lb, tb
            j += 1
            k += 1
        if write:
            ref[p] = r
            level[p] = lf
            raw[p] = la
            last_t[p] = last
    return n


def _serial_advance_samples(self: PixelEventEmulator, pixels, times_ns, levels, luminance,
                            t_end_ns, end_luminance) -> np.ndarray:
    """:meth:`PixelEventEmulator.advance_samples` as of commit c7d2105."""
    noise = self.params.noise
    t0_ns = self._t
    shape = self.shape
    n_pixels = shape[0] * shape[1]
    if np.shares_memory(self._L, self._raw):
        self._L = self._L.copy()
    ref, level, raw = self.ref.reshape(-1), self._L.reshape(-1), self._raw.reshape(-1)
    last_t = self._last_t.reshape(-1)
    normals, leak = self._leak_draws(pixels)
    exponent = np.full(max(len(pixels) - 1, 0), np.inf)
    if noise.cutoff_hz > 0:
        same = pixels[1:] == pixels[:-1]
        cutoff = _cutoff(np.asarray(luminance, np.float64), noise)
        exponent[same] = lowpass_exponent(np.diff(times_ns)[same] * 1e-9, cutoff[:-1][same],
                                          cutoff[1:][same])
    refractory = int(round(noise.refractory_period * 1e9))
    c_on, c_off = self.c_on.reshape(-1), self.c_off.reshape(-1)
    args = (pixels, times_ns, levels, exponent, ref, level, raw, last_t, c_on, c_off, leak,
            normals, refractory)
    empty = np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.int8)
    total = _serial_pixel_events(*args, False, *empty)
    out_t, out_pix, out_p = np.empty(total, np.int64), np.empty(total, np.int64), \
        np.empty(total, np.int8)
    _serial_pixel_events(*args, True, out_t, out_pix, out_p)
    order = np.argsort((out_t - t0_ns) * n_pixels + out_pix)
    events = np.empty(total, EVENT_DTYPE)
    events["t"] = out_t[order]
    events["y"], events["x"] = np.divmod(out_pix[order], shape[1])
    events["p"] = out_p[order]
    return self._close_block(events, t0_ns, t_end_ns, end_luminance)


def run_case(scene_name: str, start: float, duration: float, sampler: str, noise: str,
             record: list | None) -> dict:
    """One ``simulate`` run; its stage timings, and (``record`` a list) what the emulator was
    fed, each with the emulator's state before it: every block (per-pixel sampler), or the
    first :data:`FRAME_INTERVALS` frames (frame sampler)."""
    from scenes import resolve_scene
    from sim.scene import load_scene
    from sim.simulate import simulate

    scene = load_scene(resolve_scene(scene_name))
    owner, name = ((PixelEventEmulator, "advance_samples") if sampler == "pixel" else
                   (EventEmulator, "advance"))
    advance = getattr(owner, name)

    def recording(self, *args):
        if (record is not None and self.shape != (1, 2)              # not warm_up's sensor
                and (sampler == "pixel" or len(record) < FRAME_INTERVALS)):
            record.append((copy.deepcopy(self.get_state()), copy.deepcopy(args)))
        return advance(self, *args)

    setattr(owner, name, recording)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            result = simulate(scene, Path(tmp) / "seq", start=start, duration=duration,
                              progress=False, sampler=sampler, motion_truth=False,
                              events=EventParams.preset(noise, seed=scene.seed))
    finally:
        setattr(owner, name, advance)
    t = result.timings
    return {"scene": scene_name, "start_s": start, "duration_s": duration, "sampler": sampler,
            "noise": noise, "events": result.n_events, "event_render_s": t["event_render"],
            "emulate_s": t["emulate"], "event_sample_s": t["event_sample"],
            "emulate_compile_s": t["emulate_compile"],
            "emulate_over_render": t["emulate"] / max(t["event_render"], 1e-9),
            "variant": result.variant,
            "params": EventParams.preset(noise, seed=scene.seed), "shape": (
                scene.camera.height, scene.camera.width)}


def replay(row: dict, record: list, repeats: int) -> dict:
    """Seconds of the emulator over the recorded blocks (best of ``repeats``) through the
    code of c7d2105 (``before``), today's numba kernel (``after``) and today's Dr.Jit kernel on
    the active variant's device (``drjit``); whether their events are identical (else the
    largest time difference, ns); and where ``after``'s seconds go (:func:`_stages`)."""
    paths = {"before": ("numba", _serial_advance_samples),
             "after": ("numba", PixelEventEmulator.advance_samples),
             "drjit": ("drjit", PixelEventEmulator.advance_samples)}
    seconds, events, causes, stages = {}, {}, {}, {}
    for name, (kernel, method) in paths.items():
        emulator = PixelEventEmulator(row["shape"], row["params"], kernel=kernel)
        emulator.warm_up()
        _serial_advance_samples(*_warm_serial(row))
        best = np.inf
        for _ in range(repeats):
            total, chunks, labels = 0.0, [], []
            timers = _stages(emulator) if name == "after" else None
            for state, args in record:
                emulator.set_state(copy.deepcopy(state))
                tick = time.perf_counter()
                chunks.append(method(emulator, *args))
                total += time.perf_counter() - tick
                labels.append(emulator.last_causes)
            if total < best and timers is not None:
                stages = {**timers, "exponents, sort, pack": total - sum(timers.values())}
            best = min(best, total)
            _unwrap(emulator)
        seconds[name] = best
        events[name] = np.concatenate(chunks)
        causes[name] = np.concatenate(labels)
    before = events["before"]
    return {"blocks": len(record), "samples": int(sum(len(args[0]) for _, args in record)),
            "crossings": len(before),
            **{f"{name}_s": value for name, value in seconds.items()},
            "speedup": seconds["before"] / seconds["after"],
            "identical": np.array_equal(before, events["after"]),
            "drjit_over_numba": seconds["drjit"] / seconds["after"],
            **_agreement(before, causes["after"], events["drjit"], causes["drjit"]),
            "after_stages_s": stages}


def replay_frames(row: dict, record: list, repeats: int) -> dict:
    """Seconds of the frame emulator over the recorded frames (best of ``repeats``, numba on
    one thread as in ``simulate``) with its numba kernel and with its Dr.Jit kernel, and
    whether their events are identical (else the largest time difference, ns)."""
    seconds, events, causes = {}, {}, {}
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for kernel in ("numba", "drjit"):
            emulator = EventEmulator(row["shape"], row["params"], kernel=kernel)
            emulator.warm_up()
            best = np.inf
            for _ in range(repeats):
                total, chunks, labels = 0.0, [], []
                for state, args in record:
                    emulator.set_state(copy.deepcopy(state))
                    tick = time.perf_counter()
                    chunks.append(emulator.advance(*args))
                    total += time.perf_counter() - tick
                    labels.append(emulator.last_causes)
                best = min(best, total)
            seconds[kernel], events[kernel] = best, np.concatenate(chunks)
            causes[kernel] = np.concatenate(labels)
    finally:
        numba.set_num_threads(threads)
    return {"frames": len(record), "numba_s": seconds["numba"], "drjit_s": seconds["drjit"],
            "drjit_over_numba": seconds["drjit"] / seconds["numba"],
            **_agreement(events["numba"], causes["numba"], events["drjit"], causes["drjit"])}


def _agreement(events: np.ndarray, causes: np.ndarray, drjit: np.ndarray,
               drjit_causes: np.ndarray) -> dict:
    """Whether the Dr.Jit kernel's events and causes are the numba kernel's, and (same
    number) the largest difference of their times, ns."""
    same_count = len(drjit) == len(events)
    return {"drjit_identical": np.array_equal(events, drjit)
            and np.array_equal(causes, drjit_causes),
            "drjit_same_count": same_count,
            "drjit_max_dt_ns": int(np.abs(drjit["t"] - events["t"]).max(initial=0))
            if same_count else None}


def _agreement_text(result: dict) -> str:
    """``identical``, ``within N ns`` or ``counts differ`` (:func:`_agreement`)."""
    if result["drjit_identical"]:
        return "identical"
    if result["drjit_same_count"]:
        return f"within {result['drjit_max_dt_ns']} ns"
    return "counts differ"


def _stages(emulator: PixelEventEmulator) -> dict:
    """Time the emulator's steps of a block on this instance (its leak draws, the kernel's
    crossings, the block's noise events and close); returns the dict their seconds add up in
    (the rest of :meth:`~PixelEventEmulator.advance_samples` is the low-pass exponents, the
    sort by time and the packing into events)."""
    timers = {"leak draws": 0.0, "kernel": 0.0, "noise events, close": 0.0}
    for key, name in (("leak draws", "_leak_draws"), ("kernel", "_numba_crossings"),
                      ("noise events, close", "_close_block")):
        method = getattr(emulator, name)

        def timed(*args, _method=method, _key=key):
            tick = time.perf_counter()
            try:
                return _method(*args)
            finally:
                timers[_key] += time.perf_counter() - tick

        setattr(emulator, name, timed)
    return timers


def _unwrap(emulator: PixelEventEmulator) -> None:
    """Undo :func:`_stages` on ``emulator``."""
    for name in ("_leak_draws", "_numba_crossings", "_close_block"):
        emulator.__dict__.pop(name, None)


def _warm_serial(row: dict) -> tuple:
    """Arguments that compile the serial kernel (on a 1x2 sensor) before it is timed."""
    spare = PixelEventEmulator((1, 2), row["params"])
    spare.start(np.zeros((1, 2)), 0.0)
    levels = np.array([0.0, 1.0, 0.0, -1.0])
    return (spare, np.array([0, 0, 1, 1], np.int64),
            np.array([0, 1_000_000, 0, 1_000_000], np.int64), levels, np.exp(levels),
            1_000_000, np.array([[np.e, np.exp(-1.0)]]))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-frame", action="store_true",
                        help="leave out the frame sampler's runs")
    args = parser.parse_args(argv)
    rows = []
    for scene, start, duration in CASES:
        for sampler in ("pixel",) + (() if args.skip_frame else ("frame",)):
            for noise in ("ideal", "realistic"):
                record: list = []
                row = run_case(scene, start, duration, sampler, noise, record)
                if sampler == "pixel":
                    row["replay"] = replay(row, record, args.repeats)
                else:
                    row["frame_replay"] = replay_frames(row, record, args.repeats)
                del row["params"], row["shape"]
                rows.append(row)
    print(f"\nThe event camera's stages on {rows[0]['variant']} ({os.cpu_count()} cores), "
          "simulate --no-motion-truth, seconds")
    print(f"{'scene':>13} {'sampler':>7} {'noise':>9} {'events':>8} {'render':>7} "
          f"{'emulate':>8} {'sample':>7} {'compile':>8} {'emu/render':>10} | replay: "
          f"{'before':>7} {'after':>7} {'speed-up':>8} identical | {'drjit':>7} "
          f"{'/after':>6} drjit events")
    for r in rows:
        line = (f"{r['scene']:>13} {r['sampler']:>7} {r['noise']:>9} {r['events']:>8} "
                f"{r['event_render_s']:>7.3f} {r['emulate_s']:>8.3f} {r['event_sample_s']:>7.3f} "
                f"{r['emulate_compile_s']:>8.3f} {r['emulate_over_render']:>10.2f} |")
        if "replay" in r:
            p = r["replay"]
            line += (f" {p['before_s']:>7.3f} {p['after_s']:>7.3f} "
                     f"{p['speedup']:>7.2f}x {p['identical']!s:>9} | {p['drjit_s']:>7.3f} "
                     f"{p['drjit_over_numba']:>5.2f}x {_agreement_text(p)}")
        if "frame_replay" in r:
            p = r["frame_replay"]
            line += (f" {p['frames']} frames: numba {p['numba_s']:.3f} | {p['drjit_s']:>7.3f} "
                     f"{p['drjit_over_numba']:>5.2f}x {_agreement_text(p)}")
        print(line)
    print("\nWhere the replay's 'after' seconds go (today's numba emulator), seconds")
    for r in rows:
        if "replay" in r:
            stages = ", ".join(f"{k} {v:.3f}" for k, v in r["replay"]["after_stages_s"].items())
            print(f"{r['scene']:>13} {r['noise']:>9}: {stages}")
    result = {"cores": os.cpu_count(), "rows": rows,
              "note": "emulate_over_render goal: < 1/3; replay: the same blocks through the "
                      "emulator of c7d2105 (before), today's numba kernel (after) and today's "
                      "Dr.Jit kernel on the variant's device (drjit), best of "
                      f"{args.repeats}, in the process that rendered them"}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "emulator.json").write_text(json.dumps(result, indent=2))
    print(f"\nwritten to {RESULTS / 'emulator.json'}")
    return result


if __name__ == "__main__":
    main()
