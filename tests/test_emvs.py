"""EMVS disparity space image: rays, planes, and depth recovered from synthetic events."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.map.emvs import DSIParams, depth_planes, disparity_space_image, ray_coefficients
from sim.camera import Camera
from sim.se3 import make_pose, so3_exp
from sim.trajectory import LinearTrajectory


def _point_events(points_world: np.ndarray, trajectory, times: np.ndarray):
    """Analytic events of static points seen along ``trajectory``: each point's normalized
    coordinates (N K, 2) at each of the ``times`` (K,), and their times (N K,)."""
    xy, t_all = [], []
    for t in times:
        T = trajectory.pose(t)
        local = (points_world - T[:3, 3]) @ T[:3, :3]
        xy.append(local[:, :2] / local[:, 2:3])
        t_all.append(np.full(len(points_world), t))
    return np.concatenate(xy), np.concatenate(t_all)


def test_planes_are_uniform_in_inverse_depth():
    z = depth_planes(DSIParams(0.5, 4.0, planes=8))
    assert z[0] == pytest.approx(0.5) and z[-1] == pytest.approx(4.0)
    np.testing.assert_allclose(np.diff(1 / z), np.diff(1 / z)[0])


@pytest.mark.parametrize("low, high", [(0.0, 1.0), (2.0, 1.0), (-1.0, 3.0), (1.0, np.inf)])
def test_bad_depth_range_is_refused(low, high):
    with pytest.raises(ValueError, match="depth range"):
        DSIParams(low, high)


def test_ray_meets_each_plane_where_geometry_says():
    rng = np.random.default_rng(0)
    T = make_pose(so3_exp([0.05, -0.1, 0.02]), [0.1, -0.05, 0.2])
    xy = rng.uniform(-0.4, 0.4, (20, 2))
    coeffs = ray_coefficients(xy, T)
    for z in (0.7, 1.3, 3.0):
        d = np.concatenate([xy, np.ones((20, 1))], 1) @ T[:3, :3].T
        s = (z - T[2, 3]) / d[:, 2]
        point = T[:3, 3] + s[:, None] * d                 # on the plane Z = z, ref frame
        np.testing.assert_allclose(coeffs[:, 0] + coeffs[:, 1] / z, point[:, 0] / z, atol=1e-12)
        np.testing.assert_allclose(coeffs[:, 2] + coeffs[:, 3] / z, point[:, 1] / z, atol=1e-12)


def test_events_of_known_points_come_back_at_their_depth():
    """Analytic events of 3-D points seen along a trajectory peak at the right plane.

    The baseline (1 m) makes one plane step move a ray by at least ~1 px at the ends of the
    trajectory, so that planes can be told apart at all.
    """
    camera = Camera(80, 60, 70.0, 65.0, 39.5, 29.5)
    rng = np.random.default_rng(1)
    n_points = 25
    depth = rng.uniform(0.8, 2.5, n_points)
    uv_ref = np.stack([rng.uniform(15, 65, n_points), rng.uniform(12, 48, n_points)], 1)
    points = camera.backproject(uv_ref, depth)            # reference frame = world at t = 0.5
    trajectory = LinearTrajectory(np.array([-0.5, -0.05, 0.0]), np.array([1.0, 0.1, 0.0]),
                                  np.eye(3))
    T_world_ref = trajectory.pose(0.5)
    points_world = points + T_world_ref[:3, 3]
    xy, t_all = _point_events(points_world, trajectory, np.linspace(0.0, 1.0, 400))
    params = DSIParams(0.6, 3.0, planes=30, packet_size=n_points)
    dsi = disparity_space_image(xy, t_all, trajectory, T_world_ref, camera, params)
    assert dsi.shape == (30, 60, 80) and dsi.dtype == np.float32
    # One vote per event per plane, except where a ray leaves the view.
    assert 0.5 * len(xy) * params.planes < dsi.sum() <= len(xy) * params.planes * (1 + 1e-5)
    planes = depth_planes(params)
    inv = 1 / planes
    spacing = abs(inv[1] - inv[0])
    for (u, v), z in zip(uv_ref, depth, strict=True):
        iu, iv = int(u), int(v)                       # the 2x2 pixels the point's votes share
        window = dsi[:, iv:iv + 2, iu:iu + 2].sum(axis=(1, 2))
        best = planes[int(np.argmax(window))]
        assert abs(1 / best - 1 / z) <= spacing, (z, best)


def test_empty_input_and_shapes():
    camera = Camera(8, 6, 5.0, 5.0, 3.5, 2.5)
    params = DSIParams(1.0, 2.0, planes=4)
    traj = LinearTrajectory(np.zeros(3), np.zeros(3), np.eye(3))
    dsi = disparity_space_image(np.empty((0, 2)), np.empty(0), traj, np.eye(4), camera, params)
    assert dsi.shape == (4, 6, 8) and not dsi.any()
    with pytest.raises(ValueError, match="xy must be"):
        disparity_space_image(np.zeros((3, 3)), np.zeros(3), traj, np.eye(4), camera, params)


def test_semidense_depth_keeps_the_peaks_and_their_plane():
    from fusion.map.emvs import DepthMapParams, semidense_depth

    planes = depth_planes(DSIParams(0.5, 3.0, planes=20))
    rng = np.random.default_rng(4)
    dsi = rng.uniform(0, 2, (20, 40, 50)).astype(np.float32)    # background clutter
    edge_rows = np.arange(5, 35)
    dsi[7, edge_rows, 20] = 60.0                                  # a vertical edge at plane 7
    dsi[12, 18, 5:45] = 60.0                                      # a horizontal one at plane 12
    depth, confidence, mask = semidense_depth(dsi, planes, DepthMapParams(kernel=5, c=5,
                                                                          median=5))
    assert mask[edge_rows[1:-1], 20].all() and mask[18, 6:44].all()
    assert mask.sum() < 0.1 * mask.size                          # the clutter is dropped
    np.testing.assert_allclose(depth[10:17, 20], planes[7], rtol=1e-6)
    np.testing.assert_allclose(depth[18, 25:40], planes[12], rtol=1e-6)
    assert np.all(depth[~mask] == 0) and confidence.max() == pytest.approx(60.0)
    assert not mask[0].any() and not mask[:, -1].any()             # border cleared


def test_masked_median_removes_an_outlier_but_only_uses_masked_neighbours():
    from fusion.map.emvs import masked_median

    values = np.full((7, 7), 2.0)
    values[3, 3] = 9.0                                            # outlier on the edge
    values[:, 0] = 100.0                                          # unmasked junk
    mask = np.zeros((7, 7), bool)
    mask[3, 1:6] = True
    out = masked_median(values, mask, 5)
    assert out[3, 3] == 2.0 and out[3, 1] == 2.0 and out[0, 0] == 100.0


def _reference_votes(xy, T_ref_event, camera, params):
    """Bilinear votes one event and one plane at a time, in float64 (no sorting, no chunks)."""
    planes = depth_planes(params)
    dsi = np.zeros((params.planes, camera.height, camera.width))
    for (x, y) in xy:
        d = T_ref_event[:3, :3] @ np.array([x, y, 1.0])
        if d[2] <= 0:
            continue
        for k, z in enumerate(planes):
            s = (z - T_ref_event[2, 3]) / d[2]
            p = T_ref_event[:3, 3] + s * d
            u = camera.fx * p[0] / z + camera.cx
            v = camera.fy * p[1] / z + camera.cy
            if not (0 <= u <= camera.width - 1 and 0 <= v <= camera.height - 1):
                continue
            c, r = min(int(u), camera.width - 2), min(int(v), camera.height - 2)
            fu, fv = u - c, v - r
            dsi[k, r, c] += (1 - fu) * (1 - fv)
            dsi[k, r, c + 1] += fu * (1 - fv)
            dsi[k, r + 1, c] += (1 - fu) * fv
            dsi[k, r + 1, c + 1] += fu * fv
    return dsi


def test_votes_match_a_per_event_reference_on_any_number_of_threads():
    """The compiled kernel (float32, events sorted by row, chunked, one thread per plane) gives
    the votes of the textbook loop, including rays that leave the view, rays pointing away and
    a ray landing exactly on the last column and row."""
    import numba

    camera = Camera(31, 23, 20.0, 18.0, 15.0, 11.0)
    rng = np.random.default_rng(5)
    xy = rng.uniform(-1.2, 1.2, (3000, 2))                   # a third of them leave the view
    T = make_pose(so3_exp([0.02, 0.03, -0.01]), [0.04, -0.02, 0.01])
    params = DSIParams(0.5, 2.0, planes=7, packet_size=4096)
    trajectory = LinearTrajectory(T[:3, 3], np.zeros(3), T[:3, :3])
    expected = _reference_votes(xy, T, camera, params)
    threads = numba.get_num_threads()
    try:
        for n in sorted({1, threads}):
            numba.set_num_threads(n)
            dsi = disparity_space_image(xy, np.zeros(len(xy)), trajectory, np.eye(4), camera,
                                        params)
            np.testing.assert_allclose(dsi, expected, atol=2e-4)
    finally:
        numba.set_num_threads(threads)
    # The last column and row: a ray along the optical axis of a camera whose principal point
    # is the far corner votes its whole weight into that corner.
    corner = Camera(8, 6, 5.0, 5.0, 7.0, 5.0)
    still = LinearTrajectory(np.zeros(3), np.zeros(3), np.eye(3))
    dsi = disparity_space_image(np.array([[0.0, 0.0], [0.0, 0.0]]), np.zeros(2), still,
                                np.eye(4), corner, DSIParams(1.0, 2.0, planes=3))
    assert dsi[:, 5, 7].tolist() == [2.0, 2.0, 2.0] and dsi.sum() == 6.0


def test_maxima_on_the_first_and_last_planes_are_dropped_and_counted():
    """Issue 21: a DSI maximum on the first or last plane says the depth lies outside the
    range; such points are dropped by default (and counted), kept with keep_boundary_planes."""
    from fusion.map.emvs import DepthMapParams, semidense_depth

    planes = depth_planes(DSIParams(0.5, 3.0, planes=20))
    rng = np.random.default_rng(4)
    dsi = rng.uniform(0, 2, (20, 40, 50)).astype(np.float32)
    dsi[0, 5:35, 10] = 60.0                       # an edge nearer than the range: plane 0
    dsi[19, 5:35, 25] = 60.0                      # one beyond it: the last plane
    dsi[7, 5:35, 40] = 60.0                       # one inside it
    counts: dict = {}
    depth, _, mask = semidense_depth(dsi, planes, DepthMapParams(), counts=counts)
    kept_counts: dict = {}
    kept, _, kept_mask = semidense_depth(dsi, planes, DepthMapParams(keep_boundary_planes=True),
                                         counts=kept_counts)
    assert kept_mask[6:34, 10].all() and kept_mask[6:34, 25].all()       # rpg_emvs keeps them
    assert not mask[:, 8:13].any() and not mask[:, 23:28].any()
    assert counts == {"near": int(kept_mask[:, 10].sum()), "far": int(kept_mask[:, 25].sum()),
                      "dropped": True}
    assert kept_counts == {**counts, "dropped": False}
    assert counts["near"] >= 28 and counts["far"] >= 28
    np.testing.assert_array_equal(mask[:, 35:], kept_mask[:, 35:])       # inside: unaffected
    np.testing.assert_allclose(depth[10:30, 40], planes[7], rtol=1e-6)
    np.testing.assert_array_equal(depth[:, 35:], kept[:, 35:])


def test_points_beyond_the_range_land_on_the_last_plane_and_are_dropped():
    """Analytic events of points inside a 0.6-3 m range and of points at 6 m: those beyond the
    range peak on the last plane and leave the map; those inside keep their depth."""
    from fusion.map.emvs import DepthMapParams, semidense_depth

    camera = Camera(80, 60, 70.0, 65.0, 39.5, 29.5)
    rng = np.random.default_rng(1)
    n_points = 16
    depth = np.concatenate([rng.uniform(0.8, 2.5, n_points // 2), np.full(n_points // 2, 6.0)])
    uv_ref = np.empty((0, 2))
    while len(uv_ref) < n_points:                 # 8 px apart, so that no two peaks merge
        uv = rng.uniform([15, 12], [65, 48])
        if len(uv_ref) == 0 or np.min(np.linalg.norm(uv_ref - uv, axis=1)) > 8:
            uv_ref = np.vstack([uv_ref, uv])
    points = camera.backproject(uv_ref, depth)
    trajectory = LinearTrajectory(np.array([-0.5, -0.05, 0.0]), np.array([1.0, 0.1, 0.0]),
                                  np.eye(3))
    T_world_ref = trajectory.pose(0.5)
    points_world = points + T_world_ref[:3, 3]
    xy, t_all = _point_events(points_world, trajectory, np.linspace(0.0, 1.0, 400))
    params = DSIParams(0.6, 3.0, planes=30, packet_size=n_points)
    dsi = disparity_space_image(xy, t_all, trajectory, T_world_ref, camera, params)
    planes = depth_planes(params)
    settings = DepthMapParams(kernel=5, c=5, median=1)
    counts: dict = {}
    out, _, mask = semidense_depth(dsi, planes, settings, counts=counts)
    kept, _, kept_mask = semidense_depth(
        dsi, planes, DepthMapParams(kernel=5, c=5, median=1, keep_boundary_planes=True))
    far = np.zeros(mask.shape, bool)
    for (u, v), z in zip(uv_ref, depth, strict=True):
        # its rays on the last plane (3 m) spread +-70 px * 0.5 m * (1/3 - 1/6 m) = 6 px along x
        window = (slice(int(v) - 2, int(v) + 4), slice(int(u) - 8, int(u) + 10))
        if z > 3.0:
            far[window] = True
            peak = (slice(int(v), int(v) + 2), slice(int(u), int(u) + 2))  # its votes' 2x2
            on_last = kept_mask[peak] & (kept[peak] == np.float32(planes[-1]))
            assert on_last.any(), (u, v)                        # rpg_emvs puts it at 3 m
            assert not mask[peak][on_last].any(), (u, v)
    assert counts["far"] == int((kept_mask & (kept == np.float32(planes[-1]))).sum()) > 0
    assert counts["near"] == 0
    on_end = kept_mask & np.isin(kept, planes[[0, -1]].astype(np.float32))
    assert on_end[~far].sum() <= 0.1 * on_end[far].sum()   # the points beyond the range
    np.testing.assert_array_equal(mask, kept_mask & ~on_end)   # nothing else is touched
    np.testing.assert_array_equal(out[~on_end], kept[~on_end])
    spacing = abs(1 / planes[1] - 1 / planes[0])
    for (u, v), z in zip(uv_ref[depth < 3.0], depth[depth < 3.0], strict=True):
        peak = (slice(int(v), int(v) + 2), slice(int(u), int(u) + 2))
        assert mask[peak].any(), (u, v)                    # inside the range: still mapped
        assert np.all(np.abs(1 / out[peak][mask[peak]] - 1 / z) <= 2 * spacing), (u, v, z)


# --- sub-plane depth: the parabola through the maximum, in inverse depth -----------------------

def _profile_dsi(profile, peaks_w, planes):
    """A (planes, 1, P) DSI whose pixel p holds ``profile(w - peaks_w[p])`` at each plane."""
    w = 1.0 / planes
    return profile(w[:, None] - peaks_w[None, :])[:, None, :].astype(np.float32)


@pytest.mark.parametrize("profile, bound", [
    (lambda d, step=None: 100.0 - 2e4 * d ** 2, 1e-4),                 # a parabola: exact
])
def test_subplane_depth_is_exact_for_a_parabola_of_votes(profile, bound):
    from fusion.map.emvs import subplane_inverse_depth

    planes = depth_planes(DSIParams(0.5, 4.0, planes=40))
    w = 1.0 / planes
    step = abs(w[1] - w[0])
    peaks = np.linspace(w[5], w[34], 97)                          # between planes, anywhere
    dsi = _profile_dsi(profile, peaks, planes)
    best = np.argmax(dsi, axis=0)
    refined = subplane_inverse_depth(dsi, best, planes)[0]
    plane_error = np.abs(w[best[0]] - peaks) / step
    assert plane_error.max() > 0.45                                # the planes quantise
    assert np.abs(refined - peaks).max() / step < bound


@pytest.mark.parametrize("width, bound", [(0.7, 0.095), (1.0, 0.048), (2.0, 0.048)])
def test_subplane_depth_of_a_gaussian_peak_within_its_stated_bound(width, bound):
    """The docstring's bound for a Gaussian of ``width`` planes, over every peak position."""
    from fusion.map.emvs import subplane_inverse_depth

    planes = depth_planes(DSIParams(0.5, 4.0, planes=40))
    w = 1.0 / planes
    step = abs(w[1] - w[0])
    peaks = np.linspace(w[10], w[12], 401)
    dsi = _profile_dsi(lambda d: 50.0 * np.exp(-0.5 * (d / (width * step)) ** 2), peaks, planes)
    best = np.argmax(dsi, axis=0)
    error = np.abs(subplane_inverse_depth(dsi, best, planes)[0] - peaks) / step
    assert error.max() <= bound + 1e-3
    if width <= 1.0:
        assert error.max() > 0.9 * bound          # the bound is the worst case, not loose
    assert np.abs(w[best[0]] - peaks).max() / step > 0.49


