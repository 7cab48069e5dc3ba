"""Multi-view fusion (fusion.globalmap.fuse), checked on analytic key views.

The scene is the inside of an axis-aligned box (a room): from inside, every pixel of every view
sees a wall and no wall hides another, so which views see a point is known exactly (it projects
into their image). Exact depth maps come from ray-box intersection through each pixel centre
(the distorted view's rays undistorted by the camera model); the DSI plane spacing that bounds
the fused cloud is computed from :func:`fusion.map.emvs.depth_planes`.
"""

import numpy as np
import pytest

from fusion.globalmap.fuse import (
    FusedCloud,
    FusionParams,
    agreement_counts,
    default_voxel_size,
    evidence_counts,
    fuse_into_view,
    fuse_views,
    fused_depth_points,
    kept_points,
    view_agreement,
)
from fusion.globalmap.views import DepthView, to_camera
from fusion.map.emvs import DSIParams, depth_planes
from sim.camera import Camera
from sim.se3 import so3_exp
from sim.validation import ParameterError

LO = np.array([-1.2, -0.9, -0.6])
HI = np.array([1.2, 0.9, 2.4])
DSI = DSIParams(min_depth=1.0, max_depth=3.0)      # the planes a mapper would use for this room
PINHOLE = Camera(160, 120, 150.0, 150.0, 79.5, 59.5)
DISTORTED = Camera(160, 120, 148.0, 151.0, 80.2, 58.9,
                   distortion=(-0.15, 0.03, 0.001, -0.001, 0.0))


def _pose(w, t):
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.asarray(w, float))
    T[:3, 3] = t
    return T


POSES = [_pose([0.0, 0.0, 0.0], [-0.15, 0.0, 0.0]),
         _pose([0.03, -0.12, 0.02], [0.2, 0.05, 0.1]),
         _pose([-0.04, 0.1, -0.03], [0.05, -0.1, -0.1])]
CAMERAS = [PINHOLE, DISTORTED, PINHOLE]


def _room_depth(camera, T):
    """Exact z-depth of the room's walls through every pixel centre, (H, W) float64."""
    xy = camera.normalized_pixel_centres().reshape(-1, 2)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], 1) @ T[:3, :3].T    # z = 1 in camera
    o = T[:3, 3]
    with np.errstate(divide="ignore"):
        t = np.where(rays > 0, (HI - o) / rays, (LO - o) / rays)
    t[rays == 0] = np.inf
    return t.min(axis=1).reshape(camera.height, camera.width)           # exit distance = z


def _room_distance(points):
    """Distance of points inside (or just outside) the room to its walls."""
    q = np.abs(points - (LO + HI) / 2) - (HI - LO) / 2
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    return np.abs(outside + np.minimum(q.max(axis=1), 0))


def _spacing(z):
    """The DSI plane spacing at depth z: the gap of the two planes around it."""
    planes = depth_planes(DSI)
    k = np.clip(np.searchsorted(planes, z) - 1, 0, len(planes) - 2)
    return planes[k + 1] - planes[k]


