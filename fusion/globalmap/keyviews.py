"""Key views along a sequence: where the global map places its reference views (EMVS's criteria).

A new key view is taken when the camera has moved ``baseline`` times the depth scale of the last
key view (the median depth of that view's map once it is mapped), or rotated ``angle_deg``
since it, or when the events since it reach ``max_events``. The poses are the sequence's
``groundtruth.txt`` (the poses a map is made with; never the exact trajectory), sampled at the
file's own times: a key view's time is the first pose sample past a threshold.

Each key view maps the events from the previous key view's time to the next one's
(:func:`key_view_windows`; the data's ends for the first and the last).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.validation import ParameterError, check_parameter, positive

__all__ = ["KeyViewParams", "inverse_depth_middle", "key_view_windows", "rotation_angle_deg",
           "select_key_views"]


@dataclass(frozen=True)
class KeyViewParams:
    """When a new key view is taken (EMVS's criteria; any one triggers).

    Attributes
    ----------
    baseline : float
        Camera translation since the last key view that triggers a new one, as a share of that
        key view's depth scale (its map's median depth; before it is mapped, the DSI range's
        middle in inverse depth).
    angle_deg : float, degrees
        Camera rotation since the last key view that triggers a new one.
    max_events : int or None
        Events since the last key view that trigger a new one (None: no event budget).
    """

    baseline: float = 0.1
    angle_deg: float = 10.0
    max_events: int | None = None

    def __post_init__(self) -> None:
        check_parameter(positive, "baseline", self.baseline)
        check_parameter(positive, "angle_deg", self.angle_deg)
        if self.max_events is not None and (isinstance(self.max_events, bool)
                                            or int(self.max_events) != self.max_events
                                            or self.max_events < 1):
            raise ParameterError(f"{{max_events}} must be a whole number >= 1, got "
                                 f"{self.max_events!r}", max_events="max_events")


def inverse_depth_middle(min_depth: float, max_depth: float) -> float:
    """The middle of a depth range in inverse depth, ``2 / (1/min + 1/max)``, metres: the depth
    scale of a key view before its map gives one (the DSI's planes are uniform in inverse depth,
    so this is its middle plane)."""
    return 2.0 / (1.0 / float(min_depth) + 1.0 / float(max_depth))


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle of the relative rotation ``R_a^T R_b``, degrees.

    Parameters
    ----------
    R_a : (3, 3) ndarray
    R_b : (..., 3, 3) ndarray

    Returns
    -------
    (...) float64 ndarray, degrees in [0, 180]
    """
    relative = np.einsum("ji,...jk->...ik", np.asarray(R_a, np.float64),
                         np.asarray(R_b, np.float64))
    cosine = (np.trace(relative, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def select_key_views(times: np.ndarray, poses: np.ndarray, params: KeyViewParams,
                     depth: float | Callable[[float], float],
                     event_times: np.ndarray | None = None) -> list[float]:
    """Times of the key views along sampled poses.

    The first key view is at the first sample; each next one at the first sample after the
    last key view where the camera has moved ``params.baseline * depth(t_last)`` or more, or
    rotated ``params.angle_deg`` or more, or where ``params.max_events`` or more events
    (``event_times``) have come since ``t_last``.

    Parameters
    ----------
    times : (N,) float ndarray, seconds, strictly increasing
        The pose samples' times (e.g. ``groundtruth.txt``'s within the span to map).
    poses : (N, 4, 4) float ndarray
        ``T_world_camera`` at ``times``.
    params : KeyViewParams
    depth : float or callable
        The depth scale of a key view, metres: one value for all, or a function of the key
        view's time (its map's median depth where it is mapped).
    event_times : (M,) float ndarray, seconds, sorted, optional
        Needed with ``params.max_events``.

    Returns
    -------
    list of float, seconds
        Key view times, increasing, each one of ``times``.

    Raises
    ------
    ValueError
        Fewer than one pose, mismatched shapes, a depth scale that is not positive, or
        ``max_events`` without ``event_times``.
    """
    times = np.asarray(times, np.float64).reshape(-1)
    poses = np.asarray(poses, np.float64)
    if len(times) == 0 or poses.shape != (len(times), 4, 4):
        raise ValueError(f"expected N >= 1 times and (N, 4, 4) poses, got {times.shape} and "
                         f"{poses.shape}")
    if params.max_events is not None and event_times is None:
        raise ValueError("an event budget (max_events) needs the event times")
    depth_of = depth if callable(depth) else (lambda _t, d=float(depth): d)
    events = None if event_times is None else np.asarray(event_times, np.float64)
    positions, rotations = poses[:, :3, 3], poses[:, :3, :3]
    keys = [0]
    while True:
        i = keys[-1]
        scale = float(depth_of(float(times[i])))
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"the depth scale of the key view at {times[i]} s is {scale}, "
                             "expected a positive number of metres")
        later = slice(i + 1, None)
        trigger = np.linalg.norm(positions[later] - positions[i], axis=1) >= (
            params.baseline * scale)
        trigger |= rotation_angle_deg(rotations[i], rotations[later]) >= params.angle_deg
        if params.max_events is not None:
            since = (np.searchsorted(events, times[later], side="right")
                     - np.searchsorted(events, times[i], side="right"))
            trigger |= since >= params.max_events
        hits = np.flatnonzero(trigger)
        if len(hits) == 0:
            break
        keys.append(i + 1 + int(hits[0]))
    return [float(times[k]) for k in keys]


def key_view_windows(key_times: list[float], start: float | None = None,
                     end: float | None = None) -> list[tuple[float | None, float | None]]:
    """The event window each key view maps: from the previous key view's time to the next one's.

    Parameters
    ----------
    key_times : list of float, seconds, increasing
    start, end : float or None, seconds
        The window's ends for the first and the last key view (None: the data's).

    Returns
    -------
    list of (t0, t1), one per key view
        A single key view maps ``(start, end)``.
    """
    bounds = [start, *key_times, end]
    return [(bounds[k], bounds[k + 2]) for k in range(len(key_times))]
