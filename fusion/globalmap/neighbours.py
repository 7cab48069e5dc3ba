"""A reference view's map fused with its neighbours' (issue 25, part 2c): ``--views N``.

The one-view map (``evfuse map``'s, at reference time ``t_ref`` over the window ``[t0, t1]``)
is joined by the maps of ``N - 1`` neighbouring views made the same way, and
:func:`fusion.globalmap.fuse.fuse_into_view` re-projects their consistency-checked points into
the reference view's pixels: a denser map in the same pixel grid, which the fill stage fills
unchanged.

The neighbours' rule (:func:`neighbour_times`): reference times ``t_ref - h, t_ref + h,
t_ref - 2 h, t_ref + 2 h, ...`` (``h`` the spacing, by default a quarter of the window's
length), the nearest first and the earlier first at equal distance; each maps the reference's
window shifted by the same offset (the same length, the same place of its reference view in
it), and a neighbour is taken only when that whole window lies in the data (the events' and
the poses' spans); one that does not is skipped and the next one taken. Every neighbour's map
has the reference's DSI (depth range, planes) and extraction parameters but the adaptive
threshold's ``c`` (below), and its pose is the noisy ``groundtruth.txt`` pose at its time, as
the reference's: the fusion is blind. The exact
depth is read only to score the fused map, by the map stage's own scoring
(:func:`fusion.scoring.depth_errors` against the reference view's exact depth).

Candidates, then the check. A one-view map has no other view to reject a wrong maximum of its
DSI, so EMVS keeps only the pixels whose ray density stands ``c`` above its neighbourhood's
(the adaptive threshold, ``c`` = 5 on the 6-DoF scenes). Fused, every view's map is extracted
with a lower ``c`` (:attr:`FusedViews.c`, default :data:`CANDIDATE_C` = 0: any local excess of
ray density): more candidates, more of them wrong, and the multi-view check (default
:data:`VIEWS_FUSION`: two other views within 2 % in depth) rejects what the threshold let
through, as multi-view stereo filters its per-view depth maps. The reference view is mapped
again at that ``c`` (``views/00``). Measured on boxes_6dof's paper window (3.5-5.5 s, one view
N1 1,050 at 81.9 % within 5 %, ``c`` = 5), 5 views: ``c`` = 5, one other view, half a window
apart (the rule before this one) gives 1.21x the points at 84.1 %; ``c`` = 0, two other views,
a quarter window apart 4.06x at 88.3 % (``benchmarks/bench_views.py``; README, "Fused
reference map", for the other scenes and settings).

With ``N = 1`` there is nothing to fuse: the fused map is the one-view map, bit for bit.

Files: ``OUT/views/NN/`` (``NN`` = 01 .. N-1: each neighbour's map folder, as ``evfuse map``
writes it; ``00``: the reference view mapped again at the candidates' ``c``, when it differs
from the one-view map's) and ``OUT/map/`` (the fused map, a map folder:
``semidense_depth.exr``, ``confidence.exr`` (the reference view's DSI votes at its own points,
0 at points from the neighbours), ``mask.png``, ``overlay.png``, ``map.ply``, ``map.json`` with
a ``fused`` block).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from fusion.globalmap.fuse import FusionParams, agreement_counts, fuse_into_view
from fusion.globalmap.views import DepthView
from fusion.map.emvs import DepthMapParams, DSIParams
from fusion.map.mapping import (
    MapParams,
    MapResult,
    _ground_truth_depth,
    time_window,
    write_map,
)
from fusion.pipeline import map_window
from fusion.scoring import depth_errors
from sim.camera import Camera
from sim.exr import read_depth, read_exr_channels
from sim.output import atomic_output_dir
from sim.sequence import EXACT_TIME_S, load_sequence
from sim.validation import ParameterError, check_parameter, finite, integer, positive

__all__ = ["FusedViews", "fused_reference_map", "neighbour_times"]

DEFAULT_VIEWS = 5
"""Views of :class:`FusedViews` when none is given."""

CANDIDATE_C = 0.0
"""The adaptive threshold's ``c`` of every view's map when fused (the module's "Candidates,
then the check"): a pixel is a candidate where its ray density exceeds its neighbourhood's."""

VIEWS_FUSION = FusionParams(min_views=2)
"""The multi-view check of a fused reference map: two other views agree within 2 % in depth
(one pixel's search radius)."""

SPACING_SHARE = 0.25
"""The neighbours' default spacing ``h``, as a share of the window's length."""


def _views(value: object) -> int:
    return check_parameter(lambda name, v: integer(name, v, 1), "views", value)


def _enough_views(value: object, fusion: FusionParams) -> int:
    """``views`` checked: 1 (nothing fused) or more than the check's ``min_views`` (with fewer
    other views than the check asks to agree, no point could be kept)."""
    views = _views(value)
    if 1 < views <= fusion.min_views:
        raise ParameterError(
            f"{{views}} {views} is too few: a point is kept where {fusion.min_views} other "
            f"views agree on it, so {{views}} must be 1 (the one-view map) or at least "
            f"{fusion.min_views + 1}", views="views")
    return views


def _spacing(t0: float, t1: float, spacing: float | None) -> float:
    """``h``: the given spacing, checked, or :data:`SPACING_SHARE` of the window's length."""
    if spacing is None:
        return SPACING_SHARE * (t1 - t0)
    return check_parameter(positive, "spacing", spacing)


def neighbour_times(t_ref: float, window: tuple[float, float], views: int,
                    span: tuple[float, float], spacing: float | None = None) -> list[float]:
    """The reference times of a reference view's ``views - 1`` neighbours (the module's rule).

    Parameters
    ----------
    t_ref : float, seconds
        The reference view's time.
    window : (float, float), seconds
        The reference view's event window ``(t0, t1)``; each neighbour maps it shifted by its
        offset from ``t_ref``.
    views : int
        N >= 1, the reference view included.
    span : (float, float), seconds
        What the data covers (events and poses); a neighbour's whole window must lie in it
        (within :data:`sim.sequence.EXACT_TIME_S`).
    spacing : float or None, seconds
        ``h``; None: :data:`SPACING_SHARE` (a quarter) of the window's length.

    Returns
    -------
    list of float, seconds
        ``views - 1`` times, in the order they were taken (nearest first, earlier first at
        equal distance).

    Raises
    ------
    ParameterError
        A bad ``views`` or ``spacing``, or fewer than ``views - 1`` neighbours whose windows fit
        in the data (one line naming ``{views}``).
    """
    views = _views(views)
    t0, t1 = float(window[0]), float(window[1])
    if not t1 > t0:
        raise ParameterError(f"empty {{window}} [{t0:g}, {t1:g}] s", window="window")
    h = _spacing(t0, t1, spacing)
    lo, hi = float(span[0]) - EXACT_TIME_S, float(span[1]) + EXACT_TIME_S
    times: list[float] = []
    k = 1
    while len(times) < views - 1:
        earlier, later = t0 - k * h >= lo, t1 + k * h <= hi       # the shifted windows fit
        if not (earlier or later):
            raise ParameterError(
                f"{{views}} {views} needs {views - 1} neighbouring windows of "
                f"{t1 - t0:g} s spaced {h:g} s apart around {t_ref:g} s within the data "
                f"[{span[0]:g}, {span[1]:g}] s; only {len(times)} fit: give fewer {{views}} or "
                "more data", views="views")
        for t, fits in ((float(t_ref) - k * h, earlier), (float(t_ref) + k * h, later)):
            if fits and len(times) < views - 1:
                times.append(t)
        k += 1
    return times


def _reference(map_folder: Path) -> tuple[dict, DepthView, Path]:
    """The one-view map's ``map.json``, its depth view and its sequence folder."""
    path = map_folder / "map.json"
    if not path.is_file():
        raise ValueError(f"{map_folder}: no map.json (write a map with evfuse map first)")
    meta = json.loads(path.read_text())
    try:
        c = meta["camera"]
        camera = Camera(int(c["width"]), int(c["height"]), c["fx"], c["fy"], c["cx"], c["cy"])
        view = DepthView(read_depth(map_folder / "semidense_depth.exr"), camera,
                         np.array(meta["T_world_ref"], np.float64), float(meta["t_ref"]),
                         "reference")
        sequence = map_folder / meta["sequence"]
        _ = (meta["window_s"][1], meta["params"]["dsi"], meta["params"]["depth"])  # present
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a map.json written by evfuse map ({exc})") from exc
    return meta, view, sequence


MAP_POINT_KEYS = ("N1", "t_ref", "T_world_ref", "sequence", "params", "camera", "errors",
                  "errors_by_motion", "depth_median_m", "boundary_plane_points",
                  "outlier_radius_m", "outliers_removed", "timings", "dsi_mev_per_s",
                  "dsi_timing")
"""Keys of the reference's ``map.json`` that describe its own points and its own mapping (each
view's ``views/NN/map.json`` has its own) or are written anew by
:func:`fusion.map.mapping.write_map`: not copied into the fused map's, which keeps the window's
and the DSI range's."""


def fused_reference_map(map_folder: str | Path, out: str | Path, views: int = DEFAULT_VIEWS,
                        fusion: FusionParams | None = None, *, spacing: float | None = None,
                        c: float | None = CANDIDATE_C, overwrite: bool = False,
                        progress: bool = True) -> dict:
    """Fuse a one-view map with its ``views - 1`` neighbours' maps in its own pixels.

    Parameters
    ----------
    map_folder : str or Path
        The one-view map (``evfuse map``'s folder); its ``map.json`` gives the sequence, the
        reference time, the window, the DSI and the extraction parameters. Only read.
    out : str or Path
        Folder to write: ``views/NN/`` (the neighbours' maps, ``00`` the reference view's
        candidates) and ``map/`` (the fused map).
    views : int
        N: 1 (the one-view map, bit for bit) or more than ``fusion.min_views``, the reference
        view included (default 5).
    fusion : FusionParams, optional
        The consistency check (default :data:`VIEWS_FUSION`: two other views within 2 %, a
        pixel's search radius); ``voxel_size`` is not used.
    spacing : float or None, seconds
        Between neighbours' reference times (default a quarter of the window's length).
    c : float or None
        The adaptive threshold's ``c`` of every view's map (default :data:`CANDIDATE_C`);
        None: the one-view map's own (its map is then fused as it is, not mapped again).
    overwrite : bool
    progress : bool

    Returns
    -------
    dict
        The fused map's description (also ``map/map.json``'s ``fused``): ``views``,
        ``view_times_s`` (reference first), ``spacing_s``, ``fusion``, ``c`` (the candidates'
        threshold), ``N1_views`` (each fused map's points, the reference view's candidates
        first), ``N1_reference`` (the one-view map's points), ``N1`` (the fused map's),
        ``pixels_from_reference`` (pixels holding the reference view's own candidate depth:
        its points that other views confirm and no nearer confirmed point hides),
        ``pixels_from_neighbours`` (the rest), ``folders``.
    """
    map_folder = Path(map_folder)
    fusion = fusion or VIEWS_FUSION
    views = _enough_views(views, fusion)
    if c is not None:
        c = check_parameter(finite, "c", c)
    meta, reference, sequence_folder = _reference(map_folder)
    t_ref = reference.t
    window = (float(meta["window_s"][0]), float(meta["window_s"][1]))
    sequence = load_sequence(sequence_folder)
    data = time_window(sequence)
    span = (max(data.events_span[0], data.poses_span[0]),
            min(data.events_span[1], data.poses_span[1]))
    times = neighbour_times(t_ref, window, views, span, spacing)
    h = _spacing(*window, spacing)
    p = meta["params"]
    dsi, extraction = DSIParams(**p["dsi"]), DepthMapParams(**p["depth"])
    remap = views > 1 and c is not None and c != extraction.c
    candidates = replace(extraction, c=c) if remap else extraction
    folders = []
    with atomic_output_dir(out, overwrite=overwrite, inputs=[map_folder, sequence_folder],
                           command="evfuse run --views") as tmp:

        def mapped_view(index: int, t: float) -> tuple[DepthView, MapResult]:
            folder = Path("views") / f"{index:02d}"
            shift = t - t_ref
            mapped, _ = map_window(sequence_folder, tmp / folder, window[0] + shift,
                                   window[1] + shift, ref_time=t, min_depth=dsi.min_depth,
                                   max_depth=dsi.max_depth, planes=dsi.planes,
                                   depth=candidates, progress=progress)
            folders.append(f"{folder.as_posix()}/")
            return DepthView(mapped.depth, mapped.camera, mapped.T_world_ref, mapped.t_ref,
                             f"view {index}"), mapped

        if remap:                   # the reference view's candidates: its map at the lower c
            own_view, own_map = mapped_view(0, t_ref)
            own_confidence = own_map.confidence
        else:
            own_view = reference
            own_confidence = read_exr_channels(map_folder / "confidence.exr")["Y"]
        depth_views = [own_view] + [mapped_view(index, t)[0]
                                    for index, t in enumerate(times, start=1)]
        if views == 1:
            fused = reference.depth.copy()
        else:
            counts = agreement_counts(depth_views, fusion)
            fused = fuse_into_view(depth_views, 0, fusion, counts=counts)
        own = (own_view.depth > 0) & (fused == own_view.depth)
        confidence = np.where(own, own_confidence, 0).astype(np.float32)
        description = {
            "views": views, "view_times_s": [t_ref, *times], "spacing_s": h,
            "fusion": asdict(fusion), "c": candidates.c,
            "N1_views": [int(np.count_nonzero(v.valid)) for v in depth_views],
            "N1_reference": int(np.count_nonzero(reference.valid)),
            "N1": int(np.count_nonzero(fused)),
            "pixels_from_reference": int(np.count_nonzero(own)),
            "pixels_from_neighbours": int(np.count_nonzero((fused > 0) & ~own)),
            "folders": {"views": folders, "map": "map/"},
        }
        info = {k: v for k, v in meta.items() if k not in MAP_POINT_KEYS}
        info["fused"] = description
        info["depth_median_m"] = float(np.median(fused[fused > 0])) if fused.any() else None
        truth = _ground_truth_depth(sequence, t_ref)       # scoring only
        if truth is not None:
            info["errors"] = depth_errors(fused, truth)
        params = MapParams(dsi, candidates, t0=p.get("t0"), t1=p.get("t1"),
                           ref_time=p.get("ref_time"), clip_window=bool(p.get("clip_window")),
                           outlier_radius=p["outlier_radius"],
                           outlier_neighbours=p["outlier_neighbours"])
        result = MapResult(fused, confidence, fused > 0, reference.camera, t_ref,
                           reference.T_world_cam, info, sequence)
        write_map(result, tmp / "map", params)
    return description


@dataclass(frozen=True)
class FusedViews:
    """``evfuse run --views N``: the run's map fused with its neighbours' (an extra map of
    :func:`fusion.pipeline.run_pipeline`, written into ``<run>/fused/``).

    Attributes
    ----------
    views : int
        N >= 2 and more than ``fusion.min_views``, the reference view included (default 5).
    fusion : FusionParams
        The multi-view check (default :data:`VIEWS_FUSION`: two other views within 2 %).
    spacing : float or None, seconds
        Between neighbours' reference times (default a quarter of the window's length).
    c : float or None
        The adaptive threshold's ``c`` of every view's map (default :data:`CANDIDATE_C`, 0);
        None: the one-view map's own.
    """

    views: int = DEFAULT_VIEWS
    fusion: FusionParams = VIEWS_FUSION
    spacing: float | None = None
    c: float | None = CANDIDATE_C
    name: str = "fused"

    def __post_init__(self) -> None:
        object.__setattr__(self, "views", _enough_views(self.views, self.fusion))
        if self.spacing is not None:
            object.__setattr__(self, "spacing", check_parameter(positive, "spacing",
                                                                self.spacing))
        if self.c is not None:
            object.__setattr__(self, "c", check_parameter(finite, "c", self.c))

    def span(self, t0: float, t1: float, duration: float,
             slack: float = 0.0) -> tuple[float, float]:
        """The part of a scene ``[0, duration]`` to simulate so that the neighbours of a map of
        ``[t0, t1]`` fit.

        Each neighbour maps ``[t0 + k h, t1 + k h]`` (``k`` its signed rank,
        :func:`neighbour_times`; wherever the reference view lies in the window), chosen here
        within the scene less a margin of ``h / 2 + slack`` at each end; the span holds those
        windows and the margin. ``slack`` (seconds) is the rig's largest clock offset
        (:attr:`sim.capture_errors.RigParams.offsets`): the recorded events and poses are
        shifted from the scene's time by it. Every window chosen here lies in the recorded
        data with room to spare, so :func:`fused_reference_map` finds at least as many.

        Returns
        -------
        (float, float), seconds
            ``(start, end)`` within ``[0, duration]``, containing ``[t0, t1]``.
        """
        h = _spacing(t0, t1, self.spacing)
        margin = 0.5 * h + abs(float(slack))
        middle = 0.5 * (t0 + t1)
        times = neighbour_times(middle, (t0, t1), self.views, (margin, duration - margin),
                                self.spacing)
        offsets = [0.0, *(t - middle for t in times)]
        return (max(0.0, t0 + min(offsets) - margin),
                min(duration, t1 + max(offsets) + margin))

    def __call__(self, map_folder: Path, out: Path, progress: bool) -> dict:
        """Write the fused map into ``out/map`` (:func:`fused_reference_map`)."""
        return fused_reference_map(map_folder, out, self.views, self.fusion,
                                   spacing=self.spacing, c=self.c, progress=progress)

