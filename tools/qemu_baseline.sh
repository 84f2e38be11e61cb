#!/usr/bin/env bash
# The compiled kernels on older CPUs (issue 21): runs the kernel tests under qemu-user's
# emulation of a baseline x86-64 CPU (Nehalem: SSE4.2, no AVX, so the loader picks the
# baseline version of every hot loop) and of Haswell (AVX2 + FMA, no AVX-512: the
# x86-64-v3 clones). A build with -march=native or an AVX instruction outside the clones dies
# there with "Illegal instruction" (exit 132).
#
#   tools/qemu_baseline.sh [pytest args]      # from the checkout root, after a build
#
# Needs qemu-user (Debian: apt-get install qemu-user). Environment: PYTHON (the interpreter
# whose microlie is tested; default python3), PYTHONPATH as for any run (e.g. src for the
# inplace build), CPUS (default "Nehalem Haswell"). Default tests: the compiled kernels against
# the generic ones on the hard inputs, float32 and float64, batched and single
# (tests/test_fast.py) and the compiled text reader. Also run (session 8, Nehalem: pass):
# tests/test_optim_compiled.py tests/test_schur_compiled.py; tests/test_optim_cholesky.py is too
# slow under emulation (more than 10 min).
set -euo pipefail
PY=${PYTHON:-python3}
QEMU=$(command -v qemu-x86_64 || command -v qemu-x86_64-static || true)
[ -n "$QEMU" ] || { echo "qemu_baseline: qemu-x86_64 not found (apt-get install qemu-user)"; exit 2; }
args=("$@")
[ ${#args[@]} -gt 0 ] || args=(tests/test_fast.py tests/test_traj_io_fast.py
    -k "agree or used_by or one_element or rejects or parse")
status=0
for cpu in ${CPUS:-Nehalem Haswell}; do
    echo "== qemu-x86_64 -cpu $cpu"
    "$QEMU" -cpu "$cpu" "$PY" -c "import microlie; from microlie import _fast; \
from microlie._c import _info; print(_fast.describe()); print(_info.info())"
    "$QEMU" -cpu "$cpu" "$PY" -m pytest -p no:cacheprovider -o addopts= -q "${args[@]}" \
        || status=$?
done
exit $status
