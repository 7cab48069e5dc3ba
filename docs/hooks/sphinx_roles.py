"""MkDocs hook: the docstrings' Sphinx roles read as code in the API reference.

evfuse's numpydoc docstrings name other objects with Sphinx roles (``:func:`fill_map```,
``:mod:`fusion.map.emvs```), which Python's ``help()`` shows as they are and mkdocstrings
renders as ``:func:`` followed by the code. This hook drops the role's prefix from the rendered
HTML of every page, leaving the name as code.
"""

from __future__ import annotations

import re

_ROLE = re.compile(r":(?:py:)?(?:mod|func|class|meth|attr|data|obj|exc|const|ref|term):(?=<code)")


def on_page_content(html: str, **_: object) -> str:
    """Remove ``:role:`` before each ``<code>`` that follows one."""
    return _ROLE.sub("", html)
