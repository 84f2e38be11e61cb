"""The ``microlie`` command: numbers (vs evo fixtures / independent computations) and plots."""

from __future__ import annotations

import io
import json
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file, require

from microlie.cli import main
from microlie.data import example_paths

FIX = json.loads((Path(__file__).parent / "fixtures" / "evo" / "evo_reference.json").read_text())
CASES = FIX["cases"]
EVO = "trajectory/evo/"


def run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main(list(argv), out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def close(a: float, b: float, rtol: float = 1e-9) -> bool:
    return abs(a - b) <= rtol * abs(b) + 1e-12


def test_ape_json_matches_evo():
    gt = data_file(EVO + "freiburg1_xyz-groundtruth.txt")
    est = data_file(EVO + "freiburg1_xyz-rgbdslam.txt")
    code, out, _ = run("ape", str(gt), str(est), "--align", "se3", "--json")
    assert code == 0
    d = json.loads(out)
    ref = CASES["ape_fr1_rgbd_se3"]
    assert d["num_errors"] == ref["num_errors"]
    assert all(close(d["stats"][k], v) for k, v in ref["stats"].items())


def test_ape_text_output_and_relation_options():
    gt = data_file(EVO + "freiburg1_xyz-groundtruth.txt")
    est = data_file(EVO + "freiburg1_xyz-ORB_kf_mono.txt")
    code, out, _ = run("ape", str(gt), str(est), "-a", "sim3", "-r", "full")
    assert code == 0
    ref = CASES["ape_fr1_mono_sim3_full"]["stats"]
    lines = {ln.split()[0]: float(ln.split()[1]) for ln in out.splitlines()
             if ln.strip().split()[:1] and ln.split()[0] in ref}
    for k, v in ref.items():
        assert abs(lines[k] - v) <= 5e-7, k  # printed with 6 decimals


def test_rpe_metres_kitti_matches_evo():
    gt = data_file(EVO + "KITTI_00_gt.txt")
    est = data_file(EVO + "KITTI_00_ORB.txt")
    code, out, _ = run("rpe", str(gt), str(est), "--format", "kitti", "--delta", "10",
                       "--unit", "m", "--json")
    assert code == 0
    d = json.loads(out)
    ref = CASES["rpe_kitti_orb_m10_ortho"]  # rotations projected like our reader does
    assert d["num_errors"] == ref["num_errors"]
    assert all(close(d["stats"][k], v) for k, v in ref["stats"].items())


def test_euroc_format_and_duplicate_warning():
    gt = data_file(EVO + "V102_groundtruth.csv")
    est = data_file(EVO + "V102.txt")
    code, out, err = run("ape", str(gt), str(est), "--format", "euroc", "-a", "sim3", "--json")
    assert code == 0
    assert "repeated timestamps (GT 0, EST 4)" in err
    ref = CASES["ape_euroc_sim3"]["stats"]
    assert all(close(json.loads(out)["stats"][k], v) for k, v in ref.items())


def _kitti_devkit(g: np.ndarray, e: np.ndarray) -> tuple[float, float]:
    from test_traj_metrics import devkit_kitti

    t, r, _ = devkit_kitti(g, e)
    return t, r


def _kitti_mats(path: Path) -> np.ndarray:
    raw = np.loadtxt(path).reshape(-1, 3, 4)
    u, _, vt = np.linalg.svd(raw[:, :, :3])
    m = np.tile(np.eye(4), (len(raw), 1, 1))
    m[:, :3, :3] = u @ vt  # all dets positive here
    m[:, :3, 3] = raw[:, :, 3]
    return m


def test_kitti_command_against_devkit_restatement():
    gt = data_file(EVO + "KITTI_00_gt.txt")
    est = data_file(EVO + "KITTI_00_SPTAM.txt")
    code, out, _ = run("kitti", str(gt), str(est), "--json")
    assert code == 0
    d = json.loads(out)
    t_ref, r_ref = _kitti_devkit(_kitti_mats(gt), _kitti_mats(est))
    assert d["t_err_percent"] == pytest.approx(t_ref, rel=1e-9)
    assert d["r_err_deg_per_m"] == pytest.approx(r_ref, rel=1e-7)
    code, out, _ = run("kitti", str(gt), str(est))
    assert code == 0 and f"t_err {t_ref:.6f} %" in out


def test_example_ape_against_independent_umeyama():
    gt_path, est_path = example_paths()
    code, out, _ = run("ape", "--example", "--align", "se3", "--json")
    assert code == 0
    stats = json.loads(out)["stats"]
    g = np.loadtxt(gt_path)
    e = np.loadtxt(est_path)
    # association: every estimate stamp has a reference stamp 3 ms earlier
    j = np.array([np.argmin(np.abs(g[:, 0] - s)) for s in e[:, 0]])
    x, y = e[:, 1:4], g[j, 1:4]
    # Kabsch / Umeyama without scale, restated with NumPy
    xc, yc = x - x.mean(0), y - y.mean(0)
    u, _, vt = np.linalg.svd(yc.T @ xc)
    s = np.diag([1, 1, np.sign(np.linalg.det(u @ vt))])
    r = u @ s @ vt
    err = np.linalg.norm(y - (x @ r.T + (y.mean(0) - r @ x.mean(0))), axis=1)
    assert stats["rmse"] == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-9)
    assert stats["max"] == pytest.approx(err.max(), rel=1e-9)


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    length, kind = struct.unpack(">I4s", data[8:16])
    assert kind == b"IHDR" and length == 13
    crc = struct.unpack(">I", data[29:33])[0]
    assert crc == zlib.crc32(data[12:29])
    assert data.rstrip(b"\x00")[-8:-4] == b"IEND"
    return struct.unpack(">II", data[16:24])


