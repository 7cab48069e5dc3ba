"""The faults that fuzzing found (issue 21), each pinned by the smallest case.

Every refusal is one line naming the file (and the line or event); see tests/test_fuzz.py for
the property-based search that found them.
"""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from sim.camera import read_calib
from sim.eventio import H5EventWriter, make_events, read_events, read_window
from sim.sequence import read_index, read_sequence_json
from sim.trajectory import read_trajectory


def write_h5(path, t_ns, width=64, height=48, chunk_size=256):
    n = len(t_ns)
    events = make_events(np.asarray(t_ns, np.int64), np.arange(n) % width,
                         np.arange(n) % height, np.where(np.arange(n) % 2, 1, -1))
    with H5EventWriter(path, width, height, chunk_size=chunk_size) as writer:
        writer.write(events)
    return events


def one_line(exc_info) -> str:
    message = str(exc_info.value)
    assert "\n" not in message
    return message


# --- text files that are not UTF-8 ------------------------------------------------------------

@pytest.mark.parametrize(("name", "read"), [
    ("calib.txt", lambda p: read_calib(p, 240, 180)),
    ("groundtruth.txt", read_trajectory),
    ("images.txt", lambda p: read_index(p, check_files=False)),
])
def test_bytes_that_are_not_utf8_are_named_by_file_and_line(tmp_path, name, read):
    path = tmp_path / name
    path.write_bytes(b"# a comment\n\n1.0 2\xff.0 3 4\n")
    with pytest.raises(ValueError) as exc_info:
        read(path)
    assert one_line(exc_info).startswith(f"{path}:3: not UTF-8 text (byte 0xff at column 6)")


def test_sequence_json_that_is_not_utf8_names_the_file(tmp_path):
    path = tmp_path / "sequence.json"
    path.write_bytes(b'{"a": "\xff"}')
    with pytest.raises(ValueError, match=r"^" + str(path) + r": not UTF-8 text"):
        read_sequence_json(path)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_sequence_json_refuses_non_finite_numbers_naming_the_line(tmp_path, literal):
    path = tmp_path / "sequence.json"
    path.write_text('{\n  "name": "NaN Infinity",\n  "camera": {"fx": ' + literal + "}\n}\n")
    with pytest.raises(ValueError) as exc_info:
        read_sequence_json(path)
    assert one_line(exc_info).startswith(f"{path}:3: {literal} is not a finite number")


# --- groundtruth.txt ---------------------------------------------------------------------------

def test_groundtruth_quaternion_at_any_scale_keeps_its_rotation(tmp_path):
    """(1, 0, 0, 1) scaled by 1e200 (its squares overflow) or 1e-200 (they vanish) is still a
    rotation of 90 degrees about x; the old reader made the first the identity and refused the
    second as zero."""
    path = tmp_path / "groundtruth.txt"
    path.write_text("0 0 0 0 1e200 0 0 1e200\n1 0 0 0 1e-200 0 0 1e-200\n")
    rotations = read_trajectory(path).pose(np.array([0.0, 1.0]))[:, :3, :3]
    expected = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    np.testing.assert_allclose(rotations, [expected, expected], atol=1e-12)


def test_groundtruth_position_beyond_1e9_m_is_refused(tmp_path):
    """Positions near 1e308 m made the interpolation overflow into NaN poses, silently."""
    path = tmp_path / "groundtruth.txt"
    path.write_text("0 1e308 0 0 0 0 0 1\n1 -1e308 0 0 0 0 0 1\n")
    with pytest.raises(ValueError) as exc_info:
        read_trajectory(path)
    assert one_line(exc_info) == (f"{path}:1: position px = 1e308 is beyond 1e+09 m; expected "
                                  "positions in metres")


# --- events.h5 ---------------------------------------------------------------------------------

