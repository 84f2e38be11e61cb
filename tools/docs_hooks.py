"""MkDocs hook (mkdocs.yml: ``hooks: [tools/docs_hooks.py]``).

docs/*.md write tables as GitHub does: a pipe inside a code span of a table row is escaped,
``| `--format auto\\|g2o` | ... |``, and GitHub shows ``auto|g2o``. Python-Markdown's tables
already keep a code span's pipes in their cell but print the backslash: this hook removes it,
so the site and GitHub show the same table.
"""

from __future__ import annotations

import re
from typing import Any

CODE_SPAN = re.compile(r"(`+)(.+?)\1")
FENCE = re.compile(r"^\s*(```|~~~)")


def unescape_table_pipes(markdown: str) -> str:
    """``markdown`` with ``\\|`` turned into ``|`` inside the code spans of table rows."""
    out, fenced = [], False
    for line in markdown.split("\n"):
        if FENCE.match(line):
            fenced = not fenced
        elif not fenced and line.lstrip().startswith("|"):
            line = CODE_SPAN.sub(lambda m: m.group(0).replace("\\|", "|"), line)
        out.append(line)
    return "\n".join(out)


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    return unescape_table_pipes(markdown)
