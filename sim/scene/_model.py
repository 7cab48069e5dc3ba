"""The parsed scene: frozen dataclasses for the render settings, materials, object motion,
objects, lights and the whole :class:`Scene` (what :mod:`sim.scene._toml` builds from a
scene file; nothing here reads TOML)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sim._summary import summary_repr
from sim.camera import Camera
from sim.capture_errors import RigParams
from sim.frame_camera import FrameCamera
from sim.frames import FrameParams
from sim.imu import ImuParams
from sim.se3 import make_pose, so3_exp
from sim.trajectory import Trajectory

__all__ = ["Light", "Material", "ObjectMotion", "RenderParams", "Scene", "SceneError",
           "SceneObject"]


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the file and the key."""



@dataclass(frozen=True)
class RenderParams:
    """How frames are rendered.

    Attributes
    ----------
    spp : int
        Samples per pixel of the frames (a perfect square: the sampler is stratified): of every
        pixel of a whole-frame render, and, where frames are rendered pixel by pixel
        (:mod:`sim.frame_shader`: static scenes on a JIT variant), of the pixels that an edge
        of the geometry or of a shadow crosses during the exposure. Default 16.
    flat_spp : int
        Samples per pixel of the frames' other pixels where frames are rendered pixel by
        pixel (a perfect square; at most ``spp``, which replaces it where it is larger).
        Default 4.
    pose_rate : float
        Rate of the written ``groundtruth.txt``, Hz (>= 200). Default 1000.
    event_spp : int
        Samples per pixel of the renders that drive the event camera (a perfect square; there
        are hundreds to thousands of them per second). Default 4.
    edge_spp : int
        Samples per pixel of the event camera's renders of the pixels that an edge of the
        geometry or of a shadow crosses (either sampler, a JIT variant; a perfect square
        above ``event_spp``), or 0 (default): every pixel at ``event_spp``. See
        :mod:`sim.pixel_sampling`.
    seed : int or None
        Seed of the renders' sampling patterns: the event camera's sub-sample jitter
        (:func:`sim.shader.subsample_jitter`) and the frames' sampler. None (default): the
        scene's ``seed``. Textures and noise keep the scene's seed, so that two seeds render
        the same scene with other samples: the spread of a result over seeds is its sampling
        noise.
    """

    spp: int = 16
    pose_rate: float = 1000.0
    event_spp: int = 4
    edge_spp: int = 0
    seed: int | None = None
    flat_spp: int = 4


@dataclass(frozen=True)
class Material:
    """A diffuse material: a constant colour or a texture.

    Attributes
    ----------
    color : (3,) tuple of float
        Linear RGB reflectance in [0, 1] (a single number means grey).
    texture : dict or None
        Texture description (``type`` plus its fields), see :mod:`sim.textures`.
    texture_scale : (2,) tuple of float
        How many times the texture repeats along u and v.
    """

    color: tuple[float, float, float] = (0.5, 0.5, 0.5)
    texture: Mapping[str, Any] | None = None
    texture_scale: tuple[float, float] = (1.0, 1.0)


