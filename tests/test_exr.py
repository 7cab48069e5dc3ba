"""sim.exr: float32 depth maps (channel Z) and multi-channel maps, bit-exact round trips."""

from __future__ import annotations

import numpy as np
import pytest

from sim.exr import read_depth, read_exr_channels, write_depth, write_exr_channels


def _depth(shape=(7, 11)) -> np.ndarray:
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.1, 50.0, shape).astype(np.float32)
    depth[0, :] = 0.0                                     # "no value" pixels
    depth[-1, -1] = np.float32(1e-30)                     # tiny but valid
    depth[1, 0] = np.nextafter(np.float32(1.0), np.float32(2.0))  # needs all 24 mantissa bits
    return depth


def test_depth_round_trip_is_bit_exact_including_zeros(tmp_path):
    depth = _depth()
    path = tmp_path / "d.exr"
    write_depth(path, depth)
    back = read_depth(path)
    assert back.dtype == np.float32 and back.shape == (7, 11)
    # compare the bits, not the values: float32 survives ZIP (lossless) compression unchanged
    np.testing.assert_array_equal(back.view(np.uint32), depth.view(np.uint32))
    assert (back[0] == 0).all()


def test_depth_file_has_only_the_z_channel_and_accepts_str_paths(tmp_path):
    path = tmp_path / "d.exr"
    write_depth(str(path), _depth((3, 2)))
    channels = read_exr_channels(str(path))
    assert list(channels) == ["Z"]
    assert channels["Z"].shape == (3, 2)                  # (H, W), not transposed


def test_non_contiguous_input_is_written_in_its_logical_layout(tmp_path):
    base = _depth((6, 4))
    write_depth(tmp_path / "t.exr", base.T)               # a (4, 6) view with swapped strides
    np.testing.assert_array_equal(read_depth(tmp_path / "t.exr"), base.T)


@pytest.mark.parametrize(("bad", "message"), [
    (np.ones(5, np.float32), "2-D"),
    (np.ones((2, 3, 1), np.float32), "2-D"),
    (np.zeros((0, 3), np.float32), "non-empty"),
    (np.array([[1.0, np.nan]], np.float32), "NaN"),
    (np.array([[1.0, np.inf]], np.float32), "infinite"),
    (np.array([[1.0, -0.5]], np.float32), "negative"),
    (np.array([["a", "b"]]), "real numbers"),
])
def test_bad_depth_is_rejected_with_a_message_naming_the_problem(tmp_path, bad, message):
    path = tmp_path / "bad.exr"
    with pytest.raises(ValueError, match=message):
        write_depth(path, bad)
    assert not path.exists()


def test_missing_z_channel_lists_the_channels_it_has(tmp_path):
    path = tmp_path / "c.exr"
    write_exr_channels(path, {"confidence": np.ones((2, 2), np.float32),
                              "R": np.zeros((2, 2), np.float32)})
    with pytest.raises(ValueError, match=r"c\.exr.*'R', 'confidence'"):
        read_depth(path)


def test_read_errors_name_the_file(tmp_path):
    missing = tmp_path / "missing.exr"
    with pytest.raises(ValueError, match=r"missing\.exr does not exist"):
        read_depth(missing)
    fake = tmp_path / "fake.exr"
    fake.write_text("P2 not an exr\n")
    with pytest.raises(ValueError, match=r"fake\.exr is not an OpenEXR file"):
        read_depth(fake)


def test_multichannel_round_trip_keeps_rgb_separate_and_bit_exact(tmp_path):
    rng = np.random.default_rng(1)
    maps = {name: rng.normal(size=(5, 8)).astype(np.float32)
            for name in ("R", "G", "B", "Z", "confidence")}
    maps["confidence"][0, 0] = np.nan                     # plain channels store NaN as is
    path = tmp_path / "m.exr"
    write_exr_channels(path, maps)
    back = read_exr_channels(path)
    assert sorted(back) == sorted(maps)
    for name, values in maps.items():
        assert back[name].dtype == np.float32 and back[name].shape == (5, 8)
        np.testing.assert_array_equal(back[name].view(np.uint32), values.view(np.uint32))


def test_float64_input_is_stored_as_nearest_float32(tmp_path):
    value = 1.0 + 2.0**-30                                # not a float32: rounds to 1.0
    write_exr_channels(tmp_path / "f.exr", {"Z": np.full((2, 2), value)})
    back = read_depth(tmp_path / "f.exr")
    assert back.dtype == np.float32 and (back == 1.0).all()


def test_multichannel_errors(tmp_path):
    with pytest.raises(ValueError, match="at least one channel"):
        write_exr_channels(tmp_path / "e.exr", {})
    with pytest.raises(ValueError, match=r"'b' has shape \(3, 2\), expected \(2, 2\)"):
        write_exr_channels(tmp_path / "e.exr", {"a": np.zeros((2, 2), np.float32),
                                                "b": np.zeros((3, 2), np.float32)})
    with pytest.raises(ValueError, match="without spaces"):
        write_exr_channels(tmp_path / "e.exr", {"a b": np.zeros((2, 2), np.float32)})


def test_unwritable_path_raises_oserror(tmp_path):
    with pytest.raises(OSError, match="no_such_folder"):
        write_depth(tmp_path / "no_such_folder" / "d.exr", np.ones((2, 2), np.float32))
