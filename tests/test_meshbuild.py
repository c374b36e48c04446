"""Meshes built straight into the mesh kernel's arrays (casting/meshbuild.py), at every quality, against
the brute-force list; the parallel and Morton builds of bvhbuild.py; winding numbers and contains."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from numba import njit

from raykernel import RayScene
from raykernel.aggregates import bvhbuild
from raykernel.aggregates.memory import MemoryBudgetError
from raykernel.aggregates.widebvh import collapse
from raykernel.casting.meshbuild import QUALITY
from raykernel.casting.proximity import is_closed, winding_tree

QUALITIES = tuple(QUALITY)


def sphere(sub=3):
    m = trimesh.creation.icosphere(subdivisions=sub)
    return np.ascontiguousarray(m.vertices, np.float64), np.ascontiguousarray(m.faces, np.int64)


def edge_and_vertex_rays(v, f, rng, n=300):
    """Rays from outside aimed at vertices and at edge midpoints (shared by two triangles of a closed
    mesh), and axis-parallel rays through them."""
    targets = np.concatenate([v[rng.integers(0, len(v), n)],
                              0.5 * (v[f[rng.integers(0, len(f), n), 0]] + v[f[rng.integers(0, len(f), n), 1]])])
    c = v.mean(axis=0)
    size = np.ptp(v, axis=0).max()
    o = c + rng.normal(size=(len(targets), 3)) * size * 3
    d = targets - o
    axis = np.eye(3)[rng.integers(0, 3, len(targets))] * rng.choice([-1.0, 1.0], (len(targets), 1))
    o2 = targets - axis * size * 3
    return np.concatenate([o, o2]), np.concatenate([d, axis])


def assert_same_as_list(v, f, o, d, quality):
    fast = RayScene.from_mesh(v, f, quality=quality)
    ref = RayScene.from_mesh(v, f, accel="list")
    a, b = fast.intersect(o, d), ref.intersect(o, d)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.prim_id, b.prim_id)
    np.testing.assert_array_equal(a.normal, b.normal)
    np.testing.assert_array_equal(fast.occluded(o, d), ref.occluded(o, d))
    for x, y in zip(fast.intersect_all(o, d), ref.intersect_all(o, d)):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(fast.count_hits(o, d), ref.count_hits(o, d))
    return a


@pytest.mark.parametrize("quality", QUALITIES)
def test_every_quality_matches_the_list_on_edges_vertices_and_axis_rays(quality):
    v, f = sphere(3)
    rng = np.random.default_rng(1)
    o, d = edge_and_vertex_rays(v, f, rng)
    hits = assert_same_as_list(v, f, o, d, quality)
    # rays that cross the sphere (not grazing its silhouette) hit it, through an edge or vertex too,
    # and cross it an even number of times: the watertight test counts a shared edge once
    u = d / np.linalg.norm(d, axis=1)[:, None]
    crossing = np.linalg.norm(np.cross(o, u), axis=1) < 0.95      # the line passes within 0.95 of the centre
    assert np.isfinite(hits.t[crossing]).all()
    assert (RayScene.from_mesh(v, f, quality=quality).count_hits(o, d)[crossing] % 2 == 0).all()


@pytest.mark.parametrize("scale", [1e-6, 1e-3, 1.0, 1e3, 1e7])
@pytest.mark.parametrize("quality", ("fast", "medium"))
def test_float32_boxes_lose_no_hit_at_any_scale(scale, quality):
    v, f = sphere(2)
    rng = np.random.default_rng(int(scale * 1e6) % 1000)
    shift = np.array([scale * 3, -scale * 1e3, scale]) if scale >= 1 else np.zeros(3)
    v = v * scale + shift
    o, d = edge_and_vertex_rays(v, f, rng, 100)
    grazing = rng.uniform(-scale, scale, (100, 3)) + shift
    o = np.concatenate([o, grazing - [3 * scale, 0, 0]])
    d = np.concatenate([d, np.tile([1.0, 0, 0], (100, 1))])
    assert_same_as_list(v, f, o, d, quality)


def test_random_soup_and_rays_of_every_kind():
    rng = np.random.default_rng(7)
    v = rng.uniform(-1, 1, (900, 3))
    f = rng.integers(0, 900, (1500, 3))
    o = rng.uniform(-2, 2, (2000, 3))
    d = rng.normal(size=(2000, 3))
    for quality in QUALITIES:
        assert_same_as_list(v, f, o, d, quality)


def test_the_direct_build_is_lean_and_makes_no_scene_geometry():
    v, f = sphere(5)
    rs = RayScene.from_mesh(v, f)
    rs.intersect(v.mean(0), [0, 0, 1.0])
    assert rs._geo is None                       # ray casting needs no general Geometry
    st = rs.stats
    assert st["bytes_per_triangle"] <= 110, st["bytes_per_triangle"]
    assert st["bytes"] == rs._mesh.nbytes
    assert st["sah_cost"] > 0 and st["quality"] == "medium"
    # the general Geometry is built on first use, and point queries still answer right
    cp = rs.closest_points([[0.0, 0.0, 2.0]])
    assert rs._geo is not None and abs(cp.distance[0] - 1.0) < 1e-2


def test_the_surface_and_vertex_normals_match_the_general_path():
    v, f = sphere(2)
    n = v / np.linalg.norm(v, axis=1)[:, None]
    rng = np.random.default_rng(3)
    o = rng.normal(size=(500, 3)) * 3
    d = -o + rng.normal(size=(500, 3)) * 0.3
    a = RayScene.from_mesh(v, f, normals=n).intersect(o, d)
    b = RayScene.from_mesh(v, f, normals=n, accel="bvh(block=4)").intersect(o, d)
    for field in ("t", "prim_id", "uv", "normal", "shading_normal"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


def test_counters_do_not_depend_on_the_thread_count():
    v, f = sphere(4)
    rng = np.random.default_rng(4)
    o, d = rng.normal(size=(5000, 3)) * 2, rng.normal(size=(5000, 3))
    rs = RayScene.from_mesh(v, f)
    stats = []
    for threads in (1, 2):
        rs.intersect(o, d, threads=threads)
        stats.append({k: v for k, v in rs.last_stats.items() if not k.startswith("time.")})
    assert stats[0] == stats[1]


def test_bad_quality_and_the_memory_budget():
    v, f = sphere(3)
    with pytest.raises(ValueError, match="quality must be one of fast, medium, high"):
        RayScene.from_mesh(v, f, quality="best")
    with pytest.raises(MemoryBudgetError, match="triangles needs .* the memory budget of 64.0 KiB"):
        RayScene.from_mesh(v, f, max_memory="64K")


@pytest.mark.parametrize("threads", [1, 2])
def test_the_first_triangle_out_of_range_is_named_whichever_thread_made_it(threads):
    from raykernel.errors import SceneError
    rng = np.random.default_rng(0)
    n = 100_000                   # rows made in several ranges, on the threads
    v = rng.uniform(-1, 1, (3 * n, 3))
    f = np.arange(3 * n, dtype=np.int64).reshape(n, 3)
    v[f[90_000]] = [[0, 0, 0], [1e-32, 0, 0], [0, 1e-32, 0]]   # too small, not zero
    v[f[60_000, 1], 2] = 1e31                                                                 # too far
    v[f[99_000, 0], 0] = -1e31
    with pytest.raises(SceneError, match="triangle 60000"):
        RayScene.from_mesh(v, f, threads=threads)
    v[f[60_000, 1], 2] = 0.0
    with pytest.raises(SceneError, match="triangle 90000"):
        RayScene.from_mesh(v, f, threads=threads)
    v[f[90_000]] = 0.0                              # a point: zero size is allowed
    with pytest.raises(SceneError, match="triangle 99000"):
        RayScene.from_mesh(v, f, threads=threads)


def test_an_empty_mesh():
    rs = RayScene.from_mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    assert not np.isfinite(rs.intersect([0, 0, 0.0], [1.0, 0, 0]).t).any()


# ----------------------------------------------------------------- the builders


def leaves_of(tree):
    """Each leaf's items, in depth-first order from the root, and the node boxes checked on the way."""
    out, stack = [], [0]
    while stack:
        i = stack.pop()
        if tree.count[i] > 0 or tree.first[i] <= i:
            out.append(tuple(tree.order[tree.first[i]:tree.first[i] + tree.count[i]]))
        else:
            for c in (tree.first[i], tree.first[i] + 1):
                assert c > i and (tree.bounds[c, :3] >= tree.bounds[i, :3]).all()
                assert (tree.bounds[c, 3:] <= tree.bounds[i, 3:]).all()
            stack += [tree.first[i] + 1, tree.first[i]]
    return out


