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
