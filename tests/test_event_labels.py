"""Per-event labels (sim/event_labels.py): each event's cause and the object its pixel sees.

- object ids: a scene of known geometry (a wall and a box in front of it) seen by a rotating
  camera; every event's id against the analytic ray cast of its pixel at its own time (exact
  for a static scene; within the bracket bound with the box moving);
- causes: noise presets with shot noise, hot pixels and leak, each label checked against its
  generator (hot pixels only at the emulator's hot pixels, shot counts against the Poisson
  rate, leak only with leak on and following the leak-free rule, recomputed here by hand);
- files: the labels do not change the events; h5, txt and ``Sequence.event_labels`` agree and
  are aligned one-to-one with the events; an interrupted run resumes to the same labels.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from sim.event_depth import nearer_object
from sim.event_labels import (
    CAUSE_HOT_PIXEL,
    CAUSE_LEAK,
    CAUSE_SHOT,
    CAUSE_SIGNAL,
    CAUSES,
    LABELS_TXT_NAME,
    NO_OBJECT,
    TextEventLabelWriter,
    read_event_labels,
)
from sim.eventio import EVENT_DTYPE, read_events
from sim.events import EventEmulator, EventParams
from sim.noise import NoiseParams, leak_drift
from sim.pixel_sampling import PixelEventEmulator
from sim.sampling import SamplingParams
from sim.scene import parse_scene
from sim.sequence import load_sequence
from sim.simulate import simulate
from tests.conftest import interrupted_pixel_blocks, scene_text

# A wall 1.5 m away, 1.6 m wide (its left and right edges in view: pixels beyond them see
# nothing), and a box 0.2 m wide 0.8 m away in front of it.
WALL_Y, WALL_HALF = 1.5, (0.8, 3.0)
BOX_CENTRE, BOX_HALF = np.array([0.1, 0.8, 0.0]), 0.1
OBJECTS = f"""
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, {WALL_Y}, 0.0]
size = [{2 * WALL_HALF[0]}, {2 * WALL_HALF[1]}]
material = {{ texture = {{ type = "checkerboard", squares = [6, 9], color0 = 0.1, color1 = 0.8 }} }}