def test_ape_plot_is_png_of_expected_size(tmp_path):
    require("matplotlib")
    out_png = tmp_path / "ape.png"
    code, _, err = run("ape", "--example", "--align", "se3", "--plot", str(out_png))
    assert code == 0 and "plot written" in err
    assert png_size(out_png) == (1200, 800)


def test_plot_command_png(tmp_path):
    require("matplotlib")
    gt = data_file(EVO + "freiburg1_xyz-groundtruth.txt")
    est = data_file(EVO + "freiburg1_xyz-rgbdslam.txt")
    out_png = tmp_path / "traj.png"
    code, _, _ = run("plot", str(gt), str(est), "-o", str(out_png), "--align", "se3")
    assert code == 0
    assert png_size(out_png) == (1200, 800)
    out2 = tmp_path / "rpe.png"
    code, _, _ = run("rpe", str(gt), str(est), "-r", "rot", "--plot", str(out2))
    assert code == 0 and png_size(out2) == (1200, 800)


def test_missing_matplotlib_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    code, _, err = run("ape", "--example", "--plot", str(tmp_path / "x.png"))
    assert code == 3  # missing optional dependency
    assert "pip install 'microlie[plot]'" in err


def test_malformed_file_exit_code(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0\n")
    code, _, err = run("ape", str(bad), str(bad))
    assert code == 1  # data error
    assert f"{bad}:2: expected 8 fields" in err


def test_console_script_entry_point():
    gt, est = example_paths()
    proc = subprocess.run([sys.executable, "-m", "microlie.cli", "ape", str(gt), str(est),
                           "--align", "se3", "--json"], capture_output=True, text=True,
                          check=True)
    code, out, _ = run("ape", "--example", "--align", "se3", "--json")
    assert json.loads(proc.stdout)["stats"] == json.loads(out)["stats"]


def test_kitti_with_timestamp_files_associates_by_time():
    gt = data_file(EVO + "KITTI_00_gt.txt")
    est = data_file(EVO + "KITTI_00_ORB.txt")
    times = data_file(EVO + "KITTI_00_gt_times.txt")
    code, out, _ = run("ape", str(gt), str(est), "-f", "kitti", "--gt-times", str(times),
                       "--est-times", str(times), "-a", "se3", "--json")
    assert code == 0
    d = json.loads(out)
    assert d["info"]["pairs"] == 4541
    ref = CASES["ape_kitti_orb_se3"]["stats"]
    assert all(close(d["stats"][k], v) for k, v in ref.items())
