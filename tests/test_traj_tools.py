"""Trajectory tools: slicing, timestamp checks, preprocessing, interpolation, saved results,
and the ``microlie traj`` / ``microlie res`` commands; numbers against independent
computations (scipy's matrix exponential and logarithm, quaternion formulas, brute force)."""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from conftest import data_file
from scipy.spatial.transform import Rotation, Slerp

from microlie import traj as T
from microlie.cli import main
from microlie.data import example_paths

EVO = "trajectory/evo/"
FIX = json.loads((Path(__file__).parent / "fixtures" / "evo" / "evo_reference.json").read_text())


def run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main(list(argv), out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def random_traj(n: int, seed: int = 0, stamps: bool = True) -> T.Trajectory:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    t = np.sort(rng.uniform(0, 10, n)) if stamps else None
    return T.Trajectory.from_arrays(rng.normal(size=(n, 3)), q, t, name="r")


# ----------------------------------------------------------------------------- Trajectory
def test_slicing_masks_and_index_arrays():
    t = random_traj(20)
    p = t.positions
    np.testing.assert_array_equal(t[2:8].positions, p[2:8])
    np.testing.assert_array_equal(t[::-3].timestamps, t.timestamps[::-3])
    mask = t.timestamps > 5
    np.testing.assert_array_equal(t[mask].positions, p[mask])
    np.testing.assert_array_equal(t[[3, 1, -1]].positions, p[[3, 1, -1]])
    assert isinstance(t[0:1], T.Trajectory) and len(t[0:1]) == 1
    with pytest.raises(TypeError, match="poses\\[3\\]"):
        t[3]
    with pytest.raises(ValueError, match="boolean mask"):
        t[mask[:-1]]
    with pytest.raises(IndexError):
        t[[25]]
    with pytest.raises(ValueError, match="empty"):
        t[5:5]


def test_check_reports_repeated_and_decreasing_stamps_and_associate_warns():
    ok = T.Trajectory.from_arrays(np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)), [0, 1, 2])
    assert ok.check() == []
    bad = T.Trajectory.from_arrays(np.zeros((5, 3)), np.tile([0, 0, 0, 1.0], (5, 1)),
                                   [0, 1, 1, 0.5, 2], name="bad")
    problems = bad.check()
    assert problems == ["1 repeated timestamp (first at index 2, t = 1)",
                        "1 decreasing timestamp (first at index 3, t = 0.5)"]
    with pytest.warns(T.TimestampWarning, match="bad: 1 repeated"):
        T.associate(ok, bad)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        T.associate(ok, ok)  # no warning without problems


def test_fr2_desk_duplicate_is_reported_by_check():
    gt = T.read_tum(data_file(EVO + "fr2_desk_groundtruth.txt"))
    (problem,) = gt.check()
    assert problem.startswith("1 repeated timestamp")


def test_crop_and_downsample_follow_their_definitions():
    t = random_traj(50)
    c = t.crop(2.0, 7.0)
    keep = (t.timestamps >= 2.0) & (t.timestamps <= 7.0)
    np.testing.assert_array_equal(c.timestamps, t.timestamps[keep])
    with pytest.raises(ValueError, match="after t_end"):
        t.crop(7, 2)
    with pytest.raises(ValueError, match="no pose"):
        t.crop(20, 30)
    d = t.downsample(7)
    expected = [int(np.floor(k * 49 / 6)) for k in range(7)]  # evenly spaced, ends kept
    np.testing.assert_array_equal(d.positions, t.positions[expected])
    assert t.downsample(100) is t
    with pytest.raises(ValueError):
        t.downsample(0)


@pytest.mark.parametrize("plane, normal", [("xy", 2), ("xz", 1), ("yz", 0)])
def test_project_is_the_twist_about_the_normal(plane, normal):
    t = random_traj(40, seed=3)
    p = t.project(plane)
    assert np.all(p.positions[:, normal] == 0)
    others = [k for k in range(3) if k != normal]
    np.testing.assert_array_equal(p.positions[:, others], t.positions[:, others])
    # twist of the swing-twist decomposition: angle 2 atan2(q_n, q_w) about the normal
    q = t.quat_xyzw
    angle = 2 * np.arctan2(q[:, normal], q[:, 3])
    rotvec = np.zeros((40, 3))
    rotvec[:, normal] = angle
    expected = Rotation.from_rotvec(rotvec).as_matrix()
    np.testing.assert_allclose(p.poses.rotation().matrix(), expected, atol=1e-12)
    with pytest.raises(ValueError, match="plane"):
        t.project("xw")


