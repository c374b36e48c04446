"""bench/_report.py: how a benchmark section is split between BENCHMARKS.md and its page, and the
README's performance table read from the sections."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("bench_report", ROOT / "bench" / "_report.py")
report = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(report)

SECTION = """## Ray casting (raykernel vs peers)

Machine: Test CPU 9000, 2 cores, 2 threads; Python 3.11.

Command: `python bench/raycast.py` (2031-02-03)

| mesh | rays | raykernel Mrays/s | embreex Mrays/s | ratio | single Mrays/s | single ratio | mitsuba Mrays/s | ratio | single vs mitsuba | open3d Mrays/s | ratio | single vs open3d |
|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|
| a | coherent | 2 | 1 | 2.00 | 3 | 3.00 | 1 | 2.00 | 3.00 | 4 | 0.50 | 0.75 |
| a | incoherent | 1 | 2 | 0.50 | 1.5 | 0.75 | 4 | 0.25 | 0.38 | 1 | 1.00 | 1.50 |
| b | coherent | 3 | 2 | 1.50 | 2.5 | 1.25 | 3 | 1.00 | 0.83 | 3 | 1.00 | 0.83 |
<!-- details -->

### Every thread count

| mesh | threads |
|---|---:|
| a | 1 |
"""


def test_a_section_is_split_into_its_summary_and_its_page():
    summary, page = report.split_section("raycast", SECTION)
    assert "<!-- details -->" not in summary and "<!-- details -->" not in page
    assert "Every thread count" not in summary
    assert summary.rstrip().endswith("[docs/benchmarks/raycast.md](docs/benchmarks/raycast.md).")
    assert page.startswith("# Ray casting (raykernel vs peers)\n")
    assert "\n## Every thread count\n" in page          # one level up, as the page's own heading
    assert "| a | coherent | 2 | 1 | 2.00 | 3 |" in summary and "| a | coherent | 2 | 1 | 2.00 | 3 |" in page


def test_a_section_without_details_stays_whole():
    assert report.split_section("x", "## X\n\ntext\n") == ("## X\n\ntext", None)


def test_the_readme_table_reads_each_peer_s_ratios_their_date_and_machine():
    text = "<!-- bench:raycast -->\n" + report.split_section("raycast", SECTION)[0] + "\n<!-- /bench:raycast -->\n"
    table = report.readme_table(text).split("\n")
    assert table[0].startswith("| question |")
    coherent = next(line for line in table if "ray casting, coherent, double" in line)
    incoherent = next(line for line in table if "ray casting, incoherent, double" in line)
    # embreex 1.50-2.00, mitsuba 1.00-2.00, open3d 0.50-1.00 over the coherent rows; one row incoherent
    assert "| 1.50-2.00x, 1.00-2.00x, 0.50-1.00x |" in coherent
    assert "| 0.50x, 0.25x, 1.00x |" in incoherent
    assert "| 2031-02-03 | Test CPU 9000 |" in coherent
    # single precision against each peer: its own ratio columns
    assert "| 1.25-3.00x, 0.83-3.00x, 0.75-0.83x | embreex, Mitsuba 3, Open3D |" in next(
        line for line in table if "ray casting, coherent, single" in line)
    assert "| 0.75x, 0.38x, 1.50x | embreex, Mitsuba 3, Open3D |" in next(
        line for line in table if "ray casting, incoherent, single" in line)
    assert not any("renders" in line for line in table)     # no section, no row


def test_a_peer_that_did_not_run_leaves_its_cells_out_of_the_ratios():
    # a peer not installed on the bench's machine writes "-" in its columns
    rows = SECTION.split("\n")
    rows = [line.replace("| 4 | 0.50 | 0.75 |", "| - | - | - |") if line.startswith("| a | coherent") else line
            for line in rows]
    text = "<!-- bench:raycast -->\n" + report.split_section("raycast", "\n".join(rows))[0] + "\n<!-- /bench:raycast -->\n"
    coherent = next(line for line in report.readme_table(text).split("\n") if "ray casting, coherent, double" in line)
    assert "| 1.50-2.00x, 1.00-2.00x, 1.00x |" in coherent


def test_the_readme_s_table_is_the_one_the_sections_give():
    readme = (ROOT / "README.md").read_text()
    begin, end = "<!-- bench:readme -->\n", "\n<!-- /bench:readme -->"
    assert begin in readme and end in readme
    assert readme.split(begin, 1)[1].split(end, 1)[0] == report.readme_table(), \
        "README's performance table is stale: rerun any bench script, or bench/_report.py's write_readme_table()"


@pytest.mark.parametrize("name", ["renders", "raycast", "meshbuild", "proximity"])
def test_every_readme_row_has_its_section(name):
    assert report.section(name), f"BENCHMARKS.md has no {name} section for the README's table"
