"""Render linear luminance and exact z-depth of a scene with Mitsuba 3.

One :class:`Renderer` loads a scene once and re-renders it for any time and pose: the camera
pose and moving objects are changed through Mitsuba's parameter API, so the compiled kernels are
reused (no reload, no recompilation).

- Luminance, in cd/m^2: the scene's lights are photometric (candela, lux; see
  :mod:`sim.radiometry`) and rendering is linear in them, so a white Lambertian surface of
  albedo rho under E lux renders rho E / pi (tested). Mitsuba's ``direct`` integrator with
  point, spot and directional lights only, a
  stratified sampler and a fixed seed, a box pixel filter (each pixel integrates its own square).
  Bitmap textures are area-averaged to about one texel per pixel footprint at the object's
  closest approach (Mitsuba's bitmap has no mipmaps), and on JIT variants every sample reads its
  texture filtered over its own footprint on the surface (:class:`sim.textures.TextureFilter`:
  mip pyramids and an analytic box-filtered checkerboard, through the ``evfuse_direct``
  integrator, :func:`register_integrator`), the same lookup as the event camera's
  (:mod:`sim.shader`): texels finer than a pixel would alias under point sampling and make
  renders flicker under sub-pixel motion.
  With lights that need no sampling, the only random draws are the sub-pixel positions, which
  the fixed seed freezes: the same pose gives bit-identical images and there is no frame-to-frame
  flicker for the event emulator to see. Interreflections are not simulated.
- Depth: one ray through each pixel centre (the camera model's ray, distortion included),
  intersected with the scene; z = t_hit * d_z for the unit direction d in the camera frame, 0 where
  nothing is hit. No sub-pixel averaging, so no mixing across depth edges.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from sim._summary import summary_repr
from sim.scene._meshes import heightfield_mesh, vertex_normals
from sim.scene._model import Light, Scene, SceneObject
from sim.variant import use_variant

__all__ = ["RenderResult", "Renderer"]


@dataclass(frozen=True)
class RenderResult:
    """One rendered view.

    Attributes
    ----------
    luminance : (H, W) float32 ndarray, cd/m^2
        Linear luminance Y (HDR, no tone mapping) of the surface each pixel sees, from the
        scene's photometric lights (see :mod:`sim.radiometry`).
    depth : (H, W) float32 ndarray
        z-depth in metres at pixel centres, 0 where nothing is hit.
    """

    luminance: np.ndarray
    depth: np.ndarray

    __repr__ = summary_repr


def _key(index: int, name: str) -> str:
    return f"o{index}_" + re.sub(r"[^A-Za-z0-9_]", "_", name)[:40]


def _transform(matrix: np.ndarray):
    import mitsuba as mi

    return mi.ScalarTransform4f(np.asarray(matrix, dtype=np.float64).tolist())


def _diag(*scale: float) -> np.ndarray:
    return np.diag([*scale, 1.0])


def _heightfield_mesh(name: str, obj: SceneObject):
    """Triangle mesh of z = A sin(2 pi x / lx) cos(2 pi y / ly) over the size, local frame."""
    import mitsuba as mi

    p = obj.params
    vertices, uv, faces = heightfield_mesh(p["size"], p["amplitude"], p["wavelength"],
                                           p["resolution"])
    mesh = mi.Mesh(name, len(vertices), len(faces), has_vertex_normals=True,
                   has_vertex_texcoords=True)
    mesh.set_id(name)
    params = mi.traverse(mesh)
    _set_buffer(params, "vertex_positions", vertices)
    _set_buffer(params, "faces", faces)
    _set_buffer(params, "vertex_texcoords", uv)
    params.update()
    return mesh


def _set_buffer(params, key: str, values: np.ndarray) -> None:
    """Set a mesh's buffer parameter (``...vertex_positions``, ``...faces``, ...) from an array.

    In the parameter's own array type, which is ``mi.Float`` or ``mi.UInt32`` on JIT variants
    but a dynamic array on ``scalar_rgb`` (where ``mi.Float`` is a Python float, which refused
    an array: height fields did not load there).

    Parameters
    ----------
    params : mi.SceneParameters
        A mesh's or a scene's ``mi.traverse``.
    key : str
        The parameter's key.
    values : ndarray
        Its new values, any shape (flattened), float32 (unsigned 32-bit integers for faces).
    """
    dtype = np.uint32 if key.endswith("faces") else np.float32
    params[key] = type(params[key])(np.ascontiguousarray(values, dtype=dtype).ravel())


def _set_normals(mesh_params, prefix: str = "") -> None:
    """Give a mesh the normals of :func:`sim.scene.vertex_normals`, from its positions and
    faces in ``mesh_params`` (its ``mi.traverse``, or the scene's with ``prefix`` its key and a
    dot), replacing the ones Mitsuba summed in thread order (see there); a mesh without vertex
    normals (flat shaded) is left alone.

    Call it after an update that changed the positions: Mitsuba recomputes the normals then,
    in its own order. Scalar variants sum them in face order already and are left alone.
    """
    if not _jit() or len(mesh_params[f"{prefix}vertex_normals"]) == 0:
        return
    positions = np.asarray(mesh_params[f"{prefix}vertex_positions"]).reshape(-1, 3)
    faces = np.asarray(mesh_params[f"{prefix}faces"]).reshape(-1, 3)
    _set_buffer(mesh_params, f"{prefix}vertex_normals", vertex_normals(positions, faces))
    mesh_params.update()


def _jit() -> bool:
    """Whether the active Mitsuba variant is a JIT one (LLVM or CUDA)."""
    import drjit as dr
    import mitsuba as mi

    return dr.is_jit_v(mi.Float)


def _file_has_normals(path: str) -> bool:
    """Whether a mesh file gives its own vertex normals (OBJ ``vn`` lines, a PLY vertex
    property ``nx``), which Mitsuba then reads instead of computing them."""
    with open(path, "rb") as file:
        if path.lower().endswith(".ply"):
            for line in file:
                if line.strip() == b"end_header":
                    return False
                if line.split()[-1:] == [b"nx"]:
                    return True
            return False
        return any(line.startswith(b"vn ") for line in file)


def _texture_extent(obj: SceneObject) -> tuple[float, float] | None:
    """Smallest world size (m) one repeat of the texture spans along u and v; None if unknown.

    A box maps the whole texture onto every face, so its smallest side bounds the texel size.
    """
    p = obj.params
    if obj.shape in ("rectangle", "heightfield"):
        width, height = p["size"]
    elif obj.shape == "box":
        width = height = min(p["size"])
    elif obj.shape == "sphere":
        width, height = 2 * np.pi * p["radius"], np.pi * p["radius"]
    elif obj.shape == "cylinder":
        width, height = 2 * np.pi * p["radius"], p["height"]
    else:
        return None
    su, sv = obj.material.texture_scale
    return width / su, height / sv


def _max_texels(obj: SceneObject, scene: Scene) -> tuple[float, float] | None:
    """Texels worth keeping: about one per pixel footprint where the camera comes closest.

    The closest approach is the distance from the camera centre (200 times along the
    trajectory) to the object's bounding box (sphere: to its surface), at least 1 cm; object
    motion is ignored.
    """
    extent = _texture_extent(obj)
    if extent is None:
        return None
    traj = scene.trajectory
    times = np.linspace(max(traj.t_start, 0.0), min(traj.t_end, scene.duration), 200)
    gaps = obj.distance_to(traj.pose(times)[:, :3, 3])
    nearest = max(float(gaps.min()), 0.01)
    footprint = nearest / max(scene.camera.fx, scene.camera.fy)       # metres per pixel
    return extent[0] / footprint, extent[1] / footprint


def _bsdf_dict(index: int, obj: SceneObject, scene: Scene) -> dict:
    """Mitsuba plugin dictionary of one object's material (its texture loaded)."""
    from sim.textures import mitsuba_texture

    material = obj.material
    if material.texture is not None:
        reflectance = mitsuba_texture(material.texture, material.texture_scale,
                                      scene.seed + index,
                                      flip_v=obj.shape in ("rectangle", "cylinder"),
                                      max_texels=_max_texels(obj, scene))
    else:
        reflectance = {"type": "rgb", "value": list(material.color)}
    # The id lets sim.textures.TextureFilter find the material of a hit (its BSDF; a capped
    # cylinder's caps get ids o{index}_bsdf_top and _bottom, see _shape_dicts).
    return {"type": "twosided", "id": f"o{index}_bsdf",
            "material": {"type": "diffuse", "reflectance": reflectance}}


