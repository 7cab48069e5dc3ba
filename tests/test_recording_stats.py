"""sim.statistics' reading of a recording for ``evfuse events`` (moved out of the command line):
the event file it picks, the events it reads, the first seconds drawn and the figures."""

from __future__ import annotations

import numpy as np
import pytest

from sim.statistics import events_file, first_seconds, read_gray, read_recording, recording_stats
from tests.test_cli_messages import _sequence


def test_the_h5_file_is_read_first_and_a_folder_without_events_is_refused(tmp_path):
    folder = _sequence(tmp_path / "seq")
    assert events_file(folder) == folder / "events.h5"
    (folder / "events.h5").unlink()
    assert events_file(folder) == folder / "events.txt"
    (folder / "events.txt").unlink()
    with pytest.raises(ValueError, match="seq: no events.h5 or events.txt in this folder"):
        events_file(folder)


def test_a_recording_s_events_and_figures(tmp_path):
    folder = _sequence(tmp_path / "seq", t0=0.1, t1=0.9)
    sequence, path, events = read_recording(folder)
    assert path == folder / "events.h5" and len(events) == 200
    stats = recording_stats(sequence, events)
    assert stats["count"] == 200 and list(stats)[-1] == "frame_noise"
    assert stats["frame_noise"] == 0.0                 # the one frame is flat gray
    # The first 0.3 s from the first event: counted here from the times themselves.
    t = events["t"]
    window = first_seconds(events, 0.3)
    assert len(window) == int(np.sum(t < t[0] + 300_000_000)) < 200
    assert first_seconds(events, None) is events


def test_an_unreadable_image_is_named(tmp_path):
    path = tmp_path / "frame.png"
    path.write_text("not an image")
    with pytest.raises(ValueError, match="frame.png: not a readable image"):
        read_gray(path)
