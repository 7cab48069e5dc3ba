"""``evfuse bench``: every filling method on every scene and input, scored and ranked.

For each scene, one window is simulated and mapped (cached in ``<out>-cache``, re-used by later
runs); the standard frame nearest the window's middle is filled from four inputs, all for the
same view and scored against the same exact depth:

- ``emvs``: the event map projected into the frame, as ``evfuse fill`` uses it;
- ``oracle``: the exact depth at the event map's own pixels (the map's pattern, perfect values);
- ``oracle-edges``: the exact depth at every pixel that fired an event in the window;
- ``oracle-noisy``: ``oracle`` with relative Gaussian noise (``noise``, default 2 %) and a share
  of outliers (``outliers``, default 5 %, uniform over the DSI range), seeded;
- ``oracle-canny``: the exact depth on the frame's own Canny edges (:data:`CANNY_THRESHOLDS`),
  the protocol of a photograph with measured depth and a sparse map on its edges.

``oracle`` minus ``emvs`` is what the map's errors cost each method. Every method runs through
:func:`fusion.methods.run_method`: a method that raises or returns a wrong shape, NaN or a
negative depth gets a row saying why, the others go on. Methods run in two worker processes.
A method may run under settings of its own (a :class:`fusion.methods.MethodVariant`, given as
``plane{residual_rel=0.03}``), the same method under several: each is a row, labelled so.

Scores (:func:`fusion.scoring.dense_errors`, the definitions of ``evfuse fill``): MAE, RMSE,
AbsRel, delta < 1.05, completeness and precision within 5 % of the dense map (``all``), its
filled pixels (``filled``: pixels that were not input points) and the band within 3 px of a true
depth discontinuity apart. Methods fill different shares of the image, so each table shows the
completeness beside the errors and ranks the methods twice: by MAE on their own pixels, and by
MAE on the pixels that every method filled (``common``). For a method that returns a confidence,
``coverage_curve`` gives the MAE of its filled pixels against the share kept, most confident
first (:func:`coverage_curve`), and ``mae_at_half_cm`` its value at one half.

Outputs in ``--out``: ``bench.md`` (a ranked table per input, the best value of each column in
bold), ``bench.csv`` (fixed columns, see :data:`CSV_COLUMNS`), ``bench.json`` and one figure
per scene, ``figures/<scene>_<input>.png``: every method's dense depth and error side by side.
"""

from __future__ import annotations

import csv
import io
import json
import shlex
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import cv2
import numpy as np

from sim.output import (
    atomic_output_dir,
    check_cache_dir,
    check_output_dir,
    close_cache_dir,
    open_cache_dir,
)
from sim.validation import ParameterError, integer

__all__ = ["CSV_COLUMNS", "CURVE_SHARES", "INPUTS", "SCENE_GROUPS", "BenchParams", "bench",
           "bench_cache", "bench_command", "bench_sources", "coverage_curve", "run_bench"]

INPUTS = ("emvs", "oracle", "oracle-edges", "oracle-noisy", "oracle-canny")
CANNY_THRESHOLDS = (50, 150)
"""Hysteresis thresholds of ``oracle-canny``'s edges (OpenCV's Canny on the 8-bit frame, 3x3
Sobel, L1 gradient)."""
"""The inputs a method can be given (see the module docstring)."""
SCENE_GROUPS = {
    "complex": ("complex_sphere", "complex_cylinder", "complex_slanted_plane",
                "complex_staircase", "complex_heightfield"),
    "sliders": ("slider_close", "slider_far", "slider_hdr_close", "slider_hdr_far"),
}
"""Names ``--scenes`` accepts for several scenes."""
WINDOWS = {"complex": (1.0, 2.0), "sliders": (2.0, 3.0)}
"""Default window (s) of each group's scenes; other scenes use ``(1.0, 2.0)``."""
CSV_COLUMNS = ("scene", "input", "method", "status", "mae_cm", "rmse_cm", "abs_rel",
               "completeness", "precision_5pct", "filled_mae_cm", "filled_completeness",
               "band_mae_cm", "common_mae_cm", "common_pixels", "mae_at_half_cm", "time_ms",
               "params")
