"""Shared by the benchmark scripts: machine description, scene files, BENCHMARKS.md sections.

    replace_section("spd_scenes", markdown_text)   # rewrites only that section (and its page, below)
    path = spd_file("teapot", 6, ".obj")           # SPD teapot at size 6 as OBJ, written once by raykernel

A section's text may hold a line that is exactly `<!-- details -->` (DETAILS): what comes before it
(heading, command, date, machine, the headline table, a line of reading) goes into BENCHMARKS.md,
followed by a link to docs/benchmarks/NAME.md, and the whole text (without that line) becomes
that page, its `## ` heading its `# ` title. Without the line, the whole text goes into
BENCHMARKS.md and no page is written. split_section() is that split on its own; subtable() and
pivot() make a headline table out of a full one (markdown lines in, markdown lines out), so that
a script and a migration of its old text make the same summary.
"""

from __future__ import annotations

import os
import platform
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "BENCHMARKS.md"
README = ROOT / "README.md"
PAGES = ROOT / "docs" / "benchmarks"    # one page per split section: the full tables
CACHE = ROOT / "bench" / ".cache"       # scene files the benches make with raykernel's own writers
DETAILS = "<!-- details -->"            # the line that ends a section's summary


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


def split_section(name: str, text: str) -> tuple[str, str | None]:
    """(summary, page) of a section's text: the summary for BENCHMARKS.md (the text before the
    DETAILS line and a link to the page), the page for docs/benchmarks/NAME.md (the whole text
    without that line, every heading one level up: the section's `## ` heading its `# ` title).
    Without a DETAILS line: (text, None)."""
    lines = text.rstrip().split("\n")
    if DETAILS not in lines:
        return "\n".join(lines), None
    cut = lines.index(DETAILS)
    before, after = lines[:cut], [line for line in lines[cut + 1:] if line != DETAILS]
    while before and not before[-1].strip():
        before.pop()
    while after and not after[0].strip():
        after.pop(0)
    link = f"docs/benchmarks/{name}.md"
    summary = "\n".join(before + ["", f"Full tables: [{link}]({link})."])
    page, fence = [], False
    for line in before + [""] + after:
        if line.startswith("```"):
            fence = not fence
        elif not fence and re.match(r"#{2,6} ", line):
            line = line[1:]                     # ## -> #, ### -> ##: the page's own levels
        page.append(line)
    if not page[0].startswith("# "):
        page = [f"# {name}", ""] + page
    return summary, "\n".join(page) + "\n"


def _write(path: Path, text: str) -> None:
    """Write `text` to `path` atomically (a temporary file beside it, then os.replace)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def replace_section(name: str, text: str) -> None:
    """Put `text` between this section's markers in BENCHMARKS.md, or its summary there and the
    whole of it in docs/benchmarks/NAME.md if it holds a DETAILS line (split_section); atomically."""
    summary, page = split_section(name, text)
    if page is not None:
        _write(PAGES / f"{name}.md", page)
    begin, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    old = BENCHMARKS.read_text() if BENCHMARKS.exists() else "# Benchmarks\n\nEach section is written by the script it names; rerun it to refresh.\n"
    block = f"{begin}\n{summary}\n{end}"
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    new = pattern.sub(lambda _: block, old) if pattern.search(old) else old.rstrip() + "\n\n" + block + "\n"
    _write(BENCHMARKS, new)
    write_readme_table()


def section(name: str, text: str | None = None) -> str:
    """The text between BENCHMARKS.md's markers of section `name` ("" where it has none)."""
    text = BENCHMARKS.read_text() if text is None else text
    found = re.search(f"<!-- bench:{re.escape(name)} -->\n(.*?)<!-- /bench:{re.escape(name)} -->", text, re.S)
    return found.group(1) if found else ""


def _ratios(body: str, rows: dict, ratio_after: str, column: str | None = None) -> list[float]:
    """The ratios in the column right after the header `ratio_after` (or in the column `column`) of
    the first table of `body` that has it, over the rows whose cells match `rows` ({header: value})."""
    for table in tables(body.split("\n")):
        header = _cells(table[0])
        if (column or ratio_after) not in header:
            continue
        at = header.index(column) if column else header.index(ratio_after) + 1
        out = []
        for line in table[2:]:
            cells = _cells(line)
            if all(cells[header.index(h)] == v for h, v in rows.items()) and cells[at] not in ("", "-"):  # -: not run
                out.append(float(cells[at].rstrip("x")))
        return out
    return []


def _span(values: list[float]) -> str:
    if not values:
        return "-"
    lo, hi = min(values), max(values)
    return f"{lo:.2f}x" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}-{hi:.2f}x"


