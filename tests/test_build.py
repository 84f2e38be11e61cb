"""The compiled layer as installed (issue 21): ``microlie --version`` says which kernels are
active and why; the built extensions hold no wide-vector instruction outside their dispatched
clones (tools/check_isa.py on objdump's listing; checked against listings with known content);
the source archive holds every file the build and the tests need."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
from conftest import IN_CI, require

from microlie import _fast

ROOT = Path(__file__).resolve().parents[1]


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # (its dataclass looks its module up)
    spec.loader.exec_module(mod)
    return mod


def _version(**env: str) -> str:
    out = subprocess.run([sys.executable, "-m", "microlie.cli", "--version"], check=True,
                         capture_output=True, text=True, env=dict(os.environ, **env)).stdout
    assert len(out.splitlines()) == 1, out
    return out.strip()


def test_version_line_names_the_active_kernels():
    assert _version(MICROLIE_FAST="0").endswith("kernels: generic NumPy (MICROLIE_FAST=0)")
    if os.environ.get("MICROLIE_FAST") == "0":
        return
    require("microlie._c._lie")
    line = _version()
    info = require("microlie._c._info").info()
    from microlie._fast import NAMES

    assert f"kernels: compiled ({len(NAMES)} modules" in line, line
    assert f"this CPU: {info['active']}" in line, line
    assert info["active"] in ("baseline", "x86-64-v3", "x86-64-v4")


def test_describe_says_why_the_generic_kernels_run(monkeypatch):
    """Without built modules, the line quotes the build's record: skipped, or the compiler's
    last error line."""
    monkeypatch.setattr(_fast, "module", lambda name: None)
    monkeypatch.setattr(_fast, "build_record", lambda: {"skipped": "MICROLIE_BUILD_EXT=0"})
    assert _fast.describe() == ("kernels: generic NumPy (compiled extensions not built: "
                                "MICROLIE_BUILD_EXT=0)")
    err = "command '/nowhere/cc' failed: No such file or directory"
    monkeypatch.setattr(_fast, "build_record", lambda: {"failed": {"_lie": "x\n" + err}})
    assert _fast.describe() == ("kernels: generic NumPy (compiled extensions failed to build: "
                                f"{err})")
    monkeypatch.setattr(_fast, "build_record", dict)
    assert "pip install . builds them" in _fast.describe()


def test_isa_scanner_finds_wide_instructions_outside_clones():
    """The scanner against listings whose answer is known by construction."""
    scan = _tool("check_isa").scan
    base = ("0000000000001000 <f.default>:\n    1000:\tmovapd %xmm1,%xmm0\n"
            "    1004:\tpopcnt %rax,%rbx\n    1008:\trep bsf %eax,%eax\n"
            "0000000000001100 <f.arch_x86_64_v4>:\n    1100:\tvaddpd %zmm1,%zmm2,%zmm3{%k1}\n"
            "    1106:\tkmovw %k1,%eax\n")
    r = scan(base)
    assert (r.instructions, r.functions, r.clones, r.wide_in_clones, r.wide_outside) == \
        (5, 2, 1, 2, [])
    bad = base + ("0000000000001200 <g>:\n    1200:\tvmovsd %xmm0,(%rdi)\n"
                  "    1204:\tshlx %rax,%rbx,%rcx\n    1208:\tkmovw %k1,%eax\n"
                  "    120c:\tvzeroupper\n")
    assert len(scan(bad).wide_outside) == 4


@pytest.mark.skipif(sys.platform != "linux", reason="the ISA check reads ELF x86-64 objects")
def test_built_extensions_have_no_wide_instruction_outside_the_clones():
    import platform

    if platform.machine() != "x86_64":
        pytest.skip(f"{platform.machine()}: the check is for x86-64")
    if shutil.which("objdump") is None:
        if IN_CI:
            pytest.fail("objdump (binutils) is required in CI for the ISA check")
        pytest.skip("objdump (binutils) not found")
    lie = require("microlie._c._lie")
    info = require("microlie._c._info").info()
    if info["baseline"] == "-march=native":
        pytest.skip("a MICROLIE_NATIVE=1 build: for this CPU only")
    check = _tool("check_isa")
    files = check.built_modules()
    from microlie._fast import NAMES

    assert Path(lie.__file__) in files and len(files) == len(NAMES) + 1
    out = subprocess.run([sys.executable, str(ROOT / "tools" / "check_isa.py"),
                          *map(str, files)], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout
    if info["clones"]:  # the hot loops of _lie were cloned: wide code exists, inside them
        first = out.stdout.splitlines()[0]
        assert first.startswith(Path(lie.__file__).name) and " 0 in clones" not in first, first


def test_source_archive_holds_what_the_build_and_the_tests_need(tmp_path):
    """setup.py sdist: every C source and header, the generator, the tests and fixtures, the
    licence, changelog and citation; no built file."""
    import setuptools

    if int(setuptools.__version__.split(".")[0]) < 77 and not IN_CI:
        pytest.skip(f"setuptools {setuptools.__version__} < 77 (the build requirement) "
                    "cannot read pyproject.toml's license")
    r = subprocess.run([sys.executable, "setup.py", "-q", "sdist", "-d", str(tmp_path)],
                       cwd=ROOT, capture_output=True, text=True, env=dict(
                           os.environ, MICROLIE_BUILD_EXT="0"))
    assert r.returncode == 0, r.stderr
    (archive,) = tmp_path.glob("microlie-*.tar.gz")
    with tarfile.open(archive) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    need = {"setup.py", "pyproject.toml", "LICENSE", "README.md", "CHANGELOG.md",
            "CITATION.cff", "MANIFEST.in", "tools/gen_coeffs.py", "tools/check_isa.py",
            "tests/conftest.py"}
    need |= {str(p.relative_to(ROOT)) for p in (ROOT / "src" / "microlie" / "_c").glob("*.[ch]")}
    need |= {str(p.relative_to(ROOT)) for p in (ROOT / "tests").rglob("*")
             if p.is_file() and "__pycache__" not in p.parts}
    assert not need - names, sorted(need - names)
    assert not [n for n in names if n.endswith((".so", ".o", ".pyc", "_build.json"))]
