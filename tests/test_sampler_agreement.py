"""The per-pixel sampler against the frame sampler at lam / 4 (the reference), on crops of three
built-in scenes (the full-size runs are in benchmarks/bench_sampling.py): the same events, at
the same times within the sampling bound; and the frame sampler at the default lam on the same
scale."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from benchmarks.agreement import event_agreement
from scenes import resolve_scene
from sim.eventio import read_events
from sim.sampling import SamplingParams
from sim.scene import load_scene
from sim.simulate import simulate

CROP = (96, 72)
"""Width and height of the crop of the scene's camera (same pixels, same focal length)."""
CASES = {"slider_close": 0.0, "poster_6dof": 4.0, "complex_sphere": 1.0}
"""Scene and start time of its 0.05 s window."""


def _crop(scene):
    camera = scene.camera
    width, height = CROP
    x0, y0 = (camera.width - width) // 2, (camera.height - height) // 2
    return replace(scene, camera=replace(camera, width=width, height=height,
                                         cx=camera.cx - x0, cy=camera.cy - y0))


def _events(scene, folder, start, sampler, lam):
    result = simulate(scene, folder, start=start, duration=0.05, progress=False,
                      with_events=True, event_formats=("h5",), sampler=sampler,
                      sampling=SamplingParams(lam=lam))
    return result, read_events(folder / "events.h5")


@pytest.mark.parametrize("name", list(CASES))
def test_per_pixel_sampling_fires_the_reference_events(name, tmp_path):
    scene = _crop(load_scene(resolve_scene(name)))
    start = CASES[name]
    shape = (scene.camera.height, scene.camera.width)
    _, reference = _events(scene, tmp_path / "reference", start, "frame", 0.125)
    pixel_run, pixel = _events(scene, tmp_path / "pixel", start, "pixel", 0.5)
    _, frame = _events(scene, tmp_path / "frame", start, "frame", 0.5)
    assert pixel_run.sampler == "pixel" and len(reference) > 2000
    got = event_agreement(reference, pixel, shape)
    usual = event_agreement(reference, frame, shape)                # the same scale
    assert got.blocks >= 4, got
    assert abs(got.count_error) <= 0.01, got
    assert got.worst_block_error <= 0.03, got
    # Matched events (the i-th of a pixel and polarity in each stream): most within one
    # maximum-rate interval (50 us), 95 % within 0.5 ms; the few beyond are pairs shifted
    # by a missed or extra event of their pixel.
    assert got.matched >= 0.99 and got.dt_median_us <= 50.0 and got.dt_p95_us <= 500.0, got
    assert abs(usual.count_error) <= 0.01, usual


def test_a_static_camera_gives_no_events_per_pixel(tmp_path):
    from sim.trajectory import LinearTrajectory

    scene = _crop(load_scene(resolve_scene("poster_6dof")))
    pose = scene.trajectory.pose(2.0)
    still = LinearTrajectory(pose[:3, 3], np.zeros(3), pose[:3, :3])
    result = simulate(replace(scene, trajectory=still), tmp_path / "still", start=2.0,
                      duration=0.05, progress=False, event_formats=("h5",), sampler="pixel")
    assert result.n_events == 0 and result.event_pixel_samples == 0
    assert len(read_events(tmp_path / "still" / "events.h5")) == 0
