"""evfuse fill / run / show / reproduce: the stages wired together, on arrays, a simulated plane
and the real ECD prefix."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from fusion.fill.dense import DenseParams, densify, fill_frame
from fusion.fill.filling import filling_score
from fusion.fill.projection import project_map
from fusion.io import read_ply
from sim.camera import Camera, write_calib
from sim.exr import read_depth, write_depth, write_exr_channels
from sim.se3 import make_pose
from tests.conftest import run_cli


def test_project_map_is_the_identity_at_the_reference_view_and_shifts_with_parallax():
    camera = Camera(40, 30, 35.0, 30.0, 19.5, 14.5)
    depth = np.zeros((30, 40), np.float32)
    depth[10, 5:35] = 2.0
    depth[20, 8] = 1.0
    same = project_map(depth, camera, np.eye(4), camera, np.eye(4))
    np.testing.assert_array_equal(same, depth)
    # The frame's camera 8/35 m to the right: a point at Z moves left by fx * tx / Z pixels.
    moved = project_map(depth, camera, np.eye(4), camera, make_pose(np.eye(3), [8 / 35, 0, 0]))
    np.testing.assert_array_equal(moved[10], np.r_[np.zeros(1), np.full(30, 2.0),
                                                   np.zeros(9)])             # 4 px at 2 m
    assert moved[20, 0] == 1.0 and np.count_nonzero(moved) == 31             # 8 px at 1 m


def _two_patch_scene():
    """A 40x30 frame: background 100 with a 12x10 square of 160; map points on the square's
    one-pixel outer ring at 2 m (the square is a plane 2 m away), and 60 points of texture at
    3 m on the background's top rows, off the square's band: 60 >= 5 % of its 1,080 pixels, so
    the background, whose contour is the square's outline, is not filled from it."""
    frame = np.full((30, 40), 100, np.uint8)
    frame[10:20, 14:26] = 160
    sparse = np.zeros((30, 40), np.float32)
    sparse[9, 13:27] = sparse[20, 13:27] = 2.0
    sparse[9:21, 13] = sparse[9:21, 26] = 2.0
    sparse[0:5:2, 0:40:2] = 3.0
    return frame, sparse


def test_a_square_bounded_by_map_points_is_filled_with_their_depth():
    frame, sparse = _two_patch_scene()
    labels, regions, dense, timings = densify(frame, sparse)
    square = labels[15, 20]
    assert regions.selected[square] and (labels[10:20, 14:26] == square).all()
    np.testing.assert_array_equal(dense[10:20, 14:26], 2.0)
    assert np.count_nonzero(dense) == np.count_nonzero(sparse) + 120
    assert set(timings) == {"segment_s", "select_s", "fill_s"}


def test_fill_of_any_frame_through_the_command_line(tmp_path, capsys):
    frame, sparse = _two_patch_scene()
    cv2.imwrite(str(tmp_path / "f.png"), frame)
    write_depth(tmp_path / "d.exr", sparse)
    truth = np.full((30, 40), 3.0, np.float32)
    truth[10:20, 14:26] = 2.0
    write_depth(tmp_path / "t.exr", truth)
    write_calib(tmp_path / "calib.txt", Camera(40, 30, 35.0, 30.0, 19.5, 14.5))
    out = tmp_path / "out"
    assert run_cli(["fill", "--frame", str(tmp_path / "f.png"), "--sparse-depth",
                 str(tmp_path / "d.exr"), "--calib", str(tmp_path / "calib.txt"), "--truth",
                 str(tmp_path / "t.exr"), "--out", str(out)]) == 0
    for name in ("dense_depth.exr", "segments.png", "filled_mask.png", "figure.png",
                 "dense.ply", "fill.json", "error.png"):
        assert (out / name).is_file(), name
    meta = json.loads((out / "fill.json").read_text())
    dense = read_depth(out / "dense_depth.exr")
    # the --sparse-depth form: the map is the given sparse depth, all of it in the frame
    assert meta["N1"] == meta["N1_in_frame"] == np.count_nonzero(sparse)
    assert meta["N2"] == np.count_nonzero(dense)
    assert meta["Res"] == 1200 and meta["beta"] == pytest.approx(
        filling_score(meta["N1_in_frame"], meta["N2"], 1200))
    assert meta["beta_counts"] == "(N2 - N1_in_frame) / (Res + N1_in_frame / Res)"
    errors = meta["errors"]
    assert errors["filled"]["interior"]["mae_cm"] == 0.0             # the square, exactly 2 m
    assert errors["filled"]["overall"]["n"] == 120
    record, header = read_ply(out / "dense.ply")
    assert len(record) == meta["N2"] and (record["source"] == 1).sum() == 120
    assert header["comment"] == "T_world_frame"
    filled = cv2.imread(str(out / "filled_mask.png"), cv2.IMREAD_GRAYSCALE)
    assert (filled > 0).sum() == 120
    printed = capsys.readouterr().out
    assert "N1 = 108 (108 in the frame), N2 = 228" in printed
    # every printed error carries its coverage: the filled square is 120 of the 1200 true pixels
    assert ("filled pixels: MAE 0.00 cm on 120 px, median 0.00 cm (completeness 10.0 %), "
            "precision 100.0 % "
            "within 5 %") in printed


