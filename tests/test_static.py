"""Static checks that are part of the suite: ruff on the code and the documentation's nav (the
strict documentation build and its pages: tests/test_docs_site.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import require

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1", PYTHONPATH=str(ROOT / "src"))
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True,
                          text=True, env=env, timeout=600)


def test_ruff_clean():
    require("ruff")
    r = _run("ruff", "check", "src", "tests", "benchmarks", "examples", "tools")
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.parametrize("page", sorted(p.name for p in (ROOT / "docs").glob("*.md")))
def test_docs_pages_in_nav(page):
    nav = (ROOT / "mkdocs.yml").read_text()
    assert page in nav, f"docs/{page} is not in the mkdocs.yml nav"
