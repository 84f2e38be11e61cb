"""The public API is typed: mypy on a short user script reveals the element types (``Self``
return types) and the ``jac=True`` tuples (``typing.overload`` on ``Literal`` flags)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from conftest import require

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = '''
import numpy as np
from microlie import SE3, SO3, Sim3, Side

x = np.zeros(6)
X = SE3.exp(x)
reveal_type(X)
reveal_type(X.compose(X, jac=True))
reveal_type(X.compose(X))
reveal_type(X.inverse())
reveal_type(SE3.exp(x, jac=True))
reveal_type(X.minus(X, jac=True))
reveal_type(SO3.identity())
reveal_type(Sim3.random(3).plus(np.zeros(7)))
reveal_type(SE3.from_params(np.zeros(7), check=False))
reveal_type(SE3.stack([X, X]))
reveal_type(X[0])
side: Side = "left"
reveal_type(X.act(np.zeros(3), jac=True, side=side))
X.compose(SO3.identity())  # an error: not an SE3
'''

EXPECTED = [
    'Revealed type is "microlie.groups.se3.SE3"',
    'Revealed type is "tuple[microlie.groups.se3.SE3, Any, Any]"',
    'Revealed type is "microlie.groups.se3.SE3"',
    'Revealed type is "microlie.groups.se3.SE3"',
    'Revealed type is "tuple[microlie.groups.se3.SE3, Any]"',
    'Revealed type is "tuple[Any, Any, Any]"',
    'Revealed type is "microlie.groups.so3.SO3"',
    'Revealed type is "microlie.groups.sim3.Sim3"',
    'Revealed type is "microlie.groups.se3.SE3"',
    'Revealed type is "microlie.groups.se3.SE3"',
    'Revealed type is "microlie.groups.se3.SE3"',
    'Revealed type is "tuple[Any, Any, Any]"',
]


def test_revealed_types_of_a_user_script(tmp_path):
    require("mypy")
    script = tmp_path / "user.py"
    script.write_text(SCRIPT)
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), MYPYPATH=str(ROOT / "src"))
    r = subprocess.run([sys.executable, "-m", "mypy", "--no-incremental", "--follow-imports=silent",
                        "--cache-dir", str(tmp_path / "cache"), str(script)],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    notes = re.findall(r'Revealed type is "[^"]*"', r.stdout)
    assert notes == EXPECTED, r.stdout + r.stderr
    errors = [line for line in r.stdout.splitlines() if ": error:" in line]
    assert len(errors) == 1 and "compose" in errors[0], r.stdout