def random_boxes(n, seed):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-10, 10, (n, 3)) ** 3
    return np.c_[lo, lo + rng.exponential(0.5, (n, 3))]


def assert_parallel_build_is_serial_tree(items, monkeypatch):
    """The same arrays at 1 and 2 threads, and the same splits as the serial build (every item once,
    no node lost or left over by the compaction)."""
    one, _ = bvhbuild.build_bvh(items, block=4, threads=1)
    two, _ = bvhbuild.build_bvh(items, block=4, threads=2)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)
    monkeypatch.setattr(bvhbuild, "PARALLEL_ITEMS", 1 << 40)
    serial, _ = bvhbuild.build_bvh(items, block=4)
    assert leaves_of(serial) == leaves_of(one)
    assert sorted(i for leaf in leaves_of(one) for i in leaf) == list(range(len(items)))
    assert len(one.count) == len(serial.count)


def test_the_parallel_build_is_the_serial_tree_at_any_thread_count(monkeypatch):
    assert_parallel_build_is_serial_tree(random_boxes(bvhbuild.PARALLEL_ITEMS + 5000, 9), monkeypatch)


@pytest.mark.parametrize("stack", [1 << 16, 8])
def test_every_stage_of_the_parallel_build_keeps_the_serial_tree(monkeypatch, stack):
    """Small stages, so that the head, the middle (its blocks filled, and its stack too when small)
    and the small tasks all split nodes."""
    monkeypatch.setattr(bvhbuild, "PARALLEL_ITEMS", 1000)
    monkeypatch.setattr(bvhbuild, "DEFER_ITEMS", 40)
    monkeypatch.setattr(bvhbuild, "HEAD_PARTS", 16)
    monkeypatch.setattr(bvhbuild, "TOP_STACK", stack)
    assert_parallel_build_is_serial_tree(random_boxes(6000, 4), monkeypatch)


