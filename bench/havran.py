"""Havran's 1999 octree and uniform grid tables (Ray Tracing News 12) beside raykernel's, counter for counter.

    .venv/bin/python bench/havran.py [--resolution 512] [--depths 4 5 6 7] [--walks point neighbor parametric]
                                     [--scenes BALLS ...] [--build-only] [--no-write]

Havran built octrees over the SPD scenes at their default sizes (teapot at
size 12, the size the SPD statistics use; fluid, a scene of his own, is left
out) with a leaf holding at most one object or at the maximum depth, objects
placed in octants by their boxes, every octant of a split node a leaf of its
own (N_V = 7 N_IN + 1), no mailboxes and no shadow cache, and traced the SPD
procedure: 513 x 513 corner rays at 512 x 512, depth 5. raykernel's octree
with those settings is `octree(depth=D, leaf=1, collapse=off, budget=0,
mailbox=off)`, its three walks standing for his three traversals: point
(Glassner 1984, Octree84), neighbor (Samet 1989, Octree89) and parametric
(Revelles et al. 2000, in the place of Gargantini and Atkinson 1993,
Octree93). His "-A" octrees split at a cost minimum (Octree-R), which
raykernel does not build. His uniform grids (Havran and Sixta) are built at
the resolutions his tables print, `grid(cells=NXxNYxNZ, mailbox=off)`. The
published numbers are bench/data/havran1999_octrees.json and
havran1999_grids.json, each with its line in his files.

Build: N_IN interior nodes, N_V leaves (empty ones included), N_EV empty
leaves, N_OIV object references. Traversal, per ray (all rays: eye,
reflected, refracted, shadow): N_IT intersection tests, N_TS traversal steps
(nodes visited), N_ETS leaves visited, N_EETS empty leaves visited. N_IT_HIT
is the same tests over the rays that hit a surface (his IntersRequired): his
octree tables count N_IT so, his grid tables per ray. The rays themselves are
compared with his invariants and the SPD README's counts. Writes the `havran`
section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, machine, replace_section, subtable, tables  # noqa: E402

DATA = Path(__file__).resolve().parent / "data" / "havran1999_octrees.json"
GRID_DATA = Path(__file__).resolve().parent / "data" / "havran1999_grids.json"
SCENES = {"BALLS": "spd:balls:4", "GEARS": "spd:gears:4", "LATTICE": "spd:lattice:12", "MOUNT": "spd:mount:6",
          "RINGS": "spd:rings:7", "TEAPOT": "spd:teapot:12", "TETRA": "spd:tetra:6", "TREE": "spd:tree:11"}
WALKS = {"point": "Octree84-C", "neighbor": "Octree89-C", "parametric": "Octree93-C"}
BUILD = ("N_IN", "N_V", "N_EV", "N_OIV")
TRAVERSAL = ("N_IT", "N_IT_HIT", "N_TS", "N_ETS", "N_EETS")
R_TRAVERSAL = ("N_IT_HIT", "N_ETS", "N_EETS")
README_RAYS = ("eye_hit", "reflect", "refract", "shadow")
INVARIANTS = ("UsedIntPrimRay", "ShadowRay", "UsedIntShadRay", "SecondaryRay", "UsedIntSecRay", "IntersRequired")
# the summary in BENCHMARKS.md: the build table's rows at the first depth
SUMMARY = "Each cell: Havran's number / raykernel's (raykernel's difference). The octrees built at depth {depth}:"
BUILD_COLUMNS = ("scene", "depth") + BUILD
WALK_SUMMARY = ("Tests and steps per ray, point walk at depth {depth}: his N_IT beside raykernel's tests per ray "
                "(N_IT) and per ray that hits a surface (N_IT_HIT), the rule his octree tables follow:")
WALK_COLUMNS = ("scene", "N_IT", "N_IT_HIT", "N_TS")
GRID_COLUMNS = ("N_V", "N_EV", "N_OIV", "N_IT", "N_IT_HIT", "N_TS", "N_EETS")


def spec(depth: int, walk: str = "point") -> str:
    return f"octree(depth={depth}, leaf=1, collapse=off, budget=0, mailbox=off, walk={walk})"


def published() -> dict:
    return json.loads(DATA.read_text())["variants"]


def octree_r_spec(depth: int) -> str:
    return f"octree-r(depth={depth}, leaf=1, mailbox=off)"


def build_counts(scene, depth: int, adaptive: bool = False) -> dict:
    """Havran's build counters of raykernel's octree (adaptive: its Octree-R) over `scene` at `depth`."""
    from raykernel.engine.flatten import flatten
    _, stats = flatten(scene, octree_r_spec(depth) if adaptive else spec(depth))
    agg = stats["aggregates"][0]
    return {"N_IN": agg["octree_inner" if adaptive else "inner"], "N_V": agg["leaves"], "N_EV": agg["empty_leaves"],
            "N_OIV": agg["refs"]}


def grid_spec(resolution) -> str:
    return f"grid(cells={'x'.join(map(str, resolution))}, mailbox=off)"


def grid_counts(scene, resolution, render: bool, resolution_px: int) -> dict:
    """Havran's counters of raykernel's uniform grid at his resolution: N_V cells, N_EV empty ones,
    N_OIV references, and with render the per-ray traversal (N_TS = N_ETS: cells visited)."""
    import raykernel
    from raykernel.engine.flatten import flatten
    _, stats = flatten(scene, grid_spec(resolution))
    agg = stats["aggregates"][0]
    out = {"N_V": agg["leaves"], "N_EV": agg["empty_leaves"], "N_OIV": agg["refs"]}
    if render:
        st = raykernel.render(scene, accel=grid_spec(resolution), resolution=resolution_px, spd=True).stats
        out.update(N_IT=st["tests.per_ray"], N_IT_HIT=st["tests.total"] / max(rays_that_hit(st), 1),
                   N_TS=st["cells.visited_per_ray"], N_ETS=st["cells.leaves_per_ray"],
                   N_EETS=st["cells.empty_per_ray"])
    return out


def rule_counts(scene, depth: int, rule: str) -> dict:
    """The build counters of the same octree (centre splits, leaf of at most one item, every octant
    a leaf, raykernel's root box) with items placed by another overlap rule, counted in numpy:
    "closed" (a box touching an octant's face is in it, as raykernel places items, less its
    margin) or "halfopen" (octants as [lo, hi): a box whose top only touches an octant's bottom
    face is not in it)."""
    from raykernel.aggregates.grid import grid_box
    items = item_boxes(scene)
    lo, ext = grid_box(items)
    inner = leaves = empty = refs = 0
    stack = [(np.arange(len(items)), lo, lo + ext, 0)]
    while stack:
        idx, clo, chi, d = stack.pop()
        if len(idx) <= 1 or d == depth:
            leaves, empty, refs = leaves + 1, empty + (len(idx) == 0), refs + len(idx)
            continue
        inner += 1
        mid = 0.5 * (clo + chi)
        b = items[idx]
        for c in range(8):
            upper = np.array([(c >> a) & 1 for a in range(3)], bool)
            a0, a1 = np.where(upper, mid, clo), np.where(upper, chi, mid)
            below = b[:, :3] <= a1 if rule == "closed" else b[:, :3] < a1
            stack.append((idx[np.all(below & (b[:, 3:] >= a0), axis=1)], a0, a1, d + 1))
    return {"N_IN": inner, "N_V": leaves, "N_EV": empty, "N_OIV": refs}


def grid_rule_refs(scene, resolution) -> int:
    """The references of the uniform grid at `resolution` over raykernel's grid box with items
    placed by the half-open rule: a box in the cells from the one its low corner falls in to the
    one its high corner falls in (cells as [lo, hi)), counted in numpy."""
    from raykernel.aggregates.grid import grid_box
    items = item_boxes(scene)
    lo, ext = grid_box(items)
    res = np.asarray(resolution)
    first = np.clip(np.floor((items[:, :3] - lo) / ext * res), 0, res - 1)
    last = np.clip(np.floor((items[:, 3:] - lo) / ext * res), 0, res - 1)
    return int(np.prod(last - first + 1, axis=1).sum())


def item_boxes(scene) -> np.ndarray:
    """The item boxes raykernel's octree is built over (caught on their way to build_octree)."""
    from raykernel.aggregates import octree
    from raykernel.engine.flatten import flatten
    caught, build = [], octree.build_octree

    def catch(bounds, **kw):
        caught.append(np.asarray(bounds, np.float64).reshape(-1, 6))
        return build(bounds, **kw)
    octree.build_octree = catch
    try:
        flatten(scene, spec(1))
    finally:
        octree.build_octree = build
    return caught[0]


def rays_that_hit(st) -> int:
    """Havran's IntersRequired: the rays that meet a surface (eye, secondary, and blocked shadow rays)."""
    return st["rays.eye_hit"] + st["rays.reflect_hit"] + st["rays.refract_hit"] + st["rays.shadow_blocked"]


def traversal_counts(scene, depth: int, walk: str, resolution: int) -> dict:
    """Havran's per-ray traversal counters of a render with the SPD procedure (corner rays, depth 5);
    N_IT_HIT: the tests over the rays that hit, the rule his octree tables' N_IT follows. walk
    "kd": the Octree-R, walked as a k-d tree (its N_TS counts k-d nodes, three levels an octree's)."""
    import raykernel
    accel = octree_r_spec(depth) if walk == "kd" else spec(depth, walk)
    st = raykernel.render(scene, accel=accel, resolution=resolution, spd=True).stats
    return {"N_IT": st["tests.per_ray"], "N_IT_HIT": st["tests.total"] / max(rays_that_hit(st), 1),
            "N_TS": st["cells.visited_per_ray"], "N_ETS": st["cells.leaves_per_ray"],
            "N_EETS": st["cells.empty_per_ray"], "rays": st["rays.total"]}


def ray_counts(scene, resolution: int) -> dict:
    """The SPD procedure's ray counts in Havran's names (any structure gives the same; the BVH is quickest)."""
    import raykernel
    st = raykernel.render(scene, accel="bvh", resolution=resolution, spd=True).stats
    return {"PrimaryRay": st["rays.eye"], "UsedIntPrimRay": st["rays.eye_hit"], "ShadowRay": st["rays.shadow"],
            "UsedIntShadRay": st["rays.shadow_blocked"], "SecondaryRay": st["rays.reflect"] + st["rays.refract"],
            "UsedIntSecRay": st["rays.reflect_hit"] + st["rays.refract_hit"], "IntersRequired": rays_that_hit(st),
            # the SPD README's names; it counts a refraction ray at each total internal reflection too
            "eye_hit": st["rays.eye_hit"], "reflect": st["rays.reflect"], "refract": st["rays.refract_spd"],
            "shadow": st["rays.shadow"]}


def cell(theirs, ours) -> str:
    mine = f"{theirs:,}" if isinstance(theirs, int) else f"{theirs:g}"
    if ours is None:
        return f"{mine} / -"
    if not theirs:
        return f"{mine} / {ours:,}" if ours == 0 else f"{mine} / {ours:,.2f}"
    diff = (ours - theirs) / theirs * 100
    fmt = "{:,}" if isinstance(ours, int) else "{:.2f}"
    return f"{mine} / {fmt.format(ours)} ({diff:+.1f}%)"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--depths", type=int, nargs="*", default=[4, 5, 6, 7])
    ap.add_argument("--walks", nargs="*", default=list(WALKS))
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--build-only", action="store_true")
    ap.add_argument("--rules", action="store_true", help="also count the builds under the half-open overlap rule")
    ap.add_argument("--no-grids", action="store_true", help="leave out the uniform grids")
    ap.add_argument("--octree-r", action="store_true", help="also his -A octrees, as raykernel's octree-r")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    import raykernel
    pub = published()
    build_rows, walk_rows, rule_rows, grid_rows, ray_rows, r_rows, r_walk_rows = [], [], [], [], [], [], []
    grid_data = json.loads(GRID_DATA.read_text())
    grids, invariants, readme = grid_data["scenes"], grid_data["invariants"]["scenes"], grid_data["spd_readme_rays"]
    for name in args.scenes:
        scene = raykernel.load(SCENES[name])
        if not args.build_only:
            ours = ray_counts(scene, args.resolution)
            ray_rows.append((name, invariants[name], readme["scenes"].get(name), ours))
            print(name, {k: cell(invariants[name][k], ours[k]) for k in INVARIANTS}, flush=True)
        for depth in args.depths:
            theirs = pub["Octree84-C"][name]["depths"][str(depth)]
            ours = build_counts(scene, depth)
            build_rows.append((name, depth, theirs, ours))
            print(name, depth, {k: cell(theirs[k], ours[k]) for k in BUILD}, flush=True)
            if args.rules:
                model = rule_counts(scene, depth, "halfopen")
                rule_rows.append((name, depth, theirs, model))
                print("  half-open", {k: cell(theirs[k], model[k]) for k in BUILD}, flush=True)
            if args.octree_r:
                theirs_r = pub["Octree84-A"][name]["depths"][str(depth)]
                ours_r = build_counts(scene, depth, adaptive=True)
                r_rows.append((name, depth, theirs_r, ours_r))
                print("  octree-r", {k: cell(theirs_r[k], ours_r[k]) for k in BUILD}, flush=True)
                if not args.build_only:         # one walk of raykernel's beside both of his over that tree
                    ours_w = traversal_counts(scene, depth, "kd", args.resolution)
                    for variant in ("Octree84-A", "Octree93-A"):
                        his = pub[variant][name]["depths"][str(depth)]
                        theirs_w = dict(his, N_IT_HIT=his["N_IT"])
                        r_walk_rows.append((name, depth, variant, theirs_w, ours_w))
                        print("  octree-r", variant, {k: cell(theirs_w[k], ours_w[k]) for k in R_TRAVERSAL},
                              flush=True)
            if args.build_only:
                continue
            for walk in args.walks:
                t0 = time.perf_counter()
                theirs_w = dict(pub[WALKS[walk]][name]["depths"][str(depth)])
                theirs_w["N_IT_HIT"] = theirs_w["N_IT"]
                ours_w = traversal_counts(scene, depth, walk, args.resolution)
                walk_rows.append((name, depth, walk, theirs_w, ours_w))
                print(" ", walk, {k: cell(theirs_w[k], ours_w[k]) for k in TRAVERSAL},
                      f"{time.perf_counter() - t0:.1f} s", flush=True)
        if args.no_grids or name not in grids:
            continue
        for setting, theirs in grids[name]["settings"].items():
            theirs = dict(theirs, N_IT_HIT=theirs["N_IT"])
            ours = grid_counts(scene, theirs["Resolution"], not args.build_only, args.resolution)
            if args.rules:
                ours["N_OIV_HALFOPEN"] = grid_rule_refs(scene, theirs["Resolution"])
                theirs["N_OIV_HALFOPEN"] = theirs["N_OIV"]
            grid_rows.append((name, setting, theirs, ours))
            print(name, setting, {k: cell(theirs[k], ours[k]) for k in ours}, flush=True)
    lines = ["## Havran's 1999 octree and grid tables reproduced", "", f"Machine: {machine()}.", "",
             f"Command: `.venv/bin/python bench/havran.py {' '.join(sys.argv[1:])}` ({time.strftime('%Y-%m-%d')})",
             "",
             DETAILS, "",
             " ".join(__doc__.split("\n\n")[2:4]).replace("\n", " "), "",
             "Each cell: Havran's number / raykernel's (raykernel's difference).", "",
             "| scene | depth | " + " | ".join(BUILD) + " |", "|---|---:|" + "---:|" * len(BUILD)]
    for name, depth, theirs, ours in build_rows:
        lines.append(f"| {name} | {depth} | " + " | ".join(cell(theirs[k], ours[k]) for k in BUILD) + " |")
    if rule_rows:
        lines += ["", "The same builds counted with items placed by the half-open rule (rule_counts):", "",
                  "| scene | depth | " + " | ".join(BUILD) + " |", "|---|---:|" + "---:|" * len(BUILD)]
        for name, depth, theirs, ours in rule_rows:
            lines.append(f"| {name} | {depth} | " + " | ".join(cell(theirs[k], ours[k]) for k in BUILD) + " |")
    if ray_rows:
        lines += ["", f"The rays at {args.resolution} x {args.resolution}: the SPD README's counts / raykernel's "
                  "(refraction rays counted as the README counts them, total internal reflections included; the "
                  "README lists no lattice):", "",
                  "| scene | " + " | ".join(README_RAYS) + " |", "|---|" + "---:|" * len(README_RAYS)]
        for name, _, spd, ours in ray_rows:
            if spd:
                lines.append(f"| {name} | " + " | ".join(cell(spd[k], ours[k]) for k in README_RAYS) + " |")
        lines += ["", "Havran's invariants (the grid file's line 70 on) / raykernel's; IntersRequired: the rays that "
                  "hit a surface:", "",
                  "| scene | " + " | ".join(INVARIANTS) + " |", "|---|" + "---:|" * len(INVARIANTS)]
        for name, theirs, _, ours in ray_rows:
            lines.append(f"| {name} | " + " | ".join(cell(theirs[k], ours[k]) for k in INVARIANTS) + " |")
    if walk_rows:
        lines += ["", f"Traversal at {args.resolution} x {args.resolution} (corner rays): N_IT, N_TS, N_ETS and "
                  "N_EETS per ray of all kinds; N_IT_HIT: the same tests per ray that hits a surface "
                  "(IntersRequired), each beside his N_IT:", "",
                  "| scene | depth | walk (his) | " + " | ".join(TRAVERSAL) + " |",
                  "|---|---:|---|" + "---:|" * len(TRAVERSAL)]
        for name, depth, walk, theirs, ours in walk_rows:
            lines.append(f"| {name} | {depth} | {walk} ({WALKS[walk]}) | "
                         + " | ".join(cell(theirs[k], ours[k]) for k in TRAVERSAL) + " |")
    if r_rows:
        lines += ["", "His -A octrees (Octree-R) beside raykernel's `octree-r(depth=D, leaf=1, mailbox=off)`, whose "
                  "planes follow his statement of the rule (its docstring), stored and walked as a k-d tree: "
                  "the build (N_IN: octree nodes split)" + (", then tests and leaves per ray beside his Octree84-A and "
                  "Octree93-A (N_TS left out: the k-d tree steps through three levels an octree node)"
                  if r_walk_rows else "")
                  + ":", "",
                  "| scene | depth | " + " | ".join(BUILD) + " |", "|---|---:|" + "---:|" * len(BUILD)]
        for name, depth, theirs, ours in r_rows:
            lines.append(f"| {name} | {depth} | " + " | ".join(cell(theirs[k], ours[k]) for k in BUILD) + " |")
    if r_walk_rows:
        lines += ["", "| scene | depth | his | " + " | ".join(R_TRAVERSAL) + " |",
                  "|---|---:|---|" + "---:|" * len(R_TRAVERSAL)]
        for name, depth, variant, theirs, ours in r_walk_rows:
            lines.append(f"| {name} | {depth} | {variant} | "
                         + " | ".join(cell(theirs[k], ours[k]) for k in R_TRAVERSAL) + " |")
    if grid_rows:
        columns = GRID_COLUMNS + (("N_OIV_HALFOPEN",) if args.rules else ())
        lines += ["", "Uniform grids at his resolutions (`grid(cells=NXxNYxNZ, mailbox=off)`; N_TS = N_ETS, cells "
                  "visited" + ("; N_OIV_HALFOPEN: the references with items placed by the half-open rule, beside "
                               "his N_OIV (grid_rule_refs)" if args.rules else "") + "):", "",
                  "| scene | setting | cells | " + " | ".join(columns) + " |",
                  "|---|---|---|" + "---:|" * len(columns)]
        for name, setting, theirs, ours in grid_rows:
            lines.append(f"| {name} | {setting} | {'x'.join(map(str, theirs['Resolution']))} | "
                         + " | ".join(cell(theirs[k], ours.get(k)) for k in columns) + " |")
    at = lines.index(DETAILS)             # the summary: the build counts at the first depth
    summary = [SUMMARY.format(depth=args.depths[0]), "",
               *subtable(tables(lines)[0], BUILD_COLUMNS, {"depth": [str(args.depths[0])]}), ""]
    walked = [t for t in tables(lines) if "walk (his)" in t[0]]
    if walked:                            # and the point walk's tests at that depth, per ray and per ray that hits
        summary += [WALK_SUMMARY.format(depth=args.depths[0]), "",
                    *subtable(walked[0], WALK_COLUMNS, {"depth": [str(args.depths[0])],
                                                        "walk (his)": [f"point ({WALKS['point']})"]}), ""]
    lines[at:at] = summary
    text = "\n".join(lines)
    print(text)
    if not args.no_write:
        replace_section("havran", text)


if __name__ == "__main__":
    main()