"""Columns of ``bench.csv``: ``method`` the method's label (``plane`` or, run with settings of
its own, ``plane{residual_rel=0.03}``), ``params`` those settings as compact JSON (``{}`` for
its defaults); errors over the method's own pixels (the whole dense map),
completeness and precision as :func:`fusion.scoring.depth_errors` defines them, ``filled_*`` for
its filled pixels only, ``band_mae_cm`` within 3 px of a true discontinuity, ``common_*`` on the
pixels every method filled, ``time_ms`` the method's own time (after a first, untimed call
in its worker). Empty where not defined."""


@dataclass(frozen=True)
class BenchParams:
    """Settings of :func:`bench`.

    Attributes
    ----------
    noise : float
        Relative standard deviation of ``oracle-noisy``'s depths (default 0.02).
    outliers : float
        Share of ``oracle-noisy``'s points replaced by a depth uniform over the DSI range
        (default 0.05).
    seed : int
        Seed of ``oracle-noisy``.
    workers : int
        Worker processes for the methods (default 2: the development machine's cores).
    keep_boundary_planes : bool
        The event maps keep their points on the DSI's first and last planes
        (:class:`fusion.map.emvs.DepthMapParams`; default False, dropped).
    """

    noise: float = 0.02
    outliers: float = 0.05
    seed: int = 0
    workers: int = 2
    keep_boundary_planes: bool = False

    def __post_init__(self) -> None:
        if not (0 <= self.noise < 1 and 0 <= self.outliers <= 1):
            raise ValueError(f"noise must be in [0, 1) and outliers in [0, 1], got {self.noise} "
                             f"and {self.outliers}")
        if not (isinstance(self.workers, int) and self.workers >= 1):
            raise ValueError(f"workers must be an integer >= 1, got {self.workers!r}")
        integer("seed", self.seed, 0)


def _scene_names(scenes: list[str]) -> list[str]:
    """Built-in scene names (groups expanded) and map folders (paths holding ``map.json``)."""
    from scenes import describe_scenes

    known = describe_scenes()
    names: list[str] = []
    for item in scenes:
        if (Path(item) / "map.json").is_file() or (str(item).endswith(".toml")
                                                   and Path(item).is_file()):
            names.append(str(item))
            continue
        for name in SCENE_GROUPS.get(item, (item,)):
            if name not in known:
                raise ParameterError(f"{{scenes}} {ParameterError.literal(item)}: unknown scene "
                                     f"{ParameterError.literal(repr(name))}; expected built-in "
                                     f"scene names, {', '.join(SCENE_GROUPS)}, or a map folder "
                                     "of a simulated sequence", scenes="scenes")
            if name not in names:
                names.append(name)
    return names


def _label(name: str) -> str:
    """A scene's name in the tables (a map folder: its run folder's name)."""
    path = Path(name)
    if (path / "map.json").is_file():
        return path.resolve().parent.name if path.name == "map" else path.name
    if name.endswith(".toml"):
        return path.stem
    return name


def _window(name: str) -> tuple[float, float]:
    for group, members in SCENE_GROUPS.items():
        if name in members:
            return WINDOWS[group]
    return (1.0, 2.0)


def _mapped(name: str, cache: Path, progress: bool, keep_boundary_planes: bool = False) -> Path:
    """The cached map folder of a scene's window (simulated and mapped when missing, mapped
    again when its ``map.json`` was made with another ``keep_boundary_planes``; a map from
    before that setting existed kept those points)."""
    from fusion.map.emvs import DepthMapParams
    from fusion.pipeline import map_window
    from scenes import resolve_scene
    from sim.scene import load_scene
    from sim.simulate.window import cached_window

    if (Path(name) / "map.json").is_file():
        return Path(name)
    t0, t1 = _window(name)
    scene = load_scene(Path(name if name.endswith(".toml") else resolve_scene(name)))
    # The window's folder is named by its key (the scene's files and every simulation
    # parameter): an edited scene (a new frame sensor, a moved object) is simulated again
    # instead of read stale. Its map is kept beside the sequence.
    sequence = cached_window(scene, cache, _label(name), t0, t1 - t0, progress=progress)
    folder = sequence.parent / f"{sequence.name}_map"
    if (folder / "map.json").is_file():
        made = json.loads((folder / "map.json").read_text(encoding="utf-8"))
        if made["params"]["depth"].get("keep_boundary_planes", True) == keep_boundary_planes:
            return folder
    map_window(sequence, folder, t0, t1, overwrite=True, progress=progress,
               depth=DepthMapParams(keep_boundary_planes=keep_boundary_planes))
    return folder