def test_interpolate_se3_and_split_against_scipy():
    t = random_traj(10, seed=5)
    rng = np.random.default_rng(1)
    s = np.sort(rng.uniform(t.timestamps[0], t.timestamps[-1], 30))
    got = T.interpolate(t, s, "se3").matrices()
    mats = t.matrices()
    k = np.clip(np.searchsorted(t.timestamps, s), 1, 9)
    for m, si, ki in zip(got, s, k, strict=True):
        f = (si - t.timestamps[ki - 1]) / (t.timestamps[ki] - t.timestamps[ki - 1])
        a, b = mats[ki - 1], mats[ki]
        expected = a @ scipy.linalg.expm(f * scipy.linalg.logm(np.linalg.inv(a) @ b).real)
        np.testing.assert_allclose(m, expected, atol=1e-9)
    split = T.interpolate(t, s, "split")
    slerp = Slerp(t.timestamps, Rotation.from_quat(t.quat_xyzw))
    np.testing.assert_allclose(split.poses.rotation().matrix(), slerp(s).as_matrix(), atol=1e-12)
    for j in range(3):
        np.testing.assert_allclose(split.positions[:, j], np.interp(s, t.timestamps,
                                                                    t.positions[:, j]))
    # outside the time span: clamped to the end poses
    out = T.interpolate(t, np.array([t.timestamps[0] - 1, t.timestamps[-1] + 1]))
    np.testing.assert_allclose(out.positions, t.positions[[0, -1]], atol=1e-12)


def test_interpolated_association_pairs_exact_times():
    t = random_traj(200, seed=2)
    est = t[::7]
    est = T.Trajectory(est.poses, est.timestamps + 0.004, "est")
    r, e = T.associate(t, est, max_diff=0.1, interpolate="se3")
    np.testing.assert_array_equal(r.timestamps, e.timestamps)


def test_angle_delta_pairs_against_brute_force():
    t = random_traj(60, seed=4)
    R = t.poses.rotation().matrix()

    def angle(a, b):
        return np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1))

    pairs = T.pose_pairs(t, 150.0, "deg")
    acc, start, expected = 0.0, 0, []
    for i in range(59):
        acc += np.rad2deg(angle(R[i], R[i + 1]))
        if acc >= 150.0:
            expected.append((start, i + 1))
            acc, start = 0.0, i + 1
    np.testing.assert_array_equal(pairs, expected)
    allp = T.pose_pairs(t, 1.5, "r", all_pairs=True, rel_tol=0.05)
    expected = [(i, j) for i in range(60) for j in range(i + 1, 60)
                if abs(angle(R[i], R[j]) - 1.5) <= 0.075]
    np.testing.assert_array_equal(allp, expected)
    with pytest.raises(ValueError, match="at most 180"):
        T.pose_pairs(t, 190, "deg")


def test_merge_and_write_read_round_trips(tmp_path):
    a, b = random_traj(5, 1), random_traj(6, 2)
    m = T.merge([a, b])
    assert np.all(np.diff(m.timestamps) >= 0) and len(m) == 11
    for fmt, reader in (("tum", T.read_tum), ("euroc", T.read_euroc)):
        path = tmp_path / f"m.{fmt}"
        T.write_trajectory(path, m, fmt)
        back = reader(path)
        np.testing.assert_allclose(back.timestamps, m.timestamps, atol=1e-9)
        np.testing.assert_allclose(back.matrices(), m.matrices(), atol=1e-12)
    T.write_trajectory(tmp_path / "m.kitti", m, "kitti")
    np.testing.assert_allclose(T.read_kitti(tmp_path / "m.kitti").matrices(), m.matrices(),
                               atol=1e-12)


