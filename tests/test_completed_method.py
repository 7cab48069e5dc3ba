"""``paper-colorization`` (fusion.methods.completed): the paper's fill, completed by colorization
where it leaves pixels empty; map-global's default fill (issue 40)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.fill.dense import DenseParams, densify
from fusion.methods import get_method, run_method
from fusion.methods.completed import complete_by_colorization
from sim.camera import Camera

H, W = 60, 80
CAMERA = Camera(width=W, height=H, fx=70.0, fy=65.0, cx=39.5, cy=29.5)


def _frame() -> np.ndarray:
    """A flat dark left half, a flat bright right half with a one-pixel outline between them,
    and a block of random texture in the right half that region growing breaks into pieces too
    small to keep (so the paper leaves it empty)."""
    frame = np.full((H, W), 60, np.uint8)
    frame[:, W // 2:] = 180
    frame[:, W // 2 - 1] = 0
    frame[20:40, 55:75] = np.random.default_rng(4).integers(0, 256, (20, 20), dtype=np.uint8)
    return frame


def _sparse(depth: np.ndarray) -> np.ndarray:
    """Map points on a 6-pixel grid and along the outline (an edge the events see)."""
    sparse = np.zeros((H, W), np.float32)
    sparse[2::6, 3::6] = depth[2::6, 3::6]
    sparse[:, W // 2 - 1] = depth[:, W // 2 - 1]
    return sparse


def _slanted() -> np.ndarray:
    """A plane slanted along x, 1 / z affine in the column: 1.0 m at the left edge, 1.6 m at the
    right (float32)."""
    inverse = 1.0 + (1.0 / 1.6 - 1.0) * np.arange(W) / (W - 1)
    return (1.0 / inverse)[None, :].repeat(H, 0).astype(np.float32)


def test_the_paper_s_pixels_are_kept_and_the_rest_lie_within_its_depths():
    """Where the paper filled, the depth is the paper's bit for bit, and the segmentation is the
    paper's; the pixels it left empty (the texture block) are filled, each within the range of
    the paper's depths (colorization's weights sum to 1: a convex combination)."""
    frame, sparse = _frame(), _sparse(_slanted())
    params = DenseParams()
    labels, regions, paper, _ = densify(frame, sparse, params)
    empty = paper <= 0
    assert empty[20:40, 55:75].mean() > 0.5                   # the texture defeats the paper
    method = get_method("paper-colorization")
    filled = method.fill(frame, sparse, CAMERA, {}, method.stage_params(None, {}))
    np.testing.assert_array_equal(filled.dense[~empty], paper[~empty])
    np.testing.assert_array_equal(filled.labels, labels)
    assert filled.regions.n_regions == regions.n_regions and filled.confidence is None
    assert "completion_s" in filled.timings
    assert (filled.dense > 0).all() and filled.dense.dtype == np.float32
    low, high = paper[~empty].min(), paper[~empty].max()
    assert low <= filled.dense[empty].min() and filled.dense[empty].max() <= high
    np.testing.assert_array_equal(run_method("paper-colorization", frame, sparse, CAMERA, {})[0],
                                  filled.dense)


def test_a_surface_at_one_depth_is_completed_at_that_depth():
    """Every known pixel at 1.3 m: the completion is 1.3 m everywhere, to float32 rounding."""
    frame, sparse = _frame(), _sparse(np.full((H, W), 1.3, np.float32))
    dense = run_method("paper-colorization", frame, sparse, CAMERA, {})[0]
    np.testing.assert_allclose(dense, 1.3, rtol=1e-6)


def test_nothing_known_gives_nothing_and_no_map_point_is_refused_as_the_paper_does():
    from fusion.methods._errors import MethodError

    assert not complete_by_colorization(_frame(), np.zeros((H, W), np.float32)).any()
    for name in ("paper-idw", "paper-colorization"):
        with pytest.raises(MethodError, match=f"{name} raised ValueError: no map points"):
            run_method(name, _frame(), np.zeros((H, W), np.float32), CAMERA, {})


def test_it_takes_the_paper_s_stage_parameters_and_no_settings_of_its_own():
    from fusion.fill.segmentation import SegmentationParams
    from fusion.methods import fill_request
    from fusion.methods._errors import MethodError
    from sim.validation import ParameterError

    stages = DenseParams(segmentation=SegmentationParams(5.0))
    resolved = fill_request("paper-colorization", stages=stages)
    assert resolved.params.segmentation.threshold == 5.0
    with pytest.raises(ParameterError, match="paper-colorization uses idw weights"):
        fill_request("paper-colorization", weighting="gaussian")
    with pytest.raises((ParameterError, MethodError), match="paper-colorization"):
        fill_request("paper-colorization", ["sigma=3"])
