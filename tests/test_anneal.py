"""The annealed hierarchies (analysis/anneal.py), the cost model that prices them, the BVH
optimisers (aggregates/bvhopt.py) and Arvo's park (scene/park.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import raykernel
from raykernel.aggregates import bvhbuild, bvhopt, bvhtree
from raykernel.analysis import anneal, costmodel
from raykernel.cli import main
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.errors import OptionError
from raykernel.scene.jsonscene import read_json
from raykernel.scene.model import Group, Instance, Scene, TriangleMesh
from raykernel.scene.specs import without_specs

SMALL = dict(resolution=16, spd=True, threads=1)


def _park():
    return raykernel.load("scene:park:rides=1,horses=2,trees=3,mountain_level=2")


def _stadium():
    return raykernel.load("scene:stadium:stadium_prims=600,teapot_prims=200,ratio=1e4")


def _fingerprint(scene: Scene) -> dict:
    """Every primitive of the scene as sorted rows, instances by their group and matrix: equal for
    two scenes exactly when they hold the same primitives, none lost and none twice."""
    rows = {"sphere": [], "cone": [], "polygon": [], "patch": [], "triangle": [], "instance": []}

    def visit(g: Group):
        s = g.spheres.freeze()
        rows["sphere"] += [tuple(c) + (r, m) for c, r, m in zip(s.center, s.radius, s.material)]
        c = g.cones.freeze()
        rows["cone"] += [tuple(b) + tuple(a) + (rb, ra, m) for b, a, rb, ra, m in
                         zip(c.base, c.apex, c.base_radius, c.apex_radius, c.material)]
        for p in (g.polygons.freeze(), g.patches.freeze()):
            for i in range(len(p)):
                v, n = p.polygon(i)
                rows[p.kind].append(tuple(v.ravel()) + (() if n is None else tuple(n.ravel())) + (p.material[i],))
        for mesh in g.meshes:
            for f, m in zip(mesh.faces, mesh.material):
                rows["triangle"].append(tuple(mesh.vertices[f].ravel()) + (m,))
        for child in g.children:
            if isinstance(child, Instance):
                rows["instance"].append((id(child.group),) + tuple(child.matrix.ravel()))
            else:
                visit(child)

    visit(scene.root)
    return {k: sorted(v) for k, v in rows.items()}


# ---- the walks' counters the model prices ----------------------------------------------------------

@pytest.mark.parametrize("accel", ["list", "bvh", "grid", "octree", "hgrid", "hybrid", "rc", "lazyoctree"])
def test_walk_counters_add_up(accel):
    stats = raykernel.render(_stadium(), accel=accel, **SMALL).stats
    walks = [k for k in stats if k.startswith("walk.")]
    assert sum(stats[k] for k in walks if k.endswith(".steps")) == stats["cells.visited"]
    assert sum(stats[k] for k in walks if k.endswith(".bounds")) == stats["bounds.tests"]
    assert costmodel.walks_used(stats)


def test_reference_costs_load_and_price_every_eager_kind():
    model = costmodel.CostModel.load(costmodel.REFERENCE_PATH)
    for accel in anneal.START_SPECS:
        stats = raykernel.render(_stadium(), accel=accel, **SMALL).stats
        assert model.predict(stats) > 0, accel


def test_old_calibration_files_are_refused(tmp_path):
    path = tmp_path / "old.json"
    path.write_text(json.dumps({"costs": {"render": 1e-3}, "threads": 2}))
    with pytest.raises(OptionError, match="calibrate"):
        costmodel.CostModel.load(path)


def test_model_ranking_agrees_with_measured_times():
    """Where the model predicts one structure at least 3x slower than another on a scene, the
    measured trace times (the shortest of three) order them the same way."""
    model = costmodel.CostModel.load(costmodel.REFERENCE_PATH)
    checked = 0
    for scene in (raykernel.load("scene:stadium:stadium_prims=2000,teapot_prims=1000,ratio=1e5"),
                  raykernel.load("spd:balls:2")):
        got = {}
        for accel in ("list", "bvh", "grid", "octree"):
            runs = [raykernel.render(scene, accel=accel, resolution=48, spd=True).stats for _ in range(3)]
            got[accel] = (model.predict(runs[0]), min(r["time.trace"] for r in runs))
        for a in got:
            for b in got:
                if got[a][0] > 3 * got[b][0]:
                    assert got[a][1] > got[b][1], (scene.source, a, b, got)
                    checked += 1
    assert checked >= 3


# ---- atoms, states and moves -----------------------------------------------------------------------

def test_atoms_hold_every_primitive_once_and_respect_groups():
    scene = _park()
    atoms, tree = anneal.atoms_of(scene)
    assert atoms.counts.sum() == scene.count_primitives()
    own = anneal._own_state(tree, scene.root.accel, "bvh")
    assert sorted(own.all_atoms()) == list(range(len(atoms.groups)))
    # the scene's own hierarchy, rebuilt from atoms, is the scene (the same primitives, the same specs)
    rebuilt = anneal._with_group(scene, scene.root, anneal._merged_group(own, atoms, "park"))
    assert _fingerprint(rebuilt) == _fingerprint(scene)
    specs = sorted(n.spec for n, _, _ in own.nodes())
    assert specs.count("grid(density=0.25)") == 1 and sum(s.startswith("grid(res=woo") for s in specs) == 1


@pytest.mark.parametrize("make", [_park, _stadium, lambda: raykernel.load("spd:balls:1")])
def test_every_move_keeps_the_primitives_and_the_hits(make):
    scene = make()
    atoms, _ = anneal.atoms_of(scene)
    everything = list(range(len(atoms.groups)))
    rng = np.random.default_rng(3)
    state = anneal.Node("bvh", list(everything))
    seen = set()
    for _ in range(60):
        move, new = anneal.propose(state, atoms, rng)
        if new is None:
            continue
        seen.add(move)
        assert sorted(new.all_atoms()) == everything, move
        assert new.levels() <= anneal.MAX_LEVELS
        state = new
    assert seen == set(anneal.MOVES)
    tuned = anneal._with_group(scene, scene.root, anneal._merged_group(state, atoms, "root"))
    assert _fingerprint(tuned) == _fingerprint(scene)
    ref = raykernel.render(scene, accel="list", resolution=24, spd=True)
    got = raykernel.render(tuned, accel="list", resolution=24, spd=True)
    assert got.stats["rays.total"] == ref.stats["rays.total"]
    np.testing.assert_allclose(got.image, ref.image, atol=1e-12)
    nested = raykernel.render(tuned, resolution=24, spd=True)       # the state's own specs
    assert nested.stats["rays.total"] == ref.stats["rays.total"]
    np.testing.assert_allclose(nested.image, ref.image, atol=1e-12)


def test_annealing_is_deterministic_for_a_seed_and_never_worse_than_its_start():
    scene = _stadium()
    runs = [anneal.anneal(scene, seed=7, evaluations=40, margin=0.0, options=SMALL) for _ in range(2)]
    assert runs[0].state.key() == runs[1].state.key()
    assert runs[0].energy == runs[1].energy and runs[0].history == runs[1].history
    assert runs[0].evaluations == 40 and runs[0].stopped == "evaluations"
    assert runs[0].energy <= min(runs[0].starts.values())
    other = anneal.anneal(scene, seed=8, evaluations=40, options=SMALL)
    assert other.history != runs[0].history


def test_two_threads_anneal_at_once_and_agree():
    from concurrent.futures import ThreadPoolExecutor
    scene = _stadium()
    with ThreadPoolExecutor(2) as pool:
        runs = list(pool.map(lambda seed: anneal.anneal(scene, seed=seed, evaluations=20, options=SMALL), [5, 5]))
    alone = anneal.anneal(scene, seed=5, evaluations=20, options=SMALL)
    assert runs[0].state.key() == runs[1].state.key() == alone.state.key()
    assert runs[0].energy == runs[1].energy == alone.energy


def test_the_result_is_the_scene_regrouped():
    scene = _park()
    found = anneal.anneal(scene, seed=1, evaluations=30, options=SMALL)
    assert _fingerprint(found.scene) == _fingerprint(scene)
    assert found.scene.root is not scene.root and scene.root.accel == "grid(density=0.25)"   # the user's scene kept
    assert "primitives" in found.before and "primitives" in found.after
    summary = found.summary()
    assert summary["evaluations"] == 30 and summary["best_single"] in anneal.START_SPECS


def test_a_single_kind_found_keeps_the_scene_s_own_layout():
    # the order of a primitive set is its memory layout: a result that is one kind over the whole
    # scene renders with the scene's own sets, counter for counter as that kind does
    scene = raykernel.load("spd:balls:2")
    found = anneal.anneal(scene, seed=0, evaluations=len(anneal.START_SPECS + anneal.START_VARIANTS),
                          options=SMALL)
    assert not found.state.children
    single = without_specs(scene)
    ref = raykernel.render(single, accel=found.state.spec, **SMALL)
    got = raykernel.render(found.scene, **SMALL)
    assert {k: v for k, v in got.stats.items() if not k.startswith(("time.", "build.seconds"))} == \
        {k: v for k, v in ref.stats.items() if not k.startswith(("time.", "build.seconds"))}
    for ours, theirs in zip(found.scene.root.primitive_sets(), single.root.primitive_sets()):
        assert type(ours) is type(theirs) and len(ours) == len(theirs)
        if len(theirs):
            np.testing.assert_array_equal(ours.material, theirs.material)
    # split into groups, each group's primitives keep the scene's order among themselves
    atoms, _ = anneal.atoms_of(scene)
    ids = list(range(len(atoms.groups)))[::-1]          # atoms in reverse, in two groups
    state = anneal.Node("bvh", ids[::2], [anneal.Node("grid", ids[1::2])])
    split = anneal._with_group(scene, scene.root, anneal._merged_group(state, atoms, "root"))
    assert len(split.root.children) == 1 and len(split.root.spheres) and len(split.root.children[0].spheres)
    centres = {tuple(c): k for k, c in enumerate(scene.root.spheres.center)}

    def check(g):
        order = [centres[tuple(c)] for c in g.spheres.center]
        assert order == sorted(order)
        for c in g.children:
            check(c)

    check(split.root)
    assert _fingerprint(split) == _fingerprint(scene)


def test_a_hierarchy_predicted_only_a_little_faster_gives_way_to_the_best_kind():
    scene = raykernel.load("scene:diamond:facets=100")
    free = anneal.anneal(scene, seed=7, evaluations=12, margin=0.0, options=SMALL)
    assert free.kept is None and free.energy == free.searched <= min(free.starts.values())
    best_kind = min(anneal.START_SPECS, key=free.starts.get)
    assert free.energy < free.starts[best_kind]            # the search found something better ...
    held = anneal.anneal(scene, seed=7, evaluations=12, margin=0.9, options=SMALL)
    assert held.searched == free.searched                  # ... the same search ...
    assert held.kept == best_kind and held.energy == free.starts[best_kind]     # ... not 90% better: the kind kept
    assert held.state.spec == best_kind and not held.state.children
    assert held.summary()["kept"] == best_kind
    got = raykernel.render(held.scene, **SMALL).stats
    ref = raykernel.render(without_specs(scene), accel=best_kind, **SMALL).stats
    assert got["tests.total"] == ref["tests.total"] and got["bounds.tests"] == ref["bounds.tests"]


def test_bad_options_are_clear_errors():
    scene = _stadium()
    with pytest.raises(OptionError, match="seconds"):
        anneal.anneal(scene, seconds=-1)
    with pytest.raises(OptionError, match="cooling"):
        anneal.anneal(scene, cooling=2.0)
    with pytest.raises(OptionError, match="margin"):
        anneal.anneal(scene, margin=1.5)
    with pytest.raises(OptionError, match="margin must be"):
        raykernel.render(scene, accel="auto(margin=-0.1)", resolution=4)
    with pytest.raises(OptionError, match="seconds must be"):
        raykernel.render(scene, accel="auto(seconds=-1)", resolution=4)
    with pytest.raises(OptionError, match="no parameter 'speed'"):
        raykernel.render(scene, accel="auto(speed=1)", resolution=4)
    with pytest.raises(OptionError, match="render"):
        flatten(scene, "auto")
    with pytest.raises(OptionError, match="atoms"):
        anneal.anneal(scene, start=anneal.Node("bvh", [0]), evaluations=2, options=SMALL)


def test_a_candidate_that_cannot_be_built_is_never_accepted():
    scene = raykernel.load("spd:tetra:5")
    atoms, _ = anneal.atoms_of(scene)
    energy = anneal.Energy(scene, scene.root, atoms, dict(SMALL), "bvh", costmodel.current())
    everything = list(range(len(atoms.groups)))
    assert energy(anneal.Node("grid(res=woo, density=1000, max_res=4096)", everything)) == np.inf
    assert 0 < energy(anneal.Node("bvh", everything)) < np.inf


def test_empty_and_tiny_scenes():
    empty = Scene()
    found = anneal.anneal(empty, evaluations=5, options=SMALL)
    assert found.stopped == "empty"
    assert raykernel.render(empty, accel="auto(evaluations=5)", resolution=4).stats["rays.eye"] == 16
    one = Scene()
    one.root.spheres.add((0, 0, 0), 1.0)
    r = raykernel.render(one, accel="auto(evaluations=10)", resolution=8)
    assert r.stats["rays.eye_hit"] > 0 and r.stats["time.anneal"] > 0


# ---- auto in a render, anneal on the command line ---------------------------------------------------

def test_auto_round_trips_through_anneal_json(tmp_path, capsys):
    out = tmp_path / "tuned.json"
    assert main(["anneal", "scene:stadium:stadium_prims=600,teapot_prims=200,ratio=1e4", "--evaluations", "25",
                 "--resolution", "16", "--spd", "--threads", "1", "-o", str(out), "--plot",
                 str(tmp_path / "run.png")]) == 0
    text = capsys.readouterr().out
    assert "hierarchy found" in text and "annealing:" in text and (tmp_path / "run.png").stat().st_size > 0
    tuned = read_json(out)
    scene = _stadium()
    auto = raykernel.render(scene, accel="auto(evaluations=25)", **SMALL)
    again = raykernel.render(tuned, **SMALL)
    assert auto.stats.info["anneal"][0]["evaluations"] == 25
    for key in ("rays.total", "tests.total", "bounds.tests", "cells.visited"):
        assert again.stats[key] == auto.stats[key], key
    np.testing.assert_array_equal(again.image, auto.image)
    assert main(["anneal", "spd:balls:1", "-o", str(tmp_path / "x.png")]) == 2


def test_a_group_can_ask_for_auto(tmp_path):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({
        "camera": {"eye": [0, -8, 2], "look_at": [0, 0, 0]},
        "lights": [{"position": [3, -5, 6]}],
        "scene": {"accel": "grid", "items": [
            {"group": {"accel": "auto(evaluations=12)", "items": [
                {"sphere": {"center": [x, 0, z], "radius": 0.3}} for x in range(-3, 4) for z in range(-2, 3)]}},
            {"polygon": [[-9, -9, -3], [9, -9, -3], [9, 9, -3], [-9, 9, -3]]}]}}))
    scene = read_json(path)
    got = raykernel.render(scene, resolution=20)
    ref = raykernel.render(scene, accel="list", resolution=20)
    # the auto group is the only one annealed; the root keeps its grid
    assert got.stats.info["anneal"][0]["group"] != "(root)"
    assert got.stats["rays.total"] == ref.stats["rays.total"]
    np.testing.assert_allclose(got.image, ref.image, atol=1e-12)


def test_reannealing_the_next_frame_from_the_last():
    frames = [raykernel.load(f"scene:satellite:prims=300,time={t}") for t in (0, 30)]
    first = anneal.anneal(frames[0], seed=2, evaluations=40, options=SMALL)
    start, atoms = anneal.rebind(first.state, first.atoms, frames[1])
    nxt = anneal.anneal(frames[1], seed=2, evaluations=15, start=start, atoms=atoms, short=True, options=SMALL)
    assert list(nxt.starts) == ["previous"]
    assert _fingerprint(nxt.scene) == _fingerprint(frames[1])
    assert nxt.energy <= nxt.start_energy
    with pytest.raises(OptionError, match="structure"):
        anneal.rebind(first.state, first.atoms, raykernel.load("scene:satellite:prims=600"))


# ---- the BVH optimisers ------------------------------------------------------------------------------

def _soup(n, seed):
    rng = np.random.default_rng(seed)
    c = rng.random((n, 3))
    c[: n // 2] *= 0.02                       # a dense cluster in an empty box: room to improve
    v = (c[:, None, :] + 0.03 * rng.standard_normal((n, 3, 3))).reshape(-1, 3)
    return TriangleMesh(v, np.arange(3 * n).reshape(-1, 3))


@pytest.mark.parametrize("method", ["rotations", "reinsertion"])
@pytest.mark.parametrize("build", ["sah", "gs"])
def test_optimised_bvhs_keep_the_leaves_and_lower_the_cost(method, build):
    mesh = _soup(3000, 4)
    tri = mesh.vertices[mesh.faces]
    bounds = np.hstack([tri.min(axis=1), tri.max(axis=1)])
    if build == "sah":
        tree, _ = bvhbuild.build_bvh(bounds)
    else:
        from raykernel.aggregates.gsbvh import build_gs
        tree, _ = build_gs(bounds, order="file", seed=1)
    out, info = bvhopt.optimize(tree, method)
    assert info["sah_after"] <= info["sah_before"] + 1e-9
    assert info["sah_after"] == pytest.approx(bvhopt.sah(out))
    leaves_in = {(int(f), int(c)) for f, c in zip(tree.first[bvhtree.is_leaf(tree)], tree.count[bvhtree.is_leaf(tree)])}
    leaves_out = {(int(f), int(c)) for f, c in zip(out.first[bvhtree.is_leaf(out)], out.count[bvhtree.is_leaf(out)])}
    assert leaves_in == leaves_out and len(out.count) == len(tree.count)
    inner = np.nonzero(~bvhtree.is_leaf(out))[0]
    assert np.all(out.first[inner] > inner)                 # children after their parents
    for i in inner:                                         # tight boxes
        kids = out.bounds[out.first[i]:out.first[i] + 2]
        np.testing.assert_array_equal(out.bounds[i, :3], kids[:, :3].min(axis=0))
        np.testing.assert_array_equal(out.bounds[i, 3:], kids[:, 3:].max(axis=0))


@pytest.mark.parametrize("spec", ["bvh(optimize=rotations)", "bvh(optimize=reinsertion)",
                                  "bvh(build=gs, optimize=reinsertion)", "bvh(leaf=1, optimize=rotations)"])
def test_optimised_bvh_hits_equal_the_list(spec):
    scene = Scene()
    scene.root.add(_soup(1500, 9))
    scene.root.spheres.add((0.5, 0.5, 0.5), 0.01)
    rng = np.random.default_rng(1)
    o = rng.random((3000, 3)) * 1.4 - 0.2
    d = rng.standard_normal((3000, 3))
    d[:200] = [1, 0, 0]                                    # axis-parallel rays
    ref = cast_rays(flatten(scene, "list")[0], o, d)
    got = cast_rays(flatten(scene, spec)[0], o, d)
    for a, b in zip(ref[:4], got[:4]):
        np.testing.assert_array_equal(a, b)
    for scale in (1e-6, 1e7):
        s = Scene()
        m = _soup(300, 2)
        s.root.add(TriangleMesh(m.vertices * scale, m.faces))
        r0 = cast_rays(flatten(s, "list")[0], o[:500] * scale, d[:500])
        r1 = cast_rays(flatten(s, spec)[0], o[:500] * scale, d[:500])
        for a, b in zip(r0[:4], r1[:4]):
            np.testing.assert_array_equal(a, b)


def test_optimize_is_a_checked_parameter():
    with pytest.raises(OptionError, match="optimize must be one of"):
        raykernel.render(raykernel.load("spd:balls:1"), accel="bvh(optimize=magic)", resolution=4)
    with pytest.raises(ValueError, match="unknown BVH optimisation"):
        bvhopt.optimize(bvhbuild.build_bvh(np.zeros((4, 6)))[0], "magic")


# ---- the park -------------------------------------------------------------------------------------------

def test_the_park_has_arvos_levels_and_hierarchy():
    scene = raykernel.load("scene:park")
    mountain = next(c for c in scene.root.children if isinstance(c, Group) and c.name == "mountain")
    besides = scene.count_primitives() - mountain.count_primitives()
    assert 8000 <= besides <= 12000
    assert mountain.count_primitives() == 2 * 4 ** 6
    rides = [c for c in scene.root.children if isinstance(c, Group) and c.name.startswith("ride")]
    assert len(rides) == 6 and all(r.accel.startswith("grid(res=woo") for r in rides)
    horses = {id(c.group) for r in rides for c in r.children if isinstance(c, Instance)}
    assert len(horses) == 1                                 # one horse and rider, instanced on every pole
    assert scene.root.accel.startswith("grid")
    assert raykernel.load("scene:park:top=1").root.accel == "rc"
    with pytest.raises(OptionError, match="rides"):
        raykernel.load("scene:park:rides=0")


def test_the_park_renders_the_same_with_any_structure():
    scene = _park()
    ref = raykernel.render(scene, accel="list", resolution=24)
    for accel in (None, "bvh"):
        got = raykernel.render(scene, resolution=24) if accel is None else \
            raykernel.render(scene, accel=accel, resolution=24)
        assert got.stats["rays.total"] == ref.stats["rays.total"]
        np.testing.assert_allclose(got.image, ref.image, atol=1e-12)
    assert ref.stats["rays.reflect"] > 0                    # the chrome and the mirror reflect the park
