"""evo's command-line spellings against microlie's native ones and against evo 1.38.1 itself.

For every case of ``tests/fixtures/evo/evo_reference.json`` the exact evo command line stored
there (``evo_ape tum GT EST -a ...``) is run as ``microlie ape tum GT EST -a ...``, and the
same case is run with microlie's native options (``--format tum --align se3 ...``). The two
must give identical statistics, and both must match evo's to 1e-9 relative. KITTI: compared
with the ``*_ortho`` fixtures (evo run on the rotations projected onto SO(3) as microlie's
reader projects them; see tests/test_traj_evo.py and docs/trajectory.md).
"""

from __future__ import annotations

import io
import json
import shlex
from pathlib import Path

import pytest
from conftest import data_file

from microlie.cli import main

FIX = json.loads((Path(__file__).parent / "fixtures" / "evo" / "evo_reference.json").read_text())
CASES = FIX["cases"]
EVO_NAMES = sorted(n for n in CASES if not n.endswith("_ortho"))
NATIVE = {
    "align": "--align", "n_align": "--n-align", "relation": "--relation", "offset": "--offset",
    "max_diff": "--max-diff", "delta": "--delta", "unit": "--unit", "pairs_from": "--pairs-from",
    "t_start": "--t-start", "t_end": "--t-end", "downsample": "--downsample",
    "project": "--project-to-plane", "interpolate": "--interpolate",
    "change_unit": "--change-unit",
}


def run_json(argv: list[str]) -> dict:
    out, err = io.StringIO(), io.StringIO()
    code = main([*argv, "--json"], out=out, err=err)
    assert code == 0, err.getvalue()
    return json.loads(out.getvalue())


def evo_spelling(case: dict) -> list[str]:
    words = shlex.split(case["command"])
    tool, fmt, ref, est, flags = words[0], words[1], words[2], words[3], words[4:]
    assert tool == f"evo_{case['tool']}"
    return [case["tool"], fmt, str(data_file("trajectory/evo/" + ref)),
            str(data_file("trajectory/evo/" + est)), *flags]


def native_spelling(case: dict) -> list[str]:
    argv = [case["tool"], str(data_file("trajectory/evo/" + case["ref"])),
            str(data_file("trajectory/evo/" + case["est"])), "--format", case["format"]]
    for key, value in case["microlie"].items():
        if key == "all_pairs":
            argv.append("--all-pairs")
        else:
            argv += [NATIVE[key], str(value)]
    return argv


@pytest.mark.parametrize("name", EVO_NAMES)
def test_evo_spelling_equals_native_and_evo(name):
    case = CASES[name]
    expected = CASES.get(name + "_ortho", case)  # KITTI: the projected-rotation run of evo
    a = run_json(evo_spelling(case))
    b = run_json(native_spelling(case))
    assert a["stats"] == b["stats"]
    assert a["num_errors"] == b["num_errors"] == expected["num_errors"]
    for key, value in expected["stats"].items():
        assert abs(a["stats"][key] - value) <= 1e-9 * abs(value) + 1e-12, (key, a, value)


def test_every_required_spelling_is_covered():
    """The evo spellings the issue lists all occur in the fixtures' commands."""
    words = {w for c in CASES.values() for w in shlex.split(c["command"])}
    for flag in ("-a", "-s", "-as", "--align_origin", "-d", "-u", "--t_max_diff", "--t_offset",
                 "--n_to_align", "--all_pairs", "--t_start", "--t_end", "--downsample",
                 "--project_to_plane", "--sync_method", "--pairs_from_reference"):
        assert flag in words, flag
    for rel in ("trans_part", "rot_part", "full", "angle_deg", "angle_rad", "point_distance",
                "point_distance_error_ratio"):  # issue 19 item 18: the ratio
        assert rel in words, rel
    assert "--change_unit" in words  # issue 19 item 18
    for unit in ("f", "m", "d", "r"):
        assert unit in words, unit
    commands = {c["command"].split()[0] + " " + c["command"].split()[1] for c in CASES.values()}
    assert {"evo_ape tum", "evo_ape kitti", "evo_ape euroc", "evo_rpe tum", "evo_rpe kitti",
            "evo_rpe euroc"} <= commands