def test_bad_fill_input_gives_one_clear_line(tmp_path, capsys):
    frame, sparse = _two_patch_scene()
    cv2.imwrite(str(tmp_path / "f.png"), frame)
    write_depth(tmp_path / "small.exr", sparse[:20])
    write_depth(tmp_path / "empty.exr", np.zeros_like(sparse))
    bad = sparse.copy()
    bad[0, 0] = np.nan
    write_exr_channels(tmp_path / "nan.exr", {"Z": bad})            # write_depth refuses NaN
    write_calib(tmp_path / "calib.txt", Camera(40, 30, 35.0, 30.0, 19.5, 14.5))
    base = ["fill", "--frame", str(tmp_path / "f.png"), "--calib", str(tmp_path / "calib.txt")]
    for k, (depth, message) in enumerate([("small.exr", "must be the same size"),
                                          ("empty.exr", "no map point"),
                                          ("nan.exr", "NaN")]):
        code = run_cli([*base, "--sparse-depth", str(tmp_path / depth), "--out",
                     str(tmp_path / f"o{k}")])
        err = capsys.readouterr().err
        assert code == 2 and message in err and "Traceback" not in err, (depth, err)
        assert not (tmp_path / f"o{k}").exists()
    assert run_cli(["fill", str(tmp_path / "nomap"), "--out", str(tmp_path / "o9")]) == 2
    assert f"map folder {tmp_path / 'nomap'} does not exist" in capsys.readouterr().err
    (tmp_path / "nomap").mkdir()
    assert run_cli(["fill", str(tmp_path / "nomap"), "--out", str(tmp_path / "o9")]) == 2
    assert f"{tmp_path / 'nomap'}: no map.json" in capsys.readouterr().err


def test_fill_of_a_simulated_plane_map_is_scored_against_exact_depth(plane_sequence, tmp_path):
    mapped, out = tmp_path / "map", tmp_path / "fill"
    assert run_cli(["map", str(plane_sequence), "--out", str(mapped), "--min-depth", "0.5",
                 "--max-depth", "3", "--planes", "30", "--quiet"]) == 0
    assert run_cli(["fill", str(mapped), "--out", str(out)]) == 0
    meta = json.loads((out / "fill.json").read_text())
    map_meta = json.loads((mapped / "map.json").read_text())
    assert meta["N1"] == map_meta["N1"] >= meta["N1_in_frame"] > 30
    assert meta["N2"] >= meta["N1_in_frame"] and 0 <= meta["beta"] < 1
    assert meta["beta"] == pytest.approx(filling_score(meta["N1_in_frame"], meta["N2"],
                                                       meta["Res"]))
    errors = meta["errors"]
    assert errors["map"]["overall"]["points"] == meta["N1_in_frame"]
    assert errors["filled"]["overall"]["points"] == meta["N2"] - meta["N1_in_frame"] > 0
    # one definition per name: the map's and the fill's error blocks have the same keys
    assert set(errors["map"]["overall"]) == set(map_meta["errors"])
    assert not any(key.startswith("within") for key in map_meta["errors"])
    # The wall is flat: filling it from its own map points adds no error of its own.
    assert errors["filled"]["overall"]["mae_cm"] <= 1.1 * errors["map"]["overall"]["mae_cm"]
    assert errors["all"]["overall"]["completeness"] > errors["map"]["overall"]["completeness"]
    assert meta["frame"].startswith("images/") and meta["sequence"]