BOUNDED_UV_SHAPES = ("rectangle", "box", "heightfield")
"""Shapes whose every face spans (u, v) in [0, 1] x [0, 1], its edges at the bounds (a box's
six faces each): a footprint filter stops there (:class:`sim.textures.TextureFilter`). A sphere's
and a cylinder's u wraps round, a mesh file's (u, v) may be anything."""


def _texture_materials(scene: Scene) -> list[tuple | None]:
    """Per object, the arguments of its texture as :class:`sim.textures.TextureFilter` takes
    them (the same as :func:`_bsdf_dict` gives :func:`sim.textures.mitsuba_texture`, and
    whether its (u, v) are bounded: :data:`BOUNDED_UV_SHAPES`)."""
    return [None if obj.material.texture is None else
            (obj.material.texture, obj.material.texture_scale, scene.seed + index,
             obj.shape in ("rectangle", "cylinder"), _max_texels(obj, scene),
             obj.shape in BOUNDED_UV_SHAPES)
            for index, obj in enumerate(scene.objects)]


INTEGRATOR_PLUGIN = "evfuse_direct"
_integrator_registered: str | None = None


def direct_light(scene, si, bsdf, active, texture=1.0):
    """Direct light reflected at hits towards the camera: the sum over EVERY light of the scene.

    The expected value of Mitsuba's ``direct`` integrator with one emitter sample and no BSDF
    sample (it picks ONE light at random and weights it by the number of lights): evfuse's
    lights (point, spot, directional) are delta lights, whose direction needs no sample, so
    summing them all, each with its own shadow ray, leaves no random draw. The one estimator of
    the frames (:func:`register_integrator`) and the event camera (:mod:`sim.shader`).

    Parameters
    ----------
    scene : mi.Scene
    si : mi.SurfaceInteraction3f
        The hits (``RayFlags.All``).
    bsdf : mi.BSDFPtr
        ``si.bsdf()``.
    active : mi.Bool
        Lanes that hit something.
    texture : mi.Float or float
        Factor on every light's BSDF value (:func:`sim.textures.filtered_scale`; 1: Mitsuba's
        own texture lookup).

    Returns
    -------
    mi.Color3f
        Linear RGB radiance, 0 where inactive or in every light's shadow.
    """
    import drjit as dr
    import mitsuba as mi

    context = mi.BSDFContext()
    centre = mi.Point2f(0.5, 0.5)                # delta lights ignore their sample
    rgb = mi.Color3f(0.0)
    for emitter in scene.emitters():
        ds, weight = emitter.sample_direction(si, centre, active)
        lit = active & (ds.pdf != 0.0)
        lit = dr.select(scene.ray_test(si.spawn_ray_to(ds.p), lit), False, lit)  # not ~: bool
        value = bsdf.eval(context, si, si.to_local(ds.d), lit) * weight * texture
        rgb += dr.select(lit, value, 0.0)
    return rgb


