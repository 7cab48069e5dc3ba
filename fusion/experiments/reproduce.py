"""``evfuse reproduce``: the paper's three experiments on our twin scenes, as a Markdown report.

* Table 1: boxes / dynamic / poster / shapes 6-DoF: N1, N2, N2/N1, beta, and our errors.
* Table 2: the four slider sequences, six windows each: absolute error of the maps (cm).
* Table 3: the three weightings (inverse distance, Gaussian, exponential) on the sliders.
* A table on the complex-surface scenes: beta and errors per weighting, inside regions and near
  true depth discontinuities.

Each row is one simulated window: the scene is simulated over the window only (cached in
``cache/`` so that a second or interrupted run re-uses every finished simulation), mapped at the
frame nearest the window's middle, filled and scored against the exact depth. By default the
protocol is the paper's: six 1-s windows on each slider (one per second), the paper's own 2-s
windows on the 6-DoF scenes (Table 1's ``window_s``), 2-s windows on the complex surfaces, and
the event camera at ``evfuse simulate``'s defaults (4 samples per pixel, lam = 0.5): the
per-pixel sampler (:mod:`sim.pixel_sampling`) makes that fit in about half an hour on 2 cores.
``dynamic_6dof``, whose objects move, is sampled by whole frames, at 1 sample per pixel and
lam = 1.0 (``moving_event_spp``, ``moving_lam``); the report says so. Its errors are split
into the points on moving objects, the static points one crossed during the window and the
rest (:func:`fusion.scoring.errors_by_motion`), and Table 1 adds a control row,
``dynamic_6dof_frozen``: the same scene with its objects frozen where they are at the moving
row's reference time (:func:`sim.scene.freeze_scene`), simulated the same way (whole frames,
the same samples and lam) over the same window.
Shorter windows can be asked for (``--window``, ``--long-window``); the
report says what was used.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fusion.fill.dense import DenseParams
from fusion.fill.filling import FillParams
from fusion.globalmap.neighbours import FusedViews, fused_reference_map
from fusion.io import to_json
from fusion.map.emvs import DepthMapParams
from fusion.pipeline import fill_window, map_window
from sim.frame_sensor import FrameSensor
from sim.frames import check_frame_sensor, with_frame_sensor
from sim.output import atomic_output_dir, check_output_dir
from sim.progress import progress as progress_stage
from sim.validation import ParameterError, finite, positive

__all__ = ["PAPER", "ReproduceParams", "reproduce"]

TABLE1_SCENES = ("boxes_6dof", "dynamic_6dof", "poster_6dof", "shapes_6dof")
SLIDERS = ("slider_close", "slider_far", "slider_hdr_close", "slider_hdr_far")
COMPLEX = ("complex_sphere", "complex_cylinder", "complex_slanted_plane", "complex_staircase",
           "complex_heightfield")
WEIGHTINGS = ("idw", "gaussian", "exponential")
FROZEN_CONTROLS = ("dynamic_6dof",)
"""Table 1 scenes whose objects move, each followed by a control row: the same scene with its
objects frozen at the moving row's reference time."""

PAPER = {
    "table1": {"boxes_6dof": {"window_s": (3.5, 5.5), "N1": 2289, "N2": 10489, "beta": 0.1898},
               "dynamic_6dof": {"window_s": (6.2, 8.2), "N1": 2270, "N2": 9125,
                                "beta": 0.1587},
               "poster_6dof": {"window_s": (2.0, 4.0), "N1": 4748, "N2": 19338,
                               "beta": 0.3377},
               "shapes_6dof": {"window_s": (2.0, 4.0), "N1": 954, "N2": 2137, "beta": 0.0274}},
    "table2_cm": {"slider_close": (1.67, 1.25, 1.62, 1.57, 0.68, 1.01),
                  "slider_hdr_close": (1.34, 1.59, 2.28, 0.54, 1.06, 1.58),
                  "slider_far": (1.79, 1.24, 1.23, 1.88, 1.30, 1.37),
                  "slider_hdr_far": (1.39, 1.32, 1.35, 1.33, 1.02, 1.11)},
    "table3_cm": {"idw": {"slider_close": 1.33, "slider_hdr_close": 1.66, "slider_far": 1.48,
                          "slider_hdr_far": 1.22},
                  "gaussian": {"slider_close": 1.34, "slider_hdr_close": 1.66,
                               "slider_far": 1.51, "slider_hdr_far": 1.25},
                  "exponential": {"slider_close": 1.35, "slider_hdr_close": 1.66,
                                  "slider_far": 1.52, "slider_hdr_far": 1.25}},
}
"""The paper's Tables 1-3 (``../shared/paper/README.md``): its real DAVIS240C recordings."""


