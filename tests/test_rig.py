"""Imperfect rigs (sim/capture_errors.py): pose noise, clock offsets and calibration error on the
written
files, the truth kept apart, and a map scored against the TRUE reference view."""

from __future__ import annotations

import builtins
import io
import json
import math
import sys
from dataclasses import replace

import numpy as np
import pytest

import fusion.map.mapping as mapping
from fusion.cli import main
from fusion.fill.dense import fill_map
from fusion.map.emvs import DSIParams
from fusion.map.mapping import MapParams, map_sequence, write_map
from sim.camera import Camera, read_calib, write_calib
from sim.capture_errors import (
    EXACT_CALIB,
    EXACT_POSES,
    RIG_PRESETS,
    RigParams,
    calibration_error,
    pose_noise,
    rig_generator,
)
from sim.eventio import read_events
from sim.render import Renderer
from sim.scene import SceneError, parse_scene
from sim.se3 import so3_log
from sim.sequence import load_sequence, read_index
from sim.simulate import simulate
from sim.trajectory import read_trajectory, sample_times, write_trajectory
from tests.conftest import FAST, WALL, scene_text

PLANE_EXTRA = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n"
"""The frames of conftest's ``plane_sequence``: a rig sequence of the same scene and seed has
the same renders, so its events and frames are the perfect ones, only stamped differently."""
OFFSETS = {"events_offset": 0.0123, "frames_offset": 0.02, "poses_offset": 0.0031}
EVERYTHING = RigParams(position_sigma=1e-3, rotation_sigma=math.radians(0.2),
                       position_walk=2e-3, rotation_walk=math.radians(0.05),
                       focal_sigma=0.01, principal_point_sigma=1.0,
                       distortion_sigma=(0.01, 0.005, 5e-4, 5e-4, 0.0), **OFFSETS)


def _plane_scene():
    return parse_scene(scene_text(WALL, trajectory=FAST, duration=0.3, extra=PLANE_EXTRA))


@pytest.fixture(scope="module")
def rig_sequence(tmp_path_factory):
    """conftest's plane scene simulated through a rig with every imperfection."""
    out = tmp_path_factory.mktemp("rig") / "everything"
    return simulate(_plane_scene(), out, progress=False, rig=EVERYTHING).out


# --- the models ---------------------------------------------------------------------------------

def test_white_pose_noise_has_its_sigma():
    """60,000 draws per quantity: the sample sigma's relative standard error is 0.3 %; 3 %
    tolerance is 10 standard errors."""
    params = RigParams(position_sigma=5e-4, rotation_sigma=math.radians(0.1))
    times = np.arange(20000) * 1e-3
    dp, dw = pose_noise(times, params, np.random.default_rng(0))
    assert dp.std() == pytest.approx(5e-4, rel=0.03)
    assert dw.std() == pytest.approx(math.radians(0.1), rel=0.03)
    assert abs(dp.mean()) < 5 * 5e-4 / math.sqrt(dp.size)
    # white: consecutive errors are uncorrelated (|r| < 5 / sqrt(N))
    r = np.corrcoef(dp[1:, 0], dp[:-1, 0])[0, 1]
    assert abs(r) < 5 / math.sqrt(len(dp))


def test_random_walk_grows_as_the_square_root_of_time():
    """400 walks at 1 kHz (an uneven grid included): the spread across walks at t is
    q sqrt(t) within 10 % (1,200 samples per time: 2 % standard error, 10 % is 5 of them)."""
    q_p, q_r = 0.01, math.radians(1.0)
    params = RigParams(position_walk=q_p, rotation_walk=q_r)
    times = np.cumsum(np.r_[0.0, np.random.default_rng(9).uniform(0.5e-3, 1.5e-3, 999)])
    walks = [pose_noise(times, params, np.random.default_rng([4, k])) for k in range(400)]
    dp = np.stack([w[0] for w in walks])                 # (400, N, 3)
    dw = np.stack([w[1] for w in walks])
    assert np.all(dp[:, 0] == 0) and np.all(dw[:, 0] == 0)        # starts at the truth
    for t in (0.05, 0.2, 0.8):
        k = int(np.argmin(np.abs(times - t)))
        elapsed = times[k] - times[0]
        assert dp[:, k].std() == pytest.approx(q_p * math.sqrt(elapsed), rel=0.1)
        assert dw[:, k].std() == pytest.approx(q_r * math.sqrt(elapsed), rel=0.1)


