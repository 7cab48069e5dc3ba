"""fusion.globalmap.tsdf: the TSDF volume and its mesh against analytic surfaces; mesh PLY I/O."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fusion.globalmap.tsdf import (
    TRUNCATION_VOXELS,
    VOXEL_FOOTPRINTS,
    Mesh,
    TSDFParams,
    TSDFVolume,
    tsdf_grid,
    tsdf_mesh,
)
from fusion.globalmap.views import DepthView, to_camera
from fusion.io import read_mesh_ply, write_mesh_ply
from sim.camera import Camera
from sim.se3 import look_at, make_pose
from sim.validation import ParameterError

BOX_HALF = np.array([0.2, 0.15, 0.1])   # an axis-aligned box at the origin, metres
PLAIN = Camera(96, 72, 90.0, 90.0, 47.5, 35.5)
DISTORTED = Camera(96, 72, 88.0, 92.0, 48.3, 35.1, distortion=(-0.25, 0.08, 0.002, -0.001, 0.0))


def pose_at(eye, target=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) camera-to-world pose of a camera at ``eye`` looking at ``target`` (z up)."""
    return make_pose(look_at(eye, target), eye)


def box_view(camera: Camera, T: np.ndarray) -> DepthView:
    """Exact z-depth of the box through every pixel (slab ray-box intersection)."""
    xy = camera.normalized_pixel_centres().reshape(-1, 2)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], 1)   # z = 1: ray parameter = z-depth
    direction = rays @ T[:3, :3].T
    origin = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-BOX_HALF - origin) / direction
        t2 = (BOX_HALF - origin) / direction
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    depth = np.where((near <= far) & (near > 0), near, 0.0)
    return DepthView(depth.reshape(camera.height, camera.width).astype(np.float32), camera, T)


def sphere_view(camera: Camera, T: np.ndarray, centre, radius: float) -> DepthView:
    """Exact z-depth of a sphere through every pixel."""
    xy = camera.normalized_pixel_centres().reshape(-1, 2)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], 1)
    direction = rays @ T[:3, :3].T
    oc = T[:3, 3] - np.asarray(centre)
    a = np.sum(direction**2, 1)
    b = 2 * direction @ oc
    c = oc @ oc - radius**2
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
    depth = np.where(disc > 0, t, 0.0)
    return DepthView(depth.reshape(camera.height, camera.width).astype(np.float32), camera, T)


def box_distance(points: np.ndarray) -> np.ndarray:
    """Unsigned distance of points to the box's surface, metres."""
    q = np.abs(points) - BOX_HALF
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(1), 0.0)
    return np.abs(outside + inside)


def box_surface(spacing: float) -> np.ndarray:
    """(M, 3) points on a grid over the box's six faces."""
    faces = []
    for axis in range(3):
        a, b = [i for i in range(3) if i != axis]
        ga = np.arange(-BOX_HALF[a], BOX_HALF[a] + 1e-9, spacing)
        gb = np.arange(-BOX_HALF[b], BOX_HALF[b] + 1e-9, spacing)
        A, B = np.meshgrid(ga, gb)
        for sign in (-1, 1):
            p = np.zeros((A.size, 3))
            p[:, a], p[:, b], p[:, axis] = A.ravel(), B.ravel(), sign * BOX_HALF[axis]
            faces.append(p)
    return np.concatenate(faces)


def seen(points: np.ndarray, view: DepthView, tolerance: float = 1e-3) -> np.ndarray:
    """(M,) bool: points that ``view`` sees (their pixel's depth is their own z)."""
    pc = to_camera(points, view.T_world_cam)
    uv = view.camera.project(pc)
    ok = np.all(np.isfinite(uv), 1)
    u = np.rint(np.nan_to_num(uv[:, 0], nan=-1)).astype(int)
    v = np.rint(np.nan_to_num(uv[:, 1], nan=-1)).astype(int)
    ok &= (u >= 0) & (v >= 0) & (u < view.camera.width) & (v < view.camera.height)
    depth = np.where(ok, view.depth[np.clip(v, 0, view.camera.height - 1),
                                    np.clip(u, 0, view.camera.width - 1)], 0.0)
    return ok & (np.abs(depth - pc[:, 2]) <= tolerance)