def _inputs(map_folder: Path, params: BenchParams) -> tuple[object, dict[str, np.ndarray]]:
    """The frame's fill inputs (:class:`fusion.fill.dense.FillInputs`: frame, camera, truth) and
    each input's sparse depth."""
    from fusion.fill.dense import fill_inputs
    from sim.eventio import read_window

    base = fill_inputs(map_folder)
    if base.info.get("rig") is not None:
        raise ValueError(f"{map_folder}: evfuse bench does not take a two-camera rig (its "
                         "oracle-edges input marks the event camera's pixels in the frame); "
                         "use evfuse run or evfuse fill --method on a rig")
    if base.truth is None:
        raise ValueError(f"{map_folder}: no exact depth for the frame; the bench needs a "
                         "simulated sequence")
    truth = base.truth
    info = json.loads((map_folder / "map.json").read_text())
    sequence = (map_folder / info["sequence"]).resolve()
    t0, t1 = info["window_s"]
    events_file = next(p for p in (sequence / "events.h5", sequence / "events.txt")
                       if p.is_file())
    events = read_window(events_file, int(round(t0 * 1e9)), int(round(t1 * 1e9)))
    fired = np.zeros(truth.shape, bool)
    fired[events["y"].astype(int), events["x"].astype(int)] = True
    rng = np.random.default_rng(params.seed)
    oracle = np.where(base.sparse > 0, truth, 0).astype(np.float32)
    noisy = oracle * (1 + params.noise * rng.standard_normal(oracle.shape)).astype(np.float32)
    lo, hi = info["depth_range_m"]
    wild = (rng.random(oracle.shape) < params.outliers) & (oracle > 0)
    noisy[wild] = rng.uniform(lo, hi, int(wild.sum()))
    noisy = np.where(oracle > 0, np.maximum(noisy, 1e-3), 0).astype(np.float32)
    inputs = {"emvs": base.sparse.astype(np.float32), "oracle": oracle,
              "oracle-edges": np.where(fired, truth, 0).astype(np.float32),
              "oracle-noisy": noisy,
              "oracle-canny": np.where(cv2.Canny(base.frame, *CANNY_THRESHOLDS) > 0, truth,
                                       0).astype(np.float32)}
    return base, inputs


_WARM: set[str] = set()
"""Methods already run once in this worker process (their compilation is not timed)."""


def _run_one(variant, frame: np.ndarray, sparse: np.ndarray, camera) -> dict:
    """Run one method (a :class:`fusion.methods.MethodVariant`) in a worker: its output, or why
    it failed. A variant's first call in a worker is run twice and the second timed (JIT
    compilation and caches are not its speed)."""
    from fusion.methods import MethodError, run_method

    try:
        if variant.label not in _WARM:
            run_method(variant.spec, frame, sparse, camera, variant.params)
            _WARM.add(variant.label)
        dense, confidence, seconds = run_method(variant.spec, frame, sparse, camera,
                                                variant.params)
    except MethodError as exc:
        return {"status": f"failed: {exc}"}
    return {"status": "ok", "dense": dense, "confidence": confidence, "seconds": seconds}


def _value(errors: dict | None, key: str):
    if errors is None or errors.get("n", 0) == 0:
        return None
    return errors.get(key)


