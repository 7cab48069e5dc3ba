"""One job of a dataset: a scene, a seed and simulate's parameters (:class:`Job`), the table of
those parameters a sweep may set (:data:`PARAMETERS`), and one job run in this process
(:func:`run_job`), which is what every Dask worker calls.

A job's output depends only on its scene, seed and parameters: :attr:`Job.job_id` is a function
of them, and :func:`run_job` writes ``DIR/jobs/<job_id>/`` with :func:`sim.simulate.simulate`
(atomically, resuming from the checkpoint an interrupted run left in ``<job_id>.partial``).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from sim._atomic import write_bytes_atomically
from sim.validation import finite, integer, non_negative, positive

__all__ = ["JOBS_FOLDER", "PARAMETERS", "RUNS_LOG", "SCENE_FILE", "Job", "job_inputs",
           "job_scene", "run_job"]

JOBS_FOLDER = "jobs"
"""The dataset's folder of sequence folders, one per job (``DIR/jobs/<job_id>/``)."""
SCENE_FILE = "scene.toml"
"""The drawn scene of a family or procedural job, written into its sequence folder."""
RUNS_LOG = "runs.log"
"""``DIR/runs.log``: one line per job start, completion and failure inside a worker
(``start|done|failed <job_id> pid=<pid> t=<unix time> ...``), appended by the workers; a job's
attempts are its ``start`` lines, and no job has two ``done`` lines."""


_ONE_AT_A_TIME = threading.Lock()
"""Held by :func:`run_job` around a simulation: one per process at a time. Mitsuba's variant and
Dr.Jit's recorded kernels are process-wide: two simulations in two threads of one worker failed
(``mitsuba has no attribute set_variant``, Dr.Jit's frozen-function registry mismatches; seen
with a 1-worker x 2-thread LocalCluster), so a worker's extra threads wait instead."""


def _choice(*names: str) -> Callable[[str, object], str]:
    def check(name: str, value: object) -> str:
        if value not in names:
            raise ValueError(f"{name} must be one of {', '.join(names)}, got {value!r}")
        return str(value)
    return check


def _sensor(name: str, value: object) -> str:
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(value))
    if not isinstance(value, str) or match is None or min(map(int, match.groups())) < 1:
        raise ValueError(f"{name} must be WIDTHxHEIGHT in pixels (e.g. '48x36'), got {value!r}")
    from sim.simulate.memory import check_simulation_memory

    width, height = int(match.group(1)), int(match.group(2))
    try:                                 # at 1 sample per pixel: a lower bound, known up front
        check_simulation_memory(width, height, 1, at_least=True)
    except ValueError as exc:
        raise ValueError(str(exc)) from None
    return f"{width}x{height}"


def _spp(name: str, value: object) -> int:
    spp = integer(name, value, 1)
    if round(spp ** 0.5) ** 2 != spp:
        raise ValueError(f"{name} must be a perfect square (1, 4, 9, 16, ...), got {spp}")
    return spp


def _blocks(name: str, value: object) -> int:
    """A whole number >= 1 (what :class:`~sim.sampling.SamplingParams` takes as
    ``wavefront``)."""
    return integer(name, value, 1)


def _fraction(name: str, value: object) -> float:
    """A number in (0, 1] (what :class:`~sim.sampling.SamplingParams` takes as ``lam``)."""
    fraction = finite(name, value)
    if not 0 < fraction <= 1:
        raise ValueError(f"{name} must be in (0, 1], got {value!r}")
    return fraction


def _flag(name: str, value: object) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false, got {value!r}")
    return value


def _presets() -> dict[str, Callable[[str, object], object]]:
    from sim.capture_errors import RIG_PRESETS
    from sim.frames import FRAME_SENSOR_NAMES
    from sim.noise import NOISE_PRESETS

    return {"noise": _choice(*NOISE_PRESETS), "frame_sensor": _choice(*FRAME_SENSOR_NAMES),
            "rig": _choice(*RIG_PRESETS)}


