"""Key-view selection (fusion.globalmap.keyviews) on synthetic trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.globalmap.keyviews import (
    KeyViewParams,
    inverse_depth_middle,
    key_view_windows,
    rotation_angle_deg,
    select_key_views,
)
from sim.validation import ParameterError


def _translation(length: float, samples: int = 2001) -> tuple[np.ndarray, np.ndarray]:
    """Poses sliding ``length`` m along x in 1 s, no rotation."""
    times = np.linspace(0.0, 1.0, samples)
    poses = np.tile(np.eye(4), (samples, 1, 1))
    poses[:, 0, 3] = length * times
    return times, poses


def _rotation(degrees: float, samples: int = 2001) -> tuple[np.ndarray, np.ndarray]:
    """Poses turning ``degrees`` about the camera's y axis in 1 s, not moving."""
    times = np.linspace(0.0, 1.0, samples)
    angle = np.radians(degrees) * times
    poses = np.tile(np.eye(4), (samples, 1, 1))
    poses[:, 0, 0] = poses[:, 2, 2] = np.cos(angle)
    poses[:, 0, 2], poses[:, 2, 0] = np.sin(angle), -np.sin(angle)
    return times, poses


@pytest.mark.parametrize("length, baseline, depth", [(1.0, 0.1, 1.0), (0.6, 0.05, 2.0),
                                                      (0.3, 0.2, 0.5)])
def test_pure_translation_takes_one_key_view_per_baseline(length, baseline, depth):
    times, poses = _translation(length)
    keys = select_key_views(times, poses, KeyViewParams(baseline=baseline, angle_deg=90.0),
                            depth)
    expected = length / (baseline * depth)          # key views after the first
    assert abs((len(keys) - 1) - expected) <= 1
    # each new key view lies a baseline (to one sample) from the last
    steps = np.diff(np.interp(keys, times, poses[:, 0, 3]))
    assert np.all(steps >= baseline * depth - 1e-12)
    assert np.all(steps <= baseline * depth + length / (len(times) - 1) + 1e-12)


def test_pure_rotation_triggers_by_angle():
    times, poses = _rotation(45.0)
    keys = select_key_views(times, poses, KeyViewParams(baseline=0.1, angle_deg=10.0), 1.0)
    assert len(keys) == 5                            # 0, 10, 20, 30, 40 degrees
    angles = rotation_angle_deg(poses[0, :3, :3],
                                poses[np.searchsorted(times, keys), :3, :3])
    # each key view lies at most one sample (45/2000 degrees) past its threshold
    assert np.all(np.diff(angles) >= 10.0 - 1e-9)
    assert np.all(np.diff(angles) <= 10.0 + 45.0 / 2000 + 1e-9)


def test_rotation_angle_is_the_relative_rotation():
    _, poses = _rotation(30.0, samples=3)
    assert rotation_angle_deg(poses[1, :3, :3], poses[2, :3, :3]) == pytest.approx(15.0)


def test_event_budget_triggers_a_still_camera():
    times, poses = _translation(0.0)
    events = np.linspace(0.0, 1.0, 10_000, endpoint=False)          # 10 kev/s
    keys = select_key_views(times, poses, KeyViewParams(max_events=2500), 1.0,
                            event_times=events)
    np.testing.assert_allclose(keys, [0.0, 0.25, 0.5, 0.75], atol=1e-3)
    assert select_key_views(times, poses, KeyViewParams(), 1.0) == [0.0]   # no budget
    with pytest.raises(ValueError, match="event times"):
        select_key_views(times, poses, KeyViewParams(max_events=10), 1.0)


def test_depth_scale_per_key_view():
    """The next key view is a baseline of the last key view's own depth scale away."""
    times, poses = _translation(1.0)
    keys = select_key_views(times, poses, KeyViewParams(baseline=0.1, angle_deg=90.0),
                            lambda t: 1.0 if t < 0.5 else 3.0)
    x = np.interp(keys, times, poses[:, 0, 3])
    before, after = np.diff(x[x <= 0.5]), np.diff(x[x >= 0.5])
    np.testing.assert_allclose(before, 0.1, atol=1e-3)
    np.testing.assert_allclose(after[1:], 0.3, atol=1e-3)


def test_parameters_are_checked_and_named():
    with pytest.raises(ParameterError, match="baseline"):
        KeyViewParams(baseline=0.0)
    with pytest.raises(ParameterError, match="max_events"):
        KeyViewParams(max_events=0)
    times, poses = _translation(1.0)
    with pytest.raises(ValueError, match="depth scale"):
        select_key_views(times, poses, KeyViewParams(), 0.0)


def test_windows_span_the_neighbours_and_inverse_depth_middle():
    assert key_view_windows([1.0, 2.0, 3.0], 0.5, 3.5) == [(0.5, 2.0), (1.0, 3.0),
                                                            (2.0, 3.5)]
    assert key_view_windows([1.0]) == [(None, None)]
    assert inverse_depth_middle(0.5, 2.0) == pytest.approx(0.8)