# ----------------------------------------------------------------------------- results
def test_saved_results_round_trip_and_res_table(tmp_path):
    gt = str(data_file(EVO + "freiburg1_xyz-groundtruth.txt"))
    runs = [("rgbd.json", "freiburg1_xyz-rgbdslam.txt", ["-a"]),
            ("drift.json", "freiburg1_xyz-rgbdslam_drift.txt", ["-a"]),
            ("none.json", "freiburg1_xyz-rgbdslam.txt", [])]
    singles = []
    for fname, est, flags in runs:
        path = tmp_path / fname
        code, out, _ = run("ape", gt, str(data_file(EVO + est)), *flags, "--json",
                           "--save-results", str(path))
        assert code == 0
        singles.append(json.loads(out))
        saved = json.loads(path.read_text())
        assert saved["stats"] == singles[-1]["stats"]
        assert len(saved["errors"]) == len(saved["timestamps"]) == singles[-1]["num_errors"]
        assert saved["options"]["align"] == ("se3" if flags else "none")
        assert saved["label"] == "APE w.r.t. translation part (m)"
        errs = np.asarray(saved["errors"])
        assert np.sqrt(np.mean(errs**2)) == pytest.approx(saved["stats"]["rmse"], rel=1e-15)
    files = [str(tmp_path / r[0]) for r in runs]
    code, out, _ = run("res", *files, "--json")
    assert code == 0
    table = json.loads(out)["results"]
    assert [row["stats"] for row in table] == [s["stats"] for s in singles]
    code, out, _ = run("res", *files)
    assert code == 0
    lines = out.splitlines()
    for fname, single in zip([r[0] for r in runs], singles, strict=True):
        row = next(ln for ln in lines if ln.startswith(fname)).split()
        assert [float(v) for v in row[2:]] == [round(single["stats"][k], 6) for k in
                                               ("rmse", "mean", "median", "std", "min", "max",
                                                "sse")]


def test_load_result_rejects_tampered_files(tmp_path):
    gt, est = (str(p) for p in example_paths())
    path = tmp_path / "r.json"
    assert run("rpe", gt, est, "--save-results", str(path))[0] == 0
    d = json.loads(path.read_text())
    assert d["pairs"] is not None and d["metric"] == "rpe"
    d["errors"][0] += 1.0
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match="do not match"):
        T.load_result(path)
    (tmp_path / "x.json").write_text("{}")
    code, _, err = run("res", str(tmp_path / "x.json"))
    assert code == 1 and "not a microlie result" in err


# ----------------------------------------------------------------------------- traj
def test_traj_info_matches_independent_numbers():
    path = data_file(EVO + "freiburg1_xyz-rgbdslam.txt")
    code, out, _ = run("traj", "tum", str(path), "--json")
    assert code == 0
    (d,) = json.loads(out)["trajectories"]
    raw = np.loadtxt(path)
    assert d["poses"] == raw.shape[0]
    assert d["duration_s"] == pytest.approx(raw[-1, 0] - raw[0, 0], rel=1e-12)
    length = np.linalg.norm(np.diff(raw[:, 1:4], axis=0), axis=1).sum()
    assert d["path_length_m"] == pytest.approx(length, rel=1e-12)
    assert d["rate_hz"] == pytest.approx((raw.shape[0] - 1) / (raw[-1, 0] - raw[0, 0]))
    code, out, _ = run("traj", str(path))
    assert code == 0 and f"poses {raw.shape[0]}, path length {length:.3f} m" in out


