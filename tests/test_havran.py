"""Havran's 1999 octree tables (bench/data/havran1999_octrees.json, from his file in the SPD repository):
the build counts raykernel's octree reproduces exactly with his settings (bench/havran.py prints them all)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import raykernel
from raykernel.engine.flatten import flatten

DATA = Path(__file__).resolve().parents[1] / "bench" / "data" / "havran1999_octrees.json"
SCENES = {"BALLS": "spd:balls:4", "LATTICE": "spd:lattice:12", "MOUNT": "spd:mount:6", "RINGS": "spd:rings:7",
          "TEAPOT": "spd:teapot:12", "TREE": "spd:tree:11"}
# (scene, depth): the counts that are equal; the others differ by the overlap rule at octant faces
# (BENCHMARKS.md, "Havran's 1999 octree and grid tables reproduced")
MATCHED = {("BALLS", 4): ("N_IN", "N_V", "N_EV"), ("BALLS", 5): ("N_IN", "N_V"),
           ("LATTICE", 4): ("N_IN", "N_V", "N_EV", "N_OIV"), ("LATTICE", 5): ("N_IN", "N_V", "N_EV", "N_OIV"),
           ("LATTICE", 6): ("N_IN", "N_V"), ("MOUNT", 4): ("N_IN", "N_V"), ("RINGS", 4): ("N_IN", "N_V", "N_EV"),
           ("RINGS", 5): ("N_IN", "N_V"), ("TEAPOT", 4): ("N_IN", "N_V"), ("TREE", 4): ("N_IN", "N_V", "N_EV"),
           ("TREE", 5): ("N_IN", "N_V", "N_EV"), ("TREE", 6): ("N_IN", "N_V", "N_EV"), ("TREE", 7): ("N_IN", "N_V")}


@pytest.fixture(scope="module")
def published():
    return json.loads(DATA.read_text())["variants"]["Octree84-C"]


@pytest.mark.parametrize("scene,depth", sorted(MATCHED))
def test_the_octree_builds_as_havran_counted(published, scene, depth):
    _, stats = flatten(raykernel.load(SCENES[scene]),
                       f"octree(depth={depth}, leaf=1, collapse=off, budget=0, mailbox=off)")
    agg = stats["aggregates"][0]
    ours = {"N_IN": agg["inner"], "N_V": agg["leaves"], "N_EV": agg["empty_leaves"], "N_OIV": agg["refs"]}
    theirs = published[scene]["depths"][str(depth)]
    assert {k: ours[k] for k in MATCHED[scene, depth]} == {k: theirs[k] for k in MATCHED[scene, depth]}
    assert ours["N_V"] == 7 * ours["N_IN"] + 1          # every octant of a split node is a leaf, as in his tables


def test_the_published_numbers_are_his_file_as_printed(published):
    """A few numbers checked by hand against docs/havran_stats_octrees.txt (line 138 on)."""
    balls = published["BALLS"]
    assert balls["line"] == 138
    assert balls["depths"]["6"] == {"N_IN": 304, "N_V": 2129, "N_EV": 1038, "N_OIV": 15611, "N_IT": 209.6,
                                    "N_TS": 123.2, "N_ETS": 19.88, "N_EETS": 12.54}
    for scene in published.values():
        for row in scene["depths"].values():
            assert row["N_V"] == 7 * row["N_IN"] + 1


GRIDS = Path(__file__).resolve().parents[1] / "bench" / "data" / "havran1999_grids.json"
GRID_SCENES = dict(SCENES, TETRA="spd:tetra:6")
# (scene, setting): the counts equal at his printed resolution
GRID_MATCHED = {("BALLS", "Woo's D = 1.0"): ("N_V", "N_EV"), ("LATTICE", "Woo's D = 1.0"): ("N_V", "N_EV", "N_OIV"),
                ("LATTICE", "Woo's D = 10.0"): ("N_V", "N_EV"), ("TETRA", "Woo's D = 10.0"): ("N_V", "N_EV", "N_OIV"),
                ("TREE", "Woo's D = 1.0"): ("N_V", "N_EV"), ("TREE", "Woo's D = 10.0"): ("N_V", "N_EV"),
                ("TREE", "Customary setting"): ("N_V", "N_EV")}


@pytest.mark.parametrize("scene,setting", sorted(GRID_MATCHED))
def test_the_uniform_grid_builds_as_havran_counted(scene, setting):
    theirs = json.loads(GRIDS.read_text())["scenes"][scene]["settings"][setting]
    cells = "x".join(map(str, theirs["Resolution"]))
    _, stats = flatten(raykernel.load(GRID_SCENES[scene]), f"grid(cells={cells}, mailbox=off)")
    agg = stats["aggregates"][0]
    ours = {"N_V": agg["leaves"], "N_EV": agg["empty_leaves"], "N_OIV": agg["refs"]}
    assert tuple(agg["res"]) == tuple(theirs["Resolution"])
    assert {k: ours[k] for k in GRID_MATCHED[scene, setting]} == {k: theirs[k] for k in GRID_MATCHED[scene, setting]}


def test_grid_cells_must_be_three_positive_numbers():
    from raykernel.errors import OptionError
    for bad in ("46x46", "0x4x4", "ax4x4"):
        with pytest.raises(OptionError, match="grid cells must be three positive whole numbers"):
            flatten(raykernel.load("spd:balls:1"), f"grid(cells={bad})")