def register_integrator() -> None:
    """Register the ``evfuse_direct`` integrator with the active variant (idempotent).

    The expected value of Mitsuba's ``direct`` integrator as it would be configured here (one
    emitter sample, no BSDF sample; evfuse's lights are all delta lights, whose MIS weight is 1):
    every light's contribution with its own shadow ray (:func:`direct_light`, the event
    camera's shading), where ``direct`` picks one light at random per sample, which left
    light-selection noise in frames of scenes with two lights (boxes_6dof's frames at 16
    samples per pixel: 39 dB against a 256-sample render, two seeds 36 dB apart). The only
    random draws left are the sub-pixel positions (the ``stratified`` sampler).
    Each hit's texture is read filtered over the sample's footprint
    (:func:`sim.textures.filtered_scale`, the event camera's lookup), from the sensor's ray
    differentials (the pinhole rays one pixel right and down), which Mitsuba's render loop
    scales by ``1 / sqrt(spp)``: each sample's footprint is its stratum of the pixel. Its
    ``filtering`` attribute holds :attr:`sim.textures.TextureFilter.arrays` (set by the
    :class:`Renderer`; None reads the textures as points, Mitsuba's own lookup).
    ``scalar_rgb`` runs it too (a Python call per sample: 1.0-1.65 times ``direct``'s time
    there, measured at 96x72, spp 4, loaded machine), so that its frames and event camera have
    the JIT variants' estimator: ``direct``'s one light per sample was 24 % off the mean
    luminance of a mesh under two lights at spp 1.
    """
    global _integrator_registered
    import drjit as dr
    import mitsuba as mi

    from sim.textures import filtered_scale

    if _integrator_registered == mi.variant():
        return

    jit = dr.is_jit_v(mi.Float)

    class FilteredDirect(mi.SamplingIntegrator):
        """Every light's direct light, footprint-filtered textures (see
        :func:`register_integrator`)."""

        def __init__(self, props):
            super().__init__(props)
            self.filtering = None

        def sample(self, scene, sampler, ray, medium=None, active=True):
            si = scene.ray_intersect(mi.Ray3f(ray), ray_flags=mi.RayFlags.All, coherent=True,
                                     active=active)
            valid = mi.Bool(active) & si.is_valid()
            if not jit and not valid:
                return mi.Color3f(0.0), False, []   # scalar: a miss has no BSDF to call
            bsdf = si.bsdf()
            texture = 1.0
            if self.filtering is not None:
                si.compute_uv_partials(ray)
                texture = filtered_scale(self.filtering, si, bsdf, valid)
            return dr.select(valid, direct_light(scene, si, bsdf, valid, texture), 0.0), \
                valid, []

        def aov_names(self):
            return []

        def to_string(self):
            return "FilteredDirect[]"

    mi.register_integrator(INTEGRATOR_PLUGIN, lambda props: FilteredDirect(props))
    _integrator_registered = mi.variant()


def _object_index(shape_id: str) -> int:
    """``scene.objects`` index of the object a Mitsuba shape (keyed by :func:`_key`) belongs
    to, from its id ``o{index}_...``; -1 for a shape without such an id."""
    found = re.match(r"o(\d+)_", shape_id)
    return int(found.group(1)) if found else -1


