"""The aggregate registry, stack-entry tags and the accelerator spec parser."""

import numpy as np
import pytest

from raykernel.aggregates import WALKS
from raykernel.aggregates.walk import STEP_BITS, entry_kind, entry_step, entry_tag
from raykernel.engine.flatten import AGGREGATE_FIELDS, PRIMITIVE_FIELDS, WIDE_FIELDS, Geometry
from raykernel.errors import OptionError
from raykernel.scene import accel


def test_walk_codes_are_unique_and_dense():
    assert sorted(w.CODE for w in WALKS) == list(range(len(WALKS)))


@pytest.mark.parametrize("kind", range(len(WALKS)))
def test_entry_tags_decode_to_kind_and_step(kind):
    seen = set()
    for step in range(1 << STEP_BITS):
        tag = entry_tag(kind, step)
        assert tag < 0                      # never a reference range (stack_b >= 0)
        assert (entry_kind(tag), entry_step(tag)) == (kind, step)
        seen.add(tag)
    assert len(seen) == 1 << STEP_BITS


def test_tags_of_different_kinds_never_collide():
    tags = [entry_tag(k, s) for k in range(len(WALKS)) for s in range(1 << STEP_BITS)]
    assert len(set(tags)) == len(tags)


def test_geometry_holds_every_field_once():
    names = list(PRIMITIVE_FIELDS) + [f.name for f in AGGREGATE_FIELDS] + list(WIDE_FIELDS)
    assert len(names) == len(set(names))
    assert list(Geometry._fields) == names + ["root"]
    for w in WALKS:
        for f in w.FIELDS:
            assert f.name in Geometry._fields


def test_every_kind_can_be_built():
    for name, kind in accel.KINDS.items():
        assert callable(kind.flatten), name
        assert name in accel.describe()


def test_spec_key_given_twice_is_an_error():
    with pytest.raises(OptionError, match="leaf.*twice"):
        accel.parse_spec("bvh(leaf=1,leaf=2)")


@pytest.mark.parametrize("spec", ["", "  ", "(leaf=2)", "bvh(", "nosuchkind"])
def test_bad_spec_error_lists_every_kind(spec):
    with pytest.raises(OptionError) as err:
        accel.parse_spec(spec)
    for name in accel.KINDS:
        assert name in str(err.value)


def test_register_twice_is_refused():
    with pytest.raises(ValueError, match="twice"):
        accel.register(accel.KINDS["bvh"])


def test_format_spec_round_trips():
    for name in accel.KINDS:
        kind, params = accel.parse_spec(name)
        assert accel.parse_spec(accel.format_spec(kind, params)) == (kind, params)
    assert np.all([accel.format_spec(*accel.parse_spec(n)) == n for n in accel.KINDS])


def test_walks_own_counters_have_columns_and_names_of_their_own():
    from raykernel.aggregates import WALK_COUNTERS, csg
    from raykernel.geometry import counters as C
    named = list(C.NAMES.values())
    assert len(named) == len(set(named))
    assert max(k for k in C.NAMES if k < C.WALK_OWN) < C.WALK_OWN
    own = {C.NAMES[k] for k in C.NAMES if k >= C.WALK_OWN}
    assert own == {name for name, _ in WALK_COUNTERS}
    assert [C.NAMES[k] for k in (csg.CROSSINGS, csg.RESOLVES, csg.SURFACES)] == [n for n, _ in csg.COUNTERS]
    assert all(C.WALK_OWN <= k < C.N_COUNTERS for k in (csg.CROSSINGS, csg.RESOLVES, csg.SURFACES))


def test_claiming_more_counters_than_there_are_columns_is_an_error(monkeypatch):
    from raykernel.geometry import counters as C
    monkeypatch.setattr(C, "_next_own", [C.N_COUNTERS - 1])
    monkeypatch.setattr(C, "NAMES", dict(C.NAMES))
    with pytest.raises(ImportError, match="named twice"):
        C.claim(["rays.eye"])
    with pytest.raises(ImportError, match="no room"):
        C.claim(["toy.a", "toy.b"])
    assert C.claim(["toy.a"]) == (C.N_COUNTERS - 1,) and C.NAMES[C.N_COUNTERS - 1] == "toy.a"


def test_a_walks_own_counters_reach_the_stats_table_and_the_cost_model():
    from raykernel.aggregates import csg
    from raykernel.analysis.costmodel import features
    from raykernel.geometry import counters as C
    from raykernel.rendering.stats import Stats
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
    toy = accel.Kind("toyop", "a test operator", (accel.Param("first", 1, "operands in the first list", int, 0, 9),),
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


def test_the_csg_kinds_need_their_module_and_two_other_files():
    # adding a kind takes its module plus at most three small edits elsewhere (docs/adding-a-kind.md):
    # the CSG kinds' code is named outside csg.py only by the registry and the driver
    import io
    import tokenize
    from pathlib import Path

    import raykernel
    package = Path(raykernel.__file__).parent
    naming = set()
    for path in package.rglob("*.py"):
        tokens = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
        if any(t.type == tokenize.NAME and (t.string == "csg" or t.string.startswith("csg_")) for t in tokens):
            naming.add(path.relative_to(package).as_posix())
    assert naming == {"aggregates/csg.py", "aggregates/__init__.py", "engine/traverse.py"}