@dataclass(frozen=True)
class ObjectMotion:
    """Rigid motion of an object about its centre, as a function of time.

    ``linear``: displacement velocity * t and rotation by angular_velocity * t.
    ``sine``: displacement amplitude * sin(2 pi frequency t + phase), no rotation.

    Attributes
    ----------
    kind : {"linear", "sine"}
    velocity : (3,) ndarray, m/s (linear)
    angular_velocity : (3,) ndarray, rad/s, world axes (linear)
    amplitude : (3,) ndarray, m (sine)
    frequency : float, Hz (sine)
    phase : float, rad (sine)
    """

    kind: str
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    amplitude: np.ndarray = field(default_factory=lambda: np.zeros(3))
    frequency: float = 0.0
    phase: float = 0.0

    __repr__ = summary_repr

    def offset(self, t: float) -> np.ndarray:
        """Rigid displacement at time ``t``: (4,4) transform applied about the object centre."""
        if self.kind == "linear":
            rotation = so3_exp(self.angular_velocity * t)
            translation = self.velocity * t
        else:
            rotation = np.eye(3)
            translation = self.amplitude * math.sin(2 * math.pi * self.frequency * t + self.phase)
        return make_pose(rotation, translation)

    def twist(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The time derivative of :meth:`offset` at ``t``, world axes.

        Returns
        -------
        v : (3,) float64 ndarray, m/s
            Velocity of the object's centre.
        w : (3,) float64 ndarray, rad/s
            Angular velocity: a point ``X`` of the object moves at ``v + w x (X - centre)``.
        """
        if self.kind == "linear":
            return np.array(self.velocity, dtype=float), np.array(self.angular_velocity,
                                                                  dtype=float)
        omega = 2 * math.pi * self.frequency
        return self.amplitude * omega * math.cos(omega * t + self.phase), np.zeros(3)


@dataclass(frozen=True)
class SceneObject:
    """One object of a scene.

    Attributes
    ----------
    name : str
    shape : {"rectangle", "box", "sphere", "cylinder", "heightfield", "mesh"}
    center : (3,) ndarray, metres, world frame
    rotation : (3,3) ndarray
        Orientation of the object's local frame in the world.
    params : dict
        Shape parameters, already validated (sizes in metres).
    material : Material
    motion : ObjectMotion or None
    """

    name: str
    shape: str
    center: np.ndarray
    rotation: np.ndarray
    params: Mapping[str, Any]
    material: Material
    motion: ObjectMotion | None = None

    __repr__ = summary_repr

    def pose(self, t: float = 0.0) -> np.ndarray:
        """Object-to-world rigid transform (4,4) at time ``t`` (without the shape's scaling)."""
        base = make_pose(self.rotation, self.center)
        if self.motion is None:
            return base
        delta = self.motion.offset(t)
        moved = base.copy()
        moved[:3, :3] = delta[:3, :3] @ self.rotation
        moved[:3, 3] = self.center + delta[:3, 3]
        return moved

    def half_extents(self) -> np.ndarray:
        """Half sizes (3,) of the bounding box in the object's local frame, metres (zeros for a
        mesh, whose extent is only known once loaded)."""
        p = self.params
        if self.shape in ("rectangle", "heightfield"):
            depth = p["amplitude"] if self.shape == "heightfield" else 0.0
            return np.array([p["size"][0] / 2, p["size"][1] / 2, depth])
        if self.shape == "box":
            return np.asarray(p["size"], dtype=float) / 2
        if self.shape == "sphere":
            return np.full(3, float(p["radius"]))
        if self.shape == "cylinder":
            return np.array([p["radius"], p["radius"], p["height"] / 2])
        return np.zeros(3)

    def distance_to(self, points: np.ndarray) -> np.ndarray:
        """Distance (N,) metres from world points (N, 3) to the object at rest: to its surface
        for a sphere, to its bounding box otherwise (to its centre for a mesh); 0 inside."""
        local = (np.asarray(points, dtype=float) - self.center) @ self.rotation
        if self.shape == "sphere":
            return np.maximum(np.linalg.norm(local, axis=1) - float(self.params["radius"]), 0.0)
        return np.linalg.norm(np.maximum(np.abs(local) - self.half_extents(), 0.0), axis=1)


@dataclass(frozen=True)
class Light:
    """A light that needs no sampling, so that renders carry no noise.

    Lights are photometric (see :mod:`sim.radiometry`): renders come out in cd/m^2.

    Attributes
    ----------
    kind : {"point", "spot", "directional"}
    intensity : (3,) ndarray
        Luminous intensity in candela (lm/sr) for point and spot lights (TOML
        ``intensity_cd``), illuminance in lux on a surface facing it for a directional light
        (TOML ``illuminance_lux``); per RGB channel, equal for a grey light.
    position : (3,) ndarray or None
    target : (3,) ndarray or None
        Where a spot light points.
    direction : (3,) ndarray or None
        Direction a directional light travels.
    cutoff_angle, beam_width : float
        Spot light cone (degrees).
    """

    kind: str
    intensity: np.ndarray
    position: np.ndarray | None = None
    target: np.ndarray | None = None
    direction: np.ndarray | None = None
    cutoff_angle: float = 20.0
    beam_width: float = 15.0

    __repr__ = summary_repr


@dataclass(frozen=True)
class Scene:
    """A validated scene.

    Attributes
    ----------
    name, description : str
    duration : float
        Length of the sequence, seconds.
    seed : int
        Seed of every random draw (textures, noise).
    camera : Camera
    frames : FrameParams
        The standard camera.
    render : RenderParams
    trajectory : Trajectory
        ``T_world_camera(t)``.
    lights : tuple of Light
    objects : tuple of SceneObject
    source : Path or None
        The file it was read from (textures and meshes are relative to its folder).
    text : str
        The TOML text it was parsed from.
    depth_range : (float, float) or None, metres
        The rig's declared working depth range (top-level ``depth_range``): the range of the
        DSI that ``evfuse map`` / ``run`` / ``reproduce`` use for this scene's sequences unless
        the user gives one. A declaration, as a person setting up the rig would choose it (as
        rpg_emvs's configs declare one per sequence), never computed from the exact depth.
    rig : RigParams
        How the written poses, clocks and calibration depart from the truth (``[rig]``;
        default perfect, :mod:`sim.capture_errors`).
    up : (3,) tuple of float
        Which way is up in the world (top-level ``up``, normalised; default ``+z``, as in the
        built-in scenes): gravity points along ``-up``.
    imu : ImuParams
        The IMU riding with the camera (``[imu]``; default the ``ideal`` one, :mod:`sim.imu`).
    frame_camera : FrameCamera or None
        A rig's separate frame camera (``[event_camera]`` + ``[frame_camera]``); then
        ``camera`` is the event camera and ``trajectory`` its ``T_world_event(t)``. None for
        ``[camera]``: one DAVIS-like sensor gives both events and frames.
    """

    name: str
    description: str
    duration: float
    seed: int
    camera: Camera
    frames: FrameParams
    render: RenderParams
    trajectory: Trajectory
    lights: tuple[Light, ...]
    objects: tuple[SceneObject, ...]
    source: Path | None = None
    text: str = ""
    depth_range: tuple[float, float] | None = None
    rig: RigParams = field(default_factory=RigParams)
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    imu: ImuParams = field(default_factory=ImuParams)
    frame_camera: FrameCamera | None = None

    __repr__ = summary_repr

    @property
    def base_dir(self) -> Path:
        """Folder that relative paths in the scene file are resolved against."""
        return self.source.parent if self.source is not None else Path.cwd()

    @property
    def render_seed(self) -> int:
        """Seed of the renders' sampling patterns: ``[render] seed``, else the scene's
        ``seed`` (:attr:`RenderParams.seed`)."""
        return self.render.seed if self.render.seed is not None else self.seed

    @property
    def is_dynamic(self) -> bool:
        """True when some object moves on its own."""
        return any(obj.motion is not None for obj in self.objects)
