"""Issue 19 item 18: evo's spellings and evo_res's outputs.

References (never our own output):
* evo 1.38.1's statistics in ``tests/fixtures/evo/evo_reference.json`` (the exact commands are
  stored there; the point_distance_error_ratio and --change_unit cases are also run through
  ``test_traj_evo.py::test_matches_evo`` and ``test_traj_cli_evo.py``);
* evo 1.38.1 result archives and evo_res's table in ``tests/fixtures/evo/res`` (README there
  gives every command);
* evo's own 2018 archives in ``../shared/data/trajectory/evo/res_files`` (README numbers);
* definitions restated with NumPy / SciPy (ratio of displacement lengths, quartiles, Tukey
  whiskers, Gaussian KDE with Scott's bandwidth, ``np.histogram``).
"""

from __future__ import annotations

import io
import json
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file, require

from microlie import traj as T
from microlie.cli import main
from microlie.traj import plot as P

EVO = "trajectory/evo/"
HERE = Path(__file__).parent
FIX = json.loads((HERE / "fixtures" / "evo" / "evo_reference.json").read_text())["cases"]
RES = HERE / "fixtures" / "evo" / "res"
GT, EST = "freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt"


def run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main([str(a) for a in argv], out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def pair() -> tuple[str, str]:
    return str(data_file(EVO + GT)), str(data_file(EVO + EST))


def numpy_stats(e: np.ndarray) -> dict[str, float]:
    return {"rmse": float(np.sqrt(np.mean(e ** 2))), "mean": float(np.mean(e)),
            "median": float(np.median(e)), "std": float(np.std(e)), "min": float(np.min(e)),
            "max": float(np.max(e)), "sse": float(np.sum(e ** 2))}


# ----------------------------------------------------------------------------- ratio
def test_issue19_item18_point_distance_error_ratio_cli_matches_evo():
    """``microlie rpe tum GT EST -r point_distance_error_ratio -d 1 -u m`` gives evo's
    rmse 19.513056 (the issue's figure) and all of evo's statistics to 1e-9."""
    gt, est = pair()
    code, out, err = run("rpe", "tum", gt, est, "-r", "point_distance_error_ratio", "-d", "1",
                         "-u", "m", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["unit"] == "%" and d["label"] == "RPE w.r.t. point distance error ratio (%)"
    assert f"{d['stats']['rmse']:.6f}" == "19.513056"
    ref = FIX["rpe_fr1_rgbd_m1_pder"]
    assert ref["command"] == ("evo_rpe tum freiburg1_xyz-groundtruth.txt "
                              "freiburg1_xyz-rgbdslam.txt -r point_distance_error_ratio -d 1 "
                              "-u m --no_warnings")
    assert d["num_errors"] == ref["num_errors"]
    for k, v in ref["stats"].items():
        assert abs(d["stats"][k] - v) <= 1e-9 * abs(v), (k, d["stats"][k], v)


def test_issue19_item18_point_distance_error_ratio_definition():
    """The errors are 100 | |dp_ref| - |dp_est| | / |dp_ref| on the same pairs as any other
    relation (restated with NumPy); a pair whose reference does not move is left out and
    counted; the APE refuses the relation."""
    ref, est = (T.read_tum(p) for p in pair())
    r, e = T.associate(ref, est)
    base = T.rpe(r, e, "trans", delta=1, unit="m")
    res = T.rpe(r, e, "point_distance_error_ratio", delta=1, unit="m")
    i, j = base.pairs.T
    lr = np.linalg.norm(r.positions[j] - r.positions[i], axis=1)
    le = np.linalg.norm(e.positions[j] - e.positions[i], axis=1)
    np.testing.assert_allclose(res.errors, 100 * np.abs(lr - le) / lr, rtol=1e-12)
    np.testing.assert_array_equal(res.pairs, base.pairs)
    # a reference standing still between poses 1 and 2
    p = np.c_[np.array([0.0, 1.0, 1.0, 3.0, 4.0]), np.zeros((5, 2))]
    q = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
    still = T.Trajectory.from_arrays(p, q)
    moved = T.Trajectory.from_arrays(p * 1.1, q)
    for dtype, tol in ((np.float64, 1e-12), (np.float32, 1e-5)):  # 10 % too long
        mv = T.Trajectory.from_arrays((p * 1.1).astype(dtype), q.astype(dtype))
        out = T.rpe(still, mv, "point_distance_error_ratio")
        assert out.pairs.tolist() == [[0, 1], [2, 3], [3, 4]]
        assert out.info["zero_distance_pairs_dropped"] == 1
        np.testing.assert_allclose(out.errors, 10.0, rtol=tol)
    with pytest.raises(ValueError, match="every reference displacement has length 0"):
        T.rpe(still, moved, "point_distance_error_ratio", pairs=np.array([[1, 2]]))
    with pytest.raises(ValueError, match="RPE only"):
        T.ape(still, moved, "point_distance_error_ratio")
    code, _, err = run("ape", *pair(), "-r", "point_distance_error_ratio")
    assert code == 2 and "-r point_distance_error_ratio is an RPE relation" in err


# ----------------------------------------------------------------------------- change_unit
def test_issue19_item18_change_unit():
    """--change_unit: evo's statistics (fixtures), factors 1000 / 1e-3 / pi/180 restated, the
    label in the new unit, refusals naming the argument."""
    gt, est = pair()
    code, out, err = run("ape", "tum", gt, est, "-a", "--change_unit", "mm", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["label"] == "APE w.r.t. translation part (mm)" and d["unit"] == "mm"
    for k, v in FIX["ape_fr1_rgbd_se3_mm"]["stats"].items():
        assert abs(d["stats"][k] - v) <= 1e-9 * abs(v), k
    m = T.evaluate_ape(*(T.read_tum(p) for p in pair()), align="se3")
    np.testing.assert_allclose(m.change_unit("mm").errors, m.errors * 1000.0, rtol=1e-15)
    np.testing.assert_allclose(m.change_unit("km").errors, m.errors / 1000.0, rtol=1e-15)
    assert m.change_unit("cm").change_unit("m").stats["rmse"] == pytest.approx(
        m.stats["rmse"], rel=1e-15)
    deg = T.evaluate_rpe(*(T.read_tum(p) for p in pair()), relation="angle_deg")
    rad = deg.change_unit("rad")
    assert rad.relation == "angle_rad" and rad.unit == "rad"
    np.testing.assert_allclose(rad.errors, deg.errors * np.pi / 180, rtol=1e-15)
    with pytest.raises(ValueError, match="cannot be converted"):
        deg.change_unit("m")
    code, _, err = run("rpe", "tum", gt, est, "-r", "full", "--change_unit", "mm")
    assert code == 2 and "--change_unit mm:" in err and "cannot be converted" in err
    code, _, err = run("rpe", "tum", gt, est, "-r", "point_distance_error_ratio",
                       "--change_unit", "m")
    assert code == 2 and "--change_unit m:" in err


# ----------------------------------------------------------------------------- spellings
def test_issue19_item18_plot_spellings(tmp_path):
    """``-p``, a bare ``--plot`` (evo's flags: show a window; without a display a warning),
    ``--plot_mode xy`` with ``--save_plot f.png`` (today "expected one argument") and
    ``--plot FILE``: the PNG written equals the library's figure."""
    require("matplotlib")
    gt, est = pair()
    png = tmp_path / "f.png"
    code, out, err = run("ape", "tum", gt, est, "-a", "-p", "--plot", "--plot_mode", "xz",
                         "--save_plot", png)
    assert code == 0, err
    assert "rmse" in out and f"plot written to {png}" in err
    assert "no window can be shown" in err  # the test runs on the Agg backend
    res = T.evaluate_ape(*(T.read_tum(p) for p in pair()), align="se3")
    P.save(P.plot_error(res, plot_mode="xz"), tmp_path / "lib.png")
    import matplotlib.image

    np.testing.assert_array_equal(matplotlib.image.imread(png),
                                  matplotlib.image.imread(tmp_path / "lib.png"))
    code, _, err = run("traj", est, "--ref", gt, "-a", "-p")
    assert code == 0 and "no window can be shown" in err
    # writing the plot onto an input is refused, the input untouched
    copy = tmp_path / "est.txt"
    shutil.copy(est, copy)
    before = copy.read_bytes()
    code, _, err = run("ape", gt, copy, "--plot", copy)
    assert code == 2 and "is the input file" in err
    assert copy.read_bytes() == before


def test_issue19_item18_plot_x_dimension(tmp_path):
    """``--plot_x_dimension index|seconds|distances``: the error line's abscissa is the pose
    index, seconds from the first stamp, or the distance along the reference (restated)."""
    require("matplotlib")
    gt, est = pair()
    code, _, err = run("rpe", "tum", gt, est, "--plot_x_dimension", "distances",
                       "--save_plot", tmp_path / "r.png")
    assert code == 0, err
    res = T.evaluate_ape(*(T.read_tum(p) for p in pair()), align="se3")
    steps = np.linalg.norm(np.diff(res.ref.positions, axis=0), axis=1)
    expect = {"index": np.arange(res.errors.size),
              "seconds": res.est.timestamps - min(res.est.timestamps[0], res.ref.timestamps[0]),
              "distances": np.r_[0.0, np.cumsum(steps)]}
    for dim, x in expect.items():
        fig = P.plot_error(res, x_dimension=dim)
        (ax,) = [a for a in fig.axes if a.get_gid() == "error"]
        line = ax.get_lines()[0]
        np.testing.assert_allclose(line.get_xdata(), x, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(line.get_ydata(), res.errors)
    assert ax.get_xlabel() == "distance along the reference (m)"
    with pytest.raises(ValueError, match="x_dimension"):
        P.plot_error(res, x_dimension="metres")
    code, _, err = run("ape", gt, est, "--plot_x_dimension", "index")  # no plot asked for
    assert code == 2 and "--plot_x_dimension" in err


def test_issue19_item18_silent_and_logfile(tmp_path):
    """``--silent`` prints nothing (no table, no notes) but keeps warnings and errors;
    ``--logfile`` appends everything printed, even when silent."""
    require("matplotlib")
    gt, est = pair()
    log = tmp_path / "run.log"
    code, out, err = run("ape", "tum", gt, est, "-a", "--silent", "--logfile", log,
                         "--save_plot", tmp_path / "a.png", "--save_results",
                         tmp_path / "a.json")
    assert code == 0 and out == "" and err == ""
    text = log.read_text()
    assert re.search(r"rmse\s+0\.013470", text) and "plot written to" in text
    assert "results written to" in text
    code, out, err = run("ape", "tum", gt, est, "--logfile", log)
    assert code == 0 and out and out in log.read_text()  # appended
    assert log.read_text().startswith(text)
    code, out, err = run("ape", "tum", gt, tmp_path / "missing.txt", "--silent")
    assert code == 1 and out == "" and "missing.txt" in err  # errors still shown
    code, _, err = run("ape", "tum", gt, est, "--silent", "--json")
    assert code == 2 and "--silent and --json" in err
    code, _, err = run("ape", "tum", gt, est, "--logfile", tmp_path / "no" / "dir.log")
    assert code == 1 and "--logfile" in err


# ----------------------------------------------------------------------------- evo archives
def test_issue19_item18_res_reads_evo_archives(tmp_path):
    """``microlie res`` on evo archives (2018 ones with ``.npz`` members, 1.38.1 ones with
    ``.npy``): evo's statistics, its errors, its relation; ``--save_table`` byte-identical to
    evo_res's table; together with our JSON for the same run no warning."""
    old = [str(data_file(EVO + f"res_files/{n}_ape.zip")) for n in ("orb", "sptam")]
    code, out, err = run("res", *old, "--json")
    assert code == 0, err
    rows = json.loads(out)["results"]
    assert rows[0]["stats"]["rmse"] == 1.3034497145650266  # ../shared/data/README.md
    assert rows[1]["stats"]["rmse"] == 3.738487907582613
    r = T.load_evo_result(RES / "short_rpe_pder.zip")
    assert (r.metric, r.relation, r.unit) == ("rpe", "point_distance_error_ratio", "%")
    with zipfile.ZipFile(RES / "short_rpe_pder.zip") as z:
        np.testing.assert_array_equal(r.errors, np.load(io.BytesIO(z.read("error_array.npy"))))
        np.testing.assert_array_equal(r.timestamps, np.load(io.BytesIO(z.read("timestamps.npy"))))
    for f in ("short_ape_se3.zip", "short_ape_none.zip"):
        shutil.copy(RES / f, tmp_path / f)
    table = tmp_path / "table.csv"
    code, _, err = run("res", tmp_path / "short_ape_se3.zip", tmp_path / "short_ape_none.zip",
                       "--use_filenames", "--save_table", table, "--no_warnings")
    assert code == 0, err
    assert table.read_bytes() == (RES / "table.csv").read_bytes()
    # our own JSON of the same run next to evo's archive: same label, same numbers
    gt = str(data_file(EVO + GT))
    short = str(data_file(EVO + "freiburg1_xyz-rgbdslam_drift_short.txt"))
    ours = tmp_path / "ours.json"
    assert run("ape", "tum", gt, short, "-a", "--save-results", ours)[0] == 0
    code, out, err = run("res", ours, tmp_path / "short_ape_se3.zip", "--json")
    assert code == 0 and "different things" not in err
    a, b = json.loads(out)["results"]
    assert a["label"] == b["label"] == "APE w.r.t. translation part (m)"
    for k in a["stats"]:
        assert abs(a["stats"][k] - b["stats"][k]) <= 1e-9 * abs(b["stats"][k]), k


def _zip(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


def test_issue19_item18_res_refuses_bad_archives(tmp_path):
    """Refusals name the file and the problem; no UTF-8 traceback."""
    e = np.array([1.0, 2.0, 4.0])
    buf = io.BytesIO()
    np.save(buf, e)
    info = json.dumps({"title": "APE w.r.t. translation part (m)", "label": "APE (m)"}).encode()
    good = json.dumps(numpy_stats(e)).encode()
    bad = json.dumps({**numpy_stats(e), "rmse": 9.0}).encode()
    cases = {
        "nostats.zip": ({"info.json": info, "error_array.npy": buf.getvalue()}, "no stats.json"),
        "mismatch.zip": ({"info.json": info, "stats.json": bad,
                          "error_array.npy": buf.getvalue()}, "do not match"),
        "noarray.zip": ({"info.json": info, "stats.json": good}, "no error_array"),
        "pickle.zip": ({"info.json": info, "stats.json": good,
                        "error_array.npy": b"\x93NUMPY garbage"}, "not a NumPy array"),
    }
    for name, (members, msg) in cases.items():
        code, _, err = run("res", _zip(tmp_path / name, members))
        assert code == 1 and name in err and msg in err, (name, err)
    code, _, err = run("res", str(data_file(EVO + "res_files/orb_rpe-for-each.zip")))
    assert code == 1 and "evo_rpe-for-each" in err


# ----------------------------------------------------------------------------- evo_res plots
def _results() -> list:
    return [T.load_evo_result(RES / f) for f in ("short_ape_se3.zip", "short_ape_none.zip")]


def test_issue19_item18_res_box_violin_histogram_artists():
    """Each kind draws the expected artists with the data: box (median, quartiles, Tukey
    whiskers), violin (one body per result spanning min..max, shaped by a Scott KDE),
    histogram (one axes per result, ``np.histogram`` densities), raw (the errors over
    time), stats (evo's six statistics as bars)."""
    require("matplotlib")
    scipy_stats = pytest.importorskip("scipy.stats")
    rs = _results()
    data = [r.errors for r in rs]
    fig = P.plot_results(rs, ["a", "b"], kind="box")
    (ax,) = fig.axes
    assert ax.get_gid() == "box"
    by = {g: [ln for ln in ax.lines if ln.get_gid() == g] for g in ("boxes", "medians",
                                                                    "whiskers")}
    assert len(by["boxes"]) == len(by["medians"]) == 2 and len(by["whiskers"]) == 4
    for k, e in enumerate(data):
        q1, med, q3 = np.percentile(e, [25, 50, 75])
        np.testing.assert_allclose(by["medians"][k].get_ydata(), med, rtol=1e-12)
        ys = by["boxes"][k].get_ydata()
        np.testing.assert_allclose([min(ys), max(ys)], [q1, q3], rtol=1e-12)
        lo = e[e >= q1 - 1.5 * (q3 - q1)].min()
        hi = e[e <= q3 + 1.5 * (q3 - q1)].max()
        w = np.concatenate([ln.get_ydata() for ln in by["whiskers"][2 * k:2 * k + 2]])
        np.testing.assert_allclose([w.min(), w.max()], [lo, hi], rtol=1e-12)
    fig = P.plot_results(rs, ["a", "b"], kind="violin")
    (ax,) = fig.axes
    bodies = [c for c in ax.collections if c.get_gid() == "bodies"]
    assert len(bodies) == 2
    for k, (body, e) in enumerate(zip(bodies, data, strict=True)):
        v = body.get_paths()[0].vertices
        np.testing.assert_allclose([v[:, 1].min(), v[:, 1].max()], [e.min(), e.max()],
                                   rtol=1e-12)
        half = np.abs(v[:, 0] - (k + 1))
        kde = scipy_stats.gaussian_kde(e)(v[:, 1])
        np.testing.assert_allclose(half, 0.25 * kde / kde.max(), atol=2e-3)
    (med,) = [c for c in ax.collections if c.get_gid() == "cmedians"]
    np.testing.assert_allclose([s[0, 1] for s in med.get_segments()],
                               [np.median(e) for e in data], rtol=1e-12)
    fig = P.plot_results(rs, ["a", "b"], kind="histogram")
    assert [a.get_gid() for a in fig.axes] == ["histogram"] * 2
    for ax, e, lab in zip(fig.axes, data, ("a", "b"), strict=True):
        dens, edges = np.histogram(e, bins="auto", density=True)
        np.testing.assert_allclose([p.get_height() for p in ax.patches], dens, rtol=1e-12)
        np.testing.assert_allclose([p.get_x() for p in ax.patches], edges[:-1], rtol=1e-12)
        assert ax.get_title() == lab
    fig = P.plot_results(rs, ["a", "b"], kind="raw", rel_time=True)
    (ax,) = fig.axes
    for line, r in zip(ax.get_lines(), rs, strict=True):
        np.testing.assert_array_equal(line.get_ydata(), r.errors)
        np.testing.assert_allclose(line.get_xdata(), r.timestamps - r.timestamps[0])
    fig = P.plot_results(rs, ["a", "b"], kind="stats")
    (ax,) = fig.axes
    heights = [p.get_height() for p in ax.patches]
    keys = ("rmse", "median", "mean", "std", "min", "max")
    expect = [numpy_stats(e)[k] for e in data for k in keys]
    np.testing.assert_allclose(heights, expect, rtol=1e-12)
    with pytest.raises(ValueError, match="unknown plot kind"):
        P.plot_results(rs, ["a", "b"], kind="pie")


def test_issue19_item18_res_plot_files(tmp_path):
    """``--plot-kind all --save_plot res.png`` writes evo_res's five files (its names),
    ``.pdf`` one PDF with five pages, one kind exactly FILE (equal to the library figure);
    ``-p`` is accepted; an unknown kind is a usage error naming the option."""
    require("matplotlib")
    files = [RES / "short_ape_se3.zip", RES / "short_ape_none.zip"]
    code, _, err = run("res", *files, "--plot-kind", "all", "--save_plot", tmp_path / "res.png",
                       "--use_rel_time", "-p")
    assert code == 0, err
    for name in ("raw", "stats", "histogram", "box_plot", "violin_histogram"):
        assert (tmp_path / f"res_{name}.png").stat().st_size > 0
    assert "no window can be shown" in err
    code, _, err = run("res", *files, "--plot-kind", "all", "--save_plot", tmp_path / "r.pdf")
    assert code == 0, err
    assert len(re.findall(rb"/Type\s*/Page\b", (tmp_path / "r.pdf").read_bytes())) == 5
    code, _, err = run("res", *files, "--plot_kind", "violin", "--plot", tmp_path / "v.png")
    assert code == 0 and not (tmp_path / "v_violin_histogram.png").exists()
    P.save(P.plot_results(_results(), [f.name for f in files], kind="violin"),
           tmp_path / "lib.png")
    import matplotlib.image

    np.testing.assert_array_equal(matplotlib.image.imread(tmp_path / "v.png"),
                                  matplotlib.image.imread(tmp_path / "lib.png"))
    code, _, err = run("res", *files, "--plot-kind", "pie", "--plot", tmp_path / "x.png")
    assert code == 2 and "--plot-kind" in err
    code, _, err = run("res", *files, "--plot-kind", "box")  # nothing would be plotted
    assert code == 2 and "--plot-kind chooses figures" in err
