"""``fusion.cli.build_parser``: the whole ``evfuse`` parser, built without running anything
(issue 35), composed from one module per command group."""

from __future__ import annotations

import argparse

import pytest

from fusion import cli_experiments, cli_mapping
from fusion.cli import COMMANDS, build_parser
from sim import cli as sim_cli


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def test_every_group_s_commands_once_in_the_help_s_order():
    """Each subcommand comes from exactly one group module, and the parser lists them in
    :data:`fusion.cli.COMMANDS`' order (that of ``evfuse --help`` before the split)."""
    groups = [sim_cli.COMMANDS, cli_mapping.COMMANDS, cli_experiments.COMMANDS]
    owned = [name for group in groups for name in group]
    assert sorted(owned) == sorted(COMMANDS) and len(set(owned)) == len(owned) == 15
    assert tuple(_subcommands(build_parser())) == COMMANDS
    assert COMMANDS[:3] == ("scenes", "methods", "bench") and COMMANDS[-1] == "dataset"


def test_a_documented_command_line_parses_without_running(tmp_path):
    """``parse_args`` gives the flags' values and the handler, and runs nothing: no output
    folder appears."""
    out = tmp_path / "seq"
    args = build_parser().parse_args(["simulate", "slider_close", "--duration", "0.5", "--out",
                                      str(out)])
    assert (args.command, args.scene, args.duration, args.out) == ("simulate", "slider_close",
                                                                   0.5, str(out))
    assert callable(args.run)
    args = build_parser().parse_args(["map", "SEQ", "--out", str(tmp_path / "m"), "--planes",
                                      "50", "--debug"])
    assert (args.sequence, args.planes, args.debug) == ("SEQ", 50, True)
    assert args.flag_names["oracle"] == "--depth-range oracle"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [["simulate", "slider_close", "--no-such-flag"],
                                  ["fill", "--out", "F", "--ring", "0"]])
def test_a_flag_the_parser_lacks_or_refuses_exits_2(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(argv)
    assert exit_.value.code == 2
    assert capsys.readouterr().err.startswith(f"evfuse {argv[0]}: error: ")


def test_unknown_group_command_is_refused():
    sub = argparse.ArgumentParser().add_subparsers()
    for add in (cli_mapping.add_command, cli_experiments.add_command):
        with pytest.raises(ValueError, match="is not one of"):
            add(sub, "simulate")


@pytest.mark.parametrize("flags,reject,fuse_depth", [
    ([], "outvoted", False), (["--reject", "unconfirmed", "--fuse-depth"], "unconfirmed", True)])
def test_map_global_s_flags_give_the_global_map_s_fusion_and_tsdf(flags, reject, fuse_depth):
    """map-global's defaults are GlobalParams' (outvoted points dropped, the TSDF's search
    radius), not FusionParams' and TSDFParams' own; --reject and --voxel replace only theirs."""
    from fusion.globalmap import GlobalParams
    from fusion.globalmap.tsdf import GLOBAL_SEARCH_RADIUS

    args = build_parser().parse_args(["map-global", "SEQ", "--out", "G", "--voxel", "0.01",
                                      *flags])
    params = cli_mapping._global_params(args, cli_mapping._fill_method(args))
    assert params.fusion.reject == reject and params.fusion.fuse_depth is fuse_depth
    assert params.fusion.voxel_size == params.tsdf.voxel_size == 0.01
    assert params.tsdf.search_radius == GLOBAL_SEARCH_RADIUS == GlobalParams().tsdf.search_radius
    with pytest.raises(SystemExit):
        build_parser().parse_args(["map-global", "SEQ", "--out", "G", "--reject", "all"])


def test_map_global_fills_with_the_global_map_s_default_method_and_fill_with_the_paper_s():
    """map-global and run --global default to GLOBAL_FILL_METHOD (their --help says so); fill
    and run to the paper's; --method or --weighting names another."""
    from fusion.globalmap import GLOBAL_FILL_METHOD, GlobalParams

    assert GlobalParams().method == GLOBAL_FILL_METHOD == "paper-colorization"

    def resolved(argv, global_map):
        args = build_parser().parse_args(argv)
        pick = cli_mapping._global_fill_method if global_map else cli_mapping._fill_method
        return pick(args).method.name

    base = ["map-global", "SEQ", "--out", "G"]
    assert resolved(base, True) == GLOBAL_FILL_METHOD
    assert resolved([*base, "--method", "paper-idw"], True) == "paper-idw"
    assert resolved([*base, "--weighting", "gaussian"], True) == "paper-gaussian"
    assert resolved(["fill", "M", "--out", "F"], False) == "paper-idw"
    assert resolved(["run", "S", "--out", "R", "--global"], True) == GLOBAL_FILL_METHOD
    assert resolved(["run", "S", "--out", "R"], False) == "paper-idw"
    for command, default in (("map-global", GLOBAL_FILL_METHOD), ("fill", "paper-idw")):
        action = next(a for a in _subcommands(build_parser())[command]._actions
                      if "--method" in a.option_strings)
        assert action.help.split("(default ")[1].startswith(default)