def _views(n=3, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    views = []
    for i in range(n):
        depth = _room_depth(CAMERAS[i], POSES[i])
        depth = depth + noise * rng.uniform(-0.5, 0.5, depth.shape) * _spacing(depth)
        views.append(DepthView(depth.astype(np.float32), CAMERAS[i], POSES[i], t=0.1 * i,
                               name=f"view {i}"))
    return views


def _sees(view, points, margin=0.0):
    """Whether ``view``'s camera sees world points, at least ``margin`` pixels inside its
    image (exact: the room hides nothing)."""
    local = to_camera(points, view.T_world_cam)
    uv = view.camera.project(local)
    u, v = uv[:, 0], uv[:, 1]
    w, h = view.camera.width, view.camera.height
    with np.errstate(invalid="ignore"):
        return ((local[:, 2] > 0) & (u >= -0.5 + margin) & (u < w - 0.5 - margin)
                & (v >= -0.5 + margin) & (v < h - 0.5 - margin))


def test_the_room_depth_maps_are_exact():
    # the test's own reference: every back-projected pixel lies on a wall
    for view in _views():
        assert _room_distance(view.points_world()).max() < 1e-5


def test_noisy_points_seen_by_another_view_all_agree():
    views = _views(noise=1.0)
    rel_noise = max(float(np.max(_spacing(v.depth[v.valid]) / v.depth[v.valid])) for v in views)
    params = FusionParams(min_views=1, depth_tolerance=0.03, search_radius=1)
    assert 2 * 0.5 * rel_noise < params.depth_tolerance      # noise of both views within it
    counts = agreement_counts(views, params)
    for i, view in enumerate(views):
        exact = DepthView(_room_depth(view.camera, view.T_world_cam).astype(np.float32),
                          view.camera, view.T_world_cam).points_world()
        inner = sum(_sees(o, exact, margin=1.0) for j, o in enumerate(views) if j != i)
        outer = sum(_sees(o, exact, margin=-1.0) for j, o in enumerate(views) if j != i)
        assert counts[i].shape == (view.valid.sum(),)
        assert np.all(counts[i] >= inner)                    # every view that sees it agrees
        assert np.all(counts[i] <= outer)                    # and no view that does not
        assert np.count_nonzero(inner == 0) > 100            # some seen by this view only


def test_the_fused_cloud_lies_on_the_walls_within_one_plane_spacing():
    views = _views(noise=1.0)
    rng = np.random.default_rng(1)
    depth = views[0].depth.copy()                            # spurious points, view 0 only
    rows, cols = rng.integers(5, 115, 60), rng.integers(5, 155, 60)
    depth[rows, cols] *= 0.8
    views[0] = DepthView(depth, views[0].camera, views[0].T_world_cam)
    params = FusionParams(min_views=1, depth_tolerance=0.03)
    cloud = fuse_views(views, params)
    assert isinstance(cloud, FusedCloud)
    assert cloud.voxel_size == pytest.approx(default_voxel_size(views))
    assert cloud.points.shape == (len(cloud.support), 3) and cloud.view.shape == cloud.support.shape
    assert cloud.support.min() >= 2 and cloud.support.max() == 3
    z = np.array([to_camera(p[None], views[v].T_world_cam)[0, 2]
                  for p, v in zip(cloud.points, cloud.view, strict=True)])
    off = _room_distance(cloud.points)
    assert np.all(off <= _spacing(z)), (off / _spacing(z)).max()
    # at k = 0 the spurious points (15 % in front of a wall) and one-view points stay
    loose = fuse_views(views, FusionParams(min_views=0, depth_tolerance=0.03))
    assert np.count_nonzero(_room_distance(loose.points) > 0.1) >= 50
    assert len(loose.points) > len(cloud.points)
    assert loose.support.min() == 1


BOX_LO, BOX_HI, WALL_Z = np.array([-0.3, -0.25, 1.2]), np.array([0.3, 0.25, 1.7]), 2.6


def _box_and_wall_depth(camera, T):
    """Exact z-depth of a box standing before a wall (z = WALL_Z) through every pixel centre:
    the nearer of the ray's entry into the box (slab method) and its hit on the wall."""
    xy = camera.normalized_pixel_centres().reshape(-1, 2)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], 1) @ T[:3, :3].T
    o = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (BOX_LO - o) / rays, (BOX_HI - o) / rays
        near = np.nanmax(np.minimum(t1, t2), axis=1)
        far = np.nanmin(np.maximum(t1, t2), axis=1)
        wall = np.where(rays[:, 2] > 0, (WALL_Z - o[2]) / rays[:, 2], np.inf)
    box = np.where((near <= far) & (near > 0), near, np.inf)
    return np.minimum(box, wall).reshape(camera.height, camera.width)


def _box_and_wall_distance(points):
    q = np.abs(points - (BOX_LO + BOX_HI) / 2) - (BOX_HI - BOX_LO) / 2
    box = np.abs(np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0))
    return np.minimum(box, np.abs(points[:, 2] - WALL_Z))


