"""Data safety (issue 21): no command deletes, replaces or writes into what it reads; --overwrite
replaces only a folder evfuse wrote (its .evfuse marker), atomically; refused or failed
commands leave nothing behind; an interrupted run resumes."""

from __future__ import annotations

import json
import shutil

import pytest

from sim.output import MARKER
from tests.conftest import FAST, WALL, run_cli, scene_text, tree_hashes

MAP = ["--min-depth", "0.5", "--max-depth", "3", "--planes", "30", "--quiet"]
"""Map flags that work on the conftest plane sequence (64x48, wall at 1 m)."""


@pytest.fixture
def sequence(plane_sequence, tmp_path):
    """A private copy of the plane sequence (a refusal that failed would destroy it)."""
    return shutil.copytree(plane_sequence, tmp_path / "sim1")


def _refused(capsys, code: int, command: str, *expected: str) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"evfuse {command}: error: "), err
    for text in expected:
        assert text in lines[0], lines[0]
    assert "=True" not in lines[0] and "=False" not in lines[0], lines[0]    # flags, not Python
    return lines[0]


def _listing(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# --- the three deletions of the issue --------------------------------------------------------

def test_map_into_its_own_sequence_folder_is_refused(sequence, capsys):
    code = run_cli(["map", str(sequence), "--out", str(sequence), "--overwrite", *MAP])
    _refused(capsys, code, "map", "is the input", "choose another --out")


def test_map_into_the_folder_that_holds_the_recording_is_refused(sequence, tmp_path, capsys):
    parent = tmp_path / "parent"
    parent.mkdir()
    rec = shutil.move(sequence, parent / "rec")
    before = tree_hashes(parent)
    code = run_cli(["map", str(rec), "--out", str(parent), "--overwrite", *MAP])
    _refused(capsys, code, "map", "contains the input")
    assert tree_hashes(parent) == before


def test_simulate_into_the_scene_files_folder_is_refused(tmp_path, capsys):
    scn = tmp_path / "scn"
    scn.mkdir()
    (scn / "myscene.toml").write_text(scene_text(WALL, duration=0.2))
    (scn / "notes.txt").write_text("my notes")
    before = tree_hashes(scn)
    code = run_cli(["simulate", str(scn / "myscene.toml"), "--out", str(scn), "--overwrite",
                    "--no-events", "--no-motion-truth", "--spp", "1", "--quiet"])
    _refused(capsys, code, "simulate", "contains the input")
    assert tree_hashes(scn) == before


def test_a_texture_a_scene_names_is_an_input_too(tmp_path, capsys):
    import cv2
    import numpy as np

    assets = tmp_path / "assets"
    assets.mkdir()
    cv2.imwrite(str(assets / "brick.png"), np.full((8, 8), 128, np.uint8))
    wall = WALL.replace('{ type = "shapes", resolution = 256, count = 30, min_size = 10, '
                        'max_size = 40 }', '{ type = "image", path = "assets/brick.png" }')
    (tmp_path / "s.toml").write_text(scene_text(wall, duration=0.2))
    code = run_cli(["simulate", str(tmp_path / "s.toml"), "--out", str(assets), "--overwrite",
                    "--no-events", "--no-motion-truth", "--spp", "1", "--quiet"],
                   inputs=[tmp_path / "s.toml", assets])
    _refused(capsys, code, "simulate", "contains the input", "brick.png")


# --- links, foreign folders, nested outputs ---------------------------------------------------

def test_an_out_reached_through_a_link_into_the_input_is_refused(sequence, tmp_path, capsys):
    link = tmp_path / "link"
    link.symlink_to(sequence, target_is_directory=True)
    code = run_cli(["map", str(sequence), "--out", str(link / "map"), *MAP])
    _refused(capsys, code, "map", "lies inside the input")


def test_overwrite_refuses_a_folder_evfuse_did_not_write(sequence, tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    code = run_cli(["map", str(sequence), "--out", str(mine), "--overwrite", *MAP],
                   inputs=[sequence, mine])
    _refused(capsys, code, "map", "not written by evfuse", "delete it yourself", "--out")
    assert _listing(tmp_path) == ["mine", "sim1"]                  # no .partial either


def test_an_existing_folder_without_overwrite_says_which_flag(sequence, tmp_path, capsys):
    out = tmp_path / "m"
    out.mkdir()
    (out / "x").write_text("x")
    code = run_cli(["map", str(sequence), "--out", str(out), *MAP], inputs=[sequence, out])
    _refused(capsys, code, "map", "exists and is not empty", "--overwrite", "another --out")


def test_overwrite_replaces_an_evfuse_folder_atomically(sequence, tmp_path, monkeypatch,
                                                        capsys):
    out = tmp_path / "m"
    assert run_cli(["map", str(sequence), "--out", str(out), *MAP]) == 0
    marker = json.loads((out / MARKER).read_text())
    assert marker["written_by"] == "evfuse" and marker["command"] == "evfuse map"
    assert marker["inputs"] == [str(sequence.resolve())]
    written = tree_hashes(out)
    # Interrupted while it writes the new map: the old one stays whole, nothing else is left.
    import fusion.map.mapping

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(fusion.map.mapping, "write_ply", interrupted)
    assert run_cli(["map", str(sequence), "--out", str(out), "--overwrite", *MAP]) == 130
    assert tree_hashes(out) == written
    assert _listing(tmp_path) == ["m", "sim1"]
    monkeypatch.undo()
    assert run_cli(["map", str(sequence), "--out", str(out), "--overwrite", *MAP]) == 0
    assert (out / "map.json").is_file() and (out / MARKER).is_file()
    assert _listing(tmp_path) == ["m", "sim1"]
    capsys.readouterr()
    # Nested outputs: beside the map is fine, inside the map (the fill's input) is not, nor
    # inside the sequence folder its map.json names.
    assert run_cli(["map", str(sequence), "--out", str(tmp_path / "m2"), *MAP]) == 0
    _refused(capsys, run_cli(["fill", str(out), "--out", str(out / "dense")]), "fill",
             "lies inside the input")
    _refused(capsys, run_cli(["fill", str(out), "--out", str(sequence / "dense")],
                             inputs=[out, sequence]), "fill", "lies inside the input")
    assert run_cli(["fill", str(out), "--out", str(tmp_path / "dense")],
                   inputs=[out, sequence]) == 0


# --- never write into an input ----------------------------------------------------------------

def test_events_stats_leaves_the_recording_untouched(sequence, tmp_path, capsys):
    assert run_cli(["events", str(sequence), "--stats"]) == 0
    assert "--out" in capsys.readouterr().out
    code = run_cli(["events", str(sequence), "--stats", "--out", str(sequence / "f.png")])
    _refused(capsys, code, "events", "lies inside the input")
    assert run_cli(["events", str(sequence), "--stats", "--out", str(tmp_path / "f.png")]) == 0
    assert (tmp_path / "f.png").is_file()


# --- leftovers ---------------------------------------------------------------------------------

def test_refused_bench_and_reproduce_leave_no_cache(tmp_path, capsys):
    out = tmp_path / "bench"
    code = run_cli(["bench", "--family", "staircase", "--input", "nosuch", "--out", str(out),
                    "--quiet"])
    _refused(capsys, code, "bench", "--input")
    code = run_cli(["reproduce", "--tables", "1", "--scenes", "nosuch", "--out",
                    str(tmp_path / "repro"), "--quiet"])
    assert code == 2, capsys.readouterr().err
    assert _listing(tmp_path) == []


def test_bench_refuses_an_out_that_holds_its_cache(tmp_path, capsys):
    code = run_cli(["bench", "--scenes", "complex_cylinder", "--out", str(tmp_path), "--cache",
                    str(tmp_path / "cache"), "--quiet"])
    _refused(capsys, code, "bench", "contains the input")
    assert _listing(tmp_path) == []


# --- an interrupted run resumes ---------------------------------------------------------------

def test_an_interrupted_run_resumes_without_simulating_again(tmp_path, monkeypatch, capsys):
    import importlib

    import fusion.pipeline

    simulate_module = importlib.import_module("sim.simulate")   # sim.simulate is the function

    scene = tmp_path / "wall.toml"
    extra = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n"
    scene.write_text(scene_text(WALL, trajectory=FAST, duration=0.2, extra=extra))
    out = tmp_path / "run"
    argv = ["run", str(scene), "--out", str(out), "--spp", "1", *MAP]
    simulations = []
    real_simulate, real_map = simulate_module.simulate, fusion.pipeline.map_window

    def counted(*args, **kwargs):
        simulations.append(kwargs.get("resume"))
        return real_simulate(*args, **kwargs)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(simulate_module, "simulate", counted)
    monkeypatch.setattr(fusion.pipeline, "map_window", interrupted)
    assert run_cli(argv) == 130
    assert "--resume" in capsys.readouterr().err
    assert not out.exists() and (tmp_path / "run.partial" / "sequence" / MARKER).is_file()
    monkeypatch.setattr(fusion.pipeline, "map_window", real_map)
    _refused(capsys, run_cli([*argv, "--resume", "--planes", "31"]), "run",
             "params.planes")                                    # other parameters: refused
    assert run_cli([*argv, "--resume"]) == 0
    assert simulations == [False]                     # the simulation was re-used
    assert (out / "report.json").is_file() and (out / MARKER).is_file()
    assert _listing(tmp_path) == ["run", "wall.toml"]
    assert not (out / ".run.json").exists()
    # show reads the run; it writes only where --out says, never into the run folder
    before = tree_hashes(out)
    assert run_cli(["show", str(out), "--out", str(tmp_path / "o.png")]) == 0
    _refused(capsys, run_cli(["show", str(out), "--out", str(out / "o.png")]), "show",
             "lies inside the input")
    assert tree_hashes(out) == before


def test_a_run_interrupted_in_its_simulation_resumes_from_the_checkpoint(tmp_path,
                                                                          monkeypatch, capsys):
    import importlib

    from sim.frame_shader import FrameShader
    from tests.test_resume import _assert_same_sequence

    simulate_module = importlib.import_module("sim.simulate")
    scene = tmp_path / "wall.toml"
    extra = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n"
    scene.write_text(scene_text(WALL, trajectory=FAST, duration=0.2, extra=extra))
    argv = ["run", str(scene), "--spp", "1", *MAP]
    assert run_cli([*argv, "--out", str(tmp_path / "whole")]) == 0
    real_exposure, renders, resumed = FrameShader.exposure, [], []   # a static scene's frames

    def third_frame_interrupts(shader, *args, **kwargs):
        renders.append(1)
        if len(renders) == 3:
            raise KeyboardInterrupt
        return real_exposure(shader, *args, **kwargs)

    real_simulate = simulate_module.simulate

    def recorded(*args, **kwargs):
        resumed.append(kwargs.get("resume"))
        return real_simulate(*args, **kwargs)

    monkeypatch.setattr(FrameShader, "exposure", third_frame_interrupts)
    monkeypatch.setattr(simulate_module, "simulate", recorded)
    out = tmp_path / "run"
    assert run_cli([*argv, "--out", str(out)]) == 130
    assert "--resume" in capsys.readouterr().err
    checkpoint = tmp_path / "run.partial" / "sequence.partial" / ".checkpoint"
    assert (checkpoint / "checkpoint.json").is_file()
    assert run_cli([*argv, "--out", str(out), "--resume"]) == 0
    assert resumed == [False, True]                   # the simulation went on from there
    _assert_same_sequence(tmp_path / "whole" / "sequence", out / "sequence")
    whole, again = (json.loads((f / "report.json").read_text()) for f in (tmp_path / "whole", out))
    assert again["N1"] == whole["N1"] and again["N2"] == whole["N2"]
    assert _listing(tmp_path) == ["run", "wall.toml", "whole"]
    # every folder evfuse wrote is marked, nested ones too: `make demo`'s --overwrite replaces it
    assert all((out / sub / MARKER).is_file() for sub in ("", "sequence", "map", "fill"))


def test_a_failed_convert_leaves_no_partial_file_and_never_writes_over_its_source(tmp_path,
                                                                                   capsys):
    rows = "".join(f"0.{k:09d} {k % 60} {k % 40} {k % 2}\n" for k in range(1, 200))
    src = tmp_path / "events.txt"
    src.write_text(rows + "0.5 3 three 1\n")                    # malformed at the end
    _refused(capsys, run_cli(["convert", str(src), str(tmp_path / "out.txt")]), "convert",
             "events.txt:200")
    assert _listing(tmp_path) == ["events.txt"]
    _refused(capsys, run_cli(["convert", str(src), str(src), "--overwrite"]), "convert",
             "is the input", "choose another DST")


def test_a_nested_output_s_marker_names_its_sibling_input_as_it_will_be(tmp_path):
    """`run` writes map/ from sequence/ inside `<out>.partial`: its marker recorded
    `<out>.partial/sequence`, a path gone once the run is renamed into place. An input inside the
    same unfinished output is recorded relative to the marker's folder; any other by its real
    path."""
    import json

    from sim.output import MARKER, write_marker

    outer = tmp_path / "run.partial"
    (outer / "sequence").mkdir(parents=True)
    (outer / "map.partial").mkdir()
    other = tmp_path / "scene.toml"
    other.write_text("")
    write_marker(outer / "map.partial", "evfuse map", [outer / "sequence", other])
    (outer / "map.partial").rename(outer / "map")
    outer.rename(tmp_path / "run")
    marker = json.loads((tmp_path / "run" / "map" / MARKER).read_text())
    assert marker["inputs"] == ["../sequence", str(other.resolve())]
    assert (tmp_path / "run" / "map" / marker["inputs"][0]).is_dir()