def test_calibration_error_draws_have_their_sigmas():
    camera = Camera(240, 180, 200.0, 199.0, 120.0, 90.0, (-0.3, 0.1, 0.0, 0.0, 0.0))
    params = RigParams(focal_sigma=0.005, principal_point_sigma=1.0,
                       distortion_sigma=(0.01, 0.005, 5e-4, 5e-4, 0.0))
    draws = [calibration_error(camera, params, np.random.default_rng([1, k]))
             for k in range(4000)]
    fx = np.array([c.fx for c, _ in draws])
    fy = np.array([c.fy for c, _ in draws])
    np.testing.assert_allclose(fx / camera.fx, fy / camera.fy, rtol=1e-12)  # one focal draw
    assert (fx / camera.fx - 1).std() == pytest.approx(0.005, rel=0.06)     # 4,000 draws: 1.1 %
    assert np.std([c.cx - camera.cx for c, _ in draws]) == pytest.approx(1.0, rel=0.06)
    k = np.array([c.distortion for c, _ in draws]) - np.array(camera.distortion)
    np.testing.assert_allclose(k.std(axis=0)[:4], [0.01, 0.005, 5e-4, 5e-4], rtol=0.06)
    assert np.all(k[:, 4] == 0)


# --- the written files ------------------------------------------------------------------------

def test_a_perfect_rig_writes_the_bytes_of_before(plane_sequence, tmp_path):
    """The default (perfect) rig: calib.txt, groundtruth.txt and the index files are the bytes the
    simulator wrote before rigs existed (the same writers on the true values), and equal to the
    exact files beside them."""
    scene = _plane_scene()
    seq = load_sequence(plane_sequence)
    write_calib(tmp_path / "calib.txt", scene.camera)
    times = sample_times(0.0, 0.3, scene.render.pose_rate)
    write_trajectory(tmp_path / "groundtruth.txt", times, scene.trajectory.pose(times))
    for name, exact in (("calib.txt", EXACT_CALIB), ("groundtruth.txt", EXACT_POSES)):
        assert (plane_sequence / name).read_bytes() == (tmp_path / name).read_bytes()
        assert (plane_sequence / exact).read_bytes() == (tmp_path / name).read_bytes()
    meta = json.loads((plane_sequence / "sequence.json").read_text())
    assert meta["rig"]["perfect"] and meta["rig"]["params"]["preset"] == "perfect"
    frame_times = 0.005 + 0.05 * np.arange(len(seq.image_times))    # mid-exposure, 20 Hz
    np.testing.assert_allclose(seq.image_times, frame_times, atol=1e-12)
    assert meta["events"]["span_s"] == [0.0, 0.3]


def test_offsets_shift_every_stream_exactly(plane_sequence, rig_sequence):
    """Same scene and seed: the events are the perfect run's, each exactly 12.3 ms later; the
    frames and depth maps the same files 20 ms later; the poses' times 3.1 ms later."""
    for name in ("events.h5", "events.txt"):
        perfect, shifted = read_events(plane_sequence / name), read_events(rig_sequence / name)
        assert len(perfect) > 1000
        for field in ("x", "y", "p"):
            np.testing.assert_array_equal(perfect[field], shifted[field])
        np.testing.assert_array_equal(shifted["t"] - perfect["t"], 12_300_000)
    for index in ("images.txt", "depthmaps.txt"):
        t0, names0 = read_index(plane_sequence / index)
        t1, names1 = read_index(rig_sequence / index)
        assert names0 == names1
        np.testing.assert_allclose(t1 - t0, 0.02, atol=1e-9)              # 9 decimals written
        for name in names0:
            assert (plane_sequence / name).read_bytes() == (rig_sequence / name).read_bytes()
    exact, written = read_trajectory(rig_sequence / EXACT_POSES), read_trajectory(
        rig_sequence / "groundtruth.txt")
    np.testing.assert_allclose(written.times - exact.times, 0.0031, atol=1e-9)
    assert (rig_sequence / EXACT_POSES).read_bytes() == (plane_sequence / EXACT_POSES).read_bytes()
    meta = json.loads((rig_sequence / "sequence.json").read_text())
    assert meta["rig"]["offsets_s"] == {"events": 0.0123, "frames": 0.02, "poses": 0.0031,
                                        "imu": 0.0}
    np.testing.assert_allclose(meta["events"]["span_s"], [0.0123, 0.3123])


