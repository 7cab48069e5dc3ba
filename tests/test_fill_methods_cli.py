"""``--method`` and ``--param`` of evfuse fill and evfuse run: a method by name or module:function,
with settings of its own, fills a hand-made map folder, the paper's method stays what it was,
the settings are recorded, and unknown or contradictory flags are refused in one line."""

from __future__ import annotations

import json
import sys

import cv2
import numpy as np
import pytest

from fusion.fill.dense import DenseParams, densify
from fusion.fill.filling import FillParams, filling_score
from sim.exr import read_depth, read_exr_channels, write_depth
from tests.conftest import run_cli
from tests.test_cli_messages import _one_line

H, W = 30, 40


def _ramp_scene():
    """A 40x30 frame: background 100 with a 12x10 square of 160 (rows 10-19, columns 14-25).
    Map points on the square's one-pixel outer ring at 2 + 0.05 * column metres (a slanted
    ring, so that the paper's weightings give different interiors) and 60 points of texture at
    4 m on the background's top rows (too many inside it for the paper to fill the
    background)."""
    frame = np.full((H, W), 100, np.uint8)
    frame[10:20, 14:26] = 160
    ring = np.zeros((H, W), bool)
    ring[9, 13:27] = ring[20, 13:27] = True
    ring[9:21, 13] = ring[9:21, 26] = True
    columns = np.broadcast_to(np.arange(W, dtype=np.float32), (H, W))
    sparse = np.where(ring, np.float32(2.0) + np.float32(0.05) * columns, 0).astype(np.float32)
    sparse[0:5:2, 0:40:2] = 4.0
    return frame, sparse


def _map_folder(root):
    """A map folder by hand, as evfuse map writes it: map.json and semidense_depth.exr at the
    reference view, and its sequence (one frame at the reference time, identity poses, the
    exact depth of the frame), so that the map projects into the frame unchanged."""
    frame, sparse = _ramp_scene()
    sequence = root / "seq"
    (sequence / "images").mkdir(parents=True)
    (sequence / "depth").mkdir()
    (sequence / "calib.txt").write_text("35 30 19.5 14.5 0 0 0 0 0\n")
    cv2.imwrite(str(sequence / "images" / "frame_00000000.png"), frame)
    (sequence / "images.txt").write_text("0.5 images/frame_00000000.png\n")
    truth = np.full((H, W), 4.0, np.float32)
    truth[10:20, 14:26] = 3.0
    write_depth(sequence / "depth" / "frame_00000000.exr", truth)
    (sequence / "depthmaps.txt").write_text("0.5 depth/frame_00000000.exr\n")
    (sequence / "groundtruth.txt").write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n")
    mapped = root / "map"
    mapped.mkdir()
    write_depth(mapped / "semidense_depth.exr", sparse)
    (mapped / "map.json").write_text(json.dumps({
        "t_ref": 0.5, "T_world_ref": np.eye(4).tolist(), "sequence": "../seq",
        "camera": {"width": W, "height": H, "fx": 35.0, "fy": 30.0, "cx": 19.5, "cy": 14.5},
        "N1": int(np.count_nonzero(sparse))}))
    return mapped


def test_the_hand_made_map_projects_into_the_frame_unchanged(tmp_path):
    """The cases below rest on it: the event image is the semi-dense map itself."""
    from fusion.fill.dense import fill_map

    frame, sparse = _ramp_scene()
    result = fill_map(_map_folder(tmp_path))
    np.testing.assert_array_equal(result.sparse, sparse)
    np.testing.assert_array_equal(result.frame, frame)
    assert result.info["frame"] == "images/frame_00000000.png" and result.truth is not None


