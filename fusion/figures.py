"""Figures drawn from results: depth in colour, segmentations, point clouds, panels.

Everything returns 8-bit BGR images (``cv2.imwrite`` writes them as they are); nothing here
computes a result, so every figure can be re-drawn from the files a run saved.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fusion.scoring import error_image

__all__ = ["Legend", "depth_colours", "depth_legend", "depth_range", "error_legend",
           "label_colours", "panel_grid", "point_cloud_view", "write_image"]

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
    """

    colours: np.ndarray
    low: str
    high: str


def depth_range(depth: np.ndarray) -> tuple[float, float] | tuple[None, None]:
    """The 1st and 99th percentiles of the valid depths: a colour scale that outliers do not
    squash.

    Parameters
    ----------
    depth : (H, W) float ndarray, metres, 0 where none

    Returns
    -------
    (lo, hi) : floats, metres, or (None, None) when no pixel has a depth
    """
    valid = np.asarray(depth)[np.asarray(depth) > 0]
    if valid.size == 0:
        return None, None
    return float(np.percentile(valid, 1)), float(np.percentile(valid, 99))


def depth_legend(lo: float, hi: float) -> Legend:
    """The legend of :func:`depth_colours` over ``[lo, hi]`` metres (near red, far blue).

    Parameters
    ----------
    lo, hi : float, metres, > 0

    Returns
    -------
    Legend
        256 colours, made by :func:`depth_colours` itself, so that the bar is the scale the
        panel used.
    """
    ramp = depth_colours(np.linspace(lo, hi, 256)[None, :], lo, hi)[0]
    return Legend(ramp, f"{lo:.3g} m", f"{hi:.3g} m")


def error_legend(max_error: float) -> Legend:
    """The legend of :func:`fusion.scoring.error_image` with ``max_error``, labelled in cm.

    Parameters
    ----------
    max_error : float, metres, > 0
        The error shown in the last colour.

    Returns
    -------
    Legend
        256 colours, made by ``error_image`` itself (errors 0 to ``max_error``).
    """
    errors = np.linspace(0.0, max_error, 256)[None, :]
    ramp = error_image(1.0 + errors, np.ones_like(errors), max_error=max_error)[0]
    return Legend(ramp, "0 cm", f"{100 * max_error:.3g} cm")


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


def point_cloud_view(points: np.ndarray, colours: np.ndarray, size: tuple[int, int],
                     yaw_deg: float = 35.0, pitch_deg: float = -20.0) -> np.ndarray:
    """The points seen by a virtual camera turned around their centre, z-buffered splats.

    Parameters
    ----------
    points : (N, 3) float ndarray, metres, camera frame of the reference view
    colours : (N, 3) uint8 ndarray, BGR
    size : (width, height) of the image, pixels
    yaw_deg, pitch_deg : float, degrees
        Rotation of the virtual view about the vertical and horizontal axes through the centre.

    Returns
    -------
    (height, width, 3) uint8 ndarray, BGR (black background)
    """
    width, height = size
    image = np.zeros((height, width, 3), np.uint8)
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return image
    centre = np.median(points, axis=0)
    spread = np.percentile(np.linalg.norm(points - centre, axis=1), 75) + 1e-9
    yaw, pitch = np.radians(yaw_deg), np.radians(pitch_deg)
    r_yaw = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    r_pitch = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)],
                        [0, np.sin(pitch), np.cos(pitch)]])
    local = (points - centre) @ (r_pitch @ r_yaw).T / spread
    z = local[:, 2] + 3.0                                  # the virtual camera 3 spreads away
    ahead = z > 0.1
    focal = 1.1 * min(width, height)
    u = np.round(focal * local[:, 0] / np.where(ahead, z, 1) + width / 2).astype(np.int64)
    v = np.round(focal * local[:, 1] / np.where(ahead, z, 1) + height / 2).astype(np.int64)
    inside = ahead & (u >= 1) & (u < width - 1) & (v >= 1) & (v < height - 1)
    order = np.argsort(-z[inside])                         # far first, near drawn over them
    u, v, c = u[inside][order], v[inside][order], np.asarray(colours)[inside][order]
    for du in (-1, 0):                                     # 2x2 splats
        for dv in (-1, 0):
            image[v + dv, u + du] = c
    return image


_TITLE_H = 26
"""Height of a panel's title line, pixels."""
_LEGEND_H = 22
"""Height of the colour-bar line under the panels of a grid that has legends, pixels."""


def panel_grid(images: list[np.ndarray], titles: list[str], columns: int = 3,
               scale: float | None = None,
               legends: list[Legend | None] | None = None) -> np.ndarray:
    """Images side by side in a grid, each with its title above it and, optionally, a colour
    bar under it.

    Parameters
    ----------
    images : list of (H, W) or (H, W, 3) uint8 ndarrays, all the same size
    titles : list of str
    columns : int
    scale : float, optional
        Resize factor of every panel (default: so that a panel is at least 320 px wide).
    legends : list of Legend or None, optional
        One per image: the colour bar drawn under it (None: none). When any is given, every
        row of the grid gets a legend line.

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
        cv2.putText(canvas, title, (x0 + 6, y0 + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 0, 0), 1, cv2.LINE_AA)
        if legend is not None:
            _draw_legend(canvas[y0 + _TITLE_H + h:y0 + row_h, x0:x0 + w], legend)
    return canvas


def _draw_legend(strip: np.ndarray, legend: Legend) -> None:
    """Draw ``low [colour bar] high`` into a white (legend_h, w, 3) strip, in place."""
    font, size = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    (low_w, text_h), _ = cv2.getTextSize(legend.low, font, size, 1)
    (high_w, _), _ = cv2.getTextSize(legend.high, font, size, 1)
    height, width = strip.shape[:2]
    baseline = (height + text_h) // 2
    cv2.putText(strip, legend.low, (6, baseline), font, size, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(strip, legend.high, (width - 6 - high_w, baseline), font, size, (0, 0, 0), 1,
                cv2.LINE_AA)
    left, right = 6 + low_w + 8, width - 6 - high_w - 8
    if right - left < 8:
        return
    bar = cv2.resize(np.asarray(legend.colours, np.uint8)[None, :, :], (right - left, 1),
                     interpolation=cv2.INTER_NEAREST)
    top = (height - 10) // 2
    strip[top:top + 10, left:right] = bar


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
