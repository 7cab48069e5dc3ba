"""The benchmark page (``benchmarks/report.py``) on a planted results folder: its tables hold the
planted numbers, its plots are images beside the page, and a file it does not know, a file it
expects but does not find, and a file it cannot parse are each said so on the page."""

from __future__ import annotations

import hashlib
import json
import re

import pytest
from PIL import Image

from benchmarks.report import main, write_report

COST_ROW = {"scene": "slider_close", "size": "240x180", "sampler": "pixel",
            "window_s": [1.0, 1.1], "wall_s": 2.29, "wall_per_sim_s": 22.9,
            "steady_per_sim_s": 5.9,
            "stages_s": {"setup": 0.268, "frames": 0.208, "event render": 0.275,
                         "emulate": 0.021, "event write": 0.027, "per-event depth": 0.030,
                         "motion truth": 0.027, "other": 1.431},
            "events": 129_250, "variant": "llvm_ad_rgb"}
COST_ROW["shares"] = {k: v / COST_ROW["wall_s"] for k, v in COST_ROW["stages_s"].items()}


def _agreement(count: int, reference: int, worst: float) -> dict:
    return {"reference_count": reference, "count": count, "count_error": count / reference - 1,
            "blocks": 180, "worst_block_error": worst, "worst_block": [3, 4],
            "worst_block_events": 1020, "matched": 0.98, "dt_median_us": 2.2,
            "dt_p95_us": 65.0, "dt_max_us": 900.0}


def _run(events: int, samples: int, seconds: float) -> dict:
    return {"events": events, "sampler": "pixel", "pixel_samples": samples, "edge_samples": 0,
            "event_render_s": seconds, "gain": 0.5}


CONVERGENCE_ROW = {
    "scene": "boxes_6dof", "window_s": [3.5, 3.52], "event_spp": 4, "spp": 16,
    "reference_spp": 256, "default": _run(37_902, 1_000_000, 0.61),
    "reference": _run(37_751, 1_100_000, 20.4), "agreement": _agreement(37_902, 37_751, 0.125),
    "frames": 1, "frame_psnr_db": 47.04, "pass": {"count": True, "blocks": False, "frames": True},
    "wall_s": 60.0}
CONVERGENCE_ROW["event_spp_sweep"] = [
    {"event_spp": 1, "run": _run(41_526, 900_000, 0.2),
     "agreement": _agreement(41_526, 37_751, 0.41), "pass": {"count": False, "blocks": False},
     "is_default": False},
    {"event_spp": 4, "run": CONVERGENCE_ROW["default"], "agreement": CONVERGENCE_ROW["agreement"],
     "pass": CONVERGENCE_ROW["pass"], "is_default": True},
    {"event_spp": 16, "run": _run(37_800, 1_050_000, 2.5),
     "agreement": _agreement(37_800, 37_751, 0.047), "pass": {"count": True, "blocks": True},
     "is_default": False}]

RENDER = {"scene": "slider_close", "frames": 30,
          "rows": [{"resolution": "240x180", "variant": "llvm_ad_rgb", "spp": 16,
                    "bare_ms": 13.5, "evfuse_ms": 13.986, "overhead": 0.036}]}


def _plant(folder, name: str, data) -> None:
    (folder / name).write_text(json.dumps(data, indent=2))


