"""The event stage's checkpoints are written in the background (issue 36: at 1280x720 they cost a
fifth of a GPU run written in line): the simulation goes on while one is written, a kill in the
middle of a write leaves the previous checkpoint complete, and the resumed run's files are the
uninterrupted run's, byte for byte."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from sim.shader import EventShader
from tests.test_resume import _assert_same_sequence, _simulate

checkpoints = importlib.import_module("sim.simulate._checkpoint")
ROOT = Path(__file__).resolve().parents[1]


def test_a_background_write_returns_at_once_and_lands_whole(tmp_path):
    path = tmp_path / "state.npz"
    path.write_bytes(b"old")
    release, started = threading.Event(), threading.Event()

    def write(handle):
        handle.write(b"new, first half ")
        started.set()
        assert release.wait(30)
        handle.write(b"and second half")

    writes = checkpoints._BackgroundWrite()
    writes.submit(path, write)
    assert started.wait(30)
    assert writes.busy                                   # submit returned mid-write
    assert path.read_bytes() == b"old"                   # the old file is whole meanwhile
    assert (tmp_path / "state.npz.partial").is_file()
    release.set()
    writes.wait()
    assert not writes.busy
    assert path.read_bytes() == b"new, first half and second half"
    assert not (tmp_path / "state.npz.partial").exists()


def test_a_failed_background_write_is_raised_and_leaves_the_old_file(tmp_path):
    path = tmp_path / "state.npz"
    path.write_bytes(b"old")

    def failing(handle):
        handle.write(b"half")
        raise OSError("No space left on device")

    writes = checkpoints._BackgroundWrite()
    writes.submit(path, failing)
    with pytest.raises(OSError, match="No space left"):
        writes.submit(path, lambda handle: handle.write(b"next"))    # raised, not lost
    assert path.read_bytes() == b"old" and not (tmp_path / "state.npz.partial").exists()
    writes.submit(path, lambda handle: handle.write(b"next"))
    writes.wait()
    assert path.read_bytes() == b"next"


def test_the_simulation_renders_on_while_a_checkpoint_is_written(tmp_path, monkeypatch):
    """The first checkpoint's write waits until the event camera has rendered after the
    checkpoint was handed over: it can only finish if the simulation did not wait for it (an
    in-line write would hold the render back, and the wait would time out). A render always
    comes between two checkpoints (one is taken only after a step with no pending tail)."""
    renders, handed_over, seen = [0], [], []
    rendered = threading.Condition()
    real_frame, real_savez = EventShader.frame, np.savez
    real_submit = checkpoints._BackgroundWrite.submit

    def frame(shader, t):
        with rendered:
            renders[0] += 1
            rendered.notify_all()
        return real_frame(shader, t)

    def submit(writes, path, write):
        handed_over.append(renders[0])
        return real_submit(writes, path, write)

    def savez(handle, **arrays):
        if not seen:
            with rendered:
                seen.append(rendered.wait_for(lambda: renders[0] > handed_over[0], 60))
        return real_savez(handle, **arrays)

    monkeypatch.setattr(checkpoints, "CHECKPOINT_SAMPLES", 1)
    monkeypatch.setattr(EventShader, "frame", frame)
    monkeypatch.setattr(checkpoints._BackgroundWrite, "submit", submit)
    monkeypatch.setattr(checkpoints.np, "savez", savez)
    result = _simulate(tmp_path / "seq")
    assert result.n_events > 5000
    assert seen == [True]


_KILLED_MID_WRITE = """
import io, os, pathlib, signal, sys, threading, time
import numpy as np
from sim.shader import EventShader
from tests.test_resume import _simulate, checkpoints
checkpoints.CHECKPOINT_SAMPLES = 1
real_savez, real_frame, real_wait = np.savez, EventShader.frame, checkpoints._BackgroundWrite.wait
calls, torn = [], threading.Event()

def savez(handle, **arrays):
    calls.append(1)
    if len(calls) < 4:
        return real_savez(handle, **arrays)
    whole = io.BytesIO()
    real_savez(whole, **arrays)
    handle.write(whole.getvalue()[:len(whole.getvalue()) // 2])   # half of the 4th checkpoint
    handle.flush()
    torn.set()
    time.sleep(120)

def killed_if_torn(real):       # the simulation's next render or wait: killed there
    def call(*args):
        if torn.is_set():
            os.kill(os.getpid(), signal.SIGKILL)
        return real(*args)
    return call

checkpoints.np.savez = savez
EventShader.frame = killed_if_torn(real_frame)
checkpoints._BackgroundWrite.wait = killed_if_torn(real_wait)
_simulate(pathlib.Path(sys.argv[1]))
"""


def test_a_kill_while_a_checkpoint_is_written_resumes_to_the_uninterrupted_files(tmp_path):
    """SIGKILL in the middle of the 4th checkpoint's write, while the simulation goes on: the
    3rd is on disk, whole; the torn one only under its temporary name; the resumed run equals
    an uninterrupted one. (The kill lands in a render or a wait, outside the event files: a
    SIGKILL inside an HDF5 write can leave ``events.h5.partial`` unreadable, with or without
    background checkpoints.)"""
    whole = _simulate(tmp_path / "whole")
    out = tmp_path / "cut"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get(
        "PYTHONPATH", "")])}
    child = subprocess.run([sys.executable, "-c", _KILLED_MID_WRITE, str(out)], cwd=ROOT,
                           env=env, capture_output=True, text=True, timeout=600)
    assert child.returncode == -9, child.stderr[-2000:]
    state = tmp_path / "cut.partial" / ".checkpoint"
    assert (state / "events.npz.partial").is_file()                  # the torn write
    with np.load(state / "events.npz") as saved:                     # the one before, whole
        sample_t = json.loads(str(saved["state"]))["sample"]["t"]
        assert saved["emulator_ref"].shape == (48, 64)
    assert 0 < sample_t < 0.12
    assert not out.exists()
    result = _simulate(out, resume=True)
    assert result.n_events == whole.n_events
    _assert_same_sequence(tmp_path / "whole", out)