def test_views_of_a_box_before_a_wall_fuse_onto_the_box_and_the_wall():
    # seen from outside, the box hides part of the wall from each view: occlusion is real here
    poses = [_pose([0.0, 0.12, 0.0], [-0.3, 0.0, 0.0]),
             _pose([0.05, -0.1, 0.02], [0.3, 0.1, 0.05])]
    cameras = [PINHOLE, DISTORTED]
    rng = np.random.default_rng(4)
    views = []
    for camera, T in zip(cameras, poses, strict=True):
        depth = _box_and_wall_depth(camera, T)
        depth = depth + rng.uniform(-0.5, 0.5, depth.shape) * _spacing(depth)
        views.append(DepthView(depth.astype(np.float32), camera, T))
    for view in views:                                           # the test's reference
        exact = _box_and_wall_depth(view.camera, view.T_world_cam).astype(np.float32)
        assert _box_and_wall_distance(
            DepthView(exact, view.camera, view.T_world_cam).points_world()).max() < 1e-5
    depth = views[0].depth.copy()
    depth[rng.integers(5, 115, 60), rng.integers(5, 155, 60)] *= 0.8   # spurious, view 0 only
    views[0] = DepthView(depth, views[0].camera, views[0].T_world_cam)
    params = FusionParams(min_views=1, depth_tolerance=0.03)
    cloud = fuse_views(views, params)
    z = np.array([to_camera(p[None], views[v].T_world_cam)[0, 2]
                  for p, v in zip(cloud.points, cloud.view, strict=True)])
    assert len(cloud.points) > 10_000
    assert np.all(_box_and_wall_distance(cloud.points) <= _spacing(z))
    on_box = _box_and_wall_distance(cloud.points) < np.abs(cloud.points[:, 2] - WALL_Z)
    assert np.count_nonzero(on_box) > 1000
    # a wall point of view 0 that the box hides from view 1 is not confirmed by view 1
    counts = agreement_counts(views, params)[0]
    wall = views[0].points_world()
    local = to_camera(wall, poses[1])
    uv = DISTORTED.project(local)
    inside = DISTORTED.in_image(uv)
    seen_depth = np.full(len(wall), np.nan)
    col, row = np.round(uv[inside]).astype(int).T
    exact1 = np.pad(_box_and_wall_depth(DISTORTED, poses[1]), 2, mode="edge")
    farthest = np.max([exact1[2 + dy:122 + dy, 2 + dx:162 + dx]                # 5x5 window
                       for dy in range(-2, 3) for dx in range(-2, 3)], axis=0)
    seen_depth[inside] = farthest[row, col]                     # the box all around it in 1
    hidden = inside & (np.abs(wall[:, 2] - WALL_Z) < 0.05) & (seen_depth < local[:, 2] - 0.3)
    assert np.count_nonzero(hidden) > 100
    assert np.all(counts[hidden] == 0)
    loose = fuse_views(views, FusionParams(min_views=0, depth_tolerance=0.03))
    assert np.count_nonzero(_box_and_wall_distance(loose.points) > 0.1) >= 50


def test_a_point_seen_by_one_view_only_is_dropped_at_k_1_and_kept_at_k_0():
    views = _views(n=2)
    points = views[0].points_world()
    outside = ~_sees(views[1], points)
    assert np.count_nonzero(outside) > 200
    counts = agreement_counts(views, FusionParams(min_views=1))[0]
    assert np.all(counts[outside] == 0)
    for k, expected in ((0, True), (1, False)):
        cloud = fuse_views(views, FusionParams(min_views=k, voxel_size=1e-4))  # no merging
        kept = cloud.points[cloud.view == 0]
        assert len(kept) == (len(points) if k == 0 else np.count_nonzero(counts >= 1))
        assert np.any(~_sees(views[1], kept)) == expected


def test_support_counts_views_and_k_2_needs_both_others():
    views = _views(n=3)
    counts = agreement_counts(views, FusionParams(min_views=2))
    cloud = fuse_views(views, FusionParams(min_views=2, voxel_size=1e-4))
    assert len(cloud.points) == sum(int(np.count_nonzero(c == 2)) for c in counts)
    assert np.all(cloud.support == 3)