def _shape_dicts(index: int, obj: SceneObject, scene: Scene,
                 bsdf: dict | None = None) -> dict[str, dict]:
    """Mitsuba plugin dictionaries of one object (several for a capped cylinder), with the
    given material (default the object's own, see :func:`_bsdf_dict`)."""
    bsdf = _bsdf_dict(index, obj, scene) if bsdf is None else bsdf
    pose = replace(obj, motion=None).pose()     # at rest: _set_state moves it to its time
    key = _key(index, obj.name)
    p = obj.params
    if obj.shape == "rectangle":
        return {key: {"type": "rectangle", "bsdf": bsdf,
                      "to_world": _transform(pose @ _diag(p["size"][0] / 2, p["size"][1] / 2, 1))}}
    if obj.shape == "box":
        return {key: {"type": "cube", "bsdf": bsdf,
                      "to_world": _transform(pose @ _diag(*(np.asarray(p["size"]) / 2)))}}
    if obj.shape == "sphere":
        r = p["radius"]
        return {key: {"type": "sphere", "bsdf": bsdf,
                      "to_world": _transform(pose @ _diag(r, r, r))}}
    if obj.shape == "cylinder":
        r, h = p["radius"], p["height"]
        shift = np.eye(4)
        shift[2, 3] = -h / 2
        shapes = {key: {"type": "cylinder", "bsdf": bsdf,
                        "to_world": _transform(pose @ shift @ _diag(r, r, h))}}
        if p["caps"]:
            for sign, suffix in ((1.0, "_top"), (-1.0, "_bottom")):
                cap = np.eye(4)
                cap[2, 3] = sign * h / 2
                flip = np.diag([1.0, sign, sign, 1.0])
                cap_bsdf = {**bsdf, "id": bsdf["id"] + suffix} if "id" in bsdf else bsdf
                shapes[key + suffix] = {"type": "disk", "bsdf": cap_bsdf,
                                        "to_world": _transform(pose @ cap @ flip @ _diag(r, r, 1))}
        return shapes
    if obj.shape == "heightfield":
        import mitsuba as mi

        mesh = _heightfield_mesh(key, obj)
        mesh_params = mi.traverse(mesh)
        local = np.asarray(mesh_params["vertex_positions"]).reshape(-1, 3)
        world = local @ pose[:3, :3].T + pose[:3, 3]
        _set_buffer(mesh_params, "vertex_positions", world)
        mesh_params.update()
        _set_normals(mesh_params)
        mesh.set_bsdf(mi.load_dict(bsdf))
        return {key: mesh}
    suffix = p["path"].rsplit(".", 1)[-1].lower()
    s = p["scale"]
    description = {"type": suffix, "filename": p["path"], "bsdf": bsdf,
                   "to_world": _transform(pose @ _diag(s, s, s))}
    if not _jit() or _file_has_normals(p["path"]):
        return {key: description}
    import mitsuba as mi

    mesh = mi.load_dict({**description, "id": key})
    _set_normals(mi.traverse(mesh))
    return {key: mesh}


def _light_dict(light: Light) -> dict:
    import mitsuba as mi

    spectrum = {"type": "rgb", "value": [float(v) for v in light.intensity]}
    if light.kind == "point":
        return {"type": "point", "position": light.position.tolist(), "intensity": spectrum}
    if light.kind == "directional":
        return {"type": "directional", "direction": light.direction.tolist(),
                "irradiance": spectrum}
    direction = light.target - light.position
    up = np.array([0.0, 0.0, 1.0])
    if abs(np.dot(direction, up)) > 0.99 * np.linalg.norm(direction):
        up = np.array([0.0, 1.0, 0.0])
    return {"type": "spot", "intensity": spectrum, "cutoff_angle": light.cutoff_angle,
            "beam_width": light.beam_width,
            "to_world": mi.ScalarTransform4f().look_at(origin=light.position.tolist(),
                                                       target=light.target.tolist(),
                                                       up=up.tolist())}


