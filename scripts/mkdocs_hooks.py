"""mkdocs hooks of the documentation site (``hooks:`` in mkdocs.yml).

The docstrings cross-reference in Sphinx's roles (``:class:`~pkg.mod.Name```), which help() and IDEs show as
written; on the API pages mkdocstrings renders them as ``:class:`` followed by a code span. This hook drops the
role, and a leading ``~`` keeps only the last component of the name, as Sphinx would show it.
"""

from __future__ import annotations

import re
from typing import Any

ROLE = re.compile(r":(?:py:)?(?:class|meth|func|mod|attr|data|exc|obj|const):<code>(~?)([^<]*)</code>")


def _name(match: re.Match[str]) -> str:
    tilde, name = match.groups()
    return f"<code>{name.rsplit('.', 1)[-1] if tilde else name}</code>"


def on_page_content(html: str, **kwargs: Any) -> str:
    return ROLE.sub(_name, html)