def _two_walls(depth_j, tx=0.0, depth_i=2.0, camera=None):
    camera = camera or Camera(40, 30, 40.0, 40.0, 19.5, 14.5)
    i = DepthView(np.full((30, 40), depth_i, np.float32), camera, np.eye(4))
    j = DepthView(np.asarray(depth_j, np.float32), camera, _pose([0, 0, 0], [tx, 0, 0]))
    return i, j


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_depth_tolerance_is_relative_to_the_other_views_depth(sign):
    tol = 0.02
    params = FusionParams(depth_tolerance=tol, search_radius=0)
    for factor, agrees in ((1 - 1e-4, True), (1 + 1e-4, False)):
        i, j = _two_walls(np.full((30, 40), 1.0), depth_i=1.0 + sign * tol * factor)
        counts = agreement_counts([i, j], params)[0]
        assert np.all(counts == int(agrees)), (sign, factor)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_inverse_depth_tolerance_agrees_where_the_relative_one_does_not(sign):
    """Walls at 2 m and 2 m +- 5 cm: 2.5 % apart (over a 1 % tolerance), |1/z - 1/d| =
    0.05 / (2 (2 +- 0.05)) 1/m apart in inverse depth: agreed just above that, not just below."""
    far = 2.0 + sign * 0.05
    gap = abs(1 / 2.0 - 1 / far)
    for factor, agrees in ((1 + 1e-3, True), (1 - 1e-3, False)):
        params = FusionParams(depth_tolerance=0.01, search_radius=0,
                              inverse_depth_tolerance=gap * factor)
        i, j = _two_walls(np.full((30, 40), far))
        assert np.all(agreement_counts([i, j], params)[0] == int(agrees)), (sign, factor)


def test_an_occluded_point_does_not_agree():
    # view j, 0.2 m to the right, sees the wall at 2 m except where an occluder at 1 m hides it
    depth_j = np.full((30, 40), 2.0)
    depth_j[10:20, 5:15] = 1.0
    i, j = _two_walls(depth_j, tx=0.2)
    counts = agreement_counts([i, j], FusionParams(search_radius=1))[0]
    u, v = i.pixels().T
    u_j = u - 40.0 * 0.2 / 2.0                                   # the wall point's column in j
    hidden = (v >= 11) & (v < 19) & (u_j >= 6) & (u_j < 14)          # no wall within 1 px
    near_occluder = (v >= 9) & (v < 21) & (u_j >= 4) & (u_j < 16)
    in_j = (u_j >= -0.5)
    assert np.all(counts[hidden] == 0)
    assert np.all(counts[in_j & ~near_occluder] == 1)
    assert np.all(counts[~in_j] == 0)


def test_points_behind_a_view_are_not_seen():
    # j looks the other way from the same place: i's wall is behind it, where j has points too
    camera = Camera(40, 30, 40.0, 40.0, 19.5, 14.5)
    i = DepthView(np.full((30, 40), 2.0, np.float32), camera, np.eye(4))
    j = DepthView(np.full((30, 40), 2.0, np.float32), camera, _pose([0, np.pi, 0], [0, 0, 0]))
    assert np.all(agreement_counts([i, j], FusionParams())[0] == 0)
    report = view_agreement([i, j], FusionParams())
    assert report["pairs"] == [] and report["overlap_points"] == 0
    assert report["confirmed_points"] == 0 and report["points"] == 2 * 40 * 30


