"""Convergence of the defaults: events and frames against a 256-samples-per-pixel reference.

A pixel integrates the light over its area; the event camera takes ``[render] event_spp`` point
samples per pixel (4 by default) and the frames ``[render] spp`` (16) where an edge crosses the
pixel during the exposure and ``flat_spp`` (4) elsewhere (:mod:`sim.frame_shader`; whole-frame
renders at ``spp`` for dynamic_6dof). Per scene and window this simulates, in one process, the
scene as it is (the defaults) and its reference, the same scene with ``event_spp`` = ``spp`` =
``flat_spp`` = 256 (:data:`REFERENCE_SPP`) and nothing else changed, and reports:

- events: the default's count error and worst 16x16 block (blocks with >= 100 reference
  events) against the reference (:func:`benchmarks.agreement.event_agreement`);
- frames: the PSNR of the default's 8-bit frames against the reference's (the worst frame of
  the window). The frames come from the ``ideal`` sensor (no noise, which would dominate) at
  one gain, the reference's automatic gain, so they differ by their renders alone. The
  reference renders every pixel at 256 samples, at exposure times sized for 256 (the image
  moves 1/16 pixel between two: :func:`sim.frame_shader.exposure_times`);
- cost: the default's pixel samples (a whole-frame render counts H W) and event-render seconds
  (``sequence.json``'s ``timings_s``), after a 0.01-s run that traces and compiles the kernels;
  in the results, the frames' too (``frame_render_s``, ``frame_pixel_samples``).

Goals (issue 23), printed PASS/FAIL beside each row: event count within 3 %
(:data:`COUNT_GOAL`), every block with >= 100 events within 5 % (:data:`BLOCK_GOAL`), frames at
least 40 dB (:data:`PSNR_GOAL`). The event camera is the ``ideal`` preset (no noise), the
sampler the automatic one (per-pixel for a static scene, frame for dynamic_6dof), no motion
ground truth.

Scenes (:data:`CASES`): boxes_6dof, poster_6dof, dynamic_6dof, complex_heightfield and the
held-out ``garden_wall`` (``scenes/garden_wall.toml``, made for this benchmark and tuned to
nothing), at 240x180, each at two times over 0.05 s. ``--quick``: boxes_6dof and garden_wall at
their first time over 0.02 s.

Run: ``PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_convergence.py [--quick]`` (on 2
shared CPU cores, ``llvm_ad_rgb``: ``--quick`` about a minute; the four static scenes 5.5
minutes; dynamic_6dof's frame sampler renders whole frames at up to 20 kHz, and its reference
about 20 minutes per 0.05-s window, 9.4 minutes for 0.02 s, so the full run would take about
an hour).
``--scenes`` picks scenes, ``--first`` only their first time, ``--window`` sets the seconds.
``--edge-spp N`` also runs each default with ``[render] edge_spp = N`` (the pixels an edge
crosses rendered at N samples per pixel, :mod:`sim.pixel_sampling`; either sampler), after the
default, and prints its row below the default's (its frames are the default's).
``--event-spp 1,16,64`` also runs each default with ``[render] event_spp`` at each of those
values (perfect squares below :data:`REFERENCE_SPP`; frames unchanged), after the default, each
against the same reference: events against the event camera's samples per pixel (the scene's
own value is the default's run, not run twice).
``--floor`` renders each reference a second time with another render seed (``[render] seed``:
other sub-sample positions, the same scene) and prints that second reference against the
first on its own line: the yardstick's own spread, below which no run can be told from the
reference (its frames PSNR too).
Results are printed and written to ``benchmarks/results/convergence.json``
(``convergence_quick.json`` for ``--quick``), row by row (a row replaces an earlier run's of
the same scene and window).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from PIL import Image

from benchmarks.agreement import event_agreement
from benchmarks.bench_sampling import event_pixel_samples
from scenes import resolve_scene
from sim.eventio import read_events
from sim.scene import load_scene
from sim.sequence import read_index
from sim.simulate import simulate

RESULTS = Path(__file__).resolve().parent / "results"
REFERENCE_SPP = 256
"""Samples per pixel of the reference's event camera and frames."""
COUNT_GOAL, BLOCK_GOAL, PSNR_GOAL = 0.03, 0.05, 40.0
"""Goals at the defaults: |count error|, worst block error (fractions), frame PSNR (dB)."""
CASES = [("boxes_6dof", (3.5, 30.0)), ("poster_6dof", (2.0, 40.0)),
         ("dynamic_6dof", (6.2, 30.0)), ("complex_heightfield", (1.0, 2.5)),
         ("garden_wall", (1.0, 5.0))]