@dataclass(frozen=True)
class ReproduceParams:
    """Settings of ``evfuse reproduce``.

    Attributes
    ----------
    window : float, seconds
        Length of the slider windows (default 1, as the paper).
    long_window : float, seconds
        Length of the Table 1 and complex-surface windows (default 2, as the paper's Table 1).
    table1_start : float or None, seconds
        Start of every Table 1 window; default None: each scene's window starts where the
        paper's does (boxes 3.5 s, dynamic 6.2 s, poster and shapes 2.0 s).
    slider_windows : int
        Windows per slider (default 6, one in each second of the sequence, centred in it).
    complex_start : float, seconds
        Start of the complex-surface windows (default 1.0).
    event_spp : int
        Samples per pixel of the event camera's renders (default 4, as ``evfuse simulate``).
    lam : float
        Sampling bound of the event camera's renders, a fraction of C (default 0.5, as
        ``evfuse simulate``).
    moving_event_spp, moving_lam : int, float
        The same for scenes with moving objects (``dynamic_6dof``), which the per-pixel sampler
        cannot sample: whole frames at the fastest pixel's rate cost about 20 minutes for its
        2-s window at 4 spp and lam 0.5, so by default 1 and 1.0.
    tables : tuple of str
        Which tables to make, among "1", "2", "3", "complex" (default all).
    scenes : tuple of str or None
        Only these scenes (default all of each table); each must be a scene of one of the
        ``tables``.
    frame_sensor : str or FrameSensor or None
        Every scene's standard-camera sensor (:class:`sim.frames.FrameParams` ``sensor``:
        ``ideal``, ``davis240c_aps``, ``machine_vision`` or a
        :class:`sim.frame_sensor.FrameSensor`); default None: each scene file's own.
    event_noise : {"ideal", "realistic"}
        The event camera's noise preset (:func:`sim.noise.noise_preset`: threshold mismatch,
        refractory period, the photoreceptor's low-pass filter, leak and shot-noise events, hot
        pixels; default ``ideal``, as the paper's tables were made so far).
    methods : tuple of str or MethodVariant
        Filling methods to run on every window besides the paper's (default none):
        :func:`fusion.methods.get_method` specs, labels with settings of their own
        (``plane{residual_rel=0.03}``) or :class:`fusion.methods.MethodVariant`; the report adds
        a table of their errors beside the paper's inverse-distance fill, each method by its
        label; the paper's tables are unchanged (always the paper's settings).
    keep_boundary_planes : bool
        The event maps keep their points on the DSI's first and last planes, as rpg_emvs
        (:class:`fusion.map.emvs.DepthMapParams`; default False, dropped and counted).
    """

    window: float = 1.0
    long_window: float = 2.0
    table1_start: float | None = None
    slider_windows: int = 6
    complex_start: float = 1.0
    event_spp: int = 4
    lam: float = 0.5
    moving_event_spp: int = 1
    moving_lam: float = 1.0
    tables: tuple[str, ...] = ("1", "2", "3", "complex")
    scenes: tuple[str, ...] | None = None
    dense: DenseParams = field(default_factory=DenseParams)
    methods: tuple = ()
    frame_sensor: str | FrameSensor | None = None
    event_noise: str = "ideal"
    keep_boundary_planes: bool = False

    def __post_init__(self) -> None:
        if self.event_noise not in ("ideal", "realistic"):
            raise ParameterError(f"{{event_noise}} {ParameterError.literal(repr(self.event_noise))}"
                                 ": expected ideal or realistic", event_noise="event_noise")
        for name in ("window", "long_window", "lam", "moving_lam"):
            positive(name, getattr(self, name))
        for name in ("complex_start", "table1_start"):
            if getattr(self, name) is not None:
                finite(name, getattr(self, name))
        unknown = set(self.tables) - {"1", "2", "3", "complex"}
        if unknown:
            raise ValueError(f"unknown tables {sorted(unknown)}: choose among 1, 2, 3, complex")
        if self.scenes is not None:
            tables = {"1": TABLE1_SCENES, "2": SLIDERS, "3": SLIDERS, "complex": COMPLEX}
            offered = [s for t in self.tables for s in tables[t]]
            missing = [s for s in self.scenes if s not in offered]
            if missing:
                raise ParameterError(
                    f"{{scenes}} {ParameterError.literal(','.join(missing))}: not among the "
                    f"scenes of {{tables}} {ParameterError.literal(','.join(self.tables))} "
                    f"({', '.join(dict.fromkeys(offered))})", scenes="scenes", tables="tables")
        if self.frame_sensor is not None:
            check_frame_sensor(self.frame_sensor)
        from fusion.methods import MethodVariant

        # An unknown method or a bad setting is refused up front; kept checked and coerced.
        object.__setattr__(self, "methods", tuple(MethodVariant.of(m).checked()
                                                  for m in self.methods))


def _jobs(params: ReproduceParams) -> list[dict]:
    """Every (scene, window) to simulate, with the tables it serves."""
    jobs = []
    keep = (lambda name: True) if params.scenes is None else (lambda name: name in params.scenes)
    if "1" in params.tables:
        for s in TABLE1_SCENES:
            if not keep(s):
                continue
            job = {"scene": s, "t0": (PAPER["table1"][s]["window_s"][0]
                                      if params.table1_start is None else params.table1_start),
                   "length": params.long_window, "table": "1", "slider": False}
            jobs.append(job)
            if s in FROZEN_CONTROLS:              # its control: the objects frozen
                jobs.append({**job, "scene": f"{s}_frozen", "frozen_of": s})
    if "2" in params.tables or "3" in params.tables:
        for s in SLIDERS:
            if keep(s):
                jobs += [{"scene": s, "t0": k + 0.5 - params.window / 2,
                          "length": params.window, "table": "2", "slider": True, "k": k}
                         for k in range(params.slider_windows)]
    if "complex" in params.tables:
        jobs += [{"scene": s, "t0": params.complex_start, "length": params.long_window,
                  "table": "complex", "slider": False} for s in COMPLEX if keep(s)]
    return jobs


