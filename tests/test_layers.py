"""The package's layers hold (raykernel/layers.py): no import goes up a layer, none goes round in a
circle, no private name crosses a module boundary (every import statement, module-level or inside a
function), and docs/design.md's Layout section lists the layers as the code has them."""

from __future__ import annotations

import re
from pathlib import Path

import raykernel
from raykernel import layers

PACKAGE = Path(raykernel.__file__).parent
DESIGN = PACKAGE.parents[1] / "docs" / "design.md"
EDGES = layers.imports_of(PACKAGE)


def test_every_module_has_a_layer():
    modules = {a for a, _, _, _ in EDGES}
    assert len(modules) > 80
    assert not [m for m in modules if layers.layer_of(m) is None]


def test_no_import_goes_up_a_layer():
    assert not layers.upward(EDGES), "\n".join(layers.upward(EDGES))


def test_no_private_name_crosses_a_module_boundary():
    assert not layers.private(EDGES), "\n".join(layers.private(EDGES))


def test_no_import_cycle():
    assert not layers.cycles(EDGES)


def test_each_rule_finds_what_breaks_it(tmp_path):
    pkg = tmp_path / "raykernel"
    for folder in ("geometry", "engine", "aggregates"):
        (pkg / folder).mkdir(parents=True)
        (pkg / folder / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "geometry" / "low.py").write_text("def later():\n    from ..engine.high import run\n")
    (pkg / "engine" / "high.py").write_text("from ..geometry.low import later\nfrom ..aggregates.a import _hidden\n")
    (pkg / "aggregates" / "a.py").write_text("from .b import x\n_hidden = 1\n")
    (pkg / "aggregates" / "b.py").write_text("from . import a\nx = 2\n")
    edges = layers.imports_of(pkg)
    assert layers.upward(edges) == ["raykernel.geometry.low:2 imports raykernel.engine.high (geometry below engine)"]
    assert layers.private(edges) == ["raykernel.engine.high:2 imports raykernel.aggregates.a._hidden"]
    assert sorted(map(tuple, layers.cycles(edges))) == [
        ("raykernel.aggregates.a", "raykernel.aggregates.b"),
        ("raykernel.engine.high", "raykernel.geometry.low")]


def test_the_design_page_lists_the_layers_of_the_code():
    section = re.search(r"^## Layout\n(.*?)(?=^## |\Z)", DESIGN.read_text(), re.S | re.M)
    assert section, "docs/design.md has no Layout section"
    assert layers.describe() in section.group(1), "docs/design.md's Layout is not layers.describe()'s text"


def test_no_function_is_over_150_lines():
    import ast
    long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 150:
                long.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name}: "
                            f"{node.end_lineno - node.lineno + 1} lines")
    assert not long, "\n".join(long)


def test_the_engine_names_no_kind():
    # the engine reaches the aggregates through the registry and the modules every kind shares (the
    # walk contract, operators' crossings, lazy sets, memory, specs), never through a kind's own
    shared = {"registry", "walk", "collect", "lazyset", "memory", "spec"}
    engine = {(a, b.split(".")[2], line) for a, b, _, line in EDGES
              if a.startswith("raykernel.engine.") and b.startswith("raykernel.aggregates.")}
    assert "registry" in {b for _, b, _ in engine}
    assert not [f"{a}:{line} imports aggregates.{b}" for a, b, line in engine if b not in shared]
