"""The counter layout shared by every kernel: one int64 row per tile or chunk.

    counters = np.zeros((n_tiles, N_COUNTERS), np.int64)
    counters[tile, TESTS + SPHERE] += 1
    totals = counters.sum(axis=0)

Names follow Glassner 1988, the SPD procedure and Havran 1999 (docs/guide/statistics.md).
"""

RAYS_EYE, RAYS_EYE_HIT = 0, 1
RAYS_REFLECT, RAYS_REFLECT_HIT = 2, 3
RAYS_REFRACT, RAYS_REFRACT_HIT = 4, 5
RAYS_SHADOW, RAYS_SHADOW_BLOCKED = 6, 7
TESTS = 8                 # + primitive kind (sphere, polygon, patch, cone, triangle)
BOUNDS_TESTS = 13
CELLS_VISITED = 14        # traversal steps: nodes / cells visited (N_TS)
CELLS_LEAVES = 15         # leaves visited (N_ETS)
CELLS_EMPTY = 16          # empty leaves visited (N_EETS)
MAILBOX_SAVED = 17
SHADOW_CACHE_HITS = 18
RAYS_CAST = 19            # rays given to the ray-casting API
TRANSFORMS = 20           # + class (identity, translation, scale, affine): rays mapped into an instance
TRANSFORM_MULTIPLIES = 24  # multiplies those mappings did
RAYS_CUT_OFF = 25         # reflection and refraction rays not cast: their weight fell below the cut-off
RAYS_TIR = 26             # total internal reflections: refraction rays that Snell's law forbids
EYE_LIGHT_SKIPPED = 27    # shadow rays toward the light at the eye not cast for eye rays' hits
RAYTREE_TRIES = 28        # Haines's tricks (rendering/tricks.py): rays whose search began with the object the
RAYTREE_HITS = 29         # same node of the previous ray tree hit; of those, the searches it bounded
SHADOW_CACHE_TRIES = 30   # shadow rays that first tested the last blocker of their light and node
NORMALS_COMPUTED = 31     # surface normals computed (once per hit, or at every closer hit without trick 5)
FULL_WALKS = 32           # closest-hit searches that visited every candidate (trick 1 off)
START_LISTS = 33          # secondary rays that began with their object's start list (trick 6)
SHADOW_STEPS = 34         # closest-hit queries of filtered shadow rays walking through transparent surfaces
START_LISTS_HITS = 35     # searches a start list bounded, shadow rays it settled
START_LISTS_BUILT = 36    # start lists built (rendering/startlists.py)
POLYGON_CORNERS = 37      # corners walked by polygon and patch tests: those whose plane the ray met in range
HITS = 38                 # + primitive kind: tests that found the primitive within the ray's range
FRUSTUM_CULLED = 43       # eye rays of tiles culled whole (rendering/frustum.py): counted as misses, not traced
# each walk's share of the traversal (engine/traverse.py), by the walk's code; the registry
# (aggregates/registry.py) names them walk.<walk>.entries, .bounds and .steps
MAX_WALKS = 8
WALK_ENTRIES = 44         # + walk: rays that entered an aggregate of that walk (its box was hit)
WALK_BOUNDS = 52          # + walk: bound tests charged to it (its aggregates' boxes, its nodes' boxes and walls)
WALK_STEPS = 60           # + walk: its traversal steps (its part of cells.visited)
# each walk's counters of its own (its Walk.counters): OWN_PER_WALK columns a walk, by its code
WALK_OWN = 68
OWN_PER_WALK = 4
N_COUNTERS = WALK_OWN + MAX_WALKS * OWN_PER_WALK


NAMES = {
    RAYS_EYE: "rays.eye", RAYS_EYE_HIT: "rays.eye_hit",
    RAYS_REFLECT: "rays.reflect", RAYS_REFLECT_HIT: "rays.reflect_hit",
    RAYS_REFRACT: "rays.refract", RAYS_REFRACT_HIT: "rays.refract_hit",
    RAYS_SHADOW: "rays.shadow", RAYS_SHADOW_BLOCKED: "rays.shadow_blocked",
    TESTS + 0: "tests.sphere", TESTS + 1: "tests.polygon", TESTS + 2: "tests.patch",
    TESTS + 3: "tests.cone", TESTS + 4: "tests.triangle",
    HITS + 0: "hits.sphere", HITS + 1: "hits.polygon", HITS + 2: "hits.patch", HITS + 3: "hits.cone",
    HITS + 4: "hits.triangle",
    BOUNDS_TESTS: "bounds.tests", CELLS_VISITED: "cells.visited", CELLS_LEAVES: "cells.leaves",
    CELLS_EMPTY: "cells.empty", MAILBOX_SAVED: "mailbox.saved", SHADOW_CACHE_HITS: "shadow_cache.hits",
    RAYS_CAST: "rays.cast",
    TRANSFORMS + 0: "transforms.identity", TRANSFORMS + 1: "transforms.translation",
    TRANSFORMS + 2: "transforms.scale", TRANSFORMS + 3: "transforms.affine",
    TRANSFORM_MULTIPLIES: "transforms.multiplies",
    RAYTREE_TRIES: "raytree.tries", RAYTREE_HITS: "raytree.hits", SHADOW_CACHE_TRIES: "shadow_cache.tries",
    NORMALS_COMPUTED: "normals.computed", FULL_WALKS: "tricks.full_walks", START_LISTS: "start_lists.used",
    SHADOW_STEPS: "shadow.steps", START_LISTS_HITS: "start_lists.hits", START_LISTS_BUILT: "start_lists.built",
    RAYS_CUT_OFF: "rays.cut_off", RAYS_TIR: "rays.tir", EYE_LIGHT_SKIPPED: "shadow.eye_light_skipped",
    POLYGON_CORNERS: "polygon.corners", FRUSTUM_CULLED: "frustum.culled",
}
"""The fixed columns' names; with the walks' columns, registry.COUNTER_NAMES."""


def own_columns(code: int, n: int) -> tuple:
    """The columns of walk `code`'s n counters of its own (a walk's module takes them as it loads)."""
    if not 0 <= code < MAX_WALKS or n > OWN_PER_WALK:
        raise ImportError(f"counters: walk code {code} must be below {MAX_WALKS} and its counters at most "
                          f"{OWN_PER_WALK}, got {n}")
    first = WALK_OWN + code * OWN_PER_WALK
    return tuple(range(first, first + n))


def names(walks) -> dict:
    """Every column's name: the fixed ones, and for each walk (code, name, own counters) its entries,
    bounds, steps and own counters; the same whatever order the walks' modules were imported in."""
    out = dict(NAMES)
    for code, name, own in walks:
        out[WALK_ENTRIES + code] = f"walk.{name}.entries"
        out[WALK_BOUNDS + code] = f"walk.{name}.bounds"
        out[WALK_STEPS + code] = f"walk.{name}.steps"
        for column, counter in zip(own_columns(code, len(own)), own):
            out[column] = counter
    if len(set(out.values())) != len(out):
        raise ImportError("counters: a counter is named twice")
    return out
