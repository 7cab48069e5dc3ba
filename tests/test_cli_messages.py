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
    from sim.simulate._events import _choose_sampler
    from sim.validation import ParameterError

    code = run_cli(["simulate", "dynamic_6dof", "--out", str(tmp_path / "o"), "--sampler", "pixel",
                 "--duration", "0.05"])
    line = _one_line(capsys, code, "simulate")
    assert line == ("evfuse simulate: error: --sampler pixel: scene dynamic_6dof has moving "
                    "objects, and the per-pixel sampler needs a static scene; use --sampler frame")
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.partial").exists()
    scene = type("Scene", (), {"is_dynamic": False, "name": "s"})()
    with pytest.raises(ParameterError) as refused:
        _choose_sampler(scene, "scalar_rgb", "pixel")
    # the library names its parameter; the command line's flag replaces it
    assert str(refused.value).startswith("sampler pixel: the per-pixel sampler ")
    assert "--" not in str(refused.value)
    assert refused.value.rephrase({"sampler": "--sampler"}).startswith(
        "--sampler pixel: the per-pixel sampler traces batches of rays and needs a JIT variant")
    assert refused.value.rephrase({"sampler": "--sampler"}).endswith(
        "renders whole frames only (--sampler frame)")
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


# --- issue 21: messages that name the file, key or flag -----------------------------------------

def _line(capsys, code, command):
    """The one line of an exit-2 refusal, without its ``evfuse COMMAND: error: `` prefix."""
    return _one_line(capsys, code, command).removeprefix(f"evfuse {command}: error: ")


def test_simulate_of_a_sequence_folder_says_it_is_one(tmp_path, capsys):
    folder = _sequence(tmp_path / "seq")
    line = _line(capsys, run_cli(["simulate", str(folder), "--out", str(tmp_path / "o")]),
                 "simulate")
    assert line == (f"{folder} is a sequence folder, not a scene: a scene is a built-in name or a "
                    ".toml file; evfuse run, map, events and twin take a sequence folder")
    assert list(tmp_path.iterdir()) == [folder]


def test_a_forced_cuda_variant_without_a_device_names_the_variant_to_use(tmp_path, capsys,
                                                                       monkeypatch):
    import sim.variant as variant

    probed = []

    def probe(name, library):
        probed.append(name)
        return name != "cuda_ad_rgb"                   # no CUDA device here; LLVM works

    monkeypatch.setattr(variant, "_active", None)
    monkeypatch.setattr(variant, "_probe", probe)
    monkeypatch.setattr(variant, "_cuda_driver_present", lambda: True)
    monkeypatch.setattr(variant, "find_llvm_libraries",
                        lambda: [variant.LlvmLibrary("/usr/lib/libLLVM-19.so", 19)])
    monkeypatch.setenv("EVFUSE_VARIANT", "cuda_ad_rgb")
    out = tmp_path / "o"
    code = run_cli(["simulate", "slider_close", "--out", str(out), "--duration", "0.05"])
    assert _line(capsys, code, "simulate") == (
        "cuda_ad_rgb was asked for (from --variant or EVFUSE_VARIANT), but no CUDA device works "
        "here; use llvm_ad_rgb")
    assert probed[0] == "cuda_ad_rgb" and variant.active_variant() is None
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(variant, "_cuda_driver_present", lambda: False)   # no driver: no probe
    monkeypatch.setattr(variant, "_probe", lambda name, library: False)   # and no LLVM either
    with pytest.raises(ValueError, match="no CUDA device works here; use scalar_rgb$"):
        variant.use_variant("cuda_ad_rgb")


def test_resume_messages_name_flags_not_python_parameters(tmp_path, capsys):
    out = tmp_path / "o"
    line = _line(capsys, run_cli(["simulate", "slider_close", "--out", str(out), "--resume"]),
                 "simulate")
    assert line == (f"there is no interrupted run of {out} to resume ({out}.partial does not "
                    "exist); run without --resume to start one")
    out.mkdir()
    (out / "f").write_text("x")
    line = _line(capsys, run_cli(["simulate", "slider_close", "--out", str(out), "--resume"]),
                 "simulate")
    assert line == (f"output folder {out} is already complete; there is nothing to resume (add "
                    "--overwrite to continue an interrupted run that replaces it)")


