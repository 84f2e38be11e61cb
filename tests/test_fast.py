"""The optional compiled kernels (microlie[fast], ``pip install ./fast``): the generated header
matches microlie.groups._math, ``MICROLIE_FAST=0`` disables them, bad arguments are errors.
Agreement with the generic kernels is checked in tests/test_kernels.py."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import require

ROOT = Path(__file__).resolve().parents[1]


def _gen():
    spec = importlib.util.spec_from_file_location("gen_coeffs", ROOT / "fast" / "gen_coeffs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_coefficient_header_is_generated_from_the_generic_series():
    gen = _gen()
    assert gen.HEADER.read_text() == gen.render(), "run: PYTHONPATH=src python fast/gen_coeffs.py"
    from microlie.groups import _math as M

    text = gen.render()
    assert repr(M.C_COT[-1]) in text and f"#define SMALL2 {M.SMALL2!r}" in text


def test_environment_variable_disables_the_compiled_kernels():
    if os.environ.get("MICROLIE_FAST") != "0":
        require("microlie_fast")
    code = "from microlie import _fast; print(len(_fast.installed()), _fast.install())"
    env = dict(os.environ, MICROLIE_FAST="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["0", "[]"]


def test_compiled_kernel_rejects_bad_arguments():
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0")
    lie = require("microlie_fast._lie")
    with pytest.raises(ValueError, match=r"SE3.exp: argument 0 .*\(N, 6\)"):
        lie.se3_exp(np.zeros((2, 5)))
    with pytest.raises(ValueError, match="same N and dtype"):
        lie.se3_compose(np.zeros((2, 7)), np.zeros((2, 7), dtype=np.float32))
    with pytest.raises(ValueError, match="C-contiguous"):
        lie.so3_exp(np.zeros((3, 6))[:, ::2])
    with pytest.raises(TypeError, match="expected 2 arguments"):
        lie.so3_act(np.zeros((1, 4)))
    (q,) = lie.so3_exp(np.zeros((0, 3)))
    assert q.shape == (0, 4)
