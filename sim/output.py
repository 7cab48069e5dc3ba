"""Where evfuse writes, and what it never touches: the one output policy of every command.

* An output is written into ``<out>.partial`` and renamed into place when complete
  (:func:`atomic_output_dir`), so an interrupted run leaves nothing that looks finished.
* Every folder evfuse writes holds :data:`MARKER`; ``overwrite`` replaces only such a folder, and
  only once the new one is complete.
* An output is never an input, inside one or around one (:func:`check_not_input`, real paths).
* A run stopped part-way resumes from its ``.partial`` (:func:`resumable_partial`) when it asks
  for what it asked before (:func:`resume_differences`).
* One writer per output: a writer claims ``<out>.partial`` atomically (:data:`CLAIM`: its pid,
  host, command and start time); a second writer is refused, naming the first, until the first's
  process is gone (a stale claim, which ``resume`` takes over).
* What the final rename needs is checked first: ``out`` is no mount point, neither the current
  folder nor one of its ancestors, and its parent is writable.
* Only a ``.partial`` evfuse marked is evfuse's to delete or resume; the marker of a complete
  output lists the files evfuse wrote (``files``), and ``overwrite`` refuses a folder holding
  others.

Refusals are :class:`OutputError` (a :class:`sim.validation.ParameterError`), worded in the
library's parameters, which the command line renames to its flags. Single files are written
through :mod:`sim._atomic`.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import socket
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from collections.abc import Sequence as SequenceABC
from contextlib import contextmanager
from pathlib import Path

from sim._atomic import PARTIAL_SUFFIX  # re-exported: the suffix of all that is unfinished
from sim.validation import ParameterError

__all__ = ["CLAIM", "MARKER", "PARTIAL_SUFFIX", "OutputError", "add_written_files",
           "atomic_output_dir", "check_cache_dir", "check_not_input", "check_output_dir",
           "check_output_file", "claim_folder", "close_cache_dir", "evfuse_version",
           "list_written_files", "open_cache_dir", "partial_dir", "release_claim",
           "resumable_partial", "resume_differences", "swap_in", "write_marker"]

_literal = ParameterError.literal

MARKER = ".evfuse"
"""The file evfuse writes into every output folder it creates (JSON: ``written_by``,
``command``, ``version``, ``inputs``): ``overwrite`` replaces only a folder that has
it, so that it never deletes a folder evfuse did not write."""


CLAIM = ".evfuse-claim"
"""The file a writer creates in the folder it is writing (``<out>.partial``, or a dataset folder
``generate`` fills in place) before any work: JSON with ``pid``, ``host``, ``command`` (the
writer), ``argv`` (its command line), ``started`` (UTC) and ``token`` (which of a process's
claims). A second writer of the same output is refused while the claim's process runs;
a claim whose process is gone (same host, no such pid) is stale. Removed once the output is
complete; never listed in the marker's ``files``."""


class OutputError(ParameterError):
    """An output path refused before any work (a :class:`sim.validation.ParameterError`: its
    message names the output parameter and ``overwrite`` / ``resume`` as placeholders, which the
    command line renames to its flags)."""


def _is_nonempty_dir(path: Path) -> bool:
    with os.scandir(path) as entries:
        return any(True for _ in entries)


def _holds_nothing(folder: Path) -> bool:
    """True if ``folder`` holds no file but :data:`MARKER` and :data:`CLAIM` (empty folders
    aside)."""
    for _, _, files in os.walk(folder):
        if any(name not in (MARKER, CLAIM) for name in files):
            return False
    return True


def _written_files(folder: Path) -> list[str]:
    """Every file (and link) under ``folder``, relative, ``/``-separated and sorted, but its own
    :data:`MARKER` and :data:`CLAIM`."""
    found = []
    for root, dirs, files in os.walk(folder):
        here = Path(root).relative_to(folder)
        names = list(files) + [d for d in dirs if (Path(root) / d).is_symlink()]
        for name in names:
            relative = (here / name).as_posix()
            if relative not in (MARKER, CLAIM):
                found.append(relative)
    return sorted(found)