PARAMETERS: dict[str, tuple[str, Callable[[str, object], object] | None]] = {
    "t0": ("start of the simulated window in the scene's time, s (simulate's start; "
           "default 0)", non_negative),
    "t1": ("end of the window, s (default: the scene's end)", positive),
    "contrast": ("contrast thresholds C+ = C- (log intensity; default 0.2)", positive),
    "noise": ("event-camera noise preset (sim.noise.NOISE_PRESETS; default ideal)", None),
    "lam": ("adaptive sampling: largest change of L between renders, as a fraction of C "
            "(SamplingParams.lam, in (0, 1]; default 0.5)", _fraction),
    "min_rate": ("lowest event-camera render rate, Hz (default 100)", positive),
    "max_rate": ("highest event-camera render rate, Hz (default 20000)", positive),
    "wavefront": ("the per-pixel sampler's blocks a pass of device launches "
                  "(SamplingParams.wavefront; default 1)", _blocks),
    "sampler": ("pixel or frame (default: simulate's choice)", _choice("pixel", "frame")),
    "spp": ("samples per pixel, a perfect square (default: the scene's)", _spp),
    "frame_sensor": ("the standard camera's sensor preset (sim.frames.FRAME_SENSOR_NAMES; "
                     "default: the scene's)", None),
    "frame_rate": ("the standard camera's frame rate, Hz (default: the scene's)", positive),
    "rig": ("capture-error preset (sim.capture_errors.RIG_PRESETS; default: the scene's)",
            None),
    "sensor": ("sensor size WIDTHxHEIGHT, px: the scene's camera at another resolution, same "
               "field of view (Camera.with_resolution)", _sensor),
    "speed": ("trajectory speed scale: the camera's path played this many times as fast "
              "(TimeScaledTrajectory; moving objects keep their own clock)", positive),
    "motion_truth": ("write the motion ground truth (default true)", _flag),
}
"""Every parameter a sweep's ``[grid]`` or ``[draw]`` may set: name -> (what it is, its
check). A check of ``None`` is a preset name, checked against its table when used. Values are
checked once more by the objects simulate takes (:class:`~sim.events.EventParams`,
:class:`~sim.sampling.SamplingParams`, :class:`~sim.frames.FrameParams`, ...), which
:func:`job_inputs` builds."""


def check_parameter(name: str, value: object) -> object:
    """The value of a sweep parameter, checked (:data:`PARAMETERS`).

    Raises
    ------
    ValueError
        An unknown name (the message lists the known ones) or a bad value.
    """
    if name not in PARAMETERS:
        raise ValueError(f"unknown parameter {name!r}; expected one of {', '.join(PARAMETERS)}")
    check = PARAMETERS[name][1] or _presets()[name]
    if isinstance(value, bool) and check is not _flag:
        raise ValueError(f"{name} must not be a boolean, got {value!r}")
    return check(name, value)


@dataclass(frozen=True)
class Job:
    """One sequence of a dataset.

    Attributes
    ----------
    scene : dict
        Where the scene comes from: ``{"name": builtin}``, ``{"file": path}`` (as the sweep
        wrote it, and ``"path"``, the resolved file), ``{"family": name, knob: value, ...}``
        (:func:`sim.scene.families.family_scene`) or ``{"procedural": name, range: value, ...}``
        (:mod:`sim.scene.procedural`, drawn from the job's seed).
    seed : int
        The scene's seed (every random draw of the simulation, and of a procedural scene).
    params : dict
        Simulate's parameters (:data:`PARAMETERS`), grid and drawn ones.
    """

    scene: dict
    seed: int
    params: dict = field(default_factory=dict)

    @property
    def label(self) -> str:
        """A short name of the scene: the built-in's or family's name, the file's stem."""
        spec = self.scene
        text = (spec.get("name") or spec.get("family") or spec.get("procedural")
                or Path(spec["file"]).stem)
        return re.sub(r"[^A-Za-z0-9_]+", "_", str(text))[:40]

    @property
    def identity(self) -> dict:
        """What decides the job's output, as JSON values (the resolved path left out)."""
        scene = {k: v for k, v in self.scene.items() if k != "path"}
        return {"scene": scene, "seed": self.seed, "params": self.params}

    @property
    def job_id(self) -> str:
        """``<scene>-<seed>-<hash8>``: a function of the scene, seed and parameters only."""
        text = json.dumps(self.identity, sort_keys=True, separators=(",", ":"))
        return f"{self.label}-{self.seed}-{hashlib.sha256(text.encode()).hexdigest()[:8]}"

    @property
    def generated(self) -> bool:
        """True for a family or procedural scene (its text is written as ``scene.toml``)."""
        return "family" in self.scene or "procedural" in self.scene


def scene_text(job: Job, variant: str | None = None) -> str | None:
    """The TOML text of a family or procedural job's scene (None for a built-in or file), its
    top-level ``seed`` the job's, so that the text alone is the job's scene.

    Parameters
    ----------
    job : Job
    variant : str, optional
        The Mitsuba variant a procedural family checks its draws with.

    Raises
    ------
    ValueError
        A knob or range the family refuses.
    """
    spec = dict(job.scene)
    if "family" in spec:
        from sim.scene.families import family_scene

        text = family_scene(spec.pop("family"), **spec)
    elif "procedural" in spec:
        from sim.scene.procedural import procedural_scene

        text = procedural_scene(spec.pop("procedural"), job.seed, variant=variant, **spec)
    else:
        return None
    return _with_seed(text, job.seed)


def _with_seed(text: str, seed: int) -> str:
    """A scene text with its top-level ``seed`` set (the lines before its first table)."""
    lines = text.splitlines(keepends=True)
    first_table = next((i for i, line in enumerate(lines)
                        if line.lstrip().startswith("[")), len(lines))
    head = [line for line in lines[:first_table] if not re.match(r"\s*seed\s*=", line)]
    return f"seed = {seed}\n" + "".join(head + lines[first_table:])


