"""Messages that name the real cause and the user's own flag, key or file (issue 11, item 6), and
progress that does not flood a log (item 7): one line on standard error, exit status 2."""

from __future__ import annotations

import re

import cv2
import h5py
import numpy as np
import pytest

from fusion.cli import PLAUSIBLE_DEPTH_M
from sim.eventio import H5EventWriter, TextEventWriter, make_events
from tests.conftest import FAST, WALL, run_cli, scene_text

WIDTH, HEIGHT = 64, 48


def _sequence(folder, t0=0.1, t1=0.9, poses=(0.0, 1.0)):
    """A sequence folder by hand (no rendering): one frame, two poses, 200 events in [t0, t1] s,
    as events.h5 and events.txt."""
    folder.mkdir()
    (folder / "calib.txt").write_text("60 60 32 24 0 0 0 0 0\n")
    (folder / "images").mkdir()
    cv2.imwrite(str(folder / "images" / "frame_00000000.png"), np.full((HEIGHT, WIDTH), 128,
                                                                       np.uint8))
    (folder / "images.txt").write_text("0.5 images/frame_00000000.png\n")
    (folder / "groundtruth.txt").write_text("".join(f"{t} 0 0 0 0 0 0 1\n" for t in poses))
    rng = np.random.default_rng(1)
    t = np.sort(rng.integers(int(t0 * 1e9), int(t1 * 1e9), 200))
    events = make_events(t, rng.integers(0, WIDTH, 200), rng.integers(0, HEIGHT, 200),
                         rng.choice([-1, 1], 200))
    with H5EventWriter(folder / "events.h5", WIDTH, HEIGHT) as writer:
        writer.write(events)
    with TextEventWriter(folder / "events.txt") as writer:
        writer.write(events)
    return folder


def _in_nanoseconds(folder, keep_ms_to_idx):
    """Rewrite events/t in nanoseconds, as a user's converter that forgot DSEC's unit would."""
    (folder / "events.txt").unlink()
    with h5py.File(folder / "events.h5", "r+") as f:
        t = f["events/t"][:].astype(np.int64) * 1000 + f["events/t_ns_rem"][:]
        for name in ("events/t", "events/t_ns_rem", *(() if keep_ms_to_idx else ("ms_to_idx",))):
            del f[name]
        f["events/t"] = t


def _one_line(capsys, code, command):
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"evfuse {command}: error: "), err
    return lines[0]


# --- a. a folder without calib.txt -----------------------------------------------------------

def test_a_folder_without_calib_says_so_and_what_a_sequence_folder_needs(tmp_path, capsys):
    folder = _sequence(tmp_path / "seq")
    (folder / "calib.txt").unlink()
    line = _one_line(capsys, run_cli(["run", str(folder), "--out", str(tmp_path / "o")]), "run")
    assert f"{folder}: this folder lacks calib.txt" in line and "not a sequence folder" in line
    assert "no such scene file" not in line
    assert all(part in line for part in ("fx fy cx cy", "images.txt", "groundtruth.txt",
                                         "events.h5"))
    line = _one_line(capsys, run_cli(["map", str(folder), "--out", str(tmp_path / "o")]), "map")
    assert f"sequence folder {folder} has no calib.txt" in line and "groundtruth.txt" in line
    assert not (tmp_path / "o").exists()


# --- b. an event file given as SOURCE ---------------------------------------------------------

@pytest.mark.parametrize("name, kind", [("events.txt", "ECD text"), ("events.h5", "HDF5")])
def test_an_event_file_as_source_is_named_with_the_folder_to_give(name, kind, tmp_path, capsys):
    folder = _sequence(tmp_path / "seq")
    code = run_cli(["run", str(folder / name), "--out", str(tmp_path / "o")])
    line = _one_line(capsys, code, "run")
    assert f"{folder / name} is an event file ({kind}" in line and "not a scene" in line
    assert f"give the sequence folder holding it, {folder.resolve()}" in line
    assert "TOML" not in line


