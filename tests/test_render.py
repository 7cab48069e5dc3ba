"""Rendering follows the camera model exactly: analytic depth and projection checks."""

from __future__ import annotations

import json
from contextlib import contextmanager

import numpy as np
import pytest

from sim.render import Renderer
from sim.scene import parse_scene
from sim.se3 import look_at
from tests.conftest import scene_text, undistort_points

PLANE = """
[[objects]]
name = "plane"
type = "rectangle"
center = [0.3, 2.0, -0.2]
size = [40.0, 40.0]
normal = [-0.3, -1.0, 0.4]
material = { color = 0.5 }
"""


def _ray_directions(camera):
    """Unit-z ray directions (H, W, 3) through pixel centres, straight from u = fx X/Z + cx."""
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    return np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy,
                     np.ones_like(u)], axis=-1)


def test_plane_depth_is_analytic_z_at_every_pixel():
    trajectory = ('[trajectory]\ntype = "linear"\nposition = [0.1, -0.2, 0.15]\n'
                  "velocity = [0.0, 0.0, 0.0]\nlook_at = [0.5, 1.0, -0.1]\n")
    scene = parse_scene(scene_text(PLANE, trajectory=trajectory))
    depth = Renderer(scene, spp=1).depth(0.0)
    pose = scene.trajectory.pose(0.0)
    R, C = pose[:3, :3], pose[:3, 3]
    normal = np.array([-0.3, -1.0, 0.4])
    offset = normal @ np.array([0.3, 2.0, -0.2])
    d = _ray_directions(scene.camera)
    z = (offset - normal @ C) / ((d @ R.T) @ normal)       # the ray's parameter is z for unit-z d
    assert depth.dtype == np.float32 and depth.shape == (48, 64)
    assert np.all(z > 0)
    np.testing.assert_allclose(depth, z, rtol=0, atol=1e-5)


def test_sphere_depth_is_analytic_and_zero_off_the_sphere():
    objects = """
[[objects]]
name = "ball"
type = "sphere"
center = [0.05, 1.5, -0.03]
radius = 0.4
material = { color = 0.5 }
"""
    scene = parse_scene(scene_text(objects))
    depth = Renderer(scene, spp=1).depth(0.0)
    R = scene.trajectory.pose(0.0)[:3, :3]
    d = _ray_directions(scene.camera) @ R.T                   # world directions, camera at origin
    centre = np.array([0.05, 1.5, -0.03])
    a, b, c = np.sum(d * d, -1), -2 * d @ centre, centre @ centre - 0.4**2
    disc = b * b - 4 * a * c
    hit = disc > 0
    z = np.where(hit, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), 0.0)
    clear = np.abs(disc) > 0.02 * b * b                       # away from the grazing silhouette
    assert hit.sum() > 300 and (~hit & clear).sum() > 300
    np.testing.assert_allclose(depth[clear & hit], z[clear & hit], rtol=0, atol=1e-5)
    assert np.all(depth[clear & ~hit] == 0)


SIDE = 0.1


def _square(center, side=SIDE):
    return f"""
[[objects]]
name = "square"
type = "rectangle"
center = [{center[0]}, {center[1]}, {center[2]}]
size = [{side}, {side}]
normal = [0.0, -1.0, 0.0]
material = {{ color = 1.0 }}
"""


def _edges(profile: np.ndarray) -> tuple[float, float]:
    """Sub-pixel edges of a 1-D box-filtered bar from its per-pixel coverage.

    Pixel i integrates [i - 0.5, i + 0.5]; a bar [a, b] covers the first lit pixel i0 by
    (i0 + 0.5 - a) and the last one i1 by (b - (i1 - 0.5)).
    """
    full = np.median(profile[profile > 0.98 * profile.max()])
    coverage = profile / full
    lit = np.flatnonzero(coverage > 1e-6)
    i0, i1 = lit[0], lit[-1]
    return i0 + 0.5 - coverage[i0], i1 - 0.5 + coverage[i1]


@pytest.mark.parametrize("center", [(0.0, 1.0, 0.0), (-0.38, 1.0, 0.38), (0.5, 1.2, -0.4),
                                    (0.13, 0.8, 0.27)])
