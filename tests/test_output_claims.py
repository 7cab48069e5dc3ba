"""The output policy, part 2 (issue 39): one writer per output (a claim in ``<out>.partial``), a
``<out>.partial`` evfuse did not write is never deleted, what the final rename needs is checked
before any work, and ``overwrite`` refuses a folder holding files evfuse did not write."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading

import pytest

from sim.output import (
    CLAIM,
    MARKER,
    OutputError,
    atomic_output_dir,
    check_output_dir,
    partial_dir,
    write_marker,
)
from tests.conftest import WALL, run_cli, scene_text

SIMULATE = ["--no-events", "--no-motion-truth", "--spp", "1", "--quiet"]


def _claim(folder, pid: int) -> None:
    """A claim of ``pid`` on this host in ``folder``, as another evfuse process writes it."""
    (folder / CLAIM).write_text(json.dumps({
        "pid": pid, "host": socket.gethostname(), "command": "evfuse simulate",
        "argv": "evfuse simulate slider_far --duration 1 --out C", "started":
        "2026-11-29T03:50:00Z", "token": "someone-else"}))


@pytest.fixture
def live_pid():
    """The pid of a running process (not this one)."""
    process = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield process.pid
    process.kill()
    process.wait()


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def _one_line(capsys, code: int, *expected: str) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for text in expected:
        assert text in lines[0], lines[0]
    return lines[0]


# --- 2. one writer per output ------------------------------------------------------------------

def test_a_second_simulate_into_the_same_out_is_refused_naming_the_first(tmp_path, capsys,
                                                                         live_pid):
    (tmp_path / "s.toml").write_text(scene_text(WALL, duration=0.2))
    partial = tmp_path / "C.partial"
    partial.mkdir()
    write_marker(partial, "evfuse simulate")
    (partial / "frames").mkdir()
    (partial / "frames" / "000000.png").write_bytes(b"first writer's frame")
    _claim(partial, live_pid)
    code = run_cli(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "C"),
                    *SIMULATE])
    _one_line(capsys, code, "being written by evfuse simulate", f"pid {live_pid}",
              "started 2026-11-29T03:50:00Z", "--out C")
    assert (partial / "frames" / "000000.png").read_bytes() == b"first writer's frame"
    assert not (tmp_path / "C").exists()


def test_two_writers_in_one_process_are_two_writers(tmp_path):
    out = tmp_path / "out"
    inside, release, refused = threading.Event(), threading.Event(), []

    def first() -> None:
        with atomic_output_dir(out, command="evfuse first") as tmp:
            (tmp / "a.txt").write_text("first")
            inside.set()
            release.wait(10)

    thread = threading.Thread(target=first)
    thread.start()
    assert inside.wait(10)
    try:
        with atomic_output_dir(out, command="evfuse second") as tmp:
            (tmp / "a.txt").write_text("second")
    except OutputError as error:
        refused.append(str(error))
    release.set()
    thread.join(10)
    assert refused and "being written by evfuse first" in refused[0]
    assert (out / "a.txt").read_text() == "first" and not (out / CLAIM).exists()
    assert not partial_dir(out).exists()


def test_a_stale_claim_is_taken_over_by_resume(tmp_path):
    out = tmp_path / "out"
    partial = partial_dir(out)
    partial.mkdir()
    write_marker(partial, "evfuse simulate")
    (partial / "done.txt").write_text("kept")
    _claim(partial, _dead_pid())
    with atomic_output_dir(out, resume=True, command="evfuse simulate") as tmp:
        assert (tmp / "done.txt").read_text() == "kept"
        assert json.loads((tmp / CLAIM).read_text())["pid"] == os.getpid()
        (tmp / "more.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "done.txt", "more.txt"]


def test_a_claim_from_another_host_is_refused_with_how_to_proceed(tmp_path):
    partial = partial_dir(tmp_path / "out")
    partial.mkdir()
    write_marker(partial)
    (partial / CLAIM).write_text(json.dumps({"pid": 1, "host": "elsewhere.invalid",
                                             "command": "evfuse generate"}))
    with pytest.raises(OutputError, match="on another host.*delete .*evfuse-claim"):
        check_output_dir(tmp_path / "out")


# --- 4. a <out>.partial evfuse did not write ----------------------------------------------------

@pytest.mark.parametrize("kind", ["file", "link"])
def test_a_users_file_named_out_partial_is_never_deleted(tmp_path, capsys, kind):
    (tmp_path / "s.toml").write_text(scene_text(WALL, duration=0.2))
    partial = tmp_path / "C.partial"
    if kind == "file":
        partial.write_text("my thesis")
    else:
        (tmp_path / "target.txt").write_text("my thesis")
        partial.symlink_to(tmp_path / "target.txt")
    code = run_cli(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "C"),
                    *SIMULATE])
    _one_line(capsys, code, "C.partial", "evfuse did not write", "does not delete it")
    assert partial.read_text() == "my thesis" and partial.is_symlink() == (kind == "link")


def test_a_users_folder_named_out_partial_is_never_deleted(tmp_path):
    partial = partial_dir(tmp_path / "out")
    partial.mkdir()
    (partial / "mine.txt").write_text("mine")
    with pytest.raises(OutputError, match="not written by evfuse"):
        with atomic_output_dir(tmp_path / "out"):
            pass
    assert (partial / "mine.txt").read_text() == "mine"


# --- 3. what the final rename needs, checked first ----------------------------------------------

def test_out_a_mount_point_is_refused_before_any_work(tmp_path, monkeypatch):
    mount = tmp_path / "mnt"
    mount.mkdir()
    real_ismount = os.path.ismount
    monkeypatch.setattr(os.path, "ismount", lambda p: os.fspath(p) == os.fspath(mount)
                        or real_ismount(p))
    with pytest.raises(OutputError, match="is a mount point"):
        check_output_dir(mount)


@pytest.mark.parametrize("out", ["..", ".", "../.."])
def test_out_the_current_folder_or_an_ancestor_is_refused(tmp_path, monkeypatch, capsys, out):
    inner = tmp_path / "work" / "P1" / "sequence"
    inner.mkdir(parents=True)
    write_marker(tmp_path / "work" / "P1", "evfuse run")
    write_marker(tmp_path / "work", "evfuse run")
    (tmp_path / "s.toml").write_text(scene_text(WALL, duration=0.2))
    monkeypatch.chdir(inner)
    code = run_cli(["simulate", str(tmp_path / "s.toml"), "--out", out, "--overwrite",
                    *SIMULATE])
    _one_line(capsys, code, "current folder", "choose another --out")
    assert inner.is_dir() and not any(tmp_path.glob("**/*.partial"))


def test_an_unwritable_parent_is_refused_before_any_work(tmp_path, monkeypatch):
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: os.fspath(p) != os.fspath(tmp_path)
                        and real_access(p, mode, **kw))
    with pytest.raises(OutputError, match=f"cannot write into {tmp_path}"):
        check_output_dir(tmp_path / "new" / "out")


# --- 9. overwrite and the files evfuse did not write --------------------------------------------

def _write(out, **kwargs) -> None:
    with atomic_output_dir(out, command="evfuse test", **kwargs) as tmp:
        (tmp / "P1").mkdir()
        (tmp / "P1" / "depth.exr").write_bytes(b"depth")
        (tmp / "map.json").write_text("{}")


def test_overwrite_refuses_a_folder_holding_files_evfuse_did_not_write(tmp_path):
    out = tmp_path / "out"
    _write(out)
    assert json.loads((out / MARKER).read_text())["files"] == ["P1/depth.exr", "map.json"]
    (out / "P1" / "notes.txt").write_text("my notes")
    with pytest.raises(OutputError, match=r"holds 1 file evfuse did not write \(P1/notes.txt\)"):
        _write(out, overwrite=True)
    assert (out / "P1" / "notes.txt").read_text() == "my notes"
    (out / "P1" / "notes.txt").unlink()
    _write(out, overwrite=True)                              # only its own files: replaced


def test_a_marker_without_a_file_list_is_replaced_as_before(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    write_marker(out, "evfuse 0.2.0")                        # no "files": an older version's
    (out / "anything.txt").write_text("x")
    _write(out, overwrite=True)
    assert not (out / "anything.txt").exists()


# --- 8. bench's cache folder ---------------------------------------------------------------------

def test_bench_refuses_a_cache_inside_an_input_map_folder(tmp_path, capsys):
    from tests.conftest import tree_hashes

    mine = tmp_path / "mymap"
    mine.mkdir()
    (mine / "map.json").write_text(json.dumps({"sequence": "../seq"}))
    before = tree_hashes(mine)
    code = run_cli(["bench", "--scenes", str(mine), "--cache", str(mine / "cache"), "--out",
                    str(tmp_path / "B"), "--quiet"])
    _one_line(capsys, code, "cache folder", "lies inside the input", "--cache")
    assert tree_hashes(mine) == before and sorted(p.name for p in mine.iterdir()) == ["map.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mymap"]


def test_a_bench_cache_is_marked_and_a_refused_bench_leaves_none(tmp_path):
    from fusion.experiments.bench import bench

    cache = tmp_path / "B-cache"
    with pytest.raises(ValueError):
        bench(["nearest"], [str(tmp_path / "nomap")], ["oracle"], cache, progress=False)
    (tmp_path / "nomap").mkdir()
    (tmp_path / "nomap" / "map.json").write_text("{}")          # accepted, then refused
    with pytest.raises(Exception):                                # noqa: B017 (any refusal)
        bench(["nearest"], [str(tmp_path / "nomap")], ["oracle"], cache, progress=False)
    assert not cache.exists()
    (cache / "kept").mkdir(parents=True)
    with pytest.raises(Exception):                                # noqa: B017
        bench(["nearest"], [str(tmp_path / "nomap")], ["oracle"], cache, progress=False)
    assert json.loads((cache / MARKER).read_text())["command"] == "evfuse bench (cache)"


def test_a_second_generate_into_a_dataset_being_filled_is_refused(tmp_path, live_pid):
    from sim.dataset import generate
    from tests.test_generate import TINY

    out = tmp_path / "D"
    out.mkdir()
    write_marker(out, "evfuse generate")
    (out / "sweep.toml").write_bytes(TINY.read_bytes())
    _claim(out, live_pid)
    for kwargs in ({"resume": True}, {"overwrite": True}):
        with pytest.raises(OutputError, match=f"being written by evfuse simulate .pid {live_pid}"):
            generate(TINY, out, workers=0, report=lambda line: None, **kwargs)
    assert sorted(p.name for p in out.iterdir()) == sorted([CLAIM, MARKER, "sweep.toml"])
