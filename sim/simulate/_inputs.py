"""Simulate's inputs from plain values: :func:`simulate_inputs` builds the scene changes and the
parameter objects :func:`sim.simulate.simulate` takes (``evfuse simulate``'s flags and a dataset
job's parameters both go through it)."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Literal

from sim.validation import ParameterError

if TYPE_CHECKING:
    from sim.scene import Scene

__all__ = ["simulate_inputs"]


def simulate_inputs(scene: Scene, *, start: float = 0.0, duration: float | None = None,
                    end: float | Literal["scene"] | None = None, contrast: float = 0.2,
                    noise: str = "ideal", lam: float | None = None,
                    min_rate: float | None = None, max_rate: float | None = None,
                    wavefront: int | None = None, sampler: str | None = None,
                    spp: int | None = None,
                    frame_sensor: str | None = None, frame_rate: float | None = None,
                    rig: str | None = None, sensor: tuple[int, int] | None = None,
                    speed: float | None = None, motion_truth: bool = True,
                    ) -> tuple[Scene, dict]:
    """The scene and the keyword arguments of :func:`sim.simulate.simulate` for plain values.

    The scene is changed in this order: ``sensor``, ``frame_rate``, ``frame_sensor``,
    ``speed``; then the window is resolved and the event camera's, sampling's and rig's objects
    are built. A value left at ``None`` keeps the scene's (or the object's) default.

    Parameters
    ----------
    scene : sim.scene.Scene
        The loaded scene (its seed is the event camera's noise seed).
    start : float, s
        Start of the simulated window in the scene's time.
    duration : float, s, optional
        Length of the window (default: simulate's, the rest of the scene). Passed on as it is.
    end : float, s, or ``"scene"``, optional
        End of the window in the (speed-scaled) scene's time, instead of ``duration``:
        ``duration = end - start``, refused unless ``end > start``; ``"scene"`` is the scene's
        end. The refusal names the window's parameters ``{t0}`` and ``{t1}``.
    contrast : float, log intensity
        Contrast thresholds C+ = C- (:meth:`sim.events.EventParams.preset`).
    noise : str
        Event-camera noise preset (:data:`sim.noise.NOISE_PRESETS`).
    lam : float, optional
        Largest change of log intensity between renders, a fraction of C
        (:class:`sim.sampling.SamplingParams`; default its own).
    min_rate, max_rate : float, Hz, optional
        Bounds of the event camera's render rate (default: SamplingParams's).
    wavefront : int, optional
        The per-pixel sampler's blocks a pass (:attr:`sim.sampling.SamplingParams.wavefront`;
        default its own, 1).
    sampler : {"pixel", "frame"}, optional
        Passed on (default: simulate's choice).
    spp : int, optional
        Samples per pixel, a perfect square (default: the scene's).
    frame_sensor : str, optional
        The standard camera's sensor preset (:func:`sim.frames.with_frame_sensor`).
    frame_rate : float, Hz, optional
        The standard camera's frame rate (the scene's ``[frames] rate``). An auto-exposure
        ceiling (``max_exposure``) longer than the new frame period is lowered to it, as a
        camera's is; a fixed ``exposure`` longer than it is refused.
    rig : str, optional
        Capture-error preset (:meth:`sim.capture_errors.RigParams.from_preset`; default: the
        scene's ``[rig]``).
    sensor : (int, int), px, optional
        ``(width, height)``: the scene's camera at another resolution, same field of view
        (:meth:`sim.camera.Camera.with_resolution`).
    speed : float, optional
        Trajectory speed scale: the camera's path played this many times as fast
        (:class:`sim.trajectory.TimeScaledTrajectory`; the scene's duration divided by it).
    motion_truth : bool
        Write the motion ground truth.

    Returns
    -------
    scene : sim.scene.Scene
        With the sensor size, frame rate, frame sensor and speed asked for.
    kwargs : dict
        ``start``, ``duration``, ``events``, ``sampling``, ``rig``, ``sampler``, ``spp``,
        ``motion_truth`` for simulate.

    Raises
    ------
    ValueError
        A value the scene or the objects refuse (:class:`~sim.validation.ParameterError` for
        the window, and for a ``wavefront`` with the frame sampler:
        :func:`sim.sampling.check_sampler`).
    """
    from sim.capture_errors import RigParams
    from sim.events import EventParams
    from sim.frames import with_frame_sensor
    from sim.sampling import SamplingParams, check_sampler
    from sim.trajectory import TimeScaledTrajectory

    if sensor is not None:
        scene = replace(scene, camera=scene.camera.with_resolution(*sensor))
    if frame_rate is not None:
        ceiling = scene.frames.max_exposure
        if ceiling is not None and frame_rate > 0 and ceiling > 1.0 / frame_rate:
            ceiling = 1.0 / frame_rate
        scene = replace(scene, frames=replace(scene.frames, rate=frame_rate,
                                              max_exposure=ceiling))
    if frame_sensor is not None:
        scene = with_frame_sensor(scene, frame_sensor)
    if speed is not None:
        scene = replace(scene, trajectory=TimeScaledTrajectory(scene.trajectory, speed),
                        duration=scene.duration / speed)
    if end is not None:
        start = float(start)
        end = float(scene.duration if end == "scene" else end)
        if not end > start:
            raise ParameterError(f"window {{t0}} {start:g} s to {{t1}} {end:g} s: expected "
                                 f"t1 > t0 (scene {ParameterError.literal(scene.name)} lasts "
                                 f"{scene.duration:g} s)", t0="t0", t1="t1")
        duration = end - start
    check_sampler(wavefront, sampler)
    rates = {"lam": lam, "min_rate": min_rate, "max_rate": max_rate, "wavefront": wavefront}
    kwargs = {
        "start": start, "duration": duration,
        "events": EventParams.preset(noise, contrast=contrast, seed=scene.seed),
        "sampling": SamplingParams(**{k: v for k, v in rates.items() if v is not None}),
        "rig": None if rig is None else RigParams.from_preset(rig),
        "sampler": sampler, "spp": spp, "motion_truth": motion_truth,
    }
    return scene, kwargs