def job_scene(job: Job, text: str | None = None):
    """The job's scene (:class:`sim.scene.Scene`, its seed the job's), before its parameters.

    Parameters
    ----------
    job : Job
    text : str, optional
        A family or procedural job's :func:`scene_text`, if already drawn.

    Raises
    ------
    SceneError or ValueError
        The scene cannot be loaded or generated.
    """
    from scenes import resolve_scene
    from sim.scene import load_scene, parse_scene

    text = scene_text(job) if text is None else text
    if text is not None:
        return parse_scene(text, f"<{job.job_id}/{SCENE_FILE}>", seed=job.seed)
    if "name" in job.scene:
        return load_scene(resolve_scene(job.scene["name"]), seed=job.seed)
    return load_scene(job.scene["path"], seed=job.seed)


def job_inputs(job: Job, scene=None) -> tuple[object, dict]:
    """The scene and the keyword arguments of :func:`sim.simulate.simulate` of a job.

    Parameters
    ----------
    job : Job
    scene : sim.scene.Scene, optional
        The job's scene (:func:`job_scene`), if already loaded.

    Returns
    -------
    scene : sim.scene.Scene
        With the job's sensor size, frame rate, frame sensor and speed.
    kwargs : dict
        ``start``, ``duration``, ``events``, ``sampling``, ``rig``, ``sampler``, ``spp``,
        ``motion_truth`` for simulate: :func:`sim.simulate.simulate_inputs` of the job's
        parameters (``t0`` its ``start``, ``t1`` its ``end``, default the scene's end).

    Raises
    ------
    ValueError
        A parameter the scene or simulate's objects refuse (e.g. an exposure longer than the
        frame period at ``frame_rate``).
    """
    from sim.simulate import simulate_inputs

    p = dict(job.params)
    scene = job_scene(job) if scene is None else scene
    if "sensor" in p:
        p["sensor"] = tuple(int(v) for v in p["sensor"].split("x"))
    if "t0" in p:
        p["start"] = p.pop("t0")
    p["end"] = p.pop("t1", "scene")
    return simulate_inputs(scene, **p)


def _log(dataset: Path, event: str, job: Job, rest: str = "") -> None:
    """Append one line to ``DIR/runs.log``: ``EVENT JOB_ID pid=PID t=UNIX_TIME [REST]`` (one
    ``write`` of an ``O_APPEND`` file: lines of several workers never interleave)."""
    line = f"{event} {job.job_id} pid={os.getpid()} t={time.time():.3f} {rest}".rstrip()
    fd = os.open(dataset / RUNS_LOG, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (line.replace("\n", " ") + "\n").encode())
    finally:
        os.close(fd)


def run_job(job: Job, dataset: str | Path, variant: str | None = None,
            profile: bool = False) -> dict:
    """Simulate one job into ``DIR/jobs/<job_id>/`` in this process (what a worker runs).

    A complete folder is kept (its record read back); an interrupted one
    (``<job_id>.partial`` with a checkpoint) is resumed (:func:`sim.simulate.simulate`'s
    ``resume``), so its files come out the same as an uninterrupted run's.

    Parameters
    ----------
    job : Job
    dataset : str or Path
        The dataset folder.
    variant : str, optional
        Mitsuba variant (default: simulate's).
    profile : bool
        Also write the job's ``profile.json`` (:mod:`sim.profile`).

    Returns
    -------
    dict
        The manifest's counts of the job (:func:`sim.dataset._manifest.job_record`) and
        ``ran`` (False when the folder was already complete), ``resumed``, ``wall_s``.

    Raises
    ------
    Exception
        Whatever simulate raised (logged to ``runs.log`` first).

    Notes
    -----
    One simulation runs at a time in a process (the others wait): Mitsuba's and Dr.Jit's
    state is process-wide, so parallel jobs need worker processes, not threads.
    """
    from sim.dataset._manifest import job_record
    from sim.output import partial_dir
    from sim.simulate import simulate
    from sim.simulate._checkpoint import CHECKPOINT_FOLDER

    dataset = Path(dataset)
    folder = dataset / JOBS_FOLDER / job.job_id
    if folder.is_dir():
        if job.generated and not (folder / SCENE_FILE).is_file():
            write_bytes_atomically(folder / SCENE_FILE, scene_text(job, variant).encode())
        return {**job_record(folder), "ran": False, "resumed": False}
    clock = time.perf_counter()
    _log(dataset, "start", job)
    try:
        checkpoint = partial_dir(folder) / CHECKPOINT_FOLDER
        resume = checkpoint.is_dir() and any(checkpoint.iterdir())
        with _ONE_AT_A_TIME:
            text = scene_text(job, variant) if job.generated else None
            scene, kwargs = job_inputs(job, job_scene(job, text))
            simulate(scene, folder, variant=variant, progress=False, resume=resume,
                     profile=profile, **kwargs)
        if text is not None:
            write_bytes_atomically(folder / SCENE_FILE, text.encode())
    except BaseException as error:
        _log(dataset, "failed", job, f"{type(error).__name__}: {error}")
        raise
    wall = time.perf_counter() - clock
    _log(dataset, "done", job, f"wall_s={wall:.3f} resumed={resume}")
    return {**job_record(folder), "ran": True, "resumed": resume, "wall_s": wall}
