"""``generate --dry-run``'s cost of each job (:func:`estimate_jobs`), from short warm probes.

A job's wall time is modelled as the sum of what it costs once, per frame and per simulated
second, each measured on the job's own scene, sensor and parameters::

    estimate = draw + setup + compile + frames * per_frame + duration * (per_event_s + hash_s)

- ``draw``: drawing a family or procedural scene (:func:`~sim.dataset._jobs.scene_text`),
  timed when the probe draws it;
- ``setup``: loading the scene into Mitsuba, setting the frames up (the auto-exposure's first
  look included), and the rest of a simulation that is neither frames nor events (the IMU,
  writing ``sequence.json``), from the warm probes;
- ``compile``: what the first probe of a scene cost beyond the warm probes' model of it
  (tracing and compiling its kernels, which a worker does once per scene structure);
- ``per_frame``: the frame stage (renders, depth, optical flow, writing) per frame, from the
  warm probes: a short window holds one or two frames, so its cost is counted per frame,
  never extrapolated with the window's length;
- ``per_event_s``: the event camera (renders, sampling, emulation, writing, per-event depth and
  labels) per simulated second, and ``hash_s`` the manifest's output hash per simulated second,
  from the warm probes.

Each probed job is simulated over five windows of ``probe_seconds`` (:data:`WINDOWS`): at the
start of its window (cold: it compiles), then warm at the start again, a third and two thirds
of the way and at the end, so that a trajectory whose cost changes along the way is seen at four
places. The costs per frame and per simulated second are the warm windows' medians: a window
is short (one or two frames), so one slow step in it would otherwise count as if paid all
along. A built-in scene or scene file is probed once per distinct scene, sensor and sampler (its
first job); a family or procedural scene,
whose every seed is another scene, at :data:`PROBE_SEEDS` seeds spread over the sweep's seeds,
and its other seeds get the mean of those probes, with their spread printed.

The error against real jobs is measured by ``python -m benchmarks.bench_generate
--estimates`` (:data:`ESTIMATE_ERROR`).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from sim.dataset._jobs import Job, job_inputs, job_scene, scene_text
from sim.dataset._run import _one_line

__all__ = ["ESTIMATE_ERROR", "PROBE_SECONDS", "PROBE_SEEDS", "estimate_jobs", "estimate_report"]

PROBE_SECONDS = 0.05
"""Length of each probe window, simulated s."""
PROBE_SEEDS = 4
"""Seeds of each family or procedural scene (and sensor) that are probed."""
WINDOWS = (0.0, 0.0, 1 / 3, 2 / 3, 1.0)
"""Where a probe's windows start, as fractions of its job's window less one probe window: the
first is cold (it compiles the scene's kernels), the others warm, the first of them the same
window again (their difference is the compilation)."""
ESTIMATE_ERROR = 0.30
"""Largest relative error of a probed job's estimate against the measured job (``wall_s``) that
``benchmarks/bench_generate.py --estimates`` allows; its result
(``benchmarks/results/generate_estimates.json``) holds the errors measured, and those of the
mean a seed that is not probed gets (each seed against the mean of the others)."""

_FRAME_STAGE = ("depth", "frame_motion", "frame_edges", "render", "frame_sensor", "write", "flow")
"""``timings_s``' keys that are paid per frame (``frame_setup`` and ``exposure_control``, the
auto-exposure's first look, are paid once a simulation)."""
_EVENT_STAGE = ("event_render", "emulate", "emulate_compile", "event_sample", "event_write",
                "event_depth", "checkpoint")


def _stages(timings: dict) -> tuple[float, float, float]:
    """(frame stage, event stage, everything else) seconds of one simulation."""
    frames = sum(timings.get(k, 0.0) for k in _FRAME_STAGE)
    events = sum(timings.get(k, 0.0) for k in _EVENT_STAGE)
    return frames, events, timings["total"] - frames - events


def _probe(job: Job, variant: str | None, folder: Path, probe_seconds: float) -> dict:
    """The cost model of one job, from :data:`WINDOWS` windows of its own simulation."""
    from sim.dataset._manifest import output_hash
    from sim.frames import frame_times
    from sim.simulate import simulate

    tick = time.perf_counter()
    text = scene_text(job, variant) if job.generated else None
    scene, kwargs = job_inputs(job, job_scene(job, text))
    draw = time.perf_counter() - tick if text is not None else 0.0
    start, duration = kwargs["start"], kwargs["duration"]
    window = min(duration, probe_seconds)
    runs = []
    for k, fraction in enumerate(WINDOWS):
        out = folder / f"window{k}"
        result = simulate(scene, out, variant=variant, progress=False,
                          **dict(kwargs, start=start + fraction * (duration - window),
                                 duration=window))
        tick = time.perf_counter()
        output_hash(out)
        frames, events, other = _stages(result.timings)
        runs.append({"frames": result.n_frames, "frame_s": frames,
                     "event_s": events + time.perf_counter() - tick,
                     "setup_s": result.timings["setup"] + other,
                     "total_s": result.timings["total"] + time.perf_counter() - tick})
    cold, warm = runs[0], runs[1:]
    # Medians of the warm windows: a window is short, so one slow step in it (a kernel compiled
    # for a new exposure count, a lazily loaded kernel) would weigh as if it were paid all along.
    per_frame = [r["frame_s"] / r["frames"] for r in warm if r["frames"]]
    return {"job_id": job.job_id, "draw": draw,
            "setup": float(np.median([r["setup_s"] for r in warm])),
            "compile": max(0.0, cold["total_s"] - warm[0]["total_s"]),
            "per_frame": float(np.median(per_frame)) if per_frame else 0.0,
            "per_second": float(np.median([r["event_s"] for r in warm])) / window,
            "frames": len(frame_times(duration, scene.frames)), "duration": duration}


def _cost(model: dict, frames: int, duration: float) -> float:
    return (model["draw"] + model["setup"] + model["compile"] + frames * model["per_frame"]
            + duration * model["per_second"])


def _probed_seeds(seeds: list[int], count: int) -> set[int]:
    """``count`` seeds spread evenly over ``seeds`` (first and last included)."""
    if len(seeds) <= count:
        return set(seeds)
    index = np.round(np.linspace(0, len(seeds) - 1, count)).astype(int)
    return {seeds[i] for i in index}


def estimate_jobs(sweep, variant: str | None = None, probe_seconds: float = PROBE_SECONDS,
                  probe_seeds: int = PROBE_SEEDS) -> list[dict]:
    """Each job's estimated wall seconds in a worker, from short warm probes (module docstring).

    Parameters
    ----------
    sweep : Sweep
    variant : str, optional
    probe_seconds : float, s
        Length of each of a probe's windows.
    probe_seeds : int
        Seeds probed per family or procedural scene and sensor.

    Returns
    -------
    list of dict
        One per job: ``job_id``, ``scene``, ``seed``, ``params``, ``duration_s``,
        ``estimate_s`` (None where the probe failed), ``probed`` (True: its own probe; False:
        the mean of its scene's probed seeds), ``spread_s`` (the ``(lowest, highest)``
        estimate of those probed seeds' models at this job's length, None for a probed
        job), ``parts`` (the model's terms, seconds) and ``probe_error``.
    """
    seeds = sorted({job.seed for job in sweep.jobs})
    chosen = _probed_seeds(seeds, probe_seeds)

    def group(job: Job) -> str:
        return repr((job.identity["scene"], job.params.get("sensor"), job.params.get("sampler")))

    models: dict[str, dict | str] = {}            # probe key -> model or error
    members: dict[str, list[str]] = {}            # group -> probe keys of its probed jobs
    with tempfile.TemporaryDirectory(prefix="evfuse-probe-") as tmp:
        for job in sweep.jobs:
            key = group(job)
            if job.generated:
                if job.seed not in chosen:
                    continue
                key = f"{key}#{job.seed}"
            if key in models:
                continue
            try:
                models[key] = _probe(job, variant, Path(tmp) / f"probe{len(models)}",
                                     probe_seconds)
            except (ValueError, OSError, RuntimeError) as error:
                models[key] = _one_line(error)
            members.setdefault(group(job), []).append(key)
        rows = []
        for job in sweep.jobs:
            rows.append(_row(job, group(job), models, members))
    return rows


def _row(job: Job, key: str, models: dict, members: dict) -> dict:
    row = {"job_id": job.job_id, "scene": job.label, "seed": job.seed, "params": job.params,
           "duration_s": None, "estimate_s": None, "probed": False, "spread_s": None,
           "parts": None, "probe_error": ""}
    own = models.get(f"{key}#{job.seed}" if job.generated else key)
    if isinstance(own, str):
        row["probe_error"] = own
        return row
    if own is not None and (job.generated or own["job_id"] == job.job_id):
        row.update(probed=True, duration_s=own["duration"],
                   estimate_s=_cost(own, own["frames"], own["duration"]),
                   parts=_parts(own, own["frames"], own["duration"]))
        return row
    good = [models[k] for k in members.get(key, []) if isinstance(models[k], dict)]
    if not good:
        errors = [models[k] for k in members.get(key, []) if isinstance(models[k], str)]
        row["probe_error"] = errors[0] if errors else "no probe"
        return row
    try:
        duration, frames = _length(job, good[0])
    except (ValueError, OSError, RuntimeError) as error:
        row["probe_error"] = _one_line(error)
        return row
    costs = [_cost(model, frames, duration) for model in good]
    parts = [_parts(model, frames, duration) for model in good]
    row.update(duration_s=duration, estimate_s=float(np.mean(costs)),
               spread_s=(min(costs), max(costs)) if job.generated else None,
               parts={k: float(np.mean([p[k] for p in parts])) for k in parts[0]})
    return row


def _length(job: Job, model: dict) -> tuple[float, int]:
    """The job's simulated seconds and frames. A built-in scene or file is loaded for them
    (no render); a family or procedural seed that was not probed takes its window from its
    parameters (``t0``, ``t1``) where they give one, else the probed seed's, and its frames
    in proportion."""
    if not job.generated:
        from sim.frames import frame_times

        scene, kwargs = job_inputs(job, job_scene(job))
        return kwargs["duration"], len(frame_times(kwargs["duration"], scene.frames))
    if "t1" in job.params:
        duration = float(job.params["t1"]) - float(job.params.get("t0", 0.0))
        frames = round(model["frames"] * duration / model["duration"])
        return duration, frames
    return model["duration"], model["frames"]


def _parts(model: dict, frames: int, duration: float) -> dict:
    return {"draw": model["draw"], "setup": model["setup"], "compile": model["compile"],
            "frames": frames * model["per_frame"], "events": duration * model["per_second"]}


def _seconds(value: float) -> str:
    return f"{value:.1f}" if value >= 1 else f"{value:.2f}"


def estimate_report(sweep, rows: list[dict]) -> str:
    """``--dry-run``'s text: one line per job of :func:`estimate_jobs`' ``rows`` (its
    estimate, how it was made, its parameters) and the total.

    Parameters
    ----------
    sweep : Sweep
    rows : list of dict
        :func:`estimate_jobs`' result.
    """
    width = max(len(row["job_id"]) for row in rows)
    lines = [f"{len(rows)} jobs of sweep {sweep.name} ({sweep.source}): each job's wall seconds "
             f"in one worker, from warm probes of {PROBE_SECONDS:g} s at four places of its window "
             f"(frames counted per frame); a probed job's estimate is within "
             f"{ESTIMATE_ERROR:.0%} of the measured job (benchmarks/bench_generate.py "
             f"--estimates); a generated scene is probed at {PROBE_SEEDS} of its seeds, and its "
             "other seeds get their mean and their spread:"]
    for row in rows:
        params = ", ".join(f"{k}={v}" for k, v in row["params"].items())
        if row["estimate_s"] is None:
            lines.append(f"  {row['job_id']:<{width}}  probe failed: {row['probe_error']}  "
                         f"{params}")
            continue
        parts = row["parts"]
        once = parts["draw"] + parts["setup"] + parts["compile"]
        how = (f"frames {_seconds(parts['frames'])} + events {_seconds(parts['events'])} + "
               f"setup {_seconds(once)}")
        if row["spread_s"] is not None:
            low, high = row["spread_s"]
            how = f"mean of probed seeds, {low:.1f}-{high:.1f} s"
        cost = f"~{row['estimate_s']:.1f} s"
        lines.append(f"  {row['job_id']:<{width}}  {cost:>9}  ({how})  {params}")
    known = [row["estimate_s"] for row in rows if row["estimate_s"] is not None]
    simulated = sum(row["duration_s"] or 0 for row in rows)
    lines.append(f"total: ~{sum(known):.0f} s of one worker for {simulated:g} simulated s "
                 f"({len(rows) - len(known)} jobs not estimated); nothing written")
    return "\n".join(lines)
