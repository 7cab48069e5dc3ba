"""What a dataset's jobs cost, by part, and on which device (:func:`cost_table`): the table
``evfuse generate`` prints when its jobs are done.

Each complete job's seconds come from its ``profile.json`` when it has one (``evfuse simulate
--profile``: per stage ``wall_s`` and ``device_s``, the Dr.Jit kernels' execution time; the
``event_camera``'s ``wall_s``, ``device_s``, ``host_s`` and ``launches``; ``variant``,
``device``), else from ``sequence.json``'s ``timings_s`` (wall seconds only). The device row says
what rendered (the variant, the device's name) and, where profiles were written, how many of
the event camera's seconds the device itself spent.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

from sim.profile import EVENT_CAMERA_STAGES, PROFILE_JSON

__all__ = ["PROFILE_FILE", "cost_table", "job_costs"]

PROFILE_FILE = PROFILE_JSON
"""A sequence folder's profile (``evfuse simulate --profile``), read when present."""
PARTS = {"event camera": EVENT_CAMERA_STAGES,
         "events, rest": ("emulate_compile", "event_write", "event_depth"),
         "checkpoints": ("checkpoint",),
         "frames": ("frame_setup", "depth", "exposure_control", "frame_motion", "frame_edges",
                    "render", "frame_sensor", "write", "flow")}
"""The table's rows (and ``other``: every other stage of ``timings_s``, set-up and IMU)."""


def job_costs(folder: str | Path) -> dict:
    """One complete job's seconds by part of :data:`PARTS`, from its folder.

    Parameters
    ----------
    folder : str or Path
        A sequence folder (``sequence.json``, maybe ``profile.json``).

    Returns
    -------
    dict
        ``wall_s`` (part -> wall seconds, ``other`` and ``total`` included), ``device_s``
        (the event camera's device seconds, None without a profile that measured them),
        ``launches`` (its Dr.Jit launches, None likewise), ``simulated_s``, ``variant``,
        ``device`` (None where the profile does not name it) and ``source`` (``profile.json``
        or ``timings_s``).
    """
    folder = Path(folder)
    record = json.loads((folder / "sequence.json").read_text(encoding="utf-8"))
    timings = {k: float(v) for k, v in record.get("timings_s", {}).items() if k != "total"}
    variant = record.get("render", {}).get("variant")
    costs = {"device_s": None, "launches": None, "device": None, "source": "timings_s",
             "variant": variant, "simulated_s": float(record.get("duration") or 0.0)}
    profile_path = folder / PROFILE_FILE
    if profile_path.is_file():
        profile = json.loads(profile_path.read_text(encoding="utf-8"))
        stages = profile.get("stages", {})
        timings.update({k: float(v["wall_s"]) for k, v in stages.items()
                        if isinstance(v, dict) and v.get("wall_s") is not None})
        camera = profile.get("event_camera") or {}
        costs.update(device_s=camera.get("device_s"), launches=camera.get("launches"),
                     device=profile.get("device"), source=PROFILE_FILE,
                     variant=profile.get("variant", variant),
                     simulated_s=float(profile.get("simulated_s") or costs["simulated_s"]))
    wall = {part: sum(timings.get(k, 0.0) for k in names) for part, names in PARTS.items()}
    known = {k for names in PARTS.values() for k in names}
    wall["other"] = sum(v for k, v in timings.items() if k not in known)
    wall["total"] = sum(timings.values())
    costs["wall_s"] = wall
    return costs


def cost_table(folders: Iterable[str | Path], devices: Iterable[str] = ()) -> str:
    """The cost of a dataset's complete jobs, summed by part, and the device row.

    Parameters
    ----------
    folders : iterable of str or Path
        The complete jobs' sequence folders.
    devices : iterable of str
        The devices the workers rendered on (the workers' own report, e.g. ``NVIDIA H200``),
        named where no profile names one.

    Returns
    -------
    str
        A header line, a row per part of :data:`PARTS` (wall seconds summed over the jobs and
        per simulated second; the event camera's device and host seconds where every job's
        profile measured them), and the device row: the variants, the devices, and the
        event camera's device seconds (or why they are not known).
    """
    jobs, unread = [], []
    for folder in folders:
        try:
            jobs.append(job_costs(folder))
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
            unread.append(f"{Path(folder).name} ({type(error).__name__})")
    skipped = f"; left out, unreadable: {', '.join(unread)}" if unread else ""
    if not jobs:
        return f"cost: no complete job{skipped}"
    simulated = sum(j["simulated_s"] for j in jobs)
    profiled = [j for j in jobs if j["source"] == PROFILE_FILE]
    measured = bool(jobs) and all(j["device_s"] is not None for j in jobs)
    device_s = sum(j["device_s"] for j in jobs) if measured else None
    lines = [f"cost of {len(jobs)} jobs ({simulated:g} s simulated), seconds summed over the "
             f"jobs, from {len(profiled)} profile.json and {len(jobs) - len(profiled)} "
             f"timings_s{skipped}:",
             f"  {'part':<14} {'wall s':>9} {'device s':>9} {'host s':>9} "
             f"{'wall s per simulated s':>23}"]
    for part in (*PARTS, "other", "total"):
        wall = sum(j["wall_s"][part] for j in jobs)
        device = device_s if part == "event camera" else None
        host = "" if device is None else f"{wall - device:9.2f}"
        per = f"{wall / simulated:23.3f}" if simulated else f"{'-':>23}"
        lines.append(f"  {part:<14} {wall:9.2f} {'' if device is None else f'{device:9.2f}':>9}"
                     f" {host:>9} {per}")
    variants = sorted({j["variant"] or "?" for j in jobs})
    named = sorted({j["device"] for j in jobs if j["device"]} | set(devices))
    on = f"{', '.join(variants)} on {'; '.join(named) or 'an unnamed device'}"
    gpu = any(v.startswith("cuda") for v in variants)
    if measured:
        camera = sum(j["wall_s"]["event camera"] for j in jobs)
        launches = sum(j["launches"] or 0 for j in jobs)
        what = "GPU" if gpu else "CPU cores in Dr.Jit kernels"
        share = f" ({device_s / camera:.0%})" if camera else ""
        lines.append(f"  device: {on}: the {what} ran {device_s:.2f} s of the event camera's "
                     f"{camera:.2f} s{share}, {launches:,} launches")
    else:
        lines.append(f"  device: {on}: device seconds not measured (profile.json in "
                     f"{len(profiled)} of {len(jobs)} jobs; generate --profile writes them)")
    return "\n".join(lines)