def test_projected_square_lands_on_predicted_pixels_with_fx_not_fy(center):
    """A small fronto-parallel square renders exactly where u = fx X/Z + cx, v = fy Y/Z + cy say.

    The square is lit uniformly, so each pixel's value is its covered area; the square's edges
    are recovered from the coverage of its border pixels, to well under 0.01 px.
    """
    scene = parse_scene(scene_text(_square(center)))
    camera = scene.camera
    assert camera.fx != camera.fy
    image = Renderer(scene, spp=256).luminance(0.0).astype(np.float64)
    u0, u1 = _edges(image.sum(axis=0))
    v0, v1 = _edges(image.sum(axis=1))
    # The camera looks along +y with z up: camera X = world x, Y = -world z, Z = world y.
    X, Y, Z = center[0], -center[2], center[1]
    half = SIDE / 2
    np.testing.assert_allclose(
        [u0, u1], [camera.fx * (X - half) / Z + camera.cx, camera.fx * (X + half) / Z + camera.cx],
        atol=0.01)
    np.testing.assert_allclose(
        [v0, v1], [camera.fy * (Y - half) / Z + camera.cy, camera.fy * (Y + half) / Z + camera.cy],
        atol=0.01)


def test_distorted_camera_depth_follows_opencv_undistortion():
    cv2 = pytest.importorskip("cv2")
    camera = ("[camera]\nwidth = 64\nheight = 48\nfx = 60.0\nfy = 45.0\ncx = 30.3\ncy = 22.7\n"
              "distortion = [-0.2, 0.05, 0.001, -0.002, 0.0]\n")
    scene = parse_scene(scene_text(PLANE, camera=camera))
    depth = Renderer(scene, spp=1).depth(0.0)
    cam = scene.camera
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    pts = np.stack([u, v], -1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    xy = undistort_points(pts, cam.K, cam.distortion, criteria=criteria).reshape(
        cam.height, cam.width, 2)
    d = np.concatenate([xy, np.ones_like(xy[..., :1])], -1)
    R = scene.trajectory.pose(0.0)[:3, :3]
    normal = np.array([-0.3, -1.0, 0.4])
    offset = normal @ np.array([0.3, 2.0, -0.2])
    z = offset / ((d @ R.T) @ normal)
    np.testing.assert_allclose(depth, z, rtol=0, atol=1e-5)


def test_static_camera_gives_bit_identical_frames():
    scene = parse_scene(scene_text(PLANE.replace("color = 0.5", 'texture = { type = "noise" }')))
    renderer = Renderer(scene, spp=4)
    first, second = renderer.luminance(0.0), renderer.luminance(0.5)
    assert first.std() > 0
    assert np.array_equal(first, second)
    assert np.array_equal(renderer.depth(0.0), renderer.depth(0.7))
    # Rendering another pose in between does not disturb it either.
    renderer.luminance(0.0, pose=np.eye(4))
    assert np.array_equal(renderer.luminance(0.0), first)


def test_pose_argument_overrides_the_trajectory():
    scene = parse_scene(scene_text(PLANE))
    renderer = Renderer(scene, spp=1)
    pose = np.eye(4)
    pose[:3, :3] = look_at(np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_array_equal(renderer.depth(0.0, pose), renderer.depth(0.0))
    pose[:3, 3] = [0.0, -1.0, 0.0]                               # one metre further back
    assert np.median(renderer.depth(0.0, pose) - renderer.depth(0.0)) > 0.5
    with pytest.raises(ValueError, match="4, 4"):
        renderer.depth(0.0, np.eye(3))


def test_new_poses_and_moving_objects_reuse_the_compiled_kernels():
    """One loaded scene renders any pose without recompiling (parameters stay opaque)."""
    objects = PLANE + """
[[objects]]
name = "spinning_box"
type = "box"
center = [0.0, 1.5, 0.0]
size = [0.2, 0.2, 0.2]
motion = { type = "linear", angular_velocity = [0.0, 0.0, 90.0] }

[[objects]]
name = "swinging_ball"
type = "sphere"
center = [0.3, 1.4, 0.1]
radius = 0.1
motion = { type = "sine", amplitude = [0.1, 0.0, 0.0], frequency = 1.0 }
"""
    trajectory = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
                  "velocity = [0.1, 0.05, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
    scene = parse_scene(scene_text(objects, trajectory=trajectory))
    renderer = Renderer(scene, spp=4)
    if renderer.variant == "scalar_rgb":
        pytest.skip("scalar_rgb compiles nothing")
    import drjit as dr

    first = renderer.render(0.1)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        later = [renderer.render(t) for t in (0.2, 0.35)]
        kernels = dr.kernel_history([dr.KernelType.JIT])
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert kernels, "rendering launched no kernel"
    assert all(k["cache_hit"] for k in kernels), "a new pose compiled a new kernel"
    assert not np.array_equal(first.depth, later[0].depth)


SMALL_CAMERA = "[camera]\nwidth = 16\nheight = 12\nfx = 15.0\nfy = 11.0\ncx = 7.3\ncy = 5.6\n"


def _run_scalar(tmp_path, text: str, code: str) -> None:
    """Run Python ``code`` in a subprocess on scalar_rgb (the variant is chosen once per
    process), with ``scene`` the scene of the TOML ``text``."""
    import os
    import subprocess
    import sys

    scene_file = tmp_path / "scalar.toml"
    scene_file.write_text(text)
    code = f"import numpy as np; import sim; scene = sim.load_scene({str(scene_file)!r}); {code}"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, check=False,
                          env={**os.environ, "EVFUSE_VARIANT": "scalar_rgb"})
    assert done.returncode == 0, done.stderr
    assert "scalar_rgb" in done.stderr


def _scalar_render(tmp_path, text: str, spp: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Depth and luminance (time 0) of a scene text rendered by scalar_rgb in a subprocess."""
    _run_scalar(tmp_path, text, f"r = sim.Renderer(scene, spp={spp});"
                f"np.save({str(tmp_path / 'depth.npy')!r}, r.depth(0.0));"
                f"np.save({str(tmp_path / 'lum.npy')!r}, r.luminance(0.0))")
    return np.load(tmp_path / "depth.npy"), np.load(tmp_path / "lum.npy")


def test_scalar_fallback_renders_the_same_depth(tmp_path):
    """Without LLVM, scalar_rgb must still work and agree with the vectorised variant."""
    text = scene_text(PLANE, camera=SMALL_CAMERA)
    depth, luminance = _scalar_render(tmp_path, text)
    renderer = Renderer(parse_scene(text), spp=1)
    np.testing.assert_allclose(depth, renderer.depth(0.0), atol=1e-5)
    # Uniform plane under a directional light: both variants see the same shading.
    np.testing.assert_allclose(luminance, renderer.luminance(0.0), rtol=1e-4)


MESHES = """
[[objects]]
name = "waves"
type = "heightfield"
center = [0.0, 1.5, 0.0]
rotation = [90.0, 0.0, 0.0]
size = [1.2, 0.9]
amplitude = 0.05
wavelength = [0.3, 0.4]
resolution = [400, 300]
material = { color = 0.5 }

[[objects]]
name = "knot"
type = "mesh"
path = "builtin:torus"
center = [0.3, 1.2, 0.1]
scale = 0.15
material = { color = 0.7 }
"""


@contextmanager
def _dr_threads(count: int):
    """Dr.Jit's worker threads set to ``count`` inside, restored after."""
    import drjit as dr

    threads = dr.thread_count()
    dr.set_thread_count(count)
    try:
        yield
    finally:
        dr.set_thread_count(threads)


def _normals(renderer: Renderer) -> dict[str, np.ndarray]:
    params = renderer._params
    return {key: np.array(params[key]) for key in params.keys()
            if key.endswith("vertex_normals")}


def test_mesh_normals_and_renders_are_the_same_bits_whatever_the_dr_jit_threads():
    """Mitsuba's JIT variants sum a mesh's vertex normals with atomic adds in the order of
    Dr.Jit's worker threads: on eight threads a height field and a mesh loaded twice got
    different last bits, and so did the event camera's luminance and the events (1-4 ns); this
    test failed in 10 of 10 runs on that code (2 loaded cores). The renderer gives them
    :func:`sim.scene.vertex_normals` (a fixed order)."""

    from sim.shader import EventShader

    scene = parse_scene(scene_text(MESHES))
    with _dr_threads(8):
        loads = [Renderer(scene, spp=4) for _ in range(4)]
        normals = [_normals(renderer) for renderer in loads]
        assert len(normals[0]) == 2                          # the height field and the mesh
        pixels = np.arange(scene.camera.width * scene.camera.height)
        times = np.full(len(pixels), 0.01)
        values = [EventShader(renderer, 4, t0=0.0, t1=0.05).luminance(pixels, times)
                  for renderer in loads]
    for other in normals[1:]:
        for key, value in normals[0].items():
            assert np.array_equal(other[key], value), key
    assert np.any(values[0] > 0)
    for other in values[1:]:
        assert np.array_equal(other, values[0])


def test_moving_meshes_get_fixed_order_normals_at_every_time():
    """A moving height field or mesh: Mitsuba recomputes its normals (atomic adds, thread
    order) at every move; the renderer then sets its fixed-order normals at rest
    (:func:`sim.scene.vertex_normals`) rotated with it, those of the moved positions to float32
    rounding, so frames on eight Dr.Jit threads are the same bits load after load (on the old
    code this comparison failed in 5 of 6 runs)."""

    from sim.scene import vertex_normals

    moving = MESHES.replace("[400, 300]", "[200, 150]").replace(
        'rotation = [90.0, 0.0, 0.0]\n', 'rotation = [90.0, 0.0, 0.0]\n'
        'motion = { type = "sine", amplitude = [0.0, 0.0, 0.05], frequency = 1.0 }\n').replace(
        'scale = 0.15\n', 'scale = 0.15\n'
        'motion = { type = "sine", amplitude = [0.1, 0.0, 0.05], frequency = 2.0 }\n')
    scene = parse_scene(scene_text(moving))
    assert scene.is_dynamic
    with _dr_threads(8):
        frames = []
        for _ in range(3):
            renderer = Renderer(scene, spp=4)
            frames.append([renderer.luminance(t) for t in (0.1, 0.3)])
            params = renderer._params
            for key in _normals(renderer):
                mesh = key.removesuffix("vertex_normals")
                positions = np.array(params[f"{mesh}vertex_positions"]).reshape(-1, 3)
                faces = np.array(params[f"{mesh}faces"]).reshape(-1, 3)
                np.testing.assert_allclose(np.array(params[key]).reshape(-1, 3),
                                           vertex_normals(positions, faces), rtol=0, atol=1e-5)
    for other in frames[1:]:
        for frame, first in zip(other, frames[0], strict=True):
            assert np.array_equal(frame, first)


def test_scalar_fallback_loads_a_mesh_file(tmp_path):
    """scalar_rgb keeps Mitsuba's own normals (summed in face order there) and loads a mesh file
    as before: the same depth as the vectorised variant."""
    text = scene_text(MESHES[MESHES.index('[[objects]]\nname = "knot"'):], camera=SMALL_CAMERA)
    depth, _ = _scalar_render(tmp_path, text)
    assert np.any(depth > 0)
    np.testing.assert_allclose(depth, Renderer(parse_scene(text), spp=1).depth(0.0), atol=1e-5)


def test_scalar_fallback_simulates_a_moving_height_field(tmp_path):
    """scalar_rgb builds a height field's mesh and moves it (its buffers are not ``mi.Float``
    there, which refused an array): a short window simulates, with events, as on llvm.
    ``[render] edge_spp`` needs the JIT variants' shader: recorded as 0, with why."""
    text = scene_text(MESHES[:MESHES.index("[[objects]]\nname = \"knot\"")].replace(
        "resolution = [400, 300]", "resolution = [40, 30]\n"
        'motion = { type = "linear", velocity = [0.0, 0.0, 0.5] }'),
        camera=SMALL_CAMERA, trajectory='[trajectory]\ntype = "linear"\n'
        "position = [0.0, 0.0, 0.0]\nvelocity = [0.5, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n",
        extra="[render]\nedge_spp = 16\n")
    out = tmp_path / "seq"
    _run_scalar(tmp_path, text, f"r = sim.simulate(scene, {str(out)!r}, duration=0.02, spp=1,"
                " progress=False, event_formats=('h5',)); assert r.variant == 'scalar_rgb';"
                " assert r.n_events > 0, r")
    assert (out / "events.h5").is_file()
    record = json.loads((out / "sequence.json").read_text())["events"]
    assert record["edge_spp"] == 0 and record["edge_samples"] == 0
    assert "edge_spp = 16 needs a JIT variant's shader" in record["edge_spp_warning"]


def test_scalar_fallback_sums_every_light_as_the_jit_variants(tmp_path):
    """scalar_rgb shades with the same estimator as the JIT variants (every light in turn,
    :func:`sim.render.direct_light`), not Mitsuba's ``direct`` (one light picked at random per
    sample: unbiased, but 24 % off in this mean at spp 1): a mesh under two lights has the same
    mean luminance to 1 % (what is left: the variants' sub-pixel positions differ; 0.01 %
    measured)."""
    lights = ('[[lights]]\ntype = "point"\nposition = [0.3, 0.0, 0.4]\nintensity_cd = 5.0\n'
              '[[lights]]\ntype = "directional"\ndirection = [0.2, 1.0, -0.3]\n'
              "illuminance_lux = 300.0\n")
    torus = ('[[objects]]\nname = "knot"\ntype = "mesh"\npath = "builtin:torus"\n'
             "center = [0.0, 1.2, 0.0]\nscale = 0.35\nmaterial = { color = 0.7 }\n")
    camera = "[camera]\nwidth = 48\nheight = 36\nfx = 45.0\nfy = 33.0\ncx = 23.3\ncy = 17.6\n"
    text = scene_text(torus, camera=camera, lights=lights)
    depth, luminance = _scalar_render(tmp_path, text)
    renderer = Renderer(parse_scene(text), spp=1)
    expected = renderer.luminance(0.0)
    assert np.count_nonzero(depth) > 100
    np.testing.assert_allclose(luminance.mean(), expected.mean(), rtol=0.01)


def test_vertex_normals_are_mitsubas_to_float_rounding():
    """:func:`sim.scene.vertex_normals` is Mitsuba's angle-weighted scheme (its
    ``recompute_vertex_normals`` on one thread, float32 sums) to a few float32 ulps, and exact
    on a flat grid."""
    import mitsuba as mi

    from sim.scene import heightfield_mesh, vertex_normals
    from sim.variant import use_variant

    use_variant()
    vertices, _, faces = heightfield_mesh((1.2, 0.9), 0.05, (0.3, 0.4), (48, 36))
    flat = vertex_normals(vertices * [1.0, 1.0, 0.0], faces)
    assert np.array_equal(flat, np.tile(np.float32([0.0, 0.0, 1.0]), (len(vertices), 1)))
    mesh = mi.Mesh("waves", len(vertices), len(faces), has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    with _dr_threads(1):
        params.update()                                     # Mitsuba recomputes the normals
        theirs = np.array(params["vertex_normals"]).reshape(-1, 3)
    ours = vertex_normals(vertices.astype(np.float32), faces)
    assert np.all(np.abs(np.linalg.norm(ours, axis=1) - 1.0) < 1e-6)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name, t0", [("boxes_6dof", 3.0), ("complex_sphere", 1.0)])
def test_depth_many_is_depth_at_each_time_bit_for_bit(name, t0):
    """One ray cast for several times (each ray turned by its own time's pose) gives each
    time's :meth:`Renderer.depth` bit for bit, on non-planar scenes seen from a turning
    camera; and :class:`sim.event_depth.RecentDepth` renders each time once, batched."""
    from dataclasses import replace

    from scenes import resolve_scene
    from sim.event_depth import RecentDepth
    from sim.scene import load_scene

    scene = load_scene(resolve_scene(name))
    renderer = Renderer(replace(scene, camera=scene.camera.with_resolution(40, 30)), spp=1)
    times = t0 + np.array([0.0, 0.013, 0.05, 0.31])
    many = renderer.depth_many(times)
    one = np.stack([renderer.depth(float(t)) for t in times])
    assert many.shape == (4, 30, 40) and many.dtype == np.float32
    np.testing.assert_array_equal(many.view(np.int32), one.view(np.int32))
    assert not np.array_equal(one[0], one[-1]) and (one > 0).mean() > 0.5
    calls = []
    recent = RecentDepth(renderer.depth, render_many=lambda t: calls.append(len(t))
                         or renderer.depth_many(t))
    got = recent.many(times[:3])
    assert calls == [3] and recent.renders == 3
    np.testing.assert_array_equal(recent(float(times[1])), one[1])    # kept, not rendered
    assert recent.renders == 3
    np.testing.assert_array_equal(recent.many(times[2:])[1], one[3])  # only the new time
    assert calls == [3] and recent.renders == 4 and len(got) == 3