def _scores(dense: np.ndarray, sparse: np.ndarray, truth: np.ndarray,
            confidence: np.ndarray | None) -> dict:
    from fusion.scoring import dense_errors

    errors = dense_errors(dense, sparse, truth)
    whole, filled, band = errors["all"]["overall"], errors["filled"]["overall"], \
        errors["all"]["band"]
    row = {"mae_cm": _value(whole, "mae_cm"), "rmse_cm": _value(whole, "rmse_cm"),
           "abs_rel": _value(whole, "abs_rel"), "completeness": whole["completeness"],
           "precision_5pct": _value(whole, "precision_5pct"),
           "filled_mae_cm": _value(filled, "mae_cm"),
           "filled_completeness": filled["completeness"],
           "band_mae_cm": _value(band, "mae_cm"), "mae_at_half_cm": None}
    if confidence is not None:
        row["coverage_curve"] = coverage_curve(dense, sparse, truth, confidence)
        row["mae_at_half_cm"] = dict(row["coverage_curve"]).get(0.5)
    return row


CURVE_SHARES = (0.1, 0.25, 0.5, 0.75, 1.0)
"""Shares of a method's filled pixels, most confident first, at which the curve is taken."""


def coverage_curve(dense: np.ndarray, sparse: np.ndarray, truth: np.ndarray,
                   confidence: np.ndarray, shares: tuple[float, ...] = CURVE_SHARES
                   ) -> list[tuple[float, float | None]]:
    """Error of the filled pixels against the share of them kept, most confident first.

    Parameters
    ----------
    dense, sparse, truth : (H, W) float arrays, metres (0 = none)
    confidence : (H, W) float array in [0, 1]
    shares : tuple of float
        Shares of the filled pixels (with a true depth) to keep.

    Returns
    -------
    list of (share, MAE in cm or None)
        For each share, the MAE of the most confident ``share`` of the filled pixels; ties in
        confidence are broken in row-major pixel order, so each share is exact.
    """
    index = np.flatnonzero(((dense > 0) & (sparse == 0) & (truth > 0)).ravel())
    if index.size == 0:
        return [(share, None) for share in shares]
    order = index[np.argsort(-confidence.ravel()[index], kind="stable")]
    error = np.abs(dense.ravel()[order] - truth.ravel()[order]) * 100.0
    running = np.cumsum(error) / np.arange(1, len(error) + 1)
    return [(share, float(running[max(int(round(share * len(error))), 1) - 1]))
            for share in shares]


def bench(methods: list, scenes: list[str], inputs: list[str] = INPUTS,
          cache: str | Path = "evfuse-bench-cache", params: BenchParams | None = None,
          progress: bool = True) -> list[dict]:
    """Score every method on every scene and input.

    Parameters
    ----------
    methods : list of str or MethodVariant
        Method names or ``module:function`` specs (:func:`fusion.methods.get_method`), or
        labels with settings (``plane{residual_rel=0.03}``), or
        :class:`fusion.methods.MethodVariant`; the settings are checked before any work.
    scenes : list of str
        Built-in scene names, groups (:data:`SCENE_GROUPS`), scene files (``.toml``, e.g. from
        :mod:`sim.scene.families`) or map folders of simulated sequences (``evfuse map`` /
        ``evfuse run`` outputs).
    inputs : list of str
        Among :data:`INPUTS` (default all).
    cache : str or Path
        Folder of the simulated and mapped windows (created, re-used; default
        ``evfuse-bench-cache`` in the working directory).
    params : BenchParams, optional
    progress : bool

    Returns
    -------
    list of dict
        One row per (scene, input, method) with the :data:`CSV_COLUMNS` (``params`` as a
        dict) and, under ``"_dense"``, the dense depth (for the figures).
    """
    from fusion.methods import MethodVariant

    params = params or BenchParams()
    unknown = [name for name in inputs if name not in INPUTS]
    if unknown or not inputs:
        raise ParameterError(f"{{inputs}} {ParameterError.literal(','.join(inputs))}: expected "
                             f"among {', '.join(INPUTS)}", inputs="inputs")
    # Unknown names and bad settings refused up front; one row per label.
    variants = list({v.label: v for v in (MethodVariant.of(m).checked() for m in methods)}
                    .values())
    names = _scene_names(scenes)
    cache = Path(cache)
    check_cache_dir(cache, bench_sources(scenes, cache)[1:])
    created = open_cache_dir(cache, "evfuse bench (cache)")
    try:
        return _bench(variants, names, inputs, cache, params, progress)
    except BaseException:
        close_cache_dir(cache, created)
        raise


