"""Shared by the benchmark scripts: machine description, scene files, BENCHMARKS.md sections.

    replace_section("spd_scenes", markdown_text)   # rewrites only that section
    path = spd_file("teapot", 6, ".obj")           # SPD teapot at size 6 as OBJ, written once by raykernel
"""

from __future__ import annotations

import os
import platform
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "BENCHMARKS.md"
CACHE = ROOT / "bench" / ".cache"       # scene files the benches make with raykernel's own writers


def machine() -> str:
    import numba
    import numpy
    cpu = platform.processor() or platform.machine()
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import raykernel
    return (f"{cpu}, {os.cpu_count()} cores, {numba.get_num_threads()} threads; Python {sys.version.split()[0]}, "
            f"numpy {numpy.__version__}, numba {numba.__version__}, raykernel {raykernel.__version__}, "
            f"{platform.system()} {platform.release()}")


def replace_section(name: str, text: str) -> None:
    """Put `text` between this section's markers in BENCHMARKS.md (atomically)."""
    begin, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    old = BENCHMARKS.read_text() if BENCHMARKS.exists() else "# Benchmarks\n\nEach section is written by the script it names; rerun it to refresh.\n"
    block = f"{begin}\n{text.rstrip()}\n{end}"
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    new = pattern.sub(lambda _: block, old) if pattern.search(old) else old.rstrip() + "\n\n" + block + "\n"
    tmp = BENCHMARKS.with_suffix(".md.tmp")
    tmp.write_text(new)
    os.replace(tmp, BENCHMARKS)


def spd_file(name: str, size: int, suffix: str) -> Path:
    """An SPD scene at `size` as a .nff, .obj or .pov file, written by raykernel's generators and
    converters into bench/.cache the first time it is asked for."""
    from raykernel.scene.convert import convert
    path = CACHE / f"{name}-sf{size}{suffix}"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        convert(f"spd:{name}:{size}", path)
    return path