def test_damaged_h5_is_one_line_naming_the_file(tmp_path):
    """Bytes overwritten in the compressed data: h5py's "Can't synchronously read data (filter
    returned failure during read)" came out alone, without the file's name."""
    path = tmp_path / "events.h5"
    write_h5(path, np.sort(np.random.default_rng(0).integers(0, 10**9, 50_000)),
             chunk_size=4096)
    data = bytearray(path.read_bytes())
    data[len(data) // 2:len(data) // 2 + 200] = b"\xff" * 200
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError) as exc_info:
        read_events(path)
    assert one_line(exc_info).startswith(f"{path}: the HDF5 file is damaged (h5py: ")
    assert "copy or convert it again" in str(exc_info.value)


def rewrite(path, name, data):
    with h5py.File(path, "r+") as f:
        del f[name]
        f.create_dataset(name, data=data)


def test_h5_times_of_a_float_dtype_are_refused(tmp_path):
    path = tmp_path / "events.h5"
    write_h5(path, np.arange(100) * 1000)
    with h5py.File(path, "r") as f:
        t = f["events/t"][()]
    rewrite(path, "events/t", t.astype(np.float64) + 0.7)
    with pytest.raises(ValueError) as exc_info:
        read_events(path)
    assert one_line(exc_info) == (f"{path}: events/t has dtype float64; expected integer "
                                  "microseconds (int64)")


def test_h5_coordinates_beyond_uint16_are_refused_not_wrapped(tmp_path):
    """x stored as int64 70000 was wrapped to 4464 and read as a valid pixel."""
    path = tmp_path / "events.h5"
    write_h5(path, np.arange(100) * 1000)
    x = np.zeros(100, np.int64)
    x[42] = 70_000
    rewrite(path, "events/x", x)
    with pytest.raises(ValueError) as exc_info:
        read_events(path, 70_000 % 65536 + 1, 48)
    assert one_line(exc_info) == (f"{path}: event 42: events/x = 70000; expected pixel "
                                  "coordinates in [0, 65535]")


def test_h5_negative_times_are_refused(tmp_path):
    path = tmp_path / "events.h5"
    write_h5(path, np.arange(100) * 1000)
    with h5py.File(path, "r+") as f:
        f["events/t"][0] = -5
    with pytest.raises(ValueError) as exc_info:
        read_events(path)
    assert one_line(exc_info).startswith(f"{path}: event 0: events/t = -5 us (t_offset 0 us) "
                                         "is outside [0, ")


def test_h5_ms_to_idx_that_lies_is_refused_not_followed(tmp_path):
    """An index that skips events made a window silently miss them."""
    path = tmp_path / "events.h5"
    write_h5(path, np.arange(100) * 100_000)            # one event every 0.1 ms, to 9.9 ms
    with h5py.File(path, "r+") as f:
        f["ms_to_idx"][5] = 80
    with pytest.raises(ValueError) as exc_info:
        read_window(path, 5 * 10**6, 8 * 10**6)
    assert one_line(exc_info) == (f"{path}: ms_to_idx[5] = 80 is not the index of the first "
                                  "event at or after 5 ms (of 100 events); expected the DSEC "
                                  "layout's index")


def test_h5_last_time_out_of_order_names_the_event_not_a_unit(tmp_path):
    """A 20 s recording whose last events/t is 100 us: the unit check blamed the unit ("events/t
    runs to 0.0001 s but ms_to_idx 20 s") instead of naming the first event out of order."""
    path = tmp_path / "events.h5"
    write_h5(path, np.linspace(0, 20e9, 200).astype(np.int64))
    with h5py.File(path, "r+") as f:
        f["events/t"][199] = 100
    with pytest.raises(ValueError) as exc_info:
        read_events(path)
    assert one_line(exc_info) == (f"{path}: event 199: events/t = 100 us is before the "
                                  "previous event's 19899497 us; expected events sorted by t")


@pytest.mark.parametrize(("attr", "value"), [("width", -3), ("height", 1.5), ("t_offset", 2.5)])
def test_h5_attributes_that_are_not_integers_in_range_are_refused(tmp_path, attr, value):
    path = tmp_path / "events.h5"
    write_h5(path, np.arange(100) * 1000)
    with h5py.File(path, "r+") as f:
        if attr == "t_offset":
            del f["t_offset"]
        f.attrs[attr] = value
    with pytest.raises(ValueError) as exc_info:
        read_events(path)
    assert one_line(exc_info).startswith(f"{path}: the attribute {attr} is {value!r}; expected "
                                         "an integer number of ")