def _bench(variants: list, names: list[str], inputs: list[str], cache: Path,
           params: BenchParams, progress: bool) -> list[dict]:
    """:func:`bench` once its arguments are checked and its cache made."""
    from sim.progress import progress as progress_stage

    rows: list[dict] = []
    bar = progress_stage(total=len(names) * len(inputs) * len(variants), desc="bench",
                         unit="fill", noun="fills", enabled=progress)
    # Fresh worker processes (spawn): forking a process that holds Dr.Jit's threads can hang.
    with ProcessPoolExecutor(params.workers, mp_context=get_context("spawn")) as pool:
        for name in names:
            mapped = _mapped(name, cache, progress, params.keep_boundary_planes)
            base, sparse_inputs = _inputs(mapped, params)
            for input_name in inputs:
                sparse = sparse_inputs[input_name]
                futures = [(variant, pool.submit(_run_one, variant, base.frame, sparse,
                                                 base.camera)) for variant in variants]
                group = []
                for variant, future in futures:
                    result = future.result()
                    row = {"scene": _label(name), "input": input_name, "method": variant.label,
                           "status": result["status"], "params": variant.params}
                    if result["status"] == "ok":
                        row.update(_scores(result["dense"], sparse, base.truth,
                                           result["confidence"]))
                        row["time_ms"] = 1000 * result["seconds"]
                        row["_dense"] = result["dense"]
                    group.append(row)
                    bar.update(1)
                _common(group, sparse, base.truth)
                for row in group:
                    row["_truth"], row["_frame"] = base.truth, base.frame
                rows += group
    bar.close()
    return rows


def _common(group: list[dict], sparse: np.ndarray, truth: np.ndarray) -> None:
    """MAE of each method on the pixels that every method (that ran) filled."""
    from fusion.scoring import depth_errors

    ok = [row for row in group if row["status"] == "ok"]
    if not ok:
        return
    mask = truth > 0
    for row in ok:
        mask &= row["_dense"] > 0
    for row in ok:
        errors = depth_errors(np.where(mask, row["_dense"], 0), truth)
        row["common_mae_cm"] = _value(errors, "mae_cm")
        row["common_pixels"] = int(mask.sum())


def _number(value, digits: int = 2) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}f}"


def _markdown(rows: list[dict], seconds: float, command: str) -> str:
    lines = ["# evfuse bench: filling methods ranked", "",
             f"`{command}` ({seconds / 60:.1f} min). Errors against the exact depth, over each "
             "method's own pixels (`all`: input points and filled pixels) and over the pixels "
             "every method filled (`common`); completeness is the share of the pixels with a "
             "true depth that have one, precision the share of the points within 5 % of the "
             "exact surface; `band` within 3 px of a true depth discontinuity. Methods are "
             "ranked by MAE on their own pixels, then by MAE on the common pixels; the best "
             "value of each column is in bold.", ""]
    columns = [("mae_cm", "MAE (cm)", min, 2), ("rmse_cm", "RMSE (cm)", min, 2),
               ("abs_rel", "AbsRel", min, 4), ("completeness", "completeness", max, 3),
               ("precision_5pct", "precision 5 %", max, 3), ("band_mae_cm", "band MAE", min, 2),
               ("common_mae_cm", "common MAE", min, 2), ("mae_at_half_cm", "MAE, confident half",
                                                         min, 2),
               ("time_ms", "time (ms)", min, 1)]
    for input_name in dict.fromkeys(row["input"] for row in rows):
        lines += [f"## Input: {input_name}", ""]
        for scene in dict.fromkeys(row["scene"] for row in rows):
            group = [r for r in rows if r["input"] == input_name and r["scene"] == scene]
            ok = [r for r in group if r["status"] == "ok"]
            ranked = sorted(ok, key=lambda r: (r["mae_cm"] is None, r["mae_cm"] or 0.0))
            common = sorted(ok, key=lambda r: (r.get("common_mae_cm") is None,
                                               r.get("common_mae_cm") or 0.0))
            rank_common = {id(r): i + 1 for i, r in enumerate(common)}
            best = {}
            for key, _, pick, _ in columns:
                values = [r.get(key) for r in ok if r.get(key) is not None]
                best[key] = pick(values) if values else None
            pixels = ok[0].get("common_pixels") if ok else None
            lines += [f"### {scene} ({pixels if pixels is not None else 0} common pixels)", "",
                      "| rank | rank on common | method | " + " | ".join(c[1] for c in columns)
                      + " |", "|---|---|---|" + "---|" * len(columns)]
            for i, row in enumerate(ranked):
                cells = []
                for key, _, _, digits in columns:
                    text = _number(row.get(key), digits)
                    cells.append(f"**{text}**" if row.get(key) is not None
                                 and row.get(key) == best[key] else text)
                lines.append(f"| {i + 1} | {rank_common[id(row)]} | {row['method']} | "
                             + " | ".join(cells) + " |")
            for row in group:
                if row["status"] != "ok":
                    lines.append(f"| - | - | {row['method']} | {row['status']} |"
                                 + " |" * (len(columns) - 1))
            lines.append("")
            curves = [r for r in ok if r.get("coverage_curve")]
            if curves:
                shares = [share for share, _ in curves[0]["coverage_curve"]]
                lines += ["Precision against completeness: MAE (cm) of the filled pixels kept, "
                          "most confident first, at each share of them:", "",
                          "| method | " + " | ".join(f"{100 * x:g} %" for x in shares) + " |",
                          "|---|" + "---|" * len(shares)]
                lines += [f"| {r['method']} | " + " | ".join(_number(mae) for _, mae
                                                              in r["coverage_curve"]) + " |"
                          for r in curves]
                lines.append("")
    return "\n".join(lines)


