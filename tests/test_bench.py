"""evfuse bench on a tiny simulated run: every method x input scored and ranked twice, the
files it promises, a user's method from outside the package, and a bad method that gets its
own row while the others go on."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from fusion.cli import main
from fusion.experiments.bench import CSV_COLUMNS, bench
from tests.conftest import FAST, WALL, scene_text

EXTRA = ("depth_range = [0.4, 2.5]\n"
         "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n")
USER_MODULE = """
import numpy as np

def mean_fill(frame, sparse, camera, params):
    '''Every pixel at the mean input depth, confidence 1 near input points.'''
    dense = np.full(frame.shape, sparse[sparse > 0].mean(), np.float32)
    return dense, (sparse > 0).astype(np.float32)

def broken(frame, sparse, camera, params):
    return np.full((3, 3), 1.0)

def shifted(frame, sparse, camera, params):
    '''Every pixel without an input point at the mean input depth plus params['shift'] m.'''
    mean = sparse[sparse > 0].mean() + params.get("shift", 0.0)
    return np.where(sparse > 0, sparse, mean).astype(np.float32)
"""


@pytest.fixture(scope="module")
def tiny_map(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench")
    scene = folder / "wall.toml"
    scene.write_text(scene_text(WALL, trajectory=FAST, duration=0.3, extra=EXTRA))
    assert main(["run", str(scene), "--t0", "0.0", "--t1", "0.3", "--out",
                 str(folder / "run"), "--quiet"]) == 0
    (folder / "bench_user_methods.py").write_text(USER_MODULE)
    return folder


def test_the_bench_scores_ranks_and_writes_every_method_and_input(tiny_map, monkeypatch,
                                                                  capsys):
    monkeypatch.syspath_prepend(str(tiny_map))
    out = tiny_map / "out"
    code = main(["bench", "--scenes", str(tiny_map / "run" / "map"), "--input",
                 "emvs,oracle,oracle-edges,oracle-noisy", "--method",
                 "bench_user_methods:mean_fill,bench_user_methods:broken", "--out", str(out),
                 "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert "fills (4 failed)" in capsys.readouterr().out
    for name in ("bench.md", "bench.csv", "bench.json", "figures/run_oracle.png",
                 "figures/run_emvs.png"):
        assert (out / name).is_file(), name
    rows = list(csv.DictReader((out / "bench.csv").open()))
    assert tuple(rows[0]) == CSV_COLUMNS
    methods = {row["method"] for row in rows}
    assert {"paper-idw", "nearest", "telea", "morphological", "bench_user_methods:mean_fill",
            "bench_user_methods:broken"} <= methods
    assert {row["input"] for row in rows} == {"emvs", "oracle", "oracle-edges", "oracle-noisy"}
    assert len(rows) == 4 * len(methods)
    broken = [row for row in rows if row["method"].endswith("broken")]
    assert all(row["status"].startswith("failed: filling method bench_user_methods:broken "
                                        "returned a dense depth of shape (3, 3)")
               for row in broken)
    ok = [row for row in rows if row["status"] == "ok"]
    assert all(float(row["completeness"]) > 0 and row["time_ms"] for row in ok)
    by = {(row["input"], row["method"]): row for row in ok}
    # Perfect input points: the nearest-point fill is at least as good as from the event map,
    # and the mean fill gives its confident half a score.
    assert float(by["oracle", "nearest"]["mae_cm"]) <= float(by["emvs", "nearest"]["mae_cm"])
    assert by["oracle", "bench_user_methods:mean_fill"]["mae_at_half_cm"] != ""
    # The common pixels are the same for every method of a scene and input.
    assert len({row["common_pixels"] for row in ok if row["input"] == "oracle"}) == 1
    text = (out / "bench.md").read_text()
    assert "## Input: oracle-noisy" in text and "**" in text and "rank on common" in text
    assert "failed: filling method bench_user_methods:broken" in text


def test_the_python_entry_point_returns_the_table(tiny_map):
    rows = bench(["nearest", "paper-idw"], [str(tiny_map / "run" / "map")], ["oracle"],
                 cache=tiny_map / "cache", progress=False)
    assert [row["method"] for row in rows] == ["nearest", "paper-idw"]
    nearest = rows[0]
    assert nearest["completeness"] == pytest.approx(1.0, abs=0.05)    # fills everything seen
    assert np.count_nonzero(nearest["_dense"]) >= np.count_nonzero(rows[1]["_dense"])
    json.dumps({k: v for k, v in nearest.items() if not k.startswith("_")})


def test_one_method_under_two_settings_gives_two_rows_labelled_by_them(tiny_map, monkeypatch,
                                                                      capsys):
    """``--method M --method 'M{KEY=VALUE}'`` benches M twice; ``--param M.KEY=VALUE`` sets KEY
    for both. Each row's method is its label, and bench.csv's last column its settings as
    JSON."""
    monkeypatch.syspath_prepend(str(tiny_map))
    out = tiny_map / "out_params"
    user = "bench_user_methods:shifted"
    code = main(["bench", "--scenes", str(tiny_map / "run" / "map"), "--input", "oracle",
                 "--only", "--method", f"plane,{user}", "--method", f"{user}{{shift=0.5}}",
                 "--param", "plane.residual_rel=0.05", "--out", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert "3 fills (0 failed) of 3 methods" in capsys.readouterr().out
    rows = list(csv.DictReader((out / "bench.csv").open()))
    assert tuple(rows[0]) == CSV_COLUMNS and CSV_COLUMNS[-1] == "params"
    assert [(row["method"], row["params"]) for row in rows] == [
        ("plane{residual_rel=0.05}", '{"residual_rel":0.05}'), (user, "{}"),
        (f"{user}{{shift=0.5}}", '{"shift":0.5}')]
    assert all(row["status"] == "ok" for row in rows)
    # The setting reached the method in its worker: the oracle input is the exact depth of a
    # wall parallel to the image plane, so the mean input depth is every pixel's; the plain
    # fill is exact and the one shifted by 0.5 m is 50 cm off wherever it filled.
    by = {row["method"]: float(row["filled_mae_cm"]) for row in rows}
    assert by[user] == pytest.approx(0.0, abs=0.01)
    assert by[f"{user}{{shift=0.5}}"] == pytest.approx(50.0, abs=0.01)
    document = json.loads((out / "bench.json").read_text())
    assert [row["params"] for row in document["rows"]] == [{"residual_rel": 0.05}, {},
                                                           {"shift": 0.5}]
    text = (out / "bench.md").read_text()
    assert f"| {user}{{shift=0.5}} |" in text and "| plane{residual_rel=0.05} |" in text
    assert "--param plane.residual_rel=0.05" in text               # the command, as given


def test_without_only_the_built_ins_run_at_their_defaults_beside_the_settings(monkeypatch,
                                                                            tmp_path):
    """What is benched, before any work: every built-in at its defaults, then the --method
    entries with their settings; an entry equal to a built-in's is one row."""
    import fusion.experiments.bench
    from fusion.methods import available_methods

    asked = {}

    def run_bench(methods, *args, **kwargs):
        asked["methods"] = methods
        return []

    monkeypatch.setattr(fusion.experiments.bench, "run_bench", run_bench)
    assert main(["bench", "--method", "plane,nearest", "--param", "plane.residual_rel=0.03",
                 "--out", str(tmp_path / "o"), "--quiet"]) == 0
    labels = [variant.label for variant in asked["methods"]]
    assert labels == [*available_methods(), "plane{residual_rel=0.03}"]
    assert asked["methods"][-1].params == {"residual_rel": 0.03}