def test_run_on_the_real_ecd_prefix_and_show_redraws_it(ecd_slider, tmp_path, capsys):
    out = tmp_path / "real"
    assert run_cli(["run", str(ecd_slider), "--out", str(out), "--min-depth", "0.47",
                 "--max-depth", "2.4", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "no ground truth" in printed and str(out / "overview.png") in printed
    report = json.loads((out / "report.json").read_text())
    assert report["ground_truth"] is False and report["mae_cm"] is None
    assert report["depth_range_from"] == "given (--min-depth, --max-depth)"
    assert report["oracle"] is False
    assert report["events"] == 50000 - 3251 and report["N2"] >= report["N1_in_frame"] > 200
    assert report["errors_summary"] is None
    mapped = json.loads((out / "map" / "map.json").read_text())
    assert report["N1"] == mapped["N1"] >= report["N1_in_frame"]
    for name in ("map/map.json", "fill/fill.json", "fill/figure.png", "overview.png"):
        assert (out / name).is_file(), name
    fill = json.loads((out / "fill" / "fill.json").read_text())
    assert fill["camera"]["distortion"][0] == pytest.approx(-0.138592767408)   # undistorting
    before = cv2.imread(str(out / "overview.png"))
    assert before.shape == (2 * (26 + 240 + 22), 3 * 320, 3)   # no exact depth, no error panel
    assert run_cli(["show", str(out), "--out", str(tmp_path / "again.png")]) == 0
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "again.png")), before)


def test_fill_frame_refuses_a_calibration_of_another_size():
    frame, sparse = _two_patch_scene()
    with pytest.raises(ValueError, match="calibration is for 41x30"):
        fill_frame(frame, sparse, Camera(41, 30, 35.0, 30.0, 19.5, 14.5), DenseParams())


def test_n1_is_the_map_and_n1_in_frame_what_lands_in_it():
    """200 map points of which the 108 of the scene (48 on the square's ring, 60 on the
    background) land in the frame: beta, N2 and the errors use the 108, N1 stays the map's 200."""
    frame, sparse = _two_patch_scene()
    camera = Camera(40, 30, 35.0, 30.0, 19.5, 14.5)
    result = fill_frame(frame, sparse, camera, n1=200)
    info = result.info
    assert result.n1_in_frame == info["N1_in_frame"] == 108 and info["N1"] == 200
    assert info["N2"] == result.n2 == 108 + 120 and info["Res"] == 1200
    assert info["beta"] == pytest.approx(120 / (1200 + 108 / 1200))     # not with 200
    assert info["N2_over_N1_in_frame"] == pytest.approx(228 / 108)
    assert "N2_over_N1" not in info and "map_N1" not in info
    assert fill_frame(frame, sparse, camera).info["N1"] == 108           # default: the sparse
    with pytest.raises(ValueError, match="n1 must be the map's point count"):
        fill_frame(frame, sparse, camera, n1=107)


def test_fill_frame_takes_a_method_and_keeps_the_paper_s_weighting_consistent():
    from fusion.fill.filling import FillParams

    frame, sparse = _two_patch_scene()
    camera = Camera(40, 30, 35.0, 30.0, 19.5, 14.5)
    gaussian = DenseParams(fill=FillParams("gaussian"))
    by_name = fill_frame(frame, sparse, camera, method="paper-gaussian")
    np.testing.assert_array_equal(by_name.dense, densify(frame, sparse, gaussian)[2])
    assert by_name.info["method"] == "paper-gaussian" and by_name.regions is not None
    assert fill_frame(frame, sparse, camera, gaussian).info["method"] == "paper-gaussian"
    with pytest.raises(ValueError, match="paper-gaussian uses gaussian weights but "
                                         "params.fill.weighting is 'idw'"):
        fill_frame(frame, sparse, camera, DenseParams(), method="paper-gaussian")
    nearest = fill_frame(frame, sparse, camera, method="nearest")
    assert nearest.regions is None and nearest.info["regions"] is None
    assert nearest.labels.dtype == np.int32 and not nearest.labels.any()
    assert nearest.info["N2"] == 1200 and nearest.info["method_origin"] == "built-in"
    assert set(nearest.info["timings"]) == {"method_s", "total_s"}
    with pytest.raises(ValueError, match="unknown filling method 'nope'"):
        fill_frame(frame, sparse, camera, method="nope")
    for bad, message in ((sparse[:20], "must be the same size"),
                         (np.where(sparse > 0, np.nan, 0), "NaN"),
                         (np.zeros_like(sparse), "no map point")):
        with pytest.raises(ValueError, match=message):
            fill_frame(frame, bad, camera, method="nearest")