@pytest.fixture
def results(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    _plant(folder, "simulate_cost.json", [COST_ROW])
    _plant(folder, "convergence_quick.json", [CONVERGENCE_ROW])
    _plant(folder, "render.json", RENDER)
    _plant(folder, "mystery.json", {"alpha": 1, "beta": [2, 3]})
    (folder / "shader.json").write_text("{not json")
    _plant(folder, "host.json", [1, 2])                   # not bench_host.py's structure
    digest = hashlib.sha256((folder / "render.json").read_bytes()).hexdigest()
    _plant(folder, "provenance.json", {
        "render.json": {"command": "python -m benchmarks.bench_render",
                        "date": "2026-11-29T00:00:00Z", "wall_s": 71.0, "exit_status": 0,
                        "commit": "9f9a045",
                        "uncommitted_changes": False, "cores": 2, "machine": "x86_64",
                        "load_average_at_start": [3.5, 2.0, 1.0], "sha256": digest},
        "simulate_cost.json": {"command": "python -m benchmarks.bench_sampling", "date": "x",
                               "wall_s": 1.0, "exit_status": 0, "sha256": "0" * 64}})
    return folder


def _rows(page: str, first_cell: str) -> list[list[str]]:
    """The cells of every table row of the page that starts with ``first_cell``."""
    return [[c.strip() for c in line.strip("|").split("|")] for line in page.splitlines()
            if line.startswith(f"| {first_cell} |")]


def test_the_tables_hold_the_planted_numbers(results, tmp_path):
    page = write_report(results, tmp_path / "out").read_text()
    (cost,) = _rows(page, "slider_close")[:1]
    # 22.9 s a simulated second, 5.9 without the start, 129,250 events, 'other' 1.431 / 2.29 s.
    assert cost[:7] == ["slider_close", "240x180", "pixel", "1-1.1", "22.9", "5.9", "129,250"]
    assert cost[-1] == f"{100 * 1.431 / 2.29:.1f}" == "62.5"
    (default,) = [r for r in _rows(page, "boxes_6dof") if r[2] == "pixel"]
    # 37,902 / 37,751 - 1 = +0.4 %; worst block 12.5 % of 1,020 events in 180 blocks.
    assert default[3:6] == ["37,902 / 37,751", "+0.4 %", "12.5 % (1,020; 180)"]
    assert default[6] == "47.0 dB" and default[-1] == "PASS, FAIL, PASS"
    sweep = {r[2]: r for r in _rows(page, "boxes_6dof") if r[2] != "pixel"}
    assert sweep["1"][3:6] == ["41,526", "+10.0 %", "41.0 %"]        # 41,526 / 37,751 - 1
    assert sweep["4 (default)"][3] == "37,902"
    assert sweep["256 (reference)"][3] == "37,751"
    (render,) = _rows(page, "240x180")
    assert render[3:] == ["13.50", "13.99", "+3.6 %"]


def test_the_plots_are_images_beside_the_page_and_linked_relative_to_it(results, tmp_path):
    out = tmp_path / "out"
    page = write_report(results, out)
    links = re.findall(r"!\[[^\]]+\]\(([^)]+)\)", page.read_text())
    assert "img/bench-convergence_quick-events-vs-spp.png" in links
    assert "img/bench-simulate_cost-simulate-cost.png" in links
    assert "img/bench-render-render.png" in links
    for link in links:
        assert not link.startswith("/") and ".." not in link
        with Image.open(page.parent / link) as image:
            image.verify()
        with Image.open(page.parent / link) as image:
            assert image.format == "PNG" and image.size[0] == 800 and image.size[1] > 200


def test_unknown_missing_unreadable_files_and_provenance_are_said_so(results, tmp_path):
    page = write_report(results, tmp_path / "out").read_text()
    assert "- `mystery.json`: an object with keys `alpha`, `beta`." in page
    assert "No `events.json` in the results: `python -m benchmarks.bench_events` makes it." in page
    assert "`shader.json` could not be parsed" in page
    assert "`host.json` is not in the structure this page knows" in page
    assert "it holds a list of 2 rows." in page
    assert "provenance.json`:" not in page                  # the record is not a result
    # The record is shown while the file's hash matches it, and not once the file changed.
    assert ("Recorded 2026-11-29T00:00:00Z by `python -m benchmarks.bench_render`: 71 s wall on "
            "2 cores (x86_64), load average 3.5 at the start, commit `9f9a045`.") in page
    cost = page.split("## Cost of evfuse simulate")[1].split("##")[0]
    assert "no record of the run that wrote this file" in cost


def test_an_empty_or_absent_results_folder_gives_a_page_of_notes(tmp_path):
    page = write_report(tmp_path / "nothing", tmp_path / "out").read_text()
    assert page.count("!!! note \"Not recorded\"") >= 10
    assert "`python -m benchmarks.bench_sampling --quick` makes it" in page
    assert not list((tmp_path / "out" / "img").iterdir())


def test_the_command_line_takes_the_results_folder(results, tmp_path, capsys):
    page = main(["--out", str(tmp_path / "docs"), "--results", str(results)])
    assert page == tmp_path / "docs" / "benchmarks.md" and "129,250" in page.read_text()
    with pytest.raises(SystemExit):
        main(["--out", str(tmp_path / "docs"), "--results", str(results / "render.json")])
    assert "expected a folder of JSON files" in capsys.readouterr().err


def test_the_record_names_the_command_and_the_hash_of_each_file_it_changed(tmp_path):
    """``benchmarks.record`` runs the command, then records the files it wrote (and only
    those), which the page then shows as recorded."""
    from benchmarks import record

    folder = tmp_path / "results"
    folder.mkdir()
    _plant(folder, "render.json", RENDER)
    _plant(folder, "mystery.json", {"alpha": 1})                 # left alone by the command
    write = f"import sys; open(sys.argv[1], 'w').write({json.dumps(RENDER | {'frames': 31})!r})"
    assert record.main(["--results", str(folder), "--", "python", "-c", write,
                        str(folder / "render.json")]) == 0
    entries = json.loads((folder / "provenance.json").read_text())
    assert list(entries) == ["render.json"]
    entry = entries["render.json"]
    assert entry["command"].startswith("python -c import sys") and entry["exit_status"] == 0
    assert entry["sha256"] == hashlib.sha256((folder / "render.json").read_bytes()).hexdigest()
    page = write_report(folder, tmp_path / "out").read_text()
    assert "Recorded " in page and "Scene slider_close, 31 frames" in page