@pytest.fixture(scope="module")
def box_views() -> list[DepthView]:
    return [box_view(PLAIN, pose_at((0.9, -0.6, 0.7))),
            box_view(DISTORTED, pose_at((-0.7, -0.8, 0.5), target=(0.02, 0.01, -0.01)))]


def test_box_mesh_lies_on_the_box_and_covers_the_seen_faces(box_views):
    lo, hi, voxel, truncation = tsdf_grid(box_views)
    mesh = tsdf_mesh(box_views)
    assert len(mesh.faces) > 500
    distance = box_distance(mesh.vertices)
    assert distance.max() < 0.5 * voxel, (distance.max() / voxel)
    surface = box_surface(voxel / 4)
    visible = np.zeros(len(surface), bool)
    for view in box_views:
        visible |= seen(surface, view)
    assert visible.sum() > 1000
    gap, _ = cKDTree(mesh.sample(voxel / 8)).query(surface[visible])
    assert np.mean(gap <= voxel) >= 0.90, np.mean(gap <= voxel)


def test_sphere_from_several_views_lies_on_the_sphere():
    centre, radius = np.array([0.1, -0.05, 0.02]), 0.25
    eyes = [(1.0, 0.0, 0.3), (0.0, 1.1, -0.2), (-0.9, -0.4, 0.4), (0.2, -1.0, -0.5)]
    views = [sphere_view(DISTORTED if i % 2 else PLAIN, pose_at(e, centre), centre, radius)
             for i, e in enumerate(eyes)]
    lo, hi, voxel, _ = tsdf_grid(views)
    mesh = tsdf_mesh(views)
    assert len(mesh.faces) > 1000
    distance = np.abs(np.linalg.norm(mesh.vertices - centre, axis=1) - radius)
    assert distance.max() < 0.5 * voxel, distance.max() / voxel


def plane_view(camera: Camera, depth: float) -> DepthView:
    """A fronto-parallel plane at ``depth`` seen by a camera at the origin looking along +z."""
    return DepthView(np.full((camera.height, camera.width), depth, np.float32), camera, np.eye(4))


def test_the_kernel_reads_the_pixel_camera_project_gives():
    # each pixel's depth names the pixel: 2 + index * 1e-4 m; with a truncation larger than
    # the plane's spread, a voxel's distance is exactly depth - z, so it tells which pixel was read
    camera = DISTORTED
    index = np.arange(camera.height * camera.width).reshape(camera.height, camera.width)
    depth = (2.0 + 1e-4 * index).astype(np.float64)
    view = DepthView(depth.astype(np.float32), camera, pose_at((0.0, 0.0, 0.0), (0.1, 0.05, 1.0)))
    lo, voxel = np.array([-0.7, -0.5, 1.75]), 0.05
    volume = TSDFVolume(lo, lo + [1.4, 1.0, 0.1], voxel, truncation=2.0)
    volume.integrate(view)
    i, j, k = np.nonzero(volume.weight > 0)
    assert len(i) > 300
    centres = lo + np.stack([i, j, k], 1) * voxel
    uv = camera.project(to_camera(centres, view.T_world_cam))
    u, v = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    z = to_camera(centres, view.T_world_cam)[:, 2]
    read = np.rint((volume.tsdf[i, j, k] + z - 2.0) / 1e-4).astype(int)
    assert np.mean(read == index[v, u]) > 0.999   # float32 ties at a pixel's edge aside
    # and the pixels that no voxel reaches are outside the image: the weights count views
    assert set(np.unique(volume.weight)) <= {0.0, 1.0}