def test_fill_with_nearest_writes_every_file_without_a_segmentation(tmp_path, capsys):
    frame, sparse = _ramp_scene()
    out = tmp_path / "out"
    assert run_cli(["fill", str(_map_folder(tmp_path)), "--method", "nearest", "--out",
                 str(out)]) == 0
    for name in ("dense_depth.exr", "segments.png", "filled_mask.png", "figure.png",
                 "dense.ply", "fill.json", "error.png"):
        assert (out / name).is_file(), name
    assert not (out / "confidence.exr").exists()            # nearest gives no confidence
    meta = json.loads((out / "fill.json").read_text())
    assert meta["method"] == "nearest" and meta["method_origin"] == "built-in"
    assert meta["segmentation"] is None and meta["regions"] is None
    assert meta["regions_filled"] is None and meta["params"] == {"band": 3}
    assert "does not segment" in meta["files"]["segments.png"]
    dense = read_depth(out / "dense_depth.exr")
    # nearest fills the whole frame: N2 is every pixel, and beta the paper's formula on it
    in_frame = int(np.count_nonzero(sparse))
    assert meta["N2"] == np.count_nonzero(dense) == H * W == meta["Res"]
    assert meta["N1_in_frame"] == in_frame == 108
    assert meta["beta"] == pytest.approx((H * W - in_frame) / (H * W + in_frame / (H * W)))
    # Each pixel has its nearest map point's depth: the square's centre (15, 20) is 5 px from
    # the ring's point (20, 20) (6 and more from the others), the bottom-right corner nearest
    # the ring's corner (20, 26); a map point keeps its own depth.
    assert dense[15, 20] == sparse[20, 20] == np.float32(3.0)
    assert dense[29, 39] == sparse[20, 26]
    np.testing.assert_array_equal(dense[sparse > 0], sparse[sparse > 0])
    segments = cv2.imread(str(out / "segments.png"), cv2.IMREAD_UNCHANGED)
    assert segments.shape == (H, W) and not segments.any()
    filled = cv2.imread(str(out / "filled_mask.png"), cv2.IMREAD_GRAYSCALE)
    assert (filled > 0).sum() == H * W - in_frame
    printed = capsys.readouterr().out
    assert "N2 = 1200 (no segmentation)" in printed and "method nearest" in printed


def test_paper_idw_is_the_default_byte_for_byte(tmp_path):
    mapped = _map_folder(tmp_path)
    frame, sparse = _ramp_scene()
    runs = {"default": [], "method": ["--method", "paper-idw"], "flag": ["--weighting", "idw"],
            "gaussian": ["--method", "paper-gaussian"],
            "gaussian_flag": ["--weighting", "gaussian"]}
    for name, flags in runs.items():
        assert run_cli(["fill", str(mapped), "--out", str(tmp_path / name), *flags]) == 0, name

    def files(name):
        return {f: (tmp_path / name / f).read_bytes()
                for f in ("dense_depth.exr", "segments.png", "filled_mask.png", "figure.png",
                          "dense.ply", "error.png")}

    def meta(name):
        document = json.loads((tmp_path / name / "fill.json").read_text())
        document.pop("timings")
        return document

    assert files("default") == files("method") == files("flag")
    assert meta("default") == meta("method") == meta("flag")
    assert meta("default")["method"] == "paper-idw"
    assert meta("default")["segmentation"] == "region growing"
    assert meta("default")["regions_filled"] >= 1
    # the paper's stages themselves, called directly, give the same dense map
    np.testing.assert_array_equal(read_depth(tmp_path / "default" / "dense_depth.exr"),
                                  densify(frame, sparse)[2])
    assert files("gaussian") == files("gaussian_flag")
    assert meta("gaussian") == meta("gaussian_flag")
    assert meta("gaussian")["method"] == "paper-gaussian"
    gaussian = DenseParams(fill=FillParams("gaussian"))
    np.testing.assert_array_equal(read_depth(tmp_path / "gaussian" / "dense_depth.exr"),
                                  densify(frame, sparse, gaussian)[2])
    # ... and differs from IDW's here: the two flags did select a weighting
    assert files("gaussian")["dense_depth.exr"] != files("default")["dense_depth.exr"]