def _event_quality(scene, params: ReproduceParams) -> tuple[int, float]:
    """The event camera's samples per pixel and sampling bound for a scene."""
    if scene.is_dynamic:
        return params.moving_event_spp, params.moving_lam
    return params.event_spp, params.lam


def _frame_sensor_of(folder: Path) -> str:
    """The standard camera's sensor a simulated window was made with (its sequence.json)."""
    frames = json.loads((folder / "sequence.json").read_text(encoding="utf-8"))["frames"]
    sensor = frames.get("sensor", "ideal")
    return sensor if isinstance(sensor, str) else sensor["name"]


def _window_options(job: dict, params: ReproduceParams) -> tuple[object, dict]:
    """The scene of a job's window (its frame sensor, event camera's samples per pixel and,
    for a frozen control, its objects as the table asks) and the options
    :func:`sim.simulate.window.cached_window` simulates it with."""
    from scenes import resolve_scene
    from sim.events import EventParams
    from sim.noise import noise_preset
    from sim.sampling import SamplingParams
    from sim.scene import load_scene

    scene = load_scene(resolve_scene(job.get("frozen_of", job["scene"])))
    if params.frame_sensor is not None:
        scene = with_frame_sensor(scene, params.frame_sensor)
    spp, lam = _event_quality(scene, params)
    sampler = None
    if "frozen_of" in job:                        # the control: as the moving scene's row
        from sim.scene import freeze_scene

        scene = dataclasses.replace(freeze_scene(scene, job["frozen_at"]), frames=scene.frames)
        sampler = "frame"
    scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render, event_spp=spp))
    return scene, {"sampling": SamplingParams(lam=lam), "sampler": sampler,
                   "events": EventParams(noise=noise_preset(params.event_noise))}


def _fuses(job: dict, views: int) -> bool:
    """Whether a job's map is fused with its neighbours': Table 1's windows with ``views`` > 1,
    not the frozen control (a control of the one-view map's errors on moving objects, whose
    window would otherwise be simulated by whole frames over ``1 + views / 4`` times its
    length, :meth:`FusedViews.span`)."""
    return views > 1 and job["table"] == "1" and "frozen_of" not in job


def _simulated(job: dict, params: ReproduceParams, cache: Path, views: int = 1) -> Path:
    """The cached simulation of a job's window (simulated when missing), in a folder of
    ``cache`` named by the job and :func:`sim.simulate.window.window_key`; a Table 1 window
    with ``views`` > 1 over the span its neighbours need (:meth:`FusedViews.span`)."""
    from sim.simulate.window import cached_window

    scene, options = _window_options(job, params)
    if job["t0"] + job["length"] > scene.duration:
        raise ValueError(f"{job['scene']} lasts {scene.duration} s: no window at {job['t0']} s")
    frozen = f"_at{job['frozen_at']:.6f}" if "frozen_of" in job else ""
    start, length = _simulated_span(job, scene, views)
    return cached_window(scene, cache, f"{job['scene']}{frozen}", start, length, **options)


def _simulated_span(job: dict, scene, views: int) -> tuple[float, float]:
    """``(start, length)`` of the part of the scene a job's window is simulated over, seconds:
    its window; a fused Table 1 window (:func:`_fuses`) the span its neighbours need
    (:meth:`FusedViews.span`); with ``views`` > 1, the frozen control its window started on the
    moving row's frame grid (frames fall at whole periods from a simulation's start, so that
    the control's reference frame is the moving row's)."""
    start, length = job["t0"], job["length"]
    if not (views > 1 and job["table"] == "1"):
        return start, length
    moving_start, end = FusedViews(views).span(start, start + length, scene.duration,
                                               slack=max(map(abs, scene.rig.offsets.values())))
    if _fuses(job, views):
        return moving_start, end - moving_start
    period = 1.0 / scene.frames.rate
    shift = (start - moving_start) % period
    shift = 0.0 if min(shift, period - shift) < 1e-9 * period else shift
    return start - shift, length + shift


