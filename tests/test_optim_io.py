"""g2o and TORO files: parsing against independent counts and GTSAM's errors, the information
order with full cross terms (gtsam PR #1310), round trips, and malformed input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file
from scipy.linalg import logm
from scipy.spatial.transform import Rotation

from microlie import SE2, SE3
from microlie.optim.io.g2o import read_g2o, write_g2o
from microlie.optim.io.pose_graph import PoseGraph
from microlie.optim.io.toro import read_toro, write_toro

FIX = Path(__file__).resolve().parent / "fixtures" / "g2o"
GTSAM = json.loads((FIX / "gtsam_reference.json").read_text())

# ../shared/data/README.md: counts from an independent reader, and "GTSAM error at start (from
# the file's vertices)" computed with GTSAM 4.3.0's readG2o, with the digits printed there
SHARED = [
    ("pose_graph/sphere2500.g2o", SE3, 2500, 4949, "1305657.7"),
    ("pose_graph/parking-garage.g2o", SE3, 1661, 6275, "8363.60"),
    ("pose_graph/smallGrid3D.g2o", SE3, 125, 297, "83894.3"),
    ("pose_graph/tinyGrid3D.g2o", SE3, 9, 11, "143.318"),
    ("pose_graph/input_M3500_g2o.g2o", SE2, 3500, 5453, "1.31736e6"),
    ("pose_graph/ais2klinik.g2o", SE2, 15115, 16727, "652822"),
    ("pose_graph/MIT.g2o", SE2, 808, 827, "3.54866e9"),
    ("pose_graph/gtsam/pose3example.txt", SE3, 5, 6, "64941.32"),
    ("pose_graph/gtsam/pose2example.txt", SE2, 11, 12, "3.43010"),
    ("pose_graph/manhattan.g2o", SE2, 3500, 5453, None),
    ("pose_graph/CSAIL.g2o", SE2, 1045, 1172, None),
    ("pose_graph/kitti_00.g2o", SE2, 4541, 4677, None),
]


@pytest.mark.parametrize("rel, G, nv, ne, start", SHARED, ids=[s[0].split("/")[-1] for s in SHARED])
def test_shared_graphs_parse_with_gtsam_start_error(rel, G, nv, ne, start):
    g = read_g2o(data_file(rel))
    assert g.group is G and g.num_vertices == nv and g.num_edges == ne
    assert np.array_equal(g.ids, np.arange(nv))  # README: ids contiguous from 0
    if start is None:
        assert g.poses is None
        return
    mantissa, _, exp = start.partition("e")
    decimals = len(mantissa.partition(".")[2])
    half_unit = 0.5 * 10.0 ** (int(exp or 0) - decimals)  # of the last printed digit
    assert abs(g.cost() - float(start)) <= half_unit


# ---------------------------------------------------------------------- information order
def _hand_cost_se3(path: Path) -> float:
    """GTSAM's error built by hand: 4x4 matrices, scipy's logm, the 6x6 information from the
    21 numbers by explicit loops (no microlie code)."""
    V, total = {}, 0.0

    def T(vals):
        x, y, z, qx, qy, qz, qw = vals
        q = np.array([qx, qy, qz, qw]) / np.linalg.norm([qx, qy, qz, qw])
        M = np.eye(4)
        M[:3, :3] = Rotation.from_quat(q).as_matrix()
        M[:3, 3] = [x, y, z]
        return M

    for line in path.read_text().splitlines():
        tok = line.split()
        if tok[0] == "VERTEX_SE3:QUAT":
            V[int(tok[1])] = T([float(v) for v in tok[2:9]])
        else:
            i, j = int(tok[1]), int(tok[2])
            Z = T([float(v) for v in tok[3:10]])
            w = [float(v) for v in tok[10:31]]
            Om, k = np.zeros((6, 6)), 0
            for r in range(6):
                for c in range(r, 6):
                    Om[r, c] = Om[c, r] = w[k]
                    k += 1
            L = np.real(logm(np.linalg.inv(Z) @ np.linalg.inv(V[i]) @ V[j]))
            rv = np.array([L[0, 3], L[1, 3], L[2, 3], L[2, 1], L[0, 2], L[1, 0]])  # (rho, phi)
            total += 0.5 * rv @ Om @ rv
    return total


def test_full_6x6_information_matches_gtsam_and_hand_built_factor(tmp_path):
    path = FIX / "cross_terms_se3.g2o"
    g = read_g2o(path)
    info = g.information
    assert np.all(np.abs(info[:, :3, 3:]) > 1e-3)  # the cross terms are really there
    ref = GTSAM["cross_terms_se3.g2o"]["error_at_file_vertices"]
    assert g.cost() == pytest.approx(ref, rel=1e-12)
    assert g.cost() == pytest.approx(_hand_cost_se3(path), rel=1e-10)
    # read, write, read: the same graph and cost
    out = tmp_path / "again.g2o"
    write_g2o(out, g)
    h = read_g2o(out)
    assert np.array_equal(h.information, g.information)
    assert np.array_equal(h.i, g.i) and np.array_equal(h.j, g.j)
    np.testing.assert_allclose(h.measurements.params, g.measurements.params, rtol=0, atol=1e-15)
    np.testing.assert_allclose(h.poses.params, g.poses.params, rtol=0, atol=1e-15)
    assert h.cost() == pytest.approx(ref, rel=1e-12)


def test_full_3x3_information_g2o_and_toro_orders_agree_with_gtsam(tmp_path):
    a = read_g2o(FIX / "cross_terms_se2.g2o")
    b = read_toro(FIX / "cross_terms_se2.graph")
    ref = GTSAM["cross_terms_se2.g2o"]["error_at_file_vertices"]
    assert a.cost() == pytest.approx(ref, rel=1e-12)
    assert np.array_equal(a.information, b.information)
    assert np.all(np.abs(a.information[:, :2, 2]) > 1e-3)
    assert b.cost() == pytest.approx(ref, rel=1e-12)
    for write, read in ((write_g2o, read_g2o), (write_toro, read_toro)):
        out = tmp_path / "again.txt"
        write(out, b)
        c = read(out)
        assert np.array_equal(c.information, a.information)
        np.testing.assert_allclose(c.poses.params, a.poses.params, atol=1e-15)
        assert c.cost() == pytest.approx(ref, rel=1e-12)


def test_toro_edge2_information_order(tmp_path):
    p = tmp_path / "g.graph"
    p.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 11 12 22 33 13 23\n")
    np.testing.assert_array_equal(read_toro(p).information[0],
                                  [[11, 12, 13], [12, 22, 23], [13, 23, 33]])


def test_toro_3d_roll_pitch_yaw(tmp_path):
    roll, pitch, yaw = 0.3, -0.4, 2.5
    p = tmp_path / "g.graph"
    info = " ".join(["1 0 0 0 0 0", "2 0 0 0 0", "3 0 0 0", "4 0 0", "5 0", "6"])
    p.write_text(f"VERTEX3 0 0 0 0 0 0 0\nVERTEX3 1 1 2 3 {roll} {pitch} {yaw}\n"
                 f"EDGE3 0 1 1 2 3 {roll} {pitch} {yaw} {info}\n")
    g = read_toro(p)

    def rot(axis, a):
        c, s = np.cos(a), np.sin(a)
        i, j = [(1, 2), (0, 2), (0, 1)][axis]
        M = np.eye(3)
        M[i, i] = M[j, j] = c
        M[i, j], M[j, i] = (-s, s) if axis != 1 else (s, -s)
        return M

    R = rot(2, yaw) @ rot(1, pitch) @ rot(0, roll)
    np.testing.assert_allclose(np.asarray(g.poses[1].matrix())[:3, :3], R, atol=1e-14)
    np.testing.assert_allclose(g.information[0], np.diag([1, 2, 3, 4, 5, 6.0]))
    assert g.cost() == pytest.approx(0.0, abs=1e-24)
    out = tmp_path / "again.graph"
    write_toro(out, g)
    np.testing.assert_allclose(read_toro(out).poses.params, g.poses.params, atol=1e-15)


def test_fix_lines_and_files_without_vertices(tmp_path):
    p = tmp_path / "g.g2o"
    p.write_text("# a comment\n\nEDGE_SE2 3 5 1 0 0 1 0 0 1 0 1\nEDGE_SE2 5 7 1 0 0 1 0 0 1 0 1\n")
    g = read_g2o(p)
    assert g.poses is None and g.ids.tolist() == [3, 5, 7] and g.fixed.size == 0
    with pytest.raises(ValueError, match="no poses"):
        g.cost()
    p.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
                 "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\nFIX 2 0\n")
    g = read_g2o(p)
    assert g.fixed.tolist() == [0, 2]
    write_g2o(tmp_path / "w.g2o", g)
    assert read_g2o(tmp_path / "w.g2o").fixed.tolist() == [0, 2]
    with pytest.raises(ValueError, match="cannot hold fixed"):
        write_toro(tmp_path / "w.graph", g)


def test_vertices_in_any_order_are_sorted(tmp_path):
    p = tmp_path / "g.g2o"
    p.write_text("VERTEX_SE2 1 1 0 0.5\nVERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0.5 1 0 0 1 0 1\n")
    g = read_g2o(p)
    assert g.ids.tolist() == [0, 1]
    np.testing.assert_allclose(g.poses[1].params, [1, 0, np.cos(0.5), np.sin(0.5)])
    assert g.cost() == pytest.approx(0.0, abs=1e-28)


# ---------------------------------------------------------------------- malformed input
V2 = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
E2 = "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
V3 = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n"
INFO6 = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"

BAD = [
    (V2 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0\n", r":3: EDGE_SE2 needs 11 fields .* got 10"),
    (V2 + "EDGE_SE2 0 1 1 0 zero 1 0 0 1 0 1\n", r":3: EDGE_SE2: field 'zero' is not a number"),
    (V2 + "EDGE_SE2 0 1 1 0 nan 1 0 0 1 0 1\n", r":3: EDGE_SE2: non-finite value 'nan'"),
    ("VERTEX_SE2 0 0 inf 0\n" + E2, r":1: VERTEX_SE2: non-finite value 'inf'"),
    (V2 + "EDGE_SE2 0 x 1 0 0 1 0 0 1 0 1\n", r":3: EDGE_SE2: vertex id 'x' is not an integer"),
    (V2 + "EDGE_SE2 0 -1 1 0 0 1 0 0 1 0 1\n", r":3: EDGE_SE2: negative vertex id -1"),
    (V2 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0\nVERTEX_SE2 2 x 0 0\n",  # the first bad line wins
     r":3: EDGE_SE2 needs 11 fields"),
    (V2 + E2 + "EDGE_SE2 0 1.5 1 0 0 1 0 0 1 0 1\n",
     r":4: EDGE_SE2: vertex id '1.5' is not an integer"),
    (V2 + E2 + E2 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1 7\n", r":5: EDGE_SE2 needs 11 fields"),
    (V2 + "VERTEX_XY 2 0 0\n" + E2, r":3: unknown tag 'VERTEX_XY' in a g2o file"),
    (V2 + "EDGE_SE2 0 2 1 0 0 1 0 0 1 0 1\n",
     r":3: edge 0 -> 2 refers to vertex 2, which has no vertex line"),
    (V2 + "EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n",
     r":3: information matrix is not positive definite"),
    (V2 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 0\n",
     r":3: information matrix is not positive definite"),
    (V2 + "EDGE_SE2 1 1 1 0 0 1 0 0 1 0 1\n", r":3: edge from vertex 1 to itself"),
    (V2 + "VERTEX_SE2 1 2 0 0\n" + E2, r":3: vertex 1 is defined twice \(first on line 2\)"),
    (V2 + E2 + "FIX 4\n", r":4: FIX names vertex 4"),
    (V2 + E2 + "FIX\n", r":4: FIX needs at least one vertex id"),
    (V2 + E2 + V3,
     r":4: VERTEX_SE3:QUAT is a SE3 line but line 1 \(VERTEX_SE2\) made this a SE2 graph"),
    (V3 + f"EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 0.5 {INFO6}\n", r":3: measurement: quaternion .* norm"),
    (V2, r"no edges"),
    ("# nothing\n", r"no vertex or edge lines"),
]


@pytest.mark.parametrize("text, message", BAD)
def test_malformed_g2o_lines_name_file_and_line(tmp_path, text, message):
    p = tmp_path / "bad.g2o"
    p.write_text(text)
    with pytest.raises(ValueError, match=message) as e:
        read_g2o(p)
    assert str(p) in str(e.value)


def test_toro_reader_refuses_g2o_tags(tmp_path):
    p = tmp_path / "bad.graph"
    p.write_text(V2)
    with pytest.raises(ValueError, match=r":1: unknown tag 'VERTEX_SE2' in a TORO file"):
        read_toro(p)


def test_pose_graph_checks_its_fields():
    Z = SE2.identity((1,))
    with pytest.raises(ValueError, match="information must have shape"):
        PoseGraph(SE2, ids=np.arange(2), poses=None, i=[0], j=[1], measurements=Z,
                  information=np.eye(3))
    g = PoseGraph(SE2, ids=np.array([2, 4]), poses=None, i=[2], j=[4], measurements=Z,
                  information=np.eye(3)[None])
    assert g.index([4, 2]).tolist() == [1, 0]
    with pytest.raises(ValueError, match="vertex id 3 is not in this graph"):
        g.index(3)
    with pytest.raises(ValueError, match="vertex id 5"):
        PoseGraph(SE2, ids=np.arange(2), poses=None, i=[0], j=[5], measurements=Z,
                  information=np.eye(3)[None])


@pytest.mark.parametrize("name", ["parking-garage.g2o", "ais2klinik.g2o", "sphere2500.g2o"])
def test_compiled_bulk_reader_reads_the_same_bits(name, monkeypatch):
    # the compiled table reader (microlie._c._text) against the NumPy bulk path
    from microlie._fast import text_parser

    if text_parser() is None:
        pytest.skip("microlie._c._text not built")
    path = data_file(f"pose_graph/{name}")
    a = read_g2o(path)
    monkeypatch.setenv("MICROLIE_FAST", "0")
    b = read_g2o(path)
    np.testing.assert_array_equal(np.asarray(a.i), np.asarray(b.i))
    np.testing.assert_array_equal(np.asarray(a.ids), np.asarray(b.ids))
    np.testing.assert_array_equal(np.asarray(a.poses.params), np.asarray(b.poses.params))
    np.testing.assert_array_equal(np.asarray(a.measurements.params),
                                  np.asarray(b.measurements.params))
    np.testing.assert_array_equal(a.information, b.information)


@pytest.mark.parametrize("fast", ["1", "0"])
def test_ids_must_be_digits_on_every_path(tmp_path, monkeypatch, fast):
    monkeypatch.setenv("MICROLIE_FAST", fast)
    p = tmp_path / "g.g2o"
    p.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1.0 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    with pytest.raises(ValueError, match=":2"):
        read_g2o(p)
