"""The CSG kinds (aggregates/csg.py) against a brute-force interval reference.

Random closed solids (spheres, ellipsoids as instanced spheres, closed triangle meshes,
closed polygon boxes) combined by random difference / intersection / union trees: the
reference computes, in plain numpy, every crossing of the ray's line with every solid, the
inside intervals by parity and the operator's result along the line; the kernel's closest
hit, all hits and the normals' sides must agree with it. Kinds and nesting against `list`
bit for bit are in test_nesting.py.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from support import MeshBox, Node, Placed, Sphere, box_mesh, random_tree, rays_at_solids

import raykernel
from raykernel.casting.rayscene import RayScene
from raykernel.engine.flatten import flatten
from raykernel.errors import OptionError, SceneError
from raykernel.aggregates import csg
from raykernel.aggregates.registry import COUNTER_NAMES
from raykernel.scene import Group, Material, Scene
from raykernel.scene.jsonscene import scene_from_json, scene_to_json

# ---------------------------------------------------------------- scenes of the solids (support.py: Node,
# random_tree and the solids, each with its own crossing test)

def scene_of(node, operand_spec=None, root="list"):
    """A scene whose root (structure `root`) holds the node's group, operands built with operand_spec."""
    s = Scene()
    s.root.accel = root
    s.root.add(node.group(operand_spec))
    return s


# ---------------------------------------------------------------- against the reference

@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("scale", [1.0, 1e-4, 1e5])
def test_random_csg_trees_match_the_interval_reference(seed, scale):
    rng = np.random.default_rng(seed)
    o, d = rays_at_solids(rng, 150, scale)
    for _ in range(50):
        # a tree worth testing: not empty (an intersection of disjoint solids is)
        node = random_tree(rng, scale=scale)
        wanted = [[(t, e) for t, e in node.transitions(o[r], d[r]) if t >= 0.0] for r in range(len(o))]
        if sum(map(bool, wanted)) > 25:
            break
    rs = RayScene.from_scene(scene_of(node), "bvh")
    hits = rs.intersect(o, d)
    ray, t_all, _ = rs.intersect_all(o, d)
    hit_rays = 0
    for r, want in enumerate(wanted):
        got = np.sort(t_all[ray == r])
        assert len(got) == len(want), f"ray {r}: {len(got)} surfaces against {len(want)} ({want})"
        np.testing.assert_allclose(got, [t for t, _ in want], rtol=1e-9, atol=1e-12)
        if not want:
            assert not np.isfinite(hits.t[r])
            continue
        hit_rays += 1
        assert hits.t[r] == got[0]
        # the normal faces out of the result: against the ray where it enters, along it where it leaves
        facing = hits.normal[r] @ d[r]
        assert (facing < 0) == want[0][1], f"ray {r}: normal {hits.normal[r]} on the wrong side"
    assert hit_rays > 20


def test_difference_of_two_spheres_by_hand():
    node = Node("difference", [Sphere((0, 0, 0), 1.0), Sphere((1, 0, 0), 0.5)])
    rs = RayScene.from_scene(scene_of(node), "bvh")
    o = np.array([[5.0, 0, 0], [5, 0.3, 0], [-5, 0, 0], [0, 0, 0], [0, 5, 0]])
    d = np.array([[-1.0, 0, 0], [-1, 0, 0], [1, 0, 0], [1, 0, 0], [0, -1, 0]])
    h = rs.intersect(o, d)
    np.testing.assert_allclose(h.t, [4.5, 4 + np.sqrt(0.25 - 0.09), 4.0, 0.5, 4.0])
    # the cut surface (the subtracted sphere's) faces +x, out of the result
    np.testing.assert_allclose(h.normal[0], [1, 0, 0])
    np.testing.assert_allclose(h.normal[3], [1, 0, 0])
    np.testing.assert_allclose(h.normal[2], [-1, 0, 0])
    assert rs.last_stats["csg.resolves"] == 5 and rs.last_stats["csg.surfaces"] > 0


def test_any_hit_and_tmax_respect_the_result():
    node = Node("difference", [Sphere((0, 0, 0), 1.0), Sphere((0, 0, 0), 0.5)])     # a hollow ball
    rs = RayScene.from_scene(scene_of(node), "grid")
    o, d = np.array([[0.0, 0, 0], [0, 0, 0], [3, 0, 0]]), np.array([[1.0, 0, 0], [1, 0, 0], [-1, 0, 0]])
    # from the hollow centre the first surface is the inner wall at 0.5
    np.testing.assert_allclose(rs.intersect(o[:1], d[:1]).t, [0.5])
    assert not rs.occluded(o[1:2], d[1:2], tmax=0.4)[0]
    assert rs.occluded(o[1:2], d[1:2], tmax=0.6)[0]
    assert rs.count_hits(o[2:], d[2:]).tolist() == [4]
    # tmin inside the wall: the ray starts in the solid and leaves it at 2.5
    np.testing.assert_allclose(rs.intersect(o[2:], d[2:], tmin=2.2).t, [2.5])


