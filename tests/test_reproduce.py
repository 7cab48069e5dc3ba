"""evfuse reproduce on a tiny selection: the report's tables, the paper's numbers beside ours."""

from __future__ import annotations

import json

import pytest

from fusion.cli import main
from sim.noise import noise_preset

# The paper's Table 1 row for shapes_6dof, typed from its LaTeX source (Table "Density Evaluation
# Experiment", ../shared/paper/000_26ee4c18baf48d76.txt): window 2.0s-4.0s, N1 954, N2 2137,
# beta 0.0274. Not read back from fusion.experiments.reproduce.PAPER, which this checks.
PAPER_SHAPES_6DOF = {"t0": 2.0, "N1": "954", "N2": "2137", "beta": "0.0274"}


def test_reproduce_table_1_and_complex_on_one_scene_each(tmp_path, capsys):
    out, cache = tmp_path / "report", tmp_path / "cache"
    argv = ["reproduce", "--out", str(out), "--cache", str(cache), "--tables", "1,complex",
            "--scenes", "shapes_6dof,complex_slanted_plane", "--long-window", "0.15",
            "--quiet"]
    assert main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    rows = {r["scene"]: r for r in report["rows"]}
    assert set(rows) == {"shapes_6dof", "complex_slanted_plane"}
    # Both windows map and fill: a failed row fails the test (nothing below may skip it).
    assert {s: r.get("failed") for s, r in rows.items()} == {s: None for s in rows}
    text = (out / "report.md").read_text()
    assert "## Complex surfaces" in text and "## Table 2" not in text
    # without --views: no fused table, no trace of it in the report (as before it existed)
    assert "fused" not in text and "views" not in report["settings"]
    assert not any("fused" in r for r in report["rows"])
    assert "## DSI depth ranges" in text and "| shapes_6dof | 0.4-3 | scene file" in text
    # Table 1's row for shapes_6dof: ours on the paper's window start, the paper's own
    # N1 / N2 / beta in the "paper" columns (header: ... | beta | paper N1 | paper N2 |
    # paper beta | ...).
    assert "## Table 1" in text
    header = next(line for line in text.splitlines() if line.startswith("| scene | window (s) |"))
    columns = [c.strip() for c in header.strip("|").split("|")]
    shapes = next(line for line in text.splitlines() if line.startswith("| shapes_6dof | 2.00-"))
    cells = dict(zip(columns, (c.strip() for c in shapes.strip("|").split("|")), strict=True))
    assert rows["shapes_6dof"]["window_s"] == pytest.approx(
        [PAPER_SHAPES_6DOF["t0"], PAPER_SHAPES_6DOF["t0"] + 0.15])
    assert (cells["paper N1"], cells["paper N2"], cells["paper beta"]) == (
        PAPER_SHAPES_6DOF["N1"], PAPER_SHAPES_6DOF["N2"], PAPER_SHAPES_6DOF["beta"])
    idw = rows["shapes_6dof"]["fills"]["idw"]
    assert (cells["N1"], cells["N2"]) == (str(idw["N1"]), str(idw["N2"]))
    for row in rows.values():
        # Blind: the DSI's range is each scene file's declared working range.
        assert row["oracle"] is False
        assert row["depth_range_from"] == "scene file (declared working range)"
        for fill in row["fills"].values():
            assert fill["N2"] >= fill["N1_in_frame"] > 0 and 0 <= fill["beta"] < 1
            assert fill["N1"] >= fill["N1_in_frame"]
        assert (out / report["figures"][row["scene"]]).is_file()
    assert set(rows["complex_slanted_plane"]["fills"]) == {"idw", "gaussian", "exponential"}
    # A second run re-uses the cached simulations: no new folder, no sequence rewritten.
    def cached() -> dict[str, int]:
        return {p.parent.name: p.stat().st_mtime_ns for p in cache.glob("*/sequence.json")}

    before = cached()
    assert len(before) == 2
    assert main([*argv[:2], str(tmp_path / "again"), *argv[3:]]) == 0
    assert cached() == before
    again = json.loads((tmp_path / "again" / "report.json").read_text())
    assert [r["fills"]["idw"]["N2"] for r in again["rows"]] == [
        r["fills"]["idw"]["N2"] for r in report["rows"]]