[[objects]]
name = "box"
type = "box"
center = [{BOX_CENTRE[0]}, {BOX_CENTRE[1]}, {BOX_CENTRE[2]}]
size = [{2 * BOX_HALF}, {2 * BOX_HALF}, {2 * BOX_HALF}]
material = {{ texture = {{ type = "checkerboard", squares = [4, 4], color0 = 0.1, color1 = 0.9 }} }}
"""
CAMERA = "[camera]\nwidth = 48\nheight = 36\nfx = 36.0\nfy = 36.0\ncx = 23.5\ncy = 17.5\n"
# A camera turning about its centre (no translation): about 1 rad/s at its peaks.
ROTATING = ('[trajectory]\ntype = "handheld"\nposition = [0.0, 0.0, 0.0]\n'
            'look_at = [0.0, 1.0, 0.0]\ntranslation_amplitude = [0.0, 0.0, 0.0]\n'
            'rotation_amplitude = [8.0, 8.0, 8.0]\nfrequencies = [2.0, 2.5, 1.5, 2.2, 1.8, 2.4]\n')
EXTRA = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n"
BOX_VELOCITY = np.array([0.5, 0.0, 0.3])            # m/s, for the moving box
MOVING = OBJECTS.replace('name = "box"', 'name = "box"\nmotion = { type = "linear", velocity = '
                         f'[{BOX_VELOCITY[0]}, {BOX_VELOCITY[1]}, {BOX_VELOCITY[2]}] }}')
FORMATS = ("h5", "txt", "depth-txt")
SAMPLING = SamplingParams(max_rate=2000.0)
DURATION = 0.06
# Noise strong enough to label thousands of events in a short window.
NOISE = NoiseParams(shot_noise_rate=20.0, shot_noise_bright_factor=1.0, leak_rate=5.0,
                    hot_pixel_fraction=0.01, hot_pixel_rate=200.0)


def _scene(objects: str = OBJECTS):
    return parse_scene(scene_text(objects, camera=CAMERA, trajectory=ROTATING,
                                  duration=DURATION, extra=EXTRA))


def _run(sampler, tmp_path_factory, name, noise=NOISE, objects=OBJECTS):
    scene = _scene(objects)
    params = EventParams(seed=scene.seed, noise=noise)
    out = tmp_path_factory.mktemp(name) / "seq"
    result = simulate(scene, out, progress=False, event_formats=FORMATS, sampler=sampler,
                      sampling=SAMPLING, events=params)
    assert result.sampler == sampler
    return scene, params, result


@pytest.fixture(scope="module")
def pixel_run(tmp_path_factory):
    return _run("pixel", tmp_path_factory, "pixel")


@pytest.fixture(scope="module")
def frame_run(tmp_path_factory):
    return _run("frame", tmp_path_factory, "frame")


@pytest.fixture(scope="module")
def moving_run(tmp_path_factory):
    return _run("frame", tmp_path_factory, "moving", objects=MOVING)


# --- object ids against the analytic ray cast -------------------------------------------------

def _analytic_ids(scene, x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The object (0 wall, 1 box, -1 none) hit by the centre ray of pixels (x, y) at times t
    (seconds), from the trajectory's pose and the known geometry (the box where its motion,
    if any, has taken it)."""
    centres = scene.camera.normalized_pixel_centres()[y, x]          # (N, 2)
    rays = np.column_stack([centres, np.ones(len(x))])
    poses = scene.trajectory.pose(t)                                 # (N, 4, 4)
    d = np.einsum("nij,nj->ni", poses[:, :3, :3], rays)
    o = poses[:, :3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        s_wall = (WALL_Y - o[:, 1]) / d[:, 1]
        hit = o + s_wall[:, None] * d
        wall = (s_wall > 0) & (np.abs(hit[:, 0]) <= WALL_HALF[0]) \
            & (np.abs(hit[:, 2]) <= WALL_HALF[1])
        centre = BOX_CENTRE + (t[:, None] * BOX_VELOCITY if scene.is_dynamic else 0.0)
        lo = (centre - BOX_HALF - o) / d
        hi = (centre + BOX_HALF - o) / d
    near = np.minimum(lo, hi).max(axis=1)
    far = np.maximum(lo, hi).min(axis=1)
    box = (near <= far) & (far > 0) & (~wall | (near < s_wall))
    return np.where(box, 1, np.where(wall, 0, NO_OBJECT))


def _labelled_events(result):
    events = read_event_labels(result.out / "events.h5")
    assert events is not None and len(events) == result.n_events > 1000
    return events, events["x"].astype(np.intp), events["y"].astype(np.intp), events["t"] * 1e-9


@pytest.mark.parametrize("run", ["pixel_run", "frame_run"])
def test_object_ids_of_a_static_scene_are_exact(run, request):
    """A static scene: each event's id is its own pixel-centre ray's at its own time."""
    scene, _, result = request.getfixturevalue(run)
    events, x, y, t = _labelled_events(result)
    assert np.array_equal(events["object_id"], _analytic_ids(scene, x, y, t))
    # Every kind of id occurs: the wall, the box and nothing.
    assert {0, 1, NO_OBJECT} <= set(events["object_id"].tolist())
    meta = json.loads((result.out / "sequence.json").read_text())
    assert meta["events"]["labels"]["objects"] == {"-1": None, "0": "wall", "1": "box"}
    assert "own time" in meta["events"]["labels"]["object_rule"]


def test_object_ids_of_a_moving_object_within_the_bound(moving_run):
    """A moving box: where the analytic id is the same over the event's time +- one bracket
    (1 / min_rate), the label is exactly it; elsewhere (a boundary crossed the pixel), one of
    the ids seen within that window (the bound of sim/event_labels.py)."""
    scene, _, result = moving_run
    events, x, y, t = _labelled_events(result)
    bracket = 1.0 / SAMPLING.min_rate
    window = np.stack([_analytic_ids(scene, x, y, np.clip(t + f * bracket, 0, DURATION))
                       for f in np.linspace(-1.0, 1.0, 17)])
    at_t = _analytic_ids(scene, x, y, t)
    steady = np.all(window == at_t, axis=0)
    label = events["object_id"]
    assert np.array_equal(label[steady], at_t[steady])
    assert np.all(np.any(window == label, axis=0))
    assert steady.mean() > 0.5             # events gather at edges, where ids change
    assert {0, 1, NO_OBJECT} <= set(label.tolist())
    meta = json.loads((result.out / "sequence.json").read_text())
    assert "nearer in time" in meta["events"]["labels"]["object_rule"]


def test_nearer_object_by_hand():
    ids = nearer_object(np.array([0, 1, 2, 2]), np.array([1, 1, 0, 3]),
                        np.array([0.2, 0.9, 0.5, 0.51]))
    assert ids.dtype == np.int32 and ids.tolist() == [-1, 0, 1, 2]


# --- causes -------------------------------------------------------------------------------------

@pytest.mark.parametrize("run", ["pixel_run", "frame_run"])
def test_causes_follow_their_generators(run, request):
    scene, params, result = request.getfixturevalue(run)
    events = read_event_labels(result.out / "events.h5")
    cause = events["cause"]
    assert set(np.unique(cause).tolist()) == set(CAUSES)
    shape = (scene.camera.height, scene.camera.width)
    hot = EventEmulator(shape, params).hot_mask                    # drawn from the seed
    at_hot = hot[events["y"], events["x"]]
    # Hot-pixel events only at hot pixels, all ON; their number is Poisson(rate n T).
    assert np.all(at_hot[cause == CAUSE_HOT_PIXEL])
    assert np.all(events["p"][cause == CAUSE_HOT_PIXEL] == 1)
    mean = NOISE.hot_pixel_rate * hot.sum() * DURATION
    assert abs(np.count_nonzero(cause == CAUSE_HOT_PIXEL) - mean) < 5 * math.sqrt(mean)
    # Shot events: Poisson(rate H W T) (a flat rate: bright factor 1), ON and OFF alike.
    shot = cause == CAUSE_SHOT
    mean = NOISE.shot_noise_rate * hot.size * DURATION
    assert abs(np.count_nonzero(shot) - mean) < 5 * math.sqrt(mean)
    on = np.count_nonzero(events["p"][shot] == 1)
    assert abs(on - shot.sum() / 2) < 5 * math.sqrt(shot.sum() / 4)
    # Leak events are ON (the drift lowers the reference).
    assert np.all(events["p"][cause == CAUSE_LEAK] == 1)
    assert np.count_nonzero(cause == CAUSE_SIGNAL) > np.count_nonzero(cause == CAUSE_LEAK) > 0


def test_without_noise_every_event_is_signal(tmp_path_factory):
    scene, _, result = _run("pixel", tmp_path_factory, "ideal", noise=NoiseParams())
    events = read_event_labels(result.out / "events.h5")
    assert len(events) > 1000 and np.all(events["cause"] == CAUSE_SIGNAL)


def test_leak_off_gives_no_leak_label_and_the_same_other_labels(tmp_path_factory, pixel_run):
    """Without leak no event is a leak event; the shot and hot-pixel events, drawn after the
    leak's draws from the same generator, are then other draws, but still labelled."""
    _, _, result = _run("pixel", tmp_path_factory, "noleak", noise=replace(NOISE, leak_rate=0.0))
    cause = read_event_labels(result.out / "events.h5")["cause"]
    assert CAUSE_LEAK not in cause
    assert {CAUSE_SIGNAL, CAUSE_SHOT, CAUSE_HOT_PIXEL} <= set(cause.tolist())


def _crossings(level: float, ref: float, c_on: float, c_off: float) -> tuple[int, int]:
    """(count, polarity) of the crossings from reference ``ref`` to ``level``, by hand."""
    if level >= ref + c_on:
        return math.floor((level - ref) / c_on), 1
    if level <= ref - c_off:
        return math.floor((ref - level) / c_off), -1
    return 0, 0


def test_frame_emulator_leak_rule_recomputed_by_hand():
    """The leak rule of sim/noise.py, recomputed by hand: per pixel and interval, the
    crossings against the leak-free reference (the reference before this interval's drift)
    are signal, those beyond that count leak (the drift redrawn from the emulator's generator,
    whose first draw of an interval it is)."""
    shape = (6, 7)
    noise = NoiseParams(leak_rate=40.0, leak_jitter=0.3)
    params = EventParams(seed=5, noise=noise)
    emulator = EventEmulator(shape, params)
    rng = np.random.default_rng(1)
    frames = np.cumsum(rng.normal(0.0, 0.08, (60, *shape)), axis=0)
    frames[:, :2] = 0.3                                       # two static rows: leak only
    times = np.arange(60) * 2e-3
    emulator.start(frames[0], times[0])
    leak_seen = signal_seen = 0
    for k in range(1, len(times)):
        before = emulator.ref.copy()
        replay = np.random.default_rng()
        replay.bit_generator.state = emulator.get_state()["rng"]
        drift = leak_drift(times[k] - times[k - 1], emulator.c_on, emulator.leak_rates, noise,
                           replay)
        events = emulator.advance(frames[k], times[k])
        causes = emulator.last_causes
        assert len(causes) == len(events)
        for yy in range(shape[0]):
            for xx in range(shape[1]):
                c_on, c_off = emulator.c_on[yy, xx], emulator.c_off[yy, xx]
                n, p = _crossings(frames[k, yy, xx], before[yy, xx] + drift[yy, xx], c_on, c_off)
                n_free, p_free = _crossings(frames[k, yy, xx], before[yy, xx], c_on, c_off)
                mine = causes[(events["y"] == yy) & (events["x"] == xx)]
                assert len(mine) == n
                leak = n if p_free != p else max(n - n_free, 0)
                assert np.count_nonzero(mine == CAUSE_LEAK) == leak
                assert np.all(mine[:n - leak] == CAUSE_SIGNAL)      # the leak ones come last
                if yy < 2:
                    assert np.all(mine == CAUSE_LEAK)
                leak_seen += leak
                signal_seen += n - leak
    assert leak_seen > 20 and signal_seen > 100


def test_pixel_emulator_static_pixels_fire_leak_events_only():
    """Per-pixel samples of a static pixel: every event is leak, at the leak's rate."""
    shape = (1, 3)
    params = EventParams(seed=2,
                         noise=NoiseParams(leak_rate=100.0, leak_rate_cov_decades=0.0,
                                           leak_jitter=0.0))
    emulator = PixelEventEmulator(shape, params)
    emulator.start(np.zeros(shape), 0.0)
    total = []
    for block in range(10):
        t0, t1 = block * 10_000_000, (block + 1) * 10_000_000
        pixels = np.repeat(np.arange(3), 5)
        times = np.tile(np.linspace(t0, t1, 5).astype(np.int64), 3)
        events = emulator.advance_samples(pixels, times, np.zeros(15), np.ones(15), t1,
                                          np.ones(shape))
        assert np.all(emulator.last_causes == CAUSE_LEAK) and len(emulator.last_causes) == \
            len(events)
        total.append(len(events))
    # 100 Hz for 0.1 s per pixel, exactly (no jitter, no spread): 10 each, +-1 at the ends.
    assert abs(sum(total) - 30) <= 3


# --- files --------------------------------------------------------------------------------------

@pytest.mark.parametrize("run", ["pixel_run", "frame_run"])
def test_labels_are_aligned_with_the_events_in_every_file(run, request):
    _, _, result = request.getfixturevalue(run)
    from_h5 = read_event_labels(result.out / "events.h5")
    from_txt = read_event_labels(result.out / "events.txt")
    from_depth_txt = read_event_labels(result.out / "events_depth.txt")
    assert np.array_equal(from_h5, from_txt) and np.array_equal(from_h5, from_depth_txt)
    plain = read_events(result.out / "events.txt")
    lines = (result.out / LABELS_TXT_NAME).read_text().splitlines()
    assert len(lines) == len(plain) == len(from_h5)
    for name in EVENT_DTYPE.names:
        assert np.array_equal(from_h5[name], plain[name])
    sequence = load_sequence(result.out)
    t0, t1 = int(from_h5["t"][50]), int(from_h5["t"][-50])
    window = sequence.event_labels(t0, t1)
    assert np.array_equal(window, from_h5[(from_h5["t"] >= t0) & (from_h5["t"] < t1)])
    meta = json.loads((result.out / "sequence.json").read_text())
    assert meta["events"]["labels"]["causes"] == {"0": "signal", "1": "shot", "2": "leak",
                                                   "3": "hot_pixel"}


@pytest.mark.parametrize("sampler", ["pixel", "frame"])
def test_labels_do_not_change_the_events(sampler, pixel_run, frame_run, tmp_path):
    """A run without motion truth (no labels, no depth) writes the same events."""
    scene, params, result = pixel_run if sampler == "pixel" else frame_run
    plain = simulate(scene, tmp_path / "plain", progress=False, event_formats=("h5", "txt"),
                     sampler=sampler, sampling=SAMPLING, events=params, motion_truth=False)
    assert (plain.out / "events.txt").read_bytes() == (result.out / "events.txt").read_bytes()
    assert not (plain.out / LABELS_TXT_NAME).exists()
    assert load_sequence(plain.out).event_labels() is None


def test_an_interrupted_run_resumes_to_the_same_labels(pixel_run, tmp_path, monkeypatch):
    scene, params, result = pixel_run
    out = tmp_path / "cut"
    with interrupted_pixel_blocks(monkeypatch, 4), pytest.raises(KeyboardInterrupt):
        simulate(scene, out, progress=False, event_formats=FORMATS, sampler="pixel",
                 sampling=SAMPLING, events=params)
    assert (out.parent / "cut.partial" / f"{LABELS_TXT_NAME}.partial").exists()
    simulate(scene, out, progress=False, event_formats=FORMATS, sampler="pixel", resume=True,
             sampling=SAMPLING, events=params)
    for name in ("events.h5", LABELS_TXT_NAME, "events.txt"):
        assert (out / name).read_bytes() == (result.out / name).read_bytes(), name


def test_label_writer_and_reader_refuse_bad_input(tmp_path):
    events = np.zeros(2, EVENT_DTYPE)
    events["p"] = 1
    with TextEventLabelWriter(tmp_path / LABELS_TXT_NAME) as writer, \
            pytest.raises(ValueError, match="one value per event"):
        writer.write(events, np.zeros(1, np.uint8), np.zeros(2, np.int32))
    (tmp_path / "events.txt").write_text("0.000000001 0 0 1\n0.000000002 1 0 0\n")
    (tmp_path / LABELS_TXT_NAME).write_text("0 1\n")
    with pytest.raises(ValueError, match="1 lines for the 2 events"):
        read_event_labels(tmp_path / "events.txt")
    (tmp_path / LABELS_TXT_NAME).write_text("0 1\n7 1\n")
    with pytest.raises(ValueError, match="event 1: cause 7"):
        read_event_labels(tmp_path / "events.txt")
