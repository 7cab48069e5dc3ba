"""sim.progress: a bar on a terminal, one line per stage elsewhere, nothing when disabled."""

from __future__ import annotations

import io
import re

import pytest

from sim.progress import StageLine, progress, stderr_is_terminal


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_off_a_terminal_a_stage_writes_one_line_when_closed(monkeypatch):
    err = io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    assert not stderr_is_terminal()
    stage = progress(range(23), desc="simulate wall", unit="frame", noun="frames")
    assert isinstance(stage, StageLine)
    assert list(stage) == list(range(23))
    bar = progress(desc="map", unit="ev", noun="events")
    bar.update(400_000)
    bar.update(12_000)
    bar.set_postfix_str("7 renders")
    assert err.getvalue().count("\n") == 1              # only the finished stage so far
    bar.close()
    bar.close()                                          # closing twice writes once
    lines = err.getvalue().splitlines()
    assert re.fullmatch(r"simulate wall: 23 frames in \d+\.\d s", lines[0]), lines
    assert re.fullmatch(r"map: 412,000 events, 7 renders in \d+\.\d s", lines[1]), lines
    assert len(lines) == 2 and "\r" not in err.getvalue()


def test_a_fractional_count_is_shown_to_the_millisecond(monkeypatch):
    err = io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    bar = progress(total=0.3, desc="events wall", unit="s", noun="s simulated")
    bar.n = 0.1234
    bar.close()
    assert err.getvalue().startswith("events wall: 0.123 s simulated in ")


@pytest.mark.parametrize("terminal", [False, True])
def test_disabled_writes_nothing_anywhere(terminal, monkeypatch):
    err = _Terminal() if terminal else io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    assert list(progress(range(5), desc="x", enabled=False)) == [0, 1, 2, 3, 4]
    bar = progress(desc="y", enabled=False)
    bar.update(3)
    bar.close()
    assert err.getvalue() == ""


def test_on_a_terminal_it_is_a_tqdm_bar(monkeypatch):
    from tqdm import tqdm

    err = _Terminal()
    monkeypatch.setattr("sys.stderr", err)
    assert stderr_is_terminal()
    bar = progress(range(3), desc="map", unit="ev")
    assert isinstance(bar, tqdm)
    assert list(bar) == [0, 1, 2]
    assert "\r" in err.getvalue() and "map" in err.getvalue()


def test_a_closed_stream_is_not_a_terminal():
    stream = io.StringIO()
    stream.close()
    assert not stderr_is_terminal(stream)
