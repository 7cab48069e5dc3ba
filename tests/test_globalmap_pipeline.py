"""evfuse map-global and evfuse run --global (fusion.globalmap.pipeline) on tiny sequences."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from fusion.globalmap.keyviews import KeyViewParams, key_view_windows, select_key_views
from fusion.globalmap.pipeline import (
    GlobalParams,
    _filled_view,
    _same_view,
    _semidense_view,
    _sequence_folder,
    sequence_poses,
)
from fusion.pipeline import fill_window
from sim.sequence import load_sequence
from sim.trajectory import read_trajectory
from tests.conftest import run_cli, tree_hashes

M_KEYS = {"accuracy_cm", "completeness_cm", "chamfer_cm",
          *(f"{kind}_{x}cm" for kind in ("precision", "recall", "fscore") for x in (1, 2, 5))}
"""The issue's score block M: the keys every score in global.json holds (at least)."""

MAP_FILES = ("semidense_depth.exr", "confidence.exr", "mask.png", "overlay.png", "map.ply",
             "map.json")
FILL_FILES = ("dense_depth.exr", "segments.png", "filled_mask.png", "figure.png", "dense.ply",
              "fill.json")


@pytest.fixture(scope="module")
def global_run(plane_sequence, tmp_path_factory) -> tuple[Path, Path, dict]:
    """map-global of the 64x48 plane sequence (0.3 s sliding past a wall 1 m away), in this
    process (--workers 1); run_cli checks that the sequence folder is untouched."""
    out = tmp_path_factory.mktemp("global") / "g"
    assert run_cli(["map-global", str(plane_sequence), "--out", str(out), "--workers", "1",
                    "--quiet"]) == 0
    return plane_sequence, out, json.loads((out / "global.json").read_text())


def test_map_global_writes_every_file_and_the_contract_s_schema(global_run):
    _, out, document = global_run
    for name in ("global.ply", "global_filled.ply", "mesh.ply", "global_error.ply",
                 "global.png", "global.json", ".evfuse"):
        assert (out / name).is_file(), name
    assert not (out / ".keyviews").exists() and not Path(f"{out}.partial").exists()
    assert document["simulated"] is True and len(document["views"]) >= 2
    for k, view in enumerate(document["views"]):
        assert view["folder"] == f"views/{k:03d}"
        assert {"t_ref", "semidense", "filled"} <= set(view)
        assert M_KEYS <= set(view["semidense"]) and M_KEYS <= set(view["filled"])
        assert view["filled_against"] == "view"        # one camera: its own exact view
        assert set(view["timings"]) == {"map_s", "fill_s"}
        for name in MAP_FILES:
            assert (out / view["folder"] / "map" / name).is_file(), name
        for name in FILL_FILES:
            assert (out / view["folder"] / "fill" / name).is_file(), name
    assert set(document["global"]) == {"semidense", "filled", "tsdf"}
    for name in ("semidense", "filled", "tsdf"):
        assert M_KEYS <= set(document["global"][name])
    assert {"fusion_s", "tsdf_s", "scoring_s", "map_fill_s", "total_s"} <= set(
        document["timings"])
    assert document["memory_peak_mb"]["main"] > 0
    assert document["params"]["keyviews"] == {"baseline": 0.1, "angle_deg": 10.0,
                                              "max_events": None}
    assert document["rounds"] and document["rounds"][0]["round"] == 1
    assert document["params"]["method"] == "paper-colorization"            # GLOBAL_FILL_METHOD
    assert json.loads((out / "views" / "000" / "fill" / "fill.json").read_text())[
        "method"] == "paper-colorization"


