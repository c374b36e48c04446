"""Every acceleration structure against the brute-force list: alone, nested in one another,
instanced, on the teapot in a stadium and on every SPD scene.

    SPECS                                   # every kind in accel.KINDS (read at import) and a few variants
    scene = mixed_scene(Layout(seed=1), outer="grid", inner="octree")     # groups in groups, instances
    got, want = check_layout(Layout(seed=1), "grid", "octree")           # that scene against list

The reference is the same scene with every group's structure replaced by
`list`. Every structure hands the same primitives the same (transformed) ray,
and closest-hit ties go to the smallest (kind, index, instance), so every
answer must be identical to the last bit: the closest hit (t, kind, index,
instance), whether any hit exists (and that the one reported is a real hit),
and every hit along the ray (RayScene.intersect_all and count_hits). The
list itself is checked against the extended-precision caster of
tests/reference.py in test_intersect.py and test_primitives.py.

The boolean operators (difference, intersection, union) are checked the
same way on scenes of closed solids (csg_scene): their operands built with
every kind, the node inside every kind, nested and instanced.

Kinds registered later are covered without editing this file. The quick
part tries every spec alone on a few random scenes, every ordered pair of
kinds on one scene, the stadium and the SPD scenes at size factor 1; the
full matrix of specs on more random scenes and the SPD scenes at their
default sizes are marked slow. Each kind's own tests (its builder, its walk's
special cases, its counters) are in its own file (test_octree.py, ...).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support import (
    Node,
    affine,
    fill_box,
    random_solid,
    random_tree,
    ray_counts,
    similarity,
    stadium_rays,
    work_counts,
    world_corners,
)

import raykernel
from raykernel.aggregates import csg
from raykernel.casting.rayscene import RayScene
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.geometry import counters as C
from raykernel.geometry.primitives import PATCH
from raykernel.aggregates import registry as accel
from raykernel.scene import Group, Instance, Scene, pathological, spd

VARIANTS = ("bvh(build=gs)", "bvh(split=16)", "bvh(split=4, width=2)", "octree(walk=point)", "octree(walk=parametric)", "octree(mailbox=off)",
            "grid(mailbox=off)", "hgrid(threshold=2)")
KIND_NAMES = tuple(name for name, kind in accel.KINDS.items() if not kind.operands)    # structures
OPERATORS = tuple(name for name, kind in accel.KINDS.items() if kind.operands)         # difference, ...
SPECS = KIND_NAMES + tuple(v for v in VARIANTS if v.split("(")[0] in accel.KINDS)

QUICK = settings(max_examples=5, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.too_slow])
THOROUGH = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow])
SPD_RESOLUTION = 24


# ---------------------------------------------------------------- scenes

@dataclass(frozen=True)
class Layout:
    """What a random scene is made of: the seed of every position, the primitives per group
    (spheres, cones, polygons, patches, mesh triangles: support.fill_box, with
    negative spheres, cylinders, concave polygons and a closed octahedron), the scale of the
    whole scene, and how far the child groups spread (small: disjoint, 1: all overlapping)."""

    seed: int
    counts: tuple = (6, 3, 4, 2, 8)
    extent: float = 1.0
    spread: float = 0.6


def scaled(m: np.ndarray, s: float) -> np.ndarray:
    """The 4x4 affine map m followed by a uniform scale s about the origin."""
    return np.diag([s, s, s, 1.0]) @ m


def mixed_scene(layout: Layout, outer: str, inner: str | None = None) -> Scene:
    """The root (structure `outer`) holds primitives of every kind. With `inner` it also holds
    a child group (`inner`) with primitives, a group without a spec (merged into the child)
    and a grandchild group (`outer`); a group `shape` (`inner`) shown by three instances
    (rotated and scaled, sheared, mirrored); and a group `holder` (`outer`) holding primitives
    and an instance of `shape`, itself instanced. Ids and numbering do not depend on the specs."""
    rng = np.random.default_rng(layout.seed)
    e = layout.extent
    scene = Scene()
    scene.root.accel = outer
    fill_box(scene.root, rng, layout.counts, extent=e)
    if inner is None:
        return scene
    small = tuple((c + 1) // 2 for c in layout.counts)
    part = layout.spread * e

    def somewhere():
        return rng.uniform(-1.0, 1.0, 3) * (e - 0.5 * part)

    child = fill_box(Group(name="child", accel=inner), rng, small, center=somewhere(), extent=part)
    child.add(fill_box(Group(name="merged"), rng, small, center=somewhere(), extent=0.5 * part))
    child.add(fill_box(Group(name="grandchild", accel=outer), rng, small, center=somewhere(), extent=0.5 * part))
    scene.root.add(child)
    shape = fill_box(Group(name="shape", accel=inner), rng, small, extent=1.0)
    mirror = np.diag([1.0, -1.0, 1.0, 1.0])
    for m in (similarity(rng), affine(rng), similarity(rng) @ mirror):
        scene.root.add(Instance(shape, scaled(m, 0.4 * part)))
    holder = fill_box(Group(name="holder", accel=outer), rng, small, extent=1.0)
    holder.add(Instance(shape, affine(rng, shift=1.0)))
    scene.root.add(Instance(holder, scaled(similarity(rng), 0.4 * part)))
    return scene


def probe_rays(scene: Scene, rng, n: int, extent: float, center=(0.0, 0.0, 0.0)):
    """(origins, directions, tmin, tmax), n rays in six equal parts: from outside aimed into the
    box center +- extent; from inside in random directions; from inside with a random finite
    [tmin, tmax]; axis-parallel; axis-parallel through a polygon or triangle vertex; and aimed
    at vertices and edge midpoints (where neighbouring triangles and polygons meet)."""
    c = np.asarray(center, np.float64)
    k = n // 6
    far = rng.normal(size=(n, 3))
    far = c + 3.0 * extent * far / np.linalg.norm(far, axis=1)[:, None]
    inside = c + extent * rng.uniform(-1, 1, (n, 3))
    o = np.empty((n, 3))
    d = np.empty((n, 3))
    tmin = np.zeros(n)
    tmax = np.full(n, np.inf)
    # from outside into the box
    o[:k], d[:k] = far[:k], inside[:k] - far[:k]
    # from inside, random directions of random lengths
    o[k:3 * k] = inside[k:3 * k]
    d[k:3 * k] = rng.normal(size=(2 * k, 3)) * rng.uniform(0.2, 3.0, (2 * k, 1))
    length = np.linalg.norm(d[2 * k:3 * k], axis=1)
    tmin[2 * k:3 * k] = rng.uniform(0, 1, k) * extent / length
    tmax[2 * k:3 * k] = tmin[2 * k:3 * k] + rng.exponential(1.0, k) * extent / length
    # axis-parallel, both signs, power-of-two lengths
    axis = rng.integers(0, 3, n)
    sign = rng.choice([-1.0, 1.0], n)
    unit = np.zeros((n, 3))
    unit[np.arange(n), axis] = sign * 2.0 ** rng.integers(-2, 3, n)
    o[3 * k:4 * k] = inside[3 * k:4 * k]
    d[3 * k:4 * k] = unit[3 * k:4 * k]
    corners = world_corners(scene.root)
    if corners:
        pick = [corners[j] for j in rng.integers(0, len(corners), n)]
        vertex = np.array([p[rng.integers(len(p))] for p in pick])
        edge = np.array([0.5 * (p[j] + p[(j + 1) % len(p)]) for p in pick for j in [rng.integers(len(p))]])
        target = np.where(rng.uniform(size=(n, 1)) < 0.5, vertex, edge)
        # axis-parallel through a vertex: the ray passes it exactly
        o[4 * k:5 * k] = vertex[4 * k:5 * k] - 3.0 * extent * np.sign(unit[4 * k:5 * k])
        d[4 * k:5 * k] = unit[4 * k:5 * k]
        o[5 * k:] = far[5 * k:]
        d[5 * k:] = target[5 * k:] - far[5 * k:]
    else:
        o[4 * k:], d[4 * k:] = far[4 * k:], inside[4 * k:] - far[4 * k:]
    return o, d, tmin, tmax


# ---------------------------------------------------------------- answers

@dataclass
class Answers:
    closest: tuple        # cast_rays: t, kind, index, instance
    any_hit: tuple        # cast_rays with any_hit
    everything: tuple     # RayScene.intersect_all(ids=True): ray, t, prim_id, geom_id, inst_id
    counts: np.ndarray    # RayScene.count_hits
    stats: dict           # flatten's build statistics


def answers(scene: Scene, o, d, tmin, tmax, default="list") -> Answers:
    rs = RayScene.from_scene(scene, default)          # built once: rs.geo feeds cast_rays too
    closest = cast_rays(rs.geo, o, d, tmin, tmax)[:4]
    any_hit = cast_rays(rs.geo, o, d, tmin, tmax, any_hit=True)[:4]
    return Answers(closest, any_hit, tuple(rs.intersect_all(o, d, tmin, tmax, ids=True)),
                   rs.count_hits(o, d, tmin, tmax), rs.build_stats)


def first_difference(got, want, names) -> str:
    for name, a, b in zip(names, got, want):
        if not np.array_equal(a, b):
            if np.shape(a) != np.shape(b):
                return f"{name}: {np.shape(a)} values against {np.shape(b)}"
            r = int(np.flatnonzero(np.asarray(a) != np.asarray(b))[0])
            return f"{name} of ray {r}: {a[r]!r} against {b[r]!r}"
    return ""


def assert_same_answers(got: Answers, want: Answers, what: str, o, d):
    """Bit-identical closest hits, all-hits lists and counts; any-hit finds a hit exactly when
    there is one, and reports one of the list's hits of that ray (same t and instance)."""
    diff = first_difference(got.closest, want.closest, ("t", "kind", "index", "instance"))
    if diff:
        r = int(diff.split("ray ")[1].split(":")[0])
        pytest.fail(f"{what}: closest hit differs from list: {diff} (origin {o[r].tolist()}, "
                    f"direction {d[r].tolist()})")
    hit = np.isfinite(want.closest[0])
    found = np.isfinite(got.any_hit[0])
    bad = np.flatnonzero(hit != found)
    assert not len(bad), f"{what}: any-hit disagrees with list on {len(bad)} rays, first {bad[0]}"
    assert np.all(got.any_hit[0][found] >= want.closest[0][found])
    ray, t, inst = want.everything[0], want.everything[1], want.everything[-1]
    hits = set(zip(ray.tolist(), t.tolist(), inst.tolist()))
    for r in np.flatnonzero(found):
        key = (int(r), float(got.any_hit[0][r]), int(got.any_hit[3][r]))
        assert key in hits, f"{what}: any-hit of ray {r} at t={key[1]!r} is none of the list's hits"
    diff = first_difference(got.everything, want.everything, ("ray", "t", "prim_id", "geom_id", "inst_id"))
    assert not diff, f"{what}: intersect_all differs from list: {diff}"
    np.testing.assert_array_equal(got.counts, want.counts, err_msg=f"{what}: count_hits differs from list")


