"""``microlie optimize --abs-tol / --rel-tol`` (GTSAM's absoluteErrorTol / relativeErrorTol).

The reference optimum of parking-garage.g2o, 0.6341923996, is GTSAM 4.3's LM error at a relative
tolerance of 1e-10 (../shared/data/README.md), not one of our outputs.
"""

from __future__ import annotations

import io
import json

import pytest
from conftest import data_file

from microlie.cli import main

GARAGE_OPTIMUM = 0.6341923996  # GTSAM, ../shared/data/README.md


def _json(*argv: str) -> dict:
    out, err = io.StringIO(), io.StringIO()
    code = main(["optimize", *argv, "--json", "-q"], out=out, err=err)
    assert code == 0, err.getvalue()
    return json.loads(out.getvalue())


def test_certified_start_reaches_the_optimum_with_tight_tolerances():
    path = str(data_file("pose_graph/parking-garage.g2o"))
    default = _json(path, "--init", "certified")
    tight = _json(path, "--init", "certified", "--abs-tol", "0", "--rel-tol", "1e-12")
    chordal = _json(path, "--init", "chordal")
    # the default (GTSAM's 1e-5 absolute) stops in the flat valley above the optimum ...
    assert default["final_cost"] > GARAGE_OPTIMUM * (1 + 1e-5)
    # ... the tight tolerances reach GTSAM's optimum, no higher than the chordal start's run
    assert tight["final_cost"] == pytest.approx(GARAGE_OPTIMUM, rel=2e-10)
    assert tight["final_cost"] <= chordal["final_cost"]
    assert tight["iterations"] > default["iterations"]


@pytest.mark.parametrize("argv, message", [
    (["--abs-tol", "-1"], "must be a finite number >= 0"),
    (["--rel-tol", "inf"], "must be a finite number >= 0"),
    (["--rel-tol", "x"], "expected a number"),
])
def test_bad_tolerances_are_usage_errors(argv, message):
    out, err = io.StringIO(), io.StringIO()
    code = main(["optimize", "--example", *argv], out=out, err=err)
    assert code == 2
    assert message in err.getvalue()


def test_tolerances_refused_with_trust_region():
    out, err = io.StringIO(), io.StringIO()
    code = main(["optimize", "--example", "--solver", "trust-region", "--abs-tol", "0"],
                out=out, err=err)
    assert code == 1
    assert "--abs-tol and --rel-tol apply to --solver lm, gn and dogleg" in err.getvalue()