def test_written_poses_carry_exactly_the_seeded_noise(rig_sequence):
    """groundtruth.txt = the exact poses with pose_noise's draws from the recorded stream:
    p' = p + dp (world), R' = R exp(dw) (camera frame), to the file's precision."""
    exact = read_trajectory(rig_sequence / EXACT_POSES)
    written = read_trajectory(rig_sequence / "groundtruth.txt")
    meta = json.loads((rig_sequence / "sequence.json").read_text())
    assert meta["rig"]["streams"]["poses"] == [3, 2, 0]
    dp, dw = pose_noise(exact.times, EVERYTHING, rig_generator(3, "poses"))
    P, W = exact.pose(exact.times), written.pose(written.times)
    np.testing.assert_allclose(W[:, :3, 3] - P[:, :3, 3], dp, atol=1e-12)
    rotation = so3_log(np.swapaxes(P[:, :3, :3], 1, 2) @ W[:, :3, :3])
    np.testing.assert_allclose(rotation, dw, atol=1e-9)
    assert np.abs(dp).max() > 1e-3                                         # not vacuous


def test_calibration_error_is_written_as_declared(rig_sequence):
    exact = read_calib(rig_sequence / EXACT_CALIB, 64, 48)
    written = load_sequence(rig_sequence).camera
    assert exact == _plane_scene().camera
    drawn = json.loads((rig_sequence / "sequence.json").read_text())["rig"]["calibration_error"]
    again, redrawn = calibration_error(exact, EVERYTHING, rig_generator(3, "calibration"))
    assert written == again and drawn == redrawn
    assert written.fx == pytest.approx(exact.fx * (1 + drawn["focal_relative"]), rel=1e-15)
    assert written.fy == pytest.approx(exact.fy * (1 + drawn["focal_relative"]), rel=1e-15)
    assert written.cx == pytest.approx(exact.cx + drawn["cx_px"], abs=1e-12)
    assert written.cy == pytest.approx(exact.cy + drawn["cy_px"], abs=1e-12)
    np.testing.assert_allclose(np.subtract(written.distortion, exact.distortion),
                               drawn["distortion"], atol=1e-15)
    assert written.fx != exact.fx and written.cx != exact.cx


# --- the pipeline uses the noisy files; only scoring reads the exact ones -----------------------

def test_only_scoring_opens_the_exact_files(rig_sequence, tmp_path, monkeypatch):
    """Every open of calib_exact.txt / groundtruth_exact.txt during map + fill happens inside the
    map's scoring (``_ground_truth_depth``), which does open them; the map is built in the
    written (noisy) reference pose and calibration."""
    opened: list[tuple[str, bool]] = []
    real_open = io.open

    def spy(file, *args, **kwargs):
        name = str(file)
        if name.endswith((EXACT_CALIB, EXACT_POSES)):
            frame, scoring = sys._getframe(1), False
            while frame is not None and not scoring:
                scoring = frame.f_code is mapping._ground_truth_depth.__code__
                frame = frame.f_back
            opened.append((name, scoring))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(io, "open", spy)
    monkeypatch.setattr(builtins, "open", spy)
    params = MapParams(DSIParams(0.5, 2.0, 50))
    result = map_sequence(rig_sequence, params, progress=False)
    write_map(result, tmp_path / "map", params)
    fill_map(tmp_path / "map")
    assert opened and all(scoring for _, scoring in opened), opened
    assert {name.rsplit("/", 1)[-1] for name, _ in opened} == {EXACT_CALIB, EXACT_POSES}
    written = read_trajectory(rig_sequence / "groundtruth.txt").pose(result.t_ref)
    np.testing.assert_allclose(result.T_world_ref, written, atol=1e-12)
    calib = load_sequence(rig_sequence).camera
    assert (result.camera.fx, result.camera.cx) == (calib.fx, calib.cx)
    assert "errors" in result.info


# --- scoring: the truth is the TRUE camera at the reference time --------------------------------

STATIC = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
          "velocity = [0.0, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
