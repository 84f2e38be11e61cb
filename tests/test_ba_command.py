"""The BAL branch of ``microlie optimize`` (JSON report keys and values, -o, --plot), run through
the one engine with its solver and linear-solver words."""

from __future__ import annotations

import argparse
import io

import numpy as np
import pytest
from conftest import data_file, require

from microlie.optim.command_bal import run_bal
from microlie.optim.io.bal import read_bal


def _args(path, **kw):
    base = dict(input=str(path), robust=None, max_iter=100, output=None, plot=None, solver=None,
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
    # bundle_adjust's own words before issue 20: an error naming the engine's words
    with pytest.raises(ValueError, match=r"--linear-solver sparse is gone.*use schur"):
        run_bal(_args(src, linear_solver="sparse"), io.StringIO())
    with pytest.raises(ValueError, match=r"--linear-solver full is gone.*use cholesky"):
        run_bal(_args(src, linear_solver="full"), io.StringIO())
    with pytest.raises(ValueError, match="unknown linear solver 'qr'"):
        run_bal(_args(src, linear_solver="qr"), io.StringIO())
    with pytest.raises(ValueError, match="--gauge applies to pose graphs"):
        run_bal(_args(src, gauge="check"), io.StringIO())


def test_engine_words_reach_the_same_optimum():
    """--solver and --linear-solver take the engine's words: the default (trust-region on the
    Schur system), the full system, and GTSAM-rule LM end at GTSAM's regression value."""
    src = data_file("bal/dubrovnik-3-7-pre.txt")
    ref = run_bal(_args(src, max_iter=200), io.StringIO())
    assert (ref["solver"], ref["linear_solver"]) == ("trust-region", "schur")
    full = run_bal(_args(src, max_iter=200, linear_solver="cholesky"), io.StringIO())
    assert full["linear_solver"] == "cholesky"
    assert full["iterations"] == ref["iterations"]
    assert full["final_cost"] == pytest.approx(ref["final_cost"], rel=1e-6, abs=1e-9)
    lm = run_bal(_args(src, max_iter=200, solver="lm"), io.StringIO())
    assert lm["solver"] == "lm"
    for r in (ref, full, lm):
        assert r["final_cost"] <= 0.0199833 + 1e-5                   # GTSAM regression


def test_command_line_defaults_per_format(tmp_path):
    """Through the parser: BAL defaults to trust-region/schur, pose graphs to lm."""
    import json

    from microlie.optim.command import register, run

    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    src = data_file("bal/dubrovnik-3-7-pre.txt")
    out = io.StringIO()
    assert run(parser.parse_args(["optimize", str(src), "--json", "-q"]), out, io.StringIO()) == 0
    r = json.loads(out.getvalue())
    assert (r["solver"], r["linear_solver"]) == ("trust-region", "schur")
    g2o = tmp_path / "tiny.g2o"
    g2o.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    out = io.StringIO()
    assert run(parser.parse_args(["optimize", str(g2o), "--json", "-q"]), out, io.StringIO()) == 0
    assert json.loads(out.getvalue())["solver"] == "lm"