def check_layout(layout: Layout, outer: str, inner: str | None, n_rays: int = 240) -> tuple[Answers, Answers]:
    """Build the layout with the specs and with list everywhere, cast the same rays, compare;
    returns both answers."""
    scene = mixed_scene(layout, outer, inner)
    rays = probe_rays(scene, np.random.default_rng(layout.seed + 1), n_rays, layout.extent)
    want = answers(mixed_scene(layout, "list", None if inner is None else "list"), *rays)
    got = answers(scene, *rays)
    assert_same_answers(got, want, f"{outer} over {inner}" if inner else outer, rays[0], rays[1])
    return got, want


layouts = st.builds(Layout, seed=st.integers(0, 2 ** 31 - 1),
                    counts=st.tuples(st.integers(0, 8), st.integers(0, 4), st.integers(0, 5), st.integers(0, 3),
                                     st.integers(0, 12)),
                    extent=st.sampled_from([1e-3, 1.0, 1e4]), spread=st.floats(0.1, 1.0))


# ---------------------------------------------------------------- the specs

def test_specs_cover_every_registered_kind_and_parse():
    assert "list" in KIND_NAMES and len(KIND_NAMES) >= 6
    assert set(KIND_NAMES) <= {s.split("(")[0] for s in SPECS}
    for spec in SPECS:
        name, params = accel.parse_spec(spec)
        assert name in accel.KINDS and accel.parse_spec(accel.format_spec(name, params)) == (name, params)


