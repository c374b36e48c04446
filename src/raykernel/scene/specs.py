"""A scene's groups and the structure specs they name.

    is_operator(group)          # its spec names a boolean operator (its children are operands)
    without_specs(scene)        # no group names a structure: rendered with accel=KIND, all of it is KIND
"""

from __future__ import annotations

import dataclasses

from ..aggregates.registry import KINDS, parse_spec
from ..aggregates.spec import is_auto
from .model import Group, Instance, Scene


def is_operator(group: Group) -> bool:
    """Whether the group's spec names a kind with operands (a boolean operator)."""
    if not group.accel or is_auto(group.accel):
        return False
    return KINDS[parse_spec(group.accel)[0]].operands


def without_specs(scene: Scene) -> Scene:
    """The scene with no group naming a structure (boolean operators kept): rendered with
    accel=KIND, everything is under that one kind. The primitive sets are shared, not copied."""
    memo: dict[int, Group] = {}

    def visit(g: Group) -> Group:
        if id(g) not in memo:
            kids = [Instance(visit(c.group), c.matrix) if isinstance(c, Instance) else visit(c) for c in g.children]
            memo[id(g)] = dataclasses.replace(g, children=kids, accel=g.accel if is_operator(g) else None)
        return memo[id(g)]

    return dataclasses.replace(scene, root=visit(scene.root))
