"""Scene files: validation messages, built-in scenes, textures, moving objects."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from scenes import builtin_scenes, describe_scenes, resolve_scene
from sim.render import Renderer
from sim.scene import SceneError, load_scene, parse_scene
from tests.conftest import WALL, scene_text

BOX = """
[[objects]]
name = "box"
type = "box"
center = [0.0, 2.0, 0.0]
size = [1.0, 1.0, 1.0]
"""


def _error(text: str, tmp_path) -> str:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert str(path) in message, "the message must name the file"
    return message


def test_unknown_key_names_file_key_and_alternatives(tmp_path):
    message = _error(scene_text(BOX.replace('name = "box"', 'name = "box"\ncolour = 0.3')),
                     tmp_path)
    assert "[[objects]][0]" in message and "'colour'" in message and "material" in message


def test_missing_field_is_named(tmp_path):
    message = _error(scene_text(BOX.replace("size = [1.0, 1.0, 1.0]\n", "")), tmp_path)
    assert "[[objects]][0]" in message and "missing required key 'size'" in message


def test_wrong_type_says_what_was_expected(tmp_path):
    message = _error(scene_text(BOX.replace("[1.0, 1.0, 1.0]", '"big"')), tmp_path)
    assert "[[objects]][0].size" in message and "list of 3 positive numbers" in message
    message = _error(scene_text(BOX).replace("duration = 1.0", 'duration = "long"'), tmp_path)
    assert "duration" in message and "finite number" in message
    message = _error(scene_text(BOX).replace("fx = 60.0", "fx = -1.0"), tmp_path)
    assert "[camera]" in message


def test_invalid_toml_and_missing_file(tmp_path):
    message = _error("duration = = 3\n", tmp_path)
    assert "not valid TOML" in message and "line 1" in message
    with pytest.raises(SceneError, match="cannot read scene file"):
        load_scene(tmp_path / "absent.toml")


@pytest.mark.parametrize("value, message", [
    ("[0.5]", "expected a list of 2 positive numbers"),
    ("[2.0, 0.5]", "near < far"),
    ("[0.0, 2.0]", "expected a list of 2 positive numbers"),
    ('"near"', "expected a list of 2 positive numbers"),
])
def test_declared_depth_range_is_checked(value, message, tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(scene_text(WALL).replace("seed = 3\n", f"seed = 3\ndepth_range = {value}\n"))
    with pytest.raises(SceneError, match=rf"s.toml: depth_range: .*{message}"):
        load_scene(path)


def test_declared_depth_range_is_read(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(scene_text(WALL).replace("seed = 3\n", "seed = 3\ndepth_range = [0.5, 3]\n"))
    assert load_scene(path).depth_range == (0.5, 3.0)
    assert parse_scene(scene_text(WALL)).depth_range is None


def test_other_sections_are_checked(tmp_path):
    assert "[trajectory].type" in _error(
        scene_text(BOX).replace('type = "linear"', 'type = "teleport"'), tmp_path)
    assert "[[lights]][0]" in _error(
        scene_text(BOX).replace("illuminance_lux = 400.0", "power = 1.0"), tmp_path)
    assert "[render].spp" in _error(scene_text(BOX, extra="[render]\nspp = 10\n"), tmp_path)
    for bad in ("edge_spp = 4", "edge_spp = 12", "edge_spp = -16"):     # event_spp is 4
        message = _error(scene_text(BOX, extra=f"[render]\n{bad}\n"), tmp_path)
        assert "[render].edge_spp" in message and "\n" not in message.strip(), message
    assert parse_scene(scene_text(BOX, extra="[render]\nedge_spp = 16\n")).render.edge_spp == 16
    assert parse_scene(scene_text(BOX)).render.edge_spp == 0
    for bad in ("seed = -1", "seed = 2.0", 'seed = "7"'):
        message = _error(scene_text(BOX, extra=f"[render]\n{bad}\n"), tmp_path)
        assert "[render].seed" in message and "\n" not in message.strip(), message
    assert parse_scene(scene_text(BOX, extra="[render]\nseed = 3\n")).render.seed == 3
    assert parse_scene(scene_text(BOX)).render.seed is None
    assert "texture.name" in _error(scene_text(BOX.replace(
        'size = [1.0, 1.0, 1.0]', 'size = [1.0, 1.0, 1.0]\nmaterial = { texture = { type = '
        '"skimage", name = "mona_lisa" } }')), tmp_path)
    spline = ('[trajectory]\ntype = "spline"\nkeyframes = [\n'
              '  { t = 0.0, position = [0.0, 0.0, 0.0], look_at = [0.0, 1.0, 0.0] },\n'
              '  { t = 1.0, position = [0.1, 0.0, 0.0], look_at = [0.1, 1.0, 0.0] },\n]\n')
    message = _error(scene_text(BOX, duration=5.0, trajectory=spline), tmp_path)
    assert "duration" in message and "does not contain [0, 5.0]" in message

def test_builtin_scene_list_has_the_paper_twins_and_complex_surfaces():
    names = set(builtin_scenes())
    twins = {"slider_close", "slider_far", "slider_hdr_close", "slider_hdr_far", "poster_6dof",
             "shapes_6dof", "boxes_6dof", "dynamic_6dof"}
    assert twins <= names
    assert {"complex_sphere", "complex_cylinder", "complex_slanted_plane", "complex_staircase",
            "complex_heightfield"} <= names
    assert all(describe_scenes()[name] for name in names)
    with pytest.raises(ValueError, match="built-in"):
        resolve_scene("no_such_scene")


@pytest.mark.parametrize("name", sorted(builtin_scenes()))
def test_every_builtin_scene_loads_and_renders_one_frame(name):
    scene = load_scene(resolve_scene(name))
    if scene.frame_camera is not None:        # a rig's 640x480 event camera, at 240x180 here
        assert (scene.camera.width, scene.camera.height) == (640, 480)
        scene = replace(scene, camera=scene.camera.with_resolution(240, 180))
    assert scene.camera.width == 240 and scene.camera.height == 180
    view = Renderer(scene, spp=1).render(min(1.0, scene.duration / 2))
    assert view.luminance.shape == (180, 240) and view.depth.shape == (180, 240)
    assert np.all(np.isfinite(view.luminance)) and view.luminance.max() > 0
    hit = view.depth > 0
    assert hit.mean() > 0.95, "a built-in scene fills the view"
    assert np.percentile(np.log(view.luminance[hit] + 1e-6), 99) > -8
    # The rig's declared working range (the DSI's default range) holds what the camera sees.
    near, far = scene.depth_range
    assert near < view.depth[hit].min() and view.depth[hit].max() < far


def test_slider_twins_have_the_papers_geometry():
    for name, distance in (("slider_close", 0.231), ("slider_far", 0.585)):
        scene = load_scene(resolve_scene(name))
        assert scene.duration == 6.5
        depth = Renderer(scene, spp=1).depth(3.0)
        np.testing.assert_allclose(depth, distance, atol=1e-5)
        v0, w0 = scene.trajectory.velocity(0.0)
        v1, _ = scene.trajectory.velocity(6.0)
        np.testing.assert_allclose(v0, v1)
        assert np.allclose(w0, 0) and v0 @ np.array([0, 1.0, 0]) == 0


def test_hdr_slider_spans_a_high_dynamic_range():
    scene = load_scene(resolve_scene("slider_hdr_close"))
    lum = Renderer(scene, spp=4).luminance(3.25)
    low, high = np.percentile(lum, [2, 98])
    assert high / low > 100


def test_object_motion_moves_the_object_and_only_it():
    objects = BOX.replace('name = "box"', 'name = "box"\nmotion = { type = "linear", '
                          'velocity = [0.0, 1.0, 0.0] }') + """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 5.0, 0.0]
