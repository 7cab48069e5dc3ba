"""Checks of a drawn scene that need the renderer: the exact-depth check of procedural scenes.

:mod:`sim.scene.procedural` draws a scene and refuses a trajectory by geometry (objects in view,
bounds on the nearest and farthest surface); its last step renders the exact depth of a few
views and refuses a view whose depth leaves the declared range (:func:`exact_depth_check`). The
scene model may not import the renderer (it is below it: ``tests/test_import_graph.py``), so
that step lives here, above both, and :mod:`sim` hands it down once
(:func:`sim.scene.procedural.use_exact_depth_check`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sim.render import Renderer
from sim.scene import Material, Scene

__all__ = ["exact_depth_check"]


def exact_depth_check(scene: Scene, *, views: int, size: tuple[int, int],
                      variant: str | None = None) -> str | None:
    """Why a procedural scene's exact depth is refused, or None when it is accepted.

    The scene's exact depth, rendered by :class:`sim.render.Renderer` (one sample per pixel,
    plain materials, no texture filter) at ``size`` pixels and at ``views`` times evenly over
    ``[0, duration]``, must have a surface at every pixel and lie inside the scene's declared
    ``depth_range``. This is step 3 of :func:`sim.scene.procedural.trajectory_check`.

    Parameters
    ----------
    scene : Scene
        A drawn scene with its ``depth_range`` declared.
    views : int
        Renders of the exact depth.
    size : (int, int)
        Their width and height, pixels (same field of view as the scene's camera).
    variant : str, optional
        Mitsuba variant (see :func:`sim.variant.use_variant`).

    Returns
    -------
    str or None
        One line saying which view failed and how, or None.
    """
    near, far = scene.depth_range
    small = replace(scene, camera=scene.camera.with_resolution(*size),
                    objects=tuple(replace(obj, material=Material()) for obj in scene.objects))
    renderer = Renderer(small, spp=1, variant=variant, texture_filter=False)
    for t in np.linspace(0.0, scene.duration, views):
        depth = renderer.depth(float(t))
        if not (depth > 0).all():
            return f"a ray at t = {t:.3f} s leaves the room (no surface)"
        if depth.min() < near or depth.max() > far:
            return (f"exact depth [{depth.min():.3f}, {depth.max():.3f}] m at t = {t:.3f} s "
                    f"outside [{near}, {far}]")
    return None
