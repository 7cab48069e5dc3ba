"""Inputs refused up front (issue 39): seeds beyond what Mitsuba takes, sizes beyond memory,
image outputs that would replace a user's file, a hand-written dataset card, a twin that
simulate would refuse, a byte-order mark in a message. Each is one line, before any work."""

from __future__ import annotations

import pytest

from sim.validation import MAX_SEED
from tests.conftest import WALL, run_cli, scene_text

SWEEP = """seeds = {seeds}

[[scenes]]
name = "slider_close"

[grid]
sensor = "48x36"
t1 = 0.05
"""


def _one_line(capsys, code, command: str) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"evfuse {command}: error: "), err
    return lines[0].removeprefix(f"evfuse {command}: error: ")


# --- 6. seeds: Mitsuba's render seed is an unsigned 32-bit integer -------------------------------

def test_the_largest_seed_is_two_to_the_32_minus_one():
    assert MAX_SEED == 2**32 - 1


@pytest.mark.parametrize("command", ["simulate", "run"])
def test_a_seed_beyond_32_bits_is_refused_naming_the_flag(command, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        run_cli([command, "slider_close", "--out", str(tmp_path / "o"), "--seed", "4294967296"])
    assert _one_line(capsys, stop.value.code, command) == (
        "argument --seed: expected an integer in 0..4294967295, got '4294967296'")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("seeds, key", [
    ("[1, 4294967296]", "seeds[1]"),
    ("{ first = 4294967290, count = 7 }", "seeds"),
])
def test_a_sweep_seed_beyond_32_bits_is_refused_naming_the_key(seeds, key, tmp_path, capsys):
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(SWEEP.format(seeds=seeds))
    out = tmp_path / "d"
    line = _one_line(capsys, run_cli(["generate", str(sweep), "--out", str(out)]), "generate")
    assert f"{sweep}: {key}" in line and "0..4294967295" in line, line
    assert not out.exists() and not (tmp_path / "d.partial").exists()


def test_a_sweep_whose_last_seed_is_the_largest_is_taken(tmp_path):
    from sim.dataset import load_sweep

    sweep = tmp_path / "sweep.toml"
    sweep.write_text(SWEEP.format(seeds="{ first = 4294967290, count = 6 }"))
    assert [job.seed for job in load_sweep(sweep).jobs][-1] == MAX_SEED


@pytest.mark.parametrize("extra, key", [
    ("", "wall.toml: seed"),
    ("[render]\nseed = 4294967296\n", "[render].seed"),
])
def test_a_scene_file_seed_beyond_32_bits_is_refused_naming_the_key(extra, key, tmp_path):
    from sim.scene import SceneError, parse_scene

    text = scene_text(WALL, extra=extra)
    if not extra:
        text = text.replace("seed = 3", "seed = 4294967296")
    with pytest.raises(SceneError) as info:
        parse_scene(text, "wall.toml")
    assert "0..4294967295" in str(info.value) and key in str(info.value), str(info.value)
    assert "\n" not in str(info.value)
