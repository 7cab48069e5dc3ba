"""sim.shader: each sample at its own pose, against mi.render, against itself and against the
trajectory's exact pose."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import sim.shader
from scenes import resolve_scene
from sim.render import Renderer
from sim.scene import load_scene, parse_scene
from sim.se3 import make_pose, so3_exp
from sim.shader import EventShader, require_jit_variant
from sim.trajectory import SampledTrajectory
from tests.conftest import (
    BOX_BEFORE_WALL,
    FAST,
    LENS,
    LENS_CAMERA,
    SIDE_LIGHT_TOML,
    WALL,
    scene_text,
)

SLIDING_BOX = """
[[objects]]
name = "box"
type = "box"
center = [-0.15, 0.6, 0.0]
size = [0.2, 0.2, 0.2]
material = { texture = { type = "checkerboard", squares = [4, 4], color0 = 0.1, color1 = 0.9 } }
motion = { type = "linear", velocity = [0.4, 0.0, 0.0] }
"""


@pytest.fixture(scope="module")
def boxes() -> Renderer:
    """boxes_6dof at 48x36 through a distorting lens: two lights, textures, a turning camera."""
    scene = load_scene(resolve_scene("boxes_6dof"))
    camera = replace(scene.camera.with_resolution(48, 36), distortion=LENS)
    return Renderer(replace(scene, camera=camera), spp=4)


def _relative(a: np.ndarray, b: np.ndarray, where: np.ndarray) -> np.ndarray:
    return np.abs(a - b)[where] / b[where]


def test_frame_is_the_same_estimator_as_mi_render(boxes):
    """Against mi.render (the ``evfuse_direct`` integrator: every light, as the shader).

    The two differ only by their sub-pixel positions (Mitsuba's stratified sampler, the
    shader's fixed jittered strata), so they agree to the scale of mi.render's own noise, the
    same render with another seed: now that no light is picked at random that noise is small
    (main's direct integrator, one light picked per sub-sample: median 1.0 % here), and a
    half-pixel shift or a lens left out is 5 to 6 times further.
    """
    import mitsuba as mi

    t = 2.0
    ours = EventShader(boxes, 64, t0=0.0, t1=4.0).frame(t)
    reference = boxes.luminance(t, spp=64)
    other_seed = np.array(mi.render(boxes.mitsuba_scene, seed=boxes.seed + 1, spp=64))
    other_seed = other_seed.reshape(reference.shape)
    lit = reference > 0
    assert lit.mean() > 0.95
    assert ours.dtype == np.float32 and ours.shape == (36, 48)
    assert abs(ours.mean() / reference.mean() - 1.0) < 0.002
    noise = np.median(_relative(other_seed, reference, lit))
    assert 0.0 < noise < 0.004                   # sub-pixel positions only
    assert np.median(_relative(ours, reference, lit)) < 1.5 * noise


def test_luminance_equals_frame_bit_for_bit_for_any_subset(boxes):
    shader = EventShader(boxes, 4, t0=0.0, t1=4.0)
    t = 1.234
    frame = shader.frame(t).ravel()
    assert frame.std() > 0 and np.count_nonzero(frame) > 0.9 * frame.size
    rng = np.random.default_rng(1)
    for pixels in (rng.choice(frame.size, 300),                    # duplicates, any order
                   np.sort(rng.choice(frame.size, 300)),           # sorted: no reordering
                   rng.permutation(frame.size), np.array([17])):
        values = shader.luminance(pixels, np.full(len(pixels), t))
        assert values.dtype == np.float32
        np.testing.assert_array_equal(values, frame[pixels])


def test_each_sample_is_shaded_at_the_pose_of_its_own_time(boxes):
    shader = EventShader(boxes, 4, t0=3.0, t1=3.5)
    rng = np.random.default_rng(2)
    moments = np.linspace(3.0, 3.5, 6)
    times = rng.choice(moments, 2000)
    pixels = rng.integers(0, 48 * 36, 2000)
    values = shader.luminance(pixels, times)
    frames = {t: shader.frame(t).ravel() for t in moments}
    np.testing.assert_array_equal(values, [frames[t][p] for p, t in zip(pixels, times,
                                                                          strict=True)])
    # The camera turns: one frame for all would be wrong for most samples.
    assert np.mean(values != frames[moments[0]][pixels]) > 0.5


def test_a_sample_does_not_depend_on_the_other_samples_of_its_call(monkeypatch):
    """The kernel's pose table starts at the call's earliest time and is split where the call's
    times span more than POSE_TABLE_NODES grid intervals: neither may change a sample. A camera
    near the world origin moving fast: a fraction rounded after subtracting the table's start
    would move it by several float32 roundings of its position."""
    scene = parse_scene(scene_text(WALL, trajectory=FAST))          # at 0.2 s, 5 cm from 0
    shader = EventShader(Renderer(scene, spp=1), 4, t0=0.0, t1=1.0)
    rng = np.random.default_rng(7)
    pixels, times = np.sort(rng.integers(0, 64 * 48, 3000)), rng.uniform(0.2, 0.2002, 3000)
    alone = shader.luminance(pixels, times)
    others = rng.integers(0, 64 * 48, 300), rng.uniform(0.0, 1.0, 300)
    mixed = shader.luminance(np.concatenate([others[0], pixels]),
                             np.concatenate([others[1], times]))
    np.testing.assert_array_equal(mixed[300:], alone)
    monkeypatch.setattr(sim.shader, "POSE_TABLE_NODES", 5)             # 50 us per table
    np.testing.assert_array_equal(shader.luminance(pixels, times), alone)


def test_the_kernel_interpolates_between_pose_grid_nodes():
    """A camera sliding at constant velocity: linear interpolation is exact, so a grid with a
    node every 0.25 s renders 0.3 s (a fifth into an interval, the camera 5 cm = 3 px from
    either node) as a fine grid does, up to float32 rounding."""
    scene = parse_scene(scene_text(WALL, trajectory=FAST))
    renderer = Renderer(scene, spp=1)
    coarse = EventShader(renderer, 4, t0=0.0, t1=1.0, pose_step=0.25)
    fine = EventShader(renderer, 4, t0=0.0, t1=1.0)
    expected = fine.frame(0.3)
    assert np.abs(coarse.pose(np.array([0.3]))[0] - scene.trajectory.pose(0.3)).max() < 1e-12
    for values in (coarse.frame(0.3), coarse.luminance(np.arange(expected.size),
                                                       np.full(expected.size, 0.3))):
        close = np.abs(values.ravel() - expected.ravel()) <= 1e-5 * expected.ravel()
        assert close.mean() > 0.99
    # The nodes' own frames are 3 px away: most pixels differ
    for t in (0.25, 0.5):
        assert np.mean(np.abs(fine.frame(t) - expected) > 1e-3 * expected) > 0.3


def _pose_errors(shader: EventShader, times: np.ndarray) -> np.ndarray:
    exact = shader.renderer.scene.trajectory.pose(times)
    return np.abs(shader.pose(times) - exact)[:, :3, :]


@pytest.mark.parametrize("step", [1e-5, 2e-2])
def test_pose_interpolation_stays_within_its_stated_bound(boxes, step):
    shader = EventShader(boxes, 1, t0=20.0, t1=20.3, pose_step=step)
    times = np.random.default_rng(3).uniform(20.0, 20.3, 20000)
    errors = _pose_errors(shader, times)
    bound = shader.pose_error_bound
    assert errors.max() <= bound
    assert bound <= 50 * errors.max()            # a bound, not a blanket
    assert shader.pose_step <= step
    if step == 1e-5:
        assert bound < 1e-9                      # far below the kernel's float32 rounding


def test_pose_bound_holds_across_the_kinks_of_a_sampled_trajectory():
    """Geodesic pieces between motion-capture samples: the second derivative is a spike at
    every sample, where linear interpolation is first-order only."""
    rng = np.random.default_rng(4)
    knots = np.arange(0.0, 0.3, 0.01)
    poses = make_pose(so3_exp(rng.normal(0.0, 0.3, (len(knots), 3))),
                      rng.normal(0.0, 0.05, (len(knots), 3)))
    scene = parse_scene(scene_text(WALL))
    scene = replace(scene, trajectory=SampledTrajectory(knots, poses))
    shader = EventShader(Renderer(scene, spp=1), 1, t0=0.0, t1=0.29, pose_step=3e-3)
    errors = _pose_errors(shader, rng.uniform(0.0, 0.29, 20000))
    assert errors.max() <= shader.pose_error_bound <= 50 * errors.max()


def test_a_static_camera_gives_the_same_values_at_every_time():
    scene = parse_scene(scene_text(WALL))                 # linear trajectory, zero velocity
    shader = EventShader(Renderer(scene, spp=1), 4, t0=0.0, t1=1.0)
    first = shader.frame(0.1)
    assert first.std() > 0
    np.testing.assert_array_equal(shader.frame(0.9), first)
    pixels = np.arange(first.size)
    times = np.random.default_rng(5).uniform(0.0, 1.0, first.size)
    np.testing.assert_array_equal(shader.luminance(pixels, times), first.ravel())


def test_moving_objects_one_time_per_call_and_frames_follow_them():
    """frame(t) moves the objects to t (the frame sampler's render); luminance() refuses mixed
    times. One directional light: mi.render has no light-selection noise here."""
    scene = parse_scene(scene_text(WALL + SLIDING_BOX))
    renderer = Renderer(scene, spp=4)
    shader = EventShader(renderer, 16, t0=0.0, t1=1.0)
    with pytest.raises(ValueError, match="objects move in this scene.*one time per call"):
        shader.luminance(np.array([0, 1]), np.array([0.2, 0.7]))
    frames = {}
    for t in (0.7, 0.0, 0.7):                    # there, back and there again
        frames[t] = shader.frame(t)
        reference = renderer.luminance(t, spp=64)
        # Only sub-pixel sampling differs (4 % of the pixels, on the checkerboard's edges); a
        # box left where it was would differ on the 30 % of the image it covers then and now.
        close = _relative(frames[t], reference, reference > 0) < 0.05
        assert close.mean() > 0.9, f"t = {t}: the box is not where mi.render has it"
        pixels = np.arange(0, frames[t].size, 7)
        np.testing.assert_array_equal(shader.luminance(pixels, np.full(len(pixels), t)),
                                      frames[t].ravel()[pixels])
    assert np.mean(frames[0.0] != frames[0.7]) > 0.2
    # With moving objects the kernel is traced at every call, never replayed frozen: a frozen
    # replay after objects moved gave NaN luminance on dynamic_6dof's 2-s window (at 7.53 s).
    assert not hasattr(shader._trace, "n_recordings")           # a dr.freeze object has it
    static = EventShader(Renderer(parse_scene(scene_text(WALL))), 1, t0=0.0, t1=1.0)
    assert hasattr(static._trace, "n_recordings")


def test_calls_of_any_size_reuse_the_kernel_and_launches_change_nothing(boxes, monkeypatch):
    import drjit as dr

    shader = EventShader(boxes, 4, t0=0.0, t1=4.0)
    rng = np.random.default_rng(6)
    pixels, times = rng.integers(0, 48 * 36, 777), rng.uniform(0.0, 4.0, 777)
    shader.luminance(pixels[:100], times[:100])
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        whole = shader.luminance(pixels, times)
        shader.frame(2.5)
        kernels = dr.kernel_history([dr.KernelType.JIT])
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert kernels and all(k["cache_hit"] for k in kernels), "a new size compiled a new kernel"
    monkeypatch.setattr(sim.shader, "MAX_RAYS_PER_LAUNCH", 4 * 50)      # 16 launches
    split = EventShader(boxes, 4, t0=0.0, t1=4.0)
    np.testing.assert_array_equal(split.luminance(pixels, times), whole)


def test_small_calls_replay_the_frozen_kernel_and_give_the_same_values(boxes, monkeypatch):
    """A launch whose size equals that of an array of the scene (a box's 36 indices) is not
    replayed by Dr.Jit: it records the kernel again (and warns after 10). Small calls are
    padded (MIN_LAUNCH): one recording serves every size, and the values do not change."""
    recordings = []
    real = sim.shader._trace

    def counted(*args, **kwargs):
        recordings.append(int(args[3].shape[0]))
        return real(*args, **kwargs)

    monkeypatch.setattr(sim.shader, "_trace", counted)
    shader = EventShader(boxes, 4, t0=0.0, t1=4.0)
    rng = np.random.default_rng(8)
    pixels, times = rng.integers(0, 48 * 36, 5000), rng.uniform(0.0, 4.0, 5000)
    whole = shader.luminance(pixels, times)
    for size in (1, 24, 28, 36, 48, 72, 777):     # a box's vertices, indices, ...; any size
        np.testing.assert_array_equal(shader.luminance(pixels[:size], times[:size]),
                                      whole[:size])
    assert len(recordings) == 1, f"recorded again for launches of {recordings[1:]} samples"
    monkeypatch.setattr(sim.shader, "MIN_LAUNCH", 1)                   # unpadded: re-recorded
    bare = EventShader(boxes, 4, t0=0.0, t1=4.0)
    bare.luminance(pixels, times)
    for size in (1, 24, 28, 36, 48, 72):
        bare.luminance(pixels[:size], times[:size])
    assert len(recordings) > 2


def test_scalar_variant_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"JIT Mitsuba variant .*got scalar_rgb") as info:
        require_jit_variant("scalar_rgb")
    assert "\n" not in str(info.value)
    require_jit_variant("llvm_ad_rgb")
    require_jit_variant("cuda_ad_rgb")


def test_bad_inputs_are_refused_with_what_was_expected(boxes):
    shader = EventShader(boxes, 4, t0=1.0, t1=2.0)
    with pytest.raises(ValueError, match=r"flat indices y\*W\+x in \[0, 1728\), got \[0, 1728\]"):
        shader.luminance(np.array([0, 1728]), np.array([1.5, 1.5]))
    with pytest.raises(ValueError, match=r"\[t0, t1\] = \[1.0, 2.0\] s .*got 2.5"):
        shader.luminance(np.array([0, 1]), np.array([1.5, 2.5]))
    with pytest.raises(ValueError, match="same shape"):
        shader.luminance(np.array([0, 1]), np.array([1.5]))
    with pytest.raises(ValueError, match="integer flat indices"):
        shader.luminance(np.array([0.0, 1.0]), np.array([1.5, 1.5]))
    with pytest.raises(ValueError, match=r"\[t0, t1\]"):
        shader.frame(0.5)
    with pytest.raises(ValueError, match="perfect square"):
        EventShader(boxes, 3, t0=1.0, t1=2.0)
    with pytest.raises(ValueError, match="t0 < t1"):
        EventShader(boxes, 4, t0=2.0, t1=2.0)
    assert shader.luminance(np.zeros(0, dtype=np.int64), np.zeros(0)).shape == (0,)


def test_a_pixel_is_the_mean_of_its_subsamples_bit_for_bit(boxes):
    """The per-pixel sampler takes block-end pixel values from EventShader.subsamples."""
    from sim.pixel_sampling import pixel_means

    shader = EventShader(boxes, 4, t0=3.5, t1=3.7)
    shape = (boxes.camera.height, boxes.camera.width)
    for t in (3.5, 3.5731, 3.7):
        np.testing.assert_array_equal(pixel_means(shader.subsamples(t), shape), shader.frame(t))


BOX_LOW, BOX_HIGH = np.array([-0.1, 0.9, -0.13]), np.array([0.2, 1.1, 0.17])
SIDE_LIGHT = np.array([0.3, 1.0, -0.2])            # the direction the light travels


def _slab(origin: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit distances (N,) of rays (N, 3) through the box (entry > exit: a miss)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (BOX_LOW - origin) / direction
        b = (BOX_HIGH - origin) / direction
    return np.nanmax(np.minimum(a, b), axis=1), np.nanmin(np.maximum(a, b), axis=1)


def test_geometry_sees_the_analytic_box_wall_and_shadow_on_every_sub_sample():
    """A box before a wall, lit from the side, through a distorting lens with fx != fy: each
    sub-sample's surface (box, wall or nothing), whether the light reaches it (the box's
    shadow on the wall, by a ray-box test from the wall's hit) and its normal, against
    ray-plane and ray-box intersections in float64 of the sub-samples' own rays. Rays within
    1e-4 of a box face's border are left out (float32 in the kernel)."""
    scene = parse_scene(scene_text(BOX_BEFORE_WALL, camera=LENS_CAMERA, lights=SIDE_LIGHT_TOML))
    renderer = Renderer(scene, spp=4)
    shader = EventShader(renderer, 4, t0=0.0, t1=0.5)
    key, normal = shader.geometry(0.25)
    n, (height, width) = 2, shader.shape
    assert key.shape == (height * n, width * n) and normal.shape == key.shape + (3,)

    local = sim.shader.subsample_directions(scene.camera, 4, renderer.seed)
    pose = scene.trajectory.pose(np.array([0.25]))[0]
    rays = local @ pose[:3, :3].T
    origin = pose[:3, 3]
    entry, exit_ = _slab(origin, rays)
    on_box = (entry <= exit_) & (exit_ > 0)
    wall_t = (2.0 - origin[1]) / rays[:, 1]
    hit_wall = origin + wall_t[:, None] * rays
    on_wall = ~on_box & (wall_t > 0) & np.all(np.abs(hit_wall[:, [0, 2]]) < 2.0, axis=1)
    back = -SIDE_LIGHT / np.linalg.norm(SIDE_LIGHT)
    s_entry, s_exit = _slab(hit_wall, np.broadcast_to(back, hit_wall.shape))
    shadowed = on_wall & (s_entry <= s_exit) & (s_exit > 0)
    # Keep away from the box's borders: rays whose slab test is within 1e-4 of changing.
    clear = np.abs(exit_ - entry) > 1e-4 * np.abs(exit_)
    clear &= ~on_wall | (np.abs(s_exit - s_entry) > 1e-4 * np.abs(s_exit))

    def grid(a: np.ndarray) -> np.ndarray:
        a = a.reshape(height, width, n, n, *a.shape[1:])
        return a.swapaxes(1, 2).reshape(height * n, width * n, *a.shape[4:])

    on_box, on_wall, shadowed, clear = (grid(a) for a in (on_box, on_wall, shadowed, clear))
    assert on_box.sum() > 200 and on_wall.sum() > 2000 and shadowed.sum() > 100
    shape_of = key & 0xFFFF
    box_id, wall_id = np.unique(shape_of[on_box & clear]), np.unique(shape_of[on_wall & clear])
    assert len(box_id) == len(wall_id) == 1 and box_id[0] != wall_id[0] and 0 not in box_id
    np.testing.assert_array_equal(shape_of[clear], np.where(
        on_box, box_id[0], np.where(on_wall, wall_id[0], 0))[clear])
    lit = (key >> 16) & 1
    np.testing.assert_array_equal(lit[clear & on_wall], ~shadowed[clear & on_wall])
    assert np.all(lit[clear & on_box] == 1)            # its front face turns to the light
    seen = normal[clear & (on_box | on_wall)]
    np.testing.assert_allclose(seen, np.broadcast_to([0.0, -1.0, 0.0], seen.shape), atol=1e-6)
    assert np.all(normal[clear & ~on_box & ~on_wall] == 0.0)


def test_the_pixels_geometry_marks_are_those_whose_point_samples_miss_the_pixel_s_value():
    """The same box, wall and shadow: against the pixels' converged values (256 sub-samples),
    every pixel whose 4-sample value is off by more than 2 % of the lit wall's is marked by
    :func:`sim.pixel_sampling.geometric_edges`, no unmarked pixel is off by more than float
    rounding (flat colours: only edges make a pixel's sub-samples differ), and on the marked
    pixels 16 sub-samples (``edge_spp``) are at most half as far off as 4, on average."""
    from sim.pixel_sampling import geometric_edges

    renderer = Renderer(parse_scene(scene_text(BOX_BEFORE_WALL, camera=LENS_CAMERA,
                                               lights=SIDE_LIGHT_TOML)), spp=4)
    frames = {spp: EventShader(renderer, spp, t0=0.0, t1=0.5).frame(0.25)
              for spp in (4, 16, 256)}
    marked = geometric_edges(*EventShader(renderer, 4, t0=0.0, t1=0.5).geometry(0.25),
                             frames[4].shape)
    scale = frames[256].max()               # the shadow is black: errors relative to the wall
    error = {spp: np.abs(frames[spp] - frames[256]) / scale for spp in (4, 16)}
    off = error[4] > 0.02
    assert off.sum() > 50 and marked.mean() < 0.25
    assert np.all(marked[off])
    assert error[4][~marked].max() < 1e-5
    assert error[16][marked].mean() < 0.5 * error[4][marked].mean()


def test_the_render_seed_draws_other_sub_samples_of_the_same_scene():
    """``[render] seed`` moves the event camera's sub-samples and the frames' sampler, not the
    scene: another render seed changes pixels by sampling noise only, another scene seed
    redraws the wall's random shapes (and an explicit ``Renderer(seed=)`` wins over both)."""
    scene = parse_scene(scene_text(WALL))
    other_render = replace(scene, render=replace(scene.render, seed=scene.seed + 1))
    other_scene = replace(scene, seed=scene.seed + 1)
    renderers = [Renderer(s, spp=4) for s in (scene, other_render, other_scene)]
    assert [r.seed for r in renderers] == [scene.seed, scene.seed + 1, scene.seed + 1]
    assert Renderer(other_render, spp=4, seed=11).seed == 11
    events = [EventShader(r, 4, t0=0.0, t1=0.5).frame(0.25) for r in renderers]
    frames = [r.luminance(0.25) for r in renderers]
    for values in (events, frames):
        sampling = np.abs(values[1] - values[0]).mean()
        redrawn = np.abs(values[2] - values[0]).mean()
        assert sampling > 0.0                                  # other sub-samples
        assert sampling < 0.3 * redrawn, (sampling, redrawn)   # of the same wall