def _csv(rows: list[dict]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_COLUMNS, extrasaction="ignore",
                            lineterminator="\n")
    writer.writeheader()
    for row in rows:
        cells = {key: ("" if row.get(key) is None else row.get(key)) for key in CSV_COLUMNS}
        cells["params"] = json.dumps(row.get("params") or {}, sort_keys=True,
                                     separators=(",", ":"), default=repr)
        writer.writerow(cells)
    return buffer.getvalue()


def _figure(rows: list[dict]) -> np.ndarray:
    """Every method's dense depth and its error, side by side, for one scene and input: one
    depth scale and ONE error scale for all methods (:func:`fusion.figures.error_panels`), so
    that a colour is the same error in every method's panel."""
    from fusion.figures import (
        depth_colours,
        depth_scale,
        error_panels,
        grid_scale,
        panel_grid,
        point_radius,
    )

    ok = [r for r in rows if r["status"] == "ok"]
    truth, frame = rows[0]["_truth"], rows[0]["_frame"]
    columns = min(1 + 2 * len(ok), 5)
    width = truth.shape[1]
    radius = point_radius(width, width * grid_scale(width, columns))   # sparse fills stay seen
    scale = depth_scale(*(r["_dense"] for r in ok), truth=truth)
    lo_hi = (scale.lo, scale.hi) if scale else (None, None)
    errors, error_legend = error_panels([r["_dense"] for r in ok], truth, radius)
    images, titles, legends = [depth_colours(truth, *lo_hi, base=frame)], ["exact depth"], \
        [scale.legend() if scale else None]
    for row, error in zip(ok, errors, strict=True):
        images.append(depth_colours(row["_dense"], *lo_hi, radius=radius))
        titles.append(f"{row['method']}: MAE {_number(row['mae_cm'])} cm")
        legends.append(scale.legend() if scale else None)
        images.append(error)
        titles.append(f"|error| {row['method']}")
        legends.append(error_legend)
    return panel_grid(images, titles, columns=columns, legends=legends)


def bench_cache(out: str | Path, cache: str | Path | None = None) -> Path:
    """The cache folder of a bench writing ``out``: ``cache``, by default ``<out>-cache``
    beside it.

    Parameters
    ----------
    out : str or Path
    cache : str or Path, optional

    Returns
    -------
    Path
    """
    out = Path(out)
    return Path(cache) if cache else out.with_name(out.name + "-cache")