def test_an_event_file_outside_a_sequence_folder_says_what_is_missing(tmp_path, capsys):
    path = tmp_path / "events.txt"
    path.write_text("0.1 1 2 1\n0.2 3 4 0\n")
    line = _one_line(capsys, run_cli(["run", str(path), "--out", str(tmp_path / "o")]), "run")
    assert "is an event file" in line and f"{tmp_path.resolve()} has no calib.txt" in line


# --- c. depths in millimetres, and no .partial path in a message ------------------------------

@pytest.mark.parametrize("command", ["run", "map"])
def test_depth_bounds_in_millimetres_are_refused_up_front(command, tmp_path, capsys):
    folder = _sequence(tmp_path / "seq")
    out = tmp_path / "o"
    code = run_cli([command, str(folder), "--out", str(out), "--min-depth", "470", "--max-depth",
                 "2400", "--quiet"])
    line = _one_line(capsys, code, command)
    assert "depths are in metres: --min-depth 470 looks like millimetres (0.47 m?)" in line
    assert f"{PLAUSIBLE_DEPTH_M:g} m" in line
    code = run_cli([command, str(folder), "--out", str(out), "--max-depth", "2400", "--quiet"])
    assert "--max-depth 2400 looks like millimetres" in _one_line(capsys, code, command)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]


def test_a_run_error_never_names_the_deleted_partial_folder(tmp_path, capsys, monkeypatch):
    import fusion.pipeline

    def failing(source, folder, *args):
        raise ValueError(f"{folder / 'frame.png'}: no map point lands in the frame")

    monkeypatch.setattr(fusion.pipeline, "_simulate_window", failing)
    out = tmp_path / "run"
    line = _one_line(capsys, run_cli(["run", "slider_close", "--out", str(out), "--quiet"]), "run")
    assert ".partial" not in line and f"{out}/sequence/frame.png: no map point" in line
    assert list(tmp_path.iterdir()) == []              # the .partial folder is gone indeed


# --- d. events.h5 in nanoseconds; the window as used ------------------------------------------

@pytest.mark.parametrize("command", ["run", "map", "events"])
@pytest.mark.parametrize("keep_ms_to_idx", [True, False])
def test_an_events_h5_in_nanoseconds_is_named(command, keep_ms_to_idx, tmp_path, capsys):
    folder = _sequence(tmp_path / "seq", t0=0.1, t1=0.9, poses=(0.0, 1.0))
    _in_nanoseconds(folder, keep_ms_to_idx)
    argv = [command, str(folder)] + ([] if command == "events" else
                                     ["--out", str(tmp_path / "o"), "--min-depth", "0.5",
                                      "--max-depth", "2", "--quiet"])
    if command == "events":
        argv.append("--stats")
    line = _one_line(capsys, run_cli(argv), command)
    against = "of ms_to_idx" if keep_ms_to_idx else "against 0-1 s of poses"
    assert f"{folder / 'events.h5'}: events/t looks like nanoseconds" in line, line
    assert against in line and "DSEC layout stores microseconds" in line
    assert "None" not in line


def test_a_default_window_is_printed_as_used_never_as_none(tmp_path, capsys):
    folder = _sequence(tmp_path / "seq", t0=5.0, t1=6.0, poses=(0.0, 1.0))   # same unit, later
    code = run_cli(["run", str(folder), "--out", str(tmp_path / "o"), "--min-depth", "0.5",
                 "--max-depth", "2", "--quiet"])
    line = _one_line(capsys, code, "run")
    assert "None" not in line and "do not overlap (events [5.0" in line
    assert "poses [0.000000, 1.000000] s" in line and "nanoseconds" not in line


# --- f. flags named as typed ------------------------------------------------------------------

@pytest.mark.parametrize("flags, message", [
    (["--lambda", "2"], "--lambda 2: expected a fraction of the contrast threshold in (0, 1]"),
    (["--contrast", "0"], "--contrast 0: expected a contrast threshold > 0"),
    (["--min-rate", "1e5"], "--min-rate 100000 and --max-rate 20000: expected 0 < --min-rate"),
])
def test_simulate_flags_are_named_as_typed(flags, message, tmp_path, capsys):
    code = run_cli(["simulate", "slider_close", "--out", str(tmp_path / "o"), *flags])
    line = _one_line(capsys, code, "simulate")
    assert message in line and "Params" not in line


