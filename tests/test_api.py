"""The public Python API: explicit __all__, documented names, light imports."""

from __future__ import annotations

import inspect
import subprocess
import sys

import pytest

import fusion
import sim


@pytest.mark.parametrize("package", [fusion, sim], ids=["fusion", "sim"])
def test_every_public_name_exists_and_is_documented(package):
    assert len(package.__all__) == len(set(package.__all__)) > 10
    for name in package.__all__:
        obj = getattr(package, name)
        if inspect.isfunction(obj) or inspect.isclass(obj):
            doc = inspect.getdoc(obj) or ""
            assert len(doc) > 30, f"{package.__name__}.{name} has no docstring"


def test_functions_that_take_arrays_document_their_parameters():
    for name in ("disparity_space_image", "segment_regions", "select_regions", "fill_regions",
                 "depth_errors", "project_map", "fill_frame", "run_pipeline", "map_sequence"):
        doc = inspect.getdoc(getattr(fusion, name))
        assert "Parameters\n----------" in doc or "Raises\n------" in doc, name


def test_importing_the_packages_does_not_load_mitsuba():
    code = "import sys, sim, fusion; print('mitsuba' in sys.modules, 'drjit' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "False False"


def _guide_python_block(guide: str, marker: str) -> str:
    """The one Python example of ``docs/guides/GUIDE`` that holds ``marker``, read by the docs'
    own harness (tests/test_docs_examples.py)."""
    from tests.test_docs_examples import ROOT, examples

    blocks = [e.code for e in examples(ROOT / "docs" / "guides" / guide)
              if e.language == "python" and marker in e.code]
    assert len(blocks) == 1, f"{guide}: expected one Python example with {marker!r}"
    return blocks[0]


def test_the_file_formats_guide_s_io_example_gives_the_analytic_values(plane_sequence, tmp_path,
                                                                        monkeypatch):
    """The guide runs its example on its own simulation (tests/test_docs_examples.py); here the
    same code runs on a wall at a known distance, so its values are checked, not only run."""
    import numpy as np

    code = _guide_python_block("file-formats.md", "depth_copy.exr")
    for name in ("read_depth", "write_depth", "read_trajectory", "read_window"):
        assert name in sim.__all__ and f"{name}(" in code, name
    assert ".pose(t)" in code and ".camera_velocity(t)" in code
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "sc").symlink_to(plane_sequence, target_is_directory=True)
    scope: dict = {}
    exec(compile(code, "file-formats.md", "exec"), scope)
    # plane_sequence: a 64x48 camera at x = -0.15 + 1.0 t m looking along +y (OpenCV x = world
    # x) at a fronto-parallel wall 1 m away that fills the view.
    depth, t = scope["depth"], scope["t"]
    assert depth.shape == (48, 64) and depth.dtype == np.float32
    np.testing.assert_allclose(depth, 1.0, atol=1e-5)
    assert np.array_equal(sim.read_depth(tmp_path / "depth_copy.exr"), depth)
    np.testing.assert_allclose(scope["T_world_camera"][:3, 3], [-0.15 + t, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(scope["v"], [1.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(scope["w"], 0.0, atol=1e-9)
    window = scope["window"]
    t_ns = round(t * 1e9)
    assert len(window) > 0 and np.all(np.diff(window["t"]) >= 0)
    assert window["t"].min() >= t_ns - 5_000_000 and window["t"].max() < t_ns + 5_000_000
    events = sim.read_events(plane_sequence / "events.txt")
    inside = events[(events["t"] >= t_ns - 5_000_000) & (events["t"] < t_ns + 5_000_000)]
    assert np.array_equal(window, inside)                  # .h5 window == .txt file, same events
    assert set(np.unique(events["p"])) <= {-1, 1}


def test_the_mitsuba_sensor_module_keeps_its_old_path():
    """sim/sensor.py (the Mitsuba plugin) is now sim/mitsuba_sensor.py; the old path is an alias
    of the same module (sim._moved), not a copy."""
    import sim.sensor
    from sim.sensor import SENSOR_PLUGIN, register_sensor

    import sim.mitsuba_sensor

    assert sim.sensor is sim.mitsuba_sensor
    assert (SENSOR_PLUGIN, register_sensor) == ("evfuse_pinhole",
                                                sim.mitsuba_sensor.register_sensor)