def described_defaults() -> dict:
    """kind -> {parameter: its default as written} of the text registry.describe() prints: a line
    "kind: help" for every kind, then a line "    name=default  (values) help" for each parameter."""
    out, kind = {}, None
    for line in accel.describe().splitlines():
        if line.startswith("    "):
            key, value = line.strip().split("  ")[0].split("=", 1)
            assert key not in out[kind], f"{kind}: {key} described twice"
            out[kind][key] = value
        else:
            kind = line.split(":")[0]
            out[kind] = {}
    return out


@pytest.mark.parametrize("name", list(accel.KINDS))
def test_every_kinds_defaults_are_described_and_parsed(name):
    """describe() lists every parameter of every registered kind, in order, as name=default; that
    text read back as a spec, and the bare kind name, parse to the parameters' declared defaults."""
    params = accel.KINDS[name].params
    shown = described_defaults()[name]
    assert list(shown) == [p.name for p in params]
    assert shown == {p.name: ("on" if p.default else "off") if isinstance(p.default, bool) else str(p.default)
                     for p in params}
    text = f"{name}({', '.join(f'{k}={v}' for k, v in shown.items())})" if shown else name
    defaults = (name, {p.name: p.default for p in params})
    assert accel.parse_spec(text) == defaults
    assert accel.parse_spec(name) == defaults