def test_the_per_pixel_sampler_is_refused_where_its_premise_fails(tmp_path, capsys):
    from sim.simulate import _choose_sampler

    code = run_cli(["simulate", "dynamic_6dof", "--out", str(tmp_path / "o"), "--sampler", "pixel",
                 "--duration", "0.05"])
    line = _one_line(capsys, code, "simulate")
    assert "dynamic_6dof has moving objects" in line and "--sampler frame" in line
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.partial").exists()
    scene = type("Scene", (), {"is_dynamic": False, "name": "s"})()
    with pytest.raises(ValueError, match=r"^--sampler pixel: .* needs a JIT variant"):
        _choose_sampler(scene, "scalar_rgb", "pixel")
    assert _choose_sampler(scene, "scalar_rgb", None) == ("frame", "scalar_rgb cannot trace "
                                                          "per-pixel batches")
    assert _choose_sampler(scene, "llvm_ad_rgb", None) == ("pixel", "static scene")
    moving = type("Scene", (), {"is_dynamic": True, "name": "d"})()
    assert _choose_sampler(moving, "llvm_ad_rgb", None)[0] == "frame"


# --- item 7: progress on a terminal only ------------------------------------------------------

def test_a_short_run_logs_one_line_per_stage_and_no_carriage_return(tmp_path, capsys):
    scene = tmp_path / "wall.toml"
    extra = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n"
    scene.write_text(scene_text(WALL, trajectory=FAST, duration=0.2, extra=extra))
    assert run_cli(["run", str(scene), "--out", str(tmp_path / "run"), "--spp", "1"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.strip().splitlines()
    for start in ("simulate test: 4 frames in ", "events test: 0.200 s simulated, ",
                  "map: ", "fill: "):
        assert sum(line.startswith(start) for line in lines) == 1, (start, err)
    events = next(line for line in lines if line.startswith("events test: "))
    assert " events, per-pixel sampler (static scene): " in events, events
    assert " frames, " in events and " pixel samples in " in events
    assert re.search(r"^map: [\d,]+ events in \d+\.\d s$", err, re.M), err
    assert re.search(r"^fill: \d+ regions filled in \d+\.\d s$", err, re.M), err
    assert run_cli(["simulate", str(scene), "--out", str(tmp_path / "quiet"), "--spp", "1",
                 "--event-format", "h5", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "simulate test" not in err and "events test" not in err and "\r" not in err


def test_map_logs_one_line_and_quiet_silences_it(ecd_slider, tmp_path, capsys):
    argv = ["map", str(ecd_slider), "--min-depth", "0.47", "--max-depth", "2.4"]
    assert run_cli([*argv, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and err.startswith("map: 50,000 events in "), err
    assert len(err.strip().splitlines()) == 1
    assert run_cli([*argv, "--out", str(tmp_path / "b"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""


def test_the_hand_made_sequence_is_a_valid_one(tmp_path):
    """The messages above are not artefacts of a broken fixture: it reads back as written."""
    from sim.eventio import read_events
    from sim.sequence import load_sequence

    sequence = load_sequence(_sequence(tmp_path / "seq"))
    assert (sequence.camera.width, sequence.camera.height) == (WIDTH, HEIGHT)
    events = read_events(sequence.events_h5, WIDTH, HEIGHT)
    assert len(events) == 200 and 0.1e9 <= events["t"][0] and events["t"][-1] < 0.9e9


@pytest.mark.parametrize("command", ["simulate poster_6dof --out {out} --no-events",
                                     "reproduce --out {out} --tables 1"])
def test_an_unknown_frame_sensor_is_refused_naming_the_flag(tmp_path, capsys, command):
    argv = command.format(out=tmp_path / "out").split() + ["--frame-sensor", "davis"]
    assert run_cli(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("--frame-sensor 'davis': expected one of ideal, davis240c_aps, "
                        "machine_vision") and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()
