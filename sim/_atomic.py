"""Names of evfuse's atomic outputs, shared by every writer (:mod:`sim.sequence` for folders,
:mod:`sim.eventio` for event files): a leaf module, so that any writer can import it without an
import loop."""

from __future__ import annotations

__all__ = ["PARTIAL_SUFFIX"]

PARTIAL_SUFFIX = ".partial"
"""Suffix of a folder or file evfuse is still writing: ``<out>.partial`` is renamed to ``<out>``
only once complete, so nothing under the final name is ever half-written."""
