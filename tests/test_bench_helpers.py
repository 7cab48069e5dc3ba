"""The helpers of the cost and convergence benchmarks (``benchmarks/bench_sampling.py``,
``benchmarks/bench_convergence.py``), on no renders: what they measure is only as right as
the scene they run and the figure they compute."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from benchmarks.bench_convergence import _with_spp, event_spp_values, psnr
from benchmarks.bench_sampling import cost_cases, scene_file_at
from scenes import builtin_scenes, resolve_scene
from sim.scene import load_scene


@pytest.mark.parametrize("name", ["slider_close", "rig_boxes"])
def test_the_cost_table_s_scene_copy_has_the_size_asked_and_the_field_of_view_kept(name, tmp_path):
    own = load_scene(resolve_scene(name))
    for size, (width, height) in (("240x180", (240, 180)), ("640x480", (640, 480))):
        scene = load_scene(scene_file_at(name, size, tmp_path))
        assert scene.camera == own.camera.with_resolution(width, height)
        assert [o.name for o in scene.objects] == [o.name for o in own.objects]
        assert (scene.frame_camera is None) == (own.frame_camera is None)


def test_the_cost_table_covers_every_built_in_scene_with_the_samplers_it_allows():
    cases = cost_cases()
    assert {c[0] for c in cases} == set(builtin_scenes())
    for name, _size, start, seconds, sampler in cases:
        scene = load_scene(resolve_scene(name))
        assert sampler in (("frame",) if scene.is_dynamic else ("pixel", "frame"))
        assert 0.0 <= start and start + seconds <= scene.duration
    assert {c[1] for c in cases} == {"240x180", "640x480"}


def test_psnr_of_a_uniform_one_level_error_is_48_db():
    reference = np.full((4, 5), 100.0)
    assert psnr(reference, reference + 1.0) == pytest.approx(20 * np.log10(255.0))
    assert psnr(reference, reference) == float("inf")


def test_the_floor_s_reference_differs_from_the_reference_by_its_render_seed_alone():
    scene = load_scene(resolve_scene("boxes_6dof"))
    reference = _with_spp(scene, 256, 0.5)
    floor = _with_spp(scene, 256, 0.5, render_seed=scene.seed + 1)
    assert floor.render.seed == scene.seed + 1 and reference.render.seed is None
    assert floor.seed == reference.seed                  # textures drawn from the same seed
    assert replace(floor, render=reference.render) == reference


def test_the_event_spp_sweep_takes_perfect_squares_below_the_reference_s_256():
    """The stratified sampler takes n x n sub-samples, and the reference is 256."""
    assert event_spp_values("64,1,16,4,16") == (1, 4, 16, 64)
    for text in ("8", "256", "0", "", "four"):
        with pytest.raises(ValueError, match="--event-spp: expected"):
            event_spp_values(text)


def test_the_worst_block_counts_only_blocks_with_100_reference_events():
    """A block of 9 reference events that the stream doubles is not compared; the worst block
    is the dense one (150 events, 165 in the stream: +10 %), and its reference events are
    reported beside it."""
    from benchmarks.agreement import event_agreement

    def stream(counts: dict[tuple[int, int], int]) -> np.ndarray:
        events = np.zeros(sum(counts.values()), dtype=[("t", "<i8"), ("x", "<u2"),
                                                       ("y", "<u2"), ("p", "i1")])
        rows = [(y, x) for (y, x), n in counts.items() for _ in range(n)]
        events["y"], events["x"] = np.array(rows).T
        events["t"] = np.arange(len(rows))
        events["p"] = 1
        return events

    reference = stream({(3, 3): 150, (20, 40): 9})
    agreement = event_agreement(reference, stream({(3, 3): 165, (20, 40): 18}), (36, 48))
    assert agreement.blocks == 1
    assert agreement.worst_block == (0, 0) and agreement.worst_block_events == 150
    assert agreement.worst_block_error == pytest.approx(0.1)


def test_the_gpu_check_script_runs_its_chosen_steps_and_summarises_them(tmp_path):
    """``benchmarks/gpu_check.sh`` (for a lent GPU machine) with no steps: it says what it ran
    on and writes an empty summary; with an unknown step it says so (one line) and goes on."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "OUT": str(tmp_path / "out"), "STEPS": "9", "PYTHON": sys.executable}
    done = subprocess.run(["bash", str(root / "benchmarks" / "gpu_check.sh")], cwd=root,
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stderr.strip().splitlines()[-1] == "unknown step 9"
    env_lines = (tmp_path / "out" / "env.txt").read_text().splitlines()
    assert any(line.startswith("mitsuba ") for line in env_lines)
    assert env_lines[-1].startswith("variant ")
    summary = (tmp_path / "out" / "summary.txt").read_text().splitlines()
    assert summary[0].startswith("issue 36 on ")
    assert summary[1].split()[:2] == ["run", "variant"]
    # no step ran: every row says so, none is a figure
    assert summary[2:] and all("not run or failed" in line for line in summary[2:])