@pytest.mark.parametrize("spec", SPECS)
@QUICK
@given(layout=layouts)
def test_every_kind_alone_matches_list(spec, layout):
    check_layout(layout, spec, None)


@pytest.mark.parametrize("inner", KIND_NAMES)
@pytest.mark.parametrize("outer", KIND_NAMES)
def test_every_pair_of_kinds_nested_and_instanced_matches_list(outer, inner):
    layout = Layout(seed=1000 + 37 * KIND_NAMES.index(outer) + KIND_NAMES.index(inner), extent=4.0)
    got, want = check_layout(layout, outer, inner, n_rays=800)
    # the scene is worth comparing on: most rays hit, through every instance and every primitive kind
    t, kind, _, inst = want.closest
    assert np.isfinite(t).mean() > 0.3
    assert set(inst[np.isfinite(t)].tolist()) >= {-1, 0, 1, 2, 3, 4}
    assert set(kind[np.isfinite(t)].tolist()) == {0, 1, 2, 3, 4}
    assert want.counts.max() >= 4
    # and the structures were built as asked: root, child, grandchild, shape, holder
    built = {a["kind"].split("(")[0] for a in got.stats["aggregates"]}
    assert {outer, inner} <= built and got.stats["build.nesting"] >= 3


@pytest.mark.slow
@pytest.mark.parametrize("inner", SPECS)
@pytest.mark.parametrize("outer", SPECS)
@THOROUGH
@given(layout=layouts)
def test_every_pair_of_specs_on_random_scenes(outer, inner, layout):
    check_layout(layout, outer, inner)