@pytest.mark.parametrize("half_width, bound", [(1.0, 0.167), (1.5, 0.086), (3.0, 0.086)])
def test_subplane_depth_of_a_triangular_peak_within_its_stated_bound(half_width, bound):
    from fusion.map.emvs import subplane_inverse_depth

    planes = depth_planes(DSIParams(0.5, 4.0, planes=40))
    w = 1.0 / planes
    step = abs(w[1] - w[0])
    peaks = np.linspace(w[10], w[12], 401)
    dsi = _profile_dsi(lambda d: np.maximum(0.0, half_width * step - np.abs(d)), peaks, planes)
    best = np.argmax(dsi, axis=0)
    error = np.abs(subplane_inverse_depth(dsi, best, planes)[0] - peaks) / step
    assert error.max() <= bound + 1e-3


def test_subplane_depth_keeps_boundary_maxima_and_splits_a_tie():
    from fusion.map.emvs import subplane_inverse_depth

    planes = depth_planes(DSIParams(1.0, 2.0, planes=5))
    w = 1.0 / planes
    dsi = np.zeros((5, 1, 3), np.float32)
    dsi[:, 0, 0] = [9, 5, 1, 0, 0]                  # maximum on the first plane: kept
    dsi[:, 0, 1] = [0, 0, 1, 5, 9]                  # on the last: kept
    dsi[:, 0, 2] = [0, 4, 4, 0, 0]                  # two equal planes: midway between them
    best = np.argmax(dsi, axis=0)
    np.testing.assert_allclose(subplane_inverse_depth(dsi, best, planes)[0],
                               [w[0], w[4], 0.5 * (w[1] + w[2])])


