"""evfuse run end to end on a tiny scene, and one clear line for every kind of bad input."""

from __future__ import annotations

import json
import math
import re

import cv2
import numpy as np
import pytest

from sim.exr import read_depth
from tests.conftest import FAST, WALL, run_cli, scene_text

EXTRA = ("depth_range = [0.4, 2.5]\n"
         "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n")


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run")
    scene = folder / "wall.toml"
    scene.write_text(scene_text(WALL, trajectory=FAST, duration=0.3, extra=EXTRA))
    out = folder / "out"
    code = run_cli(["run", str(scene), "--t0", "0.0", "--t1", "0.3", "--out", str(out), "--quiet"])
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
    # Blind by default: the DSI's range is the scene file's declaration, not the exact depth.
    assert report["depth_range_from"] == "scene file (declared working range)"
    assert report["depth_range_m"] == [0.4, 2.5] and report["oracle"] is False
    assert mapped["oracle"] is False and fill["oracle"] is False
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
    overview = cv2.imread(str(out / "overview.png"))
    # frame, events, map, segmentation / dense, exact depth, error, point cloud: 4 x 2 panels of
    # 320 px (64 px scaled by 5) under 26-px titles, with a 22-px colour-bar line each row
    assert overview.shape == (2 * (26 + 5 * 48 + 22), 4 * 320, 3)


def test_run_and_map_then_fill_give_the_same_numbers(tiny_run, tmp_path, capsys):
    """One wiring: `evfuse run` is `evfuse map` + `evfuse fill` with the same arguments."""
    _, out = tiny_run
    report = json.loads((out / "report.json").read_text())
    window = ["--t0", "0.0", "--t1", "0.3"]
    assert run_cli(["map", str(out / "sequence"), "--out", str(tmp_path / "map"), "--quiet",
                 *window]) == 0
    assert run_cli(["fill", str(tmp_path / "map"), "--out", str(tmp_path / "fill")]) == 0
    assert "scene file (declared working range)" in capsys.readouterr().out
    mapped = json.loads((tmp_path / "map" / "map.json").read_text())
    fill = json.loads((tmp_path / "fill" / "fill.json").read_text())
    assert mapped["t_ref"] == report["t_ref"]
    assert mapped["depth_range_m"] == report["depth_range_m"]
    for key in ("N1", "N2", "beta"):
        assert fill[key] == report[key], key
    np.testing.assert_array_equal(read_depth(tmp_path / "fill" / "dense_depth.exr"),
                                  read_depth(out / "fill" / "dense_depth.exr"))
    assert fill["errors"] == json.loads((out / "fill" / "fill.json").read_text())["errors"]


