"""Trajectory readers and writers: shared files, round trips and malformed input."""

from __future__ import annotations

import re

import numpy as np
import pytest
from conftest import data_file
from scipy.spatial.transform import Rotation

from microlie.traj import (
    read_euroc,
    read_kitti,
    read_timestamps,
    read_trajectory,
    read_tum,
    write_kitti,
    write_tum,
)

EVO = "trajectory/evo/"


# ----------------------------------------------------------------------------- shared files
@pytest.mark.parametrize(
    "name, n",
    [
        ("freiburg1_xyz-groundtruth.txt", 3000),
        ("freiburg1_xyz-rgbdslam.txt", 788),
        ("freiburg1_xyz-ORB_kf_mono.txt", 32),
        ("fr2_desk_groundtruth.txt", 20957),
        ("fr2_desk_ORB.txt", 2893),
        ("V102.txt", 807),
        ("georeferenced.tum", 1000),
    ],
)
def test_read_tum_shared(name, n):
    path = data_file(EVO + name)
    t = read_tum(path)
    assert len(t) == n
    # independent parse: numpy's loadtxt, quaternion normalised by hand
    raw = np.loadtxt(path, comments="#")
    np.testing.assert_array_equal(t.timestamps, raw[:, 0])
    np.testing.assert_array_equal(t.positions, raw[:, 1:4])
    q = raw[:, 4:8] / np.linalg.norm(raw[:, 4:8], axis=1, keepdims=True)
    r_ours = Rotation.from_quat(t.quat_xyzw).as_matrix()
    np.testing.assert_allclose(r_ours, Rotation.from_quat(q).as_matrix(), atol=1e-14)


def test_duplicate_timestamps_reported():
    # data README: fr2_desk ground truth has one repeated stamp, V102.txt four
    assert read_tum(data_file(EVO + "fr2_desk_groundtruth.txt")).duplicate_timestamps().size == 1
    assert read_tum(data_file(EVO + "V102.txt")).duplicate_timestamps().size == 4


def test_read_kitti_shared_with_times():
    path = data_file(EVO + "KITTI_00_gt.txt")
    times = data_file(EVO + "KITTI_00_gt_times.txt")
    t = read_kitti(path, times)
    raw = np.loadtxt(path).reshape(-1, 3, 4)
    assert len(t) == 4541
    np.testing.assert_array_equal(t.positions, raw[:, :, 3])
    np.testing.assert_array_equal(t.timestamps, np.loadtxt(times))
    m = t.matrices()
    # rotations are exactly orthonormal after reading and within 1e-6 of the file's numbers
    rr = m[:, :3, :3]
    np.testing.assert_allclose(np.swapaxes(rr, 1, 2) @ rr, np.broadcast_to(np.eye(3), rr.shape),
                               atol=1e-14)
    np.testing.assert_allclose(rr, raw[:, :, :3], atol=1e-6)
    assert read_kitti(path).timestamps is None


def test_read_euroc_shared():
    path = data_file(EVO + "V102_groundtruth.csv")
    t = read_euroc(path)
    raw = np.loadtxt(path, delimiter=",", comments="#")
    assert len(t) == 16702
    np.testing.assert_array_equal(t.timestamps, raw[:, 0] / 1e9)
    np.testing.assert_array_equal(t.positions, raw[:, 1:4])
    q_wxyz = raw[:, 4:8]
    r = Rotation.from_quat(q_wxyz, scalar_first=True).as_matrix()
    np.testing.assert_allclose(t.matrices()[:, :3, :3], r, atol=1e-14)


# ----------------------------------------------------------------------------- round trips
def test_tum_kitti_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    q = Rotation.random(20, random_state=1).as_quat()
    p = rng.normal(size=(20, 3))
    stamps = 1e9 + np.arange(20) * 0.1
    f = tmp_path / "a.txt"
    lines = [" ".join(map(repr, row)) for row in np.column_stack([stamps, p, q]).tolist()]
    f.write_text("\n".join(lines) + "\n")
    t = read_tum(f)
    write_tum(tmp_path / "b.txt", t)
    t2 = read_tum(tmp_path / "b.txt")
    np.testing.assert_array_equal(t2.timestamps, stamps)
    np.testing.assert_allclose(t2.positions, p, rtol=0, atol=1e-15)
    np.testing.assert_allclose(t2.matrices(), t.matrices(), atol=1e-15)
    write_kitti(tmp_path / "c.txt", t)
    t3 = read_kitti(tmp_path / "c.txt", stamps)
    np.testing.assert_allclose(t3.matrices(), t.matrices(), atol=1e-14)
    np.testing.assert_array_equal(t3.timestamps, stamps)
    assert read_trajectory(tmp_path / "c.txt", "kitti").timestamps is None


