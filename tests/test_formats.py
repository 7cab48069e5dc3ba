"""The event format registry, Prophesee RAW (EVT 3.0 / 2.0) and AEDAT4: round trips between every
pair of formats, exact time over long spans (EVT3's 24-bit base wraps every 16.78 s), the
floor-to-microseconds rule, what faery, evlib and dv-processing write and read, bad input, and
``evfuse convert`` / ``simulate --format``."""

from __future__ import annotations

import itertools
import sys

import numpy as np
import pytest

from sim.eventio import convert_events, make_events, read_events
from sim.eventio._formats import (
    EXTRA_HINT,
    MissingExtraError,
    event_formats,
    format_for,
    format_named,
)
from tests.conftest import run_cli

W, H = 640, 480
FILES = {"txt": "e.txt", "h5": "e.h5", "aedat4": "e.aedat4", "evt3": "e3.raw", "evt2": "e2.raw"}


def _events(n: int = 20_000, span_us: int = 40_000_000, seed: int = 0,
            whole_us: bool = True) -> np.ndarray:
    """Random events over ``span_us`` (40 s: more than two EVT3 wraps), whole microseconds."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, span_us, n)) * 1000
    if not whole_us:
        t = t + rng.integers(0, 1000, n)
        t.sort()
    return make_events(t, rng.integers(0, W, n), rng.integers(0, H, n), rng.choice([-1, 1], n))


def _write(name: str, path, events: np.ndarray, chunk: int = 3_000) -> None:
    with format_named(name).open_writer(path, sensor_size=(W, H)) as writer:
        for begin in range(0, events.size, chunk):
            writer.write(events[begin:begin + chunk])


def test_the_registry_tells_formats_by_suffix_and_selector(tmp_path):
    assert format_for("a.raw").name == "evt3"
    assert format_for("a.raw", evt=2).name == "evt2"
    assert format_for("a.RAW", evt="3").name == "evt3"
    assert format_for("a.hdf5").name == "h5"
    assert {"txt", "h5", "aedat4", "evt3", "evt2"} <= {f.name for f in event_formats()}
    with pytest.raises(ValueError, match=r"a\.foo: unknown event file type '\.foo'; expected "
                                         r".*\.aedat4 \(AEDAT4\).*\.raw"):
        format_for("a.foo")
    with pytest.raises(ValueError, match=r"evt=2 does not apply to a \.aedat4 file"):
        format_for("a.aedat4", evt=2)
    with pytest.raises(ValueError, match=r"evt=4 is not a \.raw format; expected one of 3, 2"):
        format_for("a.raw", evt=4)


@pytest.mark.parametrize("name", ["evt3", "evt2", "aedat4"])
def test_a_40_s_stream_round_trips_exactly_through_each_format(tmp_path, name):
    events = _events()
    path = tmp_path / FILES[name]
    _write(name, path, events)
    back = read_events(path)
    assert np.array_equal(back, events)           # every EVT3 wrap (16.78 s) unwrapped
    assert not list(tmp_path.glob("*.partial"))


def test_a_gap_longer_than_the_evt3_time_base_round_trips(tmp_path):
    # two events 40 s apart: no time-high word between them would lose two whole wraps
    events = make_events([5_000, 40_000_005_000, 40_000_005_000], [1, 2, 3], [4, 5, 6],
                         [1, -1, 1])
    for name in ("evt3", "evt2"):
        path = tmp_path / FILES[name]
        _write(name, path, events)
        assert np.array_equal(read_events(path), events)


@pytest.mark.parametrize("name", ["evt3", "evt2", "aedat4"])
def test_times_are_floored_to_whole_microseconds(tmp_path, name):
    events = make_events([999, 1_000, 1_999, 2_500_001], [0, 1, 2, 3], [0, 0, 0, 0],
                         [1, 1, -1, -1])
    path = tmp_path / FILES[name]
    _write(name, path, events)
    assert read_events(path)["t"].tolist() == [0, 1_000, 1_000, 2_500_000]


def test_every_pair_of_formats_converts_exactly(tmp_path):
    events = _events(n=5_000)
    for src, dst in itertools.permutations(FILES, 2):
        source = tmp_path / f"src_{FILES[src]}"
        if not source.exists():
            _write(src, source, events)
        out = tmp_path / f"{src}_to_{FILES[dst]}"
        convert_events(source, out, W, H, dst_selectors=format_named(dst).selector)
        assert np.array_equal(read_events(out), events), (src, dst)


def test_a_time_out_of_order_in_a_file_is_named_with_its_index(tmp_path):
    path = tmp_path / "bad.raw"
    _write("evt3", path, make_events([0, 5_000], [1, 2], [1, 1], [1, 1]))
    data = bytearray(path.read_bytes())
    header = data.index(b"% end\n") + 6
    words = np.frombuffer(bytes(data[header:]), "<u2").copy()
    words = np.concatenate([words, [0x6000 | 3, 0x2000 | 7]]).astype("<u2")   # back to 3 us
    path.write_bytes(bytes(data[:header]) + words.tobytes())
    with pytest.raises(ValueError, match=r"bad\.raw: event 2: t = 3000 ns is before the "
                                         r"previous event's 5000 ns"):
        read_events(path)


def test_raw_without_a_header_or_with_a_foreign_one_is_refused(tmp_path):
    bare = tmp_path / "bare.raw"
    bare.write_bytes(np.array([0x8000, 0x2001], "<u2").tobytes())
    with pytest.raises(ValueError, match=r"bare\.raw: no '%' header; expected a Prophesee RAW "
                                         r"header naming EVT 3.0 or 2.0"):
        read_events(bare)
    foreign = tmp_path / "f.raw"
    foreign.write_bytes(b"% format EVT21;width=10;height=10\n% end\n" + b"\0" * 8)
    with pytest.raises(ValueError, match=r"f\.raw: '% format EVT21;width=10;height=10'"):
        read_events(foreign)
    odd = tmp_path / "odd.raw"
    _write("evt3", odd, _events(n=10))
    odd.write_bytes(odd.read_bytes() + b"\x01")
    with pytest.raises(ValueError, match=r"odd\.raw: \d+ bytes of EVT 3\.0 data is not a whole "
                                         r"number of 2-byte words"):
        read_events(odd)


def test_the_raw_header_is_the_one_metavision_reads(tmp_path):
    path = tmp_path / FILES["evt3"]
    _write("evt3", path, _events(n=10))
    head = path.read_bytes().split(b"% end\n")[0].decode()
    assert "% evt 3.0" in head and "% format EVT3;height=480;width=640" in head
    assert "% geometry 640x480" in head
    assert format_named("evt3").read_info(path)["sensor_size"] == (W, H)


def test_a_truncated_aedat4_is_refused_in_one_line(tmp_path):
    path = tmp_path / "e.aedat4"
    _write("aedat4", path, _events(n=50_000))
    cut = tmp_path / "cut.aedat4"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"cut\.aedat4: dv-processing cannot open it .*; "
                                         r"expected a whole AEDAT4 file"):
        read_events(cut)
    text = tmp_path / "text.aedat4"
    text.write_text("0.1 1 2 1\n")
    with pytest.raises(ValueError, match=r"text\.aedat4: does not begin with '#!AER-DAT4\.0'"):
        read_events(text)


def test_a_missing_optional_dependency_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "dv_processing", None)
    monkeypatch.delitem(sys.modules, "sim.eventio._aedat4", raising=False)
    with pytest.raises(MissingExtraError, match=r"the AEDAT4 format needs dv-processing, which "
                                                r"is not installed; expected it from "
                                                + EXTRA_HINT.replace("[", r"\[")
                                                .replace("]", r"\]")):
        format_named("aedat4").open_writer(tmp_path / "x.aedat4", sensor_size=(W, H))


# --- against the libraries of those ecosystems -------------------------------------------------

def test_faery_and_evlib_read_what_evfuse_writes_event_for_event(tmp_path):
    faery = pytest.importorskip("faery")
    evlib = pytest.importorskip("evlib")
    events = _events()
    for name in ("evt3", "evt2"):
        path = tmp_path / FILES[name]
        _write(name, path, events)
        theirs = faery.events_stream_from_file(path).to_array()
        assert np.array_equal(theirs["t"].astype(np.int64) * 1000, events["t"])
        assert np.array_equal(theirs["x"], events["x"]) and np.array_equal(theirs["y"],
                                                                            events["y"])
        assert np.array_equal(theirs["on"], events["p"] > 0)
        frame = evlib.load_events(str(path)).collect()
        assert np.array_equal(frame["t"].cast(int).to_numpy() * 1000, events["t"])
        assert np.array_equal(frame["x"].to_numpy(), events["x"])
        assert np.array_equal(frame["polarity"].to_numpy(), events["p"])


@pytest.mark.parametrize("version", ["evt3", "evt2"])
def test_evfuse_reads_what_faery_writes_exactly(tmp_path, version):
    faery = pytest.importorskip("faery")
    rng = np.random.default_rng(3)
    n = 30_000                    # dense (faery writes no time-high word inside a long gap)
    theirs = np.zeros(n, faery.EVENTS_DTYPE)
    theirs["t"] = np.sort(rng.integers(100, 30_000_000, n))
    theirs["x"], theirs["y"] = rng.integers(0, W, n), rng.integers(0, H, n)
    theirs["on"] = rng.integers(0, 2, n).astype(bool)
    path = tmp_path / "faery.raw"
    faery.events_stream_from_array(theirs, dimensions=(W, H)).to_file(path, version=version)
    ours = read_events(path)                     # faery's '% t0' is honoured
    assert np.array_equal(ours["t"], theirs["t"].astype(np.int64) * 1000)
    assert np.array_equal(ours["x"], theirs["x"]) and np.array_equal(ours["y"], theirs["y"])
    assert np.array_equal(ours["p"] > 0, theirs["on"])


def test_evt3_time_after_a_time_high_step_is_high_then_low_as_the_specification_says(tmp_path):
    """Prophesee's EVT 3.0 page: EVT_TIME_HIGH and EVT_TIME_LOW are the higher and lower 12 bits
    of the 24-bit time base. faery writes 4,200 us as TIME_HIGH 1, TIME_LOW 104 after TIME_LOW
    4,000: the time is 1 << 12 | 104 = 4,200 us. faery, evlib and evfuse read that;
    expelliarmus 1.1.12 also counts the time-low decrease as a step and reads 8,296 us."""
    faery = pytest.importorskip("faery")
    theirs = np.zeros(4, faery.EVENTS_DTYPE)
    theirs["t"] = [100, 4_000, 4_200, 9_000]
    theirs["x"], theirs["y"], theirs["on"] = [1, 2, 3, 4], 5, True
    path = tmp_path / "step.raw"
    faery.events_stream_from_array(theirs, dimensions=(W, H)).to_file(path, version="evt3",
                                                                      zero_t0=False)
    words = np.frombuffer(path.read_bytes().split(b"\n")[-1], "<u2")
    assert [hex(w) for w in words[5:8]] == ["0x2802", "0x8001", "0x6068"]   # the case
    assert (read_events(path)["t"] // 1000).tolist() == [100, 4_000, 4_200, 9_000]
    assert faery.events_stream_from_file(path).to_array()["t"].tolist() == [100, 4_000, 4_200,
                                                                           9_000]
    expelliarmus = pytest.importorskip("expelliarmus")
    wizard = expelliarmus.Wizard(encoding="evt3")
    wizard.set_file(str(path))
    assert wizard.read()["t"].tolist()[2] == 4_200 + 4_096     # its error, one step late


def test_dv_processing_reads_what_evfuse_writes_and_evfuse_reads_what_it_writes(tmp_path):
    dv = pytest.importorskip("dv_processing")
    events = _events(n=30_000)
    ours = tmp_path / "ours.aedat4"
    _write("aedat4", ours, events)
    recording = dv.io.MonoCameraRecording(str(ours))
    assert recording.getEventResolution() == (W, H)
    parts = []
    while (batch := recording.getNextEventBatch()) is not None:
        parts.append(batch.numpy())
    theirs = np.concatenate(parts)
    assert np.array_equal(theirs["timestamp"] * 1000, events["t"])
    assert np.array_equal(theirs["x"], events["x"]) and np.array_equal(theirs["y"], events["y"])
    assert np.array_equal(np.where(theirs["polarity"] > 0, 1, -1), events["p"])
    # what dv-processing writes itself (its own DAVIS layout, frames and IMU beside)
    path = tmp_path / "theirs.aedat4"
    writer = dv.io.MonoCameraWriter(str(path), dv.io.MonoCameraWriter.DAVISConfig("c", (W, H)))
    store = dv.EventStore()
    for t, x, y, p in zip((events["t"] // 1000).tolist(), events["x"].tolist(),
                          events["y"].tolist(), (events["p"] > 0).tolist(), strict=True):
        store.push_back(t, x, y, p)
    writer.writeEvents(store)
    writer.writeFrame(dv.Frame(1000, np.zeros((H, W), np.uint8)))
    del writer
    assert np.array_equal(read_events(path), events)


# --- the command line --------------------------------------------------------------------------

def test_evfuse_convert_takes_the_new_suffixes_and_evt_2(tmp_path, capsys):
    events = _events(n=2_000)
    src = tmp_path / "e.h5"
    _write("h5", src, events)
    assert run_cli(["convert", str(src), str(tmp_path / "e.raw"), "--evt", "2"],
                   [tmp_path / "e.h5"]) == 0
    assert (tmp_path / "e.raw").read_bytes().startswith(b"% evt 2.0\n")
    assert run_cli(["convert", str(tmp_path / "e.raw"), str(tmp_path / "e.aedat4")],
                   [tmp_path / "e.raw"]) == 0
    assert np.array_equal(read_events(tmp_path / "e.aedat4"), events)
    capsys.readouterr()
    assert run_cli(["convert", str(src), str(tmp_path / "e.foo")], [src]) == 2
    err = capsys.readouterr().err
    assert "e.foo: unknown event file type '.foo'" in err and err.count("\n") == 1
    assert not (tmp_path / "e.foo").exists() and not list(tmp_path.glob("*.partial"))


def simulated_formats(tmp_path, formats: tuple[str, ...]):
    """A moving poster's 0.3 s simulated into ``tmp_path / "seq"`` with ``formats``: the
    scene, the folder and its exact events (``events.h5``)."""
    from sim.scene import parse_scene
    from sim.simulate import simulate
    from tests.test_simulate import FRAMES, MOVING, OBJECTS, scene_text

    scene = parse_scene(scene_text(OBJECTS, trajectory=MOVING, duration=0.3, extra=FRAMES),
                        tmp_path / "s.toml")
    out = tmp_path / "seq"
    simulate(scene, out, progress=False, event_formats=formats)
    return scene, out, read_events(out / "events.h5")


def test_simulate_format_writes_aedat4_and_raw_beside_events_h5(tmp_path):
    from sim.simulate import simulate

    scene, out, exact = simulated_formats(tmp_path, ("h5", "aedat4", "evt3"))
    assert exact.size > 0
    floored = exact.copy()
    floored["t"] = exact["t"] // 1000 * 1000
    assert np.array_equal(read_events(out / "events.aedat4"), floored)
    assert np.array_equal(read_events(out / "events.raw"), floored)
    with pytest.raises(ValueError, match="would write one file twice"):
        simulate(scene, tmp_path / "two", progress=False, event_formats=("h5", "evt3", "evt2"))


# --- recordings given as one file --------------------------------------------------------------

def _small_sequence(folder):
    """A sequence folder of events, three frames and IMU samples (no poses)."""
    import cv2

    from sim.sequence import frame_name, write_index

    folder.mkdir()
    (folder / "calib.txt").write_text("200 200 32 24 0 0 0 0 0\n")
    rng = np.random.default_rng(5)
    names = [frame_name(i, "png") for i in range(3)]
    (folder / "images").mkdir()
    frames = [rng.integers(0, 256, (48, 64), np.uint8) for _ in names]
    for name, image in zip(names, frames, strict=True):
        cv2.imwrite(str(folder / name), image)
    write_index(folder / "images.txt", np.array([0.01, 0.02, 0.03]), names)
    imu = np.column_stack([np.arange(1, 6) * 0.005, rng.normal(0, 9, (5, 3)),
                           rng.normal(0, 1, (5, 3))])
    np.savetxt(folder / "imu.txt", imu, fmt="%.9f")
    (folder / "groundtruth.txt").write_text("0.0100005 0.1 -0.2 0.3 0 0 0.6 0.8\n"
                                            "0.0300009 0.2 -0.1 0.35 0 0.6 0 0.8\n")
    n = 500
    events = make_events(np.sort(rng.integers(0, 40_000, n)) * 1000, rng.integers(0, 64, n),
                         rng.integers(0, 48, n), rng.choice([-1, 1], n))
    with format_named("h5").open_writer(folder / "events.h5", sensor_size=(64, 48)) as writer:
        writer.write(events)
    return events, frames, imu


def test_a_sequence_as_one_aedat4_unpacks_to_its_events_frames_imu_and_poses(tmp_path, monkeypatch):
    pytest.importorskip("dv_processing")
    from sim.recording import recording_folder
    from sim.sequence import load_sequence

    monkeypatch.setenv("EVFUSE_CACHE", str(tmp_path / "cache"))
    events, frames, imu = _small_sequence(tmp_path / "seq")
    assert run_cli(["convert", str(tmp_path / "seq"), str(tmp_path / "seq.aedat4")]) == 0
    folder = recording_folder(tmp_path / "seq.aedat4", calib=tmp_path / "seq" / "calib.txt")
    assert folder.is_relative_to(tmp_path / "cache")            # never beside the input
    sequence = load_sequence(folder)
    assert (sequence.camera.width, sequence.camera.height) == (64, 48)
    assert np.array_equal(read_events(sequence.events_h5), events)
    assert np.allclose(sequence.image_times, [0.01, 0.02, 0.03], rtol=0, atol=1e-9)
    import cv2

    for path, image in zip(sequence.image_paths, frames, strict=True):
        assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), image)
    back = sequence.read_imu()
    assert np.array_equal(back[:, 0], imu[:, 0])
    # DV stores IMU as float32 g and deg/s: agreement to float32's relative precision
    assert np.allclose(back[:, 1:], imu[:, 1:], rtol=2e-7, atol=1e-6)
    # poses: DV's pose stream holds float32 and whole microseconds (floored)
    poses = np.loadtxt(sequence.groundtruth_path, ndmin=2)
    assert poses[:, 0].tolist() == [0.010000, 0.030000]
    assert np.allclose(poses[:, 1:], [[0.1, -0.2, 0.3, 0, 0, 0.6, 0.8],
                                      [0.2, -0.1, 0.35, 0, 0.6, 0, 0.8]], rtol=1e-7, atol=1e-8)
    assert recording_folder(tmp_path / "seq.aedat4",
                            calib=tmp_path / "seq" / "calib.txt") == folder     # cached


def test_a_raw_recording_without_calib_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("EVFUSE_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "e.raw"
    _write("evt3", path, _events(n=100))
    assert run_cli(["events", str(path), "--stats"], [path]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "e.raw: a Prophesee RAW EVT 3.0 file holds no intrinsics; expected --calib" in err
    assert not list((tmp_path / "cache" / "recordings").iterdir())       # nothing left
    (tmp_path / "seq").mkdir()
    assert run_cli(["events", str(tmp_path / "seq"), "--calib", str(path)], [path]) == 2
    assert "is a sequence folder" in capsys.readouterr().err



@pytest.mark.parametrize("command", [["map"], ["map-global"], ["run"], ["twin"]])
def test_every_command_that_reads_a_recording_opens_one_file(tmp_path, monkeypatch, capsys,
                                                            command):
    """map, map-global, run and twin go through the same opening of a one-file recording: a RAW
    without --calib is refused there, in one line, before any work."""
    monkeypatch.setenv("EVFUSE_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "e.raw"
    _write("evt3", path, _events(n=100))
    argv = [*command, str(path), "--out", str(tmp_path / "o")]
    if command == ["twin"]:
        argv += ["--depth", "1.0"]
    assert run_cli(argv, [path]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "holds no intrinsics; expected --calib" in err
    assert not (tmp_path / "o").exists()


def test_the_ecd_prefix_maps_identically_from_text_aedat4_and_raw(ecd_slider, tmp_path,
                                                                   monkeypatch):
    from sim.exr import read_depth

    monkeypatch.setenv("EVFUSE_CACHE", str(tmp_path / "cache"))
    calib, poses = str(ecd_slider / "calib.txt"), str(ecd_slider / "groundtruth.txt")
    assert run_cli(["convert", str(ecd_slider), str(tmp_path / "s.aedat4")], [ecd_slider]) == 0
    assert run_cli(["convert", str(ecd_slider / "events.txt"), str(tmp_path / "s.raw"),
                    "--sensor", "240x180"], [ecd_slider]) == 0
    assert run_cli(["map", str(ecd_slider), "--out", str(tmp_path / "txt"), "--quiet"],
                   [ecd_slider]) == 0
    assert run_cli(["map", str(tmp_path / "s.aedat4"), "--calib", calib, "--poses", poses,
                    "--out", str(tmp_path / "aedat4"), "--quiet"], [ecd_slider]) == 0
    # RAW holds no frames: the reference view is put at the frame the others snap to
    t_ref = json_value(tmp_path / "txt" / "map.json", "t_ref")
    assert run_cli(["map", str(tmp_path / "s.raw"), "--calib", calib, "--poses", poses,
                    "--ref-time", repr(t_ref), "--out", str(tmp_path / "raw"), "--quiet"],
                   [ecd_slider]) == 0
    maps = [read_depth(tmp_path / name / "semidense_depth.exr") for name in ("txt", "aedat4",
                                                                              "raw")]
    assert (maps[0] > 0).sum() > 1000
    assert np.array_equal(maps[0], maps[1]) and np.array_equal(maps[0], maps[2])


def json_value(path, key):
    import json

    return json.loads(path.read_text())[key]


@pytest.mark.parametrize("name", ["evt3", "evt2"])
def test_a_raw_writer_resumes_from_its_checkpoint(tmp_path, name):
    events = _events(n=6_000)
    path = tmp_path / FILES[name]
    writer = format_named(name).open_writer(path, sensor_size=(W, H))
    writer.write(events[:2_000])
    state = writer.checkpoint()
    writer.write(events[2_000:3_000])                  # lost with the interruption
    with pytest.raises(RuntimeError):
        with writer:
            raise RuntimeError("interrupted")
    assert not path.exists() and writer.partial.exists()
    with format_named(name).open_writer(path, sensor_size=(W, H), resume=state) as again:
        again.write(events[2_000:])
    assert np.array_equal(read_events(path), events)


def test_events_stats_reads_an_aedat4_recording_and_leaves_its_folder_untouched(tmp_path,
                                                                                monkeypatch,
                                                                                capsys):
    pytest.importorskip("dv_processing")
    monkeypatch.setenv("EVFUSE_CACHE", str(tmp_path / "cache"))
    events, _, _ = _small_sequence(tmp_path / "seq")
    recording = tmp_path / "rec" / "seq.aedat4"
    recording.parent.mkdir()
    assert run_cli(["convert", str(tmp_path / "seq"), str(recording)]) == 0
    capsys.readouterr()
    assert run_cli(["events", str(recording), "--stats", "--calib",
                    str(tmp_path / "seq" / "calib.txt")], [recording.parent]) == 0
    out = capsys.readouterr().out
    assert "(64x48)" in out and f"count                    {events.size}" in out
    assert sorted(p.name for p in recording.parent.iterdir()) == ["seq.aedat4"]
    raw = tmp_path / "rec" / "seq.raw"
    assert run_cli(["convert", str(tmp_path / "seq" / "events.h5"), str(raw)]) == 0
    capsys.readouterr()
    assert run_cli(["events", str(recording), "--stats", "--calib",
                    str(tmp_path / "seq" / "calib.txt"), "--compare", str(raw)],
                   [recording.parent]) == 0
    assert "B / A" in capsys.readouterr().out


def test_simulate_takes_format_more_than_once():
    from fusion.cli import build_parser

    args = build_parser().parse_args(["simulate", "slider_close", "--out", "x", "--format",
                                      "aedat4", "--format", "evt2"])
    assert args.format == ["aedat4", "evt2"]
