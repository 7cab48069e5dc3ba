"""Errors of a depth map against the exact depth, and images that show where they are.

The metrics are the usual ones of depth estimation (Eigen et al., NeurIPS 2014; the KITTI depth
benchmark): mean and root-mean-square absolute error, mean absolute relative error, mean error of
the inverse depth, and the share of pixels within a ratio of the truth (delta < 1.25, 1.05, 1.01).
They are evaluated where both maps have a depth (``n`` pixels); beside them, every result carries
the coverage they were measured on: completeness (how much of the truth has a depth) and
precision (how many of *all* the estimated points, those in front of no surface included, lie
within 5 % or 1 % of the exact surface). This module is the only definition of these figures:
``map.json`` and ``fill.json`` both hold :func:`depth_errors`.

In a scene whose objects move, the errors are also split by :func:`motion_regions` into the
points on moving objects, the static points that a moving object crossed during the window, and
the rest (:func:`errors_by_motion`): a static-scene method such as EMVS cannot map what moves,
and the first two sets say how much of the error that explains.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from fusion.fill.records import FillInputs
from sim.sequence import load_sequence

__all__ = ["DELTAS", "ERROR_NO_SURFACE", "ERROR_NO_VALUE", "MOTION_REGIONS", "MOTION_STEP_S",
           "PRECISIONS", "dense_errors", "depth_errors", "discontinuity_band", "error_image",
           "errors_by_motion", "frame_motion_regions", "motion_regions", "recorded_scene"]

DELTAS = (1.25, 1.05, 1.01)
"""Ratio thresholds of the delta accuracies, ``max(d / gt, gt / d) < delta``."""
PRECISIONS = (0.05, 0.01)
"""Relative tolerances of the precisions, ``|d - gt| <= tol * gt`` with ``gt > 0``."""


def _check_depth(name: str, depth) -> np.ndarray:
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"{name} must be an (H, W) depth map, got shape {depth.shape}")
    if not (np.issubdtype(depth.dtype, np.floating) or np.issubdtype(depth.dtype, np.integer)):
        raise ValueError(f"{name} must hold depths in metres, got dtype {depth.dtype}")
    depth = depth.astype(np.float64)
    bad = ~np.isfinite(depth)
    if bad.any():
        raise ValueError(f"{name} must be finite metres (0 = no depth), found {int(bad.sum())} "
                         f"NaN or infinite pixels")
    if (depth < 0).any():
        raise ValueError(f"{name} must be >= 0 metres (0 = no depth), found "
                         f"{int((depth < 0).sum())} negative pixels")
    return depth


def _check_pair(depth, gt, mask) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    depth = _check_depth("depth", depth)
    gt = _check_depth("gt", gt)
    if depth.shape != gt.shape:
        raise ValueError(f"depth has shape {depth.shape} but gt has shape {gt.shape}: expected "
                         f"the same (H, W)")
    if mask is None:
        mask = np.ones(gt.shape, bool)
    else:
        mask = np.asarray(mask)
        if mask.shape != gt.shape:
            raise ValueError(f"mask has shape {mask.shape} but gt has shape {gt.shape}: "
                             f"expected the same (H, W)")
        mask = mask.astype(bool)
    return depth, gt, mask


def depth_errors(depth: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """Errors of a depth map against the exact depth, with the coverage they were measured on.

    The errors are evaluated on the ``n`` pixels where ``depth > 0``, ``gt > 0`` and ``mask``.
    Precision is evaluated on *all* the estimated points (``depth > 0`` and ``mask``), including
    those where there is no surface (``gt == 0``, e.g. the sky), which count as not within: a
    point floating in front of nothing lowers the precision but leaves the errors unchanged.

    Parameters
    ----------
    depth : (H, W) float ndarray, metres, 0 where unknown
    gt : (H, W) float ndarray, metres, 0 where no surface
    mask : (H, W) bool ndarray, optional
        Region to evaluate (e.g. :func:`discontinuity_band` or its complement); default all.

    Returns
    -------
    dict
        ``n`` (int, pixels with both depths); ``mae_cm``, ``median_cm``, ``rmse_cm``
        (centimetres, mean / median / root-mean-square of ``|d - gt|``); ``abs_rel`` (mean
        ``|d - gt| / gt``); ``imae_per_m`` (mean ``|1/d - 1/gt|``, 1/m); ``delta_1.25``,
        ``delta_1.05``, ``delta_1.01`` (shares of the ``n`` pixels with ``max(d/gt, gt/d) <``
        the threshold); ``completeness`` (share of the pixels of the mask with ``gt > 0`` that
        have ``d > 0``); ``points`` (int, estimated points ``d > 0`` in the mask); ``no_surface``
        (int, of those, where ``gt == 0``); ``precision_5pct``, ``precision_1pct`` (share of
        the ``points`` with ``gt > 0`` and ``|d - gt| <= 0.05 gt``, resp. ``0.01 gt``).
        With nothing to evaluate, ``n`` is 0 and the errors are NaN (``completeness`` is 0.0
        when the mask holds some truth but ``d`` has none there, NaN when it holds no truth);
        the precisions are NaN when ``points`` is 0.

    Raises
    ------
    ValueError
        If the shapes differ or a depth is NaN, infinite or negative.
    """
    depth, gt, mask = _check_pair(depth, gt, mask)
    truth = mask & (gt > 0)
    estimated = mask & (depth > 0)
    both = truth & estimated
    n = int(both.sum())
    points = int(estimated.sum())
    completeness = n / int(truth.sum()) if truth.any() else float("nan")
    coverage = {"completeness": float(completeness), "points": points,
                "no_surface": points - n}
    for tol in PRECISIONS:
        within = np.abs(depth[both] - gt[both]) <= tol * gt[both]
        coverage[f"precision_{round(100 * tol)}pct"] = (
            float(np.count_nonzero(within)) / points if points else float("nan"))
    keys = (("mae_cm", "median_cm", "rmse_cm", "abs_rel", "imae_per_m")
            + tuple(f"delta_{t}" for t in DELTAS))
    if n == 0:
        return {"n": 0, **dict.fromkeys(keys, float("nan")), **coverage}
    d = depth[both]
    g = gt[both]
    err = np.abs(d - g)
    ratio = np.maximum(d / g, g / d)
    values = [100.0 * err.mean(), 100.0 * np.median(err), 100.0 * np.sqrt(np.mean(err ** 2)),
              np.mean(err / g), np.mean(np.abs(1.0 / d - 1.0 / g))]
    values += [np.mean(ratio < t) for t in DELTAS]
    return {"n": n, **{k: float(v) for k, v in zip(keys, values, strict=True)}, **coverage}


def discontinuity_band(gt: np.ndarray, width: int = 3, jump: float = 0.05) -> np.ndarray:
    """Pixels near a depth discontinuity of the exact depth, where filling is hardest.

    A discontinuity is a pair of 4-neighbours whose depths differ by more than ``jump`` times
    the smaller (a relative jump: a step of 5 cm at 1 m is as visible as 20 cm at 4 m, and the
    depth of a slanted plane changes by far less between neighbours), or of which exactly one has a
    depth (a silhouette against empty space). The band is both pixels of every such pair and every
    pixel within Chebyshev distance ``width`` of one of them (a dilation by a ``2 width + 1``
    square). A step between columns 4 and 5 with ``width = 3`` gives columns 1 to 8.

    Parameters
    ----------
    gt : (H, W) float ndarray, metres, 0 where no surface
    width : int, pixels, >= 0
    jump : float, > 0
        Relative depth jump (default 0.05).

    Returns
    -------
    (H, W) bool ndarray
    """
    gt = _check_depth("gt", gt)
    if int(width) != width or width < 0:
        raise ValueError(f"width must be an integer >= 0 pixels, got {width}")
    if not (np.isfinite(jump) and jump > 0):
        raise ValueError(f"jump must be a finite relative depth step > 0, got {jump}")
    pair = np.zeros(gt.shape, bool)
    for a, b, sa, sb in (
        (gt[:, 1:], gt[:, :-1], (slice(None), slice(1, None)), (slice(None), slice(None, -1))),
        (gt[1:, :], gt[:-1, :], (slice(1, None), slice(None)), (slice(None, -1), slice(None))),
    ):
        valid_a, valid_b = a > 0, b > 0
        step = valid_a & valid_b & (np.abs(a - b) > jump * np.minimum(a, b))
        edge = step | (valid_a != valid_b)
        pair[sa] |= edge
        pair[sb] |= edge
    if width == 0:
        return pair
    kernel = np.ones((2 * int(width) + 1, 2 * int(width) + 1), np.uint8)
    return cv2.dilate(pair.astype(np.uint8), kernel).astype(bool)


ERROR_NO_VALUE = (200, 200, 200)
"""BGR of :func:`error_image` where there is no error to show (no estimate, or neither estimate
nor surface): a light grey, at least 139 (of 255) in Euclidean distance from every turbo level, so
that it never reads as an error (black would, as turbo's cold end is nearly black)."""

ERROR_NO_SURFACE = (255, 0, 255)
"""BGR of :func:`error_image` where there is an estimate but no surface (exact depth 0): an error
of unbounded size, in magenta, which turbo never produces."""


def error_image(depth: np.ndarray, gt: np.ndarray, max_error: float | None = None) -> np.ndarray:
    """Absolute depth error as a colour image: turbo colour map, two colours no error takes.

    Parameters
    ----------
    depth : (H, W) float ndarray, metres, 0 where unknown
    gt : (H, W) float ndarray, metres, 0 where no surface
    max_error : float, metres, optional
        Error shown in the last colour (red); larger errors are clipped to it. Default: the
        largest error of the image, so that the scale is the image's own (write it beside).

    Returns
    -------
    (H, W, 3) uint8 ndarray, BGR
        For ``cv2.imwrite``: 0 m dark blue through green to ``max_error`` red where both depths
        are > 0; :data:`ERROR_NO_SURFACE` (magenta) where ``depth > 0`` and ``gt`` is 0;
        :data:`ERROR_NO_VALUE` (light grey) where ``depth`` is 0.
    """
    depth, gt, _ = _check_pair(depth, gt, None)
    both = (depth > 0) & (gt > 0)
    err = np.where(both, np.abs(depth - gt), 0.0)
    if max_error is None:
        max_error = float(err.max()) if both.any() else 0.0
    elif not (np.isfinite(max_error) and max_error > 0):
        raise ValueError(f"max_error must be a finite number > 0 metres, got {max_error}")
    scaled = err / max_error if max_error > 0 else np.zeros_like(err)
    levels = np.round(255.0 * np.clip(scaled, 0.0, 1.0)).astype(np.uint8)
    image = cv2.applyColorMap(levels, cv2.COLORMAP_TURBO)
    image[~both] = ERROR_NO_VALUE
    image[(depth > 0) & (gt == 0)] = ERROR_NO_SURFACE
    return image


MOTION_REGIONS = {"moving": 1, "crossed": 2, "static": 0}
"""Labels of :func:`motion_regions`: a moving object at the view's time; a static surface (or
nothing) whose line of sight a moving object covered during the window; the rest."""
MOTION_STEP_S = 0.01
"""Time step (s) at which :func:`motion_regions` samples the objects' motion over the window
(dynamic_6dof's fastest object, its ball, moves 6 mm in that time)."""


def recorded_scene(metadata: dict | None):
    """The scene a simulated sequence was made from, parsed from the TOML its ``sequence.json``
    recorded (with its seed), or None for a recording without one (a real recording). Ground
    truth: for scoring only.

    Parameters
    ----------
    metadata : dict or None
        The sequence's ``sequence.json`` (:attr:`sim.sequence.Sequence.metadata`).

    Returns
    -------
    sim.scene.Scene or None
    """
    meta = metadata or {}
    toml = (meta.get("scene") or {}).get("toml")
    if not toml:
        return None
    from sim.scene import parse_scene

    source = (meta.get("scene") or {}).get("source") or "<sequence.json>"
    return parse_scene(toml, source, seed=meta.get("seed"))


def motion_regions(scene, camera, pose: np.ndarray, t_view: float,
                   window: tuple[float, float], step: float = MOTION_STEP_S
                   ) -> np.ndarray | None:
    """Which pixels of a view see a moving object, or were crossed by one during a window.

    Ground truth, for scoring only. The view (camera, pose) is held fixed and the objects are
    moved: a pixel is ``moving`` where its ray hits a moving object at ``t_view``, ``crossed``
    where it does not but hits one at some time of ``window`` (sampled every ``step`` s, both
    ends included), ``static`` elsewhere. So ``crossed`` is the set of static pixels in front of
    which a moving object passed, seen from the reference view: the rays along which the
    object's events, back-projected as if the scene were static, put votes at the object's
    depth instead of the surface's. It leaves out the camera's own motion during the window
    (the object seen from the other poses of the window sweeps a slightly different set, by
    the parallax of the camera's baseline against the object's distance).

    Parameters
    ----------
    scene : sim.scene.Scene
        The scene the sequence was simulated from.
    camera : sim.camera.Camera
        The view's camera (the pixel grid of the map or frame to score).
    pose : (4, 4) ndarray
        The view's true ``T_world_camera``.
    t_view : float, seconds, true time
        The view's time (where the objects are in the map or frame).
    window : (float, float), seconds, true time
        The event window.
    step : float, seconds

    Returns
    -------
    (H, W) uint8 ndarray of :data:`MOTION_REGIONS` labels, or None when no object moves.
    """
    moving_ids = [i + 1 for i, obj in enumerate(scene.objects) if obj.motion is not None]
    if not moving_ids:
        return None
    t0, t1 = (float(t) for t in window)
    if not (math.isfinite(t0) and math.isfinite(t1) and t0 <= t1):
        raise ValueError(f"window must be two finite times t0 <= t1 (s), got {window}")
    if not (math.isfinite(step) and step > 0):
        raise ValueError(f"step must be a finite time > 0 s, got {step}")
    from sim.render import Renderer

    renderer = Renderer(replace(scene, camera=camera), spp=1)
    moving = np.isin(renderer.object_ids(float(t_view), pose=pose), moving_ids)
    crossed = np.zeros_like(moving)
    for t in np.linspace(t0, t1, max(2, math.ceil((t1 - t0) / step) + 1)):
        crossed |= np.isin(renderer.object_ids(float(t), pose=pose), moving_ids)
    labels = np.full(moving.shape, MOTION_REGIONS["static"], np.uint8)
    labels[crossed & ~moving] = MOTION_REGIONS["crossed"]
    labels[moving] = MOTION_REGIONS["moving"]
    return labels


def errors_by_motion(depth: np.ndarray, gt: np.ndarray, regions: np.ndarray) -> dict:
    """:func:`depth_errors` on each of the :func:`motion_regions`, with its share of the error.

    Parameters
    ----------
    depth : (H, W) float ndarray, metres, 0 where unknown
    gt : (H, W) float ndarray, metres, 0 where no surface
    regions : (H, W) uint8 ndarray of :data:`MOTION_REGIONS` labels

    Returns
    -------
    dict
        ``{"moving" | "crossed" | "static": depth_errors(...) + {"error_share": float}}``;
        ``error_share`` is the region's part of the sum of ``|d - gt|`` over all the pixels
        with both depths (the three add up to 1; NaN when there is no such pixel).
    """
    depth, gt, _ = _check_pair(depth, gt, None)
    regions = np.asarray(regions)
    if regions.shape != gt.shape:
        raise ValueError(f"regions has shape {regions.shape} but gt has shape {gt.shape}: "
                         "expected the same (H, W)")
    both = (depth > 0) & (gt > 0)
    err = np.where(both, np.abs(depth - gt), 0.0)
    total = float(err.sum())
    out = {}
    for name, label in MOTION_REGIONS.items():
        inside = regions == label
        share = float(err[inside].sum()) / total if total > 0 else float("nan")
        out[name] = {**depth_errors(depth, gt, inside), "error_share": share}
    return out


def dense_errors(dense: np.ndarray, sparse: np.ndarray, truth: np.ndarray, band: int = 3
                 ) -> dict:
    """Errors against the exact depth, for the map points, the filled pixels and all, overall,
    in the ``band``-pixel band around true discontinuities and in the region interiors.

    Returns
    -------
    dict
        ``{"map" | "filled" | "all": {"overall" | "band" | "interior": depth_errors(...)}}``
        (:func:`depth_errors`, the same definitions as ``map.json``'s):
        completeness is the share of the pixels with a true depth that have a depth of that
        kind; ``points`` and the precisions count every point of that kind, those where the
        exact depth is 0 (no surface) included.
    """
    sparse = np.asarray(sparse, np.float32)
    dense = np.asarray(dense, np.float32)
    filled = np.where(sparse > 0, 0.0, dense).astype(np.float32)
    near = discontinuity_band(truth, width=band)
    out = {}
    for name, depth in (("map", sparse), ("filled", filled), ("all", dense)):
        out[name] = {"overall": depth_errors(depth, truth),
                     "band": depth_errors(depth, truth, near),
                     "interior": depth_errors(depth, truth, ~near)}
    return out


def frame_motion_regions(inputs: FillInputs) -> np.ndarray | None:
    """:func:`motion_regions` of the frame to fill (the scene's own camera at its
    true pose and time, the view its exact depth was rendered in; the event window is the
    map's), or None: no exact depth, a scene whose objects do not move, or a two-camera rig
    (not split). Scoring only."""
    if inputs.truth is None or inputs.info.get("rig") is not None:
        return None
    sequence = load_sequence(inputs.info["sequence"])
    meta = sequence.metadata or {}
    scene = recorded_scene(meta)
    if scene is None or not scene.is_dynamic:
        return None
    from sim.capture_errors import true_time

    window = json.loads((Path(inputs.info["map"]) / "map.json").read_text())["window_s"]
    t_true = true_time(meta, inputs.info["t_frame"], "frames")
    camera = scene.camera.with_resolution(inputs.frame.shape[1], inputs.frame.shape[0])
    return motion_regions(scene, camera, scene.trajectory.pose(t_true), t_true,
                          tuple(true_time(meta, t, "events") for t in window))