def test_default_voxel_truncation_and_bounds_follow_the_stated_rules():
    camera = PLAIN
    view = plane_view(camera, 1.5)
    lo, hi, voxel, truncation = tsdf_grid([view])
    footprint = 1.5 / math.sqrt(camera.fx * camera.fy)
    assert voxel == pytest.approx(VOXEL_FOOTPRINTS * footprint, rel=1e-6)
    assert truncation == pytest.approx(TRUNCATION_VOXELS * voxel, rel=1e-9)
    points = view.points_world()
    np.testing.assert_allclose(lo, points.min(0) - truncation, rtol=0, atol=1e-9)
    np.testing.assert_allclose(hi, points.max(0) + truncation, rtol=0, atol=1e-9)
    # given values are kept; bounds given are not padded
    given = TSDFParams(voxel_size=0.01, truncation=0.03, bounds=((0, 0, 0), (1, 1, 1)))
    lo, hi, voxel, truncation = tsdf_grid([view], given)
    assert (voxel, truncation) == (0.01, 0.03)
    assert lo.tolist() == [0, 0, 0] and hi.tolist() == [1, 1, 1]


def test_default_voxel_grows_until_the_volume_fits_max_voxels():
    view = plane_view(PLAIN, 1.5)
    _, _, free_voxel, _ = tsdf_grid([view])
    lo, hi, voxel, truncation = tsdf_grid([view], TSDFParams(max_voxels=2_000))
    assert voxel > 2 * free_voxel
    volume = TSDFVolume(lo, hi, voxel, truncation, max_voxels=2_000)
    assert 1_000 < math.prod(volume.shape) <= 2_000


def test_a_volume_over_max_voxels_is_refused_naming_the_parameters():
    with pytest.raises(ParameterError) as error:
        TSDFVolume((0, 0, 0), (1, 1, 1), 0.01, 0.02, max_voxels=1_000_000)
    message = str(error.value)
    assert "\n" not in message
    assert "1,030,301 voxels" in message and "max_voxels 1,000,000" in message
    flags = error.value.rephrase({"max_voxels": "--max-voxels", "voxel_size": "--voxel",
                                  "bounds": "--bounds"})
    assert all(flag in flags for flag in ("--max-voxels", "--voxel ", "--bounds"))
    with pytest.raises(ParameterError, match="voxel_size"):
        tsdf_mesh([plane_view(PLAIN, 1.0)], TSDFParams(voxel_size=1e-4))
    with pytest.raises(ParameterError, match="truncation 0.005 m is under one voxel"):
        TSDFVolume((0, 0, 0), (1, 1, 1), 0.01, 0.005)


def test_no_surface_between_observed_and_unobserved_voxels():
    # a plane z = 0.5 voxel through a grid; the half x < 4 unobserved must give no face there,
    # though its (unset) distances change sign against the observed half
    volume = TSDFVolume((0, 0, 0), (0.9, 0.9, 0.9), 0.1, 0.2)
    z = np.arange(volume.shape[2]) * 0.1
    volume.tsdf[:] = (0.45 - z)[None, None, :]
    volume.weight[:] = 1.0
    volume.tsdf[:4] = -0.2
    volume.weight[:4] = 0.0
    mesh = volume.mesh()
    assert len(mesh.faces) > 0
    np.testing.assert_allclose(mesh.vertices[:, 2], 0.45, atol=1e-6)
    assert mesh.vertices[:, 0].min() == pytest.approx(0.4)   # grid x index 4: first observed
    volume.weight[:] = 0.0
    assert len(volume.mesh().faces) == 0


