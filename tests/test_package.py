"""The package's face: the sub-packages are reachable as attributes after ``import microlie``
(``microlie.imu.Preintegration(...)``), load only on first use, and unknown names fail."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _run(code: str) -> str:
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env={"PYTHONPATH": SRC, "PATH": ""}, timeout=120)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def test_subpackages_load_on_first_attribute_access():
    out = _run(
        "import sys, microlie\n"
        "eager = [m for m in ('microlie.imu', 'microlie.optim', 'microlie.traj',"
        " 'microlie.calibration') if m in sys.modules]\n"
        "print(eager)\n"
        "print(microlie.imu.Preintegration.__name__, microlie.optim.FactorGraph.__name__,"
        " microlie.traj.read_tum.__name__, microlie.calibration.hand_eye.__name__)\n")
    lines = out.splitlines()
    assert lines[0] == "[]"  # none imported by `import microlie`
    assert lines[1] == "Preintegration FactorGraph read_tum hand_eye"


def test_unknown_attribute_raises():
    import microlie

    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        microlie.nothing  # noqa: B018