class Renderer:
    """Renders a scene's luminance and depth for any time and camera pose.

    Parameters
    ----------
    scene : Scene
        A validated scene (see :func:`sim.scene.load_scene`).
    spp : int, optional
        Samples per pixel (a perfect square), default the scene's ``render.spp``.
    seed : int, optional
        Seed of the renders' sampling patterns (the frames' sampler, the event camera's
        sub-sample jitter: :class:`sim.shader.EventShader`), fixed for every render; default
        the scene's ``[render] seed``, else its ``seed``. Textures keep the scene's seed.
    variant : str, optional
        Mitsuba variant (see :func:`sim.variant.use_variant`).
    rows : bool
        Give every image row its own pose (a rolling shutter: :meth:`luminance_rows`,
        :meth:`depth_rows`); JIT variants only.
    texture_filter : bool
        Read textures filtered over each sample's footprint (default; JIT variants only: with
        ``scalar_rgb`` textures are read as points). The frames (:meth:`luminance`, through the
        ``evfuse_direct`` integrator, see :func:`register_integrator`) and the event camera
        (:class:`sim.shader.EventShader`) use the same lookup, :attr:`texture_filter`. False
        reads them as points, as Mitsuba does (a reference at many samples per pixel).

    Examples
    --------
    >>> renderer = Renderer(load_builtin_scene("slider_close"))      # doctest: +SKIP
    >>> view = renderer.render(0.5)                                   # doctest: +SKIP
    >>> view.luminance.shape, view.depth.dtype                        # doctest: +SKIP
    ((180, 240), dtype('float32'))
    """

    def __init__(self, scene: Scene, *, spp: int | None = None, seed: int | None = None,
                 variant: str | None = None, rows: bool = False, texture_filter: bool = True):
        self.variant = use_variant(variant)
        if rows and self.variant == "scalar_rgb":
            raise ValueError("a renderer with a pose per row (a rolling shutter) needs a JIT "
                             "variant (llvm_ad_rgb or cuda_ad_rgb), not scalar_rgb")
        self.rows = bool(rows)
        import drjit as dr
        import mitsuba as mi

        from sim.mitsuba_sensor import SENSOR_PLUGIN, register_sensor

        register_sensor()
        self.scene = scene
        self.camera = scene.camera
        self.spp = int(spp if spp is not None else scene.render.spp)
        if self.spp < 1 or math.isqrt(self.spp) ** 2 != self.spp:
            raise ValueError(f"spp must be a perfect square >= 1, got {self.spp}")
        self.seed = int(seed if seed is not None else scene.render_seed)
        cam = self.camera
        k1, k2, p1, p2, k3 = cam.distortion
        jit = self.variant != "scalar_rgb"
        filtering = texture_filter and jit
        register_integrator()
        description: dict = {
            "type": "scene",
            "integrator": {"type": INTEGRATOR_PLUGIN},
            "sensor": {
                "type": SENSOR_PLUGIN,
                "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
                "k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": k3,
                "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                         "pixel_format": "luminance", "rfilter": {"type": "box"},
                         "sample_border": False},
                "sampler": {"type": "stratified", "sample_count": self.spp, "jitter": True},
                **({"rows": True} if rows else {}),
            },
        }
        for i, light in enumerate(scene.lights):
            description[f"light{i}"] = _light_dict(light)
        self._moving: list[tuple[SceneObject, str, str, np.ndarray]] = []
        # Normals at rest of the moving meshes (JIT variants): rotated with them at every move.
        self._rest_normals: dict[str, np.ndarray] = {}
        shape_keys: list[tuple[SceneObject, str]] = []
        for i, obj in enumerate(scene.objects):
            shapes = _shape_dicts(i, obj, scene)
            description.update(shapes)
            shape_keys += [(obj, key) for key in shapes]
        self._mi, self._dr = mi, dr
        # Mitsuba merges meshes that share a material unless told not to; moving objects must
        # keep their own parameters, so dynamic scenes are loaded without that optimisation.
        self._scene = mi.load_dict(description, optimize=not scene.is_dynamic)
        self._params = mi.traverse(self._scene)
        self.texture_filter = None
        """:class:`sim.textures.TextureFilter` or None: the footprint-filtered textures that
        the frames and the event camera read (None: point lookups, or no texture)."""
        if filtering:
            from sim.textures import TextureFilter

            self.texture_filter = TextureFilter(self._scene, _texture_materials(scene))
            self._scene.integrator().filtering = self.texture_filter.arrays
        for obj, key in shape_keys:
            if obj.motion is None:
                continue
            if f"{key}.vertex_positions" in self._params.keys():
                initial = np.array(self._params[f"{key}.vertex_positions"]).reshape(-1, 3)
                self._moving.append((obj, key, "vertex_positions", initial))
                if _jit() and len(self._params[f"{key}.vertex_normals"]):
                    self._rest_normals[key] = np.array(
                        self._params[f"{key}.vertex_normals"], dtype=np.float64).reshape(-1, 3)
            else:
                initial = np.array(self._params[f"{key}.to_world"].matrix).reshape(4, 4)
                self._moving.append((obj, key, "to_world", initial))
        # Pixel-centre rays of the camera model, unit vectors in the camera frame.
        xy = cam.normalized_pixel_centres().reshape(-1, 2)
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        self._rays_np = rays
        if self.variant != "scalar_rgb":
            self._rays = mi.Vector3f(*(rays[:, i].astype(np.float32) for i in range(3)))
        self._pose: np.ndarray | None = None
        self._time: float | None = None
        self._geometry = None                            # see _geometry_scene

    # ----------------------------------------------------------------------------------------
    def _checked_pose(self, t: float, pose: np.ndarray | None) -> np.ndarray:
        """``pose`` (default the trajectory's at ``t``), checked: a finite (4, 4) float64."""
        if pose is None:
            pose = self.scene.trajectory.pose(float(t))
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError(f"pose must be a finite (4, 4) T_world_camera, got shape {pose.shape}")
        return pose

    def _set_state(self, t: float, pose: np.ndarray | None) -> np.ndarray:
        """Move the camera (and the moving objects) to time ``t``; return the pose used."""
        mi = self._mi
        pose = self._checked_pose(t, pose)
        changed = False
        normals: dict[str, np.ndarray] = {}
        if self._pose is None or not np.array_equal(pose, self._pose):
            self._params["sensor.R"] = mi.Matrix3f(pose[:3, :3].astype(np.float32))
            self._params["sensor.t"] = mi.Point3f(*pose[:3, 3].astype(np.float32).tolist())
            self._pose = pose.copy()
            changed = True
        if self._moving and t != self._time:
            for obj, key, kind, initial in self._moving:
                delta = obj.motion.offset(float(t))
                center = obj.center
                if kind == "vertex_positions":
                    moved = (initial - center) @ delta[:3, :3].T + center + delta[:3, 3]
                    _set_buffer(self._params, f"{key}.{kind}", moved)
                    if key in self._rest_normals:
                        normals[key] = self._rest_normals[key] @ delta[:3, :3].T
                else:
                    about = np.eye(4)
                    about[:3, 3] = center
                    back = np.eye(4)
                    back[:3, 3] = -center
                    self._params[f"{key}.{kind}"] = mi.Transform4f(
                        (about @ delta @ back @ initial).tolist())
            self._time = t
            changed = True
        if changed:
            self._params.update()
        if normals:
            # Mitsuba recomputed the moved meshes' normals in thread order (see _set_normals):
            # the fixed-order ones at rest, rotated with the mesh, replace them.
            for key, value in normals.items():
                _set_buffer(self._params, f"{key}.vertex_normals", value)
            self._params.update()
        return pose

    def set_time(self, t: float) -> None:
        """Move the camera (to the trajectory's pose) and the moving objects to time ``t``.

        For code that traces its own rays in :attr:`mitsuba_scene` (such as
        :class:`sim.shader.EventShader`) and needs the objects where they are at ``t``.

        Parameters
        ----------
        t : float, seconds
        """
        self._set_state(float(t), None)

    def luminance(self, t: float, pose: np.ndarray | None = None, spp: int | None = None
                  ) -> np.ndarray:
        """Linear luminance (H, W) float32, cd/m^2, at time ``t`` (pose from the trajectory by
        default).

        ``spp`` overrides the renderer's samples per pixel (a perfect square) for this call.
        """
        spp = self.spp if spp is None else int(spp)
        if spp < 1 or math.isqrt(spp) ** 2 != spp:
            raise ValueError(f"spp must be a perfect square >= 1, got {spp}")
        self._set_state(t, pose)
        image = self._mi.render(self._scene, seed=self.seed, spp=spp)
        return np.array(image, dtype=np.float32).reshape(self.camera.height, self.camera.width)

    def depth(self, t: float, pose: np.ndarray | None = None) -> np.ndarray:
        """z-depth (H, W) float32 in metres at pixel centres, 0 where nothing is hit."""
        pose = self._set_state(t, pose)
        mi, dr = self._mi, self._dr
        shape = (self.camera.height, self.camera.width)
        if self.variant == "scalar_rgb":
            return self._depth_scalar(pose).reshape(shape)
        rotation = mi.Matrix3f(pose[:3, :3].astype(np.float32))
        origin = mi.Point3f(*pose[:3, 3].astype(np.float32).tolist())
        dr.make_opaque(rotation, origin)                 # else each pose compiles a new kernel
        return self._cast_depth(mi.Ray3f(origin, rotation @ self._rays), self._rays.z, shape)

    def _cast_depth(self, ray, axis_z, shape: tuple[int, ...]) -> np.ndarray:
        """z-depth (float32, ``shape``) of a ray batch whose directions have camera-frame z
        ``axis_z`` (unit directions: ``t`` along the ray times it), 0 where nothing is hit."""
        mi, dr = self._mi, self._dr
        si = self._scene.ray_intersect(ray, ray_flags=mi.RayFlags.Minimal, coherent=True)
        z = dr.select(si.is_valid(), si.t * axis_z, 0.0)
        return np.array(z, dtype=np.float32).reshape(shape)

    def depth_many(self, times: np.ndarray) -> np.ndarray:
        """:meth:`depth` at several times (K,) seconds, (K, H, W) float32: one ray cast for
        all of them where the scene is static on a JIT variant, each ray turned by its own
        time's pose with the same float32 operations as :meth:`depth`'s, so that each map is
        :meth:`depth`'s bit for bit (``tests/test_render.py``); else one :meth:`depth` a time.
        """
        times = np.asarray(times, dtype=np.float64).reshape(-1)
        if self.variant == "scalar_rgb" or self.scene.is_dynamic or len(times) < 2:
            return np.stack([self.depth(float(t)) for t in times])
        mi, dr = self._mi, self._dr
        shape = (self.camera.height, self.camera.width)
        n = shape[0] * shape[1]
        poses = [self._checked_pose(float(t), None) for t in times]      # the sensor is not traced
        rotations = np.stack([pose[:3, :3] for pose in poses]).astype(np.float32).reshape(-1, 9)
        origins = np.stack([pose[:3, 3] for pose in poses]).astype(np.float32)
        lane = dr.arange(mi.UInt32, len(times) * n)
        view, pixel = lane // n, lane % n
        entries = [dr.gather(mi.Float, mi.Float(np.ascontiguousarray(rotations[:, i])), view)
                   for i in range(9)]
        rotation = mi.Matrix3f(*entries)
        origin = mi.Point3f(*(dr.gather(mi.Float, mi.Float(np.ascontiguousarray(origins[:, i])),
                                        view) for i in range(3)))
        rays = dr.gather(mi.Vector3f, self._rays, pixel)
        return self._cast_depth(mi.Ray3f(origin, rotation @ rays), rays.z, (len(times), *shape))

    def _depth_scalar(self, pose: np.ndarray) -> np.ndarray:
        mi = self._mi
        origin = mi.Point3f(*pose[:3, 3].tolist())
        directions = self._rays_np @ pose[:3, :3].T
        out = np.zeros(len(directions), dtype=np.float32)
        for i, (d, dz) in enumerate(zip(directions, self._rays_np[:, 2], strict=True)):
            si = self._scene.ray_intersect(mi.Ray3f(origin, mi.Vector3f(*d)),
                                           ray_flags=mi.RayFlags.Minimal, coherent=False)
            if si.is_valid():
                out[i] = si.t * dz
        return out

    def object_ids(self, t: float, pose: np.ndarray | None = None) -> np.ndarray:
        """Which object each pixel-centre ray hits first (the rays of :meth:`depth`).

        A static scene is loaded with Mitsuba's optimisation, which merges meshes that share a
        material into one shape; its ids then come from a copy of its geometry loaded without
        that optimisation (built at the first call, once). A dynamic scene is loaded without
        it, and its own shapes give the ids (from the same ray cast as :meth:`depth`'s).

        Parameters
        ----------
        t : float, seconds
        pose : (4, 4) ndarray, optional
            ``T_world_camera`` (default the trajectory's at ``t``).

        Returns
        -------
        (H, W) uint16 ndarray
            0 where nothing is hit, ``i`` where the ray hits ``scene.objects[i - 1]``.
        """
        pose = self._set_state(t, pose)
        mi, dr = self._mi, self._dr
        scene = self._scene if self.scene.is_dynamic else self._geometry_scene()
        shape = (self.camera.height, self.camera.width)
        if self.variant == "scalar_rgb":
            origin = mi.Point3f(*pose[:3, 3].tolist())
            out = np.zeros(len(self._rays_np), dtype=np.uint16)
            for i, d in enumerate(self._rays_np @ pose[:3, :3].T):
                si = scene.ray_intersect(mi.Ray3f(origin, mi.Vector3f(*d)),
                                         ray_flags=mi.RayFlags.Minimal, coherent=False)
                if si.is_valid():
                    out[i] = _object_index(si.shape.id()) + 1
            return out.reshape(shape)
        rotation = mi.Matrix3f(pose[:3, :3].astype(np.float32))
        origin = mi.Point3f(*pose[:3, 3].astype(np.float32).tolist())
        dr.make_opaque(rotation, origin)
        return self._hit_objects(scene, mi.Ray3f(origin, rotation @ self._rays)).reshape(shape)

    def _hit_objects(self, scene, ray) -> np.ndarray:
        """(N,) uint16: 0 where the rays hit nothing, ``i`` where ``scene.objects[i - 1]``."""
        mi, dr = self._mi, self._dr
        pointers = np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr()), dtype=np.int64)
        lookup = np.zeros(int(pointers.max()) + 1, dtype=np.uint16)     # pointer 0: no hit
        lookup[pointers] = [_object_index(s.id()) + 1 for s in scene.shapes()]
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.Minimal, coherent=True)
        return lookup[np.array(dr.reinterpret_array(mi.UInt32, si.shape), dtype=np.int64)]

    def object_ids_rows(self, t: float, poses: np.ndarray) -> np.ndarray:
        """:meth:`object_ids` with each row ``r`` seen from ``poses[r]`` (a rolling shutter,
        as :meth:`depth_rows`); ``t`` places the moving objects. JIT variants only."""
        if self.variant == "scalar_rgb":
            raise ValueError("object_ids_rows needs a JIT variant, not scalar_rgb")
        poses = self._row_poses(poses)
        self._set_state(t, poses[len(poses) // 2])
        scene = self._scene if self.scene.is_dynamic else self._geometry_scene()
        return self._hit_objects(scene, self._row_rays(poses)).reshape(
            self.camera.height, self.camera.width)

    def object_ids_at(self, pixels: np.ndarray, times: np.ndarray) -> np.ndarray:
        """:meth:`object_ids` of single pixels, each seen at its own time.

        Each pixel-centre ray is cast from the trajectory's pose at its time, all in one
        launch. A static scene only (its objects do not depend on time), on a JIT variant.

        Parameters
        ----------
        pixels : (N,) int ndarray
            Flat pixel indices (row-major).
        times : (N,) float ndarray, seconds

        Returns
        -------
        (N,) uint16 ndarray
            0 where nothing is hit, ``i`` where the ray hits ``scene.objects[i - 1]``.
        """
        if self.variant == "scalar_rgb" or self.scene.is_dynamic:
            raise ValueError("object_ids_at needs a static scene and a JIT variant (each ray "
                             "at its own time)")
        pixels = np.asarray(pixels, dtype=np.intp)
        times = np.asarray(times, dtype=np.float64)
        if pixels.shape != times.shape or pixels.ndim != 1:
            raise ValueError(f"pixels and times must be (N,) arrays of one shape, got "
                             f"{pixels.shape} and {times.shape}")
        if not len(pixels):
            return np.zeros(0, np.uint16)
        poses = np.asarray(self.scene.trajectory.pose(times), dtype=np.float64).reshape(-1, 4, 4)
        directions = np.einsum("nij,nj->ni", poses[:, :3, :3], self._rays_np[pixels])
        return self._hit_objects(self._geometry_scene(), self._ray3f(poses[:, :3, 3], directions))

    def _row_rays(self, poses: np.ndarray):
        """The pixel-centre rays, row ``r`` from ``poses[r]`` (H, 4, 4)."""
        shape = (self.camera.height, self.camera.width)
        rays = self._rays_np.reshape(*shape, 3)
        directions = np.einsum("rij,rcj->rci", poses[:, :3, :3], rays).reshape(-1, 3)
        return self._ray3f(np.repeat(poses[:, :3, 3], shape[1], axis=0), directions)

    def _ray3f(self, origins: np.ndarray, directions: np.ndarray):
        """A Mitsuba ray batch from (N, 3) origins and directions (world frame)."""
        mi = self._mi
        return mi.Ray3f(mi.Point3f(*(origins[:, i].astype(np.float32) for i in range(3))),
                        mi.Vector3f(*(directions[:, i].astype(np.float32) for i in range(3))))

    def _geometry_scene(self):
        """The scene's shapes, one Mitsuba shape per object part (no merging), no textures."""
        if self._geometry is None:
            plain = {"type": "diffuse"}
            description: dict = {"type": "scene"}
            for i, obj in enumerate(self.scene.objects):
                description.update(_shape_dicts(i, obj, self.scene, plain))
            self._geometry = self._mi.load_dict(description, optimize=False)
        return self._geometry

    def _row_poses(self, poses: np.ndarray) -> np.ndarray:
        poses = np.asarray(poses, dtype=np.float64)
        shape = (self.camera.height, 4, 4)
        if poses.shape != shape or not np.all(np.isfinite(poses)):
            raise ValueError(f"row poses must be finite T_world_camera, shape {shape}, got "
                             f"shape {poses.shape}")
        return poses

    def luminance_rows(self, t: float, poses: np.ndarray, spp: int | None = None
                       ) -> np.ndarray:
        """Linear luminance (H, W) float32, cd/m^2, each row ``r`` seen from ``poses[r]``.

        Parameters
        ----------
        t : float, seconds
            Where the moving objects are (one time for the whole image).
        poses : (H, 4, 4) float ndarray
            ``T_world_camera`` of every row.
        spp : int, optional
            Overrides the renderer's samples per pixel.
        """
        if not self.rows:
            raise ValueError("luminance_rows needs a Renderer(..., rows=True)")
        poses = self._row_poses(poses)
        flat = np.concatenate([poses[:, :3, :3].reshape(-1, 9), poses[:, :3, 3]], axis=1)
        self._params["sensor.row_pose"] = self._mi.Float(flat.astype(np.float32).ravel())
        self._params.update()
        return self.luminance(t, poses[len(poses) // 2], spp)

    def depth_rows(self, t: float, poses: np.ndarray) -> np.ndarray:
        """z-depth (H, W) float32 in metres at pixel centres, each row ``r`` from ``poses[r]``
        (0 where nothing is hit); ``t`` places the moving objects."""
        poses = self._row_poses(poses)
        self._set_state(t, poses[len(poses) // 2])
        if self.variant == "scalar_rgb":
            raise ValueError("depth_rows needs a JIT variant, not scalar_rgb")
        return self._cast_depth(self._row_rays(poses), self._rays.z,
                                (self.camera.height, self.camera.width))

    def render(self, t: float, pose: np.ndarray | None = None) -> RenderResult:
        """Luminance and depth for the same time and pose."""
        return RenderResult(self.luminance(t, pose), self.depth(t, pose))

    @property
    def mitsuba_scene(self):
        """The loaded Mitsuba scene (for benchmarks and inspection)."""
        return self._scene
