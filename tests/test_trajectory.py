"""sim.trajectory: poses, analytic velocities, spline smoothness and groundtruth.txt I/O."""

from __future__ import annotations

import numpy as np
import pytest

from sim.se3 import invert_pose, look_at, make_pose, se3_log, so3_exp, so3_log
from sim.trajectory import (
    HandheldTrajectory,
    LinearTrajectory,
    SampledTrajectory,
    SplineTrajectory,
    read_trajectory,
    sample_times,
    write_trajectory,
)

R0 = look_at([0.0, 0.0, 0.0], [0.2, 1.0, 0.1])


def linear() -> LinearTrajectory:
    return LinearTrajectory([0.1, -0.2, 0.3], [0.5, 0.1, -0.2], R0)


def handheld() -> HandheldTrajectory:
    return HandheldTrajectory(
        R0, [0.0, 0.5, 1.0], [0.02, 0.03, 0.01], [0.05, 0.08, 0.03],
        [0.7, 1.1, 0.5, 0.9, 1.3, 0.6], [0.1, 1.2, 2.3, 3.4, 4.5, 5.6], chirp=0.4,
    )


def spline() -> SplineTrajectory:
    times = np.array([0.0, 0.4, 1.1, 1.5, 2.5])
    positions = [[0.0, 0.0, 0.0], [0.3, 0.1, 0.0], [0.5, 0.5, 0.2], [0.4, 0.9, 0.1],
                 [0.0, 1.2, 0.0]]
    rotations = so3_exp([[0.0, 0.0, 0.0], [0.2, 0.5, -0.1], [0.6, 0.9, 0.3], [0.4, 1.5, 0.2],
                         [-0.2, 2.2, 0.5]])
    return SplineTrajectory(times, make_pose(R0 @ rotations, positions))


def finite_difference_velocity(traj, t: np.ndarray, h: float = 1e-5):
    plus, minus = traj.pose(t + h), traj.pose(t - h)
    v = (plus[:, :3, 3] - minus[:, :3, 3]) / (2 * h)
    w = so3_log(plus[:, :3, :3] @ np.swapaxes(minus[:, :3, :3], 1, 2)) / (2 * h)
    return v, w


@pytest.mark.parametrize("make", [linear, handheld, spline])
def test_analytic_velocities_match_finite_differences(make):
    traj = make()
    t = np.linspace(max(traj.t_start, -1.0) + 0.01, min(traj.t_end, 3.0) - 0.01, 37)
    v, w = traj.velocity(t)
    v_fd, w_fd = finite_difference_velocity(traj, t)
    scale = max(1.0, np.abs(v_fd).max(), np.abs(w_fd).max())
    np.testing.assert_allclose(v, v_fd, atol=1e-7 * scale)
    np.testing.assert_allclose(w, w_fd, atol=1e-7 * scale)
    if make is not linear:
        assert np.abs(w).max() > 0.05  # the check above is not vacuous


@pytest.mark.parametrize("make", [linear, handheld, spline])
def test_poses_are_continuous_rigid_and_shaped(make):
    traj = make()
    t = np.linspace(max(traj.t_start, 0.0), min(traj.t_end, 2.0), 50)
    T = traj.pose(t)
    assert T.shape == (50, 4, 4) and traj.pose(float(t[3])).shape == (4, 4)
    np.testing.assert_allclose(traj.pose(float(t[3])), T[3], atol=1e-15)
    R = T[:, :3, :3]
    np.testing.assert_allclose(np.swapaxes(R, 1, 2) @ R, np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-13)
    np.testing.assert_array_equal(T[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (50, 4)))
    step = traj.pose(t[1:-1] + 1e-9)
    change = np.abs(se3_log(invert_pose(T[1:-1]) @ step)).max()
    assert change < 1e-8