# --- depth EXR ---------------------------------------------------------------------------------

@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, -0.5])
def test_depth_exr_with_a_non_finite_or_negative_pixel_is_refused(tmp_path, value):
    """write_depth refuses them; read_depth passed them on (a NaN depth scored as an error of
    NaN, an inf one as a point at infinity)."""
    from sim.exr import read_depth, write_exr_channels

    depth = np.ones((4, 5), np.float32)
    depth[2, 3] = value
    path = tmp_path / "depth.exr"
    write_exr_channels(path, {"Z": depth})
    with pytest.raises(ValueError) as exc_info:
        read_depth(path)
    shown = "NaN" if np.isnan(value) else repr(value)
    assert one_line(exc_info) == (f"{path}: pixel (u=3, v=2) of channel 'Z' holds {shown} "
                                  "(1 pixel like it); expected finite depths in metres >= 0 "
                                  "(0 = none)")


def test_per_event_depth_that_is_not_finite_is_refused(tmp_path):
    """events/depth (float32 metres) of an events.h5 passed NaN on to the scoring."""
    from sim.event_depth import read_event_depth

    path = tmp_path / "events.h5"
    write_h5(path, np.arange(100) * 1000)
    with h5py.File(path, "r+") as f:
        depth = np.ones(100, np.float32)
        depth[7] = np.nan
        f.create_dataset("events/depth", data=depth)
        f.create_dataset("events/depth_flag", data=np.zeros(100, np.uint8))
    with pytest.raises(ValueError) as exc_info:
        read_event_depth(path)
    assert one_line(exc_info) == (f"{path}: event 7: events/depth = nan; expected a finite "
                                  "depth in metres >= 0 (0 = none)")


# --- evfuse map --median ------------------------------------------------------------------------

def test_median_window_far_beyond_the_image_is_the_whole_image_window():
    """``evfuse map --median 999999`` died with MemoryError (exit 1, "unexpected error"): the
    compiled median allocated a window of 999999^2 values. A window past the image on every side
    sees the whole image, so any larger one gives the same medians."""
    from fusion.map.emvs import masked_median

    values = np.arange(12, dtype=np.float32).reshape(3, 4)
    mask = values % 3 != 0
    whole = np.where(mask, np.median(values[mask]), values)
    np.testing.assert_array_equal(masked_median(values, mask, 9), whole)
    np.testing.assert_array_equal(masked_median(values, mask, 999_999), whole)


def test_h5_window_behind_an_out_of_order_time_names_that_event(tmp_path):
    """Event 49 moved to 9.999 ms: a window from 5 ms finds ms_to_idx[5] = 50 wrong against
    events/t, and the cause, event 50 before event 49, is named (not the index, not a chunk)."""
    path = tmp_path / "events.h5"
    write_h5(path, np.arange(100) * 100_000)
    with h5py.File(path, "r+") as f:
        f["events/t"][49] = 9999
    with pytest.raises(ValueError) as exc_info:
        read_window(path, 5 * 10**6, 8 * 10**6)
    assert one_line(exc_info) == (f"{path}: event 50: events/t = 5000 us is before the "
                                  "previous event's 9999 us; expected events sorted by t")


# --- scene TOML (huge numbers) -------------------------------------------------------------------

def test_scene_light_direction_at_a_huge_scale_stays_a_unit_vector():
    """direction = [1e308, 1e308, 0]: its norm overflowed, and the light travelled along
    [0, 0, 0] (parsed without a word)."""
    from sim.scene import parse_scene
    from tests.conftest import WALL, scene_text

    lights = ('[[lights]]\ntype = "directional"\ndirection = [1e308, 1e308, 0.0]\n'
              "illuminance_lux = 400.0\n")
    scene = parse_scene(scene_text(WALL, lights=lights), "huge.toml")
    np.testing.assert_allclose(scene.lights[0].direction, [2**-0.5, 2**-0.5, 0.0])