@njit
def one_thread_partition(data, order, s, e, axis, cmin, scale, bins, split_bin, lcb, rcb, lbox, rbox):
    """bvhbuild._partition (compiled without a Python wrapper: kernels call it) with its boxes gathered."""
    return bvhbuild._partition(data, order, s, e, axis, cmin, scale, bins, split_bin, lcb, rcb, True, lbox, rbox)


def rows_of(items):
    data = np.empty((len(items), bvhbuild.ROW_COLUMNS))
    bvhbuild._item_data(items, np.arange(len(items), dtype=float), data, 0, len(items))
    return data


@pytest.mark.parametrize("s, e, chunk", [(0, 5000, 64), (123, 4901, 100), (7, 90, 1000)])
@pytest.mark.parametrize("split_bin", [0, 3, 9, 16])
def test_the_partition_on_threads_against_brute_force(monkeypatch, s, e, chunk, split_bin):
    """Every item of data[s:e] whose centre falls in a bin left of split_bin ends before the middle,
    the others from it on, each row with its own index (order), nothing outside s:e touched, and the
    four boxes those of the two sides' items and centres; the same order at 1 and 2 threads, and the
    same middle and boxes as the one-thread partition."""
    monkeypatch.setattr(bvhbuild, "CHUNK_ITEMS", chunk)
    items = random_boxes(5000, split_bin)
    data = rows_of(items)
    bins, axis = 16, 1
    centre = 0.5 * items[:, :3] + 0.5 * items[:, 3:]
    cmin = np.r_[centre[s:e].min(0), 0.0]
    scale = np.r_[bins / (centre[s:e].max(0) - cmin[:3]), 0.0]
    f = (centre[:, axis] - cmin[axis]) * scale[axis]
    left = np.where(f < bins - 1, np.floor(f), bins - 1) < split_bin
    split = np.r_[axis, split_bin, bins, cmin[:3], scale[:3]].astype(float)
    out = {}
    for name in (1, 2, "plain"):
        d, order = data.copy(), np.arange(len(items))
        if name == "plain":
            lcb, rcb, lbox, rbox = (np.empty(bvhbuild.ROW) for _ in range(4))
            mid = one_thread_partition(d, order, s, e, axis, cmin, scale, bins, split_bin, lcb, rcb, lbox, rbox)
        else:
            mid, boxes = bvhbuild._partition_on_threads(d, order, s, e, split, name)
            lcb, rcb, lbox, rbox = bvhbuild._united(boxes)
        assert mid - s == left[s:e].sum()
        assert set(order[s:mid]) == set(np.flatnonzero(left[s:e]) + s)
        np.testing.assert_array_equal(d, data[order])
        assert (order[:s] == np.arange(s)).all() and (order[e:] == np.arange(e, len(items))).all()
        for side, cb, box in ((order[s:mid], lcb, lbox), (order[mid:e], rcb, rbox)):
            if len(side):
                np.testing.assert_array_equal(cb[:3], centre[side].min(0))
                np.testing.assert_array_equal(cb[4:7], centre[side].max(0))
                np.testing.assert_array_equal(box[:3], items[side, :3].min(0))
                np.testing.assert_array_equal(box[4:7], items[side, 3:].max(0))
            else:
                assert (cb[:3] == np.inf).all() and (box[4:7] == -np.inf).all()
        out[name] = order
    np.testing.assert_array_equal(out[1], out[2])


