"""Arvo's question answered: the hierarchy of subspaces found by simulated annealing.

    found = anneal(scene, seconds=30, seed=0)       # an Annealed
    found.scene                                     # the scene regrouped, each group with its spec
    print(found.before, found.after)                # the hierarchies as trees
    render(scene, accel="auto(seconds=30)")         # the same, inside any render (and --accel auto)

A state is a tree of groups, each with an accelerator spec (a kind and its parameters).
Its leaves hold atoms: clusters of a few primitives (or whole instances and boolean
operators, which are never split), made once by median splits of the primitives' centres
so that an atom is a compact piece of space. Atoms never cross the scene's own groups, so
the scene's hand-made hierarchy is a state too.

Moves (MOVES): change a group's spec (kind or parameters, from CANDIDATES); split a
group's own atoms in two along its longest axis; merge a group with its nearest sibling;
move an atom to the group nearest it; wrap an atom and its nearest neighbours in a new
group; dissolve a group into its parent. After each move a group left with nothing is
removed and one that only holds a single group is replaced by it (Glassner's single-child
replacement).

Energy: the predicted trace time of the render the caller will make, plus `memory` seconds
per MiB the structures take. A candidate is built and traced with the render's own options
at `sample` pixels along the image's longer side, its aspect kept (eye rays, their
reflections, refractions and shadow rays: the same distribution of rays at lower density), and its exact counts, scaled to the full
render, priced by the cost model (costmodel.current(): this machine's calibration, else
the reference costs). Counts are exact, so energies, and the whole run, are deterministic
for a seed, except where the time budget (`seconds`) cuts it short.

Schedule: the start is the best of the scene's own hierarchy and every structure of
START_SPECS and START_VARIANTS over the whole scene. The starting temperature T0 makes a
typical uphill move of a few sampled ones accepted with probability `accept0` (0.8):
T0 = -median(dE+) / ln 0.8.
Each temperature tries `moves` moves (default 4 per atom, 16 to 48), accepting an uphill
dE with probability exp(-dE / T) (Metropolis); then T *= `cooling` (0.8). It stops when frozen
(`patience` temperatures in a row, 3, accepting changes in under 2 % of their moves), at T
below T0 / 1000, after `evaluations` candidates, or at the time budget (compiling, on a
first run, is not counted). The best state seen is the result, unless its energy is less
than `margin` (5%) below the best kind of START_SPECS over the whole target: that kind is
kept then, over the scene's own groups and sets (_under_one), since smaller gains are within
the cost model's error.

Between frames: `state, atoms = rebind(previous.state, previous.atoms, next_frame)` moves
the atoms with their primitives, and anneal(next_frame, start=state, atoms=atoms,
short=True) re-anneals from there with T0 a tenth.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..aggregates.registry import CANDIDATES, DEFAULT, SMALL_ONLY, START_SPECS, START_VARIANTS, parse_spec
from ..aggregates.spec import is_auto
from ..errors import OptionError, RayKernelError
from ..options import number
from ..scene.model import Cones, Group, Instance, Polygons, Scene, Spheres, TriangleMesh
from ..scene.specs import is_operator, without_specs  # noqa: F401  (without_specs: for the searches' callers)

# What the search starts from and offers comes from the kinds' own declarations (spec.Search):
# START_SPECS, the kinds started from at their defaults over the whole target (lazy structures
# refine as rays arrive, so a sample of rays would price them as the coarse trees it leaves: the
# search offers only eager ones); START_VARIANTS, other specs started from but not a kind at its
# defaults (best_single leaves them out); CANDIDATES, every spec a group may be given; and
# SMALL_ONLY, kinds offered only to groups of at most so many primitives.


def _offered(spec: str, prims: int) -> bool:
    """Whether a group of `prims` primitives may be given `spec`."""
    limit = SMALL_ONLY.get(spec.split("(", 1)[0])
    return limit is None or prims <= limit


MOVES = ("spec", "split", "merge", "move", "wrap", "dissolve")
MAX_ATOMS = 192
MIN_ATOM = 8
MAX_LEVELS = 6           # groups on a path from the annealed group down (MAX_NESTING allows 16)


# ---- atoms ------------------------------------------------------------------------------------

@dataclass
class _Region:
    """A part of the scene that atoms may not cross: one of its groups with a spec."""
    spec: str | None
    elements: list = field(default_factory=list)     # (source, index or None) pairs
    children: list = field(default_factory=list)     # _Region


def _regions(group: Group) -> _Region:
    """The target group's primitives and opaque children, by the groups with specs below it."""
    region = _Region(None)

    def collect(g: Group, into: _Region):
        for s in g.primitive_sets():
            into.elements += [(s, i) for i in range(len(s))]
        for child in g.children:
            if isinstance(child, Instance) or is_operator(child):
                into.elements.append((child, None))
            elif child.accel is None or is_auto(child.accel):
                collect(child, into)
            else:
                sub = _Region(child.accel)
                into.children.append(sub)
                collect(child, sub)

    collect(group, region)
    return region


