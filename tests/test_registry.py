"""The registry (aggregates/registry.py): kinds and walks declared once, the columns and fields
derived from them, stack-entry tags, and the accelerator spec parser."""

import dataclasses
import random

import numpy as np
import pytest

import raykernel
from raykernel.aggregates import registry as accel
from raykernel.aggregates.spec import Kind, Param
from raykernel.aggregates.walk import STEP_BITS, Walk, entry_kind, entry_step, entry_tag
from raykernel.engine.flatten import flatten
from raykernel.errors import OptionError
from raykernel.geometry import counters as C


def test_walk_codes_must_be_dense_and_unique():
    bvh = accel.KINDS["bvh"]
    clash = dataclasses.replace(bvh, name="other", walk=Walk(code=bvh.walk.code, name="other"))
    with pytest.raises(ImportError, match="codes"):
        accel.walks_of({**accel.KINDS, "other": clash})
    gap = dataclasses.replace(bvh, name="other", walk=Walk(code=len(accel.WALKS) + 1, name="other"))
    with pytest.raises(ImportError, match="codes"):
        accel.walks_of({**accel.KINDS, "other": gap})
    assert [w.code for w in accel.walks_of(accel.KINDS)] == list(range(len(accel.WALKS)))


def test_a_kind_name_declared_twice_is_refused():
    class Twice:
        KINDS = (accel.KINDS["bvh"], accel.KINDS["bvh"])
    with pytest.raises(ImportError, match="twice"):
        accel.kinds_of([Twice])


@pytest.mark.parametrize("kind", range(len(accel.WALKS)))
def test_entry_tags_decode_to_kind_and_step(kind):
    seen = set()
    for step in range(1 << STEP_BITS):
        tag = entry_tag(kind, step)
        assert tag < 0                      # never a reference range (stack_b >= 0)
        assert (entry_kind(tag), entry_step(tag)) == (kind, step)
        seen.add(tag)
    assert len(seen) == 1 << STEP_BITS


def test_counter_columns_do_not_depend_on_the_order_walks_are_named_in():
    walks = [(w.code, w.name, [n for n, _ in w.counters]) for w in accel.WALKS]
    shuffled = walks[:]
    random.Random(1).shuffle(shuffled)
    assert C.names(shuffled) == C.names(walks) == accel.COUNTER_NAMES
    names = list(accel.COUNTER_NAMES.values())
    assert len(names) == len(set(names)) and max(accel.COUNTER_NAMES) < C.N_COUNTERS
    with pytest.raises(ImportError, match="named twice"):
        C.names(walks + [(len(walks), "toy", ["rays.eye"])])
    with pytest.raises(ImportError, match="at most"):
        C.own_columns(0, C.OWN_PER_WALK + 1)


@pytest.mark.parametrize("name", [n for n, k in accel.KINDS.items() if not k.operands])
def test_every_kind_fills_only_its_walks_fields_and_counts_as_its_walk(name):
    scene = raykernel.load("spd:balls:1")
    geo, _ = flatten(scene, name)
    walks = {w.code: w for w in accel.WALKS}
    used = [walks[int(k)] for k in set(geo.agg_kind.tolist())]
    assert accel.KINDS[name].walk in used
    filled = {f.name for w in accel.WALKS for f in w.fields if len(getattr(geo, f.name))}
    assert filled <= {f.name for w in used for f in w.fields}          # no other walk's arrays
    assert filled & {f.name for f in accel.KINDS[name].walk.fields} or not accel.KINDS[name].walk.fields
    stats = raykernel.render(scene, accel=name, resolution=8, spd=True).stats
    assert stats[f"walk.{accel.KINDS[name].walk.name}.entries"] > 0


def test_spec_key_given_twice_is_an_error():
    with pytest.raises(OptionError, match="leaf.*twice"):
        accel.parse_spec("bvh(leaf=1,leaf=2)")


@pytest.mark.parametrize("spec", ["", "  ", "(leaf=2)", "bvh(", "nosuchkind"])
def test_bad_spec_error_lists_every_kind(spec):
    with pytest.raises(OptionError) as err:
        accel.parse_spec(spec)
    for name in accel.KINDS:
        assert name in str(err.value)


def test_format_spec_round_trips():
    for name in accel.KINDS:
        kind, params = accel.parse_spec(name)
        assert accel.parse_spec(accel.format_spec(kind, params)) == (kind, params)
    assert np.all([accel.format_spec(*accel.parse_spec(n)) == n for n in accel.KINDS])
    assert accel.format_spec(*accel.parse_spec("bvh(leaf=2, bins=16)")) == "bvh(leaf=2)"


def test_a_walks_own_counters_reach_the_stats_table_and_the_cost_model():
    from raykernel.aggregates import csg
    from raykernel.analysis.costmodel import features
    from raykernel.rendering.stats import Stats
    assert all(C.WALK_OWN <= k < C.N_COUNTERS for k in (csg.CROSSINGS, csg.RESOLVES, csg.SURFACES))
    totals = np.zeros(C.N_COUNTERS, np.int64)
    totals[C.RAYS_EYE] = 10
    totals[csg.CROSSINGS], totals[csg.RESOLVES], totals[csg.SURFACES] = 12, 4, 6
    s = Stats.from_counters(totals, {}, 0.0, 1.0, {})
    assert (s["csg.crossings"], s["csg.resolves"], s["csg.surfaces"]) == (12, 4, 6)
    rows = [r for r in s.rows() if r[0] == "csg"]
    assert [r[2] for r in rows] == ["4", "12", "6"] and "3.00 operand surfaces per node" in rows[1][3]
    f = features(s)
    assert f["csg.crossing"] == 12 and f["csg.resolve"] == 4 and "csg.surfaces" not in f
    assert not [r for r in Stats.from_counters(np.zeros(C.N_COUNTERS, np.int64), {}, 0.0, 1.0, {}).rows()
                if r[0] == "csg"]


def test_an_operator_kind_registered_is_a_json_item_of_its_own(monkeypatch):
    # a kind's JSON item comes from its Kind alone: lists, spec from their lengths, operand limit
    from raykernel.errors import SceneError
    from raykernel.scene.jsonscene import scene_from_json
    toy = Kind("toyop", "a test operator", (Param("first", 1, "operands in the first list", int, 0, 9),),
               operands=True, operand_lists=("left", "right"), max_operands=3,
               operand_spec=lambda counts: f"toyop(first={counts['left']})")
    monkeypatch.setitem(accel.KINDS, "toyop", toy)
    ball = {"sphere": {"center": [0, 0, 0], "radius": 1}}
    doc = {"scene": {"items": [{"toyop": {"left": [ball, ball], "right": [ball]}}]}}
    group = scene_from_json(doc).root.children[0]
    assert group.accel == "toyop(first=2)" and len(group.children) == 3
    doc = {"scene": {"items": [{"toyop": {"left": [ball, ball], "right": [ball, ball]}}]}}
    with pytest.raises(SceneError, match=r"/scene/items/0/toyop.*at most 3 operands, got 4"):
        scene_from_json(doc)
    with pytest.raises(SceneError, match="right"):
        scene_from_json({"scene": {"items": [{"toyop": {"left": [ball]}}]}})
    monkeypatch.delitem(accel.KINDS, "toyop")
    with pytest.raises(SceneError, match="toyop"):
        scene_from_json({"scene": {"items": [{"toyop": {"left": [ball], "right": []}}]}})