def test_a_point_the_lens_folds_back_into_the_image_is_not_seen():
    # k1 < 0: a point far outside the field (x/z = 2.3) lands inside the image after distortion
    camera = Camera(40, 30, 40.0, 40.0, 19.5, 14.5, distortion=(-0.2, 0.0, 0.0, 0.0, 0.0))
    point = np.array([[2.3, 0.0, 1.0]])
    assert camera.in_image(camera.project(point))[0]
    source = np.zeros((30, 40), np.float32)
    source[15, 20] = 1.0
    T = np.eye(4)
    T[:3, 3] = point[0] - [0.0, 0.0, 1.0]                        # its only point is `point`
    i = DepthView(source, Camera(40, 30, 40.0, 40.0, 20.0, 15.0), T)
    uv = camera.project(point)[0]
    depth_j = np.zeros((30, 40), np.float32)
    depth_j[int(round(uv[1])), int(round(uv[0]))] = 1.0          # where the fold lands it
    j = DepthView(depth_j, camera, np.eye(4))
    np.testing.assert_allclose(i.points_world(), point)
    assert agreement_counts([i, j], FusionParams(search_radius=0))[0].tolist() == [0]


def test_the_default_voxel_is_the_median_pixel_footprint():
    camera = Camera(20, 10, 100.0, 90.0, 9.5, 4.5)
    views = []
    for z in (2.0, 4.0, 3.0):                                    # footprints 2, 4 and 3 cm
        depth = np.zeros((10, 20), np.float32)
        depth[:, :10] = z
        depth[:2, 10:] = 50.0                                    # not the median
        views.append(DepthView(depth, camera, np.eye(4)))
    views.append(DepthView(np.zeros((10, 20), np.float32), camera, np.eye(4)))  # no points
    assert default_voxel_size(views) == pytest.approx(0.03)
    assert np.isnan(default_voxel_size(views[3:]))


def test_points_in_one_voxel_merge_to_their_mean():
    camera = Camera(4, 1, 1.0, 1.0, 1.5, 0.0)
    depth = np.full((1, 4), 1.0, np.float32)
    view = DepthView(depth, camera, np.eye(4))                   # x = -1.5, -0.5, 0.5, 1.5
    cloud = fuse_views([view], FusionParams(min_views=0, voxel_size=1.0))
    # voxels [-2, -1), [-1, 0), [0, 1), [1, 2) in x: one point each
    assert len(cloud.points) == 4
    cloud = fuse_views([view], FusionParams(min_views=0, voxel_size=2.0))
    np.testing.assert_allclose(cloud.points, [[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0]])
    assert cloud.view.tolist() == [0, 0] and cloud.support.tolist() == [1, 1]


def test_a_voxels_support_is_the_most_views_that_agreed_on_any_of_its_points():
    camera = Camera(4, 1, 1.0, 1.0, 1.5, 0.0)
    T = _pose([0, 0, 0], [10.0, 0.0, 0.0])                      # all in voxel (0, 0, 0)
    a = DepthView(np.full((1, 4), 1.0, np.float32), camera, T)
    b = DepthView(np.array([[0.0, 0.0, 0.0, 1.0]], np.float32), camera, T)
    params = FusionParams(min_views=0, search_radius=0, voxel_size=100.0)
    assert agreement_counts([a, b], params)[0].tolist() == [0, 0, 0, 1]
    cloud = fuse_views([a, b], params)                           # one voxel holds all
    assert cloud.support.tolist() == [2] and cloud.view.tolist() == [0]
    np.testing.assert_allclose(cloud.points, [[10.3, 0.0, 1.0]])  # x = 10 + mean(-1.5 .. 1.5, 1.5)