def test_mesh_sample_is_area_uniform_and_seeded():
    # two triangles of areas 1 and 3 (m^2) side by side in the plane z = 2
    mesh = Mesh(np.array([[0, 0, 2], [1, 0, 2], [1, 2, 2], [1, 0, 2], [4, 0, 2], [4, 2, 2]]),
                np.array([[0, 1, 2], [3, 4, 5]]))
    np.testing.assert_allclose(mesh.areas(), [1.0, 3.0])
    points = mesh.sample(0.02, seed=3)
    assert len(points) == math.ceil(4.0 / 0.02**2)
    np.testing.assert_array_equal(points, mesh.sample(0.02, seed=3))
    assert not np.array_equal(points, mesh.sample(0.02, seed=4))
    np.testing.assert_allclose(points[:, 2], 2.0)
    first = points[:, 0] <= 1.0
    assert np.all(points[first, 1] <= 2 * points[first, 0] + 1e-9)   # inside triangle one
    assert np.mean(first) == pytest.approx(0.25, abs=0.02)
    # uniform inside a triangle: a quarter of triangle two's area lies at x >= 2.5 (the half
    # of its x span nearest the right angle holds 3/4 of it)
    second = points[~first]
    assert np.mean(second[:, 0] >= 2.5) == pytest.approx(0.75, abs=0.02)
    assert len(Mesh(np.empty((0, 3)), np.empty((0, 3))).sample(0.1)) == 0


@pytest.mark.parametrize("with_colours", [False, True])
def test_mesh_ply_round_trip(tmp_path, with_colours):
    rng = np.random.default_rng(0)
    vertices = rng.normal(size=(50, 3)).astype(np.float32).astype(np.float64)
    faces = rng.integers(0, 50, size=(70, 3)).astype(np.int32)
    colours = rng.integers(0, 256, size=(50, 3)).astype(np.uint8) if with_colours else None
    path = tmp_path / "mesh.ply"
    write_mesh_ply(path, vertices, faces, colours)
    header = path.read_bytes()[:400]
    assert b"format binary_little_endian 1.0" in header
    assert b"property list uchar int vertex_indices" in header
    v, f, c = read_mesh_ply(path)
    np.testing.assert_array_equal(v, vertices)
    np.testing.assert_array_equal(f, faces)
    assert f.dtype == np.int32
    if with_colours:
        np.testing.assert_array_equal(c, colours)
    else:
        assert c is None
    with pytest.raises(ValueError, match="faces index vertices"):
        write_mesh_ply(path, vertices, faces + 50)


def test_mesh_ply_size_is_the_binary_layout(tmp_path):
    # 3 float32 per vertex; 1 + 3 int32 bytes per face, after the header
    path = tmp_path / "m.ply"
    write_mesh_ply(path, np.zeros((4, 3)), np.array([[0, 1, 2], [1, 2, 3]]))
    data = path.read_bytes()
    body = data[data.index(b"end_header\n") + len(b"end_header\n"):]
    assert len(body) == 4 * 12 + 2 * 13
    assert body[48:49] == b"\x03"