def test_scene_whose_camera_position_overflows_is_refused():
    """velocity = [1e308, 1e308, 0] over 3 s: the poses reached inf (parsed without a word)."""
    from sim.scene import SceneError, parse_scene
    from tests.conftest import WALL, scene_text

    trajectory = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
                  "velocity = [1e308, 1e308, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
    with pytest.raises(SceneError) as exc_info:
        parse_scene(scene_text(WALL, trajectory=trajectory, duration=3.0), "huge.toml")
    assert one_line(exc_info) == ("huge.toml: [trajectory]: the camera's position overflows over "
                                  "[0, duration] (expected metres and m/s of a real scene)")


# --- evfuse fill --min-region ---------------------------------------------------------------------

def test_min_region_past_int64_keeps_no_region():
    """``evfuse fill --min-region 18446744073709551616`` died with OverflowError (exit 1): the
    bound went to the compiled loop as is. No region is larger than the frame, so any bound past
    it keeps none."""
    from fusion.fill.segmentation import SegmentationParams, segment_regions

    frame = np.zeros((6, 8), np.uint8)
    frame[:, 4:] = 200                                       # two regions of 24 pixels
    assert segment_regions(frame, SegmentationParams(min_region=24)).max() == 2
    for bound in (49, 2**64):
        assert not segment_regions(frame, SegmentationParams(min_region=bound)).any()


def test_ring_past_int64_is_the_whole_frame_band():
    """``evfuse fill --ring 18446744073709551616`` died with OverflowError (exit 1). A band
    wider than the frame covers all of it, so any wider one counts the same map points."""
    from fusion.fill.filling import SelectionParams, select_regions

    labels = np.ones((6, 8), np.int32)
    labels[:, 4:] = 2
    sparse = np.zeros((6, 8), np.float32)
    sparse[0, 0] = sparse[5, 7] = 1.0
    wide = select_regions(labels, sparse, SelectionParams(ring=8))
    huge = select_regions(labels, sparse, SelectionParams(ring=2**64))
    np.testing.assert_array_equal(huge.ring_events, wide.ring_events)
    np.testing.assert_array_equal(huge.ring_events[1:], [2, 2])       # both points, both bands


def test_scene_up_at_a_huge_scale_stays_a_unit_vector():
    """up = [1e308, 0, 1e308] was parsed as (0, 0, 0): its norm overflowed to inf."""
    from sim.scene import parse_scene
    from tests.conftest import WALL, scene_text

    scene = parse_scene(scene_text(WALL, extra="up = [1e308, 0.0, 1e308]"), "huge.toml")
    np.testing.assert_allclose(scene.up, [2**-0.5, 0.0, 2**-0.5])


def test_depth_exr_with_a_damaged_header_names_the_file(tmp_path):
    """One byte zeroed in the header (issue 39's fuzzing): OpenEXR's ValueError "Invalid part
    index '0': file has 0 parts." came out alone, without the file's name."""
    from sim.exr import read_depth, write_depth

    path = tmp_path / "depth.exr"
    write_depth(path, np.ones((12, 16), np.float32))
    data = bytearray(path.read_bytes())
    data[47] = 0
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError) as exc_info:
        read_depth(path)
    assert one_line(exc_info).startswith(f"cannot read EXR file {path}: ")


def test_sweep_lam_outside_its_range_is_refused_naming_the_key():
    """``[grid] lam = 1e308`` (issue 39's fuzzing): the sweep only checked that lam is finite,
    so generate started and every job failed in SamplingParams (exit 1, the error in the
    manifest) instead of a refusal before any work."""
    from sim.dataset import parse_sweep

    text = 'seeds = [1]\n[[scenes]]\nname = "slider_close"\n[grid]\nlam = 1e308\n'
    with pytest.raises(ValueError) as exc_info:
        parse_sweep(text, "s.toml")
    assert one_line(exc_info) == "s.toml: grid.lam: lam must be in (0, 1], got 1e+308"
    assert parse_sweep(text.replace("1e308", "1.0"), "s.toml").jobs[0].params == {"lam": 1.0}