USER_METHOD = '''
import numpy as np


def flat(frame, sparse, camera, params):
    """Every pixel at the median map depth; confidence 1 on map points, 0.25 elsewhere."""
    points = sparse > 0
    dense = np.where(points, sparse, np.median(sparse[points])).astype(np.float32)
    return dense, np.where(points, 1.0, 0.25)


def forgetful(frame, sparse, camera, params):
    """Fills the pixels without a map point and forgets the map points."""
    return np.where(sparse > 0, 0.0, 1.0).astype(np.float32)


def shifted(frame, sparse, camera, params):
    """Every pixel without a map point at params['depth'] metres."""
    return np.where(sparse > 0, sparse, params["depth"]).astype(np.float32)
'''


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    """A module written on the fly, importable as ``evfuse_test_user_fill``."""
    folder = tmp_path / "user"
    folder.mkdir()
    (folder / "evfuse_test_user_fill.py").write_text(USER_METHOD)
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.delitem(sys.modules, "evfuse_test_user_fill", raising=False)
    yield "evfuse_test_user_fill"
    sys.modules.pop("evfuse_test_user_fill", None)


def test_a_module_function_fills_and_its_confidence_is_written(tmp_path, user_module):
    from sim.camera import Camera, write_calib

    frame, sparse = _ramp_scene()
    cv2.imwrite(str(tmp_path / "f.png"), frame)
    write_depth(tmp_path / "d.exr", sparse)
    write_calib(tmp_path / "calib.txt", Camera(W, H, 35.0, 30.0, 19.5, 14.5))
    out = tmp_path / "out"
    spec = f"{user_module}:flat"
    assert run_cli(["fill", "--frame", str(tmp_path / "f.png"), "--sparse-depth",
                 str(tmp_path / "d.exr"), "--calib", str(tmp_path / "calib.txt"), "--method",
                 spec, "--out", str(out)]) == 0
    meta = json.loads((out / "fill.json").read_text())
    assert meta["method"] == spec and meta["method_origin"] == "module:function"
    assert meta["regions"] is None and "confidence.exr" in meta["files"]
    dense = read_depth(out / "dense_depth.exr")
    median = np.float32(np.median(sparse[sparse > 0]))
    assert meta["N2"] == H * W and (dense[sparse == 0] == median).all()
    confidence = read_exr_channels(out / "confidence.exr")
    assert list(confidence) == ["Y"] and confidence["Y"].dtype == np.float32
    np.testing.assert_array_equal(confidence["Y"], np.where(sparse > 0, 1.0, 0.25))
    assert meta["beta"] == pytest.approx(filling_score(108, H * W, H * W))


def test_the_figure_of_another_method_says_what_it_did_not_use(tmp_path, user_module):
    from fusion.figures import fill_figure_panels
    from fusion.fill.dense import fill_frame
    from sim.camera import Camera

    frame, sparse = _ramp_scene()
    camera = Camera(W, H, 35.0, 30.0, 19.5, 14.5)
    result = fill_frame(frame, sparse, camera, method="nearest")
    assert result.regions is None and result.labels.dtype == np.int32
    assert not result.labels.any() and result.method == "nearest"
    panels, titles, _, _ = fill_figure_panels(result, DenseParams())
    assert titles[1] == "(b) segmentation: not used by nearest"
    assert titles[2] == f"(c) pixels filled by nearest ({H * W - 108}, green)"
    assert titles[3] == "(d) regions to fill: not used by nearest"
    # (c): a filled pixel is tinted green, a map point stays the frame's gray
    assert tuple(panels[2][15, 20]) == (80, 180, 80)       # (160 + (0, 200, 0)) // 2
    assert tuple(panels[2][9, 13]) == (100, 100, 100)
    flat = fill_frame(frame, sparse, camera, method=f"{user_module}:flat")
    panels, titles, _, _ = fill_figure_panels(flat, DenseParams())
    assert titles[3] == f"(d) confidence of {user_module}:flat (black 0, white 1)"
    assert tuple(panels[3][15, 20]) == (64, 64, 64) and tuple(panels[3][9, 13]) == (255,) * 3


def test_a_method_that_drops_map_points_is_refused(tmp_path, user_module, capsys):
    code = run_cli(["fill", str(_map_folder(tmp_path)), "--method", f"{user_module}:forgetful",
                 "--out", str(tmp_path / "out")])
    line = _one_line(capsys, code, "fill")
    assert f"filling method {user_module}:forgetful left 108 of the 108 map points" in line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["fill", "run"])
