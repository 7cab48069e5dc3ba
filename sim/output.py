"""Where evfuse writes, and what it never touches: the one output policy of every command.

* An output is written into ``<out>.partial`` and renamed into place when complete
  (:func:`atomic_output_dir`), so an interrupted run leaves nothing that looks finished.
* Every folder evfuse writes holds :data:`MARKER`; ``overwrite`` replaces only such a folder, and
  only once the new one is complete.
* An output is never an input, inside one or around one (:func:`check_not_input`, real paths).
* A run stopped part-way resumes from its ``.partial`` (:func:`resumable_partial`) when it asks
  for what it asked before (:func:`resume_differences`).

Refusals are :class:`OutputError` (a :class:`sim.validation.ParameterError`), worded in the
library's parameters, which the command line renames to its flags. Single files are written
through :mod:`sim._atomic`.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Iterator
from collections.abc import Sequence as SequenceABC
from contextlib import contextmanager
from pathlib import Path

from sim._atomic import PARTIAL_SUFFIX  # re-exported: the suffix of all that is unfinished
from sim.validation import ParameterError

__all__ = ["MARKER", "PARTIAL_SUFFIX", "OutputError", "atomic_output_dir", "check_not_input",
           "check_output_dir", "check_output_file", "evfuse_version", "partial_dir",
           "resumable_partial", "resume_differences", "write_marker"]

_literal = ParameterError.literal

MARKER = ".evfuse"
"""The file evfuse writes into every output folder it creates (JSON: ``written_by``,
``command``, ``version``, ``inputs``): ``overwrite`` replaces only a folder that has
it, so that it never deletes a folder evfuse did not write."""


class OutputError(ParameterError):
    """An output path refused before any work (a :class:`sim.validation.ParameterError`: its
    message names the output parameter and ``overwrite`` / ``resume`` as placeholders, which the
    command line renames to its flags)."""


def _is_nonempty_dir(path: Path) -> bool:
    with os.scandir(path) as entries:
        return any(True for _ in entries)


def _holds_nothing(folder: Path) -> bool:
    """True if ``folder`` holds no file but :data:`MARKER` (empty folders aside)."""
    for _, _, files in os.walk(folder):
        if any(name != MARKER for name in files):
            return False
    return True


def _real(path: str | Path) -> Path:
    """``path`` with every symlink resolved, made absolute (existing or not)."""
    return Path(os.path.realpath(Path(path).expanduser()))


def check_not_input(out: str | Path, inputs: SequenceABC[str | Path] = (),
                    what: str = "output", parameter: str = "out") -> None:
    """Raise :class:`OutputError` if ``out`` is one of ``inputs``, contains one, or lies inside
    one, comparing real paths (symlinks resolved).

    Parameters
    ----------
    out : str or Path
        The output folder or file about to be written (it may not exist yet).
    inputs : sequence of str or Path
        Every file and folder the command reads (or a cache it reads and fills, which may not
        exist yet); None entries are skipped.
    what : str
        How the message names ``out`` (``output``, ``output folder``, ``output file``).
    parameter : str
        The caller's name for ``out`` (``out``; ``dst`` for a conversion), which the message
        names as a parameter (:class:`sim.validation.ParameterError`).
    """
    real_out = _real(out)
    for item in inputs:
        if item is None:
            continue
        real_in = _real(item)
        if real_in == real_out:
            relation = "is the input"
        elif real_out in real_in.parents:
            relation = "contains the input"
        elif real_in in real_out.parents:
            relation = "lies inside the input"
        else:
            continue
        shown = "" if str(real_out) == str(out) else f" ({real_out})"
        message = (f"{what} {out}{shown} {relation} {item}; evfuse never writes into, replaces "
                   "or deletes what it reads")
        raise OutputError(f"{_literal(message)}: choose another {{{parameter}}}",
                          **{parameter: "output path"})


def _check_marked(folder: Path, out: Path, overwrite: bool) -> None:
    """Raise :class:`OutputError` unless the non-empty ``folder`` (``out`` or its ``.partial``)
    may be replaced: ``overwrite`` and evfuse's marker in it."""
    if folder == out and not overwrite:
        raise OutputError(
            f"output folder {_literal(out)} exists and is not empty; choose another {{out}}, or "
            "add {overwrite} to replace a folder evfuse wrote",
            out="output folder", overwrite="overwrite=True")
    marker = folder / MARKER
    if not marker.is_file() or marker.is_symlink():
        what = "output folder" if folder == out else f"unfinished output of {out},"
        message = (f"{what} {folder} was not written by evfuse (it has no {MARKER} file; "
                   "folders written before evfuse marked its outputs have none either), so "
                   "evfuse does not replace it")
        raise OutputError(f"{_literal(message)}: choose another {{out}}, or delete it yourself",
                          out="output folder")


