"""evfuse simulate: the sequence folder, its determinism, and the command line."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from fusion.cli import main
from sim.eventio import read_events
from sim.exr import read_depth
from sim.scene import parse_scene
from sim.sequence import load_sequence
from sim.simulate import simulate
from sim.trajectory import read_trajectory
from tests.conftest import BOX_BEFORE_WALL, LENS_CAMERA, SIDE_LIGHT_TOML, scene_text

OBJECTS = """
[[objects]]
name = "poster"
type = "rectangle"
center = [0.0, 1.0, 0.0]
size = [4.0, 4.0]
material = { texture = { type = "noise", resolution = 128 } }
"""
MOVING = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
          "velocity = [0.2, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
FRAMES = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 2\n[render]\nspp = 4\n"


@pytest.fixture(scope="module")
def tiny_scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "tiny.toml"
    path.write_text(scene_text(OBJECTS, trajectory=MOVING, duration=0.3, extra=FRAMES))
    return path


@pytest.fixture(scope="module")
def tiny_run(tiny_scene_file, tmp_path_factory):
    scene = parse_scene(tiny_scene_file.read_text(), tiny_scene_file)
    out = tmp_path_factory.mktemp("runs") / "tiny"
    return scene, simulate(scene, out, progress=False)


def test_sequence_folder_has_the_conventions_layout(tiny_run):
    scene, result = tiny_run
    out = result.out
    for name in ("calib.txt", "groundtruth.txt", "images.txt", "depthmaps.txt", "sequence.json"):
        assert (out / name).is_file(), name
    assert not out.with_name(out.name + ".partial").exists()
    seq = load_sequence(out)
    assert len(seq.image_paths) == result.n_frames == len(seq.depth_paths) >= 5
    np.testing.assert_array_equal(seq.image_times, seq.depth_times)
    frame = cv2.imread(str(seq.image_paths[0]), cv2.IMREAD_UNCHANGED)
    assert frame.dtype == np.uint8 and frame.shape == (48, 64) and frame.std() > 0
    depth = read_depth(seq.depth_paths[0])
    assert depth.dtype == np.float32 and depth.shape == (48, 64)
    np.testing.assert_allclose(depth, 1.0, atol=1e-5)              # the poster is 1 m ahead
    assert seq.camera.fx == 60.0 and seq.camera.fy == 45.0
    meta = json.loads((out / "sequence.json").read_text())
    assert meta["seed"] == 3 and "mitsuba" in meta["software"]
    assert meta["frames"]["count"] == result.n_frames


def test_events_are_written_in_both_formats_and_agree(tiny_run):
    scene, result = tiny_run
    out = result.out
    from_h5 = read_events(out / "events.h5", 64, 48)
    from_txt = read_events(out / "events.txt", 64, 48)
    np.testing.assert_array_equal(from_h5, from_txt)
    document = json.loads((out / "sequence.json").read_text())
    meta, variant = document["events"], document["render"]["variant"]
    assert meta["count"] == len(from_h5) == result.n_events > 50
    assert meta["on"] + meta["off"] == meta["count"] and meta["on"] == int((from_h5["p"] > 0).sum())
    # A static scene: sampled per pixel, in 10 ms blocks (min_rate 100 Hz) with a frame at each
    # end (every sub-sample, which also gives the prediction of the next block).
    assert meta["sampler"] == result.sampler == "pixel"
    # auto: the numba kernel on llvm_ad_rgb, the Dr.Jit one on the GPU with cuda_ad_rgb
    assert meta["emulator_kernel"] == ("drjit" if variant.startswith("cuda") else "numba")
    assert meta["blocks"] == 30 and meta["full_renders"] == 1 + 30 == result.event_renders
    assert meta["pixel_samples"] == result.event_pixel_samples      # a slow scene: few or none
    assert from_h5["t"][0] > 0 and from_h5["t"][-1] <= 0.3e9
    assert meta["sampling"]["lam"] == 0.5 and meta["noise"]["shot_noise_rate"] == 0


def test_groundtruth_is_dense_and_matches_the_trajectory(tiny_run):
    scene, result = tiny_run
    written = read_trajectory(result.out / "groundtruth.txt")
    times = np.loadtxt(result.out / "groundtruth.txt")[:, 0]
    assert np.all(np.diff(times) <= 1 / 200 + 1e-9), "at least 200 Hz"
    probe = np.array([0.0, 0.1234, 0.3])
    np.testing.assert_allclose(written.pose(probe), scene.trajectory.pose(probe), atol=1e-9)


def test_same_seed_same_files_different_seed_different_texture(tiny_scene_file, tiny_run,
                                                                tmp_path):
    scene, result = tiny_run
    again = simulate(parse_scene(tiny_scene_file.read_text(), tiny_scene_file), tmp_path / "a",
                     progress=False)
    other = simulate(parse_scene(tiny_scene_file.read_text(), tiny_scene_file, seed=9),
                     tmp_path / "b", progress=False)
    for path in sorted(result.out.rglob("*")):
        rel = path.relative_to(result.out)
        if path.is_file() and rel.name != "sequence.json":
            assert path.read_bytes() == (again.out / rel).read_bytes(), rel
    first = "images/frame_00000000.png"
    assert (result.out / first).read_bytes() != (other.out / first).read_bytes()


def test_existing_output_is_not_overwritten_silently(tiny_run):
    scene, result = tiny_run
    with pytest.raises(ValueError, match="overwrite=True"):       # the library's terms
        simulate(scene, result.out, progress=False)


def test_cli_simulate_and_scenes(tiny_scene_file, tmp_path, capsys):
    assert main(["scenes"]) == 0
    listing = capsys.readouterr().out
    assert "slider_close" in listing and "0.231 m" in listing
    out = tmp_path / "cli"
    assert main(["simulate", str(tiny_scene_file), "--out", str(out), "--duration", "0.12",
                 "--seed", "7", "--quiet"]) == 0
    assert f"to {out}" in capsys.readouterr().out
    assert json.loads((out / "sequence.json").read_text())["seed"] == 7
    assert main(["simulate", str(tiny_scene_file), "--out", str(out), "--quiet"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["simulate", "no_such_scene", "--out", str(tmp_path / "x")]) == 2
    assert "built-in" in capsys.readouterr().err


def test_cli_events_stats_and_convert(tiny_run, tmp_path, capsys):
    _, result = tiny_run
    png = tmp_path / "frame.png"
    assert main(["events", str(result.out), "--stats", "--out", str(png)]) == 0
    printed = capsys.readouterr().out
    assert f"count                    {result.n_events}" in printed and "on_fraction" in printed
    # the 64x48 event frame enlarged 5x (panels are >= 320 px), its title and its ON/OFF legend
    assert cv2.imread(str(png)).shape == (26 + 5 * 48 + 22, 5 * 64, 3)
    h5, txt = tmp_path / "copy.h5", tmp_path / "copy.txt"
    assert main(["convert", str(result.out / "events.txt"), str(h5)]) == 0
    assert main(["convert", str(h5), str(txt)]) == 0
    assert txt.read_bytes() == (result.out / "events.txt").read_bytes()
    capsys.readouterr()
    assert main(["convert", str(h5), str(txt)]) == 2                 # never silently replaced
    assert "add --overwrite" in capsys.readouterr().err
    assert main(["convert", str(h5), str(txt), "--overwrite"]) == 0
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]
    assert main(["events", str(tmp_path), "--stats"]) == 2
    assert "images.txt" in capsys.readouterr().err


def test_cli_simulate_with_event_options(tiny_scene_file, tmp_path):
    out = tmp_path / "noisy"
    assert main(["simulate", str(tiny_scene_file), "--out", str(out), "--duration", "0.1",
                 "--noise", "realistic", "--contrast", "0.3", "--event-format", "h5",
                 "--quiet"]) == 0
    meta = json.loads((out / "sequence.json").read_text())["events"]
    assert meta["contrast_on"] == 0.3 and meta["noise"]["shot_noise_rate"] > 0
    assert (out / "events.h5").is_file() and not (out / "events.txt").exists()
    assert main(["simulate", str(tiny_scene_file), "--out", str(tmp_path / "none"),
                 "--duration", "0.1", "--no-events", "--quiet"]) == 0
    assert not (tmp_path / "none" / "events.h5").exists()


def test_console_script_runs_in_a_fresh_process():
    done = subprocess.run([sys.executable, "-m", "fusion.cli", "scenes"], capture_output=True,
                          text=True, check=False, timeout=120)
    assert done.returncode == 0 and "boxes_6dof" in done.stdout


def test_exposure_averages_renders_into_motion_blur(tmp_path):
    fast = MOVING.replace("velocity = [0.2, 0.0, 0.0]", "velocity = [1.0, 0.0, 0.0]")
    sharpness = {}
    for samples in (1, 8):
        frames = (f"[frames]\nrate = 20.0\nexposure = 0.04\nexposure_samples = {samples}\n"
                  "gain = 0.005\n[render]\nspp = 4\n")   # 1 / (cd/m^2): 400 lux
        checker = OBJECTS.replace('type = "noise", resolution = 128',
                                  'type = "checkerboard", squares = [64, 64]')
        scene = parse_scene(scene_text(checker, trajectory=fast, duration=0.1, extra=frames))
        out = simulate(scene, tmp_path / f"s{samples}", progress=False).out
        frame = cv2.imread(str(out / "images/frame_00000000.png"), cv2.IMREAD_UNCHANGED)
        # Gradient energy: blurring an edge over w pixels divides its sum of squares by ~w.
        sharpness[samples] = (np.diff(frame.astype(float), axis=1) ** 2).mean()
    # 1 m/s across a plane 1 m away with fx = 60: 2.4 px of blur in a 40 ms exposure.
    assert sharpness[8] < 0.6 * sharpness[1]


def test_a_late_start_covers_only_its_window_and_matches_the_full_run(tiny_run, tmp_path):
    """simulate(start=0.1): frames, depth, poses and events lie in [0.1, 0.3] s, and a frame's
    exact depth there equals the full run's at the same time."""
    scene, full = tiny_run
    late = simulate(scene, tmp_path / "late", start=0.1, duration=0.2, progress=False)
    seq, ref = load_sequence(late.out), load_sequence(full.out)
    assert seq.image_times[0] >= 0.1 and seq.image_times[-1] <= 0.3
    common = np.intersect1d(np.round(seq.image_times, 9), np.round(ref.image_times, 9))
    assert len(common) >= 3
    k, j = (int(np.argmin(abs(s.image_times - common[0]))) for s in (seq, ref))
    np.testing.assert_array_equal(read_depth(seq.depth_paths[k]), read_depth(ref.depth_paths[j]))
    poses = read_trajectory(seq.groundtruth_path)
    assert poses.t_start == pytest.approx(0.1) and poses.t_end == pytest.approx(0.3)
    assert json.loads((late.out / "sequence.json").read_text())["start"] == 0.1
    faster = MOVING.replace("0.2, 0.0, 0.0", "1.0, 0.0, 0.0")
    fast = parse_scene(scene_text(OBJECTS, trajectory=faster, duration=0.3, extra=FRAMES))
    moved = simulate(fast, tmp_path / "fast", start=0.1, duration=0.2, progress=False)
    events = read_events(moved.out / "events.h5")
    assert len(events) > 100 and events["t"][0] >= 100_000_000
    assert events["t"][-1] <= 300_000_000
    with pytest.raises(ValueError, match="start must be a finite time"):
        simulate(scene, tmp_path / "nan", start=float("nan"), progress=False)


