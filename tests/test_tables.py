"""The command line's tables at 80 columns, and piped: split or wrapped, never a number cut short."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest
from rich.console import Console

from raykernel.analysis import compare as cm
from raykernel.rendering.stats import Stats


def _printed(renderables, width):
    console = Console(width=width, file=io.StringIO(), color_system=None)
    for r in renderables:
        console.print(r)
    return console.file.getvalue()


def _comparison():
    stats = {"tests.per_ray": 123456.789, "cells.visited_per_ray": 98765.4321, "cells.leaves_per_ray": 4321.5,
             "cells.empty_per_ray": 0.25, "bounds.per_ray": 77777.77, "mailbox.saved": 123_456_789,
             "build.nodes": 9_876_543, "build.bytes": 1_234_567_890_123, "build.seconds": 12.3456,
             "time.trace": 345.678, "time.rays_per_second": 1.5e6}
    runs = [cm.Run(scene=f"scene:stadium:ratio={r}", accel=a, stats=dict(stats), image=np.zeros((1, 1, 3)),
                   primitives=1, predicted=1.25)
            for r in (10, 100000) for a in ("auto(evaluations=400, seconds=600)", "octree(walk=parametric)")]
    return cm.Comparison(runs=runs, options={}, machine={}, command="x")


@pytest.mark.parametrize("width", [60, 80, 100, 200])
def test_compare_tables_fit_and_keep_every_cell(width):
    cmp = _comparison()
    text = _printed(cm.tables(cmp, title="raykernel compare", width=width), width)
    assert "…" not in text
    assert max(len(line) for line in text.splitlines()) <= width
    for _, _, cells in cm.table_rows(cmp):
        for cell in cells:
            assert re.search(rf"(?<![\d,.]){re.escape(cell)}(?![\d,.])", text), (width, cell)
    for header, _, _ in cm.COLUMNS:
        assert header in text
    assert "scene:stadium:ratio=10" in text.replace(" │ ", "")     # names as written (no ":stadium:" emoji)
    squeezed = _printed([cm.table(cmp)], width)      # one table squeezed into the width: what it replaces
    assert width >= 200 or "…" in squeezed


def test_statistics_table_keeps_every_value_at_80_columns():
    import raykernel
    stats = raykernel.render(raykernel.load("spd:balls:1"), resolution=8, threads=1).stats
    assert isinstance(stats, Stats)
    text = _printed([stats.table(title="spd:balls:1: 11 primitives, 8x8, accel bvh -> balls.png")], 80)
    assert "…" not in text
    for _, _, value, _ in stats.rows():
        assert value.replace(" ", "") in text.replace(" ", "").replace("\n", ""), value


def test_scene_names_print_as_written(tmp_path, capsys):
    from raykernel.cli import main
    assert main(["render", "scene:stadium:ratio=50", "--resolution", "4", "--accel", "grid", "-o",
                 str(tmp_path / "s.png")]) == 0
    assert main(["compare", "scene:stadium:ratio=50", "--accel", "grid", "--resolution", "4", "--threads", "1"]) == 0
    out = capsys.readouterr().out
    assert out.replace("\n", "").count("scene:stadium:ratio=50") >= 2 and "\N{STADIUM}" not in out