def _set_boxes(s) -> np.ndarray:
    """(n, 6) boxes of a primitive set's members."""
    if isinstance(s, Spheres):
        r = np.abs(s.radius)[:, None]
        return np.hstack([s.center - r, s.center + r])
    if isinstance(s, Cones):
        r = np.maximum(np.abs(s.base_radius), np.abs(s.apex_radius))[:, None]
        return np.hstack([np.minimum(s.base, s.apex) - r, np.maximum(s.base, s.apex) + r])
    if isinstance(s, Polygons):
        lo = np.minimum.reduceat(s.vertices, s.start, axis=0)
        hi = np.maximum.reduceat(s.vertices, s.start, axis=0)
        return np.hstack([lo, hi])
    tri = s.vertices[s.faces]
    return np.hstack([tri.min(axis=1), tri.max(axis=1)])


def _box(src) -> np.ndarray:
    """Box of everything in a group or an instance (in the space it is placed in)."""
    from ..engine.flatten import transform_box
    if isinstance(src, Instance):
        return transform_box(_box(src.group), src.matrix)
    boxes = [_set_boxes(s) for s in src.primitive_sets()] + [_box(c)[None] for c in src.children]
    b = np.vstack(boxes) if boxes else np.zeros((0, 6))
    b = b[np.all(b[:, :3] <= b[:, 3:], axis=1)]         # empty children add nothing
    if not len(b):
        return np.array([np.inf] * 3 + [-np.inf] * 3)
    return np.concatenate([b[:, :3].min(axis=0), b[:, 3:].max(axis=0)])


def _subset(s, idx: np.ndarray):
    """The members idx of primitive set s, as a new set of the same kind."""
    if isinstance(s, Spheres):
        return Spheres(s.center[idx], s.radius[idx], s.material[idx])
    if isinstance(s, Cones):
        return Cones(s.base[idx], s.base_radius[idx], s.apex[idx], s.apex_radius[idx], s.material[idx])
    if isinstance(s, Polygons):
        p = Polygons(patches=s.patches)
        counts = s.count[idx]
        take = np.concatenate([np.arange(a, a + c) for a, c in zip(s.start[idx], counts)])
        p.vertices = s.vertices[take]
        if s.patches:
            p.normals = s.normals[take]
        p.start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        p.count = counts.astype(np.int64)
        p.material = s.material[idx]
        return p
    faces = s.faces[idx]
    used, local = np.unique(faces, return_inverse=True)
    return TriangleMesh(s.vertices[used], local.reshape(-1, 3), s.material[idx],
                        None if s.normals is None else s.normals[used])


@dataclass
class Atoms:
    """The annealer's units: groups of elements, each with its box and primitive count."""
    groups: list            # Group (accel None) per atom
    boxes: np.ndarray       # (n, 6)
    counts: np.ndarray      # primitives per atom
    members: list           # per atom: [(source ordinal, indices)] as they were cut, to rebind
    shape: tuple = ()       # (kind, size) of each source: what another frame must match
    sources: list = field(default_factory=list)     # the primitive sets and opaque children, by ordinal

    @property
    def centres(self) -> np.ndarray:
        return 0.5 * (self.boxes[:, :3] + self.boxes[:, 3:])


def _cut(elements, boxes, leaf: int):
    """Median splits of the element centres along their longest extent, down to `leaf` or fewer."""
    out = []
    stack = [np.arange(len(elements))]
    centres = 0.5 * (boxes[:, :3] + boxes[:, 3:])
    while stack:
        part = stack.pop()
        if len(part) <= leaf:
            out.append(part)
            continue
        c = centres[part]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        order = part[np.argsort(c[:, axis], kind="stable")]
        half = len(order) // 2
        stack += [order[half:], order[:half]]
    return out


def _sources(region: _Region, out=None) -> list:
    """The distinct primitive sets and opaque children of a region tree, in the order met."""
    out = [] if out is None else out
    seen = {id(x) for x in out}
    for src, _ in region.elements:
        if id(src) not in seen:
            seen.add(id(src))
            out.append(src)
    for sub in region.children:
        _sources(sub, out)
    return out


