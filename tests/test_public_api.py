"""The public API survives the move into subpackages (issue 22): every public name imports from
the path it had before the move, and is the same object as the package's.

:data:`BEFORE` was taken from the code before the move (each name of the ``__all__`` of ``sim``,
``fusion`` and ``scenes`` with the module that defined it then; names defined in the private
``fusion._registry`` were public through ``fusion.methods``). It is frozen here on purpose: it is
the old layout, which the code no longer shows.
"""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

BEFORE = {
    "sim.camera": ["CAMERA_PRESETS", "Camera", "camera_preset", "read_calib", "write_calib"],
    "sim.eventio": ["EVENT_DTYPE", "H5EventWriter", "TextEventWriter", "convert_events",
                    "read_events", "read_window"],
    "sim.events": ["EventEmulator", "EventParams", "emulate_events"],
    "sim.shader": ["EventShader"],
    "sim.noise": ["NoiseParams", "noise_preset"],
    "sim.sampling": ["SamplingParams"],
    "sim.statistics": ["compare_stats", "event_frame", "event_stats", "frame_noise"],
    "sim.event_depth": ["read_event_depth"],
    "sim.flow": ["read_flow", "read_motion_field", "read_object_mask"],
    "sim.imu": ["ImuParams", "read_imu", "read_velocity"],
    "sim.frames": ["FrameParams", "luminance_to_frame"],
    "sim.sequence": ["FileIndex", "FrameCameraFiles", "Sequence", "load_sequence"],
    "sim.trajectory": ["HandheldTrajectory", "LinearTrajectory", "SampledTrajectory",
                       "SplineTrajectory", "Trajectory", "read_trajectory", "write_trajectory"],
    "sim.render": ["RenderResult", "Renderer"],
    "sim.scene": ["Scene", "SceneError", "load_scene", "parse_scene"],
    "sim.scene.procedural": ["PROCEDURAL_FAMILIES", "room_scene", "tabletop_scene"],  # new: 24
    "sim.simulate": ["SimulationResult", "simulate"],
    "sim.variant": ["active_variant", "use_variant"],
    "sim.exr": ["read_depth", "write_depth"],
    "sim.dataset": ["open_dataset"],
    "fusion.benchmark": ["BenchParams", "bench", "run_bench"],
    "fusion.emvs": ["DSIParams", "DepthMapParams", "depth_planes", "disparity_space_image",
                    "semidense_depth"],
    "fusion.dsi_range": ["DSIRange", "resolve_dsi_range"],
    "fusion.dense": ["DenseParams", "DenseResult", "FillInputs", "dense_errors", "densify",
                     "fill_frame", "fill_inputs", "fill_map", "project_map", "write_fill"],
    "fusion.methods": ["FillMethod", "MethodError", "MethodVariant", "available_methods",
                       "check_params", "get_method", "run_method", "register"],
    "fusion.filling": ["FillParams", "RegionStats", "SelectionParams", "exponential_weights",
                       "fill_regions", "filling_score", "gaussian_weights",
                       "inverse_distance_weights", "select_regions"],
    "fusion.mapping": ["MapParams", "MapResult", "TimeWindow", "map_sequence", "time_window",
                       "write_map"],
    "fusion.reproduce": ["ReproduceParams", "reproduce"],
    "fusion.pipeline": ["RunParams", "draw_overview", "fill_window", "map_window",
                        "run_pipeline"],
    "fusion.segmentation": ["SegmentationParams", "segment_regions"],
    "fusion.scoring": ["depth_errors", "discontinuity_band", "error_image"],
    "fusion.pointcloud": ["read_ply", "write_ply"],
    "scenes": ["SCENE_DIR", "builtin_scenes", "describe_scenes", "resolve_scene"],
}
"""Old module path -> the public names it defined before the move."""

OTHER_MODULES = ["fusion.baselines", "fusion.mesh_fill", "fusion.surface_fit",
                 "fusion.families", "fusion.experiments.families", "fusion.frame_projection",
                 "fusion.jsonio", "sim.rig"]
"""Modules without a name in ``__all__`` that a user may still have imported by their old path."""


@pytest.mark.parametrize("old", sorted(BEFORE))
def test_every_public_name_imports_from_its_old_path(old):
    module = importlib.import_module(old)
    package = importlib.import_module(old.split(".")[0])
    for name in BEFORE[old]:
        obj = getattr(module, name)
        if name in package.__all__:
            assert obj is getattr(package, name), f"{old}.{name} is not {package.__name__}.{name}"


def test_every_name_of_every_all_is_in_the_table():
    """The table covers the whole public API: nothing public was added without an old path
    (a new name is fine, but then it has no old path to keep; it is listed here)."""
    listed = {name for names in BEFORE.values() for name in names}
    for package in ("sim", "fusion", "scenes"):
        missing = set(importlib.import_module(package).__all__) - listed
        assert not missing, f"{package}.__all__ has names the table lacks: {sorted(missing)}"


@pytest.mark.parametrize("old", OTHER_MODULES)
def test_moved_modules_import_by_their_old_path(old):
    module = importlib.import_module(old)
    assert module.__name__ != old          # the module now living elsewhere, the same object
    assert sys.modules[old] is module


def test_old_paths_import_in_a_fresh_interpreter():
    """``import fusion.dense`` as a first import (no package imported before) works."""
    code = ("import fusion.dense, sim.rig, fusion.methods; "
            "from fusion.mesh_fill import *; from fusion.dense import densify; "
            "import fusion; assert fusion.dense.densify is fusion.densify; "
            "assert callable(fusion.reproduce) and callable(fusion.bench)")
    subprocess.run([sys.executable, "-c", code], check=True)