@pytest.mark.parametrize("argv, message", [
    (["--input", "exact"], "--input exact: expected among emvs, oracle"),
    (["--scenes", "no_such_scene"], "--scenes no_such_scene: unknown scene"),
    (["--method", "no-such-method"], "unknown filling method 'no-such-method'"),
    (["--steps", "2,4"], "--steps is a knob of a scene family: give --family too"),
    (["--param", "residual_rel=0.03"],
     "--param residual_rel=0.03: no --method given; --param sets the settings of the --method "
     "ones"),
    (["--method", "plane", "--method", "guided", "--param", "radius=3"],
     "--param radius=3: 2 methods given (plane, guided), whose is it? Write --param "
     "METHOD.radius=... (every entry of METHOD) or --method 'METHOD{radius=...}' (that entry)"),
    (["--method", "plane", "--method", "plane", "--param", "residual_rel=0.03"],
     "--param residual_rel=0.03: 2 methods given (plane, plane), whose is it?"),
    (["--method", "plane", "--param", "telea.radius=3"],
     "--param telea.radius=3: telea is not among the --method ones (plane); --param sets "
     "their settings only"),
    (["--method", "plane,guided", "--param", "guided.radius=0.5"],
     "--param guided.radius=0.5: filling method guided: radius expects an integer, got 0.5"),
    (["--method", "plane{residual_rel=0}"],
     "--method plane{residual_rel=0}: filling method plane: residual_rel must be a finite "
     "number > 0, got 0.0"),
    (["--method", "plane", "--param", "plane.residual_rel"],
     "--param plane.residual_rel: expected KEY=VALUE, or METHOD.KEY=VALUE"),
])
def test_bad_bench_arguments_are_refused_in_one_line(argv, message, tmp_path, capsys):
    code = main(["bench", *argv, "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "o").exists()


def test_a_family_expands_into_one_scene_per_knob_value(tmp_path):
    from sim.scene import parse_scene
    from sim.scene.families import FAMILIES, family_scene, family_variants

    names = [parse_scene(text).name for text in family_variants("staircase",
                                                                {"steps": [2, 4, 8]})]
    assert names == ["staircase_steps2_step_depth0.2", "staircase_steps4_step_depth0.2",
                     "staircase_steps8_step_depth0.1142"]    # 8 steps share 0.8 m by default
    assert [len(parse_scene(family_scene("staircase", steps=n)).objects) for n in (2, 8)] \
        == [3, 9]                                                # the wall and the steps
    for family in FAMILIES:                                      # every member is a valid scene
        for texture in (0, 1):
            parse_scene(family_scene(family, texture=texture))
    shadow = [len(parse_scene(family_scene("sphere", shadow=s)).lights) for s in (0, 1)]
    assert shadow == [1, 2]
    from sim.scene.families import write_family

    files = write_family("sphere", {"radius": [0.1, 0.3], "texture": [0, 1]}, tmp_path / "f")
    assert len(files) == 4 and all(path.suffix == ".toml" for path in files)
    assert [parse_scene(path.read_text()).name for path in files] == [path.stem for path in files]


@pytest.mark.parametrize("family, knobs, message", [
    ("tower", {}, "family tower: expected one of staircase"),
    ("sphere", {"steps": 3}, "family sphere has no knob 'steps'"),
    ("slanted", {"angle": 80}, "angle 80: expected 0 to 75"),
    ("staircase", {"steps": 8, "step_depth": 0.3}, "steps 8 with step_depth 0.3: the last step "
                                                   "would stand at or behind the wall"),
    ("sphere", {"radius": 0.5, "distance": 0.6}, "radius 0.5 with distance 0.6: the sphere's "
                                                  "front"),
])
def test_a_bad_family_or_knob_is_named(family, knobs, message):
    """The library names its parameters, never a flag."""
    from sim.scene.families import family_scene

    with pytest.raises(ValueError) as info:
        family_scene(family, **knobs)
    assert str(info.value).startswith(message) and "--" not in str(info.value)


@pytest.mark.parametrize("argv, line", [
    (["--family", "tower"], "--family tower: expected one of staircase, sphere"),
    (["--family", "sphere", "--steps", "3"], "--family sphere has no knob 'steps'"),
    (["--family", "slanted", "--angle", "80"], "--angle 80: expected 0 to 75 for the slanted "
                                               "family"),
    (["--family", "staircase", "--steps", "8", "--step-depth", "0.3"],
     "--steps 8 with --step-depth 0.3: the last step would stand at or behind the wall"),
    (["--family", "sphere", "--radius", "0.5", "--distance", "0.6"],
     "--radius 0.5 with --distance 0.6: the sphere's front"),
    (["--scenes", "nowhere"], "--scenes nowhere: unknown scene 'nowhere'; expected built-in"),
])
def test_a_bad_family_or_scene_is_refused_in_the_flags_terms(tmp_path, capsys, argv, line):
    """``evfuse bench`` prints the family's and the scenes' refusals in its flags (as before
    they were raised in the library's terms), before any folder is made."""
    assert main(["bench", *argv, "--out", str(tmp_path / "b")]) == 2
    assert capsys.readouterr().err.startswith(f"evfuse bench: error: {line}")
    assert not list(tmp_path.iterdir())


def test_the_coverage_curve_keeps_the_most_confident_pixels_first():
    from fusion.experiments.bench import coverage_curve

    truth = np.full((2, 5), 2.0, np.float32)
    sparse = np.zeros_like(truth)
    sparse[0, 0] = 2.0                                       # an input point: not counted
    dense = truth + np.float32([[0, 0.01, 0.02, 0.03, 0.04], [0.05, 0.06, 0.07, 0.08, 0.09]])
    dense[0, 0] = 2.0
    confidence = np.float32([[1, 0.9, 0.8, 0.7, 0.6], [0.5, 0.4, 0.3, 0.3, 0.3]])
    curve = dict(coverage_curve(dense, sparse, truth, confidence, (1 / 9, 5 / 9, 1.0)))
    assert curve[1 / 9] == pytest.approx(1.0)                # the most confident: 1 cm
    assert curve[5 / 9] == pytest.approx(3.0)                # 1..5 cm
    assert curve[1.0] == pytest.approx(5.0)                  # all nine filled pixels
    assert dict(coverage_curve(dense, truth, truth, confidence, (0.5,)))[0.5] is None


def test_the_canny_input_is_the_exact_depth_on_the_frames_edges(tiny_map):
    import cv2

    from fusion.experiments.bench import CANNY_THRESHOLDS, BenchParams, _inputs

    base, inputs = _inputs(tiny_map / "run" / "map", BenchParams())
    edges = cv2.Canny(base.frame, *CANNY_THRESHOLDS) > 0
    canny = inputs["oracle-canny"]
    assert edges.any() and np.array_equal(canny > 0, edges & (base.truth > 0))
    np.testing.assert_array_equal(canny[canny > 0], base.truth[canny > 0].astype(np.float32))


def test_bench_md_records_the_family_command_that_was_run(monkeypatch, tmp_path):
    """A --family run printed `--scenes complex` (the unused default) in bench.md: the command
    it records must be one that runs the same bench again."""
    import shlex

    import fusion.experiments.bench
    from fusion.cli import _parser

    asked = {}

    def run_bench(methods, scenes, inputs, out, **kwargs):
        asked.update(scenes=scenes, command=kwargs["command"])
        return []

    monkeypatch.setattr(fusion.experiments.bench, "run_bench", run_bench)
    argv = ["bench", "--family", "staircase", "--steps", "3,5", "--input", "oracle,emvs",
            "--method", "plane", "--noise", "0.03", "--out", str(tmp_path / "b"), "--quiet"]
    assert main(argv) == 0
    command = asked["command"]
    assert "--scenes" not in command and "--family staircase --steps 3,5" in command, command
    words = shlex.split(command)
    assert words[:2] == ["evfuse", "bench"]
    again, given = _parser().parse_args(words[1:]), _parser().parse_args(argv)
    for key in ("family", "steps", "input", "method", "noise", "outliers", "scenes", "out"):
        assert getattr(again, key) == getattr(given, key), key