def test_grazing_a_sphere_operand_leaves_the_inside_unchanged():
    """A line tangent to a subtracted sphere crosses it twice at one t: the base stays whole."""
    node = Node("difference", [MeshBox((-1, -1, -1), (1, 1, 1)), Sphere((0, 0, 1.0), 0.5)])
    rs = RayScene.from_scene(scene_of(node), "bvh")
    o, d = np.array([[-3.0, 0, 0.5], [-3, 0, 0.6]]), np.array([[1.0, 0, 0], [1, 0, 0]])
    assert rs.count_hits(o, d).tolist() == [2, 4]
    ray, t, _ = rs.intersect_all(o, d)
    np.testing.assert_allclose(t[ray == 0], [2.0, 4.0])


def test_counters_count_the_extra_work():
    node = Node("union", [Sphere((0, 0, 0), 1.0), Sphere((0.5, 0, 0), 1.0)])
    rs = RayScene.from_scene(scene_of(node), "list")
    rs.intersect(np.array([[-5.0, 0, 0]]), np.array([[1.0, 0, 0]]))
    s = rs.last_stats
    assert s["csg.crossings"] == 4 and s["csg.resolves"] == 1 and s["csg.surfaces"] == 2
    assert s["tests.sphere"] == 2


# ---------------------------------------------------------------- the JSON items and their errors

def _die(pips):
    return {"difference": {
        "base": [{"mesh": {"vertices": box_mesh((-1, -1, -1), (1, 1, 1))[0].tolist(),
                           "faces": MeshBox((-1, -1, -1), (1, 1, 1)).f.tolist()}}],
        "subtract": [{"sphere": {"center": c, "radius": 0.2}} for c in pips]}}


def test_json_items_round_trip_and_render():
    data = {"camera": {"eye": [3, -4, 3], "look_at": [0, 0, 0], "resolution": 24},
            "lights": [{"position": [5, -5, 8]}],
            "scene": {"accel": "grid", "items": [
                _die([[0, 0, 1], [1, 0, 0]]),
                {"intersection": {"items": [{"sphere": {"center": [0, 0.5, 0], "radius": 1}},
                                            {"group": {"accel": "octree", "items": [
                                                {"sphere": {"center": [0, -0.5, 0], "radius": 1}}]}}]},
                 "transform": {"translate": [3, 0, 0]}},
                {"union": {"items": [{"sphere": {"center": [0, 0, 3], "radius": 0.5}}]}}]}}
    scene = scene_from_json(data)
    again = scene_from_json(json.loads(json.dumps(scene_to_json(scene))))
    a = raykernel.render(scene, resolution=24)
    b = raykernel.render(again, resolution=24)
    assert a.image.tobytes() == b.image.tobytes()
    assert a.stats["csg.resolves"] > 0
    specs = [s["kind"] for s in flatten(scene)[1]["aggregates"]]
    assert "difference" in specs and "intersection" in specs and "union" in specs and "octree" in specs


@pytest.mark.parametrize("item, words", [
    ({"difference": {"base": []}}, "missing.*subtract"),
    ({"union": {"items": [{"cone": {"base": [0, 0, 0], "base_radius": 1, "apex": [0, 0, 1],
                                    "apex_radius": 1}}]}}, "items/0: a cone is an open surface"),
    ({"union": {"items": "spheres"}}, "items: expected a list"),
    ({"intersection": {"items": [], "accel": "bvh"}}, "accel"),
    ({"union": {"items": [{"sphere": {"center": [0, 0, 0], "radius": 1}}] * 64}}, "at most 63 operands"),
    ({"union": {"items": []}, "material": "x"}, "give the union object a \"material\""),
])
def test_bad_csg_items_say_where_and_what(item, words):
    with pytest.raises(SceneError, match=words):
        scene_from_json({"scene": {"items": [item]}}, path="s.json")


def test_operators_are_not_structures_for_every_group():
    with pytest.raises(OptionError, match="boolean operator"):
        flatten(Scene(), "union")
    s = Scene()
    s.root.accel = "union"
    s.root.spheres.add((0, 0, 0), 1.0, 0)
    with pytest.raises(SceneError, match="operands are its child groups"):
        flatten(s)
    g = Group(accel="difference(base=3)")
    g.add(Group(name="a"))
    s = Scene()
    s.root.add(g)
    with pytest.raises(SceneError, match="base=3 but it has only 1"):
        flatten(s)


