"""Static checks that are part of the suite: ruff on the code and the strict documentation build
(a broken API reference or a dead link in docs/ fails here)."""

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
    r = _run("ruff", "check", "src", "tests", "benchmarks", "examples")
    assert r.returncode == 0, r.stdout + r.stderr


def test_docs_build_strict(tmp_path):
    require("mkdocs")
    require("mkdocstrings")
    r = _run("mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site"))
    assert r.returncode == 0, r.stdout + r.stderr
    page = (tmp_path / "site" / "api" / "groups" / "index.html").read_text()
    for name in ("SO3", "SE3", "Sim3", "jr_inv", "minus"):  # the reference was generated
        assert name in page


@pytest.mark.parametrize("page", sorted(p.name for p in (ROOT / "docs").glob("*.md")))
def test_docs_pages_in_nav(page):
    nav = (ROOT / "mkdocs.yml").read_text()
    assert page in nav, f"docs/{page} is not in the mkdocs.yml nav"