_HELD = threading.local()
"""``tokens``: the claims this thread holds (two writers in two threads of one process are two
writers; one thread writes one output at a time)."""


def _held() -> set[str]:
    if not hasattr(_HELD, "tokens"):
        _HELD.tokens = set()
    return _HELD.tokens


def _own(claim: dict | None) -> bool:
    return claim is not None and claim.get("token") in _held()


def _claim_alive(claim: dict) -> bool | None:
    """Whether a claim's process still runs: True / False on this host, None on another (it
    cannot be told from here)."""
    if claim.get("host") != socket.gethostname():
        return None
    try:
        pid = int(claim["pid"])
    except (KeyError, TypeError, ValueError):
        return False
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _read_claim(folder: Path) -> dict | None:
    """The claim in ``folder``, or None if it has none (an unreadable claim counts as a dead
    process's: its writer died while writing it)."""
    path = folder / CLAIM
    if not path.is_file() or path.is_symlink():
        return None
    try:
        claim = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return claim if isinstance(claim, dict) else {}


def _describe_claim(claim: dict) -> str:
    argv = str(claim.get("argv", ""))
    argv = argv if len(argv) <= 160 else argv[:157] + "..."
    return (f"{claim.get('command') or 'an evfuse command'} (pid {claim.get('pid', '?')} on "
            f"{claim.get('host', '?')}, started {claim.get('started', '?')}"
            f"{': ' + argv if argv else ''})")


def _check_claim(folder: Path, out: Path) -> None:
    """Raise :class:`OutputError` if another writer's claim in ``folder`` is alive, or cannot be
    told (another host)."""
    claim = _read_claim(folder)
    if claim is None or _own(claim):
        return
    alive = _claim_alive(claim)
    if alive is False:
        return
    if alive:
        message = (f"output folder {out} is being written by {_describe_claim(claim)}; "
                   "one writer per output")
        raise OutputError(f"{_literal(message)}: wait for it to finish, or choose another "
                          "{out}", out="output folder")
    message = (f"output folder {out} is claimed by {_describe_claim(claim)}, on another host "
               f"where evfuse cannot tell whether it still runs")
    raise OutputError(f"{_literal(message)}: if it does not, delete {_literal(folder / CLAIM)} "
                      "yourself; else choose another {out}", out="output folder")


def _command_line() -> str:
    """This process's command line, ``evfuse ...`` for evfuse's own (the script or ``python -m
    fusion.cli``)."""
    argv = list(sys.argv) or [""]
    if Path(argv[0]).name in ("evfuse", "cli.py", "__main__.py"):
        argv[0] = "evfuse"
    return shlex.join(argv)


