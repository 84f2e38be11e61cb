"""Plots: every option is checked on the PNG the command writes (pixels of the drawn path,
mapped back to data coordinates with the figure's own transforms) and on the figure's artists
(axis labels, line data, time origin, angle branches); and the caller's matplotlib state is
left alone."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
from conftest import data_file, require

from microlie import traj as T
from microlie.cli import main
from microlie.traj import plot as P

EVO = "trajectory/evo/"
BLUE = np.array([0x1F, 0x77, 0xB4]) / 255.0  # matplotlib's first colour (tab:blue)


@pytest.fixture(autouse=True)
def _mpl():
    require("matplotlib")


def run(*argv: str) -> None:
    err = io.StringIO()
    assert main(list(argv), out=io.StringIO(), err=err) == 0, err.getvalue()


def read_png(path) -> np.ndarray:
    import matplotlib.image

    img = matplotlib.image.imread(str(path))[:, :, :3]
    assert img.shape == (800, 1200, 3)
    return img


def axes(fig, gid):
    (ax,) = [a for a in fig.axes if a.get_gid() == gid]
    return ax


def drawn_extent(img: np.ndarray, fig, ax, select) -> tuple[np.ndarray, np.ndarray]:
    """Data-coordinate bounding box of the pixels ``select(rgb) -> bool`` inside ``ax``
    (its legend masked out)."""
    fig.canvas.draw()
    h = img.shape[0]
    box = ax.get_window_extent()
    rows, cols = np.nonzero(select(img))
    xd, yd = cols + 0.5, h - rows - 0.5  # display coordinates (origin bottom left)
    inside = (xd > box.x0 + 2) & (xd < box.x1 - 2) & (yd > box.y0 + 2) & (yd < box.y1 - 2)
    leg = ax.get_legend()
    if leg is not None:
        lb = leg.get_window_extent()
        inside &= ~((xd >= lb.x0) & (xd <= lb.x1) & (yd >= lb.y0) & (yd <= lb.y1))
    pts = ax.transData.inverted().transform(np.column_stack([xd[inside], yd[inside]]))
    return pts.min(axis=0), pts.max(axis=0)


def is_blue(img):
    return np.abs(img - BLUE).max(axis=2) < 0.08


def is_saturated(img):
    return img.max(axis=2) - img.min(axis=2) > 0.35


def kitti():
    return (T.read_kitti(data_file(EVO + "KITTI_00_gt.txt")),
            T.read_kitti(data_file(EVO + "KITTI_00_ORB.txt")))


@pytest.mark.parametrize("mode", [None, "xy", "xz", "yz", "zy"])
def test_plot_mode_shows_the_path_on_that_plane(tmp_path, mode):
    gt, est = kitti()
    png = tmp_path / "k.png"
    extra = [] if mode is None else ["--plot-mode", mode]
    run("plot", "kitti", str(gt.name), str(est.name), "-o", str(png), *extra)
    mode = mode or "xz"  # the KITTI default: its ground plane
    fig = P.plot_trajectories([gt, est], labels=[gt.name, est.name], plot_mode=mode)
    P.save(fig, tmp_path / "lib.png")
    img = read_png(png)
    np.testing.assert_array_equal(img, read_png(tmp_path / "lib.png"))  # the command's figure
    ax = axes(fig, "path")
    assert (ax.get_xlabel(), ax.get_ylabel()) == (f"{mode[0]} (m)", f"{mode[1]} (m)")
    dims = ["xyz".index(c) for c in mode]
    lo, hi = drawn_extent(img, fig, ax, is_blue)
    p = est.positions[:, dims]
    span = p.max(axis=0) - p.min(axis=0)
    px = np.abs(np.diff(ax.transData.inverted().transform([[0, 0], [2, 2]]), axis=0))[0]
    tol = px + 0.01 * span
    assert np.all(np.abs(lo - p.min(axis=0)) <= tol), (lo, p.min(axis=0), tol)
    assert np.all(np.abs(hi - p.max(axis=0)) <= tol), (hi, p.max(axis=0), tol)


def test_plot_mode_xyz_is_3d(tmp_path):
    gt, est = kitti()
    fig = P.plot_trajectories([gt, est], plot_mode="xyz")
    ax = axes(fig, "path")
    assert ax.name == "3d" and ax.get_zlabel() == "z (m)"
    run("plot", "kitti", str(gt.name), str(est.name), "-o", str(tmp_path / "k.png"),
        "--plot-mode", "xyz")
    P.save(fig, tmp_path / "lib.png")
    np.testing.assert_array_equal(read_png(tmp_path / "k.png"), read_png(tmp_path / "lib.png"))


def test_euroc_csv_and_tum_estimate_share_one_time_origin(tmp_path):
    gt_path, est_path = data_file(EVO + "V102_groundtruth.csv"), data_file(EVO + "V102.txt")
    png = tmp_path / "e.png"
    run("plot", "--format", "euroc", str(gt_path), str(est_path), "-o", str(png))  # est: TUM
    run("plot", str(gt_path), str(est_path), "--ref-format", "euroc", "--est-format", "tum",
        "-o", str(tmp_path / "e2.png"))
    img = read_png(png)
    np.testing.assert_array_equal(img, read_png(tmp_path / "e2.png"))
    gt, est = T.read_euroc(gt_path), T.read_tum(est_path)
    offset = est.timestamps[0] - gt.timestamps[0]
    assert offset > 4.0  # the estimate starts 4.2 s after the ground truth
    fig = P.plot_trajectories([gt, est], labels=[str(gt_path), str(est_path)])
    ax = axes(fig, "x")
    ref_line, est_line = ax.get_lines()
    assert ref_line.get_xdata()[0] == 0.0
    assert est_line.get_xdata()[0] == pytest.approx(offset, abs=1e-9)
    assert ax.get_xlabel() == "" and axes(fig, "z").get_xlabel() == "t (s)"
    # in the PNG the estimate's x(t) curve starts at t = offset, not at 0
    lo, hi = drawn_extent(img, fig, ax, is_blue)
    px = abs(np.diff(ax.transData.inverted().transform([[0, 0], [2, 0]])[:, 0])[0])
    assert lo[0] == pytest.approx(offset, abs=px + 0.2)
    assert hi[0] == pytest.approx(est.timestamps[-1] - gt.timestamps[0], abs=px + 0.2)


def test_roll_pitch_yaw_of_agreeing_trajectories_overlap(tmp_path):
    gt, est = kitti()
    est_aligned, _ = T.align(gt, est, "se3")  # KITTI: paired by index
    fig = P.plot_trajectories([gt, est_aligned], plot_mode="xz")
    # the command's PNG is this figure
    run("plot", "kitti", str(gt.name), str(est.name), "-a", "-o", str(tmp_path / "k.png"))
    P.save(fig, tmp_path / "lib.png")
    np.testing.assert_array_equal(read_png(tmp_path / "k.png"), read_png(tmp_path / "lib.png"))
    for k, gid in enumerate(("roll", "pitch", "yaw")):
        ref_line, est_line = axes(fig, gid).get_lines()
        d = np.abs(est_line.get_ydata() - ref_line.get_ydata())
        # overlap except for brief 180-degree flips of roll and yaw where pitch passes +-90
        assert np.median(d) < 2.0 and np.mean(d < 10) > 0.95, gid
        if gid != "pitch":  # unwrapping each trajectory on its own puts them 360+ apart
            alone = np.rad2deg(np.unwrap(est_aligned.euler("xyz")[:, k]) -
                               np.unwrap(gt.euler("xyz")[:, k]))
            assert np.abs(alone).max() > 300, gid
    # each drawn curve is its own orientation's angle (up to multiples of 360)
    rpy = np.rad2deg(est_aligned.euler("xyz"))
    wrapped = (axes(fig, "yaw").get_lines()[1].get_ydata() - rpy[:, 2] + 180) % 360 - 180
    np.testing.assert_allclose(wrapped, 0, atol=1e-9)


def test_error_plot_colours_the_path_on_the_chosen_plane(tmp_path):
    gt, est = (str(data_file(EVO + f)) for f in ("KITTI_00_gt.txt", "KITTI_00_ORB.txt"))
    png = tmp_path / "ape.png"
    run("ape", "kitti", gt, est, "-as", "--plot", str(png))  # default plane: xz
    res = T.evaluate_ape(T.read_kitti(gt), T.read_kitti(est), align="sim3")
    fig = P.plot_error(res, plot_mode="xz")
    P.save(fig, tmp_path / "lib.png")
    img = read_png(png)
    np.testing.assert_array_equal(img, read_png(tmp_path / "lib.png"))
    ax = axes(fig, "path")
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (m)", "z (m)")
    (sc,) = ax.collections
    np.testing.assert_array_equal(sc.get_offsets(), res.est.positions[:, [0, 2]])
    np.testing.assert_array_equal(sc.get_array(), res.errors)
    lo, hi = drawn_extent(img, fig, ax, is_saturated)
    p = res.est.positions[:, [0, 2]]
    tol = 0.02 * (p.max(axis=0) - p.min(axis=0))
    assert np.all(np.abs(lo - p.min(axis=0)) <= tol), (lo, p.min(axis=0), tol)
    assert np.all(np.abs(hi - p.max(axis=0)) <= tol), (hi, p.max(axis=0), tol)
    assert axes(fig, "error").get_ylabel() == "translation part (m)"


def test_res_and_traj_plots(tmp_path):
    gt = str(data_file(EVO + "fr2_desk_groundtruth.txt"))
    files = []
    for k, est in enumerate(("fr2_desk_ORB.txt", "fr2_desk_ORB_kf_mono.txt")):
        files.append(str(tmp_path / f"r{k}.json"))
        run("ape", gt, str(data_file(EVO + est)), "-as", "--save-results", files[-1])
    run("res", *files, "--plot", str(tmp_path / "res.png"))
    results = [T.load_result(f) for f in files]
    fig = P.plot_results(results, ["r0.json", "r1.json"])
    P.save(fig, tmp_path / "lib.png")
    np.testing.assert_array_equal(read_png(tmp_path / "res.png"), read_png(tmp_path / "lib.png"))
    lines = axes(fig, "errors").get_lines()
    for line, r in zip(lines, results, strict=True):
        np.testing.assert_array_equal(line.get_ydata(), r.errors)
    heights = [b.get_height() for b in axes(fig, "stats").patches]
    assert heights[:4] == [results[0].stats[k] for k in ("rmse", "mean", "median", "std")]
    run("traj", str(data_file(EVO + "fr2_desk_ORB.txt")), "--ref", gt, "-a", "--plot",
        str(tmp_path / "traj.png"), "--plot-mode", "yz")
    img = read_png(tmp_path / "traj.png")
    assert is_blue(img).sum() > 1000


def test_plots_leave_the_callers_matplotlib_state_alone(tmp_path):
    code = f"""
import sys, matplotlib
matplotlib.use("svg")
rc = dict(matplotlib.rcParams)
from microlie.traj import plot, read_tum
from microlie.data import example_paths
fig = plot.plot_trajectories([read_tum(p) for p in example_paths()], plot_mode="xz")
plot.save(fig, {str(tmp_path / 'x.png')!r})
assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
assert "matplotlib.pyplot" not in sys.modules
assert dict(matplotlib.rcParams) == rc
print("ok")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "ok"
    assert read_png(tmp_path / "x.png").shape == (800, 1200, 3)
