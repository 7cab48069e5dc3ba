"""The error of the filling methods' machinery (see :mod:`fusion.methods`), in a module of its own
so that every private module of the package raises it without importing another."""

from __future__ import annotations

__all__ = ["MethodError"]


class MethodError(ValueError):
    """A filling method failed or returned something that is not a dense depth map."""