def _claim_document(command: str) -> dict:
    return {"pid": os.getpid(), "host": socket.gethostname(), "command": command,
            "argv": _command_line()[:500],
            "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "token": uuid.uuid4().hex}


def claim_folder(folder: str | Path, out: str | Path, command: str = "") -> Path:
    """Claim the existing ``folder`` (``<out>.partial``, or a folder written in place) for this
    process: create :data:`CLAIM` in it atomically (``O_EXCL``), taking over a stale claim.

    Raises
    ------
    OutputError
        Another writer's claim is alive (:func:`_check_claim`), or it won the race for a stale
        one.
    """
    folder = Path(folder)
    _check_claim(folder, Path(out))
    path = folder / CLAIM
    claim = _read_claim(folder)
    if _own(claim):
        return path
    if claim is not None:                       # stale: move it aside, then claim afresh
        aside = folder / f"{CLAIM}.stale-{uuid.uuid4().hex[:12]}"
        try:
            os.rename(path, aside)
            os.unlink(aside)
        except FileNotFoundError:
            pass
    try:
        handle = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        _check_claim(folder, Path(out))
        message = f"output folder {out} was claimed by another writer at the same moment"
        raise OutputError(f"{_literal(message)}: one writer per output; choose another {{out}}",
                          out="output folder") from None
    document = _claim_document(command)
    with os.fdopen(handle, "w") as stream:
        stream.write(json.dumps(document, indent=1) + "\n")
    _held().add(document["token"])
    return path


def release_claim(folder: str | Path) -> None:
    """Remove this process's :data:`CLAIM` from ``folder`` (another's is left)."""
    claim = _read_claim(Path(folder))
    if _own(claim):
        (Path(folder) / CLAIM).unlink(missing_ok=True)
        _held().discard(claim["token"])


def _check_swap(out: Path) -> None:
    """Raise :class:`OutputError` if the final rename of ``<out>.partial`` to ``out`` could not
    happen: ``out`` a mount point, the current folder or one of its ancestors; its parent (the
    nearest existing one) not writable."""
    real = _real(out)
    if out.is_dir() and not out.is_symlink() and (os.path.ismount(out) or
                                                   real.parent.exists() and
                                                   os.stat(real).st_dev !=
                                                   os.stat(real.parent).st_dev):
        message = (f"output folder {out} is a mount point; a finished output is renamed into "
                   "place, which cannot replace a mount point")
        raise OutputError(f"{_literal(message)}: choose a folder inside it as {{out}}",
                          out="output folder")
    try:
        here = Path(os.getcwd()).resolve()
    except OSError:
        here = None
    if here is not None and (here == real or real in here.parents):
        what = "is the current folder" if here == real else "contains the current folder"
        message = (f"output folder {out} ({real}) {what}; a finished output is renamed into "
                   "place, which cannot replace the folder a command runs in")
        raise OutputError(f"{_literal(message)}: choose another {{out}}, or run from elsewhere",
                          out="output folder")
    parent = real.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not os.access(parent, os.W_OK | os.X_OK):
        message = f"cannot write into {parent}, the folder that would hold output {out}"
        raise OutputError(f"{_literal(message)}: choose another {{out}}", out="output folder")


def _check_partial(partial: Path, out: Path) -> None:
    """Raise :class:`OutputError` unless ``<out>.partial`` is absent, an empty folder, or
    evfuse's (it holds :data:`MARKER` or :data:`CLAIM`), and no live writer claims it."""
    if not partial.exists() and not partial.is_symlink():
        return
    if partial.is_symlink() or not partial.is_dir():
        message = (f"{partial}, the name evfuse writes output {out} under until it is complete, "
                   "is a file or a link evfuse did not write, so evfuse does not delete it")
        raise OutputError(f"{_literal(message)}: choose another {{out}}, or move it yourself",
                          out="output folder")
    if not _is_nonempty_dir(partial):
        return
    marked = any((partial / name).is_file() and not (partial / name).is_symlink()
                 for name in (MARKER, CLAIM))
    if not marked:
        _check_marked(partial, out, True)
    _check_claim(partial, out)


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
    if folder == out:
        _check_unlisted(out)


def _check_unlisted(out: Path) -> None:
    """Raise :class:`OutputError` if the complete ``out`` holds files its marker's ``files`` do
    not list (a user's additions, which ``overwrite`` would delete). A marker without ``files``
    (written before evfuse listed them, or by a writer still at work) is accepted as before."""
    try:
        listed = json.loads((out / MARKER).read_text()).get("files")
    except (OSError, ValueError, AttributeError):
        listed = None
    if not isinstance(listed, list):
        return
    extra = sorted(set(_written_files(out)) - {str(name) for name in listed})
    if extra:
        shown = ", ".join(extra[:5]) + (f" and {len(extra) - 5} more" if len(extra) > 5 else "")
        message = (f"output folder {out} holds {len(extra)} file{'s' * (len(extra) > 1)} evfuse "
                   f"did not write ({shown}), which replacing it would delete")
        raise OutputError(f"{_literal(message)}: move them out first, or choose another {{out}}",
                          out="output folder")


def check_output_dir(out: str | Path, overwrite: bool = False,
                     inputs: SequenceABC[str | Path] = ()) -> None:
    """Raise :class:`OutputError` (a ValueError) if :func:`atomic_output_dir` would refuse
    ``out``; call it early, before any work, to fail fast.

    Refused: ``out`` that is, contains or lies inside one of ``inputs`` (real paths,
    :func:`check_not_input`); an existing file or link; an existing non-empty folder without
    ``overwrite``, or without evfuse's :data:`MARKER` file (a folder evfuse did not write is
    never replaced), or holding files its marker does not list; a ``<out>.partial`` that is a
    file, a link, or a non-empty folder without evfuse's marker or claim (it would be deleted);
    an output another live writer claims (:data:`CLAIM`, in ``<out>.partial`` or ``out``); an
    ``out`` the final rename could not replace (a mount point, the current folder or an
    ancestor of it, a parent not writable).
    """
    out = Path(out)
    if out.name in ("", ".", ".."):              # `.`, `..`: named by where they lead
        out = Path(os.path.abspath(out))
    if not out.name:
        raise OutputError(f"output path {_literal(repr(str(out)))} has no folder name")
    check_not_input(out, inputs, "output folder")
    partial = partial_dir(out)
    check_not_input(partial, inputs, "output folder (its unfinished copy)")
    _check_swap(out)
    _check_partial(partial, out)
    if out.is_dir() and not out.is_symlink():
        _check_claim(out, out)
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



def check_cache_dir(cache: str | Path, inputs: SequenceABC[str | Path] = (),
                    parameter: str = "cache") -> None:
    """Raise :class:`OutputError` if the cache folder ``cache`` (a folder a command fills and
    reads again) would be written into, over or around one of ``inputs``
    (:func:`check_not_input`), or is an existing file or link; call it before any work, and
    create the cache with :func:`open_cache_dir` only once everything is validated."""
    check_not_input(cache, inputs, "cache folder", parameter)
    cache = Path(cache)
    if cache.is_symlink() or cache.exists() and not cache.is_dir():
        raise OutputError(f"cache folder {_literal(cache)} exists and is not a folder (a file "
                          f"or a link); choose another {{{parameter}}}",
                          **{parameter: "cache folder"})


def open_cache_dir(cache: str | Path, command: str = "") -> bool:
    """Create the cache folder ``cache`` (checked by :func:`check_cache_dir`) with evfuse's
    :data:`MARKER` if it has none; return whether this call created it (so that a command
    refused later removes it again, :func:`close_cache_dir`)."""
    cache = Path(cache)
    created = not cache.exists()
    cache.mkdir(parents=True, exist_ok=True)
    if not (cache / MARKER).exists():
        write_marker(cache, command)
    return created


def close_cache_dir(cache: str | Path, created: bool) -> None:
    """After a failed command: remove the cache folder it ``created`` if nothing but the marker
    was written into it."""
    cache = Path(cache)
    if created and cache.is_dir() and _holds_nothing(cache):
        shutil.rmtree(cache, ignore_errors=True)


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
                 inputs: SequenceABC[str | Path] = (), files: bool = False) -> Path:
    """Write evfuse's :data:`MARKER` into ``folder``: JSON with ``written_by`` ("evfuse"),
    ``command`` (which writer), ``version`` (evfuse's), ``inputs`` (their real paths; one
    inside the same unfinished output, relative to ``folder``) and, with ``files`` (once the
    output is complete), ``files``: every file now in ``folder`` (relative paths, sorted; the
    marker and :data:`CLAIM` aside), which ``overwrite`` compares with what the folder holds. No
    time (the file's own is there): the same command writes the same bytes, so that a resumed
    or repeated simulation stays identical to an uninterrupted one."""
    path = Path(folder) / MARKER
    document = {"written_by": "evfuse", "command": command, "version": evfuse_version(),
                "inputs": [_marker_path(p, folder) for p in inputs if p is not None]}
    if files:
        document["files"] = _written_files(Path(folder))
    path.write_text(json.dumps(document, indent=1) + "\n")
    return path