# ---------------------------------------------------------------- the boolean operators

def csg_scene(seed: int, op: str, outer: str, inner: str) -> Scene:
    """A CSG node `op` of four closed solids and small CSG trees (operands built with `inner`,
    base 2 for a difference), in a root of structure `outer` among random primitives, and
    the same node instanced once more, rotated and scaled."""
    rng = np.random.default_rng(seed)
    spread = 0.3 if op == "intersection" else 1.0       # overlapping enough not to be empty
    node = Node(op, [random_tree(rng, 1, spread=spread), random_solid(rng, spread=spread),
                     random_solid(rng, spread=spread), random_tree(rng, 1, spread=spread)], base=2)
    scene = Scene()
    scene.root.accel = outer
    fill_box(scene.root, rng, (4, 2, 3, 1, 6), extent=3.0)
    group = node.group(inner)
    scene.root.add(group)
    scene.root.add(Instance(group, scaled(similarity(rng), 0.7)))
    return scene


def check_csg(seed: int, op: str, outer: str, inner: str, n_rays: int = 300):
    """csg_scene against the same scene with list everywhere. The first of the seeds
    seed * 10, seed * 10 + 1, ... whose rays meet the node's surfaces (an intersection of
    random solids is often empty) is used."""
    for seed in range(10 * seed, 10 * seed + 10):
        reference = csg_scene(seed, op, "list", "list")
        rays = probe_rays(reference, np.random.default_rng(seed + 1), n_rays, 3.0)
        counts = cast_rays(flatten(reference, "list")[0], *rays)[4]
        if counts[csg.SURFACES] > 20 and counts[C.TRANSFORMS:C.TRANSFORMS + 4].sum() > 0:
            break
    else:
        pytest.fail(f"no seed gave a {op} that the rays meet")
    want = answers(reference, *rays)
    got = answers(csg_scene(seed, op, outer, inner), *rays, default=inner)
    assert_same_answers(got, want, f"{op} of {inner} operands in {outer}", rays[0], rays[1])
    built = {a["kind"].split("(")[0] for a in got.stats["aggregates"]}
    assert {op, outer.split("(")[0], inner.split("(")[0]} <= built


@pytest.mark.parametrize("kind", KIND_NAMES)
@pytest.mark.parametrize("op", OPERATORS)
def test_every_operator_over_and_inside_every_kind_matches_list(op, kind):
    seed = 7 * OPERATORS.index(op) + 100 * KIND_NAMES.index(kind)
    check_csg(seed, op, kind, "list")
    check_csg(seed + 1, op, "list", kind)


@pytest.mark.slow
@pytest.mark.parametrize("inner", SPECS)
@pytest.mark.parametrize("outer", SPECS)
@pytest.mark.parametrize("op", OPERATORS)
def test_every_operator_with_every_pair_of_specs(op, outer, inner):
    for seed in range(3):
        check_csg(1000 * seed + SPECS.index(outer) * 31 + SPECS.index(inner), op, outer, inner)


def test_the_comparison_catches_a_wrong_answer():
    """The checks fail on a scene that differs from the reference by one moved sphere."""
    layout = Layout(seed=5, extent=2.0)
    scene = mixed_scene(layout, "bvh", "grid")
    rays = probe_rays(scene, np.random.default_rng(6), 600, layout.extent)
    want = answers(mixed_scene(layout, "list", "list"), *rays)
    scene.root.spheres.center[0] += 0.05 * layout.extent
    got = answers(scene, *rays)
    with pytest.raises(pytest.fail.Exception, match="moved sphere: closest hit differs from list"):
        assert_same_answers(got, want, "moved sphere", rays[0], rays[1])


# ---------------------------------------------------------------- the teapot in a stadium