def _make_atoms(region: _Region, sources: dict, atoms: list, leaf: int):
    """Cut every region's elements into atoms; returns the region's tree as (atom ids, children)."""
    ids = []
    if region.elements:
        # each element's box, one set's members at a time
        by_set: dict[int, list] = {}
        for k, (src, _) in enumerate(region.elements):
            by_set.setdefault(id(src), []).append(k)
        boxes = np.zeros((len(region.elements), 6))
        for members in by_set.values():
            src, index = region.elements[members[0]]
            boxes[members] = _box(src) if index is None else _set_boxes(src)[[region.elements[k][1] for k in members]]
        boxes = np.where(np.all(np.isfinite(boxes), axis=1)[:, None], boxes, 0.0)    # empty ones at the origin
        for part in _cut(region.elements, boxes, leaf):
            sets, opaque = [], []
            members = []
            by: dict[int, list] = {}
            for k in part:
                by.setdefault(id(region.elements[k][0]), []).append(k)
            count = 0
            for ks in by.values():
                src = region.elements[ks[0]][0]
                ordinal = sources[id(src)]
                if region.elements[ks[0]][1] is None:
                    opaque += [region.elements[k][0] for k in ks]
                    members.append((ordinal, None))
                    count += src.count_primitives()
                    continue
                idx = np.array(sorted(region.elements[k][1] for k in ks), np.int64)
                members.append((ordinal, idx))
                sets.append(_subset(src, idx))
                count += len(idx)
            b = boxes[part]
            atoms.append((_group_of("", None, sets, opaque), np.concatenate([b[:, :3].min(axis=0), b[:, 3:].max(axis=0)]),
                          count, members))
            ids.append(len(atoms) - 1)
    return ids, [(_make_atoms(sub, sources, atoms, leaf), sub.spec) for sub in region.children]


def _group_of(name: str, spec, sets, children) -> Group:
    """A group holding `sets` (primitive sets, merged into one per kind) and `children`."""
    g = Group(name=name, accel=spec)
    kinds = {"sphere": [], "cone": [], "polygon": [], "patch": [], "triangle": []}
    for x in sets:
        kinds[x.kind].append(x)
    if kinds["sphere"]:
        g.spheres = Spheres(np.vstack([x.center for x in kinds["sphere"]]),
                            np.concatenate([x.radius for x in kinds["sphere"]]),
                            np.concatenate([x.material for x in kinds["sphere"]]))
    if kinds["cone"]:
        c = kinds["cone"]
        g.cones = Cones(np.vstack([x.base for x in c]), np.concatenate([x.base_radius for x in c]),
                        np.vstack([x.apex for x in c]), np.concatenate([x.apex_radius for x in c]),
                        np.concatenate([x.material for x in c]))
    g.polygons = _merge_polygons(kinds["polygon"], False)
    g.patches = _merge_polygons(kinds["patch"], True)
    for smooth in (True, False):     # meshes with and without vertex normals stay apart
        meshes = [m for m in kinds["triangle"] if (m.normals is not None) == smooth and len(m.faces)]
        if meshes:
            offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
            g.meshes.append(TriangleMesh(np.vstack([m.vertices for m in meshes]),
                                         np.vstack([m.faces + o for m, o in zip(meshes, offsets)]),
                                         np.concatenate([m.material for m in meshes]),
                                         np.vstack([m.normals for m in meshes]) if smooth else None))
    g.children = list(children)
    return g


# ---- states ------------------------------------------------------------------------------------

@dataclass
class Node:
    """A group of the hierarchy: its spec, its own atoms and its child groups."""
    spec: str
    atoms: list = field(default_factory=list)
    children: list = field(default_factory=list)

    def copy(self) -> Node:
        return Node(self.spec, list(self.atoms), [c.copy() for c in self.children])

    def key(self):
        return (self.spec, tuple(sorted(self.atoms)), tuple(sorted(c.key() for c in self.children)))

    def nodes(self, depth: int = 1, parent=None):
        """(node, parent, depth) for every node, this one first."""
        yield self, parent, depth
        for c in self.children:
            yield from c.nodes(depth + 1, self)

    def all_atoms(self) -> list:
        return self.atoms + [a for c in self.children for a in c.all_atoms()]

    def levels(self) -> int:
        return 1 + max((c.levels() for c in self.children), default=0)

    def to_dict(self) -> dict:
        return {"spec": self.spec, "atoms": list(self.atoms), "children": [c.to_dict() for c in self.children]}

    @classmethod
    def from_dict(cls, d) -> Node:
        return cls(d["spec"], list(d["atoms"]), [cls.from_dict(c) for c in d["children"]])


def tree_text(node: Node, atoms: Atoms, indent: str = "") -> str:
    """The hierarchy as an indented tree: spec, primitives and atoms of each group."""
    prims = int(sum(atoms.counts[a] for a in node.all_atoms()))
    own = f", {len(node.atoms)} atoms here" if node.children and node.atoms else ""
    lines = [f"{indent}{node.spec}  [{prims:,} primitives{own}]"]
    for c in sorted(node.children, key=lambda c: -sum(atoms.counts[a] for a in c.all_atoms())):
        lines.append(tree_text(c, atoms, indent + "  "))
    return "\n".join(lines)


def _normalise(node: Node) -> Node:
    """Drop empty groups; a group holding only one group becomes that group."""
    node.children = [_normalise(c) for c in node.children]
    node.children = [c for c in node.children if c.atoms or c.children]
    if not node.atoms and len(node.children) == 1:
        return node.children[0]
    return node