def test_views_and_global_maps_are_scored_on_one_reference_and_printed_so(global_run):
    """Each view's ``semidense_global`` is the view against the global maps' surface (what
    ``gain_over_best_view`` compares), every score has the depth-following tolerances, the key
    views refine depth between the planes and record their event windows, and the summary
    prints the views' scores on that reference."""
    from fusion.globalmap.pipeline import _semidense_view
    from fusion.globalmap.score import SURFACE_SUPERSAMPLE, cloud_scores, exact_surface, exact_view
    from fusion.map.dsi_range import resolve_dsi_range
    from fusion.summaries import global_summary

    sequence_folder, out, document = global_run
    sequence = load_sequence(sequence_folder)
    views = [_semidense_view(out / v["folder"] / "map") for v in document["views"]]
    assert all(view.events == tuple(v["window_s"]) for view, v in
               zip(views, document["views"], strict=True))
    reference = exact_surface([exact_view(sequence, v.t, SURFACE_SUPERSAMPLE) for v in views])
    dsi = resolve_dsi_range(sequence, None, None)
    step = (1 / dsi.min_depth - 1 / dsi.max_depth) / (document["params"]["planes"] - 1)
    assert document["inverse_depth_step_per_m"] == pytest.approx(step)
    poses = np.stack([v.T_world_cam for v in views])
    for view, entry in zip(views, document["views"], strict=True):
        expected = cloud_scores(view.points_world(), reference, document["scene_depth_m"],
                                poses=poses, inverse_depth_step=step)
        assert entry["semidense_global"] == pytest.approx(expected)
    for scores in [*document["global"].values(), document["views"][0]["semidense"]]:
        assert {"fscore_depth1pct", "fscore_step", "tau_step_median_cm"} <= set(scores)
    assert document["params"]["depth"]["subplane"] is True
    text = global_summary(document, out)
    f5 = 100 * document["views"][0]["semidense_global"]["fscore_5cm"]
    assert f"views/000: t_ref {document['views'][0]['t_ref']:.3f} s" in text
    assert f"{f5:.1f}" in text.splitlines()[1] and "plane step" in text


def test_key_views_map_between_their_neighbours_at_the_nearest_frame(global_run):
    sequence_folder, out, document = global_run
    sequence = load_sequence(sequence_folder)
    views = document["views"]
    keys = [view["t_key"] for view in views]
    # the last round's key views, re-selected with each view's own median depth
    assert document["rounds"][-1]["key_times"][0] == keys[0]
    frames = sequence.image_times
    for view, (w0, w1) in zip(views, key_view_windows(keys), strict=True):
        t_ref = view["t_ref"]
        assert t_ref == frames[np.argmin(np.abs(frames - view["t_key"]))]   # the nearest frame
        meta = json.loads((out / view["folder"] / "map" / "map.json").read_text())
        assert meta["t_ref"] == t_ref and meta["params"]["ref_time"] == t_ref
        assert meta["params"]["t0"] == w0 and meta["params"]["t1"] == w1
        fill = json.loads((out / view["folder"] / "fill" / "fill.json").read_text())
        assert fill["t_frame"] == t_ref
    # the first round selects with the DSI range's middle (2 / (1/0.2 + 1/5) m, the default
    # range): far from the wall's 1 m, so the views are selected again with their own medians
    rounds = document["rounds"]
    assert rounds[0]["depth_scale_m"] == pytest.approx([2 / (1 / 0.2 + 1 / 5)] * len(
        rounds[0]["key_times"]))
    assert len(rounds) >= 2
    used = dict(zip(rounds[-1]["key_times"], rounds[-1]["depth_scale_m"], strict=True))
    settled = all(abs(used[v["t_key"]] - v["depth_median_m"]) <= 0.1 * v["depth_median_m"]
                  for v in views)
    assert settled == document["rounds_converged"] or len(rounds) == 3


def test_the_views_are_read_back_in_the_world(global_run):
    """Each view's semi-dense map and filled map are DepthViews at the recorded poses: the
    fused semi-dense cloud's points come from them."""
    _, out, document = global_run
    view = _semidense_view(out / "views" / "000" / "map")
    meta = json.loads((out / "views" / "000" / "map" / "map.json").read_text())
    np.testing.assert_allclose(view.T_world_cam, meta["T_world_ref"])
    assert np.count_nonzero(view.depth) == meta["N1"] == document["views"][0]["N1"]
    filled = _filled_view(out / "views" / "000" / "fill")
    assert filled.t == document["views"][0]["t_frame"]
    # the wall is 1 m ahead (y): a view between two others (events on both sides of its
    # reference) puts its points near it
    middle = _semidense_view(out / "views" / "001" / "map")
    assert abs(np.median(middle.points_world()[:, 1]) - 1.0) < 0.1