@pytest.mark.parametrize("make", [linear, handheld, spline])
def test_camera_velocity_is_the_world_twist_in_camera_axes(make):
    traj = make()
    t = np.array([0.2, 0.9])
    v, w = traj.velocity(t)
    vc, wc = traj.camera_velocity(t)
    R = traj.pose(t)[:, :3, :3]
    np.testing.assert_allclose((R @ vc[:, :, None])[:, :, 0], v, atol=1e-14)
    np.testing.assert_allclose((R @ wc[:, :, None])[:, :, 0], w, atol=1e-14)
    # Body rate R^T dR/dt = hat(wc) from finite differences.
    h = 1e-5
    Rp, Rm = traj.pose(t + h)[:, :3, :3], traj.pose(t - h)[:, :3, :3]
    body = so3_log(np.swapaxes(Rm, 1, 2) @ Rp) / (2 * h)
    np.testing.assert_allclose(wc, body, atol=1e-7)


def test_linear_trajectory():
    traj = linear()
    T = traj.pose(2.0)
    np.testing.assert_allclose(T[:3, 3], [0.1 + 1.0, -0.2 + 0.2, 0.3 - 0.4], atol=1e-15)
    np.testing.assert_allclose(T[:3, :3], R0, atol=1e-15)
    v, w = traj.velocity(-5.0)
    np.testing.assert_array_equal(v, [0.5, 0.1, -0.2])
    np.testing.assert_array_equal(w, np.zeros(3))
    assert traj.t_start == -np.inf and traj.t_end == np.inf
    with pytest.raises(AttributeError):
        traj.start = np.zeros(3)
    with pytest.raises(ValueError, match="rotation must be rotation matrices"):
        LinearTrajectory([0, 0, 0], [0, 0, 0], 2 * np.eye(3))
    with pytest.raises(ValueError, match="velocity must be 3 finite numbers"):
        LinearTrajectory([0, 0, 0], [0, np.nan, 0], np.eye(3))


def test_handheld_motion_about_the_mean_pose():
    p0 = np.array([1.0, 2.0, 3.0])
    still = HandheldTrajectory(R0, p0, np.zeros(3), np.zeros(3), np.ones(6), np.zeros(6))
    np.testing.assert_allclose(still.pose(7.3), make_pose(R0, p0), atol=1e-15)
    # One translation component along the mean camera's x axis, amplitude 0.1 m, 2 Hz, chirped.
    chirp = 0.5
    traj = HandheldTrajectory(R0, p0, [0.1, 0.0, 0.0], np.zeros(3), [2.0, 1, 1, 1, 1, 1],
                              [0.3, 0, 0, 0, 0, 0], chirp=chirp)
    t = 0.37
    phase = 2 * np.pi * 2.0 * (t + chirp * t * t / 2) + 0.3
    np.testing.assert_allclose(traj.pose(t)[:3, 3], p0 + 0.1 * np.sin(phase) * R0[:, 0],
                               atol=1e-15)
    # Speed at the zero crossings grows as the instantaneous frequency f (1 + chirp t).
    crossings = (np.arange(1, 6) * np.pi - 0.3) / (2 * np.pi * 2.0)  # of the un-chirped phase
    times = (-1 + np.sqrt(1 + 2 * chirp * crossings)) / chirp  # solve t + chirp t^2 / 2 = c
    speed = np.linalg.norm(traj.velocity(times)[0], axis=1)
    np.testing.assert_allclose(speed, 0.1 * 2 * np.pi * 2.0 * (1 + chirp * times), rtol=1e-12)
    with pytest.raises(ValueError, match="chirp must be a finite number >= 0"):
        HandheldTrajectory(R0, p0, np.zeros(3), np.zeros(3), np.ones(6), np.zeros(6), -1.0)
    with pytest.raises(ValueError, match="frequencies must be 6 finite numbers"):
        HandheldTrajectory(R0, p0, np.zeros(3), np.zeros(3), np.ones(5), np.zeros(6))


def test_spline_interpolates_the_keyframes_exactly():
    traj = spline()
    np.testing.assert_allclose(traj.pose(traj.times), traj.poses, atol=1e-12)
    assert (traj.t_start, traj.t_end) == (0.0, 2.5)


