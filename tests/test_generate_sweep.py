"""Sweep files (:mod:`sim.dataset`): every refusal names the file and the key; jobs, their ids
and drawn parameters are functions of the sweep's values and seeds only; a job's parameters
reach the scene and simulate's objects. No simulation here (fast)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenes import resolve_scene
from sim.dataset import SweepError, job_inputs, load_sweep, parse_sweep
from sim.noise import noise_preset
from sim.scene import load_scene

BASE = """seeds = [1, 2]

[[scenes]]
name = "slider_close"

[grid]
sensor = "48x36"
t1 = 0.05
"""


@pytest.mark.parametrize("text, where, what", [
    ("colour = 1\n" + BASE, "colour", "unknown key"),
    (BASE.replace("seeds = [1, 2]", "seeds = [1, -2]"), "seeds[1]", "integer in 0.."),
    (BASE.replace("seeds = [1, 2]\n", ""), "seeds", "expected a list"),
    (BASE.replace('name = "slider_close"', 'name = "nowhere"'), "scenes[0].name",
     "not a built-in scene"),
    (BASE.replace('name = "slider_close"', 'name = "slider_close"\nfamily = "sphere"'),
     "scenes[0]", "exactly one of"),
    (BASE.replace('name = "slider_close"', 'file = "missing.toml"'), "scenes[0].file",
     "no scene file"),
    (BASE.replace('name = "slider_close"', 'family = "sphere"\nradius = [0.2, 9.0]'),
     "scenes[0]", "radius"),
    (BASE.replace('name = "slider_close"', 'procedural = "forest"'), "scenes[0].procedural",
     "tabletop"),
    (BASE.replace('name = "slider_close"', 'procedural = "tabletop"\nobjetcs = [5, 6]'),
     "scenes[0].objetcs", "not a range of the tabletop family"),
    (BASE.replace('name = "slider_close"', 'procedural = "room"\nobjects = [6, 5]'),
     "scenes[0]", "low <= high"),
    (BASE + "contrast = [0.2, -0.1]\n", "grid.contrast[1]", "contrast"),
    (BASE + "bogus = 3\n", "grid.bogus", "unknown parameter"),
    (BASE.replace('"48x36"', '"48 by 36"'), "grid.sensor", "WIDTHxHEIGHT"),
    (BASE + 'noise = "loud"\n', "grid.noise", "ideal"),
    (BASE + "spp = 5\n", "grid.spp", "perfect square"),
    (BASE + "wavefront = 0\n", "grid.wavefront", "integer >= 1"),
    (BASE + 'wavefront = 4\nsampler = "frame"\n', "grid", "only the per-pixel sampler"),
    (BASE + "\n[draw]\ncontrast = { gauss = [0.1, 0.2] }\n", "draw.contrast", "uniform"),
    (BASE + "\n[draw]\ncontrast = { uniform = [0.3, 0.1] }\n", "draw.contrast.uniform",
     "low < high"),
    (BASE + "\n[draw]\nt1 = { uniform = [0.1, 0.2] }\n", "draw.t1", "also in [grid]"),
    ("seeds = [1]\n[[scenes]]\nname = 'slider_close'\n[[scenes]]\nname = 'slider_close'\n",
     "scenes", "two jobs alike"),
    ("seeds = [1\n", "not valid TOML", ""),
])
def test_a_bad_sweep_is_refused_naming_file_and_key(tmp_path, text, where, what):
    path = tmp_path / "bad_sweep.toml"
    path.write_text(text)
    with pytest.raises(SweepError) as caught:
        load_sweep(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: {where}"), message
    assert what in message


def test_a_missing_sweep_file_is_named(tmp_path):
    with pytest.raises(SweepError, match="nothing.toml: cannot read"):
        load_sweep(tmp_path / "nothing.toml")


def test_jobs_are_the_product_of_scenes_grid_and_seeds_with_stable_ids(tmp_path):
    text = BASE.replace('name = "slider_close"',
                        'family = "sphere"\nradius = [0.2, 0.3]') + "contrast = [0.2, 0.3]\n"
    sweep = parse_sweep(text, tmp_path / "a.toml")
    assert len(sweep.jobs) == 2 * 2 * 2                  # radii x contrasts x seeds
    assert sweep.parameters == ("contrast", "sensor", "t1")
    again = parse_sweep(text, tmp_path / "elsewhere" / "b.toml")
    assert [j.job_id for j in again.jobs] == [j.job_id for j in sweep.jobs]
    assert len({j.job_id for j in sweep.jobs}) == 8
    # one value changed: only the jobs with that value change their ids
    other = parse_sweep(text.replace("contrast = [0.2, 0.3]", "contrast = [0.2, 0.35]"))
    same = {j.job_id for j in sweep.jobs} & {j.job_id for j in other.jobs}
    assert len(same) == 4
    assert all(j.job_id.startswith(f"sphere-{j.seed}-") for j in sweep.jobs)


def test_drawn_parameters_depend_on_the_seed_only():
    draw = "\n[draw]\ncontrast = { uniform = [0.1, 0.4] }\nnoise = { choice = ['ideal', " \
           "'realistic'] }\nspp = { choice = [1, 4] }\n"
    sweep = parse_sweep(BASE.replace("[1, 2]", "{ first = 0, count = 40 }") + draw)
    values = np.array([job.params["contrast"] for job in sweep.jobs])
    assert np.all((values >= 0.1) & (values <= 0.4)) and len(set(values)) == 40
    assert {job.params["noise"] for job in sweep.jobs} == {"ideal", "realistic"}
    # the same seed in another sweep (another scene, one more drawn parameter): same contrast
    other = parse_sweep(BASE.replace('name = "slider_close"', 'name = "boxes_6dof"')
                        .replace("[1, 2]", "[7]") + draw + "lam = { uniform = [0.3, 0.6] }\n")
    assert other.jobs[0].params["contrast"] == sweep.jobs[7].params["contrast"]


def test_a_jobs_parameters_reach_the_scene_and_simulates_objects():
    text = BASE + ('frame_rate = 20.0\nspeed = 2.0\ncontrast = 0.3\nnoise = "realistic"\n'
                   'lam = 0.4\nrig = "mocap"\nsampler = "frame"\nt0 = 0.5\n')
    job = parse_sweep(text.replace("t1 = 0.05", "t1 = 0.6")).jobs[0]
    scene, kwargs = job_inputs(job)
    assert (scene.camera.width, scene.camera.height) == (48, 36)
    assert scene.frames.rate == 20.0 and scene.seed == 1
    assert kwargs["events"].contrast_on == 0.3 and kwargs["events"].seed == 1
    assert kwargs["events"].noise == noise_preset("realistic")
    assert kwargs["sampling"].lam == 0.4 and kwargs["rig"].preset == "mocap"
    assert kwargs["start"] == 0.5 and kwargs["duration"] == pytest.approx(0.1)
    assert kwargs["sampler"] == "frame"
    base = job_inputs(parse_sweep(BASE).jobs[0])[0]
    # speed 2: the camera is where the original one was at twice the time
    assert np.allclose(scene.trajectory.pose(0.25), base.trajectory.pose(0.5))
    assert scene.duration == pytest.approx(base.duration / 2)


def test_a_parameter_the_scene_refuses_is_said_when_the_job_is_built():
    # slider_close's auto-exposure goes up to 40 ms: at 50 Hz its ceiling is the frame period,
    # as a camera's; its 5-ms exposure at 250 Hz (a 4-ms period) is refused.
    scene, _ = job_inputs(parse_sweep(BASE + "frame_rate = 50.0\n").jobs[0])
    assert scene.frames.max_exposure == pytest.approx(0.02) and scene.frames.exposure == 0.005
    job = parse_sweep(BASE + "frame_rate = 250.0\n").jobs[0]
    with pytest.raises(ValueError, match="frame period"):
        job_inputs(job)


def test_time_scaled_trajectory_is_exact():
    from sim.trajectory import TimeScaledTrajectory

    base = load_scene(resolve_scene("boxes_6dof")).trajectory        # a hand-held shake
    fast = TimeScaledTrajectory(base, 2.5)
    t = np.linspace(0.1, 1.0, 7)
    h = 1e-6
    position = lambda s: fast.pose(s)[..., :3, 3]           # noqa: E731
    v, _ = fast.velocity(t)
    assert np.allclose(v, (position(t + h) - position(t - h)) / (2 * h), atol=1e-6)
    a, _ = fast.acceleration(t)
    v_fd = (fast.velocity(t + h)[0] - fast.velocity(t - h)[0]) / (2 * h)
    assert np.allclose(a, v_fd, atol=1e-4)
    with pytest.raises(ValueError, match="scale"):
        TimeScaledTrajectory(base, 0.0)


def test_families_live_in_sim_and_keep_their_old_paths():
    import fusion.experiments.families as old

    import sim.scene.families as new
    from fusion import families as older

    assert old is new and older is new
    assert "fusion.experiments.families" in new.family_scene("sphere")   # texts unchanged


@pytest.mark.parametrize("name, jobs", [("tiny", 4), ("tabletop", 400), ("families", 84)])
def test_the_example_sweeps_are_valid(name, jobs):
    from pathlib import Path

    sweep = load_sweep(Path(__file__).resolve().parent.parent / "sweeps" / f"{name}.toml")
    assert len(sweep.jobs) == jobs


def test_generate_refuses_local_sizes_with_a_scheduler_in_its_flags(tmp_path, capsys):
    from fusion.cli import main

    sweep = str(Path(__file__).resolve().parent.parent / "sweeps" / "tiny.toml")
    out = tmp_path / "d"
    assert main(["generate", sweep, "--out", str(out), "--scheduler", "tcp://127.0.0.1:1",
                 "--workers", "2"]) == 2
    err = capsys.readouterr().err
    assert "--workers and --threads size a local cluster; with --scheduler" in err
    with pytest.raises(SystemExit) as stopped:                    # refused by its parser
        main(["generate", sweep, "--out", str(out), "--gpu-per-job", "0"])
    assert stopped.value.code == 2 and "--gpu-per-job" in capsys.readouterr().err
    assert not out.exists()


def test_a_sweep_spp_that_cannot_fit_memory_is_refused_before_any_job():
    """A sweep's ``spp`` is checked with each job's sensor (its ``sensor`` value, else its
    scene's camera) when the file is read, not left to fail every job (issue 39: 7)."""
    with pytest.raises(SweepError, match=r"grid: a job of slider_close at 240x180 with spp = "
                                         r"1000000: .* needs at least about .* GiB"):
        parse_sweep('seeds = [1]\n[[scenes]]\nname = "slider_close"\n[grid]\nspp = 1000000\n')
    with pytest.raises(SweepError, match=r"at 16x12 with spp = 100000000"):
        parse_sweep('seeds = [1]\n[[scenes]]\nname = "slider_close"\n[grid]\nsensor = "16x12"\n'
                    'spp = 100000000\n')
    assert len(parse_sweep('seeds = [1]\n[[scenes]]\nname = "slider_close"\n[grid]\n'
                           'spp = 16\n').jobs) == 1


def test_a_sweep_window_too_short_for_one_frame_is_refused_before_any_job():
    """Found by the generate fuzz target: ``t1 = 1e-09`` failed every job at run time."""
    with pytest.raises(SweepError, match=r"grid: a job of slider_close simulates 1e-09 s, too "
                                         r"short for one frame at 24 Hz"):
        parse_sweep('seeds = [1]\n[[scenes]]\nname = "slider_close"\n[grid]\nt1 = 1e-09\n')


def test_a_family_knob_of_an_empty_list_is_refused_not_a_sweep_of_no_jobs():
    """Found by the long fuzz run: ``radius = []`` made a sweep of no jobs, accepted."""
    with pytest.raises(SweepError, match=r"scenes\[0\]\.radius: an empty list \(no scene\)"):
        parse_sweep('seeds = [1]\n[[scenes]]\nfamily = "sphere"\nradius = []\n')