def test_overwrite_rules_and_parallel_workers_give_the_same_maps(global_run, capsys):
    """Without --overwrite an existing map is refused in one line; with it, replaced (here by
    two spawned workers, which map the same views as one process); a folder evfuse did not
    write is never replaced."""
    sequence_folder, out, document = global_run
    argv = ["map-global", str(sequence_folder), "--out", str(out), "--quiet"]
    assert run_cli(argv) == 2
    assert "--overwrite" in capsys.readouterr().err
    foreign = out.parent / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert run_cli(["map-global", str(sequence_folder), "--out", str(foreign), "--overwrite",
                    "--quiet"]) == 2
    assert (foreign / "notes.txt").read_text() == "mine"
    capsys.readouterr()
    assert run_cli([*argv, "--overwrite", "--workers", "2"]) == 0
    again = json.loads((out / "global.json").read_text())
    assert [v["t_ref"] for v in again["views"]] == [v["t_ref"] for v in document["views"]]
    assert [v["N1"] for v in again["views"]] == [v["N1"] for v in document["views"]]
    assert again["global"]["semidense"] == document["global"]["semidense"]


def test_a_real_recording_reports_the_views_agreement(plane_sequence, tmp_path):
    """A folder without exact depth (ECD's layout: no sequence.json, no depth/) is fused and
    checked by the agreement of its views; no score, no error cloud."""
    real = tmp_path / "real"
    shutil.copytree(plane_sequence, real,
                    ignore=shutil.ignore_patterns("sequence.json", "depth*", "*exact*"))
    assert load_sequence(real).metadata is None
    out = tmp_path / "g"
    before = tree_hashes(real)
    assert run_cli(["map-global", str(real), "--out", str(out), "--workers", "1",
                    "--t0", "0.05", "--t1", "0.25", "--quiet"]) == 0
    assert tree_hashes(real) == before
    document = json.loads((out / "global.json").read_text())
    # --t0 / --t1: the span the key views cover
    assert document["views"][0]["t_key"] == pytest.approx(0.05)
    assert document["views"][0]["window_s"][0] == pytest.approx(0.05, abs=1e-3)
    assert document["views"][-1]["window_s"][1] <= 0.25 + 1e-9
    assert document["simulated"] is False
    assert document["global"] == {"semidense": None, "filled": None, "tsdf": None}
    assert all(v["semidense"] is None and v["filled"] is None for v in document["views"])
    agreement = document["view_agreement"]
    assert {"pairs", "median_abs_difference_m", "confirmed_share"} <= set(agreement)
    assert not (out / "global_error.ply").exists() and (out / "global.ply").is_file()


def test_the_real_prefix_gives_two_or_three_key_views(ecd_slider, tmp_path):
    """The ECD slider prefix spans 4.5 cm of motion at about 0.8 m: a 2 % baseline gives
    three key views, whose agreement is reported."""
    out = tmp_path / "g"
    assert run_cli(["map-global", str(ecd_slider), "--out", str(out), "--min-depth", "0.47",
                    "--max-depth", "2.4", "--baseline", "0.02", "--workers", "1",
                    "--quiet"]) == 0
    document = json.loads((out / "global.json").read_text())
    assert 2 <= len(document["views"]) <= 3
    assert document["view_agreement"]["pairs"]