"""(scene, start times in s) of the full run: the paper's window start, and a later time."""
QUICK = [("boxes_6dof", (3.5,)), ("garden_wall", (1.0,))]
"""The ``--quick`` subset."""
FRAME_RENDER = ("frame_motion", "frame_edges", "render")
"""``timings_s`` keys of the frames' renders (``frame_render_s``; their pixel samples:
``frame_cost.pixel_samples``)."""


def _run(scene, folder: Path, start: float, seconds: float) -> dict:
    result = simulate(scene, folder, start=start, duration=seconds, progress=False,
                      event_formats=("h5",), motion_truth=False, overwrite=True)
    record = json.loads((folder / "sequence.json").read_text())
    return {"events": result.n_events, "sampler": record["events"]["sampler"],
            "pixel_samples": event_pixel_samples(scene, record["events"]),
            "edge_samples": record["events"].get("edge_samples", 0),
            "event_render_s": result.timings["event_render"],
            "frame_render_s": sum(result.timings[k] for k in FRAME_RENDER),
            "frame_pixel_samples": record["frame_cost"]["pixel_samples"],
            "gain": record["frames"]["gain_used"]}


def _frames(folder: Path) -> list[np.ndarray]:
    _, names = read_index(folder / "images.txt")
    return [np.asarray(Image.open(folder / name), dtype=np.float64) for name in names]