def test_an_unknown_method_is_refused_in_one_line(command, tmp_path, capsys):
    """Refused before anything else: evfuse run would otherwise say its SOURCE is missing."""
    source = str(_map_folder(tmp_path) if command == "fill" else tmp_path / "no-source")
    out = tmp_path / "out"
    code = run_cli([command, source, "--method", "no-such-method", "--out", str(out)])
    line = _one_line(capsys, code, command)
    assert "--method no-such-method: unknown filling method 'no-such-method'" in line
    assert "nearest" in line and "module:function" in line       # what is expected
    assert not out.exists()
    code = run_cli([command, source, "--method", "no_such_module_xyz:fill", "--out", str(out)])
    line = _one_line(capsys, code, command)
    assert "cannot import module 'no_such_module_xyz'" in line and not out.exists()


@pytest.mark.parametrize("flags, message", [
    (["--method", "nearest", "--weighting", "gaussian"],
     "--method nearest and --weighting gaussian contradict each other"),
    (["--method", "nearest", "--weighting", "idw"],
     "--method nearest and --weighting idw contradict each other"),
    (["--method", "paper-idw", "--weighting", "gaussian"],
     "--method paper-idw and --weighting gaussian contradict each other: paper-idw uses idw"),
    (["--method", "paper-gaussian", "--weighting", "idw"],
     "--method paper-gaussian and --weighting idw contradict each other"),
    (["--method", "telea", "--threshold", "5"],
     "--method telea and --threshold 5 contradict each other: only the paper's methods"),
])
@pytest.mark.parametrize("command", ["fill", "run"])
def test_contradictory_flags_are_refused_in_one_line(command, flags, message, tmp_path, capsys):
    """Refused before anything else: evfuse run would otherwise say its SOURCE is missing."""
    source = str(_map_folder(tmp_path) if command == "fill" else tmp_path / "no-source")
    out = tmp_path / "out"
    line = _one_line(capsys, run_cli([command, source, "--out", str(out), *flags]), command)
    assert message in line
    assert not out.exists()


def test_flags_at_their_default_do_not_contradict_another_method(tmp_path):
    assert run_cli(["fill", str(_map_folder(tmp_path)), "--method", "nearest", "--threshold", "3",
                 "--out", str(tmp_path / "out")]) == 0


