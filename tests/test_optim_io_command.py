"""The ``microlie optimize`` command: JSON report against GTSAM's costs, output files, plots,
formats and errors."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest
from conftest import data_file, require

from microlie.cli import main
from microlie.optim.io.formats import detect_format
from microlie.optim.io.g2o import read_g2o, write_g2o
from microlie.optim.io.toro import read_toro, write_toro

ROOT = Path(__file__).resolve().parents[1]
POSE2 = "pose_graph/gtsam/pose2example.txt"  # README: GTSAM 4.3 LM error 0.5494864475
POSE2_START = 3.43010  # README: GTSAM error at the file's vertices


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main(["optimize", *argv], out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def test_json_report_has_gtsam_costs_and_writes_the_optimised_graph(tmp_path):
    out_file = tmp_path / "opt.g2o"
    code, out, _ = _run(str(data_file(POSE2)), "--json", "-o", str(out_file))
    assert code == 0
    r = json.loads(out)
    assert r["initial_cost"] == pytest.approx(POSE2_START, abs=5e-6)
    assert r["final_cost"] == pytest.approx(0.5494864475, rel=1e-6)
    assert r["converged"] is True and r["iterations"] >= 1 and 0 < r["time_s"] < 60
    assert r["init"] == "file" and r["solver"] == "lm" and r["group"] == "SE2"
    g = read_g2o(out_file)
    assert g.cost() == pytest.approx(r["final_cost"], rel=1e-12)


@pytest.mark.parametrize("solver", ["gn", "dogleg"])
def test_other_solvers_reach_the_same_cost(solver):
    code, out, _ = _run(str(data_file(POSE2)), "--json", "--solver", solver)
    assert code == 0 and json.loads(out)["final_cost"] == pytest.approx(0.5494864475, rel=1e-6)


def test_chordal_start_on_mit_and_robust_option():
    code, out, _ = _run(str(data_file("pose_graph/MIT.g2o")), "--json", "--init", "chordal",
                        "--max-iter", "50")
    r = json.loads(out)
    assert r["init"] == "chordal" and r["final_cost"] == pytest.approx(20.60347352, rel=1e-6)
    code, out, _ = _run(str(data_file(POSE2)), "--json", "--robust", "huber:1.0")
    r = json.loads(out)
    assert r["robust"] == "huber:1.0" and r["final_cost"] < POSE2_START
    assert r["final_robust_cost"] <= r["final_cost"] + 1e-9  # Huber's rho(s) <= s


def test_files_without_vertices_start_from_odometry_and_toro_round_trip(tmp_path):
    src = read_g2o(data_file("pose_graph/CSAIL.g2o"))
    toro = tmp_path / "csail.graph"
    write_toro(toro, src)  # no vertices, TORO edge order
    assert detect_format(toro) == "toro"
    out_file = tmp_path / "opt.graph"
    code, out, _ = _run(str(toro), "--json", "-o", str(out_file))
    r = json.loads(out)
    assert r["format"] == "toro" and r["init"] == "odometry"
    assert r["final_cost"] == pytest.approx(20.27544167, rel=1e-6)  # README, odometry start
    assert read_toro(out_file).cost() == pytest.approx(r["final_cost"], rel=1e-12)


def test_bal_files_are_detected_and_dispatched():
    path = data_file("bal/dubrovnik-3-7-pre.txt")
    assert detect_format(path) == "bal"
    code, out, _ = _run(str(path), "--json", "--max-iter", "5")
    r = json.loads(out)
    assert code == 0 and r["format"] == "bal"
    assert r["initial_cost"] == pytest.approx(2764.220, abs=1e-3)  # data README


def test_auto_start_falls_back_to_chordal_without_an_odometry_chain(tmp_path):
    src = read_g2o(data_file("pose_graph/CSAIL.g2o"))
    ii, jj = src.edge_index()
    keep = ~((ii == 100) & (jj == 101))  # break the chain once; a loop closure keeps 101
    broken = src.replace(i=src.i[keep], j=src.j[keep], measurements=src.measurements[keep],
                         information=src.information[keep])
    path = tmp_path / "broken.g2o"
    write_g2o(path, broken)
    code, out, err = _run(str(path), "--json")
    r = json.loads(out)
    assert code == 0 and r["init"] == "chordal" and "no edge between vertices 100 and 101" in err
    # fewer terms than CSAIL: its optimum is at most the full graph's (GTSAM: 20.27544167)
    assert r["final_cost"] <= 20.27544167 * (1 + 1e-9)


def test_plot_draws_a_png_of_the_given_size(tmp_path):
    require("matplotlib")
    for rel in (POSE2, "pose_graph/tinyGrid3D.g2o"):
        png = tmp_path / "graph.png"
        code, out, _ = _run(str(data_file(rel)), "--plot", str(png))
        assert code == 0 and "cost" in out
        data = png.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
        assert (width, height) == (1200, 600)


def test_plot_leaves_the_pyplot_backend_alone(tmp_path):
    mpl = require("matplotlib")
    before = mpl.get_backend()
    _run(str(data_file(POSE2)), "--plot", str(tmp_path / "g.png"))
    assert mpl.get_backend() == before


def test_bad_input_is_an_error_message_with_file_and_line(tmp_path):
    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0\n")
    code, out, err = _run(str(bad))
    assert code == 1 and f"{bad}:3: EDGE_SE2 needs 11 fields" in err and out == ""
    bad.write_text("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\n")
    code, _, err = _run(str(bad), "--init", "odometry")
    assert code == 1 and "no edge between vertices 1 and 2" in err
    bad.write_text("POINT 0 1 2\n")
    code, _, err = _run(str(bad))
    assert code == 1 and "cannot tell the file format" in err
    code, _, err = _run(str(data_file(POSE2)), "--robust", "wobbly")
    assert code == 1 and "unknown robust loss 'wobbly'" in err


def test_docs_optim_examples_print_what_the_page_shows(tmp_path, monkeypatch, capsys):
    """Every ```python block of docs/optim.md runs (in one namespace, from the folder of the
    pose graphs it names) and prints exactly the ```text block that follows it."""
    page = (ROOT / "docs" / "optim.md").read_text()
    blocks = re.findall(r"```(python|text)\n(.*?)```", page, flags=re.S)
    monkeypatch.chdir(data_file("pose_graph/MIT.g2o").parent)  # the page names the file bare
    ns: dict = {}
    checked = 0
    for k, (kind, code) in enumerate(blocks):
        if kind != "python":
            continue
        code = code.replace('write_g2o("MIT-optimised.g2o"', f'write_g2o("{tmp_path}/m.g2o"')
        exec(compile(code, f"docs/optim.md block {k}", "exec"), ns)
        printed = capsys.readouterr().out
        if k + 1 < len(blocks) and blocks[k + 1][0] == "text":
            assert printed == blocks[k + 1][1], f"block {k}"
            checked += 1
    assert checked >= 3
