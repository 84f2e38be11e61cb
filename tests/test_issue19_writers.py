"""Issue 19, items 9, 14 and 19 (last three sentences): writers that never lose the old file,
commands that do not overwrite their input without ``--force``, progress on stderr when the
output is not a terminal, readers/writers exported from ``microlie.optim``, short result reprs,
``--max-iter`` that must be positive."""

from __future__ import annotations

import io
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import microlie
from microlie import SE2
from microlie.cli import main
from microlie.data import example_paths

SRC = str(Path(microlie.__file__).resolve().parents[1])  # the microlie under test
LIMIT = 4096  # bytes a file may grow to while a write is made to fail (RLIMIT_FSIZE)

# a chain of SE2 poses whose g2o/TORO text is far larger than LIMIT
N = 300
CHAIN = "".join(f"VERTEX_SE2 {k} {1.1 * k} {0.01 * k} 0.001\n" for k in range(N)) + "".join(
    f"EDGE_SE2 {k} {k + 1} 1 0 0 1 0 0 1 0 1\n" for k in range(N - 1))
# two poses, one edge 0 -> 1 of (1, 0, 0) with unit information: the prior holds pose 0 at the
# origin, so the optimum is pose 1 = (1, 0, 0) (X_1 = X_0 Z_01), cost 0
TINY = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0.1 0.05\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"


def _writers(tmp: Path) -> dict:
    """name -> (target file name, callable(path) writing more than LIMIT bytes there)."""
    from microlie import traj
    from microlie.optim.io import bal, g2o, toro
    from microlie.optim.sfm.bundle import synthetic_scene

    src = tmp / "src.g2o"
    src.write_text(CHAIN)
    graph = g2o.read_g2o(src)
    t = traj.read_tum(example_paths()[0])
    scene = synthetic_scene(4, 200, seed=3)[1].to_bal()
    res = traj.evaluate_ape(*(traj.read_tum(p) for p in example_paths()), align="se3")

    def traj_plot(path):
        from microlie.traj import plot as tplot

        tplot.save(tplot.plot_trajectories([t]), path)

    def graph_plot(path):
        from microlie.optim.plot import plot_pose_graph

        plot_pose_graph(graph, graph.poses, graph.poses, path)

    return {
        "g2o": ("out.g2o", lambda p: g2o.write_g2o(p, graph)),
        "toro": ("out.graph", lambda p: toro.write_toro(p, graph)),
        "bal": ("out.txt", lambda p: bal.write_bal(p, scene)),
        "tum": ("out.tum", lambda p: traj.write_tum(p, t)),
        "kitti": ("out.kitti", lambda p: traj.write_kitti(p, t)),
        "euroc": ("out.csv", lambda p: traj.write_euroc(p, t)),
        "result-json": ("out.json", lambda p: traj.save_result(res, p)),
        "traj-plot": ("out.png", traj_plot),
        "graph-plot": ("out.png", graph_plot),
    }


@pytest.mark.skipif(sys.platform == "win32", reason="RLIMIT_FSIZE is POSIX")
@pytest.mark.parametrize("name", ["g2o", "toro", "bal", "tum", "kitti", "euroc", "result-json",
                                  "traj-plot", "graph-plot"])
def test_issue19_item9_write_failing_midway_keeps_the_old_file(tmp_path, name):
    """A disk that fills up during the write (the kernel refuses bytes past LIMIT, as on a full
    disk): the old file stays byte-identical and no temporary file is left. On today's main
    the file is truncated to LIMIT bytes of the new content."""
    require_mpl = name.endswith("plot")
    if require_mpl:
        pytest.importorskip("matplotlib")
    import resource

    fname, write = _writers(tmp_path)[name]
    warm = tmp_path / "warm"  # imports, font caches: not inside the limited window
    warm.mkdir()
    write(warm / fname)
    assert (warm / fname).stat().st_size > LIMIT  # the new content does not fit
    folder = tmp_path / "out"
    folder.mkdir()
    target = folder / fname
    old = b"the user's only copy\n" * 10
    target.write_bytes(old)
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, hard))
    try:
        with pytest.raises(OSError):
            write(target)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, handler)
    assert target.read_bytes() == old
    assert sorted(os.listdir(folder)) == [fname]  # no temporary file behind
    write(target)  # and without the limit the same call replaces it
    assert target.read_bytes() == (warm / fname).read_bytes() or require_mpl


def test_issue19_item9_failed_write_names_the_file_and_keeps_mode(tmp_path):
    from microlie._files import atomic_write

    target = tmp_path / "a.txt"
    target.write_text("old\n")
    target.chmod(0o640)
    with pytest.raises(OSError, match="a.txt"):
        with atomic_write(target) as f:
            f.write("new, partial")
            raise OSError(28, "No space left on device")
    assert target.read_text() == "old\n" and os.listdir(tmp_path) == ["a.txt"]
    with atomic_write(target) as f:
        f.write("new\n")
    assert target.read_text() == "new\n" and (target.stat().st_mode & 0o777) == 0o640