@pytest.mark.parametrize("command", ["fill", "run"])
def test_help_gives_the_method_and_its_default(command, capsys):
    with pytest.raises(SystemExit) as stop:
        run_cli([command, "--help"])
    assert stop.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--method METHOD" in text and "(default paper-idw, the paper's;" in text
    assert "`evfuse methods`" in text and "--weighting W is --method paper-W" in text


def _meta(folder):
    document = json.loads((folder / "fill.json").read_text())
    document.pop("timings")
    return document


def test_param_settings_reach_the_method_and_fill_json_records_them(tmp_path, user_module,
                                                                    capsys):
    mapped = _map_folder(tmp_path)
    _, sparse = _ramp_scene()
    out = tmp_path / "shifted"
    assert run_cli(["fill", str(mapped), "--method", f"{user_module}:shifted", "--param",
                 "depth=2.5", "--param", "note=abc", "--out", str(out)]) == 0
    dense = read_depth(out / "dense_depth.exr")
    assert np.all(dense[sparse == 0] == 2.5)                   # the setting reached the method
    meta = _meta(out)
    assert meta["method"] == f"{user_module}:shifted"
    assert meta["method_params"] == {"depth": 2.5, "note": "abc"}   # not declared: as parsed
    assert f"method {user_module}:shifted{{depth=2.5,note=abc}}" in capsys.readouterr().out
    # Three ways to say the same settings give the same fill; an int for a float field is
    # recorded as the float it is.
    runs = {"flags": ["--method", "plane", "--param", "residual_rel=1", "--param",
                      "min_points=4"],
            "scoped": ["--method", "plane", "--param", "plane.residual_rel=1", "--param",
                       "plane.min_points=4"],
            "inline": ["--method", "plane{residual_rel=1,min_points=4}"]}
    for name, flags in runs.items():
        assert run_cli(["fill", str(mapped), "--out", str(tmp_path / name), *flags]) == 0, name
    assert _meta(tmp_path / "flags") == _meta(tmp_path / "scoped") == _meta(tmp_path / "inline")
    recorded = _meta(tmp_path / "flags")["method_params"]
    assert recorded == {"residual_rel": 1.0, "min_points": 4}
    assert type(recorded["residual_rel"]) is float and type(recorded["min_points"]) is int
    assert "method plane{min_points=4,residual_rel=1.0}" in capsys.readouterr().out
    assert run_cli(["fill", str(mapped), "--out", str(tmp_path / "default")]) == 0
    assert _meta(tmp_path / "default")["method_params"] == {}


def test_a_paper_method_s_length_set_by_param_is_its_flag(tmp_path):
    """``--weighting gaussian --param sigma=3`` is ``--sigma 3``: the same fill, the same
    paper's parameters; only method_params says how it was asked."""
    mapped = _map_folder(tmp_path)
    assert run_cli(["fill", str(mapped), "--out", str(tmp_path / "param"), "--weighting",
                 "gaussian", "--param", "sigma=3"]) == 0
    assert run_cli(["fill", str(mapped), "--out", str(tmp_path / "flag"), "--method",
                 "paper-gaussian", "--sigma", "3"]) == 0
    assert run_cli(["fill", str(mapped), "--out", str(tmp_path / "five"), "--method",
                 "paper-gaussian"]) == 0
    param, flag = _meta(tmp_path / "param"), _meta(tmp_path / "flag")
    assert param["params"]["fill"] == flag["params"]["fill"] == {
        "weighting": "gaussian", "sigma": 3.0, "scale": 1.0}
    assert param.pop("method_params") == {"sigma": 3.0} and flag.pop("method_params") == {}
    assert param == flag
    depth = {name: (tmp_path / name / "dense_depth.exr").read_bytes()
             for name in ("param", "flag", "five")}
    assert depth["param"] == depth["flag"] != depth["five"]


@pytest.mark.parametrize("flags, message", [
    (["--method", "plane", "--param", "residual_rel"],
     "--param residual_rel: expected KEY=VALUE, or METHOD.KEY=VALUE for one method's"),
    (["--method", "plane", "--param", "=0.1"], "--param =0.1: expected KEY=VALUE"),
    (["--method", "plane", "--param", "residual=0.1"],
     "--param residual=0.1: filling method plane: unknown parameter 'residual'; expected one "
     "of residual_rel, min_points,"),
    (["--method", "plane", "--param", "min_points=2.5"],
     "--param min_points=2.5: filling method plane: min_points expects an integer, got 2.5"),
    (["--method", "plane", "--param", "residual_rel=-1"],
     "--param residual_rel=-1: filling method plane: residual_rel must be a finite number > 0, "
     "got -1.0"),
    (["--method", "plane", "--param", "telea.radius=3"],
     "--param telea.radius=3: the filling method is plane, not telea"),
    (["--method", "plane{residual_rel=0.05}", "--param", "residual_rel=0.03"],
     "--param residual_rel=0.03: residual_rel of plane is already set by --method "
     "plane{residual_rel=0.05}; set it once"),
    (["--method", "plane{residual_rel}"],
     "--method plane{residual_rel}: expected NAME or NAME{KEY=VALUE,...}; got 'residual_rel'"),
    (["--method", "hybrid", "--param", "canny_low=50"],
     "--param canny_low=50: filling method hybrid: canny_low must be <= canny_high"),
    (["--param", "sigma=3"],
     "--param sigma=3: filling method paper-idw: unknown parameter 'sigma'; paper-idw takes no "
     "parameters"),
    (["--weighting", "gaussian", "--sigma", "4", "--param", "sigma=3"],
     "--sigma 4 contradicts paper-gaussian{sigma=3.0}: set sigma once"),
])
@pytest.mark.parametrize("command", ["fill", "run"])
def test_a_bad_param_is_refused_in_one_line_before_any_work(command, flags, message, tmp_path,
                                                            capsys):
    """Refused before anything else: evfuse run would otherwise say its SOURCE is missing."""
    source = str(_map_folder(tmp_path) if command == "fill" else tmp_path / "no-source")
    out = tmp_path / "out"
    line = _one_line(capsys, run_cli([command, source, "--out", str(out), *flags]), command)
    assert message in line
    assert not out.exists()
