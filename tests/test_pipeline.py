"""evfuse run end to end on a tiny scene, and one clear line for every kind of bad input."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from fusion.cli import main
from sim.exr import read_depth
from tests.conftest import FAST, WALL, scene_text

EXTRA = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run")
    scene = folder / "wall.toml"
    scene.write_text(scene_text(WALL, trajectory=FAST, duration=0.3, extra=EXTRA))
    out = folder / "out"
    code = main(["run", str(scene), "--t0", "0.0", "--t1", "0.3", "--out", str(out), "--quiet"])
    return code, out


def test_run_writes_every_promised_file_with_consistent_figures(tiny_run, capsys):
    code, out = tiny_run
    assert code == 0
    for name in ("sequence/sequence.json", "sequence/events.h5", "map/semidense_depth.exr",
                 "map/confidence.exr", "map/mask.png", "map/overlay.png", "map/map.ply",
                 "map/map.json", "fill/dense_depth.exr", "fill/segments.png",
                 "fill/filled_mask.png", "fill/figure.png", "fill/dense.ply", "fill/fill.json",
                 "fill/error.png", "overview.png", "report.json"):
        assert (out / name).is_file(), name
    assert not out.with_name("out.partial").exists()
    report = json.loads((out / "report.json").read_text())
    fill = json.loads((out / "fill" / "fill.json").read_text())
    mapped = json.loads((out / "map" / "map.json").read_text())
    # N1 is the map's count everywhere; N1_in_frame the points projected into the frame
    assert report["N1"] == fill["N1"] == mapped["N1"] >= report["N1_in_frame"]
    assert report["N1_in_frame"] == fill["N1_in_frame"] and report["N2"] == fill["N2"]
    assert mapped["N1"] == np.count_nonzero(read_depth(out / "map" / "semidense_depth.exr"))
    assert fill["N2"] == np.count_nonzero(read_depth(out / "fill" / "dense_depth.exr"))
    assert report["N2"] >= report["N1_in_frame"] > 0 and 0 <= report["beta"] < 1
    assert report["beta_counts"] == fill["beta_counts"]
    assert report["ground_truth"] and report["simulated"]
    for value in report["mae_cm"].values():
        assert math.isfinite(value)
    # every MAE carries its coverage, taken from the map's and the fill's own error blocks
    summary = report["errors_summary"]
    assert set(summary) == {"map", "map_in_frame", "filled", "all"} == set(report["mae_cm"])
    for name, block in (("map", mapped["errors"]), ("map_in_frame", fill["errors"]["map"]),
                        ("filled", fill["errors"]["filled"]), ("all", fill["errors"]["all"])):
        block = block.get("overall", block)
        for key in ("mae_cm", "n", "completeness", "points", "precision_5pct", "precision_1pct"):
            assert summary[name][key] == block[key], (name, key)
        assert report["mae_cm"][name] == block["mae_cm"]
    assert summary["map"]["points"] == mapped["N1"]
    assert summary["map_in_frame"]["points"] == report["N1_in_frame"]
    assert summary["all"]["points"] == report["N2"]
    assert 0 < summary["map"]["completeness"] < summary["all"]["completeness"] <= 1
    assert report["depth_range_from"].startswith("exact depth")
    low, high = report["depth_range_m"]
    assert low < 1.0 < high                                        # the wall is 1 m away
    overview = cv2.imread(str(out / "overview.png"))
    # frame, events, map, segmentation / dense, exact depth, error, point cloud: 4 x 2 panels of
    # 320 px (64 px scaled by 5) under 26-px titles, with a 22-px colour-bar line each row
    assert overview.shape == (2 * (26 + 5 * 48 + 22), 4 * 320, 3)


def test_the_printed_summary_gives_each_error_with_its_coverage(tiny_run, capsys):
    from fusion.cli import _print_report

    _, out = tiny_run
    report = json.loads((out / "report.json").read_text())
    _print_report(report, out)
    printed = capsys.readouterr().out
    for label, key in (("event map", "map"), ("map in the frame", "map_in_frame"),
                       ("filled pixels", "filled"), ("dense map", "all")):
        e = report["errors_summary"][key]
        line = next(row for row in printed.splitlines() if row.strip().startswith(label))
        assert f"MAE {e['mae_cm']:.2f} cm on {e['n']:,} px" in line, line
        assert f"(completeness {100 * e['completeness']:.1f} %)" in line, line
        assert f"precision {100 * e['precision_5pct']:.1f} % within 5 %" in line, line
        assert f"of {e['points']:,} points" in line, line
    rows = {row.strip().rsplit("  ", 1)[0].strip(): row.split()[-1] for row in printed.splitlines()
            if row.startswith("  N")}
    assert rows["N1 (map points)"] == f"{report['N1']:,}"
    assert rows["N1 in the frame"] == f"{report['N1_in_frame']:,}"


def test_show_redraws_the_same_overview(tiny_run, tmp_path):
    _, out = tiny_run
    target = tmp_path / "again.png"
    assert main(["show", str(out), "--out", str(target)]) == 0
    np.testing.assert_array_equal(cv2.imread(str(target)), cv2.imread(str(out / "overview.png")))


def test_a_run_is_never_overwritten_silently(tiny_run, capsys):
    _, out = tiny_run
    before = (out / "report.json").read_bytes()
    assert main(["run", str(out / "sequence"), "--out", str(out), "--quiet"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "report.json").read_bytes() == before


BAD_TOML = 'name = "x"\nduration = [1.0\n'


@pytest.mark.parametrize("argv, message", [
    (["map", "{tmp}/missing", "--out", "{tmp}/o"], "does not exist"),
    (["run", "{tmp}/missing", "--out", "{tmp}/o"], "no such scene file"),
    (["fill", "{tmp}/missing", "--out", "{tmp}/o"], "no map.json"),
    (["show", "{tmp}/missing"], "no report.json"),
    (["simulate", "{tmp}/bad.toml", "--out", "{tmp}/o"], "bad.toml"),
    (["events", "{tmp}/badevents", "--stats"], "events.txt:2: x 'three'"),
    (["map", "{tmp}/badevents", "--out", "{tmp}/o", "--t0", "0", "--t1", "0.2", "--quiet"],
     "events.txt:2: x 'three'"),
])
def test_bad_input_gives_one_line_and_exit_status_2(argv, message, tmp_path, capsys,
                                                     plane_sequence):
    (tmp_path / "bad.toml").write_text(BAD_TOML)
    bad = tmp_path / "badevents"                         # a sequence with a broken events.txt
    bad.mkdir()
    for name in ("calib.txt", "images.txt", "groundtruth.txt"):
        (bad / name).write_bytes((plane_sequence / name).read_bytes())
    (bad / "images").symlink_to(plane_sequence / "images")
    (bad / "events.txt").write_text("0.001 3 4 1\n0.002 three 4 0\n")
    code = main([a.format(tmp=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in err, err
    assert lines[0].startswith(f"evfuse {argv[0]}: error: ")


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_shows_the_traceback(tmp_path, where):
    argv = ["map", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]
    with pytest.raises(ValueError, match="does not exist"):
        main(["--debug", *argv] if where == "before" else [*argv, "--debug"])


@pytest.mark.parametrize("argv, message", [
    (["--t0", "10", "--t1", "11"], "does not overlap the poses"),
    (["--t0", "1", "--t1", "2"], "no events in the window [1.0, 2.0] s"),
    (["--min-depth", "3", "--max-depth", "8"], "does not seem to contain the scene"),
])
def test_bad_runs_on_the_real_recording_leave_nothing_behind(argv, message, ecd_slider, tmp_path,
                                                             capsys):
    out = tmp_path / "run"
    assert main(["run", str(ecd_slider), "--out", str(out), "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_an_unexpected_failure_is_still_one_line(tiny_run, monkeypatch, capsys):
    import fusion.pipeline

    def broken(*args, **kwargs):
        raise RuntimeError("disk on fire")

    _, out = tiny_run
    monkeypatch.setattr(fusion.pipeline, "draw_overview", broken)
    assert main(["show", str(out), "--out", str(out.parent / "x.png")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["evfuse show: unexpected error: RuntimeError: disk on fire (run with --debug "
                   "for the traceback)"]