def _cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main(list(argv), out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def test_issue19_item9_optimize_refuses_to_overwrite_its_input(tmp_path):
    path = tmp_path / "c.g2o"
    path.write_text(TINY)
    code, _, err = _cli("optimize", str(path), "-o", str(path))
    assert code != 0 and "-o" in err and "--force" in err and "another path" in err
    assert path.read_text() == TINY
    code, _, err = _cli("optimize", str(path), "--plot", str(path))
    assert code != 0 and "--plot" in err and path.read_text() == TINY
    link = tmp_path / "link.g2o"  # the same file under another name
    link.symlink_to(path)
    code, _, err = _cli("optimize", str(link), "-o", str(path))
    assert code != 0 and path.read_text() == TINY
    # with --force: written, and the result is the optimum (pose 1 = (1, 0, 0))
    code, out, _ = _cli("optimize", str(path), "-o", str(path), "--force", "--json")
    assert code == 0 and json.loads(out)["output"] == str(path)
    from microlie.optim import read_g2o

    g = read_g2o(path)
    assert np.allclose(g.poses.params[1], SE2.exp([1.0, 0.0, 0.0]).params, atol=1e-8)
    assert g.cost() < 1e-15


def test_issue19_item9_bundle_adjustment_refuses_to_overwrite_its_input(tmp_path):
    from microlie.optim import read_bal, write_bal
    from microlie.optim.sfm.bundle import synthetic_scene

    path = tmp_path / "scene.txt"
    write_bal(path, synthetic_scene(3, 20, seed=2)[1].to_bal())
    old = path.read_bytes()
    code, _, err = _cli("optimize", str(path), "-o", str(path))
    assert code != 0 and "--force" in err and path.read_bytes() == old
    code, out, _ = _cli("optimize", str(path), "-o", str(path), "--force", "--json")
    assert code == 0
    r = np.asarray(read_bal(path).residuals())  # the written problem, evaluated anew
    assert 0.5 * float(np.sum(r * r)) == pytest.approx(json.loads(out)["final_cost"], rel=1e-9)
    assert path.read_bytes() != old


def test_issue19_item9_trajectory_commands_refuse_to_overwrite_an_input(tmp_path):
    gt, est = (Path(shutil.copy(p, tmp_path)) for p in example_paths())
    old = {p: p.read_bytes() for p in (gt, est)}
    refused = [
        ("ape", str(gt), str(est), "--save_results", str(est)),
        ("rpe", str(gt), str(est), "--save_results", str(gt)),
        ("traj", str(est), "--save-as", "tum", str(tmp_path)),
    ]
    if _has("matplotlib"):
        refused += [("ape", str(gt), str(est), "--plot", str(gt)),
                    ("plot", str(gt), str(est), "-o", str(est))]
    for argv in refused:
        code, _, err = _cli(*argv)
        assert code != 0 and "--force" in err, (argv, err)
        assert all(p.read_bytes() == b for p, b in old.items()), argv
    # res reads result files: its plot must not replace one
    if _has("matplotlib"):
        res_file = tmp_path / "r.json"
        assert _cli("ape", str(gt), str(est), "--save_results", str(res_file))[0] == 0
        saved = res_file.read_bytes()
        code, _, err = _cli("res", str(res_file), "--plot", str(res_file))
        assert code != 0 and "--force" in err and res_file.read_bytes() == saved
    # --force: the estimate is rewritten in place, same poses as the original file
    code, _, _ = _cli("traj", str(est), "--save-as", "tum", str(tmp_path), "--force")
    assert code == 0
    orig = np.loadtxt(example_paths()[1])
    new = np.loadtxt(est)
    assert np.allclose(new[:, :4], orig[:, :4], rtol=0, atol=1e-12)  # time, position
    assert np.allclose(new[:, 4:], orig[:, 4:], rtol=0, atol=1e-7)  # quaternions, normalised


def _has(module: str) -> bool:
    try:
        __import__(module)
    except ImportError:
        return False
    return True


ROW = re.compile(r"^\s*(\d+)\s+([-+0-9.e]+)\s")


def _optimize_piped(path: Path, *flags: str) -> tuple[dict, list[str]]:
    """``microlie optimize`` with stdout and stderr pipes (not terminals)."""
    env = {**os.environ, "PYTHONPATH": SRC}
    p = subprocess.run([sys.executable, "-m", "microlie.cli", "optimize", str(path), "--json",
                        *flags], capture_output=True, text=True, timeout=300, env=env)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout), p.stderr.splitlines()


