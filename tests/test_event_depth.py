"""Per-event depth (sim/event_depth.py): each event's depth against a direct depth render at the
event's own time, on a static scene (per-pixel sampler) and a dynamic one (frame sampler)."""

from __future__ import annotations

import importlib
import json

import numpy as np
import pytest

from sim.event_depth import (
    EDGE_JUMP,
    FLAG_EDGE,
    FLAG_NO_SURFACE,
    EventDepth,
    interpolate_depth,
    read_event_depth,
)
from sim.eventio import read_events
from sim.render import Renderer
from sim.sampling import SamplingParams
from sim.scene import parse_scene
from sim.sequence import load_sequence
from sim.simulate import simulate
from tests.conftest import interrupted_pixel_blocks, scene_text

simulation = importlib.import_module("sim.simulate._run")        # simulate() and its steps

# A wall 1.5 m away and a box 0.8 m away in front of it: depth edges on every side of the box.
OBJECTS = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 1.5, 0.0]
size = [6.0, 6.0]
material = { texture = { type = "checkerboard", squares = [12, 12], color0 = 0.1, color1 = 0.8 } }

[[objects]]
name = "box"
type = "box"
center = [0.1, 0.8, 0.0]
size = [0.2, 0.2, 0.2]
material = { texture = { type = "checkerboard", squares = [4, 4], color0 = 0.1, color1 = 0.9 } }
"""
MOVING = OBJECTS.replace('name = "box"', 'name = "box"\nmotion = { type = "linear", '
                         'velocity = [0.8, 0.0, 0.3], angular_velocity = [0.0, 0.0, 90.0] }')
# fx != fy, an off-centre principal point and a distorting lens: a swapped axis, a 0.5 px
# convention error or an undistorted ray would put events on the wrong depth at the box's edges.
CAMERA = ("[camera]\nwidth = 48\nheight = 36\nfx = 45.0\nfy = 40.0\ncx = 23.3\ncy = 17.6\n"
          "distortion = [-0.2, 0.05, 0.001, -0.002, 0.0]\n")
# Hand-held: rotation and translation on every axis, about 1.5 rad/s and 0.6 m/s at their peaks.
HANDHELD = ('[trajectory]\ntype = "handheld"\nposition = [0.0, 0.0, 0.0]\n'
            'look_at = [0.0, 1.0, 0.0]\ntranslation_amplitude = [0.05, 0.05, 0.05]\n'
            'rotation_amplitude = [8.0, 8.0, 8.0]\nfrequencies = [2.0, 2.5, 1.5, 2.2, 1.8, 2.4]\n')
EXTRA = ("[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n"
         "[rig]\nevents_offset = 0.0123\n")
OFFSET_NS = 12_300_000
FORMATS = ("h5", "txt", "depth-txt")
SAMPLE = 200


def _scene(objects: str, duration: float):
    return parse_scene(scene_text(objects, camera=CAMERA, trajectory=HANDHELD,
                                  duration=duration, extra=EXTRA))


class _Brackets:
    """Record the bracket (t_a, t_b, ns on the simulation clock) of every annotated event."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.parts: list[tuple[np.ndarray, int, int]] = []
        real = EventDepth.annotate

        def annotate(depth, events, t):
            t_a = depth._t
            out = real(depth, events, t)
            if events is not None and len(events):
                self.parts.append((events["t"].copy(), round(t_a * 1e9), round(t * 1e9)))
            return out

        monkeypatch.setattr(EventDepth, "annotate", annotate)

    def of(self, times_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(t_a, t_b) of each event, by its time on the simulation clock."""
        t = np.concatenate([p[0] for p in self.parts])
        t_a = np.concatenate([np.full(len(p[0]), p[1]) for p in self.parts])
        t_b = np.concatenate([np.full(len(p[0]), p[2]) for p in self.parts])
        at = np.searchsorted(t, times_ns)
        assert np.array_equal(t[at], times_ns)
        return t_a[at], t_b[at]


def _run(objects, duration, sampler, tmp_path_factory, name):
    scene = _scene(objects, duration)
    # 2 kHz at most: the checkers' sub-pixel steps would send the frame sampler to 20 kHz.
    sampling = SamplingParams(max_rate=2000.0)
    with pytest.MonkeyPatch.context() as patch:
        brackets = _Brackets(patch)
        result = simulate(scene, tmp_path_factory.mktemp(name) / "seq", progress=False,
                          event_formats=FORMATS, sampler=sampler, sampling=sampling)
    assert result.sampler == sampler
    return scene, result, brackets


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    return _run(OBJECTS, 0.15, "pixel", tmp_path_factory, "static")


@pytest.fixture(scope="module")
def dynamic_run(tmp_path_factory):
    return _run(MOVING, 0.08, "frame", tmp_path_factory, "dynamic")


def _check_against_direct_renders(scene, result, brackets) -> dict:
    """The checks of the module docstring on a seeded sample of events; returns the figures."""
    events = read_event_depth(result.out / "events.h5")
    assert events is not None and len(events) == result.n_events > 2000
    sample = events[np.sort(np.random.default_rng(7).choice(len(events), SAMPLE, replace=False))]
    t_ns = sample["t"] - OFFSET_NS                              # back on the scene's clock
    t_a, t_b = brackets.of(t_ns)
    assert np.all((t_a <= t_ns) & (t_ns <= t_b))
    renderer = Renderer(scene, spp=1)
    grid = np.linspace(0.0, 1.0, 5)
    figures = {"unflagged": 0, "flagged": 0, "smooth": 0, "transient": 0, "worst_ratio": 0.0,
               "worst_rel": 0.0}
    for event, t, a, b in zip(sample, t_ns, t_a, t_b, strict=True):
        x, y = int(event["x"]), int(event["y"])
        direct = renderer.depth(t * 1e-9)
        truth = float(direct[y, x])
        # The pixel's depth across its bracket, straight from the renderer.
        path = np.array([renderer.depth((a + f * (b - a)) * 1e-9)[y, x] for f in grid],
                        np.float64)
        near = direct[max(y - 2, 0):y + 3, max(x - 2, 0):x + 3]     # 5x5 around the event
        near_edge = (near.min() == 0 < near.max()
                     or near.max() > (1 + EDGE_JUMP) * near.min()
                     or path.min() == 0 < path.max()
                     or path.max() > (1 + EDGE_JUMP) * path.min())
        error = abs(float(event["depth"]) - truth)
        if event["flag"]:
            figures["flagged"] += 1
            assert event["flag"] in (FLAG_EDGE, FLAG_NO_SURFACE)
            assert near_edge, f"event {event} flagged away from any depth edge"
            continue
        figures["unflagged"] += 1
        tol = 2e-6 * truth + 1e-7                                    # float32 ray casts
        steps = np.diff(path)
        if near_edge and np.any(steps > tol) and np.any(steps < -tol) and min(
                abs(path[0] - path[1:-1]).max(), abs(path[-1] - path[1:-1]).max()) > (
                EDGE_JUMP * path.min()):
            # A surface came and went within the bracket (the two renders agree, the pixel
            # saw something else between them): outside the bound, which holds for a depth
            # monotone over the bracket (module docstring of sim.event_depth). Counted.
            figures["transient"] += 1
            continue
        # Unflagged: within the edge bound, and no surface means 0.
        assert error <= EDGE_JUMP * truth + tol, (event, truth, path)
        if path.max() == 0:
            assert event["depth"] == 0 and truth == 0
            continue
        if near_edge:
            continue
        # One smooth surface across the bracket: the interpolation bound, with |z''| taken
        # from the second differences of the direct renders (twice the largest, as they
        # average z'' over a quarter of the bracket each).
        figures["smooth"] += 1
        h = (b - a) * 1e-9 / 4
        curvature = 2 * np.abs(np.diff(path, 2)).max() / h ** 2 if h > 0 else 0.0
        w = (t - a) * 1e-9
        bound = w * ((b - t) * 1e-9) / 2 * curvature
        assert error <= bound + tol, (event, truth, bound)
        figures["worst_ratio"] = max(figures["worst_ratio"], error / (bound + tol))
        figures["worst_rel"] = max(figures["worst_rel"], error / truth)
    return figures


def test_static_scene_per_pixel_sampler_depth_within_the_bound(static_run):
    figures = _check_against_direct_renders(*static_run)
    assert figures["smooth"] > SAMPLE / 2 and figures["flagged"] > 0
    assert figures["worst_rel"] < 1e-3
    # Edges that pass a pixel and leave within one 10-ms bracket are rare (1 of 200 here).
    assert figures["transient"] <= 0.02 * SAMPLE


def test_dynamic_scene_frame_sampler_depth_within_the_bound(dynamic_run):
    figures = _check_against_direct_renders(*dynamic_run)
    assert figures["smooth"] > SAMPLE / 2
    assert figures["worst_rel"] < 1e-3
    assert figures["transient"] <= 0.02 * SAMPLE


@pytest.mark.parametrize("run", ["static_run", "dynamic_run"])
def test_txt_h5_and_sequence_agree(run, request):
    scene, result, _ = request.getfixturevalue(run)
    from_h5 = read_event_depth(result.out / "events.h5")
    from_txt = read_event_depth(result.out / "events_depth.txt")
    assert np.array_equal(from_h5, from_txt)
    plain = read_events(result.out / "events.txt")
    for name in ("t", "x", "y", "p"):
        assert np.array_equal(from_h5[name], plain[name])
    sequence = load_sequence(result.out)
    t0, t1 = int(from_h5["t"][100]), int(from_h5["t"][-100])
    window = sequence.event_depth(t0, t1)
    assert np.array_equal(window, from_h5[(from_h5["t"] >= t0) & (from_h5["t"] < t1)])
    meta = json.loads((result.out / "sequence.json").read_text())
    assert meta["events"]["files"] == ["events.h5", "events.txt", "events_depth.txt"]
    assert meta["events"]["depth"]["edge_jump"] == EDGE_JUMP
    assert "event_depth" in meta["timings_s"]


def test_depth_does_not_change_the_events_and_real_folders_have_none(static_run, tmp_path):
    """The sampler shares its depth renders with the depth stage: the events stay the same
    with or without it; a folder without depth answers None."""
    scene, result, _ = static_run
    plain = simulate(scene, tmp_path / "plain", progress=False, event_formats=("txt",),
                     sampler="pixel", sampling=SamplingParams(max_rate=2000.0))
    assert (plain.out / "events.txt").read_bytes() == (result.out / "events.txt").read_bytes()
    assert load_sequence(plain.out).event_depth() is None


def test_an_interrupted_run_resumes_to_the_same_depth(static_run, tmp_path, monkeypatch):
    scene, result, _ = static_run
    out = tmp_path / "cut"
    with interrupted_pixel_blocks(monkeypatch, 8), pytest.raises(KeyboardInterrupt):
        simulate(scene, out, progress=False, event_formats=FORMATS, sampler="pixel",
                 sampling=SamplingParams(max_rate=2000.0))
    simulate(scene, out, progress=False, event_formats=FORMATS, sampler="pixel", resume=True,
             sampling=SamplingParams(max_rate=2000.0))
    for name in ("events.h5", "events_depth.txt", "events.txt"):
        assert (out / name).read_bytes() == (result.out / name).read_bytes(), name


def test_interpolate_depth_by_hand():
    a = np.array([1.0, 1.0, 1.0, 0.0, 2.0, 0.0, 1.0], np.float32)
    b = np.array([1.02, 1.2, 1.2, 3.0, 0.0, 0.0, 1.0], np.float32)
    w = np.array([0.5, 0.4, 0.6, 0.7, 0.5, 0.3, 1.0])
    depth, flag = interpolate_depth(a, b, w)
    np.testing.assert_allclose(depth, [1.01, 1.0, 1.2, 3.0, 2.0, 0.0, 1.0], rtol=1e-6)
    assert flag.tolist() == [0, FLAG_EDGE, FLAG_EDGE, FLAG_NO_SURFACE, FLAG_NO_SURFACE, 0, 0]
    assert depth.dtype == np.float32 and flag.dtype == np.uint8


def test_brackets_must_go_forward():
    depth = EventDepth(lambda t: np.ones((2, 2), np.float32), 0.5)
    with pytest.raises(ValueError, match="before its start"):
        depth.annotate(None, 0.4)


def test_depth_text_reads_exactly_as_the_line_parser(tmp_path, monkeypatch):
    """``events_depth.txt`` is read by a compiled reading (times converted exactly by integer
    arithmetic) with the line-by-line parser as fallback: both give the same rows for every
    accepted form of a time (0 to 9 decimals, ``5.``, large seconds, tabs, CRLF, comments),
    a window and a byte span read the same rows, and a bad line is named."""
    from sim.event_depth import _parse_lines, read_event_depth_span

    lines = [b"0 1 2 1 1.5 0", b"0.000000001\t5 6 1 2.25 1", b"0.5 3 4 0 0 2", b"1. 7 8 0 0.125 0",
             b"12.34 9 9 1 3 0\r", b"9223372035.999999999 1 1 0 1e-3 1",
             b"9223372035.999999999 2 2 1 7 0"]
    path = tmp_path / "events_depth.txt"
    path.write_bytes(b"\n".join(lines) + b"\n")
    expected = _parse_lines(path, enumerate(lines, 1))        # the line parser, alone
    assert expected["t"].tolist() == [0, 1, 500_000_000, 1_000_000_000, 12_340_000_000,
                                      9_223_372_035_999_999_999, 9_223_372_035_999_999_999]
    depth_module = importlib.import_module("sim.event_depth")
    with monkeypatch.context() as patch:                      # the compiled reading, alone
        patch.setattr(depth_module, "_parse_lines", lambda *a: pytest.fail("line by line"))
        np.testing.assert_array_equal(read_event_depth(path), expected)
    # a comment line sends the block line by line: the same rows
    path.write_bytes(b"# t x y p depth flag\n" + b"\n".join(lines) + b"\n")
    np.testing.assert_array_equal(read_event_depth(path), expected)
    np.testing.assert_array_equal(read_event_depth(path, 1, 12_340_000_000), expected[1:4])
    start = len(b"# t x y p depth flag\n") + len(lines[0]) + 1
    stop = start + len(lines[1]) + len(lines[2]) + 2
    np.testing.assert_array_equal(read_event_depth_span(path, start, stop, 3), expected[1:3])
    for bad, message in ((b"0.1 1 2 2 1.0 0", r"events_depth.txt:2: expected 't\[s\] x y p"),
                         (b"0.1 1 2 1 nan 0", "events_depth.txt:2: expected"),
                         (b"0.1234567891 1 2 1 1.0", "events_depth.txt:2: expected"),
                         (b".5 1 2 1 1.0 0", "events_depth.txt:2: expected")):
        path.write_bytes(lines[0] + b"\n" + bad + b"\n")
        with pytest.raises(ValueError, match=message):
            read_event_depth(path)
    path.write_bytes(lines[0] + b"\n" + b"0.1234567891 1 2 1 1.0 0\n")   # >9 decimals: cut
    assert read_event_depth(path)["t"].tolist() == [0, 123_456_789]
