"""Item 1 of issue 8: only the backend layer knows which array library an array belongs to.

``_array.py``, ``_linalg.py``, ``_kernels.py`` (the evaluator, which chunks NumPy and CPU torch
batches), ``_autodiff.py`` (JAX/torch automatic differentiation for the solver),
``_torch_compile.py`` (what Dynamo traces in place of the compiled single-element paths) and the
device engine ``optim/device/`` (LM on torch and JAX: their loops, autograd and sharding) may
test for or import an array library; no other module in ``src/microlie`` may (they ask the
layer library-neutral questions: ``is_device_array``, ``is_host_array``).
"""

from __future__ import annotations

import re
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "microlie"
LAYER = {"_array.py", "_linalg.py", "_kernels.py", "_autodiff.py", "_torch_compile.py"}
LAYER_PACKAGES = {SRC / "optim" / "device"}

# code lines only: a doctest line starts with '>>>' and is not matched
PATTERNS = {
    "is_numpy": re.compile(r"\bis_numpy(_like)?\s*\("),
    "is_torch / is_jax": re.compile(r"\bis_(torch|jax)\s*\("),
    "isinstance(..., np.ndarray)": re.compile(r"\bisinstance\([^#]*\bnp\.ndarray\b"),
    "import torch": re.compile(r"^\s*(import\s+torch\b|from\s+torch\b)"),
    "import jax": re.compile(r"^\s*(import\s+jax\b|from\s+jax\b)"),
}


def _offences() -> list[str]:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if path.parent == SRC and path.name in LAYER or path.parent in LAYER_PACKAGES:
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            for what, pat in PATTERNS.items():
                if pat.search(line):
                    found.append(f"{path.relative_to(SRC.parent)}:{i}: {what}: {line.strip()}")
    return found


def test_no_backend_tests_outside_the_layer():
    assert _offences() == []


def test_the_grep_finds_each_pattern():
    # the patterns match the forms they are meant to catch (and not a doctest line)
    lines = ["if A.is_numpy(x):", "if isinstance(S, np.ndarray):", "    import torch",
             "from jax import numpy", "ok = is_torch(t)", "ok = A.is_numpy_like(p)"]
    for line in lines:
        assert any(p.search(line) for p in PATTERNS.values()), line
    for line in [">>> import torch", "    >>> import jax", "x = numpy_is(y)"]:
        assert not any(p.search(line) for p in PATTERNS.values()), line