@pytest.mark.parametrize("kind", ["g2o", "bal"])
def test_issue19_item14_progress_on_stderr_when_not_a_terminal(tmp_path, kind):
    if kind == "g2o":
        path = tmp_path / "chain.g2o"
        rng = np.random.default_rng(5)
        text = "".join(f"VERTEX_SE2 {k} {1.1 * k + rng.normal(0, .3)} {rng.normal(0, .3)} "
                       f"{rng.normal(0, .1)}\n" for k in range(30))
        text += "".join(f"EDGE_SE2 {k} {k + 1} 1 0 0 1 0 0 1 0 1\n" for k in range(29))
        text += "EDGE_SE2 0 29 29 0.5 0 1 0 0 1 0 1\n"
        path.write_text(text)
    else:
        from microlie.optim import write_bal
        from microlie.optim.sfm.bundle import synthetic_scene

        path = tmp_path / "scene.txt"
        write_bal(path, synthetic_scene(3, 20, seed=2)[1].to_bal())
    # default: the header (before the solve), no table
    report, lines = _optimize_piped(path)
    assert len(lines) == 1 and lines[0].startswith(f"microlie optimize: {path}: ")
    assert report["problem"] in lines[0]
    # --verbose: header, then the table, one row per iteration
    report, lines = _optimize_piped(path, "--verbose")
    assert lines[0].startswith("microlie optimize:")
    assert re.match(r"\s*iter\s+cost\s+cost_change\s+\|gradient\|\s+\|step\|\s+tr_ratio",
                    lines[1])
    rows = [m for m in map(ROW.match, lines[2:]) if m]
    assert [int(m.group(1)) for m in rows] == list(range(len(rows)))
    assert len(rows) >= report["iterations"] >= 2  # BA: the stopping try has no row
    key = "final_robust_cost"
    assert float(rows[0].group(2)) == pytest.approx(report.get("initial_robust_cost",
                                                               report["initial_cost"]),
                                                    rel=1e-6)
    accepted = [float(m.group(2)) for m in rows]
    assert min(accepted) == pytest.approx(report[key], rel=1e-6)
    # --quiet: nothing on stderr; stdout still one JSON object
    report_q, lines = _optimize_piped(path, "--quiet")
    assert lines == [] and report_q["final_cost"] == pytest.approx(report["final_cost"])


def test_issue19_item14_verbose_and_quiet_are_exclusive(tmp_path):
    path = tmp_path / "c.g2o"
    path.write_text(TINY)
    code, _, err = _cli("optimize", str(path), "-v", "-q")
    assert code == 2 and "--quiet" in err


def test_issue19_item14_iteration_table_values(tmp_path, capsys):
    """The table's numbers against the solver's own history: cost after each step, its change,
    the step norm; |gradient| at the start is the max-norm of J^T W r (finite differences of
    the cost)."""
    from microlie.optim import BetweenFactor, FactorGraph, PriorFactor

    rng = np.random.default_rng(0)
    g = FactorGraph()
    x = g.add_variables(SE2.exp(rng.normal(size=(4, 3))))
    g.add(PriorFactor(x, 0, SE2.identity()))
    g.add(BetweenFactor(x, [0, 1, 2], [1, 2, 3], SE2.exp([1.0, 0.0, 0.3])))
    g.add(BetweenFactor(x, [0], [3], SE2.exp([2.5, 1.0, 0.9])))
    res = g.optimize(solver="gn", verbose=True)
    lines = capsys.readouterr().err.splitlines()
    rows = [ln.split() for ln in lines[1:]]
    assert len(rows) == res.iterations + 1
    for rec, row in zip(res.history, rows[1:], strict=True):
        assert float(row[1]) == pytest.approx(rec.cost, rel=1e-6)
        assert float(row[4]) == pytest.approx(rec.step_norm, rel=1e-2)
    assert float(rows[0][1]) == pytest.approx(res.initial_robust_cost, rel=1e-6)
    # gradient at the start, by central differences of the cost along X Exp(h e_k)
    from microlie.optim import Values

    X0 = g.initial_values()[x]

    def cost(X):
        return g.cost(Values([x], [np.asarray(X.params)]))

    h, grads = 1e-6, []
    for i in range(4):
        for k in range(3):
            d = np.zeros((4, 3))
            d[i, k] = h
            grads.append((cost(X0 @ SE2.exp(d)) - cost(X0 @ SE2.exp(-d))) / (2 * h))
    assert float(rows[0][3]) == pytest.approx(max(abs(v) for v in grads), rel=1e-2)