def test_subplane_depth_of_a_fronto_parallel_and_a_slanted_plane():
    """Analytic events of points on two planes (one facing the camera, one slanted 50 deg):
    the depth refined between the planes errs by a fraction of the plane step, the plane's by
    a quarter of a step on average (uniform quantisation)."""
    from fusion.map.emvs import DepthMapParams, semidense_depth

    camera = Camera(80, 60, 70.0, 65.0, 39.5, 29.5)
    rng = np.random.default_rng(3)
    n = 120
    uv = np.stack([rng.uniform(12, 68, n), rng.uniform(10, 50, n)], 1)
    xy = (uv - [camera.cx, camera.cy]) / [camera.fx, camera.fy]
    front = np.full(n // 2, 1.37)                                     # Z = 1.37 m
    # slanted: Z = 1.8 + 0.012 x_pixels... as a plane n.X = d: Z (1 - tan(50deg) x) = 1.8
    slant = 1.8 / (1.0 - np.tan(np.radians(50.0)) * 0.5 * xy[n // 2:, 0])
    depth = np.concatenate([front, slant])
    points = camera.backproject(uv, depth)
    trajectory = LinearTrajectory(np.array([-0.4, -0.04, 0.0]), np.array([0.8, 0.08, 0.0]),
                                  np.eye(3))
    T_world_ref = trajectory.pose(0.5)
    points_world = points + T_world_ref[:3, 3]
    events_xy, t_all = _point_events(points_world, trajectory, np.linspace(0.0, 1.0, 300))
    params = DSIParams(0.8, 3.0, planes=30, packet_size=n)
    dsi = disparity_space_image(events_xy, t_all, trajectory, T_world_ref, camera, params)
    planes = depth_planes(params)
    step = abs(1 / planes[1] - 1 / planes[0])
    errors = {}
    for subplane in (False, True):
        got, _, _ = semidense_depth(dsi, planes, DepthMapParams(median=1, c=-255.0, border=0,
                                                                subplane=subplane))
        # each point's votes land in the 2x2 pixels around it: the one nearest holds its peak
        z = got[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)]
        errors[subplane] = np.abs(1 / z - 1 / depth) / step
    assert np.median(errors[False]) > 0.15                          # quantised: ~1/4 step
    assert np.median(errors[True]) < 0.5 * np.median(errors[False])
    assert np.percentile(errors[True], 90) < 0.5