def list_written_files(folder: str | Path) -> Path:
    """Add ``files`` (:func:`write_marker`) to the marker already in the complete ``folder``,
    keeping what it says."""
    path = Path(folder) / MARKER
    document = json.loads(path.read_text())
    document["files"] = _written_files(Path(folder))
    path.write_text(json.dumps(document, indent=1) + "\n")
    return path


def add_written_files(folder: str | Path, names: SequenceABC[str]) -> None:
    """Add ``names`` (relative paths) to the ``files`` of the marker in the complete ``folder``,
    for a command that writes into an output evfuse completed (``evfuse dataset``'s card); a
    marker without ``files`` is left as it is."""
    path = Path(folder) / MARKER
    try:
        document = json.loads(path.read_text())
    except (OSError, ValueError):
        return
    if isinstance(document, dict) and isinstance(document.get("files"), list):
        document["files"] = sorted(set(document["files"]) | set(names))
        path.write_text(json.dumps(document, indent=1) + "\n")


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
    partial = _claim_partial(out, resume, command)
    try:
        write_marker(partial, command, inputs)
        yield partial
    except BaseException:
        if not keep_failed or _holds_nothing(partial):
            shutil.rmtree(partial, ignore_errors=True)
        else:
            release_claim(partial)
        raise
    try:
        check_output_dir(out, overwrite, inputs)
        write_marker(partial, command, inputs, files=True)
    except BaseException:
        if keep_failed:
            release_claim(partial)
        else:
            shutil.rmtree(partial, ignore_errors=True)
        raise
    swap_in(partial, out)