def test_bench_tsdf_scene_depth_lies_on_its_surface_distance():
    # benchmarks/bench_tsdf.py scores meshes with surface_distance: its own ray-cast points
    # must be at distance 0 from it, and points off the surface at their known distance
    from benchmarks.bench_tsdf import BALL, make_views, surface_distance

    views = make_views(3)
    points = np.concatenate([view.points_world() for view in views])
    assert len(points) > 50_000
    assert surface_distance(points).max() < 1e-6
    centre, radius = BALL
    probe = centre + np.array([[0.0, 0.0, radius + 0.01], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(surface_distance(probe), [0.01, 0.13], atol=1e-12)


def test_an_observation_of_weight_zero_leaves_the_voxel_unseen():
    """A voxel first seen exactly at -truncation (weight 0) stays unseen, not NaN: a later view
    then sets it (0 / 0 used to write a NaN that stayed, and marching cubes turned it into
    non-finite vertices)."""
    camera = Camera(8, 8, 8.0, 8.0, 3.5, 3.5)
    volume = TSDFVolume((-0.125, -0.125, 0.0), (0.125, 0.125, 1.5), 0.125, 0.25)
    k = 8                                                     # the voxels at z = 1.0 m
    volume.integrate(DepthView(np.full((8, 8), 0.75, np.float32), camera, np.eye(4)))
    assert np.all(volume.weight[:, :, k] == 0) and np.all(np.isfinite(volume.tsdf))
    volume.integrate(DepthView(np.full((8, 8), 1.0, np.float32), camera, np.eye(4)))
    assert np.all(np.isfinite(volume.tsdf))
    np.testing.assert_allclose(volume.tsdf[:, :, k], 0.0, atol=1e-7)


@pytest.mark.parametrize("depth", [1.0, 2.0])
def test_truncation_follows_the_views_depth_resolution(depth):
    """A plane at ``depth``: with an inverse-depth step s, voxels in front of it hold their exact
    distance up to TRUNCATION_STEPS depth^2 s (2 x 4 x 0.02 = 16 cm at 2 m, 4 cm at 1 m),
    clipped there; without it, at the fixed truncation (2 cm)."""
    from fusion.globalmap.tsdf import TRUNCATION_STEPS

    camera = PLAIN
    view = plane_view(camera, depth)
    voxel, step = 0.01, 0.02
    lo = np.array([-0.05, -0.05, depth - 0.3])
    band = TRUNCATION_STEPS * depth ** 2 * step
    for inverse_step, expected in ((None, 0.02), (step, band)):
        volume = TSDFVolume(lo, lo + [0.1, 0.1, 0.35], voxel, truncation=0.02,
                            inverse_depth_step=inverse_step)
        volume.integrate(view)
        column = volume.tsdf[5, 5]
        z = lo[2] + np.arange(len(column)) * voxel
        front = (z < depth) & (volume.weight[5, 5] > 0)
        np.testing.assert_allclose(column[front], np.minimum(depth - z[front], expected),
                                   atol=1e-5)
        behind = volume.weight[5, 5] > 0
        assert (depth - z[behind]).min() > -expected - 1e-6       # nothing past the band


def test_the_box_is_padded_by_the_widest_band():
    view = plane_view(PLAIN, 2.0)
    lo, hi, voxel, truncation = tsdf_grid([view], TSDFParams(inverse_depth_step=0.02))
    points = view.points_world()
    band = 2.0 * 2.0 ** 2 * 0.02
    assert band > truncation
    np.testing.assert_allclose(lo, points.min(0) - band, atol=1e-9)
    np.testing.assert_allclose(hi, points.max(0) + band, atol=1e-9)


def test_a_search_radius_meshes_a_view_sparser_than_the_voxels():
    """A fronto-parallel plane at 1 m seen on every third column only (strips 1 px wide): at
    search radius 0 a voxel's pixel mostly holds no depth, so few cubes have eight observed
    corners and the mesh covers little of the plane; at radius 1 every pixel has a strip within
    1 px, and the mesh covers the plane and lies on it (the module's bound: 0 off a
    fronto-parallel plane, to marching cubes' interpolation)."""
    camera = PLAIN
    depth = np.zeros((camera.height, camera.width), np.float32)
    depth[:, ::3] = 1.0
    view = DepthView(depth, camera, np.eye(4))
    lo, hi, voxel = np.array([-0.4, -0.3, 0.9]), np.array([0.4, 0.3, 1.1]), 0.01
    covered = {}
    for radius in (0, 1):
        mesh = tsdf_mesh([view], TSDFParams(voxel_size=voxel, truncation=0.03,
                                            bounds=(tuple(lo), tuple(hi)),
                                            search_radius=radius))
        covered[radius] = float(mesh.areas().sum())
        if radius:
            np.testing.assert_allclose(mesh.vertices[:, 2], 1.0, atol=1e-6)
    box = float(np.prod((hi - lo)[:2]))              # m^2; inside the field of view at 1 m
    assert box < (camera.width - 1) / camera.fx * (camera.height - 1) / camera.fy
    assert covered[0] < 0.2 * box, covered
    assert covered[1] > 0.95 * box, covered


def test_the_search_radius_is_checked():
    with pytest.raises(ParameterError, match="search_radius"):
        TSDFParams(search_radius=-1)
    with pytest.raises(ParameterError, match="search_radius"):
        TSDFVolume((0, 0, 0), (1, 1, 1), 0.1, 0.2, search_radius=1.5)