def check_output_dir(out: str | Path, overwrite: bool = False,
                     inputs: SequenceABC[str | Path] = ()) -> None:
    """Raise :class:`OutputError` (a ValueError) if :func:`atomic_output_dir` would refuse
    ``out``; call it early, before any work, to fail fast.

    Refused: ``out`` that is, contains or lies inside one of ``inputs`` (real paths,
    :func:`check_not_input`); an existing file or link; an existing non-empty folder without
    ``overwrite``, or without evfuse's :data:`MARKER` file (a folder evfuse did not write is
    never replaced); a non-empty ``<out>.partial`` without the marker (it would be deleted).
    """
    out = Path(out)
    if not out.name:
        raise OutputError(f"output path {_literal(repr(str(out)))} has no folder name")
    check_not_input(out, inputs, "output folder")
    partial = partial_dir(out)
    check_not_input(partial, inputs, "output folder (its unfinished copy)")
    if partial.is_dir() and not partial.is_symlink() and _is_nonempty_dir(partial):
        _check_marked(partial, out, True)
    if not out.exists() and not out.is_symlink():
        return
    if not out.is_dir() or out.is_symlink():
        raise OutputError(f"output {_literal(out)} exists and is not a folder (a file or a link); "
                          "expected a folder or a new path (anything else is never replaced)")
    if _is_nonempty_dir(out):
        _check_marked(out, out, overwrite)


def _flatten(value: object, prefix: str = "") -> dict:
    """``{"a": {"b": 1}}`` as ``{"a.b": 1}``."""
    if not isinstance(value, dict):
        return {prefix: value}
    flat: dict = {}
    for key, item in value.items():
        flat.update(_flatten(item, f"{prefix}.{key}" if prefix else str(key)))
    return flat


def resume_differences(saved: dict, current: dict, skip: tuple[str, ...] = (),
                       saved_as: str = "in the checkpoint") -> list[str]:
    """What differs between the identity an interrupted run saved and this run's: ``key (saved
    value SAVED_AS, current value now)`` for every dotted key (nested dicts flattened) whose
    values differ, keys whose first part is in ``skip`` aside."""
    old, new = _flatten(saved), _flatten(current)
    missing = "(none)"
    return [f"{key} ({str(old.get(key, missing))[:40]} {saved_as}, "
            f"{str(new.get(key, missing))[:40]} now)"
            for key in sorted(set(old) | set(new))
            if key.split(".")[0] not in skip and old.get(key, missing) != new.get(key, missing)]


def resumable_partial(out: str | Path, overwrite: bool, inputs: SequenceABC[str | Path] = (),
                      needs: str | None = None) -> Path:
    """The ``<out>.partial`` an interrupted run left, for a run that resumes it; checked as
    :func:`check_output_dir` checks ``out``.

    Parameters
    ----------
    out : str or Path
        The output folder of the interrupted run.
    overwrite : bool
        Whether the resumed run may replace a complete ``out`` (else a complete one is refused:
        there is nothing to resume).
    inputs : sequence of str or Path
        What the run reads (never an output).
    needs : str, optional
        A file or folder inside ``<out>.partial`` that an interrupted run of this kind leaves
        (checked when given; the folder itself always is).

    Raises
    ------
    OutputError
        A complete ``out`` without ``overwrite``, an ``out`` :func:`check_output_dir` refuses,
        or no ``<out>.partial`` (or no ``needs`` in it) to resume.
    """
    out = Path(out)
    if out.is_dir() and not out.is_symlink() and any(out.iterdir()) and not overwrite:
        raise OutputError(
            f"output folder {_literal(out)} is already complete; there is nothing to resume "
            "(add {overwrite} to continue an interrupted run that replaces it)",
            overwrite="overwrite=True")
    check_output_dir(out, overwrite, inputs)
    partial = partial_dir(out)
    if not partial.is_dir() or (needs is not None and not (partial / needs).exists()):
        what = (f"{partial} does not exist" if not partial.is_dir()
                else f"{partial} has no {needs}")
        raise OutputError(f"there is no interrupted run of {_literal(out)} to resume "
                          f"({_literal(what)}); run without {{resume}} to start one",
                          resume="resume=True")
    return partial


def check_output_file(out: str | Path, inputs: SequenceABC[str | Path] = (),
                      parameter: str = "out") -> None:
    """Raise :class:`OutputError` if the file ``out`` would be written into, over or around one
    of ``inputs`` (:func:`check_not_input`; ``parameter`` is the caller's name for ``out``), or
    is an existing folder."""
    check_not_input(out, inputs, "output file", parameter)
    if Path(out).is_dir():
        raise OutputError(f"output file {_literal(out)} is an existing folder; expected a file "
                          "path")



