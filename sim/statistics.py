"""Figures of an event stream and of frames: counts, rates, polarity balance, the event frame,
and the noise of a frame's flat areas; and the reading of a recording's events for them
(:func:`read_recording`, :func:`recording_stats`).

The one place where evfuse summarises a recording, simulated or real, so that a twin and its
recording are compared with the same numbers (``evfuse events --stats --compare``).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from sim.eventio import check_events, check_time_units, read_events
from sim.sequence import Sequence, load_sequence
from sim.trajectory import read_trajectory

__all__ = ["OFF_COLOUR", "ON_COLOUR", "compare_stats", "event_frame", "event_stats",
           "events_file", "first_seconds", "frame_noise", "read_gray", "read_recording",
           "recording_stats"]

EVENT_FILES = ("events.h5", "events.txt")
"""The event files of a sequence folder, the one read first."""


def event_stats(events: np.ndarray, width: int, height: int) -> dict[str, int | float]:
    """Summary figures of an event stream.

    Parameters
    ----------
    events : (N,) EVENT_DTYPE ndarray
        Valid events (checked with :func:`check_events`) inside a ``width`` x ``height`` sensor.
    width, height : int
        Sensor size in pixels.

    Returns
    -------
    dict
        In this order:

        - ``count`` (int): N.
        - ``t_first_s``, ``t_last_s`` (float, s): first and last time (0.0 when N = 0).
        - ``duration_s`` (float, s): last minus first time.
        - ``rate_ev_per_s`` (float): N / duration (0.0 when the duration is 0).
        - ``on``, ``off`` (int): ON and OFF counts; ``on_fraction`` (float): on / N (0.0 when
          N = 0).
        - ``active_pixels`` (int): pixels with at least one event.
        - ``events_per_pixel_mean`` (float): N / (width * height), over all pixels.
        - ``events_per_pixel_max`` (int): the busiest pixel's count.
        - ``hot_pixel_threshold`` (float): 10 x the median count of the active pixels.
        - ``hot_pixels`` (int): pixels whose count exceeds that threshold.

    Raises
    ------
    ValueError
        As :func:`check_events`.
    """
    check_events(events, width, height)
    count = int(events.size)
    counts = np.bincount(events["y"].astype(np.int64) * width + events["x"],
                         minlength=width * height)
    active = counts[counts > 0]
    threshold = 10.0 * float(np.median(active)) if active.size else 0.0
    on = int(np.count_nonzero(events["p"] > 0))
    t_first = int(events["t"][0]) if count else 0
    t_last = int(events["t"][-1]) if count else 0
    duration = (t_last - t_first) / 1e9
    return {
        "count": count,
        "t_first_s": t_first / 1e9,
        "t_last_s": t_last / 1e9,
        "duration_s": duration,
        "rate_ev_per_s": count / duration if duration > 0 else 0.0,
        "on": on,
        "off": count - on,
        "on_fraction": on / count if count else 0.0,
        "active_pixels": int(active.size),
        "events_per_pixel_mean": count / (width * height),
        "events_per_pixel_max": int(counts.max()) if counts.size else 0,
        "hot_pixel_threshold": threshold,
        "hot_pixels": int(np.count_nonzero(counts > threshold)) if active.size else 0,
    }


ON_COLOUR = (255, 0, 0)
"""RGB of a pixel whose latest event is ON in :func:`event_frame` (red)."""
OFF_COLOUR = (0, 0, 255)
"""RGB of a pixel whose latest event is OFF in :func:`event_frame` (blue)."""


def event_frame(events: np.ndarray, width: int, height: int,
                background: str = "white") -> np.ndarray:
    """The classic event frame: each pixel coloured by the polarity of its latest event.

    Parameters
    ----------
    events : (N,) EVENT_DTYPE ndarray
        Valid, time-sorted events inside the sensor.
    width, height : int
        Sensor size in pixels.
    background : {"white", "black"}
        Colour of pixels without events: (255, 255, 255) or (0, 0, 0).

    Returns
    -------
    (H, W, 3) uint8 ndarray, RGB
        ON (latest event +1): pure red :data:`ON_COLOUR` (255, 0, 0); OFF (latest event -1):
        pure blue :data:`OFF_COLOUR` (0, 0, 255); no event: the background. As DSEC's
        visualisation, the latest event of a pixel wins. Convert to BGR before
        ``cv2.imwrite``.

    Raises
    ------
    ValueError
        Unknown background, or as :func:`check_events`.
    """
    backgrounds = {"white": 255, "black": 0}
    if background not in backgrounds:
        raise ValueError(f"event_frame: background must be one of {sorted(backgrounds)}, got "
                         f"{background!r}")
    check_events(events, width, height)
    frame = np.full((height, width, 3), backgrounds[background], dtype=np.uint8)
    if not events.size:
        return frame
    flat = events["y"].astype(np.int64) * width + events["x"]
    # The latest event of each pixel: the first occurrence in the reversed stream.
    pixels, first_reversed = np.unique(flat[::-1], return_index=True)
    latest = events["p"][events.size - 1 - first_reversed]
    colours = np.where((latest > 0)[:, None], np.array(ON_COLOUR, np.uint8),
                       np.array(OFF_COLOUR, np.uint8))
    frame.reshape(-1, 3)[pixels] = colours
    return frame


_NOISE_KERNEL = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float64)
"""Immerkaer's operator: the difference of two Laplacians, blind to any plane and to most of
a smooth image, with sum of squares 36 (so a pixel's white noise of sigma gives sigma * 6)."""


def frame_noise(frame: np.ndarray, edge_share: float = 0.1) -> float:
    """Standard deviation of a frame's white noise, measured in its flat areas.

    Immerkaer's estimator (J. Immerkaer, "Fast noise variance estimation", CVIU 64(2), 1996),
    restricted to the pixels away from edges as Tai and Yang do ("A fast method for image noise
    estimation using Laplacian operator and adaptive edge detection", ISCCSP 2008): the
    ``edge_share`` of the interior pixels with the strongest Sobel gradient are left out, and
    ``sigma = sqrt(pi / 2) / 6 * mean(|I * N|)`` over the rest. Unbiased for white Gaussian
    noise on a piecewise smooth image (the mean of ``|X|`` for ``X ~ N(0, 36 sigma^2)`` is
    ``6 sigma sqrt(2 / pi)``); clipped pixels (0 or 255 in an 8-bit frame) are left out too.

    Parameters
    ----------
    frame : (H, W) ndarray, gray levels
        At least 3 x 3 pixels.
    edge_share : float
        Share of the pixels, strongest gradient first, left out as edges (default 0.1).

    Returns
    -------
    float, gray levels
    """
    image = np.asarray(frame, np.float64)
    if image.ndim != 2 or min(image.shape) < 3:
        raise ValueError(f"frame_noise: expected a 2-D frame of at least 3x3 pixels, got shape "
                         f"{image.shape}")
    if not 0 <= edge_share < 1:
        raise ValueError(f"frame_noise: edge_share must be in [0, 1), got {edge_share}")
    response = np.abs(cv2.filter2D(image, -1, _NOISE_KERNEL, borderType=cv2.BORDER_REFLECT))
    gradient = np.hypot(cv2.Sobel(image, cv2.CV_64F, 1, 0), cv2.Sobel(image, cv2.CV_64F, 0, 1))
    inner = (slice(1, -1), slice(1, -1))
    response, gradient = response[inner], gradient[inner]
    keep = gradient <= np.quantile(gradient, 1 - edge_share) if edge_share else \
        np.ones_like(gradient, bool)
    if np.issubdtype(np.asarray(frame).dtype, np.integer):
        # Clipped pixels (at the type's range) carry no noise: leave out their 3x3 neighbours.
        info = np.iinfo(np.asarray(frame).dtype)
        low = cv2.erode(image, np.ones((3, 3)))[inner]
        high = cv2.dilate(image, np.ones((3, 3)))[inner]
        keep &= (low > info.min) & (high < info.max)
    if not keep.any():
        return float("nan")
    return float(math.sqrt(math.pi / 2) / 6 * response[keep].mean())


def compare_stats(first: dict, second: dict) -> list[tuple[str, object, object, float | None]]:
    """The figures of two recordings side by side, with their ratio.

    Parameters
    ----------
    first, second : dict
        Figures by name (e.g. :func:`event_stats` plus ``frame_noise``).

    Returns
    -------
    list of (name, first value, second value, second / first or None)
        For every name in ``first`` (in its order) that ``second`` has too; the ratio is None
        where it is not a number or ``first`` is 0.
    """
    rows = []
    for name, a in first.items():
        if name not in second:
            continue
        b = second[name]
        numeric = isinstance(a, (int, float)) and isinstance(b, (int, float))
        ratio = b / a if numeric and a and math.isfinite(a) and math.isfinite(b) else None
        rows.append((name, a, b, ratio))
    return rows


def read_gray(path: str | Path) -> np.ndarray:
    """A gray 8-bit image.

    Parameters
    ----------
    path : str or Path
        Any image file OpenCV reads (a frame, a PNG).

    Returns
    -------
    (H, W) uint8 ndarray

    Raises
    ------
    ValueError
        ``PATH: not a readable image``.
    """
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    return image


def events_file(folder: str | Path) -> Path:
    """The event file of a sequence folder: ``events.h5``, else ``events.txt``.

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        Neither file is in ``folder``.
    """
    folder = Path(folder)
    for name in EVENT_FILES:
        if (folder / name).is_file():
            return folder / name
    raise ValueError(f"{folder}: no events.h5 or events.txt in this folder")


def read_recording(folder: str | Path) -> tuple[Sequence, Path, np.ndarray]:
    """A sequence folder's sequence, event file and events.

    Parameters
    ----------
    folder : str or Path
        A sequence folder (simulated or an Event-Camera Dataset recording) with an event file
        (:func:`events_file`).

    Returns
    -------
    sequence : Sequence
        :func:`sim.sequence.load_sequence` of ``folder``.
    path : Path
        The event file read.
    events : (N,) EVENT_DTYPE ndarray
        Its events, checked against the sensor size.

    Raises
    ------
    ValueError
        No event file, an unreadable one, or event times in another unit than the poses'
        (:func:`sim.eventio.check_time_units`).
    """
    folder = Path(folder)
    sequence = load_sequence(folder)
    path = events_file(folder)
    events = read_events(path, sequence.camera.width, sequence.camera.height)
    if len(events) and sequence.groundtruth_path is not None:      # times in the wrong unit
        poses = read_trajectory(sequence.groundtruth_path)
        check_time_units(path, events["t"][0] * 1e-9, events["t"][-1] * 1e-9, poses.t_start,
                         poses.t_end)
    return sequence, path, events


def recording_stats(sequence: Sequence, events: np.ndarray, frames: int = 10) -> dict:
    """A recording's figures: :func:`event_stats` plus ``frame_noise``.

    Parameters
    ----------
    sequence : Sequence
        The recording (its sensor size and frames).
    events : (N,) EVENT_DTYPE ndarray
        Its events.
    frames : int
        How many of its first frames ``frame_noise`` is measured on (default 10).

    Returns
    -------
    dict
        :func:`event_stats`' figures, then ``frame_noise`` (gray levels, the median of
        :func:`frame_noise` over those frames; NaN without frames).
    """
    stats = event_stats(events, sequence.camera.width, sequence.camera.height)
    noise = [frame_noise(read_gray(p)) for p in list(sequence.image_paths)[:frames]]
    stats["frame_noise"] = float(np.median(noise)) if noise else float("nan")
    return stats


def first_seconds(events: np.ndarray, seconds: float | None) -> np.ndarray:
    """The events of the first ``seconds`` of a stream (from its first event's time).

    Parameters
    ----------
    events : (N,) EVENT_DTYPE ndarray
        Time-sorted events, ``t`` in ns.
    seconds : float or None, s
        None: all of them.

    Returns
    -------
    (M,) EVENT_DTYPE ndarray
        Those with ``t < t_first + seconds``.
    """
    if seconds is None or not len(events):
        return events
    t_end = int(events["t"][0] + seconds * 1e9)
    return events[events["t"] < t_end]