def _box_of(node: Node, atoms: Atoms) -> np.ndarray:
    ids = node.all_atoms()
    b = atoms.boxes[ids]
    return np.concatenate([b[:, :3].min(axis=0), b[:, 3:].max(axis=0)])


def _centre(node: Node, atoms: Atoms) -> np.ndarray:
    b = _box_of(node, atoms)
    return 0.5 * (b[:3] + b[3:])


def propose(state: Node, atoms: Atoms, rng, max_levels: int = MAX_LEVELS):
    """One random move: (move name, new state), or (name, None) where it does not apply."""
    new = state.copy()
    nodes = list(new.nodes())
    move = MOVES[int(rng.integers(len(MOVES)))]
    node, parent, depth = nodes[int(rng.integers(len(nodes)))]
    centres = atoms.centres
    if move == "spec":
        prims = int(atoms.counts[node.all_atoms()].sum())
        choices = [c for c in CANDIDATES if c != node.spec and _offered(c, prims)]
        node.spec = choices[int(rng.integers(len(choices)))]
    elif move == "split":
        if len(node.atoms) < 2 or depth >= max_levels:
            return move, None
        own = np.array(node.atoms)
        c = centres[own]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        order = own[np.argsort(c[:, axis], kind="stable")]
        half = len(order) // 2
        node.atoms = []
        node.children += [Node(node.spec, order[:half].tolist()), Node(node.spec, order[half:].tolist())]
    elif move == "merge":
        if len(node.children) < 2:
            return move, None
        a = node.children[int(rng.integers(len(node.children)))]
        ca = _centre(a, atoms)
        others = [c for c in node.children if c is not a]
        b = min(others, key=lambda c: float(np.sum((_centre(c, atoms) - ca) ** 2)))
        node.children = [c for c in node.children if c is not a and c is not b]
        node.children.append(Node(a.spec, a.atoms + b.atoms, a.children + b.children))
    elif move == "move":
        if not node.atoms or len(nodes) < 2:
            return move, None
        atom = node.atoms[int(rng.integers(len(node.atoms)))]
        targets = [n for n, _, _ in nodes if n is not node]
        dist = [float(np.sum((_centre(n, atoms) - centres[atom]) ** 2)) for n in targets]
        near = np.argsort(dist, kind="stable")[:3]
        target = targets[int(near[int(rng.integers(len(near)))])]
        node.atoms.remove(atom)
        target.atoms.append(atom)
    elif move == "wrap":
        if len(node.atoms) < 2 or depth >= max_levels:
            return move, None
        own = np.array(node.atoms)
        seed = own[int(rng.integers(len(own)))]
        k = int(rng.integers(1, len(own)))
        near = own[np.argsort(np.sum((centres[own] - centres[seed]) ** 2, axis=1), kind="stable")[:k]]
        spec = CANDIDATES[int(rng.integers(len(CANDIDATES)))]
        if not _offered(spec, int(atoms.counts[near].sum())):
            spec = DEFAULT
        node.atoms = [a for a in node.atoms if a not in set(near.tolist())]
        node.children.append(Node(spec, near.tolist()))
    else:   # dissolve
        if parent is None:
            return move, None
        parent.children = [c for c in parent.children if c is not node]
        parent.atoms += node.atoms
        parent.children += node.children
    new = _normalise(new)
    if new.levels() > max_levels:
        return move, None
    return move, new


# ---- energy ------------------------------------------------------------------------------------

def _node_group(node: Node, atoms: Atoms, name: str) -> Group:
    """The group of a state's node, its atoms as spec-less children (merged by the build)."""
    g = Group(name=name, accel=node.spec)
    g.children = [atoms.groups[a] for a in node.atoms]
    g.children += [_node_group(c, atoms, f"{name}.{k}") for k, c in enumerate(node.children)]
    return g


def _merged_group(node: Node, atoms: Atoms, name: str) -> Group:
    """The same group with its atoms' primitives merged into one set per source, in the
    source's own order (a group holding all of a source holds that set itself): what is
    written out and rendered, laid out as the scene was as far as the grouping allows."""
    taken: dict[int, list] = {}
    for a in node.atoms:
        for ordinal, idx in atoms.members[a]:
            taken.setdefault(ordinal, []).append(idx)
    sets, children = [], []
    for ordinal in sorted(taken):
        src, parts = atoms.sources[ordinal], taken[ordinal]
        if parts[0] is None:
            children.append(src)
            continue
        idx = np.sort(np.concatenate(parts))
        sets.append(src if len(idx) == len(src) else _subset(src, idx))
    g = _group_of(name, node.spec, sets, children)
    g.children += [_merged_group(c, atoms, f"{name}.{k}") for k, c in enumerate(node.children)]
    return g


