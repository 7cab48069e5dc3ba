"""The ``evfuse`` command line: parses, validates and calls the public API, nothing more.

:func:`main` is the entry point; :func:`build_parser` gives its parser, every subcommand's flags,
without running anything. The commands live in one module per group, each with the parser
builder and the handler of its commands and an ``add_command`` that adds one to a parser:

- :mod:`sim.cli`: the simulator's (``scenes``, ``simulate``, ``events``, ``twin``, ``convert``,
  ``generate``, ``dataset``) and the parser pieces every command shares (the typed number flags,
  the one-line refusal parser, the help of ``--overwrite``);
- :mod:`fusion.cli_mapping`: ``map``, ``map-global``, ``fill``, ``run``, ``show``;
- :mod:`fusion.cli_experiments`: ``methods``, ``bench``, ``reproduce``;
- :mod:`fusion.cli_options`: the flags several of those share (map, fill, global map).

This module composes them and turns every failure into one line and an exit status.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Sequence

from fusion.cli_experiments import COMMANDS as EXPERIMENT_COMMANDS
from fusion.cli_experiments import add_command as add_experiment_command
from fusion.cli_mapping import COMMANDS as MAPPING_COMMANDS
from fusion.cli_mapping import add_command as add_mapping_command
from fusion.cli_options import VARIANT_FLAG_NAMES
from fusion.figures import write_event_frame
from sim.cli import OneLineParser
from sim.cli import add_command as add_sim_command
from sim.validation import (
    PLAUSIBLE_DEPTH_M,  # noqa: F401  (the bound of --min/--max-depth)
    ParameterError,
)

__all__ = ["COMMANDS", "build_parser", "main"]

COMMANDS = ("scenes", "methods", "bench", "simulate", "events", "twin", "map", "map-global",
            "fill", "run", "show", "reproduce", "convert", "generate", "dataset")
"""Every subcommand of ``evfuse``, in the order ``evfuse --help`` lists them."""


def build_parser() -> argparse.ArgumentParser:
    """The ``evfuse`` command line's parser, with every subcommand; nothing is run.

    Returns
    -------
    argparse.ArgumentParser
        ``parse_args(["simulate", "slider_close", "--duration", "0.5"])`` gives the namespace
        :func:`main` would run (its ``run`` default is the subcommand's handler); a refusal is
        one line on standard error and ``SystemExit(2)``.
    """
    from sim.output import evfuse_version

    parser = OneLineParser(
        prog="evfuse",
        description="Simulate event and standard cameras in ground-truthed scenes, and fuse them "
                    "into dense depth.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"evfuse {evfuse_version()}",
                        help="print evfuse's version and exit")
    sub = parser.add_subparsers(dest="command", required=True)
    # A forced Mitsuba variant is named --variant (simulate's flag; the other commands that render
    # take it from EVFUSE_VARIANT) by every command, as before; a command's own flag_names replace
    # this table (convert, which renders nothing).
    parser.set_defaults(flag_names=VARIANT_FLAG_NAMES)
    for name in COMMANDS:
        if name in MAPPING_COMMANDS:
            add_mapping_command(sub, name)
        elif name in EXPERIMENT_COMMANDS:
            add_experiment_command(sub, name)
        else:
            add_sim_command(sub, name, event_figure=write_event_frame)
    for command in sub.choices.values():         # --debug after the command works too
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help="show tracebacks on errors")
        # the flags a library error's parameters may be named by (see _in_flags)
        command.set_defaults(option_strings=frozenset(command._option_string_actions))
    return parser


_parser = build_parser
"""The old name of :func:`build_parser`, which tests still use."""


class _Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a job scheduler's time limit), taken down the path of Ctrl-C: files
    are closed, ``.partial`` outputs and checkpoints stay, and the user is told how to resume."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise _Terminated


def _interruption(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM behind ``exc``, if any: raised inside a Python callback of
    Mitsuba's renderer, it comes out wrapped in Dr.Jit's RuntimeError (as its ``__cause__``)."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


def _interrupted(args: argparse.Namespace, exc: KeyboardInterrupt) -> int:
    terminated = isinstance(exc, _Terminated)
    hint = getattr(args, "interrupted", "no complete output was written")
    print(f"evfuse {args.command}: {'terminated' if terminated else 'interrupted'}; {hint}",
          file=sys.stderr)
    return 143 if terminated else 130


def _quiet_opencv() -> None:
    """OpenCV's own warnings (``[ WARN:0@0.1] ... imread_(...)``) off: evfuse checks every image
    it reads and says what is wrong in its own one line."""
    import cv2

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def _stdout_is_closed() -> bool:
    """Whether standard output is a pipe whose reader has gone (``evfuse methods | head``); True
    where it cannot be told."""
    import select

    try:
        fd = sys.stdout.fileno()
        poller = select.poll()
    except (OSError, ValueError, AttributeError):
        return True
    poller.register(fd, select.POLLOUT)
    return any(event & (select.POLLERR | select.POLLHUP) for _, event in poller.poll(0))


def _quit_on_closed_stdout() -> int:
    """Exit quietly when the reader of standard output has gone, as Python's documentation of
    SIGPIPE recommends: the rest of the output goes to the null device (so that the flush at
    exit does not fail again), and the status is that of a process ended by SIGPIPE."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    finally:
        os.close(devnull)
    return 128 + signal.SIGPIPE if hasattr(signal, "SIGPIPE") else 1


def _in_flags(exc: Exception, args: argparse.Namespace) -> str:
    """A library error in the command line's terms: each parameter a
    :class:`sim.validation.ParameterError` names becomes the subcommand's flag of that name
    (``out`` -> ``--out``, ``overwrite`` -> ``--overwrite``), or the flag the subcommand maps it
    to (``args.flag_names``, set with ``set_defaults``); a parameter with no flag keeps the
    library's wording. Any other error is printed as it is."""
    if not isinstance(exc, ParameterError):
        return str(exc)
    options = getattr(args, "option_strings", ())
    names = {name: f"--{name.replace('_', '-')}" for name in exc.terms
             if f"--{name.replace('_', '-')}" in options}
    names.update(getattr(args, "flag_names", {}))
    return exc.rephrase(names)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``evfuse`` command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 on success, 2 for bad input (one line on standard error, no traceback
        unless ``--debug``), 1 for an unexpected error (also one line), 130 when interrupted
        (Ctrl-C) and 143 when terminated (SIGTERM), both with one line that says what is left,
        and 141 (SIGPIPE's), silently, when the reader of standard output has gone
        (``evfuse methods --params | head``).
    """
    _quiet_opencv()
    args = build_parser().parse_args(argv)
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_terminated) if in_main_thread else None
    try:
        code = args.run(args)
        sys.stdout.flush()                        # a closed pipe fails here, not at exit
        return code
    except BrokenPipeError as exc:
        if not _stdout_is_closed():
            if args.debug:
                raise
            print(f"evfuse {args.command}: error: {exc}", file=sys.stderr)
            return 2
        return _quit_on_closed_stdout()
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"evfuse {args.command}: error: {_in_flags(exc, args)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        return _interrupted(args, exc)
    except Exception as exc:                      # a bug or an unforeseen failure: still one line
        interruption = _interruption(exc)
        if interruption is not None:
            return _interrupted(args, interruption)
        if args.debug:
            raise
        print(f"evfuse {args.command}: unexpected error: {type(exc).__name__}: {exc} (run with "
              "--debug for the traceback)", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