def test_the_head_partitions_on_the_threads_as_on_one(monkeypatch):
    """A build whose head partitions in chunks on the threads: the same arrays at 1 and 2 threads,
    every item in one leaf, the boxes nested, and not the arrays of the build without chunks (so
    the chunks were taken)."""
    items = random_boxes(bvhbuild.PARALLEL_ITEMS * 4, 3)
    monkeypatch.setattr(bvhbuild, "WIDE_ITEMS", 1 << 40)
    plain, _ = bvhbuild.build_bvh(items, block=4, threads=2)
    monkeypatch.setattr(bvhbuild, "WIDE_ITEMS", bvhbuild.PARALLEL_ITEMS)
    monkeypatch.setattr(bvhbuild, "CHUNK_ITEMS", 1000)
    one, _ = bvhbuild.build_bvh(items, block=4, threads=1)
    two, _ = bvhbuild.build_bvh(items, block=4, threads=2)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)
    assert sorted(i for leaf in leaves_of(one) for i in leaf) == list(range(len(items)))
    assert leaves_of(one) != leaves_of(plain)
    np.testing.assert_array_equal(one.bounds[0], np.r_[items[:, :3].min(0), items[:, 3:].max(0)])
    np.testing.assert_array_equal(one.bounds[0], plain.bounds[0])
    for i in np.flatnonzero(one.count > 0):
        mine = items[one.order[one.first[i]:one.first[i] + one.count[i]]]
        np.testing.assert_array_equal(one.bounds[i], np.r_[mine[:, :3].min(0), mine[:, 3:].max(0)])


def test_the_wide_tree_of_the_build_with_gaps_is_the_compacted_ones(monkeypatch):
    """The mesh build leaves the parallel build's unused node rows in place: collapsed from the root,
    its 4-wide tree and SAH cost are those of the compacted tree, and the cost is the brute-force
    sum over the compacted tree's boxes widened by the margin."""
    monkeypatch.setattr(bvhbuild, "PARALLEL_ITEMS", 1000)
    monkeypatch.setattr(bvhbuild, "DEFER_ITEMS", 40)
    items = random_boxes(6000, 5)
    data = np.empty((len(items), bvhbuild.ROW_COLUMNS))
    bvhbuild._item_data(items, np.ones(len(items)), data, 0, len(items))
    dense = bvhbuild.build_rows(data.copy(), "sah", 4, 16, 1.0, 1.0, 4, 2)
    gaps = bvhbuild.build_rows(data.copy(), "sah", 4, 16, 1.0, 1.0, 4, 2, compact=False)
    n = dense[4]
    assert gaps[4] > n
    margin = 0.01
    wide, cost = collapse(dense[0][:n], dense[1][:n], dense[2][:n], 0, margin)
    wide_gaps, cost_gaps = collapse(*gaps[:3], 0, margin)
    np.testing.assert_array_equal(wide.nodes, wide_gaps.nodes)
    assert cost == cost_gaps
    box = dense[0][:n] + np.r_[[-margin] * 3, [margin] * 3]
    ext = box[:, 3:] - box[:, :3]
    area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
    count = dense[2][:n]
    assert cost == pytest.approx(float((area * np.where(count > 0, count, 1)).sum() / area[0]), rel=1e-12)


@pytest.mark.parametrize("n", [1, 2, 5, 1000, 40000])
def test_the_morton_build_holds_every_item_once_in_small_leaves(n):
    items = random_boxes(n, n)
    tree, stats = bvhbuild.build_bvh(items, leaf_size=4, method="morton")
    leaves = leaves_of(tree)
    assert sorted(i for leaf in leaves for i in leaf) == list(range(n))
    assert max(len(leaf) for leaf in leaves) <= 4 and stats["nodes"] == 2 * len(leaves) - 1
    for i in np.flatnonzero(tree.count > 0):
        mine = items[tree.order[tree.first[i]:tree.first[i] + tree.count[i]]]
        np.testing.assert_array_equal(tree.bounds[i], np.r_[mine[:, :3].min(0), mine[:, 3:].max(0)])


