"""One simulated window of a scene, for the commands that simulate a scene on their way to a map:
``evfuse run`` (into its run folder), ``evfuse reproduce`` and ``evfuse bench`` (into a cache
that later runs re-use).

One policy for all three (:func:`simulate_window`): a folder that holds a complete simulation
(its ``sequence.json``, written last, the folder renamed into place only when complete) is
re-used as it is; with ``resume``, the checkpoint an interrupted simulation left in
``<folder>.partial`` is continued; else the window is simulated afresh (a stale ``.partial``
discarded, :func:`sim.simulate.simulate`).

One cache key (:func:`window_key`): a hash of the scene's files (its scene file and every file it
names, :func:`sim.simulate.scene_files`) and of everything else that decides the simulation (the
scene's text and the parts a caller may replace, the window, the samples per pixel, the event
camera, its sampling and sampler, the event files, the motion truth), so that a window simulated
from another version of the scene or with other parameters is never taken for this one.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from sim.events import EventParams
from sim.output import partial_dir
from sim.sampling import SamplingParams
from sim.scene import Scene
from sim.simulate._checkpoint import CHECKPOINT_FOLDER, _identity
from sim.simulate._run import scene_files

__all__ = ["cached_window", "is_simulated", "scene_digest", "simulate_window", "window_key"]

KEY_LENGTH = 10
"""Hex digits of :func:`window_key` in a cache folder's name."""


def is_simulated(folder: str | Path) -> bool:
    """Whether ``folder`` holds a complete simulation (its ``sequence.json``)."""
    return (Path(folder) / "sequence.json").is_file()


def scene_digest(scene: Scene) -> str:
    """SHA-256 (hex) of the files a scene is made of: its scene file and every file it names
    (:func:`sim.simulate.scene_files`), each by its name and bytes (a missing one as missing)."""
    digest = hashlib.sha256()
    for path in scene_files(scene):
        digest.update(str(path.name).encode() + b"\0")
        digest.update(path.read_bytes() if path.is_file() else b"(missing)")
    return digest.hexdigest()


def window_key(scene: Scene, start: float, duration: float, *, spp: int | None = None,
               events: EventParams | None = None, sampling: SamplingParams | None = None,
               sampler: str | None = None, event_formats: tuple[str, ...] = ("h5", "txt"),
               motion_truth: bool = True) -> str:
    """The key of a simulated window: SHA-256 (hex) of the scene's files
    (:func:`scene_digest`) and of what :func:`sim.simulate.simulate` is given for it (its run
    identity, less the software's versions), as :func:`simulate_window` takes them.

    Parameters
    ----------
    scene : Scene
    start, duration : float, seconds
        The window: ``[start, start + duration]``.
    spp, events, sampling, sampler, event_formats, motion_truth :
        As :func:`sim.simulate.simulate` takes them (None: its defaults).

    Returns
    -------
    str
        64 hex digits.
    """
    events = events or EventParams(seed=scene.seed)
    identity = _identity(scene, float(start), float(duration), spp, events,
                         sampling or SamplingParams(), tuple(event_formats), sampler)
    del identity["software"]                     # a cache outlives the software that made it
    identity["motion_truth"] = bool(motion_truth)
    identity["scene_files_sha256"] = scene_digest(scene)
    return hashlib.sha256(json.dumps(identity, sort_keys=True).encode("utf-8")).hexdigest()


def simulate_window(scene: Scene, folder: str | Path, start: float, duration: float, *,
                    resume: bool = False, progress: bool = False, **options) -> Path:
    """Simulate ``[start, start + duration]`` of a scene into ``folder``, unless it holds that
    simulation.

    Parameters
    ----------
    scene : Scene
    folder : str or Path
        The sequence folder. One that holds a complete simulation (:func:`is_simulated`) is
        returned as it is: its name must say what it holds (a run's folder, or
        :func:`cached_window`'s).
    start, duration : float, seconds
        The window, as :func:`sim.simulate.simulate` takes it.
    resume : bool
        Continue the checkpoint an interrupted simulation left in ``<folder>.partial`` (when
        there is one; else simulate afresh).
    progress : bool
        Progress bars.
    **options
        ``spp``, ``events``, ``sampling``, ``sampler``, ``event_formats``, ``motion_truth``,
        ``profile``, as :func:`sim.simulate.simulate` takes them.

    Returns
    -------
    Path
        ``folder``.

    Raises
    ------
    ValueError
        As :func:`sim.simulate.simulate`.
    """
    # looked up at each call: a test may replace sim.simulate.simulate
    from sim.simulate import simulate

    folder = Path(folder)
    if is_simulated(folder):
        return folder
    checkpoint = partial_dir(folder) / CHECKPOINT_FOLDER / "checkpoint.json"
    simulate(scene, folder, start=start, duration=duration, progress=progress,
             resume=resume and checkpoint.is_file(), overwrite=True, **options)
    return folder


def cached_window(scene: Scene, cache: str | Path, label: str, start: float, duration: float, *,
                  progress: bool = False, **options) -> Path:
    """The simulation of ``[start, start + duration]`` of a scene in a cache folder, simulated
    when missing.

    Parameters
    ----------
    scene : Scene
    cache : str or Path
        The cache folder.
    label : str
        The start of the window's folder name, for people (the scene's name); the folder is
        ``<label>_<start>_<length>_<key>`` (times in seconds to 3 decimals, the key's first
        :data:`KEY_LENGTH` hex digits, :func:`window_key`).
    start, duration : float, seconds
    progress : bool
    **options
        As :func:`simulate_window`.

    Returns
    -------
    Path
        The sequence folder.
    """
    key = window_key(scene, start, duration, **options)[:KEY_LENGTH]
    folder = Path(cache) / f"{label}_{start:.3f}_{duration:.3f}_{key}"
    return simulate_window(scene, folder, start, duration, progress=progress, **options)