def _merge_polygons(sets, patches: bool) -> Polygons:
    p = Polygons(patches=patches)
    sets = [s for s in sets if len(s)]
    if sets:
        offsets = np.cumsum([0] + [len(s.vertices) for s in sets[:-1]])
        p.vertices = np.vstack([s.vertices for s in sets])
        if patches:
            p.normals = np.vstack([s.normals for s in sets])
        p.start = np.concatenate([s.start + o for s, o in zip(sets, offsets)]).astype(np.int64)
        p.count = np.concatenate([s.count for s in sets]).astype(np.int64)
        p.material = np.concatenate([s.material for s in sets])
    return p


def _replace(root: Group, target: Group, new: Group) -> Group:
    """root with `target` replaced by `new` (the groups on the way copied, nothing else)."""
    memo: dict[int, Group] = {}

    def visit(g: Group) -> Group:
        if g is target:
            return new
        if id(g) in memo:
            return memo[id(g)]
        kids, changed = [], False
        for c in g.children:
            inner = c.group if isinstance(c, Instance) else c
            got = visit(inner)
            changed |= got is not inner
            kids.append(c if got is inner else (Instance(got, c.matrix) if isinstance(c, Instance) else got))
        out = dataclasses.replace(g, children=kids) if changed else g
        memo[id(g)] = out
        return out

    return visit(root)


def _under_one(group: Group, spec: str) -> Group:
    """`group` under one structure: `spec` on it and no spec on the groups it merges (instances
    and operators kept whole, as atoms keep them). The scene's own groups and sets are kept, so
    a single kind found over everything renders exactly as that kind does (the same layout: a
    regrouped copy of the park, as fast by its counters, traced measurably slower)."""
    def visit(g: Group) -> Group:
        kids = [c if isinstance(c, Instance) or is_operator(c) else visit(c) for c in g.children]
        return dataclasses.replace(g, children=kids, accel=None)

    return dataclasses.replace(visit(group), accel=spec)


def _with_group(scene: Scene, target: Group, new: Group) -> Scene:
    return dataclasses.replace(scene, root=_replace(scene.root, target, new))


@dataclass
class Energy:
    """Prices candidate hierarchies of one group of one scene for one render's options."""
    scene: Scene
    target: Group
    atoms: Atoms
    options: dict           # the render's options (resolution, spd, max_depth, shading, ...)
    default: str            # the spec of groups outside the annealed tree that name none
    model: object
    sample: int = 24
    memory: float = 0.0     # seconds per MiB
    cache: dict = field(default_factory=dict)
    evaluations: int = 0

    def __post_init__(self):
        from ..rendering.render import render_options
        checked = inspect.signature(render_options).parameters         # not progress, builder: render's own
        o = render_options(self.scene, **{k: v for k, v in self.options.items() if k in checked and k != "accel"})
        w = o["resolution"] or self.scene.camera.width
        h = o["resolution"] or self.scene.camera.height
        # the sample keeps the render's aspect (and so its view), its longer side `sample` pixels
        sw = max(1, min(w, round(self.sample * w / max(w, h))))
        sh = max(1, min(h, round(self.sample * h / max(w, h))))
        self.camera = dataclasses.replace(self.scene.camera, width=sw, height=sh)
        extra = 1 if o["spd"] else 0         # SPD mode traces the pixels' corners
        self.scale = (w + extra) * (h + extra) / float((sw + extra) * (sh + extra))

    def candidate(self, state: Node) -> Scene:
        """The scene with the state's hierarchy, seen by the sample's camera."""
        scene = _with_group(self.scene, self.target, _node_group(state, self.atoms, self.target.name or "auto"))
        scene.camera = self.camera
        return scene

    def __call__(self, state: Node) -> float:
        """The state's energy; infinite where it cannot be built (a grid of too many cells, a
        structure past the memory budget), so that it is never accepted."""
        key = state.key()
        if key not in self.cache:
            try:
                self.cache[key] = self.measure(state)[0]
            except RayKernelError:
                self.cache[key] = math.inf
        return self.cache[key]

    def measure(self, state: Node):
        """(energy, predicted trace seconds, bytes, stats) of a state."""
        from ..rendering.render import render
        self.evaluations += 1
        options = {k: v for k, v in self.options.items() if k not in ("accel", "resolution", "progress", "builder")}
        stats = render(self.candidate(state), accel=self.default, **options).stats
        predicted = self.model.predict(stats, scale=self.scale, partial=True)
        memory = stats.get("build.bytes", 0)
        return predicted + self.memory * memory / 2 ** 20, predicted, memory, stats


# ---- the annealer --------------------------------------------------------------------------------