def test_traj_align_convert_and_merge(tmp_path):
    gt = str(data_file(EVO + "freiburg1_xyz-groundtruth.txt"))
    est = str(data_file(EVO + "freiburg1_xyz-ORB_kf_mono.txt"))
    code, out, err = run("traj", est, "--ref", gt, "-as", "--save-as", "kitti", str(tmp_path),
                         "-v")
    assert code == 0 and "Sim(3) Umeyama, scale" in out
    written = T.read_kitti(tmp_path / "freiburg1_xyz-ORB_kf_mono.kitti")
    # the written trajectory is the estimate moved by the sim3 alignment: its APE is evo's
    ref = T.read_tum(gt)
    moved = T.Trajectory(written.poses, T.read_tum(est).timestamps)
    r2, e2 = T.associate(ref, moved)
    expected = FIX["cases"]["ape_fr1_mono_sim3"]["stats"]["rmse"]
    assert T.ape(r2, e2).stats["rmse"] == pytest.approx(expected, rel=1e-8)
    # merge: two halves of a file give the file back
    full = T.read_tum(gt)
    T.write_tum(tmp_path / "a.txt", full[:1000])
    T.write_tum(tmp_path / "b.txt", full[1000:])
    code, _, _ = run("traj", str(tmp_path / "b.txt"), str(tmp_path / "a.txt"), "--merge",
                     "--save-as", "tum", str(tmp_path / "m"))
    assert code == 0
    merged = T.read_tum(tmp_path / "m" / "merged.tum")
    np.testing.assert_array_equal(merged.timestamps, full.timestamps)
    np.testing.assert_allclose(merged.matrices(), full.matrices(), atol=1e-15)


# ----------------------------------------------------------------------------- exit codes
def test_exit_codes_one_per_kind(tmp_path):
    gt, est = (str(p) for p in example_paths())
    assert run("ape", gt, est)[0] == 0
    assert run("ape", gt)[0] == 2  # missing EST: usage
    assert run("ape", gt, est, "--bogus")[0] == 2  # unknown option: usage (argparse)
    assert run("ape", gt, est, "-a", "--align_origin")[0] == 2  # conflicting options
    assert run("ape", gt, str(tmp_path / "missing.txt"))[0] == 1  # data error
    assert run("ape", gt, est, "--max-diff", "1e-9")[0] == 1  # no matching stamps
    code, out, _ = run("--version")
    assert code == 0 and out.startswith("microlie ")


def test_help_has_an_example_per_command():
    for cmd in ("ape", "rpe", "kitti", "traj", "res", "plot"):
        code, out, _ = run(cmd, "-h")
        assert code == 0
        epilog = out.split("\nexample")[1]
        assert f"  microlie {cmd} " in epilog


def test_combined_evo_flags():
    gt, est = (str(p) for p in example_paths())
    stats = {}
    for flags in (["-va"], ["-av"], ["-a", "-v"], ["--align", "se3", "-v"], ["-vas"], ["-sa"],
                  ["-as"], ["--align", "sim3"], ["-a", "-s"], ["-s"], ["--align", "scale"]):
        code, out, err = run("ape", gt, est, *flags)
        assert code == 0, err
        stats[" ".join(flags)] = out.split("\n\n")[-1]  # the statistics block
    assert stats["-va"] == stats["-av"] == stats["-a -v"] == stats["--align se3 -v"]
    assert stats["-vas"] == stats["-sa"] == stats["-as"] == stats["--align sim3"] == \
        stats["-a -s"]
    assert stats["-s"] == stats["--align scale"] != stats["-as"]
    assert "alignment transform" in run("ape", gt, est, "-va")[1]


def test_rot_label_and_sim3_scale_in_text_and_json():
    gt, est = (str(p) for p in example_paths())
    code, out, _ = run("ape", gt, est, "-r", "rot")
    assert code == 0 and out.startswith("APE w.r.t. rotation angle (deg)")
    code, out, _ = run("ape", gt, est, "-r", "rot", "--angle-unit", "rad")
    assert out.startswith("APE w.r.t. rotation angle (rad)")
    code, out, _ = run("ape", gt, est, "-as", "-v")
    ref, e = T.associate(T.read_tum(gt), T.read_tum(est))
    _, _, s = T.umeyama(e.positions, ref.positions, with_scale=True)
    assert f"scale {s:.6f}" in out and f"scale                 {s:.9f}" in out
    d = json.loads(run("ape", gt, est, "-as", "--json")[1])
    assert d["info"]["alignment_scale"] == pytest.approx(s, rel=1e-12)
    assert d["info"]["alignment_transform"]["scale"] == d["info"]["alignment_scale"]


def test_statistics_median_is_numpys_bit_for_bit():
    rng = np.random.default_rng(0)
    for n in [*range(1, 40), 1000, 1001]:
        e = np.abs(rng.standard_normal(n)) * rng.uniform(1e-3, 1e3)
        assert T.statistics(e)["median"] == float(np.median(e)), n