def bench_command(out: str | Path, *, scenes: str | None, inputs: str, methods: list[str],
                  params: list[str], only: bool = False, keep_boundary_planes: bool = False,
                  noise: float = BenchParams.noise, outliers: float = BenchParams.outliers,
                  cache: str | Path | None = None, family: str | None = None,
                  knobs: dict[str, str] | None = None) -> str:
    """The ``evfuse bench`` command line of a bench, for ``bench.md``: every setting that
    changes what it benches, as given.

    Parameters
    ----------
    out : str or Path
        The output folder.
    scenes : str or None
        The scenes as given (comma-separated); left out for a family's bench.
    inputs : str
        The inputs as given (comma-separated).
    methods, params : list of str
        The method labels and the ``METHOD.KEY=VALUE`` settings, as given.
    only, keep_boundary_planes : bool
        The switches (written where set).
    noise, outliers : float
        :class:`BenchParams`' (written where off their defaults).
    cache : str or Path, optional
        The cache folder, where given.
    family : str, optional
        A family's bench (:mod:`sim.scene.families`): its name instead of the scenes.
    knobs : dict of str to str, optional
        Its knobs' values as given, by knob name.

    Returns
    -------
    str
        The command, shell-quoted.
    """
    words = ["evfuse", "bench"]
    if family:
        words += ["--family", family]
        for name, value in (knobs or {}).items():
            words += [f"--{name.replace('_', '-')}", value]
    else:
        words += ["--scenes", scenes]
    words += ["--input", inputs]
    for method in methods:
        words += ["--method", method]
    for param in params:
        words += ["--param", param]
    words += ["--only"] if only else []
    words += ["--keep-boundary-planes"] if keep_boundary_planes else []
    for flag, value, default in (("--noise", noise, BenchParams.noise),
                                 ("--outliers", outliers, BenchParams.outliers)):
        if value != default:
            words += [flag, f"{value:g}"]
    words += ["--cache", str(cache)] if cache else []
    return shlex.join([*words, "--out", str(out)])


def bench_sources(scenes: list[str], cache: str | Path) -> list[Path]:
    """What a bench reads (its output must not be, hold or lie in any): the cache, and the
    scene files and map folders among ``scenes`` with the sequence folders the maps name."""
    from fusion.pipeline import fill_sources

    sources = [Path(cache)]
    for item in scenes:
        path = Path(item)
        if (path / "map.json").is_file():
            sources += fill_sources(path)
        elif path.is_file():
            sources.append(path)
    return sources


def run_bench(methods: list, scenes: list[str], inputs: list[str], out: str | Path,
              cache: str | Path | None = None, params: BenchParams | None = None,
              overwrite: bool = False, progress: bool = True, command: str = "evfuse bench"
              ) -> list[dict]:
    """:func:`bench`, then ``bench.md``, ``bench.csv``, ``bench.json`` and ``figures/`` into
    ``out`` (written under ``<out>.partial`` and renamed when complete).

    Returns
    -------
    list of dict
        The rows (without the arrays).
    """
    from fusion.figures import write_image

    out = Path(out)
    cache = bench_cache(out, cache)
    read = bench_sources(scenes, cache)
    check_output_dir(out, overwrite, read)                  # before the cache is made
    start = time.perf_counter()
    rows = bench(methods, scenes, inputs, cache, params, progress)
    seconds = time.perf_counter() - start
    with atomic_output_dir(out, overwrite=overwrite, inputs=read,
                           command="evfuse bench") as tmp:
        (tmp / "bench.md").write_text(_markdown(rows, seconds, command))
        (tmp / "bench.csv").write_text(_csv(rows))
        (tmp / "figures").mkdir()
        for scene in dict.fromkeys(r["scene"] for r in rows):
            for input_name in dict.fromkeys(r["input"] for r in rows):
                group = [r for r in rows if r["scene"] == scene and r["input"] == input_name]
                if any(r["status"] == "ok" for r in group):
                    write_image(tmp / "figures" / f"{scene}_{input_name}.png", _figure(group))
        plain = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
        (tmp / "bench.json").write_text(json.dumps({"seconds": seconds, "rows": plain},
                                                   indent=1))
    return plain