def test_reproduce_runs_other_filling_methods_beside_the_paper_s(tmp_path, capsys):
    out = tmp_path / "report"
    argv = ["reproduce", "--out", str(out), "--cache", str(tmp_path / "cache"), "--tables",
            "complex", "--scenes", "complex_slanted_plane", "--long-window", "0.15",
            "--method", "nearest,plane", "--method", "plane{residual_rel=0.05}", "--param",
            "plane.min_points=8", "--quiet"]
    assert main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    row = report["rows"][0]
    assert set(row["methods"]) == {"nearest", "plane{min_points=8}",      # JSON keys sorted
                                   "plane{min_points=8,residual_rel=0.05}"}
    assert len(row["fills"]) == 3                                     # the paper's: unchanged
    assert row["methods"]["nearest"]["N2"] == 43200                  # nearest fills every pixel
    assert row["methods"]["plane{min_points=8}"]["N2"] <= 43200
    assert row["methods"]["plane{min_points=8,residual_rel=0.05}"]["method_params"] == {
        "min_points": 8, "residual_rel": 0.05}
    assert [m["params"] for m in report["settings"]["methods"]] == [
        {}, {"min_points": 8}, {"min_points": 8, "residual_rel": 0.05}]
    text = (out / "report.md").read_text()
    assert "## Other filling methods" in text
    assert "| complex_slanted_plane | 1.00-1.15 | paper-idw |" in text
    assert "| complex_slanted_plane | 1.00-1.15 | nearest |" in text
    assert "| complex_slanted_plane | 1.00-1.15 | plane{min_points=8,residual_rel=0.05} |" in text
    base = argv[:argv.index("--method")]
    assert main([*base, "--method", "no-such", "--quiet"]) == 2
    assert "unknown filling method 'no-such'" in capsys.readouterr().err
    for flags, message in (
            (["--param", "min_points=8"], "--param min_points=8: no --method given"),
            (["--method", "nearest,plane", "--param", "min_points=8"],
             "--param min_points=8: 2 methods given (nearest, plane), whose is it?")):
        assert main([*base, *flags, "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err


def test_reproduce_with_the_realistic_event_camera_records_it_and_caches_apart(tmp_path):
    out, cache = tmp_path / "report", tmp_path / "cache"
    argv = ["reproduce", "--out", str(out), "--cache", str(cache), "--tables", "1",
            "--scenes", "shapes_6dof", "--long-window", "0.1", "--quiet"]
    assert main([*argv, "--event-noise", "realistic"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["settings"]["event_noise"] == "realistic"
    assert "event noise: realistic" in (out / "report.md").read_text()
    folders = [p.name for p in cache.iterdir()]
    assert len(folders) == 1
    # cached apart: the folder's key is the realistic event camera's, not the ideal one's
    from fusion.experiments.reproduce import ReproduceParams, _jobs, _window_options
    from sim.simulate.window import window_key

    keys = {}
    for noise in ("realistic", "ideal"):
        params = ReproduceParams(tables=("1",), scenes=("shapes_6dof",), long_window=0.1,
                                 event_noise=noise)
        job = _jobs(params)[0]
        scene, options = _window_options(job, params)
        keys[noise] = window_key(scene, job["t0"], job["length"], **options)[:10]
    assert folders[0].endswith("_" + keys["realistic"]) and keys["ideal"] != keys["realistic"]
    sequence = json.loads((cache / folders[0] / "sequence.json").read_text())
    realistic = noise_preset("realistic")
    assert sequence["events"]["noise"]["refractory_period"] == realistic.refractory_period > 0
    assert sequence["events"]["noise"]["threshold_sigma"] == realistic.threshold_sigma > 0
    with pytest.raises(SystemExit) as refused:                 # argparse: one line, exit 2
        main([*argv, "--event-noise", "bogus"])
    assert refused.value.code == 2


def test_a_cached_window_is_not_taken_for_a_changed_scene(tmp_path):
    """The cache's folder names held the scene's name, window and cameras but not what the scene
    is: after a scene file changed (issue 21 changed lights and exposure limits), reproduce
    re-used windows simulated from the old one. The name now carries the window's key
    (:func:`sim.simulate.window.window_key`), which hashes the scene's files
    (:func:`sim.simulate.scene_files`: the scene file and every file it names)."""
    from types import SimpleNamespace

    from scenes import resolve_scene
    from sim.scene import load_scene
    from sim.simulate.window import scene_digest, window_key

    texture = tmp_path / "t.png"
    path = tmp_path / "s.toml"

    def tag(texture_bytes: bytes, light_lux: float) -> str:
        texture.write_bytes(texture_bytes)
        text = ('[[objects]]\ntype = "rectangle"\n'
                'material = { texture = { type = "image", path = "t.png" } }\n'
                f'[[lights]]\ntype = "directional"\nilluminance_lux = {light_lux}\n')
        path.write_text(text)
        return scene_digest(SimpleNamespace(source=path, text=text, base_dir=tmp_path))

    first = tag(b"one", 400)
    assert tag(b"one", 400) == first                        # the same files: the same folder
    assert tag(b"two", 400) != first                        # a texture changed
    assert tag(b"one", 4000) != first                       # the scene file changed
    builtin = load_scene(resolve_scene("slider_far"))
    assert scene_digest(builtin) == scene_digest(load_scene(resolve_scene("slider_far")))
    key = window_key(builtin, 1.0, 0.5)
    assert window_key(load_scene(resolve_scene("slider_far")), 1.0, 0.5) == key
    assert window_key(builtin, 1.0, 0.25) != key            # another window
    assert window_key(builtin, 1.0, 0.5, spp=4) != key      # another parameter


def test_reproduce_views_adds_the_fused_table_beside_the_one_view_one(tmp_path, capsys):
    out, cache = tmp_path / "report", tmp_path / "cache"
    assert main(["reproduce", "--out", str(out), "--cache", str(cache), "--tables", "1",
                 "--scenes", "shapes_6dof", "--long-window", "0.15", "--views", "3",
                 "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["settings"]["views"] == 3
    (row,) = report["rows"]
    fused, one = row["fused"], row["fills"]["idw"]
    assert fused["views"] == 3 and fused["N1_reference"] == one["N1"]
    assert fused["view_times_s"][0] == pytest.approx(row["t_ref"])
    assert len(fused["view_times_s"]) == 3 and fused["spacing_s"] == pytest.approx(0.0375)
    # the window was simulated over the span its neighbours need, the map is the window's
    assert row["window_s"] == pytest.approx([2.0, 2.15])
    (sequence,) = cache.glob("*/sequence.json")
    simulated = json.loads(sequence.read_text())
    # neighbours at +-0.0375 s (a quarter window), widened by half a spacing: 1.944-2.206 s
    assert simulated["start"] < 2.0 - 0.05 and simulated["start"] + simulated["duration"] > 2.2
    run = out / "runs" / "shapes_6dof_2.00"
    for name in ("fused/map/map.json", "fused/fill_idw/fill.json", "fused/views/00/map.json",
                 "fused/views/01/map.json", "fused/views/02/map.json"):
        assert (run / name).is_file(), name
    text = (out / "report.md").read_text()
    assert "## Table 1, fused: each map with 2 neighbouring views' (3 views)" in text
    line = next(r for r in text.splitlines() if r.startswith("| shapes_6dof | 2.00-2.15 | "
                                                             f"{fused['N1_reference']} / "))
    assert f"{fused['N1_reference']} / {fused['N1']} | {fused['N1_in_frame']} | " in line
    assert "evfuse reproduce --views 3" in text
    # the introduction does not claim every window was simulated over itself only
    assert "Every window is simulated over itself only but Table 1's fused ones" in text



def test_with_views_the_frozen_control_is_not_fused_and_keeps_the_moving_row_s_frames():
    """reproduce --views: Table 1's windows are simulated over their neighbours' span, the
    frozen control over its own window (it is not fused), started on the moving row's frame
    grid, so that both map at the same reference frame, for any window length."""
    from fusion.experiments.reproduce import _fuses, _simulated_span
    from fusion.globalmap.neighbours import FusedViews
    from scenes import resolve_scene
    from sim.scene import load_scene

    scene = load_scene(resolve_scene("dynamic_6dof"))
    period = 1.0 / scene.frames.rate
    for length, views in ((2.0, 5), (0.7, 3), (1.3, 5), (0.45, 9)):
        moving = {"scene": "dynamic_6dof", "table": "1", "t0": 6.2, "length": length}
        control = {**moving, "scene": "dynamic_6dof_frozen", "frozen_of": "dynamic_6dof"}
        assert _fuses(moving, views) and not _fuses(control, views)
        assert not _fuses(moving, 1) and not _fuses({**moving, "table": "2"}, views)
        start, span = _simulated_span(moving, scene, views)
        assert (start, start + span) == pytest.approx(FusedViews(views).span(
            6.2, 6.2 + length, scene.duration))
        c_start, c_span = _simulated_span(control, scene, views)
        assert c_start <= 6.2 < c_start + period and c_start + c_span == pytest.approx(
            6.2 + length)
        frames = (c_start - start) / period
        assert frames == pytest.approx(round(frames), abs=1e-6)
        assert _simulated_span(control, scene, 1) == (6.2, length)