# The README's performance table: one row per question, each read from the headline table its
# script wrote into BENCHMARKS.md (section, rows, the column the ratio follows, the peers).
HEADLINES = [
    ("SPD renders, 13 scenes, wall / work", "renders", "POV-Ray 3.7", lambda b: (
        _span(_ratios(b, {"scene": "all"}, "POV-Ray s")) + " / " + _span(_ratios(b, {"scene": "all"}, "POV-Ray work s")))),
    ("ray casting, coherent, double precision (the peers: single)", "raycast", "embreex, Mitsuba 3, Open3D",
     lambda b: ", ".join(_span(_ratios(b, {"rays": "coherent"}, f"{peer} Mrays/s"))
                         for peer in ("embreex", "mitsuba", "open3d"))),
    ("ray casting, incoherent, double precision (the peers: single)", "raycast", "embreex, Mitsuba 3, Open3D",
     lambda b: ", ".join(_span(_ratios(b, {"rays": "incoherent"}, f"{peer} Mrays/s"))
                         for peer in ("embreex", "mitsuba", "open3d"))),
    ("ray casting, coherent, single precision", "raycast", "embreex, Mitsuba 3, Open3D", lambda b: ", ".join(
        _span(_ratios(b, {"rays": "coherent"}, "single Mrays/s", column))
        for column in ("single ratio", "single vs mitsuba", "single vs open3d"))),
    ("ray casting, incoherent, single precision", "raycast", "embreex, Mitsuba 3, Open3D", lambda b: ", ".join(
        _span(_ratios(b, {"rays": "incoherent"}, "single Mrays/s", column))
        for column in ("single ratio", "single vs mitsuba", "single vs open3d"))),
    ("mesh build and first ray, default quality, double precision", "meshbuild", "Open3D", lambda b: _span(
        _ratios(b, {"library": "raykernel medium", "precision": "double"}, "build + 1 ray s"))),
    ("mesh build and first ray, default quality, single precision", "meshbuild", "Open3D", lambda b: _span(
        _ratios(b, {"library": "raykernel medium", "precision": "single"}, "build + 1 ray s"))),
    ("mesh build and first ray, the first of a fresh process", "meshbuild", "Open3D", lambda b: _span(
        _ratios(b, {"library": "raykernel medium", "precision": "double"}, "first s"))),
    ("contains, closed meshes", "proximity", "Open3D", lambda b: _span(
        _ratios(b, {"query": "contains (parity)"}, "Open3D s"))),
    ("closest_points", "proximity", "Open3D", lambda b: _span(_ratios(b, {"query": "closest_points"}, "Open3D s"))),
]


def readme_table(text: str | None = None) -> str:
    """The README's performance table, from BENCHMARKS.md's sections (`text`: its content)."""
    text = BENCHMARKS.read_text() if text is None else text
    lines = ["| question | raykernel's speed / the peer's | peer | date | machine |", "|---|---|---|---|---|"]
    for question, name, peer, read in HEADLINES:
        body = section(name, text)
        if not body:
            continue
        day = re.search(r"\((\d{4}-\d{2}-\d{2})\)", body)
        cpu = re.search(r"Machine: ([^,]+),", body)
        lines.append(f"| [{question}](docs/benchmarks/{name}.md) | {read(body)} | {peer} | "
                     f"{day.group(1) if day else '-'} | {cpu.group(1) if cpu else '-'} |")
    return "\n".join(lines)


def write_readme_table() -> None:
    """Rewrite the README's performance table between its markers (the scripts call this)."""
    begin, end = "<!-- bench:readme -->", "<!-- /bench:readme -->"
    old = README.read_text()
    if begin not in old:
        return
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    _write(README, pattern.sub(lambda _: f"{begin}\n{readme_table()}\n{end}", old))


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip()[1:-1].split("|")]


def _line(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def subtable(table: list[str], columns, rows: dict | None = None) -> list[str]:
    """The markdown table `table` (its header line, its alignment line, its rows) cut down to the
    columns named in `columns` (a header, which keeps every column of that header, or a column's
    index; in the table's order) and to the rows whose cell in each column named in `rows` is one
    of the values listed there (the first column of that header)."""
    header = _cells(table[0])
    keep = [i for i, h in enumerate(header) if h in columns or i in columns]
    out = []
    for k, line in enumerate(table):
        cells = _cells(line)
        if k >= 2 and rows and not all(cells[header.index(c)] in allowed for c, allowed in rows.items()):
            continue
        kept = [cells[i] for i in keep if i < len(cells)]
        out.append("|" + "|".join(kept) + "|" if k == 1 else _line(kept))     # k == 1: the alignment line
    return out


def pivot(table: list[str], row: str, column: str, value: str) -> list[str]:
    """The markdown table `table` turned into one of `value` with a row per value of its column
    `row` and a column per value of its column `column` (each in the order first met)."""
    header = _cells(table[0])
    r, c, v = header.index(row), header.index(column), header.index(value)
    grid: dict[str, dict[str, str]] = {}
    names: dict[str, None] = {}
    for line in table[2:]:
        cells = _cells(line)
        grid.setdefault(cells[r], {})[cells[c]] = cells[v]
        names[cells[c]] = None
    return ([_line([row] + list(names)), "|---|" + "---:|" * len(names)]
            + [_line([key] + [values.get(n, "") for n in names]) for key, values in grid.items()])


def tables(lines: list[str]) -> list[list[str]]:
    """The markdown tables among `lines` (runs of lines that start with `|`), in order."""
    found, run = [], []
    for line in lines + [""]:
        if line.startswith("|"):
            run.append(line)
        elif run:
            found.append(run)
            run = []
    return found


def spd_file(name: str, size: int, suffix: str) -> Path:
    """An SPD scene at `size` as a .nff, .obj or .pov file, written by raykernel's generators and
    converters into bench/.cache the first time it is asked for."""
    from raykernel.scene.convert import convert
    path = CACHE / f"{name}-sf{size}{suffix}"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        convert(f"spd:{name}:{size}", path)
    return path
