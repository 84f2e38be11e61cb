#!/usr/bin/env bash
# The package as a user gets it (issue 21), in two checks; run from anywhere:
#
#   tools/wheel_check.sh [wheel]        # default
#     1. builds the sdist from the checkout, then the wheel FROM THE SDIST (python -m build, in
#        isolated environments: the sdist must hold every header and the build requirements must
#        work), with MICROLIE_REQUIRE_EXT=1 (a wheel without its compiled modules is an error);
#     2. lists what the wheel holds (LICENSE, the modules, its tag) and, when auditwheel can be
#        installed, what `auditwheel show` says about it (manylinux tags come from cibuildwheel's
#        `auditwheel repair` in CI; a local build is tagged linux_x86_64);
#     3. installs the wheel in a fresh virtualenv and runs the kernel tests of the unpacked sdist
#        against it with no compiler on PATH (PATH = the venv only, CC = a missing program),
#        failing if any compiled-code test was skipped or microlie came from anywhere but the
#        venv.
#   tools/wheel_check.sh no-compiler [pytest args]
#     installs a clean copy of the checkout (`pip install ".[test]"`) in a fresh virtualenv
#     whose CC is a missing program: the install must succeed and `microlie --version` must
#     say "generic"; then runs pytest with the given arguments (default: tests/, the whole
#     suite) from the copy against the installed package.
#
# Environment: PYTHON (default python3), KEEP=1 keeps the work directory (printed).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY=${PYTHON:-python3}
W=$(mktemp -d /tmp/microlie-check.XXXXXX)
[ "${KEEP:-0}" = 1 ] || trap 'rm -rf "$W"' EXIT
echo "work directory: $W"
NOCC="$W/no-such-compiler/cc"

if [ "${1:-}" = no-compiler ]; then
    shift
    # a clean copy of the checkout (tracked and new files, not the ignored build/ or *.so that
    # setuptools would reuse), beside a link to ../shared/data for the tests that read it
    mkdir "$W/checkout"
    (cd "$ROOT" && git ls-files -co --exclude-standard -z | xargs -0 tar c) | tar x -C "$W/checkout"
    [ -d "$ROOT/../shared" ] && ln -s "$(cd "$ROOT/../shared" && pwd)" "$W/shared"
    "$PY" -m venv "$W/venv"
    CC="$NOCC" "$W/venv/bin/pip" install -v "$W/checkout[test]" > "$W/install.log" 2>&1 \
        || { tail -30 "$W/install.log"; echo "FAIL: pip install without a compiler"; exit 1; }
    grep -m3 "microlie: " "$W/install.log" || true
    line=$(cd /tmp && PATH="$W/venv/bin" "$W/venv/bin/microlie" --version)
    echo "microlie --version: $line"
    case "$line" in *"kernels: generic"*) ;; *) echo "FAIL: expected generic kernels"; exit 1;; esac
    cd "$W/checkout"
    args=("$@")
    [ ${#args[@]} -gt 0 ] || args=(tests)
    env PATH="$W/venv/bin:/usr/bin:/bin" CC="$NOCC" "$W/venv/bin/python" -m pytest \
        -p no:cacheprovider -o addopts="" -q -rs "${args[@]}" | tee "$W/pytest.log"
    exit "${PIPESTATUS[0]}"
fi

# 1. sdist, then the wheel from the sdist
"$PY" -m venv "$W/tools"
"$W/tools/bin/pip" install -q build
if [ -n "${1:-}" ]; then
    WHEEL=$1
    "$W/tools/bin/python" -m build --sdist --outdir "$W/dist" "$ROOT" > "$W/build.log" 2>&1
else
    MICROLIE_REQUIRE_EXT=1 "$W/tools/bin/python" -m build --outdir "$W/dist" "$ROOT" \
        > "$W/build.log" 2>&1 || { tail -40 "$W/build.log"; echo "FAIL: build"; exit 1; }
    WHEEL=$(ls "$W"/dist/*.whl)
fi
SDIST=$(ls "$W"/dist/*.tar.gz)
echo "sdist: $(basename "$SDIST") ($(tar tzf "$SDIST" | wc -l) files); wheel built from it: $(basename "$WHEEL")"

# 2. what the wheel holds
"$PY" - "$WHEEL" <<'EOF'
import json, sys, zipfile
z = zipfile.ZipFile(sys.argv[1])
names = z.namelist()
lic = [n for n in names if n.endswith("LICENSE") and ".dist-info/" in n]
mods = sorted(n.split("/")[-1].split(".")[0] for n in names
              if n.startswith("microlie/_c/") and n.endswith((".so", ".pyd")))
tag = [l for l in z.read(next(n for n in names if n.endswith(".dist-info/WHEEL"))).decode()
       .splitlines() if l.startswith("Tag:")]
rec = json.loads(z.read("microlie/_c/_build.json"))
print(f"wheel: {len(names)} files; LICENSE: {lic}; compiled modules: {mods}; {tag}")
print(f"wheel build record: flags {rec.get('flags')}, defines {rec.get('defines')}, "
      f"failed {list(rec.get('failed', {}))}")
assert lic, "no LICENSE in the wheel"
assert not [n for n in names if n.endswith((".c", ".h"))], "C sources in the wheel"
EOF
if "$W/tools/bin/pip" install -q auditwheel > /dev/null 2>&1; then
    "$W/tools/bin/auditwheel" show "$WHEEL" 2>&1 | sed -n '1,12p' | sed 's/^/auditwheel: /'
fi

# 3. a fresh virtualenv, no compiler: install the wheel, run the kernel tests of the sdist
#    (setuptools>=77: tests/test_build.py makes an sdist of the unpacked sdist; objdump alone on
#    PATH besides the venv, for the ISA check)
"$PY" -m venv "$W/venv"
"$W/venv/bin/pip" install -q "$WHEEL" pytest hypothesis mpmath "setuptools>=77"
mkdir "$W/src" "$W/bin" && tar xzf "$SDIST" -C "$W/src"
if command -v objdump > /dev/null; then ln -s "$(command -v objdump)" "$W/bin/objdump"; fi
cd "$W/src"/microlie-*
RUN=(env -i HOME="$HOME" PATH="$W/venv/bin:$W/bin" CC="$NOCC")
"${RUN[@]}" "$W/venv/bin/python" -c "import shutil, sys; found = [c for c in ('gcc', 'cc', \
'clang', 'c99') if shutil.which(c)]; print('compilers on PATH:', found or 'none'); \
sys.exit(1 if found else 0)" || { echo "FAIL: a compiler is on PATH"; exit 1; }
"${RUN[@]}" "$W/venv/bin/microlie" --version
# the tests import the installed wheel, not the unpacked sources (src/ is not on sys.path)
"${RUN[@]}" "$W/venv/bin/python" -c \
    "import microlie, sys; assert '$W/venv' in microlie.__file__, microlie.__file__"
set +e
"${RUN[@]}" "$W/venv/bin/python" -m pytest \
    -p no:cacheprovider -o addopts="" -q -rs tests/test_fast.py tests/test_kernels.py \
    tests/test_single.py tests/test_build.py tests/test_traj_io_fast.py 2>&1 | tee "$W/pytest.log"
status=${PIPESTATUS[0]}
set -e
if grep -q "was not built" "$W/pytest.log"; then
    echo "FAIL: compiled-code tests were skipped"; exit 1
fi
[ "$status" = 0 ] && echo "wheel_check: OK" || echo "wheel_check: FAIL (pytest exit $status)"
exit "$status"
