"""Issue 19 (item 10 and the fuzz acceptance item; items 3 and 4 through the same oracle):
every reader on seeded mutations of a valid file.

One harness for every format. A case takes a valid seed file, applies one or two seeded
mutations (tokens deleted, duplicated, inserted, replaced or moved to the next line, lines
swapped, duplicated or deleted, an integer renamed throughout (vertex ids up to 2**63), a
byte that is not UTF-8, a byte order mark, no-break spaces,
Arabic-Indic digits, ``1_0``, nan / inf, huge integers, truncation, CRLF, blank lines, comment
lines, other line breaks) and reads the result. The outcome must be one of:

* the reader's ``ValueError`` whose message starts with ``FILE:`` (``FILE:LINE:`` with the line
  in the file), never another exception type (no ``AssertionError``, no
  ``UnicodeDecodeError``); or
* a parse equal to an independent reference reading of the mutated text written here (Python
  ``int`` / ``float`` per field, the format's field counts per line). Text the reference
  refuses (a line with a wrong number of fields, a number that is not finite, an id out of
  range) must be refused: a shifted, re-aligned line is a failure.

Mutations that do not change the data (a byte order mark, CRLF, blank or comment lines) must
give the seed's own parse.
"""

from __future__ import annotations

import json
import math
import random
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from microlie.optim.io.bal import read_bal
from microlie.optim.io.g2o import read_g2o
from microlie.optim.io.toro import read_toro
from microlie.traj import load_result, read_euroc, read_kitti, read_tum

CASES = 300
REJECT = None  # the reference says the reader must refuse the text


# ---------------------------------------------------------------------- the seeds
def _rng_rows(seed: int, n: int, k: int) -> list[list[float]]:
    return np.random.default_rng(seed).normal(size=(n, k)).round(6).tolist()


def _quats(seed: int, n: int) -> np.ndarray:
    return Rotation.random(n, random_state=seed).as_quat()  # x y z w, unit


def _fmt(xs: Any) -> str:
    return " ".join(repr(float(x)) for x in xs)


INFO3 = [500.0, 10.0, 2.0, 400.0, 5.0, 1000.0]  # upper triangle, positive definite
INFO6 = [float(v) for v in (np.eye(6) * 100 + np.triu(np.full((6, 6), 1.5), 1))
         [np.triu_indices(6)]]
EDGES = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 4), (1, 3)]


def _seed_pose_graph(vtag: str, etag: str, dim3: bool, toro: bool) -> str:
    lines = ["# seed"]
    for v in range(5):
        x = _rng_rows(v, 1, 6)[0]
        if not dim3:
            lines.append(f"{vtag} {v} {_fmt(x[:3])}")
        elif toro:
            lines.append(f"{vtag} {v} {_fmt(x[:3])} {_fmt(np.array(x[3:]) * 0.5)}")
        else:
            lines.append(f"{vtag} {v} {_fmt(x[:3])} {_fmt(_quats(v, 1)[0])}")
    for e, (i, j) in enumerate(EDGES):
        z = _rng_rows(100 + e, 1, 6)[0]
        if not dim3:
            info = [INFO3[k] for k in (0, 1, 3, 5, 2, 4)] if toro else INFO3  # TORO order
            lines.append(f"{etag} {i} {j} {_fmt(z[:3])} {_fmt(info)}")
        elif toro:
            lines.append(f"{etag} {i} {j} {_fmt(z[:3])} {_fmt(np.array(z[3:]) * 0.5)} "
                         f"{_fmt(INFO6)}")
        else:
            lines.append(f"{etag} {i} {j} {_fmt(z[:3])} {_fmt(_quats(100 + e, 1)[0])} "
                         f"{_fmt(INFO6)}")
    if not toro:
        lines.append("FIX 0")
    return "\n".join(lines) + "\n"


def _seed_bal() -> str:
    obs = [(0, 0), (1, 0), (0, 1), (1, 2), (0, 2)]
    uv = _rng_rows(7, len(obs), 2)
    params = [*_rng_rows(8, 2, 9), *_rng_rows(9, 3, 3)]
    lines = ["2 3 5"] + [f"{c} {p}     {u!r} {v!r}" for (c, p), (u, v)
                         in zip(obs, uv, strict=True)]
    lines += [repr(x) for row in params for x in row]
    return "\n".join(lines) + "\n"