size = [20.0, 20.0]
"""
    scene = parse_scene(scene_text(objects))
    assert scene.is_dynamic
    renderer = Renderer(scene, spp=1)
    centre = (24, 32)
    assert renderer.depth(0.0)[centre] == pytest.approx(1.5, abs=1e-5)
    assert renderer.depth(0.5)[centre] == pytest.approx(2.0, abs=1e-5)
    assert renderer.depth(0.5)[0, 0] == pytest.approx(renderer.depth(0.0)[0, 0], abs=1e-6)


def test_textures_come_from_skimage_procedural_and_files(tmp_path):
    import cv2

    from sim.textures import texture_image

    image = np.zeros((8, 8, 3), np.uint8)
    image[:, 4:] = 255
    cv2.imwrite(str(tmp_path / "half.png"), image)
    half = texture_image({"type": "image", "path": str(tmp_path / "half.png")})
    assert half.shape == (8, 8, 3)
    assert half[0, 0, 0] == pytest.approx(0.03) and half[0, 7, 0] == pytest.approx(0.9)
    astronaut = texture_image({"type": "skimage", "name": "astronaut"})
    assert astronaut.shape == (512, 512, 3) and 0.03 <= astronaut.min() < astronaut.max() <= 0.9
    a = texture_image({"type": "noise", "resolution": 64}, seed=1)
    b = texture_image({"type": "noise", "resolution": 64}, seed=1)
    c = texture_image({"type": "noise", "resolution": 64}, seed=2)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    spec = {"type": "shapes", "resolution": 128, "count": 10, "max_size": 50}
    shapes = texture_image(spec, seed=0)
    assert shapes.min() < 0.5 < shapes.max()


QUAD_OBJ = """# a unit square in the local x-z plane, facing -y
v -0.5 0.0 -0.5
v 0.5 0.0 -0.5
v 0.5 0.0 0.5
v -0.5 0.0 0.5
f 1 2 3
f 1 3 4
"""
QUAD_PLY = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
element face 2
property list uchar int vertex_indices
end_header
-0.5 0.0 -0.5
0.5 0.0 -0.5
0.5 0.0 0.5
-0.5 0.0 0.5
3 0 1 2
3 0 2 3
"""


