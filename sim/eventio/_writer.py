"""What both streaming event writers share: the ``<name>.partial`` file renamed to ``<name>`` by a
successful :meth:`close`, the chunk-order check, :meth:`checkpoint` and resuming from one, and
the ``with`` protocol. The name of the unfinished file is :func:`sim._atomic.partial_path`'s
(the one suffix of everything unfinished)."""

from __future__ import annotations

import os
from pathlib import Path
from types import TracebackType
from typing import Self

import numpy as np

from sim._atomic import partial_path
from sim.eventio._events import _check_array, _first_error


def _partial_path(path: Path) -> Path:
    """``<path>.partial`` (:func:`sim._atomic.partial_path`). The streaming writers keep their own
    class, not :func:`sim._atomic.atomic_file`: they hold the file open for a whole simulation and
    keep the ``.partial`` file when interrupted, for a resumed run."""
    if not path.name:
        raise ValueError(f"output path {str(path)!r} has no file name")
    return partial_path(path)


class _StreamingWriter:
    """What both writers share: the ``.partial`` file, the chunk-order check, the context."""

    path: Path
    partial: Path
    count: int
    _last_t: int | None
    _closed: bool
    _format: str
    _width: int | None = None
    _height: int | None = None

    def _begin(self, path: str | Path) -> None:
        self.path = Path(path)
        self.partial = _partial_path(self.path)
        self.count = 0
        self._last_t = None
        self._closed = False

    def _check_chunk(self, events: np.ndarray) -> None:
        source = f"{self.path}: chunk starting at event {self.count}"
        if self._closed:
            raise ValueError(f"{self.path}: write() after close(); expected writes before close")
        _check_array(events, source)
        if not events.size:
            return
        if self._last_t is not None and int(events["t"][0]) < self._last_t:
            raise ValueError(f"{source}: the chunk starts at t = {int(events['t'][0])} ns, before "
                             f"the previous chunk's last event at {self._last_t} ns; expected "
                             "consecutive, time-ordered chunks")
        error = _first_error(events, self._width, self._height, None)
        if error is not None:
            raise ValueError(f"{source}: event {self.count + error[0]}: {error[1]}")
        if int(events["t"][0]) < 0:
            raise ValueError(f"{source}: t = {int(events['t'][0])} ns is negative; expected "
                             "times >= 0 on disk")

    def checkpoint(self) -> dict:
        """Put every event written so far on disk and say where the file stands.

        The file stays open and writing goes on. After an interruption (the ``.partial`` file is
        left), a new writer of the same path given this as ``resume`` continues exactly here.

        Returns
        -------
        dict
            JSON-able: ``format`` (``"txt"`` or ``"h5"``), ``count`` (events written),
            ``last_t`` (ns of the last event, or None) and what the format needs to continue.

        Raises
        ------
        ValueError
            The writer is closed.
        """
        if self._closed:
            raise ValueError(f"{self.path}: checkpoint() after close(); expected an open writer")
        return {"format": self._format, "count": self.count, "last_t": self._last_t,
                **self._sync()}

    def _reopen(self, resume: dict, keys: tuple[str, ...]) -> None:
        """Check a :meth:`checkpoint`, restore the counts and find the file to continue."""
        if not isinstance(resume, dict) or resume.get("format") != self._format:
            got = resume.get("format") if isinstance(resume, dict) else type(resume).__name__
            raise ValueError(f"{self.path}: resume must be a checkpoint() of a {self._format} "
                             f"event writer, got {got!r}")
        missing = [key for key in ("count", "last_t", *keys) if key not in resume]
        if missing:
            raise ValueError(f"{self.path}: the checkpoint lacks {', '.join(missing)}; expected "
                             f"a dict from {type(self).__name__}.checkpoint()")
        if not self.partial.exists() and self.path.is_file():
            os.replace(self.path, self.partial)      # closed after the checkpoint: reopen it
        if not self.partial.is_file():
            raise ValueError(f"{self.partial}: no such file to resume; expected the file the "
                             "checkpointed writer left")
        self.count = int(resume["count"])
        self._last_t = None if resume["last_t"] is None else int(resume["last_t"])

    def _reopen_bytes(self, resume: dict, keys: tuple[str, ...]):
        """:meth:`_reopen` for a format written as a plain byte stream: the ``.partial`` file
        cut to the checkpoint's ``size`` (what was written after it dropped) and opened to
        append there. Returns the open binary file."""
        self._reopen(resume, ("size", *keys))
        size = int(resume["size"])
        handle = self.partial.open("r+b")
        has = handle.seek(0, os.SEEK_END)
        if has < size:
            handle.close()
            raise self._too_short("bytes", has, size)
        handle.truncate(size)
        handle.seek(size)
        return handle

    def _too_short(self, what: str, has: int, needs: int) -> ValueError:
        return ValueError(f"{self.partial} holds {has} {what}, fewer than the {needs} the "
                          "checkpoint counted; expected the file the checkpointed writer left")

    def _sync(self) -> dict:  # pragma: no cover - overridden
        raise NotImplementedError

    def _finish(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def _abort(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:
        """Finish the file and rename ``<name>.partial`` to ``<name>`` (replacing it).

        Closing twice is harmless.
        """
        if self._closed:
            return
        self._closed = True
        try:
            self._finish()
        except BaseException:
            self._abort()
            raise
        self._publish()

    def _publish(self) -> None:
        """Give the finished file its name."""
        os.replace(self.partial, self.path)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        elif not self._closed:
            self._closed = True
            self._abort()