def test_comments_blank_lines_and_commas(tmp_path):
    f = tmp_path / "c.txt"
    f.write_text("# header\n\n1.0 1 2 3 0 0 0 1\n  # indented comment\n2.0,4,5,6,0,0,1,0\n")
    t = read_tum(f)
    np.testing.assert_array_equal(t.timestamps, [1.0, 2.0])
    np.testing.assert_array_equal(t.positions, [[1, 2, 3], [4, 5, 6]])


def test_euroc_ignores_extra_columns_and_reorders_quaternion(tmp_path):
    f = tmp_path / "gt.csv"
    c, s = float(np.cos(0.25)), float(np.sin(0.25))  # 0.5 rad about z, w first
    f.write_text("#timestamp, x, y, z, qw, qx, qy, qz, vx\n"
                 f"1500000000000000000,1,2,3,{c!r},0,0,{s!r},9\n")
    t = read_euroc(f)
    assert t.timestamps[0] == 1.5e9
    np.testing.assert_allclose(t.matrices()[0, :3, :3],
                               Rotation.from_euler("z", 0.5).as_matrix(), atol=1e-15)


# ----------------------------------------------------------------------------- malformed input
TUM_OK = "1.0 0 0 0 0 0 0 1\n"


def _expect(reader, tmp_path, text, pattern, name="bad.txt", **kw):
    f = tmp_path / name
    f.write_text(text)
    with pytest.raises(ValueError) as exc:
        reader(f, **kw)
    msg = str(exc.value)
    assert str(f) in msg, msg
    assert re.search(pattern, msg), msg
    return msg


@pytest.mark.parametrize(
    "line, pattern",
    [
        ("2.0 0 0 0 0 0 1", r"expected 8 fields .* found 7"),  # missing field
        ("2.0 0 0 0 0 0 0 1 5", r"expected 8 fields .* found 9"),
        ("2.0 0 zero 0 0 0 0 1", r"field 3 is not a number: 'zero'"),
        ("2.0 0 0 nan 0 0 0 1", r"field 4 is not finite"),
        ("2.0 0 0 0 0 0 0 inf", r"field 8 is not finite"),
        ("2.0 0 0 0 0 0 0.5 0.5", r"quaternion is not unit norm"),
        ("2.0 0 0 0 0 0 0 0", r"quaternion is not unit norm"),
        ("2.0 0 0 0 1 1 1 1", r"quaternion is not unit norm"),
    ],
)
def test_tum_malformed(tmp_path, line, pattern):
    # the bad line is line 3 (after a comment and a good line)
    msg = _expect(read_tum, tmp_path, "# c\n" + TUM_OK + line + "\n", pattern)
    assert "bad.txt:3:" in msg


KITTI_OK = "1 0 0 0 0 1 0 0 0 0 1 0\n"


@pytest.mark.parametrize(
    "line, pattern",
    [
        ("1 0 0 0 0 1 0 0 0 0 1", r"expected 12 fields .* found 11"),
        ("1 0 0 0 0 1 0 0 0 0 one 0", r"field 11 is not a number"),
        ("1 0 0 nan 0 1 0 0 0 0 1 0", r"field 4 is not finite"),
        ("2 0 0 0 0 1 0 0 0 0 1 0", r"not a rotation"),
        ("-1 0 0 0 0 1 0 0 0 0 1 0", r"not a rotation"),  # reflection, det -1
        ("1 0.1 0 0 0 1 0 0 0 0 1 0", r"not a rotation"),
    ],
)
def test_kitti_malformed(tmp_path, line, pattern):
    msg = _expect(read_kitti, tmp_path, KITTI_OK + KITTI_OK + line + "\n", pattern)
    assert "bad.txt:3:" in msg


def test_kitti_timestamp_count_mismatch(tmp_path):
    f = tmp_path / "poses.txt"
    f.write_text(KITTI_OK * 3)
    times = tmp_path / "times.txt"
    times.write_text("0\n0.1\n")
    with pytest.raises(ValueError, match=r"times.txt: 2 timestamps for 3 poses"):
        read_kitti(f, times)
    times.write_text("0\nx\n0.2\n")
    with pytest.raises(ValueError, match=r"times.txt:2: field 1 is not a number"):
        read_timestamps(times)


@pytest.mark.parametrize(
    "line, pattern",
    [
        ("3000,0,0,0,1,0,0", r"expected at least 8 fields .* found 7"),
        ("3000,0,0,0,1,0,0,abc", r"field 8 is not a number"),
        ("3000,0,0,NaN,1,0,0,0", r"field 4 is not finite"),
        ("3000,0,0,0,0.9,0,0,0", r"quaternion is not unit norm"),
    ],
)
def test_euroc_malformed(tmp_path, line, pattern):
    text = "#timestamp,x,y,z,qw,qx,qy,qz\n1000,0,0,0,1,0,0,0\n" + line + "\n"
    msg = _expect(read_euroc, tmp_path, text, pattern, name="bad.csv")
    assert "bad.csv:3:" in msg