@pytest.mark.parametrize("suffix, text", [("obj", QUAD_OBJ), ("ply", QUAD_PLY)])
def test_triangle_meshes_from_obj_and_ply_are_placed_and_scaled(tmp_path, suffix, text):
    (tmp_path / f"quad.{suffix}").write_text(text)
    objects = f"""
[[objects]]
name = "quad"
type = "mesh"
path = "quad.{suffix}"
center = [0.0, 2.0, 0.0]
scale = 2.0
"""
    path = tmp_path / "mesh_scene.toml"
    path.write_text(scene_text(objects))
    depth = Renderer(load_scene(path), spp=1).depth(0.0)
    # The 2 m square at y = 2 covers |X|, |Y| <= 1 m: pixels with |u - cx| < fx / 2 - 1 etc.
    cam = load_scene(path).camera
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    inside = (np.abs(u - cam.cx) < cam.fx / 2 - 1) & (np.abs(v - cam.cy) < cam.fy / 2 - 1)
    outside = (np.abs(u - cam.cx) > cam.fx / 2 + 1) | (np.abs(v - cam.cy) > cam.fy / 2 + 1)
    np.testing.assert_allclose(depth[inside], 2.0, atol=1e-5)
    assert np.all(depth[outside] == 0)


def test_mesh_file_errors_name_the_key(tmp_path):
    objects = '[[objects]]\ntype = "mesh"\npath = "absent.obj"\ncenter = [0.0, 1.0, 0.0]\n'
    assert "[[objects]][0].path" in _error(scene_text(objects), tmp_path)
    (tmp_path / "quad.stl").write_text("solid")
    objects = objects.replace("absent.obj", "quad.stl")
    assert ".obj or .ply" in _error(scene_text(objects), tmp_path)


# --- lengths in metres, and [frames] messages in the file's own keys (issue 11, item 6) -------

def _wall_at(distance: float, size: float = 6.0) -> str:
    return (f'[[objects]]\nname = "wall"\ntype = "rectangle"\ncenter = [0.0, {distance}, 0.0]\n'
            f"size = [{size}, {size}]\n")


def test_a_scene_in_millimetres_is_refused_naming_the_key(tmp_path):
    from sim.scene import MAX_NEAREST_SURFACE_M, MAX_OBJECT_SIZE_M

    # slider_close written in millimetres: poster 231 mm in front, 1200 x 600 mm.
    message = _error(scene_text(_wall_at(231.0, size=60.0)), tmp_path)
    assert "scenes are in metres" in message and "[[objects]][0].center" in message
    assert "231 m" in message and f"{MAX_NEAREST_SURFACE_M:g} m" in message
    message = _error(scene_text(_wall_at(231.0, size=1200.0)), tmp_path)
    assert "scenes are in metres" in message and "[[objects]][0].size" in message
    assert "1200 m" in message and f"{MAX_OBJECT_SIZE_M:g} m" in message
    sphere = ('[[objects]]\nname = "ball"\ntype = "sphere"\ncenter = [0.0, 900.0, 0.0]\n'
              "radius = 300.0\n")
    message = _error(scene_text(sphere), tmp_path)
    assert "[[objects]][0].center" in message and "'ball'" in message and "600 m" in message


def test_the_metres_bound_is_the_documented_one():
    """The wall's plane is exactly d from the camera: refused just beyond the bound only."""
    from sim.scene import MAX_NEAREST_SURFACE_M

    parse_scene(scene_text(_wall_at(0.9 * MAX_NEAREST_SURFACE_M)))            # accepted
    with pytest.raises(SceneError, match="scenes are in metres"):
        parse_scene(scene_text(_wall_at(1.1 * MAX_NEAREST_SURFACE_M)))
    # a far wall does not count when something else is near
    parse_scene(scene_text(BOX + _wall_at(1.1 * MAX_NEAREST_SURFACE_M)))


