"""Progress reporting for the whole project: a bar on a terminal, one line per stage elsewhere.

Every long loop in evfuse (rendering frames, simulating events, mapping, reproducing tables)
reports through :func:`progress`, so that the choice is made in one place:

- standard error is a terminal: a tqdm bar, redrawn in place;
- standard error is a file or a pipe (a log, a job scheduler, a test): no carriage returns, no
  redraws, one line when the stage ends, e.g. ``simulate slider_close: 23 frames in 12.3 s``;
- ``enabled=False`` (``--quiet``): nothing at all.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any, TextIO

__all__ = ["StageLine", "progress", "stderr_is_terminal"]


def stderr_is_terminal(stream: TextIO | None = None) -> bool:
    """True when ``stream`` (default: the current ``sys.stderr``) is an interactive terminal."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty()) if callable(isatty) else False
    except (OSError, ValueError):              # a closed or detached stream
        return False


class StageLine:
    """The stand-in for a progress bar when standard error is not a terminal.

    It takes the calls that evfuse makes on a tqdm bar (iteration, :meth:`update`, assignment of
    ``n``, :meth:`set_postfix_str`, :meth:`close`) and writes a single line when the stage is
    closed: ``"{desc}: {n} {noun}[, {postfix}] in {seconds:.1f} s"``.

    Parameters
    ----------
    iterable : iterable, optional
        Items to pass through (counted as they go).
    desc : str
        Name of the stage.
    noun : str
        What ``n`` counts, as printed after it (``"frames"``, ``"events"``, ``"s simulated"``).
    enabled : bool
        False: count, write nothing.
    stream : text stream, optional
        Where the line goes (default: ``sys.stderr`` at close time).
    """

    def __init__(self, iterable: Iterable | None = None, *, desc: str, noun: str,
                 enabled: bool = True, stream: TextIO | None = None) -> None:
        self.iterable = iterable
        self.desc = desc
        self.noun = noun
        self.enabled = enabled
        self.stream = stream
        self.n: float = 0
        self.postfix = ""
        self.closed = False
        self._start = time.perf_counter()

    def __iter__(self) -> Iterator:
        if self.iterable is None:
            raise TypeError(f"progress stage {self.desc!r} was made without an iterable")
        try:
            for item in self.iterable:
                yield item
                self.n += 1
        finally:
            self.close()

    def update(self, n: float = 1) -> None:
        """Count ``n`` more."""
        self.n += n

    def set_postfix_str(self, text: str = "", refresh: bool = True) -> None:
        """Text shown after the count in the closing line (``refresh`` is ignored)."""
        self.postfix = str(text)

    def line(self) -> str:
        """The line :meth:`close` writes."""
        n = self.n
        count = f"{n:,}" if float(n).is_integer() else f"{n:.3f}"
        extra = f", {self.postfix}" if self.postfix else ""
        return (f"{self.desc}: {count} {self.noun}{extra} in "
                f"{time.perf_counter() - self._start:.1f} s")

    def close(self) -> None:
        """Write the stage's line once (nothing when disabled)."""
        if self.closed:
            return
        self.closed = True
        if self.enabled:
            stream = sys.stderr if self.stream is None else self.stream
            print(self.line(), file=stream, flush=True)


def progress(iterable: Iterable | None = None, *, desc: str, unit: str = "it",
             noun: str | None = None, total: float | None = None, enabled: bool = True,
             **bar_options: Any):
    """A progress reporter for one stage: a tqdm bar on a terminal, else a :class:`StageLine`.

    Parameters
    ----------
    iterable : iterable, optional
        As tqdm's first argument.
    desc : str
        Name of the stage (the bar's label, the line's start).
    unit : str
        tqdm's unit (``"frame"``, ``"ev"``, ``"s"``).
    noun : str, optional
        What the count is called in the closing line (default ``unit``).
    total : float, optional
        Expected count (the bar's length; unused by the line).
    enabled : bool
        False (``--quiet``): no bar and no line.
    **bar_options
        Passed to tqdm only (``bar_format`` and the like).

    Returns
    -------
    tqdm or StageLine
        Both support iteration, ``update``, ``n``, ``set_postfix_str`` and ``close``.
    """
    if enabled and stderr_is_terminal():
        from tqdm.auto import tqdm

        return tqdm(iterable, desc=desc, unit=unit, total=total, **bar_options)
    return StageLine(iterable, desc=desc, noun=unit if noun is None else noun, enabled=enabled)