def _row(job: dict, sequence_folder: Path, out: Path, params: ReproduceParams,
         views: int = 1) -> dict:
    """Map one window and fill it with each weighting (the stages as ``evfuse run`` wires
    them); the figures it needs, its numbers; a Table 1 window with ``views`` > 1 also its map
    fused with its neighbours', filled with inverse distance weights (``row["fused"]``)."""
    depth = (DepthMapParams(kernel=15, c=7.0) if job["slider"] else DepthMapParams())
    depth = dataclasses.replace(depth, keep_boundary_planes=params.keep_boundary_planes)
    name = f"{job['scene']}_{job['t0']:.2f}"
    mapped, map_params = map_window(sequence_folder, out / name / "map", job["t0"],
                                    job["t0"] + job["length"], depth=depth, overwrite=True,
                                    progress=False)
    row = {"scene": job["scene"], "table": job["table"], "window_s": [job["t0"],
           job["t0"] + job["length"]], "t_ref": mapped.t_ref,
           **map_params.dsi_range.as_dict(),
           "events": mapped.info["events_used"], "map_errors": mapped.info.get("errors"),
           "boundary_plane_points": mapped.info["boundary_plane_points"],
           "fills": {}}
    if "errors_by_motion" in mapped.info:
        row["map_errors_by_motion"] = mapped.info["errors_by_motion"]
    if "k" in job:
        row["k"] = job["k"]
    if "frozen_of" in job:
        row["frozen_of"], row["frozen_at"] = job["frozen_of"], job["frozen_at"]
    weightings = WEIGHTINGS if job["table"] in ("2", "complex") else ("idw",)
    if job["table"] == "2" and "3" not in params.tables:
        weightings = ("idw",)
    for weighting in weightings:
        dense = dataclasses.replace(params.dense, fill=FillParams(
            weighting, sigma=params.dense.fill.sigma, scale=params.dense.fill.scale))
        info = fill_window(out / name / "map", out / name / f"fill_{weighting}", dense,
                           overwrite=True).info
        row["fills"][weighting] = {k: info[k] for k in ("N1", "N1_in_frame", "N2", "Res",
                                                         "beta", "beta_counts",
                                                         "N2_over_N1_in_frame", "regions",
                                                         "regions_filled")}
        row["fills"][weighting]["errors"] = info.get("errors")
        if "errors_by_motion" in info:
            row["fills"][weighting]["errors_by_motion"] = info["errors_by_motion"]
    if _fuses(job, views):
        row["fused"] = _fused(out / name, views, params)
    if params.methods:
        row["methods"] = {}
    for k, variant in enumerate(params.methods):
        info = fill_window(out / name / "map", out / name / f"fill_method{k}", params.dense,
                           overwrite=True, method=variant.spec,
                           method_params=variant.params).info
        row["methods"][variant.label] = {key: info.get(key) for key in ("N2", "beta", "errors",
                                                                        "method_params")}
    return row


def _fused(run: Path, views: int, params: ReproduceParams) -> dict:
    """A Table 1 window's map fused with its ``views - 1`` neighbours' (``run/fused/map``),
    filled with inverse distance weights (``run/fused/fill_idw``): its description and
    numbers, as the one-view row's."""
    description = fused_reference_map(run / "map", run / "fused", views, overwrite=True,
                                      progress=False)
    dense = dataclasses.replace(params.dense, fill=FillParams(
        "idw", sigma=params.dense.fill.sigma, scale=params.dense.fill.scale))
    info = fill_window(run / "fused" / "map", run / "fused" / "fill_idw", dense,
                       overwrite=True).info
    mapped = json.loads((run / "fused" / "map" / "map.json").read_text())
    return {**description, **{k: info[k] for k in ("N1", "N1_in_frame", "N2", "Res", "beta",
                                                     "N2_over_N1_in_frame")},
            "map_errors": mapped.get("errors"), "errors": info.get("errors")}


def reproduce(out: str | Path, params: ReproduceParams | None = None,
              cache: str | Path | None = None, overwrite: bool = False,
              progress: bool = True, views: int = 1) -> dict:
    """Run the paper's experiments on the twin scenes and write ``report.md`` + figures.

    Parameters
    ----------
    out : str or Path
        Report folder: ``report.md``, ``report.json``, ``figures/``, ``runs/`` (every map and
        fill).
    params : ReproduceParams, optional
    cache : str or Path, optional
        Folder of the simulated windows, re-used across runs (default ``<out>-cache``).
    overwrite : bool
    progress : bool
    views : int
        N: each Table 1 window's map is also fused with N - 1 neighbouring views' maps
        (:func:`fusion.globalmap.neighbours.fused_reference_map`), its windows simulated over
        the span they need, and the report gets the fused table beside the one-view one
        (default 1: neither; the report as without it).

    Returns
    -------
    dict
        The content of ``report.json``.
    """
    params = params or ReproduceParams()
    views = FusedViews(views).views               # checked before any work
    out = Path(out)
    cache = Path(cache) if cache is not None else out.with_name(out.name + "-cache")
    check_output_dir(out, overwrite, [cache])        # the cache is read: out stays clear of it
    jobs = _jobs(params)
    if not jobs:
        raise ValueError("nothing to reproduce: no scene of the chosen tables was selected")
    cache.mkdir(parents=True, exist_ok=True)         # only once everything is validated
    clock = time.perf_counter()
    rows = []
    with atomic_output_dir(out, overwrite=overwrite, inputs=[cache],
                           command="evfuse reproduce") as tmp:
        bar = progress_stage(jobs, desc="reproduce", unit="window", noun="windows",
                             enabled=progress)
        for job in bar:
            bar.set_postfix_str(f"{job['scene']} [{job['t0']:.2f} s]")
            tick = time.perf_counter()
            failed = {"scene": job["scene"], "table": job["table"],
                      "window_s": [job["t0"], job["t0"] + job["length"]]}
            if "frozen_of" in job:               # frozen at the moving row's reference time
                moving = [r for r in rows if r["scene"] == job["frozen_of"]
                          and r["window_s"] == failed["window_s"] and "t_ref" in r]
                if not moving:
                    rows.append({**failed, "failed": f"no reference time to freeze "
                                 f"{job['frozen_of']}'s objects at: its own row failed"})
                    continue
                job = {**job, "frozen_at": moving[0]["t_ref"]}
            folder = _simulated(job, params, cache, views)
            simulated = time.perf_counter() - tick
            try:
                row = _row(job, folder, tmp / "runs", params, views)
            except ValueError as exc:            # e.g. a map with too little parallax
                row = {**failed, "failed": str(exc)}
            row["frame_sensor"] = _frame_sensor_of(folder)
            row["seconds"] = {"simulate (0 when cached)": simulated,
                              "map_fill": time.perf_counter() - tick - simulated}
            rows.append(row)
        (tmp / "figures").mkdir()
        figures = _copy_figures(rows, tmp)
        report = {"settings": {**dataclasses.asdict(params), "cache": str(cache),
                               **({"views": views} if views > 1 else {})},
                  "paper": PAPER, "rows": rows, "figures": figures,
                  "total_s": time.perf_counter() - clock}
        (tmp / "report.json").write_text(to_json(report))
        (tmp / "report.md").write_text(_markdown(report, params))
    return report


