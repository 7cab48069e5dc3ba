"""Issue 21: the errors of a scene whose objects move, split into the points on moving objects,
the static points a moving object crossed during the window, and the rest; the frozen control."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from fusion.scoring import MOTION_REGIONS, errors_by_motion, motion_regions
from tests.conftest import scene_text

MOVING, CROSSED, STATIC = (MOTION_REGIONS[k] for k in ("moving", "crossed", "static"))


def test_errors_by_motion_by_hand():
    gt = np.full((1, 8), 2.0)
    depth = np.array([[2.1, 2.3, 0.0, 3.0, 2.0, 2.02, 2.04, 1.0]])
    regions = np.array([[MOVING, MOVING, MOVING, CROSSED, STATIC, STATIC, STATIC, STATIC]],
                       np.uint8)
    split = errors_by_motion(depth, gt, regions)
    total = 0.1 + 0.3 + 1.0 + 0.0 + 0.02 + 0.04 + 1.0
    assert split["moving"]["n"] == 2 and split["moving"]["completeness"] == pytest.approx(2 / 3)
    assert split["moving"]["mae_cm"] == pytest.approx(20.0)
    assert split["moving"]["median_cm"] == pytest.approx(20.0)
    assert split["crossed"]["mae_cm"] == pytest.approx(100.0)
    assert split["static"]["mae_cm"] == pytest.approx(100 * 1.06 / 4)
    assert split["static"]["median_cm"] == pytest.approx(3.0)          # a gross outlier
    assert split["moving"]["error_share"] == pytest.approx(0.4 / total)
    assert split["crossed"]["error_share"] == pytest.approx(1.0 / total)
    assert sum(split[k]["error_share"] for k in split) == pytest.approx(1.0)


# A static camera at the origin looking along +y at a wall 1 m away; a ball of radius 0.1 m
# 0.5 m away moves along +x at 0.4 m/s, from x = -0.2 m at t = 0.
BALL = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 1.0, 0.0]
size = [6.0, 6.0]

[[objects]]
name = "ball"
type = "sphere"
center = [-0.2, 0.5, 0.0]
radius = 0.1
motion = { type = "linear", velocity = [0.4, 0.0, 0.0] }
"""


def _ray_distance_to_ball(camera, centres: np.ndarray) -> np.ndarray:
    """Smallest distance (H, W) from each pixel's ray (camera at the origin looking +y, x right,
    z up: camera x = world x, camera y = -world z, camera z = world y) to the ball's centres."""
    xy = camera.normalized_pixel_centres()
    rays = np.stack([xy[..., 0], np.ones(xy.shape[:2]), -xy[..., 1]], -1)   # world frame
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    best = np.full(xy.shape[:2], np.inf)
    for c in centres:
        along = rays @ c
        best = np.minimum(best, np.linalg.norm(rays * along[..., None] - c, axis=-1))
    return best


def test_motion_regions_are_the_ball_and_its_sweep_seen_from_the_view():
    from sim.scene import parse_scene

    scene = parse_scene(scene_text(BALL))
    pose = scene.trajectory.pose(0.0)
    regions = motion_regions(scene, scene.camera, pose, 0.25, (0.0, 0.5))
    # analytically: the ball at t = 0.25 (x = -0.1), and the capsule it sweeps over [0, 0.5]
    now = _ray_distance_to_ball(scene.camera, [np.array([-0.1, 0.5, 0.0])])
    path = np.stack([np.linspace(-0.2, 0.0, 401), np.full(401, 0.5), np.zeros(401)], 1)
    swept = _ray_distance_to_ball(scene.camera, path)
    sure = lambda d: np.abs(d - 0.1) > 0.004        # noqa: E731  (off the silhouette's edge)
    assert np.all((regions == MOVING)[sure(now)] == (now < 0.1)[sure(now)])
    crossed = (swept < 0.1) & (now >= 0.1)
    settled = sure(now) & sure(swept)
    assert np.all((regions == CROSSED)[settled] == crossed[settled])
    assert (regions == MOVING).sum() > 20 and (regions == CROSSED).sum() > 20
    assert (regions == STATIC).sum() > 0.5 * regions.size
    static = parse_scene(scene_text(BALL.replace(
        'motion = { type = "linear", velocity = [0.4, 0.0, 0.0] }', "")))
    assert motion_regions(static, static.camera, pose, 0.25, (0.0, 0.5)) is None


