"""BAL files: reading the shared problems (counts and initial costs of the data README),
exact round trip, and malformed files rejected with file:line."""

from __future__ import annotations

import io

import numpy as np
import pytest
from conftest import data_file

from microlie.optim.io.bal import BALProblem, read_bal, write_bal

TINY = """2 2 3

0 0 10.0 -20.0
1 0 5.5 6.5
1 1 -1.0 2.0
""" + "\n".join(["0.01", "0.02", "0.03", "0", "0", "-5", "500", "0", "0",
                 "0", "0", "0", "0.5", "0", "-6", "450", "0.01", "0"]) + """
0.1
-0.2
0
0.3
0.1
0.2
"""


def _lines():
    return TINY.splitlines()


def _read(text: str, name: str = "bad.txt") -> BALProblem:
    s = io.StringIO(text)
    s.name = name
    return read_bal(s)


def test_tiny_file_fields():
    p = _read(TINY)
    assert (p.n_cameras, p.n_points, p.n_observations) == (2, 2, 3)
    np.testing.assert_array_equal(p.camera_index, [0, 1, 1])
    np.testing.assert_array_equal(p.point_index, [0, 0, 1])
    np.testing.assert_array_equal(p.observations[1], [5.5, 6.5])
    np.testing.assert_array_equal(p.cameras[1], [0, 0, 0, 0.5, 0, -6, 450, 0.01, 0])
    np.testing.assert_array_equal(p.points[1], [0.3, 0.1, 0.2])


@pytest.mark.parametrize("name,counts,cost", [
    ("problem-49-7776-pre.txt", (49, 7776, 31843), 8.509125e5),
    ("dubrovnik-3-7-pre.txt", (3, 7, 19), 2764.220),
    ("dubrovnik-1-1-pre.txt", (1, 1, 1), 63.31642),
])
def test_shared_files_counts_and_initial_cost(name, counts, cost):
    # counts and initial costs: ../shared/data/README.md (independent numpy implementation)
    p = read_bal(data_file(f"bal/{name}"))
    assert (p.n_cameras, p.n_points, p.n_observations) == counts
    assert p.cost() == pytest.approx(cost, rel=1e-6)


def test_behind_camera_costs_on_problem_49():
    # README / PEERS: standard model 850912.46; GTSAM (drops points behind the camera) 850802.09
    p = read_bal(data_file("bal/problem-49-7776-pre.txt"))
    assert p.cost("evaluate") == pytest.approx(850912.46, abs=0.01)
    assert p.cost("drop") == pytest.approx(850802.09, abs=0.01)


def test_round_trip_is_exact(tmp_path):
    p = read_bal(data_file("bal/dubrovnik-3-7-pre.txt"))
    rng = np.random.default_rng(0)
    q = BALProblem(p.cameras + rng.normal(size=p.cameras.shape) * 1e-3, p.points / 3.0,
                   p.camera_index, p.point_index, p.observations * np.pi)
    f = tmp_path / "out.txt"
    write_bal(f, q)
    back = read_bal(f)
    for a in ("cameras", "points", "camera_index", "point_index", "observations"):
        np.testing.assert_array_equal(getattr(back, a), getattr(q, a))


def _replace(lineno: int, new: str | None) -> str:
    lines = _lines()
    if new is None:
        del lines[lineno - 1]
    else:
        lines[lineno - 1] = new
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("text,where,what", [
    ("", "bad.txt:1:", "empty file"),
    ("2 2\n", "bad.txt:1:", "header"),
    ("2 x 3\n", "bad.txt:1:", "integers"),
    ("\n".join(_lines()[:4]) + "\n", "bad.txt:5:", "end of file"),          # truncated obs
    ("\n".join(_lines()[:12]) + "\n", "bad.txt:13:", "end of file"),        # truncated params
    (TINY + "7\n", "bad.txt:30:", "do not match"),                          # extra value
    (TINY.replace("2 2 3", "2 2 4", 1), "bad.txt:", "fields"),               # count too large
    (TINY.replace("2 2 3", "2 3 3", 1), "bad.txt:", "end of file"),          # points count
    (_replace(4, "1 0 nan 6.5"), "bad.txt:4:", "non-finite observation"),
    (_replace(4, "1 0 5.5"), "bad.txt:4:", "4 fields"),
    (_replace(4, "1.5 0 5.5 6.5"), "bad.txt:4:", "integers"),
    (_replace(5, "2 1 -1.0 2.0"), "bad.txt:5:", "missing camera 2"),
    (_replace(5, "1 2 -1.0 2.0"), "bad.txt:5:", "missing point 2"),
    (_replace(5, "-1 1 -1.0 2.0"), "bad.txt:5:", "missing camera -1"),
    (_replace(12, "NaN"), "bad.txt:12:", "non-finite value 'NaN' \\(camera 0 parameter 6\\)"),
    (_replace(27, "inf"), "bad.txt:27:", "point 1 coordinate 0"),
    (_replace(9, "abc"), "bad.txt:9:", "not a number"),
])
def test_malformed_files_name_file_and_line(text, where, what):
    with pytest.raises(ValueError, match=where + ".*" + what):
        _read(text)


def test_path_appears_in_errors(tmp_path):
    f = tmp_path / "trunc.txt"
    f.write_text("\n".join(_lines()[:4]) + "\n")
    with pytest.raises(ValueError, match="trunc.txt:5: unexpected end of file"):
        read_bal(f)
