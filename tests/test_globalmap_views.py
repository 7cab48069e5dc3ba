"""DepthView: back-projection into the world frame, checked analytically on a rotated,
distorted camera looking at a tilted plane."""

import numpy as np
import pytest

from fusion.globalmap.views import DepthView, to_camera, to_world
from sim.camera import Camera
from sim.se3 import so3_exp


def _pose(w, t):
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.asarray(w, float))
    T[:3, 3] = t
    return T


def test_points_world_lie_on_the_plane_they_were_made_from():
    camera = Camera(40, 30, 35.0, 33.0, 19.2, 14.7, distortion=(-0.2, 0.05, 0.001, -0.002, 0.0))
    T = _pose([0.1, -0.3, 0.2], [0.5, -0.2, 1.0])
    n_cam, d_cam = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0]), 1.5
    uv = camera.pixel_centres().reshape(-1, 2)
    rays = camera.backproject(uv, np.ones(len(uv)))               # z = 1 rays through pixels
    depth = (d_cam / (rays @ n_cam)).reshape(30, 40)              # plane n . X = d
    depth[::7, ::5] = 0.0                                         # holes
    view = DepthView(depth, camera, T, t=0.25, name="plane")
    world = view.points_world()
    assert len(world) == np.count_nonzero(depth)
    n_world, d_world = T[:3, :3] @ n_cam, d_cam + (T[:3, :3] @ n_cam) @ T[:3, 3]
    np.testing.assert_allclose(world @ n_world, d_world, atol=1e-5)
    back = camera.project(to_camera(world, T))                     # the same pixels again
    np.testing.assert_allclose(back, view.pixels(), atol=1e-4)
    np.testing.assert_allclose(view.centre, T[:3, 3])


def test_to_camera_inverts_to_world():
    T = _pose([0.4, 0.1, -0.7], [1.0, 2.0, -3.0])
    p = np.random.default_rng(0).normal(size=(50, 3))
    np.testing.assert_allclose(to_camera(to_world(p, T), T), p, atol=1e-12)


def test_a_depth_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match="expected the camera's"):
        DepthView(np.ones((3, 4)), Camera(5, 3, 1.0, 1.0, 2.0, 1.0), np.eye(4))


def test_non_finite_depth_counts_as_no_point():
    depth = np.array([[1.0, np.nan], [np.inf, 2.0]], np.float32)
    view = DepthView(depth, Camera(2, 2, 1.0, 1.0, 0.5, 0.5), np.eye(4))
    assert view.valid.tolist() == [[True, False], [False, True]]
