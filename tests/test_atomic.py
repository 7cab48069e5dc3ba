"""The one single-file atomic write (:func:`sim._atomic.atomic_file`, issue 22): written under
``<name>.partial``, renamed into place only when complete, the partial file removed on failure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sim.flow
from sim._atomic import PARTIAL_SUFFIX, atomic_file, write_bytes_atomically


class _Boom(Exception):
    pass


def test_atomic_file_leaves_no_partial_and_keeps_the_old_file_when_the_body_raises(tmp_path):
    path = tmp_path / "out.bin"
    path.write_bytes(b"old")
    with pytest.raises(_Boom), atomic_file(path) as partial:
        assert partial == tmp_path / ("out.bin" + PARTIAL_SUFFIX)
        partial.write_bytes(b"half")
        assert path.read_bytes() == b"old"          # never half-written under the final name
        raise _Boom
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]
    assert path.read_bytes() == b"old"


def test_atomic_file_renames_the_complete_file_into_place(tmp_path):
    path = tmp_path / "out.bin"
    path.write_bytes(b"old")
    write_bytes_atomically(path, b"\x00new\xff")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]
    assert path.read_bytes() == b"\x00new\xff"


def test_atomic_file_removes_the_partial_when_the_fsync_fails(tmp_path, monkeypatch):
    def fail(fd):
        raise OSError("disk full")

    monkeypatch.setattr("os.fsync", fail)
    with pytest.raises(OSError, match="disk full"):
        write_bytes_atomically(tmp_path / "out.bin", b"data")
    assert list(tmp_path.iterdir()) == []


def test_flow_exr_writer_leaves_no_temporary_file_when_writing_fails(tmp_path, monkeypatch):
    """The flow/motion EXR writer left ``<name>.tmp`` behind when the EXR writer raised."""
    def half_write(path, channels):
        Path(path).write_bytes(b"half an EXR")
        raise OSError(f"{path}: cannot write")

    monkeypatch.setattr(sim.flow, "write_exr_channels", half_write)
    target = tmp_path / "forward_00000000.exr"
    with pytest.raises(OSError, match="cannot write"):
        sim.flow._write_exr(target, {"du": np.zeros((2, 2), np.float32)})
    assert list(tmp_path.iterdir()) == []


def test_figures_write_image_goes_through_the_one_policy_with_the_same_bytes(tmp_path,
                                                                            monkeypatch):
    """``write_image`` had its own style (``.<stem>.partial<ext>``, no fsync): it now writes
    ``<name>.partial``, syncs it, and writes the bytes ``cv2.imwrite`` writes with evfuse's
    ``Software`` chunk after the header (:func:`sim.image_out.mark_png`)."""
    import os

    import cv2

    from fusion.figures import write_image

    image = np.random.default_rng(3).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    reference = tmp_path / "reference.png"
    assert cv2.imwrite(str(reference), image)
    synced = []
    real_fsync = os.fsync

    def fsync(fd):
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        real_fsync(fd)

    monkeypatch.setattr("os.fsync", fsync)
    target = tmp_path / "figure.png"
    write_image(target, image)
    assert synced == [str(tmp_path / ("figure.png" + PARTIAL_SUFFIX))]
    from sim.image_out import is_evfuse_png, mark_png

    assert target.read_bytes() == mark_png(reference.read_bytes())
    assert is_evfuse_png(target) and not is_evfuse_png(reference)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure.png", "reference.png"]
