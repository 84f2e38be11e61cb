"""The compiled reader of trajectory files (``microlie._c._text.parse_table``):
every value it returns is bit-identical to Python's ``float`` of the field (the independent
reference, also what ``numpy.loadtxt`` and the careful line-by-line path use), everything outside
its plain grammar is handed back (``None``) to the NumPy / careful paths, so the readers give the
same matrices and the same ``file:line`` errors with and without it."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file, require
from hypothesis import given, settings
from hypothesis import strategies as st

EVO = "trajectory/evo/"


def _parse():
    return require("microlie._c._text").parse_table


def _bits(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64).view(np.int64)


def _float_matrix(rows: list[list[str]]) -> np.ndarray:
    return np.array([[float(f) for f in r] for r in rows], dtype=np.float64)


# Hard fields: Clinger's fast path at its edges (2^53, 10^22, 19 digits), past them (17-20
# significant digits, exponents beyond 22, subnormals, halfway cases), signs, zeros, forms
# float() accepts (".5", "5.", "1E5", "+1").
HARD = [
    "0", "-0", "+0", "0.0", "-0.0", "-0.000000000", "1", "-1", "+1.5", ".5", "-.5", "5.",
    "1e5", "1E5", "1e+5", "1e-5", "1.e5", "0.1", "0.2", "0.3", "1e22", "1e23", "9e22",
    "1e-22", "1e-23", "9007199254740992", "9007199254740993", "9007199254740994",
    "9007199254740992.5", "900719925474099.3", "1600000000.033333", "1311868164.363181",
    "1.403715529112143517e+09", "-6.151000000000000217e-02", "1.000000000000000000e+00",
    "2.2250738585072014e-308", "4.9e-324", "2e-324", "1.7976931348623157e308",
    "0.1000000000000000055511151231257827", "123456789012345678901234567890",
    "0.000000000000000000000000000001", "00000000000000000000001.5", "1.0000000000000000001",
    "2.5e-16", "5.551115e-17", "-4.440892e-16", "9.043680e-12", "1e0000000000000000001",
    "0.000017498", "999999999999999999", "9999999999999999999", "18446744073709551616",
    "7.2057594037927933e16", "1448997445238699", "3.0517578125e-05", "8.98846567431158e307",
]


def test_hard_fields_bit_identical_to_float():
    parse = _parse()
    rows = [HARD[i:i + 4] for i in range(0, len(HARD) - len(HARD) % 4, 4)]
    text = "\n".join(" ".join(r) for r in rows) + "\n"
    got = parse(text.encode(), 4, False, False)
    assert got is not None
    np.testing.assert_array_equal(_bits(got), _bits(_float_matrix(rows)))


_digits = st.text("0123456789", min_size=0, max_size=24)
_field = st.builds(
    lambda sign, a, b, dot, e, es, ed: (sign + a + (("." + b) if dot else "")
                                        + ((e + es + ed) if ed else "")),
    st.sampled_from(["", "-", "+"]), _digits, _digits, st.booleans(),
    st.sampled_from(["e", "E"]), st.sampled_from(["", "-", "+"]),
    st.text("0123456789", min_size=0, max_size=3),
).filter(lambda f: any(c.isdigit() for c in f.split("e")[0].split("E")[0]))


@settings(max_examples=300, deadline=None)
@given(st.lists(_field, min_size=3, max_size=3))
def test_random_fields_bit_identical_to_float(fields):
    parse = _parse()
    ref = [float(f) for f in fields]
    got = parse((" ".join(fields) + "\n").encode(), 3, False, False)
    if not np.isfinite(ref).all():
        assert got is None  # the careful path reports the non-finite field
    else:
        np.testing.assert_array_equal(_bits(got), _bits([ref]))


@pytest.mark.parametrize("name, ncols, comma, at_least", [
    ("fr2_desk_groundtruth.txt", 8, False, False),  # 4-decimal stamps, comment header
    ("fr2_desk_ORB.txt", 8, False, False),
    ("V102.txt", 8, False, False),  # %.18e: 19 significant digits, the slow path
    ("KITTI_00_gt.txt", 12, False, False),  # %e
    ("KITTI_00_ORB.txt", 12, False, False),
    ("KITTI_00_gt_times.txt", 1, False, False),
    ("V102_groundtruth.csv", 8, True, True),  # CSV, 17 columns, integer nanoseconds
])
def test_shared_files_bit_identical_to_loadtxt(name, ncols, comma, at_least):
    parse = _parse()
    path = data_file(EVO + name)
    got = parse(path.read_bytes(), ncols, comma, at_least)
    ref = np.loadtxt(path, ndmin=2, delimiter="," if comma else None,
                     usecols=range(ncols) if at_least else None)
    assert got is not None and got.shape == ref.shape
    np.testing.assert_array_equal(_bits(got), _bits(ref))


@pytest.mark.parametrize("text, ncols, comma, at_least", [
    ("1 2\n3\n", 2, False, False),  # too few fields
    ("1 2 3\n", 2, False, False),  # too many
    ("1 2\n3 x\n", 2, False, False),
    ("1 2\n3 4x\n", 2, False, False),
    ("1 2\n3 1_0\n", 2, False, False),  # float() takes '_'; the careful path reads it
    ("1 2\n3 nan\n", 2, False, False),
    ("1 2\n3 inf\n", 2, False, False),
    ("1 2\n3 1e999\n", 2, False, False),  # overflows to inf
    ("1 2\n3 -\n", 2, False, False),
    ("1 2\n3 .\n", 2, False, False),
    ("1 2\n3 1e\n", 2, False, False),
    ("1 2\n3 --1\n", 2, False, False),
    ("1,2\n", 2, False, False),  # commas in a space-separated file: the Python paths
    ("1 2\r3 4\n", 2, False, False),  # '\r' alone is a line break of str.splitlines
    ("1 2\x0b3 4\n", 2, False, False),
    ("1 2\x1f\n", 2, False, False),
    ("1 2\x00\n", 2, False, False),
    ("1 \u0661\n", 2, False, False),  # non-ASCII
    ("# only comments\n\n", 2, False, False),  # no data line
    ("", 2, False, False),
    ("1,,2\n", 2, True, False),  # empty CSV field
    ("1,2,\n", 2, True, False),
    ("1,2 3\n", 2, True, False),
    ("1 2\n", 2, True, True),  # spaces do not separate CSV fields
])
def test_outside_the_grammar_is_handed_back(text, ncols, comma, at_least):
    assert _parse()(text.encode("utf-8"), ncols, comma, at_least) is None


@pytest.mark.parametrize("text, ncols, comma, at_least, expected", [
    ("# c\n  # indented\n% matlab\n\n \t \n1 2\r\n3\t4  \n", 2, False, False, [[1, 2], [3, 4]]),
    ("1 2", 2, False, False, [[1, 2]]),  # no final newline
    ("#t,x\n1 , 2,junk,\n3,4\n", 2, True, True, [[1, 2], [3, 4]]),  # fields after ncols unread
    ("1,2\n", 2, True, False, [[1, 2]]),
])
def test_comments_blank_lines_separators(text, ncols, comma, at_least, expected):
    got = _parse()(text.encode(), ncols, comma, at_least)
    np.testing.assert_array_equal(got, expected)


def test_readers_same_with_and_without_the_compiled_reader(monkeypatch):
    _parse()
    from microlie.traj import read_euroc, read_kitti, read_tum

    cases = [(read_tum, "fr2_desk_groundtruth.txt"), (read_tum, "V102.txt"),
             (read_kitti, "KITTI_00_gt.txt"), (read_euroc, "V102_groundtruth.csv")]
    for reader, name in cases:
        path = data_file(EVO + name)
        fast = reader(path)
        monkeypatch.setenv("MICROLIE_FAST", "0")
        slow = reader(path)
        monkeypatch.delenv("MICROLIE_FAST")
        np.testing.assert_array_equal(_bits(fast.poses.params), _bits(slow.poses.params))
        if slow.timestamps is not None:
            np.testing.assert_array_equal(_bits(fast.timestamps), _bits(slow.timestamps))


def test_error_names_the_line_after_the_compiled_reader(tmp_path):
    _parse()
    from microlie.traj import read_tum

    f = tmp_path / "q.txt"
    f.write_text("# c\n\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0.5 0.5\n")  # read by the C path
    with pytest.raises(ValueError, match=r"q.txt:4: quaternion is not unit norm"):
        read_tum(f)


def test_bad_arguments():
    parse = _parse()
    with pytest.raises(ValueError, match="ncols"):
        parse(b"1\n", 0, False, False)
    with pytest.raises(TypeError):
        parse("1\n", 1, False, False)  # str, not bytes


@pytest.mark.parametrize("text", [b"", b"\xef\xbb\xbf", b"\xef\xbb\xbf1 0 0 0 0 0 0 1\n"])
def test_empty_file_and_byte_order_mark(tmp_path, monkeypatch, text):
    _parse()
    from microlie.traj import read_tum

    f = tmp_path / "e.txt"
    f.write_bytes(text)  # an empty file cannot be memory-mapped: read instead
    results = []
    for env in ("1", "0"):
        monkeypatch.setenv("MICROLIE_FAST", env)
        try:
            results.append(read_tum(f).poses.params.tolist())
        except ValueError as e:
            results.append(str(e))
    assert results[0] == results[1]
    assert (results[0] == [[0, 0, 0, 0, 0, 0, 1.0]]) == (len(text) > 3)