def _seed_tum() -> str:
    rows = [[0.1 * k, *_rng_rows(k, 1, 3)[0], *_quats(k, 1)[0]] for k in range(6)]
    return "# timestamp tx ty tz qx qy qz qw\n" + "".join(_fmt(r) + "\n" for r in rows)


def _seed_kitti() -> str:
    rows = []
    for k in range(5):
        R = Rotation.from_quat(_quats(k, 1)[0]).as_matrix()
        rows.append(np.hstack([R, np.array(_rng_rows(k, 1, 3)).T]).reshape(-1))
    return "".join(_fmt(r) + "\n" for r in rows)


def _seed_euroc() -> str:
    out = "#timestamp [ns],p_x,p_y,p_z,q_w,q_x,q_y,q_z,v_x,v_y,v_z\n"
    for k in range(5):
        q = _quats(k, 1)[0]
        vals = [*_rng_rows(k, 1, 3)[0], q[3], *q[:3], *_rng_rows(50 + k, 1, 3)[0]]
        out += f"{1403636579763555584 + 5000000 * k}," + ",".join(repr(float(v)) for v in vals)
        out += "\n"
    return out


def _seed_result() -> str:
    from microlie.traj.metrics import statistics

    errors = [abs(v) for v in np.array(_rng_rows(3, 6, 1)).reshape(-1).tolist()]
    doc = {"microlie_result": 1, "microlie_version": "0", "metric": "rpe",
           "relation": "trans", "label": "RPE w.r.t. translation part (m)", "unit": "m",
           "ref_name": "gt.txt", "est_name": "est.txt", "options": {"delta": 1},
           "info": {"pairs": 6}, "stats": statistics(np.array(errors)), "errors": errors,
           "timestamps": [0.1 * k for k in range(6)], "pairs": [[k, k + 1] for k in range(6)]}
    return json.dumps(doc, indent=1) + "\n"


# ---------------------------------------------------------------------- the reference readings
def _rows(text: str, comments: tuple[str, ...], split: Callable[[str], list[str]]
          ) -> list[list[str]]:
    """The fields of the data lines, as the formats define them (a leading BOM dropped); a
    data line with a character outside ASCII (a no-break space, another script's digit) is
    refused."""
    out = []
    for line in text.removeprefix("\ufeff").splitlines():
        s = line.strip()
        if s and not (comments and s.startswith(comments)):
            if not s.isascii():
                raise ValueError(s)
            out.append(split(s))
    return out


def _num(s: str) -> float:
    if "_" in s:  # Python's float reads 1_0 as 10: damage in a data file, refused
        raise ValueError(s)
    v = float(s)  # raises ValueError: the reader must refuse
    if not math.isfinite(v):
        raise ValueError(s)
    return v


def _id(s: str) -> int:
    if "_" in s:
        raise ValueError(s)
    v = int(s)
    if not 0 <= v < 2**63:
        raise ValueError(s)
    return v


def _unit(q: list[float], tol: float) -> np.ndarray:
    n = float(np.linalg.norm(q))
    if not abs(n - 1.0) <= tol or n == 0:
        raise ValueError("quaternion")
    return np.asarray(q) / n