def test_spline_is_c2_across_keyframes():
    traj = spline()
    h, d = 1e-4, 2e-3

    def acceleration(t):
        p = traj.pose(np.array([t - h, t, t + h]))[:, :3, 3]
        return (p[0] - 2 * p[1] + p[2]) / h**2

    def angular_acceleration(t):
        return (traj.velocity(t + h)[1] - traj.velocity(t - h)[1]) / (2 * h)

    for knot in traj.times[1:-1]:
        # Across a knot the acceleration changes only by O(d) (jerk x 2d), exactly as it does
        # over the same interval inside a span; a C1-only spline would jump by O(1) here.
        inside = knot + 0.1
        for acc in (acceleration, angular_acceleration):
            across = np.linalg.norm(acc(knot + d) - acc(knot - d))
            within = np.linalg.norm(acc(inside + d) - acc(inside - d))
            size = np.linalg.norm(acc(knot - d))
            assert size > 0.5  # the motion does accelerate here
            assert across < 0.05 * size and across < 10 * within + 1e-3


def test_spline_has_natural_ends_and_reproduces_uniform_motion():
    # The natural cubic spline reproduces linear data: keyframes of a camera moving at constant
    # speed and turning at a constant rate (120 deg between keyframes, 600 deg in all) give
    # exactly that motion between the keyframes too.
    times = np.arange(6.0) * 0.5
    rate = np.radians(120) / 0.5
    axis = np.array([0.0, 0.6, 0.8])
    poses = make_pose(R0 @ so3_exp(times[:, None] * rate * axis), times[:, None] * [1.0, 2.0, 0])
    traj = SplineTrajectory(times, poses)
    t = np.linspace(0.0, 2.5, 41)
    np.testing.assert_allclose(traj.pose(t)[:, :3, 3], t[:, None] * [1.0, 2.0, 0], atol=1e-12)
    np.testing.assert_allclose(traj.pose(t)[:, :3, :3], R0 @ so3_exp(t[:, None] * rate * axis),
                               atol=1e-10)
    np.testing.assert_allclose(traj.camera_velocity(t)[1], np.broadcast_to(rate * axis, (41, 3)),
                               atol=1e-9)


def test_spline_through_two_keyframes_is_a_straight_constant_rate_move():
    T0 = make_pose(np.eye(3), [0.0, 0.0, 0.0])
    T1 = make_pose(so3_exp([0.0, 0.0, 1.0]), [1.0, 2.0, 3.0])
    traj = SplineTrajectory([1.0, 3.0], np.stack([T0, T1]))
    T = traj.pose(2.5)
    np.testing.assert_allclose(T[:3, 3], [0.75, 1.5, 2.25], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], so3_exp([0.0, 0.0, 0.75]), atol=1e-12)


def test_spline_rejects_bad_keyframes():
    poses = np.stack([np.eye(4)] * 3)
    with pytest.raises(ValueError, match="strictly increasing"):
        SplineTrajectory([0.0, 1.0, 1.0], poses)
    with pytest.raises(ValueError, match="at least 2"):
        SplineTrajectory([0.0], poses[:1])
    with pytest.raises(ValueError, match=r"one per pose"):
        SplineTrajectory([0.0, 1.0], poses)