@pytest.mark.parametrize("command", ["simulate", "run"])
def test_a_negative_seed_is_blamed_on_the_flag_not_the_scene_file(command, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        run_cli([command, "slider_close", "--out", str(tmp_path / "o"), "--seed", "-1"])
    assert _line(capsys, stop.value.code, command) == (
        "argument --seed: expected an integer in 0..4294967295, got '-1'")
    assert list(tmp_path.iterdir()) == []


def test_a_negative_seed_argument_is_not_blamed_on_the_file():
    from sim.scene import SceneError, parse_scene

    with pytest.raises(SceneError) as info:
        parse_scene(scene_text(WALL), "wall.toml", seed=-1)
    assert str(info.value) == ("seed -1 (given to replace the seed of wall.toml): expected an "
                               "integer in 0..4294967295 (2**32 - 1)")


@pytest.mark.parametrize("value, message", [
    ("-300", "expected a positive number, got -300"),
    ("0", "expected a positive number, got 0"),
    ("[1, -3, 2]", "expected a list of 3 numbers >= 0, got list [1, -3, 2] (item 1)"),
    ("[0, 0, 0]", "expected a positive number or a list of 3 numbers >= 0 (one per colour "
                  "channel), not all 0, got list [0, 0, 0]"),
])
def test_a_light_s_intensity_must_be_positive(value, message, tmp_path, capsys):
    scene = tmp_path / "lit.toml"
    light = f'[[lights]]\ntype = "point"\nposition = [0.0, 0.0, 0.0]\nintensity_cd = {value}\n'
    scene.write_text(scene_text(WALL, lights=light))
    line = _line(capsys, run_cli(["simulate", str(scene), "--out", str(tmp_path / "o")]),
                 "simulate")
    assert line == f"{scene}: [[lights]][0].intensity_cd: {message}"


def test_a_reversed_twin_window_is_called_reversed(tmp_path, capsys):
    folder = _sequence(tmp_path / "seq")
    code = run_cli(["twin", str(folder), "--out", str(tmp_path / "o"), "--depth", "1",
                 "--window", "0.8,0.2"])
    assert _line(capsys, code, "twin") == ("--window 0.8,0.2: expected T0 < T1 (the window's "
                                           "start before its end, in seconds)")


def test_fill_of_a_missing_folder_says_it_does_not_exist(tmp_path, capsys):
    missing = tmp_path / "nosuch"
    code = run_cli(["fill", str(missing), "--out", str(tmp_path / "o")])
    assert _line(capsys, code, "fill") == (f"map folder {missing} does not exist or is not a "
                                           "folder (write a map with evfuse map first)")


@pytest.mark.parametrize("scenes, tables, named", [
    ("nosuch", "1,2,3,complex", "nosuch"),
    ("shapes_6dof,slider_close,nosuch", "1", "slider_close,nosuch"),
])
def test_reproduce_names_a_scene_its_tables_lack(scenes, tables, named, tmp_path, capsys):
    from fusion.experiments.reproduce import COMPLEX, SLIDERS, TABLE1_SCENES

    out, cache = tmp_path / "report", tmp_path / "cache"
    code = run_cli(["reproduce", "--out", str(out), "--cache", str(cache), "--scenes", scenes,
                 "--tables", tables])
    offered = TABLE1_SCENES + (SLIDERS + COMPLEX if tables != "1" else ())
    assert _line(capsys, code, "reproduce") == (f"--scenes {named}: not among the scenes of "
                                                f"--tables {tables} ({', '.join(offered)})")
    assert list(tmp_path.iterdir()) == []


def test_a_closed_standard_output_ends_the_listing_quietly():
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(root)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))}
    child = subprocess.Popen([sys.executable, "-m", "fusion.cli", "methods", "--params"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=root)
    child.stdout.close()                 # the reader goes before the listing is written (| head)
    err = child.stderr.read().decode()
    assert child.wait(timeout=60) == 128 + signal.SIGPIPE and err == "", err


def test_version_comes_from_the_package_metadata_or_the_source_tree(capsys, monkeypatch):
    import tomllib
    from importlib import metadata
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    with (root / "pyproject.toml").open("rb") as handle:
        declared = tomllib.load(handle)["project"]["version"]
    try:
        installed = metadata.version("evfuse")
    except metadata.PackageNotFoundError:
        installed = f"{declared} (source tree {root}, not installed)"
    with pytest.raises(SystemExit) as info:
        run_cli(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out == f"evfuse {installed}\n"

    def not_installed(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", not_installed)
    with pytest.raises(SystemExit):
        run_cli(["--version"])
    assert capsys.readouterr().out == f"evfuse {declared} (source tree {root}, not installed)\n"


def test_opencv_s_own_warnings_stay_out_of_the_log(tmp_path, capfd):
    level = cv2.utils.logging.getLogLevel()
    try:
        assert run_cli(["scenes"]) == 0
        capfd.readouterr()
        assert cv2.imread(str(tmp_path / "missing.png")) is None
        assert capfd.readouterr().err == ""
    finally:
        cv2.utils.logging.setLogLevel(level)


def test_mitsuba_s_warnings_come_out_as_one_plain_line(capfd):
    from sim.variant import use_variant

    use_variant()
    import mitsuba as mi

    capfd.readouterr()
    mi.Log(mi.LogLevel.Warn, "a test warning\nover two lines")
    err = capfd.readouterr().err
    assert err.startswith("evfuse: Mitsuba warning: [") and len(err.splitlines()) == 1, err
    assert err.endswith("a test warning over two lines\n") and "\x1b" not in err, repr(err)


@pytest.fixture(scope="module")
def ecd_run(ecd_slider, tmp_path_factory):
    """``evfuse run`` on the real ECD slider prefix (map and fill, no rendering)."""
    out = tmp_path_factory.mktemp("ecd") / "run"
    assert run_cli(["run", str(ecd_slider), "--out", str(out), "--min-depth", "0.47",
                 "--max-depth", "2.4", "--quiet"]) == 0
    return out


def test_show_names_a_missing_or_unreadable_file_of_the_run(ecd_run, tmp_path, capfd):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(ecd_run, run)
    capfd.readouterr()
    mask = run / "fill" / "filled_mask.png"
    mask.unlink()
    line = _line(capfd, run_cli(["show", str(run), "--out", str(tmp_path / "o.png")]), "show")
    assert line.startswith(f"{mask} does not exist; evfuse show needs the files evfuse run "
                           "writes (fill/fill.json, "), line
    mask.write_text("not a PNG")
    line = _line(capfd, run_cli(["show", str(run), "--out", str(tmp_path / "o.png")]), "show")
    assert line == f"cannot read {mask}"


def test_events_stats_name_an_unreadable_frame(tmp_path, capsys):
    folder = _sequence(tmp_path / "seq")
    frame = folder / "images" / "frame_00000001.png"        # the first gives the sensor size
    frame.write_text("not a PNG")
    with (folder / "images.txt").open("a") as handle:
        handle.write("0.6 images/frame_00000001.png\n")
    line = _line(capsys, run_cli(["events", str(folder), "--stats"]), "events")
    assert line == f"{frame}: not a readable image"


def test_a_user_s_method_module_imports_from_the_current_folder(ecd_run, tmp_path, capsys,
                                                                 monkeypatch):
    import json
    import os
    import sys

    name = "evfuse_messages_test_fill"
    (tmp_path / f"{name}.py").write_text(
        "import numpy as np\n\n"
        "def fill(frame, sparse, camera, params):\n"
        "    return np.where(sparse > 0, sparse, 1.5).astype(np.float32)\n")
    monkeypatch.chdir(tmp_path)
    here = os.path.realpath(tmp_path)        # as the evfuse script runs: its bin/ first, no cwd
    monkeypatch.setattr(sys, "path", [p for p in sys.path
                                      if os.path.realpath(p or os.curdir) != here])
    try:
        code = run_cli(["fill", str(ecd_run / "map"), "--out", str(tmp_path / "fill"), "--method",
                     f"{name}:fill"])
        assert code == 0, capsys.readouterr().err
    finally:
        sys.modules.pop(name, None)
    assert json.loads((tmp_path / "fill" / "fill.json").read_text())["method"] == f"{name}:fill"
    capsys.readouterr()
    code = run_cli(["fill", str(ecd_run / "map"), "--out", str(tmp_path / "fill2"), "--method",
                 "evfuse_no_such_module:fill"])
    line = _line(capsys, code, "fill")
    assert line.endswith("cannot import module 'evfuse_no_such_module' (ModuleNotFoundError: No "
                         "module named 'evfuse_no_such_module'; looked in the current folder "
                         f"{tmp_path} and on PYTHONPATH)"), line


def test_parameter_error_names_parameters_in_either_terms():
    """A library error names its parameters once; the library's wording and the command line's
    flags both come from the same sentence, and a path's own braces are never taken for a
    parameter (issue 22: library errors speak in the library's terms, the CLI translates)."""
    from sim.validation import ParameterError

    path = ParameterError.literal("runs/{out}/a}b")
    error = ParameterError(f"folder {path} exists; choose another {{out}} or add {{overwrite}}",
                           out="output folder", overwrite="overwrite=True")
    assert str(error) == ("folder runs/{out}/a}b exists; choose another output folder or add "
                          "overwrite=True")
    assert error.rephrase({"out": "--out", "overwrite": "--overwrite"}) == (
        "folder runs/{out}/a}b exists; choose another --out or add --overwrite")
    assert error.rephrase({"out": "DST"}) == (
        "folder runs/{out}/a}b exists; choose another DST or add overwrite=True")



# --- issue 22: library refusals in the library's terms, the command line's line unchanged -------

def test_convert_to_h5_without_a_sensor_size_names_the_flag(tmp_path, capsys):
    """sim.eventio says ``pass width= and height=``; evfuse convert says where it looks for the
    size and names --sensor WxH, as before the library stopped naming the flag."""
    from sim.eventio import convert_events
    from sim.validation import ParameterError

    src, dst = tmp_path / "events.txt", tmp_path / "events.h5"
    with TextEventWriter(src) as writer:
        writer.write(make_events([0, 10], [1, 2], [3, 4], [1, -1]))
    with pytest.raises(ParameterError) as caught:
        convert_events(src, dst)
    assert str(caught.value) == (f"converting {src} to {dst}: an events.h5 needs the sensor "
                                 "size; expected width and height (pass width= and height=)")
    assert _line(capsys, run_cli(["convert", str(src), str(dst)]), "convert") == (
        f"converting {src} to {dst}: an events.h5 needs the sensor size; expected width and "
        "height (evfuse convert reads them from the sequence folder, or pass --sensor WxH)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["events.txt"]


def test_an_unknown_variant_is_refused_in_the_library_terms_and_named_as_a_flag(tmp_path, capsys,
                                                                               monkeypatch):
    from sim import variant
    from sim.validation import ParameterError

    with pytest.raises(ParameterError) as caught:
        variant._choose("cuda_rgb")
    assert str(caught.value) == ("unknown Mitsuba variant 'cuda_rgb' (from variant= or "
                                 "EVFUSE_VARIANT); expected one of cuda_ad_rgb, llvm_ad_rgb, "
                                 "scalar_rgb")
    monkeypatch.setattr(variant, "_active", None)     # as in a fresh process
    monkeypatch.setenv("EVFUSE_VARIANT", "cuda_rgb")
    out = tmp_path / "o"
    for argv in (["simulate", "slider_close", "--out", str(out), "--duration", "0.05"],
                 ["run", "slider_close", "--out", str(out), "--spp", "1"]):
        assert _line(capsys, run_cli(argv), argv[0]) == (
            "unknown Mitsuba variant 'cuda_rgb' (from --variant or EVFUSE_VARIANT); expected one "
            "of cuda_ad_rgb, llvm_ad_rgb, scalar_rgb")
    assert list(tmp_path.iterdir()) == []
