"""Old module paths kept importable after issue 22's move into subpackages.

Each package's ``__init__`` names the modules it moved (old dotted path -> new dotted path) and
calls :func:`alias_modules` once: ``import fusion.dense`` and ``from fusion.dense import densify``
then give the module now at ``fusion.fill.dense``, the same object, so a user's script written
against the old layout keeps working without a second copy of any code. The table in each
``__init__`` is the only list of moves; ``tests/test_public_api.py`` imports every public name
from its old path through it.
"""

from __future__ import annotations

import importlib
import sys

__all__ = ["alias_modules"]


def alias_modules(package: object, moved: dict[str, str]) -> None:
    """Register each moved module under its old dotted path.

    Parameters
    ----------
    package : module
        The package the old paths lie in (its ``__init__`` module); each old path's last part is
        also set as an attribute of it, as an import of the old module would, unless the
        package already has that name (``fusion.reproduce`` is the function, as before).
    moved : dict of str to str
        Old dotted module path -> new dotted module path. The new module is imported now.
    """
    for old, new in moved.items():
        module = importlib.import_module(new)
        sys.modules.setdefault(old, module)
        name = old.rsplit(".", 1)[1]
        if not hasattr(package, name):
            setattr(package, name, module)
