"""Check that the compiled extensions run on a baseline x86-64 CPU: no wide-vector instruction
(AVX, AVX2, FMA, AVX-512, or the BMI/MOVBE/LZCNT instructions of x86-64-v3) outside the clones
that the loader only picks on a CPU that has them (``target_clones``: functions named
``*.arch_x86_64_v3`` / ``*.arch_x86_64_v4``; see src/microlie/_c/dispatch.h).

    python tools/check_isa.py [FILE.so ...]   # default: the built microlie._c modules

Reads ``objdump -d`` of each file, prints one line per file (instructions, functions, clones,
wide instructions inside and outside the clones, the first offenders) and exits 1 if any wide
instruction lies outside a clone (2 when objdump is missing). On other machines than x86-64 it
says so and checks nothing.
"""

from __future__ import annotations

import importlib
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

CLONE = re.compile(r"\.(arch_x86_64_v[34]|avx2|avx512\w*|fma)\b")
WIDE_REG = re.compile(r"%(ymm|zmm)\d+|%k[0-7]\b")
# VEX/EVEX mnemonics all start with "v"; these "v..." are not vector instructions
NOT_VEX = {"verr", "verw", "vmcall", "vmlaunch", "vmresume", "vmxoff", "vmxon", "vmread",
           "vmwrite", "vmptrld", "vmptrst", "vmclear", "vmfunc", "vmrun", "vmload", "vmsave"}
# x86-64-v3's scalar additions (Haswell), absent from Nehalem (tzcnt is left out: GCC emits
# "rep bsf", which objdump prints as tzcnt and which runs as bsf on older CPUs)
V3_SCALAR = {"andn", "bextr", "blsi", "blsmsk", "blsr", "bzhi", "mulx", "pdep", "pext", "rorx",
             "sarx", "shlx", "shrx", "movbe", "lzcnt"}
@dataclass
class Report:
    """What :func:`scan` found in one disassembly."""

    instructions: int = 0
    functions: int = 0
    clones: int = 0
    wide_in_clones: int = 0
    wide_outside: list[str] = field(default_factory=list)  # "function: instruction"


def is_wide(mnemonic: str, operands: str) -> bool:
    """Whether an instruction needs more than x86-64-v2 (SSE4.2, POPCNT)."""
    if WIDE_REG.search(operands):
        return True
    if mnemonic.startswith("v") and mnemonic not in NOT_VEX:
        return True
    return mnemonic in V3_SCALAR


def scan(disassembly: str) -> Report:
    """Count the wide instructions of an ``objdump -d --no-show-raw-insn`` listing, inside and
    outside the clone functions.

    Examples
    --------
    >>> text = '''0000000000001000 <f.default>:
    ...     1000:\\tmulsd  %xmm1,%xmm0
    ... 0000000000001100 <f.arch_x86_64_v3>:
    ...     1100:\\tvfmadd231sd %xmm2,%xmm1,%xmm0
    ... 0000000000001200 <g>:
    ...     1200:\\tvaddpd %ymm1,%ymm2,%ymm3
    ... '''
    >>> r = scan(text)
    >>> (r.functions, r.clones, r.wide_in_clones, r.wide_outside)
    (3, 1, 1, ['g: vaddpd %ymm1,%ymm2,%ymm3'])
    """
    r = Report()
    fn, in_clone = "?", False
    for line in disassembly.splitlines():
        head = re.match(r"^[0-9a-f]+ <(.+)>:$", line.strip())
        if head:
            fn = head.group(1)
            in_clone = bool(CLONE.search(fn))
            r.functions += 1
            r.clones += in_clone
            continue
        parts = line.split("\t")
        if len(parts) < 2 or not re.match(r"^\s*[0-9a-f]+:$", parts[0]):
            continue
        ins = parts[-1].strip()
        if not ins or ins.startswith("("):
            continue
        words = ins.split(None, 1)
        mnemonic = words[0]
        if mnemonic in ("rep", "repz", "repnz", "lock", "notrack", "bnd", "data16") and \
                len(words) > 1:
            words = words[1].split(None, 1)
            mnemonic = words[0]
        operands = words[1] if len(words) > 1 else ""
        r.instructions += 1
        if is_wide(mnemonic, operands):
            if in_clone:
                r.wide_in_clones += 1
            else:
                r.wide_outside.append(f"{fn}: {mnemonic} {operands}".strip())
    return r


def built_modules() -> list[Path]:
    """The files of the importable microlie._c modules."""
    from microlie._fast import NAMES

    files = []
    for name in (*NAMES, "_info"):
        try:
            files.append(Path(importlib.import_module(f"microlie._c.{name}").__file__))
        except ImportError:
            pass
    return files


def main(argv: list[str]) -> int:
    import platform

    if platform.machine().lower() not in ("x86_64", "amd64"):
        print(f"check_isa: {platform.machine()} is not x86-64: nothing checked")
        return 0
    objdump = shutil.which("objdump")
    if objdump is None:
        print("check_isa: objdump not found (binutils)")
        return 2
    files = [Path(a) for a in argv] or built_modules()
    if not files:
        print("check_isa: no compiled module found (build first: python setup.py build_ext "
              "--inplace, or pass the .so files)")
        return 2
    bad = 0
    for f in files:
        text = subprocess.run([objdump, "-d", "--no-show-raw-insn", str(f)], check=True,
                              capture_output=True, text=True).stdout
        r = scan(text)
        bad += len(r.wide_outside)
        first = "; ".join(r.wide_outside[:3])
        print(f"{f.name}: {r.instructions} instructions, {r.functions} functions, "
              f"{r.clones} clones; wide instructions: {r.wide_in_clones} in clones, "
              f"{len(r.wide_outside)} outside" + (f" ({first})" if first else ""))
    print("check_isa: " + ("OK, nothing wider than x86-64-v2 outside the dispatched clones"
                           if not bad else f"FAIL, {bad} wide instructions outside the clones"))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