def _claim_partial(out: Path, resume: bool, command: str) -> Path:
    """Create (or, with ``resume``, take over) ``<out>.partial`` holding this process's
    :data:`CLAIM`: a fresh one is made under a unique name with its claim inside, then renamed to
    ``<out>.partial`` (atomic: of two writers, one rename fails). An earlier run's marked,
    unclaimed (or stale) ``.partial`` is removed first, unless ``resume``."""
    partial = partial_dir(out)
    if partial.is_dir() and not partial.is_symlink() and _is_nonempty_dir(partial):
        if resume:
            claim_folder(partial, out, command)
            return partial
        _check_claim(partial, out)              # stale, or none: evfuse's, to start afresh
        shutil.rmtree(partial)
    fresh = out.with_name(f"{out.name}{PARTIAL_SUFFIX}.new-{uuid.uuid4().hex[:12]}")
    fresh.mkdir()
    try:
        claim_folder(fresh, out, command)
        os.rename(fresh, partial)               # replaces an empty folder only
    except OSError:
        shutil.rmtree(fresh, ignore_errors=True)
        if partial.is_dir():
            _check_claim(partial, out)
        message = f"output folder {out} was claimed by another writer at the same moment"
        raise OutputError(f"{_literal(message)}: one writer per output; choose another {{out}}",
                          out="output folder") from None
    return partial


def swap_in(partial: Path, out: Path) -> None:
    """Rename the complete ``partial`` to ``out`` (an existing ``out`` renamed aside first and
    deleted after, so that ``out`` is the old or the new folder at every moment), then drop
    this thread's claim (:func:`claim_folder`)."""
    old = None
    if out.exists():
        old = out.with_name(f"{out.name}.old-{uuid.uuid4().hex[:12]}")
        out.rename(old)
    try:
        partial.rename(out)
    except BaseException:
        if old is not None:
            old.rename(out)
        release_claim(partial)
        raise
    release_claim(out)
    if old is not None:
        shutil.rmtree(old)
