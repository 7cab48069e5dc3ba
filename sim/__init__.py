"""evfuse's simulator: scenes, camera motion, Mitsuba rendering and sequence folders.

Importing ``sim`` does not import Mitsuba: the variant is chosen (and announced once) by the first
:class:`Renderer`, or explicitly with :func:`use_variant`.
"""

import sys

from sim._moved import alias_modules as _alias_modules
from sim.camera import CAMERA_PRESETS, Camera, camera_preset, read_calib, write_calib
from sim.dataset import open_dataset
from sim.event_depth import read_event_depth
from sim.eventio import (
    EVENT_DTYPE,
    H5EventWriter,
    TextEventWriter,
    convert_events,
    read_events,
    read_window,
)
from sim.events import EventEmulator, EventParams, emulate_events
from sim.exr import read_depth, write_depth
from sim.flow import read_flow, read_motion_field, read_object_mask
from sim.frames import FrameParams, luminance_to_frame
from sim.imu import ImuParams, read_imu, read_velocity
from sim.noise import NoiseParams, noise_preset
from sim.render import Renderer, RenderResult
from sim.sampling import SamplingParams
from sim.scene import (
    PROCEDURAL_FAMILIES,
    Scene,
    SceneError,
    load_scene,
    parse_scene,
    room_scene,
    tabletop_scene,
)
from sim.scene.procedural import use_exact_depth_check as _use_exact_depth_check
from sim.scene_check import exact_depth_check as _exact_depth_check
from sim.sequence import FileIndex, FrameCameraFiles, Sequence, load_sequence
from sim.shader import EventShader
from sim.simulate import SimulationResult, simulate
from sim.statistics import compare_stats, event_frame, event_stats, frame_noise
from sim.trajectory import (
    HandheldTrajectory,
    LinearTrajectory,
    SampledTrajectory,
    SplineTrajectory,
    Trajectory,
    read_trajectory,
    write_trajectory,
)
from sim.variant import active_variant, use_variant

__all__ = [
    "CAMERA_PRESETS",
    "EVENT_DTYPE",
    "Camera",
    "EventEmulator",
    "EventParams",
    "EventShader",
    "H5EventWriter",
    "NoiseParams",
    "SamplingParams",
    "TextEventWriter",
    "convert_events",
    "emulate_events",
    "compare_stats",
    "event_frame",
    "event_stats",
    "frame_noise",
    "noise_preset",
    "open_dataset",
    "read_events",
    "read_event_depth",
    "read_flow",
    "read_imu",
    "read_velocity",
    "read_motion_field",
    "read_object_mask",
    "read_window",
    "FrameParams",
    "FileIndex",
    "FrameCameraFiles",
    "HandheldTrajectory",
    "ImuParams",
    "LinearTrajectory",
    "RenderResult",
    "Renderer",
    "SampledTrajectory",
    "PROCEDURAL_FAMILIES",
    "Scene",
    "SceneError",
    "Sequence",
    "SimulationResult",
    "SplineTrajectory",
    "Trajectory",
    "active_variant",
    "camera_preset",
    "load_scene",
    "load_sequence",
    "luminance_to_frame",
    "parse_scene",
    "read_calib",
    "read_depth",
    "read_trajectory",
    "room_scene",
    "simulate",
    "tabletop_scene",
    "use_variant",
    "write_calib",
    "write_depth",
    "write_trajectory",
]

# Old module paths (before the moves of issue 22), kept importable: see sim._moved.
_alias_modules(sys.modules[__name__], {"sim.rig": "sim.capture_errors",
                                     "sim.sensor": "sim.mitsuba_sensor"})

# The procedural scenes' exact-depth check renders (sim.render), which the scene model may not
# import: it is handed down here, where both are imported (see sim.scene.procedural).
_use_exact_depth_check(_exact_depth_check)
