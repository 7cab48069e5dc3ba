"""The command-line modules use the public API only (issue 22): every project name that a
command-line module of ``sim`` or ``fusion`` imports (``cli.py``, ``cli_*.py``: the command line
split by command group, issue 35) is in the ``__all__`` of the public module it comes from, and no
private module (a path part with a leading underscore) is imported.

The imports are read from the source with :mod:`ast` (at any depth: the command handlers import
inside functions); each named module is then imported to read its ``__all__``.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CLI_MODULES = tuple(sorted(
    path.relative_to(ROOT).as_posix() for package in ("sim", "fusion")
    for path in (ROOT / package).rglob("*.py")
    if any(part == "cli" or part.startswith("cli_")
           for part in path.relative_to(ROOT / package).with_suffix("").parts)))
"""Every command-line module: named ``cli`` or ``cli_*``, or inside such a package."""
PROJECT = ("sim", "fusion", "scenes")


def _private_imports(source: str) -> list[str]:
    """``module: name`` for each project import of ``source`` that is not public: a module path
    with a private part, or a name outside the module's ``__all__``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            modules = [(alias.name, None) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            modules = [(node.module, alias.name) for alias in node.names]
        else:
            continue
        for module, name in modules:
            if module.split(".")[0] not in PROJECT:
                continue
            if any(part.startswith("_") for part in module.split(".")):
                found.append(f"{module} (a private module)")
                continue
            if name is None:
                continue
            public = getattr(importlib.import_module(module), "__all__", ())
            if name not in public:
                found.append(f"{module}: {name}")
    return found


def test_the_checker_sees_private_imports():
    """A name outside ``__all__``, a private module and a private name are all reported; public
    ones are not (so that the test below can fail)."""
    source = ("from sim.validation import ParameterError\n"
              "def f():\n"
              "    from sim.validation import _number\n"
              "    from sim._atomic import write_bytes_atomically\n"
              "    from fusion.cli import _parser\n"
              "    import numpy\n")
    assert _private_imports(source) == ["sim.validation: _number",
                                        "sim._atomic (a private module)",
                                        "fusion.cli: _parser"]


def test_every_command_line_module_is_checked():
    """The modules found include the entry point and each command group's module."""
    assert {"sim/cli.py", "fusion/cli.py", "fusion/cli_mapping.py", "fusion/cli_experiments.py",
            "fusion/cli_options.py"} <= set(CLI_MODULES)


@pytest.mark.parametrize("path", CLI_MODULES)
def test_the_command_line_imports_public_names_only(path):
    assert _private_imports((ROOT / path).read_text(encoding="utf-8")) == []