@dataclass
class Annealed:
    """What anneal() found."""
    scene: Scene                  # the scene with the annealed group rebuilt (specs on its groups)
    state: Node                   # the hierarchy found
    start: Node                   # the hierarchy it started from
    atoms: Atoms
    energy: float                 # predicted seconds (+ memory term) of the result
    start_energy: float
    starts: dict                  # energy of every starting candidate, by name
    history: list                 # (evaluation, temperature, current energy, best energy) per temperature
    seconds: float                # time spent annealing
    evaluations: int
    seed: int
    stopped: str                  # why it stopped
    searched: float = math.inf    # energy of the best state the search found
    kept: str | None = None       # the kind kept instead, where that state was under `margin` better

    @property
    def before(self) -> str:
        return tree_text(self.start, self.atoms)

    @property
    def after(self) -> str:
        return tree_text(self.state, self.atoms)

    @property
    def best_single(self) -> tuple[str, float]:
        """The best single kind among the starts (the start itself where none was tried)."""
        singles = {k: v for k, v in self.starts.items() if k in START_SPECS} or self.starts
        name = min(singles, key=singles.get)
        return name, singles[name]

    def summary(self) -> dict:
        name, e = self.best_single
        return {"energy": self.energy, "start_energy": self.start_energy, "best_single": name,
                "best_single_energy": e, "starts": dict(self.starts), "seconds": self.seconds,
                "evaluations": self.evaluations, "seed": self.seed, "stopped": self.stopped,
                "searched_energy": self.searched, "kept": self.kept,
                "groups": sum(1 for _ in self.state.nodes()), "levels": self.state.levels(),
                "state": self.state.to_dict()}


def _check(name, value, lo, hi, integer=False):
    return number(value, f"anneal {name}", lo, hi, integer)


