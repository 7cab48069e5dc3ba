"""sim.sequence: atomic output folders, index files, sequence.json and load_sequence."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from sim.exr import write_depth
from sim.output import CLAIM, MARKER, atomic_output_dir
from sim.sequence import (
    frame_name,
    load_sequence,
    read_index,
    read_sequence_json,
    write_index,
    write_sequence_json,
)

CALIB = "60.0 45.0 30.3 22.7 -0.1 0.01 0.001 -0.002 0.0\n"


# --- atomic_output_dir -----------------------------------------------------------------------

def test_success_renames_partial_into_place(tmp_path):
    out = tmp_path / "deep" / "er" / "seq"                # parents are created
    with atomic_output_dir(out) as tmp:
        assert tmp == tmp_path / "deep" / "er" / "seq.partial"
        assert tmp.is_dir() and sorted(p.name for p in tmp.iterdir()) == [MARKER, CLAIM]
        assert not out.exists()                           # nothing visible while writing
        (tmp / "a.txt").write_text("new")
    assert (out / "a.txt").read_text() == "new"
    marker = json.loads((out / MARKER).read_text())       # evfuse's own folder, so marked
    assert marker["written_by"] == "evfuse" and marker["version"]
    assert not tmp.exists()


def test_exception_leaves_no_output_and_no_partial(tmp_path):
    out = tmp_path / "seq"
    with pytest.raises(RuntimeError, match="boom"), atomic_output_dir(out) as tmp:
        (tmp / "half.txt").write_text("half")
        raise RuntimeError("boom")
    assert not any(tmp_path.iterdir())


def test_a_resumable_writer_keeps_its_partial_but_never_an_empty_one(tmp_path):
    out = tmp_path / "seq"
    with pytest.raises(RuntimeError), atomic_output_dir(out, keep_failed=True) as tmp:
        (tmp / "half.txt").write_text("half")
        raise RuntimeError("boom")
    assert not out.exists()
    assert (tmp_path / "seq.partial" / "half.txt").read_text() == "half"
    other = tmp_path / "other"
    with pytest.raises(RuntimeError), atomic_output_dir(other, keep_failed=True) as tmp:
        (tmp / "empty").mkdir()
        raise RuntimeError("boom")
    assert not (tmp_path / "other.partial").exists()


def test_refuses_to_overwrite_a_non_empty_folder(tmp_path):
    out = tmp_path / "seq"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with pytest.raises(ValueError, match=r"seq exists and is not empty.*overwrite=True"), \
            atomic_output_dir(out):
        pytest.fail("the body must not run")
    assert (out / "old.txt").read_text() == "old"
    assert not (tmp_path / "seq.partial").exists()


def test_an_existing_empty_folder_is_fine_without_overwrite(tmp_path):
    out = tmp_path / "seq"
    out.mkdir()
    with atomic_output_dir(out) as tmp:
        (tmp / "a.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "a.txt"]


def test_a_file_in_the_way_is_never_replaced(tmp_path):
    out = tmp_path / "seq"
    out.write_text("precious")
    with pytest.raises(ValueError, match="is not a folder"), \
            atomic_output_dir(out, overwrite=True):
        pytest.fail("the body must not run")
    assert out.read_text() == "precious"


def _evfuse_folder(out):
    """A folder as evfuse leaves it: written through atomic_output_dir, with ``old.txt``."""
    with atomic_output_dir(out) as tmp:
        (tmp / "old.txt").write_text("old")
    return out


def test_overwrite_replaces_only_after_success(tmp_path):
    out = _evfuse_folder(tmp_path / "seq")
    with atomic_output_dir(out, overwrite=True) as tmp:
        assert (out / "old.txt").read_text() == "old"     # still intact while writing
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]   # no aside copy left


def test_overwrite_keeps_the_old_folder_when_the_new_one_fails(tmp_path):
    out = _evfuse_folder(tmp_path / "seq")
    with pytest.raises(KeyboardInterrupt), \
            atomic_output_dir(out, overwrite=True, keep_failed=True) as tmp:
        (tmp / "new.txt").write_text("new")
        raise KeyboardInterrupt
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "old.txt"]
    assert (tmp_path / "seq.partial" / "new.txt").exists()


def test_a_stale_partial_folder_is_cleared_first(tmp_path):
    stale = tmp_path / "seq.partial"
    with pytest.raises(KeyboardInterrupt), \
            atomic_output_dir(tmp_path / "seq", keep_failed=True) as tmp:
        (tmp / "junk.txt").write_text("junk")
        raise KeyboardInterrupt
    assert (stale / "junk.txt").is_file()
    with atomic_output_dir(tmp_path / "seq") as tmp:
        assert tmp == stale and sorted(p.name for p in tmp.iterdir()) == [MARKER, CLAIM]
        (tmp / "a.txt").write_text("a")
    assert sorted(p.name for p in (tmp_path / "seq").iterdir()) == [MARKER, "a.txt"]


# --- index files -----------------------------------------------------------------------------

def test_frame_names_follow_the_ecd_layout():
    assert frame_name(0, "png") == "images/frame_00000000.png"
    assert frame_name(12, ".exr") == "depth/frame_00000012.exr"
    assert frame_name(np.int64(123456789), "PNG") == "images/frame_123456789.png"
    with pytest.raises(ValueError, match=r"one of \['exr', 'png'\], got 'jpg'"):
        frame_name(0, "jpg")
    with pytest.raises(ValueError, match=">= 0, got -1"):
        frame_name(-1, "png")


def test_index_round_trip_in_ecd_format(tmp_path):
    (tmp_path / "images").mkdir()
    names = [frame_name(i, "png") for i in range(3)]
    for name in names:
        (tmp_path / name).write_bytes(b"")
    times = np.array([0.0, 1.0 / 3.0, 0.077531001])[[0, 2, 1]]
    write_index(tmp_path / "images.txt", times, names)
    # the same text as the real ECD images.txt: 9 decimals, one space, relative name
    assert (tmp_path / "images.txt").read_text().splitlines() == [
        "0.000000000 images/frame_00000000.png",
        "0.077531001 images/frame_00000001.png",
        "0.333333333 images/frame_00000002.png",
    ]
    back, relpaths = read_index(tmp_path / "images.txt")
    assert back.dtype == np.float64 and relpaths == names
    np.testing.assert_allclose(back, times, rtol=0, atol=0.5e-9)   # rounded to the nanosecond


def test_index_skips_blank_and_comment_lines_but_counts_them(tmp_path):
    (tmp_path / "a.png").write_bytes(b"")
    path = tmp_path / "images.txt"
    path.write_text("# t name\n\n0.5 a.png\n0.25 a.png\n")
    with pytest.raises(ValueError, match=r"images\.txt:4: time 0\.25 is not after"):
        read_index(path)


@pytest.mark.parametrize(("second_line", "message"), [
    ("0.1", r"images\.txt:2: expected 2 columns.*got 1"),
    ("0.1 b.png extra", r"images\.txt:2: expected 2 columns.*got 3"),
    ("0,1 b.png", r"images\.txt:2: expected a time in seconds, got '0,1'"),
    ("nan b.png", r"images\.txt:2: expected a finite time"),
    ("0.05 b.png", r"images\.txt:2: time 0\.05 is not after the previous line's 0\.050000000"),
    ("0.01 b.png", r"images\.txt:2: time 0\.01 is not after"),
    ("0.1 c.png", r"images\.txt:2: listed file .*c\.png does not exist"),
])
def test_malformed_index_lines_name_file_and_line(tmp_path, second_line, message):
    (tmp_path / "a.png").write_bytes(b"")
    (tmp_path / "b.png").write_bytes(b"")
    path = tmp_path / "images.txt"
    path.write_text(f"0.05 a.png\n{second_line}\n")
    with pytest.raises(ValueError, match=message):
        read_index(path)


def test_index_without_file_check_and_missing_index(tmp_path):
    path = tmp_path / "depthmaps.txt"
    path.write_text("1.0 depth/frame_00000000.exr\n")
    times, names = read_index(path, check_files=False)
    assert times.tolist() == [1.0] and names == ["depth/frame_00000000.exr"]
    with pytest.raises(ValueError, match=r"nothing\.txt does not exist"):
        read_index(tmp_path / "nothing.txt")


def test_write_index_rejects_bad_input(tmp_path):
    path = tmp_path / "i.txt"
    with pytest.raises(ValueError, match="2 times but 1 file names"):
        write_index(path, [0.0, 1.0], ["a.png"])
    with pytest.raises(ValueError, match="strictly increasing"):
        write_index(path, [0.0, 0.0], ["a.png", "b.png"])
    with pytest.raises(ValueError, match="strictly increasing"):       # equal once rounded
        write_index(path, [0.0, 1e-10], ["a.png", "b.png"])
    with pytest.raises(ValueError, match="finite"):
        write_index(path, [np.nan], ["a.png"])
    with pytest.raises(ValueError, match="without whitespace"):
        write_index(path, [0.0], ["my frame.png"])
    assert not path.exists()


# --- sequence.json ---------------------------------------------------------------------------

def test_sequence_json_converts_numpy_and_sorts_keys(tmp_path):
    path = tmp_path / "sequence.json"
    write_sequence_json(path, {"seed": np.int64(3), "b": {"z": np.float32(0.5), "a": None},
                               "size": np.array([64, 48]), "flag": np.bool_(True),
                               "where": tmp_path / "x"})
    text = path.read_text()
    assert text.startswith('{\n  "b": {\n    "a": null,\n    "z": 0.5\n  },\n  "flag": true,')
    data = read_sequence_json(path)
    assert data == {"seed": 3, "b": {"a": None, "z": 0.5}, "size": [64, 48], "flag": True,
                    "where": str(tmp_path / "x")}
    assert json.loads(text) == data


def test_sequence_json_errors(tmp_path):
    path = tmp_path / "s.json"
    with pytest.raises(ValueError, match="cannot write a object"):
        write_sequence_json(path, {"thing": object()})
    path.write_text('{\n  "a": 1,\n  "b": oops\n}\n')
    with pytest.raises(ValueError, match=r"s\.json:3: invalid JSON"):
        read_sequence_json(path)
    path.write_text("[1, 2]\n")
    with pytest.raises(ValueError, match="expected a JSON object"):
        read_sequence_json(path)


# --- load_sequence ---------------------------------------------------------------------------

def _ecd_like_folder(root, n=3, width=64, height=48):
    """A minimal ECD-layout folder: calib.txt, n frames of height x width, their index."""
    root.mkdir()
    (root / "calib.txt").write_text(CALIB)
    (root / "images").mkdir()
    names = [frame_name(i, "png") for i in range(n)]
    for i, name in enumerate(names):
        assert cv2.imwrite(str(root / name), np.full((height, width), 10 * i, np.uint8))
    times = 0.005 + np.arange(n) / 24.0
    write_index(root / "images.txt", times, names)
    return times


def test_load_sequence_ecd_layout_without_depth(tmp_path):
    root = tmp_path / "seq"
    times = _ecd_like_folder(root)
    (root / "groundtruth.txt").write_text("0.0 0 0 0 0 0 0 1\n")
    (root / "events.txt").write_text("0.001 1 2 1\n")
    seq = load_sequence(root)
    assert seq.folder == root
    assert (seq.camera.width, seq.camera.height) == (64, 48)   # the 48-row, 64-column frame
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy) == (60.0, 45.0, 30.3, 22.7)
    np.testing.assert_allclose(seq.image_times, times, atol=0.5e-9)
    assert seq.image_paths == tuple(root / frame_name(i, "png") for i in range(3))
    assert seq.depth_times is None and seq.depth_paths is None and seq.metadata is None
    assert seq.groundtruth_path == root / "groundtruth.txt"
    assert seq.events_txt == root / "events.txt" and seq.events_h5 is None
    with pytest.raises(ValueError, match="read-only"):
        seq.image_times[0] = 1.0


def test_load_sequence_simulated_layout_with_depth_and_json(tmp_path):
    root = tmp_path / "sim"
    times = _ecd_like_folder(root, n=2)
    (root / "depth").mkdir()
    names = [frame_name(i, "exr") for i in range(2)]
    for name in names:
        write_depth(root / name, np.ones((48, 64), np.float32))
    write_index(root / "depthmaps.txt", times, names)
    (root / "events.h5").write_bytes(b"")
    write_sequence_json(root / "sequence.json", {"seed": 5, "camera": {"width": 64,
                                                                        "height": 48}})
    seq = load_sequence(str(root))
    np.testing.assert_array_equal(seq.depth_times, seq.image_times)
    assert seq.depth_paths == (root / names[0], root / names[1])
    assert seq.metadata["seed"] == 5
    assert seq.events_h5 == root / "events.h5" and seq.events_txt is None
    assert seq.groundtruth_path is None


def test_sensor_size_comes_from_sequence_json_first(tmp_path):
    root = tmp_path / "seq"
    root.mkdir()
    (root / "calib.txt").write_text(CALIB)
    (root / "images.txt").write_text("")                  # no frame to measure
    write_sequence_json(root / "sequence.json", {"camera": {"width": 32, "height": 24}})
    seq = load_sequence(root)
    assert (seq.camera.width, seq.camera.height) == (32, 24) and len(seq.image_paths) == 0
    (root / "sequence.json").unlink()
    with pytest.raises(ValueError, match="sensor size is unknown"):
        load_sequence(root)


def test_load_sequence_errors_name_the_path(tmp_path):
    with pytest.raises(ValueError, match=r"nowhere does not exist"):
        load_sequence(tmp_path / "nowhere")
    root = tmp_path / "seq"
    root.mkdir()
    (root / "calib.txt").write_text(CALIB)
    with pytest.raises(ValueError, match=r"seq has no images\.txt"):
        load_sequence(root)
    (root / "images.txt").write_text("0.0 images/frame_00000000.png\n")
    with pytest.raises(ValueError, match=r"images\.txt:1: listed file .* does not exist"):
        load_sequence(root)


def test_load_sequence_on_the_real_ecd_folder(ecd_slider):
    seq = load_sequence(ecd_slider)
    # facts from the folder's README.md and its text files, not from this code
    assert (seq.camera.width, seq.camera.height) == (240, 180)
    assert len(seq.image_paths) == 87 and seq.image_times.shape == (87,)
    assert seq.image_times[0] == 0.0 and seq.image_times[-1] == pytest.approx(3.333822, abs=1e-9)
    assert seq.image_paths[-1] == ecd_slider / "images" / "frame_00000086.png"
    assert seq.camera.fx == pytest.approx(335.419462958)
    assert seq.camera.cy == pytest.approx(99.1864303447)
    assert seq.depth_times is None and seq.depth_paths is None and seq.metadata is None
    assert seq.groundtruth_path == ecd_slider / "groundtruth.txt"
    assert seq.events_txt == ecd_slider / "events.txt" and seq.events_h5 is None


def test_nearest_frame_and_depth_map(tmp_path):
    """Frames at 0.005 + i / 24 s: the nearest by hand, ties to the earlier frame."""
    root = tmp_path / "sim"
    times = _ecd_like_folder(root, n=3)
    seq = load_sequence(root)
    assert seq.nearest_depth(times[0]) is None                     # no depth maps: real data
    assert [seq.nearest_frame(t) for t in (-5.0, 0.0, 0.03, 0.06, 0.07, 9.0)] == [0, 0, 1, 1, 2, 2]
    assert seq.nearest_frame(0.5 * (times[0] + times[1])) == 0     # half-way: the earlier
    (root / "depth").mkdir()
    names = [frame_name(i, "exr") for i in range(3)]
    for name in names:
        write_depth(root / name, np.ones((48, 64), np.float32))
    write_index(root / "depthmaps.txt", times, names)
    seq = load_sequence(root)
    assert seq.nearest_depth(float(times[1])) == 1
    assert seq.nearest_depth(float(times[1]) + 0.5e-6) == 1        # within EXACT_TIME_S
    assert seq.nearest_depth(float(times[1]) + 0.01) is None       # not the same instant
    assert seq.nearest_depth(float(times[1]) + 0.01, tolerance=math.inf) == 1
    with pytest.raises(ValueError, match="finite"):
        seq.nearest_frame(float("nan"))
    (root / "images.txt").write_text("")
    write_sequence_json(root / "sequence.json", {"camera": {"width": 64, "height": 48}})
    with pytest.raises(ValueError, match=r"images\.txt lists no frames"):
        load_sequence(root).nearest_frame(0.0)


def test_partial_suffix_is_defined_once():
    # One suffix for everything written under a temporary name (output folders, event files):
    # defined in one module, imported by the others.
    import ast

    import sim.eventio
    import sim.output

    root = Path(__file__).resolve().parent.parent
    definitions = []
    for package in ("sim", "fusion", "scenes"):
        for path in sorted((root / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                targets = node.targets if isinstance(node, ast.Assign) else (
                    [node.target] if isinstance(node, ast.AnnAssign) else [])
                if any(isinstance(t, ast.Name) and t.id == "PARTIAL_SUFFIX" for t in targets):
                    definitions.append(f"{path.relative_to(root)}:{node.lineno}")
    assert len(definitions) == 1, definitions
    assert sim.eventio.PARTIAL_SUFFIX is sim.output.PARTIAL_SUFFIX


def test_both_json_writers_write_an_undefined_figure_as_null(tmp_path):
    # One policy for every JSON file evfuse writes: strict JSON has no NaN, so an undefined
    # figure (an error over no pixel) is null, with its coverage beside it, in sequence.json as
    # in map.json / fill.json; no NaN or Infinity token, no refusal of one writer only.
    from fusion.io import to_json

    document = {"mae_cm": float("nan"), "coverage": 0.0, "n_pixels": np.int64(0),
                "per_class": {"far": np.float32("nan"), "near": np.float64(1.5)},
                "errors": np.array([1.0, np.inf, -np.inf]), "bounds": (np.nan, 2)}
    expected = {"mae_cm": None, "coverage": 0.0, "n_pixels": 0,
                "per_class": {"far": None, "near": 1.5}, "errors": [1.0, None, None],
                "bounds": [None, 2]}
    path = tmp_path / "s.json"
    write_sequence_json(path, document)
    written = path.read_text(encoding="utf-8")
    assert "NaN" not in written and "Infinity" not in written
    assert json.loads(written) == expected == read_sequence_json(path)
    assert to_json(document) == written                    # the same bytes from both writers