@pytest.mark.parametrize("start, duration", [(0.25, 0.1), (1.0, 0.2), (-0.1, 0.2)])
def test_a_window_outside_the_scene_is_refused_before_rendering(tiny_run, tmp_path, capsys,
                                                                start, duration):
    """The tiny scene lasts 0.3 s: a linear trajectory goes on for ever, the scene does not."""
    scene, _ = tiny_run
    with pytest.raises(ValueError, match=r"outside the scene test, which covers \[0.0, 0.3\] s"):
        simulate(scene, tmp_path / "late", start=start, duration=duration, progress=False)
    assert not (tmp_path / "late").exists() and not (tmp_path / "late.partial").exists()
    code = main(["simulate", "slider_close", "--start", "100", "--duration", "1", "--out",
                 str(tmp_path / "cli")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "[100.0, 101.0] s is outside the scene slider_close" in err[0]
    assert list(tmp_path.iterdir()) == []


SLIDING_BOX = BOX_BEFORE_WALL + 'motion = { type = "linear", velocity = [0.2, 0.0, 0.0] }\n'


def test_edge_spp_is_recorded_by_both_samplers(tmp_path, capsys):
    """``[render] edge_spp`` refines the frame sampler's frames as it does the per-pixel
    sampler's pixels: both record it and how many pixel renders it took, and say nothing."""
    frames = FRAMES.replace("[render]\nspp = 4\n", "[render]\nspp = 4\nedge_spp = 16\n")
    scene = parse_scene(scene_text(BOX_BEFORE_WALL, trajectory=MOVING, duration=0.06,
                                   extra=frames))
    for sampler in ("frame", "pixel"):
        simulate(scene, tmp_path / sampler, progress=False, sampler=sampler,
                 motion_truth=False, event_formats=("h5",))
        record = json.loads((tmp_path / sampler / "sequence.json").read_text())["events"]
        assert record["edge_spp"] == 16 and record["edge_spp_warning"] is None, sampler
        assert record["edge_samples"] > 0, sampler
    assert "edge_spp" not in capsys.readouterr().err


def test_the_frame_sampler_renders_the_edges_of_moving_objects_at_edge_spp():
    """The frame sampler's whole frames (a scene whose box slides before a wall, its shadow
    on the wall, a distorting lens with fx != fy): at each frame's own time the pixels that
    an edge crosses there (:func:`sim.pixel_sampling.geometric_edges` on the geometry at that
    time, the box moved) come from the 16-sub-sample shader, every other pixel from the
    4-sub-sample frame; against 256 sub-samples, the marked pixels are at most half as far
    off as the 4-sub-sample frame's, and the unmarked pixels are off by rounding only (but
    where a corner clips a pixel between its sub-samples)."""
    import importlib

    from sim.pixel_sampling import geometric_edges
    from sim.render import Renderer
    from sim.shader import EventShader

    events = importlib.import_module("sim.simulate._events")
    scene = parse_scene(scene_text(SLIDING_BOX, camera=LENS_CAMERA, lights=SIDE_LIGHT_TOML))
    assert scene.is_dynamic
    renderer = Renderer(scene, spp=4)
    camera = events._EventCamera(renderer, 4, 0.0, 0.5, edge_spp=16)
    coarse, fine = EventShader(renderer, 4, t0=0.0, t1=0.5), EventShader(renderer, 256,
                                                                         t0=0.0, t1=0.5)
    marks = {}
    for t in (0.4, 0.1):
        frame = camera.luminance(t)
        plain, converged = coarse.frame(t), fine.frame(t)
        marks[t] = geometric_edges(*coarse.geometry(t), frame.shape)
        assert 0.02 < marks[t].mean() < 0.25
        np.testing.assert_array_equal(frame[~marks[t]], plain[~marks[t]])
        scale = converged.max()
        error = np.abs(frame - converged) / scale
        before = np.abs(plain - converged) / scale
        # A corner of the shadow can clip a pixel between its sub-samples (at t = 0.1 one
        # pixel, 0.35 % of the wall's value): nothing else differs but rounding.
        assert error[~marks[t]].max() < 0.01
        assert np.count_nonzero(error[~marks[t]] > 1e-5) <= 2
        assert error[marks[t]].mean() < 0.5 * before[marks[t]].mean()
    assert camera.edge_samples == marks[0.4].sum() + marks[0.1].sum()
    assert np.mean(marks[0.4] != marks[0.1]) > 0.02          # the marks follow the box
