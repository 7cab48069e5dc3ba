"""Figures drawn from results: depth in colour, segmentations, point clouds, panels.

Everything returns 8-bit BGR images (``cv2.imwrite`` writes them as they are), with the legend or
caption that reads them; nothing here computes a result, so every figure can be re-drawn from
the files a run saved.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fusion.scoring import ERROR_NO_SURFACE, ERROR_NO_VALUE, error_image

__all__ = ["Caption", "DepthScale", "Legend", "add_header", "depth_colours", "depth_legend",
           "depth_scale", "error_legend", "error_panel", "highlight_pixels", "label_colours",
           "panel_grid", "point_cloud_view", "write_image"]

_NO_VALUE = (40, 40, 40)
"""Colour of pixels without a depth (dark grey, so that black texture stays readable)."""


def depth_colours(depth: np.ndarray, lo: float | None = None, hi: float | None = None,
                  base: np.ndarray | None = None) -> np.ndarray:
    """Depth in colour (near red, far blue; OpenCV's JET on inverse order).

    Parameters
    ----------
    depth : (H, W) float ndarray, metres, 0 where none
    lo, hi : float, metres, optional
        Range of the colour scale (default: the range of the valid depths).
    base : (H, W) uint8 or (H, W, 3) uint8 ndarray, optional
        Image shown where there is no depth (default dark grey).

    Returns
    -------
    (H, W, 3) uint8 ndarray, BGR
    """
    depth = np.asarray(depth, dtype=np.float64)
    valid = depth > 0
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
    colours = cv2.applyColorMap((255 * (1 - scaled)).astype(np.uint8), cv2.COLORMAP_JET)
    out[valid] = colours[valid]
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
    """

    colours: np.ndarray
    low: str
    high: str
    keys: tuple[tuple[str, tuple[int, int, int]], ...] = ()


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
        The depths drawn in the first (red) and last (blue) colour.
    below, above : bool
        Some depth of the maps lies nearer than ``lo`` / farther than ``hi`` and is drawn in the
        end colour: the legend then reads "<= lo" / ">= hi".
    source : str
        ``"exact depth"`` or ``"maps, 1st-99th percentile"``: what the scale spans.
    """

    lo: float
    hi: float
    below: bool = False
    above: bool = False
    source: str = "exact depth"

    def legend(self) -> Legend:
        """:func:`depth_legend` of the scale, its ends marked where depths are clipped."""
        return depth_legend(self.lo, self.hi, below=self.below, above=self.above)


def depth_scale(*maps: np.ndarray | None, truth: np.ndarray | None = None) -> DepthScale | None:
    """One colour scale for the depth panels of a figure: the scene's, not an outlier's.

    With an exact depth the scale spans it (min to max of its surfaces), so that the panels read
    as the scene and a map that misses the far wall does not pull the scale in; without one it
    spans the 1st to 99th percentile of the maps' depths together (:data:`MAP_PERCENTILES`). It is
    widened to at least :data:`MIN_SPAN_SHARE` of its middle depth (a flat scene would otherwise
    have no span). Map depths outside it are drawn in the end colours, and the scale says so
    (``below`` / ``above``), so the legend reads "<=" / ">=" there.

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
    """The legend of :func:`depth_colours` over ``[lo, hi]`` metres (near red, far blue).

    Parameters
    ----------
    lo, hi : float, metres, > 0
    below, above : bool
        Depths beyond an end are drawn in its colour: label it "<= lo" / ">= hi".

    Returns
    -------
    Legend
        256 colours, made by :func:`depth_colours` itself, so that the bar is the scale the
        panel used.
    """
    ramp = depth_colours(np.linspace(lo, hi, 256)[None, :], lo, hi)[0]
    return Legend(ramp, f"{'<= ' if below else ''}{lo:.3g} m",
                  f"{'>= ' if above else ''}{hi:.3g} m")


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


def error_panel(depth: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, Legend]:
    """|depth - truth| in colour, with its legend: the scale ends at the 99th percentile of the
    errors (the larger ones drawn in its last colour, the legend says ``>=``).

    Parameters
    ----------
    depth : (H, W) float ndarray, metres, 0 where no estimate
    truth : (H, W) float ndarray, metres, 0 where no surface

    Returns
    -------
    image : (H, W, 3) uint8 ndarray, BGR, from :func:`fusion.scoring.error_image`
    legend : Legend, from :func:`error_legend`
    """
    depth = np.asarray(depth, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    both = (depth > 0) & (truth > 0)
    errors = np.abs(depth - truth)[both]
    top = float(np.percentile(errors, ERROR_PERCENTILE)) if errors.size else 0.0
    top = top if top > 0 else 1e-3                 # all exact (or none): a 1-mm scale
    clipped = bool((errors > top).any())
    return error_image(depth, truth, max_error=top), error_legend(top, clipped)


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
                     left_deg: float = 30.0, above_deg: float = 20.0, axes: bool = True
                     ) -> tuple[np.ndarray, Caption]:
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
    inside = ahead & (u >= 1) & (u < width - 1) & (v >= 1) & (v < height - 1)
    order = np.argsort(-z[inside])                      # far first, near drawn over them
    u, v, c = u[inside][order], v[inside][order], np.asarray(colours)[inside][order]
    for du in (-1, 0):                                  # 2x2 splats
        for dv in (-1, 0):
            image[v + dv, u + du] = c
    length = _round_length(spread)
    if axes:
        _draw_axes(image, project, centre, length)
    return image, Caption(f"{view} the camera; axes {_metres(length)}")


def _draw_axes(image: np.ndarray, project, centre: np.ndarray, length: float) -> None:
    """Arrows of ``length`` metres along +x, +y, +z from ``centre``, labelled, in place."""
    height, width = image.shape[:2]
    u0, v0, _, ahead0 = project(centre)
    font_size = max(0.3, min(width, height) / 400)
    for axis, (name, colour) in enumerate(zip("xyz", AXIS_COLOURS, strict=True)):
        u1, v1, _, ahead1 = project(centre + length * np.eye(3)[axis])
        if not (ahead0[0] and ahead1[0]):
            continue
        start = (int(round(u0[0])), int(round(v0[0])))
        end = (int(round(u1[0])), int(round(v1[0])))
        cv2.arrowedLine(image, start, end, colour, 1, cv2.LINE_8, tipLength=0.25)
        direction = np.array([end[0] - start[0], end[1] - start[1]], np.float64)
        direction /= max(float(np.linalg.norm(direction)), 1e-9)
        (text_w, text_h), _ = cv2.getTextSize(name, cv2.FONT_HERSHEY_SIMPLEX, font_size, 1)
        label = (int(round(end[0] + 4 * direction[0] - text_w / 2 + text_w / 2 * direction[0])),
                 int(round(end[1] + 4 * direction[1] + text_h / 2 + text_h / 2 * direction[1])))
        label = (min(max(label[0], 0), width - text_w - 1),           # inside the image
                 min(max(label[1], text_h + 1), height - 2))
        cv2.putText(image, name, label, cv2.FONT_HERSHEY_SIMPLEX, font_size, colour, 1,
                    cv2.LINE_8)


_TITLE_H = 26
"""Height of a panel's title line, pixels."""
_LEGEND_H = 22
"""Height of the colour-bar line under the panels of a grid that has legends, pixels."""


def panel_grid(images: list[np.ndarray], titles: list[str], columns: int = 3,
               scale: float | None = None,
               legends: list[Legend | Caption | None] | None = None) -> np.ndarray:
    """Images side by side in a grid, each with its title above it and, optionally, a colour
    bar or a caption under it.

    Parameters
    ----------
    images : list of (H, W) or (H, W, 3) uint8 ndarrays, all the same size
    titles : list of str
        Written in a smaller font where they would not fit the panel's width.
    columns : int
    scale : float, optional
        Resize factor of every panel (default: so that a panel is at least 320 px wide).
    legends : list of Legend, Caption or None, optional
        One per image: the colour bar or the line of text drawn under it (None: none). When
        any is given, every row of the grid gets a legend line.

    Returns
    -------
    (rows * (title + h [+ legend]), columns * w, 3) uint8 ndarray, BGR
    """
    legends = [None] * len(images) if legends is None else list(legends)
    if len(images) != len(titles) or len(images) != len(legends) or not images:
        raise ValueError(f"need one title and one legend (or None) per image, got "
                         f"{len(images)} images, {len(titles)} titles, {len(legends)} legends")
    height, width = images[0].shape[:2]
    scale = scale or max(1.0, 320.0 / width)
    w, h = int(round(width * scale)), int(round(height * scale))
    legend_h = _LEGEND_H if any(legend is not None for legend in legends) else 0
    row_h = _TITLE_H + h + legend_h
    rows = -(-len(images) // columns)
    canvas = np.full((rows * row_h, columns * w, 3), 255, np.uint8)
    for k, (image, title, legend) in enumerate(zip(images, titles, legends, strict=True)):
        if image.shape[:2] != (height, width):
            image = cv2.resize(image, (width, height), interpolation=cv2.INTER_NEAREST)
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        tile = cv2.resize(image, (w, h), interpolation=cv2.INTER_NEAREST)
        r, c = divmod(k, columns)
        y0, x0 = r * row_h, c * w
        canvas[y0 + _TITLE_H:y0 + _TITLE_H + h, x0:x0 + w] = tile
        cv2.putText(canvas, title, (x0 + 6, y0 + 18), cv2.FONT_HERSHEY_SIMPLEX,
                    _fitting_size(title, 0.5, w - 12), (0, 0, 0), 1, cv2.LINE_AA)
        strip = canvas[y0 + _TITLE_H + h:y0 + row_h, x0:x0 + w]
        if isinstance(legend, Caption):
            cv2.putText(strip, legend.text, (6, (legend_h + 8) // 2), cv2.FONT_HERSHEY_SIMPLEX,
                        _fitting_size(legend.text, 0.4, w - 12), (0, 0, 0), 1, cv2.LINE_AA)
        elif legend is not None:
            _draw_legend(strip, legend)
    return canvas


def _fitting_size(text: str, size: float, width: int, smallest: float = 0.3) -> float:
    """The largest font scale <= ``size`` (down to ``smallest``) at which ``text`` fits
    ``width`` pixels in OpenCV's simplex font."""
    text_w = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, size, 1)[0][0]
    return size if text_w <= width else max(smallest, size * width / text_w)


def _draw_legend(strip: np.ndarray, legend: Legend) -> None:
    """Draw ``low [colour bar] high  [ ] key ...`` into a white (legend_h, w, 3) strip, in
    place; the keys come first, the bar gets what is left (none below 8 px)."""
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
        top = (height - 10) // 2
        strip[top:top + 10, right:right + 10] = colour
        cv2.rectangle(strip, (right, top), (right + 9, top + 9), (0, 0, 0), 1)
        right -= 10
    (low_w, _), _ = cv2.getTextSize(legend.low, font, size, 1)
    (high_w, _), _ = cv2.getTextSize(legend.high, font, size, 1)
    cv2.putText(strip, legend.low, (6, baseline), font, size, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(strip, legend.high, (right - high_w, baseline), font, size, (0, 0, 0), 1,
                cv2.LINE_AA)
    left, right = 6 + low_w + 8, right - high_w - 8
    if right - left < 8:
        return
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
    """Write an image atomically: to ``.<name>.partial<ext>`` beside it, then renamed.

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
    partial = path.with_name(f".{path.stem}.partial{path.suffix}")
    if not cv2.imwrite(str(partial), image):
        partial.unlink(missing_ok=True)
        raise OSError(f"cannot write {path}")
    os.replace(partial, path)
    return path