def test_fuse_into_view_is_denser_and_lands_at_the_exact_depth():
    views = _views()
    exact = _room_depth(views[0].camera, views[0].T_world_cam)
    sparse = np.zeros_like(views[0].depth)
    sparse[::4, ::4] = views[0].depth[::4, ::4]                  # a semi-dense reference map
    views[0] = DepthView(sparse, views[0].camera, views[0].T_world_cam)
    spurious = views[1].depth.copy()                             # off the walls, view 1 only
    spurious[np.random.default_rng(2).integers(0, 120, 80),
             np.random.default_rng(3).integers(0, 160, 80)] *= 0.8
    views[1] = DepthView(spurious, views[1].camera, views[1].T_world_cam)
    params = FusionParams(min_views=1)
    own = agreement_counts(views, params)[0] >= 1
    fused = fuse_into_view(views, 0, params)
    assert fused.shape == (120, 160) and fused.dtype == np.float32
    assert np.count_nonzero(fused) >= 3 * np.count_nonzero(own)
    # a point landing within half a pixel of a centre: the exact depth there within one
    # pixel's step of the exact depth (the largest difference to a neighbour)
    padded = np.pad(exact, 1, mode="edge")
    step = np.max([np.abs(padded[1 + dy:121 + dy, 1 + dx:161 + dx] - exact)
                   for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
    valid = fused > 0
    assert np.all(np.abs(fused - exact)[valid] <= step[valid] + 1e-5)
    # the back wall, fronto-parallel to view 0: exactly its distance
    back = valid & (np.abs(exact - (HI[2] - POSES[0][2, 3])) < 1e-9) & (step < 1e-9)
    assert np.count_nonzero(back) > 1000
    np.testing.assert_allclose(fused[back], HI[2] - POSES[0][2, 3], atol=1e-5)
    # with k = 0 and one view it is the view itself
    alone = fuse_into_view(views[:1], 0, FusionParams(min_views=0))
    np.testing.assert_array_equal(alone, sparse)


def test_view_agreement_returns_a_known_depth_offset():
    views = _views(n=2)
    offset = 0.03
    b = views[1]
    views[1] = DepthView(np.where(b.valid, b.depth + offset, 0).astype(np.float32), b.camera,
                         b.T_world_cam)
    report = view_agreement(views, FusionParams(min_views=1, depth_tolerance=0.05))
    (pair,) = report["pairs"]
    assert (pair["a"], pair["b"]) == (0, 1)
    assert pair["overlap_points"] > 10_000
    assert pair["median_abs_difference_m"] == pytest.approx(offset, rel=0.05)
    assert report["median_abs_difference_m"] == pytest.approx(offset, rel=0.05)
    typical = np.median(np.concatenate([v.depth[v.valid] for v in views]))
    assert pair["median_rel_difference"] == pytest.approx(offset / typical, rel=0.05)
    assert 0 < report["confirmed_points"] <= report["points"]
    assert report["confirmed_share"] == report["confirmed_points"] / report["points"]
    assert pair["agreeing_share"] == pair["agreeing_points"] / pair["overlap_points"]
    exact = view_agreement(_views(n=2), FusionParams())
    assert exact["median_abs_difference_m"] < 0.002


@pytest.mark.parametrize("field,value", [("min_views", -1), ("min_views", 1.5),
                                         ("search_radius", -2), ("depth_tolerance", 0.0),
                                         ("depth_tolerance", float("nan")),
                                         ("voxel_size", -0.01), ("disjoint_events", 1),
                                         ("inverse_depth_tolerance", 0.0)])
def test_bad_parameters_name_the_parameter(field, value):
    with pytest.raises(ParameterError, match=field):
        FusionParams(**{field: value})


def test_views_must_be_depth_views():
    with pytest.raises(ParameterError, match="views is empty"):
        fuse_views([], FusionParams())
    with pytest.raises(ParameterError, match="expected a DepthView"):
        agreement_counts([np.zeros((2, 2))], FusionParams())
    with pytest.raises(ParameterError, match="ref must be the index"):
        fuse_into_view(_views(n=1), 3, FusionParams())


@pytest.mark.parametrize("other,expected", [(1.0, 1.0), (3.0, 2.0)])
def test_fuse_into_view_keeps_the_nearest_depth_per_pixel(other, expected):
    camera = Camera(40, 30, 40.0, 40.0, 19.5, 14.5)
    own, theirs = np.zeros((30, 40), np.float32), np.zeros((30, 40), np.float32)
    own[15, 20], theirs[15, 20], theirs[5, 7] = 2.0, other, 1.5
    views = [DepthView(own, camera, np.eye(4)), DepthView(theirs, camera, np.eye(4))]
    fused = fuse_into_view(views, 0, FusionParams(min_views=0))
    assert fused[15, 20] == pytest.approx(expected) and fused[5, 7] == pytest.approx(1.5)
    assert np.count_nonzero(fused) == 2


def test_precomputed_counts_give_the_same_results_and_are_checked():
    views = _views(noise=1.0)
    params = FusionParams(min_views=2, depth_tolerance=0.03)
    counts = agreement_counts(views, params)
    a, b = fuse_views(views, params), fuse_views(views, params, counts=counts)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.support, b.support)
    np.testing.assert_array_equal(fuse_into_view(views, 1, params),
                                  fuse_into_view(views, 1, params, counts=counts))
    zero = [np.zeros_like(c) for c in counts]                    # the counts are what is used
    assert len(fuse_views(views, params, counts=zero).points) == 0
    with pytest.raises(ParameterError, match="counts must hold one count per point"):
        fuse_views(views, params, counts=counts[:2])


# --- independent evidence: views that share events do not confirm each other --------------------

def _windowed(views, windows):
    return [DepthView(v.depth, v.camera, v.T_world_cam, v.t, v.name, events=w)
            for v, w in zip(views, windows, strict=True)]


def test_only_views_with_disjoint_events_confirm():
    """Key views 0, 1, 2 with windows [0, 2], [1, 3], [2, 4]: 0 and 2 share no events (they only
    touch at 2 s), 1 shares with both. A point of 0 is asked of view 2 only; 1 has no disjoint
    view, so it is asked of both (the fallback); without the rule every view is asked."""
    views = _views(noise=1.0)
    params = FusionParams(min_views=1, depth_tolerance=0.03, disjoint_events=True)
    plain = agreement_counts(views, FusionParams(min_views=1, depth_tolerance=0.03))
    windowed = _windowed(views, [(0.0, 2.0), (1.0, 3.0), (2.0, 4.0)])
    counts = agreement_counts(windowed, params)
    only_2 = agreement_counts([views[0], views[2]], params)[0]
    np.testing.assert_array_equal(counts[0], only_2)
    assert counts[0].sum() < plain[0].sum()                    # view 1 no longer counts
    np.testing.assert_array_equal(counts[1], plain[1])         # fallback: both asked
    # views without a recorded window: everything as before
    np.testing.assert_array_equal(np.concatenate(agreement_counts(views, params)),
                                  np.concatenate(plain))


def test_contributors_only_confirm():
    views = _views(noise=1.0)
    params = FusionParams(min_views=1, depth_tolerance=0.03)
    every = fuse_views(views, params)
    some = fuse_views(views, params, contributors=[False, True, False])
    assert set(np.unique(some.view)) == {1}
    assert 0 < len(some.points) < len(every.points)
    with pytest.raises(ParameterError, match="contributors"):
        fuse_views(views, params, contributors=[True])


def test_shares_events_rules():
    from fusion.globalmap.views import shares_events

    a, b, c = _windowed(_views(), [(0.0, 2.0), (1.0, 3.0), (2.0, 4.0)])
    assert shares_events(a, b) and shares_events(b, c) and not shares_events(a, c)
    assert not shares_events(_views(1)[0], a)                  # unknown window
    with pytest.raises(ValueError, match="events"):
        DepthView(a.depth, a.camera, a.T_world_cam, events=(2.0, 1.0))


def test_contradictions_and_the_outvoted_rule():
    """View i: a wall at 2 m. View j (the same camera): the wall on columns 0-9, a nearer
    surface (1.5 m) on 10-19, nothing on 20-39. Each of i's points is confirmed by j (0-9),
    contradicted by it (10-19) or not checked (20-39). 'unconfirmed' keeps the first; 'outvoted'
    also the unchecked ones; at k = 0 both keep all."""
    depth_j = np.zeros((30, 40))
    depth_j[:, :10] = 2.0
    depth_j[:, 10:20] = 1.5
    i, j = _two_walls(depth_j)
    u = i.pixels()[:, 0]
    params = FusionParams(search_radius=0, voxel_size=1e-4)           # no merging
    agree, contradict = evidence_counts([i, j], params)
    np.testing.assert_array_equal(agree[0], (u < 10).astype(np.int32))
    np.testing.assert_array_equal(contradict[0], ((u >= 10) & (u < 20)).astype(np.int32))
    np.testing.assert_array_equal(agree[0], agreement_counts([i, j], params)[0])
    for reject, kept_columns in (("unconfirmed", u < 10), ("outvoted", (u < 10) | (u >= 20))):
        rule = FusionParams(search_radius=0, voxel_size=1e-4, reject=reject)
        np.testing.assert_array_equal(kept_points(agree[0], contradict[0], rule), kept_columns)
        cloud = fuse_views([i, j], rule, contributors=[True, False])
        assert len(cloud.points) == np.count_nonzero(kept_columns), reject
        every = fuse_views([i, j], FusionParams(min_views=0, search_radius=0, voxel_size=1e-4,
                                                reject=reject), contributors=[True, False])
        assert len(every.points) == len(u)


def test_outvoted_drops_a_point_under_k_that_more_views_contradict_than_confirm():
    """At k = 2, a point one view confirms: dropped where two contradict it, kept where one
    does (a tie), and at k = 1 kept either way (k views confirming always keep a point)."""
    wall = np.full((30, 40), 2.0)
    near = np.full((30, 40), 1.5)
    i, confirm = _two_walls(wall)
    _, contra_a = _two_walls(near)
    _, contra_b = _two_walls(near)
    params = FusionParams(min_views=2, search_radius=0, reject="outvoted")
    agree, contradict = evidence_counts([i, confirm, contra_a, contra_b], params)
    assert np.all(agree[0] == 1) and np.all(contradict[0] == 2)
    assert not kept_points(agree[0], contradict[0], params).any()
    assert kept_points(agree[0], contradict[0], FusionParams(min_views=1,
                                                              reject="outvoted")).all()
    agree, contradict = evidence_counts([i, confirm, contra_a], params)
    assert kept_points(agree[0], contradict[0], params).all()
    with pytest.raises(ParameterError, match="reject"):
        kept_points(agree[0], None, params)


def test_the_reject_rule_is_checked():
    with pytest.raises(ParameterError, match="reject"):
        FusionParams(reject="majority")


def test_fused_depth_is_the_mean_inverse_depth_of_the_confirming_views():
    """View i: a wall at 2 m. View j, 0.2 m to the side: the wall at 2.02 m on its columns
    0-29, nothing on 30-39. Where j confirms a point of i (within 2 %), j's depth moved along
    its own ray puts the point at 2.02 m in i too, so the fused depth is 1 / mean(1/2, 1/2.02)
    and the point stays on i's ray (its pixel); where j holds nothing the point stays put.
    At one pose, two walls 1 % apart meet at their harmonic mean. (Depths are float32: 1e-7.)"""
    depth_j = np.zeros((30, 40))
    depth_j[:, :30] = 2.02
    i, j = _two_walls(depth_j, tx=0.2)
    params = FusionParams(search_radius=0)
    agree = agreement_counts([i, j], params)[0] >= 1
    assert 300 < np.count_nonzero(agree) < len(agree)
    fused = fused_depth_points([i, j], params)[0]
    own = i.points_world()
    expected = 1.0 / np.mean([1 / 2.0, 1 / 2.02])
    np.testing.assert_allclose(fused[agree, 2], expected, rtol=1e-7)
    np.testing.assert_allclose(fused[agree, :2] / fused[agree, 2:], own[agree, :2] / 2.0,
                               rtol=1e-7)                          # on i's ray
    np.testing.assert_array_equal(fused[~agree], own[~agree])
    a, b = _two_walls(np.full((30, 40), 1.99), depth_i=2.01)
    for points in fused_depth_points([a, b], params):
        np.testing.assert_allclose(points[:, 2], 1.0 / np.mean([1 / 2.01, 1 / 1.99]),
                                   rtol=1e-7)
    cloud = fuse_views([a, b], FusionParams(search_radius=0, fuse_depth=True))
    np.testing.assert_allclose(cloud.points[:, 2], 1.0 / np.mean([1 / 2.01, 1 / 1.99]),
                               rtol=1e-7)
    with pytest.raises(ParameterError, match="fuse_depth"):
        FusionParams(fuse_depth=1)