def _rotation(q_xyzw: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(q_xyzw).as_matrix().reshape(-1)


def _pose_graph_reference(vtag: str, etag: str, dim3: bool, toro: bool):
    nv, ne = (3 if not dim3 else (6 if toro else 7)), (9 if not dim3 else (27 if toro else 28))

    def pose(v: list[float]) -> list[float]:
        if not dim3:
            return [v[0], v[1], math.cos(v[2]), math.sin(v[2])]
        if toro:  # R = Rz(yaw) Ry(pitch) Rx(roll)
            R = Rotation.from_euler("ZYX", [v[5], v[4], v[3]]).as_matrix().reshape(-1)
        else:
            R = _rotation(_unit(v[3:7], 1e-2))
        return [*v[:3], *R]

    def reference(text: str) -> dict[str, np.ndarray] | None:
        verts: dict[int, list[float]] = {}
        ij, edges, fixed = [], [], []
        for f in _rows(text, ("#",), str.split):
            if f[0] == vtag and len(f) == 2 + nv:
                if _id(f[1]) in verts:
                    return REJECT
                verts[_id(f[1])] = pose([_num(x) for x in f[2:]])
            elif f[0] == etag and len(f) == 3 + ne:
                v = [_num(x) for x in f[3:]]
                z, w = v[:ne - (21 if dim3 else 6)], v[ne - (21 if dim3 else 6):]
                if toro and not dim3:
                    w = [w[k] for k in (0, 1, 4, 2, 5, 3)]  # TORO's 2-D order
                ij.append([_id(f[1]), _id(f[2])])
                edges.append([*pose(z), *w])
            elif f[0] == "FIX" and not toro and len(f) > 1:
                fixed += [_id(x) for x in f[1:]]
            else:
                return REJECT  # an unknown tag or a wrong number of fields
        ids = sorted(verts)
        return {"ids": np.array(ids, dtype=np.int64), "poses": np.array([verts[i] for i in ids]),
                "ij": np.array(ij, dtype=np.int64).reshape(-1, 2), "edges": np.array(edges),
                "fixed": np.unique(np.array(fixed, dtype=np.int64))}

    def parsed(g: Any) -> dict[str, np.ndarray]:
        d = 3 if dim3 else 2
        r, c = np.triu_indices(g.group.dof)

        def poses(X: Any) -> np.ndarray:
            p = np.asarray(X.params)
            if not dim3:
                return p
            return np.hstack([p[:, :3], Rotation.from_quat(p[:, 3:]).as_matrix().reshape(-1, 9)])

        assert g.dim == d
        return {"ids": g.ids, "poses": poses(g.poses),
                "ij": np.stack([g.i, g.j], axis=1),
                "edges": np.hstack([poses(g.measurements), g.information[:, r, c]]),
                "fixed": g.fixed}

    return reference, parsed


def _bal_reference(text: str) -> dict[str, np.ndarray] | None:
    lines = _rows(text, (), str.split)
    if not lines or len(lines[0]) != 3:
        return REJECT
    nc, npt, no = (int(h) for h in lines[0])
    if min(nc, npt, no) <= 0 or len(lines) < 1 + no:
        return REJECT
    obs = lines[1:1 + no]
    if any(len(f) != 4 or not (0 <= int(f[0]) < nc and 0 <= int(f[1]) < npt) for f in obs):
        return REJECT
    par = lines[1 + no:]
    layout = [len(f) for f in par]
    if layout not in ([1] * (9 * nc + 3 * npt), [9] * nc + [3] * npt):
        return REJECT
    vals = [_num(x) for f in par for x in f]
    return {"cameras": np.array(vals[:9 * nc]).reshape(nc, 9),
            "points": np.array(vals[9 * nc:]).reshape(npt, 3),
            "index": np.array([[int(f[0]), int(f[1])] for f in obs], dtype=np.int64),
            "uv": np.array([[_num(f[2]), _num(f[3])] for f in obs])}


def _bal_parsed(p: Any) -> dict[str, np.ndarray]:
    return {"cameras": p.cameras, "points": p.points,
            "index": np.stack([p.camera_index, p.point_index], axis=1),
            "uv": p.observations}


def _traj_reference(kind: str):
    comments = ("#", "%")

    def reference(text: str) -> dict[str, np.ndarray] | None:
        if kind == "euroc":
            rows = _rows(text, comments, lambda s: [f.strip() for f in s.split(",")])
            if not rows or len(rows[0]) < 8 or any(len(r) != len(rows[0]) for r in rows):
                return REJECT
            v = np.array([[_num(x) for x in r[:8]] for r in rows])
            q = np.array([_unit(list(r[[5, 6, 7, 4]]), 1e-3) for r in v])
            return {"t": v[:, 0] / 1e9, "p": v[:, 1:4], "R": np.array([_rotation(x) for x in q])}
        rows = _rows(text, comments, lambda s: s.replace(",", " ").split())
        n = 8 if kind == "tum" else 12
        if not rows or any(len(r) != n for r in rows):
            return REJECT
        v = np.array([[_num(x) for x in r] for r in rows])
        if kind == "tum":
            q = np.array([_unit(list(r[4:]), 1e-3) for r in v])
            return {"t": v[:, 0], "p": v[:, 1:4], "R": np.array([_rotation(x) for x in q])}
        m = v.reshape(-1, 3, 4)
        return {"t": np.zeros(0), "p": m[:, :, 3], "R": m[:, :, :3].reshape(-1, 9)}

    def parsed(t: Any) -> dict[str, np.ndarray]:
        return {"t": np.zeros(0) if t.timestamps is None else t.timestamps, "p": t.positions,
                "R": t.matrices()[:, :3, :3].reshape(-1, 9)}

    return reference, parsed


def _result_reference(text: str) -> dict[str, Any] | None:
    try:
        d = json.loads(text.removeprefix("\ufeff"))
    except (ValueError, RecursionError):
        return REJECT
    if not isinstance(d, dict) or not isinstance(d.get("errors"), list):
        return REJECT
    try:
        return {"errors": np.array([_num(repr(x)) for x in d["errors"]]),
                "stats": d["stats"], "pairs": d["pairs"],
                "timestamps": None if d["timestamps"] is None else
                np.array([_num(repr(x)) for x in d["timestamps"]]),
                "text": [d.get(k) for k in ("metric", "relation", "label", "unit", "ref_name",
                                            "est_name", "options", "info")]}
    except (KeyError, TypeError, ValueError, OverflowError):
        return REJECT


def _result_parsed(r: Any) -> dict[str, Any]:
    return {"errors": r.errors, "stats": r.stats,
            "timestamps": r.timestamps,
            "pairs": None if r.pairs is None else r.pairs.tolist(),
            "text": [r.metric, r.relation, r.label, r.unit, r.ref_name, r.est_name, r.options,
                     r.info]}


@dataclass(frozen=True)
class Format:
    seed: str
    suffix: str
    read: Callable[[Path], Any]
    reference: Callable[[str], Any]
    parsed: Callable[[Any], Any]
    comment: str | None = "#"
    atol: float = 1e-12  # KITTI: accepted rotations are projected onto SO(3)


FORMATS = {
    "g2o-SE2": Format(_seed_pose_graph("VERTEX_SE2", "EDGE_SE2", False, False), ".g2o",
                      read_g2o, *_pose_graph_reference("VERTEX_SE2", "EDGE_SE2", False, False)),
    "g2o-SE3": Format(_seed_pose_graph("VERTEX_SE3:QUAT", "EDGE_SE3:QUAT", True, False), ".g2o",
                      read_g2o, *_pose_graph_reference("VERTEX_SE3:QUAT", "EDGE_SE3:QUAT",
                                                       True, False), atol=1e-9),
    "toro-2d": Format(_seed_pose_graph("VERTEX2", "EDGE2", False, True), ".graph", read_toro,
                      *_pose_graph_reference("VERTEX2", "EDGE2", False, True)),
    "toro-3d": Format(_seed_pose_graph("VERTEX3", "EDGE3", True, True), ".graph", read_toro,
                      *_pose_graph_reference("VERTEX3", "EDGE3", True, True), atol=1e-9),
    "bal": Format(_seed_bal(), ".txt", read_bal, _bal_reference, _bal_parsed, comment=None),
    "tum": Format(_seed_tum(), ".txt", read_tum, *_traj_reference("tum"), atol=1e-9),
    "kitti": Format(_seed_kitti(), ".txt", read_kitti, *_traj_reference("kitti"), atol=3e-3),
    "euroc": Format(_seed_euroc(), ".csv", read_euroc, *_traj_reference("euroc"), atol=1e-9),
    "result-json": Format(_seed_result(), ".json", load_result, _result_reference,
                          _result_parsed, comment=None),
}


# ---------------------------------------------------------------------- the mutations
POOL = ["0", "1", "-1", "2.5", "1e-3", "1_0", "\u0661", "nan", "inf", "-inf", "1e999", "9" * 25,
        "9223372036854775808", "18446744073709551615", "1.0", "x", "+1", "0x10", "1e", "-0",
        "\u0661\u0660", "NaN"]
TOKEN = re.compile(r"[^\s,]+")


def _tokens(line: str) -> list[tuple[int, int]]:
    return [m.span() for m in TOKEN.finditer(line)]


def _pick_line(rng: random.Random, lines: list[str], need_tokens: bool = True) -> int | None:
    ok = [k for k, ln in enumerate(lines) if _tokens(ln) or not need_tokens]
    return rng.choice(ok) if ok else None


def _edit_token(rng: random.Random, text: str, how: str) -> str:
    lines = text.split("\n")
    k = _pick_line(rng, lines)
    if k is None:
        return text
    line = lines[k]
    spans = _tokens(line)
    a, b = rng.choice(spans)
    sep = "," if "," in line else " "
    if how == "delete":  # the token and the separator before it (after it when first)
        lines[k] = line[:a].rstrip(" ,") + (sep if a and b < len(line) else "") + \
            line[b:].lstrip(" ,") if a else line[b:].lstrip(" ,")
    elif how == "duplicate":
        lines[k] = line[:b] + sep + line[a:b] + line[b:]
    elif how == "insert":
        lines[k] = line[:a] + rng.choice(POOL) + sep + line[a:]
    elif how == "replace":
        lines[k] = line[:a] + rng.choice(POOL) + line[b:]
    elif how == "underscore":
        m = [i for i in range(a + 1, b) if line[i].isdigit() and line[i - 1].isdigit()]
        if m:
            i = rng.choice(m)
            lines[k] = line[:i] + "_" + line[i:]
    elif how == "arabic":
        m = [i for i in range(a, b) if line[i] in "0123456789"]
        if m:
            i = rng.choice(m)
            lines[k] = line[:i] + chr(0x660 + int(line[i])) + line[i + 1:]
    return "\n".join(lines)


def _move_token(rng: random.Random, text: str) -> str:
    """The last token of a line to the start of the next data line, or the first token of a
    line to the end of the previous one: one line with a field too many, one too few."""
    lines = text.split("\n")
    data = [k for k, ln in enumerate(lines) if _tokens(ln)]
    if len(data) < 2:
        return text
    p = rng.randrange(len(data) - 1)
    k, n = data[p], data[p + 1]
    sep = "," if "," in lines[k] else " "
    if rng.random() < 0.5:
        a, b = _tokens(lines[k])[-1]
        tok, lines[k] = lines[k][a:b], lines[k][:a].rstrip(" ,")
        lines[n] = tok + sep + lines[n]
    else:
        a, b = _tokens(lines[n])[0]
        tok, lines[n] = lines[n][a:b], lines[n][b:].lstrip(" ,")
        lines[k] = lines[k] + sep + tok
    return "\n".join(lines)


def _lines_op(rng: random.Random, text: str, how: str, comment: str | None) -> str:
    lines = text.split("\n")
    k, m = rng.randrange(len(lines)), rng.randrange(len(lines))
    if how == "swap":
        lines[k], lines[m] = lines[m], lines[k]
    elif how == "dup":
        lines.insert(m, lines[k])
    elif how == "del":
        del lines[k]
    elif how == "blank":
        lines.insert(k, rng.choice(["", "  ", "\t"]))
    elif how == "comment" and comment:
        lines.insert(k, comment + " caf\u00e9 \u00a0 note")
    return "\n".join(lines)


BENIGN = {"bom", "crlf", "blank", "comment"}
MUTATIONS = ["delete", "duplicate", "insert", "replace", "underscore", "arabic", "move",
             "swap", "dup", "del", "blank", "comment", "non-utf8", "bom", "nbsp", "tab",
             "truncate", "crlf", "break", "nonfinite", "huge", "rename"]


def mutate(fmt: Format, seed: int) -> tuple[bytes, list[str]]:
    """The mutated file's bytes and the mutations applied (one or two)."""
    rng = random.Random(seed)
    names = [rng.choice(MUTATIONS) for _ in range(1 if rng.random() < 0.7 else 2)]
    text = fmt.seed
    for name in names:
        if name in ("delete", "duplicate", "insert", "replace", "underscore", "arabic"):
            text = _edit_token(rng, text, name)
        elif name == "nonfinite":
            text = _edit_token(random.Random(seed + 1), text, "replace")
        elif name == "huge":
            lines = text.split("\n")
            k = _pick_line(rng, lines)
            if k is not None:
                a, b = _tokens(lines[k])[rng.randrange(min(3, len(_tokens(lines[k]))))]
                lines[k] = lines[k][:a] + rng.choice(
                    ["9" * 25, "9223372036854775808", "18446744073709551616",
                     "9007199254740993", "8646911284551352321"]) + lines[k][b:]
            text = "\n".join(lines)
        elif name == "rename":  # every standalone integer n becomes another (a vertex id)
            ints = sorted(set(re.findall(r"(?<![^\s,])\d+(?![^\s,])", text)))
            if ints:
                old = re.escape(rng.choice(ints))
                new = rng.choice(["9007199254740993", "8646911284551352321", str(2**63),
                                  "1_0", "\u0661", "17"])
                text = re.sub(rf"(?<![^\s,]){old}(?![^\s,])", new, text)
        elif name == "move":
            text = _move_token(rng, text)
        elif name in ("swap", "dup", "del", "blank", "comment"):
            text = _lines_op(rng, text, name, fmt.comment)
        elif name == "bom" and not text.startswith("\ufeff"):
            text = "\ufeff" + text
        elif name in ("nbsp", "tab"):
            spaces = [i for i, c in enumerate(text) if c == " "]
            if spaces:
                i = rng.choice(spaces)
                text = text[:i] + ("\u00a0" if name == "nbsp" else "\t") + text[i + 1:]
        elif name == "crlf":
            text = text.replace("\n", "\r\n")
        elif name == "break":
            i = rng.randrange(len(text))
            text = text[:i] + rng.choice(["\r", "\x0b", "\x0c", "\x1c", "\u2028"]) + text[i:]
    data = text.encode("utf-8")
    if "non-utf8" in names:
        i = rng.randrange(len(data) + 1)
        data = data[:i] + bytes([rng.choice([0x80, 0xE9, 0xFF, 0xC3])]) + data[i:]
    if "truncate" in names:
        data = data[:rng.randrange(len(data))]
    return data, names


# ---------------------------------------------------------------------- the oracle
def _same(got: Any, want: Any, atol: float) -> bool:
    if isinstance(want, dict):
        return (isinstance(got, dict) and got.keys() == want.keys()
                and all(_same(got[k], want[k], atol) for k in want))
    if isinstance(want, list) and want and all(type(x) is float for x in want):
        want = np.asarray(want)
    if isinstance(want, np.ndarray) and want.dtype.kind in "iu":  # ids: exact
        return bool(np.array_equal(np.asarray(got), want))
    if isinstance(want, np.ndarray):
        got = np.asarray(got)
        return (got.shape == want.shape and got.dtype.kind in "fiu"
                and bool(np.allclose(got, want, rtol=1e-12, atol=atol)))
    return bool(got == want)


def check(fmt: Format, path: Path, data: bytes, benign: bool) -> str | None:
    """``None`` when the reader's outcome is allowed, else what went wrong."""
    path.write_bytes(data)
    try:
        text = data.decode("utf-8")
        want = fmt.reference(text)
    except (ValueError, OverflowError):  # not UTF-8, or a field int/float refuses
        want = REJECT
    if benign:
        want = fmt.reference(fmt.seed)
    try:
        got = fmt.read(path)
    except ValueError as e:
        msg = str(e)
        if isinstance(e, UnicodeError) or not msg.startswith(f"{path}:"):
            return f"{type(e).__name__} without FILE: {msg[:200]}"
        m = re.match(rf"{re.escape(str(path))}:(\d+):", msg)
        n_lines = len(data.decode("utf-8", "replace").splitlines())
        if m and not 1 <= int(m.group(1)) <= n_lines + 1:
            return f"line {m.group(1)} outside the file ({n_lines} lines): {msg[:200]}"
        if benign:
            return f"a benign mutation refused: {msg[:200]}"
        return None
    except Exception as e:  # noqa: BLE001 - any other type is the failure looked for
        return f"{type(e).__name__}: {str(e)[:200]}"
    if want is REJECT:
        return "accepted text the reference refuses (a re-aligned or invalid line)"
    if not _same(fmt.parsed(got), want, fmt.atol):
        return "parsed records differ from the reference reading of the file"
    return None


@pytest.mark.parametrize("name", list(FORMATS))
def test_issue19_fuzz_readers(tmp_path, name):
    fmt = FORMATS[name]
    path = tmp_path / f"fuzz{fmt.suffix}"
    assert check(fmt, path, fmt.seed.encode(), benign=True) is None  # the seed reads
    failures = []
    base = 1000 * list(FORMATS).index(name)
    for k in range(CASES):
        data, names = mutate(fmt, base + k)
        why = check(fmt, path, data, benign=set(names) <= BENIGN)
        if why is not None:
            failures.append(f"case {base + k} {names}: {why}")
    assert not failures, f"{len(failures)} of {CASES} cases:\n" + "\n".join(failures[:12])