def atoms_of(scene: Scene, target: Group | None = None, max_atoms: int = MAX_ATOMS):
    """The atoms of `target` (default: the root) and the scene's own hierarchy over them."""
    target = scene.root if target is None else target
    region = _regions(target)
    total = target.count_primitives()
    leaf = max(MIN_ATOM, -(-total // max_atoms))
    raw = []
    listed = _sources(region)
    tree = _make_atoms(region, {id(src): k for k, src in enumerate(listed)}, raw, leaf)
    atoms = Atoms([r[0] for r in raw], np.array([r[1] for r in raw]).reshape(-1, 6),
                  np.array([r[2] for r in raw], np.int64), [r[3] for r in raw], _shape(listed), listed)
    return atoms, tree


def _own_state(tree, spec, default: str) -> Node:
    (ids, children) = tree
    return _normalise(Node(spec or default, list(ids), [_own_state(t, s, default) for t, s in children]))


def anneal(scene: Scene, target: Group | None = None, seconds: float = 30.0, seed: int = 0, memory: float = 0.0,
           evaluations: int = 0, moves: int = 0, cooling: float = 0.8, accept0: float = 0.8, patience: int = 3,
           sample: int = 24, margin: float = 0.05, start: Node | None = None, short: bool = False, model=None,
           default: str = "bvh", log=None, options: dict | None = None, atoms: Atoms | None = None) -> Annealed:
    """Find a hierarchy for `target` by simulated annealing, for a render with `options`.

    The energy of a candidate hierarchy is the predicted trace time of the render, from the
    exact counts of a small render of it, plus `memory` seconds per MiB its structures take
    (see the module docstring for the moves and the schedule). Counts are exact, so a run is
    deterministic for a seed, except where the time budget cuts it short.

    Parameters
    ----------
    scene : Scene
        The scene.
    target : Group, optional
        The group of `scene` whose hierarchy is annealed (default: its root).
    seconds : float, default 30
        The time budget (compiling, on a first run, is not counted).
    seed : int, default 0
        The random numbers of the search.
    memory : float, default 0
        Seconds of energy per MiB the structures take.
    evaluations : int, default 0
        The most candidates priced (0: no limit).
    moves : int, default 0
        Moves tried per temperature (0: 4 per atom, 16 to 48).
    cooling : float, default 0.8
        The temperature's factor from one temperature to the next.
    accept0 : float, default 0.8
        The probability with which a typical uphill move is accepted at the start.
    patience : int, default 3
        Temperatures in a row accepting changes in under 2% of their moves, after which the
        search stops (frozen).
    sample : int, default 24
        The candidates' renders have this many pixels along the image's longer side (its
        aspect kept); their counts are scaled to the full render.
    margin : float, default 0.05
        The best state is kept only where its energy is at least this fraction below that of
        the best kind of START_SPECS over the whole target, which is kept otherwise.
    start : Node, optional
        A state of an earlier anneal of the same scene's structure (another frame; `rebind`
        gives it and its `atoms`).
    short : bool, default False
        A short schedule from `start` (the starting temperature a tenth).
    model : CostModel, optional
        The cost model that prices the counts (default: ``costmodel.current()``, this
        machine's calibration, else the reference costs).
    default : str, default "bvh"
        The spec of groups outside the annealed tree that name none.
    log : callable, optional
        ``log(str)``, called with the progress.
    options : dict, optional
        The render's keywords (``resolution``, ``spd``, ``max_depth``, ``shading``, ...), as
        for `raykernel.render`.
    atoms : Atoms, optional
        The atoms `rebind` gave with `start`.

    Returns
    -------
    Annealed
        ``scene`` (the scene with the target regrouped, each group with its spec), ``state``
        and ``start`` (the hierarchies found and started from, ``after`` and ``before`` as
        text), ``energy``, the energies of the starts, the history of the run, its seconds,
        evaluations and why it ``stopped``.

    Raises
    ------
    OptionError
        A parameter is out of its range, `atoms` are given without `start` or `start` does not
        hold this scene's atoms, or no starting structure can be built.

    Examples
    --------
    >>> found = anneal(scene, seconds=30, seed=0)
    >>> found.scene                                     # the scene regrouped, each group with its spec
    >>> print(found.before, found.after)                # the hierarchies as trees
    """
    from ..geometry.compiletime import CompileClock
    with CompileClock() as clock:       # compiling (a first run) is not searching: not in the budget
        return _anneal(scene, target, seconds, seed, memory, evaluations, moves, cooling, accept0, patience, sample,
                       margin, start, short, model, default, log, options, atoms, clock)


def _anneal(scene, target, seconds, seed, memory, evaluations, moves, cooling, accept0, patience, sample, margin,
            start, short, model, default, log, options, atoms, clock) -> Annealed:
    from . import costmodel
    seconds = _check("seconds", seconds, 0.0, 1e7)
    seed = _check("seed", seed, 0, 2 ** 63 - 1, integer=True)
    memory = _check("memory", memory, 0.0, 1e9)
    evaluations = _check("evaluations", evaluations, 0, 10 ** 9, integer=True)
    moves = _check("moves", moves, 0, 10 ** 6, integer=True)
    cooling = _check("cooling", cooling, 0.01, 0.999)
    accept0 = _check("accept0", accept0, 0.01, 0.99)
    patience = _check("patience", patience, 1, 1000, integer=True)
    sample = _check("sample", sample, 2, 4096, integer=True)
    margin = _check("margin", margin, 0.0, 0.9)
    t0 = time.perf_counter()
    target = scene.root if target is None else target
    if atoms is None:
        atoms, tree = atoms_of(scene, target)
    else:
        tree = None
        if start is None:
            raise OptionError("anneal: atoms (from rebind) go with the start state they were bound for")
    energy = Energy(scene, target, atoms, dict(options or {}), default, model or costmodel.current(), sample=sample,
                    memory=memory)
    rng = np.random.default_rng(seed)
    if not len(atoms.groups):
        only = Node(START_SPECS[0])
        return Annealed(scene, only, only, atoms, 0.0, 0.0, {START_SPECS[0]: 0.0}, [], 0.0, 0, seed, "empty")

    everything = list(range(len(atoms.groups)))
    starts = {}
    if start is not None:
        if sorted(start.all_atoms()) != everything:
            raise OptionError("anneal: the start state does not hold this scene's atoms (another structure?)")
        candidates = {"previous": start.copy()}
    else:
        candidates = {spec: Node(spec, list(everything)) for spec in START_SPECS + START_VARIANTS}
        own = _own_state(tree, target.accel if target.accel and not is_auto(target.accel) else None, default)
        if own.key() not in {c.key() for c in candidates.values()}:
            candidates["scene"] = own
    for name, state in candidates.items():
        starts[name] = energy(state)
        if log:
            log(f"start {name:12s} predicted {starts[name]:.4f} s")
    first = min(starts, key=starts.get)
    if starts[first] == math.inf:
        raise OptionError("anneal: no starting structure could be built for this scene (see raykernel accels)")
    current = best = candidates[first]
    e_cur = e_best = starts[first]

    def elapsed():
        return time.perf_counter() - t0 - clock.seconds

    def out_of_budget():
        return (elapsed() > seconds) or (evaluations and energy.evaluations >= evaluations)

    per_t = moves or int(min(48, max(16, 4 * len(atoms.groups))))
    # T0 from sampled moves: a typical uphill dE is accepted with probability accept0
    ups = []
    for _ in range(8):
        if out_of_budget():
            break
        _, cand = propose(current, atoms, rng)
        if cand is not None:
            d = energy(cand) - e_cur
            if 0 < d < math.inf:
                ups.append(d)
    t_start = (-float(np.median(ups)) / math.log(accept0)) if ups else max(e_cur, 1e-9) * 0.01
    if short:
        t_start *= 0.1
    temperature = t_start
    history = [(energy.evaluations, temperature, e_cur, e_best)]
    stale = 0
    stopped = "schedule"
    while True:
        if out_of_budget():
            stopped = "time" if elapsed() > seconds else "evaluations"
            break
        accepted = 0
        for _ in range(per_t):
            if out_of_budget():
                break
            _, cand = propose(current, atoms, rng)
            if cand is None:
                continue
            e = energy(cand)
            d = e - e_cur
            if d <= 0 or rng.random() < math.exp(-d / temperature):
                current, e_cur = cand, e
                accepted += d != 0
                if e < e_best:
                    best, e_best = cand, e
        history.append((energy.evaluations, temperature, e_cur, e_best))
        if log:
            log(f"T {temperature:.3g}  energy {e_cur:.4f}  best {e_best:.4f}  ({energy.evaluations} candidates)")
        stale = stale + 1 if accepted < 0.02 * per_t else 0
        if stale >= patience:
            stopped = "converged"
            break
        temperature *= cooling
        if temperature < t_start * 1e-3:
            break
    searched, kept = e_best, None
    plain = {k: e for k, e in starts.items() if k in START_SPECS}
    if plain:
        kind = min(plain, key=plain.get)
        if e_best > (1.0 - margin) * plain[kind]:
            best, e_best, kept = candidates[kind], plain[kind], kind
    whole = not best.children and len(best.atoms) == len(atoms.groups)
    tuned = _with_group(scene, target, _under_one(target, best.spec) if whole else
                        _merged_group(best, atoms, target.name or "auto"))
    return Annealed(tuned, best, candidates[first], atoms, e_best, starts[first], starts, history,
                    elapsed(), energy.evaluations, seed, stopped, searched, kept)


def _shape(sources) -> tuple:
    return tuple((type(src).__name__, src.count_primitives() if isinstance(src, Group) else
                  src.group.count_primitives() if isinstance(src, Instance) else
                  len(src)) for src in sources)


def rebind(state: Node, previous: Atoms, scene: Scene, target: Group | None = None) -> tuple[Node, Atoms]:
    """(state, atoms) for anneal(scene, start=state, atoms=atoms, ...) on `scene`, another frame
    of the same structure: each atom keeps its primitives, wherever they moved."""
    target = scene.root if target is None else target
    sources = _sources(_regions(target))
    if _shape(sources) != previous.shape:
        raise OptionError("anneal: this scene's structure differs from the previous frame's; anneal from scratch")
    groups, boxes = [], []
    for members in previous.members:
        sets = [_subset(sources[o], idx) for o, idx in members if idx is not None]
        opaque = [sources[o] for o, idx in members if idx is None]
        g = _group_of("", None, sets, opaque)
        groups.append(g)
        boxes.append(_box(g))
    atoms = Atoms(groups, np.array(boxes).reshape(-1, 6), previous.counts.copy(), previous.members, previous.shape,
                  sources)
    return state.copy(), atoms


# ---- the auto spec -------------------------------------------------------------------------------

def _auto_targets(group: Group, seen=None):
    seen = set() if seen is None else seen
    if id(group) in seen:
        return
    seen.add(id(group))
    if is_auto(group.accel):
        yield group
        return
    for c in group.children:
        yield from _auto_targets(c.group if isinstance(c, Instance) else c, seen)


def resolve_auto(scene: Scene, accel: str, options: dict, log=None):
    """raykernel.render's step for `auto` specs (auto.py): (the scene with
    every auto group annealed, the default spec for the rest, a summary per annealed group),
    None where nothing is auto. With accel auto the root is annealed."""
    from ..geometry.config import tell_once
    default = DEFAULT if is_auto(accel) else accel
    targets = [(scene.root, parse_spec(accel)[1])] if is_auto(accel) else \
        [(g, parse_spec(g.accel)[1]) for g in _auto_targets(scene.root)]
    if not targets:
        return None
    tell_once("anneal", "raykernel: annealing a hierarchy for an auto spec before the render (see time.anneal)")
    reports = []
    for target, params in targets:
        label = "(root)" if target is scene.root else (target.name or "(unnamed group)")
        found = anneal(scene, target=target, default=default, log=log, options=options, **params)
        scene = found.scene
        reports.append({"group": label, **found.summary()})
    return scene, default, reports


# ---- the report ------------------------------------------------------------------------------------

def plot(found: Annealed, path) -> None:
    """figure(found) as a PNG written atomically."""
    import io

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..atomicfile import write_bytes
    fig = figure(found)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    write_bytes(path, buf.getvalue())


def figure(found: Annealed):
    """Energy (current and best) and temperature over the run: a matplotlib figure."""
    import matplotlib.pyplot as plt
    h = np.array(found.history, float).reshape(-1, 4)
    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=110)
    ax.plot(h[:, 0], h[:, 2], label="energy", color="tab:blue")
    ax.plot(h[:, 0], h[:, 3], label="best", color="tab:green")
    ax.set_xlabel("candidates priced")
    ax.set_ylabel("predicted trace s")
    t = ax.twinx()
    t.semilogy(h[:, 0], h[:, 1], label="temperature", color="tab:red", linestyle="--")
    t.set_ylabel("temperature")
    fig.legend(loc="upper right")
    ax.set_title(f"annealing ({found.evaluations} candidates, {found.seconds:.1f} s, seed {found.seed})")
    fig.tight_layout()
    return fig