def test_a_frozen_scene_holds_each_object_where_it_was():
    from sim.render import Renderer
    from sim.scene import freeze_scene, parse_scene

    text = BALL.replace('velocity = [0.4, 0.0, 0.0]',
                        'velocity = [0.4, 0.0, 0.0], angular_velocity = [0.0, 0.0, 40.0]')
    scene = parse_scene(scene_text(text))
    frozen = freeze_scene(scene, 0.25)
    assert not frozen.is_dynamic and frozen.name == "test_frozen"
    ball = frozen.objects[1]
    np.testing.assert_allclose(ball.center, [-0.1, 0.5, 0.0], atol=1e-12)      # -0.2 + 0.1
    angle = np.radians(40.0 * 0.25)
    np.testing.assert_allclose(ball.rotation, [[np.cos(angle), -np.sin(angle), 0],
                                               [np.sin(angle), np.cos(angle), 0],
                                               [0, 0, 1]], atol=1e-12)
    assert frozen.objects[0].center.tolist() == scene.objects[0].center.tolist()
    # what the frozen scene records is what it is: its text parses to the same scene
    again = parse_scene(frozen.text)
    assert not again.is_dynamic
    np.testing.assert_allclose(again.objects[1].pose(3.0), scene.objects[1].pose(0.25),
                               atol=1e-12)
    pose = scene.trajectory.pose(0.0)
    np.testing.assert_array_equal(Renderer(frozen, spp=1).depth(0.9, pose=pose),
                                  Renderer(scene, spp=1).depth(0.25, pose=pose))


def test_every_built_in_scene_survives_being_written_back_as_toml():
    """The frozen scene is rebuilt from TOML text written from the scene's own: for a static
    scene that text must give the same scene."""
    from scenes import resolve_scene
    from sim.scene import load_scene, parse_scene
    from sim.scene._freeze import _toml_text

    for name in ("dynamic_6dof", "boxes_6dof", "slider_far", "rig_boxes", "complex_staircase"):
        scene = load_scene(resolve_scene(name))
        again = parse_scene(_toml_text(tomllib.loads(scene.text)), scene.source,
                            seed=scene.seed)
        assert tomllib.loads(again.text) == tomllib.loads(scene.text), name
        for a, b in zip(scene.objects, again.objects, strict=True):
            np.testing.assert_array_equal(a.pose(1.0), b.pose(1.0))
        assert json.dumps(scene.camera.__dict__, default=str) == json.dumps(
            again.camera.__dict__, default=str)


def _with_a_moving_ball(plane_sequence, folder):
    """A copy of ``plane_sequence`` in ``folder`` whose recorded scene (the one scoring reads)
    also holds a ball 0.6 m ahead swinging 0.1 m along x at 1 Hz."""
    import shutil

    shutil.copytree(plane_sequence, folder)
    meta = json.loads((folder / "sequence.json").read_text())
    meta["scene"]["toml"] += ('\n[[objects]]\nname = "ball"\ntype = "sphere"\n'
                              "center = [0.0, 0.6, 0.0]\nradius = 0.1\n"
                              'motion = { type = "sine", amplitude = [0.1, 0.0, 0.0], '
                              "frequency = 1.0 }\n")
    (folder / "sequence.json").write_text(json.dumps(meta))
    return folder


def test_map_fill_and_run_split_the_errors_of_a_scene_with_moving_objects(plane_sequence,
                                                                          tmp_path, capsys):
    """The wall sequence, its scene given a ball swinging in front of the wall (the events are
    the wall's alone: this checks what the scoring reports, not how well EMVS maps a ball)."""

    from fusion.cli import main

    sequence = _with_a_moving_ball(plane_sequence, tmp_path / "sequence")
    run = tmp_path / "run"
    assert main(["run", str(sequence), "--out", str(run), "--min-depth", "0.5",
                 "--max-depth", "3", "--planes", "30", "--quiet"]) == 0
    printed = capsys.readouterr().out
    mapped = json.loads((run / "map" / "map.json").read_text())
    split = mapped["errors_by_motion"]
    assert set(split) == {"moving", "crossed", "static"}
    for key in ("n", "points"):
        assert sum(split[r][key] for r in split) == mapped["errors"][key]
    assert split["moving"]["n"] > 0 and split["crossed"]["n"] > 0
    assert sum(split[r]["error_share"] for r in split) == pytest.approx(1.0)
    assert all("median_cm" in split[r] for r in split)
    filled = json.loads((run / "fill" / "fill.json").read_text())
    assert set(filled["errors_by_motion"]) == {"map", "filled", "all"}
    assert sum(filled["errors_by_motion"]["all"][r]["n"] for r in split) == \
        filled["errors"]["all"]["overall"]["n"]
    report = json.loads((run / "report.json").read_text())
    assert report["errors_by_motion"]["map"] == split
    assert report["errors_by_motion"]["all"] == filled["errors_by_motion"]["all"]
    assert "median_cm" in report["errors_summary"]["map"]
    assert printed.count("on moving objects:") == 4 and "static, crossed by one:" in printed
    assert "median" in printed
    static = tmp_path / "static"
    assert main(["map", str(plane_sequence), "--out", str(static), "--min-depth", "0.5",
                 "--max-depth", "3", "--planes", "30", "--quiet"]) == 0
    assert "errors_by_motion" not in json.loads((static / "map.json").read_text())


