"""The dataset loader (issue 24, part 6): ``sim.open_dataset`` on a dataset folder as ``evfuse
generate`` writes it (``small_dataset`` in conftest: two sequences, one read from ``events.h5``,
one from ``events.txt`` alone; a failed and a pending job)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

import sim
from sim.dataset import DATASET_EVENT_DTYPE, open_dataset
from sim.eventio import line_offsets, read_events, read_text_span, text_offsets
from sim.validation import ParameterError


def _event_file(seq):
    return seq.events_h5 if seq.events_h5 is not None else seq.events_txt


def test_every_sample_holds_exactly_the_events_since_the_previous_frame(small_dataset):
    """Against the whole file read by ``read_events``: sample k of a sequence holds the events
    of ``[t_{k-1}, t_k)`` (frame 0: all before it), in order, every field equal; the samples
    of a sequence hold every event before its last frame once. From HDF5 and from text."""
    ds = open_dataset(small_dataset, time_unit="ns", report=False)
    assert ds.job_ids == ("complex_sphere-0", "boxes_6dof-0")
    assert ds.sequences[0].events_h5 is not None and ds.sequences[1].events_h5 is None
    assert len(ds) == sum(len(seq.image_times) for seq in ds.sequences) == 12
    for k, seq in enumerate(ds.sequences):
        everything = read_events(_event_file(seq))
        bounds = np.round(seq.image_times * 1e9).astype(np.int64)
        assert everything.size > 50 and everything["t"][-1] >= bounds[0]
        seen = 0
        for j, index in enumerate(ds.samples_of(k)):
            sample = ds[index]
            assert (sample.sequence, sample.frame_index, sample.job_id) == (k, j, ds.job_ids[k])
            low = -1 if j == 0 else bounds[j - 1]
            expected = everything[(everything["t"] >= low) & (everything["t"] < bounds[j])]
            got = sample.events
            assert got.dtype == DATASET_EVENT_DTYPE
            for name in ("t", "x", "y"):
                np.testing.assert_array_equal(got[name], expected[name])
            np.testing.assert_array_equal(got["p"], (expected["p"] > 0).astype(np.int8))
            seen += got.size
        assert seen == np.count_nonzero(everything["t"] < bounds[-1])


def test_event_times_are_microseconds_by_default(small_dataset):
    in_ns = open_dataset(small_dataset, time_unit="ns", report=False)
    in_us = open_dataset(small_dataset, report=False)
    for index in (0, 3, 7, 11):
        exact, tonic = in_ns[index].events, in_us[index].events
        np.testing.assert_array_equal(tonic["t"], exact["t"] // 1000)
        assert tonic.size == exact.size and in_us[index].window.time_unit == "us"


def test_a_sample_carries_its_frame_truth_and_the_events_depth(small_dataset):
    from sim.exr import read_depth
    from sim.flow import read_flow
    from sim.statistics import read_gray
    from sim.trajectory import read_trajectory

    ds = open_dataset(small_dataset, time_unit="ns", report=False)
    seq = ds.sequences[0]
    sample = ds[2]
    t = float(seq.image_times[2])
    assert sample.t == t and sample.sensor_size == (48, 36, 2)
    np.testing.assert_array_equal(sample.frame, read_gray(seq.image_paths[2]))
    np.testing.assert_array_equal(sample.depth, read_depth(seq.depth_paths[2]))
    assert sample.depth.shape == (36, 48) and (sample.depth > 0).all()
    flow, flags = read_flow(seq.forward_flow.at(t))
    np.testing.assert_array_equal(sample.forward_flow, flow)
    np.testing.assert_array_equal(sample.forward_flow_flags, flags)
    assert sample.backward_flow.shape == (36, 48, 2) and sample.motion_field.shape == (36, 48, 2)
    assert ds[0].backward_flow is None and ds[5].forward_flow is None   # first and last frame
    assert set(np.unique(sample.object_mask)) <= {0, 1, 2}
    np.testing.assert_allclose(sample.pose, read_trajectory(seq.groundtruth_path).pose(t))
    np.testing.assert_array_equal(sample.T_event_frame, np.eye(4))
    assert sample.camera == seq.camera == sample.event_camera
    imu = seq.read_imu()
    np.testing.assert_array_equal(sample.imu, imu[(imu[:, 0] >= seq.image_times[1])
                                                  & (imu[:, 0] < t)])
    # the per-event depth, aligned one to one with the sample's events
    truth = seq.event_depth()
    inside = (truth["t"] >= round(seq.image_times[1] * 1e9)) & (truth["t"] < round(t * 1e9))
    inside_h5 = inside
    np.testing.assert_array_equal(sample.window.depth, truth["depth"][inside])
    np.testing.assert_array_equal(sample.window.depth_flag, truth["flag"][inside])
    assert sample.window.depth.size == sample.events.size > 0
    # and from events_depth.txt, for a sequence without events.h5
    text = ds[6 + 4]
    truth = ds.sequences[1].event_depth()
    bounds = np.round(ds.sequences[1].image_times[3:5] * 1e9)
    inside = (truth["t"] >= bounds[0]) & (truth["t"] < bounds[1])
    np.testing.assert_array_equal(text.window.depth, truth["depth"][inside])
    assert text.window.depth.size == text.events.size > 0
    # the labels, aligned one to one with the events (the sequence's own accessor)
    labels = seq.event_labels()
    np.testing.assert_array_equal(sample.window.cause, labels["cause"][inside_h5])
    np.testing.assert_array_equal(sample.window.object_id, labels["object_id"][inside_h5])
    np.testing.assert_array_equal(labels["t"][inside_h5], sample.window.events["t"])


def test_labels_come_from_the_sequences_accessor(small_dataset):
    """Each sample carries its events' ``cause`` and ``object_id`` from the sequence's label
    accessor (``events.h5`` for the first job, ``events_labels.txt`` for the text-only one),
    one row per event; the simulated scenes are noise-free, so every cause is signal."""
    ds = open_dataset(small_dataset, time_unit="ns", report=False)
    for index in (1, 8):
        sample = ds[index]
        seq = ds.sequences[0 if index < 6 else 1]
        labels = seq.event_labels(sample.window.t_start_ns, sample.window.t_end_ns)
        np.testing.assert_array_equal(labels["t"], sample.events["t"])
        np.testing.assert_array_equal(labels["x"], sample.events["x"])
        np.testing.assert_array_equal(sample.window.object_id, labels["object_id"])
        cause = sample.window.cause
        assert cause.dtype == np.uint8 and cause.size == sample.events.size > 0
        assert (cause == 0).all() and (sample.window.object_id >= 0).any()


def test_windows_by_time(small_dataset):
    ds = open_dataset(small_dataset, time_unit="ns", report=False)
    for job in ds.job_ids:
        seq = ds.sequences[ds.job_ids.index(job)]
        everything = read_events(_event_file(seq))
        t0, t1 = 0.52, 0.575
        window = ds.window(job, t0, t1)
        expected = everything[(everything["t"] >= 520_000_000) & (everything["t"] < 575_000_000)]
        np.testing.assert_array_equal(window.events["t"], expected["t"])
        np.testing.assert_array_equal(window.events["x"], expected["x"])
        assert window.events.size > 0 and (window.t_start_ns, window.t_end_ns) == (520_000_000,
                                                                                  575_000_000)
        assert ds.window(seq, None, None).events.size == everything.size   # all of it
    with pytest.raises(ValueError, match="ends before it starts"):
        ds.window(0, 0.6, 0.5)
    with pytest.raises(ValueError, match="no done job 'broken-0'"):
        ds.window("broken-0", 0.5, 0.6)


def test_tonic_transforms_take_a_samples_events_as_they_are(small_dataset):
    tonic = pytest.importorskip("tonic")
    transforms = tonic.transforms
    ds = open_dataset(small_dataset, report=False)
    sample = ds[9]
    events, size = sample.events, sample.sensor_size
    on, off = int(np.count_nonzero(events["p"] == 1)), int(np.count_nonzero(events["p"] == 0))
    assert on > 0 and off > 0
    frames = transforms.ToFrame(sensor_size=size, n_time_bins=3)(events.copy())
    assert frames.shape == (3, 2, 36, 48)
    # tonic's slices end at the last event, which falls out of the last bin; every other one is
    # counted once, on its own pixel and polarity channel
    assert on + off - 1 <= frames.sum() <= on + off
    counts = np.zeros((2, 36, 48), np.int64)
    np.add.at(counts, (events["p"], events["y"], events["x"]), 1)
    assert np.abs(frames.sum(axis=0) - counts).sum() <= 1
    voxels = transforms.ToVoxelGrid(sensor_size=size, n_time_bins=4)(events.copy())
    assert voxels.shape == (4, 1, 36, 48) and np.isfinite(voxels).all()
    # Zhu et al.'s event volume: each event's polarity split linearly between the two time
    # bins around its normalised time n (t - t_first) / (t_last - t_first), inside [0, n)
    reference = np.zeros((4, 36, 48))
    ts = 4 * (events["t"] - events["t"][0]) / (events["t"][-1] - events["t"][0])
    for event, t in zip(events, ts, strict=True):
        sign, low = (1.0 if event["p"] == 1 else -1.0), int(t)
        for b, weight in ((low, 1 - (t - low)), (low + 1, t - low)):
            if b < 4:
                reference[b, event["y"], event["x"]] += sign * weight
    np.testing.assert_allclose(voxels[:, 0], reference, atol=1e-9)
    dt = int(events["t"][-1] - events["t"][0]) // 2 + 1
    surfaces = transforms.ToTimesurface(sensor_size=size, dt=dt, tau=5000)(events.copy())
    assert surfaces.shape[1:] == (2, 36, 48) and ((surfaces >= 0) & (surfaces <= 1)).all()
    assert (surfaces[-1] > 0).sum() > 0


def test_opening_reads_no_event(small_dataset, tmp_path):
    """Event files that cannot be parsed do not stop the dataset from opening: only a sample
    reads them (and says which file is bad)."""
    copy = tmp_path / "copy"
    shutil.copytree(small_dataset, copy)
    for path in (copy / "jobs").rglob("events.*"):
        path.write_bytes(b"not events\n" * 10)
    ds = open_dataset(copy, report=False)
    assert len(ds) == 12 and len(ds.sequences) == 2
    assert ds.sequences[0].image_times.size == 6
    with pytest.raises(ValueError, match="events.h5"):
        ds[0]
    with pytest.raises(ValueError, match=r"events.txt:1"):
        ds[6]


def test_a_sample_reads_only_its_own_events(small_dataset, tmp_path):
    """Memory bounded by one sample: with 200,000 events in a sequence's ``events.txt`` (and
    its ``events_depth.txt`` and ``events_labels.txt``, one line per event), then in its
    ``events.h5`` (with depth and labels), reading one of its samples allocates a small part of
    what reading the whole files does (traced by tracemalloc), and its depth and labels are
    its events' rows. The sequence's own accessors, given the window, stream the text files
    (memory: a block of lines and the window's rows)."""
    import tracemalloc

    from sim.event_depth import H5EventDepthWriter, TextEventDepthWriter
    from sim.event_labels import LABELS_TXT_NAME, TextEventLabelWriter
    from sim.eventio import TextEventWriter, make_events

    copy = tmp_path / "copy"
    shutil.copytree(small_dataset, copy)
    folder = copy / "jobs" / "boxes_6dof-0"
    seq = sim.load_sequence(folder)
    rng = np.random.default_rng(0)
    count = 200_000
    t0_ns = round(seq.image_times[0] * 1e9) - 10_000_000
    t = np.sort(rng.integers(t0_ns, round(seq.image_times[-1] * 1e9), count))
    events = make_events(t, rng.integers(0, 48, count), rng.integers(0, 36, count),
                         np.where(rng.random(count) < 0.5, 1, -1))
    depth = rng.uniform(0.5, 3.0, count).astype(np.float32)
    flag = rng.integers(0, 3, count).astype(np.uint8)
    cause = rng.integers(0, 4, count).astype(np.uint8)
    object_id = rng.integers(-1, 5, count).astype(np.int32)
    bounds = np.round(seq.image_times[2:4] * 1e9)
    inside = (t >= bounds[0]) & (t < bounds[1])
    for name in ("events.txt", "events.h5"):
        # the fabricated sequence carries no stale per-event file of the simulated one
        for stale in ("events.txt", "events.h5", "events_depth.txt", LABELS_TXT_NAME):
            (folder / stale).unlink(missing_ok=True)
        if name == "events.txt":
            with TextEventWriter(folder / name) as out:
                out.write(events)
            with TextEventDepthWriter(folder / "events_depth.txt") as out:
                out.write(events, depth, flag)
            with TextEventLabelWriter(folder / LABELS_TXT_NAME) as out:
                out.write(events, cause, object_id)
        else:
            with H5EventDepthWriter(folder / name, 48, 36, labels=True) as out:
                out.write(events, depth, flag, cause=cause, object_id=object_id)
        ds = open_dataset(copy, time_unit="ns", report=False)
        index = ds.samples_of("boxes_6dof-0")[3]
        ds[index]                                    # a text file's frame index, made once
        tracemalloc.start()
        sample = ds[index]
        one = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        fresh = ds.sequences[ds.job_ids.index("boxes_6dof-0")]
        whole = read_events(folder / name), fresh.event_depth(), fresh.event_labels()
        everything = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert whole[0].size == whole[1].size == whole[2].size == count
        window = sample.window
        np.testing.assert_array_equal(window.events["t"], t[inside])
        np.testing.assert_array_equal(window.depth, depth[inside])
        np.testing.assert_array_equal(window.depth_flag, flag[inside])
        np.testing.assert_array_equal(window.cause, cause[inside])
        np.testing.assert_array_equal(window.object_id, object_id[inside])
        assert one < everything / 3, (name, one, everything)
        if name == "events.txt":          # the sequence's accessors stream the text files too
            for accessor in (fresh.event_labels, fresh.event_depth):
                tracemalloc.start()
                part = accessor(int(bounds[0]), int(bounds[1]))
                peak = tracemalloc.get_traced_memory()[1]
                tracemalloc.stop()
                np.testing.assert_array_equal(part["t"], t[inside])
                assert peak < everything / 3, (accessor.__name__, peak, everything)


def test_each_text_samples_depth_and_labels_are_its_events_rows(small_dataset):
    """A text-only sequence (``events.txt``, ``events_depth.txt``, ``events_labels.txt``): each
    sample's depth, flag, cause and object id equal the rows of its window in the whole files
    (read by the sequence's accessors), and so does a window by time."""
    ds = open_dataset(small_dataset, time_unit="ns", report=False)
    seq = ds.sequences[1]
    assert seq.events_h5 is None and seq.events_labels_txt is not None \
        and seq.events_depth_txt is not None
    depth, labels = seq.event_depth(), seq.event_labels()
    np.testing.assert_array_equal(depth["t"], labels["t"])
    seen = 0
    for index in ds.samples_of(1):
        window = ds[index].window
        low = -1 if window.t_start_ns is None else window.t_start_ns
        inside = (labels["t"] >= low) & (labels["t"] < window.t_end_ns)
        np.testing.assert_array_equal(window.events["t"], labels["t"][inside])
        np.testing.assert_array_equal(window.depth, depth["depth"][inside])
        np.testing.assert_array_equal(window.depth_flag, depth["flag"][inside])
        np.testing.assert_array_equal(window.cause, labels["cause"][inside])
        np.testing.assert_array_equal(window.object_id, labels["object_id"][inside])
        seen += int(inside.sum())
    assert seen > 50 and (labels["object_id"] >= 0).any()
    window = ds.window(1, 0.52, 0.575)
    inside = (labels["t"] >= 520_000_000) & (labels["t"] < 575_000_000)
    np.testing.assert_array_equal(window.object_id, labels["object_id"][inside])
    np.testing.assert_array_equal(window.depth, depth["depth"][inside])


def test_a_per_event_file_that_is_not_one_line_per_event_is_refused(small_dataset, tmp_path):
    """A text-only sequence whose label (or depth) file lost a line: its first sample says
    which file and how many lines for how many events."""
    copy = tmp_path / "copy"
    shutil.copytree(small_dataset, copy)
    folder = copy / "jobs" / "boxes_6dof-0"
    for name in ("events_labels.txt", "events_depth.txt"):
        path = folder / name
        kept = path.read_bytes()
        lines = kept.splitlines(keepends=True)
        path.write_bytes(b"".join(lines[:-1]))
        ds = open_dataset(copy, report=False)
        with pytest.raises(ValueError, match=rf"{name}: {len(lines) - 1} lines for the "
                                             rf"{len(lines)} events of .*events.txt"):
            ds[6]
        path.write_bytes(kept)


def test_text_offsets_find_where_each_time_begins(tmp_path):
    """Against a line-by-line reading: the offset and line of the first event at or after each
    time (with comments and blank lines between), and the spans between them parse to exactly
    the events of each window."""
    lines = ["# comment", "0.000000100 1 2 1", "", "0.000000200 3 4 0", "  0.000000200 5 6 1",
             "0.000001000 7 8 0", "# another", "0.000002000 9 9 1"]
    path = tmp_path / "events.txt"
    path.write_text("\n".join(lines) + "\n")
    times = np.array([0, 100, 150, 200, 201, 1000, 2000, 2001], np.int64)
    offsets, numbers, counts = text_offsets(path, times, width=10, height=10)
    starts = np.cumsum([0] + [len(line) + 1 for line in lines])
    np.testing.assert_array_equal(offsets, starts[[1, 1, 3, 3, 5, 5, 7, 8]])
    np.testing.assert_array_equal(numbers, [2, 2, 4, 4, 6, 6, 8, 9])
    np.testing.assert_array_equal(counts, [0, 0, 1, 1, 3, 3, 4, 5])
    everything = read_events(path)
    for k in range(len(times) - 1):
        span = read_text_span(path, int(offsets[k]), int(offsets[k + 1]), int(numbers[k]))
        inside = everything[(everything["t"] >= times[k]) & (everything["t"] < times[k + 1])]
        np.testing.assert_array_equal(span, inside)
    # the same windows' lines in a per-event file aligned with the events (its own comments)
    labels = tmp_path / "events_labels.txt"
    rows = ["0 1", "# note", "0 2", "", "  3 -1", "1 4", "2 0"]
    labels.write_text("\n".join(rows) + "\n")
    at, label_numbers, total = line_offsets(labels, counts)
    assert total == everything.size
    line_starts = np.cumsum([0] + [len(row) + 1 for row in rows])
    np.testing.assert_array_equal(at, line_starts[[0, 0, 2, 2, 5, 5, 6, 7]])
    np.testing.assert_array_equal(label_numbers, [1, 1, 3, 3, 6, 6, 7, 8])
    with pytest.raises(ValueError, match="non-decreasing"):
        line_offsets(labels, [2, 1])
    path.write_text("0.1 1 1 1\n0.2 1 1 2\n")
    with pytest.raises(ValueError, match=r"events.txt:2: polarity"):
        read_text_span(path, 0, path.stat().st_size)


def test_failed_and_pending_jobs_are_skipped_and_reported(small_dataset, capsys):
    ds = open_dataset(small_dataset)
    assert ds.failed == (("broken-0", "ValueError: the scene cannot render"),)
    assert ds.pending == ("later-0",)
    err = capsys.readouterr().err
    assert "job broken-0 failed (skipped): ValueError: the scene cannot render" in err
    assert "1 jobs pending (skipped): later-0" in err
    assert "broken-0" not in ds.job_ids and "1 failed, 1 pending" in repr(ds)


def test_refusals(small_dataset, tmp_path):
    with pytest.raises(ParameterError, match="has no manifest.csv: not a dataset folder"):
        open_dataset(small_dataset / "jobs")
    with pytest.raises(ParameterError, match="does not exist"):
        open_dataset(tmp_path / "nowhere")
    with pytest.raises(ParameterError, match="time_unit must be one of us, ns, got 'ms'"):
        open_dataset(small_dataset, time_unit="ms")
    copy = tmp_path / "copy"
    shutil.copytree(small_dataset, copy)
    shutil.rmtree(copy / "jobs" / "boxes_6dof-0")
    with pytest.raises(ParameterError, match="job boxes_6dof-0 is done but its folder"):
        open_dataset(copy, report=False)
    text = (copy / "manifest.csv").read_text().replace(",pending,", ",queued,")
    (copy / "manifest.csv").write_text(text)
    with pytest.raises(ParameterError, match=r"manifest.csv:5: status 'queued'"):
        open_dataset(copy, report=False)
    ds = open_dataset(small_dataset, report=False)
    with pytest.raises(IndexError, match="sample 12 out of range: the dataset has 12"):
        ds[12]
    assert ds[-1].frame_index == 5 and ds[-1].sequence == 1


def test_a_sequence_without_event_files_gives_frames_with_no_events(small_dataset, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(small_dataset, copy)
    for path in (copy / "jobs" / "complex_sphere-0").glob("events.*"):
        path.unlink()
    ds = open_dataset(copy, report=False)
    sample = ds[2]
    assert sample.events.size == 0 and sample.events.dtype == DATASET_EVENT_DTYPE
    assert sample.window.depth is None and sample.frame.shape == (36, 48)
    assert ds[8].events.size > 0                             # the other sequence still has them