def _copy_figures(rows: list[dict], tmp: Path) -> dict:
    """One Figure 2 per scene (its first window, inverse distance weights) into figures/."""
    figures, seen = {}, set()
    for row in rows:
        if row["scene"] in seen or "failed" in row:
            continue
        seen.add(row["scene"])
        source = tmp / "runs" / f"{row['scene']}_{row['window_s'][0]:.2f}" / "fill_idw"
        target = tmp / "figures" / f"{row['scene']}.png"
        shutil.copyfile(source / "figure.png", target)
        figures[row["scene"]] = f"figures/{row['scene']}.png"
    return figures


def _f(value, digits: int = 2) -> str:
    return "-" if value is None or (isinstance(value, float) and not np.isfinite(value)) \
        else f"{value:.{digits}f}"


def _mae(errors: dict | None, kind: str, where: str = "overall") -> float | None:
    return None if errors is None else errors[kind][where]["mae_cm"]


def _share(errors: dict | None, kind: str, key: str, where: str = "overall") -> float | None:
    """A coverage figure (``completeness``, ``precision_5pct``) of one error block, or None."""
    return None if errors is None else errors[kind][where][key]


def _coverage(errors: dict | None, kind: str, where: str = "overall") -> str:
    """``completeness % / precision within 5 % %`` of one error block, for a table cell."""
    c, p = (_share(errors, kind, k, where) for k in ("completeness", "precision_5pct"))
    return f"{_f(None if c is None else 100 * c, 1)} / {_f(None if p is None else 100 * p, 1)}"