def test_frame_errors_name_the_toml_key_not_the_dataclass(tmp_path):
    message = _error(scene_text(BOX, extra="[frames]\nexposure = 0.5\n"), tmp_path)
    assert "[frames] exposure = 0.5: must be at most the frame interval" in message
    assert "0.04167 s" in message and "24 Hz" in message and "FrameParams" not in message
    message = _error(scene_text(BOX, extra="[frames]\nmax_exposure = 0.05\n"), tmp_path)
    assert "[frames] max_exposure = 0.05: must be at most the frame interval" in message
    assert "0.04167 s" in message and "FrameParams" not in message
    message = _error(scene_text(BOX, extra="[frames]\nmax_exposure = -1.0\n"), tmp_path)
    assert "[frames].max_exposure" in message and "FrameParams" not in message, message
    message = _error(scene_text(BOX, extra="[frames]\nrate = 500.0\n"), tmp_path)
    assert "[frames] exposure = 0.005 (the default)" in message and "0.002 s" in message
    for key, value in (("rate", "-1.0"), ("gamma", "0.0"), ("gain", "0.0")):
        message = _error(scene_text(BOX, extra=f"[frames]\n{key} = {value}\n"), tmp_path)
        assert f"[frames].{key}" in message and "FrameParams" not in message, message


@pytest.mark.parametrize(("frames", "expected"), [
    ('sensor = "davis241"', "[frames].sensor: expected one of ideal, davis240c_aps, "
                            "machine_vision; got 'davis241'"),
    ('sensor = { preset = "ideal" }', "[frames].sensor.preset: expected one of davis240c_aps, "
                                      "machine_vision"),
    ('sensor = { read_noise = 3.0 }', "[frames].sensor: missing required key 'preset'"),
    ('sensor = { preset = "machine_vision", well = 3.0 }', "unknown key 'well'"),
    ('sensor = { preset = "machine_vision", prnu = 0.7 }',
     "[frames].sensor: prnu must be a fraction in [0, 0.5), got 0.7"),
    ('sensor = { preset = "machine_vision", auto_exposure = 1 }',
     "[frames].sensor.auto_exposure: expected true or false"),
    ('sensor = "machine_vision"\ngain = 2.0', "[frames]: [frames] gain is the ideal camera's"),
    ("full_well = 2000.0", "[frames] full_well: the frame noise is now a sensor's"),
    ("read_noise = 1.0", 'sensor = { preset = ..., read_noise = ... } in electrons'),
])
def test_frame_sensor_errors_name_the_toml_key(tmp_path, frames, expected):
    message = _error(scene_text(BOX, extra=f"[frames]\n{frames}\n"), tmp_path)
    assert expected in message and "FrameSensor" not in message, message


def test_frame_sensor_presets_and_overrides_parse(tmp_path):
    from sim.frame_sensor import FRAME_SENSORS

    scene = parse_scene(scene_text(BOX, extra='[frames]\nsensor = "davis240c_aps"\n'))
    assert scene.frames.sensor == FRAME_SENSORS["davis240c_aps"]
    assert scene.frames.output_gamma == 1.0                     # raw linear values
    scene = parse_scene(scene_text(BOX, extra='[frames]\nsensor = { preset = "machine_vision", '
                                              'read_noise = 7.5, vignetting = "none" }\n'))
    sensor = scene.frames.sensor
    assert (sensor.name, sensor.read_noise, sensor.vignetting) == ("machine_vision+custom", 7.5,
                                                                   "none")
    assert sensor.full_well == FRAME_SENSORS["machine_vision"].full_well
    assert parse_scene(scene_text(BOX)).frames.ideal                      # the default


def test_an_event_file_given_as_a_scene_is_named_as_one(tmp_path):
    events = tmp_path / "events.txt"
    events.write_text("0.003811000 96 133 0\n0.003820001 127 171 0\n")
    with pytest.raises(SceneError, match="is an event file .ECD text") as info:
        load_scene(events)
    assert "not valid TOML" not in str(info.value)
    (tmp_path / "events.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    with pytest.raises(SceneError, match="is an event file .HDF5"):
        load_scene(tmp_path / "events.h5")


def test_distance_to_an_object_is_to_its_surface_or_bounding_box(tmp_path):
    objects = """
[[objects]]
name = "box"
type = "box"
center = [0.0, 2.0, 0.0]
size = [0.4, 0.2, 0.6]

[[objects]]
name = "ball"
type = "sphere"
center = [1.0, 3.0, 0.0]
radius = 0.5
"""
    box, ball = parse_scene(scene_text(objects)).objects
    points = np.array([[0.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.5, 2.0, 0.0], [1.0, 1.0, 0.0]])
    # the box's near face is at y = 1.9; its side at x = 0.2
    np.testing.assert_allclose(box.distance_to(points)[:3], [1.9, 0.0, 0.3])
    np.testing.assert_allclose(ball.distance_to(points[3:]), [1.5])        # 2 m to the centre