def test_reproduce_adds_a_frozen_control_and_splits_the_dynamic_row(plane_sequence, tmp_path,
                                                                     monkeypatch):
    """reproduce's dynamic_6dof row (stood in for by the wall sequence with a swinging ball in
    its scene) is split by region in report.md, and followed by its frozen control, frozen at
    the moving row's reference time."""
    import importlib

    # the package exports a function
    repro = importlib.import_module("fusion.experiments.reproduce")

    moving = _with_a_moving_ball(plane_sequence, tmp_path / "moving")
    asked = []

    def simulated(job, params, cache, views=1):
        asked.append(job)
        return plane_sequence if "frozen_of" in job else moving

    monkeypatch.setattr(repro, "_simulated", simulated)
    params = repro.ReproduceParams(tables=("1",), scenes=("dynamic_6dof",), table1_start=0.0,
                                   long_window=0.3)
    report = repro.reproduce(tmp_path / "report", params, cache=tmp_path / "cache",
                             progress=False)
    rows = report["rows"]
    assert [r["scene"] for r in rows] == ["dynamic_6dof", "dynamic_6dof_frozen"]
    assert "failed" not in rows[0] and "failed" not in rows[1], rows
    assert asked[1]["frozen_of"] == "dynamic_6dof" and asked[1]["frozen_at"] == rows[0]["t_ref"]
    assert rows[1]["frozen_at"] == rows[0]["t_ref"]
    assert set(rows[0]["map_errors_by_motion"]) == {"moving", "crossed", "static"}
    assert set(rows[0]["fills"]["idw"]["errors_by_motion"]) == {"map", "filled", "all"}
    assert "map_errors_by_motion" not in rows[1]
    text = (tmp_path / "report" / "report.md").read_text()
    assert "| dynamic_6dof_frozen | 0.00-0.30 |" in text                  # in Table 1
    assert "### Scenes with moving objects" in text
    for region in ("all", "on moving objects", "static, the rest",
                   "static, crossed by a moving object during the window"):
        assert f"| dynamic_6dof | event map | {region} |" in text, region
        assert f"| dynamic_6dof | dense map | {region} |" in text, region
    assert "| dynamic_6dof_frozen | event map | all (frozen control) |" in text
    assert "## DSI boundary planes" in text and "| dynamic_6dof | 0.00-0.30 |" in text


def test_reproduce_simulates_the_frozen_control_as_the_moving_scene(tmp_path, monkeypatch):
    import importlib

    repro = importlib.import_module("fusion.experiments.reproduce")

    seen = {}

    def fake_simulate(scene, folder, **kwargs):
        seen.update(scene=scene, **kwargs)
        raise RuntimeError("stop")

    monkeypatch.setattr(importlib.import_module("sim.simulate"), "simulate", fake_simulate)
    params = repro.ReproduceParams(tables=("1",), scenes=("dynamic_6dof",))
    jobs = repro._jobs(params)
    assert [j["scene"] for j in jobs] == ["dynamic_6dof", "dynamic_6dof_frozen"]
    with pytest.raises(RuntimeError, match="stop"):
        repro._simulated({**jobs[1], "frozen_at": 7.2}, params, tmp_path)
    scene = seen["scene"]
    assert not scene.is_dynamic and seen["sampler"] == "frame"
    assert scene.render.event_spp == params.moving_event_spp
    assert seen["sampling"].lam == params.moving_lam
    assert seen["start"] == 6.2 and seen["duration"] == 2.0
    from scenes import resolve_scene
    from sim.scene import load_scene

    original = load_scene(resolve_scene("dynamic_6dof"))
    for a, b in zip(original.objects, scene.objects, strict=True):
        np.testing.assert_allclose(b.pose(0.0), a.pose(7.2), atol=1e-12)
    assert scene.frames == original.frames