def _fused_section(table1: list[dict], views: int) -> list[str]:
    """Table 1 with each map fused with its neighbours' (``reproduce --views N``), beside the
    one-view numbers; none without ``--views``."""
    rows = [r for r in table1 if "fused" in r]
    if not rows:
        return []
    lines = [f"## Table 1, fused: each map with {views - 1} neighbouring views' ({views} views)",
             "",
             "| scene | window (s) | N1 one view / fused | N1 in frame | N2 | beta | map "
             "precision 5 % one view / fused (%) | MAE map one view / fused (cm) | MAE all "
             "one view / fused (cm) | all: completeness / precision 5 % (%), fused |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f, one = r["fused"], r["fills"]["idw"]
        p1, pf = (None if e is None else 100 * e["precision_5pct"]
                  for e in (r["map_errors"], f["map_errors"]))
        m1, mf = (None if e is None else e["mae_cm"] for e in (r["map_errors"], f["map_errors"]))
        lines.append(
            f"| {r['scene']} | {r['window_s'][0]:.2f}-{r['window_s'][1]:.2f} | "
            f"{f['N1_reference']} / {f['N1']} | {f['N1_in_frame']} | {f['N2']} | "
            f"{f['beta']:.4f} | {_f(p1, 1)} / {_f(pf, 1)} | {_f(m1)} / {_f(mf)} | "
            f"{_f(_mae(one['errors'], 'all'))} / {_f(_mae(f['errors'], 'all'))} | "
            f"{_coverage(f['errors'], 'all')} |")
    first = rows[0]["fused"]
    check = first["fusion"]
    share = first["spacing_s"] / (rows[0]["window_s"][1] - rows[0]["window_s"][0])
    again = ("; the reference view is mapped again so" if "views/00/" in first["folders"]["views"]
             else "")
    radius = check["search_radius"]
    lines += ["", f"Made by `evfuse reproduce --views {views}`: each window's one-view map "
              f"(the row above) is joined by the maps of {views - 1} neighbouring views, "
              f"reference times t_ref +- k {first['spacing_s']:g} s ({share:.3g} of the "
              "window), the nearest first, each mapping the window shifted by its offset with "
              "the same DSI and extraction (only the noisy poses) but the adaptive threshold's "
              f"c at {first['c']:g} (candidates{again}), and the "
              f"candidates that at least {check['min_views']} other views confirm within "
              f"{100 * check['depth_tolerance']:g} % (a search radius of {radius} "
              f"pixel{'s' if radius != 1 else ''}) are re-projected into the reference view "
              "(fusion.globalmap.neighbours); the fused map is filled with inverse distance "
              "weights and scored against the same exact depth. With --views, each Table 1 "
              "window is simulated over the span its neighbours need, so its one-view numbers "
              "here come from that longer simulation (the frozen control is not fused: "
              "simulated over its window only). Map precision and MAE: the event map at "
              "the reference view.", ""]
    return lines


def _simulated_over(views: int) -> str:
    """What each window of the report is simulated over (Table 1's longer with ``--views``)."""
    if views <= 1:
        return "Every window is simulated over itself only"
    return ("Every window is simulated over itself only but Table 1's fused ones (--views "
            f"{views}), simulated over the span their neighbours need (see Table 1, fused)")


def _markdown(report: dict, params: ReproduceParams) -> str:
    failed = [r for r in report["rows"] if "failed" in r]
    rows = [r for r in report["rows"] if "failed" not in r]
    protocol = ("the paper's protocol" if (params.window, params.long_window,
                                               params.table1_start) == (1.0, 2.0, None)
                else "shorter than the paper's 1-s slider and 2-s 6-DoF windows")
    lines = ["# evfuse reproduce: the paper's experiments on the twin scenes", "",
             f"Windows of {params.window:g} s on the sliders and {params.long_window:g} s on "
             f"the 6-DoF and complex scenes ({protocol}; Table 1 windows start where "
             f"{'the paper' if params.table1_start is None else 'asked'} says); event camera "
             f"renders at {params.event_spp} sample(s) per pixel with sampling bound lam = "
             f"{params.lam:g} (evfuse simulate's defaults: 4 and 0.5), sampled per pixel on "
             "the static scenes; dynamic_6dof, whose objects move, by whole frames at "
             f"{params.moving_event_spp} sample(s) per pixel and lam = {params.moving_lam:g} "
             "(whole frames at the fastest pixel's rate at full quality would take about 20 "
             "minutes for its window alone). "
             f"{_simulated_over(report['settings'].get('views', 1))}, mapped at the frame "
             "nearest its middle (DSI of 100 planes over the working range each scene file "
             "declares, listed below: never the exact depth; adaptive threshold 15 / 7 on the "
             "sliders as the paper, 5 / 5 elsewhere), filled "
             "with the paper's defaults and scored against the exact depth of that frame. "
             f"Total {report['total_s'] / 60:.1f} min.", ""]
    table1 = [r for r in rows if r["table"] == "1"]
    if table1:
        lines += ["## Table 1: filling on the 6-DoF scenes", "",
                  "| scene | window (s) | N1 | N1 in frame | N2 | N2 / N1 in frame | beta | "
                  "paper N1 | paper N2 | paper beta | MAE map (cm) | MAE filled (cm) | "
                  "MAE all (cm) | all: completeness / precision 5 % (%) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in table1:
            f = r["fills"]["idw"]
            p = PAPER["table1"].get(r["scene"], {})
            e = f["errors"]
            lines.append(
                f"| {r['scene']} | {r['window_s'][0]:.2f}-{r['window_s'][1]:.2f} | {f['N1']} | "
                f"{f['N1_in_frame']} | {f['N2']} | {_f(f['N2_over_N1_in_frame'])} | "
                f"{f['beta']:.4f} | {p.get('N1', '-')} | "
                f"{p.get('N2', '-')} | {p.get('beta', '-')} | {_f(_mae(e, 'map'))} | "
                f"{_f(_mae(e, 'filled'))} | {_f(_mae(e, 'all'))} | {_coverage(e, 'all')} |")
        windows = ("the same windows" if params.table1_start is None
                   and params.long_window == 2.0 else "other windows")
        sensors = ", ".join(sorted({r.get("frame_sensor", "ideal") for r in table1}))
        lines += ["", "The paper's N1 and N2 are from a real DAVIS240C on its own windows; ours "
                  f"come from simulated twins (frame sensor: {sensors}; event noise: "
                  f"{params.event_noise}) on {windows}, so the "
                  "counts are "
                  "comparable in size, not equal. N1 counts the map's points, N1 in frame those "
                  "that land in the frame after projection; beta = (N2 - N1 in frame) / "
                  "(Res + N1 in frame / Res), "
                  "Res = 43,200.", ""]
        frozen = [r for r in table1 if "frozen_of" in r]
        if frozen:
            lines += [", ".join(f"{r['scene']}" for r in frozen) + ": a control, the same "
                      "scene with its moving objects frozen where they are at the moving row's "
                      "reference time (" + ", ".join(f"{r['frozen_at']:.3f} s" for r in frozen)
                      + "), simulated as the moving row (whole frames, "
                      f"{params.moving_event_spp} sample(s) per pixel, lam = "
                      f"{params.moving_lam:g}) over the same window.", ""]
        lines += _fused_section(table1, report["settings"].get("views", 1))
        lines += _motion_section(table1)
    table2 = [r for r in rows if r["table"] == "2"]
    if table2:
        lines += ["## Table 2: absolute depth error on the sliders (cm)", "",
                  "MAE of the dense map (map points and filled pixels, inverse distance "
                  "weights) per window; in brackets the semi-dense event map alone. The "
                  "paper's values (real recordings, its own 1-s windows) follow each row. "
                  "Coverage: the dense map's completeness and precision within 5 %, means over "
                  "the windows.", ""]
        scenes = list(dict.fromkeys(r["scene"] for r in table2))
        n = max(r.get("k", 0) for r in table2) + 1
        lines += ["| sequence | " + " | ".join(f"w{k + 1}" for k in range(n))
                  + " | mean | completeness / precision 5 % (%) |",
                  "|---|" + "---|" * (n + 2)]
        for s in scenes:
            cells, values = [], []
            for r in sorted((r for r in table2 if r["scene"] == s), key=lambda r: r["k"]):
                e = r["fills"]["idw"]["errors"]
                all_, map_ = _mae(e, "all"), _mae(e, "map")
                values.append(all_)
                cells.append(f"{_f(all_)} ({_f(map_)})")
            mean = _nanmean(values)
            errs = [r["fills"]["idw"]["errors"] for r in table2 if r["scene"] == s]
            c = _nanmean([_share(e, "all", "completeness") for e in errs])
            p = _nanmean([_share(e, "all", "precision_5pct") for e in errs])
            cover = (f"{_f(None if c is None else 100 * c, 1)} / "
                     f"{_f(None if p is None else 100 * p, 1)}")
            lines.append(f"| {s} | " + " | ".join(cells) + f" | {_f(mean)} | {cover} |")
            paper = PAPER["table2_cm"].get(s)
            if paper:
                shown = list(paper[:n]) + [None] * max(0, n - len(paper))
                lines.append(f"| {s} (paper) | " + " | ".join(_f(v) for v in shown)
                             + f" | {_f(float(np.mean(paper)))} | - |")
        lines.append("")
        if "3" in params.tables:
            lines += ["## Table 3: the three weightings on the sliders", "",
                      "Mean over the windows of each slider: MAE of the filled pixels and of "
                      "the whole dense map (cm), the filled pixels' completeness and precision "
                      "within 5 %, and beta; the paper's mean error beside.", "",
                      "| sequence | weighting | MAE filled (cm) | MAE all (cm) | "
                      "filled: completeness / precision 5 % (%) | beta | paper (cm) |",
                      "|---|---|---|---|---|---|---|"]
            for s in scenes:
                for w in WEIGHTINGS:
                    sel = [r["fills"][w] for r in table2 if r["scene"] == s and w in r["fills"]]
                    if not sel:
                        continue
                    filled = _nanmean([_mae(f["errors"], "filled") for f in sel])
                    all_ = _nanmean([_mae(f["errors"], "all") for f in sel])
                    beta = _nanmean([f["beta"] for f in sel])
                    c = _nanmean([_share(f["errors"], "filled", "completeness") for f in sel])
                    p = _nanmean([_share(f["errors"], "filled", "precision_5pct") for f in sel])
                    cover = (f"{_f(None if c is None else 100 * c, 1)} / "
                             f"{_f(None if p is None else 100 * p, 1)}")
                    paper = PAPER["table3_cm"][w].get(s)
                    lines.append(f"| {s} | {w} | {_f(filled)} | {_f(all_)} | {cover} | "
                                 f"{beta:.4f} | {_f(paper)} |")
            lines.append("")
    complex_rows = [r for r in rows if r["table"] == "complex"]
    if complex_rows:
        lines += ["## Complex surfaces: how far from real is the filling?", "",
                  "The paper notes that its filling is \"not real if the surface is complex\". "
                  "MAE (cm) of the filled pixels inside regions and within 3 px of a true "
                  "depth discontinuity, and the share of filled pixels within 5 % of the true "
                  "depth (delta < 1.05), with the filled pixels' completeness and precision "
                  "within 5 % (points where there is no surface count against it).", "",
                  "| scene | weighting | beta | MAE filled, interior | MAE filled, band | "
                  "filled within 5 % | filled: completeness / precision 5 % (%) | MAE map |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in complex_rows:
            for w, f in r["fills"].items():
                e = f["errors"]
                within = None if e is None else e["filled"]["overall"]["delta_1.05"]
                lines.append(
                    f"| {r['scene']} | {w} | {f['beta']:.4f} | "
                    f"{_f(_mae(e, 'filled', 'interior'))} | {_f(_mae(e, 'filled', 'band'))} | "
                    f"{_f(None if within is None else 100 * within, 1)} % | "
                    f"{_coverage(e, 'filled')} | {_f(_mae(e, 'map'))} |")
        lines.append("")
    with_methods = [r for r in rows if r.get("methods")]
    if with_methods:
        lines += ["## Other filling methods", "",
                  "Each window filled by the paper's method (inverse distance) and by the "
                  "methods asked for (`--method`), from the same event map; MAE of the whole "
                  "dense map (cm), its completeness and precision within 5 % (%), and N2.", "",
                  "| scene | window (s) | method | MAE (cm) | completeness / precision 5 % (%) "
                  "| N2 |", "|---|---|---|---|---|---|"]
        for r in with_methods:
            w = f"{r['window_s'][0]:.2f}-{r['window_s'][1]:.2f}"
            idw = r["fills"].get("idw")
            entries = ([("paper-idw", idw["errors"], idw["N2"])] if idw else []) + [
                (spec, m["errors"], m["N2"]) for spec, m in r["methods"].items()]
            lines += [f"| {r['scene']} | {w} | {spec} | {_f(_mae(e, 'all'))} | "
                      f"{_coverage(e, 'all')} | {n2} |" for spec, e, n2 in entries]
        lines.append("")
    lines += _boundary_section(rows)
    ranges = {r["scene"]: r for r in rows}
    if ranges:
        lines += ["## DSI depth ranges", "", "| scene | range (m) | from |", "|---|---|---|"]
        lines += [f"| {scene} | {r['depth_range_m'][0]:g}-{r['depth_range_m'][1]:g} | "
                  f"{r['depth_range_from']} |" for scene, r in ranges.items()]
        lines.append("")
    if failed:
        lines += ["## Windows that could not be mapped", ""]
        lines += [f"- {r['scene']} [{r['window_s'][0]:.2f}, {r['window_s'][1]:.2f}] s: "
                  f"{r['failed']}" for r in failed]
        lines.append("")
    lines += ["## Figures (the paper's Figure 2, one window per scene)", ""]
    for scene, path in report["figures"].items():
        lines += [f"### {scene}", "", f"![{scene}]({path})", ""]
    return "\n".join(lines)


MOTION_ROWS = (("moving", "on moving objects"),
               ("crossed", "static, crossed by a moving object during the window"),
               ("static", "static, the rest"))


def _motion_section(rows: list[dict]) -> list[str]:
    """The errors of each row whose scene has moving objects, split by region
    (:func:`fusion.scoring.errors_by_motion`), with its frozen control beside."""
    moving = [r for r in rows if r.get("map_errors_by_motion")]
    if not moving:
        return []
    lines = ["### Scenes with moving objects: where the error is", "",
             "The event map (at the reference view) and the dense map (inverse distance, in "
             "the frame) split into the points on moving objects, the static points in front "
             "of which a moving object passed during the window (seen from the reference view, "
             "the objects sampled every 10 ms), and the rest: each region's points, share of "
             "the absolute error, MAE and median (cm), and share within 5 % of the exact depth. "
             "The frozen control's errors follow, unsplit.", "",
             "| scene | depth | region | points scored | share of error (%) | MAE (cm) | "
             "median (cm) | within 5 % (%) |", "|---|---|---|---|---|---|---|---|"]

    def cells(e: dict | None, share: float | None) -> str:
        if e is None:
            return "- | - | - | - | -"
        within = None if not e["n"] else 100 * e["delta_1.05"]
        return (f"{e['n']} | {_f(None if share is None else 100 * share, 1)} | "
                f"{_f(e['mae_cm'])} | {_f(e['median_cm'])} | {_f(within, 1)}")

    for r in moving:
        idw = r["fills"].get("idw", {})
        for depth, split, whole in (("event map", r["map_errors_by_motion"], r["map_errors"]),
                                    ("dense map", (idw.get("errors_by_motion") or {}).get("all"),
                                     ((idw.get("errors") or {}).get("all") or {}).get(
                                         "overall"))):
            if split is None:
                continue
            lines.append(f"| {r['scene']} | {depth} | all | {cells(whole, 1.0)} |")
            lines += [f"| {r['scene']} | {depth} | {name} | "
                      f"{cells(split[key], split[key]['error_share'])} |"
                      for key, name in MOTION_ROWS]
        for c in rows:
            if c.get("frozen_of") == r["scene"] and c["window_s"] == r["window_s"]:
                ce = c["fills"].get("idw", {}).get("errors")
                lines.append(f"| {c['scene']} | event map | all (frozen control) | "
                             f"{cells(c['map_errors'], 1.0)} |")
                if ce:
                    lines.append(f"| {c['scene']} | dense map | all (frozen control) | "
                                 f"{cells(ce['all']['overall'], 1.0)} |")
    return lines + [""]


def _boundary_section(rows: list[dict]) -> list[str]:
    """How many points of each window's map had their DSI maximum on the first or last plane
    (:class:`fusion.map.emvs.DepthMapParams` ``keep_boundary_planes``)."""
    counted = [r for r in rows if "boundary_plane_points" in r]
    if not counted:
        return []
    dropped = counted[0]["boundary_plane_points"]["dropped"]
    lines = ["## DSI boundary planes", "",
             "Points that passed the threshold with their DSI maximum on the first or the last "
             "depth plane: such a maximum says the depth lies outside the range, not at its "
             "edge. " + ("They were dropped from the maps (the default; "
                         "`--keep-boundary-planes` keeps them, as rpg_emvs does)."
                         if dropped else "They were kept, as rpg_emvs does "
                         "(`--keep-boundary-planes`)."), "",
             "| scene | window (s) | first plane | last plane | N1 |", "|---|---|---|---|---|"]
    for r in counted:
        b = r["boundary_plane_points"]
        n1 = r["fills"]["idw"]["N1"] if "idw" in r["fills"] else "-"
        lines.append(f"| {r['scene']} | {r['window_s'][0]:.2f}-{r['window_s'][1]:.2f} | "
                     f"{b['near']} | {b['far']} | {n1} |")
    return lines + [""]


def _nanmean(values) -> float | None:
    finite = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(finite)) if finite else None
