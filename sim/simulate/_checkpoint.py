"""Checkpoint and resume of a simulation: the run's identity, and the state of an unfinished
run in ``<out>.partial/.checkpoint/`` (see :class:`_Checkpoint`).

The event stage's state is copied on the simulation's thread and written by a background thread
(:class:`_BackgroundWrite`), under a temporary name renamed over the old file once flushed to
disk: the simulation goes on while it is written, and a crash (a kill, a power cut) mid-write
leaves the previous checkpoint, complete, never a torn one under the final name. At 1280x720 a
checkpoint is 52 MB. Written in line, it cost the simulation 0.27-0.82 s each on the shared
2-core machine (slider_close, the per-pixel sampler), and 5.46 s of a 25-s run on the H200
machine, written every second (issue 36); in the background, 0.10-0.14 s each here (the state's
copies and the event files' flush stay on the simulation's thread).

What a crash loses is bounded in wall time: the last complete checkpoint is at most
:data:`CHECKPOINT_SECONDS` (or :data:`CHECKPOINT_SAMPLES` samples, whichever comes first) plus
one sampler step plus two checkpoint writes old, since the next one is copied when due and a
checkpoint is never copied while the previous one is still being written (the simulation waits
for it instead, which it does only when a write takes longer than the interval).
"""

from __future__ import annotations

import hashlib
import json
import platform
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict
from importlib import metadata
from pathlib import Path

import numpy as np

from sim._atomic import atomic_file, write_bytes_atomically
from sim.events import EventEmulator, EventParams
from sim.output import evfuse_version, resumable_partial, resume_differences
from sim.sampling import Sample, SamplingParams
from sim.scene import Scene
from sim.validation import ParameterError

CHECKPOINT_SECONDS = 2.0
"""Wall-clock seconds between two checkpoints of the event stage (what a crash loses is at most
this plus one sampler step and two checkpoint writes: see the module docstring)."""
CHECKPOINT_SAMPLES = 1000
"""Most event-camera samples between two checkpoints of the event stage, however fast."""
CHECKPOINT_FOLDER = ".checkpoint"
"""Folder of ``<out>.partial`` that holds the state a resumed run continues from."""
_CHECKPOINT_FORMAT = "evfuse checkpoint 2"
_EMULATOR_ARRAYS = ("ref", "level", "raw", "cutoff", "last_t")