FORWARD = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
           "velocity = [0.0, 0.5, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
DISTORTED = ("[camera]\nwidth = 48\nheight = 36\nfx = 45.0\nfy = 44.0\ncx = 23.5\ncy = 17.5\n"
             "distortion = [-0.1, 0.0, 0.0, 0.0, 0.0]\n")


def test_the_map_is_scored_in_the_true_camera_at_the_true_pose(tmp_path):
    """A wall 1 m ahead, a static camera with lens distortion (so the truth is rendered), written
    poses tilted by degrees and a focal length 5 % off: the truth is 1 m at every pixel, as the
    true undistorted camera at the true pose sees it; a render at the written pose in the
    written calibration (what scoring did before) is over 5 mm off (1.4 cm measured)."""
    rig = RigParams(rotation_sigma=math.radians(3.0), focal_sigma=0.05)
    scene = parse_scene(scene_text(WALL, camera=DISTORTED, trajectory=STATIC, duration=0.2,
                                   extra=PLANE_EXTRA))
    out = simulate(scene, tmp_path / "seq", progress=False, with_events=False, rig=rig).out
    sequence = load_sequence(out)
    t_ref = float(sequence.image_times[2])
    truth = mapping._ground_truth_depth(sequence, t_ref)
    assert truth.shape == (36, 48)
    np.testing.assert_allclose(truth, 1.0, atol=1e-5)
    written_pose = read_trajectory(out / "groundtruth.txt").pose(t_ref)
    assert np.degrees(np.linalg.norm(so3_log(written_pose[:3, :3].T @ scene.trajectory.pose(
        t_ref)[:3, :3]))) > 1.0                                          # the rig did tilt it
    c = sequence.camera
    virtual = Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy)
    wrong = Renderer(replace(scene, camera=virtual), spp=1).depth(t_ref, pose=written_pose)
    assert np.abs(wrong[wrong > 0] - 1.0).max() > 5e-3                  # 500 x the tolerance


@pytest.mark.parametrize("shift", [-0.01, 0.0])
def test_the_reference_time_is_read_on_the_poses_clock(tmp_path, shift):
    """A camera driving at 0.5 m/s towards a wall 1 m away, poses stamped 10 ms late and frames
    20 ms late: the map's reference time t_ref (on the poses' clock) is the true time
    t_ref - 10 ms, where the wall is 1 - 0.5 (t_ref - 0.01) m away, whether that is a frame's
    depth map (shift -10 ms: read from depth/) or not (rendered)."""
    rig = RigParams(poses_offset=0.01, frames_offset=0.02)
    scene = parse_scene(scene_text(WALL, trajectory=FORWARD, duration=0.3, extra=PLANE_EXTRA))
    out = simulate(scene, tmp_path / "seq", progress=False, with_events=False, rig=rig).out
    sequence = load_sequence(out)
    t_ref = float(sequence.image_times[3]) + shift
    truth = mapping._ground_truth_depth(sequence, t_ref)
    np.testing.assert_allclose(truth, 1.0 - 0.5 * (t_ref - 0.01), atol=2e-5)


def test_pose_noise_makes_the_map_error_grow(plane_sequence, tmp_path):
    """End to end on the plane (64x48, 0.3 s): the same events mapped with poses jittered by 2 mm
    and 1 degree (white) are worse against the exact depth than with the perfect poses: median
    error up by at least half, precision within 5 % down by at least 0.05. Measured (seed 3),
    the points on the DSI's end planes dropped (the default): median 1.03 -> 2.00 cm, precision
    0.92 -> 0.69; kept (--keep-boundary-planes): 1.03 -> 3.43 cm, 0.80 -> 0.61."""
    rig = RigParams(position_sigma=2e-3, rotation_sigma=math.radians(1.0))
    noisy = simulate(_plane_scene(), tmp_path / "noisy", progress=False, rig=rig).out
    params = MapParams(DSIParams(0.5, 2.0, 50))
    perfect = map_sequence(plane_sequence, params, progress=False).info["errors"]
    jittered = map_sequence(noisy, params, progress=False).info["errors"]
    assert jittered["median_cm"] >= 1.5 * perfect["median_cm"]
    assert jittered["precision_5pct"] <= perfect["precision_5pct"] - 0.05