def test_twin_depth_so_small_that_the_poster_overflows_is_refused():
    """``evfuse twin --depth 9.5e-148`` (issue 39's fuzzing): the poster's padding, the camera's
    motion in views of that depth, overflowed OpenCV's int (exit 1, "unexpected error")."""
    from sim.twin import write_twin
    from sim.validation import ParameterError
    from tests.fuzz_targets import tiny_inputs

    with pytest.raises(ParameterError) as exc_info:
        write_twin(tiny_inputs()["sequence"], "/nonexistent-out-twin", 9.5e-148)
    assert one_line(exc_info).startswith("depth 9.5e-148 m: the camera moves 0.331 m over the "
                                         "window")


def test_sweep_max_rate_below_the_default_min_rate_is_refused_before_any_job():
    """``[grid] max_rate = 1e-9`` (issue 39's long fuzz run): each parameter was checked alone,
    so generate ran and every job failed in SamplingParams (min_rate 100 > max_rate)."""
    from sim.dataset import parse_sweep

    text = 'seeds = [1]\n[[scenes]]\nname = "slider_close"\n[grid]\nmax_rate = 1e-9\n'
    with pytest.raises(ValueError) as exc_info:
        parse_sweep(text, "s.toml")
    assert one_line(exc_info) == ("s.toml: grid: a job with max_rate = 1e-09: SamplingParams "
                                  "needs 0 < min_rate <= max_rate, got 100.0 and 1e-09")


@pytest.mark.parametrize("masks", ["3", '{"objects": 7}'])
def test_sequence_json_object_masks_of_the_wrong_type_names_the_file(tmp_path, masks):
    """``"object_masks": 3`` in sequence.json (issue 39's long fuzz run): load_sequence died
    with AttributeError ('int' object has no attribute 'get')."""
    import shutil

    from sim.sequence import load_sequence
    from tests.fuzz_targets import tiny_simulated

    folder = tmp_path / "seq"
    shutil.copytree(tiny_simulated(), folder)
    metadata = json.loads((folder / "sequence.json").read_text())
    metadata["object_masks"] = json.loads(masks)
    (folder / "sequence.json").write_text(json.dumps(metadata))
    with pytest.raises(ValueError) as exc_info:
        load_sequence(folder)
    assert one_line(exc_info).startswith(f"{folder / 'sequence.json'}: object_masks")


def test_twin_far_poster_writes_a_scene_that_simulate_accepts(tmp_path):
    """``evfuse twin --depth 51`` (issue 39's long fuzz run): the scene's depth_range went to
    [25.5, 102] and simulate refused it (depths above 100 m)."""
    from sim.scene import load_scene
    from sim.twin import write_twin
    from tests.fuzz_targets import tiny_inputs

    write_twin(tiny_inputs()["sequence"], tmp_path / "twin", 51.0)
    load_scene(tmp_path / "twin" / "scene.toml")


def test_bench_noise_out_of_range_is_refused_by_its_flag():
    """``evfuse bench --noise 1.0`` (issue 39's long fuzz run): the refusal spoke of BenchParams'
    "noise", no flag."""
    from tests.fuzz_targets import run_cli

    status, _, err = run_cli(["bench", "--family", "sphere", "--noise", "1.0", "--out",
                              "/nonexistent-bench-out"])
    assert status == 2
    assert err.strip() == ("evfuse bench: error: --noise 1 --outliers 0.05: expected --noise in "
                           "[0, 1) and --outliers in [0, 1]")


@pytest.mark.parametrize("steps", [float("nan"), float("inf")])
def test_staircase_steps_not_finite_is_refused_naming_the_knob(steps):
    """``bench --family staircase --steps nan`` (issue 39's long fuzz run): the default step
    depth was computed from round(steps) before the knob was checked (ValueError "cannot
    convert float NaN to integer", OverflowError for inf)."""
    from sim.scene.families import family_variants

    with pytest.raises(ValueError) as exc_info:
        family_variants("staircase", {"steps": [steps]})
    assert one_line(exc_info) == f"steps {steps}: expected 1 to 12 for the staircase family"
