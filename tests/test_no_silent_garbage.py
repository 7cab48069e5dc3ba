"""Requests that cannot give a meaningful result are refused in one line (issue 21, "No silent
garbage"): non-finite numbers, declared depth ranges that miss the scene, windows the sequence
cannot hold, millimetres, and a twin scene that its own simulation refuses."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BUILTIN_SCENES = sorted((ROOT / "scenes").glob("*.toml"))


# --------------------------------------------------------------------------------------------
# Declared depth ranges contain the exact depth
# --------------------------------------------------------------------------------------------

def _exact_depth_span(scene, times: int = 3, size: tuple[int, int] = (32, 24)):
    """(min, max) exact z-depth over ``times`` instants of ``[0, duration]``, rendered by
    Mitsuba on a small sensor of the same field of view (plain materials: geometry only)."""
    from sim.render import Renderer
    from sim.scene import Material

    objects = tuple(dataclasses.replace(o, material=Material()) for o in scene.objects)
    small = dataclasses.replace(scene, camera=scene.camera.with_resolution(*size),
                                objects=objects)
    renderer = Renderer(small, spp=1)
    low, high = np.inf, 0.0
    for t in np.linspace(0.0, scene.duration, times):
        depth = renderer.depth(float(t))
        hit = depth[depth > 0]
        assert hit.size, f"{scene.name}: nothing in view at t = {t}"
        low, high = min(low, float(hit.min())), max(high, float(hit.max()))
    return low, high


def _family_members():
    """Every family's knob-range corners and a few interior values (texture does not move
    geometry; shadow only adds a light)."""
    from sim.scene.families import FAMILIES

    for family, knobs in FAMILIES.items():
        names = list(knobs)
        values = [sorted({low, high, default, (low + high) / 2}) for default, low, high in
                  knobs.values()]
        for combo in itertools.product(*values):
            yield family, dict(zip(names, combo, strict=True))


def test_every_family_member_declares_a_range_that_contains_its_exact_depth():
    from sim.scene import parse_scene
    from sim.scene.families import FAMILIES, family_scene
    from sim.validation import ParameterError

    made = {family: 0 for family in FAMILIES}
    seen = set()
    for family, knobs in _family_members():
        try:
            text = family_scene(family, **knobs)
        except ValueError as exc:                  # a refused combination says so in one line
            # ... naming its knobs as parameters, the first word (a flag on the command line)
            assert isinstance(exc, ParameterError) and "\n" not in str(exc)
            assert exc.rephrase({name: f"--{name}" for name in exc.terms}).startswith("--")
            continue
        scene = parse_scene(text)
        geometry = repr([(o.shape, o.center, o.rotation, o.params) for o in scene.objects])
        if geometry in seen:                        # e.g. shadow 0.5 and 1: the same scene
            continue
        seen.add(geometry)
        low, high = _exact_depth_span(scene)
        near, far = scene.depth_range
        assert near <= low and high <= far, (family, knobs, (low, high), (near, far))
        made[family] += 1
    assert all(n >= 4 for n in made.values()), made


def test_a_sphere_or_cylinder_touching_the_camera_is_refused():
    from sim.scene.families import family_scene

    for family in ("sphere", "cylinder"):
        with pytest.raises(ValueError, match="^radius 0.5 with distance 0.5: the"):
            family_scene(family, radius=0.5, distance=0.5)


@pytest.mark.parametrize("path", BUILTIN_SCENES, ids=lambda p: p.stem)
def test_every_builtin_scene_declares_a_range_that_contains_its_exact_depth(path):
    from sim.scene import load_scene

    scene = load_scene(path)
    low, high = _exact_depth_span(scene, times=5)
    near, far = scene.depth_range
    assert near <= low and high <= far, ((low, high), (near, far))


# --------------------------------------------------------------------------------------------
# Non-finite numbers
# --------------------------------------------------------------------------------------------

def _numeric_flags():
    """(command, base argv, flag) for every option of every subcommand that takes a number
    (its argparse ``type`` is neither None nor str), with the base argv filling the command's
    required arguments."""
    import argparse

    from fusion.cli import _parser

    sub = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    for command, parser in sub.choices.items():
        base = [command]
        for action in parser._actions:
            if not action.option_strings and action.nargs != "?":
                base.append("x")
            elif action.required:
                base += [action.option_strings[0], "1"]
        for action in parser._actions:
            if action.option_strings and action.type not in (None, str) \
                    and action.nargs is None:
                yield command, base, action.option_strings[0]


def test_the_numeric_flags_are_found():
    found = {(command, flag) for command, _, flag in _numeric_flags()}
    for expected in [("map", "--c"), ("map", "--t0"), ("run", "--min-depth"),
                     ("simulate", "--contrast"), ("simulate", "--duration"), ("twin", "--depth"),
                     ("fill", "--sigma"), ("bench", "--noise"), ("reproduce", "--window"),
                     ("events", "--window")]:
        assert expected in found
    assert len(found) >= 40


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "NaN", "1e999"])
def test_every_numeric_flag_refuses_a_non_finite_value(value, capsys):
    """Refused by argparse (exit 2, one error line naming the flag) before any work; given
    as ``--flag=VALUE``, the form in which argparse takes ``-inf`` as a value."""
    from fusion.cli import _parser

    for command, base, flag in _numeric_flags():
        with pytest.raises(SystemExit) as stop:
            _parser().parse_args([*base, f"{flag}={value}"])
        assert stop.value.code == 2, (command, flag)
        (error,) = capsys.readouterr().err.strip().splitlines()        # one line, no usage block
        assert error.startswith(f"evfuse {command}: error: argument {flag}: expected "), error
        assert error.endswith(f", got '{value}'"), error


@pytest.mark.parametrize("command, flag, value, expected", [
    ("map", "--planes", "1", "an integer >= 2"),
    ("simulate", "--seed", "-1", "an integer in 0..4294967295"),
    ("simulate", "--seed", "4294967296", "an integer in 0..4294967295"),
    ("simulate", "--duration", "0", "a finite number > 0"),
    ("fill", "--sigma", "-2", "a finite number > 0"),
    ("twin", "--depth", "-0.5", "a finite number > 0"),
])
def test_numeric_flags_refuse_values_out_of_their_range(command, flag, value, expected, capsys):
    from fusion.cli import _parser

    base = {"map": ["map", "seq", "--out", "o"], "simulate": ["simulate", "s", "--out", "o"],
            "fill": ["fill", "m", "--out", "o"], "twin": ["twin", "r", "--out", "o"]}[command]
    with pytest.raises(SystemExit):
        _parser().parse_args([*base, flag, value])
    (error,) = capsys.readouterr().err.strip().splitlines()        # one line, no usage block
    assert error == f"evfuse {command}: error: argument {flag}: expected {expected}, got " \
                    f"'{value}'"


def test_method_settings_refuse_non_finite_numbers(tmp_path, capsys):
    from fusion.cli import main
    from fusion.methods import MethodError, check_params, get_method, parse_label, parse_value

    for text in ("1e999", " -1E999 ", "1e400"):          # literals that overflow
        with pytest.raises(MethodError, match="expected a finite number"):
            parse_value(text)
    assert parse_value("0.5") == 0.5 and parse_value("nan") == "nan"      # text, as before
    with pytest.raises(MethodError, match=r"plane\{residual_rel=1e999\}: residual_rel=1e999"):
        parse_label("plane{residual_rel=1e999}")
    with pytest.raises(MethodError, match="residual_rel expects a number, got nan"):
        check_params("plane", {"residual_rel": parse_value("nan")})
    undeclared = dataclasses.replace(get_method("nearest"), params=None)   # passed on unchecked
    with pytest.raises(MethodError, match="k expects a finite number, got nan"):
        check_params(undeclared, {"k": float("nan")})
    code = main(["fill", str(tmp_path), "--out", str(tmp_path / "o"), "--method", "plane",
                 "--param", "residual_rel=1e999"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == "evfuse fill: error: --param residual_rel=1e999: expected a " \
                                "finite number"


def test_library_parameters_refuse_non_finite_numbers():
    from fusion.experiments.reproduce import ReproduceParams
    from fusion.map.emvs import DepthMapParams
    from fusion.pipeline import RunParams
    from sim.sampling import SamplingParams

    for make, message in [
            (lambda: DepthMapParams(c=float("nan")), "c must be a finite number"),
            (lambda: DepthMapParams(kernel=float("nan")), "kernel must be an integer"),
            (lambda: SamplingParams(max_rate=float("inf")), "max_rate must be a finite"),
            (lambda: ReproduceParams(window=float("inf")), "window must be a finite"),
            (lambda: ReproduceParams(lam=float("nan")), "lam must be a finite"),
            (lambda: RunParams(t0=float("nan")), "t0 must be a finite"),
            (lambda: RunParams(max_depth=float("inf")), "max_depth must be a finite")]:
        with pytest.raises(ValueError, match=message):
            make()


def test_a_twin_window_of_non_finite_times_is_refused_naming_the_flag(tmp_path, capsys):
    from fusion.cli import main

    code = main(["twin", str(tmp_path), "--depth", "0.5", "--window", "nan,1", "--out",
                 str(tmp_path / "t")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("evfuse twin: error: --window: expected T0,T1 in "
                                        "seconds (finite)")


# --------------------------------------------------------------------------------------------
# A window the scene cannot hold
# --------------------------------------------------------------------------------------------

def test_a_default_window_past_the_scene_end_is_refused_naming_t0(tmp_path, capsys, monkeypatch):
    """`evfuse run slider_far --t0 6.4` mapped 0.1 s of the 1 s the help promises."""
    import importlib

    from fusion.cli import main
    from fusion.pipeline import RunParams, _simulate_window
    from scenes import resolve_scene
    from sim.scene import load_scene

    module = importlib.import_module("sim.simulate")
    calls = []
    monkeypatch.setattr(module, "simulate",
                        lambda scene, folder, **k: calls.append((k["start"], k["duration"])))
    code = main(["run", "slider_far", "--t0", "6.4", "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not calls, err
    assert err == ("evfuse run: error: --t0 6.4: the default 1 s window, [6.4, 7.4] s, reaches "
                   "past the end of scene slider_far ([0, 6.5] s); give --t0 at most 5.5 or "
                   "--t1 at most 6.5, or --clip-window to map [6.4, 6.5] s")
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.partial").exists()
    # With clip_window the scene is simulated to its end and the map asked the whole second
    # (map.json then records the window as clipped); a window that fits is simulated as asked.
    for params, window in ((RunParams(t0=6.4, clip_window=True), (6.4, 6.5, 7.4)),
                           (RunParams(t0=5.5), (5.5, 6.5, 6.5))):
        calls.clear()
        scene = load_scene(resolve_scene("slider_far"))
        _, t0, t1 = _simulate_window(scene, tmp_path / "s", params, False, {})
        assert (t0, calls[0][0] + calls[0][1], t1) == pytest.approx(window)


# --------------------------------------------------------------------------------------------
# Millimetres, refused where they enter
# --------------------------------------------------------------------------------------------

def test_a_scene_depth_range_in_millimetres_is_refused_naming_the_key():
    from sim.scene import SceneError, parse_scene
    from sim.validation import PLAUSIBLE_DEPTH_M

    text = (ROOT / "scenes" / "slider_far.toml").read_text()
    assert "depth_range = [0.3, 1.5]" in text
    with pytest.raises(SceneError) as error:
        parse_scene(text.replace("depth_range = [0.3, 1.5]", "depth_range = [500, 3000]"),
                    "mm.toml")
    assert str(error.value) == ("mm.toml: depths are in metres: depth_range 500 looks like "
                                f"millimetres (0.5 m?); depths above {PLAUSIBLE_DEPTH_M:g} m "
                                "are refused")
    parse_scene(text.replace("depth_range = [0.3, 1.5]", "depth_range = [0.3, 90]"))


def test_a_twin_depth_in_millimetres_is_refused_before_reading(tmp_path, capsys):
    from fusion.cli import main
    from sim.twin import write_twin

    with pytest.raises(ValueError, match=r"^depths are in metres: depth 880 looks like "
                                         r"millimetres \(0.88 m\?\)"):
        write_twin(tmp_path / "nowhere", tmp_path / "t", 880.0)
    code = main(["twin", str(tmp_path / "nowhere"), "--depth", "880", "--out",
                 str(tmp_path / "t")])
    assert code == 2 and "--depth 880 looks like millimetres" in capsys.readouterr().err
    assert not (tmp_path / "t").exists()


def test_the_library_refuses_dsi_bounds_in_millimetres():
    from types import SimpleNamespace

    from fusion.map.dsi_range import resolve_dsi_range

    # resolve_dsi_range reads a sequence's folder and the scene TOML kept in sequence.json.
    sequence = SimpleNamespace(folder=Path("seq"), metadata={"scene": {"toml": "x = 1"}})
    with pytest.raises(ValueError, match="^depths are in metres: max_depth 2400 looks like "
                                         "millimetres"):              # the parameter, not a flag
        resolve_dsi_range(sequence, 0.5, 2400.0)
    assert resolve_dsi_range(sequence, 0.5, 2.4).max_depth == 2.4
    # A sequence simulated from a scene in millimetres before scene files were checked for it.
    old = SimpleNamespace(folder=Path("seq"),
                          metadata={"scene": {"toml": "depth_range = [500, 3000]"}})
    with pytest.raises(ValueError, match=r"^the scene recorded in seq/sequence.json: depths are "
                                         r"in metres: depth_range 500 looks like millimetres"):
        resolve_dsi_range(old)
    assert resolve_dsi_range(old, 0.5, 2.4).min_depth == 0.5            # both given: used


@pytest.mark.parametrize("toml, expected", [
    ("depth_range = [0.5]", r"depth_range: expected"),
    ("depth_range = [2.0, 0.5]", r"depth_range: expected \[near, far\] metres with near < far"),
    ('depth_range = ["a", "b"]', r"depth_range: expected a list of 2 positive numbers"),
    ("depth_range = 3", r"depth_range: expected"),
    ("depth_range = [0.5, 2.0", r"not valid TOML"),
])
def test_a_malformed_recorded_depth_range_is_refused_not_ignored(toml, expected):
    from types import SimpleNamespace

    from fusion.map.dsi_range import resolve_dsi_range

    # Read by the scene parser from the scene text sequence.json keeps: one line naming the
    # file and the key, never a silent fall-back to the default range.
    sequence = SimpleNamespace(folder=Path("seq"), metadata={"scene": {"toml": toml}})
    where = r"^the scene recorded in seq/sequence.json: "
    with pytest.raises(ValueError, match=where + expected) as err:
        resolve_dsi_range(sequence)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=expected):
        resolve_dsi_range(sequence, min_depth=0.3)                      # the other bound from it
    assert resolve_dsi_range(sequence, 0.3, 3.0).source.startswith("given")


# --------------------------------------------------------------------------------------------
# evfuse twin's default output simulates
# --------------------------------------------------------------------------------------------

def test_a_twin_of_the_whole_recording_is_accepted_by_simulate(ecd_slider, tmp_path,
                                                              monkeypatch):
    """Its duration was the window's length rounded to 9 significant digits (3.38019462 s),
    past the last pose written to the nanosecond (3.380194616 s): simulate refused it."""
    import importlib

    from sim.scene import load_scene
    from sim.twin import write_twin

    scene = load_scene(write_twin(ecd_slider, tmp_path / "twin", 0.6))       # no window
    assert scene.duration <= scene.trajectory.t_end
    assert scene.duration == pytest.approx(scene.trajectory.t_end, abs=1.5e-9)

    class Validated(Exception):
        pass

    module = importlib.import_module("sim.simulate._run")          # simulate() and its steps

    def renderer(*args, **kwargs):                   # simulate's checks are done: stop here
        raise Validated

    monkeypatch.setattr(module, "Renderer", renderer)
    with pytest.raises(Validated):
        module.simulate(scene, tmp_path / "seq", progress=False)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), 2.5, True])
def test_library_integer_fields_refuse_non_integers(value):
    """Counts and seeds of the parameter dataclasses took NaN (or raised OverflowError on an
    infinity) from the Python API; each is refused in one line naming the field."""
    from fusion.experiments.bench import BenchParams
    from fusion.fill.dense import DenseParams
    from fusion.fill.filling import SelectionParams
    from fusion.fill.segmentation import SegmentationParams
    from sim.events import EventParams

    for make, name in ((lambda v: EventParams(seed=v), "EventParams.seed"),
                       (lambda v: BenchParams(seed=v), "seed"),
                       (lambda v: SegmentationParams(min_region=v), "min_region"),
                       (lambda v: DenseParams(band=v), "band"),
                       (lambda v: SelectionParams(ring=v), "ring")):
        with pytest.raises(ValueError) as info:
            make(value)
        assert str(info.value).startswith(f"{name} must be an integer >= "), str(info.value)
    assert DenseParams(band=2.0).band == 2.0 and SelectionParams(ring=3).ring == 3


def test_a_start_past_the_scene_end_names_the_start(tmp_path, capsys):
    """`simulate slider_close --start 100` said "duration must be positive, got -93.5"."""
    from tests.conftest import run_cli

    assert run_cli(["simulate", "slider_close", "--start", "100", "--out",
                    str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == ("evfuse simulate: error: start 100 s is not "
                                               "before the end of scene slider_close (6.5 s)")
    assert list(tmp_path.iterdir()) == []
