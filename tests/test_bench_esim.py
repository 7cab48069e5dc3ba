"""benchmarks/bench_esim.py's helpers: the events check and finding esim_py (the timing itself
needs esim_py, built outside the repository, and is never asserted)."""

from __future__ import annotations

import sys

import numpy as np

from benchmarks.bench_esim import compare, find_esim
from sim.eventio import EVENT_DTYPE


def _pair():
    events = np.zeros(4, EVENT_DTYPE)
    events["t"] = [1_000, 2_000, 2_000, 5_000]
    events["x"], events["y"], events["p"] = [3, 1, 2, 3], [0, 1, 1, 0], [1, -1, 1, -1]
    esim = np.stack([events["x"], events["y"], events["t"] * 1e-9, events["p"]],
                    axis=1).astype(np.float64)
    return esim[::-1].copy(), events                  # esim_py's order is its own


def test_the_same_events_in_another_order_and_float_times_compare_equal():
    esim, events = _pair()
    esim[0, 2] += 40e-9                               # a crossing time 40 ns away
    check = compare(esim, events)
    assert check["same_pixels_and_polarities"]
    assert check["max_time_difference_ns"] == 40 and check["events_over_1us_apart"] == 0


def test_a_different_polarity_count_or_time_is_reported():
    esim, events = _pair()
    esim[1, 3] = -esim[1, 3]
    assert not compare(esim, events)["same_pixels_and_polarities"]
    check = compare(esim[1:], events)
    assert not check["same_pixels_and_polarities"] and check["max_time_difference_ns"] is None
    esim, events = _pair()
    esim[2, 2] += 3e-6
    assert compare(esim, events)["events_over_1us_apart"] == 1


def test_without_esim_py_the_reason_is_given(tmp_path, monkeypatch):
    monkeypatch.delenv("ESIM_PY", raising=False)
    monkeypatch.delenv("ANCHORS", raising=False)
    monkeypatch.setattr(sys, "path", list(sys.path))
    module, why = find_esim(None)
    assert module is None and "--esim DIR" in why
    module, why = find_esim(str(tmp_path))
    assert module is None and str(tmp_path) in why