def test_issue19_item19_readers_and_writers_exported_from_optim(tmp_path):
    import microlie.optim as optim

    for name in ("read_g2o", "write_g2o", "read_toro", "write_toro", "read_bal", "write_bal",
                 "PoseGraph"):
        assert name in optim.__all__ and callable(getattr(optim, name)), name
    path = tmp_path / "c.g2o"
    path.write_text(TINY)
    g = optim.read_g2o(path)
    assert isinstance(g, optim.PoseGraph)
    optim.write_toro(tmp_path / "c.graph", g)
    back = optim.read_toro(tmp_path / "c.graph")
    assert np.allclose(back.poses.params, g.poses.params, atol=1e-15)


def test_issue19_item19_result_reprs_are_short_summaries():
    from microlie.optim import bundle_adjust
    from microlie.optim.sfm.bundle import synthetic_scene

    _, start = synthetic_scene(3, 40, seed=1)
    res = bundle_adjust(start, fix_cameras=[0])
    text = repr(res)
    assert str(res) == text and "\n" not in text and len(text) < 400 and "array" not in text
    r = np.asarray(start.with_values(res.values).residuals())
    nums = [float(v) for v in re.findall(r"cost ([-+0-9.e]+) -> ([-+0-9.e]+)", text)[0]]
    r0 = np.asarray(start.residuals())
    assert nums[0] == pytest.approx(0.5 * float(np.sum(r0 * r0)), rel=1e-9)
    assert nums[1] == pytest.approx(0.5 * float(np.sum(r * r)), rel=1e-9)
    assert f"in {res.iterations} iterations" in text
    assert res.termination in text
    assert "49 variables" in text   # 3 rotations, 3 translations, 3 intrinsics, 40 points
    ms = float(re.search(r"([0-9.]+) ms", text).group(1))
    assert ms == pytest.approx(res.time_s * 1e3, abs=0.051)
    solved = start.with_values(res.values)
    for obj in (solved, solved.to_bal()):
        assert len(repr(obj)) < 120 and "3 cameras, 40 points, 120 observations" in repr(obj)
    # the pose-graph Result: sizes too
    from microlie.optim import FactorGraph, PriorFactor

    g = FactorGraph()
    x = g.add_variables(SE2.identity(5))
    g.add(PriorFactor(x, [0, 1, 2, 3, 4], SE2.exp(np.ones((5, 3)))))
    out = g.optimize()
    assert "5 variables" in repr(out) and len(repr(out)) < 300
    assert math.isclose(float(re.search(r"cost ([-+0-9.e]+) ->", repr(out)).group(1)),
                        0.5 * 5 * 3.0, rel_tol=1e-9)  # |Log(Z)|^2 = 3 per pose


def test_issue19_item19_traj_result_reprs_are_short():
    from microlie import traj
    from microlie.traj.results import result_from_error

    ref, est = (traj.read_tum(p) for p in example_paths())
    res = traj.evaluate_ape(ref, est, align="se3")
    for obj in (res, result_from_error(res, {})):
        text = repr(obj)
        assert len(text) < 250 and "\n" not in text and "array" not in text
        assert f"{res.errors.size} errors" in text
        rmse = float(re.search(r"rmse ([-+0-9.e]+)", text).group(1))
        assert rmse == pytest.approx(math.sqrt(np.mean(res.errors ** 2)), rel=1e-5)


@pytest.mark.parametrize("value", ["-3", "0"])
@pytest.mark.parametrize("kind", ["g2o", "bal"])
def test_issue19_item19_max_iter_must_be_positive(tmp_path, kind, value):
    if kind == "g2o":
        path = tmp_path / "c.g2o"
        path.write_text(TINY)
    else:
        from microlie.optim import write_bal
        from microlie.optim.sfm.bundle import synthetic_scene

        path = tmp_path / "scene.txt"
        write_bal(path, synthetic_scene(3, 20, seed=2)[1].to_bal())
    code, out, err = _cli("optimize", str(path), "--max-iter", value)
    assert code == 2 and "--max-iter" in err and out == ""
    assert _cli("optimize", str(path), "--max-iter", "1", "--json")[0] == 0


def test_issue19_item14_header_is_flushed_before_the_solve(tmp_path, monkeypatch):
    """The header is on the error stream, flushed, when the solver starts (a log file shows it
    while a long solve runs)."""
    from microlie.optim import FactorGraph

    class Stream(io.StringIO):
        flushed = ""

        def flush(self) -> None:
            self.flushed = self.getvalue()

    err = Stream()
    seen: list[str] = []
    solve = FactorGraph.optimize

    def spy(self, *args, **kwargs):
        seen.append(err.flushed)
        return solve(self, *args, **kwargs)

    monkeypatch.setattr(FactorGraph, "optimize", spy)
    path = tmp_path / "c.g2o"
    path.write_text(TINY)
    assert main(["optimize", str(path)], out=io.StringIO(), err=err) == 0
    assert len(seen) == 1 and seen[0].startswith(f"microlie optimize: {path}: SE2 pose graph")
