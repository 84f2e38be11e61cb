"""The code in docs/bundle_adjustment.md runs, and prints what its comments say."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "bundle_adjustment.md").read_text(),
                    re.S)


def _run(code: str) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        exec(compile(code, "docs/bundle_adjustment.md", "exec"), {})
    return buf.getvalue()


def test_bal_example(monkeypatch, tmp_path):
    monkeypatch.chdir(data_file("bal/problem-49-7776-pre.txt").parent)  # the page names it bare
    out = _run(BLOCKS[0].replace('"problem-49-solved.txt"', repr(str(tmp_path / "s.txt"))))
    lines = out.split("\n")
    assert lines[0] == "49 7776 31843"
    a, b = map(float, lines[1].split())
    assert a == pytest.approx(850912.46, abs=0.01) and b == pytest.approx(13344.3184, rel=1e-6)
    assert lines[2] == "32 True"


def test_two_view_example():
    out = _run(BLOCKS[1]).split("\n")
    ok, rms = out[0].split()
    assert ok == "True" and 0.1 < float(rms) < 0.3 * 2 ** 0.5
    nums = [float(v) for v in out[1].replace("[", " ").replace("]", " ").split()]
    err, std = np.abs(nums[:3]), np.array(nums[3:])
    assert np.all(err < 3 * std) and np.all(std < 0.5)     # degrees
