"""``microlie optimize FILE --json -o OUT --init file -q`` from several source trees against
the GTSAM script, interleaved: a before/after of ``pose_graph.py --e2e``.

Each round runs, per graph, every tree with (``fast``: ``--python``) and without (``numpy``:
``--gtsam-python`` with ``MICROLIE_FAST=0``, the default install) the compiled extra, then
``gtsam_optimize.py``; wall time from process start to exit and the process's peak RSS
(``pose_graph._timed_process``). Prints, per contender, the medians and the median of the
per-round ratios to the GTSAM script (range). A tree is byte-compiled first (as ``pip
install`` does) unless it is given as ``nopyc:DIR``. Make a tree of a commit with
``git archive COMMIT src | tar -x -C DIR``::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src /work/bench-venv/bin/python benchmarks/e2e_trees.py \
        --python /work/main/.venv/bin/python --repeat 3 \
        nopyc:/tmp/old-nopyc/src /tmp/old/src src
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pose_graph import DATA, GRAPHS, _timed_process  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trees", nargs="+", help="src directories ([nopyc:]DIR)")
    ap.add_argument("--graphs", nargs="*", default=["sphere2500", "parking-garage", "M3500"],
                    choices=[g for g, (_, start) in GRAPHS.items() if start == "file"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--python", default=sys.executable, help="with the compiled extra")
    ap.add_argument("--gtsam-python", default=sys.executable, help="GTSAM; default install")
    args = ap.parse_args()
    trees = {t: t.removeprefix("nopyc:") for t in args.trees}
    for t, src in trees.items():
        if not t.startswith("nopyc:"):
            for exe in {args.python, args.gtsam_python}:
                subprocess.run([exe, "-m", "compileall", "-q", src], check=True,
                               stdout=subprocess.DEVNULL)
    script = str(Path(__file__).resolve().parent / "gtsam_optimize.py")
    base = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MICROLIE_FAST")}
    out = "/tmp/e2e_trees_out.g2o"
    for g in args.graphs:
        path = str(DATA / GRAPHS[g][0])
        res: dict[str, list[tuple[float, float]]] = {}
        for rnd in range(args.repeat + 1):  # the first round warms the file cache
            for t, src in trees.items():
                for kind, exe, fast in (("fast", args.python, "1"),
                                        ("numpy", args.gtsam_python, "0")):
                    env = dict(base, PYTHONPATH=src, MICROLIE_FAST=fast)
                    w, pk, text = _timed_process([exe, "-m", "microlie.cli", "optimize", path,
                                                  "--json", "-o", out, "--init", "file", "-q"],
                                                 env)
                    json.loads(text.strip().splitlines()[-1])  # a report was written
                    if rnd:
                        res.setdefault(f"{t} {kind}", []).append((w, pk))
            w, pk, _ = _timed_process([args.gtsam_python, script, path, out], base)
            if rnd:
                res.setdefault("GTSAM script", []).append((w, pk))
        gt = res["GTSAM script"]
        print(f"{g}: GTSAM script {statistics.median(r[0] for r in gt):.3f} s "
              f"{statistics.median(r[1] for r in gt):.0f} MB")
        for c, rs in res.items():
            if c == "GTSAM script":
                continue
            qw = [a[0] / b[0] for a, b in zip(rs, gt, strict=True)]
            qp = [a[1] / b[1] for a, b in zip(rs, gt, strict=True)]
            print(f"  {c}: {statistics.median(r[0] for r in rs):.3f} s "
                  f"{statistics.median(qw):.2f}x ({min(qw):.2f}-{max(qw):.2f}), "
                  f"{statistics.median(r[1] for r in rs):.0f} MB "
                  f"{statistics.median(qp):.2f}x ({min(qp):.2f}-{max(qp):.2f})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
