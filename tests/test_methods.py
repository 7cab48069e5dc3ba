"""Filling methods (fusion.methods): each built-in against its own analytic case (the paper's
method itself is tested stage by stage in test_filling.py and test_dense.py), a user's method
from outside the package, and bad methods refused in one line."""

from __future__ import annotations

import sys
from types import SimpleNamespace

import numpy as np
import pytest

import fusion.methods as methods_module
from fusion.cli import main
from fusion.methods import MethodError, available_methods, get_method, run_method
from sim.camera import Camera

H, W = 60, 80
CAMERA = Camera(width=W, height=H, fx=70.0, fy=65.0, cx=39.5, cy=29.5)
BUILT_IN = ["paper-idw", "paper-gaussian", "paper-exponential", "nearest", "telea",
            "morphological"]


def _grid_points(depth: np.ndarray, step: int = 6) -> np.ndarray:
    sparse = np.zeros((H, W), np.float32)
    sparse[2::step, 3::step] = depth[2::step, 3::step]
    return sparse


def _frame() -> np.ndarray:
    """Two flat regions (left dark, right bright) with a one-pixel outline between them."""
    frame = np.full((H, W), 60, np.uint8)
    frame[:, W // 2:] = 180
    frame[:, W // 2 - 1] = 0
    return frame


def test_the_built_ins_are_listed_name_first(capsys):
    assert list(available_methods())[:6] == BUILT_IN
    assert main(["methods"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines[:6]] == BUILT_IN
    assert all(len(line.split(None, 1)) == 2 for line in lines)


@pytest.mark.parametrize("name", BUILT_IN)
def test_a_constant_depth_stays_constant(name):
    sparse = _grid_points(np.full((H, W), 1.7, np.float32))
    sparse[:, W // 2 - 1] = 1.7          # and the outline, where events are (the paper's ring)
    dense, confidence, seconds = run_method(name, _frame(), sparse, CAMERA)
    assert dense.dtype == np.float32 and dense.shape == (H, W) and seconds >= 0
    filled = dense > 0
    assert np.count_nonzero(filled) > np.count_nonzero(sparse)          # it filled something
    # telea works on 16-bit levels: a constant comes back within a few levels (5e-5).
    np.testing.assert_allclose(dense[filled], 1.7, rtol=5e-5 if name == "telea" else 1e-6)
    assert confidence is None


def test_nearest_gives_each_pixel_its_nearest_map_point():
    sparse = np.zeros((H, W), np.float32)
    sparse[10, 10], sparse[50, 70] = 1.0, 3.0
    dense = run_method("nearest", _frame(), sparse, CAMERA)[0]
    v, u = np.mgrid[0:H, 0:W]
    closer = np.hypot(v - 10, u - 10) < np.hypot(v - 50, u - 70)
    tie = np.isclose(np.hypot(v - 10, u - 10), np.hypot(v - 50, u - 70), atol=0.5)
    assert np.all(dense[closer & ~tie] == 1.0) and np.all(dense[~closer & ~tie] == 3.0)


def test_telea_fills_a_slanted_plane_within_a_bound():
    """Inverse depth linear in u (a slanted plane, depth 0.85-2 m): inpainting between grid
    points 6 px apart stays within 4 % of it (1 % on average) away from the image border; a
    nearest-point fill of the same points is off by up to 6 %."""
    v, u = np.mgrid[0:H, 0:W]
    truth = (1.0 / (0.5 + 0.01 * u)).astype(np.float32)
    inner = (slice(8, H - 8), slice(8, W - 8))
    error = {name: np.abs(run_method(name, _frame(), _grid_points(truth), CAMERA)[0][inner]
                          / truth[inner] - 1) for name in ("telea", "nearest")}
    assert error["telea"].max() < 0.04 and error["telea"].mean() < 0.01
    assert error["nearest"].max() > 0.05 > error["telea"].max()


def test_the_morphological_fill_keeps_a_depth_step_between_its_points():
    """A near and a far half, map points 6 px apart: each side keeps its depth away from the
    step, and the step stays between the last near point (column 39) and the first far one
    (column 45), smoothed over a few pixels by the final blurs."""
    truth = np.where(np.arange(W)[None, :] < W // 2, 1.0, 4.0).astype(np.float32).repeat(H, 0)
    dense = run_method("morphological", _frame(), _grid_points(truth), CAMERA)[0]
    np.testing.assert_allclose(dense[:, :36], 1.0, rtol=1e-5)
    np.testing.assert_allclose(dense[:, 46:], 4.0, rtol=1e-5)
    crossing = np.argmax(dense > 2.5, axis=1)                   # first column past mid-depth
    assert np.all((crossing >= 39) & (crossing <= 45))


def test_a_method_from_a_module_outside_the_package_runs(tmp_path, monkeypatch):
    (tmp_path / "my_fill.py").write_text(
        "import numpy as np\n"
        "def densify(frame, sparse, camera, params):\n"
        "    '''Every pixel at the mean map depth.'''\n"
        "    return np.full(frame.shape, sparse[sparse > 0].mean(), np.float32), "
        "np.full(frame.shape, 0.5)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    method = get_method("my_fill:densify")
    assert method.origin == "module:function" and method.summary.startswith("Every pixel")
    sparse = _grid_points(np.full((H, W), 2.0, np.float32))
    dense, confidence, _ = run_method(method, _frame(), sparse, CAMERA)
    assert np.all(dense == 2.0) and np.all(confidence == 0.5)
    sys.modules.pop("my_fill", None)


def test_an_installed_entry_point_is_found(monkeypatch):
    def fill(frame, sparse, camera, params):
        return sparse

    point = SimpleNamespace(name="plugin-fill", value="pkg.mod:fill", load=lambda: fill,
                            dist=SimpleNamespace(name="pkg"))
    monkeypatch.setattr(methods_module.metadata, "entry_points",
                        lambda group: [point] if group == "evfuse.fill_methods" else [])
    assert "plugin-fill" in available_methods()
    method = get_method("plugin-fill")
    assert method.function is fill and method.origin == "entry point pkg"


@pytest.mark.parametrize("body, message", [
    ("return np.zeros((3, 3))", "of shape (3, 3); expected the frame's (60, 80)"),
    ("return np.full(frame.shape, np.nan)", "NaN or infinite"),
    ("return np.full(frame.shape, -1.0)", "negative depths"),
    ("raise RuntimeError('boom')", "raised RuntimeError: boom"),
    ("return sparse, np.full(frame.shape, 2.0)", "confidence outside [0, 1]"),
    ("return 'dense'", "not an array"),
])
def test_a_bad_method_is_refused_in_one_line_naming_it(body, message):
    namespace: dict = {"np": np}
    exec(f"def bad(frame, sparse, camera, params):\n    {body}\n", namespace)
    method = methods_module.FillMethod("bad", "a bad method", namespace["bad"], "test")
    sparse = _grid_points(np.full((H, W), 1.0, np.float32))
    with pytest.raises(MethodError) as info:
        run_method(method, _frame(), sparse, CAMERA)
    text = str(info.value)
    assert text.startswith("filling method bad ") and message in text and "\n" not in text


@pytest.mark.parametrize("spec, message", [
    ("no-such-method", "unknown filling method 'no-such-method'; expected one of"),
    ("no_such_module_xyz:fill", "cannot import module 'no_such_module_xyz'"),
    ("numpy:no_such_function", "module 'numpy' has no function 'no_such_function'"),
])
def test_an_unknown_method_is_named(spec, message):
    with pytest.raises(MethodError, match=message.replace("(", r"\(")):
        get_method(spec)
