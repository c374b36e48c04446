"""The package's layers, lowest first: a module imports only from its own layer or below, never
in a circle, and no private name crosses a module boundary (tests/test_layers.py holds the code to
it; docs/design.md's Layout section is describe()'s text).

    rank("raykernel.engine.traverse") > rank("raykernel.aggregates.bvh")
    edges = imports_of(package_folder)          # (module, imported module, imported name, line)
    upward(edges), private(edges), cycles(edges)   # what breaks the rules
"""

from __future__ import annotations

import ast
from pathlib import Path

# (layer, its modules and subpackages, what it holds), lowest first. The aggregates sit below the
# scene: a structure is built from item boxes and references, knowing nothing of scenes, while a
# scene names its structures by spec, which its readers check against the aggregates' registry.
LAYERS = (
    ("geometry", ("geometry", "errors", "options", "atomicfile", "layers"),
     "primitives and their tests, the hit rule, boxes, counters and work records, the kernel decorator and its "
     "cache, kernels on threads; errors, option checks"),
    ("aggregates", ("aggregates",), "one module per kind of structure: its builder, layout and walk (the BVH's walk of a whole scene "
     "too); the registry"),
    ("scene", ("scene",), "the scene model, NFF and JSON readers and writers, SPD and pathological generators"),
    ("engine", ("engine",), "flat arrays from a scene, the intersection driver, instances"),
    ("rendering, casting", ("rendering", "casting", "trimesh"),
     "shading, sampling, statistics, images; RayScene's ray casting and point queries"),
    ("analysis, cluster", ("analysis", "cluster"), "comparisons, the cost model, annealing, auto; Dask"),
    ("explorer", ("explorer",), "the work explorer: a local web app (Dash) linking every view of the work"),
    ("cli", ("cli", "__main__"), "the command line (and python -m raykernel)"),
    ("package", ("",), "raykernel's public names (raykernel/__init__.py)"),
)


def layer_of(module: str) -> str | None:
    """The layer of a dotted module name of the package (raykernel.x.y), None if none names it."""
    parts = module.split(".")
    if parts[0] != "raykernel":
        return None
    first = parts[1] if len(parts) > 1 else ""
    for name, places, _ in LAYERS:
        if first in places:
            return name
    return None


def rank(module: str) -> int:
    """The layer's position, lowest 0 (-1 for a module of no layer)."""
    name = layer_of(module)
    return next((i for i, (n, _, _) in enumerate(LAYERS) if n == name), -1)


def describe() -> str:
    """The layers as docs/design.md lists them."""
    return "\n".join(f"{i + 1}. **{name}** (`{'`, `'.join(p or 'raykernel' for p in places)}`): {what}"
                     for i, (name, places, what) in enumerate(LAYERS))


def imports_of(folder) -> list[tuple[str, str, str | None, int]]:
    """Every import of the package's own code in the package at `folder` (named as the folder):
    (importing module, imported module, imported name or None for a module, line), module-level
    and in-function imports alike."""
    folder = Path(folder)
    root = folder.name
    modules = {}
    for path in folder.rglob("*.py"):
        parts = [root, *path.relative_to(folder).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    edges = []
    for name, path in modules.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = package[:len(package) - (node.level - 1)] if node.level else []
                target = ".".join(base + ([node.module] if node.module else []))
                if target.split(".")[0] != root:
                    continue
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    edges.append((name, sub, None, node.lineno) if sub in modules
                                 else (name, target, alias.name, node.lineno))
            elif isinstance(node, ast.Import):
                edges += [(name, a.name, None, node.lineno) for a in node.names if a.name.split(".")[0] == root]
    return edges


def upward(edges) -> list[str]:
    """The imports that go up a layer."""
    return [f"{a}:{line} imports {b} ({layer_of(a)} below {layer_of(b)})" for a, b, _, line in edges
            if rank(b) > rank(a)]


def private(edges) -> list[str]:
    """The imports of a private name (_name) from another module."""
    return [f"{a}:{line} imports {b}.{n}" for a, b, n, line in edges if n and n.startswith("_") and b != a]


def cycles(edges) -> list[list[str]]:
    """The sets of modules that import each other round in a circle (strongly connected components)."""
    graph: dict[str, set] = {}
    for a, b, _, _ in edges:
        graph.setdefault(a, set())
        graph.setdefault(b, set())
        if a != b:
            graph[a].add(b)
    index, low, on, stack, found = {}, {}, set(), [], []
    for root in sorted(graph):
        if root in index:
            continue
        index[root] = low[root] = len(index)
        stack.append(root)
        on.add(root)
        work = [(root, iter(sorted(graph[root])))]
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        x = stack.pop()
                        on.discard(x)
                        comp.append(x)
                        if x == v:
                            break
                    if len(comp) > 1:
                        found.append(sorted(comp))
            elif w not in index:
                index[w] = low[w] = len(index)
                stack.append(w)
                on.add(w)
                work.append((w, iter(sorted(graph[w]))))
            elif w in on:
                low[v] = min(low[v], index[w])
    return found
