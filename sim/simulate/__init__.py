"""The simulator pipeline: a scene in, a sequence folder (CONVENTIONS.md) out.

Stages, in order: camera calibration -> ground-truth poses (``groundtruth.txt`` at the scene's
``pose_rate``) -> motion truth (``velocity.txt``, ``imu.txt``, ``imu_exact.txt``,
:mod:`sim.imu`) -> standard-camera frames (renders averaged over the exposure, camera response,
noise) and the exact depth at each frame time -> events: the event emulator driven by renders at
adaptively chosen times (:mod:`sim.sampling`), streamed to ``events.h5`` and ``events.txt`` ->
indexes and ``sequence.json``.

Everything is written into ``<out>.partial`` and renamed to ``<out>`` only when complete.

An interrupted run can be resumed (``simulate(..., resume=True)``, ``evfuse simulate --resume``)
and gives the same files as an uninterrupted one. Three things make that possible:

- Every frame is written atomically (a temporary name, then a rename) and draws its noise from
  its own generator, ``default_rng([seed, FRAME_NOISE_STREAM, index])``: a frame whose files
  exist is complete, and any frame can be made alone.
- Renders are deterministic in time (a fixed sampler seed), so the event stage can go on from
  any sample at which the sampler, the emulator and the writers were saved.
- ``<out>.partial/.checkpoint/`` holds what a resumed run needs (see :class:`_Checkpoint`):
  the run's identity (scene text, seed, times, parameters, software), the frames' gain and the
  event stage's state, saved at a sample boundary every :data:`CHECKPOINT_SECONDS` of wall
  time or :data:`CHECKPOINT_SAMPLES` samples, whichever comes first, and written in the
  background (a crash loses at most that interval plus one step and two writes: see
  ``_checkpoint``). It is removed before the folder is renamed into place.

The package's modules:

- ``_run``: :func:`simulate` and its steps (the window, the rig's files, ``sequence.json``),
  :class:`SimulationResult`, :func:`scene_files`;
- ``_frames``: the standard camera's frames and depth maps and their files;
- ``_events``: the event camera: one driver for both samplers (whole frames at one adaptive
  rate, or each pixel at its own times), the event files;
- ``_inputs``: :func:`simulate_inputs`, simulate's scene changes and parameter objects from
  plain values (``evfuse simulate``'s flags, a dataset job's parameters);
- ``_checkpoint``: the run's identity and the checkpoint a resumed run continues from;
- ``window``: one simulated window of a scene, cached under a key of everything that makes it
  (:func:`sim.simulate.window.simulate_window`, used by ``evfuse run``, ``reproduce`` and
  ``bench``). It is not re-exported here: import it from :mod:`sim.simulate.window`.
"""

from sim.simulate._checkpoint import CHECKPOINT_FOLDER, CHECKPOINT_SAMPLES, CHECKPOINT_SECONDS
from sim.simulate._frames import FRAME_NOISE_STREAM
from sim.simulate._inputs import simulate_inputs
from sim.simulate._run import SimulationResult, scene_files, simulate

__all__ = ["CHECKPOINT_FOLDER", "CHECKPOINT_SAMPLES", "CHECKPOINT_SECONDS", "FRAME_NOISE_STREAM",
           "SimulationResult", "scene_files", "simulate", "simulate_inputs"]
