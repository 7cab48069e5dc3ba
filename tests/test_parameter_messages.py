"""Library refusals name the library's parameters; ``evfuse`` prints them in its flags (issue 22).

Each case gives a refused call twice: through the library (its ``str(error)`` names parameters,
never a ``--flag``) and through the command line (the line it printed before the library
stopped speaking in flags, pinned here word for word).
"""

from __future__ import annotations

import pytest

from fusion.cli import main
from sim.validation import ParameterError
from tests.test_cli_messages import _sequence


def _cli_line(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def _library_message(call) -> str:
    with pytest.raises(ParameterError) as info:
        call()
    message = str(info.value)
    assert "--" not in message, message
    return message


@pytest.fixture
def recording(tmp_path):
    """A hand-made sequence folder without exact depth: 200 events in [0.1, 0.9] s, poses
    over [0, 1] s."""
    return _sequence(tmp_path / "seq")


def test_the_dsi_range_names_its_parameters(recording, tmp_path, capsys):
    from fusion.map.dsi_range import resolve_dsi_range
    from sim.sequence import load_sequence

    sequence = load_sequence(recording)
    assert _library_message(lambda: resolve_dsi_range(sequence, oracle=True, t_ref=0.5)) == (
        f"oracle=True needs the exact depth of a simulated sequence; {recording} has none (a "
        "real recording): give min_depth/max_depth")
    assert _library_message(lambda: resolve_dsi_range(sequence, 1.0, oracle=True)) == (
        "oracle=True takes the range from the exact depth: drop min_depth/max_depth, or drop "
        "oracle=True")
    # (the range's source, "given (--max-depth)", is recorded as it is in map.json: not reworded)
    with pytest.raises(ParameterError, match=": expected 0 < min_depth < max_depth, in metres$"):
        resolve_dsi_range(sequence, max_depth=0.1)
    out = str(tmp_path / "o")
    for command in ("map", "run"):
        assert _cli_line(capsys, [command, str(recording), "--out", out, "--depth-range",
                                  "oracle"]) == (
            f"evfuse {command}: error: --depth-range oracle needs the exact depth of a simulated "
            f"sequence; {recording} has none (a real recording): give --min-depth/--max-depth")
    assert _cli_line(capsys, ["map", str(recording), "--out", out, "--depth-range", "oracle",
                              "--min-depth", "1"]) == (
        "evfuse map: error: --depth-range oracle takes the range from the exact depth: drop "
        "--min-depth/--max-depth, or drop --depth-range oracle")
    assert _cli_line(capsys, ["map", str(recording), "--out", out, "--max-depth", "0.1"]) == (
        "evfuse map: error: depth range [0.2, 0.1] m (given (--max-depth), the other bound from "
        "the default 0.2-5 m): expected 0 < --min-depth < --max-depth, in metres")


def test_the_time_window_names_its_parameters(recording, tmp_path, capsys):
    from fusion.map.mapping import time_window
    from sim.sequence import load_sequence

    sequence = load_sequence(recording)
    data = "events [0.104660, 0.898594] s, poses [0.000000, 1.000000] s"
    assert _library_message(lambda: time_window(sequence, 0.5, 0.2)) == (
        "empty time window [0.5, 0.2] s; expected t0 < t1")
    assert _library_message(lambda: time_window(sequence, 0.2, 1.5)) == (
        f"time window [0.2, 1.5] s reaches 0.601 s past the data ({data}); choose t0/t1 within "
        "[0.104660, 0.898594] s, or add clip_window=True to map [0.200000, 0.898594] s")
    assert _library_message(lambda: time_window(sequence, ref_time=3.0)) == (
        "reference time 3.0 s is outside the poses [0.000000, 1.000000] s; choose ref_time "
        "within them")
    out = str(tmp_path / "o")
    for command in ("map", "run"):
        assert _cli_line(capsys, [command, str(recording), "--out", out, "--t0", "0.5", "--t1",
                                  "0.2"]) == (
            f"evfuse {command}: error: empty time window [0.5, 0.2] s; expected --t0 < --t1")
        assert _cli_line(capsys, [command, str(recording), "--out", out, "--t0", "0.2", "--t1",
                                  "1.5"]) == (
            f"evfuse {command}: error: time window [0.2, 1.5] s reaches 0.601 s past the data "
            f"({data}); choose --t0/--t1 within [0.104660, 0.898594] s, or add --clip-window to "
            "map [0.200000, 0.898594] s")
    assert _cli_line(capsys, ["map", str(recording), "--out", out, "--t0", "0.2", "--t1", "0.3",
                              "--ref-time", "0.95"]) == (
        "evfuse map: error: the reference view at 0.950000 s has 0 events of the window "
        "[0.200000, 0.300000] s within 25 ms of it (at least 100 needed; "
        f"{data}); move --t0/--t1 (or --ref-time) to where the events are")
    assert _cli_line(capsys, ["map", str(recording), "--out", out, "--planes", "1000000"]) == (
        "evfuse map: error: a 64x48x1000000 DSI needs 11.4 GiB, more than the 8 GiB allowed: "
        "use fewer --planes")


def test_the_experiments_name_their_parameters(tmp_path, capsys):
    from fusion.experiments.bench import bench
    from fusion.experiments.reproduce import ReproduceParams

    assert _library_message(lambda: ReproduceParams(event_noise="bogus")) == (
        "event_noise 'bogus': expected ideal or realistic")
    assert _library_message(lambda: ReproduceParams(frame_sensor="davis")) == (
        "frame_sensor 'davis': expected one of ideal, davis240c_aps, machine_vision")
    assert _library_message(lambda: ReproduceParams(tables=("2",), scenes=("x",))) == (
        "scenes x: not among the scenes of tables 2 (slider_close, slider_far, "
        "slider_hdr_close, slider_hdr_far)")
    assert _library_message(lambda: bench([], ["complex"], ["exact"], tmp_path / "c")) == (
        "inputs exact: expected among emvs, oracle, oracle-edges, oracle-noisy, oracle-canny")
    assert _cli_line(capsys, ["reproduce", "--out", str(tmp_path / "r"), "--scenes", "x",
                              "--tables", "2"]) == (
        "evfuse reproduce: error: --scenes x: not among the scenes of --tables 2 (slider_close, "
        "slider_far, slider_hdr_close, slider_hdr_far)")
    assert not list(tmp_path.iterdir())


def test_a_frame_sensor_and_a_twin_name_their_parameters(recording, tmp_path, capsys):
    from scenes import resolve_scene
    from sim.frames import with_frame_sensor
    from sim.scene import load_scene
    from sim.twin import write_twin

    scene = load_scene(resolve_scene("poster_6dof"))
    assert _library_message(lambda: with_frame_sensor(scene, "davis")) == (
        "frame_sensor 'davis': expected one of ideal, davis240c_aps, machine_vision")
    assert with_frame_sensor(scene, "ideal").frames.ideal
    assert _library_message(lambda: write_twin(recording, tmp_path / "t", 880.0)) == (
        "depths are in metres: depth 880 looks like millimetres (0.88 m?); depths above 100 m "
        "are refused")
    assert _cli_line(capsys, ["twin", str(recording), "--out", str(tmp_path / "t"), "--depth",
                              "880"]) == (
        "evfuse twin: error: depths are in metres: --depth 880 looks like millimetres (0.88 m?); "
        "depths above 100 m are refused")
