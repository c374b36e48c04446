"""Where a render's time goes, by kernel: perf samples with the cached numba kernels named.

    .venv/bin/python bench/profile.py spd:sample:1 [--seconds 8] [--threads 1] [--resolution 512] [--top 25]

Runs `perf record` on a warm process that renders the scene (SPD mode) again and again for
--seconds, then prints perf's report by symbol. perf cannot name code that numba loads from its
cache (it lives in anonymous memory), so the child keeps each kernel library's object code as
numba loads it, reads its symbols with objdump (local ones too: the private kernels, such as
the Whitted trace and the 4-wide walk, are compiled into their caller's object) and writes
/tmp/perf-PID.map, which perf reads. Needs Linux perf and objdump (binutils); Python around
the renders (image assembly, garbage collection) shows up under CPython's own symbols.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _keep_object_code():
    """From here on, remember each kernel library's object code as numba loads or compiles it."""
    from numba.core import codegen

    kept = []
    set_object = codegen.CPUCodeLibrary._set_compiled_object

    def keeping(self, value):
        kept.append((self, value))
        return set_object(self, value)

    codegen.CPUCodeLibrary._set_compiled_object = keeping
    return kept


def _short(name: str) -> str:
    """module.function of a numba symbol (its Itanium-mangled nested name, without the types)."""
    prefix = "cfunc." if name.startswith("cfunc.") else ""
    rest = name[len(prefix):]
    if not rest.startswith("_ZN"):
        return name[:80]
    rest, parts = rest[3:], []
    while rest[:1].isdigit():
        digits = re.match(r"\d+", rest).group(0)
        parts.append(rest[len(digits):len(digits) + int(digits)])
        rest = rest[len(digits) + int(digits):]
    return prefix + ".".join(parts[:4])


def _write_map(kept) -> int:
    """/tmp/perf-PID.map for every kept library: each function's address is its offset in the
    object plus the address the engine gave one of its global functions, less that one's offset."""
    symbols = {}
    for library, blob in kept:
        with tempfile.NamedTemporaryFile(suffix=".o", delete=False) as f:
            f.write(blob)
        try:
            table = subprocess.run(["objdump", "-t", f.name], capture_output=True, text=True).stdout
        finally:
            os.unlink(f.name)
        rows = []
        for line in table.splitlines():
            m = re.match(r"([0-9a-f]{16}) (.{7}) (\S+)\s+([0-9a-f]{16}) (\S+)", line)
            if m and "F" in m.group(2):
                rows.append((int(m.group(1), 16), int(m.group(4), 16), "g" in m.group(2), m.group(5)))
        base = None
        for offset, _, is_global, name in rows:
            if is_global:
                try:
                    address = library._codegen._engine.get_function_address(name)
                except Exception:
                    address = 0
                if address:
                    base = address - offset
                    break
        if base is not None:
            symbols.update({base + offset: (size, name) for offset, size, _, name in rows})
    with open(f"/tmp/perf-{os.getpid()}.map", "w") as f:
        for address in sorted(symbols):
            size, name = symbols[address]
            f.write(f"{address:x} {size:x} {_short(name)}\n")
    return len(symbols)


def child(args) -> None:
    kept = _keep_object_code()
    sys.path.insert(0, str(ROOT / "src"))
    import raykernel

    scene = raykernel.load(args.scene)
    options = dict(spd=True, resolution=args.resolution, threads=args.threads)
    raykernel.render(scene, **options)      # compiles or loads every kernel the renders use
    print(f"named {_write_map(kept)} kernel functions", flush=True)
    Path(args.child).write_text(str(os.getpid()))      # which map the report reads, and then removes
    start, renders = time.perf_counter(), 0
    while time.perf_counter() - start < args.seconds:
        result = raykernel.render(scene, **options)
        renders += 1
    print(f"{renders} renders of {args.scene}, trace {result.stats['time.trace'] * 1e3:.1f} ms each", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--child", help=argparse.SUPPRESS)     # the child's pid goes to this file
    args = ap.parse_args()
    if args.child:
        child(args)
        return
    missing = [tool for tool in ("perf", "objdump") if shutil.which(tool) is None]
    if missing:
        sys.exit(f"bench/profile.py needs {' and '.join(missing)} (Linux perf, binutils)")
    with tempfile.TemporaryDirectory() as tmp:
        data = f"{tmp}/perf.data"
        pid_file = Path(tmp) / "pid"
        command = [sys.executable, __file__, "--child", str(pid_file), args.scene, "--seconds", str(args.seconds),
                   "--threads", str(args.threads), "--resolution", str(args.resolution)]
        try:
            subprocess.run(["perf", "record", "-q", "-o", data, "--", *command], check=True)
            report = subprocess.run(["perf", "report", "-i", data, "--sort", "sym", "--stdio"], capture_output=True,
                                    text=True, check=True).stdout
        finally:
            if pid_file.exists():
                Path(f"/tmp/perf-{pid_file.read_text()}.map").unlink(missing_ok=True)
    rows = [line for line in report.splitlines() if line.strip() and not line.startswith("#")]
    print("\n".join(rows[:args.top]))


if __name__ == "__main__":
    main()
