"""evfuse twin (sim.twin) and the recording statistics it is compared with (sim.statistics).

The twin test builds its "recording" by simulating slider_close (a textured poster parallel to
the image plane at 0.231 m): its twin at the same depth is the same view, so its first frame and
exact depth must come back.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from scenes import resolve_scene
from sim import load_scene, read_calib, read_depth, simulate
from sim.statistics import compare_stats, frame_noise
from sim.twin import write_twin
from tests.conftest import run_cli

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "ecd_slider_depth_first50k"


def _smooth(shape=(120, 160)) -> np.ndarray:
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    return 100 + 40 * np.sin(u / 17.0) * np.cos(v / 23.0) + 0.3 * u


@pytest.mark.parametrize("sigma", [1.0, 2.0, 5.0])
def test_frame_noise_measures_white_noise_on_a_smooth_image(sigma):
    rng = np.random.default_rng(int(sigma * 10))
    image = _smooth() + rng.normal(0, sigma, (120, 160))
    assert frame_noise(image) == pytest.approx(sigma, rel=0.1)


def test_frame_noise_ignores_edges_and_clipped_pixels():
    image = _smooth()
    image[:, 80:] += 80                                   # a strong edge
    assert frame_noise(image) < 0.05                      # edges and smooth shading: no noise
    frame = np.clip(image, 0, 255).astype(np.uint8)
    frame[:40] = 255                                      # a saturated band
    noisy = frame.astype(np.float64) + np.random.default_rng(1).normal(0, 2.0, frame.shape)
    noisy[:40] = 255
    estimate = frame_noise(np.clip(np.round(noisy), 0, 255).astype(np.uint8))
    assert estimate == pytest.approx(np.sqrt(4 + 1 / 12), rel=0.15)   # + rounding's 1/12
    with pytest.raises(ValueError, match="at least 3x3"):
        frame_noise(np.zeros((2, 5)))


def test_compare_stats_lines_up_figures_and_ratios():
    rows = compare_stats({"count": 10, "on_fraction": 0.5, "name": "a", "only_a": 1},
                         {"count": 25, "on_fraction": 0.4, "name": "b"})
    assert rows == [("count", 10, 25, 2.5), ("on_fraction", 0.5, 0.4, pytest.approx(0.8)),
                    ("name", "a", "b", None)]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    scene = load_scene(resolve_scene("slider_close"))
    # Noiseless frames on both sides, so that the test sees the geometry (a DAVIS frame as a
    # texture would be vignetted twice and its noise rendered again).
    scene = dataclasses.replace(scene, camera=dataclasses.replace(
        scene.camera, width=96, height=72, fx=scene.camera.fx * 0.4, fy=scene.camera.fy * 0.4,
        cx=47.5, cy=35.5), frames=scene.frames.with_sensor("ideal"))
    out = tmp_path_factory.mktemp("twin") / "recording"
    simulate(scene, out, start=1.0, duration=0.1, with_events=False, progress=False, spp=4)
    return out


def test_the_twin_of_a_poster_at_its_own_depth_is_the_same_view(recording, tmp_path):
    scene_file = write_twin(recording, tmp_path / "twin", 0.231, frame_sensor="ideal")
    twin = load_scene(scene_file)
    source = read_calib(recording / "calib.txt", 96, 72)
    for name in ("width", "height", "fx", "fy", "cx", "cy"):
        assert getattr(twin.camera, name) == pytest.approx(getattr(source, name), rel=1e-8)
    out = tmp_path / "twin_seq"
    simulate(twin, out, duration=0.05, with_events=False, progress=False, spp=4)
    original = cv2.imread(str(sorted((recording / "images").glob("*.png"))[0]), 0)
    copy = cv2.imread(str(sorted((out / "images").glob("*.png"))[0]), 0)
    inner = (slice(4, -4), slice(4, -4))
    assert np.corrcoef(original[inner].ravel(), copy[inner].ravel())[0, 1] > 0.95
    depth = read_depth(sorted((out / "depth").glob("*.exr"))[0])
    np.testing.assert_allclose(depth, 0.231, rtol=1e-4)
    # The poses are the recording's, shifted to start at 0.
    rows = np.loadtxt(tmp_path / "twin" / "groundtruth.txt")
    source = np.loadtxt(recording / "groundtruth.txt")
    t0 = source[0, 0]
    np.testing.assert_allclose(rows[:, 1:], source[:len(rows), 1:])
    np.testing.assert_allclose(rows[:, 0], source[:len(rows), 0] - t0, atol=1e-9)


def test_twin_refuses_what_it_cannot_copy(recording, tmp_path):
    """The library's refusals name write_twin's parameters, never a flag."""
    with pytest.raises(ValueError, match="^depth must be a finite number > 0"):
        write_twin(recording, tmp_path / "t", 0.0)
    with pytest.raises(ValueError, match="window .* is not inside groundtruth.txt's poses"):
        write_twin(recording, tmp_path / "t", 0.2, (0.0, 50.0))
    # Checked as depth is (sim.validation.positive): a non-number is a ValueError too.
    with pytest.raises(ValueError, match="^frame_gamma must be a number, got '1'"):
        write_twin(recording, tmp_path / "t", 0.2, frame_gamma="1")
    with pytest.raises(ValueError, match="^illuminance must be a finite number > 0, got 0"):
        write_twin(recording, tmp_path / "t", 0.2, illuminance=0)
    with pytest.raises(ValueError, match=r"^window 0.8,0.2: expected T0 < T1 \(the window's"):
        write_twin(recording, tmp_path / "t", 0.2, (0.8, 0.2))
    assert run_cli(["twin", str(recording), "--depth", "0.2", "--window", "1", "--out",
                 str(tmp_path / "t")]) == 2


@pytest.mark.skipif(not SHARED.is_dir(), reason="the shared ECD recording is absent")
def test_events_stats_compare_prints_two_recordings_side_by_side(capsys, tmp_path):
    assert run_cli(["events", str(SHARED), "--stats", "--compare", str(SHARED), "--out",
                 str(tmp_path / "ef.png")]) == 0
    lines = capsys.readouterr().out.splitlines()
    rate = next(line for line in lines if line.split()[0] == "rate_ev_per_s")
    assert rate.split()[1:] == ["293522", "293522", "1"]
    noise = next(line for line in lines if line.split()[0] == "frame_noise")
    assert 0.5 < float(noise.split()[1]) < 5                # a real APS frame's noise, DN
    assert run_cli(["events", str(SHARED), "--compare", str(SHARED)]) == 2
    assert "--compare compares statistics: add --stats" in capsys.readouterr().err


@pytest.mark.skipif(not SHARED.is_dir(), reason="the shared ECD recording is absent")
def test_the_twin_of_slider_depth_fires_like_the_recording(tmp_path):
    # Issue 14's match: event rate, ON/OFF balance and the share of pixels that fire within a
    # factor 1.5 of the recording's, the frames' noise in flat areas within a factor 2. The
    # twin: the README's commands (poster at the map's median depth 0.88 m, DAVIS frames,
    # the realistic event camera at C = 0.4).
    from sim.eventio import read_events
    from sim.events import EventParams
    from sim.noise import noise_preset
    from sim.statistics import event_stats

    scene = load_scene(write_twin(SHARED, tmp_path / "twin", 0.88, (0.0223, 0.1742)))
    out = tmp_path / "seq"
    simulate(scene, out, progress=False, event_formats=("h5",),
             events=EventParams(contrast_on=0.4, contrast_off=0.4,
                                noise=noise_preset("realistic")))
    real = event_stats(read_events(SHARED / "events.txt", 240, 180), 240, 180)
    twin = event_stats(read_events(out / "events.h5", 240, 180), 240, 180)
    for key in ("rate_ev_per_s", "on_fraction", "active_pixels"):
        assert 1 / 1.5 < twin[key] / real[key] < 1.5, key
    noise = [frame_noise(cv2.imread(str(p), 0)) for p in sorted((out / "images").glob("*.png"))]
    real_noise = frame_noise(cv2.imread(str(SHARED / "images" / "frame_00000000.png"), 0))
    assert 0.5 < np.median(noise) / real_noise < 2


def test_a_twin_gives_mid_grey_frames_with_its_realistic_sensor(ecd_slider, tmp_path):
    """A twin's davis240c_aps frames stopped at the sensor's 5 ms: on 400 lux a mean grey of a
    few levels, which region growing merges (issue 21). Its auto-exposure may now go to 40 ms,
    as the built-in twins'."""
    from sim.scene import load_scene
    from sim.twin import write_twin
    from tests.test_builtin_frames import MEAN_GREY, realistic_frame_greys

    scene = load_scene(write_twin(ecd_slider, tmp_path / "twin", 0.6, window=(0.5, 1.0)))
    assert scene.frames.max_exposure <= 1.0 / scene.frames.rate
    means, exposures, _ = realistic_frame_greys(scene, [0.25])
    assert MEAN_GREY[0] <= means[0] <= MEAN_GREY[1], (means, exposures)
