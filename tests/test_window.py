"""sim.simulate.window: the one simulated scene window of run, reproduce and bench — its re-use
and resume policy and its cache key (the simulator replaced by a recorder: no rendering)."""

from __future__ import annotations

import importlib
from dataclasses import replace

import pytest

from sim.output import partial_dir
from sim.sampling import SamplingParams
from sim.scene import parse_scene
from sim.simulate.window import cached_window, is_simulated, simulate_window, window_key
from tests.conftest import scene_text

OBJECTS = '[[objects]]\ntype = "rectangle"\ncenter = [0.0, 1.0, 0.0]\nsize = [2.0, 2.0]\n'


@pytest.fixture()
def calls(monkeypatch):
    """The simulations asked for, each ``(folder, kwargs)``; each writes its sequence.json."""
    made = []

    def recorder(scene, folder, **kwargs):
        made.append((folder, kwargs))
        folder.mkdir(parents=True)
        (folder / "sequence.json").write_text("{}")

    monkeypatch.setattr(importlib.import_module("sim.simulate"), "simulate", recorder)
    return made


@pytest.fixture()
def scene(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(scene_text(OBJECTS, duration=2.0))
    return parse_scene(path.read_text(), path)


def test_a_cached_window_is_simulated_once_with_its_exact_window(scene, tmp_path, calls):
    start, duration = 0.1, 0.2                  # 0.1 + 0.2 - 0.1 != 0.2 in floating point
    folder = cached_window(scene, tmp_path / "cache", "s", start, duration)
    assert is_simulated(folder) and folder.parent == tmp_path / "cache"
    assert folder.name == f"s_0.100_0.200_{window_key(scene, start, duration)[:10]}"
    assert cached_window(scene, tmp_path / "cache", "s", start, duration) == folder
    assert len(calls) == 1                                         # re-used the second time
    kwargs = calls[0][1]
    assert kwargs["start"] == start and kwargs["duration"] == duration
    assert kwargs["resume"] is False and kwargs["overwrite"] is True


def test_each_parameter_and_the_scene_files_have_a_folder_of_their_own(scene, tmp_path, calls):
    cache = tmp_path / "cache"
    folders = {cached_window(scene, cache, "s", 0.0, 0.5),
               cached_window(scene, cache, "s", 0.0, 0.5, spp=4),
               cached_window(scene, cache, "s", 0.0, 0.5, sampling=SamplingParams(lam=0.25)),
               cached_window(scene, cache, "s", 0.0, 0.5, sampler="frame"),
               cached_window(replace(scene, render=replace(scene.render, seed=9)), cache, "s",
                             0.0, 0.5)}
    scene.source.write_text(scene.text + "\n# edited\n")              # the file, not the text
    folders.add(cached_window(scene, cache, "s", 0.0, 0.5))
    assert len(folders) == len(calls) == 6


def test_a_scene_without_a_render_seed_keeps_the_key_it_had_before_the_key_existed(scene):
    """Caches and checkpoints made before ``[render] seed`` existed still match: the render
    parameters enter the key without it when it is not set (the scene's seed is in already)."""
    from sim.simulate._checkpoint import _identity

    def render(s):
        return _identity(s, 0.0, 0.5, None, None, SamplingParams(), ("h5",))["scene"]["render"]

    assert "seed" not in render(scene)
    assert render(replace(scene, render=replace(scene.render, seed=9)))["seed"] == 9


def test_resume_continues_a_checkpoint_and_only_then(scene, tmp_path, calls):
    folder = tmp_path / "run" / "sequence"
    simulate_window(scene, folder, 0.0, 0.5, resume=True)             # no checkpoint: afresh
    checkpoint = partial_dir(tmp_path / "again") / ".checkpoint" / "checkpoint.json"
    checkpoint.parent.mkdir(parents=True)
    checkpoint.write_text("{}")
    simulate_window(scene, tmp_path / "again", 0.0, 0.5, resume=True)
    simulate_window(scene, tmp_path / "again", 0.0, 0.5, resume=True)  # complete: re-used
    assert [kwargs["resume"] for _, kwargs in calls] == [False, True]