def test_sampled_trajectory_reproduces_the_sampled_motion():
    source = handheld()
    times = sample_times(0.0, 2.0, 1000.0)
    traj = SampledTrajectory(times, source.pose(times))
    np.testing.assert_allclose(traj.pose(times), source.pose(times), atol=1e-14)
    t = np.random.default_rng(2).uniform(0.0, 2.0, 5000)
    T, T_true = traj.pose(t), source.pose(t)
    # Interpolating between samples dt apart errs by at most dt^2 / 8 * max |acceleration|
    # (and the velocity by dt / 2 * max |acceleration|); accelerations from second differences.
    dt = times[1] - times[0]
    v_grid, w_grid = source.velocity(times)
    acc = np.linalg.norm(np.diff(v_grid, axis=0), axis=1).max() / dt
    alpha = np.linalg.norm(np.diff(w_grid, axis=0), axis=1).max() / dt
    assert np.abs(T[:, :3, 3] - T_true[:, :3, 3]).max() < 1.2 * dt**2 / 8 * acc
    turn = np.linalg.norm(so3_log(np.swapaxes(T[:, :3, :3], 1, 2) @ T_true[:, :3, :3]), axis=1)
    assert turn.max() < 1.2 * dt**2 / 8 * alpha
    v, w = traj.velocity(t)
    v_true, w_true = source.velocity(t)
    assert np.linalg.norm(v - v_true, axis=1).max() < 1.2 * dt / 2 * acc
    assert np.linalg.norm(w - w_true, axis=1).max() < 1.2 * dt / 2 * alpha


def test_sampled_velocity_is_the_segment_twist():
    T0 = make_pose(np.eye(3), [0.0, 0.0, 0.0])
    T1 = make_pose(so3_exp([0.0, 0.0, np.pi / 2]), [1.0, 1.0, 0.0])
    traj = SampledTrajectory([0.0, 2.0], np.stack([T0, T1]))
    xi = se3_log(T1)
    t = np.array([0.0, 0.5, 1.3, 2.0])
    vc, wc = traj.camera_velocity(t)
    np.testing.assert_allclose(vc, np.broadcast_to(xi[:3] / 2.0, (4, 3)), atol=1e-14)
    np.testing.assert_allclose(wc, np.broadcast_to([0.0, 0.0, np.pi / 4], (4, 3)), atol=1e-14)
    # Halfway in time, halfway through the quarter turn.
    np.testing.assert_allclose(traj.pose(1.0)[:3, :3], so3_exp([0.0, 0.0, np.pi / 4]),
                               atol=1e-15)


@pytest.mark.parametrize("make", [spline, lambda: SampledTrajectory([0.5, 1.0],
                                                                     np.stack([np.eye(4)] * 2))])
def test_times_outside_the_range_are_rejected(make):
    traj = make()
    bad = traj.t_end + 0.001
    with pytest.raises(ValueError, match=rf"time {bad!r} s is outside .*\[{traj.t_start!r}, "
                                         rf"{traj.t_end!r}\]"):
        traj.pose(np.array([traj.t_start, bad]))
    with pytest.raises(ValueError, match="outside"):
        traj.velocity(traj.t_start - 1.0)
    with pytest.raises(ValueError, match="outside"):
        linear().pose(np.nan)


@pytest.mark.parametrize("fmt", ["ecd", "tum"])
def test_file_round_trip(tmp_path, fmt):
    source = handheld()
    times = 1.4e9 + sample_times(0.0, 0.5, 200.0) if fmt == "tum" else sample_times(0, 0.5, 200)
    poses = source.pose(times - times[0])
    path = tmp_path / "groundtruth.txt"
    write_trajectory(path, times, poses, format=fmt)
    lines = path.read_text().splitlines()
    assert (lines[0] == "# timestamp tx ty tz qx qy qz qw") == (fmt == "tum")
    assert len(lines) == len(times) + (fmt == "tum")
    first = lines[-1].split()
    assert len(first) == 8 and len(first[0].split(".")[1]) == 9  # nanosecond times
    traj = read_trajectory(path)
    np.testing.assert_allclose(traj.times, times, rtol=0, atol=1e-9 * max(1, times[0] / 1e7))
    np.testing.assert_allclose(traj.poses, poses, rtol=0, atol=1e-9)


