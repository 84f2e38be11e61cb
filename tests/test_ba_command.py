"""The BAL branch of ``microlie optimize`` (JSON report keys and values, -o, --plot)."""

from __future__ import annotations

import argparse
import io

import numpy as np
import pytest
from conftest import data_file, require

from microlie.optim.command_bal import run_bal
from microlie.optim.io.bal import read_bal


def _args(path, **kw):
    base = dict(input=str(path), robust=None, max_iter=100, output=None, plot=None, solver="lm",
                linear_solver="auto", json=True)
    base.update(kw)
    return argparse.Namespace(**base)


def test_report_keys_output_and_plot(tmp_path):
    matplotlib = require("matplotlib")
    backend = matplotlib.get_backend()
    src = data_file("bal/dubrovnik-3-7-pre.txt")
    out, png = tmp_path / "out.txt", tmp_path / "ba.png"
    r = run_bal(_args(src, output=str(out), plot=str(png), max_iter=200), io.StringIO())
    for k in ("initial_cost", "final_cost", "iterations", "time_s", "converged"):
        assert k in r
    assert r["initial_cost"] == pytest.approx(2764.220, abs=1e-3)      # data README
    assert r["final_cost"] <= 0.0199833 + 1e-5                           # GTSAM regression
    back = read_bal(out)
    assert back.cost() == pytest.approx(r["final_cost"], rel=1e-9, abs=1e-15)
    np.testing.assert_array_equal(back.observations, read_bal(src).observations)
    assert png.stat().st_size > 10_000
    assert matplotlib.get_backend() == backend


def test_robust_report_separates_plain_and_robust_costs():
    src = data_file("bal/dubrovnik-3-7-pre.txt")
    r = run_bal(_args(src, robust="cauchy:1.0", max_iter=5), io.StringIO())
    assert r["robust"] == "cauchy:1.0"
    assert r["final_robust_cost"] <= r["final_cost"] + 1e-12     # rho(s) <= s


def test_unsupported_options_rejected():
    src = data_file("bal/dubrovnik-1-1-pre.txt")
    with pytest.raises(ValueError, match="lm only"):
        run_bal(_args(src, solver="dogleg"), io.StringIO())
    with pytest.raises(ValueError, match="linear-solver"):
        run_bal(_args(src, linear_solver="qdldl"), io.StringIO())