def test_empty_and_unknown_format(tmp_path):
    _expect(read_tum, tmp_path, "# only a comment\n", r"no data lines")
    with pytest.raises(ValueError, match="unknown trajectory format"):
        read_trajectory(tmp_path / "bad.txt", "g2o")
    with pytest.raises(ValueError, match="needs a topic"):
        read_trajectory(tmp_path / "bad.bag", "bag")


def test_quaternion_tolerance_is_configurable(tmp_path):
    f = tmp_path / "q.txt"
    f.write_text("1 0 0 0 0 0 0 1.01\n")
    with pytest.raises(ValueError, match="not unit norm"):
        read_tum(f)
    t = read_tum(f, quat_tol=0.05)  # accepted and normalised
    np.testing.assert_allclose(t.quat_xyzw[0], [0, 0, 0, 1], atol=1e-15)


# ----------------------------------------------------------------------------- fast path
@pytest.mark.parametrize(
    "text, comma",
    [
        ("# h\n1 2 3\n4 5 6\n", False),  # direct from the file
        ("\ufeff# h\n1 2 3\n", False),  # BOM: line list
        ("1 2 3\r\n4 5 6\r\n", False),  # CRLF
        ("# h\r\n1 2 3\r\n4 5 6\r\n", False),  # CRLF after a header
        ("# h\r1 2 3\r4 5 6\r", False),  # old Mac line ends
        ("1 2 3\r\n4 5 6\r7 8 9\n", False),  # mixed
        ("1 2 3\n# middle\n\n4 5 6\n", False),  # comment below the header
        ("1,2,3\n4 , 5,6\n", False),  # commas as separators
        ("1 2 3\n,\n4 5 6\n", False),  # a line of commas has no fields: error on line 2
        ("# a\x0b1 2 3\n4 5 6\n", False),  # \x0b ends a line for str.splitlines
        ("1 2 3\n1_0 2 3\n", False),  # float() accepts underscores, loadtxt does not
        ("1 2 3\n4 5 6 # trailing\n", False),  # only whole-line comments
        ("1 2 3\n\u0661 2 3\n", False),  # non-ASCII digit (float() accepts it)
        ("1 2 3\n  \t \n4 5 6", False),  # whitespace-only line, no final newline
        ("1 2 3\n4 5\n6 7 8 9\n", False),  # 9 numbers, but lines of 2 and 4 fields
        ("1\t2 3\n4 5 6   \n", False),  # tabs and trailing spaces
        ("1 2 3\n4 nan 6\n", False),  # not finite: the careful path names the field
        ("1 2 3\n4 1e 6\n", False),  # not a number
        ("1 2 3\n4 0x10 6\n", False),  # hexadecimal is not a number for float()
        ("1 2 3\n4 5 6\x1f\n", False),  # \x1f separates fields for str.split only
        ("#t,x,y\n1,2,3,9\n4,5,6\n", True),  # extra columns ignored
        ("1,2,3\n   \n4,5,6\n", True),
        ("1 2 3\n4 5 6\n", True),  # spaces do not separate CSV fields
        ("1,,3\n", True),
    ],
)
@pytest.mark.parametrize("compiled", ["1", "0"])  # the compiled reader (if installed), NumPy's
def test_fast_path_agrees_with_careful_parser(tmp_path, monkeypatch, text, comma, compiled):
    from microlie.traj import io

    monkeypatch.setenv("MICROLIE_FAST", compiled)

    f = tmp_path / "m.txt"
    f.write_bytes(text.encode("utf-8"))

    def careful():
        numbers, rows = io._data_lines(f, comma)
        return io._to_matrix(f, numbers, rows, 3, at_least=comma, what="x")

    def fast():
        return io._read_matrix(f, 3, comma=comma, at_least=comma, what="x")[1]

    results = []
    for fn in (careful, fast):
        try:
            results.append(fn())
        except ValueError as e:
            results.append(str(e))
    if isinstance(results[0], str):
        assert results[1] == results[0]
    else:
        np.testing.assert_array_equal(results[1], results[0])


def test_euroc_rejects_space_separated_lines(tmp_path):
    # a TUM file given as EuRoC: every line is one CSV field
    _expect(read_euroc, tmp_path, TUM_OK, r"bad.csv:1: expected at least 8 fields .* found 1",
            name="bad.csv")


def test_read_tum_matches_from_arrays():
    path = data_file(EVO + "fr2_desk_ORB.txt")
    raw = np.loadtxt(path)
    from microlie.traj import Trajectory

    ref = Trajectory.from_arrays(raw[:, 1:4], raw[:, 4:8], raw[:, 0])
    np.testing.assert_array_equal(read_tum(path).poses.params, ref.poses.params)
