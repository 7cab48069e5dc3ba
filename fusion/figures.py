"""Figures drawn from results: depth in colour, segmentations, point clouds, panels.

Everything returns 8-bit BGR images (``cv2.imwrite`` writes them as they are), with the legend or
caption that reads them; nothing here computes a result, so every figure can be re-drawn from
the files a run saved (Figure 2 of a fill, :func:`fill_figure`, re-runs only the region growing
of its raw-segmentation panel).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fusion.fill.records import DenseParams, DenseResult
from fusion.fill.segmentation import SegmentationParams, segment_regions
from fusion.io import dense_cloud
from fusion.map.dsi_range import oracle_header
from fusion.scoring import ERROR_NO_SURFACE, ERROR_NO_VALUE, error_image
from sim._atomic import write_bytes_atomically
from sim.image_out import mark_png

__all__ = ["FARTHER_COLOUR", "NEARER_COLOUR", "Caption", "DepthScale", "Legend", "Swatches",
           "add_header", "depth_colours", "depth_legend", "depth_scale", "error_legend",
           "error_panel", "error_panels", "event_legend", "fill_error_figure", "fill_figure",
           "fill_figure_panels", "grid_scale", "highlight_pixels", "label_colours", "panel_grid",
           "point_cloud_view", "point_radius", "spread_pixels", "write_event_frame",
           "write_image"]

_NO_VALUE = (40, 40, 40)
"""Colour of pixels without a depth (dark grey, so that black texture stays readable)."""

DEPTH_LEVELS = (64, 224)
"""The part of OpenCV's JET map that :func:`depth_colours` uses, far (azure, level 64) to near
(red, level 224): JET's dark blue and dark red ends are left out, so that every depth colour
stands out from the dark grey of "no value" (WCAG contrast at least 3.6; JET's far end had 1.1,
and far map points vanished into the background)."""
NEARER_COLOUR = (255, 255, 255)
"""BGR of a depth nearer than the low end of the colour scale (white: no depth colour is)."""
FARTHER_COLOUR = (255, 80, 180)
"""BGR of a depth farther than the high end of the colour scale (violet: no depth colour is,
and not the magenta of an error panel's "no surface")."""


def depth_colours(depth: np.ndarray, lo: float | None = None, hi: float | None = None,
                  base: np.ndarray | None = None, radius: int = 0) -> np.ndarray:
    """Depth in colour (near red, far azure: :data:`DEPTH_LEVELS` of OpenCV's JET).

    Depths outside ``[lo, hi]`` are not clipped to the end colours: they are drawn in
    :data:`NEARER_COLOUR` / :data:`FARTHER_COLOUR`, which the scale does not use, so that a
    map point beyond the scale never reads as a plausible depth.

    Parameters
    ----------
    depth : (H, W) float ndarray, metres, 0 where none
    lo, hi : float, metres, optional
        Range of the colour scale (default: the range of the valid depths).
    base : (H, W) uint8 or (H, W, 3) uint8 ndarray, optional
        Image shown where there is no depth (default dark grey).
    radius : int, pixels, >= 0
        Draw each depth as a square of side ``2 radius + 1`` (the nearest depth wins where
        squares overlap), so that a sparse map's points survive a panel's downscaling
        (:func:`point_radius`). 0: one pixel each.

    Returns
    -------
    (H, W, 3) uint8 ndarray, BGR
    """
    depth = np.asarray(depth, dtype=np.float64)
    valid = depth > 0
    if radius > 0 and valid.any():
        nearest = np.where(valid, depth, np.inf).astype(np.float32)
        kernel = np.ones((2 * int(radius) + 1, 2 * int(radius) + 1), np.uint8)
        nearest = cv2.erode(nearest, kernel, borderType=cv2.BORDER_CONSTANT,
                            borderValue=np.inf).astype(np.float64)      # min: the nearest
        valid = np.isfinite(nearest)
        depth = np.where(valid, nearest, 0.0)
    if base is None:
        out = np.empty(depth.shape + (3,), np.uint8)
        out[:] = _NO_VALUE
    else:
        out = cv2.cvtColor(base, cv2.COLOR_GRAY2BGR) if base.ndim == 2 else base.copy()
    if not valid.any():
        return out
    lo = float(depth[valid].min()) if lo is None else lo
    hi = float(depth[valid].max()) if hi is None else hi
    scaled = np.clip((depth - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    far, near = DEPTH_LEVELS
    levels = np.round(near - (near - far) * scaled).astype(np.uint8)
    colours = cv2.applyColorMap(levels, cv2.COLORMAP_JET)
    out[valid] = colours[valid]
    out[valid & (depth < lo)] = NEARER_COLOUR
    out[valid & (depth > hi)] = FARTHER_COLOUR
    return out


@dataclass(frozen=True)
class Legend:
    """A colour bar drawn under a panel by :func:`panel_grid`.

    Attributes
    ----------
    colours : (N, 3) uint8 ndarray, BGR
        The colour scale from its low end (left) to its high end (right).
    low, high : str
        Labels written at the two ends, with units (``"0.23 m"``).
    keys : tuple of (str, (B, G, R)) pairs
        Colours outside the scale, each drawn as a swatch with its meaning after the bar
        (``("no value", (200, 200, 200))``).
    under, over : (B, G, R), optional
        The colour of values below the low / above the high end, drawn as a triangle at that
        end of the bar (as matplotlib's ``extend``); None: no value lies beyond that end.
    """

    colours: np.ndarray
    low: str
    high: str
    keys: tuple[tuple[str, tuple[int, int, int]], ...] = ()
    under: tuple[int, int, int] | None = None
    over: tuple[int, int, int] | None = None


@dataclass(frozen=True)
class Swatches:
    """Colour swatches with their meanings, drawn under a panel by :func:`panel_grid` in place
    of a colour bar (``(("ON", (0, 0, 255)), ("OFF", (255, 0, 0)))``)."""

    keys: tuple[tuple[str, tuple[int, int, int]], ...]


@dataclass(frozen=True)
class Caption:
    """A line of text drawn under a panel by :func:`panel_grid`, in place of a colour bar."""

    text: str


MIN_SPAN_SHARE = 0.1
"""A depth scale spans at least this share of its middle depth (a flat poster at 0.231 m gets
0.219-0.243 m, so that a few centimetres of error still show as colour)."""
MAP_PERCENTILES = (1.0, 99.0)
"""Without an exact depth, the scale spans these percentiles of the maps' depths."""


@dataclass(frozen=True)
class DepthScale:
    """The shared colour scale of a figure's depth panels.

    Attributes
    ----------
    lo, hi : float, metres
        The depths drawn in the first (red) and last (azure) colour.
    below, above : bool
        Some depth of the maps lies nearer than ``lo`` / farther than ``hi``; it is drawn in
        :data:`NEARER_COLOUR` / :data:`FARTHER_COLOUR`, and the legend shows that colour at
        that end of its bar, labelled "< lo" / "> hi".
    source : str
        ``"exact depth"`` or ``"maps, 1st-99th percentile"``: what the scale spans.
    """

    lo: float
    hi: float
    below: bool = False
    above: bool = False
    source: str = "exact depth"

    def legend(self) -> Legend:
        """:func:`depth_legend` of the scale, its ends marked where depths lie beyond."""
        return depth_legend(self.lo, self.hi, below=self.below, above=self.above)


def depth_scale(*maps: np.ndarray | None, truth: np.ndarray | None = None) -> DepthScale | None:
    """One colour scale for the depth panels of a figure: the scene's, not an outlier's.

    With an exact depth the scale spans it (min to max of its surfaces), so that the panels read
    as the scene and neither a map that misses the far wall nor a map point at the DSI's far
    plane stretches it; without one it spans the 1st to 99th percentile of the maps' depths
    together (:data:`MAP_PERCENTILES`). It is widened to at least :data:`MIN_SPAN_SHARE` of its
    middle depth (a flat scene would otherwise have no span). Map depths outside it are not
    given an end colour: :func:`depth_colours` draws them in :data:`NEARER_COLOUR` /
    :data:`FARTHER_COLOUR`, and the scale says that there are some (``below`` / ``above``), so
    that its legend shows those colours at the ends of its bar.

    Parameters
    ----------
    *maps : (H, W) float ndarrays, metres, 0 where none; None entries are skipped
    truth : (H, W) float ndarray, metres, 0 where no surface, optional

    Returns
    -------
    DepthScale, or None when neither the truth nor any map has a depth
    """
    values = [np.asarray(m, np.float64)[np.asarray(m) > 0] for m in maps if m is not None]
    values = np.concatenate(values) if values else np.zeros(0)
    exact = None if truth is None else np.asarray(truth, np.float64)[np.asarray(truth) > 0]
    if exact is not None and exact.size:
        lo, hi, source = float(exact.min()), float(exact.max()), "exact depth"
    elif values.size:
        lo, hi = (float(v) for v in np.percentile(values, MAP_PERCENTILES))
        source = "maps, 1st-99th percentile"
    else:
        return None
    middle = 0.5 * (lo + hi)
    if hi - lo < MIN_SPAN_SHARE * middle:
        lo, hi = middle * (1 - 0.5 * MIN_SPAN_SHARE), middle * (1 + 0.5 * MIN_SPAN_SHARE)
    return DepthScale(lo, hi, bool((values < lo).any()), bool((values > hi).any()), source)


def depth_legend(lo: float, hi: float, below: bool = False, above: bool = False) -> Legend:
    """The legend of :func:`depth_colours` over ``[lo, hi]`` metres (near red, far azure).

    Parameters
    ----------
    lo, hi : float, metres, > 0
    below, above : bool
        Some depths lie nearer than ``lo`` / farther than ``hi`` (drawn in
        :data:`NEARER_COLOUR` / :data:`FARTHER_COLOUR`): that colour is drawn at that end of
        the bar and the end is labelled "< lo" / "> hi".

    Returns
    -------
    Legend
        256 colours, made by :func:`depth_colours` itself, so that the bar is the scale the
        panel used.
    """
    ramp = depth_colours(np.linspace(lo, hi, 256)[None, :], lo, hi)[0]
    return Legend(ramp, f"{'< ' if below else ''}{lo:.3g} m", f"{'> ' if above else ''}{hi:.3g} m",
                  under=NEARER_COLOUR if below else None, over=FARTHER_COLOUR if above else None)


def error_legend(max_error: float, clipped: bool = False) -> Legend:
    """The legend of :func:`fusion.scoring.error_image` with ``max_error``, labelled in cm, with
    the two colours that are not errors: no value, and an estimate where there is no surface.

    Parameters
    ----------
    max_error : float, metres, > 0
        The error shown in the last colour.
    clipped : bool
        Some errors are larger and drawn in the last colour too: the high end reads
        ``">= X cm"``.

    Returns
    -------
    Legend
        256 colours, made by ``error_image`` itself (errors 0 to ``max_error``), and the keys
        ``no value`` and ``no surface``.
    """
    errors = np.linspace(0.0, max_error, 256)[None, :]
    ramp = error_image(1.0 + errors, np.ones_like(errors), max_error=max_error)[0]
    high = f"{100 * max_error:.3g} cm"
    return Legend(ramp, "0 cm", (">= " if clipped else "") + high,
                  keys=(("no value", ERROR_NO_VALUE), ("no surface", ERROR_NO_SURFACE)))


ERROR_PERCENTILE = 99.0
"""Percentile of the errors at which :func:`error_panel` ends its scale (outliers clipped)."""


def error_panel(depth: np.ndarray, truth: np.ndarray, radius: int = 0
                ) -> tuple[np.ndarray, Legend]:
    """|depth - truth| in colour, with its legend: the scale ends at the 99th percentile of the
    errors (the larger ones drawn in its last colour, the legend says ``>=``).

    Parameters
    ----------
    depth : (H, W) float ndarray, metres, 0 where no estimate
    truth : (H, W) float ndarray, metres, 0 where no surface
    radius : int, pixels, >= 0
        Draw each estimate as a square of side ``2 radius + 1`` (:func:`spread_pixels`), for a
        panel that :func:`panel_grid` reduces (:func:`point_radius`).

    Returns
    -------
    image : (H, W, 3) uint8 ndarray, BGR, from :func:`fusion.scoring.error_image`
    legend : Legend, from :func:`error_legend`
    """
    images, legend = error_panels([depth], truth, radius)
    return images[0], legend


def spread_pixels(image: np.ndarray, mask: np.ndarray, radius: int) -> np.ndarray:
    """The image with each pixel of ``mask`` drawn as a square of side ``2 radius + 1``: a
    pixel off the mask within ``radius`` (chessboard distance) of it takes the colour of the
    nearest pixel of the mask (a display aid, so that sparse points survive a reduction).

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
    mask : (H, W) bool ndarray
        The pixels that carry a value.
    radius : int, pixels, >= 0

    Returns
    -------
    (H, W, 3) uint8 ndarray (``image`` itself for radius 0 or an empty mask)
    """
    mask = np.asarray(mask, bool)
    if radius <= 0 or not mask.any() or mask.all():
        return image
    distance, labels = cv2.distanceTransformWithLabels(
        (~mask).astype(np.uint8), cv2.DIST_C, 3, labelType=cv2.DIST_LABEL_PIXEL)
    rows, cols = np.nonzero(mask)                    # label k: the k-th zero pixel, row-major
    source = np.zeros(len(rows) + 1, np.int64)
    source[1:] = rows * mask.shape[1] + cols
    near = ~mask & (distance <= radius)
    out = image.copy()
    out.reshape(-1, 3)[np.flatnonzero(near)] = image.reshape(-1, 3)[source[labels[near]]]
    return out


def error_panels(depths: list[np.ndarray], truth: np.ndarray, radius: int = 0
                 ) -> tuple[list[np.ndarray], Legend]:
    """The errors of several estimates of one view on ONE colour scale (a figure that compares
    methods): it ends at the 99th percentile of all their errors together, so that equal colours
    are equal errors in every panel; the legend says ``>=`` when any error is larger.

    Parameters
    ----------
    depths : list of (H, W) float ndarrays, metres, 0 where no estimate
    truth : (H, W) float ndarray, metres, 0 where no surface
    radius : int, pixels, >= 0
        As :func:`error_panel`.

    Returns
    -------
    images : list of (H, W, 3) uint8 ndarrays, BGR, from :func:`fusion.scoring.error_image`,
        one per estimate
    legend : Legend, from :func:`error_legend`, the scale of every image
    """
    truth = np.asarray(truth, dtype=np.float64)
    errors = []
    for depth in depths:
        depth = np.asarray(depth, dtype=np.float64)
        both = (depth > 0) & (truth > 0)
        errors.append(np.abs(depth - truth)[both])
    errors = np.concatenate(errors) if errors else np.zeros(0)
    top = float(np.percentile(errors, ERROR_PERCENTILE)) if errors.size else 0.0
    top = top if top > 0 else 1e-3                 # all exact (or none): a 1-mm scale
    clipped = bool((errors > top).any())
    return ([spread_pixels(error_image(depth, truth, max_error=top), np.asarray(depth) > 0,
                           radius) for depth in depths], error_legend(top, clipped))


def label_colours(labels: np.ndarray, highlight: np.ndarray | None = None) -> np.ndarray:
    """A segmentation in colour: one fixed pseudo-random colour per label, label 0 black.

    Parameters
    ----------
    labels : (H, W) int ndarray
    highlight : (K + 1,) bool ndarray, optional
        Only these labels in colour, the others grey.

    Returns
    -------
    (H, W, 3) uint8 ndarray, BGR
    """
    labels = np.asarray(labels)
    n = int(labels.max()) + 1 if labels.size else 1
    palette = np.random.default_rng(12345).integers(60, 256, (n, 3)).astype(np.uint8)
    palette[0] = 0
    if highlight is not None:
        keep = np.zeros(n, bool)
        keep[:len(highlight)] = np.asarray(highlight, bool)[:n]
        palette[~keep] = (70, 70, 70)
        palette[0] = 0
    return palette[labels]


def event_legend(background: str = "white") -> Swatches:
    """The swatches of :func:`sim.statistics.event_frame`: ON, OFF and no event.

    Parameters
    ----------
    background : {"white", "black"}
        The event frame's background (the colour of "no event").

    Returns
    -------
    Swatches
        BGR colours, as the frame is after ``cv2.cvtColor(..., cv2.COLOR_RGB2BGR)``.
    """
    from sim.statistics import OFF_COLOUR, ON_COLOUR

    level = {"white": 255, "black": 0}[background]
    return Swatches((("ON (latest event)", tuple(ON_COLOUR[::-1])),
                     ("OFF", tuple(OFF_COLOUR[::-1])), ("no event", (level, level, level))))


FILLED_COLOUR = (0, 200, 0)
"""BGR of filled pixels where they are drawn over the frame (the point cloud's green)."""


def highlight_pixels(frame: np.ndarray, mask: np.ndarray,
                     colour: tuple[int, int, int] = FILLED_COLOUR) -> np.ndarray:
    """A gray frame with the pixels of ``mask`` in ``colour``, half blended into the frame.

    Parameters
    ----------
    frame : (H, W) uint8 ndarray, gray
    mask : (H, W) bool ndarray
        The pixels to highlight (the filled ones, say).
    colour : (3,) tuple of int, BGR

    Returns
    -------
    (H, W, 3) uint8 ndarray, BGR
    """
    image = cv2.cvtColor(np.asarray(frame, np.uint8), cv2.COLOR_GRAY2BGR)
    mask = np.asarray(mask, bool)
    if mask.shape != image.shape[:2]:
        raise ValueError(f"the mask is {mask.shape[1]}x{mask.shape[0]} but the frame is "
                         f"{image.shape[1]}x{image.shape[0]}: expected the same size")
    blended = (image[mask].astype(np.uint16) + np.array(colour, np.uint16)) // 2
    image[mask] = blended.astype(np.uint8)
    return image


AXIS_COLOURS = ((255, 255, 255), (0, 255, 255), (255, 255, 0))
"""BGR of the x, y, z axes drawn by :func:`point_cloud_view`: white, yellow, cyan (the points are
red and green)."""


def _round_length(length: float) -> float:
    """The largest 1, 2 or 5 times a power of ten that is <= ``length`` (> 0)."""
    power = 10.0 ** np.floor(np.log10(length))
    return float(max(m * power for m in (1.0, 2.0, 5.0) if m * power <= length * (1 + 1e-9)))


def _metres(length: float) -> str:
    return f"{length:g} m" if length >= 1 else f"{100 * length:g} cm"


def _side(angle: float, positive: str, negative: str) -> str:
    return f"{abs(angle):g} deg {positive if angle >= 0 else negative}"


def point_cloud_view(points: np.ndarray, colours: np.ndarray, size: tuple[int, int],
                     left_deg: float = 30.0, above_deg: float = 20.0, axes: bool = True,
                     splat: int = 2) -> tuple[np.ndarray, Caption]:
    """The points seen by a virtual camera looking at their centre from beside the camera that
    took them, z-buffered splats, with the camera frame's axes drawn at the centre.

    The virtual camera stands 3 spreads (the 75th percentile of the points' distances to their
    median) from the median, turned ``left_deg`` to the left of the reference camera (about its
    y axis) and ``above_deg`` above it, and looks at the median; its image keeps the reference
    camera's "down" (+y) downwards. With both angles 0 it sees what the reference camera sees.
    The axes are arrows along the reference camera's +x (right), +y (down) and +z (forward)
    from the median, labelled x, y, z, of a round length in metres (1, 2 or 5 times a power of
    ten, between half the spread and the spread), which the caption states with the viewpoint.

    Parameters
    ----------
    points : (N, 3) float ndarray, metres, camera frame of the reference view
    colours : (N, 3) uint8 ndarray, BGR
    size : (width, height) of the image, pixels
    left_deg, above_deg : float, degrees
        Viewpoint: to the left of (negative: right of) and above (negative: below) the
        reference camera's view of the centre.
    axes : bool
        Draw the axes (colours :data:`AXIS_COLOURS`).
    splat : int, pixels, >= 1
        Side of each point's square (2; larger for a panel that :func:`panel_grid` reduces:
        ``max(2, 2 point_radius + 1)``), and the axes' line width is ``splat - 1`` (at least 1).

    Returns
    -------
    image : (height, width, 3) uint8 ndarray, BGR (black background)
    caption : Caption
        ``"seen from 30 deg left, 20 deg above the camera; axes 10 cm"``, for the line under
        the panel.
    """
    width, height = size
    image = np.zeros((height, width, 3), np.uint8)
    view = f"seen from {_side(left_deg, 'left', 'right')}, {_side(above_deg, 'above', 'below')}"
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return image, Caption(f"{view} the camera; no points")
    centre = np.median(points, axis=0)
    spread = float(np.percentile(np.linalg.norm(points - centre, axis=1), 75)) + 1e-9
    left, above = np.radians(left_deg), np.radians(above_deg)
    # From the centre to the eye: behind the centre (-z), to the left (-x), above (-y).
    to_eye = np.array([-np.sin(left) * np.cos(above), -np.sin(above),
                       -np.cos(left) * np.cos(above)])
    forward = -to_eye
    right = np.cross([0.0, 1.0, 0.0], forward)
    right = right / np.linalg.norm(right) if np.linalg.norm(right) > 1e-9 else np.array([1.0, 0, 0])
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])         # rows: the virtual camera's axes
    eye = centre + 3.0 * spread * to_eye
    focal = 1.1 * min(width, height)                    # pixels: a spread at the centre is
                                                        # 1.1 / 3 of the image's smaller side

    def project(p):
        local = (np.atleast_2d(p) - eye) @ rotation.T
        z = local[:, 2]
        ahead = z > 0.1 * spread
        zz = np.where(ahead, z, 1.0)
        return focal * local[:, 0] / zz + width / 2, focal * local[:, 1] / zz + height / 2, z, ahead

    u, v, z, ahead = project(points)
    u, v = np.round(u).astype(np.int64), np.round(v).astype(np.int64)
    splat = max(1, int(splat))
    before, after = splat // 2, splat - splat // 2      # offsets -before .. after - 1
    inside = (ahead & (u >= before) & (u < width - after) & (v >= before)
              & (v < height - after))
    order = np.argsort(-z[inside])                      # far first, near drawn over them
    u, v, c = u[inside][order], v[inside][order], np.asarray(colours)[inside][order]
    for du in range(-before, after):                    # splat x splat squares
        for dv in range(-before, after):
            image[v + dv, u + du] = c
    length = _round_length(spread)
    if axes:
        _draw_axes(image, project, centre, length, max(1, splat - 1))
    return image, Caption(f"{view} the camera; axes {_metres(length)}")


def _draw_axes(image: np.ndarray, project, centre: np.ndarray, length: float,
               thickness: int = 1) -> None:
    """Arrows of ``length`` metres along +x, +y, +z from ``centre``, labelled, in place, lines
    ``thickness`` pixels wide."""
    height, width = image.shape[:2]
    u0, v0, _, ahead0 = project(centre)
    font_size = max(0.3, min(width, height) / 400)
    for axis, (name, colour) in enumerate(zip("xyz", AXIS_COLOURS, strict=True)):
        u1, v1, _, ahead1 = project(centre + length * np.eye(3)[axis])
        if not (ahead0[0] and ahead1[0]):
            continue
        start = (int(round(u0[0])), int(round(v0[0])))
        end = (int(round(u1[0])), int(round(v1[0])))
        cv2.arrowedLine(image, start, end, colour, thickness, cv2.LINE_8, tipLength=0.25)
        direction = np.array([end[0] - start[0], end[1] - start[1]], np.float64)
        direction /= max(float(np.linalg.norm(direction)), 1e-9)
        (text_w, text_h), _ = cv2.getTextSize(name, cv2.FONT_HERSHEY_SIMPLEX, font_size,
                                              thickness)
        label = (int(round(end[0] + 4 * direction[0] - text_w / 2 + text_w / 2 * direction[0])),
                 int(round(end[1] + 4 * direction[1] + text_h / 2 + text_h / 2 * direction[1])))
        label = (min(max(label[0], 0), width - text_w - 1),           # inside the image
                 min(max(label[1], text_h + 1), height - 2))
        cv2.putText(image, name, label, cv2.FONT_HERSHEY_SIMPLEX, font_size, colour, thickness,
                    cv2.LINE_8)


_TITLE_H = 26
"""Height of a panel's title line, pixels."""
_LEGEND_H = 22
"""Height of the colour-bar line under the panels of a grid that has legends, pixels."""
MIN_PANEL_WIDTH = 320
"""A grid's panels are at least this wide, pixels (smaller images are enlarged)."""
MAX_GRID_WIDTH = 1920
"""A grid is at most this wide (a screen), pixels, unless its panels are then narrower than
:data:`MIN_PANEL_WIDTH`: larger images are reduced, so that titles and legends, drawn at one
size, stay legible when the figure is seen whole (a rig's 1280x720 frames made a 5120 px
overview with 15 px titles)."""


def grid_scale(width: int, columns: int) -> float:
    """The resize factor :func:`panel_grid` gives panels of ``width`` pixels in ``columns``
    columns: up to :data:`MIN_PANEL_WIDTH`, down to :data:`MAX_GRID_WIDTH` / ``columns``
    (not below :data:`MIN_PANEL_WIDTH`), else 1."""
    widest = max(MIN_PANEL_WIDTH, MAX_GRID_WIDTH // max(int(columns), 1))
    if width > widest:
        return widest / width
    return max(1.0, MIN_PANEL_WIDTH / width)


def point_radius(width: int, panel_width: float) -> int:
    """The ``radius`` of :func:`depth_colours` for a sparse map ``width`` pixels wide that a grid
    shows ``panel_width`` pixels wide (``first image's width * grid_scale(...)``): 0 where it is
    not reduced, else half the reduction (rounded up), so that a one-pixel map point stays at
    least a pixel wide in the grid."""
    reduction = width / panel_width
    return 0 if reduction <= 1.0 else int(np.ceil(reduction / 2))


def panel_grid(images: list[np.ndarray], titles: list[str], columns: int = 3,
               scale: float | None = None,
               legends: list[Legend | Swatches | Caption | None] | None = None) -> np.ndarray:
    """Images side by side in a grid, each with its title above it and, optionally, a colour
    bar, swatches or a caption under it.

    Parameters
    ----------
    images : list of (H, W) or (H, W, 3) uint8 ndarrays, all the same size
    titles : list of str
        Written in a smaller font where they would not fit the panel's width.
    columns : int
    scale : float, optional
        Resize factor of every panel (default :func:`grid_scale`: at least 320 px wide, and
        the grid at most 1920 px wide where the panels can stay 320 px wide). Reduced panels
        are area-averaged (draw sparse points larger, :func:`point_radius`).
    legends : list of Legend, Swatches, Caption or None, optional
        One per image: the colour bar, the swatches or the line of text drawn under it (None:
        none). When any is given, every row of the grid gets a legend line.

    Returns
    -------
    (rows * (title + h [+ legend]), columns * w, 3) uint8 ndarray, BGR
    """
    legends = [None] * len(images) if legends is None else list(legends)
    if len(images) != len(titles) or len(images) != len(legends) or not images:
        raise ValueError(f"need one title and one legend (or None) per image, got "
                         f"{len(images)} images, {len(titles)} titles, {len(legends)} legends")
    height, width = images[0].shape[:2]
    scale = scale or grid_scale(width, columns)
    w, h = int(round(width * scale)), int(round(height * scale))
    resize = cv2.INTER_AREA if scale < 1 else cv2.INTER_NEAREST
    legend_h = _LEGEND_H if any(legend is not None for legend in legends) else 0
    row_h = _TITLE_H + h + legend_h
    rows = -(-len(images) // columns)
    canvas = np.full((rows * row_h, columns * w, 3), 255, np.uint8)
    for k, (image, title, legend) in enumerate(zip(images, titles, legends, strict=True)):
        if image.shape[:2] != (height, width):
            image = cv2.resize(image, (width, height), interpolation=cv2.INTER_NEAREST)
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        tile = cv2.resize(image, (w, h), interpolation=resize)
        r, c = divmod(k, columns)
        y0, x0 = r * row_h, c * w
        canvas[y0 + _TITLE_H:y0 + _TITLE_H + h, x0:x0 + w] = tile
        cv2.putText(canvas, title, (x0 + 6, y0 + 18), cv2.FONT_HERSHEY_SIMPLEX,
                    _fitting_size(title, 0.5, w - 12), (0, 0, 0), 1, cv2.LINE_AA)
        strip = canvas[y0 + _TITLE_H + h:y0 + row_h, x0:x0 + w]
        if isinstance(legend, Caption):
            cv2.putText(strip, legend.text, (6, (legend_h + 8) // 2), cv2.FONT_HERSHEY_SIMPLEX,
                        _fitting_size(legend.text, 0.4, w - 12), (0, 0, 0), 1, cv2.LINE_AA)
        elif isinstance(legend, Swatches):
            _draw_swatches(strip, legend.keys)
        elif legend is not None:
            _draw_legend(strip, legend)
    return canvas


def _fitting_size(text: str, size: float, width: int, smallest: float = 0.3) -> float:
    """The largest font scale <= ``size`` (down to ``smallest``) at which ``text`` fits
    ``width`` pixels in OpenCV's simplex font."""
    text_w = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, size, 1)[0][0]
    return size if text_w <= width else max(smallest, size * width / text_w)


def _swatch(strip: np.ndarray, x: int, colour: tuple[int, int, int]) -> None:
    """A 10x10 swatch of ``colour`` outlined in black, its left side at ``x``, centred in the
    strip's height, in place."""
    top = (strip.shape[0] - 10) // 2
    strip[top:top + 10, x:x + 10] = colour
    cv2.rectangle(strip, (x, top), (x + 9, top + 9), (0, 0, 0), 1)


def _draw_swatches(strip: np.ndarray, keys: tuple[tuple[str, tuple[int, int, int]], ...]
                   ) -> None:
    """Draw ``[ ] name  [ ] name ...`` from the left into a white strip, in place."""
    font, size = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    (_, text_h), _ = cv2.getTextSize("0", font, size, 1)
    baseline = (strip.shape[0] + text_h) // 2
    x = 6
    for name, colour in keys:
        _swatch(strip, x, colour)
        cv2.putText(strip, name, (x + 14, baseline), font, size, (0, 0, 0), 1, cv2.LINE_AA)
        x += 14 + cv2.getTextSize(name, font, size, 1)[0][0] + 14


def _end_triangle(strip: np.ndarray, x: int, colour: tuple[int, int, int], left: bool) -> None:
    """A 10 px high, 8 px wide triangle of ``colour``, outlined in black, pointing left (from
    ``x`` to ``x + 7``) or right (from ``x + 7`` back to ``x``), in place: the colour beyond an end
    of a colour bar."""
    top = (strip.shape[0] - 10) // 2
    tip, base = (x, x + 7) if left else (x + 7, x)             # the tip outwards
    corners = np.array([[tip, top + 5], [base, top], [base, top + 9]], np.int32)
    cv2.fillConvexPoly(strip, corners, colour)
    cv2.polylines(strip, [corners], True, (0, 0, 0), 1)


def _draw_legend(strip: np.ndarray, legend: Legend) -> None:
    """Draw ``low [<][colour bar][>] high  [ ] key ...`` into a white (legend_h, w, 3) strip, in
    place; the keys come first, the bar gets what is left (none below 8 px); the triangles
    only where the legend has an ``under`` / ``over`` colour."""
    font, size = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    height, width = strip.shape[:2]
    (_, text_h), _ = cv2.getTextSize("0", font, size, 1)
    baseline = (height + text_h) // 2
    right = width - 6
    for name, colour in reversed(legend.keys):          # right-aligned, in their order
        (name_w, _), _ = cv2.getTextSize(name, font, size, 1)
        cv2.putText(strip, name, (right - name_w, baseline), font, size, (0, 0, 0), 1,
                    cv2.LINE_AA)
        right -= name_w + 4 + 10
        _swatch(strip, right, colour)
        right -= 10
    (low_w, _), _ = cv2.getTextSize(legend.low, font, size, 1)
    (high_w, _), _ = cv2.getTextSize(legend.high, font, size, 1)
    cv2.putText(strip, legend.low, (6, baseline), font, size, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(strip, legend.high, (right - high_w, baseline), font, size, (0, 0, 0), 1,
                cv2.LINE_AA)
    left, right = 6 + low_w + 8, right - high_w - 8
    if right - left < 8 + 18 * ((legend.under is not None) + (legend.over is not None)):
        return
    if legend.under is not None:
        _end_triangle(strip, left, legend.under, left=True)
        left += 10
    if legend.over is not None:
        _end_triangle(strip, right - 8, legend.over, left=False)
        right -= 10
    bar = cv2.resize(np.asarray(legend.colours, np.uint8)[None, :, :], (right - left, 1),
                     interpolation=cv2.INTER_NEAREST)
    top = (height - 10) // 2
    strip[top:top + 10, left:right] = bar


_HEADER_LINE_H = 24
"""Height of a line of :func:`add_header`, pixels."""


def add_header(image: np.ndarray, lines: list[str], colour: tuple[int, int, int] = (0, 0, 200)
               ) -> np.ndarray:
    """The image under a white header of text lines (a warning that belongs to every panel).

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray, BGR
    lines : list of str
        One header line each (none: the image as it is).
    colour : (B, G, R)
        Of the text (default dark red).

    Returns
    -------
    (H + 24 len(lines), W, 3) uint8 ndarray, BGR
    """
    if not lines:
        return image
    header = np.full((_HEADER_LINE_H * len(lines), image.shape[1], 3), 255, np.uint8)
    for k, line in enumerate(lines):
        cv2.putText(header, line, (6, _HEADER_LINE_H * k + 17), cv2.FONT_HERSHEY_SIMPLEX,
                    _fitting_size(line, 0.55, image.shape[1] - 12), colour, 1, cv2.LINE_AA)
    return np.vstack([header, image])


def write_image(path: str | Path, image: np.ndarray) -> Path:
    """Write an image atomically (:func:`sim._atomic.write_bytes_atomically`: to
    ``<name>.partial`` beside it, then renamed); a PNG carries the text chunk
    ``Software: evfuse`` (:func:`sim.image_out.mark_png`).

    Parameters
    ----------
    path : str or Path
        Target file; its extension chooses the format (``.png``).
    image : (H, W) or (H, W, 3) uint8 ndarray, BGR

    Returns
    -------
    Path
    """
    path = Path(path)
    ok, encoded = cv2.imencode(path.suffix, image)       # the bytes cv2.imwrite would write
    if not ok:
        raise OSError(f"cannot write {path}")
    data = encoded.tobytes()
    if path.suffix.lower() == ".png":                    # says evfuse wrote it (--overwrite)
        data = mark_png(data)
    write_bytes_atomically(path, data)
    return path


def fill_figure(result: DenseResult, params: DenseParams) -> np.ndarray:
    """The paper's Figure 2 for one frame, as one image of six panels (``figure.png`` of
    ``evfuse fill``, :func:`fusion.fill.dense.write_fill`)."""
    panels, titles, legends, header = fill_figure_panels(result, params)
    return add_header(panel_grid(panels, titles, columns=3, legends=legends), header)


def fill_figure_panels(result: DenseResult, params: DenseParams
                       ) -> tuple[list[np.ndarray], list[str], list, list[str]]:
    """The panels of Figure 2, their titles, their legends (the depth scale spans the exact
    depth where there is one, and both maps) and the header lines (the oracle warning).

    Panels (b)-(d) show the paper's segmentation; for a method that does not segment the frame
    they say so, and show the pixels it filled and its confidence where it gave one."""
    points, colours, _ = dense_cloud(result)
    size = (result.frame.shape[1], result.frame.shape[0])
    scale = depth_scale(result.sparse, result.dense, truth=result.truth)
    lo_hi = (scale.lo, scale.hi) if scale else (None, None)
    legend = scale.legend() if scale else None
    # a large frame is reduced in the grid: the map's points are drawn that much larger
    radius = point_radius(size[0], size[0] * grid_scale(size[0], 3))
    view, caption = point_cloud_view(points, colours, size, splat=max(2, 2 * radius + 1))
    middle, middle_titles = _segmentation_panels(result, params)
    panels = [depth_colours(result.sparse, *lo_hi, base=result.frame, radius=radius), *middle,
              depth_colours(result.dense, *lo_hi, radius=radius), view]
    titles = [f"(a) frame + {result.n1_in_frame} projected map points", *middle_titles,
              f"(e) range image (N2 = {result.n2})",
              "(f) point cloud: map points red, filled green"]
    header = oracle_header(bool(result.info.get("oracle")))
    return panels, titles, [legend, None, None, None, legend, caption], header


def _segmentation_panels(result: DenseResult, params: DenseParams
                         ) -> tuple[list[np.ndarray], list[str]]:
    """Panels (b)-(d) of Figure 2 and their titles: the raw segmentation, the valid regions and
    the regions to fill; for a method without a segmentation, the frame saying so, the filled
    pixels in green, and the method's confidence (black 0, white 1) or the frame again."""
    if result.regions is not None:
        raw = segment_regions(result.frame, SegmentationParams(params.segmentation.threshold, 1))
        return ([label_colours(raw), label_colours(result.labels),
                 label_colours(result.labels, highlight=result.regions.selected)],
                [f"(b) raw segmentation ({int(raw.max())})",
                 f"(c) valid regions ({result.regions.n_regions})",
                 f"(d) regions to fill ({int(result.regions.selected.sum())})"])
    method = result.method
    filled = (result.dense > 0) & (result.sparse == 0)
    gray = cv2.cvtColor(result.frame, cv2.COLOR_GRAY2BGR)
    if result.confidence is None:
        last, last_title = gray, f"(d) regions to fill: not used by {method}"
    else:
        level = np.round(255 * result.confidence).astype(np.uint8)
        last = cv2.cvtColor(level, cv2.COLOR_GRAY2BGR)
        last_title = f"(d) confidence of {method} (black 0, white 1)"
    return ([gray, highlight_pixels(result.frame, filled), last],
            [f"(b) segmentation: not used by {method}",
             f"(c) pixels filled by {method} ({int(filled.sum())}, green)", last_title])


def fill_error_figure(result: DenseResult) -> np.ndarray:
    """``error.png``: |error| of the dense map with its legend (scale in cm, no value, no
    surface); needs ``result.truth``."""
    image, legend = error_panel(result.dense, result.truth)
    return panel_grid([image], ["|error| of the dense map (map points and filled)"], columns=1,
                      legends=[legend])


def write_event_frame(path: str | Path, frame: np.ndarray, title: str) -> Path:
    """Write an event frame as a titled figure with the polarity legend (``evfuse events
    --out``).

    Parameters
    ----------
    path : str or Path
        PNG to write (atomically, :func:`write_image`).
    frame : (H, W, 3) uint8 ndarray, RGB
        The event frame (:func:`sim.statistics.event_frame`).
    title : str
        Written above the frame.

    Returns
    -------
    Path
        ``path``.
    """
    return write_image(path, panel_grid([cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)], [title],
                                        columns=1, legends=[event_legend()]))