def evfuse_version() -> str:
    """evfuse's version: the installed package's (its metadata), else that of the source tree
    this package was imported from (its ``pyproject.toml``, said so), else ``unknown``."""
    from importlib import metadata

    try:
        return metadata.version("evfuse")
    except metadata.PackageNotFoundError:
        pass
    import tomllib

    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    try:
        with pyproject.open("rb") as handle:
            project = tomllib.load(handle)["project"]
        if project["name"] == "evfuse":
            return f"{project['version']} (source tree {pyproject.parent}, not installed)"
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return "unknown (not installed, and no pyproject.toml of evfuse beside the source)"


def _marker_path(path: str | Path, folder: str | Path) -> str:
    """An input's path as a marker records it: its real path, or, for an input inside the same
    unfinished output as ``folder`` (``run``'s ``map/`` reads ``<out>.partial/sequence``), its
    path relative to ``folder``, which stays true once ``<out>.partial`` is renamed to ``<out>``."""
    real, here = _real(path), _real(folder)
    for ancestor in here.parents:
        if ancestor.name.endswith(PARTIAL_SUFFIX) and real.is_relative_to(ancestor):
            return os.path.relpath(real, here)
    return str(real)


def write_marker(folder: str | Path, command: str = "",
                 inputs: SequenceABC[str | Path] = ()) -> Path:
    """Write evfuse's :data:`MARKER` into ``folder``: JSON with ``written_by`` ("evfuse"),
    ``command`` (which writer), ``version`` (evfuse's) and ``inputs`` (their real paths; one
    inside the same unfinished output, relative to ``folder``). No
    time (the file's own is there): the same command writes the same bytes, so that a resumed
    or repeated simulation stays identical to an uninterrupted one."""
    path = Path(folder) / MARKER
    document = {"written_by": "evfuse", "command": command, "version": evfuse_version(),
                "inputs": [_marker_path(p, folder) for p in inputs if p is not None]}
    path.write_text(json.dumps(document, indent=1) + "\n")
    return path


def partial_dir(out: str | Path) -> Path:
    """The folder :func:`atomic_output_dir` writes ``out`` into: ``<out>.partial``."""
    out = Path(out)
    return out.with_name(out.name + PARTIAL_SUFFIX)


@contextmanager
def atomic_output_dir(out: str | Path, overwrite: bool = False, *,
                      resume: bool = False, inputs: SequenceABC[str | Path] = (),
                      command: str = "", keep_failed: bool = False) -> Iterator[Path]:
    """Write a folder under a temporary name and rename it into place when complete.

    Parameters
    ----------
    out : str or Path
        The folder to create. Its parents are created if needed.
    overwrite : bool
        Replace an existing non-empty ``out`` that evfuse wrote (it holds :data:`MARKER`); a
        folder without the marker is never replaced. The old folder is removed only once the
        new one is complete: it is renamed aside, the new one renamed in, then the old one
        deleted. An existing empty folder is replaced without ``overwrite``.
    resume : bool
        Keep the ``.partial`` folder an earlier, interrupted run left, with its contents, for
        the body to continue (it is created if there is none). The body must check that what
        it holds is what it expects.
    inputs : sequence of str or Path
        Every file and folder the writer reads: ``out`` must not be, contain or lie inside
        one (:func:`check_output_dir`). Recorded in the marker.
    command : str
        The writer, recorded in the marker (e.g. ``"evfuse map"``).
    keep_failed : bool
        Leave the ``.partial`` folder when the body raises (a writer that can resume from
        it); by default it is removed, so that a failed or interrupted writer leaves nothing.

    Yields
    ------
    Path
        The folder ``<out.parent>/<out.name>.partial`` to write into, holding the marker: fresh
        (a stale one from an earlier failed run, marked, is removed first) unless ``resume``.

    Raises
    ------
    OutputError
        The refusals of :func:`check_output_dir` (checked on entry, and again before the
        rename).

    Notes
    -----
    If the body raises, ``out`` is untouched and the exception propagates; the ``.partial``
    folder is removed unless ``keep_failed`` (its name cannot be mistaken for a complete
    result). ``out`` itself is never seen half-written.
    """
    out = Path(out)
    check_output_dir(out, overwrite, inputs)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = partial_dir(out)
    if partial.is_symlink() or partial.is_file():
        partial.unlink()
    elif partial.exists() and not resume:
        shutil.rmtree(partial)
    partial.mkdir(exist_ok=resume)
    try:
        write_marker(partial, command, inputs)
        yield partial
    except BaseException:
        if not keep_failed or _holds_nothing(partial):
            shutil.rmtree(partial, ignore_errors=True)
        raise
    check_output_dir(out, overwrite, inputs)
    old = None
    if out.exists():
        old = out.with_name(f"{out.name}.old-{uuid.uuid4().hex[:12]}")
        out.rename(old)
    try:
        partial.rename(out)
    except BaseException:
        if old is not None:
            old.rename(out)
        raise
    if old is not None:
        shutil.rmtree(old)