def test_the_oracle_range_is_opt_in_and_every_output_says_so(tiny_run, tmp_path, capsys):
    _, out = tiny_run
    run = tmp_path / "oracle"
    assert run_cli(["run", str(out / "sequence"), "--out", str(run), "--t0", "0.0", "--t1", "0.3",
                 "--depth-range", "oracle", "--quiet"]) == 0
    report = json.loads((run / "report.json").read_text())
    assert report["oracle"] is True and report["depth_range_from"].startswith("oracle")
    low, high = report["depth_range_m"]
    assert 1.0 / 1.2 - 0.05 < low < 1.0 < high < 1.25 * 1.2       # the wall, 1-1.2 m away
    for name in ("map/map.json", "fill/fill.json"):
        assert json.loads((run / name).read_text())["oracle"] is True, name
    for name in ("map/overlay.png", "fill/figure.png", "overview.png"):     # a header line
        oracle, blind = (cv2.imread(str(f / name)).shape for f in (run, out))
        assert oracle[0] > blind[0] and oracle[1] == blind[1], name
    capsys.readouterr()
    assert run_cli(["map", str(out / "sequence"), "--out", str(tmp_path / "m"), "--depth-range",
                 "oracle", "--min-depth", "0.5", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "drop --min-depth/--max-depth" in err[0]


def test_the_oracle_range_is_refused_on_a_real_recording(ecd_slider, tmp_path, capsys):
    assert run_cli(["run", str(ecd_slider), "--out", str(tmp_path / "o"), "--depth-range",
                 "oracle", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs the exact depth of a simulated sequence" in err[0]
    assert not (tmp_path / "o").exists()


def test_report_records_the_window_asked_for_and_used(tiny_run):
    """The scene was simulated over exactly [0, 0.3] s: nothing to clip."""
    _, out = tiny_run
    report = json.loads((out / "report.json").read_text())
    mapped = json.loads((out / "map" / "map.json").read_text())
    assert report["window_requested_s"] == report["window_s"] == [0.0, 0.3]
    assert report["window_clipped"] is False
    assert mapped["window_s"] == report["window_s"] and mapped["window_clipped"] is False


def test_the_printed_summary_gives_each_error_with_its_coverage(tiny_run):
    from fusion.summaries import run_summary

    _, out = tiny_run
    report = json.loads((out / "report.json").read_text())
    printed = run_summary(report, out)
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


def test_run_records_the_method_s_settings(tiny_run, tmp_path, capsys):
    """``--param`` reaches the fill of ``evfuse run``: report.json and fill.json record it, the
    summary shows the method with it; the paper's default records none."""
    _, out = tiny_run
    assert json.loads((out / "report.json").read_text())["method_params"] == {}
    run = tmp_path / "telea"
    assert run_cli(["run", str(out / "sequence"), "--out", str(run), "--t0", "0.0", "--t1", "0.3",
                 "--method", "telea", "--param", "radius=2", "--quiet"]) == 0
    report = json.loads((run / "report.json").read_text())
    fill = json.loads((run / "fill" / "fill.json").read_text())
    assert report["method"] == fill["method"] == "telea"
    assert report["method_params"] == fill["method_params"] == {"radius": 2.0}
    assert "filling method      telea{radius=2.0} (built-in)" in capsys.readouterr().out


def test_show_redraws_the_same_overview(tiny_run, tmp_path):
    _, out = tiny_run
    target = tmp_path / "again.png"
    assert run_cli(["show", str(out), "--out", str(target)]) == 0
    np.testing.assert_array_equal(cv2.imread(str(target)), cv2.imread(str(out / "overview.png")))


def test_overview_scales_cover_the_exact_depth_and_titles_name_each_count(tiny_run):
    from fusion.figures import Caption
    from fusion.pipeline import _overview_panels, draw_overview
    from sim.sequence import load_sequence

    _, out = tiny_run
    report = json.loads((out / "report.json").read_text())
    sequence = load_sequence(out / "sequence")
    k = int(np.argmin(np.abs(sequence.depth_times - report["t_frame"])))
    assert sequence.depth_times[k] == pytest.approx(report["t_frame"], abs=1e-9)
    truth = read_depth(sequence.depth_paths[k])
    maps = [read_depth(out / "map" / "semidense_depth.exr"),
            read_depth(out / "fill" / "dense_depth.exr")]
    # The wall is flat at 1 m: the shared scale is the exact depth's, widened to 10 % of it,
    # and says where map depths fall outside it.
    assert truth[truth > 0].min() == pytest.approx(1.0, abs=1e-6) == truth.max()
    values = np.concatenate([d[d > 0] for d in maps])
    low = "< 0.95 m" if (values < 0.95).any() else "0.95 m"
    high = "> 1.05 m" if (values > 1.05).any() else "1.05 m"
    panels, titles, legends, header = _overview_panels(out, report)
    for k in (2, 4, 5):                          # semi-dense, dense, exact: one shared scale
        assert (legends[k].low, legends[k].high) == (low, high), titles[k]
    # the events panel says which colour is ON and which OFF (red, blue: BGR)
    assert dict(legends[1].keys)["OFF"] == (255, 0, 0)
    assert [colour for name, colour in legends[1].keys if name.startswith("ON")] == [(0, 0, 255)]
    assert titles[6] == "|error| of the dense map"
    assert [name for name, _ in legends[6].keys] == ["no value", "no surface"]
    assert legends[6].high.endswith(" cm")
    assert isinstance(legends[7], Caption) and "deg left" in legends[7].text
    assert header == [] and titles[2] == (f"semi-dense map (N1 = {report['N1']}, "
                                          f"{report['N1_in_frame']} in the frame)")
    renamed = {**report, "N1": 2570, "N1_in_frame": 2541, "oracle": True}
    _, titles, _, header = _overview_panels(out, renamed)
    assert titles[2] == "semi-dense map (N1 = 2570, 2541 in the frame)"
    assert len(header) == 1 and "exact depth (oracle)" in header[0]
    plain, marked = draw_overview(out, report), draw_overview(out, {**report, "oracle": True})
    assert marked.shape[0] == plain.shape[0] + 24      # the header line, above the same panels
    np.testing.assert_array_equal(marked[24:], plain)
    assert (marked[:24] != 255).any()
    overlay = cv2.imread(str(out / "map" / "overlay.png"))      # the map with its colour bar
    assert overlay.shape == (26 + 5 * 48 + 22, 320, 3)


def test_a_run_is_never_overwritten_silently(tiny_run, capsys):
    _, out = tiny_run
    before = (out / "report.json").read_bytes()
    assert run_cli(["run", str(out / "sequence"), "--out", str(out), "--quiet"]) == 2
    assert "contains the input" in capsys.readouterr().err       # and would delete it
    assert run_cli(["run", str(out / "sequence"), "--out", str(out), "--quiet", "--overwrite"]) == 2
    assert (out / "report.json").read_bytes() == before


BAD_TOML = 'name = "x"\nduration = [1.0\n'


@pytest.mark.parametrize("argv, message", [
    (["map", "{tmp}/missing", "--out", "{tmp}/o"], "does not exist"),
    (["run", "{tmp}/missing", "--out", "{tmp}/o"], "no such scene file"),
    (["fill", "{tmp}/missing", "--out", "{tmp}/o"], "does not exist"),
    (["show", "{tmp}/missing", "--out", "{tmp}/o.png"], "no report.json"),
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
    code = run_cli([a.format(tmp=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in err, err
    assert lines[0].startswith(f"evfuse {argv[0]}: error: ")


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_shows_the_traceback(tmp_path, where):
    argv = ["map", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]
    with pytest.raises(ValueError, match="does not exist"):
        run_cli(["--debug", *argv] if where == "before" else [*argv, "--debug"])


@pytest.mark.parametrize("argv, message", [
    (["--t0", "10", "--t1", "11"], "time window [10, 11] s lies outside the data"),
    (["--t0", "1", "--t1", "2"], "time window [1, 2] s lies outside the data"),
    (["--t0", "0", "--t1", "1", "--min-depth", "0.47", "--max-depth", "2.4"],
     "time window [0, 1] s reaches 0.826 s past the data"),
    (["--min-depth", "3", "--max-depth", "8"], "does not seem to contain the scene"),
])
def test_bad_runs_on_the_real_recording_leave_nothing_behind(argv, message, ecd_slider, tmp_path,
                                                             capsys):
    out = tmp_path / "run"
    assert run_cli(["run", str(ecd_slider), "--out", str(out), "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_an_unexpected_failure_is_still_one_line(tiny_run, monkeypatch, capsys):
    import fusion.pipeline

    def broken(*args, **kwargs):
        raise RuntimeError("disk on fire")

    _, out = tiny_run
    monkeypatch.setattr(fusion.pipeline, "draw_overview", broken)
    assert run_cli(["show", str(out), "--out", str(out.parent / "x.png")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["evfuse show: unexpected error: RuntimeError: disk on fire (run with --debug "
                   "for the traceback)"]


def test_run_with_telea_records_it_and_its_overview_draws(tiny_run, tmp_path, capsys):
    """The same window and map as the paper's run, filled by telea: report.json and fill.json
    name it, there is no segmentation, and the overview's segmentation panel says so."""
    from fusion.pipeline import _overview_panels

    _, out = tiny_run
    run = tmp_path / "telea"
    capsys.readouterr()
    assert run_cli(["run", str(out / "sequence"), "--out", str(run), "--t0", "0.0", "--t1", "0.3",
                 "--method", "telea"]) == 0
    captured = capsys.readouterr()
    report = json.loads((run / "report.json").read_text())
    fill = json.loads((run / "fill" / "fill.json").read_text())
    paper = json.loads((out / "report.json").read_text())
    assert report["method"] == fill["method"] == "telea" and paper["method"] == "paper-idw"
    assert report["method_origin"] == fill["method_origin"] == "built-in"
    assert fill["segmentation"] is None and fill["regions"] is None
    np.testing.assert_array_equal(read_depth(run / "map" / "semidense_depth.exr"),
                                  read_depth(out / "map" / "semidense_depth.exr"))
    assert report["N1_in_frame"] == paper["N1_in_frame"]
    dense = read_depth(run / "fill" / "dense_depth.exr")
    assert report["N2"] == fill["N2"] == np.count_nonzero(dense) > paper["N2"]
    assert not cv2.imread(str(run / "fill" / "segments.png"), cv2.IMREAD_UNCHANGED).any()
    assert re.search(r"^fill: [\d,]+ pixels filled by telea in \d+\.\d s$", captured.err, re.M)
    assert re.search(r"filling method\s+telea \(built-in\)", captured.out)
    overview = cv2.imread(str(run / "overview.png"))
    assert overview.shape == cv2.imread(str(out / "overview.png")).shape
    panels, titles, _, _ = _overview_panels(run, report)
    assert titles[3] == "no segmentation (method telea; filled green)"
    filled = cv2.imread(str(run / "fill" / "filled_mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    green = panels[3][..., 1].astype(int) - panels[3][..., 2]
    assert (green[filled] > 0).all() and (green[~filled] == 0).all()
    assert run_cli(["show", str(run), "--out", str(tmp_path / "again.png")]) == 0
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "again.png")), overview)