def test_written_quaternions_are_scalar_last_with_nonnegative_w(tmp_path):
    path = tmp_path / "groundtruth.txt"
    poses = make_pose(so3_exp([[0.0, 0.0, np.pi / 2], [0.0, 0.0, -np.pi / 2]]), np.zeros((2, 3)))
    write_trajectory(path, [0.0, 1.0], poses)
    rows = np.loadtxt(path)
    s = np.sqrt(0.5)
    np.testing.assert_allclose(rows[:, 4:], [[0.0, 0.0, s, s], [0.0, 0.0, -s, s]], atol=1e-15)
    with pytest.raises(ValueError, match="format must be 'ecd' or 'tum'"):
        write_trajectory(path, [0.0, 1.0], poses, format="kitti")
    with pytest.raises(ValueError, match="nanosecond"):
        write_trajectory(path, [0.0, 1e-10], poses)


def test_comments_and_blank_lines_are_skipped(tmp_path):
    path = tmp_path / "traj.txt"
    path.write_text("# TUM\n\n0.0 1 2 3 0 0 0 1\n# mid\n1.0 1 2 4 0 0 1 1\n   \n")
    traj = read_trajectory(path)
    np.testing.assert_array_equal(traj.times, [0.0, 1.0])
    np.testing.assert_allclose(traj.pose(1.0), make_pose(so3_exp([0, 0, np.pi / 2]), [1, 2, 4]),
                               atol=1e-15)


@pytest.mark.parametrize(
    ("body", "line", "message"),
    [
        ("0.0 1 2 3 0 0 0 1\n1.0 1 2 3 0 0 1\n", 2, "expected 't px py pz qx qy qz qw'"),
        ("# c\n0.0 1 2 3 0 0 0 1\n1.0 1 2 x 0 0 0 1\n", 3, "'x' is not a number"),
        ("0.0 1 2 3 0 0 0 1\n1.0 1 2 inf 0 0 0 1\n", 2, "not finite"),
        ("0.0 1 2 3 0 0 0 1\n\n1.0 1 2 3 0 0 0 0\n", 3, "quaternion .* is zero"),
        ("0.0 1 2 3 0 0 0 1\n0.0 1 2 3 0 0 0 1\n", 2, "not after .* strictly increasing"),
    ],
)
def test_malformed_trajectory_files_name_the_line(tmp_path, body, line, message):
    path = tmp_path / "groundtruth.txt"
    path.write_text(body)
    with pytest.raises(ValueError, match=message) as info:
        read_trajectory(path)
    assert str(info.value).startswith(f"{path}:{line}: ")


def test_too_short_trajectory_file(tmp_path):
    path = tmp_path / "groundtruth.txt"
    path.write_text("# only one\n0.0 1 2 3 0 0 0 1\n")
    with pytest.raises(ValueError, match="found 1 pose.*at least 2"):
        read_trajectory(path)


def test_real_ecd_groundtruth_loads(ecd_slider):
    traj = read_trajectory(ecd_slider / "groundtruth.txt")
    assert len(traj.times) == 339
    assert traj.t_start == 0.022291582
    np.testing.assert_allclose(traj.poses[0], make_pose(np.eye(3), [0.1116875, 0.0, 0.0]))
    # A linear slider: it moves along x only, mostly forwards, with a fixed orientation.
    v, w = traj.velocity(np.linspace(traj.t_start, traj.t_end, 50))
    assert np.median(v[:, 0]) > 0.1 and np.abs(v[:, 1:]).max() < 1e-9 and np.abs(w).max() < 1e-9


def test_sample_times():
    t = sample_times(0.0, 1.0, 200.0)
    assert len(t) == 201 and t[0] == 0.0 and t[-1] == 1.0
    np.testing.assert_allclose(np.diff(t), 0.005)
    t = sample_times(0.5, 0.5123, 200.0)
    assert t[0] == 0.5 and t[-1] == 0.5123 and len(t) == 4 and np.diff(t).max() <= 0.005
    np.testing.assert_array_equal(sample_times(2.0, 2.0, 100.0), [2.0])
    with pytest.raises(ValueError, match="t1 >= t0"):
        sample_times(1.0, 0.0, 10.0)
    with pytest.raises(ValueError, match="rate must be"):
        sample_times(0.0, 1.0, 0.0)