def psnr(reference: np.ndarray, image: np.ndarray, peak: float = 255.0) -> float:
    """Peak signal-to-noise ratio of ``image`` against ``reference``, dB (inf when equal).

    Parameters
    ----------
    reference, image : ndarray
        Same shape, 8-bit values (0-``peak``).
    """
    mse = float(np.mean((np.asarray(image, np.float64) - reference) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(peak ** 2 / mse))


def _with_spp(scene, spp: int | None, gain: float | None, render_seed: int | None = None):
    """The scene with the ideal frame sensor at ``gain``, ``spp`` for events and frames (every
    frame pixel: ``spp`` and ``flat_spp``), and ``render_seed`` (``[render] seed``) when
    given."""
    frames = replace(scene.frames.with_sensor("ideal"), gain=gain)
    render = scene.render if spp is None else replace(scene.render, spp=spp, event_spp=spp,
                                                      flat_spp=spp)
    if render_seed is not None:
        render = replace(render, seed=render_seed)
    return replace(scene, frames=frames, render=render)


def _frame_psnrs(reference_folder: Path, folder: Path) -> list[float]:
    """PSNR of each frame of a run against the same frame of the reference, dB."""
    return [psnr(r, d) for r, d in zip(_frames(reference_folder), _frames(folder), strict=True)]


def _goals(agreement: dict) -> dict:
    """The event goals an agreement (``EventAgreement.as_dict()``) meets: count and blocks."""
    return {"count": bool(abs(agreement["count_error"]) <= COUNT_GOAL),
            "blocks": bool(agreement["worst_block_error"] <= BLOCK_GOAL)}


def _versus(reference_folder: Path, folder: Path, shape: tuple[int, int],
            psnrs: list[float]) -> tuple[dict, dict]:
    """Agreement of a run's events with the reference's, and the goals met."""
    agreement = event_agreement(read_events(reference_folder / "events.h5"),
                                read_events(folder / "events.h5"), shape).as_dict()
    return agreement, {**_goals(agreement),
                       "frames": bool(psnrs) and bool(min(psnrs) >= PSNR_GOAL)}


def bench_case(name: str, start: float, seconds: float, folder: Path, warm: bool,
               edge_spp: int = 0, floor: bool = False, event_spps: tuple[int, ...] = ()
               ) -> dict:
    """One scene and window: the default against the reference (see the module docstring),
    with ``edge_spp`` (> 0) the default with ``[render] edge_spp`` set too, with ``floor``
    a second reference at another render seed against the first, and with ``event_spps`` the
    default at each of those ``[render] event_spp`` (row ``event_spp_sweep``)."""
    scene = load_scene(resolve_scene(name))
    shape = (scene.camera.height, scene.camera.width)
    tick = time.perf_counter()
    reference = _run(_with_spp(scene, REFERENCE_SPP, None), folder / "reference", start, seconds)
    default_scene = _with_spp(scene, None, reference["gain"])
    if warm:                                                  # trace and compile once
        _run(default_scene, folder / "warm", start, 0.01)
    default = _run(default_scene, folder / "default", start, seconds)
    psnrs = _frame_psnrs(folder / "reference", folder / "default")
    agreement, passed = _versus(folder / "reference", folder / "default", shape, psnrs)
    row = {"scene": name, "window_s": [start, start + seconds],
           "event_spp": scene.render.event_spp, "spp": scene.render.spp,
           "reference_spp": REFERENCE_SPP, "default": default, "reference": reference,
           "agreement": agreement, "frames": len(psnrs),
           "frame_psnr_db": min(psnrs) if psnrs else None, "pass": passed}
    if edge_spp:
        edged = replace(default_scene, render=replace(default_scene.render, edge_spp=edge_spp))
        if warm:
            _run(edged, folder / "warm", start, 0.01)
        run = _run(edged, folder / "edges", start, seconds)
        agreement, passed = _versus(folder / "reference", folder / "edges", shape, psnrs)
        row["edges"] = {"edge_spp": edge_spp, "run": run, "agreement": agreement,
                        "pass": passed}
    if event_spps:
        row["event_spp_sweep"] = _event_spp_sweep(default_scene, event_spps, default, row,
                                                  folder, start, seconds, shape, warm)
    if floor:
        seed = scene.render_seed + 1
        run = _run(_with_spp(scene, REFERENCE_SPP, reference["gain"], seed),
                   folder / "reference_seed", start, seconds)
        spread = _frame_psnrs(folder / "reference", folder / "reference_seed")
        agreement, passed = _versus(folder / "reference", folder / "reference_seed", shape,
                                    spread)
        row["floor"] = {"render_seed": seed, "run": run, "agreement": agreement,
                        "frame_psnr_db": min(spread) if spread else None, "pass": passed}
    row["wall_s"] = time.perf_counter() - tick
    print(f"{name} {start:g} s: {row['wall_s']:.0f} s", flush=True)
    return row


def _event_spp_sweep(default_scene, event_spps: tuple[int, ...], default: dict, row: dict,
                     folder: Path, start: float, seconds: float, shape: tuple[int, int],
                     warm: bool) -> list[dict]:
    """The default at each ``[render] event_spp`` of ``event_spps`` against the reference: one
    entry each (``event_spp``, ``run``, ``agreement``; the scene's own value is the default's
    run)."""
    sweep = []
    for spp in event_spps:
        if spp == default_scene.render.event_spp:
            sweep.append({"event_spp": spp, "run": default, "agreement": row["agreement"],
                          "pass": _goals(row["agreement"]), "is_default": True})
            continue
        scene = replace(default_scene, render=replace(default_scene.render, event_spp=spp))
        if warm:
            _run(scene, folder / "warm", start, 0.01)
        run = _run(scene, folder / f"event_spp_{spp}", start, seconds)
        agreement = event_agreement(read_events(folder / "reference" / "events.h5"),
                                    read_events(folder / f"event_spp_{spp}" / "events.h5"),
                                    shape).as_dict()
        sweep.append({"event_spp": spp, "run": run, "agreement": agreement,
                      "pass": _goals(agreement), "is_default": False})
    return sweep


def event_spp_values(text: str) -> tuple[int, ...]:
    """``--event-spp``'s values: comma-separated perfect squares below :data:`REFERENCE_SPP`,
    ascending."""
    try:
        values = sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise ValueError(f"--event-spp: expected comma-separated integers, got {text!r}") from None
    bad = [v for v in values if v < 1 or v >= REFERENCE_SPP or math.isqrt(v) ** 2 != v]
    if bad or not values:
        raise ValueError(f"--event-spp: expected perfect squares from 1 to below the reference's "
                         f"{REFERENCE_SPP}, got {text!r}")
    return tuple(values)


def _verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def _line(label: str, run: dict, a: dict, ok: dict, frames: str) -> str:
    """One printed line: a run's events against the reference, its goals and its cost."""
    return (f"{label}  {run['sampler']:<7} "
            f"{a['count']:7,} {a['reference_count']:10,}  {100 * a['count_error']:+6.1f} % "
            f"{_verdict(ok['count'])}  {100 * a['worst_block_error']:5.1f} % "
            f"({a['worst_block_events']:5,}, {a['blocks']:3}) "
            f"{_verdict(ok['blocks'])}  {frames}  {run['pixel_samples']:13,}  "
            f"{run['event_render_s']:14.2f}")


def table(rows: list[dict]) -> str:
    """The printed table (one line a row; the goals in the header)."""
    lines = [f"goals: events within {100 * COUNT_GOAL:.0f} %, every block with >= 100 events "
             f"within {100 * BLOCK_GOAL:.0f} %, frames >= {PSNR_GOAL:.0f} dB "
             f"(reference: {REFERENCE_SPP} samples per pixel)",
             "worst block: its error (its reference events, blocks with >= 100 of them)",
             "scene                t (s)  sampler  events  reference  count        "
             "worst block (events, blocks)   frames PSNR     pixel samples  event render s"]
    for row in rows:
        lines.append(_line(f"{row['scene']:<20} {row['window_s'][0]:5.1f}", row["default"],
                           row["agreement"], row["pass"], _frames_cell(row)))
        if "edges" in row:
            e = row["edges"]
            lines.append(_line(f"  edge_spp {e['edge_spp']:<3} {'':>8}", e["run"],
                               e["agreement"], e["pass"], f"{'':13}")
                         + f"  (edge samples {e['run']['edge_samples']:,})")
        for entry in row.get("event_spp_sweep", []):
            if not entry["is_default"]:
                lines.append(_line(f"  event_spp {entry['event_spp']:<3}{'':>7}", entry["run"],
                                   entry["agreement"], entry["pass"], f"{'':13}"))
        if "floor" in row:
            f = row["floor"]
            lines.append(_line(f"  reference, seed {f['render_seed']:<3}", f["run"],
                               f["agreement"], f["pass"], _frames_cell(f))
                         + "  (against the first reference: its floor)")
    return "\n".join(lines)


def _frames_cell(row: dict) -> str:
    """The frames' PSNR column of a row (``frame_psnr_db`` and ``pass``)."""
    if row["frame_psnr_db"] is None:
        return "   -         "
    return f"{row['frame_psnr_db']:5.1f} dB {_verdict(row['pass']['frames'])}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="boxes_6dof and garden_wall at one time over 0.02 s")
    parser.add_argument("--scenes", default=None, help="comma-separated scene names")
    parser.add_argument("--window", type=float, default=None,
                        help="seconds per window (default 0.05, --quick 0.02)")
    parser.add_argument("--first", action="store_true", help="only each scene's first time")
    parser.add_argument("--edge-spp", type=int, default=0,
                        help="also run the default with [render] edge_spp = N (0: not)")
    parser.add_argument("--event-spp", default=None,
                        help="also run the default at each of these [render] event_spp "
                             "(comma-separated perfect squares below the reference's, e.g. "
                             "1,4,16,64)")
    parser.add_argument("--floor", action="store_true",
                        help="also render each reference at another render seed: its spread")
    args = parser.parse_args()
    try:
        event_spps = () if args.event_spp is None else event_spp_values(args.event_spp)
    except ValueError as error:
        parser.error(str(error))
    cases = QUICK if args.quick else CASES
    if args.scenes is not None:
        cases = [c for c in CASES if c[0] in args.scenes.split(",")]
    seconds = args.window or (0.02 if args.quick else 0.05)
    path = RESULTS / ("convergence_quick.json" if args.quick else "convergence.json")
    rows, tick = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for name, starts in cases:
            for k, start in enumerate(starts[:1] if args.first else starts):
                rows.append(bench_case(name, start, seconds, Path(tmp), warm=k == 0,
                                       edge_spp=args.edge_spp, floor=args.floor,
                                       event_spps=event_spps))
                _write_rows(path, rows[-1:])
    print(f"\n{table(rows)}\n\nwall time {time.perf_counter() - tick:.0f} s\nwritten to {path}")


def _write_rows(path: Path, rows: list[dict]) -> None:
    """Add ``rows`` to ``path``, replacing an earlier run's rows of the same scene and window."""
    RESULTS.mkdir(exist_ok=True)
    kept = json.loads(path.read_text()) if path.is_file() else []
    mine = {(r["scene"], *r["window_s"]) for r in rows}
    kept = [r for r in kept if (r["scene"], *r["window_s"]) not in mine]
    path.write_text(json.dumps(kept + rows, indent=2))


if __name__ == "__main__":
    main()
