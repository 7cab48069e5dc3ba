"""Filling methods (fusion.methods): each built-in against its own analytic case (the paper's
method itself is tested stage by stage in test_filling.py and test_dense.py), a user's method
from outside the package, and bad methods refused in one line."""

from __future__ import annotations

import re
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


# --- settings of a method (--param) -------------------------------------------------------------

def test_every_built_in_declares_its_settings_and_methods_params_lists_them(capsys):
    """``evfuse methods --params`` keeps each method's line as ``evfuse methods`` prints it and
    adds one line of its settings with their defaults (the dataclass's own)."""
    from fusion.methods import param_defaults
    from fusion.methods.baselines import GuidedParams

    built_in = [m for m in available_methods().values() if m.origin == "built-in"]
    assert all(method.params is not None for method in built_in)
    for method in built_in:
        defaults = param_defaults(method)
        assert method.params(**defaults) == method.params()        # the defaults are valid
    assert param_defaults(get_method("guided")) == {
        "radius": GuidedParams.radius, "eps": GuidedParams.eps,
        "min_support": GuidedParams.min_support}
    assert param_defaults(get_method("paper-gaussian")) == {"sigma": 5.0}
    assert param_defaults(get_method("paper-idw")) == {}
    assert main(["methods"]) == 0
    plain = capsys.readouterr().out.splitlines()
    assert main(["methods", "--params"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0::2] == plain                                     # first lines unchanged
    settings = dict(zip([line.split()[0] for line in plain], lines[1::2], strict=True))
    assert settings["paper-idw"].split() == ["params:", "none"]
    assert settings["paper-gaussian"].split() == ["params:", "sigma=5.0"]
    assert settings["telea"].split() == ["params:", "radius=5.0"]
    assert settings["guided"].split(None, 1) == ["params:",
                                                 "radius=8, eps=0.0001, min_support=0.25"]
    assert "min_subregion=none" in settings["hybrid"]


@pytest.mark.parametrize("text, value", [
    ("3", 3), ("-2", -2), ("0.03", 0.03), ("1e-3", 0.001), ("true", True), ("False", False),
    ("none", None), ("None", None), ("abc", "abc"), (" 4 ", 4), ("'a,b'", "a,b"),
    ("1,2", "1,2"), ("[1]", "[1]"), ("nan", "nan"), ("", ""),
])
def test_a_value_is_a_python_literal_where_it_is_one_else_text(text, value):
    from fusion.methods import parse_value

    parsed = parse_value(text)
    assert parsed == value and type(parsed) is type(value)


def test_values_are_coerced_to_their_field_s_type():
    from fusion.methods import check_params

    coerced = check_params("plane", {"residual_rel": 1, "min_points": np.int64(4)})
    assert coerced == {"residual_rel": 1.0, "min_points": 4}
    assert type(coerced["residual_rel"]) is float and type(coerced["min_points"]) is int
    assert check_params("hybrid", {"min_subregion": None}) == {"min_subregion": None}
    assert type(check_params("hybrid", {"min_subregion": 30})["min_subregion"]) is int
    assert check_params("paper-gaussian", {"sigma": 3}) == {"sigma": 3.0}
    assert check_params("nearest", {}) == {}


@pytest.mark.parametrize("method, params, message", [
    ("plane", {"residual": 0.1}, "filling method plane: unknown parameter 'residual'; expected "
                                 "one of residual_rel, min_points, min_inlier_share"),
    ("nearest", {"radius": 3}, "filling method nearest: unknown parameter 'radius'; nearest "
                               "takes no parameters"),
    ("paper-idw", {"sigma": 3}, "filling method paper-idw: unknown parameter 'sigma'; "
                                "paper-idw takes no parameters"),
    ("plane", {"min_points": 2.5}, "filling method plane: min_points expects an integer, got "
                                   "2.5"),
    ("guided", {"radius": True}, "filling method guided: radius expects an integer, got true"),
    ("plane", {"residual_rel": "abc"}, "filling method plane: residual_rel expects a number, "
                                       "got abc"),
    ("hybrid", {"min_subregion": "big"}, "filling method hybrid: min_subregion expects an "
                                         "integer or none, got big"),
    ("plane", {"residual_rel": -1}, "filling method plane: residual_rel must be a finite "
                                    "number > 0, got -1.0"),
    ("hybrid", {"canny_low": 50}, "filling method hybrid: canny_low must be <= canny_high, got "
                                  "50.0 > 40.0"),
    ("telea", {"radius": 0}, "filling method telea: radius must be a finite number > 0"),
    ("paper-gaussian", {"sigma": 0}, "filling method paper-gaussian: sigma must be a finite "
                                     "number > 0"),
])
def test_a_bad_setting_is_refused_in_one_line_naming_the_method_and_the_key(method, params,
                                                                           message):
    from fusion.methods import check_params

    with pytest.raises(MethodError) as info:
        check_params(method, params)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_a_label_names_a_variant_and_reads_back():
    from fusion.methods import MethodVariant, method_label, parse_label, split_labels

    variant = MethodVariant("plane", {"residual_rel": 0.03, "min_points": 4})
    assert variant.label == "plane{min_points=4,residual_rel=0.03}"      # keys in order
    assert parse_label(variant.label) == variant
    assert parse_label("plane") == MethodVariant("plane")
    assert MethodVariant("plane").label == "plane"
    odd = {"mode": "a,b", "flag": True, "word": "true", "off": None, "tiny": 1e-6}
    assert method_label("m:f", odd) == "m:f{flag=true,mode='a,b',off=none,tiny=1e-06,word='true'}"
    assert parse_label(method_label("m:f", odd)).params == odd
    assert split_labels("nearest, plane{residual_rel=0.03,min_points=4},m:f{mode='a,b'}") == [
        "nearest", "plane{residual_rel=0.03,min_points=4}", "m:f{mode='a,b'}"]
    for bad, message in (("plane{x}", "expected NAME or NAME{KEY=VALUE,...}; got 'x'"),
                         ("plane{x=1", "expected NAME or NAME{KEY=VALUE,...}"),
                         ("{x=1}", "expected NAME"), ("plane{x=1,x=2}", "x given twice")):
        with pytest.raises(MethodError, match=re.escape(f"{bad}: {message}")):
            parse_label(bad)


def test_settings_reach_the_method_and_a_user_s_undeclared_ones_pass_unchecked(tmp_path,
                                                                               monkeypatch):
    from fusion.fill.dense import DenseParams, densify
    from fusion.fill.filling import FillParams
    from fusion.methods import check_params

    (tmp_path / "my_shift.py").write_text(
        "import numpy as np\n"
        "def shifted(frame, sparse, camera, params):\n"
        "    return np.where(sparse > 0, sparse, params['depth']).astype(np.float32)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert check_params("my_shift:shifted", {"depth": 2, "anything": "x"}) == {
        "depth": 2, "anything": "x"}                       # not declared: passed on as given
    sparse = _grid_points(np.full((H, W), 1.0, np.float32))
    dense = run_method("my_shift:shifted", _frame(), sparse, CAMERA, {"depth": 2.5})[0]
    assert np.all(dense[sparse == 0] == 2.5)
    sys.modules.pop("my_shift", None)
    # The paper's Gaussian weighting with sigma 2 is densify with FillParams sigma 2 ...
    sparse = _grid_points((1.0 + 0.02 * np.arange(W, dtype=np.float32))[None, :].repeat(H, 0))
    sparse[:, W // 2 - 1] = 1.5
    dense = run_method("paper-gaussian", _frame(), sparse, CAMERA, {"sigma": 2.0})[0]
    expected = densify(_frame(), sparse, DenseParams(fill=FillParams("gaussian", sigma=2.0)))[2]
    np.testing.assert_array_equal(dense, expected)
    assert not np.array_equal(dense, run_method("paper-gaussian", _frame(), sparse, CAMERA)[0])
    # ... and a setting a method does not take is refused when it runs, too.
    with pytest.raises(MethodError, match="filling method paper-idw raised TypeError"):
        run_method("paper-idw", _frame(), sparse, CAMERA, {"sigma": 2.0})
    with pytest.raises(MethodError, match="filling method telea raised TypeError"):
        run_method("telea", _frame(), sparse, CAMERA, {"radius": 3, "speed": 1})


# --- a method resolved once, and methods asked for as text (issue 22) ---------------------------


def test_the_paper_s_methods_are_registered_methods_that_run_the_paper_s_stages():
    """paper-* are PaperMethod objects: the fill stage calls their fill(), which keeps the
    segmentation; any other method's fill() gives none (no caller asks which it is)."""
    from fusion.fill.dense import DenseParams, densify
    from fusion.methods import PaperMethod

    sparse = _grid_points((1.0 + 0.02 * np.arange(W, dtype=np.float32))[None, :].repeat(H, 0))
    sparse[:, W // 2 - 1] = 1.5
    for name, weighting in (("paper-idw", "idw"), ("paper-gaussian", "gaussian"),
                            ("paper-exponential", "exponential")):
        method = get_method(name)
        assert isinstance(method, PaperMethod) and method.weighting == weighting
        params = method.stage_params(None, {})
        assert params.fill.weighting == weighting
        filled = method.fill(_frame(), sparse, CAMERA, {}, params)
        labels, regions, dense, _ = densify(_frame(), sparse, params)
        np.testing.assert_array_equal(filled.dense, dense)
        np.testing.assert_array_equal(filled.labels, labels)
        assert filled.regions.n_regions == regions.n_regions > 0 and filled.confidence is None
    assert get_method("paper-gaussian").stage_params(None, {"sigma": 2.0}).fill.sigma == 2.0
    with pytest.raises(ValueError, match="paper-gaussian uses gaussian weights"):
        get_method("paper-gaussian").stage_params(DenseParams(), {})
    nearest = get_method("nearest").fill(_frame(), sparse, CAMERA, {}, DenseParams())
    assert nearest.regions is None and not nearest.labels.any() and "method_s" in nearest.timings
    assert get_method("nearest").progress_units() == ("px", "pixels filled by nearest")
    assert get_method("paper-idw").progress_units() == ("region", "regions filled")


def test_a_resolved_method_is_not_resolved_again(monkeypatch):
    """fill_frame handed a ResolvedMethod runs it as it is: get_method is not called again."""
    import fusion.fill.dense as dense_module
    from fusion.fill.dense import fill_frame, resolve_method
    from fusion.methods import ResolvedMethod

    resolved = resolve_method("paper-gaussian", method_params={"sigma": 3})
    assert isinstance(resolved, ResolvedMethod)
    assert resolved.settings == {"sigma": 3.0} and resolved.params.fill.sigma == 3.0
    assert resolve_method(resolved) is resolved
    with pytest.raises(ValueError, match="a resolved method carries its parameters"):
        resolve_method(resolved, method_params={"sigma": 4})

    def refuse(spec):
        raise AssertionError(f"{spec} resolved twice")

    monkeypatch.setattr(dense_module, "get_method", refuse)
    sparse = _grid_points(np.full((H, W), 1.0, np.float32))
    result = fill_frame(_frame(), sparse, CAMERA, method=resolved)
    assert result.info["method"] == "paper-gaussian"
    assert result.info["method_params"] == {"sigma": 3.0}


def test_methods_asked_for_as_text_are_refused_in_the_library_s_terms():
    """method_variants / fill_request speak of the parameters 'method' and 'param'; the command
    line names them by its flags (ParameterError.rephrase), giving the lines it printed."""
    from fusion.fill.dense import DenseParams
    from fusion.fill.segmentation import SegmentationParams
    from fusion.methods import fill_request, method_variants, parse_param
    from sim.validation import ParameterError

    flags = {"method": "--method", "param": "--param", "threshold": "--threshold",
             "weighting": "--weighting", "sigma": "--sigma"}
    assert parse_param("plane.residual_rel=0.03") == ("plane", "residual_rel", 0.03)
    assert method_variants(["telea{radius=2}"]) == [methods_module.MethodVariant(
        "telea", {"radius": 2.0})]
    cases = [
        (lambda: method_variants(["telea{radius=2}"], ["radius=3"]),
         "param radius=3: radius of telea is already set by method telea{radius=2}; set it once",
         "--param radius=3: radius of telea is already set by --method telea{radius=2}; set it "
         "once"),
        (lambda: method_variants(["plane", "telea"], ["radius=3"]),
         "param radius=3: 2 methods given (plane, telea), whose is it? Write param "
         "METHOD.radius=... (every entry of METHOD) or method 'METHOD{radius=...}' (that entry)",
         None),
        (lambda: parse_param("x"), "param x: expected KEY=VALUE, or METHOD.KEY=VALUE for one "
         "method's (e.g. param plane.residual_rel=0.03)", None),
        (lambda: fill_request("nearest", stages=DenseParams(
            segmentation=SegmentationParams(5.0))),
         "method nearest and threshold 5 contradict each other: only the paper's methods "
         "(paper-idw, paper-gaussian, paper-exponential, paper-colorization) use threshold "
         "(drop it, or give one of them)",
         "--method nearest and --threshold 5 contradict each other: only the paper's methods "
         "(paper-idw, paper-gaussian, paper-exponential, paper-colorization) use --threshold "
         "(drop it, or give one of them)"),
        (lambda: fill_request("paper-gaussian", weighting="idw"),
         "method paper-gaussian and weighting idw contradict each other: paper-gaussian uses "
         "gaussian weights (give method paper-idw, or drop weighting)", None),
    ]
    for call, library, command_line in cases:
        with pytest.raises(ParameterError) as error:
            call()
        assert str(error.value) == library
        if command_line is not None:
            assert error.value.rephrase(flags) == command_line
    resolved = fill_request(None, ["sigma=3"], weighting="gaussian")
    assert resolved.method.name == "paper-gaussian" and resolved.params.fill.sigma == 3.0
    assert fill_request("nearest").params == DenseParams()