def _versions() -> dict[str, str]:
    versions = {"python": platform.python_version(), "evfuse": evfuse_version()}
    for package in ("mitsuba", "drjit", "numpy", "opencv-python-headless", "scikit-image",
                    "OpenEXR"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def _identity(scene: Scene, start: float, duration: float, spp: int | None,
              events: EventParams | None, sampling: SamplingParams,
              formats: tuple[str, ...], sampler: str | None = None) -> dict:
    """What decides a run's output, as JSON values (the variant is added once it is known).

    The scene enters by its TOML text (hashed) and the parsed parts a caller may replace;
    files the text refers to (image textures, meshes) are not read.
    """
    render = asdict(scene.render)
    if render["seed"] is None:        # the scene's seed (below): caches made before the key match
        del render["seed"]
    identity = {
        "scene_toml_sha256": hashlib.sha256(scene.text.encode("utf-8")).hexdigest(),
        "scene": {"duration": scene.duration, "camera": asdict(scene.camera),
                  "frames": asdict(scene.frames), "render": render,
                  "rig": scene.rig.as_dict(), "imu": scene.imu.as_dict(),
                  "up": list(scene.up)},
        "seed": scene.seed,
        "start": start,
        "duration": duration,
        "spp": int(spp if spp is not None else scene.render.spp),
        "events": None if events is None else {"params": asdict(events),
                                               "sampling": asdict(sampling),
                                               "formats": list(formats),
                                               "sampler": sampler},
        "software": _versions(),
    }
    return json.loads(json.dumps(identity))           # tuples -> lists, as read back


def _fingerprint(identity: dict) -> str:
    return hashlib.sha256(json.dumps(identity, sort_keys=True).encode("utf-8")).hexdigest()


def _check_resumable(out: Path, overwrite: bool, identity: dict, inputs: list) -> None:
    """Raise ValueError (a :class:`sim.validation.ParameterError` for other inputs) unless
    ``<out>.partial`` holds a checkpoint of a run like this one."""
    partial = resumable_partial(out, overwrite, inputs)
    saved = _Checkpoint.read(partial / CHECKPOINT_FOLDER)["identity"]
    differences = resume_differences(saved, identity, skip=("variant",))
    if differences:
        raise _mismatch(partial, differences)


def _mismatch(partial: Path, differences: list[str]) -> ParameterError:
    return ParameterError(
        f"{ParameterError.literal(partial)} was left by a run with other inputs: "
        f"{ParameterError.literal('; '.join(differences))}; expected the same scene, seed, times, "
        "parameters and software to resume (or run without {resume} to start again)",
        resume="resume=True")


class _BackgroundWrite:
    """Files written on one background thread, one at a time, each atomically.

    :meth:`submit` returns at once; the next :meth:`submit` (or :meth:`wait`) first waits for
    the write before it and raises the error it met, if any (a full disk), so that no error is
    lost and no two writes of the same file race.
    """

    def __init__(self) -> None:
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    @property
    def busy(self) -> bool:
        """Whether a write is still under way."""
        return self._thread is not None and self._thread.is_alive()

    def submit(self, path: Path, write: Callable[[object], None]) -> None:
        """Write ``path`` in the background: ``write(handle)`` fills ``<path>.partial`` (an open
        binary file), which is then flushed to disk and renamed to ``path``
        (:func:`sim._atomic.atomic_file`)."""
        self.wait()

        def run() -> None:
            try:
                with atomic_file(path) as partial, partial.open("wb") as handle:
                    write(handle)
            except BaseException as error:       # raised again on the caller's thread
                self._error = error

        self._thread = threading.Thread(target=run, name=f"evfuse checkpoint {path.name}")
        self._thread.start()

    def wait(self) -> None:
        """Wait for the write under way, if any; raise the error it met."""
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        error, self._error = self._error, None
        if error is not None:
            raise error


class _Checkpoint:
    """The state of an unfinished simulation, in ``<out>.partial/.checkpoint/``.

    ``checkpoint.json`` holds ``format``, the run's ``identity`` (see :func:`_identity`) and
    its SHA-256 ``fingerprint``, the frames' ``gain`` once known (saved before the first frame
    is written), each frame's ``exposures`` and ``frame_costs`` (saved before it is written)
    and the event stage's ``events`` summary once it is done. ``events.npz`` holds
    the event stage's last saved state: the arrays ``sample_luminance``, ``sample_log`` (the
    sampler's last sample; with the per-pixel sampler, the frame at the end of the last block),
    ``observed_rates`` (per-pixel sampler only: each pixel's observed rate in that block, which
    the next block's prediction uses) and ``emulator_ref``, ``emulator_level``,
    ``emulator_raw``, ``emulator_cutoff``, ``emulator_last_t`` (see
    :meth:`EventEmulator.get_state`), and under ``state`` the JSON
    text of the sample's time and flags, the emulator's time and generator state, the sampling
    counters, the event counts and each writer's :meth:`checkpoint`. Both files are written
    under a temporary name and renamed over the old one; ``events.npz`` in the background
    (:meth:`save_events`, :meth:`in_background`).

    Parameters
    ----------
    folder : Path
        The ``.checkpoint`` folder.
    identity : dict
        This run's identity, variant included.
    resume : bool
        Read the folder (its identity must match) rather than start a new one.
    """

    def __init__(self, folder: Path, identity: dict, resume: bool) -> None:
        self.folder = folder
        self._writes = _BackgroundWrite()
        fingerprint = _fingerprint(identity)
        if resume:
            self.data = self.read(folder)
            if self.data["fingerprint"] != fingerprint:
                differences = resume_differences(self.data["identity"], identity)
                raise _mismatch(folder.parent, differences or ["fingerprint"])
        else:
            folder.mkdir()
            self.data = {"format": _CHECKPOINT_FORMAT, "fingerprint": fingerprint,
                         "identity": identity, "gain": None, "events": None}
            self._save()

    @staticmethod
    def due(samples: int, seconds: float) -> bool:
        """Whether the event stage saves its state now, ``samples`` samples and ``seconds`` of
        wall time after the last save (see :data:`CHECKPOINT_SAMPLES`,
        :data:`CHECKPOINT_SECONDS`)."""
        return samples >= CHECKPOINT_SAMPLES or seconds >= CHECKPOINT_SECONDS

    @staticmethod
    def read(folder: Path) -> dict:
        """The contents of ``checkpoint.json``, or a ValueError saying what is wrong."""
        path = folder / "checkpoint.json"
        if not path.is_file():
            raise ParameterError(
                f"{ParameterError.literal(folder.parent)} holds no checkpoint "
                f"({ParameterError.literal(path)} does not exist): the run stopped before its "
                "first one; run without {resume} to start again", resume="resume=True")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}:{exc.lineno}: invalid JSON: {exc.msg}") from None
        if not isinstance(data, dict) or data.get("format") != _CHECKPOINT_FORMAT:
            got = data.get("format") if isinstance(data, dict) else type(data).__name__
            raise ValueError(f"{path}: format {got!r}; expected {_CHECKPOINT_FORMAT!r}")
        return data

    def _save(self) -> None:
        text = json.dumps(self.data, sort_keys=True, indent=1, allow_nan=False)
        write_bytes_atomically(self.folder / "checkpoint.json", text.encode("utf-8"))

    @property
    def gain(self) -> float | None:
        """The frames' automatic gain, once the first frame has fixed it."""
        return self.data["gain"]

    def set_gain(self, gain: float) -> None:
        self.data["gain"] = float(gain)
        self._save()

    @property
    def exposures(self) -> list[float]:
        """A realistic frame sensor's exposure of each frame chosen so far, seconds."""
        return list(self.data.get("exposures", []))

    def set_exposures(self, exposures: list[float]) -> None:
        self.data["exposures"] = [float(e) for e in exposures]
        self._save()

    @property
    def frame_costs(self) -> dict[int, dict]:
        """What each frame rendered so far cost (:class:`sim.frame_shader.ExposureCost`'s
        record), by frame index."""
        return {int(k): v for k, v in self.data.get("frame_costs", {}).items()}

    @property
    def frame_stage(self) -> dict | None:
        """How the frames are rendered (:meth:`sim.simulate._frames._Exposures.record`)."""
        return self.data.get("frame_stage")

    def set_frame_stage(self, stage: dict) -> None:
        if self.data.get("frame_stage") != stage:
            self.data["frame_stage"] = stage
            self._save()

    def set_frame_cost(self, index: int, cost: dict) -> None:
        self.data.setdefault("frame_costs", {})[str(int(index))] = cost
        self._save()

    @property
    def events_done(self) -> dict | None:
        """The event stage's summary (``sequence.json``'s ``events``) once it is complete."""
        return self.data["events"]

    def set_events_done(self, info: dict) -> None:
        self._writes.wait()
        self.data["events"] = json.loads(json.dumps(info))
        self._save()

    @contextmanager
    def in_background(self) -> Iterator[None]:
        """The event stage's span: on leaving it, wait for the checkpoint being written, so
        that an interrupted run leaves its last one on disk (an error of that write is raised
        unless the stage is already leaving on an exception of its own)."""
        try:
            yield
        except BaseException:
            try:
                self._writes.wait()
            except Exception:                    # the stage's own exception goes on
                pass
            raise
        self._writes.wait()

    def save_events(self, sample: Sample, emulator: EventEmulator, stats, count: int, on: int,
                    writers: dict, **extra: np.ndarray) -> None:
        """Save the event stage after ``sample`` (which has no pending tail); ``extra`` arrays
        (the per-pixel sampler's ``observed_rates``) are saved beside the others.

        The state is copied here (the writers flushed, the arrays copied) and written to
        ``events.npz`` in the background; a write still under way is waited for first."""
        emulator_state = emulator.get_state()                       # copies
        arrays = {f"emulator_{key}": emulator_state.pop(key) for key in _EMULATOR_ARRAYS}
        state = {"sample": sample.state(),
                 "emulator": emulator_state, "stats": asdict(stats), "count": count, "on": on,
                 "writers": {fmt: writer.checkpoint() for fmt, writer in writers.items()}}
        arrays.update(sample_luminance=np.array(sample.luminance), sample_log=np.array(sample.log),
                      state=np.array(json.dumps(state)),
                      **{key: np.array(value) for key, value in extra.items()})
        self._writes.submit(self.folder / "events.npz",
                            lambda handle: np.savez(handle, **arrays))

    def load_events(self) -> tuple[dict, dict] | None:
        """The arrays and state saved by :meth:`save_events`, or None if there are none."""
        path = self.folder / "events.npz"
        if not path.is_file():
            return None
        try:
            with np.load(path) as saved:
                arrays = {key: saved[key] for key in saved.files if key != "state"}
                state = json.loads(str(saved["state"]))
        except (OSError, ValueError, KeyError) as exc:
            raise ParameterError(
                f"{ParameterError.literal(path)}: cannot read the event checkpoint "
                f"({ParameterError.literal(exc)}); run without {{resume}} to start again",
                resume="resume=True") from None
        return arrays, state

    def remove(self) -> None:
        """Delete the folder, ``checkpoint.json`` last (until then a resume still works)."""
        self._writes.wait()
        for path in sorted(self.folder.iterdir(), key=lambda p: p.name == "checkpoint.json"):
            path.unlink()
        self.folder.rmdir()


def _restore_events(checkpoint: _Checkpoint, emulator: EventEmulator, stats_type: type
                    ) -> tuple[object, int, int, dict, tuple[dict, dict] | None]:
    """The event stage's counters, restored from the checkpoint when it holds a saved state
    (the emulator is set to it): stats, events written, ON events, the writers' positions, and
    the saved ``(arrays, state)`` (None for a fresh start)."""
    saved = checkpoint.load_events()
    if saved is None:
        return stats_type(), 0, 0, {}, None
    arrays, state = saved
    emulator.set_state({**state["emulator"],
                        **{key: arrays[f"emulator_{key}"] for key in _EMULATOR_ARRAYS}})
    return (stats_type(**state["stats"]), state["count"], state["on"], state["writers"],
            saved)
