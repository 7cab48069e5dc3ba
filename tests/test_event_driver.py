"""The one event driver of :mod:`sim.simulate` runs both samplers: for each, the events it writes
are exactly those of the sampler used on its own (its emulator fed by its samples, the loop the
driver wraps), and a checkpoint is taken only where the sampler can restart."""

from __future__ import annotations

import numpy as np
import pytest

from sim.eventio import read_events
from sim.events import EventEmulator, EventParams
from sim.pixel_sampling import PixelEventEmulator, PixelSamplingStats, pixel_blocks
from sim.render import Renderer
from sim.sampling import SamplingParams, SamplingStats, adaptive_samples
from sim.scene import parse_scene
from sim.simulate import simulate
from sim.simulate._events import _EventCamera, _ShaderSource
from tests.conftest import scene_text
from tests.test_simulate import OBJECTS  # the textured poster

MOVING = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
          "velocity = [1.0, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n")
CAMERA = "[camera]\nwidth = 48\nheight = 36\nfx = 40.0\nfy = 40.0\ncx = 24.0\ncy = 18.0\n"
FRAMES = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 1\n"
START, END = 0.05, 0.15


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "small.toml"
    path.write_text(scene_text(OBJECTS, camera=CAMERA, trajectory=MOVING, duration=0.3,
                               extra=FRAMES))
    return parse_scene(path.read_text(), path)


def _as_columns(events: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(np.asarray(events[name]).astype(np.int64) for name in ("t", "x", "y", "p"))


def _on_their_own(scene, sampler: str) -> np.ndarray:
    """The events of ``sampler`` over [START, END], without the driver."""
    cam = scene.camera
    params, sampling = EventParams(seed=scene.seed), SamplingParams()
    renderer = Renderer(scene)
    camera = _EventCamera(renderer, scene.render.event_spp, START, END)
    chunks = []
    if sampler == "frame":
        emulator = EventEmulator((cam.height, cam.width), params)
        contrast = np.minimum(emulator.c_on, emulator.c_off)
        for sample in adaptive_samples(camera, START, END, contrast, params.log_eps, sampling,
                                       SamplingStats()):
            if emulator.time_ns is None:
                emulator.start(sample.log, sample.t, sample.luminance)
            else:
                chunks.append(emulator.advance(sample.log, sample.t, sample.luminance))
    else:
        emulator = PixelEventEmulator((cam.height, cam.width), params)
        contrast = np.minimum(emulator.c_on, emulator.c_off)
        chunks = [block.events for block in pixel_blocks(
            _ShaderSource(camera), emulator, START, END, contrast, params.log_eps, sampling,
            PixelSamplingStats())]
    return np.concatenate(chunks)


@pytest.mark.parametrize("sampler", ["frame", "pixel"])
def test_the_driver_writes_the_samplers_own_events(scene, sampler, tmp_path):
    result = simulate(scene, tmp_path / sampler, start=START, duration=END - START,
                      progress=False, event_formats=("h5", "txt"), sampler=sampler)
    assert result.sampler == sampler
    written = read_events(tmp_path / sampler / "events.h5")
    expected = _on_their_own(scene, sampler)
    assert len(expected) > 100 and result.n_events == len(expected)
    for got, want in zip(_as_columns(written), _as_columns(expected), strict=True):
        np.testing.assert_array_equal(got, want)
    assert len(read_events(tmp_path / sampler / "events.txt")) == len(expected)


@pytest.mark.parametrize("sampler", ["frame", "pixel"])
def test_checkpoints_are_taken_only_where_the_sampler_can_restart(scene, sampler, tmp_path,
                                                                   monkeypatch):
    import importlib

    checkpoints = importlib.import_module("sim.simulate._checkpoint")
    saved = []
    real = checkpoints._Checkpoint.save_events

    def spy(self, sample, *args, **extra):
        saved.append((sample.t, sample.tail_pending, sorted(extra)))
        return real(self, sample, *args, **extra)

    monkeypatch.setattr(checkpoints, "CHECKPOINT_SAMPLES", 1)       # at every step allowed
    monkeypatch.setattr(checkpoints._Checkpoint, "save_events", spy)
    simulate(scene, tmp_path / sampler, start=START, duration=END - START, progress=False,
             event_formats=("h5",), sampler=sampler)
    assert len(saved) >= 3
    assert all(not pending for _, pending, _ in saved)
    assert [t for t, _, _ in saved] == sorted({t for t, _, _ in saved})     # one per step
    assert all(extra == (["observed_rates"] if sampler == "pixel" else []) for *_, extra in saved)