def test_key_views_are_chosen_on_groundtruth_txt_never_the_exact_poses(plane_sequence,
                                                                       tmp_path):
    """Blind: a lab rig's groundtruth.txt (here the plane sequence's, its motion doubled)
    decides the key views, whatever groundtruth_exact.txt says."""
    noisy = tmp_path / "noisy"
    shutil.copytree(plane_sequence, noisy)
    trajectory = read_trajectory(noisy / "groundtruth.txt")
    shutil.copy(noisy / "groundtruth.txt", noisy / "groundtruth_exact.txt")
    lines = []
    for t, T in zip(trajectory.times, trajectory.poses, strict=True):
        from scipy.spatial.transform import Rotation

        x, y, z = 2 * T[:3, 3]
        qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
        lines.append(f"{t:.9f} {x:.9f} {y:.9f} {z:.9f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}")
    (noisy / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    params = KeyViewParams(baseline=0.1)
    counts = []
    for folder in (plane_sequence, noisy):
        times, poses = sequence_poses(load_sequence(folder))
        counts.append(len(select_key_views(times, poses, params, 1.0)))
        np.testing.assert_allclose(poses[:, :3, 3],
                                   read_trajectory(folder / "groundtruth.txt").pose(times)[
                                       :, :3, 3])
    assert counts[1] >= 2 * counts[0] - 1 and counts[1] > counts[0]


def test_run_global_refuses_what_makes_no_sense_in_one_line(plane_sequence, tmp_path, capsys):
    out = str(tmp_path / "r")
    assert run_cli(["run", "complex_sphere", "--global", "--resume", "--out", out]) == 2
    assert "--resume cannot be used with a global map" in capsys.readouterr().err
    assert run_cli(["run", "complex_sphere", "--global", "--out", out, "--clip-window",
                    "--depth-range", "oracle"]) == 2
    assert ("--clip-window, --depth-range oracle cannot be used with a global map"
            in capsys.readouterr().err)
    assert run_cli(["run", str(plane_sequence), "--global", "--out", out]) == 2
    assert ("is a sequence folder, not a scene: evfuse map-global maps a sequence folder "
            "(run --global simulates a scene first)") in capsys.readouterr().err
    assert run_cli(["run", "complex_sphere", "--baseline", "0.2", "--out", out]) == 2
    assert "--baseline: only with --global" in capsys.readouterr().err
    assert run_cli(["run", "complex_sphere", "--global", "--views", "3", "--out", out]) == 2
    assert "--views cannot be used with a global map" in capsys.readouterr().err
    assert run_cli(["map-global", str(plane_sequence), "--out", out, "--t1", "50"]) == 2
    assert "50" in capsys.readouterr().err                # past the data: refused, not clipped
    with pytest.raises(SystemExit):                   # argparse: a flag's own type check
        run_cli(["map-global", str(plane_sequence), "--out", out, "--angle", "-1"])
    assert "--angle" in capsys.readouterr().err
    assert not Path(out).exists()


def test_parameters_name_their_flags(plane_sequence, tmp_path, capsys):
    with pytest.raises(ValueError, match="workers"):
        GlobalParams(workers=0)
    assert run_cli(["map-global", str(plane_sequence), "--out", str(tmp_path / "g"),
                    "--method", "no-such-method", "--quiet"]) == 2
    assert "no-such-method" in capsys.readouterr().err
    assert not (tmp_path / "g").exists()


def test_a_rig_s_key_views_fill_in_the_frame_camera(tmp_path):
    """A two-camera rig: the filled view is the frame camera's (its own size and lens) at the
    frame camera's pose, T_world_event(t_frame) @ T_event_frame (the rig of
    tests/test_rig_pipeline.py, built without evfuse's camera or pose code)."""
    from tests.test_rig_pipeline import FRAME, T_EVENT_FRAME, pose, write_rig

    map_folder = write_rig(tmp_path)
    fill = tmp_path / "fill"
    fill_window(map_folder, fill, method="plane")
    view = _filled_view(fill)
    assert view.camera == FRAME and view.depth.shape == (FRAME.height, FRAME.width)
    assert view.t == pytest.approx(0.09)
    np.testing.assert_allclose(view.T_world_cam, pose(0.09)[0] @ T_EVENT_FRAME, atol=1e-9)
    semidense = _semidense_view(map_folder)
    assert semidense.camera.resolution == (64, 48)
    # scored against the global exact surface, not the event camera's view
    assert not _same_view(semidense, view) and _same_view(semidense, semidense)


def test_run_global_simulates_the_scene_then_maps_it(tmp_path, capsys):
    """evfuse run SCENE.toml --global: the window simulated into OUT/sequence (fusion.pipeline's
    simulate step), then map-global's files beside it, the views' map.json naming it."""
    from tests.conftest import FAST, WALL, scene_text

    extra = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 1\n"
    scene = tmp_path / "wall.toml"
    scene.write_text(scene_text(WALL, trajectory=FAST, duration=0.25, extra=extra))
    out = tmp_path / "run"
    assert run_cli(["run", str(scene), "--global", "--out", str(out), "--workers", "1",
                    "--baseline", "0.08"]) == 0
    printed = capsys.readouterr().out
    assert "key views after" in printed and "global semidense" in printed
    document = json.loads((out / "global.json").read_text())
    assert document["sequence"] == "sequence"
    assert (out / "sequence" / "groundtruth.txt").is_file()
    assert "simulate_s" in document["timings"] and len(document["views"]) >= 2
    meta = json.loads((out / "views" / "000" / "map" / "map.json").read_text())
    assert (out / "views" / "000" / "map" / meta["sequence"]).resolve() == (
        out / "sequence").resolve()


def test_the_source_may_be_a_run_folder(plane_sequence, tmp_path, capsys):
    """evfuse map-global runs/boxes --out runs/boxes/global (the issue's command): a folder
    written by evfuse run stands for the sequence its report.json names."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "report.json").write_text(json.dumps({"sequence": str(plane_sequence)}))
    assert _sequence_folder(run) == plane_sequence
    assert _sequence_folder(plane_sequence) == plane_sequence
    with pytest.raises(ValueError, match="nor a folder written by evfuse run"):
        _sequence_folder(tmp_path)
    assert run_cli(["map-global", str(tmp_path), "--out", str(tmp_path / "g")]) == 2
    assert "not a sequence folder" in capsys.readouterr().err
    # The run's own products are inputs too: never replaced, even with --overwrite.
    (run / "map").mkdir()
    (run / "map" / "map.json").write_text("{}")
    (run / ".evfuse").write_text("evfuse run\n")
    (run / "map" / ".evfuse").write_text("evfuse map\n")
    assert run_cli(["map-global", str(run), "--out", str(run / "map"), "--overwrite"]) == 2
    capsys.readouterr()
    assert (run / "map" / "map.json").read_text() == "{}"


def test_the_event_budget_counts_every_event_of_the_span(plane_sequence):
    """The times the event budget counts: every event in [t0, t1] (both ends), in order."""
    from fusion.globalmap.pipeline import _event_times
    from sim.eventio import read_events

    sequence = load_sequence(plane_sequence)
    events = read_events(sequence.events_h5 or sequence.events_txt)
    t = events["t"] * 1e-9
    t0, t1 = float(t[len(t) // 4]), float(t[len(t) // 2])
    times = _event_times(sequence, t0, t1)
    assert len(times) == np.count_nonzero((t >= t0) & (t <= t1)) and np.all(np.diff(times) >= 0)



def test_a_global_run_refuses_a_sequence_folder_in_the_library(plane_sequence, tmp_path):
    """run_global simulates a scene: a sequence folder is refused by the library itself (the
    command line's refusal is the test above), before anything is written."""
    from fusion.globalmap import run_global

    with pytest.raises(ValueError, match="is a sequence folder, not a scene: map_global maps "
                                         "a sequence folder"):
        run_global(plane_sequence, tmp_path / "lib")
    assert not (tmp_path / "lib").exists()


def test_map_global_lists_only_the_flags_it_accepts(plane_sequence, tmp_path, capsys):
    """--help shows no flag map-global would refuse; given anyway, argparse names it."""
    with pytest.raises(SystemExit):
        run_cli(["map-global", "--help"])
    shown = capsys.readouterr().out
    assert "--baseline" in shown and "--min-views" in shown
    assert "--clip-window" not in shown and "--depth-range" not in shown
    with pytest.raises(SystemExit):
        run_cli(["map-global", str(plane_sequence), "--out", str(tmp_path / "g"),
                 "--clip-window"])
    assert "unrecognized arguments: --clip-window" in capsys.readouterr().err


def test_fewer_than_two_key_views_are_refused_naming_baseline(plane_sequence, tmp_path,
                                                              capsys):
    """No empty success: a window whose camera moves less than the criteria ask gives one key
    view, which is refused in one line (how far it moved, what to lower), nothing written."""
    out = tmp_path / "g"
    before = tree_hashes(plane_sequence)
    assert run_cli(["map-global", str(plane_sequence), "--out", str(out), "--baseline", "50",
                    "--angle", "90", "--workers", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "gives 1 key view: the camera moved" in err[0]
    assert "--baseline 50" in err[0] and "--angle 90" in err[0]
    assert "lower --baseline or --angle, or give a longer window (--t0, --t1)" in err[0]
    assert not out.exists() and not (tmp_path / "g.partial").exists()
    assert tree_hashes(plane_sequence) == before


def test_an_empty_fused_map_is_refused_naming_baseline(plane_sequence, tmp_path, capsys):
    out = tmp_path / "g"
    assert run_cli(["map-global", str(plane_sequence), "--out", str(out), "--min-views", "40",
                    "--reject", "unconfirmed", "--workers", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is empty: no point of its" in err[0]
    assert "--min-views 40" in err[0] and "lower --baseline" in err[0]
    assert not out.exists()


def test_the_real_prefix_at_the_default_baseline_is_refused(ecd_slider, tmp_path, capsys):
    """The ECD prefix moves 4.5 cm at about 0.8 m: the default 10 % baseline gives one key
    view, which used to be fused into an empty global.ply with exit 0."""
    out = tmp_path / "g"
    assert run_cli(["map-global", str(ecd_slider), "--out", str(out), "--min-depth", "0.47",
                    "--max-depth", "2.4", "--workers", "1", "--quiet"]) == 2
    assert "gives 1 key view" in capsys.readouterr().err
    assert not out.exists()