# --- configuration -------------------------------------------------------------------------------

def test_rig_section_and_presets_parse():
    scene = parse_scene(scene_text(WALL, extra='[rig]\npreset = "mocap"\n'))
    assert scene.rig == RIG_PRESETS["mocap"] and not scene.rig.is_perfect
    scene = parse_scene(scene_text(WALL, extra="[rig]\nrotation_sigma = 0.5\nposes_offset = "
                                               "-0.002\ndistortion_sigma = [0.01, 0, 0, 0, 0]\n"))
    assert scene.rig.rotation_sigma == pytest.approx(math.radians(0.5))   # degrees in the file
    assert scene.rig.poses_offset == -0.002 and scene.rig.preset == "custom"
    assert parse_scene(scene_text(WALL)).rig.is_perfect


@pytest.mark.parametrize("text, message", [
    ("position_sigma = -1.0", r"\[rig\].position_sigma: expected a number >= 0"),
    ('preset = "vicon"', r"\[rig\].preset: expected one of perfect, mocap, lab"),
    ("jitter = 1.0", r"\[rig\]: unknown key 'jitter'"),
    ("distortion_sigma = [0.1]", r"\[rig\].distortion_sigma: expected a list of 5"),
])
def test_a_bad_rig_section_is_refused_naming_the_key(text, message):
    with pytest.raises(SceneError, match=message):
        parse_scene(scene_text(WALL, extra=f"[rig]\n{text}\n"))


def test_cli_rig_flag_and_a_negative_time_refused(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(scene_text(WALL, trajectory=STATIC, duration=0.1, extra=PLANE_EXTRA
                                + '[rig]\npreset = "perfect"\nevents_offset = -0.01\n'))
    assert main(["simulate", str(scene), "--out", str(tmp_path / "bad"), "--quiet",
                 "--no-events"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["evfuse simulate: error: rig events_offset -0.01 s would write events times "
                   "before 0 s from --start 0 s; expected start + offset >= 0 (simulate from a "
                   "later --start or use a positive offset)"]
    assert main(["simulate", str(scene), "--out", str(tmp_path / "ok"), "--quiet", "--no-events",
                 "--rig", "mocap"]) == 0                   # the flag replaces the file's [rig]
    meta = json.loads((tmp_path / "ok" / "sequence.json").read_text())
    assert meta["rig"]["params"]["preset"] == "mocap" and meta["rig"]["offsets_s"]["poses"] == 3e-3


def test_an_imperfect_rig_without_its_exact_files_is_not_scored(rig_sequence, tmp_path):
    """Scoring never falls back to the noisy files of an imperfect rig."""
    import shutil

    from sim.capture_errors import exact_camera, exact_trajectory

    copy = tmp_path / "copy"
    shutil.copytree(rig_sequence, copy)
    (copy / EXACT_CALIB).unlink()
    (copy / EXACT_POSES).unlink()
    sequence = load_sequence(copy)
    with pytest.raises(ValueError, match="imperfect rig but there is no calib_exact.txt"):
        exact_camera(sequence)
    with pytest.raises(ValueError, match="imperfect rig but there is no groundtruth_exact.txt"):
        exact_trajectory(sequence)


def test_run_on_a_scene_with_a_late_mocap_maps_what_its_poses_cover(tmp_path):
    """`evfuse run` on a scene whose [rig] stamps the poses 3 ms late: the simulated window's
    poses start 3 ms into it, so the map is clipped to them (and says so) instead of refused;
    the map is scored (its truth from the exact files)."""
    scene = tmp_path / "late.toml"
    scene.write_text(scene_text(WALL, trajectory=FAST, duration=0.3, extra=PLANE_EXTRA
                                + '[rig]\npreset = "mocap"\n'))
    run = tmp_path / "run"
    assert main(["run", str(scene), "--out", str(run), "--t0", "0.0", "--t1", "0.3",
                 "--min-depth", "0.5", "--max-depth", "2.0", "--quiet"]) == 0
    report = json.loads((run / "report.json").read_text())
    assert report["window_clipped"] is True and report["window_requested_s"] == [0.0, 0.3]
    np.testing.assert_allclose(report["window_s"], [0.003, 0.3], atol=1e-9)
    assert report["map_errors_at_reference"]["n"] > 100
