"""sim.eventio: events in memory, ECD text and DSEC HDF5 files, streaming, windows, statistics."""

from __future__ import annotations

import os
import re
import time

import h5py
import numpy as np
import pytest

from sim.eventio import (
    EVENT_DTYPE,
    H5EventWriter,
    TextEventWriter,
    check_events,
    convert_events,
    iter_event_chunks,
    make_events,
    read_events,
    read_window,
)
from sim.statistics import event_frame, event_stats

BIG_T = 1468941032255198860  # ns: Unix time with a sub-microsecond part (1468941032.255198860 s)


def random_events(n: int, seed: int, t_max: int = 3 * 10**9, width: int = 240,
                  height: int = 180, t_start: int = 0) -> np.ndarray:
    """Sorted random events with duplicate times, sub-microsecond parts and empty milliseconds."""
    rng = np.random.default_rng(seed)
    t = np.sort(t_start + rng.integers(0, t_max, n))
    t[n // 3: n // 3 + 5] = t[n // 3]                      # equal times are allowed
    return make_events(t, rng.integers(0, width, n), rng.integers(0, height, n),
                       rng.choice([-1, 1], n))


def write_text(path, events):
    with TextEventWriter(path) as writer:
        writer.write(events)


def write_h5(path, events, width=240, height=180, **kwargs):
    with H5EventWriter(path, width, height, **kwargs) as writer:
        writer.write(events)


# --- events in memory ------------------------------------------------------------------------

def test_make_events_builds_the_conventional_dtype():
    events = make_events([5, 7], [1, 2], [3, 4], [1, -1])
    assert events.dtype == np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    assert events.dtype == EVENT_DTYPE
    assert events["t"].tolist() == [5, 7] and events["p"].tolist() == [1, -1]
    assert events["x"].tolist() == [1, 2] and events["y"].tolist() == [3, 4]


@pytest.mark.parametrize(("args", "message"), [
    (([1, 2], [0, 0], [0, 0], [1, 0]), r"p\[1\] = 0; expected \+1 \(ON\) or -1 \(OFF\)"),
    (([1.5], [0], [0], [1]), r"t must hold integer nanoseconds"),
    (([1], [70000], [0], [1]), r"x\[0\] = 70000 is outside \[0, 65535\]"),
    (([1, 2], [0], [0, 0], [1, 1]), r"1-D of one length"),
])
def test_make_events_refuses_bad_columns(args, message):
    with pytest.raises(ValueError, match=message):
        make_events(*args)


def test_check_events_names_the_first_bad_index():
    events = make_events([1, 5, 4, 6], [0, 1, 2, 3], [0, 0, 0, 0], [1, 1, -1, 1])
    with pytest.raises(ValueError, match=r"^chunk: event 2: t = 4 ns is before .* 5 ns"):
        check_events(events, source="chunk")
    events = make_events([1, 2, 3], [0, 9, 10], [0, 1, 2], [1, 1, 1])
    check_events(events, width=11, height=3)
    with pytest.raises(ValueError, match=r"event 2: x = 10 is outside the sensor \(width 10\)"):
        check_events(events, width=10, height=3)
    with pytest.raises(ValueError, match=r"event 2: y = 2 is outside the sensor \(height 2\)"):
        check_events(events, width=11, height=2)
    events["p"][1] = 0
    with pytest.raises(ValueError, match=r"event 1: p = 0; expected \+1 \(ON\) or -1"):
        check_events(events)
    with pytest.raises(ValueError, match="expected a 1-D array of EVENT_DTYPE"):
        check_events(np.zeros(3))


# --- text format -----------------------------------------------------------------------------

def test_text_lines_have_nine_decimals_and_01_polarity(tmp_path):
    # Expected lines written by hand from the definition t[s] = t_ns / 1e9 with 9 decimals.
    events = make_events([0, 5, 1_000_000_000, 3_811_000, BIG_T],
                         [0, 239, 7, 96, 3], [0, 179, 8, 133, 4], [-1, 1, 1, -1, 1])
    events = events[np.argsort(events["t"], kind="stable")]
    write_text(tmp_path / "events.txt", events)
    assert (tmp_path / "events.txt").read_text() == (
        "0.000000000 0 0 0\n"
        "0.000000005 239 179 1\n"
        "0.003811000 96 133 0\n"
        "1.000000000 7 8 1\n"
        "1468941032.255198860 3 4 1\n"
    )


def test_text_round_trip_is_lossless(tmp_path):
    events = np.concatenate([random_events(20_000, seed=1),
                             random_events(1000, seed=2, t_start=BIG_T, t_max=10**9)])
    write_text(tmp_path / "events.txt", events)
    back = read_events(tmp_path / "events.txt", 240, 180)
    assert back.dtype == EVENT_DTYPE
    np.testing.assert_array_equal(back, events)
    assert (events["t"] % 1000 != 0).mean() > 0.9 and events["t"][-1] > BIG_T  # what it covers


def test_text_reader_accepts_variants_and_parses_times_exactly(tmp_path):
    path = tmp_path / "events.txt"
    path.write_bytes(b"# t x y p\n"
                     b"\n"
                     b"0.5 1 2 1\r\n"
                     b"3\t4  5 0\n"
                     b"   1468941032.255198860 6 7 1   \n"
                     b"1468941032.255198861 0 0 0")         # no final newline
    events = read_events(path)
    # Independent values: 0.5 s = 5e8 ns, 3 s = 3e9 ns, and the big time digit by digit.
    assert events["t"].tolist() == [500_000_000, 3_000_000_000, 1468941032255198860,
                                    1468941032255198861]
    assert events["x"].tolist() == [1, 4, 6, 0] and events["y"].tolist() == [2, 5, 7, 0]
    assert events["p"].tolist() == [1, -1, 1, -1]


GOOD = "0.001000000 1 2 1\n0.002000000 3 4 0\n# a comment\n\n"   # lines 1-4


@pytest.mark.parametrize(("bad_line", "message"), [
    ("0.003 abc 4 1", r"x 'abc' is not an integer in \[0, 65535\]"),
    ("zero 3 4 1", r"time 'zero' is not a non-negative number of seconds"),
    ("0.003 3 4", r"expected 4 fields 't\[s\] x y p'.*, got 3: '0.003 3 4'"),
    ("0.003 3 4 1 9", r"expected 4 fields 't\[s\] x y p'.*, got 5"),
    ("0.003 3 4 2", r"polarity '2' is not 0 or 1; expected p in \{0, 1\}"),
    ("0.003 3 4 -1", r"polarity '-1' is not 0 or 1"),
    ("0.0030000001 3 4 1", r"time '0.0030000001' is not .* with at most 9 decimals"),
    ("0.001500000 3 4 1", r"time 0.001500000 s is before the previous event's 0.002000000 s; "
                          r"expected non-decreasing times"),
    ("0.003 240 4 1", r"x = 240 is outside the sensor \(width 240\); expected 0 <= x < 240"),
    ("0.003 3 180 1", r"y = 180 is outside the sensor \(height 180\)"),
    ("0.003 3 -4 1", r"y '-4' is not an integer"),
])
def test_a_malformed_text_line_is_named(tmp_path, bad_line, message):
    path = tmp_path / "events.txt"
    path.write_text(GOOD + bad_line + "\n0.009 1 1 1\n")
    with pytest.raises(ValueError, match=re.escape(f"{path}:5: ") + message):
        read_events(path, 240, 180)


def test_a_bad_line_in_a_later_block_is_named_with_its_global_line_number(tmp_path):
    # 60,000 lines (~1.2 MB) span two 1 MiB blocks of the reader.
    events = random_events(60_000, seed=3)
    write_text(tmp_path / "events.txt", events)
    lines = (tmp_path / "events.txt").read_text().splitlines(keepends=True)
    lines[55_554] = lines[55_554].rsplit(" ", 1)[0] + " 7\n"
    (tmp_path / "events.txt").write_text("".join(lines))
    with pytest.raises(ValueError, match=re.escape("events.txt:55555: polarity '7'")):
        for _ in iter_event_chunks(tmp_path / "events.txt", chunk_events=1000):
            pass


def test_time_going_back_across_blocks_is_named(tmp_path):
    events = random_events(60_000, seed=4)
    write_text(tmp_path / "events.txt", events)
    lines = (tmp_path / "events.txt").read_text().splitlines(keepends=True)
    lines[59_000] = "0.000000000 1 1 1\n"
    (tmp_path / "events.txt").write_text("".join(lines))
    with pytest.raises(ValueError, match=r"events.txt:59001: time 0.000000000 s is before"):
        read_events(tmp_path / "events.txt")


# --- HDF5 format -----------------------------------------------------------------------------

def test_h5_layout_is_dsec_plus_the_sub_microsecond_extension(tmp_path):
    events = make_events([1_500, 999_999, 1_000_000, 3_000_001_999], [1, 2, 3, 239],
                         [4, 5, 6, 179], [1, -1, 1, -1])
    write_h5(tmp_path / "events.h5", events)
    with h5py.File(tmp_path / "events.h5", "r") as f:
        # Values written by hand: t_us = t_ns // 1000, rem = t_ns % 1000, p 1/0.
        assert f["events/t"].dtype == np.int64 and f["events/t"][:].tolist() == [1, 999, 1000,
                                                                                  3_000_001]
        assert f["events/t_ns_rem"].dtype == np.uint16
        assert f["events/t_ns_rem"][:].tolist() == [500, 999, 0, 999]
        assert f["events/x"].dtype == np.uint16 and f["events/x"][:].tolist() == [1, 2, 3, 239]
        assert f["events/y"].dtype == np.uint16 and f["events/y"][:].tolist() == [4, 5, 6, 179]
        assert f["events/p"].dtype == np.uint8 and f["events/p"][:].tolist() == [1, 0, 1, 0]
        for name in ("t", "x", "y", "p", "t_ns_rem"):
            dataset = f[f"events/{name}"]
            assert dataset.maxshape == (None,) and dataset.chunks is not None
            assert dataset.compression == "gzip"
        assert int(f["t_offset"][()]) == 0 and int(f.attrs["t_offset"]) == 0
        assert int(f.attrs["width"]) == 240 and int(f.attrs["height"]) == 180
        ms_to_idx = f["ms_to_idx"][:]
    assert ms_to_idx.dtype == np.int64
    # ms 0: event 0 (t=1 us); ms 1: first t >= 1000 us is event 2; ms 2..3000: event 3;
    # ms 3001 = last ms + 1: the number of events.
    assert ms_to_idx.shape == (3002,)
    assert ms_to_idx[:3].tolist() == [0, 2, 3] and (ms_to_idx[2:3001] == 3).all()
    assert ms_to_idx[3001] == 4


def test_h5_round_trip_is_lossless_with_large_times(tmp_path):
    events = random_events(30_000, seed=5, t_start=BIG_T, t_max=2 * 10**9)
    write_h5(tmp_path / "events.h5", events)
    np.testing.assert_array_equal(read_events(tmp_path / "events.h5", 240, 180), events)
    with h5py.File(tmp_path / "events.h5", "r") as f:
        # Unix times get an offset (the first event's whole millisecond), not 1.5e12 entries.
        assert int(f["t_offset"][()]) == events["t"][0] // 10**6 * 1000
        assert f["ms_to_idx"].shape[0] < 2100


def test_h5_round_trip_of_small_times_keeps_t_offset_zero(tmp_path):
    events = random_events(30_000, seed=6, t_start=5 * 10**9)
    write_h5(tmp_path / "events.h5", events)
    np.testing.assert_array_equal(read_events(tmp_path / "events.h5"), events)
    with h5py.File(tmp_path / "events.h5", "r") as f:
        assert int(f["t_offset"][()]) == 0
        assert f["ms_to_idx"].shape[0] == events["t"][-1] // 10**6 + 2


@pytest.mark.parametrize("t_start", [0, BIG_T])
def test_text_to_h5_to_text_is_byte_identical(tmp_path, t_start):
    events = random_events(20_000, seed=7, t_start=t_start)
    write_text(tmp_path / "a.txt", events)
    convert_events(tmp_path / "a.txt", tmp_path / "b.h5", 240, 180)
    convert_events(tmp_path / "b.h5", tmp_path / "c.txt")
    assert (tmp_path / "c.txt").read_bytes() == (tmp_path / "a.txt").read_bytes()
    convert_events(tmp_path / "b.h5", tmp_path / "d.h5")         # size copied from the source
    with h5py.File(tmp_path / "d.h5", "r") as f:
        assert (int(f.attrs["width"]), int(f.attrs["height"])) == (240, 180)
    np.testing.assert_array_equal(read_events(tmp_path / "d.h5"), events)


def test_conversion_to_h5_needs_the_sensor_size(tmp_path):
    write_text(tmp_path / "a.txt", random_events(10, seed=9))
    with pytest.raises(ValueError, match="needs the sensor size; expected width and height"):
        convert_events(tmp_path / "a.txt", tmp_path / "b.h5")
    assert not (tmp_path / "b.h5").exists()
    with pytest.raises(ValueError, match=r"x = \d+ is outside the sensor \(width 5\)"):
        convert_events(tmp_path / "a.txt", tmp_path / "b.h5", 5, 180)
    assert not (tmp_path / "b.h5").exists()


def test_reads_a_plain_dsec_file_without_the_extension(tmp_path):
    # A file as DSEC writes it: no t_ns_rem, an offset, absolute us = t + t_offset.
    path = tmp_path / "dsec.h5"
    with h5py.File(path, "w") as f:
        f["events/t"] = np.array([0, 10, 2500], np.int64)
        f["events/x"] = np.array([1, 2, 3], np.uint16)
        f["events/y"] = np.array([4, 5, 6], np.uint16)
        f["events/p"] = np.array([1, 0, 1], np.uint8)
        f["ms_to_idx"] = np.array([0, 2, 2, 3], np.int64)
        f["t_offset"] = np.int64(7_000_000)
    events = read_events(path)
    assert events["t"].tolist() == [7_000_000_000, 7_000_010_000, 7_002_500_000]
    assert events["p"].tolist() == [1, -1, 1]
    assert read_window(path, 7_000_005_000, 7_003_000_000)["t"].tolist() == [7_000_010_000,
                                                                               7_002_500_000]


def test_malformed_h5_files_are_refused(tmp_path):
    path = tmp_path / "bad.h5"
    with h5py.File(path, "w") as f:
        f["events/t"] = np.array([0, 1], np.int64)
    with pytest.raises(ValueError, match=re.escape(f"{path}: no dataset events/x")):
        read_events(path)
    with h5py.File(path, "w") as f:
        f["events/t"] = np.array([0, 1], np.int64)
        f["events/x"] = f["events/y"] = np.array([0, 1], np.uint16)
        f["events/p"] = np.array([1, 2], np.uint8)
    with pytest.raises(ValueError, match=re.escape(f"{path}: event 1: events/p = 2")):
        read_events(path)
    (tmp_path / "junk.h5").write_text("not hdf5")
    with pytest.raises(ValueError, match="cannot open as HDF5"):
        read_events(tmp_path / "junk.h5")
    with pytest.raises(ValueError, match=r"unknown event file type '\.csv'"):
        read_events(tmp_path / "events.csv")


def test_h5_writer_refuses_an_offset_after_the_first_event(tmp_path):
    with pytest.raises(ValueError, match="comes before t_offset_us = 2000"), \
            H5EventWriter(tmp_path / "e.h5", 240, 180, t_offset_us=2000) as writer:
        writer.write(make_events([1_999_999], [0], [0], [1]))
    assert not (tmp_path / "e.h5").exists()
    with pytest.raises(ValueError, match="empty ms_to_idx entries"), \
            H5EventWriter(tmp_path / "e.h5", 240, 180, t_offset_us=0) as writer:
        writer.write(make_events([BIG_T], [0], [0], [1]))


def test_h5_writer_refuses_a_gap_that_ms_to_idx_cannot_index(tmp_path):
    # 0 s and then Unix time: ms_to_idx would need 1.5e12 entries in between.
    with H5EventWriter(tmp_path / "e.h5", 240, 180) as writer:
        writer.write(make_events([5, 6], [0, 0], [0, 0], [1, 1]))
        with pytest.raises(ValueError, match=r"event 3 at t = 1468941032255198860 ns comes "
                                             r"1468941032255 ms after the previous event"):
            writer.write(make_events([7, BIG_T], [0, 0], [0, 0], [1, 1]))
        writer.write(make_events([7], [1], [1], [-1]))              # the writer goes on
    assert read_events(tmp_path / "e.h5")["t"].tolist() == [5, 6, 7]


# --- ms_to_idx and windows -------------------------------------------------------------------

def sparse_events(seed: int) -> np.ndarray:
    """Bursts with whole empty milliseconds between them, and events exactly on ms boundaries."""
    rng = np.random.default_rng(seed)
    bursts = [rng.integers(ms * 10**6, ms * 10**6 + 300_000, 40) for ms in
              (0, 1, 2, 7, 8, 30, 31, 32, 33, 90)]
    on_boundaries = np.array([3 * 10**6, 8 * 10**6, 8 * 10**6, 31 * 10**6 - 1, 90 * 10**6])
    t = np.sort(np.concatenate(bursts + [on_boundaries]))
    n = t.size
    return make_events(t, rng.integers(0, 240, n), rng.integers(0, 180, n),
                       rng.choice([-1, 1], n))


def test_ms_to_idx_follows_the_dsec_definition(tmp_path):
    events = sparse_events(seed=10)
    write_h5(tmp_path / "events.h5", events)
    with h5py.File(tmp_path / "events.h5", "r") as f:
        ms_to_idx = f["ms_to_idx"][:]
        t_us = f["events/t"][:]
    last_ms = int(events["t"][-1] // 10**6)
    assert ms_to_idx.shape == (last_ms + 2,)
    for k in range(last_ms + 2):
        # first index with t_us >= 1000 k, by brute force (the count of earlier events)
        assert ms_to_idx[k] == np.count_nonzero(events["t"] // 1000 < 1000 * k), k
        # DSEC's own statement of it
        if ms_to_idx[k] < t_us.size:
            assert t_us[ms_to_idx[k]] >= 1000 * k
        if ms_to_idx[k] > 0:
            assert t_us[ms_to_idx[k] - 1] < 1000 * k
    assert ms_to_idx[-1] == events.size


def test_windows_return_exactly_the_events_inside(tmp_path):
    events = sparse_events(seed=11)
    write_h5(tmp_path / "events.h5", events, chunk_size=64)
    write_text(tmp_path / "events.txt", events)
    rng = np.random.default_rng(12)
    edges = [int(v) for v in rng.integers(-2 * 10**6, 95 * 10**6, 120)]
    edges += [k * 10**6 for k in range(0, 95, 3)]                     # exact ms boundaries
    edges += [int(v) for v in events["t"][::25]] + [int(v) + 1 for v in events["t"][::25]]
    windows = [tuple(sorted(rng.choice(edges, 2, replace=False))) for _ in range(300)]
    windows += [(3 * 10**6, 8 * 10**6), (8 * 10**6, 8 * 10**6), (31 * 10**6 - 1, 31 * 10**6),
                (90 * 10**6, 91 * 10**6), (-5, 0), (91 * 10**6, 10**9)]
    for t0, t1 in windows:
        expected = events[(events["t"] >= t0) & (events["t"] < t1)]
        np.testing.assert_array_equal(read_window(tmp_path / "events.h5", t0, t1), expected,
                                      err_msg=f"h5 window [{t0}, {t1})")
        chunks = list(iter_event_chunks(tmp_path / "events.h5", 7, t0, t1))
        assert all(1 <= c.size <= 7 for c in chunks)
        joined = np.concatenate(chunks) if chunks else np.empty(0, EVENT_DTYPE)
        np.testing.assert_array_equal(joined, expected)
    for t0, t1 in windows[::10]:
        expected = events[(events["t"] >= t0) & (events["t"] < t1)]
        np.testing.assert_array_equal(read_window(tmp_path / "events.txt", t0, t1), expected)


def test_a_window_must_not_end_before_it_starts(tmp_path):
    write_text(tmp_path / "events.txt", random_events(10, seed=13))
    with pytest.raises(ValueError, match=r"ends before it starts; expected t0_ns <= t1_ns"):
        read_window(tmp_path / "events.txt", 10, 5)


# --- streaming writers -----------------------------------------------------------------------

def split_randomly(events: np.ndarray, seed: int) -> list[np.ndarray]:
    """200 random cuts, and empty chunks on purpose: the first, the last and one in the middle."""
    rng = np.random.default_rng(seed)
    chunks = np.split(events, np.sort(rng.integers(1, events.size, 200)))
    empty = events[:0]
    return [empty, *chunks[:100], empty, *chunks[100:], empty]


def test_writing_in_many_chunks_equals_writing_once(tmp_path):
    """The same events written at once and in 201 chunks (empty ones too) give the same bytes:
    text, and HDF5 too (its close() rewrites the file so that its bytes depend on its contents,
    not on where the chunks were cut)."""
    events = random_events(40_000, seed=14)
    chunks = split_randomly(events, seed=15)
    write_text(tmp_path / "once.txt", events)
    write_h5(tmp_path / "once.h5", events, chunk_size=1000)
    with TextEventWriter(tmp_path / "many.txt") as text, \
            H5EventWriter(tmp_path / "many.h5", 240, 180, chunk_size=1000) as h5:
        for chunk in chunks:
            text.write(chunk)
            h5.write(chunk)
    assert (tmp_path / "many.txt").read_bytes() == (tmp_path / "once.txt").read_bytes()
    assert (tmp_path / "many.h5").read_bytes() == (tmp_path / "once.h5").read_bytes()
    with h5py.File(tmp_path / "many.h5", "r") as b:
        np.testing.assert_array_equal(b["events/t"][()] * 1000 + b["events/t_ns_rem"][()],
                                      events["t"])
        np.testing.assert_array_equal(b["events/p"][()], (events["p"] > 0).astype(np.uint8))


@pytest.mark.parametrize("kind", ["txt", "h5"])
def test_a_chunk_that_goes_back_in_time_is_refused(tmp_path, kind):
    path = tmp_path / f"events.{kind}"
    first = make_events([10, 20], [1, 2], [1, 2], [1, 1])
    with TextEventWriter(path) if kind == "txt" else H5EventWriter(path, 240, 180) as writer:
        writer.write(first)
        with pytest.raises(ValueError, match=r"starts at t = 19 ns, before the previous "
                                             r"chunk's last event at 20 ns"):
            writer.write(make_events([19, 30], [0, 0], [0, 0], [1, 1]))
        writer.write(make_events([20, 30], [3, 4], [3, 4], [-1, 1]))  # equal time is fine
    assert read_events(path)["t"].tolist() == [10, 20, 20, 30]       # nothing of the refused one


@pytest.mark.parametrize("kind", ["txt", "h5"])
def test_an_exception_inside_with_leaves_only_the_partial_file(tmp_path, kind):
    path = tmp_path / f"events.{kind}"
    with pytest.raises(RuntimeError, match="renderer crashed"), \
            (TextEventWriter(path) if kind == "txt" else H5EventWriter(path, 240, 180)) as writer:
        writer.write(random_events(100, seed=16))
        raise RuntimeError("renderer crashed")
    assert not path.exists()
    assert (tmp_path / f"events.{kind}.partial").is_file()
    assert sorted(os.listdir(tmp_path)) == [f"events.{kind}.partial"]


def test_the_partial_file_is_renamed_only_on_close(tmp_path):
    writer = TextEventWriter(tmp_path / "events.txt")
    writer.write(random_events(10, seed=17))
    assert not (tmp_path / "events.txt").exists()
    writer.close()
    writer.close()
    assert (tmp_path / "events.txt").is_file() and not (tmp_path / "events.txt.partial").exists()
    with pytest.raises(ValueError, match=r"write\(\) after close\(\)"):
        writer.write(random_events(10, seed=17))


def test_writers_refuse_negative_times_and_pixels_outside_the_sensor(tmp_path):
    with pytest.raises(ValueError, match="t = -1 ns is negative"), \
            TextEventWriter(tmp_path / "a.txt") as writer:
        writer.write(make_events([-1], [0], [0], [1]))
    with pytest.raises(ValueError, match=r"event 1: y = 180 is outside the sensor"), \
            H5EventWriter(tmp_path / "a.h5", 240, 180) as writer:
        writer.write(make_events([1, 2], [0, 0], [0, 180], [1, 1]))


# --- the real ECD file -----------------------------------------------------------------------

def test_reads_the_real_ecd_slider_file(ecd_slider, tmp_path):
    path = ecd_slider / "events.txt"
    events = read_events(path, 240, 180)
    # Figures from the file itself (first and last lines, `wc -l`) and the README.
    assert events.size == 50_000
    assert events["t"][0] == 3_811_000 and events["t"][-1] == 174_156_000
    assert set(np.unique(events["p"]).tolist()) == {-1, 1}
    assert events["x"].max() < 240 and events["y"].max() < 180
    assert (events["x"][0], events["y"][0], events["p"][0]) == (96, 133, -1)
    assert events["t"][1] == 3_820_001                              # "0.003820001 127 171 0"
    # Written back, it is the dataset's own file, byte for byte.
    write_text(tmp_path / "events.txt", events)
    assert (tmp_path / "events.txt").read_bytes() == path.read_bytes()


# --- statistics and the event frame ----------------------------------------------------------

def test_event_stats_on_a_hand_made_example():
    # 4 x 3 sensor. Pixel (3, 2) fires 50 times (40 ON, 10 OFF); pixels (0, 0), (1, 0), (2, 1)
    # and (0, 2) once each (ON, OFF, OFF, ON). Times from 1 s to 3 s.
    x = [0, 1, 2, 0] + [3] * 50
    y = [0, 0, 1, 2] + [2] * 50
    p = [1, -1, -1, 1] + [1] * 40 + [-1] * 10
    t = np.linspace(10**9, 3 * 10**9, 54).astype(np.int64)
    stats = event_stats(make_events(t, x, y, p), 4, 3)
    assert stats["count"] == 54
    assert stats["duration_s"] == pytest.approx(2.0)
    assert stats["rate_ev_per_s"] == pytest.approx(27.0)
    assert stats["t_first_s"] == pytest.approx(1.0) and stats["t_last_s"] == pytest.approx(3.0)
    assert stats["on"] == 42 and stats["off"] == 12
    assert stats["on_fraction"] == pytest.approx(42 / 54)
    assert stats["active_pixels"] == 5
    assert stats["events_per_pixel_mean"] == pytest.approx(54 / 12)
    assert stats["events_per_pixel_max"] == 50
    assert stats["hot_pixel_threshold"] == pytest.approx(10.0)    # median of [1, 1, 1, 1, 50]
    assert stats["hot_pixels"] == 1


def test_event_stats_of_no_events():
    stats = event_stats(np.empty(0, EVENT_DTYPE), 4, 3)
    assert stats["count"] == 0 and stats["rate_ev_per_s"] == 0.0 and stats["hot_pixels"] == 0


def test_event_frame_colours_by_the_latest_polarity():
    events = make_events([1, 2, 3, 4, 5], [0, 0, 1, 1, 2], [0, 0, 1, 1, 2],
                         [-1, 1, 1, -1, -1])
    frame = event_frame(events, 4, 3)
    assert frame.shape == (3, 4, 3) and frame.dtype == np.uint8
    assert frame[0, 0].tolist() == [255, 0, 0]      # OFF then ON: red
    assert frame[1, 1].tolist() == [0, 0, 255]      # ON then OFF: blue
    assert frame[2, 2].tolist() == [0, 0, 255]      # OFF: blue
    assert frame[0, 3].tolist() == [255, 255, 255]  # no event: white
    assert (frame.reshape(-1, 3) != 255).any(axis=1).sum() == 3
    black = event_frame(events, 4, 3, background="black")
    assert black[0, 3].tolist() == [0, 0, 0] and black[0, 0].tolist() == [255, 0, 0]
    with pytest.raises(ValueError, match="background must be one of"):
        event_frame(events, 4, 3, background="grey")


# --- throughput (printed, never asserted; EVFUSE_BENCH=1 pytest -s to run) -------------------

@pytest.mark.skipif(os.environ.get("EVFUSE_BENCH") != "1", reason="set EVFUSE_BENCH=1 to run")
def test_throughput_of_5_million_events(tmp_path):
    n = 5_000_000
    events = random_events(n, seed=18, t_max=60 * 10**9, width=640, height=480)
    rows = []
    for kind in ("txt", "h5"):
        path = tmp_path / f"events.{kind}"
        start = time.perf_counter()
        if kind == "txt":
            write_text(path, events)
        else:
            write_h5(path, events, 640, 480)
        middle = time.perf_counter()
        back = read_events(path, 640, 480)
        end = time.perf_counter()
        np.testing.assert_array_equal(back, events)
        rows.append(f"{kind:>4}: write {n / (middle - start) / 1e6:6.2f} M ev/s, read "
                    f"{n / (end - middle) / 1e6:6.2f} M ev/s, {path.stat().st_size / n:5.1f} "
                    "bytes/event")
    print("\n" + "\n".join(rows))


# --- times in the wrong unit (issue 11, item 6) ------------------------------------------------

def _dsec_file(path, t, entries=202):
    """A DSEC-layout file holding ``t`` as events/t (whatever its unit) and an ms_to_idx of
    ``entries`` (what the true times need: the last one's ms + 2)."""
    n = len(t)
    with h5py.File(path, "w") as f:
        f["events/t"] = np.asarray(t, np.int64)
        f["events/x"] = f["events/y"] = np.zeros(n, np.uint16)
        f["events/p"] = np.ones(n, np.uint8)
        f["ms_to_idx"] = np.zeros(entries, np.int64)
    return path


def test_an_h5_in_nanoseconds_is_refused_against_its_ms_to_idx(tmp_path):
    t_us = np.array([1_000, 100_000, 200_000])                 # 0.001-0.2 s in microseconds
    read_events(_dsec_file(tmp_path / "good.h5", t_us))
    path = _dsec_file(tmp_path / "ns.h5", t_us * 1000)          # the same times in nanoseconds
    for call in (lambda: read_events(path), lambda: read_window(path, 0, 10**9),
                 lambda: convert_events(path, tmp_path / "out.txt")):
        with pytest.raises(ValueError) as info:
            call()
        assert str(info.value) == (f"{path}: events/t looks like nanoseconds (span 200 s from "
                                   "t_offset against 0.202 s of ms_to_idx); DSEC layout stores "
                                   "microseconds")
    path = _dsec_file(tmp_path / "ms.h5", t_us // 1000 + 5000, 5202)   # 5-5.2 s in ms
    with pytest.raises(ValueError, match="events/t looks like milliseconds"):
        read_events(path)
    # absolute microseconds with an ms_to_idx counted from the first event, not from t_offset
    path = _dsec_file(tmp_path / "abs.h5", t_us + 1_600_000_000_000_000)
    with pytest.raises(ValueError, match=r"ms_to_idx covers 0.202 s from the first event, but "
                                         r"events/t runs to 1.6e\+09 s after t_offset"):
        read_events(path)
    path = _dsec_file(tmp_path / "odd.h5", t_us * 37)           # no unit is 37 times another
    with pytest.raises(ValueError, match=r"events/t runs to 7.4 s but ms_to_idx 0.202 s; DSEC "
                                         "layout stores microseconds"):
        read_events(path)


def test_times_in_another_unit_are_named_against_the_poses(tmp_path):
    from sim.eventio import check_time_units

    h5 = tmp_path / "events.h5"
    # nanoseconds read as microseconds: 0.004-0.174 s become 3.8-174 s, poses 0.02-3.4 s
    with pytest.raises(ValueError) as info:
        check_time_units(h5, 3.811, 174.156, 0.0223, 3.4025)
    assert str(info.value) == (f"{h5}: events/t looks like nanoseconds (events at 3.811-174.2 s "
                               "against 0.0223-3.402 s of poses); DSEC layout stores microseconds")
    with pytest.raises(ValueError, match="events/t looks like milliseconds"):
        check_time_units(h5, 0.005, 0.0052, 4.0, 6.0)     # 5-5.2 s written in milliseconds
    with pytest.raises(ValueError, match="the times look like nanoseconds .* ECD text stores "
                                         "seconds"):
        check_time_units(tmp_path / "events.txt", 1e8, 9e8, 0.0, 1.0)
    check_time_units(h5, 0.0038, 0.174, 0.0223, 3.4)    # the real prefix: overlaps, accepted
    check_time_units(h5, 0.0, 60.0, 0.0, 3.0)           # poses for 5 % of the events: accepted
    check_time_units(h5, 5.0, 6.0, 0.0, 1.0)            # merely outside, same span: not a unit


def test_a_text_file_span_is_read_once_and_again_when_the_file_changes(tmp_path):
    from sim.eventio import event_time_span
    from sim.eventio._read import _text_time_span

    path = tmp_path / "events.txt"
    path.write_text("0.001 3 4 1\n0.002 5 6 0\n")
    before = _text_time_span.cache_info().misses
    assert event_time_span(path) == event_time_span(path) == (0.001, 0.002)
    assert _text_time_span.cache_info().misses == before + 1          # one pass for both
    path.write_text("0.001 3 4 1\n0.002 5 6 0\n0.0035 1 1 1\n")      # a new version: re-read
    assert event_time_span(path) == (0.001, 0.0035)
