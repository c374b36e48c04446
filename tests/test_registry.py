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