def test_empty_operands_and_empty_results():
    empty = Node("intersection", [Sphere((0, 0, 0), 1.0), Sphere((5, 0, 0), 1.0)])   # disjoint: nothing
    rs = RayScene.from_scene(scene_of(empty), "bvh")
    assert not np.isfinite(rs.intersect(np.array([[-3.0, 0, 0]]), np.array([[1.0, 0, 0]])).t[0])
    g = Group(accel="difference(base=1)")
    ball = Group(name="ball")
    ball.spheres.add((0, 0, 0), 1.0, 0)
    g.add(ball)
    g.add(Group(name="nothing"))            # subtracting nothing leaves the ball
    s = Scene()
    s.root.add(g)
    h = RayScene.from_scene(s).intersect(np.array([[-3.0, 0, 0]]), np.array([[1.0, 0, 0]]))
    assert h.t[0] == pytest.approx(2.0)


# ---------------------------------------------------------------- rendering: glass, shadows, the example

def test_glass_lens_refracts_like_the_same_glass_sphere_where_they_coincide():
    """A CSG intersection with one huge operand is the other operand: same image, same rays."""
    glass = Material(color=(1, 1, 1), kd=0.1, ks=0.2, shine=50, t=0.8, ior=1.5)

    def scene(csg: bool):
        s = Scene()
        m = s.add_material(glass)
        floor = s.add_material(Material(color=(0.8, 0.6, 0.4)))
        s.root.polygons.add(np.array([[-9, -9, -1.0], [9, -9, -1], [9, 9, -1], [-9, 9, -1]]), floor)
        ball = Group(name="ball")
        ball.spheres.add((0, 0, 0), 1.0, m)
        if csg:
            huge = Group(name="huge")
            huge.spheres.add((0, 0, 0), 50.0, m)
            node = Group(accel="intersection")
            node.add(ball)
            node.add(huge)
            s.root.add(node)
        else:
            s.root.add(ball)
        s.camera.eye, s.camera.look_at = np.array([0.0, -5, 1]), np.array([0.0, 0, 0])
        s.lights.append(raykernel.scene.Light(position=np.array([3.0, -4, 6])))
        return s

    a = raykernel.render(scene(False), resolution=32)
    b = raykernel.render(scene(True), resolution=32)
    assert a.stats["rays.refract"] > 100
    for k in ("rays.eye", "rays.reflect", "rays.refract", "rays.shadow", "rays.shadow_blocked"):
        assert a.stats[k] == b.stats[k], k
    np.testing.assert_allclose(a.image, b.image, atol=1e-9)


def test_csg_casts_shadows_through_its_cut():
    """Light through a hole drilled in a slab reaches the floor below; elsewhere the slab blocks it."""
    s = Scene()
    white = s.add_material(Material())
    s.root.polygons.add(np.array([[-9, -9, 0.0], [9, -9, 0], [9, 9, 0], [-9, 9, 0]]), white)
    slab = MeshBox((-3, -3, 2), (3, 3, 2.5))
    drill = Placed(Sphere((0, 0, 0), 1.0), np.diag([1.0, 1.0, 10.0, 1.0]) @ np.eye(4))   # a tall ellipsoid
    s.root.add(Node("difference", [slab, drill]).group())
    s.lights.append(raykernel.scene.Light(position=np.array([0.0, 0, 10])))
    rs_geo = flatten(s)[0]
    from raykernel.engine.traverse import cast_rays
    o = np.array([[0.0, 0, 0.001], [2.0, 0, 0.001]])
    d = np.array([[0.0, 0, 10], [-2.0, 0, 10]]) - o
    t = cast_rays(rs_geo, o, d, 0.0, 1.0, any_hit=True)[0]
    assert not np.isfinite(t[0]) and np.isfinite(t[1])


def test_the_example_scene_renders():
    r = raykernel.render(raykernel.load("example:csg"), resolution=48)
    assert r.stats["csg.resolves"] > 0 and r.stats["rays.refract"] > 0
    img = r.to_uint8()
    assert img.std() > 10
    n = raykernel.render(raykernel.load("example:csg"), resolution=48, threads=1)
    assert n.image.tobytes() == r.image.tobytes() and COUNTER_NAMES[csg.SURFACES] == "csg.surfaces" and "csg.surfaces" in n.stats