def test_the_morton_build_of_coincident_items():
    tree, _ = bvhbuild.build_bvh(np.tile([0.0, 0, 0, 1, 1, 1], (37, 1)), leaf_size=4, method="morton")
    assert sorted(i for leaf in leaves_of(tree) for i in leaf) == list(range(37))


def test_bvh_spec_build_morton_renders_like_sah():
    v, f = sphere(2)
    rng = np.random.default_rng(2)
    o, d = rng.normal(size=(300, 3)) * 3, rng.normal(size=(300, 3))
    a = RayScene.from_mesh(v, f, accel="bvh(build=morton)").intersect(o, d)
    b = RayScene.from_mesh(v, f, accel="list").intersect(o, d)
    np.testing.assert_array_equal(a.t, b.t)


# ----------------------------------------------------------------- winding numbers and contains


def brute_winding(v, f, points):
    a, b, c = (v[f[:, k]][None] - points[:, None] for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
    det = np.einsum("pti,pti->pt", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pti,pti->pt", a, b) * lc + np.einsum("pti,pti->pt", b, c) * la \
        + np.einsum("pti,pti->pt", c, a) * lb
    return (2 * np.arctan2(det, den)).sum(axis=1) / (4 * np.pi)


def open_teapot():
    """The SPD teapot as triangles (our OBJ export, read by trimesh): its lid leaves gaps."""
    import io

    import raykernel
    from raykernel.scene.convert import scene_to_obj
    obj, _ = scene_to_obj(raykernel.load("spd:teapot:2"))
    m = trimesh.load(io.StringIO(obj), file_type="obj", force="mesh", process=False)
    return np.ascontiguousarray(m.vertices, np.float64), np.ascontiguousarray(m.faces, np.int64)


def test_winding_numbers_against_the_brute_force_sum():
    from raykernel.casting.winding import winding_numbers
    rng = np.random.default_rng(5)
    for v, f in (sphere(3), open_teapot()):
        lo, hi = v.min(0), v.max(0)
        p = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (400, 3))
        rs = RayScene.from_mesh(v, f)
        mesh, far = winding_tree(rs)
        w = winding_numbers(mesh, p, far)
        exact = brute_winding(v, f, p)
        assert np.abs(w - exact).max() < 0.05, np.abs(w - exact).max()     # the dipoles: a few hundredths
        clear = np.abs(exact - 0.5) > 0.05
        np.testing.assert_array_equal(rs.contains(p, method="winding")[clear], (exact > 0.5)[clear])


def test_contains_picks_parity_for_closed_meshes_and_winding_for_open_ones():
    rng = np.random.default_rng(6)
    v, f = sphere(3)
    p = rng.uniform(-1.2, 1.2, (3000, 3))
    rs = RayScene.from_mesh(v, f)
    assert is_closed(rs)
    r = np.linalg.norm(p, axis=1)
    inside = rs.contains(p)
    clear = np.abs(r - 1) > 0.01
    np.testing.assert_array_equal(inside[clear], (r < 1)[clear])
    for method in ("parity", "winding", "vote"):
        np.testing.assert_array_equal(rs.contains(p, method=method)[clear], inside[clear])
    tv, tf = open_teapot()
    teapot = RayScene.from_mesh(tv, tf)
    assert not is_closed(teapot)
    q = rng.uniform(tv.min(0), tv.max(0), (500, 3))
    np.testing.assert_array_equal(teapot.contains(q), teapot.contains(q, method="winding"))
    with pytest.raises(ValueError, match="method must be"):
        rs.contains(p, method="odd")
    with pytest.raises(ValueError, match="triangle meshes only"):
        RayScene.from_spheres([[0, 0, 0.0]], 1.0).contains(p, method="winding")


def test_parity_on_a_box_with_points_on_its_vertex_grid():
    """Axis-aligned faces and query points on the lines and planes of the box's own vertices: the
    parity rays (no two components in a simple ratio) still count each crossing once."""
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    rs = RayScene.from_trimesh(box)
    assert is_closed(rs)
    g = np.linspace(-1.5, 1.5, 13)
    p = np.stack(np.meshgrid(g, g, g), axis=-1).reshape(-1, 3)
    inside = rs.contains(p, method="parity")
    strictly = (np.abs(p) < 1).all(axis=1)
    outside = (np.abs(p) > 1).any(axis=1)
    np.testing.assert_array_equal(inside[strictly], True)
    np.testing.assert_array_equal(inside[outside], False)
    np.testing.assert_array_equal(rs.contains(p, method="winding")[strictly | outside], inside[strictly | outside])