@pytest.mark.parametrize("ratio", [1.0, 1e6])
def test_stadium_every_kind_matches_list(ratio):
    scene = pathological.stadium(ratio=ratio)
    o, d, tmin, tmax = stadium_rays(scene, np.random.default_rng(int(ratio)), 1200)
    want = answers(scene, o, d, tmin, tmax, "list")
    t, kind, _, _ = want.closest
    assert np.isfinite(t).mean() > 0.6
    assert np.count_nonzero(kind == PATCH) > 200        # the teapot is hit, not only the stadium
    for spec in SPECS:
        if spec == "list":
            continue
        got = answers(scene, o, d, tmin, tmax, spec)
        assert_same_answers(got, want, f"{spec} on the stadium at ratio {ratio:g}", o, d)


# ---------------------------------------------------------------- the SPD scenes

def render_every_kind(scene, resolution):
    base = raykernel.render(scene, accel="list", resolution=resolution, spd=True)
    counts = ray_counts(base.stats)
    assert counts["rays.eye"] == (resolution + 1) ** 2 and counts["rays.shadow"] > 0
    for spec in SPECS:
        r = raykernel.render(scene, accel=spec, resolution=resolution, spd=True)
        assert ray_counts(r.stats) == counts, f"{spec}: ray counts differ from list"
        diff = np.argwhere(r.image != base.image)
        assert not len(diff), (f"{spec}: {len(diff)} image values differ from list, first at "
                               f"{diff[0].tolist()}: {r.image[tuple(diff[0])]!r} against "
                               f"{base.image[tuple(diff[0])]!r}")
        np.testing.assert_array_equal(r.to_uint8(), base.to_uint8())


@pytest.mark.parametrize("name", spd.NAMES)
def test_small_spd_scenes_render_identically_with_every_kind(name):
    render_every_kind(raykernel.load(f"spd:{name}:1"), 16)


@pytest.mark.slow
@pytest.mark.parametrize("name", spd.NAMES)
def test_default_spd_scenes_render_identically_with_every_kind(name):
    render_every_kind(raykernel.load(f"spd:{name}"), SPD_RESOLUTION)


# ---------------------------------------------------------------- thread counts

def work_and_hits(spec, threads):
    """A render and two RayScene queries (the lazy kinds refine during both) at `threads` threads."""
    scene = raykernel.load("spd:balls:2")
    r = raykernel.render(scene, accel=spec, resolution=40, spd=True, threads=threads)
    rng = np.random.default_rng(3)
    o = rng.normal(0, 4, (20000, 3))
    d = rng.normal(0, 1, (20000, 3)) - 0.1 * o
    numba.set_num_threads(threads)
    try:
        rs = RayScene(scene, spec)
        h = rs.intersect(o, d)
        hit_stats = {k: v for k, v in rs.last_stats.items() if not k.startswith("time.")}
        n = rs.count_hits(o, d)
        count_stats = {k: v for k, v in rs.last_stats.items() if not k.startswith("time.")}
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    return r, work_counts(r.stats), h, hit_stats, n, count_stats, rs.build_stats["build.nodes"]


@pytest.mark.parametrize("spec", SPECS)
def test_every_kind_is_the_same_at_one_and_two_threads(spec):
    one, two = work_and_hits(spec, 1), work_and_hits(spec, 2)
    assert one[0].stats.info["threads"] == 1 and two[0].stats.info["threads"] == 2
    assert one[0].image.tobytes() == two[0].image.tobytes()
    assert one[1] == two[1] and one[1]["tests.total"] > 0
    np.testing.assert_array_equal(one[2].t, two[2].t)
    np.testing.assert_array_equal(one[2].prim_id, two[2].prim_id)
    assert one[3] == two[3] and one[5] == two[5] and one[6] == two[6]
    np.testing.assert_array_equal(one[4], two[4])
    if spec.startswith(("lazyoctree", "rc")) and "lazy=off" not in spec:
        assert one[1]["build.subdivisions"] > 0     # the lazy trees refined, the same way
