"""Simulate's inputs from plain values (:func:`sim.simulate.simulate_inputs`): each value reaches
the object it names, and ``evfuse simulate`` and a dataset job with the same values give simulate
the same scene and keyword arguments. No simulation here (fast)."""

from __future__ import annotations

import importlib
from dataclasses import replace
from types import SimpleNamespace

import pytest

from fusion.cli import main
from scenes import resolve_scene
from sim.capture_errors import RigParams
from sim.dataset import job_inputs, parse_sweep
from sim.events import EventParams
from sim.frames import with_frame_sensor
from sim.sampling import SamplingParams
from sim.scene import load_scene
from sim.simulate import simulate_inputs
from sim.trajectory import TimeScaledTrajectory
from sim.validation import ParameterError


@pytest.fixture(scope="module")
def scene():
    return load_scene(resolve_scene("slider_close"), seed=3)


def test_defaults_change_nothing_and_leave_the_window_to_simulate(scene):
    out, kwargs = simulate_inputs(scene)
    assert out is scene
    assert kwargs == {"start": 0.0, "duration": None, "sampler": None, "spp": None, "rig": None,
                      "events": EventParams.preset("ideal", contrast=0.2, seed=3),
                      "sampling": SamplingParams(), "motion_truth": True}


def test_each_plain_value_reaches_its_object(scene):
    out, kwargs = simulate_inputs(
        scene, start=0.5, end=0.75, contrast=0.3, noise="realistic", lam=0.4, min_rate=50.0,
        max_rate=900.0, wavefront=4, sampler="pixel", spp=4, frame_sensor="machine_vision",
        frame_rate=20.0, rig="mocap", sensor=(48, 36), speed=2.0, motion_truth=False)
    camera = scene.camera.with_resolution(48, 36)
    assert out.camera == camera
    expected = with_frame_sensor(replace(scene, frames=replace(scene.frames, rate=20.0)),
                                 "machine_vision").frames
    assert out.frames == expected and out.frames.rate == 20.0
    assert isinstance(out.trajectory, TimeScaledTrajectory)
    assert out.duration == pytest.approx(scene.duration / 2)
    assert kwargs == {"start": 0.5, "duration": 0.25, "sampler": "pixel", "spp": 4,
                      "rig": RigParams.from_preset("mocap"),
                      "events": EventParams.preset("realistic", contrast=0.3, seed=3),
                      "sampling": SamplingParams(lam=0.4, min_rate=50.0, max_rate=900.0,
                                                 wavefront=4),
                      "motion_truth": False}
    # a duration is passed on as it is; "scene" ends the window at the (scaled) scene's end
    assert simulate_inputs(scene, start=0.1, duration=0.2)[1]["duration"] == 0.2
    assert simulate_inputs(scene, speed=2.0, end="scene")[1]["duration"] == out.duration


def test_a_window_that_ends_before_it_starts_is_refused_naming_t0_and_t1(scene):
    with pytest.raises(ParameterError) as error:
        simulate_inputs(scene, start=0.5, end=0.25)
    assert error.value.rephrase({"t0": "--t0", "t1": "--t1"}).startswith(
        "window --t0 0.5 s to --t1 0.25 s: expected t1 > t0 (scene slider_close lasts")


def test_evfuse_simulate_and_the_same_job_give_simulate_the_same_inputs(tmp_path, monkeypatch):
    calls = []

    def fake(scene, out, **kwargs):
        calls.append((scene, kwargs))
        return SimpleNamespace(n_frames=0, n_renders=0, n_events=None, sampler="pixel",
                               variant="none", timings={"total": 0.0}, out=out, profile=None)

    # the package (``sim.simulate`` as an attribute is sim's re-exported function)
    monkeypatch.setattr(importlib.import_module("sim.simulate"), "simulate", fake)
    assert main(["simulate", "slider_close", "--out", str(tmp_path / "seq"), "--seed", "3",
                 "--start", "0.5", "--duration", "0.25", "--contrast", "0.3", "--noise",
                 "realistic", "--lambda", "0.4", "--min-rate", "50", "--max-rate", "900",
                 "--wavefront", "3", "--sampler", "pixel", "--spp", "4", "--frame-sensor",
                 "machine_vision", "--rig", "lab", "--no-motion-truth", "--quiet"]) == 0
    (cli_scene, cli_kwargs), = calls
    job = parse_sweep("""seeds = [3]\n\n[[scenes]]\nname = "slider_close"\n\n[grid]
t0 = 0.5\nt1 = 0.75\ncontrast = 0.3\nnoise = "realistic"\nlam = 0.4\nmin_rate = 50.0
max_rate = 900.0\nwavefront = 3\nsampler = "pixel"\nspp = 4\nframe_sensor = "machine_vision"
rig = "lab"\nmotion_truth = false\n""").jobs[0]
    job_scene, job_kwargs = job_inputs(job)
    simulate_only = ("variant", "overwrite", "progress", "with_events", "event_formats", "resume",
                     "profile")
    assert {k: v for k, v in cli_kwargs.items() if k not in simulate_only} == job_kwargs
    assert cli_scene.frames == job_scene.frames and cli_scene.camera == job_scene.camera
    assert cli_scene.seed == job_scene.seed == 3


def test_wavefront_with_the_frame_sampler_is_refused_in_one_line(scene, tmp_path, capsys):
    with pytest.raises(ParameterError) as error:
        simulate_inputs(scene, wavefront=2, sampler="frame")
    assert str(error.value) == ("wavefront 2: only the per-pixel sampler takes it (sampler "
                                "pixel), not sampler frame")
    assert main(["simulate", "slider_close", "--out", str(tmp_path / "seq"), "--wavefront", "4",
                 "--sampler", "frame", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("--wavefront 4: only the per-pixel sampler takes it (--sampler "
                            "pixel), not --sampler frame")
    assert not (tmp_path / "seq").exists()
